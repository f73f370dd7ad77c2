"""The transport contract: one small base class that every byte link implements.

Like python-can's ``BusABC``, the base class implements the public methods once —
bounded receive buffer, ``recv()`` with its end-of-link rules, ``send()`` with its write
timeout and lock, ``close()`` — and a backend overrides three small hooks:

- ``_open()``: acquire the device or socket and start delivering received bytes by
  calling ``self._data_received(data)`` (and ``self._lost(exc)`` when the link dies);
- ``_write(view)``: write all of ``view``, waiting (asynchronously) while the link
  pushes back, counting ``stats["bytes_out"]`` as bytes leave; cancellation is how the
  base class enforces the write timeout;
- ``_release()``: free the resources, synchronously and idempotently.

Transports carry bytes only; MAVLink framing lives in the sans-IO codec/endpoint.
"""

from __future__ import annotations

import abc
import asyncio
from collections import Counter, deque
from collections.abc import Callable
from types import TracebackType
from typing import Self

from .errors import TransportClosed, TransportError, TransportOpenError, TransportTimeout

DEFAULT_WRITE_TIMEOUT_S = 1.0
# ~11 s of a saturated 921600 baud link: a reader that far behind has stalled, and
# dropping the oldest bytes keeps memory bounded while the newest telemetry survives.
DEFAULT_MAX_RX_BYTES = 1 << 20
# recv() returns at most this much, so one call's work stays bounded (and fits the
# MAVLink codec's 64 KiB receive buffer) however far behind the reader is.
MAX_RECV_CHUNK = 65536

_NEW, _OPEN, _LOST, _CLOSED = "new", "open", "lost", "closed"


class RxBuffer:
    """Received bytes waiting for ``recv()``: bounded; overflow drops the oldest bytes.

    The buffer also carries the link's end: once :meth:`fail` is called, ``get()``
    returns what is still buffered and then raises the given exception. A non-permanent
    failure (a reconnecting link's outage) can be lifted with :meth:`resume`.
    """

    def __init__(self, max_bytes: int, stats: Counter[str]) -> None:
        if max_bytes <= 0:
            raise ValueError(f"max_rx_bytes must be positive, got {max_bytes}")
        self.max_bytes = max_bytes
        self.stats = stats
        self._chunks: deque[bytes] = deque()
        self._size = 0
        self._ready = asyncio.Event()
        self._end: Callable[[], TransportClosed] | None = None
        self._permanent = False

    def __len__(self) -> int:
        return self._size

    def put(self, data: bytes) -> None:
        if self._permanent:
            return
        self._chunks.append(data)
        self._size += len(data)
        excess = self._size - self.max_bytes
        if excess > 0:
            self._drop_oldest(excess)
        self._ready.set()

    def _drop_oldest(self, n: int) -> None:
        self.stats["dropped_bytes"] += n
        self._size -= n
        while n:
            head = self._chunks[0]
            if len(head) <= n:
                self._chunks.popleft()
                n -= len(head)
            else:
                self._chunks[0] = head[n:]
                n = 0

    def fail(
        self, end: Callable[[], TransportClosed], *, permanent: bool, discard: bool = False
    ) -> None:
        """From now on an empty buffer raises ``end()`` (a fresh exception each time)."""
        if self._permanent:
            return
        self._end = end
        self._permanent = permanent
        if discard:
            self._chunks.clear()
            self._size = 0
        self._ready.set()  # wake waiters so they see the end

    def resume(self) -> None:
        if not self._permanent:
            self._end = None

    def get_nowait(self, limit: int = MAX_RECV_CHUNK) -> bytes | None:
        if self._chunks:
            if self._size <= limit:
                data = self._chunks[0] if len(self._chunks) == 1 else b"".join(self._chunks)
                self._chunks.clear()
                self._size = 0
                return data
            parts: list[bytes] = []
            n = 0
            while n < limit:
                head = self._chunks[0]
                take = min(len(head), limit - n)
                if take == len(head):
                    parts.append(self._chunks.popleft())
                else:
                    parts.append(head[:take])
                    self._chunks[0] = head[take:]
                n += take
            self._size -= n
            return b"".join(parts)
        if self._end is not None:
            raise self._end()
        return None

    async def get(self) -> bytes:
        while True:
            data = self.get_nowait()
            if data is not None:
                return data
            self._ready.clear()
            await self._ready.wait()


class Transport(abc.ABC):
    """A bidirectional byte link (serial, UDP, TCP, in-memory).

    ``stats`` counts at least ``bytes_in``, ``bytes_out``, ``dropped_bytes`` (receive
    buffer overflow) and ``write_timeouts``; backends add their own (``reconnects``,
    ``no_peer_drops``, ...). Single use: once closed or lost it stays so (wrap it in a
    :class:`ReconnectingTransport` to reopen lost links).
    """

    kind: str = "?"

    def __init__(
        self,
        url: str,
        *,
        write_timeout_s: float = DEFAULT_WRITE_TIMEOUT_S,
        max_rx_bytes: int = DEFAULT_MAX_RX_BYTES,
    ) -> None:
        if not write_timeout_s > 0:
            raise ValueError(f"write_timeout_s must be positive, got {write_timeout_s}")
        self.url = url
        self.write_timeout_s = float(write_timeout_s)
        self.stats: Counter[str] = Counter()
        self._rx = RxBuffer(max_rx_bytes, self.stats)
        self._rx.fail(lambda: TransportClosed(f"{self.url}: not open"), permanent=False)
        self._state = _NEW
        self._end_reason = "not open"
        self._send_lock = asyncio.Lock()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url} {self._state}>"

    @property
    def is_open(self) -> bool:
        return self._state == _OPEN

    # -- public API ----------------------------------------------------------------------
    async def open(self) -> None:
        """Open the link. A no-op when already open; a closed transport cannot reopen."""
        if self._state == _OPEN:
            return
        if self._state != _NEW:
            raise TransportClosed(f"{self.url}: cannot reopen a {self._state} transport")
        self._rx.resume()
        try:
            await self._open()
        except TransportError:
            self._abort_open()
            raise
        except (OSError, ValueError) as exc:
            self._abort_open()
            raise TransportOpenError(f"{self.url}: cannot open: {exc}") from exc
        if self._state == _NEW:  # _open() may already have seen the link die
            self._state = _OPEN

    def _abort_open(self) -> None:
        self._release()
        self._rx.fail(lambda: TransportClosed(f"{self.url}: not open"), permanent=False)

    async def recv(self, timeout: float | None = None) -> bytes:
        """Wait for the next received bytes (all that is buffered, up to 64 KiB).

        Raises :class:`TransportClosed` once the transport is closed (at once, also in a
        task already waiting) or the link is lost (after what was received before), and
        :class:`TransportTimeout` if ``timeout`` seconds pass with nothing received.
        """
        if timeout is None:
            return await self._rx.get()
        try:
            async with asyncio.timeout(timeout):
                return await self._rx.get()
        except TimeoutError:
            raise TransportTimeout(f"{self.url}: nothing received within {timeout} s") from None

    async def send(self, data: bytes) -> None:
        """Write all of ``data``, or raise within ``write_timeout_s``.

        Concurrent senders are serialised, so frames from different tasks never
        interleave. Raises :class:`TransportTimeout` when the bytes cannot be written
        in time (part of them may have been) and :class:`TransportClosed` when closed.
        """
        if self._state != _OPEN:
            raise TransportClosed(f"{self.url}: {self._end_reason}")
        if not data:
            return
        deadline = asyncio.timeout(self.write_timeout_s)
        try:
            async with deadline, self._send_lock:
                if self._state != _OPEN:  # lost while we waited for the lock
                    raise TransportClosed(f"{self.url}: {self._end_reason}")
                await self._write(memoryview(data).cast("B"))
        except TimeoutError as exc:
            if not deadline.expired():  # an OS-level ETIMEDOUT: the link is gone
                self._lost(exc)
                raise TransportClosed(f"{self.url}: {self._end_reason}") from exc
            self.stats["write_timeouts"] += 1
            raise TransportTimeout(
                f"{self.url}: could not write {len(data)} bytes within "
                f"{self.write_timeout_s} s (is the peer reading?)"
            ) from None
        except OSError as exc:
            self._lost(exc)
            raise TransportClosed(f"{self.url}: {self._end_reason}") from exc

    async def close(self) -> None:
        """Close and release the link; idempotent. Waiting ``recv()`` calls raise."""
        if self._state == _CLOSED:
            return
        was_active = self._state in (_OPEN, _LOST)
        self._state = _CLOSED
        self._end_reason = "closed"
        self._rx.fail(lambda: TransportClosed(f"{self.url}: closed"), permanent=True, discard=True)
        if was_active:
            await self._close()

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # -- for backends --------------------------------------------------------------------
    def _mark_open(self) -> None:
        """For links that exist from construction (a memory pair): open without ``open()``."""
        if self._state == _NEW:
            self._rx.resume()
            self._state = _OPEN

    def _data_received(self, data: bytes) -> None:
        self.stats["bytes_in"] += len(data)
        self._rx.put(data)

    def _lost(self, exc: BaseException | None) -> None:
        """The link died under us (peer closed, device hung up): end it for good."""
        if self._state not in (_NEW, _OPEN):
            return
        self._state = _LOST
        self.stats["links_lost"] += 1
        self._end_reason = f"link lost ({exc or 'closed by peer'})"
        reason = self._end_reason
        self._rx.fail(lambda: TransportClosed(f"{self.url}: {reason}"), permanent=True)
        self._release()

    async def _close(self) -> None:
        self._release()

    @abc.abstractmethod
    async def _open(self) -> None: ...

    @abc.abstractmethod
    async def _write(self, data: memoryview) -> None: ...

    @abc.abstractmethod
    def _release(self) -> None: ...
