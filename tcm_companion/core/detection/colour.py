"""The ``colour`` backend: every blob of a target colour, its bearing and angular radius,
sub-pixel.

The Triangle Closure Method compares an object's *angular* size between two frames a
second apart, so what this module must get right is the ratio of radii, to a small
fraction of a pixel, on any of the scenario format's camera models. The paper segments
a red ball by colour and grows regions from seeds; here that is, for each configured
:class:`~.settings.ColourTarget` (by default the paper's saturated red):

1. **Candidates** — a cheap full-frame test that every seed passes: the channel(s) of the
   target's hue sector well above the rest (for red: R well above G and B; see
   :class:`_Target`), or for a Lab target the box around its seed sphere in 8-bit Lab;
   a coarse grid of candidate cells gives regions of interest, so that everything after
   this step runs on small crops only.
2. **Seeds and growth (hysteresis)** — in each region, HSV seeds of strong, saturated
   colour (the lit side) and connected components of a weaker one (the dark shaded
   side); for a Lab target, pixels within the seed and the growth colour differences
   (ΔE*ab, lightness weighted) of its CIELAB colour. A component is kept only if it
   holds seeds. Notches and holes (a specular
   highlight) are filled. On a 360° panorama regions are taken modulo the width, so a
   blob across the left and right edges is one object.
3. **Measurement through the camera model** — pixels within a couple of pixels of the
   blob's edge get a fractional membership by unmixing their colour into the local
   object colour (just inside) and the local background colour (just outside), from
   chroma and brightness together: the object's share (true on any background
   brightness) and one minus the background's (true however the object is shaded),
   each weighted by how much its side's colour varies locally, so a textured dark
   hedge does not count its dark gaps as object; the band is re-centred once on the
   measured edge if the growth stopped short of it. The blob's solid angle is the
   membership-weighted sum of per-pixel solid angles, its bearing the normalised
   weighted sum of pixel-centre bearings. A sphere's image is a spherical
   cap, so ``Ω = 2π(1 - cos α)`` gives its angular radius exactly, on any lens, off
   axis or not (for other shapes, the radius of the cap of equal solid angle).

Known limits (red ball): a specular highlight *on the limb* reads as background (a few
tenths of a pixel of radius); a reddish-brown patch (hue ≈ 12°, S ≈ 0.63) touching the
ball is grown into it; a ball lit only by a dim sky (V < 0.15 everywhere) has no seeds.
The rim is unmixed in code values (``light_exponent`` 1): an edge mixed in linear light
(a camera's optics, this project's simulator) reads a dark object on a bright sky a
fixed fraction of a pixel too small (−2 to −5 % of the radius at 5° to 2°), a bright one
on a dark background too large.
Grey, white and black objects have no hue: they are Lab targets, which also find
whatever else has their colour (a grey building, white clouds; docs/detection.md), and
one object matched by two Lab targets (a grey one's shaded side is dark grey) is
reported once, by the better-matching target.

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

from ..camera import CameraModel
from .base import Detection, DetectorBackend, angular_radius_from_solid_angle, wraps_around
from .settings import ColourTarget, DetectionConfig, hue_plan

# Rim unmixing (see ``ColourDetector._rim_fractions``). Sensor noise of one code value
# (0..255 units), a floor under the noise of both shares of a pixel:
_NOISE_DN = 3.0
# Least relative spread of the object's brightness around its local estimate: shading
# changes between the rim and the samples two pixels farther in, and a JPEG smears
# colour across the edge (0.1-1.0 measured, docs/decisions.md §2; 0.5 in the middle of
# the flat optimum on the simulator and the independent examples):
_SHADING_SPREAD = 0.5
# Fixed-point iterations of the combined estimate (its weights depend on the fraction).
_COMBINE_PASSES = 3

_DEFAULT_CONFIG = DetectionConfig()

# Planes of a BGR image after cv2.split.
_B, _G, _R = 0, 1, 2
# Hue sectors every 60°: (the channels that are high, the channel(s) that are low).
# In a primary's sector (red 0°, green 120°, blue 240°) its channel is the largest; in
# a secondary's (yellow 60°, cyan 180°, magenta 300°) its two channels are the largest.
_SECTORS: dict[int, tuple[tuple[int, ...], tuple[int, ...]]] = {
    0: ((_R,), (_G, _B)),
    60: ((_R, _G), (_B,)),
    120: ((_G,), (_R, _B)),
    180: ((_G, _B), (_R,)),
    240: ((_B,), (_R, _G)),
    300: ((_R, _B), (_G,)),
}


class _Target:
    """A :class:`ColourTarget` prepared for OpenCV: HSV conversion, bounds, prefilter.

    Prefilter: within ±60° of a sector's hue P, a colour of hue θ, saturation S and value
    V has ``high - low = S·V·(1 - |θ - P|/60°)``, where ``high`` is the sector's channel
    (a primary) or the smaller of its two (a secondary), ``low`` the largest other
    channel, and the largest channel is V. So ``high - low ≥ k·V`` and
    ``≥ s·v·255·(1 - h/60°)`` hold for every seed (|θ - P| ≤ h, S ≥ s, V ≥ v; k a little
    looser, for OpenCV's 8-bit rounding of H and S): a few full-frame SIMD operations
    where HSV costs ~10× more. For red this is ``R - max(G, B) ≥ k·R``. A seed range
    reaching 60° from every sector's hue gets the exact full-frame HSV test instead.
    """

    def __init__(self, spec: ColourTarget) -> None:
        self.spec = spec
        self.label = spec.label
        self.lab: _LabTarget | None = _LabTarget(spec) if spec.is_lab else None
        self.sector: tuple[tuple[int, ...], tuple[int, ...]] | None = None
        if self.lab is not None:
            self.code = cv2.COLOR_BGR2Lab
            # The strength plane's level that every seed reaches (see _LabTarget).
            self.pure_level = self.lab.seed_strength
            return
        plan = hue_plan(spec.hue_deg, spec.seed_hue_deg, spec.grow_hue_deg)
        # COLOR_RGB2HSV on a BGR image reads a true hue θ as (240° - θ): red lands at 120
        # (half-degrees), far from the wrap, and each mask is one inRange call.
        self.code = cv2.COLOR_RGB2HSV if plan.swapped else cv2.COLOR_BGR2HSV
        s_seed = min(math.ceil(spec.seed_min_saturation * 255.0 - 1e-9), 255)
        v_seed = min(math.ceil(spec.seed_min_value * 255.0 - 1e-9), 255)
        s_grow = min(math.ceil(spec.grow_min_saturation * 255.0 - 1e-9), 255)
        v_grow = min(math.ceil(spec.grow_min_value * 255.0 - 1e-9), 255)
        self.seed_lo = (plan.seed[0], s_seed, v_seed)
        self.seed_hi = (plan.seed[1], 255, 255)
        self.grow_lo = (plan.grow[0], s_grow, v_grow)
        self.grow_hi = (plan.grow[1], 255, 255)
        seed_lo_deg = spec.hue_deg + spec.seed_hue_deg[0]
        seed_hi_deg = spec.hue_deg + spec.seed_hue_deg[1]
        centre = 0.5 * (seed_lo_deg + seed_hi_deg)
        sector = round(centre / 60.0) * 60
        h_max = max(abs(seed_lo_deg - sector), abs(seed_hi_deg - sector)) + 2.0
        self.sector = _SECTORS[sector % 360] if h_max < 60.0 else None
        self.prefilter_ratio = max(spec.seed_min_saturation * (1.0 - h_max / 60.0) - 0.01, 0.0)
        self.prefilter_min = max(
            math.floor(
                spec.seed_min_saturation * spec.seed_min_value * 255.0 * (1.0 - h_max / 60.0)
            )
            - 2.0,
            0.0,
        )
        # Seeds' least HSV saturation: the object's own colour (never a highlight).
        self.pure_level = self.seed_lo[1]

    def convert(self, image_bgr: np.ndarray) -> np.ndarray:
        """The image as the target's masks read it: HSV (H×W×3 uint8) for a hue target,
        the squared colour difference from the target colour (H×W float32) for a Lab one."""
        conv = np.asarray(cv2.cvtColor(image_bgr, self.code))
        return conv if self.lab is None else self.lab.delta_e2(conv)

    def seed_mask(self, conv: np.ndarray) -> np.ndarray:
        """255 on seed pixels of a converted image."""
        if self.lab is not None:
            return _below(conv, self.lab.seed_de2)
        return np.asarray(cv2.inRange(conv, self.seed_lo, self.seed_hi))

    def grow_mask(self, conv: np.ndarray) -> np.ndarray:
        """255 on pixels a blob may grow through."""
        if self.lab is not None:
            return _below(conv, self.lab.grow_de2)
        return np.asarray(cv2.inRange(conv, self.grow_lo, self.grow_hi))

    def strength(self, conv: np.ndarray) -> np.ndarray:
        """How strongly each pixel is of the target's colour, 0..255 (uint8): a hue
        target's HSV saturation; a Lab target's closeness, 255·(1 - ΔE/grow ΔE).
        Seeds reach :attr:`pure_level`; the detection's score is its mean over the blob."""
        if self.lab is not None:
            return self.lab.closeness(conv)
        return conv[..., 1]


def _below(values: np.ndarray, limit: float) -> np.ndarray:
    """255 where ``values`` (float32) is at most ``limit``, else 0 (uint8)."""
    return (values <= np.float32(limit)).view(np.uint8) * np.uint8(255)


class _LabTarget:
    """A Lab target on OpenCV's 8-bit Lab (``L·255/100``, ``a + 128``, ``b + 128``):
    ΔE*ab from the target colour, in true CIELAB units."""

    def __init__(self, spec: ColourTarget) -> None:
        L, a, b = spec.lab
        self.centre = np.array([L * 255.0 / 100.0, a + 128.0, b + 128.0], np.float32)
        # Per-channel scale from 8-bit units to CIELAB units (L* weighted by 1/k).
        k = spec.delta_e_lightness_factor
        self.scale = np.array([100.0 / 255.0 / k, 1.0, 1.0], np.float32)
        self.seed_de2 = float(spec.seed_max_delta_e) ** 2
        self.grow_de2 = float(spec.grow_max_delta_e) ** 2
        self.grow_de = float(spec.grow_max_delta_e)
        self.seed_strength = max(
            math.floor(255.0 * (1.0 - spec.seed_max_delta_e / spec.grow_max_delta_e)), 0
        )
        # Full-frame prefilter: the box around the seed sphere, a superset of the seeds
        # (one code value of slack for OpenCV's rounding).
        de = spec.seed_max_delta_e
        half = np.array([de * k * 2.55, de, de], np.float32)
        lo, hi = (self.centre - half).tolist(), (self.centre + half).tolist()
        self.box_lo = tuple(max(math.floor(v) - 1, 0) for v in lo)
        self.box_hi = tuple(min(math.ceil(v) + 1, 255) for v in hi)

    def delta_e2(self, lab8: np.ndarray) -> np.ndarray:
        """Squared colour difference (float32, H×W) of every pixel of an 8-bit Lab image."""
        d = (lab8.astype(np.float32) - self.centre) * self.scale
        return np.asarray(np.einsum("ijk,ijk->ij", d, d))

    def closeness(self, de2: np.ndarray) -> np.ndarray:
        """``255·(1 - ΔE/grow ΔE)``, clipped to 0..255 (uint8), from squared ΔE."""
        out = 255.0 * (1.0 - np.sqrt(de2) / np.float32(self.grow_de))
        return np.clip(out, 0.0, 255.0).astype(np.uint8)


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


class ColourDetector(DetectorBackend):
    """Finds blobs of the configured colours in BGR images of one camera (see the module
    docstring); by default, saturated red."""

    backend = "colour"

    def __init__(
        self,
        camera: CameraModel,
        config: DetectionConfig = _DEFAULT_CONFIG,
        light_exponent: float = 1.0,
    ) -> None:
        """``light_exponent``: the rim is unmixed in code values raised to this power,
        ``255·(c/255)^γ``. 1 (the default): code values, which fits images anti-aliased
        after their gamma (the independent examples); 2: linear light for a display gamma
        of 2, which is how this project's simulator and a real camera's optics mix an
        edge (docs/decisions.md §2 measures both)."""
        super().__init__(camera)
        self.config = config
        cfg = config
        if not light_exponent > 0.0:
            raise ValueError(f"light_exponent must be positive, got {light_exponent!r}")
        self._light_exponent = float(light_exponent)
        self._w, self._h = camera.width, camera.height
        self._wrap = wraps_around(camera)
        self.targets = [_Target(t) for t in cfg.colour_targets]
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
        # Full-frame scratch buffers: fresh large arrays would cost page faults per frame.
        self._planes = [np.empty((self._h, self._w), np.uint8) for _ in range(3)]
        self._scratch = np.empty((self._h, self._w), np.uint8)
        self._candidates = np.empty((self._h, self._w), np.uint8)
        self._scratch2 = np.empty((self._h, self._w), np.uint8)
        self._scratch3 = np.empty((self._h, self._w), np.uint8)
        # Full-frame HSV (conversion code, image), for targets without a prefilter.
        self._hsv: tuple[int, np.ndarray] | None = None
        # Full-frame 8-bit Lab, for Lab targets.
        self._lab: np.ndarray | None = None

    # -- public ---------------------------------------------------------------------
    def detect(self, image_bgr: np.ndarray, frame_time_us: int = 0) -> list[Detection]:
        """All blobs of every target in one BGR uint8 image, largest solid angle first
        (at most ``max_detections``). ``frame_time_us`` is not used.

        Not re-entrant (it reuses scratch buffers): one detector per thread.
        """
        if image_bgr.shape != (self._h, self._w, 3) or image_bgr.dtype != np.uint8:
            raise ValueError(
                f"expected a {self._w}x{self._h} BGR uint8 image, got shape "
                f"{image_bgr.shape} dtype {image_bgr.dtype}"
            )
        cfg = self.config
        cv2.split(image_bgr, self._planes)
        self._hsv = None
        self._lab = None
        dets: list[Detection] = []
        lab: list[tuple[int, Detection]] = []
        for i, target in enumerate(self.targets):
            found = self._detect_target(image_bgr, target)
            if target.lab is None:
                dets.extend(found)
            else:
                lab.extend((i, d) for d in found)
        if lab:
            dets = _one_per_object(dets, lab, self._w if self._wrap else 0)
        dets.sort(key=lambda d: d.solid_angle_sr, reverse=True)
        return dets[: cfg.max_detections]

    def candidates(self, image_bgr: np.ndarray) -> np.ndarray:
        """Full-frame mask (H, W) uint8, 255 where a pixel may be a seed of any target (a
        cheap superset). The returned array is a scratch buffer, overwritten by the next
        call."""
        cv2.split(image_bgr, self._planes)
        self._hsv = None
        self._lab = None
        if len(self.targets) == 1:
            return self._target_candidates(image_bgr, self.targets[0])
        union = np.zeros((self._h, self._w), np.uint8)
        for target in self.targets:
            cv2.bitwise_or(union, self._target_candidates(image_bgr, target), dst=union)
        self._candidates[:] = union
        return self._candidates

    def seeds(self, image_bgr: np.ndarray) -> np.ndarray:
        """Full-frame seed mask (H, W) uint8, 255 on strong colour of any target (for
        tests)."""
        out = np.zeros((self._h, self._w), np.uint8)
        for t in self.targets:
            cv2.bitwise_or(out, t.seed_mask(t.convert(image_bgr)), dst=out)
        return out

    # -- internals ------------------------------------------------------------------
    def _target_candidates(self, image_bgr: np.ndarray, t: _Target) -> np.ndarray:
        """One target's candidate mask (self._candidates); the planes are split."""
        if t.lab is not None:  # the box around the seed sphere, on full-frame Lab
            if self._lab is None:
                self._lab = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab)
            box = t.lab
            return np.asarray(cv2.inRange(self._lab, box.box_lo, box.box_hi, dst=self._candidates))
        if t.sector is None:
            if self._hsv is None or self._hsv[0] != t.code:
                self._hsv = (t.code, cv2.cvtColor(image_bgr, t.code))
            return np.asarray(cv2.inRange(self._hsv[1], t.seed_lo, t.seed_hi, dst=self._candidates))
        high, low = t.sector
        planes = self._planes
        if len(high) == 1:  # a primary: its channel minus the larger of the other two
            d: np.ndarray = cv2.max(planes[low[0]], planes[low[1]], dst=self._scratch)
            cv2.subtract(planes[high[0]], d, dst=d)  # saturating at 0
            top: np.ndarray = planes[high[0]]
        else:  # a secondary: the smaller of its two channels minus the third
            d = cv2.min(planes[high[0]], planes[high[1]], dst=self._scratch)
            cv2.subtract(d, planes[low[0]], dst=d)
            top = cv2.max(planes[high[0]], planes[high[1]], dst=self._scratch3)
        cv2.addWeighted(d, 1.0, top, -t.prefilter_ratio, 1.0, dst=self._scratch2)
        cv2.threshold(self._scratch2, 0, 255, cv2.THRESH_BINARY, dst=self._scratch2)
        cv2.threshold(d, t.prefilter_min, 255, cv2.THRESH_BINARY, dst=self._candidates)
        return cv2.bitwise_and(self._candidates, self._scratch2, dst=self._candidates)

    def _detect_target(self, image_bgr: np.ndarray, target: _Target) -> list[Detection]:
        cfg = self.config
        if cv2.countNonZero(self._target_candidates(image_bgr, target)) < cfg.min_seed_px:
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
            for key, det in self._detect_in_roi(image_bgr, roi, target):
                found.setdefault(key, det)
        return list(found.values())

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

    def _detect_in_roi(
        self, image_bgr: np.ndarray, roi: _Roi, t: _Target
    ) -> list[tuple[int, Detection]]:
        cfg, m = self.config, self._margin
        roi = self._clamp(roi)
        for _ in range(8):
            img_roi = np.ascontiguousarray(self._take(image_bgr, roi))
            conv_roi = t.convert(img_roi)
            seed = t.seed_mask(conv_roi)
            if cv2.countNonZero(seed) < cfg.min_seed_px:
                return []
            grow = t.grow_mask(conv_roi)
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
        strength = t.strength(conv_roi)
        for k in kept:
            res = self._measure(img_roi, strength, grow, labels, stats[k], int(k), roi, t)
            if res is not None:
                out.append(res)
        return out

    def _measure(
        self,
        img_roi: np.ndarray,
        strength: np.ndarray,
        grow: np.ndarray,
        labels: np.ndarray,
        stat: np.ndarray,
        label: int,
        roi: _Roi,
        t: _Target,
    ) -> tuple[int, Detection] | None:
        """Measure one grown blob through the camera model; None if it fails the limits.

        ``strength``: the region's :meth:`_Target.strength` plane (0..255)."""
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
            strength[by0:by1, bx0:bx1],
            grow[by0:by1, bx0:bx1],
        )
        weight = self._weights(crop, raw, filled, mask, valid, t)
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
            weight = self._weights(crop, raw, filled, edge, valid, t)
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
        # The lens's black surround: black pixels outside the blob (a black object's own
        # pixels are as dark; a hue target's never are, its growth has a minimum value).
        black = cv2.inRange(img_roi[by0:by1, bx0:bx1], (0, 0, 0), (cfg.black_level,) * 3)
        black[mask > 0] = 0
        border = self._take(self._border, sub) | _u8(cv2.dilate(black, _K3))
        touches = bool(cv2.countNonZero(border & mask))
        # Score: mean strength (0..1) of the grown pixels (a hue target: HSV saturation).
        score = cv2.mean(strength[by0:by1, bx0:bx1], mask=raw)[0] / 255.0
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
            label=t.label,
        )
        return key, det

    def _weights(
        self,
        crop: tuple[np.ndarray, np.ndarray, np.ndarray],
        raw: np.ndarray,
        filled: np.ndarray,
        mask: np.ndarray,
        valid: np.ndarray,
        t: _Target,
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
            img, strength, grow = crop
            weight[ys, xs] = self._rim_fractions(
                img, strength, grow, raw, filled, mask, inner, near, valid, ys, xs, t
            )
        return weight

    def _rim_fractions(
        self,
        img: np.ndarray,
        strength: np.ndarray,
        grow: np.ndarray,
        raw: np.ndarray,
        filled: np.ndarray,
        mask: np.ndarray,
        inner: np.ndarray,
        near: np.ndarray,
        valid: np.ndarray,
        ys: np.ndarray,
        xs: np.ndarray,
        t: _Target,
    ) -> np.ndarray:
        """Fraction of each rim pixel ``(ys, xs)`` that the object covers.

        The pixel colour ``p`` is unmixed into the local object colour ``b`` (a
        Gaussian-weighted mean over object pixels farther in) and the local background
        colour ``k`` (the same over pixels farther out): ``p ≈ a·b + c·k`` in the plane
        of the two colours. Either share gives the fraction, and each fails where the
        other holds:

        - ``1 - c`` (chroma: the object's brightness left free, only its colour's
          direction used) is exact however the object is shaded, but reads a background
          pixel darker than the local mean (a gap in a hedge, a shadow) as object;
        - ``a`` (the background's brightness left free) is exact on any background
          brightness, but reads a shaded object pixel as partly background.

        So both are combined, weighted by their expected errors: ``f²·σ_b²`` for ``a``
        and ``(1 - f)²·σ_k²`` for ``1 - c``, with ``σ_b`` and ``σ_k`` the relative
        spreads of the object's and the background's colours around their local means
        (from the same Gaussian weights; at least ``_SHADING_SPREAD`` for the object),
        plus the sensor noise of each share. A smooth sky backs the chroma share, a
        textured hedge the object's. ``raw`` is the grown blob, ``mask`` the filled one,
        ``inner`` its interior, ``near`` its dilation.
        """
        cfg = self.config
        # The object's colour comes from grown pixels as strongly of the target's colour
        # as a seed (saturated, for a hue target; never a highlight), as far inside as
        # there are any.
        pure = _u8(raw & (strength >= t.pure_level).view(np.uint8))
        source = _u8(inner & pure)
        if not source.any():
            source = _u8(cv2.erode(mask, _K3)) & pure
            if not source.any():
                source = pure if pure.any() else mask
        # The background's colour: valid pixels beyond the rim band that belong to no blob.
        outer = ((near == 0) & (valid > 0) & (grow == 0)).view(np.uint8)

        # Unmixing works on the 8-bit code values by default: renderers and cameras
        # anti-alias in that space as often as in linear light, and on the independent
        # examples code values fit better (radius bias 0.1% against 1-5% in linear light).
        code = img.astype(np.float32)
        light = code
        if self._light_exponent != 1.0:
            light = np.float32(255.0) * (code / np.float32(255.0)) ** np.float32(
                self._light_exponent
            )
        b, b_spread2, k, k_spread2 = self._local_colours(light, source, outer, ys, xs)
        p = light[ys, xs].astype(np.float64)
        pb = np.einsum("ij,ij->i", p, b)
        pk = np.einsum("ij,ij->i", p, k)
        bk = np.einsum("ij,ij->i", b, k)
        bb = np.maximum(np.einsum("ij,ij->i", b, b), 1e-6)
        kk = np.maximum(np.einsum("ij,ij->i", k, k), 1e-6)
        # |k⊥|², |b⊥|²: each colour's part orthogonal to the other.
        k_perp2 = np.maximum(kk - bk * bk / bb, 1e-6)
        b_perp2 = np.maximum(bb - bk * bk / kk, 1e-6)
        det = bb * k_perp2
        share_obj = (pb * kk - pk * bk) / det  # a
        share_bg = (pk * bb - pb * bk) / det  # c
        chroma = 1.0 - share_bg
        var_obj_shading = np.maximum(b_spread2 / bb, _SHADING_SPREAD**2)
        var_bg_texture = k_spread2 / kk
        noise2 = _NOISE_DN**2
        total = share_obj + share_bg
        frac = np.where(total > 0.05, share_obj / np.maximum(total, 1e-6), 0.5)
        frac = np.clip(frac, 0.0, 1.0)
        for _ in range(_COMBINE_PASSES):
            v_obj = frac * frac * var_obj_shading + noise2 / b_perp2
            v_bg = (1.0 - frac) ** 2 * var_bg_texture + noise2 / k_perp2
            frac = np.clip((share_obj * v_bg + chroma * v_obj) / (v_obj + v_bg), 0.0, 1.0)

        # A background of the object's own hue (dark shadow, red dirt) leaves no
        # orthogonal contrast: unmix between the two local colours,
        # f = (p-k)·(b-k) / |b-k|², or, without any contrast at all, keep the mask. The
        # contrast is judged in code values.
        if light is not code:
            bc, _, kc, _ = self._local_colours(code, source, outer, ys, xs)
            bkc = np.einsum("ij,ij->i", bc, kc)
            bbc = np.maximum(np.einsum("ij,ij->i", bc, bc), 1e-6)
            kkc = np.einsum("ij,ij->i", kc, kc)
            orth2, line2 = kkc - bkc * bkc / bbc, bbc - 2.0 * bkc + kkc
        else:
            orth2, line2 = kk - bk * bk / bb, bb - 2.0 * bk + kk
        contrast2 = cfg.min_unmix_contrast**2
        weak = orth2 < contrast2
        if weak.any():
            frac2 = (pb - pk - bk + kk) / np.maximum(bb - 2.0 * bk + kk, 1e-6)
            hard = mask[ys, xs].astype(np.float64)
            frac = np.where(weak, np.where(line2 >= contrast2, frac2, hard), frac)
        lo, hi = cfg.membership_clip
        frac = np.clip(frac, lo, hi)
        # Filled pixels (a highlight, notch or hole closed in the mask) are object by
        # topology, whatever their colour says.
        frac[filled[ys, xs] > 0] = 1.0
        return np.asarray(frac, dtype=np.float32)

    def _local_colours(
        self,
        img: np.ndarray,
        source: np.ndarray,
        outer: np.ndarray,
        ys: np.ndarray,
        xs: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """At each rim pixel ``(ys, xs)`` of ``img`` (H, W, 3 float32): the
        Gaussian-weighted mean colour of the object samples (``source``) and its spread
        (the trace of the covariance, colour units²), and the same of the background
        samples (``outer``); the mean over the whole crop where no sample is in reach."""
        cfg = self.config
        sq = np.einsum("ijk,ijk->ij", img, img)
        stack = np.empty((*img.shape[:2], 10), np.float32)
        for w, at0 in ((source, 0), (outer, 5)):
            wf = w.astype(np.float32)
            stack[..., at0 : at0 + 3] = img * wf[..., None]
            stack[..., at0 + 3] = wf
            stack[..., at0 + 4] = sq * wf
        blur = cv2.GaussianBlur(
            stack, self._ksize, cfg.colour_sigma_px, borderType=cv2.BORDER_CONSTANT
        )
        at = blur[ys, xs].astype(np.float64)
        for w_at in (3, 8):
            far = ~(at[:, w_at] > 1e-3)
            if far.any():  # out of reach of every sample: the mean over the whole crop
                totals = stack[..., w_at - 3 : w_at + 2].reshape(-1, 5).sum(axis=0)
                at[far, w_at - 3 : w_at + 2] = totals
        out: list[np.ndarray] = []
        for w_at in (3, 8):
            wsum = np.maximum(at[:, w_at], 1e-6)
            mean = at[:, w_at - 3 : w_at] / wsum[:, None]
            spread2 = np.maximum(at[:, w_at + 1] / wsum - np.einsum("ij,ij->i", mean, mean), 0.0)
            out += [mean, spread2]
        return out[0], out[1], out[2], out[3]


def _one_per_object(
    hue: list[Detection], lab: list[tuple[int, Detection]], wrap_width: int
) -> list[Detection]:
    """The hue targets' detections and the Lab targets' (target index, detection), one
    per object. Lab targets that differ mostly in lightness see each other's objects (a
    grey object's shaded side is dark grey), so a Lab detection is dropped when it and a
    kept detection of another target (any hue one, or a better-scoring Lab one) hold
    each other's centroid in their boxes. Hue detections are kept as they are (as before
    Lab targets existed), and a target's own detections are distinct objects."""
    kept: list[tuple[int, Detection]] = [(-1, d) for d in hue]
    for i, d in sorted(lab, key=lambda item: item[1].score, reverse=True):
        if not any(
            j != i
            and (
                _inside(d.centroid_px, k.bbox_px, wrap_width)
                or _inside(k.centroid_px, d.bbox_px, wrap_width)
            )
            for j, k in kept
        ):
            kept.append((i, d))
    return [d for _, d in kept]


def _inside(point: tuple[float, float], box: tuple[int, int, int, int], wrap_width: int) -> bool:
    """Whether a pixel point lies in a detection's box; on a full panorama
    (``wrap_width`` its width, else 0) a box may run past the right edge."""
    x, y = point
    x0, y0, x1, y1 = box
    return y0 <= y <= y1 and (x0 <= x <= x1 or x0 <= x + wrap_width <= x1)


def _u8(a: np.ndarray | cv2.typing.MatLike) -> NDArray[np.uint8]:
    """An OpenCV result as a uint8 array (no copy; typed for the bit operations)."""
    return np.asarray(a, dtype=np.uint8)


def _fill_holes(mask: np.ndarray) -> None:
    """Fill, in place, background regions of a 0/1 mask not connected to its border."""
    padded = cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    cv2.floodFill(padded, None, (0, 0), 2, flags=4)
    mask[padded[1:-1, 1:-1] == 0] = 1
