"""Telemetry streams of the mock autopilot: which messages, at which rates, and their unit conversions.

This module is the MAVLink unit boundary of the SITL side (independent of ``firmware_bridge``): SI values
from the world become degE7, mm, cm/s, cdeg, hPa, cdegC, mG, mrad/s, mgauss, gauss and µs here, in
the ``to_*`` helpers, and nowhere else.

Rates follow ArduPilot's ``SRx_`` stream groups (every group defaults to 1 Hz in ArduPilot's
``GCS_MAVLINK::var_info``); messages in no group (HIGHRES_IMU, SCALED_IMU, ATTITUDE_QUATERNION,
HOME_POSITION, AUTOPILOT_VERSION) are off until requested with ``MAV_CMD_SET_MESSAGE_INTERVAL`` or
``MAV_CMD_REQUEST_MESSAGE``, as on ArduPlane. :func:`gcs_request_rates` is what a recording ground station
asks for on top (every group at :data:`GCS_REQUEST_HZ`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.contract import (
    AirspeedSample,
    BaroSample,
    GnssSample,
    ImuSample,
    MagSample,
    ServoSample,
    VehicleTruth,
)
from sim.sitl.link import MavlinkMessage
from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import pressure_altitude_m
from vdm_aero.errors import UserInputError
from vdm_aero.rotation import euler_from_quat

GRAVITY_M_S2 = 9.80665  # ArduPilot's GRAVITY_MSS: RAW_IMU/SCALED_IMU accelerations are in mG of it
RHO0_KG_M3 = 1.225  # sea-level density: equivalent airspeed from pitot Δp, as ArduPilot's ARSPD_RATIO = 2/ρ0
UINT16_UNKNOWN = 65535
DEBUG_FLOAT_ARRAY_LEN = 58
SCHEDULE_EPSILON_S = 1e-6  # a message due within this of the tick is sent at it
PLANE_VERSION = (4, 5, 7)  # reported ArduPlane version in AUTOPILOT_VERSION
PX4_VERSION = (1, 15, 4)  # ... and PX4's, as the mock plays it (its EKF2 rules: ekf2_judge.py)
FIRMWARE_VERSION_TYPE_OFFICIAL = 255
FIRMWARES = ("ardupilot", "px4")  # whose rules and encodings the mock follows
PX4_MAIN_MODE_AUTO, PX4_AUTO_MISSION = 4, 4  # PX4 src/modules/commander/px4_custom_mode.h


class Stream(IntEnum):
    """ArduPilot stream groups, valued as MAV_DATA_STREAM (for REQUEST_DATA_STREAM)."""

    RAW_SENS = mavlink2.MAV_DATA_STREAM_RAW_SENSORS
    EXT_STAT = mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS
    RC_CHAN = mavlink2.MAV_DATA_STREAM_RC_CHANNELS
    RAW_CTRL = mavlink2.MAV_DATA_STREAM_RAW_CONTROLLER
    POSITION = mavlink2.MAV_DATA_STREAM_POSITION
    EXTRA1 = mavlink2.MAV_DATA_STREAM_EXTRA1
    EXTRA2 = mavlink2.MAV_DATA_STREAM_EXTRA2
    EXTRA3 = mavlink2.MAV_DATA_STREAM_EXTRA3


@dataclass(frozen=True)
class MessageSpec:
    name: str
    stream: Stream | None  # None: in no group (requested individually), or HEARTBEAT
    default_hz: float

    @property
    def msg_id(self) -> int:
        return int(getattr(mavlink2, f"MAVLINK_MSG_ID_{self.name}"))


GROUP_DEFAULT_HZ = 1.0  # ArduPilot's default for every SRx_ group
# Sent only when their group is asked for (REQUEST_DATA_STREAM, a group override, gcs_request_rates()), though
# ArduPilot SITL sends them in their group from boot: the mock's boot set stays what it was before they existed,
# so its tlogs carry no truth (SIMSTATE would become a replay's reference) and one barometer and IMU stream.
GROUP_ON_REQUEST_HZ = 0.0
# The messages the mock streams, with their ArduPilot group and default rate. The groups are ArduPlane's
# GCS_Mavlink.cpp STREAM_*_msgs tables: RAW_SENSORS = RAW_IMU, SCALED_IMU2/3, SCALED_PRESSURE/2/3; EXTRA1 =
# ATTITUDE, SIMSTATE, AHRS2, RPM, AOA_SSA, …; EXTRA2 = VFR_HUD; EXTRA3 = AHRS, WIND, SYSTEM_TIME, …
MESSAGE_TABLE: tuple[MessageSpec, ...] = (
    MessageSpec("HEARTBEAT", None, 1.0),
    MessageSpec("RAW_IMU", Stream.RAW_SENS, GROUP_DEFAULT_HZ),
    MessageSpec("SCALED_IMU2", Stream.RAW_SENS, GROUP_ON_REQUEST_HZ),
    MessageSpec("SCALED_PRESSURE", Stream.RAW_SENS, GROUP_DEFAULT_HZ),
    MessageSpec("SCALED_PRESSURE2", Stream.RAW_SENS, GROUP_ON_REQUEST_HZ),
    MessageSpec("SYS_STATUS", Stream.EXT_STAT, GROUP_DEFAULT_HZ),
    MessageSpec("GPS_RAW_INT", Stream.EXT_STAT, GROUP_DEFAULT_HZ),
    MessageSpec("SERVO_OUTPUT_RAW", Stream.RC_CHAN, GROUP_DEFAULT_HZ),
    MessageSpec("GLOBAL_POSITION_INT", Stream.POSITION, GROUP_DEFAULT_HZ),
    MessageSpec("LOCAL_POSITION_NED", Stream.POSITION, GROUP_DEFAULT_HZ),
    MessageSpec("ATTITUDE", Stream.EXTRA1, GROUP_DEFAULT_HZ),
    MessageSpec("SIMSTATE", Stream.EXTRA1, GROUP_ON_REQUEST_HZ),
    MessageSpec("AOA_SSA", Stream.EXTRA1, GROUP_DEFAULT_HZ),
    MessageSpec("VFR_HUD", Stream.EXTRA2, GROUP_DEFAULT_HZ),
    MessageSpec("SYSTEM_TIME", Stream.EXTRA3, GROUP_DEFAULT_HZ),
    MessageSpec("WIND", Stream.EXTRA3, GROUP_DEFAULT_HZ),
    MessageSpec("HIGHRES_IMU", None, 0.0),
    MessageSpec("SCALED_IMU", None, 0.0),
    MessageSpec("ATTITUDE_QUATERNION", None, 0.0),
    MessageSpec("HOME_POSITION", None, 0.0),
    MessageSpec("AUTOPILOT_VERSION", None, 0.0),
    MessageSpec("GPS_GLOBAL_ORIGIN", None, 0.0),  # on request (MSG_ORIGIN): the EKF origin ExtNav positions are from
)


# What a ground station recording the flight asks for: every SRx_ group at 4 Hz.
# * ArduPilot's own defaults (ArduPlane/GCS_Mavlink.cpp, GCS_MAVLINK_Parameters::var_info, "default stream rates
#   to 1Hz"; the SRn_RAW_SENS … SRn_EXTRA3 parameter docs) are 1 Hz per group: what the vehicle sends to nobody.
# * A GCS overrides them on connecting. In the ArduPlane SITL tlog shared/data/logs/arduplane-sitl-gcs.tlog
#   (185 s, read with pymavlink's mavutil, rates over time_boot_ms/time_usec) the GCS (sysid 255) sends
#   REQUEST_DATA_STREAM(req_stream_id 0 = MAV_DATA_STREAM_ALL, req_message_rate 4, start) every 15 s (MAVProxy's
#   default `streamrate` 4), and RAW_IMU, SCALED_IMU2, SCALED_PRESSURE, SCALED_PRESSURE2 arrive at 4.17 Hz,
#   GPS_RAW_INT 3.95, SERVO_OUTPUT_RAW 3.39, ATTITUDE 3.26, VFR_HUD 3.04 Hz. Every group was asked for at 4 Hz; the
#   shortfalls are ArduPilot's stream scheduler deferring messages under load, which the mock does not model.
GCS_REQUEST_HZ = 4.0

# ArduPlane's main loop rate, SCHED_LOOP_RATE: 50 Hz unless set (libraries/AP_Scheduler/AP_Scheduler.cpp,
# SCHEDULER_DEFAULT_LOOP_RATE: 400 for Copter and Sub, 50 otherwise). GCS_MAVLINK::update_send runs at most once a
# loop and a message goes out at most once per call, so no stream is faster than the loop, whatever interval
# SET_MESSAGE_INTERVAL asked for; and the IMU sample sent is the latest one at that loop.
PLANE_LOOP_RATE_HZ = 50.0


def gcs_request_rates(hz: float = GCS_REQUEST_HZ) -> dict[str, float]:
    """The overrides (for :func:`default_rates`) of a ground station that asks for every group at ``hz``, as
    REQUEST_DATA_STREAM(MAV_DATA_STREAM_ALL, hz) does (HEARTBEAT and messages in no group keep their rates)."""
    return {group: hz for group in Stream.__members__}


def message_spec(name: str) -> MessageSpec | None:
    return next((s for s in MESSAGE_TABLE if s.name == name), None)


def message_name(msg_id: int) -> str | None:
    """The streamable message with MAVLink id ``msg_id`` (None: the mock cannot send it on request)."""
    return next((s.name for s in MESSAGE_TABLE if s.msg_id == msg_id), None)


def default_rates(overrides: Mapping[str, float] | None) -> dict[str, float]:
    """Rates [Hz] per message: the table, then group overrides (``"EXTRA1"``), then message overrides.

    Keys are message names or SRx_ group names (RAW_SENS, EXT_STAT, RC_CHAN, RAW_CTRL, POSITION, EXTRA1,
    EXTRA2, EXTRA3); 0 disables.
    """
    rates = {s.name: s.default_hz for s in MESSAGE_TABLE}
    overrides = dict(overrides or {})
    for key, hz in overrides.items():
        if not math.isfinite(hz) or hz < 0.0:
            raise UserInputError(f"stream rate {key} = {hz}: must be a finite rate ≥ 0 Hz")
        if key not in rates and key not in Stream.__members__:
            known = ", ".join([*Stream.__members__, *rates])
            raise UserInputError(f"stream rate {key!r}: unknown message or group (known: {known})")
    for key, hz in overrides.items():
        if key in Stream.__members__:
            for spec in MESSAGE_TABLE:
                if spec.stream is Stream[key]:
                    rates[spec.name] = hz
    for key, hz in overrides.items():
        if key in rates:
            rates[key] = hz
    return rates


class StreamScheduler:
    """Per-message intervals in world time and the next due time of each message."""

    def __init__(self, defaults: Mapping[str, float], *, loop_rate_hz: float = PLANE_LOOP_RATE_HZ) -> None:
        if not math.isfinite(loop_rate_hz) or loop_rate_hz <= 0.0:
            raise UserInputError(f"loop rate {loop_rate_hz} Hz: must be a finite rate > 0")
        self.loop_rate_hz = loop_rate_hz
        self._defaults = dict(defaults)
        self._interval_s: dict[str, float] = {}
        self._next_s: dict[str, float] = {}
        for name, hz in self._defaults.items():  # every stream starts at the first step, then keeps its phase
            self.set_rate(name, hz, now_s=-math.inf)

    def set_rate(self, name: str, hz: float, *, now_s: float) -> None:
        """Send ``name`` at ``hz`` (at most the loop rate) from ``now_s`` on (0 disables)."""
        if hz <= 0.0:
            self._interval_s.pop(name, None)
            self._next_s.pop(name, None)
            return
        interval = 1.0 / min(hz, self.loop_rate_hz)
        if self._interval_s.get(name) == interval:
            # the rate it has: it keeps its phase (GCS_Common.cpp, GCS_MAVLINK::set_ap_message_interval: a message
            # already in the bucket of that interval "don't need to move it")
            return
        self._interval_s[name] = interval
        self._next_s[name] = now_s

    def set_interval(self, name: str, interval_s: float, *, now_s: float) -> None:
        self.set_rate(name, 1.0 / interval_s, now_s=now_s)

    def reset(self, name: str, *, now_s: float) -> None:
        """Back to the configured default rate."""
        self.set_rate(name, self._defaults[name], now_s=now_s)

    def set_stream(self, stream: Stream, hz: float, *, now_s: float) -> None:
        for spec in MESSAGE_TABLE:
            if spec.stream is stream:
                self.set_rate(spec.name, hz, now_s=now_s)

    def defer(self, name: str, *, now_s: float) -> None:
        """``name`` was due but had nothing to report yet: due again at the next step (keeps no stale phase)."""
        if name in self._next_s:
            self._next_s[name] = now_s

    def interval_s(self, name: str) -> float | None:
        """The current interval (None: disabled)."""
        return self._interval_s.get(name)

    def due(self, now_s: float) -> list[str]:
        """Messages due at ``now_s``, in table order; advances their next due time."""
        out: list[str] = []
        for name, next_s in self._next_s.items():
            if now_s + SCHEDULE_EPSILON_S >= next_s:
                out.append(name)
                nxt = next_s + self._interval_s[name]
                self._next_s[name] = nxt if nxt > now_s + SCHEDULE_EPSILON_S else now_s + self._interval_s[name]
        return out


# ------------------------------------------------------------------------------------ unit conversions
def to_time_boot_ms(t_s: float) -> int:
    """Autopilot time since boot [s] → uint32 ms (truncated, like AP_HAL::millis)."""
    return math.floor(t_s * 1e3 + 1e-6) & 0xFFFFFFFF


def to_time_usec(t_s: float) -> int:
    return round(t_s * 1e6)


def to_deg_e7(deg: float) -> int:
    return round(deg * 1e7)


def to_mm(m: float) -> int:
    return round(m * 1e3)


def to_cm_s_int16(m_s: float) -> int:
    return _clamp(round(m_s * 100.0), -32768, 32767)


def to_cdeg_heading(rad: float) -> int:
    """Heading [rad] → cdeg in 0..35999."""
    return round(math.degrees(rad) * 100.0) % 36000


def to_hpa(pa: float) -> float:
    return pa / 100.0


def to_cdegc(c: float) -> int:
    """°C → cdegC, int16; 0 means "unknown" in MAVLink, so a true 0 is reported as 1."""
    v = _clamp(round(c * 100.0), -32768, 32767)
    return 1 if v == 0 else v


def to_mg(m_s2: float) -> int:
    """Acceleration → int16 milli-g (ArduPilot's RAW_IMU/SCALED_IMU unit)."""
    return _clamp(round(m_s2 / GRAVITY_M_S2 * 1e3), -32768, 32767)


def to_mrad_s(rad_s: float) -> int:
    return _clamp(round(rad_s * 1e3), -32768, 32767)


def to_mgauss(t: float) -> int:
    """Magnetic flux density [T] → int16 milligauss (1 mG = 1e-7 T)."""
    return _clamp(round(t * 1e7), -32768, 32767)


def to_gauss(t: float) -> float:
    return t * 1e4


def equivalent_airspeed_m_s(dp_pa: float) -> float:
    """Pitot Δp → equivalent airspeed, ``sqrt(2Δp/ρ0)`` (ArduPilot's airspeed with ARSPD_RATIO = 2/ρ0)."""
    return math.sqrt(2.0 * max(dp_pa, 0.0) / RHO0_KG_M3)


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


# ------------------------------------------------------------------------------------------ encoders
@dataclass(frozen=True)
class NavEstimate:
    """The autopilot's own navigation solution (its EKF): truth, plus the dead-reckoning error in outages.

    What GLOBAL_POSITION_INT, LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION and VFR_HUD report (the truth is
    SIMSTATE's). The attitude carries the error of an autopilot integrating its gyro
    (:mod:`sim.flight.ap_attitude`); the body rates and the airspeed estimate are the truth's."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    pos_ned_m: F64Array
    v_ned_m_s: F64Array
    error_ned_m: F64Array
    q_nb: F64Array  # attitude body → NED, scalar first
    omega_b_rad_s: F64Array  # body rates (ArduPilot: AHRS get_gyro(), the bias-corrected gyro)
    airspeed_m_s: float  # AHRS airspeed_estimate (VFR_HUD's without an airspeed sensor)


class SensorState:
    """The latest truth, estimate and sensor samples the autopilot has (samples hold until replaced)."""

    def __init__(self, home: tuple[float, float, float]) -> None:
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = home
        self.truth: VehicleTruth | None = None
        self.estimate: NavEstimate | None = None
        self.imu: ImuSample | None = None
        self.imu2: ImuSample | None = None  # the second IMU (SCALED_IMU2)
        self.gnss: GnssSample | None = None
        self.baro: BaroSample | None = None
        self.baro2: BaroSample | None = None  # the second barometer (SCALED_PRESSURE2)
        self.ground_pressure_pa: float | None = None  # the barometer's at boot (AP_Baro's ground calibration)
        self.mag: MagSample | None = None
        self.airspeed: AirspeedSample | None = None
        self.servos: ServoSample | None = None
        self.gnss_outage = False
        self.unix_time_at_boot_us = 0

    @property
    def has_fix(self) -> bool:
        return not self.gnss_outage and self.gnss is not None and self.gnss.fix_type >= mavlink2.GPS_FIX_TYPE_2D_FIX


class TelemetryEncoder:
    """Builds each streamed message from a :class:`SensorState` at autopilot time ``t_s``.

    ``encode`` returns None when the message has nothing to report yet (e.g. no IMU sample).
    """

    def __init__(self, mav: mavlink2.MAVLink, *, firmware: str = "ardupilot") -> None:
        if firmware not in FIRMWARES:
            raise ValueError(f"firmware = {firmware!r}: one of {', '.join(FIRMWARES)}")
        self._mav = mav
        self._px4 = firmware == "px4"
        self._builders: dict[str, Callable[[SensorState, float], MavlinkMessage | None]] = {
            "HEARTBEAT": self.heartbeat,
            "RAW_IMU": self.raw_imu,
            "SCALED_IMU": self.scaled_imu,
            "SCALED_IMU2": self.scaled_imu2,
            "HIGHRES_IMU": self.highres_imu,
            "SCALED_PRESSURE": self.scaled_pressure,
            "SCALED_PRESSURE2": self.scaled_pressure2,
            "SYS_STATUS": self.sys_status,
            "GPS_RAW_INT": self.gps_raw_int,
            "SERVO_OUTPUT_RAW": self.servo_output_raw,
            "GLOBAL_POSITION_INT": self.global_position_int,
            "LOCAL_POSITION_NED": self.local_position_ned,
            "ATTITUDE": self.attitude,
            "SIMSTATE": self.simstate,
            "ATTITUDE_QUATERNION": self.attitude_quaternion,
            "AOA_SSA": self.aoa_ssa,
            "VFR_HUD": self.vfr_hud,
            "SYSTEM_TIME": self.system_time,
            "WIND": self.wind,
            "HOME_POSITION": self.home_position,
            "AUTOPILOT_VERSION": self.autopilot_version,
            "GPS_GLOBAL_ORIGIN": self.gps_global_origin,
        }
        assert set(self._builders) == {s.name for s in MESSAGE_TABLE}

    def encode(self, name: str, state: SensorState, t_s: float) -> MavlinkMessage | None:
        return self._builders[name](state, t_s)

    def heartbeat(self, state: SensorState, t_s: float) -> MavlinkMessage:
        # ArduPlane in AUTO, armed and flying; PX4 in AUTO.MISSION (px4_custom_mode.h: main mode in bits 16-23,
        # sub mode in 24-31)
        base_mode = (
            mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
            | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            | mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        )
        if self._px4:
            custom_mode = (PX4_MAIN_MODE_AUTO << 16) | (PX4_AUTO_MISSION << 24)
            return self._mav.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_PX4, base_mode,
                                              custom_mode, mavlink2.MAV_STATE_ACTIVE, 3)  # fmt: skip
        return self._mav.heartbeat_encode(
            mavlink2.MAV_TYPE_FIXED_WING,
            mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode,
            mavlink2.PLANE_MODE_AUTO,
            mavlink2.MAV_STATE_ACTIVE,
            3,
        )

    @staticmethod
    def _imu_ints(imu: ImuSample, mag: MagSample | None) -> list[int]:
        """x/y/z acc [mG], gyro [mrad/s], mag [mgauss] (0 without that compass, as ArduPilot sends)."""
        field = mag.field_b_t if mag is not None else np.zeros(3)
        return [
            *(to_mg(float(v)) for v in imu.accel_b_m_s2),
            *(to_mrad_s(float(v)) for v in imu.gyro_b_rad_s),
            *(to_mgauss(float(v)) for v in field),
        ]

    def raw_imu(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """IMU 1, already scaled (ArduPilot's RAW_IMU is SCALED_IMU's units), ``time_usec`` µs since boot."""
        imu = state.imu
        if imu is None:
            return None
        ints = self._imu_ints(imu, state.mag)
        return self._mav.raw_imu_encode(to_time_usec(imu.t_s), *ints, 0, to_cdegc(imu.temperature_c))

    def scaled_imu(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        imu = state.imu
        if imu is None:
            return None
        ints = self._imu_ints(imu, state.mag)
        return self._mav.scaled_imu_encode(to_time_boot_ms(imu.t_s), *ints, to_cdegc(imu.temperature_c))

    def scaled_imu2(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """IMU 2 with compass 2's field: the world has one magnetometer, so 0 (ArduPilot's send_scaled_imu)."""
        imu = state.imu2
        if imu is None:
            return None
        ints = self._imu_ints(imu, None)
        return self._mav.scaled_imu2_encode(to_time_boot_ms(imu.t_s), *ints, to_cdegc(imu.temperature_c))

    def highres_imu(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """As ArduPilot's GCS_MAVLINK::send_highres_imu: the first IMU and compass, and barometer 1 with
        diff_pressure = its pressure less the ground pressure (not the airspeed sensor's), temperature its.
        PX4 (src/modules/mavlink/streams/HIGHRES_IMU.hpp): diff_pressure is the airspeed sensor's
        (differential_pressure topic, bit 10 only when it has one)."""
        imu = state.imu
        if imu is None:
            return None
        updated = 0x3F  # x/y/z acc and gyro
        mag = [0.0, 0.0, 0.0]
        if state.mag is not None:
            mag = [to_gauss(float(v)) for v in state.mag.field_b_t]
            updated |= 0x1C0
        abs_hpa = diff_hpa = alt_m = temp_c = 0.0
        if state.baro is not None:
            p = state.baro.pressure_pa
            ground = state.ground_pressure_pa if state.ground_pressure_pa is not None else p
            abs_hpa, diff_hpa, alt_m = to_hpa(p), to_hpa(p - ground), pressure_altitude_m(p)
            temp_c = state.baro.temperature_c
            updated |= 0x200 | 0x400 | 0x800 | 0x1000
            if self._px4:
                diff_hpa = to_hpa(state.airspeed.dp_pa) if state.airspeed is not None else 0.0
                updated &= ~0x400 if state.airspeed is None else ~0
        return self._mav.highres_imu_encode(
            to_time_usec(imu.t_s),
            *(float(v) for v in imu.accel_b_m_s2),
            *(float(v) for v in imu.gyro_b_rad_s),
            *mag,
            abs_hpa,
            diff_hpa,
            alt_m,
            temp_c,
            updated,
            0,
        )

    @staticmethod
    def _pressure_fields(baro: BaroSample, airspeed: AirspeedSample | None) -> tuple[int, float, float, int, int]:
        """Barometer n and airspeed sensor n, as ArduPilot's send_scaled_pressure_instance: time_boot_ms,
        press_abs and press_diff [hPa] (0 without that airspeed sensor), temperature and the airspeed sensor's
        [cdegC] (0 = unknown)."""
        diff_hpa, diff_temp = 0.0, 0
        if airspeed is not None:
            diff_hpa, diff_temp = to_hpa(airspeed.dp_pa), to_cdegc(airspeed.temperature_c)
        return to_time_boot_ms(baro.t_s), to_hpa(baro.pressure_pa), diff_hpa, to_cdegc(baro.temperature_c), diff_temp

    def scaled_pressure(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        if state.baro is None:
            return None
        return self._mav.scaled_pressure_encode(*self._pressure_fields(state.baro, state.airspeed))

    def scaled_pressure2(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """Barometer 2 and airspeed sensor 2 (recent ArduPilot): the world has one airspeed sensor, so Δp 0."""
        if state.baro2 is None:
            return None
        return self._mav.scaled_pressure2_encode(*self._pressure_fields(state.baro2, None))

    def sys_status(self, state: SensorState, t_s: float) -> MavlinkMessage:
        present = (
            mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
            | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG
            | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | mavlink2.MAV_SYS_STATUS_SENSOR_DIFFERENTIAL_PRESSURE
            | mavlink2.MAV_SYS_STATUS_SENSOR_GPS
            | mavlink2.MAV_SYS_STATUS_AHRS
        )
        health = present if state.has_fix else present & ~mavlink2.MAV_SYS_STATUS_SENSOR_GPS
        health |= mavlink2.MAV_SYS_STATUS_GEOFENCE  # ArduPilot: fence healthy = not breached (none configured)
        # no battery in the world: voltage UINT16_MAX, current and remaining −1 ("not sent")
        return self._mav.sys_status_encode(present, present, health, 250, UINT16_UNKNOWN, -1, -1, 0, 0, 0, 0, 0, 0)

    def gps_raw_int(self, state: SensorState, t_s: float) -> MavlinkMessage:
        g = state.gnss
        if not state.has_fix or g is None:
            # what ArduPilot reports with the fix lost: NO_FIX, no position, unknown accuracies
            return self._mav.gps_raw_int_encode(
                to_time_usec(t_s),
                mavlink2.GPS_FIX_TYPE_NO_FIX,
                0,
                0,
                0,
                UINT16_UNKNOWN,
                UINT16_UNKNOWN,
                UINT16_UNKNOWN,
                UINT16_UNKNOWN,
                0,
            )
        vn, ve = float(g.v_ned_m_s[0]), float(g.v_ned_m_s[1])
        return self._mav.gps_raw_int_encode(
            to_time_usec(g.t_s),
            g.fix_type,
            to_deg_e7(g.lat_deg),
            to_deg_e7(g.lon_deg),
            to_mm(g.alt_m),
            min(round(g.hdop * 100.0), UINT16_UNKNOWN - 1),
            min(round(g.vdop * 100.0), UINT16_UNKNOWN - 1),
            min(round(math.hypot(vn, ve) * 100.0), UINT16_UNKNOWN - 1),
            to_cdeg_heading(math.atan2(ve, vn)),
            g.satellites,
            0,  # alt_ellipsoid: no geoid in the world
            to_mm(g.h_acc_m),
            to_mm(g.v_acc_m),
            to_mm(g.vel_acc_m_s),
            0,
            0,
        )

    def servo_output_raw(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        s = state.servos
        if s is None:
            return None
        pwm = [round(float(v)) for v in s.pwm_us[:16]]
        pwm += [0] * (16 - len(pwm))
        return self._mav.servo_output_raw_encode(to_time_usec(s.t_s) & 0xFFFFFFFF, 0, *pwm)

    def global_position_int(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        est = state.estimate
        if est is None:
            return None
        yaw = euler_from_quat(est.q_nb)[2]
        return self._mav.global_position_int_encode(
            to_time_boot_ms(t_s),
            to_deg_e7(est.lat_deg),
            to_deg_e7(est.lon_deg),
            to_mm(est.alt_m),
            to_mm(est.alt_m - state.home_alt_m),
            *(to_cm_s_int16(float(v)) for v in est.v_ned_m_s),
            to_cdeg_heading(yaw),
        )

    def local_position_ned(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        est = state.estimate
        if est is None:
            return None
        return self._mav.local_position_ned_encode(
            to_time_boot_ms(t_s), *(float(v) for v in est.pos_ned_m), *(float(v) for v in est.v_ned_m_s)
        )

    def attitude(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """The autopilot's estimate: ZYX Euler angles [rad] and body rates [rad/s]."""
        est = state.estimate
        if est is None:
            return None
        return self._mav.attitude_encode(
            to_time_boot_ms(t_s), *euler_from_quat(est.q_nb), *(float(v) for v in est.omega_b_rad_s)
        )

    def simstate(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """The simulator's truth, as ArduPilot SITL's SIM::simstate_send: roll, pitch, yaw (−π..π) [rad], the
        accelerometer's ideal reading (specific force, body) [m/s²], body rates [rad/s], lat/lng [degE7]. No
        time field: a reader stamps it with the tlog's."""
        truth = state.truth
        if truth is None:
            return None
        return self._mav.simstate_encode(
            *euler_from_quat(truth.q_nb),
            *(float(v) for v in truth.specific_force_b_m_s2),
            *(float(v) for v in truth.omega_b_rad_s),
            to_deg_e7(truth.lat_deg),
            to_deg_e7(truth.lon_deg),
        )

    def attitude_quaternion(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        est = state.estimate
        if est is None:
            return None
        return self._mav.attitude_quaternion_encode(
            to_time_boot_ms(t_s), *(float(v) for v in est.q_nb), *(float(v) for v in est.omega_b_rad_s)
        )

    def aoa_ssa(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        truth = state.truth
        if truth is None:
            return None
        return self._mav.aoa_ssa_encode(to_time_usec(t_s), math.degrees(truth.alpha_rad), math.degrees(truth.beta_rad))

    def vfr_hud(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        """Airspeed (the airspeed sensor's, else the estimate's, as ArduPlane's vfr_hud_airspeed), ground speed,
        heading [deg], throttle [%], altitude AMSL and climb rate of the estimate."""
        est, truth = state.estimate, state.truth
        if est is None or truth is None:
            return None
        airspeed = equivalent_airspeed_m_s(state.airspeed.dp_pa) if state.airspeed is not None else est.airspeed_m_s
        yaw = euler_from_quat(est.q_nb)[2]
        return self._mav.vfr_hud_encode(
            airspeed,
            math.hypot(float(est.v_ned_m_s[0]), float(est.v_ned_m_s[1])),
            round(math.degrees(yaw)) % 360,
            round(100.0 * truth.throttle),
            est.alt_m,
            -float(est.v_ned_m_s[2]),
        )

    def system_time(self, state: SensorState, t_s: float) -> MavlinkMessage:
        return self._mav.system_time_encode(state.unix_time_at_boot_us + to_time_usec(t_s), to_time_boot_ms(t_s))

    def wind(self, state: SensorState, t_s: float) -> MavlinkMessage | None:
        truth = state.truth
        if truth is None:
            return None
        wn, we, wd = (float(v) for v in truth.wind_ned_m_s)
        # ArduPilot: the direction the wind comes from [deg, −180..180], 3-D speed, vertical component
        return self._mav.wind_encode(math.degrees(math.atan2(-we, -wn)), math.sqrt(wn * wn + we * we + wd * wd), wd)

    def home_position(self, state: SensorState, t_s: float) -> MavlinkMessage:
        return self._mav.home_position_encode(
            to_deg_e7(state.home_lat_deg),
            to_deg_e7(state.home_lon_deg),
            to_mm(state.home_alt_m),
            0.0,
            0.0,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            to_time_usec(t_s),
        )

    def gps_global_origin(self, state: SensorState, t_s: float) -> MavlinkMessage:
        """The EKF origin (GCS_Common.cpp send_gps_global_origin: degE7, altitude AMSL in mm): the mock's EKF
        origin is its home, where its estimate's NED frame starts (sim/sitl/extnav_judge.py)."""
        return self._mav.gps_global_origin_encode(
            to_deg_e7(state.home_lat_deg), to_deg_e7(state.home_lon_deg), to_mm(state.home_alt_m), to_time_usec(t_s)
        )

    def autopilot_version(self, state: SensorState, t_s: float) -> MavlinkMessage:
        major, minor, patch = PX4_VERSION if self._px4 else PLANE_VERSION
        capabilities = (
            mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        )
        return self._mav.autopilot_version_encode(
            capabilities,
            (major << 24) | (minor << 16) | (patch << 8) | FIRMWARE_VERSION_TYPE_OFFICIAL,
            0,
            0,
            0,
            list(b"vdmsitl\x00"),
            [0] * 8,
            [0] * 8,
            0,
            0,
            0x5644_4D53_4954_4C31,  # "VDMSITL1"
        )

    # --------------------------------------------------------------------------- event messages (ports)
    def named_value_float(self, t_s: float, name: str, value: float) -> MavlinkMessage:
        return self._mav.named_value_float_encode(to_time_boot_ms(t_s), name.encode("ascii"), value)

    def debug_float_array(self, t_s: float, name: str, array_id: int, values: F64Array) -> MavlinkMessage:
        data = [float(v) for v in values] + [0.0] * (DEBUG_FLOAT_ARRAY_LEN - len(values))
        return self._mav.debug_float_array_encode(to_time_usec(t_s), name.encode("ascii"), array_id, data)
