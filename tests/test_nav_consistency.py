"""Filter consistency (navlie style): seeded Monte-Carlo NEES of the INS + GNSS + baro + magnetometer
filter on a coordinated turn whose sensor errors follow the filter's own stated models; also with the pitot
and synthetic sideslip (the air-data mode), with the ports' air data and the DEIM force model through a GNSS
outage (the force-model mode), and with the GNSS fixes arriving 100 ms after their time of validity (delayed
fusion). This checks the implementation (Φ, Q, the updates, ⊕, the delayed-fusion buffer):
a filter that is inconsistent even on its own models is wrong. How consistent it is on the as-built world is
what ``vdm-aero bench nav-drift`` measures."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import scipy.stats

from tests.aiding import linear_start
from vdm_aero.atmosphere import G0_M_S2, density_kg_m3
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.filter import NavConfig, NavFilter
from vdm_aero.nav.ports_frontend import PortFrame
from vdm_aero.nav.state import AERO_PARAMS, AERO_PRIOR, AERO_SLOT, N_ERR, NavState
from vdm_aero.rotation import dcm_from_quat, quat_from_euler, quat_log, quat_multiply
from vdm_aero.vehicle import load_vehicle

RUNS = 8
# The force-model mode's outage: over 8 runs its in-band share hung on the draws, on main's code as on the code with
# the side-force bias (2026-12-01: 100 / 97 / 94 / 70 % and 88 / 100 / 81 / 94 % on four seeds), so 8 runs could not
# tell a change from the seed. 32 runs average the draws, and their band is narrower (7.6–10.5 against 6.3–12.2).
RUNS_OUTAGE = 32
DURATION_S = 60.0
RATE_HZ = 50.0
V_M_S, TURN_RAD_S = 18.0, 0.1
MAG_NED_UT = np.array([20.1, -4.9, 46.5])


def _truth(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Level coordinated turn: position, velocity, attitude, body rates, specific force (body)."""
    psi = TURN_RAD_S * t
    bank = math.atan(V_M_S * TURN_RAD_S / G0_M_S2)
    r = V_M_S / TURN_RAD_S
    p = np.array([r * math.sin(psi), r * (1.0 - math.cos(psi)), -100.0])
    v = V_M_S * np.array([math.cos(psi), math.sin(psi), 0.0])
    a = V_M_S * TURN_RAD_S * np.array([-math.sin(psi), math.cos(psi), 0.0])
    q = np.array(quat_from_euler(bank, 0.0, psi))
    c_bn = dcm_from_quat(q).T
    omega_b = c_bn @ np.array([0.0, 0.0, TURN_RAD_S])
    f_b = c_bn @ (a - np.array([0.0, 0.0, G0_M_S2]))
    return p, v, q, omega_b, f_b


GNSS_DELAY_S = 0.1
PORT_AIRDATA_SIGMA = np.array([0.3, 0.01, 0.01])  # the FADS solve's stated σ: V [m/s], α, β [rad]


def _port_frame(t: float, rho: float, f_b: np.ndarray, aero: np.ndarray, cfg: NavConfig,
                rng: np.random.Generator) -> PortFrame:  # fmt: skip
    """A port frame whose errors follow the filter's own models: air data (V, α, β) = (s·V, α_b, β_b) (the turn
    is flown at α = β = 0 in still air) with the solve's σ plus the filter's floor, and DEIM coefficients
    whose specific force, by the filter's force model with the world's corrections, is the truth's with the
    force σ (the accelerometer's own bias and noise are in the IMU reading it is compared with)."""
    s = AERO_SLOT
    cov = np.diag(np.square(PORT_AIRDATA_SIGMA) + np.square(cfg.airdata_sigma_floor))
    airdata = np.array([aero[s["airspeed_scale"]] * V_M_S, aero[s["alpha_bias_rad"]], aero[s["beta_bias_rad"]]])
    airdata += rng.multivariate_normal(np.zeros(3), cov)
    vehicle = cfg.vehicle
    qsm = 0.5 * rho * V_M_S**2 * vehicle.reference.area_m2 / vehicle.mass.mass_kg
    a, b = vehicle.propulsion.thrust_regressors(0.0, 1.0, rho)  # throttle 0: no SERVO_OUTPUT_RAW is sent
    thrust_m_s2 = aero[s["thrust_scale"]] * (float(a) + float(b) * V_M_S) / vehicle.mass.mass_kg
    f = f_b + rng.normal(0.0, cfg.force_sigma_m_s2)
    c = np.zeros(6)
    c[0] = (f[0] - thrust_m_s2) / qsm - aero[s["cx_bias"]]
    c[1] = f[1] / qsm - aero[s["cy_bias"]]
    c[2] = f[2] / (qsm * aero[s["cz_scale"]])
    return PortFrame(t, np.ones(12, dtype=bool), airdata, np.diag(np.square(PORT_AIRDATA_SIGMA)), 0.5 * rho * V_M_S**2,
                     {"deim": c})  # fmt: skip


def _run(rng: np.random.Generator, mode: str = "ins", delayed: bool = False, sky: float = 1.0,
         reported: bool = True, wrong_lag: bool = False, gnss_until_s: float = math.inf, **cfg_kw: Any
         ) -> list[float]:  # fmt: skip
    """One run's NEES; ``sky``: the GNSS errors (white and Gauss–Markov) this many times the filter's nominal
    ones, the receiver's accuracy reported with them (``reported``) or not; ``wrong_lag``: the fixes' stamps
    off their time of validity by a lag error drawn from the filter's prior, and a jitter from its own σ."""
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=0.0, mag_field_ned_ut=MAG_NED_UT, **cfg_kw)
    lag_s = rng.normal(0.0, NavConfig.gnss_latency_sigma_s) if wrong_lag else 0.0
    f = NavFilter(mode, cfg)
    p, v, q, _, f_b = _truth(0.0)
    f.initialise(0.0, p, v, f_b, None)
    assert f.engine is not None
    sig0 = linear_start(f)
    truth0 = NavState(p, v, q)
    b_g = rng.normal(0.0, sig0[9:12])
    b_a = rng.normal(0.0, sig0[12:15])
    b_m = rng.normal(0.0, sig0[18:21])
    noise = cfg.noise
    g_gnss = sky * rng.normal(0.0, [noise.gnss_sigma_ne_m, noise.gnss_sigma_ne_m, noise.gnss_sigma_d_m])
    white = np.array([cfg.gnss_pos_sigma_ne_m, cfg.gnss_pos_sigma_ne_m, cfg.gnss_pos_sigma_d_m])
    acc = (math.hypot(white[0], noise.gnss_sigma_ne_m) * sky, math.hypot(white[2], noise.gnss_sigma_d_m) * sky)
    dx0 = np.zeros(N_ERR)
    dx0[:9] = rng.normal(0.0, sig0[:9])  # the filter starts off the truth in its pose (the other states at nominal)
    f.x = truth0.plus(dx0)
    f.x.b_baro_m = 0.0
    dt = 1.0 / RATE_HZ
    nees = []
    decay = math.exp(-dt / noise.gnss_tau_s)
    pending: list[tuple[float, np.ndarray, np.ndarray]] = []
    rng_pitot = np.random.default_rng(rng.bit_generator.random_raw() if mode != "ins" else 0)  # ins: the same draws
    # the port modes: the world's aero corrections drawn from the filter's prior (the filter starts at nominal)
    rng_ports = np.random.default_rng(rng.bit_generator.random_raw() if f.uses_ports else 0)
    aero_true = np.array([rng_ports.normal(*AERO_PRIOR[name]) for name in AERO_PARAMS])
    for k in range(1, round(DURATION_S * RATE_HZ) + 1):
        t = k * dt
        _, _, _, w_b, fb = _truth(t - 0.5 * dt)  # mid-step rates: the increment of a smooth motion
        inc = ImuIncrement(
            (w_b + b_g) * dt + rng.normal(0.0, noise.gyro_rad_s * math.sqrt(dt), 3),
            (fb + b_a) * dt + rng.normal(0.0, noise.accel_m_s2 * math.sqrt(dt), 3),
            dt,
        )
        f.imu(t, inc)
        g_gnss = decay * g_gnss + sky * math.sqrt(1 - decay**2) * rng.normal(
            0.0, [noise.gnss_sigma_ne_m, noise.gnss_sigma_ne_m, noise.gnss_sigma_d_m]
        )
        p, v, q, _, f_now = _truth(t)
        if k % 10 == 0 and t <= gnss_until_s:  # 5 Hz GNSS, valid now; delayed: it arrives GNSS_DELAY_S later
            pending.append((t, p + g_gnss + sky * rng.normal(0.0, white), v + rng.normal(0.0, 0.2, 3)))
        while pending and pending[0][0] <= t + 1e-9 - (GNSS_DELAY_S if delayed else 0.0):
            tv, pg, vg = pending.pop(0)
            jitter_s = rng.normal(0.0, NavConfig.gnss_jitter_sigma_s) if wrong_lag else 0.0
            f.gnss(tv + lag_s + jitter_s, t, pg, vg, *(acc if reported else (math.nan, math.nan)))
        if k % 5 == 0:
            p_static = float(101325.0 * (1.0 - 2.25577e-5 * (-p[2])) ** 5.25588)
            f.baro(t, float(101325.0 * (1.0 - 2.25577e-5 * (-p[2] + rng.normal(0.0, 1.0))) ** 5.25588))
            # the pitot's TAS error is white with the filter's σ (no wind, no gust: a coordinated turn in still air)
            rho = float(density_kg_m3(p_static, f.inputs.temperature_k))
            f.pitot(t, 0.5 * rho * (V_M_S + rng_pitot.normal(0.0, cfg.pitot_sigma_m_s)) ** 2)
            f.mag(t, dcm_from_quat(q).T @ MAG_NED_UT + b_m + rng.normal(0.0, 1.5, 3))
            if f.uses_ports:
                f.ports(_port_frame(t, rho, f_now, aero_true, cfg, rng_ports))
        if k % 5 == 0 and t > 10.0:
            x = f.x
            dth = quat_log(quat_multiply(q * np.array([1.0, -1.0, -1.0, -1.0]), x.q_nb))
            e = np.concatenate([x.p_ned - p, x.v_ned - v, dth])
            nees.append(float(e @ np.linalg.solve(f.P[:9, :9], e)))
    return nees


# the force-model mode through a GNSS outage for its last 30 s: aided, GNSS holds the pose whatever the port
# models say (a force Jacobian with its sign flipped stays in band aided, and leaves it in the outage: 44 %)
@pytest.mark.parametrize(("mode", "delayed", "wrong_lag", "gnss_until_s"),
                         [("ins", False, False, math.inf), ("ins", True, False, math.inf),
                          ("ins", True, True, math.inf), ("airspeed-dr", False, False, math.inf),
                          ("airspeed-dr", True, False, math.inf), ("vdm-deim", False, False, 30.0),
                          ("vdm-deim", True, False, 30.0)])  # fmt: skip
def test_monte_carlo_nees_inside_the_chi2_band(mode: str, delayed: bool, wrong_lag: bool, gnss_until_s: float) -> None:
    # wrong_lag: the receiver's latency error, a state, drawn from its prior (the stamps off by it)
    rng = np.random.default_rng(20261124)
    n = RUNS_OUTAGE if math.isfinite(gnss_until_s) else RUNS
    runs = np.array([_run(rng, mode, delayed, wrong_lag=wrong_lag, gnss_until_s=gnss_until_s) for _ in range(n)])
    mean = runs.mean(axis=0)
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 9 * n) / n
    inside = float(np.mean((mean >= lo) & (mean <= hi)))
    assert inside >= 0.9, f"average NEES inside [{lo:.2f}, {hi:.2f}] for {100 * inside:.0f} % of epochs"


@pytest.mark.parametrize("reported", [True, False])
def test_a_worse_sky_the_receiver_reports_keeps_the_nees_in_band(reported: bool) -> None:
    """GNSS errors 2.5× the nominal model's (multipath, a poor constellation), as the receiver's hAcc/vAcc say:
    with the reports the filter's GNSS error model follows (EKF3's FuseVelPosNED takes the reported accuracy)
    and stays consistent; without them the same flights are not."""
    rng = np.random.default_rng(20261127)
    runs = np.array([_run(rng, "ins", sky=2.5, reported=reported) for _ in range(RUNS)])
    mean = runs.mean(axis=0)
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 9 * RUNS) / RUNS
    inside = float(np.mean((mean >= lo) & (mean <= hi)))
    if reported:
        assert inside >= 0.9, f"average NEES inside [{lo:.2f}, {hi:.2f}] for {100 * inside:.0f} % of epochs"
    else:
        assert inside < 0.5, f"unreported, the average NEES is still inside for {100 * inside:.0f} % of epochs"


def test_a_reported_accuracy_better_than_nominal_changes_nothing_and_a_worse_one_widens_the_fix() -> None:
    """EKF3 floors the reported hAcc at its own noise parameter: a receiver claiming better than the filter's
    nominal model changes nothing; a worse one widens the position the fix leaves."""
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=0.0, mag_field_ned_ut=MAG_NED_UT)
    p, v, _, _, f_b = _truth(0.0)
    out = {}
    for name, acc in (("none", (math.nan, math.nan)), ("better", (0.5, 0.8)), ("worse", (5.0, 8.0))):
        f = NavFilter("ins", cfg)
        f.initialise(0.0, p, v, f_b, None)
        f.imu(0.02, ImuIncrement(np.zeros(3), f_b * 0.02, 0.02))
        f.gnss(0.02, 0.02, p + np.array([1.0, -1.0, 0.5]), v, *acc)
        out[name] = (f.x.p_ned.copy(), f.P[:3, :3].copy())
    np.testing.assert_array_equal(out["better"][0], out["none"][0])
    np.testing.assert_array_equal(out["better"][1], out["none"][1])
    assert np.all(np.diag(out["worse"][1]) > 1.5 * np.diag(out["none"][1]))
