"""Near the translation axis, does an object's own extent make TCM's triangle unreliable?

HEADON-BOX (a 2.4-m container flown at head-on, docs/decisions.md §9) is decided
``moving`` in its last 0.4 s, when the box comes off the axis by more than
``min_theta_deg``: there its range is ~1–2 of its own sizes, and the point a detection
reports (the box's or blob's centre) is no fixed point of the object: it follows the
near face. TCM's range ratio from the bearings, ``sin θ1 / sin θ0``, amplifies a bearing
error ``ε`` by ``cot θ`` (``d ln sin θ = cot θ dθ``), which is small across the track
(θ ≈ 90°) and large near its axis. If the reported point may wander by a fraction ``k``
of the object's angular radius, δ is uncertain by about

    σ_extent = k · √((α0 cot θ0)² + (α1 cot θ1)²)

This records every pair the classifier decides (``classify_pair``'s inputs and state)
while each scenario is replayed as ``eval --sim NAME --no-bsm`` does, and prints per
scenario the decided pairs, how many say ``moving``, and the share a guard
``σ_extent > max_disparity_sigma`` would refuse for several ``k`` (the guard itself,
``[classifier] head_on_extent_fraction``, is off while it records).

    .venv/bin/python tools/extent_guard_study.py --backend boxes --duration 20
    .venv/bin/python tools/extent_guard_study.py --config colours.toml --duration 20 --sim TS-BOX

Options as ``eval``'s (``--config``, ``--set``, ``--duration``, ``--seed``).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

from tcm_companion.cli.common import add_config_arguments, config_from_args
from tcm_companion.core import pipeline as pipeline_module
from tcm_companion.eval.evaluate import evaluate_scenario
from tcm_companion.sim import make_scenario

DEFAULT_SIMS = (
    "TS-BOX T45-BOX T90-BOX TS-CYL T45-CYL T90-CYL TS-DISC T45-DISC T90-DISC RAISED-DISC "
    "INPLANE-BOX COLLISION-CYL COLLISION-DISC HEADON-BOX DARKBG BACKLIT SKY2TREE MIXED "
    "TS T45 T90 RAISED INPLANE COLLISION HEADON TWO"
).split()
KS = (0.05, 0.1, 0.2, 0.3, 0.5)


def sigma_extent(k: float, th0: float, th1: float, a0: float, a1: float) -> float:
    """δ's uncertainty when the reported point may be ``k`` angular radii off (``g`` in
    the printed table is this for ``k = 1``)."""
    return k * math.hypot(a0 / math.tan(th0), a1 / math.tan(th1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sim", nargs="+", default=list(DEFAULT_SIMS))
    ap.add_argument("--backend", choices=("colour", "boxes"), default=None)
    add_config_arguments(ap)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.backend:
        args.set.append(f"detection.backend={args.backend}")
    args.set.append("classifier.head_on_extent_fraction=0")  # every pair, as before the guard
    config = config_from_args(args)
    limit = config.pipeline.classifier.max_disparity_sigma

    pairs: list[tuple[float, float, float, float, str]] = []
    original = pipeline_module.classify_pair

    def recording(t_hat: Any, b0: Any, b1: Any, a0: float, a1: float, *a: Any, **kw: Any) -> Any:
        result = original(t_hat, b0, b1, a0, a1, *a, **kw)
        if result.state != "unknown":
            pairs.append((result.theta0_rad, result.theta1_rad, a0, a1, result.state))
        return result

    pipeline_module.classify_pair = recording  # type: ignore[assignment]
    head = " | ".join(f"k={k:g}: refused (of moving)" for k in KS)
    print(f"limit {limit:g} (max_disparity_sigma)")
    print(f"| scenario | decided pairs | moving | g largest | g median | {head} |")
    print("|---|---|---|---|---|" + "---|" * len(KS))
    for name in args.sim:
        sim = make_scenario(name, duration_s=args.duration, seed=args.seed, shorter_ok=True)
        pairs.clear()
        evaluate_scenario(sim, config, with_bsm=False)
        n = len(pairs)
        moving = sum(p[4] == "moving" for p in pairs)
        g = np.array([sigma_extent(1.0, *p[:4]) for p in pairs]) if pairs else np.zeros(1)
        cells = [f"{g.max():.3f}", f"{np.median(g):.3f}"]
        for k in KS:
            s = np.array([sigma_extent(k, *p[:4]) for p in pairs]) if pairs else np.zeros(0)
            refused = s > limit
            ref_moving = sum(r and p[4] == "moving" for r, p in zip(refused, pairs, strict=True))
            cells.append(f"{int(refused.sum())} ({ref_moving})")
        print(f"| {name} | {n} | {moving} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
