"""The replay results CSV of the scenario format (one row per frame and tracked object).

A rig's (docs/scenario-format.md) has one more column, ``camera`` after ``t_us``
(:data:`RIG_RESULTS_HEADER`): the name of the camera that measured the row, whose frame
index ``frame`` is; ``track_id`` is then the rig-wide id (one per object across cameras).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from typing import TextIO

from ..core.pipeline import FrameResult

RESULTS_HEADER = [
    "frame",
    "t_us",
    "track_id",
    "azimuth_deg",
    "elevation_deg",
    "angular_radius_deg",
    "state",
    "disparity",
    "ttc_s",
]

#: A rig's results CSV: :data:`RESULTS_HEADER` with ``camera`` after ``t_us``.
RIG_RESULTS_HEADER = [*RESULTS_HEADER[:2], "camera", *RESULTS_HEADER[2:]]


def _num(x: float, digits: int) -> str:
    return "" if not math.isfinite(x) else f"{x:.{digits}f}"


class ResultsWriter:
    """Write :class:`FrameResult` rows; azimuth is clockwise from north in (-180, 180]."""

    def __init__(self, fh: TextIO, camera_names: Sequence[str] | None = None) -> None:
        """``camera_names``: a rig's cameras in camera-id order (the ``camera`` column);
        None: one camera, no such column."""
        self._w = csv.writer(fh, lineterminator="\n")
        self._cameras = list(camera_names) if camera_names is not None else None
        self._w.writerow(RESULTS_HEADER if self._cameras is None else RIG_RESULTS_HEADER)
        self.rows = 0

    def write(self, result: FrameResult, camera_id: int | None = None) -> None:
        """The rows of ``result``; a rig's writer needs the measuring camera's id."""
        cam: list[str] = []
        if self._cameras is not None:
            if camera_id is None:
                raise ValueError("a rig's results CSV needs each result's camera_id")
            cam = [self._cameras[camera_id]]
        for obj in result.objects:
            disparity = obj.classification.disparity if obj.state != "unknown" else math.nan
            self._w.writerow(
                [
                    result.frame_index,
                    result.t_us,
                    *cam,
                    obj.track_id,
                    _num(math.degrees(obj.azimuth_ned_rad), 4),
                    _num(math.degrees(obj.elevation_ned_rad), 4),
                    _num(math.degrees(obj.angular_radius_rad), 5),
                    obj.state,
                    _num(disparity, 5),
                    _num(obj.ttc_s, 3),
                ]
            )
            self.rows += 1
