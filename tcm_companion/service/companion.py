"""The daemon's logic without its IO: frames, telemetry and time in; MAVLink out.

:class:`Companion` owns one :class:`~tcm_companion.core.pipeline.Pipeline` per camera,
the :class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint`, and the per-input health
(:mod:`.inputs`). The asyncio daemon (:mod:`.daemon`) only moves frames from the camera
threads and bytes from the link into it, and asks it when to wake; SITL, tests and the
daemon therefore run exactly this code, and tests drive it with a fake clock.

Policies that live here:

- **Attitude at the frame time.** A frame is processed at once when the autopilot's
  newest attitude sample is at most ``attitude_lead_max_us`` older than the frame (the
  pipeline slerps and, over that short span, extrapolates); otherwise it waits for the
  sample after it, at most until ``attitude_wait_max_us`` after capture
  (:meth:`Companion.frame_deadline_us`).
- **Stale inputs make objects unknown.** While the attitude input is unhealthy, or the
  position input is unhealthy and the egomotion source is the autopilot's, every
  object's state is ``unknown`` with the input's problem as the reason. When a camera
  goes stale, its last objects are sent once more as ``unknown``.
- **A failing frame is not a failing daemon.** An exception in the pipeline is counted,
  reported (STATUSTEXT) and the frame yields no result; after
  ``rebuild_after_errors`` consecutive failures the camera's pipeline is rebuilt.
- **Parameter changes** that touch the pipeline rebuild it with the new configuration
  (its telemetry is kept; objects warm up again, about one interval).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.camera import CameraModel
from ..core.classify import unknown
from ..core.egomotion import TranslationEstimate
from ..core.pipeline import FrameResult, ObjectResult, Pipeline, PipelineConfig
from ..core.telemetry import AttitudeSample, ClockSync, PositionSample, TelemetryBuffer
from ..mavlink import tcm_dialect as d
from ..mavlink.endpoint import (
    AutopilotFound,
    AutopilotLost,
    AutopilotRebooted,
    CompanionEndpoint,
    Event,
    HealthReport,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
)
from ..mavlink.params import config_with_params
from .inputs import Inputs, InputSpec

log = logging.getLogger(__name__)

_EGO_SOURCE = {
    "vision": d.TCM_EGOMOTION_SOURCE_VISION,
    "autopilot": d.TCM_EGOMOTION_SOURCE_AUTOPILOT,
    "fused": d.TCM_EGOMOTION_SOURCE_FUSED,
}


@dataclass(frozen=True)
class DaemonConfig:
    """``[daemon]``: timing and health policy of the service (times in µs)."""

    # A frame may be this much newer than the newest attitude sample and still be
    # processed at once (extrapolated); beyond it, it waits for the next sample ...
    attitude_lead_max_us: int = 25_000
    # ... but never longer than this after its capture time.
    attitude_wait_max_us: int = 40_000
    camera_timeout_us: int = 500_000  # a camera is stale after this long without a frame
    attitude_timeout_us: int = 200_000  # ATTITUDE requested at 50 Hz
    position_timeout_us: int = 1_000_000  # LOCAL_POSITION_NED requested at 10 Hz
    health_interval_us: int = 1_000_000  # health check, watchdog ping, status line
    rebuild_after_errors: int = 5  # consecutive failing frames before a pipeline rebuild
    latency_window: int = 250  # frames in the running latency figure of the health message
    # Where parameters and the signing timestamp live when their [mavlink] paths are
    # relative. "": $STATE_DIRECTORY (systemd's StateDirectory=), else
    # $XDG_STATE_HOME/tcm-companion, else ~/.local/state/tcm-companion.
    state_dir: str = ""
    # OpenCV worker threads for the pipeline (0: OpenCV's default, one per core). One is
    # faster here: frames are small, and extra threads fight the camera threads and
    # the event loop for the cores (tcm-companion bench --daemon).
    opencv_threads: int = 1
    # Python's GIL switch interval while the daemon runs (default Python: 5000 µs): how
    # long a camera thread with a new frame may wait for the loop thread to let go.
    gil_switch_interval_us: int = 1000

    def __post_init__(self) -> None:
        if self.opencv_threads < 0:
            raise ValueError(f"opencv_threads must be >= 0, got {self.opencv_threads}")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name != "opencv_threads" and isinstance(value, int) and value <= 0:
                raise ValueError(f"{f.name} must be > 0, got {value}")
        if self.attitude_wait_max_us < self.attitude_lead_max_us:
            raise ValueError("attitude_wait_max_us must be >= attitude_lead_max_us")


@dataclass
class CompanionStats:
    frames_processed: int = 0
    frames_dropped: int = 0  # superseded by a newer frame before processing
    frames_failed: int = 0  # the pipeline raised
    frames_waited: int = 0  # waited for the attitude after them
    frames_without_time_base: int = 0  # processed before the autopilot's clock was known
    pipeline_rebuilds: int = 0
    objects_sent: int = 0
    objects_unknown_by_input: int = 0
    faults: Counter[str] = field(default_factory=Counter)


@dataclass
class _Camera:
    camera_id: int
    name: str
    model: CameraModel
    pipeline: Pipeline
    last_objects: tuple[ObjectResult, ...] = ()
    last_t_us: int | None = None
    consecutive_errors: int = 0


class TimesyncClock(ClockSync):
    """The pipeline's autopilot-to-companion clock, on TIMESYNC while it is fresh.

    :class:`~tcm_companion.core.telemetry.ClockSync` fits the lower envelope of
    ``receive time - boot time`` of the telemetry, which leaves the link's smallest
    one-way latency in the offset (a fraction of a ms on UDP; on a USB serial adapter
    with its latency timer, ms). TIMESYNC measures the offset with the round trip and
    halves it, which removes that bias. This clock uses TIMESYNC's offset when the
    endpoint has a fresh one that agrees with the telemetry fit to within
    ``agree_us`` (so an autopilot reboot, seen first by one of them, never mixes two boot
    clocks), and the telemetry fit otherwise.
    """

    def __init__(
        self, endpoint: CompanionEndpoint, max_age_us: int = 10_000_000, agree_us: int = 50_000
    ) -> None:
        super().__init__()
        self.endpoint = endpoint
        self.max_age_us = max_age_us
        self.agree_us = agree_us
        self._last_recv_us = 0
        self.used_timesync = False

    def observe(self, boot_us: int, recv_us: int) -> None:
        super().observe(boot_us, recv_us)
        self._last_recv_us = max(self._last_recv_us, int(recv_us))

    @property
    def offset_us(self) -> float:
        fit = super().offset_us
        ts = self.endpoint.timesync
        if (
            ts.synced
            and ts.age_us(self._last_recv_us) < self.max_age_us
            and math.isfinite(fit)
            and abs(ts.offset_us - fit) < self.agree_us
        ):
            self.used_timesync = True
            return float(ts.offset_us)
        self.used_timesync = False
        return fit


def mark_unknown(result: FrameResult, reason: str) -> FrameResult:
    """``result`` with every object's state ``unknown`` for ``reason``."""
    objs = tuple(
        dataclasses.replace(
            o,
            state="unknown",
            reason=reason,
            classification=unknown(reason, o.classification.interval_frames),
        )
        for o in result.objects
    )
    return dataclasses.replace(result, objects=objs)


class Companion:
    """The service's decisions, on an injected clock (µs, companion monotonic)."""

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        pipeline_config: PipelineConfig,
        endpoint: CompanionEndpoint,
        now_us: int,
        config: DaemonConfig = DaemonConfig(),
        camera_names: Sequence[str] | None = None,
    ) -> None:
        if not cameras:
            raise ValueError("at least one camera is needed")
        self.config = config
        self.endpoint = endpoint
        self.base_pipeline_config = pipeline_config
        self.pipeline_config = config_with_params(pipeline_config, endpoint.params.values)
        names = list(camera_names) if camera_names else [f"camera{i}" for i in range(len(cameras))]
        # One telemetry buffer for every camera: attitude at each frame's capture time
        # through the TIMESYNC mapping, one clock fit.
        self.telemetry = TelemetryBuffer(clock=TimesyncClock(endpoint))
        self.cameras = [
            _Camera(i, names[i], cam, Pipeline(cam, self.pipeline_config, telemetry=self.telemetry))
            for i, cam in enumerate(cameras)
        ]
        specs = [InputSpec(c.name, 25.0, config.camera_timeout_us) for c in self.cameras]
        ecfg = endpoint.config
        specs.append(InputSpec("attitude", ecfg.attitude_rate_hz, config.attitude_timeout_us))
        specs.append(
            InputSpec("position", ecfg.position_rate_hz, config.position_timeout_us, required=False)
        )
        self.inputs = Inputs(specs, now_us)
        self.stats = CompanionStats()
        self.latencies_ms: deque[float] = deque(maxlen=config.latency_window)
        self._frame_times: deque[int] = deque(maxlen=64)
        self._last_translation: TranslationEstimate | None = None
        self._last_drop_us: int | None = None
        self.last_override = ""  # why the last processed frame's objects were made unknown
        self.log_state = d.TCM_LOG_STATE_OFF  # the flight log's state, set by the daemon

    # -- inputs ---------------------------------------------------------------------------
    def handle_events(self, events: Sequence[Event], now_us: int) -> None:
        """Events of the endpoint (telemetry, parameters, autopilot state)."""
        for ev in events:
            if isinstance(ev, TelemetryReceived):
                s = ev.sample
                self.telemetry.add(s)
                if isinstance(s, AttitudeSample):
                    self.inputs.update("attitude", now_us, True)
                elif isinstance(s, PositionSample):
                    self.inputs.update("position", now_us, True)
            elif isinstance(ev, TelemetryRejected):
                self.inputs.update(ev.kind, now_us, False)
                self.stats.faults[f"{ev.kind} rejected"] += 1
            elif isinstance(ev, ParamChanged):
                self._apply_params(now_us)
            elif isinstance(ev, AutopilotLost):
                self.stats.faults["autopilot lost"] += 1
                self.endpoint.statustext(d.MAV_SEVERITY_WARNING, "TCM: autopilot link lost", now_us)
            elif isinstance(ev, AutopilotFound):
                self.endpoint.statustext(
                    d.MAV_SEVERITY_INFO, f"TCM: autopilot {ev.system_id} found", now_us
                )
            elif isinstance(ev, AutopilotRebooted):
                self.stats.faults["autopilot reboot"] += 1

    def _apply_params(self, now_us: int) -> None:
        new = config_with_params(self.base_pipeline_config, self.endpoint.params.values)
        if new == self.pipeline_config:
            return  # an output enable or alarm level: nothing in the pipeline changes
        self.pipeline_config = new
        for cam in self.cameras:
            self._rebuild(cam)
        self.endpoint.statustext(d.MAV_SEVERITY_INFO, "TCM: parameters applied", now_us)

    def _rebuild(self, cam: _Camera) -> None:
        # The shared telemetry keeps the attitude history and clock fit.
        cam.pipeline = Pipeline(cam.model, self.pipeline_config, telemetry=self.telemetry)
        cam.consecutive_errors = 0
        self.stats.pipeline_rebuilds += 1

    # -- frames ---------------------------------------------------------------------------
    def frame_deadline_us(self, camera_id: int, t_capture_us: int) -> int | None:
        """When a frame captured at ``t_capture_us`` should be processed.

        ``None``: now (the attitude covers it, or nothing will come). Otherwise the
        companion time to wait until, unless a new attitude sample arrives first.
        """
        newest = self.telemetry.latest_attitude_time_us()
        if newest is None:
            return None  # no attitude at all: waiting would not help
        if t_capture_us - newest <= self.config.attitude_lead_max_us:
            return None
        return t_capture_us + self.config.attitude_wait_max_us

    def note_frame_arrival(self, camera_id: int, now_us: int, valid: bool = True) -> None:
        """A camera delivered a frame (before it is processed or dropped)."""
        self.inputs.update(self.cameras[camera_id].name, now_us, valid)

    def process(
        self, camera_id: int, image: np.ndarray, t_capture_us: int, now_us: int
    ) -> FrameResult | None:
        """Run the pipeline on one frame and queue its outputs on the endpoint."""
        cam = self.cameras[camera_id]
        try:
            result = cam.pipeline.step(image, t_capture_us)
        except Exception as exc:  # one bad frame must not stop the service
            self.stats.frames_failed += 1
            self.stats.faults["pipeline exception"] += 1
            cam.consecutive_errors += 1
            log.exception("pipeline failed on %s frame at %d us", cam.name, t_capture_us)
            self.endpoint.statustext(
                d.MAV_SEVERITY_ERROR, f"TCM: pipeline error {type(exc).__name__}", now_us
            )
            if cam.consecutive_errors >= self.config.rebuild_after_errors:
                self._rebuild(cam)
                self.endpoint.statustext(d.MAV_SEVERITY_WARNING, "TCM: pipeline restarted", now_us)
            return None
        cam.consecutive_errors = 0
        reason = self._blocking_input(now_us)
        self.last_override = ""
        if reason and result.objects:
            result = mark_unknown(result, reason)
            self.last_override = reason
            self.stats.objects_unknown_by_input += len(result.objects)
        cam.last_objects = result.objects
        cam.last_t_us = t_capture_us
        if not self.endpoint.has_time_base(now_us):
            # Neither TIMESYNC nor the telemetry has given us the autopilot's boot time
            # yet: a time_boot_ms of 0 would read as ancient to the autopilot, and
            # nothing is decided without its attitude anyway. Keep quiet until it has.
            self.stats.frames_without_time_base += 1
            self.stats.frames_processed += 1
            return result
        self.endpoint.send_frame(result, now_us, camera_id)
        self.stats.frames_processed += 1
        self.stats.objects_sent += len(result.objects)
        self._frame_times.append(now_us)
        if result.translation is not None:
            self._last_translation = result.translation
        return result

    def clock_offset_us(self, camera_id: int) -> float:
        """The autopilot-to-companion offset (µs) the camera's pipeline uses now."""
        return float(self.telemetry.clock.offset_us)

    def threshold(self) -> float:
        return float(self.pipeline_config.classifier.tcm_threshold)

    def record_latency(self, latency_us: int) -> None:
        """Capture → handed to the link, for the health message."""
        self.latencies_ms.append(latency_us / 1000.0)

    def _blocking_input(self, now_us: int) -> str:
        att = self.inputs.monitors["attitude"].status(now_us)
        if not att.healthy:
            return att.problem
        if self.pipeline_config.egomotion_source == "autopilot":
            pos = self.inputs.monitors["position"].status(now_us)
            if not pos.healthy:
                return pos.problem
        return ""

    # -- once a second --------------------------------------------------------------------
    def tick(self, now_us: int) -> list[tuple[str, str]]:
        """Health bookkeeping; returns the input changes ``(input, problem)`` it reported."""
        changes = self.inputs.changes(now_us)
        for name, problem in changes:
            if problem:
                self.stats.faults[problem.split(" (")[0]] += 1
                self.endpoint.statustext(d.MAV_SEVERITY_WARNING, f"TCM: {problem}", now_us)
                cam = next((c for c in self.cameras if c.name == name), None)
                if cam is not None and cam.last_objects:
                    # Tell the autopilot once that what it last heard is no longer known.
                    # Stamped now: "as of now these are unknown" (the last frame is too
                    # old for the autopilot to accept, which is the point of saying it).
                    stale = FrameResult(-1, now_us, cam.last_objects, False, None, {})
                    self.endpoint.send_frame(mark_unknown(stale, problem), now_us, cam.camera_id)
                    cam.last_objects = ()
            else:
                self.endpoint.statustext(d.MAV_SEVERITY_INFO, f"TCM: {name} OK", now_us)
        self.endpoint.set_health(self.health_report(now_us))
        return changes

    def health_flags(self, now_us: int) -> int:
        st = self.inputs.status(now_us)
        flags = 0
        if any(not st[c.name].healthy for c in self.cameras):
            flags |= d.TCM_HEALTH_CAMERA_LOST
        if not st["attitude"].healthy:
            flags |= d.TCM_HEALTH_ATTITUDE_STALE
        if not st["position"].healthy:
            flags |= d.TCM_HEALTH_POSITION_STALE
        ts = self.endpoint.timesync
        if not ts.synced or ts.age_us(now_us) > 5_000_000:
            flags |= d.TCM_HEALTH_TIMESYNC_LOST
        if self._last_drop_us is not None and now_us - self._last_drop_us < 2_000_000:
            flags |= d.TCM_HEALTH_OVERLOADED
        if self.log_state == d.TCM_LOG_STATE_FAULT:
            flags |= d.TCM_HEALTH_LOG_FAULT
        return flags

    def note_drop(self, now_us: int) -> None:
        """A frame was superseded by a newer one before it could be processed."""
        self.stats.frames_dropped += 1
        self._last_drop_us = now_us

    def frame_rate_hz(self, now_us: int) -> float:
        recent = [t for t in self._frame_times if now_us - t <= 2_000_000]
        if len(recent) < 2:
            return 0.0
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / (span / 1e6) if span > 0 else 0.0

    def health_report(self, now_us: int) -> HealthReport:
        tr = self._last_translation
        quality = 0
        if tr is not None and tr.valid and math.isfinite(tr.sigma_rad):
            quality = round(100 * max(0.0, 1.0 - tr.sigma_rad / 0.2))
        lat = sorted(self.latencies_ms)
        p50 = lat[len(lat) // 2] if lat else 0.0
        return HealthReport(
            frame_rate_hz=self.frame_rate_hz(now_us),
            latency_ms=p50,
            frames_dropped=self.stats.frames_dropped,
            egomotion_source=_EGO_SOURCE.get(
                tr.source if tr is not None else "", d.TCM_EGOMOTION_SOURCE_NONE
            ),
            egomotion_quality_pct=quality,
            health_flags=self.health_flags(now_us),
            objects=sum(len(c.last_objects) for c in self.cameras),
            log_state=self.log_state,
        )
