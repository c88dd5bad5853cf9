"""The mock autopilot's judge of the ExternalNav route (sim/sitl/extnav_judge.py): which ODOMETRY ArduPilot's EKF3
would use, by its rules, the source-set switch, the anchoring, and the Kalman update of the mock's own estimate error
against a hand computation; and, through the mock's link, MAV_CMD_SET_EKF_SOURCE_SET ACKed and switching fusion."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.contract import WorldTick
from sim.sitl.autopilot import AutopilotOptions, DeadReckoningDrift, MockAutopilot, RunSummary
from sim.sitl.ekf_judge import Ekf3GpsRules, GpsInputJudge
from sim.sitl.extnav_judge import (
    Ek3ExtNavRules,
    Ek3SourceParams,
    ExtNavJudge,
    SourceXY,
    VisoParams,
    pose_errors_from_covariance,
)
from sim.sitl.link import MavlinkEndpoint, MavlinkMessage, MemoryLinkPair
from sim.sitl.scripted_world import OutageWindow, ScriptedWorld, scenario_config
from vdm_aero.errors import UserInputError
from vdm_aero.rotation import dcm_from_quat

SIG_V = 0.3  # DeadReckoningDrift's default velocity error at an outage's start [m/s]
NAN_COV = np.full(21, np.nan)  # "unknown": posErr 0, floored at VISO_POS_M_NSE
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])  # body = NED: v_body_frd = v_ned
COMPANION = {"system_id": 1, "component_id": mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER}


def _cov(pos_err_m: float) -> np.ndarray:
    """A pose covariance whose ArduPilot posErr = ∛(3 c²) is ``pos_err_m``."""
    c = np.zeros(21)
    c[[0, 6, 11]] = math.sqrt(pos_err_m**3 / 3.0)
    return c


def _judges(rules: Ek3ExtNavRules | None = None, rw: float = 0.0) -> tuple[GpsInputJudge, ExtNavJudge]:
    state = GpsInputJudge(Ekf3GpsRules(), velocity_sigma_m_s=SIG_V, random_walk_m_s_per_sqrt_s=rw)
    return state, ExtNavJudge(rules or Ek3ExtNavRules(), state)


def _start(state: GpsInputJudge, ext: ExtNavJudge, v0: tuple[float, float], t_s: float) -> None:
    """An outage whose drift starts with velocity error ``v0``, then ``t_s`` of it without random walk."""
    state.outage_started(np.array([*v0, 0.0]))
    ext.outage_started()
    for _ in range(round(t_s / 0.1)):
        state.propagate(0.1, np.zeros(3))


def _odo(ext: ExtNavJudge, t_s: float, e_p: tuple[float, float], e_v: tuple[float, float] = (0.0, 0.0),
         **kw: object) -> str:  # fmt: skip
    """An ODOMETRY at ``t_s`` whose position and velocity are the truth's (here 0) plus ``e_p``, ``e_v``."""
    args: dict[str, object] = dict(time_usec=round(t_s * 1e6), frame_id=mavlink2.MAV_FRAME_LOCAL_FRD,
                                   child_frame_id=mavlink2.MAV_FRAME_BODY_FRD, pos_m=np.array([*e_p, 0.0]), q=LEVEL,
                                   vel_m_s=np.array([*e_v, 0.0]), pose_covariance=NAN_COV, reset_counter=0,
                                   quality=100, truth_pos_ned_m=np.zeros(3), truth_v_ned_m_s=np.zeros(3),
                                   gnss_outage=True)  # fmt: skip
    args.update(kw)
    return ext.odometry(**args)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------- the rules
def test_pose_errors_are_derived_from_the_covariance_as_ardupilot_does() -> None:
    c = np.zeros(21)
    c[[0, 6, 11]] = [1.0, 2.0, 2.0]  # variances [m²]
    c[[15, 18, 20]] = [0.0, 0.0, 0.5]
    pos_err, ang_err = pose_errors_from_covariance(c)
    assert pos_err == pytest.approx(9.0 ** (1.0 / 3.0), rel=1e-12)  # ∛(1 + 4 + 4)
    assert ang_err == pytest.approx(0.25 ** (1.0 / 3.0), rel=1e-12)
    assert pose_errors_from_covariance(NAN_COV) == (0.0, 0.0)


def test_frame_ids_quality_and_the_interval_are_refused_as_ardupilot_would() -> None:
    """Every refused sample is 5 m off: had any been fused, the estimate (drift-free here) would have moved."""
    state, ext = _judges(Ek3ExtNavRules(viso=VisoParams(qual_min=50)))
    _start(state, ext, (0.0, 0.0), 1.0)
    ext.set_source_set(2, 1.0)
    frd, body = mavlink2.MAV_FRAME_LOCAL_FRD, mavlink2.MAV_FRAME_BODY_FRD
    off = (5.0, 5.0)
    dropped = "frame ids not LOCAL_FRD / BODY_FRD (handle_odometry drops it)"
    assert _odo(ext, 1.0, off, frame_id=mavlink2.MAV_FRAME_LOCAL_NED) == dropped
    assert _odo(ext, 1.0, off, child_frame_id=mavlink2.MAV_FRAME_LOCAL_NED) == dropped
    assert _odo(ext, 1.0, off, frame_id=body, child_frame_id=frd) == dropped
    assert _odo(ext, 1.0, off, quality=49) == "quality below VISO_QUAL_MIN"
    assert _odo(ext, 1.0, off, quality=-1) == "quality below VISO_QUAL_MIN"
    nan = np.full(3, np.nan)
    assert _odo(ext, 1.0, off, pos_m=nan, vel_m_s=nan) == "NaN (writeExtNavData drops it)"
    assert _odo(ext, 1.0, (0.0, 0.0), quality=50) == "reset (source switch)"
    assert _odo(ext, 1.019, off, (1.0, 1.0)) == "under extNavIntervalMin (20 ms) after the last"
    assert _odo(ext, 1.02, (0.0, 0.0)) == "used"
    assert sum(ext.verdicts.values()) == 9 and ext.verdicts[dropped] == 3
    np.testing.assert_allclose(state.p_err_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(state.v_err_m_s, 0.0, atol=1e-12)


def test_fusion_only_while_the_source_set_makes_extnav_the_source() -> None:
    """Set 1 (GPS): the ODOMETRY is refused and the estimate keeps its drift; MAV_CMD_SET_EKF_SOURCE_SET 2: the first
    sample resets the position onto it (ResetPositionNE), the next are fused; back to set 1: refused again."""
    state, ext = _judges()
    _start(state, ext, (0.3, -0.2), 10.0)
    drift = np.array([3.0, -2.0])
    np.testing.assert_allclose(state.p_err_m, drift, atol=1e-9)
    assert _odo(ext, 10.0, (0.1, 0.1)) == "source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"
    ext.set_source_set(1, 10.05)  # no change of POSXY source: no reset armed
    assert _odo(ext, 10.1, (0.1, 0.1)) == "source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"
    np.testing.assert_allclose(state.p_err_m, drift, atol=1e-9)
    ext.set_source_set(2, 10.15)
    v_err = (0.3, -0.2)  # the ODOMETRY's velocity error equals the estimate's: no velocity innovation
    assert _odo(ext, 10.2, (0.1, 0.1), v_err) == "reset (source switch)"
    np.testing.assert_allclose(state.p_err_m, [0.1, 0.1], atol=1e-9)
    assert _odo(ext, 10.3, (0.1, 0.1), v_err) == "used"
    ext.set_source_set(1, 10.35)
    before = state.p_err_m.copy()
    assert _odo(ext, 10.4, (5.0, 5.0)) == "source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"
    np.testing.assert_array_equal(state.p_err_m, before)
    assert [s["source_set"] for s in ext.switches] == [1.0, 2.0, 1.0]
    assert all(s["outage"] == 0.0 for s in ext.switches)


def test_fuse_all_velocities_takes_extnav_velocity_while_gps_is_the_position_source() -> None:
    """EK3_SRC_OPTIONS bit 0: set 2's VELXY = ExtNav is fused with set 1 active (useVelXYSource); position is not."""
    state, ext = _judges(Ek3ExtNavRules(sources=Ek3SourceParams(options=1)))
    _start(state, ext, (0.3, -0.2), 10.0)
    assert _odo(ext, 10.0, (9.0, 9.0), (0.0, 0.0)) == "used (velocity only)"
    assert np.all(np.abs(state.v_err_m_s) < np.array([0.3, 0.2]))  # velocity error pulled toward 0
    assert np.all(np.abs(state.p_err_m) < np.array([3.0, 2.0]))  # and position through their covariance


def test_one_odometry_against_a_hand_computed_kalman_update() -> None:
    """No random walk: after t = 10 s, P = σv²[[t², t], [t, 1]] = [[0.9·10, 0.9], [0.9, 0.09]] per axis. Position only
    (set 2 with VELXY none), posErr 1 m: R = 1 m². Sample 1 resets the position onto e₁ and fuses with no innovation:
    K = (9, 0.9)/10, P → [[0.9, 0.09], [0.09, 0.009]]. Sample 2 (e₂, same instant): p = e₁ + (0.9/1.9)(e₂ − e₁),
    v = v₀ + (0.09/1.9)(e₂ − e₁)."""
    src = Ek3SourceParams(src2=replace(Ek3SourceParams().src2, velxy=SourceXY.NONE))
    state, ext = _judges(Ek3ExtNavRules(sources=src))
    v0 = np.array([0.3, -0.2])
    _start(state, ext, (0.3, -0.2), 10.0)
    np.testing.assert_allclose(state.P[0], [[9.0, 0.9], [0.9, 0.09]], rtol=1e-9)
    ext.set_source_set(2, 10.0)
    e1, e2 = np.array([1.0, -1.0]), np.array([1.5, -0.5])
    assert _odo(ext, 10.0, tuple(e1), pose_covariance=_cov(1.0)) == "reset (source switch)"
    np.testing.assert_allclose(state.p_err_m, e1, atol=1e-12)
    np.testing.assert_allclose(state.P[1], [[0.9, 0.09], [0.09, 0.009]], rtol=1e-9)
    assert _odo(ext, 10.1, tuple(e2), pose_covariance=_cov(1.0)) == "used (position only)"
    np.testing.assert_allclose(state.p_err_m, e1 + 0.9 / 1.9 * (e2 - e1), rtol=1e-9)
    np.testing.assert_allclose(state.v_err_m_s, v0 + 0.09 / 1.9 * (e2 - e1), rtol=1e-9)
    # a position 30 m off claiming 1 m: (30² + 30²) > 5² · 2 · (P + R) → gated, nothing moves
    before = state.p_err_m.copy()
    assert _odo(ext, 10.2, (31.5, 29.5), pose_covariance=_cov(1.0)) == "gated (innovation > 5σ)"
    np.testing.assert_array_equal(state.p_err_m, before)
    # a new reset_counter: ResetPositionNE onto the sample, whatever its innovation
    assert _odo(ext, 10.3, (31.5, 29.5), pose_covariance=_cov(1.0), reset_counter=1) == "reset (reset_counter)"
    np.testing.assert_allclose(state.p_err_m, [31.5, 29.5], atol=1e-12)


def test_an_outages_end_records_the_last_position_the_estimate_and_the_gates_variance() -> None:
    """The hand computation above, then the outage ends: the record holds the last ODOMETRY's error as it came (e₂),
    the estimate after fusing it, the dead reckoning's error handed in, and the innovation variance the gate took
    for e₂ before fusing it, P_N + P_E + 2R = 0.9 + 0.9 + 2 · 1 m²; an outage without a judged position records
    nothing."""
    src = Ek3SourceParams(src2=replace(Ek3SourceParams().src2, velxy=SourceXY.NONE))
    state, ext = _judges(Ek3ExtNavRules(sources=src))
    _start(state, ext, (0.3, -0.2), 10.0)
    ext.set_source_set(2, 10.0)
    e1, e2 = np.array([1.0, -1.0]), np.array([1.5, -0.5])
    _odo(ext, 10.0, tuple(e1), pose_covariance=_cov(1.0))
    _odo(ext, 10.1, tuple(e2), pose_covariance=_cov(1.0))
    ext.outage_ended(np.array([4.0, -3.0]))
    (end,) = ext.outage_end
    est = e1 + 0.9 / 1.9 * (e2 - e1)
    assert (end["odometry_n_m"], end["odometry_e_m"]) == (1.5, -0.5)
    np.testing.assert_allclose([end["estimate_n_m"], end["estimate_e_m"]], est, rtol=1e-9)
    assert (end["free_n_m"], end["free_e_m"]) == (4.0, -3.0)
    assert end["innovation_var_m2"] == pytest.approx(3.8, rel=1e-9)
    ext.outage_started()
    ext.outage_ended(np.zeros(2))
    assert len(ext.outage_end) == 1


def test_beyond_the_glitch_radius_the_position_resets_to_extnav_with_its_variance() -> None:
    """After 100 s of σv = 0.3 m/s, P_NN + P_EE = 2 · 900 m² > EK3_GLITCH_RAD² = 625 m²: ResetPosition onto the sample,
    P_pos = (25/2)² per axis, position–velocity covariance zeroed, the sample not fused."""
    state, ext = _judges()
    _start(state, ext, (0.3, 0.0), 100.0)
    ext.set_source_set(2, 100.0)
    assert _odo(ext, 100.0, (2.0, -1.0), (0.3, 0.0)) == "reset (position variance beyond EK3_GLITCH_RAD)"
    np.testing.assert_allclose(state.p_err_m, [2.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(state.P[:, 0, 0], 12.5**2, rtol=1e-12)
    np.testing.assert_allclose(state.P[:, 0, 1], 0.0, atol=1e-12)


@pytest.mark.parametrize("viso_type", [1, 3])
def test_anchoring_mavlink_type_fuses_absolute_position_voxl_type_its_motion(viso_type: int) -> None:
    """A companion whose frame origin is 100 m north of the EKF origin and which tracks the truth exactly. VISO_TYPE 1
    aligns nothing: at the switch the estimate jumps to its 100 m error. VISO_TYPE 3 moves the sensor's position onto
    the AHRS's at each sample while GPS is the source (align_inactive_sources): at the switch the estimate resets onto
    the error it had at the last alignment, and the companion's motion after it is what is fused."""
    state, ext = _judges(Ek3ExtNavRules(viso=VisoParams(type=viso_type)))
    _start(state, ext, (0.3, -0.2), 10.0)
    assert _odo(ext, 10.0, (100.0, 0.0)) == "source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"
    at_alignment = state.p_err_m.copy()  # (3, -2) m
    for _ in range(10):  # 1 s more of drift: the estimate's error grows to (3.3, -2.2)
        state.propagate(0.1, np.zeros(3))
    ext.set_source_set(2, 11.0)
    truth = np.array([50.0, 20.0, 0.0])  # the vehicle moved; the companion saw it move
    verdict = _odo(ext, 11.0, (150.0, 20.0), (0.3, -0.2), truth_pos_ned_m=truth)  # no velocity innovation
    assert verdict == "reset (source switch)"
    if viso_type == 1:
        np.testing.assert_allclose(state.p_err_m, [100.0, 0.0], atol=1e-9)
    else:
        np.testing.assert_allclose(state.p_err_m, at_alignment, atol=1e-9)
        np.testing.assert_allclose(ext.pos_correction_ne_m, at_alignment - [100.0, 0.0], atol=1e-9)


def test_vision_position_estimate_is_the_position_path_with_quality_zero() -> None:
    state, ext = _judges(Ek3ExtNavRules(viso=VisoParams(qual_min=1)))
    _start(state, ext, (0.3, 0.0), 1.0)
    ext.set_source_set(2, 1.0)
    args = dict(pos_m=np.array([0.5, 0.0, 0.0]), covariance=NAN_COV, reset_counter=0, truth_pos_ned_m=np.zeros(3),
                gnss_outage=True)  # fmt: skip
    assert ext.vision_position_estimate(usec=1_000_000, **args) == "quality below VISO_QUAL_MIN"  # type: ignore[arg-type]
    _, ext0 = _judges()
    ext0.state.outage_started(np.zeros(3))
    ext0.set_source_set(2, 0.0)
    assert ext0.vision_position_estimate(usec=1_000_000, **args) == "reset (source switch)"  # type: ignore[arg-type]
    np.testing.assert_allclose(ext0.state.p_err_m, [0.5, 0.0], atol=1e-12)


# ---------------------------------------------------------------------------------- through the mock's link
class _OdometryCompanion:
    """A world whose step also plays the companion: at 10 Hz an ODOMETRY of the tick's truth plus seeded noise
    (σ = 0.3 m, honest covariance), and the given COMMAND_LONGs at their times. What it sends is handled at the mock's
    next step, against the same truth."""

    def __init__(self, inner: ScriptedWorld, ep: MavlinkEndpoint, commands: dict[int, float], seed: int,
                 gps_input_at: int | None) -> None:  # fmt: skip
        self.inner, self.ep, self.commands = inner, ep, dict(commands)  # step index → param1
        self.gps_input_at = gps_input_at  # step index of one GPS_INPUT of the truth (None: none)
        self.dt_s = inner.dt_s
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = inner.home_lat_deg, inner.home_lon_deg, inner.home_alt_m
        self.rng = np.random.default_rng(seed)
        self.k = 0

    def step(self) -> WorldTick:
        tick = self.inner.step()
        t = tick.truth.t_s
        if self.k in self.commands:
            self.ep.send(self.ep.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_SET_EKF_SOURCE_SET, 0,
                                                         self.commands[self.k], 0, 0, 0, 0, 0, 0))  # fmt: skip
        if self.k == self.gps_input_at:
            tr = tick.truth
            self.ep.send(self.ep.mav.gps_input_encode(round(t * 1e6), 1, 0, 0, 0, 3, round(tr.lat_deg * 1e7),
                                                      round(tr.lon_deg * 1e7), tr.alt_m, 1.0, 1.0, *tr.v_ned_m_s,
                                                      0.3, 1.0, 1.0, 12, 0))  # fmt: skip
        if self.k % round(0.1 / self.dt_s) == 0:
            q = np.asarray(tick.truth.q_nb, dtype=np.float64)
            pos = tick.truth.pos_ned_m + np.array([*(0.3 * self.rng.standard_normal(2)), 0.0])
            v_b = dcm_from_quat(q).T @ tick.truth.v_ned_m_s
            cov = _cov(0.4)  # posErr 0.4 m: a little above σ, as a cautious companion reports
            self.ep.send(self.ep.mav.odometry_encode(
                round(t * 1e6), mavlink2.MAV_FRAME_LOCAL_FRD, mavlink2.MAV_FRAME_BODY_FRD, *pos, q, *v_b,
                0.0, 0.0, 0.0, cov, np.full(21, np.nan), 0, mavlink2.MAV_ESTIMATOR_TYPE_VIO, 100))  # fmt: skip
        self.k += 1
        return tick


def _fly(commands: dict[int, float], on_gnss_loss: int | None = None,
         gps_input_at: int | None = None) -> tuple[RunSummary, list[MavlinkMessage]]:  # fmt: skip
    cfg = replace(scenario_config("circle_noiseless"), gnss_outages=(OutageWindow(2.0, 12.0),))
    inner = ScriptedWorld(cfg)
    pair = MemoryLinkPair()
    ep = MavlinkEndpoint(pair.companion_end, **COMPANION)
    world = _OdometryCompanion(inner, ep, commands, seed=5, gps_input_at=gps_input_at)
    drift = DeadReckoningDrift(horizontal_velocity_sigma_m_s=1.0, seed=2)
    opts = AutopilotOptions(drift=drift, source_set_on_gnss_loss=on_gnss_loss)
    with MockAutopilot(world, pair.autopilot_end, speed=math.inf, stream_rates={}, options=opts) as ap:  # type: ignore[arg-type]
        summary = ap.run(13.0)
    msgs: list[MavlinkMessage] = []
    while got := ep.poll(0.05):
        msgs.extend(got)
    return summary, msgs


def test_source_set_command_is_acked_and_switches_fusion_through_the_link() -> None:
    """Out-of-range source sets are DENIED; set 2 at 3 s is ACCEPTED and from then on the companion's ODOMETRY is
    fused: the mock's error at the outage's end is far below the drift without it. Set 1 instead: ACCEPTED, nothing
    fused, the error is the drift's."""
    inner_dt = ScriptedWorld(scenario_config("circle_noiseless")).dt_s
    k3 = round(3.0 / inner_dt)
    with_extnav, msgs = _fly({1: 0.0, 2: 4.0, 3: float("nan"), k3: 2.0})
    acks = [m for m in msgs if m.get_type() == "COMMAND_ACK" and m.command == mavlink2.MAV_CMD_SET_EKF_SOURCE_SET]
    assert [a.result for a in acks] == [mavlink2.MAV_RESULT_DENIED] * 3 + [mavlink2.MAV_RESULT_ACCEPTED]
    ((switch,),) = [with_extnav["source_set_switches"]]
    assert switch["source_set"] == 2.0 and switch["outage"] == 0.0 and 3.0 <= switch["t_s"] <= 3.0 + 2 * inner_dt
    v = with_extnav["odometry_verdicts"]
    assert v["reset (source switch)"] == 1 and v["used"] >= 85  # 9 s at 10 Hz after the switch
    assert v["source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"] >= 28  # 2 s..3 s, and GNSS-healthy 0..2 s
    assert v.get("gated (innovation > 5σ)", 0) == 0
    ((end,),) = [with_extnav["outage_end_errors"]]
    assert end["without_m"] > 5.0 and end["with_service_m"] < 0.5

    gps_only, msgs = _fly({k3: 1.0})
    acks = [m for m in msgs if m.get_type() == "COMMAND_ACK" and m.command == mavlink2.MAV_CMD_SET_EKF_SOURCE_SET]
    assert [a.result for a in acks] == [mavlink2.MAV_RESULT_ACCEPTED]
    assert set(gps_only["odometry_verdicts"]) == {"source not active (EK3_SRCn POSXY/VELXY not ExternalNav)"}
    ((end,),) = [gps_only["outage_end_errors"]]
    assert end["with_service_m"] == pytest.approx(end["without_m"], rel=1e-9)


def test_a_script_switching_on_gnss_loss_fuses_extnav_and_leaves_gps_input_unused() -> None:
    """``source_set_on_gnss_loss`` = 2 (a Lua script's ahrs:set_posvelyaw_source_set): set 2 at the outage's start,
    set 1 at its end, no command needed; a GPS_INPUT in the outage is not fused (POSXY is not GPS)."""
    dt = ScriptedWorld(scenario_config("circle_noiseless")).dt_s
    summary, msgs = _fly({}, on_gnss_loss=2, gps_input_at=round(5.0 / dt))
    assert not [m for m in msgs if m.get_type() == "COMMAND_ACK"]
    switches = [(s["source_set"], s["outage"]) for s in summary["source_set_switches"]]
    assert switches == [(2.0, 0.0), (1.0, 0.0)]  # at the outage's start and at its end, both counted in it
    assert [s["t_s"] for s in summary["source_set_switches"]] == pytest.approx([2.0, 12.0], abs=2 * dt)
    assert summary["odometry_verdicts"]["reset (source switch)"] == 1
    assert summary["odometry_verdicts"]["used"] >= 95
    # the outage's own count: only what came between its start and its end (the flight's ODOMETRY before it is not)
    in_outage = summary["odometry_outage_verdicts"]
    assert in_outage["used"] == summary["odometry_verdicts"]["used"] and sum(in_outage.values()) < sum(
        summary["odometry_verdicts"].values()
    )
    assert summary["gps_input_verdicts"] == {"source set: POSXY not GPS": 1}
    ((end,),) = [summary["outage_end_errors"]]
    assert end["with_service_m"] < 0.5 < 5.0 < end["without_m"]
    bad = AutopilotOptions(source_set_on_gnss_loss=4)
    with pytest.raises(UserInputError, match=r"source set 1\.\.3"):
        MockAutopilot(ScriptedWorld(scenario_config("circle_noiseless")), MemoryLinkPair().autopilot_end, options=bad)
