"""The as-built aircraft: what the real reference UAV has that its design data set does not.

The design data set (``uav-envelope``) is the designer's simulation. The aircraft that flies was built
by hand, carries a payload, has a propeller blowing over it and ports drilled into its skin. Every
difference below is a named effect that a scenario switches on (``as_built_effects``); docs/flight-sim.md
gives each one's physical source, magnitude and citation. The estimator side (``vdm_aero``) never sees
this module: it knows the design data set, the nominal vehicle description and sensor logs only.

Effects (parameters in :data:`AS_BUILT_PRESETS`):

* ``rigging``: wing incidence offset, left/right washout asymmetry (geometry: the lattice and the surface
  move), control-surface neutral offsets (the servo's 1500 µs is not the surface's zero).
* ``control_effectiveness``: each surface's effective deflection is a fraction of the servo deflection
  (hinge gap leakage, linkage slop and flex).
* ``skin_friction``: a rougher skin than the design's cf, with the turbulent flat-plate Reynolds
  dependence cf ∝ Re^−1/5 on the lifting surfaces.
* ``slipstream``: the propeller's slipstream raises the dynamic pressure over the strips it covers (wing
  root, tailplane centre, fin root) by η·T/(q̄·A_disk) (actuator-disk momentum theory).
* ``unsteady``: circulation lag (Jones' two-term Wagner approximation) on the incidence the aerodynamics
  see, and a separation lag (Beddoes–Leishman T_f) on the separation-onset (α²) part.
* ``mass_properties``: a payload and a battery placed off the design position: mass, CG and inertia
  change; aerodynamic and thrust moments act about the true CG; the IMU (at the design CG) feels the
  lever-arm accelerations.
* ``port_installation``: each port sits ~1 mm from its nominal location, reads a bias of a few per cent
  of q̄ (hole burrs and steps), and has its own tubing lag.
* ``propulsion``: the installed propeller gives less static thrust than its data sheet (fuselage
  blockage) and the battery under load spins it slower.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from sim.airframe.geometry import FUSELAGE, AirframeDesign
from sim.airframe.pressure import AirframePressureModel
from sim.airframe.spec import AirframeSpec
from sim.airframe.vlm import FlightStates
from sim.flight.aero import PortLayout, StripAero
from sim.flight.propulsion import PropulsionSpec
from sim.flight.rigid_body import MassProperties
from vdm_aero._typing import F64Array, IntArray
from vdm_aero.dataset import Reference

__all__ = [
    "AS_BUILT_EFFECTS",
    "AS_BUILT_PRESETS",
    "AsBuiltSpec",
    "AsBuiltStripAero",
    "ControlMap",
    "MassChanges",
    "PortInstallationErrors",
    "UnsteadyLag",
    "as_built_airframe",
    "as_built_mass",
    "as_built_propulsion",
    "cg_transfer_matrix",
    "draw_airframe",
    "port_installation_errors",
]

AS_BUILT_EFFECTS: Final = (
    "rigging",
    "control_effectiveness",
    "skin_friction",
    "slipstream",
    "unsteady",
    "mass_properties",
    "port_installation",
    "propulsion",
)
"""Every as-built effect, in the order docs/flight-sim.md describes them."""


# ---------------------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Rigging:
    """Rigging errors [deg]: wing incidence offset, the left half's washout minus the right half's, and the
    surfaces' neutral offsets (surface position at the servo's neutral PWM; same signs as the deflections)."""

    wing_incidence_offset_deg: float
    wing_left_twist_offset_deg: float
    aileron_offset_deg: float
    elevator_offset_deg: float
    rudder_offset_deg: float


@dataclass(frozen=True)
class ControlEffectiveness:
    """Effective deflection per servo deflection (1 = the design's)."""

    aileron: float
    elevator: float
    rudder: float


@dataclass(frozen=True)
class SkinFriction:
    """Skin-friction coefficient at the reference airspeed (the design has 0.004) and its Reynolds
    exponent (cf ∝ Re^exponent; −0.2 for a turbulent flat plate)."""

    cf_reference: float
    reference_speed_m_s: float
    reynolds_exponent: float


@dataclass(frozen=True)
class Slipstream:
    """Slipstream radius as a fraction of the propeller radius (contraction), and the fraction of the
    far-wake dynamic-pressure rise T/A_disk reached at the wing and at the tail (mixing and decay)."""

    radius_fraction: float
    wing_efficiency: float
    tail_efficiency: float


@dataclass(frozen=True)
class Unsteady:
    """Jones' approximation of Wagner's function φ(s) = 1 − A1·e^(−b1·s) − A2·e^(−b2·s) (s = 2Vt/c) and
    the separation-point time constant T_f [semichords]; ``chord_m`` the reference chord."""

    a1: float
    b1: float
    a2: float
    b2: float
    t_f_semichords: float
    chord_m: float


@dataclass(frozen=True)
class MassChanges:
    """A payload (point mass at (x, 0, z) from the design CG [m]) and the battery moved along x [m]."""

    payload_kg: float
    payload_x_m: float
    payload_z_m: float
    battery_shift_x_m: float


@dataclass(frozen=True)
class PortInstallation:
    """Per-port installation errors, drawn once per airframe from ``seed`` and the port's name: a
    chordwise position offset of ``offset_m`` (random sign), a bias ~ N(0, ``bias_cp_sigma``) in Cp and a
    tubing lag uniform in ``lag_range_s``."""

    offset_m: float
    bias_cp_sigma: float
    lag_range_s: tuple[float, float]
    seed: int


@dataclass(frozen=True)
class PropulsionChanges:
    """Installed static thrust coefficient and full-throttle speed as fractions of the data sheet's."""

    ct0_factor: float
    max_rev_factor: float


@dataclass(frozen=True)
class AsBuiltSpec:
    """One built aircraft: every effect's parameters (switched on per scenario)."""

    name: str
    rigging: Rigging
    control: ControlEffectiveness
    skin_friction: SkinFriction
    slipstream: Slipstream
    unsteady: Unsteady
    mass: MassChanges
    ports: PortInstallation
    propulsion: PropulsionChanges


AS_BUILT_PRESETS: Final = {
    "uav-2m-asbuilt": AsBuiltSpec(
        name="uav-2m-asbuilt",
        rigging=Rigging(
            wing_incidence_offset_deg=0.35,
            wing_left_twist_offset_deg=-0.5,
            aileron_offset_deg=0.6,
            elevator_offset_deg=-0.8,
            rudder_offset_deg=0.7,
        ),
        control=ControlEffectiveness(aileron=0.85, elevator=0.88, rudder=0.83),
        skin_friction=SkinFriction(cf_reference=0.0055, reference_speed_m_s=18.0, reynolds_exponent=-0.2),
        slipstream=Slipstream(radius_fraction=0.9, wing_efficiency=0.85, tail_efficiency=0.7),
        unsteady=Unsteady(a1=0.165, b1=0.0455, a2=0.335, b2=0.3, t_f_semichords=3.0, chord_m=0.2),
        mass=MassChanges(payload_kg=0.20, payload_x_m=0.18, payload_z_m=0.05, battery_shift_x_m=-0.02),
        ports=PortInstallation(offset_m=1.0e-3, bias_cp_sigma=0.01, lag_range_s=(0.010, 0.040), seed=2026),
        propulsion=PropulsionChanges(ct0_factor=0.92, max_rev_factor=0.95),
    ),
}
"""Named as-built aircraft."""


def draw_airframe(nominal: AsBuiltSpec, rng: np.random.Generator, index: int) -> AsBuiltSpec:
    """Airframe ``index`` of a fleet built to the same plans: every parameter drawn uniformly within the build
    tolerances that the preset's sources give (docs/flight-sim.md, "A fleet"): rigging within the ±0.5° of a
    clevis turn (incidence, twist) and ±1° at the surfaces' neutral; control effectiveness 0.80–0.90 (an
    unsealed gap costs 10–20 %, Hoerner & Borst); skin friction cf 0.0045–0.0065; slipstream efficiencies
    ±0.1 around the preset's; payload 0.1–0.3 kg placed by hand; port bias σ 0.5–2 % of q̄ (Shaw 1960); installed
    thrust 0.88–0.96 of the data sheet's, full-throttle speed 0.92–0.98. The unsteady aerodynamics are physics,
    not build, and stay."""
    u = rng.uniform
    return replace(
        nominal,
        name=f"{nominal.name}-{index}",
        rigging=Rigging(
            wing_incidence_offset_deg=float(u(-0.5, 0.5)),
            wing_left_twist_offset_deg=float(u(-0.7, 0.7)),
            aileron_offset_deg=float(u(-1.0, 1.0)),
            elevator_offset_deg=float(u(-1.0, 1.0)),
            rudder_offset_deg=float(u(-1.0, 1.0)),
        ),
        control=ControlEffectiveness(
            aileron=float(u(0.8, 0.9)), elevator=float(u(0.8, 0.9)), rudder=float(u(0.8, 0.9))
        ),
        skin_friction=replace(nominal.skin_friction, cf_reference=float(u(0.0045, 0.0065))),
        slipstream=Slipstream(
            radius_fraction=float(u(0.85, 0.95)),
            wing_efficiency=float(u(0.75, 0.95)),
            tail_efficiency=float(u(0.6, 0.8)),
        ),
        mass=MassChanges(
            payload_kg=float(u(0.1, 0.3)),
            payload_x_m=float(u(0.1, 0.25)),
            payload_z_m=float(u(0.02, 0.08)),
            battery_shift_x_m=float(u(-0.03, 0.03)),
        ),
        ports=replace(
            nominal.ports,
            offset_m=float(u(0.5e-3, 1.5e-3)),
            bias_cp_sigma=float(u(0.005, 0.02)),
            seed=int(rng.integers(2**31)),
        ),
        propulsion=PropulsionChanges(ct0_factor=float(u(0.88, 0.96)), max_rev_factor=float(u(0.92, 0.98))),
    )


def check_effects(names: Iterable[str], where: str) -> frozenset[str]:
    """The set of effect names, each one known (ValueError naming ``where`` otherwise)."""
    out = frozenset(names)
    unknown = sorted(out - set(AS_BUILT_EFFECTS))
    if unknown:
        raise ValueError(f"{where}: unknown as-built effects {unknown} (known: {', '.join(AS_BUILT_EFFECTS)})")
    return out


# ------------------------------------------------------------------------------------ the airframe
def as_built_airframe(spec: AirframeSpec, asb: AsBuiltSpec, effects: frozenset[str]) -> AirframeSpec:
    """The design's airframe spec with the geometric and skin effects of the built aircraft."""
    design: AirframeDesign = spec.design
    eff = {k: dict(v) for k, v in spec.effects.items()}
    if "rigging" in effects:
        r = asb.rigging
        wing = replace(
            design.wing,
            incidence_deg=design.wing.incidence_deg + r.wing_incidence_offset_deg,
            left_twist_offset_deg=r.wing_left_twist_offset_deg,
        )
        design = replace(design, wing=wing)
    if "skin_friction" in effects:
        eff["viscous_drag"] = {**eff.get("viscous_drag", {}), "cf": asb.skin_friction.cf_reference}
    return replace(spec, name=f"{spec.name}:{asb.name}", design=design, effects=eff)


def _point_inertia(m: float, r: Sequence[float] | F64Array) -> F64Array:
    v = np.asarray(r, dtype=np.float64)
    return np.asarray(m * (float(v @ v) * np.eye(3) - np.outer(v, v)))


def as_built_mass(
    design_mass: MassProperties, battery_b_m: F64Array, battery_kg: float, changes: MassChanges
) -> tuple[MassProperties, F64Array]:
    """Mass properties about the built aircraft's CG and that CG's position from the design CG [m].

    Parallel-axis theorem: the design inertia (about the design CG, the body origin) plus the payload's and
    the battery move's point inertias about the origin, then moved to the new CG."""
    r_p = np.array([changes.payload_x_m, 0.0, changes.payload_z_m])
    r_b0 = np.asarray(battery_b_m, dtype=np.float64)
    r_b1 = r_b0 + np.array([changes.battery_shift_x_m, 0.0, 0.0])
    m = design_mass.mass_kg + changes.payload_kg
    first = changes.payload_kg * r_p + battery_kg * (r_b1 - r_b0)
    r_cg = first / m
    i_origin: F64Array = np.asarray(design_mass.inertia_kg_m2, dtype=np.float64) + _point_inertia(
        changes.payload_kg, r_p
    )
    i_origin += _point_inertia(battery_kg, r_b1)
    i_origin -= _point_inertia(battery_kg, r_b0)
    i_cg = i_origin - _point_inertia(m, r_cg)
    i_cg[0, 1] = i_cg[1, 0] = i_cg[1, 2] = i_cg[2, 1] = 0.0  # y = 0 everywhere: exact zeros
    return MassProperties(mass_kg=m, inertia_kg_m2=i_cg), r_cg


def as_built_propulsion(
    design: PropulsionSpec, asb: AsBuiltSpec, effects: frozenset[str], r_cg_b: F64Array
) -> PropulsionSpec:
    """The installed propulsion: thrust and speed changes, the hub measured from the true CG."""
    out = design
    if "propulsion" in effects:
        pc = asb.propulsion
        out = replace(
            out,
            propeller=replace(
                out.propeller, name=f"{out.propeller.name}-installed", ct0=out.propeller.ct0 * pc.ct0_factor
            ),
            max_rev_s=out.max_rev_s * pc.max_rev_factor,
        )
    hub = np.asarray(out.thrust_point_b, dtype=np.float64) - np.asarray(r_cg_b)
    return replace(out, thrust_point_b=(float(hub[0]), float(hub[1]), float(hub[2])))


def cg_transfer_matrix(r_cg_b: F64Array, reference: Reference) -> F64Array:
    """(6, 6) map of body-axis coefficients about the design CG to coefficients about a CG at ``r_cg_b``
    [m]: forces unchanged, M_cg = M_0 − r_cg × F (moment coefficients on b, c, b)."""
    x, y, z = (float(v) for v in r_cg_b)
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    lref = np.array([reference.span_m, reference.chord_m, reference.span_m])
    t = np.eye(6)
    t[3:, :3] = -cross / lref[:, None]
    return t


# --------------------------------------------------------------------------------- control surfaces
@dataclass(frozen=True)
class ControlMap:
    """Servo deflection → the deflection the flow sees: δ_eff = k·δ + δ_0 per surface [rad]."""

    gain: tuple[float, float, float]  # aileron, elevator, rudder
    offset_rad: tuple[float, float, float]

    @classmethod
    def build(cls, asb: AsBuiltSpec | None, effects: frozenset[str]) -> ControlMap:
        gain, off = (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)
        if asb is not None and "control_effectiveness" in effects:
            c = asb.control
            gain = (c.aileron, c.elevator, c.rudder)
        if asb is not None and "rigging" in effects:
            r = asb.rigging
            off = tuple(math.radians(v) for v in (r.aileron_offset_deg, r.elevator_offset_deg, r.rudder_offset_deg))  # type: ignore[assignment]
        return cls(gain=gain, offset_rad=off)

    def apply(self, aileron: float, elevator: float, rudder: float) -> tuple[float, float, float]:
        (ka, ke, kr), (oa, oe, orr) = self.gain, self.offset_rad
        return ka * aileron + oa, ke * elevator + oe, kr * rudder + orr

    def servo_for(self, aileron: float, elevator: float, rudder: float) -> tuple[float, float, float]:
        """The servo deflections that give these effective deflections (the inverse of :meth:`apply`)."""
        (ka, ke, kr), (oa, oe, orr) = self.gain, self.offset_rad
        return (aileron - oa) / ka, (elevator - oe) / ke, (rudder - orr) / kr


# ------------------------------------------------------------------------------------------- ports
@dataclass(frozen=True)
class PortInstallationErrors:
    """Per port: chordwise position offset [m] (signed along the contour order), bias [Cp], tubing lag [s]."""

    offset_m: F64Array
    bias_cp: F64Array
    lag_s: F64Array


def port_installation_errors(names: Sequence[str], inst: PortInstallation) -> PortInstallationErrors:
    """Draw each port's errors from the airframe's seed and the port's name: the same port of the same
    airframe has the same errors in every flight, whatever the other ports are."""
    off, bias, lag = [], [], []
    lo, hi = inst.lag_range_s
    for name in names:
        rng = np.random.default_rng([inst.seed, zlib.crc32(name.encode())])
        off.append(inst.offset_m * (1.0 if rng.random() < 0.5 else -1.0))
        bias.append(inst.bias_cp_sigma * rng.standard_normal())
        lag.append(lo + (hi - lo) * rng.random())
    return PortInstallationErrors(np.array(off), np.array(bias), np.array(lag))


# --------------------------------------------------------------------------------- the aerodynamics
class AsBuiltStripAero(StripAero):
    """:class:`StripAero` of the built aircraft: Reynolds-dependent friction, the slipstream rows, ports
    off their nominal points and moments about the true CG.

    :meth:`outputs` returns (K, 2·(6 + P)) with a slipstream (the second block is the change per unit
    thrust coefficient T_c = T/(q̄·A_disk)), else (K, 6 + P). :meth:`evaluate` is the T_c = 0 part."""

    def __init__(
        self,
        model: AirframePressureModel,
        ports: PortLayout,
        asb: AsBuiltSpec,
        effects: frozenset[str],
        *,
        r_cg_b: F64Array,
        propulsion: PropulsionSpec,
        port_offsets_m: F64Array | None = None,
    ) -> None:
        super().__init__(model, ports)
        self.asb = asb
        self.effects = effects
        self._transfer = cg_transfer_matrix(r_cg_b, model.reference).T  # row vectors: C' = C @ Tᵀ
        self._friction = "skin_friction" in effects
        self._slip = "slipstream" in effects
        g = model.geometry
        # slipstream coverage of each lattice strip of each group: a smooth-edged disc of radius R_s about
        # the propeller axis (body x through the hub)
        hub = np.asarray(propulsion.thrust_point_b, dtype=np.float64) + np.asarray(r_cg_b)  # design frame
        r_s = asb.slipstream.radius_fraction * 0.5 * propulsion.propeller.diameter_m
        self._slip_w: list[F64Array] = []
        for grp in model.groups:
            mid = model.vlm.mid_b[grp.strips]
            r = np.hypot(mid[:, 1] - hub[1], mid[:, 2] - hub[2])
            cover = 0.5 * (1.0 - np.tanh((r - r_s) / (0.1 * r_s)))
            eff = asb.slipstream.wing_efficiency if grp.name == "wing" else asb.slipstream.tail_efficiency
            self._slip_w.append(eff * cover)
        # ports off their nominal point: interpolate towards the contour neighbour by |offset| / spacing
        n = len(ports)
        offs = np.zeros(n) if port_offsets_m is None else np.asarray(port_offsets_m, dtype=np.float64)
        self._nb_weight = np.zeros(n)
        self._nb_index = ports.point_index.copy()
        comp = g.component[ports.point_index]
        for k in range(n):
            if offs[k] == 0.0:
                continue
            pi = int(ports.point_index[k])
            if comp[k] == FUSELAGE:
                sl = g.component_slice(FUSELAGE)
                d = np.linalg.norm(g.points_b[sl] - g.points_b[pi], axis=1)
                d[pi - sl.start] = np.inf
                nb = sl.start + int(np.argmin(d))
            else:
                j = int(g.chord_index[pi])
                n_c = len(g.chord_x_c[int(np.flatnonzero([p.component == comp[k] for p in g.parts])[0])])
                step = 1 if offs[k] > 0.0 else -1
                if not 0 <= j + step < n_c:
                    step = -step
                nb = pi + step
            self._nb_index[k] = nb
            self._nb_weight[k] = min(abs(offs[k]) / float(np.linalg.norm(g.points_b[nb] - g.points_b[pi])), 1.0)
        self._nb_ports: StripAero | None = None
        if np.any(self._nb_weight > 0.0):
            nb_layout = PortLayout(
                names=tuple(f"{nm}~" for nm in ports.names),
                point_index=self._nb_index.astype(np.int64),
                snap_distance_m=np.zeros(n),
            )
            self._nb_ports = StripAero(model, nb_layout)

    @property
    def has_slipstream(self) -> bool:
        return self._slip

    def _friction_factor(self, states: FlightStates) -> F64Array:
        sf = self.asb.skin_friction
        return np.asarray((states.airspeed_m_s / sf.reference_speed_m_s) ** sf.reynolds_exponent)

    def outputs(self, states: FlightStates, *, fuselage_index: IntArray | None = None) -> F64Array:
        m = self.model
        k = len(states)
        field = m._field_quasi_steady(states, self._buf)
        fr = self._friction_factor(states)[:, None] if self._friction else None
        coeffs = np.zeros((k, 6))
        slip = np.zeros((k, 6))
        cp_ports = np.empty((k, self.n_ports))
        slip_ports = np.zeros((k, self.n_ports))
        for grp, cpg, trg, gp, w in zip(
            m.groups, field.strip_cp, field.strip_traction, self._group_ports, self._slip_w, strict=True
        ):
            c_p = cpg.reshape(k, -1) @ grp.pressure_agg
            c_f = trg.reshape(k, -1) @ grp.friction_agg
            coeffs += c_p + (c_f * fr if fr is not None else c_f)
            if self._slip:
                # the strips' local dynamic pressure is q̄(1 + w·T_c): pressure and friction scale with it
                ws = np.repeat(w, cpg.shape[2])
                slip += (cpg.reshape(k, -1) * ws) @ grp.pressure_agg
                slip += ((trg.reshape(k, -1) * ws) @ grp.friction_agg) * (fr if fr is not None else 1.0)
            if len(gp.columns):
                cp_ports[:, gp.columns] = gp.w0 * cpg[:, gp.i0, gp.chord] + gp.w1 * cpg[:, gp.i1, gp.chord]
                if self._slip:
                    wp = gp.w0 * w[gp.i0] + gp.w1 * w[gp.i1]
                    slip_ports[:, gp.columns] = cp_ports[:, gp.columns] * wp
        src = None if fuselage_index is None else np.asarray(fuselage_index, dtype=np.int64)
        if src is None:
            cp_f, c_fus = m._fuselage(field, slice(None), self._buf)
        else:
            n_f = int(np.max(src)) + 1
            cp_f, c_fus = m._fuselage(field, slice(0, n_f), self._buf)
            cp_f, c_fus = cp_f[src], c_fus[src]
        coeffs += c_fus
        if len(self._fus_cols):
            cp_ports[:, self._fus_cols] = cp_f[:, self._fus_local]
        if self._nb_ports is not None:
            # the neighbours' Cp (same field: the strip and fuselage gathers are cheap) — a second call
            # recomputes the field, so gather directly through the neighbour layout's tables
            nb = self._gather(self._nb_ports, field, cp_f)
            wgt = self._nb_weight
            cp_ports = (1.0 - wgt) * cp_ports + wgt * nb
            if self._slip:
                nb_slip = self._gather(self._nb_ports, field, None, slip_weights=True)
                slip_ports = (1.0 - wgt) * slip_ports + wgt * nb_slip
        coeffs = coeffs @ self._transfer
        if not self._slip:
            return np.hstack([coeffs, cp_ports])
        return np.hstack([coeffs, cp_ports, slip @ self._transfer, slip_ports])

    def _gather(
        self, layout: StripAero, field: object, cp_f: F64Array | None, *, slip_weights: bool = False
    ) -> F64Array:
        """Port Cp of another layout from an already computed field (``slip_weights``: the slipstream's
        per-unit-T_c rows, zero on the fuselage)."""
        k = len(field.states)  # type: ignore[attr-defined]
        out = np.zeros((k, layout.n_ports))
        for cpg, gp, w in zip(field.strip_cp, layout._group_ports, self._slip_w, strict=True):  # type: ignore[attr-defined]
            if len(gp.columns):
                val = gp.w0 * cpg[:, gp.i0, gp.chord] + gp.w1 * cpg[:, gp.i1, gp.chord]
                if slip_weights:
                    val = val * (gp.w0 * w[gp.i0] + gp.w1 * w[gp.i1])
                out[:, gp.columns] = val
        if cp_f is not None and len(layout._fus_cols):
            out[:, layout._fus_cols] = cp_f[:, layout._fus_local]
        return out

    def evaluate(self, states: FlightStates, *, fuselage_index: IntArray | None = None) -> tuple[F64Array, F64Array]:
        y = self.outputs(states, fuselage_index=fuselage_index)
        return y[:, :6], y[:, 6 : 6 + self.n_ports]

    def coefficients(self, states: FlightStates, thrust_coeff: float) -> F64Array:
        """Coefficients (K, 6) at a thrust coefficient (trim)."""
        y = self.outputs(states)
        c = y[:, :6]
        if self._slip:
            n = 6 + self.n_ports
            c = c + thrust_coeff * y[:, n : n + 6]
        return np.asarray(c)


# ------------------------------------------------------------------------------------ unsteadiness
class UnsteadyLag:
    """Circulation lag and separation lag of the incidence the aerodynamics see, stepped with the flight.

    Circulation (Leishman's recursive indicial form of Jones' approximation): X_i ← X_i·e^(−b_i·Δs) +
    A_i·Δα·e^(−b_i·Δs/2), Δs = 2VΔt/c, α_E = α − X1 − X2 (so ``alpha_lag`` = X1 + X2). Separation: the
    separation-onset incidence α_f follows α_E with T_f semichords (α_f ← α_f + (α_E − α_f)(1 − e^(−Δs/T_f)));
    ``sep_deficit`` = α_E − α_f. Both vanish in steady flight: the quasi-steady design data are the
    steady state."""

    def __init__(self, params: Unsteady, alpha0_rad: float) -> None:
        self.p = params
        self.x1 = 0.0
        self.x2 = 0.0
        self.alpha_prev = alpha0_rad
        self.alpha_f = alpha0_rad

    def step(self, alpha_rad: float, airspeed_m_s: float, dt_s: float) -> tuple[float, float]:
        """Advance with the new α [rad] and return (alpha_lag, sep_deficit) [rad]."""
        p = self.p
        ds = 2.0 * airspeed_m_s * dt_s / p.chord_m
        d_alpha = alpha_rad - self.alpha_prev
        self.alpha_prev = alpha_rad
        e1, e2 = math.exp(-p.b1 * ds), math.exp(-p.b2 * ds)
        self.x1 = self.x1 * e1 + p.a1 * d_alpha * math.sqrt(e1)
        self.x2 = self.x2 * e2 + p.a2 * d_alpha * math.sqrt(e2)
        alpha_e = alpha_rad - self.x1 - self.x2
        self.alpha_f += (alpha_e - self.alpha_f) * (1.0 - math.exp(-ds / p.t_f_semichords))
        return self.x1 + self.x2, alpha_e - self.alpha_f
