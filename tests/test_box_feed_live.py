"""The live box feed end to end (issue 14 §1): ``tcm-companion run`` as its own process
(frames from a directory, the mock autopilot in another process over UDP), the example
feeder (``tools/box_feeder_example.py``) as a third, real UDP sockets on loopback.

Every wait is on a condition the daemon reports — its systemd STATUS line, read from a
fake NOTIFY_SOCKET — with a generous time-out, never a fixed sleep: the boxes reach the
pipeline (frames processed with boxes, objects sent to the autopilot), garbage datagrams
sent meanwhile are counted and change nothing else, the feeder's end is a ``box feed
stale`` fault, and SIGTERM still ends the daemon cleanly with every count in its summary.
Then process replay of the run's flight log reproduces every result (``--check``): the
feed's datagrams are in the log.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from tcm_companion.bench.daemon import stop_processes

ROOT = Path(__file__).resolve().parents[1]
FEEDER = ROOT / "tools" / "box_feeder_example.py"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _scenario(root: Path, n: int = 25) -> Path:
    """Frames for the daemon's camera, and frames.csv + detections.csv for the feeder:
    one 20-px box per frame (a textured background, so that the vision has something)."""
    rng = np.random.default_rng(0)
    frames = root / "frames"
    frames.mkdir(parents=True)
    for k in range(n):
        img = rng.integers(0, 255, (220, 360, 3), dtype=np.uint8)
        cv2.imwrite(str(frames / f"{k:06d}.png"), img)
    t0 = 1_700_000_000_000_000
    (root / "frames.csv").write_text(
        "frame,t_us\n" + "".join(f"{k},{t0 + 40_000 * k}\n" for k in range(n))
    )
    (root / "detections.csv").write_text(
        "frame,x_min,y_min,x_max,y_max,score,label\n"
        + "".join(f"{k},150.0,90.0,170.0,110.0,0.9,ball\n" for k in range(n))
    )
    return root


class Status:
    """The daemon's STATUS= lines, from a fake systemd notify socket."""

    def __init__(self, path: Path) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.lines: list[str] = []

    def wait_for(
        self,
        what: str,
        cond: Callable[[str], bool],
        procs: list[subprocess.Popen[str]],
        timeout_s: float = 60.0,
    ) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for p in procs:
                if p.poll() is not None:
                    raise AssertionError(f"{p.args!r} ended ({p.returncode}) waiting for {what}")
            try:
                msg = self.sock.recv(4096).decode()
            except TimeoutError:
                continue
            for field in msg.split("\n"):
                if field.startswith("STATUS="):
                    line = field.removeprefix("STATUS=")
                    self.lines.append(line)
                    if cond(line):
                        return line
        raise AssertionError(
            f"no {what} in {timeout_s:.0f} s; last status lines: {self.lines[-3:]}"
        )


def _boxes(line: str) -> tuple[int, int]:
    m = re.search(r"boxes (\d+) frames, (\d+) bad", line)
    return (int(m[1]), int(m[2])) if m else (0, 0)


@pytest.mark.xdist_group("sitl")  # real time: one at a time on a 2-core machine
def test_a_feeder_process_feeds_boxes_to_a_running_daemon(tmp_path: Path) -> None:
    scenario = _scenario(tmp_path / "scenario")
    mav_port, feed_port = _free_udp_port(), _free_udp_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "NOTIFY_SOCKET": str(tmp_path / "notify")}
    env = {k: v for k, v in env.items() if not k.startswith("TCM_COMPANION__")}
    env.pop("WATCHDOG_USEC", None)
    status = Status(tmp_path / "notify")
    py = sys.executable
    summary_file = tmp_path / "summary.json"
    sets = {
        "camera.source": '"frames"',
        "camera.path": f'"{scenario / "frames"}"',
        "camera.loop": "true",
        "mavlink.url": f'"udpout:127.0.0.1:{mav_port}"',
        "daemon.state_dir": f'"{tmp_path / "state"}"',
        # A flight log with lossless frames: process replay must give the same results,
        # which it can only with the feed's datagrams in the log.
        "logging.directory": f'"{tmp_path / "logs"}"',
        "logging.image_format": '"png"',
        "detection.backend": '"boxes"',
        "daemon.box_feed": f'"udp:127.0.0.1:{feed_port}"',
        # The feeder plays its own frame times (it has no camera): half a frame period
        # lets every daemon frame find the message nearest to it.
        "detection.boxes_time_tolerance_s": "0.025",
    }
    procs: list[subprocess.Popen[str]] = []

    def start(*argv: str, **kw: object) -> subprocess.Popen[str]:
        p = subprocess.Popen(
            [py, *argv], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        procs.append(p)
        return p

    try:
        start("-m", "tcm_companion", "mock-autopilot", "--connect", f"udpin:127.0.0.1:{mav_port}")
        args = ["-m", "tcm_companion", "run", "--no-status", "--log-level", "WARNING"]
        args += ["--summary-json", str(summary_file), "--config", str(ROOT / "config.toml")]
        for k, v in sets.items():
            args += ["--set", f"{k}={v}"]
        daemon = start(*args)
        feeder = start(str(FEEDER), str(scenario), "--to", f"udp:127.0.0.1:{feed_port}", "--loop")

        # The boxes reach the pipeline: frames processed with them.
        status.wait_for("frames with boxes", lambda s: _boxes(s)[0] >= 25, procs)

        # Garbage from another process's socket: counted, not fatal.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as junk:
            for data in [b"\x00\xff not json", b"[]", b'{"v": 1, "camera": 9}'] * 10:
                junk.sendto(data, ("127.0.0.1", feed_port))
            future = {
                "v": 1,
                "camera": 0,
                "capture_mono_us": time.monotonic_ns() // 1000 + 10**9,
                "boxes": [],
            }
            junk.sendto(json.dumps(future).encode(), ("127.0.0.1", feed_port))
        seen = _boxes(status.lines[-1])[0]
        status.wait_for(
            "31 bad datagrams and frames with boxes after them",
            lambda s: _boxes(s)[1] >= 31 and _boxes(s)[0] >= seen + 25,
            procs,
        )

        # The feeder ends: the feed goes stale (a fault), the daemon carries on.
        feeder.send_signal(signal.SIGTERM)
        feeder.wait(30)
        procs.remove(feeder)
        status.wait_for("box feed stale", lambda s: "box feed stale" in s, procs)

        daemon.send_signal(signal.SIGTERM)
        out, err = daemon.communicate(timeout=60)
    finally:
        stop_processes(procs, grace_s=10.0)
        status.sock.close()
    assert daemon.returncode == 0, f"{out}\n{err}"
    summary = json.loads(summary_file.read_text())
    feed = summary["box_feed"]
    assert feed["frames with boxes"] >= 50
    assert feed["malformed"] >= 20 and feed["unknown camera"] >= 10 and feed["future"] >= 1
    assert feed["accepted"] >= 50 and feed["boxes"] >= 50
    assert summary["objects_sent"] > 0  # the boxes became objects the autopilot heard of
    assert summary["faults"].get("box feed stale") == 1
    assert summary["frames_balance"]
    assert "box feed" in out  # the summary line prints the counters

    # Process replay of the flight log: every result equal to the logged one (--check),
    # objects included (the boxes came from the log's /tcm/boxes).
    logs = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(logs) == 1, logs
    results = tmp_path / "replayed.csv"
    rp = subprocess.run(
        [py, "-m", "tcm_companion", "replay", str(logs[0]), "--results", str(results), "--check"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert rp.returncode == 0, rp.stdout + rp.stderr
    rows = results.read_text().splitlines()[1:]
    assert sum(1 for r in rows if r.split(",")[2]) >= 50  # rows with a tracked object
