"""``tcm-companion sim export``, ``sim list`` and ``mock-autopilot``: the simulator.

The mock autopilot's options are defined here (from the light
:mod:`tcm_companion.sim.scene.names`), so that building the parser does not import the
mock; :func:`~tcm_companion.sim.vehicle.mock_autopilot_run.run_from_args` runs it.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..sim.scene.names import RIGS, SCENARIO_NAMES
from .common import (
    CAMERA_PRESETS,
    FORCE_HELP,
    SEED_RANGE,
    add_command,
    add_quiet_argument,
    flight_seconds,
    float_in,
    resolution,
    whole_number,
)


def _camera_arg(args: argparse.Namespace) -> Any:
    if args.camera is None:
        return None
    from ..sim.scene.cameras import preset_camera

    return preset_camera(args.camera, args.resolution, args.name)


#: ``sim export --rig`` / ``eval --rig``: the simulator's camera rigs (``sitl --rig``'s too).
RIG_CHOICES = RIGS


def _cmd_sim_export_rig(args: argparse.Namespace) -> int:
    """``sim export NAME DIR --rig R``: every camera of the rig, one flight."""
    from ..io.outputs import SCENARIO_DIR, atomic_path
    from ..sim.scene.rig_scenario import export_rig, make_rig
    from ..sim.scene.scenarios import FlightTooLong

    if args.camera is not None:
        print("tcm-companion sim export: error: give --camera or --rig, not both", file=sys.stderr)
        return 2
    try:
        rig = make_rig(
            args.name,
            args.rig,
            duration_s=args.duration,
            seed=args.seed,
            resolution=args.resolution,
        )
    except FlightTooLong as exc:
        print(f"tcm-companion sim export: error: argument --duration: {exc}", file=sys.stderr)
        return 2
    with atomic_path(args.dir, kind=SCENARIO_DIR, force=args.force) as tmp:
        export_rig(
            rig, tmp, progress=False if args.quiet else None, detections=args.detections or None
        )
    cams = ", ".join(
        f"{n} ({c.camera.model_name} {c.camera.width}x{c.camera.height})"
        for n, c in zip(rig.camera_names, rig.cameras)
    )
    print(
        f"wrote {rig.name}: rig {args.rig}, {len(rig.cameras)} camera(s) [{cams}],"
        f" {rig.cameras[0].n_frames} frames each -> {args.dir}"
    )
    return 0


def cmd_sim_export(args: argparse.Namespace) -> int:
    from ..io.outputs import SCENARIO_DIR, atomic_path, check_output
    from ..sim import make_scenario
    from ..sim.scene.export import export_scenario
    from ..sim.scene.scenarios import FlightTooLong

    check_output(args.dir, SCENARIO_DIR, force=args.force)  # before rendering, not after
    if getattr(args, "rig", None) is not None:
        return _cmd_sim_export_rig(args)
    camera = _camera_arg(args)
    try:
        sim = make_scenario(args.name, camera=camera, duration_s=args.duration, seed=args.seed)
    except FlightTooLong as exc:  # a collision or head-on course ends before contact
        print(f"tcm-companion sim export: error: argument --duration: {exc}", file=sys.stderr)
        return 2
    if camera is None and args.resolution is not None:
        sim = make_scenario(
            args.name,
            camera=sim.camera.scaled(*args.resolution),
            duration_s=args.duration,
            seed=args.seed,
        )
    with atomic_path(args.dir, kind=SCENARIO_DIR, force=args.force) as tmp:
        export_scenario(
            sim, tmp, progress=False if args.quiet else None, detections=args.detections or None
        )
    print(
        f"wrote {sim.name}: {sim.n_frames} frames, {sim.camera.model_name} "
        f"{sim.camera.width}x{sim.camera.height} -> {args.dir}"
    )
    return 0


def cmd_sim_list(_args: argparse.Namespace) -> int:
    from ..sim.scene.scenarios import describe_scenario

    for name in SCENARIO_NAMES:
        print(f"{name:<15} {describe_scenario(name)}")
    return 0


def cmd_mock_autopilot(args: argparse.Namespace) -> int:
    from ..sim.vehicle.mock_autopilot_run import run_from_args

    return run_from_args(args)


def add_mock_autopilot_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``tcm-companion mock-autopilot`` (read by
    :func:`tcm_companion.sim.vehicle.mock_autopilot_run.config_from_args`)."""
    parser.add_argument(
        "--connect",
        required=True,
        metavar="URL",
        help="transport URL, e.g. udpout:127.0.0.1:14550, udpin:0.0.0.0:14550, "
        "serial:/dev/pts/3:921600, tcp:HOST:PORT",
    )
    parser.add_argument(
        "--scenario",
        default="T90",
        type=str.upper,
        choices=SCENARIO_NAMES,
        metavar="NAME",
        help=f"flight to fly: {', '.join(SCENARIO_NAMES)} (default T90)",
    )
    parser.add_argument(
        "--seed",
        type=whole_number(*SEED_RANGE),
        default=0,
        metavar="N",
        help="seed of the turbulence and telemetry noise, 0 to 4294967295",
    )
    parser.add_argument(
        "--noise",
        type=float_in(lambda v: 0.0 <= v <= 100.0, "a number in [0, 100]"),
        default=1.0,
        metavar="X",
        help="telemetry noise scale, 0 to 100 (default 1; 0: exact)",
    )
    parser.add_argument(
        "--sysid",
        type=whole_number(1, 255),
        default=1,
        metavar="N",
        help="MAVLink system id (default 1)",
    )
    parser.add_argument(
        "--ekf-origin-delay",
        type=float_in(lambda v: 0.0 <= v <= 600.0, "a number of seconds in [0, 600]"),
        default=3.0,
        metavar="S",
        help="seconds after boot before LOCAL_POSITION_NED exists (ArduPilot SITL: ~40)",
    )
    parser.add_argument(
        "--brake-ttc",
        type=float_in(lambda v: 0.0 < v <= 3600.0, "a number of seconds in (0, 3600]"),
        default=3.0,
        metavar="S",
        help="brake on a collision-course status with time to contact below this",
    )
    parser.add_argument(
        "--no-brake", action="store_true", help="record collision alarms but do not brake"
    )


def add_parsers(sub: Any) -> None:
    p = add_command(
        sub,
        "sim",
        "The built-in simulator: render a scenario as a tcm-scenario/1 directory, or list"
        " the scenarios.",
    )
    ssub = p.add_subparsers(
        dest="sim_command", required=True, metavar="COMMAND", help="export or list"
    )
    e = add_command(
        ssub,
        "export",
        help="write a simulated scenario as a tcm-scenario/1 directory",
        description="Render a simulated scenario and write it as a tcm-scenario/1 directory (frames,"
        " telemetry.tlog, truth.csv; with --detections also the simulated detector's boxes).",
    )
    e.add_argument(
        "name",
        type=str.upper,
        choices=SCENARIO_NAMES,
        metavar="NAME",
        help="scenario name (see: tcm-companion sim list)",
    )
    e.add_argument("dir", help="output directory")
    e.add_argument("--force", action="store_true", help=FORCE_HELP)
    add_quiet_argument(e)
    e.add_argument(
        "--detections",
        action="store_true",
        help="also write detections.csv: boxes from the simulated detector (jitter, misses,"
        " false boxes; tcm_companion/sim/scene/detector_sim.py)",
    )
    e.add_argument(
        "--camera",
        choices=CAMERA_PRESETS,
        default=None,
        help="camera preset (default: the paper's panorama, 360x220)",
    )
    e.add_argument(
        "--rig",
        choices=RIG_CHOICES,
        default=None,
        help="write a camera rig instead: every camera of it sees the same flight"
        " (quad: four 100° pinholes named front/right/rear/left; front-back: two), in the"
        " rig form of docs/scenario-format.md; --resolution rescales each camera",
    )
    e.add_argument(
        "--resolution",
        type=resolution,
        default=None,
        metavar="WxH",
        help="image size (the same field of view; 16 to 16384 pixels a side, at most"
        " 4096x4096 pixels; default: the camera's own)",
    )
    e.add_argument(
        "--duration",
        type=flight_seconds,
        default=None,
        metavar="S",
        help="seconds of flight, at most 3600 (default: the scenario's)",
    )
    e.add_argument(
        "--seed",
        type=whole_number(*SEED_RANGE),
        default=0,
        metavar="N",
        help="seed of the flight (turbulence, noise), 0 to 4294967295",
    )
    e.set_defaults(func=cmd_sim_export)
    ls = add_command(
        ssub,
        "list",
        help="list the simulated scenarios, one line each",
        description="List the simulated scenarios, one line each: name and what it shows.",
    )
    ls.set_defaults(func=cmd_sim_list)

    p = add_command(
        sub,
        "mock-autopilot",
        "An ArduPilot-like MAVLink vehicle that flies a simulated scenario, honours"
        " SET_MESSAGE_INTERVAL, answers TIMESYNC, parameters and commands, checks the"
        " companion's messages and brakes on a collision-course alarm; until SIGINT/SIGTERM"
        " or the link closes.",
    )
    add_mock_autopilot_arguments(p)
    p.set_defaults(func=cmd_mock_autopilot)
