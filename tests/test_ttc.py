"""Time to contact from looming and the collision-course flag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.core.frames import normalize
from tcm_companion.core.ttc import TTCConfig, estimate_ttc, theil_sen_slope

R = 0.375


def approach(
    d0: float, speed: float, n: int, lateral_rate: float = 0.0, noise: float = 0.0, seed: int = 0
):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 25.0
    d = d0 - speed * t
    alpha = np.arcsin(R / d) * (1.0 + noise * rng.normal(size=n))
    az = lateral_rate * t
    b = normalize(np.column_stack([np.cos(az), np.sin(az), np.zeros(n)]))
    return t, alpha, b, d


def test_theil_sen_ignores_an_outlier() -> None:
    t = np.arange(10.0)
    y = 2.0 * t + 1.0
    y[4] = 100.0
    slope, _ = theil_sen_slope(t, y)
    assert slope == pytest.approx(2.0)


def test_ttc_of_a_head_on_approach() -> None:
    t, alpha, b, d = approach(10.0, 2.0, 12)
    est = estimate_ttc(t, alpha, b)
    true_ttc = d[-1] / 2.0
    # The log-slope over a window estimates τ at the window's middle; within one window.
    assert est.ttc_s == pytest.approx(true_ttc, rel=0.06)
    assert est.collision_course


def test_ttc_with_noise_within_fifteen_percent() -> None:
    errs = []
    for seed in range(20):
        t, alpha, b, d = approach(8.0, 2.0, 12, noise=0.01, seed=seed)
        est = estimate_ttc(t, alpha, b)
        errs.append(abs(est.ttc_s - d[-1] / 2.0) / (d[-1] / 2.0))
    assert np.median(errs) < 0.15


def test_receding_or_constant_size_is_not_approaching() -> None:
    t, alpha, b, _ = approach(5.0, -1.0, 12)
    assert math.isnan(estimate_ttc(t, alpha, b).ttc_s)
    t, alpha, b, _ = approach(5.0, 0.0, 12, noise=0.01)
    est = estimate_ttc(t, alpha, b)
    assert math.isnan(est.ttc_s) and not est.collision_course


def test_fast_bearing_drift_is_a_near_miss_not_a_collision() -> None:
    t, alpha, b, _ = approach(10.0, 2.0, 12, lateral_rate=0.3)
    est = estimate_ttc(t, alpha, b)
    assert math.isfinite(est.ttc_s)
    assert est.miss_radii > TTCConfig().collision_miss_radii
    assert not est.collision_course


def test_too_few_samples() -> None:
    t, alpha, b, _ = approach(10.0, 2.0, 3)
    assert math.isnan(estimate_ttc(t, alpha, b).ttc_s)


def test_ttc_confidence_falls_with_noise_and_is_zero_without_ttc() -> None:
    clean = estimate_ttc(*approach(10.0, 2.0, 12)[:3])
    assert clean.confidence > 0.9
    noisy = [estimate_ttc(*approach(8.0, 2.0, 12, noise=0.03, seed=s)[:3]) for s in range(20)]
    conf = [e.confidence for e in noisy if math.isfinite(e.ttc_s)]
    assert conf and 0.0 < np.median(conf) < clean.confidence
    # the least significant approach the fit accepts (2 standard errors) is worth 0.5 or more
    assert min(conf) >= 0.5 - 1e-9
    receding = estimate_ttc(*approach(5.0, -1.0, 12)[:3])
    assert math.isnan(receding.ttc_s) and receding.confidence == 0.0
