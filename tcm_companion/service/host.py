"""What a driver of the :class:`~.companion.Companion` does besides moving bytes and frames.

The asyncio daemon (:mod:`.daemon`) and the virtual-time SITL (:mod:`tcm_companion.sitl.virtual`)
differ only in where frames and bytes come from and which clock runs; everything they do
with the Companion's inputs and outputs is here, once:

- a delivered frame goes to the Companion's slot and to the flight log;
- link bytes are logged (in and out, with their times) and fed to the Companion;
- a processed frame's result and annotations are logged *before* its bytes are written
  (replay needs every byte received up to the processing in the log before the result),
  and after the write its latency, stage times and ``on_result`` are recorded;
- parameter changes are logged and persisted;
- the once-a-second health check becomes log records, the systemd watchdog ping (only
  while ``loop_healthy()``), the status line (systemd and ``on_status``), and the
  flight log's own state and reports go back to the Companion;
- the run's :class:`DaemonSummary`.

Every time is µs on the companion monotonic clock (``_mono_us``) the driver runs on.
"""

from __future__ import annotations

import logging
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..core.camera import CameraModel
from ..core.pipeline import FrameResult
from ..flightlog import topics
from ..io.allocator import trim_heap
from ..io.cameras.base import CameraStats, Frame, FrameSource
from ..mavlink import tcm_dialect as d
from .companion import Companion
from .health import CompanionStats, latency_percentile_ms
from .outputs import FrameProcessed, HealthChecked, Output, ParamsChanged

if TYPE_CHECKING:
    from ..flightlog.handle import FlightLog

log = logging.getLogger("tcm_companion.service.daemon")


class NotifierLike(Protocol):
    """What the daemon needs of :class:`tcm_companion.io.sdnotify.Notifier`."""

    def ready(self, status: str = "") -> Any: ...
    def status(self, text: str) -> Any: ...
    def watchdog(self) -> Any: ...
    def stopping(self) -> Any: ...


class NoNotifier:
    """Not under systemd: nobody to notify."""

    def ready(self, status: str = "") -> None:
        pass

    def status(self, text: str) -> None:
        pass

    def watchdog(self) -> None:
        pass

    def stopping(self) -> None:
        pass


STAT_SAMPLES = 200_000
#: Per camera, the newest latencies kept for the run's summary (13 min at 25 Hz).
CAMERA_STAT_SAMPLES = 20_000


class SampleRing:
    """The newest ``capacity`` samples of a float series (ms), in one float64 array
    allocated and written once when made: the memory a run's statistics take is fixed
    from the start (8 bytes a sample). A ``deque`` of Python floats grew by ~32 bytes a
    sample until full, ~14 MB an hour for the daemon's five series at 25 Hz, which made the
    daemon's RSS creep (issue 15: flat over 10 minutes)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be positive, got {capacity}")
        self._buf = np.empty(capacity, dtype=np.float64)
        self._buf.fill(0.0)  # touch every page now, not one sample at a time
        self._count = 0  # samples appended since made (or cleared)

    def append(self, value: float) -> None:
        self._buf[self._count % self._buf.size] = value
        self._count += 1

    def clear(self) -> None:
        self._count = 0

    def __len__(self) -> int:
        return min(self._count, self._buf.size)

    def values(self) -> np.ndarray:
        """The kept samples, oldest first (a copy)."""
        size = self._buf.size
        if self._count <= size:
            return self._buf[: self._count].copy()
        head = self._count % size
        return np.concatenate((self._buf[head:], self._buf[:head]))

    def tolist(self) -> list[float]:
        return list(self.values().tolist())


@dataclass
class CameraInput:
    """One camera as the daemon runs it: its model (for the pipeline), its source, and
    the frame rate it is set to (the application's ``[camera] fps``): its input is
    ``slow`` below half of that."""

    name: str
    model: CameraModel
    source: FrameSource
    fps: float = 25.0


@dataclass
class DaemonSummary:
    """What a run did; the frame counts always add up:
    ``captured = processed + failed + dropped + rejected`` (rejected: empty or
    wrong-sized frames refused by the reader; dropped: superseded, or still waiting at
    shutdown)."""

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
    # The live box feed's counters (Companion.box_feed_counts; empty without a feed).
    box_feed: dict[str, int] = field(default_factory=dict)
    # What peers on the MAVLink link did that was refused or bounded (Companion.link_counts:
    # "signature rejected", "autopilot conflicts", "... rate-limited"; empty: nothing).
    link: dict[str, int] = field(default_factory=dict)
    # Each camera's name and frames processed (sent), in camera-id order (camera_stats is
    # in the same order).
    camera_names: list[str] = field(default_factory=list)
    processed_per_camera: list[int] = field(default_factory=list)
    # Per camera (by name): processed, dropped, latency_p50_ms, latency_p99_ms.
    per_camera: dict[str, dict[str, float]] = field(default_factory=dict)
    # The worker processes' counters (service/workers.py; empty: in-process).
    workers: dict[str, Any] = field(default_factory=dict)
    dropped_at_stop: int = 0  # of ``dropped``: still waiting (or with a worker) at the stop

    @property
    def frames_balance(self) -> bool:
        return self.captured == self.processed + self.failed + self.dropped + self.rejected

    def frames_text(self) -> str:
        """``captured 100 = processed 97 + dropped 2 + failed 1 + rejected 0``."""
        return (
            f"captured {self.captured} = processed {self.processed} + dropped {self.dropped}"
            f" + failed {self.failed} + rejected {self.rejected}"
        )

    def latency_percentile_ms(self, q: float) -> float:
        """:func:`~.health.latency_percentile_ms` of the run's latencies."""
        return latency_percentile_ms(self.latencies_ms, q)


def run_length_text(duration_s: float, planned_s: float | None, stopped_by: str = "") -> str:
    """How long a run went, for its summary. ``stopped_by``: "" (it ran its planned time),
    ``"stop"`` (its caller stopped it) or the signal that ended it (``"SIGINT"``):

    - ``20.0 s`` — its whole time;
    - ``interrupted after 7.0 of 30 s (SIGINT)`` — a signal cut it short;
    - ``stopped after 7.0 s (SIGTERM)`` — a service without a planned time, stopped the
      normal way; ``stopped after 7.0 of 30 s`` — its caller stopped it.
    """
    if not stopped_by:
        return f"{duration_s:.1f} s"
    of = " s" if planned_s is None else f" of {planned_s:.3f}".rstrip("0").rstrip(".") + " s"
    if stopped_by == "stop":
        return f"stopped after {duration_s:.1f}{of}"
    word = "stopped" if stopped_by == "SIGTERM" and planned_s is None else "interrupted"
    return f"{word} after {duration_s:.1f}{of} ({stopped_by})"


class CompanionHost:
    """The driver-independent part of running a :class:`Companion` (module docstring)."""

    def __init__(
        self,
        companion: Companion,
        cameras: Sequence[CameraInput],
        *,
        flight_log: FlightLog | None = None,
        notifier: NotifierLike | None = None,
        on_result: Callable[[int, FrameResult], None] | None = None,
        on_status: Callable[[str], None] | None = None,
        persist: Callable[[], None] | None = None,
        loop_healthy: Callable[[], tuple[bool, str]] = lambda: (True, ""),
    ) -> None:
        self.companion = companion
        self.cameras = list(cameras)
        self.flight_log = flight_log
        self.notifier: NotifierLike = notifier or NoNotifier()
        self.on_result = on_result
        self.on_status = on_status
        self.persist = persist
        self.loop_healthy = loop_healthy
        # Two hours and more at 25 Hz of each series, for the run's summary.
        self.latencies_ms = SampleRing(STAT_SAMPLES)
        # Where the capture-to-output time goes, per frame (ms): camera to the Companion,
        # waiting in the slot (incl. for the attitude), the pipeline, the link write.
        self.stage_ms: dict[str, SampleRing] = {
            k: SampleRing(STAT_SAMPLES) for k in ("handoff", "queue", "pipeline", "send")
        }
        # By camera id (a host given no camera descriptions, as tests build one, still counts).
        self.camera_latencies_ms: defaultdict[int, SampleRing] = defaultdict(
            lambda: SampleRing(CAMERA_STAT_SAMPLES)
        )
        self.watchdog_pings = 0
        self.watchdog_withheld = 0
        self.health_checks = 0
        self.processed_by_camera: Counter[int] = Counter()  # frames sent, by camera id
        self._log_doc: dict[str, Any] = {}

    # -- inputs ---------------------------------------------------------------------------
    def frame_arrived(self, frame: Frame, now_mono_us: int) -> None:
        """A camera delivered ``frame`` (its reader's ``on_frame``, on the driver's loop)."""
        self.companion.on_frame(frame.camera_id, frame.image, frame.t_capture_us, now_mono_us)
        if self.flight_log is not None:
            # Every delivered frame, processed or not: the log shows what the camera saw.
            self.flight_log.log_frame(frame.camera_id, frame.t_capture_us, frame.image)

    def box_datagram(self, data: bytes, now_mono_us: int) -> None:
        """A datagram of the live box feed arrived at ``now_mono_us`` (docs/box-feed.md);
        logged first (process replay feeds it to the Companion again, in order)."""
        if self.flight_log is not None:
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                pass  # malformed: it changes nothing but a counter
            else:
                self.flight_log.log_json(topics.BOXES, now_mono_us, {"datagram": text})
        self.companion.on_box_datagram(data, now_mono_us)

    def bytes_received(self, data: bytes, now_mono_us: int) -> None:
        """Bytes read from the autopilot link at ``now_mono_us``."""
        if self.flight_log is not None:
            self.flight_log.log_mavlink("in", now_mono_us, data)
        self.processed(self.companion.receive_data(data, now_mono_us), now_mono_us)

    # -- one turn of the driver's loop ----------------------------------------------------------
    def process_due(self, now_mono_us: int) -> list[Output]:
        """:meth:`Companion.process_due`, with the flight log's news handed in first."""
        comp = self.companion
        fl = self.flight_log
        if fl is not None:
            while not fl.events.empty():
                severity, text = fl.events.get_nowait()
                sev = d.MAV_SEVERITY_INFO if severity == "info" else d.MAV_SEVERITY_WARNING
                comp.report(sev, f"TCM: {text}", now_mono_us)
            if comp.health_due(now_mono_us):
                code, self._log_doc = fl.state()
                comp.set_log_state(
                    code,
                    int(self._log_doc.get("frames_dropped_queue", 0)),
                    int(self._log_doc.get("messages_dropped_queue", 0)),
                )
        return comp.process_due(now_mono_us)

    def processed(self, outputs: Sequence[Output], done_mono_us: int) -> None:
        """Handle ``outputs``; ``done_mono_us``: when the turn's work (the pipeline)
        finished. A turn's outputs go through :meth:`written`, once its bytes are out."""
        for out in outputs:
            if isinstance(out, FrameProcessed):
                if out.result is not None and self.flight_log is not None:
                    self._log_result(out, done_mono_us)
            elif isinstance(out, ParamsChanged):
                if self.flight_log is not None:
                    self.flight_log.log_json(
                        topics.PARAM, out.now_mono_us, {"name": out.name, "value": out.value}
                    )
                if self.persist is not None:
                    try:
                        self.persist()
                    except OSError as exc:
                        log.warning("cannot persist parameters: %s", exc)
            elif isinstance(out, HealthChecked):
                self.health_checked(out)

    def bytes_to_send(self, now_mono_us: int) -> bytes:
        """What the Companion has for the link, logged as written at ``now_mono_us``."""
        data = self.take_bytes()
        self._log_out(data, now_mono_us)
        return data

    def take_bytes(self) -> bytes:
        """A turn's bytes for the link, to be written at once; :meth:`written` then logs
        them and handles the turn's outputs."""
        return self.companion.data_to_send()

    def written(
        self, outputs: Sequence[Output], data: bytes, done_mono_us: int, sent_mono_us: int
    ) -> None:
        """A turn's bytes ``data`` (from :meth:`take_bytes`) went out at ``sent_mono_us``:
        log them as written when the work was ``done_mono_us``, then handle the outputs
        (:meth:`processed`: flight-log records, parameters saved, health) and the
        latencies (:meth:`sent`). After the write, not before: each record queued for the
        flight log wakes its writer thread, which takes the GIL, and saving parameters
        touches the disk; neither may delay what the autopilot is waiting for."""
        self._log_out(data, done_mono_us)
        self.processed(outputs, done_mono_us)
        self.sent(outputs, done_mono_us, sent_mono_us)

    def sent(self, outputs: Sequence[Output], done_mono_us: int, sent_mono_us: int) -> None:
        """The turn's bytes were written at ``sent_mono_us``: latencies and ``on_result``."""
        for out in outputs:
            if not isinstance(out, FrameProcessed) or out.result is None:
                continue
            self.processed_by_camera[out.camera_id] += 1
            latency_ms = self.companion.frame_sent(out, sent_mono_us)
            if latency_ms is not None:
                self.latencies_ms.append(latency_ms)
                self.camera_latencies_ms[out.camera_id].append(latency_ms)
            st = self.stage_ms
            st["handoff"].append((out.arrival_mono_us - out.capture_mono_us) / 1000.0)
            st["queue"].append((out.process_mono_us - out.arrival_mono_us) / 1000.0)
            st["pipeline"].append((done_mono_us - out.process_mono_us) / 1000.0)
            st["send"].append((sent_mono_us - done_mono_us) / 1000.0)
            if self.on_result is not None:
                self.on_result(out.camera_id, out.result)

    # -- details -------------------------------------------------------------------------------
    def _log_out(self, data: bytes, t_mono_us: int) -> None:
        if data and self.flight_log is not None:
            self.flight_log.log_mavlink("out", t_mono_us, data)

    def _log_result(self, out: FrameProcessed, done_mono_us: int) -> None:
        from ..flightlog.docs import annotation_circles, result_doc

        assert self.flight_log is not None and out.result is not None
        doc = result_doc(
            out.camera_id,
            out.result,
            threshold=out.threshold,
            t_process_us=out.process_mono_us,
            override=out.override,
            clock_offset_us=out.clock_offset_us,
            latency_ms=(done_mono_us - out.capture_mono_us) / 1000.0,
            object_radius_m=out.object_radius_m,
        )
        self.flight_log.log_json(topics.RESULT, out.process_mono_us, doc)
        model = self.cameras[out.camera_id].model
        self.flight_log.log_annotations(
            out.camera_id, out.result.t_us, annotation_circles(out.result, model)
        )

    def health_checked(self, hc: HealthChecked) -> None:
        """The Companion's once-a-second health check ran: input changes logged, the
        watchdog pinged (or withheld), the health record logged, the status shown.
        ``health_checks`` counts the calls (the first is about 1 s into the run; tools
        that measure the steady state wrap this method to start after start-up)."""
        self.health_checks += 1
        if self.health_checks in (1, 5):
            # Start-up is over (imports, renderer or camera set-up, first frames): return
            # what it used to the kernel, so RSS is the steady state.
            trim_heap()
        now = hc.now_mono_us
        for name, problem in hc.changes:
            if problem.startswith("waiting for "):  # a start-up state, not a fault
                log.info("input %s: %s", name, problem)
            elif problem:
                log.warning("input %s: %s", name, problem)
            else:
                log.info("input %s: OK", name)
            if self.flight_log is not None:
                self.flight_log.log_json(
                    topics.EVENT,
                    now,
                    {
                        "severity": "warning"
                        if problem and not problem.startswith("waiting for ")
                        else "info",
                        "input": name,
                        "text": problem or f"{name} OK",
                    },
                )
        healthy, why = self.loop_healthy()
        if healthy:
            self.notifier.watchdog()
            self.watchdog_pings += 1
        else:
            self.watchdog_withheld += 1
            log.error("not pinging the watchdog: %s", why)
        if self.flight_log is not None:
            rep = hc.report
            self.flight_log.log_json(
                topics.HEALTH,
                now,
                {
                    "frame_rate_hz": rep.frame_rate_hz,
                    "latency_ms": rep.latency_ms,
                    "frames_dropped": rep.frames_dropped,
                    "health_flags": rep.health_flags,
                    "egomotion_quality_pct": rep.egomotion_quality_pct,
                    "inputs": hc.problems,
                    "status": hc.status_line,
                    "log": self._log_doc,
                    "link": self.companion.link_counts(),
                    # Whose attitude the companion follows (plot and replay use the same).
                    "autopilot": self._autopilot_id(),
                },
            )
        self.notifier.status(hc.status_line)
        if self.on_status is not None:
            self.on_status(hc.status_line)

    def _autopilot_id(self) -> list[int] | None:
        ap = self.companion.endpoint.autopilot
        return None if ap is None else [ap.system_id, ap.component_id]

    def summary(
        self, duration_s: float, camera_stats: dict[str, CameraStats], lost_in_handoff: int = 0
    ) -> DaemonSummary:
        """The run's summary; ``lost_in_handoff``: delivered frames that never reached
        the Companion (the loop was closing), counted as dropped."""
        comp = self.companion
        captured = sum(s.captured for s in camera_stats.values())
        per_camera: dict[str, dict[str, float]] = {}
        for cam in comp.cameras:
            values = self.camera_latencies_ms[cam.camera_id].tolist()
            per_camera[cam.name] = {
                "processed": cam.frames_processed,
                "dropped": cam.frames_dropped,
                "latency_p50_ms": latency_percentile_ms(values, 50),
                "latency_p99_ms": latency_percentile_ms(values, 99),
            }
        rejected = sum(s.rejected_empty + s.rejected_size for s in camera_stats.values())
        return DaemonSummary(
            duration_s=duration_s,
            captured=captured,
            processed=comp.stats.frames_processed,
            failed=comp.stats.frames_failed,
            dropped=comp.stats.frames_dropped + lost_in_handoff,
            rejected=rejected,
            latencies_ms=self.latencies_ms.tolist(),
            stats=comp.stats,
            camera_stats=camera_stats,
            endpoint_stats=comp.endpoint_stats(),
            watchdog_pings=self.watchdog_pings,
            watchdog_withheld=self.watchdog_withheld,
            faults=dict(comp.stats.faults),
            stage_ms={k: v.tolist() for k, v in self.stage_ms.items()},
            box_feed=comp.box_feed_counts() if comp.box_feed else {},
            link=comp.link_counts(),
            camera_names=[c.name for c in self.cameras],
            processed_per_camera=[self.processed_by_camera[i] for i in range(len(self.cameras))],
            per_camera=per_camera,
        )
