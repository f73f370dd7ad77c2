--[[
harness.lua - fake ArduPilot scripting bindings to run tcm_avoid.lua on a PC.

  lua5.4 tools/ardupilot/harness.lua tools/ardupilot/tcm_avoid.lua < commands

Only the bindings the applet uses are faked, with the signatures of
libraries/AP_Scripting/docs/docs.lua; every call that changes something or
talks to the pilot is recorded and printed as one line.

Commands (one per line, '#' comments):
  param NAME VALUE       set a parameter (before or after the applet loads;
                         the applet's add_param defaults do not overwrite it)
  armed 0|1              arming:is_armed()
  flying 0|1             vehicle:get_likely_flying()
  mode N                 the vehicle's current mode (the pilot switching modes)
  setmode_ok 0|1         whether vehicle:set_mode() succeeds (default 1)
  fwtype N               FWVersion:type() (default 2, ArduCopter)
  prx_type N             proximity backend 0 type (default: no backend)
  frame HEX [AGE_MS]     a received wire frame (hex), queued for
                         mavlink:receive_chan() with receive time now-AGE_MS;
                         handed over as ArduPilot does: a 291-byte
                         mavlink_message_t with leftover bytes after the payload
  queue_max N            receive queue depth (default 20, as mavlink:init)
  trace 0|1              print every accepted decoded message as FIELDS {json}
  run MS                 run the scheduler for MS of simulated time
  stats                  print the applet's receive counters
  vm_steps N             VM instructions a call may take (ArduPilot's SCR_VM_I_COUNT,
                         default 10000); past it the applet is stopped, as there
  vm                     print the most VM instructions one call took so far, and
                         the last call's
Output lines:
  LOADED / TEXT t sev "text" / NAMED t name value / SET_MODE t mode ok / PRX t dist yaw pitch /
  FIELDS {json} / STATS {json} / VM peak N last L steps M / ERROR msg
--]]

local applet_path = arg[1] or "tools/ardupilot/tcm_avoid.lua"

local now = 10000 -- ms since boot
local params = { MAV_SYSID = 1 }  -- ArduPilot 4.7+ (SYSID_THISMAV before)
local state = { armed = false, flying = false, mode = 0, setmode_ok = true, fwtype = 2 }
local queue = {}
local QUEUE_MAX = 20
local registered = {}
local out = io.stdout

local function emit(line)
  out:write(line, "\n")
end

local function json_value(v)
  local t = type(v)
  if t == "number" then
    if v ~= v or v == math.huge or v == -math.huge then return "null" end
    if math.type(v) == "integer" then return string.format("%d", v) end
    return string.format("%.9g", v)
  elseif t == "string" then
    return string.format("%q", v)
  elseif t == "boolean" then
    return tostring(v)
  end
  return "null"
end

local function json_object(tbl)
  local keys = {}
  for k in pairs(tbl) do keys[#keys + 1] = k end
  table.sort(keys)
  local parts = {}
  for _, k in ipairs(keys) do
    parts[#parts + 1] = string.format("%q:%s", k, json_value(tbl[k]))
  end
  return "{" .. table.concat(parts, ",") .. "}"
end

-- param, Parameter and uint32: shared with the SITL host (lua_applet.py)
local here = arg[0]:match("^(.*)/") or "."
local uint32 = assert(loadfile(here .. "/fake_params.lua"))(params)

-- ---------------------------------------------------------------- bindings
function millis() return uint32(now) end

mavlink = {}
function mavlink:init(a, b) emit(string.format("MAVLINK_INIT %d %d", a, b)) end
function mavlink:register_rx_msgid(id)
  if registered[id] then return false end
  registered[id] = true
  return true
end
function mavlink:receive_chan()
  local m = table.remove(queue, 1)
  if m == nil then return nil end
  return m.raw, 0, uint32(m.ts)
end

gcs = {}
function gcs:send_text(sev, text)
  emit(string.format("TEXT %d %d %q", now, sev, text))
end
function gcs:send_named_float(name, value)
  assert(#name <= 10, "NAMED_VALUE_FLOAT name longer than 10: " .. name)
  emit(string.format("NAMED %d %s %.3f", now, name, value))
end

vehicle = {}
function vehicle:get_mode() return state.mode end
function vehicle:get_likely_flying() return state.flying end
function vehicle:set_mode(m)
  emit(string.format("SET_MODE %d %d %s", now, m, tostring(state.setmode_ok)))
  if state.setmode_ok then state.mode = m end
  return state.setmode_ok
end

arming = {}
function arming:is_armed() return state.armed end

FWVersion = {}
function FWVersion:type() return state.fwtype end

local prx_type = nil
local Backend = {}
Backend.__index = Backend
function Backend:type() return prx_type end
function Backend:set_distance_min_max(a, b) emit(string.format("PRX_MINMAX %g %g", a, b)); return true end
function Backend:handle_script_distance_msg(d, yaw, pitch, push)
  emit(string.format("PRX %d %.3f %.3f %.3f %s", now, d, yaw, pitch, tostring(push)))
  return true
end
function Backend:update_virtual_boundary() return true end
proximity = {}
function proximity:get_backend(i)
  if prx_type == nil or i ~= 0 then return nil end
  return setmetatable({}, Backend)
end

-- ---------------------------------------------------------------- frames
local function unhex(h)
  return (h:gsub("%x%x", function(c) return string.char(tonumber(c, 16)) end))
end

-- wire MAVLink 2 frame -> ArduPilot's mavlink_message_t as receive_chan gives it
local function to_message_t(wire)
  local len = wire:byte(2) or 0
  local header = wire:sub(1, 10)                 -- magic .. msgid
  header = header .. string.rep("\0", 10 - #header)
  local payload = wire:sub(11, 10 + len)
  local crc = wire:sub(11 + len, 12 + len)
  crc = crc .. string.rep("\0", 2 - #crc)
  -- the parser writes the CRC bytes after the payload; the rest of the
  -- 264-byte area holds leftovers of earlier messages (not zeros)
  local area = payload .. crc
  area = area .. string.rep("\xA5", 264 - #area)
  area = area:sub(1, 264)
  return crc .. header .. area .. crc .. string.rep("\0", 13)
end

-- ---------------------------------------------------------------- run
local update_fn, next_run = nil, nil

local call_limited  -- below

local stopped = false  -- removed, as ArduPilot removes a script that failed

local function load_applet()
  local chunk, err = loadfile(applet_path)
  if not chunk then error(err) end
  local fn, delay = call_limited(chunk)  -- the script's body runs under the hook too
  if fn == nil then
    stopped = true
    emit("STOPPED")
    return
  end
  update_fn, next_run = fn, now + (delay or 0)
  emit("LOADED")
end

-- ArduPilot runs each call of a script under a Lua count hook of SCR_VM_I_COUNT
-- VM instructions (default 10000; lua_scripts.cpp): past it the hook raises
-- "Exceeded CPU time", the firmware prints "Lua: <script> exceeded time limit" and
-- removes the script for good. The same here, counted exactly, with the most any
-- call took (the "vm" command prints it). Only the applet's own instructions
-- count: the bindings faked above in Lua are C functions in the firmware.
local vm_steps = 10000
local vm_used, vm_peak, vm_last = 0, 0, 0
local applet_source = "@" .. applet_path
local getinfo = debug.getinfo
local function count_step()
  if getinfo(2, "S").source ~= applet_source then return end
  vm_used = vm_used + 1
  if vm_used > vm_steps then
    debug.sethook()
    error("Exceeded CPU time")
  end
end

function call_limited(fn)
  vm_used = 0
  debug.sethook(count_step, "", 1)
  local ok, a, b = pcall(fn)
  debug.sethook()
  vm_last = vm_used
  if vm_used > vm_peak then vm_peak = vm_used end
  if not ok then
    if tostring(a):find("Exceeded CPU time", 1, true) then
      emit("ERROR " .. applet_path .. " exceeded time limit")
    else
      emit("ERROR " .. tostring(a))
    end
    return nil
  end
  return a, b
end

local function run(ms)
  if not stopped and update_fn == nil then load_applet() end
  if stopped then
    now = now + ms
    return
  end
  local stop = now + ms
  while next_run <= stop do
    now = next_run
    local fn, delay = call_limited(update_fn)
    if fn == nil then
      emit("STOPPED")
      stopped = true
      update_fn = nil
      now = stop
      return
    end
    update_fn, next_run = fn, now + delay
  end
  now = stop
end

local function trace_hook(kind, f)
  local copy = { kind = kind }
  for k, v in pairs(f) do copy[k] = v end
  emit("FIELDS " .. json_object(copy))
end

for line in io.lines() do
  line = line:gsub("#.*", "")
  local words = {}
  for w in line:gmatch("%S+") do words[#words + 1] = w end
  local cmd = words[1]
  if cmd == nil then
    -- blank
  elseif cmd == "param" then
    params[words[2]] = tonumber(words[3])
  elseif cmd == "armed" then
    state.armed = words[2] == "1"
  elseif cmd == "flying" then
    state.flying = words[2] == "1"
  elseif cmd == "mode" then
    state.mode = tonumber(words[2])
  elseif cmd == "setmode_ok" then
    state.setmode_ok = words[2] == "1"
  elseif cmd == "fwtype" then
    state.fwtype = tonumber(words[2])
  elseif cmd == "prx_type" then
    prx_type = tonumber(words[2])
  elseif cmd == "frame" then
    local age = tonumber(words[3] or "0")
    if #queue < QUEUE_MAX then
      queue[#queue + 1] = { raw = to_message_t(unhex(words[2])), ts = now - age }
    else
      emit("QUEUE_FULL")
    end
  elseif cmd == "queue_max" then
    QUEUE_MAX = tonumber(words[2])
  elseif cmd == "trace" then
    TCM_TEST_HOOK = (words[2] == "1") and trace_hook or nil
  elseif cmd == "run" then
    run(tonumber(words[2]))
  elseif cmd == "vm_steps" then
    vm_steps = tonumber(words[2])
  elseif cmd == "vm" then
    emit(string.format("VM peak %d last %d steps %d", vm_peak, vm_last, vm_steps))
  elseif cmd == "stats" then
    if TCM_APPLET then emit("STATS " .. json_object(TCM_APPLET.stats)) end
  else
    emit("ERROR unknown command " .. cmd)
  end
end
