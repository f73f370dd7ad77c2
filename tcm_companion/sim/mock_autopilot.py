"""A mock ArduCopter that flies a simulated scenario and speaks MAVLink: sans-IO core.

The companion's MAVLink endpoint needs a flight controller to talk to in tests and on the
bench. :class:`MockAutopilot` is one, built like h11/aioquic: bytes and time in
(:meth:`~MockAutopilot.receive_data`, :meth:`~MockAutopilot.poll`), events and bytes
out (:meth:`~MockAutopilot.data_to_send`), the next timer from
:meth:`~MockAutopilot.next_deadline_us`. No sockets, no clock: every entry point takes
``now_us`` (any monotonic µs; the caller's clock). The asyncio runner is
:mod:`.mock_autopilot_run`.

It behaves like ArduCopter as observed in ``docs/autopilots.md`` (one link):

- HEARTBEAT at 1 Hz from (1, 1), QUADROTOR / ARDUPILOTMEGA, MAVLink 2, the first
  ~1 s after boot; a short STATUSTEXT banner. Nothing else streams unrequested except
  a TIMESYNC request every 10 s (``tc1 = 0``, ``ts1 = boot ns + sysid``) and the
  one-off STATUSTEXT / GPS_GLOBAL_ORIGIN when the EKF gets its origin.
- MAV_CMD_SET_MESSAGE_INTERVAL (ms resolution, 0 = default, -1 = off, like ArduPilot's
  ``GCS_MAVLINK::set_message_interval``), MAV_CMD_GET_MESSAGE_INTERVAL,
  MAV_CMD_REQUEST_MESSAGE for HEARTBEAT, SYSTEM_TIME, ATTITUDE, ATTITUDE_QUATERNION,
  LOCAL_POSITION_NED (and AUTOPILOT_VERSION, GPS_GLOBAL_ORIGIN on request); FAILED
  for other ids, UNSUPPORTED for unknown commands, FAILED for a reboot while armed
  (always, here: the vehicle is flying).
- LOCAL_POSITION_NED only once the "EKF origin" delay has passed since boot; before,
  attitude is available but position is not, as on a vehicle waiting for GPS.
- TIMESYNC requests answered with ``tc1`` = boot time in ns (µs resolution), ``ts1``
  echoed. PARAM_REQUEST_LIST / _READ / PARAM_SET for a few ArduPilot parameters.

The vehicle flies the scenario's closed-form trajectory (:mod:`.scenarios`) in real time
from ``start_us``, past the scenario's nominal duration (the oscillating scenarios keep
oscillating; COLLISION / HEADON keep flying straight). Attitude comes from the
trajectory's acceleration exactly as the simulator computes it
(:meth:`~.scenarios.VehicleMotion.R_ned_from_body`), plus the simulator's telemetry
noise (:class:`~.telemetry.TelemetryConfig` levels: a constant per-axis bias and white
noise; ``noise`` scales them, 0 gives exact telemetry).

It consumes the companion's messages: every TCM_OBJECT_STATUS and TCM_PIPELINE_HEALTH is
recorded with its receive time and checked (enums, finite angles in range, and
``time_boot_ms`` against the mock's own boot clock: "stale" when too old, "future" when
ahead). A valid, fresh status with ``collision_course = 1`` and a finite ``ttc`` below
``brake_ttc_s`` makes the vehicle brake (when ``brake_on_collision``): it decelerates to
a hover at ``brake_decel_mps2`` peak, switches to BRAKE mode in its HEARTBEAT, says
"brake: collision course track N" and emits :class:`BrakeStarted`. OBSTACLE_DISTANCE,
OBSTACLE_DISTANCE_3D (ardupilotmega) and ADSB_VEHICLE are recorded;
:attr:`MockAutopilot.proximity_healthy` follows ArduPilot's AP_Proximity_MAV (healthy
while OBSTACLE_DISTANCE(_3D) keeps arriving, "No Data" 500 ms after the last one).

Faults never raise: garbage, bad CRC, unknown ids, messages for other systems, time going
backwards, a full transmit buffer are all counted in :attr:`MockAutopilot.stats`.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..core.frames import FloatArray, quat_wxyz_from_rot, rot_from_euler_zyx
from ..mavlink import tcm_dialect as mav
from ..mavlink.codec import MavlinkCodec
from .scenarios import SCENARIO_NAMES, VehicleMotion, euler_zyx_rad, flight_plan
from .telemetry import TelemetryConfig
from .world import Trajectory

__all__ = [
    "BrakeStarted",
    "BrakingPath",
    "CommandReceived",
    "MockAutopilot",
    "MockAutopilotConfig",
    "MockEvent",
    "ObstacleReceived",
    "ParamChanged",
    "PeerSeen",
    "ReceivedStatus",
    "StatusReceived",
    "VehicleTruth",
]

# ArduCopter flight modes (HEARTBEAT.custom_mode).
COPTER_MODE_GUIDED = 4
COPTER_MODE_BRAKE = 17

#: Messages the mock can stream or send on request, with their default interval (µs;
#: 0 = not streamed). ArduPilot's defaults with stream rates at 0: only the heartbeat.
STREAM_DEFAULT_INTERVAL_US: dict[int, int] = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: 1_000_000,
    mav.MAVLINK_MSG_ID_SYSTEM_TIME: 0,
    mav.MAVLINK_MSG_ID_ATTITUDE: 0,
    mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 0,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0,
}
#: Sent once on MAV_CMD_REQUEST_MESSAGE but not streamable.
_REQUEST_ONLY_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION, mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN}
)


_TCM_STATUS_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS, mav.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH}
)
_OBSTACLE_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE, mav.MAVLINK_MSG_ID_OBSTACLE_DISTANCE_3D}
)

# Integer parameter types and their limits (ArduPilot clamps a PARAM_SET to the type).
_INT_LIMITS = {
    mav.MAV_PARAM_TYPE_INT8: (-128, 127),
    mav.MAV_PARAM_TYPE_INT16: (-32768, 32767),
    mav.MAV_PARAM_TYPE_INT32: (-(2**31), 2**31 - 1),
}

_STATUSTEXT_MAX = 50
_BANNER = ("ArduCopter V4.7.0-dev (tcm mock)", "Frame: QUAD/X")
_FIRMWARE_VERSION = (4 << 24) | (7 << 16) | (0 << 8) | 0  # major.minor.patch.type(dev)
_ANGLE_SLACK_RAD = 1e-4  # float32 rounding of ±π, ±π/2 on the wire


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
        if not 1 <= self.system_id <= 255 or not 1 <= self.component_id <= 255:
            raise ValueError("system_id and component_id must be in 1..255")
        if self.scenario.upper() not in SCENARIO_NAMES:
            raise ValueError(
                f"unknown scenario {self.scenario!r}; choose one of {', '.join(SCENARIO_NAMES)}"
            )
        if not (self.noise >= 0 and self.brake_decel_mps2 > 0):
            raise ValueError("noise must be >= 0 and brake_decel_mps2 > 0")
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


@dataclass(frozen=True)
class VehicleTruth:
    """The simulated vehicle's exact state (no telemetry noise)."""

    t_s: float  # scenario time
    position_ned_m: FloatArray
    velocity_ned_mps: FloatArray
    R_ned_from_body: FloatArray


# --------------------------------------------------------------------------------------
# The brake manoeuvre
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BrakingPath(Trajectory):
    """A straight-line stop from ``origin_ned_m`` / ``linear_velocity_ned_mps`` at ``brake_t_s``.

    Velocity falls as ``v0 (1 + cos(π τ / T)) / 2``: the deceleration rises from zero and
    falls back to zero (no attitude step at either end), peaking at ``π |v0| / 2T``;
    ``T = π |v0| / (2 a_peak)`` and the stopping distance is ``|v0| T / 2``. Before
    ``brake_t_s`` the path extends the initial velocity (only the body-rate central
    difference looks there). A :class:`Trajectory`, so :class:`VehicleMotion` derives
    the attitude from its acceleration exactly as for the scenario's own path.
    """

    brake_t_s: float = 0.0
    stop_after_s: float = 0.0  # T

    @staticmethod
    def start(
        position_ned_m: FloatArray, velocity_ned_mps: FloatArray, t_s: float, decel_mps2: float
    ) -> BrakingPath:
        speed = float(np.linalg.norm(velocity_ned_mps))
        return BrakingPath(
            origin_ned_m=_vec3(position_ned_m),
            linear_velocity_ned_mps=_vec3(velocity_ned_mps),
            brake_t_s=float(t_s),
            stop_after_s=math.pi * speed / (2.0 * decel_mps2),
        )

    def _eval(self, t_s: float | FloatArray, order: int) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        tau = (t - self.brake_t_s)[..., None]
        p0 = np.asarray(self.origin_ned_m)
        v0 = np.asarray(self.linear_velocity_ned_mps)
        T = self.stop_after_s
        if T <= 0.0:  # already at rest
            out = p0 + 0.0 * tau if order == 0 else np.zeros((*t.shape, 3))
            return np.asarray(out, dtype=np.float64)
        s = np.clip(tau, 0.0, T)
        w = math.pi / T
        braking = (tau > 0.0) & (tau < T)
        if order == 0:
            moved = s / 2.0 + np.sin(w * s) / (2.0 * w)
            out = np.where(tau < 0.0, tau, moved) * v0 + p0
        elif order == 1:
            factor = np.where(tau < 0.0, 1.0, 0.5 * (1.0 + np.cos(w * s)))
            out = factor * v0
        else:
            out = np.where(braking, -0.5 * w * np.sin(w * s), 0.0) * v0
        return np.asarray(out, dtype=np.float64)


def _vec3(v: FloatArray) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------
@dataclass
class _Param:
    value: float
    mav_type: int


def _initial_params(config: MockAutopilotConfig) -> dict[str, _Param]:
    """A handful of real ArduCopter parameters that matter to a companion."""
    return {
        "SYSID_THISMAV": _Param(float(config.system_id), mav.MAV_PARAM_TYPE_INT16),
        "PRX1_TYPE": _Param(float(config.prx_type), mav.MAV_PARAM_TYPE_INT8),
        "AVD_ENABLE": _Param(0.0, mav.MAV_PARAM_TYPE_INT8),
        "AVOID_ENABLE": _Param(3.0, mav.MAV_PARAM_TYPE_INT8),
        "AVOID_MARGIN": _Param(2.0, mav.MAV_PARAM_TYPE_REAL32),
    }


def _finite(x: float) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


# --------------------------------------------------------------------------------------
# The mock
# --------------------------------------------------------------------------------------
class MockAutopilot:
    """An ArduCopter-like MAVLink vehicle flying a simulated scenario (sans-IO)."""

    def __init__(self, config: MockAutopilotConfig, start_us: int) -> None:
        self.config = config
        self.plan = flight_plan(config.scenario, seed=config.seed)
        self.stats: Counter[str] = Counter()
        self._start_us = int(start_us)
        self._now_us = self._start_us
        self._motion: VehicleMotion = self.plan.vehicle
        self._brake: BrakeStarted | None = None

        rng_seed = np.random.SeedSequence([0x4D4F434B, config.seed])  # "MOCK"
        self._rng = np.random.default_rng(rng_seed)
        tc = config.telemetry
        n = config.noise
        self._att_bias_rad = self._rng.uniform(-1.0, 1.0, 3) * math.radians(
            tc.attitude_bias_max_deg * n
        )
        self._att_sigma_rad = math.radians(tc.attitude_noise_deg * n)
        self._rate_sigma_rps = math.radians(tc.rate_noise_dps * n)
        self._pos_sigma_m = tc.position_noise_m * n
        self._vel_sigma_mps = tc.velocity_noise_mps * n
        self._att_cache: tuple[int, FloatArray, FloatArray] | None = None
        self._unix_us_at_start = (
            config.unix_us_at_start
            if config.unix_us_at_start is not None
            else 1_718_000_000_000_000
        )

        self._params = _initial_params(config)
        self._tx = bytearray()
        self.received_status: deque[ReceivedStatus] = deque(maxlen=config.max_records)
        self.received_obstacles: deque[ObstacleReceived] = deque(maxlen=config.max_records)
        self.received_adsb: deque[ObstacleReceived] = deque(maxlen=config.max_records)
        self.peers: dict[tuple[int, int], int] = {}  # (sysid, compid) -> last heartbeat µs
        self._last_obstacle_us: int | None = None
        self.timesync_rtt_us: int | None = None  # round trip of our last answered request

        self._boot(self._start_us - int(config.boot_offset_us))

    # -- boot / reboot -----------------------------------------------------------------
    def _boot(self, boot_zero_us: int) -> None:
        """(Re)start the firmware: boot clock, link state and streams; the vehicle flies on."""
        cfg = self.config
        self._boot_zero_us = boot_zero_us  # caller's clock when the boot clock read 0
        self.system_id = int(self._params["SYSID_THISMAV"].value)
        self.codec = MavlinkCodec(self.system_id, cfg.component_id)
        self.codec.stats = self.stats  # one Counter for the codec's and the mock's faults
        # SET_MESSAGE_INTERVAL is forgotten on reboot: the companion must ask again.
        self._interval_us = dict(STREAM_DEFAULT_INTERVAL_US)
        self._due_us: dict[int, int] = {
            mav.MAVLINK_MSG_ID_HEARTBEAT: max(boot_zero_us + cfg.heartbeat_delay_us, self._now_us)
        }
        self._banner_sent = False
        self._origin_announced = False
        self._next_timesync_us = (
            max(boot_zero_us, self._now_us) + cfg.timesync_period_us
            if cfg.timesync_period_us > 0
            else None
        )
        self._timesync_ts1: int | None = None

    def reboot(self, now_us: int) -> None:
        """Reboot the firmware: boot clock back to 0, stream rates forgotten, no EKF
        origin, sequence numbers from 0; SYSID_THISMAV changes take effect. The vehicle
        keeps flying (and braking) as before: only the autopilot's software restarts."""
        try:
            now = self._advance(now_us)
            self._tx.clear()  # what the old firmware had queued never went out
            self._att_cache = None
            self._boot(now)
            self.stats["reboots"] += 1
        except Exception:
            self.stats["internal error"] += 1

    # -- clocks --------------------------------------------------------------------------
    def _advance(self, now_us: int) -> int:
        """The caller's time, never going backwards (a backwards step is counted, not used)."""
        try:
            now = int(now_us)
        except (TypeError, ValueError, OverflowError):
            self.stats["bad time"] += 1
            return self._now_us
        if now < self._now_us:
            self.stats["time went backwards"] += 1
            return self._now_us
        self._now_us = now
        return now

    def boot_us(self, now_us: int | None = None) -> int:
        """The autopilot's time since boot (µs) at ``now_us`` (default: the latest time seen)."""
        return (self._now_us if now_us is None else int(now_us)) - self._boot_zero_us

    def scenario_t_s(self, now_us: int | None = None) -> float:
        """Scenario time (s) of the flight at ``now_us`` (default: the latest time seen)."""
        now = self._now_us if now_us is None else int(now_us)
        return (now - self._start_us) / 1e6 + self.config.scenario_time_offset_s

    def _boot_ms(self, now: int) -> int:
        return max(0, self.boot_us(now) // 1000) & 0xFFFFFFFF

    @property
    def ekf_has_origin(self) -> bool:
        return self.boot_us() >= self.config.ekf_origin_delay_us

    @property
    def proximity_healthy(self) -> bool:
        """ArduPilot's proximity status at the latest time seen: PRX1_TYPE = 2 and an
        OBSTACLE_DISTANCE(_3D) within ``proximity_timeout_us``."""
        if int(self._params["PRX1_TYPE"].value) != 2 or self._last_obstacle_us is None:
            return False
        return self._now_us - self._last_obstacle_us <= self.config.proximity_timeout_us

    @property
    def braking(self) -> BrakeStarted | None:
        """The brake in force (latched until the mock is discarded), or None."""
        return self._brake

    @property
    def params(self) -> dict[str, float]:
        return {name: p.value for name, p in self._params.items()}

    @property
    def stream_intervals_us(self) -> dict[int, int]:
        """Message id -> interval (µs) on this link; 0 = not streamed."""
        return dict(self._interval_us)

    def vehicle_truth(self, now_us: int | None = None) -> VehicleTruth:
        t = self.scenario_t_s(now_us)
        m = self._motion
        return VehicleTruth(
            t, m.position_ned_m(t), m.velocity_ned_mps(t), np.asarray(m.R_ned_from_body(t))
        )

    # -- output --------------------------------------------------------------------------
    def data_to_send(self) -> bytes:
        """Drain the bytes queued for the link."""
        out = bytes(self._tx)
        self._tx.clear()
        return out

    def _send(self, msg: Any) -> None:
        try:
            frame = self.codec.encode(msg, self._now_us)
        except Exception:  # a value out of the field's range: a bug here, not the peer's
            self.stats["encode error"] += 1
            return
        if len(self._tx) + len(frame) > self.config.max_tx_bytes:
            # Like a full UART buffer: ArduPilot drops the message rather than block.
            self.stats["tx overflow"] += 1
            return
        self._tx.extend(frame)

    def _statustext(self, severity: int, text: str) -> None:
        self._send(self.codec.mav.statustext_encode(severity, text[:_STATUSTEXT_MAX].encode()))

    # -- timers ----------------------------------------------------------------------------
    def next_deadline_us(self) -> int:
        """When :meth:`poll` next has something to do (caller's clock, µs); never before
        the latest time seen, so something overdue reads as "now"."""
        cands = [due for mid, due in self._due_us.items() if self._interval_us.get(mid, 0) > 0]
        if self._next_timesync_us is not None:
            cands.append(self._next_timesync_us)
        if not self._origin_announced:
            cands.append(self._boot_zero_us + self.config.ekf_origin_delay_us)
        # Nothing scheduled (every stream turned off): still wake now and then.
        return max(min(cands), self._now_us) if cands else self._now_us + 1_000_000

    def poll(self, now_us: int) -> None:
        """Advance to ``now_us`` and queue every message that has come due."""
        try:
            now = self._advance(now_us)
            self._poll(now)
        except Exception:
            self.stats["internal error"] += 1

    def _poll(self, now: int) -> None:
        for mid, interval in self._interval_us.items():
            if interval <= 0:
                continue
            due = self._due_us.get(mid, now)
            if now < due:
                continue
            self._send_message(mid, now)
            # Absolute deadlines so the rate does not drift; skip, don't burst, when late.
            due += interval
            self._due_us[mid] = due if due > now else now + interval
        # After the streams, so that a peer hears the heartbeat before anything else.
        if not self._origin_announced and self.boot_us(now) >= self.config.ekf_origin_delay_us:
            self._origin_announced = True
            self._statustext(mav.MAV_SEVERITY_INFO, "EKF3 IMU0 origin set")
            self._send_message(mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, now)
        if self._next_timesync_us is not None and now >= self._next_timesync_us:
            boot_ns = self.boot_us(now) * 1000
            self._timesync_ts1 = boot_ns + self.system_id
            self._send(self.codec.mav.timesync_encode(0, self._timesync_ts1))
            self._next_timesync_us += self.config.timesync_period_us
            if self._next_timesync_us <= now:
                self._next_timesync_us = now + self.config.timesync_period_us

    # -- messages the mock sends ---------------------------------------------------------
    def _send_message(self, mid: int, now: int) -> bool:
        """Queue one message of id ``mid``; False when it cannot be sent (yet)."""
        m = self.codec.mav
        boot_ms = self._boot_ms(now)
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            self._send_heartbeat()
        elif mid == mav.MAVLINK_MSG_ID_SYSTEM_TIME:
            # ArduPilot has no Unix time until GPS: 0 before the EKF origin.
            unix = self._unix_us_at_start + (now - self._start_us) if self.ekf_has_origin else 0
            self._send(m.system_time_encode(max(0, unix), boot_ms))
        elif mid in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            eul, rates = self._noisy_attitude(now)
            roll, pitch, yaw = (float(x) for x in eul)
            p, q, r = (float(x) for x in rates)
            if mid == mav.MAVLINK_MSG_ID_ATTITUDE:
                self._send(m.attitude_encode(boot_ms, roll, pitch, yaw, p, q, r))
            else:
                w, x, y, z = (
                    float(c) for c in quat_wxyz_from_rot(rot_from_euler_zyx(roll, pitch, yaw))
                )
                self._send(m.attitude_quaternion_encode(boot_ms, w, x, y, z, p, q, r))
        elif mid == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            if not self.ekf_has_origin:
                self.stats["position withheld (no EKF origin)"] += 1
                return False
            t = self.scenario_t_s(now)
            pos = self._motion.position_ned_m(t) + self._rng.normal(0.0, self._pos_sigma_m, 3)
            vel = self._motion.velocity_ned_mps(t) + self._rng.normal(0.0, self._vel_sigma_mps, 3)
            self._send(m.local_position_ned_encode(boot_ms, *map(float, pos), *map(float, vel)))
        elif mid == mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            if not self.ekf_has_origin:
                return False
            tc = self.config.telemetry
            self._send(
                m.gps_global_origin_encode(
                    round(tc.origin_lat_deg * 1e7),
                    round(tc.origin_lon_deg * 1e7),
                    round(tc.origin_alt_m * 1000.0),
                    max(0, self.boot_us(now)),
                )
            )
        elif mid == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = (
                mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            )
            zeros8 = [0] * 8
            self._send(
                m.autopilot_version_encode(
                    caps, _FIRMWARE_VERSION, 0, 0, 0, zeros8, zeros8, zeros8, 0, 0, 0
                )
            )
        else:
            return False
        return True

    def _send_heartbeat(self) -> None:
        if not self._banner_sent:
            # ArduPilot greets a new link with its version banner around the first heartbeat.
            self._banner_sent = True
            for line in _BANNER:
                self._statustext(mav.MAV_SEVERITY_INFO, line)
        mode = COPTER_MODE_BRAKE if self._brake is not None else COPTER_MODE_GUIDED
        self._send(
            self.codec.mav.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR,
                mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mav.MAV_MODE_FLAG_SAFETY_ARMED
                | mav.MAV_MODE_FLAG_GUIDED_ENABLED
                | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
                | mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                mode,
                mav.MAV_STATE_ACTIVE,
            )
        )

    def _noisy_attitude(self, now: int) -> tuple[FloatArray, FloatArray]:
        """``(roll, pitch, yaw)`` and ``(p, q, r)`` with the simulator's noise, once per
        instant so ATTITUDE and ATTITUDE_QUATERNION sent together agree."""
        if self._att_cache is not None and self._att_cache[0] == now:
            return self._att_cache[1], self._att_cache[2]
        t = self.scenario_t_s(now)
        eul = euler_zyx_rad(self._motion.R_ned_from_body(t))
        eul = eul + self._att_bias_rad + self._rng.normal(0.0, self._att_sigma_rad, 3)
        eul[2] = math.remainder(float(eul[2]), 2.0 * math.pi)  # yaw in [-π, π]
        rates = self._motion.body_rates_rps(t) + self._rng.normal(0.0, self._rate_sigma_rps, 3)
        self._att_cache = (now, eul, rates)
        return eul, rates

    # -- input -----------------------------------------------------------------------------
    def receive_data(self, data: bytes, now_us: int) -> list[MockEvent]:
        """Take bytes from the link; return what happened. Never raises."""
        events: list[MockEvent] = []
        try:
            now = self._advance(now_us)
            if not isinstance(data, bytes | bytearray | memoryview):
                self.stats["bad input"] += 1
                return events
            msgs = self.codec.feed(bytes(data))
        except Exception:
            self.stats["internal error"] += 1
            return events
        for msg in msgs:
            try:
                self._handle(msg, now, events)
            except Exception:  # a hostile value we did not foresee: count, carry on
                self.stats["handler error"] += 1
        return events

    def _handle(self, msg: Any, now: int, events: list[MockEvent]) -> None:
        src = (int(msg.get_srcSystem()), int(msg.get_srcComponent()))
        if src == (self.system_id, self.config.component_id):
            self.stats["own echo ignored"] += 1  # a looped-back link
            return
        mid = int(msg.get_msgId())
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if src not in self.peers:
                events.append(PeerSeen(now, src[0], src[1], int(msg.type)))
            self.peers[src] = now
        elif mid == mav.MAVLINK_MSG_ID_TIMESYNC:
            self._handle_timesync(msg, now)
        elif mid in (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT):
            self._handle_command(msg, src, now, events)
        elif mid in (
            mav.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
            mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
            mav.MAVLINK_MSG_ID_PARAM_SET,
        ):
            self._handle_param(msg, mid, now, events)
        elif mid in _TCM_STATUS_IDS:
            self._handle_status(msg, src, now, events)
        elif mid in _OBSTACLE_IDS:
            if src[0] != self.system_id:  # proximity data comes from our own companion
                self.stats["other system ignored"] += 1
                return
            self._last_obstacle_us = now
            rec = ObstacleReceived(now, src[0], src[1], msg)
            self.received_obstacles.append(rec)
            events.append(rec)
        elif mid == mav.MAVLINK_MSG_ID_ADSB_VEHICLE:
            # AP_ADSB takes traffic from any system (a GCS may relay it).
            rec = ObstacleReceived(now, src[0], src[1], msg)
            self.received_adsb.append(rec)
            events.append(rec)
        else:
            self.stats["ignored " + str(msg.get_type())] += 1

    def _for_us(self, target_system: int, target_component: int) -> bool:
        ok = target_system in (0, self.system_id) and target_component in (
            0,
            self.config.component_id,
        )
        if not ok:
            self.stats["not for us"] += 1
        return ok

    # -- TIMESYNC ------------------------------------------------------------------------
    def _handle_timesync(self, msg: Any, now: int) -> None:
        tc1, ts1 = int(msg.tc1), int(msg.ts1)
        boot_ns = self.boot_us(now) * 1000  # µs resolution, like ArduPilot
        if tc1 == 0:
            # tc1 = 0 would read as a request; a real autopilot is never at boot time 0.
            self._send(self.codec.mav.timesync_encode(max(boot_ns, 1000), ts1))
            self.stats["timesync answered"] += 1
        elif self._timesync_ts1 is not None and ts1 == self._timesync_ts1:
            # No target fields in TIMESYNC: a reply is recognised by its ts1.
            self.timesync_rtt_us = (boot_ns - (ts1 - self.system_id)) // 1000
            self.stats["timesync reply"] += 1
        else:
            self.stats["timesync ignored"] += 1

    # -- commands ------------------------------------------------------------------------
    def _handle_command(
        self, msg: Any, src: tuple[int, int], now: int, events: list[MockEvent]
    ) -> None:
        if not self._for_us(int(msg.target_system), int(msg.target_component)):
            return
        cmd = int(msg.command)
        p1, p2 = float(msg.param1), float(msg.param2)
        follow_up: int | None = None  # message to send after the ACK
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_message_interval(p1, p2, now)
        elif cmd == mav.MAV_CMD_GET_MESSAGE_INTERVAL:
            result = self._get_message_interval(p1)
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            mid = int(p1) if _finite(p1) else -1
            if mid in STREAM_DEFAULT_INTERVAL_US or mid in _REQUEST_ONLY_IDS:
                result, follow_up = mav.MAV_RESULT_ACCEPTED, mid
            else:
                result = mav.MAV_RESULT_FAILED
        elif cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            result, follow_up = mav.MAV_RESULT_ACCEPTED, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        elif cmd == mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            result = mav.MAV_RESULT_FAILED  # ArduPilot refuses while armed; we always fly
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
        self._send(self.codec.mav.command_ack_encode(cmd, result, 0, 0, src[0], src[1]))
        self.stats[f"command {cmd} result {result}"] += 1
        events.append(CommandReceived(now, cmd, result, src[0], src[1]))
        if follow_up is not None:
            # Like ArduPilot, the ACK goes first; a message that cannot exist yet
            # (LOCAL_POSITION_NED before the EKF origin) is simply not sent.
            self._send_message(follow_up, now)

    def _set_message_interval(self, p1: float, p2: float, now: int) -> int:
        if not (_finite(p1) and _finite(p2)):
            return mav.MAV_RESULT_FAILED
        mid, interval_us = int(p1), int(p2)
        if mid not in STREAM_DEFAULT_INTERVAL_US:
            return mav.MAV_RESULT_FAILED
        # ArduPilot keeps intervals in whole ms, at least 1 ms, at most 60 s.
        if interval_us == 0:
            interval = STREAM_DEFAULT_INTERVAL_US[mid]
        elif interval_us < 0:
            interval = 0  # -1 disables; ArduPilot treats other negatives as "1 ms"
            if interval_us != -1:
                interval = 1000
        elif interval_us < 1000:
            interval = 1000
        else:
            interval = min(interval_us, 60_000_000) // 1000 * 1000
        self._interval_us[mid] = interval
        if interval > 0:
            self._due_us[mid] = now  # first one at the next poll
        return mav.MAV_RESULT_ACCEPTED

    def _get_message_interval(self, p1: float) -> int:
        mid = int(p1) if _finite(p1) else -1
        if mid not in STREAM_DEFAULT_INTERVAL_US:
            if 0 <= mid < 1 << 16:
                self._send(self.codec.mav.message_interval_encode(mid, 0))  # not available
            return mav.MAV_RESULT_FAILED
        interval = self._interval_us[mid]
        self._send(self.codec.mav.message_interval_encode(mid, interval if interval > 0 else -1))
        return mav.MAV_RESULT_ACCEPTED

    # -- parameters ----------------------------------------------------------------------
    def _param_value(self, name: str) -> None:
        names = list(self._params)
        p = self._params[name]
        self._send(
            self.codec.mav.param_value_encode(
                name.encode(), p.value, p.mav_type, len(names), names.index(name)
            )
        )

    def _handle_param(self, msg: Any, mid: int, now: int, events: list[MockEvent]) -> None:
        if not self._for_us(int(msg.target_system), int(msg.target_component)):
            return
        names = list(self._params)
        if mid == mav.MAVLINK_MSG_ID_PARAM_REQUEST_LIST:
            for name in names:
                self._param_value(name)
            return
        if mid == mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ:
            index = int(msg.param_index)
            if index >= 0:
                name = names[index] if index < len(names) else ""
            else:
                name = str(msg.param_id)
            if name in self._params:
                self._param_value(name)
            else:
                self.stats["param unknown"] += 1  # ArduPilot does not answer
            return
        # PARAM_SET: unknown names and non-finite values are silently ignored, as ArduPilot does.
        name, value = str(msg.param_id), float(msg.param_value)
        if name not in self._params or not math.isfinite(value):
            self.stats["param set refused"] += 1
            return
        p = self._params[name]
        if p.mav_type in _INT_LIMITS:
            lo, hi = _INT_LIMITS[p.mav_type]
            value = float(min(max(round(value), lo), hi))
        if name == "SYSID_THISMAV" and not 1 <= value <= 255:
            self.stats["param set refused"] += 1
            return
        p.value = value
        self._param_value(name)  # the new value, as confirmation (SYSID applies on reboot)
        events.append(ParamChanged(now, name, value))

    # -- the companion's status messages -------------------------------------------------
    def _handle_status(
        self, msg: Any, src: tuple[int, int], now: int, events: list[MockEvent]
    ) -> None:
        if src[0] != self.system_id:
            # Another vehicle's companion: not about our airspace.
            self.stats["other system ignored"] += 1
            return
        boot_ms = self.boot_us(now) // 1000
        problems = self._check_time(int(msg.time_boot_ms), boot_ms)
        if msg.get_msgId() == mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS:
            problems += _check_object_status(msg)
            self.stats["object status"] += 1
        else:
            problems += _check_pipeline_health(msg)
            self.stats["pipeline health"] += 1
        for problem in problems:
            self.stats["status " + problem.split()[0]] += 1
        rec = ReceivedStatus(now, boot_ms, src[0], src[1], msg, problems)
        self.received_status.append(rec)
        events.append(StatusReceived(rec))
        if msg.get_msgId() == mav.MAVLINK_MSG_ID_TCM_OBJECT_STATUS:
            self._maybe_brake(rec, now, events)

    def _check_time(self, time_boot_ms: int, boot_ms: int) -> tuple[str, ...]:
        age = boot_ms - time_boot_ms
        if age > self.config.status_max_age_ms:
            return ("stale",)
        if -age > self.config.status_max_lead_ms:
            return ("future",)
        return ()

    def _maybe_brake(self, rec: ReceivedStatus, now: int, events: list[MockEvent]) -> None:
        msg = rec.msg
        ttc = float(msg.ttc)
        alarm = int(msg.collision_course) == 1 and math.isfinite(ttc)
        if not alarm or ttc >= self.config.brake_ttc_s:
            return
        if not self.config.brake_on_collision:
            self.stats["collision alarm (brake disabled)"] += 1
            return
        if not rec.ok:
            # An alarm we cannot trust (stale time or bad fields) is not acted on.
            self.stats["collision alarm ignored (bad status)"] += 1
            return
        brake = self.start_brake(now, int(msg.track_id), ttc)
        if brake is not None:
            events.append(brake)

    def start_brake(
        self, now_us: int, track_id: int, ttc_s: float, text: str | None = None
    ) -> BrakeStarted | None:
        """Start the brake manoeuvre now (the built-in rule above, or an outside decider
        such as the Lua applet, :mod:`.lua_applet`); None when already braking. ``text``
        replaces the STATUSTEXT (empty: none)."""
        if self._brake is not None:
            return None
        now = self._advance(now_us)
        t = self.scenario_t_s(now)
        pos = self._motion.position_ned_m(t)
        vel = self._motion.velocity_ned_mps(t)
        path = BrakingPath.start(pos, vel, t, self.config.brake_decel_mps2)
        self._motion = replace(self._motion, path=path)
        self._att_cache = None
        hover_at = now + math.ceil(path.stop_after_s * 1e6)
        self._brake = BrakeStarted(
            now,
            int(track_id),
            float(ttc_s),
            float(np.linalg.norm(vel)),
            hover_at,
            _vec3(path.position_ned_m(t + path.stop_after_s)),
        )
        self.stats["brakes"] += 1
        if text is None:
            text = f"brake: collision course track {track_id}"
        if text:
            self._statustext(mav.MAV_SEVERITY_WARNING, text)
        return self._brake


# --------------------------------------------------------------------------------------
# Field checks of the TCM messages (against tcm.xml)
# --------------------------------------------------------------------------------------
def _enum_values(name: str) -> frozenset[int]:
    """The values of a dialect enum, without pymavlink's added ``*_ENUM_END`` entry."""
    return frozenset(v for v, e in mav.enums[name].items() if not e.name.endswith("_ENUM_END"))


_REASONS = _enum_values("TCM_UNKNOWN_REASON")
_EGOMOTION_SOURCES = _enum_values("TCM_EGOMOTION_SOURCE")
_LOG_STATES = _enum_values("TCM_LOG_STATE")
_HEALTH_BITS = 0
for _bit in _enum_values("TCM_HEALTH_FLAGS"):
    _HEALTH_BITS |= _bit


def _check_object_status(msg: Any) -> tuple[str, ...]:
    bad: list[str] = []
    state, reason = int(msg.state), int(msg.reason)
    if state not in (
        mav.TCM_OBJECT_STATE_UNKNOWN,
        mav.TCM_OBJECT_STATE_STATIONARY,
        mav.TCM_OBJECT_STATE_MOVING,
    ):
        bad.append("bad state")
    if reason not in _REASONS:
        bad.append("bad reason")
    elif (state == mav.TCM_OBJECT_STATE_UNKNOWN) != (reason != mav.TCM_UNKNOWN_REASON_NONE):
        bad.append("bad reason (does not match state)")
    az, el, rad = float(msg.azimuth), float(msg.elevation), float(msg.angular_radius)
    if not (math.isfinite(az) and abs(az) <= math.pi + _ANGLE_SLACK_RAD):
        bad.append("bad azimuth")
    if not (math.isfinite(el) and abs(el) <= math.pi / 2 + _ANGLE_SLACK_RAD):
        bad.append("bad elevation")
    if not (math.isfinite(rad) and 0.0 <= rad <= math.pi + _ANGLE_SLACK_RAD):
        bad.append("bad angular_radius")
    thr = float(msg.threshold)
    if not (math.isfinite(thr) and thr >= 0.0):
        bad.append("bad threshold")
    disparity, ttc, rng = float(msg.disparity), float(msg.ttc), float(msg.range)
    if not (math.isnan(disparity) or (math.isfinite(disparity) and disparity >= 0.0)):
        bad.append("bad disparity")
    if not (math.isnan(ttc) or (math.isfinite(ttc) and ttc >= 0.0)):
        bad.append("bad ttc")  # "NaN when not approaching": never inf or negative
    if not (math.isnan(rng) or (math.isfinite(rng) and rng > 0.0)):
        bad.append("bad range")
    if int(msg.collision_course) not in (0, 1):
        bad.append("bad collision_course")
    if int(msg.confidence) > 100:
        bad.append("bad confidence")
    return tuple(bad)


def _check_pipeline_health(msg: Any) -> tuple[str, ...]:
    bad: list[str] = []
    fr, lat = float(msg.frame_rate), float(msg.latency)
    if not (math.isfinite(fr) and fr >= 0.0):
        bad.append("bad frame_rate")
    if not (math.isfinite(lat) and lat >= 0.0):
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
