"""One object, one track, whatever the camera: rig-wide tracks over per-camera pipelines.

Each camera's :class:`~.pipeline.Pipeline` keeps its own tracks (ids per camera). The
:class:`RigTracker` binds them to rig tracks in the one world frame the cameras share
(local-level NED bearings), so that

- an object crossing from one camera's view to the next keeps its id, its history and its
  decision (a *handover*): while the new camera's young track is still warming up, the rig
  decides it from a cross-camera TCM pair (the reference from the camera that saw it an
  interval earlier, the current observation and the translation from the new one);
- an object two overlapping cameras see is one track, reported by one *measuring* camera
  (the better-placed view: farther from its image border), the other view left out;
- a camera lost forgets what only it measured.

Pure: no clock, no IO; time is each result's capture time (``t_us``, the companion clock
every camera shares). The Companion builds one for two cameras or more, and replay of a
rig uses the same class.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from .camera import CameraModel
from .classify import Classification, classify_pair, decide, hold
from .frames import FloatArray, angle_between, normalize, rotate_by_vector
from .pipeline import FrameResult, ObjectResult, PipelineConfig
from .timebase import jitter_slack_s, median_period_s
from .ttc import estimate_ttc


@dataclass(frozen=True)
class RigConfig:
    """Gates of the cross-camera association (rad) and times (s)."""

    # A per-camera track seen for the first time joins a rig track whose predicted NED
    # bearing is within gate_rad + gate_radius_factor * (the larger angular radius) (the
    # per-camera tracker's gate; docs/decisions.md §11).
    gate_rad: float = math.radians(4.0)
    gate_radius_factor: float = 1.5
    # ... and whose size agrees: |ln(α_new / α_rig)| at most this (not checked for a view
    # cut by its image border, whose size is not the object's).
    max_log_size_change: float = math.log(1.6)
    # A rig track no camera has seen for this long is dropped (s): a per-camera track
    # coasts 5 frames (0.2 s at 25 Hz) before its pipeline drops it, and the object may
    # take a frame or two to be detected whole in the next camera.
    max_unseen_s: float = 0.4
    # A camera's view of an object older than this (s) does not keep it measuring.
    stale_view_s: float = 0.2
    # Another camera takes over the measuring of an object when its view is better placed
    # by this much (angular margin to the image border, rad): no flapping in the overlap.
    switch_margin_rad: float = math.radians(2.0)
    # A view whose margin to its image border (beyond the object's own radius) is below
    # this touches the border: its size is not trusted for a cross-camera pair (rad).
    border_margin_rad: float = math.radians(0.5)

    def __post_init__(self) -> None:
        for name in (
            "gate_rad",
            "gate_radius_factor",
            "max_log_size_change",
            "max_unseen_s",
            "stale_view_s",
            "switch_margin_rad",
            "border_margin_rad",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"RigConfig.{name} must be >= 0, got {value}")


@dataclass(frozen=True, slots=True)
class _RigObservation:
    t_us: int
    bearing_ned: FloatArray
    angular_radius_rad: float
    camera_id: int
    margin_rad: float  # of the object's edge from its image border
    whole: bool  # clear of its image border (its size is the object's)


@dataclass(slots=True)
class _View:
    """The latest view of a rig track by one camera."""

    t_us: int
    margin_rad: float  # angular distance of the object's edge from the image border
    detected: bool


@dataclass
class _RigTrack:
    rig_id: int
    first_t_us: int
    last_seen_us: int
    measuring: int  # the camera whose results report it
    history: list[_RigObservation]  # every camera's views, by capture time
    bound: dict[int, int] = field(default_factory=dict)  # camera id -> its track id
    bound_us: dict[int, int] = field(default_factory=dict)  # ... since (capture time)
    views: dict[int, _View] = field(default_factory=dict)
    cameras: set[int] = field(default_factory=set)  # every camera it was ever bound to
    memory: deque[tuple[int, Classification]] = field(default_factory=deque)
    decision: Classification | None = None
    label: str = ""

    def predict_bearing_ned(self, t_us: int) -> FloatArray:
        """Constant-angular-rate extrapolation of the last two observations captured at
        different times (whole views preferred: a cut one's centre is off)."""
        obs = [o for o in self.history if o.whole]
        if len(obs) < 2:
            obs = list(self.history)
        b1 = obs[-1].bearing_ned
        prev = next((o for o in reversed(obs) if o.t_us < obs[-1].t_us), None)
        if prev is None:
            return b1
        s = (t_us - obs[-1].t_us) / (obs[-1].t_us - prev.t_us)
        return np.asarray(normalize(b1 + s * (b1 - prev.bearing_ned)), dtype=np.float64)

    def nearest(
        self, t_us: int, tolerance_us: int, not_after_us: int, same_us: int
    ) -> _RigObservation | None:
        """The whole observation captured nearest ``t_us`` (within ``tolerance_us``, not
        after ``not_after_us``), from any camera; of views captured within ``same_us`` of
        each other the best-placed one (largest margin to its border)."""
        best: _RigObservation | None = None
        for obs in self.history:
            if obs.t_us > not_after_us or not obs.whole:
                continue
            dt = abs(obs.t_us - t_us)
            if dt > tolerance_us:
                continue
            if best is None:
                best = obs
                continue
            best_dt = abs(best.t_us - t_us)
            if dt < best_dt - same_us or (
                abs(dt - best_dt) <= same_us and obs.margin_rad > best.margin_rad
            ):
                best = obs
        return best


#: A camera's own result that the rig may decide from a pair over the rig track's history
#: (an end seen by another camera, or by an earlier track of this camera: one its tracker
#: lost, a rebuilt pipeline's): its track is too young for a pair of its own, or its
#: pair's other end was cut by the image border (as an object comes into view from a
#: neighbouring camera's).
CROSS_PAIR_REASONS = frozenset({"warm-up", "at image border"})


def _finite(v: FloatArray) -> bool:
    return bool(np.isfinite(v).all())


class RigTracker:
    """Per-camera results in, rig-wide results out (one object, one id).

    ``cameras``: the lens of each camera, by camera id (their mounts give nothing here:
    the pipelines already put every bearing in NED); ``pipeline_config``: the pipelines'
    (the classifier's intervals, tolerance, hold and thresholds are the rig's too).
    """

    def __init__(
        self,
        cameras: Sequence[CameraModel],
        pipeline_config: PipelineConfig,
        config: RigConfig = RigConfig(),
    ) -> None:
        self.cameras = list(cameras)
        self.pipeline_config = pipeline_config
        self.config = config
        self.stats: dict[str, int] = {"handovers": 0, "merged": 0, "rig_tracks": 0}
        # Distance (px) of every pixel centre from the image's edge or the lens's valid
        # area, and the pixel's angular size: a view's margin to its border, any lens.
        self._border_px: list[np.ndarray] = []
        for cam in self.cameras:
            valid = np.pad(cam.valid_mask.astype(np.uint8), 1)
            dist = cv2.distanceTransform(valid, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            self._border_px.append(dist[1:-1, 1:-1])
        self._tracks: dict[int, _RigTrack] = {}
        self._binding: dict[tuple[int, int], int] = {}  # (camera id, track id) -> rig id
        self._last_frame: dict[int, int] = {}
        # Per-camera tracks replaced by a newer track of the same camera for their object.
        self._retired: set[tuple[int, int]] = set()
        self._next_id = 1

    @property
    def pipeline_config(self) -> PipelineConfig:
        """The pipelines' configuration (its classifier decides the cross-camera pairs);
        set it when the pipelines are rebuilt with another (the rig tracks stay)."""
        return self._pipeline_config

    @pipeline_config.setter
    def pipeline_config(self, value: PipelineConfig) -> None:
        self._pipeline_config = value
        cls = value.classifier
        self._fit_half_us = round(0.5 * cls.fit_window_for(value.detection.backend) * 1e6)
        span_s = cls.longest_interval_s + cls.interval_tolerance_s + 2 * self._fit_half_us * 1e-6
        self._history_us = round(span_s * 1e6)

    # -- the interface -------------------------------------------------------------------
    def fuse(self, camera_id: int, result: FrameResult) -> FrameResult:
        """Camera ``camera_id``'s pipeline result for one frame -> the objects to report
        for it: track_id replaced by the rig-wide id (stable when the object moves to
        another camera), objects another camera measures better left out, a per-camera
        track that continues an object another camera saw decided with that history (a
        cross-camera TCM pair in NED bearings). Same FrameResult type; frame_index/t_us
        unchanged."""
        k, t_us = camera_id, result.t_us
        last = self._last_frame.get(k)
        if last is not None and result.frame_index <= last:
            # A new pipeline (rebuilt) numbers its frames and tracks afresh.
            self._unbind_camera(k)
        self._last_frame[k] = result.frame_index
        live = {o.track_id for o in result.objects}
        for key in [key for key in self._binding if key[0] == k and key[1] not in live]:
            self._unbind(key)
        self._retired -= {key for key in self._retired if key[0] == k and key[1] not in live}
        self._prune(t_us)
        new = [
            o
            for o in result.objects
            if (k, o.track_id) not in self._binding and (k, o.track_id) not in self._retired
        ]
        # A track bound before it had a NED bearing (the frames before the first attitude)
        # has a rig track with no history, which no other camera's track could join: once
        # it has a bearing it is associated like a new one, and keeps its rig track (and
        # id) when nothing matches.
        orphans = [
            o
            for o in result.objects
            if (k, o.track_id) in self._binding
            and o.detected
            and _finite(o.bearing_ned)
            and self._orphaned(self._tracks[self._binding[(k, o.track_id)]], k)
        ]
        if new or orphans:
            self._associate(k, new, result.objects, t_us, orphans)
        out: list[ObjectResult] = []
        for obj in result.objects:
            if (k, obj.track_id) in self._retired:
                self.stats["merged"] += 1
                continue
            rt = self._tracks[self._binding[(k, obj.track_id)]]
            margin = self._margin_rad(k, obj)
            rt.views[k] = _View(t_us, margin, obj.detected)
            if obj.detected:
                rt.last_seen_us = max(rt.last_seen_us, t_us)
            if obj.detected and _finite(obj.bearing_ned):
                whole = margin > self.config.border_margin_rad
                view = _RigObservation(
                    t_us, obj.bearing_ned, obj.angular_radius_rad, k, margin, whole
                )
                self._add(rt, view)
            if not self._measures(rt, k, t_us):
                self.stats["merged"] += 1
                continue
            if obj.label:
                rt.label = obj.label
            obj = self._decided(rt, k, obj, result)
            obj = self._looming(rt, obj, t_us)
            out.append(replace(obj, track_id=rt.rig_id))
        return replace(result, objects=tuple(out))

    def camera_lost(self, camera_id: int) -> None:
        """Camera ``camera_id`` stopped delivering: forget the rig tracks only it measured
        (and its per-camera tracks' bindings); what another camera sees too stays."""
        for rt in list(self._tracks.values()):
            others = [c for c in rt.bound if c != camera_id]
            if not others and (camera_id in rt.bound or rt.measuring == camera_id):
                self._drop(rt)
        self._unbind_camera(camera_id)
        for rt in self._tracks.values():
            rt.views.pop(camera_id, None)
            if rt.measuring == camera_id and rt.bound:
                rt.measuring = min(rt.bound)
        self._last_frame.pop(camera_id, None)

    def has_track(self, rig_id: int) -> bool:
        """Whether rig track ``rig_id`` is still kept (some camera may report it)."""
        return rig_id in self._tracks

    # -- internals -----------------------------------------------------------------------
    def _unbind(self, key: tuple[int, int]) -> None:
        rid = self._binding.pop(key)
        rt = self._tracks.get(rid)
        if rt is not None and rt.bound.get(key[0]) == key[1]:
            del rt.bound[key[0]]

    def _unbind_camera(self, camera_id: int) -> None:
        for key in [key for key in self._binding if key[0] == camera_id]:
            self._unbind(key)
        self._retired -= {key for key in self._retired if key[0] == camera_id}

    def _drop(self, rt: _RigTrack) -> None:
        for cam, tid in list(rt.bound.items()):
            self._binding.pop((cam, tid), None)
        del self._tracks[rt.rig_id]

    def _prune(self, t_us: int) -> None:
        limit_us = round(self.config.max_unseen_s * 1e6)
        for rt in list(self._tracks.values()):
            if not rt.bound and t_us - rt.last_seen_us > limit_us:
                self._drop(rt)

    def _margin_rad(self, camera_id: int, obj: ObjectResult) -> float:
        """How far the object's edge is from camera ``camera_id``'s image border (rad;
        negative: cut by it)."""
        dist = self._border_px[camera_id]
        h, w = dist.shape
        u = min(max(int(obj.centroid_px[0]), 0), w - 1)
        v = min(max(int(obj.centroid_px[1]), 0), h - 1)
        px_rad = float(self.cameras[camera_id].pixel_size_map_rad[v, u])
        if not math.isfinite(px_rad):
            return -math.inf
        return float(dist[v, u]) * px_rad - obj.angular_radius_rad

    def _new_track(self, camera_id: int, track_id: int, t_us: int) -> _RigTrack:
        rt = _RigTrack(
            rig_id=self._next_id,
            first_t_us=t_us,
            last_seen_us=t_us,
            measuring=camera_id,
            history=[],
        )
        self._next_id += 1
        self.stats["rig_tracks"] += 1
        self._tracks[rt.rig_id] = rt
        self._bind(rt, camera_id, track_id, t_us)
        return rt

    def _bind(self, rt: _RigTrack, camera_id: int, track_id: int, t_us: int) -> None:
        rt.bound[camera_id] = track_id
        rt.bound_us[camera_id] = t_us
        rt.cameras.add(camera_id)
        self._binding[(camera_id, track_id)] = rt.rig_id

    @staticmethod
    def _orphaned(rt: _RigTrack, k: int) -> bool:
        """Rig track ``rt`` never had a NED bearing and only camera ``k``'s track is bound
        to it: it was started from frames without attitude."""
        return not rt.history and set(rt.bound) == {k}

    def _associate(
        self,
        k: int,
        new: list[ObjectResult],
        now: Sequence[ObjectResult],
        t_us: int,
        orphans: Sequence[ObjectResult] = (),
    ) -> None:
        """Bind camera ``k``'s tracks seen for the first time to rig tracks (the
        Hungarian assignment over bearing and size), or start rig tracks for them;
        ``orphans`` (:meth:`_orphaned` rig tracks' tracks) move to a rig track they match
        and otherwise stay where they are."""
        cfg = self.config
        # A rig track already bound to a track of this camera is a candidate only when
        # that track lost the object this frame (the camera's tracker started a new one,
        # e.g. as the object came out from behind its image border).
        detected = {o.track_id: o.detected for o in now}
        cands = [
            rt
            for rt in self._tracks.values()
            if rt.history and (k not in rt.bound or not detected.get(rt.bound[k], False))
        ]
        objs = [o for o in [*new, *orphans] if o.detected and _finite(o.bearing_ned)]
        assigned: set[int] = set()
        if cands and objs:
            pred = np.array([rt.predict_bearing_ned(t_us) for rt in cands])
            obs_b = np.array([o.bearing_ned for o in objs])
            ang = angle_between(pred[:, None, :], obs_b[None, :, :])
            alpha_r = np.array([rt.history[-1].angular_radius_rad for rt in cands])
            alpha_o = np.array([o.angular_radius_rad for o in objs])
            gate = cfg.gate_rad + cfg.gate_radius_factor * np.maximum(
                alpha_r[:, None], alpha_o[None, :]
            )
            # An older prediction is less sure: widen the gate with the time unseen.
            unseen_s = np.array([(t_us - rt.history[-1].t_us) * 1e-6 for rt in cands])
            gate = gate * (1.0 + unseen_s / max(cfg.stale_view_s, 1e-6))[:, None]
            size = np.abs(np.log(alpha_o[None, :] / alpha_r[:, None]))
            whole_o = np.array([self._margin_rad(k, o) > cfg.border_margin_rad for o in objs])
            whole_r = np.array([rt.history[-1].whole for rt in cands])
            size_ok = (size <= cfg.max_log_size_change) | ~(whole_r[:, None] & whole_o[None, :])
            labels = np.array(
                [[not rt.label or not o.label or rt.label == o.label for o in objs] for rt in cands]
            )
            ok = (ang <= gate) & size_ok & labels
            size = np.where(np.isfinite(size), size, 0.0)
            cost = np.where(ok, ang / gate + 0.5 * np.minimum(size, 2.0), 1e6)
            if len(cands) == 1 and len(objs) == 1:
                pairs = [(0, 0)]  # the common case, without the solver (or its import)
            else:
                from scipy.optimize import linear_sum_assignment  # ~0.5 s to import

                rows, cols = linear_sum_assignment(cost)
                pairs = list(zip(rows.tolist(), cols.tolist(), strict=True))
            for r, c in pairs:
                if not ok[r, c]:
                    continue
                rt, obj = cands[r], objs[c]
                if k not in rt.cameras:
                    self.stats["handovers"] += 1  # another camera's object, now in this one
                if (k, obj.track_id) in self._binding:  # an orphan: its empty rig track goes
                    self._drop(self._tracks[self._binding[(k, obj.track_id)]])
                old = rt.bound.get(k)
                if old is not None:
                    # The camera's old track of the object coasts out, unreported.
                    self._binding.pop((k, old), None)
                    self._retired.add((k, old))
                self._bind(rt, k, obj.track_id, t_us)
                assigned.add(obj.track_id)
        for obj in new:
            if obj.track_id not in assigned:
                self._new_track(k, obj.track_id, t_us)

    def _measures(self, rt: _RigTrack, k: int, t_us: int) -> bool:
        """Whether camera ``k`` reports the rig track now (switching to it when the
        measuring camera no longer sees it, or sees it worse by the switch margin)."""
        m = rt.measuring
        if m == k:
            return True
        mine = rt.views[k]
        theirs = rt.views.get(m)
        stale_us = round(self.config.stale_view_s * 1e6)
        switch = (
            m not in rt.bound
            or theirs is None
            or t_us - theirs.t_us > stale_us
            or (mine.detected and not theirs.detected)
            or (
                mine.detected
                and mine.margin_rad > theirs.margin_rad + self.config.switch_margin_rad
            )
        )
        if not switch:
            return False
        rt.measuring = k
        # The measuring camera already reported the object this frame cycle (its frame
        # was captured with this one): this camera reports it from the next cycle on.
        same_us = round(self._slack_s(rt) * 1e6)
        reported = m in rt.bound and theirs is not None and abs(theirs.t_us - t_us) <= same_us
        return not reported

    def _add(self, rt: _RigTrack, obs: _RigObservation) -> None:
        bisect.insort(rt.history, obs, key=lambda o: o.t_us)
        newest_us = rt.history[-1].t_us
        drop = bisect.bisect_left(rt.history, newest_us - self._history_us, key=lambda o: o.t_us)
        if drop:
            del rt.history[:drop]

    def _remember(self, rt: _RigTrack, t_us: int, c: Classification) -> None:
        cls = self.pipeline_config.classifier
        rt.memory.append((t_us, c))
        hold_us = round(cls.hold_s * 1e6)
        while rt.memory and t_us - rt.memory[0][0] > hold_us:
            rt.memory.popleft()

    def _decided(
        self, rt: _RigTrack, k: int, obj: ObjectResult, result: FrameResult
    ) -> ObjectResult:
        """The object with the rig's decision: its own when its camera decided it;
        while its track warms up in a camera that took over the object, the decision of
        a cross-camera pair and the rig track's hold."""
        if obj.state != "unknown":
            self._remember(rt, result.t_us, obj.classification)
            rt.decision = obj.classification
            return obj
        if obj.reason not in CROSS_PAIR_REASONS or not obj.detected:
            return obj
        pair = self._cross_pair(rt, k, result)
        if pair is None or pair.state == "unknown":
            return obj
        cls = self.pipeline_config.classifier
        self._remember(rt, result.t_us, pair)
        decided = decide(hold(pair, [c for _, c in rt.memory]), cls)
        slack_us = round(self._slack_s(rt) * 1e6)
        young = result.t_us - rt.first_t_us < round(cls.interval_s * 1e6) - slack_us
        if decided.state == "stationary" and young:
            return obj  # as the pipeline: stationary only once seen for the full interval
        rt.decision = decided
        return replace(obj, state=decided.state, reason=decided.reason, classification=decided)

    def _looming(self, rt: _RigTrack, obj: ObjectResult, t_us: int) -> ObjectResult:
        """The object with its time to contact fitted over the rig track's whole views
        (any camera's, captured within the looming window up to ``t_us``; of views
        captured together the best-placed), when they are enough for a fit: a camera's
        own track of an object coming into its view from a neighbour's measures it cut
        by the image border, growing as it comes in, which its looming fit reads as an
        approach (a ball passing 3 m to the side read TTC 0.9 s, collision course, at
        the switch between two cameras). Too few whole views: the camera's own fit."""
        if not (obj.detected and _finite(obj.bearing_ned)):
            return obj
        ttc_cfg = self.pipeline_config.ttc
        same_us = round(self._slack_s(rt) * 1e6)
        window_us = round(ttc_cfg.window_s * 1e6) + same_us
        views: list[_RigObservation] = []
        for o in rt.history:
            if not o.whole or o.t_us > t_us or t_us - o.t_us >= window_us:
                continue
            if views and o.t_us - views[-1].t_us <= same_us:
                if o.margin_rad > views[-1].margin_rad:
                    views[-1] = o  # one view per capture time: the better-placed
                continue
            views.append(o)
        if len(views) < ttc_cfg.min_samples:
            return obj
        est = estimate_ttc(
            np.array([o.t_us * 1e-6 for o in views]),
            np.array([o.angular_radius_rad for o in views]),
            np.array([o.bearing_ned for o in views]),
            ttc_cfg,
        )
        return replace(
            obj,
            ttc_s=est.ttc_s,
            collision_course=est.collision_course,
            miss_radii=est.miss_radii,
            ttc_confidence=est.confidence,
        )

    def _slack_s(self, rt: _RigTrack) -> float:
        """A quarter of the frame period of the track's views (capture jitter)."""
        times = sorted({o.t_us for o in rt.history[-16:]}, reverse=True)
        return jitter_slack_s(median_period_s(times))

    def _cross_pair(self, rt: _RigTrack, k: int, result: FrameResult) -> Classification | None:
        """TCM on the rig track's observation nearest an interval before this frame's pair
        end (from whichever camera saw it then) and the one at the end, with this camera's
        translation over the default interval; None without the three."""
        est = result.translation
        if est is None or not est.valid:
            return None
        cls = self.pipeline_config.classifier
        tol_us = round(cls.interval_tolerance_s * 1e6)
        same_us = round(self._slack_s(rt) * 1e6)
        end_us = result.t_us - self._fit_half_us
        cur = rt.nearest(end_us, tol_us, result.t_us, same_us)
        if cur is None:
            return None
        ref = rt.nearest(cur.t_us - round(cls.interval_s * 1e6), tol_us, cur.t_us - 1, same_us)
        if ref is None:
            return None
        if ref.camera_id == k and cur.camera_id == k and ref.t_us >= rt.bound_us.get(k, 0):
            # Both ends seen by this camera's present track: its own pipeline decides.
            return None
        b1 = cur.bearing_ned
        if self.pipeline_config.egomotion_rotation_correction and est.rotation_ned_rad.any():
            b1 = rotate_by_vector(b1, est.rotation_ned_rad)
        return classify_pair(
            est.t_hat_ned,
            ref.bearing_ned,
            b1,
            ref.angular_radius_rad,
            cur.angular_radius_rad,
            cls,
            0,
            t_sigma_rad=est.sigma_rad if math.isfinite(est.sigma_rad) else 0.0,
            interval_s=(cur.t_us - ref.t_us) * 1e-6,
        )
