"""One object, one track, whatever the camera (core.rig.RigTracker).

Synthetic per-camera results first (exact geometry, fast): association, the measuring
camera, camera loss, pipeline rebuilds, the cross-camera pair. Then real pipelines on
rendered frames of the quad rig's front and right cameras (slow): an object crossing from
one to the other keeps its id and its decision.
"""

from __future__ import annotations

import asyncio
import csv
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from tcm_companion.core.camera import CameraModel
from tcm_companion.core.classify import Classification, State, unknown
from tcm_companion.core.egomotion import TranslationEstimate
from tcm_companion.core.frames import FloatArray, azel_from_bearing, normalize
from tcm_companion.core.pipeline import FrameResult, ObjectResult, Pipeline, PipelineConfig
from tcm_companion.core.rig import RigConfig, RigTracker
from tcm_companion.core.telemetry import TelemetryBuffer
from tcm_companion.sim.scene.cameras import rig_cameras
from tcm_companion.sim.scene.export import SimulatedScenario
from tcm_companion.sim.scene.scenarios import ALTITUDE_M, FlightPlan, flight_plan
from tcm_companion.sim.scene.world import Ball, Trajectory, track_axes

QUAD = [cam for _, cam in rig_cameras("quad")]
FRONT_RIGHT = QUAD[:2]  # yaw 0 and 90°, 100° wide each: 40°..50° seen by both
CONFIG = PipelineConfig(always_translate=True)
PERIOD_US = 40_000


# -- synthetic per-camera results ---------------------------------------------------------
def view(
    camera: CameraModel,
    track_id: int,
    bearing_ned: FloatArray,
    alpha_rad: float = 0.05,
    state: str = "unknown",
    reason: str = "warm-up",
    classification: Classification | None = None,
    detected: bool = True,
) -> ObjectResult:
    """Camera ``camera``'s result for an object at ``bearing_ned`` (level, heading north:
    NED = body)."""
    b_ned = np.asarray(normalize(np.asarray(bearing_ned, dtype=np.float64)))
    b_cam = camera.R_body_from_cam.T @ b_ned
    u, v = (float(x) for x in camera.pixel_from_bearing_cam(b_cam))
    az, el = azel_from_bearing(b_ned)
    c = classification if classification is not None else unknown(reason)
    return ObjectResult(
        track_id=track_id,
        detected=detected,
        state=c.state if classification is not None else state,  # type: ignore[arg-type]
        reason=c.reason if classification is not None else reason,
        bearing_cam=b_cam,
        bearing_body=b_ned,
        bearing_ned=b_ned,
        azimuth_ned_rad=float(az),
        elevation_ned_rad=float(el),
        angular_radius_rad=alpha_rad,
        centroid_px=(u, v),
        classification=c,
        ttc_s=math.nan,
        collision_course=False,
        miss_radii=math.nan,
    )


def sees(camera: CameraModel, bearing_ned: FloatArray, alpha_rad: float = 0.05) -> bool:
    """Whether the object's centre is in ``camera``'s image."""
    b_cam = camera.R_body_from_cam.T @ np.asarray(normalize(np.asarray(bearing_ned, float)))
    u, v = camera.pixel_from_bearing_cam(b_cam)
    return bool(0 <= u < camera.width and 0 <= v < camera.height)


def az(deg: float, el_deg: float = -5.0) -> FloatArray:
    e = math.radians(el_deg)
    a = math.radians(deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), -math.sin(e)])


def frame(index: int, t_us: int, *objects: ObjectResult, translation=None) -> FrameResult:  # type: ignore[no-untyped-def]
    return FrameResult(index, t_us, tuple(objects), True, translation, {})


def test_rig_config_refuses_a_negative_gate_by_name() -> None:
    with pytest.raises(ValueError, match="gate_rad"):
        RigConfig(gate_rad=-0.1)
    with pytest.raises(ValueError, match="max_unseen_s"):
        RigConfig(max_unseen_s=math.nan)


def test_an_object_two_cameras_see_is_one_rig_track_reported_once_per_cycle() -> None:
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    reports: list[list[int]] = []
    for i in range(20):
        t = i * PERIOD_US
        b = az(44.0 + 0.05 * i)  # in the 10° overlap, drifting slowly
        a = rig.fuse(0, frame(i, t, view(FRONT_RIGHT[0], 7, b)))
        c = rig.fuse(1, frame(i, t, view(FRONT_RIGHT[1], 3, b)))
        reports.append([o.track_id for o in a.objects] + [o.track_id for o in c.objects])
    assert all(len(r) == 1 for r in reports), reports
    assert {r[0] for r in reports} == {1}
    assert rig.stats["merged"] == 20 and rig.stats["handovers"] == 1


def no_attitude(obj: ObjectResult) -> ObjectResult:
    """``obj`` as a frame without attitude reports it: no NED bearing, unknown."""
    nan = np.full(3, np.nan)
    return replace(obj, bearing_ned=nan, azimuth_ned_rad=math.nan, elevation_ned_rad=math.nan)


def test_a_track_first_seen_without_attitude_joins_the_object_once_it_has_a_bearing() -> None:
    """The run's first frames have no attitude: each camera's track of the object in the
    overlap started a rig track with no bearing. Once both have bearings they are one
    object, reported once per cycle (the tracks stayed apart: two statuses a cycle); a
    track alone keeps the rig id it was given."""
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    reports: list[list[int]] = []
    for i in range(20):
        t = i * PERIOD_US
        b = az(44.0 + 0.05 * i)
        a, c = view(FRONT_RIGHT[0], 7, b), view(FRONT_RIGHT[1], 3, b)
        if i < 5:
            a, c = no_attitude(a), no_attitude(c)
        fa = rig.fuse(0, frame(i, t, a))
        fc = rig.fuse(1, frame(i, t, c))
        reports.append([o.track_id for o in fa.objects] + [o.track_id for o in fc.objects])
    assert all(len(r) == 2 for r in reports[:5])  # nothing to tell them apart by yet
    assert all(len(r) == 1 for r in reports[6:]), reports
    assert len({r[0] for r in reports[6:]}) == 1
    lone = RigTracker(FRONT_RIGHT, CONFIG)
    ids = [
        [o.track_id for o in lone.fuse(0, frame(i, i * PERIOD_US, obj)).objects]
        for i, obj in enumerate(
            [no_attitude(view(FRONT_RIGHT[0], 4, az(-20.0)))] * 3
            + [view(FRONT_RIGHT[0], 4, az(-20.0))] * 5
        )
    ]
    assert ids == [[1]] * 8


def test_the_better_placed_view_measures_and_a_small_wobble_does_not_flap() -> None:
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    measured_by: list[int] = []
    path = [41.0 + 0.2 * i for i in range(41)]  # 41° -> 49°: front's edge to right's
    path += [45.0 + 0.4 * math.sin(i) for i in range(20)]  # around the middle
    for i, deg in enumerate(path):
        t = i * PERIOD_US
        out = [rig.fuse(k, frame(i, t, view(cam, 1, az(deg)))) for k, cam in enumerate(FRONT_RIGHT)]
        (cam_id,) = [k for k, r in enumerate(out) if r.objects]
        measured_by.append(cam_id)
    first_right = measured_by.index(1)
    # The front camera keeps it past the middle of the overlap (45°) by the switch margin.
    assert path[first_right] > 45.0 + 0.5
    assert set(measured_by[first_right:41]) == {1}
    assert set(measured_by[41:]) == {1}  # a ±0.4° wobble at 45° stays with the right camera


def test_distinct_objects_far_apart_or_of_other_sizes_or_without_attitude_stay_apart() -> None:
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    nan = np.full(3, np.nan)
    small = 0.01  # rad: whole in both views at 44°
    front = view(FRONT_RIGHT[0], 1, az(44.0), small)
    rig.fuse(0, frame(0, 0, front, view(FRONT_RIGHT[0], 2, az(10.0), small)))
    far = view(FRONT_RIGHT[1], 1, az(60.0), small)  # 16° from the front's object: another
    bigger = view(FRONT_RIGHT[1], 2, az(44.2), 2.5 * small)  # same place, 2.5 times the size
    blind = replace(view(FRONT_RIGHT[1], 3, az(44.1), small), bearing_ned=nan)  # no attitude
    out = rig.fuse(1, frame(0, 0, far, bigger, blind))
    assert sorted(o.track_id for o in out.objects) == [3, 4, 5]
    assert rig.stats["handovers"] == 0
    # ... while the same object, in the gate and of its size, joins the front's track 1.
    same = view(FRONT_RIGHT[1], 4, az(44.3), small)
    out = rig.fuse(1, frame(1, PERIOD_US, far, bigger, blind, same))
    assert rig.stats["handovers"] == 1


def test_camera_lost_forgets_only_what_that_camera_alone_measured() -> None:
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    only_front, both, only_right = az(0.0), az(45.0), az(90.0)
    f = rig.fuse(0, frame(0, 0, view(FRONT_RIGHT[0], 1, only_front), view(FRONT_RIGHT[0], 2, both)))
    r = rig.fuse(1, frame(0, 0, view(FRONT_RIGHT[1], 1, both), view(FRONT_RIGHT[1], 2, only_right)))
    ids = {o.track_id for o in f.objects} | {o.track_id for o in r.objects}
    assert ids == {1, 2, 3}  # three objects, three rig ids
    rig.camera_lost(0)
    assert not rig.has_track(1) and rig.has_track(2) and rig.has_track(3)
    r = rig.fuse(
        1, frame(1, PERIOD_US, view(FRONT_RIGHT[1], 1, both), view(FRONT_RIGHT[1], 2, only_right))
    )
    assert sorted(o.track_id for o in r.objects) == [2, 3]  # the right camera reports both now


def test_a_rebuilt_pipeline_rebinds_its_tracks_to_the_same_rig_ids() -> None:
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    for i in range(5):
        out = rig.fuse(0, frame(i, i * PERIOD_US, view(FRONT_RIGHT[0], 4, az(20.0 + 0.1 * i))))
    assert [o.track_id for o in out.objects] == [1]
    # A new pipeline numbers frames and tracks from scratch: its track 1 is the same object.
    out = rig.fuse(0, frame(0, 5 * PERIOD_US, view(FRONT_RIGHT[0], 1, az(20.5))))
    assert [o.track_id for o in out.objects] == [1]
    out = rig.fuse(
        0,
        frame(
            1, 6 * PERIOD_US, view(FRONT_RIGHT[0], 1, az(20.6)), view(FRONT_RIGHT[0], 4, az(-30.0))
        ),
    )
    assert sorted(o.track_id for o in out.objects) == [1, 2]  # its new track 4: a new object


@dataclass
class Crossing:
    """An object 6 m ahead and 3 m right of a vehicle flying north at 2 m/s (level): its
    bearing sweeps from 27° (front camera) through the overlap to the right camera."""

    moving: bool

    def bearing(self, t_s: float) -> FloatArray:
        obj = np.array([6.0, 3.0 + (1.5 * t_s if self.moving else 0.0), 0.5])
        return np.asarray(normalize(obj - np.array([2.0 * t_s, 0.0, 0.0])))

    def alpha(self, t_s: float) -> float:
        obj = np.array([6.0, 3.0 + (1.5 * t_s if self.moving else 0.0), 0.5])
        return math.asin(0.4 / float(np.linalg.norm(obj - np.array([2.0 * t_s, 0, 0]))))


NORTH = TranslationEstimate(
    np.array([1.0, 0.0, 0.0]), "autopilot", 2.0, math.nan, 1.0, 0, 0.0, True
)


def run_crossing(scene: Crossing, with_rig: bool) -> list[tuple[float, int, ObjectResult]]:
    """Each camera's own results as a pipeline would give them (warm-up for the first
    second of a track, then the state of a perfect classifier), through the rig or not:
    ``(t_s, camera, object)`` of every report."""
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    first: dict[int, float] = {}
    state: State = "moving" if scene.moving else "stationary"
    out: list[tuple[float, int, ObjectResult]] = []
    for i in range(75):
        t_s = i * PERIOD_US * 1e-6
        b, alpha = scene.bearing(t_s), scene.alpha(t_s)
        for k, cam in enumerate(FRONT_RIGHT):
            objs = []
            if sees(cam, b):
                first.setdefault(k, t_s)
                own = t_s - first[k] >= 1.0
                c = (
                    Classification(state, "", disparity=0.5 if scene.moving else 0.0)
                    if own
                    else None
                )
                objs.append(view(cam, 1, b, alpha, classification=c))
            result = frame(i, round(t_s * 1e6), *objs, translation=NORTH)
            if with_rig:
                result = rig.fuse(k, result)
            out.extend((t_s, k, o) for o in result.objects)
    return out


def test_a_rebuilt_pipelines_warm_up_is_decided_from_the_rig_tracks_history() -> None:
    """One camera sees a stationary object for 1.2 s (decided after 1 s), then its
    pipeline is rebuilt (a parameter change): the new track's warm-up is decided from
    the rig track's earlier observations, as one camera's handover to itself."""
    scene, front = Crossing(moving=False), FRONT_RIGHT[0]
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    stationary = Classification("stationary", "", disparity=0.0)
    states = []
    for i in range(35):  # az 27° -> 42°: whole in the front camera
        t_s = i * PERIOD_US * 1e-6
        rebuilt = i >= 30
        own = stationary if (t_s >= 1.0 and not rebuilt) else None
        obj = view(
            front, 1 if rebuilt else 5, scene.bearing(t_s), scene.alpha(t_s), classification=own
        )
        result = frame(i - 30 if rebuilt else i, round(t_s * 1e6), obj, translation=NORTH)
        (out,) = rig.fuse(0, result).objects
        states.append((out.track_id, out.state))
    assert states[:25] == [(1, "unknown")] * 25  # its first second: warm-up
    assert states[25:] == [(1, "stationary")] * 10  # before and after the rebuild


@pytest.mark.parametrize("moving", [False, True])
def test_a_cross_camera_pair_decides_the_new_cameras_young_track(moving: bool) -> None:
    scene = Crossing(moving)
    fused = run_crossing(scene, with_rig=True)
    alone = run_crossing(scene, with_rig=False)
    entered = min(t for t, k, _ in alone if k == 1)
    # Without the rig the right camera's track is warm-up for a whole interval ...
    own = [(t, o.state) for t, k, o in alone if k == 1]
    assert all(s == "unknown" for t, s in own if t < entered + 0.96)
    # ... with it, the object is decided in every report once the front camera decided it
    # (a second after it first saw it), the right camera's included, and keeps its id.
    assert {o.track_id for _, _, o in fused} == {1}
    late = [(t, k, o) for t, k, o in fused if t >= 1.0]
    assert {o.state for _, _, o in late} == {"moving" if moving else "stationary"}
    # The right camera takes the object over once its view is the better placed one,
    # well inside what would be its warm-up, and decides it by cross-camera pairs then.
    took_over = min(t for t, k, _ in fused if k == 1)
    assert entered < took_over < entered + 0.5
    cross = [o for t, k, o in late if k == 1 and t < entered + 0.96]
    assert len(cross) >= 10
    assert all(0.9 < o.classification.interval_s < 1.1 for o in cross)


# -- real pipelines on rendered frames ---------------------------------------------------------
def crossing_plan(duration_s: float, seed: int, moving: bool) -> FlightPlan:
    """The paper's field, a vehicle flying straight at 2 m/s (with the TS flight's wobble
    and turbulence) past a ball 6 m ahead and 3 m to the right, 1 m below it: the ball
    crosses from the quad rig's front camera to its right one about 1.5 s in; ``moving``:
    the ball drifts away to the right at 1 m/s meanwhile."""
    ts = flight_plan("TS", duration_s=duration_s, seed=seed)
    ahead, right = track_axes(ts.heading_rad)
    origin = np.array(ts.vehicle.path.origin_ned_m)
    path = Trajectory(tuple(origin), tuple(2.0 * ahead), ts.vehicle.path.terms[1:])
    centre = origin + 6.0 * ahead + 3.0 * right + np.array([0.0, 0.0, ALTITUDE_M - 1.0])
    ball = Ball(Trajectory.linear(tuple(centre), tuple(1.0 * right if moving else np.zeros(3))))
    vehicle = replace(ts.vehicle, path=path)
    return replace(ts, name="CROSSING", vehicle=vehicle, balls=(ball,))


Reports = list[tuple[int, float, int, ObjectResult]]  # (frame, t_s, camera, object)


def pipeline_results(
    plan: FlightPlan, cameras: Sequence[CameraModel], seed: int
) -> list[list[FrameResult]]:
    """Per frame, each camera's own pipeline result (one telemetry buffer, as in the
    Companion; every camera's frames captured at the same instants)."""
    base = SimulatedScenario(plan, cameras[0], seed=seed)
    scenes = [base, *(base.with_camera(c) for c in cameras[1:])]
    telemetry = sorted(base.telemetry, key=lambda s: s.recv_us)
    buf = TelemetryBuffer()
    pipes = [Pipeline(c, CONFIG, telemetry=buf) for c in cameras]
    out, j = [], 0
    for i, t in enumerate(base.frame_times_us):
        while j < len(telemetry) and telemetry[j].recv_us <= int(t) + 40_000:
            buf.add(telemetry[j])
            j += 1
        out.append([p.step(s.read_frame(i), int(t)) for p, s in zip(pipes, scenes, strict=True)])
    return out


def reports(
    per_frame: list[list[FrameResult]], fuse: Callable[[int, FrameResult], FrameResult]
) -> Reports:
    t0 = per_frame[0][0].t_us
    return [
        (i, (r.t_us - t0) * 1e-6, k, o)
        for i, results in enumerate(per_frame)
        for k, r in enumerate(results)
        for o in fuse(k, r).objects
    ]


def longest_unknown_s(rows: Reports) -> float:
    """The longest run of the object's consecutive reports that are unknown (s)."""
    longest, start = 0.0, None
    for _, t, _, o in rows:
        if o.state == "unknown":
            start = t if start is None else start
            longest = max(longest, t - start + PERIOD_US * 1e-6)
        else:
            start = None
    return longest


@pytest.fixture(scope="module", params=[False, True], ids=["stationary", "moving"])
def crossing(request: pytest.FixtureRequest) -> tuple[bool, list[list[FrameResult]]]:
    moving = bool(request.param)
    return moving, pipeline_results(crossing_plan(3.5, 0, moving), FRONT_RIGHT, 0)


@pytest.mark.slow  # renders and runs two cameras for 3.5 s (~6 s of CPU)
def test_a_rendered_crossing_keeps_its_id_and_its_decision(crossing) -> None:  # type: ignore[no-untyped-def]
    moving, per_frame = crossing
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    fused = reports(per_frame, rig.fuse)
    alone = reports(per_frame, lambda k, r: r)
    assert {o.track_id for *_, o in fused} == {1}
    assert rig.stats["handovers"] >= 1 and rig.stats["merged"] > 0
    expected = "moving" if moving else "stationary"
    assert {o.state for *_, o in fused} <= {expected, "unknown"}
    # Alone, the right camera's tracks need >= 0.4 s (a whole interval for stationary, and
    # the object comes in cut by the image border) before they are decided.
    right = [(t, o) for _, t, k, o in alone if k == 1]
    entered = right[0][0]
    decided = min(t for t, o in right if o.state != "unknown")
    assert decided - entered >= 0.4
    # Through the rig the object stays decided across the handover but for a few frames
    # where every view of it is cut by an image border (<= 0.2 s), and the right camera
    # reports it decided within 0.2 s of taking it over.
    after = [row for row in fused if row[1] >= entered]
    assert longest_unknown_s(after) <= 0.2
    taken = min(t for _, t, k, _ in fused if k == 1)
    first_decided = min(t for _, t, k, o in fused if k == 1 and o.state != "unknown")
    assert first_decided - taken <= 0.2
    assert first_decided < decided - 0.2


@pytest.mark.slow  # shares the rendered crossing
def test_a_rendered_object_in_the_overlap_is_reported_once_per_frame_cycle(crossing) -> None:  # type: ignore[no-untyped-def]
    _, per_frame = crossing
    rig = RigTracker(FRONT_RIGHT, CONFIG)
    fused = reports(per_frame, rig.fuse)
    seen = {i for i, results in enumerate(per_frame) if any(r.objects for r in results)}
    both = {i for i, results in enumerate(per_frame) if all(r.objects for r in results)}
    per_cycle = {i: sum(1 for j, *_ in fused if j == i) for i in seen}
    assert len(both) >= 5  # the object spends frames in the overlap
    assert set(per_cycle.values()) == {1}


# -- the Companion with a rig -------------------------------------------------------------
def scripted(script: Callable[[int, int], FrameResult]) -> Callable[[np.ndarray, int], FrameResult]:
    """A camera pipeline's ``step`` that returns the result ``script`` gives for the
    frame's number and capture time (the Companion's rig fuses it)."""
    count = [0]

    def step(image: np.ndarray, t_us: int) -> FrameResult:
        count[0] += 1
        return script(count[0] - 1, t_us)

    return step


def test_the_companion_builds_a_rig_for_two_cameras_only() -> None:
    from tcm_companion.mavlink.endpoint import CompanionEndpoint
    from tcm_companion.service.companion import Companion

    one = Companion([QUAD[0]], PipelineConfig(), CompanionEndpoint(now_us=0), 0)
    assert one.rig is None and not one.pipeline(0).config.always_translate
    two = Companion(FRONT_RIGHT, PipelineConfig(), CompanionEndpoint(now_us=0), 0)
    assert isinstance(two.rig, RigTracker)
    assert all(two.pipeline(k).config.always_translate for k in (0, 1))
    rig = two.rig
    two._rebuild(two.cameras[0])  # repeated errors
    assert two.rig is rig and two.pipeline(0).config.always_translate
    # A parameter change rebuilds every pipeline; the rig stays and decides with it.
    from tcm_companion.mavlink import tcm_dialect as d

    mav = d.MAVLink(None, srcSystem=255, srcComponent=190)
    param_set = mav.param_set_encode(1, 191, b"TCM_THRESH", 0.2, d.MAV_PARAM_TYPE_REAL32)
    two.receive_data(bytes(param_set.pack(mav)), 1_000)
    assert two.pipeline(1).config.classifier.tcm_threshold == pytest.approx(0.2)
    assert two.rig is rig and rig.pipeline_config == two.pipeline(1).config


def test_a_lost_camera_makes_only_what_it_alone_measured_unknown(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from tcm_companion.mavlink.endpoint import CompanionEndpoint
    from tcm_companion.service.companion import Companion

    from .helpers import decode

    endpoint = CompanionEndpoint(now_us=0)
    comp = Companion(FRONT_RIGHT, PipelineConfig(), endpoint, 0, camera_names=["front", "right"])
    front, right = FRONT_RIGHT
    decided = Classification("stationary", "", disparity=0.01)
    front_step = scripted(
        lambda i, t: frame(
            i, t, view(front, 1, az(0.0), classification=decided), view(front, 2, az(44.0))
        )
    )
    right_step = scripted(
        lambda i, t: frame(
            i, t, view(right, 1, az(44.0)), view(right, 2, az(90.0), classification=decided)
        )
    )
    monkeypatch.setattr(comp.pipeline(0), "step", front_step)
    monkeypatch.setattr(comp.pipeline(1), "step", right_step)
    image = np.zeros((front.height, front.width, 3), np.uint8)
    now = 0
    for i in range(40):  # 1.6 s: both cameras for 0.4 s, then the right camera alone
        now = 100_000 + i * PERIOD_US
        cams = (0, 1) if i < 10 else (1,)
        for k in cams:
            comp.on_frame(k, image, now, now + 1_000)
        for t in range(now + 1_000, now + PERIOD_US, 5_000):
            comp.process_due(t)
        if i == 9:
            endpoint.data_to_send()  # what went before the loss
            # The front camera measures the object both see (it was first; no better view).
            assert [o.track_id for o in comp.last_objects(0)] == [1, 2]
            assert [o.track_id for o in comp.last_objects(1)] == [3]
    assert comp.stats.faults["front stale"] == 1
    rig = comp.rig
    assert rig is not None and not rig.has_track(1) and rig.has_track(2) and rig.has_track(3)
    unknown_sent = [
        m.track_id
        for m in decode(endpoint.data_to_send())
        if m.get_type() == "TCM_OBJECT_STATUS" and m.state == 0
    ]
    # Only the object the front camera alone saw is sent as unknown; the right camera
    # goes on reporting the one both saw, under its rig id.
    assert unknown_sent == [1]
    assert sorted(o.track_id for o in comp.last_objects(1)) == [2, 3]


# -- a rig's flight log ---------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.xdist_group("sitl")  # a real-time SITL run: one at a time
def test_a_rigs_flight_log_replays_every_camera_exactly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The daemon with the quad rig's front and right cameras on the mock autopilot (real
    time, 4 s, PNG frames): ``replay LOG`` recomputes every camera's processed frames in
    the logged order through one Companion (its rig included) and gets the logged results
    exactly; the results CSV names the measuring camera of each row. (Before replay held
    each frame's link bytes to those received before its processing began, the bytes a
    loaded two-camera daemon received while it wrote a turn's output reached replay's
    pipeline too early: a frame without attitude in flight had one in replay.)"""
    from tcm_companion import cli
    from tcm_companion.config import AppConfig
    from tcm_companion.io.aio import monotonic_us
    from tcm_companion.replay.log import compare, replay_log
    from tcm_companion.service.host import CameraInput
    from tcm_companion.sim.scene.truth_camera import SimulatedCamera
    from tcm_companion.sitl.mock_flight import MockAutopilot, _mock_config, run_sitl

    config = AppConfig()
    config = replace(config, logging=replace(config.logging, image_format="png"))
    mock = MockAutopilot(_mock_config(config, time.time_ns() // 1000), monotonic_us())
    noise = config.camera.source.sim_noise_dn
    cams = [
        CameraInput(
            name, model, SimulatedCamera.for_mock(model, mock, fps=10.0, noise_dn=noise), 10.0
        )
        for name, model in rig_cameras("quad")[:2]
    ]
    log = tmp_path / "log"
    asyncio.run(
        run_sitl(
            config,
            cams,
            mock=mock,
            duration_s=4.0,
            state_dir=str(tmp_path / "state"),
            log_dir=str(log),
            min_accuracy=None,
        )
    )
    frames = list(replay_log(log))
    assert {f.camera_id for f in frames} == {0, 1} and len(frames) > 20
    assert not any(f.after_gap for f in frames)
    assert [d for f in frames for d in compare(f)] == []  # bit-exact, every camera
    # The ball (on the right, T90) is one rig track, measured by the right camera.
    assert {(f.camera_id, o.track_id) for f in frames for o in f.result.objects} == {(1, 1)}
    # On the wire: that one track, with the camera that measured it.
    from tcm_companion.flightlog import topics
    from tcm_companion.flightlog.reader import read_log

    from .helpers import decode

    sent = b"".join(rec.data for rec in read_log(log, {topics.MAVLINK_OUT}))
    statuses = [m for m in decode(sent) if m.get_type() == "TCM_OBJECT_STATUS"]
    assert statuses and {(m.track_id, m.camera_id) for m in statuses} == {(1, 1)}
    capsys.readouterr()
    csv_path = tmp_path / "r.csv"
    assert cli.main(["replay", str(log), "--results", str(csv_path), "--check"]) == 0
    rows = list(csv.DictReader(csv_path.open()))
    assert rows and {r["camera"] for r in rows} == {"right"}
    assert {r["track_id"] for r in rows} == {"1"}
