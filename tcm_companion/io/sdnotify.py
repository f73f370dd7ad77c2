"""A small client for systemd's service notification protocol (``sd_notify``).

Under ``Type=notify`` systemd passes the path of a datagram socket in ``$NOTIFY_SOCKET``;
the service sends it newline-separated ``KEY=VALUE`` lines in one ``AF_UNIX`` /
``SOCK_DGRAM`` datagram: ``READY=1`` once it is serving (the unit becomes *active*),
``STATUS=...`` for the line ``systemctl status`` shows, ``WATCHDOG=1`` as the keep-alive
for ``WatchdogSec=``, ``STOPPING=1`` when it begins to shut down. A value starting with
``@`` names a socket in the Linux abstract namespace (the ``@`` stands for a leading NUL
byte). systemd documents this protocol as stable, so it is implemented here rather than
taken from a library. The kernel attaches the sender's credentials (the manager's socket
has ``SO_PASSCRED``); with ``NotifyAccess=main`` only the main process is listened to, so
send from the daemon's process (any thread), never from a child.

A notification must never take the daemon down or stall it: the socket is non-blocking,
created once and reused, and every failure (socket gone, ``ECONNREFUSED``, a full queue's
``EAGAIN``, a path too long) is counted in :attr:`Notifier.errors` and reported by a
``False`` return, never raised. Without ``$NOTIFY_SOCKET`` (run by hand, in tests) the
notifier is disabled and every call is a no-op returning ``False``.

Watchdog: with ``WatchdogSec=`` systemd sets ``$WATCHDOG_USEC`` (and ``$WATCHDOG_PID``);
:func:`watchdog_interval_us` turns them into the ping interval. Ping from the event loop
(a timer every interval), and only while the work is actually progressing, so a stuck
loop or a stalled pipeline stops the pings and systemd restarts the service.
"""

from __future__ import annotations

import os
import re
import socket
import threading
from collections.abc import Mapping

__all__ = ["Notifier", "watchdog_interval_us"]

# systemd reads one datagram into a buffer of this size; longer messages are cut off.
MAX_MESSAGE_BYTES = 4096
_KEY = re.compile(r"[A-Z][A-Z0-9_]*\Z")


def watchdog_interval_us(
    environ: Mapping[str, str] = os.environ, pid: int | None = None
) -> int | None:
    """How often (µs) to send ``WATCHDOG=1``, or None when no watchdog is expected.

    ``$WATCHDOG_USEC`` is the timeout systemd enforces (``WatchdogSec=``). If
    ``$WATCHDOG_PID`` is set and is not this process (``pid``, default ``os.getpid()``),
    the variables were inherited from a parent and are not ours: None. A missing,
    malformed, zero or negative value: None. The interval returned is half the timeout,
    as sd_watchdog_enabled(3) recommends, so one late or lost ping does not trip it.
    """
    raw = environ.get("WATCHDOG_USEC", "").strip()
    if not raw:
        return None
    watchdog_pid = environ.get("WATCHDOG_PID", "").strip()
    if watchdog_pid:
        try:
            if int(watchdog_pid) != (os.getpid() if pid is None else pid):
                return None
        except ValueError:
            return None
    try:
        timeout_us = int(raw)
    except ValueError:
        return None
    if timeout_us <= 0:
        return None
    return max(1, timeout_us // 2)


def _clean_value(value: object) -> str:
    # One field per line: a newline inside a value would start a bogus field.
    return str(value).replace("\r", " ").replace("\n", " ")


class Notifier:
    """Sends notifications to the service manager; never raises on a failed send.

    ``address`` is ``$NOTIFY_SOCKET`` as systemd sets it (an absolute path, or ``@name``
    for the abstract namespace); None (or anything else) gives a disabled notifier.
    """

    def __init__(self, address: str | None) -> None:
        self.address = address or None
        self._sockaddr: bytes | None = None
        if self.address is not None:
            if self.address.startswith("@") and len(self.address) > 1:
                self._sockaddr = b"\0" + os.fsencode(self.address[1:])
            elif self.address.startswith("/"):
                self._sockaddr = os.fsencode(self.address)
            # anything else (e.g. systemd 254's "vsock:..."): not supported, disabled
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self.sent = 0  # datagrams delivered to the socket
        self.errors = 0  # sends that failed (counted, never raised)
        self.last_error: Exception | None = None

    @classmethod
    def from_env(cls, environ: Mapping[str, str] = os.environ) -> Notifier:
        """The notifier ``$NOTIFY_SOCKET`` names (disabled when unset or empty)."""
        return cls(environ.get("NOTIFY_SOCKET") or None)

    @property
    def enabled(self) -> bool:
        """True when there is a manager socket to send to."""
        return self._sockaddr is not None

    # -- the messages the daemon sends ------------------------------------------------

    def ready(self, status: str = "") -> bool:
        """``READY=1`` (plus ``STATUS=`` if given): start-up is complete."""
        return self.notify(READY=1, STATUS=status) if status else self.notify(READY=1)

    def status(self, text: str) -> bool:
        """``STATUS=text``: the one-line state ``systemctl status`` shows."""
        return self.notify(STATUS=text)

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: the keep-alive ping for ``WatchdogSec=``."""
        return self.notify(WATCHDOG=1)

    def stopping(self, status: str = "") -> bool:
        """``STOPPING=1`` (plus ``STATUS=`` if given): shutdown has begun."""
        return self.notify(STOPPING=1, STATUS=status) if status else self.notify(STOPPING=1)

    def extend_timeout(self, usec: int) -> bool:
        """``EXTEND_TIMEOUT_USEC=usec``: start-up or shutdown needs ``usec`` more."""
        return self.notify(EXTEND_TIMEOUT_USEC=int(usec))

    # -- the protocol ------------------------------------------------------------------

    def notify(self, **fields: object) -> bool:
        """Send ``KEY=VALUE`` lines in one datagram, in the order given.

        Keys are upper-case names (``READY``, ``STATUS``, ...); newlines in values become
        spaces. True when the datagram was handed to the socket; a key that is not an
        upper-case name sends nothing and counts as an error.
        """
        bad = [key for key in fields if not _KEY.match(key)]
        if bad:  # a caller's mistake, but still not worth a crash: counted like a failed send
            if self._sockaddr is not None:
                with self._lock:
                    self.errors += 1
                    self.last_error = ValueError(f"not a notification field name: {bad[0]!r}")
            return False
        return self.send("\n".join(f"{k}={_clean_value(v)}" for k, v in fields.items()))

    def send(self, text: str) -> bool:
        """Send ``text`` as it is (already ``KEY=VALUE`` lines) in one datagram.

        A message longer than systemd's 4 KiB buffer is cut to fit. False (and counted in
        :attr:`errors` unless disabled) when it could not be sent.
        """
        if self._sockaddr is None:
            return False
        data = text.encode("utf-8", errors="replace")
        if len(data) > MAX_MESSAGE_BYTES:  # cut, without leaving half a character
            data = data[:MAX_MESSAGE_BYTES].decode("utf-8", errors="ignore").encode("utf-8")
        with self._lock:
            try:
                if self._sock is None:
                    self._sock = socket.socket(
                        socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC
                    )
                    self._sock.setblocking(False)
                self._sock.sendto(data, self._sockaddr)
            except (OSError, ValueError) as exc:
                # OSError: ENOENT/ECONNREFUSED (manager socket gone), EAGAIN (its queue is
                # full), EMSGSIZE, a path too long for sun_path; ValueError: a NUL in a path.
                self.errors += 1
                self.last_error = exc
                return False
            self.sent += 1
            return True

    def close(self) -> None:
        """Close the socket (a later send opens a new one)."""
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"Notifier(address={self.address!r}, enabled={self.enabled}, "
            f"sent={self.sent}, errors={self.errors})"
        )
