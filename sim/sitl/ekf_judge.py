"""Whether ArduPilot would use the companion's GPS_INPUT, and what it would make of it: a judge inside the mock.

The mock autopilot's own position estimate drifts through a GNSS outage (:class:`DeadReckoningDrift`). This
module decides, by ArduPilot's own rules, which GPS_INPUT fixes its EKF3 would fuse, and fuses those into the
mock's estimate, so that a test can tell the estimate the autopilot would fly on with the service from the one
without it. Rules, from ArduPilot's sources:

* ``AP_GPS_MAV.cpp``: GPS_INPUT feeds the GPS instance whose ``GPSn_TYPE`` is 14 (``gps_id``); its
  ``fix_type`` becomes the instance's status.
* ``AP_GPS.cpp`` (``GPS_AUTO_SWITCH`` = 1, use best): with the real receiver's fix lost, the instance with the
  better status is primary.
* ``AP_NavEKF3_Measurements.cpp`` ``readGpsData``: a status below 3-D is not read. The accuracies are clamped:
  position to [``EK3_POSNE_M_NSE``, 100 m], speed to [``EK3_VELNE_M_NSE``, 50 m/s]. ``gpsNoiseScaler`` is
  1 with ≥ 6 satellites in absolute aiding, 1.4 with 5, else 2 (GPS_INPUT carries no satellites: 2).
* ``AP_NavEKF3_PosVelFusion.cpp`` ``FuseVelPosNED``: R = (gpsNoiseScaler · accuracy)²; a position or velocity
  innovation beyond ``EK3_POS_I_GATE`` / ``EK3_VEL_I_GATE`` (default 500: 5σ) is rejected.
* ``AP_NavEKF3_Control.cpp`` ``setAidingMode``: a plane fusing an airspeed sensor stays in absolute aiding
  through a GNSS loss and takes GPS back without further checks; without one it drops to ``AID_NONE`` and
  returns only when ``readyToUseGPS()`` holds, which needs ``gpsGoodToAlign``, 10 s of passed GPS checks
  (``calcGpsGoodToAlign``: among them ≥ 6 satellites), which a GPS_INPUT with no satellites never passes.

The estimate's error is a linear model per horizontal axis (position and velocity error; the velocity a
random walk, :class:`DeadReckoningDrift`), so its Kalman filter here is exact for the drift: what remains
unmodelled is what the service's fixes get wrong, and that is what is judged. Not modelled: the vertical, the
5 s decaying envelope readGpsData puts on the reported accuracies, and the fix's lag (``GPSn_DELAY_MS``): each fix
is compared with the truth when it arrives.
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
GPS_INPUT_IGNORE_VEL_HORIZ = mavlink2.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ
GPS_INPUT_IGNORE_HORIZ_ACC = mavlink2.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
GPS_INPUT_IGNORE_SPEED_ACC = mavlink2.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
POS_ACC_MAX_M = 100.0  # readGpsData's clamp of the horizontal accuracy
SPEED_ACC_MAX_M_S = 50.0  # ... and of the speed accuracy


@dataclass(frozen=True)
class Ekf3GpsRules:
    """The ArduPilot parameters the judge reads, at their defaults (``EK3_*``) and as docs/service.md sets them."""

    gps_id: int = 1  # the instance with GPSn_TYPE = 14 (GPS2_TYPE, the service's outputs.gps_id)
    posne_m_nse: float = 0.5  # EK3_POSNE_M_NSE [m]
    velne_m_nse: float = 0.3  # EK3_VELNE_M_NSE [m/s]
    gate_sigma: float = 5.0  # EK3_POS_I_GATE = EK3_VEL_I_GATE = 500 (hundredths of a σ)


def _noise_scaler(satellites: int, absolute: bool) -> float:
    if satellites >= 6 and absolute:
        return 1.0
    if satellites == 5 and absolute:
        return 1.4
    return 2.0


class GpsInputJudge:
    """The mock's estimate error with the fixes ArduPilot would fuse (``error_*``) and without them
    (``free_*``), both driven by the same drift; and the count of fixes used or refused, by reason."""

    def __init__(self, rules: Ekf3GpsRules, *, velocity_sigma_m_s: float, random_walk_m_s_per_sqrt_s: float) -> None:
        self.rules = rules
        self._v0_var = velocity_sigma_m_s**2
        self._q = random_walk_m_s_per_sqrt_s**2
        self.p_err_m = np.zeros(2)  # the fused estimate's horizontal error (N, E)
        self.v_err_m_s = np.zeros(2)
        self.P = np.zeros((2, 2, 2))  # per axis: covariance of (position, velocity) error
        self.verdicts: Counter[str] = Counter()
        self.outage_end: list[dict[str, float]] = []  # per outage: the errors at its last step [m]
        self._in_outage = False

    # ------------------------------------------------------------------------------------ the drift
    def outage_started(self, v0_m_s: F64Array) -> None:
        """The drift's velocity error drawn at the outage's start (the fused estimate starts where the free
        one does: both converged on GNSS before it)."""
        self.v_err_m_s = self.v_err_m_s + np.asarray(v0_m_s, float)[:2]
        self.P = np.zeros((2, 2, 2))
        self.P[:, 1, 1] = self._v0_var
        self._in_outage = True

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
                  airspeed_aiding: bool) -> str:  # fmt: skip
        """One GPS_INPUT while the real receiver has no fix: its verdict ("used" or why not), counted. Errors are
        the fix's against the truth [m, m/s]."""
        verdict = self._judge(gps_id, fix_type, satellites, ignore_flags, np.asarray(fix_error_ne_m, float),
                              np.asarray(vel_error_ne_m_s, float), h_acc_m, speed_acc_m_s, airspeed_aiding)  # fmt: skip
        self.verdicts[verdict] += 1
        return verdict

    def _judge(self, gps_id: int, fix_type: int, satellites: int, ignore: int, e_p: F64Array, e_v: F64Array,
               h_acc_m: float, speed_acc_m_s: float, absolute: bool) -> str:  # fmt: skip
        r = self.rules
        if gps_id != r.gps_id:
            return "not the MAV instance (gps_id)"
        if fix_type < GPS_FIX_2D:
            return "no fix (not primary)"
        if fix_type < GPS_FIX_3D:
            return "2-D fix (readGpsData reads 3-D only)"
        if not absolute:
            return "AID_NONE: gpsGoodToAlign fails (satellites < 6)"
        if not self._in_outage:
            return "GNSS healthy (the real receiver is primary)"
        scale = _noise_scaler(satellites, absolute)
        acc = h_acc_m if not ignore & GPS_INPUT_IGNORE_HORIZ_ACC and math.isfinite(h_acc_m) and h_acc_m > 0 else 0.0
        sig_p = scale * min(max(acc, r.posne_m_nse), POS_ACC_MAX_M)
        use_vel = not ignore & GPS_INPUT_IGNORE_VEL_HORIZ
        sp = speed_acc_m_s if not ignore & GPS_INPUT_IGNORE_SPEED_ACC and speed_acc_m_s > 0 else 0.0
        sig_v = scale * min(max(sp, r.velne_m_nse), SPEED_ACC_MAX_M_S)
        # FuseVelPosNED gates position and velocity each as a whole (both axes)
        pos_ok = self._gate(e_p - self.p_err_m, np.array([self.P[0, 0, 0], self.P[1, 0, 0]]), sig_p**2)
        vel_ok = use_vel and self._gate(e_v - self.v_err_m_s, np.array([self.P[0, 1, 1], self.P[1, 1, 1]]), sig_v**2)
        if not pos_ok and not vel_ok:
            return "gated (innovation > 5σ)"
        for axis in range(2):
            if vel_ok:
                self.fuse(axis, 1, e_v[axis] - self.v_err_m_s[axis], sig_v**2)
            if pos_ok:
                self.fuse(axis, 0, e_p[axis] - self.p_err_m[axis], sig_p**2)
        return "used" if pos_ok else "used (velocity only)"

    def _gate(self, innov: F64Array, var: F64Array, r: float) -> bool:
        return bool(np.all(innov**2 <= self.rules.gate_sigma**2 * (var + r)))

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
