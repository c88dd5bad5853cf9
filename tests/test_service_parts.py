"""The companion service's parts, each against an independent reference: MAVLink units (the mock's own
encoders are the peer), GPS week time (a published epoch), the sd_notify protocol (a fake NOTIFY_SOCKET),
port frames, IMU increments, the autopilot clock, the config's one-line errors, and the state file."""

from __future__ import annotations

import contextlib
import math
import socket
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.config import ConfigError, load_config
from firmware_bridge.inputs import AutopilotClock, PortAssembler
from firmware_bridge.outputs import gps_week_time, inflation
from firmware_bridge.sd_notify import SdNotify
from firmware_bridge.transport import parse_url
from vdm_aero.errors import UserInputError
from vdm_aero.nav.imu_increments import ImuIntegrator

DEPLOY = Path(__file__).resolve().parent.parent / "deploy" / "config.yaml"


def _roundtrip(msg: object) -> object:
    """Pack with one codec, parse with another: what the service really sees."""
    sink = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    buf = msg.pack(sink)  # type: ignore[attr-defined]
    rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    return rx.parse_buffer(buf)[0]


def test_units_from_the_mock_encoders() -> None:
    """The mock (sim.sitl.streams) converts SI → MAVLink on its own; the service must get the SI back."""
    from sim.sitl.streams import to_cdeg_heading, to_deg_e7, to_mm

    mav = mavlink2.MAVLink(None, 1, 1)
    m = _roundtrip(mav.scaled_imu_encode(1234, 1000, -20, -980, 10, -5, 3, 200, -49, 465, 2512))
    s = units.from_scaled_imu(m)
    assert s.t_s == pytest.approx(1.234)
    np.testing.assert_allclose(s.accel_b_m_s2, np.array([1000, -20, -980]) * 9.80665e-3)
    np.testing.assert_allclose(s.gyro_b_rad_s, [0.010, -0.005, 0.003])
    np.testing.assert_allclose(s.mag_b_ut, [20.0, -4.9, 46.5])  # 1 mG = 0.1 µT
    assert s.temperature_c == pytest.approx(25.12)
    lat, lon, alt, vn, ve = 42.2830335, -71.3500307, 155.6, 12.0, -9.0
    course = math.atan2(ve, vn)
    m = _roundtrip(mav.gps_raw_int_encode(5_000_000, 3, to_deg_e7(lat), to_deg_e7(lon), to_mm(alt), 80, 120,
                                          round(100 * math.hypot(vn, ve)), to_cdeg_heading(course), 14, 0, 700,
                                          1000, 200, 0, 0))  # fmt: skip
    g = units.from_gps_raw_int(m)
    assert g is not None and g.t_s == 5.0 and g.fix_type == 3
    assert (g.lat_deg, g.lon_deg, g.alt_m) == pytest.approx((lat, lon, alt), abs=1e-7)
    np.testing.assert_allclose(g.v_ned_m_s[:2], [vn, ve], atol=0.02)  # cm/s and cdeg quantisation
    assert math.isnan(g.v_ned_m_s[2]) and g.h_acc_m == pytest.approx(0.7) and g.v_acc_m == pytest.approx(1.0)
    no_fix = _roundtrip(mav.gps_raw_int_encode(1, 1, 0, 0, 0, 65535, 65535, 65535, 65535, 0))
    assert units.from_gps_raw_int(no_fix) is None
    p = units.from_scaled_pressure(_roundtrip(mav.scaled_pressure_encode(2000, 1001.25, 0.61, 1530, 0)))
    assert (p.static_pa, p.pitot_dp_pa, p.temperature_c) == pytest.approx((100125.0, 61.0, 15.3), rel=1e-6)
    no_pitot = units.from_scaled_pressure(_roundtrip(mav.scaled_pressure_encode(2000, 1001.25, 0.0, 1530, 0)))
    assert math.isnan(no_pitot.pitot_dp_pa)
    # the airspeed sensor's temperature (a MAVLink 2 extension): cdegC, 0 = not reported
    assert math.isnan(p.pitot_temperature_c)
    warm = units.from_scaled_pressure(_roundtrip(mav.scaled_pressure_encode(2000, 1001.25, 0.61, 4480, 1234)))
    assert warm.pitot_temperature_c == pytest.approx(12.34) and warm.temperature_c == pytest.approx(44.8)
    h = units.from_highres_imu(_roundtrip(mav.highres_imu_encode(2_500, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, -0.05,
                                                                 0.45, 1001.0, 0.6, 100.0, 31.0, 0x1FFF)))  # fmt: skip
    np.testing.assert_allclose(h.mag_b_ut, [20.0, -5.0, 45.0], rtol=1e-6)  # gauss → µT
    assert h.t_s == pytest.approx(0.0025)
    h2 = units.from_highres_imu(
        _roundtrip(mav.highres_imu_encode(2_500, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x3F))
    )
    assert h2.mag_b_ut is None  # fields_updated says the magnetometer is not in this one


def test_gps_week_time_against_known_dates() -> None:
    # 2017-01-01T00:00:00Z (leap second 18 in force from then): GPS week 1930, Sunday + 18 s
    assert gps_week_time(1483228800.0) == (1930, 18_000)
    # the GPS epoch itself, in UTC, is 1980-01-06T00:00:00Z; 18 s earlier in UTC is week 0 ms 0 with 18 leaps
    assert gps_week_time(315964800.0 - 18.0) == (0, 0)
    assert inflation(5.0) == pytest.approx(math.sqrt(10.0))


def test_sd_notify_against_a_fake_socket(tmp_path: Path) -> None:
    path = str(tmp_path / "notify.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.settimeout(2.0)
    try:
        n = SdNotify(path)
        assert n.notify(ready=1, status="listening")
        assert server.recv(4096) == b"READY=1\nSTATUS=listening"
        assert n.notify(watchdog=1) and server.recv(4096) == b"WATCHDOG=1"
        assert n.notify(stopping=1) and server.recv(4096) == b"STOPPING=1"
        n.close()
    finally:
        server.close()
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path + "2")
    try:  # a receiver that never reads: its queue fills and the service goes on (counted, never blocked)
        slow = SdNotify(path + "2")
        sent = [slow.notify(watchdog=1) for _ in range(200)]
        assert sent[0] and not all(sent) and slow.failures == sent.count(False)
    finally:
        server.close()
    gone = SdNotify(path)  # the socket is gone: counted, not raised
    assert not gone.notify(ready=1) and gone.failures == 1
    assert not SdNotify(None).notify(ready=1)  # not under systemd: a no-op


def test_port_frames_complete_straddling_partial_and_unknown() -> None:
    a = PortAssembler(["P00", "P01", "P02"], timeout_s=0.05)
    assert a.add(1000, "P00", 1.0, 0.0) == [] and a.add(1000, "P01", 2.0, 0.0) == []
    (fr,) = a.add(1001, "P02", 3.0, 0.001)  # a script update straddling one millisecond is one frame
    assert fr.complete and fr.t_s == 1.0 and list(fr.dp_pa) == [1.0, 2.0, 3.0]
    a.add(1020, "P00", 4.0, 0.02)
    a.add(1020, "BATT", 12.0, 0.02)  # someone else's named value
    (partial,) = a.add(1040, "P00", 5.0, 0.04)  # the next frame starts: the open one closes partial
    assert not partial.complete and partial.dp_pa[0] == 4.0 and np.isnan(partial.dp_pa[1:]).all()
    assert a.expire(0.08) is None and a.expire(0.2) is not None  # a lone value times out
    assert a.counts == {"complete": 1, "partial": 2, "unknown_name": 1, "late": 0}


def test_a_port_value_sent_again_late_never_splits_a_frame() -> None:
    """A buffering radio sends a port value of the last frame again a second later: late, dropped and counted,
    whether a frame is open (with that port already in it) or not; after a reboot the times start again."""
    a = PortAssembler(["P00", "P01"], timeout_s=0.05)
    a.add(1000, "P00", 1.0, 0.0)
    a.add(1000, "P01", 2.0, 0.0)
    a.add(2000, "P00", 3.0, 1.0)
    assert a.add(1000, "P00", 1.0, 1.0) == []  # the old P00 again, while P00 of 2000 is in the open frame
    (fr,) = a.add(2000, "P01", 4.0, 1.0)
    assert fr.complete and list(fr.dp_pa) == [3.0, 4.0]
    assert a.add(1000, "P01", 2.0, 1.1) == []  # ... and with no frame open
    assert a.counts == {"complete": 2, "partial": 0, "unknown_name": 0, "late": 2}
    # values of the frame just closed (a straggler of a frame the timeout closed, a copy the endpoint's duplicate
    # check let through), one a millisecond after its stamp: late, not a frame of its own that the next frame
    # would close partial, nor a second copy of the frame
    assert a.add(2000, "P01", 4.0, 1.15) == [] and a.add(2001, "P00", 3.0, 1.16) == []
    a.add(2010, "P00", 7.0, 1.2)
    (fr,) = a.add(2010, "P01", 8.0, 1.2)
    assert fr.complete and list(fr.dp_pa) == [7.0, 8.0]
    assert a.counts == {"complete": 3, "partial": 0, "unknown_name": 0, "late": 4}
    a.restart()  # the autopilot rebooted: its millis() start again
    a.add(5, "P00", 5.0, 1.2)
    (fr,) = a.add(5, "P01", 6.0, 1.2)
    assert fr.complete and fr.t_s == 0.005


def test_imu_increments_integrate_a_constant_rate() -> None:
    integ = ImuIntegrator(50.0)
    w, f = np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.0, -9.8])
    steps = []
    for k in range(401):  # 1 s at 400 Hz
        if (r := integ.add(k / 400.0, (0.1, -0.2, 0.3), (0.5, 0.0, -9.8))) is not None:
            steps.append(r)
    assert len(steps) == 50
    for _, inc in steps:
        assert inc.dt_s == pytest.approx(0.02)
        np.testing.assert_allclose(inc.dtheta_b, w * 0.02, rtol=1e-9)
        np.testing.assert_allclose(inc.dvel_b, f * 0.02, rtol=1e-9)
    assert integ.add(5.0, (0.0,) * 3, (0.0,) * 3) is None and integ.gaps == 1


def test_clock_is_continuous_across_an_autopilot_reboot_and_timesync() -> None:
    c = AutopilotClock()
    assert not c.observe_boot_s(100.0)
    t_before = c.filter_s(100.0)
    assert c.observe_boot_s(2.0) and c.reboots == 1
    # down for at least the 2 s the autopilot has been up again: the filter sees that gap
    assert c.filter_s(2.0) == pytest.approx(t_before + 2.0)
    c.timesync(tc1_ns=50_000_000_000, ts1_ns=1_000_000_000, now_ns=1_002_000_000)  # 2 ms round trip
    assert c.offset_s == pytest.approx(50.0 - 1.001) and c.rtt_s == pytest.approx(0.002)


def test_urls() -> None:
    assert str(parse_url("udpin://0.0.0.0:14551")) == "udpin://0.0.0.0:14551"
    assert parse_url("serial:///dev/ttyAMA0:921600").host == "/dev/ttyAMA0"
    assert parse_url("tcp:127.0.0.1:5760").port == 5760
    for bad in ("udp://x:1", "udpin://nohost", "serial:///dev/ttyS0:12", "tcp://h:70000"):
        with pytest.raises(UserInputError):
            parse_url(bad)


# ------------------------------------------------------------------------------------------- config
def _config(tmp_path: Path, edit: dict[str, object] | None = None) -> Path:
    from vdm_aero.vehicle import load_vehicle

    load_vehicle("uav-2m")
    cfg = yaml.safe_load(DEPLOY.read_text())
    for d in ("design", "deim", "deim-nn"):
        (tmp_path / d).mkdir(exist_ok=True)
    cfg["models"].update(design_data="design", deim="deim", deim_nn="deim-nn")
    for k, v in (edit or {}).items():
        node = cfg
        *parents, last = k.split(".")
        for p in parents:
            if not isinstance(node.get(p), dict):  # ``streams: auto`` edited into a mapping
                node[p] = {}
            node = node[p]
        node[last] = v
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def test_shipped_config_reads(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path))
    assert cfg.mode == "vdm" and cfg.deim_model == tmp_path / "deim"
    assert cfg.outputs.solution == "gps_input"
    # streams: auto asks ArduPilot for RAW_IMU (HIGHRES_IMU is not in every build), and PX4 for its HIGHRES_IMU
    # (which carries its barometer and airspeed sensor)
    assert "HIGHRES_IMU" not in cfg.streams and cfg.streams["RAW_IMU"] >= 200
    assert {"SCALED_PRESSURE", "GPS_RAW_INT", "SERVO_OUTPUT_RAW", "SYSTEM_TIME", "ATTITUDE"} <= set(cfg.streams)
    px4_edit: dict[str, object] = {"autopilot": "px4", "outputs.solution": "odometry", "outputs.solution_hz": 10}
    px4 = load_config(_config(tmp_path, px4_edit))
    assert "RAW_IMU" not in px4.streams and px4.streams["HIGHRES_IMU"] >= 100 and "SCALED_PRESSURE" not in px4.streams
    mine = load_config(_config(tmp_path, {"streams.SCALED_IMU": 20}))
    assert mine.streams == {"SCALED_IMU": 20}  # a mapping replaces the set


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        ({"navigation.moed": "ins"}, "navigation.moed: unknown key"),
        ({"navigation.mode": "vdm-magic"}, "navigation.mode: expected one of"),
        ({"streams.HIGHRES_IMUU": 100}, "streams.HIGHRES_IMUU: unknown MAVLink message"),
        ({"streams": "fast"}, "streams: expected auto or a mapping"),
        ({"connection": "udp://1.2.3.4:5"}, "connection:"),
        ({"outputs.solution": "global_position_sensor"}, "outputs.solution: expected one of gps_input, odometry, none"),
        # EKF2 starts external vision only on ODOMETRY < 200 ms apart (ev_control.cpp): 5 Hz would never start it
        ({"outputs.solution_hz": 5, "autopilot": "px4", "outputs.solution": "odometry"}, "outputs.solution_hz: PX4's"),
        ({"signing.require": True}, "signing.require: signing is required but no key_file"),
        ({"models.deim": "missing-dir"}, "models.deim:"),
        ({"navigation.mag_field_ned_ut": [0.2, 0.0, 0.4]}, "not an Earth field"),
        ({"ports.names": ["P00", "P00"]}, "duplicate port name"),
    ],
)
def test_bad_config_one_line_with_key_and_line(tmp_path: Path, edit: dict[str, object], needle: str) -> None:
    path = _config(tmp_path, edit)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg
    key = next(iter(edit)).split(".")[-1]
    lines = path.read_text().splitlines()
    line = int(msg.split(":")[1])  # "<file>:<line>: key: what"
    assert key in lines[line - 1] or key == "require", (msg, lines[line - 1])


def test_cli_bad_config_exits_2_with_one_line(tmp_path: Path) -> None:
    path = _config(tmp_path, {"ports.frame_timeout_s": "fast"})
    r = subprocess.run([sys.executable, "-m", "vdm_aero_cli.main", "serve", "--check-config", "--config", str(path)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "ports.frame_timeout_s: expected a number" in r.stderr


# ------------------------------------------------------------------------------------------ outputs
def _solution() -> object:
    from firmware_bridge.outputs import Solution

    return Solution(boot_s=212.5, unix_s=1_790_000_000.25, lat_deg=42.2830335, lon_deg=-71.3500307, alt_m=155.6,
                    p_ned_m=np.array([10.0, -20.0, -105.0]), v_ned_m_s=np.array([18.0, -3.0, 0.5]),
                    q_nb=np.array([1.0, 0.0, 0.0, 0.0]), sigma_h_m=12.0, sigma_v_m=2.0, sigma_vel_m_s=0.8,
                    wind_ned_m_s=np.array([-6.0, 6.0, 0.0]), sigma_wind_m_s=0.5, fix_type=3)  # fmt: skip


def test_gps_input_decodes_to_the_solution_with_inflated_accuracies() -> None:
    from firmware_bridge.outputs import external_wind, gps_input, gps_week_time

    mav = mavlink2.MAVLink(None, 1, 191)
    s = _solution()
    m = _roundtrip(gps_input(mav, s, gps_id=1, k=3.0))  # type: ignore[arg-type]
    assert (m.gps_id, m.fix_type, m.satellites_visible) == (1, 3, 0)
    # lat/lon are degE7 integers (1e-7 deg); alt is a float32 (resolution 1.5e-5 m at 155 m)
    assert (m.lat * 1e-7, m.lon * 1e-7) == pytest.approx((42.2830335, -71.3500307), abs=1e-7)
    assert m.alt == pytest.approx(155.6, abs=2e-5)
    assert (m.vn, m.ve, m.vd) == pytest.approx((18.0, -3.0, 0.5))
    assert (m.horiz_accuracy, m.vert_accuracy, m.speed_accuracy) == pytest.approx((36.0, 6.0, 2.4))
    assert (m.time_week, m.time_week_ms) == gps_week_time(1_790_000_000.25) and m.time_usec == 212_500_000
    w = _roundtrip(external_wind(mav, s, target=(1, 1)))  # type: ignore[arg-type]
    assert w.command == 43004 and w.param1 == pytest.approx(math.hypot(6.0, 6.0))
    assert w.param3 == pytest.approx(315.0)  # blowing towards the south-east: it comes from the north-west


def test_px4_outputs_decode() -> None:
    from firmware_bridge.outputs import global_position_sensor, odometry

    mav = mavlink2.MAVLink(None, 1, 191)
    s = _solution()
    g = _roundtrip(global_position_sensor(mav, s, target=(1, 1), k=2.0))  # type: ignore[arg-type]
    assert (g.lat * 1e-7, g.lon * 1e-7) == pytest.approx((42.2830335, -71.3500307), abs=1e-7)
    assert (g.alt, g.eph, g.epv) == pytest.approx((155.6, 24.0, 4.0), abs=2e-5)  # float32 fields
    o = _roundtrip(odometry(mav, s, k=2.0, quality=77, reset_counter=258))  # type: ignore[arg-type]
    assert (o.frame_id, o.child_frame_id) == (mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_FRD)
    assert (o.quality, o.reset_counter) == (77, 2)  # a uint8 counter wraps
    assert (o.x, o.y, o.z, o.vx) == pytest.approx((10.0, -20.0, -105.0, 18.0))
    # the velocity is in the frame child_frame_id names: heading east, the body's x is east and y south
    from vdm_aero.rotation import quat_from_euler

    east_s = replace(s, q_nb=np.array(quat_from_euler(0.0, 0.0, math.pi / 2)))
    east = _roundtrip(odometry(mav, east_s, k=2.0, quality=1, reset_counter=0))  # type: ignore[arg-type]
    assert (east.vx, east.vy, east.vz) == pytest.approx((-3.0, -18.0, 0.5), abs=1e-5)
    assert east.velocity_covariance[0] == east.velocity_covariance[6] == pytest.approx((2.0 * 0.8) ** 2)
    assert (o.pose_covariance[0], o.pose_covariance[6], o.pose_covariance[11]) == pytest.approx((576.0, 576.0, 16.0))


# -------------------------------------------------------------------------------------- state file
def test_filter_state_survives_a_restart(tmp_path: Path) -> None:
    from firmware_bridge.persist import FilterStateStore
    from vdm_aero.nav.filter import NavConfig, NavFilter
    from vdm_aero.vehicle import load_vehicle

    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=np.array([20.1, -4.9, 46.5]))
    f_b, mag = np.array([0.0, 0.0, -9.80665]), np.array([20.1, -4.9, 46.5])
    a = NavFilter("airspeed-dr", cfg)
    a.initialise(0.0, np.zeros(3), np.array([20.0, 0.0, 0.0]), f_b, mag)
    assert a.x is not None
    a.x.wind_ned = np.array([-5.0, 4.0, 0.1])
    a.x.b_gyro_b = np.array([1e-3, -2e-3, 5e-4])
    a.x.aero[2] = 1.04
    store = FilterStateStore(tmp_path / "state" / "filter-state.npz")
    ids = {"models_id": "m1", "autopilot_boot_unix_s": 1_790_000_000.0}
    assert store.save(a, **ids) and not list((tmp_path / "state").glob(".*tmp"))  # atomic: no leftovers
    b = NavFilter("airspeed-dr", cfg)
    b.initialise(0.0, np.array([5.0, 5.0, 0.0]), np.array([20.0, 0.0, 0.0]), f_b, mag)
    saved = store.load()
    assert saved is not None
    restored = FilterStateStore.restore(b, saved, **ids)
    assert restored == ["bg", "ba", "wind", "bm", "baro", "aero"] and b.x is not None
    np.testing.assert_allclose(b.x.wind_ned, [-5.0, 4.0, 0.1])
    np.testing.assert_allclose(b.x.b_gyro_b, [1e-3, -2e-3, 5e-4])
    assert b.x.aero[2] == pytest.approx(1.04)
    np.testing.assert_allclose(b.x.p_ned, [5.0, 5.0, 0.0])  # the pose is the new initialisation's
    from vdm_aero.nav.state import IDX

    w = IDX["wind"]
    assert np.allclose(np.diag(b.P)[w], 4.0 * np.diag(a.P)[w])  # σ doubled
    assert np.all(np.linalg.eigvalsh(b.P) > 0.0)
    (tmp_path / "state" / "filter-state.npz").write_bytes(b"not a state file")
    with pytest.raises(UserInputError, match=r"filter-state\.npz: not a filter state file"):
        store.load()


def test_a_state_file_saved_before_an_aero_parameter_was_added_keeps_its_states(tmp_path: Path) -> None:
    """An upgrade that adds a model-correction parameter (``cy_bias``, format 3) must not cost the state an
    older service saved (format 2: six parameters, no names): each saved state keeps its value and
    covariance, the new parameter starts at its prior."""
    from firmware_bridge.persist import AERO_PARAMS_V2, FORMAT_V2, FilterStateStore
    from vdm_aero.nav.filter import NavConfig, NavFilter, slow_index
    from vdm_aero.nav.state import AERO_PARAMS, AERO_PRIOR, IDX
    from vdm_aero.vehicle import load_vehicle

    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=np.array([20.1, -4.9, 46.5]))
    f_b, mag = np.array([0.0, 0.0, -9.80665]), np.array([20.1, -4.9, 46.5])
    a = NavFilter("vdm-deim", cfg)
    a.initialise(0.0, np.zeros(3), np.array([20.0, 0.0, 0.0]), f_b, mag)
    store = FilterStateStore(tmp_path / "filter-state.npz")
    assert store.save(a, models_id="m1")
    values, cov = a.slow_states()
    n_gm = IDX["gm"].stop - IDX["gm"].start
    n_other = len(slow_index()) - len(AERO_PARAMS) - n_gm  # the aero block, then δM (format 4), end the vector
    values, cov = values[:-n_gm], cov[:-n_gm, :-n_gm]  # formats 1-3 held no δM
    rng = np.random.default_rng(3)
    values = values + rng.normal(0.0, 0.01, len(values))
    m = rng.normal(size=(len(values), len(values)))
    cov = m @ m.T * 1e-4 + np.diag(np.diag(cov))  # correlated, as a flown filter's is
    keep = np.r_[np.arange(n_other), n_other + np.array([AERO_PARAMS.index(k) for k in AERO_PARAMS_V2])]
    with np.load(store.path) as z:
        old = {k: z[k] for k in z.files if k != "aero_params"}
    old.update(format=np.array(FORMAT_V2), values=values[keep], cov=cov[np.ix_(keep, keep)])
    np.savez(store.path, **old)
    saved = store.load()
    assert saved is not None and not saved["gm_estimated"]
    got_v, got_c = saved["values"][:-n_gm], saved["cov"][:-n_gm, :-n_gm]
    assert got_v.shape == values.shape and got_c.shape == cov.shape
    assert not np.any(saved["values"][-n_gm:]) and not np.any(saved["cov"][-n_gm:])  # δM: none, not restored
    for i, k in enumerate(AERO_PARAMS):
        j = n_other + i
        if k in AERO_PARAMS_V2:
            assert got_v[j] == values[j] and got_c[j, j] == cov[j, j]
        else:  # the new one: its prior, uncorrelated with the rest
            assert (got_v[j], got_c[j, j]) == (AERO_PRIOR[k][0], AERO_PRIOR[k][1] ** 2)
            assert np.count_nonzero(got_c[j]) == 1
    np.testing.assert_array_equal(got_v[:n_other], values[:n_other])
    np.testing.assert_array_equal(got_c[:n_other, :n_other], cov[:n_other, :n_other])
    assert np.all(np.linalg.eigvalsh(got_c) > 0.0)
    b = NavFilter("vdm-deim", cfg)
    b.initialise(0.0, np.zeros(3), np.array([20.0, 0.0, 0.0]), f_b, mag)
    restored = FilterStateStore.restore(b, saved, models_id="m1")
    assert restored == ["bg", "ba", "wind", "bm", "baro", "aero", "-bias-sigma"]


def test_the_gyros_scale_errors_outlive_a_restart_a_reboot_and_a_dropped_pose(tmp_path: Path) -> None:
    """δM is learnt only in turns while GNSS aids; it is the gyro's, so a service restart (into any mode that
    estimates it, even after a power cycle), an autopilot reboot and a long IMU gap keep it. A mode that does not
    estimate it neither gives nor takes it, and a state file from before δM (format 3) leaves it at its prior."""
    from firmware_bridge.persist import FORMAT_V3, FilterStateStore
    from vdm_aero.nav.filter import NavConfig, NavFilter
    from vdm_aero.nav.state import IDX
    from vdm_aero.vehicle import load_vehicle

    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=np.array([20.1, -4.9, 46.5]))
    f_b, mag, v0 = np.array([0.0, 0.0, -9.80665]), np.array([20.1, -4.9, 46.5]), np.array([20.0, 0.0, 0.0])
    gm = IDX["gm"]
    m = np.array([[0.004, 0.002, -0.001], [-0.003, -0.005, 0.0015], [0.001, 0.0025, 0.006]])  # a learnt δM

    def flown(mode: str) -> NavFilter:
        f = NavFilter(mode, cfg)
        f.initialise(0.0, np.zeros(3), v0, f_b, mag)
        assert f.x is not None and f.engine is not None
        f.x.gyro_m_err_b = m.copy()
        p = f.engine.P
        p[gm, gm] = np.diag(np.full(9, 1e-6))  # σ 1e-3: learnt, tighter than its prior
        f.engine.P = p  # P is a new array where the mode's layout leaves δM out of the engine
        return f

    def fresh(mode: str) -> NavFilter:
        f = NavFilter(mode, cfg)
        f.initialise(0.0, np.array([5.0, 5.0, 0.0]), v0, f_b, mag)
        return f

    prior = np.sqrt(np.diag(fresh("vdm").P)[gm])
    store = FilterStateStore(tmp_path / "filter-state.npz")
    boot = 1_790_000_000.0
    assert store.save(flown("vdm"), models_id="m1", autopilot_boot_unix_s=boot)
    saved = store.load()
    assert saved is not None and saved["gm_estimated"]
    b = fresh("vdm")  # a restart after a power cycle, other models: the biases' σ and the aero go, δM stays
    got = FilterStateStore.restore(b, saved, models_id="m2", autopilot_boot_unix_s=boot + 3600.0)
    assert b.x is not None and "gm" in got and {"-aero", "-bias-sigma"} <= set(got)
    np.testing.assert_allclose(b.x.gyro_m_err_b, m)
    np.testing.assert_allclose(np.sqrt(np.diag(b.P)[gm]), 2e-3)  # the saved σ × 2
    c = fresh("ins")  # leaves δM out of its dynamics: takes nothing
    assert "gm" not in FilterStateStore.restore(c, saved, models_id="m1", autopilot_boot_unix_s=boot)
    assert c.x is not None and not np.any(c.x.gyro_m_err_b)
    assert store.save(flown("ins"), models_id="m1")  # gives nothing either: its δM was never estimated
    d = fresh("vdm")
    assert "gm" not in FilterStateStore.restore(d, store.load() or {}, models_id="m1")
    with np.load(store.path) as z:  # a format-3 file: the same states without δM
        old = {k: z[k] for k in z.files if k != "gm_estimated"}
    old.update(format=np.array(FORMAT_V3), values=old["values"][:-9], cov=old["cov"][:-9, :-9])
    np.savez(store.path, **old)
    e = fresh("vdm")
    assert "gm" not in FilterStateStore.restore(e, store.load() or {}, models_id="m1")
    assert e.x is not None and not np.any(e.x.gyro_m_err_b)
    np.testing.assert_allclose(np.sqrt(np.diag(e.P)[gm]), prior)

    for lose_pose in ("autopilot_rebooted", "long IMU gap"):  # aided: the pose starts again at the next fix
        f = flown("vdm")
        if lose_pose == "autopilot_rebooted":
            f.autopilot_rebooted()
        else:
            f._drop_pose(5.0)
        assert f.x is None
        f.initialise(10.0, np.array([300.0, 0.0, 0.0]), v0, f_b, mag)
        assert f.x is not None, lose_pose
        np.testing.assert_array_equal(f.x.gyro_m_err_b, m)
        np.testing.assert_allclose(np.sqrt(np.diag(f.P)[gm]), 1e-3)


# ------------------------------------------------------------------------------------ links, signing
def test_tcp_link_reconnects_with_backoff() -> None:
    import time

    from firmware_bridge.transport import BACKOFF_MIN_S, open_transport

    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nothing listens there yet
    t = open_transport(f"tcp://127.0.0.1:{port}")
    t.send(b"lost")
    assert not t.connected and t.dropped_sends == 1
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port))
    server.listen(1)
    try:
        deadline = time.monotonic() + 5.0
        while not t.connected and time.monotonic() < deadline:
            t.recv(0.1)  # retried after the backoff, not in a busy loop
        assert t.connected
        conn, _ = server.accept()
        conn.sendall(b"\xfd hello")
        assert t.recv(1.0) == b"\xfd hello"
        conn.close()  # the autopilot side goes away ...
        assert t.recv(1.0) == b"" and not t.connected
        time.sleep(BACKOFF_MIN_S)
        while not t.connected and time.monotonic() < deadline + 5.0:
            t.recv(0.1)
        assert t.connected and t.reconnects == 1  # ... and comes back
    finally:
        t.close()
        server.close()


def test_serial_link_on_a_pseudo_terminal() -> None:
    import os
    import tty

    from firmware_bridge.transport import open_transport

    master, slave = os.openpty()
    tty.setraw(slave)
    t = open_transport(f"serial://{os.ttyname(slave)}:921600")
    try:
        t.send(b"\xfd frame")
        assert t.connected and os.read(master, 64) == b"\xfd frame"
        os.write(master, b"\xfd reply")
        assert t.recv(1.0) == b"\xfd reply"
    finally:
        t.close()
        os.close(master)
        os.close(slave)


def test_serial_device_that_disappears_and_comes_back_is_reopened(tmp_path: Path) -> None:
    """A USB serial adapter unplugged and plugged in again: the stable name (a udev symlink, as
    /dev/serial/by-id/...) points at a new device; the transport notices, backs off and reopens it."""
    import os
    import time
    import tty

    from firmware_bridge.transport import open_transport

    link = tmp_path / "ttyFC"

    def plug() -> tuple[int, int]:
        master, slave = os.openpty()
        tty.setraw(slave)
        link.unlink(missing_ok=True)
        link.symlink_to(os.ttyname(slave))
        return master, slave

    master, slave = plug()
    t = open_transport(f"serial://{link}:921600")
    try:
        t.send(b"one")
        assert os.read(master, 64) == b"one"
        os.close(master)  # unplugged: the device's other end is gone
        os.close(slave)
        link.unlink()
        end = time.monotonic() + 2.0
        while t.connected and time.monotonic() < end:
            t.recv(0.05)
        assert not t.connected
        t.send(b"lost")  # nothing to send to: counted, not raised
        assert t.dropped_sends >= 1
        master, slave = plug()  # plugged in again, under the same name
        end = time.monotonic() + 10.0  # the backoff is at most 8 s
        got = b""
        os.write(master, b"back")
        while got != b"back" and time.monotonic() < end:
            got += t.recv(0.1)
            if not got and t.connected:
                os.write(master, b"back")
        assert got.endswith(b"back") and t.connected and t.reconnects == 1
        t.send(b"two")
        assert os.read(master, 64) == b"two"
    finally:
        t.close()
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class _Loopback:
    """A transport that hands back what it is given to ``recv`` (for the codec tests)."""

    description = "loopback"
    dropped_sends = 0
    reconnects = 0
    connected = True

    def __init__(self) -> None:
        self.inbox = b""

    def send(self, data: bytes) -> None:
        pass

    def recv(self, timeout_s: float) -> bytes:
        data, self.inbox = self.inbox, b""
        return data

    def close(self) -> None:
        pass


def test_required_signing_rejects_and_counts_unsigned(tmp_path: Path) -> None:
    import time

    from firmware_bridge.endpoint import MavEndpoint, load_signing_key

    key_file = tmp_path / "key"
    key_file.write_text("ab" * 32 + "\n")  # 64 hex digits
    key = load_signing_key(key_file, require=True)
    link = _Loopback()
    ep = MavEndpoint(link, system_id=1, component_id=191, signing=key)
    autopilot = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    unsigned = autopilot.named_value_float_encode(1000, b"P00", 12.5).pack(autopilot)
    link.inbox = unsigned
    assert ep.poll(0.0) == [] and ep.rejected_unsigned == 1
    signer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    now_ticks = int((time.time() - 1420070400) * 100_000)  # MAVLink signing time: 10 µs since 2015
    signer.signing.secret_key, signer.signing.sign_outgoing, signer.signing.timestamp = key.key, True, now_ticks
    link.inbox = signer.named_value_float_encode(1000, b"P00", 12.5).pack(signer)
    (msg,) = ep.poll(0.0)
    assert msg.value == 12.5 and ep.rejected_unsigned == 1
    (tmp_path / "short").write_bytes(b"\x01" * 16)
    with pytest.raises(UserInputError, match="32 raw bytes or 64 hex digits"):
        load_signing_key(tmp_path / "short", require=False)


def test_navigation_log_is_rotated(tmp_path: Path) -> None:
    from firmware_bridge.persist import NAV_LOG_COLUMNS, NavLog

    log = NavLog(tmp_path / "nav.csv", max_bytes=2000, backups=2)
    for k in range(200):
        log.write([float(k), 1.5, "aided", "vdm-deim"])
    log.close()
    files = sorted(p.name for p in tmp_path.iterdir())
    assert files == ["nav.csv", "nav.csv.1", "nav.csv.2"]  # older ones dropped, never grown without bound
    assert all(p.stat().st_size <= 2000 for p in tmp_path.iterdir())
    assert (tmp_path / "nav.csv").read_text().splitlines()[-1] == "199,1.5,aided,vdm-deim"
    assert NAV_LOG_COLUMNS.count(",") == 20


def test_udp_replies_go_to_the_last_sender_whose_frames_were_accepted(tmp_path: Path) -> None:
    """udpin replies to its peer; garbage or a rogue's unsigned frames (signing required) never move it."""
    import time

    from firmware_bridge.endpoint import MavEndpoint, load_signing_key
    from firmware_bridge.transport import open_transport

    key_file = tmp_path / "key"
    key_file.write_text("cd" * 32)
    key = load_signing_key(key_file, require=True)
    t = open_transport("udpin://127.0.0.1:0")
    port = t.local_address[1]
    ep = MavEndpoint(t, system_id=1, component_id=191, signing=key)
    signer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    signer.signing.secret_key, signer.signing.sign_outgoing = key.key, True
    signer.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    rogue_mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ap,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rogue,
    ):
        ap.settimeout(1.0)
        rogue.settimeout(0.3)

        def poll_all() -> list[object]:
            out: list[object] = []
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                out += ep.poll(0.05)
            return out

        rogue.sendto(b"\xfd\x09garbage-that-is-not-a-frame", ("127.0.0.1", port))
        assert poll_all() == [] and not t.connected  # garbage names no peer
        ap.sendto(signer.heartbeat_encode(1, 3, 0, 0, 4).pack(signer), ("127.0.0.1", port))
        assert len(poll_all()) == 1 and t.connected
        rogue.sendto(rogue_mav.heartbeat_encode(1, 3, 0, 0, 4).pack(rogue_mav), ("127.0.0.1", port))
        assert poll_all() == [] and ep.rejected_unsigned == 1
        ep.send(ep.mav.heartbeat_encode(18, 8, 0, 0, 4))
        assert len(ap.recv(512)) > 0  # the reply went to the autopilot
        with pytest.raises(TimeoutError):
            rogue.recv(512)
    t.close()


# ----------------------------------------------------------------------------------- servo mapping
def _vehicle_with(tmp_path: Path, edits: dict[str, dict[str, Any]]) -> Path:
    from importlib import resources

    doc = yaml.safe_load(resources.files("vdm_aero").joinpath("vehicles", "uav-2m.yaml").read_text())
    for surface, kv in edits.items():
        doc["servos"][surface].update(kv)
    p = tmp_path / "my-plane.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def test_servo_outputs_map_from_any_channel(tmp_path: Path) -> None:
    # ailerons on SERVO6 and elevator on SERVO9 (a V-tail mixer, a flaperon set-up): SERVO_OUTPUT_RAW's outputs
    # beyond the fourth reach the force model
    from firmware_bridge.units import from_servo_output_raw
    from vdm_aero.vehicle import load_vehicle

    v = load_vehicle(str(_vehicle_with(tmp_path, {"aileron": {"channel": 6}, "elevator": {"channel": 9}})))
    assert v.servos.channels == (6, 9, 3, 4)
    mav = mavlink2.MAVLink(None, 1, 1)
    pwm = [1500] * 16
    pwm[5], pwm[8], pwm[2], pwm[0], pwm[1] = 1700, 1300, 1750, 1100, 1900  # outputs 1 and 2 now drive nothing
    m = _roundtrip(mav.servo_output_raw_encode(1_000_000, 0, *pwm[:8], *pwm[8:]))
    s = from_servo_output_raw(m)
    ail, ele, rud, thr = v.servos.deflections_rad(v.servos.surfaces_pwm_us(s.pwm_us[None, :]))
    assert float(ail[0]) == pytest.approx(200.0 / 1432.394)
    assert float(ele[0]) == pytest.approx(-200.0 / 1432.394)
    assert (float(rud[0]), float(thr[0])) == pytest.approx((0.0, 0.75))


@pytest.mark.parametrize(("edits", "message"), [
    ({"aileron": {"channel": 17}}, r"servos\.aileron\.channel: expected a servo output 1\.\.16, got 17"),
    ({"rudder": {"channel": 3}}, r"servos\.rudder\.channel: output 3 is already throttle"),
])  # fmt: skip
def test_a_bad_servo_channel_is_one_line(tmp_path: Path, edits: dict[str, dict[str, Any]], message: str) -> None:
    from vdm_aero.errors import VehicleError
    from vdm_aero.vehicle import load_vehicle

    with pytest.raises(VehicleError, match=message):
        load_vehicle(str(_vehicle_with(tmp_path, edits)))


@pytest.mark.parametrize(
    ("later", "held"),
    [
        ({}, []),
        ({"models_id": "other-models"}, ["-aero"]),
        ({"mode": "ins"}, ["-aero"]),
        ({"autopilot_boot_unix_s": 1_790_000_600.0}, ["-bias-sigma"]),  # the autopilot booted since the save
        ({"autopilot_boot_unix_s": math.nan}, ["-bias-sigma"]),  # its boot unknown: assume the worst
    ],
)
def test_a_restored_state_is_checked_against_the_mode_the_models_and_the_boot(
    tmp_path: Path, later: dict[str, Any], held: list[str]
) -> None:
    from firmware_bridge.persist import FilterStateStore
    from vdm_aero.nav.filter import NavConfig, NavFilter
    from vdm_aero.nav.state import IDX
    from vdm_aero.vehicle import load_vehicle

    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=np.array([20.1, -4.9, 46.5]))
    f_b, mag = np.array([0.0, 0.0, -9.80665]), np.array([20.1, -4.9, 46.5])
    a = NavFilter("airspeed-dr", cfg)
    a.initialise(0.0, np.zeros(3), np.array([20.0, 0.0, 0.0]), f_b, mag)
    assert a.x is not None and a.engine is not None
    a.x.aero[2] = 1.04
    a.x.b_gyro_b = np.array([1e-3, -2e-3, 5e-4])
    p = a.engine.P
    p[IDX["bg"], IDX["bg"]] = 1e-8  # converged
    a.engine.P = p  # a new array in this mode's layout (EkfEngine.P)
    store = FilterStateStore(tmp_path / "filter-state.npz")
    boot = 1_790_000_000.0
    assert store.save(a, models_id="models-1", autopilot_boot_unix_s=boot)
    saved = store.load()
    assert saved is not None
    now = {"mode": "airspeed-dr", "models_id": "models-1", "autopilot_boot_unix_s": boot + 0.4} | later
    b = NavFilter(str(now["mode"]), cfg)
    b.initialise(0.0, np.zeros(3), np.array([20.0, 0.0, 0.0]), f_b, mag)
    assert b.x is not None and b.engine is not None
    got = FilterStateStore.restore(b, saved, models_id=str(now["models_id"]),
                                   autopilot_boot_unix_s=float(now["autopilot_boot_unix_s"]))  # fmt: skip
    assert [r for r in got if r.startswith("-")] == held
    assert b.x.aero[2] == pytest.approx(1.04 if "-aero" not in held else 1.0)
    np.testing.assert_allclose(b.x.b_gyro_b, [1e-3, -2e-3, 5e-4])  # the values are kept either way
    sigma_bg = np.sqrt(np.diag(b.engine.P)[IDX["bg"]])
    want = cfg.gyro_bias_sigma_rad_s if "-bias-sigma" in held else 2.0 * 1e-4  # turn-on σ, or the saved σ × 2
    np.testing.assert_allclose(sigma_bg, want, rtol=1e-6)
