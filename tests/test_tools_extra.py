"""matplotlib and tqdm are the ``tools`` extra: without them the drone's install still
replays with progress and says how to get the plots (issue 12 §5)."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest

from tcm_companion.cli import main
from tcm_companion.io.progress import progress, track

EXAMPLE = Path(__file__).parent / "data" / "examples" / "EX-PINHOLE"


def _without(monkeypatch: pytest.MonkeyPatch, *names: str, forget: tuple[str, ...] = ()) -> None:
    """As if ``names`` were not installed; ``forget``: modules to import afresh."""
    for mod in list(sys.modules):
        if any(mod == n or mod.startswith(n + ".") for n in (*names, *forget)):
            monkeypatch.delitem(sys.modules, mod)
    for n in names:
        monkeypatch.setitem(sys.modules, n, None)  # import n -> ImportError


def test_progress_without_tqdm_prints_plain_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    _without(monkeypatch, "tqdm")
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    assert list(track(range(20), 20, "replay")) == list(range(20))
    lines = err.getvalue().splitlines()
    assert len(lines) == 10 and lines[0].startswith("replay: 10% (2/20 frames")
    assert lines[-1].startswith("replay: 100% (20/20 frames")
    with progress(5, "x", enabled=False) as bar:  # -q: nothing at all
        bar.update(5)


@pytest.mark.slow  # over half a second of CPU
def test_replay_without_tqdm(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _without(monkeypatch, "tqdm")
    assert main(["replay", str(EXAMPLE), "--results", str(tmp_path / "r.csv")]) == 0
    assert "EX-PINHOLE: 100%" in capsys.readouterr().err


def test_plot_without_matplotlib_says_how_to_get_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _without(monkeypatch, "matplotlib", forget=("tcm_companion.logtools.plot",))
    assert main(["plot", str(EXAMPLE), "--out", str(tmp_path / "plots")]) == 2
    err = capsys.readouterr().err
    assert "matplotlib is not installed" in err and "tcm-companion[tools]" in err
