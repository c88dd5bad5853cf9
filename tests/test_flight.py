"""The 6-DOF flight simulator: aerodynamic adapter, trim, dynamics, environment, scenarios and the World.

One vehicle (the uav-2m preset: uav-envelope airframe, 5000 surface points) is built per module. Every
run is seeded; tolerances are stated in physical units next to each check.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.signal
import yaml

from sim.airframe.vlm import FlightStates
from sim.flight.actuators import ACTUATORS, Actuators
from sim.flight.aero import LinearizedAero, ReexpansionBounds, StripAero
from sim.flight.contract import World, WorldTick
from sim.flight.environment import (
    TURBULENCE_LEVELS,
    Atmosphere,
    DrydenTurbulence,
    dryden_length_scales_m,
    dryden_sigmas_m_s,
)
from sim.flight.guidance import l1_lateral_accel_circle, l1_lateral_accel_segment
from sim.flight.propulsion import PROPELLERS, PropulsionSpec
from sim.flight.scenario import Scenario, load_scenario, parse_scenario, scenario_names
from sim.flight.world import FlightEnvelopeError, FlightWorld, Vehicle
from vdm_aero.errors import SpecError
from vdm_aero.model import MODEL_FORMAT
from vdm_aero.rotation import dcm_from_quat, euler_from_quat

G = 9.80665


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return Vehicle.build("uav-2m")


def _raw(name: str = "survey-wind8") -> dict[str, Any]:
    text = resources.files("sim").joinpath("presets", "scenarios", f"{name}.yaml").read_text()
    return dict(yaml.safe_load(text))


def _calm(raw: dict[str, Any], **changes: Any) -> Scenario:
    """The scenario without wind and turbulence (plus top-level changes)."""
    d = copy.deepcopy(raw)
    d["wind"] = {"speed_m_s": 0.0, "from_deg": 0.0}
    d["turbulence"] = {"level": "none"}
    d.update(changes)
    return parse_scenario(d, origin="test")


def _euler(ticks: list[WorldTick]) -> np.ndarray:
    return np.array([euler_from_quat(t.truth.q_nb) for t in ticks])


# ------------------------------------------------------------------------------------ the adapter
def _random_states(rng: np.random.Generator, n: int) -> FlightStates:
    def u(lo: float, hi: float) -> np.ndarray:
        return rng.uniform(lo, hi, n)

    return FlightStates(
        airspeed_m_s=u(12.0, 30.0),
        alpha_rad=np.radians(u(-6.0, 16.0)),
        beta_rad=np.radians(u(-10.0, 10.0)),
        p_rad_s=u(-1.5, 1.5),
        q_rad_s=u(-1.0, 1.0),
        r_rad_s=u(-0.8, 0.8),
        alpha_dot_rad_s=u(-1.0, 1.0),
        aileron_rad=np.radians(u(-20.0, 20.0)),
        elevator_rad=np.radians(u(-20.0, 20.0)),
        rudder_rad=np.radians(u(-20.0, 20.0)),
    )


def test_adapter_equals_the_full_field_integral_and_the_field_at_the_ports(vehicle: Vehicle) -> None:
    rng = np.random.default_rng(11)
    geo = vehicle.geometry
    idx = np.sort(rng.choice(geo.n_points, 60, replace=False))  # ports on every component
    ports = vehicle.port_layout(tuple(f"P{i:02d}" for i in range(60)), geo.points_b[idx], 1e-6, "test")
    aero = StripAero(vehicle.model, ports)
    states = _random_states(rng, 48)
    coeffs, cp_ports = aero.evaluate(states)
    cp_full, _ = vehicle.model.evaluate_states(states)
    # the full-field pressure integral (S @ cp over all N points) plus skin friction
    integral = vehicle.model.coeffs(states, cp_full)
    np.testing.assert_allclose(coeffs, integral, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(cp_ports, cp_full[:, idx], rtol=0.0, atol=1e-12)
    # rows that differ only in control deflections may share the first row's fuselage field
    same = FlightStates.from_array(np.vstack([states.to_array()[:1]] * 4))
    arr = same.to_array()
    arr[1:, 7:] = np.radians(rng.uniform(-15.0, 15.0, (3, 3)))
    shared = FlightStates.from_array(arr)
    own = aero.evaluate(shared)
    reused = aero.evaluate(shared, fuselage_index=np.zeros(4, dtype=np.int64))
    np.testing.assert_allclose(reused[0], own[0], atol=1e-14)
    np.testing.assert_allclose(reused[1], own[1], atol=1e-14)


def test_taylor_model_is_exact_at_the_expansion_point_and_close_nearby(vehicle: Vehicle) -> None:
    geo = vehicle.geometry
    ports = vehicle.port_layout(("A", "B"), geo.points_b[[10, 4000]], 1e-6, "test")
    exact = StripAero(vehicle.model, ports)
    lin = LinearizedAero(exact)
    x0 = np.array([18.0, math.radians(2.0), math.radians(1.0), 0.2, 0.1, 0.05, 0.1, 0.01, 0.03, -0.01])
    lin.update(x0)  # a flight state: 10 values in STATE_COLUMNS order
    c0, p0 = exact.evaluate(FlightStates.from_array(x0[None]))
    np.testing.assert_allclose(lin.coeffs(x0), c0[0], atol=1e-14)
    np.testing.assert_allclose(lin.ports_cp(x0), p0[0], atol=1e-14)
    # the worst the model sees: every variable at once at a corner of the re-expansion bounds
    signs = np.random.default_rng(0).choice([-1.0, 1.0], (64, 10))
    xs = x0 + signs * ReexpansionBounds().vector()
    c_exact, cp_exact = exact.evaluate(FlightStates.from_array(xs))
    approx = np.array([lin.coeffs(x) for x in xs])
    cp_approx = np.array([lin.ports_cp(x) for x in xs])
    change = np.max(np.abs(c_exact - c0[0]), axis=0)
    err = np.max(np.abs(approx - c_exact), axis=0)
    # the remainder stays below 10 % of each coefficient's (and port Cp's) change over the bounds
    assert np.all(err <= 0.1 * change), f"Taylor error {err} for changes {change}"
    cp_change = np.max(np.abs(cp_exact - p0[0]), axis=0)
    assert np.all(np.max(np.abs(cp_approx - cp_exact), axis=0) <= 0.1 * cp_change)


def test_aero_expansion_rate_tracks_the_every_step_expansion(vehicle: Vehicle) -> None:
    """10 s of climbing turn in light turbulence: the Taylor model re-expanded at the scenario's rate (and
    early when out of bounds) vs re-expanded every 2.5 ms step, which is the pressure model itself to
    second order in 2.5 ms of motion."""
    sc = load_scenario("survey-wind8")
    runs = {}
    for rate in (sc.simulation.aero_rate_hz, sc.simulation.physics_rate_hz):
        s = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, aero_rate_hz=rate))
        ticks = FlightWorld(s, vehicle).run(4000)
        runs[rate] = (
            np.array([t.truth.pos_ned_m for t in ticks]),
            _euler(ticks),
            np.array([t.truth.specific_force_b_m_s2 for t in ticks]),
        )
    (p_s, e_s, f_s), (p_ref, e_ref, f_ref) = runs[sc.simulation.aero_rate_hz], runs[sc.simulation.physics_rate_hz]
    assert np.max(np.abs(p_s - p_ref)) < 0.05  # m
    assert np.degrees(np.max(np.abs(e_s - e_ref))) < 0.1  # deg
    # specific-force error RMS below 2 mm/s² (the ICM-42688-P's white noise is 14 mm/s² per sample)
    assert np.sqrt(np.mean((f_s - f_ref) ** 2)) < 2e-3


# ------------------------------------------------------------------------------ trim and dynamics
@pytest.mark.parametrize("airspeed", [14.0, 18.0, 24.0])
def test_trimmed_level_flight_stays_trimmed(vehicle: Vehicle, airspeed: float) -> None:
    raw = _raw()
    raw["start"] = {**raw["start"], "airspeed_m_s": airspeed}
    sc = _calm(raw)
    probe = FlightWorld(sc, vehicle, controller=lambda t, s: (0.0, 0.0, 0.0, 0.0))
    tr = probe.trim
    assert tr.residual < 1e-9
    assert -2.0 < math.degrees(tr.alpha_rad) < 8.0 and 0.0 < tr.throttle < 1.0
    assert abs(tr.elevator_rad) < math.radians(10.0) and abs(tr.beta_rad) < math.radians(0.5)
    hold = (tr.aileron_rad, tr.elevator_rad, tr.throttle, tr.rudder_rad)
    w = FlightWorld(sc, vehicle, controller=lambda t, s: hold)
    ticks = w.run(20 * 400)  # 20 s open loop
    h = np.array([-t.truth.pos_ned_m[2] for t in ticks])
    v = np.array([t.truth.airspeed_m_s for t in ticks])
    e = _euler(ticks)
    where = f"@ {airspeed} m/s"
    assert np.max(np.abs(h - sc.start.height_m)) < 0.05, f"altitude drift {where}"  # 5 cm in 20 s
    assert np.max(np.abs(v - airspeed)) < 0.01, f"airspeed drift {where}"  # 1 cm/s
    assert np.degrees(np.max(np.abs(e[:, 0]))) < 0.01, f"roll drift {where}"
    assert np.degrees(np.max(np.abs(e[:, 1] - tr.pitch_rad))) < 0.01, f"pitch drift {where}"
    assert np.degrees(np.max(np.abs(e[:, 2] - math.radians(sc.start.heading_deg)))) < 0.01, f"heading drift {where}"


def test_coordinated_turn_rate_matches_bank_and_speed(vehicle: Vehicle) -> None:
    """Loiter at the radius of a 30° bank in calm air, settled: ψ̇ = g·tanφ/V within 1 % with β ≈ 0.

    The textbook relation assumes no lateral specific force; the fin's side force in the turn leaves a
    few cm/s² (0.5 % of ψ̇). The exact kinematics of a level turn, ψ̇ = (g·cosθ·sinφ + f_y)/(V_h·cosφ),
    must hold to 0.05 % (that checks the rigid body, not the autopilot)."""
    v, bank = 18.0, math.radians(30.0)
    radius = v * v / (G * math.tan(bank))
    raw = _raw()
    raw["route"] = {
        "type": "loiter",
        "centre_ne_m": [0.0, radius],
        "radius_m": radius,
        "height_m": 60.0,
        "clockwise": True,
        "airspeed_m_s": v,
    }
    raw["start"] = {**raw["start"], "heading_deg": 0.0}
    ticks = FlightWorld(_calm(raw), vehicle).run(40 * 400)[20 * 400 :]  # the second 20 s: settled
    e = _euler(ticks)
    t = np.array([tk.truth.t_s for tk in ticks])
    yaw_rate = float(np.mean(np.gradient(np.unwrap(e[:, 2]), t)))
    va = np.array([tk.truth.airspeed_m_s for tk in ticks])
    v_ned = np.array([tk.truth.v_ned_m_s for tk in ticks])
    f_y = np.array([tk.truth.specific_force_b_m_s2[1] for tk in ticks])
    assert np.degrees(np.mean(e[:, 0])) == pytest.approx(30.0, abs=1.0)  # L1 on the circle: the circle's bank
    assert np.degrees(np.max(np.abs([tk.truth.beta_rad for tk in ticks]))) < 0.1  # coordinated
    assert yaw_rate == pytest.approx(float(np.mean(G * np.tan(e[:, 0]) / va)), rel=0.01)
    exact = (G * np.cos(e[:, 1]) * np.sin(e[:, 0]) + f_y) / (np.hypot(v_ned[:, 0], v_ned[:, 1]) * np.cos(e[:, 0]))
    assert yaw_rate == pytest.approx(float(np.mean(exact)), rel=5e-4)


def test_glide_energy_rate_equals_drag_power(vehicle: Vehicle) -> None:
    """Engine off (stopped propeller), an elevator doublet excites the motion: dE/dt = −D·V throughout.

    Pointwise (central differences at 400 Hz) within 1 % of the drag power: the aerodynamic force steps by
    the Taylor remainder (≤ 0.4 % here) where the model is re-expanded. Integrated over 0.5 s windows, the
    energy lost equals ∫D·V dt within 1e-4."""
    sc = _calm(_raw())
    tg = FlightWorld(sc, vehicle, controller=lambda t, s: (0.0, 0.0, 0.0, 0.0), trim_throttle=0.0).trim
    assert tg.gamma_rad < 0.0 and tg.thrust_n == 0.0

    def doublet(t: float, _s: object) -> tuple[float, float, float, float]:
        de = math.radians(3.0) * (1.0 if 1.0 <= t < 1.5 else -1.0 if 1.5 <= t < 2.0 else 0.0)
        return tg.aileron_rad, tg.elevator_rad + de, 0.0, tg.rudder_rad

    ticks = FlightWorld(sc, vehicle, controller=doublet, trim_throttle=0.0).run(8 * 400)
    m = vehicle.mass.mass_kg
    t = np.array([tk.truth.t_s for tk in ticks])
    h = np.array([-tk.truth.pos_ned_m[2] for tk in ticks])
    v_ned = np.array([tk.truth.v_ned_m_s for tk in ticks])
    energy = m * G * h + 0.5 * m * np.sum(v_ned**2, axis=1)
    # −D·V = F_aero·v (no thrust, calm air): the aerodynamic force is m·(specific force)
    v_b = np.array([dcm_from_quat(tk.truth.q_nb).T @ tk.truth.v_ned_m_s for tk in ticks])
    f_b = np.array([tk.truth.specific_force_b_m_s2 for tk in ticks])
    power = m * np.sum(f_b * v_b, axis=1)
    assert np.ptp(h) > 5.0 and np.ptp([tk.truth.alpha_rad for tk in ticks]) > math.radians(1.0)  # it did move
    inner = slice(2, -2)
    de_dt = np.gradient(energy, t)
    assert np.max(np.abs(de_dt[inner] - power[inner])) < 0.01 * np.mean(np.abs(power))
    for a in range(0, len(t) - 200, 200):
        lost = energy[a + 200] - energy[a]
        work = float(np.trapezoid(power[a : a + 201], t[a : a + 201]))
        assert lost == pytest.approx(work, rel=1e-4), f"window at {t[a]:.1f} s"


def test_leaving_the_envelope_is_an_error(vehicle: Vehicle) -> None:
    sc = _calm(_raw())
    w = FlightWorld(sc, vehicle, controller=lambda t, s: (0.0, math.radians(20.0), 0.0, 0.0))  # full nose-down
    with pytest.raises(FlightEnvelopeError, match="t = "):
        w.run(60 * 400)


def test_actuators_follow_lag_rate_limit_and_limits() -> None:
    spec = ACTUATORS["uav-2m-servos"]
    act = Actuators(spec, (0.0, 0.0, 0.0, 0.0))
    act.set_command(1.0, -0.05, 2.0, 0.0)  # beyond the throw and the throttle range
    dt = 1.0 / 400.0
    trace = []
    for _ in range(400):
        act.step(dt)
        trace.append(list(act.position))
    tr = np.array(trace)
    assert np.max(np.diff(tr[:, 0])) <= spec.aileron.rate_limit_per_s * dt + 1e-15  # rate limited
    assert tr[-1, 0] == pytest.approx(spec.aileron.max_value) and tr[-1, 2] == pytest.approx(1.0, abs=1e-4)
    # small step: unaffected by the rate limit, the first-order lag reaches 63 % after τ
    k = round(spec.elevator.tau_s / dt)
    assert tr[k - 1, 1] == pytest.approx(-0.05 * (1.0 - math.exp(-1.0)), rel=1e-9)
    pwm = act.pwm_us()
    assert pwm[0] == pytest.approx(2000.0) and pwm[2] == pytest.approx(2000.0, abs=0.1)


def test_propeller_thrust_and_torque() -> None:
    prop = PropulsionSpec(PROPELLERS["apc-11x7e"], max_rev_s=150.0, thrust_point_b=(0.45, 0.0, 0.0), spin=1)
    p = prop.propeller
    assert prop.thrust_torque(0.0, 18.0, 1.225) == (0.0, 0.0)  # a stopped propeller does nothing
    t_static, _ = prop.thrust_torque(1.0, 0.0, 1.225)
    assert t_static == pytest.approx(1.225 * 150.0**2 * p.diameter_m**4 * p.ct0)
    t_zero, _ = prop.thrust_torque(1.0, p.j_zero_thrust * 150.0 * p.diameter_m, 1.225)
    assert t_zero == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------------- environment
def test_isa_reference_values() -> None:
    p, t, rho = Atmosphere(0.0).at(0.0)
    assert (p, t, rho) == pytest.approx((101325.0, 288.15, 1.225), rel=1e-4)
    p11, t11, _ = Atmosphere(0.0).at(11000.0)
    assert p11 == pytest.approx(22632.0, rel=1e-4) and t11 == pytest.approx(216.65)  # ISO 2533 tropopause
    assert Atmosphere(10.0).at(0.0)[2] == pytest.approx(1.225 * 288.15 / 298.15, rel=1e-4)


@pytest.mark.parametrize("level", ["light", "moderate"])
def test_dryden_intensity_and_spectrum_match_mil_f_8785c(level: str) -> None:
    height, v, dt = 30.0, 25.0, 0.05
    sig = dryden_sigmas_m_s(level, height)
    scales = dryden_length_scales_m(height)
    assert sig[2] == pytest.approx(0.1 * TURBULENCE_LEVELS[level])  # σ_w = 0.1·W20
    turb = DrydenTurbulence(level, np.random.default_rng(8785))
    n = 200_000  # 10,000 s: ~800 correlation lengths of u, 4,000 of w
    rec = np.array([turb.step(dt, v, height) for _ in range(n)])
    fs = 1.0 / dt
    for k, name in enumerate("uvw"):
        x = rec[:, k]
        # intensity: σ within 7 % for u (fewest independent samples), 4 % for v and w
        assert np.std(x) == pytest.approx(sig[k], rel=0.07 if k == 0 else 0.04), f"σ_{name} {level}"
        # spectrum: Welch PSD / Dryden PSD, averaged per octave over 1/(2πT) … fs/8, within ±15 %
        f, psd = scipy.signal.welch(x, fs=fs, nperseg=8192)
        big_l = scales[k]
        om = 2.0 * math.pi * f / v  # spatial frequency [rad/m]
        if k == 0:
            phi = sig[k] ** 2 * (2.0 * big_l / math.pi) / (1.0 + (big_l * om) ** 2)
        else:
            phi = sig[k] ** 2 * (big_l / math.pi) * (1.0 + 3.0 * (big_l * om) ** 2) / (1.0 + (big_l * om) ** 2) ** 2
        model = phi * 2.0 * math.pi / v  # one-sided PSD per Hz
        lo = v / (2.0 * math.pi * big_l)
        edges = lo * 2.0 ** np.arange(0, int(math.log2(fs / 8.0 / lo)) + 1)
        for a, b in itertools.pairwise(edges):
            band = (f >= a) & (f < b)
            ratio = np.mean(psd[band]) / np.mean(model[band])
            assert ratio == pytest.approx(1.0, abs=0.15), (
                f"{name} {level}: PSD ratio {ratio:.3f} in [{a:.3f}, {b:.3f}] Hz"
            )


def test_l1_guidance_geometry() -> None:
    # on the circle, flying along it: exactly the centripetal acceleration (Park et al. 2004)
    r, v, l1 = 150.0, 18.0, 60.0
    acc = l1_lateral_accel_circle((0.0, 0.0), (v, 0.0), (0.0, r), r, 1.0, l1)
    assert acc == pytest.approx(v * v / r)
    # right of a northbound track, heading north: steer left, with 2V²/L1·sin η
    acc, remaining = l1_lateral_accel_segment((0.0, 10.0), (v, 0.0), (-500.0, 0.0), (500.0, 0.0), l1)
    eta = -math.atan2(10.0, math.sqrt(l1 * l1 - 100.0))
    assert acc == pytest.approx(2.0 * v * v / l1 * math.sin(eta)) and remaining == pytest.approx(500.0)


# ------------------------------------------------------------------------------------- scenarios
def test_shipped_scenarios_load() -> None:
    names = scenario_names()
    assert {"survey-wind8", "loiter-outage300", "survey-no-airspeed"} <= set(names)
    scs = {n: load_scenario(n) for n in names}
    assert scs["survey-no-airspeed"].airspeed is None and scs["survey-wind8"].airspeed is not None
    assert scs["survey-wind8"].wind.speed_m_s == 8.0
    assert [(w.start_s, w.end_s) for w in scs["survey-wind8"].gnss.outages] == [(300.0, 420.0)]
    assert [w.end_s - w.start_s for w in scs["loiter-outage300"].gnss.outages] == [300.0]
    assert scs["loiter-outage300"].route.type == "loiter" and scs["survey-wind8"].route.type == "survey"


def _mutate(path: str, value: Any) -> dict[str, Any]:
    d = _raw()
    *parents, last = path.split(".")
    node: Any = d
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node[p]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return d


_DELETE = object()


@pytest.mark.parametrize(
    ("path", "value", "key"),
    [
        ("home.lat_deg", _DELETE, "home.lat_deg: missing required key"),
        ("magnetic_field.source", _DELETE, "magnetic_field.source: missing"),
        ("magnetic_field.ned_nt", [1.0, 2.0, 3.0], "magnetic_field.ned_nt: "),
        ("wind.speed_m_s", -1.0, "wind.speed_m_s: "),
        ("turbulence.level", "severe", "turbulence.level: unknown level"),
        ("route.type", "figure9", "route.type: "),
        ("route.spacing_m", "wide", "route.spacing_m: expected a number"),
        ("route.colour", "red", "route.colour: unknown key"),
        ("sensors.imu.grade", "mpu6000", "sensors.imu.grade: unknown grade"),
        ("sensors.imu.vibration_multiplier", _DELETE, "sensors.imu.vibration_multiplier: missing"),
        ("sensors.airspeed", _DELETE, "sensors.airspeed: missing"),
        ("sensors.gnss.outages", [{"start_s": 50.0, "end_s": 40.0}], "sensors.gnss.outages[0].end_s: must be after"),
        ("sensors.ports.rate_hz", 30.0, "sensors.ports.rate_hz: must be in [50.0, 100.0]"),
        (
            "sensors.ports.points",
            [{"name": "PORT_NAME_TOO_LONG", "point_b": [0, 0, 0]}],
            "sensors.ports.points: port names",
        ),
        ("simulation.aero_rate_hz", 30.0, "simulation.aero_rate_hz: rate 30 Hz must divide"),
        ("simulation.physics_rate_hz", 200.0, "simulation.physics_rate_hz: must be in [400.0"),
        ("vehicle", "cessna", "vehicle: unknown vehicle"),
        ("seed", -3, "seed: must be in [0"),
        ("kind", "airframe", "kind: "),
    ],
)
def test_scenario_errors_name_the_key(path: str, value: Any, key: str) -> None:
    with pytest.raises(SpecError) as e:
        parse_scenario(_mutate(path, value), origin="s.yaml")
    assert f"s.yaml: {key}" in str(e.value)


def test_port_off_the_surface_is_an_error_naming_the_port(vehicle: Vehicle) -> None:
    d = _raw()
    d["sensors"]["ports"]["points"][3]["point_b"] = [0.0, 0.3, -0.3]  # 20 cm above the wing
    with pytest.raises(SpecError, match=r"sensors\.ports: port P03 is .* mm from the nearest surface point"):
        FlightWorld(parse_scenario(d, origin="s.yaml"), vehicle)


# ----------------------------------------------------------------------------------------- world
def test_world_protocol_and_sample_rates(vehicle: Vehicle) -> None:
    sc = load_scenario("survey-wind8")
    w = FlightWorld(sc, vehicle)
    world: World = w  # the structural type the mock autopilot takes
    assert world.dt_s == pytest.approx(1.0 / 400.0)
    assert (world.home_lat_deg, world.home_lon_deg, world.home_alt_m) == (42.283, -71.35, 50.0)
    ticks = [world.step() for _ in range(4 * 400)]
    t = np.array([tk.truth.t_s for tk in ticks])
    np.testing.assert_allclose(np.diff(t), 1.0 / 400.0)
    expected_hz = {"imu": 400, "baro": 50, "mag": 50, "airspeed": 50, "ports": 50, "servos": 50}
    for kind, hz in expected_hz.items():
        times = np.array([getattr(tk, kind).t_s for tk in ticks if getattr(tk, kind) is not None])
        assert len(times) == 4 * hz, kind
        np.testing.assert_allclose(np.diff(times), 1.0 / hz, err_msg=kind)
    fixes = [tk.gnss for tk in ticks if tk.gnss is not None]
    assert len(fixes) == 4 * 5 - 1  # 5 Hz, the last one still in its 100 ms latency
    assert all(f.fix_type == 3 for f in fixes)
    ports = ticks[-1].ports
    assert ports is not None and ports.names == sc.ports.names and ports.dp_pa.shape == (len(sc.ports.names),)
    tr = ticks[-1].truth
    assert np.linalg.norm(tr.q_nb) == pytest.approx(1.0) and np.linalg.norm(tr.wind_ned_m_s) > 4.0
    # the accelerometer reads the truth's specific force (plus its errors)
    imu = ticks[-1].imu
    assert imu is not None and np.linalg.norm(imu.accel_b_m_s2 - tr.specific_force_b_m_s2) < 0.5


def test_no_airspeed_scenario_has_no_pitot_samples(vehicle: Vehicle) -> None:
    ticks = FlightWorld(load_scenario("survey-no-airspeed"), vehicle).run(400)
    assert all(tk.airspeed is None for tk in ticks)
    assert sum(tk.ports is not None for tk in ticks) == 50


def test_world_gnss_outage_windows(vehicle: Vehicle) -> None:
    d = _raw()
    d["sensors"]["gnss"]["outages"] = [{"start_s": 1.0, "end_s": 2.5}]
    ticks = FlightWorld(parse_scenario(d, origin="t"), vehicle).run(4 * 400)
    for tk in ticks:
        t = tk.truth.t_s
        assert tk.gnss_outage == (1.0 <= t < 2.5)
        if tk.gnss is not None:
            assert not (1.0 <= tk.gnss.t_s < 2.5) and not (1.0 <= t < 2.5), f"fix at {t}"
    after = [tk.gnss.t_s for tk in ticks if tk.gnss is not None and tk.truth.t_s >= 2.5]
    assert after and min(after) == pytest.approx(2.6)  # first fix valid after the window (+ latency outside)


def test_worlds_are_reproducible_per_seed(vehicle: Vehicle) -> None:
    sc = load_scenario("loiter-outage300")
    a = FlightWorld(sc, vehicle).run(200)
    b = FlightWorld(sc, vehicle).run(200)
    c = FlightWorld(dataclasses.replace(sc, seed=sc.seed + 1), vehicle).run(200)
    ia, ib, ic = (ticks[-1].imu for ticks in (a, b, c))
    assert ia is not None and ib is not None and ic is not None
    np.testing.assert_array_equal(ia.accel_b_m_s2, ib.accel_b_m_s2)
    np.testing.assert_array_equal(a[-1].truth.pos_ned_m, b[-1].truth.pos_ned_m)
    assert not np.array_equal(ia.accel_b_m_s2, ic.accel_b_m_s2)


def test_ports_from_a_model_directory(vehicle: Vehicle, tmp_path: Path) -> None:
    geo = vehicle.geometry
    idx = [120, 2600, 4500]
    ports = [
        {"name": f"p{i:04d}", "point_b": [float(v) for v in geo.points_b[i]], "normal_b": [0.0, 0.0, 1.0]} for i in idx
    ]
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "model.yaml").write_text(yaml.safe_dump({"format": MODEL_FORMAT, "ports": ports}))
    d = _raw()
    d["sensors"]["ports"] = {k: v for k, v in d["sensors"]["ports"].items() if k != "points"}
    d["sensors"]["ports"]["model_dir"] = "model"  # relative to the scenario file
    sc = parse_scenario(d, origin=str(tmp_path / "s.yaml"))
    assert sc.ports.names == ("p0120", "p2600", "p4500")
    w = FlightWorld(sc, vehicle)
    np.testing.assert_array_equal(w.ports.point_index, idx)
    ticks = w.run(8)
    assert ticks[-1].ports is not None and ticks[-1].ports.names == sc.ports.names
    d["sensors"]["ports"]["model_dir"] = "missing"
    with pytest.raises(SpecError, match=r"sensors\.ports\.model_dir: cannot read the ports"):
        parse_scenario(d, origin=str(tmp_path / "s.yaml"))
