"""One frame slot per camera: the frames a camera delivered that wait to be processed,
beside the camera's pipeline and its last objects (the policy: :mod:`.companion`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.camera import CameraModel
from ..core.pipeline import ObjectResult, Pipeline


@dataclass
class FrameSlot:
    """The newest delivered frame of a camera, not yet processed."""

    image: np.ndarray
    capture_mono_us: int
    arrival_mono_us: int
    waited: bool = False
    waited_for_boxes: bool = False
    boxes_used_before: int = 0  # the live box feed's count before the step
    # Offloaded steps (Companion.offload_steps): when the step was requested and the
    # clock offset its attitude was computed with (None: processed in-process).
    requested_mono_us: int | None = None
    clock_offset_us: float | None = None


@dataclass
class CameraSlots:
    """One camera of the Companion: its pipeline, the frames waiting for it, and what it
    last reported."""

    camera_id: int
    name: str
    model: CameraModel
    pipeline: Pipeline
    # Frames delivered and not yet processed, oldest first: the newest only, unless
    # older ones still wait for their boxes (the live box feed).
    pending: list[FrameSlot] = field(default_factory=list)
    last_objects: tuple[ObjectResult, ...] = ()
    last_capture_mono_us: int | None = None
    last_processed_capture_mono_us: int | None = None  # whatever its result
    consecutive_errors: int = 0
    frames_processed: int = 0  # this camera's share of the Companion's counts
    frames_dropped: int = 0
    # Offloaded steps only: the frame a worker is processing (one at a time), whether
    # the worker can take one, and the pipeline's generation (bumped on each rebuild:
    # the worker rebuilds its own pipeline when the generation it has is older).
    in_flight: FrameSlot | None = None
    worker_up: bool = True
    generation: int = 0
