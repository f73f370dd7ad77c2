"""The companion endpoint against a scripted autopilot, in memory, time driven explicitly."""

from __future__ import annotations

import math
import os
import random
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcm_companion.core.classify import Classification
from tcm_companion.core.frames import bearing_from_azel
from tcm_companion.core.pipeline import FrameResult, ObjectResult
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec, SigningConfig
from tcm_companion.mavlink.endpoint import (
    AutopilotFound,
    AutopilotLost,
    AutopilotRebooted,
    CompanionEndpoint,
    EndpointConfig,
    ParamChanged,
    TelemetryReceived,
    TelemetryRejected,
)
from tcm_companion.mavlink.params import PARAMS
from tcm_companion.mavlink.samples import Rejected, parse_telemetry, sample_from_message
from tcm_companion.mavlink.statustext import CollisionConditions, StatustextQueue
from tcm_companion.mavlink.streams import StreamRequests
from tcm_companion.mavlink.timesync import FRESH_US

T0 = 1_000_000_000  # companion clock at start, µs
BOOT0_MS = 250_000  # autopilot boot time at start


class Autopilot:
    """A scripted ArduPilot-like peer: a codec plus the few answers the tests need."""

    def __init__(self, sysid: int = 1, key: bytes | None = None) -> None:
        self.codec = MavlinkCodec(sysid, 1, SigningConfig(key) if key else None)
        self.inbox: list = []
        self.ack_commands = True

    def hb(self) -> bytes:
        return self.codec.encode(
            d.MAVLink_heartbeat_message(
                d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
            )
        )

    def attitude(self, boot_ms: int, roll: float = 0.0) -> bytes:
        return self.codec.encode(d.MAVLink_attitude_message(boot_ms, roll, 0.0, 0.1, 0, 0, 0))

    def receive(self, data: bytes) -> list:
        msgs = self.codec.feed(data)
        self.inbox += msgs
        return msgs

    def of(self, kind: str) -> list:
        return [m for m in self.inbox if m.get_type() == kind]


def connected(now: int = T0, **cfg) -> tuple[CompanionEndpoint, Autopilot]:  # type: ignore[no-untyped-def]
    ep = CompanionEndpoint(EndpointConfig(**cfg), now_us=now)
    ap = Autopilot(sysid=7)
    events = ep.receive_data(ap.hb(), now)
    assert events == [AutopilotFound(7, 1, d.MAV_AUTOPILOT_ARDUPILOTMEGA, d.MAV_TYPE_QUADROTOR)]
    return ep, ap


def test_heartbeat_identity_and_learned_system_id() -> None:
    ep = CompanionEndpoint(now_us=T0)
    ap = Autopilot(sysid=7)
    ep.poll(T0)
    (hb,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "HEARTBEAT"]
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 191
    assert hb.type == d.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == d.MAV_AUTOPILOT_INVALID
    ep.receive_data(ap.hb(), T0 + 1000)
    for k in range(1, 4):
        ep.poll(T0 + k * 1_000_000)
    hbs = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "HEARTBEAT"]
    assert len(hbs) == 3 and all(m.get_srcSystem() == 7 for m in hbs)


def test_gcs_heartbeat_is_not_taken_for_an_autopilot() -> None:
    ep = CompanionEndpoint(now_us=T0)
    gcs = MavlinkCodec(255, 190)
    ev = ep.receive_data(gcs.encode(d.MAVLink_heartbeat_message(d.MAV_TYPE_GCS, 8, 0, 0, 4, 3)), T0)
    assert ev == [] and ep.autopilot is None


def test_message_intervals_one_at_a_time_retried_and_acked() -> None:
    ep, ap = connected()
    ep.poll(T0)
    cmds = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert len(cmds) == 1
    assert cmds[0].command == d.MAV_CMD_SET_MESSAGE_INTERVAL
    assert cmds[0].param1 == d.MAVLINK_MSG_ID_ATTITUDE and cmds[0].param2 == pytest.approx(20_000)
    assert (cmds[0].target_system, cmds[0].target_component) == (7, 1)
    ep.poll(T0 + 1_100_000)  # no ACK: sent again
    again = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert len(again) == 1 and again[0].param1 == d.MAVLINK_MSG_ID_ATTITUDE
    assert ep.stats["request retries"] == 1
    ack = ap.codec.encode(
        d.MAVLink_command_ack_message(d.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0, 0, 7, 191)
    )
    ep.receive_data(ack, T0 + 1_150_000)
    ep.poll(T0 + 1_150_001)
    nxt = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert nxt[0].param1 == d.MAVLINK_MSG_ID_LOCAL_POSITION_NED and nxt[0].param2 == pytest.approx(
        100_000
    )


def test_quaternion_refused_falls_back_to_euler() -> None:
    ep, ap = connected(attitude_message="ATTITUDE_QUATERNION")
    ep.poll(T0)
    (cmd,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert cmd.param1 == d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
    nak = d.MAVLink_command_ack_message(
        d.MAV_CMD_SET_MESSAGE_INTERVAL, d.MAV_RESULT_DENIED, 0, 0, 7, 191
    )
    ep.receive_data(ap.codec.encode(nak), T0 + 10_000)
    ep.poll(T0 + 10_001)
    (cmd,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_LONG"]
    assert cmd.param1 == d.MAVLINK_MSG_ID_ATTITUDE


def test_telemetry_events_and_filtering() -> None:
    ep, ap = connected()
    ev = ep.receive_data(ap.attitude(BOOT0_MS, roll=0.2), T0 + 5000)
    assert len(ev) == 1 and isinstance(ev[0], TelemetryReceived)
    assert ev[0].sample.time_boot_us == BOOT0_MS * 1000 and ev[0].sample.recv_us == T0 + 5000
    other = Autopilot(sysid=9)
    assert ep.receive_data(other.attitude(BOOT0_MS + 20), T0 + 6000) == []
    assert ep.stats["telemetry from another system"] == 1
    # A NaN attitude is not a sample, but the daemon hears that it came (input invalid).
    assert ep.receive_data(ap.attitude(BOOT0_MS + 40, roll=math.nan), T0 + 7000) == [
        TelemetryRejected("attitude", "ATTITUDE out of range")
    ]
    assert ep.stats["bad attitude"] == 1


def test_autopilot_reboot_and_loss() -> None:
    ep, ap = connected()
    ep.receive_data(ap.attitude(BOOT0_MS), T0)
    ev = ep.receive_data(ap.attitude(1200), T0 + 20_000)  # boot clock back at 1.2 s
    assert any(isinstance(e, AutopilotRebooted) for e in ev)
    assert any(isinstance(e, TelemetryReceived) for e in ev)
    ev = ep.poll(T0 + 6_000_000)  # no heartbeat for 6 s
    assert any(isinstance(e, AutopilotLost) for e in ev)
    ev = ep.receive_data(ap.hb(), T0 + 7_000_000)
    assert any(isinstance(e, AutopilotFound) for e in ev)


def test_timesync_offset_within_a_millisecond_with_jittery_latency() -> None:
    ep, ap = connected()
    rng = random.Random(1)
    now = T0
    offset_us = T0 - BOOT0_MS * 1000  # companion - autopilot boot
    for _ in range(60):
        now += 100_000
        ep.poll(now)
        for m in ap.receive(ep.data_to_send()):
            if m.get_type() == "TIMESYNC" and m.tc1 == 0:
                up, down = rng.uniform(0, 2000), rng.uniform(0, 2000)  # µs, jittery
                t_ap_us = m.ts1 / 1000 + up - offset_us
                reply = ap.codec.encode(d.MAVLink_timesync_message(int(t_ap_us * 1000), m.ts1))
                ep.receive_data(reply, int(m.ts1 / 1000 + up + down))
    assert ep.timesync.synced
    assert abs(ep.timesync.offset_us - offset_us) < 1000
    # A reboot (offset jump) restarts the filter instead of being averaged in.
    ep.timesync.add_reply(now, 5_000_000, now + 1000)
    assert ep.timesync.resets == 1


def test_answers_the_autopilots_timesync_request() -> None:
    ep, ap = connected()
    ep.receive_data(ap.codec.encode(d.MAVLink_timesync_message(0, 123_456)), T0 + 10)
    (reply,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "TIMESYNC"]
    assert reply.ts1 == 123_456 and reply.tc1 == (T0 + 10) * 1000


def test_parameter_protocol() -> None:
    ep, ap = connected()
    gcs = MavlinkCodec(255, 190)
    ep.receive_data(gcs.encode(d.MAVLink_param_request_list_message(7, 191)), T0)
    values = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "PARAM_VALUE"]
    assert len(values) == values[0].param_count >= 10
    assert [v.param_id for v in values] == [p.name for p in PARAMS]
    assert {v.param_id for v in values} >= {"TCM_THRESH", "TCM_EGO_SRC", "TCM_TTC_ALARM"}
    ev = ep.receive_data(
        gcs.encode(d.MAVLink_param_set_message(7, 191, b"TCM_THRESH", 0.12, 9)), T0 + 1
    )
    assert ev == [ParamChanged("TCM_THRESH", pytest.approx(0.12))]
    (echo,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "PARAM_VALUE"]
    assert echo.param_id == "TCM_THRESH" and echo.param_value == pytest.approx(0.12)
    # Out of range: refused, the current value is sent back, a warning goes out.
    ev = ep.receive_data(
        gcs.encode(d.MAVLink_param_set_message(7, 191, b"TCM_EGO_SRC", 400, 9)), T0 + 2
    )
    assert ev == [] and ep.stats["parameter refused"] == 1
    (echo,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "PARAM_VALUE"]
    assert echo.param_id == "TCM_EGO_SRC" and echo.param_value == 2
    ep.receive_data(
        gcs.encode(d.MAVLink_param_request_read_message(7, 191, b"TCM_TTC_ALARM", -1)), T0 + 3
    )
    (read,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "PARAM_VALUE"]
    assert read.param_id == "TCM_TTC_ALARM" and read.param_value == 3.0
    # Not for us: ignored.
    ep.receive_data(gcs.encode(d.MAVLink_param_request_list_message(7, 1)), T0 + 4)
    assert [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "PARAM_VALUE"] == []


def test_commands_are_acknowledged() -> None:
    ep, ap = connected()
    gcs = MavlinkCodec(255, 190)
    unknown = d.MAVLink_command_long_message(7, 191, d.MAV_CMD_DO_SET_MODE, 0, 1, 0, 0, 0, 0, 0, 0)
    ep.receive_data(gcs.encode(unknown), T0)
    (ack,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "COMMAND_ACK"]
    assert ack.result == d.MAV_RESULT_UNSUPPORTED and (ack.target_system, ack.target_component) == (
        255,
        190,
    )
    req = d.MAVLink_command_long_message(
        7, 191, d.MAV_CMD_REQUEST_MESSAGE, 0, d.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH, 0, 0, 0, 0, 0, 0
    )
    ep.receive_data(gcs.encode(req), T0 + 1)
    ep.poll(T0 + 2)
    got = ap.receive(ep.data_to_send())
    assert [m.result for m in got if m.get_type() == "COMMAND_ACK"] == [d.MAV_RESULT_ACCEPTED]
    assert any(m.get_type() == "TCM_PIPELINE_HEALTH" for m in got)


def obj(
    track: int, state: str, az_deg: float, collision: bool = False, ttc: float = math.nan
) -> ObjectResult:
    b = bearing_from_azel(np.radians(az_deg), 0.0)
    c = Classification(state, "", disparity=0.3 if state == "moving" else 0.01, range_m=4.0)  # type: ignore[arg-type]
    return ObjectResult(
        track,
        True,
        state,
        "",
        b,
        b,
        b,
        math.radians(az_deg),
        0.0,
        0.09,
        (0.0, 0.0),
        c,
        ttc,
        collision,
        math.nan,  # type: ignore[arg-type]
    )


def frame(objects: list[ObjectResult], t_us: int) -> FrameResult:
    return FrameResult(0, t_us, tuple(objects), True, None, {})


def test_frame_outputs_and_obstacle_distance() -> None:
    ep, ap = connected()
    ep.receive_data(ap.attitude(BOOT0_MS), T0)
    gcs = MavlinkCodec(255, 190)
    ep.receive_data(gcs.encode(d.MAVLink_param_set_message(7, 191, b"TCM_OUT_OBST", 1, 9)), T0)
    ap.receive(ep.data_to_send())
    ep.send_frame(
        frame([obj(3, "moving", 30.0), obj(4, "stationary", -90.0)], T0 + 1000), T0 + 2000
    )
    st = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "TCM_OBJECT_STATUS"]
    assert [(m.track_id, m.state) for m in st] == [(3, 2), (4, 1)]
    assert st[0].azimuth == pytest.approx(math.radians(30.0), abs=1e-6)
    assert st[0].time_boot_ms == pytest.approx(BOOT0_MS + 1, abs=2)
    assert math.isnan(st[0].range) is False and st[1].range == pytest.approx(4.0)
    ep.poll(T0 + 100_000)
    (od,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "OBSTACLE_DISTANCE"]
    assert od.frame == d.MAV_FRAME_BODY_FRD and len(od.distances) == 72
    left = od.distances[(360 - 90) // 5]
    assert left < od.max_distance and od.distances[10] == od.max_distance + 1
    ep.poll(T0 + 2_000_000)  # frames stale: no "all clear" is claimed
    assert [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "OBSTACLE_DISTANCE"] == []


def test_obstacle_distance_merges_every_fresh_cameras_objects() -> None:
    """A rig: each camera's frame carries its own objects; OBSTACLE_DISTANCE covers all
    of them (one camera's frame does not erase the sectors of another), and drops a
    camera's once its frames are stale."""
    ep, ap = connected()
    ep.receive_data(ap.attitude(BOOT0_MS), T0)
    gcs = MavlinkCodec(255, 190)
    ep.receive_data(gcs.encode(d.MAVLink_param_set_message(7, 191, b"TCM_OUT_OBST", 1, 9)), T0)
    ap.receive(ep.data_to_send())
    ep.send_frame(frame([obj(3, "stationary", 0.0)], T0 + 1000), T0 + 2000, camera_id=0)
    ep.send_frame(frame([obj(4, "stationary", 90.0)], T0 + 1000), T0 + 3000, camera_id=1)
    ep.poll(T0 + 100_000)
    (od,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "OBSTACLE_DISTANCE"]
    ahead, right = od.distances[0], od.distances[90 // 5]
    assert ahead < od.max_distance and right < od.max_distance
    # The front camera goes quiet; the right one goes on: its object alone remains.
    ep.send_frame(frame([obj(4, "stationary", 90.0)], T0 + 590_000), T0 + 600_000, camera_id=1)
    ep.poll(T0 + 610_000)
    (od,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "OBSTACLE_DISTANCE"]
    assert od.distances[0] == od.max_distance + 1 and od.distances[90 // 5] < od.max_distance


def test_collision_alarm_statustext_is_rate_limited() -> None:
    ep, ap = connected()
    for k in range(5):
        ep.send_frame(frame([obj(3, "moving", 0.0, collision=True, ttc=1.5)], T0 + k), T0 + k)
    for k in range(5):
        ep.poll(T0 + k * 300_000)
    texts = [m.text for m in ap.receive(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    alarms = [t for t in texts if "collision" in t]
    assert len(alarms) == 1 and "collision course track 3" in alarms[0]
    # one condition that holds: announced once, the later frames are not even new texts
    assert ep.stats["statustext suppressed"] == 0 and len(ep.statustexts_queued) == 2


def test_collision_statustext_once_per_condition_whatever_the_ttc() -> None:
    # Seen on real ArduPilot: 504 "TCM: collision course ..." texts in ~2 minutes, because
    # each carried a new TTC and the limit was per text. Now one per condition.
    ep, ap = connected()
    texts: list[str] = []
    t = T0
    for k in range(25 * 20):  # 20 s at 25 Hz, the TTC changing every frame
        t = T0 + k * 40_000
        ttc = 2.9 - 0.003 * (k % 400)
        ep.send_frame(frame([obj(1, "unknown", 0.0, collision=True, ttc=ttc)], t), t)
        ep.poll(t)
        texts += [m.text for m in ap.receive(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    alarms = [x for x in texts if "collision course" in x]
    assert len(alarms) == 1, alarms
    # the condition clears after 2 s without an alarm; a new one (after the repeat time)
    # is announced again, and a second track is a condition of its own
    t += 11_000_000
    ep.send_frame(
        frame(
            [
                obj(1, "unknown", 0.0, collision=True, ttc=1.0),
                obj(2, "moving", 40.0, collision=True, ttc=2.0),
            ],
            t,
        ),
        t,
    )
    for k in range(10):
        ep.poll(t + k * 300_000)
    later = [m.text for m in ap.receive(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    assert sorted(x.split(",")[0] for x in later if "collision" in x) == [
        "TCM: collision course track 1",
        "TCM: collision course track 2",
    ]


def test_status_carries_ttc_confidence_independent_of_state() -> None:
    # Head-on: no TCM state (unknown, confidence 0) but a confident time to contact.
    ep, ap = connected()
    ep.receive_data(ap.attitude(BOOT0_MS), T0)
    head_on = replace(
        obj(5, "moving", 0.0, collision=True, ttc=1.8),
        state="unknown",
        reason="head-on",
        ttc_confidence=0.83,
    )
    still = replace(obj(6, "stationary", 90.0), ttc_confidence=0.9)  # no ttc: 0
    ep.send_frame(frame([head_on, still], T0 + 1000), T0 + 2000)
    got = ap.receive(ep.data_to_send())
    st = {m.track_id: m for m in got if m.get_type() == "TCM_OBJECT_STATUS"}
    assert (
        st[5].state == d.TCM_OBJECT_STATE_UNKNOWN and st[5].reason == d.TCM_UNKNOWN_REASON_HEAD_ON
    )
    assert st[5].confidence == 0 and st[5].ttc_confidence == 83
    assert st[5].collision_course == 1 and st[5].ttc == pytest.approx(1.8)
    assert st[6].ttc_confidence == 0 and st[6].confidence > 0
    ep.send_health_now(T0 + 3000)
    (h,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "TCM_PIPELINE_HEALTH"]
    assert h.protocol == 2


def test_signing_rejects_unsigned_and_wrong_key() -> None:
    key = bytes(range(32))
    ep = CompanionEndpoint(now_us=T0, signing=SigningConfig(key))
    good, bad = Autopilot(key=key), Autopilot(key=bytes(32))
    plain = Autopilot()
    assert ep.receive_data(plain.hb(), T0) == [] and ep.codec.stats["unsigned rejected"] == 1
    assert ep.receive_data(bad.codec.encode(_hb(), T0), T0) == []
    assert ep.codec.stats["bad signature"] == 1
    ev = ep.receive_data(good.codec.encode(_hb(), T0 + 10), T0 + 10)
    assert isinstance(ev[0], AutopilotFound)
    ep.poll(T0 + 20)
    out = ep.data_to_send()
    assert good.receive(out) and all(m.get_signed() for m in good.inbox)


def _hb():  # type: ignore[no-untyped-def]
    return d.MAVLink_heartbeat_message(
        d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )


# A longer run is one command: TCM_FUZZ_EXAMPLES=100000 pytest tests/test_endpoint.py -k fuzz
@pytest.mark.slow  # over a second of CPU
@settings(max_examples=int(os.environ.get("TCM_FUZZ_EXAMPLES", "200")), deadline=None)
@given(junk=st.lists(st.binary(max_size=300), max_size=20), seed=st.integers(0, 1000))
def test_fuzz_receive_path_never_raises_and_keeps_working(junk: list[bytes], seed: int) -> None:
    ep, ap = connected()
    rng = random.Random(seed)
    frames = [ap.attitude(BOOT0_MS + 20 * k) for k in range(5)]
    for chunk in junk:
        if rng.random() < 0.3:  # corrupt a real frame into the stream
            f = bytearray(rng.choice(frames))
            f[rng.randrange(len(f))] ^= 1 << rng.randrange(8)
            chunk = bytes(f) + chunk
        ep.receive_data(chunk, T0 + 1000)
        ep.poll(T0 + 1000)
    # After the garbage, clean frames still decode (the buffer resynchronised). Garbage
    # may end in a plausible header whose "frame" (at most 280 bytes) swallows the next
    # bytes until it fails its CRC, so send more than that: 12 frames of 28 bytes.
    ev = ep.receive_data(
        b"".join(ap.attitude(BOOT0_MS + 10_000 + 20 * k) for k in range(12)), T0 + 2000
    )
    assert sum(isinstance(e, TelemetryReceived) for e in ev) >= 2


def test_flood_is_bounded() -> None:
    ep, _ = connected()
    ep.receive_data(b"\xfd\xff" + b"\x00" * 200_000, T0)
    assert len(ep.codec._rx) <= ep.codec.max_buffer
    assert ep.codec.stats["garbage bytes"] + ep.codec.stats["bad header"] == 200_002


def test_forged_frame_cannot_lock_out_the_real_sender() -> None:
    key = bytes(range(32))
    ep = CompanionEndpoint(now_us=T0, signing=SigningConfig(key))
    forger, good = Autopilot(key=bytes(32)), Autopilot(key=key)
    now = 1_700_000_000_000_000
    forged = forger.codec.encode(_hb(), now + 3_600_000_000)  # an hour in the future
    assert ep.receive_data(forged, now) == []
    ev = ep.receive_data(good.codec.encode(_hb(), now), now)
    assert ev and isinstance(ev[0], AutopilotFound)


def test_a_large_chunk_of_good_frames_is_parsed_whole() -> None:
    ep, ap = connected()
    chunk = b"".join(ap.attitude(BOOT0_MS + k) for k in range(3000))  # ~117 KiB
    assert len(chunk) > ep.codec.max_buffer
    ev = ep.receive_data(chunk, T0 + 10)
    assert sum(isinstance(e, TelemetryReceived) for e in ev) == 3000
    assert ep.codec.stats["overflow bytes dropped"] == 0


def test_truncated_frames_complete_across_reads() -> None:
    ep, ap = connected()
    frame = ap.attitude(BOOT0_MS)
    assert ep.receive_data(frame[:7], T0) == []
    ev = ep.receive_data(frame[7:], T0 + 1)
    assert len(ev) == 1 and isinstance(ev[0], TelemetryReceived)


def test_bad_crc_and_unknown_id_are_counted_and_skipped() -> None:
    ep, ap = connected()
    good = ap.attitude(BOOT0_MS)
    bad = bytearray(good)
    bad[-1] ^= 0x55
    unknown = bytearray(ap.attitude(BOOT0_MS + 20))
    unknown[7:10] = (60_123).to_bytes(3, "little")  # an id no dialect of ours knows
    ev = ep.receive_data(bytes(bad) + bytes(unknown) + good, T0)
    assert len(ev) == 1
    assert ep.codec.stats["bad CRC"] >= 1 and ep.codec.stats["unknown message id"] >= 1


def test_out_of_range_attitude_and_position_are_refused() -> None:
    ep, ap = connected()
    silly = ap.codec.encode(d.MAVLink_attitude_message(BOOT0_MS, 50.0, 0.0, 0.0, 0, 0, 0))
    assert ep.receive_data(silly, T0) == [TelemetryRejected("attitude", "ATTITUDE out of range")]
    assert ep.stats["bad attitude"] == 1
    nan_pos = ap.codec.encode(
        d.MAVLink_local_position_ned_message(BOOT0_MS, math.nan, 0, 0, 0, 0, 0)
    )
    assert ep.receive_data(nan_pos, T0) == [
        TelemetryRejected("position", "LOCAL_POSITION_NED not finite")
    ]
    assert ep.stats["bad position"] == 1


def test_time_going_backwards_is_harmless() -> None:
    ep, ap = connected(now=T0 + 10_000_000)
    ep.poll(T0 + 10_000_000)
    ep.data_to_send()
    ep.poll(T0)  # the caller's clock stepped back
    ev = ep.receive_data(ap.attitude(BOOT0_MS), T0 - 5_000_000)
    assert any(isinstance(e, TelemetryReceived) for e in ev)
    ep.poll(T0 + 11_000_000)
    assert ap.receive(ep.data_to_send())  # still talking


def test_statustext_on_connect_and_long_texts_are_chunked() -> None:
    ep, ap = connected()
    ep.poll(T0)
    texts = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    assert [t.text for t in texts] == ["TCM companion online"]
    ep.statustext(d.MAV_SEVERITY_WARNING, "x" * 120, T0 + 1_000_000)
    ep.poll(T0 + 1_000_000)
    chunks = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "STATUSTEXT"]
    assert (
        len(chunks) == 3
        and len({c.id for c in chunks}) == 1
        and [c.chunk_seq for c in chunks] == [0, 1, 2]
    )


def test_mavlink_ftp_requests_are_nakked_at_once() -> None:
    ep, ap = connected()
    gcs = MavlinkCodec(255, 190)
    req = bytearray(251)
    req[0], req[3] = 41, 4  # seq 41, OpenFileRO
    ep.receive_data(gcs.encode(d.MAVLink_file_transfer_protocol_message(0, 7, 191, list(req))), T0)
    (nak,) = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "FILE_TRANSFER_PROTOCOL"]
    p = bytes(nak.payload)
    assert (nak.target_system, nak.target_component) == (255, 190)
    assert p[0] == 42 and p[3] == 129 and p[5] == 4 and p[12] == 7


def test_float_parameters_keep_their_decimal_value() -> None:
    ep, _ = connected()
    gcs = MavlinkCodec(255, 190)
    ev = ep.receive_data(
        gcs.encode(d.MAVLink_param_set_message(7, 191, b"TCM_THRESH", 0.12, 9)), T0
    )
    assert ev[0].value == 0.12  # not 0.11999999731779099


# -- the endpoint's pieces and single sources -------------------------------------------------
def test_telemetry_is_judged_by_the_rule_replay_uses() -> None:
    """The endpoint's TelemetryReceived / TelemetryRejected and the replay readers'
    sample_from_message come from one function: they accept the same messages."""
    ep, ap = connected()
    quat = d.MAVLink_attitude_quaternion_message
    cases = [
        d.MAVLink_attitude_message(BOOT0_MS, 0.2, -0.1, 3.0, 0, 0, 0),
        d.MAVLink_attitude_message(BOOT0_MS + 1, 50.0, 0.0, 0.0, 0, 0, 0),  # not an angle
        d.MAVLink_attitude_message(BOOT0_MS + 2, math.nan, 0.0, 0.0, 0, 0, 0),
        quat(BOOT0_MS + 3, 1.0, 0.0, 0.0, 0.0, 0, 0, 0, [0.0] * 4),
        quat(BOOT0_MS + 4, 0.5, 0.0, 0.0, 0.0, 0, 0, 0, [0.0] * 4),  # not unit
        d.MAVLink_local_position_ned_message(BOOT0_MS + 5, 1.0, 2.0, -3.0, 0, 0, 0),
        d.MAVLink_local_position_ned_message(BOOT0_MS + 6, 1.0, math.inf, -3.0, 0, 0, 0),
    ]
    accepted = []
    for k, msg in enumerate(cases):
        frame = ap.codec.encode(msg)
        (ev,) = ep.receive_data(frame, T0 + k)
        (decoded,) = MavlinkCodec(1, 2).feed(frame)
        parsed = parse_telemetry(decoded, T0 + k)
        if isinstance(parsed, Rejected):
            assert ev == TelemetryRejected(parsed.kind, parsed.reason)
            assert sample_from_message(decoded, T0 + k) is None
        else:
            assert isinstance(ev, TelemetryReceived) and parsed is not None
            assert ev.sample.time_boot_us == parsed.time_boot_us
            accepted.append(k)
    assert accepted == [0, 3, 5]
    assert ep.stats["bad attitude"] == 3 and ep.stats["bad position"] == 1


def test_timesync_freshness_is_one_rule() -> None:
    """The health flag, the time base and boot_ms all switch at FRESH_US after the last
    TIMESYNC reply, together."""
    ep, _ = connected()
    ep.timesync.add_reply(T0, int((T0 - 100_000_000) * 1000), T0 + 1000)  # offset 100 s
    t_reply = T0 + 1000

    def health_flags(now: int) -> int:
        ep.send_health_now(now)
        (h,) = [m for m in Autopilot().receive(ep.data_to_send()) if m.get_srcComponent() == 191]
        return int(h.health)

    before, after = t_reply + FRESH_US - 1, t_reply + FRESH_US
    assert ep.timesync.fresh(before) and not ep.timesync.fresh(after)
    assert ep.has_time_base(before) and ep.boot_ms(before, before) > 0
    assert not health_flags(before) & d.TCM_HEALTH_TIMESYNC_LOST
    assert not ep.has_time_base(after) and ep.boot_ms(after, after) == 0  # no telemetry fit
    assert health_flags(after) & d.TCM_HEALTH_TIMESYNC_LOST


def test_stream_requests_on_their_own() -> None:
    stats: Counter[str] = Counter()
    att, pos = d.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, d.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    req = StreamRequests([(att, 50.0), (pos, 10.0)], 1_000_000, 3_000_000, stats, T0)
    first = req.poll(T0, (7, 1))
    assert (first.param1, first.target_system) == (att, 7)
    assert req.poll(T0 + 10, (7, 1)) is None  # one at a time
    req.on_ack(d.MAV_RESULT_DENIED, T0 + 20)  # no quaternions here: Euler instead
    assert req.poll(T0 + 20, (7, 1)).param1 == d.MAVLINK_MSG_ID_ATTITUDE
    req.on_ack(d.MAV_RESULT_ACCEPTED, T0 + 30)
    assert req.poll(T0 + 30, (7, 1)).param1 == pos
    req.on_ack(d.MAV_RESULT_ACCEPTED, T0 + 40)
    assert req.poll(T0 + 40, (7, 1)) is None  # all acknowledged
    for _ in range(200):  # attitude arrives at 50 Hz, position never
        req.received(d.MAVLINK_MSG_ID_ATTITUDE)
    assert req.poll(T0 + 4_000_000, (7, 1)) is None  # rates checked ...
    assert stats["streams re-requested"] == 1  # ... position asked for again
    assert req.poll(T0 + 5_000_000, (7, 1)).param1 == pos


def test_statustext_condition_table_stays_bounded() -> None:
    ep, _ = connected()
    t = T0
    for k in range(5000):  # a new condition every 10 ms, drained as fast as allowed
        t += 10_000
        ep.statustext(d.MAV_SEVERITY_INFO, f"condition {k}", t)
        ep.poll(t)
        assert ep.statustexts.conditions <= 256
    assert ep.stats["statustext dropped"] > 0  # the queue is bounded too
    q = StatustextQueue(0, 10_000_000, 100, Counter(), T0, max_conditions=8)
    for k in range(50):  # within the repeat time: the oldest conditions give way
        assert q.queue(d.MAV_SEVERITY_INFO, f"c{k}", T0 + k)
        q.poll(T0 + k)
        assert q.conditions <= 8
    assert not q.queue(d.MAV_SEVERITY_INFO, "c49", T0 + 60)  # a recent one still counts


def test_collision_conditions_on_their_own() -> None:
    cc = CollisionConditions(clear_us=2_000_000)
    alarm = obj(1, "moving", 0.0, collision=True, ttc=1.0)
    far = obj(2, "moving", 0.0, collision=True, ttc=9.0)
    assert cc.update([alarm, far], 3.0, T0) == [alarm]
    assert cc.update([alarm], 3.0, T0 + 1_000_000) == []  # the same condition
    assert cc.update([], 3.0, T0 + 3_500_000) == []  # cleared
    assert cc.update([alarm], 3.0, T0 + 3_600_000) == [alarm]  # a new one
    assert cc.update([alarm], 0.0, T0 + 3_700_000) == []  # alarms off


def test_health_waits_for_the_autopilots_clock() -> None:
    # A TCM_PIPELINE_HEALTH with time_boot_ms 0 reads as ancient to the autopilot: with an
    # autopilot connected, none goes out before its clock is known (TIMESYNC or telemetry).
    ep, ap = connected()
    for k in range(5):
        ep.poll(T0 + k * 500_000)
    early = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "TCM_PIPELINE_HEALTH"]
    assert early == []
    for k in range(10):  # attitude at 50 Hz: the telemetry clock fit becomes ready
        ep.receive_data(ap.attitude(BOOT0_MS + 20 * k), T0 + 2_500_000 + 20_000 * k)
    for k in range(3):
        ep.poll(T0 + 3_000_000 + k * 500_000)
    health = [m for m in ap.receive(ep.data_to_send()) if m.get_type() == "TCM_PIPELINE_HEALTH"]
    assert health and all(h.time_boot_ms > 0 for h in health)


def test_health_without_an_autopilot_still_goes_out() -> None:
    ep = CompanionEndpoint(now_us=T0)  # a ground station alone on the link
    ep.poll(T0)
    gcs = MavlinkCodec(255, 190)
    assert [m for m in gcs.feed(ep.data_to_send()) if m.get_type() == "TCM_PIPELINE_HEALTH"]
