--[[
tcm_avoid.lua - ArduPilot Lua applet for the tcm-companion MAVLink dialect.

Receives TCM_OBJECT_STATUS (45100) and TCM_PIPELINE_HEALTH (45101) from the
companion computer, checks every frame itself (ArduPilot hands unknown message
ids to scripts WITHOUT checking CRC or source, see ../../docs/mavlink.md), keeps
per-object state, and on a collision-course alarm with a short time to contact
warns and optionally switches flight mode (BRAKE / LOITER / RTL), Copter only.

Install: copy to APM/scripts on the SD card, SCR_ENABLE=1, reboot (README.md).

Binding names are checked against ArduPilot libraries/AP_Scripting/docs/docs.lua
(commit stored in the project notes; see README.md "Bindings used"):
  mavlink:init, mavlink:register_rx_msgid, mavlink:receive_chan,
  gcs:send_text, gcs:send_named_float, vehicle:get_mode, vehicle:set_mode,
  vehicle:get_likely_flying,
  arming:is_armed, millis, param:add_table, param:add_param, param:get,
  Parameter, Parameter_ud:get, FWVersion:type, proximity:get_backend,
  AP_Proximity_Backend_ud:set_distance_min_max,
  AP_Proximity_Backend_ud:handle_script_distance_msg,
  AP_Proximity_Backend_ud:update_virtual_boundary
--]]

-- luacheck: globals mavlink gcs vehicle arming millis param Parameter FWVersion proximity TCM_TEST_HOOK

local SCRIPT_NAME = "TCM"

-- ---------------------------------------------------------------------------
-- Dialect constants. They come from the generated pymavlink module
-- tcm_companion/mavlink/tcm_dialect.py; tests/test_lua_applet.py checks that
-- they still match (crc_extra, ordered_fieldnames, native_format).
-- ---------------------------------------------------------------------------
local MSGID_OBJECT_STATUS = 45100
local MSGID_PIPELINE_HEALTH = 45101
local CRC_EXTRA_OBJECT_STATUS = 111
local CRC_EXTRA_PIPELINE_HEALTH = 34
-- wire layout (fields sorted by type size, as MAVLink does, then the extension
-- fields in XML order), little-endian.
--
-- ArduPilot builds Lua with 32-bit integers and 32-bit floats (LUA_32BITS):
-- string.unpack of an 8-byte integer that does not fit raises "8-byte integer
-- does not fit into Lua Integer" and ArduPilot removes the script. So no field is
-- read wider than 4 bytes: TCM_PIPELINE_HEALTH's int64 timesync_offset_us is read
-- as its two halves (low uint32, high int32; _lo and _hi below). A uint32 ("I4")
-- above 2^31 reads as a negative integer there; time_boot_ms is only ever
-- subtracted from another millisecond count, which wraps the same way.
-- pymavlink native_format "<IfffffffHBBBBBBB"
local FMT_OBJECT_STATUS = "<I4fffffffI2BBBBBBB"
local FIELDS_OBJECT_STATUS = {
  "time_boot_ms", "disparity", "threshold", "ttc", "azimuth", "elevation",
  "angular_radius", "range", "track_id", "camera_id", "state", "reason",
  "collision_course", "confidence", "ttc_confidence", "label",
}
local LEN_OBJECT_STATUS = 41
-- pymavlink native_format "<qIffIIHBBBBB" (q read as I4 i4)
local FMT_PIPELINE_HEALTH = "<I4i4I4ffI4I4I2BBBBB"
local FIELDS_PIPELINE_HEALTH = {
  "timesync_offset_us_lo", "timesync_offset_us_hi", "time_boot_ms", "frame_rate", "latency",
  "frames_dropped", "health", "timesync_rtt_us", "egomotion_source",
  "egomotion_quality", "objects", "log_state", "protocol",
}
local LEN_PIPELINE_HEALTH = 35
-- TCM_PIPELINE_HEALTH.protocol this applet needs: 2 sends ttc_confidence, on which
-- collision alarms are judged (older companions send 0 there: no alarm).
local PROTOCOL_MIN = 2
local TWO_32 = 4294967296.0

local MAGIC_V2 = 0xFD
local STATE_STATIONARY = 1

-- Copter flight mode numbers (ArduCopter mode.h)
local MODE = {
  STABILIZE = 0, ACRO = 1, ALT_HOLD = 2, AUTO = 3, GUIDED = 4, LOITER = 5,
  RTL = 6, CIRCLE = 7, LAND = 9, POSHOLD = 16, BRAKE = 17,
}
local MODE_NAME = {}
for k, v in pairs(MODE) do MODE_NAME[v] = k end
-- Modes we may take the vehicle out of. Manual modes (STABILIZE, ACRO...),
-- LAND, RTL/SMART_RTL, BRAKE, THROW, AUTOROTATE... are the pilot's or a
-- failsafe's choice and are never overridden: there we only warn.
local ACTIONABLE_MODES = {
  [MODE.ALT_HOLD] = true, [MODE.AUTO] = true, [MODE.GUIDED] = true,
  [MODE.LOITER] = true, [MODE.CIRCLE] = true, [MODE.POSHOLD] = true,
}
-- TCMA_ACTION values -> target mode
local ACTION_NONE, ACTION_WARN = 0, 1
local ACTION_MODE = { [2] = MODE.BRAKE, [3] = MODE.LOITER, [4] = MODE.RTL }

-- MAV_SEVERITY
local SEV_CRITICAL, SEV_WARNING, SEV_NOTICE, SEV_INFO = 2, 4, 5, 6

-- ArduPilot stops a script for good when one call takes more than SCR_VM_I_COUNT
-- VM instructions (10000 by default): "Lua: tcm_avoid.lua exceeded time limit". A
-- message costs ~600 of them (half of it its CRC), an update ~200 besides and more
-- when the alarm starts, so an update reads at most 5 and runs every 20 ms: 250
-- messages/s, above the 25 Hz per object of 8 objects plus health, with the worst
-- update under half the budget (measured in tools/ardupilot/harness.lua:
-- tests/test_lua_applet.py::test_no_update_takes_more_than_half_the_vm_budget).
local UPDATE_MS = 20         -- scheduling period
local REPORT_MS = 1000       -- NAMED_VALUE_FLOATs for the GCS: data flowing, alarm
local MAX_MSGS_PER_UPDATE = 5   -- bounded work per update (above)
local MAX_OBJECTS = 32       -- bounded per-object table
local RX_QUEUE = 20
local PRX_TYPE_SCRIPTING = 15 -- PRX1_TYPE = 15 (Scripting)

-- ---------------------------------------------------------------------------
-- Parameters. A table of our own on the autopilot, prefix "TCMA_" (TCM
-- Applet). The companion's own parameters are TCM_* on component 191; a
-- distinct prefix keeps a GCS parameter list unambiguous. Names stay within
-- ArduPilot's 16-character limit (prefix included).
-- param:add_table(table_key, prefix, num_params) / param:add_param(table_key,
-- param_num, name, default_value) / Parameter(name) - docs.lua.
-- ---------------------------------------------------------------------------
local PARAM_TABLE_KEY = 87
local PARAM_PREFIX = "TCMA_"
local PARAM_DEFS = {
  -- name, default
  { "ENABLE", 1 },     -- 0: ignore everything, 1: run
  { "ACTION", 1 },     -- 0 none, 1 warn, 2 BRAKE, 3 LOITER, 4 RTL
  { "TTC", 3.0 },      -- s: alarm on a collision course with ttc below this
  { "MIN_CONF", 50 },  -- %: least ttc_confidence for an alarm (confidence for proximity)
  { "SYSID", 0 },      -- companion system id; 0 = this vehicle's (MAV_SYSID)
  { "COMPID", 191 },   -- companion component id
  { "MAX_AGE", 500 },  -- ms: drop statuses whose time_boot_ms is older
  { "OBJ_TO", 500 },   -- ms: forget an object not heard of for this long
  { "SILENT", 1000 },  -- ms: companion silent this long -> no data, warn once
  { "TXT_MS", 2000 },  -- ms: the same warning text at most once per this
  { "PRX_IDX", -1 },   -- proximity backend instance for stationary objects, -1 off
  -- hysteresis: once on, an alarm holds while a collision-course object has
  -- ttc below TTC_CLR, and clears only after HOLD_MS without one
  { "TTC_CLR", 4.5 },  -- s
  { "HOLD_MS", 2000 }, -- ms
}

assert(param:add_table(PARAM_TABLE_KEY, PARAM_PREFIX, #PARAM_DEFS), "TCM: could not add param table")
local P = {}
for i, def in ipairs(PARAM_DEFS) do
  assert(param:add_param(PARAM_TABLE_KEY, i, def[1], def[2]), "TCM: could not add param " .. def[1])
  P[def[1]] = Parameter(PARAM_PREFIX .. def[1])
end

local function pget(name)
  local v = P[name]:get()
  if v == nil then
    for _, def in ipairs(PARAM_DEFS) do
      if def[1] == name then return def[2] end
    end
  end
  return v
end

-- ---------------------------------------------------------------------------
-- helpers
-- ---------------------------------------------------------------------------
-- millis() and receive_chan()'s timestamp are uint32_t_ud (docs.lua): :toint()
local function to_int(v)
  if type(v) == "number" then return math.floor(v) end
  return v:toint()
end

local function now_ms()
  return to_int(millis())
end

local last_text = {}  -- key -> ms of last send
local function say(severity, text, key, now)
  -- rate limit per key (nil key: always send, used for once-per-episode texts)
  if key ~= nil then
    local last = last_text[key]
    if last ~= nil and now - last < pget("TXT_MS") then
      return false
    end
    last_text[key] = now
  end
  gcs:send_text(severity, SCRIPT_NAME .. ": " .. text)
  return true
end

-- MAVLink X.25 CRC (crc_accumulate in mavlink checksum.h), a byte at a time
-- from a table: ArduPilot stops a script after SCR_VM_I_COUNT (10000) VM
-- instructions per call, and the per-bit form cost ~1300 of them per status
-- message, so a queue of 7 messages killed the applet. crc_accumulate's next
-- value depends on the byte only through (b ~ crc) & 0xFF:
--   crc' = (crc >> 8) ~ CRC_TABLE[(b ~ crc) & 0xFF]
local CRC_TABLE = {}
for x = 0, 255 do
  local tmp = (x ~ (x << 4)) & 0xFF
  CRC_TABLE[x] = ((tmp << 8) ~ (tmp << 3) ~ (tmp >> 4)) & 0xFFFF
end

local function crc_accumulate(b, crc)
  return (crc >> 8) ~ CRC_TABLE[(b ~ crc) & 0xFF]
end

local function crc_string(s, i, j, crc)
  local t = CRC_TABLE
  local k = i
  while k + 7 <= j do  -- eight bytes a call: ~6 VM instructions a byte
    local b1, b2, b3, b4, b5, b6, b7, b8 = s:byte(k, k + 7)
    crc = (crc >> 8) ~ t[(b1 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b2 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b3 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b4 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b5 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b6 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b7 ~ crc) & 0xFF]
    crc = (crc >> 8) ~ t[(b8 ~ crc) & 0xFF]
    k = k + 8
  end
  for m = k, j do
    crc = (crc >> 8) ~ t[(s:byte(m) ~ crc) & 0xFF]
  end
  return crc
end

local MSG_DEFS = {
  [MSGID_OBJECT_STATUS] = {
    crc_extra = CRC_EXTRA_OBJECT_STATUS, len = LEN_OBJECT_STATUS,
    fmt = FMT_OBJECT_STATUS, fields = FIELDS_OBJECT_STATUS, kind = "status",
  },
  [MSGID_PIPELINE_HEALTH] = {
    crc_extra = CRC_EXTRA_PIPELINE_HEALTH, len = LEN_PIPELINE_HEALTH,
    fmt = FMT_PIPELINE_HEALTH, fields = FIELDS_PIPELINE_HEALTH, kind = "health",
  },
}

local stats = { rx = 0, bad_magic = 0, bad_len = 0, bad_crc = 0, bad_src = 0,
                bad_id = 0, stale = 0, low_conf = 0, ok = 0 }

-- a uint32 read by "I4" as a float, whatever the integer width (negative above
-- 2^31 with 32-bit integers)
local function u32_float(v)
  if v < 0 then return v + TWO_32 end
  return v + 0.0
end

--[[
Parse one message as handed over by mavlink:receive_chan(): the firmware's
raw mavlink_message_t (291 bytes), 1-based:
  1-2 checksum, 3 magic, 4 len, 5 incompat, 6 compat, 7 seq, 8 sysid,
  9 compid, 10-12 msgid, 13.. payload (264-byte area), 277-278 ck (wire CRC).
Bytes past len are NOT zeros (left-overs, the CRC); MAVLink 2 trims trailing
zero bytes of the payload on the wire, so zero-fill to the full length.
Returns kind, fields table or nil, reason.
--]]
local function parse(raw, want_sys, want_comp)
  if type(raw) ~= "string" or #raw < 278 then
    return nil, "bad_len"
  end
  if raw:byte(3) ~= MAGIC_V2 then
    return nil, "bad_magic"
  end
  local len = raw:byte(4)
  local incompat = raw:byte(5)
  local msgid = string.unpack("<I3", raw, 10)
  local def = MSG_DEFS[msgid]
  if def == nil then
    return nil, "bad_id"
  end
  if (incompat & 0xFE) ~= 0 or len < 1 or len > def.len then
    return nil, "bad_len"
  end
  -- CRC over len..msgid (bytes 4-12), the payload as sent, then CRC_EXTRA
  local crc = crc_string(raw, 4, 12 + len, 0xFFFF)
  crc = crc_accumulate(def.crc_extra, crc)
  local rx_crc = string.unpack("<I2", raw, 277)
  if crc ~= rx_crc then
    return nil, "bad_crc"
  end
  local sysid, compid = raw:byte(8), raw:byte(9)
  if sysid ~= want_sys or compid ~= want_comp then
    return nil, "bad_src"
  end
  local payload = raw:sub(13, 12 + len) .. string.rep("\0", def.len - len)
  local values = table.pack(string.unpack(def.fmt, payload))
  local f = {}
  for i, name in ipairs(def.fields) do
    f[name] = values[i]
  end
  f.sysid, f.compid, f.seq = sysid, compid, raw:byte(7)
  if def.kind == "health" then
    -- int64 from its halves, as a float (coarse with 32-bit floats: display only)
    f.timesync_offset_us = f.timesync_offset_us_hi * TWO_32 + u32_float(f.timesync_offset_us_lo)
  end
  return def.kind, f
end

local function is_finite(x)
  return x == x and x ~= math.huge and x ~= -math.huge
end

-- ---------------------------------------------------------------------------
-- state
-- ---------------------------------------------------------------------------
local objects = {}        -- track_id -> {t=, ttc=, cc=, ttc_conf=, state=, ...}
local n_objects = 0
local last_rx_ms = nil    -- last valid frame (either message)
local start_ms = nil
local silent_warned = false
local last_health = nil
local acted_mode = nil    -- mode we switched to, while our action stands
local stood_down = false  -- pilot changed mode after our action: wait for clear
local alarm_active = false
local alarm_hold_ms = nil -- last time an object kept the alarm on (hysteresis)
local last_alarm_id = nil -- the object of the alarm's latest evidence
local protocol_warned = false
local last_attempt_ms = nil -- last refused set_mode, retried at most every TXT_MS
local prx_backend = nil
local prx_checked = false

local function forget_objects()
  objects = {}
  n_objects = 0
end

local function store_object(f, now)
  local o = objects[f.track_id]
  if o == nil then
    if n_objects >= MAX_OBJECTS then
      -- evict the oldest
      local oldest_id, oldest_t = nil, nil
      for id, ob in pairs(objects) do
        if oldest_t == nil or ob.t < oldest_t then oldest_id, oldest_t = id, ob.t end
      end
      objects[oldest_id] = nil
      n_objects = n_objects - 1
    end
    o = {}
    objects[f.track_id] = o
    n_objects = n_objects + 1
  end
  o.t = now
  o.ttc = f.ttc
  o.cc = f.collision_course
  o.conf = f.confidence
  o.ttc_conf = f.ttc_confidence
  o.state = f.state
  o.az = f.azimuth
  o.el = f.elevation
  o.range = f.range
  o.camera = f.camera_id
end

local function expire_objects(now)
  local timeout = pget("OBJ_TO")
  for id, o in pairs(objects) do
    if now - o.t > timeout then
      objects[id] = nil
      n_objects = n_objects - 1
    end
  end
end

--[[
What a collision-course alarm is. The evidence is looming and bearing alone: the
companion's collision_course flag (near-constant bearing, closing) with a time to
contact 0 < ttc < TCMA_TTC, judged by ttc_confidence (how well the looming fit
determines ttc) >= TCMA_MIN_CONF. The motion state and its confidence do not enter:
an object dead ahead (head-on) has no TCM state (unknown, reason HEAD_ON) but the
most reliable looming there is, and it is the most dangerous case.
Hysteresis: the alarm starts on one such status; it then holds while an object on a
collision course has 0 < ttc < TCMA_TTC_CLR (same confidence test), and clears
only after TCMA_HOLD_MS without one (a ttc estimate wandering across TCMA_TTC, or
a few frames without the flag, do not end it).
--]]
local function evidence(o, ttc_max)
  return o.cc == 1 and is_finite(o.ttc) and o.ttc > 0 and o.ttc < ttc_max
    and (o.ttc_conf or 0) >= pget("MIN_CONF")
end

-- the most urgent object below ttc_max, or nil
local function most_urgent(ttc_max)
  local best = nil
  for id, o in pairs(objects) do
    if evidence(o, ttc_max) and (best == nil or o.ttc < best.ttc) then
      best = { id = id, ttc = o.ttc, az = o.az }
    end
  end
  return best
end

-- the alarm with hysteresis in ttc and time: the alarming object, or nil
local function find_alarm(now)
  local alarm = most_urgent(pget("TTC"))
  if alarm == nil and alarm_active then
    alarm = most_urgent(math.max(pget("TTC"), pget("TTC_CLR")))
  end
  if alarm ~= nil then
    alarm_hold_ms = now
    return alarm
  end
  if alarm_active and alarm_hold_ms ~= nil and now - alarm_hold_ms <= pget("HOLD_MS") then
    return { id = last_alarm_id, ttc = math.huge, held = true }
  end
  return nil
end

-- ---------------------------------------------------------------------------
-- proximity (stationary objects of known range), optional
-- ---------------------------------------------------------------------------
local function get_prx()
  local idx = pget("PRX_IDX")
  if idx < 0 or proximity == nil then return nil end
  if not prx_checked then
    prx_checked = true
    local be = proximity:get_backend(math.floor(idx))
    if be ~= nil and be:type() == PRX_TYPE_SCRIPTING then
      be:set_distance_min_max(0.2, 100)
      prx_backend = be
    else
      say(SEV_WARNING, "PRX_IDX is not a scripting proximity backend", "prx", now_ms())
    end
  end
  return prx_backend
end

local function push_proximity(f)
  if f.state ~= STATE_STATIONARY or not is_finite(f.range) or f.range <= 0 then
    return
  end
  local be = get_prx()
  if be == nil then return end
  be:handle_script_distance_msg(f.range, math.deg(f.azimuth), math.deg(f.elevation), true)
end

-- ---------------------------------------------------------------------------
-- receive
-- ---------------------------------------------------------------------------
local function want_source()
  local sys = pget("SYSID")
  if sys <= 0 then
    -- MAV_SYSID since ArduPilot 4.7; SYSID_THISMAV before
    sys = param:get("MAV_SYSID") or param:get("SYSID_THISMAV") or 1
  end
  return math.floor(sys), math.floor(pget("COMPID"))
end

local function receive(now)
  local want_sys, want_comp = want_source()
  local max_age = pget("MAX_AGE")
  local min_conf = pget("MIN_CONF")
  for _ = 1, MAX_MSGS_PER_UPDATE do
    local raw, _chan, ts = mavlink:receive_chan()
    if raw == nil then break end
    stats.rx = stats.rx + 1
    local kind, f = parse(raw, want_sys, want_comp)
    if kind == nil then
      stats[f] = (stats[f] or 0) + 1
    else
      -- frame age: time in the queue (firmware receive time) and, for the
      -- companion's own timestamp (autopilot boot time through TIMESYNC)
      local rx_age = ts and (now - to_int(ts)) or 0
      local age = now - f.time_boot_ms
      if rx_age > max_age or age > max_age or age < -max_age then
        stats.stale = stats.stale + 1
      else
        last_rx_ms = now
        if TCM_TEST_HOOK then TCM_TEST_HOOK(kind, f) end
        stats.ok = stats.ok + 1
        if kind == "status" then
          if f.collision_course == 1 and f.ttc_confidence < min_conf then
            stats.low_conf = stats.low_conf + 1  -- weak evidence: never an alarm
          end
          store_object(f, now)
          if f.confidence >= min_conf then push_proximity(f) end
        else
          if last_health ~= nil and f.health ~= last_health.health and f.health ~= 0 then
            say(SEV_WARNING, string.format("companion fault 0x%X", f.health), "health", now)
          end
          if f.protocol < PROTOCOL_MIN and not protocol_warned then
            protocol_warned = true
            say(SEV_WARNING, string.format(
              "companion protocol %d < %d: update it, no alarms", f.protocol, PROTOCOL_MIN), nil, now)
          end
          last_health = f
        end
      end
    end
  end
end

-- ---------------------------------------------------------------------------
-- decide
-- ---------------------------------------------------------------------------
local function is_copter()
  if FWVersion == nil then return true end
  local t = FWVersion:type()
  return t == 2 or t == 13  -- ArduCopter, Heli
end

local function act(alarm, now)
  local action = math.floor(pget("ACTION"))
  if action == ACTION_NONE then return end
  local mode = vehicle:get_mode()
  if not alarm.held then last_alarm_id = alarm.id end

  -- our action stands; the pilot changing mode takes over
  if acted_mode ~= nil then
    if mode ~= acted_mode then
      acted_mode = nil
      stood_down = true
      say(SEV_NOTICE, "pilot mode change, standing down", nil, now)
    end
    return
  end
  -- no fresh evidence, the alarm only holds: start nothing
  if alarm.held then return end
  local text = string.format("collision course id %d ttc %.1fs", alarm.id, alarm.ttc)

  local target = ACTION_MODE[action]
  local armed = arming:is_armed()
  local flying = vehicle:get_likely_flying()
  if target == nil or stood_down or not armed or not flying
      or not ACTIONABLE_MODES[mode] or mode == target or not is_copter() then
    say(SEV_WARNING, text, "warn", now)
    return
  end
  if last_attempt_ms ~= nil and now - last_attempt_ms < pget("TXT_MS") then
    return  -- the last attempt was refused: do not hammer set_mode
  end
  if vehicle:set_mode(target) then
    last_attempt_ms = nil
    acted_mode = target
    say(SEV_CRITICAL, string.format("%s -> %s", text, MODE_NAME[target]), nil, now)
  else
    last_attempt_ms = now
    say(SEV_WARNING, text .. ", mode change refused", "refused", now)
  end
end

--[[
What a ground station sees of the applet (besides its texts), once a second, as
NAMED_VALUE_FLOAT from the autopilot (Mission Planner: Status tab; QGroundControl:
MAVLink Inspector; MAVProxy: graph NAMED_VALUE_FLOAT):
  TCM_RX    valid TCM frames received per second (0: no companion data)
  TCM_OBJ   objects currently known
  TCM_TTC   the most urgent collision-course time to contact, s (-1: none)
  TCM_ALARM 1 while a collision alarm holds, else 0
  TCM_STALE TCM frames dropped as stale in the last second (time_boot_ms more than
            TCMA_MAX_AGE off this autopilot's clock, or queued longer): a companion
            whose TIMESYNC is off, or an autopilot too busy to read its link
--]]
local last_report_ms = nil
local ok_at_report = 0
local stale_at_report = 0

local function report(now)
  if last_report_ms ~= nil and now - last_report_ms < REPORT_MS then return end
  local dt = last_report_ms and (now - last_report_ms) or REPORT_MS
  last_report_ms = now
  local rate = (stats.ok - ok_at_report) * 1000.0 / math.max(dt, 1)
  ok_at_report = stats.ok
  local urgent = most_urgent(math.huge)
  gcs:send_named_float("TCM_RX", rate)
  gcs:send_named_float("TCM_OBJ", n_objects)
  gcs:send_named_float("TCM_TTC", urgent and urgent.ttc or -1)
  gcs:send_named_float("TCM_ALARM", alarm_active and 1 or 0)
  gcs:send_named_float("TCM_STALE", stats.stale - stale_at_report)
  stale_at_report = stats.stale
end

local function update()
  local now = now_ms()
  if start_ms == nil then start_ms = now end
  if pget("ENABLE") < 1 then
    forget_objects()
    return update, 500
  end

  receive(now)
  expire_objects(now)

  -- companion silence
  local silent_to = pget("SILENT")
  local since = last_rx_ms or start_ms
  if now - since > silent_to then
    if not silent_warned then
      silent_warned = true
      say(SEV_WARNING, "no companion data", nil, now)
    end
    forget_objects()
  elseif silent_warned and last_rx_ms ~= nil and now - last_rx_ms <= silent_to then
    silent_warned = false
    say(SEV_INFO, "companion data resumed", nil, now)
  end

  local alarm = find_alarm(now)
  if alarm ~= nil then
    alarm_active = true
    act(alarm, now)
  elseif alarm_active then
    alarm_active = false
    alarm_hold_ms = nil
    if acted_mode ~= nil or stood_down then
      say(SEV_INFO, "collision alarm clear", nil, now)
    end
    acted_mode = nil
    stood_down = false
  elseif acted_mode == nil then
    stood_down = false
  end
  report(now)
  return update, UPDATE_MS
end

-- mavlink:init(queue, ids) - the C++ binding (lua_bindings.cpp lua_mavlink_init)
-- reads arg 1 as the receive queue depth and arg 2 as the number of message
-- ids, while docs.lua names them (num_rx_msgid, msg_queue_length); both are
-- limited to 25. Passing the same value for both is correct either way.
mavlink:init(RX_QUEUE, RX_QUEUE)
mavlink:register_rx_msgid(MSGID_OBJECT_STATUS)
mavlink:register_rx_msgid(MSGID_PIPELINE_HEALTH)
gcs:send_text(SEV_INFO, SCRIPT_NAME .. ": avoid applet loaded")

-- exported for the test harness only (ignored by ArduPilot)
TCM_APPLET = { parse = parse, stats = stats, objects = function() return objects end }

return update, UPDATE_MS
