"""Per-input health — alive, rate OK, valid — from arrival times on an injected clock.

openpilot's ``SubMaster`` is the model: each input the daemon depends on (every camera,
the autopilot's attitude, its position) has an expected rate; an input is *alive* while
its newest message is younger than a time-out, *rate OK* while the rate over the last
window is at least a fraction of the expected one, and *valid* while its newest message
was usable (a NaN attitude arrives on time but is not valid). An input is *healthy*
when all three hold. Objects whose result needs an unhealthy input are reported
``unknown`` with the input's name as the reason.

What is wrong with an input is its *condition* (``missing``, ``stale``, ``invalid``,
``slow``; and ``waiting`` for an input that may come long after the start — the
autopilot's position waits for its EKF origin — and has not come yet: a start-up state,
not a fault); its *problem* is the condition as text, which may carry a number that changes
while the condition holds (``camera0 slow (8 Hz, expected 25)``). A condition is one
fault until it clears: :meth:`Inputs.changes` reports an input when its condition
changes, not when the number in its problem does.

Pure: times are arguments (µs on the companion's monotonic clock); nothing here reads
a clock.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True)
class InputSpec:
    """What the daemon expects of one input."""

    name: str  # e.g. "camera0", "attitude", "position"
    expected_hz: float
    timeout_us: int  # alive while the newest message is younger than this
    min_rate_fraction: float = 0.5  # rate OK at or above this fraction of expected_hz
    window_us: int = 2_000_000  # rate measured over this window
    required: bool = True  # an unhealthy optional input is reported but does not fault
    # May first arrive long after the start (position: the EKF origin takes seconds to
    # minutes): until then it is "waiting for NAME", a start-up state, not "missing".
    starts_late: bool = False

    def __post_init__(self) -> None:
        if not self.expected_hz > 0 or self.timeout_us <= 0 or self.window_us <= 0:
            raise ValueError(f"input {self.name}: rates, time-outs and windows must be > 0")
        if not 0.0 <= self.min_rate_fraction <= 1.0:
            raise ValueError(f"input {self.name}: min_rate_fraction must be in [0, 1]")


@dataclass(frozen=True)
class InputStatus:
    name: str
    alive: bool
    rate_ok: bool
    valid: bool
    rate_hz: float
    age_us: int | None  # since the newest message; None: never received
    expected_hz: float = 0.0  # the spec's rate (what "slow" is measured against)
    starts_late: bool = False  # the spec's: never received yet is "waiting", not "missing"

    @property
    def healthy(self) -> bool:
        return self.alive and self.rate_ok and self.valid

    @property
    def condition(self) -> str:
        """What is wrong, as one word that stays the same while it holds: ``missing``
        (``waiting`` for an input that starts late), ``stale``, ``invalid`` or ``slow``
        ("" when healthy)."""
        if self.age_us is None:
            return "waiting" if self.starts_late else "missing"
        if not self.alive:
            return "stale"
        if not self.valid:
            return "invalid"
        if not self.rate_ok:
            return "slow"
        return ""

    @property
    def problem(self) -> str:
        """Short reason for STATUSTEXT and ``unknown`` states ("" when healthy): the
        condition, and for ``slow`` the measured and the expected rate."""
        condition = self.condition
        if not condition:
            return ""
        if condition == "slow":
            return f"{self.name} slow ({self.rate_hz:.0f} Hz, expected {self.expected_hz:g})"
        if condition == "waiting":
            return f"waiting for {self.name}"
        return f"{self.name} {condition}"

    @property
    def fault(self) -> bool:
        """Whether the condition is a fault (counted, a warning); ``waiting`` is not."""
        return bool(self.condition) and self.condition != "waiting"


class InputMonitor:
    """Arrival times of one input; :meth:`status` judges them at a given time."""

    def __init__(self, spec: InputSpec, started_us: int) -> None:
        self.spec = spec
        self._started_us = started_us
        # The rate is judged one window after this: the start, or the first message
        # after the input was missing or stale. An input that (re)appears has not had a
        # window to show its rate in; judging it over time it was absent would report a
        # recovering input "slow" on its way back, a second fault for one condition.
        self._since_us = started_us
        # Enough arrivals for the window at twice the expected rate; older ones drop.
        maxlen = max(8, int(2 * spec.expected_hz * spec.window_us / 1e6) + 2)
        self._arrivals: deque[int] = deque(maxlen=maxlen)
        self._last_valid = True
        self.received = 0
        self.invalid = 0

    def update(self, t_us: int, valid: bool = True) -> None:
        """One message arrived at ``t_us``; ``valid`` says whether it was usable."""
        if self._arrivals and t_us < self._arrivals[-1]:
            # The clock the arrivals are stamped with never goes backwards; if a caller's
            # does, start the window over rather than compute a negative rate.
            self._arrivals.clear()
        if not self._arrivals or t_us - self._arrivals[-1] > self.spec.timeout_us:
            self._since_us = max(self._started_us, t_us)  # (re)appears
        self._arrivals.append(t_us)
        self._last_valid = valid
        self.received += 1
        if not valid:
            self.invalid += 1

    def status(self, now_us: int) -> InputStatus:
        spec = self.spec
        if not self._arrivals:
            return InputStatus(
                spec.name, False, False, False, 0.0, None, spec.expected_hz, spec.starts_late
            )
        age = now_us - self._arrivals[-1]
        alive = age <= spec.timeout_us
        lo = now_us - spec.window_us
        # Arrivals newer than lo. They are in time order (update() starts over when a
        # time goes back), so the count is a bisection, not a pass over up to
        # 2 × rate × window of them (the attitude's ~200, at every frame).
        n = len(self._arrivals) - bisect_right(self._arrivals, lo)
        # Before a whole window has passed since the start (or since the input came
        # back), measure over the time there was, and do not judge it yet.
        since = min(self._since_us, now_us)
        span_us = min(spec.window_us, max(now_us - since, 1))
        rate = n / (span_us / 1e6)
        warming = now_us - since < spec.window_us
        rate_ok = warming or rate >= spec.min_rate_fraction * spec.expected_hz
        valid = self._last_valid
        return InputStatus(
            spec.name, alive, rate_ok, valid, rate, age, spec.expected_hz, spec.starts_late
        )


class Inputs:
    """All monitored inputs of the daemon, with change detection for reporting."""

    def __init__(self, specs: list[InputSpec], started_us: int) -> None:
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError(f"input names must be unique, got {names}")
        self.monitors = {s.name: InputMonitor(s, started_us) for s in specs}
        self._last_condition: dict[str, str] = {}

    def update(self, name: str, t_us: int, valid: bool = True) -> None:
        self.monitors[name].update(t_us, valid)

    def status(self, now_us: int) -> dict[str, InputStatus]:
        return {name: m.status(now_us) for name, m in self.monitors.items()}

    def healthy(self, name: str, now_us: int) -> bool:
        return self.monitors[name].status(now_us).healthy

    def changes(self, now_us: int) -> list[tuple[str, str]]:
        """``(input, problem)`` for every input whose *condition* changed since the last
        call (:attr:`InputStatus.condition`; a slow input whose measured rate moves is
        still the same condition, and is not reported again); problem "" means it
        recovered. The first call reports only problems."""
        out = []
        for name, st in self.status(now_us).items():
            condition = st.condition
            if condition != self._last_condition.get(name, ""):
                out.append((name, st.problem))
            self._last_condition[name] = condition
        return out

    def condition(self, name: str) -> str:
        """``name``'s condition as of the last :meth:`changes` ("" healthy)."""
        return self._last_condition.get(name, "")
