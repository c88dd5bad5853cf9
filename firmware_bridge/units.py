"""MAVLink messages → SI samples: the one place where MAVLink units are converted (once per message type).

Times stay in the autopilot's clock (seconds since its boot); :mod:`firmware_bridge.clock` maps them.
Each ``from_*`` function takes one decoded pymavlink message and returns a frozen sample, or None when the
message carries nothing usable (no fix, fields not updated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from firmware_bridge.endpoint import MavlinkMessage
from vdm_aero._typing import F64Array

__all__ = [
    "BaroPitotSample",
    "GnssFix",
    "ImuSample",
    "ServoPwm",
    "from_gps_raw_int",
    "from_highres_imu",
    "from_scaled_imu",
    "from_scaled_pressure",
    "from_servo_output_raw",
]

G0_M_S2 = 9.80665  # ArduPilot's milli-g uses standard gravity
MG_TO_M_S2 = G0_M_S2 * 1e-3
HPA_TO_PA = 100.0
GAUSS_TO_UT = 100.0  # 1 G = 1e-4 T = 100 µT
MGAUSS_TO_UT = 0.1
HIGHRES_MAG_BITS = 0x1C0  # HIGHRES_IMU fields_updated: x/y/z mag
UINT16_UNKNOWN = 65535


Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class ImuSample:
    """Plain floats, not arrays: 400 samples a second, summed into 50 Hz increments (numpy per sample costs
    more than the sums)."""

    t_s: float  # autopilot time of the sample [s]
    gyro_b_rad_s: Vec3
    accel_b_m_s2: Vec3
    temperature_c: float
    mag_b_ut: Vec3 | None  # the magnetometer when the message carries it [µT]


@dataclass(frozen=True)
class BaroPitotSample:
    t_s: float
    static_pa: float
    pitot_dp_pa: float  # NaN when the autopilot has no airspeed sensor (it reports 0 hPa)
    temperature_c: float


@dataclass(frozen=True)
class GnssFix:
    t_valid_s: float  # time of validity [s]
    fix_type: int
    lat_deg: float
    lon_deg: float
    alt_m: float  # above mean sea level
    v_ned_m_s: F64Array  # NED; D is NaN (GPS_RAW_INT has no vertical velocity)
    h_acc_m: float  # NaN when unknown
    satellites: int


@dataclass(frozen=True)
class ServoPwm:
    t_s: float
    pwm_us: F64Array  # (16,)


def from_highres_imu(m: MavlinkMessage) -> ImuSample:
    mag = None
    if m.fields_updated & HIGHRES_MAG_BITS == HIGHRES_MAG_BITS:
        mag = (m.xmag * GAUSS_TO_UT, m.ymag * GAUSS_TO_UT, m.zmag * GAUSS_TO_UT)
    return ImuSample(
        t_s=m.time_usec * 1e-6,
        gyro_b_rad_s=(m.xgyro, m.ygyro, m.zgyro),
        accel_b_m_s2=(m.xacc, m.yacc, m.zacc),
        temperature_c=float(m.temperature),
        mag_b_ut=mag,
    )


def from_scaled_imu(m: MavlinkMessage) -> ImuSample:
    """SCALED_IMU: milli-g, mrad/s, milligauss, cdegC (0 = unknown)."""
    return ImuSample(
        t_s=m.time_boot_ms * 1e-3,
        gyro_b_rad_s=(m.xgyro * 1e-3, m.ygyro * 1e-3, m.zgyro * 1e-3),
        accel_b_m_s2=(m.xacc * MG_TO_M_S2, m.yacc * MG_TO_M_S2, m.zacc * MG_TO_M_S2),
        temperature_c=m.temperature * 0.01 if m.temperature else 15.0,
        mag_b_ut=(m.xmag * MGAUSS_TO_UT, m.ymag * MGAUSS_TO_UT, m.zmag * MGAUSS_TO_UT),
    )


def from_scaled_pressure(m: MavlinkMessage) -> BaroPitotSample:
    """SCALED_PRESSURE: hPa and cdegC. A differential pressure of exactly 0 hPa means no sensor."""
    return BaroPitotSample(
        t_s=m.time_boot_ms * 1e-3,
        static_pa=m.press_abs * HPA_TO_PA,
        pitot_dp_pa=m.press_diff * HPA_TO_PA if m.press_diff != 0.0 else math.nan,
        temperature_c=m.temperature * 0.01,
    )


def from_gps_raw_int(m: MavlinkMessage) -> GnssFix | None:
    """GPS_RAW_INT with a 3-D fix: degE7, mm, cm/s, cdeg, mm (accuracies). None without a 3-D fix."""
    if m.fix_type < 3:
        return None
    speed = m.vel * 0.01 if m.vel != UINT16_UNKNOWN else math.nan
    course = math.radians(m.cog * 0.01) if m.cog != UINT16_UNKNOWN else math.nan
    h_acc = getattr(m, "h_acc", 0)
    return GnssFix(
        t_valid_s=m.time_usec * 1e-6,
        fix_type=int(m.fix_type),
        lat_deg=m.lat * 1e-7,
        lon_deg=m.lon * 1e-7,
        alt_m=m.alt * 1e-3,
        v_ned_m_s=np.array([speed * math.cos(course), speed * math.sin(course), math.nan]),
        h_acc_m=h_acc * 1e-3 if h_acc else math.nan,
        satellites=int(m.satellites_visible),
    )


def from_servo_output_raw(m: MavlinkMessage) -> ServoPwm:
    pwm = [getattr(m, f"servo{i}_raw", 0) for i in range(1, 17)]
    return ServoPwm(t_s=m.time_usec * 1e-6, pwm_us=np.asarray(pwm, dtype=np.float64))
