"""The simulator's speed-ups give the same bits as the code they replaced.

Speed itself is measured (``tools/render_speed.py``, ``sitl --clock virtual``), not
asserted here. These tests pin what a faster path must not change: the vehicle attitude
of :class:`~tcm_companion.sim.scene.scenarios.VehicleMotion` (written out instead of
``numpy.cross``, all sinusoids in one sine call, ``t ± h`` evaluated together) equals,
byte for byte, the straightforward formulation it replaced; and the mock vehicle's cache
of exact states hands out independent arrays.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tcm_companion.sim.scene.scenarios import (
    GRAVITY_MPS2,
    SCENARIO_NAMES,
    VehicleMotion,
    flight_plan,
)
from tcm_companion.sim.vehicle.mock_vehicle import BrakingPath


def _sines_reference(terms: tuple[tuple[float, float, float], ...], t: np.ndarray) -> np.ndarray:
    out = np.zeros_like(t)
    for amp, f, ph in terms:
        out = out + amp * np.sin(2.0 * math.pi * f * t + ph)
    return out


def _rot_zyx_reference(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def _R_ned_from_body_reference(m: VehicleMotion, t_s: float | np.ndarray) -> np.ndarray:
    """The attitude as it was computed before the speed-up (numpy.cross, one sine call
    per term, np.stack)."""
    t = np.asarray(t_s, dtype=np.float64)
    flat = t.reshape(-1)
    acc = m.path.acceleration_ned_mps2(flat)
    z_b = np.array([0.0, 0.0, GRAVITY_MPS2]) - acc
    z_b /= np.linalg.norm(z_b, axis=1, keepdims=True)
    yaw = m.heading_rad + _sines_reference(m.yaw_terms, flat)
    x_c = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=1)
    y_b = np.cross(z_b, x_c)
    y_b /= np.linalg.norm(y_b, axis=1, keepdims=True)
    x_b = np.cross(y_b, z_b)
    base = np.stack([x_b, y_b, z_b], axis=2)
    turb = _rot_zyx_reference(
        _sines_reference(m.roll_terms, flat),
        _sines_reference(m.pitch_terms, flat),
        np.zeros_like(flat),
    )
    return (base @ turb).reshape(*t.shape, 3, 3)


def _body_rates_reference(m: VehicleMotion, t_s: float, h_s: float = 1e-3) -> np.ndarray:
    t = np.asarray(t_s, dtype=np.float64)
    R0 = _R_ned_from_body_reference(m, t)
    dR = (_R_ned_from_body_reference(m, t + h_s) - _R_ned_from_body_reference(m, t - h_s)) / (
        2.0 * h_s
    )
    W = np.swapaxes(R0, -1, -2) @ dR
    return 0.5 * np.stack(
        [W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
        axis=-1,
    )


def _motions() -> list[tuple[str, VehicleMotion]]:
    out = []
    for name in SCENARIO_NAMES:
        m = flight_plan(name).vehicle
        out.append((name, m))
        brake = BrakingPath.start(m.position_ned_m(3.0), m.velocity_ned_mps(3.0), 3.0, 4.0)
        out.append((f"{name}+brake", replace(m, path=brake)))
    return out


_TIMES_S = [0.0, 1e-3, 0.04, 2.96, 3.0, 3.5, 12.345678, 59.96, -0.5]


@pytest.mark.parametrize(
    ("name", "motion"), _motions(), ids=lambda v: v if isinstance(v, str) else ""
)
def test_attitude_same_bits_as_the_reference(name: str, motion: VehicleMotion) -> None:
    for t in _TIMES_S:
        want_R = _R_ned_from_body_reference(motion, t)
        want_w = _body_rates_reference(motion, t)
        assert motion.R_ned_from_body(t).tobytes() == want_R.tobytes(), (name, t)
        assert motion.body_rates_rps(t).tobytes() == want_w.tobytes(), (name, t)
        R, w = motion.attitude_and_rates(t)
        assert R.tobytes() == want_R.tobytes() and w.tobytes() == want_w.tobytes(), (name, t)
    ts = np.array(_TIMES_S)
    assert motion.R_ned_from_body(ts).tobytes() == _R_ned_from_body_reference(motion, ts).tobytes()
    grid = ts.reshape(3, 3)
    assert (
        motion.R_ned_from_body(grid).tobytes() == _R_ned_from_body_reference(motion, grid).tobytes()
    )


def test_mock_vehicle_truth_cache_hands_out_independent_arrays() -> None:
    from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot
    from tcm_companion.sim.vehicle.mock_types import MockAutopilotConfig

    mock = MockAutopilot(MockAutopilotConfig(scenario="T90"), 1_000_000)
    t_us = 1_500_000
    first = mock.vehicle_truth(t_us)
    expected = first.R_ned_from_body.copy()
    first.R_ned_from_body[:] = 0.0  # a caller scribbling on its copy
    first.position_ned_m[:] = 0.0
    again = mock.vehicle_truth(t_us)
    assert again.R_ned_from_body.tobytes() == expected.tobytes()
    m = mock.vehicle.motion
    t_s = mock.vehicle.t_s(t_us)
    assert again.position_ned_m.tobytes() == m.position_ned_m(t_s).tobytes()
    assert again.R_ned_from_body.tobytes() == np.asarray(m.R_ned_from_body(t_s)).tobytes()
