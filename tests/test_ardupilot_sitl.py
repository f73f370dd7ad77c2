"""Facts about ArduCopter measured against the real firmware (ArduPilot's SITL binary).

One SITL instance is shared by the module (booted once, ~4.5 s); the tests run in file order
but each brings the vehicle into the state it needs (proximity data flowing, flying), so any
one of them can run alone. Like every real-time test they are in the xdist group "sitl", so
under ``-n 2 --dist loadgroup`` they run on one worker, one at a time (pytest is held below 9:
pytest 9 ignores the node ids pytest-xdist 3.8 rewrites for groups). Skipped with a one-line
reason when the binary is absent (``$TCM_ARDUPILOT_SITL`` or ``../shared/ardupilot-sitl``).
The numbers quoted in the docstrings were measured on a 2-core x86-64 machine (ArduCopter
V4.8.0-dev, 1b34668c).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Iterator

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from tcm_companion.mavlink.copter_modes import COPTER_MODES
from tcm_companion.mavlink.gcs import Message
from tcm_companion.sitl.ardupilot_process import skip_reason
from tcm_companion.sitl.ardupilot_vehicle import ArduPilotSitl
from tcm_companion.sitl.gcs import GcsClient

SKIP_REASON = skip_reason()
pytestmark = [
    pytest.mark.skipif(bool(SKIP_REASON), reason=SKIP_REASON or "ArduCopter SITL present"),
    pytest.mark.xdist_group("sitl"),  # real time: one at a time
    pytest.mark.timeout(120),
]

PARAMS = {
    "SCR_ENABLE": 1,  # Lua
    "PRX1_TYPE": 2,  # proximity from MAVLink OBSTACLE_DISTANCE
    "ADSB_TYPE": 1,  # uAvionix-MAVLink: ADSB_VEHICLE in
    "AVD_ENABLE": 1,  # AP_Avoidance on ADS-B threats
}

#: reports facts about the firmware's Lua numbers as STATUSTEXT "LF <key>=<value>", then "LF done"
LUA_FACTS = r"""
local facts = {}
local function add(key, f)
  local ok, v = pcall(f)
  facts[#facts + 1] = key .. "=" .. (ok and tostring(v) or ("ERR " .. tostring(v)))
end
add("maxint", function() return math.maxinteger end)
add("type1", function() return math.type(1) end)
add("u4ff", function() local v = string.unpack("<I4", "\255\255\255\255"); return tostring(v) .. " " .. math.type(v) end)
add("u4top", function() return string.unpack("<I4", "\0\0\0\128") end)
add("i8big", function() return string.unpack("<i8", "\0\0\0\0\0\1\0\0") end)
add("i8one", function() return string.unpack("<i8", "\1\0\0\0\0\0\0\0") end)
add("u8u32max", function() return string.unpack("<I8", "\255\255\255\255\0\0\0\0") end)
add("f32", function() return 16777217.0 == 16777216.0 end)
add("fmt", function() return string.format("%.3f", 0.1 + 0.2) end)
add("tenth", function() return string.format("%.12f", 0.1) end)
add("wrap", function() return math.maxinteger + 1 end)
add("lit2p31", function() local v = 2147483648; return math.type(v) end)
add("millis", function() return math.type(millis():toint()) .. " " .. type(millis()) end)
add("u32max", function() return tostring(uint32_t(4294967295)) end)
add("u32neg1", function() return tostring(uint32_t(-1)) end)
local i = 0
local function update()
  i = i + 1
  if i > #facts then
    gcs:send_text(6, "LF done")
    return
  end
  gcs:send_text(6, "LF " .. facts[i])
  return update, 100
end
return update, 1000
"""

NO_OBSTACLE_CM = 3001  # max_distance + 1: "no obstacle" in a sector
ALL_CLEAR = [NO_OBSTACLE_CM] * 72
ONE_AHEAD = [1000] + [NO_OBSTACLE_CM] * 71  # 10 m straight ahead (sector 0)
ADSB_FLAGS = (
    mavlink2.ADSB_FLAGS_VALID_COORDS
    | mavlink2.ADSB_FLAGS_VALID_ALTITUDE
    | mavlink2.ADSB_FLAGS_VALID_HEADING
    | mavlink2.ADSB_FLAGS_VALID_VELOCITY
    | mavlink2.ADSB_FLAGS_VALID_CALLSIGN
)
M_PER_DEG_LAT = 111_319.5


@pytest.fixture(scope="module")
def sitl(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ArduPilotSitl]:
    workdir = tmp_path_factory.mktemp("ardupilot-sitl")  # kept by pytest: console log, logs/
    with ArduPilotSitl(
        params=PARAMS, script_texts={"tcm_lua_facts.lua": LUA_FACTS}, workdir=workdir
    ) as s:
        yield s


@pytest.fixture(scope="module")
def companion(sitl: ArduPilotSitl) -> GcsClient:
    """A companion on SERIAL1 as (1, 191), HEARTBEAT MAV_TYPE_ONBOARD_CONTROLLER at 1 Hz."""
    return sitl.connect(1, name="companion")


def _obstacle_distance(client: GcsClient, distances_cm: list[int]) -> Callable[[], Message]:
    def build() -> Message:
        return client.mav.obstacle_distance_encode(
            int(time.monotonic() * 1e6),
            mavlink2.MAV_DISTANCE_SENSOR_LASER,
            distances_cm,
            5,  # increment, deg
            20,  # min_distance, cm
            3000,  # max_distance, cm
            0.0,
            0.0,
            mavlink2.MAV_FRAME_BODY_FRD,
        )

    return build


def _proximity_all_clear(sitl: ArduPilotSitl, companion: GcsClient) -> None:
    """OBSTACLE_DISTANCE "nothing near" at 10 Hz (arming needs it: "PreArm: PRX1: No Data")."""
    companion.set_periodic("obstacle_distance", 10.0, _obstacle_distance(companion, ALL_CLEAR))
    sitl.gcs.wait_for(sitl.proximity_healthy, 3.0, "proximity healthy")


def _lpn(sitl: ArduPilotSitl) -> Message:
    """The last LOCAL_POSITION_NED (there is one once the SITL has started)."""
    lpn = sitl.local_position_ned()
    assert lpn is not None
    return lpn


def _latest(sitl: ArduPilotSitl, msg_type: str) -> Message:
    rec = sitl.gcs.latest(msg_type, (1, 1))
    assert rec is not None, f"no {msg_type} from (1, 1)"
    return rec.msg


def _speed_m_s(sitl: ArduPilotSitl) -> float:
    lpn = _lpn(sitl)
    return math.hypot(lpn.vx, lpn.vy)


def _ensure_flying(sitl: ArduPilotSitl, companion: GcsClient, alt_m: float = 5.0) -> None:
    _proximity_all_clear(sitl, companion)
    lpn = sitl.local_position_ned()
    if not sitl.gcs.armed or lpn is None or -lpn.z < alt_m - 1.0:
        sitl.takeoff(alt_m)
    else:
        sitl.set_mode("GUIDED")


def test_boot_gps_and_real_time(sitl: ArduPilotSitl) -> None:
    """Boot to EKF-uses-GPS ~4.5 s wall (SERIAL0 accept 0.05 s, heartbeat 0.05-0.25 s, GPS
    ~4.0 s at --speedup 10); afterwards SIM_SPEEDUP = 1 and time_boot_ms advances 1.000 s per
    wall second."""
    timings = sitl.boot_timings_s
    print("boot timings (s):", {k: round(v, 3) for k, v in timings.items()})
    assert timings["total"] < 30.0
    hb = sitl.gcs.latest("HEARTBEAT", (1, 1))
    assert hb is not None
    assert hb.msg.type == mavlink2.MAV_TYPE_QUADROTOR
    assert hb.msg.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert sitl.ekf_uses_gps()
    assert sitl.gcs.get_param("SIM_SPEEDUP") == 1.0

    lpn0 = _lpn(sitl)
    wall0 = time.monotonic()
    time.sleep(2.0)
    lpn1 = _lpn(sitl)
    wall1 = time.monotonic()
    ratio = (lpn1.time_boot_ms - lpn0.time_boot_ms) / 1000.0 / (wall1 - wall0)
    print(f"time_boot_ms per wall second: {ratio:.3f}")
    assert 0.9 < ratio < 1.1, sitl.failure_report()


def test_lua_numbers_are_float32_with_32bit_integers(sitl: ArduPilotSitl) -> None:
    """ArduPilot's Lua: 32-bit integers and 32-bit float numbers (LUA_32BITS)."""
    sitl.gcs.wait_statustext(r"^LF done$", 15.0, since_s=0.0)
    facts = {}
    for st in sitl.gcs.statustexts():
        match = re.match(r"^LF (\w+)=(.*)$", st.text)
        if match:
            facts[match[1]] = match[2]
    print("Lua facts:", facts)
    assert facts["maxint"] == "2147483647"
    assert facts["type1"] == "integer"
    # uint32 0xFFFFFFFF does not raise: it wraps to -1 (add 2^32 as a float to decode it)
    assert facts["u4ff"] == "-1 integer"
    assert facts["u4top"] == "-2147483648"
    assert facts["i8big"].startswith("ERR ")
    assert facts["i8big"].endswith("8-byte integer does not fit into Lua Integer")
    assert facts["i8one"] == "1"
    # unsigned 8 bytes with zero high half "fit" and wrap too: 2^32-1 -> -1
    assert facts["u8u32max"] == "-1"
    # numbers are float32: 2^24 + 1 == 2^24, 0.1 is 0.100000001490...
    assert facts["f32"] == "true"
    assert facts["tenth"] == "0.100000001490"
    assert facts["fmt"] == "0.300"
    assert facts["wrap"] == "-2147483648"
    assert facts["lit2p31"] == "float"
    assert facts["millis"] == "integer userdata"
    # 4294967295 as a float32 literal is 2^32, which uint32_t() wraps to 0
    assert facts["u32max"] == "0"
    assert facts["u32neg1"] == "4294967295"
    assert not [s.text for s in sitl.gcs.statustexts() if s.text.startswith("Lua:")]


def test_late_clients_and_heartbeat_routing(sitl: ArduPilotSitl, companion: GcsClient) -> None:
    """SERIAL1/SERIAL2 accept clients after boot; heartbeats of other components are routed."""
    camera = sitl.connect(
        2,
        source_system=1,
        source_component=mavlink2.MAV_COMP_ID_CAMERA,
        heartbeat_type=mavlink2.MAV_TYPE_CAMERA,
        name="camera",
    )
    camera.wait_message("HEARTBEAT", 3.0, src=(1, 1), since_s=0.0)
    companion.wait_message("HEARTBEAT", 3.0, src=(1, 1), since_s=0.0)
    sitl.gcs.wait_message(
        "HEARTBEAT", 3.0, src=(1, mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER), since_s=0.0
    )
    sitl.gcs.wait_message("HEARTBEAT", 3.0, src=(1, mavlink2.MAV_COMP_ID_CAMERA), since_s=0.0)
    companion.wait_message("HEARTBEAT", 3.0, src=(255, 190), since_s=0.0)
    companion.wait_message("HEARTBEAT", 3.0, src=(1, mavlink2.MAV_COMP_ID_CAMERA), since_s=0.0)
    camera.close()


def test_sim_state_and_simstate(sitl: ArduPilotSitl) -> None:
    """SET_MESSAGE_INTERVAL for SIM_STATE (108) and SIMSTATE (164) is ACCEPTED; both come from
    (1, 1) with the simulator's truth and no timestamp field."""
    gps = _latest(sitl, "GLOBAL_POSITION_INT")
    for msg_id in (mavlink2.MAVLINK_MSG_ID_SIM_STATE, mavlink2.MAVLINK_MSG_ID_SIMSTATE):
        assert sitl.gcs.set_message_interval(msg_id, 5.0) == mavlink2.MAV_RESULT_ACCEPTED
    try:
        sim_state = sitl.gcs.wait_message("SIM_STATE", 2.0, src=(1, 1)).msg
        simstate = sitl.gcs.wait_message("SIMSTATE", 2.0, src=(1, 1)).msg
    finally:
        for msg_id in (mavlink2.MAVLINK_MSG_ID_SIM_STATE, mavlink2.MAVLINK_MSG_ID_SIMSTATE):
            sitl.gcs.set_message_interval(msg_id, 0)
    print("SIM_STATE:", sim_state.to_dict())
    print("SIMSTATE:", simstate.to_dict())
    for msg in (sim_state, simstate):
        assert not [f for f in msg.get_fieldnames() if "time" in f]
    assert abs(sim_state.lat_int - gps.lat) < 100  # degE7, ~1 m
    assert abs(simstate.lat - gps.lat) < 100
    assert abs(sim_state.alt - gps.alt / 1000.0) < 2.0  # m AMSL
    assert math.isclose(math.hypot(sim_state.q1, sim_state.q4), 1.0, abs_tol=0.05)


def test_proximity_health_follows_obstacle_distance(
    sitl: ArduPilotSitl, companion: GcsClient
) -> None:
    """OBSTACLE_DISTANCE (BODY_FRD, 72 x 5 deg, 10 Hz) from (1, 191) on SERIAL1 with PRX1_TYPE 2:
    SYS_STATUS bit MAV_SYS_STATUS_SENSOR_PROXIMITY (0x4000000) is present and enabled
    throughout, healthy ~0.05 s after the first message and unhealthy ~0.5 s after the last;
    DISTANCE_SENSOR (orientation = 45 deg sector) only for sectors with an obstacle."""
    companion.clear_periodic("obstacle_distance")
    assert sitl.gcs.set_message_interval("SYS_STATUS", 20.0) == mavlink2.MAV_RESULT_ACCEPTED
    assert sitl.gcs.set_message_interval("DISTANCE_SENSOR", 10.0) == mavlink2.MAV_RESULT_ACCEPTED
    try:
        sitl.gcs.wait_for(lambda: sitl.proximity_healthy() is False, 3.0, "proximity unhealthy")
        status = _latest(sitl, "SYS_STATUS")
        bit = mavlink2.MAV_SYS_STATUS_SENSOR_PROXIMITY
        assert status.onboard_control_sensors_present & bit
        assert status.onboard_control_sensors_enabled & bit

        t_first = time.monotonic()
        companion.set_periodic("obstacle_distance", 10.0, _obstacle_distance(companion, ONE_AHEAD))
        sitl.gcs.wait_for(sitl.proximity_healthy, 2.0, "proximity healthy")
        to_healthy_s = time.monotonic() - t_first
        sensor = sitl.gcs.wait_message(
            "DISTANCE_SENSOR", 2.0, lambda m: m.current_distance == 1000, src=(1, 1)
        ).msg
        time.sleep(0.5)
        sectors = {r.msg.orientation for r in sitl.gcs.messages("DISTANCE_SENSOR", t_first)}
        routed = sitl.gcs.messages("OBSTACLE_DISTANCE", t_first, src=(1, 191))

        t_last = time.monotonic()
        companion.clear_periodic("obstacle_distance")
        sitl.gcs.wait_for(lambda: sitl.proximity_healthy() is False, 3.0, "proximity unhealthy")
        to_unhealthy_s = time.monotonic() - t_last
    finally:
        _proximity_all_clear(sitl, companion)
        sitl.gcs.set_message_interval("SYS_STATUS", 5.0)
        sitl.gcs.set_message_interval("DISTANCE_SENSOR", 0)
    print(f"proximity healthy after {to_healthy_s:.3f} s, unhealthy {to_unhealthy_s:.3f} s after")
    print("DISTANCE_SENSOR:", sensor.to_dict(), "sectors", sectors, "routed", len(routed))
    assert to_healthy_s < 1.0
    assert 0.2 < to_unhealthy_s < 1.5
    assert sensor.orientation == mavlink2.MAV_SENSOR_ROTATION_NONE
    assert (sensor.min_distance, sensor.max_distance) in {(19, 3000), (20, 3000)}
    assert sectors == {mavlink2.MAV_SENSOR_ROTATION_NONE}
    assert routed, "OBSTACLE_DISTANCE from (1, 191) is routed to the ground station"


def test_guided_takeoff_velocity_and_brake(sitl: ArduPilotSitl, companion: GcsClient) -> None:
    """GUIDED takeoff to 5 m (~6.5 s incl. arming), north at 2 m/s by velocity set-points
    (reached in ~1.4 s), BRAKE by set_mode: below 0.5 m/s in ~1.5 s, 0.1 m/s in ~4 s."""
    _proximity_all_clear(sitl, companion)
    t0 = time.monotonic()
    if not sitl.gcs.armed:
        sitl.takeoff(5.0)
    else:
        sitl.set_mode("GUIDED")
    takeoff_s = time.monotonic() - t0
    start = _lpn(sitl)

    t0 = time.monotonic()
    sitl.fly_velocity(2.0, 0.0, 0.0)
    sitl.gcs.wait_for(lambda: _lpn(sitl).vx > 1.8, 6.0, "north at 2 m/s")
    accel_s = time.monotonic() - t0
    time.sleep(2.0)
    cruise = _lpn(sitl)
    assert cruise.vx == pytest.approx(2.0, abs=0.3)
    assert abs(cruise.vy) < 0.3
    assert cruise.x - start.x > 3.0
    assert sitl.gcs.mode == COPTER_MODES["GUIDED"]

    sitl.stop_velocity()
    t0 = time.monotonic()
    sitl.set_mode("BRAKE")
    mode_s = time.monotonic() - t0
    sitl.gcs.wait_for(lambda: _speed_m_s(sitl) < 0.5, 5.0, "below 0.5 m/s")
    slow_s = time.monotonic() - t0
    sitl.gcs.wait_for(lambda: _speed_m_s(sitl) < 0.1, 8.0, "below 0.1 m/s")
    stop_s = time.monotonic() - t0
    stopped = _lpn(sitl)
    print(
        f"takeoff {takeoff_s:.2f} s; 2 m/s after {accel_s:.2f} s; BRAKE mode in {mode_s:.3f} s,"
        f" < 0.5 m/s after {slow_s:.2f} s, < 0.1 m/s after {stop_s:.2f} s,"
        f" {stopped.x - cruise.x:.2f} m after the command"
    )
    assert sitl.gcs.mode == COPTER_MODES["BRAKE"]
    assert [c.name for c in sitl.gcs.mode_changes()][-2:] == ["GUIDED", "BRAKE"]
    assert -stopped.z == pytest.approx(5.0, abs=1.0)


def test_adsb_vehicle_drives_ap_avoidance(sitl: ArduPilotSitl, companion: GcsClient) -> None:
    """ADSB_VEHICLE from (1, 191) on a collision course (ADSB_TYPE 1, AVD_ENABLE 1), hovering
    in GUIDED at 5 m:

    - AVD_F_ACTION 2 (climb or descend): AVOID_ADSB (19) ~0.1 s after the first message; it
      holds altitude (it would descend, but not below RTL_ALT_M); COLLISION (id = ICAO,
      threat HIGH, action 2) from (1, 1) ~1 Hz on every link. A tiny ICAO (1) is accepted.
    - the messages stop: recovery (AVD_F_RCVRY 1: back to GUIDED) ~5 s after the last.
    - AVD_F_ACTION 1 (report, the default): COLLISION only (action 0), ~0.1 s after the first
      message; no mode change. ICAO 0x7C0001 / callsign TCM0001 accepted.
    - no STATUSTEXT about any of it; the companion's ADSB_VEHICLE is not routed to the ground
      station, ArduPilot re-sends its own list from (1, 1) (when asked for ADSB_VEHICLE).
    """
    _ensure_flying(sitl, companion)
    sitl.gcs.set_param("AVD_F_ACTION", mavlink2.MAV_COLLISION_ACTION_REPORT)
    sitl.gcs.set_param("AVD_F_RCVRY", 1)  # resume the previous mode
    assert sitl.gcs.set_message_interval("ADSB_VEHICLE", 5.0) == mavlink2.MAV_RESULT_ACCEPTED
    gps = _latest(sitl, "GLOBAL_POSITION_INT")

    def threat(icao: int, callsign: str, north_m: float, speed_m_s: float) -> Callable[[], Message]:
        """Due north of the vehicle at its altitude, flying south towards it."""
        t_start = time.monotonic()

        def build() -> Message:
            north = north_m - speed_m_s * (time.monotonic() - t_start)
            return companion.mav.adsb_vehicle_encode(
                icao,
                gps.lat + round(north / M_PER_DEG_LAT * 1e7),
                gps.lon,
                mavlink2.ADSB_ALTITUDE_TYPE_GEOMETRIC,
                gps.alt,  # mm AMSL, the vehicle's
                18000,  # heading, cdeg: south
                round(speed_m_s * 100),  # cm/s
                0,
                callsign.encode(),
                mavlink2.ADSB_EMITTER_TYPE_UAV,
                0,  # tslc, s
                ADSB_FLAGS,
                0,
            )

        return build

    try:
        # 1. act (climb or descend), a tiny ICAO address
        sitl.gcs.set_param("AVD_F_ACTION", mavlink2.MAV_COLLISION_ACTION_ASCEND_OR_DESCEND)
        t_a = time.monotonic()
        companion.set_periodic("adsb", 5.0, threat(1, "TCM0001", 80.0, 5.0))
        sitl.gcs.wait_for(lambda: sitl.gcs.mode == COPTER_MODES["AVOID_ADSB"], 3.0, "AVOID_ADSB")
        avoid_s = time.monotonic() - t_a
        acting = sitl.gcs.wait_message(
            "COLLISION",
            3.0,
            lambda m: m.id == 1 and m.action == mavlink2.MAV_COLLISION_ACTION_ASCEND_OR_DESCEND,
            since_s=t_a,
        )
        assert (acting.msg.get_srcSystem(), acting.msg.get_srcComponent()) == (1, 1)
        assert acting.msg.src == mavlink2.MAV_COLLISION_SRC_ADSB
        assert acting.msg.threat_level == mavlink2.MAV_COLLISION_THREAT_LEVEL_HIGH
        time.sleep(1.0)
        hover = _lpn(sitl)

        # 2. the threat goes away
        t_b = time.monotonic()
        companion.clear_periodic("adsb")
        sitl.gcs.wait_for(
            lambda: sitl.gcs.mode == COPTER_MODES["GUIDED"], 12.0, "recovery to GUIDED"
        )
        recovery_s = time.monotonic() - t_b

        # 3. report only; our ICAO / callsign format
        sitl.gcs.set_param("AVD_F_ACTION", mavlink2.MAV_COLLISION_ACTION_REPORT)
        t_c = time.monotonic()
        companion.set_periodic("adsb", 5.0, threat(0x7C0001, "TCM0001", 80.0, 5.0))
        report = sitl.gcs.wait_message("COLLISION", 2.0, lambda m: m.id == 0x7C0001, since_s=t_c)
        report_s = report.t_s - t_c
        relisted = sitl.gcs.wait_message(
            "ADSB_VEHICLE", 3.0, lambda m: m.ICAO_address == 0x7C0001, since_s=t_c, src=(1, 1)
        ).msg
        time.sleep(1.0)
        mode_after_report = sitl.gcs.mode
    finally:
        companion.clear_periodic("adsb")
        sitl.gcs.set_param("AVD_F_ACTION", mavlink2.MAV_COLLISION_ACTION_REPORT)
        sitl.gcs.set_message_interval("ADSB_VEHICLE", 0)
    texts = [s.text for s in sitl.gcs.statustexts(t_a)]
    routed = sitl.gcs.messages("ADSB_VEHICLE", t_a, src=(1, 191))
    collisions = sitl.gcs.messages("COLLISION", t_a)
    print(
        f"AVOID_ADSB {avoid_s:.2f} s after the first ADSB_VEHICLE; back to GUIDED "
        f"{recovery_s:.2f} s after the last; report-only COLLISION after {report_s:.2f} s; "
        f"{len(collisions)} COLLISION in {time.monotonic() - t_a:.1f} s; STATUSTEXT {texts}; "
        f"acting {acting.msg.to_dict()}; report {report.msg.to_dict()}; relisted "
        f"{relisted.to_dict()}"
    )
    assert avoid_s < 1.0
    assert math.hypot(hover.vx, hover.vy) < 0.5 and abs(hover.vz) < 0.3
    assert 3.0 < recovery_s < 10.0
    assert report_s < 1.5  # COLLISION goes out at most once a second per threat
    assert report.msg.action == mavlink2.MAV_COLLISION_ACTION_NONE
    assert report.msg.threat_level == mavlink2.MAV_COLLISION_THREAT_LEVEL_HIGH
    assert mode_after_report == COPTER_MODES["GUIDED"]
    assert relisted.callsign == "TCM0001"
    assert not routed, "ArduPilot does not route the companion's ADSB_VEHICLE"
    assert not [t for t in texts if re.search(r"(?i)adsb|avoid|collision|threat", t)]
    assert [c.name for c in sitl.gcs.mode_changes()][-2:] == ["AVOID_ADSB", "GUIDED"]
