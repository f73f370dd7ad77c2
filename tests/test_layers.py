"""Imports point only down the layers (issue 12 §3): ``lint-imports`` keeps the contract of
pyproject.toml's ``[tool.importlinter]``, and a deliberate upward import breaks it.

The layers, bottom to top: core, mavlink, io | flightlog, sim, service, then the
application (config, flight_log_setup, replay | sitl, bench | eval | logtools, cli). The linter
reads the source (nothing is imported), lazy imports inside functions and imports under
``TYPE_CHECKING`` included.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # lint-imports in a subprocess

ROOT = Path(__file__).resolve().parents[1]


def lint_imports(cwd: Path, pythonpath: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on ``cwd``'s pyproject.toml, its package found first in ``pythonpath``."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert exe is not None, "lint-imports is missing: the dev extra installs import-linter"
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    return subprocess.run(
        [exe, "--no-cache"],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_imports_point_only_down_the_layers() -> None:
    proc = lint_imports(ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "1 kept, 0 broken" in proc.stdout


@pytest.mark.parametrize(
    "upward",
    [
        # a lazy import in a function body, as the code base does for heavy modules
        "\n\ndef _probe() -> object:\n    from ..service import daemon\n\n    return daemon\n",
        # an import for the type checker only
        "\nfrom typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from ..service import daemon\n",
    ],
    ids=["lazy", "type_checking"],
)
def test_an_upward_import_breaks_the_contract(tmp_path: Path, upward: str) -> None:
    """A copy of the package whose MAVLink codec imports the daemon (layer 2 -> layer 5)."""
    shutil.copytree(
        ROOT / "tcm_companion",
        tmp_path / "tcm_companion",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    codec = tmp_path / "tcm_companion" / "mavlink" / "codec.py"
    codec.write_text(codec.read_text() + upward)
    proc = lint_imports(tmp_path, pythonpath=tmp_path)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "0 kept, 1 broken" in proc.stdout
    assert "tcm_companion.mavlink.codec -> tcm_companion.service.daemon" in proc.stdout
