"""Turn decoded MAVLink telemetry messages into the core's sample types."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.telemetry import AttitudeSample, PositionSample, TelemetrySample

#: Message types the core consumes.
TELEMETRY_TYPES = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED"})


def sample_from_message(msg: Any, recv_us: int) -> TelemetrySample | None:
    """Core sample of a pymavlink message, or None for messages the core does not use."""
    kind = msg.get_type()
    if kind == "ATTITUDE":
        return AttitudeSample.from_euler(
            int(msg.time_boot_ms) * 1000,
            int(recv_us),
            float(msg.roll),
            float(msg.pitch),
            float(msg.yaw),
        )
    if kind == "ATTITUDE_QUATERNION":
        q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
        norm = float(np.linalg.norm(q))
        if not np.isfinite(norm) or norm < 1e-6:
            q = np.full(4, np.nan)
        return AttitudeSample.from_quaternion(int(msg.time_boot_ms) * 1000, int(recv_us), q)
    if kind == "LOCAL_POSITION_NED":
        return PositionSample(
            int(msg.time_boot_ms) * 1000,
            int(recv_us),
            np.array([msg.x, msg.y, msg.z], dtype=np.float64),
            np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64),
        )
    return None
