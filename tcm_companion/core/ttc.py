"""Time to contact from looming, and the collision-course test.

For a sphere of radius r at range d, ``sin α = r/d``, so ``d/dt ln sin α = -ḋ/d = 1/τ``:
the time to contact τ (range over closing speed, centre range) is the inverse slope of
``ln sin α`` against time. The slope is fitted robustly (Theil–Sen: the median of all
pairwise slopes) over a short recent window, so a single bad radius measurement cannot
swing it. The window is a span of capture time (``window_s``), so it means the same at
any frame rate; it holds fewer samples at a lower rate.

Collision course: constant bearing with decreasing range. With the bearing's angular
rate ω in the local-level frame, an object on a straight relative path passes at
``d_min ≈ d·ω·τ``; in units of the object's own radius that is ``ω·τ / sin α``, which
needs no range. The flag is raised when that predicted miss distance is small.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .frames import FloatArray, vector_norm
from .timebase import jitter_slack_s, median, median_columns


@dataclass(frozen=True)
class TTCConfig:
    # The looming fit uses the samples captured less than window_s before the newest
    # (12 frames at 25 Hz), and at least the newest min_samples: a slower camera's fit
    # spans longer (6 samples: 0.6 s at 10 fps, 1 s at 5 fps) rather than resting on a
    # few points.
    window_s: float = 0.48
    # No estimate from samples spanning less than min_span_s (10 frame intervals at
    # 25 Hz: a track must be that old) or from fewer than min_samples. The fit's error
    # comes from the spread of its pairwise slopes, which for 3 to 5 points can be tiny by
    # chance: a companion starved to ~8 fps read TTC 2.8 s for a true 7.3 s, at 75 %
    # confidence, from 4 points. And a young track's size bias still settles: on real
    # ArduCopter SITL a ball 17 m away measured 0.92 of its size at first and 0.96 0.2 s
    # later, which a 0.2-s span read as TTC 2.7 s (true 6.8 s) at 82 % confidence.
    min_span_s: float = 0.4
    min_samples: int = 6
    max_ttc_s: float = 30.0  # slower looming than this counts as "not approaching"
    min_significance: float = 2.0  # slope must exceed this many of its own spreads
    collision_miss_radii: float = 4.0  # predicted miss within this many object radii
    collision_max_ttc_s: float = 10.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ValueError(f"window_s must be > 0, got {self.window_s}")
        if not (math.isfinite(self.min_span_s) and 0 <= self.min_span_s < self.window_s):
            raise ValueError(f"min_span_s must be >= 0 and below window_s, got {self.min_span_s}")
        if self.min_samples < 3:
            raise ValueError(f"min_samples must be at least 3, got {self.min_samples}")


@dataclass(frozen=True)
class TTCEstimate:
    ttc_s: float  # NaN when not approaching
    slope_per_s: float  # d/dt ln sin α
    miss_radii: float  # predicted miss distance over object radius (NaN if unknown)
    collision_course: bool
    # Relative standard error of the looming rate, and so of the time to contact
    # (σ_τ/τ = σ_slope/slope); NaN when there is no time to contact.
    rel_stderr: float = math.nan

    @property
    def confidence(self) -> float:
        """Confidence in ``ttc_s`` and ``collision_course``, 0..1: ``1 - rel_stderr``
        (0 when there is no time to contact). At the approach test's least significance
        (slope = 2 standard errors) it is 0.5. Independent of the TCM state."""
        if not math.isfinite(self.ttc_s) or not math.isfinite(self.rel_stderr):
            return 0.0
        return max(0.0, min(1.0, 1.0 - self.rel_stderr))


@functools.lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.triu_indices(n, k=1)
    return i, j


def theil_sen_slope(t_s: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Median pairwise slope and a robust spread of the pairwise slopes (MAD·1.4826)."""
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(y, dtype=np.float64)
    i, j = _pairs(len(t))
    dt = t[j] - t[i]
    keep = dt > 0
    if not keep.any():
        return math.nan, math.nan
    slopes = (v[j] - v[i])[keep] / dt[keep]
    med = median(slopes)
    spread = 1.4826 * median(np.abs(slopes - med))
    return med, spread


def robust_level_at(t_s: FloatArray, y: FloatArray, t_eval_s: float) -> float:
    """The value at ``t_eval_s`` of a robust straight line through ``(t_s, y)``: the
    Theil–Sen slope (:func:`theil_sen_slope`) and the median of the residual levels
    ``y - slope·(t - t_eval_s)``. With samples spread evenly around ``t_eval_s`` the noise
    of one sample shrinks by about √N; a single sample is returned as it is; NaN when
    empty. Times in seconds, any origin (``t_eval_s`` on the same clock)."""
    t = np.asarray(t_s, dtype=np.float64)
    v = np.asarray(y, dtype=np.float64)
    if len(t) == 0:
        return math.nan
    if len(t) == 1:
        return float(v[0])
    slope, _ = theil_sen_slope(t, v)
    if not math.isfinite(slope):
        slope = 0.0
    return median(v - slope * (t - t_eval_s))


def estimate_ttc(
    t_s: FloatArray,
    alpha_rad: FloatArray,
    bearing_ned: FloatArray,
    config: TTCConfig = TTCConfig(),
) -> TTCEstimate:
    """TTC and collision flag from the recent samples of one track.

    ``t_s`` (N,) capture times in seconds, increasing, ``alpha_rad`` (N,) angular radii,
    ``bearing_ned`` (N, 3) unit bearings in the local-level frame; only the samples
    captured less than ``config.window_s`` before the last are used (to the nearest frame:
    within a quarter frame period of the window's start counts as outside), or the newest
    ``config.min_samples`` usable ones when the window holds fewer.
    """
    t = np.asarray(t_s, dtype=np.float64)
    a = np.asarray(alpha_rad, dtype=np.float64)
    b = np.asarray(bearing_ned, dtype=np.float64).reshape(-1, 3)
    nothing = TTCEstimate(math.nan, math.nan, math.nan, False)
    if len(t) == 0 or not math.isfinite(t[-1]):
        return nothing
    steps = np.diff(t)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    slack_s = jitter_slack_s(median(steps) if len(steps) else math.nan)
    usable = np.isfinite(t) & np.isfinite(a) & (a > 0)
    ok = usable & (t[-1] - t < config.window_s - slack_s)
    if ok.sum() < config.min_samples:
        newest = np.flatnonzero(usable)[-config.min_samples :]
        if len(newest) < config.min_samples:
            return nothing
        ok = np.zeros_like(usable)
        ok[newest] = True
    t, a, b = t[ok], a[ok], b[ok]
    if t[-1] - t[0] < config.min_span_s - slack_s:
        return nothing
    slope, spread = theil_sen_slope(t - t[0], np.log(np.sin(a)))
    if not math.isfinite(slope):
        return nothing
    # The spread of pairwise slopes shrinks with the number of pairs; compare the slope
    # with the standard error of a median over the window, not with a single pair.
    stderr = spread / math.sqrt(len(t))
    approaching = slope > 1.0 / config.max_ttc_s and slope > config.min_significance * stderr
    if not approaching:
        return TTCEstimate(math.nan, slope, math.nan, False)
    rel = stderr / slope
    # A straight-line fit over the window measures the looming rate at the window's
    # middle (ln sin α is convex in time on an approach); contact is that much closer now.
    ttc = 1.0 / slope - float(t[-1] - median(t))
    if ttc <= 0:
        ttc = 1.0 / slope
    # Bearing rate from the first and last thirds (robust to one bad bearing).
    n3 = max(1, len(t) // 3)
    b_first = np.array(median_columns(b[:n3]))
    b_last = np.array(median_columns(b[-n3:]))
    dt = median(t[-n3:]) - median(t[:n3])
    if dt <= 0:
        return TTCEstimate(ttc, slope, math.nan, False, rel)
    cosang = float(np.dot(b_first, b_last) / (vector_norm(b_first) * vector_norm(b_last)))
    omega = math.acos(max(-1.0, min(1.0, cosang))) / dt
    miss = omega * ttc / math.sin(median(a[-n3:]))
    collision = miss < config.collision_miss_radii and ttc < config.collision_max_ttc_s
    return TTCEstimate(ttc, slope, miss, collision, rel)
