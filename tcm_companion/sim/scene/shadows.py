"""Cast shadows on the ground for the renderer: the sunlit fraction of ground points
under each kind of caster (spheres, cylinders, boxes; soft edges from the sun's size),
the static clutter's shadows baked once into the macro ground texture, and the outline
hull a solid target's shadow is cast from."""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from ...core.frames import FloatArray
from .world import Box, BoxTarget, Cylinder, Ground, SolidTarget, Sphere, Sun, Tree, ground_textures

SUN_PENUMBRA = 2.0 * math.tan(math.radians(0.27))  # penumbra width per metre of shadow ray


# --------------------------------------------------------------------------------------
# Shadow coverage at ground points (n, e): fraction of the sun hidden by one caster.
# ``foot`` is the ground footprint (m) used as the minimum edge width (anti-aliasing).
# --------------------------------------------------------------------------------------
def sphere_shadow(
    n: np.ndarray, e: np.ndarray, foot: np.ndarray, centre: FloatArray, radius: float, L: FloatArray
) -> np.ndarray:
    vn, ve, vd = centre[0] - n, centre[1] - e, float(centre[2])
    s = vn * L[0] + ve * L[1] + vd * L[2]  # along the ray towards the sun
    perp = np.sqrt(np.maximum(vn * vn + ve * ve + vd * vd - s * s, 0.0))
    width = np.maximum(np.maximum(foot, s * SUN_PENUMBRA), 1e-6)
    cov = np.clip((radius - perp) / width + 0.5, 0.0, 1.0)
    return np.where(s > 0, cov, 0.0)


def cylinder_shadow(
    n: np.ndarray, e: np.ndarray, foot: np.ndarray, c: Cylinder, L: FloatArray
) -> np.ndarray:
    lh2 = max(float(L[0] ** 2 + L[1] ** 2), 1e-12)
    dn, de = c.base_ne_m[0] - n, c.base_ne_m[1] - e
    s = (dn * L[0] + de * L[1]) / lh2
    perp = np.hypot(dn - s * L[0], de - s * L[1])
    rise = -s * L[2]  # height of the shadow ray where it passes the axis
    width = np.maximum(np.maximum(foot, s * SUN_PENUMBRA), 1e-6)
    cov = np.clip((c.radius_m - perp) / width + 0.5, 0.0, 1.0)
    return np.where((s > 0) & (rise <= c.height_m), cov, 0.0)


def box_shadow(n: np.ndarray, e: np.ndarray, box: Box, L: FloatArray) -> np.ndarray:
    lo, hi = np.asarray(box.min_ned_m)[:, None], np.asarray(box.max_ned_m)[:, None]
    o = np.stack([n, e, np.full_like(n, -1e-3)])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = (1.0 / L)[:, None]
        t1 = (lo - o) * inv
        t2 = (hi - o) * inv
    tnear = np.fmin(t1, t2).max(axis=0)
    tfar = np.fmax(t1, t2).min(axis=0)
    return ((tfar >= np.maximum(tnear, 0.0)) & (tfar > 0)).astype(np.float64)


def footprint(centre: FloatArray, radius: float, L: FloatArray) -> tuple[FloatArray, float]:
    """Ground circle holding the shadow of a bounding sphere (projected along the sun)."""
    g = np.asarray(centre, np.float64) - (centre[2] / L[2]) * L
    return g, radius / max(-float(L[2]), 0.05) + 0.05


@lru_cache(maxsize=4)
def lit_macro(
    ground: Ground,
    sun: Sun,
    trees: tuple[Tree, ...],
    posts: tuple[Cylinder, ...],
    buildings: tuple[Box, ...],
) -> tuple[np.ndarray, np.ndarray]:
    """Macro texture levels with the static clutter's shadows baked into channel 3.

    The clutter does not move, so neither do its shadows: channel 3 holds the sunlit
    fraction (× 255) of each texel, and only the balls' shadows are cast per frame.
    """
    tex = ground_textures(ground)
    m0 = tex.macro_levels[0]
    h, w = m0.shape[:2]
    texel = tex.macro_texels_m[0]
    on, oe = tex.macro_origin_ne_m
    L = sun.direction_ned
    lit = np.ones((h, w), np.float64)

    def window(
        centre: FloatArray, radius: float
    ) -> tuple[slice, slice, np.ndarray, np.ndarray] | None:
        g, rg = footprint(centre, radius, L)
        x0, x1 = int((g[1] - rg - oe) / texel), int((g[1] + rg - oe) / texel) + 2
        y0, y1 = int((on - g[0] - rg) / texel), int((on - g[0] + rg) / texel) + 2
        x0, x1, y0, y1 = max(x0, 0), min(x1, w), max(y0, 0), min(y1, h)
        if x0 >= x1 or y0 >= y1:
            return None
        ee = oe + (np.arange(x0, x1) + 0.5) * texel
        nn = on - (np.arange(y0, y1) + 0.5) * texel
        n_grid, e_grid = np.meshgrid(nn, ee, indexing="ij")
        return slice(y0, y1), slice(x0, x1), n_grid, e_grid

    foot = texel
    for tree in trees:
        casters: list[tuple[str, object]] = [("cyl", tree.trunk)] + [
            ("sph", s) for s in tree.canopy
        ]
        for kind, obj in casters:
            if kind == "cyl":
                assert isinstance(obj, Cylinder)
                centre = np.array([obj.base_ne_m[0], obj.base_ne_m[1], -obj.height_m / 2.0])
                win = window(centre, math.hypot(obj.radius_m, obj.height_m / 2.0))
                if win is not None:
                    ys, xs, nn, ee = win
                    lit[ys, xs] *= 1.0 - cylinder_shadow(nn, ee, np.full_like(nn, foot), obj, L)
            else:
                assert isinstance(obj, Sphere)
                c = np.asarray(obj.centre_ned_m, np.float64)
                win = window(c, obj.radius_m)
                if win is not None:
                    ys, xs, nn, ee = win
                    lit[ys, xs] *= 1.0 - sphere_shadow(
                        nn, ee, np.full_like(nn, foot), c, obj.radius_m, L
                    )
    for post in posts:
        centre = np.array([post.base_ne_m[0], post.base_ne_m[1], -post.height_m / 2.0])
        win = window(centre, math.hypot(post.radius_m, post.height_m / 2.0))
        if win is not None:
            ys, xs, nn, ee = win
            lit[ys, xs] *= 1.0 - cylinder_shadow(nn, ee, np.full_like(nn, foot), post, L)
    for box in buildings:
        lo, hi = np.asarray(box.min_ned_m), np.asarray(box.max_ned_m)
        win = window((lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0))
        if win is not None:
            ys, xs, nn, ee = win
            lit[ys, xs] *= 1.0 - box_shadow(nn.ravel(), ee.ravel(), box, L).reshape(nn.shape)
    level0 = np.dstack([m0, np.clip(lit * 255.0 + 0.5, 0, 255).astype(np.uint8)])
    blurred = cv2.GaussianBlur(level0, (0, 0), 1.6)
    f = round(tex.macro_texels_m[1] / texel)
    level1 = cv2.resize(blurred, (w // f, h // f), interpolation=cv2.INTER_AREA)
    return level0, level1


def outline_points_ned(
    target: SolidTarget, centre_ned_m: FloatArray, R_ned_from_obj: FloatArray
) -> FloatArray:
    """(K, 3) points whose convex hull is the target (box corners, or the two rims)."""
    if isinstance(target, BoxTarget):
        hx, hy, hz = target.half_extent_m
        pts = np.array(
            [[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        )
    else:
        phi = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
        rim = np.stack([target.radius_m * np.cos(phi), target.radius_m * np.sin(phi)], axis=1)
        hh = target.height_m / 2.0
        pts = np.concatenate(
            [
                np.column_stack([rim, np.full(len(phi), -hh)]),
                np.column_stack([rim, np.full(len(phi), hh)]),
            ]
        )
    return np.asarray(centre_ned_m, np.float64) + pts @ np.asarray(R_ned_from_obj).T


def convex_hull_2d(points: FloatArray) -> FloatArray:
    """Convex hull (H, 2) of 2-D points, counter-clockwise in (x, y) (Andrew's chain)."""
    pts = np.unique(np.round(np.asarray(points, np.float64), 9), axis=0).astype(np.float64)
    if len(pts) < 3:
        return pts

    def cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    lower: list[np.ndarray] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list[np.ndarray] = []
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=np.float64)
