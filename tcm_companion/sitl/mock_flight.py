"""A SITL flight against the mock autopilot: a camera rendered from its true state, the
companion, and the flight scored and reported.

Two clocks:

- **real** (``tcm-companion sitl``, ``make run``, ``run`` with ``[camera] source =
  "sim"``): the asyncio :class:`~tcm_companion.service.daemon.Daemon` with its camera thread, the mock
  autopilot on its asyncio runner, MAVLink over real loopback UDP (the mock listens on an
  ephemeral port, ``udpin:127.0.0.1:0``), all in one process in real time, with a live
  status line.
- **virtual** (``tcm-companion sitl --clock virtual``): the same
  :class:`~tcm_companion.service.companion.Companion`, host, mock and simulated camera on one simulated
  clock (:mod:`.virtual`), as fast as the CPU allows; the same seed and
  configuration give byte-identical results and flight logs, run after run.

Either way the simulated camera renders the scenario's world from the vehicle's *true*
pose at each frame's capture time, while the companion only knows what the mock's
(noisy, delayed) telemetry tells it — the same split as on a real drone. When the mock
brakes on a collision-course alarm, the camera sees the braking, so the loop is closed.

Every processed frame is scored against the simulator's truth (objects matched by
bearing and counted after the classifier's interval: :mod:`~tcm_companion.io.scoring`,
the evaluation's rules), and :class:`SitlReport` summarises accuracy, latency, drops and faults. A run
fails (``report.ok`` False, ``sitl`` exits 1) when nothing was processed, the frame
counts do not add up, the autopilot rejected messages, the watchdog was withheld, or the
accuracy of the decided object-frames after the warm-up is below ``min_accuracy`` —
or nothing was decided although a ball was in view after the warm-up.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import math
import os
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..config import AppConfig
from ..core.camera import CameraModel
from ..core.classify import ClassifierConfig
from ..core.pipeline import FrameResult
from ..flight_log_setup import start_flight_log
from ..io.aio import monotonic_us
from ..io.cameras.settings import CameraSourceConfig
from ..io.detector_model import read_detector_model
from ..io.scoring import Handover, Score, match_truth, view_camera, warmed_up
from ..io.transports import Transport, open_transport
from ..service.host import CameraInput, DaemonSummary, NotifierLike, run_length_text
from ..service.runner import ServiceState, StartLog, open_service, open_service_state
from ..sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig
from ..sim.vehicle.mock_autopilot_run import run_mock_autopilot
from .virtual import RunTimer, VirtualTimeModel, frame_result_key

log = logging.getLogger(__name__)

#: Least accuracy of the decided object-frames after the warm-up for a run to pass.
DEFAULT_MIN_ACCURACY = 0.90

Clock = Literal["real", "virtual"]
#: ``camera_factory(mock, model, **camera_kwargs)``: the SITL camera (tests wrap the
#: simulated one to make it fail). ``camera_kwargs`` go to
#: :meth:`~tcm_companion.sim.scene.truth_camera.SimulatedCamera.for_mock`: the sensor noise, and
#: in virtual time the simulated clock and a sleep that does not sleep.
CameraFactory = Callable[..., Any]
#: A rig camera that dies: ``(camera name, seconds after the start)``; None: none;
#: ``"scenario"``: the scenario's own (:data:`~tcm_companion.sim.scene.names.CAMERA_LOSS`).
CameraLoss = tuple[str, float] | None | Literal["scenario"]
#: ``rig=CONFIG_RIG``: fly the configuration's ``[[cameras]]``, each a simulated camera.
CONFIG_RIG = "config"


@dataclass
class SitlReport:
    scenario: str
    summary: DaemonSummary
    score: Score
    braked: bool
    mock_status_received: int
    mock_status_problems: int
    mock_problem_kinds: dict[str, int]
    failures: list[str]
    clock: Clock = "real"
    min_accuracy: float | None = DEFAULT_MIN_ACCURACY
    results_sha256: str = ""  # every processed frame's result, floats exact
    results_frames: int = 0
    wall_s: float = 0.0  # how long the run took (virtual time: the speed-up's divisor)
    cpu_s: float = 0.0
    model: VirtualTimeModel | None = None  # virtual time: what it assumed
    loop_lag_max_ms: float = 0.0  # real time: the longest the event loop was late to a timer
    stale_excused: int = 0  # real time: "stale" statuses while the loop stalled >= 0.5 s
    log: Any = None  # the flight log's final stats, when logging
    log_sha256: str = ""  # the flight log's bytes (all parts, in order)
    statustexts: list[str] = field(default_factory=list)  # what the daemon told the GCS
    planned_s: float | None = None  # the run's duration as asked (None: until stopped)
    # "" ran its planned time; "stop": stopped early by its caller; the signal's name
    # ("SIGINT") when the command line knows which one stopped it.
    stopped_by: str = ""
    # A rig (several cameras): each camera's name and its share of the score (objects
    # scored in the camera that saw them nearest its axis), and the handover figure:
    # plan object index -> track ids matched to it, for the objects seen by more than
    # one camera (target 1).
    camera_names: tuple[str, ...] = ()
    camera_scores: tuple[Score, ...] = ()
    handover: dict[int, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def speedup(self) -> float:
        """Simulated (virtual) or flown (real) seconds per second of wall time."""
        return self.summary.duration_s / self.wall_s if self.wall_s > 0 else math.nan

    def accuracy_text(self) -> str:
        sc = self.score
        if not sc.decided:
            return f"no decision ({sc.truth_after_warmup} object-frames in view)"
        floor = "" if self.min_accuracy is None else f" (floor {100 * self.min_accuracy:.0f}%)"
        return f"accuracy {100 * sc.accuracy:.1f}% of {sc.decided} decided{floor}"

    def lines(self) -> list[str]:
        """The summary; with the virtual clock every line but the last ("speed") is the
        same run after run."""
        s, sc = self.summary, self.score
        lat = [s.latency_percentile_ms(q) for q in (50, 90, 99)]
        modelled = ""
        if self.model is not None:
            modelled = (
                f" (modelled: pipeline {self.model.process_us / 1000:g} ms, link"
                f" {self.model.link_latency_us / 1000:g} ms)"
            )
        coverage = "n/a" if not sc.scored else f"{100 * sc.coverage:.1f}%"
        latency = (
            f"p50 {lat[0]:.2f} ms, p90 {lat[1]:.2f} ms, p99 {lat[2]:.2f} ms"
            if s.latencies_ms
            else "n/a (no frame's output was written)"
        )
        ran = run_length_text(s.duration_s, self.planned_s, self.stopped_by)
        out = [
            f"SITL {self.scenario}: {ran}, {self.clock} clock",
            f"  frames: {s.frames_text()} ({'balanced' if s.frames_balance else 'NOT BALANCED'})",
            f"  latency capture->MAVLink: {latency}{modelled}",
            f"  objects: {sc.matched}/{sc.truth_frames} object-frames matched; after {sc.warmup_s:g} s"
            f" warm-up: {self.accuracy_text()}, coverage {coverage}",
            f"  states: {dict(sc.by_state) or 'none'}",
            f"  mock autopilot: {self.mock_status_received} TCM_OBJECT_STATUS received,"
            f" {self.mock_status_problems} with problems"
            + (f" {self.mock_problem_kinds}" if self.mock_problem_kinds else "")
            + f"; braked: {self.braked}",
            f"  faults: {s.faults or 'none'}; watchdog pings {s.watchdog_pings},"
            f" withheld {s.watchdog_withheld}",
            f"  results: sha256 {self.results_sha256[:16]} of {self.results_frames} frames",
        ]
        if len(self.camera_scores) > 1:
            for name, cs in zip(self.camera_names, self.camera_scores, strict=True):
                out.append(f"  camera {name}: {_score_text(cs)}")
            if self.handover:
                ids = ", ".join(f"object {i + 1}: {n}" for i, n in self.handover.items())
                out.append(f"  handover: track ids per object seen by several cameras: {ids}")
            else:
                out.append("  handover: no object was seen by more than one camera")
        if s.link:
            out.append(f"  link: {s.link}")
        if self.stale_excused or self.loop_lag_max_ms >= 500.0:
            out.append(
                f"  event loop stalled up to {self.loop_lag_max_ms:.0f} ms (machine load);"
                f" {self.stale_excused} status(es) the mock found stale then were excused"
            )
        if self.log is not None:
            lg = self.log
            out.append(
                f"  flight log: {lg.frames_logged} frames logged + {lg.frames_dropped_queue}"
                f" dropped (queue) + {lg.frames_dropped_disk} (disk)"
                + (f" + {lg.frames_dropped_error} (error)" if lg.frames_dropped_error else "")
                + f", {lg.bytes_written / 1e6:.1f} MB"
                f" in {len(lg.files)} file(s), sha256 {self.log_sha256[:16]}"
            )
        if self.failures:
            out.append("  FAILED: " + "; ".join(self.failures))
        if self.log is not None:
            out.append(f"  flight log files: {', '.join(str(f) for f in self.log.files[-2:])}")
        out.append(
            f"  speed: {s.duration_s:.1f} s in {self.wall_s:.1f} s wall, {self.cpu_s:.1f} s CPU:"
            f" {self.speedup:.2f}x real time"
        )
        return out


def _score_text(sc: Score) -> str:
    """One camera's share of a rig's score, on one line."""
    acc = "no decision" if not sc.decided else f"accuracy {100 * sc.accuracy:.1f}%"
    cov = "n/a" if not sc.scored else f"{100 * sc.coverage:.1f}%"
    return (
        f"{sc.matched}/{sc.truth_frames} object-frames matched; {acc} of {sc.decided}"
        f" decided, coverage {cov}; states {dict(sc.by_state) or 'none'}"
    )


#: Another camera's objects count for a frame's matching when its frame was captured
#: within this of the frame's: the same frame cycle, or the one before when that camera's
#: frame of this cycle is processed after this one (a frame period at 25 Hz and a
#: little). The rig reports an object from one camera, not necessarily the one it is
#: scored in.
_SAME_CYCLE_US = 45_000


class _Scorer:
    """Scores each frame's objects against the mock's true vehicle and balls
    (:mod:`~tcm_companion.io.scoring`: after the classifier ``cls``'s interval from
    ``start_mono_us``), and hashes every result (the digest two virtual runs must agree
    on).

    A rig (several ``cameras``): an object-frame is scored once per frame cycle, in the
    frame of the camera that sees the object nearest its optical axis (the object's
    *view*), matched against the objects of every camera in that cycle (bearings are NED,
    so any camera may have measured it). ``per_camera`` tallies each view's share (their
    sum is ``score``); ``handovers`` collects the ids matched to each object, for the
    handover figure (:meth:`handover`). One camera: exactly the single-camera score.
    ``rig_track_ids``: the ids are rig-wide (a :class:`~tcm_companion.core.rig.RigTracker`
    fuses the cameras); otherwise an id is ``(camera id, track id)``.
    """

    def __init__(
        self,
        mock: Any,
        camera: CameraModel | Sequence[CameraModel],
        start_mono_us: int,
        cls: ClassifierConfig,
        *,
        rig_track_ids: bool = False,
    ) -> None:
        self.mock = mock
        self.cameras: list[CameraModel] = list(camera) if isinstance(camera, Sequence) else [camera]
        self.camera = self.cameras[0]
        self.start_mono_us = start_mono_us
        self.cls = cls
        self.score = Score(warmup_s=cls.interval_s)
        self.per_camera = [Score(warmup_s=cls.interval_s) for _ in self.cameras]
        self.rig_track_ids = rig_track_ids
        # plan object index -> when it was first in view, and first matched by an object
        self.first_in_view_us: dict[int, int] = {}
        self.first_matched_us: dict[int, int] = {}
        self.decidable_after_us = round(1e6 * (cls.interval_s + cls.hold_s))
        self.digest = hashlib.sha256()
        self.frames = 0
        # per camera: its latest frame's capture time and detected objects
        self._latest: list[tuple[int, list[Any]]] = [(0, []) for _ in self.cameras]
        self.handovers = Handover()  # by plan object index

    def __call__(self, camera_id: int, result: FrameResult) -> None:
        self.digest.update(frame_result_key(camera_id, result))
        self.frames += 1
        truth = self.mock.vehicle_truth(result.t_us)
        warm = warmed_up((result.t_us - self.start_mono_us) / 1e6, self.cls)
        own = [o for o in result.objects if o.detected]
        self._latest[camera_id] = (result.t_us, own)
        objs = [(camera_id, o) for o in own]
        for cid, (t_us, others) in enumerate(self._latest):
            if cid != camera_id and abs(t_us - result.t_us) <= _SAME_CYCLE_US:
                objs.extend((cid, o) for o in others)
        bearings = [o.bearing_ned for _, o in objs]
        used: set[int] = set()
        sc, sc_cam = self.score, self.per_camera[camera_id]
        for i, obj in enumerate(self.mock.plan.objects):  # balls and targets of any shape
            rel = obj.centre_ned_m(truth.t_s) - truth.position_ned_m
            if view_camera(self.cameras, truth.R_ned_from_body, rel) != camera_id:
                continue
            # Could it have been decided? Once the companion has it: after the interval
            # and the hold from then; until then, as long from when it came into view.
            self.first_in_view_us.setdefault(i, result.t_us)
            m = match_truth(rel, obj.bounding_radius_m, bearings, used)
            state, tid = None, None
            if m.matched:
                self.first_matched_us.setdefault(i, result.t_us)
                src, o = objs[m.index]
                state = o.state
                tid = o.track_id if self.rig_track_ids else (src, o.track_id)
            self.handovers.add(i, camera_id, tid)
            first_us = self.first_matched_us.get(i, self.first_in_view_us[i])
            overdue = result.t_us - first_us >= self.decidable_after_us
            sc.add(warm, state, obj.moving, overdue)
            if len(self.cameras) > 1:
                sc_cam.add(warm, state, obj.moving, overdue)

    def handover(self) -> dict[int, int]:
        """Track ids per object that was viewed by more than one camera (plan object
        index -> how many ids were matched to it; the target is 1)."""
        fig = self.handovers.figure()
        return {i: fig[i] for i in sorted(k for k in fig if isinstance(k, int))}


class _LoopLag:
    """Real time only: how late the event loop runs a 50 ms timer, at worst (ms)."""

    def __init__(self) -> None:
        self.max_ms = 0.0

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            t = loop.time()
            await asyncio.sleep(0.05)
            self.max_ms = max(self.max_ms, (loop.time() - t - 0.05) * 1000.0)


@contextlib.contextmanager
def _state_directory(state_dir: str | None, config: AppConfig) -> Iterator[str]:
    """The run's state directory; a temporary one (removed after) unless given."""
    given = state_dir or config.daemon.state_dir
    if given:
        yield given
        return
    sdir = tempfile.mkdtemp(prefix="tcm-sitl-state-")
    try:
        yield sdir
    finally:
        for f in Path(sdir).glob("*"):
            with contextlib.suppress(OSError):
                f.unlink()
        with contextlib.suppress(OSError):
            os.rmdir(sdir)


def _mock_config(config: AppConfig, unix_us_at_start: int) -> MockAutopilotConfig:
    sim = config.sim
    return MockAutopilotConfig(
        scenario=sim.scenario.upper(),
        seed=sim.seed,
        noise=sim.telemetry_noise,
        ekf_origin_delay_us=sim.ekf_origin_delay_us,
        brake_on_collision=sim.brake_on_collision,
        unix_us_at_start=unix_us_at_start,
    )


def _sim_camera(
    config: AppConfig,
    mock: Any,
    model: CameraModel | None,
    camera_factory: CameraFactory | None,
    rig: str = "panorama",
    camera_loss: tuple[str, float] | None = None,
    start_us: int = 0,
    **camera_kwargs: Any,
) -> list[CameraInput]:
    """The simulated cameras: ``model`` (None: the default 360x220 panorama) or, for a
    ``rig`` other than the panorama (:func:`~tcm_companion.sim.scene.cameras.rig_cameras`),
    one camera per rig camera, in rig order, each rendering from the vehicle's true pose
    at its frame times. ``camera_loss``: ``(camera name, s)``: that camera stops
    delivering ``s`` seconds after ``start_us`` (the clock's µs) and never comes back.
    ``rig`` :data:`CONFIG_RIG`: the configuration's ``[[cameras]]`` (names, lenses, frame
    rates and noise), each simulated."""
    from ..core.camera import Equirectangular
    from ..sim.scene.cameras import rig_cameras
    from ..sim.scene.truth_camera import DyingCamera, SimulatedCamera

    # (name, lens, source name or None: the scenario's, settings)
    lenses: list[tuple[str, CameraModel, str | None, CameraSourceConfig]]
    if rig == "panorama":
        lens0 = model if model is not None else Equirectangular(360, 220)
        lenses = [("camera0", lens0, None, config.camera.source)]
    elif model is not None:
        raise ValueError(f"rig {rig!r} has its own cameras: do not pass camera_model")
    elif rig == CONFIG_RIG:
        lenses = [(c.name, c.model, f"sim-{c.name}", c.source) for c in config.cameras]
    else:
        src = config.camera.source
        lenses = [(n, lens, f"sim-{n}", src) for n, lens in rig_cameras(rig)]
    names = [n for n, _, _, _ in lenses]
    if camera_loss is not None and camera_loss[0] not in names:
        raise ValueError(
            f"camera {camera_loss[0]!r} cannot die: rig {rig!r} has {', '.join(names)}"
        )
    out = []
    for name, lens, source_name, settings in lenses:
        kwargs = dict(camera_kwargs)
        kwargs.setdefault("noise_dn", settings.sim_noise_dn)
        kwargs.setdefault("fps", settings.fps)
        if source_name is not None:
            kwargs["name"] = source_name
        if camera_factory is not None:
            source = camera_factory(mock, lens, **kwargs)
        else:
            source = SimulatedCamera.for_mock(lens, mock, **kwargs)
        if camera_loss is not None and camera_loss[0] == name:
            clock_us = camera_kwargs.get("clock_us", monotonic_us)
            source = DyingCamera(source, start_us + round(camera_loss[1] * 1e6), clock_us)
        out.append(CameraInput(name, lens, source, fps=settings.fps))
    return out


def _camera_loss(config: AppConfig, rig: str, camera_loss: CameraLoss) -> tuple[str, float] | None:
    """``camera_loss`` as given, or (``"scenario"``) the scenario's own
    (:data:`~tcm_companion.sim.scene.names.CAMERA_LOSS`) on a rig of several cameras that
    has the camera (else a warning: none dies)."""
    from ..sim.scene.cameras import rig_cameras
    from ..sim.scene.names import CAMERA_LOSS

    if camera_loss != "scenario":
        return camera_loss
    loss = CAMERA_LOSS.get(config.sim.scenario.upper())
    if rig == "panorama" or loss is None:
        return None
    names = (
        [c.name for c in config.cameras] if rig == CONFIG_RIG else [n for n, _ in rig_cameras(rig)]
    )
    if loss[0] not in names:
        log.warning(
            "%s: the %s camera dies %g s in, but this rig has %s: no camera dies",
            config.sim.scenario.upper(),
            loss[0],
            loss[1],
            ", ".join(names),
        )
        return None
    return loss


@dataclass
class _Run:
    """What the report needs of a run on either clock: the mock, the timer, the accuracy
    floor, the scorer, and the service's state (endpoint, flight log)."""

    mock: Any
    timer: RunTimer
    min_accuracy: float | None
    scorer: _Scorer
    state: ServiceState
    camera_names: tuple[str, ...] = ()


def _start_log(
    config: AppConfig, log_dir: str | None, cameras: list[CameraInput], **log_kwargs: Any
) -> StartLog | None:
    """The service's ``start_log`` for ``log_dir`` (None: no flight log), ``log_kwargs`` to
    :func:`~tcm_companion.flight_log_setup.start_flight_log`."""
    if log_dir is None or not config.logging.enabled:
        return None
    directory = Path(log_dir)
    return lambda params: start_flight_log(config, directory, cameras, params, **log_kwargs)


def _file_sha256(paths: Sequence[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        with contextlib.suppress(OSError):
            h.update(Path(p).read_bytes())
    return h.hexdigest()


def _report(
    run: _Run,
    summary: DaemonSummary,
    clock: Clock,
    *,
    model: VirtualTimeModel | None = None,
    loop_lag_ms: float = 0.0,
    planned_s: float | None = None,
    stopped_early: bool = False,
) -> SitlReport:
    mock, scorer, min_accuracy = run.mock, run.scorer, run.min_accuracy
    flight_log = run.state.flight_log
    # Real time only: the daemon and the mock share this process's event loop. When the
    # machine stalls the whole loop (a loaded CI runner), a status can reach the mock over
    # a second after capture, and the mock rightly calls it stale. That is the machine,
    # not the daemon's time base: such "stale" records are excused, and reported, only
    # when the loop was measured to stall for at least half a second. In virtual time
    # nothing stalls: every stale status is a bug.
    stalled = clock == "real" and loop_lag_ms >= 500.0
    received = list(mock.received_status)
    problems = [r for r in received if not r.ok and not (stalled and r.problems == ("stale",))]
    excused = sum(1 for r in received if not r.ok) - len(problems)
    kinds: Counter[str] = Counter()
    for r in problems:
        for p in r.problems:
            kinds[p] += 1
    sc = scorer.score
    failures = []
    if summary.processed == 0:
        failures.append("no frame was processed")
    if not summary.frames_balance:
        failures.append("frame counts do not add up")
    if not received and summary.processed > 0 and sc.matched > 0:
        failures.append("the autopilot received no TCM_OBJECT_STATUS")
    if problems:
        failures.append(f"{len(problems)} status messages failed the autopilot's checks")
    log_stats = None
    log_sha = ""
    if flight_log is not None:
        log_stats = flight_log.stats
        delivered = sum(c.delivered for c in summary.camera_stats.values())
        lg = log_stats
        dropped = lg.frames_dropped_queue + lg.frames_dropped_disk + lg.frames_dropped_error
        if lg.frames_logged + dropped != delivered:
            failures.append("flight log: frames logged + dropped != frames delivered")
        log_sha = _file_sha256(lg.files)
    if summary.watchdog_withheld:
        failures.append(f"watchdog withheld {summary.watchdog_withheld} times")
    if min_accuracy is not None:
        if sc.decided and sc.accuracy < min_accuracy:
            failures.append(
                f"accuracy {100 * sc.accuracy:.1f}% below the floor of {100 * min_accuracy:.0f}%"
            )
        elif not sc.decided and sc.overdue:
            cls = scorer.cls
            failures.append(
                f"no decision on {sc.overdue} object-frames of objects in view for "
                f"{cls.interval_s + cls.hold_s:g} s or more (the interval and the hold)"
            )
    wall_s, cpu_s = run.timer.elapsed()
    return SitlReport(
        scenario=mock.config.scenario,
        summary=summary,
        score=sc,
        braked=mock.braking is not None,
        mock_status_received=len(received),
        mock_status_problems=len(problems),
        mock_problem_kinds=dict(kinds),
        failures=failures,
        clock=clock,
        min_accuracy=min_accuracy,
        results_sha256=scorer.digest.hexdigest(),
        results_frames=scorer.frames,
        wall_s=wall_s,
        cpu_s=cpu_s,
        model=model,
        loop_lag_max_ms=loop_lag_ms,
        stale_excused=excused,
        log=log_stats,
        log_sha256=log_sha,
        statustexts=run.state.endpoint.statustexts_queued,
        planned_s=planned_s,
        stopped_by="stop" if stopped_early else "",
        camera_names=run.camera_names,
        camera_scores=tuple(scorer.per_camera) if len(scorer.cameras) > 1 else (),
        handover=scorer.handover() if len(scorer.cameras) > 1 else {},
    )


async def run_sitl(
    config: AppConfig,
    cameras: list[CameraInput] | None = None,
    *,
    camera_model: CameraModel | None = None,
    duration_s: float | None = 20.0,
    stop: asyncio.Event | None = None,
    notifier: NotifierLike | None = None,
    on_status: Callable[[str], None] | None = None,
    state_dir: str | None = None,
    mock_config: MockAutopilotConfig | None = None,
    mock: MockAutopilot | None = None,
    camera_factory: CameraFactory | None = None,
    links: tuple[Transport, Transport] | None = None,
    log_dir: str | None = None,
    clock: Clock = "real",
    min_accuracy: float | None = DEFAULT_MIN_ACCURACY,
    model: VirtualTimeModel | None = None,
    schedule: Sequence[tuple[float, Callable[[int], None]]] = (),
    link_up: Callable[[float], bool] | None = None,
    rig: str = "panorama",
    camera_loss: CameraLoss = "scenario",
) -> SitlReport:
    """Fly ``config.sim.scenario`` for ``duration_s`` (None: until ``stop``).

    ``clock="virtual"`` runs :func:`run_sitl_virtual` (and takes its ``model``,
    ``schedule`` and ``link_up``); the rest is real time. Tests may pass their own
    ``mock`` (to reboot it mid-flight; on the clock the run uses: in virtual time start
    it at :data:`~.virtual.VIRTUAL_START_MONO_US`), ``camera_factory`` (to make the
    camera fail), and in real time ``links`` — ``(mock side, daemon side)``, opened — in
    place of the loopback UDP pair (to cut the link). ``log_dir``: write the flight log
    there (``[logging]`` settings). ``min_accuracy``: the floor (None: not judged).
    ``rig``: the simulated cameras (:data:`~tcm_companion.sim.scene.cameras.RIGS`; the
    default is today's one panorama), one companion camera each, in rig order.
    ``camera_loss``: ``(camera name, s)``: that rig camera dies ``s`` seconds in (None:
    none; ``"scenario"``: the scenario's own, :data:`~tcm_companion.sim.scene.names.CAMERA_LOSS`).
    """
    if clock == "virtual":
        if cameras is not None or links is not None:
            raise ValueError("virtual time runs its own camera and links (camera_factory)")
        return run_sitl_virtual(
            config,
            camera_model=camera_model,
            duration_s=duration_s,
            should_stop=stop.is_set if stop is not None else None,
            notifier=notifier,
            on_status=on_status,
            state_dir=state_dir,
            mock_config=mock_config,
            mock=mock,
            camera_factory=camera_factory,
            log_dir=log_dir,
            min_accuracy=min_accuracy,
            model=model,
            schedule=schedule,
            link_up=link_up,
            rig=rig,
            camera_loss=camera_loss,
        )
    if clock != "real":
        raise ValueError(f"clock must be 'real' or 'virtual', got {clock!r}")
    if schedule or link_up is not None:
        raise ValueError("schedule and link_up are virtual-time hooks")
    timer = RunTimer()
    mcfg = mock_config or _mock_config(config, time.time_ns() // 1000)
    stop = stop if stop is not None else asyncio.Event()
    now_us = monotonic_us()
    if mock is None:
        mock = MockAutopilot(mcfg, now_us)
    else:
        mcfg = mock.config
    if cameras is None:
        cameras = _sim_camera(
            config,
            mock,
            camera_model,
            camera_factory,
            rig,
            _camera_loss(config, rig, camera_loss),
            now_us,
        )

    with _state_directory(state_dir, config) as sdir:
        if links is not None:
            mock_link, daemon_link = links
        else:
            mock_link = open_transport("udpin:127.0.0.1:0")
            await mock_link.open()
            host, port = mock_link.local_address  # type: ignore[attr-defined]
            daemon_link = open_transport(f"udpout:{host}:{port}")
            await daemon_link.open()
        # Two cameras or more: the Companion fuses them (core.rig), its ids are rig-wide.
        scorer = _Scorer(
            mock,
            [c.model for c in cameras],
            now_us,
            config.pipeline.classifier,
            rig_track_ids=len(cameras) > 1,
        )
        lag = _LoopLag()
        lag_task = asyncio.create_task(lag.run(), name="loop lag")
        ran_out: list[bool] = []  # the duration ended the run (not its caller's stop)
        try:
            async with open_service(
                config,
                cameras,
                state_dir=sdir,
                transport=daemon_link,
                now_us=now_us,
                start_log=_start_log(config, log_dir, cameras),
                notifier=notifier,
                on_result=scorer,
                on_status=on_status,
            ) as service:
                run = _Run(
                    mock,
                    timer,
                    min_accuracy,
                    scorer,
                    service.state,
                    tuple(c.name for c in cameras),
                )
                mock_stop = asyncio.Event()
                mock_task = asyncio.create_task(
                    run_mock_autopilot(mock_link, mcfg, mock_stop, autopilot=mock), name="mock"
                )
                timer_task: asyncio.Task[Any] | None = None
                if duration_s is not None:

                    async def _stop_after() -> None:
                        await asyncio.sleep(duration_s)
                        if not stop.is_set():
                            ran_out.append(True)
                        stop.set()

                    timer_task = asyncio.create_task(_stop_after(), name="duration")
                try:
                    summary = await service.run(stop)
                finally:
                    if timer_task is not None:
                        timer_task.cancel()
                    # The autopilot takes in the daemon's last messages before anything
                    # else may hold things up; then (leaving the service) the state is
                    # persisted and the log drains off the loop (a PNG backlog takes a
                    # while; blocking the loop on it would delay what the mock still
                    # receives and make those statuses look stale).
                    mock_stop.set()
                    with contextlib.suppress(Exception):
                        async with asyncio.timeout(2.0):
                            await mock_task
        finally:
            lag_task.cancel()
            await daemon_link.close()
            await mock_link.close()

    return _report(
        run,
        summary,
        "real",
        loop_lag_ms=lag.max_ms,
        planned_s=duration_s,
        stopped_early=not ran_out,
    )


def run_sitl_virtual(
    config: AppConfig,
    *,
    camera_model: CameraModel | None = None,
    duration_s: float | None = 20.0,
    should_stop: Callable[[], bool] | None = None,
    notifier: NotifierLike | None = None,
    on_status: Callable[[str], None] | None = None,
    state_dir: str | None = None,
    mock_config: MockAutopilotConfig | None = None,
    mock: Any = None,
    camera_factory: CameraFactory | None = None,
    log_dir: str | None = None,
    min_accuracy: float | None = DEFAULT_MIN_ACCURACY,
    model: VirtualTimeModel | None = None,
    schedule: Sequence[tuple[float, Callable[[int], None]]] = (),
    link_up: Callable[[float], bool] | None = None,
    rig: str = "panorama",
    camera_loss: CameraLoss = "scenario",
) -> SitlReport:
    """SITL in virtual time (:mod:`.virtual`): the same arguments as
    :func:`run_sitl`, plus ``model`` (what virtual time assumes: start, link latency,
    pipeline time), ``schedule`` (``(run time s, fn(now_mono_us))`` calls, e.g. a mock
    reboot), ``link_up(run time s)`` (False: the radio is out), ``rig`` and
    ``camera_loss`` (see :func:`run_sitl`). A passed ``mock``
    sets the start time (its latest time); otherwise the mock starts at
    ``model.start_mono_us`` with Unix time ``model.unix_us_at_start``."""
    import cv2

    from ..service.companion import Companion
    from ..service.host import CompanionHost
    from ..sim.scene.truth_camera import no_sleep
    from .virtual import VirtualSitl

    timer = RunTimer()
    vm = model or VirtualTimeModel()
    if mock is None:
        mcfg = mock_config or _mock_config(config, vm.unix_us_at_start)
        mock = MockAutopilot(mcfg, vm.start_mono_us)
        start = vm.start_mono_us
    else:
        start = int(mock.now_us)
    unix_minus_mono_us = vm.unix_us_at_start - start
    holder: list[VirtualSitl] = []

    def now_us() -> int:
        return holder[0].now_us() if holder else start

    cameras = _sim_camera(
        config,
        mock,
        camera_model,
        camera_factory,
        rig,
        _camera_loss(config, rig, camera_loss),
        start,
        clock_us=now_us,
        sleep=no_sleep,
    )
    if config.daemon.opencv_threads:
        cv2.setNumThreads(config.daemon.opencv_threads)

    up = start + vm.companion_start_us  # the companion's start
    with _state_directory(state_dir, config) as sdir:
        with open_service_state(
            config,
            sdir,
            up,
            start_log=_start_log(
                config,
                log_dir,
                cameras,
                unix_minus_mono_us=unix_minus_mono_us,
                started_unix_us=vm.unix_us_at_start,
                deterministic=True,
            ),
        ) as state:
            run = _Run(
                mock,
                timer,
                min_accuracy,
                _Scorer(
                    mock,
                    [c.model for c in cameras],
                    start,
                    config.pipeline.classifier,
                    rig_track_ids=len(cameras) > 1,  # the Companion fuses (core.rig)
                ),
                state,
                tuple(c.name for c in cameras),
            )
            companion = Companion(
                [c.model for c in cameras],
                config.pipeline,
                state.endpoint,
                up,
                config.daemon,
                [c.name for c in cameras],
                camera_rates_hz=[c.fps for c in cameras],
                pipeline_timer=lambda: now_us() / 1e6,  # stages take no simulated time
                detector_model=read_detector_model(config.pipeline.detection),
            )
            host = CompanionHost(
                companion,
                cameras,
                flight_log=state.flight_log,
                notifier=notifier,
                on_result=run.scorer,
                on_status=on_status,
                persist=state.persist,
            )
            sim = VirtualSitl(
                mock,
                companion,
                host,
                cameras,
                vm,
                start_mono_us=start,
                schedule=schedule,
                link_up=link_up,
            )
            holder.append(sim)
            summary = sim.run(duration_s, should_stop or (lambda: False))

    return _report(
        run, summary, "virtual", model=vm, planned_s=duration_s, stopped_early=sim.stopped_early
    )
