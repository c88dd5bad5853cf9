"""MAVLink telemetry logs (``.tlog``: MAVProxy, QGroundControl, Mission Planner, the mock autopilot) → the SI
measurement stream.

A tlog is a sequence of records: the receive time as 8 big-endian bytes of µs since the Unix epoch, then one
MAVLink 1 or 2 frame. The records are framed here from the frame headers (the length is in byte 1), so that
only the messages the stream needs are decoded, by pymavlink, with their CRC checked: the others are counted
by type and skipped undecoded, which makes reading about ten times faster than ``mavutil``'s generic loop.

The messages are decoded by the service's own decoder (:class:`firmware_bridge.decode.MavlinkDecoder`: its
table of converters, its choice of streams, its clock), so a replayed tlog gives the filter what the live
link gave it; this module only frames the records and collects the samples. Times are the autopilot's own
(``time_usec`` / ``time_boot_ms``, boot time made continuous across reboots); the tlog's wall-clock stamps
are used only for what carries no autopilot time (SIMSTATE) and to close partial port frames.

=========================  ===================================================================
message                    stream
=========================  ===================================================================
HIGHRES_IMU                IMU (SI floats), magnetometer (gauss → µT); PX4: barometer and
                           airspeed Δp (hPa → Pa) when ``fields_updated`` marks them new
RAW_IMU (ArduPilot)        the first IMU, already scaled by ArduPilot (mG, mrad/s, mgauss)
SCALED_IMU, SCALED_IMU2/3  the first, second, third IMU (mG, mrad/s, mgauss); the best of these
                           IMU streams heard is used (decode.IMU_SOURCES; the report says which)
SCALED_PRESSURE, …2, …3    static pressure (hPa → Pa) and airspeed Δp (exactly 0 = no sensor) of
                           barometer / airspeed sensor 1, 2, 3: the first alive is used
GPS_RAW_INT                3-D fixes (degE7, mm, cm/s, cdeg; no vertical velocity → v_D NaN);
                           stamped when the autopilot received the fix, so the time of validity is
                           the stamp less the autopilot's default receiver lag (ArduPilot 0.12 s,
                           PX4 0.11 s: units.GNSS_LATENCY_DEFAULT_S)
SERVO_OUTPUT_RAW           PWM of servo 1–4 (ArduPlane order: aileron, elevator, throttle, rudder)
NAMED_VALUE_FLOAT          port Δp [Pa], one message per port (the Lua script / the mock)
DEBUG_FLOAT_ARRAY          port Δp [Pa], one message per frame (``ports_array_id``)
SYSTEM_TIME                UTC of the autopilot's boot
ATTITUDE                   the autopilot's own attitude estimate (rad → quaternion)
GLOBAL_POSITION_INT        the autopilot's own position estimate (degE7, mm AMSL)
SIMSTATE, SIM_STATE        truth in ArduPilot SITL (the simulator's position and attitude)
=========================  ===================================================================
"""

from __future__ import annotations

import itertools
import math
import mmap
import struct
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.decode import IMU_SOURCES, MESSAGES, MavlinkDecoder
from firmware_bridge.endpoint import MavlinkMessage
from firmware_bridge.inputs import PortFrameIn
from firmware_bridge.logs.common import LogFormatError, LogRead, ReadReport, StreamBuilder, TruthTrack
from vdm_aero._typing import F64Array
from vdm_aero.rotation import quat_from_euler

__all__ = ["read_tlog"]

STAMP = struct.Struct(">Q")
V1, V2 = 0xFE, 0xFD
V2_SIGNED = 0x01
STAMP_PLAUSIBLE_US = 86_400 * 10**6  # resynchronising: a record stamped within a day of the last good one
PORT_FRAME_TIMEOUT_S = 0.05
PROGRESS_EVERY_BYTES = 1 << 20
_NAMES = {i: getattr(c, "msgname", str(i)) for i, c in mavlink2.mavlink_map.items()}
_NEEDED_IDS = {i for i, n in _NAMES.items() if n in MESSAGES}  # the rest is counted undecoded


class _Reader:
    """Frames the file's records and is the decoder's sink: the SI samples go to a :class:`StreamBuilder`."""

    def __init__(self, path: Path, port_names: Sequence[str], system_id: int | None, ports_array_id: int,
                 gnss_latency_s: float | None = None) -> None:  # fmt: skip
        self.path = path
        self.report = ReadReport(path=path, format="tlog", time_base="")
        self.builder = StreamBuilder(port_names)
        self.mav = mavlink2.MAVLink(None)
        self.decoder = MavlinkDecoder(
            self,
            system_id=system_id,
            port_names=port_names,
            ports_array_id=ports_array_id,
            port_frame_timeout_s=PORT_FRAME_TIMEOUT_S,
            gnss_latency_s=gnss_latency_s,
        )
        self.boot_minus_stamp_s: float | None = None  # autopilot time − tlog stamp, from the latest IMU sample
        self.unix_boot: list[float] = []
        self.truth: list[tuple[float, ...]] = []
        self.truth_source = ""

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
        self.decoder.expire_ports(math.inf)

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

    # ------------------------------------------------------------------------- the decoder's sink
    def _message(self, m: mavlink2.MAVLink_message, stamp_s: float) -> None:
        try:
            self.decoder.feed(m, stamp_s)
        except ValueError as e:  # a message no autopilot sends (a glitched sensor): skipped, counted, named once
            kind = m.get_type()
            if f"{kind} (refused)" not in self.report.unknown:
                self.report.warn(f"{self.path.name}: {kind} refused (the first of them): {e}")
            self.report.skip(f"{kind} (refused)")

    def on_autopilot(self, src: tuple[int, int], new: bool, t_in: float) -> None:
        pass

    def on_reboot(self, boot_s: float) -> None:
        self.report.reboots += 1

    def on_imu_source(self, kind: str) -> None:
        pass

    def on_imu(self, t_s: float, s: units.ImuSample, t_in: float) -> None:
        self.boot_minus_stamp_s = t_s - t_in
        self.builder.imu(t_s, s.gyro_b_rad_s, s.accel_b_m_s2, s.temperature_c)

    def on_mag(self, t_s: float, field_b_ut: tuple[float, float, float]) -> None:
        self.builder.mag(t_s, field_b_ut)

    def on_baro(self, t_s: float, static_pa: float) -> None:
        self.builder.baro(t_s, static_pa)

    def on_pitot(self, t_s: float, dp_pa: float, temperature_c: float) -> None:
        self.builder.pitot(t_s, dp_pa, temperature_c)

    def on_gnss(self, t_valid_s: float, t_arrived_s: float, fix: units.GnssFix) -> None:
        self.builder.gnss(t_valid_s, fix.lat_deg, fix.lon_deg, fix.alt_m, fix.v_ned_m_s, fix.h_acc_m, fix.v_acc_m)

    def on_servo(self, t_s: float, pwm_us: F64Array) -> None:
        self.builder.servo(t_s, pwm_us[:4])

    def on_ports(self, t_s: float, frame: PortFrameIn) -> None:
        self.builder.ports(t_s, frame.dp_pa)

    def on_system_time(self, unix_minus_boot_s: float) -> None:
        self.unix_boot.append(unix_minus_boot_s)

    def on_truth(self, kind: str, msg: MavlinkMessage, t_in: float) -> None:
        self._truth(msg, kind, t_in)

    def on_ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        self.builder.ap_attitude(t_s, q_nb)

    def on_ap_position(self, t_s: float, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        self.builder.ap_position(t_s, lat_deg, lon_deg, alt_m)

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
        rep, dec = self.report, self.decoder
        if dec.autopilot is None:
            raise LogFormatError(f"{self.path}: no autopilot HEARTBEAT (cannot tell the autopilot's messages apart)")
        for k, n in dec.used.items():
            rep.used[k] = rep.used.get(k, 0) + n
        for k, n in dec.skipped.items():
            rep.unknown[k] = rep.unknown.get(k, 0) + n
        rep.duplicates.update(dec.duplicates)
        reboots = f", {dec.clock.reboots} reboot(s) made continuous" if dec.clock.reboots else ""
        stamps = [k + (".time_usec" if k in ("HIGHRES_IMU", "RAW_IMU") else ".time_boot_ms") for k in dec.imu_switches]
        imu = " then ".join(stamps) if stamps else "no IMU stream"
        rep.time_base = f"{imu} (autopilot boot time{reboots})"
        rank = [IMU_SOURCES.index(k) for k in dec.imu_switches]
        if any(b > a for a, b in itertools.pairwise(rank)):  # a fall-back to a worse stream, not a better one arriving
            rep.warn(f"{self.path.name}: the IMU stream changed during the log ({imu}): a sensor or stream stopped")
        if (a := dec.assembler) is not None:
            c = a.counts
            rep.used["port frames"] = c["complete"] + c["partial"]
            if c["partial"]:
                rep.warn(f"{self.path.name}: {c['partial']} port frames incomplete (missing ports are NaN)")
            if c["unknown_name"]:
                rep.unknown["NAMED_VALUE_FLOAT (not a port)"] = c["unknown_name"]
            if c["complete"] + c["partial"] + dec.dfa_frames == 0:
                rep.warn(f"{self.path.name}: no port values ({', '.join(a.names)}) in the log")
        truth = None
        if self.truth:
            t = np.array(self.truth)
            truth = TruthTrack(self.truth_source, t[:, 0], t[:, 1], t[:, 2], t[:, 3], None, t[:, 4:8])
        unix = float(np.median(self.unix_boot)) if self.unix_boot else None
        log = self.builder.build(self.path, rep, meta={"autopilot": list(dec.autopilot), "imu": dec.imu_source,
                                                       "gnss_latency_s": dec.gnss_latency_s})  # fmt: skip
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
