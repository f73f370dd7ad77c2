"""The companion's MAVLink endpoint: a sans-IO state machine (bytes and time in, events and
bytes out), in the manner of h11 and aioquic.

What it does, as a well-behaved companion component (mavlink.io microservices):

- HEARTBEAT at 1 Hz as MAV_TYPE_ONBOARD_CONTROLLER / MAV_AUTOPILOT_INVALID, component id
  191 by default, system id learned from the autopilot; the autopilot is *lost* after
  ~5 missed heartbeats and *rebooted* when its boot clock goes backwards.
- Requests the telemetry it needs with MAV_CMD_SET_MESSAGE_INTERVAL, one command at a
  time (a COMMAND_ACK does not say which message it is for), retried on no ACK, falling
  back from ATTITUDE_QUATERNION to ATTITUDE if refused, and re-requested when the
  measured rate falls short (a rebooted autopilot forgets).
- TIMESYNC requests; replies matched by ``ts1`` (the message has no target fields) and
  filtered (:mod:`.timesync`); the autopilot's own requests answered.
- The parameter protocol for our tunables (:mod:`.params`), COMMAND_LONG/COMMAND_INT to
  us answered with COMMAND_ACK (UNSUPPORTED when we do not support it), STATUSTEXT
  rate-limited, optional MAVLink 2 signing (:mod:`.codec`).
- Outputs: TCM_OBJECT_STATUS for every object of every frame, TCM_PIPELINE_HEALTH at
  2 Hz, and when enabled OBSTACLE_DISTANCE (10 Hz, only while frames are fresh),
  OBSTACLE_DISTANCE_3D and ADSB_VEHICLE (:mod:`.outputs`).

It never raises into its caller: malformed input is counted in :attr:`stats` and dropped.
Time is always an argument (``now_us``, the companion's clock, the same clock as the
frame times); :meth:`next_deadline_us` says when :meth:`poll` has work next.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..core.pipeline import FrameResult, ObjectResult
from ..core.telemetry import AttitudeSample, ClockSync, PositionSample, TelemetrySample
from . import outputs
from . import tcm_dialect as d
from .codec import MavlinkCodec, SigningConfig
from .params import PARAMS, ParamTable
from .timesync import TimesyncFilter

MAV_COMP_ID_ALL = 0
_FTP_NAK = 129  # MAVLink FTP opcode
_FTP_ERR_UNKNOWN_COMMAND = 7


@dataclass(frozen=True)
class EndpointConfig:
    component_id: int = 191
    default_system_id: int = 1  # until the autopilot's heartbeat tells us its system id
    heartbeat_interval_us: int = 1_000_000
    autopilot_timeout_us: int = 5_000_000  # ~5 missed heartbeats
    attitude_message: Literal["ATTITUDE", "ATTITUDE_QUATERNION"] = "ATTITUDE"
    attitude_rate_hz: float = 50.0
    position_rate_hz: float = 10.0
    request_retry_us: int = 1_000_000  # no COMMAND_ACK within this: send again
    rate_check_us: int = 3_000_000  # after an ACK, the rate must show within this
    timesync_interval_us: int = 1_000_000
    timesync_fast_interval_us: int = 200_000  # until the filter has a few samples
    health_interval_us: int = 500_000
    obstacle_interval_us: int = 100_000
    fresh_frame_us: int = 500_000  # obstacle outputs stop when frames are older
    statustext_min_interval_us: int = 250_000
    statustext_repeat_us: int = 10_000_000  # the same condition is not repeated within this
    collision_clear_us: int = 2_000_000  # a track's collision ends this long after its last alarm
    statustext_queue: int = 16


# -- events ---------------------------------------------------------------------------------
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


@dataclass
class _Request:
    """One SET_MESSAGE_INTERVAL we want honoured."""

    msg_id: int
    rate_hz: float
    acked_at_us: int | None = None
    attempts: int = 0
    refused: bool = False


@dataclass
class _Autopilot:
    system_id: int
    component_id: int
    last_heartbeat_us: int
    lost: bool = False
    last_boot_ms: int = -1


@dataclass
class _Statustext:
    severity: int
    text: str


class CompanionEndpoint:
    """Sans-IO MAVLink endpoint of the companion (one per link)."""

    def __init__(
        self,
        config: EndpointConfig = EndpointConfig(),
        params: Mapping[str, float] | None = None,
        signing: SigningConfig | None = None,
        now_us: int = 0,
        threshold: float | None = None,
    ) -> None:
        self.config = config
        self.codec = MavlinkCodec(config.default_system_id, config.component_id, signing)
        self.params = ParamTable(params)
        self.stats: Counter[str] = Counter()
        self.timesync = TimesyncFilter()
        self.telemetry_clock = ClockSync()  # fallback mapping when TIMESYNC is silent
        self.autopilot: _Autopilot | None = None
        self.origin: GlobalOrigin | None = None
        self.vehicle_pos_ned_m: np.ndarray | None = None
        self._out = bytearray()
        self._events: list[Event] = []
        self._start_us = now_us
        self._next_heartbeat = now_us
        self._next_timesync = now_us
        self._next_health = now_us
        self._next_obstacle = now_us
        self._next_request = now_us
        self._timesync_sent: deque[int] = deque(maxlen=16)  # ts1 values (ns) awaiting replies
        self._requests = self._wanted_requests()
        self._pending: _Request | None = None
        self._rx_count: Counter[int] = Counter()
        self._rx_since_us: dict[int, int] = {}
        self._health = HealthReport()
        self._last_objects: tuple[ObjectResult, ...] = ()
        self._last_frame_us: int | None = None
        self._statustext: deque[_Statustext] = deque()
        self._statustext_sent: dict[str, int] = {}  # condition -> when last queued
        self._statustext_log: deque[str] = deque(maxlen=256)
        # track id -> companion time of its last alarming frame (a collision condition)
        self._collision_alarm_us: dict[int, int] = {}
        self._next_statustext = now_us
        self._threshold = threshold

    # -- identity --------------------------------------------------------------------------
    @property
    def system_id(self) -> int:
        return self.codec.src_system

    @property
    def component_id(self) -> int:
        return self.codec.src_component

    @property
    def autopilot_connected(self) -> bool:
        return self.autopilot is not None and not self.autopilot.lost

    # -- receiving ---------------------------------------------------------------------------
    def receive_data(self, data: bytes, now_us: int) -> list[Event]:
        """Bytes from the link; returns what they meant. Never raises."""
        for msg in self.codec.feed(data):
            try:
                self._handle(msg, now_us)
            except Exception as exc:  # a hostile but well-framed message: count, go on
                self.stats[f"handler error {type(exc).__name__}"] += 1
        return self._take_events()

    def _take_events(self) -> list[Event]:
        events, self._events = self._events, []
        return events

    def _handle(self, msg: Any, now_us: int) -> None:
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            self._on_heartbeat(msg, src, now_us)
            return
        ap = self.autopilot
        from_autopilot = ap is not None and src == (ap.system_id, ap.component_id)
        if kind in ("ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED"):
            if from_autopilot:
                self._on_telemetry(msg, now_us)
            else:
                self.stats["telemetry from another system"] += 1
        elif kind == "TIMESYNC":
            self._on_timesync(msg, now_us)
        elif kind == "COMMAND_ACK":
            if from_autopilot and msg.target_system in (0, self.system_id):
                self._on_command_ack(msg, now_us)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            if self._addressed_to_us(msg.target_system, msg.target_component, broadcast=False):
                self._on_command(msg, src, now_us)
        elif kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            if self._addressed_to_us(msg.target_system, msg.target_component, broadcast=True):
                self._on_param(msg, kind, now_us)
        elif kind == "FILE_TRANSFER_PROTOCOL":
            if self._addressed_to_us(msg.target_system, msg.target_component, broadcast=False):
                self._on_ftp(msg, src, now_us)
        elif kind in ("GPS_GLOBAL_ORIGIN", "HOME_POSITION"):
            if from_autopilot and kind == "GPS_GLOBAL_ORIGIN":
                self.origin = GlobalOrigin(
                    msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
                )
                self._events.append(self.origin)
        else:
            self.stats[f"ignored {kind}"] += 1

    def _addressed_to_us(self, target_system: int, target_component: int, broadcast: bool) -> bool:
        if target_system not in (0, self.system_id):
            return False
        if target_component == self.component_id:
            return True
        return broadcast and target_component == MAV_COMP_ID_ALL

    def _on_heartbeat(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        is_autopilot = (
            msg.autopilot != d.MAV_AUTOPILOT_INVALID
            and msg.type not in (d.MAV_TYPE_GCS, d.MAV_TYPE_ONBOARD_CONTROLLER)
            and src[1] == d.MAV_COMP_ID_AUTOPILOT1
        )
        ap = self.autopilot
        if ap is not None and src == (ap.system_id, ap.component_id):
            if ap.lost:
                ap.lost = False
                self._restart_requests(now_us)
                self._events.append(AutopilotFound(src[0], src[1], msg.autopilot, msg.type))
            ap.last_heartbeat_us = now_us
            return
        if ap is None and is_autopilot:
            self.autopilot = _Autopilot(src[0], src[1], now_us)
            self.codec.src_system = src[0]  # we belong to the autopilot's system
            self._restart_requests(now_us)
            self._events.append(AutopilotFound(src[0], src[1], msg.autopilot, msg.type))
            self.statustext(d.MAV_SEVERITY_INFO, "TCM companion online", now_us)
        elif not is_autopilot:
            self.stats["heartbeat of another component"] += 1

    def _on_telemetry(self, msg: Any, now_us: int) -> None:
        assert self.autopilot is not None
        boot_ms = int(msg.time_boot_ms)
        ap = self.autopilot
        if ap.last_boot_ms >= 0 and boot_ms < ap.last_boot_ms - 1000:
            # The autopilot's boot clock went back: it rebooted and forgot our requests.
            self._on_reboot(now_us)
            ap.last_boot_ms = boot_ms
        else:
            ap.last_boot_ms = max(ap.last_boot_ms, boot_ms)
        self._rx_count[msg.get_msgId()] += 1
        sample = self._sample(msg, now_us)
        if sample is None:
            return
        self.telemetry_clock.observe(sample.time_boot_us, now_us)
        if isinstance(sample, PositionSample):
            self.vehicle_pos_ned_m = sample.pos_ned_m
        self._events.append(TelemetryReceived(sample))

    def _on_reboot(self, now_us: int, keep_timesync: bool = False) -> None:
        self.stats["autopilot reboots"] += 1
        self._events.append(AutopilotRebooted())
        self.statustext(d.MAV_SEVERITY_NOTICE, "TCM: autopilot reboot seen, re-requesting", now_us)
        if not keep_timesync:
            self.timesync = TimesyncFilter()
        self.telemetry_clock = ClockSync()
        if self.autopilot is not None:
            self.autopilot.last_boot_ms = -1
        self._restart_requests(now_us)

    def _sample(self, msg: Any, now_us: int) -> TelemetrySample | None:
        kind = msg.get_type()
        boot_us = int(msg.time_boot_ms) * 1000
        if kind == "ATTITUDE":
            angles = (msg.roll, msg.pitch, msg.yaw)
            if not all(math.isfinite(a) and abs(a) <= 2 * math.pi for a in angles):
                self.stats["bad attitude"] += 1
                self._events.append(TelemetryRejected("attitude", "ATTITUDE out of range"))
                return None
            return AttitudeSample.from_euler(boot_us, now_us, *angles)
        if kind == "ATTITUDE_QUATERNION":
            q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
            norm = float(np.linalg.norm(q))
            if not math.isfinite(norm) or abs(norm - 1.0) > 0.1:
                self.stats["bad attitude"] += 1
                self._events.append(TelemetryRejected("attitude", "quaternion not unit"))
                return None
            return AttitudeSample.from_quaternion(boot_us, now_us, q)
        pos = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            self.stats["bad position"] += 1
            self._events.append(TelemetryRejected("position", "LOCAL_POSITION_NED not finite"))
            return None
        return PositionSample(boot_us, now_us, pos, vel)

    # -- telemetry requests -------------------------------------------------------------------
    def _wanted_requests(self) -> list[_Request]:
        att = (
            d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
            if self.config.attitude_message == "ATTITUDE_QUATERNION"
            else d.MAVLINK_MSG_ID_ATTITUDE
        )
        return [
            _Request(att, self.config.attitude_rate_hz),
            _Request(d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, self.config.position_rate_hz),
        ]

    def _restart_requests(self, now_us: int) -> None:
        for r in self._requests:
            r.acked_at_us = None
            r.attempts = 0
        self._pending = None
        self._next_request = now_us
        self._rx_count.clear()
        self._rx_since_us.clear()

    def _service_requests(self, now_us: int) -> None:
        if not self.autopilot_connected or now_us < self._next_request:
            return
        if self._pending is not None and self._pending.acked_at_us is None:
            self.stats["request retries"] += 1  # no ACK in time: send it again
        todo = next((r for r in self._requests if r.acked_at_us is None and not r.refused), None)
        if todo is None:
            self._check_rates(now_us)
            self._next_request = now_us + self.config.request_retry_us
            return
        ap = self.autopilot
        assert ap is not None
        todo.attempts += 1
        self._pending = todo
        self._send(
            d.MAVLink_command_long_message(
                ap.system_id,
                ap.component_id,
                d.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                float(todo.msg_id),
                1e6 / todo.rate_hz,
                0,
                0,
                0,
                0,
                0,
            ),
            now_us,
        )
        self._next_request = now_us + self.config.request_retry_us

    def _on_command_ack(self, msg: Any, now_us: int) -> None:
        if msg.command != d.MAV_CMD_SET_MESSAGE_INTERVAL or self._pending is None:
            return
        req, self._pending = self._pending, None
        if msg.result == d.MAV_RESULT_ACCEPTED:
            req.acked_at_us = now_us
            self._rx_count[req.msg_id] = 0
            self._rx_since_us[req.msg_id] = now_us
        elif msg.result == d.MAV_RESULT_IN_PROGRESS:
            req.attempts -= 1
            return
        elif req.msg_id == d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            # Refused: the plain Euler message carries the same attitude.
            req.msg_id = d.MAVLINK_MSG_ID_ATTITUDE
            req.attempts = 0
        else:
            self.stats["requests refused"] += 1
        self._next_request = now_us  # on to the next request at once

    def _check_rates(self, now_us: int) -> None:
        """Re-request a stream that stopped or runs well below the rate we asked for."""
        for r in self._requests:
            since = self._rx_since_us.get(r.msg_id)
            if r.acked_at_us is None or since is None:
                continue
            elapsed = now_us - since
            if elapsed < self.config.rate_check_us:
                continue
            rate = self._rx_count[r.msg_id] * 1e6 / elapsed
            if rate < 0.5 * r.rate_hz:
                self.stats["streams re-requested"] += 1
                r.acked_at_us = None
                r.attempts = 0
            self._rx_count[r.msg_id] = 0
            self._rx_since_us[r.msg_id] = now_us

    # -- TIMESYNC -------------------------------------------------------------------------------
    def _on_timesync(self, msg: Any, now_us: int) -> None:
        if msg.tc1 == 0:
            # A request (ArduPilot sends one every 10 s): answer with our clock.
            self._send(d.MAVLink_timesync_message(now_us * 1000, msg.ts1), now_us)
            return
        if msg.ts1 not in self._timesync_sent:
            self.stats["timesync reply not ours"] += 1
            return
        self._timesync_sent.remove(msg.ts1)
        before = self.timesync.resets
        if self.timesync.add_reply(msg.ts1 // 1000, msg.tc1, now_us) is None:
            self.stats["timesync rejected"] += 1
        elif self.timesync.resets != before:
            # The autopilot's clock jumped: a reboot (it has forgotten our streams). This
            # is usually the first sign of one, a second before the telemetry shows it.
            self.stats["timesync resets"] += 1
            self._on_reboot(now_us, keep_timesync=True)

    def _service_timesync(self, now_us: int) -> None:
        if now_us < self._next_timesync or not self.autopilot_connected:
            return
        ts1 = now_us * 1000
        self._timesync_sent.append(ts1)
        self._send(d.MAVLink_timesync_message(0, ts1), now_us)
        fast = self.timesync.n_samples < 4
        self._next_timesync = now_us + (
            self.config.timesync_fast_interval_us if fast else self.config.timesync_interval_us
        )

    def has_time_base(self, now_us: int) -> bool:
        """Whether :meth:`boot_ms` maps companion times (TIMESYNC or the telemetry fit)."""
        return (
            self.timesync.synced
            and self.timesync.age_us(now_us) < 10 * self.config.timesync_interval_us
        ) or self.telemetry_clock.ready

    def boot_ms(self, companion_us: int, now_us: int) -> int:
        """Autopilot boot time (ms) of a companion-clock instant: TIMESYNC if fresh, else
        the telemetry clock fit, else 0."""
        if (
            self.timesync.synced
            and self.timesync.age_us(now_us) < 10 * self.config.timesync_interval_us
        ):
            return max(0, int(self.timesync.to_autopilot_us(companion_us) // 1000))
        if self.telemetry_clock.ready:
            return max(0, int((companion_us - self.telemetry_clock.offset_us) // 1000))
        return 0

    # -- commands and parameters -----------------------------------------------------------------
    def _on_command(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        cmd = int(msg.command)
        params = tuple(float(getattr(msg, f"param{i}", math.nan)) for i in range(1, 8))
        result = d.MAV_RESULT_UNSUPPORTED
        if cmd == d.MAV_CMD_REQUEST_MESSAGE:
            wanted = int(params[0]) if math.isfinite(params[0]) else -1
            if wanted == d.MAVLINK_MSG_ID_HEARTBEAT:
                result = d.MAV_RESULT_ACCEPTED
                self._next_heartbeat = now_us
            elif wanted == d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH:
                result = d.MAV_RESULT_ACCEPTED
                self._next_health = now_us
            else:
                result = d.MAV_RESULT_DENIED
        elif (
            cmd == d.MAV_CMD_SET_MESSAGE_INTERVAL
            and int(params[0]) == d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH
        ):
            interval = params[1]
            if interval > 0:
                self.config = dataclasses.replace(self.config, health_interval_us=int(interval))
                result = d.MAV_RESULT_ACCEPTED
            else:
                result = d.MAV_RESULT_DENIED
        self.stats[f"command {cmd}"] += 1
        self._send(
            d.MAVLink_command_ack_message(cmd, result, 0, 0, src[0], src[1]),
            now_us,
        )
        self._events.append(CommandReceived(cmd, params, src, result))

    def _on_ftp(self, msg: Any, src: tuple[int, int], now_us: int) -> None:
        """We serve no files: NAK every MAVLink FTP request at once, so a ground station
        that tries FTP first (MAVProxy's parameter download) falls back without waiting
        out its time-out."""
        req = bytes(msg.payload)
        if len(req) < 12:
            self.stats["malformed ftp"] += 1
            return
        seq = (req[0] | (req[1] << 8)) + 1
        payload = bytearray(251)
        payload[0], payload[1] = seq & 0xFF, (seq >> 8) & 0xFF
        payload[2] = req[2]  # session
        payload[3] = _FTP_NAK
        payload[4] = 1  # data size: the error code
        payload[5] = req[3]  # the request's opcode
        payload[12] = _FTP_ERR_UNKNOWN_COMMAND
        self.stats["ftp refused"] += 1
        self._send(
            d.MAVLink_file_transfer_protocol_message(0, src[0], src[1], list(payload)), now_us
        )

    def _param_value(self, index: int) -> Any:
        spec = PARAMS[index]
        return d.MAVLink_param_value_message(
            spec.name.encode(),
            self.params.values[spec.name],
            d.MAV_PARAM_TYPE_REAL32,
            len(PARAMS),
            index,
        )

    def _on_param(self, msg: Any, kind: str, now_us: int) -> None:
        if kind == "PARAM_REQUEST_LIST":
            for i in range(len(PARAMS)):
                self._send(self._param_value(i), now_us)
            return
        name = _param_name(msg.param_id)
        if kind == "PARAM_REQUEST_READ":
            index = msg.param_index if msg.param_index >= 0 else self._index_of(name)
            if index is None or not 0 <= index < len(PARAMS):
                self.stats["unknown parameter"] += 1
                return
            self._send(self._param_value(index), now_us)
            return
        index = self._index_of(name)
        if index is None:
            self.stats["unknown parameter"] += 1
            return
        old = self.params.values[name]
        stored = self.params.set(name, float(msg.param_value))
        if stored is None:
            self.stats["parameter refused"] += 1
            self.statustext(d.MAV_SEVERITY_WARNING, f"{name}: value out of range", now_us)
        elif stored != old:
            self._events.append(ParamChanged(name, stored))
        self._send(self._param_value(index), now_us)  # the current value, as the protocol asks

    def _index_of(self, name: str) -> int | None:
        try:
            return self.params.index(name)
        except ValueError:
            return None

    # -- sending -------------------------------------------------------------------------------
    def _send(self, msg: Any, now_us: int) -> None:
        self._out += self.codec.encode(msg, now_us)

    def data_to_send(self) -> bytes:
        """Everything queued for the link since the last call."""
        out, self._out = bytes(self._out), bytearray()
        return out

    @property
    def statustexts_queued(self) -> list[str]:
        """The distinct STATUSTEXTs this endpoint queued lately (the last 256; most recent
        last)."""
        return list(dict.fromkeys(self._statustext_log))

    def statustext(self, severity: int, text: str, now_us: int, key: str | None = None) -> bool:
        """Queue a STATUSTEXT; dropped (False) if the same condition went out recently.

        A condition is ``key`` (default: the text itself). Texts that carry a changing
        number (a TTC, a rate) must pass a key naming the condition, or each new number
        would count as a new text and flood the ground station.
        """
        cond = text if key is None else key
        last = self._statustext_sent.get(cond)
        if last is not None and now_us - last < self.config.statustext_repeat_us:
            self.stats["statustext suppressed"] += 1
            return False
        if len(self._statustext) >= self.config.statustext_queue:
            self.stats["statustext dropped"] += 1
            return False
        if len(self._statustext_sent) >= 256:  # bounded: forget conditions long past
            horizon = now_us - self.config.statustext_repeat_us
            for k in [k for k, t in self._statustext_sent.items() if t < horizon]:
                del self._statustext_sent[k]
        self._statustext_sent[cond] = now_us
        self._statustext_log.append(text)
        self._statustext.append(_Statustext(severity, text))
        return True

    def _service_statustext(self, now_us: int) -> None:
        if not self._statustext or now_us < self._next_statustext:
            return
        item = self._statustext.popleft()
        data = item.text.encode("utf-8", "replace")
        if len(data) <= 50:
            self._send(d.MAVLink_statustext_message(item.severity, data, 0, 0), now_us)
        else:
            # MAVLink 2 chunking: same id, increasing chunk_seq, last chunk NUL-terminated.
            msg_id = (now_us // 1000) & 0xFFFF or 1
            chunks = [data[i : i + 50] for i in range(0, len(data), 50)]
            for seq, chunk in enumerate(chunks):
                self._send(d.MAVLink_statustext_message(item.severity, chunk, msg_id, seq), now_us)
        self._next_statustext = now_us + self.config.statustext_min_interval_us

    def set_health(self, report: HealthReport) -> None:
        self._health = report

    def send_frame(self, result: FrameResult, now_us: int, camera_id: int = 0) -> None:
        """Queue the outputs of one processed frame (TCM_OBJECT_STATUS per object, and
        OBSTACLE_DISTANCE_3D / ADSB_VEHICLE when enabled)."""
        self._last_objects = result.objects
        self._last_frame_us = now_us
        v = self.params.values
        threshold = self._threshold if self._threshold is not None else v["TCM_THRESH"]
        radius = v["TCM_OBJ_RADIUS"]
        boot_ms = self.boot_ms(result.t_us, now_us)
        if v["TCM_OUT_STATUS"]:
            for msg in outputs.object_statuses(result, boot_ms, threshold, camera_id, radius):
                self._send(msg, now_us)
        if v["TCM_OUT_OBST3D"]:
            for obstacle in outputs.obstacle_distance_3d(result.objects, boot_ms, radius):
                self._send(obstacle, now_us)
        if v["TCM_OUT_ADSB"] and self.origin is not None and self.vehicle_pos_ned_m is not None:
            o = self.origin
            for traffic in outputs.adsb_vehicles(
                result.objects, self.vehicle_pos_ned_m, o.lat_deg, o.lon_deg, o.alt_m, radius, {}
            ):
                self._send(traffic, now_us)
        self._announce_collisions(result, now_us)

    def _announce_collisions(self, result: FrameResult, now_us: int) -> None:
        """One STATUSTEXT per collision condition, not per frame or per TTC value.

        A track's condition starts with its first alarming frame (collision course,
        ``ttc`` below TCM_TTC_ALARM) and lasts until it has not alarmed for
        ``collision_clear_us``; a new condition of the same track is announced at most
        once per ``statustext_repeat_us``.
        """
        alarm = self.params.values["TCM_TTC_ALARM"]
        clear_us = self.config.collision_clear_us
        conds = self._collision_alarm_us
        for tid in [t for t, last in conds.items() if now_us - last > clear_us]:
            del conds[tid]
        if alarm <= 0:
            return
        for obj in result.objects:
            if not (obj.collision_course and obj.ttc_s < alarm):
                continue
            if obj.track_id not in conds:
                self.statustext(
                    d.MAV_SEVERITY_WARNING,
                    f"TCM: collision course track {obj.track_id}, TTC {obj.ttc_s:.1f}s",
                    now_us,
                    key=f"collision course track {obj.track_id}",
                )
            conds[obj.track_id] = now_us

    # -- timers --------------------------------------------------------------------------------
    def poll(self, now_us: int) -> list[Event]:
        """Run whatever is due at ``now_us``; returns events (e.g. the autopilot lost)."""
        cfg = self.config
        if now_us >= self._next_heartbeat:
            self._send(
                d.MAVLink_heartbeat_message(
                    d.MAV_TYPE_ONBOARD_CONTROLLER,
                    d.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    d.MAV_STATE_ACTIVE,
                    3,
                ),
                now_us,
            )
            self._next_heartbeat = now_us + cfg.heartbeat_interval_us
        ap = self.autopilot
        if (
            ap is not None
            and not ap.lost
            and now_us - ap.last_heartbeat_us > cfg.autopilot_timeout_us
        ):
            ap.lost = True
            self._events.append(AutopilotLost(now_us - ap.last_heartbeat_us))
        self._service_requests(now_us)
        self._service_timesync(now_us)
        self._service_statustext(now_us)
        if now_us >= self._next_health:
            if self.params.values["TCM_OUT_HEALTH"]:
                self._send(self._health_message(now_us), now_us)
            self._next_health = now_us + cfg.health_interval_us
        if now_us >= self._next_obstacle:
            fresh = (
                self._last_frame_us is not None
                and now_us - self._last_frame_us < cfg.fresh_frame_us
            )
            if self.params.values["TCM_OUT_OBST"] and fresh:
                # Stale frames (camera lost) send nothing: the autopilot then flags its
                # proximity sensor unhealthy, which is the truth.
                self._send(
                    outputs.obstacle_distance(
                        self._last_objects, now_us, self.params.values["TCM_OBJ_RADIUS"]
                    ),
                    now_us,
                )
            self._next_obstacle = now_us + cfg.obstacle_interval_us
        return self._take_events()

    def send_health_now(self, now_us: int) -> None:
        """Queue a TCM_PIPELINE_HEALTH at once (as MAV_CMD_REQUEST_MESSAGE does)."""
        self._send(self._health_message(now_us), now_us)

    def _health_message(self, now_us: int) -> Any:
        h = self._health
        flags = h.health_flags
        if (
            not self.timesync.synced
            or self.timesync.age_us(now_us) > 10 * self.config.timesync_interval_us
        ):
            flags |= d.TCM_HEALTH_TIMESYNC_LOST
        offset = self.timesync.offset_us
        rtt = self.timesync.last_rtt_us
        return d.MAVLink_tcm_pipeline_health_message(
            time_boot_ms=self.boot_ms(now_us, now_us) & 0xFFFFFFFF,
            frame_rate=h.frame_rate_hz,
            latency=h.latency_ms,
            frames_dropped=h.frames_dropped & 0xFFFFFFFF,
            egomotion_source=h.egomotion_source,
            egomotion_quality=max(0, min(100, h.egomotion_quality_pct)),
            health=flags,
            objects=max(0, min(255, h.objects)),
            log_state=h.log_state,
            timesync_offset_us=int(offset) if math.isfinite(offset) else 0,
            timesync_rtt_us=min(rtt, 0xFFFF) if rtt is not None else 0xFFFF,
            protocol=outputs.PROTOCOL,
        )

    def next_deadline_us(self) -> int:
        """When :meth:`poll` next has something to do."""
        deadlines = [self._next_heartbeat, self._next_health]
        if self.autopilot_connected:
            deadlines += [self._next_request, self._next_timesync]
            ap = self.autopilot
            assert ap is not None
            deadlines.append(ap.last_heartbeat_us + self.config.autopilot_timeout_us + 1)
        if self._statustext:
            deadlines.append(self._next_statustext)
        if self.params.values["TCM_OUT_OBST"]:
            deadlines.append(self._next_obstacle)
        return min(deadlines)


def _param_name(raw: Any) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]
