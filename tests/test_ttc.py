"""Time to contact from looming and the collision-course flag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.core.frames import normalize
from tcm_companion.core.ttc import TTCConfig, estimate_ttc, theil_sen_slope

R = 0.375


def approach(
    d0: float,
    speed: float,
    n: int,
    lateral_rate: float = 0.0,
    noise: float = 0.0,
    seed: int = 0,
    fps: float = 25.0,
):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fps
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


def test_the_window_is_time_not_samples() -> None:
    """0.48 s of looming, whatever the rate: the same τ from 25, 10 and 5 fps."""
    cfg = TTCConfig()
    for fps in (25.0, 10.0, 5.0):
        t, alpha, b, d = approach(10.0, 2.0, int(3 * fps), fps=fps)
        est = estimate_ttc(t, alpha, b, cfg)
        assert est.ttc_s == pytest.approx(d[-1] / 2.0, rel=0.06), fps
    # At 25 Hz the window holds 12 samples: a wrong radius 13 samples back is not used.
    t, alpha, b, _ = approach(10.0, 2.0, 30)
    bad = alpha.copy()
    bad[:-12] *= 3.0
    assert estimate_ttc(t, bad, b).ttc_s == estimate_ttc(t, alpha, b).ttc_s
    # With capture jitter a sample 0.48 s back is still outside (to the nearest frame).
    t_jit = t + np.where(np.arange(30) == 17, 0.0003, 0.0)
    assert estimate_ttc(t_jit, bad, b).ttc_s == estimate_ttc(t, alpha, b).ttc_s


def test_too_short_a_span_gives_no_estimate() -> None:
    cfg = TTCConfig()
    # 25 Hz: 10 samples span 0.36 s (< min_span_s); 11 span 0.4 s.
    assert math.isnan(estimate_ttc(*approach(10.0, 2.0, 10)[:3], cfg).ttc_s)
    assert math.isfinite(estimate_ttc(*approach(10.0, 2.0, 11)[:3], cfg).ttc_s)
    # 5 fps: the window holds 3 samples, and the fit takes the newest 6 (1 s) instead:
    # five are too few, six enough.
    assert math.isnan(estimate_ttc(*approach(10.0, 2.0, 5, fps=5.0)[:3], cfg).ttc_s)
    assert math.isfinite(estimate_ttc(*approach(10.0, 2.0, 6, fps=5.0)[:3], cfg).ttc_s)
    with pytest.raises(ValueError, match="min_span_s"):
        TTCConfig(window_s=0.2, min_span_s=0.3)


def test_a_young_track_gets_no_ttc_until_it_spans_most_of_the_window() -> None:
    """Seen on real ArduCopter SITL, the crossing flight, four runs in four: 0.2 s after a
    ball 17 m away was first tracked, the looming fit read TTC 2.7 s for a true 6.8 s at
    82 % confidence, and the copter braked 12 m short. The measured radius was 0.92 of
    the truth in the first frames and 0.96 0.2 s later (the measurements below, 25 Hz):
    a settling bias a 0.2-s span reads as looming. Over 0.4 s the same track gives TTC
    above 4 s, and a clean approach's true TTC comes out as ever."""
    t = np.arange(11) * 0.04
    ratio = np.array([0.922, 0.922, 0.944, 0.946, 0.959, 0.954, 0.975, 0.965, 0.925, 0.931, 0.946])
    d = 17.3 - 2.5 * t  # closing at 2.5 m/s: TTC ~6.9 s
    true_alpha = np.arcsin(0.375 / d)
    b = np.tile([1.0, 0.0, 0.0], (11, 1))
    measured = true_alpha * ratio
    short = estimate_ttc(t[:6], measured[:6], b[:6], TTCConfig(min_span_s=0.2))
    assert short.ttc_s < 3.0 and short.confidence > 0.8  # the false alarm, as seen
    assert math.isnan(estimate_ttc(t[:6], measured[:6], b[:6]).ttc_s)  # now: too young
    spanned = estimate_ttc(t, measured, b)
    assert not (spanned.ttc_s < 4.0)
    clean = estimate_ttc(t, true_alpha, b)
    assert clean.ttc_s == pytest.approx(d[-1] / 2.5, rel=0.05)


def test_a_slow_camera_fits_six_samples_not_the_few_in_the_window() -> None:
    """Seen on real ArduCopter SITL with the companion starved to ~8 fps: 4 samples in the
    0.48-s window, a ball 14 m away, and the looming fit read TTC 2.8 s for a true 7.3 s at
    75 % confidence (a brake 14 m short). Four samples whose radius noise (a few percent
    of a 1.5-px radius) happens to line up make a steep, tight slope; the newest six
    (0.75 s at 8 fps) do not, and on a clean approach they give the true TTC."""
    fps = 8.0
    t = np.arange(6) / fps
    d = 14.1 - 1.93 * t
    alpha = np.arcsin(0.375 / d)
    b = np.tile([1.0, 0.0, 0.0], (6, 1))
    noisy = alpha * (1.0 + np.array([0.03, 0.02, -0.03, -0.01, 0.02, 0.05]))
    window_only = estimate_ttc(t, noisy, b, TTCConfig(min_samples=3))
    assert window_only.ttc_s < 3.0 and window_only.collision_course  # the false alarm
    assert window_only.confidence > 0.9
    six = estimate_ttc(t, noisy, b)
    assert not (six.ttc_s < 3.0) and six.confidence < 0.5
    clean = estimate_ttc(t, alpha, b)
    assert clean.ttc_s == pytest.approx(d[-1] / 1.93, rel=0.01)
