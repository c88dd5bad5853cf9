"""``vdm-aero sitl --gcs-recording``: a tlog as a ground station records ArduPlane SITL, read back by pymavlink
(the reference reader), by the project's reader and by ``vdm-aero replay``.

The expectation is ArduPilot's GCS stream set at what a GCS asks for (sim/sitl/streams.py, GCS_REQUEST_HZ): every
SRx_ group at 4 Hz (MAVProxy's REQUEST_DATA_STREAM(ALL, 4), measured in shared/data/logs/arduplane-sitl-gcs.tlog),
HEARTBEAT at 1 Hz, the scenario's ports as named values, no HIGHRES_IMU. The flights are seeded scenarios at
``--speed 0`` on a null link (no peer); times are the tlog's stamps, which are the autopilot's clock.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vdm_aero.atmosphere import isa
from vdm_aero.rotation import euler_from_quat, quat_from_euler, quat_log, quat_multiply

GCS_HZ = 4.0  # every SRx_ group, as the recording GCS asks for it
GCS_SET = {  # ArduPlane's STREAM_*_msgs members the mock can send
    "RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE", "SCALED_PRESSURE2",  # RAW_SENS
    "SYS_STATUS", "GPS_RAW_INT",  # EXT_STAT
    "SERVO_OUTPUT_RAW",  # RC_CHAN
    "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED",  # POSITION
    "ATTITUDE", "SIMSTATE", "AOA_SSA",  # EXTRA1
    "VFR_HUD",  # EXTRA2
    "SYSTEM_TIME", "WIND",  # EXTRA3
}  # fmt: skip
FLIGHT_S = 40.0
PORTS_HZ = 50.0  # survey-wind8's ports
G_M_S2 = 9.80665


class Flight:
    """One recorded flight: every autopilot message with its tlog stamp [µs], and the truth file."""

    def __init__(self, tlog: Path, truth: Path) -> None:
        self.tlog, self.truth_path = tlog, truth
        self.truth = dict(np.load(truth))
        self.msgs: dict[str, list[tuple[int, Any]]] = defaultdict(list)
        for stamp_us, m in _read_with_mavutil(tlog):
            if (m.get_srcSystem(), m.get_srcComponent()) == (1, 1):
                self.msgs[m.get_type()].append((stamp_us, m))
        # RAW_IMU's time_usec is µs since boot and the IMU samples every world step: stamp − time_usec is the boot
        boots = {s - m.time_usec for s, m in self.msgs["RAW_IMU"]}
        assert max(boots) - min(boots) <= 2, boots  # the tlog's µs pass through a float in mavutil
        self.boot_us = min(boots)
        self.truth_us = np.round(self.truth["t_s"] * 1e6).astype(np.int64)

    def row(self, stamp_us: int) -> int:
        """The truth row of the world step at which a message was sent."""
        i = int(np.argmin(np.abs(self.truth_us - (stamp_us - self.boot_us))))
        assert abs(int(self.truth_us[i]) - (stamp_us - self.boot_us)) <= 2
        return i

    def times_s(self, kind: str) -> np.ndarray:
        return np.array([s for s, _ in self.msgs[kind]], dtype=np.float64) * 1e-6


def _read_with_mavutil(path: Path) -> Iterator[tuple[int, Any]]:
    from pymavlink import mavutil

    with pytest.MonkeyPatch.context() as mp:  # mavutil switches its global dialect and MAVLINK20: undone after
        mp.setattr(mavutil, "mavlink", mavutil.mavlink)
        mp.setattr(mavutil, "current_dialect", mavutil.current_dialect)
        mp.setenv("MAVLINK20", "1")
        mavutil.set_dialect("ardupilotmega")
        log = mavutil.mavlink_connection(str(path))
        try:
            while (m := log.recv_match()) is not None:
                yield round(m._timestamp * 1e6), m
        finally:
            log.close()


def _fly(out: Path, scenario: str, duration_s: float, *extra: str) -> Flight:
    from vdm_aero_cli.main import main

    out.mkdir(parents=True, exist_ok=True)
    tlog, truth = out / "flight.tlog", out / "truth.npz"
    rc = main(["sitl", "--scenario", scenario, "--connect", "null", "--speed", "0", "--duration-s", str(duration_s),
               "--gcs-recording", "--tlog", str(tlog), "--truth", str(truth), *extra])  # fmt: skip
    assert rc == 0
    return Flight(tlog, truth)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return _fly(tmp_path_factory.mktemp("gcs"), "survey-wind8", FLIGHT_S)


def test_the_gcs_stream_set_at_its_rates(flight: Flight) -> None:
    """ArduPilot's GCS set and nothing the service would ask for: each group message at 4 Hz (0.25 s apart in the
    autopilot's time), HEARTBEAT at 1 Hz, the ports as named values at their own rate."""
    sent = set(flight.msgs)
    assert sent == GCS_SET | {"HEARTBEAT", "NAMED_VALUE_FLOAT"}, sent ^ (GCS_SET | {"HEARTBEAT", "NAMED_VALUE_FLOAT"})
    assert not {"HIGHRES_IMU", "SCALED_IMU", "ATTITUDE_QUATERNION", "DEBUG_FLOAT_ARRAY"} & sent
    for kind, hz in [*((k, GCS_HZ) for k in sorted(GCS_SET)), ("HEARTBEAT", 1.0)]:
        t = flight.times_s(kind)
        assert len(t) == round(FLIGHT_S * hz), (kind, len(t))
        assert (len(t) - 1) / (t[-1] - t[0]) == pytest.approx(hz, rel=0.01), kind
        assert np.all(np.abs(np.diff(t) - 1.0 / hz) < 0.003), kind  # one world step (2.5 ms) of jitter at most
    names = {m.name for _, m in flight.msgs["NAMED_VALUE_FLOAT"]}
    assert len(flight.msgs["NAMED_VALUE_FLOAT"]) == round(len(names) * PORTS_HZ * FLIGHT_S) and "P00" in names


def test_imu_messages_are_scaled_like_arduplanes(flight: Flight) -> None:
    """RAW_IMU in mG, mrad/s, mgauss (ArduPilot scales it), time_usec = µs since boot; SCALED_IMU2 a second IMU:
    the same motion with its own noise, no second compass."""
    raw = [m for _, m in flight.msgs["RAW_IMU"]]
    acc = np.array([[m.xacc, m.yacc, m.zacc] for m in raw], dtype=float)
    assert -1100.0 < np.median(acc[:, 2]) < -950.0 and np.all(np.abs(np.median(acc[:, :2], axis=0)) < 150.0)
    for k, (s, m) in enumerate(flight.msgs["RAW_IMU"]):
        i = flight.row(s)
        f_mg = flight.truth["specific_force_b_m_s2"][i] / G_M_S2 * 1e3
        assert np.all(np.abs([m.xacc, m.yacc, m.zacc] - f_mg) < 60.0)  # the IMU's bias and noise, in mG
        w = flight.truth["omega_b_rad_s"][i] * 1e3
        assert np.all(np.abs([m.xgyro, m.ygyro, m.zgyro] - w) < 25.0)  # mrad/s (turn-on bias ≤ 3σ of 0.5 °/s)
        if k > 0:  # the first is sent at the first step, before the first magnetometer sample (50 Hz)
            assert 400 < math.hypot(m.xmag, m.ymag, m.zmag) < 700  # mgauss: ~51 µT of Earth field plus hard iron
    diffs = []
    for (s1, m1), (s2, m2) in zip(flight.msgs["RAW_IMU"], flight.msgs["SCALED_IMU2"], strict=True):
        assert s1 == s2 and m2.time_boot_ms == m1.time_usec // 1000  # the same step, ms since boot
        assert (m2.xmag, m2.ymag, m2.zmag) == (0, 0, 0)
        diffs.append([m2.xacc - m1.xacc, m2.yacc - m1.yacc, m2.zacc - m1.zacc,
                      m2.xgyro - m1.xgyro, m2.ygyro - m1.ygyro, m2.zgyro - m1.zgyro])  # fmt: skip
    d = np.array(diffs, dtype=float)
    assert np.all(np.abs(d) <= 8.0)  # mG, mrad/s: σ 1.4 mG, 1.0 mrad/s of independent noise
    assert 0.8 < np.std(d[:, :3]) < 2.5 and 0.6 < np.std(d[:, 3:]) < 2.0  # not the same samples


def test_pressures_in_hpa_barometer_and_airspeed_sensor(flight: Flight) -> None:
    """SCALED_PRESSURE: barometer 1 [hPa] and the pitot's Δp [hPa] with its temperature; SCALED_PRESSURE2:
    barometer 2 and airspeed sensor 2, of which there is none (Δp 0, temperature unknown)."""
    for (s1, p1), (s2, p2) in zip(flight.msgs["SCALED_PRESSURE"], flight.msgs["SCALED_PRESSURE2"], strict=True):
        i = flight.row(s1)
        p_isa, t_k, rho = isa(float(flight.truth["alt_m"][i]))
        assert p1.press_abs == pytest.approx(p_isa / 100.0, abs=0.3)  # hPa: the baro's drift and noise
        q_hpa = 0.5 * rho * flight.truth["airspeed_m_s"][i] ** 2 / 100.0
        assert p1.press_diff == pytest.approx(q_hpa, rel=0.15, abs=0.1)  # a pitot reads ~the dynamic pressure
        assert p1.temperature_press_diff == pytest.approx((t_k - 273.15) * 100.0, abs=300)  # cdegC
        assert s2 == s1 and p2.press_diff == 0.0 and p2.temperature_press_diff == 0
        assert p2.press_abs == pytest.approx(p1.press_abs, abs=0.1) and p2.temperature == p1.temperature


def test_attitude_and_vfr_hud_are_the_autopilots_estimate(flight: Flight) -> None:
    """ATTITUDE and VFR_HUD from the autopilot's estimate: its attitude is the truth turned by the error of a gyro
    integrated at full rate and pulled back by the aiding (sim.flight.ap_attitude: within a degree, and not the
    truth), its position the truth outside GNSS outages; the body rates the truth's. VFR_HUD's airspeed the
    pitot's equivalent airspeed, heading in degrees, throttle in %, altitude AMSL."""
    off = []
    for s, m in flight.msgs["ATTITUDE"]:
        i = flight.row(s)
        q_ap = quat_from_euler(m.roll, m.pitch, m.yaw)
        off.append(float(np.linalg.norm(quat_log(quat_multiply(flight.truth["q_nb"][i] * [1, -1, -1, -1], q_ap)))))
        np.testing.assert_allclose([m.rollspeed, m.pitchspeed, m.yawspeed], flight.truth["omega_b_rad_s"][i],
                                   atol=1e-6)  # fmt: skip
    assert max(off) < math.radians(1.0), max(off)  # an aided estimate's error
    assert max(off) > 1e-4, max(off)  # ... and not the truth (a float32 message holds ~1e-7 rad)
    for s, m in flight.msgs["VFR_HUD"]:
        i = flight.row(s)
        tr = {k: flight.truth[k][i] for k in ("alt_m", "v_ned_m_s", "q_nb", "throttle", "airspeed_m_s")}
        assert m.alt == pytest.approx(tr["alt_m"], abs=1e-3)
        assert m.groundspeed == pytest.approx(math.hypot(*tr["v_ned_m_s"][:2]), abs=1e-4)
        assert m.climb == pytest.approx(-tr["v_ned_m_s"][2], abs=1e-4)
        yaw = math.degrees(euler_from_quat(tr["q_nb"])[2]) % 360.0
        # rounded to whole degrees, from the estimate (within the degree its attitude is off, above)
        assert min(abs(m.heading - yaw), 360.0 - abs(m.heading - yaw)) <= 0.5 + math.degrees(max(off)) + 1e-6
        assert m.throttle == round(100.0 * tr["throttle"])
        eas = tr["airspeed_m_s"] * math.sqrt(isa(tr["alt_m"])[2] / 1.225)  # the pitot's Δp ↦ equivalent airspeed
        assert m.airspeed == pytest.approx(eas, rel=0.03), (m.airspeed, eas, tr["airspeed_m_s"])
    fixes = [m.fix_type for s, m in flight.msgs["GPS_RAW_INT"] if s - flight.boot_us > 1_000_000]
    assert fixes and set(fixes) == {3}  # 3-D fixes once the receiver has delivered its first (latency)


def test_simstate_is_the_truth(flight: Flight) -> None:
    """SIMSTATE as ArduPilot SITL sends it: the simulator's attitude [rad], accelerometer reading [m/s²], body
    rates [rad/s] and position [degE7], equal to the truth file at the step it was sent."""
    assert len(flight.msgs["SIMSTATE"]) == round(FLIGHT_S * GCS_HZ)
    for s, m in flight.msgs["SIMSTATE"]:
        i = flight.row(s)
        tr = flight.truth
        np.testing.assert_allclose([m.roll, m.pitch, m.yaw], euler_from_quat(tr["q_nb"][i]), atol=1e-6)
        np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], tr["specific_force_b_m_s2"][i], rtol=1e-6, atol=1e-5)
        np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], tr["omega_b_rad_s"][i], rtol=1e-6, atol=1e-7)
        assert abs(m.lat - tr["lat_deg"][i] * 1e7) <= 0.5 + 1e-6 and abs(m.lng - tr["lon_deg"][i] * 1e7) <= 0.5 + 1e-6


def test_the_projects_reader_and_replay_take_it(
    flight: Flight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """firmware_bridge's tlog reader uses RAW_IMU (the best IMU stream in a GCS recording) and SIMSTATE as the
    truth; ``vdm-aero replay --modes ins`` with a GNSS outage cut in runs to the end."""
    from firmware_bridge.logs.tlog import read_tlog
    from vdm_aero_cli.main import main

    rec = read_tlog(flight.tlog)
    assert rec.log.meta["imu"] == "RAW_IMU" and rec.log.meta["rates_hz"]["imu"] == pytest.approx(GCS_HZ, rel=0.01)
    assert rec.report.used["SIMSTATE"] == round(FLIGHT_S * GCS_HZ)
    capsys.readouterr()
    rc = main(["replay", str(flight.tlog), "--outage", "20:30", "--modes", "ins", "--json", "--out",
               str(tmp_path / "r"), "--jobs", "1"])  # fmt: skip
    out = capsys.readouterr()
    assert rc == 0, out.err[-2000:]
    doc = json.loads(out.out)
    assert doc["modes"] == ["ins"] and doc["reference"] == "truth: tlog SIMSTATE"
    assert math.isfinite(doc["outages"][0]["modes"]["ins"]["final_error_m"])


def test_without_an_airspeed_sensor_and_with_an_override(tmp_path: Path) -> None:
    """No pitot: SCALED_PRESSURE's Δp and its temperature are 0 and VFR_HUD's airspeed is the estimate's;
    --stream-rate overrides the ground station's request for one message, its group keeps 4 Hz."""
    f = _fly(tmp_path, "survey-no-airspeed", 5.0, "--stream-rate", "ATTITUDE=10")
    assert all(m.press_diff == 0.0 and m.temperature_press_diff == 0 for _, m in f.msgs["SCALED_PRESSURE"])
    for s, m in f.msgs["VFR_HUD"]:
        assert m.airspeed == pytest.approx(f.truth["airspeed_m_s"][f.row(s)], rel=1e-6)
    assert len(f.msgs["ATTITUDE"]) == 50 and len(f.msgs["SIMSTATE"]) == len(f.msgs["AOA_SSA"]) == 20
