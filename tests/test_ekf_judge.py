"""The mock autopilot's judge of GPS_INPUT (sim/sitl/ekf_judge.py): which fixes ArduPilot's EKF3 would use, by its
rules, and the Kalman update of the mock's own estimate error against a hand computation."""

from __future__ import annotations

import math

import numpy as np

from sim.sitl.ekf_judge import Ekf3GpsRules, GpsInputJudge

SIG_V, RW = 0.3, 0.02  # DeadReckoningDrift's defaults


def _judge() -> GpsInputJudge:
    return GpsInputJudge(Ekf3GpsRules(), velocity_sigma_m_s=SIG_V, random_walk_m_s_per_sqrt_s=RW)


def _fix(j: GpsInputJudge, e_p: tuple[float, float], **kw: object) -> str:
    args: dict[str, object] = dict(gps_id=1, fix_type=3, satellites=0, ignore_flags=0, h_acc_m=3.0,
                                   fix_error_ne_m=np.array(e_p), vel_error_ne_m_s=np.zeros(2), speed_acc_m_s=0.5,
                                   airspeed_aiding=True)  # fmt: skip
    args.update(kw)
    return j.gps_input(**args)  # type: ignore[arg-type]


def test_the_rules_refuse_what_arduplane_would_not_read() -> None:
    j = _judge()
    j.outage_started(np.zeros(3))
    assert _fix(j, (0.0, 0.0), fix_type=2) == "2-D fix (readGpsData reads 3-D only)"
    assert _fix(j, (0.0, 0.0), fix_type=1) == "no fix (not primary)"
    assert _fix(j, (0.0, 0.0), gps_id=0) == "not the MAV instance (gps_id)"
    assert _fix(j, (0.0, 0.0), airspeed_aiding=False) == "AID_NONE: gpsGoodToAlign fails (satellites < 6)"
    assert _fix(j, (0.0, 0.0)) == "used"
    assert j.verdicts["used"] == 1 and sum(j.verdicts.values()) == 5


def test_one_fix_against_a_hand_computed_kalman_update() -> None:
    """No random walk: after t s the position variance is σv²·t². A fix with error e and accuracy a is fused
    with R = (2a)² (0 satellites: gpsNoiseScaler 2): the error becomes p + K(e − p), K = P/(P + R)."""
    j = GpsInputJudge(Ekf3GpsRules(), velocity_sigma_m_s=SIG_V, random_walk_m_s_per_sqrt_s=0.0)
    v0 = np.array([0.3, -0.2, 0.0])
    j.outage_started(v0)
    t, dt = 10.0, 0.1
    for _ in range(round(t / dt)):
        j.propagate(dt, np.zeros(3))
    p = v0[:2] * t  # (3, -2) m
    np.testing.assert_allclose(j.p_err_m, p, atol=1e-9)
    a = 1.0
    e = np.array([0.5, 0.5])
    assert _fix(j, tuple(e), h_acc_m=a, vel_error_ne_m_s=j.v_err_m_s.copy()) == "used"  # velocity: no innovation
    # the velocity update (zero innovation) first shrinks P; recompute by hand: prior P = σv²[[t², t], [t, 1]]
    prior = SIG_V**2 * np.array([[t * t, t], [t, 1.0]])
    rv = (2.0 * 0.5) ** 2  # speed accuracy 0.5 m/s, scaler 2
    kv = prior[:, 1] / (prior[1, 1] + rv)
    after_v = prior - np.outer(kv, prior[1, :])
    k = after_v[0, 0] / (after_v[0, 0] + (2.0 * a) ** 2)
    np.testing.assert_allclose(j.p_err_m, p + k * (e - p), rtol=1e-9)


def test_a_fix_that_understates_its_error_is_gated_and_honest_fixes_help() -> None:
    """A fix 50 m off claiming 1 m is beyond 5σ of a fresh estimate: gated. Fixes whose errors are as large as
    they say (σ = a/2 per axis, a = 4 m) bring the estimate's error at the end under the free drift's."""
    rng = np.random.default_rng(3)
    j = _judge()
    j.outage_started(np.array([0.8, -0.6, 0.0]))
    free = np.zeros(2)
    v_free = np.array([0.8, -0.6])
    for k in range(600):  # 120 s at 5 Hz
        dv = RW * math.sqrt(0.2) * rng.standard_normal(3)
        j.propagate(0.2, dv)
        v_free = v_free + dv[:2]
        free = free + v_free * 0.2
        if k == 10:  # position gated (its velocity, exact here, is still taken)
            before = j.p_err_m.copy()
            assert _fix(j, (50.0, 0.0), h_acc_m=1.0, vel_error_ne_m_s=j.v_err_m_s.copy()) == "used (velocity only)"
            np.testing.assert_allclose(j.p_err_m, before, atol=0.05)
            assert _fix(j, (50.0, 0.0), h_acc_m=1.0, vel_error_ne_m_s=j.v_err_m_s + 20.0) == "gated (innovation > 5σ)"
        elif k > 10:
            _fix(j, tuple(2.0 * rng.standard_normal(2)), h_acc_m=4.0, vel_error_ne_m_s=0.3 * rng.standard_normal(2))
    assert np.hypot(*free) > 50.0  # the drift alone: ~1 m/s for 120 s
    assert np.hypot(*j.p_err_m) < 5.0
    j.outage_ended(np.array([*free, 0.0]))
    (end,) = j.outage_end
    assert end["with_service_m"] < 5.0 < 50.0 < end["without_m"]
