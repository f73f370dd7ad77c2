"""The mock autopilot's configuration, its clock, and what it records and reports.

Shared by its parts (:mod:`.mock_firmware`, :mod:`.mock_vehicle`, :mod:`.mock_checks`)
and re-exported by :mod:`.mock_autopilot`, which composes them.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from ..scene.scenarios import SCENARIO_NAMES
from .telemetry import TelemetryConfig


@dataclass(frozen=True)
class MockAutopilotConfig:
    """How the mock vehicle identifies itself, flies and judges what it receives."""

    system_id: int = 1
    component_id: int = 1
    scenario: str = "T90"  # one of SCENARIO_NAMES
    seed: int = 0  # turbulence of the flight and telemetry noise
    noise: float = 1.0  # scales the telemetry noise levels of ``telemetry``; 0 = exact
    telemetry: TelemetryConfig = field(default_factory=TelemetryConfig)
    scenario_time_offset_s: float = 0.0  # scenario time at start_us
    boot_offset_us: int = 0  # how long the autopilot had been up at start_us
    heartbeat_delay_us: int = 1_000_000  # first heartbeat after boot
    ekf_origin_delay_us: int = 3_000_000  # boot time until LOCAL_POSITION_NED exists
    timesync_period_us: int = 10_000_000  # own TIMESYNC requests; 0 = never
    unix_us_at_start: int | None = None  # SYSTEM_TIME's clock; None: 2024-06-10
    brake_on_collision: bool = True
    brake_ttc_s: float = 3.0  # brake on a collision-course status with ttc below this
    brake_decel_mps2: float = 3.0  # peak deceleration of the brake manoeuvre
    status_max_age_ms: int = 1000  # an older time_boot_ms is "stale"
    status_max_lead_ms: int = 50  # a time_boot_ms this far ahead of ours is "future"
    proximity_timeout_us: int = 500_000  # AP_Proximity_MAV's PROXIMITY_MAV_TIMEOUT_MS
    prx_type: int = 2  # PRX1_TYPE at first boot: 2 = MAVLink proximity (docs/autopilots.md)
    max_records: int = 100_000  # per received-message log; the oldest go first
    max_tx_bytes: int = 256 * 1024  # outgoing buffer; further messages are dropped

    def __post_init__(self) -> None:
        for name in ("system_id", "component_id"):
            if not 1 <= getattr(self, name) <= 255:
                raise ValueError(f"{name} must be in 1..255, got {getattr(self, name)!r}")
        if self.scenario.upper() not in SCENARIO_NAMES:
            raise ValueError(
                f"unknown scenario {self.scenario!r}; choose one of {', '.join(SCENARIO_NAMES)}"
            )
        if not self.noise >= 0:
            raise ValueError(f"noise must be >= 0, got {self.noise!r}")
        if not self.brake_decel_mps2 > 0:
            raise ValueError(f"brake_decel_mps2 must be > 0, got {self.brake_decel_mps2!r}")
        for name in (
            "boot_offset_us",
            "heartbeat_delay_us",
            "ekf_origin_delay_us",
            "timesync_period_us",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")
        if self.max_records < 1 or self.max_tx_bytes < 300:
            raise ValueError("max_records must be >= 1 and max_tx_bytes >= 300 (one frame)")


class MockClock:
    """The caller's time as the mock has seen it (µs): it never goes backwards; a step
    back or a value that is no time is counted in ``stats`` and not used."""

    def __init__(self, start_us: int, stats: Counter[str]) -> None:
        self.start_us = int(start_us)
        self.now_us = self.start_us  # the latest time seen
        self.stats = stats

    def advance(self, now_us: int) -> int:
        """Move to ``now_us`` if it is later; returns the time to act at."""
        try:
            now = int(now_us)
        except (TypeError, ValueError, OverflowError):
            self.stats["bad time"] += 1
            return self.now_us
        if now < self.now_us:
            self.stats["time went backwards"] += 1
            return self.now_us
        self.now_us = now
        return now


# --------------------------------------------------------------------------------------
# Records and events
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReceivedStatus:
    """One TCM_OBJECT_STATUS or TCM_PIPELINE_HEALTH as the mock received and judged it."""

    recv_us: int  # caller's clock at receipt
    boot_ms: int  # the mock's boot clock at receipt
    src_system: int
    src_component: int
    msg: Any  # the decoded pymavlink message
    problems: tuple[str, ...]  # "stale", "future", "bad <field>"; empty when fine

    @property
    def name(self) -> str:
        return str(self.msg.get_type())

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def age_ms(self) -> int:
        """The mock's boot time minus the message's ``time_boot_ms`` at receipt."""
        return self.boot_ms - int(self.msg.time_boot_ms)


@dataclass(frozen=True)
class StatusReceived:
    record: ReceivedStatus


@dataclass(frozen=True)
class ObstacleReceived:
    """OBSTACLE_DISTANCE, OBSTACLE_DISTANCE_3D or ADSB_VEHICLE."""

    recv_us: int
    src_system: int
    src_component: int
    msg: Any


@dataclass(frozen=True)
class CommandReceived:
    recv_us: int
    command: int
    result: int  # MAV_RESULT sent back in the COMMAND_ACK
    src_system: int
    src_component: int


@dataclass(frozen=True)
class ParamChanged:
    recv_us: int
    name: str
    value: float


@dataclass(frozen=True)
class PeerSeen:
    """First HEARTBEAT from a (system, component) on the link."""

    recv_us: int
    system: int
    component: int
    mav_type: int


@dataclass(frozen=True)
class BrakeStarted:
    recv_us: int
    track_id: int
    ttc_s: float
    speed_mps: float  # ground-relative speed when the brake began
    hover_at_us: int  # caller's clock when the vehicle is at rest
    hover_ned_m: tuple[float, float, float]


MockEvent = (
    StatusReceived | ObstacleReceived | CommandReceived | ParamChanged | PeerSeen | BrakeStarted
)
