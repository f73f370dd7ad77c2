"""Multi-object tracking by bearing: association with gating, stable ids, history.

Detections are associated in the local-level (NED-aligned) frame, after derotation, so
a vehicle's roll or yaw does not move an object out of its gate. Each track predicts its
next bearing from its last angular velocity, and a detection may join it only within an
angular gate (a fixed angle plus a multiple of the object's angular radius) and with a
plausible size change. The assignment is optimal over all pairs (Hungarian). Tracks keep
the observation history the classifier needs, by capture time (``history_s``, at least its
longest interval), and answer "the observation captured nearest time t". A detection
joins only a track of its own label (``keep_labels``), where the detector names them.

A frame without attitude has no local-level bearings (NaN): its observations are
associated in the camera frame instead (each track's camera bearing, extrapolated the same
way), so objects stay tracked in the image through a gap in the telemetry; so are pairs
whose track was last seen without attitude. A track's label is the most frequent non-empty
label among the observations it keeps (the most recent of equally frequent ones), so a
detector's occasional wrong class does not flicker through.

Association is between consecutive frames, so ``max_misses`` and the gate's growth while
a track coasts count frames: at a lower rate each miss is a longer coast, but also the
only evidence there is.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .frames import FloatArray, angle_between, normalize
from .timebase import frames_to_cover


@dataclass(frozen=True)
class TrackerConfig:
    gate_rad: float = math.radians(4.0)  # fixed part of the association gate
    gate_radius_factor: float = 1.5  # plus this many angular radii of the object
    max_log_size_change: float = math.log(1.6)  # |ln(α_new / α_old)| per association
    max_misses: int = 5  # frames a track may go undetected before it is dropped
    # Observations kept per track, s of capture time (the pipeline keeps at least the
    # classifier's longest interval and tolerance); at most what this span holds at
    # timebase.MAX_FRAME_RATE_HZ, so memory stays bounded at any rate.
    history_s: float = 2.0
    # A detection never continues a track of another label (both labels non-empty): a
    # detector that names its objects does not turn a car into a cloud that drifts past.
    keep_labels: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.history_s) and self.history_s > 0):
            raise ValueError(f"history_s must be > 0, got {self.history_s}")
        if self.max_misses < 0:
            raise ValueError(f"max_misses must be >= 0, got {self.max_misses}")


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
    label: str = ""  # what the detector called it ("" when it does not say)
    # Whether the local-level bearing is known (the frame had an attitude): decided once
    # here, since the classifier, the looming fit and the tracker ask many times a frame.
    has_attitude: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        finite = all(math.isfinite(x) for x in np.asarray(self.bearing_ned).ravel().tolist())
        object.__setattr__(self, "has_attitude", finite)


@dataclass
class Track:
    """A tracked object: id, observations (newest last, by capture time) and bookkeeping."""

    track_id: int
    history: deque[Observation]
    misses: int = 0
    hits: int = 1
    history_us: int = 2_000_000  # observations captured longer before the newest are dropped
    first_t_us: int | None = None  # capture time of the first observation ever
    _by_frame: dict[int, Observation] = field(default_factory=dict, repr=False)

    @property
    def last(self) -> Observation:
        return self.history[-1]

    @property
    def coasting(self) -> bool:
        """True when this frame brought no detection for the track."""
        return self.misses > 0

    def age_s(self, t_us: int) -> float:
        """Time since the track's first observation at capture time ``t_us`` (s)."""
        first = self.first_t_us if self.first_t_us is not None else self.history[0].t_us
        return (t_us - first) * 1e-6

    def add(self, obs: Observation) -> None:
        if self.first_t_us is None:
            self.first_t_us = obs.t_us
        if len(self.history) == self.history.maxlen:
            old = self.history[0]
            self._by_frame.pop(old.frame_index, None)
        self.history.append(obs)
        self._by_frame[obs.frame_index] = obs
        while len(self.history) > 1 and obs.t_us - self.history[0].t_us > self.history_us:
            old = self.history.popleft()
            self._by_frame.pop(old.frame_index, None)

    @property
    def label(self) -> str:
        """The most frequent non-empty label of the kept observations ("" if none); of
        equally frequent ones, the most recent."""
        counts: dict[str, int] = {}
        last: dict[str, int] = {}
        for i, obs in enumerate(self.history):
            if obs.label:
                counts[obs.label] = counts.get(obs.label, 0) + 1
                last[obs.label] = i
        if not counts:
            return ""
        return max(counts, key=lambda k: (counts[k], last[k]))

    def at_frame(self, frame_index: int) -> Observation | None:
        return self._by_frame.get(frame_index)

    def nearest_in_time(
        self,
        t_us: int,
        tolerance_us: int,
        not_after_us: int | None = None,
        prefer_earlier_us: int = 0,
    ) -> Observation | None:
        """The observation captured nearest ``t_us`` and within ``tolerance_us`` of it,
        ignoring any captured after ``not_after_us``; None if there is none.

        Of the two either side of ``t_us``, the earlier one wins unless the later one is
        nearer by more than ``prefer_earlier_us`` (capture jitter must not decide between
        two frames equally far from ``t_us``: the longer pair is the better evidence)."""
        times = [o.t_us for o in self.history]
        hi = len(times) if not_after_us is None else bisect.bisect_right(times, not_after_us)
        i = bisect.bisect_left(times, t_us, 0, hi)
        before = i - 1 if i - 1 >= 0 and t_us - times[i - 1] <= tolerance_us else None
        after = i if i < hi and times[i] - t_us <= tolerance_us else None
        if before is None:
            return self.history[after] if after is not None else None
        if after is not None and times[after] - t_us < t_us - times[before] - prefer_earlier_us:
            return self.history[after]
        return self.history[before]

    def predict_bearing_ned(self, t_us: int) -> FloatArray:
        """Constant-angular-rate extrapolation of the last two observations."""
        b1 = self.last.bearing_ned
        if len(self.history) < 2:
            return b1
        prev = self.history[-2]
        dt_prev = self.last.t_us - prev.t_us
        if dt_prev <= 0 or not prev.has_attitude:
            return b1
        s = (t_us - self.last.t_us) / dt_prev
        return np.asarray(normalize(b1 + s * (b1 - prev.bearing_ned)), dtype=np.float64)

    def predict_bearing_cam(self, t_us: int) -> FloatArray:
        """Constant-angular-rate extrapolation in the camera frame (frames without
        attitude: the vehicle's rotation is not undone)."""
        b1 = self.last.bearing_cam
        if len(self.history) < 2:
            return b1
        prev = self.history[-2]
        dt_prev = self.last.t_us - prev.t_us
        if dt_prev <= 0:
            return b1
        s = (t_us - self.last.t_us) / dt_prev
        return np.asarray(normalize(b1 + s * (b1 - prev.bearing_cam)), dtype=np.float64)


class Tracker:
    """Keeps tracks across frames; ids start at 1 and are never reused."""

    def __init__(self, config: TrackerConfig = TrackerConfig()) -> None:
        self.config = config
        self.tracks: list[Track] = []
        self._ids = itertools.count(1)

    def reset(self) -> None:
        self.tracks.clear()

    def _same_labels(self, observations: Sequence[Observation]) -> np.ndarray | bool:
        """(tracks, observations) bool: may the pair be associated by its labels (equal,
        or either one empty)? True for all when the detector names nothing."""
        obs_labels = [o.label for o in observations]
        if not any(obs_labels):
            return True
        track_labels = [tr.label for tr in self.tracks]
        if len({label for label in track_labels + obs_labels if label}) < 2:
            return True  # one label (the usual single-target case), or none
        return np.array([[not a or not b or a == b for b in obs_labels] for a in track_labels])

    def update(self, observations: Sequence[Observation], t_us: int) -> list[Track]:
        """Associate this frame's observations; returns live tracks (detected or coasting)."""
        cfg = self.config
        n_t, n_o = len(self.tracks), len(observations)
        assigned_obs: set[int] = set()
        if n_t and n_o:
            # np.array of a list of (3,) arrays: np.stack's (N, 3), without its checks.
            pred = np.array([tr.predict_bearing_ned(t_us) for tr in self.tracks])
            obs_b = np.array([o.bearing_ned for o in observations])
            ang = angle_between(pred[:, None, :], obs_b[None, :, :])
            if not np.isfinite(ang).all():
                # No local-level bearing on one side (a frame without attitude): compare
                # camera-frame bearings for those pairs.
                pred_c = np.stack([tr.predict_bearing_cam(t_us) for tr in self.tracks])
                obs_c = np.stack([o.bearing_cam for o in observations])
                ang_c = angle_between(pred_c[:, None, :], obs_c[None, :, :])
                ang = np.where(np.isfinite(ang), ang, ang_c)
            alpha_t = np.array([tr.last.angular_radius_rad for tr in self.tracks])
            alpha_o = np.array([o.angular_radius_rad for o in observations])
            gate = cfg.gate_rad + cfg.gate_radius_factor * np.maximum(
                alpha_t[:, None], alpha_o[None, :]
            )
            # A coasting track's prediction is older: widen its gate with the misses.
            gate = gate * (1.0 + np.array([tr.misses for tr in self.tracks]))[:, None]
            size = np.abs(np.log(alpha_o[None, :] / alpha_t[:, None]))
            ok = (ang <= gate) & (size <= cfg.max_log_size_change)
            if cfg.keep_labels:
                ok &= self._same_labels(observations)
            cost = np.where(ok, ang / gate + 0.5 * size, 1e6)
            if n_t == 1 and n_o == 1:
                # One pair (the common case): the assignment is that pair (the cost is
                # finite by construction), without the solver's call overhead.
                pairs = [(0, 0)]
            else:
                # Imported here: scipy.optimize costs ~0.5 s of start-up (replay, the
                # daemon) and single-object scenes never need it.
                from scipy.optimize import linear_sum_assignment

                rows, cols = linear_sum_assignment(cost)
                pairs = list(zip(rows.tolist(), cols.tolist()))
            for r, c in pairs:
                if ok[r, c]:
                    tr = self.tracks[r]
                    tr.add(observations[c])
                    tr.misses = 0
                    tr.hits += 1
                    assigned_obs.add(c)
                else:
                    self.tracks[r].misses += 1
            for r in set(range(n_t)) - {r for r, _ in pairs}:
                self.tracks[r].misses += 1
        else:
            for tr in self.tracks:
                tr.misses += 1
        # Tracks updated this frame have misses == 0; the rest were incremented above.
        self.tracks = [tr for tr in self.tracks if tr.misses <= cfg.max_misses]
        for i, obs in enumerate(observations):
            if i not in assigned_obs:
                tr = Track(
                    next(self._ids),
                    deque(maxlen=frames_to_cover(cfg.history_s)),
                    history_us=round(cfg.history_s * 1e6),
                )
                tr.add(obs)
                self.tracks.append(tr)
        return list(self.tracks)

    def coast_all(self) -> list[Track]:
        """A frame without usable detections (e.g. no attitude): every track misses."""
        return self.update((), 0) if self.tracks else []
