"""Whether ArduPilot would use the companion's GPS_INPUT, and what it would make of it: a judge inside the mock.

The mock autopilot's own position estimate drifts through a GNSS outage (:class:`DeadReckoningDrift`). This
module decides, by ArduPilot's own rules, which GPS_INPUT fixes its EKF3 would fuse, and fuses those into the
mock's estimate, so that a test can tell the estimate the autopilot would fly on with the service from the one
without it. Rules, from ArduPilot's sources:

* ``AP_GPS_MAV.cpp``: GPS_INPUT feeds the GPS instance whose ``GPSn_TYPE`` is 14 (``gps_id``); its
  ``fix_type`` becomes the instance's status.
* ``AP_GPS.cpp`` ``update_primary`` picks the instance EKF3 reads (``AP_NavEKF3_Measurements.cpp``
  ``update_gps_selection``: ``selected_gps = gps.primary_sensor()``, the blended instance when blending; the
  ``EK3_AFFINITY`` GPS bit, default off, is not modelled), by ``GPS_AUTO_SWITCH`` (``var_info`` ``_AUTO_SWITCH``):

  - 1, use best (the default): the instance with the higher status is primary, so with the real receiver's fix
    lost the MAV instance is. A tie keeps the current primary until the other has more satellites (5 s / 20 s
    after the last swap); GPS_INPUT carries 0 satellites, so the judge gives ties to the real receiver.
  - 0, use primary: always ``GPS_PRIMARY`` (default 0, the real receiver): the MAV instance (``gps_id`` 1) is
    never read, outage or not. 3 (the old "use second") is converted in ``AP_GPS::init`` to 0 with
    ``GPS_PRIMARY`` = 1 when ``GPS_PRIMARY`` was not set: the MAV instance always.
  - 4, use primary if 3-D fix or better: ``GPS_PRIMARY`` while its status is ≥ 3-D, else use best (so with
    ``GPS_PRIMARY`` 0 as 1 through an outage).
  - 2, blend: ``AP_GPS_Blended.cpp`` ``_calc_weights`` fails (and ``update_primary`` falls back to use best, after
    one update through its "switch away from blended" rule, which admits only a 3-D fix) when either receiver's
    status is ≤ NO_FIX, when any accuracy is infinite, when the two receivers' last messages are ≥ 2 ·
    ``GPS_RATE_MS`` apart (default 200 ms, which is also the cap: 0.4 s), or when no metric of ``GPS_BLEND_MASK``
    (default 5: bit 0 horizontal position, bit 1 vertical position, bit 2 speed accuracy) can be used: a metric
    is dropped as soon as one receiver taking part (horizontal: status ≥ 2-D; vertical, speed: ≥ 3-D) does
    not report it (> 0). Each metric used weighs the receivers by inverse variance (accuracies ≥ 1 mm), the
    weight is their mean. ``calc_weights`` keeps a health counter: +10 per failed update (at most 100), −1 per
    good one, blending while it is < 50 (ArduPlane runs ``AP_GPS::update`` at 50 Hz); any other setting zeroes
    it. So through an outage (the real receiver without a fix) blending is off and the MAV instance is primary
    by use best, exactly as with 1; blending resumes ~1 s (51 good updates) after both have fixes again.
    ``calc_state``: the blended instance's status is the higher one, position and velocity the weighted means,
    its accuracies the best (smallest) reported, its satellites the largest non-zero count (the real
    receiver's: GPS_INPUT's 0 satellites change nothing there). Blending is also off with a moving-baseline
    RTK pair (not modelled).
* ``AP_NavEKF3_Measurements.cpp`` ``readGpsData``: a status below 3-D is not read. The accuracies are clamped:
  position to [``EK3_POSNE_M_NSE``, 100 m], speed to [``EK3_VELNE_M_NSE``, 50 m/s]. ``gpsNoiseScaler`` is
  1 with ≥ 6 satellites in absolute aiding, 1.4 with 5, else 2 (GPS_INPUT carries no satellites: 2).
* ``AP_NavEKF3_PosVelFusion.cpp`` ``FuseVelPosNED``: fused with R = (gpsNoiseScaler · accuracy)², velocity before
  position. Gated before the scaler, one test ratio over N and E each: position Σi² < gate² · Σ(P + accuracy²),
  velocity Σi² < gate² · Σ(P + EK3_VELNE_M_NSE²) (``R_OBS_DATA_CHECKS``: not the reported speed accuracy; its
  manoeuvre term ``gpsNEVelVarAccScale · accNavMag`` and the vertical velocity in the ratio are not modelled),
  gate = ``EK3_POS_I_GATE`` / ``EK3_VEL_I_GATE`` (default 500: 5σ). A passing position while P_NN + P_EE >
  ``EK3_GLITCH_RAD``² (25 m) resets onto the fix (``ResetPosition``, P = (EK3_GLITCH_RAD / 2)²) instead.
* ``AP_NavEKF3_Control.cpp`` ``setAidingMode``: a plane fusing an airspeed sensor stays in absolute aiding
  through a GNSS loss and takes GPS back without further checks; without one it drops to ``AID_NONE`` and
  returns only when ``readyToUseGPS()`` holds, which needs ``gpsGoodToAlign``, 10 s of passed GPS checks
  (``calcGpsGoodToAlign``: among them ≥ 6 satellites), which a GPS_INPUT with no satellites never passes (but
  ``calcGpsGoodToAlign`` sets ``gpsGoodToAlign`` unchecked for a plane in flight without a compass: not modelled,
  the judge assumes a compass).
* ``AP_NavEKF3_VehicleStatus.cpp`` ``calcGpsGoodForFlight``, run by ``readGpsData`` at every 3-D fix it reads (on
  the ground or in flight), sets ``gpsSpdAccPass`` (the reported speed accuracy through a low-pass, 0.2 per read,
  held in [0, 10], then a peak hold decaying with τ = 10 s: fails above 1.5 m/s, passes again below 1.0),
  ``ekfInnovationsPass`` (fails after 1 s without ``velTestRatio`` and ``posTestRatio`` both < 1, passes after 10 s
  without either > 0.7) and ``gpsAccuracyGood`` (both). No fusion decision reads them: ``readyToUseGPS`` needs
  ``gpsGoodToAlign``, ``SelectVelPosFusion``/``FuseVelPosNED`` gate on the test ratios alone. They feed
  ``updateFilterStatus`` (``gps_glitching`` = not ``gpsAccuracyGood`` in absolute aiding: EKF_STATUS_REPORT,
  AP_Notify, arming checks), ``detectFlight`` (not ``gpsSpdAccPass`` stops the EKF-GSF yaw estimator, the source of
  emergency yaw resets; yaw is not modelled) and the vertical only, not modelled: ``selectHeightForFusion`` takes
  GPS as height source (``EK3_SRC1_POSZ`` 3, ArduPlane's default is 1, baro) only while ``gpsAccuracyGood``, and
  ``correctEkfOriginHeight`` (``EK3_OGN_HGT_MASK``) too. So the judge keeps the speed-accuracy half for information
  only (``spd_acc_pass``, ``spd_acc_fail_reads``), at each GPS_INPUT read as primary; it never changes a verdict.

The estimate's error is a linear model per horizontal axis (position and velocity error; the velocity a
random walk, :class:`DeadReckoningDrift`), so its Kalman filter here is exact for the drift: what remains
unmodelled is what the service's fixes get wrong, and that is what is judged. Not modelled: the vertical, the
5 s decaying envelope readGpsData puts on the reported accuracies, and the fix's lag (``GPSn_DELAY_MS``): each fix
is compared with the truth when it arrives. A blended fix is counted, never fused: blending needs the real
receiver's fix, and outside outages the mock's estimate follows GNSS. The blend's health counter is advanced
only at each GPS_INPUT (given its time ``t_s``), taking the conditions then as held since the one before,
except that the MAV instance's data goes stale (≥ 0.4 s old) between two GPS_INPUTs more than 0.4 s apart;
without ``t_s`` the counter is taken as settled (blending iff the weights can be formed now).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vdm_aero._typing import F64Array

__all__ = ["Ekf3GpsRules", "GpsInputJudge"]

GPS_FIX_3D = mavlink2.GPS_FIX_TYPE_3D_FIX
GPS_FIX_2D = mavlink2.GPS_FIX_TYPE_2D_FIX
GPS_NO_FIX = mavlink2.GPS_FIX_TYPE_NO_FIX
GPS_INPUT_IGNORE_VEL_HORIZ = mavlink2.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ
GPS_INPUT_IGNORE_HORIZ_ACC = mavlink2.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
GPS_INPUT_IGNORE_VERT_ACC = mavlink2.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY
GPS_INPUT_IGNORE_SPEED_ACC = mavlink2.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
POS_ACC_MAX_M = 100.0  # readGpsData's clamp of the horizontal accuracy
SPEED_ACC_MAX_M_S = 50.0  # ... and of the speed accuracy
# GPS_AUTO_SWITCH (AP_GPS.cpp var_info): 0 use primary, 1 use best, 2 blend, 3 old "use second", 4 primary if 3-D
AUTO_SWITCH_NONE, AUTO_SWITCH_BEST, AUTO_SWITCH_BLEND, AUTO_SWITCH_SECOND, AUTO_SWITCH_PRIMARY_3D = 0, 1, 2, 3, 4
BLEND_MASK_HPOS, BLEND_MASK_VPOS, BLEND_MASK_SPD = 1, 2, 4  # GPS_BLEND_MASK bits (AP_GPS_Blended.cpp)
BLEND_MAX_GAP_S = 0.4  # _calc_weights: last messages < 2 · GPS_RATE_MS apart (default 200 ms, also its cap)
GPS_UPDATE_HZ = 50.0  # ArduPlane runs AP_GPS::update (update_primary → calc_weights) at 50 Hz
BLEND_FAIL_STEP, BLEND_HEALTH_MAX, BLEND_HEALTH_OFF = 10, 100, 50  # calc_weights' health counter
# calcGpsGoodForFlight's speed-accuracy filter: low-pass coefficient per read, peak hold decay, state cap, hysteresis
SACC_LPF_ALPHA, SACC_PEAK_TAU_S, SACC_FILT_MAX_M_S = 0.2, 10.0, 10.0
SACC_FAIL_M_S, SACC_PASS_M_S = 1.5, 1.0  # gpsSpdAccPass: false above 1.5 m/s, true again below 1.0 m/s


@dataclass(frozen=True)
class Ekf3GpsRules:
    """The ArduPilot parameters the judge reads, at their defaults (``EK3_*``, ``GPS_*``) and as docs/service.md
    sets them."""

    gps_id: int = 1  # the instance with GPSn_TYPE = 14 (GPS2_TYPE, the service's outputs.gps_id)
    posne_m_nse: float = 0.5  # EK3_POSNE_M_NSE [m]
    velne_m_nse: float = 0.3  # EK3_VELNE_M_NSE [m/s]
    gate_sigma: float = 5.0  # EK3_POS_I_GATE = EK3_VEL_I_GATE = 500 (hundredths of a σ)
    glitch_rad_m: float = 25.0  # EK3_GLITCH_RAD: a passing fix with P_NN + P_EE beyond its square resets onto it
    # GPS_AUTO_SWITCH: 0 use primary (GPS_PRIMARY always), 1 use best (default), 2 blend, 3 old "use second"
    # (AP_GPS::init converts it to 0 with GPS_PRIMARY 1), 4 use GPS_PRIMARY while it has a 3-D fix, else best
    auto_switch: int = AUTO_SWITCH_BEST
    blend_mask: int = BLEND_MASK_HPOS | BLEND_MASK_SPD  # GPS_BLEND_MASK (default 5: horizontal, speed accuracy)
    primary: int = 0  # GPS_PRIMARY (0 first, 1 second instance; others are taken as 0, as update_primary does)

    def __post_init__(self) -> None:
        if self.auto_switch not in (0, 1, 2, 3, 4):
            raise ValueError(f"GPS_AUTO_SWITCH {self.auto_switch}: ArduPilot has 0, 1, 2, 4 (and the old 3)")


@dataclass(frozen=True)
class _Receiver:
    """What _calc_weights reads of one instance: its status and accuracies (None: not reported)."""

    status: int
    h_acc: float | None
    v_acc: float | None
    s_acc: float | None


def _blend_weights(a: _Receiver, b: _Receiver, mask: int, gap_s: float) -> tuple[tuple[float, float] | None, str]:
    """``AP_GPS_Blended::_calc_weights`` for two receivers whose last messages are ``gap_s`` apart: their weights,
    or None and why not."""
    rx = (a, b)
    if any(r.status <= GPS_NO_FIX for r in rx):
        return None, "a receiver without a fix"
    if any(x is not None and math.isinf(x) for r in rx for x in (r.h_acc, r.v_acc, r.s_acc)):
        return None, "an accuracy is infinite"
    if not gap_s < BLEND_MAX_GAP_S:
        return None, "their last fixes ≥ 0.4 s apart"
    weights = [0.0, 0.0]
    used = 0
    for bit, min_status, accs in ((BLEND_MASK_HPOS, GPS_FIX_2D, (a.h_acc, b.h_acc)),
                                  (BLEND_MASK_VPOS, GPS_FIX_3D, (a.v_acc, b.v_acc)),
                                  (BLEND_MASK_SPD, GPS_FIX_3D, (a.s_acc, b.s_acc))):  # fmt: skip
        if not mask & bit:
            continue
        sum_sq = 0.0
        for r, x in zip(rx, accs, strict=True):
            if r.status >= min_status:
                if x is not None and x > 0.0:
                    sum_sq += x * x
                else:  # one receiver taking part does not report it: the metric is not used
                    sum_sq = 0.0
                    break
        if not sum_sq > 0.0:
            continue
        w = [sum_sq / x**2 if r.status >= min_status and x is not None and x >= 0.001 else 0.0
             for r, x in zip(rx, accs, strict=True)]  # fmt: skip
        total = sum(w)
        if total > 0.0:
            weights = [acc + wi / total for acc, wi in zip(weights, w, strict=True)]
            used += 1
    if used == 0:
        return None, "no accuracy to weigh by GPS_BLEND_MASK"
    return (weights[0] / used, weights[1] / used), ""


def _noise_scaler(satellites: int, absolute: bool) -> float:
    if satellites >= 6 and absolute:
        return 1.0
    if satellites == 5 and absolute:
        return 1.4
    return 2.0


class GpsInputJudge:
    """The mock's estimate error with the fixes ArduPilot would fuse (``error_*``) and without them
    (``free_*``), both driven by the same drift; and the count of fixes used or refused, by reason (``verdicts``;
    ``outage_verdicts`` the same, of what came during GNSS outages)."""

    def __init__(self, rules: Ekf3GpsRules, *, velocity_sigma_m_s: float, random_walk_m_s_per_sqrt_s: float) -> None:
        self.rules = rules
        self._v0_var = velocity_sigma_m_s**2
        self._q = random_walk_m_s_per_sqrt_s**2
        self.p_err_m = np.zeros(2)  # the fused estimate's horizontal error (N, E)
        self.v_err_m_s = np.zeros(2)
        self.P = np.zeros((2, 2, 2))  # per axis: covariance of (position, velocity) error
        self.verdicts: Counter[str] = Counter()
        self.outage_verdicts: Counter[str] = Counter()
        self.outage_end: list[dict[str, float]] = []  # per outage: the errors at its last step [m]
        self._in_outage = False
        self.blend_health = 0  # AP_GPS_Blended::_blend_health_counter (GPS_AUTO_SWITCH 2)
        self._blend_t_s: float | None = None  # the last GPS_INPUT the counter was advanced to
        # calcGpsGoodForFlight's speed-accuracy half (informational: no fusion decision reads it)
        self.sacc_lpf_m_s = 0.0  # sAccFilterState1
        self.sacc_peak_m_s = 0.0  # sAccFilterState2
        self.spd_acc_pass = True  # gpsSpdAccPass
        self.spd_acc_fail_reads = 0  # GPS_INPUTs read while gpsSpdAccPass is false
        self._sacc_t_s: float | None = None

    # ------------------------------------------------------------------------------------ the drift
    def outage_started(self, v0_m_s: F64Array) -> None:
        """The drift's velocity error drawn at the outage's start (the fused estimate starts where the free
        one does: both converged on GNSS before it)."""
        self.v_err_m_s = self.v_err_m_s + np.asarray(v0_m_s, float)[:2]
        self.P = np.zeros((2, 2, 2))
        self.P[:, 1, 1] = self._v0_var
        self._in_outage = True
        # the real receiver's fix is lost: calc_weights fails at every update (+10 each) for the second before the
        # service's first GPS_INPUT, so the blend's health counter is saturated
        self.blend_health = BLEND_HEALTH_MAX
        # the real receiver's reads before it (not given) taken as passing with a negligible speed accuracy
        self.sacc_lpf_m_s = self.sacc_peak_m_s = 0.0
        self.spd_acc_pass = True
        self._sacc_t_s = None

    def propagate(self, dt_s: float, dv_m_s: F64Array) -> None:
        """One step of the drift: ``dv_m_s`` the random walk's increment (the free estimate's too)."""
        self.v_err_m_s = self.v_err_m_s + np.asarray(dv_m_s, float)[:2]
        self.p_err_m = self.p_err_m + self.v_err_m_s * dt_s
        f = np.array([[1.0, dt_s], [0.0, 1.0]])
        q = self._q * np.array([[dt_s**3 / 3.0, dt_s**2 / 2.0], [dt_s**2 / 2.0, dt_s]])
        self.P = f @ self.P @ f.T + q

    def decay(self, factor: float) -> None:
        """GNSS back: the estimate converges on it as the free one does (DeadReckoningDrift.recovery_tau_s)."""
        self.p_err_m = self.p_err_m * factor
        self.v_err_m_s = np.zeros(2)
        self.P = np.zeros((2, 2, 2))

    def outage_ended(self, free_error_m: F64Array) -> None:
        self.outage_end.append({"with_service_m": float(np.hypot(*self.p_err_m)),
                                "without_m": float(np.hypot(*np.asarray(free_error_m, float)[:2]))})  # fmt: skip
        self._in_outage = False

    # ------------------------------------------------------------------------------------ the fixes
    def gps_input(self, *, gps_id: int, fix_type: int, satellites: int, ignore_flags: int,
                  fix_error_ne_m: F64Array, vel_error_ne_m_s: F64Array, h_acc_m: float, speed_acc_m_s: float,
                  airspeed_aiding: bool, v_acc_m: float = 0.0, real_fix_type: int | None = None,
                  real_h_acc_m: float | None = None, real_v_acc_m: float | None = None,
                  real_speed_acc_m_s: float | None = None, real_age_s: float = 0.0,
                  t_s: float | None = None) -> str:  # fmt: skip
        """One GPS_INPUT: its verdict ("used" or why not), counted. Errors are the fix's against the truth [m, m/s].

        The real receiver (the other instance): ``real_fix_type`` its status (GPS_FIX_TYPE; None: no fix during
        an outage, else a fix at least as good as the GPS_INPUT's, the real receiver primary), its accuracies
        [m, m, m/s] (None: not reported) and ``real_age_s`` the age of its last message when this GPS_INPUT
        arrives. ``v_acc_m`` is the GPS_INPUT's vertical accuracy, ``t_s`` its arrival time (the blend's health
        counter; None: settled). All of these matter for ``GPS_AUTO_SWITCH`` 2 only, ``real_fix_type`` for all."""
        if real_fix_type is None:
            real_fix_type = GPS_NO_FIX if self._in_outage else max(GPS_FIX_3D, fix_type)
        real = _Receiver(real_fix_type, real_h_acc_m, real_v_acc_m, real_speed_acc_m_s)
        verdict = self._judge(gps_id, fix_type, satellites, ignore_flags, np.asarray(fix_error_ne_m, float),
                              np.asarray(vel_error_ne_m_s, float), h_acc_m, speed_acc_m_s, airspeed_aiding,
                              v_acc_m, real, real_age_s, t_s)  # fmt: skip
        self.verdicts[verdict] += 1
        if self._in_outage:
            self.outage_verdicts[verdict] += 1
        return verdict

    def _blend_healthy(self, ok: bool, t_s: float | None) -> bool:
        """``AP_GPS_Blended::calc_weights``' counter, advanced over the 50 Hz updates since the last GPS_INPUT: with
        the weights formed now, the updates that saw the last GPS_INPUT ≥ 0.4 s old failed (the timing check)."""
        if t_s is None:
            self.blend_health = 0 if ok else BLEND_HEALTH_MAX
        else:
            n = 1 if self._blend_t_s is None else max(1, round((t_s - self._blend_t_s) * GPS_UPDATE_HZ))
            self._blend_t_s = t_s
            if ok:
                stale = max(0, n - round(BLEND_MAX_GAP_S * GPS_UPDATE_HZ))
                h = max(0, self.blend_health - (n - stale - 1))  # the fresh ones before
                h = min(BLEND_HEALTH_MAX, h + BLEND_FAIL_STEP * stale)
                self.blend_health = max(0, h - 1)  # and the one that reads this GPS_INPUT
            else:
                self.blend_health = min(BLEND_HEALTH_MAX, self.blend_health + BLEND_FAIL_STEP * n)
        return self.blend_health < BLEND_HEALTH_OFF

    def _select(self, fix_type: int, ignore: int, h_acc_m: float, v_acc_m: float, speed_acc_m_s: float,
                real: _Receiver, real_age_s: float, t_s: float | None) -> tuple[bool, str]:  # fmt: skip
        """``AP_GPS::update_primary``: whether the MAV instance is primary, or the verdict if it is not read."""
        r = self.rules
        switch, primary = r.auto_switch, r.primary if r.primary in (0, 1) else 0
        if switch == AUTO_SWITCH_SECOND:  # AP_GPS::init, GPS_PRIMARY not set
            switch, primary = AUTO_SWITCH_NONE, 1
        primary_is_mav = primary == r.gps_id
        if switch == AUTO_SWITCH_NONE:
            return (True, "") if primary_is_mav else (False, "not primary (GPS_AUTO_SWITCH 0: GPS_PRIMARY always)")
        if switch == AUTO_SWITCH_PRIMARY_3D:
            if primary_is_mav and fix_type >= GPS_FIX_3D:
                return True, ""
            if not primary_is_mav and real.status >= GPS_FIX_3D:
                return False, "not primary (GPS_AUTO_SWITCH 4: GPS_PRIMARY has a 3-D fix)"
        why = ""
        if switch == AUTO_SWITCH_BLEND:
            mav = _Receiver(fix_type, None if ignore & GPS_INPUT_IGNORE_HORIZ_ACC else h_acc_m,
                            None if ignore & GPS_INPUT_IGNORE_VERT_ACC else v_acc_m,
                            None if ignore & GPS_INPUT_IGNORE_SPEED_ACC else speed_acc_m_s)  # fmt: skip
            weights, why = _blend_weights(real, mav, r.blend_mask, real_age_s)
            if self._blend_healthy(weights is not None, t_s) and weights is not None:
                return False, f"blended (weight {weights[1]:.2f})"
            why = why or f"health counter ≥ {BLEND_HEALTH_OFF}"
        # use best: the higher status (a tie stays with the current primary: taken as the real receiver)
        if fix_type > real.status:
            return True, ""
        if switch == AUTO_SWITCH_BLEND and fix_type > GPS_NO_FIX and real.status > GPS_NO_FIX:
            return False, f"not blended ({why}): the real receiver is primary"
        return False, ""

    def _judge(self, gps_id: int, fix_type: int, satellites: int, ignore: int, e_p: F64Array, e_v: F64Array,
               h_acc_m: float, speed_acc_m_s: float, absolute: bool, v_acc_m: float, real: _Receiver,
               real_age_s: float, t_s: float | None) -> str:  # fmt: skip
        r = self.rules
        if gps_id != r.gps_id:
            return "not the MAV instance (gps_id)"
        primary, why = self._select(fix_type, ignore, h_acc_m, v_acc_m, speed_acc_m_s, real, real_age_s, t_s)
        if why:
            return why
        if fix_type < GPS_FIX_2D:
            return "no fix (readGpsData reads 3-D only)" if primary else "no fix (not primary)"
        if fix_type < GPS_FIX_3D:
            return "2-D fix (readGpsData reads 3-D only)"
        if primary:  # readGpsData reads it and runs calcGpsGoodForFlight (informational)
            self._spd_acc_check(ignore, speed_acc_m_s, t_s)
        if not absolute:
            return "AID_NONE: gpsGoodToAlign fails (satellites < 6)"
        if not primary:
            return "GNSS healthy (the real receiver is primary)"
        if not self._in_outage:
            return "primary outside an outage (not fused: the estimate follows GNSS)"
        scale = _noise_scaler(satellites, absolute)
        acc = h_acc_m if not ignore & GPS_INPUT_IGNORE_HORIZ_ACC and math.isfinite(h_acc_m) and h_acc_m > 0 else 0.0
        acc_p = min(max(acc, r.posne_m_nse), POS_ACC_MAX_M)  # R_OBS[3] = R_OBS_DATA_CHECKS[3], before the scaler
        use_vel = not ignore & GPS_INPUT_IGNORE_VEL_HORIZ
        sp = speed_acc_m_s if not ignore & GPS_INPUT_IGNORE_SPEED_ACC and speed_acc_m_s > 0 else 0.0
        acc_v = min(max(sp, r.velne_m_nse), SPEED_ACC_MAX_M_S)  # R_OBS[0]
        # FuseVelPosNED: one test ratio over N and E for the position and one for the velocity, against the
        # variances before gpsNoiseScaler; the velocity's R_OBS_DATA_CHECKS is EK3_VELNE_M_NSE's, not the accuracy
        # reported ("we don't want the acceptance radius to increase with reported GPS accuracy")
        vel_check = min(max(r.velne_m_nse, 0.05), 5.0) ** 2
        pos_ok = self._gate(e_p - self.p_err_m, self.P[:, 0, 0], acc_p**2)
        vel_ok = use_vel and self._gate(e_v - self.v_err_m_s, self.P[:, 1, 1], vel_check)
        if not pos_ok and not vel_ok:
            return "gated (innovation > 5σ)"
        reset = pos_ok and float(self.P[0, 0, 0] + self.P[1, 0, 0]) > r.glitch_rad_m**2
        if reset:  # ResetPosition onto the fix, P = (EK3_GLITCH_RAD / 2)² per axis, the fix not fused
            self.p_err_m = np.asarray(e_p, float).copy()
            self.P[:, 0, :] = 0.0
            self.P[:, :, 0] = 0.0
            self.P[:, 0, 0] = (0.5 * r.glitch_rad_m) ** 2
        for axis in range(2):  # the fusion's R is scaled (R_OBS *= gpsNoiseScaler²), velocity first
            if vel_ok:
                self.fuse(axis, 1, e_v[axis] - self.v_err_m_s[axis], (scale * acc_v) ** 2)
            if pos_ok and not reset:
                self.fuse(axis, 0, e_p[axis] - self.p_err_m[axis], (scale * acc_p) ** 2)
        if reset:
            return "reset (position variance beyond EK3_GLITCH_RAD)"
        return "used" if pos_ok else "used (velocity only)"

    def _spd_acc_check(self, ignore: int, speed_acc_m_s: float, t_s: float | None) -> None:
        """``calcGpsGoodForFlight``'s speed-accuracy filter and ``gpsSpdAccPass``, at one read (``t_s`` its time; None:
        the filters taken as settled at this accuracy). Informational: it changes no verdict (module docstring)."""
        raw = speed_acc_m_s if not ignore & GPS_INPUT_IGNORE_SPEED_ACC and speed_acc_m_s > 0 else 0.0
        if t_s is None:
            self.sacc_lpf_m_s = self.sacc_peak_m_s = min(raw, SACC_FILT_MAX_M_S)
        else:
            dt = 0.0 if self._sacc_t_s is None else t_s - self._sacc_t_s
            self._sacc_t_s = t_s
            decay = 1.0 - min(max(dt / SACC_PEAK_TAU_S, 0.0), 1.0)
            lpf = SACC_LPF_ALPHA * raw + (1.0 - SACC_LPF_ALPHA) * self.sacc_lpf_m_s
            self.sacc_lpf_m_s = min(max(lpf, 0.0), SACC_FILT_MAX_M_S)
            self.sacc_peak_m_s = max(self.sacc_lpf_m_s, decay * self.sacc_peak_m_s)
        if self.sacc_peak_m_s > SACC_FAIL_M_S:
            self.spd_acc_pass = False
        elif self.sacc_peak_m_s < SACC_PASS_M_S:
            self.spd_acc_pass = True
        if not self.spd_acc_pass:
            self.spd_acc_fail_reads += 1

    def _gate(self, innov: F64Array, var: F64Array, r: float) -> bool:
        """FuseVelPosNED's test ratio over both horizontal axes: Σ innovation² < gate² · Σ (P + R)."""
        return bool(np.sum(innov**2) < self.rules.gate_sigma**2 * float(np.sum(var + r)))

    def fuse(self, axis: int, i: int, innov: float, r: float) -> None:
        """One scalar Kalman update of a direct observation of the position (``i`` = 0) or velocity (1) error on one
        horizontal axis, innovation ``innov`` and variance ``r`` (FuseVelPosNED's sequential fusion; the ExternalNav
        judge, sim/sitl/extnav_judge.py, fuses into the same state)."""
        p = self.P[axis]
        s = p[i, i] + r
        k = p[:, i] / s
        x = np.array([self.p_err_m[axis], self.v_err_m_s[axis]]) + k * innov
        self.p_err_m[axis], self.v_err_m_s[axis] = x
        self.P[axis] = p - np.outer(k, p[i, :])
