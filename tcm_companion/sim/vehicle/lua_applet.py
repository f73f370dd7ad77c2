"""Run the ArduPilot Lua applet (tools/ardupilot/tcm_avoid.lua) inside the mock autopilot.

:class:`LuaAppletAutopilot` wraps a :class:`~.mock_autopilot.MockAutopilot` (build it
with ``brake_on_collision=False`` so that its built-in rule stays out of the way) and
runs the applet in an embedded Lua 5.4 (``lupa``) with the bindings it uses, as
``tools/ardupilot/harness.lua`` fakes them for the command-line tests:

- ``mavlink:receive_chan()`` gets every wire frame of ids 45100/45101 the mock receives,
  unchecked (as ArduPilot hands unknown ids to scripts: neither CRC nor source checked),
  as a 291-byte ``mavlink_message_t`` with the mock's boot time in ms;
- ``vehicle:set_mode(17)`` (BRAKE) starts the mock's brake manoeuvre
  (:meth:`MockAutopilot.start_brake`); other modes are refused (the mock flies only its
  scenario and BRAKE); ``vehicle:get_mode()`` is BRAKE while braking, else GUIDED
  (what the mock's HEARTBEAT says) unless :attr:`mode` is set;
- ``gcs:send_text`` becomes the mock's STATUSTEXT (:meth:`MockAutopilot.statustext`) and
  is recorded in :attr:`texts`;
- ``arming:is_armed()`` / ``vehicle:get_likely_flying()`` follow :attr:`armed` /
  :attr:`flying` (the mock is always airborne: True by default);
- ``millis()`` is the mock's boot clock; parameters live in :attr:`params`
  (``param`` and ``Parameter`` are ``tools/ardupilot/fake_params.lua``, shared with the
  harness);
- each call of the applet runs within ``vm_steps`` Lua VM instructions (ArduPilot's
  ``SCR_VM_I_COUNT``, 10000): past it the firmware's ``Lua: ./scripts/tcm_avoid.lua
  exceeded time limit`` and the applet is gone, as on ArduPilot. (The fake parameter
  bindings are Lua here and count; the firmware's are C: a little stricter.)

The applet runs every time it asks to (``return update, 20``) as the caller's time
passes through :meth:`receive_data` and :meth:`poll`.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ...mavlink.tcm_dialect import COPTER_MODE_BRAKE, COPTER_MODE_GUIDED
from .mock_autopilot import MockAutopilot, MockEvent

APPLET_PATH = Path(__file__).resolve().parents[3] / "tools" / "ardupilot" / "tcm_avoid.lua"
# param, Parameter and uint32_t_ud, faked once for both hosts (harness.lua loads it too).
FAKE_PARAMS_PATH = APPLET_PATH.with_name("fake_params.lua")
SCRIPT_IDS = (45100, 45101)
_MSG_T_PAYLOAD = 264
_QUEUE_MAX = 20

# Lua side of the bindings: thin wrappers over the Python host object ``HOST``.
_PRELUDE = r"""
local HOST, uint32 = ...

function millis() return uint32(HOST.millis()) end

mavlink = {}
function mavlink:init(a, b) HOST.mavlink_init(a, b) end
function mavlink:register_rx_msgid(id) return HOST.register(id) end
function mavlink:receive_chan()
  local raw, chan, ts = HOST.receive()
  if raw == nil then return nil end
  return raw, chan, uint32(ts)
end

gcs = {}
function gcs:send_text(sev, text) HOST.send_text(sev, text) end
function gcs:send_named_float(name, value) HOST.send_named_float(name, value) end

vehicle = {}
function vehicle:get_mode() return HOST.get_mode() end
function vehicle:set_mode(m) return HOST.set_mode(m) end
function vehicle:get_likely_flying() return HOST.flying end

arming = {}
function arming:is_armed() return HOST.armed end

FWVersion = {}
function FWVersion:type() return 2 end

-- ArduPilot runs each call of a script under a count hook of SCR_VM_I_COUNT VM
-- instructions and removes the script past it (lua_scripts.cpp).
local function overtime()
  debug.sethook()
  error("Exceeded CPU time")
end
function TCM_CALL_LIMITED(fn, steps)
  debug.sethook(overtime, "", steps)
  local ok, a, b = pcall(fn)
  debug.sethook()
  return ok, a, b
end

"""


def message_t(wire: bytes) -> bytes:
    """A wire MAVLink 2 frame as ArduPilot's ``mavlink_message_t`` (291 bytes)."""
    length = wire[1]
    header = wire[:10].ljust(10, b"\0")
    payload = wire[10 : 10 + length]
    crc = wire[10 + length : 12 + length].ljust(2, b"\0")
    area = (payload + crc).ljust(_MSG_T_PAYLOAD, b"\xa5")[:_MSG_T_PAYLOAD]
    return crc + header + area + crc + bytes(13)


class _Host:
    """The Python side of the bindings (attributes read from Lua through lupa)."""

    def __init__(self, owner: LuaAppletAutopilot) -> None:
        self._o = owner
        self.params: Any = None  # a Lua table, set once the runtime exists

    @property
    def armed(self) -> bool:
        return bool(self._o.armed)

    @property
    def flying(self) -> bool:
        return bool(self._o.flying)

    def millis(self) -> int:
        return self._o.clock_ms

    def mavlink_init(self, queue: int, ids: int) -> None:
        self._o.mavlink_init = (int(queue), int(ids))

    def register(self, msgid: int) -> bool:
        if msgid in self._o.registered:
            return False
        self._o.registered.add(int(msgid))
        return True

    def receive(self) -> tuple[Any, ...]:
        if not self._o.queue:
            return (None,)
        raw, ts = self._o.queue.pop(0)
        return raw, 0, ts

    def send_text(self, severity: int, text: Any) -> None:
        s = text.decode() if isinstance(text, bytes) else str(text)
        self._o.texts.append((self._o.clock_ms, int(severity), s))
        self._o.mock.statustext(int(severity), s)  # the mock's own STATUSTEXT path

    def send_named_float(self, name: Any, value: float) -> None:
        key = name.decode() if isinstance(name, bytes) else str(name)
        self._o.named_values[key] = float(value)  # the latest NAMED_VALUE_FLOAT of each name

    def get_mode(self) -> int:
        if self._o.mock.braking is not None:
            return COPTER_MODE_BRAKE
        return self._o.mode

    def set_mode(self, mode: int) -> bool:
        self._o.mode_requests.append(int(mode))
        if mode != COPTER_MODE_BRAKE:
            return False
        mock = self._o.mock
        brake = mock.start_brake(mock.now_us, -1, float("nan"), text="")
        if brake is not None:
            self._o.events.append(brake)
        return True


class LuaAppletAutopilot:
    """A :class:`MockAutopilot` whose brake decision comes from the Lua applet."""

    def __init__(
        self,
        mock: MockAutopilot,
        applet: Path = APPLET_PATH,
        params: dict[str, float] | None = None,
        vm_steps: int = 10000,
    ) -> None:
        from lupa import lua54  # optional dependency: only this module needs it

        self.mock = mock
        self.registered: set[int] = set()
        self.queue: list[tuple[bytes, int]] = []
        self.texts: list[tuple[int, int, str]] = []
        self.named_values: dict[str, float] = {}
        self.mode_requests: list[int] = []
        self.events: list[MockEvent] = []
        self.mode = COPTER_MODE_GUIDED
        self.armed = True  # arming:is_armed()
        self.flying = True  # vehicle:get_likely_flying() (the mock is always airborne)
        self.mavlink_init: tuple[int, int] | None = None
        self._rx = bytearray()
        self.clock_ms = self._boot_ms()
        self.host = _Host(self)
        self.lua = lua54.LuaRuntime(encoding=None, unpack_returned_tuples=True)
        self.host.params = self.lua.table_from({"MAV_SYSID": mock.system_id})
        for k, v in (params or {}).items():
            self.host.params[k.encode()] = v
        uint32 = self.lua.execute(FAKE_PARAMS_PATH.read_bytes(), self.host.params)
        self.lua.execute(_PRELUDE.encode(), self.host, uint32)
        chunk = self.lua.globals().loadfile(str(applet).encode())
        if chunk is None:
            raise RuntimeError(f"cannot load {applet}")
        self.vm_steps = vm_steps
        self._script = f"./scripts/{applet.name}"
        self._call_limited = self.lua.globals().TCM_CALL_LIMITED
        self._update: Any = None
        self._next_ms = self._boot_ms()
        loaded = self._call(chunk)  # the body runs under the budget too
        if loaded is not None:
            fn, delay = loaded
            self._update, self._next_ms = fn, self._boot_ms() + int(delay)

    def _call(self, fn: Any) -> tuple[Any, Any] | None:
        """``fn()`` within ``vm_steps`` VM instructions, its two results; None when it
        failed, after the firmware's text (and the script is then removed, as
        ArduPilot removes it: no further updates)."""
        ok, a, b = self._call_limited(fn, self.vm_steps)
        if ok:
            return a, b
        why = a.decode(errors="replace") if isinstance(a, bytes) else str(a)
        if "Exceeded CPU time" in why:
            self.host.send_text(2, f"Lua: {self._script} exceeded time limit")
        else:
            self.host.send_text(2, f"Lua: {why}")
        self.mock.stats["lua script removed"] += 1
        self._update = None
        return None

    def param(self, name: str) -> float | None:
        return self.host.params[name.encode()]

    def set_param(self, name: str, value: float) -> None:
        self.host.params[name.encode()] = value

    def _boot_ms(self) -> int:
        return self.mock.boot_us() // 1000

    # -- frames for the script ------------------------------------------------------------
    def _scan(self, data: bytes) -> Iterable[bytes]:
        """Wire frames of the registered ids in ``data`` (no CRC check: that is the
        applet's job, as on ArduPilot)."""
        self._rx += data
        buf = self._rx
        while True:
            start = buf.find(b"\xfd")
            if start < 0:
                buf.clear()
                return
            del buf[:start]
            if len(buf) < 10:
                return
            length, incompat = buf[1], buf[2]
            total = 12 + length + (13 if incompat & 1 else 0)
            if len(buf) < total:
                return
            msgid = buf[7] | (buf[8] << 8) | (buf[9] << 16)
            if msgid in self.registered:
                yield bytes(buf[:total])
                del buf[:total]
            else:
                del buf[:1]  # not ours (the mock's codec handles it): resync on next magic

    # -- the mock's interface ---------------------------------------------------------------
    def receive_data(self, data: bytes, now_us: int) -> list[MockEvent]:
        events = self.mock.receive_data(data, now_us)
        ts = self._boot_ms()
        for frame in self._scan(bytes(data)):
            if len(self.queue) < _QUEUE_MAX:
                self.queue.append((message_t(frame), ts))
            else:
                self.mock.stats["lua queue full"] += 1
        return events + self.run_until(now_us)

    def poll(self, now_us: int) -> list[MockEvent]:
        events = self.mock.poll(now_us)
        return events + self.run_until(now_us)

    def run_until(self, now_us: int) -> list[MockEvent]:
        """Run the applet's updates that fall due up to ``now_us``."""
        self.events = []
        boot_zero = self.mock.boot_us(0)  # = -boot_zero_us
        stop_ms = (now_us + boot_zero) // 1000
        while self._update is not None and self._next_ms <= stop_ms:
            self.clock_ms = self._next_ms
            called = self._call(self._update)
            if called is None or called[0] is None:
                self._update = None
                break
            fn, delay = called
            self._update, self._next_ms = fn, self._next_ms + int(delay)
        self.clock_ms = max(self.clock_ms, stop_ms)
        return self.events

    def data_to_send(self) -> bytes:
        return self.mock.data_to_send()

    def __getattr__(self, name: str) -> Any:  # everything else: the mock's
        return getattr(self.mock, name)
