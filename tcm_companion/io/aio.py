"""asyncio helpers the daemon's tasks share: a cancellation-safe wait, and the clock they
stamp with and wait on.

:func:`wait_event` exists because of a CPython 3.11 bug in :func:`asyncio.wait_for`
(python/cpython gh-86296, fixed in 3.12 where ``wait_for`` is built on
:func:`asyncio.timeout`): when the awaited thing completes in the same loop iteration as
the waiting task is cancelled, ``wait_for`` returns the result and the cancellation is
lost. A task that waits for telemetry in a loop, and is cancelled at shutdown while
telemetry keeps arriving, then never ends — the daemon's ``TaskGroup`` waits for it
forever (seen in CI: a SITL run kept processing frames past its duration).
:func:`asyncio.timeout` uncancels only its own cancellation, so a stop is never lost.

:class:`MonotonicClock` is the companion's monotonic clock (µs, ``_mono_us``) as the
daemon uses it: every time stamp comes from :meth:`~MonotonicClock.now_us`, and every
wait is for an instant *of that clock* (:meth:`~MonotonicClock.wait_until`). The event
loop's own timers run on the same kernel clock, but uvloop's only to the millisecond and
from a time cached at the start of the loop iteration, so a timer can fire a little
before the instant it was computed for; each wait therefore re-reads this clock and
waits again until it has really reached the deadline. A caller that stamps with one
clock and sleeps on another (the daemon before issue 12) cannot be run on any other
clock; the virtual-time SITL (:mod:`tcm_companion.sitl.virtual`) drives the same
sans-IO :class:`~tcm_companion.service.companion.Companion` without asyncio instead.
"""

from __future__ import annotations

import asyncio
import time
from typing import Protocol


async def wait_event(event: asyncio.Event, timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` for ``event``; True if it was set, False on time-out.

    A cancellation of the calling task always propagates (unlike ``asyncio.wait_for``
    on Python 3.11; see the module docstring).
    """
    try:
        async with asyncio.timeout(timeout_s):
            await event.wait()
    except TimeoutError:
        return False
    return True


def monotonic_us() -> int:
    """The companion monotonic clock (µs): ``time.monotonic_ns() // 1000``."""
    return time.monotonic_ns() // 1000


class LoopClock(Protocol):
    """A clock an asyncio task stamps with and waits on (µs)."""

    def now_us(self) -> int: ...

    async def wait_until(self, event: asyncio.Event | None, deadline_us: int) -> bool: ...


class MonotonicClock:
    """The companion monotonic clock for asyncio tasks: stamps and waits on one clock."""

    def now_us(self) -> int:
        return monotonic_us()

    async def wait_until(self, event: asyncio.Event | None, deadline_us: int) -> bool:
        """Until ``event`` is set (True) or this clock reaches ``deadline_us`` (False).

        An event already set returns True at once; the caller clears it.
        """
        while True:
            if event is not None and event.is_set():
                return True
            remaining_us = deadline_us - self.now_us()
            if remaining_us <= 0:
                return False
            if event is None:
                await asyncio.sleep(remaining_us / 1e6)
            elif await wait_event(event, remaining_us / 1e6):
                return True


MONOTONIC = MonotonicClock()
