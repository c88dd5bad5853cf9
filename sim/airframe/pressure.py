"""Surface pressure of the whole aircraft as a function of flight state.

Layers (docs/airframe.md has the full story):

1. **Lattice** (:mod:`sim.airframe.vlm`): spanwise loading, induced incidence, rate and control effects →
   per strip the effective incidence α_eff, the local in-plane speed and the section incidence rate.
   The tailplane adds the wing's downwash lag dε/dα·α̇·l/V.
2. **Sections** (:mod:`sim.airfoil.flow`): each strip's chordwise Cp is the 2-D model's pressure at
   α_eff, scaled by (V_local/V)² to the freestream dynamic pressure, so trailing-edge separation with its
   plateau, the dynamic-stall vortex, Wagner lag and apparent mass carry over strip by strip.
   Quasi-steadily (:meth:`AirframePressureModel.cp_quasi_steady`) the static separation f(α_eff) is used
   and history effects (``circulation_lag``, ``separation_lag``, ``leading_edge_vortex``) are at their
   steady state; along a time history (:meth:`AirframePressureModel.field_marched`) every strip runs
   :meth:`AirfoilFlow.march` on its own α_eff(t).
   Control surfaces: the lattice and α_eff carry the flap's lift (τ·δ); the chordwise shape is corrected
   by the thin-airfoil flap loading minus the equivalent-incidence loading (zero net lift, the hinge
   suction peak and the flap's pitching moment).
3. **Spanwise interpolation**: surface strips take the strip Cp linearly interpolated in span, so any
   surface resolution (hundreds to millions of points) costs two weighted gathers per lifting point.
4. **Fuselage**: exact potential flow of a prolate spheroid (surface velocity = tangential part of
   (1+k1)U_x e_x + (1+k2)U_⊥, Lamb's added-mass coefficients k1, k2) with the local relative velocity
   including body rates, giving Munk's moment; subcritical crossflow separation (leeward plateau at
   ``CROSSFLOW_BASE_CP`` of the crossflow dynamic pressure aft of ``CROSSFLOW_SEPARATION_DEG``); the
   crossflow apparent-mass pressure 2k2(a·r_⊥)/V² with ``added_mass``.
5. **Truth**: the pressure integral over all points plus skin friction cf·(u_e/V)² along the local
   surface flow on attached surface (``viscous_drag``), which the ports cannot see.

Cp is referenced to the freestream dynamic pressure ½ρV² and normals point into the body.

Speed: states are evaluated in blocks of :data:`BLOCK_STATES` with in-place arithmetic on scratch
buffers reused from block to block (a quasi-steady state costs ~25–55 ns per surface point); the strip
stage evaluates ``AirfoilFlow.cp``'s formula in place (tests keep it equal to ``cp()``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np
from numpy.typing import DTypeLike

from sim.airfoil.effects import EFFECTS, effect_defaults
from sim.airfoil.flow import CP_BASE, PLATEAU_BLEND_C, AirfoilFlow, EvalSurface, FlowState, f_static, kirchhoff_factor
from sim.airfoil.naca import locate_taps
from sim.airframe.geometry import (
    FUSELAGE,
    HTAIL_L,
    HTAIL_R,
    VTAIL,
    WING_L,
    WING_R,
    AirframeGeometry,
    build_geometry,
    default_design,
    surface_for,
)
from sim.airframe.vlm import FlightStates, StripKinematics, VlmResolution, VortexLattice
from vdm_aero._typing import BoolArray, F64Array, FloatArray, IntArray
from vdm_aero.coefficients import force_moment_matrix
from vdm_aero.dataset import Reference

__all__ = [
    "AIRCRAFT_EFFECTS",
    "HISTORY_EFFECTS",
    "AirframePressureModel",
    "ScratchBuffers",
    "SurfaceField",
    "benchmark_states_per_second",
    "spheroid_added_mass",
]

AIRCRAFT_EFFECTS: Final = frozenset({"incidence_offset", "viscous_drag", "port_lag", "port_bias"})
"""Effects that act on the whole aircraft or its measurements, not inside the 2-D section model."""
HISTORY_EFFECTS: Final = ("circulation_lag", "separation_lag", "leading_edge_vortex")
"""Section effects that need a time history (steady state in quasi-steady evaluation)."""
CROSSFLOW_SEPARATION_DEG: Final = 80.0  # laminar separation angle of a subcritical cylinder in crossflow
CROSSFLOW_BLEND_DEG: Final = 20.0
# A slender body's crossflow stays attached at small incidence (its boundary layer is swept aft by the
# axial flow); leeward separation sets in over a band of crossflow angle (Allen & Perkins data: ~5–15°).
CROSSFLOW_ONSET_DEG: Final = (4.0, 12.0)
CROSSFLOW_BASE_CP: Final = -1.0  # leeward base pressure on the crossflow dynamic pressure (c_d,cyl ≈ 1.2)
# [rad of θ, x/c = (1 − cos θ)/2]: rounds the inviscid log singularity at the flap hinge over ~±3 % of chord
# (real hinges have a gap and a rounded shroud); the linearised loading is also capped at stagnation, Cp ≤ 1
HINGE_ROUNDING: Final = 0.08
DEFAULT_SECTION_PANELS: Final = 160
BLOCK_STATES: Final = 64
"""States per evaluation block: scratch arrays stay cache-sized and BLAS calls single-threaded (threaded
small matrix products slow down badly on a busy machine)."""


def spheroid_added_mass(length_m: float, diameter_m: float) -> tuple[float, float]:
    """Lamb's axial and transverse added-mass coefficients (k1, k2) of a prolate spheroid."""
    a, b = 0.5 * length_m, 0.5 * diameter_m
    e = math.sqrt(1.0 - (b / a) ** 2)
    lg = math.log((1.0 + e) / (1.0 - e))
    alpha0 = 2.0 * (1.0 - e * e) / e**3 * (0.5 * lg - e)
    beta0 = 1.0 / (e * e) - (1.0 - e * e) / (2.0 * e**3) * lg
    return alpha0 / (2.0 - alpha0), beta0 / (2.0 - beta0)


def _smoothstep_inplace(u: F64Array, tmp: F64Array) -> None:
    """u ← s(clip(u, 0, 1)) with s(u) = u²(3 − 2u), using ``tmp`` as scratch."""
    np.clip(u, 0.0, 1.0, out=u)
    np.multiply(u, u, out=tmp)
    u *= -2.0
    u += 3.0
    u *= tmp


class ScratchBuffers:
    """Scratch arrays reused from block to block: allocating large temporaries costs page faults that
    dominate the arithmetic (several µs per 100 kB on virtual machines)."""

    def __init__(self) -> None:
        self._flat: dict[str, np.ndarray[Any, Any]] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype: DTypeLike = np.float64) -> np.ndarray[Any, Any]:
        size = math.prod(shape)
        a = self._flat.get(name)
        if a is None or a.size < size or a.dtype != np.dtype(dtype):
            a = np.empty(size, dtype=dtype)
            self._flat[name] = a
        return a[:size].reshape(shape)


@dataclass(frozen=True, eq=False)
class _Group:
    """A lifting family evaluated together: wing (both halves), tailplane (both halves), fin."""

    name: str
    parts: tuple[int, ...]
    flow: AirfoilFlow
    surface: EvalSurface
    strips: IntArray  # lattice strips of the group (S_g,), part by part
    flap_runs: tuple[slice, ...]  # contiguous group-local strip ranges with a control surface
    flap_shape: F64Array  # (S_g, n_c) thin-airfoil flap loading log term, signed per side (upper −½, lower +½)
    flap_eps: F64Array  # (S_g,) 2 sin θ_h / c_lα: the flap lift as an equivalent incidence per unit δ
    added_mass_shape: F64Array  # (n_c,) ∓½√(1 − ξ²): the V·α̇ apparent-mass loading per side
    suction_tables: tuple[tuple[F64Array, F64Array, F64Array], ...]  # (lower, upper): x/c, ut0, ut90 sorted
    interp: tuple[tuple[IntArray, IntArray, F64Array, F64Array], ...]  # per part: i0, i1, w0, w1 (local)
    pressure_agg: F64Array  # (S_g·n_c, 6) force/moment coefficients per unit strip Cp
    friction_agg: F64Array  # (S_g·n_c, 6) per unit strip traction


@dataclass(frozen=True, eq=False)
class SurfaceField:
    """What the surface Cp of K states is assembled from (small: independent of N).

    ``strip_cp`` / ``strip_traction``: per lifting group (K, S_g, n_c) section Cp and skin-friction
    traction (signed along the contour order), both on the freestream dynamic pressure;
    ``flow_states`` the states the flow sees (incidence offset applied); ``omega_dot`` (K, 3) [rad/s²]
    and ``accel`` (K, 3) [m/s²] drive the fuselage's apparent-mass pressure."""

    states: FlightStates
    flow_states: FlightStates
    kinematics: StripKinematics
    strip_cp: tuple[F64Array, ...]
    strip_traction: tuple[F64Array, ...]
    omega_dot: F64Array
    accel: F64Array

    def __len__(self) -> int:
        return len(self.states)


class AirframePressureModel:
    """Cp at every surface point of an :class:`AirframeGeometry` for any flight state.

    ``effects``: the airfoil simulator's effect names with their parameters (defaults fill the gaps; see
    :mod:`sim.airfoil.effects`); section effects apply strip by strip, ``incidence_offset`` to the
    aircraft's α, ``viscous_drag`` to all surfaces (truth only), ``port_lag``/``port_bias`` are
    measurement effects applied by the data set driver. ``separation``: per airfoil name the complete
    ``trailing_edge_separation`` parameters (calibrated per section family, see
    :func:`sim.airframe.simulate.complete_airframe_effects`); required for every airfoil when that effect
    is on. ``speed_m_s`` is the flow speed of the strip flows in :meth:`field_marched`.

    Quasi-steady: :meth:`evaluate_states` (Cp and truth coefficients), :meth:`cp_quasi_steady`,
    :meth:`coeffs`. Time histories: :meth:`simulate_motion`, or :meth:`field_marched` then
    :meth:`evaluate` in row chunks for huge N. :meth:`vlm_coeffs` gives the lattice's own loads.
    """

    def __init__(
        self,
        geometry: AirframeGeometry,
        *,
        effects: Mapping[str, Mapping[str, Any]] | None = None,
        separation: Mapping[str, Mapping[str, float]] | None = None,
        reference: Reference | None = None,
        vlm_resolution: VlmResolution | None = None,
        section_panels: int = DEFAULT_SECTION_PANELS,
        speed_m_s: float = 20.0,
    ) -> None:
        self.geometry = geometry
        unknown = set(effects or {}) - set(EFFECTS)
        if unknown:
            raise ValueError(f"unknown effects {sorted(unknown)}")
        # parameters left out take the documented defaults (the separation fit comes per airfoil below)
        self.effects = {
            k: dict(v) if k == "port_bias" else {**effect_defaults(k), **v} for k, v in (effects or {}).items()
        }
        self.reference = reference or geometry.default_reference()
        self.section_panels = section_panels
        self.speed_m_s = speed_m_s
        tes = "trailing_edge_separation" in self.effects
        airfoils = sorted({p.design.airfoil.lower() for p in geometry.parts})
        sep = {k.lower(): dict(v) for k, v in (separation or {}).items()}
        if tes:
            missing = [a for a in airfoils if a not in sep]
            if missing:
                raise ValueError(f"trailing_edge_separation needs calibrated parameters for {missing}")
        self.section_effects: dict[str, dict[str, dict[str, Any]]] = {}
        self.flows: dict[str, AirfoilFlow] = {}
        for af in airfoils:
            eff = {k: dict(v) for k, v in self.effects.items() if k not in AIRCRAFT_EFFECTS}
            if tes:
                eff["trailing_edge_separation"] = {**eff["trailing_edge_separation"], **sep[af]}
            self.section_effects[af] = eff
            self.flows[af] = AirfoilFlow(
                airfoil=af,
                n_panels=section_panels,
                chord_m=geometry.design.wing.mac_m,
                span_m=1.0,
                pivot_x_c=0.25,
                speed_m_s=speed_m_s,
                effects=eff,
            )

        section: dict[int, tuple[float, float]] = {}
        for part in geometry.parts:
            flow = self.flows[part.design.airfoil.lower()]
            slope = flow.param("trailing_edge_separation", "slope_factor") if tes else 1.0
            section[part.component] = (flow.cn_alpha * slope, flow.alpha_0l)
        self.vlm = VortexLattice(geometry.parts, section, vlm_resolution)
        self.force_matrix = force_moment_matrix(
            geometry.points_b, geometry.normals_b, geometry.areas_m2, self.reference
        )
        # unit tractions along the contour order: skin friction per point = traction · this column
        self._friction_matrix = force_moment_matrix(
            geometry.points_b, geometry.tangents_b, geometry.areas_m2, self.reference
        )
        self.groups = tuple(
            self._group(name, comps)
            for name, comps in (("wing", (WING_R, WING_L)), ("htail", (HTAIL_R, HTAIL_L)), ("vtail", (VTAIL,)))
        )
        self._init_fuselage()
        self._strip_flows: dict[int, AirfoilFlow] = {}

    # ------------------------------------------------------------------------------------ set-up
    def _group(self, name: str, comps: tuple[int, ...]) -> _Group:
        g = self.geometry
        pidx = tuple(i for i, p in enumerate(g.parts) if p.component in comps)
        flow = self.flows[g.parts[pidx[0]].design.airfoil.lower()]
        x_c, upper = g.chord_x_c[pidx[0]], g.chord_upper[pidx[0]]
        surface = flow.surface_at(locate_taps(flow.nodes, np.clip(x_c, 0.0, 1.0), upper))
        strips = np.concatenate([self.vlm.strips_of(i) for i in pidx])
        n_c = len(x_c)
        interp = []
        off = 0
        s_g = len(strips)
        p_agg = np.zeros((s_g * n_c, 6))
        f_agg = np.zeros((s_g * n_c, 6))
        fric = self._friction_matrix
        for i in pidx:
            eta_v = self.vlm.eta[self.vlm.strips_of(i)]
            eta_s = g.strip_eta[i]
            i1 = np.clip(np.searchsorted(eta_v, eta_s), 1, len(eta_v) - 1)
            i0 = i1 - 1
            w1 = np.clip((eta_s - eta_v[i0]) / (eta_v[i1] - eta_v[i0]), 0.0, 1.0)
            interp.append((i0 + off, i1 + off, 1.0 - w1, w1))
            sl = g.component_slice(g.parts[i].component)
            s_pts = self.force_matrix[:, sl].T.reshape(len(eta_s), n_c, 6)
            f_pts = fric[:, sl].T.reshape(len(eta_s), n_c, 6)
            rows0 = ((i0 + off)[:, None] * n_c + np.arange(n_c)[None, :]).ravel()
            rows1 = ((i1 + off)[:, None] * n_c + np.arange(n_c)[None, :]).ravel()
            for rows, w in ((rows0, 1.0 - w1), (rows1, w1)):
                np.add.at(p_agg, rows, (w[:, None, None] * s_pts).reshape(-1, 6))
                np.add.at(f_agg, rows, (w[:, None, None] * f_pts).reshape(-1, 6))
            off += len(eta_v)
        # thin-airfoil flap loading (Glauert): ΔCp = 4δ[(1 − θ_h/π)·cot(θ/2) + (1/π)·ln|sin((θ+θ_h)/2) /
        # sin((θ−θ_h)/2)|]; the cot part and the lift 2δ·sin θ_h of the log part are already in α_eff
        # (τ·δ), so the strips get the log part minus the equivalent incidence loading (zero net lift)
        has_flap = np.any(self.vlm.flap_map[strips] != 0.0, axis=1)
        edges = np.flatnonzero(np.diff(np.concatenate(([0], has_flap.astype(np.int8), [0]))))
        runs = tuple(slice(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2], strict=True))
        th = np.arccos(np.clip(1.0 - 2.0 * np.clip(x_c, 0.0, 1.0), -1.0, 1.0))[None, :]
        th_h = np.arccos(np.clip(1.0 - 2.0 * self.vlm.hinge_x_c[strips], -1.0, 1.0))[:, None]
        num = np.abs(np.sin(0.5 * (th + th_h)))
        den = np.sqrt(np.sin(0.5 * (th - th_h)) ** 2 + HINGE_ROUNDING**2)
        shape = (4.0 / math.pi) * np.log(num / den) * np.where(upper, -0.5, 0.5)[None, :] * has_flap[:, None]
        xi = 2.0 * surface.x_c - 1.0
        ps = flow.panel_surface
        tables = []
        for side in (False, True):
            sel = ps.upper == side
            order = np.argsort(ps.x_c[sel])
            tables.append((ps.x_c[sel][order], ps.ut0[sel][order], ps.ut90[sel][order]))
        return _Group(
            name=name,
            parts=pidx,
            flow=flow,
            surface=surface,
            strips=strips,
            flap_runs=runs,
            flap_shape=shape,
            flap_eps=2.0 * np.sin(th_h[:, 0]) / flow.cn_alpha * has_flap,
            added_mass_shape=np.where(surface.upper, -0.5, 0.5) * np.sqrt(np.clip(1.0 - xi * xi, 0.0, None)),
            suction_tables=(tables[0], tables[1]),
            interp=tuple(interp),
            pressure_agg=p_agg,
            friction_agg=f_agg,
        )

    def _init_fuselage(self) -> None:
        g = self.geometry
        fus = g.design.fuselage
        sl = g.component_slice(FUSELAGE)
        self._fus_slice = sl
        r = g.points_b[sl]
        n = g.normals_b[sl]
        self.k1, self.k2 = spheroid_added_mass(fus.length_m, fus.diameter_m)
        m = len(r)
        # U_air(r) = −u − ω × r = −u + [r]×·ω as a map of s = [u, v, w, p, q, r]; component-major columns
        # (d·m + i) so that each component is a contiguous (K, m) block
        x, y, z = r[:, 0], r[:, 1], r[:, 2]
        zero = np.zeros(m)
        lin = np.zeros((m, 3, 6))
        lin[:, :, 0:3] = -np.eye(3)[None]
        lin[:, :, 3:6] = np.stack(
            [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], axis=1
        )
        self._fus_u = np.ascontiguousarray(np.transpose(lin, (2, 1, 0)).reshape(6, -1))  # (6, 3·m)
        self._fus_n = np.ascontiguousarray(n.T)  # (3, m)
        self._fus_r = np.ascontiguousarray(r.T)
        r_perp = np.column_stack((zero, y, z - g.fuselage_axis_z_m))
        rn = np.linalg.norm(r_perp, axis=1)
        self._fus_rhat = np.ascontiguousarray((r_perp[:, 1:3] / np.maximum(rn, 1e-12)[:, None]).T)  # (2, m)
        # apparent mass: a·r_⊥ with a = a_cg + ω̇ × r → [a_cg, ω̇] · [r_⊥, r × r_⊥]
        self._fus_am = np.vstack([r_perp.T, np.cross(r, r_perp).T])  # (6, m)
        self._fus_area = g.areas_m2[sl]
        b1, b2 = 1.0 + self.k1, 1.0 + self.k2
        self._fus_ax2 = b1 * b1 * (1.0 - n[:, 0] ** 2)
        self._fus_cross = 2.0 * b1 * b2 * n[:, 0]
        self._fus_force = np.ascontiguousarray(self.force_matrix[:, sl].T)  # (m, 6)
        self._lref = np.array([self.reference.span_m, self.reference.chord_m, self.reference.span_m])
        half = 0.5 * CROSSFLOW_BLEND_DEG
        self._fus_cos_band = (
            math.cos(math.radians(CROSSFLOW_SEPARATION_DEG + half)),
            math.cos(math.radians(CROSSFLOW_SEPARATION_DEG - half)),
        )
        lo, hi = CROSSFLOW_ONSET_DEG
        self._fus_sin2_band = (math.sin(math.radians(lo)) ** 2, math.sin(math.radians(hi)) ** 2)

    def strip_flow(self, strip: int) -> AirfoilFlow:
        """The 2-D flow of one lattice strip for time marching: its chord, its pitch axis through the CG
        (projected on the chord) and the model speed."""
        if strip not in self._strip_flows:
            part = self.geometry.parts[int(self.vlm.part_index[strip])]
            af = part.design.airfoil.lower()
            self._strip_flows[strip] = AirfoilFlow(
                airfoil=af,
                n_panels=self.section_panels,
                chord_m=float(self.vlm.chord_m[strip]),
                span_m=1.0,
                pivot_x_c=float(self.vlm.pivot_x_c[strip]),
                speed_m_s=self.speed_m_s,
                effects=self.section_effects[af],
            )
        return self._strip_flows[strip]

    # --------------------------------------------------------------------------------- the flow
    def flow_states(self, states: FlightStates) -> FlightStates:
        """The states the flow sees: α + ``incidence_offset`` (the recorded α is unchanged)."""
        if "incidence_offset" not in self.effects:
            return states
        d = math.radians(float(self.effects["incidence_offset"]["delta_deg"]))
        return replace(states, alpha_rad=states.alpha_rad + d)

    def _static_state(self, flow: AirfoilFlow, alpha_e: F64Array, nc_a: F64Array) -> FlowState:
        """The steady state of the 2-D model at effective incidence ``alpha_e`` (flattened samples)."""
        eff = flow.effects
        if "lift_slope_scale" in eff:
            alpha_e = flow.alpha_0l + flow.param("lift_slope_scale", "scale") * (alpha_e - flow.alpha_0l)
        rel = alpha_e - flow.alpha_0l
        if "trailing_edge_separation" in eff:
            p = eff["trailing_edge_separation"]
            f = f_static(rel, p["alpha1_deg"], p["s1_deg"], p["s2_deg"])
            rel_r = np.arcsin(np.clip(p["slope_factor"] * kirchhoff_factor(f) * np.sin(rel), -1.0, 1.0))
        else:
            f, rel_r = np.ones_like(rel), rel
        k = len(alpha_e)
        return FlowState(
            alpha_e=alpha_e,
            alpha_r=flow.alpha_0l + rel_r,
            x_sep=np.asarray(f, dtype=np.float64),
            suction_upper=np.asarray(rel_r >= 0.0),
            cn_prime=flow.cn_attached(alpha_e),
            lev_cn=np.zeros(k),
            lev_x=np.full(k, np.nan),
            nc_a=nc_a,
            nc_b=np.zeros(k),
        )

    def _strip_stage(
        self,
        grp: _Group,
        st: FlowState,
        kin: StripKinematics,
        k: int,
        buf: ScratchBuffers,
        base_cp: F64Array | None = None,
    ) -> tuple[F64Array, F64Array]:
        """Strip Cp and skin-friction traction (k, S_g, n_c) of a group on the freestream dynamic pressure.

        ``st`` holds the k·S_g strip flow states (sample-major). Without ``base_cp`` the section Cp is
        :meth:`AirfoilFlow.cp` of a state without vortex and with ``nc_b = 0`` (the quasi-steady case),
        evaluated in place (tests check it against ``cp()``); ``base_cp`` (k·S_g, n_c) is a ``cp()`` result
        (time marching). Then the flap shape correction, the (V_local/V)² scaling and the friction
        traction cf·u|u| on the attached surface, signed along the contour order.
        """
        flow, surf = grp.flow, grp.surface
        s_g, n_c = len(grp.strips), len(surf.x_c)
        shape3 = (k, s_g, n_c)
        tes = "trailing_edge_separation" in flow.effects
        viscous = "viscous_drag" in self.effects
        g = grp.name
        alpha_r = st.alpha_r.reshape(k, s_g, 1)
        ca, sa = np.cos(alpha_r), np.sin(alpha_r)
        u = buf.get(g + "u", shape3)
        t1 = buf.get(g + "t1", shape3)
        t2 = buf.get(g + "t2", shape3)
        np.multiply(ca, surf.ut0, out=u)
        np.multiply(sa, surf.ut90, out=t1)
        u += t1  # signed surface speed / V_local of the circulation-reduced potential flow
        w = None
        if tes:
            # plateau weight: smoothstep over PLATEAU_BLEND_C aft of x_sep, suction side only
            w = buf.get(g + "w", shape3)
            np.subtract(surf.x_c, st.x_sep.reshape(k, s_g, 1), out=w)
            w *= 1.0 / PLATEAU_BLEND_C
            np.clip(w, 0.0, 1.0, out=w)
            np.multiply(w, w, out=t1)
            w *= -2.0
            w += 3.0
            w *= t1
            mask = buf.get(g + "m", shape3, np.bool_)
            np.equal(surf.upper, st.suction_upper.reshape(k, s_g, 1), out=mask)
            np.multiply(w, mask, out=w)
        cp = buf.get(g + "cp", shape3)
        if base_cp is None:
            np.multiply(u, u, out=cp)
            np.subtract(1.0, cp, out=cp)
            if w is not None:
                plateau = self._plateau(grp, st).reshape(k, s_g, 1)
                np.subtract(plateau, cp, out=t1)
                t1 *= w
                cp += t1
            if "added_mass" in flow.effects:
                np.multiply(st.nc_a.reshape(k, s_g, 1), grp.added_mass_shape, out=t1)
                cp += t1
        else:
            cp[...] = base_cp.reshape(shape3)
        flap = kin.flap[:, grp.strips]
        for run in grp.flap_runs:
            fl = flap[:, run, None]
            if not np.any(fl):
                continue
            # corr = shape − ε·dCp/dα with dCp/dα = −2u·(cos α·ut90 − sin α·ut0)
            d, e = t1[:, run], t2[:, run]
            np.multiply(ca[:, run], surf.ut90, out=d)
            np.multiply(sa[:, run], surf.ut0, out=e)
            d -= e
            d *= u[:, run]
            d *= (2.0 * grp.flap_eps[run])[None, :, None]
            d += grp.flap_shape[None, run]
            if w is not None:
                # flap loading fades with the Kirchhoff factor and vanishes under the separated plateau
                np.subtract(1.0, w[:, run], out=e)
                d *= e
                d *= kirchhoff_factor(st.x_sep.reshape(k, s_g, 1)[:, run])
            d *= fl
            cp[:, run] += d
            np.minimum(cp[:, run], 1.0, out=cp[:, run])
        q_ratio = (kin.speed_ratio[:, grp.strips] ** 2)[..., None]
        cp *= q_ratio
        traction = buf.get(g + "tr", shape3)
        if viscous:
            np.abs(u, out=traction)
            traction *= u
            if w is not None:
                np.subtract(1.0, w, out=t1)
                traction *= t1
            traction *= float(self.effects["viscous_drag"]["cf"]) * q_ratio
        else:
            traction[...] = 0.0
        return cp, traction

    @staticmethod
    def _plateau(grp: _Group, st: FlowState) -> F64Array:
        """Separated-plateau Cp per strip state: the attached pressure at x_sep on the suction side,
        bounded by the base pressure (as in :meth:`AirfoilFlow.cp`)."""
        out = np.empty(len(st.alpha_r))
        for side, (xs, u0, u90) in zip((False, True), grp.suction_tables, strict=True):
            m = st.suction_upper == side
            a = st.alpha_r[m]
            us = np.cos(a) * np.interp(st.x_sep[m], xs, u0) + np.sin(a) * np.interp(st.x_sep[m], xs, u90)
            out[m] = np.maximum(1.0 - us * us, CP_BASE)
        return out

    def _field_quasi_steady(self, states: FlightStates, buf: ScratchBuffers) -> SurfaceField:
        fs = self.flow_states(states)
        kin = self.vlm.kinematics(fs)
        k = len(states)
        cps, trs = [], []
        for grp in self.groups:
            s_g = len(grp.strips)
            a_e = kin.alpha_eff[:, grp.strips].reshape(-1)
            if "added_mass" in grp.flow.effects:
                scale = grp.flow.param("added_mass", "scale")
                nc_a = scale * 2.0 * self.vlm.chord_m[grp.strips][None, :] * kin.rate[:, grp.strips]
                nc_a = (nc_a / kin.speed[:, grp.strips]).reshape(-1)
            else:
                nc_a = np.zeros(k * s_g)
            st = self._static_state(grp.flow, a_e, nc_a)
            cp, tr = self._strip_stage(grp, st, kin, k, buf)
            cps.append(cp)
            trs.append(tr)
        return SurfaceField(
            states=states,
            flow_states=fs,
            kinematics=kin,
            strip_cp=tuple(cps),
            strip_traction=tuple(trs),
            omega_dot=np.zeros((k, 3)),
            accel=fs.accel_cg_b(),
        )

    def field_quasi_steady(self, states: FlightStates) -> SurfaceField:
        """The quasi-steady surface field of K independent states (history effects at steady state)."""
        return self._field_quasi_steady(states, ScratchBuffers())

    def field_marched(self, t: F64Array, states: FlightStates, *, warmup: int = 0) -> SurfaceField:
        """The surface field along a time history: every lattice strip runs the unsteady 2-D model on
        its own α_eff(t) (pitch axis through the CG, so the rate terms are the strip's real motion).

        ``states`` are sampled at times ``t`` [s] (strictly increasing, one speed = ``speed_m_s``);
        derivatives (section incidence accelerations, ω̇) are taken numerically. The lags start from
        rest: the first ``warmup`` samples settle them and are dropped from the result.
        """
        t = np.asarray(t, dtype=np.float64)
        if len(t) != len(states):
            raise ValueError(f"t has {len(t)} samples but states has {len(states)}")
        if not np.allclose(states.airspeed_m_s, self.speed_m_s, rtol=1e-6):
            raise ValueError(f"field_marched needs airspeed = the model speed {self.speed_m_s} m/s")
        fs = self.flow_states(states)
        kin = self.vlm.kinematics(fs)
        k = len(states)
        rate_dot = np.gradient(kin.rate, t, axis=0) if k > 1 else np.zeros_like(kin.rate)
        v = self.speed_m_s
        cps, trs = [], []
        for grp in self.groups:
            s_g = len(grp.strips)
            per_strip: list[FlowState] = []
            cp_rows = np.empty((k, s_g, len(grp.surface.x_c)))
            for j, strip in enumerate(grp.strips):
                flow = self.strip_flow(int(strip))
                rate = kin.rate[:, strip]
                # the flow adds rate·c·(3/4 − x_p)/V back: α_34 then equals the lattice's α_eff
                a_in = kin.alpha_eff[:, strip] - rate * flow.chord_m * (0.75 - flow.pivot_x_c) / v
                st = flow.march(t, a_in, rate, rate_dot[:, strip])
                per_strip.append(st)
                cp_rows[:, j, :] = flow.cp(st, grp.surface)
            # (K·S_g) sample-major flattening, the layout _strip_stage expects
            st_all = FlowState(
                **{
                    name: np.stack([np.asarray(getattr(s, name)) for s in per_strip], axis=1).reshape(-1)
                    for name in FlowState.__dataclass_fields__
                }
            )
            cp, tr = self._strip_stage(grp, st_all, kin, k, ScratchBuffers(), cp_rows.reshape(k * s_g, -1))
            cps.append(cp[warmup:])
            trs.append(tr[warmup:])
        rates = fs.rates_b()
        omega_dot = np.gradient(rates, t, axis=0) if k > 1 else np.zeros_like(rates)
        keep = slice(warmup, None)
        kin_kept = StripKinematics(**{n: getattr(kin, n)[keep] for n in StripKinematics.__dataclass_fields__})
        return SurfaceField(
            states=states.take(keep),
            flow_states=fs.take(keep),
            kinematics=kin_kept,
            strip_cp=tuple(cps),
            strip_traction=tuple(trs),
            omega_dot=omega_dot[keep],
            accel=fs.accel_cg_b()[keep],
        )

    # ------------------------------------------------------------------------------- assembling
    def _fuselage(self, field: SurfaceField, rows: slice, buf: ScratchBuffers) -> tuple[F64Array, F64Array]:
        """Fuselage Cp (k, m) and its truth coefficients (k, 6): pressure integral plus skin friction.

        Spheroid surface velocity u_e = P_t[(1+k1)·U_x e_x + (1+k2)·U_⊥] (P_t = I − n nᵀ) in closed form:
        with nU = n·U_⊥, |u_e|² = (1+k1)²(1−n_x²)U_x² + (1+k2)²(|U_⊥|² − nU²) − 2(1+k1)(1+k2)·n_x·U_x·nU.
        In place on scratch buffers (see :class:`ScratchBuffers`).
        """
        fs = field.flow_states.take(rows)
        vinf = fs.airspeed_m_s
        s = np.hstack([fs.velocity_b(), fs.rates_b()]) / vinf[:, None]  # everything below is per V
        k = len(vinf)
        m = self._fus_slice.stop - self._fus_slice.start
        nx, ny, nz = self._fus_n
        b1, b2 = 1.0 + self.k1, 1.0 + self.k2
        u = buf.get("f_u", (k, 3 * m))
        np.matmul(s, self._fus_u, out=u)
        ux, uy, uz = (u[:, i * m : (i + 1) * m] for i in range(3))
        nu, ucr2, vax2, vs2, t1, t2, w, cp = (buf.get(f"f_{i}", (k, m)) for i in range(8))
        np.multiply(uy, ny, out=nu)
        np.multiply(uz, nz, out=t1)
        nu += t1
        np.multiply(uy, uy, out=ucr2)
        np.multiply(uz, uz, out=t1)
        ucr2 += t1
        np.multiply(ux, ux, out=vax2)
        vax2 *= self._fus_ax2
        np.multiply(nu, nu, out=vs2)
        np.subtract(ucr2, vs2, out=vs2)
        vs2 *= b2 * b2
        vs2 += vax2
        np.multiply(ux, nu, out=t1)
        t1 *= self._fus_cross
        vs2 -= t1
        # leeward separation: polar angle θ from the windward stagnation line beyond CROSSFLOW_SEPARATION_DEG,
        # switched on by the local crossflow angle; blends written in cos θ and sin²α_c (no inverse trig)
        rh = self._fus_rhat
        np.multiply(uy, rh[0], out=w)
        np.multiply(uz, rh[1], out=t1)
        w += t1
        np.maximum(ucr2, 1e-24, out=t1)
        np.sqrt(t1, out=t1)
        np.divide(w, t1, out=w)  # = −cos θ
        c_lo, c_hi = self._fus_cos_band
        w += c_hi
        w *= 1.0 / (c_hi - c_lo)
        _smoothstep_inplace(w, t1)
        np.multiply(ux, ux, out=t2)
        t2 += ucr2
        np.maximum(t2, 1e-24, out=t2)
        np.divide(ucr2, t2, out=t2)  # sin²α_c
        s2_lo, s2_hi = self._fus_sin2_band
        t2 -= s2_lo
        t2 *= 1.0 / (s2_hi - s2_lo)
        _smoothstep_inplace(t2, t1)
        w *= t2
        np.subtract(vs2, vax2, out=cp)
        np.multiply(ucr2, CROSSFLOW_BASE_CP, out=t1)
        cp += t1
        cp *= w
        cp -= vs2
        cp += 1.0
        if "added_mass" in self.effects:
            acc = np.hstack([field.accel[rows], field.omega_dot[rows]])
            scale = float(self.effects["added_mass"]["scale"])
            np.matmul(acc * ((scale * 2.0 * self.k2) / (vinf * vinf))[:, None], self._fus_am, out=t1)
            cp += t1
        coeffs = cp @ self._fus_force
        if "viscous_drag" in self.effects:
            # τ = cf·|u_e|·u_e on the attached part; u_e = (1+k1)U_x e_x + (1+k2)U_⊥ − n·c, c = (1+k1)n_x U_x + (1+k2)nU
            g = vs2
            np.sqrt(vs2, out=g)
            np.subtract(1.0, w, out=t1)
            g *= t1
            g *= float(self.effects["viscous_drag"]["cf"]) * self._fus_area
            c = nu
            c *= b2
            np.multiply(ux, b1 * nx, out=t1)
            c += t1
            a_ref = self.reference.area_m2
            rx, ry, rz = self._fus_r
            gv: list[F64Array] = []
            for comp, n_i, scale_i in ((ux, nx, b1), (uy, ny, b2), (uz, nz, b2)):
                v = buf.get(f"f_gv{len(gv)}", (k, m))
                np.multiply(comp, scale_i, out=v)
                np.multiply(c, n_i, out=t1)
                v -= t1
                v *= g
                gv.append(v)
            coeffs[:, 0] += gv[0].sum(axis=1) / a_ref
            coeffs[:, 1] += gv[1].sum(axis=1) / a_ref
            coeffs[:, 2] += gv[2].sum(axis=1) / a_ref
            coeffs[:, 3] += (gv[2] @ ry - gv[1] @ rz) / (a_ref * self._lref[0])
            coeffs[:, 4] += (gv[0] @ rz - gv[2] @ rx) / (a_ref * self._lref[1])
            coeffs[:, 5] += (gv[1] @ rx - gv[0] @ ry) / (a_ref * self._lref[2])
        return cp, np.asarray(coeffs)

    def evaluate(
        self,
        field: SurfaceField,
        rows: slice = slice(None),
        dtype: DTypeLike = np.float64,
        *,
        out: FloatArray | None = None,
        buf: ScratchBuffers | None = None,
    ) -> tuple[FloatArray, F64Array]:
        """Cp (k, N) at every surface point and the truth coefficients (k, 6) for the states ``rows`` of
        ``field`` (the fuselage is evaluated once for both). Chunk huge N by rows; ``out`` may be a
        preallocated (k, N) array (e.g. rows of a memory map)."""
        g = self.geometry
        buf = buf or ScratchBuffers()
        idx = range(len(field))[rows]
        k = len(idx)
        cp_out = np.empty((k, g.n_points), dtype=dtype) if out is None else out
        coeffs = np.zeros((k, 6))
        for grp, cpg, trg in zip(self.groups, field.strip_cp, field.strip_traction, strict=True):
            c = cpg[rows]
            coeffs += c.reshape(k, -1) @ grp.pressure_agg
            coeffs += trg[rows].reshape(k, -1) @ grp.friction_agg
            for ip, (i0, i1, w0, w1) in zip(grp.parts, grp.interp, strict=True):
                sl = g.component_slice(g.parts[ip].component)
                blk = cp_out[:, sl].reshape(k, len(w0), -1)  # a view: the component's points are strip-major
                tmp = buf.get("gather", blk.shape)
                np.take(c, i0, axis=1, out=tmp)
                np.multiply(tmp, w0[None, :, None], out=blk)
                np.take(c, i1, axis=1, out=tmp)
                tmp *= w1[None, :, None]
                blk += tmp
        cp_f, c_f = self._fuselage(field, rows, buf)
        cp_out[:, self._fus_slice] = cp_f
        return cp_out, coeffs + c_f

    def assemble_cp(self, field: SurfaceField, rows: slice = slice(None), dtype: DTypeLike = np.float64) -> FloatArray:
        """Cp (k, N) at every surface point for the states ``rows`` of ``field``."""
        return self.evaluate(field, rows, dtype)[0]

    def truth_coeffs(self, field: SurfaceField) -> F64Array:
        """Ground-truth body-axis coefficients (K, 6): the pressure integral over all points (lifting
        surfaces from the strip field, identical to ``cp @ S.T``) plus skin friction; the cost does not
        depend on the lifting-surface resolution."""
        k = len(field)
        out = np.zeros((k, 6))
        buf = ScratchBuffers()
        for a in range(0, k, BLOCK_STATES):
            rows = slice(a, min(a + BLOCK_STATES, k))
            for grp, cpg, trg in zip(self.groups, field.strip_cp, field.strip_traction, strict=True):
                n = rows.stop - rows.start
                out[rows] += cpg[rows].reshape(n, -1) @ grp.pressure_agg + trg[rows].reshape(n, -1) @ grp.friction_agg
            out[rows] += self._fuselage(field, rows, buf)[1]
        return out

    # ---------------------------------------------------------------------------------- public
    def evaluate_states(
        self, states: FlightStates, dtype: DTypeLike = np.float64, *, out: FloatArray | None = None
    ) -> tuple[FloatArray, F64Array]:
        """Quasi-steady Cp (K, N) at every surface point and truth coefficients (K, 6), in blocks of
        :data:`BLOCK_STATES` states. ``out`` may be a preallocated (K, N) array."""
        k = len(states)
        cp = np.empty((k, self.geometry.n_points), dtype=dtype) if out is None else out
        coeffs = np.empty((k, 6))
        buf = ScratchBuffers()
        for a in range(0, k, BLOCK_STATES):
            rows = slice(a, min(a + BLOCK_STATES, k))
            field = self._field_quasi_steady(states.take(rows), buf)
            coeffs[rows] = self.evaluate(field, out=cp[rows], buf=buf)[1]
        return cp, coeffs

    def cp_quasi_steady(self, states: FlightStates, dtype: DTypeLike = np.float64) -> FloatArray:
        """Quasi-steady Cp (K, N) at every surface point (see :meth:`evaluate_states`)."""
        return self.evaluate_states(states, dtype)[0]

    def coeffs(self, states: FlightStates, cp: FloatArray) -> F64Array:
        """Truth coefficients (K, 6) of quasi-steady states with their Cp (K, N): the pressure integral of
        ``cp`` plus the skin friction of the states' flow."""
        k = len(states)
        fric = np.zeros((k, 6))
        buf = ScratchBuffers()
        for a in range(0, k, BLOCK_STATES):
            rows = slice(a, min(a + BLOCK_STATES, k))
            field = self._field_quasi_steady(states.take(rows), buf)
            n = rows.stop - rows.start
            for grp, trg in zip(self.groups, field.strip_traction, strict=True):
                fric[rows] += trg.reshape(n, -1) @ grp.friction_agg
            cp_f, c_f = self._fuselage(field, slice(None), buf)
            fric[rows] += c_f - cp_f @ self._fus_force
        return np.asarray(np.asarray(cp, dtype=np.float64) @ self.force_matrix.T + fric)

    def vlm_coeffs(self, states: FlightStates) -> F64Array:
        """Kutta–Joukowski coefficients (K, 6) of the lattice (lifting surfaces, no fuselage)."""
        return self.vlm.loads(self.flow_states(states), self.reference)

    def simulate_motion(
        self, t: F64Array, states: FlightStates, *, warmup: int = 0
    ) -> tuple[FloatArray, F64Array, SurfaceField]:
        """Cp (K, N), truth coefficients (K, 6) and the field along a time history (see
        :meth:`field_marched`); for huge N use the field with :meth:`assemble_cp` in row chunks."""
        field = self.field_marched(t, states, warmup=warmup)
        cp = np.empty((len(field), self.geometry.n_points))
        coeffs = np.empty((len(field), 6))
        buf = ScratchBuffers()
        for a in range(0, len(field), BLOCK_STATES):
            rows = slice(a, min(a + BLOCK_STATES, len(field)))
            coeffs[rows] = self.evaluate(field, rows, out=cp[rows], buf=buf)[1]
        return cp, coeffs, field

    def point_mask(self, components: tuple[int, ...]) -> BoolArray:
        """Boolean mask (N,) of the points on the given components."""
        return np.isin(self.geometry.component, components)


def benchmark_states_per_second(
    n_points: int = 2000, n_states: int = 20000, chunk: int = 2000, seed: int = 0, repeats: int = 3
) -> dict[str, float]:
    """Quasi-steady throughput: Cp at all points plus the truth coefficients of random flight states.

    The model (default airframe at ``n_points``, static separation and skin friction on, fixed
    separation parameters so no calibration runs) is built outside the timing; the best of ``repeats``
    runs over ``n_states`` states in chunks of ``chunk`` is reported. Bar: ≥ 10,000 states/s at N = 2,000.
    """
    geo = build_geometry(default_design(), surface_for(n_points))
    sep = {"alpha1_deg": 12.0, "s1_deg": 2.5, "s2_deg": 3.0, "slope_factor": 0.9}
    effects = {"trailing_edge_separation": {}, "added_mass": {"scale": 1.0}, "viscous_drag": {"cf": 0.003}}
    airfoils = {p.design.airfoil.lower() for p in geo.parts}
    t_build = time.perf_counter()
    model = AirframePressureModel(geo, effects=effects, separation={a: sep for a in airfoils})
    t_build = time.perf_counter() - t_build
    rng = np.random.default_rng(seed)
    states = FlightStates(
        airspeed_m_s=rng.uniform(12.0, 30.0, n_states),
        alpha_rad=np.radians(rng.uniform(-6.0, 20.0, n_states)),
        beta_rad=np.radians(rng.uniform(-10.0, 10.0, n_states)),
        p_rad_s=rng.uniform(-1.5, 1.5, n_states),
        q_rad_s=rng.uniform(-1.0, 1.0, n_states),
        r_rad_s=rng.uniform(-0.8, 0.8, n_states),
        alpha_dot_rad_s=rng.uniform(-1.0, 1.0, n_states),
        aileron_rad=np.radians(rng.uniform(-20.0, 20.0, n_states)),
        elevator_rad=np.radians(rng.uniform(-20.0, 20.0, n_states)),
        rudder_rad=np.radians(rng.uniform(-20.0, 20.0, n_states)),
    )
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for a in range(0, n_states, chunk):
            model.evaluate_states(states.take(slice(a, a + chunk)))
        best = min(best, time.perf_counter() - t0)
    return {
        "n_points": float(geo.n_points),
        "n_states": float(n_states),
        "seconds": best,
        "states_per_second": n_states / best,
        "build_seconds": t_build,
    }
