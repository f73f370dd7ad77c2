"""What the colour backend's targets find in simulated flights: the objects, and what else.

The detector alone (no tracking) runs on every ``--step``-th frame of each scenario with
the targets of ``--config`` (as ``tcm-companion eval --config`` would use them). Each
detection is matched to the simulator's truth: it is *true* when its centroid lies on
the object's silhouette (the renderer's ``object_coverage``, grown by 2 px); otherwise it
is *false*, and the table says what it sat on (sky above the horizon, or the ground, by
the elevation of its bearing) and its mean CIELAB colour. Per scenario and target label:

- object-frames: frames where an object is at least ``--min-px`` pixels of silhouette,
  and how many of them a detection of that label found;
- false detections per frame, and the three largest with their size, frame, elevation
  and mean colour.

This is how docs/detection.md's Lab targets were checked for false detections (the
scenario replay of ``tools/angular_size_by_scenario.py`` gives accuracy and coverage,
but does not count detections that match nothing)::

    .venv/bin/python tools/lab_target_study.py --config /tmp/lab.toml --duration 20 \\
        --step 10 --sim TS-DISC RAISED-DISC HEADON-BOX TS T90-BOX \\
        --tolerances 6 12 1 --tolerances 6 12 2

``--tolerances SEED GROW K`` (repeatable) runs every Lab target with those tolerances
(``seed_max_delta_e``, ``grow_max_delta_e``, ``delta_e_lightness_factor``): how the
defaults were compared (docs/decisions.md §10).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from tcm_companion.config import load_config
from tcm_companion.core.detection.colour import ColourDetector
from tcm_companion.sim import make_scenario
from tcm_companion.sim.scene.export import SimulatedScenario


@dataclass
class LabelResult:
    """One target label's result in one scenario."""

    frames: int = 0
    found: dict[int, tuple[int, int]] = field(default_factory=dict)  # id: (found, visible)
    false: int = 0
    # (area px, frame, elevation deg, mean L*a*b*) of each false detection
    false_dets: list[tuple[float, int, float, tuple[float, float, float]]] = field(
        default_factory=list
    )


def study(
    sim: SimulatedScenario, detector: ColourDetector, step: int, min_px: float
) -> dict[str, LabelResult]:
    """Per target label: object-frames visible / found, and the false detections."""
    out: dict[str, LabelResult] = defaultdict(LabelResult)
    seen: dict[int, int] = defaultdict(int)
    found_by: dict[tuple[int, str], int] = defaultdict(int)
    n_frames = 0
    bearing = sim.camera.bearing_map_cam
    to_lab = np.array([100.0 / 255.0, 1.0, 1.0])
    for frame in range(0, sim.n_frames, step):
        img, cov = sim.read_frame_with_coverage(frame)
        n_frames += 1
        dets = detector.detect(img)
        lab = cv2.cvtColor(img, cv2.COLOR_BGR2Lab).astype(np.float64) * to_lab - [0, 128, 128]
        near = {
            oid: cv2.dilate((c > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            for oid, c in cov.items()
        }
        for oid, c in cov.items():
            if float(c.sum()) >= min_px:
                seen[oid] += 1
        hit: set[tuple[int, str]] = set()
        for d in dets:
            cx, cy = d.centroid_px
            ix = min(max(int(cx), 0), sim.camera.width - 1)
            iy = min(max(int(cy), 0), sim.camera.height - 1)
            owner = next((oid for oid, m in near.items() if m[iy, ix]), None)
            if owner is not None:
                hit.add((owner, d.label))
                continue
            x0, y0, x1, y1 = d.bbox_px
            patch = lab[max(y0, 0) : y1, max(x0, 0) : x1].reshape(-1, 3)
            mean = patch.mean(axis=0) if len(patch) else np.full(3, math.nan)
            # Camera FRD: z points down, so the elevation is -asin(z).
            elev = -math.degrees(math.asin(float(np.clip(bearing[iy, ix, 2], -1.0, 1.0))))
            res = out[d.label]
            res.false += 1
            res.false_dets.append((d.area_px, frame, elev, (mean[0], mean[1], mean[2])))
        for key in hit:
            found_by[key] += 1
    for t in detector.targets:
        res = out[t.label]
        res.frames = n_frames
        res.found = {oid: (found_by[(oid, t.label)], n) for oid, n in seen.items()}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sim", nargs="+", required=True, metavar="NAME")
    p.add_argument("--config", default=None, help="a config file with [[detection.targets]]")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE")
    p.add_argument("--duration", type=float, default=None, help="seconds (default: the scenario's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", type=int, default=10, help="every STEP-th frame (default 10)")
    p.add_argument(
        "--min-px", type=float, default=4.0, help="least silhouette (px) of a visible object"
    )
    p.add_argument(
        "--tolerances",
        nargs=3,
        type=float,
        action="append",
        metavar=("SEED", "GROW", "K"),
        help="run with every Lab target's seed_max_delta_e, grow_max_delta_e and "
        "delta_e_lightness_factor set to these (repeatable: one pass each; default: as "
        "configured)",
    )
    args = p.parse_args(argv)
    path = args.config
    if path is None and Path("config.toml").is_file():
        path = "config.toml"
    config = load_config(path, environ=os.environ, sets=[*args.set, "detection.backend=colour"])
    base = config.pipeline.detection
    print(f"targets: {[(t.label, t.lab or t.hue_deg) for t in base.colour_targets]}")
    print(
        "| tolerances | scenario | label | objects found / visible frames | false per frame "
        "| largest false (px, frame, elevation, L*a*b*) |"
    )
    print("|---|---|---|---|---|---|")
    for tol in args.tolerances or [None]:
        det_cfg, name_tol = base, "as configured"
        if tol is not None:
            targets = tuple(
                replace(
                    t,
                    seed_max_delta_e=tol[0],
                    grow_max_delta_e=tol[1],
                    delta_e_lightness_factor=tol[2],
                )
                if t.is_lab
                else t
                for t in base.colour_targets
            )
            det_cfg = replace(base, targets=targets)
            name_tol = f"{tol[0]:g} / {tol[1]:g} / k {tol[2]:g}"
        for name in args.sim:
            sim = make_scenario(name, duration_s=args.duration, seed=args.seed, shorter_ok=True)
            res = study(sim, ColourDetector(sim.camera, det_cfg), args.step, args.min_px)
            for label, r in res.items():
                seen = ", ".join(f"#{oid} {k}/{n}" for oid, (k, n) in sorted(r.found.items()))
                worst = "; ".join(
                    f"{a:.0f} px f{f} {e:+.0f}° ({c[0]:.0f}, {c[1]:.0f}, {c[2]:.0f})"
                    for a, f, e, c in sorted(r.false_dets, reverse=True)[:3]
                )
                rate = r.false / max(r.frames, 1)
                print(
                    f"| {name_tol} | {name} | {label} | {seen} | {rate:.2f} | {worst} |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
