"""TCP client transport: ``tcp:HOST:PORT`` (SITL's 5760, a telemetry radio's bridge).

An asyncio protocol feeds received bytes to the bounded buffer. Writes are bounded by
asyncio's flow control: ``send()`` returns once the unsent backlog is under
``write_buffer_bytes``, so a peer that stops reading makes ``send()`` time out instead
of growing memory. The peer closing the connection ends the transport
(:class:`TransportClosed` after the bytes already received); wrap it in a
:class:`ReconnectingTransport` to reconnect.
"""

from __future__ import annotations

import asyncio
from typing import Any

from .base import Transport
from .errors import TransportClosed, TransportOpenError
from .urls import parse_host_port


class _StreamProtocol(asyncio.Protocol):
    def __init__(self, owner: TcpTransport) -> None:
        self.owner = owner

    def data_received(self, data: bytes) -> None:
        self.owner._data_received(data)

    def eof_received(self) -> bool:
        return False  # a half-closed MAVLink link is useless: close our side too

    def pause_writing(self) -> None:
        self.owner._writable.clear()

    def resume_writing(self) -> None:
        self.owner._writable.set()

    def connection_lost(self, exc: Exception | None) -> None:
        owner = self.owner
        owner._writable.set()  # wake a blocked send() so it sees the loss
        owner._closed_event.set()
        owner._lost(exc)


class TcpTransport(Transport):
    kind = "tcp"

    def __init__(
        self,
        url: str,
        host: str,
        port: int,
        *,
        connect_timeout_s: float = 5.0,
        write_buffer_bytes: int = 64 * 1024,
        **options: Any,
    ) -> None:
        super().__init__(url, **options)
        self.host, self.port = host, port
        self.connect_timeout_s = connect_timeout_s
        self.write_buffer_bytes = write_buffer_bytes
        self._transport: asyncio.Transport | None = None
        self._writable = asyncio.Event()
        self._writable.set()
        self._closed_event = asyncio.Event()

    @classmethod
    def from_url(cls, url: str, **options: Any) -> TcpTransport:
        _, _, rest = url.partition(":")
        host, port = parse_host_port(url, rest)
        return cls(url, host, port, **options)

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                transport, _ = await loop.create_connection(
                    lambda: _StreamProtocol(self), self.host, self.port
                )
        except TimeoutError:
            raise TransportOpenError(
                f"{self.url}: no connection within {self.connect_timeout_s} s"
            ) from None
        # asyncio enables TCP_NODELAY by default: small MAVLink frames go out at once.
        transport.set_write_buffer_limits(high=self.write_buffer_bytes)
        self._transport = transport

    async def _write(self, data: memoryview) -> None:
        await self._writable.wait()
        transport = self._transport
        if transport is None or transport.is_closing():
            raise TransportClosed(f"{self.url}: {self._end_reason}")
        transport.write(bytes(data))
        self.stats["bytes_out"] += len(data)
        # Like StreamWriter.drain(): done when the backlog is under the high-water mark.
        await self._writable.wait()

    def _release(self) -> None:
        transport, self._transport = self._transport, None
        if transport is not None:
            # A backlog means the peer is not reading: close() would wait for it forever.
            if transport.get_write_buffer_size():
                transport.abort()
            else:
                transport.close()
        self._writable.set()

    async def _close(self) -> None:
        had_transport = self._transport is not None
        self._release()
        if had_transport:
            # Let connection_lost run, so the socket is really closed when we return.
            try:
                async with asyncio.timeout(1.0):
                    await self._closed_event.wait()
            except TimeoutError:
                pass
