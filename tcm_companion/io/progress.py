"""Progress on long work, with or without tqdm.

tqdm draws the bar when it is installed (the ``tools`` extra: ``pip install
'tcm-companion[tools]'``; ``make`` installs it); without it a plain line on stderr every
10% says how far the work is, so a drone's small install still reports progress.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO, TypeVar

T = TypeVar("T")


class _Lines:
    """The fallback bar: ``desc: 40% (40/100 frames, 3.1 s)`` at every 10% step."""

    def __init__(self, total: int, desc: str, unit: str, stream: TextIO) -> None:
        self.total, self.desc, self.unit, self.stream = max(0, total), desc, unit, stream
        self.n = 0
        self._next_pct = 10
        self._t0 = time.monotonic()

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.total <= 0:
            return
        pct = 100 * self.n // self.total
        if pct >= self._next_pct:
            self._next_pct = (pct // 10 + 1) * 10
            self.stream.write(
                f"{self.desc}: {pct}% ({self.n}/{self.total} {self.unit}s,"
                f" {time.monotonic() - self._t0:.1f} s)\n"
            )
            self.stream.flush()

    def close(self) -> None:
        pass

    def __enter__(self) -> _Lines:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Off:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> _Off:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def progress(total: int, desc: str, enabled: bool = True, unit: str = "frame") -> Any:
    """A context manager with ``update(n)``: tqdm's bar on stderr, or plain lines."""
    if not enabled:
        return _Off()
    try:
        from tqdm import tqdm
    except ImportError:
        return _Lines(total, desc, unit, sys.stderr)
    return tqdm(total=total, desc=desc, unit=unit, leave=False, file=sys.stderr)


def track(items: Iterable[T], total: int, desc: str, unit: str = "frame") -> Iterator[T]:
    """``items`` with progress reported as they are consumed."""
    with progress(total, desc, True, unit) as bar:
        for item in items:
            yield item
            bar.update(1)
