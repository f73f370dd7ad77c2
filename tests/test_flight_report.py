"""The ArduPilot SITL flight report's own arithmetic (no SITL needed)."""

from __future__ import annotations

import pytest

from tcm_companion.sitl.ardupilot import _sitl_clock


def test_sitl_clock_rate_and_how_far_it_fell_behind() -> None:
    # In step with us for 1 s, then half speed for 1 s (a starved SITL): 0.75x overall,
    # 0.5 s behind at the end.
    samples = [(10.0 + 0.1 * k, 5000 + 100 * k) for k in range(11)]
    samples += [(11.0 + 0.1 * k, 6000 + 50 * k) for k in range(1, 11)]
    rate, behind = _sitl_clock(samples) or (0.0, 0.0)
    assert rate == pytest.approx(0.75)
    assert behind == pytest.approx(0.5)
    # A clock running ahead is never "behind"; too few samples tell nothing.
    rate, behind = _sitl_clock([(0.0, 0), (1.0, 1100)]) or (0.0, 1.0)
    assert rate == pytest.approx(1.1) and behind == pytest.approx(0.0)
    assert _sitl_clock([(0.0, 0)]) is None and _sitl_clock([(1.0, 0), (1.0, 10)]) is None
