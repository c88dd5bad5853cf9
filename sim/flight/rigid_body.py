"""6-DOF rigid-body dynamics of the aircraft: quaternion attitude, RK4, forces from aerodynamics,
propeller and gravity.

State (13 floats, a tuple): position NED from home [m], velocity NED over ground [m/s], attitude
quaternion body → NED (scalar first), body rates p, q, r [rad/s]. Flat, non-rotating Earth with the
constant standard gravity g0 along NED down (a 10-minute flight at 18 m/s: Coriolis ≈ 3 mm/s², far
below the sensors' noise). Equations (body FRD about the CG, which is the aerodynamic moment reference):

    ṗ_ned = v_ned,      v̇_ned = R(q)·f_b + g·e_D,      q̇ = ½ q ⊗ (0, ω),
    I·ω̇ = M_b − ω × (I·ω),      f_b = (F_aero + F_prop)/m   (the specific force an accelerometer reads).

Inputs held over a step (zero-order hold at the physics rate): wind NED (steady + turbulence), the
four actuator positions, the angle-of-attack rate α̇ used by the aerodynamics (see :class:`StepInputs`)
and the air density. The air-relative velocity is ``v_b = Rᵀ(v_ned − wind_ned)``, V = |v_b|,
α = atan2(w, u), β = asin(v/V) (the :class:`sim.airframe.vlm.FlightStates` convention).

Everything in the right-hand side is plain Python floats: at 400 Hz × 4 RK4 stages for ten minutes the
function runs ~10⁶ times, where numpy's per-call overhead on 3-vectors would cost more than the arithmetic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np

from sim.airframe.geometry import AirframeGeometry
from sim.flight.aero import QUADRATIC_TERMS, LinearizedAero
from sim.flight.environment import G0_M_S2
from sim.flight.propulsion import PropulsionSpec
from vdm_aero._typing import F64Array
from vdm_aero.dataset import Reference

__all__ = [
    "N_STATE",
    "AircraftDynamics",
    "MassProperties",
    "StepInputs",
]

N_STATE: Final = 13
_HOT_LOOP_TERMS: Final = ((1, 1), (2, 2), (3, 3), (7, 7), (3, 7))  # α², β², p̂², δa², p̂·δa (indices into z)
State = tuple[float, ...]


@dataclass(frozen=True)
class MassProperties:
    """Mass [kg] and inertia tensor about the CG in body axes [kg·m²] (Ixy = Iyz = 0: a symmetric aircraft)."""

    mass_kg: float
    inertia_kg_m2: F64Array

    def __post_init__(self) -> None:
        i = np.asarray(self.inertia_kg_m2, dtype=np.float64)
        if i.shape != (3, 3) or not np.allclose(i, i.T):
            raise ValueError("inertia_kg_m2 must be a symmetric (3, 3) tensor")
        if abs(i[0, 1]) > 1e-12 * abs(i[0, 0]) or abs(i[1, 2]) > 1e-12 * abs(i[1, 1]):
            raise ValueError("inertia_kg_m2: Ixy and Iyz must be 0 (the aircraft is left-right symmetric)")
        if not self.mass_kg > 0.0 or np.any(np.linalg.eigvalsh(i) <= 0.0):
            raise ValueError("mass and principal inertias must be > 0")

    @classmethod
    def from_geometry(cls, geometry: AirframeGeometry) -> MassProperties:
        """The airframe's mass properties (:mod:`sim.airframe.geometry`: components, equipment, battery)."""
        return cls(mass_kg=float(geometry.mass_kg), inertia_kg_m2=np.array(geometry.inertia_kg_m2, dtype=np.float64))


class StepInputs(NamedTuple):
    """Inputs held constant over one physics step."""

    wind_n: float
    wind_e: float
    wind_d: float
    aileron: float
    elevator: float
    throttle: float
    rudder: float
    alpha_dot: float  # [rad/s] filtered, from the previous steps (see FlightWorld)
    rho: float  # [kg/m³]
    # as-built unsteady aerodynamics (sim.flight.asbuilt.UnsteadyLag; 0 for the quasi-steady design):
    alpha_lag: float = 0.0  # [rad] circulation-lag deficit: the aerodynamics see α − alpha_lag
    sep_deficit: float = 0.0  # [rad] separation lag: the α² (separation onset) term sees a further lag
    # the harsh world's Earth (sim.flight.world_effects): gravity's difference from g0 and the Coriolis and
    # transport-rate accelerations, NED [m/s²], held over the step (0 on the flat, non-rotating Earth)
    earth_n: float = 0.0
    earth_e: float = 0.0
    earth_d: float = 0.0


class Aux(NamedTuple):
    """Derived quantities at a state: specific force (body) [m/s²], airspeed [m/s], α, β [rad], thrust [N]."""

    f_x: float
    f_y: float
    f_z: float
    airspeed: float
    alpha: float
    beta: float
    thrust: float


class AircraftDynamics:
    """The aircraft's equations of motion with the aerodynamics of a :class:`LinearizedAero`."""

    def __init__(
        self,
        mass: MassProperties,
        reference: Reference,
        propulsion: PropulsionSpec,
        aero: LinearizedAero,
        gravity_m_s2: float = G0_M_S2,
    ) -> None:
        self.mass = mass
        self.reference = reference
        self.propulsion = propulsion
        self.aero = aero
        self.gravity_m_s2 = gravity_m_s2
        if QUADRATIC_TERMS != _HOT_LOOP_TERMS:
            raise ValueError(f"the hot loop spells out {_HOT_LOOP_TERMS}, the Taylor model has {QUADRATIC_TERMS}")
        i = mass.inertia_kg_m2
        inv = np.linalg.inv(i)
        self._inertia = tuple(
            float(v) for v in (i[0, 0], i[1, 1], i[2, 2], i[0, 2], inv[0, 0], inv[1, 1], inv[2, 2], inv[0, 2])
        )
        _, yp, zp = propulsion.thrust_point_b
        # slipstream (as-built): thrust coefficient T_c = T/(q̄·A_disk) scales the aero's slip rows
        self._inv_disk_m2 = 4.0 / (math.pi * propulsion.propeller.diameter_m**2)
        self._slip = aero.has_slipstream
        self._const = (
            float(reference.area_m2),
            float(reference.span_m),
            float(reference.chord_m),
            float(mass.mass_kg),
            float(gravity_m_s2),
            float(propulsion.max_rev_s),
            *propulsion.constants(),
            float(zp),
            float(yp),
            float(propulsion.spin),
        )

    def derivative(self, y: State, u: StepInputs) -> tuple[State, Aux]:
        """State derivative and the derived quantities at state ``y`` under inputs ``u``."""
        dy, aux = self._rhs(y, u)
        return dy, Aux(*aux)

    def _rhs(self, y: State, u: StepInputs) -> tuple[State, tuple[float, ...]]:
        # hot path (see the module docstring): locals only, plain tuples
        _, _, _, vn, ve, vd, q0, q1, q2, q3, p, q, r = y
        wind_n, wind_e, wind_d, d_ail, d_ele, thr, d_rud, alpha_dot, rho, alpha_lag, sep_deficit, en, ee, ed = u
        s_area, s_span, s_chord, mass, g, nmax, kt0, kt1, kq0, kq1, zp, yp, spin = self._const
        ixx, iyy, izz, ixz, jxx, jyy, jzz, jxz = self._inertia
        # body → NED rotation (vdm_aero.rotation.dcm_from_quat spelt out in floats; tests compare the two)
        q00, q11, q22, q33 = q0 * q0, q1 * q1, q2 * q2, q3 * q3
        q01, q02, q03, q12, q13, q23 = q0 * q1, q0 * q2, q0 * q3, q1 * q2, q1 * q3, q2 * q3
        r11, r12, r13 = q00 + q11 - q22 - q33, 2.0 * (q12 - q03), 2.0 * (q13 + q02)
        r21, r22, r23 = 2.0 * (q12 + q03), q00 - q11 + q22 - q33, 2.0 * (q23 - q01)
        r31, r32, r33 = 2.0 * (q13 - q02), 2.0 * (q23 + q01), q00 - q11 - q22 + q33
        an, ae, ad = vn - wind_n, ve - wind_e, vd - wind_d
        ub = r11 * an + r21 * ae + r31 * ad
        vb = r12 * an + r22 * ae + r32 * ad
        wb = r13 * an + r23 * ae + r33 * ad
        v_air = math.sqrt(ub * ub + vb * vb + wb * wb)
        alpha = math.atan2(wb, ub)
        beta = math.asin(vb / v_air)
        # aerodynamic coefficients from the local Taylor model: features [1, Δz, Δα², Δβ², Δp̂², Δδa², Δp̂·Δδa]
        # (z with reduced rates, see sim.flight.aero.QUADRATIC_TERMS)
        aero = self.aero
        z0 = aero.z0
        da, db = alpha - alpha_lag - z0[1], beta - z0[2]
        daf = da - sep_deficit
        inv_v = 1.0 / v_air
        dph = p * inv_v - z0[3]
        dail = d_ail - z0[7]
        feat = (
            1.0,
            v_air - z0[0],
            da,
            db,
            dph,
            q * inv_v - z0[4],
            r * inv_v - z0[5],
            alpha_dot * inv_v - z0[6],
            dail,
            d_ele - z0[8],
            d_rud - z0[9],
            daf * daf,
            db * db,
            dph * dph,
            dail * dail,
            dph * dail,
        )
        qbar = 0.5 * rho * v_air * v_air
        qs = qbar * s_area
        # propeller along body x at the hub (thrust moment r × F), reaction torque about x
        n = nmax * thr
        thrust = rho * (kt0 * n * n - kt1 * n * ub)
        torque = rho * (kq0 * n * n - kq1 * n * ub)
        if self._slip:
            # windmilling lowers the slipstream's dynamic pressure; momentum theory fails past −½ (wake stalls)
            tc = max(thrust * self._inv_disk_m2 / qbar, -0.5)
            cx, cy, cz, cl, cm, cn, sx, sy, sz, sl, sm, sn = (aero.force_rows @ feat).tolist()
            cx, cy, cz = cx + tc * sx, cy + tc * sy, cz + tc * sz
            cl, cm, cn = cl + tc * sl, cm + tc * sm, cn + tc * sn
        else:
            cx, cy, cz, cl, cm, cn = (aero.force_rows @ feat).tolist()
        mx = qs * s_span * cl - spin * torque
        my = qs * s_chord * cm + zp * thrust
        mz = qs * s_span * cn - yp * thrust
        sfx, sfy, sfz = (qs * cx + thrust) / mass, qs * cy / mass, qs * cz / mass
        # Euler's equations with the Ixz product (Ixy = Iyz = 0)
        hx = ixx * p + ixz * r
        hy = iyy * q
        hz = ixz * p + izz * r
        tx = mx - (q * hz - r * hy)
        ty = my - (r * hx - p * hz)
        tz = mz - (p * hy - q * hx)
        dy = (
            vn,
            ve,
            vd,
            r11 * sfx + r12 * sfy + r13 * sfz + en,
            r21 * sfx + r22 * sfy + r23 * sfz + ee,
            r31 * sfx + r32 * sfy + r33 * sfz + g + ed,
            -0.5 * (q1 * p + q2 * q + q3 * r),
            0.5 * (q0 * p + q2 * r - q3 * q),
            0.5 * (q0 * q - q1 * r + q3 * p),
            0.5 * (q0 * r + q1 * q - q2 * p),
            jxx * tx + jxz * tz,
            jyy * ty,
            jxz * tx + jzz * tz,
        )
        return dy, (sfx, sfy, sfz, v_air, alpha, beta, thrust)

    def rk4(self, y: State, u: StepInputs, dt_s: float, k1: State) -> State:
        """One classical RK4 step from ``y`` whose derivative ``k1`` is already known; the quaternion is
        renormalised afterwards (RK4 does not preserve its norm)."""
        f = self._rhs
        h2 = 0.5 * dt_s
        k2 = f(tuple([a + h2 * b for a, b in zip(y, k1, strict=True)]), u)[0]
        k3 = f(tuple([a + h2 * b for a, b in zip(y, k2, strict=True)]), u)[0]
        k4 = f(tuple([a + dt_s * b for a, b in zip(y, k3, strict=True)]), u)[0]
        h6 = dt_s / 6.0
        out = [a + h6 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(y, k1, k2, k3, k4, strict=True)]
        q0, q1, q2, q3 = out[6:10]
        s = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        out[6:10] = (q0 * s, q1 * s, q2 * s, q3 * s)
        return tuple(out)
