"""``tcm-companion export``, ``import`` and ``plot``: flight logs and scenarios, both ways."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import (
    FLIGHT_HELP,
    FORCE_HELP,
    TOOLS_HINT,
    TolerantFrames,
    add_command,
    add_config_arguments,
    config_file,
    config_from_args,
    is_log,
    require_inputs,
    whole_number,
)


def cmd_export(args: argparse.Namespace) -> int:
    from ..io.outputs import SCENARIO_DIR, atomic_path
    from ..logtools.convert import check_log_path, log_to_scenario

    check_log_path(Path(args.log), args.flight)  # a missing log is named as such, not as an output
    with atomic_path(args.scenario, kind=SCENARIO_DIR, force=args.force, inputs=[args.log]) as tmp:
        summary = log_to_scenario(args.log, tmp, camera_id=args.camera_id, flight=args.flight)
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    rig = f" of a rig ({', '.join(summary.cameras)})" if summary.cameras else ""
    print(f"{args.log} -> {args.scenario}: {summary.frames} frames{rig}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from ..io.outputs import FLIGHT_LOG, atomic_path
    from ..logtools.convert import scenario_to_log

    config = config_from_args(args) if args.results else None
    inputs = [args.scenario, config_file(args) if args.results else None]
    with atomic_path(args.log, kind=FLIGHT_LOG, force=args.force, inputs=inputs) as tmp:
        scenario_to_log(
            args.scenario,
            tmp,
            image_format=args.image_format,
            results=args.results,
            config=config,
        )
    print(f"{args.scenario} -> {args.log}")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    try:
        from ..logtools.plot import PLOT_NAMES, plot_log, plot_scenario
    except ImportError as exc:
        if getattr(exc, "name", "") and str(exc.name).startswith("matplotlib"):
            print(f"error: plot: {TOOLS_HINT}", file=sys.stderr)
            return 2
        raise

    from ..io.outputs import PNG_FILE, check_folder

    log = is_log(args.source)
    check_folder(
        args.out,
        inputs=[args.source, None if log else config_file(args)],
        files=[(f"{name}.png", PNG_FILE) for name in PLOT_NAMES],
    )
    if log:
        paths = plot_log(args.source, args.out, flight=args.flight)
    else:
        from ..io.scenario import load_scenario

        config = config_from_args(args)
        # as replay does: the reader's warnings (a .tlog cut short, junk appended) first,
        # and an unreadable frame is a gap in the plots, reported, not the end of them
        scenario = TolerantFrames(load_scenario(args.source))
        require_inputs(scenario, config)
        for w in scenario.warnings:
            print(f"warning: {w}", file=sys.stderr)
        paths = plot_scenario(scenario, args.out, config)
        scenario.report_unreadable()
    for p in paths:
        print(p)
    for name, why in getattr(paths, "skipped", {}).items():
        print(f"skipped {name}: {why}", file=sys.stderr)
    if not paths:  # every plot skipped: a file that is not a flight log, or holds nothing
        print(f"error: {args.source}: nothing to plot (every plot skipped, above)", file=sys.stderr)
        return 2
    return 0


def add_parsers(sub: Any) -> None:
    p = add_command(
        sub,
        "export",
        "Convert a flight log to a tcm-scenario/1 directory: its frames and a .tlog of its"
        " MAVLink traffic (MAVProxy and MAVExplorer open it).",
    )
    p.add_argument("log", help="flight log file or directory")
    p.add_argument("--scenario", required=True, metavar="DIR", help="scenario directory to write")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    p.add_argument(
        "--camera-id",
        type=whole_number(0),
        default=None,
        metavar="N",
        help="export only this camera, as a one-camera scenario (default: every camera; a"
        " log of two cameras or more becomes a rig scenario, [[cameras]])",
    )
    p.add_argument("--flight", metavar="ID", default=None, help=FLIGHT_HELP)
    p.set_defaults(func=cmd_export)

    p = add_command(
        sub,
        "import",
        "Convert a tcm-scenario/1 directory to a flight log (MCAP); with --results also"
        " replay it and log each frame's results.",
    )
    add_config_arguments(p, what="; the --results replay")
    p.add_argument("scenario", help="scenario directory")
    p.add_argument("--log", required=True, metavar="FILE", help="MCAP file to write")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    p.add_argument(
        "--image-format",
        choices=("png", "jpeg"),
        default="png",
        help="how frames are stored: png (lossless, exact replay; default) or jpeg",
    )
    p.add_argument(
        "--results",
        action="store_true",
        help="also replay the scenario and log /tcm/result (for plots and the Foxglove layout)",
    )
    p.set_defaults(func=cmd_import)

    p = add_command(
        sub,
        "plot",
        "PNG plots of a flight log or a scenario (replayed): disparity against the threshold,"
        " bearings, time to contact, egomotion quality, latency, attitude and health, with"
        " the truth when a scenario has it.",
    )
    add_config_arguments(p, what="; a scenario's replay (a flight log is plotted as flown)")
    p.add_argument("source", help="flight log (file or directory) or scenario directory")
    p.add_argument(
        "--out", default="out/plots", metavar="DIR", help="folder for the PNGs (default out/plots)"
    )
    p.add_argument("--flight", metavar="ID", default=None, help="flight log: " + FLIGHT_HELP)
    p.set_defaults(func=cmd_plot)
