"""``tcm-companion run``, ``sitl`` and ``config check``: the service, its simulated runs
and its configuration.

``run`` is the service systemd starts: it loads the configuration (CLI ``--set`` >
environment > file > defaults), builds the camera source, and runs the daemon on uvloop
until SIGTERM/SIGINT, notifying systemd (READY, STATUS, WATCHDOG, STOPPING). With
``[camera] source = "sim"`` there is no vehicle to look at, so ``run`` flies the mock
autopilot in the same process (SITL) and goes on until stopped.

asyncio and everything beyond the standard library are imported by the commands, not
here (see :mod:`.common`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import os
import signal
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..sim.scene.names import SCENARIO_NAMES
from .common import (
    add_command,
    add_config_arguments,
    add_log_level_argument,
    add_set_argument,
    config_from_args,
    setup_logging,
)

if TYPE_CHECKING:
    import asyncio

    from ..config import AppConfig

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


def _run_loop(main: Callable[[], Coroutine[Any, Any, int]]) -> int:
    """Run ``main`` on uvloop (the asyncio loop written in libuv), asyncio if missing."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - uvloop is a dependency; a bare install still runs
        import asyncio

        return asyncio.run(main())
    return uvloop.run(main())


def _install_signals(stop: asyncio.Event) -> None:
    import asyncio

    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)


class _StatusPrinter:
    """The live one-line status: rewritten in place on a terminal, a line every 5 s else."""

    def __init__(self, stream: Any = sys.stderr, every: int = 5) -> None:
        self.stream = stream
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self.every = every
        self.n = 0

    def __call__(self, line: str) -> None:
        self.n += 1
        if self.tty:
            self.stream.write("\r\x1b[2K" + line[:200])
            self.stream.flush()
        elif self.n % self.every == 1 or self.every == 1:
            print(line, file=self.stream, flush=True)

    def done(self) -> None:
        if self.tty and self.n:
            self.stream.write("\n")
            self.stream.flush()


# -- run ------------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    setup_logging(args.log_level)
    config = config_from_args(args)
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
    printer = _StatusPrinter(every=args.status_every) if not args.no_status else None

    if config.camera.source.source == "sim":
        log.info("camera source is the simulator: flying the mock autopilot (SITL)")
        from ..logsetup import log_directory

        log_dir = str(log_directory(config, state)) if config.logging.enabled else None
        # The service's exit status is about the service, not the simulation's accuracy.
        return _run_sitl_until(
            config,
            args.duration,
            printer,
            notifier=notifier,
            state_dir=str(state),
            log_dir=log_dir,
            min_accuracy=None,
        )

    async def main_flight() -> int:
        import asyncio

        from ..io.cameras.base import CameraError
        from ..io.cameras.settings import open_source
        from ..service.daemon import CameraInput, Daemon
        from ..sim.sources import register_sim_sources

        register_sim_sources()  # source = "sim_autopilot" is the simulator's
        cam = config.camera
        try:
            source = open_source(cam.source, cam.model)
        except CameraError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        stop = asyncio.Event()
        _install_signals(stop)
        if args.duration is not None:
            asyncio.get_running_loop().call_later(args.duration, stop.set)
        from ..io.aio import monotonic_us
        from ..io.persist import SigningKeyError
        from ..service.endpoint_setup import make_endpoint, persist

        cameras = [CameraInput(cam.name, cam.model, source)]
        try:
            endpoint, warnings = make_endpoint(config.mavlink, monotonic_us())
        except SigningKeyError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        for w in warnings:
            log.warning("%s", w)
        flight_log = None
        if config.logging.enabled:
            from ..logsetup import log_directory, start_flight_log

            log_dir = log_directory(config, state)
            # The parameters in force at start (persisted ones included): replay needs them.
            flight_log = start_flight_log(config, log_dir, cameras, dict(endpoint.params.values))
            log.info("flight log in %s", log_dir)
        daemon = Daemon(
            config,
            cameras,
            endpoint=endpoint,
            persist_params=True,
            notifier=notifier,
            watchdog_interval_us=wd_us,
            on_status=printer,
            flight_log=flight_log,
        )
        try:
            summary = await daemon.run(stop)
        finally:
            if flight_log is not None:
                await asyncio.to_thread(flight_log.stop)  # drains the queue; off the loop
            with contextlib.suppress(OSError):
                persist(config.mavlink, endpoint)
        if printer is not None:
            printer.done()
        if args.summary_json:
            write_summary_json(args.summary_json, summary)
        lat = summary.latency_percentile_ms(99)
        print(
            f"stopped after {summary.duration_s:.1f} s: captured {summary.captured}, processed "
            f"{summary.processed}, dropped {summary.dropped}, failed {summary.failed}, rejected "
            f"{summary.rejected}; latency p99 {lat:.2f} ms; faults {summary.faults or 'none'}"
        )
        return 0

    return _run_loop(main_flight)


def write_summary_json(path: str, summary: Any) -> None:
    """Latency percentiles, frame accounting and faults of a run, for tools and benches."""
    import json

    import numpy as np

    doc = {
        "duration_s": summary.duration_s,
        "captured": summary.captured,
        "processed": summary.processed,
        "dropped": summary.dropped,
        "failed": summary.failed,
        "rejected": summary.rejected,
        "frames_balance": summary.frames_balance,
        "latency_p50_ms": summary.latency_percentile_ms(50),
        "latency_p90_ms": summary.latency_percentile_ms(90),
        "latency_p99_ms": summary.latency_percentile_ms(99),
        "latency_max_ms": summary.latency_percentile_ms(100),
        "faults": summary.faults,
        "watchdog_pings": summary.watchdog_pings,
        "watchdog_withheld": summary.watchdog_withheld,
        "frames_waited_for_attitude": summary.stats.frames_waited,
        "stages_ms": {
            k: {
                "p50": float(np.percentile(v, 50)) if v else None,
                "p99": float(np.percentile(v, 99)) if v else None,
            }
            for k, v in summary.stage_ms.items()
        },
    }
    Path(path).write_text(json.dumps(doc, indent=2))


# -- sitl -----------------------------------------------------------------------------------
def cmd_sitl(args: argparse.Namespace) -> int:
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
    from ..sitl.mock import DEFAULT_MIN_ACCURACY

    pct = 100.0 * DEFAULT_MIN_ACCURACY if args.min_accuracy is None else args.min_accuracy
    min_accuracy = None if pct <= 0 else pct / 100.0
    printer = _StatusPrinter(every=args.status_every)
    if args.clock == "virtual":
        return _run_sitl_virtual(config, args.duration, printer, args.log, min_accuracy)
    return _run_sitl_until(
        config, args.duration, printer, log_dir=args.log, min_accuracy=min_accuracy
    )


def _run_sitl_virtual(
    config: AppConfig,
    duration_s: float,
    printer: _StatusPrinter,
    log_dir: str | None,
    min_accuracy: float | None,
) -> int:
    """``sitl --clock virtual``: no event loop; SIGINT/SIGTERM end the simulation early."""
    import threading

    from ..sitl.mock import run_sitl_virtual

    stop = threading.Event()
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # not the main thread
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        report = run_sitl_virtual(
            config,
            camera_model=config.camera.model,
            duration_s=duration_s,
            should_stop=stop.is_set,
            on_status=printer,
            log_dir=log_dir,
            min_accuracy=min_accuracy,
        )
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    printer.done()
    print("\n".join(report.lines()))
    return 0 if report.ok else 1


def _run_ardupilot(args: argparse.Namespace, config: AppConfig) -> int:
    """``sitl --autopilot ardupilot``: real ArduCopter SITL with the applet, one flight."""
    from ..sim.vehicle.ardupilot_sitl import skip_reason
    from ..sitl.ardupilot import SCENES

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

        report = await run_ardupilot_sitl(config, scene, pilot_mode=args.pilot_mode)
        print("\n".join(report.lines()))
        return 0 if report.ok else 1

    return _run_loop(main)


def _run_sitl_until(
    config: AppConfig,
    duration_s: float | None,
    printer: _StatusPrinter | None,
    **kwargs: Any,
) -> int:
    """SITL on uvloop until ``duration_s`` or SIGINT/SIGTERM; prints the report."""

    async def main() -> int:
        import asyncio

        from ..sitl.mock import run_sitl

        stop = asyncio.Event()
        _install_signals(stop)
        report = await run_sitl(
            config,
            camera_model=config.camera.model,
            duration_s=duration_s,
            stop=stop,
            on_status=printer,
            **kwargs,
        )
        if printer is not None:
            printer.done()
        print("\n".join(report.lines()))
        return 0 if report.ok else 1

    return _run_loop(main)


# -- config check ---------------------------------------------------------------------------
def cmd_config_check(args: argparse.Namespace) -> int:
    from ..config import config_to_toml

    config = config_from_args(args)  # a ConfigError is reported by main: exit 2
    print(f"# {args.config}: OK. Effective configuration (CLI > environment > file > defaults):")
    print(config_to_toml(config))
    return 0


def add_parsers(sub: Any) -> None:
    """Register ``run``, ``sitl`` and ``config`` on the main parser's subparsers."""
    p = add_command(
        sub,
        "run",
        "The flight daemon: cameras in, one status per object and frame out on MAVLink, until"
        ' SIGTERM. With [camera] source = "sim" it flies the mock autopilot in the same'
        " process.",
    )
    add_config_arguments(p)
    add_log_level_argument(p)
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    p.add_argument(
        "--status-every",
        type=int,
        default=5,
        metavar="N",
        help="status line every N s when not a terminal (default 5)",
    )
    p.add_argument(
        "--summary-json", metavar="FILE", default=None, help="write the run's summary as JSON"
    )
    p.set_defaults(func=cmd_run)

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
    p.add_argument("--duration", type=float, default=20.0, metavar="S", help="seconds (default 20)")
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
        type=float,
        default=None,
        metavar="PCT",
        help="mock: fail (exit 1) when the accuracy of the decided object-frames after the"
        " warm-up is below this, or nothing was decided (default 90; 0: not judged)",
    )
    p.add_argument("--log", metavar="DIR", default=None, help="write the flight log (MCAP) here")
    p.add_argument(
        "--status-every",
        type=int,
        default=5,
        metavar="N",
        help="status line every N s when not a terminal (default 5)",
    )
    p.set_defaults(func=cmd_sitl)

    p = add_command(sub, "config", "Configuration tools: config check FILE.")
    csub = p.add_subparsers(dest="config_command", required=True, metavar="COMMAND", help="check")
    c = add_command(
        csub,
        "check",
        help="validate a config file and print the effective settings",
        description="Validate a config file with the environment (TCM_COMPANION__TABLE__KEY) and --set"
        " applied, and print the effective configuration as TOML. Errors name the file, table"
        " and key, and the variable or flag that set a bad value (exit 2).",
    )
    c.add_argument("config", metavar="FILE", help="the config.toml to check")
    add_set_argument(c)
    c.set_defaults(func=cmd_config_check)
