"""The streams the service asks for, and what it does with what comes (issue 24): an autopilot that sends slower
than asked (ArduPilot: nothing faster than its loop, SCHED_LOOP_RATE) is said once and not asked again while the
stream keeps that rate; a stream that falls below it (a reboot's 1 Hz defaults) is asked for again; an IMU too
slow to integrate alone starts a filter that fuses the autopilot's ATTITUDE, as replay does."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from tests.test_fault_inputs import WARM_S, WARM_T0_S, _Autopilot, _close, _service_config, _warm_service


def _raw_imu(ap: _Autopilot, t: float) -> object:
    """Level, still: 1 g up in FRD (mG), no rotation, a field of ~0.5 G (mgauss), 25 °C."""
    return ap(ap.tx.raw_imu_encode(round(t * 1e6), 0, 0, -1000, 0, 0, 0, 200, -49, 465, 0, 2500))


def test_a_stream_capped_by_the_autopilot_is_said_once_and_healed_when_it_drops(
    design_deim12: dict[str, Path], tmp_path: Path
) -> None:
    from vdm_aero.nav.models import NavModels

    cfg = _service_config(tmp_path, design_deim12, "caps", {})  # streams: auto → RAW_IMU at 400 Hz on ArduPilot
    assert cfg.streams["RAW_IMU"] == 400
    models = NavModels.load(cfg.design_data, cfg.deim_model, None, cfg.vehicle)
    ap = _Autopilot()
    svc = _warm_service(cfg, models, ap)
    try:
        check_s = 3.0  # service.STREAM_CHECK_S: the counts below are per check

        def check(imu_hz: float, t0: float) -> tuple[int, float]:
            n0 = svc.stats.stream_requests
            for k in range(round(imu_hz * check_s)):
                svc._dispatch(_raw_imu(ap, t0 + k / imu_hz), t0 + k / imu_hz)
            svc._request_streams()
            return svc.stats.stream_requests - n0, t0 + check_s

        t = WARM_T0_S + WARM_S + 0.02
        asked, t = check(50.0, t)  # the first check: every stream is asked for
        assert asked == len(cfg.streams)
        asked, t = check(50.0, t)  # RAW_IMU came at 50 Hz of 400 after it was asked: capped, said, not asked again
        assert svc.stream_caps_hz == {"RAW_IMU": pytest.approx(50.0)}
        out = svc.out.getvalue()
        assert out.count("RAW_IMU comes at 50 Hz of the 400 Hz asked for") == 1 and "SCHED_LOOP_RATE" in out
        assert asked == len(cfg.streams) - 1  # the others never came in this test: asked again
        asked, t = check(50.0, t)
        assert asked == len(cfg.streams) - 1 and svc.out.getvalue().count("RAW_IMU comes at") == 1
        asked, t = check(1.0, t)  # an autopilot reboot: its 1 Hz default, under half the cap: asked again
        assert asked == len(cfg.streams)
    finally:
        _close(svc)


def test_an_imu_too_slow_to_integrate_fuses_the_autopilots_attitude(
    design_deim12: dict[str, Path], tmp_path: Path
) -> None:
    """RAW_IMU at 10 Hz, as a 57600-baud radio carries it: the filter starts with held-sample noise and the
    autopilot's ATTITUDE fused (10 Hz); a heading the magnetometer alone would take seconds to find is the
    autopilot's within a few updates. At 50 Hz nothing of this is switched on."""
    from firmware_bridge.service import CompanionService
    from vdm_aero.nav.models import NavModels
    from vdm_aero.rotation import euler_from_quat

    streams = {"RAW_IMU": 10, "SCALED_PRESSURE": 10, "GPS_RAW_INT": 5, "ATTITUDE": 10}
    results = {}
    for imu_hz in (10.0, 50.0):
        cfg = _service_config(tmp_path, design_deim12, f"slow{imu_hz:g}", {"streams": dict(streams)})
        models = NavModels.load(cfg.design_data, cfg.deim_model, None, cfg.vehicle)
        ap = _Autopilot()
        svc = CompanionService(cfg, out=io.StringIO(), models=models)
        m = ap.tx
        try:
            svc._dispatch(ap(m.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                0, 0, 4)), WARM_T0_S - 0.01)  # fmt: skip
            yaw = math.radians(30.0)  # the autopilot's heading; the magnetometer below says north
            n = round(6.0 * imu_hz)
            for k in range(n + 1):
                t = WARM_T0_S + k / imu_hz
                svc._dispatch(_raw_imu(ap, t), t)
                if k % max(1, round(imu_hz / 10)) == 0:
                    svc._dispatch(ap(m.attitude_encode(round(t * 1e3), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)), t)
                    svc._dispatch(ap(m.scaled_pressure_encode(round(t * 1e3), 1000.0, 0.0, 2500)), t)
                if k % max(1, round(imu_hz / 5)) == 0 and t >= WARM_T0_S + 1.0:
                    svc._dispatch(ap(m.gps_raw_int_encode(round(t * 1e6), 3, 422830335, -713500307, 155600, 80,
                                                          120, 0, 0, 14)), t)  # fmt: skip
            f = svc.filter
            assert f is not None and f.initialised and f.x is not None
            results[imu_hz] = {
                "sigma": f.config.ap_attitude_sigma_rad,
                "points": f.config.imu_point_samples,
                "fused": f.health()["updates"].get("ap_attitude", 0),
                "yaw_err_deg": abs(math.degrees(euler_from_quat(f.x.q_nb)[2] - yaw)),
                "log": svc.out.getvalue(),
            }
            assert np.all(np.isfinite(f.x.q_nb))
        finally:
            _close(svc)
    slow, fast = results[10.0], results[50.0]
    assert slow["sigma"] is not None and slow["points"] and slow["fused"] >= 20, slow["fused"]
    assert "IMU at 10.0 Hz, too slow to integrate alone" in slow["log"] and "its ATTITUDE is fused" in slow["log"]
    assert slow["yaw_err_deg"] < 5.0, slow["yaw_err_deg"]
    assert fast["sigma"] is None and not fast["points"] and fast["fused"] == 0
    assert "too slow" not in fast["log"]
    assert fast["yaw_err_deg"] > 25.0  # on its own IMU and compass the filter keeps the compass's heading
