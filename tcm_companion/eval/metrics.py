"""Classification metrics of the paper: accuracy, ROC and its area, separation.

Positive means *moving*. Scores are "larger = more likely moving" (TCM disparity, ECM
angle, BSM pixel count); a threshold ``th`` decides moving iff ``score > th``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.frames import FloatArray


@dataclass(frozen=True)
class Confusion:
    tp: int
    tn: int
    fp: int
    fn: int

    @property
    def n(self) -> int:
        return self.tp + self.tn + self.fp + self.fn

    @property
    def accuracy(self) -> float:
        return (self.tp + self.tn) / self.n if self.n else math.nan

    @property
    def tpr(self) -> float:
        return self.tp / (self.tp + self.fn) if (self.tp + self.fn) else math.nan

    @property
    def fpr(self) -> float:
        return self.fp / (self.fp + self.tn) if (self.fp + self.tn) else math.nan


def confusion(truth_moving: np.ndarray, predicted_moving: np.ndarray) -> Confusion:
    t = np.asarray(truth_moving, dtype=bool)
    p = np.asarray(predicted_moving, dtype=bool)
    return Confusion(
        tp=int(np.sum(t & p)),
        tn=int(np.sum(~t & ~p)),
        fp=int(np.sum(~t & p)),
        fn=int(np.sum(t & ~p)),
    )


@dataclass(frozen=True)
class ROC:
    thresholds: FloatArray  # descending; decision is score > threshold
    fpr: FloatArray
    tpr: FloatArray
    accuracy: FloatArray
    auc: float
    best_threshold: float
    best_accuracy: float


def roc(truth_moving: np.ndarray, score: np.ndarray) -> ROC:
    """ROC over every distinct threshold; AUC by the trapezoid rule (ties handled).

    ``best_threshold`` maximises accuracy; it is placed midway between the two
    neighbouring distinct scores so that it generalises rather than sitting on a sample.
    """
    t = np.asarray(truth_moving, dtype=bool)
    s = np.asarray(score, dtype=np.float64)
    keep = np.isfinite(s)
    t, s = t[keep], s[keep]
    n_pos, n_neg = int(t.sum()), int((~t).sum())
    if n_pos == 0 or n_neg == 0 or len(s) == 0:
        empty = np.array([], dtype=np.float64)
        return ROC(empty, empty, empty, empty, math.nan, math.nan, math.nan)
    order = np.argsort(-s, kind="mergesort")
    s_sorted, t_sorted = s[order], t[order]
    distinct = np.r_[np.nonzero(np.diff(s_sorted))[0], len(s_sorted) - 1]
    tps = np.cumsum(t_sorted)[distinct]
    fps = (distinct + 1) - tps
    tpr = np.r_[0.0, tps / n_pos]
    fpr = np.r_[0.0, fps / n_neg]
    auc = float(np.trapezoid(tpr, fpr))
    # Threshold just below each distinct score (everything >= it is called moving).
    vals = s_sorted[distinct]
    below = np.r_[vals[1:], vals[-1] - 1.0]
    thresholds = np.r_[vals[0] + 1.0, 0.5 * (vals + below)]
    acc = (tpr * n_pos + (1.0 - fpr) * n_neg) / (n_pos + n_neg)
    best = int(np.argmax(acc))
    return ROC(thresholds, fpr, tpr, acc, auc, float(thresholds[best]), float(acc[best]))


def separation(static_scores: np.ndarray, moving_scores: np.ndarray) -> float:
    """``(μ_moving - σ_moving) - (μ_static + σ_static)`` (our reading of the paper's eq. 7)."""
    a = np.asarray(static_scores, dtype=np.float64)
    b = np.asarray(moving_scores, dtype=np.float64)
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if len(a) < 2 or len(b) < 2:
        return math.nan
    return float((b.mean() - b.std()) - (a.mean() + a.std()))
