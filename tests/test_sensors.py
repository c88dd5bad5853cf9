"""Sensor models of sim.flight: noise statistics, latency and outages, pneumatic lag, quantisation.

All records are seeded; tolerances are stated with their meaning next to each check.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim.flight.sensors import (
    GNSS_GRADES,
    IMU_GRADES,
    PITOT_GRADES,
    PORT_GRADES,
    Gnss,
    GnssGlitch,
    Imu,
    MagGrade,
    Magnetometer,
    PitotAirspeed,
    PressurePorts,
    TimeWindow,
)
from vdm_aero.geodesy import LocalFrame
from vdm_aero.rotation import dcm_from_quat, quat_from_euler

IMU_RATE_HZ = 400.0
ALLAN_RECORD_S = 300.0  # long enough for τ ≤ 0.5 s to hold thousands of independent clusters
SLOPE_TOL = 0.03  # |fitted log-log slope − (−½)| in the white-noise region
DENSITY_RTOL = 0.10  # the brief's bound on the recovered random-walk coefficient
HOME = LocalFrame(42.283, -71.35, 50.0)


def allan_deviation(rate: np.ndarray, fs_hz: float, clusters: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of a rate record at τ = m/fs for each cluster size m (IEEE Std 952)."""
    theta = np.concatenate(([0.0], np.cumsum(rate))) / fs_hz
    out = np.empty(len(clusters))
    for i, m in enumerate(clusters):
        tau = m / fs_hz
        d = theta[2 * m :] - 2.0 * theta[m:-m] + theta[: -2 * m]
        out[i] = math.sqrt(float(np.mean(d * d)) / (2.0 * tau * tau))
    return out


def _white_region_fit(rate: np.ndarray) -> tuple[float, float]:
    """(log-log slope, median σ(τ)·√τ) of the Allan deviation for τ in [2.5 ms, 0.5 s]."""
    m = np.unique(np.round(np.logspace(0, math.log10(0.5 * IMU_RATE_HZ), 14)).astype(int))
    tau = m / IMU_RATE_HZ
    adev = allan_deviation(rate, IMU_RATE_HZ, m)
    slope = float(np.polyfit(np.log(tau), np.log(adev), 1)[0])
    return slope, float(np.median(adev * np.sqrt(tau)))


@pytest.mark.parametrize("grade", sorted(IMU_GRADES))
def test_imu_allan_deviation_white_noise_matches_the_grade(grade: str) -> None:
    g = IMU_GRADES[grade]
    imu = Imu(g, IMU_RATE_HZ, vibration_multiplier=1.0, rng=np.random.default_rng(42))
    n = int(ALLAN_RECORD_S * IMU_RATE_HZ)
    err = imu.errors(np.zeros(n))
    for axis, density in ((0, g.accel_noise_density_m_s2), (4, g.gyro_noise_density_rad_s)):
        slope, coeff = _white_region_fit(err[:, axis])
        assert abs(slope + 0.5) < SLOPE_TOL, f"{grade} axis {axis}: Allan slope {slope:.3f}, expected -0.5"
        assert coeff == pytest.approx(density, rel=DENSITY_RTOL), (
            f"{grade} axis {axis}: N = {coeff:.3e} vs {density:.3e}"
        )


def test_imu_vibration_multiplies_the_noise_density_with_throttle() -> None:
    g = IMU_GRADES["icm-42688-p"]
    imu = Imu(g, IMU_RATE_HZ, vibration_multiplier=3.0, rng=np.random.default_rng(7))
    err = imu.errors(np.ones(int(100.0 * IMU_RATE_HZ)))  # full throttle: 3× the datasheet density
    _, coeff = _white_region_fit(err[:, 1])
    assert coeff == pytest.approx(3.0 * g.accel_noise_density_m_s2, rel=DENSITY_RTOL)


def test_imu_turn_on_bias_spread_matches_the_grade() -> None:
    g = IMU_GRADES["laupre-2019"]
    biases = np.array([Imu(g, IMU_RATE_HZ, 1.0, np.random.default_rng(s)).turn_on_bias for s in range(400)])
    # 400 draws per axis: the sample σ is within ±7 % (2σ of its own spread) of the true one
    assert np.std(biases[:, :3]) == pytest.approx(g.accel_turn_on_sigma_m_s2, rel=0.07)
    assert np.std(biases[:, 3:]) == pytest.approx(g.gyro_turn_on_sigma_rad_s, rel=0.07)


def test_imu_sample_and_errors_draw_the_same_stream() -> None:
    g = IMU_GRADES["icm-42688-p"]
    a, b = (Imu(g, IMU_RATE_HZ, 2.0, np.random.default_rng(3)) for _ in range(2))
    thr = np.linspace(0.0, 1.0, 10)
    err = b.errors(thr)
    for k, t in enumerate(thr):
        s = a.sample(k / IMU_RATE_HZ, (0.0, 0.0, -9.8), (0.1, 0.0, 0.0), float(t), 20.0)
        np.testing.assert_allclose(s.accel_b_m_s2 - (0.0, 0.0, -9.8), err[k, :3], atol=1e-15)
        np.testing.assert_allclose(s.gyro_b_rad_s - (0.1, 0.0, 0.0), err[k, 3:], atol=1e-15)


def _gnss_run(gnss: Gnss, duration_s: float, tick_hz: float = 400.0) -> list:
    out = []
    period_ticks = round(tick_hz / gnss.grade.rate_hz)
    for k in range(1, round(duration_s * tick_hz) + 1):
        t = k / tick_hz
        if k % period_ticks == 0:
            gnss.measure(t, (100.0, -50.0, -80.0), (15.0, 5.0, 0.0))
        s = gnss.deliver(t)
        if s is not None:
            out.append((t, s))
    return out


def test_gnss_latency_and_scripted_outages() -> None:
    g = GNSS_GRADES["ublox-neo-m9n"]
    outages = (TimeWindow(2.0, 3.5), TimeWindow(6.0, 6.4))
    got = _gnss_run(Gnss(g, HOME, outages, (), np.random.default_rng(1)), 10.0)
    for t_deliver, s in got:
        assert t_deliver - s.t_s == pytest.approx(g.latency_s, abs=1.0 / 400.0)  # one world step
        for w in outages:
            assert not w.contains(s.t_s) and not w.contains(t_deliver), f"fix valid {s.t_s} inside {w}"
    valid = {round(s.t_s, 6) for _, s in got}
    expected = {
        round(k / g.rate_hz, 6)
        for k in range(1, int(10.0 * g.rate_hz) + 1)
        if k / g.rate_hz + g.latency_s <= 10.0
        and not any(w.contains(k / g.rate_hz) or w.contains(k / g.rate_hz + g.latency_s) for w in outages)
    }
    assert valid == expected  # fixes resume right after each window, none are lost elsewhere


def test_gnss_noise_and_glitch_offset() -> None:
    g = GNSS_GRADES["ublox-neo-m9n"]
    glitch = GnssGlitch(TimeWindow(20.0, 30.0), (40.0, -25.0, 0.0))
    got = _gnss_run(Gnss(g, HOME, (), (glitch,), np.random.default_rng(5)), 2000.0, tick_hz=20.0)
    m, _ = HOME.radii_m
    north = np.array([math.radians(s.lat_deg - HOME.lat_deg) * (m + HOME.alt_m) for _, s in got])
    t = np.array([s.t_s for _, s in got])
    inside = (t >= 20.0) & (t < 30.0)
    # the GM error (σ 1.6 m) barely moves in 10 s: the jump is the scripted offset within 1 m
    assert np.mean(north[inside]) - np.mean(north[(t >= 8.0) & (t < 18.0)]) == pytest.approx(40.0, abs=3.0)
    vel = np.array([s.v_ned_m_s for _, s in got])
    # 10,000 white velocity samples: σ within ±3 %
    assert np.std(vel[:, 0] - 15.0) == pytest.approx(g.h_vel_sigma_m_s, rel=0.03)
    assert np.std(vel[:, 2]) == pytest.approx(g.v_vel_sigma_m_s, rel=0.03)


def _noise_free_ports(lag_s: float, resolution_pa: float = 1e-9) -> PressurePorts:
    grade = dataclasses.replace(PORT_GRADES["sdp31"], noise_pa=0.0, offset_sigma_pa=0.0, resolution_pa=resolution_pa)
    return PressurePorts(grade, ("P00", "P01"), 100.0, lag_s, np.random.default_rng(0))


def test_ports_lag_time_constant_is_recovered_from_a_step() -> None:
    tau = 0.035
    ports = _noise_free_ports(tau)
    t = np.arange(200) / 100.0
    x = np.where(t >= 0.5, 120.0, 20.0)
    y = np.array([ports.sample(float(tk), np.array([xk, -xk])).dp_pa for tk, xk in zip(t, x, strict=True)])
    after = (t >= 0.52) & (t <= 0.75)  # one sample past the step (the input is a ramp inside that interval)
    gap = 120.0 - y[after, 0]
    slope = np.polyfit(t[after], np.log(gap), 1)[0]
    assert -1.0 / slope == pytest.approx(tau, rel=0.01)  # exact discretisation: τ recovered to 1 %
    np.testing.assert_allclose(y[:, 1], -y[:, 0])
    assert y[0, 0] == 20.0  # starts settled


def test_ports_quantisation_step_is_visible_and_range_clipped() -> None:
    res = PORT_GRADES["sdp31"].resolution_pa
    ports = _noise_free_ports(0.0, res)
    ramp = np.linspace(0.0, 1.0, 400)  # 1 Pa in 400 samples: many samples per quantisation step
    y = np.array([ports.sample(k / 100.0, np.array([v, 1000.0])).dp_pa for k, v in enumerate(ramp)])
    np.testing.assert_allclose(y[:, 0] / res, np.round(y[:, 0] / res), atol=1e-9)
    steps = np.diff(y[:, 0])
    assert set(np.round(steps[steps != 0.0] / res).astype(int)) == {1}
    assert len(np.unique(y[:, 0])) == pytest.approx(1.0 / res + 1, abs=1)
    assert np.all(y[:, 1] == PORT_GRADES["sdp31"].range_pa)


def test_ports_noise_and_offset_follow_the_grade() -> None:
    g = PORT_GRADES["sdp31"]
    offsets = np.concatenate(
        [
            PressurePorts(g, tuple(f"P{i}" for i in range(20)), 50.0, 0.02, np.random.default_rng(s)).offset_pa
            for s in range(20)
        ]
    )
    assert np.std(offsets) == pytest.approx(g.offset_sigma_pa, rel=0.12)  # 400 draws: ±12 % is 2.4σ
    ports = PressurePorts(g, ("P00",), 50.0, 0.02, np.random.default_rng(9))
    y = np.array([ports.sample(k / 50.0, np.array([50.0])).dp_pa[0] for k in range(5000)])
    assert np.std(y) == pytest.approx(math.hypot(g.noise_pa, g.resolution_pa / math.sqrt(12.0)), rel=0.05)


def test_magnetometer_rotates_the_earth_field_and_adds_hard_iron() -> None:
    field = np.array([20139.0, -4905.0, 46532.0]) * 1e-9
    hard = np.array([2500.0, -1200.0, 4000.0]) * 1e-9
    mag = Magnetometer(MagGrade("ideal", 50.0, 0.0, "test"), field, hard, np.random.default_rng(0))
    dcm = dcm_from_quat(quat_from_euler(0.3, -0.1, 2.0))
    np.testing.assert_allclose(mag.sample(1.0, dcm).field_b_t, dcm.T @ field + hard, atol=1e-15)


def test_pitot_reads_the_dynamic_pressure() -> None:
    g = PITOT_GRADES["ms4525do-001d"]
    pitot = PitotAirspeed(g, np.random.default_rng(4))
    q = 0.5 * 1.2 * 18.0**2
    dp = np.array([pitot.sample(k / 50.0, q, 15.0).dp_pa for k in range(5000)])
    assert np.mean(dp) == pytest.approx(q + pitot.offset_pa, abs=0.1)  # mean of 5000: ±0.05 Pa
    np.testing.assert_allclose(dp / g.resolution_pa, np.round(dp / g.resolution_pa), atol=1e-9)
