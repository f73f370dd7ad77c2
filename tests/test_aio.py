"""wait_event: a stop (task cancellation) is never lost, even when the event fires in the
same loop iteration — the Python 3.11 ``asyncio.wait_for`` race that hung a SITL run."""

from __future__ import annotations

import asyncio

import pytest

from tcm_companion.io.aio import wait_event


async def _waits_in_a_loop(event: asyncio.Event, wakes: list[bool]) -> None:
    # The shape of the daemon's frame loop: wait for telemetry with a deadline, again and again.
    while True:
        event.clear()
        wakes.append(await wait_event(event, 1.0))


@pytest.mark.parametrize("ticks_between_set_and_cancel", [0, 1, 2, 3])
def test_a_cancel_that_races_the_event_still_ends_the_task(
    ticks_between_set_and_cancel: int,
) -> None:
    async def go() -> str:
        event = asyncio.Event()
        wakes: list[bool] = []
        task = asyncio.create_task(_waits_in_a_loop(event, wakes))
        for _ in range(3):
            await asyncio.sleep(0)
        event.set()
        for _ in range(ticks_between_set_and_cancel):
            await asyncio.sleep(0)
        task.cancel()
        try:
            async with asyncio.timeout(0.5):
                await asyncio.shield(task)
        except asyncio.CancelledError:
            return "cancelled"
        except TimeoutError:
            task.cancel()  # the cancel was swallowed; do not leak the task
            with pytest.raises(asyncio.CancelledError):
                await task
            return "still running after cancel"
        return "returned"

    assert asyncio.run(go()) == "cancelled"


def test_returns_true_when_set_and_false_on_timeout() -> None:
    async def go() -> tuple[bool, bool, float]:
        loop = asyncio.get_running_loop()
        event = asyncio.Event()
        loop.call_later(0.01, event.set)
        got = await wait_event(event, 5.0)
        event.clear()
        t0 = loop.time()
        timed_out = await wait_event(event, 0.05)
        return got, timed_out, loop.time() - t0

    got, timed_out, waited_s = asyncio.run(go())
    assert got is True
    assert timed_out is False
    assert waited_s >= 0.05


def test_the_monotonic_clock_waits_until_its_own_deadline() -> None:
    """Stamps and waits are on one clock: a wait ends when *that* clock reaches the
    deadline (the loop's timers may fire a little early), or when the event is set."""
    from tcm_companion.io.aio import MONOTONIC

    async def go() -> tuple[bool, int, bool, bool]:
        event = asyncio.Event()
        deadline = MONOTONIC.now_us() + 30_000
        timed_out = await MONOTONIC.wait_until(event, deadline)
        late_us = MONOTONIC.now_us() - deadline
        asyncio.get_running_loop().call_later(0.01, event.set)
        woken = await MONOTONIC.wait_until(event, MONOTONIC.now_us() + 5_000_000)
        already = await MONOTONIC.wait_until(event, 0)  # set: at once, not cleared
        await MONOTONIC.wait_until(None, MONOTONIC.now_us() + 1_000)
        return timed_out, late_us, woken, already

    timed_out, late_us, woken, already = asyncio.run(go())
    assert timed_out is False and late_us >= 0
    assert woken is True and already is True
