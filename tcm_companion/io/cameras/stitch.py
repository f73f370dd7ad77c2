"""Stitch the paper's two back-to-back fisheye cameras into the equirectangular panorama.

Everything geometric happens once, at construction: every panorama pixel centre gets its
body-frame bearing (``panorama.R_body_from_cam @ bearing_cam``), each lens's pixel for
that bearing (through the lens's mount and :class:`~tcm_companion.core.camera.Fisheye`
model, so the maps agree with ``cv2.fisheye``) and a blend weight. The tables are then
converted to OpenCV's fixed-point form (``cv2.convertMaps(..., CV_16SC2)``), so a frame
costs two ``cv2.remap`` calls plus a blend of the few pixels of the seam band.

Which lens a panorama pixel comes from: the one whose optical axis is nearer (the
equal-angle boundary, a great circle half-way between the axes, e.g. ±90° azimuth for
lenses yawed 0° and 180°). Across a band of ``blend_deg`` centred on that boundary the
two lenses are cross-faded (a smoothstep of the distance to the boundary, half the
difference of the two off-axis angles), so exposure or calibration differences leave no visible seam. A pixel only one lens
sees takes that lens whatever the weight; a pixel neither sees is black and ``False``
in :attr:`FisheyeStitcher.coverage_mask`.

A lens sees a direction when it lies within its field of view (``fov_deg``; by default
the image circle inscribed in the image, as on a circular-fisheye rig) and its pixel
lies inside the image far enough for bilinear interpolation.

Pixel coordinates follow ``tcm-scenario/1`` (pixel centres at ``i + 0.5``); OpenCV's
maps have centres at integers, hence the ``- 0.5`` where the tables are built.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from ...core.camera import CameraModelError, Equirectangular, Fisheye, camera_from_dict
from ...core.frames import FloatArray

__all__ = ["FisheyeStitcher", "bench"]

#: Map coordinate for "this lens does not supply this pixel": far outside any image, so
#: ``cv2.remap`` with ``BORDER_TRANSPARENT`` leaves the destination pixel alone.
_OUTSIDE = -64.0
_SEAM_COLS = 1024  # compact seam maps are laid out in rows of this many pixels
_WEIGHT_ONE = 256  # blend weights are fixed point, 8 fractional bits

_CALIBRATION_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "dist", "mount_rpy_deg")
_OPTIONAL_KEYS = ("fov_deg", "model")


class _LensTable:
    """One lens's view of the panorama: pixel per panorama pixel and off-axis angle."""

    def __init__(
        self, lens: Fisheye, bearing_body: FloatArray, pano_valid: np.ndarray, fov_deg: float | None
    ) -> None:
        # v_cam = R_body_from_cam.T @ v_body, i.e. row vectors times R_body_from_cam.
        bearing_cam = bearing_body @ lens.R_body_from_cam
        uv = lens.pixel_from_bearing_cam(bearing_cam)
        self.theta_limit_rad = _theta_limit_rad(lens, fov_deg)
        with np.errstate(invalid="ignore"):
            self.theta_rad = np.arccos(np.clip(bearing_cam[..., 0], -1.0, 1.0))
            # Bilinear interpolation needs the pixel centres on both sides: [0.5, W - 0.5].
            inside = (
                (uv[..., 0] >= 0.5)
                & (uv[..., 0] <= lens.width - 0.5)
                & (uv[..., 1] >= 0.5)
                & (uv[..., 1] <= lens.height - 0.5)
            )
            self.seen = np.asarray(pano_valid & inside & (self.theta_rad <= self.theta_limit_rad))
        self.uv = np.where(self.seen[..., None], uv, np.nan)


def _theta_limit_rad(lens: Fisheye, fov_deg: float | None) -> float:
    """Largest off-axis angle the lens sees: half its field of view, or by default the
    image circle inscribed in the image (never beyond the model's own limit)."""
    if fov_deg is not None:
        if not (math.isfinite(fov_deg) and 0.0 < fov_deg <= 360.0):
            raise ValueError(f"fov_deg must lie in (0, 360], got {fov_deg!r}")
        return min(math.radians(fov_deg) / 2.0, lens.theta_max_rad)
    # Normalised radius (θd) of the largest circle about (cx, cy) inside [0.5, W - 0.5].
    theta_d = min(
        (lens.cx - 0.5) / lens.fx,
        (lens.width - 0.5 - lens.cx) / lens.fx,
        (lens.cy - 0.5) / lens.fy,
        (lens.height - 0.5 - lens.cy) / lens.fy,
    )
    if theta_d <= 0.0:
        return 0.0
    edge = lens.bearing_cam_from_pixel(np.array([lens.cx + theta_d * lens.fx, lens.cy]))
    if not np.isfinite(edge[0]):
        return lens.theta_max_rad
    return float(np.arccos(np.clip(edge[0], -1.0, 1.0)))


def _fixed_point(uv: FloatArray, use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV fixed-point maps (CV_16SC2 + interpolation table) of ``uv`` where ``use``."""
    map_x = np.where(use, uv[..., 0] - 0.5, _OUTSIDE).astype(np.float32)
    map_y = np.where(use, uv[..., 1] - 0.5, _OUTSIDE).astype(np.float32)
    m1, m2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    return m1, m2


def _compact(values: FloatArray, rows: int) -> FloatArray:
    """(N, …) values padded with ``_OUTSIDE`` and laid out as (rows, _SEAM_COLS, …)."""
    n = values.shape[0]
    out = np.full((rows * _SEAM_COLS, *values.shape[1:]), _OUTSIDE, dtype=np.float64)
    out[:n] = values
    return out.reshape(rows, _SEAM_COLS, *values.shape[1:])


def _smoothstep(x: FloatArray) -> FloatArray:
    t = np.clip(x, 0.0, 1.0)
    return np.asarray(t * t * (3.0 - 2.0 * t))


class FisheyeStitcher:
    """Two fisheye images → one equirectangular panorama through precomputed remap tables.

    ``front`` and ``back`` are the two lenses (their mounts place them in the body frame;
    back-to-back means yaw 0° and 180°), ``panorama`` the output model (its mount too).
    ``blend_deg`` is the width of the cross-fade band around the equal-angle boundary
    (0: a hard seam). ``front_fov_deg`` / ``back_fov_deg`` limit each lens to its field
    of view; ``None`` takes the image circle inscribed in the image.

    Attributes: ``front``, ``back``, ``panorama``; ``coverage_mask`` (H, W) bool, the
    panorama pixels at least one lens sees; ``weight_front`` (H, W) float in [0, 1], the
    front lens's share of each covered pixel (0 where uncovered); ``front_uv`` and
    ``back_uv`` (H, W, 2), each lens's continuous pixel coordinates of every panorama
    pixel it sees (NaN elsewhere); ``seam_pixels``, how many pixels are blended.
    """

    def __init__(
        self,
        front: Fisheye,
        back: Fisheye,
        panorama: Equirectangular,
        blend_deg: float = 4.0,
        *,
        front_fov_deg: float | None = None,
        back_fov_deg: float | None = None,
    ) -> None:
        for name, lens in (("front", front), ("back", back)):
            if not isinstance(lens, Fisheye):
                raise TypeError(f"{name} must be a Fisheye model, got {type(lens).__name__}")
        if not isinstance(panorama, Equirectangular):
            raise TypeError(
                f"panorama must be an Equirectangular model, got {type(panorama).__name__}"
            )
        if not (math.isfinite(blend_deg) and blend_deg >= 0.0):
            raise ValueError(f"blend_deg must be a non-negative number, got {blend_deg!r}")
        self.front = front
        self.back = back
        self.panorama = panorama
        self.blend_deg = float(blend_deg)

        pano_valid = np.asarray(panorama.valid_mask)
        bearing_body = panorama.bearing_map_cam @ panorama.R_body_from_cam.T
        tf = _LensTable(front, bearing_body, pano_valid, front_fov_deg)
        tb = _LensTable(back, bearing_body, pano_valid, back_fov_deg)
        self.front_uv: FloatArray = tf.uv
        self.back_uv: FloatArray = tb.uv
        self.front_theta_limit_deg = math.degrees(tf.theta_limit_rad)
        self.back_theta_limit_deg = math.degrees(tb.theta_limit_rad)

        # Front's share: 1 well inside its half, 0 well inside the back's, smoothstep
        # across the band. Half the difference of the off-axis angles is the angular
        # distance to the equal-angle boundary (exactly so for opposite axes), so the
        # band is blend_deg wide on the sphere.
        with np.errstate(invalid="ignore"):
            dist_deg = np.nan_to_num(np.degrees(tb.theta_rad - tf.theta_rad) / 2.0)
        if self.blend_deg > 0.0:
            w = _smoothstep(0.5 + dist_deg / self.blend_deg)
        else:
            w = (dist_deg >= 0.0).astype(np.float64)
        both = tf.seen & tb.seen
        w = np.where(both, w, np.where(tf.seen, 1.0, 0.0))
        self.coverage_mask: np.ndarray = np.asarray(tf.seen | tb.seen)
        self.weight_front: FloatArray = np.where(self.coverage_mask, w, 0.0)

        w_fixed = np.rint(w * _WEIGHT_ONE).astype(np.int32)
        seam = both & (w_fixed > 0) & (w_fixed < _WEIGHT_ONE)
        use_front = tf.seen & (w_fixed * 2 >= _WEIGHT_ONE)
        use_back = tb.seen & ~use_front
        self._front_maps = _fixed_point(tf.uv, use_front & ~seam)
        self._back_maps = _fixed_point(tb.uv, use_back & ~seam)

        # The seam band: both lenses sampled on compact maps, blended, scattered back.
        idx = np.flatnonzero(seam)
        self.seam_pixels = int(idx.size)
        self._seam_idx = idx
        rows = max(1, -(-idx.size // _SEAM_COLS))
        filled = (np.arange(rows * _SEAM_COLS) < idx.size).reshape(rows, _SEAM_COLS)
        self._seam_front_maps = _fixed_point(_compact(tf.uv.reshape(-1, 2)[idx], rows), filled)
        self._seam_back_maps = _fixed_point(_compact(tb.uv.reshape(-1, 2)[idx], rows), filled)
        wf = w_fixed.reshape(-1)[idx].astype(np.uint16)[:, None]
        self._seam_w_front = wf
        self._seam_w_back = (_WEIGHT_ONE - wf).astype(np.uint16)
        self._front_shape = (front.height, front.width, 3)
        self._back_shape = (back.height, back.width, 3)
        self._out_shape = (panorama.height, panorama.width, 3)

    # -- per frame -----------------------------------------------------------------------
    def stitch(self, front_bgr: np.ndarray, back_bgr: np.ndarray) -> np.ndarray:
        """The panorama (H, W, 3) ``uint8`` of two BGR ``uint8`` fisheye images.

        Raises ``ValueError`` naming the image whose size or type is wrong.
        """
        _check_image("front", front_bgr, self._front_shape)
        _check_image("back", back_bgr, self._back_shape)
        out = np.zeros(self._out_shape, dtype=np.uint8)
        for img, (m1, m2) in ((front_bgr, self._front_maps), (back_bgr, self._back_maps)):
            cv2.remap(img, m1, m2, cv2.INTER_LINEAR, dst=out, borderMode=cv2.BORDER_TRANSPARENT)
        n = self.seam_pixels
        if n:
            sf = cv2.remap(front_bgr, *self._seam_front_maps, cv2.INTER_LINEAR)
            sb = cv2.remap(back_bgr, *self._seam_back_maps, cv2.INTER_LINEAR)
            a = sf.reshape(-1, 3)[:n].astype(np.uint16)
            b = sb.reshape(-1, 3)[:n].astype(np.uint16)
            a *= self._seam_w_front
            b *= self._seam_w_back
            a += b
            a += _WEIGHT_ONE // 2
            a >>= 8
            out.reshape(-1, 3)[self._seam_idx] = a
        return out

    # -- construction from a calibration file ------------------------------------------
    @classmethod
    def from_calibration(
        cls,
        front: Mapping[str, Any],
        back: Mapping[str, Any],
        panorama_size: tuple[int, int] = (360, 220),
        blend_deg: float = 4.0,
    ) -> FisheyeStitcher:
        """A stitcher from two calibration tables and the paper's 360°×150° panorama.

        Each table holds ``width, height, fx, fy, cx, cy, dist = [k1, k2, k3, k4]`` and
        ``mount_rpy_deg = [roll, pitch, yaw]`` (back-to-back: yaw 0 and 180), optionally
        ``fov_deg``. ``panorama_size`` is ``(width, height)``. Errors are ``ValueError``
        naming the key, e.g. ``back.fx``.
        """
        lenses: list[Fisheye] = []
        fovs: list[float | None] = []
        for where, table in (("front", front), ("back", back)):
            lens, fov = _lens_from_table(table, where)
            lenses.append(lens)
            fovs.append(fov)
        size = tuple(panorama_size)
        if len(size) != 2 or not all(
            isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size
        ):
            raise ValueError(
                f"panorama_size must be two positive integers (width, height), got {panorama_size!r}"
            )
        return cls(
            lenses[0],
            lenses[1],
            Equirectangular(int(size[0]), int(size[1])),
            blend_deg,
            front_fov_deg=fovs[0],
            back_fov_deg=fovs[1],
        )


def _check_image(name: str, img: object, shape: tuple[int, int, int]) -> None:
    expected = f"expected {shape} uint8 ({shape[1]}x{shape[0]} BGR)"
    if not isinstance(img, np.ndarray):
        raise ValueError(f"{name} image is a {type(img).__name__}, {expected}")
    if img.shape != shape or img.dtype != np.uint8:
        raise ValueError(f"{name} image has shape {img.shape} {img.dtype}, {expected}")


def _lens_from_table(table: Mapping[str, Any], where: str) -> tuple[Fisheye, float | None]:
    if not isinstance(table, Mapping):
        raise ValueError(f"{where} must be a table of calibration keys, got {type(table).__name__}")
    for key in table:
        if key not in _CALIBRATION_KEYS and key not in _OPTIONAL_KEYS:
            raise ValueError(
                f"{where}.{key}: unknown key (expected {', '.join(_CALIBRATION_KEYS)}"
                f" and optionally fov_deg)"
            )
    for key in _CALIBRATION_KEYS:
        if key not in table:
            raise ValueError(f"{where}.{key} is missing")
    if table.get("model", "fisheye") != "fisheye":
        raise ValueError(f"{where}.model must be 'fisheye', got {table['model']!r}")
    dist = table["dist"]
    if not isinstance(dist, list | tuple) or len(dist) != 4:
        raise ValueError(f"{where}.dist must be four numbers [k1, k2, k3, k4], got {dist!r}")
    try:
        lens = camera_from_dict({**table, "model": "fisheye"}, where=where)
    except CameraModelError as exc:
        raise ValueError(str(exc)) from None
    assert isinstance(lens, Fisheye)
    fov = table.get("fov_deg")
    if fov is not None:
        if (
            not isinstance(fov, int | float)
            or isinstance(fov, bool)
            or not (math.isfinite(fov) and 0.0 < fov <= 360.0)
        ):
            raise ValueError(f"{where}.fov_deg must be a number in (0, 360], got {fov!r}")
        fov = float(fov)
    return lens, fov


def bench(
    stitcher: FisheyeStitcher | None = None, repeats: int = 200, threads: int = 1
) -> dict[str, float]:
    """Time :meth:`FisheyeStitcher.stitch` on random images; median and p99 in ms.

    Default: the paper's 360×220 panorama from two 640×640 200° lenses back-to-back.
    OpenCV runs on ``threads`` threads (1: the one-core budget) and is restored after.
    """
    if stitcher is None:
        stitcher = FisheyeStitcher(*_demo_lenses(), Equirectangular(360, 220))
    rng = np.random.default_rng(0)
    f = rng.integers(0, 256, (stitcher.front.height, stitcher.front.width, 3), dtype=np.uint8)
    b = rng.integers(0, 256, (stitcher.back.height, stitcher.back.width, 3), dtype=np.uint8)
    old = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        for _ in range(10):
            stitcher.stitch(f, b)
        times = np.empty(repeats)
        for i in range(repeats):
            t0 = time.perf_counter()
            stitcher.stitch(f, b)
            times[i] = time.perf_counter() - t0
    finally:
        cv2.setNumThreads(old)
    return {
        "median_ms": float(np.median(times) * 1e3),
        "p99_ms": float(np.percentile(times, 99) * 1e3),
        "seam_pixels": float(stitcher.seam_pixels),
    }


def _demo_lenses(size: int = 640, fov_deg: float = 200.0) -> tuple[Fisheye, Fisheye]:
    """Two equidistant lenses whose ``fov_deg`` image circle fills a ``size``² image."""
    f = (size / 2.0 - 0.5) / math.radians(fov_deg / 2.0)
    c = size / 2.0
    return (
        Fisheye(size, size, (0.0, 0.0, 0.0), fx=f, fy=f, cx=c, cy=c),
        Fisheye(size, size, (0.0, 0.0, 180.0), fx=f, fy=f, cx=c, cy=c),
    )


if __name__ == "__main__":  # python -m tcm_companion.io.cameras.stitch
    result = bench()
    print(
        f"stitch 2x640x640 -> 360x220, 1 thread: median {result['median_ms']:.3f} ms, "
        f"p99 {result['p99_ms']:.3f} ms, {int(result['seam_pixels'])} seam pixels"
    )
