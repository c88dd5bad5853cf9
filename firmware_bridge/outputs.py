"""SI navigation solution → MAVLink: the output side of the units boundary.

**Back to the autopilot, during a GNSS outage** (:class:`SolutionOut`):

* ArduPilot: ``GPS_INPUT`` into a ``GPSn_TYPE = 14`` (MAVLink) instance. ``time_week``/``time_week_ms``
  are filled from UTC (GPS time = UTC + :data:`GPS_LEAP_S`), the fix type follows the filter's health, the
  accuracies are the filter's 1σ inflated by :func:`inflation` (below). Optionally
  ``MAV_CMD_EXTERNAL_WIND_ESTIMATE`` (43004) with the held wind.
* ArduPilot, ExternalNav (:func:`ardupilot_odometry`): ``ODOMETRY`` as ``GCS_MAVLINK::handle_odometry`` takes
  it (``VISO_TYPE = 1``), the position in the NED frame of the autopilot's EKF origin, and
  ``MAV_CMD_SET_EKF_SOURCE_SET`` (42007, :func:`set_ekf_source_set`) to switch EKF3 to it and back.
* PX4: ``GLOBAL_POSITION_SENSOR`` (296, auxiliary global position, EKF2_AGP_*) or ``ODOMETRY``
  (EKF2_EV_*, position in the local NED frame of our origin).

**Inflation.** The autopilot's EKF fuses every message as an independent measurement, but our errors are
not independent: during an outage the solution drifts slowly (its error at 5 Hz is the same error five
times a second), and it integrates the same IMU the autopilot's EKF already fuses. Sent with its own σ,
the autopilot would count that information ``rate × τ`` times (τ ≈ 1 s, the autopilot's innovation
smoothing) and the IMU twice. The σ sent is therefore σ·√(2·rate·τ): over τ, the autopilot then gains no
more information from us than our own covariance holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.endpoint import MavlinkMessage
from vdm_aero._typing import F64Array
from vdm_aero.rotation import dcm_from_quat

__all__ = [
    "GPS_LEAP_S",
    "Solution",
    "ardupilot_odometry",
    "gps_week_time",
    "inflation",
    "odometry_quality",
    "set_ekf_source_set",
]

GPS_EPOCH_UNIX_S = 315964800  # 1980-01-06T00:00:00Z
GPS_LEAP_S = 18  # GPS − UTC since 2017-01-01 (no leap second announced since)
SECONDS_PER_WEEK = 604800
MAV_CMD_EXTERNAL_WIND_ESTIMATE = 43004  # MAVLink common (ArduPilot 4.5+); not in every pymavlink release
EKF_SMOOTHING_S = 1.0
# GPS_INPUT ignore flags: we send no HDOP/VDOP-derived fields beyond the accuracies
GPS_INPUT_IGNORE = mavlink2.GPS_INPUT_IGNORE_FLAG_HDOP | mavlink2.GPS_INPUT_IGNORE_FLAG_VDOP
MAV_CMD_SET_EKF_SOURCE_SET = mavlink2.MAV_CMD_SET_EKF_SOURCE_SET  # 42007, ardupilotmega.xml: param1 = set 1..3
# ODOMETRY.quality (MAVLink common): -1 the odometry has failed, 0 unknown, 1 worst … 100 best
QUALITY_FAILED = -1
AGP_SENSOR_ID = 1  # GLOBAL_POSITION_SENSOR.id, what EKF2_AGP0_ID is set to (docs/service.md)
QUALITY_FALLBACK_MAX = 50  # no port air data (airspeed dead reckoning): at most half, as GPS_INPUT's 2-D fix


def gps_week_time(unix_s: float) -> tuple[int, int]:
    """UTC [s since 1970] → (GPS week, ms of the week)."""
    gps_s = unix_s - GPS_EPOCH_UNIX_S + GPS_LEAP_S
    week = int(gps_s // SECONDS_PER_WEEK)
    return week, round((gps_s - week * SECONDS_PER_WEEK) * 1e3) % (SECONDS_PER_WEEK * 1000)


def inflation(rate_hz: float) -> float:
    """The factor on the σ sent to the autopilot (module docstring)."""
    return math.sqrt(max(2.0 * rate_hz * EKF_SMOOTHING_S, 1.0))


@dataclass(frozen=True)
class Solution:
    """The navigation solution at ``boot_s`` (autopilot time), SI, with 1σ uncertainties."""

    boot_s: float
    unix_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    p_ned_m: F64Array
    v_ned_m_s: F64Array
    q_nb: F64Array
    sigma_h_m: float
    sigma_v_m: float
    sigma_vel_m_s: float
    wind_ned_m_s: F64Array
    sigma_wind_m_s: float
    fix_type: int  # from the filter's health: 3 (3-D), 2 (degraded), 0 (no solution)


def fix_type_from(sigma_h_m: float, *, healthy: bool, max_sigma_3d_m: float, max_sigma_m: float) -> int:
    """3-D fix while the horizontal 1σ is under ``max_sigma_3d_m``; 2-D up to ``max_sigma_m``; else none."""
    if not healthy or not math.isfinite(sigma_h_m) or sigma_h_m > max_sigma_m:
        return mavlink2.GPS_FIX_TYPE_NO_FIX
    return mavlink2.GPS_FIX_TYPE_3D_FIX if sigma_h_m <= max_sigma_3d_m else mavlink2.GPS_FIX_TYPE_2D_FIX


def gps_input(mav: mavlink2.MAVLink, s: Solution, *, gps_id: int, k: float) -> MavlinkMessage:
    """GPS_INPUT (ArduPilot ``GPS_TYPE = 14``): degE7, m, m/s, accuracies [m, m/s] inflated by ``k``."""
    week, week_ms = gps_week_time(s.unix_s)
    return mav.gps_input_encode(
        round(s.boot_s * 1e6),
        gps_id,
        GPS_INPUT_IGNORE,
        week_ms,
        week,
        s.fix_type,
        round(s.lat_deg * 1e7),
        round(s.lon_deg * 1e7),
        s.alt_m,
        0.0,
        0.0,
        *(float(v) for v in s.v_ned_m_s),
        k * s.sigma_vel_m_s,
        k * s.sigma_h_m,
        k * s.sigma_v_m,
        0,  # satellites: none, the solution is dead-reckoned
    )


def global_position_sensor(mav: mavlink2.MAVLink, s: Solution, *, target: tuple[int, int], k: float
                           ) -> MavlinkMessage:  # fmt: skip
    """GLOBAL_POSITION_SENSOR (296, PX4 auxiliary global position): degE7, m AMSL, eph/epv [m]; ``id``
    :data:`AGP_SENSOR_ID` (PX4 main's EKF2_AGP0_ID takes the message whose id it names; 0 disables the slot)."""
    return mav.global_position_sensor_encode(
        target[0], target[1], AGP_SENSOR_ID, round(s.boot_s * 1e6), 0, 0, 0,
        round(s.lat_deg * 1e7), round(s.lon_deg * 1e7), math.nan, s.alt_m, k * s.sigma_h_m, k * s.sigma_v_m,
    )  # fmt: skip


def _covariances(s: Solution, k: float, sigma_att_rad: tuple[float, float, float] | None = None
                 ) -> tuple[list[float], list[float]]:  # fmt: skip
    """ODOMETRY's pose and velocity covariances (upper triangles of 6×6, row-major: indices 0, 6, 11 are x, y,
    z; 15, 18, 20 roll, pitch, yaw) with the σ inflated by ``k``: horizontal position σ_h on both axes (the
    larger eigenvalue), vertical σ_v, the velocity's isotropic σ (so a rotation to the body frame leaves it as it
    is); what is not known (the cross terms, the rates, an attitude σ not given) is NaN."""
    pose_cov = [math.nan] * 21
    pose_cov[0] = pose_cov[6] = (k * s.sigma_h_m) ** 2
    pose_cov[11] = (k * s.sigma_v_m) ** 2
    if sigma_att_rad is not None:  # not inflated: the autopilot fuses no attitude from it (EK3_SRCn_YAW = 1)
        pose_cov[15], pose_cov[18], pose_cov[20] = (float(v) ** 2 for v in sigma_att_rad)
    vel_cov = [math.nan] * 21
    vel_cov[0] = vel_cov[6] = vel_cov[11] = (k * s.sigma_vel_m_s) ** 2
    return pose_cov, vel_cov


def _v_body(s: Solution) -> F64Array:
    """The velocity in the body frame FRD [m/s]: v_b = C_nbᵀ·v_ned."""
    return dcm_from_quat(s.q_nb).T @ np.asarray(s.v_ned_m_s, dtype=np.float64)


def odometry(mav: mavlink2.MAVLink, s: Solution, *, k: float, quality: int, reset_counter: int) -> MavlinkMessage:
    """ODOMETRY (PX4 EKF2_EV_*): the pose in MAV_FRAME_LOCAL_NED of our origin, the velocity in the frame
    ``child_frame_id`` names, MAV_FRAME_BODY_FRD (v_b = C_nbᵀ·v_ned; PX4's mavlink_receiver maps that id to
    its body-frame velocity), with diagonal covariances (the velocity's is isotropic, so the rotation leaves
    it as it is; EKF2_EV_NOISE_MD = 0 takes them, floored by EKF2_EVP_NOISE / EKF2_EVV_NOISE), ``quality``
    (:func:`odometry_quality`; EKF2_EV_QMIN) and ``reset_counter`` (a jump of our pose: EKF2 resets onto it)."""
    pose_cov, vel_cov = _covariances(s, k)
    return mav.odometry_encode(
        round(s.boot_s * 1e6), mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_FRD,
        *(float(v) for v in s.p_ned_m), [float(v) for v in s.q_nb], *(float(v) for v in _v_body(s)),
        math.nan, math.nan, math.nan, pose_cov, vel_cov, reset_counter % 256, mavlink2.MAV_ESTIMATOR_TYPE_VIO,
        quality,
    )  # fmt: skip


def odometry_quality(s: Solution, *, max_sigma_m: float, fallback: bool) -> int:
    """ODOMETRY.quality from the filter's health: -1 (failed) without a solution (no 2-D or 3-D fix type: not
    initialised, or σ_h above ``max_sigma_m``), else 100·(1 − σ_h/max_sigma_m) rounded, in 1..100, at most
    :data:`QUALITY_FALLBACK_MAX` while the ports give no air data. ArduPilot fuses a sample only when its
    quality is ≥ VISO_QUAL_MIN (AP_VisualOdom_MAV::handle_pose_estimate / handle_vision_speed_estimate)."""
    if s.fix_type < mavlink2.GPS_FIX_TYPE_2D_FIX or not math.isfinite(s.sigma_h_m):  # NO_GPS 0, NO_FIX 1
        return QUALITY_FAILED
    q = min(max(round(100.0 * (1.0 - s.sigma_h_m / max_sigma_m)), 1), 100)
    return min(q, QUALITY_FALLBACK_MAX) if fallback else q


def ardupilot_odometry(mav: mavlink2.MAVLink, s: Solution, *, p_ned_m: F64Array, k: float, quality: int,
                       reset_counter: int, sigma_att_rad: tuple[float, float, float]) -> MavlinkMessage:  # fmt: skip
    """ODOMETRY for ArduPilot's ExternalNav (``VISO_TYPE = 1``), as ``GCS_MAVLINK::handle_odometry``
    (libraries/GCS_MAVLink/GCS_Common.cpp) reads it:

    * ``frame_id`` MAV_FRAME_LOCAL_FRD (20) and ``child_frame_id`` MAV_FRAME_BODY_FRD (12): any other pair is
      dropped without a word (and VisualOdom turns unhealthy, "VisOdom: not healthy"). LOCAL_FRD is the label
      ArduPilot requires; it takes the axes as its EKF's north, east, down (VISO_ORIENT = 0).
    * ``x, y, z`` = ``p_ned_m``: north, east, down [m] from the autopilot's **EKF origin** (GPS_GLOBAL_ORIGIN).
      The MAVLink backend aligns nothing (AP_VisualOdom_Backend::align_position_to_ahrs is empty; only the
      T265/VOXL backends align), and EKF3 fuses ExtNav position as its own NED state and resets to it at the
      source switch, so our origin would put the aircraft where it is not.
    * ``q``: body FRD → NED (w, x, y, z); ArduPilot rotates the velocity with it (``vel = q * vel``) and fuses its
      yaw only with EK3_SRCn_YAW = 6.
    * ``vx, vy, vz``: the velocity in the body frame FRD [m/s], v_b = C_nbᵀ·v_ned.
    * ``pose_covariance``: ArduPilot reads only [0], [6], [11] (posErr = ∛(c0² + c6² + c11²)) and [15], [18],
      [20] (angErr, the same of the attitude variances); a NaN in [0] means 0 (then VISO_POS_M_NSE). The
      attitude variances are the filter's, since a NaN there would reach constrain_float as NaN.
    * ``velocity_covariance``: sent (honest, as for PX4); the handle_odometry read ignores it and VISO_VEL_M_NSE
      is the velocity noise (AP_VisualOdom_MAV::handle_vision_speed_estimate); newer front ends take a
      velocity error.
    * rates NaN (ArduPilot reads none), ``reset_counter`` bumped when our pose jumps (EKF3 then resets its
      position to ours instead of gating it), ``estimator_type`` MAV_ESTIMATOR_TYPE_UNKNOWN (no entry of the
      enum is an air-data INS; ArduPilot ignores it), ``quality`` (:func:`odometry_quality`).
    """
    pose_cov, vel_cov = _covariances(s, k, sigma_att_rad)
    return mav.odometry_encode(
        round(s.boot_s * 1e6), mavlink2.MAV_FRAME_LOCAL_FRD, mavlink2.MAV_FRAME_BODY_FRD,
        *(float(v) for v in p_ned_m), [float(v) for v in s.q_nb], *(float(v) for v in _v_body(s)),
        math.nan, math.nan, math.nan, pose_cov, vel_cov, reset_counter % 256,
        mavlink2.MAV_ESTIMATOR_TYPE_UNKNOWN, int(quality),
    )  # fmt: skip


def set_ekf_source_set(mav: mavlink2.MAVLink, *, target: tuple[int, int], source_set: int, confirmation: int
                       ) -> MavlinkMessage:  # fmt: skip
    """COMMAND_LONG MAV_CMD_SET_EKF_SOURCE_SET: param1 = the source set 1..3 (ArduPilot's
    GCS_MAVLINK::handle_command_set_ekf_source_set: ACCEPTED for 1..3, else refused; the exact result code was
    not checked in its source here, and the service treats every refusal alike); ``confirmation`` 0 on the
    first transmission, +1 on each retransmission (the MAVLink command protocol)."""
    return mav.command_long_encode(target[0], target[1], MAV_CMD_SET_EKF_SOURCE_SET, min(confirmation, 255),
                                   float(source_set), 0, 0, 0, 0, 0, 0)  # fmt: skip


def external_wind(mav: mavlink2.MAVLink, s: Solution, *, target: tuple[int, int]) -> MavlinkMessage:
    """MAV_CMD_EXTERNAL_WIND_ESTIMATE: speed [m/s] and its 1σ, direction the wind comes from [deg] and 1σ."""
    wn, we = float(s.wind_ned_m_s[0]), float(s.wind_ned_m_s[1])
    speed = math.hypot(wn, we)
    from_deg = math.degrees(math.atan2(-we, -wn)) % 360.0
    dir_sigma = math.degrees(s.sigma_wind_m_s / max(speed, 0.5))
    return mav.command_long_encode(target[0], target[1], MAV_CMD_EXTERNAL_WIND_ESTIMATE, 0,
                                   speed, s.sigma_wind_m_s, from_deg, min(dir_sigma, 180.0), 0, 0, 0)  # fmt: skip


def named_values(mav: mavlink2.MAVLink, boot_s: float, values: dict[str, float]) -> list[MavlinkMessage]:
    """NAMED_VALUE_FLOAT per entry (names ≤ 10 ASCII characters), all stamped ``boot_s``."""
    ms = int(boot_s * 1e3) & 0xFFFFFFFF
    return [mav.named_value_float_encode(ms, n.encode("ascii"), float(v)) for n, v in values.items()
            if np.isfinite(v)]  # fmt: skip
