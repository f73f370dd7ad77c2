"""Speed of the simulator's renderer: ms per frame of ``Renderer.render`` (and of its
construction), on the poses the scenario flies.

    .venv/bin/python tools/render_speed.py                     # T90, 150 frames, 360x220
    .venv/bin/python tools/render_speed.py --scenarios T90 TS --frames 300
    .venv/bin/python tools/render_speed.py --camera fisheye --scenarios T90

Frames are rendered at 25 Hz scenario time (``--rate``) along the scenario's own flight (the pose the
virtual-time SITL's camera renders from), with the sensor noise on. The time per frame
is CPU time (``time.process_time``: what one core spends, not what a loaded machine's
wall clock shows) and wall time; OpenCV on one thread, as in
the daemon; the median and the mean over the frames are printed, and
a digest of every frame's bytes, which a speed-up must not change.

``--baseline DIR`` checks a change against another checkout of the package (a worktree
of the commit before it: ``git worktree add /tmp/base HEAD``): the same scenarios are
rendered by both, in subprocesses (``PYTHONPATH=DIR`` and this one's), alternately,
``--repeats`` times each; every frame's SHA-256 must be equal (exit 1 otherwise), and
the medians over the repeats of the per-frame median CPU time are printed side by side.
Pin it to one core (``taskset -c 0``); subprocesses inherit the affinity.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from tcm_companion.sim.scene.cameras import preset_camera
from tcm_companion.sim.scene.render import Renderer
from tcm_companion.sim.scene.scenarios import flight_plan, plan_world


def measure(
    scenario: str, frames: int, seed: int = 0, camera_name: str = "panorama", rate_hz: float = 25.0
) -> dict[str, object]:
    """Build the scenario's renderer and render ``frames`` frames; timings (ms), the
    digest of all frames and each frame's own digest."""
    plan = flight_plan(scenario, seed=seed)
    camera = preset_camera(camera_name, scenario=scenario)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    renderer = Renderer(plan_world(plan), camera, seed=seed)
    build_cpu_ms = 1e3 * (time.process_time() - cpu0)
    build_wall_ms = 1e3 * (time.perf_counter() - wall0)
    rng = np.random.default_rng(np.random.SeedSequence([20160628, seed, 2]))
    t_s = np.arange(frames) / rate_hz
    pos_ned_m = plan.vehicle.position_ned_m(t_s)
    R_ned_from_body = plan.vehicle.R_ned_from_body(t_s)
    digest = hashlib.sha256()
    frame_sha: list[str] = []
    cpu_ms: list[float] = []
    wall_ms: list[float] = []
    for k in range(frames):
        c0, w0 = time.process_time(), time.perf_counter()
        image = renderer.render(float(t_s[k]), pos_ned_m[k], R_ned_from_body[k], rng=rng)
        cpu_ms.append(1e3 * (time.process_time() - c0))
        wall_ms.append(1e3 * (time.perf_counter() - w0))
        digest.update(image.tobytes())
        frame_sha.append(hashlib.sha256(image.tobytes()).hexdigest())
    return {
        "build_cpu_ms": build_cpu_ms,
        "build_wall_ms": build_wall_ms,
        "cpu_median_ms": statistics.median(cpu_ms),
        "cpu_mean_ms": statistics.fmean(cpu_ms),
        "wall_median_ms": statistics.median(wall_ms),
        "wall_mean_ms": statistics.fmean(wall_ms),
        "sha256": digest.hexdigest()[:16],
        "frame_sha256": frame_sha,
    }


def _run_json(pythonpath: str, args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """This script's ``--json`` output, run with ``PYTHONPATH=pythonpath``."""
    cmd = [sys.executable, __file__, "--json", "--frames", str(args.frames)]
    cmd += ["--seed", str(args.seed), "--camera", args.camera, "--rate", str(args.rate)]
    cmd += ["--scenarios", *args.scenarios]
    env = dict(os.environ, PYTHONPATH=pythonpath, PYTHONDONTWRITEBYTECODE="1")
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    result: dict[str, dict[str, object]] = json.loads(out)
    return result


def compare(args: argparse.Namespace) -> int:
    """Render with the baseline checkout and with this one, alternately; compare frames."""
    here = str(Path(__file__).resolve().parents[1])
    base = str(Path(args.baseline).resolve())
    times: dict[str, dict[str, list[float]]] = {"base": {}, "new": {}}
    digests: dict[str, dict[str, list[str]]] = {"base": {}, "new": {}}
    for rep in range(args.repeats):
        order = [("base", base), ("new", here)]
        if rep % 2:
            order.reverse()
        for which, path in order:
            for name, r in _run_json(path, args).items():
                times[which].setdefault(name, []).append(float(r["cpu_median_ms"]))  # type: ignore[arg-type]
                sha = list(r["frame_sha256"])  # type: ignore[call-overload]
                if digests[which].setdefault(name, sha) != sha:
                    print(f"{name}: {which} is not deterministic across runs")
                    return 1
    bad = 0
    print(
        f"# camera {args.camera}, {args.frames} frames at {args.rate:g} Hz, {args.repeats} runs each, CPU ms/frame"
    )
    print("scenario   base median   new median   speed-up   frames equal")
    for name in args.scenarios:
        b, n = digests["base"][name], digests["new"][name]
        equal = sum(x == y for x, y in zip(b, n))
        bad += equal != len(b)
        tb, tn = statistics.median(times["base"][name]), statistics.median(times["new"][name])
        print(
            f"{name:10s} {tb:8.2f}      {tn:8.2f}     {tb / tn:6.2f}x    {equal}/{len(b)}"
            + ("" if equal == len(b) else f"  FIRST DIFF frame {_first_diff(b, n)}")
        )
    return 1 if bad else 0


def _first_diff(a: list[str], b: list[str]) -> int:
    return next(k for k, (x, y) in enumerate(zip(a, b)) if x != y)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["T90"])
    parser.add_argument("--frames", type=int, default=150, help="frames per scenario (150)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--camera", default="panorama", help="camera preset: panorama, pinhole, fisheye"
    )
    parser.add_argument("--rate", type=float, default=25.0, help="frames per second of flight (25)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--baseline", help="another checkout to compare frames and time with")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each with --baseline")
    args = parser.parse_args()
    if args.baseline:
        return compare(args)
    cv2.setNumThreads(1)  # as the daemon and the virtual-time SITL run it (one core)
    if args.json:
        results = {
            n: measure(n, args.frames, args.seed, args.camera, args.rate) for n in args.scenarios
        }
        print(json.dumps(results))
        return 0
    print(f"# {platform.node()} {platform.machine()} Python {platform.python_version()}")
    print(
        "scenario  build cpu/wall (ms)   render cpu median/mean (ms)  "
        "wall median/mean (ms)  frames sha256"
    )
    for name in args.scenarios:
        r = measure(name, args.frames, args.seed, args.camera, args.rate)
        print(
            f"{name:8s}  {r['build_cpu_ms']:7.0f} / {r['build_wall_ms']:7.0f}    "
            f"{r['cpu_median_ms']:6.2f} / {r['cpu_mean_ms']:6.2f}              "
            f"{r['wall_median_ms']:6.2f} / {r['wall_mean_ms']:6.2f}        {r['sha256']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
