"""``tcm-companion run``: the service systemd starts.

It loads the configuration (CLI ``--set`` > environment > file > defaults), builds the
camera source, and runs the service (:func:`tcm_companion.service.runner.open_service`)
on uvloop until SIGTERM (exit 0) or SIGINT (exit 130), notifying systemd (READY, STATUS,
WATCHDOG, STOPPING); docs/daemon.md, "Stopping and exit status". With ``[camera] source
= "sim"`` there is no vehicle to look at, so ``run`` flies the mock autopilot in the same
process (SITL, :mod:`.sitl`) and goes on until stopped.

asyncio and everything beyond the standard library are imported by the command, not
here (see :mod:`.common`).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import (
    add_command,
    add_config_arguments,
    add_log_level_argument,
    config_file,
    config_from_args,
    run_seconds,
    setup_logging,
)
from .event_loop import run_until_signal
from .interrupts import RunSignals, interruptible
from .run_outputs import check_outputs, run_inputs, write_summary_json
from .scenario_camera import camera_from_scenario, lens_overrides
from .sitl import run_sitl_until, warn_url_ignored
from .status_line import StatusPrinter, add_status_every, status_printer

if TYPE_CHECKING:
    import asyncio

    from ..config import AppConfig
    from ..flightlog.handle import FlightLog
    from ..service.host import DaemonSummary
    from ..service.runner import StartLog

log = logging.getLogger("tcm_companion")


def state_dir_for(config: AppConfig) -> Path:
    """``[daemon] state_dir``, else systemd's, XDG's or ~/.local/state/tcm-companion."""
    if config.daemon.state_dir:
        return Path(config.daemon.state_dir)
    env = os.environ.get("STATE_DIRECTORY")
    if env:
        return Path(env.split(":")[0])
    xdg = os.environ.get("XDG_STATE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".local" / "state"
    return base / "tcm-companion"


@interruptible
def cmd_run(args: argparse.Namespace) -> int:
    """The service. Exit 0 when SIGTERM (systemd's stop) or ``--duration`` ends it,
    130 when SIGINT (Ctrl-C) does, 2 on a configuration or start-up error."""
    setup_logging(args.log_level)
    config = config_from_args(args)
    from ..config import rig_source_problems

    problems = rig_source_problems(config, config_file(args) or "config")
    if problems:
        for problem in problems:
            print(f"error: {problem}", file=sys.stderr)
        return 2
    from ..io.sdnotify import Notifier, watchdog_interval_us

    notifier = Notifier.from_env()
    wd_us = watchdog_interval_us(os.environ)
    state = state_dir_for(config)
    try:
        state.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"error: state directory {state}: {exc.strerror}", file=sys.stderr)
        return 2
    from ..service.endpoint_setup import resolve_state_paths

    config = dataclasses.replace(config, mavlink=resolve_state_paths(config.mavlink, state))
    inputs = run_inputs(args, config)
    run_log_dir = None
    if config.logging.enabled:
        from ..flight_log_setup import log_directory

        run_log_dir = log_directory(config, state)
    # found now, not after a flight of hours
    check_outputs(inputs, run_log_dir, args.summary_json, "[logging] directory")
    if config.camera.source.source == "scenario":
        try:
            config = camera_from_scenario(config, lens_overrides(args.set, os.environ))
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    signals = RunSignals()
    ran_out: list[bool] = []  # --duration ended the run (not a signal)

    if config.camera.source.source == "sim":
        log.info("camera source is the simulator: flying the mock autopilot (SITL)")
        warn_url_ignored(config, 'with [camera] source = "sim"')
        from ..flight_log_setup import log_directory

        log_dir = str(log_directory(config, state)) if config.logging.enabled else None
        # The service's exit status is about the service, not the simulation's accuracy.
        return run_sitl_until(
            config,
            args.duration,
            status_printer(args.status_every, not args.no_status),
            signals,
            service=True,
            notifier=notifier,
            state_dir=str(state),
            log_dir=log_dir,
            min_accuracy=None,
            summary_json=(
                None
                if args.summary_json is None
                else lambda summary: write_summary_json(
                    args.summary_json, summary, inputs=inputs, others=[log_dir]
                )
            ),
        )

    from ..io.cameras.base import CameraError
    from ..io.cameras.settings import open_source
    from ..sim.sources import register_sim_sources

    register_sim_sources()  # source = "sim_autopilot" is the simulator's
    sources = []
    for cam in config.cameras:
        try:
            # built; its reader thread opens it
            sources.append(open_source(cam.source, cam.model))
        except CameraError as exc:
            rig = f"camera {cam.name}: " if len(config.cameras) > 1 else ""
            print(f"error: {rig}{exc}", file=sys.stderr)
            return 2

    async def main_flight(
        printer: StatusPrinter | None, stop: asyncio.Event
    ) -> DaemonSummary | int:
        import asyncio

        from ..service.daemon import CameraInput

        if args.duration is not None:

            def time_up() -> None:
                if not stop.is_set():
                    ran_out.append(True)
                stop.set()

            asyncio.get_running_loop().call_later(args.duration, time_up)
        from ..io.persist import SigningKeyError
        from ..service.runner import open_service

        # Each camera is expected at the rate it is set to ([camera] fps, or its
        # [[cameras]] table's); camera id = its index in the configuration.
        cameras = [
            CameraInput(cam.name, cam.model, source, fps=cam.source.fps)
            for cam, source in zip(config.cameras, sources, strict=True)
        ]
        start_log: StartLog | None = None
        if config.logging.enabled:
            from ..flight_log_setup import log_directory, start_flight_log

            log_dir = log_directory(config, state)

            def start_log_in_dir(params: Mapping[str, float]) -> FlightLog:
                # The parameters in force at start (persisted ones included): replay
                # needs them.
                flight_log = start_flight_log(config, log_dir, cameras, params)
                log.info("flight log in %s", log_dir)
                return flight_log

            start_log = start_log_in_dir

        try:
            async with open_service(
                config,
                cameras,
                state_dir=state,
                start_log=start_log,
                persist_changes=True,
                notifier=notifier,
                watchdog_interval_us=wd_us,
                on_status=printer,
            ) as service:
                return await service.run(stop)
        except SigningKeyError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2

    with status_printer(args.status_every, not args.no_status) as printer:
        summary = run_until_signal(signals, lambda stop: main_flight(printer, stop))
    if isinstance(summary, int):
        return summary
    if args.summary_json:
        write_summary_json(args.summary_json, summary, inputs=inputs, others=[run_log_dir])
    from ..service.host import run_length_text

    stopped_by = "" if ran_out else signals.stopped_by(True) or "stop"
    lat = summary.latency_percentile_ms(99)
    latency = f"latency p99 {lat:.2f} ms" if summary.latencies_ms else "latency n/a"
    ran = run_length_text(summary.duration_s, args.duration, stopped_by)
    if not ran.startswith(("stopped", "interrupted")):
        ran = f"stopped after {ran}"
    feed = ""
    if len(summary.camera_names) > 1:  # a rig: each camera's frames, processed/captured
        from .run_outputs import camera_summaries

        feed += "; cameras " + ", ".join(
            f"{c['name']} {c['processed']}/{c['captured']}" for c in camera_summaries(summary)
        )
    feed += f"; box feed {summary.box_feed}" if summary.box_feed else ""
    feed += f"; link {summary.link}" if summary.link else ""
    print(
        f"{ran}: captured {summary.captured}, processed {summary.processed}, dropped"
        f" {summary.dropped}, failed {summary.failed}, rejected {summary.rejected}; {latency};"
        f" faults {summary.faults or 'none'}{feed}"
    )
    silent = cameras_without_frames(summary.camera_stats)
    for line in silent:
        print(f"error: {line}", file=sys.stderr)
    return RunSignals.exit_status(not silent, stopped_by, service=True)


def cameras_without_frames(camera_stats: dict[str, Any]) -> list[str]:
    """Why each camera that delivered no frame in the whole run did not, one line each
    (a run that saw nothing is not a success, whatever stopped it)."""
    out = []
    for name, s in camera_stats.items():
        if s.delivered:
            continue
        if s.captured:
            why = (
                f"all {s.captured} images it returned were rejected ({s.rejected_empty} empty,"
                f" {s.rejected_size} of the wrong size)"
            )
        elif s.open_failures:
            why = f"it could not be opened ({s.open_failures} tries; last: {s.last_error})"
        elif s.last_error:
            why = f"reading failed ({s.last_error})"
        else:
            why = "it returned no image"
        out.append(f"camera {name} never produced a frame: {why}")
    return out


def add_parsers(sub: Any) -> None:
    """Register ``run`` on the main parser's subparsers."""
    p = add_command(
        sub,
        "run",
        "The flight daemon: cameras in, one status per object and frame out on MAVLink, until"
        ' SIGTERM. With [camera] source = "sim" it flies the mock autopilot in the same'
        " process.",
    )
    add_config_arguments(p)
    add_log_level_argument(p)
    p.add_argument(
        "--duration",
        type=run_seconds,
        default=None,
        metavar="S",
        help="stop after S seconds (> 0, at most a week; default: until SIGTERM, exit 0, or"
        " SIGINT, exit 130)",
    )
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    add_status_every(p)
    p.add_argument(
        "--summary-json", metavar="FILE", default=None, help="write the run's summary as JSON"
    )
    p.set_defaults(func=cmd_run, sigterm_status=0)  # systemd stops it so: a normal end
