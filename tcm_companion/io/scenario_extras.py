"""The scenario format's optional ``[[target]]`` tables and ``detections.csv``.

``[[target]]`` (one table per object, in ``object_id`` order; absent: saturated red
spheres): ``object_id``, ``shape`` (sphere, box, cylinder, disc, other), ``colour_rgb``
(0..255) and ``size_m`` (extent along the object's own x, y, z; a sphere's diameter three
times). ``detections.csv``: ``frame,x_min,y_min,x_max,y_max,score,label``, one row per
box, in frame order; continuous pixel coordinates; a panorama box across the ±180° seam
has ``x_min > x_max``. Readers follow the scenario reader's rule for malformed input: a
:class:`~tcm_companion.io.scenario.ScenarioError` naming the file, the line and the
problem. The simulator writes both (``sim/scene/scenario_io.py``).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .scenario import ScenarioError, csv_rows, float_field, int_field, read_toml_text

SHAPES = ("sphere", "box", "cylinder", "disc", "other")
DETECTIONS_HEADER = ["frame", "x_min", "y_min", "x_max", "y_max", "score", "label"]


@dataclass(frozen=True)
class TargetSpec:
    """One ``[[target]]`` table."""

    object_id: int
    shape: str
    colour_rgb: tuple[int, int, int]
    size_m: tuple[float, float, float]


def read_targets(root: str | Path) -> list[TargetSpec]:
    """The ``[[target]]`` tables of scenario directory ``root`` ([] when there are none)."""
    path = Path(root) / "scenario.toml"
    meta, text = read_toml_text(path)
    tables = meta.get("target")
    if tables is None:
        return []
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ScenarioError(f"{path}: target must be an array of tables ([[target]])")
    header_lines = [
        i + 1
        for i, line in enumerate(text.splitlines())
        if re.match(r"\s*\[\[\s*target\s*\]\]", line)
    ]
    specs: list[TargetSpec] = []
    for k, table in enumerate(tables):
        line = header_lines[k] if k < len(header_lines) else 0
        where = (
            f"{path}: line {line}: [[target]] {k + 1}" if line else f"{path}: [[target]] {k + 1}"
        )
        specs.append(_target_from_table(table, where))
    ids = [s.object_id for s in specs]
    for k in range(1, len(ids)):
        if ids[k] <= ids[k - 1]:
            raise ScenarioError(
                f"{path}: [[target]] tables must be in object_id order "
                f"(object_id {ids[k]} after {ids[k - 1]})"
            )
    return specs


def _target_from_table(table: dict[str, Any], where: str) -> TargetSpec:
    known = {"object_id", "shape", "colour_rgb", "size_m"}
    for key in table:
        if key not in known:
            raise ScenarioError(f"{where}: unknown key {key!r} (known: {', '.join(sorted(known))})")
    for key in sorted(known):
        if key not in table:
            raise ScenarioError(f"{where}: missing {key}")
    oid = table["object_id"]
    if not isinstance(oid, int) or isinstance(oid, bool):
        raise ScenarioError(f"{where}: object_id must be an integer, got {oid!r}")
    shape = table["shape"]
    if shape not in SHAPES:
        raise ScenarioError(f"{where}: shape must be one of {', '.join(SHAPES)}, got {shape!r}")
    colour = table["colour_rgb"]
    if (
        not isinstance(colour, list)
        or len(colour) != 3
        or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255 for c in colour)
    ):
        raise ScenarioError(f"{where}: colour_rgb must be three integers 0..255, got {colour!r}")
    size = table["size_m"]
    if (
        not isinstance(size, list)
        or len(size) != 3
        or not all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and x > 0
            for x in size
        )
    ):
        raise ScenarioError(f"{where}: size_m must be three positive numbers, got {size!r}")
    return TargetSpec(
        object_id=oid,
        shape=str(shape),
        colour_rgb=(colour[0], colour[1], colour[2]),
        size_m=(float(size[0]), float(size[1]), float(size[2])),
    )


@dataclass(frozen=True)
class Detection:
    """One row of ``detections.csv``.

    ``object_id`` and ``image_frame`` are the simulator's truth and are not written:
    which object the box was made from (0: a false box) and which frame's image it
    describes (``frame - latency``; -1 for a false box or a box read from a file).
    """

    frame: int
    x_min: float
    y_min: float
    x_max: float
    y_max: float
    score: float
    label: str
    object_id: int = 0
    image_frame: int = -1


def write_detections_csv(path: str | Path, detections: Iterable[Detection]) -> None:
    """Write ``detections`` (in frame order) as ``detections.csv``."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(DETECTIONS_HEADER)
        for d in detections:
            w.writerow(
                [
                    d.frame,
                    f"{d.x_min:.3f}",
                    f"{d.y_min:.3f}",
                    f"{d.x_max:.3f}",
                    f"{d.y_max:.3f}",
                    f"{d.score:.3f}",
                    d.label,
                ]
            )


def read_detections_csv(
    path: str | Path,
    n_frames: int | None = None,
    image_size: tuple[int, int] | None = None,
    wraps: bool = False,
) -> list[Detection]:
    """Read ``detections.csv``; a malformed row is a ScenarioError with file and line.

    ``n_frames``: frames must be below it; ``image_size`` (W, H): coordinates must lie in
    the image; ``wraps`` (a full panorama): ``x_min > x_max`` is a box across the seam,
    elsewhere it is an error.
    """
    path = Path(path)
    out: list[Detection] = []
    for line, row in csv_rows(path, DETECTIONS_HEADER):
        out.append(_detection_row(path, line, row, n_frames, image_size, wraps))
        if len(out) > 1 and out[-1].frame < out[-2].frame:
            raise ScenarioError(
                f"{path}: line {line}: frame {out[-1].frame} after frame "
                f"{out[-2].frame} (rows must be in frame order)"
            )
    return out


def _detection_row(
    path: Path,
    line: int,
    row: list[str],
    n_frames: int | None,
    image_size: tuple[int, int] | None,
    wraps: bool,
) -> Detection:
    where = f"{path}: line {line}"
    frame = int_field(path, line, "frame", row[0])
    if frame < 0 or (n_frames is not None and frame >= n_frames):
        raise ScenarioError(f"{where}: frame {frame} is not in frames.csv")
    x0, y0, x1, y1, score = (
        float_field(path, line, name, text) for name, text in zip(DETECTIONS_HEADER[1:6], row[1:6])
    )
    if not 0.0 <= score <= 1.0:
        raise ScenarioError(f"{where}: score must be in [0, 1], got {score:g}")
    if not y1 > y0:
        raise ScenarioError(f"{where}: y_max ({y1:g}) must exceed y_min ({y0:g})")
    if x1 == x0 or (x1 < x0 and not wraps):
        raise ScenarioError(
            f"{where}: x_max ({x1:g}) must exceed x_min ({x0:g})"
            + ("" if wraps else " (only a full panorama's boxes may cross the seam)")
        )
    if image_size is not None:
        w, h = image_size
        if not (0 <= x0 <= w and 0 <= x1 <= w and 0 <= y0 <= h and 0 <= y1 <= h):
            raise ScenarioError(
                f"{where}: box ({x0:g}, {y0:g}, {x1:g}, {y1:g}) leaves the {w}x{h} image"
            )
    return Detection(frame, x0, y0, x1, y1, score, row[6])
