"""What a SITL run writes to disk: the telemetry log (``.tlog``) and the truth record (``.npz``).

**tlog** — the MAVProxy/QGroundControl format: every MAVLink frame, sent or received, prefixed by its
time as an 8-byte big-endian unsigned integer of microseconds since the Unix epoch. Readable with
``pymavlink.mavutil.mavlink_connection(path)``. The times are the autopilot's clock (``SYSTEM_TIME``:
Unix time at boot + world time), so rates read from the log are world-time rates at any ``speed``.

**truth** — a NumPy ``.npz`` (``numpy.load(path)``) with format key ``"vdm-aero-sitl-truth/1"``; the
keys and units are listed in ``TRUTH_KEYS`` / ``PORTS_KEYS`` / ``GPS_INPUT_KEYS`` / ``ODOMETRY_KEYS`` and
in docs/sitl.md.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

import numpy as np

from sim.flight.contract import PortsSample, VehicleTruth
from vdm_aero._typing import F64Array

TRUTH_FORMAT = "vdm-aero-sitl-truth/1"
_TLOG_STAMP = struct.Struct(">Q")
_CHUNK_ROWS = 4096

# (key, columns, unit / meaning); one row per recorded world step
TRUTH_KEYS: tuple[tuple[str, int, str], ...] = (
    ("t_s", 1, "world time = autopilot time since boot [s]"),
    ("lat_deg", 1, "latitude [deg]"),
    ("lon_deg", 1, "longitude [deg]"),
    ("alt_m", 1, "altitude above mean sea level [m]"),
    ("pos_ned_m", 3, "position from home, NED [m]"),
    ("v_ned_m_s", 3, "ground velocity, NED [m/s]"),
    ("q_nb", 4, "attitude quaternion body→NED, scalar first"),
    ("omega_b_rad_s", 3, "body rates p, q, r [rad/s]"),
    ("specific_force_b_m_s2", 3, "specific force, body FRD [m/s²]"),
    ("airspeed_m_s", 1, "true airspeed [m/s]"),
    ("alpha_rad", 1, "angle of attack [rad]"),
    ("beta_rad", 1, "sideslip angle [rad]"),
    ("wind_ned_m_s", 3, "wind at the vehicle, NED [m/s]"),
    ("throttle", 1, "throttle 0..1"),
    ("gnss_outage", 1, "inside a scripted GNSS outage window (bool)"),
    ("estimate_error_ned_m", 3, "position error of the autopilot's own estimate (GLOBAL_POSITION_INT) [m]"),
)
PORTS_KEYS: tuple[tuple[str, str], ...] = (
    ("port_names", "(k,) port names, ≤ 10 characters"),
    ("ports_t_s", "(m,) sample times [s]"),
    ("ports_dp_pa", "(m, k) Δp = p_port − p_static as sampled (what was sent) [Pa]"),
)
GPS_INPUT_KEYS: tuple[tuple[str, str], ...] = (
    ("gps_input_received_t_s", "(g,) autopilot time when received [s]"),
    ("gps_input_time_usec", "(g,) time_usec as sent [µs]"),
    ("gps_input_fix_type", "(g,) GPS_FIX_TYPE"),
    ("gps_input_lat_deg", "(g,) latitude [deg]"),
    ("gps_input_lon_deg", "(g,) longitude [deg]"),
    ("gps_input_alt_m", "(g,) altitude MSL [m]"),
    ("gps_input_v_ned_m_s", "(g, 3) velocity NED [m/s]"),
    ("gps_input_h_acc_m", "(g,) horizontal accuracy [m]"),
    ("gps_input_v_acc_m", "(g,) vertical accuracy [m]"),
    ("gps_input_speed_acc_m_s", "(g,) speed accuracy [m/s]"),
    ("gps_input_satellites", "(g,) satellites visible"),
    ("gps_input_ignore_flags", "(g,) GPS_INPUT_IGNORE_FLAGS bitmask"),
)
ODOMETRY_KEYS: tuple[tuple[str, str], ...] = (
    ("odometry_received_t_s", "(o,) autopilot time when received [s]"),
    ("odometry_time_usec", "(o,) time_usec as sent [µs]"),
    ("odometry_frame_id", "(o,) MAV_FRAME of the pose"),
    ("odometry_child_frame_id", "(o,) MAV_FRAME of the velocity"),
    ("odometry_pos_m", "(o, 3) x, y, z [m]"),
    ("odometry_q", "(o, 4) attitude quaternion w, x, y, z"),
    ("odometry_vel_m_s", "(o, 3) vx, vy, vz [m/s]"),
    ("odometry_rates_rad_s", "(o, 3) roll, pitch, yaw rates [rad/s]"),
    ("odometry_pose_covariance", "(o, 21) upper triangle of the pose covariance"),
    ("odometry_velocity_covariance", "(o, 21) upper triangle of the velocity covariance"),
    ("odometry_quality", "(o,) quality 0..100 (-1 failed)"),
)


class TlogWriter:
    """Append frames to a ``.tlog``: 8-byte big-endian Unix µs, then the raw frame."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file: BinaryIO = path.open("wb")
        self.frames = 0

    def write(self, t_unix_us: int, frame: bytes) -> None:
        self._file.write(_TLOG_STAMP.pack(t_unix_us))
        self._file.write(frame)
        self.frames += 1

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class _Rows:
    """A growable float64 table filled in chunks (no per-row Python objects kept)."""

    def __init__(self, width: int) -> None:
        self._width = width
        self._chunks: list[F64Array] = []
        self._fill = _CHUNK_ROWS

    def append(self, row: Sequence[float] | F64Array) -> None:
        if self._fill == _CHUNK_ROWS:
            self._chunks.append(np.empty((_CHUNK_ROWS, self._width), dtype=np.float64))
            self._fill = 0
        self._chunks[-1][self._fill] = row
        self._fill += 1

    def array(self) -> F64Array:
        if not self._chunks:
            return np.empty((0, self._width), dtype=np.float64)
        return np.concatenate([*self._chunks[:-1], self._chunks[-1][: self._fill]])


@dataclass(frozen=True)
class GpsInputRecord:
    """A GPS_INPUT received from the companion, in SI units."""

    received_t_s: float  # autopilot time (since boot) when it arrived
    time_usec: int
    gps_id: int
    ignore_flags: int
    fix_type: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    v_ned_m_s: F64Array  # (3,)
    hdop: float
    vdop: float
    h_acc_m: float
    v_acc_m: float
    speed_acc_m_s: float
    satellites: int
    yaw_rad: float | None  # None: not available (yaw = 0 in the message)


@dataclass(frozen=True)
class OdometryRecord:
    """An ODOMETRY received from the companion (already SI in MAVLink)."""

    received_t_s: float
    time_usec: int
    frame_id: int
    child_frame_id: int
    pos_m: F64Array  # (3,)
    q: F64Array  # (4,) w, x, y, z
    vel_m_s: F64Array  # (3,)
    rates_rad_s: F64Array  # (3,)
    pose_covariance: F64Array  # (21,)
    velocity_covariance: F64Array  # (21,)
    reset_counter: int
    estimator_type: int
    quality: int


class TruthRecorder:
    """Collects the truth (every ``every_n_steps``-th world step), the port samples and companion inputs."""

    def __init__(self, *, home: tuple[float, float, float], every_n_steps: int = 1) -> None:
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps = {every_n_steps}: must be ≥ 1")
        self._home = home
        self._every = every_n_steps
        self._steps = 0
        self._truth = _Rows(sum(n for _, n, _ in TRUTH_KEYS))
        self._port_names: tuple[str, ...] | None = None
        self._ports_t: list[float] = []
        self._ports: _Rows | None = None

    def add_truth(self, truth: VehicleTruth, *, gnss_outage: bool, estimate_error_ned_m: F64Array) -> None:
        self._steps += 1
        if (self._steps - 1) % self._every:
            return
        row = np.concatenate(
            [
                [truth.t_s, truth.lat_deg, truth.lon_deg, truth.alt_m],
                truth.pos_ned_m,
                truth.v_ned_m_s,
                truth.q_nb,
                truth.omega_b_rad_s,
                truth.specific_force_b_m_s2,
                [truth.airspeed_m_s, truth.alpha_rad, truth.beta_rad],
                truth.wind_ned_m_s,
                [truth.throttle, float(gnss_outage)],
                estimate_error_ned_m,
            ]
        )
        self._truth.append(row)

    def add_ports(self, sample: PortsSample) -> None:
        if self._ports is None:
            self._port_names = sample.names
            self._ports = _Rows(len(sample.names))
        if sample.names != self._port_names:
            raise ValueError(f"port names changed during the run: {self._port_names} → {sample.names}")
        self._ports_t.append(sample.t_s)
        self._ports.append(sample.dp_pa)

    def arrays(self, gps_inputs: Sequence[GpsInputRecord], odometry: Sequence[OdometryRecord]) -> dict[str, np.ndarray]:
        table = self._truth.array()
        out: dict[str, np.ndarray] = {"format": np.array(TRUTH_FORMAT)}
        col = 0
        for key, width, _ in TRUTH_KEYS:
            block = table[:, col : col + width]
            out[key] = block[:, 0] if width == 1 else block
            col += width
        out["gnss_outage"] = out["gnss_outage"].astype(bool)
        out["home_lat_deg"], out["home_lon_deg"], out["home_alt_m"] = (np.array(v) for v in self._home)
        out["port_names"] = np.array(self._port_names or (), dtype="<U10")
        out["ports_t_s"] = np.asarray(self._ports_t, dtype=np.float64)
        out["ports_dp_pa"] = self._ports.array() if self._ports is not None else np.empty((0, 0))
        g = gps_inputs
        out["gps_input_received_t_s"] = np.array([r.received_t_s for r in g], dtype=np.float64)
        out["gps_input_time_usec"] = np.array([r.time_usec for r in g], dtype=np.int64)
        out["gps_input_fix_type"] = np.array([r.fix_type for r in g], dtype=np.int64)
        out["gps_input_lat_deg"] = np.array([r.lat_deg for r in g], dtype=np.float64)
        out["gps_input_lon_deg"] = np.array([r.lon_deg for r in g], dtype=np.float64)
        out["gps_input_alt_m"] = np.array([r.alt_m for r in g], dtype=np.float64)
        out["gps_input_v_ned_m_s"] = np.array([r.v_ned_m_s for r in g], dtype=np.float64).reshape(-1, 3)
        out["gps_input_h_acc_m"] = np.array([r.h_acc_m for r in g], dtype=np.float64)
        out["gps_input_v_acc_m"] = np.array([r.v_acc_m for r in g], dtype=np.float64)
        out["gps_input_speed_acc_m_s"] = np.array([r.speed_acc_m_s for r in g], dtype=np.float64)
        out["gps_input_satellites"] = np.array([r.satellites for r in g], dtype=np.int64)
        out["gps_input_ignore_flags"] = np.array([r.ignore_flags for r in g], dtype=np.int64)
        o = odometry
        out["odometry_received_t_s"] = np.array([r.received_t_s for r in o], dtype=np.float64)
        out["odometry_time_usec"] = np.array([r.time_usec for r in o], dtype=np.int64)
        out["odometry_frame_id"] = np.array([r.frame_id for r in o], dtype=np.int64)
        out["odometry_child_frame_id"] = np.array([r.child_frame_id for r in o], dtype=np.int64)
        out["odometry_pos_m"] = np.array([r.pos_m for r in o], dtype=np.float64).reshape(-1, 3)
        out["odometry_q"] = np.array([r.q for r in o], dtype=np.float64).reshape(-1, 4)
        out["odometry_vel_m_s"] = np.array([r.vel_m_s for r in o], dtype=np.float64).reshape(-1, 3)
        out["odometry_rates_rad_s"] = np.array([r.rates_rad_s for r in o], dtype=np.float64).reshape(-1, 3)
        out["odometry_pose_covariance"] = np.array([r.pose_covariance for r in o], dtype=np.float64).reshape(-1, 21)
        out["odometry_velocity_covariance"] = np.array([r.velocity_covariance for r in o], dtype=np.float64).reshape(
            -1, 21
        )
        out["odometry_quality"] = np.array([r.quality for r in o], dtype=np.int64)
        return out

    def write(self, path: Path, gps_inputs: Sequence[GpsInputRecord], odometry: Sequence[OdometryRecord]) -> None:
        """Write the ``.npz`` (``np.savez`` appends ``.npz`` to a path without it; we keep the path as given)."""
        with path.open("wb") as f:
            np.savez(f, allow_pickle=False, **self.arrays(gps_inputs, odometry))
