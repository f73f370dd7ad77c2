"""Start and drive ArduPilot's real ArduCopter SITL binary (a flight controller nobody here wrote).

The mock autopilot (:mod:`.mock_autopilot`) behaves like ArduCopter as far as we have observed
it; this module runs the real thing, so that tests and ``tcm-companion sitl --autopilot
ardupilot`` check the daemon and the Lua applet against the firmware itself. See
``../shared/ardupilot-sitl/README.md`` (the build) and ``../shared/docs/autopilots.md``.

::

    with ArduPilotSitl(params={"PRX1_TYPE": 2}) as sitl:   # boots, GPS, back to real time
        companion = sitl.connect(1, source_system=1, source_component=191)   # SERIAL1
        sitl.takeoff(5.0)
        sitl.fly_velocity(2.0, 0.0, 0.0)                   # north at 2 m/s, re-sent at 5 Hz
        sitl.set_mode("BRAKE")

What :meth:`ArduPilotSitl.start` does, and how long each step took here (wall time, 2-core
x86-64, ``--speedup 10``; :attr:`ArduPilotSitl.boot_timings_s` has the numbers of each run):

1. Picks a free instance N (``-I N``: tcp 5760+10N SERIAL0, 5762+10N SERIAL1, 5763+10N
   SERIAL2): holds ``/tmp/tcm-ardupilot-sitl-N.lock`` (``flock``, exclusive, for the
   instance's lifetime, so two processes or pytest-xdist workers never share one) and checks
   that the ports of N can be bound. Scanning starts at ``first_instance`` (default 20, or
   ``$TCM_ARDUPILOT_FIRST_INSTANCE``) and goes up.
2. Makes a working directory (its state: ``eeprom.bin``, ``scripts/``, ``logs/``), copies the
   Lua scripts into ``scripts/``, writes ``extra.parm`` with the caller's parameters and
   starts the binary by absolute path (a MAVLink reboot ``execv()``\\ s ``argv[0]``) with
   ``--model + --speedup 10 --defaults copter.parm,extra.parm -I N --home ... -w``. A
   comma-separated ``--defaults`` list works in this build (the console says ``Loaded
   defaults from copter.parm,extra.parm``; the later file wins). Console output goes to
   ``arducopter.log`` in the working directory.
3. Connects a ground-station link (system 255, component 190, MAVLink 2) to SERIAL0, which
   the binary waits for before it boots: accepted 0.05-0.4 s after the spawn; HEARTBEAT
   0.05-0.25 s after connecting.
4. Asks for LOCAL_POSITION_NED, GLOBAL_POSITION_INT, SYS_STATUS and EKF_STATUS_REPORT with
   MAV_CMD_SET_MESSAGE_INTERVAL (applies to this link only; ~0.01 s for the four) and waits
   until the EKF uses GPS (STATUSTEXT ``EKF3 IMU0 is using GPS``, or EKF_STATUS_REPORT with an
   absolute horizontal position) and LOCAL_POSITION_NED flows: 4.0 s of wall time.
5. Sets ``SIM_SPEEDUP`` = 1 (confirmed by PARAM_VALUE, ~0.005 s), so that the rest runs in
   real time: afterwards ``time_boot_ms`` advances 1.000 s per wall second. The whole
   ``start()`` takes 4.2-4.5 s. :meth:`ArduPilotSitl.reboot` takes the same ~4.2 s (the
   binary re-executes itself without wiping: parameters set before survive).

Observed with this runner (ArduCopter V4.8.0-dev 1b34668c; ``tests/test_ardupilot_sitl.py``):
SERIAL1/SERIAL2 accept clients connecting any time after boot; heartbeats of other
components (a companion (1, 191) on SERIAL1) are routed to SERIAL0 and back; SIM_STATE (108)
and SIMSTATE (164) are sent when asked for, without any timestamp field (SIM_STATE's float
``lat``/``lon`` carry degE7, use ``lat_int``/``lon_int``); proximity health is SYS_STATUS bit
MAV_SYS_STATUS_SENSOR_PROXIMITY (:meth:`ArduPilotSitl.proximity_healthy`); ADSB_VEHICLE from
a companion is consumed by AP_ADSB/AP_Avoidance (COLLISION messages, AVOID_ADSB mode) but not
routed to other links.

The ground-station link (:class:`MavlinkTcpClient`) has one I/O thread that reads
continuously and records every message with its receive time (``time.monotonic()``): the
autopilot's heartbeats (mode = ``custom_mode``, armed flag), every STATUSTEXT, the latest
message of each type, the history of mode changes. Sends take a lock (pymavlink's
``MAVLink`` object is not thread-safe); periodic senders (our own HEARTBEAT at 1 Hz, the
GUIDED velocity set-point at 5 Hz) run on the I/O thread. The link reconnects by itself
when the TCP connection drops (a reboot).

Hygiene: :meth:`ArduPilotSitl.stop` (SIGTERM, wait, SIGKILL) runs on ``__exit__``, at
interpreter exit (``atexit``) and on a failed start; when started from the main thread the
child also gets SIGTERM from the kernel if this process dies (``PR_SET_PDEATHSIG``, which
survives the firmware's reboot ``execv``).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import errno
import fcntl
import math
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from ...mavlink.copter_modes import mode_name, mode_number
from ...mavlink.statustext import StatustextAssembler

__all__ = [
    "DEFAULT_HOME",
    "ENV_BINARY",
    "ENV_DEFAULTS",
    "ENV_FIRST_INSTANCE",
    "ArduPilotSitl",
    "Heartbeat",
    "MavlinkTcpClient",
    "Message",
    "ModeChange",
    "Received",
    "SitlError",
    "SitlTimeout",
    "StatusText",
    "find_binary",
    "find_defaults",
    "serial_port",
    "skip_reason",
]

ENV_BINARY = "TCM_ARDUPILOT_SITL"
ENV_DEFAULTS = "TCM_ARDUPILOT_DEFAULTS"
ENV_FIRST_INSTANCE = "TCM_ARDUPILOT_FIRST_INSTANCE"

#: tcm_companion/sim/vehicle/ardupilot_sitl.py -> the repository root
REPO_ROOT = Path(__file__).resolve().parents[3]
_SHARED_SITL = REPO_ROOT.parent / "shared" / "ardupilot-sitl"

#: ArduPilot's SITL test site (CMAC, Canberra): lat_deg, lon_deg, alt_m AMSL, heading_deg
DEFAULT_HOME: tuple[float, float, float, float] = (-35.363261, 149.165230, 584.0, 353.0)

#: SERIALn -> tcp port offset for instance 0 (``-I N`` adds 10 N)
_SERIAL_PORT_BASE = {0: 5760, 1: 5762, 2: 5763}
_DEFAULT_FIRST_INSTANCE = 20
_LOCK_DIR = Path("/tmp")

#: SET_POSITION_TARGET_LOCAL_NED type_mask: use vx, vy, vz (and yaw unless ignored) only
_TYPEMASK_VELOCITY = (
    mavlink2.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)

_EKF_USING_GPS = re.compile(r"EKF\d IMU\d is using GPS")

Message = Any  # a pymavlink MAVLink_message (pymavlink has no type stubs)
T = TypeVar("T")


class SitlError(RuntimeError):
    """The SITL did not start, or refused or ignored a request."""


class SitlTimeout(SitlError, TimeoutError):
    """A wait ran out of time."""


# ---------------------------------------------------------------------------------------------
# Finding the binary


def find_binary() -> Path | None:
    """The ArduCopter SITL binary: ``$TCM_ARDUPILOT_SITL``, else ``../shared/ardupilot-sitl/bin/
    arducopter`` next to this repository; None if that file does not exist."""
    env = os.environ.get(ENV_BINARY)
    path = Path(env) if env else _SHARED_SITL / "bin" / "arducopter"
    path = path.expanduser().resolve()
    return path if path.is_file() and os.access(path, os.X_OK) else None


def find_defaults(binary: Path | None = None) -> Path | None:
    """The SITL defaults file: ``$TCM_ARDUPILOT_DEFAULTS``, else ``params/copter.parm`` next to the
    binary's ``bin/``; None if absent."""
    env = os.environ.get(ENV_DEFAULTS)
    if env:
        path = Path(env).expanduser().resolve()
    else:
        binary = binary or find_binary()
        if binary is None:
            return None
        path = binary.parent.parent / "params" / "copter.parm"
    return path if path.is_file() else None


def skip_reason() -> str:
    """A one-line reason to skip tests that need the binary ('' when it is present)."""
    binary = find_binary()
    if binary is None:
        if os.environ.get(ENV_BINARY):
            return f"ArduCopter SITL not found: ${ENV_BINARY}={os.environ[ENV_BINARY]} is no binary"
        return (
            f"ArduCopter SITL not found: set ${ENV_BINARY} to an arducopter SITL binary "
            f"(looked for {_SHARED_SITL / 'bin' / 'arducopter'})"
        )
    if find_defaults(binary) is None:
        return f"ArduCopter SITL defaults not found: set ${ENV_DEFAULTS} (copter.parm)"
    return ""


def serial_port(instance: int, serial: int) -> int:
    """The tcp port of SERIAL0/1/2 of SITL instance ``instance`` (``-I``)."""
    return _SERIAL_PORT_BASE[serial] + 10 * instance


# ---------------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True, slots=True)
class Received:
    """A message and when it was received (``time.monotonic()``, s)."""

    t_s: float
    msg: Message


@dataclass(frozen=True, slots=True)
class StatusText:
    t_s: float
    severity: int
    text: str
    src_system: int
    src_component: int


@dataclass(frozen=True, slots=True)
class Heartbeat:
    t_s: float
    custom_mode: int
    armed: bool
    system_status: int


@dataclass(frozen=True, slots=True)
class ModeChange:
    """The autopilot's heartbeat showed ``mode`` (custom_mode) after ``previous`` (None: first)."""

    t_s: float
    mode: int
    previous: int | None

    @property
    def name(self) -> str:
        return mode_name(self.mode)


def _msg_id(msg_type: str | int) -> int:
    if isinstance(msg_type, int):
        return msg_type
    value = getattr(mavlink2, f"MAVLINK_MSG_ID_{msg_type.upper()}", None)
    if value is None:
        raise ValueError(f"unknown MAVLink message {msg_type!r}")
    return int(value)


# ---------------------------------------------------------------------------------------------
# A MAVLink 2 TCP client with its own I/O thread


class _Periodic:
    __slots__ = ("due_s", "factory", "period_s")

    def __init__(self, period_s: float, factory: Callable[[], Message | None], due_s: float):
        self.period_s = period_s
        self.factory = factory
        self.due_s = due_s


class MavlinkTcpClient:
    """A MAVLink 2 client of one SITL tcp port, as system ``source_system``/``source_component``.

    One I/O thread reads the socket, records every message and runs the periodic senders
    (its own HEARTBEAT at 1 Hz unless ``heartbeat_type`` is None). :meth:`send` may be called
    from any thread (a lock guards the pymavlink encoder/parser). When the connection drops
    (the autopilot rebooted) it reconnects by itself; sends in between are dropped and
    counted in :attr:`dropped_sends`.

    ``target_system``/``target_component`` (the autopilot, (1, 1)) are whose heartbeats feed
    :meth:`heartbeats`, :meth:`mode_changes`, :attr:`mode` and :attr:`armed`.
    """

    def __init__(
        self,
        port: int,
        *,
        host: str = "127.0.0.1",
        source_system: int = 255,
        source_component: int = mavlink2.MAV_COMP_ID_MISSIONPLANNER,
        heartbeat_type: int | None = mavlink2.MAV_TYPE_GCS,
        heartbeat_rate_hz: float = 1.0,
        target_system: int = 1,
        target_component: int = 1,
        connect_timeout_s: float = 10.0,
        history: int = 50_000,
        name: str = "",
    ) -> None:
        self.host = host
        self.port = port
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.target_component = target_component
        self.name = name or f"tcp:{host}:{port}"
        self.t0_s = time.monotonic()
        self._io_lock = threading.Lock()  # the socket writes and the pymavlink object
        self._cond = threading.Condition(threading.RLock())  # the records below
        self._mav = self._new_mav()
        self._sock: socket.socket | None = None
        self._history: deque[Received] = deque(maxlen=history)
        self._latest: dict[str, Received] = {}
        self._latest_by_source: dict[tuple[str, int, int], Received] = {}
        self._statustexts: list[StatusText] = []
        self._statustext_chunks = StatustextAssembler()
        self._heartbeats: deque[Heartbeat] = deque(maxlen=10_000)
        self._mode_changes: list[ModeChange] = []
        self._counts: dict[str, int] = {}
        self._periodic: dict[str, _Periodic] = {}
        self._periodic_lock = threading.Lock()
        self._stop = threading.Event()
        self.connects = 0
        self.disconnects = 0
        self.dropped_sends = 0
        self.bad_data = 0
        self._connect(timeout_s=connect_timeout_s)
        if heartbeat_type is not None:
            hb = self._mav.heartbeat_encode(
                heartbeat_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
            )
            self.set_periodic("heartbeat", heartbeat_rate_hz, lambda: hb)
        self._thread = threading.Thread(target=self._run, name=f"mavlink {self.name}", daemon=True)
        self._thread.start()

    # -- plumbing ----------------------------------------------------------------------------

    def _new_mav(self) -> Any:
        mav = mavlink2.MAVLink(
            self, srcSystem=self.source_system, srcComponent=self.source_component
        )
        mav.robust_parsing = True
        return mav

    def _connect(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.settimeout(1.0)
            try:
                sock.connect((self.host, self.port))
            except OSError as exc:
                sock.close()
                if time.monotonic() >= deadline or self._stop.is_set():
                    raise SitlError(f"cannot connect to {self.name}: {exc}") from exc
                time.sleep(0.05)
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(2.0)  # for sendall; reads only follow select()
            with self._io_lock:
                self._mav = self._new_mav()  # drop a half-parsed frame of the old connection
                self._sock = sock
            self.connects += 1
            return

    def write(self, buf: bytes) -> None:
        """pymavlink's ``file.write`` (called with the I/O lock held)."""
        sock = self._sock
        if sock is None:
            self.dropped_sends += 1
            return
        try:
            sock.sendall(buf)
        except OSError:
            self.dropped_sends += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            sock = self._sock
            if sock is None:
                try:
                    self._connect(timeout_s=0.5)
                except SitlError:
                    continue
                continue
            now = time.monotonic()
            with self._periodic_lock:
                due = min((p.due_s for p in self._periodic.values()), default=now + 0.05)
            timeout = max(0.0, min(0.05, due - now))
            try:
                readable, _, _ = select.select([sock], [], [], timeout)
            except (OSError, ValueError):
                readable = [sock]
            if readable:
                try:
                    data = sock.recv(65536)
                except (BlockingIOError, InterruptedError, TimeoutError):
                    data = None
                except OSError:
                    data = b""
                if data == b"":
                    self._drop_connection(sock)
                    continue
                if data:
                    with self._io_lock:
                        msgs = self._mav.parse_buffer(data) or []
                    self._record(time.monotonic(), msgs)
            self._run_periodic()

    def _drop_connection(self, sock: socket.socket) -> None:
        with self._io_lock:
            if self._sock is sock:
                self._sock = None
        with contextlib.suppress(OSError):
            sock.close()
        self.disconnects += 1

    def _run_periodic(self) -> None:
        now = time.monotonic()
        with self._periodic_lock:
            periodics = list(self._periodic.values())
        for periodic in periodics:
            if periodic.due_s <= now:
                # no drift, but no burst after a stall either
                periodic.due_s = max(periodic.due_s + periodic.period_s, now)
                msg = periodic.factory()
                if msg is not None:
                    self.send(msg)

    def _record(self, t_s: float, msgs: Iterable[Message]) -> None:
        with self._cond:
            for msg in msgs:
                mtype = msg.get_type()
                if mtype == "BAD_DATA":
                    self.bad_data += 1
                    continue
                rec = Received(t_s, msg)
                self._history.append(rec)
                self._latest[mtype] = rec
                src = (mtype, msg.get_srcSystem(), msg.get_srcComponent())
                self._latest_by_source[src] = rec
                self._counts[mtype] = self._counts.get(mtype, 0) + 1
                if mtype == "STATUSTEXT":
                    self._record_statustext(t_s, msg, src[1], src[2])
                elif mtype == "HEARTBEAT" and src[1:] == (
                    self.target_system,
                    self.target_component,
                ):
                    hb = Heartbeat(
                        t_s,
                        msg.custom_mode,
                        bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED),
                        msg.system_status,
                    )
                    previous = self._mode_changes[-1].mode if self._mode_changes else None
                    if previous != hb.custom_mode:
                        self._mode_changes.append(ModeChange(t_s, hb.custom_mode, previous))
                    self._heartbeats.append(hb)
            self._cond.notify_all()

    def _record_statustext(self, t_s: float, msg: Message, sysid: int, compid: int) -> None:
        """One :class:`StatusText` per text (chunks joined, :class:`StatustextAssembler`)."""
        whole = self._statustext_chunks.add(msg, t_s)
        if whole is not None:
            first_t_s, text = whole
            self._statustexts.append(StatusText(first_t_s, msg.severity, text, sysid, compid))

    # -- sending -----------------------------------------------------------------------------

    @property
    def mav(self) -> Any:
        """The pymavlink ``MAVLink`` object, for ``*_encode``. Send with :meth:`send`."""
        return self._mav

    def send(self, msg: Message) -> bool:
        """Send a message built with ``client.mav.<name>_encode(...)``; False if not connected."""
        with self._io_lock:
            if self._sock is None:
                self.dropped_sends += 1
                return False
            self._mav.send(msg)
            return True

    def send_bytes(self, data: bytes) -> bool:
        """Send frames encoded elsewhere (e.g. our dialect's, which this link's pymavlink
        does not know); False if not connected."""
        with self._io_lock:
            if self._sock is None:
                self.dropped_sends += 1
                return False
            self.write(data)
            return True

    def autopilot_boot_ms(self) -> int | None:
        """The autopilot's ``time_boot_ms`` now, from its latest time-stamped message
        (ATTITUDE, LOCAL_POSITION_NED, SYSTEM_TIME ...) plus the time since it came."""
        best: Received | None = None
        with self._cond:
            for kind in ("ATTITUDE", "LOCAL_POSITION_NED", "SYSTEM_TIME", "GLOBAL_POSITION_INT"):
                rec = self._latest_by_source.get((kind, self.target_system, self.target_component))
                if rec is not None and (best is None or rec.t_s > best.t_s):
                    best = rec
        if best is None:
            return None
        return int(best.msg.time_boot_ms + (time.monotonic() - best.t_s) * 1000.0)

    def set_periodic(self, key: str, rate_hz: float, factory: Callable[[], Message | None]) -> None:
        """Send ``factory()`` (skipped when None) at ``rate_hz`` from the I/O thread, the first
        one now, until :meth:`clear_periodic` (a new ``factory`` for ``key`` replaces it)."""
        if rate_hz <= 0:
            raise ValueError("rate_hz must be positive")
        with self._periodic_lock:
            self._periodic[key] = _Periodic(1.0 / rate_hz, factory, time.monotonic())

    def clear_periodic(self, key: str) -> None:
        with self._periodic_lock:
            self._periodic.pop(key, None)

    def time_boot_ms(self) -> int:
        """Milliseconds since this client started (for our messages' ``time_boot_ms``)."""
        return int((time.monotonic() - self.t0_s) * 1000) & 0xFFFFFFFF

    # -- records -----------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def latest(self, msg_type: str, src: tuple[int, int] | None = None) -> Received | None:
        """The last message of a type (from ``src`` = (sysid, compid) if given)."""
        with self._cond:
            if src is None:
                return self._latest.get(msg_type)
            return self._latest_by_source.get((msg_type, *src))

    def messages(
        self,
        msg_type: str | None = None,
        since_s: float | None = None,
        src: tuple[int, int] | None = None,
    ) -> list[Received]:
        """Recorded messages (bounded history), optionally of one type, received at or after
        ``since_s`` (monotonic), from ``src``."""
        with self._cond:
            out = list(self._history)
        return [
            r
            for r in out
            if (msg_type is None or r.msg.get_type() == msg_type)
            and (since_s is None or r.t_s >= since_s)
            and (src is None or (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == src)
        ]

    def count(self, msg_type: str) -> int:
        with self._cond:
            return self._counts.get(msg_type, 0)

    def statustexts(self, since_s: float | None = None) -> list[StatusText]:
        with self._cond:
            return [s for s in self._statustexts if since_s is None or s.t_s >= since_s]

    def heartbeats(self) -> list[Heartbeat]:
        """The target's (autopilot's) heartbeats, oldest first."""
        with self._cond:
            return list(self._heartbeats)

    def heartbeat_sources(self) -> dict[tuple[int, int], Received]:
        """The last HEARTBEAT from each (sysid, compid) seen on this link."""
        with self._cond:
            return {
                (k[1], k[2]): v for k, v in self._latest_by_source.items() if k[0] == "HEARTBEAT"
            }

    def mode_changes(self) -> list[ModeChange]:
        with self._cond:
            return list(self._mode_changes)

    @property
    def mode(self) -> int | None:
        """The target's custom_mode in its last heartbeat."""
        with self._cond:
            return self._heartbeats[-1].custom_mode if self._heartbeats else None

    @property
    def armed(self) -> bool | None:
        with self._cond:
            return self._heartbeats[-1].armed if self._heartbeats else None

    # -- waiting -----------------------------------------------------------------------------

    def wait_for(self, predicate: Callable[[], T | None], timeout_s: float, what: str = "") -> T:
        """Wait until ``predicate()`` (evaluated after each received batch, and at least every
        0.1 s) is truthy and return it; :class:`SitlTimeout` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                value = predicate()
                if value:
                    return value
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise SitlTimeout(
                        f"{self.name}: timed out after {timeout_s:.1f} s waiting for "
                        f"{what or getattr(predicate, '__name__', 'a condition')}"
                    )
                self._cond.wait(min(remaining, 0.1))

    def wait_message(
        self,
        msg_type: str,
        timeout_s: float,
        predicate: Callable[[Message], bool] | None = None,
        since_s: float | None = None,
        src: tuple[int, int] | None = None,
    ) -> Received:
        """The first message of a type received at/after ``since_s`` (default: now) from
        ``src`` that satisfies ``predicate``."""
        since = time.monotonic() if since_s is None else since_s

        def find() -> Received | None:
            found = None
            with self._cond:
                for rec in reversed(self._history):  # newest first, back to ``since``
                    if rec.t_s < since:
                        break
                    msg = rec.msg
                    if msg.get_type() != msg_type:
                        continue
                    if src is not None and (msg.get_srcSystem(), msg.get_srcComponent()) != src:
                        continue
                    if predicate is None or predicate(msg):
                        found = rec
            return found

        return self.wait_for(find, timeout_s, what=f"{msg_type}")

    def wait_statustext(
        self, pattern: str, timeout_s: float, since_s: float | None = None
    ) -> StatusText:
        """The first STATUSTEXT at/after ``since_s`` (default: now) matching regex ``pattern``."""
        since = time.monotonic() if since_s is None else since_s
        regex = re.compile(pattern)

        def find() -> StatusText | None:
            for st in self.statustexts(since):
                if regex.search(st.text):
                    return st
            return None

        return self.wait_for(find, timeout_s, what=f"STATUSTEXT /{pattern}/")

    def close(self) -> None:
        """Stop the I/O thread and close the socket (idempotent)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        with self._io_lock:
            sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def __enter__(self) -> MavlinkTcpClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------------
# Instance allocation


def _ports_free(instance: int) -> bool:
    """Whether the SITL's tcp ports (SERIAL0-2) and udp ports (RC in 5501+10N, irlock
    9005+10N) of ``instance`` can be bound (SO_REUSEADDR like the SITL's own listeners)."""
    tcp = [serial_port(instance, s) for s in (0, 1, 2)]
    udp = [5501 + 10 * instance, 9005 + 10 * instance]
    for kind, ports in ((socket.SOCK_STREAM, tcp), (socket.SOCK_DGRAM, udp)):
        for port in ports:
            with socket.socket(socket.AF_INET, kind) as sock:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    sock.bind(("0.0.0.0", port))
                except OSError:
                    return False
    return True


def _claim_instance(first: int, count: int) -> tuple[int, int]:
    """(instance, lock fd): the first instance >= ``first`` whose lock file we can hold and
    whose ports are free."""
    for instance in range(first, first + count):
        path = _LOCK_DIR / f"tcm-ardupilot-sitl-{instance}.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                continue
            raise
        if _ports_free(instance):
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return instance, fd
        os.close(fd)  # releases the lock
    raise SitlError(f"no free ArduPilot SITL instance in {first}..{first + count - 1}")


def _pdeathsig_preexec() -> Callable[[], None] | None:
    """A preexec_fn that asks the kernel to SIGTERM the child when its parent thread dies."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    pr_set_pdeathsig = 1

    def preexec() -> None:
        prctl(pr_set_pdeathsig, signal.SIGTERM)

    return preexec


# ---------------------------------------------------------------------------------------------
# The SITL


class ArduPilotSitl:
    """A running ArduCopter SITL and a ground-station link to it. Use as a context manager.

    ``params`` go into an extra defaults file (applied at every boot, after ``copter.parm``;
    ``-w`` wipes ``eeprom.bin`` at start). ``scripts`` (paths) and ``script_texts`` (file name
    -> Lua source) go into ``scripts/``. ``workdir``: use (and keep) this directory instead of
    a temporary one (removed at :meth:`stop` unless ``keep_workdir``). ``streams_hz``: message
    name -> rate asked for on the ground-station link at boot. ``real_time``: set SIM_SPEEDUP
    to 1 once the EKF uses GPS. ``die_with_parent``: PR_SET_PDEATHSIG (default: when started
    from the main thread; the kernel signals when the *thread* that started it ends).
    """

    DEFAULT_STREAMS_HZ: Mapping[str, float] = {
        "LOCAL_POSITION_NED": 10.0,
        "GLOBAL_POSITION_INT": 5.0,
        "SYS_STATUS": 5.0,
        "EKF_STATUS_REPORT": 2.0,
    }

    def __init__(
        self,
        *,
        params: Mapping[str, float] | None = None,
        scripts: Iterable[str | Path] = (),
        script_texts: Mapping[str, str] | None = None,
        binary: str | Path | None = None,
        defaults: str | Path | None = None,
        first_instance: int | None = None,
        instance_count: int = 80,
        speedup: float = 10.0,
        real_time: bool = True,
        home: Sequence[float] = DEFAULT_HOME,
        model: str = "+",
        workdir: str | Path | None = None,
        keep_workdir: bool = False,
        streams_hz: Mapping[str, float] | None = None,
        boot_timeout_s: float = 60.0,
        die_with_parent: bool | None = None,
    ) -> None:
        found = Path(binary) if binary is not None else find_binary()
        if found is None:
            raise SitlError(skip_reason())
        self.binary = found.expanduser().resolve()
        found_defaults = Path(defaults) if defaults is not None else find_defaults(self.binary)
        if found_defaults is None:
            raise SitlError(skip_reason() or "no defaults file")
        self.defaults = found_defaults.expanduser().resolve()
        self.params = dict(params or {})
        self.scripts = [Path(s) for s in scripts]
        self.script_texts = dict(script_texts or {})
        if first_instance is None:
            first_instance = int(os.environ.get(ENV_FIRST_INSTANCE, _DEFAULT_FIRST_INSTANCE))
        self.first_instance = first_instance
        self.instance_count = instance_count
        self.speedup = speedup
        self.real_time = real_time
        self.home = tuple(home)
        self.model = model
        self._workdir_arg = Path(workdir) if workdir is not None else None
        self.keep_workdir = keep_workdir or workdir is not None
        self.streams_hz = dict(self.DEFAULT_STREAMS_HZ if streams_hz is None else streams_hz)
        self.boot_timeout_s = boot_timeout_s
        self.die_with_parent = die_with_parent
        #: wall-clock durations (s) of the start-up steps of the last (re)boot
        self.boot_timings_s: dict[str, float] = {}
        self.instance: int | None = None
        self.workdir: Path | None = None
        self.process: subprocess.Popen[bytes] | None = None
        self._lock_fd: int | None = None
        self._log_file: Any = None
        self._gcs: MavlinkTcpClient | None = None
        self._clients: list[MavlinkTcpClient] = []
        self._velocity_key = "velocity"

    # -- life cycle --------------------------------------------------------------------------

    def __enter__(self) -> ArduPilotSitl:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Claim an instance, spawn the binary, connect, wait for GPS, go real time."""
        if self.process is not None:
            raise SitlError("already started")
        atexit.register(self.stop)
        try:
            self._start()
        except BaseException as exc:
            report = self.failure_report()
            self.stop()
            if isinstance(exc, SitlError):
                raise SitlError(f"{exc}\n{report}") from exc
            raise

    def _start(self) -> None:
        t_start = time.monotonic()
        self.instance, self._lock_fd = _claim_instance(self.first_instance, self.instance_count)
        prefix = f"tcm-ardupilot-sitl-{self.instance}-"
        # working directories of this instance left by a killed process (we hold its lock now)
        for stale in Path(tempfile.gettempdir()).glob(prefix + "*"):
            if stale.is_dir() and not (stale / ".keep").exists():
                shutil.rmtree(stale, ignore_errors=True)
        if self._workdir_arg is not None:
            self.workdir = self._workdir_arg.resolve()
            self.workdir.mkdir(parents=True, exist_ok=True)
        else:
            self.workdir = Path(tempfile.mkdtemp(prefix=prefix))
            if self.keep_workdir:
                (self.workdir / ".keep").touch()
        scripts_dir = self.workdir / "scripts"
        scripts_dir.mkdir(exist_ok=True)
        for script in self.scripts:
            shutil.copy(script, scripts_dir / script.name)
        for name, text in self.script_texts.items():
            (scripts_dir / name).write_text(text)
        extra = self.workdir / "extra.parm"
        extra.write_text("".join(f"{k} {v:.9g}\n" for k, v in self.params.items()))
        argv = [
            str(self.binary),
            "--model",
            self.model,
            "--speedup",
            f"{self.speedup:g}",
            "--defaults",
            f"{self.defaults},{extra}",
            "-I",
            str(self.instance),
            "--home",
            ",".join(f"{v:.9g}" for v in self.home),
            "-w",
        ]
        die = self.die_with_parent
        if die is None:
            die = threading.current_thread() is threading.main_thread()
        self._log_file = open(self.console_log_path, "wb")
        self.process = subprocess.Popen(
            argv,
            cwd=self.workdir,
            stdin=subprocess.DEVNULL,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
            preexec_fn=_pdeathsig_preexec() if die else None,
        )
        timings = {"claim_and_spawn": time.monotonic() - t_start}
        t = time.monotonic()
        self._gcs = self._connect_gcs()
        timings["serial0_accept"] = time.monotonic() - t
        self._wait_ready(timings, t_start)

    def _connect_gcs(self) -> MavlinkTcpClient:
        deadline = time.monotonic() + 15.0
        while True:
            self._check_alive()
            try:
                return MavlinkTcpClient(
                    self.serial_port(0), connect_timeout_s=0.2, name=f"SITL{self.instance} GCS"
                )
            except SitlError:
                if time.monotonic() > deadline:
                    raise

    def _wait_ready(self, timings: dict[str, float], t_start: float) -> None:
        gcs = self.gcs
        t = time.monotonic()
        gcs.wait_for(
            lambda: self._check_alive() or gcs.heartbeats(), 15.0, "the autopilot's HEARTBEAT"
        )
        timings["heartbeat"] = time.monotonic() - t
        self._streams_gps_real_time(timings, t_start, t_start, "")

    def _streams_gps_real_time(
        self, timings: dict[str, float], t_start: float, gps_since: float, after: str
    ) -> None:
        """The end of a boot: ask for the streams, wait until the EKF uses GPS (texts since
        ``gps_since``), then back to real time; step times into ``timings``."""
        t = time.monotonic()
        for name, rate_hz in self.streams_hz.items():
            self.set_message_interval(name, rate_hz)
        timings["message_intervals"] = time.monotonic() - t
        t = time.monotonic()
        since = gps_since if gps_since else t
        self.gcs.wait_for(
            lambda: self._check_alive() or self.ekf_uses_gps(since_s=since),
            self.boot_timeout_s,
            f"the EKF to use GPS and LOCAL_POSITION_NED to flow{after}",
        )
        timings["ekf_uses_gps"] = time.monotonic() - t
        if self.real_time:
            t = time.monotonic()
            self.set_param("SIM_SPEEDUP", 1.0)
            timings["sim_speedup_1"] = time.monotonic() - t
        timings["total"] = time.monotonic() - t_start
        self.boot_timings_s = timings

    def ekf_uses_gps(self, since_s: float | None = None) -> bool:
        """Whether the EKF has said it uses GPS (STATUSTEXT, or EKF_STATUS_REPORT with an
        absolute horizontal position) and LOCAL_POSITION_NED arrived (after ``since_s``)."""
        gcs = self.gcs
        lpn = gcs.latest("LOCAL_POSITION_NED")
        if lpn is None or (since_s is not None and lpn.t_s < since_s):
            return False
        if any(_EKF_USING_GPS.search(s.text) for s in gcs.statustexts(since_s)):
            return True
        ekf = gcs.latest("EKF_STATUS_REPORT")
        flags = ekf.msg.flags if ekf is not None else 0
        return bool(flags & mavlink2.EKF_POS_HORIZ_ABS) and not (
            flags & mavlink2.EKF_CONST_POS_MODE
        )

    def _check_alive(self) -> bool:
        """Raise if the process has exited; False otherwise (so it can sit in an ``or``)."""
        if self.process is not None and self.process.poll() is not None:
            raise SitlError(f"arducopter exited with status {self.process.returncode}")
        return False

    def stop(self) -> None:
        """Close every link, SIGTERM the process (SIGKILL after 5 s), release the instance.
        Idempotent; also runs at interpreter exit."""
        atexit.unregister(self.stop)
        for client in [*self._clients, *([self._gcs] if self._gcs else [])]:
            client.close()
        self._clients.clear()
        proc, self.process = self.process, None
        if proc is not None and proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                proc.wait(timeout=5.0)
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
        if self.workdir is not None and not self.keep_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    # -- where things are --------------------------------------------------------------------

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process is not None else None

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def console_log_path(self) -> Path:
        """The binary's stdout+stderr."""
        if self.workdir is None:
            raise SitlError("not started")
        return self.workdir / "arducopter.log"

    def serial_port(self, serial: int) -> int:
        """The tcp port of SERIAL0/1/2 of this instance."""
        if self.instance is None:
            raise SitlError("not started")
        return serial_port(self.instance, serial)

    def serial_url(self, serial: int) -> str:
        """``tcp:127.0.0.1:PORT`` of SERIAL0/1/2 (our daemon: SERIAL1; a camera: SERIAL2)."""
        return f"tcp:127.0.0.1:{self.serial_port(serial)}"

    @property
    def serial1_url(self) -> str:
        return self.serial_url(1)

    @property
    def serial2_url(self) -> str:
        return self.serial_url(2)

    @property
    def gcs(self) -> MavlinkTcpClient:
        """The ground-station link on SERIAL0 (system 255, component 190)."""
        if self._gcs is None:
            raise SitlError("not started")
        return self._gcs

    def connect(
        self,
        serial: int = 1,
        *,
        source_system: int = 1,
        source_component: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER,
        heartbeat_type: int | None = mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
        name: str = "",
    ) -> MavlinkTcpClient:
        """Another MAVLink client on SERIALn (default: a companion, (1, 191), on SERIAL1);
        closed by :meth:`stop`."""
        client = MavlinkTcpClient(
            self.serial_port(serial),
            source_system=source_system,
            source_component=source_component,
            heartbeat_type=heartbeat_type,
            name=name or f"SITL{self.instance} SERIAL{serial} ({source_system},{source_component})",
        )
        self._clients.append(client)
        return client

    def console_tail(self, lines: int = 40) -> str:
        try:
            text = self.console_log_path.read_text(errors="replace")
        except (OSError, SitlError):
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def failure_report(self, lines: int = 30) -> str:
        """The console's tail and the last STATUSTEXTs, for assertion messages."""
        texts = self._gcs.statustexts()[-lines:] if self._gcs is not None else []
        where = f"SITL instance {self.instance}, working directory {self.workdir}"
        return (
            f"{where}\n--- console ---\n{self.console_tail(lines)}\n--- STATUSTEXT ---\n"
            + "\n".join(f"{s.t_s:.2f} [{s.severity}] {s.text}" for s in texts)
        )

    # -- the recorded link (delegates to the GCS client) -------------------------------------

    def statustexts(self, since_s: float | None = None) -> list[StatusText]:
        return self.gcs.statustexts(since_s)

    def mode_changes(self) -> list[ModeChange]:
        return self.gcs.mode_changes()

    def heartbeats(self) -> list[Heartbeat]:
        return self.gcs.heartbeats()

    def latest(self, msg_type: str, src: tuple[int, int] | None = None) -> Received | None:
        return self.gcs.latest(msg_type, src)

    def wait_for(self, predicate: Callable[[], T | None], timeout_s: float, what: str = "") -> T:
        return self.gcs.wait_for(predicate, timeout_s, what)

    def wait_message(
        self,
        msg_type: str,
        timeout_s: float,
        predicate: Callable[[Message], bool] | None = None,
        since_s: float | None = None,
        src: tuple[int, int] | None = None,
    ) -> Received:
        return self.gcs.wait_message(msg_type, timeout_s, predicate, since_s, src)

    def wait_statustext(
        self, pattern: str, timeout_s: float, since_s: float | None = None
    ) -> StatusText:
        return self.gcs.wait_statustext(pattern, timeout_s, since_s)

    @property
    def mode(self) -> int | None:
        return self.gcs.mode

    @property
    def armed(self) -> bool | None:
        return self.gcs.armed

    def local_position_ned(self) -> Message | None:
        """The last LOCAL_POSITION_NED (x, y, z m; vx, vy, vz m/s; time_boot_ms)."""
        rec = self.gcs.latest("LOCAL_POSITION_NED")
        return rec.msg if rec is not None else None

    def proximity_healthy(self) -> bool | None:
        """From the last SYS_STATUS: None if no proximity sensor is present (or no SYS_STATUS
        yet), else its bit MAV_SYS_STATUS_SENSOR_PROXIMITY in ``onboard_control_sensors_health``."""
        rec = self.gcs.latest("SYS_STATUS", (1, 1))
        if rec is None:
            return None
        bit = mavlink2.MAV_SYS_STATUS_SENSOR_PROXIMITY
        if not rec.msg.onboard_control_sensors_present & bit:
            return None
        return bool(rec.msg.onboard_control_sensors_health & bit)

    # -- commands ----------------------------------------------------------------------------

    def command_long(
        self,
        command: int,
        *params: float,
        timeout_s: float = 3.0,
        target_component: int = 1,
    ) -> int:
        """Send COMMAND_LONG (up to 7 params) and return the final COMMAND_ACK result
        (MAV_RESULT); :class:`SitlTimeout` without one."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        gcs = self.gcs
        since = time.monotonic()
        gcs.send(gcs.mav.command_long_encode(1, target_component, command, 0, *p[:7]))
        rec = gcs.wait_message(
            "COMMAND_ACK",
            timeout_s,
            lambda m: m.command == command and m.result != mavlink2.MAV_RESULT_IN_PROGRESS,
            since_s=since,
        )
        return int(rec.msg.result)

    def set_message_interval(self, msg_type: str | int, rate_hz: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL on the ground-station link (0 Hz: off); the result."""
        interval_us = -1.0 if rate_hz <= 0 else 1e6 / rate_hz
        return self.command_long(
            mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, _msg_id(msg_type), interval_us
        )

    def _param_values(
        self, name: str, target_component: int, timeout_s: float, request: Callable[[], Any]
    ) -> Iterator[Received]:
        """Sends ``request()`` (a PARAM_SET or PARAM_REQUEST_READ message) and yields the
        PARAM_VALUE of ``name`` from ``target_component`` that answers it; re-sends after
        a second without one, until ``timeout_s``. The caller stops when it is satisfied."""
        gcs = self.gcs
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            since = time.monotonic()
            gcs.send(request())
            try:
                rec = gcs.wait_message(
                    "PARAM_VALUE",
                    min(1.0, max(0.05, deadline - time.monotonic())),
                    lambda m: m.param_id == name,
                    since_s=since,
                    src=(1, target_component),
                )
            except SitlTimeout:
                continue
            yield rec

    def set_param(
        self, name: str, value: float, timeout_s: float = 5.0, target_component: int = 1
    ) -> float:
        """PARAM_SET to ``target_component`` of system 1 (the autopilot, or e.g. the companion
        at 191 through the autopilot's routing), re-sent every second until a PARAM_VALUE
        with the new value comes back; returns it. :class:`SitlError` if it keeps another
        value."""
        mav = self.gcs.mav
        last: Received | None = None
        for last in self._param_values(
            name,
            target_component,
            timeout_s,
            lambda: mav.param_set_encode(
                1, target_component, name.encode(), float(value), mavlink2.MAV_PARAM_TYPE_REAL32
            ),
        ):
            if math.isclose(last.msg.param_value, value, rel_tol=1e-6, abs_tol=1e-6):
                return float(last.msg.param_value)
        if last is not None:
            raise SitlError(f"{name} set to {value} but reads {last.msg.param_value}")
        raise SitlTimeout(f"no PARAM_VALUE for {name} (unknown parameter?)")

    def get_param(self, name: str, target_component: int = 1, timeout_s: float = 3.0) -> float:
        """PARAM_REQUEST_READ by name; the value of the PARAM_VALUE reply."""
        mav = self.gcs.mav
        for rec in self._param_values(
            name,
            target_component,
            timeout_s,
            lambda: mav.param_request_read_encode(1, target_component, name.encode(), -1),
        ):
            return float(rec.msg.param_value)
        raise SitlTimeout(f"no PARAM_VALUE for {name} from component {target_component}")

    def set_mode(self, mode: str | int, timeout_s: float = 5.0) -> None:
        """MAV_CMD_DO_SET_MODE (custom mode) and wait for a heartbeat in that mode."""
        number = mode_number(mode)
        result = self.command_long(
            mavlink2.MAV_CMD_DO_SET_MODE,
            mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            number,
            timeout_s=timeout_s,
        )
        if result != mavlink2.MAV_RESULT_ACCEPTED:
            raise SitlError(f"mode {mode_name(number)} refused (MAV_RESULT {result})")
        self.gcs.wait_for(lambda: self.gcs.mode == number, timeout_s, f"mode {mode_name(number)}")

    def arm(self, timeout_s: float = 20.0, force: bool = False) -> None:
        """Arm, retrying every second while pre-arm checks fail; SitlError with the last
        pre-arm texts on timeout."""
        since = time.monotonic()
        deadline = since + timeout_s
        while time.monotonic() < deadline:
            try:
                self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196 if force else 0)
            except SitlTimeout:
                pass
            try:
                self.gcs.wait_for(lambda: self.gcs.armed, 1.0, "armed")
                return
            except SitlTimeout:
                continue
        texts = [s.text for s in self.gcs.statustexts(since) if "arm" in s.text.lower()][-5:]
        raise SitlError(f"could not arm in {timeout_s:.0f} s: {texts}")

    def disarm(self, force: bool = False, timeout_s: float = 5.0) -> None:
        self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)
        self.gcs.wait_for(lambda: self.gcs.armed is False, timeout_s, "disarmed")

    def takeoff(self, alt_m: float, timeout_s: float = 30.0, tolerance_m: float = 0.5) -> None:
        """GUIDED, arm, MAV_CMD_NAV_TAKEOFF to ``alt_m`` above home; wait until within
        ``tolerance_m`` of it (LOCAL_POSITION_NED z, the EKF origin being home)."""
        self.set_mode("GUIDED")
        self.arm()
        result = self.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_m)
        if result != mavlink2.MAV_RESULT_ACCEPTED:
            raise SitlError(f"takeoff refused (MAV_RESULT {result})")

        def up() -> bool:
            lpn = self.local_position_ned()
            return lpn is not None and -lpn.z >= alt_m - tolerance_m

        self.gcs.wait_for(up, timeout_s, f"altitude {alt_m} m")

    def fly_velocity(
        self,
        vn_m_s: float,
        ve_m_s: float,
        vd_m_s: float,
        yaw_rad: float | None = None,
        rate_hz: float = 5.0,
    ) -> None:
        """Fly at this NED velocity in GUIDED (SET_POSITION_TARGET_LOCAL_NED, MAV_FRAME_LOCAL_NED,
        velocity only; heading ``yaw_rad`` if given). ArduCopter drops a velocity target after
        ~3 s, so it is re-sent at ``rate_hz`` until :meth:`stop_velocity` or another call."""
        gcs = self.gcs
        mask = _TYPEMASK_VELOCITY | (
            mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE if yaw_rad is None else 0
        )

        def target() -> Message:
            return gcs.mav.set_position_target_local_ned_encode(
                gcs.time_boot_ms(),
                1,
                1,
                mavlink2.MAV_FRAME_LOCAL_NED,
                mask,
                0.0,
                0.0,
                0.0,
                vn_m_s,
                ve_m_s,
                vd_m_s,
                0.0,
                0.0,
                0.0,
                0.0 if yaw_rad is None else yaw_rad,
                0.0,
            )

        gcs.set_periodic(self._velocity_key, rate_hz, target)

    def stop_velocity(self) -> None:
        """Stop re-sending the velocity set-point (GUIDED then holds after its ~3 s time-out)."""
        self.gcs.clear_periodic(self._velocity_key)

    def reboot(self, timeout_s: float | None = None) -> None:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (disarmed): the binary ``execv``\\ s itself with the
        same arguments; reconnect, wait for GPS again and return to real time."""
        gcs = self.gcs
        if self.real_time:
            self.set_param("SIM_SPEEDUP", self.speedup)
        disconnects = gcs.disconnects
        t_start = time.monotonic()
        result = self.command_long(mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
        if result != mavlink2.MAV_RESULT_ACCEPTED:
            raise SitlError(f"reboot refused (MAV_RESULT {result})")
        gcs.wait_for(
            lambda: self._check_alive() or gcs.disconnects > disconnects, 10.0, "the reboot"
        )
        t = time.monotonic()
        gcs.wait_for(lambda: self._check_alive() or gcs.connected, 10.0, "reconnection")
        timings = {"disconnect": t - t_start, "reconnect": time.monotonic() - t}
        t = time.monotonic()
        gcs.wait_message("HEARTBEAT", 15.0, since_s=t_start, src=(1, 1))
        timings["heartbeat"] = time.monotonic() - t
        if timeout_s is not None:
            self.boot_timeout_s = timeout_s
        self._streams_gps_real_time(timings, t_start, 0.0, " after the reboot")
