"""In-memory links: two transports that hand bytes to each other, for tests.

Like python-can's virtual bus. :func:`memory_pair` returns two connected, open ends;
``memory:NAME`` URLs join two transports opened with the same name (the first waits
for the second; bytes sent before then are dropped and counted, as on a UDP link
nobody listens to). Closing one end makes the other's ``recv()`` raise
:class:`TransportClosed` after the bytes already delivered, like a TCP peer closing.
A memory link never pushes back: a peer that stops reading loses its oldest bytes to
its bounded receive buffer instead.
"""

from __future__ import annotations

from typing import Any

from .base import Transport
from .errors import TransportURLError

# Named ends waiting for their partner (module state: one process, one namespace).
_waiting: dict[str, MemoryTransport] = {}


class MemoryTransport(Transport):
    kind = "memory"

    def __init__(self, url: str = "memory:", *, channel: str = "", **options: Any) -> None:
        super().__init__(url, **options)
        self.channel = channel
        self._peer: MemoryTransport | None = None

    @classmethod
    def from_url(cls, url: str, **options: Any) -> MemoryTransport:
        _, _, channel = url.partition(":")
        if not channel:
            raise TransportURLError(
                f"{url!r}: a memory URL needs a channel name, e.g. 'memory:link1' (two "
                "transports opened with the same name are connected); or use memory_pair()"
            )
        return cls(url, channel=channel, **options)

    async def _open(self) -> None:
        if not self.channel or self._peer is not None:
            return
        other = _waiting.pop(self.channel, None)
        if other is not None and other.is_open and other._peer is None:
            self._peer, other._peer = other, self
        else:
            _waiting[self.channel] = self

    async def _write(self, data: memoryview) -> None:
        peer = self._peer
        if peer is None:
            self.stats["no_peer_drops"] += 1
            self.stats["dropped_bytes_out"] += len(data)
            return
        # A copy: the caller may reuse its buffer, and bytes are what recv() returns.
        peer._data_received(bytes(data))
        self.stats["bytes_out"] += len(data)

    def _release(self) -> None:
        if _waiting.get(self.channel) is self:
            del _waiting[self.channel]
        peer, self._peer = self._peer, None
        if peer is not None:
            peer._peer = None
            peer._lost(None)


def memory_pair(**options: Any) -> tuple[MemoryTransport, MemoryTransport]:
    """Two connected in-memory transports, already open (``open()`` is a no-op)."""
    a = MemoryTransport("memory:pair-a", **options)
    b = MemoryTransport("memory:pair-b", **options)
    a._peer, b._peer = b, a
    a._mark_open()
    b._mark_open()
    return a, b
