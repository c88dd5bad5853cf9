"""The named, parameterised physical effects of the airfoil simulator.

These names are the vocabulary of the discrepancy workflow (``vdm-aero discover``): keep them stable.
Each effect has typed parameters with a default (the value a spec gets when it switches the effect on
without naming the parameter) and a documented physical range (what the hidden-effect tests draw
from). Times are non-dimensional in semichords, s = 2·V·t/c, as in the Beddoes–Leishman literature,
unless the name carries a unit suffix.

References: Leishman & Beddoes (1989) J. AHS 34(3); Leishman, *Principles of Helicopter
Aerodynamics*, 2nd ed., ch. 8–9; Theodorsen (1935) NACA Rep. 496; Hansen, Gaunaa & Madsen (2004)
Risø-R-1354 (Øye/Beddoes separation lag); Sheng, Galbraith & Coton (2008) J. Sol. Energy Eng.
130(3) 031013 and dos Santos & Marques (2021) J. Fluids Struct. 106 103375 (low-Mach revisions);
OpenFAST AeroDyn UnsteadyAero documentation and source (T_f0, T_V0, T_p, T_VL). Each range is
reviewed against these, with the values and the source of each, in docs/simulator.md ("Effect
parameters and physical ranges").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType


@dataclass(frozen=True)
class ParamInfo:
    """One effect parameter: default, physical range and unit (``"-"`` when non-dimensional)."""

    default: float
    low: float
    high: float
    unit: str
    doc: str


@dataclass(frozen=True)
class EffectInfo:
    """A named effect. ``layer`` says where it acts: on the flow (pressures and forces), on the
    truth forces only (invisible to pressure ports), on the tap measurements only, or on the
    incidence the flow sees."""

    name: str
    layer: str  # "flow" | "truth_only" | "ports"
    doc: str
    params: Mapping[str, ParamInfo]
    requires: tuple[str, ...] = ()


def _effect(
    name: str, layer: str, doc: str, params: dict[str, ParamInfo], requires: tuple[str, ...] = ()
) -> EffectInfo:
    return EffectInfo(name, layer, doc, MappingProxyType(params), requires)


_ALL = (
    _effect(
        "circulation_lag",
        "flow",
        "Circulatory lift builds up with Wagner's indicial response (Jones' two-exponential fit "
        "A1=0.165, b1=0.0455, A2=0.335, b2=0.3) applied to the 3/4-chord incidence. Off: quasi-steady.",
        {
            "time_scale": ParamInfo(
                1.0, 0.5, 2.0, "-", "multiplies both Wagner time constants (1/b1, 1/b2) in semichords"
            )
        },
    ),
    _effect(
        "added_mass",
        "flow",
        "Non-circulatory (apparent-mass) pressure of the pitching plate: loading sqrt(1-ξ²) for the "
        "V·α̇ term and (ξ/2-a)·sqrt(1-ξ²) for the b·α̈ term, normalised to Theodorsen's lift.",
        {"scale": ParamInfo(1.0, 0.5, 1.5, "-", "multiplies the apparent-mass pressure")},
    ),
    _effect(
        "trailing_edge_separation",
        "flow",
        "Static trailing-edge separation: Kirchhoff separation point f(α) = x_sep/c with the "
        "Beddoes exponential fit; circulation reduced by slope_factor·((1+√f)/2)² and a pressure "
        "plateau aft of "
        "x_sep on the suction side. Parameters left out are calibrated from NeuralFoil's viscous "
        "polar at the spec's Reynolds number.",
        {
            "alpha1_deg": ParamInfo(15.0, 10.0, 22.0, "deg", "incidence where f = 0.7 (break of the fit)"),
            "s1_deg": ParamInfo(2.5, 1.0, 6.0, "deg", "width of the separation growth below alpha1"),
            "s2_deg": ParamInfo(
                3.0, 0.7, 8.0, "deg", "width of the separation growth above alpha1 (NACA 0012, M ≤ 0.3: 0.7–2.3)"
            ),
            "slope_factor": ParamInfo(
                0.9, 0.75, 1.0, "-", "attached viscous lift slope / potential-flow lift slope (decambering)"
            ),
        },
    ),
    _effect(
        "separation_lag",
        "flow",
        "Beddoes–Leishman lags: leading-edge pressure lag T_p on the normal force that drives "
        "separation, and boundary-layer lag T_f on the separation point (Øye-type first-order lag). "
        "T_f → 0 reproduces the static response.",
        {
            "tf": ParamInfo(
                3.0,
                1.5,
                12.0,
                "-",
                "separation-point lag time constant [semichords]; one constant for separation and "
                "reattachment (Beddoes-type models use T_f0/2 … 4·T_f0 with T_f0 ≈ 3)",
            ),
            "tp": ParamInfo(
                1.7,
                0.8,
                4.0,
                "-",
                "leading-edge pressure lag time constant [semichords] (1.7 at M = 0.3, up to 4 at low Mach)",
            ),
        },
        requires=("trailing_edge_separation",),
    ),
    _effect(
        "leading_edge_vortex",
        "flow",
        "Dynamic-stall vortex: shed when the lagged normal force exceeds cn1, fed (with decay tv) by "
        "the growth since onset of the lift the separated flow lost, convecting along the suction "
        "side as a Gaussian suction bump that "
        "reaches the trailing edge after tvl semichords, then decaying.",
        {
            "cn1": ParamInfo(
                2.1,
                1.4,
                2.6,
                "-",
                "critical lagged normal force for vortex onset, on the potential-flow normal force of the "
                "panel method (NACA 0012: 1.4 ↔ 11.9°, 2.1 ↔ 18.7°, 2.6 ↔ 24.4°)",
            ),
            "tvl": ParamInfo(
                8.0,
                3.0,
                13.0,
                "-",
                "vortex travel time to the trailing edge [semichords] (3.3–5 at low Mach, 6–13 AeroDyn)",
            ),
            "tv": ParamInfo(6.0, 3.0, 10.0, "-", "vortex lift decay time constant [semichords]"),
        },
        requires=("trailing_edge_separation",),
    ),
    _effect(
        "viscous_drag",
        "truth_only",
        "Skin friction τ = cf·½ρu_e² along the local surface flow on attached panels; it enters the "
        "ground-truth coefficients only (pressure ports cannot see it).",
        {"cf": ParamInfo(0.003, 0.001, 0.008, "-", "skin-friction coefficient on edge dynamic pressure")},
    ),
    _effect(
        "incidence_offset",
        "flow",
        "The flow sees α + delta (tunnel flow angularity, model mounting offset): the recorded α is unchanged.",
        {"delta_deg": ParamInfo(0.5, -2.0, 2.0, "deg", "incidence seen by the flow minus recorded α")},
    ),
    _effect(
        "lift_slope_scale",
        "flow",
        "Circulatory incidence scaled about the zero-lift angle (tunnel-wall and 3-D end effects, "
        "viscous decambering).",
        {"scale": ParamInfo(0.92, 0.75, 1.1, "-", "factor on (α_E − α_0L)")},
    ),
    _effect(
        "port_lag",
        "ports",
        "First-order pneumatic lag of the tubing between each tap and its transducer.",
        {"tau_s": ParamInfo(0.004, 0.001, 0.02, "s", "tubing time constant")},
    ),
    _effect(
        "port_bias",
        "ports",
        "Constant Cp offset on named taps (transducer zero drift, a leaking tube). Parameters are "
        "tap names with their offset, e.g. {p0007: 0.08}; any tap name is accepted.",
        {},
    ),
)

EFFECTS: Mapping[str, EffectInfo] = MappingProxyType({e.name: e for e in _ALL})
"""All effects by name, in documentation order."""

PORT_BIAS_RANGE_CP = (-0.2, 0.2)
"""Physical range of a port_bias offset [Cp]."""


def effect_defaults(name: str) -> dict[str, float]:
    """Default parameters of effect ``name``."""
    return {k: p.default for k, p in EFFECTS[name].params.items()}
