"""Reopening lost serial/TCP links with exponential backoff.

A :class:`ReconnectingTransport` owns one inner transport at a time, made by a factory.
A supervisor task opens it, pumps its received bytes into this transport's own bounded
buffer, and when the link dies (USB adapter unplugged, SITL restarted) opens a fresh
one after 0.1 s, 0.2 s, 0.4 s … capped at 5 s, back to 0.1 s once a link has stayed up
for a whole cap. ``stats["reconnects"]`` counts successful reopenings.

During an outage nothing hangs: ``recv()`` raises :class:`LinkDown` (after the bytes
received before the loss), ``send()`` raises :class:`TransportTimeout` at once without
writing — stale telemetry is worth nothing, so the caller drops it rather than queueing
it. ``await wait_connected()`` waits for the link to be back.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from .base import DEFAULT_MAX_RX_BYTES, Transport
from .errors import LinkDown, TransportClosed, TransportError, TransportTimeout

log = logging.getLogger(__name__)


class ReconnectingTransport(Transport):
    kind = "reconnecting"

    def __init__(
        self,
        factory: Callable[[], Transport],
        url: str | None = None,
        *,
        initial_backoff_s: float = 0.1,
        max_backoff_s: float = 5.0,
        max_rx_bytes: int = DEFAULT_MAX_RX_BYTES,
    ) -> None:
        if not 0 < initial_backoff_s <= max_backoff_s:
            raise ValueError("need 0 < initial_backoff_s <= max_backoff_s")
        self._factory = factory
        probe = url
        if probe is None:
            probe = factory().url  # unopened: costs nothing but the name
        super().__init__(probe, max_rx_bytes=max_rx_bytes)
        self.initial_backoff_s = initial_backoff_s
        self.max_backoff_s = max_backoff_s
        self._inner: Transport | None = None
        self._connected = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._down_reason = "not connected yet"

    @property
    def connected(self) -> bool:
        return self._inner is not None and self._inner.is_open

    @property
    def inner(self) -> Transport | None:
        """The current link, or None during an outage."""
        return self._inner

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Wait until the link is up; :class:`TransportTimeout` after ``timeout`` s."""
        if self._task is None or self._task.done():
            raise TransportClosed(f"{self.url}: {self._end_reason}")
        try:
            async with asyncio.timeout(timeout):
                await self._connected.wait()
        except TimeoutError:
            raise TransportTimeout(
                f"{self.url}: link still down after {timeout} s ({self._down_reason})"
            ) from None

    async def _open(self) -> None:
        first_attempt: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._set_down("not connected yet")
        task = asyncio.create_task(self._supervise(first_attempt), name=f"link {self.url}")
        task.add_done_callback(self._supervisor_done)
        self._task = task
        # A healthy link is up when open() returns; a missing one is retried in the
        # background rather than failing the service's start.
        try:
            await asyncio.wait([first_attempt, task], return_when=asyncio.FIRST_COMPLETED)
        except BaseException:  # open() itself cancelled: do not leave the supervisor behind
            task.cancel()
            raise
        if task.done() and not task.cancelled() and task.exception() is not None:
            raise TransportError(f"{self.url}: cannot start: {task.exception()!r}")

    def _supervisor_done(self, task: asyncio.Task[None]) -> None:
        if task.cancelled() or task.exception() is None:
            return
        # A bug, not a link fault: end the transport visibly instead of hanging callers.
        log.error("%s: link supervisor failed", self.url, exc_info=task.exception())
        self._end_reason = f"link supervisor failed: {task.exception()!r}"
        reason = self._end_reason
        self._rx.fail(lambda: TransportClosed(f"{self.url}: {reason}"), permanent=True)

    def _set_down(self, reason: str) -> None:
        reason = reason.removeprefix(f"{self.url}: ")  # the inner link's messages name it too
        self._down_reason = reason
        self._rx.fail(
            lambda: LinkDown(f"{self.url}: link down ({reason}); reconnecting"), permanent=False
        )

    async def _supervise(self, first_attempt: asyncio.Future[None]) -> None:
        loop = asyncio.get_running_loop()
        delay = self.initial_backoff_s
        ever_connected = False
        failures = 0
        while True:
            inner = self._factory()
            try:
                await inner.open()
            except TransportError as exc:
                self.stats["open_failures"] += 1
                failures += 1
                self._set_down(str(exc))
                # One warning per outage; the retries are debug noise.
                (log.warning if failures == 1 else log.debug)(
                    "%s: %s; retrying with backoff up to %.1f s",
                    self.url,
                    self._down_reason,
                    self.max_backoff_s,
                )
                if not first_attempt.done():
                    first_attempt.set_result(None)
                await asyncio.sleep(delay)
                delay = min(2 * delay, self.max_backoff_s)
                continue
            failures = 0
            if ever_connected:
                self.stats["reconnects"] += 1
                log.info("%s: link back", self.url)
            ever_connected = True
            self._inner = inner
            self._rx.resume()
            self._connected.set()
            if not first_attempt.done():
                first_attempt.set_result(None)
            up_since = loop.time()
            try:
                while True:
                    self._data_received(await inner.recv())
            except TransportClosed as exc:
                reason = str(exc)
            finally:
                self._inner = None
                self._connected.clear()
                self.stats["dropped_bytes"] += inner.stats["dropped_bytes"]
                await inner.close()
            self.stats["links_lost"] += 1
            self._set_down(reason)
            log.warning("%s: %s; reconnecting", self.url, self._down_reason)
            if loop.time() - up_since >= self.max_backoff_s:
                delay = self.initial_backoff_s
            await asyncio.sleep(delay)
            delay = min(2 * delay, self.max_backoff_s)

    async def send(self, data: bytes) -> None:
        """Send on the current link; during an outage raise :class:`TransportTimeout` at once."""
        if not self.is_open:
            raise TransportClosed(f"{self.url}: {self._end_reason}")
        if self._task is None or self._task.done():
            raise TransportClosed(f"{self.url}: {self._end_reason}")
        inner = self._inner
        if inner is None:
            self.stats["sends_while_down"] += 1
            raise TransportTimeout(f"{self.url}: link down ({self._down_reason}); not sent")
        before = inner.stats["bytes_out"]
        try:
            await inner.send(data)
        except TransportTimeout:
            self.stats["write_timeouts"] += 1
            raise
        except TransportClosed as exc:
            # The link died under this send; the supervisor is already reconnecting.
            self.stats["sends_while_down"] += 1
            raise TransportTimeout(f"{self.url}: link lost during send ({exc})") from exc
        finally:
            self.stats["bytes_out"] += inner.stats["bytes_out"] - before

    async def _write(self, data: memoryview) -> None:  # pragma: no cover - send() overrides
        raise NotImplementedError

    def _release(self) -> None:
        if self._task is not None:
            self._task.cancel()

    async def _close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            await asyncio.wait([task])  # unlike `await task`, keeps our own cancellation
        inner, self._inner = self._inner, None
        if inner is not None:
            await inner.close()
