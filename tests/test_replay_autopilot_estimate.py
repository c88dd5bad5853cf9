"""The autopilot's own estimate (issue 24, item 5): the DataFlash and ULog readers fill ``ap_pos``/``ap_att``
from the logs' own messages (checked against pymavlink's and pyulog's decoding of the real logs), and the
replay report puts the autopilot's horizontal error beside the modes' outside the outages only."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
import pytest
from pyulog import ULog

from firmware_bridge.logs.dataflash import read_dataflash
from firmware_bridge.logs.ulog import read_ulog
from tests.test_log_dataflash import _records
from tests.test_log_tlog import TlogBuilder
from tests.test_log_ulog import _write_ulog
from vdm_aero.atmosphere import isa
from vdm_aero.geodesy import LocalFrame, normal_gravity_m_s2
from vdm_aero.rotation import dcm_from_quat, quat_from_euler

DATAFLASH = "arduplane-3.8-pixhawk-ground.BIN"
ULOG = "px4-standard-vtol-cubeorange.ulg"


def _angles_deg(q: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw [deg] read off the rotation matrix (nose azimuth, nose elevation, wing tilt)."""
    c = dcm_from_quat(q)
    return (math.degrees(math.atan2(c[2, 1], c[2, 2])), math.degrees(-math.asin(c[2, 0])),
            math.degrees(math.atan2(c[1, 0], c[0, 0])))  # fmt: skip


# ------------------------------------------------------------------------------------------------ DataFlash
def test_dataflash_real_log_fills_the_estimate_from_pos_and_att(shared_logs: Path) -> None:
    r = read_dataflash(shared_logs / DATAFLASH)
    log, rep = r.log, r.report
    recs = [m for _, _, m in _records(shared_logs / DATAFLASH)]
    pos = [m for m in recs if m.get_type() == "POS"]
    att = [m for m in recs if m.get_type() == "ATT"]
    assert log.meta["ap_estimate"] == {"position": "POS", "attitude": "ATT"}
    assert rep.used["POS"] == len(pos) == len(log["ap_pos_t_s"]) == 23 and rep.used["ATT"] == len(att) == 24
    # POS: TimeUS µs → s; Lat/Lng (format L) degrees; Alt metres AMSL, as pymavlink decodes them
    np.testing.assert_allclose(log["ap_pos_t_s"], [m.TimeUS * 1e-6 for m in pos], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["ap_pos_lat_deg"], [m.Lat for m in pos], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["ap_pos_lon_deg"], [m.Lng for m in pos], rtol=0, atol=1e-9)
    np.testing.assert_allclose(log["ap_pos_alt_m"], [m.Alt for m in pos], rtol=0, atol=1e-4)
    assert -35.37 < log["ap_pos_lat_deg"][0] < -35.36 and 580.0 < log["ap_pos_alt_m"][0] < 590.0  # Canberra
    # ATT: centidegrees decoded to degrees, yaw 0–360 (337° here): the quaternion's axes give them back
    np.testing.assert_allclose(log["ap_att_t_s"], [m.TimeUS * 1e-6 for m in att], rtol=0, atol=1e-9)
    got = np.array([_angles_deg(q) for q in log["ap_att_q_nb"]])
    want = np.array([(m.Roll, m.Pitch, m.Yaw) for m in att])
    np.testing.assert_allclose(got[:, :2], want[:, :2], atol=1e-6)
    np.testing.assert_allclose(np.mod(got[:, 2], 360.0), want[:, 2], atol=1e-6)
    assert want[0, 2] > 300.0 and log["ap_att_q_nb"][0, 0] > 0.0  # yaw wrapped: w ≥ 0 like ATTITUDE's
    np.testing.assert_allclose(np.linalg.norm(log["ap_att_q_nb"], axis=1), 1.0, atol=1e-12)
    # the estimate is no sensor: it does not stretch the log's duration, and NKF1 (POS is there) is skipped
    assert rep.unknown["NKF1"] == sum(m.get_type() == "NKF1" for m in recs)


def test_dataflash_without_pos_falls_back_to_nkf1_at_the_ekf_origin(shared_logs: Path, tmp_path: Path) -> None:
    """The real log with its POS records cut out: NKF1's PN/PE/PD from the EKF origin (ORGN Type 0, logged after
    the first NKF1) give the positions POS had (both are the EKF's output at the same step) within 2 cm."""
    src = shared_logs / DATAFLASH
    data, recs = src.read_bytes(), _records(src)
    kept = b"".join(data[a:b] for a, b, m in recs if m.get_type() != "POS") + data[recs[-1][1] :]
    (tmp_path / "nopos.bin").write_bytes(kept)
    r = read_dataflash(tmp_path / "nopos.bin")
    log, rep = r.log, r.report
    nkf1 = [m for _, _, m in recs if m.get_type() == "NKF1"]
    pos = [m for _, _, m in recs if m.get_type() == "POS"]
    origin = next(m for _, _, m in recs if m.get_type() == "ORGN" and m.Type == 0)
    assert origin.TimeUS > nkf1[0].TimeUS  # the origin comes after the first positions it is the origin of
    assert log.meta["ap_estimate"]["position"] == "NKF1" and rep.used["NKF1"] == len(nkf1) == len(log["ap_pos_t_s"])
    np.testing.assert_allclose(log["ap_pos_t_s"], [m.TimeUS * 1e-6 for m in nkf1], rtol=0, atol=1e-9)
    # each POS against the NKF1 record of the same EKF step (logged within a millisecond before it)
    t_pos = np.array([m.TimeUS * 1e-6 for m in pos])
    k = np.searchsorted(log["ap_pos_t_s"], t_pos) - 1
    assert np.all((t_pos - log["ap_pos_t_s"][k] > 0.0) & (t_pos - log["ap_pos_t_s"][k] < 0.002))
    n, e, d = pymap3d.geodetic2ned(log["ap_pos_lat_deg"][k], log["ap_pos_lon_deg"][k], log["ap_pos_alt_m"][k],
                                   [m.Lat for m in pos], [m.Lng for m in pos], [m.Alt for m in pos])  # fmt: skip
    assert np.all(np.hypot(n, e) < 0.02) and np.all(np.abs(d) < 0.02)
    # and against the origin: 0.9 m north, 5.7 m west of it in this log (a sign or unit slip would be metres off)
    ne0 = pymap3d.geodetic2ned(log["ap_pos_lat_deg"][0], log["ap_pos_lon_deg"][0], log["ap_pos_alt_m"][0],
                               origin.Lat, origin.Lng, origin.Alt)  # fmt: skip
    np.testing.assert_allclose(ne0, [nkf1[0].PN, nkf1[0].PE, nkf1[0].PD], atol=0.01)


# ------------------------------------------------------------------------------------------------------ ULog
def test_ulog_real_log_fills_the_attitude_and_says_why_there_is_no_position(shared_logs: Path) -> None:
    r = read_ulog(shared_logs / ULOG)
    log, rep = r.log, r.report
    att = ULog(str(shared_logs / ULOG), ["vehicle_attitude"]).get_dataset("vehicle_attitude").data
    q = np.stack([att[f"q[{i}]"] for i in range(4)], axis=1).astype(np.float64)
    assert log.meta["ap_estimate"] == {"position": None, "attitude": "vehicle_attitude"}
    assert rep.used["vehicle_attitude"] == len(att["timestamp"]) == len(log["ap_att_t_s"]) == 1298
    np.testing.assert_allclose(log["ap_att_t_s"], att["timestamp"] * 1e-6, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(log["ap_att_q_nb"], q)  # already w x y z, body FRD → NED
    # on the ground: level within a few degrees, the nose ~14° east of north (2·atan2(q3, q0))
    roll, pitch, yaw = _angles_deg(log["ap_att_q_nb"][0])
    assert abs(roll) < 5.0 and abs(pitch) < 5.0 and 10.0 < yaw < 20.0
    # its EKF never had a GNSS origin (xy_global 0 throughout): no position, and the reader says why
    assert len(log["ap_pos_t_s"]) == 0
    assert any("vehicle_local_position never has a global reference" in w for w in rep.warnings)
    assert "vehicle_local_position" in rep.unknown


HOME = LocalFrame(47.4, 8.5, 400.0)
MOVED = LocalFrame(*HOME.to_geodetic(100.0, 0.0, 0.0))  # the EKF origin after a reset, 100 m north


def _ulog_with_positions(path: Path, *, global_position: bool) -> tuple[Path, np.ndarray, np.ndarray]:
    """2 s at 10 Hz: vehicle_local_position from HOME (its reference set from the 4th row on, the origin
    moved 100 m north from the 12th), and optionally vehicle_global_position with an invalid first row.
    Returns (path, the local rows' NED [m], their times [µs])."""
    us = 10**6
    t = np.arange(10 * us, 12 * us, 100_000)
    ned = np.column_stack([5.0 * np.arange(20.0), -2.0 * np.arange(20.0), np.full(20, -30.0)])
    refs = [MOVED if i >= 11 else HOME for i in range(len(t))]
    rows = [(int(ti), *ned[i], i >= 3, i >= 3, True, refs[i].lat_deg, refs[i].lon_deg, refs[i].alt_m)
            for i, ti in enumerate(t)]  # fmt: skip
    topics: dict[str, tuple[str, list[tuple[Any, ...]]]] = {
        "vehicle_local_position": ("uint64_t timestamp;float x;float y;float z;bool xy_valid;bool xy_global;"
                                   "bool z_global;double ref_lat;double ref_lon;float ref_alt;", rows),
    }  # fmt: skip
    if global_position:
        lat, lon, alt = HOME.to_geodetic_array(ned)
        topics["vehicle_global_position"] = (
            "uint64_t timestamp;double lat;double lon;float alt;bool lat_lon_valid;",
            [(int(ti), lat[i], lon[i], alt[i], i > 0) for i, ti in enumerate(t)],
        )
    return _write_ulog(path, topics), ned, t


def test_ulog_local_position_made_geodetic_at_its_reference(tmp_path: Path) -> None:
    path, ned, t_us = _ulog_with_positions(tmp_path / "local.ulg", global_position=False)
    r = read_ulog(path)
    log = r.log
    assert log.meta["ap_estimate"]["position"] == "vehicle_local_position"
    # the rows without a global reference (the first three) are left out
    np.testing.assert_allclose(log["ap_pos_t_s"], t_us[3:] * 1e-6)
    # pymap3d (independent of the reader's LocalFrame) at each row's own reference: HOME, then 100 m north
    refs = [HOME if i < 11 else MOVED for i in range(3, 20)]
    want = np.array([pymap3d.ned2geodetic(*ned[i], r.lat_deg, r.lon_deg, float(np.float32(r.alt_m)))
                     for i, r in zip(range(3, 20), refs, strict=True)])  # fmt: skip
    np.testing.assert_allclose(log["ap_pos_lat_deg"], want[:, 0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(log["ap_pos_lon_deg"], want[:, 1], rtol=0, atol=1e-8)
    np.testing.assert_allclose(log["ap_pos_alt_m"], want[:, 2], atol=1e-3)
    # the reset shows: the row after the origin moved is ~100 m north of where the one before it was
    n = HOME.to_ned(log["ap_pos_lat_deg"], log["ap_pos_lon_deg"], log["ap_pos_alt_m"])[:, 0]
    assert n[11 - 3] - n[10 - 3] == pytest.approx(100.0 + 5.0, abs=0.05)


def test_ulog_global_position_is_preferred_and_invalid_rows_left_out(tmp_path: Path) -> None:
    path, ned, t_us = _ulog_with_positions(tmp_path / "global.ulg", global_position=True)
    r = read_ulog(path)
    log, rep = r.log, r.report
    assert log.meta["ap_estimate"]["position"] == "vehicle_global_position"
    np.testing.assert_allclose(log["ap_pos_t_s"], t_us[1:] * 1e-6)  # lat_lon_valid false in the first row
    np.testing.assert_allclose(HOME.to_ned(log["ap_pos_lat_deg"], log["ap_pos_lon_deg"], log["ap_pos_alt_m"]),
                               ned[1:], atol=1e-3)  # fmt: skip
    assert rep.used["vehicle_global_position"] == 20 and rep.unknown["vehicle_local_position"] == 20


# ---------------------------------------------------------------------------------------------------- replay
SPEED_M_S, COURSE_RAD = 20.0, math.radians(30.0)
V_NED = np.array([SPEED_M_S * math.cos(COURSE_RAD), SPEED_M_S * math.sin(COURSE_RAD), 0.0])
MAG_NED_UT = (20.0, 1.0, 45.0)
AP_OFFSET_N_M = 3.0  # the autopilot's estimate: the truth 3 m north
AP_OUTAGE_OFFSET_N_M = 50.0  # ... and 50 m north inside the outage window: must not reach the comparison
FLIGHT_S, OUTAGE = 60.0, (20.0, 40.0)
FLY_HOME = LocalFrame(47.4, 8.5, 500.0)


def _tlog(path: Path, *, truth: bool, estimate: bool) -> Path:
    """Straight and level at 20 m/s on course 30°: HIGHRES_IMU 100 Hz (gravity's reaction, the field in the
    body), SCALED_PRESSURE 10 Hz, GPS_RAW_INT and SIMSTATE (the truth) 5 Hz, GLOBAL_POSITION_INT 4 Hz."""
    b = TlogBuilder()
    b.heartbeat(0.0)
    g = normal_gravity_m_s2(FLY_HOME.lat_deg, FLY_HOME.alt_m)
    mag_b_gauss = dcm_from_quat(quat_from_euler(0.0, 0.0, COURSE_RAD)).T @ np.array(MAG_NED_UT) * 0.01
    static_hpa = float(isa(FLY_HOME.alt_m)[0]) * 0.01
    dp_hpa = 0.5 * 1.225 * SPEED_M_S**2 * 0.01
    for k in range(round(FLIGHT_S * 100)):
        t = 0.01 + k / 100.0
        b.add(t, b.ap.highres_imu_encode(round(t * 1e6), 0.0, 0.0, -g, 0.0, 0.0, 0.0, *mag_b_gauss, static_hpa, 0.0,
                                         0.0, 20.0, 0x1FF))  # fmt: skip
        p = V_NED * t
        if k % 10 == 0:
            b.add(t, b.ap.scaled_pressure_encode(round(t * 1e3), static_hpa, dp_hpa, 2000, 0))
        if k % 20 == 0:
            lat, lon, alt = FLY_HOME.to_geodetic(*p)
            b.add(t, b.ap.gps_raw_int_encode(round(t * 1e6), 3, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3),
                                             80, 120, round(SPEED_M_S * 100), round(math.degrees(COURSE_RAD) * 100),
                                             14))  # fmt: skip
            if truth:
                b.add(t, b.ap.simstate_encode(0.0, 0.0, COURSE_RAD, 0.0, 0.0, -g, 0.0, 0.0, 0.0, round(lat * 1e7),
                                              round(lon * 1e7)))  # fmt: skip
        if estimate and k % 25 == 0:
            # 50 m off well inside the window only: the epochs next to it interpolate between 3 m samples
            off = AP_OUTAGE_OFFSET_N_M if OUTAGE[0] + 1.0 <= t < OUTAGE[1] - 1.0 else AP_OFFSET_N_M
            lat, lon, alt = FLY_HOME.to_geodetic(p[0] + off, p[1], p[2])
            b.add(t, b.ap.global_position_int_encode(round(t * 1e3), round(lat * 1e7), round(lon * 1e7),
                                                     round(alt * 1e3), 0, round(V_NED[0] * 100),
                                                     round(V_NED[1] * 100), 0, 3000))  # fmt: skip
        if k % 100 == 0:
            b.heartbeat(t)
    return b.write(path)


def _replay(capsys: pytest.CaptureFixture[str], path: Path, out: Path) -> tuple[dict[str, Any], str]:
    from vdm_aero_cli.main import main

    capsys.readouterr()
    rc = main(["replay", str(path), "--outage", f"{OUTAGE[0]:g}:{OUTAGE[1]:g}", "--modes", "ins,airspeed-dr",
               "--jobs", "1", "--mag-field", ",".join(map(str, MAG_NED_UT)), "--gnss-latency-s", "0", "--json",
               "--out", str(out)])  # fmt: skip
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    return json.loads(captured.out), (out / "replay.md").read_text()


@pytest.mark.parametrize("truth", [True, False], ids=["truth", "own-gnss"])
def test_replay_puts_the_autopilot_beside_the_modes_outside_the_outages(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], truth: bool
) -> None:
    doc, md = _replay(capsys, _tlog(tmp_path / "f.tlog", truth=truth, estimate=True), tmp_path / "r")
    ap = doc["autopilot"]
    assert ap["source"] == "GLOBAL_POSITION_INT" and ap["reference"] == doc["reference"]
    assert doc["reference"].startswith("truth: tlog SIMSTATE" if truth else "the log's own GNSS")
    # its error is the 3 m offset (a sign, unit or time-base slip at 20 m/s would be metres off), and the 50 m
    # inside the outage window is not in it
    a = ap["autopilot"]
    assert a["median_error_m"] == pytest.approx(AP_OFFSET_N_M, abs=0.15)
    assert a["max_error_m"] == pytest.approx(AP_OFFSET_N_M, abs=0.3)
    # the modes over the same epochs: 5 Hz outside the 20 s outage of the 60 s (the filters start at the first fix)
    assert 190 <= ap["epochs"] <= 200 and ap["seconds"] == pytest.approx(ap["epochs"] / 5.0)
    assert set(ap["modes"]) == {"ins", "airspeed-dr"}
    assert all(r["median_error_m"] < 0.5 for r in ap["modes"].values())  # tracking the fixes: well under 3 m
    # inside the outages: said plainly, and not in the outage table
    assert ap["inside_outages"].startswith("not comparable inside the outages: the autopilot had GNSS throughout")
    assert set(doc["outages"][0]["modes"]) == {"ins", "airspeed-dr"}
    outage_section = md.split("## GNSS outage")[1].split("## ")[0]
    assert "autopilot (its own estimate)" not in outage_section
    assert "(GLOBAL_POSITION_INT) is not comparable inside the outages" in outage_section
    assert "The autopilot's own position estimate: GLOBAL_POSITION_INT." in md
    row = next(line for line in md.splitlines() if line.startswith("| autopilot (its own estimate) |"))
    assert float(row.split("|")[2]) == pytest.approx(AP_OFFSET_N_M, abs=0.15)


def test_replay_of_a_log_without_an_estimate_says_so_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc, md = _replay(capsys, _tlog(tmp_path / "f.tlog", truth=False, estimate=False), tmp_path / "r")
    assert doc["autopilot"]["source"] is None and doc["autopilot"]["note"].startswith("none in the log")
    lines = [line for line in md.splitlines() if line.startswith("The autopilot's own")]
    assert lines == [f"The autopilot's own position estimate: {doc['autopilot']['note']}."]
    assert "autopilot (its own estimate)" not in md and "not comparable" not in md
