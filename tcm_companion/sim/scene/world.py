"""The simulated field: what is in the scene and how it looks, as small frozen dataclasses.

The scene follows the paper's field test: flat grass at NED ``d = 0`` with stones, dirt
patches and a dirt path; a sky with a gradient, clouds, a sun disc and distant hills;
static clutter standing on the ground (trees = trunk cylinder + canopy spheres, thin
posts, a box building); and the target objects whose centres follow a
:class:`Trajectory`: saturated red balls (:class:`Ball`, the paper's) and objects of other
shapes (:class:`BoxTarget` — a car, a crate —, :class:`CylinderTarget` — a person, a post
—, :class:`DiscTarget` — a small drone), each with its albedo and a little specular
highlight if asked. Everything is in local NED metres; colours are *linear* RGB albedos
in [0, 1] (the renderer applies the lighting and the display gamma).

A target's own frame ("obj": x forward, y right, z down, origin at its centre) is the NED
frame turned by the target's yaw about the vertical (``R_ned_from_obj``); targets do not
pitch or roll. Their ``size_m`` is the extent along the object's own x, y, z, as in the
``[[target]]`` tables of the scenario format.

Everything here is hashable, so the procedural textures derived from a :class:`Ground`
or :class:`Sky` (:func:`ground_textures`, :func:`sky_textures`) are built once per
process and shared by every renderer.

The textures are what optic flow tracks: the detail layer has grass noise from 2 cm to
40 cm wavelengths and scattered stones (periodic, 20.48 m at 1 cm per texel, with a mip
chain for distant ground); the macro layer (160 m at 10 cm per texel) carries the slow
colour variation of the lawn, the dirt patches and the path. The dirt is desaturated
brown/orange on purpose: it is a distractor a red-ball detector must reject.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import ClassVar

import cv2
import numpy as np

from ...core.frames import FloatArray
from .texture_cache import cached_arrays

Vec3 = tuple[float, float, float]
Rgb = tuple[float, float, float]


def vec3(v: object) -> Vec3:
    """A 3-vector (sequence or array) as a tuple of floats."""
    a = np.asarray(v, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


#: Diameter 75 cm: the paper's ball.
BALL_RADIUS_M = 0.375
BALL_ALBEDO_RGB: Rgb = (0.75, 0.05, 0.05)


# --------------------------------------------------------------------------------------
# Motion
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SineTerm:
    """``amplitude_ned_m · sin(2π freq_hz t + phase_rad)``."""

    amplitude_ned_m: Vec3
    freq_hz: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class Trajectory:
    """A point moving as ``origin + v t + Σ A_k sin(2π f_k t + φ_k)`` (NED m, t in s).

    Closed form, so velocity and acceleration are exact; the methods accept a scalar
    time (returning shape (3,)) or an array of times (returning (N, 3)).
    """

    origin_ned_m: Vec3
    linear_velocity_ned_mps: Vec3 = (0.0, 0.0, 0.0)
    terms: tuple[SineTerm, ...] = ()

    @staticmethod
    def static(centre_ned_m: Vec3) -> Trajectory:
        return Trajectory(vec3(centre_ned_m))

    @staticmethod
    def oscillation(
        centre_ned_m: Vec3,
        direction_ned: Vec3,
        amplitude_m: float,
        freq_hz: float,
        phase_rad: float = 0.0,
    ) -> Trajectory:
        """Sinusoidal back-and-forth of ±``amplitude_m`` along ``direction_ned``."""
        d = np.asarray(direction_ned, dtype=np.float64)
        amp = vec3(amplitude_m * d / np.linalg.norm(d))
        return Trajectory(
            vec3(centre_ned_m), terms=(SineTerm(amp, float(freq_hz), float(phase_rad)),)
        )

    @staticmethod
    def linear(start_ned_m: Vec3, velocity_ned_mps: Vec3) -> Trajectory:
        return Trajectory(vec3(start_ned_m), vec3(velocity_ned_mps))

    @property
    def is_static(self) -> bool:
        return not self.terms and not any(self.linear_velocity_ned_mps)

    def _eval(self, t_s: float | FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        tt = t[..., None]
        if order == 0:
            out = np.asarray(self.origin_ned_m) + tt * np.asarray(self.linear_velocity_ned_mps)
        elif order == 1:
            out = np.broadcast_to(np.asarray(self.linear_velocity_ned_mps), (*t.shape, 3)).copy()
        else:
            out = np.zeros((*t.shape, 3))
        for term in self.terms:
            w = 2.0 * math.pi * term.freq_hz
            arg = w * tt + term.phase_rad
            amp = np.asarray(term.amplitude_ned_m)
            if order == 0:
                out = out + amp * np.sin(arg)
            elif order == 1:
                out = out + amp * w * np.cos(arg)
            else:
                out = out - amp * w * w * np.sin(arg)
        return np.asarray(out, dtype=np.float64)

    def position_ned_m(self, t_s: float | FloatArray) -> FloatArray:
        return self._eval(t_s, 0)

    def velocity_ned_mps(self, t_s: float | FloatArray) -> FloatArray:
        return self._eval(t_s, 1)

    def acceleration_ned_mps2(self, t_s: float | FloatArray) -> FloatArray:
        return self._eval(t_s, 2)


# --------------------------------------------------------------------------------------
# Objects
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Ball:
    """A target sphere: saturated red, 75 cm across unless told otherwise."""

    trajectory: Trajectory
    radius_m: float = BALL_RADIUS_M
    albedo_rgb: Rgb = BALL_ALBEDO_RGB
    object_id: int = 1

    @property
    def moving(self) -> bool:
        """True when the scenario moves the ball (an oscillating ball always counts)."""
        return not self.trajectory.is_static

    def centre_ned_m(self, t_s: float) -> FloatArray:
        return self.trajectory.position_ned_m(t_s)

    shape: ClassVar[str] = "sphere"
    label: ClassVar[str] = "ball"
    specular: ClassVar[float] = 0.08  # the renderer's fixed highlight of a ball

    @property
    def size_m(self) -> Vec3:
        """Extent along the object's own axes: the diameter, three times."""
        d = 2.0 * self.radius_m
        return (d, d, d)

    @property
    def bounding_radius_m(self) -> float:
        return self.radius_m

    def R_ned_from_obj(self, t_s: float) -> FloatArray:
        """A sphere's frame is NED's (it has no orientation to speak of)."""
        return np.eye(3)


#: Linear albedos of the target colours. Seen under unit irradiance through the
#: renderer's display gamma 2, a face shows ``255 · sqrt(albedo)`` (e.g. red ≈ 221, 57, 57).
COLOURS: dict[str, Rgb] = {
    "red": BALL_ALBEDO_RGB,
    "blue": (0.035, 0.085, 0.50),
    "yellow": (0.78, 0.60, 0.035),
    "white": (0.78, 0.78, 0.76),
    "dark_grey": (0.045, 0.045, 0.05),
    "orange": (0.80, 0.22, 0.02),
}


class _Solid:
    """What every non-spherical target shares: motion, yaw, bounding sphere, truth."""

    trajectory: Trajectory
    yaw_rad: float
    yaw_rate_radps: float
    yaw_follows_path: bool

    @property
    def moving(self) -> bool:
        """True when the scenario moves the object (an oscillating one always counts)."""
        return not self.trajectory.is_static

    def centre_ned_m(self, t_s: float) -> FloatArray:
        return self.trajectory.position_ned_m(t_s)

    def yaw_at_rad(self, t_s: float) -> float:
        """Heading of the object's x axis (clockwise from north) at time ``t_s``.

        ``yaw_follows_path``: the heading of the horizontal velocity (of the acceleration
        where the object stops, at the ends of an oscillation), so a car drives along its
        path; otherwise ``yaw_rad + yaw_rate_radps · t``.
        """
        if self.yaw_follows_path:
            v = self.trajectory.velocity_ned_mps(t_s)
            if math.hypot(float(v[0]), float(v[1])) > 0.05:
                return math.atan2(float(v[1]), float(v[0]))
            a = self.trajectory.acceleration_ned_mps2(t_s)
            if math.hypot(float(a[0]), float(a[1])) > 1e-6:
                return math.atan2(float(a[1]), float(a[0]))
            return self.yaw_rad
        return self.yaw_rad + self.yaw_rate_radps * t_s

    def R_ned_from_obj(self, t_s: float) -> FloatArray:
        """Rotation (3, 3) from the object's frame to NED: a yaw about the vertical."""
        yaw = self.yaw_at_rad(t_s)
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class BoxTarget(_Solid):
    """A box target (a car: 4.2 × 1.8 × 1.5 m by default), its length along its yaw.

    ``size_m`` is (length along x, width along y, height along z), centred on the
    trajectory's point (a car standing on the ground has its centre at ``d = -h/2``).
    """

    trajectory: Trajectory
    size_m: Vec3 = (4.2, 1.8, 1.5)
    albedo_rgb: Rgb = COLOURS["blue"]
    specular: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    yaw_follows_path: bool = False
    object_id: int = 1
    label: str = "car"
    shape: ClassVar[str] = "box"

    @property
    def half_extent_m(self) -> Vec3:
        return (self.size_m[0] / 2.0, self.size_m[1] / 2.0, self.size_m[2] / 2.0)

    @property
    def bounding_radius_m(self) -> float:
        return 0.5 * math.sqrt(sum(x * x for x in self.size_m))


@dataclass(frozen=True)
class CylinderTarget(_Solid):
    """An upright capped cylinder (a person: radius 0.25 m, 1.8 m tall, by default)."""

    trajectory: Trajectory
    radius_m: float = 0.25
    height_m: float = 1.8
    albedo_rgb: Rgb = COLOURS["yellow"]
    specular: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    yaw_follows_path: bool = False
    object_id: int = 1
    label: str = "person"
    shape: ClassVar[str] = "cylinder"

    @property
    def size_m(self) -> Vec3:
        return (2.0 * self.radius_m, 2.0 * self.radius_m, self.height_m)

    @property
    def bounding_radius_m(self) -> float:
        return math.hypot(self.radius_m, self.height_m / 2.0)


@dataclass(frozen=True)
class DiscTarget(_Solid):
    """A flat horizontal disc (a small drone: radius 0.3 m, 0.1 m thick, by default)."""

    trajectory: Trajectory
    radius_m: float = 0.3
    thickness_m: float = 0.1
    albedo_rgb: Rgb = COLOURS["dark_grey"]
    specular: float = 0.1
    yaw_rad: float = 0.0
    yaw_rate_radps: float = 0.0
    yaw_follows_path: bool = False
    object_id: int = 1
    label: str = "drone"
    shape: ClassVar[str] = "disc"

    @property
    def height_m(self) -> float:
        return self.thickness_m

    @property
    def size_m(self) -> Vec3:
        return (2.0 * self.radius_m, 2.0 * self.radius_m, self.thickness_m)

    @property
    def bounding_radius_m(self) -> float:
        return math.hypot(self.radius_m, self.thickness_m / 2.0)


#: Non-spherical targets (the renderer draws them with sub-sampled rays).
SolidTarget = BoxTarget | CylinderTarget | DiscTarget
#: Any target object: what truth.csv, ``[[target]]`` and the detector simulator describe.
Target = Ball | BoxTarget | CylinderTarget | DiscTarget


@dataclass(frozen=True)
class Sphere:
    """A static sphere (tree canopy); ``leafy`` gives it a surface texture."""

    centre_ned_m: Vec3
    radius_m: float
    albedo_rgb: Rgb
    leafy: bool = True


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder standing on the ground (trunk, post)."""

    base_ne_m: tuple[float, float]
    radius_m: float
    height_m: float
    albedo_rgb: Rgb


@dataclass(frozen=True)
class Box:
    """An axis-aligned box on the ground (a building), walls with windows, a dark roof."""

    min_ned_m: Vec3
    max_ned_m: Vec3
    wall_albedo_rgb: Rgb = (0.45, 0.43, 0.40)
    roof_albedo_rgb: Rgb = (0.14, 0.13, 0.14)
    window_albedo_rgb: Rgb = (0.03, 0.04, 0.06)


@dataclass(frozen=True)
class Tree:
    trunk: Cylinder
    canopy: tuple[Sphere, ...]


# --------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sun:
    """Directional light: irradiance on a surface facing it, plus sky ambient."""

    azimuth_deg: float = 215.0
    elevation_deg: float = 52.0
    irradiance: float = 1.0
    ambient: float = 0.35  # sky light on an upward-facing surface
    ground_bounce: float = 0.12  # light reflected up from the grass
    angular_radius_deg: float = 0.8  # drawn disc (larger than the real 0.27°, as a lens sees it)

    @property
    def direction_ned(self) -> FloatArray:
        """Unit vector from the scene towards the sun."""
        az, el = math.radians(self.azimuth_deg), math.radians(self.elevation_deg)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])


@dataclass(frozen=True)
class Sky:
    zenith_rgb: Rgb = (0.17, 0.33, 0.76)
    horizon_rgb: Rgb = (0.60, 0.70, 0.84)
    cloud_rgb: Rgb = (0.86, 0.88, 0.92)
    cloud_cover: float = 0.3  # fraction of the cloud layer that is cloud
    cloud_height_m: float = 1000.0
    hill_rgb: Rgb = (0.20, 0.30, 0.24)
    hill_height_deg: float = 1.6
    haze_distance_m: float = 350.0
    seed: int = 0


@dataclass(frozen=True)
class DirtPatch:
    centre_ne_m: tuple[float, float]
    radius_m: float
    albedo_rgb: Rgb


@dataclass(frozen=True)
class Ground:
    """Procedural grass: see the module docstring for the two texture layers."""

    seed: int = 0
    grass_rgb: Rgb = (0.11, 0.245, 0.048)
    dry_grass_rgb: Rgb = (0.21, 0.265, 0.066)
    stone_rgb: Rgb = (0.54, 0.53, 0.49)
    stones_per_m2: float = 2.0
    patches: tuple[DirtPatch, ...] = ()
    path_ne_m: tuple[tuple[float, float], ...] = ()
    path_width_m: float = 1.1
    path_rgb: Rgb = (0.33, 0.27, 0.16)
    extent_m: float = 160.0  # side of the macro texture, centred on the origin
    macro_texel_m: float = 0.1
    detail_texel_m: float = 0.01
    detail_px: int = 2048


@dataclass(frozen=True)
class World:
    ground: Ground = field(default_factory=Ground)
    sky: Sky = field(default_factory=Sky)
    sun: Sun = field(default_factory=Sun)
    trees: tuple[Tree, ...] = ()
    posts: tuple[Cylinder, ...] = ()
    buildings: tuple[Box, ...] = ()
    balls: tuple[Ball, ...] = ()
    targets: tuple[SolidTarget, ...] = ()

    def with_balls(self, balls: tuple[Ball, ...]) -> World:
        return replace(self, balls=tuple(balls))

    @property
    def objects(self) -> tuple[Target, ...]:
        """Every target object, balls and others, in ``object_id`` order."""
        return tuple(sorted((*self.balls, *self.targets), key=lambda o: o.object_id))


# --------------------------------------------------------------------------------------
# The paper's field
# --------------------------------------------------------------------------------------
def track_axes(heading_rad: float) -> tuple[FloatArray, FloatArray]:
    """Horizontal unit vectors (NED) along the track and to its right."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([c, s, 0.0]), np.array([-s, c, 0.0])


def field_world(
    balls: tuple[Ball, ...],
    heading_rad: float,
    seed: int = 0,
    keep_out_along_m: tuple[float, float] = (-18.0, 18.0),
    keep_out_right_m: tuple[float, float] = (-7.0, 14.0),
) -> World:
    """The field around a track through the origin along ``heading_rad``.

    Raised clutter (trees, posts, the building) stays outside the keep-out rectangle
    (in track coordinates, metres along the track and to its right) where the
    scenarios fly and move their balls, so it never hides a ball; flat distractors
    (dirt patches) are placed inside it too.
    """
    rng = np.random.default_rng(np.random.SeedSequence([7919, seed]))
    ax, rt = track_axes(heading_rad)

    def ne(along: float, right: float) -> tuple[float, float]:
        p = along * ax + right * rt
        return float(p[0]), float(p[1])

    def in_keep_out(along: float, right: float, margin: float) -> bool:
        return (
            keep_out_along_m[0] - margin < along < keep_out_along_m[1] + margin
            and keep_out_right_m[0] - margin < right < keep_out_right_m[1] + margin
        )

    trees: list[Tree] = []
    while len(trees) < 15:
        rng_m = rng.uniform(12.0, 42.0)
        bearing = rng.uniform(-math.pi, math.pi)
        along, right = rng_m * math.cos(bearing), rng_m * math.sin(bearing)
        if in_keep_out(along, right, 2.0):
            continue
        n, e = ne(along, right)
        trunk_h = float(rng.uniform(1.8, 2.8))
        trunk = Cylinder(
            (n, e), float(rng.uniform(0.13, 0.24)), trunk_h + 0.8, (0.11, 0.075, 0.045)
        )
        canopy = []
        crown_r = float(rng.uniform(1.2, 1.9))
        tint = float(rng.uniform(0.8, 1.2))
        for _ in range(int(rng.integers(2, 5))):
            off = rng.normal(0.0, 0.45, 3)
            r = crown_r * float(rng.uniform(0.7, 1.0))
            centre = (n + off[0], e + off[1], -(trunk_h + crown_r * 0.8 + abs(off[2])))
            canopy.append(Sphere(centre, r, (0.028 * tint, 0.085 * tint, 0.022 * tint), leafy=True))
        trees.append(Tree(trunk, tuple(canopy)))

    grey = (0.30, 0.30, 0.28)
    posts = (
        *(Cylinder(ne(along, -8.5), 0.045, 2.6, grey) for along in (-7.0, -1.0, 5.0)),
        Cylinder(ne(21.0, 4.0), 0.05, 2.4, grey),
    )

    bn, be = ne(17.0, -17.0)
    building = Box((bn - 4.0, be - 2.5, -3.5), (bn + 4.0, be + 2.5, 0.0))

    patches: list[DirtPatch] = []
    dirt_colours = [
        (0.30, 0.165, 0.095),
        (0.27, 0.17, 0.11),
        (0.31, 0.19, 0.11),
        (0.25, 0.15, 0.10),
    ]
    for i in range(36):
        if i < 6:  # distractors near the ball and the track
            along, right = rng.uniform(-7.0, 7.0), rng.uniform(1.0, 9.0)
        else:
            rr, bb = rng.uniform(3.0, 45.0), rng.uniform(-math.pi, math.pi)
            along, right = rr * math.cos(bb), rr * math.sin(bb)
        colour = dirt_colours[int(rng.integers(len(dirt_colours)))]
        patches.append(DirtPatch(ne(along, right), float(rng.uniform(0.35, 1.8)), colour))

    path = tuple(
        ne(a, r)
        for a, r in [
            (-80, -20),
            (-40, -9),
            (-15, -6),
            (0, -5.5),
            (12, -6.5),
            (28, -12),
            (50, -26),
            (80, -50),
        ]
    )
    ground = Ground(seed=seed, patches=tuple(patches), path_ne_m=path)
    return World(
        ground=ground,
        sky=Sky(seed=seed),
        sun=Sun(),
        trees=tuple(trees),
        posts=posts,
        buildings=(building,),
        balls=tuple(balls),
    )


# --------------------------------------------------------------------------------------
# Procedural textures
# --------------------------------------------------------------------------------------
def _band_noise(
    shape: tuple[int, int],
    rng: np.random.Generator,
    wavelength_min_px: float,
    wavelength_max_px: float,
    slope: float = 1.0,
) -> np.ndarray:
    """Periodic band-limited noise with unit standard deviation (float32).

    White noise filtered in the Fourier domain: amplitude ∝ ``|k|^-slope`` between the
    two wavelengths, smooth roll-off outside; periodic by construction so it tiles.
    """
    h, w = shape
    white = rng.standard_normal(shape).astype(np.float32)
    import scipy.fft  # here: textures usually come from the cache (texture_cache.py)

    spec = scipy.fft.rfft2(white)
    ky = np.fft.fftfreq(h).astype(np.float32)[:, None]
    kx = np.fft.rfftfreq(w).astype(np.float32)[None, :]
    k2 = kx * kx + ky * ky
    k2[0, 0] = 1e-18
    k_lo2, k_hi2 = np.float32(wavelength_max_px**2), np.float32(wavelength_min_px**2)
    gain = k2 ** np.float32(-slope / 2.0)
    # gain *= exp(-(k2 k_hi2)²) · (1 - exp(-(k2 k_lo2)²)), in place (the same values).
    roll = k2 * k_hi2
    np.square(roll, out=roll)
    np.negative(roll, out=roll)
    np.exp(roll, out=roll)
    gain *= roll
    np.multiply(k2, k_lo2, out=roll)
    np.square(roll, out=roll)
    np.negative(roll, out=roll)
    np.exp(roll, out=roll)
    np.subtract(1.0, roll, out=roll)
    gain *= roll
    spec *= gain
    out = scipy.fft.irfft2(spec, s=shape).astype(np.float32, copy=False)
    out -= out.mean()
    out /= max(float(out.std()), 1e-12)
    return out


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True, eq=False)
class GroundTextures:
    """Texture images of a :class:`Ground`, ready for ``cv2.remap``.

    ``macro_levels``: uint8 (H, W, 3) images of albedo / ``macro_scale`` at texel sizes
    ``macro_texels_m``; pixel (0, 0) is the north-west corner ``macro_origin_ne_m``
    (row = south, column = east). ``detail_atlas``: uint8 (H, W, 4) holding the mip chain
    of the periodic detail layer (RGB multiplier × 128, stone coverage × 255), each level
    with a one-texel wrap border at ``detail_offsets_px[k]``.
    """

    macro_levels: tuple[np.ndarray, ...]
    macro_texels_m: tuple[float, ...]
    macro_scale: float
    macro_origin_ne_m: tuple[float, float]
    detail_atlas: np.ndarray
    detail_offsets_px: np.ndarray  # (levels, 2) x, y of each level's texel (0, 0)
    detail_texel_m: float
    detail_px: int


MACRO_SCALE = 0.5 / 255.0  # albedo per DN of the macro texture (albedos stay below 0.5)
DETAIL_LEVELS = 7


def _build_ground_textures(ground: Ground) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(np.random.SeedSequence([104729, ground.seed]))
    macro0 = _macro_texture(ground, rng)
    blurred = cv2.GaussianBlur(macro0, (0, 0), 1.6)
    macro1 = cv2.resize(
        blurred, (macro0.shape[1] // 4, macro0.shape[0] // 4), interpolation=cv2.INTER_AREA
    )
    detail = _detail_texture(ground, rng)
    atlas, offsets = _mip_atlas(detail, DETAIL_LEVELS)
    return {"macro0": macro0, "macro1": macro1, "atlas": atlas, "offsets": offsets}


@lru_cache(maxsize=4)
def ground_textures(ground: Ground) -> GroundTextures:
    """Build (once per :class:`Ground`, and kept on disk between runs:
    :mod:`.texture_cache`) the texture images the renderer samples."""
    t = cached_arrays(
        "ground",
        ground,
        __file__,
        ("macro0", "macro1", "atlas", "offsets"),
        lambda: _build_ground_textures(ground),
    )
    macro0, macro1, atlas, offsets = t["macro0"], t["macro1"], t["atlas"], t["offsets"]
    half = ground.extent_m / 2.0
    return GroundTextures(
        macro_levels=(macro0, macro1),
        macro_texels_m=(ground.macro_texel_m, ground.macro_texel_m * 4.0),
        macro_scale=MACRO_SCALE,
        macro_origin_ne_m=(half, -half),
        detail_atlas=atlas,
        detail_offsets_px=offsets,
        detail_texel_m=ground.detail_texel_m,
        detail_px=ground.detail_px,
    )


def _macro_texture(ground: Ground, rng: np.random.Generator) -> np.ndarray:
    """Lawn colour, dirt patches and the path, as uint8 linear albedo / MACRO_SCALE."""
    px = round(ground.extent_m / ground.macro_texel_m)
    texel = ground.macro_texel_m
    half = ground.extent_m / 2.0
    shape = (px, px)
    lawn = _band_noise(shape, rng, 2.0 / texel, 40.0 / texel, slope=1.2)
    mottle = _band_noise(shape, rng, 0.3 / texel, 3.0 / texel, slope=0.8)
    edge = _band_noise(shape, rng, 0.3 / texel, 2.0 / texel, slope=0.5)
    dry = _smoothstep(-0.6, 1.8, lawn)[..., None]
    grass = np.asarray(ground.grass_rgb, np.float32)
    dry_rgb = np.asarray(ground.dry_grass_rgb, np.float32)
    # In place where a full-size temporary would be made (the same values, less memory
    # traffic): albedo = (grass (1 - dry) + dry_rgb dry) · exp(0.10 mottle).
    mottle_gain = np.exp(0.10 * mottle)[..., None]
    albedo = grass * (1.0 - dry)
    albedo += dry_rgb * dry
    albedo *= mottle_gain

    def to_px(n: float, e: float) -> tuple[int, int]:
        return round((e + half) / texel * 4), round((half - n) / texel * 4)  # 2 fractional bits

    # Dirt patches: discs with noisy edges, each its own colour.
    for patch in ground.patches:
        r_px = patch.radius_m / texel
        cx, cy = (patch.centre_ne_m[1] + half) / texel, (half - patch.centre_ne_m[0]) / texel
        x0, x1 = max(int(cx - 2 * r_px) - 2, 0), min(int(cx + 2 * r_px) + 3, px)
        y0, y1 = max(int(cy - 2 * r_px) - 2, 0), min(int(cy + 2 * r_px) + 3, px)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        dist = np.hypot(xx + 0.5 - cx, yy + 0.5 - cy) / r_px + 0.28 * edge[y0:y1, x0:x1]
        cover = _smoothstep(1.05, 0.8, dist)[..., None]
        colour = (
            np.asarray(patch.albedo_rgb, np.float32)
            * np.exp(0.12 * mottle[y0:y1, x0:x1])[..., None]
        )
        albedo[y0:y1, x0:x1] = albedo[y0:y1, x0:x1] * (1.0 - cover) + colour * cover

    # The path: a thick polyline, its edge roughened by noise.
    if len(ground.path_ne_m) >= 2:
        mask = np.zeros(shape, np.uint8)
        pts = np.array([to_px(n, e) for n, e in ground.path_ne_m], np.int32)
        thickness = max(1, round(ground.path_width_m / texel))
        cv2.polylines(mask, [pts], False, 255, thickness, cv2.LINE_AA, shift=2)
        soft = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (0, 0), 1.5)
        cover = _smoothstep(0.35, 0.65, soft + 0.18 * edge)[..., None]
        colour = np.asarray(ground.path_rgb, np.float32) * mottle_gain
        albedo *= 1.0 - cover
        colour *= cover
        albedo += colour
    albedo /= MACRO_SCALE
    albedo += 0.5
    np.clip(albedo, 0, 255, out=albedo)
    return albedo.astype(np.uint8)


def _detail_texture(ground: Ground, rng: np.random.Generator) -> np.ndarray:
    """Periodic grass detail: RGB multiplier (× 128) and stone coverage (× 255)."""
    px, texel = ground.detail_px, ground.detail_texel_m
    shape = (px, px)
    lum = _band_noise(shape, rng, 0.02 / texel, 0.4 / texel, slope=0.6)
    fine = _band_noise(shape, rng, 2.0, 0.05 / texel, slope=0.0)
    hue = _band_noise(shape, rng, 0.05 / texel, 0.6 / texel, slope=0.7)
    log_m = 0.26 * lum + 0.08 * fine
    log_m -= 0.25 * _smoothstep(1.6, 2.6, -lum)  # dark gaps between tufts
    mult = np.empty((px, px, 3), np.float32)
    mult[..., 0] = np.exp(log_m + 0.14 * hue)
    mult[..., 1] = np.exp(log_m + 0.02 * hue)
    mult[..., 2] = np.exp(log_m - 0.10 * hue)

    stones = np.zeros(shape, np.uint8)
    area_m2 = (px * texel) ** 2
    count = int(rng.poisson(ground.stones_per_m2 * area_m2))
    for _ in range(count):
        r_m = float(np.clip(rng.lognormal(math.log(0.028), 0.45), 0.008, 0.12))
        a = r_m / texel * float(rng.uniform(0.8, 1.25))
        b = a * float(rng.uniform(0.55, 1.0))
        cx, cy = rng.uniform(0, px), rng.uniform(0, px)
        angle = float(rng.uniform(0, 180))
        for dx in (-px, 0, px):
            for dy in (-px, 0, px):
                x, y = cx + dx, cy + dy
                if -2 * a < x < px + 2 * a and -2 * a < y < px + 2 * a:
                    cv2.ellipse(
                        stones,
                        (round(x * 16), round(y * 16)),
                        (max(1, round(a * 16)), max(1, round(b * 16))),
                        angle,
                        0,
                        360,
                        255,
                        -1,
                        cv2.LINE_AA,
                        shift=4,
                    )
    tex = np.empty((px, px, 4), np.uint8)
    mult *= 128.0  # clip(mult × 128 + 0.5) to uint8, in place
    mult += 0.5
    np.clip(mult, 0, 255, out=mult)
    tex[..., :3] = mult.astype(np.uint8)
    tex[..., 3] = stones
    return tex


def _mip_atlas(tex: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Pack a periodic texture's mip chain into one image, each level wrap-bordered.

    Level 0 sits at the left; the smaller levels are stacked in a column to its right.
    """
    chain: list[np.ndarray] = [tex.astype(np.float32)]
    for _ in range(1, levels):
        prev = chain[-1]
        h, w = prev.shape[:2]
        # 2×2 box average (exact for a factor of 2, and periodic like the texture).
        chain.append(cv2.resize(prev, (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    s0 = tex.shape[0]
    width = (s0 + 2) + (s0 // 2 + 2)
    height = s0 + 2
    atlas = np.zeros((height, width, tex.shape[2]), np.uint8)
    offsets = np.zeros((levels, 2), np.float32)
    x, y = s0 + 2, 0
    for k, level in enumerate(chain):
        if k == 0 and tex.dtype == np.uint8:
            # uint8 → float32 → +0.5, clip, truncate is the identity: pad the uint8 texture
            # itself (the same bytes without four passes over a 64 MB float copy).
            img = np.pad(tex, ((1, 1), (1, 1), (0, 0)), mode="wrap")
        else:
            bordered = np.pad(level, ((1, 1), (1, 1), (0, 0)), mode="wrap")
            img = np.clip(bordered + 0.5, 0, 255).astype(np.uint8)
        if k == 0:
            ox, oy = 0, 0
        else:
            ox, oy = x, y
            y += img.shape[0]
        atlas[oy : oy + img.shape[0], ox : ox + img.shape[1]] = img
        offsets[k] = (ox + 1, oy + 1)
    return atlas, offsets


@dataclass(frozen=True, eq=False)
class SkyTextures:
    """Cloud density (periodic, float32, ``cloud_texel_m`` per texel on the cloud layer)
    and the hill-top elevation (radians) at ``hill_az_rad`` azimuths."""

    cloud: np.ndarray  # (S, S, 2): density in [0, 1], brightness modulation
    cloud_texel_m: float
    hill_az_rad: np.ndarray
    hill_el_rad: np.ndarray


@lru_cache(maxsize=4)
def sky_textures(sky: Sky) -> SkyTextures:
    """The sky's cloud layer and hill profile (once per :class:`Sky`, kept on disk)."""
    t = cached_arrays(
        "sky", sky, __file__, ("cloud", "az", "hill"), lambda: _build_sky_textures(sky)
    )
    return SkyTextures(t["cloud"], 25.0, t["az"], t["hill"])


def _build_sky_textures(sky: Sky) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(np.random.SeedSequence([15485863, sky.seed]))
    size = 512
    base = _band_noise((size, size), rng, 16.0, 300.0, slope=1.4)
    detail = _band_noise((size, size), rng, 3.0, 24.0, slope=0.5)
    shape_noise = base + 0.15 * detail
    threshold = float(np.quantile(shape_noise, 1.0 - sky.cloud_cover))
    density = 0.95 * _smoothstep(threshold, threshold + 1.4, shape_noise)
    cloud = np.stack([density, 0.85 + 0.15 * np.tanh(detail)], axis=-1).astype(np.float32)
    n_az = 1024
    az = np.linspace(-math.pi, math.pi, n_az + 1)
    prof = _band_noise((1, n_az), rng, 8.0, 400.0, slope=1.0)[0]
    prof = np.append(prof, prof[0])
    hill = np.radians(sky.hill_height_deg) * (0.55 + 0.45 * np.tanh(0.8 * prof))
    return {"cloud": cloud, "az": az, "hill": hill.astype(np.float64)}
