"""Red-ball detector: every saturated-red blob's bearing and angular radius, sub-pixel.

The Triangle Closure Method compares an object's *angular* size between two frames a
second apart, so what this module must get right is the ratio of radii, to a small
fraction of a pixel, on any of the scenario format's camera models. The paper segments
by colour and grows regions from seeds; here that is:

1. **Candidates** — a cheap full-frame test that every seed passes (red channel well
   above green and blue); a coarse grid of candidate cells gives regions of interest,
   so that everything after this step runs on small crops only.
2. **Seeds and growth (hysteresis)** — in each region, HSV seeds of strong, saturated
   red (the lit side) and connected components of a weaker red (the dark shaded side);
   a component is kept only if it holds seeds. Notches and holes (a specular highlight)
   are filled. On a 360° panorama regions are taken modulo the width, so a blob across
   the left and right edges is one object.
3. **Measurement through the camera model** — pixels within a couple of pixels of the
   blob's edge get a fractional membership by unmixing their colour into the local ball
   colour (just inside) and the local background colour (just outside); the band is
   re-centred once on the measured edge if the growth stopped short of it. The blob's
   solid angle is the membership-weighted sum of per-pixel solid angles, its bearing the
   normalised weighted sum of pixel-centre bearings. A sphere's image is a spherical
   cap, so ``Ω = 2π(1 - cos α)`` gives its angular radius exactly, on any lens, off
   axis or not.

Known limits: a specular highlight *on the limb* reads as background (a few tenths of
a pixel of radius); a reddish-brown patch (hue ≈ 12°, S ≈ 0.63) touching the ball is
grown into it; a ball lit only by a dim sky (V < 0.15 everywhere) has no seeds.

Pure: numpy and OpenCV over an image passed in; no IO, no clock.

Pixel coordinates follow ``tcm-scenario/1``: continuous, ``(0, 0)`` is the top-left
corner of the top-left pixel. Bearings are unit vectors in camera FRD.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel, Equirectangular
from .frames import FloatArray

# OpenCV's 8-bit hue is half-degrees, 0..179, and pure red sits on the wrap (0 = 180).
# Converting a BGR image with COLOR_RGB2HSV swaps red and blue, so a true hue θ reads as
# (240° - θ): red lands at 120 (half-degrees), far from the wrap, and each mask is one
# inRange call instead of two.
_SWAPPED_RED_HUE = 120

# Pairs of colour rows whose dot products the unmixing needs: p·b, p·k, b·k, b·b, k·k.
_GRAM_A = np.array([0, 1, 2, 0, 1, 2, 3, 4, 5, 3, 4, 5, 6, 7, 8])
_GRAM_B = np.array([3, 4, 5, 6, 7, 8, 6, 7, 8, 3, 4, 5, 6, 7, 8])


@dataclass(frozen=True)
class DetectionConfig:
    """Thresholds of the red-ball detector.

    Hues are signed degrees from pure red, positive towards orange/yellow and negative
    towards magenta. Saturation and value are fractions (0..1) of HSV's S and V.
    The defaults are chosen for a saturated red ball against grass, sky, dirt and
    buildings under daylight, and reject brown/orange dirt, skin, shadows and grey.
    """

    # Seeds: unmistakably saturated red (lit side). Strict, because a seed is what
    # makes a blob an object at all.
    seed_hue_deg: tuple[float, float] = (-15.0, 12.0)
    seed_min_saturation: float = 0.70
    seed_min_value: float = 0.15
    # Growth: weaker red, connected to a seed. Value may be very low (the shaded side
    # of the ball is nearly black but still saturated); the orange side of the hue
    # range stays narrow so that brown and orange dirt next to the ball is not absorbed.
    grow_hue_deg: tuple[float, float] = (-30.0, 14.0)
    grow_min_saturation: float = 0.60
    grow_min_value: float = 0.07
    # Acceptance.
    min_seed_px: int = 3
    min_area_px: float = 6.0
    min_angular_radius_rad: float = 0.0
    max_detections: int = 8
    # Sub-pixel edge: pixels within rim_width_px inside / rim_width_out_px outside the
    # grown blob's boundary get a fractional membership; the local ball and background
    # colours are Gaussian-weighted means (this sigma) over pixels farther in / out.
    rim_width_px: int = 2
    rim_width_out_px: int = 2
    colour_sigma_px: float = 1.5
    # Re-centre the band on the measured edge (membership ½) when the grown edge is on
    # average more than refine_min_shift_px away from it (at most refine_passes times).
    refine_passes: int = 1
    refine_min_shift_px: float = 0.5
    # Fractional memberships are clipped to this range: a little beyond [0, 1] keeps
    # the sum unbiased under noise, while a grass fleck or a highlight cannot count as
    # several pixels of ball.
    membership_clip: tuple[float, float] = (-0.25, 1.25)
    # Below this colour contrast (0..255 units) between ball and background the
    # unmixing is noise, and the hard mask is used instead.
    min_unmix_contrast: float = 12.0
    # Coarse grid cell for grouping seeds into regions of interest.
    coarse_cell_px: int = 8
    # Pixels no brighter than this in every channel (0..255) next to a blob count as
    # the lens's black surround for ``touches_border``: the scenario format gives a
    # fisheye no field of view, so the camera model alone cannot say where it ends.
    black_level: int = 8

    def __post_init__(self) -> None:
        for name in ("seed_hue_deg", "grow_hue_deg", "membership_clip"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"DetectionConfig.{name} must be (low, high) with low < high")
        if not (
            self.grow_hue_deg[0] <= self.seed_hue_deg[0]
            and self.seed_hue_deg[1] <= self.grow_hue_deg[1]
        ):
            raise ValueError("DetectionConfig.seed_hue_deg must lie inside grow_hue_deg")
        if not -90.0 <= self.grow_hue_deg[0] and self.grow_hue_deg[1] <= 90.0:
            raise ValueError("DetectionConfig.grow_hue_deg must lie within ±90°")
        for name in (
            "seed_min_saturation",
            "seed_min_value",
            "grow_min_saturation",
            "grow_min_value",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"DetectionConfig.{name} must lie in [0, 1]")
        if self.grow_min_saturation > self.seed_min_saturation:
            raise ValueError("DetectionConfig.grow_min_saturation must not exceed the seed's")
        if self.grow_min_value > self.seed_min_value:
            raise ValueError("DetectionConfig.grow_min_value must not exceed the seed's")
        if (
            min(self.rim_width_px, self.rim_width_out_px) < 1
            or self.coarse_cell_px < 2
            or self.min_seed_px < 1
        ):
            raise ValueError(
                "DetectionConfig: rim_width_px ≥ 1, coarse_cell_px ≥ 2, min_seed_px ≥ 1"
            )
        if self.max_detections < 1 or self.colour_sigma_px <= 0:
            raise ValueError("DetectionConfig: max_detections ≥ 1 and colour_sigma_px > 0")


_DEFAULT_CONFIG = DetectionConfig()


@dataclass(frozen=True, slots=True)
class Detection:
    """One red blob, measured through the camera model.

    - ``bearing_cam``: unit vector in camera FRD, the solid-angle-weighted mean direction
      of the blob (for a sphere, exactly its centre's direction).
    - ``angular_radius_rad``: from the blob's solid angle, ``Ω = 2π(1 - cos α)``.
    - ``area_px``: the membership sum in pixels (fractional on the rim).
    - ``centroid_px``: membership-weighted mean of pixel centres, continuous pixel
      coordinates of the scenario format, ``0 <= u < width``.
    - ``bbox_px``: ``(x0, y0, x1, y1)`` of the grown blob, exclusive ends; anti-aliased
      rim pixels may lie a pixel or two outside it. On a full-circle panorama a blob
      across the left/right seam has ``x1 > width``: its columns are ``x0 .. x1 - 1``
      modulo the width (``0 <= x0 < width`` always).
    - ``touches_border``: the blob meets the image edge (not a panorama's seam), a pixel
      without a bearing, or a black lens surround, so part of it may be cut off and its
      size is unreliable.
    - ``score``: mean HSV saturation (0..1) of the grown pixels.
    """

    centroid_px: tuple[float, float]
    bearing_cam: FloatArray
    angular_radius_rad: float
    solid_angle_sr: float
    area_px: float
    bbox_px: tuple[int, int, int, int]
    touches_border: bool
    score: float


def angular_radius_from_solid_angle(solid_angle_sr: float) -> float:
    """Half-angle α of a spherical cap of solid angle Ω = 2π(1 - cos α) = 4π sin²(α/2)."""
    s = math.sqrt(min(max(solid_angle_sr, 0.0) / (4.0 * math.pi), 1.0))
    return 2.0 * math.asin(s)


def _hue_bounds(hue_deg: tuple[float, float]) -> tuple[int, int]:
    """Swapped-HSV hue bounds (half-degrees, inclusive) of a signed true-hue range."""
    lo = math.ceil(_SWAPPED_RED_HUE - hue_deg[1] / 2.0 - 1e-9)
    hi = math.floor(_SWAPPED_RED_HUE - hue_deg[0] / 2.0 + 1e-9)
    return max(lo, 0), min(hi, 179)


def _hsv_bounds(
    hue_deg: tuple[float, float], min_s: float, min_v: float
) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    h_lo, h_hi = _hue_bounds(hue_deg)
    s_lo = min(math.ceil(min_s * 255.0 - 1e-9), 255)
    v_lo = min(math.ceil(min_v * 255.0 - 1e-9), 255)
    return (h_lo, s_lo, v_lo), (h_hi, 255, 255)


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


_K3 = np.ones((3, 3), np.uint8)


@dataclass
class _Roi:
    """Region of interest; x may run past the image edges on a full-circle panorama."""

    x0: int
    y0: int
    x1: int
    y1: int


class Detector:
    """Finds saturated red blobs in BGR images of one camera (see the module docstring)."""

    def __init__(self, camera: CameraModel, config: DetectionConfig = _DEFAULT_CONFIG) -> None:
        self.camera = camera
        self.config = config
        cfg = config
        self._w, self._h = camera.width, camera.height
        self._wrap = isinstance(camera, Equirectangular) and (
            abs(camera.azimuth_max_deg - camera.azimuth_min_deg - 360.0) < 1e-9
        )
        self._seed_lo, self._seed_hi = _hsv_bounds(
            cfg.seed_hue_deg, cfg.seed_min_saturation, cfg.seed_min_value
        )
        self._grow_lo, self._grow_hi = _hsv_bounds(
            cfg.grow_hue_deg, cfg.grow_min_saturation, cfg.grow_min_value
        )
        self._omega_sr = np.ascontiguousarray(camera.solid_angle_map_sr, dtype=np.float64)
        self._bearing_cam = np.ascontiguousarray(
            np.nan_to_num(camera.bearing_map_cam, nan=0.0), dtype=np.float64
        )
        valid = np.asarray(camera.valid_mask, dtype=bool)
        self._valid = valid.astype(np.uint8)
        # Where a blob's size is unreliable: next to pixels without a bearing (the
        # fisheye's black surround) and on the image edge (but not on a panorama's seam).
        border = cv2.dilate((~valid).astype(np.uint8), _K3) > 0
        border[0, :] = border[-1, :] = True
        if not self._wrap:
            border[:, 0] = border[:, -1] = True
        self._border = border.astype(np.uint8)
        self._k_rim_in = _disc(cfg.rim_width_px)
        self._k_rim_out = _disc(cfg.rim_width_out_px)
        self._k_close = _disc(2)
        k = 2 * math.ceil(3.0 * cfg.colour_sigma_px) + 1
        self._ksize = (k, k)
        cell = cfg.coarse_cell_px
        self._k_cell = np.ones((cell, cell), np.uint8)
        half = cell // 2
        self._coarse_rows = np.minimum(np.arange(half, self._h + half, cell), self._h - 1)
        self._coarse_cols = np.minimum(np.arange(half, self._w + half, cell), self._w - 1)
        # Crop margin around a blob: the rim band plus the reach of the colour estimates.
        self._margin = cfg.rim_width_out_px + math.ceil(3.0 * cfg.colour_sigma_px) + 2
        # A seed (|hue| ≤ h, S ≥ s, V ≥ v) has red as its largest channel and
        # R - max(G, B) = S·R·(1 - |hue|/60°), so R - max(G, B) ≥ k·R and ≥ s·v·255·(...)
        # hold for every seed (k a little looser, for OpenCV's 8-bit rounding of H and S).
        # A few full-frame SIMD operations where HSV costs ~10× more; HSV then runs on
        # crops around the candidates only.
        h_max = max(abs(cfg.seed_hue_deg[0]), abs(cfg.seed_hue_deg[1])) + 2.0
        self._prefilter_ratio = max(cfg.seed_min_saturation * (1.0 - h_max / 60.0) - 0.01, 0.0)
        self._prefilter_min = max(
            math.floor(cfg.seed_min_saturation * cfg.seed_min_value * 255.0 * (1.0 - h_max / 60.0))
            - 2.0,
            0.0,
        )
        # Full-frame scratch buffers: fresh large arrays would cost page faults per frame.
        self._planes = [np.empty((self._h, self._w), np.uint8) for _ in range(3)]
        self._scratch = np.empty((self._h, self._w), np.uint8)
        self._candidates = np.empty((self._h, self._w), np.uint8)
        self._scratch2 = np.empty((self._h, self._w), np.uint8)

    # -- public ---------------------------------------------------------------------
    def detect(self, image_bgr: np.ndarray) -> list[Detection]:
        """All red blobs in one BGR uint8 image, largest solid angle first.

        Not re-entrant (it reuses scratch buffers): one Detector per thread.
        """
        if image_bgr.shape != (self._h, self._w, 3) or image_bgr.dtype != np.uint8:
            raise ValueError(
                f"expected a {self._w}x{self._h} BGR uint8 image, got shape "
                f"{image_bgr.shape} dtype {image_bgr.dtype}"
            )
        cfg = self.config
        if cv2.countNonZero(self.candidates(image_bgr)) < cfg.min_seed_px:
            return []

        # Coarse grid of cells holding a candidate; its components are regions of interest.
        cv2.dilate(self._candidates, self._k_cell, dst=self._scratch)
        coarse = self._scratch.take(self._coarse_rows, axis=0).take(self._coarse_cols, axis=1)
        n, _, stats, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
        cell, m = cfg.coarse_cell_px, self._margin
        found: dict[int, Detection] = {}
        for i in range(1, n):
            x, y, w, h = (int(v) for v in stats[i, :4])
            roi = _Roi(x * cell - m, y * cell - m, (x + w) * cell + m, (y + h) * cell + m)
            for key, det in self._detect_in_roi(image_bgr, roi):
                found.setdefault(key, det)
        dets = sorted(found.values(), key=lambda d: d.solid_angle_sr, reverse=True)
        return dets[: cfg.max_detections]

    def candidates(self, image_bgr: np.ndarray) -> np.ndarray:
        """Full-frame mask (H, W) uint8, 255 where a pixel may be a seed (a cheap superset).

        The returned array is a scratch buffer, overwritten by the next call.
        """
        b, g, r = self._planes
        cv2.split(image_bgr, self._planes)
        d = cv2.max(g, b, dst=self._scratch)
        cv2.subtract(r, d, dst=d)  # R - max(G, B), saturating at 0
        cv2.addWeighted(d, 1.0, r, -self._prefilter_ratio, 1.0, dst=self._scratch2)
        cv2.threshold(self._scratch2, 0, 255, cv2.THRESH_BINARY, dst=self._scratch2)
        cv2.threshold(d, self._prefilter_min, 255, cv2.THRESH_BINARY, dst=self._candidates)
        return cv2.bitwise_and(self._candidates, self._scratch2, dst=self._candidates)

    def seeds(self, image_bgr: np.ndarray) -> np.ndarray:
        """Full-frame seed mask (H, W) uint8, 255 on strong saturated red (for tests)."""
        hsv = cv2.cvtColor(image_bgr, cv2.COLOR_RGB2HSV)  # swapped on purpose, see top
        return np.asarray(cv2.inRange(hsv, self._seed_lo, self._seed_hi))

    # -- internals ------------------------------------------------------------------
    def _clamp(self, roi: _Roi) -> _Roi:
        y0, y1 = max(roi.y0, 0), min(roi.y1, self._h)
        if not self._wrap:
            return _Roi(max(roi.x0, 0), y0, min(roi.x1, self._w), y1)
        x0, x1 = roi.x0, roi.x1
        if x1 - x0 > self._w:  # a region never needs more than the whole circle
            x1 = x0 + self._w
        return _Roi(x0, y0, x1, y1)

    def _take(self, arr: np.ndarray, roi: _Roi) -> np.ndarray:
        """Crop rows and columns of a full-frame array; columns modulo W on a panorama."""
        rows = arr[roi.y0 : roi.y1]
        if 0 <= roi.x0 and roi.x1 <= self._w:
            return rows[:, roi.x0 : roi.x1]
        return np.take(rows, np.arange(roi.x0, roi.x1) % self._w, axis=1)

    def _detect_in_roi(self, image_bgr: np.ndarray, roi: _Roi) -> list[tuple[int, Detection]]:
        cfg, m = self.config, self._margin
        roi = self._clamp(roi)
        for _ in range(8):
            img_roi = np.ascontiguousarray(self._take(image_bgr, roi))
            hsv_roi = cv2.cvtColor(img_roi, cv2.COLOR_RGB2HSV)  # swapped on purpose, see top
            seed = cv2.inRange(hsv_roi, self._seed_lo, self._seed_hi)
            if cv2.countNonZero(seed) < cfg.min_seed_px:
                return []
            grow = cv2.inRange(hsv_roi, self._grow_lo, self._grow_hi)
            n, labels, stats, _ = cv2.connectedComponentsWithStats(grow, connectivity=8)
            seed_counts = np.bincount(labels[seed > 0], minlength=n)
            kept = np.flatnonzero(seed_counts[1:] >= cfg.min_seed_px) + 1
            # Grow the region until every kept blob sits inside it with a full margin,
            # unless the region already meets the image edge on that side.
            bigger = _Roi(roi.x0, roi.y0, roi.x1, roi.y1)
            for k in kept:
                x, y, w, h = (int(v) for v in stats[k, :4])
                if x < m:
                    bigger.x0 = min(bigger.x0, roi.x0 + x - 2 * m)
                if y < m:
                    bigger.y0 = min(bigger.y0, roi.y0 + y - 2 * m)
                if x + w > roi.x1 - roi.x0 - m:
                    bigger.x1 = max(bigger.x1, roi.x0 + x + w + 2 * m)
                if y + h > roi.y1 - roi.y0 - m:
                    bigger.y1 = max(bigger.y1, roi.y0 + y + h + 2 * m)
            bigger = self._clamp(bigger)
            if (bigger.x0, bigger.y0, bigger.x1, bigger.y1) == (roi.x0, roi.y0, roi.x1, roi.y1):
                break
            roi = bigger
        out: list[tuple[int, Detection]] = []
        for k in kept:
            res = self._measure(img_roi, hsv_roi, grow, labels, stats[k], int(k), roi)
            if res is not None:
                out.append(res)
        return out

    def _measure(
        self,
        img_roi: np.ndarray,
        hsv_roi: np.ndarray,
        grow: np.ndarray,
        labels: np.ndarray,
        stat: np.ndarray,
        label: int,
        roi: _Roi,
    ) -> tuple[int, Detection] | None:
        """Measure one grown blob through the camera model; None if it fails the limits."""
        cfg, m = self.config, self._margin
        x, y, w, h = (int(v) for v in stat[:4])
        bx0, by0 = max(x - m, 0), max(y - m, 0)
        bx1, by1 = min(x + w + m, labels.shape[1]), min(y + h + m, labels.shape[0])
        sub = _Roi(roi.x0 + bx0, roi.y0 + by0, roi.x0 + bx1, roi.y0 + by1)
        raw = (labels[by0:by1, bx0:bx1] == label).view(np.uint8)
        # Closing first: a specular highlight on the limb is a notch, not a hole.
        mask = _u8(cv2.morphologyEx(raw, cv2.MORPH_CLOSE, self._k_close))
        _fill_holes(mask)
        valid = self._take(self._valid, sub)
        filled = _u8(cv2.subtract(mask, raw))
        crop = (
            img_roi[by0:by1, bx0:bx1],
            hsv_roi[by0:by1, bx0:bx1, 1],
            grow[by0:by1, bx0:bx1],
        )
        weight = self._weights(crop, raw, filled, mask, valid)
        for _ in range(cfg.refine_passes):
            # Re-centre the rim band on the measured edge (membership ½) when the grown
            # edge sits on average more than refine_min_shift_px from it: the band must
            # hold the whole transition, and the background samples must lie beyond it.
            edge = (weight >= 0.5).view(np.uint8) | filled
            moved = cv2.countNonZero(cv2.bitwise_xor(edge, mask))
            perimeter = math.sqrt(4.0 * math.pi * cv2.countNonZero(mask))
            if moved <= cfg.refine_min_shift_px * perimeter:
                break
            _fill_holes(edge)
            weight = self._weights(crop, raw, filled, edge, valid)
            mask = edge

        area = float(weight.sum(dtype=np.float64))
        omega = self._take(self._omega_sr, sub) * weight
        solid_angle = float(omega.sum())
        if not (solid_angle > 0.0 and area >= cfg.min_area_px):
            return None
        alpha = angular_radius_from_solid_angle(solid_angle)
        if alpha < cfg.min_angular_radius_rad:
            return None
        vec = omega.reshape(-1) @ self._take(self._bearing_cam, sub).reshape(-1, 3)
        norm = math.sqrt(float(vec @ vec))
        if not norm > 0.0:
            return None

        hh, ww = mask.shape
        cx = float(weight.sum(axis=0) @ (np.arange(ww) + 0.5 + sub.x0)) / area
        cy = float(weight.sum(axis=1) @ (np.arange(hh) + 0.5 + sub.y0)) / area
        gx0 = roi.x0 + x
        shift = (gx0 // self._w) * self._w if self._wrap else 0
        bbox = (gx0 - shift, roi.y0 + y, gx0 - shift + w, roi.y0 + y + h)
        black = cv2.inRange(img_roi[by0:by1, bx0:bx1], (0, 0, 0), (cfg.black_level,) * 3)
        border = self._take(self._border, sub) | _u8(cv2.dilate(black, _K3))
        touches = bool(cv2.countNonZero(border & mask))
        # Score: mean HSV saturation (0..1) of the grown pixels.
        score = cv2.mean(hsv_roi[by0:by1, bx0:bx1, 1], mask=raw)[0] / 255.0
        # One key per object even when two regions of interest reach it: its first
        # pixel in raster order (top row, smallest column modulo the width).
        top = np.flatnonzero(raw[y - by0])
        key = (roi.y0 + y) * self._w + int(np.min((top + sub.x0) % self._w))
        det = Detection(
            centroid_px=(cx % self._w if self._wrap else cx, cy),
            bearing_cam=vec / norm,
            angular_radius_rad=alpha,
            solid_angle_sr=solid_angle,
            area_px=area,
            bbox_px=bbox,
            touches_border=touches,
            score=score,
        )
        return key, det

    def _weights(
        self,
        crop: tuple[np.ndarray, np.ndarray, np.ndarray],
        raw: np.ndarray,
        filled: np.ndarray,
        mask: np.ndarray,
        valid: np.ndarray,
    ) -> np.ndarray:
        """Membership (H, W) of every crop pixel: 1 inside ``mask``, fractional on its rim."""
        inner = _u8(cv2.erode(mask, self._k_rim_in))
        if not inner.any():  # a tiny blob: everything is rim
            inner = _u8(cv2.erode(mask, _K3))
        inner &= valid
        near = _u8(cv2.dilate(mask, self._k_rim_out))
        weight = inner.astype(np.float32)
        ys, xs = np.nonzero(_u8(cv2.subtract(near, inner)) & valid)
        if ys.size:
            img, saturation, grow = crop
            weight[ys, xs] = self._rim_fractions(
                img, saturation, grow, raw, filled, mask, inner, near, valid, ys, xs
            )
        return weight

    def _rim_fractions(
        self,
        img: np.ndarray,
        saturation: np.ndarray,
        grow: np.ndarray,
        raw: np.ndarray,
        filled: np.ndarray,
        mask: np.ndarray,
        inner: np.ndarray,
        near: np.ndarray,
        valid: np.ndarray,
        ys: np.ndarray,
        xs: np.ndarray,
    ) -> np.ndarray:
        """Fraction of each rim pixel ``(ys, xs)`` that the ball covers.

        The pixel colour is unmixed into ball and background with both colours
        estimated locally (Gaussian-weighted over pixels farther in and farther out),
        so an anti-aliased, blurred or JPEG-smeared edge contributes the fraction it
        covers and the blob's sum is sub-pixel. ``raw`` is the grown blob, ``mask`` the
        filled one, ``inner`` its interior, ``near`` its dilation.
        """
        cfg = self.config
        # The ball's colour comes from saturated grown pixels (never a highlight), as
        # far inside as there are any.
        pure = _u8(raw & (saturation >= self._seed_lo[1]).view(np.uint8))
        source = _u8(inner & pure)
        if not source.any():
            source = _u8(cv2.erode(mask, _K3)) & pure
            if not source.any():
                source = pure if pure.any() else mask
        # The background's colour: valid pixels beyond the rim band that belong to no blob.
        outer = ((near == 0) & (valid > 0) & (grow == 0)).view(np.uint8)

        # Colour × weight and weight, for the ball's and the background's samples.
        # Unmixing works on the 8-bit code values: renderers and cameras anti-alias in
        # that space as often as in linear light, and on the example scenarios code
        # values fit better (radius bias 0.1% against 1-5% in linear light).
        stack = cv2.merge([cv2.copyTo(img, source), source, cv2.copyTo(img, outer), outer])
        stack = stack.astype(np.float32)
        blur = cv2.GaussianBlur(
            stack, self._ksize, cfg.colour_sigma_px, borderType=cv2.BORDER_CONSTANT
        )
        at = blur[ys, xs]
        if not (at[:, 3::4] > 1e-3).all():
            # Out of reach of every sample: the mean over the whole crop instead.
            totals = stack.reshape(-1, 8).sum(axis=0)
            for k in (3, 7):
                far = ~(at[:, k] > 1e-3)
                at[far, k - 3 : k + 1] = totals[k - 3 : k + 1]
        # Rows 0-2: the pixel; 3-5: the local ball colour b; 6-8: the background k.
        cols = np.empty((9, ys.size), np.float32)
        cols[0:3] = img[ys, xs].T
        cols[3:6] = at[:, 0:3].T / np.maximum(at[:, 3], 1e-6)
        cols[6:9] = at[:, 4:7].T / np.maximum(at[:, 7], 1e-6)
        prods = cols[_GRAM_A] * cols[_GRAM_B]
        pb, pk, bk, bb, kk = prods[0::3] + prods[1::3] + prods[2::3]
        bb = np.maximum(bb, 1e-6)
        # Shading only scales the ball's colour, so its chromaticity (direction b/|b| in
        # colour space) is what is known at the rim, not its brightness (the lit limb is
        # brighter than the pixels just inside). Orthogonally to that direction the ball
        # contributes nothing and a pixel reads (1 - f)·k⊥, k the background; with
        # k⊥ = k - (k·b)b/|b|²: f = 1 - p·k⊥ / |k⊥|².
        den = kk - bk * bk / bb
        frac = 1.0 - (pk - pb * bk / bb) / np.maximum(den, 1e-6)
        contrast2 = cfg.min_unmix_contrast**2
        weak = den < contrast2
        if weak.any():
            # A background of the ball's own hue (dark shadow, red dirt) leaves no
            # orthogonal contrast: unmix between the two local colours,
            # f = (p-k)·(b-k) / |b-k|², or, without any contrast at all, keep the mask.
            den2 = bb - 2.0 * bk + kk
            frac2 = (pb - pk - bk + kk) / np.maximum(den2, 1e-6)
            hard = mask[ys, xs].astype(np.float32)
            frac = np.where(weak, np.where(den2 >= contrast2, frac2, hard), frac)
        lo, hi = cfg.membership_clip
        frac = np.clip(frac, lo, hi)
        # Filled pixels (a highlight, notch or hole closed in the mask) are ball by
        # topology, whatever their colour says.
        frac[filled[ys, xs] > 0] = 1.0
        return np.asarray(frac)


def _u8(a: np.ndarray | cv2.typing.MatLike) -> NDArray[np.uint8]:
    """An OpenCV result as a uint8 array (no copy; typed for the bit operations)."""
    return np.asarray(a, dtype=np.uint8)


def _fill_holes(mask: np.ndarray) -> None:
    """Fill, in place, background regions of a 0/1 mask not connected to its border."""
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(padded, None, (0, 0), 2, flags=4)
    mask[padded[1:-1, 1:-1] == 0] = 1
