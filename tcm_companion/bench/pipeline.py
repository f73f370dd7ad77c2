"""``tcm-companion bench``: per-stage time per frame of the pipeline, one core.

Frames of the simulated T90 flight are rendered first (rendering is not timed), then the
same frames and telemetry go through a fresh pipeline per method. OpenCV is limited to
one thread, as on a busy companion computer. Reported: median and p99 per stage (ms), the
BSM/TCM ratio of the whole-pipeline medians, and the process's peak resident memory.
"""

from __future__ import annotations

import platform
import resource
import time
from collections.abc import Iterator, Sequence

import cv2
import numpy as np

from ..config import AppConfig
from ..core.camera import CameraModel
from ..core.pipeline import FrameResult, Pipeline, PipelineConfig
from ..io.detector_model import read_detector_model
from ..replay.scenario import with_method

STAGES = ("telemetry", "detect", "flow", "track", "classify", "bsm", "total")


class _CpuTimedPipeline(Pipeline):
    """A pipeline that also records each step's CPU time (this thread's clock, ms).

    The stage times are wall clock; on a shared machine a frame's wall time includes
    the time the process waited for a core, so the CPU time of the whole step is
    reported beside them (the ``cpu`` column): what a frame costs, whatever the load.
    """

    def __init__(
        self, camera: CameraModel, config: PipelineConfig, detector_model: bytes | None
    ) -> None:
        super().__init__(camera, config, detector_model=detector_model)
        self.cpu_ms: list[float] = []

    def step(self, frame: np.ndarray, frame_time_us: int) -> FrameResult:
        start = time.thread_time()
        result = super().step(frame, frame_time_us)
        self.cpu_ms.append((time.thread_time() - start) * 1e3)
        return result


def rendered_frames(
    resolution: tuple[int, int], n_frames: int
) -> tuple[object, list[tuple[int, int, np.ndarray]]]:
    """The simulated T90 flight at ``resolution`` (width, height px) and its first
    ``n_frames`` + 30 rendered frames ``(index, t_us, BGR image)``, for timing."""
    from ..sim import make_scenario

    sim = make_scenario("T90", duration_s=(n_frames + 30) / 25.0, seed=0)
    sim = make_scenario(
        "T90", camera=sim.camera.scaled(*resolution), duration_s=(n_frames + 30) / 25.0, seed=0
    )
    return sim, list(sim.iter_frames())


def time_stages(
    config: AppConfig,
    sim: object,
    frames: list[tuple[int, int, np.ndarray]],
    gap_s: float = 0.0,
) -> dict[str, np.ndarray]:
    """Per-stage ms of each frame after a warm-up (wall clock; ``cpu``: the whole step on
    this thread's CPU clock); ``gap_s``: sleep before each frame
    (``tools/pipeline_pacing_study.py``: the daemon's 40 ms between frames vs back to back)."""
    from ..replay.scenario import run_replay

    class _Frozen:
        """The rendered frames replayed without re-rendering."""

        name = sim.name  # type: ignore[attr-defined]
        camera = sim.camera  # type: ignore[attr-defined]
        frame_times_us = sim.frame_times_us  # type: ignore[attr-defined]
        telemetry = sim.telemetry  # type: ignore[attr-defined]
        n_frames = len(frames)

        def iter_frames(self) -> Iterator[tuple[int, int, np.ndarray]]:
            for f in frames:
                if gap_s > 0:
                    time.sleep(gap_s)
                yield f

    pipe = _CpuTimedPipeline(
        sim.camera,  # type: ignore[attr-defined]
        config.pipeline,
        read_detector_model(config.pipeline.detection),
    )
    rows: dict[str, list[float]] = {s: [] for s in STAGES}
    for k, result in enumerate(run_replay(_Frozen(), config, pipe)):
        if k < 30:  # warm-up: caches, first tracks, first full interval
            continue
        for s in STAGES:
            rows[s].append(result.timings_ms.get(s, 0.0))
    out = {s: np.asarray(v) for s, v in rows.items()}
    out["cpu"] = np.asarray(pipe.cpu_ms[30:])
    return out


def run_bench(
    config: AppConfig, resolutions: Sequence[tuple[int, int]], n_frames: int = 200
) -> str:
    cv2.setNumThreads(1)
    lines = [
        f"tcm-companion bench: {n_frames} frames of simulated T90 per run, one OpenCV thread, "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
        f"OpenCV {cv2.__version__}",
        f"egomotion source: {config.pipeline.egomotion_source}; times in ms per frame, median / p99",
        "",
        "cpu: the whole step on this thread's CPU clock (what a frame costs whatever the "
        "machine's load; the stages are wall clock)",
        "",
        "resolution  method  " + "  ".join(f"{s:>13}" for s in (*STAGES, "cpu")),
    ]
    for res in resolutions:
        sim, frames = rendered_frames(res, n_frames)
        # One untimed pass first: the first run in a process pays one-off costs (heap
        # growth, OpenCV and numpy internals) that would otherwise land on one method.
        time_stages(config, sim, frames[:60])
        medians = {}
        cpu = {}
        for method in ("tcm", "ecm", "fused", "bsm"):
            cfg = with_method(config, method)
            t = time_stages(cfg, sim, frames)
            medians[method] = float(np.median(t["total"]))
            cpu[method] = float(np.median(t["cpu"]))
            cells = [
                f"{np.median(t[s]):6.2f}/{np.percentile(t[s], 99):6.2f}" for s in (*STAGES, "cpu")
            ]
            lines.append(f"{res[0]:>4}x{res[1]:<5}  {method:<6}  " + "  ".join(cells))
        lines.append(
            f"{res[0]:>4}x{res[1]:<5}  BSM/TCM median ratio: {medians['bsm'] / medians['tcm']:.2f}"
            f" (cpu: {cpu['bsm'] / cpu['tcm']:.2f})"
        )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    lines += [
        "",
        f"peak resident memory of this process (frames held in memory included): {peak_mb:.0f} MB",
    ]
    return "\n".join(lines)
