"""OpenCV ``VideoCapture`` sources: a V4L2 device, a GStreamer pipeline, a video file.

Capture times. OpenCV's ``CAP_PROP_POS_MSEC`` on V4L2 is the driver's buffer timestamp,
which is on ``CLOCK_MONOTONIC`` only for drivers that say so (others copy the source's
clock or use the realtime clock) and which OpenCV versions report differently — not
reliably on the companion's monotonic clock. So a live frame's ``t_capture_us`` is the
monotonic clock read right after ``grab()`` returns: the moment the buffer was
dequeued, later than the middle of the exposure by about half the exposure plus the
transfer (a few ms, roughly constant for one camera and mode). ``CAP_PROP_BUFFERSIZE =
1`` is requested so a slow reader gets a fresh frame rather than a queued old one.

Blocking. V4L2 waits for each frame in ``select()`` with a timeout OpenCV reads once,
on the first capture, from ``OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT`` (seconds, default 10).
Importing this module sets it to 1 s unless the environment already sets it, so a
stalled camera makes ``read()`` fail (→ :class:`CameraGone`, reopen) within a second and
``CameraReader.stop()`` never waits on a dead device for long.

Files play at the file's frame rate (``realtime``) or as fast as possible; either way
capture times are a proper series ``start + i / fps`` (see :class:`~.base.Pacer`).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from ..aio import monotonic_us
from .base import CameraError, CameraGone, EndOfStream, FrameSource, PacedSource

log = logging.getLogger(__name__)

os.environ.setdefault("OPENCV_VIDEOIO_V4L_SELECT_TIMEOUT", "1")

#: V4L2's ``V4L2_CID_EXPOSURE_AUTO`` values as OpenCV's V4L2 backend passes them through
#: ``CAP_PROP_AUTO_EXPOSURE``: 1 = manual exposure, 3 = aperture priority (auto). Other
#: backends use other conventions (e.g. 0.25 / 0.75), hence ``api="any"`` leaves it alone.
V4L2_EXPOSURE_MANUAL = 1
V4L2_EXPOSURE_AUTO = 3

DEFAULT_FILE_FPS = 25.0

_APIS = {"v4l2": cv2.CAP_V4L2, "any": cv2.CAP_ANY}


def gstreamer_available() -> bool:
    """Whether this OpenCV build can open GStreamer pipelines (``cv2.getBuildInformation``)."""
    m = re.search(r"^\s*GStreamer:\s*(\S+)", cv2.getBuildInformation(), re.MULTILINE)
    return m is not None and m.group(1).upper() == "YES"


def _fps_or_default(value: float, default: float = DEFAULT_FILE_FPS) -> float:
    return value if math.isfinite(value) and 0.0 < value <= 1000.0 else default


class _CaptureSource(FrameSource):
    """A live ``cv2.VideoCapture``: ``grab()`` (stamp the clock) then ``retrieve()``."""

    def __init__(
        self, name: str, width: int, height: int, clock_us: Callable[[], int] = monotonic_us
    ) -> None:
        super().__init__(name, width, height)
        self.clock_us = clock_us
        self._cap: Any = None

    def read(self) -> tuple[np.ndarray | None, int | None]:
        cap = self._cap
        if cap is None:
            raise CameraGone(f"camera {self.name}: not open")
        if not cap.grab():
            raise CameraGone(f"camera {self.name}: grab() failed (unplugged or stalled)")
        t_us = self.clock_us()  # buffer dequeued: see the module docstring
        ok, image = cap.retrieve()
        if not ok:
            raise CameraGone(f"camera {self.name}: retrieve() failed")
        return image, t_us

    def close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def _check_size(self, cap: Any) -> None:
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if (w, h) != (0, 0) and (w, h) != (self.width, self.height):
            log.warning(
                "camera %s: delivers %dx%d, expected %dx%d (frames will be rejected)",
                self.name,
                w,
                h,
                self.width,
                self.height,
            )


class OpenCVDevice(_CaptureSource):
    """A V4L2 camera by index (``0``, ``"0"``) or path (``"/dev/video0"``).

    ``fps`` in frames per second; ``fourcc`` a four-character pixel format such as
    ``"MJPG"`` or ``"YUYV"`` (empty: the driver's default); ``exposure`` None for auto,
    else ``CAP_PROP_EXPOSURE`` in the driver's units (V4L2 ``exposure_absolute``: 100 µs
    steps) with auto exposure switched off. ``api="v4l2"`` forces the V4L2 backend;
    ``"any"`` lets OpenCV choose (and leaves exposure mode alone, see
    :data:`V4L2_EXPOSURE_MANUAL`).
    """

    def __init__(
        self,
        device: str | int,
        width: int,
        height: int,
        fps: float = 25.0,
        fourcc: str = "",
        exposure: float | None = None,
        api: Literal["v4l2", "any"] = "v4l2",
        *,
        clock_us: Callable[[], int] = monotonic_us,
        name: str | None = None,
    ) -> None:
        if api not in _APIS:
            raise ValueError(f"api must be one of {sorted(_APIS)}, got {api!r}")
        if fourcc and len(fourcc) != 4:
            raise ValueError(f"fourcc must be 4 characters (e.g. 'MJPG'), got {fourcc!r}")
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps!r}")
        self.device: str | int = device
        self.fps = float(fps)
        self.fourcc = fourcc
        self.exposure = exposure
        self.api = api
        super().__init__(name or str(device), width, height, clock_us)

    def _target(self) -> str | int:
        if isinstance(self.device, int):
            return self.device
        text = self.device.strip()
        return int(text) if text.isdigit() else text

    def open(self) -> None:
        self.close()
        target = self._target()
        if isinstance(target, str) and not Path(target).exists():
            raise CameraError(f"camera device {target}: no such device")
        cap = cv2.VideoCapture(target, _APIS[self.api])
        if not cap.isOpened():
            cap.release()
            raise CameraError(
                f"camera device {target}: cannot be opened "
                f"({'no such camera, busy, or no permission' if self.api == 'v4l2' else 'no backend opens it'})"
            )
        # V4L2 wants the pixel format before the size; every set() may be refused.
        if self.fourcc:
            self._set(cap, cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc), "fourcc")
        self._set(cap, cv2.CAP_PROP_FRAME_WIDTH, self.width, "width")
        self._set(cap, cv2.CAP_PROP_FRAME_HEIGHT, self.height, "height")
        self._set(cap, cv2.CAP_PROP_FPS, self.fps, "fps")
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # a fresh frame, not a queued one (if supported)
        if self.api == "v4l2":
            if self.exposure is None:
                self._set(cap, cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_AUTO, "auto exposure")
            else:
                self._set(cap, cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL, "manual exposure")
                self._set(cap, cv2.CAP_PROP_EXPOSURE, self.exposure, "exposure")
        elif self.exposure is not None:
            self._set(cap, cv2.CAP_PROP_EXPOSURE, self.exposure, "exposure")
        self._check_size(cap)
        self._cap = cap

    def _set(self, cap: Any, prop: int, value: float, what: str) -> None:
        if not cap.set(prop, value):
            log.warning("camera %s: the driver refused %s = %s", self.name, what, value)


class GStreamerSource(_CaptureSource):
    """A GStreamer pipeline ending in ``appsink`` (BGR), e.g.
    ``"v4l2src device=/dev/video0 ! videoconvert ! video/x-raw,format=BGR ! appsink drop=true max-buffers=1"``.

    Needs an OpenCV built with GStreamer; PyPI's ``opencv-python(-headless)`` wheels are
    not, and ``open()`` then says so. The V4L2 select timeout does not apply inside a
    pipeline: end it in ``appsink drop=true max-buffers=1`` and prefer sources that
    error out when the device goes (``v4l2src`` does); a read stuck anyway only delays
    the reader thread's exit, never ``CameraReader.stop()`` beyond its timeout.
    """

    def __init__(
        self,
        pipeline: str,
        width: int,
        height: int,
        *,
        clock_us: Callable[[], int] = monotonic_us,
        name: str | None = None,
    ) -> None:
        self.pipeline = pipeline
        super().__init__(name or "gstreamer", width, height, clock_us)

    def open(self) -> None:
        self.close()
        if not gstreamer_available():
            raise CameraError(
                f"camera {self.name}: this OpenCV build ({cv2.__version__}) has no GStreamer "
                "support (cv2.getBuildInformation() says 'GStreamer: NO'; the PyPI "
                "opencv-python wheels are built without it). Install an OpenCV built with "
                "GStreamer (e.g. the distribution's python3-opencv) or use camera.source = "
                "'device'"
            )
        if not self.pipeline.strip():
            raise CameraError(f"camera {self.name}: empty GStreamer pipeline")
        cap = cv2.VideoCapture(self.pipeline, cv2.CAP_GSTREAMER)
        if not cap.isOpened():
            cap.release()
            raise CameraError(
                f"camera {self.name}: GStreamer pipeline {self.pipeline!r} does not open"
            )
        self._check_size(cap)
        self._cap = cap


class VideoFileSource(PacedSource):
    """Frames of a video file, paced at the file's frame rate or as fast as possible.

    ``realtime``: frame ``i`` is returned at ``t_open + i / fps`` on the monotonic clock
    (``fps`` from ``CAP_PROP_FPS``, 25 if the file has none) and that deadline is its
    ``t_capture_us``. Otherwise nothing sleeps and ``t_capture_us = t_open + i / fps``
    still. Finite (``EndOfStream`` at the end) unless ``loop``, which rewinds and keeps
    the time series going (the source is then live and reopened if it fails).
    ``sleep`` defaults to an interruptible wait woken by :meth:`interrupt`.
    """

    def __init__(
        self,
        path: str | Path,
        width: int,
        height: int,
        realtime: bool = True,
        loop: bool = False,
        clock_us: Callable[[], int] = monotonic_us,
        sleep: Callable[[float], object] | None = None,
        *,
        name: str | None = None,
    ) -> None:
        self.path = Path(path)
        super().__init__(
            name or self.path.name,
            width,
            height,
            realtime=realtime,
            loop=loop,
            fps=DEFAULT_FILE_FPS,  # until open() reads the file's
            clock_us=clock_us,
            sleep=sleep,
        )
        self._cap: Any = None
        self._pending: np.ndarray | None = None  # frame 0, decoded by open()

    def open(self) -> None:
        self.close()
        self._waker.reset()
        if not self.path.is_file():
            raise CameraError(f"{self.path}: no such video file")
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise CameraError(f"{self.path}: OpenCV cannot open this video")
        ok, first = cap.read()
        if not ok or first is None:
            cap.release()
            raise CameraError(f"{self.path}: no frame can be decoded")
        self._cap, self._pending = cap, first
        self._start(_fps_or_default(float(cap.get(cv2.CAP_PROP_FPS))))

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if self._cap is None:
            raise CameraGone(f"{self.path}: not open")
        if self._pending is not None:
            image, self._pending = self._pending, None
        else:
            ok, image = self._cap.read()
            if not ok:
                if not self.loop:
                    raise EndOfStream(f"{self.path}: end after {self._index} frames")
                self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, image = self._cap.read()
                if not ok:
                    raise CameraGone(f"{self.path}: cannot rewind")
        return self._paced(image)

    def close(self) -> None:
        cap, self._cap, self._pending = self._cap, None, None
        if cap is not None:
            cap.release()
