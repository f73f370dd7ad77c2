"""Rotation conventions: MAVLink ZYX Euler, quaternions, slerp."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tcm_companion.core.frames import (
    angle_between,
    azel_from_bearing,
    bearing_from_azel,
    euler_zyx_from_rot,
    quat_wxyz_from_rot,
    rot_from_euler_zyx,
    rot_from_quat_wxyz,
    slerp_rotation,
)

angles = st.floats(-3.0, 3.0)


@given(angles, st.floats(-1.5, 1.5), angles)
def test_euler_matches_scipy_intrinsic_zyx_and_inverts(
    roll: float, pitch: float, yaw: float
) -> None:
    R = rot_from_euler_zyx(roll, pitch, yaw)
    ref = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    np.testing.assert_allclose(R, ref, atol=1e-12)
    r2, p2, y2 = euler_zyx_from_rot(R)
    np.testing.assert_allclose(rot_from_euler_zyx(r2, p2, y2), R, atol=1e-9)


def test_yaw_turns_forward_to_east() -> None:
    R = rot_from_euler_zyx(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    # Positive pitch raises the nose: forward gets a negative down component.
    R = rot_from_euler_zyx(0.0, 0.1, 0.0)
    assert (R @ [1.0, 0.0, 0.0])[2] < 0


@given(angles, st.floats(-1.5, 1.5), angles)
def test_quaternion_scalar_first_round_trip(roll: float, pitch: float, yaw: float) -> None:
    R = rot_from_euler_zyx(roll, pitch, yaw)
    q = quat_wxyz_from_rot(R)
    assert q[0] >= 0
    np.testing.assert_allclose(rot_from_quat_wxyz(q), R, atol=1e-12)


def test_nan_quaternion_gives_nan_matrix() -> None:
    assert np.all(np.isnan(rot_from_quat_wxyz(np.array([np.nan, 0, 0, 0]))))


def test_slerp_is_constant_rate() -> None:
    R0 = rot_from_euler_zyx(0.0, 0.0, 0.0)
    R1 = rot_from_euler_zyx(0.0, 0.0, 0.4)
    np.testing.assert_allclose(
        slerp_rotation(R0, R1, 0.25), rot_from_euler_zyx(0, 0, 0.1), atol=1e-12
    )
    np.testing.assert_allclose(
        slerp_rotation(R0, R1, 1.5), rot_from_euler_zyx(0, 0, 0.6), atol=1e-12
    )


@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5))
def test_azel_round_trip(az: float, el: float) -> None:
    b = bearing_from_azel(np.asarray(az), np.asarray(el))
    a2, e2 = azel_from_bearing(b)
    assert float(a2) == pytest.approx(az, abs=1e-12)
    assert float(e2) == pytest.approx(el, abs=1e-12)


def test_angle_between_is_stable_near_zero() -> None:
    a = np.array([1.0, 0.0, 0.0])
    b = np.array([1.0, 1e-10, 0.0])
    assert float(angle_between(a, b)) == pytest.approx(1e-10, rel=1e-6)


def test_cross3_matches_numpy_with_broadcasting() -> None:
    from tcm_companion.core.frames import cross3

    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 1, 3)), rng.normal(size=(4, 3))
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b), atol=1e-15)
    np.testing.assert_allclose(cross3(a[0, 0], b[0]), np.cross(a[0, 0], b[0]), atol=1e-15)
