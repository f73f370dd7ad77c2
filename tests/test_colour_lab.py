"""Lab colour targets (issue 14 §1): grey, white and black objects by a CIELAB colour.

A ``[[detection.targets]]`` table with ``lab = [L*, a*, b*]`` seeds a blob where a pixel
is within ``seed_max_delta_e`` of that colour and grows it within ``grow_max_delta_e``
(lightness differences counted 1/``delta_e_lightness_factor``); everything after the
masks (connected components, the rim unmixing, the solid angle) is the hue targets'.
Checked here: the configuration names a bad key; a grey, a dark and a white ball whose
colour was sampled from another frame, as a user would pick it, are found at the true
bearing and size on sky and grass through three lenses; a hue target's detections are
bit-for-bit those of before Lab targets existed, alone or mixed with Lab targets; mixed
targets each find their own object and nothing of the other's.
"""

from __future__ import annotations

import math
import tomllib

import cv2
import numpy as np
import pytest

from tcm_companion.config import ConfigError, config_from_dict, config_to_toml
from tcm_companion.core.camera import CameraModel
from tcm_companion.core.detection import ColourDetector, ColourTarget, Detection, DetectionConfig
from tcm_companion.core.detection.settings import _HUE_KEYS, _LAB_KEYS

from .detection_scene import (
    CAMERAS,
    Background,
    Ball,
    ball_at,
    field_background,
    pixel_errors,
    render,
    sky_background,
)

GREYS_BGR = {
    "white": (235.0, 235.0, 235.0),
    "grey": (130.0, 130.0, 130.0),
    "dark": (70.0, 70.0, 72.0),
}


def lab_of(bgr: tuple[float, float, float]) -> tuple[float, float, float]:
    """True CIELAB of one 8-bit BGR colour (OpenCV's 8-bit Lab undone)."""
    px = cv2.cvtColor(np.array([[bgr]], np.uint8), cv2.COLOR_BGR2Lab)[0, 0].astype(np.float64)
    return (px[0] * 100.0 / 255.0, px[1] - 128.0, px[2] - 128.0)


def frontlit(
    cam: CameraModel, ball: Ball, *, seed: int, background: Background = field_background
) -> np.ndarray:
    """A ball lit from near the camera (its lit face towards it, darker to the rim)."""
    light = -ball.centre_cam + np.array([0.0, 0.3, -0.4])
    return render(cam, [ball], background=background, seed=seed, light_cam=light, ambient=0.5)


def sampled_lab(cam: CameraModel, albedo: tuple[float, float, float]) -> tuple[float, ...]:
    """The colour a user would configure: the median CIELAB of a 7×7 patch at the centre
    of the object in another frame (another place, another noise)."""
    ball = Ball(ball_at(0.0, -10.0, 8.0).centre_cam, math.radians(8.0), albedo)
    img = frontlit(cam, ball, seed=99)
    x, y = (int(v) for v in cam.pixel_from_bearing_cam(ball.centre_cam))
    patch = cv2.cvtColor(img[y - 3 : y + 4, x - 3 : x + 4], cv2.COLOR_BGR2Lab).reshape(-1, 3)
    L, a, b = np.median(patch.astype(np.float64), axis=0)
    return (round(L * 100.0 / 255.0, 1), round(a - 128.0, 1), round(b - 128.0, 1))


# -- configuration ----------------------------------------------------------------------


def test_lab_targets_from_the_config_file() -> None:
    cfg = config_from_dict(
        {
            "detection": {
                "targets": [
                    {"label": "ball"},
                    {"label": "drone", "lab": [22, 0, -1], "seed_max_delta_e": 5},
                ]
            }
        }
    )
    ball, drone = cfg.pipeline.detection.colour_targets
    assert not ball.is_lab and ball == ColourTarget(label="ball")
    assert drone.is_lab and drone.lab == (22.0, 0.0, -1.0)
    assert drone.seed_max_delta_e == 5.0 and drone.grow_max_delta_e == 12.0
    assert drone.delta_e_lightness_factor == 2.0
    # The flat keys describe one Lab target too.
    flat = config_from_dict({"detection": {"lab": [80, 0, 0], "label": "box"}})
    assert flat.pipeline.detection.colour_targets[0].lab == (80.0, 0.0, 0.0)


def test_config_check_prints_each_target_s_own_keys() -> None:
    """A Lab target's table holds no hue key and a hue target's no Lab key (they printed
    every key of both kinds, the unused kind at its defaults), and the text loads back."""
    cfg = config_from_dict(
        {
            "detection": {
                "targets": [
                    {"label": "ball", "hue_deg": 10},
                    {"label": "drone", "lab": [22, 0, -1], "delta_e_lightness_factor": 1},
                ]
            }
        }
    )
    text = config_to_toml(cfg)
    ball, drone = tomllib.loads(text)["pipeline"]["detection"]["targets"]
    assert set(ball) == {"label", *_HUE_KEYS} and ball["hue_deg"] == 10.0
    assert set(drone) == {"label", *_LAB_KEYS} and drone["lab"] == [22.0, 0.0, -1.0]
    assert drone["delta_e_lightness_factor"] == 1.0
    assert config_from_dict(tomllib.loads(text)) == cfg


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"lab": [50, 0]}, r"targets\[0\]\.lab must be three numbers"),
        ({"lab": [50, 0, "x"]}, r"targets\[0\]\.lab must be three numbers"),
        ({"lab": [120, 0, 0]}, r"targets\[0\]\] lab\[0\] \(L\) = 120 is out of range"),
        ({"lab": [50, 0, -200]}, r"targets\[0\]\] lab\[2\] \(b\) = -200 is out of range"),
        ({"lab": [50, 0, 0], "hue_deg": 30}, r"targets\[0\]\.hue_deg is a hue target's key"),
        (
            {"lab": [50, 0, 0], "grow_min_value": 0.01},
            r"targets\[0\]\.grow_min_value is a hue target's key",
        ),
        ({"seed_max_delta_e": 5}, r"targets\[0\]\.seed_max_delta_e is a Lab target's key"),
        (
            {"hue_deg": 120, "delta_e_lightness_factor": 1},
            r"targets\[0\]\.delta_e_lightness_factor is a Lab target's key",
        ),
        (
            {"lab": [50, 0, 0], "seed_max_delta_e": 8, "grow_max_delta_e": 6},
            r"targets\[0\]\.grow_max_delta_e must be at least seed_max_delta_e",
        ),
        ({"lab": [50, 0, 0], "seed_max_delta_e": 0}, r"seed_max_delta_e = 0 is out of range"),
        (
            {"lab": [50, 0, 0], "delta_e_lightness_factor": 20},
            r"delta_e_lightness_factor = 20 is out of range",
        ),
    ],
)
def test_a_bad_lab_target_names_its_key(table: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        config_from_dict({"detection": {"targets": [table]}}, "c.toml")


def test_flat_keys_refuse_a_hue_key_on_a_lab_target() -> None:
    with pytest.raises(ConfigError, match=r"seed_hue_deg is a hue target's key"):
        config_from_dict({"detection": {"lab": [50, 0, 0], "seed_hue_deg": [-10, 10]}})
    with pytest.raises(ValueError, match=r"ColourTarget\.lab must be three numbers"):
        ColourTarget(lab=(50.0,))


# -- detection --------------------------------------------------------------------------

# (camera, azimuth, elevation, angular radius): on the sky, on the grass, small, large.
PLACES = [
    ("equirectangular", -20.0, -15.0, 5.0),
    ("equirectangular", -30.0, 20.0, 3.0),
    ("equirectangular", 30.0, -10.0, 2.5),
    ("pinhole", 10.0, -20.0, 4.0),
    ("pinhole", -25.0, 10.0, 3.0),
    ("fisheye", 0.0, -15.0, 4.0),
    ("fisheye", 50.0, 15.0, 3.0),
]


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("grey", sorted(GREYS_BGR))
@pytest.mark.parametrize(("cam_name", "az", "el", "alpha"), PLACES)
def test_grey_and_white_balls_are_found_at_their_size(
    grey: str, cam_name: str, az: float, el: float, alpha: float
) -> None:
    """A grey, a dark and a white ball (no hue at all) on sky or grass: one detection,
    radius within 2 % and bearing within 0.2 px, with the colour sampled from another
    frame and the default tolerances (the white one's growth wider). A hue target sees
    nothing of them."""
    cam = CAMERAS[cam_name]
    albedo = GREYS_BGR[grey]
    # A white ball shades from L* 89 to about 55 before its rim: more than the default
    # growth (12, lightness counted half) follows, so its growth is widened to 20.
    grow = 20.0 if grey == "white" else ColourTarget.grow_max_delta_e
    target = ColourTarget(label=grey, lab=sampled_lab(cam, albedo), grow_max_delta_e=grow)
    ball = Ball(ball_at(az, el, alpha).centre_cam, math.radians(alpha), albedo)
    for seed, background in enumerate((sky_background, field_background)):
        img = frontlit(cam, ball, seed=seed, background=background)
        dets = ColourDetector(cam, DetectionConfig(targets=(target,))).detect(img)
        assert len(dets) == 1, (background.__name__, dets)
        rad_err, bearing_err_px = pixel_errors(cam, dets[0], ball)
        assert abs(rad_err) < 0.02, (background.__name__, rad_err)
        assert bearing_err_px < 0.2, (background.__name__, bearing_err_px)
        assert dets[0].label == grey and 0.0 < dets[0].score <= 1.0
        assert not dets[0].touches_border
        assert ColourDetector(cam).detect(img) == []


@pytest.mark.slow  # over a second of CPU
def test_a_black_object_is_not_the_lens_s_black_surround() -> None:
    """A black ball (its pixels at or below ``black_level``) in the middle of the frame
    does not touch the border: the surround check counts black pixels outside the blob
    only (it flagged every detection of a black object). A black object against a
    fisheye's black surround merges with it, as any object does with a background of
    its own colour."""
    cam = CAMERAS["pinhole"]
    albedo = (1.0, 1.0, 1.0)
    ball = Ball(ball_at(10.0, 10.0, 4.0).centre_cam, math.radians(4.0), albedo)
    img = frontlit(cam, ball, seed=0, background=sky_background)
    x, y = (int(v) for v in cam.pixel_from_bearing_cam(ball.centre_cam))
    assert img[y - 2 : y + 3, x - 2 : x + 3].max() <= DetectionConfig().black_level
    target = ColourTarget(label="black", lab=sampled_lab(cam, albedo))
    assert target.lab[0] < 3.0
    dets = ColourDetector(cam, DetectionConfig(targets=(target,))).detect(img)
    assert len(dets) == 1
    assert abs(pixel_errors(cam, dets[0], ball)[0]) < 0.03
    assert not dets[0].touches_border


def test_a_lab_target_rejects_other_colours_and_the_sky() -> None:
    """A mid-grey target: nothing on an empty field, nothing in a red ball, and a grey
    ball's blob stops at the pale sky (it does not leak into it)."""
    cam = CAMERAS["equirectangular"]
    target = ColourTarget(label="grey", lab=lab_of(GREYS_BGR["grey"]))
    det = ColourDetector(cam, DetectionConfig(targets=(target,)))
    assert det.detect(render(cam, [])) == []
    assert det.detect(render(cam, [ball_at(-20.0, -15.0, 5.0)])) == []
    white = ColourDetector(cam, DetectionConfig(targets=(ColourTarget(lab=(89.0, 0.0, 0.0)),)))
    assert white.detect(render(cam, [], background=sky_background)) == []


# -- the hue path is unchanged, and targets mix ------------------------------------------

# Detections of the default red target on this frame before Lab targets existed (commit
# 67243eb): centroid, area, solid angle, score, box.
HUE_BEFORE = {
    "equirectangular": [
        ((160.0092016242289, 132.03736095564534), 119.27521632958087, 0.023902320109653367,
         0.8427774779636625, (155, 125, 165, 139)),
        ((219.98571683141364, 117.34737421099787), 28.95360480126692, 0.005988964836879469,
         0.8351307189542483, (218, 114, 222, 121)),
    ],
    "fisheye": [
        ((251.55644213562087, 373.6316176949388), 1002.3268916421584, 0.023924917464621793,
         0.8461212343565285, (234, 356, 269, 391)),
        ((460.453864626839, 339.1522177926998), 267.09409607888665, 0.0059419794924817975,
         0.8564642117009407, (452, 330, 469, 348)),
    ],
}  # fmt: skip


def _red_frame(cam: CameraModel) -> np.ndarray:
    return render(cam, [ball_at(-20.0, -15.0, 5.0), ball_at(40.0, -5.0, 2.5)], seed=3, specular=0.4)


@pytest.mark.parametrize("cam_name", sorted(HUE_BEFORE))
@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_the_red_target_is_unchanged_alone_and_mixed_with_lab_targets(cam_name: str) -> None:
    cam = CAMERAS[cam_name]
    img = _red_frame(cam)
    alone = ColourDetector(cam).detect(img)
    got = [(*d.centroid_px, d.area_px, d.solid_angle_sr, d.score) for d in alone]
    before = [(*c, area, omega, score) for c, area, omega, score, _ in HUE_BEFORE[cam_name]]
    assert np.array(got) == pytest.approx(np.array(before), rel=1e-12, abs=0.0)
    assert [d.bbox_px for d in alone] == [b[-1] for b in HUE_BEFORE[cam_name]]
    mixed_cfg = DetectionConfig(
        targets=(
            ColourTarget(label="grey", lab=(52.0, 0.0, 0.0)),
            ColourTarget(),
            ColourTarget(label="white", lab=(89.0, 0.0, 0.0)),
        )
    )
    mixed = ColourDetector(cam, mixed_cfg).detect(img)
    # The Lab targets find nothing here and change nothing.
    assert [_fields(d) for d in mixed] == [_fields(d) for d in alone]


def _fields(d: Detection) -> tuple[object, ...]:
    return (
        d.centroid_px,
        d.bearing_cam.tolist(),
        d.area_px,
        d.solid_angle_sr,
        d.bbox_px,
        d.score,
        d.label,
    )


def test_mixed_hue_and_lab_targets_each_find_their_own_object() -> None:
    cam = CAMERAS["equirectangular"]
    grey = Ball(ball_at(30.0, -10.0, 4.0).centre_cam, math.radians(4.0), GREYS_BGR["grey"])
    red = ball_at(-30.0, -12.0, 3.0)
    dark = Ball(ball_at(100.0, -20.0, 5.0).centre_cam, math.radians(5.0), GREYS_BGR["dark"])
    img = render(cam, [grey, red, dark], light_cam=(-1.0, 0.0, -0.3), ambient=0.6, seed=5)
    cfg = DetectionConfig(
        targets=(
            ColourTarget(label="red"),
            ColourTarget(label="grey", lab=sampled_lab(cam, GREYS_BGR["grey"])),
            ColourTarget(label="dark", lab=sampled_lab(cam, GREYS_BGR["dark"])),
        )
    )
    dets = ColourDetector(cam, cfg).detect(img)
    # The grey ball's shaded side is the dark target's colour: it is still one object.
    assert sorted(d.label for d in dets) == ["dark", "grey", "red"]
    for d in dets:
        ball = {"red": red, "grey": grey, "dark": dark}[d.label]
        rad_err, bearing_err_px = pixel_errors(cam, d, ball)
        assert abs(rad_err) < 0.03 and bearing_err_px < 0.3, (d.label, rad_err, bearing_err_px)
    # The seeds and candidates of the mixed detector hold every target's.
    seeds = ColourDetector(cam, cfg).seeds(img)
    cands = ColourDetector(cam, cfg).candidates(img)
    assert cv2.countNonZero(seeds) > 0 and cv2.countNonZero(cv2.subtract(seeds, cands)) == 0
