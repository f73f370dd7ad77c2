"""``tcm-companion bench``: per-stage time per frame, the MAVLink link, the running daemon."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from .common import (
    add_command,
    add_config_arguments,
    add_quiet_argument,
    bench_seconds,
    config_from_args,
    float_in,
    resolution,
    whole_number,
)


def cpu_list(text: str) -> tuple[int, ...]:
    """``--cpus``: CPU numbers separated by commas (``0`` or ``0,1``)."""
    try:
        cpus = tuple(sorted({int(x) for x in text.split(",") if x.strip()}))
    except ValueError:
        raise argparse.ArgumentTypeError(f"CPU numbers separated by commas, got {text!r}") from None
    if not cpus or min(cpus) < 0:
        raise argparse.ArgumentTypeError(f"CPU numbers separated by commas, got {text!r}")
    return cpus


#: ``--cpu-quota``: a fraction of one core.
fraction_of_a_core = float_in(lambda v: 0.0 < v <= 1.0, "a fraction of one core in (0, 1]")


def cmd_bench(args: argparse.Namespace) -> int:
    if args.mavlink:
        from ..bench.mavlink import run_mavlink_bench

        print(run_mavlink_bench())
        return 0
    if args.daemon:
        if args.config is not None:
            print(
                "error: bench --daemon runs the daemon with ./config.toml (if present), the"
                " environment and the bench's own settings; give yours with --set, not --config",
                file=sys.stderr,
            )
            return 2
        from ..bench.daemon import (
            CpuQuotaError,
            RigBench,
            print_daemon_bench,
            print_rig_scaling,
            run_daemon_bench,
        )

        # The --set the daemon will get, checked here: a bad one is this command's
        # "config error", not a RuntimeError traceback carrying the daemon's.
        base = config_from_args(args)
        rigs: list[RigBench | None] = [None]
        if args.cameras is not None or args.cpus:
            allowed = os.sched_getaffinity(0)
            for cpus in args.cpus or []:
                if not set(cpus) <= allowed:
                    print(
                        f"error: --cpus {','.join(map(str, cpus))}: this process may run on"
                        f" CPUs {','.join(map(str, sorted(allowed)))} only",
                        file=sys.stderr,
                    )
                    return 2
            n = args.cameras if args.cameras is not None else 1
            rigs = [RigBench(n, base, cpus) for cpus in (args.cpus or [None])]
        results = []
        for rig in rigs:
            try:
                result = run_daemon_bench(
                    args.duration, extra_sets=tuple(args.set), cpu_quota=args.cpu_quota, rig=rig
                )
            except CpuQuotaError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 2
            except RuntimeError as exc:  # the daemon failed: its first and last words
                lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
                print(
                    f"error: bench --daemon: {lines[0].rstrip(':')}: {lines[-1]}", file=sys.stderr
                )
                return 1
            print_daemon_bench(result)
            results.append(result)
        if len(results) > 1:
            print_rig_scaling(results)
        return 0
    for given, name in ((args.cpu_quota, "--cpu-quota"), (args.cameras, "--cameras"),
                        (args.cpus, "--cpus")):  # fmt: skip
        if given is not None:
            print(f"error: {name} goes with --daemon", file=sys.stderr)
            return 2
    from ..bench.pipeline import run_bench

    config = config_from_args(args)
    print(run_bench(config, args.resolutions or [(360, 220), (900, 550)], args.frames))
    return 0


def add_parsers(sub: Any) -> None:
    p = add_command(
        sub,
        "bench",
        "Time every stage per frame on one core at 360x220 and 900x550 for each method"
        " (median and p99, BSM/TCM ratio); or, with --mavlink, the MAVLink encode cost and"
        " link latency; or, with --daemon, the running service's latency, CPU and memory.",
    )
    add_config_arguments(p, what="; not with --daemon (give --set, passed to the daemon)")
    add_quiet_argument(p)
    p.add_argument(
        "--resolutions",
        type=resolution,
        nargs="+",
        metavar="WxH",
        help="image sizes to time, 16 to 16384 pixels a side and at most 4096x4096 pixels"
        " (default 360x220 900x550)",
    )
    p.add_argument(
        "--frames",
        type=whole_number(1, 100000),
        default=200,
        metavar="N",
        help="frames timed per resolution and method, 1 to 100000 (default 200)",
    )
    p.add_argument(
        "--mavlink",
        action="store_true",
        help="instead: MAVLink encode cost and link latency (pty via socat, UDP)",
    )
    p.add_argument(
        "--daemon",
        action="store_true",
        help="instead: the running service's latency, CPU and memory (own process, 25 Hz)",
    )
    p.add_argument(
        "--duration",
        type=bench_seconds,
        default=60.0,
        metavar="S",
        help="--daemon: seconds to run, at most 3600 (default 60)",
    )
    p.add_argument(
        "--cpu-quota",
        type=fraction_of_a_core,
        metavar="F",
        help="--daemon: limit the daemon to this fraction of one core (0 < F <= 1; e.g."
        " 0.25, a slow companion computer) with a cgroup CPU quota (needs root)",
    )
    p.add_argument(
        "--cameras",
        type=whole_number(1, 16),
        metavar="N",
        help="--daemon: a rig of N cameras (1 to 16), each reading the rendered frames at 25"
        " Hz; per camera fps and latency, CPU per process, the issue's targets",
    )
    p.add_argument(
        "--cpus",
        type=cpu_list,
        action="append",
        metavar="LIST",
        help="--daemon: pin the daemon and its workers to these CPUs (e.g. 0 or 0,1; the"
        " mock autopilot is not pinned); given several times, one run each and the frames"
        " per second compared",
    )
    p.set_defaults(func=cmd_bench)
