"""Translation direction from bearings, positions and velocities, and their fusion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tcm_companion.core.egomotion import (
    EgomotionConfig,
    TranslationEstimate,
    fuse,
    translation_from_bearings,
    translation_from_positions,
)
from tcm_companion.core.frames import angle_between, normalize
from tools.egomotion_study import translation_from_velocities


def static_scene(
    rng: np.random.Generator, T_ned_m: np.ndarray, n: int = 300
) -> tuple[np.ndarray, np.ndarray]:
    """Bearings from the origin and from ``T`` of static points 2–20 m away, all around."""
    d = normalize(rng.normal(size=(n, 3)))
    P = d * rng.uniform(2.0, 20.0, size=(n, 1))
    return normalize(P), normalize(P - T_ned_m)


def perturb(rng: np.random.Generator, b: np.ndarray, sigma_rad: float) -> np.ndarray:
    """Bearings rotated by small random rotations (σ per axis)."""
    rv = rng.normal(0.0, sigma_rad, size=b.shape)
    return normalize(b + np.cross(rv, b))


def t_strategy() -> st.SearchStrategy[tuple[float, float, float]]:
    return st.tuples(*(st.floats(-1.0, 1.0, allow_nan=False) for _ in range(3)))


@settings(max_examples=40, deadline=None)
@given(t=t_strategy(), seed=st.integers(0, 2**31 - 1))
def test_exact_bearings_give_the_direction_to_1e9(t: tuple[float, float, float], seed: int) -> None:
    T = np.array(t)
    assume(0.2 <= np.linalg.norm(T) <= 1.5)
    rng = np.random.default_rng(seed)
    b0, b1 = static_scene(rng, T)
    est = translation_from_bearings(b0, b1, rng_seed=seed)
    assert est.source == "vision"
    # Exact even when the parallax is too small to trust the direction in real data.
    assert est.valid == (est.parallax_rad >= EgomotionConfig().min_parallax_rad)
    assert float(angle_between(est.t_hat_ned, T)) < 1e-9  # sign included
    assert math.isnan(est.magnitude_m)
    assert est.inlier_ratio == 1.0
    assert np.linalg.norm(est.rotation_ned_rad) < 1e-9


@settings(max_examples=25, deadline=None)
@given(t=t_strategy(), seed=st.integers(0, 2**31 - 1))
def test_noise_and_30_percent_outliers_degrade_gracefully(
    t: tuple[float, float, float], seed: int
) -> None:
    T = np.array(t)
    assume(0.5 <= np.linalg.norm(T) <= 1.5)
    rng = np.random.default_rng(seed)
    b0, b1 = static_scene(rng, T, n=300)
    b0, b1 = perturb(rng, b0, 0.001), perturb(rng, b1, 0.001)
    clean = translation_from_bearings(b0, b1, rng_seed=seed)
    # Outliers as tracking gives them: a third of the points jump by up to ~6°.
    bad = rng.choice(len(b1), 90, replace=False)
    b1_out = b1.copy()
    b1_out[bad] = perturb(rng, b1[bad], 0.05)
    est = translation_from_bearings(b0, b1_out, rng_seed=seed)
    assert clean.valid and est.valid
    assert float(angle_between(clean.t_hat_ned, T)) < math.radians(1.0)
    assert float(angle_between(est.t_hat_ned, T)) < math.radians(1.5)
    assert 0.6 <= est.inlier_ratio <= 0.85  # some jumps happen to run along the epipolar plane
    # The reported uncertainty is of the right order.
    assert float(angle_between(est.t_hat_ned, T)) < 5.0 * est.sigma_rad


def test_uniformly_random_outliers_are_rejected() -> None:
    rng = np.random.default_rng(7)
    T = np.array([0.4, -0.3, 0.1])
    b0, b1 = static_scene(rng, T, n=400)
    b0, b1 = perturb(rng, b0, 0.001), perturb(rng, b1, 0.001)
    bad = rng.choice(400, 120, replace=False)
    b1[bad] = normalize(rng.normal(size=(120, 3)))
    est = translation_from_bearings(b0, b1, rng_seed=1)
    assert est.valid
    assert float(angle_between(est.t_hat_ned, T)) < math.radians(1.5)


@pytest.mark.parametrize("seed", range(5))
def test_residual_rotation_is_estimated_and_removed(seed: int) -> None:
    """An attitude error between the frames looks like rotational flow; it is absorbed."""
    rng = np.random.default_rng(seed)
    T = normalize(rng.normal(size=3)) * 0.5
    b0, b1_true = static_scene(rng, T, n=300)
    err = Rotation.from_rotvec(rng.normal(0.0, math.radians(1.0), 3))
    b1 = err.apply(b1_true)
    est = translation_from_bearings(b0, b1, rng_seed=seed)
    plain = translation_from_bearings(b0, b1, EgomotionConfig(rotation_prior_rad=0.0), seed)
    assert est.valid
    assert float(angle_between(est.t_hat_ned, T)) < 1e-3
    assert float(angle_between(est.t_hat_ned, T)) < 0.2 * float(angle_between(plain.t_hat_ned, T))
    corrected = Rotation.from_rotvec(est.rotation_ned_rad).apply(b1)
    assert np.max(angle_between(corrected, b1_true)) < 1e-3


@pytest.mark.parametrize("direction", [(1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, -1, 0)])
def test_sign_static_points_recede_from_the_translation(direction: tuple[int, int, int]) -> None:
    rng = np.random.default_rng(3)
    T = 0.5 * normalize(np.array(direction, dtype=float))
    b0, b1 = static_scene(rng, T)
    est = translation_from_bearings(b0, b1)
    assert float(np.dot(est.t_hat_ned, T)) > 0.99 * np.linalg.norm(T)
    # Swapping the frames reverses the motion.
    back = translation_from_bearings(b1, b0)
    assert float(np.dot(back.t_hat_ned, T)) < -0.99 * np.linalg.norm(T)


def test_forward_flight_with_points_on_one_side_only() -> None:
    """Ground ahead and below a forward-looking camera: the epipole is in view."""
    rng = np.random.default_rng(11)
    n = 300
    P = np.column_stack(
        [rng.uniform(3, 15, n), rng.uniform(-8, 8, n), np.full(n, 2.0)]
    )  # ground 2 m below
    T = np.array([0.8, 0.1, 0.0])
    b0, b1 = normalize(P), normalize(P - T)
    est = translation_from_bearings(perturb(rng, b0, 5e-4), perturb(rng, b1, 5e-4))
    assert est.valid
    assert float(angle_between(est.t_hat_ned, T)) < math.radians(2.0)


@pytest.mark.parametrize("noise", [0.0, 0.001])
def test_hover_is_invalid(noise: float) -> None:
    rng = np.random.default_rng(5)
    b0, b1 = static_scene(rng, np.zeros(3))
    if noise:
        b0, b1 = perturb(rng, b0, noise), perturb(rng, b1, noise)
    est = translation_from_bearings(b0, b1)
    assert not est.valid
    assert est.parallax_rad < EgomotionConfig().min_parallax_rad or math.isnan(est.parallax_rad)


def test_hover_with_attitude_error_is_invalid() -> None:
    """Pure rotation is parallax for the raw angle but not after the rotation is removed."""
    rng = np.random.default_rng(6)
    b0, b1 = static_scene(rng, np.zeros(3))
    b1 = Rotation.from_rotvec([0.01, -0.02, 0.015]).apply(perturb(rng, b1, 0.001))
    est = translation_from_bearings(perturb(rng, b0, 0.001), b1)
    assert not est.valid


def test_tiny_baseline_reports_a_large_uncertainty() -> None:
    rng = np.random.default_rng(8)
    T = np.array([1.0, 0.0, 0.0])
    b0, b1 = static_scene(rng, T * 0.5)
    big = translation_from_bearings(perturb(rng, b0, 1e-3), perturb(rng, b1, 1e-3))
    b0, b1 = static_scene(rng, T * 0.03)
    small = translation_from_bearings(perturb(rng, b0, 1e-3), perturb(rng, b1, 1e-3))
    assert small.sigma_rad > 5 * big.sigma_rad
    assert small.parallax_rad < big.parallax_rad


def test_too_few_or_invalid_points() -> None:
    rng = np.random.default_rng(9)
    b0, b1 = static_scene(rng, np.array([0.5, 0.0, 0.0]), n=5)
    est = translation_from_bearings(b0, b1)
    assert not est.valid and np.all(np.isnan(est.t_hat_ned))
    empty = translation_from_bearings(np.zeros((0, 3)), np.zeros((0, 3)))
    assert not empty.valid and empty.n_points == 0


def test_nan_rows_are_ignored() -> None:
    rng = np.random.default_rng(10)
    T = np.array([0.2, 0.5, -0.1])
    b0, b1 = static_scene(rng, T)
    b1[::7] = np.nan
    est = translation_from_bearings(b0, b1)
    assert est.valid and est.n_points == len(b0) - len(b0[::7])
    assert float(angle_between(est.t_hat_ned, T)) < 1e-9


def test_deterministic_for_a_seed() -> None:
    rng = np.random.default_rng(12)
    T = np.array([0.3, 0.3, 0.0])
    b0, b1 = static_scene(rng, T)
    b0, b1 = perturb(rng, b0, 0.002), perturb(rng, b1, 0.002)
    a = translation_from_bearings(b0, b1, rng_seed=4)
    b = translation_from_bearings(b0, b1, rng_seed=4)
    np.testing.assert_array_equal(a.t_hat_ned, b.t_hat_ned)
    assert a.sigma_rad == b.sigma_rad


# -- autopilot ---------------------------------------------------------------------------
def test_positions_give_direction_and_magnitude() -> None:
    est = translation_from_positions(np.array([1.0, 2.0, -2.0]), np.array([1.3, 2.4, -2.0]))
    assert est.valid and est.source == "autopilot"
    np.testing.assert_allclose(est.t_hat_ned, [0.6, 0.8, 0.0], atol=1e-12)
    assert est.magnitude_m == pytest.approx(0.5)
    assert est.sigma_rad == pytest.approx(math.atan2(2 * EgomotionConfig().position_sigma_m, 0.5))


def test_positions_too_close_are_invalid() -> None:
    p = np.array([0.0, 0.0, -2.0])
    assert not translation_from_positions(p, p).valid
    assert not translation_from_positions(p, p + np.array([0.1, 0.0, 0.0])).valid  # σ ≈ 17°
    assert translation_from_positions(
        p, p + np.array([0.1, 0.0, 0.0]), position_sigma_m=0.002
    ).valid


def test_integrated_velocity() -> None:
    t_us = np.arange(0, 1_000_001, 40_000)
    v = np.tile([0.5, -0.5, 0.0], (len(t_us), 1))
    est = translation_from_velocities(t_us, v)
    assert est.valid
    assert est.magnitude_m == pytest.approx(math.sqrt(0.5))
    np.testing.assert_allclose(est.t_hat_ned, normalize(np.array([1.0, -1.0, 0.0])), atol=1e-12)
    assert not translation_from_velocities(t_us[:1], v[:1]).valid


# -- fusion ------------------------------------------------------------------------------
def _est(
    t: tuple[float, float, float], sigma: float, source: str, mag: float = math.nan
) -> TranslationEstimate:
    return TranslationEstimate(
        t_hat_ned=normalize(np.array(t, dtype=float)),
        source=source,
        magnitude_m=mag,
        parallax_rad=0.05 if source == "vision" else math.nan,
        inlier_ratio=0.9,
        n_points=300,
        sigma_rad=sigma,
        valid=True,
    )


def test_fuse_agreeing_estimates_weights_by_variance() -> None:
    v = _est((1.0, 0.0, 0.0), 0.01, "vision")
    a = _est((1.0, 0.02, 0.0), 0.02, "autopilot", mag=0.8)
    f = fuse(v, a)
    assert f.valid and f.source == "fused"
    assert f.magnitude_m == 0.8
    assert f.sigma_rad < 0.01
    # Four times the weight on vision: the fused direction sits a fifth of the way over.
    ang = math.atan2(f.t_hat_ned[1], f.t_hat_ned[0])
    assert ang == pytest.approx(math.atan(0.02) / 5, rel=0.05)


def test_fuse_disagreeing_estimates_takes_the_more_certain() -> None:
    v = _est((1.0, 0.0, 0.0), 0.01, "vision")
    a = _est((0.0, 1.0, 0.0), 0.05, "autopilot", mag=0.8)
    assert fuse(v, a).source == "vision"
    v_bad = _est((1.0, 0.0, 0.0), 0.2, "vision")
    assert fuse(v_bad, a).source == "autopilot"


def test_fuse_with_one_or_no_valid_input() -> None:
    v = _est((1.0, 0.0, 0.0), 0.01, "vision")
    a = _est((1.0, 0.0, 0.0), 0.02, "autopilot", mag=0.8)
    bad_v = TranslationEstimate.invalid("vision")
    bad_a = TranslationEstimate.invalid("autopilot")
    assert fuse(bad_v, a) is a
    assert fuse(v, bad_a) is v
    out = fuse(bad_v, bad_a)
    assert not out.valid and out.source == "fused"
