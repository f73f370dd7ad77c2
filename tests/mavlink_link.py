"""For tests: the companion endpoint alone on a link (an asyncio adapter: feed bytes in,
drain events, re-arm a timer).

Like aioquic's ``asyncio/protocol.py``: the endpoint
(:mod:`tcm_companion.mavlink.endpoint`) holds all the protocol logic; this only moves
bytes between it and a transport, wakes it at its deadlines, and hands its events to a
callback. Frame outputs are pushed with
:meth:`CompanionLink.send_frame` from the same event loop. The daemon does not use this
class (its :class:`~tcm_companion.service.companion.Companion` owns the endpoint and the
daemon moves the bytes itself), so it lives with the tests that drive the endpoint alone
over a real link: the interop, loop and spoofing tests.

The clock is injected (:class:`~tcm_companion.io.aio.LoopClock`, µs; by default the
companion monotonic clock) and must be the clock the frame times are on, because the
endpoint maps frame times to the autopilot's boot time through TIMESYNC. Time stamps and
waits are both on it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from tcm_companion.core.pipeline import FrameResult
from tcm_companion.io.aio import MONOTONIC, LoopClock
from tcm_companion.io.transports import (
    Transport,
    TransportClosed,
    TransportError,
    TransportTimeout,
)
from tcm_companion.mavlink.endpoint import CompanionEndpoint, Event

__all__ = ["CompanionLink"]

_RETRY_US = 100_000  # a closed or failing transport is read again after this
_POLL_MAX_US = 1_000_000  # the timer polls at least this often


class CompanionLink:
    """Runs one :class:`CompanionEndpoint` over one transport."""

    def __init__(
        self,
        transport: Transport,
        endpoint: CompanionEndpoint,
        on_event: Callable[[Event], None] | None = None,
        clock: LoopClock = MONOTONIC,
        on_bytes: Callable[[str, int, bytes], object] | None = None,
    ) -> None:
        self.transport = transport
        self.endpoint = endpoint
        self.on_event = on_event
        self.clock = clock
        # ("in" | "out", time µs, bytes) for every chunk received or handed to the
        # transport: the flight log records the link exactly (a .tlog can be rebuilt).
        self.on_bytes = on_bytes
        self._wake = asyncio.Event()
        self._stopping = False
        self.send_errors = 0

    def now_us(self) -> int:
        return self.clock.now_us()

    def send_frame(self, result: FrameResult, camera_id: int = 0) -> None:
        """Queue one frame's outputs; they go out at once (the writer is woken)."""
        self.endpoint.send_frame(result, self.now_us(), camera_id)
        self._wake.set()

    async def flush(self) -> None:
        """Write what the endpoint has queued now (frame outputs go out the same tick)."""
        await self._flush()

    def wake(self) -> None:
        """Make the timer task poll the endpoint now (after health or STATUSTEXT changes)."""
        self._wake.set()

    def stop(self) -> None:
        self._stopping = True
        self._wake.set()

    def _dispatch(self, events: list[Event]) -> None:
        if self.on_event is None:
            return
        for ev in events:
            self.on_event(ev)

    async def _flush(self) -> None:
        data = self.endpoint.data_to_send()
        if not data:
            return
        if self.on_bytes is not None:
            self.on_bytes("out", self.now_us(), data)
        try:
            await self.transport.send(data)
        except (TransportTimeout, TransportClosed):
            # The link is down or the peer stopped reading: drop rather than block the
            # pipeline; the endpoint's timers resend what matters (heartbeats, requests).
            self.send_errors += 1

    async def _reader(self) -> None:
        while not self._stopping:
            try:
                data = await self.transport.recv()
            except TransportClosed:
                if self._stopping:
                    return
                await self.clock.wait_until(None, self.now_us() + _RETRY_US)
                continue
            except TransportError:
                await self.clock.wait_until(None, self.now_us() + _RETRY_US)
                continue
            now = self.now_us()
            if self.on_bytes is not None:
                self.on_bytes("in", now, data)
            self._dispatch(self.endpoint.receive_data(data, now))
            self._wake.set()

    async def _timer(self) -> None:
        while not self._stopping:
            now = self.now_us()
            self._dispatch(self.endpoint.poll(now))
            await self._flush()
            deadline = min(self.endpoint.next_deadline_us(), self.now_us() + _POLL_MAX_US)
            self._wake.clear()
            await self.clock.wait_until(self._wake, deadline)

    async def run(self) -> None:
        """Until :meth:`stop`: read, poll, write."""
        reader = asyncio.create_task(self._reader())
        try:
            await self._timer()
        finally:
            reader.cancel()
            try:
                await reader
            except asyncio.CancelledError:
                pass
            await self._flush()
