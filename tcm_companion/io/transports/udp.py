"""UDP transports: ``udpin:HOST:PORT`` (listen) and ``udpout:HOST:PORT`` (send to a peer).

As in MAVProxy and pymavlink: ``udpin`` binds and replies to the last address that sent
to it (a ground station or SITL that connects later, or moves, is followed); before
anyone has sent, outgoing bytes are dropped and counted. ``udpout`` sends to a fixed
peer and receives its replies (the socket is connected, so strangers are filtered out
by the kernel). UDP never pushes back and is never "lost": a peer that stops listening
costs datagrams (ICMP errors are counted), not a closed transport.

Large sends are cut into datagrams of ``max_datagram`` bytes (default 1472: one
Ethernet/Wi-Fi frame, so no IP fragmentation, where one lost fragment loses all).
MAVLink receivers parse UDP payloads as a byte stream, so a frame cut across two
datagrams still decodes; callers that send frame by frame get one frame per datagram.
"""

from __future__ import annotations

import asyncio
import socket
from typing import Any

from .base import Transport
from .bind import bound_datagram_endpoint
from .urls import parse_host_port

# Kernel receive buffer to ask for: bursts of telemetry should not overflow the
# default (~200 KiB) while the event loop is busy; the kernel caps it at rmem_max.
_SO_RCVBUF = 1 << 20
# Our own bound on datagrams asyncio holds when the kernel's send buffer is full.
_MAX_TX_BACKLOG = 256 * 1024


class _DatagramProtocol(asyncio.DatagramProtocol):
    def __init__(self, owner: UdpTransport) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.owner._datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable and the like: the peer is not listening (yet). UDP has
        # no connection to lose, so count it and carry on.
        self.owner.stats["icmp_errors"] += 1

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            self.owner._lost(exc)


class UdpTransport(Transport):
    def __init__(
        self,
        url: str,
        host: str,
        port: int,
        *,
        listen: bool,
        max_datagram: int = 1472,
        **options: Any,
    ) -> None:
        super().__init__(url, **options)
        if not 1 <= max_datagram <= 65507:
            raise ValueError(f"max_datagram must be 1..65507, got {max_datagram}")
        self.kind = "udpin" if listen else "udpout"
        self.host, self.port, self.listen = host, port, listen
        self.max_datagram = max_datagram
        self.peer: Any = None  # udpin: the last sender; udpout: None (connected socket)
        self._transport: asyncio.DatagramTransport | None = None

    @classmethod
    def from_url(cls, url: str, **options: Any) -> UdpTransport:
        scheme, _, rest = url.partition(":")
        listen = scheme == "udpin"
        host, port = parse_host_port(url, rest, allow_zero_port=listen)
        return cls(url, host, port, listen=listen, **options)

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound address (useful with ``udpin:127.0.0.1:0``)."""
        if self._transport is None:
            raise RuntimeError(f"{self.url}: not open")
        host, port = self._transport.get_extra_info("sockname")[:2]
        return host, port

    async def _open(self) -> None:
        loop = asyncio.get_running_loop()
        if self.listen:
            # Bound here: a port in use is named with its holder, not "could not bind".
            transport, _ = await bound_datagram_endpoint(
                lambda: _DatagramProtocol(self), self.host, self.port
            )
        else:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _DatagramProtocol(self), remote_addr=(self.host, self.port)
            )
        self._transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _SO_RCVBUF)
            except OSError:
                pass  # a smaller buffer still works; bursts may drop sooner

    def _datagram_received(self, data: bytes, addr: Any) -> None:
        if self.listen and addr != self.peer:
            if self.peer is not None:
                self.stats["peer_changes"] += 1
            self.peer = addr
        self.stats["datagrams_in"] += 1
        self._data_received(data)

    async def _write(self, data: memoryview) -> None:
        transport = self._transport
        if transport is None or (self.listen and self.peer is None):
            self.stats["no_peer_drops"] += 1
            self.stats["dropped_bytes_out"] += len(data)
            return
        step = self.max_datagram
        for offset in range(0, len(data), step):
            chunk = bytes(data[offset : offset + step])
            if transport.is_closing():
                return
            # (asyncio's datagram transports have it; typeshed's ABC does not declare it)
            if transport.get_write_buffer_size() > _MAX_TX_BACKLOG:  # type: ignore[attr-defined]
                self.stats["dropped_bytes_out"] += len(chunk)
                continue
            transport.sendto(chunk, self.peer if self.listen else None)
            self.stats["datagrams_out"] += 1
            self.stats["bytes_out"] += len(chunk)
            # UDP has no backpressure: yield after each datagram so that a receiver in
            # this process (tests, the mock autopilot) drains its socket in step with a
            # burst instead of the kernel dropping what overflows its buffer.
            await asyncio.sleep(0)

    def _release(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
