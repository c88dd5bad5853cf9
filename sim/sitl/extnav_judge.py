"""Whether ArduPilot would use the companion's ODOMETRY as ExternalNav, and what it would make of it: a judge inside
the mock, beside the GPS_INPUT judge (sim/sitl/ekf_judge.py) and fusing into the same drift error state.

Rules, from ArduPilot's sources (recent master):

* ``GCS_Common.cpp`` ``handle_odometry``: read only with ``frame_id`` = MAV_FRAME_LOCAL_FRD (20) and
  ``child_frame_id`` = MAV_FRAME_BODY_FRD (12), else dropped silently. From ``pose_covariance`` (upper triangle
  of 6x6, row-major: variances at 0, 6, 11 and 15, 18, 20) ``posErr = cbrt(c0² + c6² + c11²)``, ``angErr`` likewise
  (0 when c0 is NaN): ArduPilot's formula, variances squared under a cube root. The velocity is rotated body →
  NED by the message's own quaternion (``vel = q * vel``); ``velocity_covariance`` is not read.
  ``handle_vision_position_estimate`` is the position path alone, quality 0, no frame ids.
* ``AP_VisualOdom_MAV.cpp`` (VISO_TYPE = 1) ``handle_pose_estimate`` / ``handle_vision_speed_estimate``:
  position x VISO_SCALE; ``posErr`` clamped to [VISO_POS_M_NSE, 100 m]; position and velocity go to the EKF only
  with ``quality`` ≥ VISO_QUAL_MIN; the velocity's noise is VISO_VEL_M_NSE. A new ``reset_counter`` stamps a new
  reset time (``AP_VisualOdom_Backend.cpp`` ``get_reset_timestamp_ms``).
* Anchoring. VISO_TYPE = 1 aligns nothing (``AP_VisualOdom_MAV`` keeps the backend's no-op
  ``align_position_to_ahrs``): x, y are north and east of the EKF origin, and EKF3 resets its position onto them
  at the switch (below). Only VISO_TYPE 2/3 (``AP_VisualOdom_IntelT265.cpp``) move the sensor's position onto the
  AHRS's (``align_position`` → ``_pos_correction``) at every sample while ``AP_NavEKF_Source.cpp``
  ``align_inactive_sources`` (end of each ``NavEKF3::UpdateFilter``) asks: some set has POSXY = ExternalNav and the
  active POSXY is GPS or Beacon. After the switch, what is fused is the sensor's motion since its last alignment.
* ``AP_NavEKF3_Measurements.cpp`` ``writeExtNavData`` / ``writeExtNavVelData``: NaN is dropped; a sample under
  ``extNavIntervalMin_ms`` (20 ms) after the last one written is dropped; a new reset time marks ``posReset``.
* ``AP_NavEKF_Source.cpp``: EK3_SRCn_POSXY/VELXY = 6 is ExternalNav; ``setPosVelYawSourceSet`` (set index =
  MAV_CMD_SET_EKF_SOURCE_SET's param1 − 1, an RC aux switch, or a Lua script's ``ahrs:set_posvelyaw_source_set``);
  ``useVelXYSource``: the active set's VELXY, or any set's with EK3_SRC_OPTIONS bit 0 (FuseAllVelocities).
* ``AP_NavEKF3_PosVelFusion.cpp`` ``SelectVelPosFusion``: ExtNav position is fused only while the active POSXY is
  ExternalNav; a change of POSXY source arms ``posxy_source_reset``, and the first ExtNav sample after it, or one
  marked ``posReset``, resets the position onto it (``ResetPositionNE``: covariance untouched) before it is fused.
  ``FuseVelPosNED``: R_pos = (gpsNoiseScaler · clamp(posErr, 0.01, 10 m))², R_vel = (gpsNoiseScaler · clamp(err,
  0.05, 5 m/s))²; one test ratio over N and E each for position and velocity, ``Σi² < gate² · Σ(P + R)`` (R without
  the scaler), gate = max(EK3_POS_I_GATE / 100, 1), likewise EK3_VEL_I_GATE. A position that passes while
  P_NN + P_EE > EK3_GLITCH_RAD² resets onto the ExtNav position (``ResetPosition``) with P = (EK3_GLITCH_RAD / 2)²
  per axis and is not fused.

Outside GNSS outages the mock's estimate follows GNSS (DeadReckoningDrift), so samples there are counted, not
fused, and a reset armed by a switch waits for the first sample in the outage. The ArduPilot wiki's Non-GPS Position
Estimation page advises VISO_TYPE = 3 (VOXL) for a companion's ODOMETRY: that is the aligned route above.

The error model is ekf_judge's (exact for the drift, per horizontal axis), so what is judged is what the companion's
ODOMETRY gets wrong against the truth when it arrives. Not modelled: the vertical (POSZ, VELZ, z, vz), yaw (the set's
yaw is the compass; T265's yaw alignment), VISO_POS_X/Y/Z, VISO_DELAY_MS and the jitter-corrected timestamp (the
20 ms interval is applied to ``time_usec``), the manoeuvre terms (accNavMag), the innovation timeouts, AID_NONE, and
a ResetPosition that would prefer a fresh GPS_INPUT. FuseVelPosNED takes the GPS's reported accuracies instead
of ExtNav's whenever they are > 0 (``gpsPosAccuracy``, ``gpsSpdAccuracy``) and scales by ``gpsNoiseScaler``, all
three set by ``readGpsData`` from the last GPS data (not checked here whether a lost fix clears them). Here the
accuracies are taken as 0 and the scaler as ``Ek3ExtNavRules.gps_noise_scaler``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.sitl.ekf_judge import GpsInputJudge
from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.rotation import dcm_from_quat

__all__ = [
    "Ek3ExtNavRules",
    "Ek3SourceParams",
    "ExtNavJudge",
    "SourceSet",
    "SourceXY",
    "SourceYaw",
    "SourceZ",
    "VisoParams",
    "pose_errors_from_covariance",
]

SOURCE_SET_COUNT = 3  # AP_NAKEKF_SOURCE_SET_MAX
EXTNAV_INTERVAL_MIN_S = 0.020  # AP_NavEKF3.h extNavIntervalMin_ms
POS_ERR_MAX_M = 100.0  # AP_VisualOdom_MAV's clamp of posErr
R_POS_MIN_M, R_POS_MAX_M = 0.01, 10.0  # FuseVelPosNED's clamp of extNavDataDelayed.posErr
R_VEL_MIN_M_S, R_VEL_MAX_M_S = 0.05, 5.0  # ... and of extNavVelDelayed.err
FRAME_ID = mavlink2.MAV_FRAME_LOCAL_FRD
CHILD_FRAME_ID = mavlink2.MAV_FRAME_BODY_FRD
FUSE_ALL_VELOCITIES = 1  # EK3_SRC_OPTIONS bit 0


class SourceXY(IntEnum):
    """EK3_SRCn_POSXY / _VELXY values (AP_NavEKF_Source.h)."""

    NONE = 0
    GPS = 3
    BEACON = 4
    OPTFLOW = 5
    EXTNAV = 6
    WHEEL_ENCODER = 7


class SourceZ(IntEnum):
    """EK3_SRCn_POSZ / _VELZ values."""

    NONE = 0
    BARO = 1
    RANGEFINDER = 2
    GPS = 3
    BEACON = 4
    EXTNAV = 6


class SourceYaw(IntEnum):
    """EK3_SRCn_YAW values."""

    NONE = 0
    COMPASS = 1
    GPS = 2
    GPS_COMPASS_FALLBACK = 3
    EXTNAV = 6
    GSF = 8


@dataclass(frozen=True)
class SourceSet:
    """One EK3_SRCn_* group."""

    posxy: SourceXY
    velxy: SourceXY
    posz: SourceZ
    velz: SourceZ
    yaw: SourceYaw


@dataclass(frozen=True)
class Ek3SourceParams:
    """EK3_SRC1..3_* and EK3_SRC_OPTIONS. Set 1 is ArduPilot's default (GPS, baro, compass); set 2 ExternalNav
    for POSXY, VELXY and VELZ, baro for POSZ (the wiki's GPS/Non-GPS transitions page) and compass for yaw (a plane
    without ExtNav yaw); set 3 ArduPilot's default (none). EK3_SRC_OPTIONS = 0 as that page sets it: with the
    default 1 (FuseAllVelocities) set 2's ExtNav velocity would be fused while set 1 is active."""

    src1: SourceSet = SourceSet(SourceXY.GPS, SourceXY.GPS, SourceZ.BARO, SourceZ.GPS, SourceYaw.COMPASS)
    src2: SourceSet = SourceSet(SourceXY.EXTNAV, SourceXY.EXTNAV, SourceZ.BARO, SourceZ.EXTNAV, SourceYaw.COMPASS)
    src3: SourceSet = SourceSet(SourceXY.NONE, SourceXY.NONE, SourceZ.NONE, SourceZ.NONE, SourceYaw.NONE)
    options: int = 0  # EK3_SRC_OPTIONS

    def set(self, number: int) -> SourceSet:
        """Source set ``number`` (1..3, as EK3_SRCn_ and MAV_CMD_SET_EKF_SOURCE_SET count)."""
        return (self.src1, self.src2, self.src3)[number - 1]

    def use_velxy(self, active: int, source: SourceXY) -> bool:
        """AP_NavEKF_Source::useVelXYSource."""
        if self.set(active).velxy == source:
            return True
        fuse_all = bool(self.options & FUSE_ALL_VELOCITIES)
        return fuse_all and any(self.set(n).velxy == source for n in range(1, SOURCE_SET_COUNT + 1))


@dataclass(frozen=True)
class VisoParams:
    """VISO_* at ArduPilot's defaults (AP_VisualOdom.cpp), with VISO_TYPE = 1 (MAVLink)."""

    type: int = 1  # VISO_TYPE: 1 MAVLink (no alignment); 2 IntelT265, 3 VOXL (position aligned to the AHRS)
    scale: float = 1.0  # VISO_SCALE
    pos_m_nse: float = 0.2  # VISO_POS_M_NSE [m]: the floor of posErr
    vel_m_nse: float = 0.1  # VISO_VEL_M_NSE [m/s]: the velocity's noise
    yaw_m_nse: float = 0.2  # VISO_YAW_M_NSE [rad] (yaw is not modelled)
    qual_min: int = 0  # VISO_QUAL_MIN [%]: -1 takes everything, 0 good or unknown


@dataclass(frozen=True)
class Ek3ExtNavRules:
    """The ArduPilot parameters the ExternalNav judge reads."""

    sources: Ek3SourceParams = field(default_factory=Ek3SourceParams)
    viso: VisoParams = field(default_factory=VisoParams)
    pos_gate_sigma: float = 5.0  # max(EK3_POS_I_GATE / 100, 1), default 500
    vel_gate_sigma: float = 5.0  # max(EK3_VEL_I_GATE / 100, 1), default 500
    glitch_radius_m: float = 25.0  # EK3_GLITCH_RAD
    gps_noise_scaler: float = 1.0  # gpsNoiseScaler left by the real receiver (≥ 6 satellites: 1)


def pose_errors_from_covariance(pose_covariance: FloatArray) -> tuple[float, float]:
    """``(posErr, angErr)`` as GCS_Common.cpp derives them from ODOMETRY's ``pose_covariance`` (0, 0 when its
    first element is NaN). Units as ArduPilot treats them: m and rad."""
    c = np.asarray(pose_covariance, dtype=np.float64)
    if math.isnan(c[0]):
        return 0.0, 0.0
    return float(np.cbrt(c[0] ** 2 + c[6] ** 2 + c[11] ** 2)), float(np.cbrt(c[15] ** 2 + c[18] ** 2 + c[20] ** 2))


class ExtNavJudge:
    """The ExternalNav route: source sets, the ODOMETRY rules, the anchoring, and fusion into ``state`` (the GPS
    judge's drift error: position and velocity error per horizontal axis and their covariance)."""

    def __init__(self, rules: Ek3ExtNavRules, state: GpsInputJudge) -> None:
        self.rules = rules
        self.state = state
        self.active_set = 1
        self.verdicts: Counter[str] = Counter()
        self.outage_verdicts: Counter[str] = Counter()  # the same, of what came during GNSS outages
        self.switches: list[dict[str, float]] = []  # {t_s, source_set, outage (index; -1 between outages)}
        self._reset_pending = False  # posxy_source_reset
        self._outage = -1
        self._outages = 0
        self._last_pos_t_s: float | None = None  # extNavMeasTime_ms
        self._last_vel_t_s: float | None = None  # extNavVelMeasTime_ms
        self._reset_counter = 0  # AP_VisualOdom_Backend::_last_reset_counter
        self._reset_seen = 0  # changes of it not yet consumed by writeExtNavData
        self.pos_correction_ne_m = np.zeros(2)  # AP_VisualOdom_Backend::_pos_correction, horizontally
        # per outage, at its end: the last position judged in it against the truth, as it came and as fused, the
        # mock's own dead reckoning's, and FuseVelPosNED's innovation variance then (N + E, as its gate sums them)
        self.outage_end: list[dict[str, float]] = []
        self._last_pos: tuple[F64Array, float] | None = None  # (its error NE [m], its innovation variance [m²])

    # ------------------------------------------------------------------------------------ source sets
    def set_source_set(self, number: int, t_s: float) -> None:
        """AP_NavEKF_Source::setPosVelYawSourceSet(number − 1); a change of POSXY source arms the position reset."""
        if not 1 <= number <= SOURCE_SET_COUNT:
            raise ValueError(f"source set {number}: 1..{SOURCE_SET_COUNT}")
        old = self.rules.sources.set(self.active_set).posxy
        new = self.rules.sources.set(number).posxy
        if new != old:
            self._reset_pending = new != SourceXY.NONE
        self.active_set = number
        self.switches.append({"t_s": t_s, "source_set": float(number), "outage": float(self._outage)})

    def outage_started(self) -> None:
        self._outage = self._outages
        self._outages += 1

    def outage_ended(self, free_error_ne_m: FloatArray) -> None:
        """The outage's end: ``free_error_ne_m`` the mock's own dead reckoning's horizontal error then [m]."""
        if self._last_pos is not None:
            (e_p, var), p, free = self._last_pos, self.state.p_err_m, np.asarray(free_error_ne_m, dtype=np.float64)
            self.outage_end.append({"odometry_n_m": float(e_p[0]), "odometry_e_m": float(e_p[1]),
                                    "estimate_n_m": float(p[0]), "estimate_e_m": float(p[1]),
                                    "free_n_m": float(free[0]), "free_e_m": float(free[1]),
                                    "innovation_var_m2": var})  # fmt: skip
        self._outage = -1
        self._last_pos = None

    # ------------------------------------------------------------------------------------ the messages
    def odometry(self, *, time_usec: int, frame_id: int, child_frame_id: int, pos_m: FloatArray, q: FloatArray,
                 vel_m_s: FloatArray, pose_covariance: FloatArray, reset_counter: int, quality: int,
                 truth_pos_ned_m: FloatArray, truth_v_ned_m_s: FloatArray, gnss_outage: bool) -> str:  # fmt: skip
        """One ODOMETRY: its verdict ("used…", "reset…" or why not), counted. ``truth_*`` the vehicle's true NED
        position from the EKF origin [m] and velocity [m/s] when it arrives."""
        if frame_id != FRAME_ID or child_frame_id != CHILD_FRAME_ID:
            return self._count("frame ids not LOCAL_FRD / BODY_FRD (handle_odometry drops it)")
        pos_err_m, _ = pose_errors_from_covariance(pose_covariance)
        v_ned = dcm_from_quat(np.asarray(q, dtype=np.float64)) @ np.asarray(vel_m_s, dtype=np.float64)
        return self._judge(time_usec * 1e-6, np.asarray(pos_m, dtype=np.float64)[:2], pos_err_m, v_ned[:2],
                           reset_counter, quality, np.asarray(truth_pos_ned_m, dtype=np.float64)[:2],
                           np.asarray(truth_v_ned_m_s, dtype=np.float64)[:2], gnss_outage)  # fmt: skip

    def vision_position_estimate(self, *, usec: int, pos_m: FloatArray, covariance: FloatArray, reset_counter: int,
                                 truth_pos_ned_m: FloatArray, gnss_outage: bool) -> str:  # fmt: skip
        """One VISION_POSITION_ESTIMATE (position only, quality 0: GCS_Common.cpp passes none)."""
        pos_err_m, _ = pose_errors_from_covariance(covariance)
        return self._judge(usec * 1e-6, np.asarray(pos_m, dtype=np.float64)[:2], pos_err_m, None, reset_counter, 0,
                           np.asarray(truth_pos_ned_m, dtype=np.float64)[:2], None, gnss_outage)  # fmt: skip

    def _count(self, verdict: str) -> str:
        self.verdicts[verdict] += 1
        if self._outage >= 0:  # what the share is of: every ODOMETRY of the outage, switched to or not
            self.outage_verdicts[verdict] += 1
        return verdict

    def _judge(self, t_s: float, pos_ne_m: F64Array, pos_err_m: float, v_ne_m_s: F64Array | None, reset_counter: int,
               quality: int, truth_p: F64Array, truth_v: F64Array | None, gnss_outage: bool) -> str:  # fmt: skip
        r, viso, src = self.rules, self.rules.viso, self.rules.sources
        sensor_p = pos_ne_m * viso.scale
        active = src.set(self.active_set)
        if viso.type in (2, 3):  # IntelT265 / VOXL: aligned to the AHRS before the quality check
            could = any(src.set(n).posxy == SourceXY.EXTNAV for n in range(1, SOURCE_SET_COUNT + 1))
            if could and active.posxy in (SourceXY.GPS, SourceXY.BEACON):
                self.pos_correction_ne_m = self.state.p_err_m + truth_p - sensor_p
        p_meas = sensor_p + self.pos_correction_ne_m
        if quality < viso.qual_min:
            return self._count("quality below VISO_QUAL_MIN")
        if reset_counter != self._reset_counter:  # get_reset_timestamp_ms: a new reset time
            self._reset_counter = reset_counter
            self._reset_seen += 1
        pos_in = not (np.any(np.isnan(p_meas)) or math.isnan(pos_err_m))
        vel_in = v_ne_m_s is not None and not bool(np.any(np.isnan(v_ne_m_s)))
        if not pos_in and not vel_in:
            return self._count("NaN (writeExtNavData drops it)")
        if pos_in and self._last_pos_t_s is not None and t_s - self._last_pos_t_s < EXTNAV_INTERVAL_MIN_S:
            pos_in = False
        if vel_in and self._last_vel_t_s is not None and t_s - self._last_vel_t_s < EXTNAV_INTERVAL_MIN_S:
            vel_in = False
        if not pos_in and not vel_in:
            return self._count("under extNavIntervalMin (20 ms) after the last")
        pos_reset = False
        if pos_in:
            self._last_pos_t_s = t_s
            pos_reset = self._reset_seen > 0
            self._reset_seen = 0
        if vel_in:
            self._last_vel_t_s = t_s
        use_pos = pos_in and active.posxy == SourceXY.EXTNAV
        use_vel = vel_in and src.use_velxy(self.active_set, SourceXY.EXTNAV)
        if not use_pos and not use_vel:
            return self._count("source not active (EK3_SRCn POSXY/VELXY not ExternalNav)")
        if not gnss_outage:  # the mock's estimate follows GNSS outside outages (DeadReckoningDrift)
            return self._count("not judged: GNSS healthy")
        st = self.state
        e_p = p_meas - truth_p
        verdict = ""
        if use_pos and (pos_reset or self._reset_pending):  # SelectVelPosFusion → ResetPositionNE
            verdict = "reset (source switch)" if self._reset_pending else "reset (reset_counter)"
            self._reset_pending = False
            st.p_err_m = e_p.copy()
        sig_p = min(max(min(max(pos_err_m, viso.pos_m_nse), POS_ERR_MAX_M), R_POS_MIN_M), R_POS_MAX_M)
        sig_v = min(max(viso.vel_m_nse, R_VEL_MIN_M_S), R_VEL_MAX_M_S)
        pos_ok = use_pos and self._passes(e_p - st.p_err_m, 0, sig_p**2, r.pos_gate_sigma)
        if use_pos:  # the innovation's variance as the gate takes it, before this sample is fused
            self._last_pos = (e_p.copy(), float(st.P[0, 0, 0] + st.P[1, 0, 0] + 2.0 * sig_p**2))
        e_v, vel_ok = np.zeros(2), False
        if use_vel and v_ne_m_s is not None and truth_v is not None:
            e_v = v_ne_m_s - truth_v
            vel_ok = self._passes(e_v - st.v_err_m_s, 1, sig_v**2, r.vel_gate_sigma)
        if pos_ok and st.P[0, 0, 0] + st.P[1, 0, 0] > r.glitch_radius_m**2:  # ResetPosition, not fused
            st.p_err_m = e_p.copy()
            st.P[:, 0, :] = 0.0
            st.P[:, :, 0] = 0.0
            st.P[:, 0, 0] = (0.5 * r.glitch_radius_m) ** 2
            pos_ok, verdict = False, "reset (position variance beyond EK3_GLITCH_RAD)"
        scale2 = r.gps_noise_scaler**2
        for axis in range(2):
            if vel_ok:
                st.fuse(axis, 1, e_v[axis] - st.v_err_m_s[axis], scale2 * sig_v**2)
            if pos_ok:
                st.fuse(axis, 0, e_p[axis] - st.p_err_m[axis], scale2 * sig_p**2)
        if verdict:
            return self._count(verdict)
        if not pos_ok and not vel_ok:
            return self._count("gated (innovation > 5σ)")
        if pos_ok and vel_ok:
            return self._count("used")
        return self._count("used (position only)" if pos_ok else "used (velocity only)")

    def _passes(self, innov: F64Array, i: int, r: float, gate: float) -> bool:
        """FuseVelPosNED's test: one ratio over N and E."""
        var = self.state.P[0, i, i] + self.state.P[1, i, i] + 2.0 * r
        return bool(np.sum(innov**2) < gate**2 * var)
