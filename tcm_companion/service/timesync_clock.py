"""The clock the Companion's pipelines use: autopilot boot time to companion monotonic
time, from TIMESYNC while it is fresh and from the telemetry otherwise."""

from __future__ import annotations

import math

from ..core.telemetry import ClockSync
from ..mavlink.endpoint import CompanionEndpoint


class TimesyncClock(ClockSync):
    """The pipeline's autopilot-boot-to-companion-monotonic clock, on TIMESYNC while fresh.

    :class:`~tcm_companion.core.telemetry.ClockSync` fits the lower envelope of
    ``receive time (_mono_us) - boot time (_boot_us)`` of the telemetry, which leaves the
    link's smallest one-way latency in the offset (a fraction of a ms on UDP; on a USB
    serial adapter with its latency timer, ms). TIMESYNC measures the offset with the
    round trip and halves it, which removes that bias. This clock uses TIMESYNC's offset
    when the endpoint has a fresh one that agrees with the telemetry fit to within
    ``agree_us`` (so an autopilot reboot, seen first by one of them, never mixes two boot
    clocks), and the telemetry fit otherwise. Process replay forces the offset the live
    pipeline used (:meth:`forced`).
    """

    def __init__(self, endpoint: CompanionEndpoint, agree_us: int = 50_000) -> None:
        super().__init__()
        self.endpoint = endpoint
        self.agree_us = agree_us
        self._last_recv_mono_us = 0
        self._forced_us: float | None = None
        self.used_timesync = False

    def observe(self, boot_us: int, recv_us: int) -> None:
        super().observe(boot_us, recv_us)
        self._last_recv_mono_us = max(self._last_recv_mono_us, int(recv_us))

    def force(self, offset_us: float | None) -> None:
        """Use ``offset_us`` (µs, companion monotonic minus autopilot boot) until
        ``force(None)``; a non-finite value forces nothing."""
        self._forced_us = (
            float(offset_us) if offset_us is not None and math.isfinite(offset_us) else None
        )

    @property
    def offset_us(self) -> float:
        if self._forced_us is not None:
            return self._forced_us
        fit = super().offset_us
        ts = self.endpoint.timesync
        if (
            ts.fresh(self._last_recv_mono_us)
            and math.isfinite(fit)
            and abs(ts.offset_us - fit) < self.agree_us
        ):
            self.used_timesync = True
            return float(ts.offset_us)
        self.used_timesync = False
        return fit
