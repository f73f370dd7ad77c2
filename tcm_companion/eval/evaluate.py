"""Run scenarios through the pipeline and score the results against truth.

Each truth object in each frame becomes one :class:`ObjectFrame`: matched to the track
whose local-level bearing is closest (within a gate), with the states and scores of
every method. From these, :func:`summarize` computes the paper's numbers per method:
accuracy at the configured threshold, coverage (object-frames after warm-up that got a
decision), ROC area and the accuracy-optimal threshold. Warm-up is time: object-frames
captured at least the classifier's ``interval_s`` after the scenario's first frame count
(:func:`~tcm_companion.io.scoring.after_warmup`, the rule SITL scores with too).

All methods are scored on the same object-frames: those where TCM reached a decision
(so a method is never credited for frames TCM declined as degenerate).

Any detection backend can be scored. With ``[detection] backend = "boxes"`` the boxes are
the scenario's ``detections.csv``; a simulated scenario, which has none, gets the
simulator's detector (:func:`scenario_detections`). Truth for a shape other than a sphere
gives the bounding sphere's radius, so ``radius err`` compares the measured angular radius
with the bounding sphere's (for a box estimator it is a bias, not an error of the method).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..config import AppConfig
from ..core.classify import METHODS, ClassifierConfig, Method, fused_score
from ..core.pipeline import FrameResult, Pipeline
from ..io.detector_model import read_detector_model
from ..io.scenario_extras import Detection
from ..io.scoring import after_warmup, match_truth
from ..io.truth import Truth
from ..replay.scenario import DetectionRow, ScenarioLike, run_replay, with_method
from .metrics import confusion, roc


@dataclass(frozen=True)
class ObjectFrame:
    """One truth object in one frame, and what the pipeline said about it."""

    frame: int
    t_us: int
    object_id: int
    truth_moving: bool
    matched: bool
    track_id: int = -1
    state: str = "unknown"
    reason: str = "not detected"
    disparity: float = math.nan
    omega_rad: float = math.nan
    bsm_score: float = math.nan
    bearing_error_rad: float = math.nan
    radius_error_rel: float = math.nan
    ttc_s: float = math.nan
    true_ttc_s: float = math.nan
    collision_course: bool = False
    true_collision_course: bool = False
    interval_frames: int = 0
    interval_s: float = math.nan  # capture time between the pair's observations
    time_s: float = math.nan  # capture time since the scenario's first frame
    label: str = ""  # the matched track's label

    def score(self, method: Method, cls: ClassifierConfig) -> float:
        if method == "tcm":
            return self.disparity
        if method == "ecm":
            return self.omega_rad
        if method == "bsm":
            return self.bsm_score
        return fused_score(self.disparity, self.omega_rad, cls)


@dataclass
class ScenarioEval:
    name: str
    resolution: tuple[int, int]
    records: list[ObjectFrame] = field(default_factory=list)
    false_tracks: int = 0  # track-frames matching no truth object
    frame_ms: list[float] = field(default_factory=list)
    interval_disparities: dict[int, list[tuple[bool, float]]] = field(default_factory=dict)


def truth_ttc_s(truth: Truth, frame_times_us: np.ndarray) -> np.ndarray:
    """:meth:`Truth.ttc_s <tcm_companion.io.truth.Truth.ttc_s>` (kept for the studies in
    tools/ that call it by this name)."""
    return truth.ttc_s(frame_times_us)


def match_frame(
    result: FrameResult,
    truth: Truth,
    frame: int,
    true_ttc: np.ndarray,
    true_collision: np.ndarray | None = None,
    t0_us: int | None = None,
) -> tuple[list[ObjectFrame], int]:
    """Truth objects of one frame matched to result objects (greedy by bearing,
    :func:`~tcm_companion.io.scoring.match_truth`).

    ``frame`` is the scenario's frame index (the truth's), which differs from the
    pipeline's own count when frames were dropped; ``t0_us`` the scenario's first capture
    time (for :attr:`ObjectFrame.time_s`)."""
    rows = truth.rows_for_frame(frame)
    objs = [o for o in result.objects if o.detected]
    bearings = [o.bearing_ned for o in objs]
    used: set[int] = set()
    out = []
    for r in rows:
        m = match_truth(
            truth.obj_ned_m[r] - truth.veh_ned_m[r], truth.obj_radius_m[r], bearings, used
        )
        base = dict(
            frame=frame,
            t_us=result.t_us,
            time_s=(result.t_us - t0_us) * 1e-6 if t0_us is not None else math.nan,
            object_id=int(truth.object_id[r]),
            truth_moving=bool(truth.moving[r]),
            true_ttc_s=float(true_ttc[r]),
            true_collision_course=bool(true_collision[r]) if true_collision is not None else False,
        )
        if not m.matched:
            out.append(ObjectFrame(matched=False, **base))  # type: ignore[arg-type]
            continue
        o = objs[m.index]
        c = o.classification
        out.append(
            ObjectFrame(
                matched=True,
                track_id=o.track_id,
                state=o.state,
                reason=o.reason,
                disparity=c.disparity,
                omega_rad=c.omega_rad,
                bsm_score=c.bsm_score,
                bearing_error_rad=m.bearing_error_rad,
                radius_error_rel=o.angular_radius_rad / m.alpha_true_rad - 1.0,
                ttc_s=o.ttc_s,
                collision_course=o.collision_course,
                interval_frames=c.interval_frames,
                interval_s=c.interval_s,
                label=o.label,
                **base,  # type: ignore[arg-type]
            )
        )
    return out, len(objs) - len(used)


class ResizedScenario:
    """A scenario seen through the same lens at another resolution (frames resized, and
    the boxes of its ``detections.csv`` scaled with them)."""

    def __init__(self, inner: ScenarioLike, width: int, height: int) -> None:
        self.inner = inner
        self.name = inner.name
        self.camera = inner.camera.scaled(width, height)
        self.frame_times_us = inner.frame_times_us
        self.telemetry = inner.telemetry
        self.truth = getattr(inner, "truth", None)
        rows = getattr(inner, "detections", None)
        self.detections: list[Detection] | None = None
        if rows is not None:
            sx, sy = width / inner.camera.width, height / inner.camera.height
            self.detections = [
                Detection(
                    r.frame,
                    r.x_min * sx,
                    r.y_min * sy,
                    r.x_max * sx,
                    r.y_max * sy,
                    r.score,
                    r.label,
                )
                for r in rows
            ]

    @property
    def n_frames(self) -> int:
        return self.inner.n_frames

    def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
        size = (self.camera.width, self.camera.height)
        for i, t, img in self.inner.iter_frames():
            if img is None or img.shape[1::-1] == size:  # None: unreadable (TolerantFrames)
                yield i, t, img
            else:
                yield i, t, cv2.resize(img, size, interpolation=cv2.INTER_AREA)


def at_resolution(scenario: ScenarioLike, width: int, height: int) -> ScenarioLike:
    """The scenario at another image size: re-rendered if simulated, else resized frames."""
    if (width, height) == (scenario.camera.width, scenario.camera.height):
        return scenario
    rerender = getattr(scenario, "with_camera", None)
    if rerender is not None:
        return rerender(scenario.camera.scaled(width, height))
    return ResizedScenario(scenario, width, height)


def scenario_detections(scenario: ScenarioLike) -> list[Any] | None:
    """The external detector's boxes of a scenario: its ``detections.csv`` (``detections``),
    else, for a simulated scenario, the simulator's detector with its default noise
    (``sim/scene/detector_sim.py``); None when there are none."""
    rows = getattr(scenario, "detections", None)
    if rows is not None:
        return list(rows)
    if getattr(scenario, "plan", None) is not None and hasattr(scenario, "renderer"):
        from ..sim.scene.detector_sim import simulate_detections

        return list(simulate_detections(scenario))  # type: ignore[arg-type]
    return None


def evaluate_scenario(
    scenario: ScenarioLike,
    config: AppConfig,
    with_bsm: bool = True,
    intervals: tuple[int, ...] = (),
    on_frame: Callable[[FrameResult], None] | None = None,
) -> ScenarioEval:
    """Replay one scenario (with truth) and collect one record per truth object-frame.

    ``intervals``: also compute the TCM disparity for each of these intervals counted in
    frames (the separation study of the paper's Fig. 4, about frame intervals at 25 Hz).
    """
    truth: Truth | None = getattr(scenario, "truth", None)
    if truth is None:
        raise ValueError(f"{scenario.name}: no truth.csv, cannot evaluate")
    cfg = with_method(config, "tcm", bsm=with_bsm)
    pipe = Pipeline(
        scenario.camera, cfg.pipeline, detector_model=read_detector_model(cfg.pipeline.detection)
    )
    detections: list[DetectionRow] | None = None
    if cfg.pipeline.detection.backend == "boxes":
        detections = scenario_detections(scenario)
        if detections is None:
            raise ValueError(
                f'{scenario.name}: [detection] backend "boxes" needs the scenario\'s '
                "detections.csv (sim export NAME DIR --detections writes one)"
            )
    true_ttc = truth.ttc_s(scenario.frame_times_us)
    ttc_cfg = cfg.pipeline.ttc
    true_coll = truth.collision_course(
        scenario.frame_times_us, ttc_cfg.collision_miss_radii, ttc_cfg.collision_max_ttc_s
    )
    ev = ScenarioEval(scenario.name, (scenario.camera.width, scenario.camera.height))
    t0_us = int(scenario.frame_times_us[0]) if len(scenario.frame_times_us) else None
    for result in run_replay(scenario, cfg, pipe, detections):
        recs, false = match_frame(
            result, truth, result.frame_index, true_ttc, true_coll, t0_us=t0_us
        )
        ev.records.extend(recs)
        ev.false_tracks += false
        ev.frame_ms.append(result.timings_ms.get("total", math.nan))
        if intervals:
            moving = {r.track_id: r.truth_moving for r in recs if r.matched}
            for k, per_track in pipe.disparities_for_frame_intervals(intervals).items():
                for tid, delta in per_track.items():
                    if tid in moving:
                        ev.interval_disparities.setdefault(k, []).append((moving[tid], delta))
        if on_frame is not None:
            on_frame(result)
    return ev


@dataclass(frozen=True)
class MethodSummary:
    method: str
    n_decided: int
    coverage: float
    accuracy: float  # at the configured threshold
    auc: float
    best_threshold: float
    best_accuracy: float
    tpr: float
    fpr: float


def summarize(
    records: list[ObjectFrame], cls: ClassifierConfig, warmup_s: float | None = None
) -> list[MethodSummary]:
    """Per-method metrics over pooled records (static and moving flights together);
    coverage and accuracy count the records after the warm-up
    (:func:`~tcm_companion.io.scoring.after_warmup`)."""
    after = after_warmup(records, cls, warmup_s)
    decided = [r for r in after if r.state != "unknown"]
    coverage = len(decided) / len(after) if after else math.nan
    truth = np.array([r.truth_moving for r in decided], dtype=bool)
    out = []
    thresholds = {
        "tcm": cls.tcm_threshold,
        "ecm": cls.ecm_threshold_rad,
        "bsm": cls.bsm_threshold,
        "fused": 1.0,
    }
    for method in METHODS:
        score = np.array([r.score(method, cls) for r in decided], dtype=np.float64)
        if not np.any(np.isfinite(score)):
            continue
        pred = score > thresholds[method]
        c = confusion(truth[np.isfinite(score)], pred[np.isfinite(score)])
        curve = roc(truth, score)
        out.append(
            MethodSummary(
                method,
                len(decided),
                coverage,
                c.accuracy,
                curve.auc,
                curve.best_threshold,
                curve.best_accuracy,
                c.tpr,
                c.fpr,
            )
        )
    return out
