"""What the flight log's writer counts: every item once, by what became of it, and the
log's state (as MAVLink's ``TCM_LOG_STATE``)."""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

# MAVLink enum TCM_LOG_STATE (tcm_companion/mavlink/tcm.xml)
TCM_LOG_STATE_OFF = 0
TCM_LOG_STATE_RECORDING = 1
TCM_LOG_STATE_FAULT = 2

LogState = Literal["off", "recording", "frames paused (disk)", "fault"]
STATE_CODES: dict[str, int] = {
    "off": TCM_LOG_STATE_OFF,
    "recording": TCM_LOG_STATE_RECORDING,
    "frames paused (disk)": TCM_LOG_STATE_RECORDING,
    "fault": TCM_LOG_STATE_FAULT,
}

# What becomes of a logged item (the suffix of a FlightLogStats counter).
Outcome = Literal["queued", "logged", "dropped_queue", "dropped_disk", "dropped_error"]
#: The kinds of queued item.
KIND_FRAME, KIND_ANNOTATIONS, KIND_MAVLINK, KIND_JSON = 0, 1, 2, 3
KIND_NAMES = {
    KIND_FRAME: "frame",
    KIND_ANNOTATIONS: "annotations",
    KIND_MAVLINK: "MAVLink",
    KIND_JSON: "JSON",
}


@dataclass
class FlightLogStats:
    """The writer's counts: the writer keeps one under its lock and counts into it;
    :attr:`FlightLogWriter.stats` returns a copy (a snapshot) with the live values
    (bytes, files, state, queue depth) filled in.

    Once stopped, every ``log_frame`` call is exactly one of ``frames_logged``,
    ``frames_dropped_queue`` (queue full, or not recording, or still queued when ``stop``
    timed out), ``frames_dropped_disk`` (free-space floor) and ``frames_dropped_error``
    (log in fault, or the image could not be encoded); ``frames_dropped_error`` is 0 unless
    something failed. ``messages_*`` count the other calls (annotations, MAVLink, JSON) the
    same way. ``write_errors`` counts every failed file operation, retries included.
    """

    frames_queued: int = 0
    frames_logged: int = 0
    frames_dropped_queue: int = 0
    frames_dropped_disk: int = 0
    messages_logged: int = 0
    messages_dropped_queue: int = 0
    bytes_written: int = 0
    files: list[Path] = field(default_factory=list)
    write_errors: int = 0
    state: LogState = "off"
    frames_dropped_error: int = 0
    messages_queued: int = 0
    messages_dropped_disk: int = 0  # annotations under the free-space floor
    messages_dropped_error: int = 0
    encode_errors: int = 0
    writer_cpu_s: float = 0.0  # CPU time of the writer thread
    queue_depth: int = 0

    def count(self, kind: int, outcome: Outcome) -> None:
        """One more frame (``kind`` :data:`KIND_FRAME`) or other message, ``outcome``."""
        name = f"{'frames' if kind == KIND_FRAME else 'messages'}_{outcome}"
        setattr(self, name, getattr(self, name) + 1)

    @property
    def log_state_code(self) -> int:
        """The state as MAVLink ``TCM_LOG_STATE`` (OFF=0, RECORDING=1, FAULT=2)."""
        return STATE_CODES[self.state]


def lost_outcome(exc: BaseException) -> Outcome:
    """How an item lost to the write error ``exc`` is counted: a full disk (ENOSPC, or
    a quota: EDQUOT) is ``dropped_disk``, like the free-space floor; anything else
    ``dropped_error``."""
    full = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
    return "dropped_disk" if full else "dropped_error"
