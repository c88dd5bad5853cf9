"""The flight simulator as a :class:`sim.flight.contract.World`: vehicle, trim, and the stepping loop.

``FlightWorld(load_scenario("survey-wind8"))`` builds the vehicle (airframe spec → pressure model, ~2 s for
the NeuralFoil separation calibration; pass a prebuilt :class:`Vehicle` to share it between worlds),
trims it at the start state, and then every :meth:`FlightWorld.step` advances one RK4 step at the physics
rate and returns a :class:`~sim.flight.contract.WorldTick` with the truth and whatever sensors sampled.

Order within a step (the inputs of a step are held over it: zero-order hold at the physics rate):

1. RK4 from t to t + Δ with the actuator positions, wind, α̇ and density of the step;
2. actuators advance towards their commands, turbulence advances, density follows the altitude;
3. at the aerodynamic rate the Taylor model is re-expanded at the new state, and earlier whenever the
   state has moved beyond :class:`~sim.flight.aero.ReexpansionBounds` from the expansion point;
4. the derivative at the new state (reused as the next step's first RK4 stage) gives the specific force,
   airspeed, α and β of the truth;
5. at the control rate the autopilot reads the truth and issues commands (and the servo outputs);
6. sensors sample at their rates; GNSS fixes are delivered after their latency.

α̇ (the aerodynamics' angle-of-attack rate: tail downwash lag, apparent mass) is the finite difference of α
low-passed with a 40 ms time constant, about the convection time over the tail arm at cruise (the
downwash reaching the tail is itself such an average), which also keeps the white-noise part of the
Dryden vertical gust from producing unbounded α̇.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Final

import numpy as np
import scipy.optimize
import yaml

from sim.airframe.geometry import AirframeGeometry
from sim.airframe.pressure import AirframePressureModel
from sim.airframe.simulate import AirframeSimulator
from sim.airframe.spec import AirframeSpec, parse_airframe_spec
from sim.airframe.vlm import FlightStates
from sim.flight.actuators import Actuators
from sim.flight.aero import LinearizedAero, PortLayout, StripAero, resolve_ports
from sim.flight.asbuilt import (
    AsBuiltSpec,
    AsBuiltStripAero,
    ControlMap,
    MassChanges,
    PortInstallationErrors,
    UnsteadyLag,
    as_built_airframe,
    as_built_mass,
    as_built_propulsion,
    check_effects,
    port_installation_errors,
)
from sim.flight.contract import VehicleTruth, WorldTick
from sim.flight.environment import G0_M_S2, DrydenTurbulence
from sim.flight.guidance import Autopilot, NavState, TrimPoint
from sim.flight.propulsion import PropulsionSpec
from sim.flight.rigid_body import (
    AircraftDynamics,
    Aux,
    MassProperties,
    StepInputs,
)
from sim.flight.scenario import VEHICLES, Manoeuvre, Scenario, VehiclePreset, port_points_array
from sim.flight.sensors import (
    IMU_GRADES,
    Barometer,
    Gnss,
    Imu,
    Magnetometer,
    PitotAirspeed,
    PressurePorts,
    ServoOutputs,
)
from sim.flight.world_effects import FLEET_SEED, IMU_INSTALLATION_EFFECTS, draw_installation, site_field_anomaly_ned_t
from sim.presets import preset_text
from vdm_aero._typing import F64Array
from vdm_aero.dataset import Reference
from vdm_aero.errors import SpecError, VdmAeroError
from vdm_aero.geodesy import WGS84_A_M, LocalFrame, earth_rate_ned, normal_gravity_m_s2
from vdm_aero.rotation import dcm_from_quat, euler_from_quat, quat_from_euler

__all__ = [
    "ALPHA_DOT_TAU_S",
    "Controller",
    "FlightEnvelopeError",
    "FlightWorld",
    "Trim",
    "Vehicle",
    "trim_flight",
]

ALPHA_DOT_TAU_S: Final = 0.04
_MAX_ALPHA_RAD: Final = math.radians(25.0)
_MAX_BETA_RAD: Final = math.radians(20.0)
_MIN_AIRSPEED_M_S: Final = 6.0
Controller = Callable[[float, NavState], tuple[float, float, float, float]]
"""A controller: (world time [s], truth) → commands (aileron, elevator, throttle, rudder)."""


class FlightEnvelopeError(VdmAeroError):
    """The aircraft left what the simulator can represent: ground impact, or α, β or airspeed outside the
    aerodynamic model's envelope (a crash or a loss of control)."""


# ---------------------------------------------------------------------------------------- vehicle
@dataclass(frozen=True, eq=False)
class Vehicle:
    """A built vehicle: the preset, its airframe spec, pressure model, geometry, reference and mass; for an
    as-built aircraft also the effects that are on, its CG's offset from the design CG [m] and its
    installed propulsion (thrust point from the true CG)."""

    preset: VehiclePreset
    airframe: AirframeSpec
    model: AirframePressureModel
    geometry: AirframeGeometry
    reference: Reference
    mass: MassProperties
    propulsion: PropulsionSpec
    effects: frozenset[str] = frozenset()
    r_cg_b: F64Array = field(default_factory=lambda: np.zeros(3))

    @property
    def as_built(self) -> AsBuiltSpec | None:
        return self.preset.as_built

    @classmethod
    def build(cls, preset: VehiclePreset | str, effects: frozenset[str] | None = None) -> Vehicle:
        """Build from a preset (or its name). A design vehicle's airframe spec effects are completed exactly
        as for its data set (NeuralFoil separation calibration), so its truth is the data set's truth; an
        as-built vehicle adds ``effects`` (default: all of them) of :mod:`sim.flight.asbuilt`."""
        if isinstance(preset, str):
            if preset not in VEHICLES:
                raise SpecError(f"{preset}: unknown vehicle (known: {', '.join(VEHICLES)})")
            preset = VEHICLES[preset]
        spec = parse_airframe_spec(
            yaml.safe_load(preset_text(preset.airframe_spec)), origin=f"preset:{preset.airframe_spec}"
        )
        asb = preset.as_built
        if asb is None:
            if effects:
                raise SpecError(f"{preset.name}: a design vehicle has no as-built effects ({sorted(effects)})")
            on: frozenset[str] = frozenset()
        else:
            on = check_effects(asb_all() if effects is None else effects, preset.name)
            spec = as_built_airframe(spec, asb, on)
        sim = AirframeSimulator(spec)
        mass = MassProperties.from_geometry(sim.geometry)
        r_cg = np.zeros(3)
        if asb is not None and "mass_properties" in on:
            mass, r_cg = _built_mass(sim.geometry, asb.mass)
        propulsion = preset.propulsion if asb is None else as_built_propulsion(preset.propulsion, asb, on, r_cg)
        return cls(
            preset=preset,
            airframe=spec,
            model=sim.model,
            geometry=sim.geometry,
            reference=sim.reference,
            mass=mass,
            propulsion=propulsion,
            effects=on,
            r_cg_b=r_cg,
        )

    def without_payload(self) -> Vehicle:
        """The same aircraft once its payload is released (a drop, a delivery): mass, CG and inertia without
        it, the thrust hub measured from the new CG. ValueError if it carries none (only an as-built vehicle
        with ``mass_properties`` does)."""
        asb = self.as_built
        if asb is None or "mass_properties" not in self.effects or not asb.mass.payload_kg > 0.0:
            raise ValueError(f"{self.preset.name}: carries no payload to release (as-built mass_properties off)")
        mass, r_cg = _built_mass(self.geometry, replace(asb.mass, payload_kg=0.0))
        propulsion = as_built_propulsion(self.preset.propulsion, asb, self.effects, r_cg)
        return replace(self, mass=mass, r_cg_b=r_cg, propulsion=propulsion)

    def port_layout(self, names: tuple[str, ...], points_b: F64Array, tolerance_m: float, where: str) -> PortLayout:
        """Ports snapped to this vehicle's surface points (see :func:`sim.flight.aero.resolve_ports`)."""
        try:
            return resolve_ports(self.geometry, names, points_b, tolerance_m, where)
        except ValueError as e:
            raise SpecError(str(e)) from None


def asb_all() -> frozenset[str]:
    from sim.flight.asbuilt import AS_BUILT_EFFECTS

    return frozenset(AS_BUILT_EFFECTS)


def _built_mass(geometry: AirframeGeometry, changes: MassChanges) -> tuple[MassProperties, F64Array]:
    """The as-built mass properties and CG offset [m] (:func:`sim.flight.asbuilt.as_built_mass`)."""
    design_battery_kg = geometry.design.mass_kg - _component_mass(geometry)
    return as_built_mass(MassProperties.from_geometry(geometry), geometry.battery_b, design_battery_kg, changes)


def _component_mass(geometry: AirframeGeometry) -> float:
    """Everything but the battery: lifting surfaces, fuselage and equipment [kg]."""
    d = geometry.design
    return float(
        d.wing.mass_kg + d.htail.mass_kg + d.vtail.mass_kg + d.fuselage.mass_kg + sum(e.mass_kg for e in d.equipment)
    )


# ------------------------------------------------------------------------------------------- trim
@dataclass(frozen=True)
class Trim:
    """A steady wings-level straight flight point (air-relative): flight-path angle γ [rad] (0 = level),
    angles [rad], deflections [rad], throttle, the thrust and its slope dT/dδ_t [N], and the largest
    residual acceleration [m/s² or rad/s²] of the solution."""

    airspeed_m_s: float
    rho_kg_m3: float
    gamma_rad: float
    alpha_rad: float
    beta_rad: float
    aileron_rad: float
    elevator_rad: float
    rudder_rad: float
    throttle: float
    thrust_n: float
    thrust_per_throttle_n: float
    residual: float

    @property
    def pitch_rad(self) -> float:
        return self.alpha_rad + self.gamma_rad

    def point(self) -> TrimPoint:
        return TrimPoint(
            airspeed_m_s=self.airspeed_m_s,
            alpha_rad=self.alpha_rad,
            beta_rad=self.beta_rad,
            aileron_rad=self.aileron_rad,
            elevator_rad=self.elevator_rad,
            rudder_rad=self.rudder_rad,
            throttle=self.throttle,
            thrust_per_throttle_n=self.thrust_per_throttle_n,
        )


def trim_flight(
    vehicle: Vehicle, aero: StripAero, airspeed_m_s: float, rho_kg_m3: float, *, throttle: float | None = None
) -> Trim:
    """Trim wings-level straight flight with the exact aerodynamics (the deflections are those the flow
    sees: an as-built aircraft's servos sit at :meth:`ControlMap.servo_for` of them).

    ``throttle=None``: level flight, unknowns α, β, δa, δe, δr, δ_t. A given throttle (e.g. 0 for a
    glide): the flight-path angle γ replaces δ_t as unknown. The six equations are the body-axis force
    and moment balances (as accelerations); φ = 0 and θ = α + γ.
    """
    m, g = vehicle.mass.mass_kg, G0_M_S2
    ref = vehicle.reference
    prop = vehicle.propulsion
    disk_m2 = 0.25 * math.pi * prop.propeller.diameter_m**2
    inertia = np.diag(vehicle.mass.inertia_kg_m2)
    qs = 0.5 * rho_kg_m3 * airspeed_m_s**2 * ref.area_m2
    lref = np.array([ref.span_m, ref.chord_m, ref.span_m])
    _, yp, zp = prop.thrust_point_b

    def unpack(z: np.ndarray) -> tuple[float, float, float, float, float, float, float]:
        a, b, da, de, dr, last = (float(v) for v in z)
        return (a, b, da, de, dr, last, 0.0) if throttle is None else (a, b, da, de, dr, throttle, last)

    def forces(z: np.ndarray) -> tuple[np.ndarray, float]:
        a, b, da, de, dr, thr, gamma = unpack(z)
        st = FlightStates.make(airspeed_m_s, alpha_rad=a, beta_rad=b, aileron_rad=da, elevator_rad=de, rudder_rad=dr)
        t, q = prop.thrust_torque(thr, airspeed_m_s * math.cos(a) * math.cos(b), rho_kg_m3)
        if isinstance(aero, AsBuiltStripAero):
            c = aero.coefficients(st, max(t / (disk_m2 * 0.5 * rho_kg_m3 * airspeed_m_s**2), -0.5))[0]
        else:
            c = aero.evaluate(st)[0][0]
        f = qs * c[0:3] + np.array([t, 0.0, 0.0])
        mom = qs * c[3:6] * lref + np.array([-prop.spin * q, zp * t, -yp * t])
        theta = a + gamma
        res = np.concatenate([f / m + g * np.array([-math.sin(theta), 0.0, math.cos(theta)]), mom / inertia])
        return res, t

    z0 = np.array([0.03, 0.0, 0.0, -0.02, 0.0, 0.5 if throttle is None else -0.05])
    lim = math.radians(20.0)
    lo = [-0.2, -0.3, -lim, -lim, -lim, 0.0 if throttle is None else -0.5]
    hi = [0.4, 0.3, lim, lim, lim, 1.0 if throttle is None else 0.5]
    sol = scipy.optimize.least_squares(lambda z: forces(z)[0], z0, bounds=(lo, hi), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    res, thrust = forces(sol.x)
    a, b, da, de, dr, thr, gamma = unpack(sol.x)
    residual = float(np.max(np.abs(res)))
    if residual > 1e-6:
        raise ValueError(f"no trim at {airspeed_m_s} m/s (residual {residual:.2e}): outside the vehicle's envelope")
    dthr = 1e-4
    u_ax = airspeed_m_s * math.cos(a) * math.cos(b)
    slope = (
        prop.thrust_torque(min(thr + dthr, 1.0), u_ax, rho_kg_m3)[0] - prop.thrust_torque(thr, u_ax, rho_kg_m3)[0]
    ) / dthr
    return Trim(
        airspeed_m_s=airspeed_m_s,
        rho_kg_m3=rho_kg_m3,
        gamma_rad=gamma,
        alpha_rad=a,
        beta_rad=b,
        aileron_rad=da,
        elevator_rad=de,
        rudder_rad=dr,
        throttle=thr,
        thrust_n=thrust,
        thrust_per_throttle_n=max(slope, 1e-3),
        residual=residual,
    )


# ------------------------------------------------------------------------------------------ world
class FlightWorld:
    """The 6-DOF flight of a scenario (implements :class:`sim.flight.contract.World`).

    ``vehicle``: a prebuilt :class:`Vehicle` of the scenario's preset (default: built here).
    ``controller``: replaces the autopilot (tests fly open loop or hold a bank), called at the control rate.
    ``trim_throttle``: trim the start state at this throttle (a glide when 0) instead of level flight.
    """

    def __init__(
        self,
        scenario: Scenario,
        vehicle: Vehicle | None = None,
        *,
        controller: Controller | None = None,
        trim_throttle: float | None = None,
    ) -> None:
        self.scenario = sc = scenario
        if vehicle is None:
            vehicle = Vehicle.build(sc.vehicle, sc.as_built_effects if sc.vehicle.as_built is not None else None)
        elif vehicle.preset.name != sc.vehicle.name:
            raise ValueError(f"vehicle {vehicle.preset.name!r} does not match the scenario's {sc.vehicle.name!r}")
        elif vehicle.effects != sc.as_built_effects:
            raise ValueError(
                f"vehicle built with effects {sorted(vehicle.effects)}, the scenario has {sorted(sc.as_built_effects)}"
            )
        self.vehicle = vehicle
        asb = vehicle.as_built
        on = vehicle.effects
        sim = sc.simulation
        self.dt_s = sim.dt_s
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = sc.home_lat_deg, sc.home_lon_deg, sc.home_alt_m
        self.frame = LocalFrame(sc.home_lat_deg, sc.home_lon_deg, sc.home_alt_m)
        self.ports = vehicle.port_layout(
            sc.ports.names, port_points_array(sc.ports), sc.ports.tolerance_m, f"{sc.origin}: sensors.ports"
        )
        # port installation (as-built): each port's offset, bias and tubing lag belong to the airframe
        self.port_errors: PortInstallationErrors | None = None
        if asb is not None and "port_installation" in on:
            self.port_errors = port_installation_errors(self.ports.names, asb.ports)
        self._fly(vehicle)
        self.control_map = ControlMap.build(asb, on)
        self._unsteady: UnsteadyLag | None = None
        self._disk_m2 = 0.25 * math.pi * vehicle.propulsion.propeller.diameter_m**2
        self._release_s = sc.payload_release_s
        if self._release_s is not None:
            self._light = vehicle.without_payload()  # fails at build time, not mid-flight
        self._manoeuvres = list(sc.manoeuvres)
        self._throttle_hold: tuple[float, float] | None = None  # (until [s], throttle)
        self._doublet: tuple[float, float, int, float] | None = None  # (start, period, axis, amplitude [rad])

        # independent, reproducible streams: one generator per stochastic component (spawning more children
        # leaves the first ones as they were, so the kind world's draws do not change)
        seeds = np.random.SeedSequence(sc.seed).spawn(8)
        rngs = [np.random.default_rng(s) for s in seeds]
        # the harsh world (sim.flight.world_effects): the airframe's installation is drawn from the fleet's
        # generator and the airframe's index, so every flight of one airframe has the same build
        fx = sc.world_effects
        self.installation = (
            draw_installation(fx, np.random.default_rng([FLEET_SEED, sc.airframe_index]), part_index=sc.airframe_index)
            if fx
            else None
        )
        inst = self.installation
        imu_grade = IMU_GRADES[inst.imu.part] if inst is not None and inst.imu.part is not None else sc.imu.grade
        imu_inst = inst.imu if inst is not None and fx & IMU_INSTALLATION_EFFECTS else None
        self.turbulence = DrydenTurbulence(sc.turbulence, rngs[0])
        self.imu = Imu(imu_grade, sim.physics_rate_hz, sc.imu.vibration_multiplier, rngs[1], installation=imu_inst)
        self.gnss = Gnss(sc.gnss.grade, self.frame, sc.gnss.outages, sc.gnss.glitches, rngs[2],
                         true_latency_s=inst.gnss_latency_s if inst is not None else None,
                         varying_accuracy="gnss-accuracy" in fx)  # fmt: skip
        self.baro = Barometer(sc.baro, rngs[3], installation=inst.baro if inst is not None else None)
        field_ned = np.asarray(sc.magnetic_field.ned_t)
        if "mag-site-field" in fx:  # the site's true field: the scenario's (WMM) value is the model's
            field_ned = field_ned + site_field_anomaly_ned_t(rngs[7])
        self.mag = Magnetometer(sc.mag.grade, field_ned, np.asarray(sc.mag.hard_iron_b_t), rngs[4],
                                installation=inst.mag if inst is not None else None)  # fmt: skip
        self.pitot = (
            PitotAirspeed(sc.airspeed, rngs[5], installation=inst.pitot if inst is not None else None)
            if sc.airspeed is not None
            else None
        )
        # the Earth (earth-gravity, earth-rotation): normal gravity at home and its height gradient, Earth rate
        self._gravity = "earth-gravity" in fx
        self._rotation = "earth-rotation" in fx
        self._omega_ie_ned = earth_rate_ned(sc.home_lat_deg)
        self._earth = (0.0, 0.0, 0.0)
        lag = sc.ports.lag_s if self.port_errors is None else self.port_errors.lag_s
        self.port_sensors = PressurePorts(sc.ports.grade, self.ports.names, sc.ports.rate_hz, lag, rngs[6])
        self.servos = ServoOutputs(sim.control_rate_hz)

        self._div_aero = sim.steps_per(sim.aero_rate_hz)
        self._div_ctrl = sim.steps_per(sim.control_rate_hz)
        self._div_gnss = sim.steps_per(sc.gnss.grade.rate_hz)
        self._div_baro = sim.steps_per(sc.baro.rate_hz)
        self._div_mag = sim.steps_per(sc.mag.grade.rate_hz)
        self._div_pitot = sim.steps_per(sc.airspeed.rate_hz) if sc.airspeed is not None else 0
        self._div_ports = sim.steps_per(sc.ports.rate_hz)

        # --- initial state: trimmed straight flight at the start
        st = sc.start
        alt0 = sc.home_alt_m + st.height_m
        rho0 = sc.atmosphere.at(alt0)[2]
        self.trim = trim_flight(vehicle, self.strip_aero, st.airspeed_m_s, rho0, throttle=trim_throttle)
        tr = self.trim
        q = quat_from_euler(0.0, tr.pitch_rad, math.radians(st.heading_deg))
        v_air_b = (
            st.airspeed_m_s * math.cos(tr.alpha_rad) * math.cos(tr.beta_rad),
            st.airspeed_m_s * math.sin(tr.beta_rad),
            st.airspeed_m_s * math.sin(tr.alpha_rad) * math.cos(tr.beta_rad),
        )
        v_air_ned = dcm_from_quat(q) @ np.asarray(v_air_b)
        self._wind_steady = sc.wind.ned_m_s
        if sc.wind_profile is not None:
            self._wind_steady = sc.wind_profile.wind_ned(sc.wind, st.height_m)
        self._turb_heading = sc.wind.to_heading_rad
        gust = self.turbulence.step(0.0, st.airspeed_m_s, st.height_m)
        wind0 = self._wind_steady + self._gust_ned(gust)
        v_ned = v_air_ned + wind0
        self._y: tuple[float, ...] = (
            st.north_m,
            st.east_m,
            -st.height_m,
            *(float(v) for v in v_ned),
            *q,
            0.0,
            0.0,
            0.0,
        )
        # the servos sit where the flow sees the trim deflections (as-built: effectiveness and offsets)
        sa, se, sr = self.control_map.servo_for(tr.aileron_rad, tr.elevator_rad, tr.rudder_rad)
        self.actuators = Actuators(sc.vehicle.actuators, (sa, se, tr.throttle, sr))
        if controller is None:
            point = replace(tr.point(), aileron_rad=sa, elevator_rad=se, rudder_rad=sr)
            ap = Autopilot(sc.route, sc.vehicle.gains, point, vehicle.mass.mass_kg, 1.0 / sim.control_rate_hz)
            ap.start_leg_from(st.north_m, st.east_m)
            self.autopilot: Autopilot | None = ap
            self._controller: Controller = lambda _t, s: ap.update(s)
        else:
            self.autopilot = None
            self._controller = controller
        self._alpha_dot = 0.0
        self._rho = rho0
        self._temp_c = sc.atmosphere.at(alt0)[1] - 273.15
        self._p_static = sc.atmosphere.at(alt0)[0]
        self._wind = (float(wind0[0]), float(wind0[1]), float(wind0[2]))
        if asb is not None and "unsteady" in on:
            self._unsteady = UnsteadyLag(asb.unsteady, tr.alpha_rad)
        self._alpha_lag = 0.0
        self._sep_deficit = 0.0
        self._u = self._inputs()
        self.aero.update(self._air_state(self._y))
        self._k1, self._aux = self.dynamics.derivative(self._y, self._u)
        self._alpha_prev = self._aux.alpha
        self._n = 0
        self.t_s = 0.0
        self._pwm_cmd = self.actuators.pwm_of(self.actuators.command)

    def _fly(self, vehicle: Vehicle) -> None:
        """The aerodynamics and equations of motion of ``vehicle``'s mass, CG and propulsion (at the start,
        and again when a payload leaves: the aerodynamic moments are taken about the CG)."""
        asb, on = vehicle.as_built, vehicle.effects
        self.strip_aero: StripAero
        if asb is not None and on:
            self.strip_aero = AsBuiltStripAero(
                vehicle.model,
                self.ports,
                asb,
                on,
                r_cg_b=vehicle.r_cg_b,
                propulsion=vehicle.propulsion,
                port_offsets_m=None if self.port_errors is None else self.port_errors.offset_m,
            )
        else:
            self.strip_aero = StripAero(vehicle.model, self.ports)
        self.aero = LinearizedAero(self.strip_aero)
        self.dynamics = AircraftDynamics(vehicle.mass, vehicle.reference, vehicle.propulsion, self.aero)
        self._imu_arm_b = -np.asarray(vehicle.r_cg_b)  # the IMU sits at the design CG
        self._has_arm = bool(np.any(self._imu_arm_b != 0.0))

    def _release_payload(self) -> None:
        """The payload leaves at once (a drop): from this step on the aircraft flies without its mass. The
        autopilot is not told; its integrators retrim, as a real one's do."""
        self._release_s = None
        self.vehicle = self._light
        self._fly(self._light)

    # ----------------------------------------------------------------------------------- helpers
    @property
    def duration_s(self) -> float:
        return self.scenario.duration_s

    @property
    def n_steps(self) -> int:
        """World steps in the scenario's duration (stepping further is allowed: the route repeats)."""
        return self.scenario.n_steps

    @property
    def state(self) -> tuple[float, ...]:
        """The rigid-body state (13,): NED position, NED velocity, quaternion, body rates."""
        return self._y

    @property
    def aux(self) -> Aux:
        """Specific force, airspeed, α, β and thrust at the current state."""
        return self._aux

    def _gust_ned(self, gust: tuple[float, float, float]) -> np.ndarray:
        ug, vg, wg = gust
        c, s = math.cos(self._turb_heading), math.sin(self._turb_heading)
        return np.array([c * ug - s * vg, s * ug + c * vg, wg])

    def _inputs(self) -> StepInputs:
        a, e, t, r = self.actuators.position
        a, e, r = self.control_map.apply(a, e, r)
        return StepInputs(*self._wind, a, e, t, r, self._alpha_dot, self._rho, self._alpha_lag, self._sep_deficit,
                          *self._earth)  # fmt: skip

    def _earth_accel(self, y: tuple[float, ...]) -> tuple[float, float, float]:
        """Gravity's difference from g0 and −(2ω_ie + ω_en) × v, NED [m/s²] (Groves 2013, eq. 5.54)."""
        vn, ve, vd = y[3], y[4], y[5]
        en = ee = ed = 0.0
        if self._gravity:
            lat, _, h = self.frame.to_geodetic(y[0], y[1], y[2])
            ed = normal_gravity_m_s2(lat, h) - G0_M_S2
        if self._rotation:
            wx, wy, wz = self._transport_plus_earth(y, 2.0)
            en -= wy * vd - wz * ve
            ee -= wz * vn - wx * vd
            ed -= wx * ve - wy * vn
        return en, ee, ed

    def _transport_plus_earth(self, y: tuple[float, ...], k_earth: float) -> tuple[float, float, float]:
        """k·ω_ie + ω_en in NED [rad/s] (ω_en: the transport rate over the curved Earth, Groves eq. 5.44)."""
        r = WGS84_A_M - y[2]
        lat = math.radians(self.home_lat_deg)
        vn, ve = y[3], y[4]
        wie = self._omega_ie_ned
        return (
            k_earth * float(wie[0]) + ve / r,
            -vn / r,
            k_earth * float(wie[2]) - ve * math.tan(lat) / r,
        )

    def thrust_coeff(self) -> float:
        """T_c = T/(q̄·A_disk) at the current state (the slipstream's strength)."""
        a = self._aux
        return max(a.thrust / (self._disk_m2 * 0.5 * self._rho * a.airspeed * a.airspeed), -0.5)

    def aero_coeffs(self) -> F64Array:
        """The truth's aerodynamic coefficients (6,) at the current state: body axes about the true CG, on
        the freestream dynamic pressure and the reference geometry (what the IMU and gyros feel)."""
        return self.aero.coeffs(self._air_state(self._y), self.thrust_coeff(), self._sep_deficit)

    def _apply_manoeuvres(self, t: float, cmd: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        """Start the scripted manoeuvres due at ``t`` and add the active ones to the commands."""
        ap = self.autopilot
        while self._manoeuvres and self._manoeuvres[0].start_s <= t:
            m: Manoeuvre = self._manoeuvres.pop(0)
            if m.type == "airspeed" and ap is not None:
                ap.airspeed_demand_m_s = m.value
            elif m.type == "height" and ap is not None:
                ap.height_offset_m += m.value
            elif m.type == "throttle":
                self._throttle_hold = (m.start_s + m.duration_s, m.value)
            elif m.type == "doublet":
                axis = {"roll": 0, "pitch": 1, "yaw": 3}[m.axis]
                self._doublet = (m.start_s, m.duration_s, axis, math.radians(m.value))
        out = list(cmd)
        if self._throttle_hold is not None:
            if t < self._throttle_hold[0]:
                out[2] = self._throttle_hold[1]
            else:
                self._throttle_hold = None
        if self._doublet is not None:
            t0, period, axis, amp = self._doublet
            if t < t0 + period:
                out[axis] += amp if t < t0 + 0.5 * period else -amp
            else:
                self._doublet = None
        return out[0], out[1], out[2], out[3]

    def _air_state(self, y: tuple[float, ...]) -> tuple[float, ...]:
        """The aerodynamic state (V, α, β, p, q, r, α̇, δa, δe, δr) at ``y`` under the current inputs (α as the
        flow sees it: less the circulation lag of an as-built aircraft; deflections as the flow sees them)."""
        _, _, _, vn, ve, vd, q0, q1, q2, q3, p, q, r = y
        u = self._u
        an, ae, ad = vn - u.wind_n, ve - u.wind_e, vd - u.wind_d
        ub = (q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) * an + 2 * (q1 * q2 + q0 * q3) * ae + 2 * (q1 * q3 - q0 * q2) * ad
        vb = 2 * (q1 * q2 - q0 * q3) * an + (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) * ae + 2 * (q2 * q3 + q0 * q1) * ad
        wb = 2 * (q1 * q3 + q0 * q2) * an + 2 * (q2 * q3 - q0 * q1) * ae + (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) * ad
        v = math.sqrt(ub * ub + vb * vb + wb * wb)
        alpha = math.atan2(wb, ub) - u.alpha_lag
        return (v, alpha, math.asin(vb / v), p, q, r, u.alpha_dot, u.aileron, u.elevator, u.rudder)

    def nav_state(self) -> NavState:
        """The truth as the autopilot reads it."""
        n, e, d, vn, ve, vd, q0, q1, q2, q3, p, q, r = self._y
        roll, pitch, yaw = euler_from_quat((q0, q1, q2, q3))
        k1 = self._k1
        return NavState(
            north_m=n,
            east_m=e,
            down_m=d,
            v_n=vn,
            v_e=ve,
            v_d=vd,
            a_n=k1[3],
            a_e=k1[4],
            a_d=k1[5],
            roll=roll,
            pitch=pitch,
            yaw=yaw,
            p=p,
            q=q,
            r=r,
            airspeed_m_s=self._aux.airspeed,
            beta_rad=self._aux.beta,
        )

    def _check_envelope(self) -> None:
        a = self._aux
        height = -self._y[2]
        msg = None
        if height < 0.0:
            msg = "hit the ground"
        elif a.airspeed < _MIN_AIRSPEED_M_S:
            msg = f"airspeed {a.airspeed:.1f} m/s below {_MIN_AIRSPEED_M_S} m/s"
        elif abs(a.alpha) > _MAX_ALPHA_RAD:
            msg = f"alpha {math.degrees(a.alpha):.1f} deg outside ±{math.degrees(_MAX_ALPHA_RAD):.0f} deg"
        elif abs(a.beta) > _MAX_BETA_RAD:
            msg = f"beta {math.degrees(a.beta):.1f} deg outside ±{math.degrees(_MAX_BETA_RAD):.0f} deg"
        if msg is not None:
            raise FlightEnvelopeError(
                f"{self.scenario.name}: t = {self.t_s:.3f} s: the aircraft {msg} (height {height:.1f} m)"
            )

    # ------------------------------------------------------------------------------------- step
    def step(self) -> WorldTick:
        """Advance one physics step (see the module docstring) and return what happened."""
        dt = self.dt_s
        self._y = self.dynamics.rk4(self._y, self._u, dt, self._k1)
        self._n += 1
        n = self._n
        self.t_s = t = n * dt
        y = self._y
        height = -y[2]

        # inputs of the next step
        self.actuators.step(dt)
        gust = self.turbulence.step(dt, self._aux.airspeed, max(height, 0.0))
        ug, vg, wg = gust
        c, s = math.cos(self._turb_heading), math.sin(self._turb_heading)
        if (shear := self.scenario.wind_shear) is not None:
            self._wind_steady = shear.wind_ned(self.scenario.wind, t)
        if (profile := self.scenario.wind_profile) is not None:
            self._wind_steady = profile.wind_ned(self.scenario.wind, height)
        ws = self._wind_steady
        self._wind = (float(ws[0]) + c * ug - s * vg, float(ws[1]) + s * ug + c * vg, float(ws[2]) + wg)
        alt = self.home_alt_m + height
        self._p_static, temp_k, self._rho = self.scenario.atmosphere.at(min(max(alt, -500.0), 11000.0))
        self._temp_c = temp_k - 273.15
        if self._unsteady is not None:
            self._alpha_lag, self._sep_deficit = self._unsteady.step(self._aux.alpha, self._aux.airspeed, dt)
        if self._gravity or self._rotation:
            self._earth = self._earth_accel(y)
        self._u = self._inputs()
        x_air = self._air_state(y)
        release = self._release_s is not None and t >= self._release_s
        if release:
            self._release_payload()
        if release or n % self._div_aero == 0 or self.aero.out_of_bounds(x_air):
            self.aero.update(x_air)
        self._k1, aux = self.dynamics.derivative(y, self._u)
        self._aux = aux
        # α̇: finite difference of α, low-passed (see the module docstring)
        raw = (aux.alpha - self._alpha_prev) / dt
        self._alpha_prev = aux.alpha
        self._alpha_dot += (raw - self._alpha_dot) * (dt / (ALPHA_DOT_TAU_S + dt))
        self._check_envelope()

        servos = None
        if n % self._div_ctrl == 0:
            cmd = self._controller(t, self.nav_state())
            if self._manoeuvres or self._throttle_hold is not None or self._doublet is not None:
                cmd = self._apply_manoeuvres(t, cmd)
            self.actuators.set_command(*cmd)
            self._pwm_cmd = self.actuators.pwm_of(self.actuators.command)
            servos = self.servos.sample(t, self._pwm_cmd)

        # --- sensors
        _, _, _, vn, ve, vd, q0, q1, q2, q3, p, q, r = y
        f_imu = (aux.f_x, aux.f_y, aux.f_z)
        if self._has_arm:  # the IMU off the true CG feels ω̇ × r + ω × (ω × r)
            rx, ry, rz = self._imu_arm_b
            k1 = self._k1
            pd, qd, rd = k1[10], k1[11], k1[12]
            wx, wy, wz = q * rz - r * ry, r * rx - p * rz, p * ry - q * rx  # ω × r
            f_imu = (
                f_imu[0] + qd * rz - rd * ry + q * wz - r * wy,
                f_imu[1] + rd * rx - pd * rz + r * wx - p * wz,
                f_imu[2] + pd * ry - qd * rx + p * wy - q * wx,
            )
        omega_imu = (p, q, r)
        if self._rotation:  # the gyros sense the rotation of the navigation frame too: ω_ib = ω_nb + C_bn·ω_in
            w_in = self._transport_plus_earth(y, 1.0)
            c_nb = dcm_from_quat((q0, q1, q2, q3))
            wb = c_nb.T @ np.asarray(w_in)
            omega_imu = (p + float(wb[0]), q + float(wb[1]), r + float(wb[2]))
        imu = self.imu.sample(t, f_imu, omega_imu, self._u.throttle, self._temp_c)
        if n % self._div_gnss == 0:
            self.gnss.measure(t, y[0:3], y[3:6])
        gnss = self.gnss.deliver(t)
        qbar = 0.5 * self._rho * aux.airspeed * aux.airspeed
        baro = None
        if n % self._div_baro == 0:
            baro = self.baro.sample(t, self._p_static, self._temp_c, qbar, aux.alpha)
        mag = None
        if n % self._div_mag == 0:
            mag = self.mag.sample(t, dcm_from_quat((q0, q1, q2, q3)), self._u.throttle)
        airspeed = None
        if self.pitot is not None and n % self._div_pitot == 0:
            airspeed = self.pitot.sample(t, qbar, self._temp_c, aux.alpha, aux.beta)
        ports = None
        if n % self._div_ports == 0:
            cp = self.aero.ports_cp(x_air, self.thrust_coeff(), self._sep_deficit)
            if self.port_errors is not None:
                cp = cp + self.port_errors.bias_cp
            ports = self.port_sensors.sample(t, cp * qbar)

        lat, lon, alt_m = self.frame.to_geodetic(y[0], y[1], y[2])
        truth = VehicleTruth(
            t_s=t,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt_m,
            pos_ned_m=np.array(y[0:3]),
            v_ned_m_s=np.array((vn, ve, vd)),
            q_nb=np.array((q0, q1, q2, q3)),
            omega_b_rad_s=np.array((p, q, r)),
            specific_force_b_m_s2=np.array((aux.f_x, aux.f_y, aux.f_z)),
            airspeed_m_s=aux.airspeed,
            alpha_rad=aux.alpha,
            beta_rad=aux.beta,
            wind_ned_m_s=np.array(self._wind),
            throttle=self._u.throttle,
        )
        return WorldTick(
            truth=truth,
            imu=imu,
            gnss=gnss,
            baro=baro,
            mag=mag,
            airspeed=airspeed,
            ports=ports,
            servos=servos,
            gnss_outage=self.gnss.in_outage(t),
        )

    def run(self, n_steps: int | None = None) -> list[WorldTick]:
        """Step ``n_steps`` times (default: the scenario's duration) and return the ticks."""
        return [self.step() for _ in range(self.n_steps if n_steps is None else n_steps)]
