"""Speed of the simulator's renderer: ms per frame of ``Renderer.render`` (and of its
construction), on the poses the scenario flies.

    .venv/bin/python tools/render_speed.py                     # T90, 150 frames, 360x220
    .venv/bin/python tools/render_speed.py --scenarios T90 TS --frames 300

Frames are rendered at 25 Hz scenario time along the scenario's own flight (the pose the
virtual-time SITL's camera renders from), with the sensor noise on. The time per frame
is CPU time (``time.process_time``: what one core spends, not what a loaded machine's
wall clock shows) and wall time; OpenCV on one thread, as in
the daemon; the median and the mean over the frames are printed, and
a digest of every frame's bytes, which a speed-up must not change.
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import statistics
import time

import cv2
import numpy as np

from tcm_companion.sim.scene.render import Renderer
from tcm_companion.sim.scene.scenarios import default_camera, flight_plan, plan_world


def measure(scenario: str, frames: int, seed: int = 0) -> dict[str, float | str]:
    """Build the scenario's renderer and render ``frames`` frames; timings (ms) and digest."""
    plan = flight_plan(scenario, seed=seed)
    camera = default_camera()
    cpu0, wall0 = time.process_time(), time.perf_counter()
    renderer = Renderer(plan_world(plan), camera, seed=seed)
    build_cpu_ms = 1e3 * (time.process_time() - cpu0)
    build_wall_ms = 1e3 * (time.perf_counter() - wall0)
    rng = np.random.default_rng(np.random.SeedSequence([20160628, seed, 2]))
    t_s = np.arange(frames) / 25.0
    pos_ned_m = plan.vehicle.position_ned_m(t_s)
    R_ned_from_body = plan.vehicle.R_ned_from_body(t_s)
    digest = hashlib.sha256()
    cpu_ms: list[float] = []
    wall_ms: list[float] = []
    for k in range(frames):
        c0, w0 = time.process_time(), time.perf_counter()
        image = renderer.render(float(t_s[k]), pos_ned_m[k], R_ned_from_body[k], rng=rng)
        cpu_ms.append(1e3 * (time.process_time() - c0))
        wall_ms.append(1e3 * (time.perf_counter() - w0))
        digest.update(image.tobytes())
    return {
        "build_cpu_ms": build_cpu_ms,
        "build_wall_ms": build_wall_ms,
        "cpu_median_ms": statistics.median(cpu_ms),
        "cpu_mean_ms": statistics.fmean(cpu_ms),
        "wall_median_ms": statistics.median(wall_ms),
        "wall_mean_ms": statistics.fmean(wall_ms),
        "sha256": digest.hexdigest()[:16],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["T90"])
    parser.add_argument("--frames", type=int, default=150, help="frames per scenario (150)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as the daemon and the virtual-time SITL run it (one core)
    print(f"# {platform.node()} {platform.machine()} Python {platform.python_version()}")
    print(
        "scenario  build cpu/wall (ms)   render cpu median/mean (ms)  "
        "wall median/mean (ms)  frames sha256"
    )
    for name in args.scenarios:
        r = measure(name, args.frames, args.seed)
        print(
            f"{name:8s}  {r['build_cpu_ms']:7.0f} / {r['build_wall_ms']:7.0f}    "
            f"{r['cpu_median_ms']:6.2f} / {r['cpu_mean_ms']:6.2f}              "
            f"{r['wall_median_ms']:6.2f} / {r['wall_mean_ms']:6.2f}        {r['sha256']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
