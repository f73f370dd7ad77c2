"""Which TCM decision rule: one interval (the paper's), several, a hold, a shorter warm-up?

The paper compares two frames 25 apart. A ball oscillating at 0.35 Hz has, twice per
period, a 1-s displacement that nearly vanishes, so even a perfect measurement gives
δ < 0.09 there (about 12% of T90 frames and 18% of T45 frames, from truth). This study
runs each scenario once, records δ for every frame interval 5..40 per tracked object,
then replays decision rules offline:

- ``K``: intervals compared at each frame (score = the largest δ among them);
- ``H``: hold — a score counts for H frames after it was measured;
- ``kmin``: shortest interval used while a track is younger than every interval in K.

It prints, per rule, TCM accuracy and coverage per scenario (coverage: object-frames
from frame ``kmin`` on that got a decision) and the pooled ROC area.

    .venv/bin/python tools/decision_study.py            # ~10 min on 2 cores
    .venv/bin/python tools/decision_study.py --quick    # shorter flights

The last rule, ``a``, also refuses to call a track stationary before it has been seen
for the full interval (moving may be called from ``kmin``): absence of motion over a
short interval is weak evidence. The printed table is quoted in docs/decisions.md; it
is the evidence behind the defaults, 25, 12 and 10 frames at the simulator's 25 Hz, now
stated in seconds: ``interval_s = 1.0, hold_s = 0.48, min_interval_s = 0.4`` (this
study counts frames at 25 Hz by design; tools/time_base_study.py is about other rates).
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from tcm_companion.config import AppConfig
from tcm_companion.core.pipeline import Pipeline
from tcm_companion.eval.evaluate import match_frame, truth_ttc_s
from tcm_companion.eval.metrics import roc
from tcm_companion.io.scenario import load_scenario
from tcm_companion.replay.scenario import run_replay

INTERVALS = tuple(range(5, 41))
SIM = ("TS", "T45", "T90", "RAISED", "INPLANE", "COLLISION", "TWO")
EXAMPLES = Path(__file__).resolve().parents[1] / "tests" / "data" / "examples"
THRESHOLD = 0.09

# (label, intervals K, hold H, kmin, stationary only after the full interval)
RULES: list[tuple[str, tuple[int, ...], int, int, bool]] = [
    ("paper: K=25", (25,), 0, 25, False),
    ("K=25, kmin=10", (25,), 0, 10, False),
    ("K=25, H=6", (25,), 6, 10, False),
    ("K=25, H=12", (25,), 12, 10, False),
    ("K=25, H=25", (25,), 25, 10, False),
    ("K=12,25", (12, 25), 0, 10, False),
    ("K=12,25,40", (12, 25, 40), 0, 10, False),
    ("K=12,25, H=6", (12, 25), 6, 10, False),
    ("K=12,25, H=12", (12, 25), 12, 10, False),
    ("K=12,25,40, H=12", (12, 25, 40), 12, 10, False),
    ("default: K=25,H=12,a", (25,), 12, 10, True),
]


def record(
    name: str, duration: float | None
) -> tuple[str, list[tuple[int, int, bool, dict[int, float]]]]:
    """(frame, track, truth moving, {interval: δ}) for every matched object-frame."""
    if name.startswith("EX-"):
        sc = load_scenario(EXAMPLES / name)
    else:
        from tcm_companion.sim import make_scenario

        sc = make_scenario(name, duration_s=duration, seed=0)
    cfg = AppConfig()
    pipe = Pipeline(sc.camera, cfg.pipeline)
    truth = sc.truth
    assert truth is not None
    ttc = truth_ttc_s(truth, sc.frame_times_us)
    rows = []
    for result in run_replay(sc, cfg, pipe):
        recs, _ = match_frame(result, truth, result.frame_index, ttc)
        per_k = pipe.disparities_for_frame_intervals(INTERVALS)
        for r in recs:
            if r.matched:
                ds = {k: v[r.track_id] for k, v in per_k.items() if r.track_id in v}
                rows.append((r.frame, r.track_id, r.truth_moving, ds))
    return name, rows


def apply_rule(rows, K, H, kmin, asym=False):  # type: ignore[no-untyped-def]
    """Per object-frame: (truth moving, score or NaN if undecided, frame).

    ``asym``: a track younger than the longest interval in K may be called moving but
    not stationary (undecided instead).
    """
    history: dict[int, list[tuple[int, float]]] = defaultdict(list)
    first_seen: dict[int, int] = {}
    out = []
    for frame, tid, moving, ds in rows:
        first_seen.setdefault(tid, frame)
        vals = [ds[k] for k in K if k in ds]
        if not vals:
            younger = [k for k in ds if kmin <= k < min(K)]
            vals = [ds[max(younger)]] if younger else []
        score = max(vals) if vals else math.nan
        if math.isfinite(score):
            history[tid].append((frame, score))
        recent = [s for f, s in history[tid] if frame - f <= H]
        held = max(recent) if (recent and math.isfinite(score)) else math.nan
        if asym and held <= THRESHOLD and frame - first_seen[tid] < max(K):
            held = math.nan
        out.append((moving, held, frame))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="15-s flights instead of 30 s")
    args = ap.parse_args()
    duration = 15.0 if args.quick else 30.0
    names = [*SIM, "EX-T90", "EX-PINHOLE", "EX-FISHEYE"]
    with ProcessPoolExecutor(2) as pool:
        data = dict(
            pool.map(record, names, [None if n == "COLLISION" else duration for n in names])
        )
    header = f"{'rule':<20}" + "".join(f"{n:>16}" for n in names) + "   pooled AUC (TS+T45+T90)"
    print(f"TCM accuracy / coverage at δ_th = {THRESHOLD}\n")
    print(header)
    for label, K, H, kmin, asym in RULES:
        cells = []
        pooled_t, pooled_s = [], []
        for n in names:
            res = apply_rule(data[n], K, H, kmin, asym)
            after = [(m, s) for m, s, f in res if f >= kmin]
            dec = [(m, s) for m, s in after if math.isfinite(s)]
            acc = np.mean([(s > THRESHOLD) == m for m, s in dec]) if dec else math.nan
            cov = len(dec) / len(after) if after else math.nan
            cells.append(f"{100 * acc:6.1f}%/{100 * cov:5.1f}%")
            if n in ("TS", "T45", "T90"):
                pooled_t += [m for m, _ in dec]
                pooled_s += [s for _, s in dec]
        auc = roc(np.array(pooled_t), np.array(pooled_s)).auc
        print(f"{label:<20}" + "".join(f"{c:>16}" for c in cells) + f"   {auc:.4f}")


if __name__ == "__main__":
    main()
