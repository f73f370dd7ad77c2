"""The Triangle Closure Method and the epipolar baseline as pure geometry.

All vectors are in one world-aligned frame (NED after derotation with attitude and
mount): ``t_hat_ned`` is the unit translation of the camera from frame 0 to frame 1,
``b0_ned``/``b1_ned`` the unit bearings of the object in the two frames and
``alpha0_rad``/``alpha1_rad`` its angular radii. Every function is vectorised over leading
axes and returns NaN for undefined geometry rather than raising.

TCM (method.md): for a stationary object the triangle camera-0, camera-1, object closes,
so the range ratio predicted by the sine rule, ``R_geo = sin θ1 / sin θ0``, equals the
ratio measured from looming, ``R_img = sin α1 / sin α0``; the disparity is
``δ = |R_img - R_geo|``. ECM: the angle Ω between the epipolar-plane normals
``T̂ × b0`` and ``T̂ × b1``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .frames import FloatArray, angle_between, cross3


@dataclass(frozen=True)
class TriangleGeometry:
    """Everything TCM computes for one pair of observations (arrays broadcast together)."""

    theta0_rad: FloatArray
    theta1_rad: FloatArray
    r_geo: FloatArray  # predicted d0/d1 if stationary
    r_img: FloatArray  # measured d0/d1 from looming
    disparity: FloatArray  # |r_img - r_geo|


def triangle_geometry(
    t_hat_ned: FloatArray,
    b0_ned: FloatArray,
    b1_ned: FloatArray,
    alpha0_rad: FloatArray | float,
    alpha1_rad: FloatArray | float,
) -> TriangleGeometry:
    """TCM disparity and its parts; ``θi`` via atan2 (stable near 0 and π)."""
    theta0 = angle_between(t_hat_ned, b0_ned)
    theta1 = angle_between(t_hat_ned, b1_ned)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_geo = np.sin(theta1) / np.sin(theta0)
        r_img = np.sin(np.asarray(alpha1_rad, dtype=np.float64)) / np.sin(
            np.asarray(alpha0_rad, dtype=np.float64)
        )
    return TriangleGeometry(theta0, theta1, r_geo, r_img, np.abs(r_img - r_geo))


def tcm_disparity(
    t_hat_ned: FloatArray,
    b0_ned: FloatArray,
    b1_ned: FloatArray,
    alpha0_rad: FloatArray | float,
    alpha1_rad: FloatArray | float,
) -> FloatArray:
    """``δ = |sin α1 / sin α0 - sin θ1 / sin θ0|`` (dimensionless)."""
    return triangle_geometry(t_hat_ned, b0_ned, b1_ned, alpha0_rad, alpha1_rad).disparity


def ecm_omega_rad(t_hat_ned: FloatArray, b0_ned: FloatArray, b1_ned: FloatArray) -> FloatArray:
    """ECM angle between epipolar-plane normals, ``arccos(|n0·n1| / (|n0||n1|))`` in [0, π/2]."""
    n0 = cross3(t_hat_ned, b0_ned)
    n1 = cross3(t_hat_ned, b1_ned)
    ang = angle_between(n0, n1)
    # |n0·n1|: a plane normal has no sign, so Ω folds into [0, π/2].
    return np.minimum(ang, np.pi - ang)


def stationary_range_m(
    t_ned_m: FloatArray, b0_ned: FloatArray, b1_ned: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Ranges ``(d0, d1)`` to a stationary object from a metric translation (sine rule).

    ``d0 = |T| sin θ1 / sin(θ1 - θ0)``, ``d1 = |T| sin θ0 / sin(θ1 - θ0)``; NaN when the
    bearings barely change (no parallax).
    """
    t = np.asarray(t_ned_m, dtype=np.float64)
    mag = np.linalg.norm(t, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_hat = t / mag[..., None]
        th0 = angle_between(t_hat, b0_ned)
        th1 = angle_between(t_hat, b1_ned)
        s = np.sin(th1 - th0)
        s = np.where(np.abs(s) > 1e-9, s, np.nan)
        return mag * np.sin(th1) / s, mag * np.sin(th0) / s


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
