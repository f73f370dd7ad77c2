"""The flight log as the companion host writes to it: :class:`FlightLog`, a handle on a
running :class:`~.writer.FlightLogWriter`, live (a full queue drops, counted) or
deterministic (a producer waits for room; the counters are read once the writer has
caught up). :mod:`tcm_companion.flight_log_setup` opens it from the configuration and describes
both modes.
"""

from __future__ import annotations

import queue
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from .stats import FlightLogStats
from .writer import FlightLogWriter


class FlightLog:
    """The flight log as the companion host uses it (see the module docstring).

    Producers (``log_*``) are the writer's: non-blocking, False when the item was
    dropped — except in deterministic mode, where they wait for room. ``events`` holds
    the writer's own reports ``(severity, text)`` (disk below the floor, write faults),
    put there from its thread; the plumbing turns them into STATUSTEXT.
    """

    def __init__(self, writer: FlightLogWriter) -> None:
        self.writer = writer
        self.deterministic = writer.deterministic
        self.events: queue.SimpleQueue[tuple[str, str]] = queue.SimpleQueue()

    def log_frame(self, camera_id: int, t_capture_mono_us: int, image: np.ndarray) -> bool:
        return self.writer.log_frame(camera_id, t_capture_mono_us, image)

    def log_annotations(
        self,
        camera_id: int,
        t_capture_mono_us: int,
        circles: list[tuple[float, float, float, str]],
    ) -> bool:
        return self.writer.log_annotations(camera_id, t_capture_mono_us, circles)

    def log_mavlink(self, direction: Literal["in", "out"], t_mono_us: int, data: bytes) -> bool:
        return self.writer.log_mavlink(direction, t_mono_us, data)

    def log_json(self, topic: str, t_mono_us: int, doc: Mapping[str, Any]) -> bool:
        return self.writer.log_json(topic, t_mono_us, doc)

    def caught_up(self) -> FlightLogStats:
        """The writer's counters; in deterministic mode once it has written everything
        queued so far (so that they depend on what was logged, not on thread timing)."""
        if self.deterministic:
            self.writer.wait_drained(timeout_s=600.0)
        return self.writer.stats

    def state(self) -> tuple[int, dict[str, Any]]:
        """``(TCM_LOG_STATE, counters for the health record)``."""
        st = self.caught_up()
        code = st.log_state_code
        doc = {
            "state": st.state,
            "frames_logged": st.frames_logged,
            "frames_dropped_queue": st.frames_dropped_queue,
            "frames_dropped_disk": st.frames_dropped_disk,
            "frames_dropped_error": st.frames_dropped_error,
            "messages_dropped_queue": st.messages_dropped_queue,
            "queue_depth": st.queue_depth,
            "bytes_written": st.bytes_written,
            "write_errors": st.write_errors,
        }
        return code, doc

    @property
    def stats(self) -> FlightLogStats:
        return self.writer.stats

    def stop(self) -> None:
        """Write what is queued and close the file (blocks: run it off the event loop)."""
        self.writer.stop(timeout_s=600.0 if self.deterministic else 5.0)
