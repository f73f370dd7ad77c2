"""Durations on the frame clock: the method counts seconds, not frames.

The paper's interval, hold and warm-ups are frame counts at 25 Hz (25 frames = 1 s). A
companion that cannot keep up runs at whatever rate it manages, and 25 frames at 8 fps
are 3 s, about one period of an oscillating object: the triangle closes again. So every
duration of the method is stated in seconds and compared with the capture times of the
frames it spans.

Capture times jitter (a camera's clock, a busy reader thread), and a duration is usually
a whole number of frame periods, so "is this pair 1 s apart" is asked with a small
allowance: a quarter of the recent frame period (:func:`jitter_slack_s`). A frame within
it of the boundary counts as on it. At a steady rate that is exactly the old frame count
(25 frames at 25 Hz is "1 s"), and no jitter smaller than a quarter period moves a
decision by a frame.

Memory is bounded by frame counts sized for the fastest rate supported,
:data:`MAX_FRAME_RATE_HZ` (:func:`frames_to_cover`); faster cameras still work, with
histories that span less time.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence

import numpy as np

#: The fastest frame rate every history is sized for (frames per second).
MAX_FRAME_RATE_HZ = 60.0

#: A quarter of a frame period: how near a boundary a capture time counts as on it.
JITTER_FRACTION = 0.25


def frames_to_cover(span_s: float, rate_hz: float = MAX_FRAME_RATE_HZ) -> int:
    """Frames (and so ring entries) that hold ``span_s`` seconds at ``rate_hz``: the
    frames of the span, both ends included, plus one spare."""
    return math.ceil(max(0.0, span_s) * rate_hz) + 2


def median_period_s(times_us: Iterable[int]) -> float:
    """Median step between consecutive capture times (s), given in either order; NaN
    with fewer than two."""
    t = [float(x) for x in times_us]
    steps = [s for a, b in itertools.pairwise(t) if (s := abs(b - a)) > 0]
    return median(steps) * 1e-6 if steps else math.nan


def median(values: Sequence[float] | np.ndarray) -> float:
    """``float(np.median(values))`` of a 1-D sequence, to the bit, without its overhead
    (tens of microseconds per call, which the per-object path paid several times).

    The middle value, or the mean of the two middle values computed as numpy does
    (``(a + b) / 2``); NaN when empty or when any value is NaN (sorted last).
    """
    v = np.sort(np.asarray(values, dtype=np.float64))
    n = len(v)
    if n == 0 or v[-1] != v[-1]:
        return math.nan
    k = n // 2
    if n % 2:
        return float(v[k])
    return (float(v[k - 1]) + float(v[k])) / 2.0


def median_columns(values: np.ndarray) -> list[float]:
    """:func:`median` of each column of a 2-D array, to the bit, from one sort along the
    rows (the looming fit's bearing medians: one call instead of three)."""
    v = np.sort(np.asarray(values, dtype=np.float64), axis=0)
    n = len(v)
    if n == 0:
        return [math.nan] * v.shape[1]
    k = n // 2
    last = v[-1].tolist()
    if n % 2:
        mid = v[k].tolist()
        return [math.nan if x != x else m for x, m in zip(last, mid, strict=True)]
    lo, hi = v[k - 1].tolist(), v[k].tolist()
    return [math.nan if x != x else (a + b) / 2.0 for x, a, b in zip(last, lo, hi, strict=True)]


def jitter_slack_s(period_s: float) -> float:
    """The allowance for capture-time jitter at frame period ``period_s``: a quarter of
    it (0 when the period is unknown)."""
    return JITTER_FRACTION * period_s if math.isfinite(period_s) and period_s > 0 else 0.0
