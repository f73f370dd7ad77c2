"""Every evidence script in tools/ answers ``--help`` with its usage, and runs nothing.

(Before, four of them started their study — minutes of CPU — or died on ``int("--help")``.)
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # every tool in a subprocess

TOOLS = sorted((Path(__file__).resolve().parent.parent / "tools").glob("*.py"))


@pytest.mark.parametrize("tool", TOOLS, ids=[t.stem for t in TOOLS])
def test_the_tool_answers_help_with_its_usage(tool: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(tool), "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(f"usage: {tool.name}"), done.stdout[:500]
