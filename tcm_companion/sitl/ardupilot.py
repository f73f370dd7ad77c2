"""The daemon against real ArduCopter SITL: the applet loaded, a flight, a ball on a collision course.

``tcm-companion sitl --autopilot ardupilot --scenario crossing|headon`` (and
tests/test_ardupilot_flight.py) runs, in one process and in real time:

- ArduPilot's own SITL binary (:class:`~tcm_companion.sitl.ardupilot_vehicle.ArduPilotSitl`:
  ``$TCM_ARDUPILOT_SITL`` or ``../shared/ardupilot-sitl/bin/arducopter``) with Lua on and
  ``tools/ardupilot/tcm_avoid.lua`` in its ``scripts/``; a ground-station link on SERIAL0
  that flies the vehicle (GUIDED, take-off, a steady velocity) and records its modes and
  texts;
- the daemon on SERIAL1 (TCP), exactly as it runs on a drone: TIMESYNC, streams, statuses,
  health;
- a simulated camera on SERIAL2 (:class:`~tcm_companion.sim.scene.autopilot_camera.
  AutopilotSimCamera`) that renders the simulated field from the pose the autopilot
  reports, and launches a ball on a collision course once the vehicle flies steadily:
  ``crossing`` (from the right, constant bearing) or ``headon`` (a stationary ball dead
  ahead: no TCM state there, only looming).

:func:`fly_scene` makes one such flight with a running SITL and returns a
:class:`FlightReport`: when the ball appeared, the daemon's first alarming frame (a status
the applet alarms on: collision course, ``0 < ttc < TCMA_TTC``, ``ttc_confidence >=
TCMA_MIN_CONF``), when the vehicle entered BRAKE (its heartbeat, and the applet's text),
how long the alarm held and whether the vehicle stayed braked meanwhile, the closest
approach, and whether a pilot's mode change made the applet stand down.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import re
import tempfile
import time
from collections import Counter
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import AppConfig
from ..core.camera import CameraModel
from ..core.pipeline import FrameResult
from ..io.aio import monotonic_us
from ..io.cameras.base import FrameSource
from ..io.scoring import match_truth
from ..io.transports import open_transport
from ..mavlink.copter_modes import mode_name, mode_number
from ..mavlink.endpoint import CompanionEndpoint
from ..service.daemon import CameraInput, DaemonSummary
from ..service.runner import open_service
from ..sim.scene.autopilot_camera import AutopilotSimCamera, Launch, SceneConfig
from ..sim.scene.cameras import rig_cameras
from .ardupilot_vehicle import ArduPilotSitl

log = logging.getLogger(__name__)

APPLET = Path(__file__).resolve().parents[2] / "tools" / "ardupilot" / "tcm_avoid.lua"
SCENES = ("crossing", "headon")
BRAKE = mode_number("BRAKE")
#: What the flights set on the firmware: Lua on (the applet), proximity off (nothing must
#: need our OBSTACLE_DISTANCE to arm), and the applet's action BRAKE.
SITL_PARAMS: dict[str, float] = {"SCR_ENABLE": 1, "PRX1_TYPE": 0}
APPLET_PARAMS: dict[str, float] = {"TCMA_ACTION": 2}
#: The ball matches the daemon's object nearest its bearing within this plus its true
#: angular diameter (:func:`~tcm_companion.io.scoring.match_truth`, the evaluation's rule;
#: these flights have always used a gate a degree wider than its MATCH_GATE_RAD, kept so
#: that their reports and traces stay as they were).
MATCH_GATE_RAD = math.radians(6.0)
CLEAR_TEXT = r"^TCM: collision alarm clear"


@dataclass(frozen=True)
class FlightPlanAP:
    """One flight: the scene, and how the ground station flies and what the "pilot" does.

    ``heading_deg``: the direction flown (clockwise from north) at ``speed_mps``,
    ``altitude_m`` above home; ``pilot_mode``/``pilot_after_s``: if set, the pilot switches
    to that mode this long after the vehicle entered BRAKE (the applet must stand down);
    ``watch_s``: how long to keep watching after BRAKE (or after the predicted contact,
    when there was none) for the alarm to clear.
    """

    scene: SceneConfig = field(default_factory=SceneConfig)
    heading_deg: float = 0.0
    speed_mps: float = 2.0
    altitude_m: float = 5.0
    pilot_mode: str | None = None
    pilot_after_s: float = 1.0
    watch_s: float = 8.0
    ttc_alarm_s: float = 3.0  # TCMA_TTC
    min_conf_pct: int = 50  # TCMA_MIN_CONF
    # the daemon's TCM_* parameters, set from the ground station through ArduPilot
    companion_params: tuple[tuple[str, float], ...] = ()
    # A camera rig (sim.scene.cameras.RIGS, or "config": the configuration's [[cameras]];
    # None: its one camera): one daemon camera per rig camera, all rendered from the pose
    # the autopilot reports.
    rig: str | None = None
    # Turn: this long after the ball's launch, the vehicle turns its nose by turn_deg
    # (positive clockwise) and flies on along the same velocity, so that a ball held at
    # a constant bearing crosses from one camera's view into another's. The flight then
    # commands its heading (heading_deg) from the start.
    turn_deg: float = 0.0
    turn_after_s: float = 1.5


@dataclass(frozen=True)
class TraceRow:
    """The ball in one processed frame: what the daemon estimated against the truth."""

    t_capture_us: int
    track_id: int  # the object matched to the ball (-1: none)
    ttc_s: float  # estimated (NaN: none)
    ttc_confidence: float
    collision_course: bool
    miss_radii: float
    alpha_rad: float  # measured angular radius (NaN: not matched)
    alpha_true_rad: float
    range_m: float  # true centre range
    ttc_true_s: float  # true range over closing speed (inf when not closing)
    state: str


@dataclass(frozen=True)
class AlarmFrame:
    """A processed frame whose status the applet alarms on."""

    t_mono_us: int  # when the daemon sent it (companion monotonic clock)
    t_capture_us: int
    track_id: int
    ttc_s: float
    ttc_confidence_pct: int
    state: str
    reason: str
    camera_id: int = 0


class _Recorder:
    """The daemon's results as they go out: alarming frames, states, closest approach."""

    def __init__(self, camera: AutopilotSimCamera, plan: FlightPlanAP) -> None:
        self.camera = camera
        self.plan = plan
        self.frames = 0
        self.alarms: list[AlarmFrame] = []
        self.states: Counter[str] = Counter()
        self.min_clearance_m = math.inf  # centre distance minus the ball's radius
        self.matched = 0
        self.trace: list[TraceRow] = []
        self._last: tuple[int, float] | None = None  # (t_us, range_m) of the last frame
        self.matched_by_camera: Counter[int] = Counter()  # a rig: frames matched per camera
        self.first_matched_us: dict[int, int] = {}  # a rig: camera id -> first match

    def __call__(self, camera_id: int, result: FrameResult) -> None:
        now = monotonic_us()
        self.frames += 1
        for o in result.objects:
            conf = round(100 * max(0.0, min(1.0, o.ttc_confidence))) if o.ttc_s == o.ttc_s else 0
            if (
                o.collision_course
                and 0.0 < o.ttc_s < self.plan.ttc_alarm_s
                and conf >= self.plan.min_conf_pct
            ):
                self.alarms.append(
                    AlarmFrame(
                        now, result.t_us, o.track_id, o.ttc_s, conf, o.state, o.reason, camera_id
                    )
                )
        truth = self.camera.truth_at(result.t_us)
        if truth.pos_ned_m is None or not truth.ball_centres_ned_m:
            return
        centre, radius = truth.ball_centres_ned_m[0], truth.ball_radii_m[0]
        rel = np.asarray(centre) - np.asarray(truth.pos_ned_m)
        dist = float(np.linalg.norm(rel))
        self.min_clearance_m = min(self.min_clearance_m, dist - radius)
        objs = [o for o in result.objects if o.detected]
        m = match_truth(rel, radius, [o.bearing_ned for o in objs], set(), MATCH_GATE_RAD)
        if m.matched:
            self.matched_by_camera[camera_id] += 1
            self.first_matched_us.setdefault(camera_id, result.t_us)
        elif camera_id != 0:
            return  # a rig's other cameras: a trace row only where they see the ball
        ttc_true = math.inf
        if self._last is not None and result.t_us > self._last[0]:
            closing = (self._last[1] - dist) / ((result.t_us - self._last[0]) * 1e-6)
            ttc_true = dist / closing if closing > 1e-3 else math.inf
        self._last = (result.t_us, dist)
        alpha = m.alpha_true_rad
        nan = math.nan
        if m.matched:
            o = objs[m.index]
            self.matched += 1
            self.states[o.state] += 1
            self.trace.append(
                TraceRow(
                    result.t_us,
                    o.track_id,
                    o.ttc_s,
                    o.ttc_confidence,
                    o.collision_course,
                    o.miss_radii,
                    o.angular_radius_rad,
                    alpha,
                    dist,
                    ttc_true,
                    o.state,
                )
            )
        else:
            self.trace.append(
                TraceRow(result.t_us, -1, nan, 0.0, False, nan, nan, alpha, dist, ttc_true, "")
            )


@dataclass
class FlightReport:
    """What happened in one flight; times are seconds after the ground station commanded
    the steady flight (``t0``), on the companion's monotonic clock."""

    scene: str
    plan: FlightPlanAP
    t0_s: float
    launch: Launch | None
    alarms: list[AlarmFrame]
    brake_heartbeat_s: float | None  # the autopilot's heartbeat first said BRAKE
    brake_text_s: float | None  # the applet's "... -> BRAKE" text
    brake_text: str
    clear_text_s: float | None  # the applet's "collision alarm clear"
    stand_down_text_s: float | None
    pilot_mode_s: float | None  # when the "pilot" switched mode
    modes: list[tuple[float, str]]  # (t, mode) from the first BRAKE on
    texts: list[tuple[float, str]]  # every STATUSTEXT seen, from t0 on
    # AP_Avoidance's COLLISION reports (t, id, threat_level, action): the firmware's view of
    # our ADSB_VEHICLE (TCM_OUT_ADSB) with ADSB_TYPE = 1 and AVD_ENABLE = 1
    collisions: list[tuple[float, int, int, int]]
    min_clearance_m: float
    states: dict[str, int]
    matched_frames: int
    trace: list[TraceRow]
    summary: DaemonSummary | None
    camera_stats: dict[str, Any]
    failures: list[str] = field(default_factory=list)
    # The applet's TCM_STALE once a second (t, statuses dropped as stale in that second):
    # time_boot_ms more than TCMA_MAX_AGE off the autopilot's clock, or queued too long
    stale: list[tuple[float, float]] = field(default_factory=list)
    # The autopilot's clock against ours over the flight, from LOCAL_POSITION_NED's
    # time_boot_ms: (rate, most it fell behind s); None without two such messages. A
    # starved SITL's simulated clock falls behind, and TIMESYNC'd stamps drift from it.
    sitl_clock: tuple[float, float] | None = None
    # A rig: its cameras' names (camera id order), the frames in which each matched the
    # ball and when it first did (s, the companion clock), and when the vehicle turned.
    cameras: tuple[str, ...] = ()
    matched_by_camera: dict[int, int] = field(default_factory=dict)
    first_matched_s: dict[int, float] = field(default_factory=dict)
    turn_s: float | None = None

    @property
    def ok(self) -> bool:
        return not self.failures

    def rel(self, t_s: float | None) -> float | None:
        return None if t_s is None else t_s - self.t0_s

    @property
    def ball_track_ids(self) -> list[int]:
        """The daemon's track ids matched to the ball, in order (a rig: one if the
        handover from camera to camera kept the id)."""
        return sorted({row.track_id for row in self.trace if row.track_id >= 0})

    @property
    def first_alarm_s(self) -> float | None:
        return self.alarms[0].t_mono_us / 1e6 if self.alarms else None

    @property
    def first_alarm_truth(self) -> TraceRow | None:
        """The truth at the first alarming frame (true range and time to contact)."""
        if not self.alarms:
            return None
        t = self.alarms[0].t_capture_us
        return next((row for row in self.trace if row.t_capture_us == t), None)

    @property
    def brake_s(self) -> float | None:
        """When the vehicle was in BRAKE: the earlier of its heartbeat and the applet's text."""
        ts = [t for t in (self.brake_heartbeat_s, self.brake_text_s) if t is not None]
        return min(ts) if ts else None

    @property
    def alarm_to_brake_s(self) -> float | None:
        if self.first_alarm_s is None or self.brake_s is None:
            return None
        return self.brake_s - self.first_alarm_s

    @property
    def alarm_held_s(self) -> float | None:
        """From BRAKE to the applet's "collision alarm clear" (None if it never cleared)."""
        if self.brake_s is None or self.clear_text_s is None:
            return None
        return self.clear_text_s - self.brake_s

    @property
    def left_brake_while_alarm(self) -> list[tuple[float, str]]:
        """Mode changes away from BRAKE between BRAKE and the alarm clearing that the pilot
        did not make."""
        if self.brake_s is None:
            return []
        end = self.clear_text_s if self.clear_text_s is not None else math.inf
        pilot = self.pilot_mode_s if self.pilot_mode_s is not None else math.inf
        return [
            (t, m) for t, m in self.modes if self.brake_s < t < min(end, pilot) and m != "BRAKE"
        ]

    def lines(self) -> list[str]:
        def at(t: float | None) -> str:
            r = self.rel(t)
            return "never" if r is None else f"+{r:.2f} s"

        out = [
            f"ArduCopter SITL, {self.scene}: GUIDED at {self.plan.speed_mps:.1f} m/s, "
            f"{self.plan.altitude_m:.0f} m up, heading {self.plan.heading_deg:.0f}°"
        ]
        la = self.launch
        if la is None:
            out.append("  the ball was never launched (the vehicle did not fly steadily)")
        else:
            rng = float(
                np.linalg.norm(
                    np.asarray(la.ball.centre_ned_m(0.0)) - np.asarray(la.vehicle_pos_ned_m)
                )
            )
            out.append(
                f"  ball launched {at(la.launch_us / 1e6)} at {rng:.1f} m, predicted contact"
                f" {at(la.contact_us / 1e6)}"
            )
        if len(self.cameras) > 1:
            seen = ", ".join(
                f"{name} {self.matched_by_camera.get(cid, 0)} frames"
                + (
                    f" (from {at(self.first_matched_s[cid])})"
                    if cid in self.first_matched_s
                    else ""
                )
                for cid, name in enumerate(self.cameras)
            )
            turned = (
                f"; turned {self.plan.turn_deg:+.0f}° {at(self.turn_s)}"
                if self.turn_s is not None
                else ""
            )
            out.append(
                f"  rig {self.plan.rig}: the ball matched in {seen}{turned}; its track ids"
                f" {self.ball_track_ids} (one: the handover kept it)"
            )
        if self.alarms:
            a = self.alarms[0]
            cam = f" camera {self.cameras[a.camera_id]}," if len(self.cameras) > 1 else ""
            out.append(
                f"  first alarming frame {at(self.first_alarm_s)}:{cam} track {a.track_id}, TTC"
                f" {a.ttc_s:.2f} s, ttc_confidence {a.ttc_confidence_pct}%, state {a.state}"
                + (f" ({a.reason})" if a.reason else "")
                + f"; {len(self.alarms)} alarming frames over"
                f" {(self.alarms[-1].t_mono_us - a.t_mono_us) / 1e6:.2f} s"
            )
            truth = self.first_alarm_truth
            if truth is not None:
                out.append(
                    f"  truth then: range {truth.range_m:.1f} m, time to contact"
                    f" {truth.ttc_true_s:.2f} s (centre range over closing speed)"
                )
        else:
            out.append("  the daemon never sent an alarming status")
        d = self.alarm_to_brake_s
        out.append(
            f"  BRAKE: heartbeat {at(self.brake_heartbeat_s)}, applet {at(self.brake_text_s)}"
            + (f" ({self.brake_text!r})" if self.brake_text else "")
            + (f": {1000 * d:.0f} ms after the first alarming frame" if d is not None else "")
        )
        held = self.alarm_held_s
        out.append(
            "  alarm "
            + (
                f"held {held:.2f} s (clear {at(self.clear_text_s)})"
                if held is not None
                else "did not clear while watched"
            )
            + (
                "; vehicle stayed in BRAKE"
                if not self.left_brake_while_alarm
                else f"; LEFT BRAKE: {self.left_brake_while_alarm}"
            )
        )
        if self.collisions:
            t, ident, threat, action = self.collisions[0]
            out.append(
                f"  AP_Avoidance: COLLISION id {ident:#x} threat {threat} action {action}"
                f" {at(t)} ({len(self.collisions)} reports)"
            )
        if self.pilot_mode_s is not None:
            out.append(
                f"  pilot switched to {self.plan.pilot_mode} {at(self.pilot_mode_s)}; applet"
                f" stood down {at(self.stand_down_text_s)}"
            )
        out.append(
            f"  closest approach: {self.min_clearance_m:.2f} m from the ball's surface;"
            f" states of the ball {self.states or '{}'} ({self.matched_frames} frames matched)"
        )
        if self.summary is not None:
            s = self.summary
            out.append(
                f"  daemon: {s.frames_text()}; latency p50"
                f" {s.latency_percentile_ms(50):.1f} ms, p99 {s.latency_percentile_ms(99):.1f} ms;"
                f" faults {s.faults or 'none'}"
            )
        dropped = sum(v for _, v in self.stale)
        out.append(
            f"  applet: {dropped:.0f} statuses dropped as stale"
            + (
                " ("
                + ", ".join(f"{v:.0f} in the second to {at(t)}" for t, v in self.stale if v)
                + ")"
                if dropped
                else ""
            )
            + f"; {len(self.stale)} TCM_STALE reports"
            + (
                f"; SITL clock {self.sitl_clock[0]:.3f}x ours, at most"
                f" {1000 * self.sitl_clock[1]:.0f} ms behind"
                if self.sitl_clock is not None
                else "; SITL clock not seen"
            )
        )
        tcm = [f"{at(t)} {x}" for t, x in self.texts if x.startswith("TCM") or x.startswith("Lua")]
        if tcm:
            out.append("  texts: " + " | ".join(tcm[:12]))
        if self.failures:
            out.append("  FAILED: " + "; ".join(self.failures))
        return out


async def _until(pred: Callable[[], bool], timeout_s: float, step_s: float = 0.02) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() >= deadline:
            return False
        await asyncio.sleep(step_s)
    return True


def _text_time(texts: list[tuple[float, str]], pattern: str) -> tuple[float | None, str]:
    rx = re.compile(pattern)
    for t, x in texts:
        if rx.search(x):
            return t, x
    return None, ""


@contextlib.asynccontextmanager
async def daemon_on_sitl(
    config: AppConfig,
    sitl: ArduPilotSitl,
    camera: AutopilotSimCamera | list[CameraInput],
    state_dir: str,
    **daemon_kwargs: Any,
) -> AsyncIterator[tuple[asyncio.Task[DaemonSummary], CompanionEndpoint]]:
    """The daemon on the SITL's SERIAL1 with ``camera`` (the configuration's camera; or
    the cameras of a rig, as given), its state in ``state_dir``, as it runs on a drone:
    yields its task and endpoint; stopped (its state persisted, its link closed) on exit.
    The task's result is the run's summary, or the exception that ended it."""
    link = open_transport(sitl.serial1_url)
    await link.open()
    cam = config.camera
    cameras = camera if isinstance(camera, list) else [CameraInput(cam.name, cam.model, camera)]
    try:
        async with open_service(
            config,
            cameras,
            state_dir=state_dir,
            transport=link,
            **daemon_kwargs,
        ) as service:
            stop = asyncio.Event()
            task = asyncio.create_task(service.run(stop), name="daemon")
            try:
                yield task, service.endpoint
            finally:
                stop.set()
                await asyncio.wait([task])
    finally:
        await link.close()


async def fly_scene(
    config: AppConfig,
    sitl: ArduPilotSitl,
    plan: FlightPlanAP,
    *,
    state_dir: str | None = None,
    on_status: Callable[[str], None] | None = None,
) -> FlightReport:
    """One flight against a running SITL (the applet loaded, see :data:`SITL_PARAMS`):
    start the daemon and the camera, take off (or go back to GUIDED), fly steadily until
    the scene's ball is launched and the applet brakes, watch, stop the daemon."""
    cam_cfg = config.camera
    lenses: list[tuple[str, CameraModel]]
    if plan.rig is None:
        lenses = [(cam_cfg.name, cam_cfg.model)]
    elif plan.rig == CONFIG_RIG:
        lenses = [(c.name, c.model) for c in config.cameras]
    else:
        lenses = rig_cameras(plan.rig)
    camera = AutopilotSimCamera(
        lenses[0][1],
        sitl.serial2_url,
        plan.scene,
        fps=cam_cfg.source.fps,
        heading_deg=plan.heading_deg,
        seed=cam_cfg.source.sim_seed,
        noise_dn=cam_cfg.source.sim_noise_dn,
        views=lenses[1:],
    )
    fps = cam_cfg.source.fps
    cameras: AutopilotSimCamera | list[CameraInput] = camera
    if plan.rig is not None:
        sources: list[FrameSource] = [camera, *camera.views]
        cameras = [
            CameraInput(name, model, src, fps=fps)
            for (name, model), src in zip(lenses, sources, strict=True)
        ]
    recorder = _Recorder(camera, plan)
    turn_t: float | None = None
    t0 = time.monotonic()
    pilot_t: float | None = None
    summary: DaemonSummary | None = None
    failures: list[str] = []
    with contextlib.ExitStack() as stack:
        sdir = state_dir or stack.enter_context(tempfile.TemporaryDirectory(prefix="tcm-ap-"))
        async with daemon_on_sitl(
            config, sitl, cameras, sdir, on_result=recorder, on_status=on_status
        ) as (task, endpoint):
            if not await _until(lambda: recorder.frames >= 10 or task.done(), 20.0):
                failures.append("the daemon processed no frames within 20 s")
            if task.done():
                task.result()  # raise what stopped it
            for name, value in APPLET_PARAMS.items():
                await asyncio.to_thread(sitl.gcs.set_param, name, value)
            for name, value in plan.companion_params:
                await asyncio.to_thread(
                    sitl.gcs.set_param, name, value, 10.0, endpoint.component_id
                )
            await asyncio.to_thread(sitl.gcs.set_param, "TCMA_TTC", plan.ttc_alarm_s)
            await asyncio.to_thread(sitl.gcs.set_param, "TCMA_MIN_CONF", plan.min_conf_pct)
            if sitl.gcs.armed:
                await asyncio.to_thread(sitl.set_mode, "GUIDED")
            else:
                await asyncio.to_thread(sitl.takeoff, plan.altitude_m)
            h = math.radians(plan.heading_deg)
            vn, ve = plan.speed_mps * math.cos(h), plan.speed_mps * math.sin(h)
            steered = plan.rig is not None or plan.turn_deg != 0.0
            t0 = time.monotonic()
            sitl.fly_velocity(vn, ve, 0.0, h if steered else None)
            if not await _until(lambda: camera.launch is not None, 15.0):
                failures.append("the ball was not launched within 15 s of steady flight")
            else:
                launch = camera.launch
                assert launch is not None
                if plan.turn_deg != 0.0:
                    turn_at_s = launch.launch_us / 1e6 + plan.turn_after_s
                    await _until(
                        lambda: sitl.gcs.mode == BRAKE, max(0.0, turn_at_s - time.monotonic())
                    )
                    if sitl.gcs.mode != BRAKE:
                        turn_t = time.monotonic()
                        sitl.fly_velocity(vn, ve, 0.0, h + math.radians(plan.turn_deg))
                left_s = launch.contact_us / 1e6 + 2.0 - time.monotonic()
                await _until(lambda: sitl.gcs.mode == BRAKE, max(0.5, left_s))
            sitl.stop_velocity()
            watch_until = time.monotonic() + plan.watch_s
            if sitl.gcs.mode == BRAKE and plan.pilot_mode is not None:
                await asyncio.sleep(plan.pilot_after_s)
                pilot_t = time.monotonic()
                await asyncio.to_thread(sitl.set_mode, plan.pilot_mode)

            def cleared() -> bool:
                return (
                    _text_time([(x.t_s, x.text) for x in sitl.gcs.statustexts(t0)], CLEAR_TEXT)[0]
                    is not None
                )

            await _until(cleared, max(0.0, watch_until - time.monotonic()))
            await asyncio.sleep(0.3)  # the last heartbeats and texts
        try:
            summary = task.result()
        except Exception as exc:  # reported, not raised: the report says what happened
            failures.append(f"the daemon failed: {exc!r}")

    texts = [(s.t_s, s.text) for s in sitl.gcs.statustexts(t0)]
    brake_hb = next(
        (m.t_s for m in sitl.gcs.mode_changes() if m.mode == BRAKE and m.t_s >= t0), None
    )
    brake_text_t, brake_text = _text_time(texts, r"-> BRAKE$")
    clear_t, _ = _text_time(texts, CLEAR_TEXT)
    stand_t, _ = _text_time(texts, r"^TCM: pilot mode change, standing down")
    first_brake = min((t for t in (brake_hb, brake_text_t) if t is not None), default=None)
    modes = [
        (m.t_s, mode_name(m.mode))
        for m in sitl.gcs.mode_changes()
        if first_brake is not None and m.t_s >= first_brake - 1e-3
    ]
    report = FlightReport(
        scene=plan.scene.kind,
        plan=plan,
        t0_s=t0,
        launch=camera.launch,
        alarms=recorder.alarms,
        brake_heartbeat_s=brake_hb,
        brake_text_s=brake_text_t,
        brake_text=brake_text,
        clear_text_s=clear_t,
        stand_down_text_s=stand_t,
        pilot_mode_s=pilot_t,
        modes=modes,
        texts=texts,
        collisions=[
            (m.t_s, int(m.msg.id), int(m.msg.threat_level), int(m.msg.action))
            for m in sitl.gcs.messages("COLLISION", since_s=t0)
        ],
        min_clearance_m=recorder.min_clearance_m,
        states=dict(recorder.states),
        matched_frames=recorder.matched,
        trace=recorder.trace,
        summary=summary,
        camera_stats=camera.stats(),
        failures=failures,
        stale=[
            (m.t_s, float(m.msg.value))
            for m in sitl.gcs.messages("NAMED_VALUE_FLOAT", since_s=t0)
            if m.msg.name == "TCM_STALE"
        ],
        sitl_clock=_sitl_clock(
            [(m.t_s, m.msg.time_boot_ms) for m in sitl.gcs.messages("LOCAL_POSITION_NED", t0)]
        ),
        cameras=tuple(name for name, _ in lenses) if plan.rig is not None else (),
        matched_by_camera=dict(recorder.matched_by_camera),
        first_matched_s={c: t / 1e6 for c, t in recorder.first_matched_us.items()},
        turn_s=turn_t,
    )
    report.failures += _judge(report)
    return report


def _sitl_clock(samples: list[tuple[float, int]]) -> tuple[float, float] | None:
    """(rate of the autopilot's ``time_boot_ms`` against our receive times, most it fell
    behind them, s) over ``samples`` of (receive time s, time_boot_ms); None if fewer
    than two or no time passed."""
    if len(samples) < 2 or not samples[-1][0] > samples[0][0]:
        return None
    (w0, b0), (w1, b1) = samples[0], samples[-1]
    rate = (b1 - b0) / 1000.0 / (w1 - w0)
    behind = max((w - w0) - (b - b0) / 1000.0 for w, b in samples)
    return rate, behind


def _judge(r: FlightReport) -> list[str]:
    """What makes a flight fail (the CLI's exit code; the tests assert each separately)."""
    out = []
    if r.launch is not None and not r.alarms:
        out.append("no alarming status from the daemon")
    if r.alarms and r.brake_s is None:
        out.append("the vehicle never entered BRAKE")
    d = r.alarm_to_brake_s
    if d is not None and d > 0.5:
        out.append(f"BRAKE {d:.2f} s after the first alarm (> 0.5 s)")
    if r.left_brake_while_alarm:
        out.append(f"the vehicle left BRAKE while the alarm held: {r.left_brake_while_alarm}")
    if any(x.startswith("Lua") for _, x in r.texts):
        out.append("the firmware reported a Lua error")
    if r.summary is not None and not r.summary.frames_balance:
        out.append("frame counts do not add up")
    if r.pilot_mode_s is not None and r.stand_down_text_s is None:
        out.append("the applet did not stand down after the pilot's mode change")
    return out


#: ``FlightPlanAP.rig``: the configuration's ``[[cameras]]``.
CONFIG_RIG = "config"
#: A rig flight's turn (degrees, clockwise) after the crossing ball's launch: the ball
#: comes in at 37° right of the nose (in the front camera; the right one starts at 40°),
#: and after the turn at 77° (right camera) for front-right and quad; at 147° (rear
#: camera, crossing the unseen side) for front-back.
RIG_TURN_DEG = {"front-right": -40.0, "quad": -40.0, "front-back": -110.0, "panorama": 0.0}


def rig_plan(
    scene: str = "crossing", rig: str = "front-right", pilot_mode: str | None = None
) -> FlightPlanAP:
    """The flight of ``scene`` with camera rig ``rig``: the crossing ball appears in one
    camera and, after the vehicle's turn (:data:`RIG_TURN_DEG`), reaches it through
    another (``rig`` :data:`CONFIG_RIG`, the configuration's cameras: no turn)."""
    turn = RIG_TURN_DEG.get(rig, 0.0) if scene == "crossing" else 0.0
    return FlightPlanAP(
        scene=SceneConfig(kind=scene),  # type: ignore[arg-type]
        pilot_mode=pilot_mode,
        rig=rig,
        turn_deg=turn,
    )


async def run_ardupilot_sitl(
    config: AppConfig,
    scene: str = "crossing",
    *,
    on_status: Callable[[str], None] | None = None,
    pilot_mode: str | None = None,
    rig: str | None = None,
) -> FlightReport:
    """Start ArduCopter SITL with the applet, fly ``scene`` once (with camera rig ``rig``:
    :func:`rig_plan`), stop it."""
    if scene not in SCENES:
        raise ValueError(f"scene must be one of {', '.join(SCENES)}, got {scene!r}")
    sitl = ArduPilotSitl(params=SITL_PARAMS, scripts=[APPLET])
    await asyncio.to_thread(sitl.start)
    try:
        if rig is not None:
            plan = rig_plan(scene, rig, pilot_mode)
        else:
            plan = FlightPlanAP(scene=SceneConfig(kind=scene), pilot_mode=pilot_mode)  # type: ignore[arg-type]
        report = await fly_scene(config, sitl, plan, on_status=on_status)
        if not report.ok:
            log.warning("SITL console tail:\n%s", sitl.console_tail(20))
        return report
    finally:
        await asyncio.to_thread(sitl.stop)
