"""Per-stage CPU cost of the pipeline per frame, for comparing two source trees.

``tcm-companion bench`` times stages with the wall clock; on a shared machine (2 cores,
other jobs running) a frame's wall time includes the time the process waited for a core,
and the medians move by 2-3x between runs. This study times the same stages with the
thread's CPU clock (``time.thread_time``, which stops while the thread is descheduled), so
two versions measured under different load stay comparable. It imports whichever
``tcm_companion`` is first on ``sys.path``, so the baseline is measured with::

    cd /tmp/base && PYTHONPATH=/tmp/base /work/main/.venv/bin/python \\
        /work/main/tools/pipeline_cost_study.py --json /tmp/cost_base.json
    cd /work/main && .venv/bin/python tools/pipeline_cost_study.py --json /tmp/cost_new.json
    .venv/bin/python tools/pipeline_cost_study.py --compare /tmp/cost_base.json /tmp/cost_new.json

(``/tmp/base``: ``git archive 99b4b75 | tar -x -C /tmp/base``, issue 15's baseline.)
Frames are the bench's (simulated T90, rendered first and not timed); each method runs
``--repeats`` times on a fresh pipeline and every frame's stage times of all repeats are
pooled before taking the median. One OpenCV thread, as in the bench.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np

STAGES = ("telemetry", "detect", "flow", "track", "classify", "bsm", "total")
WARMUP_FRAMES = 30  # as the bench: caches, first tracks, first full interval


def _imports() -> tuple[Any, Any, Any, Any, Any]:
    """The pieces this study needs, from the current tree or from the issue's baseline."""
    from tcm_companion.config import AppConfig
    from tcm_companion.core.pipeline import Pipeline

    try:
        from tcm_companion.replay.scenario import run_replay, with_method
    except ImportError:  # the baseline (99b4b75): replay was one module
        from tcm_companion.replay import run_replay, with_method  # type: ignore[no-redef,attr-defined]
    from tcm_companion.sim import make_scenario

    return AppConfig, Pipeline, run_replay, with_method, make_scenario


def _time(
    config: Any, sim: Any, frames: list[tuple[int, int, np.ndarray]], clock: Any
) -> dict[str, list[float]]:
    _, Pipeline, run_replay, _, _ = _imports()

    class _Frozen:
        name = sim.name
        camera = sim.camera
        frame_times_us = sim.frame_times_us
        telemetry = sim.telemetry
        n_frames = len(frames)

        def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
            yield from frames

    pipe = Pipeline(sim.camera, config.pipeline, clock)
    rows: dict[str, list[float]] = {s: [] for s in STAGES}
    for k, result in enumerate(run_replay(_Frozen(), config, pipe)):
        if k >= WARMUP_FRAMES:
            for s in STAGES:
                rows[s].append(result.timings_ms.get(s, 0.0))
    return rows


def measure(
    resolutions: list[tuple[int, int]], methods: list[str], n_frames: int, repeats: int, wall: bool
) -> dict[str, Any]:
    AppConfig, _, _, with_method, make_scenario = _imports()
    cv2.setNumThreads(1)
    clock = time.perf_counter if wall else time.thread_time
    out: dict[str, Any] = {"clock": "wall" if wall else "thread CPU", "results": {}}
    base = AppConfig()
    for w, h in resolutions:
        duration = (n_frames + 30) / 25.0
        sim = make_scenario("T90", duration_s=duration, seed=0)
        sim = make_scenario("T90", camera=sim.camera.scaled(w, h), duration_s=duration, seed=0)
        frames = list(sim.iter_frames())
        _time(base, sim, frames[:60], clock)  # one-off costs, untimed
        pooled: dict[str, dict[str, list[float]]] = {m: {s: [] for s in STAGES} for m in methods}
        for _ in range(repeats):
            for m in methods:  # interleaved, so a burst of load hits every method alike
                rows = _time(with_method(base, m), sim, frames, clock)
                for s in STAGES:
                    pooled[m][s] += rows[s]
        out["results"][f"{w}x{h}"] = {
            m: {s: float(np.median(v)) for s, v in pooled[m].items()} for m in methods
        }
    return out


def _table(data: dict[str, Any]) -> str:
    lines = [f"median ms per frame ({data['clock']} clock)"]
    lines.append("resolution  method  " + "  ".join(f"{s:>9}" for s in STAGES))
    for res, per in data["results"].items():
        for m, st in per.items():
            lines.append(f"{res:<10}  {m:<6}  " + "  ".join(f"{st[s]:9.2f}" for s in STAGES))
    return "\n".join(lines)


def compare(a: dict[str, Any], b: dict[str, Any]) -> str:
    lines = ["new / baseline, median per stage"]
    lines.append("resolution  method  " + "  ".join(f"{s:>15}" for s in STAGES))
    for res, per in b["results"].items():
        for m, st in per.items():
            ref = a["results"].get(res, {}).get(m)
            if ref is None:
                continue
            cells = [
                f"{ref[s]:5.2f}->{st[s]:5.2f}" + (f" {st[s] / ref[s]:4.2f}" if ref[s] > 0 else "")
                for s in STAGES
            ]
            lines.append(f"{res:<10}  {m:<6}  " + "  ".join(f"{c:>15}" for c in cells))
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolutions", nargs="+", default=["360x220", "900x550"])
    ap.add_argument("--methods", nargs="+", default=["tcm"])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--wall", action="store_true", help="wall clock instead of thread CPU")
    ap.add_argument("--json", help="also write the medians here")
    ap.add_argument("--compare", nargs=2, metavar=("BASE_JSON", "NEW_JSON"))
    args = ap.parse_args()
    if args.compare:
        with open(args.compare[0]) as fa, open(args.compare[1]) as fb:
            print(compare(json.load(fa), json.load(fb)))
        return 0
    res = [tuple(int(x) for x in r.split("x")) for r in args.resolutions]
    data = measure(res, args.methods, args.frames, args.repeats, args.wall)  # type: ignore[arg-type]
    print(_table(data))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(data, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
