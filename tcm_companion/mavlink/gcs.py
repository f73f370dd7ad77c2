"""The ground-station side of a MAVLink link, sans-IO: what it heard, what it sends when.

:class:`GroundStation` frames with :class:`~.codec.MavlinkCodec` (MAVLink 2, our dialect,
which includes ardupilotmega) and records every received message with its receive time
(seconds on the caller's clock, the same clock every method here takes): the latest of
each type and sender, a bounded history, every STATUSTEXT as one whole text
(:class:`~.statustext.StatustextAssembler`), the target's (the autopilot's) heartbeats
and the changes of its flight mode. Periodic senders (its own HEARTBEAT, a velocity
set-point re-sent at 5 Hz, ...) are due at absolute times that do not drift:
:meth:`GroundStation.poll` returns the frames due now.

No sockets, threads or sleeps here (the SITL drivers run it on a transport in a thread:
:mod:`tcm_companion.sitl.gcs`). Every method takes :attr:`GroundStation.lock`, so an
adapter may query it from other threads; :attr:`GroundStation.changed` is notified after
each received batch.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from . import tcm_dialect as dialect
from .codec import MavlinkCodec
from .copter_modes import mode_name
from .statustext import StatustextAssembler

__all__ = [
    "GroundStation",
    "Heartbeat",
    "Message",
    "ModeChange",
    "Received",
    "StatusText",
    "message_id",
]

Message = Any  # a pymavlink MAVLink_message (pymavlink has no type stubs)


@dataclass(frozen=True, slots=True)
class Received:
    """A message and when it was received (s, the ground station's clock)."""

    t_s: float
    msg: Message


@dataclass(frozen=True, slots=True)
class StatusText:
    """One whole STATUSTEXT (chunks joined), at the receive time of its first chunk (s)."""

    t_s: float
    severity: int
    text: str
    src_system: int
    src_component: int


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """The target's HEARTBEAT at ``t_s`` (s): flight mode (``custom_mode``), armed flag."""

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


def message_id(msg_type: str | int) -> int:
    """The MAVLink message id of a name (``"LOCAL_POSITION_NED"``) or of an id."""
    if isinstance(msg_type, int):
        return msg_type
    value = getattr(dialect, f"MAVLINK_MSG_ID_{msg_type.upper()}", None)
    if value is None:
        raise ValueError(f"unknown MAVLink message {msg_type!r}")
    return int(value)


class _Periodic:
    __slots__ = ("due_s", "factory", "period_s")

    def __init__(self, period_s: float, factory: Callable[[], Message | None], due_s: float):
        self.period_s = period_s
        self.factory = factory
        self.due_s = due_s


class GroundStation:
    """A MAVLink 2 ground station as system ``source_system``/``source_component``.

    It sends its own HEARTBEAT (``heartbeat_type``, ``MAV_AUTOPILOT_INVALID``) at
    ``heartbeat_rate_hz`` unless ``heartbeat_type`` is None. ``target_system``/
    ``target_component`` (the autopilot, (1, 1)) are whose heartbeats feed
    :meth:`heartbeats`, :meth:`mode_changes`, :attr:`mode` and :attr:`armed`.
    ``now_s`` is the clock's time at creation (the first heartbeat is due then).
    """

    def __init__(
        self,
        *,
        source_system: int = 255,
        source_component: int = dialect.MAV_COMP_ID_MISSIONPLANNER,
        heartbeat_type: int | None = dialect.MAV_TYPE_GCS,
        heartbeat_rate_hz: float = 1.0,
        target_system: int = 1,
        target_component: int = 1,
        history: int = 50_000,
        now_s: float = 0.0,
    ) -> None:
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.target_component = target_component
        self.t0_s = now_s
        self.lock = threading.RLock()
        self.changed = threading.Condition(self.lock)
        self.codec = MavlinkCodec(source_system, source_component)
        self._history: deque[Received] = deque(maxlen=history)
        self._latest: dict[str, Received] = {}
        self._latest_by_source: dict[tuple[str, int, int], Received] = {}
        self._statustexts: list[StatusText] = []
        self._statustext_chunks = StatustextAssembler()
        self._heartbeats: deque[Heartbeat] = deque(maxlen=10_000)
        self._mode_changes: list[ModeChange] = []
        self._counts: dict[str, int] = {}
        self._periodic: dict[str, _Periodic] = {}
        if heartbeat_type is not None:
            hb = self.mav.heartbeat_encode(
                heartbeat_type, dialect.MAV_AUTOPILOT_INVALID, 0, 0, dialect.MAV_STATE_ACTIVE
            )
            self.set_periodic("heartbeat", heartbeat_rate_hz, lambda: hb, now_s)

    # -- sending ---------------------------------------------------------------------------

    @property
    def mav(self) -> Any:
        """The pymavlink ``MAVLink`` object, for ``*_encode``; frame with :meth:`encode`."""
        return self.codec.mav

    def encode(self, msg: Message) -> bytes:
        """One message built with ``mav.<name>_encode(...)`` as a frame (the next sequence
        number)."""
        with self.lock:
            return self.codec.encode(msg)

    def set_periodic(
        self,
        key: str,
        rate_hz: float,
        factory: Callable[[], Message | None],
        first_s: float | None = None,
    ) -> None:
        """Send ``factory()`` (skipped when None) at ``rate_hz``, the first one due at
        ``first_s`` (None: at the next :meth:`poll`), until :meth:`clear_periodic` (a new
        ``factory`` for ``key`` replaces it)."""
        if rate_hz <= 0:
            raise ValueError("rate_hz must be positive")
        due_s = -math.inf if first_s is None else first_s
        with self.lock:
            self._periodic[key] = _Periodic(1.0 / rate_hz, factory, due_s)

    def clear_periodic(self, key: str) -> None:
        with self.lock:
            self._periodic.pop(key, None)

    def next_deadline_s(self, now_s: float, max_wait_s: float = 0.05) -> float:
        """When :meth:`poll` has something to send next (at most ``max_wait_s`` from now)."""
        with self.lock:
            due = min((p.due_s for p in self._periodic.values()), default=now_s + max_wait_s)
        return min(due, now_s + max_wait_s)

    def poll(self, now_s: float) -> list[bytes]:
        """The frames of the periodic senders due at ``now_s``."""
        with self.lock:
            periodics = list(self._periodic.values())
        out = []
        for periodic in periodics:
            if periodic.due_s <= now_s:
                # no drift, but no burst after a stall either
                periodic.due_s = max(periodic.due_s + periodic.period_s, now_s)
                msg = periodic.factory()
                if msg is not None:
                    out.append(self.encode(msg))
        return out

    def time_boot_ms(self, now_s: float) -> int:
        """Milliseconds since this ground station started (our messages' ``time_boot_ms``)."""
        return int((now_s - self.t0_s) * 1000) & 0xFFFFFFFF

    # -- receiving -------------------------------------------------------------------------

    def receive_data(self, data: bytes, t_s: float) -> list[Message]:
        """Take bytes received at ``t_s``; record and return the messages they complete."""
        with self.changed:
            msgs = self.codec.feed(data)
            self._record(t_s, msgs)
            self.changed.notify_all()
        return msgs

    @property
    def bad_data(self) -> int:
        """Received bytes or frames that were no message of ours (garbage, CRC, unknown)."""
        with self.lock:
            stats = self.codec.stats
            return sum(n for k, n in stats.items() if k not in ("bytes", "received", "sent"))

    def _record(self, t_s: float, msgs: Iterable[Message]) -> None:
        for msg in msgs:
            mtype = msg.get_type()
            rec = Received(t_s, msg)
            self._history.append(rec)
            self._latest[mtype] = rec
            src = (mtype, msg.get_srcSystem(), msg.get_srcComponent())
            self._latest_by_source[src] = rec
            self._counts[mtype] = self._counts.get(mtype, 0) + 1
            if mtype == "STATUSTEXT":
                whole = self._statustext_chunks.add(msg, t_s)
                if whole is not None:
                    self._statustexts.append(
                        StatusText(whole[0], msg.severity, whole[1], src[1], src[2])
                    )
            elif mtype == "HEARTBEAT" and src[1:] == (self.target_system, self.target_component):
                hb = Heartbeat(
                    t_s,
                    msg.custom_mode,
                    bool(msg.base_mode & dialect.MAV_MODE_FLAG_SAFETY_ARMED),
                    msg.system_status,
                )
                previous = self._mode_changes[-1].mode if self._mode_changes else None
                if previous != hb.custom_mode:
                    self._mode_changes.append(ModeChange(t_s, hb.custom_mode, previous))
                self._heartbeats.append(hb)

    # -- what was heard --------------------------------------------------------------------

    def latest(self, msg_type: str, src: tuple[int, int] | None = None) -> Received | None:
        """The last message of a type (from ``src`` = (sysid, compid) if given)."""
        with self.lock:
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
        ``since_s``, from ``src``."""
        with self.lock:
            out = list(self._history)
        return [
            r
            for r in out
            if (msg_type is None or r.msg.get_type() == msg_type)
            and (since_s is None or r.t_s >= since_s)
            and (src is None or (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == src)
        ]

    def first_message(
        self,
        msg_type: str,
        since_s: float,
        predicate: Callable[[Message], bool] | None = None,
        src: tuple[int, int] | None = None,
    ) -> Received | None:
        """The first message of a type received at/after ``since_s`` from ``src`` that
        satisfies ``predicate``; None if none has come yet."""
        found = None
        with self.lock:
            for rec in reversed(self._history):  # newest first, back to ``since``
                if rec.t_s < since_s:
                    break
                msg = rec.msg
                if msg.get_type() != msg_type:
                    continue
                if src is not None and (msg.get_srcSystem(), msg.get_srcComponent()) != src:
                    continue
                if predicate is None or predicate(msg):
                    found = rec
        return found

    def count(self, msg_type: str) -> int:
        with self.lock:
            return self._counts.get(msg_type, 0)

    def statustexts(self, since_s: float | None = None) -> list[StatusText]:
        with self.lock:
            return [s for s in self._statustexts if since_s is None or s.t_s >= since_s]

    def heartbeats(self) -> list[Heartbeat]:
        """The target's (autopilot's) heartbeats, oldest first."""
        with self.lock:
            return list(self._heartbeats)

    def heartbeat_sources(self) -> dict[tuple[int, int], Received]:
        """The last HEARTBEAT from each (sysid, compid) seen on this link."""
        with self.lock:
            return {
                (k[1], k[2]): v for k, v in self._latest_by_source.items() if k[0] == "HEARTBEAT"
            }

    def mode_changes(self) -> list[ModeChange]:
        with self.lock:
            return list(self._mode_changes)

    @property
    def mode(self) -> int | None:
        """The target's custom_mode in its last heartbeat."""
        with self.lock:
            return self._heartbeats[-1].custom_mode if self._heartbeats else None

    @property
    def armed(self) -> bool | None:
        with self.lock:
            return self._heartbeats[-1].armed if self._heartbeats else None

    def autopilot_boot_ms(self, now_s: float) -> int | None:
        """The autopilot's ``time_boot_ms`` at ``now_s``, from its latest time-stamped message
        (ATTITUDE, LOCAL_POSITION_NED, SYSTEM_TIME ...) plus the time since it came."""
        best: Received | None = None
        with self.lock:
            for kind in ("ATTITUDE", "LOCAL_POSITION_NED", "SYSTEM_TIME", "GLOBAL_POSITION_INT"):
                rec = self._latest_by_source.get((kind, self.target_system, self.target_component))
                if rec is not None and (best is None or rec.t_s > best.t_s):
                    best = rec
        if best is None:
            return None
        return int(best.msg.time_boot_ms + (now_s - best.t_s) * 1000.0)
