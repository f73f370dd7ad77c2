"""Sparse optic-flow tracks: sub-pixel accuracy, FB check, seeding masks, seam, history."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.core.camera import Equirectangular, Pinhole
from tcm_companion.core.flow import FlowConfig, FlowTracker, auto_downscale
from tcm_companion.core.frames import angle_between, azel_from_bearing, rot_from_euler_zyx

W, H = 360, 220
NO_SKY = math.pi / 2  # sky_elevation_rad that never excludes anything


def texture(
    width: int, height: int, shift_px: tuple[float, float] = (0.0, 0.0), seed: int = 1
) -> np.ndarray:
    """Smooth random texture whose content moves by ``shift_px`` (exact, no resampling).

    Sums of cosines with whole numbers of periods across the width, so the texture is
    also seamless across the left/right edge (a full panorama).
    """
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    u = u - shift_px[0]
    v = v - shift_px[1]
    img = np.zeros((height, width))
    for _ in range(40):
        cycles = rng.integers(6, 40)
        fu = cycles / width
        fv = rng.uniform(-1.0 / 6, 1.0 / 6)
        img += np.cos(2 * np.pi * (fu * u + fv * v) + rng.uniform(0, 2 * np.pi))
    img = 128 + 30 * img / img.std()
    return np.clip(img, 0, 255).astype(np.uint8)


def panorama() -> Equirectangular:
    return Equirectangular(W, H)


def test_subpixel_shift_is_recovered() -> None:
    tracker = FlowTracker(panorama(), FlowConfig(sky_elevation_rad=NO_SKY))
    R = np.eye(3)
    shift = (1.3, -0.6)
    tracker.update(texture(W, H), 0, R)
    stats = tracker.update(texture(W, H, shift), 1, R)
    p0, p1 = tracker.pixel_correspondences(0, 1)
    assert len(p0) > 300 and stats.n_tracked == len(p0)
    d = p1 - p0
    d[:, 0] = (d[:, 0] + W / 2) % W - W / 2
    err = np.hypot(d[:, 0] - shift[0], d[:, 1] - shift[1])
    assert np.median(err) < 0.03
    assert np.percentile(err, 95) < 0.1


def test_bearings_are_ned_aligned_unit_vectors() -> None:
    cam = panorama()
    R = rot_from_euler_zyx(0.05, -0.1, 0.7)
    tracker = FlowTracker(cam, FlowConfig(sky_elevation_rad=NO_SKY))
    tracker.update(texture(W, H), 0, R)
    tracker.update(texture(W, H, (0.5, 0.2)), 1, R)
    b0, b1 = tracker.correspondences(0, 1)
    p0, p1 = tracker.pixel_correspondences(0, 1)
    np.testing.assert_allclose(np.linalg.norm(b1, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(b0, cam.bearing_cam_from_pixel(p0) @ R.T, atol=1e-6)
    np.testing.assert_allclose(b1, cam.bearing_cam_from_pixel(p1) @ R.T, atol=1e-6)


def test_forward_backward_check_drops_occluded_points() -> None:
    tracker = FlowTracker(panorama(), FlowConfig(sky_elevation_rad=NO_SKY, fb_every=1))
    R = np.eye(3)
    a = texture(W, H)
    b = texture(W, H, (0.8, 0.4))
    # An occluder with unrelated texture covers a block in the second frame.
    box = (slice(60, 140), slice(100, 200))
    b[box] = texture(W, H, seed=99)[box]
    tracker.update(a, 0, R)
    stats = tracker.update(b, 1, R)
    p0, _ = tracker.pixel_correspondences(0, 1)
    inside = (p0[:, 0] > 106) & (p0[:, 0] < 194) & (p0[:, 1] > 66) & (p0[:, 1] < 134)
    assert stats.n_fb_checked == stats.n_tracked + stats.n_lost_fb
    assert inside.sum() <= 2
    assert stats.n_lost_fb + stats.n_lost_lk > 20
    outside = (p0[:, 0] < 90) | (p0[:, 0] > 210) | (p0[:, 1] < 50) | (p0[:, 1] > 150)
    assert outside.sum() > 150  # the rest kept tracking


def test_sky_is_not_seeded() -> None:
    cam = panorama()
    R_ned_from_cam = rot_from_euler_zyx(0.0, math.radians(10.0), 0.3)  # nose up 10°
    tracker = FlowTracker(cam, FlowConfig(sky_elevation_rad=0.0))
    stats = tracker.update(texture(W, H), 0, R_ned_from_cam)
    assert stats.n_seeded > 200
    b = cam.bearing_cam_from_pixel(tracker.live_points_px) @ R_ned_from_cam.T
    _, el = azel_from_bearing(b)
    assert np.all(el <= 1e-9)
    # Pitching up lowers the horizon in the image: seeds reach into the upper half on
    # the side the nose points to but never above the horizon.
    assert np.max(el) > math.radians(-3.0)


def test_sky_elevation_is_configurable() -> None:
    cam = panorama()
    tracker = FlowTracker(cam, FlowConfig(sky_elevation_rad=math.radians(-20.0)))
    tracker.update(texture(W, H), 0, np.eye(3))
    _, el = azel_from_bearing(cam.bearing_cam_from_pixel(tracker.live_points_px))
    assert np.all(el <= math.radians(-20.0))


def test_excluded_boxes_are_not_seeded_and_tracks_entering_them_drop() -> None:
    cfg = FlowConfig(sky_elevation_rad=NO_SKY, exclude_margin_px=4)
    tracker = FlowTracker(panorama(), cfg)
    boxes = [(100, 120, 160, 180), (340, 20, 370, 60)]  # the second wraps over the seam
    tracker.update(texture(W, H), 0, np.eye(3), boxes)
    p = tracker.live_points_px

    def in_box(p: np.ndarray, box: tuple[int, int, int, int], m: int) -> np.ndarray:
        u0, v0, u1, v1 = box
        du = np.mod(p[:, 0] - (u0 - m), W)
        return (du < (u1 - u0) + 2 * m) & (p[:, 1] >= v0 - m) & (p[:, 1] < v1 + m)

    for box in boxes:
        assert not in_box(p, box, 4).any()
    assert (p[:, 0] < 10).any() and (p[:, 0] > 350).any()  # seeds near the seam elsewhere
    # A box appearing over live tracks drops them.
    new_box = (200, 100, 260, 160)
    before = in_box(p, new_box, 4).sum()
    stats = tracker.update(texture(W, H, (0.3, 0.0)), 1, np.eye(3), [new_box])
    assert before > 10 and stats.n_dropped >= before
    assert not in_box(tracker.live_points_px, new_box, 4).any()


def test_low_texture_is_not_seeded() -> None:
    img = texture(W, H)
    img[:, : W // 2] = 128  # left half flat
    tracker = FlowTracker(panorama(), FlowConfig(sky_elevation_rad=NO_SKY))
    tracker.update(img, 0, np.eye(3))
    u = tracker.live_points_px[:, 0]
    # Seeds within a window of the seam see the textured right edge through the wrap.
    assert np.all((u > W // 2 - 6) | (u < 6))


def test_panorama_tracks_cross_the_seam() -> None:
    cam = panorama()
    tracker = FlowTracker(cam, FlowConfig(sky_elevation_rad=NO_SKY))
    R = np.eye(3)
    step = 2.5
    for i in range(6):
        tracker.update(texture(W, H, (i * step, 0.0)), i, R)
    p0, p5 = tracker.pixel_correspondences(0, 5)
    crossed = (p0[:, 0] > W - 5 * step) & (p5[:, 0] < 5 * step)
    assert crossed.sum() >= 5
    # Every track moved by exactly the shift in azimuth (1° per column here).
    b0, b5 = tracker.correspondences(0, 5)
    ang = np.degrees(angle_between(b0, b5))
    _, el = azel_from_bearing(b0)
    expected = np.degrees(
        angle_between(
            b0,
            np.stack(
                [
                    np.cos(np.radians(5 * step)) * b0[:, 0]
                    - np.sin(np.radians(5 * step)) * b0[:, 1],
                    np.sin(np.radians(5 * step)) * b0[:, 0]
                    + np.cos(np.radians(5 * step)) * b0[:, 1],
                    b0[:, 2],
                ],
                axis=1,
            ),
        )
    )
    assert np.median(np.abs(ang - expected)) < 0.03
    assert np.all(np.abs(el) < math.radians(76))


@pytest.mark.parametrize("predict", [True, False])
def test_fast_yaw_is_followed_through_the_attitude(predict: bool) -> None:
    """8° of yaw per frame (200°/s): 8 px at 360 px, beyond one pyramid level's reach."""
    cam = panorama()
    cfg = FlowConfig(sky_elevation_rad=NO_SKY, predict_rotation=predict)
    tracker = FlowTracker(cam, cfg)
    yaw_deg = 8.0
    for i in range(6):
        R = rot_from_euler_zyx(0.0, 0.0, math.radians(yaw_deg * i))
        # Yawing right moves the scene left in the image.
        tracker.update(texture(W, H, (-yaw_deg * i * W / 360.0, 0.0)), i, R)
    b0, b5 = tracker.correspondences(0, 5)
    if predict:
        assert len(b0) > 300
        # A static scene seen from one place: NED bearings do not change.
        assert np.degrees(np.median(angle_between(b0, b5))) < 0.05
    else:
        assert len(b0) < 150  # most are lost without the prediction


@pytest.mark.slow  # over a second of CPU
def test_pinhole_edges_drop_tracks_and_history_is_bounded() -> None:
    cam = Pinhole(320, 240, fx=250, fy=250, cx=160, cy=120)
    cfg = FlowConfig(sky_elevation_rad=NO_SKY, max_history=10, n_points=200)
    tracker = FlowTracker(cam, cfg)
    R = np.eye(3)
    for i in range(14):
        stats = tracker.update(texture(320, 240, (3.0 * i, 0.0)), i, R)
        assert stats.n_live <= cfg.n_points
    assert len(tracker.correspondences(3, 13)[0]) == 0  # frame 3 has left the 10-frame history
    assert len(tracker.correspondences(4, 13)[0]) > 50
    assert tracker.has_frame(13) and not tracker.has_frame(3)
    p = tracker.live_points_px
    assert np.all((p[:, 0] >= 0) & (p[:, 0] < 320))


def test_missing_attitude_leaves_a_gap_but_tracks_continue() -> None:
    tracker = FlowTracker(panorama(), FlowConfig(sky_elevation_rad=NO_SKY))
    R = np.eye(3)
    tracker.update(texture(W, H), 0, R)
    stats = tracker.update(texture(W, H, (0.7, 0.0)), 1, None)
    assert not stats.has_bearings and stats.n_seeded == 0
    tracker.update(texture(W, H, (1.4, 0.0)), 2, R)
    assert len(tracker.correspondences(0, 1)[0]) == 0
    assert len(tracker.pixel_correspondences(0, 1)[0]) > 300
    assert len(tracker.correspondences(0, 2)[0]) > 300


def test_skipped_frames_and_restart() -> None:
    tracker = FlowTracker(panorama(), FlowConfig(sky_elevation_rad=NO_SKY))
    R = np.eye(3)
    tracker.update(texture(W, H), 0, R)
    tracker.update(texture(W, H, (0.5, 0.0)), 3, R)  # frames 1, 2 never came
    assert not tracker.has_frame(1)
    assert len(tracker.correspondences(0, 3)[0]) > 300
    stats = tracker.update(texture(W, H), 2, R)  # back in time: start over
    assert stats.n_tracked == 0 and not tracker.has_frame(0)


@pytest.mark.parametrize("fb_every", [2, 3])
@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_staggered_forward_backward_check(fb_every: int) -> None:
    """Each track is checked once per fb_every frames, a share of them every frame."""
    n_points = 300
    cfg = FlowConfig(sky_elevation_rad=NO_SKY, fb_every=fb_every, n_points=n_points)
    tracker = FlowTracker(panorama(), cfg)
    R = np.eye(3)
    checked = []
    for i in range(10):
        checked.append(tracker.update(texture(W, H, (0.6 * i, 0.0)), i, R).n_fb_checked)
    per_frame = np.array(checked[fb_every + 1 :])
    assert np.all(np.abs(per_frame - n_points / fb_every) < 0.2 * n_points / fb_every)
    # An occluder over a block in one frame: the tracks under it are gone afterwards.
    for i in range(10, 10 + 2 * fb_every):
        img = texture(W, H, (0.6 * i, 0.0))
        if i == 11:
            img[60:140, 100:200] = texture(W, H, seed=99)[60:140, 100:200]
        tracker.update(img, i, R)
    p10, _ = tracker.pixel_correspondences(10, 9 + 2 * fb_every)
    inside = (p10[:, 0] > 106) & (p10[:, 0] < 190) & (p10[:, 1] > 66) & (p10[:, 1] < 134)
    assert inside.sum() <= 2
    assert len(p10) > 150


def test_downscaled_tracking_reports_full_resolution_pixels() -> None:
    cam = Equirectangular(720, 440)
    tracker = FlowTracker(cam, FlowConfig(sky_elevation_rad=NO_SKY, downscale=2))
    R = np.eye(3)
    tracker.update(texture(720, 440), 0, R)
    tracker.update(texture(720, 440, (2.0, 1.0)), 1, R)
    p0, p1 = tracker.pixel_correspondences(0, 1)
    assert len(p0) > 300
    d = p1 - p0
    # 0.05 px at the tracking resolution.
    assert np.median(np.abs(d[:, 0] - 2.0)) < 0.12
    assert np.median(np.abs(d[:, 1] - 1.0)) < 0.12


def test_automatic_downscale() -> None:
    assert auto_downscale(Equirectangular(360, 220)) == 1
    assert auto_downscale(Equirectangular(900, 550)) == 2
    assert auto_downscale(Equirectangular(1250, 764)) == 2  # 3 does not divide the width
    assert auto_downscale(Pinhole(640, 480, fx=300, fy=300, cx=320, cy=240)) == 1
    assert auto_downscale(Pinhole(1280, 960, fx=600, fy=600, cx=640, cy=480)) == 3


def test_rejects_a_wrong_image_size() -> None:
    tracker = FlowTracker(panorama())
    with pytest.raises(ValueError, match="360x220"):
        tracker.update(np.zeros((100, 100), np.uint8), 0, np.eye(3))


def test_example_scenario_gives_the_true_translation_direction() -> None:
    """Flow + egomotion on the independent EX-T90 against its truth (first 40 frames)."""
    import cv2

    from tcm_companion.core.egomotion import translation_from_bearings
    from tcm_companion.core.telemetry import TelemetryBuffer
    from tcm_companion.io.scenario import load_scenario

    from .helpers import example_path

    s = load_scenario(example_path("EX-T90"))
    assert s.truth is not None
    tb = TelemetryBuffer()
    tb.extend(s.telemetry)
    tracker = FlowTracker(s.camera)
    errors = []
    for i, t in enumerate(s.frame_times_us[:40]):
        R_body = tb.attitude_at(int(t))
        assert R_body is not None
        gray = cv2.cvtColor(s.read_frame(i), cv2.COLOR_BGR2GRAY)
        tracker.update(gray, i, R_body @ s.camera.R_body_from_cam)
        if i >= 25:
            b0, b1 = tracker.correspondences(i - 25, i)
            est = translation_from_bearings(b0, b1, rng_seed=i)
            T = (
                s.truth.veh_ned_m[s.truth.frame == i][0]
                - s.truth.veh_ned_m[s.truth.frame == i - 25][0]
            )
            assert est.valid
            errors.append(float(angle_between(est.t_hat_ned, T)))
    # The attitude carries up to ~1° of bias by design: that is the floor here.
    assert np.degrees(np.median(errors)) < 2.0
