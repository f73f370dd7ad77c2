"""Binding a listening UDP socket with an error a person can act on.

asyncio's (and uvloop's) ``create_datagram_endpoint(local_addr=...)`` reports a port in
use as "could not bind to local_addr" with no errno; binding the socket here and handing
it over (``sock=``) keeps the kernel's reason, and for a port in use says which process
holds it when this user may see it (Linux ``/proc``; elsewhere just "in use").
"""

from __future__ import annotations

import asyncio
import errno
import os
import socket
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

_P = TypeVar("_P", bound=asyncio.DatagramProtocol)


def bound_udp_socket(host: str, port: int, what: str = "") -> socket.socket:
    """A non-blocking UDP socket bound to ``host:port``. Raises :class:`OSError` (with
    the kernel's ``errno``) whose message is one line naming ``what`` (``"[daemon]
    box_feed udp:127.0.0.1:14660"``; "" leaves it to the caller), the address and the
    reason, and for a port in use, its holder (:func:`port_holder`)."""
    head = f"{what}: " if what else ""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise _error(exc.errno, f"{head}cannot resolve {host!r}: {exc.strerror}") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        why = exc.strerror or str(exc)
        if exc.errno == errno.EADDRINUSE:
            holder = port_holder("udp", port)
            why = f"UDP port {port} is already in use" + (f" by {holder}" if holder else "")
        raise _error(exc.errno, f"{head}cannot listen on {host}:{port}: {why}") from None
    sock.setblocking(False)
    return sock


async def bound_datagram_endpoint(
    protocol_factory: Callable[[], _P], host: str, port: int, what: str = ""
) -> tuple[asyncio.DatagramTransport, _P]:
    """``loop.create_datagram_endpoint`` listening on ``host:port``, on a socket bound
    by :func:`bound_udp_socket` (its errors; the socket is closed if asyncio fails)."""
    sock = bound_udp_socket(host, port, what)
    try:
        return await asyncio.get_running_loop().create_datagram_endpoint(
            protocol_factory, sock=sock
        )
    except BaseException:
        sock.close()
        raise


def _error(number: int | None, message: str) -> OSError:
    """An OSError that prints as ``message`` alone (no "[Errno N]") and keeps ``errno``."""
    exc = OSError(message)
    exc.errno = number
    return exc


def port_holder(protocol: str, port: int, proc: Path = Path("/proc")) -> str:
    """Who holds local ``port`` (``protocol`` "udp" or "tcp"): ``"pid 1234 (mavproxy)"``,
    ``"another process (not visible to this user)"``, or "" when ``proc`` lists no such
    socket (not Linux, or the port is free by now)."""
    inodes: set[str] = set()
    for table in (f"net/{protocol}", f"net/{protocol}6"):
        try:
            lines = (proc / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 9 and fields[1].rpartition(":")[2] == f"{port:04X}":
                inodes.add(fields[9])
    inodes.discard("0")
    if not inodes:
        return ""
    wanted = {f"socket:[{i}]" for i in inodes}
    for pid_dir in proc.iterdir():
        if not pid_dir.name.isdigit():
            continue
        try:
            for fd in (pid_dir / "fd").iterdir():
                if os.readlink(fd) in wanted:
                    comm = (pid_dir / "comm").read_text().strip()
                    return f"pid {pid_dir.name} ({comm})"
        except OSError:
            continue  # another user's process, or gone
    return "another process (not visible to this user)"
