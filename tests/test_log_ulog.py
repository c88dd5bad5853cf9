"""PX4 ULog reader (firmware_bridge.logs.ulog): the shared real log checked against independent physics, and
small ULogs written here (current PX4 field names, SITL groundtruth) and broken on purpose.

The shared log, as pyulog reads it: 6.5 s of sensor data (boot time 20.3–26.8 s) on the ground, sensor_combined
at 204.6 Hz. Its README's "1,193 s, about 1 Hz" does not match the file: the 1,193 s run to the single
``mission`` message, stamped 1194.4 s, and no sensor topic is decimated to 1 Hz (differential_pressure and the
raw sensor_* topics are the ones at 1 Hz in this file). The tests check what the file holds.
"""

from __future__ import annotations

import math
import re
import signal
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyulog import ULog

from firmware_bridge.logs.common import LogFormatError, LogRead
from firmware_bridge.logs.ulog import read_ulog
from vdm_aero.atmosphere import pressure_altitude_m
from vdm_aero.geodesy import LocalFrame

REAL = "px4-standard-vtol-cubeorange.ulg"
RHO0_KG_M3 = 1.225  # PX4's indicated airspeed uses sea-level density


def _g_somigliana(lat_deg: float) -> float:
    """Normal gravity on the WGS-84 ellipsoid [m/s²] (Somigliana; NIMA TR8350.2 eq. 4-1)."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    return 9.7803253359 * (1.0 + 0.00193185265241 * s2) / math.sqrt(1.0 - 0.00669437999013 * s2)


@pytest.fixture(scope="module")
def real(shared_logs: Path) -> tuple[LogRead, Any, list[float]]:
    """(the reader's result, pyulog's own parse of the same file for cross-checks, the progress calls)."""
    calls: list[float] = []
    return read_ulog(shared_logs / REAL, ("p1", "p2"), progress=calls.append), ULog(str(shared_logs / REAL)), calls


def test_real_log_rates_duration_and_accounting(real: tuple[LogRead, Any, list[float]]) -> None:
    r, ul, calls = real
    log, rep = r.log, r.report
    assert calls[0] == 0.0 and calls[-1] == 1.0 and calls == sorted(calls)
    assert rep.format == "ulog" and rep.time_base == "ULog timestamp (autopilot boot time)"
    # IMU rate against the sensor's own integration interval (gyro_integral_dt [µs]), not the time stamps
    sc = ul.get_dataset("sensor_combined").data
    assert log.meta["rates_hz"]["imu"] == pytest.approx(1e6 / np.median(sc["gyro_integral_dt"]), rel=0.02)
    assert log.meta["rates_hz"]["imu"] > 100.0 and not any("IMU at" in w for w in rep.warnings)  # not decimated
    # duration: the sensor topics' span (pyulog's raw stamps), not the lone `mission` stamp 1194 s after boot
    span_s = (int(sc["timestamp"][-1]) - int(sc["timestamp"][0])) * 1e-6
    assert span_s <= log.duration_s <= span_s + 0.5 and log.duration_s < 60.0
    assert int(ul.get_dataset("mission").data["timestamp"][0]) * 1e-6 > 1000.0
    # every message is either used or skipped, with its count
    assert sum(rep.used.values()) + sum(rep.unknown.values()) == sum(len(d.data["timestamp"]) for d in ul.data_list)
    assert rep.used["vehicle_attitude"] == len(ul.get_dataset("vehicle_attitude").data["timestamp"])  # ap_att
    assert {"actuator_outputs", "vehicle_local_position", "airspeed", "differential_pressure[1]"} <= set(rep.unknown)
    assert rep.used["sensor_combined"] == len(log["imu_t_s"])
    assert rep.used["vehicle_gps_position"] >= len(log["gnss_t_s"])
    # what a PX4 log does not give: servos (mixer-dependent), ports, truth
    assert any("no servo stream" in w for w in rep.warnings) and len(log["servo_t_s"]) == 0
    assert log["ports_dp_pa"].shape == (0, 2) and r.truth is None
    assert rep.truncated_at_byte is None and rep.malformed == 0


def test_real_log_utc_of_boot_agrees_with_every_fix(real: tuple[LogRead, Any, list[float]]) -> None:
    r, ul, _ = real
    g = ul.get_dataset("vehicle_gps_position").data
    boot_us = g["timestamp"].astype(np.float64) + g["timestamp_time_relative"]  # the UTC stamp's boot time
    assert r.unix_time_at_boot_s is not None
    np.testing.assert_allclose(r.unix_time_at_boot_s + boot_us * 1e-6, g["time_utc_usec"] * 1e-6, atol=1e-3)
    assert r.unix_time_at_boot_s > 1577836800.0  # 2020-01-01: PX4 v1.11 (the log's firmware) is younger


def test_real_log_specific_force_is_gravity_on_the_ground(real: tuple[LogRead, Any, list[float]]) -> None:
    """Standing still (GNSS speed < 0.3 m/s), the accelerometer measures −g along the body's down axis (FRD)
    and the gyro almost nothing: catches g-units, mg, deg/s and axis-sign errors."""
    log = real[0].log
    lat = float(np.mean(log["gnss_lat_deg"]))
    assert np.linalg.norm(log["gnss_v_ned_m_s"][:, :2], axis=1).max() < 0.3
    f = log["imu_accel_b_m_s2"]
    g = _g_somigliana(lat)  # 9.822 m/s² at 63.4° N
    assert float(np.mean(np.linalg.norm(f, axis=1))) == pytest.approx(g, rel=0.03)  # a MEMS scale/bias budget
    assert float(np.mean(f[:, 2])) < -0.97 * g  # level: nearly all of it on −z (FRD)
    assert np.abs(log["imu_gyro_b_rad_s"]).max() < 0.05  # rad/s; deg/s would be 57× larger
    assert np.all((log["imu_temperature_c"] > -40.0) & (log["imu_temperature_c"] < 85.0))  # the sensor's range


def test_real_log_baro_consistent_with_gnss_altitude_through_the_isa(real: tuple[LogRead, Any, list[float]]) -> None:
    r, ul, _ = real
    log = r.log
    h_p = pressure_altitude_m(log["baro_pa"])
    # the weather: QNH 980–1050 hPa moves the pressure altitude ±300 m from the true (GNSS MSL) one
    assert abs(float(np.mean(h_p)) - float(np.mean(log["gnss_alt_m"]))) < 300.0
    # PX4 computed baro_alt_meter from the same pressure with QNH = SENS_BARO_QNH; standard here → the ISA
    assert ul.initial_parameters["SENS_BARO_QNH"] == pytest.approx(1013.25)
    air = ul.get_dataset("vehicle_air_data").data
    np.testing.assert_allclose(h_p, air["baro_alt_meter"], atol=0.5)


def test_real_log_magnetometer_is_an_earth_field(real: tuple[LogRead, Any, list[float]]) -> None:
    b_ut = np.linalg.norm(real[0].log["mag_field_b_t"], axis=1) * 1e6
    assert len(b_ut) > 100 and np.all((b_ut > 20.0) & (b_ut < 70.0))  # the Earth's surface field: 22–67 µT


def test_real_log_gnss_velocity_consistent_with_positions(real: tuple[LogRead, Any, list[float]]) -> None:
    """The vehicle stands still, so positions only wander within the receiver's accuracy: the displacement over
    the log must match the integrated velocity within twice the receiver's eph/epv, and the velocity's
    horizontal norm must equal the receiver's own ground speed. A unit error in lat/lon (degE7), alt (mm) or
    velocity fails this; the axis order is checked on the moving synthetic track below."""
    r, ul, _ = real
    log = r.log
    t, v = log["gnss_t_s"], log["gnss_v_ned_m_s"]
    home = LocalFrame(float(log["gnss_lat_deg"][0]), float(log["gnss_lon_deg"][0]), float(log["gnss_alt_m"][0]))
    ned = home.to_ned(log["gnss_lat_deg"], log["gnss_lon_deg"], log["gnss_alt_m"])
    g = ul.get_dataset("vehicle_gps_position").data
    tol = 2.0 * np.array([g["eph"].max(), g["eph"].max(), g["epv"].max()])
    assert np.all(np.abs((ned[-1] - ned[0]) - np.trapezoid(v, t, axis=0)) < tol)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), g["vel_m_s"][g["fix_type"] >= 3], atol=0.01)
    # the receiver's accuracy, eph/epv [m], one per fix (the filter scales its GNSS model by it)
    np.testing.assert_allclose(log["gnss_h_acc_m"], g["eph"][g["fix_type"] >= 3], rtol=1e-6)
    np.testing.assert_allclose(log["gnss_v_acc_m"], g["epv"][g["fix_type"] >= 3], rtol=1e-6)


def test_real_log_pitot_agrees_with_px4_airspeed(real: tuple[LogRead, Any, list[float]]) -> None:
    """The README says differential_pressure is logged: it is, at 1 Hz. On the ground (no flight in this log)
    Δp is the sensor's offset and the wind: a few Pa, of either sign. PX4's airspeed topic, computed from the
    same sensor at ~100 Hz, must give the same indicated airspeed √(2|Δp|/ρ₀) (sign included)."""
    r, ul, _ = real
    dp = r.log["pitot_dp_pa"]
    assert r.log.has_pitot and len(dp) >= 5 and r.log.meta["rates_hz"]["pitot"] == pytest.approx(1.0, rel=0.1)
    assert np.abs(dp).max() < 20.0  # < 5.7 m/s indicated: standing still; hPa read as Pa would be 100× off
    ias = float(np.median(ul.get_dataset("airspeed").data["indicated_airspeed_m_s"]))
    dp_med = float(np.median(dp))
    assert math.copysign(math.sqrt(2.0 * abs(dp_med) / RHO0_KG_M3), dp_med) == pytest.approx(ias, abs=1.0)
    # the airspeed sensor's own temperature comes along (the density's, ahead of the heated IMU's): on this
    # CubeOrange the IMU reads ~40 °C, the airspeed sensor the room's ~23 °C
    temp, imu = r.log["pitot_temperature_c"], float(np.median(r.log["imu_temperature_c"]))
    assert len(temp) == len(dp) and np.all((temp > 0.0) & (temp < 35.0)) and imu > np.max(temp) + 10.0


# ---------------------------------------------------------------------------------------------- synthetic logs
_CODE = {"uint64_t": "Q", "int32_t": "i", "uint32_t": "I", "uint8_t": "B", "bool": "?", "float": "f", "double": "d"}


def _write_ulog(path: Path, topics: dict[str, tuple[str, list[tuple[Any, ...]]]]) -> Path:
    """A minimal ULog (PX4 "ULog File Format"): the file header, a format ('F') and a subscription ('A') per
    topic, then its data ('D'). ``topics``: name → ("type field;…" with arrays as "float[3] name", flat rows)."""

    def msg(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0))
    for name, (fields, _) in topics.items():
        out += msg("F", f"{name}:{fields}".encode())
    for msg_id, (name, (fields, rows)) in enumerate(topics.items()):
        out += msg("A", struct.pack("<BH", 0, msg_id) + name.encode())
        fmt = "<" + "".join(f"{n or 1}{_CODE[t]}" for t, n in re.findall(r"(\w+)(?:\[(\d+)\])? \w+;", fields))
        out += b"".join(msg("D", struct.pack("<H", msg_id) + struct.pack(fmt, *row)) for row in rows)
    path.write_bytes(bytes(out))
    return path


HOME = LocalFrame(47.4, 8.5, 400.0)
V_NED = np.array([12.0, -5.0, -1.5])  # north-east and climbing
UTC_BOOT_S = 1.7e9
GYRO, ACCEL = (0.01, 0.02, -0.03), (0.3, -0.2, -9.7)


def _synthetic(path: Path, style: str) -> Path:
    """3 s: IMU 250 Hz, baro/mag 50 Hz, pitot 10 Hz, GNSS 10 Hz (the first fix 2-D) on a straight climb at
    :data:`V_NED`, SITL's groundtruth. ``style``: "current" (PX4 ≥ 1.15 names, timestamp_sample) or "old"
    (int degE7/mm GNSS, raw/filtered Δp, vehicle_air_data without pressure, local-position groundtruth)."""
    us = 10**6
    t_imu = np.arange(10 * us, 13 * us, 4000)
    t10 = np.arange(10 * us, 13 * us, 100_000)
    t50 = np.arange(10 * us, 13 * us, 20_000)
    lag, rel = 60_000, -20_000  # the fix is 60 ms old when published; the UTC belongs to timestamp − 20 ms
    sample = t10 - lag
    pos = (sample - 10 * us)[:, None] * 1e-6 * V_NED
    lat, lon, alt = HOME.to_geodetic_array(pos)
    topics: dict[str, tuple[str, list[tuple[Any, ...]]]] = {
        "sensor_combined": ("uint64_t timestamp;float[3] gyro_rad;uint32_t gyro_integral_dt;"
                            "int32_t accelerometer_timestamp_relative;float[3] accelerometer_m_s2;",
                            [(t, *GYRO, 4000, 0, *ACCEL) for t in t_imu]),
        "vehicle_magnetometer": ("uint64_t timestamp;uint64_t timestamp_sample;float[3] magnetometer_ga;",
                                 [(t, t - 1000, 0.2, 0.0, 0.45) for t in t50]),
        "actuator_outputs": ("uint64_t timestamp;uint32_t noutputs;float[4] output;",
                             [(t, 4, 1500.0, 1500.0, 1100.0, 1500.0) for t in t10]),
    }  # fmt: skip
    utc = [int(UTC_BOOT_S * us) + t + rel for t in t10]
    vel_valid = [1] * (len(t10) - 1) + [0]
    fix = [2] + [3] * (len(t10) - 1)
    if style == "current":
        topics |= {
            "vehicle_air_data": ("uint64_t timestamp;uint64_t timestamp_sample;float baro_alt_meter;"
                                 "float baro_temp_celcius;float baro_pressure_pa;",
                                 [(t, t - 2000, 400.0, 25.0, 96500.0) for t in t50]),
            "differential_pressure": ("uint64_t timestamp;uint64_t timestamp_sample;float differential_pressure_pa;",
                                      [(t, t - 3000, 150.0) for t in t10]),
            "vehicle_gps_position": ("uint64_t timestamp;uint64_t timestamp_sample;double latitude_deg;"
                                     "double longitude_deg;double altitude_msl_m;float vel_n_m_s;float vel_e_m_s;"
                                     "float vel_d_m_s;int32_t timestamp_time_relative;uint64_t time_utc_usec;"
                                     "uint8_t fix_type;bool vel_ned_valid;",
                                     [(t10[i], sample[i], lat[i], lon[i], alt[i], *V_NED, rel, utc[i], fix[i],
                                       vel_valid[i]) for i in range(len(t10))]),
            "vehicle_global_position_groundtruth": ("uint64_t timestamp;double lat;double lon;float alt;",
                                                    [(sample[i], lat[i], lon[i], alt[i]) for i in range(len(t10))]),
        }  # fmt: skip
    else:
        e7 = [(round(a * 1e7), round(b * 1e7), round(c * 1e3)) for a, b, c in zip(lat, lon, alt, strict=True)]
        topics |= {
            "vehicle_air_data": ("uint64_t timestamp;float baro_alt_meter;", [(t, 400.0) for t in t50]),
            "differential_pressure": ("uint64_t timestamp;float differential_pressure_raw_pa;"
                                      "float differential_pressure_filtered_pa;", [(t, 150.0, 140.0) for t in t10]),
            "vehicle_gps_position": ("uint64_t timestamp;uint64_t time_utc_usec;int32_t lat;int32_t lon;int32_t alt;"
                                     "float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;int32_t timestamp_time_relative;"
                                     "uint8_t fix_type;",
                                     [(sample[i], utc[i] - lag, *e7[i], *V_NED, rel, fix[i]) for i in range(len(t10))]),
            "vehicle_local_position_groundtruth": ("uint64_t timestamp;float x;float y;float z;float vx;float vy;"
                                                   "float vz;double ref_lat;double ref_lon;float ref_alt;",
                                                   [(sample[i], *pos[i], *V_NED, HOME.lat_deg, HOME.lon_deg,
                                                     HOME.alt_m) for i in range(len(t10))]),
        }  # fmt: skip
    return _write_ulog(path, topics)


@pytest.mark.parametrize("style", ["current", "old"])
def test_synthetic_log_field_names_units_axes_and_truth(tmp_path: Path, style: str) -> None:
    r = read_ulog(_synthetic(tmp_path / f"{style}.ulg", style))
    log, rep = r.log, r.report
    assert log.meta["rates_hz"]["imu"] == pytest.approx(250.0) and not any("IMU at" in w for w in rep.warnings)
    np.testing.assert_allclose(log["imu_gyro_b_rad_s"][7], GYRO, rtol=1e-6)
    np.testing.assert_allclose(log["imu_accel_b_m_s2"][7], ACCEL, rtol=1e-6)
    np.testing.assert_allclose(log["mag_field_b_t"][3], [20e-6, 0.0, 45e-6], rtol=1e-6)  # gauss → T
    # GNSS: the 2-D first fix dropped; stamped with the time of validity (10.04 s is the second fix's sample)
    t = log["gnss_t_s"]
    assert len(t) == 29 and t[0] == pytest.approx(10.04)
    # positions and velocities agree over the track (axis order, degE7/mm or degrees/metres)
    ned = HOME.to_ned(log["gnss_lat_deg"], log["gnss_lon_deg"], log["gnss_alt_m"])
    np.testing.assert_allclose((ned[-1] - ned[0]) / (t[-1] - t[0]), V_NED, atol=0.02)
    np.testing.assert_allclose(log["gnss_v_ned_m_s"][0], V_NED, rtol=1e-6)
    assert r.unix_time_at_boot_s == pytest.approx(UTC_BOOT_S, abs=1e-6)
    assert r.truth is not None and r.truth.source == "PX4 groundtruth" and len(r.truth.t_s) == 30
    np.testing.assert_allclose(HOME.to_ned(r.truth.lat_deg[-1], r.truth.lon_deg[-1], r.truth.alt_m[-1]),
                               (r.truth.t_s[-1] - 10.0) * V_NED, atol=0.05)  # fmt: skip
    assert rep.unknown == {"actuator_outputs": 30} and any("no servo stream" in w for w in rep.warnings)
    if style == "current":
        assert np.isnan(log["gnss_v_ned_m_s"][-1]).all()  # vel_ned_valid false
        assert log["baro_t_s"][0] == pytest.approx(9.998) and np.all(log["baro_pa"] == 96500.0)
        assert np.all(log["pitot_dp_pa"] == 150.0) and np.all(log["imu_temperature_c"] == 25.0)
    else:
        assert len(log["baro_t_s"]) == 0 and any("no baro_pressure_pa" in w for w in rep.warnings)
        assert np.all(log["pitot_dp_pa"] == 150.0)  # the raw Δp, not the low-passed one
        assert np.all(log["imu_temperature_c"] == 15.0)  # no temperature in the log: ISA sea level
        assert r.truth.v_ned_m_s is not None and np.allclose(r.truth.v_ned_m_s, V_NED)


# ---------------------------------------------------------------------------------------------- damaged files
def test_truncated_copy_reads_up_to_the_last_whole_record(tmp_path: Path, shared_logs: Path) -> None:
    data = (shared_logs / REAL).read_bytes()
    full = read_ulog(shared_logs / REAL).log
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: int(0.6 * len(data))])
    r = read_ulog(cut)
    at = r.report.truncated_at_byte
    assert at is not None and 0 < int(0.6 * len(data)) - at < 3 + 65535  # inside one record (≤ 64 KiB)
    assert any("truncated" in w for w in r.report.warnings)
    n = len(r.log["imu_t_s"])
    assert 0 < n < len(full["imu_t_s"]) and np.array_equal(r.log["imu_t_s"], full["imu_t_s"][:n])
    # the reported offset is a record boundary: the file cut there ends cleanly, with the same records
    clean = tmp_path / "clean.ulg"
    clean.write_bytes(data[:at])
    r2 = read_ulog(clean)
    assert r2.report.truncated_at_byte is None and len(r2.log["imu_t_s"]) == n


def test_corrupt_record_is_skipped_and_reported(tmp_path: Path, shared_logs: Path) -> None:
    data = bytearray((shared_logs / REAL).read_bytes())
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: int(0.6 * len(data))])
    at = read_ulog(cut).report.truncated_at_byte  # a record boundary (test above)
    assert at is not None
    data[at : at + 3] = bytes(3)  # that record's header: length 0, type 0
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(bytes(data))
    r = read_ulog(bad)
    full = read_ulog(shared_logs / REAL).log
    assert r.report.malformed >= 1 and any("corrupt" in w for w in r.report.warnings)
    # pyulog resynchronises at the next sync marker: data after the damage is still read, some before it lost
    assert r.log["imu_t_s"][-1] == full["imu_t_s"][-1] and len(r.log["imu_t_s"]) < len(full["imu_t_s"])


@contextmanager
def _deadline(seconds: int) -> Iterator[None]:
    def fail(*_: object) -> None:
        pytest.fail(f"no answer within {seconds} s")  # not an OSError, which the reader would convert

    old = signal.signal(signal.SIGALRM, fail)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


HEADER = b"ULog\x01\x12\x35\x01" + bytes(8)


@pytest.mark.parametrize(
    "content",
    [
        b"",
        bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8)),
        b"timestamp,lat,lon\n1,2,3\n",
        HEADER[:10],
        # a header, then a record declaring 5000 bytes near the end: raw pyulog 1.3 seeks back before it and
        # loops forever (40,000 bytes in) or fails with EINVAL (100 bytes in)
        HEADER + bytes(40_000) + b"\x88\x13\x00" + bytes(10),
        HEADER + bytes(100) + b"\x88\x13\x00" + bytes(10),
    ],
    ids=["empty", "random", "csv", "short-header", "pyulog-loop", "pyulog-einval"],
)
def test_not_a_ulog_is_one_line_naming_the_file(tmp_path: Path, content: bytes) -> None:
    p = tmp_path / "bad.ulg"
    p.write_bytes(content)
    with _deadline(20), pytest.raises(LogFormatError) as e:
        read_ulog(p)
    assert str(e.value).startswith(f"{p}: ") and "\n" not in str(e.value)
    assert "cannot read" not in str(e.value)  # a format error, not an I/O failure (pyulog's EINVAL)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(LogFormatError, match="cannot read"):
        read_ulog(tmp_path / "nope.ulg")
