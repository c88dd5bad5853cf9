"""The mock autopilot's PX4 judge (sim/sitl/ekf2_judge.py): which of the companion's GPS_INPUT, ODOMETRY and
GLOBAL_POSITION_SENSOR PX4's EKF2 would fuse in a GNSS outage, by the rules read from PX4's sources, and what that
does to the mock's own estimate error. Each test is named after the rule it checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.sitl.ekf2_judge import Ekf2Judge, Ekf2Rules
from sim.sitl.ekf_judge import Ekf3GpsRules, GpsInputJudge
from vdm_aero.rotation import dcm_from_quat

V0 = (0.5, -0.3)  # the drift's velocity error at the outage's start [m/s]
OFFSET = np.array([100.0, -50.0])  # the service's local origin minus the mock's [m]
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
YAW90 = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])  # body x east
WAITING = "waiting to start (< 200 ms after the last sample)"


def _judge(**rules: object) -> tuple[GpsInputJudge, Ekf2Judge]:
    state = GpsInputJudge(Ekf3GpsRules(), velocity_sigma_m_s=0.3, random_walk_m_s_per_sqrt_s=0.0)
    return state, Ekf2Judge(Ekf2Rules(**rules), state)  # type: ignore[arg-type]


def _cov(var: float) -> np.ndarray:
    c = np.full(21, np.nan)
    c[[0, 6, 11]] = var
    return c


def _truth(t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle flying east at 30 m/s."""
    return np.array([5.0, 30.0 * t_s, -100.0]), np.array([0.0, 30.0, 0.0])


def _odo(j: Ekf2Judge, t_s: float, *, outage: bool, e_p: tuple[float, float] = (0.0, 0.0),
         e_v: tuple[float, float] = (0.0, 0.0), q: np.ndarray = YAW90, pos_var: float = 1.0,
         **kw: object) -> str:  # fmt: skip
    """An ODOMETRY as firmware_bridge.outputs.odometry sends it: the pose in the service's LOCAL_NED frame (the
    mock's shifted by OFFSET) plus ``e_p``, the body FRD velocity (truth plus ``e_v``) rotated by ``q``."""
    p, v = _truth(t_s)
    v_ned = v + np.array([*e_v, 0.0])
    v_body = dcm_from_quat(q).T @ v_ned
    args: dict[str, object] = dict(t_s=t_s, frame_id=mavlink2.MAV_FRAME_LOCAL_NED,
                                   child_frame_id=mavlink2.MAV_FRAME_BODY_FRD,
                                   pos_m=p + np.array([*(OFFSET + np.array(e_p)), 0.0]), q=q, vel_m_s=v_body,
                                   pose_covariance=_cov(pos_var), velocity_covariance=_cov(0.25), reset_counter=0,
                                   quality=80, truth_pos_ned_m=p, truth_v_ned_m_s=v, gnss_outage=outage)  # fmt: skip
    args.update(kw)
    return j.odometry(**args)  # type: ignore[arg-type]


def _fly(state: GpsInputJudge, j: Ekf2Judge, t0: float, t1: float, *, dt: float = 0.1, outage: bool = True,
         send: bool = True, **kw: object) -> list[str]:  # fmt: skip
    """From ``t0`` to ``t1``: the drift propagated (in an outage), an ODOMETRY every ``dt`` (if ``send``)."""
    out = []
    for k in range(1, round((t1 - t0) / dt) + 1):
        if outage:
            state.propagate(dt, np.zeros(3))
        if send:
            out.append(_odo(j, t0 + k * dt, outage=outage, **kw))  # type: ignore[arg-type]
    return out


def _outage(state: GpsInputJudge, j: Ekf2Judge, t_s: float) -> None:
    state.outage_started(np.array([*V0, 0.0]))
    j.outage_started(t_s)


# ------------------------------------------------------------------------------------ GPS_INPUT, 296
@pytest.mark.parametrize("satellites", [0, 12])
def test_gps_input_has_no_handler_in_mavlink_receiver(satellites: int) -> None:
    """No case for GPS_INPUT in MavlinkReceiver::handle_message: not even a perfect 3-D fix reaches EKF2."""
    state, j = _judge()
    _outage(state, j, 0.0)
    for k in range(300):  # 60 s at 5 Hz, far beyond the 10 s of passing checks
        state.propagate(0.2, np.zeros(3))
        j.gps_input(t_s=0.2 * k, fix_type=mavlink2.GPS_FIX_TYPE_3D_FIX, satellites=satellites, hdop=0.7, vdop=1.0,
                    h_acc_m=0.5, v_acc_m=0.8, speed_acc_m_s=0.1, ignore_flags=0, fix_error_ne_m=np.zeros(2),
                    vel_error_ne_m_s=np.zeros(2), gnss_outage=True)  # fmt: skip
    assert j.verdicts["GPS_INPUT"] == {"PX4 v1.16: no handler for message 232": 300}
    assert j.outage_verdicts["GPS_INPUT"]["PX4 v1.16: no handler for message 232"] == 300
    assert state.p_err_m == pytest.approx(np.array(V0) * 60.0)  # the free drift: nothing fused


def test_global_position_sensor_has_no_handler_in_v1_16() -> None:
    state, j = _judge()
    _outage(state, j, 0.0)
    state.propagate(10.0, np.zeros(3))
    v = j.global_position_sensor(t_s=10.0, fix_error_ne_m=np.zeros(2), eph_m=1.0, epv_m=2.0, flags=0, gnss_outage=True)
    assert v == "PX4 v1.16: no handler for message 296"
    assert state.p_err_m == pytest.approx(np.array(V0) * 10.0)


def test_aux_global_position_on_main_fuses_its_slot_id_only() -> None:
    """agp_handler (main, PR #26307): EKF2_AGP0_ID selects the message id; noise max(eph, EKF2_AGP_NOISE); one
    Kalman update of the position error, checked by hand."""
    state, j = _judge(agp_handler=True)
    _outage(state, j, 0.0)
    state.propagate(8.0, np.zeros(3))
    kw = dict(fix_error_ne_m=np.array([0.2, -0.1]), eph_m=3.0, epv_m=5.0, flags=0, gnss_outage=True)
    assert j.global_position_sensor(t_s=8.0, **kw) == "id is no enabled EKF2_AGPn_ID slot"  # type: ignore[arg-type]
    p, pp = state.p_err_m.copy(), state.P[:, 0, 0].copy()
    assert j.global_position_sensor(t_s=8.0, sensor_id=1, **kw) == "used"  # type: ignore[arg-type]
    assert state.p_err_m == pytest.approx(p + pp / (pp + 9.0) * (np.array([0.2, -0.1]) - p))


# ------------------------------------------------------------------------------------ ODOMETRY: the receiver
def test_odometry_in_an_unknown_frame_is_not_used() -> None:
    state, j = _judge()
    _outage(state, j, 0.0)
    v = _fly(state, j, 0.0, 10.0, frame_id=mavlink2.MAV_FRAME_GLOBAL, child_frame_id=mavlink2.MAV_FRAME_GLOBAL)
    assert set(v) == {"no valid pose or velocity frame"}
    assert state.p_err_m == pytest.approx(np.array(V0) * 10.0)


def test_odometry_from_a_gps_estimator_is_not_published() -> None:
    _, j = _judge()
    v = _odo(j, 1.0, outage=True, estimator_type=mavlink2.MAV_ESTIMATOR_TYPE_GPS)
    assert v == "estimator_type not VISION/VIO (not published)"


# ------------------------------------------------------------------------------------ ODOMETRY: EKF2's rules
def test_quality_below_ev_qmin_is_never_used() -> None:
    """Quality 80 with EKF2_EV_QMIN = 90: nothing starts (and at the default, 1, a failed solution's −1 is refused)."""
    state, j = _judge(ev_qmin=90)
    _outage(state, j, 0.0)
    assert set(_fly(state, j, 0.0, 20.0)) == {"quality below EKF2_EV_QMIN"}
    assert state.p_err_m == pytest.approx(np.array(V0) * 20.0)
    state, j = _judge()
    _outage(state, j, 0.0)
    assert set(_fly(state, j, 0.0, 5.0, quality=-1)) == {"quality below EKF2_EV_QMIN"}


@pytest.mark.parametrize(("dt", "starts"), [(0.2, False), (0.19, True)])
def test_fusion_starts_only_under_ev_max_interval(dt: float, starts: bool) -> None:
    """controlExternalVisionFusion: (t − t_prev) < EV_MAX_INTERVAL (200 ms), strictly: at 5 Hz EV never starts."""
    state, j = _judge()
    _outage(state, j, 0.0)
    v = _fly(state, j, 0.0, 19.0, dt=dt)
    assert v[0] == WAITING
    if starts:
        assert v[1] == "started" and v.count("used") == len(v) - 3  # and the reset 7 s after the loss
    else:
        assert set(v) == {WAITING}
        assert state.p_err_m == pytest.approx(np.array(V0) * 19.0)


def test_origin_offset_learnt_with_gnss_carries_into_the_outage() -> None:
    """_ev_pos_b_est learns the service's origin offset while GNSS is fused; when GNSS stops (7 s after the loss)
    the bias turning off resets the position to EV − bias, and exact ODOMETRY then holds the error near zero."""
    state, j = _judge()
    assert set(_fly(state, j, 0.0, 5.0, outage=False)) == {"GNSS healthy: not judged"}
    assert j.bias_ne_m == pytest.approx(OFFSET)
    _outage(state, j, 5.0)
    v = _fly(state, j, 5.0, 35.0)
    assert v.count("reset (GNSS lost: EV − bias the reference)") == 1
    assert v.index("reset (GNSS lost: EV − bias the reference)") == pytest.approx(70, abs=1)  # 7 s at 10 Hz
    assert v.count("used") >= 290
    assert float(np.hypot(*state.p_err_m)) < 0.2  # free: 0.58 m/s × 30 s = 17 m
    assert j.verdicts["ODOMETRY"]["GNSS healthy: not judged"] == 50
    assert sum(j.outage_verdicts["ODOMETRY"].values()) == 300


def test_odometry_from_the_outage_start_still_learns_the_offset_while_gnss_is_flagged() -> None:
    """The service sends only in outages: its first ODOMETRY 1 s after the loss still finds gnss_pos on
    (reset_timeout_max), so startEvPosFusion sets the bias to EV − EKF position, and the offset is learnt."""
    state, j = _judge()
    _outage(state, j, 0.0)
    _fly(state, j, 0.0, 1.0, send=False)
    v = _fly(state, j, 1.0, 30.0)
    assert v[:2] == [WAITING, "started"]
    assert v.index("reset (GNSS lost: EV − bias the reference)") == 59  # at 7 s: GNSS fusion stops
    assert float(np.hypot(*state.p_err_m)) < 1.0  # about the error at the first sample: 0.58 m
    assert float(np.hypot(*(j.bias_ne_m - OFFSET))) < 1.0


def test_without_gnss_a_start_resets_to_the_raw_ev_position() -> None:
    """startEvPosFusion with gnss_pos off: the position is reset to the EV position itself, bias zeroed, so an
    origin offset becomes the error."""
    state, j = _judge()
    _outage(state, j, 0.0)
    _fly(state, j, 0.0, 8.0, send=False)
    v = _fly(state, j, 8.0, 20.0)
    assert v[1] == "reset (start without GNSS: the raw EV position)"
    assert float(np.hypot(*state.p_err_m)) == pytest.approx(float(np.hypot(*OFFSET)), abs=1.0)


def test_position_variance_is_the_message_floored_by_evp_noise() -> None:
    """EKF2_EV_NOISE_MD = 0: max(pose_covariance, EKF2_EVP_NOISE²) is the reset's variance."""
    for pos_var, expected in ((4.0, 4.0), (1e-4, 0.01)):
        state, j = _judge(ev_ctrl=1)
        _outage(state, j, 0.0)
        _fly(state, j, 0.0, 8.0, send=False)
        _fly(state, j, 8.0, 8.2, pos_var=pos_var)
        assert state.P[:, 0, 0] == pytest.approx([expected, expected])


def test_position_innovation_beyond_evp_gate_is_rejected() -> None:
    state, j = _judge(ev_ctrl=1)
    _fly(state, j, 0.0, 2.0, outage=False)
    _outage(state, j, 2.0)
    _fly(state, j, 2.0, 12.0)
    before = state.p_err_m.copy()
    assert _odo(j, 12.1, outage=True, e_p=(50.0, 0.0)) == "gated"
    assert state.p_err_m == pytest.approx(before)


def test_fusion_failing_for_one_second_resets_to_ev() -> None:
    """updateEvPosFusion: no fusion for no_aid_timeout_max (1 s) and quality sufficient: reset to EV − bias."""
    state, j = _judge(ev_ctrl=1)
    _fly(state, j, 0.0, 2.0, outage=False)
    _outage(state, j, 2.0)
    _fly(state, j, 2.0, 12.0)
    v = _fly(state, j, 12.0, 13.5, e_p=(50.0, 0.0))
    assert v[:10] == ["gated"] * 10 and "reset (fusion failing)" in v
    assert state.p_err_m[0] == pytest.approx(50.0, abs=0.5)


def test_a_new_reset_counter_resets_the_position() -> None:
    state, j = _judge(ev_ctrl=1)
    _fly(state, j, 0.0, 2.0, outage=False)
    _outage(state, j, 2.0)
    _fly(state, j, 2.0, 12.0)
    assert _odo(j, 12.1, outage=True, e_p=(20.0, 0.0), reset_counter=1) == "reset (reset_counter)"
    assert state.p_err_m == pytest.approx(OFFSET + np.array([20.0, 0.0]) - j.bias_ne_m)  # EV − bias, exactly


def test_body_frd_velocity_is_rotated_by_the_attitude() -> None:
    """BODY_FRD: the velocity is the body's (yaw 90°: forward is east); without other aiding the start resets the
    velocity to it, then it is fused: the velocity error goes to zero."""
    state, j = _judge(ev_ctrl=4)
    _outage(state, j, 0.0)
    v = _fly(state, j, 0.0, 12.0)
    assert v[1] == "started" and v[-1] == "used (velocity only)"  # test ratio < 0.1 while gnss_vel is on
    assert float(np.hypot(*state.v_err_m_s)) < 0.02  # free: 0.58 m/s
    state, j = _judge(ev_ctrl=4)
    _outage(state, j, 0.0)
    v = _fly(state, j, 0.0, 12.0, truth_q=LEVEL)  # the EKF's attitude is not the message's
    assert "reset (start)" in v  # gated while gnss_vel is on, then (no other aiding) reset to the wrong velocity
    assert float(np.hypot(*state.v_err_m_s)) == pytest.approx(30.0 * math.sqrt(2.0), abs=0.1)
