"""Run a command's coroutine on uvloop (the asyncio loop written in libuv), and a
real-time run until SIGINT or SIGTERM: its handlers (:class:`.interrupts.RunSignals`)
installed once, here, for ``run`` and ``sitl`` alike.

asyncio and uvloop are imported when a command runs, not here (see :mod:`.common`).
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import TYPE_CHECKING, Any, TypeVar

from .interrupts import RunSignals

if TYPE_CHECKING:
    import asyncio

_T = TypeVar("_T")


def run_loop(main: Callable[[], Coroutine[Any, Any, _T]]) -> _T:
    """Run ``main`` on uvloop, asyncio if missing."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - uvloop is a dependency; a bare install still runs
        import asyncio

        return asyncio.run(main())
    return uvloop.run(main())


def run_until_signal(
    signals: RunSignals, main: Callable[[asyncio.Event], Coroutine[Any, Any, _T]]
) -> _T:
    """Run ``main(stop)`` on :func:`run_loop`; SIGINT and SIGTERM set ``stop`` (and
    ``signals`` records which came first)."""

    async def with_signals() -> _T:
        import asyncio

        stop = asyncio.Event()
        signals.install(stop)
        return await main(stop)

    return run_loop(with_signals)
