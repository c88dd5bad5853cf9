"""The tlog reader on synthetic logs written with pymavlink's encoder: units, time bases, autopilot reboots,
port frames, truth, and damaged files."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.logs import LogFormatError, read_log
from firmware_bridge.logs.tlog import read_tlog

UNIX_BOOT_S = 1_700_000_000.0
PORTS = ("P00", "P01", "P02")


class TlogBuilder:
    """Frames from an autopilot (1/1) and other components, each stamped like MAVProxy's tlog."""

    def __init__(self) -> None:
        self.ap = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.records: list[bytes] = []

    def add(self, t_boot_s: float, msg: mavlink2.MAVLink_message, mav: mavlink2.MAVLink | None = None) -> None:
        frame = msg.pack(mav or self.ap)
        self.records.append(struct.pack(">Q", round((UNIX_BOOT_S + t_boot_s) * 1e6)) + frame)

    def heartbeat(self, t: float) -> None:
        self.add(t, self.ap.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             0, 0, 0))  # fmt: skip

    def imu(self, t: float, boot_us: int | None = None, gyro: float = 0.01) -> None:
        self.add(t, self.ap.highres_imu_encode(boot_us if boot_us is not None else round(t * 1e6), 0.5, -0.2, -9.7,
                                               gyro, -gyro, 0.03, 0.2, 0.01, 0.45, 1000.0, 0.0, 0.0, 21.5,
                                               0x1FF))  # fmt: skip

    def write(self, path: Path) -> Path:
        path.write_bytes(b"".join(self.records))
        return path


def _flight(tmp_path: Path, seconds: float = 3.0) -> TlogBuilder:
    b = TlogBuilder()
    b.add(0.0, b.gcs.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0), b.gcs)
    b.heartbeat(0.0)
    b.add(0.001, b.ap.system_time_encode(round(UNIX_BOOT_S * 1e6) + 1000, 1))
    for k in range(round(seconds * 400)):
        t = 0.01 + k / 400.0
        b.imu(t)
        if k % 8 == 0:
            ms = round(t * 1e3)
            b.add(t, b.ap.scaled_pressure_encode(ms, 1001.25, 2.5, 2150, 0))
            b.add(t, b.ap.servo_output_raw_encode(round(t * 1e6), 0, 1500, 1600, 1200, 1450, *[0] * 12))
            for i, name in enumerate(PORTS):
                b.add(t, b.ap.named_value_float_encode(ms, name.encode(), 100.0 * (i + 1) + t))
        if k % 80 == 0:
            b.add(t, b.ap.gps_raw_int_encode(round(t * 1e6), 3, 473_977_420, 85_455_940, 488_000, 80, 120, 1500, 9000,
                                             14, 0, 1800, 2900))  # fmt: skip
            b.add(t, b.gcs.named_value_float_encode(round(t * 1e3), b"P00", -1.0), b.gcs)  # not the autopilot's
        if k % 400 == 0:
            b.heartbeat(t)
    return b


def test_units_and_time_base(tmp_path: Path) -> None:
    r = read_tlog(_flight(tmp_path).write(tmp_path / "f.tlog"), PORTS)
    log, rep = r.log, r.report
    assert rep.time_base.startswith("HIGHRES_IMU.time_usec") and rep.malformed == 0
    assert np.allclose(log["imu_accel_b_m_s2"][0], [0.5, -0.2, -9.7])
    assert np.allclose(log["imu_gyro_b_rad_s"][0], [0.01, -0.01, 0.03])
    assert log["imu_temperature_c"][0] == pytest.approx(21.5)
    assert np.allclose(log["mag_field_b_t"][0], [20e-6, 1e-6, 45e-6])  # gauss → tesla (1 G = 100 µT)
    assert log["baro_pa"][0] == pytest.approx(100125.0) and log["pitot_dp_pa"][0] == pytest.approx(250.0, rel=1e-6)
    assert log["gnss_lat_deg"][0] == pytest.approx(47.397742) and log["gnss_alt_m"][0] == pytest.approx(488.0)
    v = log["gnss_v_ned_m_s"][0]  # 15 m/s on course 90°: east, no vertical velocity in GPS_RAW_INT
    assert v[0] == pytest.approx(0.0, abs=1e-9) and v[1] == pytest.approx(15.0) and math.isnan(v[2])
    assert log["gnss_h_acc_m"][0] == pytest.approx(1.8) and log["gnss_v_acc_m"][0] == pytest.approx(2.9)  # mm
    assert np.allclose(log["servo_pwm_us"][0], [1500, 1600, 1200, 1450])
    # one port frame per time_boot_ms with every port; the ground station's P00 is not the autopilot's
    assert log["ports_dp_pa"].shape == (len(log["ports_t_s"]), 3) and np.all(np.isfinite(log["ports_dp_pa"]))
    assert np.allclose(log["ports_dp_pa"][:, 1] - log["ports_dp_pa"][:, 0], 100.0, atol=1e-3)
    assert rep.unknown["NAMED_VALUE_FLOAT (not from the autopilot)"] == 3.0 * 400 / 80  # one per GPS record
    assert r.unix_time_at_boot_s == pytest.approx(UNIX_BOOT_S, abs=1e-3)
    assert log.meta["rates_hz"]["imu"] == pytest.approx(400.0, rel=1e-6)
    # pymavlink's own tlog reader (mavutil) as the independent count of what the autopilot sent
    m = mavutil.mavlink_connection(str(tmp_path / "f.tlog"))
    n = 0
    while (msg := m.recv_match(type="HIGHRES_IMU")) is not None:
        n += msg.get_srcSystem() == 1
    assert n == len(log["imu_t_s"]) == rep.used["HIGHRES_IMU"]


def test_reboot_unix_time_gnss_and_servo_clock_wrap(tmp_path: Path) -> None:
    b = TlogBuilder()
    b.heartbeat(0.0)
    b.add(0.0, b.ap.system_time_encode(round(UNIX_BOOT_S * 1e6), 0))
    for k in range(200):
        b.imu(k * 0.01, boot_us=round(4294.0e6 + k * 1e4))  # 4294 s after boot: SERVO_OUTPUT_RAW's µs wrap
        b.add(k * 0.01, b.ap.servo_output_raw_encode((round(4294.0e6) + k * 10_000) % 2**32, 0, 1500, 1500, 1000,
                                                     1500, *[0] * 12))  # fmt: skip
    # a fix stamped in Unix time (some autopilots' GPS_RAW_INT): mapped to boot time by SYSTEM_TIME
    b.add(1.0, b.ap.gps_raw_int_encode(round((UNIX_BOOT_S + 4295.0) * 1e6), 3, 1, 1, 1000, 0, 0, 0, 0, 10))
    for k in range(100):  # the autopilot reboots: its clock starts again
        b.imu(2.0 + k * 0.01, boot_us=round(0.5e6 + k * 1e4))
    r = read_tlog(b.write(tmp_path / "r.tlog"))
    t = r.log["imu_t_s"]
    assert r.report.reboots == 1 and "1 reboot(s) made continuous" in r.report.time_base
    # the reboot's first sample is held back (a stale frame looks the same) until the second confirms it
    assert np.all(np.diff(t) > 0) and len(t) == 299
    s = r.log["servo_t_s"]  # unwrapped against the IMU's clock: it keeps counting past 2³² µs
    assert np.all(np.diff(s) > 0) and s[-1] == pytest.approx(4294.0 + 1.99, abs=1e-6)
    # the stamp is when ArduPilot received the fix: valid its default u-blox lag (0.12 s) earlier
    assert r.log["gnss_t_s"][0] == pytest.approx(4295.0 - 0.12, abs=1e-3)


def test_scaled_imu_when_there_is_no_highres(tmp_path: Path) -> None:
    b = TlogBuilder()
    b.heartbeat(0.0)
    for k in range(50):
        b.add(k * 0.02, b.ap.scaled_imu_encode(k * 20, 0, 0, -1000, 10, 0, 0, 200, 0, 450, 2500))
    r = read_tlog(b.write(tmp_path / "s.tlog"))
    assert r.report.time_base.startswith("SCALED_IMU.time_boot_ms") and len(r.log["imu_t_s"]) == 50
    assert r.log["imu_accel_b_m_s2"][0, 2] == pytest.approx(-9.80665)  # −1000 mG
    assert r.log["imu_gyro_b_rad_s"][0, 0] == pytest.approx(0.01) and r.log["imu_temperature_c"][0] == 25.0
    assert any("IMU at 50.0 Hz" in w for w in r.report.warnings)


def test_partial_port_frames_are_nan_and_counted(tmp_path: Path) -> None:
    b = TlogBuilder()
    b.heartbeat(0.0)
    for k in range(20):
        b.imu(k * 0.01)
        for name in PORTS[:2] if k == 5 else PORTS:  # P02 of the sixth frame is lost on the link
            b.add(k * 0.01, b.ap.named_value_float_encode(k * 10, name.encode(), 1.0))
    r = read_tlog(b.write(tmp_path / "p.tlog"), PORTS)
    dp = r.log["ports_dp_pa"]
    assert dp.shape == (20, 3) and np.isnan(dp[5, 2]) and np.isfinite(np.delete(dp, 5, axis=0)).all()
    assert any("1 port frames incomplete" in w for w in r.report.warnings)


def test_simstate_is_the_truth(tmp_path: Path) -> None:
    b = TlogBuilder()
    b.heartbeat(0.0)
    for k in range(10):
        b.imu(k * 0.1)
        b.add(k * 0.1, b.ap.simstate_encode(0.1, -0.2, 1.5, 0, 0, 0, 0, 0, 0, 473_977_420 + k, 85_455_940))
    r = read_tlog(b.write(tmp_path / "t.tlog"))
    assert r.truth is not None and r.truth.source == "tlog SIMSTATE" and len(r.truth.t_s) == 10
    assert r.truth.t_s[3] == pytest.approx(0.3, abs=1e-6)  # the tlog stamp mapped onto the autopilot's clock
    assert r.truth.lat_deg[1] == pytest.approx(47.3977421) and math.isnan(r.truth.alt_m[0])
    from vdm_aero.rotation import euler_from_quat

    assert np.allclose(euler_from_quat(r.truth.q_nb[0]), (0.1, -0.2, 1.5), atol=1e-6)


def test_garbage_crc_errors_and_truncation(tmp_path: Path) -> None:
    b = _flight(tmp_path, 2.0)
    clean = read_tlog(b.write(tmp_path / "clean.tlog"), PORTS)
    recs = list(b.records)
    rng = np.random.default_rng(1)
    bad = bytearray(recs[500])
    bad[20] ^= 0xFF  # a flipped payload byte: the CRC fails
    recs[500] = bytes(bad)
    recs.insert(900, rng.integers(0, 256, 333, dtype=np.uint8).tobytes())  # a block of garbage between records
    data = b"".join(recs)
    (tmp_path / "bad.tlog").write_bytes(data[:-7])  # and the last record cut short
    r = read_tlog(tmp_path / "bad.tlog", PORTS)
    assert r.report.malformed >= 2 and r.report.truncated_at_byte == len(data) - len(recs[-1])
    lost = len(clean.log["imu_t_s"]) - len(r.log["imu_t_s"])
    assert 0 <= lost <= 2  # at most the damaged record (and the cut one, if an IMU) is lost
    assert r.log["imu_t_s"][-1] > clean.log["imu_t_s"][-1] - 0.01  # reading went on after the garbage


@pytest.mark.parametrize("content", [b"", b"hello, this is a text file\n" * 10, b"\x00" * 64])
def test_not_a_tlog_is_one_clear_error(tmp_path: Path, content: bytes) -> None:
    p = tmp_path / "x.tlog"
    p.write_bytes(content)
    with pytest.raises(LogFormatError, match=str(p)):
        read_log(p)


def test_no_autopilot_heartbeat_is_named(tmp_path: Path) -> None:
    b = TlogBuilder()
    b.imu(0.0)
    with pytest.raises(LogFormatError, match="no autopilot HEARTBEAT"):
        read_tlog(b.write(tmp_path / "h.tlog"))
