"""Scoring the pipeline against ground truth: one rule for ``eval``, SITL and the flights.

- :func:`match_truth` matches one truth object to the pipeline's objects: the nearest
  bearing not yet taken, within :data:`MATCH_GATE_RAD` plus the object's true angular
  diameter.
- The warm-up: an object-frame counts once it was captured at least the classifier's
  ``interval_s`` after the start (the first frame of a scenario, the start of a SITL run),
  after which a stationary object can be decided (:func:`warmed_up`,
  :func:`after_warmup`), less :data:`WARMUP_SLACK_S` of capture jitter.
- :class:`Score`: the tally of object-frames in view, matched, decided and correct, with
  accuracy and coverage, as SITL reports it.
- A camera rig: :func:`view_camera` — the camera an object-frame is scored in (the one
  that sees the object nearest its optical axis), once per frame cycle — and
  :class:`Handover`, the track ids matched to each object seen by more than one camera
  (target 1).

The evaluation (``eval``, :mod:`tcm_companion.eval.evaluate`), the mock-autopilot SITL in
real and virtual time (:mod:`tcm_companion.sitl.mock`) and the ArduPilot SITL flight
report (:mod:`tcm_companion.sitl.ardupilot`) all score with this module.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, TypeVar

import numpy as np

from ..core.classify import ClassifierConfig
from ..core.frames import angle_between, normalize
from ..core.timebase import JITTER_FRACTION, MAX_FRAME_RATE_HZ

if TYPE_CHECKING:
    from ..core.camera import CameraModel

#: A truth object matches a detected object whose bearing is within this of its centre's,
#: plus twice its true angular radius (a box or blob centre may sit anywhere on the disc).
MATCH_GATE_RAD = math.radians(5.0)


@dataclass(frozen=True)
class TruthMatch:
    """Which of the candidates one truth object matched (``index``, -1: none within the
    gate), the bearing error to the nearest free candidate (inf: none) and the object's
    true angular radius (rad)."""

    index: int
    bearing_error_rad: float
    alpha_true_rad: float

    @property
    def matched(self) -> bool:
        return self.index >= 0


def match_truth(
    rel_ned_m: np.ndarray,
    radius_m: float,
    bearings_ned: Sequence[np.ndarray],
    used: set[int],
    gate_rad: float = MATCH_GATE_RAD,
) -> TruthMatch:
    """Match a truth object at ``rel_ned_m`` from the camera (its radius ``radius_m``) to
    the nearest of ``bearings_ned`` (the pipeline's detected objects) not in ``used``,
    accepted within ``gate_rad + 2 α`` (α: its true angular radius). A match is added to
    ``used``: called for each truth object of a frame in turn, it matches greedily, one
    object to one truth object."""
    b_true = normalize(rel_ned_m)
    alpha = math.asin(min(1.0, radius_m / float(np.linalg.norm(rel_ned_m))))
    best, best_ang = -1, math.inf
    for i, b in enumerate(bearings_ned):
        if i in used:
            continue
        ang = float(angle_between(b, b_true))
        if ang < best_ang:
            best, best_ang = i, ang
    if best < 0 or best_ang > gate_rad + 2.0 * alpha:
        return TruthMatch(-1, best_ang, alpha)
    used.add(best)
    return TruthMatch(best, best_ang, alpha)


#: A record captured this close before the end of the warm-up counts as after it
#: (capture jitter; a quarter frame at the fastest rate supported).
WARMUP_SLACK_S = JITTER_FRACTION / MAX_FRAME_RATE_HZ


def warmed_up(time_s: float, cls: ClassifierConfig, warmup_s: float | None = None) -> bool:
    """Whether an object-frame captured ``time_s`` seconds after the start counts: at
    least ``warmup_s`` (default: the classifier's ``interval_s``, after which a stationary
    object can be decided), less :data:`WARMUP_SLACK_S`."""
    warm = cls.interval_s if warmup_s is None else warmup_s
    return time_s >= warm - WARMUP_SLACK_S


class Timed(Protocol):
    """A record with its capture time in seconds since the start (``time_s``)."""

    @property
    def time_s(self) -> float: ...


T = TypeVar("T", bound=Timed)


def after_warmup(
    records: Iterable[T], cls: ClassifierConfig, warmup_s: float | None = None
) -> list[T]:
    """The records captured at least ``warmup_s`` (default: the classifier's interval,
    after which a stationary object can be decided) after their scenario's first frame
    (:func:`warmed_up`)."""
    return [r for r in records if warmed_up(r.time_s, cls, warmup_s)]


@dataclass
class Score:
    """Object-frames of objects in view, matched to the daemon's objects by bearing
    (:func:`match_truth`); those captured after the warm-up (``warmup_s``, seconds after
    the start: :func:`warmed_up`) are scored."""

    warmup_s: float = 0.0
    truth_frames: int = 0  # object-frames with the object in front of the camera
    truth_after_warmup: int = 0  # ... of them after the warm-up
    # ... of them of an object that the companion has had (or that has been in view, if
    # it never had it) for at least the classifier's interval and hold: each could have
    # been decided (a run that decides none has failed; a run too short has not)
    overdue: int = 0
    matched: int = 0
    decided: int = 0  # matched and not "unknown" (after the warm-up)
    correct: int = 0
    scored: int = 0  # matched after the warm-up
    by_state: Counter[str] = field(default_factory=Counter)

    def add(self, warm: bool, state: str | None, truth_moving: bool, overdue: bool = False) -> None:
        """Count one object-frame in view: ``warm`` after the warm-up; ``state``: the
        matched object's state (None: no object matched it); ``overdue``: see the field."""
        self.truth_frames += 1
        self.truth_after_warmup += int(warm)
        self.overdue += int(warm and overdue)
        if state is None:
            return
        self.matched += 1
        if not warm:
            return
        self.scored += 1
        self.by_state[state] += 1
        if state != "unknown":
            self.decided += 1
            self.correct += int((state == "moving") == truth_moving)

    @property
    def accuracy(self) -> float:
        return self.correct / self.decided if self.decided else math.nan

    @property
    def coverage(self) -> float:
        return self.decided / self.scored if self.scored else math.nan


def view_camera(
    cameras: Sequence[CameraModel], R_ned_from_body: np.ndarray, rel_ned_m: np.ndarray
) -> int:
    """The camera of a rig that an object at ``rel_ned_m`` (NED, from the vehicle) is
    scored in: of those whose image holds its centre, the one nearest its optical axis
    (camera FRD +x); -1 when none does. One camera: 0 when in its image."""
    best, best_cos = -1, -math.inf
    b = normalize(rel_ned_m)
    for cid, cam in enumerate(cameras):
        R_ned_from_cam = R_ned_from_body @ cam.R_body_from_cam
        px = cam.pixel_from_bearing_cam(R_ned_from_cam.T @ b)
        if not np.all(np.isfinite(px)) or not bool(cam.in_image(px)):
            continue
        if len(cameras) == 1:
            return cid
        cos = float(R_ned_from_cam[:, 0] @ b)  # the optical axis: camera FRD x
        if cos > best_cos:
            best, best_cos = cid, cos
    return best


@dataclass
class Handover:
    """Per truth object: the cameras it was scored in (:func:`view_camera`) and the track
    ids matched to it. :meth:`figure` is the handover figure: for each object scored in
    more than one camera, how many ids it got (one is the target: it kept its track)."""

    views: dict[Hashable, set[int]] = field(default_factory=dict)
    track_ids: dict[Hashable, set[Hashable]] = field(default_factory=dict)

    def add(self, obj: Hashable, camera_id: int, track_id: Hashable | None) -> None:
        """Object ``obj`` scored in ``camera_id``, matched to ``track_id`` (None: not)."""
        self.views.setdefault(obj, set()).add(camera_id)
        if track_id is not None:
            self.track_ids.setdefault(obj, set()).add(track_id)

    def figure(self) -> dict[Hashable, int]:
        return {
            obj: len(self.track_ids.get(obj, ()))
            for obj, cams in self.views.items()
            if len(cams) > 1
        }
