"""Replay a camera rig (a rig scenario on disk or a simulated rig) through one pipeline per
camera and the rig tracker, as the daemon runs a rig.

Every camera's :class:`~tcm_companion.core.pipeline.Pipeline` reads one shared
:class:`~tcm_companion.core.telemetry.TelemetryBuffer`; frames are processed in capture
time order across cameras (ties: camera id order), each seeing the telemetry received by
its capture time + ``[daemon] attitude_wait_max_us`` (as :func:`.scenario.run_replay`),
and each result goes through :meth:`tcm_companion.core.rig.RigTracker.fuse` (two cameras
or more; one camera's results are the pipeline's, as a one-camera replay's).
"""

from __future__ import annotations

import dataclasses
import heapq
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import AppConfig
from ..core.detection import Box, BoxesDetector
from ..core.pipeline import FrameResult, Pipeline, PipelineConfig
from ..core.rig import RigTracker
from ..core.telemetry import TelemetryBuffer
from ..io.detector_model import read_detector_model
from .scenario import DetectionRow, boxes_by_frame, telemetry_wait_us

__all__ = ["RigFrame", "RigReplay", "rig_pipeline_config"]


def rig_pipeline_config(config: PipelineConfig, n_cameras: int) -> PipelineConfig:
    """The pipelines' configuration for a rig of ``n_cameras``: as the Companion makes it
    (two cameras or more: every frame's translation, for the rig's cross-camera pairs)."""
    if n_cameras >= 2:
        return dataclasses.replace(config, always_translate=True)
    return config


@dataclass(frozen=True)
class RigFrame:
    """One processed frame of one camera: the pipeline's result and the rig's (``fused``:
    rig-wide track ids, objects another camera measures left out)."""

    camera_id: int
    raw: FrameResult
    fused: FrameResult


class RigReplay:
    """The replay of one rig: ``cameras`` are per-camera scenario-likes (``camera``,
    ``frame_times_us``, ``iter_frames()``, optional ``detections``) sharing
    ``telemetry``. Iterate :meth:`frames` once; ``pipelines`` and ``tracker`` stay
    readable after (stats, per-camera health)."""

    def __init__(
        self,
        cameras: Sequence[Any],
        telemetry: Iterable[Any],
        config: AppConfig,
        detections: Sequence[Iterable[DetectionRow] | None] | None = None,
        name: str = "rig",
    ) -> None:
        self.config = config
        self.cameras = list(cameras)
        pipe_cfg = rig_pipeline_config(config.pipeline, len(self.cameras))
        model = read_detector_model(pipe_cfg.detection)
        self.buffer = TelemetryBuffer()
        self.pipelines = [
            Pipeline(c.camera, pipe_cfg, telemetry=self.buffer, detector_model=model)
            for c in self.cameras
        ]
        self.tracker: RigTracker | None = (
            RigTracker([c.camera for c in self.cameras], pipe_cfg)
            if len(self.cameras) >= 2
            else None
        )
        self._telemetry = sorted(telemetry, key=lambda s: s.recv_us)
        self._boxes: list[dict[int, list[Box]] | None] = []
        for k, (cam, pipe) in enumerate(zip(self.cameras, self.pipelines)):
            if not isinstance(pipe.detector, BoxesDetector):
                self._boxes.append(None)
                continue
            rows = detections[k] if detections is not None else getattr(cam, "detections", None)
            if rows is None:
                raise ValueError(
                    f'{getattr(cam, "name", name)}: [detection] backend "boxes" replays the'
                    " boxes of each camera's detections.csv, and this camera has none"
                )
            self._boxes.append(boxes_by_frame(rows))

    def frames(self) -> Iterator[RigFrame]:
        """Every camera's frames in capture-time order, processed and fused."""
        wait = telemetry_wait_us(self.config)
        telemetry = self._telemetry

        def tagged(k: int) -> Iterator[tuple[int, int, int, np.ndarray | None]]:
            for index, t_us, image in self.cameras[k].iter_frames():
                yield int(t_us), k, index, image

        j = 0
        merged = heapq.merge(*(tagged(k) for k in range(len(self.cameras))), key=lambda x: x[:2])
        for t_us, k, index, image in merged:
            start = j
            while j < len(telemetry) and telemetry[j].recv_us <= t_us + wait:
                j += 1
            self.buffer.extend(telemetry[start:j])
            pipe = self.pipelines[k]
            boxes = self._boxes[k]
            if boxes is not None:
                assert isinstance(pipe.detector, BoxesDetector)
                pipe.detector.push(t_us, boxes.get(index, ()))
            raw = pipe.step(image, t_us)  # type: ignore[arg-type]  # None: an unreadable frame
            fused = raw if self.tracker is None else self.tracker.fuse(k, raw)
            yield RigFrame(k, raw, fused)
