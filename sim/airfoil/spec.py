"""The airfoil simulation spec (YAML): typed, frozen, validated with messages that name the key.

See docs/simulator.md for every key. Unknown keys are errors (a typo must not silently fall back to a
default); effect parameters left out take the documented defaults, except the static separation fit,
which is calibrated from a viscous polar when its parameters are left out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim.airfoil.effects import EFFECTS, PORT_BIAS_RANGE_CP
from sim.spec_reader import SpecReader as _Reader
from sim.spec_reader import read_yaml_file
from vdm_aero.errors import SpecError

CASE_ROLES = ("train", "validation", "test", "unassigned")


@dataclass(frozen=True)
class Motion:
    """Harmonic pitch α(t) = α0 + A·sin(2π f t) about ``pivot_x_c`` (fraction of chord)."""

    alpha0_deg: float
    amplitude_deg: float
    pivot_x_c: float
    freqs_hz: tuple[float, ...]
    cycles: int
    samples_per_cycle: int
    case_roles: tuple[str, ...]
    type: str = "sinusoidal_pitch"


@dataclass(frozen=True)
class Taps:
    """Pressure taps at chordwise stations; the data set then holds only the taps."""

    x_c: tuple[float, ...]
    upper: tuple[bool, ...]
    names: tuple[str, ...]


@dataclass(frozen=True)
class AirfoilSpec:
    """A complete, validated airfoil simulation spec. SI units."""

    name: str
    source: str
    airfoil: str
    chord_m: float
    span_m: float
    surface_points: int
    speed_m_s: float
    density_kg_m3: float
    kinematic_viscosity_m2_s: float
    motion: Motion
    effects: Mapping[str, Mapping[str, Any]]
    taps: Taps | None
    cp_std_fraction: float
    seed: int
    kind: str = "airfoil"
    origin: str = field(default="<spec>", compare=False)

    @property
    def reynolds(self) -> float:
        """Chord Reynolds number V·c/ν."""
        return self.speed_m_s * self.chord_m / self.kinematic_viscosity_m2_s

    def has(self, effect: str) -> bool:
        return effect in self.effects

    def to_dict(self) -> dict[str, Any]:
        """Plain-YAML form; ``parse_spec(spec.to_dict())`` gives the same spec."""
        m = self.motion
        d: dict[str, Any] = {
            "kind": self.kind,
            "name": self.name,
            "source": self.source,
            "airfoil": self.airfoil,
            "chord_m": self.chord_m,
            "span_m": self.span_m,
            "surface_points": self.surface_points,
            "speed_m_s": self.speed_m_s,
            "density_kg_m3": self.density_kg_m3,
            "kinematic_viscosity_m2_s": self.kinematic_viscosity_m2_s,
            "motion": {
                "type": m.type,
                "alpha0_deg": m.alpha0_deg,
                "amplitude_deg": m.amplitude_deg,
                "pivot_x_c": m.pivot_x_c,
                "freqs_hz": list(m.freqs_hz),
                "cycles": m.cycles,
                "samples_per_cycle": m.samples_per_cycle,
                "case_roles": list(m.case_roles),
            },
            "effects": {k: dict(v) for k, v in self.effects.items()},
            "noise": {"cp_std_fraction": self.cp_std_fraction},
            "seed": self.seed,
        }
        if self.taps is not None:
            d["taps"] = {
                "x_c": list(self.taps.x_c),
                "surface": ["upper" if u else "lower" for u in self.taps.upper],
                "names": list(self.taps.names),
            }
        return d

    def with_effects(self, effects: Mapping[str, Mapping[str, Any]]) -> AirfoilSpec:
        """A copy with another effect set (validated)."""
        d = self.to_dict()
        d["effects"] = {k: dict(v) for k, v in effects.items()}
        return parse_spec(d, origin=self.origin)


def parse_effects(
    data: Any,
    origin: str,
    *,
    forbidden: Mapping[str, str] | None = None,
    known_points: set[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Validate an ``effects:`` mapping against the library (names, parameters, ranges, requirements).

    ``forbidden``: effect name → why this kind of spec cannot have it; ``known_points``: the names a
    ``port_bias`` may refer to (None: checked by the caller). Shared by every spec kind."""
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise SpecError(f"{origin}: effects: expected a mapping of effect name to parameters")
    out: dict[str, dict[str, Any]] = {}
    for name, params in data.items():
        if name not in EFFECTS:
            raise SpecError(f"{origin}: effects.{name}: unknown effect (known: {', '.join(EFFECTS)})")
        if forbidden and name in forbidden:
            raise SpecError(f"{origin}: effects.{name}: {forbidden[name]}")
        info = EFFECTS[name]
        params = {} if params is None else params
        if not isinstance(params, Mapping):
            raise SpecError(f"{origin}: effects.{name}: expected a mapping of parameters")
        parsed: dict[str, Any] = {}
        if name == "port_bias":
            lo, hi = PORT_BIAS_RANGE_CP
            for tap, v in params.items():
                if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= float(v) <= hi:
                    raise SpecError(f"{origin}: effects.port_bias.{tap}: expected a Cp offset in [{lo}, {hi}]")
                if known_points is not None and str(tap) not in known_points:
                    raise SpecError(f"{origin}: effects.port_bias.{tap}: no surface point of that name")
                parsed[str(tap)] = float(v)
        else:
            for p, v in params.items():
                if p not in info.params:
                    raise SpecError(
                        f"{origin}: effects.{name}.{p}: unknown parameter (known: {', '.join(info.params)})"
                    )
                pi = info.params[p]
                if isinstance(v, bool) or not isinstance(v, int | float) or v != v:
                    raise SpecError(f"{origin}: effects.{name}.{p}: expected a number, got {v!r}")
                # Twice the documented range is allowed (users explore); beyond that it is a typo.
                span = pi.high - pi.low
                if not pi.low - span <= float(v) <= pi.high + span:
                    raise SpecError(
                        f"{origin}: effects.{name}.{p}: {v} [{pi.unit}] is far outside the physical "
                        f"range [{pi.low}, {pi.high}]"
                    )
                parsed[p] = float(v)
        out[name] = parsed
    for name in out:
        for req in EFFECTS[name].requires:
            if req not in out:
                raise SpecError(f"{origin}: effects.{name}: requires effect '{req}' to be switched on too")
    return out


def parse_spec(data: Any, *, origin: str = "<spec>") -> AirfoilSpec:
    """Validate a spec mapping (as loaded from YAML) into an :class:`AirfoilSpec`."""
    r = _Reader(data, origin, "")
    kind = r.text("kind")
    if kind != "airfoil":
        raise r.fail("kind", f"'{kind}' is not an airfoil spec (expected 'airfoil')")
    airfoil = r.text("airfoil").lower().removeprefix("naca")
    if len(airfoil) != 4 or not airfoil.isdigit():
        raise r.fail("airfoil", f"expected a NACA 4-digit name such as naca0012, got {r.data['airfoil']!r}")
    mr = _Reader(r.raw("motion"), origin, "motion")
    mtype = mr.text("type")
    if mtype != "sinusoidal_pitch":
        raise mr.fail("type", f"'{mtype}' is not supported (supported: sinusoidal_pitch)")
    freqs = tuple(float(f) for f in mr.seq("freqs_hz"))
    if not freqs or any(not f > 0 for f in freqs):
        raise mr.fail("freqs_hz", "expected a non-empty list of positive frequencies [Hz]")
    roles = tuple(str(x) for x in mr.seq("case_roles", ["unassigned"] * len(freqs)))
    if len(roles) != len(freqs) or any(x not in CASE_ROLES for x in roles):
        raise mr.fail("case_roles", f"expected {len(freqs)} entries from {CASE_ROLES}")
    motion = Motion(
        alpha0_deg=mr.num("alpha0_deg", lo=-90, hi=90),
        amplitude_deg=mr.num("amplitude_deg", lo=0, hi=45),
        pivot_x_c=mr.num("pivot_x_c", 0.25, lo=0.0, hi=1.0),
        freqs_hz=freqs,
        cycles=mr.integer("cycles", 3, lo=1),
        samples_per_cycle=mr.integer("samples_per_cycle", 128, lo=8),
        case_roles=roles,
        type=mtype,
    )
    mr.finish()

    taps: Taps | None = None
    if (traw := r.raw("taps", None)) is not None:
        tr = _Reader(traw, origin, "taps")
        x_c = tuple(float(x) for x in tr.seq("x_c"))
        surf = tuple(str(s) for s in tr.seq("surface"))
        if len(surf) != len(x_c) or any(s not in ("upper", "lower") for s in surf):
            raise tr.fail("surface", f"expected {len(x_c)} entries, each 'upper' or 'lower'")
        if any(not 0.0 <= x <= 1.0 for x in x_c):
            raise tr.fail("x_c", "tap positions must lie in [0, 1] (fraction of chord)")
        names = tuple(str(n) for n in tr.seq("names", [f"p{i:04d}" for i in range(len(x_c))]))
        if len(names) != len(x_c) or len(set(names)) != len(names):
            raise tr.fail("names", f"expected {len(x_c)} unique names")
        tr.finish()
        taps = Taps(x_c=x_c, upper=tuple(s == "upper" for s in surf), names=names)

    noise = _Reader(r.raw("noise", {}), origin, "noise")
    cp_std = noise.num("cp_std_fraction", 0.0, lo=0.0, hi=0.5)
    noise.finish()

    effects = parse_effects(r.raw("effects", {}), origin)
    if "port_bias" in effects:
        known = set(taps.names) if taps is not None else None
        for tap in effects["port_bias"]:
            if known is not None and tap not in known:
                raise SpecError(f"{origin}: effects.port_bias.{tap}: no tap of that name in taps.names")

    spec = AirfoilSpec(
        name=r.text("name", "airfoil"),
        source=r.text("source", "vdm-aero sim.airfoil"),
        airfoil=f"naca{airfoil}",
        chord_m=r.num("chord_m", positive=True),
        span_m=r.num("span_m", positive=True),
        surface_points=r.integer("surface_points", lo=16),
        speed_m_s=r.num("speed_m_s", positive=True),
        density_kg_m3=r.num("density_kg_m3", 1.225, positive=True),
        kinematic_viscosity_m2_s=r.num("kinematic_viscosity_m2_s", 1.46e-5, positive=True),
        motion=motion,
        effects=effects,
        taps=taps,
        cp_std_fraction=cp_std,
        seed=r.integer("seed", 0, lo=0),
        kind=kind,
        origin=origin,
    )
    r.finish()
    return spec


def load_spec(path: str | Path) -> AirfoilSpec:
    """Read and validate a spec file."""
    p = Path(path)
    data = read_yaml_file(p)
    return parse_spec(data, origin=str(p))
