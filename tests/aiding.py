"""The aiding sensors of the tests' synthetic 50-Hz flights, drawn from the filter's own noise model (GNSS: its
Gauss–Markov error plus white noise at 5 Hz; baro and compass at 10 Hz), and the 9-dof NEES those tests score."""

from __future__ import annotations

import math

import numpy as np
import scipy.stats

from vdm_aero.nav.filter import NavConfig, NavFilter
from vdm_aero.rotation import quat_log, quat_multiply


class AidingSensors:
    """GNSS, baro and compass for a flight stepped at ``dt_s``: one call of :meth:`step` per IMU step."""

    def __init__(self, cfg: NavConfig, rng: np.random.Generator, dt_s: float) -> None:
        n = cfg.noise
        self._rng = rng
        self._sig = np.array([n.gnss_sigma_ne_m, n.gnss_sigma_ne_m, n.gnss_sigma_d_m])
        self._gnss_err = rng.normal(0.0, self._sig)
        self._decay = math.exp(-dt_s / n.gnss_tau_s)
        self._white = np.array([cfg.gnss_pos_sigma_ne_m, cfg.gnss_pos_sigma_ne_m, cfg.gnss_pos_sigma_d_m])

    def step(self, f: NavFilter, k: int, t_s: float, p_ned: np.ndarray, v_ned: np.ndarray, mag_b_ut: np.ndarray
             ) -> bool:  # fmt: skip
        """Step ``k``: the GNSS error moves; a fix every 10th step, the baro and the compass (``mag_b_ut``, the
        noise-free reading [µT]) every 5th. True on the compass's steps."""
        rng = self._rng
        self._gnss_err = self._decay * self._gnss_err + math.sqrt(1 - self._decay**2) * rng.normal(0.0, self._sig)
        if k % 10 == 0:
            f.gnss(t_s, t_s, p_ned + self._gnss_err + rng.normal(0.0, self._white), v_ned + rng.normal(0.0, 0.2, 3))
        if k % 5:
            return False
        f.baro(t_s, float(101325.0 * (1.0 - 2.25577e-5 * (-p_ned[2] + rng.normal(0.0, 1.0))) ** 5.25588))
        f.mag(t_s, mag_b_ut + rng.normal(0.0, 1.5, 3))
        return True


def nees_9dof(f: NavFilter, p_ned: np.ndarray, v_ned: np.ndarray, q_nb: np.ndarray) -> tuple[float, np.ndarray]:
    """The filter's position, velocity and attitude NEES against the truth, and its attitude error [rad]."""
    x = f.x
    assert x is not None
    dth = quat_log(quat_multiply(q_nb * np.array([1.0, -1.0, -1.0, -1.0]), x.q_nb))
    e = np.concatenate([x.p_ned - p_ned, x.v_ned - v_ned, dth])
    return float(e @ np.linalg.solve(f.P[:9, :9], e)), dth


def in_band(runs: np.ndarray) -> float:
    """The fraction of epochs whose NEES averaged over the runs (rows) is inside χ²(9·runs)/runs's 95 % band."""
    n = len(runs)
    lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], 9 * n) / n
    mean = runs.mean(axis=0)
    return float(np.mean((mean >= lo) & (mean <= hi)))


def linear_start(f: NavFilter) -> np.ndarray:
    """Narrow a just-initialised filter's prior to start inside the linear region (an EKF started 15° off in
    heading is not expected to be consistent until the heading converges): 2° of attitude and 0.1 °/s of gyro
    bias. Returns the prior's σ, from which the tests draw their worlds."""
    assert f.engine is not None
    sig0 = np.sqrt(np.diag(f.engine.P))
    sig0[6:9] = math.radians(2.0)
    sig0[9:12] = math.radians(0.1)
    f.engine.P = np.diag(sig0**2)
    return sig0
