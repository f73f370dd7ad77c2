"""The paper's rig: two back-to-back fisheye cameras stitched into one panorama.

Each ``read()`` reads the front camera, then the back one (one read cycle = one pair),
and returns ``stitcher.stitch(front_bgr, back_bgr)``, the equirectangular panorama
(``stitcher.panorama`` gives its size). The pair's ``t_capture_us`` is the **mean** of
the two capture times: the panorama mixes both exposures, and the mean is the time whose
error is at most half their skew for either half of the image (hardware-triggered
cameras agree to well under a millisecond; free-running ones differ by up to a frame
period, which ``last_skew_us`` and ``max_skew_us`` expose). Either camera lost →
``CameraGone`` (the reader closes and reopens both); either ends → the pair ends.
"""

from __future__ import annotations

import logging
from typing import Any, Protocol

import numpy as np

from ..aio import monotonic_us
from .base import FrameSource

log = logging.getLogger(__name__)

# Returned when one fisheye image has the wrong size: not the panorama's shape, so the
# reader counts the pair as ``rejected_size`` (stitching it would remap garbage).
_WRONG_SIZE = np.full((1, 1, 3), 255, np.uint8)


class Stitcher(Protocol):
    """What :class:`DualFisheyeSource` needs of ``stitch.FisheyeStitcher``."""

    front: Any  # core.camera.Fisheye
    back: Any  # core.camera.Fisheye
    panorama: Any  # core.camera.Equirectangular

    def stitch(self, front_bgr: np.ndarray, back_bgr: np.ndarray) -> np.ndarray: ...


class DualFisheyeSource(FrameSource):
    """Pair ``front`` and ``back`` frames and stitch them (see the module docstring)."""

    def __init__(
        self, front: FrameSource, back: FrameSource, stitcher: Stitcher, *, name: str | None = None
    ) -> None:
        pano = stitcher.panorama
        super().__init__(name or f"{front.name}+{back.name}", int(pano.width), int(pano.height))
        self.front = front
        self.back = back
        self.stitcher = stitcher
        self.live = front.live and back.live
        self.last_skew_us = 0  # |t_front - t_back| of the last pair
        self.max_skew_us = 0
        self.bad_pairs = 0  # pairs with a missing or wrong-sized fisheye image

    def open(self) -> None:
        self.front.open()
        try:
            self.back.open()
        except BaseException:
            self.front.close()
            raise

    def read(self) -> tuple[np.ndarray | None, int | None]:
        front_img, t_front = self.front.read()
        if t_front is None:
            t_front = monotonic_us()
        back_img, t_back = self.back.read()
        if t_back is None:
            t_back = monotonic_us()
        skew = abs(int(t_front) - int(t_back))
        self.last_skew_us = skew
        self.max_skew_us = max(self.max_skew_us, skew)
        t_us = (int(t_front) + int(t_back)) // 2
        if front_img is None or back_img is None:
            self.bad_pairs += 1
            return None, t_us
        for cam, img in ((self.front, front_img), (self.back, back_img)):
            if img.shape != (cam.height, cam.width, 3) or img.dtype != np.uint8:
                self.bad_pairs += 1
                log.debug("camera %s: %s image of shape %s", self.name, cam.name, img.shape)
                return _WRONG_SIZE.copy(), t_us
        return self.stitcher.stitch(front_img, back_img), t_us

    def interrupt(self) -> None:
        self.front.interrupt()
        self.back.interrupt()

    def close(self) -> None:
        try:
            self.front.close()
        finally:
            self.back.close()
