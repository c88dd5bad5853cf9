--[[
Runs an ArduPilot Lua script against tests/lua/ardupilot_stubs.lua the way AP_Scripting does, and prints
every recorded call as one tab-separated line on stdout.

  lua5.4 tests/lua/run_script.lua SCRIPT SCENARIO

SCENARIO is a Lua file returning { params = {...}, updates = K, frames = {...}, ... } (see the stubs).
The script's chunk runs once (its top level: parameters), and returns (function, delay_ms); as in
AP_Scripting, the function runs again delay_ms after the millis() at which the previous run returned,
and the delay must be an integer (luaL_checkinteger). A script error, a non-integer delay or a nil return
ends the run as it would end the script on the autopilot: DIED / END lines.

Lines: CALL k ms | RET k ms delay | MUX_OPEN k n | NVF k ms name value | TEXT k ms severity text |
XFER k address n_sent n_read result | I2C_DEV k bus address | ADD_TABLE key prefix n |
ADD_PARAM key idx name default | DIED k message | END k
--]]

local here = arg[0]:match("^(.*)/") or "."
local stubs = dofile(here .. "/ardupilot_stubs.lua")
local scenario = dofile(arg[2])

local function clean(v)
  return (tostring(v):gsub("[\t\n]", " "))
end

local function emit(...)
  local parts = table.pack(...)
  for i = 1, parts.n do
    parts[i] = clean(parts[i])
  end
  io.stdout:write(table.concat(parts, "\t", 1, parts.n), "\n")
end

local env, hooks = stubs.new(scenario, emit)
-- AP_Scripting's sandbox: the bindings and the safe parts of the standard library (no io, os, load, require)
for _, name in ipairs({
  "assert", "error", "ipairs", "next", "pairs", "pcall", "xpcall", "select", "tonumber", "tostring", "type",
  "rawequal", "rawget", "rawlen", "rawset", "getmetatable", "setmetatable",
}) do
  env[name] = _G[name]
end
env.string, env.math, env.table = string, math, table

local file = assert(io.open(arg[1], "r"))
local source = file:read("a")
file:close()
local chunk, err = load(source, "@" .. arg[1]:match("[^/]*$"), "t", env)
if chunk == nil then
  emit("DIED", 0, err)
  return
end

-- one run of the script; returns the next function and its start time [ms], or nil when the script ended
local function run(fn, k)
  local ok, next_fn, delay = pcall(fn)
  local t_ms = math.floor(hooks.clock_us() / 1000)
  if not ok then
    emit("DIED", k, next_fn)
    return nil
  end
  if next_fn == nil then
    emit("END", k)
    return nil
  end
  local d = math.tointeger(delay)
  if type(next_fn) ~= "function" or d == nil or d < 0 then
    emit("DIED", k, "bad reschedule: " .. tostring(next_fn) .. ", " .. tostring(delay))
    return nil
  end
  emit("RET", k, t_ms, d)
  emit("MUX_OPEN", k, hooks.open_channels())
  return next_fn, t_ms + d
end

hooks.begin_update(0, 0)
local fn, start_ms = run(chunk, 0)
for k = 1, scenario.updates or 1 do
  if fn == nil then
    break
  end
  hooks.begin_update(k, start_ms * 1000)
  emit("CALL", k, start_ms)
  fn, start_ms = run(fn, k)
end
