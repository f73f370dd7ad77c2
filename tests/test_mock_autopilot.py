"""The mock autopilot, driven by a companion-side codec in memory with explicit time.

A :class:`Companion` is a bare :class:`MavlinkCodec` (system 1, component 191) wired to
the sans-IO mock: what it sends goes straight into ``receive_data``; time only moves
when the test says so (``advance``), jumping from one ``next_deadline_us`` to the next.
The runner tests use a two-queue fake transport and the real memory pair; they run on
the event loop for a few milliseconds.
"""

from __future__ import annotations

import asyncio
import math
import random
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega

from tcm_companion.cli.sim import add_mock_autopilot_arguments
from tcm_companion.io.transports import memory_pair
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec
from tcm_companion.mavlink.tcm_dialect import COPTER_MODE_BRAKE, COPTER_MODE_GUIDED
from tcm_companion.sim.vehicle.mock_autopilot import (
    BrakeStarted,
    BrakingPath,
    CommandReceived,
    MockAutopilot,
    MockAutopilotConfig,
    ParamChanged,
    PeerSeen,
    StatusReceived,
)
from tcm_companion.sim.vehicle.mock_autopilot_run import (
    TransportClosed,
    config_from_args,
    run_mock_autopilot,
)
from tcm_companion.sim.vehicle.mock_checks import check_status, collision_alarm
from tcm_companion.sim.vehicle.telemetry import TelemetryConfig, TelemetryNoise

T0_US = 5_000_000_000  # the caller's clock when the mock starts (arbitrary monotonic µs)
S = 1_000_000  # µs per second


class Companion:
    """Companion-side test client: a codec wired in memory to the mock."""

    def __init__(self, ap: MockAutopilot, now_us: int = T0_US, sysid: int = 1) -> None:
        self.ap = ap
        self.now = now_us
        self.codec = MavlinkCodec(sysid, 191)
        self.rx: list[tuple[int, Any]] = []  # (receive time, message)
        self.raw = bytearray()

    @property
    def mav(self) -> Any:
        return self.codec.mav

    def send(self, msg: Any) -> list:
        return self.send_bytes(self.codec.encode(msg))

    def send_bytes(self, data: bytes) -> list:
        events = self.ap.receive_data(data, self.now)
        self.pump()
        return events

    def pump(self) -> None:
        data = self.ap.data_to_send()
        self.raw += data
        self.rx += [(self.now, m) for m in self.codec.feed(data)]

    def advance(self, dt_us: int) -> None:
        """Move time forward by ``dt_us``, polling the mock at each of its deadlines."""
        end = self.now + dt_us
        for _ in range(1_000_000):
            due = self.ap.next_deadline_us()
            if due > end:
                break
            self.now = max(self.now, due)
            self.ap.poll(self.now)
            self.pump()
        self.now = end
        self.ap.poll(end)
        self.pump()

    def of(self, kind: str, since_us: int | None = None) -> list:
        return [
            m for t, m in self.rx if m.get_type() == kind and (since_us is None or t >= since_us)
        ]

    def times(self, kind: str) -> list[int]:
        return [t for t, m in self.rx if m.get_type() == kind]

    def command(self, command: int, *params: float, target: tuple[int, int] = (1, 1)) -> list:
        p = [*params, *[0.0] * (7 - len(params))]
        return self.send(self.mav.command_long_encode(target[0], target[1], command, 0, *p))

    def set_interval(self, msg_id: float, interval_us: float) -> list:
        return self.command(d.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)

    def status(self, **fields: Any) -> Any:
        """A TCM_OBJECT_STATUS stamped with the mock's current boot time (unless given)."""
        values: dict[str, Any] = {
            "time_boot_ms": max(0, self.ap.boot_us(self.now) // 1000 - 40),  # 40 ms ago
            "track_id": 7,
            "camera_id": 0,
            "state": d.TCM_OBJECT_STATE_MOVING,
            "reason": d.TCM_UNKNOWN_REASON_NONE,
            "disparity": 0.3,
            "threshold": 0.1,
            "ttc": math.nan,
            "collision_course": 0,
            "azimuth": 0.2,
            "elevation": -0.1,
            "angular_radius": 0.05,
            "range": math.nan,
            "confidence": 90,
        }
        values.update(fields)
        return self.mav.tcm_object_status_encode(**values)

    def health(self, **fields: Any) -> Any:
        values: dict[str, Any] = {
            "time_boot_ms": self.ap.boot_us(self.now) // 1000,
            "frame_rate": 25.0,
            "latency": 12.0,
            "frames_dropped": 0,
            "egomotion_source": d.TCM_EGOMOTION_SOURCE_AUTOPILOT,
            "egomotion_quality": 100,
            "health": 0,
            "objects": 1,
            "log_state": d.TCM_LOG_STATE_RECORDING,
            "timesync_offset_us": 0,
            "timesync_rtt_us": 5000,
        }
        values.update(fields)
        return self.mav.tcm_pipeline_health_encode(**values)


def make(**cfg: Any) -> tuple[MockAutopilot, Companion]:
    ap = MockAutopilot(MockAutopilotConfig(**cfg), T0_US)
    return ap, Companion(ap)


def acks(c: Companion, command: int) -> list:
    return [m for m in c.of("COMMAND_ACK") if m.command == command]


def timesync_request(c: Companion, ts1: int = 123_456_789_000) -> Any:
    return c.mav.timesync_encode(0, ts1)


# --------------------------------------------------------------------------------------
# Heartbeat and what streams unasked
# --------------------------------------------------------------------------------------
def test_heartbeat_rate_and_content_and_nothing_else_unrequested() -> None:
    ap, c = make()
    c.advance(20 * S + 1)
    hbs = c.of("HEARTBEAT")
    assert len(hbs) == 20  # first ~1 s after boot, then 1 Hz
    assert c.times("HEARTBEAT")[0] == T0_US + 1 * S
    gaps = np.diff(c.times("HEARTBEAT"))
    assert np.all(gaps == 1 * S)
    hb = hbs[0]
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == d.MAV_TYPE_QUADROTOR
    assert hb.autopilot == d.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == COPTER_MODE_GUIDED
    assert hb.base_mode & d.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.mavlink_version == 3
    assert c.raw[0] == 0xFD  # MAVLink 2 framing
    kinds = {m.get_type() for _, m in c.rx}
    assert kinds <= {"HEARTBEAT", "STATUSTEXT", "TIMESYNC", "GPS_GLOBAL_ORIGIN"}
    texts = [m.text for m in c.of("STATUSTEXT")]
    assert texts[0].startswith("ArduCopter") and "EKF3 IMU0 origin set" in texts
    # ArduPilot's own TIMESYNC requests: every 10 s, tc1 = 0, ts1 = boot ns + sysid.
    reqs = [(t, m) for t, m in c.rx if m.get_type() == "TIMESYNC"]
    assert [t - T0_US for t, _ in reqs] == [10 * S, 20 * S]
    for t, m in reqs:
        assert m.tc1 == 0 and m.ts1 == ap.boot_us(t) * 1000 + 1


@pytest.mark.slow  # over half a second of CPU
def test_set_message_interval_acked_and_rates_measured() -> None:
    ap, c = make(ekf_origin_delay_us=2 * S)
    rates_hz = {
        d.MAVLINK_MSG_ID_ATTITUDE: 50.0,
        d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 100.0,
        d.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
        d.MAVLINK_MSG_ID_SYSTEM_TIME: 2.0,
    }
    for mid, hz in rates_hz.items():
        events = c.set_interval(mid, 1e6 / hz)
        assert events == [CommandReceived(c.now, d.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 1, 191)]
    ack = acks(c, d.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert len(ack) == 4
    assert all(a.result == d.MAV_RESULT_ACCEPTED for a in ack)
    assert all((a.target_system, a.target_component) == (1, 191) for a in ack)

    c.advance(3 * S)  # past the EKF origin
    start = c.now
    c.advance(10 * S)
    names = {
        d.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
        d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: "ATTITUDE_QUATERNION",
        d.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
        d.MAVLINK_MSG_ID_SYSTEM_TIME: "SYSTEM_TIME",
    }
    for mid, hz in rates_hz.items():
        n = len(c.of(names[mid], since_us=start + 1))
        assert n == pytest.approx(10 * hz, rel=0.1), names[mid]

    # time_boot_ms is the mock's own boot clock at the send time.
    for t, m in c.rx:
        if m.get_type() in ("ATTITUDE", "LOCAL_POSITION_NED", "SYSTEM_TIME"):
            assert m.time_boot_ms == ap.boot_us(t) // 1000
    st_msgs = c.of("SYSTEM_TIME", since_us=start)
    assert all(m.time_unix_usec > 1_700_000_000_000_000 for m in st_msgs)


def test_telemetry_follows_the_scenario_with_realistic_noise() -> None:
    ap, c = make(scenario="T90", ekf_origin_delay_us=0, seed=3)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 20_000)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 20_000)
    c.set_interval(d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000)
    c.advance(5 * S)
    att_err, pos_err = [], []
    for t, m in c.rx:
        truth = ap.vehicle_truth(t)
        if m.get_type() == "ATTITUDE":
            R = truth.R_ned_from_body
            roll = math.atan2(R[2, 1], R[2, 2])
            pitch = math.asin(-R[2, 0])
            att_err += [m.roll - roll, m.pitch - pitch]
        elif m.get_type() == "LOCAL_POSITION_NED":
            pos_err.append(np.array([m.x, m.y, m.z]) - truth.position_ned_m)
        elif m.get_type() == "ATTITUDE_QUATERNION":
            q = np.array([m.q1, m.q2, m.q3, m.q4])
            assert abs(np.linalg.norm(q) - 1.0) < 1e-5 and q[0] > 0  # scalar first
    att_err_deg = np.degrees(np.abs(att_err))
    # Bias up to 0.8° plus 0.3° white noise (the simulator's TelemetryConfig levels).
    assert 0.01 < np.std(np.degrees(att_err)) < 0.6
    assert att_err_deg.max() < 2.5
    pos_err_m = np.abs(np.array(pos_err))
    assert 0.001 < pos_err_m.mean() < 0.05 and pos_err_m.max() < 0.12
    # The vehicle really flies: the back-and-forth track moves it by metres.
    ned = np.array([[m.x, m.y] for m in c.of("LOCAL_POSITION_NED")])
    assert np.ptp(ned[:, 0]) + np.ptp(ned[:, 1]) > 1.0


def test_attitude_is_exact_with_zero_noise() -> None:
    ap, c = make(noise=0.0, ekf_origin_delay_us=0)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 100_000)
    c.advance(2 * S)
    from tcm_companion.core.frames import rot_from_quat_wxyz

    for t, m in c.rx:
        if m.get_type() == "ATTITUDE_QUATERNION":
            R = rot_from_quat_wxyz(np.array([m.q1, m.q2, m.q3, m.q4]))
            assert np.allclose(R, ap.vehicle_truth(t).R_ned_from_body, atol=1e-6)


def test_local_position_only_after_ekf_origin() -> None:
    _, c = make(ekf_origin_delay_us=4 * S)
    c.set_interval(d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 100_000)
    c.advance(6 * S)
    pos_times = c.times("LOCAL_POSITION_NED")
    assert pos_times and min(pos_times) >= T0_US + 4 * S
    assert min(c.times("ATTITUDE")) < T0_US + 1 * S  # attitude from the start
    origin = c.of("GPS_GLOBAL_ORIGIN")
    assert len(origin) == 1 and origin[0].latitude != 0
    c.command(d.MAV_CMD_REQUEST_MESSAGE, d.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)  # once more
    assert len(c.of("GPS_GLOBAL_ORIGIN")) == 2
    # Requesting one before the origin: ACCEPTED, but nothing comes (as ArduPilot).
    _, c2 = make(ekf_origin_delay_us=4 * S)
    c2.command(d.MAV_CMD_REQUEST_MESSAGE, d.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
    assert acks(c2, d.MAV_CMD_REQUEST_MESSAGE)[0].result == d.MAV_RESULT_ACCEPTED
    assert not c2.of("LOCAL_POSITION_NED")


def test_interval_disable_default_get_and_request_message() -> None:
    ap, c = make(ekf_origin_delay_us=0)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 20_000)
    c.advance(1 * S)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, -1)
    stopped = c.now
    c.advance(2 * S)
    assert not c.of("ATTITUDE", since_us=stopped + 1)
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_ATTITUDE] == 0
    # 0 = default: off for ATTITUDE, 1 Hz for HEARTBEAT.
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 0)
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_ATTITUDE] == 0
    c.set_interval(d.MAVLINK_MSG_ID_HEARTBEAT, 500_000)
    c.set_interval(d.MAVLINK_MSG_ID_HEARTBEAT, 0)
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_HEARTBEAT] == 1_000_000
    # ArduPilot keeps whole milliseconds: 30 Hz = 33 ms.
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 1e6 / 30)
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_ATTITUDE] == 33_000
    c.command(d.MAV_CMD_GET_MESSAGE_INTERVAL, d.MAVLINK_MSG_ID_ATTITUDE)
    mi = c.of("MESSAGE_INTERVAL")[-1]
    assert (mi.message_id, mi.interval_us) == (d.MAVLINK_MSG_ID_ATTITUDE, 33_000)
    c.command(d.MAV_CMD_GET_MESSAGE_INTERVAL, d.MAVLINK_MSG_ID_SYSTEM_TIME)
    assert c.of("MESSAGE_INTERVAL")[-1].interval_us == -1  # off
    # Unknown message ids: FAILED, as ArduPilot.
    c.set_interval(9999, 20_000)
    assert acks(c, d.MAV_CMD_SET_MESSAGE_INTERVAL)[-1].result == d.MAV_RESULT_FAILED
    c.command(d.MAV_CMD_REQUEST_MESSAGE, 9999)
    assert acks(c, d.MAV_CMD_REQUEST_MESSAGE)[-1].result == d.MAV_RESULT_FAILED
    n = len(c.of("SYSTEM_TIME"))
    c.command(d.MAV_CMD_REQUEST_MESSAGE, d.MAVLINK_MSG_ID_SYSTEM_TIME)
    assert acks(c, d.MAV_CMD_REQUEST_MESSAGE)[-1].result == d.MAV_RESULT_ACCEPTED
    assert len(c.of("SYSTEM_TIME")) == n + 1
    c.command(d.MAV_CMD_REQUEST_MESSAGE, d.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    av = c.of("AUTOPILOT_VERSION")
    assert av and av[0].capabilities & d.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    # NaN parameters are refused, not raised.
    c.set_interval(math.nan, 20_000)
    assert acks(c, d.MAV_CMD_SET_MESSAGE_INTERVAL)[-1].result == d.MAV_RESULT_FAILED


def test_command_int_set_message_interval() -> None:
    ap, c = make()
    c.send(
        c.mav.command_int_encode(
            1,
            1,
            0,
            d.MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            0,
            d.MAVLINK_MSG_ID_ATTITUDE,
            20_000,
            0,
            0,
            0,
            0,
            0,
        )
    )
    assert acks(c, d.MAV_CMD_SET_MESSAGE_INTERVAL)[-1].result == d.MAV_RESULT_ACCEPTED
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_ATTITUDE] == 20_000


def test_unsupported_and_refused_commands() -> None:
    _, c = make()
    c.command(d.MAV_CMD_USER_1)
    ack = acks(c, d.MAV_CMD_USER_1)
    assert len(ack) == 1 and ack[0].result == d.MAV_RESULT_UNSUPPORTED
    # Broadcast target (0, 0) is for us too.
    c.command(d.MAV_CMD_USER_2, target=(0, 0))
    assert acks(c, d.MAV_CMD_USER_2)[0].result == d.MAV_RESULT_UNSUPPORTED
    # ArduPilot refuses to reboot while armed; the mock is always flying.
    c.command(d.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
    assert acks(c, d.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN)[0].result == d.MAV_RESULT_FAILED


# --------------------------------------------------------------------------------------
# TIMESYNC
# --------------------------------------------------------------------------------------
def test_timesync_reply_carries_boot_time_in_ns() -> None:
    _, c = make(boot_offset_us=250 * S)  # the autopilot booted 250 s before we connect
    c.advance(3 * S + 123_457)
    ts1 = 987_654_321_000
    c.send(timesync_request(c, ts1))
    replies = [m for m in c.of("TIMESYNC") if m.tc1 != 0]
    assert len(replies) == 1
    r = replies[0]
    assert r.ts1 == ts1
    assert r.tc1 == (c.now - T0_US + 250 * S) * 1000  # boot ns, µs resolution
    assert r.tc1 % 1000 == 0
    assert (r.get_srcSystem(), r.get_srcComponent()) == (1, 1)


def test_mock_measures_round_trip_of_its_own_timesync() -> None:
    ap, c = make()
    c.advance(10 * S)
    req = c.of("TIMESYNC")[-1]
    c.now += 5_000  # 5 ms later the companion answers
    c.send(c.mav.timesync_encode(123, req.ts1))
    assert ap.timesync_rtt_us == 5_000
    c.send(c.mav.timesync_encode(123, 42))  # someone else's reply: ignored
    assert ap.stats["timesync ignored"] == 1


# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------
def test_param_protocol() -> None:
    ap, c = make()
    c.send(c.mav.param_request_list_encode(1, 1))
    values = c.of("PARAM_VALUE")
    names = [v.param_id for v in values]
    assert {"SYSID_THISMAV", "PRX1_TYPE", "AVD_ENABLE"} <= set(names)
    assert [v.param_index for v in values] == list(range(len(values)))
    assert all(v.param_count == len(values) for v in values)
    assert {v.param_id: v.param_value for v in values}["PRX1_TYPE"] == 2

    c.send(c.mav.param_request_read_encode(1, 1, b"AVD_ENABLE", -1))
    v = c.of("PARAM_VALUE")[-1]
    assert v.param_id == "AVD_ENABLE" and v.param_type == d.MAV_PARAM_TYPE_INT8
    c.send(c.mav.param_request_read_encode(1, 1, b"", names.index("PRX1_TYPE")))
    assert c.of("PARAM_VALUE")[-1].param_id == "PRX1_TYPE"

    events = c.send(c.mav.param_set_encode(1, 1, b"AVD_ENABLE", 1.0, d.MAV_PARAM_TYPE_INT8))
    assert events == [ParamChanged(c.now, "AVD_ENABLE", 1.0)]
    v = c.of("PARAM_VALUE")[-1]
    assert (v.param_id, v.param_value) == ("AVD_ENABLE", 1.0)
    assert ap.params["AVD_ENABLE"] == 1.0
    # Integer parameters are rounded and clamped to their type.
    c.send(c.mav.param_set_encode(1, 1, b"PRX1_TYPE", 300.4, d.MAV_PARAM_TYPE_INT8))
    assert ap.params["PRX1_TYPE"] == 127

    # Unknown names and NaN values: no answer, as ArduPilot.
    n = len(c.of("PARAM_VALUE"))
    c.send(c.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, d.MAV_PARAM_TYPE_REAL32))
    c.send(c.mav.param_set_encode(1, 1, b"AVOID_MARGIN", math.nan, d.MAV_PARAM_TYPE_REAL32))
    c.send(c.mav.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
    c.send(c.mav.param_request_read_encode(1, 1, b"", 99))
    assert len(c.of("PARAM_VALUE")) == n
    # Addressed to another system: not for us.
    c.send(c.mav.param_request_list_encode(2, 1))
    assert len(c.of("PARAM_VALUE")) == n


def test_sysid_change_applies_on_reboot() -> None:
    ap, c = make()
    c.send(c.mav.param_set_encode(1, 1, b"SYSID_THISMAV", 7.0, d.MAV_PARAM_TYPE_INT16))
    c.advance(2 * S)
    assert c.of("HEARTBEAT")[-1].get_srcSystem() == 1
    ap.reboot(c.now)
    c.advance(2 * S)
    assert c.of("HEARTBEAT")[-1].get_srcSystem() == 7


# --------------------------------------------------------------------------------------
# The companion's messages: records, checks, brake
# --------------------------------------------------------------------------------------
def test_status_and_health_recorded_and_checked() -> None:
    ap, c = make()
    c.advance(2 * S)
    (ev,) = c.send(c.status())
    assert isinstance(ev, StatusReceived) and ev.record.ok and ev.record.age_ms == 40
    assert c.send(c.health())[0].record.ok
    bad_cases: dict[str, dict[str, Any]] = {
        "bad state": {"state": 5},
        "bad reason": {"reason": 42},
        "bad azimuth": {"azimuth": 4.0},
        "bad elevation": {"elevation": math.nan},
        "bad angular_radius": {"angular_radius": -0.1},
        "bad ttc": {"ttc": math.inf},
        "bad range": {"range": -3.0},
        "bad confidence": {"confidence": 101},
        "bad collision_course": {"collision_course": 2},
    }
    for problem, fields in bad_cases.items():
        (ev,) = c.send(c.status(**fields))
        assert problem in ev.record.problems, (problem, ev.record.problems)
    (ev,) = c.send(c.status(state=d.TCM_OBJECT_STATE_UNKNOWN))  # unknown needs a reason
    assert ev.record.problems == ("bad reason (does not match state)",)
    (ev,) = c.send(c.status(time_boot_ms=ap.boot_us(c.now) // 1000 - 1500))
    assert ev.record.problems == ("stale",)
    (ev,) = c.send(c.status(time_boot_ms=ap.boot_us(c.now) // 1000 + 500))
    assert ev.record.problems == ("future",)
    (ev,) = c.send(c.health(egomotion_source=9, health=1 << 20, latency=math.nan))
    assert set(ev.record.problems) == {"bad egomotion_source", "bad health", "bad latency"}
    assert len(ap.received_status) == 2 + len(bad_cases) + 4
    assert ap.stats["status stale"] == 1 and ap.stats["status future"] == 1
    assert ap.stats["status bad"] >= len(bad_cases) + 2
    assert all(r.recv_us == c.now for r in ap.received_status)


def _speed(ap: MockAutopilot, now_us: int) -> float:
    return float(np.linalg.norm(ap.vehicle_truth(now_us).velocity_ned_mps))


def test_brake_on_collision_alarm_stops_the_vehicle() -> None:
    ap, c = make(scenario="COLLISION", ekf_origin_delay_us=0, brake_decel_mps2=3.0)
    c.set_interval(d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 50_000)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 20_000)
    c.advance(2 * S)
    v0 = _speed(ap, c.now)
    assert v0 == pytest.approx(1.5, abs=0.1)  # COLLISION flies straight at 1.5 m/s

    events = c.send(c.status(collision_course=1, ttc=2.0, track_id=12))
    brake = [e for e in events if isinstance(e, BrakeStarted)]
    assert len(brake) == 1 and brake[0].track_id == 12 and ap.braking == brake[0]
    assert "brake: collision course track 12" in [m.text for m in c.of("STATUSTEXT")]
    t_brake = c.now
    stop_s = math.pi * v0 / (2 * 3.0)  # the smooth stop's duration at 3 m/s² peak
    assert brake[0].hover_at_us - t_brake == pytest.approx(stop_s * 1e6, abs=1000)

    # Deceleration never exceeds the configured peak; the speed reaches ~0 in time.
    ts = np.linspace(t_brake, t_brake + 1.5 * S, 301).astype(np.int64)
    speeds = np.array([_speed(ap, int(t)) for t in ts])
    assert np.all(np.diff(speeds) <= 1e-9)
    decel = -np.diff(speeds) / (np.diff(ts) / 1e6)
    assert decel.max() <= 3.0 * 1.01
    assert _speed(ap, t_brake + round(stop_s * 1e6) + 1000) < 0.01
    assert _speed(ap, t_brake + round(0.5 * stop_s * 1e6)) > 0.3  # not instantaneous
    # The attitude reflects the deceleration: pitched back (nose up) while braking.
    mid = t_brake + round(0.5 * stop_s * 1e6)
    R = ap.vehicle_truth(mid).R_ned_from_body
    assert math.degrees(math.asin(-R[2, 0])) > 10.0

    c.advance(3 * S)
    pos = c.of("LOCAL_POSITION_NED", since_us=t_brake + 2 * S)
    assert pos and all(math.hypot(m.vx, m.vy) < 0.15 for m in pos)  # hovering (noise only)
    hover = np.array([[m.x, m.y] for m in pos])
    assert np.ptp(hover, axis=0).max() < 0.15
    assert np.allclose(hover.mean(axis=0), brake[0].hover_ned_m[:2], atol=0.05)
    assert c.of("HEARTBEAT")[-1].custom_mode == COPTER_MODE_BRAKE

    # Without a brake the same flight keeps going at 1.5 m/s.
    ap2, c2 = make(scenario="COLLISION", ekf_origin_delay_us=0, brake_on_collision=False)
    c2.advance(2 * S)
    c2.send(c2.status(collision_course=1, ttc=2.0))
    assert ap2.braking is None
    assert _speed(ap2, c2.now + 2 * S) == pytest.approx(1.5, abs=0.1)
    assert ap2.stats["collision alarm (brake disabled)"] == 1


@pytest.mark.parametrize(
    "fields",
    [
        {"collision_course": 1, "ttc": math.nan},  # not approaching
        {"collision_course": 1, "ttc": 5.0},  # above the 3 s threshold
        {"collision_course": 0, "ttc": 1.0},  # approaching but missing
        {"collision_course": 1, "ttc": 1.0, "time_boot_ms": 0},  # stale: not trusted
        {"collision_course": 1, "ttc": 1.0, "azimuth": 7.0},  # bad fields: not trusted
    ],
)
def test_no_brake_without_a_valid_alarm(fields: dict[str, Any]) -> None:
    ap, c = make(scenario="COLLISION")
    c.advance(2 * S)
    events = c.send(c.status(**fields))
    assert not any(isinstance(e, BrakeStarted) for e in events)
    assert ap.braking is None


def test_braking_path_is_continuous() -> None:
    path = BrakingPath.start(np.array([1.0, 2.0, -2.0]), np.array([1.2, -0.9, 0.0]), 3.0, 3.0)
    T = path.stop_after_s
    eps = 1e-7
    for t in (3.0, 3.0 + T):
        for order in (0, 1, 2):
            a = path._eval(t - eps, order)
            b = path._eval(t + eps, order)
            assert np.allclose(a, b, atol=1e-5)
    assert np.allclose(path.velocity_ned_mps(3.0), [1.2, -0.9, 0.0])
    assert np.allclose(path.velocity_ned_mps(3.0 + T + 1), 0.0)
    assert np.allclose(path.position_ned_m(3.0 + T + 5), path.position_ned_m(3.0 + T))
    stop_dist = np.linalg.norm(path.position_ned_m(3.0 + T) - [1.0, 2.0, -2.0])
    assert stop_dist == pytest.approx(1.5 * T / 2)
    ts = np.linspace(2.9, 3.0 + T + 0.1, 50)
    assert path.position_ned_m(ts).shape == (50, 3)


def test_the_checks_are_pure_functions_of_the_message_and_the_boot_clock() -> None:
    _, c = make()
    ok = c.status(time_boot_ms=1000, collision_course=1, ttc=1.5)
    assert check_status(ok, 1040, 1000, 50) == ()
    assert check_status(ok, 2500, 1000, 50) == ("stale",)
    assert check_status(ok, 900, 1000, 50) == ("future",)
    assert collision_alarm(ok, 3.0) and not collision_alarm(ok, 1.0)
    health = c.health(log_state=9)
    assert check_status(health, int(health.time_boot_ms), 1000, 50) == ("bad log_state",)


def test_poll_returns_events_like_the_endpoint_and_the_parts_are_reachable() -> None:
    ap, c = make()
    events = ap.poll(T0_US + 2 * S)
    assert events == []  # nothing the mock reports comes of time alone
    assert ap.now_us == T0_US + 2 * S and ap.scenario_t_s() == pytest.approx(2.0)
    ap.statustext(d.MAV_SEVERITY_INFO, "x" * 80)  # cut to 50, as ArduPilot
    c.pump()
    assert c.of("STATUSTEXT")[-1].text == "x" * 50
    assert ap.codec is ap.firmware.codec and ap.system_id == ap.firmware.system_id
    assert ap.vehicle_truth().t_s == ap.vehicle.t_s()


def test_the_mock_uses_the_synthetic_telemetrys_noise_model() -> None:
    for scale in (1.0, 0.5, 0.0):
        ap, _ = make(noise=scale, seed=4)
        cfg = ap.config.telemetry
        noise = ap.vehicle.noise
        assert isinstance(noise, TelemetryNoise)
        assert noise.attitude_sigma_rad == pytest.approx(
            math.radians(cfg.attitude_noise_deg) * scale
        )
        assert noise.position_sigma_m == pytest.approx(cfg.position_noise_m * scale)
        bias = np.abs(noise.attitude_bias_rad)
        assert np.all(bias <= math.radians(cfg.attitude_bias_max_deg) * scale + 1e-12)
    # One model: the same draws give the same measurement, whoever asks.
    model = TelemetryNoise.draw(TelemetryConfig(), 1.0, np.random.default_rng(1))
    one = model.attitude(np.array([0.1, 0.2, 3.1]), np.zeros(3), np.random.default_rng(2))
    many = model.attitude(np.array([[0.1, 0.2, 3.1]]), np.zeros((1, 3)), np.random.default_rng(2))
    assert np.array_equal(one[0], many[0][0]) and np.array_equal(one[1], many[1][0])
    assert abs(one[0][2]) <= math.pi  # yaw wrapped


def test_obstacle_messages_and_proximity_health() -> None:
    ap, c = make()
    c.advance(1 * S)
    assert not ap.proximity_healthy  # "PreArm: PRX1: No Data"
    dist = c.mav.obstacle_distance_encode(
        0, 0, [2000] * 72, 5, 20, 2000, 0.0, 0.0, d.MAV_FRAME_BODY_FRD
    )
    for _ in range(20):  # 10 Hz for 2 s
        c.send(dist)
        assert ap.proximity_healthy
        c.advance(100_000)
    c.advance(400_000)
    assert ap.proximity_healthy
    c.advance(200_000)  # 600 ms after the last: AP_Proximity_MAV's 500 ms timeout
    assert not ap.proximity_healthy
    assert len(ap.received_obstacles) == 20
    assert ap.received_obstacles[0].src_component == 191

    # OBSTACLE_DISTANCE_3D is an ardupilotmega message: the mock decodes it too.
    apm = ardupilotmega.MAVLink(None, srcSystem=1, srcComponent=191)
    o3d = apm.obstacle_distance_3d_encode(
        1000, 0, d.MAV_FRAME_BODY_FRD, 7, 3.0, 0.5, -0.2, 0.2, 30.0
    )
    c.send_bytes(bytes(o3d.pack(apm)))
    assert ap.received_obstacles[-1].msg.get_type() == "OBSTACLE_DISTANCE_3D"
    assert ap.received_obstacles[-1].msg.obstacle_id == 7
    assert ap.proximity_healthy

    adsb = c.mav.adsb_vehicle_encode(
        0xABC, -274975000, 1530137000, 0, 32000, 9000, 150, 0, b"TCM7", 0, 1, 0, 0
    )
    c.send(adsb)
    assert ap.received_adsb[-1].msg.ICAO_address == 0xABC

    # PRX1_TYPE other than 2: OBSTACLE_DISTANCE is recorded but proximity stays off.
    c.send(c.mav.param_set_encode(1, 1, b"PRX1_TYPE", 0, d.MAV_PARAM_TYPE_INT8))
    c.send(dist)
    assert not ap.proximity_healthy


def test_peer_heartbeats_seen() -> None:
    ap, c = make()
    hb = c.mav.heartbeat_encode(d.MAV_TYPE_ONBOARD_CONTROLLER, d.MAV_AUTOPILOT_INVALID, 0, 0, 4)
    assert c.send(hb) == [PeerSeen(c.now, 1, 191, d.MAV_TYPE_ONBOARD_CONTROLLER)]
    assert c.send(hb) == []
    assert ap.peers[(1, 191)] == c.now


# --------------------------------------------------------------------------------------
# Robustness: the mock never raises
# --------------------------------------------------------------------------------------
def _still_answers(c: Companion) -> bool:
    """The mock answers TIMESYNC requests again. Garbage may have left a partial
    "frame" (up to 280 bytes) waiting in the receive buffer that swallows the next
    bytes until it fails its CRC, so several requests go out and the last must be
    answered."""
    n = len([m for m in c.of("TIMESYNC") if m.tc1 != 0])
    for i in range(12):
        c.send(timesync_request(c, 777_000 + i))
    replies = [m for m in c.of("TIMESYNC") if m.tc1 != 0][n:]
    return bool(replies) and replies[-1].ts1 == 777_011


def test_garbage_bytes() -> None:
    ap, c = make()
    rnd = random.Random(1)
    for _ in range(50):
        c.send_bytes(bytes(rnd.getrandbits(8) for _ in range(rnd.randint(0, 3000))))
    assert ap.stats["garbage bytes"] > 10_000
    assert _still_answers(c)


def test_truncated_frames() -> None:
    _, c = make()
    frame = c.codec.encode(timesync_request(c, 111_000))
    c.send_bytes(frame[:7])  # a frame cut short ...
    assert not c.of("TIMESYNC")
    c.send_bytes(frame[7:])  # ... completes when the rest arrives
    assert c.of("TIMESYNC")[-1].ts1 == 111_000
    # A truncated frame followed by a whole one: the whole one is still understood.
    cut = c.codec.encode(timesync_request(c, 222_000))[:-5]
    whole = c.codec.encode(timesync_request(c, 333_000))
    c.send_bytes(cut + whole)
    assert c.of("TIMESYNC")[-1].ts1 == 333_000
    # Byte by byte.
    for b in c.codec.encode(timesync_request(c, 444_000)):
        c.send_bytes(bytes([b]))
    assert c.of("TIMESYNC")[-1].ts1 == 444_000


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_oversized_input() -> None:
    ap, c = make()
    c.send_bytes(b"\xfd\xff" * 600_000)  # 1.2 MB of frame starts that never complete
    # No such frame can exist (bad headers): rejected byte by byte, nothing buffered.
    assert ap.codec.stats["bad header"] + ap.codec.stats["garbage bytes"] >= 1_199_990
    assert len(ap.codec._rx) <= ap.codec.max_buffer
    assert _still_answers(c)


def _frame_with_id(frame: bytes, msg_id: int) -> bytes:
    """A MAVLink 2 frame re-labelled as ``msg_id``, with a CRC that is right for an
    unknown id's CRC_EXTRA of 0 (nobody can check it)."""
    from pymavlink.generator.mavcrc import x25crc

    f = bytearray(frame)
    f[7:10] = msg_id.to_bytes(3, "little")
    crc = x25crc(bytes(f[1:-2]))
    crc.accumulate(bytes([0]))
    f[-2:] = crc.crc.to_bytes(2, "little")
    return bytes(f)


def test_unknown_message_id() -> None:
    ap, c = make()
    c.send_bytes(_frame_with_id(c.codec.encode(timesync_request(c)), 60_000))
    assert ap.stats["unknown message id"] >= 1
    assert not c.of("TIMESYNC")
    # A message of a dialect the mock knows but does not handle: ignored, counted.
    apm = ardupilotmega.MAVLink(None, srcSystem=1, srcComponent=191)
    c.send_bytes(bytes(apm.ahrs_encode(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(apm)))
    assert _still_answers(c)


def test_messages_from_or_for_another_system() -> None:
    ap, c = make(scenario="COLLISION")
    c.advance(2 * S)
    other = Companion(ap, c.now, sysid=2)
    events = other.send(other.status(collision_course=1, ttc=1.0))
    assert events == [] and ap.braking is None and not ap.received_status
    other.send(other.mav.obstacle_distance_encode(0, 0, [500] * 72, 5, 20, 2000))
    assert not ap.received_obstacles
    assert ap.stats["other system ignored"] == 2
    c.command(d.MAV_CMD_USER_1, target=(2, 1))  # addressed to system 2
    c.command(d.MAV_CMD_USER_1, target=(1, 100))  # addressed to a camera on our system
    assert not acks(c, d.MAV_CMD_USER_1)
    assert ap.stats["not for us"] == 2
    # A looped-back link: the mock's own messages come back to it.
    c.send_bytes(ap.codec.encode(ap.codec.mav.timesync_encode(0, 5)))
    assert ap.stats["own echo ignored"] == 1
    # TIMESYNC is answered whoever asks (ArduPilot does, per link).
    assert _still_answers(other)


def test_bad_crc() -> None:
    ap, c = make()
    frame = bytearray(c.codec.encode(timesync_request(c, 555_000)))
    frame[-1] ^= 0xFF
    c.send_bytes(bytes(frame))
    assert ap.stats["bad CRC"] >= 1
    assert not c.of("TIMESYNC")
    assert _still_answers(c)


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_flood() -> None:
    ap, c = make(max_tx_bytes=16 * 1024, max_records=1000)
    burst = b"".join(c.codec.encode(timesync_request(c, 1000 * i)) for i in range(1, 5001))
    c.send_bytes(burst)  # 5000 requests (125 kB) in one read
    answered = [m for m in c.of("TIMESYNC") if m.tc1 != 0]
    # Every request is parsed (good frames are never trimmed away); the answers fill the
    # transmit buffer and the rest are dropped. Every loss is counted; nothing raises.
    n = ap.stats["timesync answered"]
    assert n == 5000
    assert 0 < len(answered) < n
    assert ap.stats["tx overflow"] == n - len(answered)
    # A sustained flood of statuses (30 reads of 100): all handled, the record bounded.
    for _ in range(30):
        c.send_bytes(b"".join(c.codec.encode(c.status()) for _ in range(100)))
    assert ap.stats["object status"] == 3000
    assert len(ap.received_status) == 1000  # max_records: the newest are kept
    assert _still_answers(c)


def test_time_going_backwards() -> None:
    ap, c = make()
    c.advance(5 * S)
    boot = ap.boot_us()
    ap.poll(c.now - 3 * S)
    ap.receive_data(c.codec.encode(timesync_request(c)), c.now - 4 * S)
    assert ap.stats["time went backwards"] == 2
    assert ap.boot_us() == boot  # the mock's clock does not go back
    c.pump()
    reply = [m for m in c.of("TIMESYNC") if m.tc1 != 0][-1]
    assert reply.tc1 == boot * 1000
    n = len(c.of("HEARTBEAT"))
    c.advance(3 * S)
    assert len(c.of("HEARTBEAT")) == n + 3


def test_bad_input_types_and_nonsense_time() -> None:
    ap, c = make()
    assert ap.receive_data(None, c.now) == []  # type: ignore[arg-type]
    assert ap.receive_data("text", c.now) == []  # type: ignore[arg-type]
    ap.poll("soon")  # type: ignore[arg-type]
    ap.poll(math.nan)  # type: ignore[arg-type]
    assert ap.stats["bad input"] == 2 and ap.stats["bad time"] == 2
    assert _still_answers(c)


def test_reboot_restarts_boot_clock_and_forgets_streams() -> None:
    ap, c = make(boot_offset_us=300 * S, ekf_origin_delay_us=2 * S)
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 100_000)
    c.set_interval(d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000)
    c.advance(5 * S)
    c.send(timesync_request(c, 1_000))
    before = [m for m in c.of("TIMESYNC") if m.tc1 != 0][-1].tc1
    assert before > 300 * S * 1000

    ap.reboot(c.now)
    t_reboot = c.now
    c.advance(100_000)
    c.send(timesync_request(c, 2_000))
    after = [m for m in c.of("TIMESYNC") if m.tc1 != 0][-1]
    assert after.ts1 == 2_000 and after.tc1 == 100_000 * 1000  # restarted near 0
    c.advance(5 * S)
    hb_after = [t for t in c.times("HEARTBEAT") if t > t_reboot]
    assert hb_after[0] == t_reboot + 1 * S and len(hb_after) == 5  # first ~1 s after boot
    # Stream rates are forgotten: the companion must ask again.
    assert not c.of("ATTITUDE", since_us=t_reboot + 1)
    assert ap.stream_intervals_us[d.MAVLINK_MSG_ID_ATTITUDE] == 0
    c.set_interval(d.MAVLINK_MSG_ID_ATTITUDE, 100_000)
    c.advance(1 * S)
    att = c.of("ATTITUDE", since_us=t_reboot + 1)
    assert att and att[0].time_boot_ms < 7_000
    assert ap.stats["reboots"] == 1
    # Statuses stamped with the old boot time are now "future" (TIMESYNC must follow).
    (ev,) = c.send(c.status(time_boot_ms=before // 1_000_000))
    assert ev.record.problems == ("future",)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chunks=st.lists(st.binary(max_size=300), max_size=6), dt=st.integers(-S, S))
def test_fuzz_receive_never_raises(chunks: list[bytes], dt: int) -> None:
    ap = MockAutopilot(MockAutopilotConfig(), T0_US)
    c = Companion(ap)
    # Mix valid frames into the noise so decoding paths are reached too.
    valid = c.codec.encode(c.status(collision_course=1, ttc=0.5))
    for i, chunk in enumerate(chunks):
        ap.receive_data(chunk + (valid if i % 2 else b""), T0_US + i * dt)
        ap.poll(T0_US + i * dt)
    ap.data_to_send()
    assert ap.stats["internal error"] == 0 and ap.stats["handler error"] == 0


# --------------------------------------------------------------------------------------
# The asyncio runner
# --------------------------------------------------------------------------------------
class QueueTransport:
    """One end of a fake link made of two asyncio queues."""

    def __init__(
        self, inbox: asyncio.Queue[bytes | None], outbox: asyncio.Queue[bytes | None]
    ) -> None:
        self.inbox, self.outbox = inbox, outbox

    async def recv(self) -> bytes:
        data = await self.inbox.get()
        if data is None:
            raise TransportClosed("closed")
        return data

    async def send(self, data: bytes) -> None:
        await self.outbox.put(data)


async def _expect(codec: MavlinkCodec, outbox: asyncio.Queue[bytes | None], kind: str) -> Any:
    async with asyncio.timeout(2.0):
        while True:
            data = await outbox.get()
            for m in codec.feed(data or b""):
                if m.get_type() == kind:
                    return m


def test_runner_with_fake_transport() -> None:
    async def main() -> MockAutopilot:
        to_mock: asyncio.Queue[bytes | None] = asyncio.Queue()
        from_mock: asyncio.Queue[bytes | None] = asyncio.Queue()
        stop = asyncio.Event()
        cfg = MockAutopilotConfig(heartbeat_delay_us=0)
        events: list = []
        task = asyncio.create_task(
            run_mock_autopilot(
                QueueTransport(to_mock, from_mock), cfg, stop, on_event=events.append
            )
        )
        codec = MavlinkCodec(1, 191)
        hb = await _expect(codec, from_mock, "HEARTBEAT")
        assert hb.type == d.MAV_TYPE_QUADROTOR
        await to_mock.put(codec.encode(codec.mav.timesync_encode(0, 4242)))
        reply = await _expect(codec, from_mock, "TIMESYNC")
        assert reply.ts1 == 4242 and reply.tc1 > 0
        await to_mock.put(
            codec.encode(
                codec.mav.command_long_encode(1, 1, d.MAV_CMD_USER_1, 0, 0, 0, 0, 0, 0, 0, 0)
            )
        )
        ack = await _expect(codec, from_mock, "COMMAND_ACK")
        assert ack.result == d.MAV_RESULT_UNSUPPORTED
        assert any(isinstance(e, CommandReceived) for e in events)
        stop.set()
        async with asyncio.timeout(1.0):
            return await task

    ap = asyncio.run(main())
    assert ap.stats["timesync answered"] == 1


def test_runner_ends_when_link_closes() -> None:
    async def main() -> MockAutopilot:
        to_mock: asyncio.Queue[bytes | None] = asyncio.Queue()
        from_mock: asyncio.Queue[bytes | None] = asyncio.Queue()
        task = asyncio.create_task(
            run_mock_autopilot(QueueTransport(to_mock, from_mock), MockAutopilotConfig())
        )
        await to_mock.put(None)
        async with asyncio.timeout(1.0):
            return await task

    assert isinstance(asyncio.run(main()), MockAutopilot)


def test_runner_over_memory_pair() -> None:
    async def main() -> None:
        mock_end, companion_end = memory_pair()
        stop = asyncio.Event()
        task = asyncio.create_task(
            run_mock_autopilot(mock_end, MockAutopilotConfig(heartbeat_delay_us=0), stop)
        )
        codec = MavlinkCodec(1, 191)
        await companion_end.send(codec.encode(codec.mav.timesync_encode(0, 99)))
        async with asyncio.timeout(2.0):
            got: list = []
            while not any(m.get_type() == "TIMESYNC" and m.ts1 == 99 for m in got):
                got += codec.feed(await companion_end.recv())
        assert any(m.get_type() == "HEARTBEAT" for m in got)
        stop.set()
        async with asyncio.timeout(1.0):
            await task
        await companion_end.close()
        await mock_end.close()

    asyncio.run(main())


def test_cli_arguments_make_a_config() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    add_mock_autopilot_arguments(parser)
    args = parser.parse_args(
        [
            "--connect",
            "udpout:127.0.0.1:14550",
            "--scenario",
            "collision",
            "--no-brake",
            "--ekf-origin-delay",
            "0.5",
        ]
    )
    cfg = config_from_args(args)
    assert cfg.scenario == "COLLISION" and not cfg.brake_on_collision
    assert cfg.ekf_origin_delay_us == 500_000
    with pytest.raises(ValueError):
        MockAutopilotConfig(scenario="NOPE")


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("system_id", 0, "system_id must be in 1..255, got 0"),
        ("component_id", 300, "component_id must be in 1..255, got 300"),
        ("noise", -1.0, "noise must be >= 0, got -1.0"),
        ("brake_decel_mps2", 0.0, "brake_decel_mps2 must be > 0, got 0.0"),
    ],
)
def test_a_bad_mock_setting_names_only_its_key(key: str, value: Any, message: str) -> None:
    """The messages named two keys at once ("noise must be >= 0 and brake_decel_mps2 > 0")."""
    with pytest.raises(ValueError) as err:
        MockAutopilotConfig(**{key: value})
    assert str(err.value) == message
