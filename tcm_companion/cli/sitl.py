"""``tcm-companion sitl``: the daemon with a simulated camera against the mock autopilot
(real time over loopback UDP, or virtual time on one simulated clock) or against
ArduCopter SITL, for a fixed time; then the report. Exit 0, 1 if the run failed, 128 +
the signal (130 for SIGINT) if one cut it short (docs/daemon.md, "Stopping and exit
status"). ``run`` with ``[camera] source = "sim"`` flies the same real-time SITL
(:func:`run_sitl_until`).

Like every command module, this one leaves asyncio and what lies beyond the standard
library to the command's own imports (:mod:`.common`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ..sim.scene.names import RIGS, SCENARIO_NAMES
from .common import (
    add_command,
    add_config_arguments,
    add_log_level_argument,
    config_from_args,
    percent,
    run_seconds,
    setup_logging,
)
from .event_loop import run_loop, run_until_signal
from .interrupts import RunSignals, interruptible
from .run_outputs import check_outputs, run_inputs
from .status_line import StatusPrinter, add_status_every, status_printer

if TYPE_CHECKING:
    import asyncio

    from ..config import AppConfig
    from ..service.host import DaemonSummary
    from ..sitl.mock_flight import SitlReport

log = logging.getLogger("tcm_companion")


@interruptible
def cmd_sitl(args: argparse.Namespace) -> int:
    """SITL for ``--duration``. Exit 0, 1 if the run failed, 128 + the signal (130 for
    SIGINT) if one cut it short."""
    setup_logging(args.log_level)
    config = config_from_args(args)
    if args.autopilot == "ardupilot":
        return _run_ardupilot(args, config)
    if args.scenario and args.scenario not in SCENARIO_NAMES:
        print(
            f"error: --scenario {args.scenario} is not one of the mock autopilot's"
            f" ({', '.join(SCENARIO_NAMES)}); CROSSING and HEADON of --autopilot ardupilot"
            " are flown by the real firmware",
            file=sys.stderr,
        )
        return 2
    if args.scenario:
        config = dataclasses.replace(
            config, sim=dataclasses.replace(config.sim, scenario=args.scenario)
        )
    warn_url_ignored(config, "by sitl")
    from ..sitl.mock_flight import DEFAULT_MIN_ACCURACY

    pct = 100.0 * DEFAULT_MIN_ACCURACY if args.min_accuracy is None else args.min_accuracy
    min_accuracy = None if pct <= 0 else pct / 100.0
    printer = status_printer(args.status_every, not args.no_status)
    if args.log is not None:
        check_outputs(run_inputs(args, config), args.log, None, "--log")
    signals = RunSignals()
    rig = args.rig or ("config" if len(config.cameras) > 1 else "panorama")
    if args.clock == "virtual":
        return _run_sitl_virtual(
            config, args.duration, printer, signals, args.log, min_accuracy, rig
        )
    return run_sitl_until(
        config,
        args.duration,
        printer,
        signals,
        log_dir=args.log,
        min_accuracy=min_accuracy,
        rig=rig,
    )


def warn_url_ignored(config: AppConfig, when: str) -> None:
    """Say that ``[mavlink] url`` is not used (``when``): the daemon then talks to the
    mock autopilot in the same process, over a loopback UDP pair of its own."""
    from ..service.endpoint_setup import MavlinkConfig

    url = config.mavlink.url
    if url != MavlinkConfig.url:
        log.warning(
            "[mavlink] url = %r is ignored %s: the daemon talks to the mock autopilot in this"
            " process over loopback UDP; to fly the simulated camera against your own"
            ' autopilot, use [camera] source = "sim_autopilot" with sim_url',
            url,
            when,
        )


def _finish(report: SitlReport, signals: RunSignals, *, service: bool = False) -> int:
    """Print ``report`` (naming the signal that cut it short) and return the exit status."""
    stopped_by = signals.stopped_by(report.stopped_by == "stop")
    if stopped_by:
        report = dataclasses.replace(report, stopped_by=stopped_by)
    print("\n".join(report.lines()))
    return RunSignals.exit_status(report.ok, stopped_by, service=service)


def _run_sitl_virtual(
    config: AppConfig,
    duration_s: float,
    printer: contextlib.AbstractContextManager[StatusPrinter | None],
    signals: RunSignals,
    log_dir: str | None,
    min_accuracy: float | None,
    rig: str = "panorama",
) -> int:
    """``sitl --clock virtual``: no event loop; SIGINT/SIGTERM end the simulation early."""
    from ..sitl.mock_flight import run_sitl_virtual

    stop = threading.Event()
    with printer as on_status, signals.installed(stop.set):
        report = run_sitl_virtual(
            config,
            camera_model=config.camera.model if rig == "panorama" else None,
            rig=rig,
            duration_s=duration_s,
            should_stop=stop.is_set,
            on_status=on_status,
            log_dir=log_dir,
            min_accuracy=min_accuracy,
        )
    return _finish(report, signals)


def _run_ardupilot(args: argparse.Namespace, config: AppConfig) -> int:
    """``sitl --autopilot ardupilot``: real ArduCopter SITL with the applet, one flight."""
    from ..sitl.ardupilot import SCENES
    from ..sitl.ardupilot_process import skip_reason

    scene = (args.scenario or "CROSSING").lower()
    if scene not in SCENES:
        print(
            f"error: with --autopilot ardupilot, --scenario is one of"
            f" {', '.join(s.upper() for s in SCENES)}, got {args.scenario}",
            file=sys.stderr,
        )
        return 2
    missing = skip_reason()
    if missing:
        print(f"error: {missing}", file=sys.stderr)
        return 2

    async def main() -> int:
        from ..sitl.ardupilot import run_ardupilot_sitl

        rig = args.rig or ("config" if len(config.cameras) > 1 else None)
        report = await run_ardupilot_sitl(config, scene, pilot_mode=args.pilot_mode, rig=rig)
        print("\n".join(report.lines()))
        return 0 if report.ok else 1

    return run_loop(main)


def run_sitl_until(
    config: AppConfig,
    duration_s: float | None,
    printer: contextlib.AbstractContextManager[StatusPrinter | None],
    signals: RunSignals,
    *,
    service: bool = False,
    summary_json: Callable[[DaemonSummary], None] | None = None,
    rig: str = "panorama",
    **kwargs: Any,
) -> int:
    """SITL on uvloop until ``duration_s`` or SIGINT/SIGTERM; prints the report.
    ``service``: ``run`` (SIGTERM is its normal stop, exit 0); ``summary_json`` writes
    the daemon's summary (``run --summary-json``); ``rig``: the simulated cameras
    (:func:`~tcm_companion.sitl.mock_flight.run_sitl`)."""

    async def main(on_status: StatusPrinter | None, stop: asyncio.Event) -> SitlReport:
        from ..sitl.mock_flight import run_sitl

        return await run_sitl(
            config,
            camera_model=config.camera.model if rig == "panorama" else None,
            rig=rig,
            duration_s=duration_s,
            stop=stop,
            on_status=on_status,
            **kwargs,
        )

    with printer as on_status:
        report = run_until_signal(signals, lambda stop: main(on_status, stop))
    if summary_json is not None:
        summary_json(report.summary)
    return _finish(report, signals, service=service)


def add_parsers(sub: Any) -> None:
    """Register ``sitl`` on the main parser's subparsers."""
    p = add_command(
        sub,
        "sitl",
        "The daemon with a simulated camera against the mock autopilot (loopback UDP, or one"
        " simulated clock with --clock virtual) or against real ArduCopter SITL (--autopilot"
        " ardupilot), for a fixed time; then the summary. Exit 1 if the run failed.",
    )
    add_config_arguments(p)
    add_log_level_argument(p)
    p.add_argument(
        "--autopilot",
        choices=("mock", "ardupilot"),
        default="mock",
        help="mock: the built-in mock autopilot flies a scenario (default); ardupilot:"
        " ArduPilot's own SITL binary ($TCM_ARDUPILOT_SITL, or ../shared/ardupilot-sitl)"
        " with the Lua applet, flown in GUIDED at a ball on a collision course",
    )
    p.add_argument(
        "--scenario",
        type=str.upper,
        default=None,
        metavar="NAME",
        help=f"mock: {', '.join(SCENARIO_NAMES)} (default T90); ardupilot: CROSSING"
        " (default) or HEADON",
    )
    p.add_argument(
        "--pilot-mode",
        default=None,
        metavar="MODE",
        help="ardupilot: the pilot switches to this mode (e.g. LOITER) 1 s after the applet"
        " braked; the applet must stand down",
    )
    p.add_argument(
        "--duration",
        type=run_seconds,
        default=20.0,
        metavar="S",
        help="seconds, > 0, at most a week (default 20); SIGINT ends the run early (exit 130)",
    )
    p.add_argument(
        "--clock",
        choices=("real", "virtual"),
        default="real",
        help="mock: real (default) runs the daemon in real time over loopback UDP with a"
        " live status line; virtual runs the companion, the mock and the camera on one"
        " simulated clock as fast as the CPU allows, the same results and flight log"
        " every run",
    )
    p.add_argument(
        "--min-accuracy",
        type=percent,
        default=None,
        metavar="PCT",
        help="mock: fail (exit 1) when the accuracy of the decided object-frames after the"
        " warm-up is below this, or nothing was decided (default 90; 0: not judged)",
    )
    p.add_argument(
        "--rig",
        choices=RIGS,
        default=None,
        help="the simulated cameras: panorama (one 360° camera), quad (front, right, rear,"
        " left: four 100° pinholes) or front-back; the daemon runs one camera per rig"
        " camera, each rendered from the vehicle's pose (default: the configuration's"
        " [[cameras]] when it has two or more, else [camera])",
    )
    p.add_argument("--log", metavar="DIR", default=None, help="write the flight log (MCAP) here")
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    add_status_every(p)
    p.set_defaults(func=cmd_sitl)
