"""Issue 14's targets per scenario and detection backend, in one pass per scenario.

Each simulated scenario is replayed through the pipeline exactly as ``tcm-companion eval
--sim NAME --no-bsm`` does (:func:`~tcm_companion.eval.evaluate.evaluate_scenario`, the
same matching to truth, :func:`~tcm_companion.eval.evaluate.summarize` for TCM's accuracy
at the configured threshold, coverage and decided object-frames), and each matched
object-frame's measured angular radius is compared with the truth. ``eval`` itself only
reports the error against the *bounding sphere* (``radius err``), which for a box, a
cylinder or a disc is a bias of the shape, not an error of the measurement; so each
backend is also scored against what it claims to measure, from the simulator's exact
geometry (:mod:`tcm_companion.sim.scene.truth`, the renderer's coverage):

- ``colour`` reports the radius of the cap with the blob's solid angle: truth is the
  equal-solid-angle radius of the object's whole silhouette (``object_coverage`` times
  the camera's per-pixel solid angle; occlusion not removed, so a hidden part counts as
  an error of the measurement);
- ``boxes`` reports its ``box_radius`` statistic of the angles across the box (default
  ``"rms"``: half of ``√((θw² + θh²)/2)``, the diagonal over √2; ``"mean"``: half of
  ``√(θw·θh)``): truth is the same statistic of the silhouette's true box
  (:func:`~tcm_companion.sim.scene.truth.object_views`, ``extent_rad``).

For a ball all of these are ``asin(r / d)``. Errors are relative, ``α_measured / α_true - 1``,
over every matched object-frame (warm-up included): median and p90 of the absolute value,
and the signed median (bias).

    .venv/bin/python tools/angular_size_by_scenario.py --backend colour --sim TS-BOX T45-CYL
    .venv/bin/python tools/angular_size_by_scenario.py --backend boxes --duration 20 \\
        --sim TS-BOX TS-CYL

Options as ``eval``'s: ``--config``, ``--set``, ``--duration``, ``--seed``. Prints one
Markdown table row per scenario (and the pooled TCM row), flushing as it goes.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from tcm_companion.config import AppConfig, load_config
from tcm_companion.core.detection.base import angular_radius_from_solid_angle
from tcm_companion.eval.evaluate import ObjectFrame, evaluate_scenario, summarize
from tcm_companion.sim import make_scenario
from tcm_companion.sim.scene.export import SimulatedScenario
from tcm_companion.sim.scene.truth import object_views


def box_statistic(w_rad: float, h_rad: float, how: str) -> float:
    """The angular radius ``box_radius = how`` reports for a box ``w_rad`` × ``h_rad``."""
    if how == "mean":
        return 0.5 * math.sqrt(w_rad * h_rad)
    if how == "rms":
        return 0.5 * math.sqrt((w_rad * w_rad + h_rad * h_rad) / 2.0)
    return 0.5 * (min(w_rad, h_rad) if how == "short" else max(w_rad, h_rad))


def true_radii(
    sim: SimulatedScenario, frame: int, box_radius: str = "rms"
) -> dict[int, tuple[float, float, float]]:
    """Per object id: (bounding sphere, equal-solid-angle silhouette, the silhouette's box
    by ``box_radius``) angular radius (rad) at ``frame``; NaN where not in view."""
    t = float(sim.frame_times_s[frame])
    pos, R = sim.vehicle_pose(frame)
    omega = sim.camera.solid_angle_map_sr
    out: dict[int, tuple[float, float, float]] = {}
    for obj, view in zip(sim.plan.objects, object_views(sim, frame), strict=True):
        sphere = math.asin(min(1.0, view.bounding_radius_m / view.range_m))
        if view.shape == "sphere":
            out[obj.object_id] = (sphere, sphere, sphere)
            continue
        cov = sim.renderer.object_coverage(obj, t, pos, R)
        solid = float(np.sum(cov * omega))
        area = angular_radius_from_solid_angle(solid) if solid > 0 else math.nan
        box = math.nan
        if view.extent_rad is not None:
            box = box_statistic(view.extent_rad[0], view.extent_rad[1], box_radius)
        out[obj.object_id] = (sphere, area, box)
    return out


def radius_errors(
    sim: SimulatedScenario, records: list[ObjectFrame], box_radius: str = "rms"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Relative errors of the matched records' measured radius against the bounding
    sphere, the equal-solid-angle silhouette and the silhouette's box."""
    cache: dict[int, dict[int, tuple[float, float, float]]] = {}
    errs: list[tuple[float, float, float]] = []
    for r in records:
        if not r.matched or not math.isfinite(r.radius_error_rel):
            continue
        truth = cache.get(r.frame)
        if truth is None:
            truth = cache[r.frame] = true_radii(sim, r.frame, box_radius)
        sphere, area, box = truth[r.object_id]
        measured = (1.0 + r.radius_error_rel) * sphere
        errs.append((measured / sphere - 1.0, measured / area - 1.0, measured / box - 1.0))
    a = np.array(errs, dtype=np.float64).reshape(-1, 3)
    return a[:, 0], a[:, 1], a[:, 2]


def _stats(err: np.ndarray) -> tuple[float, float, float]:
    e = err[np.isfinite(err)]
    if not len(e):
        return math.nan, math.nan, math.nan
    return (
        float(np.median(np.abs(e))),
        float(np.percentile(np.abs(e), 90)),
        float(np.median(e)),
    )


def _pct(x: float, signed: bool = False) -> str:
    if not math.isfinite(x):
        return "—"
    return f"{100 * x:+.1f}%" if signed else f"{100 * x:.1f}%"


def config_for(args: argparse.Namespace) -> AppConfig:
    path = args.config
    if path is None and Path("config.toml").is_file():
        path = "config.toml"
    sets = [*args.set, f"detection.backend={args.backend}"]
    return load_config(path, environ=os.environ, sets=sets)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--backend", choices=("colour", "boxes"), default="colour")
    p.add_argument("--sim", nargs="+", required=True, metavar="NAME")
    p.add_argument("--config", default=None)
    p.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE")
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    config = config_for(args)
    cls = config.pipeline.classifier
    own = "silhouette (equal solid angle)" if args.backend == "colour" else "silhouette box"
    print(
        f"backend {args.backend}, TCM threshold {cls.tcm_threshold}, seed {args.seed}, "
        f"duration {args.duration or 'scenario default'}; radius error against the {own}"
    )
    print(
        "| scenario | frames | TCM accuracy | coverage | decided | radius |err| median | p90 "
        "| signed median | vs bounding sphere: median |err| | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    pooled: list[ObjectFrame] = []
    for name in args.sim:
        t0 = time.monotonic()
        sim = make_scenario(name, duration_s=args.duration, seed=args.seed, shorter_ok=True)
        ev = evaluate_scenario(sim, config, with_bsm=False)
        pooled.extend(ev.records)
        tcm = {s.method: s for s in summarize(ev.records, cls)}.get("tcm")
        sphere, area, box = radius_errors(sim, ev.records, config.pipeline.detection.box_radius)
        med, p90, signed = _stats(area if args.backend == "colour" else box)
        sph_med = _stats(sphere)[0]
        acc = _pct(tcm.accuracy) if tcm else "—"
        cov = _pct(tcm.coverage) if tcm else "0.0%"
        dec = str(tcm.n_decided) if tcm else "0"
        print(
            f"| {name} | {sim.n_frames} | {acc} | {cov} | {dec} | {_pct(med)} | {_pct(p90)} "
            f"| {_pct(signed, True)} | {_pct(sph_med)} | {time.monotonic() - t0:.0f} |",
            flush=True,
        )
    tcm = {s.method: s for s in summarize(pooled, cls)}.get("tcm")
    if tcm is not None:
        print(
            f"| pooled | | {_pct(tcm.accuracy)} | {_pct(tcm.coverage)} | {tcm.n_decided} "
            "| | | | | |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
