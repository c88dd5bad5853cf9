"""The process model: strapdown INS mechanisation driven by IMU increments (the IMU is the input).

Why the IMU drives the process instead of being an observation of a dynamic-model process (Khaghani &
Skaloud): the IMU is the one sensor that is always there, at hundreds of hertz, with a well-known error
model; the aerodynamic model is uncertain (the as-built aircraft is not the design) and enters as a
measurement whose noise states that uncertainty. A dynamic-model process would put that model error into
the process noise of every step and needs thrust, moments and inertia exactly, and the calibrated moment
coefficients are the least accurate part of the model (docs/navigation.md).

Flat, non-rotating Earth about the local origin: over an outage of minutes and kilometres the neglected
terms (Earth rate 7.3e-5 rad/s, transport rate, gravity change) are far below the MEMS errors; the gyro
bias state absorbs the Earth rate.

Error-state dynamics (body-frame attitude error, q = q̂ ⊗ exp(δθ)):
  δṗ = δv,  δv̇ = −Ĉ[f̂×]δθ − Ĉδb_a − Ĉn_a,  δθ̇ = −[ω̂×]δθ − (I − δM̂)δb_g − U·δm − n_g,
  with the gyro read as (I + δM)·ω + b and corrected as ω̂ = (I − δM̂)(ω_m − b̂) (first order in the 1 % of δM),
  δm = δM row by row and U·δm = δM·(ω_m − b̂) (U = I ⊗ (ω_m − b̂)ᵀ); δM a random walk (where a mode leaves it
  out of the dynamics, δM̂ = 0 and the terms vanish),
  biases, wind, magnetometer and baro offsets and aero parameters: random walks; the GNSS position error:
  first-order Gauss–Markov; the horizontal wind follows its gradient with height G as the aircraft climbs or
  descends, ẇ_NE = −G·v_D, so δẇ_NE = −G·δv_D − v_D·δG (the nominal v_D at mid-step, as the attitude).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vdm_aero._typing import F64Array, IntArray
from vdm_aero.atmosphere import G0_M_S2
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.state import IDX, N_ERR, NavState
from vdm_aero.rotation import dcm_from_quat, quat_exp, quat_multiply

__all__ = ["InsProcess", "ProcessNoise", "skew"]


def skew(v: F64Array) -> F64Array:
    """[v×]: skew(v) @ u = v × u."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class ProcessNoise:
    """Continuous-time noise densities (per √s) of the error-state random walks.

    accel: ICM-42688-P 70 µg/√Hz ×2 for motor vibration, raised to 0.01 m/s²/√s for coning/sculling of the
    50 Hz increments and the unmodelled lever arm; gyro: 2.8 mdps/√Hz raised likewise; bias random walks:
    the datasheet temperature drift over minutes; wind: the drift of the mean wind (turbulence itself is
    measurement noise of the air data); aero parameters: slow (they change with configuration, not with time).
    """

    accel_m_s2: float = 0.01
    gyro_rad_s: float = 8.0e-4
    accel_bias_m_s3: float = 2.0e-4
    gyro_bias_rad_s2: float = 5.0e-6
    wind_horizontal_m_s2: float = 0.05
    wind_vertical_m_s2: float = 0.01
    mag_bias_ut_s: float = 0.005
    baro_m_s: float = 0.02
    aero_per_s: tuple[float, ...] = (1e-5, 1e-5, 1e-5, 2e-5, 2e-5, 1e-4, 1e-4)
    # single-frequency GNSS: metre-level errors (ionosphere, multipath) correlated over minutes; a user
    # knows the receiver's accuracy class, not these numbers exactly (u-blox M9: 1.5 m CEP)
    gnss_sigma_ne_m: float = 1.5
    gnss_sigma_d_m: float = 2.5
    gnss_tau_s: float = 100.0
    # the receiver's latency error (a state): it moves only with the receiver's load and its link, by a few ms
    # over a flight
    gnss_lag_s_per_sqrt_s: float = 1.0e-4
    # the wind's gradient with height: the profile changes with the terrain and the time of day, over kilometres
    # and tens of minutes: ~10 % of its prior (NavConfig.wind_gradient_sigma_per_s) in 10 minutes
    wind_gradient_per_s_sqrt_s: float = 4.0e-5
    # the gyro's scale and cross-axis errors move with the board's temperature (a few 0.01 %/K in MEMS data
    # sheets' sensitivity change over temperature): 0.1 % in 10 minutes
    gyro_m_err_per_sqrt_s: float = 4.0e-5
    # the accelerometer's: its sensitivity moves with temperature less than the gyro's (MEMS data sheets:
    # ±0.005–0.02 %/K), 0.03 % in 10 minutes
    accel_m_err_per_sqrt_s: float = 1.0e-5
    # turbulence: MIL-F-8785C low-altitude light-to-moderate intensities (σ_u,v ≈ 1.5, σ_w ≈ 1 m/s at
    # 100 m) and correlation times L/V (L_u ≈ 250 m at 18 m/s; L_w = h ≈ 100 m)
    gust_sigma_m_s: tuple[float, float, float] = (1.5, 1.5, 1.0)
    gust_tau_s: tuple[float, float, float] = (14.0, 14.0, 6.0)


_I3 = np.eye(3)
_I3.flags.writeable = False
_I2 = np.eye(2)
_I2.flags.writeable = False
_W = slice(IDX["wind"].start, IDX["wind"].start + 2)  # the horizontal wind's rows
_WG = IDX["wg"]
_GM = IDX["gm"]
_AM = IDX["am"]
_POSE_ROWS = np.arange(9)  # p, v, θ: the rows of Φ that couple states (transition)
_POSE_WIND_ROWS = np.r_[_POSE_ROWS, np.arange(_W.start, _W.stop)]  # ... and the horizontal wind's, with its gradient


def _times_u(a: F64Array, u: F64Array) -> F64Array:
    """A·(I₃ ⊗ uᵀ) for a 3 × 3 ``a`` and a k-vector ``u``: the 3 × 3k matrix whose columns kj … kj + k − 1 are
    a[:, j]·uᵀ, written as one broadcast product (``np.kron`` costs ~20 µs of Python per call, twice a step: 8 % of
    ``vdm``'s step; docs/performance.md)."""
    return (a[:, :, None] * u[None, None, :]).reshape(3, -1)


class InsProcess:
    """Strapdown mechanisation (:class:`~vdm_aero.nav.contracts.ProcessModel`)."""

    def __init__(self, noise: ProcessNoise | None = None) -> None:
        self.noise_densities = noise or ProcessNoise()
        n = self.noise_densities
        q = np.zeros(N_ERR)
        q[IDX["v"]] = n.accel_m_s2**2
        q[IDX["theta"]] = n.gyro_rad_s**2
        q[IDX["ba"]] = n.accel_bias_m_s3**2
        q[IDX["bg"]] = n.gyro_bias_rad_s2**2
        q[IDX["wind"]] = (n.wind_horizontal_m_s2**2, n.wind_horizontal_m_s2**2, n.wind_vertical_m_s2**2)
        q[IDX["bm"]] = n.mag_bias_ut_s**2
        q[IDX["baro"]] = n.baro_m_s**2
        q[IDX["aero"]] = np.square(n.aero_per_s)
        q[IDX["lag"]] = n.gnss_lag_s_per_sqrt_s**2
        q[IDX["wg"]] = n.wind_gradient_per_s_sqrt_s**2
        q[IDX["gm"]] = n.gyro_m_err_per_sqrt_s**2
        q[_AM] = n.accel_m_err_per_sqrt_s**2
        q[IDX["gnss"]] = 2.0 / n.gnss_tau_s * np.square([n.gnss_sigma_ne_m, n.gnss_sigma_ne_m, n.gnss_sigma_d_m])
        self._gust_rate = 1.0 / np.asarray(n.gust_tau_s)
        self.wind_height_rate_scale = 0.0  # > 0: wind noise × (1 + scale·|ḣ|), EKF2/3's WIND_PSCALE
        self.wind_change_m_s2 = 0.0  # > 0: a wind change under way, its horizontal noise density [m/s/√s] added
        self.wind_gradient = True  # the wind follows its gradient with height (freeze_wind_gradient: not)
        self.gyro_m_err = True  # the gyro's scale and cross-axis errors correct it (freeze_gyro_m_err: not)
        self.accel_m_err = True  # the same for the accelerometer (freeze_accel_m_err: not)
        self._qc = q
        self.set_gust_sigma(np.asarray(n.gust_sigma_m_s, dtype=np.float64))
        self._g = np.array([0.0, 0.0, G0_M_S2])
        # the diagonal Gauss–Markov decay rates of the GNSS error and the gust (the rest of F is filled from the
        # state each step, in the blocks :meth:`transition` names)
        rates = np.zeros(N_ERR)
        rates[IDX["gnss"]] = 1.0 / self.noise_densities.gnss_tau_s
        rates[IDX["gust"]] = self._gust_rate
        self._decay_rates = rates
        self._phi_dt = math.nan  # Δt of the cached state-independent part of Φ
        self._phi_const = np.eye(N_ERR)

    def set_gnss_scale(self, scale_ne: float, scale_d: float) -> None:
        """The GNSS error's steady-state σ as this multiple of :class:`ProcessNoise`'s (horizontal, vertical):
        the receiver's reported accuracy against its nominal one (:meth:`NavFilter.gnss`)."""
        n = self.noise_densities
        sig = np.array([n.gnss_sigma_ne_m * scale_ne, n.gnss_sigma_ne_m * scale_ne, n.gnss_sigma_d_m * scale_d])
        self._qc[IDX["gnss"]] = 2.0 / n.gnss_tau_s * np.square(sig)

    def set_gust_sigma(self, sigma_m_s: F64Array) -> None:
        """The gust's steady-state standard deviation (N, E, D) [m/s]: q = 2σ²/τ keeps the Gauss–Markov
        variance at σ² (the filter sets it from the turbulence it measures while aided)."""
        self.gust_sigma_m_s = np.array(sigma_m_s, dtype=np.float64)
        self._qc[IDX["gust"]] = 2.0 * self._gust_rate * np.square(self.gust_sigma_m_s)

    def freeze_wind_gradient(self) -> None:
        """A mode that does not model the wind's gradient: the states leave the dynamics (no noise, no coupling
        to the wind), so they stay at their prior, uncorrelated with everything, and the wind is as before."""
        self._qc[IDX["wg"]] = 0.0
        self.wind_gradient = False

    def freeze_gyro_m_err(self) -> None:
        """A mode that does not model the gyro's scale and cross-axis errors (the autopilots' EKFs do not): the
        states leave the dynamics and stay at their prior, uncorrelated with everything."""
        self._qc[_GM] = 0.0
        self.gyro_m_err = False

    def freeze_accel_m_err(self) -> None:
        """A mode that does not model the accelerometer's scale and cross-axis errors: as
        :meth:`freeze_gyro_m_err`."""
        self._qc[_AM] = 0.0
        self.accel_m_err = False

    def _force_b(self, x: NavState, u: ImuIncrement) -> tuple[F64Array, F64Array]:
        """The specific force [m/s²] the increment gives, less the bias and less the scale and cross-axis errors
        where the mode models them; and what it read less the bias alone (δMa's regressor in Φ)."""
        a_b = u.dvel_b / u.dt_s - x.b_accel_b
        return (np.asarray(a_b - x.accel_m_err_b @ a_b) if self.accel_m_err else a_b), a_b

    def _rate_b(self, x: NavState, u: ImuIncrement) -> F64Array:
        """The body rate [rad/s] the increment gives: less the bias, and less the scale and cross-axis errors
        where the mode models them."""
        w_b = u.dtheta_b / u.dt_s - x.b_gyro_b
        if self.gyro_m_err:
            w_b = w_b - x.gyro_m_err_b @ w_b
        return np.asarray(w_b)

    @property
    def coupled_rows(self) -> IntArray:
        """The rows of :meth:`transition`'s Φ with entries off its diagonal: the pose's (p, v, θ), and the
        horizontal wind's while it follows its gradient. Every other row is diagonal (1, or a Gauss–Markov decay),
        which :meth:`EkfEngine.predict <vdm_aero.nav.engine.EkfEngine.predict>` exploits;
        ``tests/test_nav_models.py`` holds Φ to it."""
        return _POSE_WIND_ROWS if self.wind_gradient else _POSE_ROWS

    def propagate(self, x: NavState, u: ImuIncrement) -> NavState:
        out = x.copy()
        self.propagate_inplace(out, u)
        return out

    def propagate_inplace(self, x: NavState, u: ImuIncrement) -> None:
        dt = u.dt_s
        x.b_gnss_ned *= math.exp(-dt / self.noise_densities.gnss_tau_s)
        x.gust_ned *= np.exp(-dt * self._gust_rate)
        c0 = dcm_from_quat(x.q_nb)
        dth = self._rate_b(x, u) * dt
        q = quat_multiply(x.q_nb, quat_exp(dth))
        x.q_nb = q / math.sqrt(float(q @ q))
        c1 = dcm_from_quat(x.q_nb)
        dv_n = 0.5 * (c0 + c1) @ (self._force_b(x, u)[0] * dt) + self._g * dt
        v0 = x.v_ned.copy()
        x.v_ned = v0 + dv_n
        x.p_ned = x.p_ned + 0.5 * (v0 + x.v_ned) * dt
        if self.wind_gradient:
            x.wind_ned[:2] -= x.wind_gradient_ne_per_s * (0.5 * float(v0[2] + x.v_ned[2]) * dt)  # dw = G·dh

    def transition(self, x: NavState, u: ImuIncrement) -> F64Array:
        """Φ ≈ I + F·Δt + ½(F·Δt)², with the attitude at mid-step (as the mechanisation rotates Δv).

        F's non-zero blocks (p, v, θ, b_g, b_a at 0, 3, 6, 9, 12): F_pv = I, F_vθ = −Ĉ[f×], F_vba = −Ĉ(I − δM̂a),
        F_vma = −Ĉ·Ua (the accelerometer's scale and cross-axis errors), F_θθ = −[ω×], F_θbg = −(I − δM̂),
        F_θm = −U (the gyro's), and the GNSS error's and the gust's decay on the diagonal. F² is written out
        block by block (F_pv·F_v•, F_vθ·F_θ•, F_θθ·F_θ•) instead of a dense N_ERR × N_ERR product: the profile's
        largest single cost of a step (docs/performance.md)."""
        dt = u.dt_s
        f_b, a_b = self._force_b(x, u)
        w_b = self._rate_b(x, u)
        c = dcm_from_quat(quat_multiply(x.q_nb, quat_exp(0.5 * w_b * dt)))
        if dt != self._phi_dt:  # the diagonal: 1 − aΔt + ½(aΔt)², constant while Δt is
            a = self._decay_rates * dt
            self._phi_const = np.diag(1.0 - a + 0.5 * a * a)
            self._phi_dt = dt
        cf = c @ skew(f_b)
        wx = skew(w_b)
        h = 0.5 * dt * dt
        ca = c @ (_I3 - x.accel_m_err_b) if self.accel_m_err else c  # ∂f/∂b_a = −(I − δM̂a)
        phi = self._phi_const.copy()
        phi[0:3, 3:6] = _I3 * dt
        phi[0:3, 6:9] = -h * cf
        phi[0:3, 12:15] = -h * ca
        phi[3:6, 6:9] = -dt * cf + h * (cf @ wx)
        phi[3:6, 9:12] = h * cf
        phi[3:6, 12:15] = -dt * ca
        if self.accel_m_err:
            cu = _times_u(c, a_b[:2])  # Ĉ·Ua: δMa·f̃ = Ua·δma (two columns)
            phi[0:3, _AM] = -h * cu
            phi[3:6, _AM] = -dt * cu
        phi[6:9, 6:9] = _I3 - dt * wx + h * (wx @ wx)
        phi[6:9, 9:12] = -dt * _I3 + h * wx
        if self.gyro_m_err:
            a = _I3 - x.gyro_m_err_b
            w_u = u.dtheta_b / dt - x.b_gyro_b  # U = I₃ ⊗ uᵀ: δM·u = U·δm
            th = -dt * _I3 + h * wx
            phi[3:6, 9:12] = h * (cf @ a)
            phi[6:9, 9:12] = th @ a
            phi[3:6, _GM] = h * _times_u(cf, w_u)
            phi[6:9, _GM] = _times_u(th, w_u)
        if not self.wind_gradient:
            return phi
        # the wind at the aircraft's height: ẇ_NE = −G·v_D, with v_D at mid-step (the rows' F² terms through δv_D)
        g_ne = x.wind_gradient_ne_per_s
        vd_mid = float(x.v_ned[2]) + 0.5 * dt * (float(c[2] @ f_b) + G0_M_S2)
        phi[_W, _WG] = -vd_mid * dt * _I2
        phi[_W, 5] = -dt * g_ne
        phi[_W, 6:9] = h * np.outer(g_ne, cf[2])
        phi[_W, 12:15] = h * np.outer(g_ne, ca[2])
        if self.accel_m_err:
            phi[_W, _AM] = h * np.outer(g_ne, cu[2])
        return phi

    def noise(self, x: NavState, u: ImuIncrement) -> F64Array:
        """Q_d = G·Q_c·Gᵀ·Δt (the velocity noise rotated to NED; its covariance is isotropic); the wind's
        grows with the height rate when :attr:`wind_height_rate_scale` is set (a climb or descent crosses
        the wind gradient: EKF2/3 scale the wind's process noise the same way), and the horizontal wind's by
        :attr:`wind_change_m_s2` while a wind change is under way."""
        if self.wind_height_rate_scale <= 0.0 and self.wind_change_m_s2 <= 0.0:
            return np.diag(self._qc * u.dt_s)
        q = self._qc.copy()
        if self.wind_height_rate_scale > 0.0:
            q[IDX["wind"]] *= (1.0 + self.wind_height_rate_scale * abs(float(x.v_ned[2]))) ** 2
        q[_W] += self.wind_change_m_s2**2
        return np.diag(q * u.dt_s)
