--[[
fake_params.lua - the fakes of ArduPilot's parameter bindings and uint32_t_ud that
both hosts of tcm_avoid.lua share: harness.lua (the command-line tests) and
tcm_companion/sim/vehicle/lua_applet.py (the applet inside the mock autopilot, SITL).

  local uint32 = loadfile(".../fake_params.lua")(params)

params: the table holding parameter values by full name (the host reads and sets it).
Installs the globals param and Parameter (signatures of
libraries/AP_Scripting/docs/docs.lua) and returns uint32(v), the uint32_t_ud stand-in.
--]]

local params = ...

-- uint32_t_ud: docs.lua gives it :toint() and :tofloat()
local U32 = {}
U32.__index = U32
function U32:toint() return self.v end
function U32:tofloat() return self.v + 0.0 end
local function uint32(v) return setmetatable({ v = math.floor(v) & 0xFFFFFFFF }, U32) end

local tables = {}
param = {}
function param:add_table(key, prefix, n)
  tables[key] = { prefix = prefix, n = n }
  return true
end
function param:add_param(key, idx, name, default)
  local t = tables[key]
  if t == nil or idx < 1 or idx > t.n then return false end
  local full = t.prefix .. name
  if #full > 16 then error("parameter name too long: " .. full) end
  if params[full] == nil then params[full] = default end
  return true
end
function param:get(name) return params[name] end
function param:set(name, v) params[name] = v; return true end

local ParamUD = {}
ParamUD.__index = ParamUD
function ParamUD:get() return params[self.name] end
function ParamUD:set(v) params[self.name] = v; return true end
function Parameter(name)
  if params[name] == nil then error("Parameter(): no such parameter " .. tostring(name)) end
  return setmetatable({ name = name }, ParamUD)
end

return uint32
