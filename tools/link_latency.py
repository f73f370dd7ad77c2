"""Link latency of a TCM_OBJECT_STATUS frame: pty at 921600 baud (via socat) and UDP.

A frame is handed to the transport on one end; the clock stops when the far end's
codec has decoded it (see tcm_companion/bench/mavlink.py). Target (issue 3): p99 ≤ 2 ms
through the pty on loopback.

    .venv/bin/python tools/link_latency.py                 # pty, udp, memory; ~10 s
    .venv/bin/python tools/link_latency.py --kinds pty --n 5000

Measured 2026-11-22 (2-core x86_64 VM, Python 3.11, n = 2000, 1 ms idle between
frames; seven runs, the range over runs):

    link   median (ms)   p99 (ms)     max (ms)
    pty    0.12–0.27     0.33–1.47    2.6–10     51-byte frame; a real UART at 921600
    udp    0.07–0.14     0.21–0.31    0.4–3.0    baud adds 0.553 ms of wire time
    memory 0.04          0.12         2.6

At 25 Hz pacing (``--n 1000 --interval-ms 40``, deeper idle between frames): pty median
0.47, p99 0.85 ms; udp 0.31 / 0.47 ms. Back to back (``--interval-ms 0``): pty p99 0.17 ms.
So the pty meets p99 ≤ 2 ms in every run; with the UART's wire time added the worst
run's p99 was 2.03 ms (the tail is this VM scheduling socat, a separate process).
"""

from __future__ import annotations

import argparse
import platform

from tcm_companion.bench.mavlink import KINDS, measure_link_latency


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--n", type=int, default=2000, help="messages per link (default 2000)")
    parser.add_argument(
        "--interval-ms", type=float, default=1.0, help="idle time between messages (default 1)"
    )
    args = parser.parse_args()
    print(f"# {platform.node()} {platform.machine()} Python {platform.python_version()}")
    print(f"{'link':<8}{'n':>6}{'median':>9}{'p90':>8}{'p99':>8}{'max':>8}   (ms)")
    failed = False
    for kind in args.kinds:
        r = measure_link_latency(kind, args.n, interval_s=args.interval_ms / 1e3)
        line = (
            f"{kind:<8}{r['n']:>6}{r['median_ms']:>9.3f}{r['p90_ms']:>8.3f}"
            f"{r['p99_ms']:>8.3f}{r['max_ms']:>8.3f}"
        )
        if kind == "pty":
            line += (
                f"   {r['frame_bytes']}-byte frame; on a real UART at {r['baud']} baud add "
                f"{r['uart_wire_ms']:.3f} ms wire time -> p99 {r['p99_with_wire_ms']:.3f}"
            )
            failed |= r["p99_ms"] > 2.0
        print(line)
        failed |= r["decode_faults"] > 0
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
