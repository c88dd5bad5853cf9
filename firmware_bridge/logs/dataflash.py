"""ArduPilot DataFlash logs (``.bin``, the autopilot's own SD-card log) → the SI measurement stream.

pymavlink's :class:`DFReader.DFReader_binary` decodes the records. It applies only the scale factors implied by
the format characters (``c``/``C``/``e``/``E`` ×0.01, ``L`` ×1e-7); the FMTU multipliers merely rename units.
So ``TimeUS`` is raw µs, ``Lat``/``Lng`` (``L``) are degrees, the GPS ``Alt`` (``e``) is metres and the ``MAG``
fields (``h``) are raw milligauss.

============  ==========================  ======================================  ==============================
message       fields                      log units                               stream (SI)
============  ==========================  ======================================  ==============================
IMU           GyrX..Z, AccX..Z, T         rad/s, m/s² (body FRD), °C              imu
BARO          Press                       Pa                                      baro
ARSP, ASPD    DiffPress                   Pa                                      pitot
MAG           MagX..Z                     mGauss (body FRD)                       mag, ×0.1 → µT
GPS           Lat, Lng, Alt               deg, deg, m AMSL                        gnss, Status ≥ 3 (3-D fix) only
GPS           Spd, GCrs, VZ               m/s, deg, m/s (down positive)           v_NED = (Spd cos GCrs,
                                                                                  Spd sin GCrs, VZ)
GPS           GWk, GMS                    GPS week, ms of the week                UTC of the boot
RCOU          C1..C14                     µs                                      servo, by SERVOn_FUNCTION
SIM (SITL)    Lat, Lng, Alt, Roll..Yaw    deg, deg, m AMSL, deg                   truth (q_nb from the angles)
SIM2 (SITL)   VN, VE, VD                  m/s                                     truth velocity
VPP0, VPP1 …  P00 … (the port names)      Pa (Δp = p_port − p_static)             ports, by name
============  ==========================  ======================================  ==============================

Sensors are read from their first instance: the records whose ``I`` field is 0 on current firmware; older
firmware (e.g. 3.8) logs the other instances as other message types (IMU2, MAG2, BAR2, GPS2, ASP2), which are
skipped. Times are ``TimeUS`` × 1e-6: seconds since the autopilot's boot. Of several outputs with one servo
function, the lowest channel is taken. The ports are in the log when the Lua script writes them (VPP_LOG = 1,
its default): VPP0 holds P00..P11, VPP1 P12..P23, ..., each with TimeUS and one float [Pa] per port; the chunks
of one reading join one frame. (The NAMED_VALUE_FLOAT the script sends to the companion is not logged.)

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
from vdm_aero.rotation import quat_from_euler

__all__ = ["read_dataflash"]

TIME_BASE = "DataFlash TimeUS (autopilot boot time)"
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
# ArduPlane order of the servo stream: (name, SERVOn_FUNCTION value, channel when the log does not say)
SERVO_FUNCTIONS = (("aileron", 4, 1), ("elevator", 19, 2), ("throttle", 70, 3), ("rudder", 21, 4))
PROGRESS_STEPS = 100
PORTS_MSG_PREFIX = "VPP"  # the Lua script's port messages: VPP0, VPP1, ... (firmware_bridge/ardupilot)
PORT_CHUNK_MERGE_S = 0.002  # the chunks of one reading are logged within microseconds of each other
T = TypeVar("T")


class _Discard(io.TextIOBase):
    def write(self, s: str) -> int:
        return len(s)


_DISCARD = _Discard()


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
        self._handlers: dict[str, Callable[[Any, float], bool | None]] = {
            "IMU": self._imu, "BARO": self._baro, "ARSP": self._pitot, "ASPD": self._pitot, "MAG": self._mag,
            "GPS": self._gps, "RCOU": self._rcou, "SIM": self._sim, "SIM2": self._sim2,
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
        try:
            ok = handler(m, m.TimeUS * US_TO_S)
        except AttributeError:  # a format without the fields this reader knows (another firmware's layout)
            self.report.skip(f"{kind} (unknown layout)")
            return
        if ok:
            self.report.count(kind)
        elif ok is not None:  # decoded, but NaN or infinite: a corrupted record
            self.report.malformed += 1

    def _imu(self, m: Any, t: float) -> bool:
        gyro, accel = (m.GyrX, m.GyrY, m.GyrZ), (m.AccX, m.AccY, m.AccZ)
        if not _finite(t, *gyro, *accel):
            return False
        self.builder.imu(t, gyro, accel, getattr(m, "T", math.nan))
        return True

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
        week = getattr(m, "GWk", 0)  # absent before ArduPilot 3.3
        if week > 0:
            self.boot_utc_s.append(_gps_to_unix_s(week, m.GMS) - t)
        self.builder.gnss(t, m.Lat, m.Lng, m.Alt, v_ned)
        return True

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
        self.rcou.append((t, *(float(getattr(m, f"C{c}", 0)) for c in range(1, RCOU_CHANNELS + 1))))
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

    def finish(self, params: Mapping[str, float]) -> tuple[dict[str, int], TruthTrack | None, float | None]:
        """Servo channels from the parameters, the truth track, the UTC of the boot."""
        self.flush_ports()
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
        return channels, truth, boot


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
    channels, truth, boot = conv.finish(params)
    if port_names and conv.port_frames == 0:
        report.warn(f"{path.name}: no port values in the log (VPPn messages: the Lua script writes them with "
                    "VPP_LOG = 1; NAMED_VALUE_FLOAT itself is not logged)")  # fmt: skip
    meta = {"firmware": conv.firmware, "servo_channels": channels}
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
    SERVOn_FUNCTION (RCn_FUNCTION before ArduPlane 3.8); the default channel, with a warning, when none has it."""
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


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _sorted_unique(a: F64Array) -> F64Array:
    """Rows sorted by time (column 0), the first of each repeated time kept."""
    _, first = np.unique(a[:, 0], return_index=True)
    return a[first]
