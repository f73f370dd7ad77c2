"""Ground truth: a scenario's truth rows.

:class:`Truth` holds a scenario's truth rows (``truth.csv``, or a simulated scenario's):
one per frame and object. Its :meth:`~Truth.ttc_s` is the true time to contact and
:meth:`~Truth.collision_course` the true collision course, for the evaluation and the
plots alike. Scoring the pipeline against it (matching, warm-up, tallies) is
:mod:`.scoring`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Truth:
    """Ground truth rows as arrays (one entry per frame and object)."""

    frame: np.ndarray  # int64
    object_id: np.ndarray  # int64
    moving: np.ndarray  # bool
    obj_ned_m: np.ndarray  # (N, 3)
    obj_radius_m: np.ndarray
    veh_ned_m: np.ndarray  # (N, 3)

    @property
    def object_ids(self) -> list[int]:
        return sorted({int(i) for i in self.object_id})

    def rows_for_frame(self, frame: int) -> np.ndarray:
        return np.nonzero(self.frame == frame)[0]

    def rows_for_object(self, object_id: int) -> np.ndarray:
        """The rows of one object, in frame order."""
        rows = np.nonzero(self.object_id == object_id)[0]
        return rows[np.argsort(self.frame[rows])]

    def ttc_s(self, frame_times_us: np.ndarray) -> np.ndarray:
        """True time to contact ``-d/ḋ`` (centre range over closing speed) per row; NaN
        where the object is not closing, and for an object seen in fewer than 3 frames.
        ``frame_times_us``: the scenario's frame times (ḋ is differentiated on seconds
        since its first frame)."""
        times = np.asarray(frame_times_us)
        out = np.full(len(self.frame), np.nan)
        for oid in self.object_ids:
            rows = self.rows_for_object(oid)
            if len(rows) < 3:
                continue
            d = np.linalg.norm(self.obj_ned_m[rows] - self.veh_ned_m[rows], axis=1)
            t_s = (times[self.frame[rows]] - times[0]) / 1e6
            ddot = np.gradient(d, t_s)
            with np.errstate(divide="ignore", invalid="ignore"):
                out[rows] = np.where(ddot < 0, -d / ddot, np.nan)
        return out

    def collision_course(
        self, frame_times_us: np.ndarray, miss_radii: float, horizon_s: float
    ) -> np.ndarray:
        """Per row: does the current relative velocity bring the object within
        ``miss_radii`` of its own radius of the camera, within ``horizon_s``?"""
        out = np.zeros(len(self.frame), dtype=bool)
        for oid in self.object_ids:
            rows = self.rows_for_object(oid)
            if len(rows) < 3:
                continue
            rel = self.obj_ned_m[rows] - self.veh_ned_m[rows]
            vel = np.gradient(rel, frame_times_us[self.frame[rows]] * 1e-6, axis=0)
            speed2 = np.maximum(np.sum(vel * vel, axis=1), 1e-12)
            t_cpa = -np.sum(rel * vel, axis=1) / speed2
            cpa = np.linalg.norm(rel + vel * t_cpa[:, None], axis=1)
            out[rows] = (
                (t_cpa > 0) & (t_cpa < horizon_s) & (cpa < miss_radii * self.obj_radius_m[rows])
            )
        return out
