"""The shared geometry, atmosphere and lag code against independent references (scipy, pymap3d, ISA tables,
analytic responses), and the simulator's inline formulas against the shared ones."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from vdm_aero.atmosphere import density_kg_m3, isa, outside_air_temperature_c, pressure_altitude_m
from vdm_aero.geodesy import LocalFrame
from vdm_aero.lag import FirstOrderLag, first_order_lag, lag_coefficients
from vdm_aero.rotation import (
    dcm_from_quat,
    euler_from_quat,
    quat_exp,
    quat_from_dcm,
    quat_from_euler,
    quat_log,
    quat_multiply,
)

HOME = LocalFrame(42.283, -71.35, 50.0)
ANGLES = [(0.3, -0.2, 2.5), (-1.2, 0.7, -3.0), (0.0, 1.4, 0.1), (2.9, -0.05, 1.0)]


def _scipy(q: tuple[float, ...] | np.ndarray) -> Rotation:
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])  # scipy is scalar-last


@pytest.mark.parametrize("angles", ANGLES)
def test_quaternions_against_scipy(angles: tuple[float, float, float]) -> None:
    q = quat_from_euler(*angles)
    ref = Rotation.from_euler("ZYX", angles[::-1])  # intrinsic yaw, pitch, roll
    np.testing.assert_allclose(dcm_from_quat(q), ref.as_matrix(), atol=1e-14)
    assert euler_from_quat(q) == pytest.approx(angles, abs=1e-12)
    np.testing.assert_allclose(quat_from_dcm(ref.as_matrix()), q if q[0] >= 0 else -np.asarray(q), atol=1e-14)
    b = quat_from_euler(0.1, -0.3, 0.7)
    np.testing.assert_allclose(dcm_from_quat(quat_multiply(q, b)), (_scipy(q) * _scipy(b)).as_matrix(), atol=1e-14)


def test_quat_from_dcm_is_vectorised_and_sign_normalised() -> None:
    rots = Rotation.random(50, random_state=np.random.default_rng(3).integers(2**31))
    q = quat_from_dcm(rots.as_matrix())
    assert q.shape == (50, 4) and np.all(q[:, 0] >= 0.0)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q, rots.as_quat()[:, [3, 0, 1, 2]])), 1.0, atol=1e-13)


def test_rotation_vector_exp_log() -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        axis = rng.normal(size=3)
        v = axis / np.linalg.norm(axis) * rng.uniform(1e-9, 3.0)  # angles below π: log is then exact
        np.testing.assert_allclose(dcm_from_quat(quat_exp(v)), Rotation.from_rotvec(v).as_matrix(), atol=1e-13)
        np.testing.assert_allclose(quat_log(quat_exp(v)), v, atol=1e-12)


def test_hot_loop_dcm_is_the_shared_one() -> None:
    # the rigid body's right-hand side spells the DCM out in floats; its specific force must rotate by it
    from sim.flight.scenario import load_scenario
    from sim.flight.world import FlightWorld

    w = FlightWorld(load_scenario("survey-wind8"))
    for _ in range(200):
        w.step()
    y, k1 = w.state, w._k1
    f_b = np.array([w.aux.f_x, w.aux.f_y, w.aux.f_z])
    a_ned = dcm_from_quat(y[6:10]) @ f_b + np.array([0.0, 0.0, 9.80665])
    np.testing.assert_allclose(k1[3:6], a_ned, atol=1e-12)


def test_isa_against_published_table() -> None:
    # ICAO standard atmosphere table (Doc 7488): altitude → p [Pa], T [K], ρ [kg/m³]
    for h, p, t, rho in ((0.0, 101325.0, 288.15, 1.2250), (1000.0, 89874.6, 281.65, 1.1117),
                         (3000.0, 70108.5, 268.65, 0.90912), (11000.0, 22632.1, 216.65, 0.36392)):  # fmt: skip
        pp, tt, rr = isa(h)
        assert pp == pytest.approx(p, rel=2e-5) and tt == pytest.approx(t, abs=1e-9), f"FAILED @ {h} m"
        assert rr == pytest.approx(rho, rel=2e-4), f"FAILED @ {h} m"
        assert pressure_altitude_m(pp) == pytest.approx(h, abs=1e-6)
    assert density_kg_m3(101325.0, 288.15) == pytest.approx(1.2250, rel=1e-4)
    assert isa(500.0, 10.0)[0] == isa(500.0)[0] and isa(500.0, 10.0)[1] == isa(500.0)[1] + 10.0


def test_the_outside_air_temperature_is_picked_as_ardupilot_picks_it() -> None:
    # AP_Baro::get_external_temperature(): the airspeed sensor's while it reads, else the board's clamped to
    # 35 °C (INTERNAL_TEMPERATURE_CLAMP); a reading outside the sensors' operating range is no reading
    assert outside_air_temperature_c(12.5, 45.0) == 12.5
    assert outside_air_temperature_c(math.nan, 45.0) == 35.0
    assert outside_air_temperature_c(math.nan, 21.0) == 21.0
    assert outside_air_temperature_c(-60.0, 21.0) == 21.0 and outside_air_temperature_c(120.0, 40.0) == 35.0
    got = outside_air_temperature_c(np.array([10.0, np.nan, 90.0]), np.array([44.0, 44.0, 20.0]))
    np.testing.assert_array_equal(got, [10.0, 35.0, 20.0])


def test_geodesy_against_pymap3d() -> None:
    atol_m = 1e-3  # 1 mm
    rng = np.random.default_rng(11)
    for n, e, d in rng.uniform(-20_000.0, 20_000.0, size=(30, 3)) * np.array([1.0, 1.0, 0.02]):
        lat, lon, alt = HOME.to_geodetic(n, e, d)
        ref = pymap3d.ned2geodetic(n, e, d, HOME.lat_deg, HOME.lon_deg, HOME.alt_m)
        assert lat == pytest.approx(ref[0], abs=1e-9) and lon == pytest.approx(ref[1], abs=1e-9)
        assert alt == pytest.approx(ref[2], abs=atol_m)
        np.testing.assert_allclose(HOME.to_ned(lat, lon, alt), (n, e, d), atol=atol_m)
    # a hand-checked point: 1 km north at 42.283° N is 1000/M rad of latitude, M = 6,363,3xx m there
    m, _ = HOME.radii_m
    assert HOME.to_geodetic(1000.0, 0.0, 0.0)[0] - HOME.lat_deg == pytest.approx(
        math.degrees(1000.0 / (m + 50.0)), rel=1e-6
    )
    lat, lon, alt = HOME.to_geodetic_array(np.array([[100.0, 200.0, -30.0], [0.0, 0.0, 0.0]]))
    assert alt[1] == pytest.approx(50.0, abs=1e-6) and lat[0] == pytest.approx(HOME.to_geodetic(100.0, 200.0, -30.0)[0])


def test_lag_step_and_ramp_responses() -> None:
    tau, dt = 0.02, 0.001
    t = np.arange(0.0, 0.2, dt)
    step = np.where(t > 0.0, 1.0, 0.0)
    y = first_order_lag(t, step, tau)
    # the sampled step rises linearly over the first interval (first-order hold), then decays exactly
    k = t > 0.01
    np.testing.assert_allclose(
        y[k], 1.0 - (tau / dt) * (1.0 - math.exp(-dt / tau)) * np.exp(-(t[k] - dt) / tau), atol=1e-12
    )
    ramp = 3.0 * t
    yr = first_order_lag(t, ramp, tau)
    analytic = 3.0 * (t - tau * (1.0 - np.exp(-t / tau)))  # ramp from rest, exact
    np.testing.assert_allclose(yr, analytic, atol=1e-12)
    f = FirstOrderLag(dt, np.array([tau, 0.0]))
    out = [f.step(np.array([v, v])) for v in ramp]
    np.testing.assert_allclose(np.array(out)[:, 0], yr, atol=1e-12)
    np.testing.assert_allclose(np.array(out)[:, 1], ramp)
    assert lag_coefficients(dt, 0.0) == (0.0, 0.0, 1.0)
