"""The one MAVLink → SI decoder (firmware_bridge.decode) on the message sets autopilots really send: ArduPilot's
GCS set (RAW_IMU already scaled, SCALED_IMU2/3, SCALED_PRESSURE2 as the second airspeed sensor) and PX4's
(HIGHRES_IMU with its barometer and differential pressure); which stream is used and when it changes; repeats,
reboots and Unix-time fixes; and the service and the tlog reader both going through it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.decode import MavlinkDecoder
from firmware_bridge.logs.tlog import read_tlog


class Recorder:
    """A DecodedSink that keeps everything."""

    def __init__(self) -> None:
        self.ev: dict[str, list[Any]] = {}

    def __getattr__(self, name: str) -> Any:
        if not name.startswith("on_"):
            raise AttributeError(name)
        return lambda *a: self.ev.setdefault(name[3:], []).append(a)


def _mav(autopilot: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, comp: int = 1) -> tuple[mavlink2.MAVLink, Any]:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=comp)
    hb = mavlink2.MAVLink_heartbeat_message(mavlink2.MAV_TYPE_FIXED_WING, autopilot, 0, 0, 0, 3)
    return mav, hb


def _feed(dec: MavlinkDecoder, mav: mavlink2.MAVLink, msg: Any, t_in: float) -> None:
    dec.feed(mav.decode(bytearray(msg.pack(mav))), t_in)


def test_ardupilot_raw_imu_is_scaled_and_preferred_to_the_second_imu() -> None:
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    for k in range(8):  # ArduPilot's RAW_SENSORS stream at 4 Hz: IMU 1 in RAW_IMU, IMU 2 in SCALED_IMU2
        t = 1.0 + 0.25 * k
        _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(round(t * 1e6), 100, -50, -1000, 20, -10, 5,
                                                         200, -30, 450, 0, 4150), t)  # fmt: skip
        _feed(dec, mav, mavlink2.MAVLink_scaled_imu2_message(round(t * 1e3), 0, 0, -1000, 0, 0, 0,
                                                             0, 0, 0, 0), t)  # fmt: skip
    assert dec.imu_source == "RAW_IMU" and rec.ev["imu_source"] == [("RAW_IMU",)]
    imu = rec.ev["imu"]
    assert len(imu) == 8 and dec.skipped["SCALED_IMU2 (RAW_IMU used)"] == 8
    _, s, _ = imu[0]
    assert s.t_s == pytest.approx(1.0)
    assert s.accel_b_m_s2 == pytest.approx((0.980665, -0.4903325, -9.80665))  # mG
    assert s.gyro_b_rad_s == pytest.approx((0.020, -0.010, 0.005))  # mrad/s
    assert s.temperature_c == pytest.approx(41.5)  # cdegC
    assert rec.ev["mag"][0][1] == pytest.approx((20.0, -3.0, 45.0))  # mgauss → µT, once: it did not change
    assert len(rec.ev["mag"]) == 1


def test_a_silent_imu_hands_over_to_the_next_and_a_better_one_takes_back() -> None:
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)

    def imu2(t: float) -> None:
        _feed(dec, mav, mavlink2.MAVLink_scaled_imu2_message(round(t * 1e3), 0, 0, -1000, 1, 0, 0, 0, 0, 0, 0), t)

    for t in (1.0, 1.25):
        _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(round(t * 1e6), 0, 0, -1000, 2, 0, 0, 0, 0, 0, 0, 0), t)
        imu2(t)
    imu2(1.5)  # RAW_IMU silent for 0.25 s only: SCALED_IMU2 still waits
    assert dec.imu_source == "RAW_IMU"
    imu2(2.5)  # ... 1.25 s: the first IMU has stopped
    assert dec.imu_source == "SCALED_IMU2" and [e[0] for e in rec.ev["imu_source"]] == ["RAW_IMU", "SCALED_IMU2"]
    t = 2.75
    _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(round(t * 1e6), 0, 0, -1000, 2, 0, 0, 0, 0, 0, 0, 0), t)
    assert dec.imu_source == "RAW_IMU"
    assert [round(e[1].gyro_b_rad_s[0] * 1e3) for e in rec.ev["imu"]] == [2, 2, 1, 2]


def test_raw_imu_from_an_autopilot_that_sends_raw_counts_is_refused() -> None:
    mav, hb = _mav(mavlink2.MAV_AUTOPILOT_PX4)
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(1_000_000, 100, 0, -1000, 0, 0, 0, 0, 0, 0, 0, 0), 1.0)
    assert "imu" not in rec.ev and dec.skipped == {"RAW_IMU (raw sensor counts: only ArduPilot's are scaled)": 1}
    assert dec.gnss_latency_s == units.GNSS_LATENCY_DEFAULT_S["px4"]


def test_the_second_airspeed_sensor_is_read_where_the_first_has_none() -> None:
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    for k, dp_hpa in enumerate((2.5, 2.5, 2.9, 2.2)):  # airspeed sensor 2 in flight: Δp moves with the gusts
        t, ms = 1.0 + 0.25 * k, 1000 + 250 * k
        _feed(dec, mav, mavlink2.MAVLink_scaled_pressure_message(ms, 1001.0, 0.0, 2100, 0), t)
        _feed(dec, mav, mavlink2.MAVLink_scaled_pressure2_message(ms, 1002.0, dp_hpa, 2200, 3100), t)
    _feed(dec, mav, mavlink2.MAVLink_scaled_pressure2_message(1750, 1002.0, 2.2, 2200, 3100), 1.8)  # repeated
    assert [b[1] for b in rec.ev["baro"]] == [100100.0] * 4  # barometer 1
    # undecided until the ground it implies moved: then airspeed sensor 2, with its own temperature
    assert rec.ev["pitot"] == [(1.5, pytest.approx(290.0), 31.0), (1.75, pytest.approx(220.0), 31.0)]
    assert dec.duplicates == {"SCALED_PRESSURE2": 1}


def test_a_barometer_relative_press_diff_is_not_taken_for_an_airspeed_sensor() -> None:
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    for k in range(20):  # earlier ArduPilot: SCALED_PRESSURE2.press_diff = barometer 2 less its ground pressure
        t, ms, p_hpa = 1.0 + 0.25 * k, 1000 + 250 * k, 1000.0 - 0.1 * k  # climbing
        _feed(dec, mav, mavlink2.MAVLink_scaled_pressure2_message(ms, p_hpa, p_hpa - 1000.5, 2200, 0), t)
    assert "pitot" not in rec.ev and len(rec.ev["baro"]) == 20
    assert any("not an airspeed sensor" in k for k in dec.skipped)


def test_px4_highres_imu_carries_the_barometer_and_the_airspeed_sensor_when_marked_new() -> None:
    mav, hb = _mav(mavlink2.MAV_AUTOPILOT_PX4)
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    imu_bits = 0x1FF
    for k, bits in enumerate((imu_bits, imu_bits | 0x200 | 0x400, imu_bits)):
        t = 2.0 + 0.004 * k
        _feed(dec, mav, mavlink2.MAVLink_highres_imu_message(round(t * 1e6), 0.1, 0.0, -9.8, 0.01, 0.0, 0.0,
                                                             0.2, 0.0, 0.4, 990.5, 1.75, 180.0, 35.0, bits, 0),
              t)  # fmt: skip
    assert len(rec.ev["imu"]) == 3
    ((t_baro, static_pa),) = rec.ev["baro"]  # only the sample marked new
    ((t_pitot, dp_pa, temperature_c),) = rec.ev["pitot"]
    assert t_baro == t_pitot == pytest.approx(2.004) and static_pa == pytest.approx(99050.0)
    assert dp_pa == pytest.approx(175.0) and math.isnan(temperature_c)


def test_repeats_reboots_and_unix_time_fixes() -> None:
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec, gnss_latency_s=0.2)
    _feed(dec, mav, hb, 0.0)

    def imu(t: float) -> None:
        _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(round(t * 1e6), 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0, 0), t)

    imu(100.0)
    imu(100.0)  # a router repeating a frame
    assert len(rec.ev["imu"]) == 1 and dec.duplicates == {"RAW_IMU": 1}
    imu(0.5)  # the autopilot rebooted: its clock starts again (one sample could be a stale frame) ...
    assert "reboot" not in rec.ev and dec.stale == {"RAW_IMU": 1}
    imu(0.52)  # ... the next confirms it; ours goes on
    assert len(rec.ev["reboot"]) == 1 and rec.ev["imu"][-1][0] > 100.0
    unix_boot = 1_700_000_000.0
    gps = mavlink2.MAVLink_gps_raw_int_message(round((unix_boot + 0.9) * 1e6), 3, 473977420, 85455940, 500000,
                                               100, 150, 1500, 0, 10)  # fmt: skip
    _feed(dec, mav, gps, 0.6)
    assert dec.skipped["GPS_RAW_INT (Unix time before SYSTEM_TIME)"] == 1
    _feed(dec, mav, mavlink2.MAVLink_system_time_message(round(unix_boot * 1e6 + 0.6e6), 600), 0.6)
    _feed(dec, mav, gps, 0.7)
    ((t_valid, t_arrived, fix),) = rec.ev["gnss"]
    assert t_arrived == pytest.approx(dec.clock.filter_s(0.9)) and t_valid == pytest.approx(t_arrived - 0.2)
    assert fix.lat_deg == pytest.approx(47.397742) and fix.v_ned_m_s[0] == pytest.approx(15.0)
    with pytest.raises(ValueError, match="SYSTEM_TIME"):
        _feed(dec, mav, mavlink2.MAVLink_system_time_message(29618095652006494, 600), 0.8)


def test_messages_from_another_component_are_not_the_autopilots() -> None:
    mav, hb = _mav()
    camera = mavlink2.MAVLink(None, srcSystem=1, srcComponent=100)
    rec = Recorder()
    dec = MavlinkDecoder(rec, system_id=1)
    _feed(dec, mav, hb, 0.0)
    _feed(dec, camera, mavlink2.MAVLink_raw_imu_message(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0, 0), 1.0)
    assert "imu" not in rec.ev and dec.skipped == {"RAW_IMU (not from the autopilot)": 1}


def test_a_real_ardupilot_gcs_tlog_is_read_from_its_raw_imu(shared_logs: Path) -> None:
    r = read_tlog(shared_logs / "arduplane-sitl-gcs.tlog")
    log, rep = r.log, r.report
    assert log.meta["imu"] == "RAW_IMU" and rep.time_base.startswith("RAW_IMU.time_usec")
    t = log["imu_t_s"]
    assert len(t) > 700 and 3.0 < 1.0 / float(np.median(np.diff(t))) < 6.0  # ArduPilot's 4 Hz default
    f = log["imu_accel_b_m_s2"]
    assert 8.0 < float(np.median(np.linalg.norm(f, axis=1))) < 12.0  # about 1 g: mG scaled right
    # no airspeed sensor: SCALED_PRESSURE's Δp is 0; SCALED_PRESSURE2's is barometer 2 less its ground pressure
    assert len(log["pitot_t_s"]) == 0 and any("not an airspeed sensor" in k for k in rep.unknown)
    assert len(log["gnss_t_s"]) > 100 and math.isfinite(float(log["baro_pa"][0]))


def test_px4_altitude_is_the_barometer_only_while_no_pressure_stream_comes() -> None:
    mav, hb = _mav(mavlink2.MAV_AUTOPILOT_PX4)
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    alt = mavlink2.MAVLink_altitude_message(3_000_000, 1000.0, 1001.0, 20.0, 20.0, math.nan, 30.0)
    _feed(dec, mav, alt, 3.0)
    ((t, p_pa),) = rec.ev["baro"]
    # ISA at 1000 m: 898.746 hPa (ICAO Doc 7488)
    assert t == pytest.approx(3.0) and p_pa == pytest.approx(89874.6, rel=1e-4)
    _feed(dec, mav, mavlink2.MAVLink_scaled_pressure_message(3100, 898.0, 0.0, 2000, 0), 3.1)
    _feed(dec, mav, mavlink2.MAVLink_altitude_message(3_200_000, 1000.5, 1001.5, 20.5, 20.5, math.nan, 30.5), 3.2)
    assert [b[1] for b in rec.ev["baro"]][1:] == [89800.0]  # SCALED_PRESSURE took over; ALTITUDE is not used
    assert dec.skipped == {"ALTITUDE (SCALED_PRESSURE used)": 1}


def test_the_service_integrates_only_the_imu_streams_it_asked_for() -> None:
    """After a reboot the autopilot streams its defaults (RAW_IMU at a few Hz) before the service's requests
    take effect: a decoder limited to the requested HIGHRES_IMU never integrates those in its place."""
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec, imu_sources=["HIGHRES_IMU"])
    _feed(dec, mav, hb, 0.0)
    _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(1_000_000, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0, 0), 1.0)
    assert "imu" not in rec.ev and dec.skipped == {"RAW_IMU (not an IMU stream asked for)": 1}


def _raw(dec: MavlinkDecoder, mav: mavlink2.MAVLink, boot_s: float, t_in: float) -> None:
    _feed(dec, mav, mavlink2.MAVLink_raw_imu_message(round(boot_s * 1e6), 0, 0, -1000, 0, 0, 0, 0, 0, 0, 0, 0), t_in)


def test_a_stale_imu_frame_is_discarded_and_counted_not_taken_for_a_reboot() -> None:
    """A buffering radio or router sends a genuine sample again 0.7 s and 1.2 s late: each is dropped and
    counted; the clock does not move and no reboot is seen (it used to be, at 1.2 s, and the filter's clock
    jumped)."""
    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    t = 100.0
    for k in range(200):  # 50 Hz
        t = 100.0 + k / 50
        _raw(dec, mav, t, t)
        if k in (100, 150):
            late = 0.7 if k == 100 else 1.2
            _raw(dec, mav, t - late, t)
    assert dec.stale == {"RAW_IMU": 2} and dec.clock.reboots == 0 and "reboot" not in rec.ev
    assert len(rec.ev["imu"]) == 200
    boot = [ev[1].t_s for ev in rec.ev["imu"]]
    assert np.all(np.diff(boot) > 0)  # what reached the sink never went back in time
    assert dec.clock.filter_s(t) == pytest.approx(t)


@pytest.mark.parametrize("uptime_s", [0.0, 100.0])
def test_a_reboot_is_a_run_of_new_samples(uptime_s: float) -> None:
    """Near boot a reboot is confirmed by its second sample (the first is held back, counted); an autopilot
    heard again long after its boot (uptime 100 s, older than before) only by a run lasting REBOOT_RUN_S."""
    from firmware_bridge.decode import REBOOT_RUN_S

    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    for k in range(50):
        _raw(dec, mav, 200.0 + k / 50, 10.0 + k / 50)
    n_before = len(rec.ev["imu"])
    held = 0
    for k in range(300):  # the rebooted autopilot at 50 Hz (asked again at once)
        _raw(dec, mav, uptime_s + k / 50, 20.0 + k / 50)
        if "reboot" in rec.ev:
            break
        held += 1
    assert len(rec.ev["reboot"]) == 1 and dec.clock.reboots == 1
    if uptime_s < 60.0:
        assert held == 1
    else:
        assert held == pytest.approx(REBOOT_RUN_S * 50, abs=1)
    assert dec.stale["RAW_IMU"] == held
    assert len(rec.ev["imu"]) == n_before + 1  # the confirming sample went on, at a filter time after the last
    assert rec.ev["imu"][-1][0] > rec.ev["imu"][n_before - 1][0]


def test_a_component_other_than_autopilot1_is_never_the_autopilot() -> None:
    """A second component of our system calling itself a fixed-wing ArduPilot (a gimbal, another companion, a
    stranger on the link), heard first and all along: never the autopilot; MAV_COMP_ID_AUTOPILOT1 is."""
    mav, hb = _mav()
    imp_mav, imp_hb = _mav(comp=2)
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, imp_mav, imp_hb, 0.0)
    assert dec.autopilot is None and "autopilot" not in rec.ev
    for k in range(10):
        _feed(dec, mav, hb, 0.6 + k)
        _feed(dec, imp_mav, imp_hb, 0.5 + k + 5.0)  # even after the autopilot has been silent 3 s
    assert dec.autopilot == (1, 1) and [a[0] for a in rec.ev["autopilot"] if a[1]] == [(1, 1)]
    assert dec.skipped["HEARTBEAT (a vehicle's, but not from MAV_COMP_ID_AUTOPILOT1)"] == 11


def test_late_re_sends_back_to_back_are_not_a_reboot_but_a_reboot_soon_after_boot_is() -> None:
    """Two samples re-sent 1.1 s late back to back, early in the flight (both near boot, both newer than the
    one before): stale, not a reboot (the relay bench found two such false reboots a flight at 1 % re-sends).
    An autopilot that rebooted 3 s after its boot is only that far behind too: confirmed by the fourth sample."""
    from firmware_bridge.decode import REBOOT_RUN_NEAR

    mav, hb = _mav()
    rec = Recorder()
    dec = MavlinkDecoder(rec)
    _feed(dec, mav, hb, 0.0)
    for k in range(4000):  # 400 Hz from 20 s of uptime
        t = 20.0 + k / 400
        _raw(dec, mav, t, t)
        if k == 2000:
            _raw(dec, mav, t - 1.1, t)
            _raw(dec, mav, t - 1.1 + 1 / 400, t)
    assert dec.stale == {"RAW_IMU": 2} and dec.clock.reboots == 0 and "reboot" not in rec.ev
    rec2 = Recorder()
    dec2 = MavlinkDecoder(rec2)
    _feed(dec2, mav, hb, 0.0)
    for k in range(1200):  # up 3 s, then rebooted: the new boot's samples from 0.1 s on
        _raw(dec2, mav, k / 400, k / 400)
    held = 0
    for k in range(100):
        _raw(dec2, mav, 0.1 + k / 400, 4.0 + k / 400)
        if "reboot" in rec2.ev:
            break
        held += 1
    assert held == REBOOT_RUN_NEAR - 1 and dec2.clock.reboots == 1
