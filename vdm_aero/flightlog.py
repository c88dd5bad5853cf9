"""``vdm-aero-flightlog/1``: a flight's sensor streams in SI units, and (for simulated flights) its truth.

A flight-log directory holds:

* ``flight.yaml``: format, name, source (scenario, vehicle, seed), duration, port names, stream rates;
* ``sensors.npz``: what a user's aircraft records (the only file :func:`load_sensor_log` reads):
  ``imu_t_s`` (N,), ``imu_accel_b_m_s2`` (N, 3), ``imu_gyro_b_rad_s`` (N, 3), ``imu_temperature_c`` (N,);
  ``ports_t_s`` (M,), ``ports_dp_pa`` (M, P) (Δp = p_port − p_static); ``pitot_t_s``, ``pitot_dp_pa``,
  ``pitot_temperature_c`` (the airspeed sensor's temperature, NaN where it reports none; optional: a log
  written before 2026-11-26 reads as all NaN);
  ``baro_t_s``, ``baro_pa``; ``servo_t_s``, ``servo_pwm_us`` (K, 4, ArduPlane order aileron, elevator,
  throttle, rudder); ``gnss_t_s`` (time of validity), ``gnss_lat_deg``, ``gnss_lon_deg``, ``gnss_alt_m``,
  ``gnss_v_ned_m_s`` (G, 3), ``gnss_h_acc_m``, ``gnss_v_acc_m`` (the receiver's accuracy estimates, NaN where
  it reports none; optional: a log written before 2026-11-27 reads as all NaN); ``mag_t_s``, ``mag_field_b_t``
  (H, 3). A stream the aircraft lacks (no pitot) has zero rows. What the autopilot's own estimator said, where
  the log holds it (optional, zero rows when absent): ``ap_att_t_s``, ``ap_att_q_nb`` (A, 4: body FRD → NED,
  w x y z); ``ap_pos_t_s``, ``ap_pos_lat_deg``, ``ap_pos_lon_deg``, ``ap_pos_alt_m`` (B,) — for comparison,
  and the autopilot's attitude as a measurement where the IMU is logged too slowly to integrate (a ground
  station's tlog).
* ``truth.npz`` (simulated flights only, for evaluation; never an input of calibration or navigation):
  at the port sample times ``t_s``, the aerodynamic coefficients ``coeffs`` (M, 6) (body axes about the
  true CG, on the true dynamic pressure ``qbar_pa`` and the reference geometry), ``airspeed_m_s``,
  ``alpha_rad``, ``beta_rad``, ``pos_ned_m``, ``v_ned_m_s``, ``q_nb``, ``omega_b_rad_s``, ``wind_ned_m_s``,
  ``thrust_n``.

Writes are atomic (a sibling temporary directory renamed into place).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vdm_aero._typing import F64Array
from vdm_aero.atomic import install_directory
from vdm_aero.dataset import to_plain
from vdm_aero.errors import UserInputError

__all__ = ["FLIGHTLOG_FORMAT", "FlightLogError", "SensorLog", "load_sensor_log", "load_truth", "write_flight_log"]

FLIGHTLOG_FORMAT = "vdm-aero-flightlog/1"
SENSOR_KEYS: dict[str, int] = {
    "imu_t_s": 1,
    "imu_accel_b_m_s2": 2,
    "imu_gyro_b_rad_s": 2,
    "imu_temperature_c": 1,
    "ports_t_s": 1,
    "ports_dp_pa": 2,
    "pitot_t_s": 1,
    "pitot_dp_pa": 1,
    "pitot_temperature_c": 1,
    "baro_t_s": 1,
    "baro_pa": 1,
    "servo_t_s": 1,
    "servo_pwm_us": 2,
    "gnss_t_s": 1,
    "gnss_lat_deg": 1,
    "gnss_lon_deg": 1,
    "gnss_alt_m": 1,
    "gnss_v_ned_m_s": 2,
    "gnss_h_acc_m": 1,
    "gnss_v_acc_m": 1,
    "mag_t_s": 1,
    "mag_field_b_t": 2,
    "ap_att_t_s": 1,
    "ap_att_q_nb": 2,
    "ap_pos_t_s": 1,
    "ap_pos_lat_deg": 1,
    "ap_pos_lon_deg": 1,
    "ap_pos_alt_m": 1,
}
"""Every sensor array and its number of dimensions."""
_OPTIONAL = {
    "pitot_temperature_c": "pitot_t_s",
    "gnss_h_acc_m": "gnss_t_s",
    "gnss_v_acc_m": "gnss_t_s",
}  # filled with NaN, one per row of its stream, when absent
# the autopilot's own estimate: zero rows when a log has none (and in logs written before 2026-11-26)
_EMPTY_IF_ABSENT: dict[str, tuple[int, ...]] = {
    "ap_att_t_s": (0,), "ap_att_q_nb": (0, 4), "ap_pos_t_s": (0,), "ap_pos_lat_deg": (0,), "ap_pos_lon_deg": (0,),
    "ap_pos_alt_m": (0,),
}  # fmt: skip
_STREAMS = {
    "imu": ("imu_t_s", "imu_accel_b_m_s2", "imu_gyro_b_rad_s", "imu_temperature_c"),
    "ports": ("ports_t_s", "ports_dp_pa"),
    "pitot": ("pitot_t_s", "pitot_dp_pa", "pitot_temperature_c"),
    "baro": ("baro_t_s", "baro_pa"),
    "servo": ("servo_t_s", "servo_pwm_us"),
    "gnss": (
        "gnss_t_s",
        "gnss_lat_deg",
        "gnss_lon_deg",
        "gnss_alt_m",
        "gnss_v_ned_m_s",
        "gnss_h_acc_m",
        "gnss_v_acc_m",
    ),
    "mag": ("mag_t_s", "mag_field_b_t"),
    "ap_att": ("ap_att_t_s", "ap_att_q_nb"),
    "ap_pos": ("ap_pos_t_s", "ap_pos_lat_deg", "ap_pos_lon_deg", "ap_pos_alt_m"),
}


class FlightLogError(UserInputError):
    """A flight log that is missing, malformed or inconsistent."""


@dataclass(frozen=True, eq=False)
class SensorLog:
    """A flight's sensor streams (see the module docstring for the arrays) and its metadata."""

    path: Path
    meta: Mapping[str, Any]
    port_names: tuple[str, ...]
    arrays: Mapping[str, F64Array]

    def __getitem__(self, key: str) -> F64Array:
        return self.arrays[key]

    @property
    def duration_s(self) -> float:
        return float(self.meta["duration_s"])

    @property
    def has_pitot(self) -> bool:
        return len(self.arrays["pitot_t_s"]) > 0

    def window(self, t0_s: float, t1_s: float) -> SensorLog:
        """The same log restricted to t0 ≤ t < t1 [s] in every stream."""
        out: dict[str, F64Array] = {}
        for keys in _STREAMS.values():
            if keys[0] not in self.arrays:
                continue  # an in-memory log built without the optional streams
            t = self.arrays[keys[0]]
            m = (t >= t0_s) & (t < t1_s)
            for k in keys:
                out[k] = self.arrays[k][m]
        meta = {**self.meta, "duration_s": min(t1_s, self.duration_s) - max(t0_s, 0.0), "window_s": [t0_s, t1_s]}
        return SensorLog(path=self.path, meta=meta, port_names=self.port_names, arrays=out)


def write_flight_log(
    path: str | Path,
    *,
    meta: Mapping[str, Any],
    port_names: tuple[str, ...],
    sensors: Mapping[str, np.ndarray],
    truth: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write a flight-log directory atomically; ``sensors`` must hold every key of :data:`SENSOR_KEYS`."""
    sensors = {**{k: np.zeros(shape) for k, shape in _EMPTY_IF_ABSENT.items()}, **sensors}
    missing = sorted(set(SENSOR_KEYS) - set(sensors))
    if missing:
        raise ValueError(f"sensor arrays missing: {missing}")
    root = Path(path)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        arrays: dict[str, Any] = {k: np.asarray(sensors[k], dtype=np.float64) for k in SENSOR_KEYS}
        np.savez(tmp / "sensors.npz", **arrays)
        if truth is not None:
            tarrays: dict[str, Any] = {k: np.asarray(v, dtype=np.float64) for k, v in truth.items()}
            np.savez(tmp / "truth.npz", **tarrays)
        doc = {"format": FLIGHTLOG_FORMAT, **dict(meta), "port_names": list(port_names)}
        (tmp / "flight.yaml").write_text(yaml.safe_dump(to_plain(doc), sort_keys=False, allow_unicode=True))
        if root.exists() and not (root / "flight.yaml").is_file():
            raise FlightLogError(f"{root}: exists and is not a flight log; refusing to overwrite")
        install_directory(tmp, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return root


def _meta(root: Path) -> dict[str, Any]:
    p = root / "flight.yaml"
    if not root.is_dir():
        raise FlightLogError(f"{root}: no such flight-log directory")
    try:
        meta = yaml.safe_load(p.read_text())
    except OSError:
        raise FlightLogError(f"{p}: missing (not a {FLIGHTLOG_FORMAT} directory)") from None
    except yaml.YAMLError:
        raise FlightLogError(f"{p}: YAML syntax error") from None
    if not isinstance(meta, dict) or meta.get("format") != FLIGHTLOG_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else None
        raise FlightLogError(f"{p}: format {got!r} is not supported (expected {FLIGHTLOG_FORMAT})")
    for k in ("duration_s", "port_names"):
        if k not in meta:
            raise FlightLogError(f"{p}: {k}: missing")
    return meta


def load_sensor_log(path: str | Path) -> SensorLog:
    """Read and check a flight log's sensors (never its truth)."""
    root = Path(path)
    meta = _meta(root)
    names = tuple(str(n) for n in meta["port_names"])
    f = root / "sensors.npz"
    try:
        with np.load(f, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k], dtype=np.float64) for k in SENSOR_KEYS
                      if k in z.files or (k not in _OPTIONAL and k not in _EMPTY_IF_ABSENT)}  # fmt: skip
        for k, shape in _EMPTY_IF_ABSENT.items():
            arrays.setdefault(k, np.zeros(shape))
        for k, rows in _OPTIONAL.items():
            arrays.setdefault(k, np.full(len(arrays[rows]), np.nan))
    except KeyError as e:
        raise FlightLogError(f"{f}: array {e} missing") from None
    except (OSError, ValueError) as e:
        raise FlightLogError(f"{f}: unreadable ({e})") from None
    for k, nd in SENSOR_KEYS.items():
        if arrays[k].ndim != nd:
            raise FlightLogError(f"{f}: {k} has {arrays[k].ndim} dimensions, expected {nd}")
    for stream, keys in _STREAMS.items():
        n = len(arrays[keys[0]])
        for k in keys[1:]:
            if len(arrays[k]) != n:
                raise FlightLogError(f"{f}: {k} has {len(arrays[k])} rows but {keys[0]} has {n}")
        if n and np.any(np.diff(arrays[keys[0]]) <= 0.0):
            raise FlightLogError(f"{f}: {keys[0]}: times must increase ({stream} stream)")
    if arrays["ports_dp_pa"].ndim == 2 and arrays["ports_dp_pa"].shape[1] != len(names) and len(arrays["ports_t_s"]):
        raise FlightLogError(
            f"{f}: ports_dp_pa has {arrays['ports_dp_pa'].shape[1]} columns for {len(names)} port names"
        )
    if len(arrays["servo_t_s"]) and arrays["servo_pwm_us"].shape[1] != 4:
        raise FlightLogError(f"{f}: servo_pwm_us must have 4 columns (aileron, elevator, throttle, rudder)")
    return SensorLog(path=root, meta=meta, port_names=names, arrays=arrays)


def load_truth(path: str | Path) -> dict[str, F64Array]:
    """A simulated flight's truth (evaluation only)."""
    f = Path(path) / "truth.npz"
    if not f.is_file():
        raise FlightLogError(f"{f}: missing (only simulated flights have a truth)")
    with np.load(f, allow_pickle=False) as z:
        return {k: np.asarray(z[k], dtype=np.float64) for k in z.files}
