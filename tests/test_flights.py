"""Every flight is its own (issue 24 §2): a log directory holding several flights.

Two ``sitl --clock virtual`` runs into one directory were named as two parts of one
session (``tcm-20240610-061320-000``, ``-001``: the simulation's start time) and
replayed as one flight, the second's tracks carried over from the first, without a word;
under systemd every flight shares ``/var/log/tcm-companion``. Now each flight has an id
(in every part's metadata and file name): a directory's flights are listed and one is
picked (``--flight``), a flight's parts are joined in their order and never with another
flight's, and what does not belong (another flight's part, a copy, a file that is no log)
is named. Logs written before flights had ids are grouped by name stem, metadata and time.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from tcm_companion import cli
from tcm_companion.config import AppConfig
from tcm_companion.flightlog.reader import (
    find_flights,
    parse_part_name,
    read_metadata,
    select_flight,
)
from tcm_companion.sitl.mock_flight import SitlReport, run_sitl_virtual

from .helpers import REFERENCE_LOG as REFERENCE
from .helpers import split_log

REFERENCE_FRAMES = 61  # processed frames of tests/data/logs/sitl-t90.mcap


@dataclass
class Run:
    report: SitlReport
    flight_id: str
    parts: list[Path]

    @property
    def processed(self) -> int:
        return self.report.summary.processed


def _config() -> AppConfig:
    c = AppConfig()
    # PNG for an exact replay; a part per simulated second: flights of several parts
    return replace(c, logging=replace(c.logging, image_format="png", rotate_interval_s=1.0))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Run]]:
    """Two runs of the same simulation (same seed, same start) into ONE directory."""
    tmp = tmp_path_factory.mktemp("flights")
    shared = tmp / "shared"
    out = []
    for k in range(2):
        report = run_sitl_virtual(
            _config(), duration_s=2.5, state_dir=str(tmp / f"state{k}"), log_dir=str(shared)
        )
        assert report.ok, report.lines()
        parts = list(report.log.files)
        ids = {parse_part_name(p.name)[1] for p in parts}  # type: ignore[index]
        assert len(ids) == 1 and len(parts) >= 3, parts
        out.append(Run(report, ids.pop(), parts))
    return shared, out


def run_cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli.main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


def replayed(out: str) -> int:
    m = re.search(r"(\d+) frames replayed", out)
    assert m, out
    return int(m.group(1))


def copy_flight(run: Run, dst: Path) -> list[Path]:
    dst.mkdir()
    return [Path(shutil.copy2(p, dst / p.name)) for p in run.parts]


# ---------------------------------------------------------------------------------------
# Two flights in one directory


@pytest.mark.slow  # over a second of CPU
def test_two_runs_into_one_directory_are_two_flights(runs: tuple[Path, list[Run]]) -> None:
    shared, (a, b) = runs
    assert a.flight_id != b.flight_id  # the same simulation, but another flight
    for run in (a, b):
        assert all(read_metadata(p)["flight_id"] == run.flight_id for p in run.parts)
        assert [read_metadata(p)["log_part"] for p in run.parts] == [
            str(k) for k in range(len(run.parts))
        ]
    flights, orphans = find_flights(shared)
    assert orphans == []
    assert [(f.flight_id, f.parts) for f in flights] == [
        (a.flight_id, a.parts),
        (b.flight_id, b.parts),
    ]
    assert all(f.problems == [] and not f.legacy for f in flights)


@pytest.mark.slow  # over half a second of CPU
def test_a_directory_of_two_flights_is_never_replayed_as_one(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was: "132 frames replayed, 137 rows", the second flight on the first's tracks."""
    shared, (a, b) = runs
    csv = str(tmp_path / "r.csv")
    rc, out, err = run_cli(capsys, "replay", str(shared), "--results", csv, "--check", "-q")
    assert rc == 2 and out == "", (out, err)
    assert f"error: {shared} holds 2 flights: pick one with --flight ID" in err
    assert f"  {a.flight_id}  started 2024-06-10 06:13:20 UTC, {len(a.parts)} part(s)" in err
    assert f"  {b.flight_id}  started 2024-06-10 06:13:20 UTC, {len(b.parts)} part(s)" in err
    assert "Traceback" not in err
    for run, pick in ((a, a.flight_id[:6]), (b, b.flight_id), (b, "latest")):
        rc, out, err = run_cli(
            capsys, "replay", str(shared), "--flight", pick, "--results", csv, "--check",
            "--force", "-q",
        )  # fmt: skip
        assert rc == 0, (out, err)
        assert replayed(out) == run.processed  # that flight's frames, all identical
        assert f"{run.processed} identical to the flight, 0 differ" in out
        assert f"flight {run.flight_id} of the 2 flights in the directory" in err
    rc, out, err = run_cli(
        capsys, "replay", str(shared), "--flight", "f" * 13, "--results", csv + ".2"
    )
    assert rc == 2 and f"no flight with id '{'f' * 13}'" in err
    # a part file on its own is that file only
    rc, out, err = run_cli(capsys, "replay", str(a.parts[0]), "--results", csv, "--force", "-q")
    assert rc == 0 and 0 < replayed(out) < a.processed, (out, err)


def test_export_and_plot_pick_a_flight_too(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shared, (a, _b) = runs
    rc, out, err = run_cli(capsys, "export", str(shared), "--scenario", str(tmp_path / "s"))
    assert rc == 2 and "holds 2 flights" in err and not (tmp_path / "s").exists()
    rc, out, err = run_cli(capsys, "plot", str(shared), "--out", str(tmp_path / "p"))
    assert rc == 2 and "holds 2 flights" in err
    rc, out, err = run_cli(
        capsys, "export", str(shared), "--flight", a.flight_id, "--scenario", str(tmp_path / "s")
    )
    assert rc == 0, err
    assert f": {a.report.log.frames_logged} frames" in out


# ---------------------------------------------------------------------------------------
# One flight's parts, tampered with


def check(capsys: pytest.CaptureFixture[str], log: Path, tmp_path: Path) -> tuple[int, str, str]:
    return run_cli(
        capsys, "replay", str(log), "--results", str(tmp_path / "r.csv"), "--check", "--force",
        "-q",
    )  # fmt: skip


def test_parts_are_joined_in_their_order_not_their_names(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, (a, _b) = runs
    log = tmp_path / "log"
    parts = copy_flight(a, log)
    first, last = parts[0], parts[-1]
    tmp = log / "x"
    first.rename(tmp)  # the first part under the last one's name, and back
    last.rename(first)
    tmp.rename(last)
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 0, (out, err)
    assert replayed(out) == a.processed and err == ""


@pytest.mark.slow  # over half a second of CPU
def test_a_missing_part_is_named_and_fails_the_check(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, (a, _b) = runs
    log = tmp_path / "log"
    parts = copy_flight(a, log)
    parts[1].unlink()
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 1, (out, err)
    n = len(parts)
    assert f"warning: flight {a.flight_id}: part(s) 1 of {n} missing" in err
    assert "check failed: the log is not whole" in err
    assert 0 < replayed(out) < a.processed  # what is there replays


def test_another_flights_part_dropped_in_is_not_joined(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Even named as this flight's next part: the metadata says whose it is."""
    _, (a, b) = runs
    log = tmp_path / "log"
    parts = copy_flight(a, log)
    session, _, n = parse_part_name(parts[-1].name)  # type: ignore[misc]
    shutil.copy2(b.parts[1], log / f"tcm-{session}-{a.flight_id}-{n + 1:03d}.mcap")
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 2 and "holds 2 flights" in err and b.flight_id in err, (out, err)
    rc, out, err = run_cli(
        capsys, "replay", str(log), "--flight", a.flight_id, "--results",
        str(tmp_path / "r.csv"), "--check", "--force", "-q",
    )  # fmt: skip
    assert rc == 0, (out, err)
    assert replayed(out) == a.processed


@pytest.mark.slow  # over half a second of CPU
def test_a_copy_of_a_part_is_read_once_and_another_part_with_its_number_fails(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, (a, _b) = runs
    log = tmp_path / "log"
    parts = copy_flight(a, log)
    copy = log / parts[1].name.replace("-001.mcap", "-042.mcap")
    shutil.copy2(parts[1], copy)
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 0 and replayed(out) == a.processed, (out, err)
    assert f"warning: {copy}: a copy of {parts[1].name} (part 1): skipped" in err
    data = bytearray(copy.read_bytes())
    data[-40] ^= 0xFF  # in the summary: same metadata, other bytes
    copy.write_bytes(bytes(data))
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 1 and replayed(out) == a.processed, (out, err)
    assert f"warning: {copy}: another part 1 of flight {a.flight_id}" in err


@pytest.mark.slow  # over half a second of CPU
def test_an_empty_part_of_the_flight_is_reported_and_other_files_are_skipped(
    runs: tuple[Path, list[Run]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, (a, _b) = runs
    log = tmp_path / "log"
    parts = copy_flight(a, log)
    notes = log / "tcm-notes.mcap"
    notes.write_text("not a log\n")
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 0 and replayed(out) == a.processed, (out, err)  # a stray file: named only
    assert f"warning: {notes}: skipped: not a part of flight {a.flight_id}" in err
    session, _, n = parse_part_name(parts[-1].name)  # type: ignore[misc]
    empty = log / f"tcm-{session}-{a.flight_id}-{n + 1:03d}.mcap"
    empty.write_bytes(b"")  # a writer killed as it opened its next part
    rc, out, err = check(capsys, log, tmp_path)
    assert rc == 1 and replayed(out) == a.processed, (out, err)
    assert f"{empty}: truncated: the file is empty" in err
    # a file that is no log, given on its own: one line, exit 2
    rc, out, err = run_cli(capsys, "replay", str(notes), "--results", str(tmp_path / "n.csv"))
    assert rc == 2 and err.count("\n") == 1, err
    assert "not an MCAP file" in err and "not a flight log" in err
    rc, out, err = run_cli(capsys, "plot", str(notes), "--out", str(tmp_path / "p"))
    assert rc == 2 and "not an MCAP file" in err, (out, err)  # it drew empty plots (exit 0)


# ---------------------------------------------------------------------------------------
# Logs written before flights had ids


@pytest.mark.slow  # over half a second of CPU
def test_logs_without_flight_ids_are_grouped_by_name_metadata_and_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The reference log rotated into three parts: one flight, as it was.
    split = tmp_path / "split"
    split_log(REFERENCE, split, 3)
    flights, _ = find_flights(split)
    assert len(flights) == 1 and flights[0].legacy and len(flights[0].parts) == 3
    rc, out, err = run_cli(
        capsys, "replay", str(split), "--results", str(tmp_path / "r.csv"), "--check",
        "--rel-tol", "1e-9", "-q",
    )  # fmt: skip
    assert rc == 0 and replayed(out) == REFERENCE_FRAMES, (out, err)
    # Two runs of one simulation into one directory, before flights had ids: named as
    # parts 000 and 001 of one session, same metadata, but the second does not start
    # after the first: two flights.
    two = tmp_path / "two"
    two.mkdir()
    for k in range(2):
        shutil.copy2(REFERENCE, two / f"tcm-20261202-103013-{k:03d}.mcap")
    flights, _ = find_flights(two)
    assert [f.flight_id for f in flights] == ["tcm-20261202-103013-000", "tcm-20261202-103013-001"]
    rc, out, err = run_cli(capsys, "replay", str(two), "--results", str(tmp_path / "t.csv"))
    assert rc == 2 and "holds 2 flights" in err and "written before flights had ids" in err
    rc, out, err = run_cli(
        capsys, "replay", str(two), "--flight", "tcm-20261202-103013-001", "--results",
        str(tmp_path / "t.csv"), "--check", "--rel-tol", "1e-9", "-q",
    )  # fmt: skip
    assert rc == 0 and replayed(out) == REFERENCE_FRAMES, (out, err)
    assert select_flight(REFERENCE).parts == [REFERENCE]
