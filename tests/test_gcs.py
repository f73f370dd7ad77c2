"""The ground-station side, sans-IO: what it sends when, and what it makes of what it hears."""

from __future__ import annotations

import socket
import threading

from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec
from tcm_companion.mavlink.copter_modes import COPTER_MODES
from tcm_companion.mavlink.gcs import GroundStation, message_id
from tcm_companion.mavlink.statustext import statustext_messages
from tcm_companion.sitl.gcs import GcsClient


def _copter_heartbeat(ap: MavlinkCodec, mode: str, armed: bool) -> bytes:
    base = d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (d.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return ap.encode(
        ap.mav.heartbeat_encode(
            d.MAV_TYPE_QUADROTOR,
            d.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            COPTER_MODES[mode],
            d.MAV_STATE_ACTIVE,
        )
    )


def test_heartbeat_and_periodic_senders_keep_their_rate_without_bursts() -> None:
    gs = GroundStation(now_s=100.0)
    ap = MavlinkCodec(1, 1)
    sent = [m for t in (100.0, 100.5, 101.0) for m in ap.feed(b"".join(gs.poll(t)))]
    assert [m.get_type() for m in sent] == ["HEARTBEAT", "HEARTBEAT"]
    assert (sent[0].get_srcSystem(), sent[0].get_srcComponent(), sent[0].type) == (
        255,
        d.MAV_COMP_ID_MISSIONPLANNER,
        d.MAV_TYPE_GCS,
    )
    gs.set_periodic("ping", 10.0, lambda: gs.mav.system_time_encode(0, gs.time_boot_ms(101.0)))
    assert len(gs.poll(101.01)) == 1  # the first one at the next poll
    assert gs.next_deadline_s(101.02) <= 101.11
    assert len(gs.poll(105.0)) == 2  # after a stall: one ping and one heartbeat, no burst
    gs.clear_periodic("ping")
    assert [ap.feed(f)[0].get_type() for f in gs.poll(106.0)] == ["HEARTBEAT"]
    assert message_id("SYSTEM_TIME") == d.MAVLINK_MSG_ID_SYSTEM_TIME


def test_records_the_targets_modes_and_whole_statustexts() -> None:
    gs = GroundStation(heartbeat_type=None)
    ap, other = MavlinkCodec(1, 1), MavlinkCodec(1, 191)
    gs.receive_data(_copter_heartbeat(ap, "GUIDED", armed=False), 1.0)
    gs.receive_data(_copter_heartbeat(other, "BRAKE", armed=True), 1.5)  # not the target
    gs.receive_data(_copter_heartbeat(ap, "GUIDED", armed=True), 2.0)
    gs.receive_data(_copter_heartbeat(ap, "BRAKE", armed=True), 3.0)
    chunks = statustext_messages(d.MAV_SEVERITY_INFO, "EKF3 IMU0 is using GPS " * 4, 7_000)
    data = b"".join(ap.encode(m) for m in chunks)
    gs.receive_data(data[:40], 4.0)  # a frame split between reads
    gs.receive_data(data[40:], 4.1)
    assert [(c.t_s, c.name, c.previous) for c in gs.mode_changes()] == [
        (1.0, "GUIDED", None),
        (3.0, "BRAKE", COPTER_MODES["GUIDED"]),
    ]
    assert (gs.mode, gs.armed, len(gs.heartbeats())) == (COPTER_MODES["BRAKE"], True, 3)
    assert set(gs.heartbeat_sources()) == {(1, 1), (1, 191)}
    [text] = gs.statustexts()
    assert (text.text, text.src_component) == ("EKF3 IMU0 is using GPS " * 4, 1)
    assert gs.count("STATUSTEXT") == len(chunks) and gs.statustexts(since_s=4.2) == []
    assert gs.first_message("HEARTBEAT", 1.2, src=(1, 1)).t_s == 2.0
    assert gs.latest("HEARTBEAT").t_s == 3.0 and gs.latest("HEARTBEAT", (1, 191)).t_s == 1.5
    assert len(gs.messages("HEARTBEAT", since_s=1.5)) == 3 and gs.bad_data == 0


def test_the_gcs_client_commands_an_autopilot_over_udp_and_ends_its_thread() -> None:
    """GcsClient end to end on a real transport: heartbeat out, the autopilot's mode in,
    a command answered by its COMMAND_ACK; close() ends the link's thread."""
    ap = MavlinkCodec(1, 1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(5.0)
        port = sock.getsockname()[1]
        with GcsClient(f"udpout:127.0.0.1:{port}", name="gcs under test") as gcs:
            data, peer = sock.recvfrom(4096)
            assert [m.get_type() for m in ap.feed(data)] == ["HEARTBEAT"]
            sock.sendto(_copter_heartbeat(ap, "GUIDED", armed=True), peer)
            gcs.wait_for(lambda: gcs.mode == COPTER_MODES["GUIDED"], 5.0, "GUIDED")

            def autopilot() -> None:  # answers the first COMMAND_LONG
                while True:
                    for msg in ap.feed(sock.recvfrom(4096)[0]):
                        if msg.get_type() == "COMMAND_LONG":
                            ack = ap.mav.command_ack_encode(msg.command, d.MAV_RESULT_ACCEPTED)
                            sock.sendto(ap.encode(ack), peer)
                            return

            answering = threading.Thread(target=autopilot)
            answering.start()
            assert gcs.set_message_interval("ATTITUDE", 10.0) == d.MAV_RESULT_ACCEPTED
            answering.join(5.0)
            assert gcs.armed is True and gcs.dropped_sends == 0
    assert not [t for t in threading.enumerate() if t.name == "mavlink gcs under test"]
