"""The transports' exception tree, with the situations that raise each one.

Edges translate what the libraries raise (``OSError``, ``serial.SerialException``,
``asyncio`` timeouts) into these, so a caller handles one small tree, the way
python-can's ``can/exceptions.py`` does::

    TransportError
     ├── TransportURLError      (also a ValueError)
     ├── TransportOpenError
     ├── TransportClosed
     │    └── LinkDown
     └── TransportTimeout
"""

from __future__ import annotations


class TransportError(Exception):
    """Base of everything a transport raises.

    Also raised as is when a backend cannot be loaded at all, e.g. ``serial:`` without
    pyserial installed (the message names the package to install).
    """


class TransportURLError(TransportError, ValueError):
    """A transport URL that cannot be understood; the message names the bad part.

    Examples: ``ser:/dev/ttyAMA0`` (unknown scheme), ``udpin:0.0.0.0`` (no port),
    ``tcp:localhost:http`` (port not a number), ``serial:/dev/ttyAMA0:9`` (baud rate out
    of range), ``serial::921600`` (empty device path).
    """


class TransportOpenError(TransportError):
    """The link could not be opened.

    Examples: ``/dev/ttyAMA0`` does not exist (UART not enabled, USB adapter unplugged);
    permission denied (the service user is not in ``dialout``); the port is locked by
    another process (a second daemon, ModemManager); TCP connection refused or timed
    out (SITL not started yet); ``udpin`` port already in use.
    """


class TransportClosed(TransportError):
    """``recv()`` or ``send()`` on a transport that is closed.

    Examples: after our own ``close()`` (recv raises at once, also in a task already
    waiting); the peer went away (TCP peer closed the connection, the other end of a
    memory pair was closed); the device hung up (USB serial adapter unplugged, the
    socat behind a pty exited). Data received before the loss is delivered first.
    """


class LinkDown(TransportClosed):
    """A :class:`ReconnectingTransport`'s link is down and being reopened.

    Raised by ``recv()`` during the outage (after delivering what arrived before it)
    instead of waiting an unknown time; ``await transport.wait_connected()`` and call
    ``recv()`` again. A caller that only catches :class:`TransportClosed` ends its loop,
    which is the right thing for a caller that cannot handle reconnection.
    """


class TransportTimeout(TransportError):
    """An operation did not finish in time.

    Examples: ``send()`` could not write within ``write_timeout_s`` because the peer
    stopped reading (a pty or a TCP peer whose buffers are full, a UART whose RTS/CTS
    flow control holds us off) — part of the data may have been written, and MAVLink
    receivers resynchronise on the next frame; ``send()`` while a
    :class:`ReconnectingTransport` is reconnecting (raised at once, nothing written);
    ``recv(timeout=...)`` with nothing received; ``wait_connected(timeout=...)``.
    """
