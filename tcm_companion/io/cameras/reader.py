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

import numpy as np

from .base import CameraGone, CameraStats, EndOfStream, Frame, FrameSource, monotonic_us

log = logging.getLogger(__name__)

#: States reported to ``on_state`` (on transitions only).
STATES = ("open", "lost", "reconnected", "ended", "failed")


class CameraReader:
    """Read one :class:`FrameSource` in a daemon thread and deliver :class:`Frame` objects.

    ``on_frame(frame)`` is called from the reader thread for every accepted image, with
    ``frame.t_capture_us`` on the companion monotonic clock (µs): the source's time, or
    ``clock_us()`` taken right after ``read()`` returned when the source gives None.
    Capture times are strictly increasing (a source time not after the previous frame's
    is moved to previous + 1 µs and counted in ``stats.retimed``) and ``frame.seq``
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
    ) -> None:
        if not (initial_backoff_s > 0 and max_backoff_s >= initial_backoff_s):
            raise ValueError("need 0 < initial_backoff_s <= max_backoff_s")
        self.source = source
        self.camera_id = camera_id
        self.on_frame = on_frame
        self.on_state = on_state
        self.clock_us = clock_us
        self.initial_backoff_s = float(initial_backoff_s)
        self.max_backoff_s = float(max_backoff_s)

        self._lock = threading.Lock()
        self._stats = CameraStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._backoff_s = self.initial_backoff_s
        self._state = "idle"
        self._last_frame_us: int | None = None
        self._warned: set[str] = set()

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
        with self._lock:
            return dataclasses.replace(self._stats)

    @property
    def last_frame_us(self) -> int | None:
        """``t_capture_us`` of the last delivered frame (companion monotonic µs), or None."""
        return self._last_frame_us

    @property
    def alive(self) -> bool:
        """The reader thread is running (started, not stopped, source not ended)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def state(self) -> str:
        """The last state: ``"idle"`` before the first open attempt, then one of ``STATES``."""
        return self._state

    # -- thread ------------------------------------------------------------------------
    def _run(self) -> None:
        src = self.source
        lost = False  # a loss happened and no open has succeeded since
        try:
            while not self._stop.is_set():
                try:
                    src.open()
                except Exception as exc:
                    with self._lock:
                        self._stats.open_failures += 1
                    log.warning(
                        "camera %s: open failed (%s); retrying in %.1f s",
                        src.name,
                        exc,
                        self._backoff_s,
                    )
                    self._set_state("failed")
                    self._close()
                    if self._back_off():
                        break
                    continue
                if self._stop.is_set():
                    break
                if lost:
                    with self._lock:
                        self._stats.reconnects += 1
                    log.info("camera %s: reconnected", src.name)
                    self._set_state("reconnected")
                    lost = False
                else:
                    log.info("camera %s: open", src.name)
                    self._set_state("open")

                outcome = self._read_until_done()
                self._close()
                if outcome == "stop":
                    break
                if outcome == "ended" or not src.live:
                    with self._lock:
                        self._stats.ended = True
                    log.info("camera %s: ended", src.name)
                    self._set_state("ended")
                    break
                lost = True
                self._set_state("lost")
                if self._back_off():
                    break
        except BaseException:  # a bug of ours; never leave the source open
            log.exception("camera %s: reader thread crashed", src.name)
            raise
        finally:
            self._close()

    def _read_until_done(self) -> str:
        """Read until the source is lost (``"lost"``), ends (``"ended"``) or stop (``"stop"``)."""
        src = self.source
        while not self._stop.is_set():
            try:
                image, t_us = src.read()
                now_us = self.clock_us()
            except EndOfStream:
                return "stop" if self._stop.is_set() else "ended"
            except CameraGone as exc:
                if self._stop.is_set():
                    return "stop"
                with self._lock:
                    self._stats.read_errors += 1
                log.warning("camera %s: lost (%s)", src.name, exc)
                return "lost"
            except Exception as exc:
                if self._stop.is_set():
                    return "stop"
                with self._lock:
                    self._stats.read_errors += 1
                log.warning(
                    "camera %s: read() raised %r; treated as lost", src.name, exc, exc_info=True
                )
                return "lost"
            if self._stop.is_set():
                return "stop"  # read after stop: discarded, not counted
            # The source answers again: the next loss starts the backoff from the beginning.
            self._backoff_s = self.initial_backoff_s
            self._accept(image, now_us if t_us is None else int(t_us))
        return "stop"

    def _accept(self, image: np.ndarray | None, t_us: int) -> None:
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
            return
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
        try:
            self.on_frame(Frame(self.camera_id, seq, t_us, image))
        except Exception:  # e.g. the event loop closed under us; keep reading
            log.exception("camera %s: on_frame failed", src.name)

    def _back_off(self) -> bool:
        """Sleep the current backoff (woken by stop) and double it; True if stopping."""
        stopping = self._stop.wait(self._backoff_s)
        self._backoff_s = min(self._backoff_s * 2.0, self.max_backoff_s)
        return stopping

    def _close(self) -> None:
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
    if not image.any():
        return "empty"
    return None


def _describe(image: object) -> str:
    if image is None:
        return "None"
    if isinstance(image, np.ndarray):
        return f"shape {image.shape} {image.dtype}"
    return type(image).__name__
