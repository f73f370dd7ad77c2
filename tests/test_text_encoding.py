"""Text files that are not UTF-8 are refused in one line naming the file, line and byte
(issue 13: a config or scenario file in another encoding crashed with a traceback)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tcm_companion.config import ConfigError, load_config
from tcm_companion.io.scenario import ScenarioError, load_scenario

EXAMPLE = Path(__file__).parent / "data" / "examples" / "EX-PINHOLE"


def test_config_not_utf8_names_file_line_and_byte(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_bytes(b'[classifier]\nmethod = "tcm"\n# caf\xe9 latin-1\n')
    with pytest.raises(ConfigError) as err:
        load_config(p)
    assert str(err.value) == f"{p}: line 3: not UTF-8 text (byte 0xe9 at offset 33)"


@pytest.mark.parametrize("name", ["scenario.toml", "frames.csv", "truth.csv"])
def test_scenario_file_not_utf8_names_file_and_line(tmp_path: Path, name: str) -> None:
    sc = tmp_path / "sc"
    shutil.copytree(EXAMPLE, sc)
    f = sc / name
    if not f.exists():
        pytest.skip(f"the example has no {name}")
    data = f.read_bytes()
    f.write_bytes(data + b"# \xff\n")
    line = data.count(b"\n") + 1
    with pytest.raises(ScenarioError) as err:
        load_scenario(sc)
    assert str(err.value).startswith(f"{f}: line {line}: not UTF-8 text (byte 0xff")


@pytest.mark.slow  # a subprocess
def test_cli_says_one_line_not_a_traceback(tmp_path: Path) -> None:
    p = tmp_path / "c.toml"
    p.write_bytes(b"x = 1 # \xff\n")
    proc = subprocess.run(
        [sys.executable, "-m", "tcm_companion", "config", "check", str(p)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert (
        proc.stderr.strip() == f"config error: {p}: line 1: not UTF-8 text (byte 0xff at offset 8)"
    )
