"""Per-frame cost of two source trees' pipelines, paired frame by frame in one process.

On a shared machine (2 cores, load 4-10 from other jobs) two bench runs minutes apart
differ by more than a few-percent speed-up: the load changes between them, and even the
thread's CPU clock moves with it (caches shared with the other jobs). This study takes
the load out of the comparison: the pipeline core (``tcm_companion/core``, which imports
only itself) of a second tree (``--base``) is loaded beside this tree's under another
package name, both get the same rendered frames and the same telemetry, and each frame
is processed by both, one right after the other (which goes first alternates), each on
the thread's CPU clock. A burst of load hits both alike; the per-frame ratio new/base is
reported with its quartiles. Each frame's results (every ``FrameResult`` field, floats
as hex, stage timings left out) are compared between the two: the last column says
whether every frame was bit-identical.

Frames: the bench's (simulated T90, rendered by this tree and not timed), one OpenCV
thread, 30 warm-up frames per round excluded. Issue 15 (second round)::

    cd /tmp/wB && PYTHONPATH=/tmp/wB taskset -c 1 /work/main/.venv/bin/python \\
        tools/pipeline_pair_study.py --base /tmp/wB-base --rounds 3

(``/tmp/wB-base``: ``git worktree add /tmp/wB-base 67243eb``, main before that round.)
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib.util
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import cv2
import numpy as np

# The result digest of the cost study (tools/ is this script's directory, on sys.path).
from pipeline_cost_study import feed_result

STAGES = ("telemetry", "detect", "flow", "track", "classify", "total")
WARMUP_FRAMES = 30
BASE_PACKAGE = "_pair_base_core"


def load_core(tree: Path) -> ModuleType:
    """``tree/tcm_companion/core`` imported as the package ``_pair_base_core``."""
    init = tree / "tcm_companion" / "core" / "__init__.py"
    spec = importlib.util.spec_from_file_location(
        BASE_PACKAGE, init, submodule_search_locations=[str(init.parent)]
    )
    if spec is None or spec.loader is None:
        raise SystemExit(f"no pipeline core at {init.parent}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[BASE_PACKAGE] = module
    spec.loader.exec_module(module)
    return module


def _as_class(obj: Any, cls: type) -> Any:
    """``obj`` rebuilt as an instance of ``cls`` (the other tree's class of that name)."""
    if dataclasses.is_dataclass(obj) and getattr(cls, "__slots__", None):
        return cls(**{f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)})
    new: Any = object.__new__(cls)
    new.__dict__.update(obj.__dict__)
    return new


def _digest(result: Any) -> bytes:
    h = hashlib.sha256()
    feed_result(result, h)
    return h.digest()


def measure(base_tree: Path, resolution: tuple[int, int], method: str, n_frames: int, rounds: int):  # type: ignore[no-untyped-def]
    from tcm_companion.config import AppConfig
    from tcm_companion.core.pipeline import Pipeline
    from tcm_companion.replay.scenario import telemetry_wait_us, with_method
    from tcm_companion.sim import make_scenario

    base = sys.modules.get(BASE_PACKAGE) or load_core(base_tree)
    importlib.import_module(f"{BASE_PACKAGE}.pipeline")
    base_pipeline = sys.modules[f"{BASE_PACKAGE}.pipeline"]
    base_camera = sys.modules[f"{BASE_PACKAGE}.camera"]
    base_telemetry = importlib.import_module(f"{BASE_PACKAGE}.telemetry")
    assert base is not None

    w, h = resolution
    duration = (n_frames + WARMUP_FRAMES) / 25.0
    sim = make_scenario("T90", duration_s=duration, seed=0)
    sim = make_scenario("T90", camera=sim.camera.scaled(w, h), duration_s=duration, seed=0)
    frames = list(sim.iter_frames())
    config = with_method(AppConfig(), method)  # type: ignore[arg-type]
    wait = telemetry_wait_us(config)
    telemetry = sorted(sim.telemetry, key=lambda s: s.recv_us)
    telemetry_base = [_as_class(s, getattr(base_telemetry, type(s).__name__)) for s in telemetry]
    camera_base = _as_class(sim.camera, getattr(base_camera, type(sim.camera).__name__))

    rows: dict[str, dict[str, list[float]]] = {k: {s: [] for s in STAGES} for k in ("base", "new")}
    ratio: list[float] = []
    identical = True
    for _ in range(rounds):
        pipes = {
            "base": base_pipeline.Pipeline(camera_base, config.pipeline, time.thread_time),
            "new": Pipeline(sim.camera, config.pipeline, time.thread_time),
        }
        samples = {"base": telemetry_base, "new": telemetry}
        j = 0
        for k, (_, t_us, image) in enumerate(frames):
            start = j
            while j < len(telemetry) and telemetry[j].recv_us <= t_us + wait:
                j += 1
            order = ("base", "new") if k % 2 == 0 else ("new", "base")
            results = {}
            for name in order:
                pipes[name].telemetry.extend(samples[name][start:j])
                results[name] = pipes[name].step(image, t_us)
            identical = identical and _digest(results["base"]) == _digest(results["new"])
            if k < WARMUP_FRAMES:
                continue
            for name in ("base", "new"):
                for s in STAGES:
                    rows[name][s].append(results[name].timings_ms.get(s, 0.0))
            ratio.append(results["new"].timings_ms["total"] / results["base"].timings_ms["total"])
    return rows, np.asarray(ratio), identical


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, type=Path, help="the other source tree (a checkout)")
    ap.add_argument("--resolutions", nargs="+", default=["360x220", "900x550"])
    ap.add_argument("--methods", nargs="+", default=["tcm"])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3, help="fresh pipelines per resolution")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    print(
        f"thread-CPU ms per frame, median over {args.rounds} x {args.frames} frames; "
        f"base = {args.base}, new = this tree"
    )
    print(
        "resolution  method  version "
        + "  ".join(f"{s:>9}" for s in STAGES)
        + "   new/base per frame: median [q25, q75]   bit-identical"
    )
    for r in args.resolutions:
        res = tuple(int(x) for x in r.split("x"))
        for m in args.methods:
            rows, ratio, identical = measure(args.base, res, m, args.frames, args.rounds)  # type: ignore[arg-type]
            med = {k: {s: float(np.median(v)) for s, v in rows[k].items()} for k in rows}
            for k in ("base", "new"):
                print(f"{r:<10}  {m:<6}  {k:<7} " + "  ".join(f"{med[k][s]:9.3f}" for s in STAGES))
            q25, q50, q75 = np.percentile(ratio, [25, 50, 75])
            print(
                f"{r:<10}  {m:<6}  ratio   "
                + "  ".join(
                    f"{med['new'][s] / med['base'][s]:9.3f}" if med["base"][s] > 0 else f"{'':9}"
                    for s in STAGES
                )
                + f"   {q50:.3f} [{q25:.3f}, {q75:.3f}]   {'yes' if identical else 'NO'}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
