"""Camera models: round trips, conventions of the scenario format, solid angles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcm_companion.core.camera import (
    CameraModelError,
    Equirectangular,
    Fisheye,
    Pinhole,
    camera_from_dict,
)
from tcm_companion.core.frames import angle_between, normalize

CAMERAS = {
    "equirectangular": Equirectangular(360, 220),
    "partial-panorama": Equirectangular(
        200,
        100,
        azimuth_min_deg=-60,
        azimuth_max_deg=40,
        elevation_max_deg=30,
        elevation_min_deg=-20,
    ),
    "pinhole": Pinhole(
        640,
        480,
        (0.0, -10.0, 50.0),
        fx=320,
        fy=320,
        cx=320,
        cy=240,
        dist=(-0.05, 0.01, 0.0, 0.0, 0.0),
    ),
    "pinhole-tangential": Pinhole(
        800, 600, fx=500, fy=480, cx=410, cy=290, dist=(-0.2, 0.05, 0.001, -0.002, 0.01)
    ),
    "fisheye": Fisheye(
        640,
        640,
        (0.0, -10.0, -45.0),
        fx=200,
        fy=200,
        cx=320,
        cy=320,
        dist=(0.02, -0.005, 0.001, 0.0),
    ),
}


@pytest.mark.parametrize("name", sorted(CAMERAS))
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_pixel_bearing_round_trip_to_1e9_rad(name: str, seed: int) -> None:
    cam = CAMERAS[name]
    rng = np.random.default_rng(seed)
    px = rng.uniform([0, 0], [cam.width, cam.height], size=(500, 2))
    b = cam.bearing_cam_from_pixel(px)
    ok = np.isfinite(b[:, 0])
    assert ok.mean() > 0.99
    np.testing.assert_allclose(np.linalg.norm(b[ok], axis=1), 1.0, atol=1e-12)
    px2 = cam.pixel_from_bearing_cam(b[ok])
    b2 = cam.bearing_cam_from_pixel(px2)
    assert np.max(angle_between(b[ok], b2)) < 1e-9
    assert np.max(np.abs(px2 - px[ok])) < 1e-6


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_bearing_pixel_round_trip_random_directions(name: str) -> None:
    cam = CAMERAS[name]
    rng = np.random.default_rng(1)
    b = normalize(rng.normal(size=(4000, 3)))
    px = cam.pixel_from_bearing_cam(b)
    seen = np.isfinite(px[:, 0]) & cam.in_image(px)
    assert seen.sum() > 50
    b2 = cam.bearing_cam_from_pixel(px[seen])
    assert np.max(angle_between(b[seen], b2)) < 1e-9


def test_equirectangular_matches_format_formula() -> None:
    cam = Equirectangular(360, 220)
    # Column 180 (left edge) is azimuth 0; the top edge of row 0 is elevation 75°.
    b = cam.bearing_cam_from_pixel(np.array([180.0, 0.0]))
    el = math.radians(75.0)
    np.testing.assert_allclose(b, [math.cos(el), 0.0, -math.sin(el)], atol=1e-15)
    # Azimuth positive to the right: a bearing with +y lands right of centre.
    px = cam.pixel_from_bearing_cam(np.array([1.0, 1.0, 0.0]))
    np.testing.assert_allclose(px, [225.0, 110.0], atol=1e-9)
    # Rows are 150/220 degrees tall, columns 1 degree wide.
    b0 = cam.bearing_cam_from_pixel(np.array([10.0, 10.0]))
    b1 = cam.bearing_cam_from_pixel(np.array([10.0, 11.0]))
    assert math.degrees(angle_between(b0, b1)) == pytest.approx(150 / 220, rel=1e-9)


def test_equirectangular_seam_wraps() -> None:
    cam = Equirectangular(360, 220)
    # Just left of straight behind is azimuth -180° + ε: the left edge, column 0.
    behind_left = cam.pixel_from_bearing_cam(np.array([-1.0, -1e-9, 0.0]))
    behind_right = cam.pixel_from_bearing_cam(np.array([-1.0, 1e-9, 0.0]))
    assert behind_left[0] == pytest.approx(0.0, abs=1e-6)
    assert behind_right[0] == pytest.approx(360.0, abs=1e-6)


def test_partial_panorama_rejects_unseen_directions() -> None:
    cam = CAMERAS["partial-panorama"]
    assert np.all(np.isnan(cam.pixel_from_bearing_cam(np.array([-1.0, 0.0, 0.0]))))
    assert np.all(np.isnan(cam.pixel_from_bearing_cam(np.array([0.0, 0.0, -1.0]))))


def test_pinhole_axes_and_half_pixel_convention() -> None:
    cam = Pinhole(640, 480, fx=320, fy=320, cx=320, cy=240, dist=(0.0,) * 5)
    # The optical axis hits the exact centre of the image (cx = 320 on a 640-wide image).
    np.testing.assert_allclose(cam.pixel_from_bearing_cam(np.array([1.0, 0.0, 0.0])), [320, 240])
    # Camera FRD: +y (right) goes right in the image, +z (down) goes down.
    right = cam.pixel_from_bearing_cam(np.array([1.0, 0.5, 0.0]))
    down = cam.pixel_from_bearing_cam(np.array([1.0, 0.0, 0.5]))
    np.testing.assert_allclose(right, [480, 240])
    np.testing.assert_allclose(down, [320, 400])
    # Behind the camera there is no pixel.
    assert np.all(np.isnan(cam.pixel_from_bearing_cam(np.array([-1.0, 0.0, 0.0]))))
    # OpenCV's camera matrix puts pixel centres at integers.
    assert cam.cv_camera_matrix()[0, 2] == pytest.approx(319.5)


def test_pinhole_distortion_matches_opencv() -> None:
    import cv2

    cam = CAMERAS["pinhole-tangential"]
    assert isinstance(cam, Pinhole)
    rng = np.random.default_rng(3)
    pts_cv = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.4, 0.4, 50), np.ones(50)])
    img, _ = cv2.projectPoints(
        pts_cv, np.zeros(3), np.zeros(3), cam.cv_camera_matrix(), np.asarray(cam.dist)
    )
    ours = cam.pixel_from_bearing_cam(pts_cv[:, [2, 0, 1]])
    np.testing.assert_allclose(ours, img.reshape(-1, 2) + 0.5, atol=1e-9)


def test_fisheye_matches_opencv() -> None:
    import cv2

    cam = CAMERAS["fisheye"]
    assert isinstance(cam, Fisheye)
    rng = np.random.default_rng(4)
    pts_cv = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-2, 2, 50), np.ones(50)])
    img, _ = cv2.fisheye.projectPoints(
        pts_cv.reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        cam.cv_camera_matrix(),
        np.asarray(cam.dist),
    )
    ours = cam.pixel_from_bearing_cam(pts_cv[:, [2, 0, 1]])
    np.testing.assert_allclose(ours, img.reshape(-1, 2) + 0.5, atol=1e-7)


def test_fisheye_sees_beyond_90_degrees_until_model_turns() -> None:
    cam = Fisheye(400, 400, fx=100, fy=100, cx=200, cy=200, dist=(0.0, 0.0, 0.0, 0.0))
    side = cam.pixel_from_bearing_cam(np.array([-0.1, 1.0, 0.0]))
    assert np.all(np.isfinite(side))
    assert side[0] > 200 + 100 * math.pi / 2


def test_solid_angles_sum_to_the_field_of_view() -> None:
    cam = Equirectangular(360, 220)
    expected = 2 * math.pi * (math.sin(math.radians(75)) - math.sin(math.radians(-75)))
    assert cam.solid_angle_map_sr.sum() == pytest.approx(expected, rel=1e-9)
    # A pinhole sees a rectangle of solid angle 4·asin(sin a sin b) for half-angles a, b.
    pin = Pinhole(200, 100, fx=100, fy=100, cx=100, cy=50, dist=(0.0,) * 5)
    a, b = math.atan(1.0), math.atan(0.5)
    rect = 4 * math.asin(math.sin(a) * math.sin(b))
    assert pin.solid_angle_map_sr.sum() == pytest.approx(rect, rel=1e-9)


def test_mount_rotation_order() -> None:
    cam = Pinhole(64, 48, (0.0, -10.0, 50.0), fx=32, fy=32, cx=32, cy=24, dist=(0.0,) * 5)
    axis_body = cam.R_body_from_cam @ np.array([1.0, 0.0, 0.0])
    # Yaw 50° right, pitch 10° down: the optical axis points right-forward and down.
    yaw = math.degrees(math.atan2(axis_body[1], axis_body[0]))
    pitch = math.degrees(math.atan2(-axis_body[2], math.hypot(axis_body[0], axis_body[1])))
    assert yaw == pytest.approx(50.0)
    assert pitch == pytest.approx(-10.0)


def test_camera_from_dict_errors_name_the_key() -> None:
    with pytest.raises(CameraModelError, match=r"camera\.model"):
        camera_from_dict({"model": "orthographic", "width": 10, "height": 10})
    with pytest.raises(CameraModelError, match=r"camera\.fx is required"):
        camera_from_dict({"model": "pinhole", "width": 10, "height": 10})
    with pytest.raises(CameraModelError, match=r"camera\.width"):
        camera_from_dict({"model": "equirectangular", "width": -1, "height": 10})
    with pytest.raises(CameraModelError, match=r"camera\.dist"):
        camera_from_dict(
            {
                "model": "fisheye",
                "width": 64,
                "height": 64,
                "fx": 30,
                "fy": 30,
                "cx": 32,
                "cy": 32,
                "dist": [0.1],
            }
        )
    with pytest.raises(CameraModelError, match=r"camera\.mount_rpy_deg"):
        camera_from_dict(
            {"model": "equirectangular", "width": 10, "height": 10, "mount_rpy_deg": [1, 2]}
        )
    # The ranges config.toml's camera is held to (issue 13): a too-small image, a lens
    # coefficient that is a typo, a mount beyond a whole turn.
    with pytest.raises(CameraModelError, match=r"camera\.width = 10 is out of range"):
        camera_from_dict({"model": "equirectangular", "width": 10, "height": 64})
    with pytest.raises(CameraModelError, match=r"camera\.dist = \[0\.1, 500\.0, 0\.0, 0\.0\]"):
        pinhole = {"model": "pinhole", "width": 64, "height": 64, "fx": 30, "fy": 30}
        camera_from_dict({**pinhole, "cx": 32, "cy": 32, "dist": [0.1, 500.0, 0.0, 0.0]})
    with pytest.raises(CameraModelError, match=r"camera\.mount_rpy_deg = \[0\.0, 0\.0, 400\.0\]"):
        camera_from_dict(
            {"model": "equirectangular", "width": 64, "height": 32, "mount_rpy_deg": [0, 0, 400]}
        )


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_to_dict_round_trip_and_scaling(name: str) -> None:
    cam = CAMERAS[name]
    assert camera_from_dict(cam.to_dict()) == cam
    big = cam.scaled(cam.width * 2, cam.height * 2)
    # The same direction lands on the same relative image position.
    b = cam.bearing_cam_from_pixel(np.array([cam.width * 0.3, cam.height * 0.6]))
    np.testing.assert_allclose(
        big.pixel_from_bearing_cam(b), [cam.width * 0.6, cam.height * 1.2], atol=1e-6
    )
