"""The colour backend's angular size against the renderer's truth, frame by frame, per
object: where the size error comes from (issue 14 §3, docs/decisions.md §2).

Unlike ``tools/angular_size_by_scenario.py`` (the whole pipeline, as ``eval`` runs it),
this runs the colour detector alone on every ``--step``-th frame and compares each
object's measured angular radius with the equal-solid-angle radius of its anti-aliased
silhouette (the renderer's ``object_coverage`` times the camera's per-pixel solid angle;
occlusion not removed). A detection is matched to an object when its centroid lies
within 10 px of the silhouette's. It prints, per scenario and object, the median and
p90 of |error| and the signed median, for each ``--light-exponent`` (the space the rim
is unmixed in: 1 code values, the default; 2 linear light for the simulator's display
gamma), and with ``--by-radius`` the signed median per band of true radius (a bias
that is a fixed fraction of a pixel of radius grows as 1/α).

    .venv/bin/python tools/rim_unmixing_study.py --sim DARKBG SKY2TREE COLLISION \\
        --step 4 --light-exponent 1 2 --by-radius
    .venv/bin/python tools/rim_unmixing_study.py --examples tests/data/examples/EX-* \\
        --light-exponent 1 2

``--examples``: scenario directories with truth.csv (a ball: truth ``asin(r/d)``), every
frame.

Options: ``--config`` (e.g. with more colour targets), ``--seed``, ``--duration``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
from pathlib import Path

import numpy as np

from tcm_companion.config import load_config
from tcm_companion.core.detection.base import angular_radius_from_solid_angle
from tcm_companion.core.detection.colour import ColourDetector
from tcm_companion.io.scenario import load_scenario
from tcm_companion.sim import make_scenario
from tcm_companion.sim.scene.export import SimulatedScenario

_MATCH_PX = 10.0
_RADIUS_BANDS_DEG = (0.0, 2.0, 3.0, 4.0, 6.0, 90.0)


def errors(
    sim: SimulatedScenario, det: ColourDetector, step: int
) -> dict[int, list[tuple[float, float]]]:
    """Per object id: (true radius rad, relative error) of every matched frame."""
    omega_sr = sim.camera.solid_angle_map_sr
    out: dict[int, list[tuple[float, float]]] = {}
    for i in range(0, sim.n_frames, step):
        dets = det.detect(sim.read_frame(i))
        pos, R = sim.vehicle_pose(i)
        t_s = float(sim.frame_times_s[i])
        for obj in sim.plan.objects:
            cov = sim.renderer.object_coverage(obj, t_s, pos, R)
            ys, xs = np.nonzero(cov > 0.5)
            if not len(ys) or not dets:
                continue
            cx, cy = float(xs.mean()) + 0.5, float(ys.mean()) + 0.5
            d = min(dets, key=lambda d: math.hypot(d.centroid_px[0] - cx, d.centroid_px[1] - cy))
            if math.hypot(d.centroid_px[0] - cx, d.centroid_px[1] - cy) > _MATCH_PX:
                continue
            alpha_true = angular_radius_from_solid_angle(float(np.sum(cov * omega_sr)))
            out.setdefault(obj.object_id, []).append(
                (alpha_true, d.angular_radius_rad / alpha_true - 1.0)
            )
    return out


def example_errors(root: str, det_for: dict[float, ColourDetector]) -> dict[float, np.ndarray]:
    """Per light exponent: the relative radius error of every frame of a recorded
    scenario with one ball (truth ``asin(r/d)``)."""
    scenario = load_scenario(root)
    truth = scenario.truth
    assert truth is not None, f"{root}: no truth.csv"
    out: dict[float, list[float]] = {g: [] for g in det_for}
    for i, _, img in scenario.iter_frames():
        row = truth.rows_for_frame(i)[0]
        rng = float(np.linalg.norm(truth.obj_ned_m[row] - truth.veh_ned_m[row]))
        alpha_true = math.asin(float(truth.obj_radius_m[row]) / rng)
        for gamma, det in det_for.items():
            dets = det.detect(img)
            if len(dets) == 1:
                out[gamma].append(dets[0].angular_radius_rad / alpha_true - 1.0)
    return {g: np.array(e) for g, e in out.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sim", nargs="+", default=[], metavar="NAME")
    p.add_argument("--examples", nargs="+", default=[], metavar="DIR")
    p.add_argument("--step", type=int, default=5, help="every STEP-th frame (default 5)")
    p.add_argument("--light-exponent", type=float, nargs="+", default=[1.0])
    p.add_argument("--by-radius", action="store_true")
    p.add_argument("--config", default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None)
    args = p.parse_args(argv)
    path = args.config
    if path is None and Path("config.toml").is_file():
        path = "config.toml"
    dcfg = load_config(path, environ=os.environ, sets=[]).pipeline.detection
    bands = list(itertools.pairwise(_RADIUS_BANDS_DEG))
    head = "| scenario | object | light exponent | frames | \\|err\\| median | p90 | bias |"
    if args.by_radius:
        head += "".join(f" bias, α {lo:g}–{hi:g}° |" for lo, hi in bands)
    print(head)
    print("|" + "---|" * (head.count("|") - head.count("\\|") - 1))
    for root in args.examples:
        cam = load_scenario(root, check_frames=False).camera
        dets = {g: ColourDetector(cam, dcfg, light_exponent=g) for g in args.light_exponent}
        for gamma, e in example_errors(root, dets).items():
            print(
                f"| {Path(root).name} | ball | {gamma:g} | {len(e)} "
                f"| {100 * np.median(np.abs(e)):.2f}% | {100 * np.percentile(np.abs(e), 90):.2f}% "
                f"| {100 * np.median(e):+.2f}% |",
                flush=True,
            )
    for name in args.sim:
        sim = make_scenario(name, duration_s=args.duration, seed=args.seed, shorter_ok=True)
        for gamma in args.light_exponent:
            det = ColourDetector(sim.camera, dcfg, light_exponent=gamma)
            for oid, rows in sorted(errors(sim, det, args.step).items()):
                a = np.array(rows)
                e = a[:, 1]
                line = (
                    f"| {name} | {oid} | {gamma:g} | {len(e)} | {100 * np.median(np.abs(e)):.1f}% "
                    f"| {100 * np.percentile(np.abs(e), 90):.1f}% | {100 * np.median(e):+.1f}% |"
                )
                if args.by_radius:
                    deg = np.degrees(a[:, 0])
                    for lo, hi in bands:
                        sel = e[(deg >= lo) & (deg < hi)]
                        line += (
                            f" {100 * np.median(sel):+.1f}% ({len(sel)}) |" if len(sel) else " — |"
                        )
                print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
