--[[
Stubbed ArduPilot scripting bindings for tests/test_lua_ports_script.py.

Only what a script may really call, with the real signatures and the real checks the bindings make
(sources: libraries/AP_Scripting/docs/docs.lua, lua_bindings.cpp, generator/description/bindings.desc):
  millis() -> uint32_t userdata (:toint(), :tofloat()); no arithmetic here, so a script relying on it fails
  param:add_table(key 0..200, prefix, n 1..63), param:add_param(key, idx 1..63, name, default)
  Parameter() + :init(name) / Parameter(name); :get() -> number
  i2c:get_device(bus 0..4, address 0..128 [, clock, smbus]): 4 handles for all scripts together
    (SCRIPTING_MAX_NUM_I2C_DEVICE)
  device:set_address(a), :set_retries(n), :transfer(send_string, read_len 0..255) -> string | nil
  gcs:send_named_float(name, value), gcs:send_text(severity 0..7, text)
  mavlink:send_chan(chan, msgid, payload) -> true | false (no tx space) | nil (no such channel): as
    lua_mavlink_send_chan; it knows DEBUG_FLOAT_ARRAY (350) only, and errors as the binding would misbehave
    on a payload shorter than the message's max_msg_len (the binding reads that many bytes). Absent with
    scenario.no_mavlink (firmware before 4.5); scenario.mav_channels (default 3) channels exist;
    scenario.tx_full[k]: no tx space in update k

Every call is recorded through emit(kind, ...) as one tab-separated line. The clock is simulated: an I2C
transfer takes its bus time at 400 kHz, so a script that sends between reads gets different millis().

The bus: scenario.frames[k][port] holds the 4 raw bytes port `port` (0-based) returns in update k.
Wiring follows the VPP_ parameters: port p sits behind TCA9548A (mux + p // 8), channel p % 8, at `addr`;
without a mux (mux 0) at addr + p. Each read consumes the sample: a second read sees status 2 (stale)
unless a measurement request (Read_MR) came in between, as the transducer does. Open channels on several
muxes put several transducers on the wire: the read returns their bytes ANDed (open drain), i.e. wrong
values, as on a real bus.
scenario.sleep_mode: the transducers convert only on Read_MR (the datasheet's sleep-mode parts).
Faults: scenario.nack[port] (transducer never answers), scenario.mux_fail[k][port] (the mux write that
would route to `port` is not acknowledged in update k, leaving the previous channel open),
scenario.raise_at[k] (the first transfer of update k raises a Lua error, as a binding does on bad input).
--]]

local M = {}

local I2C_BIT_US = 2.5 -- 400 kHz
local I2C_OVERHEAD_US = 20 -- start/stop and driver time per transfer

local function fmt_value(v)
  if type(v) == "number" then
    return string.format("%.17g", v)
  end
  return tostring(v)
end

local function check_int(v, lo, hi, what)
  if math.type(v) ~= "integer" and not (type(v) == "number" and math.tointeger(v)) then
    error(string.format("%s: expected an integer, got %s", what, tostring(v)), 3)
  end
  v = math.tointeger(v)
  if v < lo or v > hi then
    error(string.format("%s: %d out of range %d..%d", what, v, lo, hi), 3)
  end
  return v
end

function M.new(scenario, emit)
  local S = {
    clock_us = 0,
    update = 0, -- current update number (0: the load)
    params = {}, -- name -> value
    defined = {}, -- name -> true once add_param'ed
    tables = {}, -- key -> {prefix, n}
    devices = 0,
    mux = {}, -- mux address -> channel mask
    fresh = {}, -- port -> sample not read yet in this update
    raised = {}, -- update -> true once the injected error was raised
  }
  for name, value in pairs(scenario.params or {}) do
    S.params[name] = value -- the user's values (saved in EEPROM), they win over add_param defaults
  end

  local function p(name)
    return S.params[name]
  end

  local env = {}

  -- millis ----------------------------------------------------------------------------------------------
  local u32 = {}
  u32.__index = u32
  function u32:toint()
    return self.v
  end
  function u32:tofloat()
    return self.v + 0.0
  end
  u32.__tostring = function(self)
    return tostring(self.v)
  end
  local boot_us = (scenario.boot_ms or 0) * 1000 -- the autopilot's uptime when the run starts
  local function now_ms()
    return math.floor((S.clock_us + boot_us) / 1000)
  end
  env.millis = function()
    return setmetatable({ v = now_ms() }, u32)
  end
  env.micros = function()
    return setmetatable({ v = math.floor(S.clock_us + boot_us) }, u32)
  end

  -- param / Parameter -----------------------------------------------------------------------------------
  local param = {}
  function param:add_table(key, prefix, n)
    key = check_int(key, 0, 200, "add_table key")
    n = check_int(n, 1, 63, "add_table num_params")
    emit("ADD_TABLE", key, prefix, n)
    if S.tables[key] and S.tables[key].prefix ~= prefix then
      return false
    end
    S.tables[key] = { prefix = prefix, n = n }
    return true
  end
  function param:add_param(key, idx, name, default)
    key = check_int(key, 0, 200, "add_param key")
    idx = check_int(idx, 1, 63, "add_param index")
    emit("ADD_PARAM", key, idx, name, fmt_value(default))
    local t = S.tables[key]
    if t == nil or idx > t.n then
      return false
    end
    local full = t.prefix .. name
    if #full > 16 then -- AP_MAX_NAME_SIZE
      return false
    end
    S.defined[full] = true
    if S.params[full] == nil then
      S.params[full] = default
    end
    return true
  end
  function param:get(name)
    return S.params[name]
  end
  env.param = param

  local param_ud = {}
  param_ud.__index = param_ud
  function param_ud:init(name)
    if S.params[name] == nil then
      return false
    end
    self.name = name
    return true
  end
  function param_ud:get()
    if self.name == nil then
      error("Parameter not initialised", 2)
    end
    local v = S.params[self.name]
    return v + 0.0 -- AP_Param hands out floats
  end
  function param_ud:set(v)
    S.params[self.name] = v
    return true
  end
  env.Parameter = function(name)
    local obj = setmetatable({}, param_ud)
    if name ~= nil and not obj:init(name) then
      error("No parameter: " .. tostring(name), 2)
    end
    return obj
  end

  -- gcs -------------------------------------------------------------------------------------------------
  local gcs = {}
  function gcs:send_named_float(name, value)
    if type(name) ~= "string" then
      error("send_named_float: name must be a string", 2)
    end
    if type(value) ~= "number" then
      error("send_named_float: value must be a number", 2)
    end
    emit("NVF", S.update, now_ms(), name, fmt_value(value))
  end
  function gcs:send_text(severity, text)
    severity = check_int(severity, 0, 7, "send_text severity")
    emit("TEXT", S.update, now_ms(), severity, (tostring(text):gsub("[\t\n]", " ")))
  end
  env.gcs = gcs

  -- mavlink (4.5+) ----------------------------------------------------------------------------------------
  if not scenario.no_mavlink then
    local max_msg_len = { [350] = 252 } -- DEBUG_FLOAT_ARRAY
    local mavlink = {}
    function mavlink:send_chan(chan, msgid, payload)
      chan = check_int(chan, 0, 255, "send_chan chan")
      msgid = check_int(msgid, 0, 16777215, "send_chan msgid")
      if max_msg_len[msgid] == nil then
        error(string.format("Unknown MAVLink message ID (%d)", msgid), 2)
      end
      if type(payload) ~= "string" or #payload < max_msg_len[msgid] then
        error(string.format("send_chan: payload of %s bytes, message %d reads %d", #tostring(payload), msgid,
          max_msg_len[msgid]), 2)
      end
      if chan >= (scenario.mav_channels or 3) then
        return nil
      end
      local full = scenario.tx_full and scenario.tx_full[S.update]
      emit("MAV", S.update, now_ms(), chan, msgid, (payload:gsub(".", function(c)
        return string.format("%02x", c:byte())
      end)), tostring(not full))
      return not full
    end
    env.mavlink = mavlink
  end

  -- logger (AP_Scripting's logger:write checks, lua_bindings.cpp: name ≤ 4, labels < 57, format < 15
  -- characters; as many values as format characters; scripts may use i, L, e, f, n, M, B, I, E, N)
  local logger = {}
  local formats = {}
  function logger:write(name, labels, fmt, ...)
    if type(name) ~= "string" or #name > 4 then
      error("Name must be 4 or less chars long", 2)
    end
    if type(labels) ~= "string" or #labels >= 57 then
      error("labels must be less than 57 chars long", 2)
    end
    if type(fmt) ~= "string" or #fmt >= 15 or fmt:find("[^iLefnMBIEN]") then
      error("bad format " .. tostring(fmt), 2)
    end
    local n = select("#", ...)
    local _, commas = labels:gsub(",", "")
    if n ~= #fmt or commas + 1 ~= #fmt then
      error("logger:write: " .. n .. " values, " .. (commas + 1) .. " labels for format " .. fmt, 2)
    end
    local key = labels .. "|" .. fmt
    if formats[name] ~= nil and formats[name] ~= key then
      error("logger:write: " .. name .. " changed its labels or format during the log", 2)
    end
    formats[name] = key
    local vals = {}
    for i = 1, n do
      local v = select(i, ...)
      if type(v) ~= "number" then
        error("logger:write: value " .. i .. " is not a number", 2)
      end
      vals[i] = fmt_value(v)
    end
    emit("LOG", S.update, now_ms(), name, labels, table.concat(vals, ","))
  end
  env.logger = logger

  -- the simulated bus -------------------------------------------------------------------------------------
  local function wiring()
    local mux = math.tointeger(p("VPP_MUX_ADDR")) or 0
    local addr = math.tointeger(p("VPP_ADDR")) or 0x28
    local count = math.tointeger(p("VPP_COUNT")) or 0
    return mux, addr, count
  end

  local function port_bytes(port)
    local frame = scenario.frames and scenario.frames[S.update]
    local b = frame and frame[port]
    if b == nil then
      return { 0xFF, 0xFF, 0xFF, 0xFF } -- no data for this update: a stuck-high bus
    end
    b = { b[1], b[2], b[3], b[4] }
    if not S.fresh[port] then
      b[1] = (b[1] & 0x3F) | 0x80 -- read before a new conversion: status 2, stale
    end
    return b
  end

  -- ports whose transducer answers at `address` now
  local function reachable(address)
    local mux, addr, count = wiring()
    local out = {}
    for port = 0, count - 1 do
      local here
      if mux == 0 then
        here = (address == addr + port)
      else
        local m = mux + port // 8
        here = (address == addr) and (((S.mux[m] or 0) >> (port % 8)) & 1) == 1
      end
      if here and not (scenario.nack and scenario.nack[port]) then
        out[#out + 1] = port
      end
    end
    return out
  end

  local function transfer(address, send, read_len)
    local mux, _, count = wiring()
    -- a mux write
    if mux ~= 0 and address >= mux and address <= mux + (count - 1) // 8 and #send == 1 and read_len == 0 then
      local mask = string.byte(send)
      local fails = scenario.mux_fail and scenario.mux_fail[S.update]
      if fails then
        for port in pairs(fails) do
          if mux + port // 8 == address and mask == (1 << (port % 8)) then
            return nil -- not acknowledged: the previous channel stays open
          end
        end
      end
      S.mux[address] = mask
      return ""
    end
    local ports = reachable(address)
    if #ports == 0 then
      return nil -- nobody acknowledged the address
    end
    if #send == 0 and read_len >= 1 then -- Read_DF: plain read
      local acc = { 0xFF, 0xFF, 0xFF, 0xFF }
      for _, port in ipairs(ports) do
        local b = port_bytes(port)
        for j = 1, 4 do
          acc[j] = acc[j] & b[j]
        end
        S.fresh[port] = false
      end
      local out = {}
      for j = 1, read_len do
        out[j] = string.char(acc[j] or 0xFF)
      end
      return table.concat(out)
    end
    if send == "\0" and read_len == 0 then -- Read_MR: starts a conversion, the next read is fresh
      for _, port in ipairs(ports) do
        S.fresh[port] = true
      end
      return ""
    end
    return nil -- a command this transducer does not know
  end

  local dev_mt = {}
  dev_mt.__index = dev_mt
  function dev_mt:set_address(a)
    self.address = check_int(a, 0, 127, "set_address")
  end
  function dev_mt:set_retries(n)
    self.retries = check_int(n, 0, 255, "set_retries")
  end
  function dev_mt:transfer(send, read_len)
    if type(send) ~= "string" then
      error("transfer: bytes to send must be a string", 2)
    end
    read_len = check_int(read_len, 0, 255, "transfer read_length")
    S.clock_us = S.clock_us + I2C_OVERHEAD_US + (1 + #send + read_len) * 9 * I2C_BIT_US
    if scenario.raise_at and scenario.raise_at[S.update] and not S.raised[S.update] then
      S.raised[S.update] = true
      emit("XFER", S.update, self.address, #send, read_len, "raise")
      error("simulated I2C driver fault", 2)
    end
    local result = transfer(self.address, send, read_len)
    emit("XFER", S.update, self.address, #send, read_len, result and "ok" or "nil")
    return result
  end
  function dev_mt:read_registers()
    error("read_registers: not expected from this script", 2)
  end

  local i2c = {}
  function i2c:get_device(bus, address, clock, smbus)
    bus = check_int(bus, 0, 4, "get_device bus")
    address = check_int(address, 0, 128, "get_device address")
    emit("I2C_DEV", S.update, bus, address)
    if S.devices >= 4 then
      error("no i2c devices available", 2)
    end
    S.devices = S.devices + 1
    return setmetatable({ bus = bus, address = address, retries = 0 }, dev_mt)
  end
  env.i2c = i2c

  -- hooks for the driver ----------------------------------------------------------------------------------
  local hooks = {}
  function hooks.begin_update(k, at_us)
    S.update = k
    S.clock_us = at_us
    local _, _, count = wiring()
    if not scenario.sleep_mode then
      for port = 0, count - 1 do
        S.fresh[port] = true -- a free-running transducer has converted since the last update
      end
    end -- a sleep-mode part converts only on a measurement request
    local changes = scenario.param_changes and scenario.param_changes[k]
    for name, value in pairs(changes or {}) do
      S.params[name] = value
    end
  end
  function hooks.clock_us()
    return S.clock_us
  end
  function hooks.open_channels()
    local n = 0
    for _, mask in pairs(S.mux) do
      if mask ~= 0 then
        n = n + 1
      end
    end
    return n
  end
  return env, hooks
end

return M
