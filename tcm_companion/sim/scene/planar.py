"""Per-pixel data held planar, ``(channels, pixels)``, for the renderer: gathers and
scatters along the last axis (several times faster than row gathers in numpy), masked
copies and blends, and bilinear texture sampling with ``cv2.remap`` over flat pixel
lists."""

from __future__ import annotations

import cv2
import numpy as np

REMAP_COLS = 1024  # cv2.remap wants both map dimensions below SHRT_MAX


def remap_flat(src: np.ndarray, x: np.ndarray, y: np.ndarray, border: int) -> np.ndarray:
    """Bilinear samples of ``src`` at (x, y) (OpenCV pixel-centre coordinates), shape (N, C)."""
    n = x.shape[0]
    channels = src.shape[2] if src.ndim == 3 else 1
    if n == 0:
        return np.zeros((0, channels), src.dtype)
    rows = -(-n // REMAP_COLS)
    pad = rows * REMAP_COLS - n
    if pad:
        x = np.concatenate([x, np.zeros(pad, np.float32)])
        y = np.concatenate([y, np.zeros(pad, np.float32)])
    out = cv2.remap(
        src,
        x.reshape(rows, REMAP_COLS),
        y.reshape(rows, REMAP_COLS),
        cv2.INTER_LINEAR,
        borderMode=border,
    )
    return out.reshape(rows * REMAP_COLS, channels)[:n]


class RemapMaps:
    """Reusable float32 ``cv2.remap`` maps for a flat list of points.

    ``x, y = maps.coords(n)`` are views the caller writes the points' coordinates into
    (in place, so no padding copy); ``maps.sample(src, border)`` then returns the
    bilinear samples (n, C) of those points. The maps' tail past ``n`` holds stale but
    finite coordinates whose samples are dropped. Each remapped point depends on its own
    coordinates only, so the samples equal :func:`remap_flat`'s.
    """

    def __init__(self) -> None:
        self._x = np.zeros(REMAP_COLS, np.float32)
        self._y = np.zeros(REMAP_COLS, np.float32)
        self._n = 0

    def coords(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        size = max(-(-n // REMAP_COLS), 1) * REMAP_COLS
        if self._x.size < size:
            self._x = np.zeros(size, np.float32)
            self._y = np.zeros(size, np.float32)
        self._n = n
        return self._x[:n], self._y[:n]

    def sample(self, src: np.ndarray, border: int) -> np.ndarray:
        n = self._n
        channels = src.shape[2] if src.ndim == 3 else 1
        if n == 0:
            return np.zeros((0, channels), src.dtype)
        rows = -(-n // REMAP_COLS)
        size = rows * REMAP_COLS
        out = cv2.remap(
            src,
            self._x[:size].reshape(rows, REMAP_COLS),
            self._y[:size].reshape(rows, REMAP_COLS),
            cv2.INTER_LINEAR,
            borderMode=border,
        )
        return out.reshape(size, channels)[:n]


def planes_f32(samples: np.ndarray) -> np.ndarray:
    """(n, C) uint8 samples as (C, n) float32 planes, C-contiguous (the values exactly):
    ``cv2.transpose`` of the bytes, then one conversion (cv2.split and C conversions
    cost several times more)."""
    if samples.shape[1] == 1:
        return samples[:, 0].astype(np.float32)[None, :]
    return cv2.transpose(samples).astype(np.float32)


def span(mask: np.ndarray) -> tuple[int, int]:
    """``(first, last + 1)`` of the True entries of a 1-D bool array, (0, 0) if none."""
    i0 = int(mask.argmax())
    if not mask[i0]:
        return 0, 0
    return i0, mask.shape[0] - int(mask[::-1].argmax())


def copy_where(dst: np.ndarray, src: np.ndarray, mask: np.ndarray) -> None:
    """``dst[..., mask] = src[..., mask]`` for planar rows; the part of the span past the
    mask's last False entry is copied whole (the ground below the horizon band)."""
    rest = mask[::-1].argmin()
    j = mask.shape[0] - int(rest) if not mask[-1 - int(rest)] else 0
    if j:
        if dst.ndim == 1:
            np.putmask(dst[:j], mask[:j], src[:j])
        else:
            for c in range(dst.shape[0]):
                np.putmask(dst[c, :j], mask[:j], src[c, :j])
    dst[..., j:] = src[..., j:]


def apply_shades(
    lit: np.ndarray,
    ball_shades: list[tuple[np.ndarray, np.ndarray]],
    target_shades: list[tuple[np.ndarray, np.ndarray]],
) -> None:
    """``lit *= sunlit``, sunlit the balls' sunlit fractions multiplied in order (from 1),
    times the targets' likewise: over the span of the shaded points only (elsewhere the
    factor is exactly 1)."""
    locs = [loc for loc, _ in ball_shades + target_shades]
    lo = min(int(loc[0]) for loc in locs)
    hi = max(int(loc[-1]) for loc in locs) + 1
    products = []
    for shades in (ball_shades, target_shades):
        if shades:
            sunlit = np.ones(hi - lo, np.float32)
            for loc, frac in shades:
                sunlit[loc - lo] *= frac
            products.append(sunlit)
    if len(products) == 2:
        products[0] *= products[1]
    lit[lo:hi] *= products[0]


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) * (1.0 / (e1 - e0)), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# Per-pixel data is planar, (channels, pixels): numpy gathers and scatters along the last
# axis of such arrays are several times faster than row gathers of (pixels, channels).
def take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    return a.take(idx, axis=-1)  # the method: np.take's Python wrapper costs as much


def take_all(idx: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`take` of several arrays at the same indices."""
    return tuple(take(a, idx) for a in arrays)


def put(dst: np.ndarray, idx: np.ndarray, values: np.ndarray) -> None:
    for c in range(dst.shape[0]):
        dst[c, idx] = values[c]
