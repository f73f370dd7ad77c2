"""The two-fisheye stitcher: geometry of its tables, coverage, blending, and a rendered scene.

The rendered comparison draws the same field through two back-to-back 200° fisheyes and
directly through the paper's 360×220 panorama, stitches the fisheye pair and compares.
Measured (noise-free): mean absolute difference 1.96-1.99 DN over the whole panorama
(the same inside and outside the seam band), red-ball centroid 0.03-0.09 px off (a ball
straddling the seam included). For scale, the direct panorama against itself shifted by
one column differs by 3.7 DN, and stitching fisheye images shifted by one fisheye pixel
(~0.3 panorama px) gives 2.84 DN, so the 2.5 DN bound catches a misregistration of a
fraction of a panorama pixel while leaving ~25% headroom over the (deterministic,
noise-free) measurement.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tcm_companion.core.camera import Equirectangular, Fisheye
from tcm_companion.io.cameras.stitch import FisheyeStitcher, bench
from tcm_companion.sim.scene.render import Renderer
from tcm_companion.sim.scene.scenarios import FlightPlan, flight_plan
from tcm_companion.sim.scene.world import Ball, Trajectory, World, field_world

LENS_DIST = (0.02, -0.005, 0.001, 0.0)
MAD_BOUND_DN = 2.5  # measured 1.96-1.99; see the module docstring
CENTROID_BOUND_PX = 0.5  # measured ≤ 0.09


def _lens(
    yaw_deg: float, fov_deg: float = 200.0, size: int = 640, roll_pitch_deg: tuple = (0.0, 0.0)
) -> Fisheye:
    """A fisheye whose ``fov_deg`` image circle just fits a ``size``² image."""
    th = math.radians(fov_deg / 2.0)
    k1, k2, k3, k4 = LENS_DIST
    t2 = th * th
    theta_d = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    f = (size / 2.0 - 0.5) / theta_d
    mount = (roll_pitch_deg[0], roll_pitch_deg[1], yaw_deg)
    return Fisheye(size, size, mount, fx=f, fy=f, cx=size / 2.0, cy=size / 2.0, dist=LENS_DIST)


def _calibration(yaw_deg: float) -> dict[str, object]:
    lens = _lens(yaw_deg)
    return {
        "width": lens.width,
        "height": lens.height,
        "fx": lens.fx,
        "fy": lens.fy,
        "cx": lens.cx,
        "cy": lens.cy,
        "dist": list(lens.dist),
        "mount_rpy_deg": [0.0, 0.0, yaw_deg],
    }


@pytest.fixture(scope="module")
def stitcher() -> FisheyeStitcher:
    return FisheyeStitcher(_lens(0.0), _lens(180.0), Equirectangular(360, 220))


@pytest.fixture(scope="module")
def tilted() -> FisheyeStitcher:
    """Still back-to-back (opposite axes), but rolled, pitched and yawed, and the panorama
    yawed too: the mounts' rotations are not their own transposes as 0°/180° yaw are."""
    front = _lens(30.0, roll_pitch_deg=(15.0, -10.0))
    back = _lens(210.0, roll_pitch_deg=(-20.0, 10.0))
    return FisheyeStitcher(front, back, Equirectangular(360, 220, (0.0, 0.0, 10.0)))


@pytest.fixture(scope="module", params=["back_to_back", "tilted"])
def any_rig(request: pytest.FixtureRequest) -> FisheyeStitcher:
    return request.getfixturevalue("stitcher" if request.param == "back_to_back" else "tilted")


# --------------------------------------------------------------------------------------
# The fisheye model the tables use is OpenCV's
# --------------------------------------------------------------------------------------
def test_fisheye_pixels_agree_with_opencv() -> None:
    lens = _lens(0.0)
    # Camera FRD bearings within 90° of the axis (OpenCV's projection takes z > 0 only).
    bearings = np.array(
        [[1.0, 0.0, 0.0], [1.0, 0.3, -0.2], [0.5, -0.8, 0.1], [0.2, 0.6, 0.7], [0.05, 1.0, 0.0]]
    )
    ours = lens.pixel_from_bearing_cam(bearings)
    # FRD (x forward, y right, z down) → OpenCV (x right, y down, z forward).
    pts_cv = bearings[:, [1, 2, 0]]
    K, D = lens.cv_camera_matrix(), np.asarray(lens.dist)
    projected, _ = cv2.fisheye.projectPoints(
        pts_cv.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D
    )
    np.testing.assert_allclose(ours, projected.reshape(-1, 2) + 0.5, atol=1e-6)
    normalised = (pts_cv[:, :2] / pts_cv[:, 2:]).reshape(1, -1, 2)
    distorted = cv2.fisheye.distortPoints(normalised, K, D)
    np.testing.assert_allclose(ours, distorted.reshape(-1, 2) + 0.5, atol=1e-6)


# --------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------
def test_panorama_bearing_round_trips_through_each_lens(any_rig: FisheyeStitcher) -> None:
    stitcher = any_rig
    assert stitcher.coverage_mask.all()
    pano = stitcher.panorama
    bearing_body = pano.bearing_map_cam @ pano.R_body_from_cam.T
    for lens, uv in ((stitcher.front, stitcher.front_uv), (stitcher.back, stitcher.back_uv)):
        seen = np.isfinite(uv[..., 0])
        assert seen.mean() > 0.5
        back_cam = lens.bearing_cam_from_pixel(uv[seen])
        back_body = back_cam @ lens.R_body_from_cam.T
        cosang = np.sum(back_body * bearing_body[seen], axis=-1)
        cross = np.linalg.norm(np.cross(back_body, bearing_body[seen]), axis=-1)
        err = np.arctan2(cross, cosang)
        assert float(err.max()) < 1e-6


def test_remap_of_a_synthetic_pattern(any_rig: FisheyeStitcher) -> None:
    """Each lens image encodes its own pixel coordinates (ramps of 4 DN per pixel) and its
    identity; the stitched panorama must hold the coordinates its float tables predict
    (so the fixed-point maps and the half-pixel convention are right) and the blend
    weight it reports."""
    stitcher = any_rig
    size = stitcher.front.width
    i = np.arange(size)
    ramp = ((4 * i) % 256).astype(np.uint8)

    def pattern(identity: int) -> np.ndarray:
        img = np.empty((size, size, 3), np.uint8)
        img[..., 0] = ramp[None, :]  # B: 4 × column
        img[..., 1] = ramp[:, None]  # G: 4 × row
        img[..., 2] = identity
        return img

    out = stitcher.stitch(pattern(255), pattern(0)).astype(np.float64)
    w = stitcher.weight_front
    cov = stitcher.coverage_mask
    # R is 255 × front's share everywhere (rounding of the 8-bit weights: ≤ 1 DN).
    assert np.abs(out[..., 2] - 255.0 * w)[cov].max() <= 1.0
    for full, uv in ((w == 1.0, stitcher.front_uv), (w == 0.0, stitcher.back_uv)):
        sel = full & cov
        x = uv[sel] - 0.5  # OpenCV pixel-centre coordinates
        phase = np.mod(x, 64.0)
        keep = np.all((phase > 1.0) & (phase < 62.0), axis=-1)  # both bilinear taps in one ramp
        expected = 4.0 * phase[keep]
        got = out[sel][keep][:, [0, 1]]
        assert keep.sum() > 10_000
        # Bilinear of a linear ramp is exact; fixed point (1/32 px) and 8-bit rounding
        # leave < 1 DN. Half a pixel off would be 2 DN.
        assert float(np.abs(got - expected).max()) < 1.0


# --------------------------------------------------------------------------------------
# Coverage and seam
# --------------------------------------------------------------------------------------
def test_two_200_degree_lenses_cover_the_whole_panorama(stitcher: FisheyeStitcher) -> None:
    assert stitcher.front_theta_limit_deg == pytest.approx(100.0)
    assert np.array_equal(stitcher.coverage_mask, stitcher.panorama.valid_mask)
    assert stitcher.coverage_mask.all()
    assert 0 < stitcher.seam_pixels < 0.05 * stitcher.coverage_mask.size


@pytest.mark.parametrize("explicit_fov", [False, True])
def test_two_150_degree_lenses_leave_gaps_at_90_degrees_azimuth(explicit_fov: bool) -> None:
    pano = Equirectangular(360, 220)
    fov = 150.0 if explicit_fov else None
    # explicit: the 200° lenses limited to 150°; default: 150° image circles.
    front, back = (
        (_lens(0.0), _lens(180.0)) if explicit_fov else (_lens(0.0, 150), _lens(180.0, 150))
    )
    st = FisheyeStitcher(front, back, pano, front_fov_deg=fov, back_fov_deg=fov)
    b = pano.bearing_map_cam
    # Seen iff within 75° of the nearer axis (front +x, back -x): the gaps are the band
    # within 15° of the great circle through azimuth ±90° and the poles (|x| < sin 15°),
    # 30° wide at the horizon and widening towards the top and bottom rows.
    cos75 = math.cos(math.radians(75.0))
    expected = np.abs(b[..., 0]) >= cos75
    near_edge = np.abs(np.abs(b[..., 0]) - cos75) < 1e-9
    assert np.array_equal(st.coverage_mask[~near_edge], expected[~near_edge])
    gaps = ~st.coverage_mask
    assert 0.15 < gaps.mean() < 0.4
    az_deg = -180.0 + np.arange(360) + 0.5
    horizon = gaps[110]  # the row just below the horizon: gaps 75°..105° on both sides
    assert set(np.floor(az_deg[horizon]).astype(int).tolist()) == set(range(75, 105)) | set(
        range(-105, -75)
    )
    assert st.seam_pixels == 0  # no pixel is seen by both
    out = st.stitch(np.full((640, 640, 3), 200, np.uint8), np.full((640, 640, 3), 100, np.uint8))
    assert np.all(out[gaps] == 0)
    assert np.all(out[st.coverage_mask & (b[..., 0] > 0)] == 200)
    assert np.all(out[st.coverage_mask & (b[..., 0] < 0)] == 100)


def test_a_field_of_view_wider_than_the_image_is_clipped_to_the_image() -> None:
    # 260° asked of lenses whose 200° circle fills the image: the corners are used, and
    # no table entry leaves the span where bilinear interpolation has both neighbours.
    st = FisheyeStitcher(
        _lens(0.0), _lens(180.0), Equirectangular(360, 220), front_fov_deg=260, back_fov_deg=260
    )
    assert st.front_theta_limit_deg == pytest.approx(130.0)
    for lens, uv in ((st.front, st.front_uv), (st.back, st.back_uv)):
        seen = uv[np.isfinite(uv[..., 0])]
        assert seen.min() >= 0.5 and seen[:, 0].max() <= lens.width - 0.5
        assert seen[:, 1].max() <= lens.height - 0.5
        assert np.hypot(seen[:, 0] - lens.cx, seen[:, 1] - lens.cy).max() > lens.width / 2


def test_exposure_difference_is_cross_faded_across_the_seam(stitcher: FisheyeStitcher) -> None:
    out = stitcher.stitch(
        np.full((640, 640, 3), 200, np.uint8), np.full((640, 640, 3), 160, np.uint8)
    )
    row = out[110, :, 0].astype(int)  # just below the horizon
    right = row[180:360]  # azimuth 0..180: front → back at +90°
    assert right[0] == 200 and right[-1] == 160
    assert np.all(np.diff(right) <= 0)  # monotonic
    assert np.abs(np.diff(right)).max() <= 15  # no step: ≥ 3 intermediate values
    assert len(set(right.tolist()) - {160, 200}) >= 3
    between = np.nonzero((right < 200) & (right > 160))[0]
    assert set(between.tolist()) <= set(range(87, 93))  # within blend_deg/2 + ½ px of 90°


# --------------------------------------------------------------------------------------
# A rendered scene: stitched fisheye pair vs the direct panorama
# --------------------------------------------------------------------------------------
def _red_centroid(img: np.ndarray) -> tuple[float, float, np.ndarray]:
    """Redness-weighted centroid (continuous pixel coordinates) and the ball mask."""
    b, g, r = (img[..., c].astype(np.float64) for c in range(3))
    red = np.clip(r - 1.8 * np.maximum(g, b), 0.0, None)
    mask = red > 20.0
    ys, xs = np.nonzero(mask)
    wts = red[mask]
    return (
        float(np.sum(wts * (xs + 0.5)) / wts.sum()),
        float(np.sum(wts * (ys + 0.5)) / wts.sum()),
        mask,
    )


def _render(
    world: World, t_s: float, pos: np.ndarray, R: np.ndarray, st: FisheyeStitcher
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free front, back and direct-panorama frames of one pose."""
    imgs = [
        Renderer(world, cam, fisheye_fov_deg=200.0).render(t_s, pos, R, noise_dn=0)
        for cam in (st.front, st.back, st.panorama)
    ]
    return imgs[0], imgs[1], imgs[2]


@pytest.fixture(scope="module")
def plan_and_world() -> tuple[FlightPlan, World]:
    plan = flight_plan("TS")
    return plan, field_world(plan.balls, plan.heading_rad)


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize(
    ("rig", "t_s", "lens_of_ball"),
    [("stitcher", 2.5, "back"), ("stitcher", 7.5, "front"), ("tilted", 7.5, "front")],
)
def test_stitched_scene_matches_direct_panorama(
    request: pytest.FixtureRequest,
    plan_and_world: tuple[FlightPlan, World],
    rig: str,
    t_s: float,
    lens_of_ball: str,
) -> None:
    stitcher: FisheyeStitcher = request.getfixturevalue(rig)
    plan, world = plan_and_world
    pos, R = plan.vehicle.position_ned_m(t_s), plan.vehicle.R_ned_from_body(t_s)
    front_img, back_img, direct = _render(world, t_s, pos, R, stitcher)
    stitched = stitcher.stitch(front_img, back_img)
    assert stitched.shape == direct.shape and stitched.dtype == np.uint8
    diff = np.abs(stitched.astype(np.int16) - direct.astype(np.int16))
    mad = float(diff.mean())
    su, sv, smask = _red_centroid(stitched)
    du, dv, dmask = _red_centroid(direct)
    err = math.hypot(su - du, sv - dv)
    lens_w = stitcher.weight_front[dmask]
    print(
        f"{rig} t={t_s}: MAD {mad:.2f} DN, centroid error {err:.3f} px, front share {lens_w.mean():.2f}"
    )
    assert mad < MAD_BOUND_DN
    assert err < CENTROID_BOUND_PX
    # The ball really is inside one lens here.
    assert np.all(lens_w == (1.0 if lens_of_ball == "front" else 0.0))
    assert abs(int(smask.sum()) - int(dmask.sum())) <= 0.1 * dmask.sum()


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_ball_across_the_seam(
    stitcher: FisheyeStitcher, plan_and_world: tuple[FlightPlan, World]
) -> None:
    plan, world = plan_and_world
    t_s = 0.0
    pos, R = plan.vehicle.position_ned_m(t_s), plan.vehicle.R_ned_from_body(t_s)
    # 3.5 m to the body's right and 1 m down: centred on the +90° seam.
    centre = pos + R @ np.array([0.0, 3.5, 1.0])
    seam_world = world.with_balls((Ball(Trajectory.static((centre[0], centre[1], centre[2]))),))
    front_img, back_img, direct = _render(seam_world, t_s, pos, R, stitcher)
    stitched = stitcher.stitch(front_img, back_img)
    su, sv, _ = _red_centroid(stitched)
    du, dv, dmask = _red_centroid(direct)
    w = stitcher.weight_front[dmask]
    # Both lenses contribute to the ball, and the blend band runs through it.
    assert (w == 1.0).sum() > 10 and (w == 0.0).sum() > 10
    assert ((w > 0.0) & (w < 1.0)).sum() > 10
    err = math.hypot(su - du, sv - dv)
    near_ball = cv2.dilate(dmask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    diff = np.abs(stitched.astype(np.int16) - direct.astype(np.int16))
    mad_ball = float(diff[near_ball].mean())
    print(f"seam ball: centroid error {err:.3f} px, MAD around the ball {mad_ball:.2f} DN")
    assert err < CENTROID_BOUND_PX
    # The ball's rim is resampled differently (its anti-aliasing is per camera), so the
    # neighbourhood of the ball differs more than the whole image; measured 2.97 DN.
    assert mad_ball < 4.5
    seam = (stitcher.weight_front > 0.0) & (stitcher.weight_front < 1.0)
    assert float(diff[seam].mean()) < MAD_BOUND_DN


# --------------------------------------------------------------------------------------
# Errors, construction from a calibration, timing
# --------------------------------------------------------------------------------------
def test_wrong_image_sizes_raise_naming_the_image(stitcher: FisheyeStitcher) -> None:
    good = np.zeros((640, 640, 3), np.uint8)
    with pytest.raises(ValueError, match="front"):
        stitcher.stitch(np.zeros((480, 640, 3), np.uint8), good)
    with pytest.raises(ValueError, match="back"):
        stitcher.stitch(good, np.zeros((640, 640), np.uint8))
    with pytest.raises(ValueError, match="back"):
        stitcher.stitch(good, good.astype(np.float32))


def test_from_calibration_builds_the_same_stitcher(stitcher: FisheyeStitcher) -> None:
    st = FisheyeStitcher.from_calibration(_calibration(0.0), _calibration(180.0))
    assert st.front == stitcher.front and st.back == stitcher.back
    assert st.panorama == stitcher.panorama
    assert np.array_equal(st.coverage_mask, stitcher.coverage_mask)
    small = FisheyeStitcher.from_calibration(
        {**_calibration(0.0), "fov_deg": 150.0},
        {**_calibration(180.0), "fov_deg": 150},
        panorama_size=(180, 110),
    )
    assert small.panorama.width == 180 and small.panorama.height == 110
    assert not small.coverage_mask.all()


@pytest.mark.parametrize(
    ("which", "change", "key"),
    [
        ("front", {"fx": None}, "front.fx"),
        ("back", {"mount_rpy_deg": None}, "back.mount_rpy_deg"),
        ("back", {"fy": -3.0}, "back.fy"),
        ("front", {"dist": [0.1, 0.2]}, "front.dist"),
        ("back", {"width": 640.5}, "back.width"),
        ("front", {"cx": "320"}, "front.cx"),
        ("front", {"mount_rpy_deg": [0.0, 0.0]}, "front.mount_rpy_deg"),
        ("back", {"fov_deg": 0.0}, "back.fov_deg"),
        ("front", {"focal": 200.0}, "front.focal"),
    ],
)
def test_from_calibration_errors_name_the_key(which: str, change: dict, key: str) -> None:
    tables = {"front": _calibration(0.0), "back": _calibration(180.0)}
    for k, v in change.items():
        if v is None:
            del tables[which][k]
        else:
            tables[which][k] = v
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        FisheyeStitcher.from_calibration(tables["front"], tables["back"])


def test_from_calibration_rejects_a_bad_panorama_size() -> None:
    with pytest.raises(ValueError, match="panorama_size"):
        FisheyeStitcher.from_calibration(
            _calibration(0.0), _calibration(180.0), panorama_size=(360, 0)
        )


def test_bench_reports_the_stitch_time(stitcher: FisheyeStitcher) -> None:
    result = bench(stitcher, repeats=50)
    # Timing is printed, not asserted (the budget is ≤ 2 ms on one core).
    print(f"stitch 2×640² → 360×220, 1 thread: median {result['median_ms']:.3f} ms")
    assert result["median_ms"] > 0.0
