"""What the :class:`~.companion.Companion` hands its driver after each call: a processed
frame, the once-a-second health check, a parameter a ground station set, and (when its
steps are offloaded to worker processes) a frame to step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.pipeline import FrameResult, PipelineConfig
from ..mavlink.endpoint import HealthReport


@dataclass(frozen=True)
class FrameProcessed:
    """A frame went through its camera's pipeline (``result`` None: the pipeline raised).

    Its MAVLink output is in :meth:`Companion.data_to_send`; ``clock_offset_us`` (the
    autopilot-to-companion offset the pipeline used) and ``override`` (why the objects
    were made unknown, "" if they were not) are what process replay needs."""

    camera_id: int
    result: FrameResult | None
    capture_mono_us: int
    arrival_mono_us: int  # delivered by the camera (on_frame)
    process_mono_us: int  # processing started
    waited: bool  # waited for the attitude sample after it
    clock_offset_us: float
    override: str
    threshold: float
    object_radius_m: float  # TCM_OBJ_RADIUS: what ranges were computed with


@dataclass(frozen=True)
class HealthChecked:
    """The once-a-second health check ran (the daemon pings the watchdog and shows
    ``status_line``); ``changes`` are the inputs whose problem changed (``""``: OK again)."""

    now_mono_us: int
    changes: tuple[tuple[str, str], ...]
    status_line: str
    report: HealthReport
    problems: dict[str, str]  # input -> its problem ("" when healthy)


@dataclass(frozen=True)
class ParamsChanged:
    """A ground station set one of our parameters (the driver persists and logs it)."""

    name: str
    value: float
    now_mono_us: int


@dataclass(frozen=True, eq=False)
class StepRequested:
    """Offloaded steps (:meth:`Companion.offload_steps`): run camera ``camera_id``'s
    pipeline on ``image`` captured at ``capture_mono_us`` and hand the result to
    :meth:`Companion.on_step_done`.

    The telemetry the pipeline would read from the shared buffer at the capture time
    comes with it, computed by the Companion when it asked: ``R_ned_from_body`` (None: no
    attitude covers the frame) and ``pos_ned_m``/``vel_ned_mps`` (None: no position).
    ``generation`` counts the camera's pipeline rebuilds: a worker whose pipeline is of
    an older generation builds a new one from ``pipeline_config`` first."""

    camera_id: int
    image: np.ndarray
    capture_mono_us: int
    R_ned_from_body: np.ndarray | None
    pos_ned_m: np.ndarray | None
    vel_ned_mps: np.ndarray | None
    requested_mono_us: int
    generation: int
    pipeline_config: PipelineConfig


Output = FrameProcessed | HealthChecked | ParamsChanged | StepRequested
