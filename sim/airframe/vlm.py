"""Vectorised vortex-lattice (Weissinger) model of the lifting surfaces, with unit solutions.

One horseshoe vortex per spanwise strip (wing halves, tailplane halves, fin): the bound vortex on the
quarter-chord line, trailing legs parallel to the body x axis to far downstream (AVL's fixed wake), a
control point on the local chord at a distance a0·c/(4π) behind the bound vortex. That is the
generalised Weissinger rule: with a0 the section lift slope [1/rad] a single strip then reproduces the
2-D section's lift slope, and a0 = 2π gives the classic 3/4-chord point. Camber enters through the zero-lift
angle (the control-point normal is tilted to the zero-lift line), twist and incidence through the
section frames.

Boundary condition at control point i with normal n_i: (V_air,i + v_induced,i)·n_i = 0, where the
air velocity relative to the aircraft is ``V_air(r) = −(u + ω × r)``, ``u = V (cos α cos β, sin β,
sin α cos β)`` and ``ω = (p, q, r)`` (body axes FRD). The right-hand side is linear in the 15-vector
``s = [u, v, w, p, q, r, δa·(u, v, w), δe·(u, v, w), δr·(u, v, w)]``: control deflections tilt the normal
by τ·δ about the hinge line (thin-airfoil flap effectiveness τ(c_f/c) times a viscous factor), linearised
in δ. The influence matrix is factorised once per geometry; every state's circulation is the matrix
product ``Γ = s @ G.T`` with ``G = A⁻¹ R`` (S × 15).

Control-deflection signs (section flap angle δ_sec > 0 = trailing edge towards −e_u, i.e. "down" on
the wing and tailplane):

* aileron δa > 0: right aileron trailing edge down, left trailing edge up → rolls left (Croll < 0);
* elevator δe > 0: trailing edge down → more tail lift → nose down (Cpitch < 0);
* rudder δr > 0: trailing edge to the left → fin force to the right (CY > 0) → nose left (Cyaw < 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Final

import numpy as np
import scipy.linalg

from sim.airframe.geometry import HTAIL_L, HTAIL_R, WING_L, WING_R, LiftingPart, span_stations
from vdm_aero._typing import F64Array, IntArray
from vdm_aero.coefficients import ReferenceLike
from vdm_aero.dataset import AIRFRAME_STATE_COLUMNS as STATE_COLUMNS

__all__ = [
    "CONTROLS",
    "STATE_COLUMNS",
    "FlightStates",
    "StripKinematics",
    "VlmResolution",
    "VortexLattice",
    "flap_effectiveness",
]

# the column order is part of the data-set format (the navigation filter reads states.npy): one definition

CONTROLS: Final = ("aileron", "elevator", "rudder")
FLAP_VISCOUS_FACTOR: Final = 0.85
"""Plain flaps reach ~80–90 % of the thin-airfoil effectiveness at small deflections (gap and boundary-layer
losses; Abbott & von Doenhoff §8.5, ESDU 74011)."""
_FAR_WAKE_SPANS: Final = 100.0  # trailing legs end this many spans downstream
_CORE_FRACTION: Final = 0.1  # vortex core radius / strip width (removes the singularity near a leg)


@dataclass(frozen=True)
class FlightStates:
    """K flight states (all arrays (K,), SI units). ``alpha_dot_rad_s`` is the rate of change of the
    angle of attack (not the pitch rate q): it drives the tail's downwash lag and the apparent mass of
    a plunging aircraft. Control-deflection signs: see the module docstring."""

    airspeed_m_s: F64Array
    alpha_rad: F64Array
    beta_rad: F64Array
    p_rad_s: F64Array
    q_rad_s: F64Array
    r_rad_s: F64Array
    alpha_dot_rad_s: F64Array
    aileron_rad: F64Array
    elevator_rad: F64Array
    rudder_rad: F64Array

    def __post_init__(self) -> None:
        arrs = [np.atleast_1d(np.asarray(getattr(self, f.name), dtype=np.float64)) for f in fields(self)]
        k = np.broadcast_shapes(*(a.shape for a in arrs))
        if len(k) != 1:
            raise ValueError(f"flight states must be 1-D arrays, got shape {k}")
        for f, a in zip(fields(self), arrs, strict=True):
            object.__setattr__(self, f.name, np.ascontiguousarray(np.broadcast_to(a, k)))
        if not np.all(self.airspeed_m_s > 0.0):
            raise ValueError("airspeed_m_s must be > 0")

    @classmethod
    def make(cls, airspeed_m_s: float | F64Array, **kwargs: float | F64Array) -> FlightStates:
        """States with unspecified fields zero, e.g. ``FlightStates.make(20.0, alpha_rad=np.radians(a))``."""
        unknown = set(kwargs) - set(STATE_COLUMNS)
        if unknown:
            raise TypeError(f"unknown flight-state fields: {sorted(unknown)}")
        vals = {name: kwargs.get(name, 0.0) for name in STATE_COLUMNS[1:]}
        return cls(
            airspeed_m_s=np.asarray(airspeed_m_s, dtype=np.float64), **{k: np.asarray(v) for k, v in vals.items()}
        )

    @classmethod
    def from_array(cls, table: F64Array) -> FlightStates:
        """From a (K, 10) table in :data:`STATE_COLUMNS` order."""
        a = np.asarray(table, dtype=np.float64)
        if a.ndim != 2 or a.shape[1] != len(STATE_COLUMNS):
            raise ValueError(f"state table: shape {a.shape}, expected (K, {len(STATE_COLUMNS)})")
        return cls(*(a[:, i] for i in range(len(STATE_COLUMNS))))

    def to_array(self) -> F64Array:
        """The (K, 10) table in :data:`STATE_COLUMNS` order."""
        return np.column_stack([getattr(self, n) for n in STATE_COLUMNS])

    def __len__(self) -> int:
        return int(self.airspeed_m_s.shape[0])

    def take(self, idx: slice | IntArray) -> FlightStates:
        """A subset of the states."""
        return FlightStates(*(getattr(self, n)[idx] for n in STATE_COLUMNS))

    def velocity_b(self) -> F64Array:
        """Aircraft velocity relative to the air in body axes, (K, 3) [m/s]: V(cos α cos β, sin β, sin α cos β)."""
        v, a, b = self.airspeed_m_s, self.alpha_rad, self.beta_rad
        return np.column_stack((v * np.cos(a) * np.cos(b), v * np.sin(b), v * np.sin(a) * np.cos(b)))

    def rates_b(self) -> F64Array:
        """Body rates (K, 3) [rad/s]."""
        return np.column_stack((self.p_rad_s, self.q_rad_s, self.r_rad_s))

    def accel_cg_b(self) -> F64Array:
        """CG acceleration (K, 3) [m/s²] implied by α̇ at constant airspeed and sideslip: only the normal
        component ``a_z = ẇ + p v − q u`` is known from the state."""
        v, a, b = self.airspeed_m_s, self.alpha_rad, self.beta_rad
        u_b, v_b = v * np.cos(a) * np.cos(b), v * np.sin(b)
        w_dot = v * np.cos(a) * np.cos(b) * self.alpha_dot_rad_s
        out = np.zeros((len(self), 3))
        out[:, 2] = w_dot + self.p_rad_s * v_b - self.q_rad_s * u_b
        return out


@dataclass(frozen=True)
class VlmResolution:
    """Spanwise horseshoes per wing half, per tailplane half and on the fin."""

    wing_strips: int = 16
    htail_strips: int = 6
    vtail_strips: int = 6

    def for_part(self, part: LiftingPart) -> int:
        if part.component in (WING_R, WING_L):
            return self.wing_strips
        if part.component in (HTAIL_R, HTAIL_L):
            return self.htail_strips
        return self.vtail_strips


def flap_effectiveness(chord_fraction: float) -> float:
    """Thin-airfoil flap effectiveness τ = dα_0L/dδ magnitude for a flap of ``chord_fraction`` c_f/c:
    τ = 1 − (θ_h − sin θ_h)/π, cos θ_h = 1 − 2 x_h, x_h = 1 − c_f/c."""
    th = math.acos(1.0 - 2.0 * (1.0 - chord_fraction))
    return 1.0 - (th - math.sin(th)) / math.pi


def _control_sign(part: LiftingPart) -> tuple[int, float]:
    """(control index, section-flap sign) of a part's control surface (see the module docstring)."""
    if part.component == WING_R:
        return 0, 1.0
    if part.component == WING_L:
        return 0, -1.0
    if part.component in (HTAIL_R, HTAIL_L):
        return 1, 1.0
    return 2, -1.0  # rudder TE left = TE towards the fin's e_u (−y) = section flap up


def _segments_velocity(p: F64Array, a: F64Array, b: F64Array, core: F64Array) -> F64Array:
    """Velocity (P, S, 3) induced at points p (P, 3) by straight vortex segments a → b (S, 3) of unit
    strength (Biot–Savart; a core of radius ``core`` (S,) smooths the field near the line)."""
    r1 = p[:, None, :] - a[None, :, :]
    r2 = p[:, None, :] - b[None, :, :]
    r0 = b - a
    c = np.cross(r1, r2)
    c2 = np.einsum("psk,psk->ps", c, c)
    n1 = np.maximum(np.linalg.norm(r1, axis=-1), 1e-12)
    n2 = np.maximum(np.linalg.norm(r2, axis=-1), 1e-12)
    proj = np.einsum("sk,psk->ps", r0, r1 / n1[..., None] - r2 / n2[..., None])
    den = 4.0 * np.pi * (c2 + (core * core * np.einsum("sk,sk->s", r0, r0))[None, :])
    return np.asarray(c * (proj / den)[..., None])


@dataclass(frozen=True, eq=False)
class StripKinematics:
    """Per state and strip (K, S): circulation ``gamma`` [m²/s], in-plane local speed ``speed``
    [m/s] and ``speed_ratio`` = speed/V, section lift coefficient ``cl`` on the local dynamic
    pressure, effective incidence ``alpha_eff`` [rad] (what the 2-D section sees, incl. induced
    incidence, rate effects and the tail's downwash lag), geometric in-plane incidence ``alpha_geo``
    [rad], the section's incidence rate for apparent mass ``rate`` [rad/s] and the section flap angle
    ``flap`` [rad]."""

    gamma: F64Array
    speed: F64Array
    speed_ratio: F64Array
    cl: F64Array
    alpha_eff: F64Array
    alpha_geo: F64Array
    rate: F64Array
    flap: F64Array


class VortexLattice:
    """The Weissinger lattice of the aircraft's lifting parts.

    ``section`` maps each lifting part's component id to ``(a0, alpha_0l)``: the section lift slope
    [1/rad] and zero-lift angle [rad] of its airfoil (from the 2-D model, so that the lattice and the
    section pressures agree in attached flow).
    """

    def __init__(
        self,
        parts: Sequence[LiftingPart],
        section: Mapping[int, tuple[float, float]],
        resolution: VlmResolution | None = None,
    ) -> None:
        self.parts = tuple(parts)
        self.resolution = resolution or VlmResolution()
        rows: dict[str, list[F64Array]] = {
            k: [] for k in ("part", "eta", "a", "b", "mid", "cp", "n", "e_c", "e_u", "e_c_geo", "chord", "a0", "a0l")
        }
        rows.update(flap=[], tau=[], hinge=[], pivot=[])
        for ip, part in enumerate(self.parts):
            n = self.resolution.for_part(part)
            eta = span_stations(n)
            ends = part.frames(eta).r_qc
            em = 0.5 * (eta[:-1] + eta[1:])
            f = part.frames(em)
            a0, a0l = section[part.component]
            # zero-lift line: the section frame rotated by −α_0L (nose up for positive camber)
            th = -a0l
            e_u = math.sin(th) * f.e_c + math.cos(th) * f.e_u
            e_c = math.cos(th) * f.e_c - math.sin(th) * f.e_u
            a_pt, b_pt = ends[:-1], ends[1:]
            # bound vortex along e_x × e_u0, so that ρΓ V_air × l lifts along e_u for Γ > 0
            e_u0 = part.axes()[2] * (np.array([1.0, -1.0, 1.0]) if part.mirror else 1.0)
            swap = np.einsum("sk,k->s", b_pt - a_pt, np.cross(np.array([1.0, 0.0, 0.0]), e_u0)) < 0.0
            a_pt, b_pt = np.where(swap[:, None], b_pt, a_pt), np.where(swap[:, None], a_pt, b_pt)
            mid = 0.5 * (a_pt + b_pt)
            rows["part"].append(np.full(n, ip, dtype=np.float64))
            rows["eta"].append(em)
            rows["a"].append(a_pt)
            rows["b"].append(b_pt)
            rows["mid"].append(mid)
            rows["cp"].append(mid + (a0 * f.chord / (4.0 * math.pi))[:, None] * f.e_c)
            rows["n"].append(e_u)
            rows["e_c"].append(e_c)
            rows["e_u"].append(f.e_u)
            rows["e_c_geo"].append(f.e_c)
            rows["chord"].append(f.chord)
            rows["a0"].append(np.full(n, a0))
            rows["a0l"].append(np.full(n, a0l))
            flap = np.zeros((n, 3))
            tau = np.zeros(n)
            hinge = np.ones(n)
            ctrl = part.design.control
            if ctrl is not None:
                ic, sign = _control_sign(part)
                lo, hi = eta[:-1], eta[1:]
                cover = np.clip(np.minimum(hi, ctrl.eta_end) - np.maximum(lo, ctrl.eta_start), 0.0, None) / (hi - lo)
                flap[:, ic] = sign * cover
                tau[:] = FLAP_VISCOUS_FACTOR * flap_effectiveness(ctrl.chord_fraction)
                hinge[:] = 1.0 - ctrl.chord_fraction
            rows["flap"].append(flap)
            rows["tau"].append(tau)
            rows["hinge"].append(hinge)
            # rotation axis through the CG (origin) projected on the chord line, as a fraction of chord from the LE
            rows["pivot"].append(-np.einsum("sk,sk->s", f.r_le, f.e_c) / f.chord)
        cat = {k: np.concatenate(v) for k, v in rows.items()}
        self.part_index: IntArray = cat["part"].astype(np.int64)
        self.eta = cat["eta"]
        self.a_b, self.b_b, self.mid_b, self.cp_b = cat["a"], cat["b"], cat["mid"], cat["cp"]
        self.normal_b = cat["n"]
        self.e_c_b, self.e_u_b = cat["e_c_geo"], cat["e_u"]
        self.chord_m = cat["chord"]
        self.a0, self.alpha_0l = cat["a0"], cat["a0l"]
        self.flap_map = cat["flap"]  # (S, 3) section flap per unit control deflection (sign × coverage)
        self.tau = cat["tau"]
        self.hinge_x_c = cat["hinge"]
        self.pivot_x_c = cat["pivot"]
        seg = self.b_b - self.a_b
        self.width_m = np.linalg.norm(seg, axis=1)
        self.bound_dir = seg / self.width_m[:, None]
        self.section_axis = np.cross(self.e_u_b, self.e_c_b)  # rotation about it raises the LE
        self.cos_sweep = np.abs(np.einsum("sk,sk->s", self.bound_dir, self.section_axis))
        self.n_strips = len(self.eta)

        span = max(2.0 * p.semispan_m for p in self.parts)
        far = np.array([_FAR_WAKE_SPANS * span, 0.0, 0.0])
        core = _CORE_FRACTION * self.width_m
        v = (
            _segments_velocity(self.cp_b, self.a_b - far, self.a_b, core)
            + _segments_velocity(self.cp_b, self.a_b, self.b_b, core)
            + _segments_velocity(self.cp_b, self.b_b, self.b_b - far, core)
        )
        self.influence = np.einsum("isk,ik->is", v, self.normal_b)
        rhs = np.zeros((self.n_strips, 15))
        rhs[:, 0:3] = self.normal_b
        rhs[:, 3:6] = np.cross(self.cp_b, self.normal_b)
        for ic in range(3):
            rhs[:, 6 + 3 * ic : 9 + 3 * ic] = (self.flap_map[:, ic] * self.tau)[:, None] * cat["e_c"]
        self.unit_rhs = rhs
        lu = scipy.linalg.lu_factor(self.influence)
        self.unit_gamma = np.asarray(scipy.linalg.lu_solve(lu, rhs))  # (S, 15)
        self._downwash_lag = self._tail_downwash_lag()

    # ------------------------------------------------------------------------------------ helpers
    def strips_of(self, part_index: int) -> IntArray:
        """Strip indices of one lifting part, root to tip."""
        return np.flatnonzero(self.part_index == part_index)

    def _tail_downwash_lag(self) -> F64Array:
        """Per strip, dε/dα · l [m]: the tailplane sees the wing's downwash l/V late (l from the wing's
        quarter-chord line), so its incidence gains dε/dα·α̇·l/V. Zero on the wing and the fin."""
        comp = np.array([self.parts[i].component for i in self.part_index])
        wing = np.isin(comp, (WING_R, WING_L))
        tail = np.isin(comp, (HTAIL_R, HTAIL_L))
        # downwash per unit α: the wing's part of the induced normal velocity per unit w
        v_n = self.influence[:, wing] @ self.unit_gamma[wing, 2]
        deps = -v_n  # normal velocity is upwash-positive; ε per unit w/V
        x_wing = float(np.average(self.mid_b[wing, 0], weights=self.width_m[wing] * self.chord_m[wing]))
        out = np.zeros(self.n_strips)
        out[tail] = deps[tail] * (x_wing - self.cp_b[tail, 0])
        return out

    def downwash_gradient(self) -> F64Array:
        """dε/dα at every tailplane control point (0 elsewhere): the wing's downwash per unit α."""
        comp = np.array([self.parts[i].component for i in self.part_index])
        wing = np.isin(comp, (WING_R, WING_L))
        tail = np.isin(comp, (HTAIL_R, HTAIL_L))
        out = np.zeros(self.n_strips)
        out[tail] = -(self.influence[:, wing] @ self.unit_gamma[wing, 2])[tail]
        return out

    @staticmethod
    def state_vector(states: FlightStates) -> F64Array:
        """The (K, 15) right-hand-side coordinates ``s`` of the states."""
        u = states.velocity_b()
        s = np.empty((len(states), 15))
        s[:, 0:3] = u
        s[:, 3:6] = states.rates_b()
        for ic, d in enumerate((states.aileron_rad, states.elevator_rad, states.rudder_rad)):
            s[:, 6 + 3 * ic : 9 + 3 * ic] = d[:, None] * u
        return s

    def circulation(self, states: FlightStates) -> F64Array:
        """Bound circulation (K, S) [m²/s] (positive = lift along the section's e_u)."""
        return np.asarray(self.state_vector(states) @ self.unit_gamma.T)

    def air_velocity(self, states: FlightStates, points_b: F64Array) -> F64Array:
        """Air velocity relative to the aircraft at points (S, 3): (K, S, 3) [m/s], −(u + ω × r)."""
        u = states.velocity_b()
        w = states.rates_b()
        return np.asarray(-(u[:, None, :] + np.cross(w[:, None, :], points_b[None, :, :])))

    def kinematics(self, states: FlightStates) -> StripKinematics:
        """Strip quantities of the linear lattice solution for every state."""
        gamma = self.circulation(states)
        v_air = self.air_velocity(states, self.mid_b)
        v_ax = np.einsum("ksi,si->ks", v_air, self.section_axis)
        speed = np.sqrt(np.maximum(np.einsum("ksi,ksi->ks", v_air, v_air) - v_ax * v_ax, 1e-12))
        vmag = states.airspeed_m_s[:, None]
        speed = np.maximum(speed, 1e-3 * vmag)
        cross = np.linalg.norm(np.cross(v_air, self.bound_dir[None, :, :]), axis=-1)
        cl = 2.0 * gamma * cross / (self.cos_sweep * speed * speed * self.chord_m)
        cl = cl + self.a0 * self._downwash_lag[None, :] * (states.alpha_dot_rad_s / states.airspeed_m_s)[:, None]
        # bounded to ±90° from zero lift: beyond, the section is in reversed flow, outside the model
        alpha_eff = self.alpha_0l + np.clip(cl / self.a0, -0.5 * np.pi, 0.5 * np.pi)
        alpha_geo = np.arctan2(np.einsum("ksi,si->ks", v_air, self.e_u_b), np.einsum("ksi,si->ks", v_air, self.e_c_b))
        a_cg = states.accel_cg_b()
        rate = states.rates_b() @ self.section_axis.T + (a_cg @ (-self.e_u_b).T) / speed
        flap = np.column_stack((states.aileron_rad, states.elevator_rad, states.rudder_rad)) @ self.flap_map.T
        return StripKinematics(
            gamma=gamma,
            speed=speed,
            speed_ratio=speed / vmag,
            cl=cl,
            alpha_eff=alpha_eff,
            alpha_geo=alpha_geo,
            rate=rate,
            flap=flap,
        )

    def loads(self, states: FlightStates, reference: ReferenceLike, gamma: F64Array | None = None) -> F64Array:
        """Kutta–Joukowski body-axis coefficients (K, 6) of the lattice, F_j = ρΓ_j V_air,j × (B_j − A_j)
        (freestream and rotation only, so no induced drag), moments about the origin."""
        g = self.circulation(states) if gamma is None else gamma
        v_air = self.air_velocity(states, self.mid_b)
        seg = self.b_b - self.a_b
        f = g[..., None] * np.cross(v_air, seg[None, :, :])  # per ρ
        m = np.cross(self.mid_b[None, :, :], f)
        q = 0.5 * states.airspeed_m_s[:, None] ** 2
        out = np.empty((len(states), 6))
        out[:, 0:3] = f.sum(axis=1) / (q * reference.area_m2)
        lref = np.array([reference.span_m, reference.chord_m, reference.span_m])
        out[:, 3:6] = m.sum(axis=1) / (q * reference.area_m2 * lref[None, :])
        return out
