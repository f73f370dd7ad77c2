"""Multi-object tracking by bearing: association with gating, stable ids, history.

Detections are associated in the local-level (NED-aligned) frame, after derotation, so
a vehicle's roll or yaw does not move an object out of its gate. Each track predicts its
next bearing from its last angular velocity, and a detection may join it only within an
angular gate (a fixed angle plus a multiple of the object's angular radius) and with a
plausible size change. The assignment is optimal over all pairs (Hungarian). Tracks keep
the observation history the classifier needs (at least its longest frame interval).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from .frames import FloatArray, angle_between, normalize


@dataclass(frozen=True)
class TrackerConfig:
    gate_rad: float = math.radians(4.0)  # fixed part of the association gate
    gate_radius_factor: float = 1.5  # plus this many angular radii of the object
    max_log_size_change: float = math.log(1.6)  # |ln(α_new / α_old)| per association
    max_misses: int = 5  # frames a track may go undetected before it is dropped
    history_frames: int = 64  # observations kept per track (≥ the longest interval)


@dataclass(frozen=True, slots=True)
class Observation:
    """One detection of an object, with its bearing in each frame of interest."""

    frame_index: int
    t_us: int
    bearing_ned: FloatArray  # (3,) unit, local level
    bearing_body: FloatArray  # (3,) unit, body FRD
    bearing_cam: FloatArray  # (3,) unit, camera FRD
    angular_radius_rad: float
    centroid_px: tuple[float, float]
    touches_border: bool = False


@dataclass
class Track:
    """A tracked object: id, observations (newest last) and bookkeeping."""

    track_id: int
    history: deque[Observation]
    misses: int = 0
    hits: int = 1
    _by_frame: dict[int, Observation] = field(default_factory=dict, repr=False)

    @property
    def last(self) -> Observation:
        return self.history[-1]

    @property
    def coasting(self) -> bool:
        """True when this frame brought no detection for the track."""
        return self.misses > 0

    def add(self, obs: Observation) -> None:
        if len(self.history) == self.history.maxlen:
            old = self.history[0]
            self._by_frame.pop(old.frame_index, None)
        self.history.append(obs)
        self._by_frame[obs.frame_index] = obs

    def at_frame(self, frame_index: int) -> Observation | None:
        return self._by_frame.get(frame_index)

    def nearest_at_or_before(self, frame_index: int, tolerance: int) -> Observation | None:
        """The observation at ``frame_index``, else the closest earlier one within tolerance."""
        for k in range(tolerance + 1):
            obs = self._by_frame.get(frame_index - k)
            if obs is not None:
                return obs
        return None

    def predict_bearing_ned(self, t_us: int) -> FloatArray:
        """Constant-angular-rate extrapolation of the last two observations."""
        b1 = self.last.bearing_ned
        if len(self.history) < 2:
            return b1
        prev = self.history[-2]
        dt_prev = self.last.t_us - prev.t_us
        if dt_prev <= 0:
            return b1
        s = (t_us - self.last.t_us) / dt_prev
        return np.asarray(normalize(b1 + s * (b1 - prev.bearing_ned)), dtype=np.float64)


class Tracker:
    """Keeps tracks across frames; ids start at 1 and are never reused."""

    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self.tracks: list[Track] = []
        self._ids = itertools.count(1)

    def reset(self) -> None:
        self.tracks.clear()

    def update(self, observations: Sequence[Observation], t_us: int) -> list[Track]:
        """Associate this frame's observations; returns live tracks (detected or coasting)."""
        cfg = self.config
        n_t, n_o = len(self.tracks), len(observations)
        assigned_obs: set[int] = set()
        if n_t and n_o:
            pred = np.stack([tr.predict_bearing_ned(t_us) for tr in self.tracks])
            obs_b = np.stack([o.bearing_ned for o in observations])
            ang = angle_between(pred[:, None, :], obs_b[None, :, :])
            alpha_t = np.array([tr.last.angular_radius_rad for tr in self.tracks])
            alpha_o = np.array([o.angular_radius_rad for o in observations])
            gate = cfg.gate_rad + cfg.gate_radius_factor * np.maximum(
                alpha_t[:, None], alpha_o[None, :]
            )
            # A coasting track's prediction is older: widen its gate with the misses.
            gate = gate * (1.0 + np.array([tr.misses for tr in self.tracks]))[:, None]
            size = np.abs(np.log(alpha_o[None, :] / alpha_t[:, None]))
            ok = (ang <= gate) & (size <= cfg.max_log_size_change)
            cost = np.where(ok, ang / gate + 0.5 * size, 1e6)
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows, cols):
                if ok[r, c]:
                    tr = self.tracks[r]
                    tr.add(observations[c])
                    tr.misses = 0
                    tr.hits += 1
                    assigned_obs.add(int(c))
                else:
                    self.tracks[r].misses += 1
            for r in set(range(n_t)) - {int(x) for x in rows}:
                self.tracks[r].misses += 1
        else:
            for tr in self.tracks:
                tr.misses += 1
        # Tracks updated this frame have misses == 0; the rest were incremented above.
        self.tracks = [tr for tr in self.tracks if tr.misses <= cfg.max_misses]
        for i, obs in enumerate(observations):
            if i not in assigned_obs:
                tr = Track(next(self._ids), deque(maxlen=cfg.history_frames))
                tr.add(obs)
                self.tracks.append(tr)
        return list(self.tracks)

    def coast_all(self) -> list[Track]:
        """A frame without usable detections (e.g. no attitude): every track misses."""
        return self.update((), 0) if self.tracks else []
