"""Simulator objects of other shapes: rendering geometry, occlusion, shadows, the new
scenarios, truth beyond truth.csv, ``[[target]]`` and ``detections.csv``, and the
simulated box detector's statistics."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from tcm_companion.core.camera import CameraModel, Equirectangular, Fisheye, Pinhole
from tcm_companion.io.scenario import ScenarioError, load_scenario
from tcm_companion.sim import export_scenario, make_scenario
from tcm_companion.sim.scene.detector_sim import (
    DetectorSimConfig,
    TrueBox,
    detections_from_truth,
    simulate_detections,
    true_boxes,
)
from tcm_companion.sim.scene.render import Renderer
from tcm_companion.sim.scene.scenario_io import (
    read_detections_csv,
    read_targets,
    target_spec,
    write_detections_csv,
)
from tcm_companion.sim.scene.scenarios import (
    HEADING_RAD,
    OBJECT_SCENARIO_NAMES,
    PAPER_SCENARIO_NAMES,
    _track_point,
    describe_scenario,
    flight_plan,
    plan_world,
)
from tcm_companion.sim.scene.truth import (
    box_centre_px,
    box_width_px,
    coverage_box_px,
    is_full_panorama,
    project_object,
)
from tcm_companion.sim.scene.world import (
    COLOURS,
    Ball,
    BoxTarget,
    CylinderTarget,
    DiscTarget,
    Target,
    Trajectory,
    field_world,
)

RED = COLOURS["red"]
CAMERAS: dict[str, CameraModel] = {
    "equirectangular": Equirectangular(360, 220),
    "pinhole": Pinhole(
        320, 240, (0.0, -10.0, 90.0), fx=200.0, fy=200.0, cx=160.0, cy=120.0,
        dist=(-0.05, 0.01, 0.0, 0.0, 0.0),
    ),
    "fisheye": Fisheye(
        320, 320, (0.0, -10.0, 60.0), fx=100.0, fy=100.0, cx=160.0, cy=160.0,
        dist=(0.02, -0.005, 0.001, 0.0),
    ),
}  # fmt: skip
SHAPES: dict[str, Target] = {
    "box": BoxTarget(
        Trajectory.static(_track_point(0.5, 6.0, -0.75)), albedo_rgb=RED, yaw_rad=HEADING_RAD + 0.4
    ),
    "cylinder": CylinderTarget(Trajectory.static(_track_point(-1.0, 3.5, -0.9)), albedo_rgb=RED),
    "disc_above": DiscTarget(Trajectory.static(_track_point(-1.0, 3.0, -2.8)), albedo_rgb=RED),
    "disc_below": DiscTarget(Trajectory.static(_track_point(1.0, 3.5, -1.0)), albedo_rgb=RED),
}
PLAN = flight_plan("TS")
FIELD = field_world((), PLAN.heading_rad)


def red_mask(bgr: np.ndarray) -> np.ndarray:
    b, g, r = (bgr[..., i].astype(np.int32) for i in range(3))
    return (r > 40) & (r * 10 > 16 * g) & (r * 10 > 16 * b)


def world_with(*objs: Target):
    balls = tuple(o for o in objs if isinstance(o, Ball))
    targets = tuple(o for o in objs if not isinstance(o, Ball))
    return replace(FIELD, balls=balls, targets=targets)


def pose(t: float = 0.0):
    return PLAN.vehicle.position_ned_m(t), PLAN.vehicle.R_ned_from_body(t)


# --------------------------------------------------------------------------------------
# Rendering geometry
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("shape", list(SHAPES))
@pytest.mark.parametrize("cam_name", list(CAMERAS))
def test_shape_renders_where_it_projects(cam_name, shape):
    cam, obj = CAMERAS[cam_name], SHAPES[shape]
    renderer = Renderer(world_with(obj), cam)
    pos, R = pose()
    img = renderer.render(0.0, pos, R, noise_dn=0.0)
    mask = red_mask(img)
    view = project_object(obj, 0.0, cam, pos, R)
    assert view.box_px is not None and mask.sum() > 30
    vv, uu = np.nonzero(mask)
    x0, y0, x1, y1 = view.box_px
    size = max(x1 - x0, y1 - y0)
    # The silhouette's centroid is near the projected centre (perspective moves it a
    # little for large objects), its extent that of the projected silhouette.
    centroid = np.array([uu.mean() + 0.5, vv.mean() + 0.5])
    assert np.linalg.norm(centroid - view.centre_px) < max(2.0, 0.08 * size)
    mask_box = np.array([uu.min(), vv.min(), uu.max() + 1, vv.max() + 1], float)
    np.testing.assert_allclose(mask_box, view.box_px, atol=1.0)
    # The renderer's anti-aliased coverage has the projected extent to a fraction of a pixel;
    # red pixels are covered pixels, and covered pixels are red (but for a few dark ones
    # on the limb, mixed with the grass).
    cov = renderer.object_coverage(obj, 0.0, pos, R)
    cov_box = coverage_box_px(cov, is_full_panorama(cam))
    np.testing.assert_allclose(cov_box, view.box_px, atol=0.35)
    assert np.all(cov[mask] >= 0.2)
    assert np.count_nonzero((cov >= 0.95) & ~mask) <= 0.03 * mask.sum() + 2
    # The image of render_with_coverage is render's, byte for byte.
    rng = np.random.default_rng(4)
    img2, visible = renderer.render_with_coverage(0.0, pos, R, rng=rng)
    np.testing.assert_array_equal(img2, renderer.render(0.0, pos, R, rng=np.random.default_rng(4)))
    np.testing.assert_allclose(visible[obj.object_id], cov, atol=1e-6)


def test_box_across_the_panorama_seam():
    cam = Equirectangular(180, 110)
    pos, R = pose()
    # Straight behind the vehicle: the panorama's left and right edges.
    behind = pos - 5.0 * np.array([math.cos(HEADING_RAD), math.sin(HEADING_RAD), 0.0])
    box = BoxTarget(Trajectory.static((behind[0], behind[1], -0.75)), albedo_rgb=RED, yaw_rad=0.3)
    renderer = Renderer(world_with(box), cam)
    view = project_object(box, 0.0, cam, pos, R)
    assert view.box_px is not None
    x0, _, x1, _ = view.box_px
    assert x0 > x1, "a box across the seam has x_min > x_max"
    cov_box = coverage_box_px(renderer.object_coverage(box, 0.0, pos, R), wrap_columns=True)
    np.testing.assert_allclose(cov_box, view.box_px, atol=0.35)
    mask = red_mask(renderer.render(0.0, pos, R, noise_dn=0.0))
    assert mask[:, :3].any() and mask[:, -3:].any()
    assert box_width_px(view.box_px, cam.width) == pytest.approx(
        np.count_nonzero(mask.any(axis=0)), abs=1.5
    )


def test_ball_view_extent_matches_angular_diameter():
    ball = Ball(Trajectory.static(_track_point(0.0, 3.5, -1.0)))
    pos, R = pose()
    view = project_object(ball, 0.0, CAMERAS["pinhole"], pos, R)
    d = float(np.linalg.norm(ball.centre_ned_m(0.0) - pos))
    assert view.range_m == pytest.approx(d)
    assert view.extent_rad is not None
    np.testing.assert_allclose(view.extent_rad, 2.0 * math.asin(ball.radius_m / d), rtol=0.01)


def test_occlusion_between_objects():
    cam = CAMERAS["pinhole"]
    pos, R = pose()
    car = BoxTarget(
        Trajectory.static(_track_point(0.0, 7.0, -0.75)), yaw_rad=HEADING_RAD, object_id=1
    )
    person = CylinderTarget(Trajectory.static(_track_point(0.0, 4.0, -0.9)), object_id=2)
    renderer = Renderer(world_with(car, person), cam)
    img, visible = renderer.render_with_coverage(0.0, pos, R, noise_dn=0.0)
    whole_car = renderer.object_coverage(car, 0.0, pos, R)
    whole_person = renderer.object_coverage(person, 0.0, pos, R)
    np.testing.assert_allclose(visible[2], whole_person, atol=1e-6)  # nothing in front
    front = whole_person >= 1.0
    assert np.count_nonzero(front & (whole_car >= 1.0)) > 50, "the person stands before the car"
    assert np.all(visible[1][front] == 0.0)
    assert np.all(visible[1] <= whole_car + 1e-6)
    # Where the person hides the car the image is yellow, not blue.
    b, g, r = (img[..., i].astype(int) for i in range(3))
    hidden = front & (whole_car >= 1.0)
    assert np.mean((r > b + 40) & (g > b + 30) & hidden) / np.mean(hidden) > 0.9
    beside = (whole_car >= 1.0) & (whole_person == 0.0)
    assert np.mean((b > r + 20) & beside) / np.mean(beside) > 0.9


def test_occlusion_by_clutter():
    cam = Equirectangular(360, 220)
    pos, R = pose()
    building = FIELD.buildings[0]
    lo, hi = np.asarray(building.min_ned_m), np.asarray(building.max_ned_m)
    middle = (lo + hi) / 2.0
    ray = (middle - pos) * np.array([1.0, 1.0, 0.0])
    ray /= np.linalg.norm(ray)
    far = middle + 8.0 * ray
    hidden = CylinderTarget(Trajectory.static((far[0], far[1], -0.9)), albedo_rgb=RED, object_id=1)
    pole = CylinderTarget(
        Trajectory.static((far[0], far[1], -4.0)), radius_m=0.4, height_m=8.0, albedo_rgb=RED,
        object_id=2,
    )  # fmt: skip
    renderer = Renderer(world_with(hidden, pole), cam)
    _, visible = renderer.render_with_coverage(0.0, pos, R, noise_dn=0.0)
    assert renderer.object_coverage(hidden, 0.0, pos, R).sum() > 2.0
    assert 1 not in visible, "a person behind the building is not seen"
    whole = renderer.object_coverage(pole, 0.0, pos, R)
    seen = visible[2]
    assert 0.1 * whole.sum() < seen.sum() < 0.8 * whole.sum(), "only its top shows"
    rows_seen = np.nonzero(seen.max(axis=1) > 0.5)[0]
    rows_whole = np.nonzero(whole.max(axis=1) > 0.5)[0]
    assert rows_seen.max() < rows_whole.max() - 3 and rows_seen.min() == rows_whole.min()


def test_target_casts_its_shadow():
    cam = CAMERAS["pinhole"]
    pos, R = pose()
    person = SHAPES["cylinder"]
    world = world_with(person)
    lit = Renderer(world, cam).render_linear(0.0, pos, R).sum(axis=2)
    bare = Renderer(FIELD, cam).render_linear(0.0, pos, R).sum(axis=2)
    cov = Renderer(world, cam).object_coverage(person, 0.0, pos, R)
    ratio = lit / np.maximum(bare, 1e-6)
    # Where each pixel's ray meets the ground, and its distance to the shadow: a capsule
    # round the segment from the base's centre to the top's centre cast along the sun.
    b = cam.bearing_map_cam @ (R @ cam.R_body_from_cam).T
    t = -pos[2] / np.where(b[..., 2] > 1e-6, b[..., 2], np.nan)
    g = pos[:2] + t[..., None] * b[..., :2]
    L = FIELD.sun.direction_ned
    base = person.centre_ned_m(0.0)[:2]
    top = base - (-person.height_m / L[2]) * L[:2]
    seg = top - base
    s = np.clip(((g - base) @ seg) / (seg @ seg), 0.0, 1.0)
    dist = np.linalg.norm(g - (base + s[..., None] * seg), axis=-1)
    free = (cov == 0) & np.isfinite(dist)
    inside = free & (dist < person.radius_m - 0.04)
    outside = free & (dist > person.radius_m + 0.1) & (dist < 3.0)
    assert inside.sum() > 100 and outside.sum() > 1000
    assert np.all(ratio[inside] < 0.7), "shadowed"
    assert np.all(ratio[outside] > 0.98), "lit"


def test_box_yaw_follows_its_path():
    car = flight_plan("T90-BOX").targets[0]
    axis = np.asarray(car.trajectory.terms[0].amplitude_ned_m)
    axis_yaw = math.atan2(axis[1], axis[0])
    for t in np.linspace(0.0, 6.0, 31):
        d = (car.yaw_at_rad(float(t)) - axis_yaw) % math.pi
        assert min(d, math.pi - d) < 1e-6
    parked = flight_plan("TS-BOX").targets[0]
    assert parked.yaw_at_rad(3.0) == pytest.approx(HEADING_RAD)


# --------------------------------------------------------------------------------------
# The new scenarios
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over a second of CPU
def test_object_scenarios_catalogue():
    small = Equirectangular(120, 74)
    for name in OBJECT_SCENARIO_NAMES:
        plan = flight_plan(name)
        assert describe_scenario(name) == plan.description and len(plan.description) > 30
        ids = [o.object_id for o in plan.objects]
        assert ids == list(range(1, len(ids) + 1)), name
        assert plan.fps == 25.0
        t = np.linspace(0.0, plan.duration_s, 201)
        veh = plan.vehicle.position_ned_m(t)
        assert np.all(np.abs(veh[:, 2] + 2.0) < 0.1), "flies at 2 m"
        for o in plan.objects:
            centre = o.trajectory.position_ned_m(t)
            clearance = np.linalg.norm(centre - veh, axis=1) - o.bounding_radius_m
            assert clearance.min() > (-0.5 if name == "HEADON-BOX" else 0.3), (name, o)
            assert np.all(centre[:, 2] <= o.size_m[2] / 2.0 + 1e-9), "not under the ground"
        base = name.split("-")[0]
        if base in ("TS", "RAISED", "HEADON"):
            assert [o.moving for o in plan.objects] == [False] * len(plan.objects)
        if base in ("T45", "T90", "INPLANE", "COLLISION"):
            assert [o.moving for o in plan.objects] == [True]
        if base == "COLLISION":
            tt = np.linspace(0.0, plan.duration_s, 50)
            rel = plan.objects[0].trajectory.position_ned_m(tt) - plan.vehicle.position_ned_m(tt)
            rng_m = np.linalg.norm(rel, axis=1)
            assert rng_m[0] > 12.0 and 1.4 < rng_m[-1] < 2.0 and np.all(np.diff(rng_m) < 0)
            cosang = rel @ rel[0] / (rng_m * rng_m[0])
            assert np.degrees(np.arccos(np.clip(cosang, -1, 1))).max() < 2.0, "constant bearing"
        if name in ("DARKBG", "BACKLIT", "SKY2TREE", "MIXED"):
            assert sorted(o.moving for o in plan.objects)[0] is False
            assert any(o.moving for o in plan.objects)
        # Every object is in view at the start.
        sim = make_scenario(name, camera=small, duration_s=0.04, noise=0.0)
        pos, R = sim.vehicle_pose(0)
        seen = sim.renderer.visible_coverage(float(sim.frame_times_s[0]), pos, R)
        assert sorted(seen) == ids, name
    for name in PAPER_SCENARIO_NAMES:
        plan = flight_plan(name)
        assert plan.targets == () and plan_world(plan) == field_world(plan.balls, plan.heading_rad)


def _behind_and_around(sim, frame):
    """Per object: mean luminance (linear) of the object, of what is behind it (the scene
    rendered without objects) and of the scene around it."""
    r = sim.renderer
    empty = Renderer(replace(sim.world, balls=(), targets=()), sim.camera)
    pos, R = sim.vehicle_pose(frame)
    t = float(sim.frame_times_s[frame])
    bg, full = empty.render_linear(t, pos, R), r.render_linear(t, pos, R)
    out = {}
    for oid, c in r.visible_coverage(t, pos, R).items():
        m = (c > 0.5).astype(np.uint8)
        ring = cv2.dilate(m, np.ones((7, 7), np.uint8)) - m
        out[oid] = (full[m > 0].mean(), bg[m > 0].mean(), full[ring > 0].mean())
    return out


@pytest.mark.slow  # over a second of CPU
def test_hard_backgrounds():
    dark = make_scenario("DARKBG", duration_s=30.0, noise=0.0)
    for frame in (0, 260, 530):
        lum = _behind_and_around(dark, frame)
        assert lum[1][1] < 0.02 and lum[2][1] < 0.03, "dark hedge, dark building right behind"
    backlit = make_scenario("BACKLIT", duration_s=12.0, noise=0.0)
    plan = backlit.plan
    ball = plan.balls[0].centre_ned_m(0.0) - plan.vehicle.path.origin_ned_m
    sun = backlit.world.sun.direction_ned
    assert math.degrees(math.acos(ball @ sun / np.linalg.norm(ball))) < 1.0, "sun behind ball 1"
    for frame in (0, 150):
        for obj_lum, behind, around in _behind_and_around(backlit, frame).values():
            assert obj_lum < 0.35 * min(behind, around), "shaded side against a bright sky"
    sky = make_scenario("SKY2TREE", duration_s=40.0, noise=0.0)
    behind = [_behind_and_around(sky, f)[1][1] for f in range(0, 1000, 50)]
    assert min(behind) < 0.05 and max(behind) > 0.4, "ball 1 seen against foliage and sky"
    behind2 = [_behind_and_around(sky, f)[2][1] for f in range(0, 1000, 100)]
    assert max(behind2) - min(behind2) > 0.2, "ball 2's background changes by parallax"


# --------------------------------------------------------------------------------------
# Truth
# --------------------------------------------------------------------------------------
def test_truth_of_non_spherical_objects():
    sim = make_scenario("MIXED", camera=Equirectangular(180, 110), duration_s=1.2, noise=0.0)
    tr = sim.truth
    for o in sim.plan.objects:
        rows = tr.object_id == o.object_id
        np.testing.assert_allclose(tr.obj_radius_m[rows], o.bounding_radius_m)
    car = next(o for o in sim.plan.objects if o.shape == "box")
    assert car.bounding_radius_m == pytest.approx(0.5 * math.sqrt(4.2**2 + 1.8**2 + 1.5**2))
    r0 = tr.rows_for_frame(0)[tr.object_id[tr.rows_for_frame(0)] == 3][0]
    r1 = tr.rows_for_frame(29)[tr.object_id[tr.rows_for_frame(29)] == 3][0]
    d0 = np.linalg.norm(tr.obj_ned_m[r0] - tr.veh_ned_m[r0])
    d1 = np.linalg.norm(tr.obj_ned_m[r1] - tr.veh_ned_m[r1])
    assert sim.true_range_m(0, 3) == pytest.approx(d0)
    assert sim.true_range_ratio(0, 29, 3) == pytest.approx(d0 / d1)
    views = sim.object_views(5)
    assert [v.object_id for v in views] == [1, 2, 3, 4, 5]
    for v in views:
        assert v.box_px is not None and v.extent_rad is not None
        cx, _ = box_centre_px(v.box_px, sim.camera.width)
        assert abs(cx - v.centre_px[0]) < 0.2 * box_width_px(v.box_px, 180) + 1.0
        assert v.box_px[1] <= v.centre_px[1] <= v.box_px[3]


# --------------------------------------------------------------------------------------
# [[target]] and detections.csv
# --------------------------------------------------------------------------------------
def test_target_tables_round_trip(tmp_path):
    sim = make_scenario("MIXED", camera=Equirectangular(120, 74), duration_s=0.08)
    out = export_scenario(sim, tmp_path / "mixed", progress=False)
    sc = load_scenario(out)  # the reader accepts the tables
    assert sc.warnings == [] and sc.name == "MIXED"
    specs = read_targets(out)
    assert specs == [target_spec(o) for o in sim.plan.objects]
    assert [s.shape for s in specs] == ["sphere", "box", "cylinder", "disc", "disc"]
    assert specs[0].colour_rgb == (221, 57, 57) and specs[0].size_m == (0.75, 0.75, 0.75)
    assert specs[1].size_m == (4.2, 1.8, 1.5) and specs[3].size_m == (0.6, 0.6, 0.1)
    assert not (out / "detections.csv").exists()
    # The paper's scenarios keep scenario.toml without tables (red spheres by default).
    two = export_scenario(
        make_scenario("TWO", camera=Equirectangular(120, 74), duration_s=0.04), tmp_path / "two"
    )
    assert "[[target]]" not in (two / "scenario.toml").read_text() and read_targets(two) == []


@pytest.mark.parametrize(
    ("table", "problem"),
    [
        ('object_id = 1\nshape = "blob"\ncolour_rgb = [1, 2, 3]\nsize_m = [1, 1, 1]', "shape"),
        (
            'object_id = 1\nshape = "box"\ncolour_rgb = [1, 2, 300]\nsize_m = [1, 1, 1]',
            "colour_rgb",
        ),
        ('object_id = 1\nshape = "box"\ncolour_rgb = [1, 2, 3]\nsize_m = [1, 0, 1]', "size_m"),
        ('object_id = 1\nshape = "box"\ncolour_rgb = [1, 2, 3]', "missing size_m"),
        (
            'object_id = 1\nshape = "box"\ncolour_rgb = [1, 2, 3]\nsize_m = [1, 1, 1]\nmass = 3',
            "mass",
        ),
    ],
)
def test_target_tables_refused(tmp_path, table, problem):
    (tmp_path / "scenario.toml").write_text(
        f'format = "tcm-scenario/1"\nname = "x"\n\n[camera]\nmodel = "equirectangular"\n\n'
        f"[[target]]\n{table}\n"
    )
    with pytest.raises(
        ScenarioError, match=rf"scenario.toml: line 7: \[\[target\]\] 1: .*{problem}"
    ):
        read_targets(tmp_path)


def test_target_tables_in_object_id_order(tmp_path):
    t = 'shape = "disc"\ncolour_rgb = [1, 2, 3]\nsize_m = [1, 1, 1]\n'
    (tmp_path / "scenario.toml").write_text(
        f"[[target]]\nobject_id = 2\n{t}\n[[target]]\nobject_id = 1\n{t}"
    )
    with pytest.raises(ScenarioError, match="object_id order"):
        read_targets(tmp_path)


@pytest.mark.slow  # over a second of CPU
def test_detections_csv_export_and_read(tmp_path):
    sim = make_scenario("MIXED", camera=Equirectangular(180, 110), duration_s=0.6)
    cfg = DetectorSimConfig(latency_frames=2, false_per_frame=0.5, seed=3)
    out = export_scenario(sim, tmp_path / "mixed", progress=False, detections=cfg)
    rows = read_detections_csv(out / "detections.csv", sim.n_frames, (180, 110), wraps=True)
    expected = simulate_detections(sim, cfg)
    assert len(rows) == len(expected) > 20
    for a, b in zip(rows, expected):
        assert (a.frame, a.label) == (b.frame, b.label)
        np.testing.assert_allclose(
            [a.x_min, a.y_min, a.x_max, a.y_max, a.score],
            [b.x_min, b.y_min, b.x_max, b.y_max, b.score],
            atol=6e-4,
        )
    assert {r.label for r in rows} <= {"ball", "car", "person", "drone"}
    assert all(r.frame >= 2 for r in expected if r.object_id), "latency: nothing real before 2"
    # The frames are the same with or without detections.
    plain = export_scenario(sim, tmp_path / "plain", progress=False)
    for i in (0, sim.n_frames - 1):
        a = cv2.imread(str(out / "frames" / f"{i:06d}.png"))
        b = cv2.imread(str(plain / "frames" / f"{i:06d}.png"))
        np.testing.assert_array_equal(a, b)
    assert not (plain / "detections.csv").exists()


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("0,1,2,3,4,0.5", "expected 7 fields"),
        ("x,1,2,3,4,0.5,a", "frame must be an integer"),
        ("9,1,2,3,4,0.5,a", "frame 9 is not in frames.csv"),
        ("0,1,2,3,4,1.5,a", "score must be in"),
        ("0,1,4,3,2,0.5,a", "y_max"),
        ("0,5,2,3,4,0.5,a", "x_max"),
        ("0,1,2,3,400,0.5,a", "leaves the 100x50 image"),
        ("0,1,2,3,nan,0.5,a", "must be finite"),
    ],
)
def test_detections_csv_refused(tmp_path, line, problem):
    path = tmp_path / "detections.csv"
    path.write_text(f"frame,x_min,y_min,x_max,y_max,score,label\n1,1,2,3,4,0.9,ball\n{line}\n")
    with pytest.raises(ScenarioError, match=rf"detections.csv: line 3: .*{problem}"):
        read_detections_csv(path, n_frames=5, image_size=(100, 50))


def test_detections_csv_order_and_seam(tmp_path):
    path = tmp_path / "detections.csv"
    path.write_text("frame,x_min,y_min,x_max,y_max,score,label\n2,1,2,3,4,0.9,\n1,1,2,3,4,0.9,a\n")
    with pytest.raises(ScenarioError, match="line 3: frame 1 after frame 2"):
        read_detections_csv(path)
    path.write_text("frame,x_min,y_min,x_max,y_max,score,label\n0,350,2,3,4,0.9,ball\n")
    assert read_detections_csv(path, wraps=True)[0].x_min == 350.0
    with pytest.raises(ScenarioError, match="x_max"):
        read_detections_csv(path, wraps=False)


# --------------------------------------------------------------------------------------
# The detector simulator
# --------------------------------------------------------------------------------------
def _moving_truth(n_frames: int) -> list[list[TrueBox]]:
    """Two objects a frame: one drifting right 0.7 px per frame round the panorama (it
    crosses the seam), one still; sizes 12×9 and 20×30 px."""
    out = []
    for k in range(n_frames):
        x = (150.0 + 0.7 * k) % 360.0
        x0, x1 = (x - 6.0) % 360.0, (x + 6.0) % 360.0
        out.append(
            [
                TrueBox(1, "drone", (x0, 100.0, x1, 109.0), 1.0),
                TrueBox(2, "car", (40.0, 60.0, 60.0, 90.0), 0.8),
            ]
        )
    return out


@pytest.mark.slow  # over half a second of CPU
def test_detector_statistics_match_settings():
    cam = Equirectangular(360, 220)
    truth = _moving_truth(3000)
    cfg = DetectorSimConfig(
        centre_sigma_px=1.5,
        scale_sigma=0.05,
        miss_probability=0.2,
        false_per_frame=0.3,
        latency_frames=3,
        seed=11,
    )
    rows = detections_from_truth(truth, cam, cfg, labels=("drone", "car"))
    real = [r for r in rows if r.object_id]
    false = [r for r in rows if not r.object_id]
    assert all(r.image_frame == r.frame - 3 for r in real)
    assert min(r.frame for r in real) >= 3
    n_possible = 2 * (3000 - 3)
    assert len(real) / n_possible == pytest.approx(0.8, abs=0.02)
    assert len(false) / 3000 == pytest.approx(0.3, abs=0.03)
    dx, dy, sw, sh = [], [], [], []
    for r in real:
        tb = next(b for b in truth[r.image_frame] if b.object_id == r.object_id)
        box = (r.x_min, r.y_min, r.x_max, r.y_max)
        cx, cy = box_centre_px(box, 360)
        tx, ty = box_centre_px(tb.box_px, 360)
        dx.append((cx - tx + 180.0) % 360.0 - 180.0)
        dy.append(cy - ty)
        sw.append(math.log(box_width_px(box, 360) / box_width_px(tb.box_px, 360)))
        sh.append(math.log((r.y_max - r.y_min) / (tb.box_px[3] - tb.box_px[1])))
    assert np.std(dx) == pytest.approx(1.5, rel=0.06) and abs(np.mean(dx)) < 0.1
    assert np.std(dy) == pytest.approx(1.5, rel=0.06) and abs(np.mean(dy)) < 0.1
    assert np.std(sw) == pytest.approx(0.05, rel=0.06)
    assert np.std(sh) == pytest.approx(0.05, rel=0.06)
    assert any(r.x_min > r.x_max for r in real), "boxes across the seam"
    # Latency as a user would measure it: the lag that best explains the moving object.
    drone = [r for r in real if r.object_id == 1]

    def err(lag: int) -> float:
        e = []
        for r in drone:
            if r.frame - lag >= 0:
                cx, _ = box_centre_px((r.x_min, r.y_min, r.x_max, r.y_max), 360)
                tx, _ = box_centre_px(truth[r.frame - lag][0].box_px, 360)
                e.append(abs((cx - tx + 180.0) % 360.0 - 180.0))
        return float(np.median(e))

    assert min(range(8), key=err) == 3
    scores = [r.score for r in real if r.object_id == 1]
    assert 0.6 <= min(scores) and max(scores) <= 0.98
    assert max(r.score for r in false) <= 0.7


def test_detector_is_deterministic_and_clips():
    truth = _moving_truth(200)
    cam = Pinhole(300, 200, fx=150.0, fy=150.0, cx=150.0, cy=100.0)
    cfg = DetectorSimConfig(false_per_frame=1.0, seed=2)
    a = detections_from_truth(truth, cam, cfg)
    assert a == detections_from_truth(truth, cam, cfg)
    assert a != detections_from_truth(truth, cam, replace(cfg, seed=3))
    assert a[: len(a) // 2] == detections_from_truth(truth[:100], cam, cfg)[: len(a) // 2]
    for r in a:
        assert 0.0 <= r.x_min < r.x_max <= 300.0 and 0.0 <= r.y_min < r.y_max <= 200.0
    perfect = DetectorSimConfig(
        centre_sigma_px=0, scale_sigma=0, miss_probability=0, false_per_frame=0
    )
    exact = detections_from_truth(truth[:1], Equirectangular(360, 220), perfect)
    assert [(r.x_min, r.y_min, r.x_max, r.y_max) for r in exact] == [
        pytest.approx(b.box_px) for b in truth[0]
    ]
    with pytest.raises(ValueError):
        DetectorSimConfig(miss_probability=1.5)


def test_simulated_detections_on_a_scenario(tmp_path):
    sim = make_scenario("T90-CYL", camera=Equirectangular(180, 110), duration_s=0.4, noise=0.0)
    perfect = DetectorSimConfig(
        centre_sigma_px=0, scale_sigma=0, miss_probability=0, false_per_frame=0
    )
    rows = simulate_detections(sim, perfect)
    assert [r.frame for r in rows] == list(range(sim.n_frames))
    for r in rows:
        view = sim.object_views(r.frame)[0]
        assert r.label == "person" and r.object_id == 1
        np.testing.assert_allclose((r.x_min, r.y_min, r.x_max, r.y_max), view.box_px, atol=0.4)
    # The same boxes as the frame's visible coverage, and the truth of the box says so.
    tb = true_boxes(sim, 3)
    assert tb[0].visible_fraction == pytest.approx(1.0, abs=1e-3)
    write_detections_csv(tmp_path / "d.csv", rows)
    back = read_detections_csv(tmp_path / "d.csv", sim.n_frames, (180, 110), wraps=True)
    assert [(r.frame, r.label) for r in back] == [(r.frame, r.label) for r in rows]
