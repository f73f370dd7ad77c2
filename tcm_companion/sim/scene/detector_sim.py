"""A simulated box detector: what a neural "boxes" backend would report on a simulated flight.

Each frame's true boxes come from the renderer's geometry: the bounding box of each
object's *visible* coverage (anti-aliased silhouette minus what clutter and nearer
objects hide; :meth:`~.render.Renderer.visible_coverage`, :func:`~.truth.coverage_box_px`),
with the visible fraction of its silhouette. :func:`detections_from_truth` then makes them
look like a detector's output, with every imperfection a setting of
:class:`DetectorSimConfig`:

- latency: the boxes reported for frame ``k`` describe frame ``k - latency_frames``
  (frames before that report nothing but false boxes);
- misses: each object-frame is dropped with ``miss_probability`` (independently), and
  always when less than ``min_visible`` of the silhouette shows or the box is smaller
  than ``min_size_px`` on a side;
- jitter: the box centre moves by Gaussian noise of σ ``centre_sigma_px`` on each axis,
  its width and height are scaled by ``exp(N(0, scale_sigma²))`` each;
- false boxes: a Poisson number (mean ``false_per_frame``) per frame, anywhere in the
  valid image, 4 to 40 px on a side, labelled like one of the scene's objects;
- scores: uniform in ``score_true`` for real boxes (times the visible fraction's square
  root), in ``score_false`` for false ones.

Seeded and deterministic: the noise of object ``i`` in frame ``k`` depends only on
``(seed, scenario seed, k, i)``, not on the order frames are processed or on other
objects. Boxes follow the scenario format (continuous pixels, ``(0, 0)`` the top-left
corner; a full panorama's box across the ±180° seam has ``x_min > x_max``) and are
returned as :class:`~.scenario_io.Detection` rows, which carry the truth (object and
described frame) for evaluation; :func:`~.scenario_io.write_detections_csv` writes them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...core.camera import CameraModel
from .scenario_io import Detection
from .truth import BoxPx, box_centre_px, box_width_px, coverage_box_px, is_full_panorama

if TYPE_CHECKING:
    from .export import SimulatedScenario

_SEED_TAG = 8_675_309


@dataclass(frozen=True)
class DetectorSimConfig:
    """Settings of the simulated detector (see the module docstring)."""

    centre_sigma_px: float = 1.0
    scale_sigma: float = 0.04
    miss_probability: float = 0.05
    false_per_frame: float = 0.02
    latency_frames: int = 0
    min_visible: float = 0.25
    min_size_px: float = 2.0
    score_true: tuple[float, float] = (0.6, 0.98)
    score_false: tuple[float, float] = (0.3, 0.7)
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.miss_probability <= 1.0:
            raise ValueError(f"miss_probability must be in [0, 1], got {self.miss_probability!r}")
        if self.latency_frames < 0:
            raise ValueError(f"latency_frames must be >= 0, got {self.latency_frames!r}")
        for name in ("centre_sigma_px", "scale_sigma", "false_per_frame", "min_size_px"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class TrueBox:
    """An object's visible silhouette in one frame: its bounding box (pixels) and the
    fraction of its whole silhouette's solid angle that is visible."""

    object_id: int
    label: str
    box_px: BoxPx
    visible_fraction: float


def true_boxes_from_coverage(
    sim: SimulatedScenario, frame: int, coverage: dict[int, np.ndarray]
) -> list[TrueBox]:
    """True boxes of frame ``frame`` from its visible coverage images (object order)."""
    cam = sim.camera
    wrap = is_full_panorama(cam)
    omega = cam.solid_angle_map_sr
    t = float(sim.frame_times_s[frame])
    pos, R = sim.vehicle_pose(frame)
    out: list[TrueBox] = []
    for obj in sim.plan.objects:
        cov = coverage.get(obj.object_id)
        if cov is None:
            continue
        box = coverage_box_px(cov, wrap)
        if box is None:
            continue
        whole = float(np.sum(sim.renderer.object_coverage(obj, t, pos, R) * omega))
        seen = float(np.sum(cov * omega))
        frac = min(1.0, seen / whole) if whole > 0 else 0.0
        out.append(TrueBox(obj.object_id, obj.label, box, frac))
    return out


def true_boxes(sim: SimulatedScenario, frame: int) -> list[TrueBox]:
    """True boxes of frame ``frame`` (renders the objects' visible coverage)."""
    pos, R = sim.vehicle_pose(frame)
    cov = sim.renderer.visible_coverage(float(sim.frame_times_s[frame]), pos, R)
    return true_boxes_from_coverage(sim, frame, cov)


def detections_from_truth(
    truth: Sequence[Sequence[TrueBox]],
    camera: CameraModel,
    config: DetectorSimConfig,
    scenario_seed: int = 0,
    labels: Sequence[str] = ("ball",),
) -> list[Detection]:
    """Detector output for frames whose true boxes are ``truth[k]`` (see the module)."""
    w, h = float(camera.width), float(camera.height)
    wrap = is_full_panorama(camera)
    valid_rc = np.argwhere(camera.valid_mask)
    out: list[Detection] = []
    lo_t, hi_t = config.score_true
    lo_f, hi_f = config.score_false
    for k in range(len(truth)):
        src = k - config.latency_frames
        rows: list[Detection] = []
        if src >= 0:
            for tb in truth[src]:
                rng = np.random.default_rng(
                    np.random.SeedSequence([_SEED_TAG, config.seed, scenario_seed, k, tb.object_id])
                )
                u_miss, u_score = rng.random(2)
                n = rng.standard_normal(4)
                if u_miss < config.miss_probability or tb.visible_fraction < config.min_visible:
                    continue
                bw = box_width_px(tb.box_px, camera.width)
                bh = tb.box_px[3] - tb.box_px[1]
                if min(bw, bh) < config.min_size_px:
                    continue
                cx, cy = box_centre_px(tb.box_px, camera.width)
                cx += config.centre_sigma_px * n[0]
                cy += config.centre_sigma_px * n[1]
                bw *= math.exp(config.scale_sigma * n[2])
                bh *= math.exp(config.scale_sigma * n[3])
                score = (lo_t + (hi_t - lo_t) * u_score) * math.sqrt(tb.visible_fraction)
                box = _place(cx, cy, bw, bh, w, h, wrap)
                if box is not None:
                    rows.append(Detection(k, *box, float(score), tb.label, tb.object_id, src))
        rng = np.random.default_rng(
            np.random.SeedSequence([_SEED_TAG, config.seed, scenario_seed, k, 0])
        )
        for _ in range(int(rng.poisson(config.false_per_frame))):
            r, c = valid_rc[int(rng.integers(len(valid_rc)))]
            side = math.exp(rng.uniform(math.log(4.0), math.log(40.0)))
            aspect = math.exp(rng.uniform(-0.7, 0.7))
            box = _place(c + 0.5, r + 0.5, side * aspect, side / aspect, w, h, wrap)
            if box is not None:
                score = lo_f + (hi_f - lo_f) * float(rng.random())
                label = labels[int(rng.integers(len(labels)))] if labels else ""
                rows.append(Detection(k, *box, score, label, 0, -1))
        out.extend(rows)
    return out


def _place(
    cx: float, cy: float, bw: float, bh: float, w: float, h: float, wrap: bool
) -> tuple[float, float, float, float] | None:
    """A box of centre (cx, cy) and size (bw, bh) in the image: clipped, or wrapped
    round a full panorama's seam (``x_min > x_max``); None if under a pixel is left."""
    y0, y1 = max(cy - bh / 2.0, 0.0), min(cy + bh / 2.0, h)
    if y1 - y0 < 1.0:
        return None
    if wrap:
        bw = min(bw, w - 1e-3)
        x0 = (cx - bw / 2.0) % w
        x1 = (cx + bw / 2.0) % w
        if x1 == 0.0:
            x1 = w
    else:
        x0, x1 = max(cx - bw / 2.0, 0.0), min(cx + bw / 2.0, w)
        if x1 - x0 < 1.0:
            return None
    return (x0, y0, x1, y1)


def simulate_detections(
    sim: SimulatedScenario,
    config: DetectorSimConfig | None = None,
    truth: Sequence[Sequence[TrueBox]] | None = None,
) -> list[Detection]:
    """The simulated detector's rows for every frame of ``sim`` (``detections.csv``).

    ``truth``: the frames' true boxes if already known (``export_scenario`` collects them
    while rendering); otherwise each frame's objects are rendered (no ground or sky).
    """
    cfg = config if config is not None else DetectorSimConfig()
    if truth is None:
        truth = [true_boxes(sim, k) for k in range(sim.n_frames)]
    labels = sorted({o.label for o in sim.plan.objects})
    return detections_from_truth(truth, sim.camera, cfg, scenario_seed=sim.seed, labels=labels)
