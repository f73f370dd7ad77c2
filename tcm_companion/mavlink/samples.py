"""Decoded MAVLink telemetry messages → the core's sample types: the one rule for which
messages are usable, shared by the live endpoint and every replay.

:func:`parse_telemetry` is that rule. The companion's endpoint
(:class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint`) turns a :class:`Rejected`
into its ``TelemetryRejected`` event; the ``.tlog`` and scenario readers, the simulated
camera and the exporters call :func:`sample_from_message`, which drops it. So a message
the daemon refused in flight is refused by replay too, and the other way round.

Usable means:

- ``ATTITUDE``: roll, pitch and yaw finite and within ±2π (ArduPilot sends ±π);
- ``ATTITUDE_QUATERNION``: a finite quaternion within 10 % of unit length (it is then
  normalised);
- ``LOCAL_POSITION_NED``: position and velocity finite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..core.telemetry import AttitudeSample, PositionSample, TelemetrySample

#: Message types the core consumes.
TELEMETRY_TYPES = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED"})

#: Largest attitude angle taken (rad); anything wider is not an attitude.
MAX_ANGLE_RAD = 2.0 * math.pi
#: Largest departure of a quaternion's norm from 1 that is still a rotation.
MAX_QUATERNION_NORM_ERROR = 0.1


@dataclass(frozen=True)
class Rejected:
    """A telemetry message that is no usable sample (NaN, out of range, not a rotation)."""

    kind: Literal["attitude", "position"]
    reason: str


def parse_telemetry(msg: Any, recv_us: int) -> TelemetrySample | Rejected | None:
    """The sample of a telemetry message, why it is unusable, or None for messages that
    are not telemetry (see the module docstring for the rule)."""
    kind = msg.get_type()
    if kind not in TELEMETRY_TYPES:
        return None
    boot_us = int(msg.time_boot_ms) * 1000
    recv_us = int(recv_us)
    if kind == "ATTITUDE":
        angles = (float(msg.roll), float(msg.pitch), float(msg.yaw))
        if not all(math.isfinite(a) and abs(a) <= MAX_ANGLE_RAD for a in angles):
            return Rejected("attitude", "ATTITUDE out of range")
        return AttitudeSample.from_euler(boot_us, recv_us, *angles)
    if kind == "ATTITUDE_QUATERNION":
        q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
        norm = float(np.linalg.norm(q))
        if not math.isfinite(norm) or abs(norm - 1.0) > MAX_QUATERNION_NORM_ERROR:
            return Rejected("attitude", "quaternion not unit")
        return AttitudeSample.from_quaternion(boot_us, recv_us, q)
    pos = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
    vel = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
        return Rejected("position", "LOCAL_POSITION_NED not finite")
    return PositionSample(boot_us, recv_us, pos, vel)


def sample_from_message(msg: Any, recv_us: int) -> TelemetrySample | None:
    """Core sample of a pymavlink message; None for messages the core does not use and
    for unusable ones (:func:`parse_telemetry` says which and why)."""
    parsed = parse_telemetry(msg, recv_us)
    return None if isinstance(parsed, Rejected) else parsed
