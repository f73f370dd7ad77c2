"""Simulated camera rigs: one flight seen by every camera of a rig, in memory and on disk.

:func:`make_rig` builds a flight of :mod:`.scenarios` once and looks at it through each
camera of :func:`~.cameras.rig_cameras` (``quad``, ``front-back``, ...): every camera is a
:class:`~.export.SimulatedScenario` of the same plan, seed and telemetry, so the cameras
are synchronised (the same frame times) and their truth is the same objects under the
same ``object_id``. The :class:`SimulatedRig` quacks like
:class:`tcm_companion.io.scenario.RigScenario`; :func:`export_rig` writes it in the rig
form of ``tcm-scenario/1`` (docs/scenario-format.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.camera import CameraModel
from ...core.telemetry import AttitudeSample, PositionSample
from ...io.scenario_writer import RigWriter, rig_scenario_toml
from .cameras import rig_cameras
from .export import SimulatedScenario, detector_config, make_scenario, write_frames
from .scenario_io import targets_toml

if TYPE_CHECKING:
    from .detector_sim import DetectorSimConfig

__all__ = ["SimulatedRig", "export_rig", "make_rig"]


class SimulatedRig:
    """A simulated flight seen by several cameras, with the interface of
    :class:`~tcm_companion.io.scenario.RigScenario` (``cameras[i]``: camera id ``i``)."""

    root: Path | None = None

    def __init__(self, base: SimulatedScenario, cameras: Sequence[tuple[str, CameraModel]]):
        if not cameras:
            raise ValueError("a rig needs at least one camera")
        self.name = flight = base.name
        self.description = f"{base.description}, rig of {len(cameras)} camera(s)"
        self.camera_names = [n for n, _ in cameras]
        self.cameras: list[SimulatedScenario] = []
        for cam_name, lens in cameras:
            sim = base if lens is base.camera else base.with_camera(lens)
            sim.name = f"{flight}/{cam_name}"
            sim.telemetry = base.telemetry  # one telemetry (the same samples anyway)
            self.cameras.append(sim)
        self.plan = base.plan
        self.telemetry = base.telemetry
        self.tlog_bytes = base.tlog_bytes
        self.tlog_stats = base.tlog_stats
        self.truth = base.truth  # every camera's (synchronised: the same frames)
        self.warnings: list[str] = []

    @property
    def n_frames(self) -> int:
        """Frames of every camera together."""
        return sum(c.n_frames for c in self.cameras)

    @property
    def has_truth(self) -> bool:
        return True

    def attitude_samples(self) -> list[AttitudeSample]:
        return [s for s in self.telemetry if isinstance(s, AttitudeSample)]

    def position_samples(self) -> list[PositionSample]:
        return [s for s in self.telemetry if isinstance(s, PositionSample)]


def make_rig(
    name: str,
    rig: str = "quad",
    duration_s: float | None = None,
    seed: int = 0,
    noise: float = 1.0,
    *,
    resolution: tuple[int, int] | None = None,
    shorter_ok: bool = False,
) -> SimulatedRig:
    """Flight ``name`` seen by rig ``rig`` (:func:`~.cameras.rig_cameras`; ``resolution``
    rescales each lens); the other arguments as :func:`~.export.make_scenario`'s."""
    cameras = rig_cameras(rig, resolution)
    base = make_scenario(
        name, cameras[0][1], duration_s=duration_s, seed=seed, noise=noise, shorter_ok=shorter_ok
    )
    return SimulatedRig(base, cameras)


def export_rig(
    rig: SimulatedRig,
    out_dir: str | Path,
    progress: bool | None = None,
    detections: DetectorSimConfig | bool | None = None,
) -> Path:
    """Write ``rig`` as a rig scenario directory (``[[cameras]]``; each camera's frames,
    ``frames.csv``, ``truth.csv`` and, when asked as by
    :func:`~.export.export_scenario`, ``detections.csv`` in ``cameras/NAME``); returns
    its path."""
    writer = RigWriter(out_dir)
    cams = [(n, c.camera) for n, c in zip(rig.camera_names, rig.cameras)]
    extra = targets_toml(rig.plan.objects)
    writer.write_toml(rig_scenario_toml(rig.name, rig.description, cams, extra=extra))
    writer.write_telemetry(rig.tlog_bytes)
    det_config = detector_config(detections)
    show = progress if progress is not None else rig.n_frames > 50
    for cam_name, sim in zip(rig.camera_names, rig.cameras):
        cw = writer.camera(cam_name)
        cw.write_frames_csv(sim.frame_times_us)
        cw.write_truth(sim.truth)
        cw.remove_stale_frames(sim.n_frames)
        if det_config is None:
            cw.remove_detections()
        write_frames(sim, cw, det_config, show)
    return writer.root
