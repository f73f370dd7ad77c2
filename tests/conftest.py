"""Hooks for the whole suite. What test modules share is in tests/helpers.py.

Which tests are ``slow`` (left out of ``make test-fast``; ``make test`` runs everything):
a test that runs in real time, starts a subprocess (the CLI, socat, MAVProxy, ArduCopter
SITL) or takes more than about half a second of CPU (a rendered or replayed flight, a
long property test). Marked so by the rules below, or by ``pytest.mark.slow`` in its
module (``pytestmark``) or on the test with a comment saying which of these it is.
"""

from __future__ import annotations

import pytest
from hypothesis import settings

# No per-example deadline: it measures the machine's load, not the code (a property test
# on a busy two-core machine tripped hypothesis's 200 ms). Slow examples still show in
# --durations and in the fast lane's time.
settings.register_profile("tcm", deadline=None)
settings.load_profile("tcm")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``tests/test_adversarial_*.py`` is the adversarial suite (issue 24's "Done when"):
    ``pytest -m adversarial`` (``make test-adversarial``) runs it alone. Slow: it runs the
    CLI in subprocesses, signals them mid-write, fills disks and floods links.

    A test in the xdist group "sitl" runs in real time (one at a time on two cores): slow.
    """
    for item in items:
        if item.path.name.startswith("test_adversarial_"):
            item.add_marker(pytest.mark.adversarial)
            item.add_marker(pytest.mark.slow)
        group = item.get_closest_marker("xdist_group")
        if group is not None and group.args and group.args[0] == "sitl":
            item.add_marker(pytest.mark.slow)
