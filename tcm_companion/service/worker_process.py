"""The worker process's side of :mod:`.workers`: what runs in each spawned worker.

Apart from :mod:`.workers` (the daemon's side) so that a worker imports the core and
NumPy/OpenCV only: it is started by reference to :func:`worker_main`, and a fresh
interpreter that imported the daemon's modules (the MAVLink dialect above all) would take
three to four times the memory (166 MB against 45 MB at import).
"""

from __future__ import annotations

import contextlib
import multiprocessing.connection
import os
import signal
import traceback
from multiprocessing import resource_tracker, shared_memory
from pathlib import Path
from typing import cast

import numpy as np

from ..core.camera import CameraModel
from ..core.pipeline import FrameResult, Pipeline, PipelineConfig
from ..core.telemetry import TelemetryBuffer
from ..io.allocator import trim_heap, tune_allocator

#: After this many frames a worker gives its heap's free memory back once (the first
#: frames' one-off allocations), as the daemon does at its fifth health check.
TRIM_AFTER_FRAMES = 125


class _ShippedTelemetry:
    """What a worker's pipeline reads as its telemetry: the attitude and position the
    daemon computed for the frame at hand (from its one buffer, at the capture time)."""

    def __init__(self) -> None:
        self.R_ned_from_body: np.ndarray | None = None
        self.position: tuple[np.ndarray, np.ndarray] | None = None

    def attitude_at(self, t_us: int) -> np.ndarray | None:
        return self.R_ned_from_body

    def position_at(self, t_us: int) -> tuple[np.ndarray, np.ndarray] | None:
        return self.position


def _attach(name: str) -> shared_memory.SharedMemory:
    """The daemon's shared memory block ``name``, without registering it with the resource
    tracker (Python 3.11 registers every attach, and the tracker would unlink the
    daemon's block, or warn of a leak, when this worker ends)."""
    register = resource_tracker.register
    resource_tracker.register = lambda *args, **kwargs: None
    try:
        return shared_memory.SharedMemory(name=name)
    finally:
        resource_tracker.register = register


def _name_process(name: str) -> None:
    with contextlib.suppress(OSError):
        Path("/proc/self/comm").write_text(name.encode("utf-8")[:15].decode("utf-8", "ignore"))


def _new_pipeline(
    model: CameraModel,
    config: PipelineConfig,
    telemetry: _ShippedTelemetry,
    detector_model: bytes | None,
) -> Pipeline:
    # The pipeline reads attitude_at and position_at of its telemetry, nothing else.
    return Pipeline(
        model,
        config,
        telemetry=cast(TelemetryBuffer, telemetry),
        detector_model=detector_model,
    )


def worker_main(
    camera_id: int,
    proc_name: str,
    model: CameraModel,
    config: PipelineConfig,
    detector_model: bytes | None,
    shm_name: str,
    shape: tuple[int, ...],
    conn: multiprocessing.connection.Connection,
    opencv_threads: int,
) -> None:
    """A worker process: camera ``camera_id``'s pipeline, one frame per message of
    ``conn``, until the pipe closes or says ``stop``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the daemon stops us (closes the pipe)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _name_process(proc_name)
    # The daemon's allocator settings (the CLI sets them in its process; a spawned
    # interpreter starts with glibc's): numpy's per-frame temporaries reuse the heap
    # instead of page-faulting fresh mappings (io/allocator.py).
    tune_allocator()
    import cv2

    # What the pipeline imports lazily, now rather than in the middle of a frame: the
    # tracker's assignment (core/tracking.py) imported SciPy on the first frame with two
    # tracks, 0.3 s on a quiet machine, 8 s seen on a loaded one (a frame that late).
    import scipy.optimize  # noqa: F401

    if opencv_threads:
        cv2.setNumThreads(opencv_threads)
    shm = _attach(shm_name)
    frame = np.ndarray(shape, dtype=np.uint8, buffer=shm.buf)
    telemetry = _ShippedTelemetry()
    pipeline = _new_pipeline(model, config, telemetry, detector_model)
    trim_heap()  # start-up's garbage (imports) back to the kernel
    frames = 0
    try:
        try:
            conn.send(("ready", os.getpid()))
        except OSError:  # the daemon stopped before we were ready
            return
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            kind = msg[0]
            if kind == "stop":
                break
            if kind == "config":
                pipeline = _new_pipeline(model, msg[1], telemetry, detector_model)
                continue
            _, capture_us, R, pos, vel, image = msg
            telemetry.R_ned_from_body = R
            telemetry.position = None if pos is None else (pos, vel)
            if image is None:
                image = frame.copy()  # the pipeline may keep what it is given
            reply: tuple[str, FrameResult | None, str, str]
            try:
                reply = ("done", pipeline.step(image, capture_us), "", "")
            except Exception as exc:  # one bad frame must not stop the worker
                reply = ("done", None, type(exc).__name__, traceback.format_exc())
            try:
                conn.send(reply)
            except OSError:  # the daemon closed the pipe meanwhile (stopping): done
                break
            frames += 1
            if frames == TRIM_AFTER_FRAMES:  # as the daemon does once it runs
                trim_heap()
    finally:
        del frame
        shm.close()
