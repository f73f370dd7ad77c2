"""The ``boxes`` backend: boxes from someone else's detector, measured through the camera
model; and the geometry of a box that the ``onnx`` backend shares.

A box says where an object is in the image, not what shape it has. Its bearing is that
of its centre; its angular extent comes from the angles across it, between the bearings
of the midpoints of its left and right edges (θw) and of its top and bottom edges (θh) —
through the camera model, so a panorama's rows far from the equator, a fisheye's rim
and a distorted pinhole's corners all give true angles (a sphere's box on a panorama:
exactly its angular diameter across, whatever its elevation). The angular
radius is half of the box's diagonal over √2, ``√((θw² + θh²)/2)``, by default
(``box_radius = "rms"``; "mean": half of ``√(θw·θh)``, "short" and "long": half of the
smaller and the larger): for a sphere, whose box circumscribes its disc, all four equal
its angular radius; for a box, a cylinder or a disc seen from a moving camera the
diagonal follows the range best (docs/decisions.md §9, tools/shape_scale_study.py).

Boxes arrive with the capture time of the frame they were made from: :meth:`BoxesDetector.push`
(replay pushes each frame's rows of ``detections.csv`` before the frame; a live feeder
process would push them as its detector produces them) and
:meth:`BoxesDetector.detect` takes those of the frame being processed. Boxes carry no
identity (the tracker gives it) and may be late, jittery, missing or false.

Pixel coordinates follow ``tcm-scenario/1``: continuous, ``(0, 0)`` the top-left corner of
the top-left pixel; on a full-circle panorama a box across the ±180° seam has
``x_min > x_max`` (it runs from ``x_min`` to the right edge and on from 0 to ``x_max``).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import CameraModel
from ..frames import angle_between
from .base import Detection, DetectorBackend, cap_solid_angle_sr, wraps_around
from .settings import BoxRadius, DetectionConfig

#: Boxes pushed but not yet consumed are kept for at most this many frame times.
MAX_PENDING = 64


@dataclass(frozen=True, slots=True)
class Box:
    """One box of an external detector, continuous pixels (see the module docstring)."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float
    score: float = 1.0
    label: str = ""


@dataclass(frozen=True, slots=True)
class BoxExtents:
    """A box measured through the camera model: its span in pixels (``x0``, ``x1`` =
    ``x0 + w_px``, unwrapped; ``cx``, ``cy`` its centre), the centre's bearing
    ``centre_cam`` (camera FRD), the angles from it to the four edge midpoints (``half``:
    left, right, top, bottom) and the angles across the box along the image's u and v
    axes (``theta_w_rad``, ``theta_h_rad``)."""

    x0: float
    x1: float
    w_px: float
    h_px: float
    cx: float
    cy: float
    centre_cam: np.ndarray
    half: np.ndarray
    theta_w_rad: float
    theta_h_rad: float


def image_axes_cam(camera: CameraModel, u_px: float, v_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangent directions (camera FRD) of the image's u and v axes at pixel
    ``(u_px, v_px)``: where a bearing moves as u, or v, grows (central differences of
    half a pixel through the camera model, made perpendicular to the pixel's bearing).
    NaN where the camera has no bearing."""
    pts = np.array(
        [
            [u_px, v_px],
            [u_px - 0.5, v_px],
            [u_px + 0.5, v_px],
            [u_px, v_px - 0.5],
            [u_px, v_px + 0.5],
        ],
        dtype=np.float64,
    )
    b = np.asarray(camera.bearing_cam_from_pixel(pts), dtype=np.float64)
    out = []
    for d in (b[2] - b[1], b[4] - b[3]):
        d = d - float(d @ b[0]) * b[0]
        out.append(d / np.linalg.norm(d))
    return out[0], out[1]


class BoxGeometry:
    """Boxes → :class:`Detection` for one camera (bearing and extent through its model)."""

    def __init__(self, camera: CameraModel, radius: BoxRadius = "rms") -> None:
        self.camera = camera
        self.radius = radius
        self._w, self._h = camera.width, camera.height
        self._wrap = wraps_around(camera)
        valid = np.asarray(camera.valid_mask, dtype=bool)
        # Where a box's size is unreliable: it meets the image edge (not a panorama's
        # seam) or pixels without a bearing.
        border = cv2.dilate((~valid).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        border[0, :] = border[-1, :] = True
        if not self._wrap:
            border[:, 0] = border[:, -1] = True
        self._border = border

    def width_px(self, box: Box) -> float:
        """The box's width in pixels (across the seam when ``x_min > x_max``)."""
        w = box.x_max - box.x_min
        return w + self._w if (w < 0 and self._wrap) else w

    def extents(self, box: Box) -> BoxExtents | None:
        """The box's centre bearing and the angles across it (camera FRD, rad), or None if
        the box is empty, outside the camera's view or (on anything but a full panorama)
        has ``x_min > x_max``."""
        w_px, h_px = self.width_px(box), box.y_max - box.y_min
        if not (w_px > 0 and h_px > 0 and w_px <= self._w):
            return None
        x0 = box.x_min % self._w if self._wrap else box.x_min
        x1 = x0 + w_px
        cx, cy = x0 + 0.5 * w_px, 0.5 * (box.y_min + box.y_max)
        pts = np.array(
            [[cx, cy], [x0, cy], [x1, cy], [cx, box.y_min], [cx, box.y_max]], dtype=np.float64
        )
        b = self.camera.bearing_cam_from_pixel(pts)
        centre = b[0]
        if not np.all(np.isfinite(centre)):
            return None
        half = angle_between(centre[None, :], b[1:])  # centre to left, right, top, bottom
        theta_w = _across(b[1], b[2], float(half[0]), float(half[1]))
        theta_h = _across(b[3], b[4], float(half[2]), float(half[3]))
        if not (theta_w > 0 and theta_h > 0):
            return None
        return BoxExtents(x0, x1, w_px, h_px, cx, cy, centre, half, theta_w, theta_h)

    def detection(self, box: Box) -> Detection | None:
        """The object a box shows, or None if the box is empty, outside the camera's view
        or (on anything but a full panorama) has ``x_min > x_max``."""
        ext = self.extents(box)
        if ext is None:
            return None
        x0, x1, w_px, h_px, cx, cy = ext.x0, ext.x1, ext.w_px, ext.h_px, ext.cx, ext.cy
        centre, half, theta_w, theta_h = ext.centre_cam, ext.half, ext.theta_w_rad, ext.theta_h_rad
        if self.radius == "short":
            alpha = 0.5 * min(theta_w, theta_h)
        elif self.radius == "long":
            alpha = 0.5 * max(theta_w, theta_h)
        elif self.radius == "rms":
            alpha = 0.5 * math.sqrt(0.5 * (theta_w * theta_w + theta_h * theta_h))
        else:
            alpha = 0.5 * math.sqrt(theta_w * theta_h)
        bbox = (
            math.floor(x0),
            max(math.floor(box.y_min), 0),
            math.ceil(x1),
            min(math.ceil(box.y_max), self._h),
        )
        if not self._wrap:
            bbox = (max(bbox[0], 0), bbox[1], min(bbox[2], self._w), bbox[3])
        elif bbox[0] >= self._w:
            bbox = (bbox[0] - self._w, bbox[1], bbox[2] - self._w, bbox[3])
        touches = not bool(np.all(np.isfinite(half))) or self._on_border(bbox)
        return Detection(
            centroid_px=(cx % self._w if self._wrap else cx, cy),
            bearing_cam=centre,
            angular_radius_rad=alpha,
            solid_angle_sr=cap_solid_angle_sr(alpha),
            area_px=w_px * h_px,
            bbox_px=bbox,
            touches_border=touches,
            score=float(box.score),
            label=box.label,
            box_px=(box.x_min, box.y_min, box.x_max, box.y_max),
        )

    def _on_border(self, bbox: tuple[int, int, int, int]) -> bool:
        """Whether the box's outline (its outermost pixels) meets the border mask."""
        x0, y0, x1, y1 = bbox
        if x1 <= x0 or y1 <= y0:
            return True
        cols = np.arange(x0, x1) % self._w if self._wrap else np.arange(x0, x1)
        rows = np.arange(y0, y1)
        m = self._border
        return bool(
            m[y0, cols].any()
            or m[y1 - 1, cols].any()
            or m[rows, cols[0]].any()
            or m[rows, cols[-1]].any()
        )


def _across(p: np.ndarray, q: np.ndarray, a: float, b: float) -> float:
    """The angle across a box between the bearings ``p`` and ``q`` of two opposite edges'
    midpoints (``a``, ``b``: their angles from the centre's); an edge without a bearing (a
    fisheye's rim) counts as the mirror of the other."""
    if math.isfinite(a) and math.isfinite(b):
        return float(angle_between(p, q))
    if math.isfinite(a):
        return 2.0 * a
    if math.isfinite(b):
        return 2.0 * b
    return math.nan


def select(
    dets: Iterable[Detection], config: DetectionConfig, min_score: float | None = None
) -> list[Detection]:
    """Detections scoring at least ``min_score`` (default: the config's), of the
    configured ``classes`` (all when empty), at least ``min_angular_radius_rad`` in
    radius; highest score first, at most ``max_detections``."""
    floor = config.min_score if min_score is None else min_score
    keep = set(config.classes)
    out = [
        d
        for d in dets
        if d.score >= floor
        and (not keep or d.label in keep)
        and d.angular_radius_rad >= config.min_angular_radius_rad
    ]
    out.sort(key=lambda d: d.score, reverse=True)
    return out[: config.max_detections]


class BoxesDetector(DetectorBackend):
    """Boxes pushed by someone else's detector, taken by the frame they were made from.

    ``push(frame_time_us, boxes)`` hands over the boxes made from the frame captured at
    ``frame_time_us`` (all of them at once; an empty list says "nothing in that frame");
    ``detect(image, frame_time_us)`` returns those pushed for a capture time within
    ``boxes_time_tolerance_s`` of the frame's (the nearest such push), drops every push
    older than that window (counted: ``stats["stale"]``) and keeps newer ones for later
    frames. The image is not used. ``ready(frame_time_us)`` says whether a push for that
    frame or a later one has arrived, i.e. whether waiting longer can change the answer.
    """

    backend = "boxes"

    def __init__(self, camera: CameraModel, config: DetectionConfig | None = None) -> None:
        super().__init__(camera)
        self.config = config if config is not None else DetectionConfig(backend="boxes")
        self.geometry = BoxGeometry(camera, self.config.box_radius)
        self._tol_us = round(self.config.boxes_time_tolerance_s * 1e6)
        self._times: list[int] = []  # capture times of pending pushes, increasing
        self._boxes: list[list[Box]] = []
        self._newest_us: int | None = None
        #: pushes ("pushed"), pushes used by a frame ("used"), pushes no frame took
        #: ("stale"), pushes dropped for room ("overflow"), boxes seen and kept.
        self.stats: Counter[str] = Counter()

    def push(self, frame_time_us: int, boxes: Sequence[Box]) -> None:
        """Boxes made from the frame captured at ``frame_time_us`` (companion clock)."""
        t = int(frame_time_us)
        i = bisect.bisect_left(self._times, t)
        if i < len(self._times) and self._times[i] == t:
            self._boxes[i].extend(boxes)
        else:
            self._times.insert(i, t)
            self._boxes.insert(i, list(boxes))
        self.stats["pushed"] += 1
        self._newest_us = t if self._newest_us is None else max(self._newest_us, t)
        while len(self._times) > MAX_PENDING:
            self._times.pop(0)
            self._boxes.pop(0)
            self.stats["overflow"] += 1

    def ready(self, frame_time_us: int) -> bool:
        """Whether boxes for the frame at ``frame_time_us`` (or a later one) were pushed."""
        return self._newest_us is not None and self._newest_us >= frame_time_us - self._tol_us

    def detect(self, image_bgr: np.ndarray | None, frame_time_us: int = 0) -> list[Detection]:
        lo, hi = frame_time_us - self._tol_us, frame_time_us + self._tol_us
        while self._times and self._times[0] < lo:
            self._times.pop(0)
            self._boxes.pop(0)
            self.stats["stale"] += 1
        best = -1
        for i, t in enumerate(self._times):
            if t > hi:
                break
            if best < 0 or abs(t - frame_time_us) < abs(self._times[best] - frame_time_us):
                best = i
        if best < 0:
            return []
        boxes = self._boxes[best]
        self.stats["stale"] += best  # earlier pushes inside the window: not this frame's
        del self._times[: best + 1]
        del self._boxes[: best + 1]
        self.stats["used"] += 1
        self.stats["boxes"] += len(boxes)
        dets = [d for d in map(self.geometry.detection, boxes) if d is not None]
        out = select(dets, self.config)
        self.stats["kept"] += len(out)
        return out
