"""asyncio helpers the daemon's tasks share.

:func:`wait_event` exists because of a CPython 3.11 bug in :func:`asyncio.wait_for`
(python/cpython gh-86296, fixed in 3.12 where ``wait_for`` is built on
:func:`asyncio.timeout`): when the awaited thing completes in the same loop iteration as
the waiting task is cancelled, ``wait_for`` returns the result and the cancellation is
lost. A task that waits for telemetry in a loop, and is cancelled at shutdown while
telemetry keeps arriving, then never ends — the daemon's ``TaskGroup`` waits for it
forever (seen in CI: a SITL run kept processing frames past its duration).
:func:`asyncio.timeout` uncancels only its own cancellation, so a stop is never lost.
"""

from __future__ import annotations

import asyncio


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
