"""A directory of still images played as a camera (``*.png``, ``*.jpg``, ``*.jpeg``, ``*.bmp``).

Files play in natural name order (``2.png`` before ``10.png``) at ``fps``, paced in real
time or as fast as possible, with capture times ``t_open + i / fps`` on the monotonic
clock either way (see :class:`~.base.Pacer`). A ``frames.csv`` next to the images is
ignored here: a ``tcm-scenario/1`` directory with its own frame times is played by
:class:`~.scenario_source.ScenarioSource`.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ..aio import monotonic_us
from .base import CameraError, CameraGone, EndOfStream, PacedSource

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def _natural_key(path: Path) -> list[object]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def list_images(directory: Path) -> list[Path]:
    """The image files of ``directory`` in natural name order."""
    files = [p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=_natural_key)


class FramesDirSource(PacedSource):
    """Images of a directory as frames ``i = 0, 1, …`` at ``fps`` (frames per second).

    An image that cannot be decoded is returned as None (the reader counts it as
    rejected) and its time slot is kept. Finite unless ``loop``. ``sleep`` defaults to an
    interruptible wait woken by :meth:`interrupt`.
    """

    def __init__(
        self,
        path: str | Path,
        width: int,
        height: int,
        realtime: bool = True,
        fps: float = 25.0,
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
            fps=fps,
            clock_us=clock_us,
            sleep=sleep,
        )
        self.files: list[Path] = []
        self._open = False

    def open(self) -> None:
        self._waker.reset()
        if not self.path.is_dir():
            raise CameraError(f"{self.path}: no such directory")
        files = list_images(self.path)
        if not files:
            raise CameraError(
                f"{self.path}: no images ({', '.join('*' + s for s in IMAGE_SUFFIXES)})"
            )
        self.files, self._open = files, True
        self._start()

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if not self._open:
            raise CameraGone(f"{self.path}: not open")
        n = len(self.files)
        if self._index >= n and not self.loop:
            raise EndOfStream(f"{self.path}: end after {n} frames")
        path = self.files[self._index % n]
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            log.warning("%s: cannot be read as an image", path)
        return self._paced(image)

    def close(self) -> None:
        self._open = False
