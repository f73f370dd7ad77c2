"""Where the daemon's CPU goes besides the pipeline (docs/decisions.md §8.3).

Runs the daemon as ``tcm-companion bench --daemon`` runs it (frames of the simulated T90
flight from PNG files at 25 Hz, 360×220, looped; the mock autopilot in its own process
over loopback UDP) for ``--seconds``, and reports, over the steady part (from the 10th
second to 5 s before the end):

- each thread's CPU (% of one core) and context switches per second, voluntary and
  involuntary (``/proc/PID/task/*``);
- the loop thread split on its own CPU clock: ``Pipeline.step`` against everything else
  the loop thread did, per processed frame (the daemon process times ``Pipeline.step``
  with ``time.thread_time``; it prints the split when it exits).

Whichever source tree is first on ``sys.path`` is measured. Pin it to one core as the
issue does, and alternate trees:

    cd TREE && PYTHONPATH=TREE taskset -c 0 /work/main/.venv/bin/python \\
        tools/daemon_loop_study.py --frames DIR --seconds 40

``--frames DIR``: PNG frames to loop (``bench --daemon`` leaves them in
``/tmp/tcm-bench-daemon-*/frames``); rendered into a temporary directory if not given.
"""

from __future__ import annotations

import argparse
import atexit
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TICKS = os.sysconf("SC_CLK_TCK")


def _as_daemon(argv: list[str]) -> None:
    """The daemon process: ``tcm-companion run ARGV`` with ``Pipeline.step`` timed."""
    from tcm_companion.cli import main
    from tcm_companion.core import pipeline
    from tcm_companion.service import host

    acc = {"step_s": 0.0, "frames": 0}
    mark: dict[str, float] = {}
    step = pipeline.Pipeline.step

    def timed_step(self, *a, **k):  # type: ignore[no-untyped-def]
        t0 = time.thread_time()
        try:
            return step(self, *a, **k)
        finally:
            acc["step_s"] += time.thread_time() - t0
            acc["frames"] += 1

    health = host.CompanionHost.health_checked

    def checked(self, hc):  # type: ignore[no-untyped-def]
        if self.health_checks == 9:  # the 10th second: start-up is over
            mark.update(cpu=time.thread_time(), step=acc["step_s"], frames=acc["frames"])
        return health(self, hc)

    def report() -> None:
        if not mark:
            return
        n = acc["frames"] - mark["frames"]
        cpu = time.thread_time() - mark["cpu"]
        st = acc["step_s"] - mark["step"]
        if n:
            sys.stderr.write(
                f"LOOP frames {n} loop thread {cpu / n * 1e6:.0f} us/frame:"
                f" Pipeline.step {st / n * 1e6:.0f}, the rest {(cpu - st) / n * 1e6:.0f}\n"
            )

    pipeline.Pipeline.step = timed_step  # type: ignore[method-assign]
    host.CompanionHost.health_checked = checked  # type: ignore[method-assign]
    atexit.register(report)
    sys.argv = ["tcm-companion", *argv]
    main()


def _threads(pid: int) -> dict[int, tuple[str, float, int, int]]:
    """``{tid: (name, CPU s, voluntary, involuntary context switches)}``."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
            status = (task / "status").read_text()
            name = (task / "comm").read_text().strip()
        except OSError:
            continue
        f = stat[stat.rindex(")") + 2 :].split()
        vol = int(re.search(r"^voluntary_ctxt_switches:\s*(\d+)", status, re.M).group(1))  # type: ignore[union-attr]
        inv = int(re.search(r"^nonvoluntary_ctxt_switches:\s*(\d+)", status, re.M).group(1))  # type: ignore[union-attr]
        tid = int(task.name)
        out[tid] = ("main" if tid == pid else name, (int(f[11]) + int(f[12])) / TICKS, vol, inv)
    return out


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--as-daemon":
        _as_daemon(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=Path, help="PNG frames to loop (default: render 20 s of T90)")
    ap.add_argument("--seconds", type=float, default=40.0)
    args = ap.parse_args()
    if args.seconds < 20:
        ap.error("--seconds must be at least 20 (10 s of start-up, 5 s at the end)")
    tmp = Path(tempfile.mkdtemp(prefix="tcm-loop-study-"))
    frames = args.frames
    if frames is None:
        from tcm_companion.bench.daemon import write_frames

        frames = tmp / "frames"
        write_frames(frames, "T90", 20.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    py = sys.executable
    mock = subprocess.Popen(
        [py, "-m", "tcm_companion", "mock-autopilot", "--connect", f"udpin:127.0.0.1:{port}",
         "--scenario", "T90"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    sets = [
        'camera.source="frames"',
        f'camera.path="{frames}"',
        "camera.loop=true",
        f'mavlink.url="udpout:127.0.0.1:{port}"',
        f'daemon.state_dir="{tmp / "state"}"',
    ]
    cmd = [py, __file__, "--as-daemon", "run", "--no-status", "--log-level", "ERROR",
           "--duration", str(args.seconds), "--summary-json", str(tmp / "summary.json")]  # fmt: skip
    for s_ in sets:
        cmd += ["--set", s_]
    daemon = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(10.0)
        a, t0 = _threads(daemon.pid), time.monotonic()
        time.sleep(args.seconds - 15.0)
        b, t1 = _threads(daemon.pid), time.monotonic()
        _, err = daemon.communicate(timeout=60)
    finally:
        for p in (daemon, mock):
            if p.poll() is None:
                p.terminate()
                p.wait(10)
        shutil.rmtree(tmp, ignore_errors=True)  # the daemon's state and flight log
    wall = t1 - t0
    print(
        f"{args.seconds:.0f} s, threads over {wall:.1f} s (CPU % of one core; context switches/s)"
    )
    for tid, (name, cpu, vol, inv) in b.items():
        if tid in a:
            _, cpu0, vol0, inv0 = a[tid]
            if cpu == cpu0 and vol == vol0 and inv == inv0:
                continue  # idle all along (uvloop's worker threads)
            print(
                f"  {name:16s} CPU {100 * (cpu - cpu0) / wall:5.1f} %"
                f"  voluntary {(vol - vol0) / wall:6.1f}/s  involuntary {(inv - inv0) / wall:6.1f}/s"
            )
    for line in err.splitlines():
        if line.startswith("LOOP "):
            print("  " + line[5:])


if __name__ == "__main__":
    main()
