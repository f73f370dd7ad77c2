"""The mock autopilot's checks of the companion's messages (against tcm.xml), pure functions.

Every TCM_OBJECT_STATUS and TCM_PIPELINE_HEALTH is judged: its ``time_boot_ms`` against
the mock's own boot clock ("stale" when older than ``status_max_age_ms``, "future" when
more than ``status_max_lead_ms`` ahead), enums, finite angles within range, NaN only
where the dialect allows it. A problem is a short text: its first word (``stale``,
``future``, ``bad``) is what the mock counts.

:func:`collision_alarm` is the built-in brake rule's trigger.
"""

from __future__ import annotations

import math
from typing import Any

from ...mavlink import tcm_dialect as mav

STATUS_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS, mav.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH}
)
ANGLE_SLACK_RAD = 1e-4  # float32 rounding of ±π, ±π/2 on the wire


def _enum_values(name: str) -> frozenset[int]:
    """The values of a dialect enum, without pymavlink's added ``*_ENUM_END`` entry."""
    return frozenset(v for v, e in mav.enums[name].items() if not e.name.endswith("_ENUM_END"))


_STATES = _enum_values("TCM_OBJECT_STATE")
_REASONS = _enum_values("TCM_UNKNOWN_REASON")
_EGOMOTION_SOURCES = _enum_values("TCM_EGOMOTION_SOURCE")
_LOG_STATES = _enum_values("TCM_LOG_STATE")
_HEALTH_BITS = 0
for _bit in _enum_values("TCM_HEALTH_FLAGS"):
    _HEALTH_BITS |= _bit


def check_status(msg: Any, boot_ms: int, max_age_ms: int, max_lead_ms: int) -> tuple[str, ...]:
    """Every problem of a TCM_OBJECT_STATUS or TCM_PIPELINE_HEALTH received at the mock's
    boot time ``boot_ms``; empty when it is fine."""
    problems = check_time(int(msg.time_boot_ms), boot_ms, max_age_ms, max_lead_ms)
    if msg.get_msgId() == mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS:
        return problems + check_object_status(msg)
    return problems + check_pipeline_health(msg)


def check_time(
    time_boot_ms: int, boot_ms: int, max_age_ms: int, max_lead_ms: int
) -> tuple[str, ...]:
    age = boot_ms - time_boot_ms
    if age > max_age_ms:
        return ("stale",)
    if -age > max_lead_ms:
        return ("future",)
    return ()


def _finite_in(x: float, lo: float, hi: float) -> bool:
    return math.isfinite(x) and lo <= x <= hi


def _nan_or_at_least(x: float, lo: float, strict: bool = False) -> bool:
    """NaN (the dialect's "none"), or finite and >= ``lo`` (> when ``strict``)."""
    return math.isnan(x) or (math.isfinite(x) and (x > lo if strict else x >= lo))


def check_object_status(msg: Any) -> tuple[str, ...]:
    bad: list[str] = []
    state, reason = int(msg.state), int(msg.reason)
    if state not in _STATES:
        bad.append("bad state")
    if reason not in _REASONS:
        bad.append("bad reason")
    elif (state == mav.TCM_OBJECT_STATE_UNKNOWN) != (reason != mav.TCM_UNKNOWN_REASON_NONE):
        bad.append("bad reason (does not match state)")
    slack = ANGLE_SLACK_RAD
    if not _finite_in(float(msg.azimuth), -math.pi - slack, math.pi + slack):
        bad.append("bad azimuth")
    if not _finite_in(float(msg.elevation), -math.pi / 2 - slack, math.pi / 2 + slack):
        bad.append("bad elevation")
    if not _finite_in(float(msg.angular_radius), 0.0, math.pi + slack):
        bad.append("bad angular_radius")
    if not _finite_in(float(msg.threshold), 0.0, math.inf):
        bad.append("bad threshold")
    if not _nan_or_at_least(float(msg.disparity), 0.0):
        bad.append("bad disparity")
    if not _nan_or_at_least(float(msg.ttc), 0.0):
        bad.append("bad ttc")  # "NaN when not approaching": never inf or negative
    if not _nan_or_at_least(float(msg.range), 0.0, strict=True):
        bad.append("bad range")
    if int(msg.collision_course) not in (0, 1):
        bad.append("bad collision_course")
    if int(msg.confidence) > 100:
        bad.append("bad confidence")
    return tuple(bad)


def check_pipeline_health(msg: Any) -> tuple[str, ...]:
    bad: list[str] = []
    if not _finite_in(float(msg.frame_rate), 0.0, math.inf):
        bad.append("bad frame_rate")
    if not _finite_in(float(msg.latency), 0.0, math.inf):
        bad.append("bad latency")
    if int(msg.egomotion_source) not in _EGOMOTION_SOURCES:
        bad.append("bad egomotion_source")
    if int(msg.egomotion_quality) > 100:
        bad.append("bad egomotion_quality")
    if int(msg.health) & ~_HEALTH_BITS:
        bad.append("bad health")
    if int(msg.log_state) not in _LOG_STATES:
        bad.append("bad log_state")
    return tuple(bad)


def collision_alarm(msg: Any, brake_ttc_s: float) -> bool:
    """A TCM_OBJECT_STATUS that says collision course with a finite ``ttc`` below
    ``brake_ttc_s`` (whether it can be trusted is :func:`check_status`'s question)."""
    ttc = float(msg.ttc)
    return int(msg.collision_course) == 1 and math.isfinite(ttc) and ttc < brake_ttc_s
