"""Ground truth of simulated objects beyond truth.csv, for evaluation (in memory, not on disk).

``truth.csv`` gives each object's centre and the radius of its bounding sphere. For
objects that are not spheres, looming estimators need more to be scored against:

- the true range from the camera to the object's centre (:func:`true_range_m`) and the
  true ratio of ranges between two frames, ``d0 / d1`` (:func:`true_range_ratio`: the
  ``R_img`` a looming estimator should measure; for a sphere ``sin α1 / sin α0``);
- the object's image: where its centre projects, the bounding box of its silhouette
  (occlusion ignored) and its angular extent along the image axes (:func:`project_object`,
  :func:`object_views`), from the exact geometry (:func:`~.shapes.silhouette_points_ned`),
  not from the rendered pixels;
- :func:`coverage_box_px`: the bounding box of a coverage image (the renderer's
  :meth:`~.render.Renderer.visible_coverage`), with sub-pixel edges: what part of the
  object the camera really shows (the detector simulator's boxes).

Pixel boxes follow the scenario format: continuous coordinates, ``(0, 0)`` the top-left
corner of the top-left pixel, ``(x_min, y_min, x_max, y_max)``; in a full panorama a box
across the ±180° seam has ``x_min > x_max`` (it runs from ``x_min`` to the right edge and
on from 0 to ``x_max``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...core.camera import CameraModel, Equirectangular
from ...core.frames import FloatArray
from .shapes import silhouette_points_ned
from .world import Target

if TYPE_CHECKING:
    from .export import SimulatedScenario

BoxPx = tuple[float, float, float, float]


@dataclass(frozen=True)
class ObjectView:
    """One object as the camera sees it at one instant (exact geometry, no occlusion).

    ``centre_px``: pixel (u, v) of the centre's bearing (NaN when the camera cannot see
    that direction). ``box_px``: bounding box of the silhouette's image, clipped to the
    image (None when no part of it is in view). ``extent_rad``: the angles subtended
    across the box through its centre, along the image's u axis and along its v axis
    (between the bearings of the box's left and right edge midpoints, and of its top and
    bottom edge midpoints).
    """

    object_id: int
    shape: str
    label: str
    moving: bool
    centre_ned_m: FloatArray
    range_m: float
    bounding_radius_m: float
    centre_px: FloatArray
    box_px: BoxPx | None
    extent_rad: tuple[float, float] | None


def is_full_panorama(camera: CameraModel) -> bool:
    return (
        isinstance(camera, Equirectangular)
        and abs(camera.azimuth_max_deg - camera.azimuth_min_deg - 360.0) < 1e-9
    )


def project_object(
    obj: Target,
    t_s: float,
    camera: CameraModel,
    pos_ned_m: FloatArray,
    R_ned_from_body: FloatArray,
) -> ObjectView:
    """Where ``obj`` is in the image of ``camera`` at ``pos_ned_m``, ``R_ned_from_body``."""
    centre = np.asarray(obj.centre_ned_m(t_s), np.float64)
    eye = np.asarray(pos_ned_m, np.float64).reshape(3)
    R_cam_from_ned = (np.asarray(R_ned_from_body, np.float64) @ camera.R_body_from_cam).T
    centre_px = np.asarray(camera.pixel_from_bearing_cam(R_cam_from_ned @ (centre - eye)))
    pts = silhouette_points_ned(obj, centre, obj.R_ned_from_obj(t_s), eye)
    box: BoxPx | None = None
    extent: tuple[float, float] | None = None
    if len(pts):
        uv = np.asarray(camera.pixel_from_bearing_cam((pts - eye) @ R_cam_from_ned.T))
        box = _box_of_points(uv, camera, centre_px)
        if box is not None:
            extent = _extent_rad(box, camera)
    return ObjectView(
        object_id=obj.object_id,
        shape=obj.shape,
        label=obj.label,
        moving=obj.moving,
        centre_ned_m=centre,
        range_m=float(np.linalg.norm(centre - eye)),
        bounding_radius_m=obj.bounding_radius_m,
        centre_px=centre_px,
        box_px=box,
        extent_rad=extent,
    )


def _box_of_points(uv: np.ndarray, camera: CameraModel, centre_px: np.ndarray) -> BoxPx | None:
    ok = np.all(np.isfinite(uv), axis=1)
    if not ok.any():
        return None
    u, v = uv[ok, 0], uv[ok, 1]
    w, h = float(camera.width), float(camera.height)
    if is_full_panorama(camera):
        ref = float(centre_px[0]) if np.isfinite(centre_px[0]) else float(u[0])
        u = ref + np.mod(u - ref + w / 2.0, w) - w / 2.0
        x0, x1 = float(u.min()), float(u.max())
        if x1 - x0 >= w:
            x0, x1 = 0.0, w
        elif x0 < 0.0:
            x0 += w
        elif x1 > w:
            x1 -= w
    else:
        x0, x1 = float(np.clip(u.min(), 0.0, w)), float(np.clip(u.max(), 0.0, w))
        if x1 <= x0:
            return None
    y0, y1 = float(np.clip(v.min(), 0.0, h)), float(np.clip(v.max(), 0.0, h))
    if y1 <= y0:
        return None
    return (x0, y0, x1, y1)


def box_width_px(box: BoxPx, image_width: int) -> float:
    """Width of a box, counting a panorama box across the seam (``x_min > x_max``)."""
    x0, _, x1, _ = box
    return x1 - x0 if x1 >= x0 else x1 + image_width - x0


def box_centre_px(box: BoxPx, image_width: int) -> tuple[float, float]:
    """Centre of a box (wrapped into ``[0, W)`` for a box across the seam)."""
    x0, y0, _, y1 = box
    return (x0 + box_width_px(box, image_width) / 2.0) % image_width, (y0 + y1) / 2.0


def _extent_rad(box: BoxPx, camera: CameraModel) -> tuple[float, float]:
    x0, y0, _, y1 = box
    x1 = x0 + box_width_px(box, camera.width)
    xc, yc = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    b = camera.bearing_cam_from_pixel(np.array([[x0, yc], [x1, yc], [xc, y0], [xc, y1]]))

    def angle(a: np.ndarray, c: np.ndarray) -> float:
        return float(math.atan2(np.linalg.norm(np.cross(a, c)), float(a @ c)))

    return angle(b[0], b[1]), angle(b[2], b[3])


def coverage_box_px(coverage: np.ndarray, wrap_columns: bool, floor: float = 0.02) -> BoxPx | None:
    """Bounding box of the pixels of a coverage image (H, W) above ``floor``.

    Sub-pixel edges: the outermost column (row) counts for the largest coverage found in
    it, so a straight edge crossing a pixel is placed where it crosses. ``wrap_columns``
    (a full panorama): a silhouette across the seam gives ``x_min > x_max``.
    """
    cov = np.asarray(coverage, np.float64)
    col_p = cov.max(axis=0)
    row_p = cov.max(axis=1)
    cols = np.nonzero(col_p > floor)[0]
    rows = np.nonzero(row_p > floor)[0]
    if cols.size == 0 or rows.size == 0:
        return None
    w = cov.shape[1]
    c0, c1 = int(cols[0]), int(cols[-1])
    if wrap_columns and cols.size < w:
        # The box starts after the widest run of empty columns, round the circle.
        gaps = np.diff(np.append(cols, cols[0] + w))
        k = int(np.argmax(gaps))
        c1, c0 = int(cols[k]), int(cols[(k + 1) % cols.size])
    r0, r1 = int(rows[0]), int(rows[-1])
    x0 = c0 + 1.0 - float(col_p[c0])
    x1 = c1 + float(col_p[c1])
    y0 = r0 + 1.0 - float(row_p[r0])
    y1 = r1 + float(row_p[r1])
    return (x0, y0, x1, y1)


# --------------------------------------------------------------------------------------
# Per simulated scenario
# --------------------------------------------------------------------------------------
def _object(sim: SimulatedScenario, object_id: int) -> Target:
    for o in sim.plan.objects:
        if o.object_id == object_id:
            return o
    raise KeyError(f"{sim.name} has no object {object_id}")


def true_range_m(sim: SimulatedScenario, frame: int, object_id: int) -> float:
    """Range (m) from the camera centre to the object's centre at frame ``frame``."""
    t = float(sim.frame_times_s[frame])
    centre = _object(sim, object_id).centre_ned_m(t)
    return float(np.linalg.norm(centre - sim.plan.vehicle.position_ned_m(t)))


def true_range_ratio(sim: SimulatedScenario, frame0: int, frame1: int, object_id: int) -> float:
    """``d0 / d1``: range at ``frame0`` over range at ``frame1`` (TCM's ``R``)."""
    return true_range_m(sim, frame0, object_id) / true_range_m(sim, frame1, object_id)


def object_views(sim: SimulatedScenario, frame: int) -> list[ObjectView]:
    """Every object's :class:`ObjectView` at frame ``frame`` (true pose, exact geometry)."""
    t = float(sim.frame_times_s[frame])
    pos, R = sim.vehicle_pose(frame)
    return [project_object(o, t, sim.camera, pos, R) for o in sim.plan.objects]
