"""Flight scenarios (YAML, ``kind: flight-scenario``): typed, frozen, validated with messages that name the key.

A scenario names its vehicle preset, home position, Earth magnetic field (stated with its source: there is
no built-in location), atmosphere, wind and turbulence, the route, the start state, every sensor's grade
and installation, GNSS outage and glitch windows, the seed and the duration. Every key is required unless
documented as optional (docs/flight-sim.md lists them); unknown keys are errors. Shipped scenarios live
in ``sim/presets/scenarios/*.yaml`` (:func:`scenario_names`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Final

import numpy as np

from sim.flight.actuators import ACTUATORS, ActuatorSetSpec
from sim.flight.asbuilt import AS_BUILT_EFFECTS, AS_BUILT_PRESETS, AsBuiltSpec, draw_airframe
from sim.flight.environment import TURBULENCE_LEVELS, Atmosphere, SteadyWind, WindProfile, WindShear
from sim.flight.guidance import AUTOPILOT_GAINS, AutopilotGains, LoiterRoute, Route, SurveyRoute, WaypointRoute
from sim.flight.propulsion import PROPELLERS, PropulsionSpec
from sim.flight.sensors import (
    BARO_GRADES,
    GNSS_GRADES,
    IMU_GRADES,
    MAG_GRADES,
    PITOT_GRADES,
    PORT_GRADES,
    BaroGrade,
    GnssGlitch,
    GnssGrade,
    ImuGrade,
    MagGrade,
    PitotGrade,
    PortGrade,
    TimeWindow,
)
from sim.flight.world_effects import FLEET_SEED, HARSH, check_world_effects
from sim.spec_reader import SpecReader, parse_yaml
from vdm_aero._typing import F64Array
from vdm_aero.errors import ModelError, SpecError
from vdm_aero.model import read_model_yaml

__all__ = [
    "KIND",
    "MANOEUVRE_TYPES",
    "VEHICLES",
    "GnssConfig",
    "MagneticField",
    "Manoeuvre",
    "PortsConfig",
    "Scenario",
    "SimulationConfig",
    "StartState",
    "VehiclePreset",
    "load_scenario",
    "parse_scenario",
    "port_points_array",
    "scenario_names",
    "with_world",
]

KIND: Final = "flight-scenario"
_SCENARIO_DIR: Final = ("presets", "scenarios")
PORT_NAME_MAX_CHARS: Final = 10  # MAVLink NAMED_VALUE_FLOAT.name, how the mock autopilot sends each port


# -------------------------------------------------------------------------------------- vehicles
@dataclass(frozen=True)
class VehiclePreset:
    """A flyable vehicle: the airframe spec preset that defines its geometry, mass properties, surface
    resolution and aerodynamic effects (``sim/presets/<airframe_spec>.yaml``), its propulsion,
    actuators and autopilot tuning."""

    name: str
    airframe_spec: str
    propulsion: PropulsionSpec
    actuators: ActuatorSetSpec
    gains: AutopilotGains
    description: str
    as_built: AsBuiltSpec | None = None  # the built aircraft's differences from its design (sim.flight.asbuilt)


_UAV_2M_PROPULSION: Final = PropulsionSpec(
    propeller=PROPELLERS["apc-11x7e"],
    max_rev_s=150.0,  # 9000 rpm: ~1000 Kv outrunner on a loaded 4S pack; 18.5 N static thrust (T/W 0.75)
    # hub just ahead of the nose (x_nose = 0.42 m), on the fuselage axis (z measured from the CG)
    thrust_point_b=(0.45, 0.0, 0.0),
    spin=1,
)

VEHICLES: Final = {
    "uav-2m": VehiclePreset(
        name="uav-2m",
        airframe_spec="uav-envelope",
        propulsion=_UAV_2M_PROPULSION,
        actuators=ACTUATORS["uav-2m-servos"],
        gains=AUTOPILOT_GAINS["uav-2m"],
        description="the reference 2 m / 2.5 kg UAV of sim.airframe (uav-envelope spec: 5000 surface points, "
        "static separation, apparent mass and skin friction) with an electric tractor propeller",
    ),
    "uav-2m-asbuilt": VehiclePreset(
        name="uav-2m-asbuilt",
        airframe_spec="uav-envelope",
        propulsion=_UAV_2M_PROPULSION,
        actuators=ACTUATORS["uav-2m-servos"],
        gains=AUTOPILOT_GAINS["uav-2m"],
        description="the reference UAV as built: its design (uav-2m) plus rigging errors, control effectiveness, "
        "a rough skin, slipstream, unsteady aerodynamics, a payload, port installation errors and the installed "
        "propeller (sim.flight.asbuilt; each switched by the scenario's as_built_effects)",
        as_built=AS_BUILT_PRESETS["uav-2m-asbuilt"],
    ),
}
"""Named vehicle presets."""


# ------------------------------------------------------------------------------------ dataclasses
MANOEUVRE_TYPES: Final = ("airspeed", "height", "doublet", "throttle")
DOUBLET_AXES: Final = ("roll", "pitch", "yaw")


@dataclass(frozen=True)
class Manoeuvre:
    """A scripted excitation on top of the route (calibration flights):

    * ``airspeed``: from ``start_s`` the autopilot holds ``value`` [m/s] (speed sweeps);
    * ``height``: from ``start_s`` the route's height demand is raised by ``value`` [m] (climbs and
      descents: throttle steps through the energy controller);
    * ``doublet``: at ``start_s`` a surface doublet on ``axis`` of ``value`` [deg], +value for half of
      ``duration_s`` then −value for the other half, added to the autopilot's command;
    * ``throttle``: from ``start_s`` for ``duration_s`` the throttle is held at ``value`` (0…1).
    """

    type: str
    start_s: float
    value: float
    duration_s: float = 0.0
    axis: str = ""


@dataclass(frozen=True)
class MagneticField:
    """The Earth's field at home in NED [T] and where the numbers come from (model, epoch, location)."""

    ned_t: tuple[float, float, float]
    source: str


@dataclass(frozen=True)
class StartState:
    """Where the flight starts: trimmed level flight at (north, east) [m] from home, ``height_m`` above
    home, heading [deg from north] and airspeed [m/s]."""

    north_m: float
    east_m: float
    height_m: float
    heading_deg: float
    airspeed_m_s: float


@dataclass(frozen=True)
class ImuConfig:
    grade: ImuGrade
    vibration_multiplier: float


@dataclass(frozen=True)
class GnssConfig:
    grade: GnssGrade
    outages: tuple[TimeWindow, ...]
    glitches: tuple[GnssGlitch, ...]


@dataclass(frozen=True)
class MagConfig:
    grade: MagGrade
    hard_iron_b_t: tuple[float, float, float]


@dataclass(frozen=True)
class PortsConfig:
    """Pressure ports: transducer grade, sample rate [Hz], tubing lag [s], names and requested body-frame
    locations (n, 3) [m], the snapping tolerance [m] and where the layout came from."""

    grade: PortGrade
    rate_hz: float
    lag_s: float
    names: tuple[str, ...]
    points_b: tuple[tuple[float, float, float], ...]
    tolerance_m: float
    layout_source: str


@dataclass(frozen=True)
class SimulationConfig:
    """Integration rates [Hz]: rigid body (RK4; also the IMU rate and the world step), aerodynamic
    re-expansion (:class:`sim.flight.aero.LinearizedAero`) and the autopilot/servo outputs."""

    physics_rate_hz: float
    aero_rate_hz: float
    control_rate_hz: float

    @property
    def dt_s(self) -> float:
        return 1.0 / self.physics_rate_hz

    def steps_per(self, rate_hz: float) -> int:
        return round(self.physics_rate_hz / rate_hz)


@dataclass(frozen=True)
class Scenario:
    """A complete, validated flight scenario (SI units; angles in degrees where the name says so)."""

    name: str
    description: str
    seed: int
    duration_s: float
    vehicle: VehiclePreset
    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float
    magnetic_field: MagneticField
    atmosphere: Atmosphere
    wind: SteadyWind
    turbulence: str
    route: Route
    start: StartState
    imu: ImuConfig
    gnss: GnssConfig
    baro: BaroGrade
    mag: MagConfig
    airspeed: PitotGrade | None
    ports: PortsConfig
    simulation: SimulationConfig
    as_built_effects: frozenset[str] = frozenset()
    manoeuvres: tuple[Manoeuvre, ...] = ()
    wind_shear: WindShear | None = None
    wind_profile: WindProfile | None = None
    payload_release_s: float | None = None  # the as-built payload is dropped at this time [s] (None: kept)
    # the harsh world (sim.flight.world_effects): which effects are on, and which airframe of the fleet flies
    # (its sensor installation, and with ``fleet`` its build, are drawn from the fleet's generator and it)
    world_effects: frozenset[str] = frozenset()
    airframe_index: int = 0
    origin: str = field(default="<scenario>", compare=False)

    @property
    def n_steps(self) -> int:
        """World steps in ``duration_s``."""
        return round(self.duration_s * self.simulation.physics_rate_hz)


# ---------------------------------------------------------------------------------------- reader
class _Reader(SpecReader):
    """:class:`sim.spec_reader.SpecReader` plus the few accessors scenarios need (every key required)."""

    def sub(self, k: str, default: Any = ...) -> _Reader:
        return _Reader(self.raw(k, default), self.origin, self.key(k))

    def has(self, k: str) -> bool:
        return k in self.data

    def boolean(self, k: str) -> bool:
        v = self.raw(k)
        if not isinstance(v, bool):
            raise self.fail(k, f"expected true or false, got {v!r}")
        return v

    def choice(self, k: str, options: Mapping[str, Any]) -> str:
        v = self.text(k)
        if v not in options:
            raise self.fail(k, f"unknown {k} {v!r} (known: {', '.join(options)})")
        return v


def _triple(v: tuple[float, ...]) -> tuple[float, float, float]:
    return (v[0], v[1], v[2])


# ------------------------------------------------------------------------------------------ parts
def _window(r: _Reader, where: str, duration_s: float) -> TimeWindow:
    w = TimeWindow(start_s=r.num("start_s", lo=0.0), end_s=r.num("end_s", lo=0.0))
    if w.end_s <= w.start_s:
        raise r.fail("end_s", f"must be after start_s ({w.start_s}), got {w.end_s}")
    if w.start_s >= duration_s:
        raise r.fail("start_s", f"{where} starts after the end of the flight (duration_s = {duration_s})")
    return w


def _parse_route(r: _Reader) -> Route:
    rtype = r.text("type")
    airspeed = r.num("airspeed_m_s", lo=8.0, hi=40.0)
    route: Route
    if rtype == "waypoints":
        items = r.seq("waypoints")
        if len(items) < 2:
            raise r.fail("waypoints", f"expected at least 2 waypoints, got {len(items)}")
        wps = []
        for i, item in enumerate(items):
            wr = _Reader(item, r.origin, f"{r.key('waypoints')}[{i}]")
            wps.append((wr.num("north_m"), wr.num("east_m"), wr.num("height_m", lo=10.0, hi=3000.0)))
            wr.finish()
        route = WaypointRoute(
            waypoints=tuple(wps), airspeed_m_s=airspeed, acceptance_m=r.num("acceptance_m", positive=True)
        )
    elif rtype == "loiter":
        c = r.numbers("centre_ne_m", n=2)
        route = LoiterRoute(
            centre_ne_m=(c[0], c[1]),
            radius_m=r.num("radius_m", lo=30.0),
            height_m=r.num("height_m", lo=10.0, hi=3000.0),
            clockwise=r.boolean("clockwise"),
            airspeed_m_s=airspeed,
        )
    elif rtype == "survey":
        o = r.numbers("origin_ne_m", n=2)
        route = SurveyRoute(
            origin_ne_m=(o[0], o[1]),
            length_m=r.num("length_m", positive=True),
            width_m=r.num("width_m", lo=0.0),
            spacing_m=r.num("spacing_m", positive=True),
            heading_deg=r.num("heading_deg", lo=-360.0, hi=360.0),
            height_m=r.num("height_m", lo=10.0, hi=3000.0),
            airspeed_m_s=airspeed,
            acceptance_m=r.num("acceptance_m", positive=True),
        )
    else:
        raise r.fail("type", f"{rtype!r} is not a route type (known: waypoints, loiter, survey)")
    r.finish()
    return route


def _parse_ports(r: _Reader) -> PortsConfig:
    grade = PORT_GRADES[r.choice("grade", PORT_GRADES)]
    rate = r.num("rate_hz", lo=50.0, hi=100.0)
    lag = r.num("lag_s", lo=0.0, hi=1.0)
    tol = r.num("snap_tolerance_m", positive=True)
    names: list[str] = []
    points: list[tuple[float, float, float]] = []
    if r.has("model_dir") and r.has("points"):
        raise r.fail("model_dir", "give either points or model_dir, not both")
    if r.has("model_dir"):
        rel = Path(r.text("model_dir"))
        base = Path(r.origin).parent if not r.origin.startswith("preset:") else Path.cwd()
        root = rel if rel.is_absolute() else base / rel
        try:
            meta = read_model_yaml(root)
            for p in meta.get("ports") or []:
                names.append(str(p["name"]))
                points.append(_triple(tuple(float(v) for v in p["point_b"])))
        except (ModelError, KeyError, TypeError, ValueError) as e:
            raise r.fail("model_dir", f"cannot read the ports of {root}: {e}") from None
        source = f"model {root}"
    else:
        for i, item in enumerate(r.seq("points")):
            pr = _Reader(item, r.origin, f"{r.key('points')}[{i}]")
            names.append(pr.text("name"))
            points.append(_triple(pr.numbers("point_b", n=3)))
            pr.finish()
        source = "scenario"
    key = "model_dir" if source != "scenario" else "points"
    if not names:
        raise r.fail(key, "no ports given")
    if len(set(names)) != len(names):
        raise r.fail(key, "port names must be unique")
    for name in names:
        if not (0 < len(name) <= PORT_NAME_MAX_CHARS and name.isascii() and name.isprintable()):
            raise r.fail(key, f"port names are 1..{PORT_NAME_MAX_CHARS} printable ASCII characters, got {name!r}")
    r.finish()
    return PortsConfig(
        grade=grade,
        rate_hz=rate,
        lag_s=lag,
        names=tuple(names),
        points_b=tuple(points),
        tolerance_m=tol,
        layout_source=source,
    )


def parse_scenario(data: Any, *, origin: str = "<scenario>") -> Scenario:
    """Validate a scenario mapping (as loaded from YAML) into a :class:`Scenario`."""
    r = _Reader(data, origin, "")
    kind = r.text("kind")
    if kind != KIND:
        raise r.fail("kind", f"{kind!r} is not a flight scenario (expected {KIND!r})")
    duration = r.num("duration_s", positive=True)

    sr = r.sub("simulation")
    sim = SimulationConfig(
        physics_rate_hz=sr.num("physics_rate_hz", lo=400.0, hi=4000.0),
        aero_rate_hz=sr.num("aero_rate_hz", positive=True),
        control_rate_hz=sr.num("control_rate_hz", positive=True),
    )
    for k in ("aero_rate_hz", "control_rate_hz"):
        _check_divides(sr, k, getattr(sim, k), sim.physics_rate_hz)
    sr.finish()

    hr = r.sub("home")
    home = (
        hr.num("lat_deg", lo=-89.0, hi=89.0),
        hr.num("lon_deg", lo=-180.0, hi=180.0),
        hr.num("alt_m", lo=-400.0, hi=8000.0),
    )
    hr.finish()
    mr = r.sub("magnetic_field")
    ned = mr.numbers("ned_nt", n=3)
    if not 20_000.0 <= math.hypot(*ned) <= 70_000.0:
        raise mr.fail("ned_nt", f"|B| = {math.hypot(*ned):.0f} nT is not an Earth field (20,000–70,000 nT)")
    mag_field = MagneticField(ned_t=_triple(tuple(v * 1e-9 for v in ned)), source=mr.text("source"))
    mr.finish()
    ar = r.sub("atmosphere")
    atmosphere = Atmosphere(isa_delta_t_k=ar.num("isa_delta_t_k", lo=-40.0, hi=40.0))
    ar.finish()
    wr = r.sub("wind")
    wind = SteadyWind(speed_m_s=wr.num("speed_m_s", lo=0.0, hi=20.0), from_deg=wr.num("from_deg", lo=-360.0, hi=360.0))
    shear = None
    if wr.has("shear"):
        sr = wr.sub("shear")
        shear = WindShear(
            start_s=sr.num("start_s", lo=0.0),
            ramp_s=sr.num("ramp_s", lo=0.0, hi=600.0),
            to=SteadyWind(
                speed_m_s=sr.num("speed_m_s", lo=0.0, hi=20.0), from_deg=sr.num("from_deg", lo=-360.0, hi=360.0)
            ),
        )
        sr.finish()
    profile = None
    if wr.has("profile"):  # optional: the wind changes with height (power law with veer)
        pr_ = wr.sub("profile")
        profile = WindProfile(
            reference_height_m=pr_.num("reference_height_m", lo=1.0, hi=1000.0),
            exponent=pr_.num("exponent", lo=0.0, hi=0.6),
            veer_deg_per_100m=pr_.num("veer_deg_per_100m", lo=-30.0, hi=30.0),
        )
        pr_.finish()
    wr.finish()
    tr = r.sub("turbulence")
    turbulence = tr.choice("level", TURBULENCE_LEVELS)
    tr.finish()

    route = _parse_route(r.sub("route"))
    st = r.sub("start")
    start = StartState(
        north_m=st.num("north_m"),
        east_m=st.num("east_m"),
        height_m=st.num("height_m", lo=10.0, hi=3000.0),
        heading_deg=st.num("heading_deg", lo=-360.0, hi=360.0),
        airspeed_m_s=st.num("airspeed_m_s", lo=8.0, hi=40.0),
    )
    st.finish()

    sens = r.sub("sensors")
    ir = sens.sub("imu")
    imu = ImuConfig(
        grade=IMU_GRADES[ir.choice("grade", IMU_GRADES)],
        vibration_multiplier=ir.num("vibration_multiplier", lo=1.0, hi=20.0),
    )
    ir.finish()
    gr = sens.sub("gnss")
    outages = []
    for i, w in enumerate(gr.seq("outages")):
        wr_ = _Reader(w, origin, f"{gr.key('outages')}[{i}]")
        outages.append(_window(wr_, "the outage", duration))
        wr_.finish()
    glitches = []
    for i, w in enumerate(gr.seq("glitches")):
        gl = _Reader(w, origin, f"{gr.key('glitches')}[{i}]")
        offset = _triple(gl.numbers("offset_ned_m", n=3))
        glitches.append(GnssGlitch(window=_window(gl, "the glitch", duration), offset_ned_m=offset))
        gl.finish()
    gnss_grade = GNSS_GRADES[gr.choice("grade", GNSS_GRADES)]
    _check_divides(gr, "grade", gnss_grade.rate_hz, sim.physics_rate_hz)
    gnss = GnssConfig(grade=gnss_grade, outages=tuple(outages), glitches=tuple(glitches))
    gr.finish()
    br = sens.sub("baro")
    baro = BARO_GRADES[br.choice("grade", BARO_GRADES)]
    _check_divides(br, "grade", baro.rate_hz, sim.physics_rate_hz)
    br.finish()
    mgr = sens.sub("mag")
    mag_grade = MAG_GRADES[mgr.choice("grade", MAG_GRADES)]
    _check_divides(mgr, "grade", mag_grade.rate_hz, sim.physics_rate_hz)
    mag = MagConfig(grade=mag_grade, hard_iron_b_t=_triple(tuple(v * 1e-9 for v in mgr.numbers("hard_iron_b_nt", n=3))))
    mgr.finish()
    airspeed: PitotGrade | None = None
    if sens.raw("airspeed") is not None:  # the key is required; null states "no airspeed sensor"
        pr = sens.sub("airspeed")
        airspeed = PITOT_GRADES[pr.choice("grade", PITOT_GRADES)]
        _check_divides(pr, "grade", airspeed.rate_hz, sim.physics_rate_hz)
        pr.finish()
    portr = sens.sub("ports")
    ports = _parse_ports(portr)
    _check_divides(portr, "rate_hz", ports.rate_hz, sim.physics_rate_hz)
    sens.finish()

    vehicle = VEHICLES[r.choice("vehicle", VEHICLES)]
    effects: frozenset[str] = frozenset()
    if vehicle.as_built is not None:  # required for a built aircraft: which differences are on
        raw = r.raw("as_built_effects")
        if raw == "all":
            effects = frozenset(AS_BUILT_EFFECTS)
        elif isinstance(raw, list) and all(isinstance(x, str) for x in raw):
            bad = sorted(set(raw) - set(AS_BUILT_EFFECTS))
            if bad:
                raise r.fail("as_built_effects", f"unknown effects {bad} (known: {', '.join(AS_BUILT_EFFECTS)})")
            effects = frozenset(raw)
        else:
            raise r.fail("as_built_effects", f"expected 'all' or a list of effect names, got {raw!r}")
    elif r.has("as_built_effects"):
        raise r.fail("as_built_effects", f"vehicle {vehicle.name} is a design, not an as-built aircraft")
    manoeuvres = _parse_manoeuvres(r, duration) if r.has("manoeuvres") else ()
    world_effects: frozenset[str] = frozenset()
    if r.has("world_effects"):  # optional: the harsh world's effects, "all" or a list (default: none)
        raw = r.raw("world_effects")
        if raw == "all":
            world_effects = HARSH
        elif isinstance(raw, list) and all(isinstance(x, str) for x in raw):
            try:
                world_effects = check_world_effects(tuple(raw), r.key("world_effects"))
            except SpecError as e:
                raise r.fail("world_effects", str(e).split(": ", 1)[1]) from None
        else:
            raise r.fail("world_effects", f"expected 'all' or a list of effect names, got {raw!r}")
    airframe_index = r.integer("airframe_index") if r.has("airframe_index") else 0
    release = None
    if r.has("payload_release_s"):  # optional: the as-built payload is dropped then (a delivery)
        if "mass_properties" not in effects:
            raise r.fail("payload_release_s", "only an as-built vehicle with mass_properties carries a payload")
        release = r.num("payload_release_s", lo=0.0, hi=duration)
    if r.has("max_bank_deg"):  # the autopilot's bank limit (ArduPlane ROLL_LIMIT_DEG) for manoeuvring flight
        bank = math.radians(r.num("max_bank_deg", lo=10.0, hi=60.0))
        vehicle = replace(vehicle, gains=replace(vehicle.gains, max_bank_rad=bank))

    scenario = Scenario(
        name=r.text("name"),
        description=r.text("description"),
        seed=r.integer("seed"),
        duration_s=duration,
        vehicle=vehicle,
        home_lat_deg=home[0],
        home_lon_deg=home[1],
        home_alt_m=home[2],
        magnetic_field=mag_field,
        atmosphere=atmosphere,
        wind=wind,
        turbulence=turbulence,
        route=route,
        start=start,
        imu=imu,
        gnss=gnss,
        baro=baro,
        mag=mag,
        airspeed=airspeed,
        ports=ports,
        simulation=sim,
        as_built_effects=effects,
        manoeuvres=manoeuvres,
        wind_shear=shear,
        wind_profile=profile,
        payload_release_s=release,
        world_effects=world_effects,
        airframe_index=airframe_index,
        origin=origin,
    )
    r.finish()
    return scenario


def _parse_manoeuvres(r: _Reader, duration_s: float) -> tuple[Manoeuvre, ...]:
    out = []
    for i, item in enumerate(r.seq("manoeuvres")):
        mr = _Reader(item, r.origin, f"{r.key('manoeuvres')}[{i}]")
        kind = mr.text("type")
        if kind not in MANOEUVRE_TYPES:
            raise mr.fail("type", f"unknown manoeuvre {kind!r} (known: {', '.join(MANOEUVRE_TYPES)})")
        start = mr.num("start_s", lo=0.0, hi=duration_s)
        if kind == "airspeed":
            m = Manoeuvre(kind, start, mr.num("airspeed_m_s", lo=10.0, hi=30.0))
        elif kind == "height":
            m = Manoeuvre(kind, start, mr.num("height_change_m", lo=-200.0, hi=200.0))
        elif kind == "doublet":
            axis = mr.text("axis")
            if axis not in DOUBLET_AXES:
                raise mr.fail("axis", f"expected one of {', '.join(DOUBLET_AXES)}, got {axis!r}")
            m = Manoeuvre(
                kind, start, mr.num("amplitude_deg", lo=0.5, hi=15.0), mr.num("period_s", lo=0.2, hi=10.0), axis
            )
        else:
            m = Manoeuvre(kind, start, mr.num("throttle", lo=0.0, hi=1.0), mr.num("duration_s", lo=0.5, hi=120.0))
        mr.finish()
        out.append(m)
    return tuple(sorted(out, key=lambda m: m.start_s))


def _check_divides(r: _Reader, k: str, rate_hz: float, physics_rate_hz: float) -> None:
    n = physics_rate_hz / rate_hz
    if rate_hz > physics_rate_hz or abs(n - round(n)) > 1e-9:
        raise r.fail(k, f"rate {rate_hz:g} Hz must divide the physics rate {physics_rate_hz:g} Hz")


# -------------------------------------------------------------------------------------- loading
def scenario_names() -> list[str]:
    """Names of the shipped scenarios (``sim/presets/scenarios/*.yaml``), sorted."""
    root = resources.files("sim").joinpath(*_SCENARIO_DIR)
    return sorted(p.name.removesuffix(".yaml") for p in root.iterdir() if p.name.endswith(".yaml"))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A shipped scenario by name, or a scenario file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        try:
            text = p.read_text()
        except OSError as e:
            raise SpecError(f"{p}: cannot read scenario: {e.strerror or e}") from None
        origin = str(p)
    else:
        name = str(name_or_path)
        if name not in scenario_names():
            raise SpecError(f"{name}: no such scenario and no such file (scenarios: {', '.join(scenario_names())})")
        text = resources.files("sim").joinpath(*_SCENARIO_DIR, f"{name}.yaml").read_text()
        origin = f"preset:{name}"
    return parse_scenario(parse_yaml(text, origin), origin=origin)


def with_world(scenario: Scenario, effects: frozenset[str], airframe_index: int) -> Scenario:
    """The scenario in a world with ``effects`` (sim.flight.world_effects), flown by airframe ``airframe_index``
    of the fleet: its sensor installation, and with ``fleet`` its as-built airframe drawn from the build
    tolerances (:func:`sim.flight.asbuilt.draw_airframe`)."""
    vehicle = scenario.vehicle
    if "fleet" in effects and vehicle.as_built is not None:
        rng = np.random.default_rng([FLEET_SEED, 1, airframe_index])
        vehicle = replace(vehicle, as_built=draw_airframe(vehicle.as_built, rng, airframe_index))
    return replace(scenario, vehicle=vehicle, world_effects=frozenset(effects), airframe_index=airframe_index)


def port_points_array(ports: PortsConfig) -> F64Array:
    """The requested port locations (n, 3) [m]."""
    return np.asarray(ports.points_b, dtype=np.float64).reshape(-1, 3)
