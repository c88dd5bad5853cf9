"""Calibrate the static separation point f(α) from an independent viscous polar (NeuralFoil).

For each incidence we find the separation point f at which *our pressure model* (Kirchhoff-reduced
circulation plus the suction-side plateau) integrates to the polar's normal force
C_N = C_L·cos α + C_D·sin α, then fit Beddoes' exponential f(α) to those points. The model's own
pressure distribution is what is calibrated, so the integrated forces follow the polar.
NeuralFoil ships its network weights in its PyPI package and runs offline.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from sim.airfoil.effects import EFFECTS, effect_defaults
from sim.airfoil.flow import AirfoilFlow, FlowState, f_static, kirchhoff_factor
from vdm_aero._typing import F64Array

CALIBRATION_ALPHA_DEG = np.arange(1.0, 30.01, 0.5)
SLOPE_WINDOW_DEG = (1.0, 5.0)
# A polar normal force within 3 % of the attached model is attributed to the slope fit, not separation.
ATTACHED_TOLERANCE = 0.97  # attached, linear range of the polar where the viscous lift slope is read
_F_GRID = np.linspace(0.0, 1.0, 201)


def neuralfoil_polar(airfoil: str, reynolds: float, alpha_deg: F64Array) -> tuple[F64Array, F64Array]:
    """Lift and drag coefficients of a NACA airfoil from NeuralFoil (``xlarge`` network)."""
    import aerosandbox as asb  # heavy import (CasADi): only when a calibration is needed
    import neuralfoil as nf

    aero = nf.get_aero_from_airfoil(asb.Airfoil(airfoil), alpha=alpha_deg, Re=reynolds, model_size="xlarge")
    return np.asarray(aero["CL"], dtype=np.float64), np.asarray(aero["CD"], dtype=np.float64)


def separation_from_polar(flow: AirfoilFlow, alpha_deg: F64Array, cn_target: F64Array, slope_factor: float) -> F64Array:
    """Separation point f at each incidence such that the model's normal force equals ``cn_target``.

    ``flow`` must have ``trailing_edge_separation`` switched on (its pressure plateau is part of the
    model being calibrated; its f-fit parameters are not used here)."""
    if "trailing_edge_separation" not in flow.effects:
        raise ValueError("separation_from_polar needs a flow with trailing_edge_separation switched on")
    surf = flow.panel_surface
    w = np.asarray(flow.geometry.normals_b[:, 2] * flow.geometry.length_c)
    out = np.empty(len(alpha_deg))
    for i, a_deg in enumerate(alpha_deg):
        rel = math.radians(float(a_deg)) - flow.alpha_0l
        kf = slope_factor * kirchhoff_factor(_F_GRID)
        rel_r = np.arcsin(np.clip(kf * math.sin(rel), -1, 1))
        k = len(_F_GRID)
        st = FlowState(
            alpha_e=np.full(k, rel + flow.alpha_0l),
            alpha_r=flow.alpha_0l + rel_r,
            x_sep=_F_GRID.copy(),
            suction_upper=rel_r >= 0,
            cn_prime=np.zeros(k),
            lev_cn=np.zeros(k),
            lev_x=np.full(k, np.nan),
            nc_a=np.zeros(k),
            nc_b=np.zeros(k),
        )
        cn = -(flow.cp(st, surf) @ w)
        target = float(cn_target[i])
        # C_N(f) is not monotone (a plateau near the LE adds suction aft at low α): take the crossing
        # nearest to attached flow, i.e. the largest f.
        d = cn - target
        if target >= ATTACHED_TOLERANCE * cn[-1]:
            out[i] = 1.0
            continue
        cross = np.flatnonzero(d[:-1] * d[1:] <= 0.0)
        if cross.size == 0:
            out[i] = float(_F_GRID[int(np.argmin(np.abs(d)))])
            continue
        j = int(cross[-1])
        out[i] = float(np.interp(0.0, [d[j], d[j + 1]], [_F_GRID[j], _F_GRID[j + 1]]))
    return out


def fit_f_static(alpha_deg: F64Array, f: F64Array) -> dict[str, float]:
    """Least-squares fit of Beddoes' exponential to separation points."""
    from scipy.optimize import least_squares

    info = EFFECTS["trailing_edge_separation"].params
    names = ("alpha1_deg", "s1_deg", "s2_deg")
    lo = [info[n].low - (info[n].high - info[n].low) for n in names]
    hi = [info[n].high + (info[n].high - info[n].low) for n in names]
    lo = [max(v, 0.2) for v in lo]
    x0 = [info[n].default for n in names]

    def resid(p: F64Array) -> F64Array:
        return np.asarray(f_static(np.radians(alpha_deg), *p) - f)

    sol = least_squares(resid, x0, bounds=(lo, hi))
    return {n: round(float(v), 4) for n, v in zip(names, sol.x, strict=True)}


def calibrate_static_separation(flow: AirfoilFlow, airfoil: str, reynolds: float) -> dict[str, Any]:
    """The ``trailing_edge_separation`` parameters for this airfoil and Reynolds number."""
    a = CALIBRATION_ALPHA_DEG
    cl, cd = neuralfoil_polar(airfoil, reynolds, a)
    ar = np.radians(a)
    cn_polar = cl * np.cos(ar) + cd * np.sin(ar)
    lin = (a >= SLOPE_WINDOW_DEG[0]) & (a <= SLOPE_WINDOW_DEG[1])
    # κ from C_N,polar(α) ≈ κ·C_N,potential(α) over the linear range (the model's own statement: the
    # circulation about the zero-lift angle is scaled), as a least-squares ratio at the geometric α
    cn_pot = flow.cn_attached(ar[lin])
    slope_factor = float(np.clip(np.sum(cn_polar[lin] * cn_pot) / np.sum(cn_pot * cn_pot), 0.5, 1.0))
    f = separation_from_polar(flow, a, cn_polar, slope_factor)
    # f(α) is a function of the incidence above the zero-lift angle (see flow.f_static)
    return {**fit_f_static(a - np.degrees(flow.alpha_0l), f), "slope_factor": round(slope_factor, 4)}


def complete_effects(
    effects: Mapping[str, Mapping[str, Any]],
    *,
    airfoil: str,
    reynolds: float,
    flow_factory: Any,
) -> dict[str, dict[str, Any]]:
    """Every switched-on effect with every parameter filled in: user values, then NeuralFoil
    calibration (static separation), then documented defaults. ``flow_factory(effects)`` builds an
    :class:`AirfoilFlow` for the calibration."""
    out: dict[str, dict[str, Any]] = {}
    for name, params in effects.items():
        if name == "port_bias":
            out[name] = dict(params)
            continue
        full = effect_defaults(name)
        if name == "trailing_edge_separation" and not set(EFFECTS[name].params) <= set(params):
            probe = flow_factory({name: effect_defaults(name)})
            full.update(calibrate_static_separation(probe, airfoil, reynolds))
        full.update(params)
        out[name] = full
    return out
