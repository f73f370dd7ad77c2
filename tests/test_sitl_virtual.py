"""SITL in virtual time (sitl/virtual.py): the same results and flight-log bytes
every run, the accuracy floor, and what the simulated clock models.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.config import AppConfig
from tcm_companion.flightlog.reader import read_log, read_metadata
from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig
from tcm_companion.sitl.mock_flight import SitlReport, run_sitl, run_sitl_virtual
from tcm_companion.sitl.virtual import (
    VIRTUAL_START_MONO_US,
    VIRTUAL_UNIX_US_AT_START,
    VirtualTimeModel,
)

pytestmark = pytest.mark.slow  # whole SITL runs, seconds of CPU each, and the CLI in a subprocess


def _stable(lines: list[str]) -> list[str]:
    """The summary without what may differ between identical runs: the wall-clock speed
    and the log's directory (each run logs to its own)."""
    return [
        x.replace("/log-a/", "/log-X/").replace("/log-b/", "/log-X/")
        for x in lines
        if not x.startswith("  speed:")
    ]


def _log_bytes(directory: Path) -> list[bytes]:
    return [p.read_bytes() for p in sorted(directory.glob("*.mcap"))]


def test_two_runs_give_identical_results_and_flight_log_bytes(tmp_path: Path) -> None:
    reports: list[SitlReport] = []
    for run in ("a", "b"):
        reports.append(
            run_sitl_virtual(
                AppConfig(),
                duration_s=4.0,
                state_dir=str(tmp_path / f"state-{run}"),
                log_dir=str(tmp_path / f"log-{run}"),
            )
        )
    a, b = reports
    assert a.ok, a.lines()
    assert a.results_frames >= 4 * 25 - 2
    assert a.results_sha256 == b.results_sha256
    assert _stable(a.lines()) == _stable(b.lines())
    logs_a, logs_b = _log_bytes(tmp_path / "log-a"), _log_bytes(tmp_path / "log-b")
    assert logs_a and logs_a == logs_b  # byte for byte
    names = [sorted(p.name for p in (tmp_path / f"log-{r}").glob("*.mcap")) for r in "ab"]
    assert names[0] == names[1] and names[0][0].startswith("tcm-20240610-061320")
    assert a.log_sha256 == b.log_sha256
    # Its times are the simulation's: monotonic from VIRTUAL_START_MONO_US, Unix time
    # (the log's wall clock, log_time) from VIRTUAL_UNIX_US_AT_START.
    meta = read_metadata(tmp_path / "log-a")
    assert meta["started_utc"] == "2024-06-10T06:13:20Z"
    first = next(read_log(tmp_path / "log-a"))
    mono_us = first.publish_time_ns // 1000
    assert VIRTUAL_START_MONO_US <= mono_us < VIRTUAL_START_MONO_US + 4_000_000
    assert first.log_time_ns // 1000 - mono_us == VIRTUAL_UNIX_US_AT_START - VIRTUAL_START_MONO_US


def test_the_pipeline_and_the_links_take_modelled_time(tmp_path: Path) -> None:
    model = VirtualTimeModel(process_us=7_000, link_latency_us=2_000)
    report = run_sitl_virtual(AppConfig(), duration_s=3.0, state_dir=str(tmp_path), model=model)
    s = report.summary
    # Capture -> written: the pipeline's modelled 7 ms (frames are handed over at their
    # instant and never wait behind another one at 25 Hz).
    assert s.latency_percentile_ms(50) == pytest.approx(7.0)
    assert s.dropped <= 1 and s.frames_balance
    # The mock received each status a link latency after it was written.
    assert report.mock_status_received > 0 and report.mock_status_problems == 0
    assert "modelled: pipeline 7 ms, link 2 ms" in "\n".join(report.lines())


def test_a_slow_pipeline_drops_frames_behind_it(tmp_path: Path) -> None:
    """A pipeline that takes longer than a frame period: the loop is busy, the next frame
    waits in its slot and the one after replaces it (dropped, counted, flagged)."""
    model = VirtualTimeModel(process_us=70_000)
    report = run_sitl_virtual(
        AppConfig(), duration_s=3.0, state_dir=str(tmp_path), model=model, min_accuracy=None
    )
    s = report.summary
    assert s.frames_balance
    assert s.dropped >= 0.3 * s.captured and s.processed >= 0.3 * s.captured
    assert s.latency_percentile_ms(50) >= 70.0


def test_accuracy_below_the_floor_fails_the_run(tmp_path: Path) -> None:
    report = run_sitl_virtual(
        AppConfig(), duration_s=4.0, state_dir=str(tmp_path), min_accuracy=1.01
    )
    assert report.score.decided > 0
    assert not report.ok
    assert any("below the floor of 101%" in f for f in report.failures), report.failures
    assert "(floor 101%)" in "\n".join(report.lines())


def test_a_run_that_decides_nothing_says_so_and_fails(tmp_path: Path) -> None:
    # No link at all: no attitude, every object unknown.
    report = run_sitl_virtual(
        AppConfig(), duration_s=3.0, state_dir=str(tmp_path), link_up=lambda t_s: False
    )
    text = "\n".join(report.lines())
    assert report.score.decided == 0 and report.score.overdue > 0
    assert "no decision" in text and "nan" not in text
    assert any(f.startswith("no decision on") for f in report.failures), report.failures
    assert not report.ok


def test_a_run_too_short_to_decide_says_so_and_does_not_fail(tmp_path: Path) -> None:
    """The companion has T90's objects from about 1 s in (it waits for a position first):
    a 2-s run has frames after the 1-s warm-up, but had no object for the interval and
    the hold, so no decision is no failure (one scorer with eval made SITL's warm-up 1 s,
    not 2 s, and such runs failed)."""
    report = run_sitl_virtual(AppConfig(), duration_s=2.0, state_dir=str(tmp_path))
    assert report.score.decided == 0 and report.score.truth_after_warmup > 0
    assert report.score.overdue == 0
    assert "no decision" in "\n".join(report.lines())
    assert report.ok, report.failures


def test_a_run_that_processes_nothing_says_so_without_nan(tmp_path: Path) -> None:
    """A camera that delivers only empty images: every frame rejected, nothing processed.
    The live line and the summary say "n/a" and "no decision", never "nan"."""
    from tcm_companion.io.cameras.base import FrameSource
    from tcm_companion.sim.scene.truth_camera import SimulatedCamera

    class Blank(FrameSource):
        def __init__(self, inner: SimulatedCamera) -> None:
            super().__init__(inner.name, inner.width, inner.height)
            self.inner = inner

        def open(self) -> None:
            self.inner.open()

        def read(self) -> Any:
            _, t = self.inner.read()
            return None, t

        def close(self) -> None:
            self.inner.close()

    lines: list[str] = []
    report = run_sitl_virtual(
        AppConfig(),
        duration_s=3.0,
        state_dir=str(tmp_path),
        on_status=lines.append,
        camera_factory=lambda mock, model, **kw: Blank(SimulatedCamera.for_mock(model, mock, **kw)),
    )
    text = "\n".join(report.lines())
    assert report.summary.processed == 0 and report.summary.rejected > 0
    assert lines and all("latency n/a" in x and "nan" not in x for x in lines), lines
    assert "nan" not in text, text
    assert "latency capture->MAVLink: n/a" in text and "no decision" in text
    assert "states: none" in text
    assert "no frame was processed" in report.failures


def test_a_camera_set_to_10_fps_is_expected_at_10(tmp_path: Path) -> None:
    """[camera] fps reaches the simulated camera and the companion's input check: a
    10 Hz camera is not "slow" (it was, against a hard-coded 25 Hz)."""
    config = AppConfig()
    config = config.with_camera(
        dataclasses.replace(
            config.camera, source=dataclasses.replace(config.camera.source, fps=10.0)
        )
    )
    lines: list[str] = []
    report = run_sitl_virtual(
        config, duration_s=4.0, state_dir=str(tmp_path), on_status=lines.append
    )
    s = report.summary
    assert 4.0 * 10 - 2 <= s.processed <= 4.0 * 10 + 1  # the camera ran at 10 fps
    assert not [k for k in s.faults if k.startswith("camera0")], s.faults
    assert not [x for x in lines if "slow" in x], lines
    assert report.ok, report.lines()


def test_run_sitl_takes_the_virtual_clock_and_a_mock_of_its_own(tmp_path: Path) -> None:
    """A mock passed in sets the start of the simulated clock (any start works)."""
    start = 5_000_000_000
    mock = MockAutopilot(MockAutopilotConfig(scenario="COLLISION"), start)
    config = AppConfig()
    config = dataclasses.replace(config, sim=dataclasses.replace(config.sim, scenario="COLLISION"))
    report = asyncio.run(
        run_sitl(config, duration_s=3.0, state_dir=str(tmp_path), mock=mock, clock="virtual")
    )
    assert report.summary.processed >= 3 * 25 - 2
    assert min(r.recv_us for r in mock.received_status) >= start
    with pytest.raises(ValueError, match="virtual time runs its own"):
        asyncio.run(run_sitl(config, cameras=[], clock="virtual"))


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[Any]:
    # The persisted state (params.json) goes under cwd, never the user's own.
    env = {**os.environ, "XDG_STATE_HOME": str(cwd / "state")}
    env.pop("STATE_DIRECTORY", None)
    return subprocess.run(
        [sys.executable, "-m", "tcm_companion", "sitl", "--clock", "virtual", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
        env=env,
    )


#: The static TS ball judged with a threshold far below its disparity: all "moving".
_EVERYTHING_MOVES = (
    "--duration", "6", "--scenario", "TS", "--log-level", "WARNING",
    "--set", "classifier.method=tcm", "--set", "classifier.tcm_threshold=0.001",
)  # fmt: skip


def test_the_cli_exits_non_zero_below_the_accuracy_floor(tmp_path: Path) -> None:
    ok = _cli("--duration", "3", "--log-level", "ERROR", cwd=tmp_path)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "virtual clock" in ok.stdout and "(floor 90%)" in ok.stdout
    bad = _cli(*_EVERYTHING_MOVES, cwd=tmp_path)
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert "FAILED: accuracy 0.0% below the floor of 90%" in bad.stdout
    unjudged = _cli(*_EVERYTHING_MOVES, "--min-accuracy", "0", cwd=tmp_path)
    assert unjudged.returncode == 0 and "accuracy 0.0% of" in unjudged.stdout


def test_the_configuration_is_followed_unless_a_parameter_was_set(tmp_path: Path) -> None:
    """The parameter table started from its own defaults and overrode the configuration:
    tcm_threshold in config.toml (or --set) had no effect on run/sitl, and every run
    persisted every value, so later edits of the file were shadowed too, silently."""
    state = ("--set", f"daemon.state_dir={tmp_path / 'state'}")
    params = tmp_path / "state" / "params.json"
    run = _cli(*_EVERYTHING_MOVES, *state, "--min-accuracy", "0", cwd=tmp_path)
    assert "accuracy 0.0% of" in run.stdout, run.stdout  # the --set threshold is used
    assert json.loads(params.read_text()) == {}  # nothing was set over MAVLink
    # A value set over MAVLink (persisted) wins, and says that it shadows the file's.
    params.write_text(json.dumps({"TCM_THRESH": 0.09}))
    run = _cli(*_EVERYTHING_MOVES, *state, cwd=tmp_path)
    assert run.returncode == 0 and "accuracy 100.0% of" in run.stdout, run.stdout
    assert (
        "TCM_THRESH = 0.09 (set over MAVLink) overrides the configuration's"
        " [classifier] tcm_threshold = 0.001"
    ) in run.stderr
    assert json.loads(params.read_text()) == {"TCM_THRESH": 0.09}
