"""The navigation state: nominal values, the error-state layout, ⊕ and ⊖.

Nominal state (SI, NED navigation frame about a local origin, FRD body frame):

* ``p_ned`` position [m], ``v_ned`` velocity [m/s], ``q_nb`` attitude (scalar-first quaternion body → NED);
* ``b_gyro_b`` gyro bias [rad/s], ``b_accel_b`` accelerometer bias [m/s²];
* ``wind_ned`` mean wind (air motion over ground) [m/s]: a slow random walk, held during outages;
* ``gust_ned`` the turbulent part of the wind [m/s]: a first-order Gauss–Markov process (Dryden-like
  intensity and correlation time), estimated with and without GNSS (air data against the INS);
* ``b_mag_b_ut`` magnetometer hard-iron bias [µT] (µT, not T, so that the covariance stays well scaled);
* ``b_baro_m`` barometric altitude offset [m] (weather and the ISA deviation);
* ``b_gnss_ned`` the GNSS receiver's slowly varying position error [m] (a Gauss–Markov process: without
  it the filter would average correlated fixes as if independent and claim decimetres);
* ``aero`` the model correction parameters :data:`AERO_PARAMS`;
* ``wind_gradient_ne_per_s`` the mean wind's change with height, d(w_N, w_E)/dh [1/s]: the boundary layer's
  wind grows and veers with height, so a wind learnt at one height is wrong at another; the wind state is the
  wind at the aircraft's height and follows the gradient as it climbs or descends (learnt while GNSS aids and
  the aircraft changes height, held through an outage);
* ``gnss_lag_s`` the error of the receiver latency the fixes' times of validity assume [s] (true − assumed):
  a fix stamped t is valid at t − lag, so it reads p − v·lag and v − a·lag. The lag is fixed for a receiver
  and its link within tens of ms; treated as white noise per fix, it is averaged as if it were independent,
  and through every turn its a·lag pulls roll, pitch and heading (the harsh world's ``gnss-latency``);
* ``gyro_m_err_b`` the gyro's scale-factor and cross-axis errors δM (3 × 3, dimensionless): the gyro reads
  (I + δM)·ω + b. MEMS data sheets allow ±0.5–1 % of scale and ±1–1.25 % of cross-axis sensitivity, and no
  autopilot calibrates them; in a 20°/s turn they turn the tilt by 0.2–0.3°/s, which the bias states cannot
  hold because it follows the rate, not the time (learnt while GNSS aids through the turns).
* ``accel_m_err_b`` the accelerometer's scale-factor and cross-axis errors δMa (3 × 3, dimensionless): it reads
  (I + δMa)·f + b. MEMS data sheets allow ±0.5 % of scale and ±1–2 % of cross-axis sensitivity; the autopilot's
  level trim cancels the part that tilts gravity at rest, and the rotation that cancels x's sensitivity to z adds
  as much to z's sensitivity to x, so to along-track accelerations the accelerometer looks pitched while to
  gravity it looks level (docs/navigation.md, "Where the tilt offset comes from, measured"). A bias cannot hold
  an error that follows the specific force (learnt while GNSS aids through speed changes and turns). Only its
  first two columns (the sensitivity to f_x and f_y) are states: in flight f_z stays near −g, so the third column
  is the accelerometer bias again, and with it as states the bias wandered along their common direction in an
  outage (docs/navigation.md); the level trim has already taken its cross terms δMa[0, 2] and δMa[1, 2] away.

The error state δx (:data:`N_ERR` components) is additive for every block except attitude, whose error
is a body-frame rotation vector: q = q̂ ⊗ exp(δθ), the ⊕ of :mod:`vdm_aero.rotation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.rotation import quat_exp, quat_log, quat_multiply

__all__ = ["AERO_INDEX", "AERO_PARAMS", "AERO_PRIOR", "AERO_SLOT", "IDX", "N_ERR", "NavState"]

AERO_PARAMS: Final = (
    "alpha_bias_rad", "beta_bias_rad", "airspeed_scale", "cx_bias", "cy_bias", "cz_scale", "thrust_scale",
)  # fmt: skip
"""Model correction parameters: the port air data's angle offsets (installation, rigging), the air-data
speed scale (pitot or ports, whichever the mode fuses), a drag-coefficient bias, a side-force-coefficient
bias and a lift-coefficient scale (the as-built aircraft's skin friction, rigging and port installation),
and the installed thrust factor."""
AERO_PRIOR: Final = {
    # (nominal, 1σ): what a user knows before flight. Angles: ports within ±2° of their design location's
    # flow angle; speed scale: pitot/port calibration within 5 %; CX bias: drag build-up within 0.01 (about
    # a third of the design CD0); CZ scale: lift slope within 10 %; thrust: propeller data sheet ±20 %.
    "alpha_bias_rad": (0.0, 0.035),
    "beta_bias_rad": (0.0, 0.035),
    "airspeed_scale": (1.0, 0.05),
    "cx_bias": (0.0, 0.01),
    # CY bias: what a port installation's β offset (the prior above) makes of a side-force slope of
    # ~0.3 /rad, or a fin rigged a degree off; the DEIM coefficients read β from the same ports
    "cy_bias": (0.0, 0.01),
    "cz_scale": (1.0, 0.1),
    "thrust_scale": (1.0, 0.2),
}


def _block(start: int, n: int) -> slice:
    return slice(start, start + n)


IDX: Final = {
    "p": _block(0, 3),
    "v": _block(3, 3),
    "theta": _block(6, 3),
    "bg": _block(9, 3),
    "ba": _block(12, 3),
    "wind": _block(15, 3),
    "bm": _block(18, 3),
    "baro": _block(21, 1),
    "gnss": _block(22, 3),
    "gust": _block(25, 3),
    "aero": _block(28, len(AERO_PARAMS)),
    "lag": _block(28 + len(AERO_PARAMS), 1),
    "wg": _block(29 + len(AERO_PARAMS), 2),
    "gm": _block(31 + len(AERO_PARAMS), 9),
    "am": _block(40 + len(AERO_PARAMS), 6),
}
"""Error-state slices by block name (``gm``: δM row by row, δM[i, j] at ``gm.start + 3 i + j``; ``am``: δMa's
first two columns row by row, δMa[i, j] at ``am.start + 2 i + j``)."""
N_ERR: Final = 46 + len(AERO_PARAMS)
AERO_INDEX: Final = {name: 28 + i for i, name in enumerate(AERO_PARAMS)}
"""Error-state index of each aero parameter."""
AERO_SLOT: Final = {name: i for i, name in enumerate(AERO_PARAMS)}
"""Position of each aero parameter in :attr:`NavState.aero`."""


@dataclass
class NavState:
    """The nominal navigation state (see the module docstring). Mutable: the filter updates it in place."""

    p_ned: F64Array
    v_ned: F64Array
    q_nb: F64Array
    b_gyro_b: F64Array = field(default_factory=lambda: np.zeros(3))
    b_accel_b: F64Array = field(default_factory=lambda: np.zeros(3))
    wind_ned: F64Array = field(default_factory=lambda: np.zeros(3))
    b_mag_b_ut: F64Array = field(default_factory=lambda: np.zeros(3))
    b_baro_m: float = 0.0
    b_gnss_ned: F64Array = field(default_factory=lambda: np.zeros(3))
    gust_ned: F64Array = field(default_factory=lambda: np.zeros(3))
    aero: F64Array = field(default_factory=lambda: np.array([AERO_PRIOR[k][0] for k in AERO_PARAMS]))
    gnss_lag_s: float = 0.0
    wind_gradient_ne_per_s: F64Array = field(default_factory=lambda: np.zeros(2))
    gyro_m_err_b: F64Array = field(default_factory=lambda: np.zeros((3, 3)))
    accel_m_err_b: F64Array = field(default_factory=lambda: np.zeros((3, 3)))

    @property
    def air_motion_ned(self) -> F64Array:
        """Total wind (mean + gust) [m/s]."""
        return self.wind_ned + self.gust_ned

    def copy(self) -> NavState:
        return NavState(
            self.p_ned.copy(), self.v_ned.copy(), self.q_nb.copy(), self.b_gyro_b.copy(), self.b_accel_b.copy(),
            self.wind_ned.copy(), self.b_mag_b_ut.copy(), self.b_baro_m, self.b_gnss_ned.copy(),
            self.gust_ned.copy(), self.aero.copy(), self.gnss_lag_s, self.wind_gradient_ne_per_s.copy(),
            self.gyro_m_err_b.copy(), self.accel_m_err_b.copy(),
        )  # fmt: skip

    def plus(self, dx: F64Array) -> NavState:
        """x ⊕ δx (a new state)."""
        out = self.copy()
        out.plus_inplace(dx)
        return out

    def plus_inplace(self, dx: F64Array) -> None:
        """x ← x ⊕ δx."""
        self.p_ned += dx[IDX["p"]]
        self.v_ned += dx[IDX["v"]]
        q = quat_multiply(self.q_nb, quat_exp(dx[IDX["theta"]]))
        self.q_nb = q / math.sqrt(float(q @ q))
        self.b_gyro_b += dx[IDX["bg"]]
        self.b_accel_b += dx[IDX["ba"]]
        self.wind_ned += dx[IDX["wind"]]
        self.b_mag_b_ut += dx[IDX["bm"]]
        self.b_baro_m += float(dx[IDX["baro"]][0])
        self.b_gnss_ned += dx[IDX["gnss"]]
        self.gust_ned += dx[IDX["gust"]]
        self.aero += dx[IDX["aero"]]
        self.gnss_lag_s += float(dx[IDX["lag"]][0])
        self.wind_gradient_ne_per_s += dx[IDX["wg"]]
        self.gyro_m_err_b += dx[IDX["gm"]].reshape(3, 3)
        self.accel_m_err_b[:, :2] += dx[IDX["am"]].reshape(3, 2)

    def minus(self, other: NavState) -> F64Array:
        """x ⊖ y: the error state δx with y ⊕ δx = x."""
        conj = other.q_nb * np.array([1.0, -1.0, -1.0, -1.0])
        return np.concatenate(
            [
                self.p_ned - other.p_ned,
                self.v_ned - other.v_ned,
                quat_log(quat_multiply(conj, self.q_nb)),
                self.b_gyro_b - other.b_gyro_b,
                self.b_accel_b - other.b_accel_b,
                self.wind_ned - other.wind_ned,
                self.b_mag_b_ut - other.b_mag_b_ut,
                [self.b_baro_m - other.b_baro_m],
                self.b_gnss_ned - other.b_gnss_ned,
                self.gust_ned - other.gust_ned,
                self.aero - other.aero,
                [self.gnss_lag_s - other.gnss_lag_s],
                self.wind_gradient_ne_per_s - other.wind_gradient_ne_per_s,
                (self.gyro_m_err_b - other.gyro_m_err_b).ravel(),
                (self.accel_m_err_b - other.accel_m_err_b)[:, :2].ravel(),
            ]
        )
