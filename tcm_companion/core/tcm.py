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
