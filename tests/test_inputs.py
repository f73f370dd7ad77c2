"""Per-input health (alive, rate OK, valid) on an injected clock."""

from __future__ import annotations

import pytest

from tcm_companion.service.inputs import Inputs, InputSpec

T0 = 1_000_000_000


def feed(inputs: Inputs, name: str, hz: float, t0: int, t1: int, valid: bool = True) -> int:
    step = int(1e6 / hz)
    t = t0
    while t < t1:
        inputs.update(name, t, valid)
        t += step
    return t


def test_missing_then_healthy_then_stale() -> None:
    inputs = Inputs([InputSpec("attitude", 50.0, 200_000)], T0)
    st = inputs.status(T0 + 100_000)["attitude"]
    assert not st.healthy and st.problem == "attitude missing" and st.age_us is None
    t = feed(inputs, "attitude", 50.0, T0, T0 + 3_000_000)
    st = inputs.status(t)["attitude"]
    assert st.healthy and st.problem == "" and 45 <= st.rate_hz <= 55
    st = inputs.status(t + 250_000)["attitude"]
    assert not st.alive and st.problem == "attitude stale"


def test_slow_rate_is_reported_after_the_first_window() -> None:
    inputs = Inputs([InputSpec("camera0", 25.0, 500_000)], T0)
    t = feed(inputs, "camera0", 10.0, T0, T0 + 1_000_000)
    # Within the first window the rate is not judged (start-up).
    assert inputs.status(t)["camera0"].rate_ok
    t = feed(inputs, "camera0", 10.0, t, T0 + 4_000_000)
    st = inputs.status(t)["camera0"]
    assert st.alive and not st.rate_ok and st.problem.startswith("camera0 slow (10 Hz")


def test_invalid_messages_make_the_input_unhealthy_until_a_valid_one() -> None:
    inputs = Inputs([InputSpec("attitude", 50.0, 200_000)], T0)
    t = feed(inputs, "attitude", 50.0, T0, T0 + 2_500_000)
    inputs.update("attitude", t, valid=False)
    assert inputs.status(t)["attitude"].problem == "attitude invalid"
    inputs.update("attitude", t + 20_000, valid=True)
    assert inputs.status(t + 20_000)["attitude"].healthy
    assert inputs.monitors["attitude"].invalid == 1


def test_changes_reports_each_transition_once() -> None:
    inputs = Inputs([InputSpec("attitude", 50.0, 200_000), InputSpec("camera0", 25, 500_000)], T0)
    t = feed(inputs, "attitude", 50.0, T0, T0 + 2_500_000)
    feed(inputs, "camera0", 25.0, T0, T0 + 2_500_000)
    assert inputs.changes(t) == []  # healthy from the start: nothing to say
    assert inputs.changes(t + 300_000) == [("attitude", "attitude stale")]
    assert inputs.changes(t + 310_000) == []  # said once
    t2 = feed(inputs, "attitude", 50.0, t + 320_000, t + 3_000_000)
    feed(inputs, "camera0", 25.0, t + 320_000, t + 3_000_000)
    assert inputs.changes(t2) == [("attitude", "")]  # recovered


def test_clock_going_backwards_restarts_the_window() -> None:
    inputs = Inputs([InputSpec("attitude", 50.0, 200_000)], T0)
    feed(inputs, "attitude", 50.0, T0, T0 + 2_500_000)
    inputs.update("attitude", T0, True)  # a caller's clock stepped back
    st = inputs.status(T0 + 10_000)["attitude"]
    assert st.alive and st.rate_hz >= 0


def test_bad_specs_are_refused() -> None:
    with pytest.raises(ValueError, match="rates"):
        InputSpec("x", 0.0, 1)
    with pytest.raises(ValueError, match="unique"):
        Inputs([InputSpec("x", 1, 1), InputSpec("x", 1, 1)], T0)


def test_a_slow_input_is_one_condition_while_its_rate_moves() -> None:
    """The problem text follows the measured rate; the change (what is counted, announced
    and clears objects) is reported once, and again only when it clears."""
    inputs = Inputs([InputSpec("camera0", 25.0, 500_000)], T0)
    t = feed(inputs, "camera0", 25.0, T0, T0 + 2_500_000)
    assert inputs.changes(t) == []
    seen: list[str] = []
    reported: list[tuple[str, str]] = []
    t = feed(inputs, "camera0", 8.0, t, t + 2_000_000)  # the window is all slow now
    for hz in (7.0, 9.0, 11.0, 8.0, 6.0, 12.0):  # then a second each, jittering
        t = feed(inputs, "camera0", hz, t, t + 1_000_000)
        seen.append(inputs.status(t)["camera0"].problem)
        reported += inputs.changes(t)
    assert len(set(seen)) >= 3  # the number moves ...
    assert reported == [("camera0", seen[0])]  # ... the condition is reported once
    assert all(p.startswith("camera0 slow (") and p.endswith(" Hz, expected 25)") for p in seen)
    assert inputs.condition("camera0") == "slow"
    t = feed(inputs, "camera0", 25.0, t, t + 2_500_000)
    assert inputs.changes(t) == [("camera0", "")] and inputs.condition("camera0") == ""


def test_a_condition_that_changes_kind_is_reported() -> None:
    inputs = Inputs([InputSpec("camera0", 25.0, 500_000)], T0)
    t = feed(inputs, "camera0", 8.0, T0, T0 + 3_000_000)
    assert inputs.changes(t) == [("camera0", inputs.status(t)["camera0"].problem)]
    assert inputs.changes(t + 600_000) == [("camera0", "camera0 stale")]  # worse: new


def test_an_input_that_comes_back_is_not_slow_on_its_way_back() -> None:
    """Position appears 3 s after start (the EKF origin), a camera comes back after 1.5 s
    away: each is judged on its rate only a window after it (re)appeared, so the
    condition goes missing/stale -> OK, not -> "slow (0 Hz)" -> OK (a second fault)."""
    inputs = Inputs([InputSpec("position", 10.0, 1_000_000), InputSpec("camera0", 25, 500_000)], T0)
    feed(inputs, "camera0", 25.0, T0, T0 + 3_000_000)
    assert inputs.changes(T0 + 1_000_000) == [("position", "position missing")]
    reported: list[tuple[str, str]] = []
    t = T0 + 3_000_000
    # Position from 3 s on; the camera away from 3 s to 4.5 s, then back.
    for k in range(1, 9):
        now = t + k * 1_000_000
        feed(inputs, "position", 10.0, now - 1_000_000, now)
        if now > T0 + 4_500_000:
            feed(inputs, "camera0", 25.0, max(now - 1_000_000, T0 + 4_500_000), now)
        reported += inputs.changes(now)
    assert reported == [("position", ""), ("camera0", "camera0 stale"), ("camera0", "")]
