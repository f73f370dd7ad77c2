"""``tcm-companion run`` and ``sitl`` as a user meets them: the live status line and log
records on a terminal, ``--status-every``, ``--duration``, and what SIGINT/SIGTERM make
of the summary and the exit status.

The commands run in this process (their ``func``, as ``main`` calls it). A signal is
raised by the command's own status line — at its N-th update, an event, not a time —
so no test waits on the clock; virtual time where the clock is not the point.
"""

from __future__ import annotations

import io
import logging
import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tcm_companion import cli
from tcm_companion.cli import sitl as sitl_cli
from tcm_companion.cli import status_line
from tcm_companion.cli.interrupts import RunSignals
from tcm_companion.service.host import run_length_text


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """No ./config.toml, no TCM_COMPANION__ variables: the built-in defaults."""
    monkeypatch.chdir(tmp_path)
    for name in list(os.environ):
        if name.startswith("TCM_COMPANION__"):
            monkeypatch.delenv(name)


def command(*argv: str) -> int:
    args = cli.build_parser().parse_args(list(argv))
    return int(args.func(args))


def signal_at_status(monkeypatch: pytest.MonkeyPatch, sig: signal.Signals, n: int) -> list[str]:
    """The command's status line raises ``sig`` at its ``n``-th update; the updates."""
    seen: list[str] = []
    real = status_line.StatusPrinter.__call__

    def call(self: status_line.StatusPrinter, line: str) -> None:
        real(self, line)
        seen.append(line)
        if len(seen) == n:
            signal.raise_signal(sig)

    monkeypatch.setattr(status_line.StatusPrinter, "__call__", call)
    return seen


# -- the status line and log records ----------------------------------------------------------
class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def screen(text: str) -> list[str]:
    """What a terminal shows after ``text``: \\r to the line's start, ESC[2K clears it."""
    rows, col = [""], 0
    for token in re.split(r"(\r|\n|\x1b\[2K)", text):
        if token == "\r":
            col = 0
        elif token == "\n":
            rows.append("")
            col = 0
        elif token == "\x1b[2K":
            rows[-1] = ""
        elif token:
            row = rows[-1]
            rows[-1] = row[:col] + token + row[col + len(token) :]
            col += len(token)
    return rows


@pytest.fixture
def root_handler() -> Iterator[tuple[logging.Logger, FakeTerminal]]:
    """A terminal the root logger writes to (as ``setup_logging`` does to stderr)."""
    term = FakeTerminal()
    root = logging.getLogger()
    handler = logging.StreamHandler(term)
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    before = list(root.handlers), root.level
    root.handlers = [handler]
    root.setLevel(logging.INFO)
    try:
        yield root, term
    finally:
        root.handlers, level = before
        root.setLevel(level)


def test_log_records_go_above_the_live_line_on_a_terminal(
    root_handler: tuple[logging.Logger, FakeTerminal],
) -> None:
    root, term = root_handler
    printer = status_line.StatusPrinter(stream=term)
    with printer.logs_above():
        printer("objects 1 (1 moving) | 25.0 fps")
        logging.getLogger("tcm_companion.x").warning("input camera0: camera0 stale")
        logging.getLogger("tcm_companion.x").info("input camera0: OK")
        printer("objects 0 (none) | 0.0 fps")
    assert screen(term.getvalue()) == [
        "WARNING input camera0: camera0 stale",
        "INFO input camera0: OK",
        "objects 0 (none) | 0.0 fps",
        "",
    ]
    # Afterwards the handler is the logger's own again.
    assert root.handlers and isinstance(root.handlers[0], logging.StreamHandler)
    assert not isinstance(root.handlers[0], status_line.AboveStatusLine)


def test_the_live_line_fits_one_row_and_plain_output_gets_every_nth(
    root_handler: tuple[logging.Logger, FakeTerminal],
) -> None:
    _, term = root_handler
    printer = status_line.StatusPrinter(stream=term)
    printer._width = lambda: 30  # type: ignore[method-assign]
    printer("x" * 100)
    assert screen(term.getvalue()) == ["x" * 30]
    pipe = io.StringIO()
    plain = status_line.StatusPrinter(stream=pipe, every=2)
    for k in range(5):
        plain(f"line {k}")
    assert pipe.getvalue() == "line 0\nline 2\nline 4\n"


@pytest.mark.slow  # over half a second of CPU
def test_status_every_0_means_no_status_line(capsys: pytest.CaptureFixture[str]) -> None:
    """It divided by zero; now there is no status line (and negative is refused)."""
    code = command("sitl", "--clock", "virtual", "--duration", "1.5", "--status-every", "0",
                   "--log-level", "ERROR")  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert "SITL T90: 1.5 s, virtual clock" in out
    assert "fps" not in err and "fps" not in out
    with status_line.status_printer(0) as printer:
        assert printer is None
    with pytest.raises(SystemExit):
        command("sitl", "--status-every", "-1")
    assert "0: no status line" in capsys.readouterr().err


# -- --duration -------------------------------------------------------------------------------
@pytest.mark.parametrize("cmd", ["sitl", "run"])
@pytest.mark.parametrize("value", ["0", "-5", "nan", "inf", "soon"])
def test_a_non_positive_duration_is_refused(
    cmd: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args([cmd, "--duration", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --duration: must be a" in err and f"got '{value}'" in err
    args = cli.build_parser().parse_args([cmd, "--duration", "0.5"])
    assert args.duration == 0.5


@pytest.mark.parametrize("value", ["150", "-5", "nan", "most"])
def test_min_accuracy_is_a_percentage(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    """-5 silently meant "not judged" and 150 failed every run."""
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args(["sitl", "--min-accuracy", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument --min-accuracy: must be a percentage in [0, 100], got '{value}'" in err
    for ok in ("0", "97.5", "100"):
        assert cli.build_parser().parse_args(["sitl", "--min-accuracy", ok]).min_accuracy == float(
            ok
        )


# -- signals ----------------------------------------------------------------------------------
def test_how_a_run_ended_reads() -> None:
    assert run_length_text(20.0, 20.0) == "20.0 s"
    assert run_length_text(7.0, 30.0, "SIGINT") == "interrupted after 7.0 of 30 s (SIGINT)"
    assert run_length_text(7.0, 2.5, "SIGTERM") == "interrupted after 7.0 of 2.5 s (SIGTERM)"
    assert run_length_text(7.0, None, "SIGTERM") == "stopped after 7.0 s (SIGTERM)"
    assert run_length_text(7.0, None, "SIGINT") == "interrupted after 7.0 s (SIGINT)"
    assert run_length_text(4.0, 60.0, "stop") == "stopped after 4.0 of 60 s"
    status = RunSignals.exit_status
    assert status(True, "") == 0 and status(False, "") == 1
    assert status(True, "SIGINT") == 130 and status(False, "SIGINT") == 130
    assert status(True, "SIGTERM") == 143
    assert status(True, "SIGTERM", service=True) == 0  # systemd's stop
    assert status(True, "SIGINT", service=True) == 130


@pytest.mark.slow  # over a second of CPU
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_sitl_in_virtual_time_cut_short_by_a_signal_says_so(
    sig: signal.Signals,
    code: int,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    signal_at_status(monkeypatch, sig, 3)  # 3 s of simulated time
    before = signal.getsignal(sig)
    rc = command("sitl", "--clock", "virtual", "--duration", "30", "--log-level", "ERROR")
    out = capsys.readouterr().out
    assert rc == code, out
    assert out.startswith(f"SITL T90: interrupted after 3.0 of 30 s ({sig.name}), virtual clock")
    assert signal.getsignal(sig) == before  # the handler is put back


@pytest.mark.xdist_group("sitl")  # real-time SITL: one at a time
def test_sitl_in_real_time_cut_short_by_sigint_says_so(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    signal_at_status(monkeypatch, signal.SIGINT, 1)
    rc = command("sitl", "--duration", "30", "--log-level", "ERROR")
    out = capsys.readouterr().out
    assert rc == 130, out
    assert re.match(r"SITL T90: interrupted after \d+\.\d of 30 s \(SIGINT\), real clock", out), out
    assert "(balanced)" in out


def _frames(directory: Path) -> Path:
    import cv2

    directory.mkdir()
    for k in range(5):
        cv2.imwrite(str(directory / f"{k:04d}.png"), np.full((220, 360, 3), 60 + k, np.uint8))
    return directory


def _run_args(tmp_path: Path, *extra: str) -> tuple[str, ...]:
    """``run`` on a looping directory of frames, no autopilot on the link."""
    sets = {
        "camera.source": "frames",
        "camera.path": str(_frames(tmp_path / "frames")),
        "camera.loop": "true",
        "logging.enabled": "false",
        "daemon.state_dir": str(tmp_path / "state"),
        "mavlink.url": "udpout:127.0.0.1:9",  # discard: nobody answers
    }
    pairs = [x for k, v in sets.items() for x in ("--set", f"{k}={v}")]
    return ("run", *pairs, "--log-level", "ERROR", *extra)


@pytest.mark.xdist_group("sitl")
@pytest.mark.parametrize(
    ("sig", "extra", "code", "said"),
    [
        (signal.SIGINT, (), 130, "interrupted after {} s (SIGINT)"),
        (signal.SIGTERM, ("--duration", "30"), 0, "interrupted after {} of 30 s (SIGTERM)"),
        (signal.SIGTERM, (), 0, "stopped after {} s (SIGTERM)"),
    ],
)
def test_run_stopped_by_a_signal(
    sig: signal.Signals,
    extra: tuple[str, ...],
    code: int,
    said: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The service: SIGTERM (systemd's stop) exits 0, SIGINT (Ctrl-C) 130; the summary
    says which ended it."""
    signal_at_status(monkeypatch, sig, 1)
    rc = command(*_run_args(tmp_path, *extra))
    out = capsys.readouterr().out
    assert rc == code, out
    pattern = re.escape(said).replace(re.escape("{}"), r"\d+\.\d")
    assert re.match(pattern + ": captured", out), out


@pytest.mark.xdist_group("sitl")
def test_run_for_its_duration_exits_0(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = command(*_run_args(tmp_path, "--duration", "1", "--status-every", "0"))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert re.match(r"stopped after \d+\.\d s: captured \d+", out) and "SIG" not in out, out


def test_ctrl_c_before_the_run_starts_is_one_line_and_130(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def interrupted(*a: Any, **k: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(sitl_cli, "config_from_args", interrupted)
    assert command("sitl", "--clock", "virtual") == 130
    assert capsys.readouterr().err.strip() == "interrupted (SIGINT)"


@pytest.mark.xdist_group("sitl")
def test_run_with_the_simulator_writes_its_summary_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run --summary-json`` with ``[camera] source = "sim"`` (the repository's
    config.toml) flies the mock autopilot in-process; the summary was silently not
    written (exit 0, no file)."""
    import json

    where = tmp_path / "summary.json"
    rc = command(
        *("run", "--duration", "2", "--status-every", "0", "--log-level", "ERROR"),
        *("--set", "camera.source=sim", "--set", "logging.enabled=false"),
        *("--set", f"daemon.state_dir={tmp_path / 'state'}", "--summary-json", str(where)),
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    doc = json.loads(where.read_text())
    assert doc["processed"] > 0 and doc["frames_balance"] is True, doc
