"""The as-built aircraft: each effect does what its physics says, and the estimator side never sees it."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sim.airframe.vlm import FlightStates
from sim.flight.asbuilt import (
    AS_BUILT_EFFECTS,
    AS_BUILT_PRESETS,
    ControlMap,
    UnsteadyLag,
    cg_transfer_matrix,
    port_installation_errors,
)
from sim.flight.record import fly
from sim.flight.scenario import VEHICLES, load_scenario, parse_scenario
from sim.flight.world import FlightWorld, Vehicle
from vdm_aero.dataset import Reference
from vdm_aero.errors import SpecError

ROOT = Path(__file__).resolve().parents[1]
ASB = AS_BUILT_PRESETS["uav-2m-asbuilt"]


@pytest.fixture(scope="module")
def asbuilt() -> Vehicle:
    return Vehicle.build("uav-2m-asbuilt")


@pytest.fixture(scope="module")
def design() -> Vehicle:
    return Vehicle.build("uav-2m")


def test_estimator_side_never_imports_the_world() -> None:
    # the as-built truth lives in sim; vdm_aero (calibration, navigation) must not reach it
    for path in (ROOT / "vdm_aero").rglob("*.py"):
        text = path.read_text()
        assert "asbuilt" not in text and "import sim" not in text and "from sim" not in text, path


def test_mass_properties_follow_the_parallel_axis_theorem(asbuilt: Vehicle, design: Vehicle) -> None:
    m0, m1 = design.mass.mass_kg, asbuilt.mass.mass_kg
    assert m1 == pytest.approx(m0 + ASB.mass.payload_kg, abs=1e-12)
    # CG: first moment of the payload and the battery move over the new mass
    battery_kg = design.geometry.design.mass_kg - (
        sum(e.mass_kg for e in design.geometry.design.equipment)
        + sum(
            s.mass_kg for s in (design.geometry.design.wing, design.geometry.design.htail, design.geometry.design.vtail)
        )
        + design.geometry.design.fuselage.mass_kg
    )
    x_cg = (ASB.mass.payload_kg * ASB.mass.payload_x_m + battery_kg * ASB.mass.battery_shift_x_m) / m1
    assert asbuilt.r_cg_b[0] == pytest.approx(x_cg, abs=1e-12)
    assert asbuilt.r_cg_b[2] == pytest.approx(ASB.mass.payload_kg * ASB.mass.payload_z_m / m1, abs=1e-12)
    # the payload sits 0.18 m off the CG: Iyy and Izz grow by about m·x², Ixx by about m·z²
    d_iyy = asbuilt.mass.inertia_kg_m2[1, 1] - design.mass.inertia_kg_m2[1, 1]
    assert 0.5 * ASB.mass.payload_kg * 0.18**2 < d_iyy < 2.0 * ASB.mass.payload_kg * 0.2**2
    # thrust acts at the hub seen from the true CG
    assert asbuilt.propulsion.thrust_point_b[0] == pytest.approx(0.45 - asbuilt.r_cg_b[0], abs=1e-12)


def test_cg_transfer_moves_moments_by_r_cross_f() -> None:
    ref = Reference(0.39, 0.2, 2.0)
    r = np.array([0.01, 0.0, 0.004])
    c = np.array([-0.03, 0.01, -0.5, 0.001, 0.02, -0.002])
    out = cg_transfer_matrix(r, ref) @ c
    f = c[:3] * 1.0  # per unit q̄S
    m = c[3:] * np.array([2.0, 0.2, 2.0]) - np.cross(r, f)
    assert np.allclose(out[:3], c[:3]) and np.allclose(out[3:] * np.array([2.0, 0.2, 2.0]), m)


def test_rigging_and_friction_change_the_aerodynamics(asbuilt: Vehicle, design: Vehicle) -> None:
    st = FlightStates.make(18.0, alpha_rad=math.radians(3.0))
    c0 = design.model.evaluate_states(st)[1][0]
    c1 = asbuilt.model.evaluate_states(st)[1][0]
    # +0.35° wing incidence → more lift (CZ more negative) at the same body α; rougher skin → more drag
    assert c1[2] < c0[2] - 0.01
    assert c1[0] < c0[0]
    # the left wing washes out 0.5° more: it lifts less, so the aircraft rolls left (Croll < 0)
    assert c1[3] < c0[3] - 1e-4


def test_control_map_effectiveness_and_offsets() -> None:
    cm = ControlMap.build(ASB, frozenset({"control_effectiveness", "rigging"}))
    a, e, r = cm.apply(0.1, -0.1, 0.05)
    assert a == pytest.approx(0.85 * 0.1 + math.radians(0.6))
    assert e == pytest.approx(0.88 * -0.1 + math.radians(-0.8))
    assert cm.servo_for(a, e, r) == pytest.approx((0.1, -0.1, 0.05))
    assert ControlMap.build(ASB, frozenset()).apply(0.1, 0.2, 0.3) == (0.1, 0.2, 0.3)


def test_unsteady_lag_is_wagner_like() -> None:
    # a step in α: the effective incidence starts at φ(0) = 1 − A1 − A2 = 0.5 of the step and recovers
    # along Jones' φ(s) (a small step: the recursion assumes α linear within a step)
    lag = UnsteadyLag(ASB.unsteady, 0.0)
    v, dt, c = 18.0, 1e-4, ASB.unsteady.chord_m
    step = math.radians(2.0)
    alag, _ = lag.step(step, v, dt)
    assert (step - alag) / step == pytest.approx(0.5, abs=0.02)
    t = dt
    while t < 0.5:
        alag, sep = lag.step(step, v, dt)
        t += dt
    s = 2 * v * t / c
    phi = 1 - 0.165 * math.exp(-0.0455 * s) - 0.335 * math.exp(-0.3 * s)
    assert (step - alag) / step == pytest.approx(phi, abs=0.01)
    # the separation onset trails α_E by T_f·dα_E/dt: < 1 % of the step once the fast part has settled
    assert abs(sep) < 0.01 * step
    t_f_s = ASB.unsteady.t_f_semichords * c / (2 * v)
    d_alpha_e = (step - alag) - (step - lag.step(step, v, dt)[0])
    # a first-order lag of an input decaying with τ ≈ 0.15 s (Wagner's slow term) trails by
    # T_f·rate/(1 − T_f/τ) ≈ 1.13·T_f·rate
    assert sep == pytest.approx(-1.13 * t_f_s * d_alpha_e / dt, rel=0.05)


def test_port_installation_errors_belong_to_the_airframe() -> None:
    a = port_installation_errors(("p1", "p2", "p3"), ASB.ports)
    b = port_installation_errors(("p3", "p1"), ASB.ports)
    assert b.bias_cp[1] == a.bias_cp[0] and b.lag_s[0] == a.lag_s[2]  # same port, same errors
    lo, hi = ASB.ports.lag_range_s
    assert np.all((a.lag_s >= lo) & (a.lag_s <= hi)) and len(set(a.lag_s)) == 3
    assert np.all(np.abs(a.offset_m) == ASB.ports.offset_m)


def test_a_released_payload_leaves_the_aircraft_lighter_at_once(asbuilt: Vehicle, design: Vehicle) -> None:
    # the payload-release scenario: mass, CG and inertia lose the payload; at the release instant nothing
    # aerodynamic has changed yet (same airflow, same deflections, same thrust), so Newton's second law scales
    # every axis of the specific force by m_before / m_after
    light = asbuilt.without_payload()
    assert light.mass.mass_kg == pytest.approx(design.mass.mass_kg, abs=1e-12)
    assert light.r_cg_b[0] == pytest.approx(asbuilt.r_cg_b[0] - ASB.mass.payload_kg * ASB.mass.payload_x_m
                                            / asbuilt.mass.mass_kg, abs=1e-3)  # fmt: skip
    assert np.all(np.diag(light.mass.inertia_kg_m2) < np.diag(asbuilt.mass.inertia_kg_m2))
    with pytest.raises(ValueError, match="no payload"):
        design.without_payload()
    sc = replace(load_scenario("calibration-asbuilt"), turbulence="none", duration_s=30.0, payload_release_s=2.0)
    world = FlightWorld(sc, asbuilt)
    f_b = {}
    while world.t_s < 2.0 + 1.5 * world.dt_s:
        tick = world.step()
        f_b[round(world.t_s / world.dt_s)] = tick.truth.specific_force_b_m_s2
    n = round(2.0 / world.dt_s)
    k = asbuilt.mass.mass_kg / light.mass.mass_kg  # 1.08
    # one 2.5-ms step's own change of the flow stays well under the payload's 8 % (f_y is near zero: absolute)
    assert f_b[n] == pytest.approx(k * f_b[n - 1], rel=2e-3, abs=0.01)
    assert np.linalg.norm(f_b[n] - f_b[n - 1]) > 0.5  # the step itself: ≈ 8 % of g
    assert world.vehicle.mass.mass_kg == light.mass.mass_kg
    with pytest.raises(ValueError, match="no payload"):
        FlightWorld(replace(sc, vehicle=VEHICLES["uav-2m"], as_built_effects=frozenset()))


def test_slipstream_grows_with_thrust(asbuilt: Vehicle) -> None:
    sc = load_scenario("calibration-asbuilt")
    world = FlightWorld(sc, asbuilt)
    st = FlightStates.make(16.0, alpha_rad=math.radians(3.0))
    y = world.strip_aero.outputs(st)
    n = 6 + world.strip_aero.n_ports
    slip = y[0, n : n + 6]
    # more dynamic pressure over the wing root and tail per unit T_c: more lift (CZ < 0) and a tail moment
    assert slip[2] < -1e-3
    assert abs(slip[4]) > 1e-4
    assert world.thrust_coeff() > 0.05  # cruise thrust gives a T_c of order 0.1


def test_every_effect_switches(asbuilt: Vehicle) -> None:
    sc = load_scenario("calibration-asbuilt")
    assert sc.as_built_effects == frozenset(AS_BUILT_EFFECTS)
    none = replace(sc, as_built_effects=frozenset())
    w0 = FlightWorld(none, Vehicle.build("uav-2m-asbuilt", frozenset()))
    w1 = FlightWorld(sc, asbuilt)
    assert w0.trim.throttle < w1.trim.throttle - 0.03  # payload, drag and a weaker propeller: more throttle


def test_scenario_effects_are_checked() -> None:
    text = (ROOT / "sim/presets/scenarios/calibration-asbuilt.yaml").read_text()
    import yaml

    doc = yaml.safe_load(text)
    doc["as_built_effects"] = ["slipstream", "warp_drive"]
    with pytest.raises(SpecError, match=r"as_built_effects.*warp_drive"):
        parse_scenario(doc, origin="c.yaml")
    doc["as_built_effects"] = ["slipstream"]
    assert parse_scenario(doc, origin="c.yaml").as_built_effects == frozenset({"slipstream"})
    doc["vehicle"] = "uav-2m"
    with pytest.raises(SpecError, match="as_built_effects: vehicle uav-2m is a design"):
        parse_scenario(doc, origin="c.yaml")
    doc["payload_release_s"] = 5.0  # the payload this aircraft carries (mass_properties) can be dropped
    with pytest.raises(SpecError, match="payload_release_s: only an as-built vehicle with mass_properties"):
        parse_scenario(doc | {"vehicle": "uav-2m-asbuilt"}, origin="c.yaml")
    del doc["payload_release_s"]
    del doc["as_built_effects"]
    doc["manoeuvres"] = [{"type": "doublet", "start_s": 1.0, "axis": "sideways", "amplitude_deg": 2, "period_s": 1}]
    with pytest.raises(SpecError, match=r"manoeuvres\[0\].axis"):
        parse_scenario(doc, origin="c.yaml")
    assert "uav-2m-asbuilt" in VEHICLES
    doc |= {"vehicle": "uav-2m-asbuilt", "as_built_effects": "all", "payload_release_s": 5.0}
    del doc["manoeuvres"]
    assert parse_scenario(doc, origin="c.yaml").payload_release_s == 5.0


def test_manoeuvres_excite_the_aircraft(asbuilt: Vehicle) -> None:
    sc = replace(load_scenario("calibration-asbuilt"), duration_s=40.0)
    sensors, truth, _ = fly(sc, asbuilt)
    t, omega = truth["t_s"], truth["omega_b_rad_s"]
    # the pitch doublet at 32 s (cycle start 20 s + 12 s) gives a pitch-rate burst well above the cruise's
    burst = np.abs(omega[(t > 32.0) & (t < 34.0), 1]).max()
    calm = np.abs(omega[(t > 25.0) & (t < 31.0), 1]).max()
    assert burst > 3.0 * calm
    # per-port tubing lags and biases reach the sensors: the flight log has every stream
    assert sensors["ports_dp_pa"].shape == (len(truth["t_s"]), 18)
    assert len(sensors["imu_t_s"]) == round(40.0 * 400)
