"""The TCM pipeline: one object that turns frames and telemetry into per-object results.

``Pipeline.step(frame, frame_time_us)`` runs, for one camera frame (the autopilot's
telemetry reaches it one way only: the :class:`TelemetryBuffer` given to the constructor,
which the caller feeds and may share between cameras):
attitude at the frame time (slerp on the autopilot clock mapped to the companion clock)
→ detection (the ``[detection] backend``: colour, boxes or onnx) → tracking by bearing →
optic flow → translation between the frame and the one captured ``interval_s`` earlier
(vision, autopilot or fused) → TCM/ECM (and BSM when enabled) per track → time to contact.

A frame without attitude still reports the objects it sees: tracked in the camera frame,
``unknown`` with reason "no attitude", their local-level bearing NaN and no time to
contact (``ObjectResult``); the body-frame bearing, angular radius and label are known. It keeps the short history the method needs and
nothing else; it never reads a clock, a file or a device (stage timings use an injected
timer and do not affect results). Flight, SITL and replay all call this same object.

Frames arrive at whatever rate the companion manages (frames it cannot process are
dropped, never queued), so every duration of the method is in seconds of capture time:
the reference observation is the one captured nearest ``interval_s`` earlier, the hold,
the warm-ups and the looming window are measured in seconds (:mod:`.timebase`). The
histories are frame rings sized for the longest interval at ``MAX_FRAME_RATE_HZ``.
"""

from __future__ import annotations

import itertools
import math
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from .bsm import BackgroundSubtractor, BSMConfig
from .camera import CameraModel
from .classify import (
    Classification,
    ClassifierConfig,
    State,
    classify_hover,
    classify_pair,
    combine_pairs,
    decide,
    hold,
    unknown,
)
from .detection import Detection, DetectionConfig, DetectorBackend, make_detector
from .egomotion import (
    EgomotionConfig,
    TranslationEstimate,
    fuse,
    translation_from_bearings,
    translation_from_positions,
)
from .flow import FlowConfig, FlowTracker
from .frames import FloatArray, azel_from_bearing, rotate_by_vector, vector_norm
from .tcm import stationary_range_m, triangle_geometry
from .telemetry import TelemetryBuffer
from .timebase import frames_to_cover, jitter_slack_s, median_period_s
from .tracking import Observation, Track, Tracker, TrackerConfig
from .ttc import TTCConfig, estimate_ttc, robust_level_at

#: Frame records kept at least (the paper's Fig. 4 study compares frames up to 40 apart,
#: at 25 Hz, through :meth:`Pipeline.disparities_for_frame_intervals`).
MIN_FRAME_RECORDS = 48
#: Frames whose capture times give the frame period for the jitter allowance.
PERIOD_FRAMES = 16

EgomotionSource = Literal["vision", "autopilot", "fused"]

#: The local-level bearing of an object seen in a frame without attitude.
_NO_BEARING: FloatArray = np.full(3, np.nan)
_NO_BEARING.setflags(write=False)


@dataclass(frozen=True)
class PipelineConfig:
    """Every tunable of the core, one frozen dataclass per stage."""

    egomotion_source: EgomotionSource = "fused"
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    tracking: TrackerConfig = field(default_factory=TrackerConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    egomotion: EgomotionConfig = field(default_factory=EgomotionConfig)
    classifier: ClassifierConfig = field(default_factory=ClassifierConfig)
    ttc: TTCConfig = field(default_factory=TTCConfig)
    bsm: BSMConfig = field(default_factory=BSMConfig)
    bsm_enabled: bool = False  # BSM costs a whole-frame warp; on for method "bsm" or eval
    # Undo the attitude error between two frames that vision egomotion measured.
    egomotion_rotation_correction: bool = True
    # Compute the default interval's translation at every frame, even when no track's
    # pair needed it (FrameResult.translation): a camera rig decides a young track that
    # continues another camera's object with it (core.rig). None (unset, and so left out
    # of a written configuration): off; the Companion sets True for two cameras or more.
    always_translate: bool | None = None


@dataclass(frozen=True)
class ObjectResult:
    """One tracked object in one frame."""

    track_id: int
    detected: bool  # False while the track coasts through a missed detection
    state: State
    reason: str  # why the state is unknown ("" otherwise)
    bearing_cam: FloatArray  # (3,) unit, camera FRD
    bearing_body: FloatArray  # (3,) unit, body FRD
    bearing_ned: FloatArray  # (3,) unit, local level NED; NaN in a frame without attitude
    azimuth_ned_rad: float  # clockwise from north (NaN without attitude)
    elevation_ned_rad: float  # positive up (NaN without attitude)
    angular_radius_rad: float
    centroid_px: tuple[float, float]
    classification: Classification
    ttc_s: float  # NaN when not approaching
    collision_course: bool
    miss_radii: float  # predicted miss distance in object radii (NaN if unknown)
    # Confidence in ttc_s and collision_course (0..1), from the looming fit alone: a
    # head-on object has no TCM state but may have a confident time to contact.
    ttc_confidence: float = 0.0
    # What the detector calls it: the track's most frequent recent label ("" if none).
    label: str = ""

    @property
    def disparity(self) -> float:
        return self.classification.disparity


@dataclass(frozen=True)
class FrameResult:
    frame_index: int
    t_us: int
    objects: tuple[ObjectResult, ...]
    attitude_ok: bool
    translation: TranslationEstimate | None  # for the default interval, if computed
    timings_ms: dict[str, float]


@dataclass
class PipelineHealth:
    frames: int = 0
    frames_without_attitude: int = 0
    time_backwards: int = 0
    bad_frames: int = 0
    events: Counter[str] = field(default_factory=Counter)


@dataclass(frozen=True)
class _FrameRecord:
    index: int
    t_us: int
    R_ned_from_cam: FloatArray | None
    pos_ned_m: FloatArray | None
    gray: np.ndarray | None  # kept only when BSM is enabled


class Pipeline:
    """Frames and telemetry in, :class:`FrameResult` out. One per camera."""

    def __init__(
        self,
        camera: CameraModel,
        config: PipelineConfig = PipelineConfig(),
        timer: Callable[[], float] = time.perf_counter,
        *,
        telemetry: TelemetryBuffer | None = None,
        detector_model: bytes | None = None,
    ) -> None:
        """``detector_model``: the bytes of the model file the ``onnx`` detection backend
        runs (the caller reads ``[detection] onnx_model``; None for the other backends)."""
        self.camera = camera
        self.config = config
        self._timer = timer
        self._telemetry = telemetry if telemetry is not None else TelemetryBuffer()
        cls = config.classifier
        # Every history covers the longest interval and its tolerance at the fastest
        # frame rate supported (and at least MIN_FRAME_RECORDS frames, for the Fig. 4
        # study); by count, so memory is bounded whatever the rate.
        span_s = cls.longest_interval_s + cls.interval_tolerance_s
        depth = max(frames_to_cover(span_s), MIN_FRAME_RECORDS)
        tracking = config.tracking
        if tracking.history_s < span_s:
            tracking = replace(tracking, history_s=span_s)
        flow_cfg = config.flow
        if flow_cfg.max_history < depth:
            flow_cfg = replace(flow_cfg, max_history=depth)
        self.detector: DetectorBackend = make_detector(camera, config.detection, detector_model)
        self.tracker = Tracker(tracking)
        self.flow = FlowTracker(camera, flow_cfg)
        self._frames: deque[_FrameRecord] = deque(maxlen=depth)
        self._bsm = (
            BackgroundSubtractor(camera, config.bsm)
            if (config.bsm_enabled or cls.method == "bsm")
            else None
        )
        self._index = 0
        self._last_t_us: int | None = None
        self._bsm_s = 0.0  # time spent in BSM this step (reported apart from classify)
        self._bsm_warps: dict[int, np.ndarray] = {}  # reference frame -> warp, this step
        self._bsm_warps_for = -1
        # Recent decided classifications per track (capture time, result), for the hold.
        self._memory: dict[int, deque[tuple[int, Classification]]] = {}
        # Allowance for capture-time jitter this step (s): a quarter frame period.
        self._slack_s = 0.0
        # Fit window of the pair's ends (classify.fit_window_for): half of it, µs.
        self._fit_half_us = round(0.5 * cls.fit_window_for(config.detection.backend) * 1e6)
        self.health = PipelineHealth()

    @property
    def telemetry(self) -> TelemetryBuffer:
        """The attitude and position this pipeline reads (the caller feeds it)."""
        return self._telemetry

    # -- the one entry point -------------------------------------------------------
    def step(self, frame: np.ndarray, frame_time_us: int) -> FrameResult:
        """Process one BGR frame captured at ``frame_time_us`` (companion clock), with the
        telemetry its buffer holds by then."""
        timings: dict[str, float] = {}
        clock = self._timer
        t_start = clock()
        if self._last_t_us is not None and frame_time_us <= self._last_t_us:
            # Time went backwards (camera restart, clock step): history is meaningless.
            self.health.time_backwards += 1
            self._reset_history()
        self._last_t_us = frame_time_us
        index = self._index
        self._index += 1
        self.health.frames += 1

        if (
            frame is None
            or frame.ndim != 3
            or frame.shape[:2] != (self.camera.height, self.camera.width)
        ):
            self.health.bad_frames += 1
            return FrameResult(index, frame_time_us, (), False, None, {"total": 0.0})

        R_body = self.telemetry.attitude_at(frame_time_us)
        R_ned_from_cam = None if R_body is None else R_body @ self.camera.R_body_from_cam
        if R_ned_from_cam is None:
            self.health.frames_without_attitude += 1
        pos = self.telemetry.position_at(frame_time_us)
        t0 = clock()
        timings["telemetry"] = (t0 - t_start) * 1e3

        detections = self.detector.detect(frame, frame_time_us)
        t1 = clock()
        timings["detect"] = (t1 - t0) * 1e3

        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        boxes = [d.bbox_px for d in detections]
        self.flow.update(gray, index, R_ned_from_cam, boxes)
        t2 = clock()
        timings["flow"] = (t2 - t1) * 1e3

        self._frames.append(
            _FrameRecord(
                index,
                frame_time_us,
                R_ned_from_cam,
                None if pos is None else pos[0],
                gray if self._bsm is not None else None,
            )
        )
        self._slack_s = jitter_slack_s(
            median_period_s(r.t_us for r in itertools.islice(reversed(self._frames), PERIOD_FRAMES))
        )
        # Without attitude the objects are still tracked, in the camera frame (their
        # local-level bearings are NaN), and reported as unknown ("no attitude").
        obs = [self._observation(d, index, frame_time_us, R_ned_from_cam) for d in detections]
        tracks = self.tracker.update(obs, frame_time_us)
        t3 = clock()
        timings["track"] = (t3 - t2) * 1e3

        cache: dict[tuple[int, int], TranslationEstimate] = {}
        self._bsm_s = 0.0
        objects = [self._object_result(tr, frame_time_us, cache) for tr in tracks]
        live = {tr.track_id for tr in tracks}
        for tid in [t for t in self._memory if t not in live]:
            del self._memory[tid]
        # The translation reported: the default interval's, ending at this frame (with a
        # fit window, at the frame half a window back, where the pairs end).
        end = self._frame_near(frame_time_us - self._fit_half_us) if self._fit_half_us else None
        end_index, end_us = (index, frame_time_us) if end is None else (end.index, end.t_us)
        default_ref = self._frame_near(end_us - round(self.config.classifier.interval_s * 1e6))
        if self.config.always_translate and default_ref is not None:
            key = (default_ref.index, end_index)
            if key not in cache and default_ref.index != end_index:
                cache[key] = self._translation(*key)
        t4 = clock()
        timings["bsm"] = self._bsm_s * 1e3
        timings["classify"] = (t4 - t3 - self._bsm_s) * 1e3
        timings["total"] = (t4 - t_start) * 1e3
        return FrameResult(
            index,
            frame_time_us,
            tuple(objects),
            R_ned_from_cam is not None,
            cache.get((default_ref.index, end_index)) if default_ref is not None else None,
            timings,
        )

    def disparities_for_frame_intervals(
        self, intervals_frames: Sequence[int]
    ) -> dict[int, dict[int, float]]:
        """TCM disparity of every track detected in the last frame, for each interval
        counted in processed frames.

        An analysis hook for the paper's Fig. 4 separation study, which is about frame
        intervals at the paper's 25 Hz by design (``eval --intervals``); the decisions
        themselves use seconds. Call right after :meth:`step`; intervals up to
        ``MIN_FRAME_RECORDS - 2`` frames are always available. Returns
        ``{interval: {track_id: δ}}`` where defined.
        """
        intervals = intervals_frames
        out: dict[int, dict[int, float]] = {}
        if not self._frames:
            return out
        index = self._frames[-1].index
        for k in intervals:
            per_track: dict[int, float] = {}
            est: TranslationEstimate | None = None
            for track in self.tracker.tracks:
                cur = track.last
                ref = track.at_frame(index - k)
                if track.coasting or ref is None or cur.frame_index != index:
                    continue
                if not (ref.has_attitude and cur.has_attitude):
                    continue
                if est is None:
                    est = self._translation(index - k, index)
                if not est.valid:
                    break
                geo = triangle_geometry(
                    est.t_hat_ned,
                    ref.bearing_ned,
                    cur.bearing_ned,
                    ref.angular_radius_rad,
                    cur.angular_radius_rad,
                )
                per_track[track.track_id] = float(geo.disparity)
            out[k] = per_track
        return out

    # -- internals ---------------------------------------------------------------------
    def _reset_history(self) -> None:
        self._memory.clear()
        self._frames.clear()
        self.tracker.reset()
        self.flow.reset()

    def _observation(
        self, det: Detection, index: int, t_us: int, R_ned_from_cam: FloatArray | None
    ) -> Observation:
        b_body = self.camera.R_body_from_cam @ det.bearing_cam
        return Observation(
            frame_index=index,
            t_us=t_us,
            bearing_ned=(
                R_ned_from_cam @ det.bearing_cam if R_ned_from_cam is not None else _NO_BEARING
            ),
            bearing_body=b_body,
            bearing_cam=det.bearing_cam,
            angular_radius_rad=det.angular_radius_rad,
            centroid_px=det.centroid_px,
            touches_border=det.touches_border,
            label=det.label,
        )

    def _record(self, index: int) -> _FrameRecord | None:
        if not self._frames:
            return None
        offset = index - self._frames[0].index
        if 0 <= offset < len(self._frames) and self._frames[offset].index == index:
            return self._frames[offset]
        for rec in self._frames:
            if rec.index == index:
                return rec
        return None

    def _frame_near(self, t_us: int) -> _FrameRecord | None:
        """The frame record captured nearest ``t_us``, within the interval tolerance (as
        :meth:`Track.nearest_in_time` picks a track's reference)."""
        tol_us = round(self.config.classifier.interval_tolerance_s * 1e6)
        slack_us = round(self._slack_s * 1e6)
        best: _FrameRecord | None = None
        for rec in reversed(self._frames):  # newest first: an earlier one wins near-ties
            dt = abs(rec.t_us - t_us)
            if dt <= tol_us and (best is None or dt <= abs(best.t_us - t_us) + slack_us):
                best = rec
            if rec.t_us < t_us - tol_us:
                break
        return best

    def _translation(self, ref_index: int, cur_index: int) -> TranslationEstimate:
        src = self.config.egomotion_source
        vision = autopilot = None
        if src in ("vision", "fused"):
            b0, b1 = self.flow.correspondences(ref_index, cur_index)
            vision = translation_from_bearings(b0, b1, self.config.egomotion, rng_seed=cur_index)
        if src in ("autopilot", "fused"):
            r0, r1 = self._record(ref_index), self._record(cur_index)
            if r0 is None or r1 is None or r0.pos_ned_m is None or r1.pos_ned_m is None:
                autopilot = TranslationEstimate.invalid("autopilot")
            else:
                autopilot = translation_from_positions(
                    r0.pos_ned_m, r1.pos_ned_m, self.config.egomotion
                )
        if vision is None:
            assert autopilot is not None
            return autopilot
        if autopilot is None:
            return vision
        return fuse(vision, autopilot, self.config.egomotion)

    def _classify(
        self,
        track: Track,
        cache: dict[tuple[int, int], TranslationEstimate],
        t_us: int | None = None,
    ) -> Classification:
        """Compare the newest observation with earlier ones, then apply the hold.

        For each interval, the reference is the observation captured nearest
        ``interval_s`` earlier, within ``interval_tolerance_s``. With none for any interval
        (a young track, or detections missed around that time) the one nearest the
        primary interval's time among those at least ``min_interval_s`` old serves.

        With a fit window (``fit_window_s`` > 0, the default for box detectors) the later
        end is the observation captured nearest half a window before the frame at ``t_us``
        (the frame being processed; default the track's newest observation), and each end's
        size and bearing are fitted over the window centred on it (:meth:`_fitted`), so
        the pair is judged as of half a window ago; a frame that missed the object is
        still decided from the observations around that time.
        """
        cls = self.config.classifier
        cur = track.last
        if self._fit_half_us > 0:
            now_us = cur.t_us if t_us is None else t_us
            slack_us = round(self._slack_s * 1e6)
            anchor = track.nearest_in_time(
                now_us - self._fit_half_us,
                self._fit_half_us + slack_us,
                not_after_us=now_us,
                prefer_earlier_us=slack_us,
            )
            if anchor is None:
                return unknown("lost track")
            cur = anchor
        elif track.coasting:
            return unknown("lost track")
        fitted: dict[int, Observation] = {}

        def fit(obs: Observation) -> Observation:
            """The pair's end ``obs``, fitted over its window when there is one."""
            if self._fit_half_us <= 0:
                return obs
            if obs.frame_index not in fitted:
                fitted[obs.frame_index] = self._fitted(track, obs)
            return fitted[obs.frame_index]

        if not cur.has_attitude:
            return unknown("no attitude")
        slack_us = round(self._slack_s * 1e6)
        tol_us = round(cls.interval_tolerance_s * 1e6)
        interval_us = round(cls.interval_s * 1e6)
        pairs: list[Classification] = []
        for interval_s in cls.intervals_s:
            k_us = round(interval_s * 1e6)
            ref = track.nearest_in_time(
                cur.t_us - k_us, tol_us, not_after_us=cur.t_us - 1, prefer_earlier_us=slack_us
            )
            if ref is not None:
                # BSM (a whole-frame warp) only for a full primary-interval pair.
                full = k_us == interval_us and cur.t_us - ref.t_us >= interval_us - slack_us
                full = full and cur is track.last and not track.coasting
                pairs.append(self._classify_pair(fit(ref), fit(cur), cache, bsm=full))
        if not pairs:
            newest_us = cur.t_us - round(cls.warmup_moving_s * 1e6) + slack_us
            ref = track.nearest_in_time(
                cur.t_us - interval_us, 1 << 62, not_after_us=min(newest_us, cur.t_us - 1)
            )
            if ref is None:
                return unknown("warm-up")
            pairs.append(self._classify_pair(fit(ref), fit(cur), cache, bsm=False))
        decided = [c for c in pairs if c.state != "unknown"]
        if not decided:
            return pairs[-1]
        combined = combine_pairs(decided)
        memory = self._memory.setdefault(track.track_id, deque())
        memory.append((cur.t_us, combined))
        hold_us = round(cls.hold_s * 1e6) + slack_us
        while memory and cur.t_us - memory[0][0] > hold_us:
            memory.popleft()
        result = decide(hold(combined, [c for _, c in memory]), cls)
        if result.state == "stationary" and track.age_s(cur.t_us) < cls.interval_s - self._slack_s:
            # Motion can show over a short interval; its absence cannot: a young track is
            # called stationary only once it has been seen for the full interval.
            return replace(result, state="unknown", reason="warm-up")
        return result

    def _classify_pair(
        self,
        ref: Observation,
        cur: Observation,
        cache: dict[tuple[int, int], TranslationEstimate],
        bsm: bool,
    ) -> Classification:
        cls = self.config.classifier
        interval = cur.frame_index - ref.frame_index
        interval_s = (cur.t_us - ref.t_us) * 1e-6
        if not ref.has_attitude:  # the reference frame had no attitude
            return unknown("no attitude", interval, interval_s)
        key = (ref.frame_index, cur.frame_index)
        if key not in cache:
            cache[key] = self._translation(ref.frame_index, cur.frame_index)
        est = cache[key]
        if not est.valid:
            hovering = est.parallax_rad < self.config.egomotion.min_parallax_rad or (
                est.magnitude_m < cls.hover_max_baseline_m
            )
            if cls.hover_test and hovering and not (cur.touches_border or ref.touches_border):
                return classify_hover(
                    ref.bearing_ned,
                    cur.bearing_ned,
                    ref.angular_radius_rad,
                    cur.angular_radius_rad,
                    cls,
                    interval,
                    interval_s,
                )
            return unknown("no translation", interval, interval_s)
        if cls.min_baseline_m > 0 and not (est.magnitude_m >= cls.min_baseline_m):
            if math.isfinite(est.magnitude_m):
                return unknown("small baseline", interval, interval_s)
        if cls.min_flow_parallax_rad > 0 and est.parallax_rad < cls.min_flow_parallax_rad:
            return unknown("small baseline", interval, interval_s)
        if cur.touches_border or ref.touches_border:
            return unknown("at image border", interval, interval_s)
        bsm_score = self._bsm_score(ref) if (bsm and self._bsm is not None) else math.nan
        b1 = cur.bearing_ned
        if self.config.egomotion_rotation_correction and est.rotation_ned_rad.any():
            # Vision measured the attitude error between the two frames: undo it.
            b1 = rotate_by_vector(b1, est.rotation_ned_rad)
        result = classify_pair(
            est.t_hat_ned,
            ref.bearing_ned,
            b1,
            ref.angular_radius_rad,
            cur.angular_radius_rad,
            cls,
            interval,
            bsm_score,
            t_sigma_rad=est.sigma_rad if math.isfinite(est.sigma_rad) else 0.0,
            interval_s=interval_s,
        )
        parallax = abs(result.theta1_rad - result.theta0_rad)
        if (
            result.state == "stationary"
            and math.isfinite(est.magnitude_m)
            and parallax >= cls.min_range_parallax_rad
        ):
            _, d1 = stationary_range_m(est.t_hat_ned * est.magnitude_m, ref.bearing_ned, b1)
            result = replace(result, range_m=float(d1) if float(d1) > 0 else math.nan)
        return result

    def _fitted(self, track: Track, obs: Observation) -> Observation:
        """``obs`` with its size and local-level bearing fitted over the track's
        observations captured within half a fit window of it (robust straight lines of
        ``ln sin α`` and of each bearing component against time, evaluated at its capture
        time: a box detector's per-frame jitter averages down by about √N); as it is when
        fewer than two such observations have attitude and a whole object."""
        span_us = self._fit_half_us + round(self._slack_s * 1e6)
        near = [
            o
            for o in track.history
            if abs(o.t_us - obs.t_us) <= span_us
            and o.has_attitude
            and not o.touches_border
            and o.angular_radius_rad > 0
        ]
        if len(near) < 2 or not obs.has_attitude:
            return obs
        t_s = np.array([(o.t_us - obs.t_us) * 1e-6 for o in near])
        log_sin = np.log(np.sin(np.array([o.angular_radius_rad for o in near])))
        b = np.array([o.bearing_ned for o in near])
        level = robust_level_at(t_s, log_sin, 0.0)
        bearing = np.array([robust_level_at(t_s, b[:, k], 0.0) for k in range(3)])
        norm = vector_norm(bearing)
        if not (math.isfinite(level) and norm > 0 and math.isfinite(norm)):
            return obs
        alpha = math.asin(min(1.0, math.exp(level)))
        return replace(obs, bearing_ned=bearing / norm, angular_radius_rad=alpha)

    def _bsm_score(self, ref: Observation) -> float:
        assert self._bsm is not None
        r0, r1 = self._record(ref.frame_index), self._frames[-1]
        if (
            r0 is None
            or r0.gray is None
            or r1.gray is None
            or r0.R_ned_from_cam is None
            or r1.R_ned_from_cam is None
            or r0.pos_ned_m is None
            or r1.pos_ned_m is None
        ):
            return math.nan
        start = self._timer()
        warped = self._bsm_warps.get(ref.frame_index) if self._bsm_warps_for == r1.index else None
        if warped is None:
            warped = self._bsm.warp_current_into_earlier(
                r1.gray, r0.R_ned_from_cam, r1.R_ned_from_cam, r0.pos_ned_m, r1.pos_ned_m
            )
            if self._bsm_warps_for != r1.index:
                self._bsm_warps = {}
                self._bsm_warps_for = r1.index
            self._bsm_warps[ref.frame_index] = warped
        u, v = ref.centroid_px
        px_size = float(
            self.camera.pixel_size_map_rad[
                min(int(v), self.camera.height - 1), min(int(u), self.camera.width - 1)
            ]
        )
        radius_px = ref.angular_radius_rad / max(px_size, 1e-9)
        score = self._bsm.score(r0.gray, warped, ref.centroid_px, radius_px)
        self._bsm_s += self._timer() - start
        return score

    def _object_result(
        self, track: Track, t_us: int, cache: dict[tuple[int, int], TranslationEstimate]
    ) -> ObjectResult:
        obs = track.last
        cls = self._classify(track, cache, t_us)
        # The looming fit: observations captured within window_s of this frame, and at
        # least the newest min_samples (estimate_ttc takes the same ones).
        window_us = round(self.config.ttc.window_s * 1e6) - round(self._slack_s * 1e6)
        least = self.config.ttc.min_samples
        hist = [
            o
            for _, o in itertools.takewhile(
                lambda ko: ko[0] < least or t_us - ko[1].t_us < window_us,
                enumerate(reversed(track.history)),
            )
        ]
        hist.reverse()
        if not obs.has_attitude:
            hist = []  # no time to contact from a frame without attitude
        elif not all(o.has_attitude for o in hist):
            hist = [o for o in hist if o.has_attitude]
        ttc = estimate_ttc(
            np.array([o.t_us * 1e-6 for o in hist]),
            np.array([o.angular_radius_rad for o in hist]),
            np.array([o.bearing_ned for o in hist]).reshape(-1, 3),
            self.config.ttc,
        )
        az, el = azel_from_bearing(obs.bearing_ned)
        return ObjectResult(
            track_id=track.track_id,
            detected=not track.coasting,
            state=cls.state,
            reason=cls.reason,
            bearing_cam=obs.bearing_cam,
            bearing_body=obs.bearing_body,
            bearing_ned=obs.bearing_ned,
            azimuth_ned_rad=float(az),
            elevation_ned_rad=float(el),
            angular_radius_rad=obs.angular_radius_rad,
            centroid_px=obs.centroid_px,
            classification=cls,
            ttc_s=ttc.ttc_s,
            collision_course=ttc.collision_course,
            miss_radii=ttc.miss_radii,
            ttc_confidence=ttc.confidence,
            label=track.label,
        )
