"""Open the flight log for a run: where it goes, what its metadata record holds, and the
handle the daemon's plumbing writes through.

The metadata record makes a log self-contained for process replay and export: the
effective configuration (TOML), the parameter values at start, each camera's model, the
version, and the relation between the companion's monotonic clock (``_mono_us``, what
every record is stamped with) and Unix time (``_unix_us``, what viewers show).

Two modes:

- **Live** (``run``, real-time ``sitl``): the writer's thread takes items from a bounded
  queue; a full queue drops the item (counted), never delays the daemon; Unix time is
  the machine's.
- **Deterministic** (``sitl --clock virtual``): the same writer and file format, but the
  log's bytes depend only on what was logged. Unix time is the simulation's
  (``unix_minus_mono_us``), a producer waits for room instead of dropping (waiting costs
  no simulated time), the counters are read once the writer has caught up, and chunks
  end every ``flush_interval_s`` of the *records'* time instead of the wall clock's
  (:class:`_RecordTimeFlushWriter`, see there for the change it stands in for).
"""

from __future__ import annotations

import json
import os
import queue
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .. import __version__
from ..config import AppConfig, config_to_toml
from ..io.flightlog import FlightLogStats, FlightLogWriter
from .plumbing import CameraInput

_WAIT_S = 0.0005  # how often a deterministic producer looks whether the writer caught up


def log_directory(config: AppConfig, state_dir: Path | None = None) -> Path:
    """``[logging] directory``, else systemd's ``$LOGS_DIRECTORY``, else ``STATE/logs``."""
    if config.logging.directory:
        return Path(config.logging.directory)
    env = os.environ.get("LOGS_DIRECTORY")
    if env:
        return Path(env.split(":")[0])
    base = (
        state_dir if state_dir is not None else Path.home() / ".local" / "state" / "tcm-companion"
    )
    return Path(base) / "logs"


def metadata(
    config: AppConfig,
    cameras: Sequence[CameraInput],
    params: Mapping[str, float],
    started_unix_us: int | None = None,
) -> dict[str, str]:
    """The ``tcm-companion`` metadata record; ``started_unix_us`` defaults to now."""
    started_s = time.time() if started_unix_us is None else started_unix_us / 1e6
    meta = {
        "version": __version__,
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started_s)),
        "config": config_to_toml(config),
        "params": json.dumps(dict(params), sort_keys=True),
        "cameras": json.dumps([c.name for c in cameras]),
    }
    for i, cam in enumerate(cameras):
        meta[f"camera{i}"] = json.dumps(cam.model.to_dict())
    return meta


class _RecordTimeFlushWriter(FlightLogWriter):
    """A :class:`FlightLogWriter` whose chunks end on the records' own time.

    The writer ends its open MCAP chunk and flushes every ``flush_interval_s`` of wall
    time, so where chunks end — and the file's bytes — depends on how fast the machine
    ran. In virtual time that must not be. This subclass skips the wall-clock flushes and
    flushes instead before the first record whose time stamp (companion clock, simulated
    here) is ``flush_interval_s`` past the last flush: the same crash-safety bound, in the
    log's own time.

    It stands in for a change to ``io/flightlog.py`` (not this module's to make): a
    constructor option ``flush_on="wall" | "records"`` doing exactly this in ``_loop``
    and ``_process``, plus ``block_when_full`` for :class:`FlightLog`'s waiting producers.
    It overrides two private methods of the writer; ``tests/test_sitl_virtual.py``
    catches a writer change that breaks it (the two logs' bytes differ).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._next_flush_record_us: int | None = None

    def _flush(self, now: float) -> None:  # the wall-clock flushes of the writer loop
        return

    def _process(self, item: tuple[Any, ...]) -> None:
        t_us = int(item[2])  # every queued item is (kind, key, t_us, payload)
        step_us = round(self.config.flush_interval_s * 1e6)
        if self._next_flush_record_us is None:
            self._next_flush_record_us = t_us + step_us
        elif t_us >= self._next_flush_record_us:
            FlightLogWriter._flush(self, time.monotonic())
            self._next_flush_record_us = t_us + step_us
        super()._process(item)


class FlightLog:
    """The flight log as the daemon's plumbing uses it (see the module docstring).

    Producers (``log_*``) are the writer's: non-blocking, False when the item was
    dropped — except in deterministic mode, where they wait for room. ``events`` holds
    the writer's own reports ``(severity, text)`` (disk below the floor, write faults),
    put there from its thread; the plumbing turns them into STATUSTEXT.
    """

    def __init__(self, writer: FlightLogWriter, deterministic: bool = False) -> None:
        self.writer = writer
        self.deterministic = deterministic
        self.events: queue.SimpleQueue[tuple[str, str]] = queue.SimpleQueue()
        self._room = max(1, writer.config.queue_items - 1)

    def _wait_for_room(self) -> None:
        if self.deterministic:
            while self.writer.stats.queue_depth >= self._room and self.writer.alive:
                time.sleep(_WAIT_S)

    def log_frame(self, camera_id: int, t_capture_mono_us: int, image: np.ndarray) -> bool:
        self._wait_for_room()
        return self.writer.log_frame(camera_id, t_capture_mono_us, image)

    def log_annotations(
        self,
        camera_id: int,
        t_capture_mono_us: int,
        circles: list[tuple[float, float, float, str]],
    ) -> bool:
        self._wait_for_room()
        return self.writer.log_annotations(camera_id, t_capture_mono_us, circles)

    def log_mavlink(self, direction: Literal["in", "out"], t_mono_us: int, data: bytes) -> bool:
        self._wait_for_room()
        return self.writer.log_mavlink(direction, t_mono_us, data)

    def log_json(self, topic: str, t_mono_us: int, doc: Mapping[str, Any]) -> bool:
        self._wait_for_room()
        return self.writer.log_json(topic, t_mono_us, doc)

    def caught_up(self) -> FlightLogStats:
        """The writer's counters; in deterministic mode once it has written everything
        queued so far (so that they depend on what was logged, not on thread timing)."""
        st = self.writer.stats
        while self.deterministic and self.writer.alive:
            frames_done = st.frames_logged + st.frames_dropped_disk + st.frames_dropped_error
            msgs_done = st.messages_logged + st.messages_dropped_disk + st.messages_dropped_error
            if frames_done >= st.frames_queued and msgs_done >= st.messages_queued:
                break
            time.sleep(_WAIT_S)
            st = self.writer.stats
        return st

    def state(self) -> tuple[int, dict[str, Any]]:
        """``(TCM_LOG_STATE, counters for the health record)``."""
        st = self.caught_up()
        code = st.log_state_code
        doc = {
            "state": st.state,
            "frames_logged": st.frames_logged,
            "frames_dropped_queue": st.frames_dropped_queue,
            "frames_dropped_disk": st.frames_dropped_disk,
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


def start_flight_log(
    config: AppConfig,
    directory: Path,
    cameras: Sequence[CameraInput],
    params: Mapping[str, float],
    *,
    unix_minus_mono_us: int | None = None,
    started_unix_us: int | None = None,
    deterministic: bool = False,
) -> FlightLog:
    """Start a :class:`~tcm_companion.io.flightlog.FlightLogWriter` in ``directory``.

    ``params``: the endpoint's parameter values now (persisted ones included), which
    replay needs. ``unix_minus_mono_us``: Unix time minus the companion monotonic clock,
    and ``started_unix_us``: when the run started (both default to the machine's, now;
    a simulation passes its own); ``deterministic``: see the module docstring.
    """
    wall_minus_mono_ns: int | None = None
    if unix_minus_mono_us is not None:
        wall_minus_mono_ns = int(unix_minus_mono_us) * 1000
    if deterministic and (unix_minus_mono_us is None or started_unix_us is None):
        raise ValueError("a deterministic flight log needs the simulation's Unix time")
    holder: list[FlightLog] = []

    def on_event(severity: str, text: str) -> None:  # the writer's thread
        if holder:
            holder[0].events.put((severity, text))

    cls = _RecordTimeFlushWriter if deterministic else FlightLogWriter
    writer = cls(
        config.logging, directory, wall_minus_mono_ns=wall_minus_mono_ns, on_event=on_event
    )
    flight_log = FlightLog(writer, deterministic)
    holder.append(flight_log)
    writer.start(metadata(config, cameras, params, started_unix_us))
    return flight_log
