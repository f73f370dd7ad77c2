"""Outputs are whole or absent, never silently replaced; one unreadable frame is skipped,
reported and given ``unknown`` rows (issue 13: a zero-byte PNG at frame 50 aborted the
replay after it had overwritten the results with 50 rows, and nothing said so)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from tcm_companion import cli
from tcm_companion.io.outputs import (
    SCENARIO_DIR,
    OutputExists,
    OutputKind,
    atomic_path,
    atomic_text,
    text_starting,
)

EXAMPLE = Path(__file__).parent / "data" / "examples" / "EX-T90"


@pytest.fixture()
def scenario(tmp_path: Path) -> Path:
    sc = tmp_path / "sc"
    shutil.copytree(EXAMPLE, sc)
    return sc


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow  # over a second of CPU
def test_replay_never_replaces_an_output_unless_forced(scenario: Path, tmp_path: Path) -> None:
    out = tmp_path / "results.csv"
    # an earlier run's results (--force replaces only a results CSV: issue 24)
    precious = (
        "frame,t_us,track_id,azimuth_deg,elevation_deg,angular_radius_deg,state,disparity,ttc_s\n"
    )
    out.write_text(precious)
    assert cli.main(["replay", str(scenario), "--results", str(out), "-q"]) == 2
    assert out.read_text() == precious
    assert cli.main(["replay", str(scenario), "--results", str(out), "-q", "--force"]) == 0
    assert len(_rows(out)) > 50
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".results.csv")]


@pytest.mark.slow  # over a second of CPU
def test_unreadable_frame_is_skipped_reported_and_unknown(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clean = tmp_path / "clean.csv"
    assert cli.main(["replay", str(scenario), "--results", str(clean), "-q"]) == 0
    (scenario / "frames" / "000050.png").write_bytes(b"")  # zero bytes
    (scenario / "frames" / "000060.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    out = tmp_path / "results.csv"
    capsys.readouterr()
    assert cli.main(["replay", str(scenario), "--results", str(out), "-q"]) == 0
    captured = capsys.readouterr()
    assert "2 unreadable frame(s) skipped" in captured.out
    assert "frame 50 skipped" in captured.err and "000050.png" in captured.err
    rows, before = _rows(out), _rows(clean)
    frames = sorted({int(r["frame"]) for r in rows})
    assert frames == sorted({int(r["frame"]) for r in before})  # numbering intact
    for bad in (50, 60):
        mine = [r for r in rows if int(r["frame"]) == bad]
        assert mine and all(r["state"] == "unknown" and r["disparity"] == "" for r in mine)
    # the frames before the damage are untouched
    assert [r for r in rows if int(r["frame"]) < 50] == [r for r in before if int(r["frame"]) < 50]


def test_a_failed_replay_leaves_no_output(
    scenario: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import tcm_companion.replay.scenario as replay

    real = replay.run_replay

    def failing(*a, **kw):  # type: ignore[no-untyped-def]
        for k, result in enumerate(real(*a, **kw)):
            if k == 30:
                raise RuntimeError("power cut")
            yield result

    monkeypatch.setattr(replay, "run_replay", failing)
    out = tmp_path / "results.csv"
    with pytest.raises(RuntimeError, match="power cut"):
        cli.main(["replay", str(scenario), "--results", str(out), "-q"])
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".results.csv")]


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_sim_export_into_an_existing_scenario_needs_force(tmp_path: Path) -> None:
    dest = tmp_path / "TS"
    args = ["sim", "export", "TS", str(dest), "--duration", "0.2", "--resolution", "90x55"]
    assert cli.main(args) == 0  # an earlier export
    first = (dest / "scenario.toml").read_text()
    (dest / "frames.csv").write_text("frame,t_us\n")  # to see that it is replaced
    assert cli.main(args) == 2
    assert (dest / "frames.csv").read_text() == "frame,t_us\n"
    assert cli.main([*args, "--force"]) == 0
    assert (dest / "scenario.toml").read_text() == first
    assert (dest / "frames.csv").read_text() != "frame,t_us\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["TS"]  # no temporaries left
    # a directory holding anything but a scenario's files is never replaced (issue 24)
    (dest / "mine.txt").write_text("keep")
    assert cli.main([*args, "--force"]) == 2
    assert (dest / "mine.txt").read_text() == "keep"


def test_atomic_helpers(tmp_path: Path) -> None:
    text = OutputKind("text", text_starting("one"))
    p = tmp_path / "a.txt"
    with atomic_text(p, kind=text) as fh:
        fh.write("one")
        assert not p.exists()  # not in place before it is complete
    assert p.read_text() == "one"
    with pytest.raises(OutputExists):
        with atomic_text(p, kind=text):
            pass
    with pytest.raises(ValueError), atomic_path(tmp_path / "d", kind=SCENARIO_DIR) as d:
        (d / "x").write_text("half")
        raise ValueError("interrupted")
    assert not (tmp_path / "d").exists()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


@pytest.mark.slow  # over a second of CPU
def test_eval_skips_an_unreadable_frame_and_says_so(
    scenario: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As replay and plot do (before, eval stopped with "cannot be read as an image"):
    the frame's truth objects count as undecided, the report and stderr say which frame,
    and the frame is not also blamed on the telemetry ("no attitude")."""
    (scenario / "frames" / "000050.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    out = tmp_path / "eval"
    assert cli.main(["eval", str(scenario), "--out", str(out), "--no-bsm", "-q"]) == 0
    err = capsys.readouterr().err
    assert "1 unreadable frame(s) skipped" in err and "000050.png" in err
    assert "no attitude" not in err
    report = (out / "report.txt").read_text()
    assert "1 unreadable frame(s) skipped" in report
    row = next(ln for ln in report.splitlines() if ln.startswith("EX-T90 "))
    assert "100.0%" in row  # what was decided is still right
