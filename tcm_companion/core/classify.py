"""Moving / stationary decision for one track: TCM, the ECM and BSM baselines, fused.

The classifier looks back ``interval_s`` seconds (the paper's 25 frames at 25 Hz) from the
current observation, to the track's observation captured nearest that time, takes the
vehicle's translation direction between the two actual frames, and computes the TCM
disparity δ and the ECM angle Ω. Every duration is in seconds of capture time, so the
decision means the same at whatever frame rate the companion manages (see
:mod:`.timebase`). The decision is ``unknown`` whenever the geometry cannot support one,
with the reason:

- ``warm-up``: the track is younger than the shortest usable interval (or, for a
  stationary decision, than the full interval);
- ``lost track``: no detection this frame (the track is coasting);
- ``no attitude``/``no translation``: egomotion unavailable for the pair;
- ``small baseline``: the vehicle moved too little between the frames (hover, turnaround);
- ``head-on``: the object lies within ``min_theta`` of the translation axis (0/0), or so
  near it for its angular size that the wander of its centre on a solid object makes δ
  too uncertain (``head_on_extent_fraction``);
- ``at image border``: the object is cut by the image edge, so its size is not its size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .frames import angle_between
from .tcm import ecm_omega_rad, triangle_geometry

Method = Literal["tcm", "ecm", "bsm", "fused"]
METHODS: tuple[Method, ...] = ("tcm", "ecm", "bsm", "fused")
State = Literal["moving", "stationary", "unknown"]
#: Default fit window of a pair's ends per detection backend (s): colour measures sizes
#: to a fraction of a pixel (δ of a static ball 0.015 ± 0.005) and stays bit-identical with
#: single observations; a box detector's 1-px / 4 % jitter needs the window (§9).
FIT_WINDOW_S: dict[str, float] = {"colour": 0.0, "boxes": 0.48, "onnx": 0.48}


@dataclass(frozen=True)
class ClassifierConfig:
    method: Method = "tcm"
    # Time between the two observations compared, s (paper: 25 frames at 25 Hz). The
    # reference is the track's observation captured nearest ``interval_s`` earlier.
    interval_s: float = 1.0
    # More intervals compared at every frame (s); the largest score decides. A moving
    # object whose displacement over one interval happens to vanish shows it over another.
    extra_intervals_s: tuple[float, ...] = ()
    # A score counts for this long after it was measured (s): an oscillating object whose
    # displacement over the interval passes through zero is still moving
    # (tools/decision_study.py: T45 80% -> 99.7%, stationary scenarios unchanged).
    hold_s: float = 0.48
    # Warm-up: a young track may be called moving from a pair this far apart (s), but
    # stationary only once it has been seen for the whole ``interval_s``.
    min_interval_s: float = 0.4
    # The reference observation may be captured this much earlier or later than
    # ``interval_s`` before the current one (s); outside it the nearest one still serves
    # (with at least ``min_interval_s``), as a shorter or longer pair.
    interval_tolerance_s: float = 0.08
    tcm_threshold: float = 0.09  # δ above this: moving (paper's mean optimum)
    ecm_threshold_rad: float = 0.05  # Ω above this: moving
    bsm_threshold: float = 100.0  # supra-threshold pixels around the object: moving
    min_theta_rad: float = math.radians(10.0)  # closer to the translation axis: head-on
    # A detection's centre (a blob's, a box's) is no fixed point of a solid object: it may
    # wander by this fraction of the object's angular radius as the view changes (a deep
    # box seen from 2 m follows its near face). Near the translation axis TCM's range
    # ratio amplifies a bearing error by cot θ, so a pair whose δ that wander makes more
    # uncertain than ``max_disparity_sigma`` is "head-on" for its size (0: off;
    # tools/extent_guard_study.py).
    head_on_extent_fraction: float = 0.05
    min_baseline_m: float = 0.0  # autopilot |T| below this: small baseline (0: off)
    min_flow_parallax_rad: float = 0.0  # vision ground parallax below this: small baseline
    # When the vehicle barely moved between the frames (vision parallax below egomotion's
    # minimum, or autopilot |T| below hover_max_baseline_m), a stationary object keeps its
    # bearing and size: decide on δ_hover = hypot(R_img - 1, angle(b0, b1)) instead of
    # reporting "no translation" (method.md's hover extension).
    hover_test: bool = True
    hover_max_baseline_m: float = 0.05
    # Largest 1-σ uncertainty of δ that the translation direction's own uncertainty may
    # cause (see classify_pair); beyond it the pair is "translation too uncertain".
    max_disparity_sigma: float = 0.03
    # A stationary object's range needs this much parallax (the bearing change relative
    # to the translation) to be worth reporting: its error is bearing noise / parallax.
    min_range_parallax_rad: float = math.radians(2.0)
    # Each end of a pair is the size and bearing fitted over this window (s) centred on
    # it (robust lines against time), and the pair ends half a window before the frame:
    # a box detector's per-frame jitter averages down instead of passing into δ
    # (docs/decisions.md §9). 0: the two single observations. None: per backend,
    # FIT_WINDOW_S (0 for colour, whose sizes are sub-pixel; 0.48 s for boxes and onnx).
    fit_window_s: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.interval_s) and self.interval_s > 0):
            raise ValueError(f"interval_s must be > 0, got {self.interval_s}")
        if not all(math.isfinite(k) and k > 0 for k in self.extra_intervals_s):
            raise ValueError(f"extra_intervals_s must all be > 0, got {self.extra_intervals_s}")
        if not (math.isfinite(self.min_interval_s) and self.min_interval_s > 0):
            raise ValueError(f"min_interval_s must be > 0, got {self.min_interval_s}")
        if self.fit_window_s is not None and not (
            math.isfinite(self.fit_window_s) and self.fit_window_s >= 0
        ):
            raise ValueError(f"fit_window_s must be >= 0, got {self.fit_window_s}")
        for name in ("hold_s", "interval_tolerance_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be >= 0, got {value}")

    def fit_window_for(self, backend: str) -> float:
        """The fit window (s) for detections from ``backend``: ``fit_window_s`` when set,
        else the backend's default (:data:`FIT_WINDOW_S`)."""
        if self.fit_window_s is not None:
            return self.fit_window_s
        return FIT_WINDOW_S.get(backend, 0.0)

    @property
    def intervals_s(self) -> tuple[float, ...]:
        """All intervals compared (s), longest first (the primary one included)."""
        return tuple(sorted({self.interval_s, *self.extra_intervals_s}, reverse=True))

    @property
    def longest_interval_s(self) -> float:
        """The longest interval compared (s)."""
        return max(self.intervals_s)

    @property
    def warmup_moving_s(self) -> float:
        """A track this old (s) may be called moving (never later than the interval)."""
        return min(self.min_interval_s, self.interval_s)


@dataclass(frozen=True)
class Classification:
    state: State
    reason: str
    disparity: float = math.nan
    omega_rad: float = math.nan
    bsm_score: float = math.nan
    r_img: float = math.nan
    r_geo: float = math.nan
    theta0_rad: float = math.nan
    theta1_rad: float = math.nan
    interval_frames: int = 0  # frames processed between the two observations (information)
    interval_s: float = math.nan  # capture time between the two observations, s
    # Range to the object at the later frame (m), from the sine rule with the autopilot's
    # metric translation: valid for a stationary object only, NaN otherwise.
    range_m: float = math.nan

    def score(self, method: Method, config: ClassifierConfig) -> float:
        """The method's score normalised by its threshold (> 1 means moving)."""
        if method == "tcm":
            return self.disparity / config.tcm_threshold
        if method == "ecm":
            return self.omega_rad / config.ecm_threshold_rad
        if method == "bsm":
            return self.bsm_score / config.bsm_threshold
        return fused_score(self.disparity, self.omega_rad, config)


def _replaced(c: Classification, **changes: Any) -> Classification:
    """``dataclasses.replace(c, **changes)`` for the classifier's own fields: the same
    object (fields in order, frozen), without ``replace``'s per-field rebuild through
    ``__init__`` (a few per object-frame, ~10 µs each). Classification has no
    ``__post_init__``; ``changes`` must name its fields."""
    new = object.__new__(type(c))
    new.__dict__.update(c.__dict__)
    new.__dict__.update(changes)
    return new


def classify_hover(
    b0_ned: np.ndarray,
    b1_ned: np.ndarray,
    alpha0_rad: float,
    alpha1_rad: float,
    config: ClassifierConfig,
    interval_frames: int,
    interval_s: float = math.nan,
) -> Classification:
    """The hover test: with no translation, any change of bearing or size is motion.

    ``hypot(R_img - 1, angle(b0, b1))`` is the object's displacement over its range, on
    the same scale as the TCM disparity, so the same threshold applies. ECM has no
    meaning without translation; its score stays NaN.
    """
    r_img = math.sin(alpha1_rad) / math.sin(alpha0_rad)
    delta = math.hypot(r_img - 1.0, float(angle_between(b0_ned, b1_ned)))
    c = Classification(
        "unknown",
        "hover",
        disparity=delta,
        r_img=r_img,
        r_geo=1.0,
        interval_frames=interval_frames,
        interval_s=interval_s,
    )
    return decide(c, config) if config.method in ("tcm", "fused") else c


def fused_score(disparity: float, omega_rad: float, config: ClassifierConfig) -> float:
    """TCM+ECM: moving if either test fires (each covers the other's blind spot)."""
    scores = [disparity / config.tcm_threshold, omega_rad / config.ecm_threshold_rad]
    finite = [x for x in scores if math.isfinite(x)]
    return max(finite) if finite else math.nan


def unknown(reason: str, interval_frames: int = 0, interval_s: float = math.nan) -> Classification:
    return Classification("unknown", reason, interval_frames=interval_frames, interval_s=interval_s)


def classify_pair(
    t_hat_ned: np.ndarray,
    b0_ned: np.ndarray,
    b1_ned: np.ndarray,
    alpha0_rad: float,
    alpha1_rad: float,
    config: ClassifierConfig,
    interval_frames: int,
    bsm_score: float = math.nan,
    t_sigma_rad: float = 0.0,
    interval_s: float = math.nan,
) -> Classification:
    """Decide from one pair of observations and the translation between them.

    ``t_sigma_rad`` is the 1-σ uncertainty of ``t_hat_ned``. An in-plane error η of the
    direction moves ``ln R_geo`` by ``η sin(θ1 - θ0) / (sin θ0 sin θ1)`` (method.md), so
    a poor direction matters little when the object's bearing barely changed relative to
    it; the pair is refused only when the resulting uncertainty of δ is too large.
    """
    geo = triangle_geometry(t_hat_ned, b0_ned, b1_ned, alpha0_rad, alpha1_rad)
    th0, th1 = float(geo.theta0_rad), float(geo.theta1_rad)
    measured = Classification(
        "unknown",
        "",
        disparity=float(geo.disparity),
        omega_rad=float(ecm_omega_rad(t_hat_ned, b0_ned, b1_ned)),
        bsm_score=bsm_score,
        r_img=float(geo.r_img),
        r_geo=float(geo.r_geo),
        theta0_rad=th0,
        theta1_rad=th1,
        interval_frames=interval_frames,
        interval_s=interval_s,
    )
    lo, hi = config.min_theta_rad, math.pi - config.min_theta_rad
    if config.method != "bsm" and not (lo <= th0 <= hi and lo <= th1 <= hi):
        return _replaced(measured, reason="head-on")
    if config.method != "bsm" and config.head_on_extent_fraction > 0:
        sigma_extent = extent_disparity_sigma(
            float(geo.r_geo), th0, th1, alpha0_rad, alpha1_rad, config.head_on_extent_fraction
        )
        if sigma_extent > config.max_disparity_sigma:  # NaN: decided below
            return _replaced(measured, reason="head-on")
    if config.method in ("tcm", "fused") and t_sigma_rad > 0:
        sigma_delta = abs(float(geo.r_geo)) * t_sigma_rad * abs(math.sin(th1 - th0))
        sigma_delta /= math.sin(th0) * math.sin(th1)
        if not sigma_delta <= config.max_disparity_sigma:
            return _replaced(measured, reason="translation too uncertain")
    score = measured.score(config.method, config)
    if not math.isfinite(score):
        return _replaced(measured, reason="degenerate geometry")
    return _replaced(measured, state="moving" if score > 1.0 else "stationary")


def extent_disparity_sigma(
    r_geo: float,
    theta0_rad: float,
    theta1_rad: float,
    alpha0_rad: float,
    alpha1_rad: float,
    fraction: float,
) -> float:
    """1-σ uncertainty of δ when each end's bearing may be ``fraction`` of the object's
    angular radius ``alpha_rad`` off the point it should track: ``R_geo = sin θ1 / sin θ0``
    moves by ``R_geo cot θ`` per radian of either θ, so ``|R_geo| · fraction ·
    √((α0 cot θ0)² + (α1 cot θ1)²)``. Small across the track, large near its axis for an
    object that looks big (NaN for θ at 0 or π)."""
    t0, t1 = math.tan(theta0_rad), math.tan(theta1_rad)
    if t0 == 0 or t1 == 0:
        return math.nan
    return abs(r_geo) * fraction * math.hypot(alpha0_rad / t0, alpha1_rad / t1)


def combine_pairs(pairs: list[Classification]) -> Classification:
    """Several decided pairs of one track in one frame → one: each score's maximum.

    The geometry fields (ratios, angles, interval) are those of the pair with the
    largest disparity; the BSM score is the one pair that computed it.
    """
    top = max(pairs, key=lambda c: c.disparity if math.isfinite(c.disparity) else -math.inf)
    return _replaced(
        top,
        disparity=_peak([c.disparity for c in pairs]),
        omega_rad=_peak([c.omega_rad for c in pairs]),
        bsm_score=_peak([c.bsm_score for c in pairs]),
    )


def _peak(values: list[float]) -> float:
    """Largest finite value, NaN if none."""
    finite = [v for v in values if math.isfinite(v)]
    return max(finite) if finite else math.nan


def hold(current: Classification, recent: list[Classification]) -> Classification:
    """``current`` with each score replaced by its maximum over ``recent`` (current included)."""

    def peak(values: list[float]) -> float:
        finite = [v for v in values if math.isfinite(v)]
        return max(finite) if finite else math.nan

    return _replaced(
        current,
        disparity=peak([c.disparity for c in recent]),
        omega_rad=peak([c.omega_rad for c in recent]),
        bsm_score=peak([c.bsm_score for c in recent]),
    )


def decide(c: Classification, config: ClassifierConfig) -> Classification:
    """Set the state from the configured method's score."""
    score = c.score(config.method, config)
    if not math.isfinite(score):
        return _replaced(c, state="unknown", reason="degenerate geometry")
    return _replaced(c, state="moving" if score > 1.0 else "stationary", reason="")
