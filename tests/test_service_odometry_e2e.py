"""End to end, ArduPilot's ExternalNav route (issue 23): the service sends ODOMETRY in the frame of the
autopilot's EKF origin all flight and switches EKF3's source set on GNSS loss and back
(``outputs.solution: odometry``, ``outputs.source_switch``); the mock judges every ODOMETRY by ArduPilot's rules
(sim/sitl/extnav_judge.py) and fuses what EKF3 would. Survey seed 0, a 60 s outage, as the GPS_INPUT route's
end-to-end test flies it, in the product mode ``vdm`` (the shipped config's): its air-data sources all fused
and none excluded in a healthy flight."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vdm_aero.nav.filter import NavConfig
from vdm_aero_cli.service_sitl import ServiceRun, run_service_sitl, site_mag_field_ut

pytestmark = pytest.mark.slow

HOLD_S = 10.0  # outputs.source_switch.gnss_hold_s (the default)
CHI2_2DOF_95 = -2.0 * math.log(0.05)  # χ²'s 95 % quantile at 2 degrees of freedom (closed form for 2)


def test_the_autopilot_flies_the_outage_on_the_services_odometry(
    design_deim12: dict[str, Path], tmp_path: Path
) -> None:
    # the product mode (pitot, port air data, the DEIM force model, the air-data FDI, the wind relearnt) through
    # the service: the GPS_INPUT route's end-to-end tests fly vdm-deim, whose in-process benchmark they match
    # the autopilot as docs/service.md sets it up: VISO_QUAL_MIN 1, VISO_VEL_M_NSE at ArduPilot's default (the
    # service's own velocity σ there left EKF3 farther from the truth in 4 of 5 flights, docs/service.md)
    run = ServiceRun(design_deim12["data"], design_deim12["model"], None, mode="vdm", scenario="survey",
                     seed=0, outage_s=60.0, speed=4.0, solution="odometry",
                     source_switch=(("gnss_set", 1), ("extnav_set", 2)),
                     viso=(("QUAL_MIN", 1),))  # fmt: skip
    res = run_service_sitl(run, tmp_path / "odometry", mag_field_ned_ut=site_mag_field_ut(run))
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    a, b = res["outage"]
    mock, svc = res["mock"], res["service"]
    assert svc["handler_errors"] == {}
    assert svc["ekf_origin"] is not None and svc["odometry_without_origin"] <= 5  # the origin came at once
    # the switches, in the mock's own record: set 1 asked once at start (the service cannot know the autopilot's
    # set), ExternalNav within 2 s of the loss (GNSS_TIMEOUT_S 1 s + the next ODOMETRY), GNSS after the hold
    sets = [(s["t_s"], int(s["source_set"])) for s in mock["source_set_switches"]]
    assert [k for _, k in sets] == [1, 2, 1], sets
    assert a < sets[1][0] < a + 2.0 and b + HOLD_S - 1.0 < sets[2][0] < b + HOLD_S + 3.0, (sets, a, b)
    sw = svc["source_switch"]
    assert sw["accepted"] == sw["sent"] == 3 and sw["gave_up"] == 0 and sw["active"] == 1
    # ArduPilot's rules take the ODOMETRY of the outage (the source switched, frames, interval, quality, the
    # gate): ≥ 90 % of every ODOMETRY that came in it used (the second before the switch included)
    v = mock["odometry_outage_verdicts"]
    came = sum(v.values())
    assert v.get("used", 0) >= 0.9 * came and came >= 0.9 * 5.0 * (b - a), v
    # EKF3 follows ExternalNav: at the outage's end the mock's estimate is where FuseVelPosNED's weights put it, near
    # the service's last ODOMETRY position, not at its own dead reckoning. EKF3 weighs that position with posErr
    # clamped to 10 m (R_pos, extnav_judge.py) and the velocity with VISO_VEL_M_NSE, so where the service's position
    # moves by its own updates more than its velocity says, EKF3 trails it by up to about the innovation's σ. Near
    # is therefore inside the 95 % region of the innovation EKF3's gate takes, |Δ|² ≤ χ²₂(0.95)·(P_N + P_E + 2R)/2,
    # and nearer than its own dead reckoning. Measured (2026-12-02, one run each): with ArduPilot's default
    # VISO_VEL_M_NSE (0.1 m/s) the service's last ODOMETRY 34.9 m off, the mock 20.2 m, 14.9 m between them against
    # a bound of 24.5 m (15.2 and 15.4 m in two more runs); the dead reckoning 3.8 m off, 33.2 m from the service's.
    # At the service's own velocity σ (1.95 m/s) the mock weighs the position more: 11.1 m between them. (The
    # test's earlier bound, half the σ the service reported, took that σ for EKF3's R, and failed a run: 14.6 m
    # between the errors' sizes against 0.5 × 25.2 m. The service's own error moves by metres between real-time
    # runs: 30.8–34.8 m.)
    (fin,) = mock["odometry_outage_end"]
    odo = np.array([fin["odometry_n_m"], fin["odometry_e_m"]])
    gap = float(np.linalg.norm(np.array([fin["estimate_n_m"], fin["estimate_e_m"]]) - odo))
    ignored = float(np.linalg.norm(np.array([fin["free_n_m"], fin["free_e_m"]]) - odo))
    assert gap**2 <= CHI2_2DOF_95 * fin["innovation_var_m2"] / 2.0 and gap < ignored, (fin, gap, ignored)
    # the product mode fused each of its air-data sources all flight, and the FDI excluded none of them in
    # this healthy flight (a false alarm would show as an exclusion)
    health = svc["health"]
    up = health["updates"]
    assert health["mode"] == "vdm"
    assert min(up.get(k, 0) for k in ("pitot", "ports_airdata")) >= 1000, up
    # the force model at its own rate, a quarter of the port frames' (NavConfig.force_fusion_rate_hz)
    share = NavConfig.force_fusion_rate_hz / NavConfig.aiding_rate_hz
    assert up.get("aero_force", 0) >= 0.9 * share * up["ports_airdata"], up
    assert health["airdata_excluded"] == [] and not [k for k in up if k.startswith("fdi_") and "excluded" in k], up
