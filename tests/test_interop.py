"""Interop with MAVLink peers we did not write (issue 3): our :class:`CompanionLink` on real
transports against MAVProxy (a ground station) and MAVSDK 4 (``mavlink_direct``).

What is checked against what we sent (every message our link sends is decoded on the way
out with our dialect, so "what we sent" is the bytes, not our intentions):

- **MAVProxy** (its own venv, ``tools/interop_env.py``; ``--dialect=tcm``, daemon,
  non-interactive) on ``udpin``, our link on ``udpout``. The ``.tlog`` it records
  decodes with our dialect and holds our TCM_OBJECT_STATUS and TCM_PIPELINE_HEALTH with
  the field values we sent; pymavlink's ``mavlogdump.py --dialect=tcm`` in that venv
  decodes them too; MAVProxy's own ``status`` command shows TCM_OBJECT_STATUS (so it
  decoded them itself, not just logged bytes). It reads our parameters (all 14, saved
  to its ``mav_1_191.parm``) and sets ``TCM_THRESH`` = 0.12 on component 191: our
  endpoint reports ``ParamChanged``, MAVProxy's log holds our PARAM_VALUE with the new
  value, and the statuses we send afterwards carry the new threshold. Run twice: our
  link alone on MAVProxy's port, and with the mock autopilot, both behind a frame router
  in the test (as an autopilot forwards its companion's messages to the GCS): MAVProxy
  then detects vehicle 1:1 and component 1:191, and the time stamps of our statuses in
  its log agree with the vehicle's ATTITUDE boot time (TIMESYNC through the router).
- **MAVSDK 4** over UDP and over a socat pty pair at 921600 baud: it discovers system 1
  with our component 191 (not an autopilot), its ``mavlink_direct`` plugin loads our
  ``tcm.xml`` with ``load_custom_xml`` and delivers our HEARTBEAT and TCM_OBJECT_STATUS
  with the values we sent (a NaN float arrives as JSON ``null``).

Notes from making these run (details in the test bodies):

- MAVProxy needs no autopilot on the link: it adopts our component as the target
  (``--target-system=1 --target-component=191``) and fetches our parameters.
- MAVProxy first asks for parameters over MAVLink FTP (``@PARAM/param.pck``); our
  endpoint NAKs every FTP request at once, so stock MAVProxy falls back to
  PARAM_REQUEST_LIST without waiting out its ~11 s time-out (the test relies on it).
- In daemon mode MAVProxy reads no stdin, and ``param set`` refuses a parameter it has
  not fetched yet, so the set is a start-up command repeated every second (``repeat add
  1 param set ...``) until the fetched list makes it valid.

Skips: only when a peer cannot run here — MAVSDK's bundled C library does not load on
this platform, socat is missing (pty case), or the MAVProxy venv cannot be built
(no access to PyPI). Under CI (``CI`` set) a missing MAVProxy venv or mavsdk package
fails instead: ``.ci/run`` builds the venv before ``make test``.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import importlib.util
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from tcm_companion.core.classify import Classification
from tcm_companion.core.frames import bearing_from_azel
from tcm_companion.core.pipeline import FrameResult, ObjectResult
from tcm_companion.io.aio import monotonic_us
from tcm_companion.io.transports import (
    Transport,
    TransportClosed,
    TransportError,
    memory_pair,
    open_transport,
)
from tcm_companion.io.transports.socat import SocatPtyPair, socat_available
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.endpoint import CompanionEndpoint, Event, ParamChanged
from tcm_companion.mavlink.params import PARAMS
from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig
from tcm_companion.sim.vehicle.mock_autopilot import ParamChanged as MockParamChanged
from tcm_companion.sim.vehicle.mock_autopilot_run import run_mock_autopilot

from .mavlink_link import CompanionLink

ROOT = Path(__file__).resolve().parents[1]
XML = ROOT / "tcm_companion" / "mavlink" / "tcm.xml"
OUR_COMPONENT = 191
OUR_SYSTEM = 1  # the endpoint's default until an autopilot tells it otherwise
NEW_THRESHOLD = 0.12
CI = bool(os.environ.get("CI"))


# -- what we send ---------------------------------------------------------------------------
def _object(
    track_id: int,
    az_el_deg: tuple[float, float],
    angular_radius_rad: float,
    centroid_px: tuple[float, float],
    classification: Classification,
    ttc_s: float,
    miss_radii: float,
) -> ObjectResult:
    """A detected object seen along ``az_el_deg`` (body = camera = NED here)."""
    b = bearing_from_azel(np.radians(np.array(az_el_deg[0])), np.radians(np.array(az_el_deg[1])))
    return ObjectResult(
        track_id=track_id,
        detected=True,
        state=classification.state,
        reason="",
        bearing_cam=b,
        bearing_body=b,
        bearing_ned=b,
        azimuth_ned_rad=0.0,
        elevation_ned_rad=0.0,
        angular_radius_rad=angular_radius_rad,
        centroid_px=centroid_px,
        classification=classification,
        ttc_s=ttc_s,
        collision_course=math.isfinite(ttc_s),
        miss_radii=miss_radii,
    )


def _frame(t_us: int) -> FrameResult:
    """Two objects that exercise most fields: a mover on a collision course (range from the
    configured object radius) and a stationary object with a range and no TTC (NaN)."""
    mover = _object(
        7, (5.0, -3.0), 0.087, (320.0, 240.0), Classification("moving", "", disparity=0.4), 2.5, 0.5
    )
    still = _object(
        12,
        (-20.0, 10.0),
        0.05,
        (100.0, 80.0),
        Classification("stationary", "", disparity=0.02, range_m=8.25),
        math.nan,
        math.nan,
    )
    return FrameResult(0, t_us, (mover, still), True, None, {})


def _check_semantics(by_track: dict[int, dict[str, Any]]) -> None:
    """The values a peer decoded mean what the frame said (NaN may arrive as None)."""
    mover, still = by_track[7], by_track[12]
    assert mover["state"] == d.TCM_OBJECT_STATE_MOVING
    assert mover["collision_course"] == 1
    assert math.isclose(mover["ttc"], 2.5)
    assert math.isclose(mover["azimuth"], math.radians(5.0), rel_tol=1e-6)
    assert math.isclose(mover["elevation"], math.radians(-3.0), rel_tol=1e-6)
    assert math.isclose(mover["disparity"], 0.4, rel_tol=1e-6)
    assert math.isclose(mover["range"], 0.375 / math.sin(0.087), rel_tol=1e-6)
    assert still["state"] == d.TCM_OBJECT_STATE_STATIONARY
    assert still["collision_course"] == 0
    assert still["ttc"] is None or math.isnan(still["ttc"])
    assert math.isclose(still["range"], 8.25)
    assert math.isclose(still["azimuth"], math.radians(-20.0), rel_tol=1e-6)


class RecordingTransport:
    """Passes bytes through and decodes what our link sends with our dialect."""

    def __init__(self, inner: Transport) -> None:
        self.inner = inner
        self._parser = d.MAVLink(None)
        self.sent: list[Any] = []

    async def send(self, data: bytes) -> None:
        await self.inner.send(data)
        self.sent += self._parser.parse_buffer(data) or []

    async def recv(self) -> bytes:
        return await self.inner.recv()

    def of_type(self, kind: str, since: int = 0) -> list[Any]:
        return [m for m in self.sent[since:] if m.get_type() == kind]


def _fields(msg: Any) -> dict[str, Any]:
    return {k: v for k, v in msg.to_dict().items() if k != "mavpackettype"}


def _same(a: Any, b: Any) -> bool:
    """Equal as MAVLink fields: floats to float32 precision, NaN equal to NaN or None."""
    if isinstance(a, float) and math.isnan(a):
        return b is None or (isinstance(b, float) and math.isnan(b))
    if isinstance(a, float) or isinstance(b, float):
        return b is not None and math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)
    return bool(a == b)


def _matches_one_of(got: dict[str, Any], sent: list[dict[str, Any]]) -> bool:
    return any(all(_same(s[k], got.get(k)) for k in s) for s in sent)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _until(
    condition: Callable[[], bool], timeout_s: float, what: str, alive: Callable[[], None]
) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        alive()
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        await asyncio.sleep(0.05)


# -- MAVProxy -------------------------------------------------------------------------------
@functools.cache
def _interop_tool() -> ModuleType:
    path = ROOT / "tools" / "interop_env.py"
    spec = importlib.util.spec_from_file_location("tcm_interop_env", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def interop_env() -> Any:
    tool = _interop_tool()
    try:
        return tool.ensure()
    except tool.InteropEnvError as exc:
        message = f"the MAVProxy venv (tools/interop_env.py) cannot be built here: {exc}"
        if CI:
            pytest.fail(message)
        pytest.skip(message)


@contextlib.contextmanager
def _process_group(
    cmd: list[str], log_path: Path, cwd: Path, env: dict[str, str]
) -> Iterator[subprocess.Popen[bytes]]:
    """A subprocess in its own session; on exit SIGTERM to its group, SIGKILL if needed."""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            cmd,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        yield proc
    finally:
        _stop_group(proc)


def _stop_group(proc: subprocess.Popen[bytes], grace_s: float = 10.0) -> None:
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)  # MAVProxy: clean shutdown in daemon mode
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # anything it left behind in its group


def _frame_length(buf: bytes | bytearray, pos: int) -> int | None:
    """Length of the MAVLink frame at ``pos`` (None: not a frame start, or too short)."""
    if len(buf) - pos < 3:
        return None
    if buf[pos] == 0xFD:
        return 12 + buf[pos + 1] + (13 if buf[pos + 2] & 0x01 else 0)
    if buf[pos] == 0xFE:
        return 8 + buf[pos + 1]
    return None


def _take_frames(buf: bytearray) -> list[bytes]:
    """Whole frames from the front of a byte stream (removed from ``buf``)."""
    frames = []
    while buf:
        if buf[0] not in (0xFD, 0xFE):
            del buf[0]  # resynchronise on the next magic byte
            continue
        n = _frame_length(buf, 0)
        if n is None or len(buf) < n:
            break
        frames.append(bytes(buf[:n]))
        del buf[:n]
    return frames


def _tlog_messages(path: Path) -> list[Any]:
    """Every record of a .tlog (8-byte timestamp + one frame), decoded with our dialect. A
    frame that does not decode fails the test; a record still being written ends it."""
    data = path.read_bytes() if path.exists() else b""
    parser = d.MAVLink(None)
    out, pos = [], 0
    while pos + 8 + 3 <= len(data):
        n = _frame_length(data, pos + 8)
        if n is None:
            raise AssertionError(f"{path}: no MAVLink frame at byte {pos + 8}")
        frame = data[pos + 8 : pos + 8 + n]
        if len(frame) < n:
            break
        out.append(parser.decode(bytearray(frame)))
        pos += 8 + n
    return out


def _from_us(msg: Any) -> bool:
    return (msg.get_srcSystem(), msg.get_srcComponent()) == (OUR_SYSTEM, OUR_COMPONENT)


def _param_id(msg: Any) -> str:
    raw = msg.param_id
    return (raw.decode() if isinstance(raw, bytes) else str(raw)).split("\x00", 1)[0]


@dataclass
class _MavproxyRun:
    events: list[Event]  # what our endpoint reported
    sent: list[Any]  # every message our link sent, decoded
    ready_index: int  # sent[ready_index:] went out once MAVProxy was listening
    mock: MockAutopilot | None
    mock_param_changes: list[MockParamChanged]


@pytest.mark.slow  # a subprocess (MAVProxy)
@pytest.mark.parametrize("vehicle", [False, True], ids=["companion-only", "with-vehicle"])
def test_mavproxy_records_our_messages_and_sets_our_parameter(
    interop_env: Any, tmp_path: Path, vehicle: bool
) -> None:
    """companion-only: our link straight to MAVProxy. with-vehicle: the mock autopilot and
    our companion behind a frame router, as a GCS sees them through an autopilot that
    routes its companion's messages (so MAVProxy has a vehicle and our time stamps are
    in its boot time)."""
    port = _free_udp_port()
    tlog = tmp_path / "flight.tlog"
    out = tmp_path / "mavproxy.out"
    startup = ";".join(
        [
            "set flushlogs 1",  # the tlog is complete on disk while MAVProxy runs
            f"repeat add 1 param set TCM_THRESH {NEW_THRESHOLD}",
            "repeat add 1 status TCM_OBJECT_STATUS",
        ]
    )
    cmd = [
        str(interop_env.python),
        str(interop_env.mavproxy),
        f"--master=udpin:127.0.0.1:{port}",
        "--dialect=tcm",
        "--daemon",
        "--non-interactive",
        f"--logfile={tlog}",
        f"--target-system={OUR_SYSTEM}",
        f"--target-component={OUR_COMPONENT}",  # MAVProxy's commands address us
        f"--cmd={startup}",
    ]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # HOME: keep a developer's ~/.mavinit.scr and ~/.mavproxy out of the test.
    env.update(HOME=str(tmp_path), MAVLINK20="1", PYTHONUNBUFFERED="1")

    with _process_group(cmd, out, tmp_path, env) as proc:

        def alive() -> None:
            if proc.poll() is not None:
                raise AssertionError(
                    f"MAVProxy exited ({proc.returncode}):\n{out.read_text(errors='replace')}"
                )

        run = asyncio.run(_drive_mavproxy(port, alive, tlog, vehicle))
        mavproxy_out = out.read_text(errors="replace")
    records = _tlog_messages(tlog)

    # Our endpoint saw MAVProxy's PARAM_SET and applied it.
    changes = [e for e in run.events if isinstance(e, ParamChanged)]
    assert [c.name for c in changes] == ["TCM_THRESH"], mavproxy_out
    assert math.isclose(changes[0].value, NEW_THRESHOLD, rel_tol=1e-6)

    # MAVProxy read our parameter list: every parameter logged, and saved to its file.
    ours = [m for m in records if _from_us(m)]
    names = {_param_id(m) for m in ours if m.get_type() == "PARAM_VALUE"}
    assert names == {p.name for p in PARAMS}
    assert f"Received {len(PARAMS)} parameters" in mavproxy_out
    parm = (tmp_path / f"mav_{OUR_SYSTEM}_{OUR_COMPONENT}.parm").read_text()
    assert all(p.name in parm for p in PARAMS)
    # ... and set one on our component; we answered with the new value.
    sets = [
        m
        for m in records
        if m.get_type() == "PARAM_SET"
        and (m.target_system, m.target_component) == (OUR_SYSTEM, OUR_COMPONENT)
    ]
    assert sets and all(_param_id(m) == "TCM_THRESH" for m in sets)
    assert any(
        m.get_type() == "PARAM_VALUE"
        and _param_id(m) == "TCM_THRESH"
        and math.isclose(m.param_value, NEW_THRESHOLD, rel_tol=1e-6)
        for m in ours
    )

    # Our messages, as recorded by MAVProxy, carry the values we sent.
    for kind in ("TCM_OBJECT_STATUS", "TCM_PIPELINE_HEALTH"):
        sent_fields = [_fields(m) for m in run.sent if m.get_type() == kind]
        recorded = [_fields(m) for m in ours if m.get_type() == kind]
        assert recorded, f"no {kind} in {tlog}"
        bad = [r for r in recorded if not _matches_one_of(r, sent_fields)]
        assert not bad, f"{kind} recorded with values we never sent: {bad[:3]}"
    after_ready = [m for m in run.sent[run.ready_index :] if m.get_type() == "TCM_OBJECT_STATUS"]
    statuses = [m for m in ours if m.get_type() == "TCM_OBJECT_STATUS"]
    assert len(statuses) >= len(after_ready) // 2, (len(statuses), len(after_ready))
    new = [m for m in statuses if math.isclose(m.threshold, NEW_THRESHOLD, rel_tol=1e-6)]
    assert {m.track_id for m in new} == {7, 12}  # the threshold in force changed
    _check_semantics({m.track_id: _fields(m) for m in new})

    # pymavlink's own tool in MAVProxy's venv decodes them with the installed dialect.
    dump = subprocess.run(
        [
            str(interop_env.python),
            str(interop_env.mavlogdump),
            "--dialect=tcm",
            "--types=TCM_OBJECT_STATUS,TCM_PIPELINE_HEALTH",
            "--format=json",
            str(tlog),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=True,
    )
    dumped = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
    assert {r["meta"]["type"] for r in dumped} == {"TCM_OBJECT_STATUS", "TCM_PIPELINE_HEALTH"}
    assert sum(r["meta"]["type"] == "TCM_OBJECT_STATUS" for r in dumped) == len(statuses)
    # MAVProxy decoded them itself (its `status` command lists them by name and value;
    # with another --dialect the .tlog still holds the bytes, but this line is missing).
    assert re.search(r"TCM_OBJECT_STATUS \{.*track_id : (7|12),", mavproxy_out), mavproxy_out
    # Our collision-course STATUSTEXT reached the ground station's console.
    assert "TCM: collision course track 7" in mavproxy_out

    if vehicle:
        assert f"Detected vehicle {OUR_SYSTEM}:1 on link" in mavproxy_out
        assert f"Detected vehicle {OUR_SYSTEM}:{OUR_COMPONENT} on link" in mavproxy_out
        # As the GCS sees them, our time stamps are in the vehicle's boot time: each
        # status lies within a few ATTITUDE periods of the vehicle's latest ATTITUDE.
        last_attitude_ms, checked = None, 0
        for m in records:
            if m.get_type() == "ATTITUDE" and m.get_srcComponent() == 1:
                last_attitude_ms = m.time_boot_ms
            elif m.get_type() == "TCM_OBJECT_STATUS" and _from_us(m):
                if last_attitude_ms is not None:
                    assert abs(m.time_boot_ms - last_attitude_ms) < 250, (m, last_attitude_ms)
                    checked += 1
        assert checked >= len(statuses) // 2, (checked, len(statuses))
        # The PARAM_SET was for us: the autopilot's parameters are untouched.
        assert run.mock is not None and not run.mock_param_changes


class FrameHub:
    """Routes whole MAVLink frames between links, flooding, as an autopilot forwards its
    companion's messages to the GCS link and the GCS's to its companion."""

    def __init__(self, ports: list[Transport]) -> None:
        self.ports = ports
        self.frames = 0

    async def run(self) -> None:
        await asyncio.gather(*(self._pump(p) for p in self.ports))

    async def _pump(self, port: Transport) -> None:
        buf = bytearray()
        while True:
            try:
                buf += await port.recv()
            except TransportClosed:
                return
            for frame in _take_frames(buf):
                self.frames += 1
                for other in self.ports:
                    if other is not port:
                        with contextlib.suppress(TransportError):
                            await other.send(frame)


async def _drive_mavproxy(
    port: int, alive: Callable[[], None], tlog: Path, vehicle: bool
) -> _MavproxyRun:
    mavproxy_side = open_transport(f"udpout:127.0.0.1:{port}")
    await mavproxy_side.open()
    background: list[asyncio.Task[Any]] = []
    mock_task: asyncio.Task[MockAutopilot] | None = None
    stop_mock = asyncio.Event()
    mock_params: list[MockParamChanged] = []
    if vehicle:
        companion_side, hub_companion = memory_pair()
        mock_side, hub_mock = memory_pair()
        background.append(
            asyncio.create_task(FrameHub([hub_companion, hub_mock, mavproxy_side]).run())
        )
        # Up for 10 min: its boot time is nowhere near our clock or zero.
        config = MockAutopilotConfig(ekf_origin_delay_us=0, boot_offset_us=600_000_000)
        mock_task = asyncio.create_task(
            run_mock_autopilot(
                mock_side,
                config,
                stop_mock,
                on_event=lambda e: (
                    mock_params.append(e) if isinstance(e, MockParamChanged) else None
                ),
            )
        )
        transport: Transport = companion_side
    else:
        transport = mavproxy_side
    rec = RecordingTransport(transport)
    events: list[Event] = []
    endpoint = CompanionEndpoint(now_us=monotonic_us())
    link = CompanionLink(rec, endpoint, on_event=events.append)  # type: ignore[arg-type]
    link_task = asyncio.create_task(link.run())

    def ready() -> bool:
        # MAVProxy answers (heartbeats, PARAM_REQUEST_LIST) once it hears a heartbeat;
        # what went out before it was listening hit a closed port. With a vehicle, we
        # also wait for TIMESYNC, so that our time stamps are the vehicle's boot time.
        heard = mavproxy_side.stats["datagrams_in"] > 0
        return heard and (
            not vehicle or (endpoint.autopilot_connected and endpoint.timesync.synced)
        )

    def changed() -> bool:
        return any(isinstance(e, ParamChanged) for e in events)

    def logged() -> bool:
        recs = _tlog_messages(tlog)
        return any(
            r.get_type() == "TCM_OBJECT_STATUS"
            and math.isclose(r.threshold, NEW_THRESHOLD, rel_tol=1e-6)
            for r in recs
        ) and any(r.get_type() == "TCM_PIPELINE_HEALTH" for r in recs)

    mock = None
    try:
        await _until(ready, 30, "MAVProxy (and the vehicle's TIMESYNC)", alive)
        ready_index = len(rec.sent)
        deadline = time.monotonic() + 30
        while not changed():
            alive()
            assert time.monotonic() < deadline, "MAVProxy never set TCM_THRESH"
            link.send_frame(_frame(link.now_us()))
            await asyncio.sleep(0.1)
        for _ in range(5):  # statuses with the new threshold
            link.send_frame(_frame(link.now_us()))
            await asyncio.sleep(0.1)
        await asyncio.sleep(0.6)  # a TCM_PIPELINE_HEALTH (2 Hz) after the change
        await _until(logged, 10, "MAVProxy's tlog to hold our messages", alive)
    finally:
        link.stop()
        await link_task
        stop_mock.set()
        if mock_task is not None:
            mock = await mock_task
        for task in background:
            if not task.done():
                task.cancel()
        await asyncio.gather(*background, return_exceptions=True)
        await mavproxy_side.close()
        await transport.close()
    return _MavproxyRun(events, rec.sent, ready_index, mock, mock_params)


# -- MAVSDK ---------------------------------------------------------------------------------
def _import_mavsdk() -> tuple[Any, Any]:
    try:
        import mavsdk.asyncio as mavsdk_asyncio
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
    except ModuleNotFoundError as exc:
        message = f"mavsdk is not installed (pip install -e '.[dev]'): {exc}"
        if CI:
            pytest.fail(message)
        pytest.skip(message)
    except Exception as exc:  # LibraryNotFoundError, OSError: no libcmavsdk for this platform
        pytest.skip(f"MAVSDK's bundled C library does not load on this platform: {exc}")
    return mavsdk_asyncio, MavlinkDirectAsync


@pytest.mark.slow  # real transports, socat's pty pair
@pytest.mark.parametrize("link_kind", ["udp", "serial"])
def test_mavsdk_sees_our_component_and_decodes_our_status(link_kind: str) -> None:
    mavsdk_asyncio, direct_cls = _import_mavsdk()
    if link_kind == "udp":
        port = _free_udp_port()
        # MAVSDK 4 URLs: udpin://HOST:PORT listens (udp://:PORT is the old spelling).
        result = asyncio.run(
            _drive_mavsdk(
                mavsdk_asyncio, direct_cls, f"udpin://127.0.0.1:{port}", f"udpout:127.0.0.1:{port}"
            )
        )
    else:
        if not socat_available():
            pytest.skip("socat is not installed (apt-get install socat): no pty pair")
        with SocatPtyPair(baud=921600) as pair:
            result = asyncio.run(
                _drive_mavsdk(
                    mavsdk_asyncio,
                    direct_cls,
                    f"serial://{pair.paths[1]}:921600",
                    f"serial:{pair.paths[0]}:921600",
                )
            )
    system_id, component_ids, has_autopilot, heartbeats, statuses, sent = result

    assert system_id == OUR_SYSTEM
    assert OUR_COMPONENT in component_ids
    assert not has_autopilot  # we are a companion component, not a vehicle
    hb = json.loads(heartbeats[0].fields_json)
    assert (heartbeats[0].system_id, heartbeats[0].component_id) == (OUR_SYSTEM, OUR_COMPONENT)
    assert hb["type"] == d.MAV_TYPE_ONBOARD_CONTROLLER
    assert hb["autopilot"] == d.MAV_AUTOPILOT_INVALID

    sent_fields = [_fields(m) for m in sent if m.get_type() == "TCM_OBJECT_STATUS"]
    by_track: dict[int, dict[str, Any]] = {}
    for msg in statuses:
        assert (msg.system_id, msg.component_id) == (OUR_SYSTEM, OUR_COMPONENT)
        got = json.loads(msg.fields_json)
        assert got["message_id"] == d.MAVLINK_MSG_ID_TCM_OBJECT_STATUS
        assert _matches_one_of(got, sent_fields), f"MAVSDK decoded values we never sent: {got}"
        by_track[got["track_id"]] = got
    assert set(by_track) == {7, 12}
    assert by_track[12]["ttc"] is None  # NaN travels; MAVSDK's JSON renders it as null
    _check_semantics(by_track)


async def _drive_mavsdk(
    mavsdk_asyncio: Any, direct_cls: Any, mavsdk_url: str, our_url: str
) -> tuple[int, list[int], bool, list[Any], list[Any], list[Any]]:
    config = mavsdk_asyncio.Configuration.create_with_component_type(
        mavsdk_asyncio.ComponentType.GROUND_STATION
    )
    async with mavsdk_asyncio.Mavsdk(config) as mavsdk:
        await mavsdk.add_any_connection(mavsdk_url)
        transport = open_transport(our_url)
        await transport.open()
        rec = RecordingTransport(transport)
        endpoint = CompanionEndpoint(now_us=monotonic_us())
        link = CompanionLink(rec, endpoint)  # type: ignore[arg-type]
        task = asyncio.create_task(link.run())
        collectors: list[asyncio.Task[None]] = []
        try:
            system = None
            deadline = time.monotonic() + 20
            while system is None:
                assert time.monotonic() < deadline, "MAVSDK discovered no system"
                for candidate in await mavsdk.get_systems():
                    if OUR_COMPONENT in await candidate.component_ids():
                        system = candidate
                await asyncio.sleep(0.05)
            system_id = await system.get_system_id()
            component_ids = await system.component_ids()
            has_autopilot = await system.has_autopilot()

            direct = direct_cls(system)
            await direct.load_custom_xml(XML.read_text())  # raises MavlinkDirectError if refused
            heartbeats: list[Any] = []
            statuses: list[Any] = []

            async def collect(name: str, sink: list[Any]) -> None:
                async for msg in direct.subscribe_message(name):
                    if msg.component_id == OUR_COMPONENT:
                        sink.append(msg)

            collectors = [
                asyncio.create_task(collect("HEARTBEAT", heartbeats)),
                asyncio.create_task(collect("TCM_OBJECT_STATUS", statuses)),
            ]

            def done() -> bool:
                tracks = [json.loads(m.fields_json).get("track_id") for m in statuses]
                return bool(heartbeats) and tracks.count(7) >= 2 and tracks.count(12) >= 2

            deadline = time.monotonic() + 20
            while not done():
                assert time.monotonic() < deadline, (
                    f"MAVSDK delivered {len(heartbeats)} heartbeats, {len(statuses)} statuses"
                )
                link.send_frame(_frame(link.now_us()))
                await asyncio.sleep(0.1)
        finally:
            for c in collectors:
                c.cancel()
            await asyncio.gather(*collectors, return_exceptions=True)
            link.stop()
            await task
            await transport.close()
    return system_id, component_ids, has_autopilot, heartbeats, statuses, rec.sent


def test_frame_helper_is_what_the_endpoint_encodes() -> None:
    """The reference the interop tests compare against: our own decode of our bytes."""
    endpoint = CompanionEndpoint(now_us=0)
    endpoint.send_frame(_frame(0), 0)
    msgs: list[Any] = d.MAVLink(None).parse_buffer(endpoint.data_to_send()) or []
    by_track = {m.track_id: _fields(m) for m in msgs if m.get_type() == "TCM_OBJECT_STATUS"}
    assert set(by_track) == {7, 12}
    _check_semantics(by_track)
    assert np.isnan(by_track[12]["ttc"])
