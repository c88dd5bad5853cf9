"""``vdm-aero-vehicle/1``: the nominal vehicle description a user writes for their aircraft.

What the estimator side (calibration, navigation) may know about the airframe besides the design data set:
mass properties, reference geometry, the propeller, the servo PWM → deflection map, the IMU position and
the ports. It is a *description* (designer's numbers, weighed and measured once), not the as-built truth.
Every key is required; unknown keys are errors; messages name the file and the key path. See
docs/formats.md for the format key by key, and ``vdm_aero/vehicles/uav-2m.yaml`` for the reference UAV.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.dataset import Reference
from vdm_aero.errors import VehicleError
from vdm_aero.ports import Port

__all__ = [
    "VEHICLE_FORMAT",
    "MassDescription",
    "PropulsionDescription",
    "ServoChannel",
    "ServoMap",
    "VehicleDescription",
    "load_vehicle",
    "parse_vehicle",
    "vehicle_names",
]

VEHICLE_FORMAT: Final = "vdm-aero-vehicle/1"
PORT_MATCH_TOLERANCE_M: Final = 1e-3  # 1 mm: a description's port and a model's port are the same hole
REFERENCE_RTOL: Final = 1e-6


@dataclass(frozen=True)
class MassDescription:
    """Mass [kg], inertia about the CG in body FRD axes [kg·m²] (Ixz the tensor entry), CG position from
    the body origin (the aero model's moment reference) [m]."""

    mass_kg: float
    ixx_kg_m2: float
    iyy_kg_m2: float
    izz_kg_m2: float
    ixz_kg_m2: float
    cg_b_m: tuple[float, float, float]

    @property
    def inertia_kg_m2(self) -> F64Array:
        return np.array(
            [[self.ixx_kg_m2, 0.0, self.ixz_kg_m2], [0.0, self.iyy_kg_m2, 0.0], [self.ixz_kg_m2, 0.0, self.izz_kg_m2]]
        )


@dataclass(frozen=True)
class PropulsionDescription:
    """Fixed-pitch propeller with linear C_T(J) = C_T0(1 − J/J_T), C_P(J) = C_P0(1 − J/J_P), speed
    n = n_max·δ_t [rev/s], thrust along body +x at ``thrust_point_b_m`` [m]; ``spin`` +1 = clockwise seen
    from behind (the airframe feels −spin·Q about x)."""

    diameter_m: float
    ct0: float
    j_zero_thrust: float
    cp0: float
    j_zero_power: float
    max_rev_s: float
    thrust_point_b_m: tuple[float, float, float]
    spin: int

    def thrust_regressors(
        self, throttle: FloatArray | float, u_axial_m_s: FloatArray | float, rho_kg_m3: FloatArray | float
    ) -> tuple[F64Array, F64Array]:
        """The two thrust terms ρ·D⁴C_T0·n² and −ρ·D³(C_T0/J_T)·n·u [N] whose sum is the thrust."""
        n = self.max_rev_s * np.asarray(throttle, dtype=np.float64)
        rho = np.asarray(rho_kg_m3, dtype=np.float64)
        d = self.diameter_m
        return (
            rho * d**4 * self.ct0 * n * n,
            -rho * d**3 * (self.ct0 / self.j_zero_thrust) * n * np.asarray(u_axial_m_s, dtype=np.float64),
        )

    def thrust_torque(
        self, throttle: FloatArray | float, u_axial_m_s: FloatArray | float, rho_kg_m3: FloatArray | float
    ) -> tuple[F64Array, F64Array]:
        """Thrust [N] and shaft torque [N·m] (array or scalar inputs broadcast)."""
        n = self.max_rev_s * np.asarray(throttle, dtype=np.float64)
        u = np.asarray(u_axial_m_s, dtype=np.float64)
        rho = np.asarray(rho_kg_m3, dtype=np.float64)
        d = self.diameter_m
        t1, t2 = self.thrust_regressors(throttle, u, rho)
        q = rho * (d**5 * self.cp0 * n * n - d**4 * self.cp0 / self.j_zero_power * n * u) / (2.0 * math.pi)
        return t1 + t2, q


@dataclass(frozen=True)
class ServoChannel:
    """PWM → deflection: δ = (pwm − trim_us)/us_per_rad, PWM clipped to [min_us, max_us]."""

    trim_us: float
    us_per_rad: float
    min_us: float
    max_us: float

    def deflection_rad(self, pwm_us: FloatArray | float) -> F64Array:
        p = np.clip(np.asarray(pwm_us, dtype=np.float64), self.min_us, self.max_us)
        return np.asarray((p - self.trim_us) / self.us_per_rad)


SERVO_OUTPUTS: Final = 16  # SERVO_OUTPUT_RAW's servo1_raw … servo16_raw
ARDUPLANE_CHANNELS: Final = (1, 2, 3, 4)  # ArduPlane's default outputs of aileron, elevator, throttle, rudder


@dataclass(frozen=True)
class ServoMap:
    """The autopilot's servo outputs in SI; ``channels``: the outputs (1 … 16, SERVOn) of aileron, elevator,
    throttle and rudder (ArduPlane's defaults 1, 2, 3, 4; any SERVOn_FUNCTION assignment is a new mapping)."""

    aileron: ServoChannel
    elevator: ServoChannel
    rudder: ServoChannel
    throttle_min_us: float
    throttle_max_us: float
    channels: tuple[int, int, int, int] = ARDUPLANE_CHANNELS

    def surfaces_pwm_us(self, outputs_pwm_us: FloatArray) -> F64Array:
        """The PWM (…, 4) [µs] of aileron, elevator, throttle and rudder, in the flight log's ArduPlane column
        order, from every output (…, ≥ the highest mapped channel) [µs], output 1 first."""
        p = np.asarray(outputs_pwm_us, dtype=np.float64)
        return p[..., [c - 1 for c in self.channels]]

    def deflections_rad(self, pwm_us: FloatArray) -> tuple[F64Array, F64Array, F64Array, F64Array]:
        """(aileron [rad], elevator [rad], rudder [rad], throttle 0…1) from PWM (…, 4) [µs]."""
        p = np.asarray(pwm_us, dtype=np.float64)
        thr = (p[..., 2] - self.throttle_min_us) / (self.throttle_max_us - self.throttle_min_us)
        return (
            self.aileron.deflection_rad(p[..., 0]),
            self.elevator.deflection_rad(p[..., 1]),
            self.rudder.deflection_rad(p[..., 3]),
            np.clip(thr, 0.0, 1.0),
        )


@dataclass(frozen=True)
class VehicleDescription:
    """A nominal vehicle description (see the module docstring). ``ports`` is None for ``from_model``."""

    name: str
    description: str
    mass: MassDescription
    reference: Reference
    propulsion: PropulsionDescription
    servos: ServoMap
    imu_position_b_m: tuple[float, float, float]
    ports: tuple[Port, ...] | None
    origin: str = "<vehicle>"

    def check_reference(self, reference: Reference) -> None:
        """Refuse an aero model whose reference geometry is not this vehicle's."""
        a = (self.reference.area_m2, self.reference.chord_m, self.reference.span_m)
        b = (reference.area_m2, reference.chord_m, reference.span_m)
        if not np.allclose(a, b, rtol=REFERENCE_RTOL):
            raise VehicleError(f"{self.origin}: reference: {a} (area, chord, span) but the aero model has {b}")

    def check_ports(self, ports: tuple[Port, ...]) -> None:
        """Refuse an aero model whose ports are not the listed ones (by name, within 1 mm)."""
        if self.ports is None:
            return
        listed = {p.name: p for p in self.ports}
        for p in ports:
            q = listed.get(p.name)
            if q is None:
                raise VehicleError(f"{self.origin}: ports: the aero model's port {p.name} is not listed")
            d = float(np.linalg.norm(np.subtract(p.point_b, q.point_b)))
            if d > PORT_MATCH_TOLERANCE_M:
                raise VehicleError(f"{self.origin}: ports: {p.name} is {d * 1e3:.1f} mm from the aero model's port")


# ---------------------------------------------------------------------------------------------- reading
class _Keys:
    """A mapping read key by key: every key required, unknown keys refused, errors name the key path."""

    def __init__(self, data: Any, origin: str, path: str) -> None:
        if not isinstance(data, Mapping):
            raise VehicleError(f"{origin}: {path or 'top level'}: expected a mapping")
        self.data, self.origin, self.path = data, origin, path
        self.seen: set[str] = set()

    def key(self, k: str) -> str:
        return f"{self.path}.{k}" if self.path else k

    def fail(self, k: str, msg: str) -> VehicleError:
        return VehicleError(f"{self.origin}: {self.key(k)}: {msg}")

    def raw(self, k: str) -> Any:
        if k not in self.data:
            raise self.fail(k, "missing")
        self.seen.add(k)
        return self.data[k]

    def sub(self, k: str) -> _Keys:
        return _Keys(self.raw(k), self.origin, self.key(k))

    def text(self, k: str) -> str:
        v = self.raw(k)
        if not isinstance(v, str) or not v:
            raise self.fail(k, f"expected a non-empty string, got {v!r}")
        return v

    def num(self, k: str, *, lo: float = -math.inf, hi: float = math.inf, positive: bool = False) -> float:
        v = self.raw(k)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
            raise self.fail(k, f"expected a number, got {v!r}")
        x = float(v)
        if positive and not x > 0.0:
            raise self.fail(k, f"must be > 0, got {x:g}")
        if not lo <= x <= hi:
            raise self.fail(k, f"must be within [{lo:g}, {hi:g}], got {x:g}")
        return x

    def triple(self, k: str, *, limit: float = 10.0) -> tuple[float, float, float]:
        v = self.raw(k)
        if not isinstance(v, list) or len(v) != 3 or not all(isinstance(x, int | float) for x in v):
            raise self.fail(k, f"expected [x, y, z] in metres, got {v!r}")
        t = (float(v[0]), float(v[1]), float(v[2]))
        if max(abs(x) for x in t) > limit or not all(map(math.isfinite, t)):
            raise self.fail(k, f"each value must be within ±{limit:g} m, got {t}")
        return t

    def finish(self) -> None:
        extra = sorted(set(self.data) - self.seen)
        if extra:
            raise self.fail(str(extra[0]), "unknown key")


def _channel(servos: _Keys, surface: str, default: int) -> int:
    """A surface's output number (SERVOn, 1 … 16), read without using up the surface's section."""
    r = servos.sub(surface)
    v = r.data.get("channel", default)
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= SERVO_OUTPUTS:
        raise r.fail("channel", f"expected a servo output 1..{SERVO_OUTPUTS}, got {v!r}")
    return int(v)


def _servo(r: _Keys) -> ServoChannel:
    r.seen.add("channel")  # read by _channel
    ch = ServoChannel(
        trim_us=r.num("trim_us", lo=800.0, hi=2200.0),
        us_per_rad=r.num("us_per_rad", lo=-1e5, hi=1e5),
        min_us=r.num("min_us", lo=800.0, hi=2200.0),
        max_us=r.num("max_us", lo=800.0, hi=2200.0),
    )
    if abs(ch.us_per_rad) < 10.0:
        raise r.fail("us_per_rad", f"|us_per_rad| must be ≥ 10 µs/rad, got {ch.us_per_rad:g}")
    if not ch.min_us < ch.trim_us < ch.max_us:
        raise r.fail("trim_us", f"must lie between min_us ({ch.min_us:g}) and max_us ({ch.max_us:g})")
    r.finish()
    return ch


def parse_vehicle(doc: Any, origin: str) -> VehicleDescription:
    """Validate a parsed YAML document into a :class:`VehicleDescription`."""
    r = _Keys(doc, origin, "")
    fmt = r.raw("format")
    if fmt != VEHICLE_FORMAT:
        raise r.fail("format", f"{fmt!r} is not supported (expected {VEHICLE_FORMAT})")
    mr = r.sub("mass")
    mass = MassDescription(
        mass_kg=mr.num("mass_kg", positive=True, hi=1000.0),
        ixx_kg_m2=mr.num("ixx_kg_m2", positive=True),
        iyy_kg_m2=mr.num("iyy_kg_m2", positive=True),
        izz_kg_m2=mr.num("izz_kg_m2", positive=True),
        ixz_kg_m2=mr.num("ixz_kg_m2"),
        cg_b_m=mr.triple("cg_b_m", limit=1.0),
    )
    if np.any(np.linalg.eigvalsh(mass.inertia_kg_m2) <= 0.0):
        raise mr.fail("ixz_kg_m2", "the inertia tensor is not positive definite")
    mr.finish()
    rr = r.sub("reference")
    reference = Reference(
        rr.num("area_m2", positive=True), rr.num("chord_m", positive=True), rr.num("span_m", positive=True)
    )
    rr.finish()
    pr = r.sub("propulsion")
    spin = pr.raw("spin")
    if spin not in (1, -1) or isinstance(spin, bool):
        raise pr.fail("spin", f"expected +1 (clockwise seen from behind) or -1, got {spin!r}")
    prop = PropulsionDescription(
        diameter_m=pr.num("diameter_m", positive=True, hi=5.0),
        ct0=pr.num("ct0", positive=True, hi=1.0),
        j_zero_thrust=pr.num("j_zero_thrust", positive=True, hi=5.0),
        cp0=pr.num("cp0", positive=True, hi=1.0),
        j_zero_power=pr.num("j_zero_power", positive=True, hi=5.0),
        max_rev_s=pr.num("max_rev_s", positive=True, hi=1000.0),
        thrust_point_b_m=pr.triple("thrust_point_b_m"),
        spin=int(spin),
    )
    pr.finish()
    sr = r.sub("servos")
    tr = sr.sub("throttle")
    tmin, tmax = tr.num("min_us", lo=800.0, hi=2200.0), tr.num("max_us", lo=800.0, hi=2200.0)
    if not tmax > tmin:
        raise tr.fail("max_us", f"must exceed min_us ({tmin:g}), got {tmax:g}")
    tr.seen.add("channel")  # read by _channel
    tr.finish()
    surfaces = ("aileron", "elevator", "throttle", "rudder")
    channels = [_channel(sr, s, ARDUPLANE_CHANNELS[i]) for i, s in enumerate(surfaces)]
    for i, s in enumerate(surfaces):
        if channels[i] in channels[:i]:
            raise sr.sub(s).fail("channel", f"output {channels[i]} is already {surfaces[channels.index(channels[i])]}")
    servos = ServoMap(
        aileron=_servo(sr.sub("aileron")),
        elevator=_servo(sr.sub("elevator")),
        rudder=_servo(sr.sub("rudder")),
        throttle_min_us=tmin,
        throttle_max_us=tmax,
        channels=(channels[0], channels[1], channels[2], channels[3]),
    )
    sr.finish()
    ir = r.sub("imu")
    imu = ir.triple("position_b_m", limit=5.0)
    ir.finish()
    raw_ports = r.raw("ports")
    ports: tuple[Port, ...] | None
    if raw_ports == "from_model":
        ports = None
    elif isinstance(raw_ports, list) and raw_ports:
        out = []
        for i, p in enumerate(raw_ports):
            pk = _Keys(p, origin, f"ports[{i}]")
            name = pk.text("name")
            if len(name) > 10 or not name.isascii() or not name.isprintable():
                raise pk.fail("name", f"1..10 printable ASCII characters (MAVLink NAMED_VALUE_FLOAT), got {name!r}")
            out.append(Port(name, pk.triple("point_b_m"), pk.triple("normal_b", limit=1.0)))
            pk.finish()
        if len({p.name for p in out}) != len(out):
            raise r.fail("ports", "port names must be unique")
        ports = tuple(out)
    else:
        raise r.fail("ports", f"expected 'from_model' or a list of {{name, point_b_m, normal_b}}, got {raw_ports!r}")
    v = VehicleDescription(
        name=r.text("name"),
        description=r.text("description"),
        mass=mass,
        reference=reference,
        propulsion=prop,
        servos=servos,
        imu_position_b_m=imu,
        ports=ports,
        origin=origin,
    )
    r.finish()
    return v


def vehicle_names() -> list[str]:
    """The shipped descriptions (``vdm_aero/vehicles/*.yaml``)."""
    root = resources.files("vdm_aero").joinpath("vehicles")
    return sorted(p.name.removesuffix(".yaml") for p in root.iterdir() if p.name.endswith(".yaml"))


def load_vehicle(name_or_path: str | Path) -> VehicleDescription:
    """A shipped description by name, or a description file."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        origin = str(p)
        try:
            text = p.read_text()
        except OSError as e:
            raise VehicleError(f"{p}: cannot read vehicle description: {e.strerror or e}") from None
    else:
        if str(name_or_path) not in vehicle_names():
            raise VehicleError(f"{name_or_path}: no such vehicle description (shipped: {', '.join(vehicle_names())})")
        origin = f"vehicle:{name_or_path}"
        text = resources.files("vdm_aero").joinpath("vehicles", f"{name_or_path}.yaml").read_text()
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise VehicleError(f"{origin}: YAML syntax error{where}") from None
    return parse_vehicle(doc, origin)
