"""Shared fixtures: paths to the independent example scenarios.

The three examples of shared/examples (rendered by code outside this project) are
vendored under tests/data/examples so that CI checks our reader against them too.
"""

from __future__ import annotations

from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent / "data" / "examples"
EXAMPLE_NAMES = ("EX-T90", "EX-PINHOLE", "EX-FISHEYE")


def example_path(name: str) -> Path:
    path = EXAMPLES / name
    if not path.is_dir():
        pytest.skip(f"example scenarios not found at {EXAMPLES}")
    return path


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``tests/test_adversarial_*.py`` is the adversarial suite (issue 24's "Done when"):
    ``pytest -m adversarial`` (``make test-adversarial``) runs it alone."""
    for item in items:
        if item.path.name.startswith("test_adversarial_"):
            item.add_marker(pytest.mark.adversarial)
