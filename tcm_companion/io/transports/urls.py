"""Parsing the parts of transport URLs, with errors that name the bad part."""

from __future__ import annotations

import ipaddress
import re

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


#: One label of a host name (RFC 1123): letters, digits and hyphens, not at either end.
_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def check_host(url: str, host: str) -> str:
    """``host`` if it is an IPv4 or IPv6 address or a host name (RFC 1123 syntax; it is
    not resolved here), else a :class:`TransportURLError` naming it."""
    try:
        if ":" in host:
            ipaddress.IPv6Address(host)
        elif re.fullmatch(r"[0-9.]+", host):
            ipaddress.IPv4Address(host)
        elif len(host) > 253 or not all(_LABEL.fullmatch(p) for p in host.split(".")):
            raise ValueError(host)
    except ValueError:
        raise TransportURLError(f"{url!r}: {host!r} is not an IP address or a host name") from None
    return host


#: What ``check_url`` names as the URLs a link may have.
URL_FORMS = "serial:PATH[:BAUD], udpin:HOST:PORT, udpout:HOST:PORT or tcp:HOST:PORT"


def check_url(url: str, schemes: tuple[str, ...] = ("serial", "udpin", "udpout", "tcp")) -> None:
    """Raise :class:`TransportURLError` naming the bad part when ``url`` is not a link URL
    of one of ``schemes``: the scheme, the host's syntax, the port (1..65535; 0 = any
    free port for ``udpin``), the baud rate and the device path (absolute). Nothing is
    opened or resolved, and no backend is imported (pyserial may be missing)."""
    scheme, sep, rest = url.partition(":")
    if not sep or scheme not in schemes:
        raise TransportURLError(
            f"{url!r}: unknown transport {scheme + sep!r}; expected {URL_FORMS}"
        )
    if scheme == "serial":
        path, _ = parse_serial(url, rest)
        if not path.startswith("/") or re.search(r"[\s\x00]", path):
            raise TransportURLError(
                f"{url!r}: the device path {path!r} must be an absolute path without spaces"
                " (serial:/dev/ttyAMA0:921600)"
            )
        return
    if scheme == "memory":
        if not rest:
            raise TransportURLError(f"{url!r}: a memory URL needs a channel name")
        return
    host, _ = parse_host_port(url, rest, allow_zero_port=scheme == "udpin")
    check_host(url, host)
