"""One object, one track, whatever the camera: rig-wide tracks over per-camera pipelines.

Each camera's :class:`~.pipeline.Pipeline` keeps its own tracks (ids per camera). The
:class:`RigTracker` binds them to rig tracks in the one world frame the cameras share
(local-level NED bearings), so that

- an object crossing from one camera's view to the next keeps its id, its history and its
  decision (a *handover*): while the new camera's young track is still warming up, the rig
  decides it from a cross-camera TCM pair (the reference from the camera that saw it an
  interval earlier, the current observation and the translation from the new one);
- an object two overlapping cameras see is one track, reported by one *measuring* camera
  (the better-placed view: farther from its image border), the other view left out;
- a camera lost forgets what only it measured.

Pure: no clock, no IO; time is each result's capture time (``t_us``, the companion clock
every camera shares). The Companion builds one for two cameras or more, and replay of a
rig uses the same class.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .camera import CameraModel
from .pipeline import FrameResult, PipelineConfig


@dataclass(frozen=True)
class RigConfig:
    """Gates of the cross-camera association (rad) and times (s)."""

    # A per-camera track seen for the first time joins a rig track whose predicted NED
    # bearing is within gate_rad + gate_radius_factor * (the larger angular radius).
    gate_rad: float = math.radians(4.0)
    gate_radius_factor: float = 1.5
    # ... and whose size agrees: |ln(α_new / α_rig)| at most this (not checked for a view
    # cut by its image border, whose size is not the object's).
    max_log_size_change: float = math.log(1.6)
    # A rig track no camera has seen for this long is dropped (s).
    max_unseen_s: float = 0.4
    # Another camera takes over the measuring of an object when its view is better placed
    # by this much (angular margin to the image border, rad): no flapping in the overlap.
    switch_margin_rad: float = math.radians(2.0)
    # A view within this angle of its image border (beyond the object's own radius)
    # touches it: its size is not trusted for a cross-camera pair.
    border_margin_rad: float = math.radians(0.5)

    def __post_init__(self) -> None:
        for name in (
            "gate_rad",
            "gate_radius_factor",
            "max_log_size_change",
            "max_unseen_s",
            "switch_margin_rad",
            "border_margin_rad",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"RigConfig.{name} must be >= 0, got {value}")


class RigTracker:
    """Per-camera results in, rig-wide results out (one object, one id)."""

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        pipeline_config: PipelineConfig,
        config: RigConfig = RigConfig(),
    ) -> None:
        self.cameras = list(cameras)
        self.pipeline_config = pipeline_config
        self.config = config
        self.stats: dict[str, int] = {"handovers": 0, "merged": 0, "rig_tracks": 0}

    def fuse(self, camera_id: int, result: FrameResult) -> FrameResult:
        """Camera ``camera_id``'s pipeline result for one frame -> the objects to report
        for it: track_id replaced by the rig-wide id (stable when the object moves to
        another camera), objects another camera measures better left out, a per-camera
        track that continues an object another camera saw decided with that history (a
        cross-camera TCM pair in NED bearings). Same FrameResult type; frame_index/t_us
        unchanged."""
        return result

    def camera_lost(self, camera_id: int) -> None:
        """Camera ``camera_id`` stopped delivering: forget the rig tracks only it measured
        (and its per-camera tracks' bindings)."""
