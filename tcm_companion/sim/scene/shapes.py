"""Ray intersection and silhouettes of the non-spherical targets (box, upright cylinder, disc).

Pure, vectorised geometry shared by the renderer (which draws and shadows the targets
with it) and by the truth helpers (which project the targets' silhouettes into the image).

Rays are ``origin + t · direction`` with directions as (3, M) arrays, origins (3,) or
(3, M); everything is in the target's own frame ("obj": x forward, y right, z down,
origin at the target's centre) unless a name says ``_ned``. The intersections return
the entry and exit parameters ``(t_near, t_far)`` of the ray's segment inside the solid
(``t_near > t_far`` where the ray misses) and the outward surface normal at the entry.
With unit directions ``t`` is the range in metres.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.frames import FloatArray
from .world import Ball, BoxTarget, SolidTarget, Target

_BIG = 1e30


def _slab(o: np.ndarray, d: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit of rays ``o + t d`` (one axis) through the slab ``|x| <= half``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    lo = np.fmin(t1, t2)
    hi = np.fmax(t1, t2)
    parallel = d == 0.0
    if np.any(parallel):
        inside = np.abs(o) <= half
        lo = np.where(parallel, np.where(inside, -_BIG, _BIG), lo)
        hi = np.where(parallel, np.where(inside, _BIG, -_BIG), hi)
    return lo, hi


def ray_box_obj(
    origin_obj: np.ndarray, dir_obj: np.ndarray, half_extent_m: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays against the box ``|x| <= hx, |y| <= hy, |z| <= hz`` (slab method)."""
    o = np.asarray(origin_obj, np.float64).reshape(3, -1)
    d = np.asarray(dir_obj, np.float64)
    los, his = [], []
    for k in range(3):
        lo, hi = _slab(o[k], d[k], half_extent_m[k])
        los.append(np.broadcast_to(lo, d.shape[1:]))
        his.append(np.broadcast_to(hi, d.shape[1:]))
    lo3 = np.stack(los)
    t_near = lo3.max(axis=0)
    t_far = np.stack(his).min(axis=0)
    axis = lo3.argmax(axis=0)
    cols = np.arange(d.shape[1])
    normal = np.zeros_like(d)
    normal[axis, cols] = -np.sign(d[axis, cols])
    return t_near, t_far, normal


def ray_cylinder_obj(
    origin_obj: np.ndarray, dir_obj: np.ndarray, radius_m: float, half_height_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays against the capped cylinder ``x² + y² <= r², |z| <= h/2`` (axis = obj z)."""
    o = np.asarray(origin_obj, np.float64).reshape(3, -1)
    d = np.asarray(dir_obj, np.float64)
    a = d[0] * d[0] + d[1] * d[1]
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] * o[0] + o[1] * o[1] - radius_m * radius_m
    disc = b * b - a * c
    vertical = a < 1e-18
    safe_a = np.where(vertical, 1.0, a)
    root = np.sqrt(np.maximum(disc, 0.0))
    r_lo = np.where(vertical, np.where(c <= 0, -_BIG, _BIG), (-b - root) / safe_a)
    r_hi = np.where(vertical, np.where(c <= 0, _BIG, -_BIG), (-b + root) / safe_a)
    miss = (~vertical) & (disc < 0)
    r_lo = np.where(miss, _BIG, r_lo)
    r_hi = np.where(miss, -_BIG, r_hi)
    z_lo, z_hi = _slab(o[2], d[2], half_height_m)
    z_lo = np.broadcast_to(z_lo, r_lo.shape)
    t_near = np.maximum(r_lo, z_lo)
    t_far = np.minimum(r_hi, z_hi)
    side = r_lo >= z_lo
    px = o[0] + t_near * d[0]
    py = o[1] + t_near * d[1]
    norm = np.maximum(np.hypot(px, py), 1e-12)
    normal = np.stack(
        [
            np.where(side, px / norm, 0.0),
            np.where(side, py / norm, 0.0),
            np.where(side, 0.0, -np.sign(d[2])),
        ]
    )
    return t_near, t_far, normal


def ray_target_ned(
    target: SolidTarget,
    centre_ned_m: FloatArray,
    R_ned_from_obj: FloatArray,
    origin_ned_m: np.ndarray,
    dir_ned: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays (NED) against a target posed at ``centre_ned_m``, ``R_ned_from_obj``.

    Returns ``(t_near, t_far, normal_ned)``; the normal is the outward one at the entry.
    """
    R = np.asarray(R_ned_from_obj, np.float64)
    c = np.asarray(centre_ned_m, np.float64).reshape(3, 1)
    o_obj = R.T @ (np.asarray(origin_ned_m, np.float64).reshape(3, -1) - c)
    d_obj = R.T @ np.asarray(dir_ned, np.float64)
    if isinstance(target, BoxTarget):
        t_near, t_far, n_obj = ray_box_obj(o_obj, d_obj, target.half_extent_m)
    else:
        t_near, t_far, n_obj = ray_cylinder_obj(
            o_obj, d_obj, target.radius_m, target.height_m / 2.0
        )
    return t_near, t_far, R @ n_obj


# --------------------------------------------------------------------------------------
# Silhouettes
# --------------------------------------------------------------------------------------
def silhouette_points_ned(
    target: Target,
    centre_ned_m: FloatArray,
    R_ned_from_obj: FloatArray,
    eye_ned_m: FloatArray,
    samples: int = 48,
) -> FloatArray:
    """Points (K, 3) on the target whose images bound its silhouette seen from ``eye``.

    A sphere: its circle of tangency from the eye. A box: its twelve edges (in a
    panorama straight edges image as curves, so they are sampled along their length).
    A cylinder or disc: its two rims and the two vertical lines where the eye's
    tangent planes touch the side. The image of the solid lies inside the images of
    these points (sampled ``samples`` times per circle, ``samples // 3`` per line).
    """
    c = np.asarray(centre_ned_m, np.float64).reshape(3)
    eye = np.asarray(eye_ned_m, np.float64).reshape(3)
    R = np.asarray(R_ned_from_obj, np.float64)
    phi = np.linspace(0.0, 2.0 * math.pi, samples, endpoint=False)
    line = np.linspace(0.0, 1.0, max(samples // 3, 2))
    if isinstance(target, Ball):
        r = target.bounding_radius_m
        v = c - eye
        d = float(np.linalg.norm(v))
        if d <= r:
            return np.empty((0, 3))
        u = v / d
        a = _perpendicular(u)
        b = np.cross(u, a)
        ring_c = c - (r * r / d) * u
        ring_r = r * math.sqrt(1.0 - (r / d) ** 2)
        return ring_c + ring_r * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)
    if isinstance(target, BoxTarget):
        hx, hy, hz = target.half_extent_m
        corners = np.array(
            [[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        )
        edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
        pts_obj = np.concatenate(
            [corners[i] + line[:, None] * (corners[j] - corners[i]) for i, j in edges]
        )
        return c + pts_obj @ R.T
    # Upright cylinder or disc (axis = obj z = NED down).
    radius, half_h = target.radius_m, target.height_m / 2.0
    rims = [
        np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full_like(phi, z)], axis=1)
        for z in (-half_h, half_h)
    ]
    eye_obj = R.T @ (eye - c)
    w = float(math.hypot(eye_obj[0], eye_obj[1]))
    sides = []
    if w > radius:
        base = math.atan2(eye_obj[1], eye_obj[0])
        for sgn in (-1.0, 1.0):
            ang = base + sgn * math.acos(radius / w)
            z = -half_h + line * 2.0 * half_h
            sides.append(
                np.stack(
                    [
                        np.full_like(z, radius * math.cos(ang)),
                        np.full_like(z, radius * math.sin(ang)),
                        z,
                    ],
                    axis=1,
                )
            )
    pts_obj = np.concatenate(rims + sides)
    return c + pts_obj @ R.T


def _perpendicular(u: FloatArray) -> FloatArray:
    """A unit vector perpendicular to unit ``u``."""
    k = int(np.argmin(np.abs(u)))
    e = np.zeros(3)
    e[k] = 1.0
    p = e - u * float(u @ e)
    return np.asarray(p / np.linalg.norm(p), np.float64)
