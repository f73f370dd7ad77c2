"""What several test modules share (``from .helpers import ...``); conftest.py keeps only
fixtures and hooks.

- The independent example scenarios: the three examples of shared/examples (rendered by
  code outside this project) are vendored under tests/data/examples so that CI checks our
  reader against them too.
- :func:`decode`: the MAVLink messages in bytes the companion sent.
- :func:`simulated_flight` and two drivers that feed a
  :class:`~tcm_companion.service.companion.Companion` through its surface only, the way the
  daemon does, on a fake clock (µs, the companion's monotonic clock), in time order:
  :class:`Driver` (telemetry and frames; tests/test_companion.py) and :class:`FedDriver`
  (the same with a live box feed; tests/test_box_feed.py).
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tcm_companion.core.camera import Equirectangular
from tcm_companion.core.detection import DetectionConfig
from tcm_companion.core.pipeline import PipelineConfig
from tcm_companion.core.telemetry import AttitudeSample
from tcm_companion.flightlog.reader import part_name
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.endpoint import CompanionEndpoint, TelemetryReceived, TelemetryRejected
from tcm_companion.service.box_feed import encode_box_message
from tcm_companion.service.companion import Companion
from tcm_companion.service.daemon_config import DaemonConfig
from tcm_companion.service.outputs import FrameProcessed, HealthChecked
from tcm_companion.sim.scene.export import SimulatedScenario
from tcm_companion.sim.scene.scenarios import flight_plan

EXAMPLES = Path(__file__).resolve().parent / "data" / "examples"
EXAMPLE_NAMES = ("EX-T90", "EX-PINHOLE", "EX-FISHEYE")

CAMERA = Equirectangular(360, 220)
"""The camera of :func:`simulated_flight` and of both drivers (pixels)."""
FEED = "udp:127.0.0.1:14660"
"""The box feed :class:`FedDriver`'s companion is configured with (never opened)."""


def example_path(name: str) -> Path:
    """The vendored example scenario ``name`` (one of :data:`EXAMPLE_NAMES`); skips the
    test when the examples are absent."""
    path = EXAMPLES / name
    if not path.is_dir():
        pytest.skip(f"example scenarios not found at {EXAMPLES}")
    return path


def decode(data: bytes) -> list[Any]:
    """The MAVLink messages (tcm dialect) in ``data``, skipping what does not parse."""
    mav = d.MAVLink(None)
    mav.robust_parsing = True
    return [m for m in (mav.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]


def simulated_flight(duration_s: float) -> tuple[SimulatedScenario, list[np.ndarray]]:
    """The simulated TS flight (a stationary ball) for ``duration_s`` seconds, seen by
    :data:`CAMERA`: the scenario and its rendered frames, in order."""
    scenario = SimulatedScenario(flight_plan("TS", duration_s=duration_s), CAMERA)
    return scenario, [img for _, _, img in scenario.iter_frames()]


class _CompanionDriver:
    """A companion on :data:`CAMERA` whose clock starts 0.5 s before the scenario's first
    frame, and what it sent to the autopilot (decoded)."""

    def __init__(
        self,
        scenario: SimulatedScenario,
        frames: list[np.ndarray],
        pipeline: PipelineConfig,
        config: DaemonConfig,
        *companion_args: Any,
        **companion_kw: Any,
    ) -> None:
        self.scenario = scenario
        self.frames = frames
        t0 = int(scenario.frame_times_us[0]) - 500_000
        self.endpoint = CompanionEndpoint(now_us=t0)
        self.companion = Companion(
            [CAMERA], pipeline, self.endpoint, t0, config, *companion_args, **companion_kw
        )
        self.now = t0
        self.sent: list[Any] = []

    def statuses(self) -> list[Any]:
        return [m for m in self.sent if m.get_type() == "TCM_OBJECT_STATUS"]

    def texts(self) -> list[str]:
        return [m.text for m in self.sent if m.get_type() == "STATUSTEXT"]


class Driver(_CompanionDriver):
    """Feeds a companion like the daemon, in time order: telemetry at its receive time,
    each frame 1 ms after capture, and ``process_due`` whenever it is due."""

    def __init__(
        self,
        scenario: SimulatedScenario,
        frames: list[np.ndarray],
        config: DaemonConfig | None = None,
        **companion_kw: Any,
    ) -> None:
        super().__init__(
            scenario, frames, PipelineConfig(), config or DaemonConfig(), **companion_kw
        )
        self.telemetry = sorted(scenario.telemetry, key=lambda s: s.recv_us)
        self.j = 0
        self.outputs: list[Any] = []
        self.results: list[Any] = []  # per frame processed: its result (None: it failed)
        self.keep: Any = lambda s: True
        self.nan_attitude = False

    # -- the event loop ----------------------------------------------------------------
    def _telemetry(self, s: Any) -> None:
        if not self.keep(s):
            return
        if self.nan_attitude and isinstance(s, AttitudeSample):
            self.companion.on_events([TelemetryRejected("attitude", "NaN")], s.recv_us)
            return
        # As the endpoint does when it receives telemetry: its clock fit.
        self.endpoint.telemetry_clock.observe(s.time_boot_us, s.recv_us)
        self.companion.on_events([TelemetryReceived(s)], s.recv_us)

    def turn(self, now: int) -> list[Any]:
        outs = self.companion.process_due(now)
        self.outputs += outs
        self.results += [o.result for o in outs if isinstance(o, FrameProcessed)]
        self.sent += decode(self.companion.data_to_send())
        return outs

    def advance(self, until_us: int) -> None:
        """Telemetry arrivals and the companion's deadlines up to ``until_us``, in order."""
        while True:
            tel = self.telemetry[self.j].recv_us if self.j < len(self.telemetry) else math.inf
            due = max(self.companion.next_deadline_us(), self.now)
            t = min(tel, due)
            if t > until_us:
                break
            self.now = int(t)
            if tel <= due:
                self.j += 1
                self._telemetry(self.telemetry[self.j - 1])
            else:
                self.turn(self.now)
        self.now = max(self.now, until_us)

    def run(self, first: int, last: int, keep: Any = None, nan_attitude: bool = False) -> None:
        self.keep = keep or (lambda s: True)
        self.nan_attitude = nan_attitude
        for i in range(first, last):
            t = int(self.scenario.frame_times_us[i])
            self.advance(t + 1_000)
            n = len(self.results)
            self.companion.on_frame(0, self.frames[i], t, t + 1_000)
            # Until it is processed (at once, or after its bounded wait for the attitude).
            self.advance(t + 1_000 + self.companion.config.attitude_wait_max_us)
            assert len(self.results) == n + 1
        self.keep = lambda s: True
        self.nan_attitude = False

    def run_frames(self, indices: list[int]) -> None:
        """Like :meth:`run`, for any subset of the frames (a slower or jittering camera)."""
        for i in indices:
            t = int(self.scenario.frame_times_us[i])
            self.advance(t + 1_000)
            self.companion.on_frame(0, self.frames[i], t, t + 1_000)
            self.advance(t + 1_000 + self.companion.config.attitude_wait_max_us)

    def health_checks(self) -> list[HealthChecked]:
        return [o for o in self.outputs if isinstance(o, HealthChecked)]


class FedDriver(_CompanionDriver):
    """Feeds a Companion with a live box feed (:data:`FEED`, camera "front"), in time
    order: telemetry at its receive time, each frame 1 ms after capture, each frame's
    boxes as a datagram ``latency_us`` after capture, and ``process_due`` at every
    deadline it names.

    ``flight`` is ``(scenario, frames, boxes by frame index)``. ``datagram(i, t_capture)``
    is what the feeder sends for frame ``i`` (None: nothing)."""

    def __init__(
        self, flight: Any, config: DaemonConfig | None = None, *, warm: bool = True
    ) -> None:
        scenario, frames, self.boxes = flight
        pipeline = dataclasses.replace(PipelineConfig(), detection=DetectionConfig(backend="boxes"))
        super().__init__(
            scenario, frames, pipeline, config or DaemonConfig(box_feed=FEED), ["front"]
        )
        self.events: list[tuple[int, int, str, Any]] = []  # (time, order, kind, what)
        self.n = 0
        for s in self.scenario.telemetry:
            self._at(s.recv_us, "telemetry", s)
        self.processed: list[FrameProcessed] = []
        self.replies: list[str] = []
        if warm:
            # The feeder is there before the first frame (an empty message about an
            # earlier frame): from the first frame on, frames wait for their boxes.
            t = int(self.scenario.frame_times_us[0])
            self._at(t - 100_000, "datagram", encode_box_message(0, t - 200_000, []))

    def _at(self, t: int, kind: str, what: Any) -> None:
        heapq.heappush(self.events, (int(t), self.n, kind, what))
        self.n += 1

    def frames_with_boxes(
        self,
        first: int,
        last: int,
        latency_us: int = 60_000,
        datagram: Callable[[int, int], bytes | None] | None = None,
    ) -> None:
        def default(i: int, t: int) -> bytes:
            return encode_box_message("front", t, self.boxes.get(i, []))

        make = datagram or default
        for i in range(first, last):
            t = int(self.scenario.frame_times_us[i])
            self._at(t + 1_000, "frame", (i, t))
            data = make(i, t)
            if data is not None:
                self._at(t + latency_us, "datagram", data)

    def run_until(self, until_us: int) -> None:
        comp = self.companion
        while True:
            due = max(comp.next_deadline_us(), self.now)
            t_ev = self.events[0][0] if self.events else math.inf
            t = min(due, t_ev)
            if t > until_us:
                break
            self.now = int(t)
            if t_ev <= due:
                _, _, kind, what = heapq.heappop(self.events)
                if kind == "telemetry":
                    self.endpoint.telemetry_clock.observe(what.time_boot_us, what.recv_us)
                    comp.on_events([TelemetryReceived(what)], self.now)
                elif kind == "frame":
                    i, t_cap = what
                    comp.on_frame(0, self.frames[i], t_cap, self.now)
                elif kind == "mavlink":
                    outs = comp.receive_data(what, self.now)
                    self.replies += [type(o).__name__ for o in outs]
                else:
                    self.replies.append(comp.on_box_datagram(what, self.now))
            else:
                outs = comp.process_due(self.now)
                self.processed += [o for o in outs if isinstance(o, FrameProcessed)]
                self.sent += decode(comp.data_to_send())
        self.now = max(self.now, until_us)

    def t(self, i: int) -> int:
        """Frame ``i``'s capture time (µs, companion monotonic)."""
        return int(self.scenario.frame_times_us[i])


# -- flight logs ----------------------------------------------------------------------

#: The reference flight log process replay must reproduce (tests/data/logs/README.md).
REFERENCE_LOG = Path(__file__).resolve().parent / "data" / "logs" / "sitl-t90.mcap"


def split_log(
    src: Path,
    dst: Path,
    n: int,
    edit: Callable[[str, bytes], bytes] | None = None,
    drop: Callable[[str, int], bool] | None = None,
) -> list[Path]:
    """``src`` rewritten as ``n`` parts of a log directory (each with the metadata, the
    messages in their order, 128 KiB chunks), as the writer's rotation would leave it;
    ``edit(topic, data)`` may change a message's data on the way, and a message for which
    ``drop(topic, publish_time_ns)`` is true is left out."""
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[Metadata] = []
    messages: list[Message] = []
    with open(src, "rb") as fh:
        for rec in StreamReader(fh).records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                metadata.append(rec)
            elif isinstance(rec, Message):
                messages.append(rec)
    dst.mkdir()
    per = math.ceil(len(messages) / n)
    paths = []
    for k in range(n):
        path = dst / part_name("20260101-120000", k)
        with open(path, "wb") as fh:
            w = Writer(fh, chunk_size=128 * 1024)
            w.start()
            for m in metadata:
                w.add_metadata(m.name, m.metadata)
            ids: dict[int, int] = {}
            for msg in messages[k * per : (k + 1) * per]:
                if drop is not None and drop(channels[msg.channel_id].topic, msg.publish_time):
                    continue
                if msg.channel_id not in ids:
                    ch = channels[msg.channel_id]
                    sid = 0
                    if ch.schema_id:
                        s = schemas[ch.schema_id]
                        sid = w.register_schema(s.name, s.encoding, s.data)
                    ids[msg.channel_id] = w.register_channel(
                        ch.topic, ch.message_encoding, sid, ch.metadata
                    )
                data = msg.data if edit is None else edit(channels[msg.channel_id].topic, msg.data)
                w.add_message(
                    ids[msg.channel_id], msg.log_time, data, msg.publish_time, msg.sequence
                )
            w.finish()
        paths.append(path)
    return paths
