"""Where a rig of cameras looks at the horizon: what each camera sees, where two overlap,
and what no camera sees (``tcm-companion config check`` prints it).

Pure geometry over the camera models: the horizon is sampled at body azimuths (degrees
clockwise from the nose, body FRD, elevation 0) and a direction is seen by a camera when
it projects inside the camera's image (:meth:`~.camera.CameraModel.pixel_from_bearing_cam`
of the bearing in camera FRD, then :meth:`~.camera.CameraModel.in_image`; a pinhole's
projection is NaN for bearings behind it, camera x <= 0). Azimuths are reported in
(-180, 180], an arc from its start clockwise to its end.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .camera import CameraModel


def wrap_deg(azimuth_deg: float) -> float:
    """An azimuth in (-180, 180] degrees."""
    a = -((-azimuth_deg + 180.0) % 360.0) + 180.0
    return 180.0 if a == -180.0 else a


@dataclass(frozen=True)
class Arc:
    """An arc of the horizon: from ``start_deg`` clockwise over ``width_deg`` (body
    azimuths, degrees clockwise from the nose)."""

    start_deg: float
    width_deg: float

    @property
    def end_deg(self) -> float:
        return wrap_deg(self.start_deg + self.width_deg)

    def text(self, *, width: bool = True) -> str:
        """``"40°..50° (10°)"`` (``width``: with the width); the whole circle is
        ``"all round (360°)"``."""
        if self.width_deg >= 360.0:
            return "all round (360°)" if width else "all round"
        span = f"{_deg(self.start_deg)}°..{_deg(self.end_deg)}°"
        return f"{span} ({_deg(self.width_deg)}°)" if width else span


def _deg(x: float) -> str:
    return f"{x:.0f}" if abs(x - round(x)) < 1e-9 else f"{x:.1f}"


@dataclass(frozen=True)
class HorizonCoverage:
    """The horizon seen by each camera of a rig, sampled every ``step_deg``.

    ``azimuths_deg`` (N,): the sampled body azimuths (the centres of N bins of
    ``step_deg`` from -180°); ``seen`` (n_cameras, N): whether camera i sees each.
    Widths are counts of bins × ``step_deg``: exact to within a bin at each edge."""

    step_deg: float
    azimuths_deg: NDArray[np.float64]
    seen: NDArray[np.bool_]

    def camera_arcs(self, camera_id: int) -> list[Arc]:
        """The arcs camera ``camera_id`` sees."""
        return self._arcs(self.seen[camera_id])

    def fov_deg(self, camera_id: int) -> float:
        """How much of the horizon (degrees) camera ``camera_id`` sees: its horizontal
        field of view at the horizon."""
        return float(np.count_nonzero(self.seen[camera_id]) * self.step_deg)

    def overlaps(self) -> list[tuple[int, int, list[Arc]]]:
        """Each pair of cameras ``(i, j)``, ``i < j``, that see some of the horizon both,
        with the arcs they share."""
        n = self.seen.shape[0]
        out = []
        for i in range(n):
            for j in range(i + 1, n):
                arcs = self._arcs(self.seen[i] & self.seen[j])
                if arcs:
                    out.append((i, j, arcs))
        return out

    def gaps(self) -> list[Arc]:
        """The arcs no camera sees."""
        return self._arcs(np.logical_not(np.any(self.seen, axis=0)))

    @property
    def unseen_deg(self) -> float:
        """How much of the horizon (degrees) no camera sees."""
        return float(np.count_nonzero(~self.seen.any(axis=0)) * self.step_deg)

    def _arcs(self, mask: NDArray[np.bool_]) -> list[Arc]:
        """The runs of ``mask`` round the circle, as arcs between bin edges."""
        n = mask.size
        first_edge = float(self.azimuths_deg[0]) - self.step_deg / 2.0
        if mask.all():
            return [Arc(first_edge, 360.0)]
        if not mask.any():
            return []
        shift = int(np.argmin(mask))  # a bin not in the mask: no run crosses it
        rolled = np.roll(mask, -shift).astype(np.int8)
        edges = np.diff(np.concatenate(([0], rolled, [0])))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        return [
            Arc(wrap_deg(first_edge + ((s + shift) % n) * self.step_deg), (e - s) * self.step_deg)
            for s, e in zip(starts, ends, strict=True)
        ]


def horizon_coverage(models: Sequence[CameraModel], step_deg: float = 1.0) -> HorizonCoverage:
    """Which body azimuths at the horizon (elevation 0) each camera of ``models`` sees,
    sampled at the centres of bins of ``step_deg`` (which must divide 360)."""
    n_bins = round(360.0 / step_deg)
    if step_deg <= 0 or abs(n_bins * step_deg - 360.0) > 1e-9:
        raise ValueError(f"step_deg must divide 360, got {step_deg!r}")
    az_deg = -180.0 + (np.arange(n_bins, dtype=np.float64) + 0.5) * float(step_deg)
    az_rad = np.radians(az_deg)
    bearing_body = np.stack([np.cos(az_rad), np.sin(az_rad), np.zeros_like(az_rad)], axis=-1)
    seen = np.zeros((len(models), n_bins), dtype=bool)
    for i, model in enumerate(models):
        # v_cam = R_body_from_cam^T v_body (row vectors: v_body @ R_body_from_cam)
        bearing_cam = bearing_body @ model.R_body_from_cam
        pixel_uv = model.pixel_from_bearing_cam(bearing_cam)
        finite = np.isfinite(pixel_uv).all(axis=-1)
        seen[i] = finite & model.in_image(pixel_uv)
    return HorizonCoverage(step_deg=float(step_deg), azimuths_deg=az_deg, seen=seen)
