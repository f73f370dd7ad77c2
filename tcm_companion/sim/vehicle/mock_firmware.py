"""The mock autopilot's firmware side: ArduCopter's MAVLink on one link, sans-IO.

It behaves like ArduCopter as observed in ``docs/autopilots.md``:

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
- A bounded transmit buffer: when it is full a message is dropped (``tx overflow``), as
  ArduPilot does with a full UART.

The content of the telemetry comes from the vehicle (:class:`~.mock_vehicle.MockVehicle`);
the flight mode in the HEARTBEAT is :attr:`MockFirmware.mode`, set by whoever decides to
brake.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

from ...core.frames import quat_wxyz_from_rot, rot_from_euler_zyx
from ...mavlink import tcm_dialect as mav
from ...mavlink.codec import MavlinkCodec
from .mock_types import (
    CommandReceived,
    MockAutopilotConfig,
    MockClock,
    MockEvent,
    ParamChanged,
    PeerSeen,
)
from .mock_vehicle import MockVehicle
from .telemetry import copter_heartbeat

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
REQUEST_ONLY_IDS = frozenset(
    {mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION, mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN}
)
_PARAM_IDS = frozenset(
    {
        mav.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
        mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
        mav.MAVLINK_MSG_ID_PARAM_SET,
    }
)
_COMMAND_IDS = frozenset({mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT})

# Integer parameter types and their limits (ArduPilot clamps a PARAM_SET to the type).
_INT_LIMITS = {
    mav.MAV_PARAM_TYPE_INT8: (-128, 127),
    mav.MAV_PARAM_TYPE_INT16: (-32768, 32767),
    mav.MAV_PARAM_TYPE_INT32: (-(2**31), 2**31 - 1),
}

STATUSTEXT_MAX = 50
_BANNER = ("ArduCopter V4.7.0-dev (tcm mock)", "Frame: QUAD/X")
_FIRMWARE_VERSION = (4 << 24) | (7 << 16) | (0 << 8) | 0  # major.minor.patch.type(dev)
_UNIX_US_DEFAULT = 1_718_000_000_000_000  # 2024-06-10


@dataclass
class Param:
    value: float
    mav_type: int


def initial_params(config: MockAutopilotConfig) -> dict[str, Param]:
    """A handful of real ArduCopter parameters that matter to a companion."""
    return {
        "SYSID_THISMAV": Param(float(config.system_id), mav.MAV_PARAM_TYPE_INT16),
        "PRX1_TYPE": Param(float(config.prx_type), mav.MAV_PARAM_TYPE_INT8),
        "AVD_ENABLE": Param(0.0, mav.MAV_PARAM_TYPE_INT8),
        "AVOID_ENABLE": Param(3.0, mav.MAV_PARAM_TYPE_INT8),
        "AVOID_MARGIN": Param(2.0, mav.MAV_PARAM_TYPE_REAL32),
    }


def _finite(x: float) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


class MockFirmware:
    """ArduCopter's MAVLink side on one link (see the module docstring). Faults are
    counted in ``stats`` (shared with the codec and the rest of the mock)."""

    def __init__(
        self,
        config: MockAutopilotConfig,
        vehicle: MockVehicle,
        clock: MockClock,
        stats: Counter[str],
    ) -> None:
        self.config = config
        self.vehicle = vehicle
        self.clock = clock
        self.stats = stats
        self.params = initial_params(config)
        self.mode = mav.COPTER_MODE_GUIDED  # HEARTBEAT.custom_mode
        self.peers: dict[tuple[int, int], int] = {}  # (sysid, compid) -> last heartbeat µs
        self.timesync_rtt_us: int | None = None  # round trip of our last answered request
        self._unix_us_at_start = (
            config.unix_us_at_start if config.unix_us_at_start is not None else _UNIX_US_DEFAULT
        )
        self._tx = bytearray()
        self.boot(clock.start_us - int(config.boot_offset_us))

    # -- boot --------------------------------------------------------------------------
    def boot(self, boot_zero_us: int) -> None:
        """(Re)start: boot clock, link state and streams (the vehicle flies on)."""
        cfg = self.config
        now = self.clock.now_us
        self.boot_zero_us = boot_zero_us  # caller's clock when the boot clock read 0
        self.system_id = int(self.params["SYSID_THISMAV"].value)
        self.codec = MavlinkCodec(self.system_id, cfg.component_id)
        self.codec.stats = self.stats  # one Counter for the codec's and the mock's faults
        # SET_MESSAGE_INTERVAL is forgotten on reboot: the companion must ask again.
        self.interval_us = dict(STREAM_DEFAULT_INTERVAL_US)
        self._due_us: dict[int, int] = {
            mav.MAVLINK_MSG_ID_HEARTBEAT: max(boot_zero_us + cfg.heartbeat_delay_us, now)
        }
        self._banner_sent = False
        self._origin_announced = False
        self._next_timesync_us = (
            max(boot_zero_us, now) + cfg.timesync_period_us if cfg.timesync_period_us > 0 else None
        )
        self._timesync_ts1: int | None = None

    def reboot(self) -> None:
        """Reboot now: what was queued never goes out; boot clock from 0."""
        self._tx.clear()
        self.boot(self.clock.now_us)

    def boot_us(self, now_us: int | None = None) -> int:
        """Time since boot (µs) at ``now_us`` (default: the latest time seen)."""
        return (self.clock.now_us if now_us is None else int(now_us)) - self.boot_zero_us

    def boot_ms(self, now_us: int) -> int:
        """``time_boot_ms`` of a message sent at ``now_us``."""
        return max(0, self.boot_us(now_us) // 1000) & 0xFFFFFFFF

    def ekf_has_origin(self, now_us: int | None = None) -> bool:
        return self.boot_us(now_us) >= self.config.ekf_origin_delay_us

    # -- output --------------------------------------------------------------------------
    def data_to_send(self) -> bytes:
        """Drain the bytes queued for the link."""
        out = bytes(self._tx)
        self._tx.clear()
        return out

    def send(self, msg: Any) -> None:
        try:
            frame = self.codec.encode(msg, self.clock.now_us)
        except Exception:  # a value out of the field's range: a bug here, not the peer's
            self.stats["encode error"] += 1
            return
        if len(self._tx) + len(frame) > self.config.max_tx_bytes:
            # Like a full UART buffer: ArduPilot drops the message rather than block.
            self.stats["tx overflow"] += 1
            return
        self._tx.extend(frame)

    def statustext(self, severity: int, text: str) -> None:
        """A STATUSTEXT (cut to 50 characters, as ArduPilot's ``gcs().send_text``)."""
        self.send(self.codec.mav.statustext_encode(severity, text[:STATUSTEXT_MAX].encode()))

    # -- timers ----------------------------------------------------------------------------
    def next_deadline_us(self) -> int:
        """When :meth:`poll` next has something to do (caller's clock, µs); never before
        the latest time seen, so something overdue reads as "now"."""
        cands = [due for mid, due in self._due_us.items() if self.interval_us.get(mid, 0) > 0]
        if self._next_timesync_us is not None:
            cands.append(self._next_timesync_us)
        if not self._origin_announced:
            cands.append(self.boot_zero_us + self.config.ekf_origin_delay_us)
        now = self.clock.now_us
        # Nothing scheduled (every stream turned off): still wake now and then.
        return max(min(cands), now) if cands else now + 1_000_000

    def poll(self, now: int) -> None:
        """Queue every message that has come due at ``now``."""
        for mid, interval in self.interval_us.items():
            if interval <= 0:
                continue
            due = self._due_us.get(mid, now)
            if now < due:
                continue
            self.send_message(mid, now)
            # Absolute deadlines so the rate does not drift; skip, don't burst, when late.
            due += interval
            self._due_us[mid] = due if due > now else now + interval
        # After the streams, so that a peer hears the heartbeat before anything else.
        if not self._origin_announced and self.ekf_has_origin(now):
            self._origin_announced = True
            self.statustext(mav.MAV_SEVERITY_INFO, "EKF3 IMU0 origin set")
            self.send_message(mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, now)
        if self._next_timesync_us is not None and now >= self._next_timesync_us:
            self._timesync_ts1 = self.boot_us(now) * 1000 + self.system_id
            self.send(self.codec.mav.timesync_encode(0, self._timesync_ts1))
            self._next_timesync_us += self.config.timesync_period_us
            if self._next_timesync_us <= now:
                self._next_timesync_us = now + self.config.timesync_period_us

    # -- messages it sends ---------------------------------------------------------------
    def send_message(self, mid: int, now: int) -> bool:
        """Queue one message of id ``mid``; False when it cannot be sent (yet)."""
        m = self.codec.mav
        boot_ms = self.boot_ms(now)
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            self._send_heartbeat()
        elif mid == mav.MAVLINK_MSG_ID_SYSTEM_TIME:
            # ArduPilot has no Unix time until GPS: 0 before the EKF origin.
            unix = (
                self._unix_us_at_start + (now - self.clock.start_us) if self.ekf_has_origin() else 0
            )
            self.send(m.system_time_encode(max(0, unix), boot_ms))
        elif mid in (mav.MAVLINK_MSG_ID_ATTITUDE, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION):
            eul, rates = self.vehicle.attitude(now)
            roll, pitch, yaw = (float(x) for x in eul)
            p, q, r = (float(x) for x in rates)
            if mid == mav.MAVLINK_MSG_ID_ATTITUDE:
                self.send(m.attitude_encode(boot_ms, roll, pitch, yaw, p, q, r))
            else:
                w, x, y, z = (
                    float(c) for c in quat_wxyz_from_rot(rot_from_euler_zyx(roll, pitch, yaw))
                )
                self.send(m.attitude_quaternion_encode(boot_ms, w, x, y, z, p, q, r))
        elif mid == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            if not self.ekf_has_origin():
                self.stats["position withheld (no EKF origin)"] += 1
                return False
            pos, vel = self.vehicle.local_position(now)
            self.send(m.local_position_ned_encode(boot_ms, *map(float, pos), *map(float, vel)))
        elif mid == mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            if not self.ekf_has_origin():
                return False
            tc = self.config.telemetry
            self.send(
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
            self.send(
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
                self.statustext(mav.MAV_SEVERITY_INFO, line)
        self.send(copter_heartbeat(self.codec.mav, self.mode))

    # -- input -----------------------------------------------------------------------------
    def handle(
        self, msg: Any, mid: int, src: tuple[int, int], now: int, events: list[MockEvent]
    ) -> bool:
        """Take a message of the link protocol (HEARTBEAT, TIMESYNC, commands, parameters);
        False when ``mid`` is none of those."""
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if src not in self.peers:
                events.append(PeerSeen(now, src[0], src[1], int(msg.type)))
            self.peers[src] = now
        elif mid == mav.MAVLINK_MSG_ID_TIMESYNC:
            self._handle_timesync(msg, now)
        elif mid in _COMMAND_IDS:
            self._handle_command(msg, src, now, events)
        elif mid in _PARAM_IDS:
            self._handle_param(msg, mid, now, events)
        else:
            return False
        return True

    def _for_us(self, target_system: int, target_component: int) -> bool:
        ok = target_system in (0, self.system_id) and target_component in (
            0,
            self.config.component_id,
        )
        if not ok:
            self.stats["not for us"] += 1
        return ok

    def _handle_timesync(self, msg: Any, now: int) -> None:
        tc1, ts1 = int(msg.tc1), int(msg.ts1)
        boot_ns = self.boot_us(now) * 1000  # µs resolution, like ArduPilot
        if tc1 == 0:
            # tc1 = 0 would read as a request; a real autopilot is never at boot time 0.
            self.send(self.codec.mav.timesync_encode(max(boot_ns, 1000), ts1))
            self.stats["timesync answered"] += 1
        elif self._timesync_ts1 is not None and ts1 == self._timesync_ts1:
            # No target fields in TIMESYNC: a reply is recognised by its ts1.
            self.timesync_rtt_us = (boot_ns - (ts1 - self.system_id)) // 1000
            self.stats["timesync reply"] += 1
        else:
            self.stats["timesync ignored"] += 1

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
            if mid in STREAM_DEFAULT_INTERVAL_US or mid in REQUEST_ONLY_IDS:
                result, follow_up = mav.MAV_RESULT_ACCEPTED, mid
            else:
                result = mav.MAV_RESULT_FAILED
        elif cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            result, follow_up = mav.MAV_RESULT_ACCEPTED, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        elif cmd == mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            result = mav.MAV_RESULT_FAILED  # ArduPilot refuses while armed; we always fly
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
        self.send(self.codec.mav.command_ack_encode(cmd, result, 0, 0, src[0], src[1]))
        self.stats[f"command {cmd} result {result}"] += 1
        events.append(CommandReceived(now, cmd, result, src[0], src[1]))
        if follow_up is not None:
            # Like ArduPilot, the ACK goes first; a message that cannot exist yet
            # (LOCAL_POSITION_NED before the EKF origin) is simply not sent.
            self.send_message(follow_up, now)

    def _set_message_interval(self, p1: float, p2: float, now: int) -> int:
        if not (_finite(p1) and _finite(p2)):
            return mav.MAV_RESULT_FAILED
        mid, interval_us = int(p1), int(p2)
        if mid not in STREAM_DEFAULT_INTERVAL_US:
            return mav.MAV_RESULT_FAILED
        # ArduPilot keeps intervals in whole ms, at least 1 ms, at most 60 s.
        if interval_us == 0:
            interval = STREAM_DEFAULT_INTERVAL_US[mid]
        elif interval_us == -1:
            interval = 0  # disabled
        elif interval_us < 1000:
            interval = 1000  # ArduPilot treats other negatives as "1 ms" too
        else:
            interval = min(interval_us, 60_000_000) // 1000 * 1000
        self.interval_us[mid] = interval
        if interval > 0:
            self._due_us[mid] = now  # first one at the next poll
        return mav.MAV_RESULT_ACCEPTED

    def _get_message_interval(self, p1: float) -> int:
        mid = int(p1) if _finite(p1) else -1
        if mid not in STREAM_DEFAULT_INTERVAL_US:
            if 0 <= mid < 1 << 16:
                self.send(self.codec.mav.message_interval_encode(mid, 0))  # not available
            return mav.MAV_RESULT_FAILED
        interval = self.interval_us[mid]
        self.send(self.codec.mav.message_interval_encode(mid, interval if interval > 0 else -1))
        return mav.MAV_RESULT_ACCEPTED

    def _param_value(self, name: str) -> None:
        names = list(self.params)
        p = self.params[name]
        self.send(
            self.codec.mav.param_value_encode(
                name.encode(), p.value, p.mav_type, len(names), names.index(name)
            )
        )

    def _handle_param(self, msg: Any, mid: int, now: int, events: list[MockEvent]) -> None:
        if not self._for_us(int(msg.target_system), int(msg.target_component)):
            return
        names = list(self.params)
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
            if name in self.params:
                self._param_value(name)
            else:
                self.stats["param unknown"] += 1  # ArduPilot does not answer
            return
        # PARAM_SET: unknown names and non-finite values are silently ignored, as ArduPilot does.
        name, value = str(msg.param_id), float(msg.param_value)
        if name not in self.params or not math.isfinite(value):
            self.stats["param set refused"] += 1
            return
        p = self.params[name]
        if p.mav_type in _INT_LIMITS:
            lo, hi = _INT_LIMITS[p.mav_type]
            value = float(min(max(round(value), lo), hi))
        if name == "SYSID_THISMAV" and not 1 <= value <= 255:
            self.stats["param set refused"] += 1
            return
        p.value = value
        self._param_value(name)  # the new value, as confirmation (SYSID applies on reboot)
        events.append(ParamChanged(now, name, value))
