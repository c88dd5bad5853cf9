"""The harsh world's effects (sim.flight.world_effects), each against its sourced formula or published numbers."""

from __future__ import annotations

import math
from dataclasses import replace
from importlib import resources

import numpy as np
import pytest

from sim.flight.asbuilt import AS_BUILT_PRESETS, draw_airframe
from sim.flight.environment import SteadyWind, WindProfile
from sim.flight.scenario import load_scenario, parse_scenario, with_world
from sim.flight.sensors import (
    BARO_GRADES,
    GNSS_GRADES,
    IMU_GRADES,
    MAG_GRADES,
    PITOT_GRADES,
    Barometer,
    Gnss,
    Imu,
    Magnetometer,
    PitotAirspeed,
)
from sim.flight.world_effects import (
    GNSS_JITTER_S,
    HARSH,
    HEATER_TARGET_C,
    IMU_PARTS,
    MOTOR_INTERFERENCE,
    WMM_SIGMA_NT,
    BaroInstallation,
    BoardThermal,
    ImuInstallation,
    MagInstallation,
    PitotInstallation,
    draw_installation,
    site_field_anomaly_ned_t,
)
from sim.spec_reader import parse_yaml
from vdm_aero.errors import SpecError
from vdm_aero.geodesy import EARTH_RATE_RAD_S, LocalFrame, earth_rate_ned, normal_gravity_m_s2
from vdm_aero.rotation import dcm_from_quat, quat_from_euler

NO_NOISE_IMU = replace(
    IMU_GRADES["icm-42688-p"],
    accel_noise_density_m_s2=0.0,
    accel_turn_on_sigma_m_s2=0.0,
    accel_gm_sigma_m_s2=0.0,
    gyro_noise_density_rad_s=0.0,
    gyro_turn_on_sigma_rad_s=0.0,
    gyro_gm_sigma_rad_s=0.0,
)
_IDEAL_IMU = ImuInstallation(None, None, None, None, None, None, None, None, False)


# ------------------------------------------------------------------------------------------ Earth
def test_normal_gravity_matches_the_wgs84_published_values() -> None:
    # NIMA TR8350.2 table 3.4: γ_e = 9.7803253359, γ_p = 9.8321849378 m/s²; the free-air gradient ≈ −0.3086 mGal/m
    assert normal_gravity_m_s2(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity_m_s2(90.0, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    grad = (normal_gravity_m_s2(45.0, 100.0) - normal_gravity_m_s2(45.0, 0.0)) / 100.0
    assert grad == pytest.approx(-3.086e-6, rel=2e-3)
    w = earth_rate_ned(60.0)
    assert np.linalg.norm(w) == pytest.approx(EARTH_RATE_RAD_S)
    assert w[0] == pytest.approx(EARTH_RATE_RAD_S * 0.5) and w[2] < 0.0  # northern hemisphere: up component


@pytest.fixture(scope="module")
def earth_world() -> object:
    from sim.flight.world import FlightWorld

    sc = load_scenario("nav-survey")
    return FlightWorld(with_world(replace(sc, duration_s=2.0), frozenset({"earth-gravity", "earth-rotation"}), 0))


def test_the_world_adds_coriolis_and_normal_gravity(earth_world: object) -> None:
    w = earth_world
    y = (0.0, 0.0, -100.0, 20.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    en, ee, ed = w._earth_accel(y)  # type: ignore[attr-defined]
    lat = math.radians(w.home_lat_deg)  # type: ignore[attr-defined]
    # flying north at 20 m/s: −2Ω×v has an east part 2Ω·sin(lat)·v (the Coriolis drift to the right)
    assert ee == pytest.approx(2.0 * EARTH_RATE_RAD_S * math.sin(lat) * 20.0, rel=1e-3)
    lat_deg, _, h = w.frame.to_geodetic(0.0, 0.0, -100.0)  # type: ignore[attr-defined]
    g_extra = normal_gravity_m_s2(lat_deg, h) - 9.80665
    # the transport rate adds v²/R downwards-up (−v_N²/R on the down axis)
    assert ed == pytest.approx(g_extra - 20.0**2 / (6378137.0 + 100.0), abs=1e-6)
    assert abs(en) < 1e-6


def test_the_gyros_sense_the_earth_rate(earth_world: object) -> None:
    w = earth_world
    tick = w.step()  # type: ignore[attr-defined]
    t = tick.truth
    c_nb = dcm_from_quat(t.q_nb)
    omega_ie_b = c_nb.T @ earth_rate_ned(w.home_lat_deg)  # type: ignore[attr-defined]
    # noise and biases are there too: the Earth-rate part is what differs from the truth's ω_nb beyond them
    g = IMU_GRADES["icm-42688-p"]
    resid = tick.imu.gyro_b_rad_s - t.omega_b_rad_s - w.imu.turn_on_bias[3:]  # type: ignore[attr-defined]
    bound = 5 * (g.gyro_gm_sigma_rad_s + g.gyro_noise_density_rad_s * math.sqrt(400.0) * 2.0) + 1e-5
    assert np.all(np.abs(resid - omega_ie_b) < bound)


# ----------------------------------------------------------------------------------- magnetometer
def test_soft_iron_and_the_motor_field_follow_their_formula() -> None:
    grade = replace(MAG_GRADES["rm3100"], noise_t=0.0)
    field = np.array([20e-6, -5e-6, 46e-6])
    hard = np.array([1e-6, 2e-6, -1e-6])
    inst = draw_installation(frozenset({"mag-soft-iron", "mag-motor"}), np.random.default_rng(1), part_index=0).mag
    assert inst.soft_iron is not None and inst.motor_field_b_t is not None
    np.testing.assert_allclose(inst.soft_iron, inst.soft_iron.T)  # soft iron is symmetric
    assert np.max(np.abs(inst.soft_iron)) <= 0.03
    # the interference at full throttle is 5–30 % of a 50 µT field (ArduPilot's acceptable compassmot range)
    frac = np.linalg.norm(inst.motor_field_b_t) / 50e-6
    assert MOTOR_INTERFERENCE[0] <= frac <= MOTOR_INTERFERENCE[1]
    mag = Magnetometer(grade, field, hard, np.random.default_rng(0), installation=inst)
    c = dcm_from_quat(quat_from_euler(0.1, -0.05, 1.2))
    s = mag.sample(0.0, c, throttle=0.6)
    b = c.T @ field
    np.testing.assert_allclose(s.field_b_t, b + inst.soft_iron @ b + hard + 0.6 * inst.motor_field_b_t, atol=1e-15)
    ideal = Magnetometer(grade, field, hard, np.random.default_rng(0), installation=MagInstallation(None, None))
    np.testing.assert_allclose(ideal.sample(0.0, c, throttle=0.6).field_b_t, b + hard, atol=1e-15)


def test_the_site_field_differs_from_the_wmm_by_its_error_model() -> None:
    rng = np.random.default_rng(4)
    d = np.array([site_field_anomaly_ned_t(rng) for _ in range(4000)]) * 1e9
    np.testing.assert_allclose(d.std(axis=0), WMM_SIGMA_NT, rtol=0.06)
    assert np.all(np.abs(d.mean(axis=0)) < 10.0)


# -------------------------------------------------------------------------------------------- IMU
def _imu(inst: ImuInstallation, grade: object = NO_NOISE_IMU) -> Imu:
    return Imu(grade, 400.0, 1.0, np.random.default_rng(0), installation=inst)  # type: ignore[arg-type]


def test_the_level_calibration_levels_the_accelerometer_as_ardupilot_does() -> None:
    """ArduPilot's level calibration (AP_InertialSensor::_calculate_trim) trims roll and pitch from the
    accelerometer's sample at rest, cross-axis terms included: after it, every airframe's accelerometer reads
    gravity along z, level, to within the calibration's own residual, whatever its cross-axis draws."""
    from sim.flight.world_effects import LEVEL_TRIM_RESIDUAL_RAD

    worst = 0.0
    effects = frozenset({"imu-grade", "imu-scale-misalignment"})
    for airframe in range(40):
        inst = draw_installation(effects, np.random.default_rng([7, airframe]), part_index=airframe).imu
        assert inst.accel_m is not None
        a = inst.accel_m @ np.array([0.0, 0.0, -9.81])  # the sample on the bench, level
        roll, pitch = math.atan2(-a[1], -a[2]), math.atan2(a[0], math.hypot(a[1], a[2]))
        worst = max(worst, abs(roll), abs(pitch))
    # the residual is drawn within ±LEVEL_TRIM_RESIDUAL_RAD; second-order terms of a 1 % matrix add < 1e-4 rad
    assert worst <= LEVEL_TRIM_RESIDUAL_RAD + 1e-4


def test_scale_factor_misalignment_and_g_sensitivity() -> None:
    inst = draw_installation(
        frozenset({"imu-scale-misalignment", "imu-g-sensitivity"}), np.random.default_rng(2), part_index=1
    ).imu
    assert inst.accel_m is not None and inst.gyro_m is not None and inst.gyro_g_sens is not None
    part = IMU_PARTS["icm-42688-p"]  # imu-grade is off: the scenario's part
    assert np.max(np.abs(np.diag(inst.gyro_m) - 1.0)) <= part.gyro_scale_tol
    # the level calibration turned both sensors so that the accelerometer reads level at rest
    # (test_the_level_calibration_levels_the_accelerometer_as_ardupilot_does); yaw is not levelled
    off_a = inst.accel_m - np.diag(np.diag(inst.accel_m))
    anti = 0.5 * (off_a - off_a.T)
    assert abs(anti[1, 0]) <= part.accel_cross_axis
    off = inst.gyro_m - np.diag(np.diag(inst.gyro_m))
    assert np.max(np.abs(off)) <= part.gyro_cross_axis + part.accel_cross_axis + 1e-3
    assert np.max(np.abs(inst.gyro_g_sens)) <= part.gyro_g_sens_rad_s_per_m_s2
    f, w = np.array([1.0, -0.5, -9.6]), np.array([0.2, -0.1, 0.05])
    s = _imu(inst).sample(0.0, f, w, 0.5, 15.0)
    np.testing.assert_allclose(s.accel_b_m_s2, inst.accel_m @ f, atol=1e-12)
    np.testing.assert_allclose(s.gyro_b_rad_s, inst.gyro_m @ w + inst.gyro_g_sens @ f, atol=1e-12)


def test_the_board_temperature_and_the_thermal_bias() -> None:
    th = BoardThermal(heated=False, self_heating_k=12.0, tau_s=600.0, start_fraction=0.5)
    inst = replace(_IDEAL_IMU, thermal=th, accel_tempco_m_s2_k=np.array([1e-3, -2e-3, 0.5e-3]),
                   gyro_tempco_rad_s_k=np.array([1e-5, 0.0, -2e-5]))  # fmt: skip
    imu = _imu(inst)
    f, w = np.array([0.0, 0.0, -9.8]), np.zeros(3)
    air = 10.0
    first = imu.sample(0.0, f, w, 0.5, air)
    assert first.temperature_c == pytest.approx(air + 0.5 * 12.0)  # the board, not the air
    n = 400 * 300
    for k in range(1, n + 1):
        s = imu.sample(k / 400.0, f, w, 0.5, air)
    # first order towards air + self-heating: T(t) = T_target + (T0 − T_target)·e^(−t/τ)
    expect = air + 12.0 + (first.temperature_c - air - 12.0) * math.exp(-300.0 / 600.0)
    assert s.temperature_c == pytest.approx(expect, rel=1e-9)
    dtemp = s.temperature_c - first.temperature_c
    np.testing.assert_allclose(s.accel_b_m_s2 - f, inst.accel_tempco_m_s2_k * dtemp, atol=1e-12)
    np.testing.assert_allclose(s.gyro_b_rad_s, inst.gyro_tempco_rad_s_k * dtemp, atol=1e-12)
    heated = BoardThermal(heated=True, self_heating_k=5.0, tau_s=600.0, start_fraction=1.0)
    assert heated.target_c(-5.0) == HEATER_TARGET_C and heated.target_c(45.0) == 50.0


def test_an_installed_imu_has_no_additive_error_stream() -> None:
    with pytest.raises(ValueError, match="ideal part"):
        _imu(replace(_IDEAL_IMU, saturate=True)).errors(np.zeros(3))


def test_the_ranges_clip() -> None:
    inst = replace(_IDEAL_IMU, saturate=True)
    part = IMU_PARTS["icm-42688-p"]
    s = _imu(inst).sample(0.0, np.array([200.0, 0.0, -9.8]), np.array([0.0, 50.0, 0.0]), 1.0, 15.0)
    assert s.accel_b_m_s2[0] == part.accel_range_m_s2 == pytest.approx(16 * 9.80665)
    assert s.gyro_b_rad_s[1] == part.gyro_range_rad_s == pytest.approx(math.radians(2000.0))


def test_the_fleet_alternates_imu_parts_and_the_vibration_varies() -> None:
    a = draw_installation(HARSH, np.random.default_rng([1, 0]), part_index=0).imu
    b = draw_installation(HARSH, np.random.default_rng([1, 1]), part_index=1).imu
    assert {a.part, b.part} == {"icm-42688-p", "bmi088"}
    assert a.vibration_multiplier != b.vibration_multiplier
    # an Imu built with the installation takes its vibration level
    imu = Imu(IMU_GRADES["bmi088"], 400.0, 2.0, np.random.default_rng(0), installation=b)
    assert imu.vibration_multiplier == b.vibration_multiplier


def test_switching_one_effect_off_leaves_the_other_draws() -> None:
    one = draw_installation(HARSH, np.random.default_rng(9), part_index=2)
    two = draw_installation(HARSH - {"mag-motor"}, np.random.default_rng(9), part_index=2)
    assert two.mag.motor_field_b_t is None
    np.testing.assert_array_equal(one.mag.soft_iron, two.mag.soft_iron)
    np.testing.assert_array_equal(one.imu.gyro_m, two.imu.gyro_m)
    assert one.pitot == two.pitot


# ------------------------------------------------------------------------------------------ pitot
def test_the_pitot_position_error_and_ratio_follow_their_formula() -> None:
    inst = PitotInstallation(ratio_error=0.03, static_cp=0.01, static_cp_per_rad=0.04, incidence_k=0.1,
                             mount_rad=(0.0, 0.0), lag_s=0.0)  # fmt: skip
    p = PitotAirspeed(PITOT_GRADES["ms4525do-001d"], np.random.default_rng(0), installation=inst)
    q, a, b = 220.0, math.radians(6.0), math.radians(3.0)
    theta = math.acos(math.cos(a) * math.cos(b))
    expect = q * (1.03 * (1.0 - 0.1 * theta**2) - (0.01 + 0.04 * a))
    assert p.probe_dp_pa(q, a, b) == pytest.approx(expect, rel=1e-12)
    # Gracey: a simple total-pressure tube reads within 1 % up to about ±10–15°: k·θ² ≤ 1 % at 10°
    assert 0.15 * math.radians(10.0) ** 2 <= 0.01


def test_the_pitot_tubing_lag_is_first_order() -> None:
    inst = PitotInstallation(0.0, 0.0, 0.0, 0.0, (0.0, 0.0), lag_s=0.04)
    grade = replace(PITOT_GRADES["ms4525do-001d"], noise_pa=0.0, offset_sigma_pa=0.0, resolution_pa=1e-9)
    p = PitotAirspeed(grade, np.random.default_rng(0), installation=inst)
    p.sample(0.0, 100.0, 15.0)  # settles on the first sample
    t = np.arange(1, 11) / grade.rate_hz
    out = [p.sample(tk, 200.0, 15.0).dp_pa for tk in t]
    # the input ramps 100 → 200 Pa over the first interval Δ (first-order hold), then holds: the exact
    # response of τ·ẏ + y = u is y(t) = 200 − 100·(τ/Δ)(1 − e^(−Δ/τ))·e^(−(t − Δ)/τ) for t ≥ Δ
    dt, tau = 1.0 / grade.rate_hz, 0.04
    expect = 200.0 - 100.0 * (tau / dt) * (1.0 - math.exp(-dt / tau)) * np.exp(-(t - dt) / tau)
    np.testing.assert_allclose(out, expect, rtol=1e-9)
    assert np.all(np.diff(out) > 0.0)


def test_the_airspeed_sensor_reads_its_own_warmth() -> None:
    inst = PitotInstallation(0.0, 0.0, 0.0, 0.0, (0.0, 0.0), lag_s=0.0, temperature_offset_k=5.5)
    p = PitotAirspeed(PITOT_GRADES["ms4525do-001d"], np.random.default_rng(0), installation=inst)
    assert p.sample(0.0, 200.0, 12.0).temperature_c == pytest.approx(17.5)
    kind = PitotAirspeed(PITOT_GRADES["ms4525do-001d"], np.random.default_rng(0))
    assert kind.sample(0.0, 200.0, 12.0).temperature_c == 12.0
    warm = [draw_installation(HARSH, np.random.default_rng(k), part_index=0).pitot for k in range(20)]
    offsets = [w.temperature_offset_k for w in warm if w is not None]
    assert len(offsets) == 20 and 0.0 <= min(offsets) < max(offsets) <= 8.0
    off = draw_installation(HARSH - {"pitot-temperature"}, np.random.default_rng(3), part_index=0).pitot
    assert off is not None and off.temperature_offset_k == 0.0


# ------------------------------------------------------------------------------------------- GNSS
def test_gnss_latency_and_the_time_an_autopilot_logs() -> None:
    grade = GNSS_GRADES["ublox-neo-m9n"]
    gnss = Gnss(grade, LocalFrame(42.0, -71.0, 50.0), (), (), np.random.default_rng(0), true_latency_s=0.15)
    gnss.measure(1.0, (0.0, 0.0, -100.0), (20.0, 0.0, 0.0))
    assert gnss.deliver(1.0 + 0.15 - 1e-6) is None  # not before the true latency
    s = gnss.deliver(1.0 + 0.15 + 6 * GNSS_JITTER_S)
    assert s is not None
    # the log carries arrival − the assumed 100 ms: the time of validity is off by the latency's error
    assert 0.05 <= s.t_s - 1.0 <= 0.05 + 6 * GNSS_JITTER_S


def test_gnss_accuracy_varies_and_the_reported_h_acc_follows_it() -> None:
    grade = GNSS_GRADES["ublox-neo-m9n"]
    frame = LocalFrame(42.0, -71.0, 50.0)

    def h_acc(seed: int, fixes: int) -> np.ndarray:
        gnss = Gnss(grade, frame, (), (), np.random.default_rng(seed), varying_accuracy=True)
        out = []
        for k in range(fixes):
            gnss.measure(k * 0.2, (0.0, 0.0, -100.0), (0.0, 0.0, 0.0))
            out.append(gnss.deliver(k * 0.2 + 0.2).h_acc_m)
        return np.array(out)

    one = h_acc(1, 3000)  # ten minutes of one receiver: the sky changes over minutes
    assert one.max() / one.min() > 1.5
    assert np.abs(np.diff(np.log(one))).max() < 0.1  # slowly (T = 300 s), not fix to fix
    # across receivers the log-scale is stationary with the sourced σ_ln = 0.35 around the grade's figure
    first = np.array([h_acc(s, 1)[0] for s in range(600)])
    nominal = math.hypot(grade.h_white_sigma_m, grade.h_gm_sigma_m)
    assert np.std(np.log(first / nominal)) == pytest.approx(0.35, rel=0.1)
    assert abs(np.mean(np.log(first / nominal))) < 0.05


# ------------------------------------------------------------------------------------------- baro
def test_the_static_source_error_of_the_barometer() -> None:
    grade = replace(BARO_GRADES["ms5611"], noise_pa=0.0, gm_sigma_pa=0.0, resolution_pa=1e-9)
    b = Barometer(grade, np.random.default_rng(0), installation=BaroInstallation(0.02, -0.1))
    s = b.sample(0.0, 100000.0, 15.0, qbar_pa=220.0, alpha_rad=0.05)
    assert s.pressure_pa == pytest.approx(100000.0 + 220.0 * (0.02 - 0.1 * 0.05), abs=1e-6)


# ------------------------------------------------------------------------------------- wind, fleet
def test_the_wind_profile_is_a_power_law_with_veer() -> None:
    prof = WindProfile(reference_height_m=120.0, exponent=0.2, veer_deg_per_100m=4.0)
    ref = SteadyWind(8.0, 250.0)
    w = prof.wind_ned(ref, 300.0)
    assert np.linalg.norm(w) == pytest.approx(8.0 * 2.5**0.2)
    np.testing.assert_allclose(w, SteadyWind(8.0 * 2.5**0.2, 250.0 + 4.0 * 1.8).ned_m_s)
    np.testing.assert_allclose(prof.wind_ned(ref, 120.0), ref.ned_m_s)


def test_the_fleet_draws_airframes_within_the_build_tolerances() -> None:
    nominal = AS_BUILT_PRESETS["uav-2m-asbuilt"]
    a = draw_airframe(nominal, np.random.default_rng([1, 0]), 0)
    b = draw_airframe(nominal, np.random.default_rng([1, 1]), 1)
    assert a != b and a.unsteady == nominal.unsteady  # the build varies, the physics does not
    for x in (a, b):
        assert abs(x.rigging.wing_incidence_offset_deg) <= 0.5
        assert 0.8 <= x.control.elevator <= 0.9 and 0.88 <= x.propulsion.ct0_factor <= 0.96
    sc = load_scenario("nav-survey")
    one = with_world(sc, HARSH, 1)
    assert one.world_effects == HARSH and one.airframe_index == 1
    assert one.vehicle.as_built == draw_airframe(nominal, np.random.default_rng([20261125, 1, 1]), 1)
    assert with_world(sc, HARSH - {"fleet"}, 1).vehicle == sc.vehicle


def test_a_scenario_names_its_world_effects() -> None:
    text = resources.files("sim").joinpath("presets", "scenarios", "nav-survey.yaml").read_text()
    data = parse_yaml(text, "nav-survey")
    assert parse_scenario({**data, "world_effects": "all"}).world_effects == HARSH
    assert parse_scenario({**data, "world_effects": ["mag-motor"]}).world_effects == {"mag-motor"}
    assert parse_scenario(data).world_effects == frozenset()  # the shipped scenarios: the kind world
    with pytest.raises(SpecError, match=r"world_effects.*unknown world effects.*'magnetic-storm'"):
        parse_scenario({**data, "world_effects": ["magnetic-storm"]})
