"""Measurement models with analytic Jacobians (each checked against :func:`~vdm_aero.nav.contracts.jacobian_fd`).

Air-relative velocity in the body frame, v_b = Ĉ_bn(v − w), carries the navigation value of air data:
with the wind held, an air-velocity measurement is a ground-velocity measurement. The wind is the mean
plus the gust state (w = w̄ + g); the derivatives chain through ∂v_b/∂v = Ĉ_bn, ∂v_b/∂w̄ = ∂v_b/∂g = −Ĉ_bn
and ∂v_b/∂δθ = [v_b×] (body-frame attitude error).

Units: SI; the magnetometer in µT (see :mod:`vdm_aero.nav.state`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.nav.ins import skew
from vdm_aero.nav.state import AERO_INDEX, AERO_SLOT, IDX, N_ERR, NavState
from vdm_aero.rotation import dcm_from_quat, euler_from_quat, quat_from_euler, quat_log, quat_multiply

__all__ = [
    "AirKinematics",
    "AutopilotAttitude",
    "BaroAltitude",
    "ClassicForce",
    "DerivativeModel",
    "ForceContext",
    "GnssPosition",
    "GnssVelocity",
    "InsWindowFix",
    "MagField",
    "MagHeading",
    "PitotAirspeed",
    "PortAirData",
    "PortForce",
    "SyntheticSideslip",
]

_E_Y = np.array([0.0, 1.0, 0.0])
_ALPHA, _BETA, _SCALE = AERO_SLOT["alpha_bias_rad"], AERO_SLOT["beta_bias_rad"], AERO_SLOT["airspeed_scale"]
_CX, _CY, _CZ = AERO_SLOT["cx_bias"], AERO_SLOT["cy_bias"], AERO_SLOT["cz_scale"]
_THRUST = AERO_SLOT["thrust_scale"]


class DerivativeModel(Protocol):
    """Body force coefficients (3,) and their gradient (3, 3) with respect to (V, α, β)."""

    def coeffs_and_gradient(
        self, speed_m_s: float, alpha_rad: float, beta_rad: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[F64Array, F64Array]: ...


@dataclass(frozen=True)
class AirKinematics:
    """v_b, airspeed V [m/s], α, β [rad] of a state and their gradients with respect to v_b."""

    c_bn: F64Array
    v_b: F64Array
    speed: float
    alpha: float
    beta: float
    d_speed: F64Array
    d_alpha: F64Array
    d_beta: F64Array

    @classmethod
    def of(cls, x: NavState) -> AirKinematics:
        c_bn = dcm_from_quat(x.q_nb).T
        v_b = c_bn @ (x.v_ned - x.wind_ned - x.gust_ned)
        u, v, w = v_b.tolist()
        speed = max(math.sqrt(u * u + v * v + w * w), 1e-3)
        uw2 = max(u * u + w * w, 1e-6)
        s = max(min(v / speed, 1.0), -1.0)
        d_speed = v_b / speed
        d_sinb = _E_Y / speed - v * v_b / speed**3
        return cls(
            c_bn=c_bn,
            v_b=v_b,
            speed=speed,
            alpha=math.atan2(w, u),
            beta=math.asin(s),
            d_speed=d_speed,
            d_alpha=np.array([-w, 0.0, u]) / uw2,
            d_beta=d_sinb / max(math.sqrt(1.0 - s * s), 1e-6),
        )

    def chain(self, d_vb: F64Array) -> F64Array:
        """Rows (m, 3) of ∂h/∂v_b → (m, N_ERR) columns for v, wind and attitude."""
        h = np.zeros((d_vb.shape[0], N_ERR))
        g = d_vb @ self.c_bn
        h[:, IDX["v"]] = g
        h[:, IDX["wind"]] = -g
        h[:, IDX["gust"]] = -g
        h[:, IDX["theta"]] = d_vb @ skew(self.v_b)
        return h


def _diag(sigmas: tuple[float, ...] | F64Array) -> F64Array:
    return np.diag(np.square(np.asarray(sigmas, dtype=np.float64)))


# --------------------------------------------------------------------------------------------- GNSS
@dataclass(frozen=True)
class GnssPosition:
    """GNSS position in the local NED frame [m] = p + the receiver's correlated error − v·lag (antenna at the
    IMU; a fix stamped t is valid at t − lag, the latency error the filter estimates); the σ here is its
    white part. ``timing_ned_m``: the position error of a fix whose arrival jitters by 1σ about the lag
    (σ_jitter·v [m]), a rank-one term along the track."""

    sigma_ne_m: float
    sigma_d_m: float
    timing_ned_m: F64Array | None = None
    name: str = "gnss_pos"

    def evaluate(self, x: NavState) -> F64Array:
        return x.p_ned + x.b_gnss_ned - x.v_ned * x.gnss_lag_s

    def jacobian(self, x: NavState) -> F64Array:
        h = np.zeros((3, N_ERR))
        h[:, IDX["p"]] = np.eye(3)
        h[:, IDX["gnss"]] = np.eye(3)
        h[:, IDX["v"]] = -x.gnss_lag_s * np.eye(3)
        h[:, IDX["lag"].start] = -x.v_ned
        return h

    def covariance(self) -> F64Array:
        r = _diag((self.sigma_ne_m, self.sigma_ne_m, self.sigma_d_m))
        return r if self.timing_ned_m is None else r + np.outer(self.timing_ned_m, self.timing_ned_m)


@dataclass(frozen=True)
class InsWindowFix:
    """Horizontal position N, E [m] and velocity N, E [m/s] of a free INS over the last few seconds, started
    from the filter's own pose (:meth:`~vdm_aero.nav.airdata_fdi.WindChangeDetector.ins_window`): what undoes
    a wind change that the air data fed into the velocity before it was seen. Its error holds that pose's, so
    the filter fuses it relative to a clone of it (:meth:`~vdm_aero.nav.engine.EkfEngine.update_relative`)."""

    sigma_p_m: float
    sigma_v_m_s: float
    name: str = "ins_window"

    def evaluate(self, x: NavState) -> F64Array:
        return np.array([x.p_ned[0], x.p_ned[1], x.v_ned[0], x.v_ned[1]])

    def jacobian(self, x: NavState) -> F64Array:
        h = np.zeros((4, N_ERR))
        h[0:2, IDX["p"]] = np.eye(3)[:2]
        h[2:4, IDX["v"]] = np.eye(3)[:2]
        return h

    def covariance(self) -> F64Array:
        return _diag((self.sigma_p_m, self.sigma_p_m, self.sigma_v_m_s, self.sigma_v_m_s))

    @staticmethod
    def clone_jacobian(tau_s: float) -> F64Array:
        """∂(innovation)/∂(the clone's error in p N, E, v N, E) for a free INS run ``tau_s`` [s] from it: its
        position is p + v·τ + ∫Δv, so the clone's velocity error moves it by τ times that error."""
        a = -np.eye(4)
        a[0, 2] = a[1, 3] = -tau_s
        return a


@dataclass(frozen=True)
class GnssVelocity:
    """GNSS velocity NED [m/s] = v − a·lag (``accel_ned_m_s2``: the acceleration over ground [m/s²] at the fix;
    the lag as :class:`GnssPosition`'s); ``horizontal_only``: N and E (MAVLink's GPS_RAW_INT has no vertical
    speed). ``timing_ned_m_s``: as :class:`GnssPosition`'s, σ_jitter·a [m/s] along the acceleration."""

    sigma_m_s: float
    horizontal_only: bool = False
    timing_ned_m_s: F64Array | None = None
    accel_ned_m_s2: F64Array | None = None
    name: str = "gnss_vel"

    @property
    def _n(self) -> int:
        return 2 if self.horizontal_only else 3

    def evaluate(self, x: NavState) -> F64Array:
        v = x.v_ned[: self._n]
        if self.accel_ned_m_s2 is None:
            return v.copy()
        return v - self.accel_ned_m_s2[: self._n] * x.gnss_lag_s

    def jacobian(self, x: NavState) -> F64Array:
        h = np.zeros((self._n, N_ERR))
        h[:, IDX["v"]] = np.eye(3)[: self._n]
        if self.accel_ned_m_s2 is not None:
            h[:, IDX["lag"].start] = -self.accel_ned_m_s2[: self._n]
        return h

    def covariance(self) -> F64Array:
        r = _diag((self.sigma_m_s,) * self._n)
        if self.timing_ned_m_s is None:
            return r
        t = self.timing_ned_m_s[: self._n]
        return r + np.outer(t, t)


# ------------------------------------------------------------------------------------ baro and mag
@dataclass(frozen=True)
class BaroAltitude:
    """ISA pressure altitude [m] = origin altitude − p_D + baro offset."""

    origin_alt_m: float
    sigma_m: float
    name: str = "baro"

    def evaluate(self, x: NavState) -> F64Array:
        return np.array([self.origin_alt_m - x.p_ned[2] + x.b_baro_m])

    def jacobian(self, x: NavState) -> F64Array:
        h = np.zeros((1, N_ERR))
        h[0, 2] = -1.0
        h[0, IDX["baro"]] = 1.0
        return h

    def covariance(self) -> F64Array:
        return _diag((self.sigma_m,))


@dataclass(frozen=True)
class MagField:
    """Body-frame magnetic field [µT] = Ĉ_bn·m_ned + hard-iron bias."""

    field_ned_ut: F64Array
    sigma_ut: float
    name: str = "mag"

    def evaluate(self, x: NavState) -> F64Array:
        return np.asarray(dcm_from_quat(x.q_nb).T @ self.field_ned_ut + x.b_mag_b_ut)

    def jacobian(self, x: NavState) -> F64Array:
        h = np.zeros((3, N_ERR))
        h[:, IDX["theta"]] = skew(dcm_from_quat(x.q_nb).T @ self.field_ned_ut)
        h[:, IDX["bm"]] = np.eye(3)
        return h

    def covariance(self) -> F64Array:
        return _diag((self.sigma_ut,) * 3)


@dataclass(frozen=True)
class MagHeading:
    """The heading (ZYX yaw) [rad] the compass gives once its field, less the hard-iron estimate, is levelled
    with the estimate's own roll and pitch: ArduPilot EKF3's yaw fusion (``fuseEulerYaw``, EK3_MAG_CAL 2) and
    PX4 EKF2's heading fusion. h(x) is the state's yaw, so the compass corrects the heading and, unlike the
    field's three axes (:class:`MagField`), never reads its own errors as tilt; the tilt's error enters the
    measured heading instead (:meth:`measured`), as in those filters. With q = q̂ ⊗ exp(δθ_b) the yaw moves by
    (sin φ·δθ_y + cos φ·δθ_z)/cos θ."""

    sigma_rad: float
    name: str = "mag"

    @staticmethod
    def measured(x: NavState, field_b_ut: F64Array, field_ned_ut: F64Array) -> float:
        """The compass heading [rad]: the field less x's hard iron, levelled by x's roll and pitch, against the
        Earth field's own direction (its declination), within ±π of x's yaw."""
        roll, pitch, yaw = euler_from_quat(x.q_nb)
        level = dcm_from_quat(quat_from_euler(roll, pitch, 0.0)) @ (np.asarray(field_b_ut) - x.b_mag_b_ut)
        psi = math.atan2(float(field_ned_ut[1]), float(field_ned_ut[0])) - math.atan2(level[1], level[0])
        return yaw + math.remainder(psi - yaw, 2.0 * math.pi)

    def evaluate(self, x: NavState) -> F64Array:
        return np.array([euler_from_quat(x.q_nb)[2]])

    def jacobian(self, x: NavState) -> F64Array:
        roll, pitch, _ = euler_from_quat(x.q_nb)
        h = np.zeros((1, N_ERR))
        h[0, IDX["theta"]] = np.array([0.0, math.sin(roll), math.cos(roll)]) / math.cos(pitch)
        return h

    def covariance(self) -> F64Array:
        return _diag((self.sigma_rad,))


@dataclass(frozen=True)
class AutopilotAttitude:
    """The autopilot's own attitude estimate as a measurement: h(x) = Log(q̂_nb⁻¹ ⊗ q_ap) [rad], the body-frame
    rotation from the state's attitude to the autopilot's, measured as zero. Used where the IMU is logged too
    slowly to integrate (a ground station's 4 Hz tlog): the autopilot integrated its IMU at full rate.

    With q = q̂ ⊗ exp(δθ), h = Log(exp(−δθ)·exp(r)) ≈ r − J_l⁻¹(r)·δθ, so ∂h/∂δθ = −J_l⁻¹(r) (the left Jacobian's
    inverse of SO(3), Sola et al. 2018, "A micro Lie theory", eq. 146)."""

    q_ap_nb: F64Array
    sigma_rad: F64Array  # roll, pitch, heading-axis 1σ of the autopilot's estimate
    name: str = "ap_attitude"

    def evaluate(self, x: NavState) -> F64Array:
        q = x.q_nb
        return quat_log(quat_multiply(np.array([q[0], -q[1], -q[2], -q[3]]), self.q_ap_nb))

    def jacobian(self, x: NavState) -> F64Array:
        r = self.evaluate(x)
        th = float(np.linalg.norm(r))
        k = skew(r)
        jl_inv = np.eye(3) - 0.5 * k
        if th > 1e-6:
            jl_inv += (1.0 / th**2 - (1.0 + math.cos(th)) / (2.0 * th * math.sin(th))) * (k @ k)
        h = np.zeros((3, N_ERR))
        h[:, IDX["theta"]] = -jl_inv
        return h

    def covariance(self) -> F64Array:
        return np.diag(np.square(self.sigma_rad))


# -------------------------------------------------------------------------------------------- air data
@dataclass(frozen=True)
class PitotAirspeed:
    """Pitot true airspeed [m/s] = speed scale × |v − w| (the pitot reads the air speed magnitude)."""

    sigma_m_s: float
    name: str = "pitot"

    def evaluate(self, x: NavState) -> F64Array:
        return np.array([x.aero[_SCALE] * float(np.linalg.norm(x.v_ned - x.air_motion_ned))])

    def jacobian(self, x: NavState) -> F64Array:
        k = AirKinematics.of(x)
        scale = x.aero[_SCALE]
        h = k.chain(scale * k.d_speed[None, :])
        h[0, AERO_INDEX["airspeed_scale"]] = k.speed
        return h

    def covariance(self) -> F64Array:
        return _diag((self.sigma_m_s,))


@dataclass(frozen=True)
class SyntheticSideslip:
    """EKF3's synthetic sideslip: sin β = 0 with a standard deviation (a fixed wing flies coordinated)."""

    sigma: float
    name: str = "sideslip"

    def evaluate(self, x: NavState) -> F64Array:
        k = AirKinematics.of(x)
        return np.array([k.v_b[1] / k.speed])

    def jacobian(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[1]

    def evaluate_with_jacobian(self, x: NavState) -> tuple[F64Array, F64Array]:
        k = AirKinematics.of(x)
        d = _E_Y / k.speed - k.v_b[1] * k.v_b / k.speed**3
        return np.array([k.v_b[1] / k.speed]), k.chain(d[None, :])

    def covariance(self) -> F64Array:
        return _diag((self.sigma,))


@dataclass(frozen=True)
class PortAirData:
    """(V [m/s], α, β [rad]) from the FADS solve on the ports, with the port installation offsets:
    h = (s·V, α + α_bias, β + β_bias). ``cov`` is the solve's covariance (inflated when ports are lost)."""

    cov: F64Array
    name: str = "ports_airdata"

    def evaluate(self, x: NavState) -> F64Array:
        return self._value(x, AirKinematics.of(x))

    def jacobian(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[1]

    def evaluate_with_jacobian(self, x: NavState) -> tuple[F64Array, F64Array]:
        k = AirKinematics.of(x)
        h = k.chain(np.vstack([x.aero[_SCALE] * k.d_speed, k.d_alpha, k.d_beta]))
        h[0, AERO_INDEX["airspeed_scale"]] = k.speed
        h[1, AERO_INDEX["alpha_bias_rad"]] = 1.0
        h[2, AERO_INDEX["beta_bias_rad"]] = 1.0
        return self._value(x, k), h

    @staticmethod
    def _value(x: NavState, k: AirKinematics) -> F64Array:
        a = x.aero
        return np.array([a[_SCALE] * k.speed, k.alpha + a[_ALPHA], k.beta + a[_BETA]])

    def covariance(self) -> F64Array:
        return self.cov


# ------------------------------------------------------------------------------- aerodynamic force
@dataclass(frozen=True)
class ForceContext:
    """What the specific-force prediction needs besides the state: air density [kg/m³], q̄S/m scale
    (S/m [m²/kg]), and the thrust T = k_T·(thrust_a + thrust_b·u) [N] with u the axial airspeed;
    ``accel_m_err``: the mode models the accelerometer's scale and cross-axis errors, so the prediction is
    what the accelerometer reads of the force, (I + δMa)·f + b_a (else f + b_a)."""

    rho_kg_m3: float
    area_per_mass_m2_kg: float
    mass_kg: float
    thrust_a_n: float
    thrust_b_n_s_m: float
    accel_m_err: bool = False


def _force_rows(
    x: NavState, k: AirKinematics, c: F64Array, ctx: ForceContext
) -> tuple[F64Array, F64Array, float, F64Array]:
    """(f (3,), ∂f/∂v_b through q̄ and thrust (3, 3), q̄S/m, thrust [N]) for body coefficients c (3,): the
    specific force, before the accelerometer reads it (:func:`_as_read`)."""
    a = x.aero
    qsm = 0.5 * ctx.rho_kg_m3 * k.speed**2 * ctx.area_per_mass_m2_kg
    u = float(k.v_b[0])
    thrust = a[_THRUST] * (ctx.thrust_a_n + ctx.thrust_b_n_s_m * u)
    cc = np.array([c[0] + a[_CX], c[1] + a[_CY], c[2] * a[_CZ]])
    h = qsm * cc
    h[0] += thrust / ctx.mass_kg
    dqsm = ctx.rho_kg_m3 * ctx.area_per_mass_m2_kg * k.v_b  # ∂(q̄S/m)/∂v_b
    d = np.outer(cc, dqsm)
    d[0, 0] += a[_THRUST] * ctx.thrust_b_n_s_m / ctx.mass_kg
    return h, d, qsm, np.array([thrust])


def _force_params(h: F64Array, x: NavState, qsm: float, c: F64Array, ctx: ForceContext, k: AirKinematics) -> None:
    h[0, AERO_INDEX["cx_bias"]] = qsm
    h[1, AERO_INDEX["cy_bias"]] = qsm
    h[2, AERO_INDEX["cz_scale"]] = qsm * c[2]
    h[0, AERO_INDEX["thrust_scale"]] = (ctx.thrust_a_n + ctx.thrust_b_n_s_m * float(k.v_b[0])) / ctx.mass_kg


_BA, _AM0 = IDX["ba"], IDX["am"].start
_I3 = np.eye(3)
_I3.flags.writeable = False


def _as_read(f: F64Array, h: F64Array, x: NavState, ctx: ForceContext) -> tuple[F64Array, F64Array]:
    """What the accelerometer reads of the specific force ``f`` whose Jacobian is ``h``: (I + δMa)·f + b_a, with
    its Jacobian (δMa·f = Fa·δma, Fa = I ⊗ fᵀ; δMa only where the mode models it)."""
    if ctx.accel_m_err:
        m = x.accel_m_err_b
        z = f + m @ f + x.b_accel_b
        h = h + m @ h
        for i in range(3):
            h[i, _AM0 + 2 * i : _AM0 + 2 * i + 2] = f[:2]
    else:
        z = f + x.b_accel_b
    h[:, _BA] = _I3
    return z, h


@dataclass(frozen=True)
class PortForce:
    """Specific force [m/s²] predicted from the ports' coefficients (DEIM, DEIM+NN): the coefficients come
    from the measured Cp and do not depend on the state; the state sets q̄ and the thrust."""

    coeffs_xyz: F64Array
    ctx: ForceContext
    sigma_m_s2: F64Array
    name: str = "aero_force"

    def evaluate(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[0]

    def jacobian(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[1]

    def evaluate_with_jacobian(self, x: NavState) -> tuple[F64Array, F64Array]:
        k = AirKinematics.of(x)
        f, d, qsm, _ = _force_rows(x, k, self.coeffs_xyz, self.ctx)
        h = k.chain(d)
        _force_params(h, x, qsm, self.coeffs_xyz, self.ctx, k)
        return _as_read(f, h, x, self.ctx)

    def covariance(self) -> F64Array:
        return _diag(self.sigma_m_s2)


@dataclass(frozen=True)
class ClassicForce:
    """Specific force [m/s²] from polynomial stability derivatives of the state's V, α, β, the gyro rates
    and the control deflections (the VDM literature's model; no ports)."""

    derivatives: DerivativeModel
    omega_b: F64Array
    controls_rad: F64Array
    ctx: ForceContext
    sigma_m_s2: F64Array
    name: str = "aero_force_classic"

    def _coeffs(self, k: AirKinematics) -> tuple[F64Array, F64Array]:
        return self.derivatives.coeffs_and_gradient(k.speed, k.alpha, k.beta, self.omega_b, self.controls_rad)

    def evaluate(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[0]

    def jacobian(self, x: NavState) -> F64Array:
        return self.evaluate_with_jacobian(x)[1]

    def evaluate_with_jacobian(self, x: NavState) -> tuple[F64Array, F64Array]:
        k = AirKinematics.of(x)
        c, grad = self._coeffs(k)  # grad (3, 3): ∂C/∂(V, α, β)
        f, d, qsm, _ = _force_rows(x, k, c, self.ctx)
        scale = np.array([1.0, 1.0, x.aero[_CZ]])
        d_c = grad @ np.vstack([k.d_speed, k.d_alpha, k.d_beta])  # ∂C/∂v_b
        h = k.chain(d + qsm * scale[:, None] * d_c)
        _force_params(h, x, qsm, c, self.ctx, k)
        return _as_read(f, h, x, self.ctx)

    def covariance(self) -> F64Array:
        return _diag(self.sigma_m_s2)
