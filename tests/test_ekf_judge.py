"""The mock autopilot's judge of GPS_INPUT (sim/sitl/ekf_judge.py): which fixes ArduPilot's EKF3 would use, by its
rules, and the Kalman update of the mock's own estimate error against a hand computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20.ardupilotmega import GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY

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


# ---------------------------------------------------------------------------------------- GPS_AUTO_SWITCH
REAL = dict(real_fix_type=3, real_h_acc_m=1.0, real_speed_acc_m_s=0.25)  # the real receiver, both accuracies
BLENDED = "blended (weight 0.15)"  # GPS_INPUT 3 m / 0.5 m/s: position 0.1, speed 0.2 by inverse variance


def _rules_judge(**rules: int) -> GpsInputJudge:
    return GpsInputJudge(Ekf3GpsRules(**rules), velocity_sigma_m_s=SIG_V, random_walk_m_s_per_sqrt_s=RW)


def _in_outage(j: GpsInputJudge, seconds: float = 10.0) -> None:
    j.outage_started(np.array([0.5, -0.3, 0.0]))
    for _ in range(round(seconds / 0.2)):
        j.propagate(0.2, np.zeros(3))


def _exact(j: GpsInputJudge, **kw: object) -> str:
    """A fix exactly where the estimate already is (no innovation): used whenever it is read."""
    return _fix(j, (float(j.p_err_m[0]), float(j.p_err_m[1])), vel_error_ne_m_s=j.v_err_m_s.copy(), **kw)


def test_an_unknown_auto_switch_is_refused() -> None:
    with pytest.raises(ValueError, match="GPS_AUTO_SWITCH 5"):
        Ekf3GpsRules(auto_switch=5)


def test_auto_switch_0_reads_gps_primary_only_and_3_is_the_second_instance() -> None:
    """0: GPS_PRIMARY (default the real receiver) always, outage or not: the MAV instance is never fused. 3 is
    converted at boot to 0 with GPS_PRIMARY 1: the MAV instance always, even with no fix."""
    j = _rules_judge(auto_switch=0)
    _in_outage(j)
    before = j.p_err_m.copy()
    assert _fix(j, (0.0, 0.0)) == "not primary (GPS_AUTO_SWITCH 0: GPS_PRIMARY always)"
    np.testing.assert_array_equal(j.p_err_m, before)
    for rules in ({"auto_switch": 0, "primary": 1}, {"auto_switch": 3}):
        k = _rules_judge(**rules)
        _in_outage(k)
        assert _exact(k) == "used", rules
        assert _exact(k, fix_type=1) == "no fix (readGpsData reads 3-D only)", rules
        assert _exact(k, real_fix_type=3) == "used", rules  # a real fix changes nothing: no switching


def test_auto_switch_4_keeps_gps_primary_while_it_has_a_3d_fix() -> None:
    j = _rules_judge(auto_switch=4)
    _in_outage(j)
    assert _exact(j) == "used"  # GPS_PRIMARY (the real receiver) has no fix: use best
    k = _rules_judge(auto_switch=4)  # no outage: the real receiver has its 3-D fix
    assert _exact(k, real_fix_type=3) == "not primary (GPS_AUTO_SWITCH 4: GPS_PRIMARY has a 3-D fix)"
    m = _rules_judge(auto_switch=4, primary=1)  # the MAV instance preferred: read beside a healthy receiver ...
    assert _exact(m, real_fix_type=3) == "primary outside an outage (not fused: the estimate follows GNSS)"
    assert _exact(m, real_fix_type=3, fix_type=2) == "2-D fix (readGpsData reads 3-D only)"  # ... at 3-D only
    assert not m.outage_verdicts and sum(m.verdicts.values()) == 2


def test_blending_in_an_outage_is_the_mav_instance_alone() -> None:
    """The real receiver has no fix: _calc_weights fails, update_primary falls back to use best. The same drift
    and fixes give GPS_AUTO_SWITCH 2 exactly the verdicts and the estimate of 1."""
    judges = [_rules_judge(auto_switch=1), _rules_judge(auto_switch=2)]
    rng = np.random.default_rng(11)
    dvs = RW * math.sqrt(0.2) * rng.standard_normal((300, 3))
    fixes = [(2.0 * rng.standard_normal(2), 0.3 * rng.standard_normal(2), int(rng.integers(1, 4))) for _ in dvs]
    real = REAL | {"real_fix_type": 1}  # no fix, its accuracies still reported
    for j in judges:
        j.outage_started(np.array([0.8, -0.6, 0.0]))
        for k, (dv, (e_p, e_v, fix)) in enumerate(zip(dvs, fixes, strict=True)):
            j.propagate(0.2, dv)
            _fix(j, tuple(e_p), vel_error_ne_m_s=e_v, fix_type=fix, h_acc_m=4.0, t_s=0.2 * k, **real)
    best, blend = judges
    assert blend.verdicts == best.verdicts and blend.outage_verdicts == blend.verdicts
    assert blend.verdicts["used"] > 50 and blend.verdicts["2-D fix (readGpsData reads 3-D only)"] > 50
    assert not any(v.startswith(("blended", "not blended")) for v in blend.verdicts)
    np.testing.assert_array_equal(blend.p_err_m, best.p_err_m)
    assert blend.blend_health == 100


def test_blended_outside_an_outage_by_inverse_variance_counted_not_fused() -> None:
    """Both with 3-D fixes: EKF3 reads the blended instance. GPS_BLEND_MASK 5 averages the position weight
    (1/3²)/(1/3² + 1/1²) = 0.1 and the speed weight (1/0.5²)/(1/0.5² + 1/0.25²) = 0.2."""
    j = _rules_judge(auto_switch=2)
    assert _fix(j, (20.0, 0.0), speed_acc_m_s=0.5, **REAL) == BLENDED
    np.testing.assert_array_equal(j.p_err_m, np.zeros(2))  # not fused: the estimate follows GNSS here
    assert j.verdicts == {BLENDED: 1} and not j.outage_verdicts
    # vertical (bit 1) 4 m against 2 m: 0.2 alone; all three: (0.1 + 0.2 + 0.2) / 3
    for mask, weight in ((1, 0.10), (4, 0.20), (2, 0.20), (7, 0.17)):
        k = _rules_judge(auto_switch=2, blend_mask=mask)
        v = _fix(k, (0.0, 0.0), speed_acc_m_s=0.5, v_acc_m=4.0, real_v_acc_m=2.0, **REAL)
        assert v == f"blended (weight {weight:.2f})", mask
    # the default real receiver outside an outage (no accuracies given): nothing to weigh
    assert _fix(_rules_judge(auto_switch=2), (0.0, 0.0)) == (
        "not blended (no accuracy to weigh by GPS_BLEND_MASK): the real receiver is primary"
    )


def test_blend_metrics_need_both_receivers_and_the_weights_need_fresh_finite_fixes() -> None:
    """A metric one receiver taking part does not report is dropped; speed and vertical weigh 3-D fixes only
    (a 2-D GPS_INPUT weighs by position alone); infinite accuracies or fixes ≥ 0.4 s apart stop blending."""

    def verdict(**kw: object) -> str:
        return _fix(_rules_judge(auto_switch=2), (0.0, 0.0), speed_acc_m_s=0.5, **REAL | kw)

    assert verdict(real_speed_acc_m_s=None) == "blended (weight 0.10)"  # position only
    assert verdict(ignore_flags=GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY) == "blended (weight 0.10)"
    assert verdict(fix_type=2) == "blended (weight 0.05)"  # position 0.1; speed: the real receiver alone (0)
    assert verdict(real_fix_type=2) == "blended (weight 0.55)"  # position 0.1; speed: the MAV instance alone (1)
    stop = "not blended ({}): the real receiver is primary"
    assert verdict(real_h_acc_m=None, real_speed_acc_m_s=None) == stop.format("no accuracy to weigh by GPS_BLEND_MASK")
    assert verdict(h_acc_m=math.inf) == stop.format("an accuracy is infinite")
    assert verdict(real_age_s=0.4) == stop.format("their last fixes ≥ 0.4 s apart")
    assert verdict(real_age_s=0.39) == BLENDED
    # the real receiver without a fix outside an outage: no blending, use best makes the MAV instance primary
    assert verdict(real_fix_type=1) == "primary outside an outage (not fused: the estimate follows GNSS)"


def test_blending_resumes_only_as_the_health_counter_decays_after_an_outage() -> None:
    """The outage saturates calc_weights' counter (100); at 5 Hz each GPS_INPUT brings 10 good 50 Hz updates
    (−1 each): blending (counter < 50) resumes with the 6th. At 1 Hz the MAV instance's data is ≥ 0.4 s old for
    30 of each 50 updates (+10 each): never."""
    for hz, first_blended in ((5.0, 6), (1.0, None)):
        j = _rules_judge(auto_switch=2)
        _in_outage(j, 5.0)
        t = 0.0
        for _ in range(5):
            t += 1.0 / hz
            assert _exact(j, t_s=t, real_fix_type=1) == "used"
        j.outage_ended(np.zeros(3))
        seen = []
        for _ in range(20):
            t += 1.0 / hz
            seen.append(_fix(j, (0.0, 0.0), speed_acc_m_s=0.5, t_s=t, **REAL))
        off = "not blended (health counter ≥ 50): the real receiver is primary"
        n = first_blended or len(seen) + 1
        assert seen == [off] * (n - 1) + [BLENDED] * (len(seen) - n + 1), (hz, seen)
    quiet = _rules_judge(auto_switch=2)  # no GPS_INPUT in the outage: the fix's loss alone saturated the counter
    _in_outage(quiet)
    quiet.outage_ended(np.zeros(3))
    assert _fix(quiet, (0.0, 0.0), speed_acc_m_s=0.5, t_s=100.0, **REAL).startswith("not blended (health counter")
    assert quiet.blend_health == 99
    settled = _rules_judge(auto_switch=2)  # without t_s the counter is taken as settled
    _in_outage(settled)
    settled.outage_ended(np.zeros(3))
    assert _fix(settled, (0.0, 0.0), speed_acc_m_s=0.5, **REAL) == BLENDED


# ---------------------------------------------------------------------------------------- calcGpsGoodForFlight
def test_speed_accuracy_check_is_tracked_with_its_hysteresis_but_never_blocks_fusion() -> None:
    """calcGpsGoodForFlight's gpsSpdAccPass: low-pass s1 += 0.2 (raw − s1) per read, peak hold
    s2 = max(s1, s2 (1 − dt/10 s)), false above 1.5 m/s, true again below 1.0. At 5 Hz with 2 m/s:
    s1 = 2 (1 − 0.8^k), > 1.5 first at k = 7 (1.58; k = 6: 1.48); after 10 reads s2 = 1.785. Then 0.5 m/s: s1 falls
    fast, s2 = 1.785 · 0.98^j stays in the hysteresis band until j = 28 (1.014) and passes at j = 29 (0.994). No
    fusion decision reads it: all "used"."""
    j = _judge()
    _in_outage(j)
    t = 0.0
    seen = []
    for _ in range(10):
        t += 0.2
        assert _exact(j, speed_acc_m_s=2.0, t_s=t) == "used"
        seen.append(j.spd_acc_pass)
    assert seen == [True] * 6 + [False] * 4
    np.testing.assert_allclose(j.sacc_peak_m_s, 2.0 * (1.0 - 0.8**10), rtol=1e-12)
    seen = []
    for _ in range(30):
        t += 0.2
        assert _exact(j, speed_acc_m_s=0.5, t_s=t) == "used"
        seen.append(j.spd_acc_pass)
    assert seen == [False] * 28 + [True] * 2
    assert j.spd_acc_fail_reads == 4 + 28 and j.verdicts == {"used": 40}


def test_speed_accuracy_check_settled_reads_only_what_ekf3_reads() -> None:
    """Without t_s the filters are taken as settled at each read: 1.2 m/s keeps whichever state it finds (the band
    between 1.0 and 1.5). Only reads count: not a 2-D fix, not the MAV instance behind a primary real receiver; an
    ignored speed accuracy reads as 0; a new outage starts passing."""
    j = _judge()
    _in_outage(j)
    states = []
    for acc in (1.2, 2.0, 1.2, 0.9):
        _exact(j, speed_acc_m_s=acc)
        states.append(j.spd_acc_pass)
    assert states == [True, False, False, True]
    _exact(j, speed_acc_m_s=3.0, fix_type=2)  # readGpsData reads 3-D only
    assert j.spd_acc_pass and j.sacc_peak_m_s == 0.9
    _exact(j, speed_acc_m_s=3.0, ignore_flags=GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY)
    assert j.spd_acc_pass and j.sacc_peak_m_s == 0.0
    _exact(j, speed_acc_m_s=math.inf)  # held at 10
    assert not j.spd_acc_pass and j.sacc_peak_m_s == 10.0
    j.outage_ended(np.zeros(3))
    assert _exact(j, speed_acc_m_s=3.0, real_fix_type=3) == "GNSS healthy (the real receiver is primary)"
    assert j.sacc_peak_m_s == 10.0 and j.spd_acc_fail_reads == 3  # 2.0, 1.2 and inf
    _in_outage(j)
    assert j.spd_acc_pass and j.sacc_peak_m_s == 0.0


# ---------------------------------------------------------------------------------------- FuseVelPosNED's tests
def _fresh_outage(seconds: float) -> GpsInputJudge:
    """An outage ``seconds`` old, no random walk: P_pos = σv²·t² per axis, P_vel = σv²."""
    j = GpsInputJudge(Ekf3GpsRules(), velocity_sigma_m_s=SIG_V, random_walk_m_s_per_sqrt_s=0.0)
    j.outage_started(np.zeros(3))
    for _ in range(round(seconds / 0.1)):
        j.propagate(0.1, np.zeros(3))
    return j


def test_the_position_gate_is_one_ratio_over_both_axes_before_the_noise_scaler() -> None:
    """10 s in, P_pos = 9 m² per axis; a 3 m fix: σ² = 9 + 9 per axis. 5.5σ on north and nothing on east fails a
    per-axis 5σ test but passes FuseVelPosNED's ratio over both axes (30.25 / 50); 7.5σ on north fails that too
    (56.25 / 50). With the scaler of 2 in the gate (R = 36) the second would have passed."""
    sig = math.sqrt(9.0 + 9.0)
    assert _fix(_fresh_outage(10.0), (5.5 * sig, 0.0), h_acc_m=3.0) == "used"
    j = _fresh_outage(10.0)
    assert _fix(j, (7.5 * sig, 0.0), h_acc_m=3.0) == "used (velocity only)"
    assert j.p_err_m == pytest.approx([0.0, 0.0])


def test_the_velocity_gate_takes_ek3_velne_m_nse_not_the_reported_speed_accuracy() -> None:
    """A fix 100 m off (its position gated) claiming 5 m/s speed accuracy with 2.5 m/s velocity errors on both axes:
    within 5σ of its own accuracy, but FuseVelPosNED checks the velocity against EK3_VELNE_M_NSE (0.3 m/s) and P_vel
    (0.09 m²/s²): 12.5 / (25 · 2 · 0.18) > 1, refused too. At 1.2 m/s on one axis (1.44 / 9 < 1) its velocity is
    used."""
    far = (100.0, 0.0)
    bad_v = np.array([2.5, 2.5])
    assert _fix(_fresh_outage(10.0), far, speed_acc_m_s=5.0, vel_error_ne_m_s=bad_v) == "gated (innovation > 5σ)"
    ok_v = np.array([1.2, 0.0])
    assert _fix(_fresh_outage(10.0), far, speed_acc_m_s=5.0, vel_error_ne_m_s=ok_v) == "used (velocity only)"


def test_a_fix_after_a_long_silence_resets_onto_itself_beyond_the_glitch_radius() -> None:
    """60 s without fixes: P_NN + P_EE = 2·(0.3·60)² = 648 m² > EK3_GLITCH_RAD² (625): a passing fix resets the position
    onto itself (ResetPosition), P = 12.5² per axis, and is not fused."""
    j = _fresh_outage(60.0)
    e = (4.0, -3.0)
    assert _fix(j, e, h_acc_m=3.0) == "reset (position variance beyond EK3_GLITCH_RAD)"
    np.testing.assert_allclose(j.p_err_m, e)
    np.testing.assert_allclose(j.P[:, 0, 0], 12.5**2)
    assert _fix(_fresh_outage(58.0), e, h_acc_m=3.0) == "used"  # 2·17.4² = 606 m²: fused
