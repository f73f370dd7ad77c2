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
  (the writer's ``deterministic`` mode).
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


class FlightLog:
    """The flight log as the daemon's plumbing uses it (see the module docstring).

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

    session = None
    if deterministic:
        assert started_unix_us is not None
        session = time.strftime("%Y%m%d-%H%M%S", time.gmtime(started_unix_us / 1e6))
    writer = FlightLogWriter(
        config.logging,
        directory,
        wall_minus_mono_ns=wall_minus_mono_ns,
        on_event=on_event,
        deterministic=deterministic,
        session=session,
    )
    flight_log = FlightLog(writer)
    holder.append(flight_log)
    writer.start(metadata(config, cameras, params, started_unix_us))
    return flight_log
