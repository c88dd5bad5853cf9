"""MAVLink telemetry logs (``.tlog``: MAVProxy, QGroundControl, Mission Planner, the mock autopilot) → the SI
measurement stream.

A tlog is a sequence of records: the receive time as 8 big-endian bytes of µs since the Unix epoch, then one
MAVLink 1 or 2 frame. The records are framed here from the frame headers (the length is in byte 1), so that
only the messages the stream needs are decoded, by pymavlink, with their CRC checked: the others are counted
by type and skipped undecoded, which makes reading about ten times faster than ``mavutil``'s generic loop.

The conversion is the service's (:mod:`firmware_bridge.units`, :class:`~firmware_bridge.inputs.PortAssembler`,
:class:`~firmware_bridge.inputs.AutopilotClock`), so a replayed tlog gives the filter what the live link gave
it. Times are the autopilot's own (``time_usec`` / ``time_boot_ms``, boot time made continuous across
reboots); the tlog's wall-clock stamps are used only for what carries no autopilot time (SIMSTATE) and to
close partial port frames.

===================  =========================================================================
message              stream
===================  =========================================================================
HIGHRES_IMU          IMU (SI floats) and magnetometer (gauss → µT); preferred when present
SCALED_IMU           IMU (mG, mrad/s) and magnetometer (mgauss) when there is no HIGHRES_IMU
SCALED_PRESSURE      static pressure (hPa → Pa) and pitot Δp (hPa → Pa; exactly 0 = no sensor)
GPS_RAW_INT          3-D fixes (degE7, mm, cm/s, cdeg; no vertical velocity → v_D NaN); stamped when the
                     autopilot received the fix, so the time of validity is the stamp less the autopilot's
                     default receiver lag (ArduPilot 0.12 s, PX4 0.11 s: units.GNSS_LATENCY_DEFAULT_S)
SERVO_OUTPUT_RAW     PWM of servo 1–4 (ArduPlane order: aileron, elevator, throttle, rudder)
NAMED_VALUE_FLOAT    port Δp [Pa], one message per port (the Lua script / the mock)
DEBUG_FLOAT_ARRAY    port Δp [Pa], one message per frame (``ports_array_id``)
SYSTEM_TIME          UTC of the autopilot's boot
SIMSTATE, SIM_STATE  truth in ArduPilot SITL (the simulator's position and attitude)
===================  =========================================================================
"""

from __future__ import annotations

import math
import mmap
import struct
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.inputs import AutopilotClock, PortAssembler, PortFrameIn
from firmware_bridge.logs.common import LogFormatError, LogRead, ReadReport, StreamBuilder, TruthTrack
from vdm_aero.rotation import quat_from_euler

__all__ = ["read_tlog"]

STAMP = struct.Struct(">Q")
V1, V2 = 0xFE, 0xFD
V2_SIGNED = 0x01
UNIX_USEC_MIN = 10**15  # time_usec above this is Unix time (2001+), not time since boot
UINT32_WRAP_S = 2**32 * 1e-6  # SERVO_OUTPUT_RAW.time_usec is a uint32: it wraps every 71.6 min
STAMP_PLAUSIBLE_US = 86_400 * 10**6  # resynchronising: a record stamped within a day of the last good one
PORT_FRAME_TIMEOUT_S = 0.05
PROGRESS_EVERY_BYTES = 1 << 20
_NEEDED = {
    "HEARTBEAT", "HIGHRES_IMU", "SCALED_IMU", "SCALED_PRESSURE", "GPS_RAW_INT", "SERVO_OUTPUT_RAW",
    "NAMED_VALUE_FLOAT", "DEBUG_FLOAT_ARRAY", "SYSTEM_TIME", "SIMSTATE", "SIM_STATE",
}  # fmt: skip
_NOT_VEHICLES = (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_TYPE_ONBOARD_CONTROLLER)
_NAMES = {i: getattr(c, "msgname", str(i)) for i, c in mavlink2.mavlink_map.items()}
_NEEDED_IDS = {i for i, n in _NAMES.items() if n in _NEEDED}


class _Reader:
    def __init__(self, path: Path, port_names: Sequence[str], system_id: int | None, ports_array_id: int,
                 gnss_latency_s: float | None = None) -> None:  # fmt: skip
        self.path = path
        self.report = ReadReport(path=path, format="tlog", time_base="")
        self.builder = StreamBuilder(port_names)
        self.mav = mavlink2.MAVLink(None)
        self.system_id = system_id
        self.autopilot: tuple[int, int] | None = None
        self.latency_given = gnss_latency_s
        self.gnss_latency_s = (
            gnss_latency_s if gnss_latency_s is not None else units.GNSS_LATENCY_DEFAULT_S["ardupilot"]
        )
        self.ports_array_id = ports_array_id
        self.n_ports = len(port_names)
        self.assembler = PortAssembler(port_names, timeout_s=PORT_FRAME_TIMEOUT_S) if port_names else None
        self.clock = AutopilotClock()
        self.boot_minus_stamp_s: float | None = None  # autopilot time − tlog stamp, from the latest IMU sample
        self.imu_t_s = -math.inf  # the latest IMU time (continuous)
        self.scaled_imu: list[units.ImuSample] = []
        self.highres = 0
        self.last_mag: tuple[float, float, float] | None = None
        self.unix_boot: list[float] = []
        self.truth: list[tuple[float, ...]] = []
        self.truth_source = ""
        self.dfa_frames = 0

    # -------------------------------------------------------------------------------------- framing
    def read(self, progress: Callable[[float], None] | None) -> None:
        with self.path.open("rb") as f:
            size = self.report.file_bytes = self.path.stat().st_size
            if size == 0:
                raise LogFormatError(f"{self.path}: empty file (not a MAVLink telemetry log)")
            buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            try:
                self._records(buf, size, progress)
            finally:
                buf.close()

    def _records(self, buf: mmap.mmap, size: int, progress: Callable[[float], None] | None) -> None:
        pos, decoded, last_stamp = 0, 0, None
        next_progress = PROGRESS_EVERY_BYTES
        needed, names, rep = _NEEDED_IDS, _NAMES, self.report
        while pos + 8 < size:
            if progress is not None and pos >= next_progress:
                progress(pos / size)
                next_progress = pos + PROGRESS_EVERY_BYTES
            magic = buf[pos + 8]
            if magic == V2 and pos + 18 <= size:
                n = 12 + buf[pos + 9] + (13 if buf[pos + 10] & V2_SIGNED else 0)
                msg_id = buf[pos + 15] | buf[pos + 16] << 8 | buf[pos + 17] << 16
            elif magic == V1 and pos + 14 <= size:
                n = 8 + buf[pos + 9]
                msg_id = buf[pos + 13]
            elif magic in (V1, V2):
                rep.truncated_at_byte = pos
                break
            else:
                pos = self._resync(buf, pos, size, last_stamp)
                continue
            end = pos + 8 + n
            if end > size:
                rep.truncated_at_byte = pos  # the file ends inside this record
                break
            stamp = STAMP.unpack_from(buf, pos)[0]
            if last_stamp is not None and abs(stamp - last_stamp) > STAMP_PLAUSIBLE_US:
                pos = self._resync(buf, pos, size, last_stamp)
                continue
            if msg_id not in needed:
                name = names.get(msg_id)
                rep.skip(name if name is not None else f"id {msg_id}")
                pos, last_stamp = end, stamp
                continue
            try:
                msg = self.mav.decode(bytearray(buf[pos + 8 : end]))
            except (mavlink2.MAVError, struct.error, ValueError, IndexError):
                pos = self._resync(buf, pos, size, last_stamp)
                continue
            pos, last_stamp, decoded = end, stamp, decoded + 1
            self._message(msg, stamp * 1e-6)
        if decoded == 0:  # records skipped undecoded are not proof: garbage can look like a frame header
            raise LogFormatError(f"{self.path}: no valid MAVLink message with a sensor stream (not a telemetry log)")
        if self.assembler is not None and (fr := self.assembler.expire(math.inf)) is not None:
            self._port_frame(fr)

    def _resync(self, buf: mmap.mmap, pos: int, size: int, last_stamp: int | None) -> int:
        """A record that is not one (garbage, a corrupted length): count it and look for the next offset whose
        stamp is plausible and whose frame starts with a MAVLink magic byte."""
        self.report.malformed += 1
        p = pos + 1
        while p + 8 < size:
            if buf[p + 8] in (V1, V2):
                stamp = STAMP.unpack_from(buf, p)[0]
                if last_stamp is None or abs(stamp - last_stamp) <= STAMP_PLAUSIBLE_US:
                    return p
            p += 1
        return size

    # ------------------------------------------------------------------------------------- messages
    def _message(self, m: mavlink2.MAVLink_message, stamp_s: float) -> None:
        kind = m.get_type()
        src = (m.get_srcSystem(), m.get_srcComponent())
        if kind == "HEARTBEAT":
            is_autopilot = m.autopilot != mavlink2.MAV_AUTOPILOT_INVALID and m.type not in _NOT_VEHICLES
            if self.autopilot is None and is_autopilot and self.system_id in (None, src[0]):
                self.autopilot = src
                if self.latency_given is None:
                    self.gnss_latency_s = units.gnss_latency_default_s(int(m.autopilot))
            return
        if src != self.autopilot:
            self.report.skip(f"{kind} (not from the autopilot)")
            return
        rep = self.report
        if kind == "HIGHRES_IMU":
            self.highres += 1
            self._imu(units.from_highres_imu(m), stamp_s)
        elif kind == "SCALED_IMU":
            self.scaled_imu.append(units.from_scaled_imu(m))
        elif kind == "SCALED_PRESSURE":
            try:
                s = units.from_scaled_pressure(m)
            except ValueError:  # an impossible static pressure (a glitched sensor): skipped and counted
                rep.skip("SCALED_PRESSURE (static pressure out of range)")
                return
            t = self.clock.filter_s(s.t_s)
            self.builder.baro(t, s.static_pa)
            if math.isfinite(s.pitot_dp_pa):
                self.builder.pitot(t, s.pitot_dp_pa, s.pitot_temperature_c)
        elif kind == "GPS_RAW_INT":
            fix = units.from_gps_raw_int(m)
            if fix is None:
                rep.skip("GPS_RAW_INT (no 3-D fix)")
                return
            t = fix.t_s - self.gnss_latency_s  # the time of validity (the log's gnss_t_s)
            if m.time_usec > UNIX_USEC_MIN:  # some autopilots stamp fixes in Unix time
                if not self.unix_boot:
                    rep.skip("GPS_RAW_INT (Unix time before SYSTEM_TIME)")
                    return
                t -= float(np.median(self.unix_boot))
            self.builder.gnss(self.clock.filter_s(t), fix.lat_deg, fix.lon_deg, fix.alt_m, fix.v_ned_m_s)
        elif kind == "SERVO_OUTPUT_RAW":
            pwm = units.from_servo_output_raw(m)
            t = pwm.t_s
            if math.isfinite(self.imu_t_s):  # unwrap the uint32 µs against the IMU's clock
                t += round((self.clock.boot_s(self.imu_t_s) - t) / UINT32_WRAP_S) * UINT32_WRAP_S
            self.builder.servo(self.clock.filter_s(t), pwm.pwm_us[:4])
        elif kind == "NAMED_VALUE_FLOAT":
            if self.assembler is None:
                rep.skip("NAMED_VALUE_FLOAT (no port names given)")
                return
            name = m.name if isinstance(m.name, str) else m.name.decode("ascii", "replace")
            for fr in self.assembler.add(int(m.time_boot_ms), name.rstrip("\0"), float(m.value), stamp_s):
                self._port_frame(fr)
        elif kind == "DEBUG_FLOAT_ARRAY":
            if self.n_ports == 0 or m.array_id != self.ports_array_id:
                rep.skip("DEBUG_FLOAT_ARRAY (not the ports)")
                return
            self.dfa_frames += 1
            if self.assembler is None or self.assembler.counts["complete"] == 0:  # named values win when both
                self._port_frame(PortFrameIn(m.time_usec * 1e-6, np.asarray(m.data[: self.n_ports], float), True,
                                             stamp_s))  # fmt: skip
        elif kind == "SYSTEM_TIME":
            if m.time_unix_usec > 0:
                self.unix_boot.append(m.time_unix_usec * 1e-6 - m.time_boot_ms * 1e-3)
        elif kind in ("SIMSTATE", "SIM_STATE"):
            self._truth(m, kind, stamp_s)
            return
        rep.count(kind)

    def _imu(self, s: units.ImuSample, stamp_s: float) -> None:
        if self.clock.observe_boot_s(s.t_s):
            self.report.reboots += 1
        t = self.clock.filter_s(s.t_s)
        self.imu_t_s = t
        self.boot_minus_stamp_s = t - stamp_s
        self.builder.imu(t, s.gyro_b_rad_s, s.accel_b_m_s2, s.temperature_c)
        if s.mag_b_ut is not None and s.mag_b_ut != self.last_mag:
            self.last_mag = s.mag_b_ut  # HIGHRES_IMU repeats a slower magnetometer's sample: keep new ones
            self.builder.mag(t, s.mag_b_ut)

    def _port_frame(self, fr: PortFrameIn) -> None:
        self.builder.ports(self.clock.filter_s(fr.t_s), fr.dp_pa)

    def _truth(self, m: mavlink2.MAVLink_message, kind: str, stamp_s: float) -> None:
        if self.boot_minus_stamp_s is None:
            self.report.skip(f"{kind} (before the first IMU sample)")
            return
        t = stamp_s + self.boot_minus_stamp_s  # neither carries an autopilot time: the tlog stamp, mapped
        if kind == "SIMSTATE":  # degE7, radians; no altitude
            q = quat_from_euler(m.roll, m.pitch, m.yaw)
            self.truth.append((t, m.lat * 1e-7, m.lng * 1e-7, math.nan, *q))
        else:  # SIM_STATE: degrees as floats (lat_int/lon_int degE7 on newer firmware), m, quaternion w, x, y, z
            lat = m.lat_int * 1e-7 if getattr(m, "lat_int", 0) else m.lat
            lon = m.lon_int * 1e-7 if getattr(m, "lon_int", 0) else m.lon
            self.truth.append((t, lat, lon, m.alt, m.q1, m.q2, m.q3, m.q4))
        self.truth_source = f"tlog {kind}"
        self.report.count(kind)

    # ---------------------------------------------------------------------------------------- result
    def result(self) -> LogRead:
        rep = self.report
        if self.autopilot is None:
            raise LogFormatError(f"{self.path}: no autopilot HEARTBEAT (cannot tell the autopilot's messages apart)")
        if self.highres == 0:
            for s in self.scaled_imu:  # the coarser integers, only when there is nothing better
                self._imu(s, math.nan)
            if self.scaled_imu:
                rep.used["SCALED_IMU"] = len(self.scaled_imu)
        elif self.scaled_imu:
            rep.unknown["SCALED_IMU (HIGHRES_IMU used)"] = len(self.scaled_imu)
        rep.time_base = ("HIGHRES_IMU.time_usec" if self.highres else "SCALED_IMU.time_boot_ms") + (
            " (autopilot boot time" + (f", {self.clock.reboots} reboot(s) made continuous)" if self.clock.reboots
                                       else ")"))  # fmt: skip
        if self.assembler is not None:
            c = self.assembler.counts
            rep.used["port frames"] = c["complete"] + c["partial"]
            if c["partial"]:
                rep.warn(f"{self.path.name}: {c['partial']} port frames incomplete (missing ports are NaN)")
            if c["unknown_name"]:
                rep.unknown["NAMED_VALUE_FLOAT (not a port)"] = c["unknown_name"]
            if c["complete"] + c["partial"] + self.dfa_frames == 0:
                rep.warn(f"{self.path.name}: no port values ({', '.join(self.assembler.names)}) in the log")
        truth = None
        if self.truth:
            a = np.array(self.truth)
            truth = TruthTrack(self.truth_source, a[:, 0], a[:, 1], a[:, 2], a[:, 3], None, a[:, 4:8])
        unix = float(np.median(self.unix_boot)) if self.unix_boot else None
        log = self.builder.build(self.path, rep, meta={"autopilot": list(self.autopilot),
                                                       "gnss_latency_s": self.gnss_latency_s})  # fmt: skip
        return LogRead(log, truth, rep, unix)


def read_tlog(path: Path, port_names: Sequence[str] = (), *, system_id: int | None = None, ports_array_id: int = 0,
              gnss_latency_s: float | None = None, progress: Callable[[float], None] | None = None
              ) -> LogRead:  # fmt: skip
    """Read a telemetry log (module docstring); ``port_names`` in the order of the returned port columns,
    ``system_id`` the autopilot's (default: the first autopilot heard); ``gnss_latency_s`` the receiver latency
    between a fix's validity and its GPS_RAW_INT stamp (default: the autopilot's default; in ``meta``)."""
    r = _Reader(Path(path), port_names, system_id, ports_array_id, gnss_latency_s)
    r.read(progress)
    return r.result()
