"""One daemon thread per camera: open, read, validate, hand frames to the daemon.

The idea of python-can's ``Notifier`` (``can/notifier.py``): blocking IO — here
``FrameSource.read()`` — runs in its own thread and hands each result to a callback;
the daemon passes a callback that does ``loop.call_soon_threadsafe(...)``, so the event
loop never blocks on a camera.

The thread never dies of a source's failure:

- ``open()`` fails → ``open_failures += 1``, state ``"failed"``, back off (0.1 s, 0.2 s, …
  up to ``max_backoff_s``) and try again.
- ``read()`` raises :class:`CameraGone` (or any other exception, which is logged with
  its traceback and treated alike) → ``read_errors += 1``, state ``"lost"``, close, back
  off, reopen (``reconnects += 1`` and state ``"reconnected"`` when that succeeds). A
  *finite* source (``live = False``: file, frames directory, scenario) is not reopened —
  it would replay frames already delivered — and ends instead.
- ``read()`` raises :class:`EndOfStream` → ``ended = True``, state ``"ended"``, the thread
  exits.

The decisions (open, read, accept or reject, reconnect with backoff) are one state
machine, :class:`ReaderCore`, taking one step per call on a caller's clock; the thread
runs it in a loop and sleeps its backoffs, and the virtual-time SITL
(:mod:`tcm_companion.sitl.virtual`) steps the same machine on a simulated clock.

Stopping: ``stop()`` sets a flag, calls the source's :meth:`FrameSource.interrupt` (which
wakes the paced and simulated sources' waits at once) and joins the thread for at most
``timeout_s``. It never closes the source from its own thread — OpenCV's
``VideoCapture`` is not thread-safe, and releasing it under a blocked ``read()`` can
crash in the driver wrapper — so sources must keep ``read()`` short instead: OpenCV
devices wait at most ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` (1 s, see :mod:`.opencv`).
If a read is stuck longer, ``stop()`` still returns after ``timeout_s`` (returning
False); the daemon thread closes the source itself when ``read()`` comes back.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from ..aio import monotonic_us
from .base import CameraGone, CameraStats, EndOfStream, Frame, FrameSource

log = logging.getLogger(__name__)

#: States reported to ``on_state`` (on transitions only).
STATES = ("open", "lost", "reconnected", "ended", "failed")


@dataclass(frozen=True)
class ReaderStep:
    """What one :meth:`ReaderCore.step` did: a frame to deliver, a backoff to wait
    before the next step (s; 0: step again at once), or the end of reading.
    ``t_image_us``: the capture time of the image read, accepted or rejected."""

    frame: Frame | None = None
    wait_s: float = 0.0
    finished: bool = False
    t_image_us: int | None = None


class ReaderCore:
    """One camera's reading, a step at a time: open (with backoff), read, validate,
    reconnect — what :class:`CameraReader`'s thread does, without the thread.

    ``step(clock_us, stopping)`` opens the source if it is closed, otherwise reads one
    image; it blocks only as long as the source's ``open()`` / ``read()`` do.
    ``clock_us`` stamps an image whose source gives no capture time (right after
    ``read()`` returned); ``stopping()`` says a stop was asked for (a read that returns
    after it is discarded, not counted). Stats are read under a lock from any thread.
    """

    def __init__(
        self,
        source: FrameSource,
        camera_id: int,
        *,
        initial_backoff_s: float = 0.1,
        max_backoff_s: float = 2.0,
        on_state: Callable[[str, str], None] | None = None,
        no_future: bool = False,
    ) -> None:
        if not (initial_backoff_s > 0 and max_backoff_s >= initial_backoff_s):
            raise ValueError("need 0 < initial_backoff_s <= max_backoff_s")
        self.source = source
        self.no_future = no_future
        self.camera_id = camera_id
        self.on_state = on_state
        self.initial_backoff_s = float(initial_backoff_s)
        self.max_backoff_s = float(max_backoff_s)
        self._lock = threading.Lock()
        self._stats = CameraStats()
        self._backoff_s = self.initial_backoff_s
        self._state = "idle"
        self._last_frame_us: int | None = None
        self._warned: set[str] = set()
        self._opened = False
        self._lost = False  # a loss happened and no open has succeeded since

    @property
    def stats(self) -> CameraStats:
        with self._lock:
            return dataclasses.replace(self._stats)

    @property
    def last_frame_us(self) -> int | None:
        return self._last_frame_us

    @property
    def state(self) -> str:
        return self._state

    def step(self, clock_us: Callable[[], int], stopping: Callable[[], bool]) -> ReaderStep:
        """Open the source, or read one image from it; see the class docstring."""
        if not self._opened:
            return self._open(stopping)
        src = self.source
        outcome = ""
        try:
            image, t_us = src.read()
            now_us = clock_us()
        except EndOfStream:
            outcome = "stop" if stopping() else "ended"
        except CameraGone as exc:
            if stopping():
                outcome = "stop"
            else:
                with self._lock:
                    self._stats.read_errors += 1
                    self._stats.last_error = str(exc)
                log.warning("camera %s: lost (%s)", src.name, exc)
                outcome = "lost"
        except Exception as exc:
            if stopping():
                outcome = "stop"
            else:
                with self._lock:
                    self._stats.read_errors += 1
                    self._stats.last_error = f"read() raised {exc!r}"
                log.warning(
                    "camera %s: read() raised %r; treated as lost", src.name, exc, exc_info=True
                )
                outcome = "lost"
        else:
            if stopping():
                outcome = "stop"  # read after stop: discarded, not counted
            else:
                # The source answers again: the next loss starts the backoff from the start.
                self._backoff_s = self.initial_backoff_s
                t_image_us = now_us if t_us is None else int(t_us)
                if self.no_future and t_image_us > now_us:
                    # A source's own series that runs ahead of the clock (a file read as
                    # fast as possible, realtime = false): a frame is not captured after
                    # it was read, so its time on this clock is the read's.
                    t_image_us = now_us
                    with self._lock:
                        self._stats.restamped += 1
                return ReaderStep(self._accept(image, t_image_us), t_image_us=t_image_us)
        self.close()
        if outcome == "stop":
            return ReaderStep(finished=True)
        if outcome == "ended" or not src.live:
            with self._lock:
                self._stats.ended = True
            log.info("camera %s: ended", src.name)
            self._set_state("ended")
            return ReaderStep(finished=True)
        self._lost = True
        self._set_state("lost")
        return ReaderStep(wait_s=self._back_off())

    def _open(self, stopping: Callable[[], bool]) -> ReaderStep:
        src = self.source
        try:
            src.open()
        except Exception as exc:
            with self._lock:
                self._stats.open_failures += 1
                self._stats.last_error = str(exc)
            log.warning(
                "camera %s: open failed (%s); retrying in %.1f s", src.name, exc, self._backoff_s
            )
            self._set_state("failed")
            self.close()
            return ReaderStep(wait_s=self._back_off())
        self._opened = True
        if stopping():
            return ReaderStep(finished=True)
        if self._lost:
            with self._lock:
                self._stats.reconnects += 1
            log.info("camera %s: reconnected", src.name)
            self._set_state("reconnected")
            self._lost = False
        else:
            log.info("camera %s: open", src.name)
            self._set_state("open")
        return ReaderStep()

    def _back_off(self) -> float:
        """The current backoff (s), doubled for next time up to ``max_backoff_s``."""
        wait = self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, self.max_backoff_s)
        return wait

    def _accept(self, image: np.ndarray | None, t_us: int) -> Frame | None:
        src = self.source
        reason = _reject_reason(image, src.width, src.height)
        if reason is not None:
            with self._lock:
                self._stats.captured += 1
                if reason == "empty":
                    self._stats.rejected_empty += 1
                else:
                    self._stats.rejected_size += 1
            if reason not in self._warned:  # once per kind: the counters tell the rest
                self._warned.add(reason)
                log.warning(
                    "camera %s: rejected %s image (%s); expected %dx%dx3 uint8",
                    src.name,
                    reason,
                    _describe(image),
                    src.width,
                    src.height,
                )
            return None
        assert image is not None
        retimed = self._last_frame_us is not None and t_us <= self._last_frame_us
        if retimed:
            assert self._last_frame_us is not None
            t_us = self._last_frame_us + 1
        with self._lock:
            seq = self._stats.delivered
            self._stats.captured += 1
            self._stats.delivered += 1
            self._stats.retimed += int(retimed)
        self._last_frame_us = t_us
        return Frame(self.camera_id, seq, t_us, image)

    def close(self) -> None:
        """Close the source (safe to call twice)."""
        self._opened = False
        try:
            self.source.close()
        except Exception:
            log.exception("camera %s: close() failed", self.source.name)

    def _set_state(self, state: str) -> None:
        if state == self._state:
            return
        self._state = state
        if self.on_state is not None:
            try:
                self.on_state(self.source.name, state)
            except Exception:
                log.exception("camera %s: on_state failed", self.source.name)


class CameraReader:
    """Read one :class:`FrameSource` in a daemon thread and deliver :class:`Frame` objects.

    ``on_frame(frame)`` is called from the reader thread for every accepted image, with
    ``frame.t_capture_us`` on the companion monotonic clock (µs): the source's time, or
    ``clock_us()`` taken right after ``read()`` returned when the source gives None.
    Capture times are strictly increasing (a source time not after the previous frame's
    is moved to previous + 1 µs and counted in ``stats.retimed``); with ``no_future`` (the
    daemon's readers) never later than the read (a source time after ``clock_us()`` at
    the read is taken as that, counted in ``stats.restamped``: a file read as fast as
    possible has a series of times of its own, ahead of the clock) and ``frame.seq``
    counts delivered frames 0, 1, 2, … across reconnects.

    ``on_state(camera_name, state)`` is called on transitions between ``"open"``,
    ``"lost"``, ``"reconnected"``, ``"ended"`` and ``"failed"`` (open failed).
    """

    def __init__(
        self,
        source: FrameSource,
        camera_id: int,
        on_frame: Callable[[Frame], None],
        *,
        clock_us: Callable[[], int] = monotonic_us,
        initial_backoff_s: float = 0.1,
        max_backoff_s: float = 2.0,
        on_state: Callable[[str, str], None] | None = None,
        no_future: bool = False,
    ) -> None:
        self.core = ReaderCore(
            source,
            camera_id,
            initial_backoff_s=initial_backoff_s,
            max_backoff_s=max_backoff_s,
            on_state=on_state,
            no_future=no_future,
        )
        self.source = source
        self.camera_id = camera_id
        self.on_frame = on_frame
        self.clock_us = clock_us
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- public ----------------------------------------------------------------------
    def start(self) -> None:
        """Start the reader thread (once per reader)."""
        if self._thread is not None:
            raise RuntimeError(f"camera {self.source.name}: reader already started")
        self._thread = threading.Thread(
            target=self._run, name=f"camera-{self.camera_id}-{self.source.name}", daemon=True
        )
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Ask the thread to finish and wait at most ``timeout_s``; True if it has finished.

        Returns within ``timeout_s`` even when ``read()`` is blocked in a driver (see the
        module docstring); the thread then closes the source when the read returns.
        """
        self._stop.set()
        try:
            self.source.interrupt()
        except Exception:
            log.exception("camera %s: interrupt() failed", self.source.name)
        if self._thread is None:
            return True
        self._thread.join(max(0.0, timeout_s))
        if self._thread.is_alive():
            log.warning(
                "camera %s: read() still blocked %.1f s after stop; the thread will "
                "close the source when it returns",
                self.source.name,
                timeout_s,
            )
            return False
        return True

    @property
    def stats(self) -> CameraStats:
        """A consistent snapshot: ``captured = delivered + rejected_empty + rejected_size``."""
        return self.core.stats

    @property
    def last_frame_us(self) -> int | None:
        """``t_capture_us`` of the last delivered frame (companion monotonic µs), or None."""
        return self.core.last_frame_us

    @property
    def alive(self) -> bool:
        """The reader thread is running (started, not stopped, source not ended)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def state(self) -> str:
        """The last state: ``"idle"`` before the first open attempt, then one of ``STATES``."""
        return self.core.state

    # -- thread ------------------------------------------------------------------------
    def _run(self) -> None:
        core = self.core
        try:
            while not self._stop.is_set():
                step = core.step(self.clock_us, self._stop.is_set)
                if step.frame is not None:
                    try:
                        self.on_frame(step.frame)
                    except Exception:  # e.g. the event loop closed under us; keep reading
                        log.exception("camera %s: on_frame failed", self.source.name)
                if step.finished:
                    break
                # Sleep the backoff, woken by stop.
                if step.wait_s > 0 and self._stop.wait(step.wait_s):
                    break
        except BaseException:  # a bug of ours; never leave the source open
            log.exception("camera %s: reader thread crashed", self.source.name)
            raise
        finally:
            core.close()


def _reject_reason(image: object, width: int, height: int) -> str | None:
    """``"empty"``, ``"size"`` or None (accepted) for a BGR uint8 (height, width, 3) image."""
    if image is None:
        return "empty"
    if not isinstance(image, np.ndarray):
        return "size"
    if image.size == 0:
        return "empty"
    if image.shape != (height, width, 3) or image.dtype != np.uint8:
        return "size"
    if not _any_nonzero(image):
        return "empty"
    return None


def _any_nonzero(image: np.ndarray) -> bool:
    """``image.any()`` for a (h, w, 3) uint8 frame: OpenCV's ``hasNonZero`` stops at the
    first non-zero byte, where numpy casts and reads all of it (~240 kB a frame at
    360×220, from a cold cache on the camera thread); tests/test_fast_paths.py holds the
    two equal."""
    return bool(cv2.hasNonZero(image.reshape(image.shape[0], -1)))


def _describe(image: object) -> str:
    if image is None:
        return "None"
    if isinstance(image, np.ndarray):
        return f"shape {image.shape} {image.dtype}"
    return type(image).__name__
