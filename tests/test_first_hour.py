"""What a new user hit in the first hour (issue 13), as they hit it: a closed pipe, a
scenario whose ``.tlog`` is cut short or has junk appended, a run that decided nothing,
an unreadable frame in ``plot``, and out-of-range numbers on the command line."""

from __future__ import annotations

import io
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tcm_companion import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "tests" / "data" / "examples" / "EX-T90"


# -- a reader that closes stdout early (``tcm-companion sim list | head -1``) ------------------
def _with_closed_stdout(*args: str) -> subprocess.CompletedProcess[bytes]:
    """Run the command line with stdout a pipe whose reader has already gone: its first
    write fails with EPIPE, every time (no race with a real ``head``)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(
            [sys.executable, "-m", "tcm_companion", *args],
            stdout=write_end,
            stderr=subprocess.PIPE,
            cwd=ROOT,
            timeout=120,
            check=False,
        )
    finally:
        os.close(write_end)


@pytest.mark.slow  # a subprocess
@pytest.mark.parametrize(
    "argv", [["sim", "list"], ["config", "check", "config.toml"]], ids=["sim-list", "config-check"]
)
def test_a_closed_stdout_ends_the_command_quietly_with_141(argv: list[str]) -> None:
    """As ``seq 100000 | head -1`` does: no traceback, no "error: Broken pipe", no
    "Exception ignored" at the interpreter's exit; the status says SIGPIPE (128 + 13)."""
    proc = _with_closed_stdout(*argv)
    assert proc.stderr.decode() == ""
    assert proc.returncode == cli.EXIT_BROKEN_PIPE == 141


def test_a_closed_stdout_in_process(monkeypatch: pytest.MonkeyPatch) -> None:
    class Closed(io.StringIO):
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", Closed())
    assert cli.main(["sim", "list"]) == 141


# -- scenario warnings in eval and plot ------------------------------------------------------
@pytest.fixture(params=["cut", "junk"])
def damaged(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[Path, str]:
    """EX-T90 with its .tlog cut in half, or with 4000 bytes of junk appended, and the
    words the reader's warning uses for it."""
    sc = tmp_path / f"EX-{request.param}"
    shutil.copytree(EXAMPLE, sc)
    tlog = sc / "telemetry.tlog"
    data = tlog.read_bytes()
    if request.param == "cut":
        tlog.write_bytes(data[: len(data) // 2])
        return sc, "truncated last record"
    tlog.write_bytes(data + bytes(range(7, 207)) * 20)
    return sc, "bytes skipped"


@pytest.mark.slow
def test_eval_prints_the_scenario_s_warnings_and_keeps_them_in_the_report(
    damaged: tuple[Path, str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc, words = damaged
    out = tmp_path / "ev"
    assert cli.main(["eval", str(sc), "--no-bsm", "-q", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert any(words in line and "telemetry.tlog" in line for line in warned), err
    report = (out / "report.txt").read_text()
    assert "Warnings" in report and words in report
    if sc.name == "EX-cut":  # the second half of the flight has no attitude: said so
        assert any("frames have no attitude" in line for line in warned), err
        assert "frames have no attitude" in report


@pytest.mark.slow
def test_plot_prints_the_scenario_s_warnings(
    damaged: tuple[Path, str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc, words = damaged
    assert cli.main(["plot", str(sc), "--out", str(tmp_path / "plots")]) == 0
    err = capsys.readouterr().err
    assert any(
        line.startswith("warning: ") and words in line and "telemetry.tlog" in line
        for line in err.splitlines()
    ), err


@pytest.mark.slow
def test_plot_skips_an_unreadable_frame_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As replay does: a zero-byte PNG is a gap in the plots, reported, not the end."""
    sc = tmp_path / "sc"
    shutil.copytree(EXAMPLE, sc)
    (sc / "frames" / "000050.png").write_bytes(b"")
    out = tmp_path / "plots"
    assert cli.main(["plot", str(sc), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "warning: frame 50 skipped" in captured.err
    assert (out / "disparity.png").stat().st_size > 1000
    assert str(out / "disparity.png") in captured.out


# -- a run that decided nothing ---------------------------------------------------------------
@pytest.mark.slow
def test_eval_of_a_run_that_decided_nothing_says_no_decision(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One second of flight ends before the 1 s warm-up: every table is empty or dashes,
    and the report says why instead of leaving the methods table bare."""
    out = tmp_path / "ev"
    argv = ["eval", "--sim", "T90", "--duration", "1", "--no-bsm", "-q", "--out", str(out)]
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "T90 360x220: no decision" in text
    assert "nan" not in text
    assert "no decision" in (out / "report.txt").read_text()


# -- numbers out of range are usage errors, not tracebacks ------------------------------------
@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["eval", "--sim", "T90", "--duration", "0"], "--duration"),
        (["eval", "--sim", "T90", "--seed", "-1"], "--seed"),
        (["demo", "--duration", "-5"], "--duration"),
        (["demo", "--seed", "-1"], "--seed"),
        (["sim", "export", "T90", "DIR", "--duration", "0"], "--duration"),
        (["sim", "export", "T90", "DIR", "--duration", "nan"], "--duration"),
        (["sim", "export", "T90", "DIR", "--seed", "-1"], "--seed"),
        (["bench", "--frames", "0"], "--frames"),
        (["bench", "--daemon", "--duration", "-1"], "--duration"),
        (["replay", "SC", "--results", "r.csv", "--camera-id", "-1"], "--camera-id"),
        (["export", "LOG", "--scenario", "DIR", "--camera-id", "-1"], "--camera-id"),
        (["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--noise", "-1"], "--noise"),
        (["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--sysid", "0"], "--sysid"),
        (["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--sysid", "256"], "--sysid"),
        (["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--seed", "-1"], "--seed"),
        (
            ["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--ekf-origin-delay", "-1"],
            "--ekf-origin-delay",
        ),
        (["mock-autopilot", "--connect", "udpout:127.0.0.1:9", "--brake-ttc", "0"], "--brake-ttc"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else v,
)
def test_an_out_of_range_number_is_a_usage_error_naming_the_option(
    argv: list[str], option: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"error: argument {option}: must be" in err
    assert "Traceback" not in err


# -- one --duration over flights that end at contact -------------------------------------------
@pytest.mark.slow
def test_eval_keeps_a_collision_flight_s_own_length_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``eval --sim TS COLLISION --duration 20`` is how the docs run one duration over
    every flight; a collision course ends before contact (7 s), so it was a traceback."""
    out = tmp_path / "ev"
    argv = ["eval", "--sim", "COLLISION", "--duration", "20", "--no-bsm", "-q", "--out", str(out)]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    assert (
        "eval: COLLISION lasts 7.00 s, not the --duration 20 asked "
        "(the flight ends before contact)\n" == captured.err
    )
    assert "COLLISION      360x220       175" in captured.out


def test_sim_export_of_a_flight_longer_than_its_contact_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "hb"
    assert cli.main(["sim", "export", "HEADON-BOX", str(target), "--duration", "20"]) == 2
    err = capsys.readouterr().err
    assert err == (
        "tcm-companion sim export: error: argument --duration: HEADON-BOX lasts at most "
        "7.77 s (box centre reached at 8.57 s)\n"
    )
    assert not target.exists()


# -- set-up ----------------------------------------------------------------------------------
@pytest.mark.slow  # a subprocess
def test_pyproject_gives_setuptools_no_deprecation_warning() -> None:
    """The ``license = { text = ... }`` table made every install print setuptools'
    deprecation warnings; the SPDX string (PEP 639) does not (nor may a License classifier
    come back beside it)."""
    code = (
        "from setuptools.config.pyprojecttoml import apply_configuration\n"
        "from setuptools.dist import Distribution\n"
        "d = apply_configuration(Distribution(), 'pyproject.toml')\n"
        "print(d.metadata.license_expression)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-W", "always", "-c", code],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    assert "Deprecat" not in proc.stderr, proc.stderr
    assert proc.stdout.strip() == "MIT"


# -- a scenario without a file the command needs ------------------------------------------------
def test_eval_of_a_scenario_without_truth_is_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = tmp_path / "sc"
    shutil.copytree(EXAMPLE, sc)
    (sc / "truth.csv").unlink()
    out = tmp_path / "ev"
    assert cli.main(["eval", str(EXAMPLE), str(sc), "-q", "--out", str(out)]) == 2
    assert (
        capsys.readouterr().err
        == f"error: {sc}: no truth.csv: eval scores a scenario against its truth\n"
    )
    assert not out.exists()  # refused before evaluating the other scenario


@pytest.mark.parametrize("command", ["replay", "plot", "eval"])
def test_the_boxes_backend_without_detections_is_one_error_line(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = {
        "replay": ["replay", str(EXAMPLE), "--results", str(tmp_path / "r.csv"), "-q"],
        "plot": ["plot", str(EXAMPLE), "--out", str(tmp_path / "plots")],
        "eval": ["eval", str(EXAMPLE), "-q", "--out", str(tmp_path / "ev")],
    }[command]
    assert cli.main([*argv, "--set", "detection.backend=boxes"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {EXAMPLE}: no detections.csv")
    assert err.count("\n") == 1
    assert not any(tmp_path.iterdir())
