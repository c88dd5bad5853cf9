"""The airframe simulation spec (YAML, ``kind: airframe``): typed, frozen, validated with messages that
name the key (same style as :mod:`sim.airfoil.spec`).

Two motions: ``sinusoidal_pitch`` (the method's 3-D case: the aircraft pitches harmonically about its
CG in a steady stream, one case per frequency, time-marched so that dynamic stall carries over) and
``envelope`` (quasi-steady flight states: one sweep per state variable plus random combinations, for the
navigation filter). See docs/airframe.md for every key. Unknown keys are errors; geometry keys left out
take the reference UAV's values (:func:`sim.airframe.geometry.default_design`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from sim.airfoil.effects import EFFECTS
from sim.airfoil.naca import naca4_params
from sim.airfoil.spec import parse_effects
from sim.airframe.geometry import (
    AirframeDesign,
    ControlDesign,
    FuselageDesign,
    LiftingSurfaceDesign,
    PointMass,
    build_geometry,
    default_design,
    surface_for,
)
from sim.airframe.pressure import HISTORY_EFFECTS
from sim.airframe.vlm import VlmResolution
from sim.spec_reader import SpecReader as _Reader
from sim.spec_reader import read_yaml_file
from vdm_aero.dataset import Reference, default_point_names
from vdm_aero.errors import SpecError

__all__ = [
    "CASE_ROLES",
    "ENVELOPE_VARIABLES",
    "AirframeSpec",
    "EnvelopeMotion",
    "PitchMotion",
    "load_airframe_spec",
    "parse_airframe_spec",
]

CASE_ROLES: Final = ("train", "validation", "test", "unassigned")

ENVELOPE_VARIABLES: Final[Mapping[str, tuple[str, float]]] = {
    "speed_m_s": ("airspeed_m_s", 1.0),
    "alpha_deg": ("alpha_rad", math.pi / 180.0),
    "beta_deg": ("beta_rad", math.pi / 180.0),
    "p_rad_s": ("p_rad_s", 1.0),
    "q_rad_s": ("q_rad_s", 1.0),
    "r_rad_s": ("r_rad_s", 1.0),
    "alpha_dot_rad_s": ("alpha_dot_rad_s", 1.0),
    "aileron_deg": ("aileron_rad", math.pi / 180.0),
    "elevator_deg": ("elevator_rad", math.pi / 180.0),
    "rudder_deg": ("rudder_rad", math.pi / 180.0),
}
"""Envelope variable (spec name, unit in the name) → (flight-state field, factor to SI)."""

DEFAULT_RANGES: Final[Mapping[str, tuple[float, float]]] = {
    "speed_m_s": (12.0, 30.0),
    "alpha_deg": (-6.0, 20.0),
    "beta_deg": (-12.0, 12.0),
    "p_rad_s": (-2.0, 2.0),
    "q_rad_s": (-1.0, 1.0),
    "r_rad_s": (-1.0, 1.0),
    "alpha_dot_rad_s": (-1.5, 1.5),
    "aileron_deg": (-20.0, 20.0),
    "elevator_deg": (-20.0, 20.0),
    "rudder_deg": (-20.0, 20.0),
}
"""Default envelope ranges: a 2 m, 2.5 kg UAV from near stall to dash, rates up to p·b/2V ≈ 0.1."""


@dataclass(frozen=True)
class PitchMotion:
    """Harmonic pitch α(t) = α0 + A·sin(2π f t) about the CG at constant airspeed and sideslip
    (q = α̇: the stream is fixed, the aircraft rotates). One case per frequency."""

    speed_m_s: float
    alpha0_deg: float
    amplitude_deg: float
    beta_deg: float
    freqs_hz: tuple[float, ...]
    case_roles: tuple[str, ...]
    cycles: int
    samples_per_cycle: int
    type: str = "sinusoidal_pitch"


@dataclass(frozen=True)
class EnvelopeMotion:
    """Quasi-steady states: a sweep of each variable in ``sweeps`` over its range (others at ``base``),
    then random combinations uniform over all ranges, split into train/validation/test cases."""

    speed_m_s: float
    base: Mapping[str, float]
    ranges: Mapping[str, tuple[float, float]]
    sweeps: tuple[str, ...]
    sweep_points: int
    random_counts: Mapping[str, int]
    sample_interval_s: float
    type: str = "envelope"


@dataclass(frozen=True)
class AirframeSpec:
    """A complete, validated airframe simulation spec. SI units."""

    name: str
    source: str
    design: AirframeDesign
    surface_points: int
    lattice: VlmResolution
    section_panels: int
    density_kg_m3: float
    kinematic_viscosity_m2_s: float
    reference: Reference | None
    motion: PitchMotion | EnvelopeMotion
    effects: Mapping[str, Mapping[str, Any]]
    separation_calibration: Mapping[str, Mapping[str, float]]
    cp_std_fraction: float
    seed: int
    kind: str = "airframe"
    origin: str = field(default="<spec>", compare=False)

    @property
    def speed_m_s(self) -> float:
        """Nominal airspeed [m/s] (the pitch speed; the envelope's sweep speed)."""
        return self.motion.speed_m_s

    @property
    def n_cases(self) -> int:
        """Number of cases the spec simulates (for progress bars)."""
        m = self.motion
        if isinstance(m, PitchMotion):
            return len(m.freqs_hz)
        return len(m.sweeps) + sum(1 for n in m.random_counts.values() if n > 0)

    def reynolds(self, mean_chord_m: float) -> float:
        """Reynolds number V·c/ν at the nominal speed for a chord [m]."""
        return self.speed_m_s * mean_chord_m / self.kinematic_viscosity_m2_s

    def to_dict(self) -> dict[str, Any]:
        """Plain-YAML form; ``parse_airframe_spec(spec.to_dict())`` gives the same spec."""
        d: dict[str, Any] = {
            "kind": self.kind,
            "name": self.name,
            "source": self.source,
            "airframe": _design_to_dict(self.design),
            "surface_points": self.surface_points,
            "lattice": dataclasses.asdict(self.lattice),
            "section_panels": self.section_panels,
            "density_kg_m3": self.density_kg_m3,
            "kinematic_viscosity_m2_s": self.kinematic_viscosity_m2_s,
        }
        if self.reference is not None:
            d["reference"] = self.reference.to_dict()
        m = self.motion
        if isinstance(m, PitchMotion):
            d["motion"] = {
                "type": m.type,
                "speed_m_s": m.speed_m_s,
                "alpha0_deg": m.alpha0_deg,
                "amplitude_deg": m.amplitude_deg,
                "beta_deg": m.beta_deg,
                "freqs_hz": list(m.freqs_hz),
                "case_roles": list(m.case_roles),
                "cycles": m.cycles,
                "samples_per_cycle": m.samples_per_cycle,
            }
        else:
            d["motion"] = {
                "type": m.type,
                "speed_m_s": m.speed_m_s,
                "base": dict(m.base),
                "ranges": {k: list(v) for k, v in m.ranges.items()},
                "sweeps": list(m.sweeps),
                "sweep_points": m.sweep_points,
                "random": dict(m.random_counts),
                "sample_interval_s": m.sample_interval_s,
            }
        d["effects"] = {k: dict(v) for k, v in self.effects.items()}
        if self.separation_calibration:
            d["separation_calibration"] = {k: dict(v) for k, v in self.separation_calibration.items()}
        d["noise"] = {"cp_std_fraction": self.cp_std_fraction}
        d["seed"] = self.seed
        return d


def _design_to_dict(design: AirframeDesign) -> dict[str, Any]:
    def surf(s: LiftingSurfaceDesign) -> dict[str, Any]:
        out = dataclasses.asdict(s)
        if s.control is None:
            out.pop("control")
        return out

    return {
        "mass_kg": design.mass_kg,
        "battery_size_m": list(design.battery_size_m),
        "battery_z_m": design.battery_z_m,
        "wing": surf(design.wing),
        "htail": surf(design.htail),
        "vtail": surf(design.vtail),
        "fuselage": dataclasses.asdict(design.fuselage),
        "equipment": [{**dataclasses.asdict(e), "size_m": list(e.size_m)} for e in design.equipment],
    }


def _parse_surface(r: _Reader, base: LiftingSurfaceDesign, *, vertical: bool) -> LiftingSurfaceDesign:
    airfoil = r.text("airfoil", base.airfoil).lower()
    try:
        naca4_params(airfoil.removeprefix("naca"))
    except ValueError:
        raise r.fail("airfoil", f"expected a NACA 4-digit name such as naca0012, got {airfoil!r}") from None
    if vertical and naca4_params(airfoil.removeprefix("naca"))[0] != 0.0:
        raise r.fail("airfoil", "the fin must have a symmetric section (NACA 00xx)")
    root = r.num("root_chord_m", base.root_chord_m, positive=True)
    ctrl = base.control
    craw = r.raw("control", None) if "control" in r.data else base.control
    if craw is None:
        ctrl = None
    elif not isinstance(craw, ControlDesign):
        cr = _Reader(craw, r.origin, r.key("control"))
        b = ctrl or ControlDesign(0.25, 0.0, 1.0)
        ctrl = ControlDesign(
            chord_fraction=cr.num("chord_fraction", b.chord_fraction, lo=0.05, hi=0.6),
            eta_start=cr.num("eta_start", b.eta_start, lo=0.0, hi=1.0),
            eta_end=cr.num("eta_end", b.eta_end, lo=0.0, hi=1.0),
        )
        if ctrl.eta_end <= ctrl.eta_start:
            raise cr.fail("eta_end", f"must exceed eta_start ({ctrl.eta_start}), got {ctrl.eta_end}")
        cr.finish()
    out = LiftingSurfaceDesign(
        airfoil=f"naca{airfoil.removeprefix('naca')}",
        span_m=r.num("span_m", base.span_m, positive=True),
        root_chord_m=root,
        tip_chord_m=r.num("tip_chord_m", base.tip_chord_m, positive=True),
        x_m=r.num("x_m", base.x_m, lo=-5.0, hi=5.0),
        z_m=r.num("z_m", base.z_m, lo=-2.0, hi=2.0),
        incidence_deg=r.num("incidence_deg", base.incidence_deg, lo=-15.0, hi=15.0),
        twist_deg=r.num("twist_deg", base.twist_deg, lo=-15.0, hi=15.0),
        dihedral_deg=r.num("dihedral_deg", base.dihedral_deg, lo=-20.0, hi=20.0),
        sweep_deg=r.num("sweep_deg", base.sweep_deg, lo=-45.0, hi=60.0),
        mass_kg=r.num("mass_kg", base.mass_kg, lo=0.0),
        control=ctrl,
        left_twist_offset_deg=r.num("left_twist_offset_deg", base.left_twist_offset_deg, lo=-5.0, hi=5.0),
    )
    r.finish()
    return out


def _parse_design(data: Any, origin: str) -> AirframeDesign:
    base = default_design()
    r = _Reader({} if data is None else data, origin, "airframe")
    wing = _parse_surface(r.sub("wing", {}), base.wing, vertical=False)
    htail = _parse_surface(r.sub("htail", {}), base.htail, vertical=False)
    vtail = _parse_surface(r.sub("vtail", {}), base.vtail, vertical=True)
    fr = r.sub("fuselage", {})
    fus = FuselageDesign(
        length_m=fr.num("length_m", base.fuselage.length_m, positive=True),
        diameter_m=fr.num("diameter_m", base.fuselage.diameter_m, positive=True),
        x_nose_m=fr.num("x_nose_m", base.fuselage.x_nose_m, lo=-5.0, hi=5.0),
        mass_kg=fr.num("mass_kg", base.fuselage.mass_kg, lo=0.0),
    )
    if fus.diameter_m >= fus.length_m:
        raise fr.fail("diameter_m", f"must be smaller than length_m ({fus.length_m}), got {fus.diameter_m}")
    fr.finish()
    equipment = base.equipment
    if (eq := r.raw("equipment", None)) is not None:
        if not isinstance(eq, list):
            raise r.fail("equipment", "expected a list of {name, mass_kg, x_m, z_m, size_m}")
        items = []
        for i, e in enumerate(eq):
            er = _Reader(e, origin, f"airframe.equipment[{i}]")
            items.append(
                PointMass(
                    name=er.text("name"),
                    mass_kg=er.num("mass_kg", positive=True),
                    x_m=er.num("x_m", lo=-5.0, hi=5.0),
                    z_m=er.num("z_m", 0.0, lo=-2.0, hi=2.0),
                    size_m=_triple(er.numbers("size_m", [0.05, 0.05, 0.05], n=3)),
                )
            )
            er.finish()
        equipment = tuple(items)
    design = AirframeDesign(
        wing=wing,
        htail=htail,
        vtail=vtail,
        fuselage=fus,
        equipment=equipment,
        mass_kg=r.num("mass_kg", base.mass_kg, positive=True),
        battery_size_m=_triple(r.numbers("battery_size_m", list(base.battery_size_m), n=3)),
        battery_z_m=r.num("battery_z_m", base.battery_z_m, lo=-1.0, hi=1.0),
    )
    r.finish()
    try:
        build_geometry(design, surface_for(300))  # mass balance and section names
    except ValueError as e:
        raise SpecError(f"{origin}: airframe: {e}") from None
    return design


def _triple(v: tuple[float, ...]) -> tuple[float, float, float]:
    return (v[0], v[1], v[2])


# ------------------------------------------------------------------------------------------- motion
def _parse_pitch(mr: _Reader, seed: int) -> PitchMotion:
    freqs = mr.numbers("freqs_hz", [])
    if any(not f > 0 for f in freqs):
        raise mr.fail("freqs_hz", "expected positive frequencies [Hz]")
    roles = tuple(str(x) for x in mr.seq("case_roles", ["train"] * len(freqs)))
    if len(roles) != len(freqs) or any(x not in CASE_ROLES for x in roles):
        raise mr.fail("case_roles", f"expected {len(freqs)} entries from {CASE_ROLES}")
    if (rf := mr.raw("random_freqs", None)) is not None:
        rr = _Reader(rf, mr.origin, mr.key("random_freqs"))
        lo = rr.num("low_hz", positive=True)
        hi = rr.num("high_hz", positive=True)
        if hi <= lo:
            raise rr.fail("high_hz", f"must exceed low_hz ({lo}), got {hi}")
        counts = {role: rr.integer(role, 0, hi=100) for role in ("train", "validation", "test")}
        rr.finish()
        rng = np.random.default_rng(seed)
        for role, n in counts.items():
            drawn = rng.uniform(lo, hi, n)
            freqs += tuple(round(float(f), 4) for f in drawn)
            roles += (role,) * n
    if not freqs:
        raise mr.fail("freqs_hz", "expected at least one frequency (freqs_hz or random_freqs)")
    motion = PitchMotion(
        speed_m_s=mr.num("speed_m_s", positive=True),
        alpha0_deg=mr.num("alpha0_deg", lo=-30.0, hi=60.0),
        amplitude_deg=mr.num("amplitude_deg", lo=0.0, hi=40.0),
        beta_deg=mr.num("beta_deg", 0.0, lo=-30.0, hi=30.0),
        freqs_hz=freqs,
        case_roles=roles,
        cycles=mr.integer("cycles", 2, lo=1, hi=100),
        samples_per_cycle=mr.integer("samples_per_cycle", 96, lo=8, hi=10000),
    )
    mr.finish()
    return motion


def _parse_envelope(mr: _Reader) -> EnvelopeMotion:
    speed = mr.num("speed_m_s", positive=True)
    ranges = dict(DEFAULT_RANGES)
    rr = mr.sub("ranges", {})
    for var in ENVELOPE_VARIABLES:
        lo, hi = rr.numbers(var, list(ranges[var]), n=2)
        if hi < lo:
            raise rr.fail(var, f"expected [low, high] with low ≤ high, got [{lo}, {hi}]")
        if var == "speed_m_s" and lo <= 0.0:
            raise rr.fail(var, f"airspeeds must be > 0, got [{lo}, {hi}]")
        ranges[var] = (lo, hi)
    rr.finish()
    br = mr.sub("base", {})
    base = {
        var: br.num(var, speed if var == "speed_m_s" else (4.0 if var == "alpha_deg" else 0.0))
        for var in ENVELOPE_VARIABLES
    }
    if base["speed_m_s"] <= 0.0:
        raise br.fail("speed_m_s", f"must be > 0, got {base['speed_m_s']}")
    br.finish()
    sweeps = tuple(str(v) for v in mr.seq("sweeps", list(ENVELOPE_VARIABLES)))
    for v in sweeps:
        if v not in ENVELOPE_VARIABLES:
            raise mr.fail("sweeps", f"unknown variable {v!r} (known: {', '.join(ENVELOPE_VARIABLES)})")
    if len(set(sweeps)) != len(sweeps):
        raise mr.fail("sweeps", "variables must be unique")
    ran = mr.sub("random", {})
    counts = {
        role: ran.integer(role, d, hi=10_000_000) for role, d in (("train", 1000), ("validation", 200), ("test", 200))
    }
    ran.finish()
    motion = EnvelopeMotion(
        speed_m_s=speed,
        base=base,
        ranges=ranges,
        sweeps=sweeps,
        sweep_points=mr.integer("sweep_points", 41, lo=2, hi=100_000),
        random_counts=counts,
        sample_interval_s=mr.num("sample_interval_s", 0.02, positive=True),
    )
    if not motion.sweeps and not any(counts.values()):
        raise mr.fail("sweeps", "the envelope is empty: give sweeps or random states")
    mr.finish()
    return motion


# ------------------------------------------------------------------------------------------ effects
def _parse_calibration(data: Any, origin: str) -> dict[str, dict[str, float]]:
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise SpecError(f"{origin}: separation_calibration: expected a mapping of airfoil name to parameters")
    params = EFFECTS["trailing_edge_separation"].params
    out: dict[str, dict[str, float]] = {}
    for af, vals in data.items():
        r = _Reader(vals, origin, f"separation_calibration.{af}")
        out[str(af).lower()] = {p: r.num(p) for p in params}
        r.finish()
    return out


# -------------------------------------------------------------------------------------------- parse
def parse_airframe_spec(data: Any, *, origin: str = "<spec>") -> AirframeSpec:
    """Validate a spec mapping (as loaded from YAML) into an :class:`AirframeSpec`."""
    r = _Reader(data, origin, "")
    kind = r.text("kind")
    if kind != "airframe":
        raise r.fail("kind", f"'{kind}' is not an airframe spec (expected 'airframe')")
    seed = r.integer("seed", 0)
    design = _parse_design(r.raw("airframe", {}), origin)
    n_target = r.integer("surface_points", 5000, lo=100, hi=50_000_000)
    lr = r.sub("lattice", {})
    lattice = VlmResolution(
        wing_strips=lr.integer("wing_strips", VlmResolution.wing_strips, lo=2, hi=200),
        htail_strips=lr.integer("htail_strips", VlmResolution.htail_strips, lo=2, hi=200),
        vtail_strips=lr.integer("vtail_strips", VlmResolution.vtail_strips, lo=2, hi=200),
    )
    lr.finish()
    reference = None
    if (ref := r.raw("reference", None)) is not None:
        rr = _Reader(ref, origin, "reference")
        reference = Reference(
            area_m2=rr.num("area_m2", positive=True),
            chord_m=rr.num("chord_m", positive=True),
            span_m=rr.num("span_m", positive=True),
        )
        rr.finish()
    mr = r.sub("motion")
    mtype = mr.text("type")
    motion: PitchMotion | EnvelopeMotion
    if mtype == "sinusoidal_pitch":
        motion = _parse_pitch(mr, seed)
    elif mtype == "envelope":
        motion = _parse_envelope(mr)
    else:
        raise mr.fail("type", f"'{mtype}' is not supported (supported: sinusoidal_pitch, envelope)")
    n_points = surface_for(n_target).n_points
    quasi_steady = isinstance(motion, EnvelopeMotion)
    needs_history = (
        "needs a time history, but an envelope spec is quasi-steady (use it with motion.type sinusoidal_pitch)"
    )
    effects = parse_effects(
        r.raw("effects", {}),
        origin,
        forbidden={n: needs_history for n in (*HISTORY_EFFECTS, "port_lag")} if quasi_steady else None,
        known_points=set(default_point_names(n_points)),
    )
    noise = r.sub("noise", {})
    cp_std = noise.num("cp_std_fraction", 0.0, lo=0.0, hi=0.5)
    noise.finish()
    spec = AirframeSpec(
        name=r.text("name", "airframe"),
        source=r.text("source", "vdm-aero sim.airframe"),
        design=design,
        surface_points=n_target,
        lattice=lattice,
        section_panels=r.integer("section_panels", 160, lo=40, hi=2000),
        density_kg_m3=r.num("density_kg_m3", 1.225, positive=True),
        kinematic_viscosity_m2_s=r.num("kinematic_viscosity_m2_s", 1.46e-5, positive=True),
        reference=reference,
        motion=motion,
        effects=effects,
        separation_calibration=_parse_calibration(r.raw("separation_calibration", None), origin),
        cp_std_fraction=cp_std,
        seed=seed,
        kind=kind,
        origin=origin,
    )
    r.finish()
    return spec


def load_airframe_spec(path: str | Path) -> AirframeSpec:
    """Read and validate a spec file."""
    p = Path(path)
    data = read_yaml_file(p)
    return parse_airframe_spec(data, origin=str(p))
