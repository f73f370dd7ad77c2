"""What a cheaper pipeline costs in accuracy: settings that change results, measured.

Issue 15 asks for the pipeline at a fraction of its cost with every eval number within
0.5 points. With results held bit-identical the floor is the Lucas–Kanade tracking of
``[flow] n_points`` points and the vision egomotion over the same points
(docs/decisions.md §8). This study renders each flight once, keeps its frames in memory,
and replays them through the same ``evaluate_scenario`` as ``tcm-companion eval`` under
each variant of the configuration (``config.toml`` plus ``--set``-style overrides),
timing the pipeline's steps on the thread's CPU clock (``time.thread_time``, which
stops while the thread waits for a core: comparable under load) and reporting, per
variant and flight, TCM accuracy, coverage and mean δ of the static and the moving
objects, as ``eval`` counts them (after the 1-s warm-up, at the configured threshold).

    .venv/bin/python tools/pipeline_budget_study.py                    # all variants, ~15 min
    .venv/bin/python tools/pipeline_budget_study.py --variants base n200 --sim T90 --duration 10
    .venv/bin/python tools/pipeline_budget_study.py --timing 5 --variants base n200 n150

Flights: the paper's TS/T45/T90, the traps RAISED/INPLANE/COLLISION, TWO (simulated,
360×220, seed 0, their own 40-s durations) and the three independent examples (rendered
by other code, ``tests/data/examples``). One OpenCV thread, as in the daemon.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from tcm_companion.config import load_config
from tcm_companion.core.pipeline import Pipeline
from tcm_companion.eval.evaluate import evaluate_scenario, summarize
from tcm_companion.io.scenario import load_scenario
from tcm_companion.io.scoring import after_warmup
from tcm_companion.sim import make_scenario

ROOT = Path(__file__).resolve().parent.parent
SIM = ("TS", "T45", "T90", "RAISED", "INPLANE", "COLLISION", "TWO")
EXAMPLES = ("EX-T90", "EX-PINHOLE", "EX-FISHEYE")

#: name -> overrides (``table.key=value``, as ``--set``); "base" is config.toml as it is.
VARIANTS: dict[str, list[str]] = {
    "base": [],
    "n300": ["flow.n_points=300"],
    "n200": ["flow.n_points=200"],
    "n150": ["flow.n_points=150"],
    "win7": ["flow.win_size_px=7"],
    "iter5": ["flow.max_iterations=5"],
    "fb6": ["flow.fb_every=6"],
    "hyp32": ["egomotion.n_hypotheses=32"],
    "n200+win7": ["flow.n_points=200", "flow.win_size_px=7"],
    "n200+iter5": ["flow.n_points=200", "flow.max_iterations=5"],
    "n100": ["flow.n_points=100"],
    "lean150": [
        "flow.n_points=150",
        "flow.fb_every=6",
        "flow.max_iterations=5",
        "egomotion.n_hypotheses=32",
    ],
    "lean100": [
        "flow.n_points=100",
        "flow.fb_every=6",
        "flow.max_iterations=5",
        "egomotion.n_hypotheses=32",
    ],
}


class _Frozen:
    """A scenario whose frames were decoded or rendered once and are kept in memory."""

    def __init__(self, inner: Any) -> None:
        self.name = inner.name
        self.camera = inner.camera
        self.frame_times_us = inner.frame_times_us
        self.telemetry = inner.telemetry
        self.truth = inner.truth
        self._frames = list(inner.iter_frames())
        self.n_frames = len(self._frames)

    def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
        yield from self._frames


class _CpuPipeline(Pipeline):
    """The pipeline, each ``step`` timed on this thread's CPU clock."""

    cpu_ms: ClassVar[list[float]] = []

    def step(self, *args: Any, **kwargs: Any) -> Any:
        c0 = time.thread_time()
        out = super().step(*args, **kwargs)
        type(self).cpu_ms.append(1e3 * (time.thread_time() - c0))
        return out


def _delta(records: list[Any], moving: bool) -> float:
    d = [r.disparity for r in records if r.truth_moving == moving and math.isfinite(r.disparity)]
    return float(np.mean(d)) if d else math.nan


def run_variant(flights: list[_Frozen], sets: list[str]) -> list[dict[str, float | str]]:
    """One row per flight: accuracy, coverage, δ static / moving, CPU ms per frame."""
    import tcm_companion.eval.evaluate as ev_mod

    config = load_config(ROOT / "config.toml", sets=sets)
    rows = []
    real = ev_mod.Pipeline
    ev_mod.Pipeline = _CpuPipeline  # type: ignore[misc]
    try:
        for f in flights:
            _CpuPipeline.cpu_ms = []
            ev = evaluate_scenario(f, config, with_bsm=False)
            cls = config.pipeline.classifier
            summ = {m.method: m for m in summarize(ev.records, cls)}
            tcm = summ.get("tcm")
            after = [r for r in after_warmup(ev.records, cls) if r.state != "unknown"]
            cpu = _CpuPipeline.cpu_ms[30:] or _CpuPipeline.cpu_ms
            rows.append(
                {
                    "flight": f.name,
                    "accuracy": 100.0 * tcm.accuracy if tcm else math.nan,
                    "coverage": 100.0 * tcm.coverage if tcm else math.nan,
                    "delta_static": _delta(after, False),
                    "delta_moving": _delta(after, True),
                    "cpu_ms": float(np.median(cpu)) if cpu else math.nan,
                }
            )
    finally:
        ev_mod.Pipeline = real  # type: ignore[misc]
    return rows


STAGES = ("detect", "flow", "track", "classify", "total")


def time_variants(
    variants: list[str], rounds: int, n_frames: int = 230
) -> dict[str, dict[str, float]]:
    """Per-stage thread-CPU ms per frame (median over ``rounds`` interleaved rounds of
    simulated T90 at 360×220, the first 30 frames of each run not counted)."""
    from tcm_companion.replay.scenario import run_replay

    sim = _Frozen(make_scenario("T90", duration_s=n_frames / 25.0, seed=0))
    pooled: dict[str, dict[str, list[float]]] = {v: {s: [] for s in STAGES} for v in variants}
    for _ in range(rounds):
        for v in variants:  # interleaved: a burst of load hits every variant alike
            config = load_config(ROOT / "config.toml", sets=VARIANTS[v])
            pipe = Pipeline(sim.camera, config.pipeline, time.thread_time)
            for k, result in enumerate(run_replay(sim, config, pipe)):
                if k >= 30:
                    for s in STAGES:
                        pooled[v][s].append(result.timings_ms.get(s, 0.0))
    return {v: {s: float(np.median(x)) for s, x in st.items()} for v, st in pooled.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--sim", nargs="*", default=list(SIM), help="simulated flights")
    ap.add_argument("--examples", nargs="*", default=list(EXAMPLES), help="example scenarios")
    ap.add_argument("--duration", type=float, default=None, help="s (default: the flights')")
    ap.add_argument(
        "--timing",
        type=int,
        metavar="ROUNDS",
        help="instead: per-stage CPU of each variant on T90, ROUNDS interleaved rounds",
    )
    args = ap.parse_args()
    cv2.setNumThreads(1)
    if args.timing:
        table = time_variants(args.variants, args.timing)
        base = table.get("base")
        print("variant       " + "  ".join(f"{s:>8}" for s in STAGES) + "   total/base")
        for v, st in table.items():
            ratio = f"{st['total'] / base['total']:.2f}" if base else ""
            print(f"{v:<12}  " + "  ".join(f"{st[s]:8.2f}" for s in STAGES) + f"   {ratio}")
        return 0
    flights: list[_Frozen] = []
    for name in args.sim:
        print(f"rendering {name} ...", file=sys.stderr, flush=True)
        flights.append(_Frozen(make_scenario(name, duration_s=args.duration, seed=0)))
    for name in args.examples:
        flights.append(_Frozen(load_scenario(ROOT / "tests" / "data" / "examples" / name)))
    print("variant      flight       accuracy  coverage  δ static  δ moving  cpu ms/frame")
    for v in args.variants:
        t0 = time.monotonic()
        rows = run_variant(flights, VARIANTS[v])
        for r in rows:
            print(
                f"{v:<12} {r['flight']:<12} {r['accuracy']:7.1f}%  {r['coverage']:7.1f}%"
                f"  {r['delta_static']:8.3f}  {r['delta_moving']:8.3f}  {r['cpu_ms']:8.2f}"
            )
        cpu = [float(r["cpu_ms"]) for r in rows]
        print(
            f"{v:<12} {'(median)':<12} {'':>27} {'':>18} {float(np.median(cpu)):8.2f}"
            f"   ({time.monotonic() - t0:.0f} s)",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
