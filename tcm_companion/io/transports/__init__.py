"""Byte transports for MAVLink: serial, UDP, TCP and in-memory links behind one interface.

Thin asyncio edges around the sans-IO codec/endpoint: they move bytes and nothing else.
Open one by URL (python-can's backend registry is the model: backends are imported only
when used, and a bad URL gets an error naming the bad part)::

    async with open_transport("serial:/dev/ttyAMA0:921600", reconnect=True) as link:
        await link.send(codec.encode(msg))
        msgs = codec.feed(await link.recv())

URLs:

==============================  ===================================================
``serial:PATH[:BAUD]``          pyserial device or pty (baud default 115200)
``udpin:HOST:PORT``             listen; reply to the last peer that sent to us
``udpout:HOST:PORT``            send to a fixed peer, receive its replies
``tcp:HOST:PORT``               TCP client
``memory:NAME``                 in-process; two opened with one NAME are connected
==============================  ===================================================

Options (keyword arguments): ``write_timeout_s`` (1.0), ``max_rx_bytes`` (1 MiB) for
all; ``reconnect=True`` wraps serial and TCP links in a :class:`ReconnectingTransport`
(``initial_backoff_s`` 0.1, ``max_backoff_s`` 5.0; UDP and memory links cannot be lost,
so it changes nothing there); serial: ``exclusive`` (True), ``rtscts`` (False); UDP:
``max_datagram`` (1472); TCP: ``connect_timeout_s`` (5.0), ``write_buffer_bytes``
(64 KiB).
"""

from __future__ import annotations

import importlib
from typing import Any

from .base import DEFAULT_MAX_RX_BYTES, DEFAULT_WRITE_TIMEOUT_S, Transport
from .errors import (
    LinkDown,
    TransportClosed,
    TransportError,
    TransportOpenError,
    TransportTimeout,
    TransportURLError,
)
from .memory import MemoryTransport, memory_pair
from .reconnect import ReconnectingTransport
from .urls import check_url

__all__ = [
    "DEFAULT_MAX_RX_BYTES",
    "DEFAULT_WRITE_TIMEOUT_S",
    "LinkDown",
    "MemoryTransport",
    "ReconnectingTransport",
    "Transport",
    "TransportClosed",
    "TransportError",
    "TransportOpenError",
    "TransportTimeout",
    "TransportURLError",
    "check_url",
    "memory_pair",
    "open_transport",
]

# scheme -> (module, class); imported on first use so that e.g. UDP works without pyserial.
BACKENDS: dict[str, tuple[str, str]] = {
    "serial": (".serial_port", "SerialTransport"),
    "udpin": (".udp", "UdpTransport"),
    "udpout": (".udp", "UdpTransport"),
    "tcp": (".tcp", "TcpTransport"),
    "memory": (".memory", "MemoryTransport"),
}
RECONNECTABLE = frozenset({"serial", "tcp"})
# Import name -> what to pip install, for the error when a backend's library is missing.
_PIP_NAMES = {"serial": "pyserial>=3.5"}
_RECONNECT_OPTIONS = ("initial_backoff_s", "max_backoff_s")


def _backend(url: str, scheme: str) -> Any:
    module_name, class_name = BACKENDS[scheme]
    try:
        module = importlib.import_module(module_name, __name__)
    except ImportError as exc:
        missing = exc.name or "?"
        raise TransportError(
            f"{url!r}: the {scheme!r} transport needs the {missing!r} module "
            f"(pip install '{_PIP_NAMES.get(missing, missing)}')"
        ) from exc
    return getattr(module, class_name)


def open_transport(url: str, *, reconnect: bool = False, **options: Any) -> Transport:
    """The transport for ``url``, not yet open (``await t.open()`` or ``async with t``).

    Raises :class:`TransportURLError` for a URL that cannot be parsed and
    :class:`TransportError` when the backend's library is missing; device and network
    errors come from ``open()`` as :class:`TransportOpenError`.
    """
    scheme, sep, _ = url.partition(":")
    if not sep or scheme not in BACKENDS:
        known = ", ".join(f"{s}:" for s in BACKENDS)
        raise TransportURLError(
            f"{url!r}: unknown transport {scheme + sep!r}; expected one of {known}"
        )
    cls = _backend(url, scheme)
    wrapper_options = {k: options.pop(k) for k in _RECONNECT_OPTIONS if k in options}
    transport: Transport = cls.from_url(url, **options)  # parses: URL errors surface here
    if not reconnect or scheme not in RECONNECTABLE:
        if wrapper_options:
            raise TypeError(
                f"{sorted(wrapper_options)} only apply to serial: and tcp: links with reconnect=True"
            )
        return transport
    if "max_rx_bytes" in options:
        wrapper_options["max_rx_bytes"] = options["max_rx_bytes"]
    return ReconnectingTransport(lambda: cls.from_url(url, **options), url, **wrapper_options)
