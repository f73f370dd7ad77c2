"""Flight logs of the daemon: process replay, reference logs, frame accounting, kill -9.

The reference logs under tests/data/logs were written by ``tcm-companion sitl --log``
with lossless frames (see tests/data/logs/README.md for the command that made them and
the one that updates the expected results when a change is intended).
"""

from __future__ import annotations

import asyncio
import csv
import io
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from tcm_companion.config import AppConfig
from tcm_companion.io.flightlog import LoggingConfig, decode_json, read_log
from tcm_companion.io.results import ResultsWriter
from tcm_companion.replay_log import compare, replay_log
from tcm_companion.service.sitl import run_sitl

ROOT = Path(__file__).resolve().parents[1]

# Real-time SITL runs: one at a time (one xdist group), so that two of them never share
# the two cores of a CI machine and their timing stays what they test.
pytestmark = pytest.mark.xdist_group("sitl")
LOGS = ROOT / "tests" / "data" / "logs"
REFERENCES = sorted(LOGS.glob("*.mcap"))


def lossless(config: AppConfig) -> AppConfig:
    return replace(config, logging=replace(config.logging, image_format="png"))


def test_a_sitl_log_replays_to_exactly_the_logged_results(tmp_path: Path) -> None:
    report = asyncio.run(
        run_sitl(
            lossless(AppConfig()),
            duration_s=4.0,
            state_dir=str(tmp_path / "state"),
            log_dir=str(tmp_path / "log"),
        )
    )
    assert report.ok, report.lines()
    log = report.log
    assert log is not None and log.frames_logged > 10
    # Every frame the cameras delivered is either in the log or counted as dropped.
    delivered = sum(c.delivered for c in report.summary.camera_stats.values())
    assert log.frames_logged + log.frames_dropped_queue + log.frames_dropped_disk == delivered
    frames = list(replay_log(tmp_path / "log"))
    assert len(frames) == report.summary.processed
    diffs = [d for f in frames for d in compare(f)]
    assert diffs == []
    decided = [o for f in frames for o in f.result.objects if o.state != "unknown"]
    assert decided  # the comparison is about something


@pytest.mark.parametrize("log", REFERENCES, ids=[p.stem for p in REFERENCES])
def test_reference_logs_replay_to_their_expected_results(log: Path) -> None:
    expected = log.with_suffix(".results.csv")
    assert expected.exists(), f"missing {expected.name}: see tests/data/logs/README.md"
    frames = list(replay_log(log))
    assert [d for f in frames for d in compare(f)] == []  # as in flight
    buf = io.StringIO()
    writer = ResultsWriter(buf)
    for f in frames:
        writer.write(f.result)
    got = list(csv.reader(io.StringIO(buf.getvalue())))
    want = list(csv.reader(expected.open()))
    assert got == want, (
        "replayed results differ from the reference; if the change is intended, update it "
        "with the command in tests/data/logs/README.md"
    )


def test_logged_results_carry_what_replay_and_plots_need(tmp_path: Path) -> None:
    asyncio.run(
        run_sitl(
            lossless(AppConfig()),
            duration_s=3.0,
            state_dir=str(tmp_path / "state"),
            log_dir=str(tmp_path / "log"),
        )
    )
    topics = {r.topic for r in read_log(tmp_path / "log")}
    assert {"/camera0/image", "/camera0/annotations", "/mavlink/in", "/mavlink/out"} <= topics
    assert {"/tcm/result", "/tcm/health"} <= topics
    doc = next(decode_json(r) for r in read_log(tmp_path / "log", {"/tcm/result"}))
    for key in ("t_capture_us", "t_process_us", "clock_offset_us", "override", "latency_ms"):
        assert key in doc


def _frames_logged(log_dir: Path) -> int:
    return sum(1 for r in read_log(log_dir, {"/camera0/image"}))


def test_kill_9_loses_at_most_about_a_second(tmp_path: Path) -> None:
    log_dir = tmp_path / "log"
    env = {**os.environ, "TCM_COMPANION__DAEMON__STATE_DIR": str(tmp_path / "state")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tcm_companion", "sitl", "--duration", "60", "--log", str(log_dir),
         "--log-level", "WARNING"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        # Wait until frames are being logged (read the growing file as a crash would
        # leave it; a loaded machine may take a while), then kill at a random moment.
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if list(log_dir.glob("*.mcap")) and _frames_logged(log_dir) > 10:
                break
            time.sleep(0.5)
        time.sleep(random.uniform(0.0, 3.0))
        killed_at_us = time.monotonic_ns() // 1000
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    last = max(r.publish_time_ns // 1000 for r in read_log(log_dir))
    lost_s = (killed_at_us - last) / 1e6
    assert 0 <= lost_s <= LoggingConfig().flush_interval_s + 0.6, lost_s
    # And what is there replays.
    assert _frames_logged(log_dir) > 10


def test_a_log_that_cannot_keep_up_drops_frames_counts_them_and_says_so(tmp_path: Path) -> None:
    config = lossless(AppConfig())
    config = replace(config, logging=replace(config.logging, queue_items=1))
    report = asyncio.run(
        run_sitl(config, duration_s=6.0, state_dir=str(tmp_path / "s"), log_dir=str(tmp_path / "l"))
    )
    log = report.log
    # One queue slot: whatever the thread is encoding, the next item (frame, result,
    # annotation or MAVLink chunk) has nowhere to go.
    assert log is not None and log.frames_dropped_queue + log.messages_dropped_queue > 0
    delivered = sum(c.delivered for c in report.summary.camera_stats.values())
    assert log.frames_logged + log.frames_dropped_queue + log.frames_dropped_disk == delivered
    assert report.summary.frames_balance  # the avoidance output did not wait for the log
    assert any("log behind" in t for t in report.statustexts), report.statustexts
