"""Serial transport: ``serial:PATH[:BAUD]`` (a flight controller's TELEM port, a pty).

pyserial opens and configures the port (raw mode, baud rate, optional RTS/CTS, an
exclusive lock so two daemons cannot share one UART); after that its file descriptor,
which pyserial opens non-blocking, is driven by the event loop directly: ``add_reader``
delivers bytes as they arrive (no polling interval, no reader thread), and a write that
the kernel cannot take (``EAGAIN``: the UART is held off by flow control, or a pty's
other end stopped reading) waits on ``add_writer``, bounded by the base class's write
timeout. POSIX only — the companion computers run Linux.

A hang-up (USB adapter unplugged, the socat behind a pty exited) shows as a readable
descriptor that yields no bytes, or as ``EIO``: the transport is then lost; wrap it in a
:class:`ReconnectingTransport` to reopen the device when it comes back.
"""

from __future__ import annotations

import asyncio
import os
import select
import sys
from typing import Any

import serial  # pyserial

from .base import Transport
from .errors import TransportClosed, TransportError, TransportOpenError
from .urls import parse_serial

_READ_SIZE = 65536
# A readable descriptor that yields no bytes this many times in a row is hung up even
# if poll() does not say so (some USB serial drivers).
_MAX_EMPTY_READS = 3


def _hung_up(fd: int) -> bool:
    poller = select.poll()
    poller.register(fd, 0)  # POLLHUP, POLLERR and POLLNVAL are always reported
    return any(ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL) for _, ev in poller.poll(0))


class SerialTransport(Transport):
    kind = "serial"

    def __init__(
        self,
        url: str,
        path: str,
        baudrate: int,
        *,
        exclusive: bool = True,
        rtscts: bool = False,
        **options: Any,
    ) -> None:
        super().__init__(url, **options)
        self.path, self.baudrate = path, baudrate
        self.exclusive, self.rtscts = exclusive, rtscts
        self._serial: serial.Serial | None = None
        self._fd = -1
        self._loop: asyncio.AbstractEventLoop | None = None
        self._write_waiter: asyncio.Future[None] | None = None
        self._empty_reads = 0

    @classmethod
    def from_url(cls, url: str, **options: Any) -> SerialTransport:
        _, _, rest = url.partition(":")
        path, baud = parse_serial(url, rest)
        return cls(url, path, baud, **options)

    async def _open(self) -> None:
        if sys.platform == "win32":
            raise TransportError(f"{self.url}: the serial transport needs a POSIX system")
        try:
            port = serial.Serial(
                port=self.path,
                baudrate=self.baudrate,
                timeout=0,
                write_timeout=0,
                exclusive=self.exclusive,
                rtscts=self.rtscts,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportOpenError(f"{self.url}: cannot open {self.path}: {exc}") from exc
        self._serial = port
        self._fd = port.fileno()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._fd, self._on_readable)

    def _on_readable(self) -> None:
        try:
            data = os.read(self._fd, _READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EIO: the device or the pty's master is gone
            self._lost(exc)
            return
        if data:
            self._empty_reads = 0
            self._data_received(data)
            return
        self._empty_reads += 1
        if _hung_up(self._fd) or self._empty_reads >= _MAX_EMPTY_READS:
            self._lost(OSError("device hung up"))
        else:
            self.stats["spurious_wakeups"] += 1

    async def _write(self, data: memoryview) -> None:
        while data:
            try:
                n = os.write(self._fd, data)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError as exc:
                self._lost(exc)
                raise TransportClosed(f"{self.url}: {self._end_reason}") from exc
            self.stats["bytes_out"] += n
            data = data[n:]
            if data:
                await self._wait_writable()

    async def _wait_writable(self) -> None:
        assert self._loop is not None
        waiter: asyncio.Future[None] = self._loop.create_future()

        def ready() -> None:
            if not waiter.done():
                waiter.set_result(None)

        self._write_waiter = waiter
        self._loop.add_writer(self._fd, ready)
        try:
            await waiter
        finally:
            self._write_waiter = None
            if self._fd >= 0:
                self._loop.remove_writer(self._fd)

    def _release(self) -> None:
        if self._fd >= 0 and self._loop is not None:
            self._loop.remove_reader(self._fd)
            self._loop.remove_writer(self._fd)
        self._fd = -1
        waiter = self._write_waiter
        if waiter is not None and not waiter.done():
            waiter.set_exception(TransportClosed(f"{self.url}: {self._end_reason}"))
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass  # already gone with the device
            self._serial = None
