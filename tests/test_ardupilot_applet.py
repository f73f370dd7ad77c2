"""The applet (tools/ardupilot/tcm_avoid.lua) inside the real firmware, fed hand-made frames.

ArduCopter SITL (ArduPilot's own build: 32-bit Lua, its scripting bindings, its MAVLink
routing) loads the applet from ``scripts/``; a companion link on SERIAL1, as (1, 191),
sends frames from OUR encoder. The daemon-driven flights are in
tests/test_ardupilot_flight.py. Skipped with a one-line reason when the binary is absent.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec
from tcm_companion.sitl.ardupilot_process import skip_reason
from tcm_companion.sitl.ardupilot_vehicle import ArduPilotSitl
from tcm_companion.sitl.gcs import GcsClient

ROOT = Path(__file__).resolve().parents[1]
APPLET = ROOT / "tools" / "ardupilot" / "tcm_avoid.lua"
SKIP_REASON = skip_reason()
pytestmark = [
    pytest.mark.skipif(bool(SKIP_REASON), reason=SKIP_REASON or "ArduCopter SITL present"),
    pytest.mark.xdist_group("sitl"),  # real time: one at a time (see tests/test_daemon.py)
    pytest.mark.timeout(120),
]


@pytest.fixture(scope="module")
def sitl() -> Iterator[ArduPilotSitl]:
    with ArduPilotSitl(params={"SCR_ENABLE": 1}, scripts=[APPLET]) as s:
        yield s


@pytest.fixture(scope="module")
def companion(sitl: ArduPilotSitl) -> GcsClient:
    return sitl.connect(1)  # (1, 191), heartbeats as an onboard controller


def _boot_ms(sitl: ArduPilotSitl) -> int:
    boot = sitl.gcs.autopilot_boot_ms(time.monotonic())
    assert boot is not None, "no time-stamped message from the autopilot"
    return boot


def _health(boot_ms: int, offset_us: int) -> d.MAVLink_tcm_pipeline_health_message:
    return d.MAVLink_tcm_pipeline_health_message(
        time_boot_ms=boot_ms & 0xFFFFFFFF,
        frame_rate=25.0,
        latency=6.0,
        frames_dropped=0,
        egomotion_source=d.TCM_EGOMOTION_SOURCE_FUSED,
        egomotion_quality=100,
        health=0,
        objects=1,
        log_state=d.TCM_LOG_STATE_RECORDING,
        timesync_offset_us=offset_us,
        timesync_rtt_us=4400,
        protocol=2,
    )


def _alarm(boot_ms: int, **kw: float) -> d.MAVLink_tcm_object_status_message:
    v: dict[str, float] = dict(
        time_boot_ms=boot_ms & 0xFFFFFFFF,
        track_id=7,
        camera_id=0,
        state=d.TCM_OBJECT_STATE_UNKNOWN,
        reason=d.TCM_UNKNOWN_REASON_HEAD_ON,
        disparity=math.nan,
        threshold=0.09,
        ttc=1.5,
        collision_course=1,
        azimuth=0.0,
        elevation=0.0,
        angular_radius=0.05,
        range=math.nan,
        confidence=0,
        ttc_confidence=90,
    )
    v.update(kw)
    return d.MAVLink_tcm_object_status_message(**v)  # type: ignore[arg-type]


def test_applet_loads_with_its_parameters(sitl: ArduPilotSitl) -> None:
    sitl.gcs.wait_statustext(r"^TCM: avoid applet loaded", 10.0, since_s=0.0)
    assert sitl.gcs.get_param("TCMA_ACTION") == 1.0  # warn, by default
    assert sitl.gcs.get_param("TCMA_TTC_CLR") == pytest.approx(4.5)
    assert sitl.gcs.get_param("TCMA_HOLD_MS") == 2000.0


@pytest.mark.parametrize("hours", [2.2, -5.0])
def test_applet_survives_hour_scale_clock_offset(
    sitl: ArduPilotSitl, companion: GcsClient, hours: float
) -> None:
    # On this firmware the old applet died 0.15 s after loading: "8-byte integer does not
    # fit into Lua Integer", on the first TCM_PIPELINE_HEALTH of a companion booted more
    # than ~36 min apart from the autopilot (its int64 timesync_offset_us past 2^31).
    codec = MavlinkCodec(1, 191)
    t0 = time.monotonic()
    offset_us = int(hours * 3600e6)
    for k in range(6):  # 3 s at 2 Hz, the offset drifting a little
        companion.send_bytes(codec.encode(_health(_boot_ms(sitl), offset_us + 37 * k)))
        time.sleep(0.5)
    # still running and decoding: an alarm on the ground (disarmed) is a warning text
    companion.send_bytes(codec.encode(_alarm(_boot_ms(sitl))))
    warn = sitl.gcs.wait_statustext(r"^TCM: collision course id 7 ttc 1\.5s$", 3.0, since_s=t0)
    lua_errors = [t.text for t in sitl.gcs.statustexts(t0) if t.text.startswith("Lua")]
    assert lua_errors == []
    assert warn.t_s > t0


def test_ground_station_sees_companion_data_flowing(
    sitl: ArduPilotSitl, companion: GcsClient
) -> None:
    # the applet's NAMED_VALUE_FLOATs reach the ground station's link from the autopilot
    codec = MavlinkCodec(1, 191)
    t0 = time.monotonic()
    for _ in range(8):
        companion.send_bytes(codec.encode(_health(_boot_ms(sitl), 0)))
        time.sleep(0.25)
    rx = sitl.gcs.wait_message(
        "NAMED_VALUE_FLOAT",
        3.0,
        lambda m: m.name == "TCM_RX" and m.value >= 1.0,
        since_s=t0,
        src=(1, 1),
    )
    assert 1.0 <= rx.msg.value <= 6.0  # health at 4 Hz
    names = {m.msg.name for m in sitl.gcs.messages("NAMED_VALUE_FLOAT", since_s=t0)}
    assert {"TCM_RX", "TCM_OBJ", "TCM_TTC", "TCM_ALARM"} <= names


def test_a_burst_of_statuses_does_not_exceed_the_vm_budget(
    sitl: ArduPilotSitl, companion: GcsClient
) -> None:
    """Seen in the flights on a loaded machine: "Lua: ./scripts/tcm_avoid.lua exceeded
    time limit", the applet removed, no BRAKE. ArduPilot stops a script whose call runs
    more than SCR_VM_I_COUNT (10000) VM instructions, and the applet read up to 20 queued
    messages a call at ~1,500 each. A burst of 20 statuses (eight tracked objects and a
    late scheduling slot make one) reached it at once here; it must read them over
    several calls and still warn of the alarm that follows."""
    codec = MavlinkCodec(1, 191)
    t0 = time.monotonic()
    burst = b"".join(
        codec.encode(_alarm(_boot_ms(sitl), track_id=20 + i, collision_course=0, ttc=math.nan))
        for i in range(20)
    )
    companion.send_bytes(burst)
    time.sleep(1.0)
    assert [t.text for t in sitl.gcs.statustexts(t0) if t.text.startswith("Lua")] == []
    companion.send_bytes(codec.encode(_alarm(_boot_ms(sitl), track_id=9)))
    warn = sitl.gcs.wait_statustext(r"^TCM: collision course id 9 ttc 1\.5s$", 3.0, since_s=t0)
    assert warn.t_s > t0
