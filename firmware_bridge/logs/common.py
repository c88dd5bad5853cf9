"""What every log reader produces: the SI measurement stream (a :class:`~vdm_aero.flightlog.SensorLog`), an
optional truth, and a report of what was read, skipped and warned about.

Each reader converts its format's units once per message type and appends SI samples to a
:class:`StreamBuilder`; the builder sorts each stream, drops repeated time stamps (a stream sent faster
than its sensor, or a reboot's overlap) and counts them. Times are seconds on the autopilot's clock (its
boot time, made continuous across reboots), the clock the service runs its filter on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.flightlog import SENSOR_KEYS, FlightLogError, SensorLog
from vdm_aero.nav.filter import SLOW_IMU_HZ

__all__ = ["LogFormatError", "LogRead", "ReadReport", "StreamBuilder", "TruthTrack"]

Vec = Sequence[float] | F64Array
UT_TO_T = 1e-6
LOW_IMU_RATE_HZ = 100.0  # below this the strapdown integration of manoeuvres is poor: warned about
LOW_AIDING_RATE_HZ = {"baro": 5.0, "pitot": 5.0, "mag": 5.0, "gnss": 1.0, "ports": 10.0}
"""Below these a stream was logged decimated: the filter fuses the aiding sensors at up to 10 Hz."""


class LogFormatError(FlightLogError):
    """A file that is not a log of the format its reader expects (wrong magic, unreadable)."""


@dataclass
class ReadReport:
    """What a reader did with a file: per message type counts, what it skipped, where it stopped."""

    path: Path
    format: str  # "tlog", "dataflash", "ulog"
    time_base: str  # what the stream's times are, e.g. "HIGHRES_IMU.time_usec (autopilot boot time)"
    file_bytes: int = 0
    used: dict[str, int] = field(default_factory=dict)  # message type → messages converted
    unknown: dict[str, int] = field(default_factory=dict)  # message type → skipped (not needed or not known)
    malformed: int = 0  # records that failed to decode (CRC, length, garbage): skipped
    duplicates: dict[str, int] = field(default_factory=dict)  # stream → samples with a repeated time stamp
    truncated_at_byte: int | None = None  # the file ends inside a record: read up to here
    last_time_s: float | None = None  # the last whole record's time
    reboots: int = 0
    warnings: list[str] = field(default_factory=list)

    def count(self, kind: str) -> None:
        self.used[kind] = self.used.get(kind, 0) + 1

    def skip(self, kind: str) -> None:
        self.unknown[kind] = self.unknown.get(kind, 0) + 1

    def warn(self, line: str) -> None:
        if line not in self.warnings:
            self.warnings.append(line)

    def to_dict(self) -> dict[str, Any]:
        return {"path": str(self.path), "format": self.format, "time_base": self.time_base,
                "file_bytes": self.file_bytes, "used": dict(self.used), "unknown": dict(self.unknown),
                "malformed": self.malformed, "duplicates": dict(self.duplicates),
                "truncated_at_byte": self.truncated_at_byte, "last_time_s": self.last_time_s,
                "reboots": self.reboots, "warnings": list(self.warnings)}  # fmt: skip


@dataclass(frozen=True, eq=False)
class TruthTrack:
    """A reference trajectory better than the log's GNSS: SITL's SIMSTATE/SIM, or the mock's truth file.

    ``t_s`` on the stream's clock; geodetic position; velocity and attitude when the source has them."""

    source: str
    t_s: F64Array
    lat_deg: F64Array
    lon_deg: F64Array
    alt_m: F64Array
    v_ned_m_s: F64Array | None = None
    q_nb: F64Array | None = None


@dataclass(frozen=True, eq=False)
class LogRead:
    log: SensorLog
    truth: TruthTrack | None
    report: ReadReport
    unix_time_at_boot_s: float | None = None  # UTC of the autopilot's boot (SYSTEM_TIME, GPS time), if known


class StreamBuilder:
    """Collects SI samples per stream (module docstring); :meth:`build` makes the :class:`SensorLog`."""

    def __init__(self, port_names: Sequence[str] = ()) -> None:
        self.port_names = tuple(port_names)
        self._rows: dict[str, list[Any]] = {
            k: [] for k in ("imu", "ports", "pitot", "baro", "servo", "gnss", "mag", "ap_att", "ap_pos")
        }

    def imu(self, t_s: float, gyro_b_rad_s: Vec, accel_b_m_s2: Vec, temperature_c: float) -> None:
        self._rows["imu"].append((t_s, *gyro_b_rad_s, *accel_b_m_s2, temperature_c))

    def baro(self, t_s: float, pressure_pa: float) -> None:
        self._rows["baro"].append((t_s, pressure_pa))

    def pitot(self, t_s: float, dp_pa: float, temperature_c: float = math.nan) -> None:
        """Differential pressure [Pa] and the airspeed sensor's temperature [°C] (NaN: none in the log)."""
        self._rows["pitot"].append((t_s, dp_pa, temperature_c))

    def mag(self, t_s: float, field_b_ut: Vec) -> None:
        self._rows["mag"].append((t_s, *(v * UT_TO_T for v in field_b_ut)))

    def gnss(self, t_valid_s: float, lat_deg: float, lon_deg: float, alt_m: float, v_ned_m_s: Vec,
             h_acc_m: float = math.nan, v_acc_m: float = math.nan) -> None:  # fmt: skip
        """A 3-D fix at its time of validity; v_D NaN when the format has no vertical velocity; the receiver's
        horizontal and vertical accuracy [m], NaN where the log has none."""
        self._rows["gnss"].append((t_valid_s, lat_deg, lon_deg, alt_m, *v_ned_m_s, h_acc_m, v_acc_m))

    def gnss_accuracy(self, t_s: float, h_acc_m: float, v_acc_m: float) -> bool:
        """The accuracy of the last fix, logged apart from it with the same stamp (DataFlash's GPA beside its
        GPS); False when the last fix has another stamp."""
        rows = self._rows["gnss"]
        if not rows or abs(rows[-1][0] - t_s) > 1e-6:
            return False
        rows[-1] = (*rows[-1][:7], h_acc_m, v_acc_m)
        return True

    def servo(self, t_s: float, pwm_us: Vec) -> None:
        """PWM [µs] of aileron, elevator, throttle, rudder (ArduPlane order)."""
        self._rows["servo"].append((t_s, *pwm_us))

    def ports(self, t_s: float, dp_pa: Vec) -> None:
        """One port frame in :attr:`port_names` order (NaN for a port that did not arrive)."""
        self._rows["ports"].append((t_s, *dp_pa))

    def ap_attitude(self, t_s: float, q_nb: Vec) -> None:
        """The autopilot's own attitude estimate (body FRD → NED quaternion, w x y z)."""
        self._rows["ap_att"].append((t_s, *q_nb))

    def ap_position(self, t_s: float, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        """The autopilot's own position estimate (altitude above mean sea level [m])."""
        self._rows["ap_pos"].append((t_s, lat_deg, lon_deg, alt_m))

    def __len__(self) -> int:
        return sum(len(v) for v in self._rows.values())

    def _table(self, stream: str, width: int, report: ReadReport) -> F64Array:
        rows = self._rows[stream]
        a = np.array(rows, dtype=np.float64).reshape(-1, width) if rows else np.zeros((0, width))
        if len(a) < 2:
            return a
        a = a[np.argsort(a[:, 0], kind="stable")]
        keep = np.concatenate([[True], np.diff(a[:, 0]) > 0.0])
        if not keep.all():
            report.duplicates[stream] = int((~keep).sum())
        return a[keep]

    def build(self, path: Path, report: ReadReport, meta: dict[str, Any] | None = None) -> SensorLog:
        n_p = len(self.port_names)
        imu = self._table("imu", 8, report)
        ports = self._table("ports", 1 + n_p, report)
        pitot = self._table("pitot", 3, report)
        baro = self._table("baro", 2, report)
        servo = self._table("servo", 5, report)
        gnss = self._table("gnss", 9, report)
        mag = self._table("mag", 4, report)
        att = self._table("ap_att", 5, report)
        pos = self._table("ap_pos", 4, report)
        arrays: dict[str, F64Array] = {
            "imu_t_s": imu[:, 0], "imu_gyro_b_rad_s": imu[:, 1:4], "imu_accel_b_m_s2": imu[:, 4:7],
            "imu_temperature_c": imu[:, 7], "ports_t_s": ports[:, 0], "ports_dp_pa": ports[:, 1:],
            "pitot_t_s": pitot[:, 0], "pitot_dp_pa": pitot[:, 1], "pitot_temperature_c": pitot[:, 2],
            "baro_t_s": baro[:, 0], "baro_pa": baro[:, 1],
            "servo_t_s": servo[:, 0], "servo_pwm_us": servo[:, 1:], "gnss_t_s": gnss[:, 0],
            "gnss_lat_deg": gnss[:, 1], "gnss_lon_deg": gnss[:, 2], "gnss_alt_m": gnss[:, 3],
            "gnss_v_ned_m_s": gnss[:, 4:7], "gnss_h_acc_m": gnss[:, 7], "gnss_v_acc_m": gnss[:, 8],
            "mag_t_s": mag[:, 0], "mag_field_b_t": mag[:, 1:],
            "ap_att_t_s": att[:, 0], "ap_att_q_nb": att[:, 1:], "ap_pos_t_s": pos[:, 0], "ap_pos_lat_deg": pos[:, 1],
            "ap_pos_lon_deg": pos[:, 2], "ap_pos_alt_m": pos[:, 3],
        }  # fmt: skip
        assert set(arrays) == set(SENSOR_KEYS)
        sensed = [a for k, a in arrays.items() if k.endswith("_t_s") and not k.startswith("ap_") and len(a)]
        starts, ends = [a[0] for a in sensed], [a[-1] for a in sensed]
        duration = (max(ends) - min(starts)) if starts else 0.0
        report.last_time_s = max(ends) if ends else None
        rates = {s: _rate_hz(arrays[f"{s}_t_s"]) for s in ("imu", "ports", "pitot", "baro", "servo", "gnss", "mag")}
        imu_hz = rates["imu"]
        if len(imu) >= 2 and imu_hz < SLOW_IMU_HZ and len(att):
            report.warn(
                f"{path.name}: IMU at {imu_hz:.1f} Hz, too slow to integrate alone: the autopilot's own attitude "
                f"({_rate_hz(att[:, 0]):.1f} Hz) is fused as a measurement; the autopilot had GNSS through the "
                "whole flight, outages cut in here included, so the outage figures are optimistic"
            )
        elif len(imu) >= 2 and imu_hz < LOW_IMU_RATE_HZ:
            report.warn(
                f"{path.name}: IMU at {imu_hz:.1f} Hz (< {LOW_IMU_RATE_HZ:g} Hz: a decimated log?); the "
                "strapdown integration between samples is poor and the drift figures are not representative"
            )
        slow = [f"{k} {rates[k]:.1f} Hz" for k, lo in LOW_AIDING_RATE_HZ.items() if 0.0 < rates[k] < lo]
        if slow:
            report.warn(f"{path.name}: streams logged at reduced rates (a decimated log?): {', '.join(slow)}; the "
                        "filter fuses them at up to 10 Hz, so the figures are worse than the aircraft's")  # fmt: skip
        if not len(pitot):
            report.warn(f"{path.name}: no airspeed (pitot) samples: the modes that fuse the pitot run without it")
        doc = {"name": path.name, "source": {"log": str(path), "format": report.format},
               "duration_s": float(duration), "rates_hz": rates, **(meta or {})}  # fmt: skip
        return SensorLog(path=path, meta=doc, port_names=self.port_names, arrays=arrays)


def _rate_hz(t: F64Array) -> float:
    """The stream's typical rate: 1 / median sample interval [Hz] (0 for fewer than two samples)."""
    if len(t) < 2:
        return 0.0
    return float(1.0 / max(float(np.median(np.diff(t))), 1e-9))
