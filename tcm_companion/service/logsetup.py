"""Open the flight log for a run: where it goes, and what its metadata record holds.

The metadata record makes a log self-contained for process replay and export: the
effective configuration (TOML), the parameter values at start, each camera's model, the
version, and the wall-clock/monotonic relation the writer uses.
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from .. import __version__
from ..config import AppConfig, config_to_toml
from ..mavlink import tcm_dialect as d
from ..mavlink.endpoint import CompanionEndpoint
from .daemon import CameraInput


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
    config: AppConfig, cameras: Sequence[CameraInput], params: dict[str, float]
) -> dict[str, str]:
    meta = {
        "version": __version__,
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "config": config_to_toml(config),
        "params": json.dumps(params, sort_keys=True),
        "cameras": json.dumps([c.name for c in cameras]),
    }
    for i, cam in enumerate(cameras):
        meta[f"camera{i}"] = json.dumps(cam.model.to_dict())
    return meta


def start_flight_log(
    config: AppConfig,
    directory: Path,
    cameras: Sequence[CameraInput],
    endpoint: CompanionEndpoint,
    loop: asyncio.AbstractEventLoop,
) -> tuple[Any, Callable[[], tuple[int, dict[str, Any]]]]:
    """Start a :class:`~tcm_companion.io.flightlog.FlightLogWriter`; returns it and the
    ``log_state`` callable the daemon polls once a second.

    The writer's own events (disk below the floor, write faults, recovery) become
    STATUSTEXTs on ``endpoint``, handed to ``loop`` from the writer's thread. The
    metadata records the endpoint's parameter values now (persisted ones included),
    which replay needs.
    """
    from ..io.flightlog import FlightLogWriter

    def on_event(severity: str, text: str) -> None:  # the writer's thread
        sev = d.MAV_SEVERITY_INFO if severity == "info" else d.MAV_SEVERITY_WARNING
        now_us = time.monotonic_ns() // 1000
        loop.call_soon_threadsafe(endpoint.statustext, sev, f"TCM: {text}", now_us)

    params = dict(endpoint.params.values)
    writer = FlightLogWriter(config.logging, directory, on_event=on_event)
    writer.start(metadata(config, cameras, params))

    def state() -> tuple[int, dict[str, Any]]:
        st = writer.stats
        code = int(getattr(st, "log_state_code", d.TCM_LOG_STATE_RECORDING))
        doc = {
            "state": st.state,
            "frames_logged": st.frames_logged,
            "frames_dropped_queue": st.frames_dropped_queue,
            "frames_dropped_disk": st.frames_dropped_disk,
            "messages_dropped_queue": st.messages_dropped_queue,
            "queue_depth": getattr(st, "queue_depth", 0),
            "bytes_written": st.bytes_written,
            "write_errors": st.write_errors,
        }
        return code, doc

    return writer, state
