"""PX4 ULog (``.ulg``) → the SI measurement stream, parsed by pyulog.

PX4's body frame is FRD and its navigation frame NED, like ours, so the vectors pass unrotated. Times are
the topics' ``timestamp`` (µs since the autopilot's boot), or ``timestamp_sample`` (the sensor's sampling
time) where the topic has it. Only instance 0 of a multi-instance topic is read (PX4's primary or selected
sensor); the other instances are counted as skipped. Field names changed between PX4 versions: both the
v1.11 names (the shared real log) and the current ones are read.

=================================  ===============================================================
topic                              stream
=================================  ===============================================================
sensor_combined                    IMU: gyro_rad [rad/s], accelerometer_m_s2 [m/s²]
sensor_accel, vehicle_air_data     IMU temperature [°C] (the selected accelerometer's, else the
                                   barometer's, else 15 °C)
vehicle_air_data                   static pressure: baro_pressure_pa [Pa] (logs with only
                                   baro_alt_meter give no barometer stream: warned)
differential_pressure              pitot Δp [Pa]: differential_pressure_pa (current), else
                                   differential_pressure_raw_pa / _filtered_pa (≤ v1.12)
vehicle_magnetometer               magnetometer: magnetometer_ga [gauss] → µT
vehicle_gps_position (sensor_gps)  3-D fixes (fix_type ≥ 3): lat/lon degE7 (int) or latitude_deg /
                                   longitude_deg; alt [mm] or altitude_msl_m (AMSL); vel_n/e/d_m_s;
                                   time_utc_usec → UTC of the boot; eph, epv [m]: the receiver's
                                   accuracy
vehicle_global_position_           truth (SITL only): lat/lon/alt
groundtruth
vehicle_local_position_            truth (SITL only, when there is no global one): NED offsets from
groundtruth                        ref_lat/ref_lon/ref_alt, and the velocity
vehicle_attitude                   the autopilot's own attitude (ap_att): q, w x y z, body FRD → NED
vehicle_global_position            the autopilot's own position (ap_pos): lat, lon [deg], alt [m AMSL]
                                   (rows with lat_lon_valid false, where logged, left out)
vehicle_local_position             the same when there is no vehicle_global_position: x, y, z [m NED]
                                   from ref_lat, ref_lon, ref_alt, in the rows with xy_global (the EKF
                                   had its GNSS origin) and xy_valid; alt NaN where z_global is false
=================================  ===============================================================

PX4's actuator_outputs depend on the airframe's mixer, so there is no generic map to (aileron, elevator,
throttle, rudder): no servo stream (warned). vehicle_global_position is the autopilot's own EKF, not a
truth: it is read only as the autopilot's estimate, for comparison (``log.meta["ap_estimate"]`` names the
topics). PX4 logs carry no pressure ports.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from pyulog import ULog
from pyulog.exceptions import ULogException

from firmware_bridge.logs.common import LogFormatError, LogRead, ReadReport, StreamBuilder, TruthTrack
from vdm_aero._typing import F64Array
from vdm_aero.geodesy import LocalFrame

__all__ = ["read_ulog"]

TIME_BASE = "ULog timestamp (autopilot boot time)"
US_TO_S = 1e-6
GAUSS_TO_UT = 100.0  # 1 G = 1e-4 T = 100 µT
DEG_E7 = 1e-7
MM_TO_M = 1e-3
FIX_3D = 3
DEFAULT_TEMPERATURE_C = 15.0  # ISA sea level: when the log has no accelerometer or barometer temperature
INVALID_TEMPERATURE_C = -100.0  # PX4 reports -1000 °C for a sensor without a temperature
RELATIVE_TIMESTAMP_INVALID = 0x7FFFFFFF  # sensor_combined.accelerometer_timestamp_relative: no sample
ACCEL_GYRO_SKEW_WARN_S = 1e-3
UNIX_USEC_MIN = 10**15  # time_utc_usec above this is a real UTC (2001+), 0 before the receiver has one
PROGRESS_PARSED = 0.8  # pyulog parses in one call: the fraction reported when it returns
PYULOG_LINES_KEPT = 3  # pyulog prints one line per unknown message id: a corrupt file gives dozens

Topic = dict[str, np.ndarray]


class _GuardedFile:
    """The file object pyulog reads through. It records where a truncated file ends inside a record (pyulog
    stops there silently), and after such a short read it keeps pyulog's skip-one-byte resynchronisation
    (a seek back by the record's declared length) from landing before the record: near the end of a corrupt
    file that loops forever, or fails with EINVAL before the file's start (both found by fuzzing pyulog 1.3
    with a valid header followed by random bytes)."""

    def __init__(self, f: BinaryIO) -> None:
        self._f = f
        self._record_at = 0  # where the latest 3-byte message header was read
        self._after_header = False
        self._short = False  # the latest read returned less than asked
        self.cut_at: int | None = None  # the start of the record the file ends in

    def read(self, size: int = -1) -> bytes:
        pos = self._f.tell()
        data = self._f.read(size)
        if size == 3:
            self._record_at = pos
        self._short = 0 < len(data) < 3 if size == 3 else self._after_header and len(data) < size
        if self._short and self.cut_at is None:
            self.cut_at = self._record_at
        self._after_header = size == 3 and len(data) == 3
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        if whence == 1 and self._short:
            offset, whence = max(self._f.tell() + offset, self._record_at + 1), 0
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        self._f.close()


def read_ulog(path: Path, port_names: Sequence[str] = (), *, progress: Callable[[float], None] | None = None
              ) -> LogRead:  # fmt: skip
    """Read a PX4 ULog into the SI stream (module docstring); :class:`LogFormatError` if it is not one."""
    path = Path(path)
    if progress is not None:
        progress(0.0)
    ulog, guard, printed = _parse(path)
    if progress is not None:
        progress(PROGRESS_PARSED)
    report = ReadReport(path=path, format="ulog", time_base=TIME_BASE, file_bytes=path.stat().st_size)
    topics = _Topics(ulog, report)
    take = topics.take
    b = StreamBuilder(port_names)
    _imu(b, topics, report)
    if (air := take("vehicle_air_data")) is not None:
        if "baro_pressure_pa" in air:
            for t, p in zip(_t_sample_s(air), air["baro_pressure_pa"], strict=True):
                b.baro(float(t), float(p))
        else:
            report.warn(f"{path.name}: vehicle_air_data has no baro_pressure_pa (an older PX4: altitude only): "
                        "no barometer stream")  # fmt: skip
    if (dp := take("differential_pressure")) is not None:
        names = ("differential_pressure_pa", "differential_pressure_raw_pa", "differential_pressure_filtered_pa")
        field = next(k for k in names if k in dp)  # the raw Δp before the filtered one: no filter lag
        temps = dp.get("temperature", np.full(len(dp[field]), np.nan))  # [°C]; PX4 drivers without one: NaN
        for t, v, c in zip(_t_sample_s(dp), dp[field], temps, strict=True):
            b.pitot(float(t), float(v), float(c))
    if (mag := take("vehicle_magnetometer")) is not None:
        for t, m in zip(_t_sample_s(mag), _vec(mag, "magnetometer_ga") * GAUSS_TO_UT, strict=True):
            b.mag(float(t), m)
    gps = take("vehicle_gps_position")
    unix_boot = _gnss(b, gps if gps is not None else take("sensor_gps"), report)
    truth = _truth(topics)
    ap_estimate = _ap_estimate(b, topics, report)

    report.warn(f"{path.name}: no servo stream: PX4's actuator_outputs depend on the airframe's mixer (no generic "
                "map to aileron, elevator, throttle, rudder); the force-model modes run without control "
                "deflections")  # fmt: skip
    if port_names:
        report.warn(f"{path.name}: PX4 logs carry no pressure ports: the {len(port_names)} ports have no samples")
    for key in sorted(set(topics.all) - topics.used):
        report.unknown[_label(*key)] = len(topics.all[key]["timestamp"])
    _integrity(path, ulog, guard, printed, report)
    info = ulog.msg_info_dict
    meta = {"autopilot": "PX4", **{k: str(info[k]) for k in ("ver_sw_branch", "ver_sw", "ver_hw") if k in info},
            "gnss_alt": "AMSL", "ap_estimate": ap_estimate}  # fmt: skip
    log = b.build(path, report, meta=meta)
    if progress is not None:
        progress(1.0)
    return LogRead(log=log, truth=truth, report=report, unix_time_at_boot_s=unix_boot)


def _parse(path: Path) -> tuple[Any, _GuardedFile, str]:
    """pyulog's ULog of the file, the guard it read through, and what pyulog printed (it reports corruption
    on stdout: captured so that it becomes report warnings instead of mixing into a command's output)."""
    printed = io.StringIO()
    try:
        with path.open("rb") as f, contextlib.redirect_stdout(printed):
            guard = _GuardedFile(f)
            ulog = ULog(guard)
    except ULogException as e:
        raise LogFormatError(f"{path}: not a PX4 ULog ({e})") from None
    except OSError as e:
        raise LogFormatError(f"{path}: cannot read ({e.strerror or e})") from None
    if not ulog.data_list:
        where = f"; the file ends inside a record at byte {guard.cut_at}" if guard.cut_at is not None else ""
        raise LogFormatError(f"{path}: a ULog header but no data messages (corrupt or truncated{where})")
    return ulog, guard, printed.getvalue()


def _t_s(d: Topic) -> F64Array:
    return np.asarray(d["timestamp"], dtype=np.float64) * US_TO_S


def _t_sample_s(d: Topic) -> F64Array:
    """The sensor's sampling time when the topic has it (newer PX4), else the publication time."""
    return np.asarray(d.get("timestamp_sample", d["timestamp"]), dtype=np.float64) * US_TO_S


def _vec(d: Topic, name: str) -> F64Array:
    return np.stack([np.asarray(d[f"{name}[{i}]"], dtype=np.float64) for i in range(3)], axis=1)


class _Topics:
    """The log's topics by (name, instance); :meth:`take` counts a topic as used, the rest are reported as
    skipped."""

    def __init__(self, ulog: Any, report: ReadReport) -> None:
        self.all: dict[tuple[str, int], Topic] = {(d.name, d.multi_id): d.data for d in ulog.data_list}
        self.used: set[tuple[str, int]] = set()
        self._report = report

    def peek(self, name: str, instance: int = 0) -> Topic | None:
        return self.all.get((name, instance))

    def take(self, name: str, instance: int = 0) -> Topic | None:
        d = self.all.get((name, instance))
        if d is not None:
            self.used.add((name, instance))
            self._report.used[_label(name, instance)] = len(d["timestamp"])
        return d


def _label(name: str, instance: int) -> str:
    return name if instance == 0 else f"{name}[{instance}]"


def _imu(b: StreamBuilder, topics: _Topics, report: ReadReport) -> None:
    sc = topics.take("sensor_combined")
    if sc is None:
        report.warn(f"{report.path.name}: no sensor_combined: no IMU samples")
        return
    t = _t_s(sc)  # the gyro's sample time
    rel = np.asarray(sc.get("accelerometer_timestamp_relative", np.zeros(1)), dtype=np.int64)
    rel = np.abs(rel[rel != RELATIVE_TIMESTAMP_INVALID])
    if len(rel) and rel.max() * US_TO_S > ACCEL_GYRO_SKEW_WARN_S:
        report.warn(f"{report.path.name}: accelerometer samples up to {rel.max() * 1e-3:.1f} ms from the gyro's "
                    "in sensor_combined: both are stamped with the gyro's time")  # fmt: skip
    temp = np.full(len(t), DEFAULT_TEMPERATURE_C)
    if (src := _temperature(topics)) is not None and (ok := src[1] > INVALID_TEMPERATURE_C).any():
        temp = np.interp(t, src[0][ok], src[1][ok])
    for i, (g, a) in enumerate(zip(_vec(sc, "gyro_rad"), _vec(sc, "accelerometer_m_s2"), strict=True)):
        b.imu(float(t[i]), g, a, float(temp[i]))


def _temperature(topics: _Topics) -> tuple[F64Array, F64Array] | None:
    """(times [s], temperatures [°C]) for the IMU: the accelerometer that sensor_selection names (the one
    sensor_combined carries), else the first; else the barometer's (on the same board); None → 15 °C."""
    sel = topics.take("sensor_selection")
    want = int(sel["accel_device_id"][-1]) if sel is not None else -1
    instances = [i for i in range(4) if topics.peek("sensor_accel", i) is not None]  # PX4: at most 4
    chosen = next((i for i in instances if int(topics.all["sensor_accel", i]["device_id"][0]) == want), 0)
    if (acc := topics.take("sensor_accel", chosen)) is not None:
        return _t_sample_s(acc), np.asarray(acc["temperature"], dtype=np.float64)
    air = topics.peek("vehicle_air_data")
    if air is not None and "baro_temp_celcius" in air:  # sic: PX4's spelling
        return _t_sample_s(air), np.asarray(air["baro_temp_celcius"], dtype=np.float64)
    return None


def _gnss(b: StreamBuilder, g: Topic | None, report: ReadReport) -> float | None:
    """Append the 3-D fixes; return the UTC of the boot [s] (median over the fixes with a UTC) or None."""
    if g is None:
        report.warn(f"{report.path.name}: no vehicle_gps_position: no GNSS fixes")
        return None
    if "latitude_deg" in g:  # PX4 ≥ 1.15: float64 degrees, metres
        lat, lon = np.asarray(g["latitude_deg"], np.float64), np.asarray(g["longitude_deg"], np.float64)
        alt = np.asarray(g["altitude_msl_m"], np.float64)
    else:  # int32 degE7 and mm
        scale = DEG_E7 if g["lat"].dtype.kind in "iu" else 1.0  # some versions log float degrees as lat/lon
        lat, lon = (np.asarray(g[k], np.float64) * scale for k in ("lat", "lon"))
        alt = np.asarray(g["alt"], np.float64) * MM_TO_M
    v = np.stack([np.asarray(g[f"vel_{a}_m_s"], np.float64) for a in "ned"], axis=1)
    if "vel_ned_valid" in g:
        v[np.asarray(g["vel_ned_valid"]) == 0] = math.nan
    ok = np.asarray(g["fix_type"]) >= FIX_3D
    t = _t_sample_s(g)
    # the receiver's accuracy: eph, epv [m] (PX4's ubx driver: hAcc, vAcc); a field that is not positive is none
    acc = [np.asarray(g[k], np.float64) if k in g else np.full(len(t), np.nan) for k in ("eph", "epv")]
    h_acc, v_acc = (np.where(np.isfinite(a) & (a > 0.0), a, np.nan) for a in acc)
    for i in np.flatnonzero(ok):
        b.gnss(float(t[i]), float(lat[i]), float(lon[i]), float(alt[i]), v[i], float(h_acc[i]), float(v_acc[i]))
    if not ok.any():
        report.warn(f"{report.path.name}: no 3-D GNSS fix in {len(t)} vehicle_gps_position messages")
    if "time_utc_usec" not in g:
        return None
    utc = np.asarray(g["time_utc_usec"], dtype=np.float64)
    boot = np.asarray(g["timestamp"], np.float64) + np.asarray(g.get("timestamp_time_relative", 0), np.float64)
    has = ok & (utc > UNIX_USEC_MIN)  # the UTC belongs to timestamp + timestamp_time_relative
    return float(np.median(utc[has] - boot[has])) * US_TO_S if has.any() else None


def _truth(topics: _Topics) -> TruthTrack | None:
    """SITL's ground truth (Gazebo's / the simulator's state), when logged; real flights have none."""
    src = "PX4 groundtruth"
    if (gp := topics.take("vehicle_global_position_groundtruth")) is not None:
        lat, lon, alt = (np.asarray(gp[k], dtype=np.float64) for k in ("lat", "lon", "alt"))
        return TruthTrack(source=src, t_s=_t_s(gp), lat_deg=lat, lon_deg=lon, alt_m=alt)
    lp = topics.peek("vehicle_local_position_groundtruth")
    if lp is not None and "ref_lat" in lp and topics.take("vehicle_local_position_groundtruth") is not None:
        home = LocalFrame(float(lp["ref_lat"][-1]), float(lp["ref_lon"][-1]), float(lp["ref_alt"][-1]))
        lat, lon, alt = home.to_geodetic_array(np.stack([np.asarray(lp[k], np.float64) for k in "xyz"], axis=1))
        v = np.stack([np.asarray(lp[k], np.float64) for k in ("vx", "vy", "vz")], axis=1)
        return TruthTrack(source=src, t_s=_t_s(lp), lat_deg=lat, lon_deg=lon, alt_m=alt, v_ned_m_s=v)
    return None


def _ap_estimate(b: StreamBuilder, topics: _Topics, report: ReadReport) -> dict[str, str | None]:
    """The autopilot's own attitude and position estimate (module docstring) into the builder; the topics read."""
    out: dict[str, str | None] = {"position": None, "attitude": None}
    if (att := topics.take("vehicle_attitude")) is not None:
        q = np.stack([np.asarray(att[f"q[{i}]"], np.float64) for i in range(4)], axis=1)
        for t, qi in zip(_t_sample_s(att), q, strict=True):
            if np.isfinite(qi).all() and qi.any():  # a zero quaternion is no attitude (none estimated yet)
                b.ap_attitude(float(t), qi)
        out["attitude"] = "vehicle_attitude"
    if (gp := topics.take("vehicle_global_position")) is not None:
        ok = np.asarray(gp.get("lat_lon_valid", np.ones(len(gp["timestamp"]))), dtype=bool)
        lat, lon, alt = (np.asarray(gp[k], np.float64) for k in ("lat", "lon", "alt"))
        if "alt_valid" in gp:
            alt = np.where(np.asarray(gp["alt_valid"], dtype=bool), alt, math.nan)
        t = _t_sample_s(gp)
        for i in np.flatnonzero(ok):
            b.ap_position(float(t[i]), float(lat[i]), float(lon[i]), float(alt[i]))
        out["position"] = "vehicle_global_position"
        return out
    lp = topics.peek("vehicle_local_position")
    if lp is None or "ref_lat" not in lp:
        return out
    n = len(lp["timestamp"])
    ok = np.asarray(lp.get("xy_global", np.zeros(n)), dtype=bool) & np.asarray(lp.get("xy_valid", np.ones(n)), bool)
    if not ok.any():
        report.warn(f"{report.path.name}: vehicle_local_position never has a global reference (xy_global: the EKF "
                    "had no GNSS origin): no autopilot position estimate")  # fmt: skip
        return out
    topics.take("vehicle_local_position")
    ned = np.stack([np.asarray(lp[k], np.float64) for k in "xyz"], axis=1)
    ref = np.stack([np.asarray(lp[k], np.float64) for k in ("ref_lat", "ref_lon", "ref_alt")], axis=1)
    z_global = np.asarray(lp.get("z_global", np.ones(n)), dtype=bool)
    t = _t_sample_s(lp)
    # the reference moves when the EKF resets its origin: each run of rows is made geodetic at its own
    for r in np.unique(ref[ok], axis=0):
        sel = np.flatnonzero(ok & np.all(ref == r, axis=1))
        lat, lon, alt = LocalFrame(*(float(v) for v in r)).to_geodetic_array(ned[sel])
        for i, la, lo, al in zip(sel, lat, lon, alt, strict=True):
            b.ap_position(float(t[i]), float(la), float(lo), float(al) if z_global[i] else math.nan)
    out["position"] = "vehicle_local_position"
    return out


def _integrity(path: Path, ulog: Any, guard: _GuardedFile, printed: str, report: ReadReport) -> None:
    """Truncation, corruption and logging dropouts → the report."""
    if guard.cut_at is not None:
        report.truncated_at_byte = guard.cut_at
        report.warn(f"{path.name}: truncated: the file ends inside a record at byte {guard.cut_at}; read up to it")
    if ulog.file_corruption:
        report.malformed += 1  # pyulog skips corrupt data without counting it: at least one
        report.warn(f"{path.name}: corrupt data skipped (pyulog resynchronised; the amount is unknown)")
    lines = list(dict.fromkeys(x.strip() for x in printed.splitlines() if x.strip()))
    for line in lines[:PYULOG_LINES_KEPT]:
        report.warn(f"{path.name}: pyulog: {line}")
    if len(lines) > PYULOG_LINES_KEPT:
        report.warn(f"{path.name}: pyulog: … and {len(lines) - PYULOG_LINES_KEPT} more such messages")
    if ulog.dropouts:
        lost_ms = sum(int(d.duration) for d in ulog.dropouts)
        report.warn(f"{path.name}: {len(ulog.dropouts)} logging dropouts ({lost_ms} ms of data not written)")
