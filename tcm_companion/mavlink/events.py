"""What the companion endpoint reports to its caller (:meth:`CompanionEndpoint.receive_data`
and :meth:`CompanionEndpoint.poll` return them), and what the caller tells it about the
pipeline (:class:`HealthReport`). Plain frozen data; :mod:`.endpoint` re-exports all of it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.telemetry import TelemetrySample
from . import tcm_dialect as d


@dataclass(frozen=True)
class AutopilotFound:
    system_id: int
    component_id: int
    autopilot: int  # MAV_AUTOPILOT
    vehicle_type: int  # MAV_TYPE


@dataclass(frozen=True)
class AutopilotLost:
    silent_us: int


@dataclass(frozen=True)
class AutopilotRebooted:
    pass


@dataclass(frozen=True)
class TelemetryReceived:
    sample: TelemetrySample


@dataclass(frozen=True)
class TelemetryRejected:
    """A telemetry message arrived on time but could not be used (NaN, not a rotation)."""

    kind: str  # "attitude" or "position"
    reason: str


@dataclass(frozen=True)
class ParamChanged:
    name: str
    value: float


@dataclass(frozen=True)
class CommandReceived:
    command: int
    params: tuple[float, ...]
    source: tuple[int, int]
    result: int  # the MAV_RESULT we answered


@dataclass(frozen=True)
class GlobalOrigin:
    lat_deg: float
    lon_deg: float
    alt_m: float


Event = (
    AutopilotFound
    | AutopilotLost
    | AutopilotRebooted
    | TelemetryReceived
    | TelemetryRejected
    | ParamChanged
    | CommandReceived
    | GlobalOrigin
)


@dataclass(frozen=True)
class HealthReport:
    """What the daemon knows about the pipeline, for TCM_PIPELINE_HEALTH."""

    frame_rate_hz: float = 0.0
    latency_ms: float = 0.0
    frames_dropped: int = 0
    egomotion_source: int = d.TCM_EGOMOTION_SOURCE_NONE
    egomotion_quality_pct: int = 0
    health_flags: int = 0
    objects: int = 0
    log_state: int = d.TCM_LOG_STATE_OFF
