"""Unsteady surface-pressure model of a pitching airfoil.

Steady potential flow (linear-vorticity panel method, superposition of the α = 0° and 90° unit
solutions) is the backbone; unsteady, viscous and separated effects act on it *as pressure
distributions*, never only on integrated forces, so that pressure ports see them:

1. incidence seen by the flow: α_g = α + δ (``incidence_offset``) and the 3/4-chord downwash of the
   pitch rate, α_34 = α_g + α̇·c·(3/4 − x_p)/V (thin-airfoil quasi-steady theory);
2. ``circulation_lag``: Wagner indicial lag of α_34 (Jones' approximation) → effective incidence α_E;
3. ``lift_slope_scale``: α_E ← α_0L + k·(α_E − α_0L);
4. ``trailing_edge_separation`` (+ ``separation_lag``): Kirchhoff separation point f from the
   Beddoes exponential fit driven by the lagged normal force; the circulation is reduced by
   κ·((1+√f)/2)² (reduced incidence α_r; κ the viscous lift-slope factor) and the suction side aft of
   x_sep = f·c carries a pressure plateau (the attached pressure at x_sep, bounded by the base
   pressure ``CP_BASE``), blended over ``PLATEAU_BLEND_C`` of chord;
5. ``leading_edge_vortex``: Beddoes–Leishman vortex, a Gaussian suction bump convecting along the
   suction side, whose normal force lags towards the lift the separated flow lost;
6. ``added_mass``: flat-plate apparent-mass loading normalised to Theodorsen's lift;
7. ``viscous_drag``: skin friction on attached panels, returned separately (truth-only).

Times inside the recursions are in semichords, s = 2·V·t/c. Arrays are (K,) per sample and
(K, n) per sample and surface point.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.airfoil.naca import SurfaceGeometry, naca4_nodes, surface_geometry
from sim.airfoil.panel import PanelSolution, solve_panels
from vdm_aero._typing import BoolArray, F64Array
from vdm_aero.coefficients import force_moment_matrix
from vdm_aero.dataset import Reference

# Jones' two-exponential approximation of Wagner's function: φ(s) = 1 − A1 e^{−b1 s} − A2 e^{−b2 s}.
WAGNER_A1, WAGNER_B1 = 0.165, 0.0455
WAGNER_A2, WAGNER_B2 = 0.335, 0.3
PLATEAU_BLEND_C = 0.04  # chord fraction over which attached pressure blends into the separated plateau
# Separated-region (base) pressure bound: the plateau takes the attached pressure at x_sep, but never
# more suction than a bluff-body base pressure (Roshko's modified free-streamline theory; flat plates
# at high incidence show Cp_b ≈ −0.5 … −1). Without it a separation point near the LE would spread
# the suction peak over the whole separated region.
CP_BASE = -0.6
LEV_WIDTH_C = (0.06, 0.14)  # Gaussian half-width of the vortex bump at the LE and at the TE [chord]
F_MIN = 0.0  # fully separated
MAX_STEP_SEMICHORDS = 0.5  # internal step of the lag/vortex recursions (Tp ≈ 1.7 is the shortest constant)


def f_static(alpha_rel: F64Array, alpha1_deg: float, s1_deg: float, s2_deg: float) -> F64Array:
    """Beddoes' exponential fit of the Kirchhoff separation point f(α) (1 = attached at the TE).

    ``alpha_rel`` is the incidence above the zero-lift angle [rad]; symmetric in its sign.
    """
    a = np.degrees(np.abs(alpha_rel))
    below = 1.0 - 0.3 * np.exp((a - alpha1_deg) / s1_deg)
    above = 0.04 + 0.66 * np.exp((alpha1_deg - a) / s2_deg)
    return np.clip(np.where(a <= alpha1_deg, below, above), 0.0, 1.0)


def kirchhoff_factor(f: F64Array) -> F64Array:
    """Normal-force factor of a flat plate separated at x/c = f: ((1+√f)/2)²."""
    return ((1.0 + np.sqrt(np.clip(f, 0.0, 1.0))) / 2.0) ** 2


@dataclass(frozen=True)
class EvalSurface:
    """Points where Cp is evaluated: chordwise station, side, and the two unit tangential speeds."""

    x_c: F64Array
    upper: BoolArray
    ut0: F64Array
    ut90: F64Array


@dataclass(frozen=True)
class FlowState:
    """Per-sample state of the flow that the pressure field is built from. All (K,)."""

    alpha_e: F64Array  # effective circulatory incidence [rad]
    alpha_r: F64Array  # incidence whose potential flow carries the (reduced) circulation [rad]
    x_sep: F64Array  # separation point on the suction side [chord]; 1 = attached
    suction_upper: BoolArray
    cn_prime: F64Array  # lagged attached normal force (drives separation and vortex onset)
    lev_cn: F64Array  # vortex normal-force contribution
    lev_x: F64Array  # vortex centre [chord]; may exceed 1 once shed past the TE
    nc_a: F64Array  # apparent-mass loading amplitude of the V·α̇ term
    nc_b: F64Array  # apparent-mass loading amplitude of the b·α̈ term


def _deficiency(u: F64Array, decay: F64Array, gain: F64Array) -> F64Array:
    """D_n = D_{n−1}·decay_n + gain_n·(u_n − u_{n−1}), D_0 = 0 (Leishman's recursive deficiency).

    A pure-Python loop over floats: the recursion is sequential and ~1 µs per step this way.
    """
    out = [0.0] * len(u)
    d = 0.0
    ul, dl, gl = u.tolist(), decay.tolist(), gain.tolist()
    for n in range(1, len(ul)):
        d = d * dl[n] + gl[n] * (ul[n] - ul[n - 1])
        out[n] = d
    return np.asarray(out)


class AirfoilFlow:
    """The pressure model of one airfoil at one speed, with a set of effects switched on.

    ``effects`` maps effect names (see :mod:`sim.airfoil.effects`) to complete parameter dicts;
    ``trailing_edge_separation`` must carry ``alpha1_deg``, ``s1_deg`` and ``s2_deg`` already
    (see :func:`sim.airfoil.separation.complete_effects`).
    """

    def __init__(
        self,
        *,
        airfoil: str,
        n_panels: int,
        chord_m: float,
        span_m: float,
        pivot_x_c: float,
        speed_m_s: float,
        effects: Mapping[str, Mapping[str, Any]],
    ) -> None:
        self.chord_m = chord_m
        self.span_m = span_m
        self.pivot_x_c = pivot_x_c
        self.speed_m_s = speed_m_s
        self.effects = {k: dict(v) for k, v in effects.items()}
        self.nodes = naca4_nodes(airfoil.lower().removeprefix("naca"), n_panels)
        self.geometry: SurfaceGeometry = surface_geometry(
            self.nodes, chord_m=chord_m, span_m=span_m, pivot_x_c=pivot_x_c
        )
        self.panels: PanelSolution = solve_panels(self.nodes)
        self.reference = Reference(area_m2=chord_m * span_m, chord_m=chord_m, span_m=span_m)
        g = self.geometry
        self.panel_surface = EvalSurface(
            x_c=np.asarray(g.mid_xc[:, 0], dtype=np.float64),
            upper=np.asarray(g.upper, dtype=bool),
            ut0=np.asarray(self.panels.ut0, dtype=np.float64),
            ut90=np.asarray(self.panels.ut90, dtype=np.float64),
        )
        # C_N(α) = Σ u² n_z,in l/c is quadratic in (cos α, sin α) because Σ n_z l = 0 on a closed contour.
        w = np.asarray(g.normals_b[:, 2] * g.length_c, dtype=np.float64)
        u0, u90 = self.panel_surface.ut0, self.panel_surface.ut90
        self._cn_q = (float(w @ (u0 * u0)), float(w @ (2 * u0 * u90)), float(w @ (u90 * u90)))
        self.alpha_0l = float(math.atan2(-self.panels.circulation0, self.panels.circulation90))
        h = 1e-5
        self.cn_alpha = float((self.cn_attached(self.alpha_0l + h) - self.cn_attached(self.alpha_0l - h)) / (2 * h))
        # table to invert C_N^C(α) (monotone over ±60°): the incidence whose attached normal force is C_N'
        self._inv_alpha = self.alpha_0l + np.radians(np.linspace(-60.0, 60.0, 2401))
        self._inv_cn = self.cn_attached(self._inv_alpha)
        self.force_matrix = force_moment_matrix(g.points_b, g.normals_b, g.areas_m2, self.reference)
        d = np.diff(self.nodes, axis=0)
        t_af = d / np.linalg.norm(d, axis=1)[:, None]
        tangents_b = np.stack([-t_af[:, 0], np.zeros(len(t_af)), -t_af[:, 1]], axis=1)
        self.friction_matrix = force_moment_matrix(g.points_b, tangents_b, g.areas_m2, self.reference)
        self._suction_tables = {side: self._side_table(side) for side in (True, False)}

    def with_effects(self, effects: Mapping[str, Mapping[str, Any]]) -> AirfoilFlow:
        """The same airfoil (geometry and panel solution reused) with another complete effect set."""
        other = copy.copy(self)
        other.effects = {k: dict(v) for k, v in effects.items()}
        return other

    # ----------------------------------------------------------------------------------------- helpers
    def _side_table(self, upper: bool) -> tuple[F64Array, F64Array, F64Array]:
        s = self.panel_surface
        m = s.upper == upper
        order = np.argsort(s.x_c[m])
        return s.x_c[m][order], s.ut0[m][order], s.ut90[m][order]

    def cn_attached(self, alpha: F64Array | float) -> F64Array:
        """Normal-force coefficient of the attached potential flow at incidence ``alpha`` [rad]."""
        a = np.asarray(alpha, dtype=np.float64)
        c, s = np.cos(a), np.sin(a)
        q0, q1, q2 = self._cn_q
        return np.asarray(q0 * c * c + q1 * s * c + q2 * s * s)

    def surface_at(self, s_c: F64Array) -> EvalSurface:
        """An evaluation surface at arc-length stations ``s_c`` (e.g. pressure taps)."""
        ut0, ut90 = self.panels.interpolate(s_c)
        ref = self.panel_surface
        # x/c and side at the query points, interpolated along the same arc length
        s_mid = np.asarray(self.geometry.s_c, dtype=np.float64)
        x = np.interp(s_c, s_mid, ref.x_c)
        s_le = float(s_mid[np.argmin(ref.x_c)])
        return EvalSurface(
            x_c=np.asarray(x, dtype=np.float64),
            upper=np.asarray(s_c < s_le),
            ut0=np.asarray(ut0, dtype=np.float64),
            ut90=np.asarray(ut90, dtype=np.float64),
        )

    def param(self, effect: str, name: str) -> float:
        return float(self.effects[effect][name])

    # ------------------------------------------------------------------------------------------- march
    def march(self, t: F64Array, alpha: F64Array, alpha_dot: F64Array, alpha_ddot: F64Array) -> FlowState:
        """Integrate the unsteady states along a motion sampled at times ``t`` [s].

        The recursions run on an internal grid of at most ``MAX_STEP_SEMICHORDS`` (inputs linearly
        interpolated between samples) so that lag and vortex timing do not depend on how densely the
        caller samples; the states are returned at the caller's samples.

        ``alpha`` [rad], ``alpha_dot`` [rad/s], ``alpha_ddot`` [rad/s²] are the recorded geometric
        incidence and its derivatives. States start from rest at the first sample: callers prepend a
        warm-up (one cycle for periodic motions) and drop it.
        """
        V, c = self.speed_m_s, self.chord_m
        t = np.asarray(t, dtype=np.float64)
        if len(t) > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("sample times must increase strictly")
        # refine: each sample interval split into enough sub-steps to keep Δs ≤ MAX_STEP_SEMICHORDS
        ds_samples = np.diff(t) * 2.0 * V / c
        sub = np.maximum(1, np.ceil(ds_samples / MAX_STEP_SEMICHORDS).astype(np.int64))
        idx = np.concatenate([[0], np.cumsum(sub)])  # position of each caller sample on the fine grid
        # sample i's sub-steps at i + j/k_i, j < k_i (vectorised: the same two float operations per point as
        # the per-sample aranges it replaces, which took a quarter of the discovery workflow's time)
        start = np.repeat(idx[:-1], sub)
        k_rep = np.repeat(sub, sub)
        frac = np.append((np.arange(idx[-1]) - start) / k_rep + np.repeat(np.arange(len(sub)), sub), len(t) - 1.0)
        tf_ = np.interp(frac, np.arange(len(t)), t)
        full = self._march_fine(
            tf_,
            np.interp(frac, np.arange(len(t)), alpha),
            np.interp(frac, np.arange(len(t)), alpha_dot),
            np.interp(frac, np.arange(len(t)), alpha_ddot),
        )
        return FlowState(**{k: np.asarray(getattr(full, k))[idx] for k in FlowState.__dataclass_fields__})

    def _march_fine(self, t: F64Array, alpha: F64Array, alpha_dot: F64Array, alpha_ddot: F64Array) -> FlowState:
        V, c = self.speed_m_s, self.chord_m
        eff = self.effects
        ds = np.concatenate([[0.0], np.diff(t) * 2.0 * V / c])
        alpha_g = alpha + (
            math.radians(self.param("incidence_offset", "delta_deg")) if "incidence_offset" in eff else 0.0
        )
        a34 = alpha_g + alpha_dot * c * (0.75 - self.pivot_x_c) / V
        if "circulation_lag" in eff:
            ts = self.param("circulation_lag", "time_scale")
            x1 = _deficiency(a34, np.exp(-WAGNER_B1 * ds / ts), WAGNER_A1 * np.exp(-WAGNER_B1 * ds / (2 * ts)))
            x2 = _deficiency(a34, np.exp(-WAGNER_B2 * ds / ts), WAGNER_A2 * np.exp(-WAGNER_B2 * ds / (2 * ts)))
            alpha_e = a34 - x1 - x2
        else:
            alpha_e = a34
        if "lift_slope_scale" in eff:
            alpha_e = self.alpha_0l + self.param("lift_slope_scale", "scale") * (alpha_e - self.alpha_0l)
        cn_c = self.cn_attached(alpha_e)
        rel_e = alpha_e - self.alpha_0l
        if "trailing_edge_separation" in eff:
            p = eff["trailing_edge_separation"]
            if "separation_lag" in eff:
                tp, tf = self.param("separation_lag", "tp"), self.param("separation_lag", "tf")
                cn_prime = cn_c - _deficiency(cn_c, np.exp(-ds / tp), np.exp(-ds / (2 * tp)))
                alpha_f = np.interp(cn_prime, self._inv_cn, self._inv_alpha) - self.alpha_0l
                f1 = f_static(alpha_f, p["alpha1_deg"], p["s1_deg"], p["s2_deg"])
                f = np.clip(f1 - _deficiency(f1, np.exp(-ds / tf), np.exp(-ds / (2 * tf))), F_MIN, 1.0)
            else:
                cn_prime = cn_c
                f = f_static(rel_e, p["alpha1_deg"], p["s1_deg"], p["s2_deg"])
            kf = p["slope_factor"] * kirchhoff_factor(f)
            rel_r = np.arcsin(np.clip(kf * np.sin(rel_e), -1.0, 1.0))
        else:
            cn_prime, f, kf, rel_r = cn_c, np.ones_like(alpha_e), np.ones_like(alpha_e), rel_e
        alpha_r = self.alpha_0l + rel_r
        if "leading_edge_vortex" in eff:
            lev_cn, lev_x = self._vortex(ds, cn_prime, cn_c * (1.0 - kf))
        else:
            lev_cn, lev_x = np.zeros_like(alpha_e), np.full_like(alpha_e, np.nan)
        if "added_mass" in eff:
            k = self.param("added_mass", "scale")
            nc_a, nc_b = k * 2.0 * c * alpha_dot / V, k * c * c * alpha_ddot / (V * V)
        else:
            nc_a, nc_b = np.zeros_like(alpha_e), np.zeros_like(alpha_e)
        return FlowState(
            alpha_e=alpha_e,
            alpha_r=alpha_r,
            x_sep=np.asarray(f, dtype=np.float64),
            suction_upper=np.asarray(rel_r >= 0.0),
            cn_prime=np.asarray(cn_prime, dtype=np.float64),
            lev_cn=lev_cn,
            lev_x=lev_x,
            nc_a=np.asarray(nc_a, dtype=np.float64),
            nc_b=np.asarray(nc_b, dtype=np.float64),
        )

    def _vortex(self, ds: F64Array, cn_prime: F64Array, cn_lost: F64Array) -> tuple[F64Array, F64Array]:
        """Beddoes–Leishman vortex: onset when |C_N'| > cn1; while the vortex is over the chord
        (τ_v ≤ T_vl) it is fed by the increments of the lift the separated flow lost,
        C_v = C_N^C·(1 − K_f), decaying with T_v: C_N^v ← C_N^v·E + ΔC_v·√E, E = exp(−Δs/T_v);
        afterwards it decays with T_v/2. Onset (and a secondary vortex after 2·T_vl) needs |C_N'| above
        cn1 and rising."""
        cn1, tvl, tv = (self.param("leading_edge_vortex", k) for k in ("cn1", "tvl", "tv"))
        n = len(ds)
        out_cn, out_x = [0.0] * n, [math.nan] * n
        tau, cnv = -1.0, 0.0
        dsl, cpl, cll = ds.tolist(), cn_prime.tolist(), cn_lost.tolist()
        for i in range(n):
            # onset only while the loading still grows: no new vortex on the downstroke
            rising = i > 0 and abs(cpl[i]) > abs(cpl[i - 1])
            if tau < 0.0:
                if rising and abs(cpl[i]) > cn1:
                    # onset inside this step, located by linear interpolation of C_N' (keeps the
                    # response continuous in cn1, which parameter fits rely on)
                    tau = dsl[i] * (abs(cpl[i]) - cn1) / (abs(cpl[i]) - abs(cpl[i - 1]))
            else:
                tau += dsl[i]
                if tau > 2.0 * tvl:
                    tau = 0.0 if rising and abs(cpl[i]) > cn1 else -1.0
            if 0.0 <= tau <= tvl and i > 0:
                e = math.exp(-dsl[i] / tv)
                feed = min(1.0, tau / dsl[i]) if dsl[i] > 0 else 1.0  # part of this step after onset
                cnv = cnv * e + feed * (cll[i] - cll[i - 1]) * math.sqrt(e)
            else:
                cnv *= math.exp(-2.0 * dsl[i] / tv)
            out_cn[i] = cnv
            out_x[i] = tau / tvl if tau >= 0.0 else math.nan
        return np.asarray(out_cn), np.asarray(out_x)

    # ---------------------------------------------------------------------------------------- pressure
    def _plateau_weight(self, st: FlowState, surf: EvalSurface) -> tuple[F64Array, F64Array]:
        """Blend weight (K, n) of the separated plateau, and the suction-side mask."""
        suction = surf.upper[None, :] == st.suction_upper[:, None]
        if "trailing_edge_separation" not in self.effects:
            return np.zeros((len(st.alpha_r), len(surf.x_c))), suction
        u = np.clip((surf.x_c[None, :] - st.x_sep[:, None]) / PLATEAU_BLEND_C, 0.0, 1.0)
        return u * u * (3.0 - 2.0 * u) * suction, suction

    def _velocity(self, st: FlowState, surf: EvalSurface) -> F64Array:
        """Signed tangential velocity /V∞ (K, n) of the potential flow carrying the reduced circulation."""
        return np.asarray(
            np.cos(st.alpha_r)[:, None] * surf.ut0[None, :] + np.sin(st.alpha_r)[:, None] * surf.ut90[None, :]
        )

    def cp(self, st: FlowState, surf: EvalSurface) -> F64Array:
        """Surface pressure coefficient (K, n) at the points of ``surf``."""
        return self._cp(st, surf, self._velocity(st, surf), *self._plateau_weight(st, surf))

    def _cp(self, st: FlowState, surf: EvalSurface, u: F64Array, w: F64Array, suction: F64Array) -> F64Array:
        cp = 1.0 - u * u
        if "trailing_edge_separation" in self.effects:
            plateau = np.empty(len(st.alpha_r))
            for side in (True, False):
                xs, u0, u90 = self._suction_tables[side]
                m = st.suction_upper == side
                us = np.cos(st.alpha_r[m]) * np.interp(st.x_sep[m], xs, u0) + np.sin(st.alpha_r[m]) * np.interp(
                    st.x_sep[m], xs, u90
                )
                plateau[m] = np.maximum(1.0 - us * us, CP_BASE)
            cp += w * (plateau[:, None] - cp)
        if "leading_edge_vortex" in self.effects:
            on = np.flatnonzero(np.isfinite(st.lev_x) & (st.lev_cn != 0.0))
            if on.size:  # only the samples with a vortex (the bump is the costly part)
                xv = st.lev_x[on]
                width = LEV_WIDTH_C[0] + (LEV_WIDTH_C[1] - LEV_WIDTH_C[0]) * np.clip(xv, 0.0, 1.0)
                amp = np.abs(st.lev_cn[on]) / (width * math.sqrt(math.pi))
                bump = np.exp(-(((surf.x_c[None, :] - xv[:, None]) / width[:, None]) ** 2))
                cp[on] -= suction[on] * amp[:, None] * bump
        if "added_mass" in self.effects:
            xi = 2.0 * surf.x_c - 1.0
            sq = np.sqrt(np.clip(1.0 - xi * xi, 0.0, None))
            a = 2.0 * self.pivot_x_c - 1.0
            dcp = st.nc_a[:, None] * sq[None, :] + st.nc_b[:, None] * ((xi / 2.0 - a) * sq)[None, :]
            cp += np.where(surf.upper[None, :], -0.5, 0.5) * dcp
        return np.asarray(cp)

    def _friction(self, u: F64Array, w: F64Array) -> F64Array:
        if "viscous_drag" not in self.effects:
            return np.zeros((len(u), 6))
        traction = self.param("viscous_drag", "cf") * u * np.abs(u) * (1.0 - w)
        return np.asarray(traction @ self.friction_matrix.T)

    def friction_coeffs(self, st: FlowState) -> F64Array:
        """Skin-friction body-axis coefficients (K, 6) on attached panels; zero without viscous_drag."""
        surf = self.panel_surface
        return self._friction(self._velocity(st, surf), self._plateau_weight(st, surf)[0])

    def panel_cp_and_truth(self, st: FlowState) -> tuple[F64Array, F64Array]:
        """(Cp on all panels (K, N), truth coefficients (K, 6)) sharing one velocity/plateau evaluation."""
        surf = self.panel_surface
        u = self._velocity(st, surf)
        w, suction = self._plateau_weight(st, surf)
        cp = self._cp(st, surf, u, w, suction)
        return cp, np.asarray(cp @ self.force_matrix.T + self._friction(u, w))

    def truth_coeffs(self, st: FlowState, cp_panels: F64Array) -> F64Array:
        """Ground-truth body-axis coefficients (K, 6): pressure integral on all panels + friction."""
        return np.asarray(cp_panels @ self.force_matrix.T + self.friction_coeffs(st))
