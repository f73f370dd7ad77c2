"""Damaged input through ``tcm-companion replay``: nothing lost, nothing silently partial
(issue 13).

- A flight log cut short (a killed daemon, a copy taken while it was written) replays as
  far as it is readable, says that it is truncated, where it ends and how much of the file
  was readable; ``--check`` fails on it. A log of several parts names the damaged part.
- A ``.tlog`` cut short, with junk appended or with a corrupt stretch in its middle: the
  intact records kept, the rest reported (bytes skipped, where, records kept); a ``.tlog``
  with nothing usable is still an error.
- A scenario whose telemetry ends before its frames: the summary says which frames had no
  attitude and from when (exit 0, but not a summary that looks complete).
"""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import pytest

from tcm_companion import cli
from tcm_companion.flightlog import topics
from tcm_companion.flightlog.reader import check_log

from .helpers import REFERENCE_LOG as REFERENCE
from .helpers import split_log

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "tests" / "data" / "examples" / "EX-T90"


def replay(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli.main(["replay", *args, "-q"])
    out, err = capsys.readouterr()
    return rc, out, err


# ---------------------------------------------------------------------------------------
# Flight logs


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.97])
def test_a_truncated_log_says_so_and_fails_the_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], fraction: float
) -> None:
    """It replayed with exit 0 and no word of it ("0 frames replayed", exit 0)."""
    data = REFERENCE.read_bytes()
    size = int(len(data) * fraction)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:size])
    (part,) = check_log(cut).parts
    rc, out, err = replay(capsys, str(cut), "--results", str(tmp_path / "r.csv"), "--check")
    assert rc == 1, (out, err)
    assert f"warning: {cut}: truncated: {part.read_bytes} of {size} bytes" in err
    assert re.search(r"\d+ messages readable, the last \d+\.\d\d s into the log", err), err
    assert "check failed: the log is not whole" in err
    assert "INCOMPLETE: the log is truncated (readable to " in out
    assert f"{100.0 * part.read_bytes / size:.1f}% of the file" in out


def test_without_check_a_truncated_log_replays_what_is_readable_with_exit_0(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = REFERENCE.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    rc, out, err = replay(capsys, str(cut), "--results", str(tmp_path / "r.csv"))
    assert rc == 0
    assert "truncated" in err and "INCOMPLETE" in out
    m = re.search(
        r"(\d+) frames replayed.*?(\d+) differ(?: \((\d+) of them only by float rounding)?", out
    )
    assert m, out
    frames, differ, rounding = int(m[1]), int(m[2]), int(m[3] or 0)
    # Bit-exact where the numeric environment is the recording's; elsewhere the last bits
    # move (docs/logging.md), and only those: nothing differs beyond float rounding.
    assert frames > 0 and differ == rounding, out
    with open(tmp_path / "r.csv", newline="") as fh:
        assert len({row["frame"] for row in csv.DictReader(fh)}) == frames


@pytest.mark.slow  # over half a second of CPU
def test_exporting_a_truncated_log_says_the_scenario_is_partial(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``export`` of a cut log wrote a scenario of what was readable, without a word."""
    data = REFERENCE.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    capsys.readouterr()
    rc = cli.main(["export", str(cut), "--scenario", str(tmp_path / "sc")])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert f"warning: {cut}: truncated: " in err and "(exported what was readable)" in err
    frames = int(re.search(r": (\d+) frames", out).group(1))  # type: ignore[union-attr]
    assert 0 < frames == len(list((tmp_path / "sc" / "frames").iterdir()))
    capsys.readouterr()
    cli.main(["export", str(REFERENCE), "--scenario", str(tmp_path / "whole")])
    whole_out, whole_err = capsys.readouterr()
    assert "truncated" not in whole_err
    assert frames < int(re.search(r": (\d+) frames", whole_out).group(1))  # type: ignore[union-attr]


def test_a_log_cut_before_its_metadata_is_an_error_that_says_truncated(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(REFERENCE.read_bytes()[:40])
    rc, _, err = replay(capsys, str(cut), "--results", str(tmp_path / "r.csv"), "--check")
    assert rc == 2
    assert "no tcm-companion metadata record readable" in err and "truncated: " in err
    assert not (tmp_path / "r.csv").exists()


@pytest.mark.slow  # over half a second of CPU
def test_a_whole_log_passes_the_check_without_warnings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Short but whole (it has its footer): fine. Within float rounding: the reference was
    written on another machine (docs/logging.md); test_log_replay.py checks it bit-exactly
    where the numeric environment is the recording's."""
    rc, out, err = replay(
        capsys, str(REFERENCE), "--results", str(tmp_path / "r.csv"), "--check", "--rel-tol", "1e-9"
    )
    assert rc == 0, (out, err)
    assert "warning" not in err and "INCOMPLETE" not in out


@pytest.mark.slow  # over half a second of CPU
def test_check_with_a_tolerance_accepts_rounding_and_nothing_more(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--rel-tol 1e-9`` is for a log written on another machine (its last bits round
    differently); a disparity logged 1e-6 away from what the pipeline gives is a changed
    behaviour, and the check still fails on it, naming the tolerance."""
    edited: list[int] = []

    def nudge(topic: str, data: bytes) -> bytes:
        if topic != topics.RESULT or edited:
            return data
        doc = json.loads(data)
        for obj in doc["objects"]:
            if obj.get("disparity") is not None:
                obj["disparity"] *= 1.0 + 1e-6
                edited.append(doc["frame_index"])
                return json.dumps(doc).encode()
        return data

    (path,) = split_log(REFERENCE, tmp_path / "log", 1, edit=nudge)
    assert edited
    rc, out, err = replay(
        capsys, str(path), "--results", str(tmp_path / "r.csv"), "--check", "--rel-tol", "1e-9"
    )
    assert rc == 1, (out, err)
    assert "check failed: 1 frame(s) differ from the flight beyond 1e-09 relative" in err
    assert f"frame {edited[0]} " in out


@pytest.mark.slow  # over half a second of CPU
def test_a_log_of_several_parts_names_the_damaged_part(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    parts = split_log(REFERENCE, tmp_path / "log", 3)
    assert check_log(tmp_path / "log").problems() == []
    data = parts[1].read_bytes()
    parts[1].write_bytes(data[: len(data) // 2])
    rc, out, err = replay(
        capsys, str(tmp_path / "log"), "--results", str(tmp_path / "r.csv"), "--check"
    )
    assert rc == 1, (out, err)
    assert f"warning: part 2 of 3: {parts[1]}: truncated: " in err
    assert f"INCOMPLETE: of 3 parts, part 2 ({parts[1].name}) truncated" in out
    assert parts[0].name not in err and parts[2].name not in err
    # the parts after the damage are replayed too (a frame whose image was lost is skipped)
    frames = int(re.search(r"(\d+) frames replayed", out).group(1))  # type: ignore[union-attr]
    assert 0 < frames < 70


@pytest.mark.slow  # over a second of CPU
def test_a_log_whose_writer_dropped_frames_replays_and_checks_what_it_can(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 24 §2: frames the writer dropped (queue full, disk floor, disk full; counted
    in the log's health records) stopped the replay: "error: frame at ... us was processed
    but is not in the log", exit 2. Now they are counted and skipped; the frames after the
    first hole are replayed but not compared (the replay's pipeline lacked a frame the
    flight's had), and --check passes when every frame it could compare is the flight's."""
    from tcm_companion.flightlog.reader import decode_json, read_log

    results = [decode_json(r) for r in read_log(REFERENCE, {topics.RESULT})]
    assert len(results) == 61
    holes = {int(d["t_capture_us"]) * 1000 for d in results[30:34]}  # 4 frames mid-flight
    image = topics.camera_image(0)
    (path,) = split_log(
        REFERENCE, tmp_path / "log", 1, drop=lambda topic, t_ns: topic == image and t_ns in holes
    )
    args = ("--results", str(tmp_path / "r.csv"), "--rel-tol", "1e-9", "--check")
    rc, out, err = replay(capsys, str(path), *args)
    assert rc == 0, (out, err)
    assert "57 frames replayed, 57 rows" in out
    assert compared(out) == 30  # the frames before the hole (differing by rounding at most)
    assert (
        "4 processed frame(s) whose image is not in the log (dropped by the writer), not"
        " replayed; 27 frame(s) after the first hole replayed without what it lacks, not"
        " compared"
    ) in out
    # The first frame missing: nothing to compare, and the check says so.
    first = {int(results[0]["t_capture_us"]) * 1000}
    (path,) = split_log(
        REFERENCE, tmp_path / "log2", 1, drop=lambda topic, t_ns: topic == image and t_ns in first
    )
    rc, out, err = replay(capsys, str(path), *args, "--force")
    assert rc == 1 and "60 frames replayed" in out, (out, err)
    assert "check failed: no frame could be compared" in err
    # A result the writer dropped (a jump in the logged frame_index) is a hole too.
    dropped = int(results[20]["t_capture_us"])
    (path,) = split_log(
        REFERENCE,
        tmp_path / "log3",
        1,
        drop=lambda topic, t_ns: topic == topics.RESULT and _result_of(t_ns, results) == dropped,
    )
    rc, out, err = replay(capsys, str(path), *args, "--force")
    assert rc == 0, (out, err)
    assert "60 frames replayed" in out and compared(out) == 20
    assert "1 whose result is not (dropped by the writer), not replayed" in out


@pytest.mark.slow  # over half a second of CPU
def test_messages_the_writer_dropped_make_a_hole_too(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A live writer whose queue fills drops MAVLink bytes and box-feed datagrams too
    (counted in the health records' ``log`` counters, once a second): the replay then
    lacks inputs the daemon had, and its results differ from the drop on; --check failed
    on frames it could not have reproduced. The frames processed after the health record
    before the count went up are not compared, and the summary says why."""
    from tcm_companion.flightlog.reader import read_log

    health = [r.publish_time_ns for r in read_log(REFERENCE, {topics.HEALTH})]
    t1, t2 = health[1], health[2]
    mav = [r for r in read_log(REFERENCE, {topics.MAVLINK_IN}) if t1 < r.publish_time_ns < t2]
    assert len(mav) > 20

    def counted(topic: str, data: bytes) -> bytes:  # the record after the drop counts it
        if topic == topics.HEALTH:
            doc = json.loads(data)
            if doc["log"]["frames_logged"] == 48:  # the third one, at t2
                doc["log"]["messages_dropped_queue"] = len(mav)
                return json.dumps(doc).encode()
        return data

    (path,) = split_log(
        REFERENCE,
        tmp_path / "log",
        1,
        edit=counted,
        drop=lambda topic, t_ns: topic == topics.MAVLINK_IN and t1 < t_ns < t2,
    )
    before = sum(
        1 for r in read_log(REFERENCE, {topics.RESULT}) if r.publish_time_ns < t1
    )  # the results logged before the health record at t1
    rc, out, err = replay(
        capsys, str(path), "--results", str(tmp_path / "r.csv"), "--rel-tol", "1e-9", "--check"
    )
    assert rc == 0, (out, err)
    assert "61 frames replayed" in out and compared(out) == before > 10
    assert (
        f"{len(mav)} other message(s) the writer dropped (MAVLink, box feed, ...: the log's"
        " health records count them)"
    ) in out


def compared(out: str) -> int:
    """Frames the summary compared: identical + differing."""
    m = re.search(r"(\d+) identical to the flight, (\d+) differ", out)
    assert m, out
    return int(m.group(1)) + int(m.group(2))


def _result_of(t_ns: int, results: list[dict]) -> int | None:
    """The capture time of the result logged at ``t_ns`` (results are logged when the
    frame was processed, ``t_process_us``)."""
    for d in results:
        if int(d["t_process_us"]) * 1000 == t_ns:
            return int(d["t_capture_us"])
    return None


# ---------------------------------------------------------------------------------------
# Scenarios and their .tlog


@pytest.fixture()
def scenario(tmp_path: Path) -> Path:
    sc = tmp_path / "sc"
    shutil.copytree(EXAMPLE, sc)
    for p in [sc, *sc.rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    return sc


@pytest.mark.slow  # over a second of CPU
def test_frames_the_telemetry_does_not_cover_are_named_in_the_summary(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A .tlog cut short gave rows for only the frames it covered, silently."""
    from tcm_companion.config import AppConfig
    from tcm_companion.io.scenario import load_scenario
    from tcm_companion.replay.scenario import run_replay

    tlog = scenario / "telemetry.tlog"
    data = tlog.read_bytes()
    tlog.write_bytes(data[: len(data) * 45 // 100])
    sc = load_scenario(scenario)
    without = [r.frame_index for r in run_replay(sc, AppConfig()) if not r.attitude_ok]
    assert without and without == list(range(without[0], sc.n_frames))  # the tail
    t0 = sc.frame_times_us[0]
    ends = (sc.attitude_samples()[-1].recv_us - t0) / 1e6
    first, last = (sc.frame_times_us[without[0]] - t0) / 1e6, (sc.frame_times_us[-1] - t0) / 1e6

    rc, out, err = replay(capsys, str(scenario), "--results", str(tmp_path / "r.csv"))
    assert rc == 0
    n = len(without)
    assert f"; {n} frame(s) without attitude (see the warnings) -> " in out
    assert f"warning: {n} of {sc.n_frames} frames have no attitude" in err
    assert (
        f"frames {without[0]}–{sc.n_frames - 1} ({first:.2f}–{last:.2f} s): the .tlog's"
        f" attitude ends at {ends:.2f} s" in err
    )
    assert "truncated last record" in err  # and the .tlog's own warning


@pytest.mark.slow  # over a second of CPU
def test_a_whole_scenario_has_no_attitude_warning(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc, out, err = replay(capsys, str(scenario), "--results", str(tmp_path / "r.csv"))
    assert rc == 0 and err == "" and "without attitude" not in out


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize("damage", ["junk", "middle"])
def test_a_tlog_with_junk_or_a_corrupt_middle_replays_and_says_what_was_skipped(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    """Junk appended refused the whole scenario while a cut only warned: now both (and a
    corrupt stretch in the middle) keep what is intact and report the rest."""
    tlog = scenario / "telemetry.tlog"
    data = tlog.read_bytes()
    if damage == "junk":
        tlog.write_bytes(data + b"appended junk\n" * 50)
        expect = f"700 bytes skipped at byte {len(data)}, to the end of the file"
    else:
        mid = len(data) // 2
        tlog.write_bytes(data[:mid] + bytes(range(256)) * 2 + data[mid + 512 :])
        expect = "bytes skipped at byte "
    rc, out, err = replay(capsys, str(scenario), "--results", str(tmp_path / "r.csv"))
    assert rc == 0, err
    assert f"warning: {tlog}: " in err and " records kept, received " in err
    assert expect in err
    if damage == "middle":
        assert "resynchronised at byte " in err
    assert " rows (" in out


def test_a_tlog_with_nothing_usable_is_refused_naming_file_and_offset(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tlog = scenario / "telemetry.tlog"
    tlog.write_bytes(b"not a tlog at all\n" * 100)
    rc, _, err = replay(capsys, str(scenario), "--results", str(tmp_path / "r.csv"))
    assert rc == 2
    assert f"error: {tlog}: no usable MAVLink record in 1800 bytes (record 0 at byte 0: " in err
