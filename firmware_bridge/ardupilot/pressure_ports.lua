--[[
pressure_ports.lua: the aircraft's surface pressure ports -> NAMED_VALUE_FLOAT, for the vdm-aero companion.

Every update reads N differential-pressure transducers (TE MS4525DO, I2C) and then sends each port's
differential pressure in Pa with gcs:send_named_float("P00", dp), "P01", ... All sends of one reading come
back to back after the I2C work, because ArduPilot stamps each NAMED_VALUE_FLOAT with millis() at the call
and the companion groups one frame by that time_boot_ms (it tolerates a 1-2 ms straddle). A port whose
reading is stale, faulted or not answering is sent as NaN, not left out: a missing name would hold the
companion's frame open until its timeout, a NaN completes the frame and marks that port lost in it.

Zero offset: an MS4525DO reads several to tens of Pa at zero pressure, different for every part (inside
the datasheet's total error band, +-1 % of span). As AP_Airspeed zeroes its pitot at boot (ARSPD_OFFSET,
AP_Airspeed::calibrate() and update_calibration()), the script zeroes every port: at its first update, after
the startup delay, if the vehicle is not armed, it averages each port's valid readings over at least
CAL_MIN_MS and CAL_MIN_READINGS readings, the first CAL_DISCARD left out, and subtracts that mean from every
later reading of the port. Meanwhile every port is sent (and logged) as NaN: the readings are not yet a
pressure difference the companion may use, and NaNs still complete each frame at the usual cadence (above).
A port without a valid reading in the window keeps offset 0; arming during the window ends it with the
readings so far (none: offsets 0); armed at the first update (an in-flight reboot: AP_Airspeed skips its
calibration after a watchdog reset, which a script cannot see) there is no calibration, offsets 0. Each of
these is said once in a warning text. VPP_SKIP_CAL = 1: no calibration, offsets 0 (the parts' own zero).
So boot the aircraft at rest and out of the wind, taps untouched: wind on a tap or a hand on the tubing
during the window becomes that port's offset for the whole flight.

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
VPP_ parameters; reboot (VPP_BUS is read once; and after replacing a copy older than VPP_MAV_CHAN: the VPP_
table grew to 10 parameters, and AP_Param cannot grow a table without a reboot).

One message per reading (VPP_MAV_CHAN >= 0, ArduPilot 4.5 and later): instead of one NAMED_VALUE_FLOAT per
port to every link, one DEBUG_FLOAT_ARRAY (350: time_usec = the reading's boot time, array_id 0, name "PORTS",
data = the ports in order, NaN for a lost one) on that one MAVLink channel, with mavlink:send_chan: 12 times
fewer messages for the companion to parse (its main CPU cost at 100 Hz) and about 3.5 times fewer bytes (MAVLink 2
trims the unused floats). The channel is MAVLink's numbering (0 = the first serial port with a MAVLink
protocol, ...) and must be the companion's, SERIALn_PROTOCOL = 2 (a MAVLink 1 port drops message ids above
255 without a word); the companion's ports.source: debug_float_array. The binding packs the message's whole
252-byte payload (lua_bindings.cpp lua_mavlink_send_chan reads max_msg_len bytes). Firmware without the binding,
or a channel that does not exist: the named values as before, said once.
SCR_HEAP_SIZE: this script keeps ~31 kB of Lua heap, its compiled code included (stock Lua 5.3 under the
test stubs, after a full GC, 12 ports; 32 ports add < 1 kB; ~1.5 kB more during the boot calibration). The
same measurement gives ~24 kB for the script before the zero-offset calibration (mostly its code makes the
difference); the ~11 kB quoted by earlier versions is not reproduced (it matches their data without the
code). The H7 default (100-200 kB) does; with the 43 kB default of small boards set 65536 or more: the
scripting engine's own tables share that heap. SCR_DEBUG_OPTS bit 1 prints each script's memory and run time
on the autopilot: check there. VM instructions per update (the script's own; binding calls are C, which
SCR_VM_I_COUNT does not count): ~1700 at 12 ports (~1900 while calibrating, ~2200 in the update that ends
the calibration), ~4300 at 32 (~5400 in that update): below SCR_VM_I_COUNT (10000).
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
-- Zero-offset calibration window, after AP_Airspeed::update_calibration() (ArduPilot libraries/AP_Airspeed/
-- AP_Airspeed.cpp: done after >= 1 s and > 15 readings, the first 5 discarded, mean of the healthy ones):
-- the same discard, but 2 s: at 50 Hz ~95 readings per port, so the +-1 count flicker averages to ~0.1 count
-- (0.1 Pa at +-1 psi), and a second of ground wind or handling weighs half as much. 2 s more at boot costs
-- nothing (arming takes far longer). At low VPP_RATE_HZ the 16 readings set the length (16 s at 1 Hz).
local CAL_DISCARD = 5 -- first readings not averaged: the transducer settling after power-up
local CAL_MIN_MS = 2000 -- the window lasts at least this long ...
local CAL_MIN_READINGS = 16 -- ... and at least this many readings (the discarded ones included)
local SEV_WARNING, SEV_INFO = 4, 6 -- MAV_SEVERITY
-- DEBUG_FLOAT_ARRAY (common.xml, id 350) in wire order: time_usec uint64 (two 32-bit words: Lua's integers may be
-- 32-bit), array_id uint16, name char[10], data float[58] (an extension field): 252 bytes
local DFA_MSGID = 350
local DFA_LEN = 58
local DFA_FORMAT = "<I4I4I2c10" .. string.rep("f", DFA_LEN)
local DFA_NAME = "PORTS\0\0\0\0\0" -- padded by hand to char[10]
local DFA_ARRAY_ID = 0 -- the companion's ports.debug_array_id
local NAN = 0 / 0

assert(#NAME_PREFIX + 2 <= NAME_MAX, "VPP: NAME_PREFIX too long for NAMED_VALUE_FLOAT")

-- Parameters --------------------------------------------------------------------------------------------
-- 10 slots for the 10 parameters (indices 1..10; 8 before VPP_SKIP_CAL, 9 before VPP_MAV_CHAN): a table's size can only
-- grow across a reboot (AP_Param), and a new parameter must take the next index, never reuse one
assert(param:add_table(PARAM_TABLE_KEY, PARAM_PREFIX, 10), "VPP: could not add param table (key in use?)")

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
--[[
  // @Param: VPP_SKIP_CAL
  // @DisplayName: Skip the ports' zero-offset calibration
  // @Description: 0: at boot, if not armed, average each port for 2 s at rest and subtract that mean from it from then on (as ARSPD_OFFSET; the ports are sent as NaN meanwhile); keep the aircraft still and out of the wind, ports untouched. 1: no calibration, offsets 0 (the transducers' own zero); unlike ARSPD_SKIP_CAL there is no stored offset to fall back on
  // @Values: 0:Calibrate at boot,1:Skip
--]]
local VPP_SKIP_CAL = bind_add_param("SKIP_CAL", 9, 0)
--[[
  // @Param: VPP_MAV_CHAN
  // @DisplayName: MAVLink channel for one message per reading
  // @Description: -1: each port as a NAMED_VALUE_FLOAT to every link (any firmware). 0 or more: every reading as one DEBUG_FLOAT_ARRAY (name PORTS, array_id 0) on this MAVLink channel alone (0 = the first serial port with MAVLink, ...), the companion's, which must be MAVLink 2 (ArduPilot 4.5 and later; set the companion's ports.source to debug_float_array)
  // @Range: -1 9
--]]
local VPP_MAV_CHAN = bind_add_param("MAV_CHAN", 10, -1)

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
local offsets = {} -- port index -> zero offset [Pa] subtracted from every reading; 0 until calibrated
for i = 0, MAX_PORTS - 1 do
  offsets[i] = 0.0
end
local cal_due = true -- the calibration starts at the first enabled update
local cal = nil -- while it runs: { start_ms, readings, sum = port -> Pa, n = port -> valid readings }
local cal_texts = {} -- calibration warnings not sent yet (warn() is rate-limited), oldest first
local dfa = {} -- DEBUG_FLOAT_ARRAY data, reused; beyond VPP_COUNT 0.0 (trimmed on the wire)
for i = 1, DFA_LEN do
  dfa[i] = 0.0
end
local dfa_count = DFA_LEN -- ports last written into dfa
local array_said = false -- VPP_MAV_CHAN's fallback to named values, said once

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

-- ms since boot -> microseconds as two 32-bit words (low, high), in 16-bit limbs: exact with 32- or 64-bit
-- Lua integers (ms < 2^31; an unsigned 32-bit pattern that a 32-bit Lua holds as negative packs the same)
local function usec_words(ms)
  local p0 = (ms & 0xFFFF) * 1000
  local t = ((ms >> 16) & 0xFFFF) * 1000 + (p0 >> 16)
  return (p0 & 0xFFFF) | ((t & 0xFFFF) << 16), t >> 16
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

-- Zero-offset calibration ------------------------------------------------------------------------------
local function cal_begin()
  cal_due = false
  if VPP_SKIP_CAL:get() >= 0.5 then
    return
  end
  if arming:is_armed() then -- as AP_Airspeed after a watchdog reset: an in-flight reboot is no time to zero
    cal_texts[#cal_texts + 1] = "VPP: armed at start: no zero cal, offsets 0"
    return
  end
  cal = { start_ms = now_ms(), readings = 0, sum = {}, n = {} }
  for i = 0, MAX_PORTS - 1 do
    cal.sum[i], cal.n[i] = 0.0, 0
  end
  gcs:send_text(SEV_INFO, "VPP: zero cal, keep the aircraft still")
end

-- Ends the calibration: offsets from the readings gathered (a port with none keeps 0, and is reported unless
-- no reading was averaged at all: armed that early, the arming text says it), and this update's readings,
-- taken with offset 0, corrected.
local function cal_end()
  local failed = {}
  local zeroed, max_abs, max_name = 0, -1, ""
  for i = 0, cfg.count - 1 do
    local n = cal.n[i]
    if n > 0 then
      local off = cal.sum[i] / n
      offsets[i] = off
      values[i] = values[i] - off
      zeroed = zeroed + 1
      if math.abs(off) > max_abs then
        max_abs, max_name = math.abs(off), names[i]
      end
    else
      failed[#failed + 1] = names[i]
    end
  end
  local averaged = cal.readings > CAL_DISCARD
  cal = nil
  if #failed > 0 and averaged then
    local text = "VPP: no zero cal for " .. table.concat(failed, ",")
    if #text > 50 then
      text = string.format("VPP: no zero cal for %d ports, %s first", #failed, failed[1])
    end
    cal_texts[#cal_texts + 1] = text
  end
  if zeroed > 0 then
    gcs:send_text(SEV_INFO, string.format("VPP: zeroed %d ports, max %.1f Pa %s", zeroed, max_abs, max_name))
  end
end

-- One update's readings (values: Pa with offset 0, NaN if bad) into the running calibration.
local function cal_step()
  if arming:is_armed() then -- armed before the end: keep what was gathered, not this reading
    local used = cal.readings - CAL_DISCARD
    cal_texts[#cal_texts + 1] = used > 0 and string.format("VPP: armed, zero cal cut at %d readings", used)
      or "VPP: armed before zero cal: offsets 0"
    cal_end()
    return
  end
  cal.readings = cal.readings + 1
  if cal.readings > CAL_DISCARD then
    local sum, n = cal.sum, cal.n
    for i = 0, cfg.count - 1 do
      local v = values[i]
      if v == v then -- not NaN: a valid reading
        sum[i] = sum[i] + v
        n[i] = n[i] + 1
      end
    end
  end
  if cal.readings >= CAL_MIN_READINGS and now_ms() - cal.start_ms >= CAL_MIN_MS then
    cal_end()
  end
end

-- VPP_MAV_CHAN >= 0: the reading as one DEBUG_FLOAT_ARRAY on that channel. False: send the named values instead
-- (not asked for; no binding on this firmware; no such channel: the last two said once).
local function send_array()
  local chan = math.floor(VPP_MAV_CHAN:get())
  if chan < 0 then
    return false
  end
  if mavlink == nil then
    if not array_said then
      array_said = true
      cal_texts[#cal_texts + 1] = "VPP: VPP_MAV_CHAN needs 4.5+: named floats"
    end
    return false
  end
  for i = 0, cfg.count - 1 do
    dfa[i + 1] = values[i]
  end
  for i = cfg.count + 1, dfa_count do
    dfa[i] = 0.0
  end
  dfa_count = cfg.count
  local lo, hi = usec_words(now_ms())
  local ok = mavlink:send_chan(chan, DFA_MSGID,
    string.pack(DFA_FORMAT, lo, hi, DFA_ARRAY_ID, DFA_NAME, table.unpack(dfa, 1, DFA_LEN)))
  if ok == nil then -- no such channel (recent firmware says so; older ones must not be given one)
    if not array_said then
      array_said = true
      cal_texts[#cal_texts + 1] = string.format("VPP: no MAVLink channel %d: named floats", chan)
    end
    return false
  end
  if not ok then -- no room in the channel's buffer: the reading is lost, counted as a bad one
    bad_count = bad_count + 1
    bad_last = "link full"
  end
  return true
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
    if cal ~= nil then -- disabled half way: start again, with a new arming check, when enabled
      cal, cal_due = nil, true
    end
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
  if cal_due then
    cal_begin()
  end

  -- all I2C first ...
  for i = 0, cfg.count - 1 do
    local pa, why = read_port(i)
    values[i] = pa - offsets[i] -- NaN stays NaN
    if why ~= nil then
      bad_count = bad_count + 1
      bad_last = names[i] .. " " .. why
    end
  end
  close_muxes()
  if cal ~= nil then
    cal_step()
    if cal ~= nil then -- still running: no pressure difference yet, NaN for every port (header comment)
      for i = 0, cfg.count - 1 do
        values[i] = NAN
      end
    end
  end
  -- ... then every send back to back: one millis() for the whole frame
  if not send_array() then
    for i = 0, cfg.count - 1 do
      gcs:send_named_float(names[i], values[i])
    end
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

  if cal_texts[1] ~= nil then -- a calibration warning goes out once, before the next fault summary
    if warn(cal_texts[1]) then
      table.remove(cal_texts, 1)
    end
  elseif bad_count > 0 and warn(string.format("VPP: %d bad readings, last %s", bad_count, bad_last)) then
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
