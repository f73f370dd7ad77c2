"""The replay results CSV of the scenario format (one row per frame and tracked object)."""

from __future__ import annotations

import csv
import math
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


def _num(x: float, digits: int) -> str:
    return "" if not math.isfinite(x) else f"{x:.{digits}f}"


class ResultsWriter:
    """Write :class:`FrameResult` rows; azimuth is clockwise from north in (-180, 180]."""

    def __init__(self, fh: TextIO) -> None:
        self._w = csv.writer(fh, lineterminator="\n")
        self._w.writerow(RESULTS_HEADER)
        self.rows = 0

    def write(self, result: FrameResult) -> None:
        for obj in result.objects:
            disparity = obj.classification.disparity if obj.state != "unknown" else math.nan
            self._w.writerow(
                [
                    result.frame_index,
                    result.t_us,
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
