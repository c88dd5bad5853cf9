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
:class:`vdm_aero.nav.imu_increments.ImuIntegrator`, where the time of the sample still counts.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.endpoint import MavlinkMessage
from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import isa
from vdm_aero.rotation import quat_from_euler

__all__ = [
    "ApAttitude",
    "ApPosition",
    "BaroPitotSample",
    "GnssFix",
    "ImuSample",
    "ServoPwm",
    "from_altitude",
    "from_attitude",
    "from_global_position_int",
    "from_gps_raw_int",
    "from_highres_imu",
    "from_highres_pressure",
    "from_raw_imu",
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
HIGHRES_ABS_PRESSURE_BIT = 0x200  # ... abs_pressure (the barometer)
HIGHRES_DIFF_PRESSURE_BIT = 0x400  # ... diff_pressure (PX4 puts its airspeed sensor's reading here)
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
    h_acc_m: float  # the receiver's horizontal accuracy [m], NaN when unknown
    satellites: int
    v_acc_m: float = math.nan  # its vertical accuracy [m], NaN when unknown


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


def _mag_mgauss(m: MavlinkMessage) -> Vec3 | None:
    """The integer magnetometer fields [mgauss] → µT; None when the autopilot has no compass there (it then
    sends exactly 0, 0, 0: no field on Earth reads that)."""
    if m.xmag == 0 and m.ymag == 0 and m.zmag == 0:
        return None
    return (m.xmag * MGAUSS_TO_UT, m.ymag * MGAUSS_TO_UT, m.zmag * MGAUSS_TO_UT)


def _scaled_imu(m: MavlinkMessage, t_s: float) -> ImuSample:
    """The fields SCALED_IMU, SCALED_IMU2/3 and ArduPilot's RAW_IMU share: milli-g, mrad/s, milligauss,
    cdegC (0 = unknown)."""
    temperature = getattr(m, "temperature", 0)
    return ImuSample(
        t_s=t_s,
        gyro_b_rad_s=(m.xgyro * 1e-3, m.ygyro * 1e-3, m.zgyro * 1e-3),
        accel_b_m_s2=(m.xacc * MG_TO_M_S2, m.yacc * MG_TO_M_S2, m.zacc * MG_TO_M_S2),
        temperature_c=_imu_temperature_c(temperature * 0.01) if temperature else UNKNOWN_TEMPERATURE_C,
        mag_b_ut=_mag_mgauss(m),
    )


def from_scaled_imu(m: MavlinkMessage) -> ImuSample:
    """SCALED_IMU, SCALED_IMU2, SCALED_IMU3 (the first, second, third IMU): stamped in ms since boot."""
    return _scaled_imu(m, m.time_boot_ms * 1e-3)


def from_raw_imu(m: MavlinkMessage) -> ImuSample:
    """ArduPilot's RAW_IMU: despite the name and the MAVLink spec (raw sensor counts), ArduPilot sends its
    first IMU already scaled, in SCALED_IMU's units (GCS_MAVLINK::send_raw_imu: mG, mrad/s, mgauss), stamped in
    µs since boot. Only ArduPilot's may be read so: :class:`firmware_bridge.decode.MavlinkDecoder` checks."""
    return _scaled_imu(m, m.time_usec * 1e-6)


def from_scaled_pressure(m: MavlinkMessage) -> BaroPitotSample:
    """SCALED_PRESSURE, SCALED_PRESSURE2, SCALED_PRESSURE3 (ArduPilot: barometer n with airspeed sensor n's
    differential pressure): hPa and cdegC. A differential pressure of exactly 0 hPa (or not finite) means no
    sensor; ``temperature_press_diff`` (a MAVLink 2 extension) of 0 means not reported (the spec asks a real
    0 °C to be sent as 1 cdegC). ValueError for a static pressure outside :data:`STATIC_PA_RANGE` (module
    docstring)."""
    static_pa = m.press_abs * HPA_TO_PA
    lo, hi = STATIC_PA_RANGE
    if not lo <= static_pa <= hi:
        raise ValueError(f"{m.get_type()} press_abs {m.press_abs:g} hPa is not a static pressure "
                         f"({lo / HPA_TO_PA:g}..{hi / HPA_TO_PA:g} hPa)")  # fmt: skip
    dp_pa = m.press_diff * HPA_TO_PA
    return BaroPitotSample(
        t_s=m.time_boot_ms * 1e-3,
        static_pa=static_pa,
        pitot_dp_pa=dp_pa if dp_pa != 0.0 and math.isfinite(dp_pa) else math.nan,
        temperature_c=m.temperature * 0.01,
        pitot_temperature_c=diff_temp * 0.01 if (diff_temp := getattr(m, "temperature_press_diff", 0)) else math.nan,
    )


def from_highres_pressure(m: MavlinkMessage) -> BaroPitotSample | None:
    """The barometer and differential pressure PX4 sends in HIGHRES_IMU (hPa), when ``fields_updated`` says
    they are new; None when neither is. ValueError for an impossible static pressure, as SCALED_PRESSURE."""
    new_abs = bool(m.fields_updated & HIGHRES_ABS_PRESSURE_BIT)
    new_diff = bool(m.fields_updated & HIGHRES_DIFF_PRESSURE_BIT)
    if not (new_abs or new_diff):
        return None
    static_pa = m.abs_pressure * HPA_TO_PA if new_abs else math.nan
    lo, hi = STATIC_PA_RANGE
    if new_abs and not lo <= static_pa <= hi:
        raise ValueError(f"HIGHRES_IMU abs_pressure {m.abs_pressure:g} hPa is not a static pressure "
                         f"({lo / HPA_TO_PA:g}..{hi / HPA_TO_PA:g} hPa)")  # fmt: skip
    dp_pa = m.diff_pressure * HPA_TO_PA if new_diff else math.nan
    return BaroPitotSample(
        t_s=m.time_usec * 1e-6,
        static_pa=static_pa,
        pitot_dp_pa=dp_pa if math.isfinite(dp_pa) else math.nan,
        temperature_c=_imu_temperature_c(float(m.temperature)),
    )


def from_altitude(m: MavlinkMessage) -> BaroPitotSample | None:
    """PX4's ALTITUDE: ``altitude_monotonic`` is its barometric altitude (air_data.baro_alt_meter, from the
    static pressure by the ISA at SENS_BARO_QNH, default 1013.25 hPa); the static pressure back through the same
    ISA [Pa]. None when not finite. Only a fall-back: a non-default QNH shifts it (a constant, which the
    filter's barometer bias takes)."""
    if not math.isfinite(m.altitude_monotonic):
        return None
    return BaroPitotSample(t_s=m.time_usec * 1e-6, static_pa=isa(float(m.altitude_monotonic))[0],
                           pitot_dp_pa=math.nan, temperature_c=math.nan)  # fmt: skip


def from_gps_raw_int(m: MavlinkMessage) -> GnssFix | None:
    """GPS_RAW_INT with a 3-D fix: degE7, mm, cm/s, cdeg, mm (accuracies). None without a 3-D fix, and for
    a position off the globe (int32 degE7 reaches ±214°)."""
    if m.fix_type < 3 or abs(m.lat) > MAX_LAT_DEG_E7 or abs(m.lon) > MAX_LON_DEG_E7:
        return None
    speed = m.vel * 0.01 if m.vel != UINT16_UNKNOWN else math.nan
    course = math.radians(m.cog * 0.01) if m.cog != UINT16_UNKNOWN else math.nan
    h_acc, v_acc = getattr(m, "h_acc", 0), getattr(m, "v_acc", 0)  # MAVLink 2 extensions: 0 when unknown
    return GnssFix(
        t_s=m.time_usec * 1e-6,
        fix_type=int(m.fix_type),
        lat_deg=m.lat * 1e-7,
        lon_deg=m.lon * 1e-7,
        alt_m=m.alt * 1e-3,
        v_ned_m_s=np.array([speed * math.cos(course), speed * math.sin(course), math.nan]),
        h_acc_m=h_acc * 1e-3 if h_acc else math.nan,
        satellites=int(m.satellites_visible),
        v_acc_m=v_acc * 1e-3 if v_acc else math.nan,
    )


@dataclass(frozen=True)
class ApAttitude:
    """The autopilot's own attitude estimate."""

    t_s: float
    q_nb: F64Array  # body FRD → NED, w x y z


@dataclass(frozen=True)
class ApPosition:
    """The autopilot's own position estimate."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # above mean sea level


def from_attitude(m: MavlinkMessage) -> ApAttitude | None:
    """ATTITUDE: roll, pitch, yaw [rad] (ZYX Euler angles of body FRD in NED); None when not finite."""
    if not all(math.isfinite(v) for v in (m.roll, m.pitch, m.yaw)):
        return None
    return ApAttitude(
        t_s=m.time_boot_ms * 1e-3, q_nb=np.asarray(quat_from_euler(m.roll, m.pitch, m.yaw), dtype=np.float64)
    )


def from_global_position_int(m: MavlinkMessage) -> ApPosition | None:
    """GLOBAL_POSITION_INT: degE7, mm (AMSL); None for a position off the globe, or none yet (0, 0)."""
    if (m.lat == 0 and m.lon == 0) or abs(m.lat) > MAX_LAT_DEG_E7 or abs(m.lon) > MAX_LON_DEG_E7:
        return None
    return ApPosition(t_s=m.time_boot_ms * 1e-3, lat_deg=m.lat * 1e-7, lon_deg=m.lon * 1e-7, alt_m=m.alt * 1e-3)


def from_servo_output_raw(m: MavlinkMessage) -> ServoPwm:
    pwm = [getattr(m, f"servo{i}_raw", 0) for i in range(1, 17)]
    return ServoPwm(t_s=m.time_usec * 1e-6, pwm_us=np.asarray(pwm, dtype=np.float64))
