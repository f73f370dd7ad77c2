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
class AutopilotConflict:
    """Two senders use the followed autopilot's (system, component) id (``active``), or
    the conflict ended (not ``active``): :class:`~.peers.SenderGuard`."""

    system_id: int
    component_id: int
    active: bool


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
class TrackingImageStatus:
    """A CAMERA_TRACKING_IMAGE_STATUS (id 275) from a tracking camera: what it tracks, as
    MAVLink gives it (normalised image coordinates 0..1, x right, y down; NaN unknown).
    It carries no time: ``recv_us`` is when it arrived (companion monotonic µs)."""

    source: tuple[int, int]  # (system, component) that sent it
    tracking_status: int  # CAMERA_TRACKING_STATUS_FLAGS
    tracking_mode: int  # CAMERA_TRACKING_MODE
    target_data: int  # CAMERA_TRACKING_TARGET_DATA
    rec_top_x: float
    rec_top_y: float
    rec_bottom_x: float
    rec_bottom_y: float
    camera_device_id: int
    recv_us: int


@dataclass(frozen=True)
class GlobalOrigin:
    lat_deg: float
    lon_deg: float
    alt_m: float


Event = (
    AutopilotFound
    | AutopilotLost
    | AutopilotRebooted
    | AutopilotConflict
    | TelemetryReceived
    | TelemetryRejected
    | ParamChanged
    | CommandReceived
    | GlobalOrigin
    | TrackingImageStatus
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
