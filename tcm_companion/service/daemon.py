"""The flight daemon: camera threads and the MAVLink link around one :class:`Companion`.

Everything here is plumbing; the decisions are in :mod:`.companion`.

- One reader thread per camera (:class:`~tcm_companion.io.cameras.reader.CameraReader`)
  blocks in the camera's ``read()``, stamps the capture time on the monotonic clock and
  hands the frame to the event loop with ``call_soon_threadsafe``.
- Each camera has a one-frame slot: a frame that arrives while the previous one still
  waits replaces it, and the replaced one is counted as dropped. Stale frames are never
  queued.
- The processing task takes the newest frame of each camera, waits (briefly, bounded)
  for the attitude sample after it when the attitude is behind, runs the pipeline on
  the loop thread and flushes the frame's MAVLink output at once.
- The health task runs every second: input health, the health message, STATUSTEXT on
  changes, the systemd watchdog ping (only while every task and camera thread is alive)
  and the status line.
- Shutdown (SIGTERM/SIGINT, or ``stop``): the tasks of a ``TaskGroup`` end, then an
  ``AsyncExitStack`` undoes the start-up in reverse — notify STOPPING, stop the camera
  threads, persist parameters and the signing timestamp, close the link.

Frame accounting always closes: ``captured = processed + failed + dropped + rejected``
(rejected: empty or wrong-sized frames refused by the reader; dropped: superseded, or
still waiting at shutdown).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import cv2
import numpy as np

from ..config import AppConfig
from ..core.camera import CameraModel
from ..core.pipeline import FrameResult
from ..io.aio import wait_event
from ..io.allocator import trim_heap
from ..io.cameras.base import CameraStats, Frame, FrameSource
from ..io.transports import Transport, open_transport
from ..mavlink import tcm_dialect as d
from ..mavlink.endpoint import CompanionEndpoint, Event, ParamChanged, TelemetryReceived
from ..mavlink.link import CompanionLink, monotonic_us
from ..mavlink.setup import make_endpoint, persist
from .companion import Companion, CompanionStats

log = logging.getLogger(__name__)


class NotifierLike(Protocol):
    """What the daemon needs of :class:`tcm_companion.io.sdnotify.Notifier`."""

    def ready(self, status: str = "") -> Any: ...
    def status(self, text: str) -> Any: ...
    def watchdog(self) -> Any: ...
    def stopping(self) -> Any: ...


class FlightLogLike(Protocol):
    """What the daemon needs of :class:`tcm_companion.io.flightlog.FlightLogWriter`:
    non-blocking producers (False = dropped and counted by the writer)."""

    def log_frame(self, camera_id: int, t_capture_us: int, image: np.ndarray) -> bool: ...
    def log_annotations(
        self, camera_id: int, t_capture_us: int, circles: list[tuple[float, float, float, str]]
    ) -> bool: ...
    def log_mavlink(self, direction: Any, t_us: int, data: bytes) -> bool: ...
    def log_json(self, topic: str, t_us: int, doc: dict[str, Any]) -> bool: ...


class _NoNotifier:
    def ready(self, status: str = "") -> None:
        pass

    def status(self, text: str) -> None:
        pass

    def watchdog(self) -> None:
        pass

    def stopping(self) -> None:
        pass


@dataclass
class CameraInput:
    """One camera as the daemon runs it: its model (for the pipeline) and its source."""

    name: str
    model: CameraModel
    source: FrameSource


@dataclass
class DaemonSummary:
    """What a run did; the frame counts always add up (see the module docstring)."""

    duration_s: float
    captured: int
    processed: int
    failed: int
    dropped: int
    rejected: int
    latencies_ms: list[float]
    stats: CompanionStats
    camera_stats: dict[str, CameraStats]
    endpoint_stats: dict[str, int]
    watchdog_pings: int
    watchdog_withheld: int
    faults: dict[str, int] = field(default_factory=dict)
    stage_ms: dict[str, list[float]] = field(default_factory=dict)

    @property
    def frames_balance(self) -> bool:
        return self.captured == self.processed + self.failed + self.dropped + self.rejected

    def latency_percentile_ms(self, q: float) -> float:
        if not self.latencies_ms:
            return float("nan")
        return float(np.percentile(np.asarray(self.latencies_ms), q))


def _format_status(companion: Companion, now_us: int, latencies: Sequence[float]) -> str:
    """One line: objects and states, nearest TTC, fps, latency, drops, faults."""
    objs = [o for c in companion.cameras for o in c.last_objects]
    states: dict[str, int] = {}
    for o in objs:
        states[o.state] = states.get(o.state, 0) + 1
    ttcs = [o.ttc_s for o in objs if o.ttc_s == o.ttc_s]
    st = ", ".join(f"{n} {s}" for s, n in sorted(states.items())) or "none"
    lat = sorted(latencies)
    p99 = lat[min(len(lat) - 1, int(0.99 * len(lat)))] if lat else float("nan")
    p50 = lat[len(lat) // 2] if lat else float("nan")
    problems = [s.problem for s in companion.inputs.status(now_us).values() if s.problem]
    return (
        f"objects {len(objs)} ({st}) | TTC {min(ttcs):.1f}s | "
        if ttcs
        else f"objects {len(objs)} ({st}) | "
    ) + (
        f"{companion.frame_rate_hz(now_us):4.1f} fps | latency p50 {p50:.1f} p99 {p99:.1f} ms | "
        f"drops {companion.stats.frames_dropped} | "
        + ("; ".join(problems) if problems else "inputs OK")
    )


class Daemon:
    """``tcm-companion run``: cameras + pipeline + MAVLink until stopped.

    ``transport`` and ``endpoint`` default to what ``config.mavlink`` describes; tests
    and SITL pass their own. ``on_result`` sees every processed frame (SITL scores them),
    ``on_status`` the status line once a second.
    """

    def __init__(
        self,
        config: AppConfig,
        cameras: Sequence[CameraInput],
        *,
        transport: Transport | None = None,
        endpoint: CompanionEndpoint | None = None,
        notifier: NotifierLike | None = None,
        watchdog_interval_us: int | None = None,
        clock_us: Callable[[], int] = monotonic_us,
        on_result: Callable[[int, FrameResult], None] | None = None,
        on_status: Callable[[str], None] | None = None,
        flight_log: FlightLogLike | None = None,
        log_state: Callable[[], tuple[int, dict[str, Any]]] | None = None,
        persist_params: bool = False,
    ) -> None:
        if not cameras:
            raise ValueError("the daemon needs at least one camera")
        self.config = config
        self.camera_inputs = list(cameras)
        self._transport = transport
        self._endpoint = endpoint
        self.notifier: NotifierLike = notifier or _NoNotifier()
        self.clock_us = clock_us
        self.on_result = on_result
        self.on_status = on_status
        self.flight_log = flight_log
        # Write parameter changes to config.mavlink's files at once (always when the
        # daemon made the endpoint from the configuration itself).
        self._persist_params = persist_params
        self._log_dropped_reported = 0
        # () -> (TCM_LOG_STATE, stats for the health log); the writer's, when logging.
        self.log_state = log_state
        interval = config.daemon.health_interval_us
        if watchdog_interval_us is not None:
            interval = min(interval, watchdog_interval_us)
        self.health_interval_us = interval
        self.companion: Companion | None = None
        self.link: CompanionLink | None = None
        self.readers: list[Any] = []
        self.latencies_ms: deque[float] = deque(maxlen=200_000)
        self._pending: list[Frame | None] = [None] * len(self.camera_inputs)
        self._arrival_us: list[int] = [0] * len(self.camera_inputs)
        # Where the capture-to-output time goes, per frame (ms): camera thread to loop,
        # waiting in the slot (incl. for the attitude), the pipeline, the link write.
        self.stage_ms: dict[str, deque[float]] = {
            k: deque(maxlen=200_000) for k in ("handoff", "queue", "pipeline", "send")
        }
        self._frame_event = asyncio.Event()
        self._telemetry_event = asyncio.Event()
        self._handoff_failures = 0
        self._pending_at_stop = 0
        self.watchdog_pings = 0
        self.watchdog_withheld = 0
        self._tasks: list[asyncio.Task[Any]] = []

    # -- frames from the camera threads -------------------------------------------------
    def _make_on_frame(self, loop: asyncio.AbstractEventLoop) -> Callable[[Frame], None]:
        def on_frame(frame: Frame) -> None:  # runs on a camera thread
            try:
                loop.call_soon_threadsafe(self._on_frame, frame)
            except RuntimeError:  # the loop is closing: the frame is lost, but counted
                self._handoff_failures += 1

        return on_frame

    def _on_frame(self, frame: Frame) -> None:
        assert self.companion is not None
        now = self.clock_us()
        cid = frame.camera_id
        self.companion.note_frame_arrival(cid, now)
        if self._pending[cid] is not None:
            self.companion.note_drop(now)  # the older frame is stale: never queue it
        self._pending[cid] = frame
        self._arrival_us[cid] = now
        if self.flight_log is not None:
            # Every delivered frame, processed or not: the log shows what the camera saw.
            self.flight_log.log_frame(cid, frame.t_capture_us, frame.image)
        self._frame_event.set()

    # -- events from the link --------------------------------------------------------------
    def _on_event(self, ev: Event) -> None:
        assert self.companion is not None
        now = self.clock_us()
        self.companion.handle_events([ev], now)
        if isinstance(ev, TelemetryReceived):
            self._telemetry_event.set()
        elif isinstance(ev, ParamChanged):
            if self.flight_log is not None:
                self.flight_log.log_json("/tcm/param", now, {"name": ev.name, "value": ev.value})
            with contextlib.suppress(OSError):
                if self._persist_params:
                    persist(self.config.mavlink, self.companion.endpoint)

    # -- tasks -------------------------------------------------------------------------------
    async def _process_loop(self) -> None:
        comp = self.companion
        link = self.link
        assert comp is not None and link is not None
        while True:
            await self._frame_event.wait()
            self._frame_event.clear()
            for cid in range(len(self._pending)):
                frame = self._pending[cid]
                if frame is None:
                    continue
                deadline = comp.frame_deadline_us(cid, frame.t_capture_us)
                if deadline is not None:
                    comp.stats.frames_waited += 1
                    while True:
                        remaining = deadline - self.clock_us()
                        if remaining <= 0:
                            break
                        self._telemetry_event.clear()
                        if not await wait_event(self._telemetry_event, remaining / 1e6):
                            break
                        if comp.frame_deadline_us(cid, frame.t_capture_us) is None:
                            break
                    frame = self._pending[cid]  # a newer frame may have replaced it
                    if frame is None:
                        continue
                self._pending[cid] = None
                arrived = self._arrival_us[cid]
                now = self.clock_us()
                result = comp.process(cid, frame.image, frame.t_capture_us, now)
                done = self.clock_us()
                if result is not None and self.flight_log is not None:
                    # Logged before anything else can run (the write below yields to the
                    # loop): what the pipeline used — the clock offset, the telemetry up to
                    # here — is then exactly what replay sees before this record.
                    self._log_result(cid, result, now, done - frame.t_capture_us)
                await link.flush()
                if result is not None:
                    sent = self.clock_us()
                    latency = sent - frame.t_capture_us
                    comp.record_latency(latency)
                    self.latencies_ms.append(latency / 1000.0)
                    st = self.stage_ms
                    st["handoff"].append((arrived - frame.t_capture_us) / 1000.0)
                    st["queue"].append((now - arrived) / 1000.0)
                    st["pipeline"].append((done - now) / 1000.0)
                    st["send"].append((sent - done) / 1000.0)
                    if self.on_result is not None:
                        self.on_result(cid, result)

    def _log_result(
        self, cid: int, result: FrameResult, t_process_us: int, latency_us: int
    ) -> None:
        from .logdocs import annotation_circles, result_doc

        comp = self.companion
        assert comp is not None and self.flight_log is not None
        doc = result_doc(
            cid,
            result,
            threshold=comp.threshold(),
            t_process_us=t_process_us,
            override=comp.last_override,
            clock_offset_us=comp.clock_offset_us(cid),
            latency_ms=latency_us / 1000.0,
            object_radius_m=comp.endpoint.params.values["TCM_OBJ_RADIUS"],
        )
        self.flight_log.log_json("/tcm/result", t_process_us, doc)
        model = self.camera_inputs[cid].model
        self.flight_log.log_annotations(cid, result.t_us, annotation_circles(result, model))

    def _loop_healthy(self) -> tuple[bool, str]:
        for task in self._tasks:
            if task.done():
                return False, f"task {task.get_name()} ended"
        for reader in self.readers:
            if not reader.alive and not reader.stats.ended:
                return False, f"camera thread {reader.source.name} died"
        return True, ""

    async def _health_loop(self) -> None:
        comp = self.companion
        assert comp is not None and self.link is not None
        ticks = 0
        while True:
            await asyncio.sleep(self.health_interval_us / 1e6)
            ticks += 1
            if ticks in (1, 5):
                # Start-up is over (imports, renderer or camera set-up, first frames):
                # return what it used to the kernel, so RSS is the steady state.
                trim_heap()
            now = self.clock_us()
            if self.log_state is not None:
                comp.log_state, log_stats = self.log_state()
                frames = int(log_stats.get("frames_dropped_queue", 0))
                behind = frames + int(log_stats.get("messages_dropped_queue", 0))
                if behind > self._log_dropped_reported:
                    # The disk (or the writer) cannot keep up: say so, once in a while.
                    comp.endpoint.statustext(
                        d.MAV_SEVERITY_WARNING,
                        f"TCM: log behind, {frames} frames, {behind - frames} msgs lost",
                        now,
                    )
                    self._log_dropped_reported = behind
            for name, problem in comp.tick(now):
                if problem:
                    log.warning("input %s: %s", name, problem)
                else:
                    log.info("input %s: OK", name)
                if self.flight_log is not None:
                    self.flight_log.log_json(
                        "/tcm/event",
                        now,
                        {
                            "severity": "warning" if problem else "info",
                            "input": name,
                            "text": problem or f"{name} OK",
                        },
                    )
            self.link.wake()
            healthy, why = self._loop_healthy()
            if healthy:
                self.notifier.watchdog()
                self.watchdog_pings += 1
            else:
                self.watchdog_withheld += 1
                log.error("not pinging the watchdog: %s", why)
            line = _format_status(comp, now, list(comp.latencies_ms))
            if self.flight_log is not None:
                rep = comp.health_report(now)
                st = comp.inputs.status(now)
                self.flight_log.log_json(
                    "/tcm/health",
                    now,
                    {
                        "frame_rate_hz": rep.frame_rate_hz,
                        "latency_ms": rep.latency_ms,
                        "frames_dropped": rep.frames_dropped,
                        "health_flags": rep.health_flags,
                        "egomotion_quality_pct": rep.egomotion_quality_pct,
                        "inputs": {k: v.problem for k, v in st.items()},
                        "status": line,
                        "log": log_stats if self.log_state is not None else {},
                    },
                )
            self.notifier.status(line)
            if self.on_status is not None:
                self.on_status(line)

    # -- the whole run -------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event | None = None) -> DaemonSummary:
        """Run until ``stop`` is set (or a fatal error); returns the run's summary."""
        from ..io.cameras.reader import CameraReader

        stop = stop if stop is not None else asyncio.Event()
        loop = asyncio.get_running_loop()
        t0 = self.clock_us()
        if self.config.daemon.opencv_threads:
            cv2.setNumThreads(self.config.daemon.opencv_threads)
        # A camera thread that wakes with a frame needs the GIL; by default it may wait
        # 5 ms for the loop thread to let go. A shorter switch interval bounds that wait
        # (handoff p50 2.3 ms -> see docs/daemon.md for the measurement).
        sys.setswitchinterval(self.config.daemon.gil_switch_interval_us / 1e6)
        async with contextlib.AsyncExitStack() as stack:
            # MAVLink: endpoint (persisted params, signing) and the transport.
            endpoint = self._endpoint
            if endpoint is None:
                endpoint, warnings = make_endpoint(self.config.mavlink, t0)
                self._persist_params = True
                for w in warnings:
                    log.warning("%s", w)
                stack.callback(persist, self.config.mavlink, endpoint)
            transport = self._transport
            if transport is None:
                transport = open_transport(self.config.mavlink.url, reconnect=True)
                await transport.open()
                stack.push_async_callback(transport.close)
            self.companion = Companion(
                [c.model for c in self.camera_inputs],
                self.config.pipeline,
                endpoint,
                t0,
                self.config.daemon,
                [c.name for c in self.camera_inputs],
            )
            on_bytes: Callable[[str, int, bytes], object] | None = None
            if self.flight_log is not None:
                on_bytes = self.flight_log.log_mavlink
            self.link = CompanionLink(
                transport, endpoint, self._on_event, self.clock_us, on_bytes=on_bytes
            )

            # Cameras: one reader thread each; stopped (joined) on the way out.
            on_frame = self._make_on_frame(loop)
            for cid, cam in enumerate(self.camera_inputs):
                reader = CameraReader(
                    cam.source,
                    cid,
                    on_frame,
                    clock_us=self.clock_us,
                )
                self.readers.append(reader)
                reader.start()
                stack.callback(reader.stop)
            stack.callback(self.notifier.stopping)
            self.notifier.ready(
                f"running: {len(self.camera_inputs)} camera(s), link {transport.url}"
            )
            log.info("running: %d camera(s), link %s", len(self.camera_inputs), transport.url)

            try:
                async with asyncio.TaskGroup() as tg:
                    self._tasks = [
                        tg.create_task(self.link.run(), name="link"),
                        tg.create_task(self._process_loop(), name="process"),
                        tg.create_task(self._health_loop(), name="health"),
                    ]
                    await stop.wait()
                    self.link.stop()
                    for task in self._tasks[1:]:
                        task.cancel()
            finally:
                # Stop the cameras first, then let the frames they handed over in the
                # meantime land in their slots, so every delivered frame is accounted for.
                for reader in self.readers:
                    reader.stop()
                for _ in range(3):
                    await asyncio.sleep(0)
                self._pending_at_stop = sum(1 for f in self._pending if f is not None)
                self._pending = [None] * len(self._pending)
        return self._summary(t0)

    def _summary(self, t0_us: int) -> DaemonSummary:
        comp = self.companion
        assert comp is not None
        cam_stats = {r.source.name: r.stats for r in self.readers}
        captured = sum(s.captured for s in cam_stats.values())
        rejected = sum(s.rejected_empty + s.rejected_size for s in cam_stats.values())
        dropped = comp.stats.frames_dropped + self._pending_at_stop + self._handoff_failures
        return DaemonSummary(
            duration_s=(self.clock_us() - t0_us) / 1e6,
            captured=captured,
            processed=comp.stats.frames_processed,
            failed=comp.stats.frames_failed,
            dropped=dropped,
            rejected=rejected,
            latencies_ms=list(self.latencies_ms),
            stats=comp.stats,
            camera_stats=cam_stats,
            endpoint_stats=dict(comp.endpoint.stats),
            watchdog_pings=self.watchdog_pings,
            watchdog_withheld=self.watchdog_withheld,
            faults=dict(comp.stats.faults),
            stage_ms={k: list(v) for k, v in self.stage_ms.items()},
        )
