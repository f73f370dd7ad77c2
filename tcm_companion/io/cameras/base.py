"""The camera contract: a blocking frame source, and the frame the daemon receives.

A :class:`FrameSource` is opened, read and closed from *one* reader thread
(:class:`~tcm_companion.io.cameras.reader.CameraReader`); it never touches the event
loop. ``read()`` blocks until the next image is there and returns it with its capture
time on the companion's monotonic clock in µs (:func:`~tcm_companion.io.aio.monotonic_us`), or
``None`` for the time when the source cannot tell (the reader then stamps the moment
``read()`` returned). Failures are exceptions, never silent empty frames:

- :class:`CameraGone` — the device disappeared or stopped answering; a *live* source
  is closed and reopened with backoff by the reader.
- :class:`EndOfStream` — a finite source (file, frames directory, scenario) is done.
- ``read()`` returning an image of the wrong size or an empty one is not an error of the
  source: the reader rejects and counts it (``CameraStats``).

``read()`` must not block for long: a source either waits with a short internal timeout
(V4L2's select timeout, see :mod:`.opencv`) or makes its waits wake on
:meth:`FrameSource.interrupt`, which the reader calls from another thread on ``stop()``.
:class:`Pacer` is the shared clock maths of the paced (``realtime``) sources.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


class CameraError(RuntimeError):
    """A camera cannot be opened or configured (bad device, bad settings)."""


class CameraGone(CameraError):
    """A live camera stopped delivering (unplugged, driver error); reopen it."""


class EndOfStream(Exception):
    """A finite source has no more frames."""


@dataclass(frozen=True)
class Frame:
    """One accepted image, as the daemon receives it."""

    camera_id: int
    seq: int  # frames this reader has delivered before this one (0, 1, 2, ...)
    t_capture_us: int  # companion monotonic clock
    image: np.ndarray  # BGR uint8 (height, width, 3)


@dataclass
class CameraStats:
    """Counters of one reader. ``captured = delivered + rejected_empty + rejected_size``."""

    captured: int = 0  # images read() returned (good or bad)
    delivered: int = 0  # handed to the daemon
    rejected_empty: int = 0  # None, zero-sized or all-zero images
    rejected_size: int = 0  # wrong width/height/channels/dtype
    read_errors: int = 0  # CameraGone raised by read()
    open_failures: int = 0  # open() raised
    reconnects: int = 0  # successful re-opens after a loss
    ended: bool = False  # a finite source reached its end
    retimed: int = 0  # delivered frames whose t_capture_us was moved forward to stay increasing
    last_error: str = ""  # why the last open() or read() failed ("" none yet)
    restamped: int = 0  # no_future readers: source times after the read, taken as the read's


class FrameSource(ABC):
    """A camera, video file, directory, simulator ... read from one thread."""

    #: Live sources (devices, pipelines, simulator) are reopened when lost; finite
    #: sources (file, frames directory, scenario) end with :class:`EndOfStream`.
    live: bool = True

    def __init__(self, name: str, width: int, height: int) -> None:
        self.name = name
        self.width = width
        self.height = height

    @abstractmethod
    def open(self) -> None:
        """Acquire the device or file. Raises :class:`CameraError`."""

    @abstractmethod
    def read(self) -> tuple[np.ndarray | None, int | None]:
        """Block for the next image: ``(BGR image or None, capture time µs or None)``.

        Raises :class:`CameraGone` (live source lost) or :class:`EndOfStream`.
        """

    @abstractmethod
    def close(self) -> None:
        """Release everything; safe to call twice and after a failed ``open``."""

    def interrupt(self) -> None:
        """Wake a ``read()`` blocked in this source's own wait; called from another thread.

        Only sets a flag or an event (never releases the device: OpenCV captures are not
        thread-safe). After it, ``read()`` may return early with anything; the reader
        discards it. The default does nothing (the source relies on a short timeout).
        """
        return None  # a hook with a default, deliberately not abstract

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self.width}x{self.height})"


class Pacer:
    """Absolute frame deadlines on the monotonic clock that do not drift.

    openpilot's Ratekeeper maths (``common/realtime.py``): frame ``k`` is due at
    ``anchor_us + rel_us(k)``, computed from the anchor each time rather than by adding
    periods to the previous deadline, so sleep overshoot never accumulates. A frame more
    than ``max_lag_us`` late moves the anchor forward (the frame is due *now*, later frames
    keep their spacing from it) and counts in ``late``. With ``realtime`` off nothing
    sleeps and the deadlines are simply ``anchor_us + rel_us`` (replay as fast as possible,
    still a proper series of capture times).

    The returned deadline is the frame's ``t_capture_us``: strictly increasing whenever
    ``rel_us`` is.
    """

    def __init__(
        self,
        clock_us: Callable[[], int],
        sleep: Callable[[float], object],
        realtime: bool,
        max_lag_us: int,
    ) -> None:
        self.clock_us = clock_us
        self.sleep = sleep
        self.realtime = realtime
        self.max_lag_us = max(1, int(max_lag_us))
        self.anchor_us = 0
        self.late = 0  # frames that re-anchored the schedule

    def start(self) -> None:
        """Anchor the schedule at the current time (frame with ``rel_us = 0`` is due now)."""
        self.anchor_us = int(self.clock_us())

    def wait(self, rel_us: int) -> int:
        """Wait (realtime) until the frame at ``rel_us`` after the anchor is due; its time (µs)."""
        deadline = self.anchor_us + int(rel_us)
        if not self.realtime:
            return deadline
        now = int(self.clock_us())
        lag = now - deadline
        if lag > self.max_lag_us:
            self.anchor_us += lag
            self.late += 1
            return now
        if lag < 0:
            self.sleep(-lag / 1e6)
        return deadline


class Waker:
    """An interruptible sleep: ``sleep(s)`` returns early once ``interrupt()`` was called."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._event.wait(seconds)

    def interrupt(self) -> None:
        self._event.set()

    def reset(self) -> None:
        self._event.clear()

    @property
    def interrupted(self) -> bool:
        return self._event.is_set()


class PacedSource(FrameSource):
    """A recording played as frames ``i = 0, 1, …`` at ``fps``: frame ``i``'s capture time
    is ``t_open + i / fps`` on ``clock_us``, waited for when ``realtime`` (:class:`Pacer`;
    otherwise nothing sleeps and the times are the same series). Finite unless ``loop``
    (then live: reopened when it fails). ``sleep`` defaults to an interruptible wait woken
    by :meth:`interrupt`. Subclasses call :meth:`_start` at the end of ``open`` and return
    :meth:`_paced` of each image from ``read``."""

    def __init__(
        self,
        name: str,
        width: int,
        height: int,
        *,
        realtime: bool,
        loop: bool,
        fps: float,
        clock_us: Callable[[], int],
        sleep: Callable[[float], object] | None,
    ) -> None:
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        super().__init__(name, width, height)
        self.realtime = realtime
        self.loop = loop
        self.live = loop
        self.fps = float(fps)
        self.clock_us = clock_us
        self._waker = Waker()
        self._sleep = sleep if sleep is not None else self._waker.sleep
        self.pacer = Pacer(clock_us, self._sleep, realtime, max_lag_us=round(1e6 / self.fps))
        self._index = 0  # frames returned since open

    def _start(self, fps: float | None = None) -> None:
        """Frame 0 is due now (``fps``: the rate the opened recording says it has)."""
        if fps is not None:
            self.fps = float(fps)
            self.pacer.max_lag_us = round(1e6 / self.fps)
        self._index = 0
        self.pacer.start()

    def _paced(self, image: np.ndarray | None) -> tuple[np.ndarray | None, int]:
        """``image`` as the next frame, with its capture time (waited for if realtime)."""
        t_us = self.pacer.wait(round(self._index * 1e6 / self.fps))
        self._index += 1
        return image, t_us

    def interrupt(self) -> None:
        self._waker.interrupt()
