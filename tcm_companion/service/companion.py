"""The daemon's logic without its IO: frames, link bytes and time in; MAVLink bytes and
outputs out.

:class:`Companion` is the service, sans-IO in the manner of aioquic's ``QuicConnection``:
every entry point takes the time as an argument (µs on the companion's monotonic clock,
``_mono_us``), nothing here reads a clock, a socket or a camera, and it says when it next
wants to run. It owns one :class:`~tcm_companion.core.pipeline.Pipeline` per camera (all
reading one shared :class:`~tcm_companion.core.telemetry.TelemetryBuffer`), the
:class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint`, the per-input health
(:mod:`.inputs`), one frame slot per camera (:mod:`.slots`), and the once-a-second health
check. Beside it, one job each: its settings and their rules (:mod:`.daemon_config`), what
it hands its drivers (:mod:`.outputs`), the pipelines' clock (:mod:`.timesync_clock`), its
counters and latency figures (:mod:`.health`).

Its drivers only move things in and out, all through the same surface:

- the asyncio daemon (:mod:`.daemon`: camera threads, a real transport, systemd),
- the virtual-time SITL (:mod:`tcm_companion.sitl.virtual`: the mock autopilot, the simulated camera
  and modelled links on one simulated clock),
- process replay of a flight log (:mod:`tcm_companion.replay.log`), and the tests.

The surface::

    comp = Companion(cameras, pipeline_config, endpoint, now_mono_us, daemon_config)
    comp.on_frame(camera_id, image, capture_mono_us, now_mono_us)   # a camera delivered
    outputs = comp.receive_data(data, now_mono_us)                  # bytes from the link
    outputs = comp.process_due(now_mono_us)                         # timers, one frame
    data = comp.data_to_send()                                      # bytes for the link
    comp.frame_sent(output, sent_mono_us)                           # the bytes went out
    when = comp.next_deadline_us()                                  # call process_due then

With several cameras the daemon runs the pipelines in worker processes
(:mod:`.workers`): after ``comp.offload_steps()``, ``process_due`` hands out a
:class:`~.outputs.StepRequested` (the frame and the telemetry its pipeline reads) for each
camera whose worker is idle instead of running the pipeline, and the driver gives each
result back with ``outputs = comp.on_step_done(camera_id, result, error_name, now_mono_us)``
(``worker_ready`` / ``worker_lost`` say when a worker can take frames). Everything after
the step is the same code either way (``_finish``).

After each ``process_due`` a driver handles the outputs in order (a processed frame's
result is logged *before* its bytes are written: replay relies on that order), then
writes ``data_to_send()`` and reports the write time of each processed frame with
``frame_sent`` (the latency in the health message is capture → written).

Policies that live here:

- **One slot per camera.** A frame delivered while the previous one of its camera still
  waits replaces it; the replaced one is counted as dropped (``stats.frames_dropped``),
  and the health message flags the overload for 2 s. Stale frames are never queued.
  Dropping frames is ``overloaded`` (``processing 14.2 of 25 fps``): one fault until no
  frame was dropped for :data:`OVERLOAD_WINDOW_US`, announced once (STATUSTEXT), shown on
  the status line; the method's durations are seconds, so decisions go on at the rate
  managed (docs/decisions.md §7).
- **Attitude at the frame time.** A frame is ready at once when the autopilot's newest
  attitude sample is at most ``attitude_lead_max_us`` older than the frame (the pipeline
  slerps and, over that short span, extrapolates); otherwise it waits for the sample
  after it, at most until ``attitude_wait_max_us`` after capture
  (:meth:`Companion.frame_deadline_us`). Of several ready frames, the oldest capture
  goes first; one frame per ``process_due``, so its bytes go out before the next frame.
- **Stale inputs make objects unknown.** While the attitude input is unhealthy, or the
  position input is unhealthy and the egomotion source is the autopilot's, every
  object's state is ``unknown`` with the input's problem as the reason. When a camera
  becomes unhealthy (stale, slow), its last objects are sent once more as ``unknown``.
  A condition is one fault until it clears: it is counted, announced (STATUSTEXT) and
  clears the objects once, however its measured rate moves meanwhile. A camera's
  expected rate is its own (``camera_rates_hz``: the application's ``[camera] fps``).
- **A failing frame is not a failing daemon.** An exception in the pipeline is counted,
  reported (STATUSTEXT) and the frame yields no result; after
  ``rebuild_after_errors`` consecutive failures the camera's pipeline is rebuilt.
- **The live box feed** (``[daemon] box_feed``, ``box_tracking``; docs/box-feed.md) is
  its own object, :class:`~.live_boxes.LiveBoxes`: a frame of a fed camera waits for its
  boxes (bounded by ``box_wait_max_us``); the Companion asks it when a slot is due and
  whether a waiting frame stays when a newer one arrives.
- **Parameter changes** from the ground station that touch the pipeline rebuild it with
  the new configuration (the shared telemetry is kept; objects warm up again).
- **One object, one track** with two cameras or more: every camera's result goes through
  one :class:`~tcm_companion.core.rig.RigTracker` (rig-wide track ids, each object
  reported by the camera that sees it best, a track entering from another camera's view
  decided with that history). A lost camera makes only what it alone measured unknown;
  OBSTACLE_DISTANCE covers every camera. One camera: no rig, results as before.
- **Nothing is sent before the autopilot's boot clock is known** (TIMESYNC or the
  telemetry): a ``time_boot_ms`` of 0 would read as ancient.
- **Once a second** (``health_interval_us``, on absolute deadlines that skip rather
  than burst after a stall): input health, STATUSTEXT on changes, the health message's
  content, the flight log falling behind, and a :class:`HealthChecked` output that the
  daemon turns into the systemd watchdog ping and status line.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..core.camera import CameraModel
from ..core.egomotion import TranslationEstimate
from ..core.pipeline import FrameResult, ObjectResult, Pipeline, PipelineConfig
from ..core.rig import RigTracker
from ..core.telemetry import AttitudeSample, PositionSample, TelemetryBuffer
from ..mavlink import tcm_dialect as d
from ..mavlink.endpoint import (
    AutopilotConflict,
    AutopilotFound,
    AutopilotLost,
    AutopilotRebooted,
    CompanionEndpoint,
    Event,
    HealthReport,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
    TrackingImageStatus,
)
from ..mavlink.params import config_with_params, params_problem
from .box_feed import INPUT_NAME as BOX_FEED
from .daemon_config import DaemonConfig
from .health import (
    CompanionStats,
    egomotion_quality_pct,
    egomotion_source_code,
    latency_percentile_ms,
    mark_unknown,
    status_line_text,
)
from .inputs import Inputs, InputSpec
from .live_boxes import MAX_FRAMES_WAITING_FOR_BOXES, LiveBoxes
from .outputs import FrameProcessed, HealthChecked, Output, ParamsChanged, StepRequested
from .slots import CameraSlots, FrameSlot
from .timesync_clock import TimesyncClock

log = logging.getLogger(__name__)

#: A camera's expected frame rate when the driver does not give one (Hz).
DEFAULT_CAMERA_HZ = 25.0
#: Frames dropped within this long make the pipeline "overloaded" (health flag, problem).
OVERLOAD_WINDOW_US = 2_000_000


class Companion:
    """The service's decisions; every time is µs on the companion monotonic clock."""

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        pipeline_config: PipelineConfig,
        endpoint: CompanionEndpoint,
        now_mono_us: int,
        config: DaemonConfig = DaemonConfig(),
        camera_names: Sequence[str] | None = None,
        *,
        camera_rates_hz: Sequence[float] | None = None,
        pipeline_timer: Callable[[], float] | None = None,
        detector_model: bytes | None = None,
    ) -> None:
        """``camera_rates_hz``: the frame rate each camera is set to (the application's
        ``[camera] fps``; default :data:`DEFAULT_CAMERA_HZ` each): a camera is ``slow``
        below half of its own. ``pipeline_timer`` is what the pipelines time their stages
        with (seconds; default ``time.perf_counter``); the virtual-time SITL passes its
        own so that nothing it records depends on the machine's speed. ``detector_model``:
        the bytes of the ``onnx`` backend's model file (the driver reads it; None for the
        other backends), kept for the pipelines' rebuilds."""
        if not cameras:
            raise ValueError("at least one camera is needed")
        rates = (
            [DEFAULT_CAMERA_HZ] * len(cameras)
            if camera_rates_hz is None
            else [float(r) for r in camera_rates_hz]
        )
        self._expected_hz = sum(rates)
        if len(rates) != len(cameras):
            raise ValueError(f"{len(cameras)} camera(s) but {len(rates)} camera rate(s)")
        if not all(math.isfinite(r) and r > 0 for r in rates):
            raise ValueError(f"camera rates must be positive frames per second, got {rates}")
        self.config = config
        self.endpoint = endpoint
        if len(cameras) >= 2:
            # A rig: every camera's translation at every frame, for the cross-camera pairs
            # of core.rig (one camera stays exactly as it was).
            pipeline_config = dataclasses.replace(pipeline_config, always_translate=True)
        self.base_pipeline_config = pipeline_config
        # A PARAM_SET whose value passes its own range but cannot be applied with the
        # others (a seed hue range leaving the grow range) is refused by the endpoint,
        # never raised in the middle of the event loop.
        endpoint.param_check = self._param_problem
        refused = params_problem(pipeline_config, endpoint.params.values)
        if refused:
            # Stored values that cannot be applied together: the configuration's instead.
            endpoint.params.values.update(endpoint.params.defaults)
        self.pipeline_config = config_with_params(pipeline_config, endpoint.params.values)
        if refused:
            endpoint.statustext(
                d.MAV_SEVERITY_WARNING,
                f"TCM: stored parameters refused ({refused}); using the configuration's",
                now_mono_us,
            )
        self._timer_kw: dict[str, Callable[[], float]] = (
            {"timer": pipeline_timer} if pipeline_timer is not None else {}
        )
        self._detector_model = detector_model
        names = list(camera_names) if camera_names else [f"camera{i}" for i in range(len(cameras))]
        # One telemetry buffer for every camera: attitude at each frame's capture time
        # through the TIMESYNC mapping, one clock fit.
        self.clock = TimesyncClock(endpoint)
        self.telemetry = TelemetryBuffer(clock=self.clock)
        self.cameras = [
            CameraSlots(i, names[i], cam, self._new_pipeline(cam)) for i, cam in enumerate(cameras)
        ]
        # Two cameras or more: one track per object across the rig (core.rig).
        self.rig = RigTracker(cameras, self.pipeline_config) if len(cameras) >= 2 else None
        specs = [
            InputSpec(c.name, rate, config.camera_timeout_us)
            for c, rate in zip(self.cameras, rates, strict=True)
        ]
        ecfg = endpoint.config
        specs.append(InputSpec("attitude", ecfg.attitude_rate_hz, config.attitude_timeout_us))
        specs.append(
            InputSpec(
                "position",
                ecfg.position_rate_hz,
                config.position_timeout_us,
                required=False,
                starts_late=True,  # the autopilot's EKF origin: "waiting for position"
            )
        )
        # The live box feed: one input for every camera's boxes, judged alive only (a
        # detector may run at any rate).
        LiveBoxes.check(config, self.cameras)
        if LiveBoxes.configured(config):
            specs.append(
                InputSpec(BOX_FEED, max(rates), config.box_feed_timeout_us, min_rate_fraction=0.0)
            )
        self.inputs = Inputs(specs, now_mono_us)
        self._started_mono_us = now_mono_us
        self.stats = CompanionStats()
        self.boxes = LiveBoxes(config, self.cameras, self.stats.box_feed, self.inputs, endpoint)
        self.latencies_ms: deque[float] = deque(maxlen=config.latency_window)
        self._frame_times_mono_us: deque[int] = deque(maxlen=64)
        self._last_translation: TranslationEstimate | None = None
        self._last_drop_mono_us: int | None = None
        self._overloaded = False  # the condition announced by the last health check
        self._next_health_mono_us = now_mono_us + config.health_interval_us
        self.last_override = ""  # why the last processed frame's objects were made unknown
        # Two senders use the autopilot's id ("" when not): the objects' reason meanwhile.
        self.conflict = ""
        # The flight log's state (set_log_state), reported in the health message.
        self.log_state = d.TCM_LOG_STATE_OFF
        self._log_behind = 0  # items the log has lost so far (frames and messages)
        self._log_frames_lost = 0
        self._log_behind_reported = 0
        self._offload = False  # offload_steps: the pipelines run in the driver's workers

    def _new_pipeline(self, model: CameraModel) -> Pipeline:
        return Pipeline(
            model,
            self.pipeline_config,
            telemetry=self.telemetry,
            detector_model=self._detector_model,
            **self._timer_kw,
        )

    # -- inputs -----------------------------------------------------------------------------
    def on_frame(
        self, camera_id: int, image: np.ndarray, capture_mono_us: int, now_mono_us: int
    ) -> None:
        """Camera ``camera_id`` delivered a frame captured at ``capture_mono_us``.

        It takes the camera's slot; a frame still waiting there is dropped (counted).
        """
        cam = self.cameras[camera_id]
        self.inputs.update(cam.name, now_mono_us, True)
        self.boxes.frame_delivered(capture_mono_us)
        # An older frame still here is stale: never queue it ... unless it still waits
        # for its boxes (the live feed's detector takes its time; bounded in time by
        # box_wait_max_us and in number).
        keep = [
            s
            for s in cam.pending
            if self.boxes.holds(s.waited_for_boxes, s.capture_mono_us, now_mono_us)
        ]
        keep = keep[-(MAX_FRAMES_WAITING_FOR_BOXES - 1) :]
        for _ in range(len(cam.pending) - len(keep)):
            self._drop(now_mono_us, cam)
        # A frame the attitude does not cover yet waits (bounded) for the next sample.
        waits = self.frame_deadline_us(camera_id, capture_mono_us) is not None
        slot = FrameSlot(image, int(capture_mono_us), int(now_mono_us), waits)
        slot.waited_for_boxes = self.boxes.deadline_us(camera_id, slot.capture_mono_us) is not None
        cam.pending = [*keep, slot]

    @property
    def box_feed(self) -> bool:
        """Whether a live box feed is configured (``[daemon] box_feed`` or ``box_tracking``)."""
        return self.boxes.enabled

    def on_box_datagram(self, data: bytes, now_mono_us: int) -> str:
        """A datagram of the live box feed (``tcm-boxes/1``) arrived at ``now_mono_us``:
        :meth:`.LiveBoxes.on_datagram`."""
        return self.boxes.on_datagram(data, now_mono_us)

    def receive_data(self, data: bytes, now_mono_us: int) -> list[Output]:
        """Bytes from the autopilot link (any chunking)."""
        return self.on_events(self.endpoint.receive_data(data, now_mono_us), now_mono_us)

    def on_events(self, events: Sequence[Event], now_mono_us: int) -> list[Output]:
        """Events of the endpoint (telemetry, parameters, the autopilot's state)."""
        out: list[Output] = []
        for ev in events:
            if isinstance(ev, TelemetryReceived):
                s = ev.sample
                self.telemetry.add(s)
                if isinstance(s, AttitudeSample):
                    self.inputs.update("attitude", now_mono_us, True)
                elif isinstance(s, PositionSample):
                    self.inputs.update("position", now_mono_us, True)
            elif isinstance(ev, TelemetryRejected):
                self.inputs.update(ev.kind, now_mono_us, False)
                self.stats.faults[f"{ev.kind} rejected"] += 1
            elif isinstance(ev, ParamChanged):
                self._apply_params(now_mono_us)
                out.append(ParamsChanged(ev.name, ev.value, now_mono_us))
            elif isinstance(ev, AutopilotLost):
                self.stats.faults["autopilot lost"] += 1
                self.endpoint.statustext(
                    d.MAV_SEVERITY_WARNING, "TCM: autopilot link lost", now_mono_us
                )
            elif isinstance(ev, AutopilotFound):
                self.endpoint.statustext(
                    d.MAV_SEVERITY_INFO, f"TCM: autopilot {ev.system_id} found", now_mono_us
                )
            elif isinstance(ev, AutopilotRebooted):
                self.stats.faults["autopilot reboot"] += 1
            elif isinstance(ev, AutopilotConflict):
                self._on_conflict(ev, now_mono_us)
            elif isinstance(ev, TrackingImageStatus):
                if self.config.box_tracking:
                    self.boxes.on_tracking_image(ev, now_mono_us)
                else:
                    self.stats.box_feed["tracking ignored"] += 1
        return out

    def _on_conflict(self, ev: AutopilotConflict, now_mono_us: int) -> None:
        """Two senders use the autopilot's id (the endpoint announced it): one fault;
        every object ``unknown`` while it lasts (the endpoint uses one sender's telemetry
        only, but which one is real is not known). When it ends the pipelines start
        over, so that nothing is decided from attitude of the conflict's time."""
        if ev.active:
            self.stats.faults["autopilot conflict"] += 1
            self.conflict = f"two senders as autopilot {ev.system_id}/{ev.component_id}"
            for cam in self.cameras:
                if cam.last_objects:  # what the autopilot last heard is unknown now
                    stale = FrameResult(-1, now_mono_us, cam.last_objects, False, None, {})
                    self.endpoint.send_frame(
                        mark_unknown(stale, self.conflict), now_mono_us, cam.camera_id
                    )
                    cam.last_objects = ()
        else:
            self.conflict = ""
            for cam in self.cameras:
                self._rebuild(cam)

    def set_log_state(self, state: int, frames_lost: int, messages_lost: int) -> None:
        """The flight log's ``TCM_LOG_STATE`` and how many frames and other messages it
        has lost so far on a full queue. Call before :meth:`process_due` when
        :meth:`health_due`: the health check reports them."""
        self.log_state = int(state)
        self._log_frames_lost = int(frames_lost)
        self._log_behind = int(frames_lost) + int(messages_lost)

    def report(self, severity: int, text: str, now_mono_us: int) -> None:
        """Tell the ground station ``text`` (a STATUSTEXT, rate-limited per text): for
        the daemon's own components, e.g. the flight log's writer."""
        self.endpoint.statustext(severity, text, now_mono_us)

    # -- time ------------------------------------------------------------------------------
    def next_deadline_us(self) -> int:
        """When :meth:`process_due` has work next (companion monotonic µs; a time in
        the past means now): the endpoint's timers, the health check, a ready frame, or
        the end of a frame's wait for the attitude."""
        due = min(self.endpoint.next_deadline_us(), self._next_health_mono_us)
        for cam in self.cameras:
            if cam.pending and self._can_step(cam):
                due = min(due, self._slot_due_us(cam, cam.pending[0]))
        return due

    def health_due(self, now_mono_us: int) -> bool:
        """Whether the next :meth:`process_due` at ``now_mono_us`` runs the health check."""
        return now_mono_us >= self._next_health_mono_us

    def process_due(self, now_mono_us: int) -> list[Output]:
        """Run what is due at ``now_mono_us``: the endpoint's timers, the health check,
        then at most one ready frame (the oldest capture). Then send
        :meth:`data_to_send`; call again while :meth:`next_deadline_us` has passed."""
        out = self.on_events(self.endpoint.poll(now_mono_us), now_mono_us)
        if self.health_due(now_mono_us):
            out.append(self._health_check(now_mono_us))
            nxt = self._next_health_mono_us + self.config.health_interval_us
            # Absolute deadlines; after a stall, skip rather than burst.
            if nxt <= now_mono_us:
                nxt = now_mono_us + self.config.health_interval_us
            self._next_health_mono_us = nxt
        # A camera's frames go in capture order: an older one is due whenever a newer one is.
        ready = [
            c
            for c in self.cameras
            if c.pending and self._can_step(c) and self._slot_due_us(c, c.pending[0]) <= now_mono_us
        ]
        if self._offload:  # every idle worker gets its camera's frame, oldest first
            ready.sort(key=lambda c: (c.pending[0].capture_mono_us, c.camera_id))
            out.extend(self._request(cam, now_mono_us) for cam in ready)
        elif ready:
            cam = min(ready, key=lambda c: (c.pending[0].capture_mono_us, c.camera_id))
            out.append(self._process(cam, now_mono_us))
        return out

    def _can_step(self, cam: CameraSlots) -> bool:
        """Whether camera ``cam``'s next frame can be processed now (in-process: always;
        offloaded: its worker is up and idle)."""
        return not self._offload or (cam.worker_up and cam.in_flight is None)

    def data_to_send(self) -> bytes:
        """The MAVLink bytes queued for the autopilot since the last call."""
        return self.endpoint.data_to_send()

    def frame_sent(self, frame: FrameProcessed, sent_mono_us: int) -> float | None:
        """``frame``'s output was written to the link at ``sent_mono_us``: its
        capture-to-MAVLink latency (ms), counted in the latency figures (None: the frame
        failed, nothing was sent for it)."""
        if frame.result is None:
            return None
        latency_ms = (sent_mono_us - frame.capture_mono_us) / 1000.0
        self.latencies_ms.append(latency_ms)
        return latency_ms

    def discard_pending(self, now_mono_us: int) -> int:
        """At stop: frames still in their slots are dropped (counted); how many."""
        n = 0
        for cam in self.cameras:
            for _ in cam.pending:
                self._drop(now_mono_us, cam)
                n += 1
            cam.pending = []
            if cam.in_flight is not None:  # its worker's result will not be waited for
                cam.in_flight = None
                self._drop(now_mono_us, cam)
                n += 1
        return n

    # -- frames ----------------------------------------------------------------------------
    def frame_deadline_us(self, camera_id: int, capture_mono_us: int) -> int | None:
        """When a frame of ``camera_id`` captured at ``capture_mono_us`` may be processed.

        ``None``: now (the attitude covers it, or there is no attitude to wait for).
        Otherwise the time to wait until, unless a new attitude sample arrives first.
        """
        newest = self.telemetry.latest_attitude_time_us()
        if newest is None:
            return None  # no attitude at all: waiting would not help
        if capture_mono_us - newest <= self.config.attitude_lead_max_us:
            return None
        return capture_mono_us + self.config.attitude_wait_max_us

    def _slot_due_us(self, cam: CameraSlots, slot: FrameSlot) -> int:
        deadline = self.frame_deadline_us(0, slot.capture_mono_us)
        due = slot.arrival_mono_us if deadline is None else deadline
        boxes = self.boxes.deadline_us(cam.camera_id, slot.capture_mono_us)
        return due if boxes is None else max(due, boxes)

    def _drop(self, now_mono_us: int, cam: CameraSlots) -> None:
        self.stats.frames_dropped += 1
        cam.frames_dropped += 1
        self._last_drop_mono_us = now_mono_us

    def _dropped_recently(self, now_mono_us: int) -> bool:
        """A frame was dropped within :data:`OVERLOAD_WINDOW_US`: the pipeline is behind."""
        last = self._last_drop_mono_us
        return last is not None and now_mono_us - last < OVERLOAD_WINDOW_US

    def overload_problem(self, now_mono_us: int) -> str:
        """``overloaded: processing 14.2 of 25 fps`` while frames were dropped (superseded
        before the pipeline got to them) within :data:`OVERLOAD_WINDOW_US`; "" otherwise."""
        if not self._dropped_recently(now_mono_us):
            return ""
        return (
            f"overloaded: processing {self.frame_rate_hz(now_mono_us):.1f}"
            f" of {self._expected_hz:g} fps"
        )

    def _step(
        self, cam: CameraSlots, image: np.ndarray, capture_mono_us: int, now_mono_us: int
    ) -> FrameResult | None:
        """The pipeline on one frame; an exception costs this frame only (None)."""
        try:
            result = cam.pipeline.step(image, capture_mono_us)
        except Exception as exc:  # one bad frame must not stop the service
            log.exception("pipeline failed on %s frame at %d us", cam.name, capture_mono_us)
            self._step_failed(cam, type(exc).__name__, now_mono_us)
            return None
        cam.consecutive_errors = 0
        return result

    def _step_failed(self, cam: CameraSlots, error_name: str, now_mono_us: int) -> None:
        """Camera ``cam``'s step raised ``error_name``: counted, reported, and after
        ``rebuild_after_errors`` in a row the pipeline is rebuilt."""
        self.stats.frames_failed += 1
        self.stats.faults["pipeline exception"] += 1
        cam.consecutive_errors += 1
        self.endpoint.statustext(
            d.MAV_SEVERITY_ERROR, f"TCM: pipeline error {error_name}", now_mono_us
        )
        if cam.consecutive_errors >= self.config.rebuild_after_errors:
            self._rebuild(cam)
            self.endpoint.statustext(d.MAV_SEVERITY_WARNING, "TCM: pipeline restarted", now_mono_us)

    # -- offloaded steps (the daemon's worker processes) ------------------------------------
    def offload_steps(self, enabled: bool = True) -> None:
        """From now on (``enabled``), :meth:`process_due` does not run the pipelines: it
        hands out a :class:`StepRequested` for every camera whose worker is idle and whose
        frame is due, and the driver gives each result back with :meth:`on_step_done`.
        One frame per camera is with its worker at a time; a newer frame replaces a
        waiting one as ever (dropped, counted). The default (in-process steps) is what
        the virtual-time SITL, replay and the tests run. Not with the live box feed (its
        boxes go to the pipelines in this process)."""
        if enabled and self.box_feed:
            raise ValueError("steps cannot be offloaded with a live box feed")
        self._offload = enabled
        for cam in self.cameras:  # until each worker is ready (worker_ready)
            cam.worker_up = not enabled

    @property
    def steps_offloaded(self) -> bool:
        return self._offload

    def _request(self, cam: CameraSlots, now_mono_us: int) -> StepRequested:
        """Camera ``cam``'s next frame to its worker, with the telemetry its pipeline
        would have read from the shared buffer now."""
        slot = cam.pending.pop(0)
        slot.requested_mono_us = now_mono_us
        slot.clock_offset_us = self.clock_offset_us()
        cam.in_flight = slot
        R = self.telemetry.attitude_at(slot.capture_mono_us)
        pos = self.telemetry.position_at(slot.capture_mono_us)
        return StepRequested(
            cam.camera_id,
            slot.image,
            slot.capture_mono_us,
            R,
            None if pos is None else pos[0],
            None if pos is None else pos[1],
            now_mono_us,
            cam.generation,
            self.pipeline_config,
        )

    def on_step_done(
        self, camera_id: int, result: FrameResult | None, error_name: str, now_mono_us: int
    ) -> list[FrameProcessed]:
        """Camera ``camera_id``'s worker finished the frame it was given at
        ``now_mono_us``: ``result``, or None and the exception's name ``error_name``
        (counted and reported as an in-process step's would be). Returns the
        :class:`FrameProcessed` (none for a result nobody waits for)."""
        cam = self.cameras[camera_id]
        slot = cam.in_flight
        if slot is None:
            return []
        cam.in_flight = None
        if result is None:
            self._step_failed(cam, error_name or "unknown error", now_mono_us)
        else:
            cam.consecutive_errors = 0
        return [self._finish(cam, slot, result, now_mono_us)]

    def worker_lost(self, camera_id: int, why: str, now_mono_us: int) -> None:
        """Camera ``camera_id``'s worker process is gone (``why``): a fault of that camera,
        counted and announced; its last objects go out once more as ``unknown``, the frame
        it had is failed, and the camera's frames are dropped until
        :meth:`worker_ready`."""
        cam = self.cameras[camera_id]
        cam.worker_up = False
        self.stats.faults[f"{cam.name} worker lost"] += 1
        problem = f"{cam.name} worker lost ({why})"
        self.endpoint.statustext(d.MAV_SEVERITY_WARNING, f"TCM: {problem}", now_mono_us)
        if cam.in_flight is not None:
            cam.in_flight = None
            self.stats.frames_failed += 1
        self._rig_camera_lost(cam)
        self._objects_unknown(cam, problem, now_mono_us)

    def worker_ready(self, camera_id: int, now_mono_us: int) -> None:
        """Camera ``camera_id``'s worker (re)started and takes frames."""
        cam = self.cameras[camera_id]
        if not cam.worker_up:
            self.endpoint.statustext(
                d.MAV_SEVERITY_INFO, f"TCM: {cam.name} worker restarted", now_mono_us
            )
        cam.worker_up = True

    def _objects_unknown(self, cam: CameraSlots, problem: str, now_mono_us: int) -> None:
        """Tell the autopilot once that what camera ``cam`` last reported is no longer known
        (``problem``). Stamped now: "as of now these are unknown" (the last frame is too
        old for the autopilot to accept, which is the point of saying it)."""
        if not cam.last_objects:
            return
        stale = FrameResult(-1, now_mono_us, cam.last_objects, False, None, {})
        self.endpoint.send_frame(mark_unknown(stale, problem), now_mono_us, cam.camera_id)
        cam.last_objects = ()

    def _process(self, cam: CameraSlots, now_mono_us: int) -> FrameProcessed:
        slot = cam.pending.pop(0)
        slot.boxes_used_before = self.boxes.boxes_used(cam.camera_id)
        result: FrameResult | None = self._step(cam, slot.image, slot.capture_mono_us, now_mono_us)
        return self._finish(cam, slot, result, now_mono_us)

    def _finish(
        self, cam: CameraSlots, slot: FrameSlot, result: FrameResult | None, now_mono_us: int
    ) -> FrameProcessed:
        """Everything after camera ``cam``'s step on ``slot`` (``result`` None: it failed):
        the input override, what is sent, the counters, the output for the driver."""
        if slot.waited:
            self.stats.frames_waited += 1
        result = self._fused(cam, result, now_mono_us)
        cam.last_processed_capture_mono_us = slot.capture_mono_us
        self.boxes.frame_processed(cam.camera_id, slot.waited_for_boxes, slot.boxes_used_before)
        offset = self.clock_offset_us() if slot.clock_offset_us is None else slot.clock_offset_us
        self.last_override = ""
        if result is not None:
            reason = self._blocking_input(now_mono_us)
            if reason and result.objects:
                result = mark_unknown(result, reason)
                self.last_override = reason
                self.stats.objects_unknown_by_input += len(result.objects)
            cam.last_objects = result.objects
            cam.last_capture_mono_us = slot.capture_mono_us
            self.stats.frames_processed += 1
            cam.frames_processed += 1
            if not self.endpoint.has_time_base(now_mono_us):
                # Neither TIMESYNC nor the telemetry has given us the autopilot's boot time
                # yet: a time_boot_ms of 0 would read as ancient to the autopilot, and
                # nothing is decided without its attitude anyway. Keep quiet until it has.
                self.stats.frames_without_time_base += 1
            else:
                self.endpoint.send_frame(result, now_mono_us, cam.camera_id)
                self.stats.objects_sent += len(result.objects)
                self._frame_times_mono_us.append(now_mono_us)
                if result.translation is not None:
                    self._last_translation = result.translation
        return FrameProcessed(
            cam.camera_id,
            result,
            slot.capture_mono_us,
            slot.arrival_mono_us,
            now_mono_us if slot.requested_mono_us is None else slot.requested_mono_us,
            slot.waited,
            offset,
            self.last_override,
            self.threshold(),
            float(self.endpoint.params.values["TCM_OBJ_RADIUS"]),
        )

    def _fused(
        self, cam: CameraSlots, result: FrameResult | None, now_mono_us: int
    ) -> FrameResult | None:
        """A rig's camera result as the rig reports it (:meth:`.RigTracker.fuse`: rig-wide
        ids, objects another camera measures left out); as it is with one camera."""
        if self.rig is None or result is None:
            return result
        return self.rig.fuse(cam.camera_id, result)

    def _rig_camera_lost(self, cam: CameraSlots) -> None:
        """A rig forgets what only camera ``cam`` measured (:meth:`.RigTracker.camera_lost`)
        and keeps in its last objects only those, to be sent once as unknown; what another
        camera sees too goes on there. Nothing with one camera."""
        rig = self.rig
        if rig is None:
            return
        rig.camera_lost(cam.camera_id)
        cam.last_objects = tuple(o for o in cam.last_objects if not rig.has_track(o.track_id))

    def replay_frame(
        self,
        camera_id: int,
        image: np.ndarray,
        capture_mono_us: int,
        process_mono_us: int,
        *,
        clock_offset_us: float | None,
        override: str,
    ) -> FrameResult | None:
        """Process replay (:mod:`tcm_companion.replay.log`): run camera ``camera_id``'s
        pipeline on a logged frame as the daemon did when it processed it at
        ``process_mono_us`` — with the clock offset its pipeline used then and the
        input-health override it applied (logged, because replay does not re-create the
        inputs' arrival times). Nothing is sent."""
        cam = self.cameras[camera_id]
        self.clock.force(clock_offset_us)
        # The telemetry the daemon had when it started on the frame (a worker's frame is
        # logged when it came back: the samples received meanwhile are in already).
        self.telemetry.received_by_us = int(process_mono_us)
        try:
            result = self._step(cam, image, capture_mono_us, process_mono_us)
        finally:
            self.clock.force(None)
            self.telemetry.received_by_us = None
        result = self._fused(cam, result, process_mono_us)
        # What the live box feed's later messages are judged against (late or not).
        cam.last_processed_capture_mono_us = capture_mono_us
        if result is not None and override:
            result = mark_unknown(result, override)
        return result

    def _param_problem(self, values: Mapping[str, float]) -> str:
        """Why the parameter ``values`` cannot be applied to the pipeline ("" if they can)."""
        return params_problem(self.base_pipeline_config, values)

    def _apply_params(self, now_mono_us: int) -> None:
        new = config_with_params(self.base_pipeline_config, self.endpoint.params.values)
        if new == self.pipeline_config:
            return  # an output enable or alarm level: nothing in the pipeline changes
        self.pipeline_config = new
        for cam in self.cameras:
            self._rebuild(cam)
        if self.rig is not None:  # its tracks bridge the pipelines' warm-up
            self.rig.pipeline_config = new
        self.endpoint.statustext(d.MAV_SEVERITY_INFO, "TCM: parameters applied", now_mono_us)

    def _rebuild(self, cam: CameraSlots) -> None:
        # The shared telemetry keeps the attitude history and clock fit.
        cam.pipeline = self._new_pipeline(cam.model)
        cam.consecutive_errors = 0
        cam.generation += 1
        self.stats.pipeline_rebuilds += 1

    def clock_offset_us(self) -> float:
        """The autopilot-boot-to-companion-monotonic offset (µs) the pipelines use now."""
        return float(self.clock.offset_us)

    def endpoint_stats(self) -> dict[str, int]:
        """The MAVLink endpoint's counters (malformed input, suppressed texts, ...)."""
        return dict(self.endpoint.stats)

    def link_counts(self) -> dict[str, int]:
        """What peers did that was refused or bounded (:meth:`CompanionEndpoint.link_counts`:
        signatures rejected, conflicts under the autopilot's id, rate-limited requests)."""
        return self.endpoint.link_counts()

    def threshold(self) -> float:
        return float(self.pipeline_config.classifier.tcm_threshold)

    def pipeline(self, camera_id: int) -> Pipeline:
        """Camera ``camera_id``'s pipeline now (read-only use: tests, tools)."""
        return self.cameras[camera_id].pipeline

    def last_objects(self, camera_id: int) -> tuple[ObjectResult, ...]:
        """What camera ``camera_id``'s last processed frame reported (and was sent)."""
        return self.cameras[camera_id].last_objects

    def _blocking_input(self, now_mono_us: int) -> str:
        if self.conflict:
            return self.conflict
        att = self.inputs.monitors["attitude"].status(now_mono_us)
        if not att.healthy:
            return att.problem
        if self.pipeline_config.egomotion_source == "autopilot":
            pos = self.inputs.monitors["position"].status(now_mono_us)
            if not pos.healthy:
                return pos.problem
        if self.box_feed:
            feed = self.inputs.monitors[BOX_FEED].status(now_mono_us)
            if not feed.healthy:
                return feed.problem
        return ""

    # -- once a second ---------------------------------------------------------------------
    def _health_check(self, now_mono_us: int) -> HealthChecked:
        if self._log_behind > self._log_behind_reported:
            # The disk (or the writer) cannot keep up: say so, once in a while.
            frames = self._log_frames_lost
            self.endpoint.statustext(
                d.MAV_SEVERITY_WARNING,
                f"TCM: log behind, {frames} frames, {self._log_behind - frames} msgs lost",
                now_mono_us,
            )
            self._log_behind_reported = self._log_behind
        changes = self.check_inputs(now_mono_us)
        st = self.inputs.status(now_mono_us)
        return HealthChecked(
            now_mono_us,
            tuple(changes),
            self.status_line(now_mono_us),
            self.health_report(now_mono_us),
            {k: v.problem for k, v in st.items()},
        )

    def check_inputs(self, now_mono_us: int) -> list[tuple[str, str]]:
        """The input part of the health check (run by :meth:`process_due` once a
        second); returns the input changes ``(input, problem)`` it reported, and
        ``("pipeline", problem)`` when the pipeline starts or stops being overloaded."""
        # Once per condition (Inputs.changes): a slow camera whose measured rate moves
        # from 8 to 9 Hz is the same fault, not a new one to count, announce and clear
        # the objects for.
        changes = self.inputs.changes(now_mono_us)
        for name, problem in changes:
            if problem and self.inputs.condition(name) == "waiting":
                # A start-up state (no position before the EKF origin), not a fault.
                self.endpoint.statustext(
                    d.MAV_SEVERITY_INFO, f"TCM: {problem}", now_mono_us, key=f"input {name}"
                )
            elif problem:
                condition = self.inputs.condition(name)
                self.stats.faults[f"{name} {condition}"] += 1
                self.endpoint.statustext(
                    d.MAV_SEVERITY_WARNING,
                    f"TCM: {problem}",
                    now_mono_us,
                    key=f"input {name} {condition}",
                )
                # The box feed's boxes are every camera's objects.
                cams = (
                    self.cameras
                    if name == BOX_FEED
                    else [c for c in self.cameras if c.name == name]
                )
                for cam in cams:
                    if name != BOX_FEED:
                        self._rig_camera_lost(cam)
                    self._objects_unknown(cam, problem, now_mono_us)
            else:
                self.endpoint.statustext(d.MAV_SEVERITY_INFO, f"TCM: {name} OK", now_mono_us)
        if self.box_feed:
            self.boxes.report(now_mono_us)
        overload = self.overload_problem(now_mono_us)
        if bool(overload) != self._overloaded:
            # One fault per overloaded spell, however the managed rate moves meanwhile.
            self._overloaded = bool(overload)
            if overload:
                self.stats.faults["pipeline overloaded"] += 1
                self.endpoint.statustext(
                    d.MAV_SEVERITY_WARNING, f"TCM: {overload}", now_mono_us, key="overload"
                )
            else:
                self.endpoint.statustext(
                    d.MAV_SEVERITY_INFO, "TCM: pipeline keeping up", now_mono_us
                )
            changes = [*changes, ("pipeline", overload)]
        self.endpoint.set_health(self.health_report(now_mono_us))
        return changes

    def box_feed_counts(self) -> dict[str, int]:
        """The live box feed's counters: :meth:`.LiveBoxes.all_counts`."""
        return self.boxes.all_counts()

    def health_flags(self, now_mono_us: int) -> int:
        st = self.inputs.status(now_mono_us)
        flags = 0
        if any(not st[c.name].healthy or not c.worker_up for c in self.cameras):
            flags |= d.TCM_HEALTH_CAMERA_LOST
        if not st["attitude"].healthy:
            flags |= d.TCM_HEALTH_ATTITUDE_STALE
        if not st["position"].healthy:
            flags |= d.TCM_HEALTH_POSITION_STALE
        ts = self.endpoint.timesync
        if not ts.fresh(now_mono_us):  # one rule for "fresh": timesync.FRESH_US
            flags |= d.TCM_HEALTH_TIMESYNC_LOST
        if self._dropped_recently(now_mono_us):
            flags |= d.TCM_HEALTH_OVERLOADED
        if self.log_state == d.TCM_LOG_STATE_FAULT:
            flags |= d.TCM_HEALTH_LOG_FAULT
        return flags | self.endpoint.link_health_flags(now_mono_us)

    def frame_rate_hz(self, now_mono_us: int) -> float:
        recent = [t for t in self._frame_times_mono_us if now_mono_us - t <= 2_000_000]
        if len(recent) < 2:
            return 0.0
        span = recent[-1] - recent[0]
        return (len(recent) - 1) / (span / 1e6) if span > 0 else 0.0

    def health_report(self, now_mono_us: int) -> HealthReport:
        tr = self._last_translation
        p50 = latency_percentile_ms(self.latencies_ms, 50) if self.latencies_ms else 0.0
        return HealthReport(
            frame_rate_hz=self.frame_rate_hz(now_mono_us),
            latency_ms=p50,
            frames_dropped=self.stats.frames_dropped,
            egomotion_source=egomotion_source_code(tr),
            egomotion_quality_pct=egomotion_quality_pct(tr),
            health_flags=self.health_flags(now_mono_us),
            objects=sum(len(c.last_objects) for c in self.cameras),
            log_state=self.log_state,
        )

    def status_line(self, now_mono_us: int) -> str:
        """One line: objects and states, nearest TTC, fps, latency, drops, problems."""
        problems = [s.problem for s in self.inputs.status(now_mono_us).values() if s.problem]
        problems += [f"{c.name} worker down" for c in self.cameras if not c.worker_up]
        overload = self.overload_problem(now_mono_us)
        if overload:
            problems.append(overload)
        if self.conflict:
            problems.append(self.conflict)
        starting = (
            len(self._frame_times_mono_us) < 2 and now_mono_us - self._started_mono_us < 2_000_000
        )
        return status_line_text(
            [o for c in self.cameras for o in c.last_objects],
            None if starting else self.frame_rate_hz(now_mono_us),
            self.latencies_ms,
            f"{self.stats.frames_dropped}{self.boxes.status()}",
            problems,
        )
