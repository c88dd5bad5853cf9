"""The autopilot-side Lua script (firmware_bridge/ardupilot/pressure_ports.lua) under lua5.4 with stubbed
ArduPilot bindings (tests/lua/ardupilot_stubs.lua, driven by tests/lua/run_script.lua).

Expectations are computed here from the raw bytes the simulated transducers return, with the MS4525DO
datasheet's transfer function written out independently of the script.

The stubs have no ``arming`` binding: :data:`ARMING_SHIM` adds ``arming:is_armed()`` to them for every run
(scenario ``armed_from = k``: armed from update k on, 0 = armed at boot; absent: never armed).
"""

from __future__ import annotations

import math
import random
import re
import subprocess
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import require_tool

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "firmware_bridge" / "ardupilot" / "pressure_ports.lua"
DRIVER = ROOT / "tests" / "lua" / "run_script.lua"

# TE MS4525DO datasheet, output type A: 14-bit counts, 10 %..90 % of full scale span -range..+range psi
FULL_COUNTS = 2**14 - 1
PSI_TO_PA = 6894.757
NAME_MAX = 10  # NAMED_VALUE_FLOAT.name is char[10]
AP_MAX_NAME_SIZE = 16  # ArduPilot parameter names
SEV_WARNING = 4  # MAV_SEVERITY: 0..4 are warnings and worse
# VPP_SKIP_CAL = 1: the bus, framing and transfer-function tests read the transducers' own zero from update 1
WIRING = {
    "VPP_COUNT": 12,
    "VPP_RATE_HZ": 50,
    "VPP_MUX_ADDR": 0x70,
    "VPP_ADDR": 0x28,
    "VPP_RANGE_PSI": 1,
    "VPP_SKIP_CAL": 1,
}
CALIBRATE = WIRING | {"VPP_SKIP_CAL": 0}  # the default: zero-offset calibration at boot
ZERO_COUNTS = 0.5 * FULL_COUNTS  # 0 Pa on a type-A part: the middle of its 10 %..90 % span
LSB_PA = 2 * PSI_TO_PA / (0.8 * FULL_COUNTS)  # one count of the ±1 psi part, 1.05 Pa
SEV_INFO = 6

# arming:is_armed() for the stubs, installed by `lua -e` before run_script.lua loads them: it wraps the stubs'
# constructor, follows the update number through hooks.begin_update and records each call as ARMED k result
ARMING_SHIM = """
local real_dofile = dofile
function dofile(path)
  local m = real_dofile(path)
  if type(path) == "string" and path:match("ardupilot_stubs%.lua$") then
    local new = m.new
    m.new = function(scenario, emit)
      local env, hooks = new(scenario, emit)
      local k = 0
      local begin = hooks.begin_update
      hooks.begin_update = function(kk, at_us)
        k = kk
        return begin(kk, at_us)
      end
      local arming = {}
      function arming:is_armed()
        local armed = scenario.armed_from ~= nil and k >= scenario.armed_from
        emit("ARMED", k, tostring(armed))
        return armed
      end
      env.arming = arming
      return env, hooks
    end
  end
  return m
end
"""


@pytest.fixture
def lua() -> str:
    return require_tool("lua5.4", "lua5.4")


@pytest.fixture(params=["lua5.4", "lua5.3"])
def any_lua(request: pytest.FixtureRequest) -> str:
    """Both interpreters: lua5.3 is the version ArduPilot embeds."""
    return require_tool(request.param, request.param)


def datasheet_pa(counts: float, range_psi: float) -> float:
    """Inverse of the datasheet's output = 0.8·16383/(Pmax−Pmin)·(P−Pmin) + 0.1·16383, in Pa."""
    p_min, p_max = -range_psi, range_psi
    return ((counts - 0.1 * FULL_COUNTS) * (p_max - p_min) / (0.8 * FULL_COUNTS) + p_min) * PSI_TO_PA


def pack(dp_counts: int, temp_counts: int, status: int = 0) -> list[int]:
    """A Read_DF4 per the datasheet: [S1 S0 P13..P8] [P7..P0] [T10..T3] [T2..T0 x x x x x]."""
    return [(status << 6) | (dp_counts >> 8), dp_counts & 0xFF, temp_counts >> 3, (temp_counts & 0x7) << 5]


def to_lua(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        return "{" + ", ".join(f"[{to_lua(k)}] = {to_lua(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list | tuple):
        return "{" + ", ".join(to_lua(x) for x in v) + "}"
    raise TypeError(v)


@dataclass
class Sensors:
    """Raw counts per update (1-based) and port (0-based), and the bytes the transducers return."""

    counts: dict[int, dict[int, int]]
    frames: dict[int, dict[int, list[int]]]


def make_sensors(seed: int, updates: int, ports: int, status: dict[tuple[int, int], int] | None = None) -> Sensors:
    rng = random.Random(seed)
    counts: dict[int, dict[int, int]] = {}
    frames: dict[int, dict[int, list[int]]] = {}
    for k in range(1, updates + 1):
        counts[k] = {p: rng.randint(1700, 14600) for p in range(ports)}
        if k == 1 and ports >= 3:  # the ends and the middle of the type-A span
            counts[k].update({0: round(0.1 * FULL_COUNTS), 1: round(0.9 * FULL_COUNTS), 2: 8192})
        frames[k] = {p: pack(c, rng.randint(200, 1800), (status or {}).get((k, p), 0)) for p, c in counts[k].items()}
    return Sensors(counts, frames)


@dataclass
class Run:
    rows: list[list[str]]

    def of(self, kind: str) -> list[list[str]]:
        return [r[1:] for r in self.rows if r[0] == kind]

    def values(self, k: int) -> dict[str, float]:
        return {name: float(v) for kk, _, name, v in self.of("NVF") if int(kk) == k}

    def nvf_ms(self, k: int) -> set[int]:
        return {int(ms) for kk, ms, _, _ in self.of("NVF") if int(kk) == k}

    def calls(self) -> list[tuple[int, int]]:
        return [(int(k), int(ms)) for k, ms in self.of("CALL")]

    def warnings(self) -> list[tuple[int, str]]:
        return [(int(ms), text) for _, ms, sev, text in self.of("TEXT") if int(sev) <= SEV_WARNING]

    def infos(self) -> list[str]:
        return [text for _, _, sev, text in self.of("TEXT") if int(sev) == SEV_INFO]


def run_script(lua: str, tmp_path: Path, **scenario: object) -> Run:
    path = tmp_path / f"scenario_{len(list(tmp_path.glob('scenario_*.lua')))}.lua"
    path.write_text("return " + to_lua(scenario) + "\n")
    shim = tmp_path / "arming_shim.lua"
    if not shim.exists():
        shim.write_text(ARMING_SHIM)
    proc = subprocess.run(
        [lua, "-e", f"dofile([[{shim}]])", str(DRIVER), str(SCRIPT), str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    run = Run([line.split("\t") for line in proc.stdout.splitlines()])
    assert not run.of("DIED"), run.of("DIED")
    return run


def port_names(n: int) -> list[str]:
    return [f"P{i:02d}" for i in range(n)]


def script_constant(name: str) -> int:
    m = re.search(rf"^local {name} = (\d+)", SCRIPT.read_text(), re.MULTILINE)
    assert m, f"the script states {name}"
    return int(m.group(1))


def text_interval_ms() -> int:
    return script_constant("TEXT_INTERVAL_MS")


@pytest.mark.parametrize("count", [1, 12, 20])
def test_each_update_sends_every_port_once_at_one_millis(lua: str, tmp_path: Path, count: int) -> None:
    updates = 6
    sensors = make_sensors(1, updates, count)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_COUNT": count}, updates=updates, frames=sensors.frames)
    sends = run.of("NVF")
    assert len(sends) == updates * count
    calls = dict(run.calls())
    assert sorted(calls) == list(range(1, updates + 1))
    for k in calls:
        names = [name for kk, _, name, _ in sends if int(kk) == k]
        assert sorted(names) == port_names(count)  # each port exactly once per update
        assert all(len(n) <= NAME_MAX and n.isascii() for n in names)
        assert len(run.nvf_ms(k)) == 1  # one time_boot_ms for the frame
    if count >= 12:
        # the bus time is simulated: the frame's millis is after the update started, so sending between
        # reads would have given the ports different millis
        assert all(min(run.nvf_ms(k)) > calls[k] for k in calls)


@pytest.mark.parametrize("range_psi", [1, 5])
def test_values_follow_the_datasheet_transfer_function(lua: str, tmp_path: Path, range_psi: int) -> None:
    assert datasheet_pa(0.1 * FULL_COUNTS, range_psi) == pytest.approx(-range_psi * PSI_TO_PA)
    assert datasheet_pa(0.9 * FULL_COUNTS, range_psi) == pytest.approx(range_psi * PSI_TO_PA)
    updates = 4
    sensors = make_sensors(2, updates, 12)
    run = run_script(
        lua, tmp_path, params=WIRING | {"VPP_RANGE_PSI": range_psi}, updates=updates, frames=sensors.frames
    )
    for k in range(1, updates + 1):
        got = run.values(k)
        want = {f"P{p:02d}": datasheet_pa(c, range_psi) for p, c in sensors.counts[k].items()}
        assert got == pytest.approx(want, rel=1e-12, abs=1e-9)
    assert abs(run.values(1)["P02"]) < datasheet_pa(1, range_psi) - datasheet_pa(0, range_psi)  # mid-scale ≈ 0


@pytest.mark.parametrize("rate_hz", [50, 25, 30])
def test_updates_start_every_1000_over_rate_ms(lua: str, tmp_path: Path, rate_hz: int) -> None:
    updates = 12
    sensors = make_sensors(3, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_RATE_HZ": rate_hz}, updates=updates, frames=sensors.frames)
    period_ms = round(1000 / rate_hz)
    starts = [ms for _, ms in run.calls()]
    assert len(starts) == updates
    assert {b - a for a, b in pairwise(starts)} == {period_ms}
    # the returned delay counts from the return (as AP_Scripting does), so it makes up for the I2C time
    rets = {int(k): (int(ms), int(d)) for k, ms, d in run.of("RET")}
    for k, start in run.calls():
        ret_ms, delay = rets[k]
        assert ret_ms + delay - start == period_ms


def test_stale_or_faulted_reading_is_nan_for_that_port_only(lua: str, tmp_path: Path) -> None:
    updates = 6
    bad = {(2, 3): 3, (4, 7): 2, (5, 10): 1}  # fault, stale, reserved status bits
    sensors = make_sensors(4, updates, 12, status=bad)
    sensors.frames[3][0] = pack(0x3FFF, 900)  # all-ones pressure word: a stuck bus, not a pressure
    run = run_script(lua, tmp_path, params=WIRING, updates=updates, frames=sensors.frames)
    nan_at = {(3, 0), *bad}
    for k in range(1, updates + 1):
        got = run.values(k)
        assert sorted(got) == port_names(12)
        for p in range(12):
            v = got[f"P{p:02d}"]
            if (k, p) in nan_at:
                assert math.isnan(v), (k, p)
            else:
                assert v == pytest.approx(datasheet_pa(sensors.counts[k][p], 1), rel=1e-12), (k, p)


def test_unanswered_transducer_keeps_the_script_running_and_texts_rate_limited(lua: str, tmp_path: Path) -> None:
    updates = 500  # 10 s at 50 Hz
    sensors = make_sensors(5, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING, updates=updates, frames=sensors.frames, nack={5: True})
    assert len(run.calls()) == updates  # rescheduled every time
    for k in (1, updates // 2, updates):
        got = run.values(k)
        assert math.isnan(got["P05"])
        assert all(math.isfinite(v) for n, v in got.items() if n != "P05")
    interval = text_interval_ms()
    assert interval >= 1000
    warned = [ms for ms, _ in run.warnings()]
    span_ms = run.calls()[-1][1] - run.calls()[0][1]
    assert 1 <= len(warned) <= span_ms // interval + 1  # 500 bad readings, a handful of texts
    assert all(b - a >= interval for a, b in pairwise(warned))
    assert "P05" in run.warnings()[0][1]


def test_lua_error_in_an_update_is_caught_and_the_script_goes_on(lua: str, tmp_path: Path) -> None:
    updates = 10
    sensors = make_sensors(6, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING, updates=updates, frames=sensors.frames, raise_at={3: True, 4: True})
    assert len(run.calls()) == updates
    assert run.values(3) == {} and run.values(4) == {}  # the error came before any send
    for k in range(5, updates + 1):  # recovered, mux state re-established
        want = {f"P{p:02d}": datasheet_pa(c, 1) for p, c in sensors.counts[k].items()}
        assert run.values(k) == pytest.approx(want, rel=1e-12)
    texts = [text for _, text in run.warnings()]
    assert len(texts) == 1  # updates 3 and 4 are 20 ms apart: one text
    assert "simulated I2C driver fault" in texts[0]


def test_failed_mux_switch_never_reports_another_ports_pressure(lua: str, tmp_path: Path) -> None:
    # at update 2 the write that routes to P09 is not acknowledged: P08's channel stays open, and P08's
    # transducer has a fresh conversion (the script's measurement request), so a blind read gets P08's value
    updates = 3
    sensors = make_sensors(7, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING, updates=updates, frames=sensors.frames, mux_fail={2: {9: True}})
    got = run.values(2)
    assert math.isnan(got["P09"])
    assert got["P08"] == pytest.approx(datasheet_pa(sensors.counts[2][8], 1), rel=1e-12)
    assert got["P10"] == pytest.approx(datasheet_pa(sensors.counts[2][10], 1), rel=1e-12)
    assert math.isfinite(run.values(3)["P09"])


def test_sleep_mode_transducers_are_read_after_a_measurement_request(lua: str, tmp_path: Path) -> None:
    # sleep-mode MS4525DO parts convert only on Read_MR: the first reading after boot is stale (NaN), every
    # later one is fresh because the script requests the next conversion after each read
    updates = 4
    sensors = make_sensors(13, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING, updates=updates, frames=sensors.frames, sleep_mode=True)
    assert all(math.isnan(v) for v in run.values(1).values())
    for k in range(2, updates + 1):
        want = {f"P{p:02d}": datasheet_pa(c, 1) for p, c in sensors.counts[k].items()}
        assert run.values(k) == pytest.approx(want, rel=1e-12)


def test_mux_channels_are_closed_between_updates(lua: str, tmp_path: Path) -> None:
    sensors = make_sensors(8, 4, 20)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_COUNT": 20}, updates=4, frames=sensors.frames)
    open_after = [int(n) for k, n in run.of("MUX_OPEN") if int(k) >= 1]
    assert open_after == [0, 0, 0, 0]  # ArduPilot's own drivers on the bus never meet a transducer


def test_without_a_mux_ports_are_at_consecutive_addresses(lua: str, tmp_path: Path) -> None:
    sensors = make_sensors(9, 3, 3)
    params = {"VPP_COUNT": 3, "VPP_MUX_ADDR": 0, "VPP_ADDR": 0x28, "VPP_RANGE_PSI": 2, "VPP_SKIP_CAL": 1}
    run = run_script(lua, tmp_path, params=params, updates=3, frames=sensors.frames)
    for k in (1, 2, 3):
        want = {f"P{p:02d}": datasheet_pa(c, 2) for p, c in sensors.counts[k].items()}
        assert run.values(k) == pytest.approx(want, rel=1e-12)
    assert {int(addr) for _, addr, *_ in run.of("XFER")} == {0x28, 0x29, 0x2A}


def test_disabled_sends_nothing_and_enabling_needs_no_reboot(lua: str, tmp_path: Path) -> None:
    updates = 6
    sensors = make_sensors(10, updates, 12)
    run = run_script(
        lua,
        tmp_path,
        params=WIRING | {"VPP_ENABLE": 0},
        updates=updates,
        frames=sensors.frames,
        param_changes={4: {"VPP_ENABLE": 1}},
    )
    assert len(run.calls()) == updates  # a disabled script still polls VPP_ENABLE
    for k in (1, 2, 3):
        assert run.values(k) == {}
        assert not [x for x in run.of("XFER") if int(x[0]) == k]  # the bus is left alone
    assert [int(k) for k, *_ in run.of("I2C_DEV")] == [4]  # opened when first enabled
    for k in (4, 5, 6):
        assert sorted(run.values(k)) == port_names(12)


def test_parameters_fit_ardupilot_limits_and_companion_defaults(lua: str, tmp_path: Path) -> None:
    run = run_script(lua, tmp_path, updates=0)
    (table,) = run.of("ADD_TABLE")
    key, prefix, n = int(table[0]), table[1], int(table[2])
    assert 0 <= key <= 200 and prefix == "VPP_" and 1 <= n <= 63  # bindings.desc: add_table uint8_t 0 200, 1 63
    params = {name: (int(idx), float(default)) for k, idx, name, default in run.of("ADD_PARAM") if int(k) == key}
    idxs = [idx for idx, _ in params.values()]
    assert len(set(idxs)) == len(idxs) and all(1 <= i <= n for i in idxs)
    assert all(len(prefix + name) <= AP_MAX_NAME_SIZE for name in params)
    assert {"ENABLE", "RATE_HZ", "COUNT", "BUS", "MUX_ADDR", "RANGE_PSI", "SKIP_CAL"} <= set(params)
    assert params["RATE_HZ"][1] == 50
    assert params["SKIP_CAL"][1] == 0  # zero-offset calibration at boot by default, as ARSPD_SKIP_CAL = 0
    assert n == len(params)  # no unused slot, no parameter beyond the table
    # defaults match the companion's: 12 ports P00..P11
    assert params["COUNT"][1] == 12


def test_one_i2c_handle_for_all_ports(lua: str, tmp_path: Path) -> None:
    # scripts share SCRIPTING_MAX_NUM_I2C_DEVICE = 4 handles in all: one handle, moved with set_address
    sensors = make_sensors(11, 3, 20)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_COUNT": 20}, updates=3, frames=sensors.frames)
    assert [(int(bus), int(addr)) for _, bus, addr in run.of("I2C_DEV")] == [(0, 0x28)]


def test_runs_under_the_lua_53_that_ardupilot_embeds(tmp_path: Path) -> None:
    exe = require_tool("lua5.3", "lua5.3")  # ArduPilot embeds Lua 5.3.6
    sensors = make_sensors(12, 3, 12)
    run = run_script(exe, tmp_path, params=WIRING, updates=3, frames=sensors.frames)
    for k in (1, 2, 3):
        want = {f"P{p:02d}": datasheet_pa(c, 1) for p, c in sensors.counts[k].items()}
        assert run.values(k) == pytest.approx(want, rel=1e-12)


def test_readings_are_logged_to_dataflash_in_fixed_chunks(lua: str, tmp_path: Path) -> None:
    """VPP_LOG = 1 (the default): each update writes VPP0 (P00..P11) and VPP1 (P12..P23, NaN beyond VPP_COUNT)
    with the values it sent, within AP_Scripting's logger limits (checked by the stub); VPP_LOG = 0: nothing."""
    sensors = make_sensors(21, 3, 20)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_COUNT": 20}, updates=3, frames=sensors.frames)
    rows = run.of("LOG")
    assert [(int(k), name) for k, _, name, _, _ in rows] == [(k, n) for k in (1, 2, 3) for n in ("VPP0", "VPP1")]
    for k, ms, _name, labels, vals in rows:
        sent = run.values(int(k))
        logged = dict(zip(labels.split(","), vals.split(","), strict=True))
        assert {int(ms)} == run.nvf_ms(int(k))  # written with the frame's sends
        for port, v in logged.items():
            if port in sent:
                assert float(v) == sent[port] or (math.isnan(float(v)) and math.isnan(sent[port]))
            else:
                assert int(port[1:]) >= 20 and math.isnan(float(v))
    assert set(rows[1][3].split(",")) == set(port_names(24)) - set(port_names(12))
    off = run_script(lua, tmp_path, params=WIRING | {"VPP_LOG": 0}, updates=2, frames=make_sensors(2, 2, 12).frames)
    assert off.of("LOG") == [] and len(off.of("NVF")) == 24


# ---------------------------------------------------------------------------------- zero-offset calibration
@dataclass
class AtRestThenFlow:
    """Transducers with per-port zero offsets: at rest (0 Pa) for updates 1..rest, then random pressures.

    Offsets are m + ½ counts (m integer, |m| ≥ 5) so that a reading is 8192 + m + j (+ noise) counts exactly for a
    true pressure of 8191.5 + j counts: no rounding, the remaining error after the calibration is the offset
    estimate's alone. ``noise`` (±1 count, the part's flicker) is on the readings at rest only."""

    frames: dict[int, dict[int, list[int]]]
    true_pa: dict[int, dict[int, float]]  # per update after the rest, the true Δp of each port
    offset_pa: list[float]


def at_rest_then_flow(
    seed: int, ports: int, rest: int, flow: int, *, noise: bool = True, warmup: int = 0, dead: int | None = None
) -> AtRestThenFlow:
    """``warmup``: the first ``warmup`` readings are 300 counts off (settling); ``dead``: that port reports a fault
    (status 3) at rest."""
    rng = np.random.default_rng(seed)
    m = rng.integers(5, 40, ports) * rng.choice([-1, 1], ports)
    frames: dict[int, dict[int, list[int]]] = {}
    true_pa: dict[int, dict[int, float]] = {}
    for k in range(1, rest + flow + 1):
        j = np.zeros(ports, dtype=np.int64) if k <= rest else rng.integers(-3000, 3001, ports)
        jitter = rng.integers(-1, 2, ports) if (noise and k <= rest) else np.zeros(ports, dtype=np.int64)
        counts = 8192 + m + j + jitter + (300 if k <= warmup else 0)
        temps = rng.integers(200, 1800, ports)
        frames[k] = {
            p: pack(int(counts[p]), int(temps[p]), 3 if (p == dead and k <= rest) else 0) for p in range(ports)
        }
        if k > rest:
            true_pa[k] = {p: datasheet_pa(ZERO_COUNTS + float(j[p]), 1) for p in range(ports)}
    offset_pa = [(float(mm) + 0.5) * LSB_PA for mm in m]
    return AtRestThenFlow(frames, true_pa, offset_pa)


def first_finite_update(run: Run) -> int:
    return min(int(k) for k, _, _, v in run.of("NVF") if math.isfinite(float(v)))


def test_zero_offsets_are_calibrated_at_boot_and_subtracted(any_lua: str, tmp_path: Path) -> None:
    """Every part reads 5.5..39.5 counts (6..42 Pa) at 0 Pa. After the boot window (≥ CAL_MIN_MS at rest, the first
    CAL_DISCARD readings, here a settling transient of 300 counts, left out) each port reads the true Δp within a
    count; during the window every port is sent, and logged, as NaN in complete frames."""
    rest, flow = 150, 20  # 3 s at rest at 50 Hz: longer than the window
    discard, window_ms = script_constant("CAL_DISCARD"), script_constant("CAL_MIN_MS")
    assert discard >= 5 and window_ms >= 1000  # no shorter than AP_Airspeed's boot calibration
    sim = at_rest_then_flow(31, 12, rest, flow, warmup=discard)
    assert min(abs(o) for o in sim.offset_pa) > 5 * LSB_PA  # the uncorrected script would be off by > 5 counts
    run = run_script(any_lua, tmp_path, params=CALIBRATE, updates=rest + flow, frames=sim.frames)
    calls = dict(run.calls())
    done = first_finite_update(run)
    period_ms = 1000 // CALIBRATE["VPP_RATE_HZ"]
    assert window_ms <= calls[done] - calls[1] <= window_ms + 2 * period_ms  # the window, not much more
    for k in range(1, done):  # calibrating: every port, one millis, NaN
        got = run.values(k)
        assert sorted(got) == port_names(12) and all(math.isnan(v) for v in got.values()), k
        assert len(run.nvf_ms(k)) == 1
    logged = [v for kk, _, _, _, vals in run.of("LOG") if int(kk) < done for v in vals.split(",")]
    assert logged and all(math.isnan(float(v)) for v in logged)
    for k in range(done, rest + 1):  # still at rest, now zeroed: 0 Pa within the ±1 count flicker
        assert all(abs(v) <= 1.5 * LSB_PA for v in run.values(k).values()), k
    for k in range(rest + 1, rest + flow + 1):
        want = {f"P{p:02d}": pa for p, pa in sim.true_pa[k].items()}
        got = run.values(k)
        assert sorted(got) == sorted(want)
        for name, pa in want.items():
            assert abs(got[name] - pa) <= 0.5 * LSB_PA, (k, name, got[name] - pa)
    assert run.warnings() == []
    assert sum("zeroed 12 ports" in t for t in run.infos()) == 1


@pytest.mark.parametrize("armed_from", [0, 3])
def test_armed_before_any_reading_is_averaged_keeps_offsets_zero(lua: str, tmp_path: Path, armed_from: int) -> None:
    """Armed at boot (an in-flight reboot: no calibration at all) or within the discarded first readings: offsets
    stay 0, the readings are sent as they are from then on, and one warning says so."""
    updates = 40
    sim = at_rest_then_flow(32, 12, 0, updates)
    run = run_script(lua, tmp_path, params=CALIBRATE, updates=updates, frames=sim.frames, armed_from=armed_from)
    assert first_finite_update(run) == max(1, armed_from)
    for k in range(max(1, armed_from), updates + 1):
        want = {f"P{p:02d}": pa + sim.offset_pa[p] for p, pa in sim.true_pa[k].items()}  # the raw readings
        assert run.values(k) == pytest.approx(want, rel=1e-12, abs=1e-9), k
    armed_texts = [t for _, t in run.warnings() if "armed" in t and "zero cal" in t]
    assert len(armed_texts) == 1
    assert not [t for t in run.infos() if "zeroed" in t]


def test_arming_during_the_window_ends_it_with_the_readings_so_far(lua: str, tmp_path: Path) -> None:
    """Armed at update 30: the offsets are the means of readings 6..29 (exact here: no noise), the reading of
    update 30 is the first corrected one, and a warning says the calibration was cut short."""
    discard = script_constant("CAL_DISCARD")
    armed_at, flow = 30, 20
    sim = at_rest_then_flow(33, 12, armed_at - 1, flow + 1, noise=False, warmup=discard)
    run = run_script(lua, tmp_path, params=CALIBRATE, updates=armed_at + flow, frames=sim.frames, armed_from=armed_at)
    assert first_finite_update(run) == armed_at
    for k in range(armed_at, armed_at + flow + 1):
        want = {f"P{p:02d}": pa for p, pa in sim.true_pa[k].items()}
        assert run.values(k) == pytest.approx(want, rel=1e-9, abs=1e-6), k
    (text,) = [t for _, t in run.warnings() if "armed" in t]
    assert f"{armed_at - 1 - discard} readings" in text


def test_port_without_a_valid_reading_in_the_window_keeps_offset_zero_and_says_so_once(
    lua: str, tmp_path: Path
) -> None:
    """P04 reports a fault all through the window, then recovers: it is sent uncorrected (offset 0), the others
    zeroed, and one warning (rate-limited: it waits for the fault-text interval after the first fault summary)
    names P04. It is not repeated, and the fault summary of the window's bad readings follows it."""
    rest, flow = 150, 500  # 13 s: room for the warning (~6 s), a repeat or the next summary (~11 s)
    sim = at_rest_then_flow(34, 12, rest, flow, dead=4)
    run = run_script(lua, tmp_path, params=CALIBRATE, updates=rest + flow, frames=sim.frames)
    for k in range(rest + 1, rest + flow + 1):
        got = run.values(k)
        assert got["P04"] == pytest.approx(sim.true_pa[k][4] + sim.offset_pa[4], rel=1e-12), k
        for p in set(range(12)) - {4}:
            assert abs(got[f"P{p:02d}"] - sim.true_pa[k][p]) <= 0.5 * LSB_PA, (k, p)
    texts = [t for _, t in run.warnings()]
    cal_texts = [i for i, t in enumerate(texts) if "zero cal" in t]
    assert len(cal_texts) == 1 and "P04" in texts[cal_texts[0]]
    assert any("bad readings, last P04" in t for t in texts[cal_texts[0] + 1 :])
    assert all(b - a >= text_interval_ms() for a, b in pairwise(ms for ms, _ in run.warnings()))
    assert sum("zeroed 11 ports" in t for t in run.infos()) == 1


# ------------------------------------------------------------------- one message per reading (VPP_MAV_CHAN)
def _arrays(run: Run) -> list[tuple[int, int, int, bytes, dict[str, object]]]:
    """Each DEBUG_FLOAT_ARRAY sent: (update, ms, channel, payload, fields), the fields unpacked with pymavlink's own
    wire layout of message 350 (an independent reading of the bytes the script packed)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    layout = mavlink2.MAVLink_debug_float_array_message.unpacker  # "<QH10s58f", wire order
    out = []
    for k, ms, chan, msgid, hexp, ok in run.of("MAV"):
        assert int(msgid) == mavlink2.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY and ok == "true"
        payload = bytes.fromhex(hexp)
        t_us, array_id, name, *data = layout.unpack(payload)
        out.append((int(k), int(ms), int(chan), payload, {"time_usec": t_us, "array_id": array_id, "name": name,
                                                          "data": data}))  # fmt: skip
    return out


def test_one_debug_float_array_per_reading_on_the_companions_channel(any_lua: str, tmp_path: Path) -> None:
    """VPP_MAV_CHAN = 1: every reading is one DEBUG_FLOAT_ARRAY on channel 1 alone, no named values: the ports in
    order (NaN for a faulted one), zeros beyond them (trimmed on the wire: pymavlink's own packing of the same
    message gives the same first 68 bytes and no more), array_id 0, name PORTS, time_usec the frame's millis in µs
    (an autopilot up 83 minutes: above 2^32 µs, the high word in use)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    updates, boot_ms = 5, 5_000_000
    bad = {(3, 4): 3}
    sensors = make_sensors(6, updates, 12, status=bad)
    run = run_script(any_lua, tmp_path, params=WIRING | {"VPP_MAV_CHAN": 1}, updates=updates, frames=sensors.frames,
                     boot_ms=boot_ms)  # fmt: skip
    assert run.of("NVF") == []
    arrays = _arrays(run)
    assert [a[0] for a in arrays] == list(range(1, updates + 1)) and {a[2] for a in arrays} == {1}
    mav = mavlink2.MAVLink(None, 1, 1)
    for k, ms, _, payload, f in arrays:
        assert len(payload) == 252 and ms > boot_ms
        assert f["time_usec"] == ms * 1000 > 2**32 and f["array_id"] == 0 and f["name"] == b"PORTS\0\0\0\0\0"
        data = f["data"]
        assert isinstance(data, list) and data[12:] == [0.0] * 46
        for p in range(12):
            if (k, p) in bad:
                assert math.isnan(data[p])
            else:  # float32 on the wire
                assert data[p] == pytest.approx(datasheet_pa(sensors.counts[k][p], 1), rel=1e-6, abs=1e-3), (k, p)
        if (k, 4) not in bad:  # NaN ≠ NaN: compare the wire bytes on the frames without one
            frame = mav.debug_float_array_encode(f["time_usec"], b"PORTS", 0, data).pack(mav)
            wire = frame[10:-2]  # MAVLink 2: 10-byte header, 2-byte CRC, the payload's trailing zeros trimmed
            assert len(wire) == 20 + 4 * 12 and wire == payload[: len(wire)] and not any(payload[len(wire) :])


@pytest.mark.parametrize(("scenario", "text"), [
    ({"no_mavlink": True}, "VPP: VPP_MAV_CHAN needs 4.5+: named floats"),
    ({"mav_channels": 1}, "VPP: no MAVLink channel 1: named floats"),
], ids=["firmware-before-4.5", "no-such-channel"])  # fmt: skip
def test_without_the_binding_or_the_channel_the_named_values_go_out(
    lua: str, tmp_path: Path, scenario: dict[str, object], text: str
) -> None:
    updates = 4
    sensors = make_sensors(7, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_MAV_CHAN": 1}, updates=updates, frames=sensors.frames,
                     **scenario)  # fmt: skip
    assert run.of("MAV") == [] and len(run.of("NVF")) == 12 * updates
    assert [t for _, t in run.warnings()] == [text]  # said once


def test_a_full_link_loses_that_reading_and_says_so(lua: str, tmp_path: Path) -> None:
    """No tx space in update 2 (send_chan false): that reading is lost, not sent again as named values, and the
    fault summary names it."""
    updates = 4
    sensors = make_sensors(8, updates, 12)
    run = run_script(lua, tmp_path, params=WIRING | {"VPP_MAV_CHAN": 0}, updates=updates, frames=sensors.frames,
                     tx_full={2: True})  # fmt: skip
    assert run.of("NVF") == [] and len(run.of("MAV")) == updates
    assert [ok for *_, ok in run.of("MAV")] == ["true", "false", "true", "true"]
    assert [t for _, t in run.warnings()] == ["VPP: 1 bad readings, last link full"]
