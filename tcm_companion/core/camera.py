"""Camera models of the scenario format: equirectangular, pinhole and fisheye.

Pixel coordinates are continuous with ``(0, 0)`` at the top-left corner of the
top-left pixel (pixel centres at ``i + 0.5``), exactly as ``tcm-scenario/1`` defines
them; this is half a pixel off OpenCV's convention, so :meth:`CameraModel.cv_camera_matrix`
shifts the principal point for OpenCV calls.

Bearings are unit vectors in camera FRD (x along the optical axis or the panorama's
centre column, y right, z down). Every mapping is vectorised over leading axes and
returns NaN where the geometry is undefined (behind a pinhole, outside a fisheye's field
of view, outside a partial panorama) instead of raising, so the hot path never branches.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from .frames import R_CAM_FROM_CV, R_CV_FROM_CAM, FloatArray, cross3, mount_rotation, normalize

_NEWTON_ITERATIONS = 30


class CameraModelError(ValueError):
    """A camera description is incomplete or inconsistent (names the key at fault)."""


@dataclass(frozen=True)
class CameraModel(ABC):
    """Common part of every model: image size and the mount in the body frame."""

    width: int
    height: int
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    model_name: str = field(init=False, default="")

    # -- the two mappings every model defines -------------------------------------
    @abstractmethod
    def bearing_cam_from_pixel(self, pixel_uv: FloatArray) -> FloatArray:
        """Unit bearings (…, 3) in camera FRD of continuous pixel coordinates (…, 2)."""

    @abstractmethod
    def pixel_from_bearing_cam(self, bearing_cam: FloatArray) -> FloatArray:
        """Continuous pixel coordinates (…, 2) of bearings (…, 3) in camera FRD.

        Bearings need not be unit length. NaN where the model cannot see the direction;
        coordinates outside the image are returned as they are (callers check bounds).
        """

    # -- derived -------------------------------------------------------------------
    @cached_property
    def R_body_from_cam(self) -> FloatArray:
        """Mount rotation, ``v_body = R_body_from_cam @ v_cam``."""
        return mount_rotation(self.mount_rpy_deg)

    @cached_property
    def bearing_map_cam(self) -> FloatArray:
        """Bearing (H, W, 3) at every pixel centre, camera FRD; NaN outside the view."""
        u = np.arange(self.width, dtype=np.float64) + 0.5
        v = np.arange(self.height, dtype=np.float64) + 0.5
        uu, vv = np.meshgrid(u, v)
        return self.bearing_cam_from_pixel(np.stack([uu, vv], axis=-1))

    @cached_property
    def solid_angle_map_sr(self) -> FloatArray:
        """Solid angle (H, W) in steradians that each pixel covers; 0 outside the view."""
        u = np.arange(self.width + 1, dtype=np.float64)
        v = np.arange(self.height + 1, dtype=np.float64)
        uu, vv = np.meshgrid(u, v)
        c = self.bearing_cam_from_pixel(np.stack([uu, vv], axis=-1))
        a, b, cc, d = c[:-1, :-1], c[:-1, 1:], c[1:, 1:], c[1:, :-1]
        omega = _triangle_solid_angle(a, b, cc) + _triangle_solid_angle(a, cc, d)
        omega = np.where(np.isfinite(omega), omega, 0.0)
        return np.where(np.isfinite(self.bearing_map_cam[..., 0]), omega, 0.0)

    @cached_property
    def valid_mask(self) -> np.ndarray:
        """Boolean (H, W): pixel centres that carry a bearing."""
        return np.asarray(np.isfinite(self.bearing_map_cam[..., 0]))

    @cached_property
    def pixel_size_map_rad(self) -> FloatArray:
        """Approximate angular size (H, W) of each pixel, ``sqrt(solid angle)``."""
        return np.sqrt(self.solid_angle_map_sr)

    def in_image(self, pixel_uv: FloatArray) -> np.ndarray:
        """Boolean (…,): finite coordinates inside ``[0, W) × [0, H)``."""
        p = np.asarray(pixel_uv, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            return np.asarray(
                (p[..., 0] >= 0)
                & (p[..., 0] < self.width)
                & (p[..., 1] >= 0)
                & (p[..., 1] < self.height)
            )

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same lens at another resolution (intrinsics scale with the image)."""
        return _scale_model(self, width, height)

    def to_dict(self) -> dict[str, Any]:
        """The ``[camera]`` table of ``scenario.toml`` for this model."""
        return {
            "model": self.model_name,
            "width": self.width,
            "height": self.height,
            "mount_rpy_deg": list(self.mount_rpy_deg),
            **self._lens_dict(),
        }

    @abstractmethod
    def _lens_dict(self) -> dict[str, Any]:
        """The model's own keys of :meth:`to_dict`."""


def _triangle_solid_angle(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Solid angle of spherical triangles with unit-vector corners (Van Oosterom–Strackee)."""
    num = np.abs(np.sum(a * cross3(b, c), axis=-1))
    den = 1.0 + np.sum(a * b, axis=-1) + np.sum(b * c, axis=-1) + np.sum(c * a, axis=-1)
    return 2.0 * np.arctan2(num, den)


@dataclass(frozen=True)
class Equirectangular(CameraModel):
    """Panorama: column maps linearly to azimuth, row to elevation (degrees in the file)."""

    azimuth_min_deg: float = -180.0
    azimuth_max_deg: float = 180.0
    elevation_max_deg: float = 75.0
    elevation_min_deg: float = -75.0
    model_name: str = field(init=False, default="equirectangular")

    def __post_init__(self) -> None:
        # Each message names one key ("camera." is replaced by the caller's location).
        if not self.azimuth_max_deg > self.azimuth_min_deg:
            raise CameraModelError(
                f"camera.azimuth_max_deg = {self.azimuth_max_deg:g} must exceed "
                f"azimuth_min_deg = {self.azimuth_min_deg:g}"
            )
        if self.azimuth_max_deg - self.azimuth_min_deg > 360.0 + 1e-9:
            raise CameraModelError(
                f"camera.azimuth_max_deg = {self.azimuth_max_deg:g} must be at most 360 "
                f"above azimuth_min_deg = {self.azimuth_min_deg:g}"
            )
        for name in ("elevation_max_deg", "elevation_min_deg"):
            value = getattr(self, name)
            if not -90.0 <= value <= 90.0:
                raise CameraModelError(f"camera.{name} must lie within [-90, 90], got {value:g}")
        if not self.elevation_max_deg > self.elevation_min_deg:
            raise CameraModelError(
                f"camera.elevation_max_deg = {self.elevation_max_deg:g} must exceed "
                f"elevation_min_deg = {self.elevation_min_deg:g}"
            )

    @property
    def _az_span_rad(self) -> float:
        return math.radians(self.azimuth_max_deg - self.azimuth_min_deg)

    @property
    def _full_circle(self) -> bool:
        return abs(self.azimuth_max_deg - self.azimuth_min_deg - 360.0) < 1e-9

    def bearing_cam_from_pixel(self, pixel_uv: FloatArray) -> FloatArray:
        p = np.asarray(pixel_uv, dtype=np.float64)
        az = math.radians(self.azimuth_min_deg) + (p[..., 0] / self.width) * self._az_span_rad
        el_max, el_min = math.radians(self.elevation_max_deg), math.radians(self.elevation_min_deg)
        el = el_max - (p[..., 1] / self.height) * (el_max - el_min)
        ce = np.cos(el)
        # Written into one array (np.stack's generic bookkeeping costs more than the
        # arithmetic for the few hundred flow points per frame).
        out = np.empty((*ce.shape, 3))
        np.multiply(ce, np.cos(az), out=out[..., 0])
        np.multiply(ce, np.sin(az), out=out[..., 1])
        np.negative(np.sin(el), out=out[..., 2])
        return out

    @cached_property
    def solid_angle_map_sr(self) -> FloatArray:
        """Exact per-pixel solid angle: ``Δaz · (sin el_top - sin el_bottom)``."""
        el_max, el_min = math.radians(self.elevation_max_deg), math.radians(self.elevation_min_deg)
        edges = el_max - np.arange(self.height + 1) / self.height * (el_max - el_min)
        row = (self._az_span_rad / self.width) * (np.sin(edges[:-1]) - np.sin(edges[1:]))
        return np.repeat(row[:, None], self.width, axis=1)

    def pixel_from_bearing_cam(self, bearing_cam: FloatArray) -> FloatArray:
        b = np.asarray(bearing_cam, dtype=np.float64)
        az = np.arctan2(b[..., 1], b[..., 0])
        el = np.arctan2(-b[..., 2], np.hypot(b[..., 0], b[..., 1]))
        az_min = math.radians(self.azimuth_min_deg)
        rel = np.mod(az - az_min, 2.0 * math.pi)
        u = rel / self._az_span_rad * self.width
        el_max, el_min = math.radians(self.elevation_max_deg), math.radians(self.elevation_min_deg)
        v = (el_max - el) / (el_max - el_min) * self.height
        with np.errstate(invalid="ignore"):
            outside_az = np.zeros(u.shape, dtype=bool) if self._full_circle else u > self.width
            bad = outside_az | (el > el_max + 1e-12) | (el < el_min - 1e-12)
        return np.stack([np.where(bad, np.nan, u), np.where(bad, np.nan, v)], axis=-1)

    def _lens_dict(self) -> dict[str, Any]:
        return {
            "azimuth_min_deg": self.azimuth_min_deg,
            "azimuth_max_deg": self.azimuth_max_deg,
            "elevation_max_deg": self.elevation_max_deg,
            "elevation_min_deg": self.elevation_min_deg,
        }


@dataclass(frozen=True)
class _Intrinsic(CameraModel):
    """Shared part of the two OpenCV models: focal lengths and principal point."""

    fx: float = 1.0
    fy: float = 1.0
    cx: float = 0.0
    cy: float = 0.0
    dist: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not value > 0:
                raise CameraModelError(f"camera.{name} must be positive, got {value!r}")

    def cv_camera_matrix(self) -> FloatArray:
        """OpenCV ``K`` (pixel centre at integer coordinates, so c - 0.5)."""
        return np.array(
            [[self.fx, 0.0, self.cx - 0.5], [0.0, self.fy, self.cy - 0.5], [0.0, 0.0, 1.0]]
        )

    def _to_normalised(self, pixel_uv: FloatArray) -> tuple[FloatArray, FloatArray]:
        p = np.asarray(pixel_uv, dtype=np.float64)
        return (p[..., 0] - self.cx) / self.fx, (p[..., 1] - self.cy) / self.fy

    def _from_normalised(self, x: FloatArray, y: FloatArray) -> FloatArray:
        return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)

    def _lens_dict(self) -> dict[str, Any]:
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "dist": list(self.dist),
        }


@dataclass(frozen=True)
class Pinhole(_Intrinsic):
    """OpenCV pinhole with ``dist = [k1, k2, p1, p2, k3]`` (Brown–Conrady)."""

    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    model_name: str = field(init=False, default="pinhole")

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.dist) != 5:
            raise CameraModelError("camera.dist for a pinhole must be [k1, k2, p1, p2, k3]")

    def _distort(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return xd, yd

    def _undistort(self, xd: FloatArray, yd: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Invert the distortion by Newton's method (converges to ~1e-15 in a few steps)."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xd.copy(), yd.copy()
        for _ in range(_NEWTON_ITERATIONS):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
            fx_ = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            fy_ = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            j11 = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
            j12 = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            j21 = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            j22 = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
            det = j11 * j22 - j12 * j21
            dx = (j22 * fx_ - j12 * fy_) / det
            dy = (-j21 * fx_ + j11 * fy_) / det
            x = x - dx
            y = y - dy
            if np.all(~np.isfinite(dx) | (np.abs(dx) + np.abs(dy) < 1e-15)):
                break
        return x, y

    def bearing_cam_from_pixel(self, pixel_uv: FloatArray) -> FloatArray:
        xd, yd = self._to_normalised(pixel_uv)
        x, y = self._undistort(np.asarray(xd), np.asarray(yd))
        v_cv = np.stack([x, y, np.ones_like(x)], axis=-1)
        return normalize(v_cv @ R_CAM_FROM_CV.T)

    def pixel_from_bearing_cam(self, bearing_cam: FloatArray) -> FloatArray:
        v_cv = np.asarray(bearing_cam, dtype=np.float64) @ R_CV_FROM_CAM.T
        z = v_cv[..., 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            zz = np.where(z > 0, z, np.nan)
            x, y = v_cv[..., 0] / zz, v_cv[..., 1] / zz
        xd, yd = self._distort(x, y)
        return self._from_normalised(xd, yd)


@dataclass(frozen=True)
class Fisheye(_Intrinsic):
    """OpenCV ``cv2.fisheye`` model, ``θd = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)``.

    θ is the angle from the optical axis. The model is used for θ up to the first
    turning point of θd(θ) (at most π), so lenses wider than 180° work too; beyond it
    pixels carry no bearing.
    """

    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    model_name: str = field(init=False, default="fisheye")

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.dist) != 4:
            raise CameraModelError("camera.dist for a fisheye must be [k1, k2, k3, k4]")

    def _theta_d(self, theta: FloatArray) -> FloatArray:
        k1, k2, k3, k4 = self.dist
        t2 = theta * theta
        return np.asarray(theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))))

    def _dtheta_d(self, theta: FloatArray) -> FloatArray:
        k1, k2, k3, k4 = self.dist
        t2 = theta * theta
        return np.asarray(1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4))))

    @cached_property
    def theta_max_rad(self) -> float:
        """Largest off-axis angle the model maps one-to-one (first turning point, ≤ π)."""
        grid = np.linspace(0.0, math.pi, 4097)
        bad = np.nonzero(self._dtheta_d(grid) <= 0.0)[0]
        return float(grid[bad[0] - 1]) if bad.size else math.pi

    def bearing_cam_from_pixel(self, pixel_uv: FloatArray) -> FloatArray:
        mx, my = self._to_normalised(pixel_uv)
        theta_d = np.hypot(mx, my)
        theta_d_max = float(self._theta_d(np.asarray(self.theta_max_rad)))
        theta = np.minimum(theta_d, self.theta_max_rad)
        for _ in range(_NEWTON_ITERATIONS):
            step = (self._theta_d(theta) - theta_d) / self._dtheta_d(theta)
            theta = np.clip(theta - step, 0.0, self.theta_max_rad)
            if np.all(np.abs(step) < 1e-15):
                break
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(theta_d > 1e-15, np.sin(theta) / theta_d, 1.0)
        v_cv = np.stack([mx * scale, my * scale, np.cos(theta)], axis=-1)
        v_cv = np.where((theta_d <= theta_d_max)[..., None], v_cv, np.nan)
        return normalize(v_cv @ R_CAM_FROM_CV.T)

    def pixel_from_bearing_cam(self, bearing_cam: FloatArray) -> FloatArray:
        v_cv = np.asarray(bearing_cam, dtype=np.float64) @ R_CV_FROM_CAM.T
        rho = np.hypot(v_cv[..., 0], v_cv[..., 1])
        theta = np.arctan2(rho, v_cv[..., 2])
        theta_d = self._theta_d(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rho > 1e-300, theta_d / rho, 0.0)
            scale = np.where(theta <= self.theta_max_rad, scale, np.nan)
        return self._from_normalised(v_cv[..., 0] * scale, v_cv[..., 1] * scale)


def _scale_model(cam: CameraModel, width: int, height: int) -> CameraModel:
    if isinstance(cam, Equirectangular):
        return Equirectangular(
            width=width,
            height=height,
            mount_rpy_deg=cam.mount_rpy_deg,
            azimuth_min_deg=cam.azimuth_min_deg,
            azimuth_max_deg=cam.azimuth_max_deg,
            elevation_max_deg=cam.elevation_max_deg,
            elevation_min_deg=cam.elevation_min_deg,
        )
    if isinstance(cam, _Intrinsic):
        sx, sy = width / cam.width, height / cam.height
        return type(cam)(
            width=width,
            height=height,
            mount_rpy_deg=cam.mount_rpy_deg,
            fx=cam.fx * sx,
            fy=cam.fy * sy,
            cx=cam.cx * sx,
            cy=cam.cy * sy,
            dist=cam.dist,
        )
    raise TypeError(f"cannot scale {type(cam).__name__}")


_MODELS: dict[str, type[CameraModel]] = {
    "equirectangular": Equirectangular,
    "pinhole": Pinhole,
    "fisheye": Fisheye,
}

_KEYS: dict[str, tuple[str, ...]] = {
    "equirectangular": (
        "azimuth_min_deg",
        "azimuth_max_deg",
        "elevation_max_deg",
        "elevation_min_deg",
    ),
    "pinhole": ("fx", "fy", "cx", "cy", "dist"),
    "fisheye": ("fx", "fy", "cx", "cy", "dist"),
}


#: The valid range of each lens key of a camera table, as (low, high) in the key's unit;
#: ``"width"``/``"height"`` as a bound means that key's value. One home: ``config.py``
#: states and checks the same ranges for ``[camera]``, and :func:`camera_from_dict`
#: checks them for a scenario's ``scenario.toml``.
LENS_RANGES: dict[str, tuple[float, float | str, str]] = {
    # 16 px: the detector's coarse cells (8 px) and the flow's 9 px windows need a few of
    # each across; 16384: larger than any camera this runs, and below OpenCV's limit for
    # the remap that warps and stitches frames (32767 px).
    "width": (16, 16384, "px"),
    "height": (16, 16384, "px"),
    # At least a pixel: a 1-px focal length already sees ±89.8° across a 640-px pinhole
    # image; 1e5 px is a 0.4° field of view on 640 px.
    "fx": (1, 100000, "px"),
    "fy": (1, 100000, "px"),
    # Principal point within the image (scenario convention: width / 2 is the centre).
    "cx": (0, "width", "px"),
    "cy": (0, "height", "px"),
    # Calibrated lenses give |k| of order 1 (a wide lens's k3 reaches tens); beyond 100 is
    # a typo, or another model's coefficients.
    "dist": (-100, 100, ""),
    # Roll, pitch, yaw: any rotation; beyond a whole turn is a typo.
    "mount_rpy_deg": (-360, 360, "deg"),
}


def lens_range_text(key: str) -> str:
    """``LENS_RANGES[key]`` as ``config.py`` writes a range: ``"[1, 100000] px"``."""
    lo, hi, unit = LENS_RANGES[key]
    return f"[{lo:g}, {hi if isinstance(hi, str) else format(hi, 'g')}]" + (
        f" {unit}" if unit else ""
    )


def _check_lens_ranges(kwargs: Mapping[str, Any], where: str) -> None:
    for key, (lo, hi, _unit) in LENS_RANGES.items():
        if key not in kwargs:
            continue
        high = float(kwargs[hi]) if isinstance(hi, str) else float(hi)
        value = kwargs[key]
        for v in value if isinstance(value, tuple) else (value,):
            if not lo <= float(v) <= high:
                bound = f" ({hi} = {high:g})" if isinstance(hi, str) else ""
                shown = list(value) if isinstance(value, tuple) else value
                raise CameraModelError(
                    f"{where}.{key} = {shown} is out of range: must be in"
                    f" {lens_range_text(key)}{bound}"
                )


def camera_from_dict(table: Mapping[str, Any], where: str = "camera") -> CameraModel:
    """Build a model from a ``[camera]`` table; errors name the offending key.

    ``where`` prefixes key names in messages (e.g. ``"scenario.toml: camera"``).
    """
    model = table.get("model")
    if model not in _MODELS:
        raise CameraModelError(f"{where}.model must be one of {sorted(_MODELS)}, got {model!r}")
    kwargs: dict[str, Any] = {}
    for key in ("width", "height"):
        value = table.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise CameraModelError(f"{where}.{key} must be a positive integer, got {value!r}")
        kwargs[key] = value
    mount = table.get("mount_rpy_deg", [0.0, 0.0, 0.0])
    if (
        not isinstance(mount, list | tuple)
        or len(mount) != 3
        or not all(_is_number(m) for m in mount)
    ):
        raise CameraModelError(f"{where}.mount_rpy_deg must be three numbers [roll, pitch, yaw]")
    kwargs["mount_rpy_deg"] = tuple(float(m) for m in mount)
    for key in _KEYS[model]:
        if key not in table:
            if model == "equirectangular":
                continue  # the format's defaults apply (full 360° x 150° panorama)
            raise CameraModelError(f"{where}.{key} is required for a {model} camera")
        value = table[key]
        if key == "dist":
            if not isinstance(value, list | tuple) or not all(_is_number(d) for d in value):
                raise CameraModelError(f"{where}.dist must be a list of numbers")
            kwargs[key] = tuple(float(d) for d in value)
        else:
            if not _is_number(value):
                raise CameraModelError(f"{where}.{key} must be a number, got {value!r}")
            kwargs[key] = float(value)
    _check_lens_ranges(kwargs, where)
    try:
        return _MODELS[model](**kwargs)
    except CameraModelError as exc:
        raise CameraModelError(str(exc).replace("camera.", f"{where}.")) from None


def _is_number(x: object) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(float(x))
