"""Open the flight log for a run: where it goes, what its metadata record holds, and the
handle the companion host writes through (:class:`~tcm_companion.flightlog.handle.FlightLog`).

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

Every flight has an id, in each part's metadata and file name, so that the flights that
share a directory are never joined. Live it is random. A deterministic run derives it
from what makes the run (:func:`deterministic_flight_id`: the configuration, seed
included, the parameters and the simulated start) and from the ids already in the
directory: the same run into an empty directory gives the same bytes every time, and a
second run into the same directory gets another id — two flights, not one.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from . import __version__
from .config import AppConfig, config_to_toml
from .flightlog.handle import FlightLog
from .flightlog.reader import log_files, parse_part_name
from .flightlog.writer import FlightLogWriter
from .service.host import CameraInput


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


def deterministic_flight_id(meta: Mapping[str, str], directory: Path) -> str:
    """The flight id of a deterministic run: a hash of its metadata record (the
    configuration with its seed, the parameters, the cameras, the simulated start) and of
    how many of the ids it would take are already in ``directory`` — the first one not
    there (a second identical run into one directory is another flight)."""
    base = hashlib.sha256(json.dumps(dict(meta), sort_keys=True).encode()).hexdigest()
    try:
        names = [parse_part_name(f.name) for f in log_files(directory)]
    except FileNotFoundError:  # no directory yet
        names = []
    taken = {n[1] for n in names if n is not None and n[1]}
    for n in range(1_000_000):
        fid = hashlib.sha256(f"{base}/{n}".encode()).hexdigest()[:12]
        if fid not in taken:
            return fid
    raise RuntimeError(f"{directory}: no free flight id")  # pragma: no cover


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
    """Start a :class:`~tcm_companion.flightlog.writer.FlightLogWriter` in ``directory``.

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

    session = flight_id = None
    meta = metadata(config, cameras, params, started_unix_us)
    if deterministic:
        assert started_unix_us is not None
        session = time.strftime("%Y%m%d-%H%M%S", time.gmtime(started_unix_us / 1e6))
        flight_id = deterministic_flight_id(meta, directory)
    writer = FlightLogWriter(
        config.logging,
        directory,
        wall_minus_mono_ns=wall_minus_mono_ns,
        on_event=on_event,
        deterministic=deterministic,
        session=session,
        flight_id=flight_id,
    )
    flight_log = FlightLog(writer)
    holder.append(flight_log)
    writer.start(meta)
    return flight_log
