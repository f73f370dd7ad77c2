"""SITL: the mock autopilot, a camera rendered from its true state, and the daemon.

All three run in one process, in real time, and talk MAVLink over real loopback UDP: the
mock autopilot listens on an ephemeral port (``udpin:127.0.0.1:0``) and the daemon sends
to it. The simulated camera renders the scenario's world from the vehicle's *true* pose
at each frame's capture time, while the daemon only knows what the mock's (noisy,
delayed) telemetry tells it — the same split as on a real drone. When the mock brakes on
a collision-course alarm, the camera sees the braking, so the loop is closed.

Every processed frame is scored against the simulator's truth (objects matched by
bearing), and :class:`SitlReport` summarises accuracy, latency, drops and faults.
``tcm-companion run`` with ``[camera] source = "sim"`` runs this too, until stopped.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config import AppConfig
from ..core.camera import CameraModel
from ..core.frames import angle_between, normalize
from ..core.pipeline import FrameResult
from ..io.transports import Transport, open_transport
from ..mavlink.setup import make_endpoint, persist, resolve_state_paths
from ..sim.mock_autopilot import MockAutopilot, MockAutopilotConfig
from ..sim.mock_autopilot_run import run_mock_autopilot
from .daemon import CameraInput, Daemon, DaemonSummary, NotifierLike
from .logsetup import start_flight_log

log = logging.getLogger(__name__)

MATCH_GATE_RAD = math.radians(5.0)
WARMUP_S = 2.0  # object-frames before this (run time) are not scored for coverage


@dataclass
class Score:
    """Object-frames of balls in view, matched to the daemon's objects by bearing."""

    truth_frames: int = 0  # ball-frames with the ball in front of the camera
    matched: int = 0
    decided: int = 0  # matched and not "unknown" (after the warm-up)
    correct: int = 0
    scored: int = 0  # matched after the warm-up
    by_state: Counter[str] = field(default_factory=Counter)

    @property
    def accuracy(self) -> float:
        return self.correct / self.decided if self.decided else math.nan

    @property
    def coverage(self) -> float:
        return self.decided / self.scored if self.scored else math.nan


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
    loop_lag_max_ms: float = 0.0  # the longest the event loop was late to a 50 ms timer
    stale_excused: int = 0  # "stale" statuses while the loop stalled >= 0.5 s (machine load)
    log: Any = None  # the flight log's final stats, when logging
    statustexts: list[str] = field(default_factory=list)  # what the daemon told the GCS

    @property
    def ok(self) -> bool:
        return not self.failures

    def lines(self) -> list[str]:
        s, sc = self.summary, self.score
        lat = [s.latency_percentile_ms(q) for q in (50, 90, 99)]
        out = [
            f"SITL {self.scenario}: {s.duration_s:.1f} s",
            f"  frames: captured {s.captured} = processed {s.processed} + dropped {s.dropped}"
            f" + failed {s.failed} + rejected {s.rejected}"
            f" ({'balanced' if s.frames_balance else 'NOT BALANCED'})",
            f"  latency capture->MAVLink: p50 {lat[0]:.2f} ms, p90 {lat[1]:.2f} ms,"
            f" p99 {lat[2]:.2f} ms",
            f"  objects: {sc.matched}/{sc.truth_frames} ball-frames matched; after {WARMUP_S:.0f} s"
            f" warm-up: accuracy {100 * sc.accuracy:.1f}% of {sc.decided} decided,"
            f" coverage {100 * sc.coverage:.1f}%",
            f"  states: {dict(sc.by_state)}",
            f"  mock autopilot: {self.mock_status_received} TCM_OBJECT_STATUS received,"
            f" {self.mock_status_problems} with problems"
            + (f" {self.mock_problem_kinds}" if self.mock_problem_kinds else "")
            + f"; braked: {self.braked}",
            f"  faults: {s.faults or 'none'}; watchdog pings {s.watchdog_pings},"
            f" withheld {s.watchdog_withheld}",
        ]
        if self.stale_excused or self.loop_lag_max_ms >= 500.0:
            out.append(
                f"  event loop stalled up to {self.loop_lag_max_ms:.0f} ms (machine load);"
                f" {self.stale_excused} status(es) the mock found stale then were excused"
            )
        if self.log is not None:
            lg = self.log
            out.append(
                f"  flight log: {lg.frames_logged} frames logged + {lg.frames_dropped_queue}"
                f" dropped (queue) + {lg.frames_dropped_disk} (disk), {lg.bytes_written / 1e6:.1f} MB"
                f" in {len(lg.files)} file(s): {', '.join(str(f) for f in lg.files[-2:])}"
            )
        if self.failures:
            out.append("  FAILED: " + "; ".join(self.failures))
        return out


class _Scorer:
    """Scores each frame's objects against the mock's true vehicle and balls."""

    def __init__(self, mock: MockAutopilot, camera: CameraModel, start_us: int) -> None:
        self.mock = mock
        self.camera = camera
        self.start_us = start_us
        self.score = Score()

    def __call__(self, camera_id: int, result: FrameResult) -> None:
        truth = self.mock.vehicle_truth(result.t_us)
        R_cam_from_ned = (truth.R_ned_from_body @ self.camera.R_body_from_cam).T
        warm = (result.t_us - self.start_us) / 1e6 >= WARMUP_S
        objs = [o for o in result.objects if o.detected]
        used: set[int] = set()
        sc = self.score
        for ball in self.mock.plan.balls:
            rel = ball.centre_ned_m(truth.t_s) - truth.position_ned_m
            b_true = normalize(rel)
            px = self.camera.pixel_from_bearing_cam(R_cam_from_ned @ b_true)
            if not np.all(np.isfinite(px)) or not bool(self.camera.in_image(px)):
                continue
            sc.truth_frames += 1
            alpha = math.asin(min(1.0, ball.radius_m / float(np.linalg.norm(rel))))
            best, best_ang = -1, math.inf
            for i, o in enumerate(objs):
                ang = float(angle_between(o.bearing_ned, b_true))
                if i not in used and ang < best_ang:
                    best, best_ang = i, ang
            if best < 0 or best_ang > MATCH_GATE_RAD + 2 * alpha:
                continue
            used.add(best)
            sc.matched += 1
            if not warm:
                continue
            o = objs[best]
            sc.scored += 1
            sc.by_state[o.state] += 1
            if o.state != "unknown":
                sc.decided += 1
                sc.correct += int((o.state == "moving") == ball.moving)


class _LoopLag:
    """How late the event loop runs a 50 ms timer, at worst (ms)."""

    def __init__(self) -> None:
        self.max_ms = 0.0

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            t = loop.time()
            await asyncio.sleep(0.05)
            self.max_ms = max(self.max_ms, (loop.time() - t - 0.05) * 1000.0)


def _default_state_dir() -> str:
    return tempfile.mkdtemp(prefix="tcm-sitl-state-")


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
    camera_factory: Callable[[MockAutopilot, CameraModel], Any] | None = None,
    links: tuple[Transport, Transport] | None = None,
    log_dir: str | None = None,
) -> SitlReport:
    """Fly ``config.sim.scenario`` for ``duration_s`` (None: until ``stop``).

    Tests may pass their own ``mock`` (to reboot it mid-flight), ``camera_factory``
    (to make the camera fail), and ``links`` — ``(mock side, daemon side)``, opened — in
    place of the loopback UDP pair (to cut the link). ``log_dir``: write the flight log
    there (``[logging]`` settings).
    """
    from ..io.cameras.sim import SimulatedCamera

    sim = config.sim
    mcfg = mock_config or MockAutopilotConfig(
        scenario=sim.scenario.upper(),
        seed=sim.seed,
        noise=sim.telemetry_noise,
        ekf_origin_delay_us=sim.ekf_origin_delay_us,
        brake_on_collision=sim.brake_on_collision,
        unix_us_at_start=time.time_ns() // 1000,
    )
    stop = stop if stop is not None else asyncio.Event()
    now_us = time.monotonic_ns() // 1000
    if mock is None:
        mock = MockAutopilot(mcfg, now_us)
    else:
        mcfg = mock.config
    model = camera_model
    if model is None:
        from ..core.camera import Equirectangular

        model = Equirectangular(360, 220)
    if cameras is None:
        if camera_factory is not None:
            source = camera_factory(mock, model)
        else:
            source = SimulatedCamera.for_mock(
                model, mock, noise_dn=config.camera.source.sim_noise_dn
            )
        cameras = [CameraInput("camera0", model, source)]

    own_state = state_dir is None and not config.daemon.state_dir
    sdir = state_dir or config.daemon.state_dir or _default_state_dir()
    settings = resolve_state_paths(config.mavlink, sdir)

    if links is not None:
        mock_link, daemon_link = links
    else:
        mock_link = open_transport("udpin:127.0.0.1:0")
        await mock_link.open()
        host, port = mock_link.local_address  # type: ignore[attr-defined]
        daemon_link = open_transport(f"udpout:{host}:{port}")
        await daemon_link.open()
    scorer = _Scorer(mock, cameras[0].model, now_us)
    endpoint, warnings = make_endpoint(settings, now_us)
    for w in warnings:
        log.warning("%s", w)
    writer = None
    log_state = None
    if log_dir is not None and config.logging.enabled:
        writer, log_state = start_flight_log(
            config, Path(log_dir), cameras, endpoint, asyncio.get_running_loop()
        )
    daemon = Daemon(
        replace(config, mavlink=settings),
        cameras,
        transport=daemon_link,
        endpoint=endpoint,
        notifier=notifier,
        on_result=scorer,
        on_status=on_status,
        flight_log=writer,
        log_state=log_state,
    )
    mock_stop = asyncio.Event()
    lag = _LoopLag()
    lag_task = asyncio.create_task(lag.run(), name="loop lag")
    try:
        mock_task = asyncio.create_task(
            run_mock_autopilot(mock_link, mcfg, mock_stop, autopilot=mock), name="mock"
        )
        timer: asyncio.Task[Any] | None = None
        if duration_s is not None:

            async def _stop_after() -> None:
                await asyncio.sleep(duration_s)
                stop.set()

            timer = asyncio.create_task(_stop_after(), name="duration")
        try:
            summary = await daemon.run(stop)
            persist(settings, endpoint)
        finally:
            if timer is not None:
                timer.cancel()
            # The autopilot takes in the daemon's last messages before anything else may
            # hold things up, then the log drains off the loop (a PNG backlog takes a
            # while; blocking the loop on it would delay what the mock still receives
            # and make those statuses look stale).
            mock_stop.set()
            with contextlib.suppress(Exception):
                async with asyncio.timeout(2.0):
                    await mock_task
            if writer is not None:
                await asyncio.to_thread(writer.stop)
    finally:
        await daemon_link.close()
        await mock_link.close()
        if own_state:
            for f in Path(sdir).glob("*"):
                with contextlib.suppress(OSError):
                    f.unlink()
            with contextlib.suppress(OSError):
                os.rmdir(sdir)

    lag_task.cancel()
    # The daemon and the mock share this process's event loop. When the machine stalls
    # the whole loop (a loaded CI runner), a status can reach the mock over a second
    # after capture, and the mock rightly calls it stale. That is the machine, not the
    # daemon's time base: such "stale" records are excused, and reported, only when the
    # loop was measured to stall for at least half a second.
    stalled = lag.max_ms >= 500.0
    problems = [
        r for r in mock.received_status if not r.ok and not (stalled and r.problems == ("stale",))
    ]
    excused = sum(1 for r in mock.received_status if not r.ok) - len(problems)
    kinds: Counter[str] = Counter()
    for r in problems:
        for p in r.problems:
            kinds[p] += 1
    failures = []
    if summary.processed == 0:
        failures.append("no frame was processed")
    if not summary.frames_balance:
        failures.append("frame counts do not add up")
    if not mock.received_status and summary.processed > 0 and scorer.score.matched > 0:
        failures.append("the autopilot received no TCM_OBJECT_STATUS")
    if problems:
        failures.append(f"{len(problems)} status messages failed the autopilot's checks")
    if writer is not None:
        lg = writer.stats
        delivered = sum(c.delivered for c in summary.camera_stats.values())
        if lg.frames_logged + lg.frames_dropped_queue + lg.frames_dropped_disk != delivered:
            failures.append("flight log: frames logged + dropped != frames delivered")
    if summary.watchdog_withheld:
        failures.append(f"watchdog withheld {summary.watchdog_withheld} times")
    return SitlReport(
        scenario=mcfg.scenario,
        summary=summary,
        score=scorer.score,
        braked=mock.braking is not None,
        mock_status_received=len(mock.received_status),
        mock_status_problems=len(problems),
        mock_problem_kinds=dict(kinds),
        failures=failures,
        loop_lag_max_ms=lag.max_ms,
        stale_excused=excused,
        log=writer.stats if writer is not None else None,
        statustexts=endpoint.statustexts_queued,
    )
