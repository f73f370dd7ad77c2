"""The scenario format's optional ``[[target]]`` tables and ``detections.csv``, from the
simulator's objects (the format itself, readers included, is ``io/scenario_extras.py``).

``[[target]]`` (one table per object, in ``object_id`` order; absent: saturated red
spheres): ``object_id``, ``shape`` (sphere, box, cylinder, disc, other), ``colour_rgb``
(0..255: the simulator writes ``255 · sqrt(albedo)``, the colour a face shows under unit
irradiance through the renderer's display gamma) and ``size_m`` (extent along the
object's own x, y, z; a sphere's diameter three times).

``detections.csv``: ``frame,x_min,y_min,x_max,y_max,score,label``, one row per box, in
frame order; continuous pixel coordinates; a panorama box across the ±180° seam has
``x_min > x_max``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from ...io.scenario_extras import (
    DETECTIONS_HEADER,
    SHAPES,
    Detection,
    TargetSpec,
    read_detections_csv,
    read_targets,
    write_detections_csv,
)
from .world import BALL_ALBEDO_RGB, BALL_RADIUS_M, Ball, Target

__all__ = [
    "DETECTIONS_HEADER",
    "SHAPES",
    "Detection",
    "TargetSpec",
    "colour_rgb_from_albedo",
    "is_default_target",
    "read_detections_csv",
    "read_targets",
    "target_spec",
    "targets_toml",
    "write_detections_csv",
]


def colour_rgb_from_albedo(albedo_rgb: Sequence[float]) -> tuple[int, int, int]:
    """``255 · sqrt(albedo)``, rounded: the colour of a face under unit irradiance."""
    r, g, b = (round(255.0 * math.sqrt(min(max(float(a), 0.0), 1.0))) for a in albedo_rgb)
    return (r, g, b)


def target_spec(obj: Target) -> TargetSpec:
    """The ``[[target]]`` table of a simulated object."""
    size = tuple(round(float(x), 6) for x in obj.size_m)
    return TargetSpec(
        object_id=obj.object_id,
        shape=obj.shape,
        colour_rgb=colour_rgb_from_albedo(obj.albedo_rgb),
        size_m=(size[0], size[1], size[2]),
    )


def is_default_target(obj: Target) -> bool:
    """A saturated red 75 cm sphere: what a scenario without ``[[target]]`` holds."""
    return (
        isinstance(obj, Ball)
        and obj.radius_m == BALL_RADIUS_M
        and tuple(obj.albedo_rgb) == BALL_ALBEDO_RGB
    )


def targets_toml(objects: Iterable[Target]) -> str:
    """The ``[[target]]`` tables of ``objects`` ("" when all are the default sphere: the
    format's default then says it, and files of the paper's scenarios stay as they were)."""
    objs = sorted(objects, key=lambda o: o.object_id)
    if all(is_default_target(o) for o in objs):
        return ""
    out = []
    for o in objs:
        spec = target_spec(o)
        out += [
            "",
            "[[target]]",
            f"object_id = {spec.object_id}",
            f'shape = "{spec.shape}"',
            "colour_rgb = [{}, {}, {}]".format(*spec.colour_rgb),
            "size_m = [{}]".format(", ".join(repr(float(x)) for x in spec.size_m)),
        ]
    return "\n".join(out) + "\n"
