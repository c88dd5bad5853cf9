"""The DataFlash reader against a real ArduPlane log (../shared/data/logs), against synthetic logs written here
with known contents, and against damaged copies."""

from __future__ import annotations

import datetime as dt
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink import DFReader

from firmware_bridge.logs.common import LogFormatError, LogRead
from firmware_bridge.logs.dataflash import read_dataflash
from vdm_aero.atmosphere import isa
from vdm_aero.rotation import dcm_from_quat, quat_from_euler

REAL = "arduplane-3.8-pixhawk-ground.BIN"
G0_M_S2 = 9.80665
MGAUSS_TO_T = 1e-7  # 1 G = 1e-4 T
MAX_RECORD_BYTES = 89  # FMT, the longest record of the real log


@pytest.fixture(scope="module")
def real(shared_logs: Path) -> LogRead:
    return read_dataflash(shared_logs / REAL)


def _records(path: Path) -> list[tuple[int, int, Any]]:
    """(start, end, message) of every record, from pymavlink's own sequential read."""
    r = DFReader.DFReader_binary(str(path), zero_time_base=True)
    out = []
    while (m := r.recv_msg()) is not None:
        out.append((r.offset - m.fmt.len, r.offset, m))
    r.close()
    return out


def _raw(m: Any, field: str) -> float:
    """A field as stored in the record, before pymavlink applies its format multiplier."""
    return float(m._elements[m.fmt.colhash[field]])


# ------------------------------------------------------------------------------------------------ the real log
def test_real_log_imu_at_the_logged_rate_and_at_rest(shared_logs: Path, real: LogRead) -> None:
    log, records = real.log, _records(shared_logs / REAL)
    params = {m.Name: m.Value for _, _, m in records if m.get_type() == "PARM"}
    att = [m for _, _, m in records if m.get_type() == "ATT"]
    t = log["imu_t_s"]
    assert len(t) == sum(m.get_type() == "IMU" for _, _, m in records)  # IMU2 (the second IMU) left out
    # this log has IMU at its main-loop rate, the log's own SCHED_LOOP_RATE parameter
    assert 1.0 / np.median(np.diff(t)) == pytest.approx(params["SCHED_LOOP_RATE"], rel=0.02)
    f = log["imu_accel_b_m_s2"].mean(axis=0)
    # at rest the specific force is gravity's reaction; 0.25 m/s² allows this Pixhawk's accel calibration
    # (INS_ACCSCAL_Y = 0.90 in the log) and local gravity (9.795 m/s² at Canberra, 590 m)
    assert np.linalg.norm(f) == pytest.approx(G0_M_S2, abs=0.25)
    # body FRD: f = C_bn (0, 0, −g) at the log's own attitude (ATT); 5° allows AHRS_TRIM_X = 2.8° in this log
    c_nb = dcm_from_quat(quat_from_euler(math.radians(att[0].Roll), math.radians(att[0].Pitch), 0.0))
    predicted = c_nb.T @ np.array([0.0, 0.0, -G0_M_S2])
    assert f[2] < -9.0
    assert math.degrees(math.acos(f @ predicted / np.linalg.norm(f) / G0_M_S2)) < 5.0
    # the attitude changes by under 1° in the second (ATT), so the mean rate is gyro bias: < 0.02 rad/s
    assert max(abs(att[-1].Roll - att[0].Roll), abs(att[-1].Pitch - att[0].Pitch)) < 1.0
    assert np.all(np.abs(log["imu_gyro_b_rad_s"].mean(axis=0)) < 0.02)
    assert np.all((log["imu_temperature_c"] > 0.0) & (log["imu_temperature_c"] < 85.0))


def test_real_log_baro_gnss_and_mag_agree_with_independent_models(shared_logs: Path, real: LogRead) -> None:
    log, records = real.log, _records(shared_logs / REAL)
    lat, lon, alt = (float(np.median(log[k])) for k in ("gnss_lat_deg", "gnss_lon_deg", "gnss_alt_m"))
    # the fix where the log's own EKF (POS) puts the aircraft: within 5 m horizontally, 10 m vertically
    pos = [m for _, _, m in records if m.get_type() == "POS"]
    m_per_deg = 111_320.0
    assert abs(lat - pos[0].Lat) * m_per_deg < 5.0
    assert abs(lon - pos[0].Lng) * m_per_deg * math.cos(math.radians(lat)) < 5.0
    assert abs(alt - pos[0].Alt) < 10.0
    assert np.all(np.linalg.norm(log["gnss_v_ned_m_s"], axis=1) < 1.0)  # on the ground
    # static pressure reduced to sea level with the ISA at the GPS altitude: within the weather's range
    p_sl = np.median(log["baro_pa"]) * isa(0.0)[0] / isa(alt)[0]
    assert 95_000.0 < p_sl < 105_000.0
    # the magnetometer against the World Magnetic Model at the site and the log's UTC date
    geomag = pytest.importorskip("pygeomag")
    assert real.unix_time_at_boot_s is not None
    year = dt.datetime.fromtimestamp(real.unix_time_at_boot_s, tz=dt.UTC)
    wmm = geomag.GeoMag(coefficients_file="wmm/WMM_2015.COF").calculate(
        glat=lat, glon=lon, alt=alt * 1e-3, time=year.year + year.timetuple().tm_yday / 365.25
    )
    b_ned_t = np.array([wmm.x, wmm.y, wmm.z]) * 1e-9
    mag = log["mag_field_b_t"]
    assert np.all((np.linalg.norm(mag, axis=1) > 20e-6) & (np.linalg.norm(mag, axis=1) < 70e-6))
    assert np.linalg.norm(mag.mean(axis=0)) == pytest.approx(np.linalg.norm(b_ned_t), rel=0.10)
    # rotated to NED with the log's attitude (ATT, yaw from the EKF): within 10° of the model's direction
    att = next(m for _, _, m in records if m.get_type() == "ATT")
    c_nb = dcm_from_quat(quat_from_euler(*(math.radians(a) for a in (att.Roll, att.Pitch, att.Yaw))))
    m_ned = c_nb @ mag.mean(axis=0)
    assert math.degrees(math.acos(m_ned @ b_ned_t / np.linalg.norm(m_ned) / np.linalg.norm(b_ned_t))) < 10.0


def test_real_log_unit_conversions_match_the_raw_records(shared_logs: Path, real: LogRead) -> None:
    """The stored integers with ArduPilot's documented scales: Lat/Lng 1e-7 deg, GPS Alt cm, MAG milligauss."""
    records = _records(shared_logs / REAL)
    gps = [m for _, _, m in records if m.get_type() == "GPS" and m.Status >= 3]
    mag = [m for _, _, m in records if m.get_type() == "MAG"]
    log = real.log
    np.testing.assert_allclose(log["gnss_lat_deg"], [_raw(m, "Lat") * 1e-7 for m in gps], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["gnss_lon_deg"], [_raw(m, "Lng") * 1e-7 for m in gps], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["gnss_alt_m"], [_raw(m, "Alt") * 0.01 for m in gps], rtol=0, atol=1e-9)
    # the receiver's accuracy: GPA, logged beside each GPS with its TimeUS, HAcc/VAcc in cm
    gpa = {m.TimeUS: m for _, _, m in records if m.get_type() == "GPA"}
    assert all(m.TimeUS in gpa for m in gps)
    np.testing.assert_allclose(log["gnss_h_acc_m"], [_raw(gpa[m.TimeUS], "HAcc") * 0.01 for m in gps], atol=1e-9)
    np.testing.assert_allclose(log["gnss_v_acc_m"], [_raw(gpa[m.TimeUS], "VAcc") * 0.01 for m in gps], atol=1e-9)
    raw_mag = np.array([[_raw(m, f) for f in ("MagX", "MagY", "MagZ")] for m in mag])
    np.testing.assert_allclose(log["mag_field_b_t"], raw_mag * MGAUSS_TO_T, rtol=1e-12)
    # the UTC of the boot: pymavlink's own GPS-time clock, and a date in ArduPlane 3.8.2's time (late 2017)
    clock = DFReader.DFReader_binary(str(shared_logs / REAL), zero_time_base=False)
    assert real.unix_time_at_boot_s is not None
    assert real.unix_time_at_boot_s == pytest.approx(clock.clock.timebase, abs=0.05)
    clock.close()
    assert dt.datetime.fromtimestamp(real.unix_time_at_boot_s, tz=dt.UTC).year == 2017


def test_real_log_report(shared_logs: Path, real: LogRead) -> None:
    rep, log = real.report, real.log
    size = (shared_logs / REAL).stat().st_size
    last = _records(shared_logs / REAL)[-1]
    assert rep.format == "dataflash" and rep.time_base == "DataFlash TimeUS (autopilot boot time)"
    assert rep.file_bytes == size == 65536
    # cut at 64 KiB inside a record: the read stops where pymavlink's last whole record ends
    assert rep.truncated_at_byte == last[1] < size
    assert rep.last_time_s is not None and rep.last_time_s <= last[2].TimeUS * 1e-6
    assert log.duration_s == pytest.approx(1.0, abs=0.1)  # "1.05 s on the ground" (the README)
    assert rep.malformed == 0 and not rep.duplicates
    # ATT, POS: the autopilot's estimate; GPA: the receiver's accuracy
    assert set(rep.used) == {"IMU", "BARO", "MAG", "GPS", "GPA", "RCOU", "ATT", "POS"}
    assert {"NKF1", "IMU2", "MAG2", "AHR2"} <= set(rep.unknown)  # NKF1: POS is there
    assert real.truth is None
    assert any("no airspeed" in w for w in rep.warnings)  # no ARSP in this log
    assert not any("SERVO" in w for w in rep.warnings)  # SERVO1..4_FUNCTION are in the log
    assert log.meta["servo_channels"] == {"aileron": 1, "elevator": 2, "throttle": 3, "rudder": 4}
    assert str(log.meta["firmware"]).startswith("ArduPlane V3.8")
    pwm = log["servo_pwm_us"]
    assert pwm.shape == (len(log["servo_t_s"]), 4) and np.all((pwm >= 900) & (pwm <= 2100))


# ------------------------------------------------------------------------------------------- damaged copies
def test_truncated_copies_read_up_to_the_last_whole_record(shared_logs: Path, tmp_path: Path) -> None:
    data = (shared_logs / REAL).read_bytes()
    records = _records(shared_logs / REAL)
    starts = [s for s, _, _ in records]
    rng = np.random.default_rng(20240611)
    cuts = [*rng.integers(12_000, len(data), 5).tolist(), starts[-20] + 1, starts[-20] + 2, starts[-20]]
    for cut in cuts:
        p = tmp_path / f"cut{cut}.bin"
        p.write_bytes(data[:cut])
        r = read_dataflash(p)
        # the record the cut falls in: a whole one of the original, or the original's own partial last record
        inside = [s for s, e, _ in records if s < cut < e] + ([records[-1][1]] if cut > records[-1][1] else [])
        assert r.report.truncated_at_byte == (inside[0] if inside else None), cut
        assert r.report.file_bytes == cut
        n_imu = sum(m.get_type() == "IMU" and e <= cut for _, e, m in records)
        assert len(r.log["imu_t_s"]) == n_imu, cut


def test_garbage_in_the_middle_is_skipped_and_counted(shared_logs: Path, tmp_path: Path,
                                                      capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    data = (shared_logs / REAL).read_bytes()
    records = _records(shared_logs / REAL)
    clean = read_dataflash(shared_logs / REAL)
    imu = [(s, e, m.TimeUS * 1e-6) for s, e, m in records if m.get_type() == "IMU"]
    clean_imu = dict(zip(clean.log["imu_t_s"].tolist(), clean.log["imu_accel_b_m_s2"].tolist(), strict=True))
    rng = np.random.default_rng(7)
    # garbage from inside an IMU record's body (after its TimeUS): that record must not come out with garbage
    # values; then blocks at random places
    blocks = [(imu[len(imu) // 2][0] + 20, 500)]
    for _ in range(5):
        n = int(rng.integers(100, 3000))
        blocks.append((int(rng.integers(imu[0][0], len(data) - n - 4000)), n))
    for start, n in blocks:
        bad = bytearray(data)
        bad[start : start + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        p = tmp_path / "garbage.bin"
        p.write_bytes(bytes(bad))
        r = read_dataflash(p)
        got = set(r.log["imu_t_s"].tolist())
        assert r.report.malformed >= 1
        # nothing invented from the garbage: every sample is the clean log's, time and values
        for t, f in zip(r.log["imu_t_s"].tolist(), r.log["imu_accel_b_m_s2"].tolist(), strict=True):
            assert clean_imu.get(t) == f, (start, t)
        # every sample clear of the garbage (and of the record the garbage starts in) is kept
        before = {t for s, e, t in imu if e <= start - MAX_RECORD_BYTES}
        after = {t for s, e, t in imu if s >= start + n + 2 * MAX_RECORD_BYTES}
        assert before | after <= got
        assert after, "the garbage should leave samples after it"
        assert r.report.truncated_at_byte == clean.report.truncated_at_byte
    out = capfd.readouterr()
    assert out.out == "" and out.err == ""  # counted in the report, not printed


@pytest.mark.parametrize("content", ["empty", "random", "text", "missing"])
def test_not_a_dataflash_log(tmp_path: Path, content: str) -> None:
    p = tmp_path / f"{content}.bin"
    if content == "random":
        p.write_bytes(np.random.default_rng(3).integers(0, 256, 20_000, dtype=np.uint8).tobytes())
    elif content == "text":
        p.write_text("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n" * 50)
    elif content == "empty":
        p.write_bytes(b"")
    with pytest.raises(LogFormatError) as e:
        read_dataflash(p)
    assert str(e.value).startswith(f"{p}: ") and "\n" not in str(e.value)


# --------------------------------------------------------------------------------------------- synthetic logs
HEAD = b"\xa3\x95"
FORMATS = {  # name: (type, format, columns), ArduPilot 4.x layouts trimmed to the fields read
    "FMT": (0x80, "BBnNZ", "Type,Length,Name,Format,Columns"),
    "PARM": (0x81, "QNf", "TimeUS,Name,Value"),
    "IMU": (0x82, "QBfffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T"),
    "BARO": (0x83, "QBf", "TimeUS,I,Press"),
    "ARSP": (0x84, "QBff", "TimeUS,I,Airspeed,DiffPress"),
    "MAG": (0x85, "QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
    "GPS": (0x86, "QBBIHLLefff", "TimeUS,I,Status,GMS,GWk,Lat,Lng,Alt,Spd,GCrs,VZ"),
    "RCOU": (0x87, "Q" + "H" * 14, "TimeUS," + ",".join(f"C{i}" for i in range(1, 15))),
    "SIM": (0x88, "QccCfLL", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
    "SIM2": (0x89, "Qdddffff", "TimeUS,PN,PE,PD,VN,VE,VD,As"),
    "MSG": (0x8A, "QZ", "TimeUS,Message"),
    "ATT": (0x8B, "Qcc", "TimeUS,Roll,Pitch"),
    # the Lua script's port chunks (logger:write adds TimeUS): 12 ports, then the rest
    "VPP0": (0x8C, "Q" + "f" * 12, "TimeUS," + ",".join(f"P{i:02d}" for i in range(12))),
    "VPP1": (0x8D, "Qff", "TimeUS,P12,P13"),
}
_STRUCTS = {n: DFReader.DFFormat(t, n, 0, f, c).msg_struct for n, (t, f, c) in FORMATS.items()}
T0_US = 10_000_000
UTC_AT_FIRST_FIX = dt.datetime(2024, 3, 10, 12, 0, 0, tzinfo=dt.UTC)
GPS_MINUS_UTC_S = 18  # since 2017-01-01 (IERS Bulletin C)


def _rec(name: str, *values: object) -> bytes:
    return HEAD + bytes([FORMATS[name][0]]) + struct.pack(_STRUCTS[name], *values)


def _synthetic(path: Path, servo_params: dict[int, int] | None) -> Path:
    """50 IMU samples at 50 Hz (instance 1 with other values interleaved) and the slower sensors at 10 Hz."""
    out = [
        _rec("FMT", t, 3 + struct.calcsize(_STRUCTS[n]), n.encode(), f.encode(), c.encode())
        for n, (t, f, c) in FORMATS.items()
    ]
    for ch, function in (servo_params or {}).items():
        out.append(_rec("PARM", T0_US, f"SERVO{ch}_FUNCTION".encode(), float(function)))
    out.append(_rec("MSG", T0_US, b"ArduPlane V4.5.7 (2a3dc4b7)"))
    gps_s = (UTC_AT_FIRST_FIX - dt.datetime(1980, 1, 6, tzinfo=dt.UTC)).total_seconds() + GPS_MINUS_UTC_S
    week, ms0 = int(gps_s // 604_800), round(gps_s % 604_800 * 1000)
    for k in range(50):
        t = T0_US + 20_000 * k
        out.append(_rec("IMU", t, 0, 0.01 * k, -0.02, 0.03, 0.1, -0.2, -9.8, 30.0))
        out.append(_rec("IMU", t, 1, 99.0, 99.0, 99.0, 99.0, 99.0, 99.0, 99.0))
        out.append(_rec("ATT", t, 1000, -500))
        out.append(_rec("RCOU", t + 1, *(1000 + 10 * c for c in range(1, 15))))
        if k % 5 == 0:
            out.append(_rec("BARO", t + 2, 0, 95_000.0 + k))
            out.append(_rec("BARO", t + 2, 1, 1.0))
            out.append(_rec("ARSP", t + 3, 0, 15.0, 150.0 + k))
            out.append(_rec("MAG", t + 4, 0, 200, -100, 450))
            status = 1 if k == 0 else 3  # the first without a fix
            gms = ms0 + (t + 5 - (T0_US + 20_000 * 5 + 5)) // 1000
            out.append(_rec("GPS", t + 5, 0, status, gms, week, -351234567, 1491653034, 58882, 10.0, 90.0, -1.5))
            out.append(_rec("SIM", t + 6, 1000, -500, 27000, 600.5, -351234567, 1491653034))
            out.append(_rec("SIM2", t + 7000, 0.0, 0.0, 0.0, 0.1 * k, 2.0, -1.0, 15.0))
    path.write_bytes(b"".join(out))
    return path


def test_synthetic_log_fields_units_instances_and_truth(tmp_path: Path) -> None:
    calls: list[float] = []
    servo = {1: 21, 2: 19, 3: 70, 5: 4, 6: 4}  # rudder on 1, ailerons on 5 and 6
    r = read_dataflash(_synthetic(tmp_path / "s.bin", servo), ("a", "b", "c"), progress=calls.append)
    log, rep = r.log, r.report
    # instance 0 only
    assert len(log["imu_t_s"]) == 50 and rep.unknown["IMU[1]"] == 50 and rep.unknown["BARO[1]"] == 10
    np.testing.assert_allclose(log["imu_gyro_b_rad_s"][:, 0], 0.01 * np.arange(50), atol=1e-6)
    np.testing.assert_allclose(log["imu_accel_b_m_s2"], np.tile([0.1, -0.2, -9.8], (50, 1)), atol=1e-6)
    np.testing.assert_allclose(log["imu_t_s"], (T0_US + 20_000 * np.arange(50)) * 1e-6)
    np.testing.assert_allclose(log["baro_pa"], 95_000.0 + 5 * np.arange(10))
    np.testing.assert_allclose(log["pitot_dp_pa"], 150.0 + 5 * np.arange(10))
    np.testing.assert_allclose(log["mag_field_b_t"], np.tile([200e-7, -100e-7, 450e-7], (10, 1)), rtol=1e-12)
    # GPS: the fix-less first record skipped; course 90° = east; VZ down positive
    assert len(log["gnss_t_s"]) == 9 and rep.unknown["GPS (no 3-D fix)"] == 1
    np.testing.assert_allclose(log["gnss_v_ned_m_s"], np.tile([0.0, 10.0, -1.5], (9, 1)), atol=1e-9)
    np.testing.assert_allclose(log["gnss_lat_deg"], -35.1234567, atol=1e-9)
    np.testing.assert_allclose(log["gnss_alt_m"], 588.82, atol=1e-9)
    assert r.unix_time_at_boot_s == pytest.approx(UTC_AT_FIRST_FIX.timestamp() - (T0_US + 100_005) * 1e-6, abs=2e-3)
    # servos: ArduPlane order from SERVOn_FUNCTION, the lowest channel of a function shared by two
    assert log.meta["servo_channels"] == {"aileron": 5, "elevator": 2, "throttle": 3, "rudder": 1}
    np.testing.assert_array_equal(log["servo_pwm_us"], np.tile([1050, 1020, 1030, 1010], (50, 1)))
    assert log.meta["firmware"] == "ArduPlane V4.5.7 (2a3dc4b7)"
    # truth: roll 10°, pitch −5°, yaw 270°: the nose points west and 5° down, the right wing dips
    assert r.truth is not None and r.truth.source == "DataFlash SIM" and len(r.truth.t_s) == 10
    assert r.truth.q_nb is not None and r.truth.v_ned_m_s is not None
    c_nb = dcm_from_quat(r.truth.q_nb[0])
    np.testing.assert_allclose(c_nb @ [1.0, 0.0, 0.0], [0.0, -math.cos(math.radians(5)), math.sin(math.radians(5))],
                               atol=1e-4)  # fmt: skip
    assert (c_nb @ [0.0, 1.0, 0.0])[2] == pytest.approx(math.sin(math.radians(10)) * math.cos(math.radians(5)))
    np.testing.assert_allclose(r.truth.alt_m, 600.5)
    # SIM2's VN grows 0.5 m/s per 0.1 s: interpolated linearly to SIM's times (7 ms earlier) where both exist
    inner = r.truth.t_s >= T0_US * 1e-6 + 0.007
    np.testing.assert_allclose(r.truth.v_ned_m_s[inner, 0], 5.0 * (r.truth.t_s[inner] - T0_US * 1e-6 - 0.007),
                               atol=1e-5)  # fmt: skip
    # no ports in a DataFlash log: the port array has its width and no rows
    assert log["ports_dp_pa"].shape == (0, 3) and any("no port values in the log" in w for w in rep.warnings)
    assert not any("SERVO" in w or "airspeed" in w for w in rep.warnings)
    # ATT without Yaw is no layout ArduPilot logs: skipped, not read as the autopilot's attitude
    assert rep.unknown["ATT (unknown layout)"] == 50 and len(log["ap_att_t_s"]) == 0
    assert rep.truncated_at_byte is None and rep.malformed == 0
    assert 10 <= len(calls) <= 101 and calls == sorted(calls) and calls[-1] == 1.0


@pytest.mark.parametrize(("params", "expected", "warned"), [
    (None, [1010, 1020, 1030, 1040], "no SERVOn_FUNCTION parameters"),
    ({1: 4, 2: 19, 3: 70}, [1010, 1020, 1030, 1040], "rudder (21): channel 4"),
    ({1: 70, 2: 4, 3: 21, 4: 19}, [1020, 1040, 1010, 1030], None),
])  # fmt: skip
def test_servo_channels_default_with_a_warning(tmp_path: Path, params: dict[int, int] | None,
                                               expected: list[int], warned: str | None) -> None:  # fmt: skip
    rep = (r := read_dataflash(_synthetic(tmp_path / "s.bin", params))).report
    np.testing.assert_array_equal(r.log["servo_pwm_us"][0], expected)
    servo_warnings = [w for w in rep.warnings if "SERVO" in w]
    if warned is None:
        assert servo_warnings == []
    else:
        assert len(servo_warnings) == 1 and warned in servo_warnings[0]


def test_the_lua_scripts_port_chunks_become_frames(tmp_path: Path) -> None:
    """VPP0 (ports 0..11) and VPP1 (12, 13) written back to back by one update join one frame, in the order of
    the names asked for; a NaN stays a lost port; a lone chunk is a frame with the other ports NaN."""
    names = tuple(f"P{i:02d}" for i in (13, *range(13)))  # the model's order need not be the log's
    out = [_rec("FMT", t, 3 + struct.calcsize(_STRUCTS[n]), n.encode(), f.encode(), c.encode())
           for n, (t, f, c) in FORMATS.items()]  # fmt: skip
    for k in range(20):
        t = T0_US + 20_000 * k
        vals = [100.0 * i + k for i in range(14)]
        if k == 3:
            vals[5] = math.nan
        out.append(_rec("VPP0", t, *vals[:12]))
        if k != 7:  # one update's second chunk lost
            out.append(_rec("VPP1", t + 40, *vals[12:]))
    (tmp_path / "p.bin").write_bytes(b"".join(out))
    r = read_dataflash(tmp_path / "p.bin", names)
    dp, t = r.log["ports_dp_pa"], r.log["ports_t_s"]
    assert dp.shape == (20, 14) and r.report.used["VPP0"] == 20 and r.report.used["VPP1"] == 19
    np.testing.assert_allclose(t, (T0_US + 20_000 * np.arange(20)) * 1e-6)
    np.testing.assert_allclose(dp[0], [1300.0, *(100.0 * i for i in range(13))])
    assert math.isnan(dp[3, 6]) and np.isfinite(np.delete(dp[3], 6)).all()  # P05 is column 6 here
    # P13 and P12 (columns 0 and 13) of the update whose VPP1 was lost
    assert np.isnan(dp[7, [0, 13]]).all() and np.isfinite(dp[7, 1:13]).all()
    assert not any("no port values" in w for w in r.report.warnings)
