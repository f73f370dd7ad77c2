"""Hooks for the whole suite. What test modules share is in tests/helpers.py."""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``tests/test_adversarial_*.py`` is the adversarial suite (issue 24's "Done when"):
    ``pytest -m adversarial`` (``make test-adversarial``) runs it alone."""
    for item in items:
        if item.path.name.startswith("test_adversarial_"):
            item.add_marker(pytest.mark.adversarial)
