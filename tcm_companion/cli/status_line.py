"""The live status line of ``run`` and ``sitl`` on stderr, with log records kept above it,
and its ``--status-every`` option."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import threading
from collections.abc import Iterator
from typing import Any


class StatusPrinter:
    """The live one-line status on ``stream`` (stderr).

    On a terminal the line is rewritten in place, cut to the terminal's width, and log
    records never land on it: while it is shown (:meth:`logs_above`), the root logger's
    handlers that write to the same terminal are wrapped so that each record clears the
    line, is written, and the line is drawn again below it (one lock for both, as
    records come from the camera and flight-log threads too). Not a terminal (a pipe,
    the journal): a plain line every ``every`` status updates (once a second: every N
    s), and log records go out as they come, whole lines either way.
    """

    def __init__(self, stream: Any = None, every: int = 5) -> None:
        if every < 1:
            raise ValueError(f"every must be >= 1 (no printer at all for no status), got {every}")
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every = every
        self.n = 0
        self.lock = threading.RLock()
        self.shown = ""  # the line on the terminal now ("" none)
        self._wrapped: list[tuple[logging.Handler, AboveStatusLine]] = []

    def _width(self) -> int:
        try:
            columns = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):
            columns = 0
        return max(20, columns - 1) if columns > 0 else 199  # 0: the size is not known

    def __call__(self, line: str) -> None:
        with self.lock:
            self.n += 1
            if self.tty:
                # One physical row: a wrapped line could not be cleared by \r.
                self.shown = line[: self._width()]
                self.stream.write("\r\x1b[2K" + self.shown)
                self.stream.flush()
            elif (self.n - 1) % self.every == 0:
                self.stream.write(line + "\n")
                self.stream.flush()

    def erase(self) -> None:
        """Clear the line (the cursor back at its start); :meth:`redraw` puts it back."""
        with self.lock:
            if self.tty and self.shown:
                self.stream.write("\r\x1b[2K")
                self.stream.flush()

    def redraw(self) -> None:
        with self.lock:
            if self.tty and self.shown:
                self.stream.write(self.shown)
                self.stream.flush()

    def _same_stream(self, handler: logging.Handler) -> bool:
        stream = getattr(handler, "stream", None)
        if stream is None:
            return False
        if stream is self.stream:
            return True
        try:
            return os.path.samestat(os.fstat(stream.fileno()), os.fstat(self.stream.fileno()))
        except (AttributeError, OSError, ValueError):
            return False

    @contextlib.contextmanager
    def logs_above(self) -> Iterator[StatusPrinter]:
        """While the block runs, log records go above the live line (a terminal only);
        at its end the line is left as it was, with a new line after it."""
        root = logging.getLogger()
        if self.tty:
            for i, h in enumerate(root.handlers):  # in place: the order stays
                if isinstance(h, logging.StreamHandler) and self._same_stream(h):
                    above = AboveStatusLine(h, self)
                    root.handlers[i] = above
                    self._wrapped.append((h, above))
        try:
            yield self
        finally:
            for inner, wrapper in self._wrapped:
                if wrapper in root.handlers:
                    root.handlers[root.handlers.index(wrapper)] = inner
            self._wrapped.clear()
            self.done()

    def done(self) -> None:
        with self.lock:
            if self.tty and self.shown:
                self.stream.write("\n")
                self.stream.flush()
            self.shown = ""


class AboveStatusLine(logging.Handler):
    """A log handler that writes through ``inner`` above the printer's live line."""

    def __init__(self, inner: logging.Handler, printer: StatusPrinter) -> None:
        super().__init__(inner.level)
        self.inner = inner
        self.printer = printer

    def emit(self, record: logging.LogRecord) -> None:
        with self.printer.lock:
            self.printer.erase()
            try:
                self.inner.handle(record)
            finally:
                self.printer.redraw()


def status_printer(every: int, enabled: bool = True) -> contextlib.AbstractContextManager[Any]:
    """The live status line (:class:`StatusPrinter`, logs above it), or None when
    ``enabled`` is false or ``every`` is 0 (``--status-every 0``: no status line)."""
    if not enabled or every == 0:
        return contextlib.nullcontext(None)
    return StatusPrinter(every=every).logs_above()


def status_every(text: str) -> int:
    """``argparse`` type of ``--status-every``: whole seconds >= 0 (0: no status line)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(
            f"must be a whole number of seconds >= 0 (0: no status line), got {text!r}"
        )
    return value


def add_status_every(p: argparse.ArgumentParser) -> None:
    """``--status-every N`` (``run`` and ``sitl``)."""
    p.add_argument(
        "--status-every",
        type=status_every,
        default=5,
        metavar="N",
        help="status line every N s when not a terminal (default 5; 0: no status line)",
    )
