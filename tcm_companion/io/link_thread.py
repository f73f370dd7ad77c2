"""A MAVLink link for blocking callers: one transport run by a thread with its own event loop.

The daemon moves its bytes on its own asyncio loop. Two clients live in threads instead:
the simulated camera on an autopilot (:mod:`tcm_companion.sim.scene.autopilot_camera`,
whose ``read()`` blocks in the camera reader thread) and the ground-station client of the
SITL drivers (:mod:`tcm_companion.sitl.gcs`, called from tests and ``asyncio.to_thread``).
Both keep their protocol sans-IO and hand it to a :class:`LinkThread`, which only moves
bytes: every received chunk to ``on_data(data)``, and whatever ``on_tick()`` returns (frames
to send) back to the transport, then sleeps what ``on_tick`` asked (s) or until
:meth:`LinkThread.wake`.

The transport is opened by URL (:func:`~tcm_companion.io.transports.open_transport`);
serial and TCP links are reopened with backoff (``initial_backoff_s``/``max_backoff_s``)
when lost, and a peer that is not there yet is retried in the background. Sends during an
outage are dropped and counted (:attr:`LinkThread.send_errors`), never queued: stale
commands and telemetry are worth nothing.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Any

from .transports import (
    RECONNECTABLE,
    LinkDown,
    Transport,
    TransportClosed,
    TransportError,
    TransportTimeout,
    open_transport,
)

__all__ = ["LinkThread"]

log = logging.getLogger(__name__)

_SEND_TIMEOUT_S = 3.0  # a send from another thread waits this long for the loop


class LinkThread:
    """The transport at ``url`` in a background thread (see the module docstring).

    ``on_data(data)`` and ``on_tick() -> (frames, sleep_s)`` run on the link's thread;
    ``on_link_down()`` when a reconnecting link is lost. A bug in them ends the link (logged,
    and :attr:`error` says what); a lost link that cannot be reopened (UDP, memory) ends it
    too. :attr:`alive` tells whether it still runs.
    """

    def __init__(
        self,
        url: str,
        *,
        on_data: Callable[[bytes], object],
        on_tick: Callable[[], tuple[list[bytes], float]],
        on_link_down: Callable[[], None] | None = None,
        initial_backoff_s: float = 0.1,
        max_backoff_s: float = 1.0,
        name: str = "",
    ) -> None:
        self.url = url
        self.name = name or url
        self.on_data = on_data
        self.on_tick = on_tick
        self.on_link_down = on_link_down
        self.initial_backoff_s = initial_backoff_s
        self.max_backoff_s = max_backoff_s
        self.send_errors = 0  # frames not sent: link down or closed, or a write timeout
        self.error: BaseException | None = None  # why the link could not start, or crashed
        self._transport: Any = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stopping = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._wake: asyncio.Event | None = None

    # -- from the caller's threads -----------------------------------------------------------

    def start(self, timeout_s: float = 5.0) -> None:
        """Start the thread and open the transport; :class:`TransportError` if it cannot
        (a TCP or serial peer that is not there yet is no error: it is retried)."""
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise TransportError(f"{self.url}: link did not start within {timeout_s} s")
        if self.error is not None:
            self.stop()
            raise TransportError(f"{self.url}: {self.error}")

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Close the transport and end the thread; True if it ended within ``timeout_s``."""
        self._stopping.set()
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            with contextlib.suppress(RuntimeError):  # the loop already closed
                loop.call_soon_threadsafe(stop.set)
        thread = self._thread
        if thread is None or thread is threading.current_thread():
            return True
        thread.join(timeout_s)
        return not thread.is_alive()

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def connected(self) -> bool:
        """The link is up now (a reconnecting one may be between connections)."""
        transport = self._transport
        if transport is None:
            return False
        return bool(getattr(transport, "connected", transport.is_open))

    @property
    def links_lost(self) -> int:
        """How many times the connection was lost (e.g. by an autopilot's reboot)."""
        transport = self._transport
        return int(transport.stats["links_lost"]) if transport is not None else 0

    def wake(self) -> None:
        """Run ``on_tick`` now (e.g. a new periodic message is due at once)."""
        loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(wake.set)

    def send(self, data: bytes) -> bool:
        """Send ``data`` from any thread, waiting until it is written; False (counted in
        :attr:`send_errors`) when the link is down or the write failed."""
        loop = self._loop
        if loop is None or not self.connected:
            self.send_errors += 1
            return False
        if threading.current_thread() is self._thread:
            loop.create_task(self._send(data))
            return True
        future = asyncio.run_coroutine_threadsafe(self._send(data), loop)
        try:
            return future.result(_SEND_TIMEOUT_S)
        except (concurrent.futures.TimeoutError, concurrent.futures.CancelledError, RuntimeError):
            future.cancel()
            self.send_errors += 1
            return False

    # -- the thread --------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # a bug of ours: make it visible, end the link
            log.exception("%s crashed", self.name)
            self.error = self.error or exc
        finally:
            self._ready.set()

    async def _main(self) -> None:
        self._stop = asyncio.Event()
        self._wake = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        if self._stopping.is_set():
            return
        try:
            backoff: dict[str, Any] = {}
            if self.url.partition(":")[0] in RECONNECTABLE:
                backoff = {
                    "initial_backoff_s": self.initial_backoff_s,
                    "max_backoff_s": self.max_backoff_s,
                }
            transport = open_transport(self.url, reconnect=True, **backoff)
            await transport.open()
        except Exception as exc:
            self.error = exc
            return
        self._transport = transport
        self._ready.set()
        tasks = [
            asyncio.create_task(self._stop.wait(), name=f"{self.name} stop"),
            asyncio.create_task(self._receive(transport), name=f"{self.name} rx"),
            asyncio.create_task(self._transmit(transport), name=f"{self.name} tx"),
        ]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for t in tasks:
                if t.done() and not t.cancelled() and t.exception() is not None:
                    raise RuntimeError(f"{t.get_name()} failed") from t.exception()
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await transport.close()

    async def _receive(self, transport: Transport) -> None:
        while True:
            try:
                data = await transport.recv()
            except LinkDown:
                if self.on_link_down is not None:
                    self.on_link_down()
                wait_connected = getattr(transport, "wait_connected", None)
                if wait_connected is None:
                    return
                with contextlib.suppress(TransportTimeout):
                    await wait_connected()
                continue
            except TransportClosed:
                return
            self.on_data(data)

    async def _transmit(self, transport: Transport) -> None:
        assert self._wake is not None
        while True:
            self._wake.clear()
            frames, sleep_s = self.on_tick()
            for frame in frames:
                await self._send(frame)
                if not transport.is_open:
                    return
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(0.0, sleep_s)):
                    await self._wake.wait()

    async def _send(self, frame: bytes) -> bool:
        transport = self._transport
        if transport is None:
            self.send_errors += 1
            return False
        try:
            await transport.send(frame)
        except TransportError:  # down (reconnecting), closed, or a write timeout
            self.send_errors += 1
            return False
        return True
