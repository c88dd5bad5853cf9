--[[
pressure_ports.lua: the aircraft's surface pressure ports -> NAMED_VALUE_FLOAT, for the vdm-aero companion.

Every update reads N differential-pressure transducers (TE MS4525DO, I2C) and then sends each port's
differential pressure in Pa with gcs:send_named_float("P00", dp), "P01", ... All sends of one reading come
back to back after the I2C work, because ArduPilot stamps each NAMED_VALUE_FLOAT with millis() at the call
and the companion groups one frame by that time_boot_ms (it tolerates a 1-2 ms straddle). A port whose
reading is stale, faulted or not answering is sent as NaN, not left out: a missing name would hold the
companion's frame open until its timeout, a NaN completes the frame and marks that port lost in it.

Why Lua reads the transducers itself: ArduPilot has at most 2 airspeed instances, and scripts get at most 4
I2C handles in total (SCRIPTING_MAX_NUM_I2C_DEVICE), so this script uses ONE handle and moves it between
addresses with set_address().

Wiring (one I2C bus, VPP_BUS; ArduPilot's bus numbering, as ARSPD_BUS):
  * MS4525DO all at 0x28 (VPP_ADDR) behind TCA9548A multiplexers: mux 0 at VPP_MUX_ADDR (0x70) carries
    ports 0..7 on its channels 0..7, a second mux at VPP_MUX_ADDR+1 (A0 high) ports 8..15, and so on.
    Port i = mux (i // 8), channel (i % 8). Every downstream channel needs its own pull-ups; 3.3 V
    logic, or a level shifter to 5 V transducers.
  * or, without a mux (VPP_MUX_ADDR = 0): port i at address VPP_ADDR + i on VPP_BUS (parts ordered with
    different addresses). The MS4525DO address is fixed by the part number (0x28 for the common parts).
  * Transducer port 1 to the surface tap, port 2 to the static reference (a static line shared by all
    ports): the companion takes dp = p_port - p_static. The sign follows the TE datasheet (counts rise with
    P1 - P2); AP_Airspeed_MS4525 negates it for its pitot plumbing, this script does not.
  * Keep tubes short and of equal length: pneumatic lag grows with length and unequal lags skew the ports.
  * No other device at 0x28 on this bus (e.g. an ARSPD_TYPE=MS4525 pitot on the same ARSPD_BUS).

ArduPilot setup: SCR_ENABLE = 1, reboot; copy this file to APM/scripts/ on the SD card (MAVFTP); set the
VPP_ parameters; reboot (VPP_BUS is read once). SCR_HEAP_SIZE: this script keeps ~11 kB (measured under
stock Lua 5.3 after a GC; ~25 kB with GC headroom), so the board default (43 kB on small boards, 100-200 kB
on H7 class) does for it alone; with other scripts on a small board set 65536 or more. SCR_DEBUG_OPTS bit 1
prints each script's memory and run time on the autopilot. ~1600 VM instructions per update at 12 ports:
far below SCR_VM_I_COUNT (10000).
Telemetry budget and serial settings: docs/lua-script.md in the vdm-aero repository.

Written for the Lua 5.3 that ArduPilot embeds (no 5.4-only syntax); tested under lua5.3/lua5.4 with stubs.
--]]

local PARAM_TABLE_KEY = 161 -- unique among this autopilot's scripts (0..200); change it if add_table fails
local PARAM_PREFIX = "VPP_"
local NAME_PREFIX = "P" -- port names P00, P01, ...: the companion's ports.names must list the same names
local NAME_MAX = 10 -- NAMED_VALUE_FLOAT name field; longer names are silently truncated by ArduPilot
local MAX_PORTS = 32 -- 4 muxes; beyond that the telemetry budget is the limit, not the wiring
local MUX_CHANNELS = 8 -- TCA9548A
local MUX_ADDR_MIN, MUX_ADDR_MAX = 0x70, 0x77 -- TCA9548A address range (A2..A0)

-- MS4525DO transfer function (datasheet, output type A): 14-bit counts, 10 % .. 90 % of 16383 spans
-- -range .. +range psi. Type B parts (5 % .. 95 %) would need 0.05 / 0.90 here.
local COUNTS_FULL = 16383
local COUNTS_AT_PMIN = 0.1 * COUNTS_FULL
local COUNTS_SPAN = 0.8 * COUNTS_FULL
local PSI_TO_PA = 6894.757
local STATUS_STALE = 2 -- status bits (top 2 of byte 1): 0 normal, 1 reserved, 2 stale, 3 fault

local TEXT_INTERVAL_MS = 5000 -- at most one fault text per 5 s: a dead sensor must not flood the link
local DISABLED_PERIOD_MS = 1000 -- poll VPP_ENABLE while disabled, so enabling needs no reboot
local STARTUP_DELAY_MS = 1000 -- let the transducers power up before the first read
local SEV_WARNING, SEV_INFO = 4, 6 -- MAV_SEVERITY
local NAN = 0 / 0

assert(#NAME_PREFIX + 2 <= NAME_MAX, "VPP: NAME_PREFIX too long for NAMED_VALUE_FLOAT")

-- Parameters --------------------------------------------------------------------------------------------
-- 8 slots for the 8 parameters
assert(param:add_table(PARAM_TABLE_KEY, PARAM_PREFIX, 8), "VPP: could not add param table (key in use?)")

-- Parameter() + init() works on older firmware too (Parameter(name) came later)
local function bind_add_param(name, idx, default_value)
  assert(param:add_param(PARAM_TABLE_KEY, idx, name, default_value), "VPP: could not add param " .. name)
  local p = Parameter()
  assert(p:init(PARAM_PREFIX .. name), "VPP: could not find param " .. name)
  return p
end

--[[
  // @Param: VPP_ENABLE
  // @DisplayName: Pressure ports enable
  // @Description: 1 reads the ports and sends them; 0 leaves the I2C bus alone and sends nothing
  // @Values: 0:Disabled,1:Enabled
--]]
local VPP_ENABLE = bind_add_param("ENABLE", 1, 1)
--[[
  // @Param: VPP_RATE_HZ
  // @DisplayName: Pressure ports rate
  // @Description: Readings per second; every reading sends VPP_COUNT NAMED_VALUE_FLOAT messages
  // @Range: 1 100
  // @Units: Hz
--]]
local VPP_RATE_HZ = bind_add_param("RATE_HZ", 2, 50)
--[[
  // @Param: VPP_COUNT
  // @DisplayName: Number of pressure ports
  // @Description: Ports P00 .. P(N-1); port i is mux i // 8, channel i % 8
  // @Range: 1 32
--]]
local VPP_COUNT = bind_add_param("COUNT", 3, 12)
--[[
  // @Param: VPP_BUS
  // @DisplayName: I2C bus of the pressure ports
  // @Description: ArduPilot I2C bus number (as ARSPD_BUS); read once, reboot after changing it
  // @Range: 0 4
--]]
local VPP_BUS = bind_add_param("BUS", 4, 0)
--[[
  // @Param: VPP_MUX_ADDR
  // @DisplayName: First TCA9548A address
  // @Description: 7-bit address of the mux of ports 0..7 (next mux at +1); 0: no mux, port i at VPP_ADDR+i
  // @Range: 0 119
--]]
local VPP_MUX_ADDR = bind_add_param("MUX_ADDR", 5, 0x70)
--[[
  // @Param: VPP_ADDR
  // @DisplayName: Transducer address
  // @Description: 7-bit I2C address of the MS4525DO transducers (0x28 = 40 for the standard part)
  // @Range: 1 127
--]]
local VPP_ADDR = bind_add_param("ADDR", 6, 0x28)
--[[
  // @Param: VPP_RANGE_PSI
  // @DisplayName: Transducer range
  // @Description: Full scale of the +-range MS4525DO part (the 001 in MS4525DO-DS5AI001DP is 1 psi)
  // @Units: psi
--]]
local VPP_RANGE_PSI = bind_add_param("RANGE_PSI", 7, 1)

--[[
  // @Param: VPP_LOG
  // @DisplayName: Log the ports
  // @Description: 1 also writes every reading to the DataFlash log, so that a log replay or an in-flight calibration has the ports without a telemetry log: messages VPP0 (ports 0..11), VPP1 (12..23), VPP2 (24..31), each TimeUS and one float per port [Pa] named like the port (NaN for a lost port, ports beyond VPP_COUNT NaN)
  // @Values: 0:Disabled,1:Enabled
--]]
local VPP_LOG = bind_add_param("LOG", 8, 1)

-- State ---------------------------------------------------------------------------------------------------
local names = {} -- port index (0-based) -> name, built once: no string garbage per update
for i = 0, MAX_PORTS - 1 do
  names[i] = string.format("%s%02d", NAME_PREFIX, i)
end

local dev = nil -- the one I2C handle
local dev_bus = nil
local mux_mask = {} -- mux address -> open channel mask; nil: unknown (after a failed write), so re-write it
local values = {} -- port index -> Pa of the current reading
local cfg = { period_ms = 20 }
local due_ms = nil -- when the current update was due; keeps a start-to-start cadence
local last_text_ms = nil
local bad_count, bad_last = 0, "" -- bad readings since the last fault text, and the latest one
local announced = false

-- DataFlash: AP_Logger takes at most 14 format characters and 56 label characters from a script (it adds
-- TimeUS); 12 ports ("P00,...,P11", 47 characters) per message. Fixed layouts: a message's format must not
-- change during a log, so every chunk always carries its 12 ports (NaN beyond VPP_COUNT).
local LOG_CHUNK = 12
local log_chunks = {} -- chunk index -> { name, labels, format, first port }
for c = 0, (MAX_PORTS - 1) // LOG_CHUNK do
  local first = c * LOG_CHUNK
  local last = math.min(MAX_PORTS, first + LOG_CHUNK) - 1
  local labels = {}
  for i = first, last do
    labels[#labels + 1] = names[i]
  end
  log_chunks[c] = { "VPP" .. c, table.concat(labels, ","), string.rep("f", last - first + 1), first, last }
end

local function now_ms()
  return millis():toint()
end

local function warn(text)
  -- rate-limited: returns true when the text went out
  local t = now_ms()
  if last_text_ms ~= nil and t - last_text_ms < TEXT_INTERVAL_MS then
    return false
  end
  last_text_ms = t
  gcs:send_text(SEV_WARNING, string.sub(text, 1, 50)) -- STATUSTEXT holds 50 characters
  return true
end

local function read_config()
  local rate_hz = math.max(1, math.min(100, VPP_RATE_HZ:get()))
  cfg.period_ms = math.floor(1000 / rate_hz + 0.5) -- the scheduler takes whole milliseconds
  cfg.count = math.floor(math.max(1, math.min(MAX_PORTS, VPP_COUNT:get())))
  cfg.bus = math.floor(VPP_BUS:get())
  cfg.mux = math.floor(VPP_MUX_ADDR:get())
  cfg.addr = math.floor(VPP_ADDR:get())
  cfg.range_psi = VPP_RANGE_PSI:get()
  cfg.last_mux = cfg.mux + (cfg.count - 1) // MUX_CHANNELS
  if cfg.mux ~= 0 and (cfg.mux < MUX_ADDR_MIN or cfg.last_mux > MUX_ADDR_MAX) then
    error(string.format("VPP_MUX_ADDR %d: muxes must be 0x70..0x77", cfg.mux), 0)
  end
  if cfg.addr < 1 or cfg.addr + (cfg.mux == 0 and cfg.count - 1 or 0) > 127 then
    error(string.format("VPP_ADDR %d out of range", cfg.addr), 0)
  end
  if not (cfg.range_psi > 0) then
    error("VPP_RANGE_PSI must be > 0", 0)
  end
end

-- I2C -----------------------------------------------------------------------------------------------------
local function mux_write(addr, mask)
  dev:set_address(addr)
  local ok = dev:transfer(string.char(mask), 0) ~= nil
  mux_mask[addr] = ok and mask or nil
  return ok
end

-- Route the bus to port i. All transducers share one address, so every other mux must be closed first:
-- two open channels would put two 0x28s on the wire (wired-AND garbage, not an error).
local function select_port(i)
  if cfg.mux == 0 then
    return true
  end
  local target = cfg.mux + i // MUX_CHANNELS
  for m = cfg.mux, cfg.last_mux do
    if m ~= target and mux_mask[m] ~= 0 and not mux_write(m, 0) then
      return false
    end
  end
  -- on failure the previous channel may still be open: the caller must not read, it would get another port
  return mux_write(target, 1 << (i % MUX_CHANNELS))
end

-- Leave every channel closed so ArduPilot's own drivers on this bus never see our transducers.
local function close_muxes()
  if cfg.mux == 0 then
    return
  end
  for m = cfg.mux, cfg.last_mux do
    if mux_mask[m] ~= 0 then
      mux_write(m, 0)
    end
  end
end

local function counts_to_pa(counts)
  local psi = (counts - COUNTS_AT_PMIN) * (2 * cfg.range_psi) / COUNTS_SPAN - cfg.range_psi
  return psi * PSI_TO_PA
end

-- One port: Pa, or NaN and why.
local function read_port(i)
  if not select_port(i) then
    return NAN, "mux"
  end
  dev:set_address(cfg.mux == 0 and cfg.addr + i or cfg.addr)
  local raw = dev:transfer("", 4) -- Read_DF4: a plain 4-byte read, no command byte
  if raw == nil or #raw < 4 then
    return NAN, "no answer"
  end
  -- measurement request for the next reading: needed by sleep-mode parts, harmless for the others
  -- (AP_Airspeed_MS4525 does the same)
  dev:transfer(string.char(0), 0)
  local b1, b2, b3, b4 = string.byte(raw, 1, 4)
  local status = b1 >> 6
  if status ~= 0 then
    return NAN, status == STATUS_STALE and "stale" or "fault"
  end
  local dp_counts = ((b1 & 0x3F) << 8) | b2
  local temp_counts = ((b3 << 8) | b4) >> 5
  -- all-zero / all-one words are a stuck bus or a lifted ground, not a pressure (as AP_Airspeed_MS4525)
  if dp_counts == 0 or dp_counts == 0x3FFF or temp_counts == 0 or temp_counts == 0x7FF then
    return NAN, "rail"
  end
  return counts_to_pa(dp_counts), nil
end

-- Update --------------------------------------------------------------------------------------------------
local function update()
  if VPP_ENABLE:get() < 0.5 then
    return false
  end
  read_config()
  if dev == nil then
    dev = i2c:get_device(cfg.bus, cfg.addr) -- raises if the bus does not exist; retried next update
    dev:set_retries(2) -- a retry is cheaper than a NaN; more would stretch the update
    dev_bus = cfg.bus
  elseif dev_bus ~= cfg.bus then
    warn("VPP: reboot to apply VPP_BUS")
  end
  if not announced then
    announced = true
    gcs:send_text(SEV_INFO, string.format("VPP: %d ports at %d ms on bus %d", cfg.count, cfg.period_ms, dev_bus))
  end

  -- all I2C first ...
  for i = 0, cfg.count - 1 do
    local pa, why = read_port(i)
    values[i] = pa
    if why ~= nil then
      bad_count = bad_count + 1
      bad_last = names[i] .. " " .. why
    end
  end
  close_muxes()
  -- ... then every send back to back: one millis() for the whole frame
  for i = 0, cfg.count - 1 do
    gcs:send_named_float(names[i], values[i])
  end
  if VPP_LOG:get() >= 0.5 then
    for i = cfg.count, MAX_PORTS - 1 do
      values[i] = NAN
    end
    for c = 0, (cfg.count - 1) // LOG_CHUNK do
      local ch = log_chunks[c]
      logger:write(ch[1], ch[2], ch[3], table.unpack(values, ch[4], ch[5]))
    end
  end

  if bad_count > 0 and warn(string.format("VPP: %d bad readings, last %s", bad_count, bad_last)) then
    bad_count = 0
  end
  return true
end

-- Delay to the next update so that updates START every period: the scheduler counts the delay from the
-- return, and 12 ports of I2C take a few ms (~3 ms at 400 kHz): 50 Hz would otherwise run at ~43 Hz.
local function next_delay(start_ms)
  if due_ms == nil or start_ms - due_ms >= cfg.period_ms then
    due_ms = start_ms -- first run, or fell a whole period behind: resynchronise instead of bursting
  end
  due_ms = due_ms + cfg.period_ms
  return math.max(1, due_ms - now_ms())
end

-- The protected call keeps the script alive in flight: a Lua error (I2C driver fault, bad parameter) is
-- reported, at the limited rate, and the next update is scheduled as usual.
local function protected_update()
  local start_ms = now_ms()
  local ok, result = pcall(update)
  if not ok then
    mux_mask = {} -- unknown after an error half way: close/re-write every mux next time
    -- "pressure_ports.lua:177: msg" -> "line 177: msg": STATUSTEXT has 50 characters, keep the message
    warn("VPP: " .. string.gsub(tostring(result), "^[^:]*:(%d+): ", "line %1: "))
  elseif not result then
    due_ms = nil
    return protected_update, DISABLED_PERIOD_MS
  end
  return protected_update, next_delay(start_ms)
end

return protected_update, STARTUP_DELAY_MS
