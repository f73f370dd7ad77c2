"""The ArduPilot Lua applet (tools/ardupilot/tcm_avoid.lua) fed with frames from OUR encoder.

Runs the applet with the fake bindings of tools/ardupilot/harness.lua under every Lua
there is: Debian's ``lua5.4`` (64-bit integers and doubles; skipped when missing:
``apt-get install -y lua5.4``) and a Lua 5.4 built with 32-bit integers and floats, as
ArduPilot builds it (``tools/ardupilot/build_lua32.py``, ``make lua32``). Both must do
exactly the same; only the 32-bit one shows what kills a script on the firmware. Each
test writes a command script (state, parameters, wire frames as hex, simulated time) and
checks what the applet did: STATUSTEXTs, mode changes, proximity pushes, decoded fields.
The real firmware runs it in tests/test_ardupilot_applet.py.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec

ROOT = Path(__file__).resolve().parents[1]
APPLET = ROOT / "tools" / "ardupilot" / "tcm_avoid.lua"
HARNESS = ROOT / "tools" / "ardupilot" / "harness.lua"
LUA = shutil.which("lua5.4")
LUA32 = next(
    (
        p
        for p in (
            os.environ.get("TCM_LUA32"),
            str(ROOT / ".venv" / "bin" / "lua5.4-32"),
            shutil.which("lua5.4-32"),
        )
        if p and Path(p).is_file()
    ),
    None,
)
LUAS = [p for p in (LUA32, LUA) if p is not None]

pytestmark = [
    pytest.mark.skipif(
        not LUAS,
        reason="no Lua: apt-get install -y lua5.4, and make lua32 (ArduPilot's 32-bit Lua)",
    ),
    pytest.mark.slow,  # the applet runs in a Lua interpreter, a subprocess per test
]


def need_lua32() -> str:
    """The 32-bit Lua; CI must have it (``make lua32``), elsewhere its tests skip."""
    if LUA32 is None:
        if os.environ.get("CI"):
            pytest.fail("no 32-bit Lua in CI: make lua32 (tools/ardupilot/build_lua32.py)")
        pytest.skip("no 32-bit Lua (make lua32 builds ArduPilot's kind)")
    return LUA32


NAN = float("nan")
BRAKE, LOITER, RTL, AUTO, GUIDED, STABILIZE, LAND, ALT_HOLD, POSHOLD = 17, 5, 6, 3, 4, 0, 9, 2, 16


@dataclass
class Result:
    lines: list[str]
    by_lua: dict[str, list[str]] = field(default_factory=dict)  # every interpreter's lines

    @property
    def texts(self) -> list[str]:
        out = []
        for line in self.lines:
            m = re.match(r'TEXT (\d+) (\d+) "(.*)"$', line)
            if m:
                out.append(m.group(3))
        return out

    def texts_with(self, part: str) -> list[str]:
        return [t for t in self.texts if part in t]

    @property
    def set_modes(self) -> list[int]:
        return [int(line.split()[2]) for line in self.lines if line.startswith("SET_MODE")]

    @property
    def fields(self) -> list[dict]:
        return [json.loads(line[7:]) for line in self.lines if line.startswith("FIELDS ")]

    @property
    def stats(self) -> dict:
        return [json.loads(line[6:]) for line in self.lines if line.startswith("STATS ")][-1]

    @property
    def prx(self) -> list[list[float]]:
        return [
            [float(x) for x in line.split()[2:5]] for line in self.lines if line.startswith("PRX ")
        ]


@dataclass
class Scenario:
    """A command script for the harness; ``now`` tracks the harness clock (ms since boot)."""

    sysid: int = 1
    compid: int = 191
    now: int = 10000
    cmds: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.codec = MavlinkCodec(self.sysid, self.compid)

    def vehicle(self, armed: bool = True, flying: bool = True, mode: int = AUTO) -> Scenario:
        self.cmds += [f"armed {int(armed)}", f"flying {int(flying)}", f"mode {mode}"]
        return self

    def param(self, name: str, value: float | str) -> Scenario:
        self.cmds.append(f"param {name} {value}")
        return self

    def cmd(self, text: str) -> Scenario:
        self.cmds.append(text)
        return self

    def frame(self, data: bytes, rx_age_ms: int = 0) -> Scenario:
        self.cmds.append(f"frame {data.hex()} {rx_age_ms}")
        return self

    def status_msg(self, **kw) -> d.MAVLink_tcm_object_status_message:
        age = kw.pop("age_ms", 0)
        v = dict(
            time_boot_ms=self.now - age,
            track_id=7,
            camera_id=0,
            state=2,
            reason=0,
            disparity=0.3,
            threshold=0.09,
            ttc=1.5,
            collision_course=1,
            azimuth=0.1,
            elevation=-0.05,
            angular_radius=0.02,
            range=NAN,
            confidence=90,
            ttc_confidence=85,
        )
        v.update(kw)
        return d.MAVLink_tcm_object_status_message(**v)

    def status(self, codec: MavlinkCodec | None = None, mutate=None, **kw) -> Scenario:
        data = (codec or self.codec).encode(self.status_msg(**kw))
        return self.frame(mutate(data) if mutate else data)

    def health(self, health: int = 0, **kw) -> Scenario:
        v = dict(
            time_boot_ms=self.now,
            frame_rate=25.0,
            latency=12.5,
            frames_dropped=3,
            egomotion_source=3,
            egomotion_quality=88,
            health=health,
            objects=1,
            log_state=1,
            timesync_offset_us=-123456789012,
            timesync_rtt_us=5400,
            protocol=2,
        )
        v.update(kw)
        return self.frame(self.codec.encode(d.MAVLink_tcm_pipeline_health_message(**v)))

    def run(self, ms: int) -> Scenario:
        self.cmds.append(f"run {ms}")
        self.now += ms
        return self

    def stream(self, ms: int, period: int = 40, **kw) -> Scenario:
        """Statuses every ``period`` ms for ``ms`` ms (a tracked object at 25 Hz)."""
        for _ in range(ms // period):
            self.status(**kw)
            self.run(period)
        return self

    def execute(self, luas: list[str] | None = None) -> Result:
        """Run the script under every Lua (``luas``, default all there are); they must
        agree line for line (decoded fields to float32 precision). The result is the
        first's: the 32-bit one's when there is one."""
        script = "\n".join([*self.cmds, "stats"]) + "\n"
        by_lua: dict[str, list[str]] = {}
        for lua in luas or LUAS:
            proc = subprocess.run(
                [lua, str(HARNESS), str(APPLET)],
                input=script,
                capture_output=True,
                text=True,
                timeout=20,
                cwd=ROOT,
            )
            assert proc.returncode == 0, (lua, proc.stderr)
            lines = proc.stdout.splitlines()
            assert not [line for line in lines if line.startswith("ERROR")], (lua, lines)
            by_lua[lua] = lines
        first = next(iter(by_lua.values()))
        for lua in list(by_lua)[1:]:
            a = [x for x in first if not x.startswith("FIELDS ")]
            b = [x for x in by_lua[lua] if not x.startswith("FIELDS ")]
            assert a == b, f"{lua} disagrees with {next(iter(by_lua))}"
        return Result(first, by_lua)


def armed_scenario(action: int = 2, mode: int = AUTO) -> Scenario:
    return Scenario().vehicle(mode=mode).param("TCMA_ACTION", action)


# ---------------------------------------------------------------- constants
def _lua_const(name: str) -> str:
    m = re.search(rf"^local {name} = (.+)$", APPLET.read_text(), re.M)
    assert m, name
    return m.group(1).strip()


def _lua_list(name: str) -> list[str]:
    m = re.search(rf"local {name} = \{{(.*?)\}}", APPLET.read_text(), re.S)
    assert m, name
    return re.findall(r'"(\w+)"', m.group(1))


# ArduPilot's Lua has 32-bit integers: nothing may be read wider than 4 bytes, so an
# 8-byte integer is two fields, its low (unsigned) and high (signed) halves.
_PY_TO_LUA = {"I": "I4", "i": "i4", "H": "I2", "h": "i2", "B": "B", "b": "b"}
_PY_TO_LUA.update({"f": "f", "q": "I4i4", "Q": "I4I4"})


@pytest.mark.parametrize(
    "cls, suffix",
    [
        (d.MAVLink_tcm_object_status_message, "OBJECT_STATUS"),
        (d.MAVLink_tcm_pipeline_health_message, "PIPELINE_HEALTH"),
    ],
)
def test_lua_constants_match_generated_dialect(cls, suffix):
    assert int(_lua_const(f"MSGID_{suffix}")) == cls.id
    assert int(_lua_const(f"CRC_EXTRA_{suffix}")) == cls.crc_extra
    fmt = cls.native_format.decode()
    assert fmt[0] == "<"
    names = []
    for name, code in zip(cls.ordered_fieldnames, fmt[1:], strict=True):
        names += [f"{name}_lo", f"{name}_hi"] if code in "qQ" else [name]
    assert _lua_list(f"FIELDS_{suffix}") == names
    lua_fmt = "<" + "".join(_PY_TO_LUA[c] for c in fmt[1:])  # no "d", "i8": 32-bit Lua
    assert _lua_const(f"FMT_{suffix}") == f'"{lua_fmt}"'
    assert int(_lua_const(f"LEN_{suffix}")) == cls.unpacker.size


# ---------------------------------------------------------------- golden frames
def _pymavlink_fields(frame: bytes) -> dict:
    rx = MavlinkCodec(255, 190)
    (msg,) = rx.feed(frame)
    return {name: getattr(msg, name) for name in msg.ordered_fieldnames}


def _same(a, b) -> bool:
    if isinstance(a, float) and math.isnan(a):
        return b is None
    if isinstance(a, float):
        return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)
    return a == b


@pytest.mark.parametrize(
    "kw",
    [
        dict(ttc=1.25, range=12.5, confidence=77, state=1, reason=0, camera_id=2, track_id=65000),
        # trailing zero fields: MAVLink 2 trims them on the wire; Lua must zero-fill
        dict(
            ttc=NAN,
            collision_course=0,
            confidence=0,
            ttc_confidence=0,
            reason=0,
            state=0,
            azimuth=-3.0,
        ),
    ],
)
def test_golden_status_frame_decodes_the_same_in_python_and_lua(kw):
    s = Scenario().param("TCMA_MIN_CONF", 0).cmd("trace 1").run(10)
    frame = s.codec.encode(s.status_msg(**kw))
    if kw.get("confidence") == 0:
        assert frame[1] < d.MAVLink_tcm_object_status_message.unpacker.size  # truncated
    s.frame(frame).run(60)
    py = _pymavlink_fields(frame)
    for lua_name, lines in s.execute().by_lua.items():
        (lua,) = Result(lines).fields
        assert lua["kind"] == "status"
        for name, value in py.items():
            assert _same(value, lua[name]), (lua_name, name, value, lua[name])


def _health_msg(s: Scenario, offset_us: int, **kw) -> d.MAVLink_tcm_pipeline_health_message:
    v = dict(
        time_boot_ms=s.now,
        frame_rate=24.5,
        latency=17.25,
        frames_dropped=123456,
        egomotion_source=2,
        egomotion_quality=95,
        health=0x21,
        objects=3,
        log_state=1,
        timesync_offset_us=offset_us,
        timesync_rtt_us=65535,
        protocol=2,
    )
    v.update(kw)
    return d.MAVLink_tcm_pipeline_health_message(**v)


@pytest.mark.parametrize(
    "offset_us",
    [
        -987654321012,
        3_600_000_000 * 5 + 123,  # the companion booted 5 h before the autopilot
        -(2**31) - 1,  # just past what 32 bits hold
        2**31 - 1,
        0x7FFF_FFFF_FFFF_FFFF,
        -(2**63),
    ],
)
def test_golden_health_frame_decodes_the_same_in_python_and_lua(offset_us):
    s = Scenario().cmd("trace 1").run(10)
    frame = s.codec.encode(_health_msg(s, offset_us))
    s.frame(frame).run(60)
    py = _pymavlink_fields(frame)
    for lua_name, lines in s.execute().by_lua.items():
        (lua,) = Result(lines).fields
        assert lua["kind"] == "health"
        for name, value in py.items():
            if name == "timesync_offset_us":
                # read as two 32-bit halves; a float there (float32 in ArduPilot's Lua)
                assert lua[name] == pytest.approx(value, rel=1e-7), (lua_name, value, lua[name])
            else:
                assert _same(value, lua[name]), (lua_name, name, value, lua[name])


def test_applet_survives_hour_scale_clock_offset_in_32_bit_lua():
    # On real ArduPilot the applet died 0.15 s after loading: "tcm_avoid.lua:219: 8-byte
    # integer does not fit into Lua Integer", on the first TCM_PIPELINE_HEALTH of a
    # companion booted more than ~36 min apart from the autopilot.
    lua32 = need_lua32()
    s = armed_scenario(2).run(10)
    for k in range(10):  # 2 h 10 min apart, at 2 Hz, alongside a collision alarm
        s.frame(s.codec.encode(_health_msg(s, -7_800_000_000 - k * 1000, health=0))).run(250)
        s.status(ttc=2.0, ttc_confidence=90).run(250)
    r = s.execute([lua32])
    assert "STOPPED" not in r.lines
    assert r.stats["ok"] == 20 and r.set_modes == [BRAKE]


# ---------------------------------------------------------------- actions
@pytest.mark.parametrize(
    "action, mode, name", [(2, BRAKE, "BRAKE"), (3, LOITER, "LOITER"), (4, RTL, "RTL")]
)
def test_collision_course_switches_mode_per_parameter(action, mode, name):
    r = armed_scenario(action).stream(400).execute()
    assert r.set_modes == [mode]  # once per alarm episode
    (text,) = r.texts_with(f"-> {name}")
    assert "collision course id 7 ttc 1.5s" in text


@pytest.mark.parametrize("mode", [AUTO, GUIDED, LOITER, ALT_HOLD, POSHOLD, 7])  # 7 CIRCLE
def test_brake_from_every_actionable_mode(mode):
    assert armed_scenario(2, mode).stream(200).execute().set_modes == [BRAKE]


def test_warn_action_only_warns():
    r = armed_scenario(1).stream(400).execute()
    assert r.set_modes == []
    assert len(r.texts_with("collision course id 7")) == 1


def test_action_none_is_silent():
    r = armed_scenario(0).stream(400).execute()
    assert r.set_modes == [] and r.texts_with("collision") == []


def test_disabled_applet_ignores_everything():
    r = armed_scenario(2).param("TCMA_ENABLE", 0).stream(400).execute()
    assert r.set_modes == [] and r.texts_with("collision") == []


def _flip_payload_byte(b: bytes) -> bytes:
    x = bytearray(b)
    x[12] ^= 0x40
    return bytes(x)


@pytest.mark.parametrize(
    "why, kw, counter",
    [
        ("bad crc", dict(mutate=_flip_payload_byte), "bad_crc"),
        ("bad crc byte", dict(mutate=lambda b: b[:-1] + bytes([b[-1] ^ 1])), "bad_crc"),
        ("truncated", dict(mutate=lambda b: b[:20]), "bad_crc"),
        ("wrong system", dict(codec=MavlinkCodec(2, 191)), "bad_src"),
        ("wrong component", dict(codec=MavlinkCodec(1, 190)), "bad_src"),
        ("stale", dict(age_ms=2000), "stale"),
        ("from the future", dict(age_ms=-2000), "stale"),
        ("weak time to contact", dict(ttc_confidence=30), "low_conf"),
        ("MAVLink 1", dict(mutate=lambda b: b"\xfe" + b[1:]), "bad_magic"),
    ],
)
def test_rejected_frames_cause_no_action(why, kw, counter):
    r = armed_scenario(2).stream(400, **kw).execute()
    assert r.set_modes == [], why
    assert r.texts_with("collision") == [], why
    assert r.stats[counter] >= 10, (why, r.stats)
    # a frame that fails a check is dropped; weak evidence is a valid frame, no alarm
    assert r.stats["ok"] == (r.stats[counter] if counter == "low_conf" else 0)


def test_frame_waiting_too_long_in_the_queue_is_stale():
    s = armed_scenario(2).run(10)
    s.frame(s.codec.encode(s.status_msg()), rx_age_ms=1000).run(100)
    r = s.execute()
    assert r.set_modes == [] and r.stats["stale"] == 1


@pytest.mark.parametrize(
    "why, kw",
    [
        ("no collision course", dict(collision_course=0)),
        ("ttc above threshold", dict(ttc=4.0)),
        ("ttc unknown", dict(ttc=NAN)),
        ("ttc negative", dict(ttc=-1.0)),
    ],
)
def test_no_alarm_no_action(why, kw):
    r = armed_scenario(2).stream(400, **kw).execute()
    assert r.set_modes == [] and r.texts_with("collision") == [], why
    assert r.stats["ok"] >= 10


@pytest.mark.parametrize(
    "why, vehicle",
    [
        ("disarmed", dict(armed=False)),
        ("not flying", dict(flying=False)),
        ("STABILIZE (manual)", dict(mode=STABILIZE)),
        ("LAND", dict(mode=LAND)),
        ("RTL already", dict(mode=RTL)),
        ("BRAKE already", dict(mode=BRAKE)),
    ],
)
def test_unsafe_state_warns_without_mode_change(why, vehicle):
    r = Scenario().vehicle(**vehicle).param("TCMA_ACTION", 2).stream(400).execute()
    assert r.set_modes == [], why
    assert len(r.texts_with("collision course id 7")) == 1, why


def test_loiter_action_in_loiter_only_warns():
    r = armed_scenario(3, LOITER).stream(400).execute()
    assert r.set_modes == [] and len(r.texts_with("collision course")) == 1


def test_not_a_copter_only_warns():
    r = armed_scenario(2).cmd("fwtype 3").stream(400).execute()
    assert r.set_modes == [] and len(r.texts_with("collision course")) == 1


def test_refused_mode_change_is_announced():
    r = armed_scenario(2).cmd("setmode_ok 0").stream(400).execute()
    assert r.set_modes == [BRAKE]  # tried once per TXT_MS
    assert len(r.texts_with("mode change refused")) == 1


def test_companion_sysid_parameter():
    other = MavlinkCodec(5, 191)
    ok = armed_scenario(2).param("TCMA_SYSID", 5).stream(200, codec=other).execute()
    assert ok.set_modes == [BRAKE]
    own = armed_scenario(2).param("TCMA_SYSID", 5).stream(200).execute()
    assert own.set_modes == [] and own.stats["bad_src"] >= 5


def test_vehicle_system_id_from_mav_sysid_or_sysid_thismav():
    # ArduPilot 4.7+ names it MAV_SYSID; SYSID_THISMAV no longer exists there (nil)
    seven = MavlinkCodec(7, 191)
    r = armed_scenario(2).param("MAV_SYSID", 7).stream(200, codec=seven).execute()
    assert r.set_modes == [BRAKE]
    old = armed_scenario(2).param("MAV_SYSID", "nil").param("SYSID_THISMAV", 5)
    assert old.stream(200, codec=MavlinkCodec(5, 191)).execute().set_modes == [BRAKE]


def test_companion_compid_parameter():
    r = armed_scenario(2).param("TCMA_COMPID", 190).stream(200, codec=MavlinkCodec(1, 190))
    assert r.execute().set_modes == [BRAKE]


def test_ttc_threshold_parameter():
    assert armed_scenario(2).param("TCMA_TTC", 5).stream(200, ttc=4.0).execute().set_modes == [
        BRAKE
    ]


def test_head_on_alarm_brakes_although_state_is_unknown():
    # Seen on real ArduPilot: a head-on approach, statuses unknown (reason head-on) with
    # confidence 0 but collision_course 1 and TTC 2.9 -> 1.2 s, was dropped by the
    # confidence filter and the vehicle never braked.
    s = armed_scenario(2, GUIDED)
    for k in range(20):
        s.status(state=0, reason=3, confidence=0, ttc=2.9 - 0.09 * k, ttc_confidence=80)
        s.run(40)
    r = s.execute()
    assert r.set_modes == [BRAKE]
    (text,) = r.texts_with("-> BRAKE")  # the most urgent of the first update's two
    assert re.search(r"collision course id 7 ttc 2\.[89]s -> BRAKE", text), text


def test_weak_looming_evidence_is_no_alarm_whatever_the_state_confidence():
    r = armed_scenario(2).stream(400, confidence=100, ttc_confidence=20).execute()
    assert r.set_modes == [] and r.stats["low_conf"] >= 10
    r = armed_scenario(2).param("TCMA_MIN_CONF", 10).stream(400, ttc_confidence=20).execute()
    assert r.set_modes == [BRAKE]


def test_alarm_holds_while_ttc_wanders_above_the_threshold():
    # Seen on real ArduPilot: the alarm cleared 0.76 s after it started because the TTC
    # estimate crossed back over TCMA_TTC (2.95 -> 3.87 s).
    s = armed_scenario(2).stream(400, ttc=2.95).stream(1500, ttc=3.87)
    s.stream(600, collision_course=0)  # a few frames without the flag: time hysteresis
    s.stream(400, ttc=2.5)
    r = s.execute()
    assert r.set_modes == [BRAKE]
    assert r.texts_with("alarm clear") == []
    # no evidence at all for TCMA_HOLD_MS (2 s): it clears, once
    s.stream(2500, ttc=NAN, collision_course=0)
    r = s.execute()
    assert len(r.texts_with("alarm clear")) == 1 and r.set_modes == [BRAKE]


def test_alarm_clears_above_ttc_clr_and_after_the_hold_time():
    s = armed_scenario(2).stream(400, ttc=2.0).stream(1900, ttc=5.0)  # above TCMA_TTC_CLR
    assert s.execute().texts_with("alarm clear") == []  # not yet: 2 s hold
    s.stream(400, ttc=5.0)
    assert len(s.execute().texts_with("alarm clear")) == 1
    r = armed_scenario(2).param("TCMA_HOLD_MS", 500).stream(400).stream(800, ttc=5.0).execute()
    assert len(r.texts_with("alarm clear")) == 1


def test_old_companion_protocol_is_announced_once():
    s = Scenario()
    for _ in range(4):
        s.health(protocol=0).run(300)
    s.health(protocol=2).run(300)
    r = s.execute()
    assert r.texts_with("companion protocol") == [
        "TCM: companion protocol 0 < 2: update it, no alarms"
    ]


def test_pilot_mode_change_wins_until_alarm_clears():
    s = armed_scenario(2).stream(200)
    s.cmd(f"mode {LOITER}")  # the pilot takes over during the alarm
    s.stream(1000)
    r1 = s.execute()
    assert r1.set_modes == [BRAKE]
    assert len(r1.texts_with("standing down")) == 1
    # the alarm clears (the object forgotten after TCMA_OBJ_TO, then TCMA_HOLD_MS without
    # evidence), then comes back
    s.run(3000).cmd(f"mode {AUTO}").stream(200)
    r2 = s.execute()
    assert r2.set_modes == [BRAKE, BRAKE]
    assert len(r2.texts_with("alarm clear")) == 1


def test_no_mode_change_while_pilot_in_charge_even_with_new_object():
    s = armed_scenario(2).stream(200).cmd(f"mode {AUTO}")  # pilot re-engages AUTO
    s.stream(600, track_id=8)
    r = s.execute()
    assert r.set_modes == [BRAKE]
    assert len(r.texts_with("standing down")) == 1


def test_warnings_are_rate_limited():
    r = armed_scenario(1).stream(5000).execute()
    # TCMA_TXT_MS = 2000: at 0, 2, 4 s
    assert len(r.texts_with("collision course")) == 3
    r = armed_scenario(1).param("TCMA_TXT_MS", 1000).stream(5000).execute()
    assert len(r.texts_with("collision course")) == 5


def test_silence_warned_once_then_resumed():
    s = armed_scenario(1).stream(400, collision_course=0).run(3000)
    s.stream(400, collision_course=0).run(3000)
    texts = s.execute().texts
    assert [t for t in texts if "companion data" in t] == [
        "TCM: no companion data",
        "TCM: companion data resumed",
        "TCM: no companion data",
    ]


def test_silence_forgets_objects():
    # the alarm's object is forgotten when the companion goes quiet: no action later
    s = armed_scenario(2, STABILIZE).stream(200).run(1500).cmd(f"mode {AUTO}").run(500)
    assert s.execute().set_modes == []


def test_health_fault_announced_on_change():
    s = Scenario()
    for health in (0, 0, 2, 2, 2, 0):
        s.health(health).run(300)
    r = s.execute()
    assert r.texts_with("companion fault") == ["TCM: companion fault 0x2"]
    assert r.stats["ok"] == 6


def test_gcs_sees_data_flowing_and_the_alarm_as_named_values():
    # statuses at 25 Hz from 10.0 s: no alarm until 11.5 s, then an alarm until 12.5 s,
    # then for a second statuses 2 s older than the autopilot's clock (a companion whose
    # TIMESYNC is off), then the companion goes quiet
    s = armed_scenario(2).stream(1500, collision_course=0).stream(1000, ttc=2.0)
    s = s.stream(1000, collision_course=0, age_ms=2000).run(3000)
    r = s.execute()
    by_t: dict[int, dict[str, float]] = {}
    for line in r.lines:
        if line.startswith("NAMED "):
            _, t, name, value = line.split()
            by_t.setdefault(int(t), {})[name] = float(value)
    first = 10000 + int(_lua_const("UPDATE_MS").split()[0])  # the first update
    assert sorted(by_t) == list(range(first, first + 7000, 1000))  # once a second from it
    names = {"TCM_RX", "TCM_OBJ", "TCM_TTC", "TCM_ALARM", "TCM_STALE"}
    assert all(set(x) == names for x in by_t.values())
    flowing = by_t[first + 1000]
    assert flowing["TCM_RX"] == pytest.approx(25, abs=2) and flowing["TCM_OBJ"] == 1
    assert flowing["TCM_TTC"] == -1 and flowing["TCM_ALARM"] == 0
    assert flowing["TCM_STALE"] == 0
    alarm = by_t[first + 2000]
    assert alarm["TCM_TTC"] == pytest.approx(2.0) and alarm["TCM_ALARM"] == 1
    # The stale statuses (12.5 to 13.5 s) count as stale, not as received, in the
    # second each report covers: 25 a second between them, none once they stop.
    half, stale = by_t[first + 3000], by_t[first + 4000]
    assert half["TCM_RX"] + half["TCM_STALE"] == pytest.approx(25, abs=2)
    assert half["TCM_STALE"] == pytest.approx(14, abs=2)
    assert stale["TCM_RX"] == 0 and stale["TCM_STALE"] == pytest.approx(11, abs=2)
    assert by_t[first + 5000]["TCM_STALE"] == 0
    quiet = by_t[first + 6000]
    assert quiet["TCM_RX"] == 0 and quiet["TCM_OBJ"] == 0 and quiet["TCM_ALARM"] == 0


def test_stationary_objects_pushed_to_scripting_proximity_backend():
    s = Scenario().cmd("prx_type 15").param("TCMA_PRX_IDX", 0)
    s.status(state=1, range=6.5, azimuth=math.radians(30), elevation=math.radians(-10)).run(60)
    s.status(state=2, range=6.5).run(60)  # moving: not a proximity obstacle
    s.status(state=1, range=NAN).run(60)  # no range
    r = s.execute()
    assert len(r.prx) == 1
    dist, yaw, pitch = r.prx[0]
    assert dist == pytest.approx(6.5) and yaw == pytest.approx(30, abs=1e-3)
    assert pitch == pytest.approx(-10, abs=1e-3)


def test_proximity_off_by_default_and_wrong_backend_warned():
    s = Scenario().cmd("prx_type 15").status(state=1, range=6.5).run(60)
    assert s.execute().prx == []
    s = Scenario().cmd("prx_type 2").param("TCMA_PRX_IDX", 0).status(state=1, range=6.5).run(60)
    r = s.execute()
    assert r.prx == [] and len(r.texts_with("not a scripting proximity")) == 1


def test_work_per_update_is_bounded():
    s = armed_scenario(0).cmd("queue_max 40").run(10)
    for i in range(30):
        s.status(track_id=i, collision_course=0)
    s.run(20)  # exactly one update: at most 5 messages
    assert s.execute().stats["rx"] == 5
    s.run(100)  # five more updates take the rest
    assert s.execute().stats["rx"] == 30


def _vm_peak(r: Result) -> tuple[int, int]:
    """The harness's "VM peak N last L steps M": the most VM instructions one call of
    the applet took, and the budget (ArduPilot's SCR_VM_I_COUNT)."""
    line = [x for x in r.lines if x.startswith("VM ")][-1].split()
    return int(line[2]), int(line[6])


def test_no_update_takes_more_than_half_the_vm_budget():
    """Seen on the real ArduCopter SITL under load: "Lua: ./scripts/tcm_avoid.lua exceeded
    time limit", and the vehicle never braked. ArduPilot stops a script for good when one
    call runs more than SCR_VM_I_COUNT (10000) VM instructions; the applet read up to 20
    queued messages per update at ~1,500 instructions each, so 7 queued messages killed
    it. The worst update here: 32 objects known, the receive queue full of
    collision-course statuses, proximity on, the alarm starting (a mode change and texts)
    and the GCS report due. Half the budget is the margin for ArduPilot's Lua 5.3, whose
    instruction counts differ from this Lua 5.4's."""
    s = armed_scenario(2).cmd("prx_type 15").param("TCMA_PRX_IDX", 0).cmd("queue_max 20").run(20)
    for batch in range(7):  # 32 objects known (the most it keeps), none alarming
        for i in range(5):
            s.status(track_id=100 + 5 * batch + i, collision_course=0, state=1, range=6.5)
        s.run(20)
    for i in range(20):  # a full queue at once, all on a collision course
        s.status(track_id=i, collision_course=1, ttc=1.5, state=2)
    s.run(1000).cmd("vm").cmd("stats")  # every message read, the report sent
    r = s.execute()  # (no "ERROR ... exceeded time limit": execute checks)
    assert r.stats["ok"] == 55
    assert r.texts_with("BRAKE")
    peak, budget = _vm_peak(r)
    assert budget == 10000
    assert peak <= budget // 2, peak


def test_the_harness_stops_an_applet_past_the_vm_budget_as_ardupilot_does():
    """The budget is real in the harness: at 100 instructions a call the applet's load
    (declaring its parameters) is already too much, and it is reported and stopped."""
    lua = LUAS[0]
    proc = subprocess.run(
        [lua, str(HARNESS), str(APPLET)],
        input="vm_steps 100\nrun 100\n",
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        check=False,
    )
    assert f"ERROR {APPLET} exceeded time limit" in proc.stdout, proc.stdout


def test_parameter_names_fit_ardupilot_limit():
    names = re.findall(r'\{ "(\w+)", ', APPLET.read_text())
    assert names and all(len("TCMA_" + n) <= 16 for n in names)


# ---------------------------------------------------------------- inside the mock autopilot
def _mock_run(action: int, ttc: float = 2.0, cc: int = 1):
    pytest.importorskip("lupa", reason="lupa not installed (pip install lupa)")
    import numpy as np

    from tcm_companion.sim.vehicle.lua_applet import LuaAppletAutopilot
    from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig

    t0 = 5_000_000_000
    cfg = MockAutopilotConfig(scenario="COLLISION", ekf_origin_delay_us=0, brake_on_collision=False)
    ap = LuaAppletAutopilot(MockAutopilot(cfg, t0), params={"TCMA_ACTION": action})
    codec = MavlinkCodec(1, 191)
    now = t0
    events = []
    for _ in range(50):  # 2 s at 25 Hz
        now += 40_000
        msg = d.MAVLink_tcm_object_status_message(
            ap.mock.boot_us(now) // 1000,
            12,
            0,
            2,
            0,
            0.3,
            0.09,
            ttc,
            cc,
            0.0,
            0.0,
            0.02,
            NAN,
            90,
            ttc_confidence=90,
        )
        events += ap.receive_data(codec.encode(msg), now)
        ap.data_to_send()
    speed = float(np.linalg.norm(ap.mock.vehicle_truth(now + 2_000_000).velocity_ned_mps))
    return ap, events, speed


def test_mock_autopilot_brakes_through_the_applet():
    from tcm_companion.sim.vehicle.mock_autopilot import BrakeStarted

    ap, events, speed = _mock_run(action=2)
    assert ap.mavlink_init == (20, 20) and ap.registered == {45100, 45101}
    assert ap.mode_requests == [BRAKE]
    assert ap.braking is not None and [e for e in events if isinstance(e, BrakeStarted)]
    assert any("-> BRAKE" in t for _, _, t in ap.texts)
    assert speed < 0.05  # hovering after the stop (COLLISION flies at 1.5 m/s)
    assert ap.mock.stats["brakes"] == 1


@pytest.mark.parametrize("action, kw", [(1, {}), (2, {"cc": 0}), (2, {"ttc": 5.0})])
def test_mock_autopilot_does_not_brake_without_applet_action(action, kw):
    ap, _, speed = _mock_run(action, **kw)
    assert ap.braking is None and ap.mode_requests == []
    assert speed == pytest.approx(1.5, abs=0.1)


def _mock_with_burst(vm_steps: int = 10000) -> tuple[Any, list[str]]:
    """The applet in the mock autopilot, given 20 statuses at once and then an alarm;
    the texts it sent."""
    pytest.importorskip("lupa", reason="lupa not installed (pip install lupa)")
    from tcm_companion.sim.vehicle.lua_applet import LuaAppletAutopilot
    from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig

    t0 = 5_000_000_000
    cfg = MockAutopilotConfig(scenario="COLLISION", ekf_origin_delay_us=0, brake_on_collision=False)
    ap = LuaAppletAutopilot(MockAutopilot(cfg, t0), params={"TCMA_ACTION": 1}, vm_steps=vm_steps)
    s = Scenario()
    now = t0 + 100_000
    s.now = ap.mock.boot_us(now) // 1000
    burst = b"".join(
        s.codec.encode(s.status_msg(track_id=20 + i, collision_course=0)) for i in range(20)
    )
    ap.receive_data(burst, now)
    ap.poll(now + 500_000)
    s.now = ap.mock.boot_us(now + 500_000) // 1000
    ap.receive_data(s.codec.encode(s.status_msg(track_id=9)), now + 500_000)
    ap.poll(now + 600_000)
    return ap, [t for _, _, t in ap.texts]


def test_the_mock_autopilot_holds_the_applet_to_ardupilots_vm_budget() -> None:
    """As the firmware does (tests/test_ardupilot_applet.py has the same burst on real
    ArduPilot): a burst of 20 statuses is read over several calls within the budget, and
    a budget too small for a call (here the applet's load, ~3,500 instructions with the
    fake parameter bindings in Lua) removes the applet with the firmware's text."""
    ap, texts = _mock_with_burst()
    assert not [t for t in texts if t.startswith("Lua")], texts
    assert "TCM: collision course id 9 ttc 1.5s" in texts
    ap, texts = _mock_with_burst(vm_steps=1500)
    assert texts.count("Lua: ./scripts/tcm_avoid.lua exceeded time limit") == 1, texts
    assert not [t for t in texts if "collision course" in t]
    assert ap.mock.stats["lua script removed"] == 1


def test_closed_loop_sitl_the_daemon_drives_the_applet_to_brake(tmp_path: Path) -> None:
    """The real companion's output into the applet inside the mock, in virtual time (one
    simulated clock: deterministic, whatever the machine's load): a ball on a collision
    course makes the applet switch to BRAKE and the vehicle stop."""
    pytest.importorskip("lupa")
    import asyncio
    from dataclasses import replace

    from tcm_companion.config import AppConfig
    from tcm_companion.sim.vehicle.lua_applet import LuaAppletAutopilot
    from tcm_companion.sim.vehicle.mock_autopilot import MockAutopilot, MockAutopilotConfig
    from tcm_companion.sitl.mock_flight import run_sitl
    from tcm_companion.sitl.virtual import (
        VIRTUAL_START_MONO_US,
        VIRTUAL_UNIX_US_AT_START,
    )

    mcfg = MockAutopilotConfig(
        scenario="COLLISION", brake_on_collision=False, unix_us_at_start=VIRTUAL_UNIX_US_AT_START
    )
    mock = LuaAppletAutopilot(MockAutopilot(mcfg, VIRTUAL_START_MONO_US), params={"TCMA_ACTION": 2})
    config = AppConfig()
    config = replace(config, sim=replace(config.sim, scenario="COLLISION"))
    report = asyncio.run(
        run_sitl(config, duration_s=10.0, state_dir=str(tmp_path), mock=mock, clock="virtual")  # type: ignore[arg-type]
    )
    texts = [t for _, _, t in mock.texts]
    assert any("-> BRAKE" in t for t in texts), texts
    assert report.braked and mock.braking is not None
    assert report.mock_status_problems == 0, report.lines()
