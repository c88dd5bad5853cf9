"""MAVLink messages → SI samples: the one place where MAVLink units are converted (once per message type).

Times stay in the autopilot's clock (seconds since its boot); :mod:`firmware_bridge.clock` maps them.
Each ``from_*`` function takes one decoded pymavlink message and returns a frozen sample, or None when the
message carries nothing usable (no fix, fields not updated).

Values no sensor reports are stopped here, at the boundary, not in the filter: a non-finite magnetometer
reading is dropped from its IMU sample, a non-finite or impossible IMU temperature is taken as unknown
(:data:`UNKNOWN_TEMPERATURE_C`, as SCALED_IMU's 0), a GNSS position off the globe is no fix, a non-finite
pitot reading is no pitot. A static pressure no atmosphere has (≤ 0, NaN, above any sea-level record) raises
``ValueError``: the service counts and logs the message and skips it, before a density of 0 or below reaches
the air-data equations. (Non-finite or impossible rates and accelerations are refused by
:class:`firmware_bridge.inputs.ImuIntegrator`, where the time of the sample still counts.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

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
MAX_LAT_DEG_E7, MAX_LON_DEG_E7 = 900_000_000, 1_800_000_000
UNKNOWN_TEMPERATURE_C = 15.0  # an IMU temperature not reported (or impossible): ISA sea level
IMU_TEMPERATURE_RANGE_C = (-100.0, 150.0)  # beyond any MEMS IMU's operating range: a sensor fault
STATIC_PA_RANGE = (100.0, 120_000.0)  # 100 Pa ≈ 48 km altitude; 120 kPa is above the sea-level record (108.4)


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
    temperature_c: float  # the barometer's die
    pitot_temperature_c: float = math.nan  # the airspeed sensor's; NaN when not reported


# the receiver latency each autopilot subtracts from a fix's arrival by default [s]: ArduPilot's u-blox driver
# (AP_GPS_UBLOX::get_lag: 0.12 s for the 7 and M8 series "based on flight logs", GPS_DELAY_MS overrides) and
# PX4's EKF2_GPS_DELAY (110 ms). GPS_RAW_INT and the logs stamp a fix when the autopilot received it.
GNSS_LATENCY_DEFAULT_S: Final = {"ardupilot": 0.12, "px4": 0.11}


def gnss_latency_default_s(mav_autopilot: int) -> float:
    """The default receiver latency [s] of a HEARTBEAT's autopilot (MAV_AUTOPILOT); ArduPilot's for others."""
    return GNSS_LATENCY_DEFAULT_S["px4" if mav_autopilot == mavlink2.MAV_AUTOPILOT_PX4 else "ardupilot"]


@dataclass(frozen=True)
class GnssFix:
    t_s: float  # the autopilot's stamp [s]: when it received the fix (ArduPilot's last_fix_time_ms, PX4's
    # sensor_gps timestamp), the receiver's latency after the time of validity
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


def _imu_temperature_c(t_c: float) -> float:
    lo, hi = IMU_TEMPERATURE_RANGE_C
    return t_c if lo <= t_c <= hi else UNKNOWN_TEMPERATURE_C  # NaN fails the comparison too


def from_highres_imu(m: MavlinkMessage) -> ImuSample:
    mag = None
    if m.fields_updated & HIGHRES_MAG_BITS == HIGHRES_MAG_BITS:
        mag = (m.xmag * GAUSS_TO_UT, m.ymag * GAUSS_TO_UT, m.zmag * GAUSS_TO_UT)
        if not all(math.isfinite(v) for v in mag):
            mag = None
    return ImuSample(
        t_s=m.time_usec * 1e-6,
        gyro_b_rad_s=(m.xgyro, m.ygyro, m.zgyro),
        accel_b_m_s2=(m.xacc, m.yacc, m.zacc),
        temperature_c=_imu_temperature_c(float(m.temperature)),
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
    """SCALED_PRESSURE: hPa and cdegC. A differential pressure of exactly 0 hPa (or not finite) means no
    sensor; ``temperature_press_diff`` (a MAVLink 2 extension) of 0 means not reported (the spec asks a real
    0 °C to be sent as 1 cdegC). ValueError for a static pressure outside :data:`STATIC_PA_RANGE` (module
    docstring)."""
    static_pa = m.press_abs * HPA_TO_PA
    lo, hi = STATIC_PA_RANGE
    if not lo <= static_pa <= hi:
        raise ValueError(f"SCALED_PRESSURE press_abs {m.press_abs:g} hPa is not a static pressure "
                         f"({lo / HPA_TO_PA:g}..{hi / HPA_TO_PA:g} hPa)")  # fmt: skip
    dp_pa = m.press_diff * HPA_TO_PA
    return BaroPitotSample(
        t_s=m.time_boot_ms * 1e-3,
        static_pa=static_pa,
        pitot_dp_pa=dp_pa if dp_pa != 0.0 and math.isfinite(dp_pa) else math.nan,
        temperature_c=m.temperature * 0.01,
        pitot_temperature_c=diff_temp * 0.01 if (diff_temp := getattr(m, "temperature_press_diff", 0)) else math.nan,
    )


def from_gps_raw_int(m: MavlinkMessage) -> GnssFix | None:
    """GPS_RAW_INT with a 3-D fix: degE7, mm, cm/s, cdeg, mm (accuracies). None without a 3-D fix, and for
    a position off the globe (int32 degE7 reaches ±214°)."""
    if m.fix_type < 3 or abs(m.lat) > MAX_LAT_DEG_E7 or abs(m.lon) > MAX_LON_DEG_E7:
        return None
    speed = m.vel * 0.01 if m.vel != UINT16_UNKNOWN else math.nan
    course = math.radians(m.cog * 0.01) if m.cog != UINT16_UNKNOWN else math.nan
    h_acc = getattr(m, "h_acc", 0)
    return GnssFix(
        t_s=m.time_usec * 1e-6,
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
