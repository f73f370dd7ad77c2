"""The mock autopilot's vehicle: the scenario's flight, the brake manoeuvre, the exact
state and the noisy telemetry of it (sans-IO; time is the caller's µs).

The vehicle flies the scenario's closed-form trajectory (:mod:`tcm_companion.sim.scene.scenarios`) in real time
from the mock's start, past the scenario's nominal duration (the oscillating scenarios
keep oscillating; COLLISION / HEADON keep flying straight). Attitude comes from the
trajectory's acceleration exactly as the simulator computes it
(:meth:`~tcm_companion.sim.scene.scenarios.VehicleMotion.R_ned_from_body`). Its telemetry carries the
simulator's noise model (:class:`~.telemetry.TelemetryNoise`, the same as the synthetic
``.tlog``'s), drawn from a generator seeded by the configuration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ...core.frames import FloatArray
from ..scene.scenarios import FlightPlan, VehicleMotion, euler_zyx_rad
from ..scene.world import Trajectory
from .mock_types import MockAutopilotConfig, MockClock
from .telemetry import TelemetryNoise

_NOISE_SEED = 0x4D4F434B  # "MOCK"
_TRUTH_CACHE_SIZE = 16  # exact states kept (a few frames' worth of instants)


@dataclass(frozen=True)
class VehicleTruth:
    """The simulated vehicle's exact state (no telemetry noise)."""

    t_s: float  # scenario time
    position_ned_m: FloatArray
    velocity_ned_mps: FloatArray
    R_ned_from_body: FloatArray


@dataclass(frozen=True)
class BrakingPath(Trajectory):
    """A straight-line stop from ``origin_ned_m`` / ``linear_velocity_ned_mps`` at ``brake_t_s``.

    Velocity falls as ``v0 (1 + cos(π τ / T)) / 2``: the deceleration rises from zero and
    falls back to zero (no attitude step at either end), peaking at ``π |v0| / 2T``;
    ``T = π |v0| / (2 a_peak)`` and the stopping distance is ``|v0| T / 2``. Before
    ``brake_t_s`` the path extends the initial velocity (only the body-rate central
    difference looks there). A :class:`Trajectory`, so :class:`VehicleMotion` derives
    the attitude from its acceleration exactly as for the scenario's own path.
    """

    brake_t_s: float = 0.0
    stop_after_s: float = 0.0  # T

    @staticmethod
    def start(
        position_ned_m: FloatArray, velocity_ned_mps: FloatArray, t_s: float, decel_mps2: float
    ) -> BrakingPath:
        speed = float(np.linalg.norm(velocity_ned_mps))
        return BrakingPath(
            origin_ned_m=vec3(position_ned_m),
            linear_velocity_ned_mps=vec3(velocity_ned_mps),
            brake_t_s=float(t_s),
            stop_after_s=math.pi * speed / (2.0 * decel_mps2),
        )

    def _eval(self, t_s: float | FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        tau = (t - self.brake_t_s)[..., None]
        p0 = np.asarray(self.origin_ned_m)
        v0 = np.asarray(self.linear_velocity_ned_mps)
        T = self.stop_after_s
        if T <= 0.0:  # already at rest
            out = p0 + 0.0 * tau if order == 0 else np.zeros((*t.shape, 3))
            return np.asarray(out, dtype=np.float64)
        s = np.clip(tau, 0.0, T)
        w = math.pi / T
        braking = (tau > 0.0) & (tau < T)
        if order == 0:
            moved = s / 2.0 + np.sin(w * s) / (2.0 * w)
            out = np.where(tau < 0.0, tau, moved) * v0 + p0
        elif order == 1:
            factor = np.where(tau < 0.0, 1.0, 0.5 * (1.0 + np.cos(w * s)))
            out = factor * v0
        else:
            out = np.where(braking, -0.5 * w * np.sin(w * s), 0.0) * v0
        return np.asarray(out, dtype=np.float64)


def vec3(v: FloatArray) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class Brake:
    """A brake manoeuvre begun at caller time ``start_us``."""

    start_us: int
    speed_mps: float  # ground-relative speed when it began
    hover_at_us: int  # caller's clock when the vehicle is at rest
    hover_ned_m: tuple[float, float, float]


class MockVehicle:
    """The mock's vehicle in flight: exact state and measured (noisy) telemetry."""

    def __init__(self, plan: FlightPlan, config: MockAutopilotConfig, clock: MockClock) -> None:
        self.plan = plan
        self.motion: VehicleMotion = plan.vehicle
        self._clock = clock
        self._t_offset_s = config.scenario_time_offset_s
        self._rng = np.random.default_rng(np.random.SeedSequence([_NOISE_SEED, config.seed]))
        self.noise = TelemetryNoise.draw(config.telemetry, config.noise, self._rng)
        self._att_cache: tuple[int, FloatArray, FloatArray] | None = None
        # Exact states already computed, by scenario time, for the current motion: the
        # camera and the scorer ask for the same instants (cleared when the path changes).
        self._truth_cache: dict[float, VehicleTruth] = {}

    def t_s(self, now_us: int | None = None) -> float:
        """Scenario time (s) at ``now_us`` (default: the latest time seen)."""
        now = self._clock.now_us if now_us is None else int(now_us)
        return (now - self._clock.start_us) / 1e6 + self._t_offset_s

    def truth(self, now_us: int | None = None) -> VehicleTruth:
        """The exact state at ``now_us`` (default: the latest time seen); each call
        returns its own arrays."""
        t = self.t_s(now_us)
        hit = self._truth_cache.get(t)
        if hit is None:
            m = self.motion
            hit = VehicleTruth(
                t, m.position_ned_m(t), m.velocity_ned_mps(t), np.asarray(m.R_ned_from_body(t))
            )
            if len(self._truth_cache) >= _TRUTH_CACHE_SIZE:
                del self._truth_cache[next(iter(self._truth_cache))]  # the oldest
            self._truth_cache[t] = hit
        return VehicleTruth(
            hit.t_s,
            hit.position_ned_m.copy(),
            hit.velocity_ned_mps.copy(),
            hit.R_ned_from_body.copy(),
        )

    def attitude(self, now_us: int) -> tuple[FloatArray, FloatArray]:
        """Measured ``(roll, pitch, yaw)`` and ``(p, q, r)``, drawn once per instant so
        ATTITUDE and ATTITUDE_QUATERNION sent together agree."""
        if self._att_cache is not None and self._att_cache[0] == now_us:
            return self._att_cache[1], self._att_cache[2]
        t = self.t_s(now_us)
        R_ned_from_body, rates_rps = self.motion.attitude_and_rates(t)
        eul, rates = self.noise.attitude(euler_zyx_rad(R_ned_from_body), rates_rps, self._rng)
        self._att_cache = (now_us, eul, rates)
        return eul, rates

    def local_position(self, now_us: int) -> tuple[FloatArray, FloatArray]:
        """Measured LOCAL_POSITION_NED position and velocity."""
        t = self.t_s(now_us)
        return self.noise.local_position(
            self.motion.position_ned_m(t), self.motion.velocity_ned_mps(t), self._rng
        )

    def redraw(self) -> None:
        """The next attitude is drawn anew even at the same instant (a reboot)."""
        self._att_cache = None

    def start_brake(self, now_us: int, decel_mps2: float) -> Brake:
        """From ``now_us`` on, a smooth straight stop to a hover (:class:`BrakingPath`)."""
        t = self.t_s(now_us)
        vel = self.motion.velocity_ned_mps(t)
        path = BrakingPath.start(self.motion.position_ned_m(t), vel, t, decel_mps2)
        self.motion = replace(self.motion, path=path)
        self._att_cache = None
        self._truth_cache.clear()
        return Brake(
            now_us,
            float(np.linalg.norm(vel)),
            now_us + math.ceil(path.stop_after_s * 1e6),
            vec3(path.position_ned_m(t + path.stop_after_s)),
        )
