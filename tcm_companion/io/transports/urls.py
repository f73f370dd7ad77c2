"""Parsing the parts of transport URLs, with errors that name the bad part."""

from __future__ import annotations

from .errors import TransportURLError


def parse_port(url: str, text: str, *, allow_zero: bool = False) -> int:
    """A TCP/UDP port number; 0 (any free port) only where binding makes it meaningful."""
    lowest = 0 if allow_zero else 1
    if not text.isdigit() or not lowest <= int(text) <= 65535:
        raise TransportURLError(f"{url!r}: port {text!r} is not a number from {lowest} to 65535")
    return int(text)


def parse_host_port(url: str, rest: str, *, allow_zero_port: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` or ``[IPV6]:PORT`` after the scheme."""
    host, sep, port_text = rest.rpartition(":")
    if not sep:
        raise TransportURLError(f"{url!r}: expected HOST:PORT after the scheme, got {rest!r}")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host:
        raise TransportURLError(f"{url!r}: the host before ':{port_text}' is empty")
    return host, parse_port(url, port_text, allow_zero=allow_zero_port)


DEFAULT_BAUD = 115200  # pymavlink's and MAVProxy's default
_BAUD_RANGE = (50, 20_000_000)


def parse_serial(url: str, rest: str) -> tuple[str, int]:
    """``PATH[:BAUD]``. Device paths may contain colons (``/dev/serial/by-path/...``), so
    only an all-digit last part is a baud rate."""
    path, sep, baud_text = rest.rpartition(":")
    if not sep or not baud_text.isdigit():
        path, baud = rest, DEFAULT_BAUD
    else:
        baud = int(baud_text)
        if not _BAUD_RANGE[0] <= baud <= _BAUD_RANGE[1]:
            raise TransportURLError(
                f"{url!r}: baud rate {baud} is out of range {_BAUD_RANGE}; if ':{baud_text}' "
                "is part of the device path, add the baud rate: serial:PATH:BAUD"
            )
    if not path:
        raise TransportURLError(f"{url!r}: the device path is empty (serial:/dev/ttyAMA0:921600)")
    return path, baud
