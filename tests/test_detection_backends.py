"""Detection behind one interface: one contract over every backend (colour, boxes, onnx),
colour with several targets, and boxes from a simulated ``detections.csv``.

The contract: ``make_detector`` gives the configured backend, whose ``detect`` returns
:class:`Detection` s with a unit bearing in camera FRD that agrees with the camera model
(the object's true centre; the detection's own centroid pixel), a positive angular radius
measured through the model (a sphere's, to a few percent, on a panorama, a distorted
pinhole and a fisheye), a consistent solid angle, a score in [0, 1], the label, the
pixels or box it came from; nothing when there is nothing. Tracking then works the same
whichever backend found the objects, and carries their labels.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from tcm_companion.config import AppConfig
from tcm_companion.core.camera import CameraModel, Equirectangular
from tcm_companion.core.detection import (
    Box,
    BoxesDetector,
    ColourDetector,
    ColourTarget,
    Detection,
    DetectionConfig,
    DetectorBackend,
    OnnxDetector,
    angular_radius_from_solid_angle,
    make_detector,
)
from tcm_companion.core.detection.onnx_yolo import Letterbox
from tcm_companion.core.detection.settings import hue_plan
from tcm_companion.core.frames import angle_between
from tcm_companion.core.pipeline import Pipeline, PipelineConfig
from tcm_companion.io.detector_model import read_detector_model

from .detection_scene import CAMERAS, Ball, ball_at, render
from .yolo_graphs import constant_model, red_box_model

BACKEND_NAMES = ("colour", "boxes", "onnx")
ONNX_INPUT = (320, 320)


def true_box(cam: CameraModel, ball: Ball) -> tuple[float, float, float, float]:
    """The box a perfect detector draws round a ball's silhouette (format convention: on
    a full panorama ``x_min > x_max`` across the seam)."""
    c = ball.centre_cam
    helper = [0.0, 0.0, 1.0] if abs(c[2]) < 0.9 else [0.0, 1.0, 0.0]
    e1 = np.cross(c, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(c, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, 3601)[:, None]
    a = ball.alpha_rad
    ring = math.cos(a) * c + math.sin(a) * (np.cos(phi) * e1 + np.sin(phi) * e2)
    px = cam.pixel_from_bearing_cam(ring)
    xs, ys = px[:, 0], px[:, 1]
    if isinstance(cam, Equirectangular):
        u_c = float(cam.pixel_from_bearing_cam(c)[0])
        xs = u_c + (xs - u_c + cam.width / 2) % cam.width - cam.width / 2
        return (
            float(xs.min()) % cam.width,
            float(ys.min()),
            float(xs.max()) % cam.width,
            float(ys.max()),
        )
    return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())


# Two balls per camera (azimuth, elevation, angular radius in degrees, camera FRD).
SCENES: dict[str, list[tuple[float, float, float]]] = {
    "equirectangular": [(-30.0, -15.0, 6.0), (150.0, -25.0, 3.5)],
    "pinhole": [(-5.0, -12.0, 4.0), (25.0, -22.0, 2.5)],
    "fisheye": [(0.0, -15.0, 5.0), (50.0, -10.0, 3.0)],
}


def scene(cam_name: str) -> tuple[CameraModel, list[Ball], np.ndarray]:
    cam = CAMERAS[cam_name]
    balls = [ball_at(*b) for b in SCENES[cam_name]]
    return cam, balls, render(cam, balls, seed=7)


def backend_for(
    name: str, cam: CameraModel, balls: list[Ball], tmp: Path, **cfg: object
) -> tuple[DetectorBackend, Callable[[int], None]]:
    """The backend ``name`` for ``cam`` set to find ``balls`` (labelled "ball"), and what
    must happen before a frame is detected (the boxes backend: push that frame's boxes)."""
    boxes = [Box(*true_box(cam, b), score=0.9 - 0.1 * i, label="ball") for i, b in enumerate(balls)]
    if name == "colour":
        det = make_detector(cam, DetectionConfig(label="ball", **cfg))  # type: ignore[arg-type]
        return det, lambda t_us: None
    if name == "boxes":
        det = make_detector(cam, DetectionConfig(backend="boxes", **cfg))  # type: ignore[arg-type]
        assert isinstance(det, BoxesDetector)
        return det, lambda t_us: det.push(t_us, boxes)
    lb = Letterbox(cam.width, cam.height, *ONNX_INPUT)
    cols = []
    for b in boxes:
        assert b.x_min < b.x_max, "no seam boxes in the contract scenes"
        w = b.x_max - b.x_min
        x0, y0 = lb.left + b.x_min * lb.sx, lb.top + b.y_min * lb.sy
        cols.append([x0 + 0.5 * w * lb.sx, y0 + 0.5 * (b.y_max - b.y_min) * lb.sy,
                     w * lb.sx, (b.y_max - b.y_min) * lb.sy, b.score])  # fmt: skip
    model = constant_model(tmp / "balls.onnx", np.array(cols), *ONNX_INPUT)
    det = make_detector(
        cam,
        DetectionConfig(
            backend="onnx",
            onnx_model=str(model),
            onnx_input_size=ONNX_INPUT,
            onnx_class_names=("ball",),
            **cfg,  # type: ignore[arg-type]
        ),
        model.read_bytes(),
    )
    return det, lambda t_us: None


BACKEND_CLASSES = {"colour": ColourDetector, "boxes": BoxesDetector, "onnx": OnnxDetector}
# How close to the truth each backend is held (a box measures a sphere through its
# circumscribed box: exact on the axes, not in between on a panorama far from its equator).
RADIUS_TOL = {"colour": 0.02, "boxes": 0.03, "onnx": 0.03}
BEARING_TOL_RADII = {"colour": 0.05, "boxes": 0.1, "onnx": 0.1}


@pytest.mark.parametrize("cam_name", sorted(SCENES))
@pytest.mark.parametrize("backend", BACKEND_NAMES)
def test_contract(backend: str, cam_name: str, tmp_path: Path) -> None:
    cam, balls, img = scene(cam_name)
    det, before = backend_for(backend, cam, balls, tmp_path)
    assert isinstance(det, BACKEND_CLASSES[backend]) and isinstance(det, DetectorBackend)
    assert det.backend == backend and det.camera is cam
    before(1_000_000)
    found = det.detect(img, 1_000_000)
    assert isinstance(found, list) and len(found) == len(balls)
    assert all(isinstance(d, Detection) for d in found)
    matched = set()
    for d in found:
        # A unit bearing in camera FRD, at one of the balls' centres ...
        assert np.linalg.norm(d.bearing_cam) == pytest.approx(1.0, abs=1e-12)
        errs = [float(angle_between(d.bearing_cam, b.centre_cam)) for b in balls]
        k = int(np.argmin(errs))
        ball = balls[k]
        matched.add(k)
        assert errs[k] < BEARING_TOL_RADII[backend] * ball.alpha_rad
        # ... consistent with the detection's own pixel through the camera model.
        px = cam.pixel_from_bearing_cam(d.bearing_cam)
        du = (px[0] - d.centroid_px[0] + cam.width / 2) % cam.width - cam.width / 2
        assert abs(du) < 0.5 and abs(px[1] - d.centroid_px[1]) < 0.5
        # An angular radius through the camera model, and its solid angle.
        assert d.angular_radius_rad > 0
        assert abs(d.angular_radius_rad / ball.alpha_rad - 1.0) < RADIUS_TOL[backend]
        assert angular_radius_from_solid_angle(d.solid_angle_sr) == pytest.approx(
            d.angular_radius_rad, rel=1e-9
        )
        # Confidence, label, where it came from.
        assert 0.0 <= d.score <= 1.0
        assert d.label == "ball"
        assert d.area_px > 0 and not d.touches_border
        x0, y0, x1, y1 = d.bbox_px
        u = d.centroid_px[0] if d.centroid_px[0] >= x0 else d.centroid_px[0] + cam.width
        assert x0 <= u <= x1 and y0 <= d.centroid_px[1] <= y1
        assert (d.box_px is None) == (backend == "colour")
    assert matched == set(range(len(balls)))


@pytest.mark.parametrize("backend", BACKEND_NAMES)
def test_contract_nothing_found(backend: str, tmp_path: Path) -> None:
    cam, balls, _ = scene("pinhole")
    empty = render(cam, [], seed=3)
    if backend == "onnx":  # the model always says "ball": nothing above the threshold
        det, _before = backend_for(backend, cam, balls, tmp_path, min_score=0.95)
    else:
        det, _before = backend_for(backend, cam, balls, tmp_path)
    if backend == "boxes":
        assert isinstance(det, BoxesDetector)
        det.push(2_000_000, [])  # "nothing in that frame"
    assert det.detect(empty, 2_000_000) == []


@pytest.mark.parametrize("backend", BACKEND_NAMES)
def test_contract_max_detections_and_min_radius(backend: str, tmp_path: Path) -> None:
    cam, balls, img = scene("equirectangular")
    det, before = backend_for(backend, cam, balls, tmp_path, max_detections=1)
    before(0)
    assert len(det.detect(img, 0)) == 1
    big = max(b.alpha_rad for b in balls)
    det, before = backend_for(backend, cam, balls, tmp_path, min_angular_radius_rad=0.8 * big)
    before(0)
    (only,) = det.detect(img, 0)
    assert only.angular_radius_rad > 0.8 * big


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("backend", BACKEND_NAMES)
def test_tracking_is_the_same_whichever_backend(backend: str, tmp_path: Path) -> None:
    """The simulated TS flight (the static red ball): one stable track, labelled, whose
    local-level bearing follows the truth, from every backend."""
    from tcm_companion.eval.evaluate import scenario_detections
    from tcm_companion.replay.scenario import run_replay
    from tcm_companion.sim import make_scenario

    sim = make_scenario("TS", duration_s=1.2, seed=2)
    cam = sim.camera
    if backend == "colour":
        det_cfg = DetectionConfig(label="ball")
    elif backend == "boxes":
        det_cfg = DetectionConfig(backend="boxes")
    else:  # a model that boxes the strongly red pixels it is fed
        model = red_box_model(tmp_path / "red.onnx", *ONNX_INPUT)
        det_cfg = DetectionConfig(
            backend="onnx",
            onnx_model=str(model),
            onnx_input_size=ONNX_INPUT,
            onnx_class_names=("ball",),
        )
    app = AppConfig()
    cfg = PipelineConfig(detection=det_cfg)
    pipe = Pipeline(cam, cfg, detector_model=read_detector_model(det_cfg))
    rows = scenario_detections(sim) if backend == "boxes" else None
    results = list(run_replay(sim, app, pipe, rows))
    ids = {o.track_id for r in results[5:] for o in r.objects if o.detected}
    assert len(ids) == 1
    labels = {o.label for r in results[5:] for o in r.objects}
    assert labels == {"ball"}
    truth = sim.truth
    for r in results[5:]:
        for o in r.objects:
            row = truth.rows_for_frame(r.frame_index)[0]
            los = truth.obj_ned_m[row] - truth.veh_ned_m[row]
            assert math.degrees(float(angle_between(o.bearing_ned, los))) < 3.0


# -- colour: several targets --------------------------------------------------------

BLUE_CAR = ColourTarget(
    label="car",
    hue_deg=228.0,
    seed_hue_deg=(-10.0, 10.0),
    seed_min_saturation=0.65,
    grow_hue_deg=(-16.0, 16.0),
    grow_min_saturation=0.6,
)
YELLOW_PERSON = ColourTarget(
    label="person",
    hue_deg=51.0,
    seed_hue_deg=(-10.0, 10.0),
    seed_min_saturation=0.65,
    grow_hue_deg=(-16.0, 16.0),
    grow_min_saturation=0.6,
)
RED_BALL = ColourTarget(label="ball")


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("TS-BOX", {"car"}),
        ("TS-CYL", {"person"}),
        ("TS", {"ball"}),
        ("MIXED", {"ball", "car", "person"}),  # the two drones are grey and white
    ],
)
def test_colour_several_targets(name: str, expected: set[str]) -> None:
    from tcm_companion.sim import make_scenario

    sim = make_scenario(name, duration_s=1.0, seed=0)
    det = ColourDetector(sim.camera, DetectionConfig(targets=(RED_BALL, BLUE_CAR, YELLOW_PERSON)))
    for frame in (0, 20):
        found = det.detect(sim.read_frame(frame))
        assert sorted(d.label for d in found) == sorted(expected)
        views = {v.label: v for v in sim.object_views(frame)}
        for d in found:
            view = views[d.label]
            centre = sim.camera.bearing_cam_from_pixel(np.array(view.centre_px))
            # A blob's solid-angle centre is not a box's centre (shaded faces, shadow):
            # within a fraction of the object's extent.
            assert float(angle_between(d.bearing_cam, centre)) < 0.2 * max(view.extent_rad)
            assert 0.25 * min(view.extent_rad) < d.angular_radius_rad < max(view.extent_rad)


def test_colour_targets_choose_their_hsv_conversion() -> None:
    """Red reads in the swapped HSV (far from OpenCV's hue wrap) with the version-1 bounds;
    blue in the plain one; a range across both wraps is refused."""
    red = hue_plan(0.0, (-15.0, 12.0), (-30.0, 14.0))
    assert red.swapped and red.seed == (114, 127) and red.grow == (113, 135)
    blue = hue_plan(228.0, (-10.0, 10.0), (-16.0, 16.0))
    assert not blue.swapped and blue.seed == (109, 119)
    with pytest.raises(ValueError, match="hue wrap"):
        ColourTarget(hue_deg=300.0, seed_hue_deg=(-80.0, 80.0), grow_hue_deg=(-90.0, 90.0))


def test_colour_targets_from_the_config_file() -> None:
    from tcm_companion.config import ConfigError, config_from_dict

    cfg = config_from_dict(
        {
            "detection": {
                "targets": [
                    {"label": "car", "hue_deg": 228, "seed_hue_deg": [-10, 10]},
                    {"label": "ball"},
                ]
            }
        }
    )
    targets = cfg.pipeline.detection.colour_targets
    assert [t.label for t in targets] == ["car", "ball"]
    assert targets[0].hue_deg == 228.0 and targets[0].seed_hue_deg == (-10.0, 10.0)
    assert targets[1] == ColourTarget(label="ball")
    with pytest.raises(ConfigError, match=r"targets\[0\]: unknown key 'hue'"):
        config_from_dict({"detection": {"targets": [{"hue": 10}]}})
    with pytest.raises(ConfigError, match=r"targets\[0\].*seed_min_value"):
        config_from_dict({"detection": {"targets": [{"seed_min_value": 2}]}})
    with pytest.raises(ConfigError, match=r"backend must be one of"):
        config_from_dict({"detection": {"backend": "magic"}})
    with pytest.raises(ConfigError, match=r'backend "onnx" needs onnx_model'):
        config_from_dict({"detection": {"backend": "onnx"}})


def test_default_config_is_the_red_ball() -> None:
    cfg = DetectionConfig()
    assert cfg.backend == "colour"
    assert cfg.colour_targets == (ColourTarget(),)
    assert ColourTarget().label == ""  # no label: the wire format of protocol 2 unchanged


# -- boxes ----------------------------------------------------------------------------


def boxes_detector(cam: CameraModel | None = None, **cfg: object) -> BoxesDetector:
    cam = cam if cam is not None else CAMERAS["equirectangular"]
    return BoxesDetector(cam, DetectionConfig(backend="boxes", **cfg))  # type: ignore[arg-type]


def test_boxes_are_taken_by_the_frame_they_were_made_from() -> None:
    det = boxes_detector(boxes_time_tolerance_s=0.01)
    a, b = Box(10, 100, 20, 110, 0.9, "car"), Box(50, 100, 60, 110, 0.8, "person")
    assert not det.ready(1_000_000)
    det.push(1_000_000, [a])
    det.push(1_040_000, [b])
    assert det.ready(1_000_000) and det.ready(1_040_000) and not det.ready(1_080_000)
    (d,) = det.detect(None, 1_004_000)  # capture times agree within the tolerance
    assert d.label == "car"
    assert det.detect(None, 1_020_000) == []  # nothing pushed for that frame
    det.push(1_060_000, [a])
    (d,) = det.detect(None, 1_060_000)  # 1_040_000 was never taken: stale
    assert d.label == "car"
    assert det.stats["stale"] == 1 and det.stats["used"] == 2 and det.stats["pushed"] == 3
    assert det.detect(None, 1_100_000) == []


def test_boxes_filters_and_order() -> None:
    det = boxes_detector(min_score=0.5, classes=("car", "person"))
    det.push(0, [
        Box(10, 100, 20, 110, 0.6, "car"),
        Box(50, 100, 60, 110, 0.9, "person"),
        Box(90, 100, 99, 110, 0.4, "car"),  # below min_score
        Box(150, 100, 160, 110, 0.95, "tree"),  # not a kept class
    ])  # fmt: skip
    assert [d.label for d in det.detect(None, 0)] == ["person", "car"]  # by score


def test_box_across_the_panorama_seam_is_one_object() -> None:
    cam = CAMERAS["equirectangular"]
    ball = ball_at(179.0, -15.0, 5.0)
    box = true_box(cam, ball)
    assert box[0] > box[2]  # x_min > x_max: across the seam
    det = boxes_detector(cam)
    det.push(0, [Box(*box, score=0.9, label="ball")])
    (d,) = det.detect(None, 0)
    assert float(angle_between(d.bearing_cam, ball.centre_cam)) < 0.05 * ball.alpha_rad
    assert abs(d.angular_radius_rad / ball.alpha_rad - 1) < 0.02
    assert 0 <= d.bbox_px[0] < cam.width < d.bbox_px[2]
    assert not d.touches_border and d.box_px == box


def test_box_radius_estimators() -> None:
    det = {m: boxes_detector(box_radius=m) for m in ("short", "mean", "long")}
    box = Box(100, 80, 140, 100, 0.9, "car")  # 40 x 20 px
    r = {}
    for m, dd in det.items():
        dd.push(0, [box])
        (d,) = dd.detect(None, 0)
        r[m] = d.angular_radius_rad
    assert r["short"] < r["mean"] < r["long"]
    assert r["mean"] == pytest.approx(math.sqrt(r["short"] * r["long"]), rel=1e-12)
    # 40 columns (40° of azimuth) at the box's centre row, elevation 75 - 90·150/220 deg:
    # the great circle across them.
    el = math.radians(75.0 - 90.0 * 150.0 / 220.0)
    across = 2.0 * math.asin(math.cos(el) * math.sin(math.radians(20.0)))
    assert r["long"] == pytest.approx(0.5 * across, rel=1e-9)


def test_box_at_the_edge_or_outside_the_lens() -> None:
    pinhole = CAMERAS["pinhole"]
    det = boxes_detector(pinhole)
    det.push(0, [Box(0.0, 200, 30, 240), Box(300, 200, 330, 230)])
    edge, inside = sorted(det.detect(None, 0), key=lambda d: d.centroid_px[0])
    assert edge.touches_border and not inside.touches_border
    # A fisheye whose model ends 141 px from the centre (its first turning point).
    from tcm_companion.core.camera import Fisheye

    fisheye = Fisheye(640, 640, fx=200, fy=200, cx=320, cy=320, dist=(-0.3, 0.0, 0.0, 0.0))
    assert not fisheye.valid_mask[10, 10] and fisheye.valid_mask[320, 420]
    det = boxes_detector(fisheye)
    det.push(0, [Box(0.0, 0.0, 20.0, 20.0), Box(410.0, 300.0, 470.0, 340.0)])
    (rim,) = det.detect(None, 0)  # the corner box has no bearing at all
    assert rim.touches_border  # its right edge is beyond the lens


@pytest.mark.slow  # over a second of CPU
def test_boxes_from_a_simulated_detections_csv(tmp_path: Path) -> None:
    """``sim export TS-BOX DIR --detections``, replayed with the boxes backend: the parked
    car is one labelled track, and the label goes out on MAVLink."""
    from tcm_companion.io.scenario import load_scenario
    from tcm_companion.mavlink import tcm_dialect as d
    from tcm_companion.mavlink.outputs import object_status
    from tcm_companion.replay.scenario import run_replay
    from tcm_companion.sim import make_scenario
    from tcm_companion.sim.scene.export import export_scenario

    export_scenario(
        make_scenario("TS-BOX", duration_s=2.0, seed=0), tmp_path / "s", detections=True
    )
    scenario = load_scenario(tmp_path / "s")
    assert scenario.detections and {r.label for r in scenario.detections} == {"car"}
    assert scenario.targets and scenario.targets[0].shape == "box"
    app = AppConfig()
    pipe = Pipeline(scenario.camera, PipelineConfig(detection=DetectionConfig(backend="boxes")))
    results = list(run_replay(scenario, app, pipe))
    assert len(results) == scenario.n_frames
    detected = [o for r in results for o in r.objects if o.detected]
    assert {o.label for r in results for o in r.objects} == {"car"}
    # One track holds the car (5% of its boxes are missed); a false box (2% of frames)
    # makes a short-lived track of its own.
    per_track = Counter(o.track_id for o in detected)
    (car, n), *others = per_track.most_common()
    assert n >= 0.9 * scenario.n_frames and all(k <= 3 for _, k in others)
    assert scenario.truth is not None
    truth = scenario.truth
    for r in results:
        for o in r.objects:
            if o.track_id != car:
                continue
            row = truth.rows_for_frame(r.frame_index)[0]
            los = truth.obj_ned_m[row] - truth.veh_ned_m[row]
            assert math.degrees(float(angle_between(o.bearing_ned, los))) < 4.0
    (last,) = [o for o in results[-1].objects if o.track_id == car]
    msg = object_status(last, 1234, 0.09, 0, 0.0)
    mav = d.MAVLink(None, srcSystem=1, srcComponent=191)
    got = d.MAVLink(None).decode(bytearray(msg.pack(mav)))
    assert got.label == d.TCM_OBJECT_LABEL_CAR


def test_boxes_backend_needs_detections() -> None:
    from tcm_companion.replay.scenario import run_replay
    from tcm_companion.sim import make_scenario

    sim = make_scenario("TS", duration_s=0.2, seed=0)
    pipe = Pipeline(sim.camera, PipelineConfig(detection=DetectionConfig(backend="boxes")))
    with pytest.raises(ValueError, match=r"detections\.csv"):
        next(run_replay(sim, AppConfig(), pipe))
