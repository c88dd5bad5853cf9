"""The wind's gradient with height (issue 22, "the wind through an outage"): the product mode carries the mean
wind's change with height as states, learns it while GNSS aids a climb, and lets the held wind follow a descent
in the outage. Checked on a seeded synthetic flight through a linear gradient, against the analytic wind, and
against the same flight without the states (the ablation ``vdm-no-gradient``, EKF3's WIND_PSCALE instead)."""

from __future__ import annotations

import math

import numpy as np

from vdm_aero.atmosphere import G0_M_S2, density_kg_m3
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.filter import NavConfig, NavFilter
from vdm_aero.nav.ins import InsProcess
from vdm_aero.nav.state import NavState
from vdm_aero.rotation import dcm_from_quat, quat_from_euler
from vdm_aero.vehicle import load_vehicle

MAG_NED_UT = np.array([20.1, -4.9, 46.5])
RATE_HZ = 50.0
AIRSPEED_M_S = 18.0
W0_NE_M_S = np.array([-4.0, 3.0])  # the wind at 100 m
G_NE_PER_S = np.array([0.012, -0.008])  # its change per metre of height: a power law's 0.2 exponent at ~10 m/s
CLIMB_M_S = 3.0
# (end time [s], height rate [m/s]): level, climb 100 → 280 m with GNSS, level, lost; descend back to 100 m, level
LEGS = ((30.0, 0.0), (90.0, CLIMB_M_S), (150.0, 0.0), (210.0, -CLIMB_M_S), (240.0, 0.0))
GNSS_LOST_S = 150.0


def test_a_held_wind_follows_its_gradient_through_a_descent() -> None:
    """The process alone: with the gradient G, the wind changes by G·Δh as the height changes (the analytic
    integral of ẇ = −G·v_D), and not at all without one."""
    ins = InsProcess()
    x = NavState(np.array([0.0, 0.0, -280.0]), np.array([18.0, 0.0, 3.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    x.wind_ned = np.array([-4.0, 3.0, 0.0])
    x.wind_gradient_ne_per_s = G_NE_PER_S.copy()
    flat = x.copy()
    flat.wind_gradient_ne_per_s = np.zeros(2)
    dt = 0.02
    u = ImuIncrement(np.zeros(3), np.array([0.0, 0.0, -G0_M_S2]) * dt, dt)  # level, unaccelerated: v_D stays 3
    for _ in range(3000):  # 60 s: 180 m down
        ins.propagate_inplace(x, u)
        ins.propagate_inplace(flat, u)
    dh = -(x.p_ned[2] + 280.0)  # the height changed [m]
    assert math.isclose(dh, -180.0, rel_tol=1e-9)
    np.testing.assert_allclose(x.wind_ned[:2], np.array([-4.0, 3.0]) + G_NE_PER_S * dh, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(flat.wind_ned, np.array([-4.0, 3.0, 0.0]))


def _height(t: float) -> tuple[float, float, float]:
    """Height [m], its rate [m/s] and ∫(h − 100 m) dt from 0 to t [m·s], leg by leg (piecewise linear height)."""
    h, t0, area = 100.0, 0.0, 0.0
    for t1, rate in LEGS:
        span = min(t, t1) - t0
        area += (h - 100.0) * span + 0.5 * rate * span * span
        if t <= t1:
            return h + rate * span, rate, area
        h += rate * span
        t0 = t1
    return h, 0.0, area + (h - 100.0) * (t - t0)


def _wind_ne(h: float) -> np.ndarray:
    return W0_NE_M_S + G_NE_PER_S * (h - 100.0)


def _truth(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flying north at a constant air velocity through the gradient, level and heading north: position,
    velocity, specific force (NED). Ground velocity = air velocity + the wind at the height, so the aircraft
    accelerates by G·ḣ while it climbs or descends (and steps its vertical speed between legs)."""
    h, rate, area = _height(t)
    w = _wind_ne(h)
    v = np.array([AIRSPEED_M_S + w[0], w[1], -rate])
    p = np.array([AIRSPEED_M_S * t + W0_NE_M_S[0] * t + G_NE_PER_S[0] * area, W0_NE_M_S[1] * t + G_NE_PER_S[1] * area,
                  -h])  # fmt: skip
    a = np.zeros(3)
    a[:2] = G_NE_PER_S * rate
    return p, v, a - np.array([0.0, 0.0, G0_M_S2])


def _fly(mode: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """One flight: the gradient learnt when GNSS is lost [1/s], the wind's change the filter carried from then to
    the end (mean and gust, NE) [m/s], the position error at the end [m]."""
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=0.0, mag_field_ned_ut=MAG_NED_UT)
    f = NavFilter(mode, cfg)
    c_bn = dcm_from_quat(np.array(quat_from_euler(0.0, 0.0, 0.0))).T
    p, v, f_n = _truth(0.0)
    f.initialise(0.0, p, v, f_n, c_bn @ MAG_NED_UT)  # the heading from the compass, as the service starts
    dt = 1.0 / RATE_HZ
    end = LEGS[-1][0]
    for k in range(1, round(end * RATE_HZ) + 1):
        t = k * dt
        # the velocity increment less gravity's: also the steps of the height rate between legs
        dv_n = _truth(t)[1] - _truth(t - dt)[1] - np.array([0.0, 0.0, G0_M_S2]) * dt
        f.imu(t, ImuIncrement(rng.normal(0.0, 1e-4, 3), c_bn @ dv_n + rng.normal(0.0, 1e-3, 3), dt))
        if k == round(GNSS_LOST_S * RATE_HZ):
            assert f.x is not None
            g_learnt, w_lost = f.x.wind_gradient_ne_per_s.copy(), f.x.wind_ned[:2] + f.x.gust_ned[:2]
        if k % 10 == 0:
            p, v, _ = _truth(t)
            if t < GNSS_LOST_S:
                f.gnss(t, t, p + rng.normal(0.0, 0.5, 3), v + rng.normal(0.0, 0.1, 3), math.nan, math.nan)
            h = -p[2]
            f.baro(t, float(101325.0 * (1.0 - 2.25577e-5 * (h + rng.normal(0.0, 0.5))) ** 5.25588))
            rho = float(density_kg_m3(float(101325.0 * (1.0 - 2.25577e-5 * h) ** 5.25588), f.inputs.temperature_k))
            w = _wind_ne(h)
            tas = float(np.linalg.norm(v - np.array([w[0], w[1], 0.0])))
            f.pitot(t, 0.5 * rho * (tas + rng.normal(0.0, 0.3)) ** 2)
            f.mag(t, c_bn @ MAG_NED_UT + rng.normal(0.0, 0.5, 3))
    assert f.x is not None and f.in_outage
    shown = f.health()["wind_gradient_m_s_per_100m"]  # what the service's status and log show
    assert (
        shown is None if mode == "vdm-no-gradient" else shown == [round(100 * g, 2) for g in f.x.wind_gradient_ne_per_s]
    )
    change = f.x.wind_ned[:2] + f.x.gust_ned[:2] - w_lost
    return g_learnt, change, float(np.linalg.norm(f.x.p_ned[:2] - _truth(end)[0][:2]))


def test_the_product_mode_learns_the_gradient_in_a_climb_and_follows_it_down_in_the_outage() -> None:
    """Aided through a 180 m climb, then a 180 m descent without GNSS (a straight track: the crosswind rests on
    the compass's heading, so the gradient's cross component is learnt least well). The product mode learns the
    gradient to within half of it, carries the wind's change down the descent to within half of the change, and
    ends nearer than the ablation, which holds the wind of the top (its error is most of the change)."""
    rng = np.random.default_rng(20261128)
    g, change, pos = _fly("vdm", rng)
    _, change_off, pos_off = _fly("vdm-no-gradient", np.random.default_rng(20261128))
    truth_change = _wind_ne(100.0) - _wind_ne(280.0)
    size = float(np.linalg.norm(truth_change))
    assert float(np.linalg.norm(g - G_NE_PER_S)) < 0.5 * float(np.linalg.norm(G_NE_PER_S)), g
    assert float(np.linalg.norm(change - truth_change)) < 0.5 * size, (change, truth_change)
    assert float(np.linalg.norm(change_off - truth_change)) > 0.6 * size, (change_off, truth_change)
    assert pos < 0.5 * pos_off, (pos, pos_off)
