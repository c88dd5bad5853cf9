"""End to end, PX4's external-vision route (issue 23): the service, configured ``autopilot: px4`` and
``outputs.solution: odometry`` at 10 Hz, sends ODOMETRY in its own NED frame all flight; the mock plays PX4 v1.16
(``sitl --firmware px4``: its HEARTBEAT, HIGHRES_IMU with the airspeed sensor, EKF2's rules in
sim/sitl/ekf2_judge.py) and fuses what EKF2 would. Survey seed 0, a 60 s outage, as the ArduPilot routes' end-to-end
tests fly it."""

from __future__ import annotations

from pathlib import Path

import pytest

from vdm_aero_cli.service_sitl import ServiceRun, run_service_sitl, score_service, site_mag_field_ut

pytestmark = pytest.mark.slow

SOLUTION_HZ = 10.0


def test_px4_flies_the_outage_on_the_services_external_vision(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    run = ServiceRun(design_deim12["data"], design_deim12["model"], None, mode="vdm-deim", scenario="survey",
                     seed=0, outage_s=60.0, speed=4.0, autopilot="px4", solution="odometry",
                     solution_hz=SOLUTION_HZ)  # fmt: skip
    res = run_service_sitl(run, tmp_path / "px4", mag_field_ned_ut=site_mag_field_ut(run))
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    a, b = res["outage"]
    mock, svc = res["mock"], res["service"]
    assert svc["handler_errors"] == {}
    # the service read PX4's streams: its HIGHRES_IMU (no RAW_IMU, no SCALED_PRESSURE asked for) and the ports
    assert svc["port_frames"]["complete"] > 1000, svc["port_frames"]
    assert mock["received"].get("GPS_INPUT", 0) == 0 and mock["received"].get("GLOBAL_POSITION_SENSOR", 0) == 0
    # ODOMETRY all flight (EKF2 learns our frame's offset while it fuses GNSS), not only in the outage
    v_all, v = mock["ekf2_verdicts"]["ODOMETRY"], mock["ekf2_outage_verdicts"]["ODOMETRY"]
    assert v_all.get("GNSS healthy: not judged", 0) >= 0.9 * SOLUTION_HZ * (a - 60.0), v_all  # initialised by 60 s
    # EKF2's rules take the outage's ODOMETRY: one reset onto EV − bias at the loss, then fused, ≥ 90 % of them
    came = sum(v.values())
    # how well the two processes kept real time, for a failure's reader: EKF2 stops external vision after 400 ms
    # of world time without it, which at ×4 is 100 ms of a starved service's wall time
    pace = (f"world {mock['world_time_s']:.0f} s in {mock['wall_time_s']:.0f} s of wall time (×{run.speed:g} asked), "
            f"the mock's largest lag {mock['max_lag_s']:.2f} s, the service's latency {svc['latency_ms']}")  # fmt: skip
    assert came >= 0.85 * SOLUTION_HZ * (b - a) and v.get("used", 0) >= 0.9 * came, (v, pace)
    assert sum(n for k, n in v.items() if k.startswith("reset")) == 1, (v, pace)
    # EKF2 follows the service through the outage: the bias it learnt took the service's error at the loss away, so
    # the mock ends no further off than the service itself (plus its noise), and far from a frame offset
    end = mock["outage_end_errors"][0]
    own = score_service(res)["final_error_m"]
    assert end["with_service_m"] <= own + 3.0, (end, own)
