"""TIMESYNC: the autopilot's boot clock on the companion's clock, filtered, sans-IO.

The companion sends ``TIMESYNC(tc1=0, ts1=t_send)``; the autopilot answers with its boot
time ``tc1`` and ``ts1`` echoed. With ``t_recv`` the arrival time, the offset
``companion - autopilot`` is ``(t_send + t_recv)/2 - tc1`` if the link is symmetric,
uncertain by half the round trip. Samples with a long round trip are the worst, so the
filter keeps recent samples and uses the median offset of those with the smallest round
trips (NTP's clock filter in miniature). A jump far beyond the round trip (the autopilot
rebooted, or its clock stepped) restarts the filter rather than being averaged in.

All times are integers: the companion clock in µs (whatever clock the caller uses
everywhere), autopilot boot time in ns as on the wire.

*Fresh.* An offset is used (the endpoint's ``time_boot_ms`` of our messages, the
pipeline's clock) and TIMESYNC counts as working (health flag TIMESYNC_LOST clear) while
its newest reply is younger than :data:`FRESH_US`: ten missed replies at the 1 Hz the
endpoint asks once synchronised. :meth:`TimesyncFilter.fresh` is that rule, the one
place it is written.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

#: A TIMESYNC offset is fresh while its newest reply is younger than this (µs).
FRESH_US = 10_000_000


@dataclass(frozen=True)
class TimesyncSample:
    offset_us: float  # companion - autopilot boot, µs
    rtt_us: int
    at_us: int  # companion time the reply arrived


class TimesyncFilter:
    """Offset estimate from request/reply pairs; exposes offset, round trip, resets."""

    def __init__(
        self,
        window: int = 16,
        best: int = 4,
        max_rtt_us: int = 200_000,
        jump_us: int = 50_000,
        max_age_us: int = 30_000_000,
        fresh_us: int = FRESH_US,
    ) -> None:
        self.window = window
        self.best = best
        self.max_rtt_us = max_rtt_us
        self.jump_us = jump_us
        self.max_age_us = max_age_us
        self.fresh_us = fresh_us
        self._samples: deque[TimesyncSample] = deque(maxlen=window)
        self._offset_us = math.nan
        self.last_rtt_us: int | None = None
        self.resets = 0
        self.rejected = 0

    @property
    def offset_us(self) -> float:
        """Companion clock minus autopilot boot clock (µs); NaN before the first reply."""
        return self._offset_us

    @property
    def synced(self) -> bool:
        return math.isfinite(self._offset_us)

    @property
    def n_samples(self) -> int:
        return len(self._samples)

    def age_us(self, now_us: int) -> float:
        return now_us - self._samples[-1].at_us if self._samples else math.inf

    def fresh(self, now_us: int) -> bool:
        """Synchronised, and the newest reply is younger than ``fresh_us`` at ``now_us``."""
        return self.synced and self.age_us(now_us) < self.fresh_us

    def would_restart(self, ts1_sent_us: int, tc1_remote_ns: int, now_us: int) -> bool:
        """Whether :meth:`add_reply` of this reply would restart the filter (its offset
        jumps), without taking it."""
        rtt = now_us - ts1_sent_us
        if rtt < 0 or rtt > self.max_rtt_us or tc1_remote_ns <= 0 or not self._samples:
            return False
        offset = (ts1_sent_us + now_us) / 2.0 - tc1_remote_ns / 1000.0
        return abs(offset - self._offset_us) > max(self.jump_us, 4 * rtt)

    def add_reply(self, ts1_sent_us: int, tc1_remote_ns: int, now_us: int) -> TimesyncSample | None:
        """Take one reply to our request sent at ``ts1_sent_us``; returns the sample if used."""
        rtt = now_us - ts1_sent_us
        if rtt < 0 or rtt > self.max_rtt_us or tc1_remote_ns <= 0:
            self.rejected += 1
            return None
        sample = TimesyncSample((ts1_sent_us + now_us) / 2.0 - tc1_remote_ns / 1000.0, rtt, now_us)
        self.last_rtt_us = rtt
        if self._samples and abs(sample.offset_us - self._offset_us) > max(self.jump_us, 4 * rtt):
            # A reboot or a clock step, not noise: start over from this sample.
            self._samples.clear()
            self.resets += 1
        while self._samples and now_us - self._samples[0].at_us > self.max_age_us:
            self._samples.popleft()
        self._samples.append(sample)
        fastest = sorted(self._samples, key=lambda s: s.rtt_us)[: self.best]
        offsets = sorted(s.offset_us for s in fastest)
        mid = len(offsets) // 2
        self._offset_us = (
            offsets[mid] if len(offsets) % 2 else 0.5 * (offsets[mid - 1] + offsets[mid])
        )
        return sample

    def to_autopilot_us(self, companion_us: float) -> float:
        """Autopilot boot time (µs) of a companion-clock instant (NaN until synced)."""
        return companion_us - self._offset_us

    def to_companion_us(self, autopilot_us: float) -> float:
        return autopilot_us + self._offset_us
