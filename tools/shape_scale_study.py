"""Looming for any shape (issue 14 §2): which image measurement gives the range ratio.

TCM compares the range ratio ``d0/d1`` predicted by the triangle with the one measured
from the object's looming. For a sphere ``sin α1 / sin α0`` is exact; for a box, a
cylinder or a disc the size seen also changes with the viewpoint. This study scores each
estimator against the simulator's true range ratio (:func:`~tcm_companion.sim.scene.truth.true_range_ratio`,
ranges to the object's centre) over pairs of frames ``--interval-s`` apart (every
``--stride`` frames), on the exact geometry (no detector noise):

- ``a``  features: points found (``cv2.goodFeaturesToTrack``) inside the object's true box
  in the rendered earlier frame, followed into the later one by pyramidal Lucas–Kanade
  (started from the box centre's shift, forward–backward checked), the median of pairwise
  separation ratios (:func:`feature_scale_ratio`);
- ``a⊥`` the same, separations measured along the epipolar normal only;
- ``b``  the box's extent along the image direction perpendicular to the translation
  (:func:`box_extent_across_rad`);
- ``c``  the box's geometric mean ``√(θw·θh)`` (the boxes backend before this study);
- ``diag`` the box's diagonal ``√(θw² + θh²)``; ``w``, ``h`` its width and height alone;
- ``area`` the radius of the cap with the silhouette's solid angle (what the colour
  backend measures, from the renderer's coverage).

Then the box estimators ``b`` and ``c`` again, from the detector simulator's boxes
(:mod:`~tcm_companion.sim.scene.detector_sim`, default noise: 1-px centre jitter, 4 %
scale noise per side, 5 % misses), from single frames and fitted over a window of
``--window-s`` (:func:`~tcm_companion.core.ttc.robust_level_at` on ``ln sin(e/2)``):
``centred`` fits both ends over the window centred on each (the pair then ends half a
window before the newest frame), ``trailing`` fits the later end over the window ending
at it (no delay; the line is evaluated at the window's end).

Errors are ``R_est - R_true`` (the units of the TCM disparity δ, threshold 0.09): median
and p90 of the absolute error and the signed median, per scenario and estimator; the last
table pools each shape. Seed 0, true pose (the translation T̂ is the true one).

Commands (docs/decisions.md §9; ~10 min on a shared 2-core machine):

    .venv/bin/python tools/shape_scale_study.py --duration 20 --sim TS-BOX T45-BOX \\
        T90-BOX TS-CYL T45-CYL T90-CYL TS-DISC T45-DISC T90-DISC RAISED-DISC INPLANE-BOX \\
        COLLISION-CYL COLLISION-DISC HEADON-BOX MIXED
    .venv/bin/python tools/shape_scale_study.py --duration 20 --sim TS T90   # spheres

``--resolution WxH`` renders the scenarios' panorama at another size (e.g. 900x550).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import defaultdict
from collections.abc import Sequence

import cv2
import numpy as np

from tcm_companion.core.camera import Equirectangular
from tcm_companion.core.detection.base import angular_radius_from_solid_angle
from tcm_companion.core.detection.boxes import Box, BoxGeometry, image_axes_cam
from tcm_companion.core.frames import FloatArray, angle_between, cross3, normalize
from tcm_companion.core.ttc import robust_level_at
from tcm_companion.sim import make_scenario
from tcm_companion.sim.scene.detector_sim import simulate_detections
from tcm_companion.sim.scene.export import SimulatedScenario


# --------------------------------------------------------------------------------------
# Looming for any shape: the range ratio d0/d1 from two images of a non-spherical object
# (issue 14 §2; docs/decisions.md §9 measures them). For a sphere sin α1 / sin α0 is exact;
# for a box, a cylinder or a person the size seen also changes with the viewpoint, which
# the translation turns about the epipolar plane's normal n = b × T̂. An object's extent
# along n does not change under that turn (the projection of a solid onto an axis normal
# to the line of sight is its extent along that axis, whatever the viewpoint), so it
# scales exactly as 1/d for a stationary object.
# --------------------------------------------------------------------------------------
def epipolar_normal(t_hat_ned: FloatArray, b_ned: FloatArray) -> FloatArray:
    """Unit normal ``b × T̂`` of the epipolar plane through bearing ``b_ned`` (NaN when
    ``b_ned`` lies on the translation axis). Frames: both in the same world-aligned frame."""
    n = np.asarray(cross3(np.asarray(b_ned, np.float64), np.asarray(t_hat_ned, np.float64)))
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def box_mean_extent_rad(theta_w_rad: float, theta_h_rad: float) -> float:
    """Estimator (c): the box's geometric-mean extent ``√(θw·θh)`` (rad), what the boxes
    backend reports as twice its angular radius."""
    return math.sqrt(theta_w_rad * theta_h_rad)


def box_extent_across_rad(
    theta_w_rad: float,
    theta_h_rad: float,
    u_axis: FloatArray,
    v_axis: FloatArray,
    normal: FloatArray,
) -> float:
    """Estimator (b): the extent (rad) of an image-aligned box along ``normal``, the image
    direction perpendicular to the translation (:func:`epipolar_normal`).

    ``theta_w_rad``, ``theta_h_rad``: the angles across the box along the image's u and v
    axes; ``u_axis``, ``v_axis``: unit tangent directions of those axes at the box's centre
    and ``normal`` a unit vector, all three in one frame (e.g. NED). A box only knows its
    extents along u and v, so along a direction between them it gives the width of the
    rectangle's projection, ``θw |n·u| + θh |n·v|`` (exact along either axis).
    """
    nu = abs(float(np.dot(normal, u_axis)))
    nv = abs(float(np.dot(normal, v_axis)))
    return theta_w_rad * nu + theta_h_rad * nv


def extent_ratio(extent0_rad: float, extent1_rad: float) -> float:
    """``d0/d1`` from an extent measured at both observations, ``sin(e1/2) / sin(e0/2)``
    (for a sphere's diameter exactly ``sin α1 / sin α0``)."""
    return math.sin(0.5 * extent1_rad) / math.sin(0.5 * extent0_rad)


def feature_scale_ratio(
    b0_ned: FloatArray,
    b1_ned: FloatArray,
    normal_ned: FloatArray | None = None,
    min_separation_rad: float = 0.0,
) -> float:
    """Estimator (a): ``d0/d1`` from N points tracked on the object between the two
    observations: the median over pairs of points of the ratio of their separations,
    later over earlier (the scale change; robust to a few bad tracks).

    ``b0_ned``, ``b1_ned``: (N, 3) unit bearings of the same points at the two
    observations, in one world-aligned frame (for plain separations any frame per
    observation will do: angles between bearings do not depend on it). With
    ``normal_ned`` (the epipolar normal, :func:`epipolar_normal`), only the separations'
    components along it are compared (invariant to the viewpoint's turn). Pairs closer
    than ``min_separation_rad`` in the earlier image are ignored (their ratio is noise).
    NaN with no usable pair.
    """
    p0 = np.asarray(b0_ned, np.float64).reshape(-1, 3)
    p1 = np.asarray(b1_ned, np.float64).reshape(-1, 3)
    if len(p0) < 2 or len(p0) != len(p1):
        return math.nan
    i, j = np.triu_indices(len(p0), k=1)
    if normal_ned is None:
        s0 = angle_between(p0[i], p0[j])
        s1 = angle_between(p1[i], p1[j])
    else:
        n = np.asarray(normal_ned, np.float64)
        s0 = np.abs((p0[i] - p0[j]) @ n)
        s1 = np.abs((p1[i] - p1[j]) @ n)
    keep = (s0 > max(min_separation_rad, 1e-12)) & np.isfinite(s0) & np.isfinite(s1)
    if not np.any(keep):
        return math.nan
    return float(np.median(s1[keep] / s0[keep]))


TRUTH_ESTIMATORS = ("a", "a⊥", "b", "c", "diag", "w", "h", "area")
NOISY_ESTIMATORS = ("b", "c", "diag")
NOISY_MODES = ("single", "centred", "trailing")


def scenario(
    name: str, duration_s: float | None, seed: int, resolution: str | None
) -> SimulatedScenario:
    """``make_scenario`` (a collision course keeps its own, shorter duration)."""
    sim = make_scenario(name, duration_s=duration_s, seed=seed, shorter_ok=True)
    if resolution:
        w, h = (int(x) for x in resolution.lower().split("x"))
        cam = sim.camera
        assert isinstance(cam, Equirectangular), "--resolution needs a panorama scenario"
        sim = sim.with_camera(cam.scaled(w, h))
    return sim


def _R_ned_from_cam(sim: SimulatedScenario, k: int) -> tuple[np.ndarray, np.ndarray]:
    pos, R = sim.vehicle_pose(k)
    return np.asarray(pos, np.float64), np.asarray(R, np.float64) @ sim.camera.R_body_from_cam


def _box_terms(
    geometry: BoxGeometry, box: tuple[float, float, float, float], R: np.ndarray, t_hat: np.ndarray
) -> tuple[float, float, float, float, float] | None:
    """(c, b, diag, w, h) extents (rad) of a pixel box, ``b`` across ``t_hat`` (NED)."""
    ext = geometry.extents(Box(*box))
    if ext is None:
        return None
    u_ax, v_ax = image_axes_cam(geometry.camera, ext.cx, ext.cy)
    b_ned = R @ ext.centre_cam
    n = epipolar_normal(t_hat, b_ned)
    across = box_extent_across_rad(ext.theta_w_rad, ext.theta_h_rad, R @ u_ax, R @ v_ax, n)
    tw, th = ext.theta_w_rad, ext.theta_h_rad
    return box_mean_extent_rad(tw, th), across, math.hypot(tw, th), tw, th


def _features(
    sim: SimulatedScenario,
    gray: dict[int, np.ndarray],
    k0: int,
    k1: int,
    box0: tuple[float, float, float, float],
    shift_px: np.ndarray,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Bearings (camera FRD) of points inside ``box0`` at ``k0`` and where LK finds
    them at ``k1``."""
    for k in (k0, k1):
        if k not in gray:
            gray[k] = cv2.cvtColor(sim.read_frame(k), cv2.COLOR_BGR2GRAY)
    g0, g1 = gray[k0], gray[k1]
    h, w = g0.shape
    x0, y0, x1, y1 = box0
    if x1 < x0:  # across a panorama's seam: not handled here
        return None
    mask = np.zeros_like(g0)
    mask[
        max(int(y0) - 1, 0) : min(math.ceil(y1) + 1, h),
        max(int(x0) - 1, 0) : min(math.ceil(x1) + 1, w),
    ] = 255
    p0 = cv2.goodFeaturesToTrack(
        g0, maxCorners=60, qualityLevel=0.01, minDistance=2, mask=mask, blockSize=3
    )
    if p0 is None or len(p0) < 3:
        return None
    p0 = p0.astype(np.float32).reshape(-1, 1, 2)
    guess = (p0 + shift_px.astype(np.float32).reshape(1, 1, 2)).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)

    def lk(a: np.ndarray, b: np.ndarray, pts: np.ndarray, start: np.ndarray) -> tuple:
        return cv2.calcOpticalFlowPyrLK(
            a, b, pts, start.copy(), winSize=(9, 9), maxLevel=2, criteria=crit,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )  # fmt: skip

    p1, st, _ = lk(g0, g1, p0, guess)
    back, st2, _ = lk(g1, g0, p1, p0)
    ok = (
        (st.ravel() == 1)
        & (st2.ravel() == 1)
        & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < 0.5)
    )
    if ok.sum() < 3:
        return None
    cam = sim.camera
    b0 = np.asarray(cam.bearing_cam_from_pixel(p0.reshape(-1, 2)[ok].astype(np.float64)))
    b1 = np.asarray(cam.bearing_cam_from_pixel(p1.reshape(-1, 2)[ok].astype(np.float64)))
    good = np.all(np.isfinite(b0), axis=1) & np.all(np.isfinite(b1), axis=1)
    return b0[good], b1[good]


def _area_radius(sim: SimulatedScenario, obj_index: int, k: int) -> float:
    obj = sim.plan.objects[obj_index]
    pos, R = sim.vehicle_pose(k)
    cov = sim.renderer.object_coverage(obj, float(sim.frame_times_s[k]), pos, R)
    solid = float(np.sum(cov * sim.camera.solid_angle_map_sr))
    return angular_radius_from_solid_angle(solid) if solid > 0 else math.nan


def _level(
    geometry: BoxGeometry,
    boxes: dict[int, tuple[float, float, float, float]],
    poses: Sequence[tuple[np.ndarray, np.ndarray]],
    times: np.ndarray,
    t_hat: np.ndarray,
    frames: Sequence[int],
    t_eval_s: float,
    j: int,
) -> float:
    """``ln sin(e/2)`` of box extent ``j`` (of :func:`_box_terms`) fitted over the
    detected ``frames`` at ``t_eval_s``."""
    ts, ys = [], []
    for k in frames:
        if k in boxes and 0 <= k < len(poses):
            terms = _box_terms(geometry, boxes[k], poses[k][1], t_hat)
            if terms is not None:
                ts.append(times[k])
                ys.append(math.log(math.sin(0.5 * terms[j])))
    return robust_level_at(np.array(ts), np.array(ys), t_eval_s)


def study(
    sim: SimulatedScenario, interval_s: float, stride: int, window_s: float, features: bool
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Errors ``R_est - R_true`` per estimator: exact geometry, and detector-noise
    (keys ``"b single"``, ``"c centred"``, ...)."""
    times = np.asarray(sim.frame_times_s, np.float64)
    period = float(np.median(np.diff(times)))
    K = max(1, round(interval_s / period))
    half = max(1, round(0.5 * window_s / period))
    n = sim.n_frames
    views = [sim.object_views(k) for k in range(n)]
    poses = [_R_ned_from_cam(sim, k) for k in range(n)]
    geometry = BoxGeometry(sim.camera, "mean")
    truth_err: dict[str, list[float]] = defaultdict(list)
    noisy_err: dict[str, list[float]] = defaultdict(list)
    gray: dict[int, np.ndarray] = {}
    dets = simulate_detections(sim)
    noisy: dict[int, dict[int, tuple[float, float, float, float]]] = defaultdict(dict)
    for d in dets:
        if d.object_id > 0 and d.image_frame == d.frame:
            noisy[d.object_id][d.frame] = (d.x_min, d.y_min, d.x_max, d.y_max)
    for k0 in range(0, n - K, stride):
        k1 = k0 + K
        (pos0, R0), (pos1, R1) = poses[k0], poses[k1]
        t_vec = pos1 - pos0
        if np.linalg.norm(t_vec) < 0.05:
            continue
        t_hat = np.asarray(normalize(t_vec))
        for i, obj in enumerate(sim.plan.objects):
            v0, v1 = views[k0][i], views[k1][i]
            if v0.box_px is None or v1.box_px is None:
                continue
            r_true = v0.range_m / v1.range_m
            b0c = np.asarray(normalize(v0.centre_ned_m - pos0))
            b1c = np.asarray(normalize(v1.centre_ned_m - pos1))
            th0 = math.atan2(np.linalg.norm(np.cross(t_hat, b0c)), float(t_hat @ b0c))
            if not (math.radians(10) < th0 < math.radians(170)):
                continue  # head-on: TCM does not decide
            terms0 = _box_terms(geometry, v0.box_px, R0, t_hat)
            terms1 = _box_terms(geometry, v1.box_px, R1, t_hat)
            if terms0 is None or terms1 is None:
                continue
            c0, b0, g0, w0, h0 = terms0
            c1, b1, g1, w1, h1 = terms1
            for key, e0, e1 in (
                ("c", c0, c1),
                ("b", b0, b1),
                ("diag", g0, g1),
                ("w", w0, w1),
                ("h", h0, h1),
            ):
                truth_err[key].append(extent_ratio(e0, e1) - r_true)
            if obj.shape == "sphere":
                truth_err["area"].append(
                    math.sin(math.asin(min(1.0, v1.bounding_radius_m / v1.range_m)))
                    / math.sin(math.asin(min(1.0, v0.bounding_radius_m / v0.range_m)))
                    - r_true
                )
            else:
                a0, a1 = _area_radius(sim, i, k0), _area_radius(sim, i, k1)
                if a0 > 0 and a1 > 0:
                    truth_err["area"].append(math.sin(a1) / math.sin(a0) - r_true)
            if features:
                shift = np.asarray(v1.centre_px, np.float64) - np.asarray(v0.centre_px, np.float64)
                if np.all(np.isfinite(shift)):
                    if abs(shift[0]) > sim.camera.width / 2:
                        shift[0] -= math.copysign(sim.camera.width, shift[0])
                    got = _features(sim, gray, k0, k1, v0.box_px, shift)
                    if got is not None:
                        f0, f1 = got
                        f0n, f1n = f0 @ R0.T, f1 @ R1.T
                        nn = np.asarray(
                            normalize(epipolar_normal(t_hat, b0c) + epipolar_normal(t_hat, b1c))
                        )
                        ra = feature_scale_ratio(
                            f0n,
                            f1n,
                            min_separation_rad=2 * math.radians(1.0) * 360 / sim.camera.width,
                        )
                        rp = feature_scale_ratio(
                            f0n,
                            f1n,
                            nn,
                            min_separation_rad=2 * math.radians(1.0) * 360 / sim.camera.width,
                        )
                        if math.isfinite(ra):
                            truth_err["a"].append(ra - r_true)
                        if math.isfinite(rp):
                            truth_err["a⊥"].append(rp - r_true)
            # The detector simulator's boxes.
            boxes = noisy.get(obj.object_id, {})
            if k0 not in boxes or k1 not in boxes:
                continue
            s0 = _box_terms(geometry, boxes[k0], R0, t_hat)
            s1 = _box_terms(geometry, boxes[k1], R1, t_hat)
            if s0 is None or s1 is None:
                continue
            for j, key in ((1, "b"), (0, "c"), (2, "diag")):
                noisy_err[f"{key} single"].append(extent_ratio(s0[j], s1[j]) - r_true)

            cen0 = range(k0 - half, k0 + half + 1)
            cen1 = range(k1 - half, k1 + half + 1)
            trail1 = range(k1 - 2 * half, k1 + 1)
            for j, key in ((1, "b"), (0, "c"), (2, "diag")):
                l0 = _level(geometry, boxes, poses, times, t_hat, cen0, times[k0], j)
                lc = _level(geometry, boxes, poses, times, t_hat, cen1, times[k1], j)
                lt = _level(geometry, boxes, poses, times, t_hat, trail1, times[k1], j)
                noisy_err[f"{key} centred"].append(math.exp(lc - l0) - r_true)
                noisy_err[f"{key} trailing"].append(math.exp(lt - l0) - r_true)
    return truth_err, noisy_err


def _stats(err: Sequence[float]) -> str:
    e = np.asarray([x for x in err if math.isfinite(x)], np.float64)
    if not len(e):
        return "—"
    a = np.abs(e)
    return f"{np.median(a):.3f} / {np.percentile(a, 90):.3f} / {np.median(e):+.3f}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sim", nargs="+", required=True, metavar="NAME")
    p.add_argument("--duration", type=float, default=None, help="s (collision flights keep theirs)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--interval-s", type=float, default=1.0, help="time between the two frames (s)")
    p.add_argument("--stride", type=int, default=10, help="frames between pairs")
    p.add_argument(
        "--window-s", type=float, default=0.48, help="fit window for the noisy boxes (s)"
    )
    p.add_argument("--no-features", action="store_true", help="skip estimator a (renders frames)")
    p.add_argument(
        "--resolution", default=None, help="WxH of the panorama (default: the scenario's)"
    )
    args = p.parse_args(argv)
    print(
        f"R_est - R_true over pairs {args.interval_s:g} s apart, every {args.stride} frames; seed "
        f"{args.seed}; |err| median / p90 / signed median; noisy fit window {args.window_s:g} s"
    )
    truth_cols = list(TRUTH_ESTIMATORS)
    noisy_cols = [f"{k} {m}" for k in NOISY_ESTIMATORS for m in NOISY_MODES]
    by_shape: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    rows: list[tuple[str, str, dict[str, list[float]]]] = []
    for name in args.sim:
        t0 = time.monotonic()
        sim = scenario(name, args.duration, args.seed, args.resolution)
        truth_err, noisy_err = study(
            sim, args.interval_s, args.stride, args.window_s, not args.no_features
        )
        shapes = "+".join(sorted({o.shape for o in sim.plan.objects}))
        merged = {**truth_err, **noisy_err}
        for key, errs in merged.items():
            by_shape[shapes][key].extend(errs)
        rows.append((name, shapes, merged))
        print(
            f"{name}: {len(truth_err['c'])} pairs, {time.monotonic() - t0:.0f} s",
            file=sys.stderr,
            flush=True,
        )
    for title, cols in (("exact geometry", truth_cols), ("detector simulator's boxes", noisy_cols)):
        print(f"\n{title}\n")
        print("| scenario | shape | pairs | " + " | ".join(cols) + " |")
        print("|---|---|---|" + "---|" * len(cols))
        for name, shapes, merged in rows:
            n = (
                len(merged.get(cols[0], []))
                if title != "exact geometry"
                else len(merged.get("c", []))
            )
            print(
                f"| {name} | {shapes} | {n} | "
                + " | ".join(_stats(merged.get(c, [])) for c in cols)
                + " |"
            )
        print("\n| shape (pooled) | pairs | " + " | ".join(cols) + " |")
        print("|---|---|" + "---|" * len(cols))
        for shape, merged in sorted(by_shape.items()):
            n = (
                len(merged.get(cols[0], []))
                if title != "exact geometry"
                else len(merged.get("c", []))
            )
            print(
                f"| {shape} | {n} | " + " | ".join(_stats(merged.get(c, [])) for c in cols) + " |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
