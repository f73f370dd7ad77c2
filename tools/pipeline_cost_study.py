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

``--digest`` instead prints, per resolution and configuration (methods tcm, ecm, fused
and bsm; egomotion sources fused, vision and autopilot), a SHA-256 of every field of
every ``FrameResult`` (floats as hex, stage timings left out), of the flow's live points
after each frame and of the Fig. 4 disparities hook: two trees whose lines are equal
give the same results to the bit on these frames. Issue 15's second round (the
per-frame overhead cut without changing a result; NOTES in docs/decisions.md §8.2) was
checked with::

    cd /tmp/wB-base && PYTHONPATH=/tmp/wB-base /work/main/.venv/bin/python \
        /tmp/wB/tools/pipeline_cost_study.py --digest > /tmp/digest_base.txt
    cd /tmp/wB && PYTHONPATH=/tmp/wB /work/main/.venv/bin/python \
        tools/pipeline_cost_study.py --digest > /tmp/digest_new.txt
    diff /tmp/digest_base.txt /tmp/digest_new.txt   # no output: bit-identical
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
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


def _frozen(sim: Any, frames: list[tuple[int, int, np.ndarray]]) -> Any:
    """``sim`` with its frames rendered once (``frames``), for replay after replay."""

    class _Frozen:
        name = sim.name
        camera = sim.camera
        frame_times_us = sim.frame_times_us
        telemetry = sim.telemetry
        n_frames = len(frames)

        def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
            yield from frames

    return _Frozen()


def _bench_frames(w: int, h: int, n_frames: int) -> tuple[Any, list[tuple[int, int, np.ndarray]]]:
    """The bench's frames: simulated T90 at ``w``×``h``, rendered once (30 frames of
    warm-up beyond ``n_frames``)."""
    make_scenario = _imports()[4]
    duration = (n_frames + 30) / 25.0
    sim = make_scenario("T90", duration_s=duration, seed=0)
    sim = make_scenario("T90", camera=sim.camera.scaled(w, h), duration_s=duration, seed=0)
    return sim, list(sim.iter_frames())


def _time(
    config: Any, sim: Any, frames: list[tuple[int, int, np.ndarray]], clock: Any
) -> dict[str, list[float]]:
    _, Pipeline, run_replay, _, _ = _imports()

    pipe = Pipeline(sim.camera, config.pipeline, clock)
    rows: dict[str, list[float]] = {s: [] for s in STAGES}
    for k, result in enumerate(run_replay(_frozen(sim, frames), config, pipe)):
        if k >= WARMUP_FRAMES:
            for s in STAGES:
                rows[s].append(result.timings_ms.get(s, 0.0))
    return rows


def measure(
    resolutions: list[tuple[int, int]], methods: list[str], n_frames: int, repeats: int, wall: bool
) -> dict[str, Any]:
    AppConfig, _, _, with_method, _ = _imports()
    cv2.setNumThreads(1)
    clock = time.perf_counter if wall else time.thread_time
    out: dict[str, Any] = {"clock": "wall" if wall else "thread CPU", "results": {}}
    base = AppConfig()
    for w, h in resolutions:
        sim, frames = _bench_frames(w, h, n_frames)
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


DIGEST_CONFIGS = (
    ("tcm", None),
    ("ecm", None),
    ("fused", None),
    ("tcm", "vision"),
    ("tcm", "autopilot"),
    ("bsm", None),
)


def feed_result(x: Any, h: Any) -> None:
    """Every bit of a result into the hash: floats as hex, arrays as their bytes."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        for f in dataclasses.fields(x):
            if f.name != "timings_ms":  # wall-clock stage times: not results
                h.update(f.name.encode())
                feed_result(getattr(x, f.name), h)
    elif isinstance(x, float):
        h.update(x.hex().encode())
    elif isinstance(x, np.ndarray):
        h.update(str(x.dtype).encode() + str(x.shape).encode())
        h.update(np.ascontiguousarray(x).tobytes())
    elif isinstance(x, np.floating):
        h.update(float(x).hex().encode())
    elif isinstance(x, (tuple, list)):
        h.update(b"[")
        for y in x:
            feed_result(y, h)
        h.update(b"]")
    elif isinstance(x, dict):
        for k in sorted(x):
            h.update(repr(k).encode())
            feed_result(x[k], h)
    else:  # bool, int, str, None, numpy integers and bools
        h.update(repr(x).encode())


def _digest_one(config: Any, sim: Any, frames: list[tuple[int, int, np.ndarray]]) -> str:
    """SHA-256 (16 hex digits) of one configuration's results on these frames."""
    _, Pipeline, run_replay, _, _ = _imports()

    pipe = Pipeline(sim.camera, config.pipeline)
    sha = hashlib.sha256()
    for result in run_replay(_frozen(sim, frames), config, pipe):
        feed_result(result, sha)
        sha.update(pipe.flow.live_points_px.tobytes())
        feed_result(pipe.disparities_for_frame_intervals([5, 25]), sha)
    return sha.hexdigest()[:16]


def digest(resolutions: list[tuple[int, int]], n_frames: int) -> list[str]:
    """One line per resolution and configuration: its results' SHA-256 (16 hex digits)."""
    AppConfig, _, _, with_method, _ = _imports()
    cv2.setNumThreads(1)
    lines = []
    for w, h in resolutions:
        sim, frames = _bench_frames(w, h, n_frames)
        for method, source in DIGEST_CONFIGS:
            config = with_method(AppConfig(), method)
            if source is not None:
                config = dataclasses.replace(
                    config,
                    pipeline=dataclasses.replace(config.pipeline, egomotion_source=source),
                )
            sha = _digest_one(config, sim, frames)
            lines.append(f"{w}x{h}  {method:<5}  {source or 'default':<9}  {sha}")
            print(lines[-1], flush=True)
    return lines


def floor(resolutions: list[tuple[int, int]], n_frames: int) -> str:
    """How much of a frame is OpenCV's own work: the thread CPU spent inside ``cv2``
    calls, per frame, with cProfile on the thread CPU clock over the bench's frames
    (method tcm, default configuration). That is what the pipeline would still cost if
    every line of Python and numpy around those calls took no time at all: a floor for
    any rewrite that keeps the same OpenCV work (same points, same images)."""
    import cProfile
    import pstats

    AppConfig = _imports()[0]
    cv2.setNumThreads(1)
    names = {n for n in dir(cv2) if callable(getattr(cv2, n, None))}
    lines = [
        "thread-CPU ms per frame under cProfile (method tcm); 'opencv': inside cv2 calls",
        f"{'resolution':<11} {'profiled total':>14} {'opencv':>8}  largest OpenCV calls",
    ]
    for w, h in resolutions:
        sim, frames = _bench_frames(w, h, n_frames)
        _time(AppConfig(), sim, frames[:60], time.thread_time)  # one-off costs
        prof = cProfile.Profile(time.thread_time)
        prof.enable()
        _time(AppConfig(), sim, frames, time.thread_time)
        prof.disable()
        stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
        total = 0.0
        per: dict[str, float] = {}
        for (file, _, func), (_, _, tottime, _, _) in stats.items():
            total += tottime
            if file == "~" and func.startswith("<") and func[1:-1] in names:
                per[func[1:-1]] = tottime
        n = len(frames)
        top = sorted(per.items(), key=lambda kv: -kv[1])[:5]
        lines.append(
            f"{w:>4}x{h:<6} {total / n * 1e3:>14.2f} {sum(per.values()) / n * 1e3:>8.2f}  "
            + ", ".join(f"{k} {v / n * 1e3:.2f}" for k, v in top)
        )
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
    ap.add_argument(
        "--digest",
        action="store_true",
        help="instead: a SHA-256 of every result bit per resolution and configuration "
        "(compare two trees' outputs with diff)",
    )
    ap.add_argument(
        "--floor",
        action="store_true",
        help="instead: the thread CPU per frame spent inside OpenCV calls (cProfile)",
    )
    args = ap.parse_args()
    res = [tuple(int(x) for x in r.split("x")) for r in args.resolutions]
    if args.floor:
        print(floor(res, args.frames))  # type: ignore[arg-type]
        return 0
    if args.digest:
        lines = digest(res, args.frames)  # type: ignore[arg-type]
        print("all:", hashlib.sha256("\n".join(lines).encode()).hexdigest()[:16])
        return 0
    if args.compare:
        with open(args.compare[0]) as fa, open(args.compare[1]) as fb:
            print(compare(json.load(fa), json.load(fb)))
        return 0
    data = measure(res, args.methods, args.frames, args.repeats, args.wall)  # type: ignore[arg-type]
    print(_table(data))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(data, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
