"""Virtual-time SITL at the rates a busy companion manages (issue 12 §1).

``tools/time_base_study.py`` replays recorded flights with frames taken away; this runs
the whole service instead — mock autopilot, simulated camera, daemon — on one simulated
clock (``run_sitl_virtual``), with the camera set to 25, 15, 10 and 5 fps
(``[camera] fps``), and at 25 fps with 20% of the frames lost at random (seeded: the
camera delivers an empty image, which the daemon counts and skips). Virtual time makes
every figure independent of the machine's load: run it on a busy machine and the table
is the same.

Accuracy and coverage are the SITL summary's (decided object-frames after the warm-up,
scored against the mock's truth), so each row is what ``tcm-companion sitl --clock
virtual`` would say.

    .venv/bin/python tools/virtual_sitl_rates.py              # T45 and T90, 30 s each
    .venv/bin/python tools/virtual_sitl_rates.py --duration 10 --scenarios T90

The table it prints is quoted in docs/decisions.md §7.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from typing import Any

import numpy as np

from tcm_companion.config import AppConfig
from tcm_companion.io.cameras.base import FrameSource
from tcm_companion.sim.scene.truth_camera import SimulatedCamera
from tcm_companion.sitl.mock_flight import run_sitl_virtual


class LossyCamera(FrameSource):
    """The simulated camera losing ``fraction`` of its frames at random (seeded): a lost
    frame arrives as an empty image at its capture time, as a USB camera's torn frame."""

    def __init__(self, inner: SimulatedCamera, fraction: float, seed: int) -> None:
        super().__init__(inner.name, inner.width, inner.height)
        self.inner = inner
        self.fraction = fraction
        self._rng = np.random.default_rng(seed)

    def open(self) -> None:
        self.inner.open()

    def read(self) -> Any:
        image, t_us = self.inner.read()
        if image is not None and self._rng.random() < self.fraction:
            return None, t_us
        return image, t_us

    def close(self) -> None:
        self.inner.close()


def run(scenario: str, fps: float, loss: float, duration_s: float) -> dict[str, Any]:
    config = AppConfig()
    config = dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, scenario=scenario)
    ).with_camera(
        dataclasses.replace(
            config.camera, source=dataclasses.replace(config.camera.source, fps=fps)
        )
    )
    factory = None
    if loss > 0:

        def factory(mock: Any, model: Any, **kw: Any) -> FrameSource:
            return LossyCamera(SimulatedCamera.for_mock(model, mock, **kw), loss, seed=7)

    with tempfile.TemporaryDirectory() as state:
        report = run_sitl_virtual(
            config,
            duration_s=duration_s,
            state_dir=state,
            camera_factory=factory,
            min_accuracy=None,
        )
    sc = report.score
    s = report.summary
    return {
        "scenario": scenario,
        "rate": f"{fps:g} fps" + (f", {100 * loss:.0f}% lost" if loss else ""),
        "processed": s.processed,
        "decided": sc.decided,
        "accuracy": 100.0 * sc.accuracy if sc.decided else float("nan"),
        "coverage": 100.0 * sc.coverage if sc.scored else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["T45", "T90"])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per run")
    args = ap.parse_args(argv)
    cases = [(25.0, 0.0), (15.0, 0.0), (10.0, 0.0), (5.0, 0.0), (25.0, 0.2)]
    print(f"virtual-time SITL, {args.duration:g} s per run")
    print(
        f"{'flight':7s} {'camera':16s} {'processed':>9s} {'decided':>8s} {'accuracy':>9s} {'coverage':>9s}"
    )
    for scenario in args.scenarios:
        base = None
        for fps, loss in cases:
            r = run(scenario, fps, loss, args.duration)
            base = r["accuracy"] if base is None else base
            print(
                f"{r['scenario']:7s} {r['rate']:16s} {r['processed']:9d} {r['decided']:8d}"
                f" {r['accuracy']:8.1f}% {r['coverage']:8.1f}%"
                + (f"  ({r['accuracy'] - base:+.1f} points)" if r["rate"] != "25 fps" else ""),
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
