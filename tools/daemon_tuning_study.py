"""Which daemon settings keep capture-to-MAVLink latency and CPU low (evidence for
config.toml's [daemon] opencv_threads, gil_switch_interval_us and attitude_lead_max_us),
and what the flight log costs ([logging]: on with JPEG by default, off, PNG).

Each variant runs ``tcm-companion run`` as its own process for DURATION seconds at 25 Hz
(frames from disk, the mock autopilot in another process over UDP; see
tcm_companion/bench/daemon.py) and reports latency percentiles, the pipeline's
share, CPU and RSS. Run:

    .venv/bin/python tools/daemon_tuning_study.py [DURATION]
"""

from __future__ import annotations

import argparse
import tempfile

from tcm_companion.bench.daemon import run_daemon_bench

VARIANTS: list[tuple[str, tuple[str, ...]]] = [
    ("defaults (1 OpenCV thread, 1 ms GIL switch, 25 ms attitude lead)", ()),
    ("OpenCV's default threads", ("daemon.opencv_threads=0",)),
    ("Python's default GIL switch (5 ms)", ("daemon.gil_switch_interval_us=5000",)),
    ("always wait for the attitude after the frame", ("daemon.attitude_lead_max_us=1",)),
    ("flight log off", ("logging.enabled=false",)),
    ("flight log with lossless PNG frames", ('logging.image_format="png"',)),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("duration", nargs="?", type=float, default=30.0, help="s per variant (30)")
    duration = ap.parse_args().duration
    work = tempfile.mkdtemp(prefix="tcm-tuning-")
    print(f"{duration:.0f} s per variant, 25 Hz, 360x220; latency in ms (capture -> MAVLink)")
    print(
        f"{'variant':<62} {'p50':>6} {'p90':>6} {'p99':>6} {'pipe p50':>8} {'CPU %':>6} {'RSS MiB':>8} {'waited':>6} {'log GB/h':>8}"
    )
    for name, sets in VARIANTS:
        r = run_daemon_bench(duration, out=lambda _s: None, workdir=work, extra_sets=sets)
        pipe = r["stages_ms"]["pipeline"]["p50"]
        print(
            f"{name:<62} {r['latency_p50_ms']:6.2f} {r['latency_p90_ms']:6.2f} "
            f"{r['latency_p99_ms']:6.2f} {pipe:8.2f} {r['cpu_pct_of_one_core']:6.1f} "
            f"{r['rss_mib_max']:8.1f} {r['frames_waited_for_attitude']:6d}"
            f" {r['log_gb_per_hour']:8.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
