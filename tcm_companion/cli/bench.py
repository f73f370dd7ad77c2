"""``tcm-companion bench``: per-stage time per frame, the MAVLink link, the running daemon."""

from __future__ import annotations

import argparse
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
        from ..bench.daemon import CpuQuotaError, print_daemon_bench, run_daemon_bench

        # The --set the daemon will get, checked here: a bad one is this command's
        # "config error", not a RuntimeError traceback carrying the daemon's.
        config_from_args(args)
        try:
            result = run_daemon_bench(
                args.duration, extra_sets=tuple(args.set), cpu_quota=args.cpu_quota
            )
        except CpuQuotaError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except RuntimeError as exc:  # the daemon failed: its first and last words
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
            print(f"error: bench --daemon: {lines[0].rstrip(':')}: {lines[-1]}", file=sys.stderr)
            return 1
        print_daemon_bench(result)
        return 0
    if args.cpu_quota is not None:
        print("error: --cpu-quota goes with --daemon", file=sys.stderr)
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
    p.set_defaults(func=cmd_bench)
