"""``tcm-companion bench --daemon``: the service's own cost, measured from outside.

The daemon runs as its own process, exactly as systemd starts it (``tcm-companion run``),
with a camera that costs it what a real one would — images read from disk at 25 Hz
(``[camera] source = "frames"``, PNGs of a simulated flight at 360×220, looped) — and
the mock autopilot in a second process on loopback UDP. Rendering and the autopilot are
therefore not on the daemon's bill. While it runs, ``/proc/<pid>`` is sampled once a
second for CPU time and resident memory; at the end the daemon's own summary (JSON)
gives capture-to-MAVLink latency percentiles and the frame accounting.

The telemetry is the mock's flight of the same scenario but not the same instant as the
frames, so the classifications are meaningless here; the work per frame is the same.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2

PAGE = os.sysconf("SC_PAGE_SIZE")
TICKS = os.sysconf("SC_CLK_TCK")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _proc_sample(pid: int) -> tuple[float, int] | None:
    """(CPU seconds user+system, RSS bytes) of ``pid``, or None if it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        statm = Path(f"/proc/{pid}/statm").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()
    cpu = (int(fields[11]) + int(fields[12])) / TICKS
    rss = int(statm.split()[1]) * PAGE
    return cpu, rss


def write_frames(directory: Path, scenario: str, seconds: float) -> int:
    """Render ``seconds`` of ``scenario`` at 360×220 to PNG files; returns the count."""
    from ..sim import make_scenario

    directory.mkdir(parents=True, exist_ok=True)
    sim = make_scenario(scenario, duration_s=seconds, seed=0)
    n = 0
    for i, _t, image in sim.iter_frames():
        cv2.imwrite(str(directory / f"{i:05d}.png"), image)
        n += 1
    return n


def measure_flight_log(frames_dir: Path, n: int = 100) -> dict[str, dict[str, float]]:
    """The flight-log writer's cost per frame, in this process, on ``n`` frames of
    ``frames_dir`` written as the daemon logs them (a frame, its annotations and a
    result per frame at 25 Hz), for each image format: the producer's ``log_frame`` call
    (median µs: what the loop pays), the writer thread's CPU (ms/frame) and the size
    (GB/h at 25 Hz)."""
    import numpy as np

    from ..flightlog.writer import FlightLogWriter, LoggingConfig

    images: list[np.ndarray] = []
    for path in sorted(frames_dir.glob("*.png"))[:n]:
        img = cv2.imread(str(path))
        if img is not None:
            images.append(img)
    out: dict[str, dict[str, float]] = {}
    if not images:
        return out
    for fmt in ("jpeg", "png"):
        with tempfile.TemporaryDirectory(prefix="tcm-bench-log-") as d:
            w = FlightLogWriter(LoggingConfig(image_format=fmt, queue_items=1024), d)
            w.start({})
            call_s = []
            for i, img in enumerate(images):
                t = 1_000_000 + 40_000 * i
                c0 = time.perf_counter()
                w.log_frame(0, t, img)
                call_s.append(time.perf_counter() - c0)
                w.log_annotations(0, t, [(100.0, 50.0, 6.0, "moving ttc 3.0 s")])
                w.log_json("/tcm/result", t, {"track": 1, "state": "moving", "ttc_s": 3.0})
            w.stop(timeout_s=30)
            st = w.stats
            seconds = len(images) / 25.0
            out[fmt] = {
                "frames": float(st.frames_logged),
                "log_frame_call_median_us": float(np.median(call_s)) * 1e6,
                "writer_cpu_ms_per_frame": st.writer_cpu_s / len(images) * 1e3,
                "gb_per_hour": st.bytes_written / seconds * 3600 / 1e9,
            }
    return out


def run_daemon_bench(
    duration_s: float = 60.0,
    scenario: str = "T90",
    frames_s: float = 20.0,
    out: Callable[[str], Any] = print,
    workdir: str | None = None,
    extra_sets: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Run the daemon for ``duration_s`` and measure it; ``extra_sets`` are more
    ``--set table.key=value`` overrides (for tuning studies)."""
    tmp = Path(workdir or tempfile.mkdtemp(prefix="tcm-bench-daemon-"))
    frames = tmp / "frames"
    if not any(frames.glob("*.png")):
        out(f"rendering {frames_s:.0f} s of {scenario} to {frames} ...")
        write_frames(frames, scenario, frames_s)
    port = _free_udp_port()
    py = sys.executable
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    mock = subprocess.Popen(
        [py, "-m", "tcm_companion", "mock-autopilot", "--connect", f"udpin:127.0.0.1:{port}",
         "--scenario", scenario],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
    )  # fmt: skip
    summary_file = tmp / "summary.json"
    sets = [
        'camera.source="frames"',
        f'camera.path="{frames}"',
        "camera.loop=true",
        f'mavlink.url="udpout:127.0.0.1:{port}"',
        f'daemon.state_dir="{tmp / "state"}"',
        *extra_sets,
    ]
    cmd = [py, "-m", "tcm_companion", "run", "--no-status", "--log-level", "WARNING",
           "--duration", str(duration_s), "--summary-json", str(summary_file)]  # fmt: skip
    for s in sets:
        cmd += ["--set", s]
    daemon = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    samples: list[tuple[float, float, int]] = []  # (wall s, cpu s, rss bytes)
    t0 = time.monotonic()
    try:
        next_report = t0 + 10.0
        while daemon.poll() is None:
            sample = _proc_sample(daemon.pid)
            if sample is not None and sample[1] > 0:  # an exited (zombie) process has no RSS
                samples.append((time.monotonic() - t0, *sample))
            if time.monotonic() >= next_report and samples:
                w, c, r = samples[-1]
                out(f"  {w:5.0f} s: RSS {r / 2**20:6.1f} MiB, CPU so far {c:6.1f} s")
                next_report += 10.0
            time.sleep(1.0)
        _stdout, stderr = daemon.communicate()
    finally:
        for p in (daemon, mock):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(5)
                except subprocess.TimeoutExpired:
                    p.kill()
    if daemon.returncode != 0 or not summary_file.exists():
        raise RuntimeError(f"daemon failed (exit {daemon.returncode}):\n{stderr[-2000:]}")
    summary = json.loads(summary_file.read_text())
    logs = tmp / "state" / "logs"
    log_bytes = sum(f.stat().st_size for f in logs.glob("*.mcap")) if logs.is_dir() else 0
    if logs.is_dir():  # each run starts without the previous run's logs
        for f in logs.glob("*.mcap"):
            f.unlink()
    # CPU over the steady part: from 5 s in (start-up: imports, first frames) to the end.
    steady = [s for s in samples if s[0] >= 5.0]
    cpu_pct = (
        100.0 * (steady[-1][1] - steady[0][1]) / (steady[-1][0] - steady[0][0])
        if len(steady) >= 2
        else float("nan")
    )
    rss = [s[2] / 2**20 for s in steady]
    n = len(rss)
    result = {
        "duration_s": duration_s,
        "cpu_pct_of_one_core": cpu_pct,
        "rss_mib_start": rss[0] if rss else float("nan"),
        "rss_mib_middle": rss[n // 2] if rss else float("nan"),
        "rss_mib_end": rss[-1] if rss else float("nan"),
        "rss_mib_max": max(rss) if rss else float("nan"),
        "log_bytes": log_bytes,
        "log_gb_per_hour": log_bytes / 1e9 * 3600.0 / max(duration_s, 1e-9),
        "flight_log_writer": measure_flight_log(frames),
        **summary,
    }
    return result


def print_daemon_bench(result: dict[str, Any], out: Callable[[str], Any] = print) -> None:
    r = result
    out(
        f"daemon bench: {r['duration_s']:.0f} s at 25 Hz, 360x220, frames from disk, mock autopilot over UDP"
    )
    out(
        f"  latency capture->MAVLink (ms): p50 {r['latency_p50_ms']:.2f}  p90 {r['latency_p90_ms']:.2f}"
        f"  p99 {r['latency_p99_ms']:.2f}  max {r['latency_max_ms']:.2f}   (target p99 <= 10)"
    )
    out(f"  CPU: {r['cpu_pct_of_one_core']:.1f}% of one core   (target <= 25%)")
    out(
        f"  flight log: {r['log_bytes'] / 1e6:.1f} MB in {r['duration_s']:.0f} s"
        f" = {r['log_gb_per_hour']:.2f} GB/h   (target <= 1 GB/h)"
    )
    for fmt, c in r.get("flight_log_writer", {}).items():
        out(
            f"  flight log writer ({fmt}, in-process, 360x220 at 25 Hz):"
            f" log_frame call median {c['log_frame_call_median_us']:.1f} µs,"
            f" writer CPU {c['writer_cpu_ms_per_frame']:.2f} ms/frame,"
            f" {c['gb_per_hour']:.2f} GB/h"
        )
    out(
        f"  RSS (MiB): start {r['rss_mib_start']:.1f}, middle {r['rss_mib_middle']:.1f}, end "
        f"{r['rss_mib_end']:.1f}, max {r['rss_mib_max']:.1f}   (target <= 200, flat)"
    )
    out(
        f"  frames: captured {r['captured']} = processed {r['processed']} + dropped {r['dropped']}"
        f" + failed {r['failed']} + rejected {r['rejected']}"
        f" ({'balanced' if r['frames_balance'] else 'NOT BALANCED'});"
        f" {r['frames_waited_for_attitude']} waited for the attitude"
    )
    stages = ", ".join(
        f"{k} {v['p50']:.2f}/{v['p99']:.2f}"
        for k, v in r["stages_ms"].items()
        if v["p50"] is not None
    )
    out(f"  where the time goes (p50/p99 ms): {stages}")
