"""SIGINT and SIGTERM end a command the same clean way: one line, no traceback, the
shell's status (128 + the signal: 130, 143), and every ``finally`` run on the way out,
so that an output being written is removed, not left as a hidden ``.NAME.*.tmp``.

Python turns SIGINT into :class:`KeyboardInterrupt`; :func:`sigterm_raises` turns SIGTERM
into :class:`Terminated` while a command runs (a second SIGTERM is ignored, so that the
clean-up is not cut short; SIGKILL still ends it). ``run`` and ``sitl`` put their own
handlers in place while they fly (a clean stop, the summary; ``docs/daemon.md``) and
these take over around them.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any


class Terminated(BaseException):
    """SIGTERM arrived (a BaseException, as KeyboardInterrupt is: ``except Exception``
    does not swallow it)."""


#: The exit status of a command that SIGINT or SIGTERM ended: 128 + the signal.
EXIT_SIGINT = 128 + int(signal.SIGINT)
EXIT_SIGTERM = 128 + int(signal.SIGTERM)


def _raise_terminated(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the clean-up runs to its end
    raise Terminated


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
