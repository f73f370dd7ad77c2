"""The simulated flights: the paper's field test (TS, T45, T90) and the traps around it.

The vehicle is a quadrotor at 2 m altitude (NED ``d = -2``) flying back and forth along
a 3 m straight track at 0.1 Hz (sinusoidal, reversing every 5 s, about 0.94 m/s at the
middle) without turning round, so it flies backwards half the time. The track runs
through the origin along ``HEADING_RAD``; the balls stand to its right, so the vehicle
passes to the ball's left as in the paper. Attitude follows the thrust needed for the
acceleration (exact, not small-angle) plus a small yaw wobble and seeded turbulence.

Scenarios (``SCENARIO_NAMES``):

- ``TS``: static ball, centre 1 m above the ground, 3.5 m to the right of the track.
- ``T45`` / ``T90``: the same ball oscillating ±1 m at 0.35 Hz, horizontally, at 45° /
  90° to the track.
- ``RAISED``: a static ball with its centre 3.75 m up and 2.5 m from the track: large
  parallax against the background (background subtraction's trap).
- ``INPLANE``: a ball at the camera's altitude oscillating towards and away from the
  track; the plane through the track and the ball hardly changes (the epipolar
  method's trap).
- ``COLLISION``: the vehicle flies straight at 1.5 m/s while a ball at its altitude
  approaches on a collision course (constant bearing, range 15 m → 1.6 m).
- ``HEADON``: the vehicle flies at 1.75 m/s straight at a static ball, range 15 m → 2 m
  (time to contact).
- ``TWO``: a static ball and, 4 m along the track from it, an oscillating one (T90).

Rig flights (``RIG_SCENARIO_NAMES``, for ``sitl --rig quad`` / ``front-back``; any camera
sees them): ``PASS`` (the vehicle flies straight past a static ball 3 m to its right: the
ball crosses from the front camera's view into the right one's and on into the rear
one's), ``OVERLAP`` (a ball on a collision course from 45° right: inside the quad rig's
front/right overlap throughout) and ``CAMLOSS`` (a static ball ahead-left, an oscillating
one behind-right, the vehicle on the paper's back-and-forth track; the ``front`` camera
dies 8 s in: :data:`~.names.CAMERA_LOSS`).

Objects of other kinds (``OBJECT_SCENARIO_NAMES``; see ``docs/simulator.md``): the same
flights with a car-sized box (``-BOX``), a person-sized upright cylinder (``-CYL``) or a
small drone (a flat disc, ``-DISC``) instead of the ball — ``TS-``, ``T45-``, ``T90-`` of
each, ``RAISED-DISC``, ``INPLANE-BOX``, ``COLLISION-CYL``, ``COLLISION-DISC``,
``HEADON-BOX`` —, scenes that make angular size hard — ``DARKBG`` (balls in front of a
dark hedge and a dark building), ``BACKLIT`` (a low sun behind the objects),
``SKY2TREE`` (objects whose background changes from sky to foliage) — and ``MIXED``
(five objects of four kinds, moving and stationary, hiding each other at times).
:func:`describe_scenario` says in one line what each shows; :func:`plan_world` builds the
world a plan flies in (the field, the plan's objects, its extra clutter and sun).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from ...core.camera import Equirectangular
from ...core.frames import FloatArray
from .names import MAX_FLIGHT_S, OBJECT_SCENARIO_NAMES, RIG_SCENARIO_NAMES, SCENARIO_NAMES
from .names import PAPER_SCENARIO_NAMES as PAPER_SCENARIO_NAMES  # re-exported
from .world import (
    COLOURS,
    Ball,
    Box,
    BoxTarget,
    Cylinder,
    CylinderTarget,
    DiscTarget,
    SineTerm,
    SolidTarget,
    Sphere,
    Sun,
    Target,
    Trajectory,
    Tree,
    World,
    field_world,
    track_axes,
    vec3,
)

FPS = 25.0
HEADING_RAD = math.radians(25.0)  # the track's direction (clockwise from north)
ALTITUDE_M = 2.0
TRACK_HALF_LENGTH_M = 1.5
TRACK_FREQ_HZ = 0.1
BALL_FREQ_HZ = 0.35
BALL_AMPLITUDE_M = 1.0
GRAVITY_MPS2 = 9.80665
_GRAVITY_NED = np.array([0.0, 0.0, GRAVITY_MPS2])

# Collision course: vehicle and ball velocities (track axes) and the contact time.
_COLLISION_VEH_MPS = 1.5
_COLLISION_BALL_RIGHT_MPS = -1.2  # the ball moves leftwards, towards the track
_COLLISION_START_RANGE_M = 15.0
_HEADON_SPEED_MPS = 1.75
_HEADON_START_ALONG_M = -13.0
_HEADON_BALL_ALONG_M = 2.0

_DEFAULT_DURATION_S = {
    "TS": 40.0,
    "T45": 40.0,
    "T90": 40.0,
    "RAISED": 40.0,
    "INPLANE": 40.0,
    "COLLISION": 7.0,
    "HEADON": 7.4,
    "TWO": 40.0,
}

#: The objects of the non-spherical scenarios (sizes in metres).
CAR_SIZE_M = (4.2, 1.8, 1.5)
CRATE_SIZE_M = (1.0, 0.7, 0.5)
CONTAINER_SIZE_M = (2.0, 2.4, 2.6)
PERSON_RADIUS_M, PERSON_HEIGHT_M = 0.25, 1.8
DRONE_RADIUS_M, DRONE_THICKNESS_M = 0.3, 0.1


def default_camera() -> Equirectangular:
    """The paper's panorama: 360×220, azimuth -180..180°, elevation 75..-75°, mount 0."""
    return Equirectangular(width=360, height=220)


@dataclass(frozen=True)
class VehicleMotion:
    """Vehicle (= camera) position and attitude as closed-form functions of time.

    ``yaw_terms``, ``roll_terms``, ``pitch_terms``: ``(amplitude_rad, freq_hz, phase_rad)``
    sinusoids added to the heading and, as turbulence, to the thrust-aligned attitude.
    """

    path: Trajectory
    heading_rad: float
    yaw_terms: tuple[tuple[float, float, float], ...] = ()
    roll_terms: tuple[tuple[float, float, float], ...] = ()
    pitch_terms: tuple[tuple[float, float, float], ...] = ()

    def position_ned_m(self, t_s: float | FloatArray) -> FloatArray:
        return self.path.position_ned_m(t_s)

    def velocity_ned_mps(self, t_s: float | FloatArray) -> FloatArray:
        return self.path.velocity_ned_mps(t_s)

    @staticmethod
    def _sines(terms: tuple[tuple[float, float, float], ...], t: np.ndarray) -> np.ndarray:
        out = np.zeros_like(t)
        for amp, f, ph in terms:
            out = out + amp * np.sin(2.0 * math.pi * f * t + ph)
        return out

    def R_ned_from_body(self, t_s: float | FloatArray) -> FloatArray:
        """Body attitude (3, 3), or (N, 3, 3) for an array of times.

        Element by element the arithmetic of the thrust-aligned frame (``z_b`` along
        ``g - a``, ``x_b`` towards the heading) times the turbulence; the cross products
        are written out as :func:`numpy.cross` computes them (``a1 b2 - a2 b1``, ...),
        which gives the same bits without its per-call overhead.
        """
        t = np.asarray(t_s, dtype=np.float64)
        flat = t.reshape(-1)
        acc = self.path.acceleration_ned_mps2(flat)
        # Thrust (along -z_body) supplies the specific force a - g.
        z_b = _GRAVITY_NED - acc
        z_b /= np.sqrt(np.add.reduce(z_b * z_b, axis=1, keepdims=True))
        yaw_sines, roll_rad, pitch_rad = _sine_sums(
            (self.yaw_terms, self.roll_terms, self.pitch_terms), flat
        )
        yaw = self.heading_rad + yaw_sines
        # y_b = z_b × x_c with x_c = (cos yaw, sin yaw, 0).
        cyaw, syaw = np.cos(yaw), np.sin(yaw)
        zero = np.zeros_like(yaw)
        zx, zy, zz = z_b[:, 0], z_b[:, 1], z_b[:, 2]
        y_b = np.empty_like(z_b)
        y_b[:, 0] = zy * zero - zz * syaw
        y_b[:, 1] = zz * cyaw - zx * zero
        y_b[:, 2] = zx * syaw - zy * cyaw
        y_b /= np.sqrt(np.add.reduce(y_b * y_b, axis=1, keepdims=True))
        # x_b = y_b × z_b.
        yx, yy, yz = y_b[:, 0], y_b[:, 1], y_b[:, 2]
        base = np.empty((flat.shape[0], 3, 3))
        base[:, 0, 0] = yy * zz - yz * zy
        base[:, 1, 0] = yz * zx - yx * zz
        base[:, 2, 0] = yx * zy - yy * zx
        base[:, :, 1] = y_b
        base[:, :, 2] = z_b
        turb = _rot_zyx(roll_rad, pitch_rad, zero)
        R = base @ turb
        return R.reshape(*t.shape, 3, 3)

    def body_rates_rps(self, t_s: float | FloatArray, h_s: float = 1e-3) -> FloatArray:
        """Body angular rates ``(p, q, r)`` (rad/s), from ``Rᵀ dR/dt`` (central difference)."""
        return self.attitude_and_rates(t_s, h_s)[1]

    def attitude_and_rates(
        self, t_s: float | FloatArray, h_s: float = 1e-3
    ) -> tuple[FloatArray, FloatArray]:
        """``(R_ned_from_body, body_rates_rps)`` at ``t_s``: the attitude at ``t``,
        ``t + h`` and ``t - h`` in one evaluation (each the same as on its own)."""
        t = np.asarray(t_s, dtype=np.float64)
        R3 = self.R_ned_from_body(np.stack([t, t + h_s, t - h_s]))
        R0 = R3[0]
        dR = (R3[1] - R3[2]) / (2.0 * h_s)
        W = np.swapaxes(R0, -1, -2) @ dR
        rates = 0.5 * np.stack(
            [W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
            axis=-1,
        )
        return R0, rates


@lru_cache(maxsize=64)
def _sine_table(
    groups: tuple[tuple[tuple[float, float, float], ...], ...],
) -> tuple[FloatArray, FloatArray, FloatArray, tuple[int, ...]]:
    """Angular frequencies ``2π f`` (K, 1), phases (K, 1) and amplitudes (K, 1) of the
    sinusoid groups' terms, one after the other, and where each group ends."""
    terms = [term for group in groups for term in group]
    omega = np.array([2.0 * math.pi * f for _, f, _ in terms], np.float64).reshape(-1, 1)
    phase = np.array([ph for _, _, ph in terms], np.float64).reshape(-1, 1)
    amp = np.array([a for a, _, _ in terms], np.float64).reshape(-1, 1)
    ends = tuple(int(e) for e in np.cumsum([len(g) for g in groups]))
    return omega, phase, amp, ends


def _sine_sums(
    groups: tuple[tuple[tuple[float, float, float], ...], ...], t: np.ndarray
) -> list[np.ndarray]:
    """Per group ``Σ amp · sin(2π f t + phase)`` at the times ``t`` (N,): one sine call
    for all terms; each sum the same bits as :meth:`VehicleMotion._sines` (the same
    products, added in the same order from zero)."""
    omega, phase, amp, ends = _sine_table(groups)
    s = omega * t[None, :]
    s += phase
    np.sin(s, out=s)
    s *= amp
    sums = []
    start = 0
    for end in ends:
        out = np.zeros_like(t)
        for k in range(start, end):
            out = out + s[k]
        sums.append(out)
        start = end
    return sums


def _rot_zyx(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Vectorised ``Rz(yaw) Ry(pitch) Rx(roll)``, shape (N, 3, 3)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    out = np.empty((*np.shape(roll), 3, 3))
    out[..., 0, 0] = cy * cp
    out[..., 0, 1] = cy * sp * sr - sy * cr
    out[..., 0, 2] = cy * sp * cr + sy * sr
    out[..., 1, 0] = sy * cp
    out[..., 1, 1] = sy * sp * sr + cy * cr
    out[..., 1, 2] = sy * sp * cr - cy * sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def euler_zyx_rad(R_ned_from_body: FloatArray) -> FloatArray:
    """Vectorised MAVLink ``(roll, pitch, yaw)`` of (…, 3, 3) rotations, shape (…, 3)."""
    R = np.asarray(R_ned_from_body, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


@dataclass(frozen=True)
class SceneExtras:
    """What a scenario adds to the paper's field: clutter placed on purpose (behind an
    object, say) and its own sun. Empty for the paper's scenarios."""

    trees: tuple[Tree, ...] = ()
    buildings: tuple[Box, ...] = ()
    sun: Sun | None = None


class FlightTooLong(ValueError):
    """A flight asked to last longer than it can: a collision or head-on course ends
    shortly before contact. ``max_duration_s`` is the longest it can last."""

    def __init__(self, name: str, max_duration_s: float, why: str) -> None:
        super().__init__(f"{name} lasts at most {max_duration_s:.2f} s ({why})")
        self.name = name
        self.max_duration_s = max_duration_s


@dataclass(frozen=True)
class FlightPlan:
    """One scenario's design: vehicle motion, objects, duration and frame rate.

    ``balls`` are the red spheres, ``targets`` the objects of other shapes; ``objects``
    lists both in ``object_id`` order. ``extras``: see :class:`SceneExtras`.
    """

    name: str
    description: str
    duration_s: float
    vehicle: VehicleMotion
    balls: tuple[Ball, ...]
    heading_rad: float = HEADING_RAD
    fps: float = FPS
    targets: tuple[SolidTarget, ...] = ()
    extras: SceneExtras = SceneExtras()

    @property
    def n_frames(self) -> int:
        return max(1, round(self.duration_s * self.fps))

    @property
    def objects(self) -> tuple[Target, ...]:
        """Every object, balls and others, in ``object_id`` order."""
        return tuple(sorted((*self.balls, *self.targets), key=lambda o: o.object_id))


def plan_world(plan: FlightPlan) -> World:
    """The world ``plan`` flies in: :func:`~.world.field_world` with the plan's balls,
    plus its other objects, extra clutter and sun (the field alone for the paper's)."""
    world = field_world(plan.balls, plan.heading_rad)
    ex = plan.extras
    if not plan.targets and ex == SceneExtras():
        return world
    return replace(
        world,
        targets=plan.targets,
        trees=world.trees + ex.trees,
        buildings=world.buildings + ex.buildings,
        sun=ex.sun if ex.sun is not None else world.sun,
    )


def _track_point(along_m: float, right_m: float, down_m: float) -> tuple[float, float, float]:
    ax, rt = track_axes(HEADING_RAD)
    p = along_m * ax + right_m * rt
    return (float(p[0]), float(p[1]), float(down_m))


def _track_dir(along: float, right: float, down: float = 0.0) -> tuple[float, float, float]:
    ax, rt = track_axes(HEADING_RAD)
    d = along * ax + right * rt + np.array([0.0, 0.0, down])
    d /= np.linalg.norm(d)
    return (float(d[0]), float(d[1]), float(d[2]))


def _wobble(rng: np.random.Generator) -> tuple[SineTerm, ...]:
    """Small position wander (a few cm) on top of the commanded path."""
    _, rt = track_axes(HEADING_RAD)
    return (
        SineTerm(vec3(0.05 * rt), 0.17, float(rng.uniform(0, 2 * math.pi))),
        SineTerm((0.0, 0.0, 0.03), 0.23, float(rng.uniform(0, 2 * math.pi))),
    )


def _attitude_terms(
    rng: np.random.Generator,
) -> tuple[tuple[tuple[float, float, float], ...], ...]:
    def turbulence() -> tuple[tuple[float, float, float], ...]:
        return tuple(
            (
                math.radians(float(rng.uniform(0.12, 0.28))),
                float(rng.uniform(0.3, 2.5)),
                float(rng.uniform(0, 2 * math.pi)),
            )
            for _ in range(4)
        )

    yaw = (
        (math.radians(1.5), 0.07, float(rng.uniform(0, 2 * math.pi))),
        (math.radians(0.8), 0.19, float(rng.uniform(0, 2 * math.pi))),
        (math.radians(0.2), 1.3, float(rng.uniform(0, 2 * math.pi))),
    )
    return yaw, turbulence(), turbulence()


def _duration_and_rng(
    duration_s: float | None, default_s: float, seed: int
) -> tuple[float, np.random.Generator]:
    """A flight's duration (``duration_s``, else the scenario's ``default_s``; checked
    against :data:`MAX_FLIGHT_S`) and the generator of its ``seed``'s variations."""
    duration = float(duration_s) if duration_s is not None else default_s
    if not 0 < duration <= MAX_FLIGHT_S:
        raise ValueError(
            f"duration_s must be positive and at most {MAX_FLIGHT_S:g} s, got {duration_s!r}"
        )
    return duration, np.random.default_rng(np.random.SeedSequence([31337, seed]))


def flight_plan(name: str, duration_s: float | None = None, seed: int = 0) -> FlightPlan:
    """The design of scenario ``name`` (one of ``SCENARIO_NAMES``).

    ``seed`` varies the turbulence, wobble and ball phases; the field is always the same.
    """
    key = name.upper()
    if key not in SCENARIO_NAMES:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIO_NAMES)}")
    if key in OBJECT_SCENARIO_NAMES:
        return _object_plan(key, duration_s, seed)
    if key in RIG_SCENARIO_NAMES:
        return _rig_plan(key, duration_s, seed)
    duration, rng = _duration_and_rng(duration_s, _DEFAULT_DURATION_S[key], seed)
    yaw_terms, roll_terms, pitch_terms = _attitude_terms(rng)
    wobble = _wobble(rng)
    ball_phase = float(rng.uniform(0, 2 * math.pi))
    ax, _ = track_axes(HEADING_RAD)

    if key in ("COLLISION", "HEADON"):
        speed = _COLLISION_VEH_MPS if key == "COLLISION" else _HEADON_SPEED_MPS
        start_along = -5.25 if key == "COLLISION" else _HEADON_START_ALONG_M
        path = Trajectory(_track_point(start_along, 0.0, -ALTITUDE_M), vec3(speed * ax), wobble)
    else:
        track = SineTerm(vec3(TRACK_HALF_LENGTH_M * ax), TRACK_FREQ_HZ, 0.0)
        path = Trajectory(_track_point(0.0, 0.0, -ALTITUDE_M), terms=(track, *wobble))
    vehicle = VehicleMotion(path, HEADING_RAD, yaw_terms, roll_terms, pitch_terms)

    def oscillating(
        centre: tuple[float, float, float], direction: tuple[float, float, float], oid: int = 1
    ) -> Ball:
        traj = Trajectory.oscillation(centre, direction, BALL_AMPLITUDE_M, BALL_FREQ_HZ, ball_phase)
        return Ball(traj, object_id=oid)

    ball_centre = _track_point(0.0, 3.5, -1.0)
    balls: tuple[Ball, ...]
    if key == "TS":
        balls = (Ball(Trajectory.static(ball_centre)),)
        desc = "static ball 3.5 m right of a back-and-forth track (paper's TS)"
    elif key == "T45":
        balls = (oscillating(ball_centre, _track_dir(1.0, 1.0)),)
        desc = "ball oscillating ±1 m at 0.35 Hz at 45° to the back-and-forth track (paper's T45)"
    elif key == "T90":
        balls = (oscillating(ball_centre, _track_dir(0.0, 1.0)),)
        desc = "ball oscillating ±1 m at 0.35 Hz perpendicular to the back-and-forth track (paper's T90)"
    elif key == "RAISED":
        balls = (Ball(Trajectory.static(_track_point(0.0, 2.5, -3.75))),)
        desc = "static ball raised 3.75 m, 2.5 m from the track: large parallax (BSM's trap)"
    elif key == "INPLANE":
        balls = (oscillating(_track_point(0.0, 4.0, -ALTITUDE_M), _track_dir(0.0, 1.0)),)
        desc = "ball at camera altitude oscillating towards/away from the track, inside the epipolar plane (ECM's trap)"
    elif key == "TWO":
        balls = (
            Ball(Trajectory.static(_track_point(-1.5, 3.5, -1.0)), object_id=1),
            oscillating(_track_point(2.5, 3.5, -1.0), _track_dir(0.0, 1.0), oid=2),
        )
        desc = "two balls 4 m apart: one static, one oscillating perpendicular to the track"
    elif key == "COLLISION":
        v_veh = _COLLISION_VEH_MPS * ax
        _, rt = track_axes(HEADING_RAD)
        v_ball = _COLLISION_BALL_RIGHT_MPS * rt
        closing = float(np.linalg.norm(v_veh - v_ball))
        t_contact = _COLLISION_START_RANGE_M / closing
        if duration > t_contact - 0.5:
            raise FlightTooLong(key, t_contact - 0.5, f"contact at {t_contact:.2f} s")
        meet = np.asarray(path.origin_ned_m) + v_veh * t_contact  # the vehicle's commanded point
        start = meet - v_ball * t_contact
        balls = (Ball(Trajectory.linear(vec3(start), vec3(v_ball))),)
        desc = "ball on a collision course: constant bearing, range 15 m to 1.6 m"
    else:  # HEADON
        t_contact = (_HEADON_BALL_ALONG_M - _HEADON_START_ALONG_M) / _HEADON_SPEED_MPS
        if duration > t_contact - 0.8:
            raise FlightTooLong(key, t_contact - 0.8, f"ball reached at {t_contact:.2f} s")
        balls = (Ball(Trajectory.static(_track_point(_HEADON_BALL_ALONG_M, 0.25, -1.75))),)
        desc = "vehicle flying straight at a static ball at 1.75 m/s, range 15 m to 2 m (time to contact)"
    return FlightPlan(key, desc, duration, vehicle, balls)


def describe_scenario(name: str) -> str:
    """One line saying what scenario ``name`` shows."""
    return flight_plan(name).description


# --------------------------------------------------------------------------------------
# Objects of other kinds, and hard backgrounds
# --------------------------------------------------------------------------------------
_OBJECT_DURATION_S = {"COLLISION-CYL": 7.0, "COLLISION-DISC": 7.0, "HEADON-BOX": 7.4}
_DESCRIPTIONS = {
    "TS-BOX": "static blue car (4.2×1.8×1.5 m box) parked along the track, 5.5 m to its right",
    "T45-BOX": "blue car driving ±1 m at 0.35 Hz at 45° to the track, turned along its path",
    "T90-BOX": "blue car driving ±1 m at 0.35 Hz perpendicular to the track, facing along its path",
    "TS-CYL": "static person-sized yellow cylinder (r 0.25 m, 1.8 m tall) 3.5 m right of the track",
    "T45-CYL": "yellow person-sized cylinder walking ±1 m at 0.35 Hz at 45° to the track",
    "T90-CYL": "yellow person-sized cylinder walking ±1 m at 0.35 Hz perpendicular to the track",
    "TS-DISC": "static dark-grey drone (disc r 0.3 m, 0.1 m thick) hovering where the TS ball is",
    "T45-DISC": "dark-grey drone (disc) oscillating ±1 m at 0.35 Hz at 45° to the track",
    "T90-DISC": "dark-grey drone (disc) oscillating ±1 m at 0.35 Hz perpendicular to the track",
    "RAISED-DISC": "static white drone hovering 3.75 m up, 2.5 m from the track: its shaded "
    "underside against the sky, large parallax (BSM's trap)",
    "INPLANE-BOX": "red crate (1.0×0.7×0.5 m box) at camera altitude oscillating towards/away "
    "from the track, inside the epipolar plane (ECM's trap)",
    "COLLISION-CYL": "upright cylinder (r 0.25 m, 1.8 m tall) on a collision course at the "
    "vehicle's altitude: constant bearing, range 15 m to 1.6 m",
    "COLLISION-DISC": "dark-grey drone on a collision course: constant bearing, range 15 m to 1.6 m",
    "HEADON-BOX": "vehicle flying straight at a static white 2.0×2.4×2.6 m box (a container) "
    "at 1.75 m/s, range to its centre 15 m to 2 m (time to contact)",
    "DARKBG": "two red balls on dark backgrounds: a static one in front of a dark hedge, one "
    "oscillating perpendicular to the track in front of a dark building",
    "BACKLIT": "low sun (12° up) behind the objects: a static ball in front of the sun, an "
    "oscillating ball and an oscillating white drone, their shaded sides to the camera",
    "SKY2TREE": "backgrounds changing from sky to foliage: a ball oscillating along the track "
    "in front of a tree clump's edge, and a static ball whose background crosses it by parallax",
    "MIXED": "five objects of four kinds: static ball, parked car, a person walking in front of "
    "it, a hovering and an oscillating drone (objects hide each other at times)",
}


def _standing(along_m: float, right_m: float, height_m: float) -> tuple[float, float, float]:
    """Centre of an object of height ``height_m`` standing on the ground."""
    return _track_point(along_m, right_m, -height_m / 2.0)


def _dark_tree(
    along_m: float, right_m: float, crown_r_m: float, crown_h_m: float, trunk_h_m: float
) -> Tree:
    """A dark leafy crown on a short trunk (clutter placed behind an object on purpose)."""
    n, e, _ = _track_point(along_m, right_m, 0.0)
    trunk = Cylinder((n, e), 0.18, trunk_h_m, (0.06, 0.045, 0.03))
    crown = Sphere((n, e, -crown_h_m), crown_r_m, (0.012, 0.036, 0.01), leafy=True)
    return Tree(trunk, (crown,))


def _dark_building(
    along_m: tuple[float, float], right_m: tuple[float, float], height_m: float
) -> Box:
    """An axis-aligned (NED) dark building covering the track-coordinate rectangle."""
    corners = np.array(
        [_track_point(a, r, 0.0) for a in along_m for r in right_m], dtype=np.float64
    )
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    return Box(
        (float(lo[0]), float(lo[1]), -height_m),
        (float(hi[0]), float(hi[1]), 0.0),
        wall_albedo_rgb=(0.05, 0.048, 0.045),
        roof_albedo_rgb=(0.03, 0.03, 0.032),
        window_albedo_rgb=(0.015, 0.018, 0.025),
    )


def _object_plan(key: str, duration_s: float | None, seed: int) -> FlightPlan:
    """The design of one of ``OBJECT_SCENARIO_NAMES`` (see :func:`flight_plan`)."""
    duration, rng = _duration_and_rng(duration_s, _OBJECT_DURATION_S.get(key, 40.0), seed)
    yaw_terms, roll_terms, pitch_terms = _attitude_terms(rng)
    wobble = _wobble(rng)
    phase = float(rng.uniform(0, 2 * math.pi))
    ax, rt = track_axes(HEADING_RAD)
    base = key.split("-")[0]

    if base in ("COLLISION", "HEADON"):
        speed = _COLLISION_VEH_MPS if base == "COLLISION" else _HEADON_SPEED_MPS
        start_along = -5.25 if base == "COLLISION" else _HEADON_START_ALONG_M
        path = Trajectory(_track_point(start_along, 0.0, -ALTITUDE_M), vec3(speed * ax), wobble)
    else:
        track = SineTerm(vec3(TRACK_HALF_LENGTH_M * ax), TRACK_FREQ_HZ, 0.0)
        path = Trajectory(_track_point(0.0, 0.0, -ALTITUDE_M), terms=(track, *wobble))
    vehicle = VehicleMotion(path, HEADING_RAD, yaw_terms, roll_terms, pitch_terms)

    def osc(
        centre: tuple[float, float, float], direction: tuple[float, float, float], ph: float = 0.0
    ) -> Trajectory:
        return Trajectory.oscillation(centre, direction, BALL_AMPLITUDE_M, BALL_FREQ_HZ, phase + ph)

    def paper_motion(centre: tuple[float, float, float]) -> Trajectory:
        if base == "TS":
            return Trajectory.static(centre)
        return osc(centre, _track_dir(1.0, 1.0) if base == "T45" else _track_dir(0.0, 1.0))

    balls: tuple[Ball, ...] = ()
    targets: tuple[SolidTarget, ...] = ()
    extras = SceneExtras()
    if key in ("TS-BOX", "T45-BOX", "T90-BOX"):
        traj = paper_motion(_standing(0.0, 5.5, CAR_SIZE_M[2]))
        targets = (
            BoxTarget(
                traj,
                CAR_SIZE_M,
                COLOURS["blue"],
                specular=0.15,
                yaw_rad=HEADING_RAD,
                yaw_follows_path=not traj.is_static,
            ),
        )
    elif key in ("TS-CYL", "T45-CYL", "T90-CYL"):
        traj = paper_motion(_standing(0.0, 3.5, PERSON_HEIGHT_M))
        targets = (CylinderTarget(traj, PERSON_RADIUS_M, PERSON_HEIGHT_M, COLOURS["yellow"]),)
    elif key in ("TS-DISC", "T45-DISC", "T90-DISC"):
        traj = paper_motion(_track_point(0.0, 3.5, -1.0))
        targets = (DiscTarget(traj, DRONE_RADIUS_M, DRONE_THICKNESS_M),)
    elif key == "RAISED-DISC":
        targets = (
            DiscTarget(
                Trajectory.static(_track_point(0.0, 2.5, -3.75)),
                DRONE_RADIUS_M,
                DRONE_THICKNESS_M,
                COLOURS["white"],
            ),
        )
    elif key == "INPLANE-BOX":
        traj = osc(_track_point(0.0, 4.0, -ALTITUDE_M), _track_dir(0.0, 1.0))
        targets = (
            BoxTarget(
                traj,
                CRATE_SIZE_M,
                COLOURS["red"],
                specular=0.05,
                yaw_rad=HEADING_RAD,
                label="crate",
            ),
        )
    elif base == "COLLISION":
        v_veh = _COLLISION_VEH_MPS * ax
        v_obj = _COLLISION_BALL_RIGHT_MPS * rt
        t_contact = _COLLISION_START_RANGE_M / float(np.linalg.norm(v_veh - v_obj))
        if duration > t_contact - 0.5:
            raise FlightTooLong(key, t_contact - 0.5, f"contact at {t_contact:.2f} s")
        meet = np.asarray(path.origin_ned_m) + v_veh * t_contact
        traj = Trajectory.linear(vec3(meet - v_obj * t_contact), vec3(v_obj))
        if key == "COLLISION-CYL":
            targets = (
                CylinderTarget(
                    traj, PERSON_RADIUS_M, PERSON_HEIGHT_M, COLOURS["yellow"], label="cylinder"
                ),
            )
        else:
            targets = (DiscTarget(traj, DRONE_RADIUS_M, DRONE_THICKNESS_M),)
    elif key == "HEADON-BOX":
        t_contact = (_HEADON_BALL_ALONG_M - _HEADON_START_ALONG_M) / _HEADON_SPEED_MPS
        if duration > t_contact - 0.8:
            raise FlightTooLong(key, t_contact - 0.8, f"box centre reached at {t_contact:.2f} s")
        centre = _standing(_HEADON_BALL_ALONG_M, 0.25, CONTAINER_SIZE_M[2])
        targets = (
            BoxTarget(
                Trajectory.static(centre),
                CONTAINER_SIZE_M,
                COLOURS["white"],
                yaw_rad=HEADING_RAD,
                label="container",
            ),
        )
    elif key == "DARKBG":
        balls = (
            Ball(Trajectory.static(_track_point(-2.5, 3.5, -1.0)), object_id=1),
            Ball(osc(_track_point(2.0, 3.5, -2.2), _track_dir(0.0, 1.0)), object_id=2),
        )
        hedge = tuple(
            _dark_tree(a, 6.0, 1.3, 0.9, 0.3) for a in np.arange(-10.0, 1.01, 1.1).tolist()
        )
        extras = SceneExtras(
            trees=hedge, buildings=(_dark_building((1.0, 14.0), (10.0, 13.0), 7.0),)
        )
    elif key == "BACKLIT":
        sun_el_deg = 12.0
        h = ALTITUDE_M + 4.0 * math.tan(math.radians(sun_el_deg))
        balls = (
            Ball(Trajectory.static(_track_point(0.0, 4.0, -h)), object_id=1),
            Ball(osc(_track_point(3.0, 4.0, -h), _track_dir(0.0, 1.0)), object_id=2),
        )
        targets = (
            DiscTarget(
                osc(_track_point(-3.0, 4.0, -h - 0.6), _track_dir(1.0, 1.0), 1.0),
                DRONE_RADIUS_M,
                DRONE_THICKNESS_M,
                COLOURS["white"],
                object_id=3,
            ),
        )
        extras = SceneExtras(
            sun=Sun(azimuth_deg=math.degrees(HEADING_RAD) + 90.0, elevation_deg=sun_el_deg)
        )
    elif key == "SKY2TREE":
        balls = (
            Ball(
                Trajectory.oscillation(
                    _track_point(-1.0, 6.0, -2.6), _track_dir(1.0, 0.0), 3.0, 0.13, phase
                ),
                object_id=1,
            ),
            Ball(Trajectory.static(_track_point(1.0, 5.0, -3.6)), object_id=2),
        )
        clump = tuple(
            _dark_tree(a, 15.5 + 0.8 * math.sin(a), 2.1, 5.0 + 0.4 * math.cos(2 * a), 3.0)
            for a in np.arange(3.5, 14.01, 1.5).tolist()
        )
        extras = SceneExtras(trees=clump)
    elif key == "MIXED":
        balls = (Ball(Trajectory.static(_track_point(-2.5, 3.5, -1.0)), object_id=1),)
        targets = (
            BoxTarget(
                Trajectory.static(_standing(1.5, 7.5, CAR_SIZE_M[2])),
                CAR_SIZE_M,
                COLOURS["blue"],
                specular=0.15,
                yaw_rad=HEADING_RAD,
                object_id=2,
            ),
            CylinderTarget(
                Trajectory.oscillation(
                    _standing(1.5, 4.8, PERSON_HEIGHT_M), _track_dir(1.0, 0.0), 2.2, 0.06, phase
                ),
                PERSON_RADIUS_M,
                PERSON_HEIGHT_M,
                COLOURS["yellow"],
                object_id=3,
            ),
            DiscTarget(
                Trajectory.static(_track_point(-5.0, 4.0, -3.0)),
                DRONE_RADIUS_M,
                DRONE_THICKNESS_M,
                object_id=4,
            ),
            DiscTarget(
                osc(_track_point(4.5, 3.5, -2.6), _track_dir(0.0, 1.0), 2.0),
                DRONE_RADIUS_M,
                DRONE_THICKNESS_M,
                COLOURS["white"],
                specular=0.2,
                object_id=5,
            ),
        )
    else:  # pragma: no cover - every name of OBJECT_SCENARIO_NAMES is handled above
        raise AssertionError(key)
    return FlightPlan(
        key,
        _DESCRIPTIONS[key],
        duration,
        vehicle,
        balls,
        targets=targets,
        extras=extras,
    )


# --------------------------------------------------------------------------------------
# Rig flights (issue 26): crossing views, an overlap, a camera dying
# --------------------------------------------------------------------------------------
_RIG_DURATION_S = {"PASS": 10.0, "OVERLAP": 6.5, "CAMLOSS": 16.0}
_PASS_SPEED_MPS = 1.5
_PASS_START_ALONG_M = -7.5
_PASS_BALL_RIGHT_M = 3.0
_OVERLAP_START_RANGE_M = 15.0


def _rig_plan(key: str, duration_s: float | None, seed: int) -> FlightPlan:
    """The design of one of ``RIG_SCENARIO_NAMES`` (see the module docstring)."""
    duration, rng = _duration_and_rng(duration_s, _RIG_DURATION_S[key], seed)
    yaw_terms, roll_terms, pitch_terms = _attitude_terms(rng)
    wobble = _wobble(rng)
    phase = float(rng.uniform(0, 2 * math.pi))
    ax, rt = track_axes(HEADING_RAD)
    if key == "CAMLOSS":
        track = SineTerm(vec3(TRACK_HALF_LENGTH_M * ax), TRACK_FREQ_HZ, 0.0)
        path = Trajectory(_track_point(0.0, 0.0, -ALTITUDE_M), terms=(track, *wobble))
    else:
        start_along = _PASS_START_ALONG_M if key == "PASS" else -5.25
        path = Trajectory(
            _track_point(start_along, 0.0, -ALTITUDE_M), vec3(_PASS_SPEED_MPS * ax), wobble
        )
    vehicle = VehicleMotion(path, HEADING_RAD, yaw_terms, roll_terms, pitch_terms)
    balls: tuple[Ball, ...]
    if key == "PASS":
        balls = (Ball(Trajectory.static(_track_point(0.0, _PASS_BALL_RIGHT_M, -1.5))),)
        desc = (
            "vehicle flying straight at 1.5 m/s past a static ball 3 m to its right: the ball"
            " crosses from the front view to the right and the rear (quad rig)"
        )
    elif key == "OVERLAP":
        # Ball speed across the track = the vehicle's along it: bearing 45° right, constant.
        v_veh = _PASS_SPEED_MPS * ax
        v_ball = -_PASS_SPEED_MPS * rt
        t_contact = _OVERLAP_START_RANGE_M / float(np.linalg.norm(v_veh - v_ball))
        if duration > t_contact - 0.5:
            raise FlightTooLong(key, t_contact - 0.5, f"contact at {t_contact:.2f} s")
        meet = np.asarray(path.origin_ned_m) + v_veh * t_contact
        balls = (Ball(Trajectory.linear(vec3(meet - v_ball * t_contact), vec3(v_ball))),)
        desc = (
            "ball on a collision course from 45° right, range 15 m to 1 m: in the quad rig's"
            " front/right overlap throughout"
        )
    else:  # CAMLOSS
        balls = (
            Ball(Trajectory.static(_track_point(6.0, -2.5, -1.0)), object_id=1),
            Ball(
                Trajectory.oscillation(
                    _track_point(-6.0, 2.0, -1.0),
                    _track_dir(0.0, 1.0),
                    BALL_AMPLITUDE_M,
                    BALL_FREQ_HZ,
                    phase,
                ),
                object_id=2,
            ),
        )
        desc = (
            "a static ball ahead-left (front camera) and one oscillating behind-right (rear"
            " camera) of the back-and-forth track; the front camera dies 8 s in"
        )
    return FlightPlan(key, desc, duration, vehicle, balls)
