"""The mock autopilot's own attitude estimate (sim.flight.ap_attitude) against the solutions of its error equation."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sim.flight.ap_attitude import AP_CORRECTION_TAU_S, AP_GYRO_OFFSET_TAU_S, AutopilotAttitude
from sim.flight.contract import ImuSample, VehicleTruth
from vdm_aero.rotation import quat_exp, quat_log, quat_multiply

DT_S = 0.0025  # a 400 Hz IMU


def _truth(t_s: float, q_nb: np.ndarray, omega_b: np.ndarray) -> VehicleTruth:
    z = np.zeros(3)
    return VehicleTruth(t_s=t_s, lat_deg=0.0, lon_deg=0.0, alt_m=0.0, pos_ned_m=z, v_ned_m_s=z, q_nb=q_nb,
                        omega_b_rad_s=omega_b, specific_force_b_m_s2=z, airspeed_m_s=20.0, alpha_rad=0.0,
                        beta_rad=0.0, wind_ned_m_s=z, throttle=0.5)  # fmt: skip


def _fly(offset_b: Callable[[float], np.ndarray], omega_b: np.ndarray, seconds: float
         ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Turn at ``omega_b`` with a gyro reading ω + offset(t): the times and the estimate's error Log(q⁻¹ ⊗ q_ap)."""
    ap = AutopilotAttitude()
    q = np.array([1.0, 0.0, 0.0, 0.0])
    ts, errs = [], []
    for k in range(round(seconds / DT_S)):
        t = k * DT_S
        truth = _truth(t, q, omega_b)
        ap.step(ImuSample(t, np.zeros(3), omega_b + offset_b(t), 25.0), truth)
        err = quat_multiply(q * np.array([1.0, -1.0, -1.0, -1.0]), ap.q_nb(truth))
        ts.append(t)
        errs.append(quat_log(err))
        q = quat_multiply(q, quat_exp(omega_b * DT_S))
    return np.array(ts), np.array(errs)


def test_an_offset_measured_at_boot_leaves_no_error_in_a_turn() -> None:
    offset = np.array([0.008, -0.004, 0.006])  # the ICM-42688-P's ±0.5°/s turn-on offset, calibrated at boot
    _, e = _fly(lambda _t: offset, np.array([0.05, 0.02, 0.3]), 60.0)
    assert np.max(np.abs(e)) < 1e-9


def test_an_offset_that_moves_after_boot_tilts_it_as_the_error_equation_says() -> None:
    """A step δ of the offset after boot (the board warming up), flying straight: the estimate's offset follows
    δ with τ_b, and ė = δ·e^(−t/τ_b) − e/τ_c has e(t) = δ·τ_c·τ_b/(τ_b − τ_c)·(e^(−t/τ_b) − e^(−t/τ_c)): at
    most ~δ·τ_c (0.9° for 0.1°/s), back towards zero over minutes."""
    delta = math.radians(0.1)
    t, e = _fly(lambda s: np.array([0.0, delta, 0.0]) if s > 0.0 else np.zeros(3), np.zeros(3), 120.0)
    tc, tb = AP_CORRECTION_TAU_S, AP_GYRO_OFFSET_TAU_S
    analytic = delta * tc * tb / (tb - tc) * (np.exp(-t / tb) - np.exp(-t / tc))
    np.testing.assert_allclose(e[:, 1], analytic, atol=0.02 * float(analytic.max()))
    assert np.max(np.abs(e[:, [0, 2]])) < 1e-9
    assert 0.6 * delta * tc < float(analytic.max()) < delta * tc
