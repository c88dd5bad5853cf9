"""ArduPilot DataFlash logs (``.bin``, the autopilot's own SD-card log) → the SI measurement stream.

pymavlink's :class:`DFReader.DFReader_binary` decodes the records. It applies only the scale factors implied by
the format characters (``c``/``C``/``e``/``E`` ×0.01, ``L`` ×1e-7); the FMTU multipliers merely rename units.
So ``TimeUS`` is raw µs, ``Lat``/``Lng`` (``L``) are degrees, the GPS ``Alt`` (``e``) is metres and the ``MAG``
fields (``h``) are raw milligauss. Field names come from the log's own FMT records, so the older layouts
(ArduPilot before 3.3, noted "old" below) are read by their names as well.

============  ==========================  ======================================  ==============================
message       fields                      log units                               stream (SI)
============  ==========================  ======================================  ==============================
IMU, IMU2 …   GyrX..Z, AccX..Z, T         rad/s, m/s² (body FRD), °C              imu, one instance (below)
              (old: Temp, or none)
BARO          Press                       Pa                                      baro
ARSP, ASPD    DiffPress                   Pa                                      pitot
MAG           MagX..Z                     mGauss (body FRD)                       mag, ×0.1 → µT
GPS           Lat, Lng, Alt               deg, deg, m AMSL                        gnss, Status ≥ 3 (3-D fix) only
GPS           Spd, GCrs, VZ               m/s, deg, m/s (down positive)           v_NED = (Spd cos GCrs,
                                                                                  Spd sin GCrs, VZ)
GPS           GWk, GMS (old: Week,        GPS week, ms of the week                UTC of the boot
              TimeMS)
GPA           HAcc, VAcc                  m                                       the receiver's accuracy, of the
                                                                                  GPS record with its TimeUS
RCOU          C1..C14 (old: Ch1..Ch12,    µs                                      servo, by SERVOn_FUNCTION
              Chan1..Chan8)                                                       (old: RCMAP_*)
SIM (SITL)    Lat, Lng, Alt, Roll..Yaw    deg, deg, m AMSL, deg                   truth (q_nb from the angles)
SIM2 (SITL)   VN, VE, VD                  m/s                                     truth velocity
VPP0, VPP1 …  P00 … (the port names)      Pa (Δp = p_port − p_static)             ports, by name
ATT           Roll, Pitch, Yaw            deg (yaw 0–360)                         ap_att (the AHRS's attitude)
POS           Lat, Lng, Alt               deg, deg, m AMSL                        ap_pos (the AHRS's position)
XKF1, NKF1    PN, PE, PD                  m NED from the EKF origin (ORGN)        ap_pos when there is no POS
ORGN          Lat, Lng, Alt (Type 0)      deg, deg, m AMSL                        the EKF origin of XKF1/NKF1
============  ==========================  ======================================  ==============================

Times are seconds since the autopilot's boot: ``TimeUS`` × 1e-6, or in the old layouts ``TimeMS`` × 1e-3. The
old GPS record's ``TimeMS`` is not boot time but the GPS time of week (beside ``Week``); its boot time is ``T``
[ms], the field pymavlink's own old-log clock (``DFReaderClock_msec``) takes as well. A GPS record with neither
``TimeUS`` nor ``T`` cannot be placed on the boot clock and is skipped.

The IMU is read from one instance for the whole log, like the autopilot's primary: the first (lowest instance)
that is healthy throughout, i.e. never flagged unhealthy (``GH``/``AH``, old ``GyHlt``/``AcHlt``, where logged)
and with at least IMU_COMPLETE of the samples of the fullest instance (a stream that stopped is not); when
none is, the one with the most healthy samples. Instances are the ``I`` field on current firmware, separate
message types (IMU2, IMU3) on older firmware (e.g. 3.8). ``log.meta["imu"]`` names the one read, a warning says
why when it is not the first, and the others count as skipped. The other sensors are read from their first
instance (``I`` = 0; MAG2, BAR2, GPS2, ASP2 skipped). Of several outputs with one servo function, the lowest
channel is taken. The ports are in the log when the Lua script writes them (VPP_LOG = 1, its default): VPP0
holds P00..P11, VPP1 P12..P23, ..., each with TimeUS and one float [Pa] per port; the chunks of one reading
join one frame. (The NAMED_VALUE_FLOAT the script sends to the companion is not logged.)

The autopilot's own estimate (for comparison with the replayed filters) is the AHRS's: ATT and POS, what the
autopilot flew on. Logs without POS fall back to the EKF's first core (XKF1 of EKF3, NKF1 of EKF2; the one
AHRS_EKF_TYPE names, else the one with more records), its NED offsets made geodetic at the EKF origin in force
(the latest ORGN of Type 0, the first for records before it). ``log.meta["ap_estimate"]`` names the messages.

DataFlash records have no checksum. A run of bytes that is not a record (a corrupted block) is skipped by
pymavlink, which resynchronises on the next record header; the record just before such a run is dropped as
well, since its own tail may be the first corrupted bytes.
"""

from __future__ import annotations

import datetime as dt
import io
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pymavlink import DFReader

from firmware_bridge.logs.common import LogFormatError, LogRead, ReadReport, StreamBuilder, TruthTrack
from vdm_aero._typing import F64Array
from vdm_aero.geodesy import LocalFrame
from vdm_aero.rotation import quat_from_euler

__all__ = ["read_dataflash"]

TIME_BASE = "DataFlash TimeUS (autopilot boot time)"
GPS_BOOT_MS = "GPS.T"  # the old GPS record's boot time [ms] (its TimeMS is the GPS time of week)
HEADER = b"\xa3\x95"  # every record starts with these two bytes, then its message type
US_TO_S = 1e-6
MS_TO_S = 1e-3
MGAUSS_TO_UT = 0.1
FIX_3D = 3  # GPS Status: 3 = 3-D fix (4, 5, 6: DGPS, RTK float, RTK fixed)
GPS_EPOCH_UNIX_S = dt.datetime(1980, 1, 6, tzinfo=dt.UTC).timestamp()
WEEK_S = 7 * 86_400.0
# GPS − UTC [s] from each leap second on (IERS Bulletin C), newest first
LEAP_SECONDS = tuple((dt.datetime(*d, tzinfo=dt.UTC).timestamp(), n) for d, n in (
    ((2017, 1, 1), 18), ((2015, 7, 1), 17), ((2012, 7, 1), 16), ((2009, 1, 1), 15), ((2006, 1, 1), 14)))  # fmt: skip
RCOU_CHANNELS = 14  # RCOU carries C1..C14 (newer firmware logs 15+ in RCO2)
RCOU_NAMES = ("C{}", "Ch{}", "Chan{}")  # channel n's field: 3.5 on, 3.2–3.4, 3.1 and before
IMU_TYPES = {"IMU": 0, "IMU2": 1, "IMU3": 2}  # message type → instance (IMU2/IMU3: firmware before the I field)
IMU_HEALTH_FIELDS = (("GH", "AH"), ("GyHlt", "AcHlt"))  # gyro, accel healthy (1) or not (0): 3.4 on, 3.3
IMU_COMPLETE = 0.9  # an instance with fewer than this share of the fullest one's samples stopped or dropped out
# ArduPlane order of the servo stream: (name, SERVOn_FUNCTION value, channel when the log does not say)
SERVO_FUNCTIONS = (("aileron", 4, 1), ("elevator", 19, 2), ("throttle", 70, 3), ("rudder", 21, 4))
RCMAP = {"aileron": "RCMAP_ROLL", "elevator": "RCMAP_PITCH", "throttle": "RCMAP_THROTTLE", "rudder": "RCMAP_YAW"}
PROGRESS_STEPS = 100
PORTS_MSG_PREFIX = "VPP"  # the Lua script's port messages: VPP0, VPP1, ... (firmware_bridge/ardupilot)
PORT_CHUNK_MERGE_S = 0.002  # the chunks of one reading are logged within microseconds of each other
EKF_POSITION = {3: "XKF1", 2: "NKF1"}  # AHRS_EKF_TYPE → the EKF's position message (core 0 without a C field)
ORIGIN_EKF = 0  # ORGN.Type: 0 the EKF origin, 1 the AHRS home
T = TypeVar("T")


class _Discard(io.TextIOBase):
    def write(self, s: str) -> int:
        return len(s)


_DISCARD = _Discard()


class _Imu:
    """One IMU instance's samples, kept until the log is read and the instance to use is chosen."""

    def __init__(self, label: str) -> None:
        self.label = label  # "IMU", "IMU2", "IMU[1]": how the report names it
        self.records = 0
        self.samples: list[tuple[float, ...]] = []  # (t, gyro, accel, temperature)
        self.bad = 0  # NaN or infinite: corrupted records
        self.unhealthy = 0  # records the autopilot flagged unhealthy
        self.fields: set[str] = set()  # the time fields its samples came from

    def healthy(self, most: int) -> bool:
        return len(self.samples) >= max(2, IMU_COMPLETE * most) and self.unhealthy == 0

    def why_not(self, most: int) -> str:
        if self.unhealthy:
            return f"{self.label} flagged unhealthy in {self.unhealthy} of {self.records} records"
        return f"{self.label} has {len(self.samples)} samples of {most}"


class _Converter:
    """Converts one decoded record at a time (the table in the module docstring) into the builder."""

    def __init__(self, path: Path, report: ReadReport, port_names: Sequence[str]) -> None:
        self.path = path
        self.report = report
        self.builder = StreamBuilder(port_names)
        self.rcou: list[tuple[float, ...]] = []  # (t, C1..C14): mapped once the log's parameters are known
        self.sim: list[tuple[float, ...]] = []  # (t, lat, lon, alt, q0..q3)
        self.sim2: list[tuple[float, ...]] = []  # (t, vN, vE, vD)
        self.boot_utc_s: list[float] = []
        self.firmware: str | None = None
        self.port_index = {n: i for i, n in enumerate(port_names)}
        self._frame_t: float | None = None  # the port frame being assembled from VPPn chunks
        self._frame: list[float] = []
        self.port_frames = 0
        self.imus: dict[int, _Imu] = {}
        self.imu_unknown: dict[str, str] = {}  # IMU type → the columns of a layout it could not read
        self.time_fields: set[str] = set()  # which of TimeUS, TimeMS, GPS.T the converted records were timed by
        self._rcou_fields: dict[tuple[str, ...], list[str | None]] = {}  # a RCOU layout → its C1..C14 fields
        self.ap_pos_records = 0  # POS records converted
        self.ekf: dict[str, list[tuple[float, ...]]] = {k: [] for k in EKF_POSITION.values()}  # (t, PN, PE, PD)
        self.ekf_fields: dict[str, set[str]] = {k: set() for k in EKF_POSITION.values()}
        self.origins: list[tuple[float, ...]] = []  # (t, lat, lon, alt) of the EKF origin
        self.ap_estimate: dict[str, str | None] = {"position": None, "attitude": None}  # the messages read
        self._handlers: dict[str, Callable[[Any, float], bool | None]] = {
            "BARO": self._baro, "ARSP": self._pitot, "ASPD": self._pitot, "MAG": self._mag,
            "GPS": self._gps, "GPA": self._gpa, "RCOU": self._rcou, "SIM": self._sim, "SIM2": self._sim2,
            "ATT": self._att, "POS": self._pos, "XKF1": self._ekf_pos, "NKF1": self._ekf_pos, "ORGN": self._orgn,
        }  # fmt: skip

    def convert(self, m: Any) -> None:
        kind: str = m.get_type()
        if kind.startswith(PORTS_MSG_PREFIX) and kind[len(PORTS_MSG_PREFIX) :].isdigit():
            if self.port_index:
                self._ports(m, m.TimeUS * US_TO_S)
                self.report.count(kind)
            else:
                self.report.skip(f"{kind} (no port names given)")
            return
        if kind in IMU_TYPES:
            self._imu(m, kind)
            return
        handler = self._handlers.get(kind)
        if handler is None:
            if kind == "MSG" and self.firmware is None and str(m.Message).startswith("Ardu"):
                self.firmware = str(m.Message)  # e.g. "ArduPlane V3.8.2-dev (8178ab40)"
            self.report.skip(kind)
            return
        instance = m.I if "I" in m.fmt.colhash else 0
        if instance != 0:
            self.report.skip(f"{kind}[{instance}]")
            return
        if (timed := _boot_time(m, kind)) is None:
            self.report.skip(f"{kind} (no boot time field)")
            return
        try:
            ok = handler(m, timed[0])
        except AttributeError:  # a format without the fields this reader knows (another firmware's layout)
            self.report.skip(f"{kind} (unknown layout)")
            return
        if ok:
            self.report.count(kind)
            self.time_fields.add(timed[1])
        elif ok is not None:  # decoded, but NaN or infinite: a corrupted record
            self.report.malformed += 1

    def _imu(self, m: Any, kind: str) -> None:
        """An IMU record of any instance: kept in its instance until :meth:`_choose_imu`."""
        cols = m.fmt.colhash
        instance = int(m.I) if "I" in cols else IMU_TYPES[kind]
        label = f"{kind}[{instance}]" if "I" in cols and instance != 0 else kind
        timed = _boot_time(m, kind)
        try:
            gyro, accel = (m.GyrX, m.GyrY, m.GyrZ), (m.AccX, m.AccY, m.AccZ)
        except AttributeError:
            timed = None
        if timed is None:  # another firmware's layout
            self.report.skip(f"{kind} (unknown layout)")
            self.imu_unknown.setdefault(kind, ",".join(m.fmt.columns))
            return
        imu = self.imus.setdefault(instance, _Imu(label))
        imu.records += 1
        t = timed[0]
        if not _finite(t, *gyro, *accel):
            imu.bad += 1
            return
        temp = next((float(getattr(m, f)) for f in ("T", "Temp") if f in cols), math.nan)  # T: 3.4 on
        if any(int(getattr(m, f)) == 0 for pair in IMU_HEALTH_FIELDS for f in pair if f in cols):
            imu.unhealthy += 1
        imu.samples.append((t, *gyro, *accel, temp))
        imu.fields.add(timed[1])

    def _choose_imu(self) -> str | None:
        """Puts the IMU instance to read (module docstring) into the builder; its label (None: no IMU). IMU
        records none of which could be read (e.g. ArduPilot 2.9's, which carry no time) are a LogFormatError: the
        log has no IMU to navigate with, and the error says why rather than an empty stream."""
        if not any(i.samples for i in self.imus.values()) and self.imu_unknown:
            kind, cols = next(iter(self.imu_unknown.items()))
            raise LogFormatError(f"{self.path}: {kind} records in a layout this reader cannot read ({cols}: no "
                                 "TimeUS or TimeMS, or no GyrX..AccZ); no IMU samples")  # fmt: skip
        if not self.imus:
            return None
        order = sorted(self.imus)
        most = max(len(i.samples) for i in self.imus.values())
        k = next((k for k in order if self.imus[k].healthy(most)), None)
        name = self.path.name
        if k is None:
            k = max(order, key=lambda k: (len(self.imus[k].samples) - self.imus[k].unhealthy, -k))
            if len(self.imus[k].samples) >= 2:
                why = "; ".join(self.imus[j].why_not(most) for j in order)
                self.report.warn(f"{name}: no IMU is healthy throughout the log ({why}): {self.imus[k].label} "
                                 "read, the one with the most healthy samples")  # fmt: skip
        elif k != order[0]:
            why = "; ".join(self.imus[j].why_not(most) for j in order if j < k)
            self.report.warn(f"{name}: {self.imus[k].label} (IMU instance {k}) read instead of the first IMU: {why}")
        chosen = self.imus[k]
        for row in chosen.samples:
            self.builder.imu(row[0], row[1:4], row[4:7], row[7])
        self.time_fields |= chosen.fields
        if chosen.samples:
            self.report.used[chosen.label] = len(chosen.samples)
        self.report.malformed += chosen.bad
        for j in order:
            if j != k:
                self.report.unknown[self.imus[j].label] = self.imus[j].records
        return chosen.label if chosen.samples else None

    def _baro(self, m: Any, t: float) -> bool:
        if not _finite(t, m.Press):
            return False
        self.builder.baro(t, m.Press)
        return True

    def _pitot(self, m: Any, t: float) -> bool:
        if not _finite(t, m.DiffPress):
            return False
        temp = getattr(m, "Temp", math.nan)  # ARSP.Temp [°C], the airspeed sensor's die
        self.builder.pitot(t, m.DiffPress, float(temp) if _finite(temp) else math.nan)
        return True

    def _mag(self, m: Any, t: float) -> bool:
        self.builder.mag(t, (m.MagX * MGAUSS_TO_UT, m.MagY * MGAUSS_TO_UT, m.MagZ * MGAUSS_TO_UT))
        return True

    def _gps(self, m: Any, t: float) -> bool | None:
        if m.Status < FIX_3D:
            self.report.skip("GPS (no 3-D fix)")
            return None
        course = math.radians(m.GCrs)
        v_ned = (m.Spd * math.cos(course), m.Spd * math.sin(course), getattr(m, "VZ", math.nan))
        if not _finite(t, m.Lat, m.Lng, m.Alt, *v_ned[:2]):
            return False
        # GPS week and ms of the week: GWk, GMS from ArduPilot 3.3; Week, TimeMS before
        week, ms = (m.GWk, m.GMS) if "GWk" in m.fmt.colhash else (getattr(m, "Week", 0), getattr(m, "TimeMS", 0))
        if week > 0:
            self.boot_utc_s.append(_gps_to_unix_s(week, ms) - t)
        self.builder.gnss(t, m.Lat, m.Lng, m.Alt, v_ned)
        return True

    def _gpa(self, m: Any, t: float) -> bool | None:
        """The accuracy ArduPilot logs beside each GPS record, with its TimeUS (0: not reported); None when its
        fix was not kept (no 3-D fix)."""
        h, v = (float(a) if _finite(a) and a > 0.0 else math.nan for a in (m.HAcc, m.VAcc))
        return self.builder.gnss_accuracy(t, h, v) or None

    def _ports(self, m: Any, t: float) -> None:
        """A chunk of a port frame (VPP0: ports 0..11, VPP1: 12..23, ...; fields named like the ports). The
        chunks of one reading are written back to back: they join one frame while within PORT_CHUNK_MERGE_S and
        not repeating a port."""
        cols = [(self.port_index[c], float(getattr(m, c))) for c in m.fmt.columns if c in self.port_index]
        if self._frame_t is not None and (t - self._frame_t > PORT_CHUNK_MERGE_S
                                          or any(not math.isnan(self._frame[i]) for i, _ in cols)):  # fmt: skip
            self.flush_ports()
        if self._frame_t is None:
            self._frame_t, self._frame = t, [math.nan] * len(self.port_index)
        for i, v in cols:
            self._frame[i] = v if math.isfinite(v) else math.nan

    def flush_ports(self) -> None:
        if self._frame_t is not None:
            self.builder.ports(self._frame_t, self._frame)
            self.port_frames += 1
            self._frame_t = None

    def _rcou(self, m: Any, t: float) -> bool:
        """PWM [µs] of C1..C14; 0 for a channel the layout lacks, the value ArduPilot logs for an unused one."""
        fields = self._rcou_fields.get(key := tuple(m.fmt.columns))
        if fields is None:
            cols = m.fmt.colhash
            fields = self._rcou_fields[key] = [next((f.format(c) for f in RCOU_NAMES if f.format(c) in cols), None)
                                               for c in range(1, RCOU_CHANNELS + 1)]  # fmt: skip
        self.rcou.append((t, *(float(getattr(m, f)) if f is not None else 0.0 for f in fields)))
        return True

    def _sim(self, m: Any, t: float) -> bool:
        angles = (m.Roll, m.Pitch, m.Yaw)
        if not _finite(t, m.Lat, m.Lng, m.Alt, *angles):
            return False
        self.sim.append((t, m.Lat, m.Lng, m.Alt, *quat_from_euler(*(math.radians(a) for a in angles))))
        return True

    def _sim2(self, m: Any, t: float) -> bool:
        self.sim2.append((t, m.VN, m.VE, m.VD))
        return True

    def _att(self, m: Any, t: float) -> bool:
        angles_deg = (m.Roll, m.Pitch, m.Yaw)
        if not _finite(t, *angles_deg):
            return False
        roll, pitch, yaw = (math.radians(a) for a in angles_deg)
        # yaw to ±180° as ATTITUDE and PX4 have it: the same rotation, with the quaternion's w ≥ 0 in level flight
        self.builder.ap_attitude(t, quat_from_euler(roll, pitch, math.remainder(yaw, math.tau)))
        return True

    def _pos(self, m: Any, t: float) -> bool:
        if not _finite(t, m.Lat, m.Lng, m.Alt):
            return False
        self.builder.ap_position(t, m.Lat, m.Lng, m.Alt)
        self.ap_pos_records += 1
        return True

    def _ekf_pos(self, m: Any, t: float) -> bool | None:
        """Kept until the end: used only when the log has no POS, and its origin (ORGN) may come later."""
        kind = m.get_type()
        if "C" in m.fmt.colhash and int(m.C) != 0:  # EKF3 on 4.x: one record per core
            self.report.skip(f"{kind}[{int(m.C)}]")
            return None
        if not _finite(t, m.PN, m.PE, m.PD):
            return False
        self.ekf[kind].append((t, m.PN, m.PE, m.PD))
        self.ekf_fields[kind].add("TimeUS" if "TimeUS" in m.fmt.colhash else "TimeMS")
        return None

    def _orgn(self, m: Any, t: float) -> bool | None:
        if int(m.Type) != ORIGIN_EKF:
            self.report.skip("ORGN (home)")
            return None
        if not _finite(m.Lat, m.Lng, m.Alt):
            return False
        self.origins.append((t, m.Lat, m.Lng, m.Alt))
        return None

    def _ekf_position(self, params: Mapping[str, float]) -> str | None:
        """Without POS, the EKF's positions (module docstring) into the builder; the message used (None: none).
        The EKF records not used are counted as skipped."""
        have = [k for k, rows in self.ekf.items() if rows]
        want = EKF_POSITION.get(int(params.get("AHRS_EKF_TYPE", -1)))
        kind = None
        if self.ap_pos_records == 0 and have:
            kind = want if want in have else max(have, key=lambda k: len(self.ekf[k]))
            if not self.origins:
                self.report.warn(f"{self.path.name}: {kind} positions but no EKF origin (ORGN of Type 0) in the "
                                 "log: no autopilot position estimate")  # fmt: skip
                kind = None
        for k in have:
            if k != kind:
                self.report.unknown[k] = self.report.unknown.get(k, 0) + len(self.ekf[k])
        if kind is None:
            if self.origins:
                self.report.unknown["ORGN"] = self.report.unknown.get("ORGN", 0) + len(self.origins)
            return None
        rows, origins = np.array(self.ekf[kind]), np.array(self.origins)
        # the origin in force at each record: the latest before it, the first for records before any
        which = np.clip(np.searchsorted(origins[:, 0], rows[:, 0], side="right") - 1, 0, len(origins) - 1)
        for i in np.unique(which):
            sel = which == i
            lat, lon, alt = LocalFrame(*(float(v) for v in origins[i, 1:4])).to_geodetic_array(rows[sel, 1:4])
            for t, la, lo, al in zip(rows[sel, 0], lat, lon, alt, strict=True):
                self.builder.ap_position(float(t), float(la), float(lo), float(al))
        self.report.used[kind] = len(rows)
        self.report.used["ORGN"] = len(origins)
        self.time_fields |= self.ekf_fields[kind]
        return kind

    def finish(self, params: Mapping[str, float]
               ) -> tuple[str | None, dict[str, int], TruthTrack | None, float | None]:  # fmt: skip
        """The IMU read, servo channels from the parameters, the truth track, the UTC of the boot."""
        self.flush_ports()
        imu = self._choose_imu()
        ekf = self._ekf_position(params)
        self.ap_estimate = {"position": "POS" if self.ap_pos_records else ekf,
                            "attitude": "ATT" if self.report.used.get("ATT") else None}  # fmt: skip
        self.report.time_base = _time_base(self.time_fields)
        if (n := self.report.unknown.get("GPS (no boot time field)", 0)) > 0:
            self.report.warn(f"{self.path.name}: {n} GPS records have no boot time (neither TimeUS nor T): "
                             "their fixes cannot be placed on the log's clock and are left out")  # fmt: skip
        channels = _servo_channels(params, self.report, self.path.name) if self.rcou else {}
        for row in self.rcou:
            self.builder.servo(row[0], [row[c] for c in channels.values()])
        truth = None
        if self.sim:
            a = _sorted_unique(np.array(self.sim))
            v_ned = None
            if len(self.sim2) >= 2:  # SIM2 is logged on its own ticks: interpolated to SIM's times
                v = _sorted_unique(np.array(self.sim2))
                v_ned = np.column_stack([np.interp(a[:, 0], v[:, 0], v[:, k]) for k in (1, 2, 3)])
            truth = TruthTrack("DataFlash SIM", a[:, 0], a[:, 1], a[:, 2], a[:, 3], v_ned, a[:, 4:8])
        boot = float(np.median(self.boot_utc_s)) if self.boot_utc_s else None
        return imu, channels, truth, boot


def read_dataflash(path: Path, port_names: Sequence[str] = (), *, progress: Callable[[float], None] | None = None
                   ) -> LogRead:  # fmt: skip
    """Read an ArduPilot DataFlash log (module docstring). ``port_names`` only size the (empty) port columns;
    ``progress`` is called with the fraction of the file read, at most about 100 times."""
    path = Path(path)
    report = ReadReport(path=path, format="dataflash", time_base=TIME_BASE)
    conv = _Converter(path, report, port_names)
    reader = _open(path)
    try:
        report.file_bytes = size = int(reader.data_len)
        last_end = _read_records(reader, conv, size, progress)
        if last_end == 0:
            raise LogFormatError(f"{path}: no DataFlash records (not an ArduPilot .bin log)")
        # a header after the last whole record, or the first byte of one at the very end: the file ends inside
        # a record (not merely in padding)
        if last_end < size and (reader.data_map.find(HEADER, last_end) >= 0 or reader.data_map[-1:] == HEADER[:1]):
            report.truncated_at_byte = last_end
        params = dict(reader.params)
    finally:
        reader.close()
    if progress is not None:
        progress(1.0)
    imu, channels, truth, boot = conv.finish(params)
    if port_names and conv.port_frames == 0:
        report.warn(f"{path.name}: no port values in the log (VPPn messages: the Lua script writes them with "
                    "VPP_LOG = 1; NAMED_VALUE_FLOAT itself is not logged)")  # fmt: skip
    meta = {"firmware": conv.firmware, "servo_channels": channels, "imu": imu, "ap_estimate": conv.ap_estimate}
    log = conv.builder.build(path, report, meta=meta)
    return LogRead(log, truth, report, boot)


class _FileOrderReader(DFReader.DFReader_binary):
    """``DFReader_binary`` for reading records in file order (``recv_msg``) only. Its constructor would first
    index the file for ``recv_match`` (the compiled indexer prints to the process's stderr for every bad byte)
    and search it for a clock base (for ``_timestamp``): neither is used here, and each costs a pass."""

    def init_arrays(self, progress_callback: object = None) -> None:
        pass

    def init_arrays_fast(self, progress_callback: object = None) -> None:
        pass

    def init_clock(self) -> None:
        pass


def _open(path: Path) -> Any:
    try:
        if path.stat().st_size == 0:
            raise LogFormatError(f"{path}: empty file (not a DataFlash log)")
        return _quietly(lambda: _FileOrderReader(str(path), zero_time_base=True))
    except OSError as e:
        raise LogFormatError(f"{path}: cannot read ({e.strerror})") from None


def _read_records(reader: Any, conv: _Converter, size: int, progress: Callable[[float], None] | None) -> int:
    """Decode every record in file order; returns the byte offset where the last whole record ended.

    A record is converted once the next one is seen to start right where it ends; when bytes were skipped in
    between, both the skipped run and the record before it count as malformed."""
    pending: Any = None
    prev_end = 0
    step = max(size // PROGRESS_STEPS, 1)
    next_progress = step
    while True:
        try:
            m = _quietly(reader.recv_msg)
        except Exception as e:  # noqa: BLE001 - pymavlink raises bare exceptions on records it cannot decode
            raise LogFormatError(f"{conv.path}: unreadable record at byte {reader.offset} ({e})") from None
        if m is None:
            break
        end = int(reader.offset)
        if end - m.fmt.len != prev_end:
            conv.report.malformed += 1 + (pending is not None)
            pending = None
        elif pending is not None:
            conv.convert(pending)
        pending, prev_end = m, end
        if progress is not None and end >= next_progress:
            progress(end / size)
            next_progress = end + step
    if pending is not None:
        conv.convert(pending)  # the last record: nothing follows it to vouch for it, but nothing is amiss
    return prev_end


def _quietly(call: Callable[[], T]) -> T:
    """``call()`` with pymavlink's prints about bad data (to stdout and stderr) discarded: the report counts it
    instead. Swapped per call, so that a caller's progress display writes normally in between."""
    saved = sys.stdout, sys.stderr
    sys.stdout = sys.stderr = _DISCARD
    try:
        return call()
    finally:
        sys.stdout, sys.stderr = saved


def _servo_channels(params: Mapping[str, float], report: ReadReport, name: str) -> dict[str, int]:
    """RCOU channel (1-based) of aileron, elevator, throttle, rudder: the lowest channel with each function in
    SERVOn_FUNCTION; before ArduPlane 3.8 (no SERVOn_FUNCTION), the RCMAP_ROLL, _PITCH, _THROTTLE, _YAW channels,
    which then drove both the input and the output (RCn_FUNCTION only assigned the auxiliary channels, 5 on),
    else RCn_FUNCTION; the default channel, with a warning, when none has it."""
    if not any(f"SERVO{ch}_FUNCTION" in params for ch in range(1, RCOU_CHANNELS + 1)) and any(
        p in params for p in RCMAP.values()
    ):
        return {n: int(params.get(RCMAP[n], default)) for n, _, default in SERVO_FUNCTIONS}
    by_function: dict[int, int] = {}
    for prefix in ("SERVO", "RC"):
        for ch in range(1, RCOU_CHANNELS + 1):
            if (f := params.get(f"{prefix}{ch}_FUNCTION")) is not None:
                by_function.setdefault(int(f), ch)
        if by_function:
            break
    if not by_function:
        report.warn(f"{name}: no SERVOn_FUNCTION parameters in the log: servo channels 1, 2, 3, 4 assumed to be "
                    "aileron, elevator, throttle, rudder")  # fmt: skip
        return {n: default for n, _, default in SERVO_FUNCTIONS}
    missing = [f"{n} ({function}): channel {default}" for n, function, default in SERVO_FUNCTIONS
               if function not in by_function]  # fmt: skip
    if missing:
        report.warn(f"{name}: no SERVOn_FUNCTION for {'; '.join(missing)} assumed")
    return {n: by_function.get(function, default) for n, function, default in SERVO_FUNCTIONS}


def _gps_to_unix_s(week: int, ms: int) -> float:
    """UTC Unix time [s] of a GPS week and millisecond of the week."""
    gps_s = GPS_EPOCH_UNIX_S + week * WEEK_S + ms * MS_TO_S
    return gps_s - next((n for since, n in LEAP_SECONDS if gps_s >= since), 13)


def _boot_time(m: Any, kind: str) -> tuple[float, str] | None:
    """(seconds since boot, the field it came from) of a record; None when it has no boot time (module
    docstring): TimeUS; in the old layouts TimeMS, except GPS, whose TimeMS is the GPS time of week and whose
    boot time is T."""
    cols = m.fmt.colhash
    if "TimeUS" in cols:
        return m.TimeUS * US_TO_S, "TimeUS"
    if kind == "GPS":
        return (m.T * MS_TO_S, GPS_BOOT_MS) if "T" in cols else None
    if "TimeMS" in cols:
        return m.TimeMS * MS_TO_S, "TimeMS"
    return None


def _time_base(fields: set[str]) -> str:
    """The report's time base: TIME_BASE for the current layouts, else the boot-time fields the log used."""
    if not fields - {"TimeUS"}:
        return TIME_BASE
    used = " and ".join(f for f in ("TimeUS", "TimeMS", GPS_BOOT_MS) if f in fields)
    return f"DataFlash {used} (autopilot boot time; TimeMS, T in ms)"


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _sorted_unique(a: F64Array) -> F64Array:
    """Rows sorted by time (column 0), the first of each repeated time kept."""
    _, first = np.unique(a[:, 0], return_index=True)
    return a[first]
