"""Evaluation metrics: accuracy, ROC/AUC, optimal threshold, separation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tcm_companion.eval.metrics import confusion, roc, separation


def test_confusion_counts_and_rates() -> None:
    c = confusion(np.array([1, 1, 0, 0, 1], bool), np.array([1, 0, 0, 1, 1], bool))
    assert (c.tp, c.tn, c.fp, c.fn) == (2, 1, 1, 1)
    assert c.accuracy == pytest.approx(0.6)
    assert c.tpr == pytest.approx(2 / 3) and c.fpr == pytest.approx(0.5)


def test_perfect_and_random_and_inverted_auc() -> None:
    truth = np.r_[np.zeros(50, bool), np.ones(50, bool)]
    assert roc(truth, np.r_[np.zeros(50), np.ones(50)]).auc == pytest.approx(1.0)
    assert roc(truth, np.r_[np.ones(50), np.zeros(50)]).auc == pytest.approx(0.0)
    assert roc(truth, np.ones(100)).auc == pytest.approx(0.5)
    rng = np.random.default_rng(0)
    assert abs(roc(truth, rng.random(100)).auc - 0.5) < 0.15


def test_auc_matches_rank_statistic() -> None:
    rng = np.random.default_rng(1)
    truth = rng.random(300) < 0.4
    score = rng.normal(size=300) + truth * 1.0
    score[::7] = np.round(score[::7], 1)  # some ties
    pos, neg = score[truth], score[~truth]
    mw = (np.sum(pos[:, None] > neg[None, :]) + 0.5 * np.sum(pos[:, None] == neg[None, :])) / (
        len(pos) * len(neg)
    )
    assert roc(truth, score).auc == pytest.approx(mw, abs=1e-12)


def test_best_threshold_separates_and_reproduces_accuracy() -> None:
    truth = np.r_[np.zeros(40, bool), np.ones(60, bool)]
    score = np.r_[np.linspace(0.0, 0.08, 40), np.linspace(0.1, 1.0, 60)]
    r = roc(truth, score)
    assert 0.08 < r.best_threshold < 0.1 and r.best_accuracy == 1.0
    assert confusion(truth, score > r.best_threshold).accuracy == r.best_accuracy


def test_nan_scores_ignored_and_single_class_is_nan() -> None:
    r = roc(np.array([0, 1, 1], bool), np.array([0.1, np.nan, 0.9]))
    assert r.auc == pytest.approx(1.0)
    assert math.isnan(roc(np.ones(5, bool), np.arange(5.0)).auc)


def test_separation() -> None:
    static = np.array([0.03, 0.05, 0.04, 0.04])
    moving = np.array([0.3, 0.5, 0.4, 0.4])
    expected = (0.4 - np.std(moving)) - (0.04 + np.std(static))
    assert separation(static, moving) == pytest.approx(expected)
