"""SIGINT and SIGTERM end a command the same clean way: one line, no traceback, the
shell's status (128 + the signal: 130, 143), and every ``finally`` run on the way out,
so that an output being written is removed, not left as a hidden ``.NAME.*.tmp``.

Python turns SIGINT into :class:`KeyboardInterrupt`; :func:`sigterm_raises` turns SIGTERM
into :class:`Terminated` while a command runs (a second SIGTERM is ignored, so that the
clean-up is not cut short; SIGKILL still ends it). ``run`` and ``sitl`` put their own
handlers in place while they fly (:class:`RunSignals`: a clean stop, the summary, the
exit status; ``docs/daemon.md``) and these take over around them (:func:`interruptible`).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import asyncio


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


class RunSignals:
    """SIGINT and SIGTERM stop the run (``stop``); :attr:`received` says which came first.

    Exit status of a run a signal cut short (:meth:`exit_status`): 128 + the signal, the
    shell's convention (130 for SIGINT, 143 for SIGTERM) — except SIGTERM for ``run``,
    which is how systemd stops the service: that is a normal end (0).
    """

    HANDLED = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: signal.Signals | None = None

    def _got(self, sig: signal.Signals, stop: Callable[[], object]) -> None:
        if self.received is None:
            self.received = sig
        stop()

    def install(self, stop: asyncio.Event) -> None:
        """On the running event loop (real time): :func:`.event_loop.run_until_signal`
        installs them, once, for every real-time run."""
        import asyncio

        loop = asyncio.get_running_loop()
        for sig in self.HANDLED:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self._got, sig, stop.set)

    @contextlib.contextmanager
    def installed(self, stop: Callable[[], object]) -> Iterator[None]:
        """As Python signal handlers while the block runs (virtual time: no event loop)."""
        previous: dict[signal.Signals, Any] = {}
        for sig in self.HANDLED:

            def handler(signum: int, frame: Any, sig: signal.Signals = sig) -> None:
                self._got(sig, stop)

            with contextlib.suppress(ValueError):  # not the main thread
                previous[sig] = signal.signal(sig, handler)
        try:
            yield
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)

    def stopped_by(self, stopped_early: bool) -> str:
        """What ended a run: its signal's name if a signal cut it short ("" if not)."""
        return self.received.name if stopped_early and self.received is not None else ""

    @staticmethod
    def exit_status(ok: bool, stopped_by: str, *, service: bool = False) -> int:
        """0 (1 if the run failed); 128 + the signal that cut it short (see the class)."""
        if stopped_by in ("SIGINT", "SIGTERM") and not (service and stopped_by == "SIGTERM"):
            return 128 + int(signal.Signals[stopped_by])
        return 0 if ok else 1


def interruptible(cmd: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A Ctrl-C while the run's own handlers are not in place (loading the configuration
    and the imports before it, the moment after it) ends the command with 130 and one
    line, not a traceback."""

    def wrapped(args: argparse.Namespace) -> int:
        try:
            return cmd(args)
        except KeyboardInterrupt:
            print("\ninterrupted (SIGINT)", file=sys.stderr)
            return 128 + int(signal.SIGINT)

    wrapped.__doc__ = cmd.__doc__
    return wrapped
