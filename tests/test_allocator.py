"""The allocator tuning the CLI applies (glibc mallopt)."""

from __future__ import annotations

import sys

import pytest

from tcm_companion.io.allocator import tune_allocator


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc only")
def test_tune_allocator_applies_on_linux() -> None:
    assert tune_allocator() is True
