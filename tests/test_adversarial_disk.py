"""Adversarial: the flight log's disk (issue 24 §2, "Done when").

What an adversarial first day did to the log's disk, each asserting that nothing was
lost that the program says it kept:

- ENOSPC during logging, on a real full file system (a small tmpfs, mounted in a mount
  namespace of its own: ``unshare -rm``, which needs no root): the daemon (``sitl``, the
  daemon's code on the simulated clock) keeps running and deciding; frames logged +
  dropped == frames delivered; the log up to the failure is readable, holds exactly the
  frames counted as logged, and replays; no empty parts.
- The writer on a full tmpfs resumes when space returns, in a new part of the same flight.
- Two flights in one directory are never replayed as one.

Bounded: well under a minute on one core (simulated time, small file systems).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
from dataclasses import replace
from pathlib import Path

import pytest

from tcm_companion import cli
from tcm_companion.config import AppConfig
from tcm_companion.flightlog import topics
from tcm_companion.flightlog.reader import check_log, read_log, read_metadata
from tcm_companion.sitl.mock_flight import run_sitl_virtual


def _namespace_works() -> str:
    """ "" when ``unshare -rm`` can mount a tmpfs here, else why not."""
    if shutil.which("unshare") is None:
        return "no unshare(1) on this machine"
    with tempfile.TemporaryDirectory() as d:
        try:
            r = subprocess.run(
                ["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {d} 2>&1"],
                capture_output=True, text=True, timeout=20,
            )  # fmt: skip
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"unshare -rm failed: {exc}"
    if r.returncode != 0:
        return f"cannot mount a tmpfs in a mount namespace: {(r.stderr or r.stdout).strip()}"
    return ""


WHY_NOT = _namespace_works()
needs_tmpfs = pytest.mark.skipif(bool(WHY_NOT), reason=WHY_NOT or "ok")


def in_small_tmpfs(
    size: str, mount: Path, copy_to: Path, argv: list[str], env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` with a tmpfs of ``size`` mounted at ``mount`` (in a mount namespace
    of its own), then copy what it left there to ``copy_to`` (the mount goes with the
    namespace)."""
    mount.mkdir(parents=True, exist_ok=True)
    copy_to.mkdir(parents=True, exist_ok=True)
    script = (
        'mount -t tmpfs -o size="$1" tmpfs "$2" || exit 97; mnt="$2"; shift 2; '
        '"$@"; rc=$?; cp -a "$mnt"/. "$OUT"/ || exit 98; exit $rc'
    )
    return subprocess.run(
        ["unshare", "-rm", "sh", "-c", script, "sh", size, str(mount), *argv],
        capture_output=True, text=True, timeout=120,
        env={**os.environ, **(env or {}), "OUT": str(copy_to)},
    )  # fmt: skip


@needs_tmpfs
def test_a_full_disk_mid_flight_is_counted_and_the_log_replays(tmp_path: Path) -> None:
    """``min_free_mb = 0`` on a full disk said "146 frames logged + 0 dropped (queue) + 0
    (disk) ... FAILED: frames logged + dropped != frames delivered" and left empty parts
    ``-001``, ``-002``."""
    mnt, out = tmp_path / "mnt", tmp_path / "log"
    r = in_small_tmpfs(
        "1m",
        mnt,
        out,
        [sys.executable, "-m", "tcm_companion", "sitl", "--clock", "virtual", "--duration",
         "6", "--log", str(mnt), "--status-every", "0", "--set", "logging.min_free_mb=0"],
        env={"TCM_COMPANION__DAEMON__STATE_DIR": str(tmp_path / "state")},
    )  # fmt: skip
    text = r.stdout + r.stderr
    assert r.returncode == 0, text  # the run passed: nothing FAILED
    assert "FAILED" not in text
    m = re.search(r"frames: captured (\d+) = processed (\d+) \+ dropped (\d+)", text)
    assert m, text
    captured, processed = int(m.group(1)), int(m.group(2))
    assert processed >= captured - 2 and processed > 120  # deciding all along
    m = re.search(r"flight log: (\d+) frames logged \+ (\d+) dropped \(queue\) \+ (\d+) \(disk\)"
                  r"(?: \+ (\d+) \(error\))?", text)  # fmt: skip
    assert m, text
    logged, queue, disk, error = (int(g or 0) for g in m.groups())
    assert logged + queue + disk + error == captured  # every frame accounted for
    assert disk > 10 and logged > 40 and error == 0  # the disk filled up mid-flight
    # one part, cut where the disk filled, holding exactly the frames counted as logged
    (part,) = sorted(out.glob("*.mcap"))
    assert read_metadata(part)
    image = topics.camera_image(0)
    assert sum(1 for _ in read_log(out, {image})) == logged
    (problem,) = check_log(out).problems()
    assert "truncated" in problem
    # ... and it replays as far as it is readable (exit 0 without --check)
    rc = cli.main(["replay", str(out), "--results", str(tmp_path / "r.csv"), "-q"])
    assert rc == 0
    rows = (tmp_path / "r.csv").read_text().count("\n")
    assert rows > 10


WRITER = textwrap.dedent(
    """
    import json, os, sys, time
    from pathlib import Path
    import numpy as np
    from tcm_companion.flightlog.settings import LoggingConfig
    from tcm_companion.flightlog.writer import FlightLogWriter

    d = Path(sys.argv[1])
    filler = d / "filler"
    events = []
    w = FlightLogWriter(
        LoggingConfig(image_format="png", min_free_mb=0.0, flush_interval_s=0.05),
        d / "log",
        on_event=lambda sev, text: events.append([sev, text]),
        retry_interval_s=0.05,
        free_check_interval_s=0.02,
    )
    w.start({"camera0": {"w": 360}})
    rng = np.random.default_rng(1)
    calls = []

    def log(n):
        for _ in range(n):
            t = 1_000_000 + 40_000 * len(calls)
            calls.append(t)
            img = rng.integers(0, 256, (220, 360, 3), dtype=np.uint8)  # ~240 kB as PNG
            w.log_frame(0, t, img)
            w.log_json("/tcm/result", t, {"t": t})
            time.sleep(0.01)

    log(2)
    deadline = time.monotonic() + 30
    while w.stats.bytes_written < 400_000 and time.monotonic() < deadline:
        time.sleep(0.01)  # both in the file (flushed)
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)  # another program fills the disk
    try:
        while True:
            os.write(fd, b"x" * 4096)
    except OSError:
        pass
    os.close(fd)
    log(6)
    deadline = time.monotonic() + 30
    while w.state != "fault" and time.monotonic() < deadline:
        time.sleep(0.01)
    state_full = w.state
    log(3)
    filler.unlink()  # space returns
    while w.state != "recording" and time.monotonic() < deadline:
        time.sleep(0.01)
    state_back = w.state
    log(2)
    w.stop()
    s = w.stats
    print(json.dumps({
        "calls": calls, "full": state_full, "back": state_back, "events": events,
        "logged": s.frames_logged, "queue": s.frames_dropped_queue,
        "disk": s.frames_dropped_disk, "error": s.frames_dropped_error,
        "messages_logged": s.messages_logged, "files": [p.name for p in s.files],
    }))
    """
)


@needs_tmpfs
def test_the_writer_resumes_in_a_new_part_when_space_returns(tmp_path: Path) -> None:
    mnt, out = tmp_path / "mnt", tmp_path / "out"
    r = in_small_tmpfs("2m", mnt, out, [sys.executable, "-c", WRITER, str(mnt)])
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(r.stdout.strip().splitlines()[-1])
    assert (res["full"], res["back"]) == ("fault", "recording"), res
    assert [sev for sev, _ in res["events"]] == ["error", "info"], res["events"]
    assert "No space left on device" in res["events"][0][1]
    n = len(res["calls"])
    assert res["logged"] + res["queue"] + res["disk"] + res["error"] == n
    assert res["disk"] > 0 and res["error"] == 0
    log = out / "log"
    assert sorted(p.name for p in log.glob("*.mcap")) == sorted(res["files"])  # no empty part
    assert len(res["files"]) == 2  # the part the disk cut, and the one after
    got = [r.publish_time_ns // 1000 for r in read_log(log, {topics.camera_image(0)})]
    assert len(got) == res["logged"]  # what was counted as logged is in the log
    assert got[-1] == res["calls"][-1]  # logged again after the space returned
    ids = {read_metadata(p)["flight_id"] for p in log.glob("*.mcap")}
    assert len(ids) == 1  # one flight


def test_two_flights_in_one_directory_are_never_joined(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shared = tmp_path / "logs"  # as under systemd: every flight in one directory
    config = AppConfig()
    config = replace(config, logging=replace(config.logging, image_format="png"))
    processed = []
    for k in range(2):
        report = run_sitl_virtual(
            config, duration_s=1.5, state_dir=str(tmp_path / f"s{k}"), log_dir=str(shared)
        )
        processed.append(report.summary.processed)
    capsys.readouterr()
    rc = cli.main(["replay", str(shared), "--results", str(tmp_path / "r.csv"), "-q"])
    out, err = capsys.readouterr()
    assert rc == 2 and "holds 2 flights" in err and not (tmp_path / "r.csv").exists()
    ids = re.findall(r"^  ([0-9a-f]{12})  started", err, re.M)
    assert len(ids) == 2 and ids[0] != ids[1], err
    for fid, n in zip(ids, processed):
        rc = cli.main(
            ["replay", str(shared), "--flight", fid, "--results", str(tmp_path / f"{fid}.csv"),
             "--check", "-q"]
        )  # fmt: skip
        out, err = capsys.readouterr()
        assert rc == 0 and f": {n} frames replayed" in out, (out, err)
