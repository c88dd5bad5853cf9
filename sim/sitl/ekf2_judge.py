"""Whether PX4 would use the companion's navigation messages in a GNSS outage, and what its EKF2 would make of them: a
judge inside the mock (as PX4), fusing into the GPS_INPUT judge's drift error state (sim/sitl/ekf_judge.py) as the
ArduPilot ExternalNav judge does (sim/sitl/extnav_judge.py).

Release: PX4 v1.16 (EKF2 sources of its era: ``ekf2_*`` parameter names, ``GnssChecks``, ``EvVelBodyFrameFrd``); main's
auxiliary global position (2026) is an option (``Ekf2Rules.agp_handler``). Rules, from PX4's sources:

* GPS_INPUT (232): ``mavlink_receiver.cpp`` ``MavlinkReceiver::handle_message`` has no case for it (v1.14..v1.16 and
  main; PR #28554, open, would add one); only HIL_GPS becomes ``sensor_gps``, in HIL or with MAV_USEHILGPS from the
  autopilot's own system id. No GPS_INPUT reaches ``vehicle_gps_position`` or ``GnssChecks``: each is "no handler".
* GNSS flags, ``gps_control.cpp`` ``controlGpsFusion``: a lost fix fails the checks, and GNSS fusion stops only
  ``reset_timeout_max`` (7 s, ``common.h``) after the last pass; until then ``gnss_pos`` holds.
* ODOMETRY (331), ``handle_message_odometry``: a finite pose in ``frame_id`` LOCAL_NED (LOCAL_ENU swapped) is
  POSE_FRAME_NED, LOCAL_FRD / FLU POSE_FRAME_FRD, else none; variances ``pose_covariance`` [0], [6], [11]; a finite
  velocity in ``child_frame_id`` LOCAL_NED / ENU is NED, LOCAL_FRD / FLU FRD, BODY_FRD (BODY_NED, BODY_OFFSET_NED)
  BODY_FRD, variances ``velocity_covariance`` [0], [6], [11]; none read for MAV_ESTIMATOR_TYPE_NAIVE; published
  for estimator types UNKNOWN, NAIVE, VISION, VIO only; ``quality`` and ``reset_counter`` copied.
* ``EKF2.cpp`` ``UpdateExtVisionSample``: EKF2_EV_NOISE_MD = 0 takes the message's variances, if all three finite,
  floored by EKF2_EVP_NOISE² / EKF2_EVV_NOISE², else the parameters'.
* ``ev_control.cpp`` ``controlExternalVisionFusion``: quality sufficient if EKF2_EV_QMIN ≤ 0 or quality ≥ it; fusion
  starts only with a sample < EV_MAX_INTERVAL (200 ms, strictly) after the last sufficient one (never with the
  first); none for 400 ms stops it; a new ``reset_counter`` is a reset.
* ``ev_pos_control.cpp`` ``controlEvPosFusion`` (EKF2_EV_CTRL bit 0, NED, yaw aligned): while ``gnss_pos`` the bias
  estimator ``_ev_pos_b_est`` is on: set to EV − EKF position as it turns on, then fused with them
  (``bias_estimator.cpp``: 3σ gate, variance capped at the EV's, 0.13 m/s/√Hz), and the EV position is fused as
  EV − bias with variance EV (floored by EKF2_GPS_P_NOISE²) + bias. GNSS lost: the bias turns off and that change
  resets the position to EV − bias (``updateEvPosFusion``), the bias kept: an origin offset learnt with GNSS carries
  into the outage. ``startEvPosFusion`` without GNSS resets to the raw EV position, bias zeroed. Gate
  EKF2_EVP_GATE over both axes; 1 s without fusion (``no_aid_timeout_max``) resets (5 times in air), then stops.
* ``ev_vel_control.cpp`` / ``ev_vel.h`` (bit 2): BODY_FRD velocity fused in the body frame, floored by
  EKF2_EVV_NOISE²; starts with test ratios < 0.1, or with no other horizontal aiding by a reset (variance ×5); gate
  EKF2_EVV_GATE; 1 s without fusion resets (5 times), then stops.
* GLOBAL_POSITION_SENSOR (296): no handler in v1.16 ("no handler"); main (PR #26307) publishes it as
  ``aux_global_position``. Then ``aux_global_position_control.cpp`` ``AgpSource::update`` (v1.16's
  ``AuxGlobalPosition::update`` alike): EKF2_AGP(0)_CTRL bit 0; noise max(eph, EKF2_AGP_NOISE, 0.01); gate
  EKF2_AGP_GATE; fused alongside GNSS too, not only when dead reckoning; starts by fusing, else by a reset if allowed
  (EKF2_AGP_MODE 0: no other horizontal position source, 1: no other horizontal aiding); 7 s without fusion resets
  (if allowed) else stops; 5 s without data stops. EKF2_AGP0_ID selects the message ``id``, 0 disabling the slot
  (``params_aux_global_position.yaml``; the routing code and the receiver's use of ``flags`` were not seen).

Not modelled: the vertical (heights, vz, EKF2_EV_CTRL bit 1), yaw (bit 3) and attitude errors (the body velocity is
rotated by the truth's attitude if given, else the message's), LOCAL_FRD poses and velocities (rotated by the EV
attitude-error filter), EKF2_EV_DELAY / EKF2_AGP_DELAY and the timesync (a message is judged at ``t_s`` against the
truth then), the bias estimator's offset-detection boost, the global origin (taken as valid), GNSS's return (its flags
follow ``gnss_outage``; the mock's estimate follows GNSS then, so samples outside outages are counted and teach the
bias only), and main's reuse of a learnt bias when EV restarts without GNSS (``wasFusionActive``).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.sitl.ekf_judge import GpsInputJudge
from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.rotation import dcm_from_quat

__all__ = ["Ekf2Judge", "Ekf2Rules"]

EV_CTRL_HPOS, EV_CTRL_VEL = 1, 4  # EKF2_EV_CTRL bits 0, 2
AGP_CTRL_HPOS = 1  # EKF2_AGP_CTRL bit 0
EV_MAX_INTERVAL_US = 200_000  # common.h EV_MAX_INTERVAL
NO_AID_TIMEOUT_S = 1.0  # common.h no_aid_timeout_max
RESET_TIMEOUT_S = 7.0  # common.h reset_timeout_max
AGP_DATA_TIMEOUT_S = 5.0  # AgpSource::update: "Aux global position data stopped"
EV_RESETS = 5  # _nb_ev_pos_reset_available / _nb_ev_vel_reset_available
BIAS_GATE, BIAS_NSD, BIAS_VAR0 = 3.0, 0.13, 0.1  # BiasEstimator _gate_size, ev_hgt_bias_nsd, _state_var
VAR_MIN = 0.01**2
LOCAL_NED = {mavlink2.MAV_FRAME_LOCAL_NED: False, mavlink2.MAV_FRAME_LOCAL_ENU: True}  # frame → x, y swapped
LOCAL_FRD = {mavlink2.MAV_FRAME_LOCAL_FRD, mavlink2.MAV_FRAME_LOCAL_FLU}
VEL_BODY = {mavlink2.MAV_FRAME_BODY_FRD, mavlink2.MAV_FRAME_BODY_NED, mavlink2.MAV_FRAME_BODY_OFFSET_NED}
EV_ESTIMATORS = {mavlink2.MAV_ESTIMATOR_TYPE_UNKNOWN, mavlink2.MAV_ESTIMATOR_TYPE_NAIVE,
                 mavlink2.MAV_ESTIMATOR_TYPE_VISION, mavlink2.MAV_ESTIMATOR_TYPE_VIO}  # fmt: skip


@dataclass(frozen=True)
class Ekf2Rules:
    """The PX4 parameters the judge reads: PX4's defaults, except where docs/service.md's "What to set on PX4" sets
    them (EKF2_EV_CTRL, EKF2_AGP_CTRL)."""

    release: str = "v1.16"  # named in the "no handler" verdicts
    ev_ctrl: int = EV_CTRL_HPOS | EV_CTRL_VEL  # EKF2_EV_CTRL: default 0; service.md: horizontal position + velocity
    ev_noise_md: int = 0  # EKF2_EV_NOISE_MD (default 0: the message's variance, floored by the parameters)
    ev_qmin: int = 1  # EKF2_EV_QMIN: default 0; service.md sets 1 (the service sends quality −1 without a solution)
    evp_noise_m: float = 0.1  # EKF2_EVP_NOISE
    evv_noise_m_s: float = 0.1  # EKF2_EVV_NOISE
    evp_gate: float = 5.0  # EKF2_EVP_GATE [σ]
    evv_gate: float = 3.0  # EKF2_EVV_GATE [σ]
    gps_p_noise_m: float = 0.5  # EKF2_GPS_P_NOISE: EV position floor while GNSS position is fused
    agp_handler: bool = False  # 296 reaches aux_global_position: main (PR #26307), not v1.16
    agp_id: int = 1  # EKF2_AGP0_ID (main; default 0 disables the slot): the message id taken
    agp_ctrl: int = AGP_CTRL_HPOS  # EKF2_AGP(0)_CTRL: default 0; service.md enables it
    agp_mode: int = 0  # EKF2_AGP(0)_MODE: 0 automatic, 1 dead reckoning
    agp_noise_m: float = 1.0  # EKF2_AGP(0)_NOISE
    agp_gate: float = 3.0  # EKF2_AGP(0)_GATE [σ]


class Ekf2Judge:
    """EKF2's route for the companion's messages, fusing into ``state`` (position and velocity error per horizontal
    axis). ``verdicts`` / ``outage_verdicts`` per message name; ``details`` the EV position and velocity outcomes."""

    def __init__(self, rules: Ekf2Rules, state: GpsInputJudge) -> None:
        self.rules = rules
        self.state = state
        names = ("GPS_INPUT", "ODOMETRY", "GLOBAL_POSITION_SENSOR")
        self.verdicts: dict[str, Counter[str]] = {n: Counter() for n in names}
        self.outage_verdicts: dict[str, Counter[str]] = {n: Counter() for n in names}
        self.details: Counter[str] = Counter()  # "pos: …", "vel: …" per ODOMETRY
        self._t_lost: float | None = None  # the GNSS fix's loss (outage start)
        self.ev_pos = self.ev_vel = False  # _control_status.flags.ev_pos / ev_vel
        self._ev_prev_t, self._ev_prev_quality, self._ev_prev_reset = -math.inf, 0, 0  # _ev_sample_prev
        self._pos_fused_t = self._vel_fused_t = -math.inf  # aid_src.time_last_fuse
        self._hpos_fused_t = -math.inf  # _time_last_hor_pos_fuse (any source)
        self._pos_resets = self._vel_resets = 0
        self.bias_ne_m = np.zeros(2)  # _ev_pos_b_est: EV position − EKF position
        self.bias_var_m2 = np.full(2, BIAS_VAR0)
        self._bias_var_max = np.full(2, 2.0)
        self._bias_on, self._bias_t = False, -math.inf
        self.agp_state, self._agp_fused_t, self._agp_push_t = "stopped", -math.inf, -math.inf

    # ------------------------------------------------------------------------------------ outages
    def outage_started(self, t_s: float) -> None:
        """The GNSS fix lost at ``t_s`` (else taken from the first message flagged ``gnss_outage``)."""
        self._t_lost = t_s

    def outage_ended(self) -> None:
        self._t_lost = None

    def _gnss(self, t_s: float, gnss_outage: bool) -> bool:
        """``gnss_pos`` / ``gnss_vel``: on outside outages and for reset_timeout_max after the loss."""
        if not gnss_outage:
            self._t_lost, self._hpos_fused_t = None, t_s
            return True
        if self._t_lost is None:
            self._t_lost = t_s
        return t_s - self._t_lost < RESET_TIMEOUT_S

    def _count(self, name: str, verdict: str, gnss_outage: bool) -> str:
        self.verdicts[name][verdict] += 1
        if gnss_outage:
            self.outage_verdicts[name][verdict] += 1
        return verdict

    # ------------------------------------------------------------------------------------ GPS_INPUT
    def gps_input(self, *, t_s: float, fix_type: int, satellites: int, hdop: float, vdop: float, h_acc_m: float,
                  v_acc_m: float, speed_acc_m_s: float, ignore_flags: int, fix_error_ne_m: FloatArray,
                  vel_error_ne_m_s: FloatArray, gnss_outage: bool) -> str:  # fmt: skip
        """One GPS_INPUT: mavlink_receiver has no case for it, so nothing of it reaches EKF2."""
        self._gnss(t_s, gnss_outage)
        return self._count("GPS_INPUT", f"PX4 {self.rules.release}: no handler for message 232", gnss_outage)

    # ------------------------------------------------------------------------------------ ODOMETRY
    def odometry(self, *, t_s: float, frame_id: int, child_frame_id: int, pos_m: FloatArray, q: FloatArray,
                 vel_m_s: FloatArray, pose_covariance: FloatArray, velocity_covariance: FloatArray,
                 reset_counter: int, quality: int, truth_pos_ned_m: FloatArray, truth_v_ned_m_s: FloatArray,
                 gnss_outage: bool, estimator_type: int = mavlink2.MAV_ESTIMATOR_TYPE_VIO,
                 truth_q: FloatArray | None = None) -> str:  # fmt: skip
        """One ODOMETRY at ``t_s``: its verdict, counted. ``pos_m`` is in the sender's local NED frame (its origin
        may differ from the mock's by a constant: the EV bias), ``truth_*`` the mock's NED position and velocity."""
        r, name = self.rules, "ODOMETRY"
        gnss = self._gnss(t_s, gnss_outage)
        if estimator_type not in EV_ESTIMATORS:
            return self._count(name, "estimator_type not VISION/VIO (not published)", gnss_outage)
        naive = estimator_type == mavlink2.MAV_ESTIMATOR_TYPE_NAIVE
        p, pc = np.asarray(pos_m, np.float64), np.asarray(pose_covariance, np.float64)
        v, vc = np.asarray(vel_m_s, np.float64), np.asarray(velocity_covariance, np.float64)
        pose = "ned" if frame_id in LOCAL_NED else "frd" if frame_id in LOCAL_FRD else ""
        pose = pose if np.all(np.isfinite(p)) else ""
        vf = "ned" if child_frame_id in LOCAL_NED else "frd" if child_frame_id in LOCAL_FRD else ""
        vf = "body" if child_frame_id in VEL_BODY else vf
        vf = vf if np.all(np.isfinite(v)) else ""
        if not pose and not vf:
            return self._count(name, "no valid pose or velocity frame", gnss_outage)
        p_var = np.full(3, np.nan) if naive else pc[[0, 6, 11]]
        v_var = np.full(3, np.nan) if naive else vc[[0, 6, 11]]
        if LOCAL_NED.get(frame_id):
            p, p_var = p[[1, 0, 2]], p_var[[1, 0, 2]]
        if LOCAL_NED.get(child_frame_id):
            v, v_var = v[[1, 0, 2]], v_var[[1, 0, 2]]
        p_var = self._floored(p_var, r.evp_noise_m)
        v_var = self._floored(v_var, r.evv_noise_m_s)
        since_us = round((t_s - self._ev_prev_t) * 1e6) if math.isfinite(self._ev_prev_t) else 2**63  # uint64 µs
        if since_us > 2 * EV_MAX_INTERVAL_US:  # no sufficient sample for 400 ms: "vision data stopped"
            self.ev_pos = self.ev_vel = False
        if self._bias_on:  # _ev_pos_b_est.predict at each EKF step
            self.bias_var_m2 = np.clip(self.bias_var_m2 + BIAS_NSD**2 * (t_s - self._bias_t), 1e-8, self._bias_var_max)
        self._bias_t = t_s
        ev_reset = reset_counter != self._ev_prev_reset
        q_ok = r.ev_qmin <= 0 or quality >= r.ev_qmin
        prev_ok = r.ev_qmin <= 0 or self._ev_prev_quality >= r.ev_qmin
        starting = q_ok and prev_ok and since_us < EV_MAX_INTERVAL_US
        truth_p = np.asarray(truth_pos_ned_m, np.float64)[:2]
        v_var = np.maximum(v_var, max(VAR_MIN, r.evv_noise_m_s**2))  # ExternalVisionVel::enforceMinimumVariance
        e_v, var, reset_var = np.zeros(2), v_var[:2], v_var[:2]
        if vf == "body":  # fused in the body frame: as NED with the variances rotated (attitude errors aside)
            c = dcm_from_quat(np.asarray(q if truth_q is None else truth_q, np.float64))
            e_v, var = (c @ v)[:2] - np.asarray(truth_v_ned_m_s, np.float64)[:2], ((c**2) @ v_var)[:2]
            reset_var = 5.0 * var  # EvVelBodyFrameFrd::resetVelocity bumps the variance ×5
            vf = vf if np.all(np.isfinite(c)) else ""  # no attitude to stand for the EKF's (pass truth_q)
        elif vf == "ned":
            e_v = v[:2] - np.asarray(truth_v_ned_m_s, np.float64)[:2]
        vel_v = self._ev_velocity(t_s, vf, e_v, var, reset_var, q_ok, starting, ev_reset, gnss, gnss_outage)
        pos_v = self._ev_position(t_s, pose, p[:2], p_var[:2], truth_p, q_ok, starting, ev_reset, gnss, gnss_outage)
        if q_ok:
            self._ev_prev_t, self._ev_prev_quality, self._ev_prev_reset = t_s, quality, reset_counter
        self.details[f"pos: {pos_v}"] += 1
        self.details[f"vel: {vel_v}"] += 1
        if not gnss_outage:
            return self._count(name, "GNSS healthy: not judged", gnss_outage)
        if pos_v.startswith("reset") or (vel_v.startswith("reset") and pos_v != "fused"):
            return self._count(name, pos_v if pos_v.startswith("reset") else vel_v, gnss_outage)
        used = {(True, True): "used", (True, False): "used (position only)", (False, True): "used (velocity only)"}
        verdict = used.get((pos_v == "fused", vel_v == "fused"))
        if verdict is None:
            verdict = vel_v if pos_v in ("off (EKF2_EV_CTRL)", "no position") else pos_v
        return self._count(name, verdict, gnss_outage)

    def _floored(self, var: F64Array, noise: float) -> F64Array:
        """UpdateExtVisionSample: the message's variances floored by the noise parameter's square if all finite."""
        if self.rules.ev_noise_md == 0 and np.all(np.isfinite(var)):
            return np.maximum(var, noise**2)
        return np.full(3, noise**2)

    def _ev_velocity(self, t_s: float, vf: str, e_v: F64Array, var: F64Array, reset_var: F64Array, q_ok: bool,
                     starting: bool, ev_reset: bool, gnss: bool, judged: bool) -> str:  # fmt: skip
        """controlEvVelFusion, horizontally; ``e_v`` the measurement's error against the truth (NED)."""
        r, st = self.rules, self.state
        if not r.ev_ctrl & EV_CTRL_VEL:
            return "off (EKF2_EV_CTRL)"
        if vf not in ("body", "ned"):
            self.ev_vel = False
            return "no velocity" if not vf else "LOCAL_FRD velocity: not modelled"
        ratio = (e_v - st.v_err_m_s) ** 2 / (max(r.evv_gate, 1.0) ** 2 * (st.P[:, 1, 1] + var))
        others = self._others(gnss, ev_pos=True, agp=True)  # isHorizontalAidingActive, but EV velocity itself
        if not self.ev_vel:
            if not (starting and (float(np.max(ratio)) < 0.1 or not others)):
                return self._not_starting(q_ok)
            self.ev_vel, self._vel_fused_t, self._vel_resets = True, t_s, EV_RESETS
            if not others:
                self._reset(1, e_v, reset_var, judged)
                return "reset (start)"
            return "started"
        if ev_reset and not others:
            if not q_ok:
                self.ev_vel = False
                return "stopped (reset_counter, quality)"
            self._vel_fused_t = t_s
            self._reset(1, e_v, reset_var, judged)
            return "reset (reset_counter)"
        verdict = "quality below EKF2_EV_QMIN"
        if q_ok:
            verdict = "fused" if self._fuse(1, e_v, var, ratio, judged) else "gated"
            self._vel_fused_t = t_s if verdict == "fused" else self._vel_fused_t
        if t_s - self._vel_fused_t > NO_AID_TIMEOUT_S:
            if self._vel_resets > 0 and q_ok:
                self._vel_resets -= 1  # in air
                self._vel_fused_t = t_s
                self._reset(1, e_v, reset_var, judged)
                return "reset (fusion failing)"
            self.ev_vel = False
            return "stopped (fusion failing)"
        return verdict

    def _ev_position(self, t_s: float, pose: str, meas: F64Array, mvar: F64Array, truth_p: F64Array, q_ok: bool,
                     starting: bool, ev_reset: bool, gnss: bool, judged: bool) -> str:  # fmt: skip
        """controlEvPosFusion, startEvPosFusion, updateEvPosFusion; ``meas`` in the sender's frame."""
        r, st = self.rules, self.state
        est = truth_p + st.p_err_m  # the EKF's horizontal position, in the mock's frame
        was_on = self._bias_on
        if pose != "ned":
            self._bias_on = False
            self._bias_reset()
            self.ev_pos = False
            return "no position" if not pose else "LOCAL_FRD pose: not modelled"
        self._bias_on = gnss
        if gnss:
            mvar = np.maximum(mvar, r.gps_p_noise_m**2)
        mvar = np.maximum(mvar, max(r.evp_noise_m**2, VAR_MIN))
        if not was_on and self._bias_on:
            if q_ok:
                self.bias_ne_m = meas - est
            elif self._others(gnss, ev_vel=True, agp=True):
                self.ev_pos = False
        if q_ok and self._bias_on:  # BiasEstimator::fuseBias, before the main filter's update
            self._bias_var_max = np.maximum(mvar, VAR_MIN)
            s = self.bias_var_m2 + np.maximum(mvar + st.P[:, 0, 0], VAR_MIN)
            innov = meas - est - self.bias_ne_m
            ok = innov**2 / (BIAS_GATE**2 * s) < 1.0
            k = np.where(ok, self.bias_var_m2 / s, 0.0)
            self.bias_ne_m = self.bias_ne_m + k * innov
            self.bias_var_m2 = np.clip(self.bias_var_m2 * (1.0 - k), 1e-8, self._bias_var_max)
        if not r.ev_ctrl & EV_CTRL_HPOS:
            self.ev_pos = False
            return "off (EKF2_EV_CTRL)"
        if not self.ev_pos:
            if not starting:
                return self._not_starting(q_ok)
            self.ev_pos, self._pos_fused_t, self._pos_resets = True, t_s, EV_RESETS
            if gnss:  # startEvPosFusion: relative to the EKF, with a bias
                self.bias_ne_m, self._bias_on = meas - est, True
                return "started"
            self._bias_reset()
            self._reset(0, meas - truth_p, mvar, judged)
            return "reset (start without GNSS: the raw EV position)"
        e_p = meas - self.bias_ne_m - truth_p
        if ev_reset or was_on != self._bias_on:
            if not q_ok:
                self.ev_pos = False
                return "stopped (reset, quality)"
            self._pos_fused_t = t_s
            cause = "reset_counter" if ev_reset else "GNSS back" if gnss else "GNSS lost: EV − bias the reference"
            if gnss:
                self.bias_ne_m = meas - est
                return f"bias reset ({cause})"
            self._reset(0, e_p, mvar, judged)
            return f"reset ({cause})"
        verdict = "quality below EKF2_EV_QMIN"
        if q_ok:
            obs_var = mvar + self.bias_var_m2
            ratio = (e_p - st.p_err_m) ** 2 / (max(r.evp_gate, 1.0) ** 2 * (st.P[:, 0, 0] + obs_var))
            verdict = "fused" if self._fuse(0, e_p, obs_var, ratio, judged) else "gated"
            if verdict == "fused":
                self._pos_fused_t = self._hpos_fused_t = t_s
        if t_s - self._pos_fused_t > NO_AID_TIMEOUT_S:
            if self._pos_resets > 0 and q_ok:
                self._pos_resets -= 1
                self._pos_fused_t = t_s
                if gnss and t_s - self._hpos_fused_t <= NO_AID_TIMEOUT_S:
                    self.bias_ne_m = meas - est
                    return "bias reset (fusion failing)"
                self._reset(0, e_p, mvar + (self.bias_var_m2 if gnss else 0.0), judged)  # the bias kept
                return "reset (fusion failing)"
            self.ev_pos = False
            return "stopped (fusion failing)"
        return verdict

    def _bias_reset(self) -> None:
        self.bias_ne_m, self.bias_var_m2 = np.zeros(2), np.zeros(2)

    def _others(self, gnss: bool, *, ev_pos: bool = False, ev_vel: bool = False, agp: bool = False) -> bool:
        """Whether GNSS or one of the sources named True is active (isOtherSourceOf…AidingThan)."""
        return gnss or (ev_pos and self.ev_pos) or (ev_vel and self.ev_vel) or (agp and self.agp_state == "active")

    @staticmethod
    def _not_starting(q_ok: bool) -> str:
        return "waiting to start (< 200 ms after the last sample)" if q_ok else "quality below EKF2_EV_QMIN"

    # ------------------------------------------------------------------------------------ the error state
    def _fuse(self, i: int, e: F64Array, var: F64Array, ratio: F64Array, judged: bool) -> bool:
        """Both axes of a position (``i`` = 0) or velocity (1) observation whose error is ``e``, if all test ratios
        pass (the aid source's innovation_rejected); into the state only in an outage (``judged``)."""
        if not np.all(ratio <= 1.0):
            return False
        if judged:
            st = self.state
            for axis in range(2):
                x = st.p_err_m if i == 0 else st.v_err_m_s
                st.fuse(axis, i, float(e[axis] - x[axis]), float(var[axis]))
        return True

    def _reset(self, i: int, e: F64Array, var: F64Array, judged: bool) -> None:
        """resetHorizontalPositionTo / resetVelocityTo: the state set to the measurement, its variance to ``var``,
        its correlations removed (uncorrelateCovarianceSetVariance)."""
        if judged:
            st = self.state
            (st.p_err_m if i == 0 else st.v_err_m_s)[:] = e
            st.P[:, i, 1 - i] = st.P[:, 1 - i, i] = 0.0
            st.P[:, i, i] = np.maximum(var, VAR_MIN)

    # ------------------------------------------------------------------------------------ GLOBAL_POSITION_SENSOR
    def global_position_sensor(self, *, t_s: float, fix_error_ne_m: FloatArray, eph_m: float, epv_m: float,
                               flags: int, gnss_outage: bool, sensor_id: int = 0) -> str:  # fmt: skip
        """One GLOBAL_POSITION_SENSOR: ``fix_error_ne_m`` its position's error against the truth [m], ``sensor_id``
        its ``id`` (the service sends 0)."""
        r, st, name = self.rules, self.state, "GLOBAL_POSITION_SENSOR"
        gnss = self._gnss(t_s, gnss_outage)
        if not r.agp_handler:
            return self._count(name, f"PX4 {r.release}: no handler for message 296", gnss_outage)
        if r.agp_id == 0 or sensor_id != r.agp_id:
            return self._count(name, "id is no enabled EKF2_AGPn_ID slot", gnss_outage)
        if self.agp_state != "stopped" and t_s - self._agp_push_t > AGP_DATA_TIMEOUT_S:
            self.agp_state = "stopped"
        self._agp_push_t = t_s
        if not r.agp_ctrl & AGP_CTRL_HPOS:
            self.agp_state = "stopped"
            return self._count(name, "off (EKF2_AGP_CTRL)", gnss_outage)
        e = np.asarray(fix_error_ne_m, np.float64)[:2]
        if not np.all(np.isfinite(e)):
            self.agp_state = "stopped"
            return self._count(name, "lat/lon not finite", gnss_outage)
        sigma = max(eph_m if math.isfinite(eph_m) else 0.0, r.agp_noise_m, 0.01)  # math::max drops a NaN eph
        var = np.full(2, sigma**2)
        ratio = (e - st.p_err_m) ** 2 / (max(r.agp_gate, 1.0) ** 2 * (st.P[:, 0, 0] + var))
        # isResetAllowed: EKF2_AGP_MODE 0 no other horizontal position source, 1 no other horizontal aiding
        blocked = self._others(gnss, ev_pos=True, ev_vel=r.agp_mode == 1)
        fused = self._fuse(0, e, var, ratio, gnss_outage)
        verdict = "used" if fused else "gated"
        if fused:
            self._agp_fused_t = self._hpos_fused_t = t_s
        if self.agp_state != "active":  # stopped / starting
            self.agp_state = "active" if fused or not blocked else "starting"
            if not fused and not blocked:
                self._agp_fused_t = t_s
                self._reset(0, e, var, gnss_outage)
                verdict = "reset (start)"
        elif t_s - self._agp_fused_t > RESET_TIMEOUT_S:
            if blocked:
                self.agp_state, verdict = "stopped", "stopped (fusion timeout, reset not allowed)"
            else:
                self._agp_fused_t = t_s
                self._reset(0, e, var, gnss_outage)
                verdict = "reset (fusion timeout)"
        return self._count(name, verdict if gnss_outage else "GNSS healthy: not judged", gnss_outage)
