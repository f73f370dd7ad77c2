"""What every detection backend reports, and the interface they share.

A backend turns one camera frame into :class:`Detection` s: a bearing in camera FRD and an
angular radius measured *through the camera model* (never in raw pixels: off-axis and
fisheye pixels are not equal angles), a confidence, optionally a class label, and the
pixels (colour) or the box (boxes, onnx) it came from. The tracker and the classifier see
nothing else, so they work the same whatever found the object.

Pure: no IO, no clock.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..camera import CameraModel, Equirectangular
from ..frames import FloatArray


@dataclass(frozen=True, slots=True)
class Detection:
    """One object found in one frame, measured through the camera model.

    - ``bearing_cam``: unit vector in camera FRD (colour: the solid-angle-weighted mean
      direction of the blob, for a sphere exactly its centre's; a box: its centre's).
    - ``angular_radius_rad``: colour: from the blob's solid angle, ``Ω = 2π(1 - cos α)``; a
      box: from the angles across it (``DetectionConfig.box_radius``).
    - ``solid_angle_sr``: the blob's solid angle; for a box, that of the cap of radius α.
    - ``area_px``: colour: the membership sum in pixels (fractional on the rim); a box:
      its area in pixels.
    - ``centroid_px``: continuous pixel coordinates of the scenario format,
      ``0 <= u < width`` (colour: the membership-weighted mean of pixel centres; a box: its
      centre).
    - ``bbox_px``: ``(x0, y0, x1, y1)`` integer pixels, exclusive ends; anti-aliased rim
      pixels may lie a pixel or two outside a colour blob's. On a full-circle panorama an
      object across the left/right seam has ``x1 > width``: its columns are ``x0 .. x1 - 1``
      modulo the width (``0 <= x0 < width`` always).
    - ``touches_border``: the object meets the image edge (not a panorama's seam), a pixel
      without a bearing, or a black lens surround, so part of it may be cut off and its
      size is unreliable.
    - ``score``: confidence, 0..1 (colour: the mean HSV saturation of the grown pixels;
      boxes and onnx: the detector's score).
    - ``label``: what the object is ("" when the backend does not say): a colour target's
      configured label, a box's label, the onnx model's class name.
    - ``box_px``: the box a box-based backend was given or decoded, ``(x_min, y_min,
      x_max, y_max)`` continuous pixels of the scenario format (``x_min > x_max`` across a
      full panorama's seam); None for a colour blob.
    """

    centroid_px: tuple[float, float]
    bearing_cam: FloatArray
    angular_radius_rad: float
    solid_angle_sr: float
    area_px: float
    bbox_px: tuple[int, int, int, int]
    touches_border: bool
    score: float
    label: str = ""
    box_px: tuple[float, float, float, float] | None = None


def angular_radius_from_solid_angle(solid_angle_sr: float) -> float:
    """Half-angle α of a spherical cap of solid angle Ω = 2π(1 - cos α) = 4π sin²(α/2)."""
    s = math.sqrt(min(max(solid_angle_sr, 0.0) / (4.0 * math.pi), 1.0))
    return 2.0 * math.asin(s)


def cap_solid_angle_sr(angular_radius_rad: float) -> float:
    """Solid angle of a spherical cap of half-angle α: ``4π sin²(α/2)``."""
    return 4.0 * math.pi * math.sin(0.5 * angular_radius_rad) ** 2


def wraps_around(camera: CameraModel) -> bool:
    """True for a full-circle panorama, whose left and right edges are one seam."""
    return isinstance(camera, Equirectangular) and (
        abs(camera.azimuth_max_deg - camera.azimuth_min_deg - 360.0) < 1e-9
    )


class DetectorBackend(ABC):
    """One detection backend for one camera: ``detect(image, frame_time_us)``.

    ``frame_time_us`` is the frame's capture time (companion clock); image-based backends
    ignore it, the boxes backend uses it to pick the boxes pushed for that frame. Backends
    are not re-entrant (they reuse scratch buffers): one per camera and thread.
    """

    #: ``[detection] backend`` value that selects this class.
    backend: ClassVar[str]

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera

    @abstractmethod
    def detect(self, image_bgr: np.ndarray, frame_time_us: int = 0) -> list[Detection]:
        """The objects in one BGR uint8 frame captured at ``frame_time_us``."""
