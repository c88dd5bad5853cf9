"""A flight log as the filter's time-ordered measurement stream, and a runner that drives several
filters (modes) through it together, with GNSS removed inside outage windows.

The runner is the log-side twin of the service's MAVLink loop: both hand SI events to the same
:class:`~vdm_aero.nav.driver.NavDriver`. It can be copied (``copy.deepcopy``) at any point, so that one
converged run branches into several outages.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.flightlog import SensorLog
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.driver import NavDriver
from vdm_aero.nav.filter import NavFilter
from vdm_aero.nav.imu_increments import increments
from vdm_aero.nav.ports_frontend import PortFrontEnd
from vdm_aero.vehicle import VehicleDescription

__all__ = ["LogRunner", "NavStream", "SolutionRecorder"]

_IMU, _GNSS, _BARO, _MAG, _PITOT, _SERVO, _PORTS, _ATT = range(8)
T_TESLA_TO_UT = 1e6


@dataclass(frozen=True, eq=False)
class NavStream:
    """Every measurement of a log in SI units (magnetometer µT), IMU summed to filter-rate increments."""

    imu_t_s: F64Array
    dtheta_b: F64Array
    dvel_b: F64Array
    imu_dt_s: F64Array
    imu_temperature_c: F64Array
    gnss_t_valid_s: F64Array
    gnss_t_s: F64Array
    gnss_p_ned_m: F64Array
    gnss_v_ned_m_s: F64Array
    gnss_acc_m: F64Array  # (G, 2): the receiver's horizontal and vertical accuracy [m], NaN where not reported
    baro_t_s: F64Array
    baro_pa: F64Array
    mag_t_s: F64Array
    mag_b_ut: F64Array
    pitot_t_s: F64Array
    pitot_dp_pa: F64Array
    pitot_temperature_c: F64Array
    servo_t_s: F64Array
    controls_rad: F64Array
    throttle: F64Array
    ports_t_s: F64Array
    ports_dp_pa: F64Array
    ap_att_t_s: F64Array  # the autopilot's own attitude estimate (fused only where the config asks)
    ap_att_q_nb: F64Array
    events: np.ndarray  # (E, 2) int64: kind, index; in time order
    event_t_s: F64Array  # (E,) the events' times [s]

    @classmethod
    def from_log(
        cls,
        log: SensorLog,
        vehicle: VehicleDescription,
        frame: LocalFrame,
        *,
        filter_rate_hz: float = 50.0,
        gnss_latency_s: float = 0.1,
    ) -> NavStream:
        t = log["imu_t_s"]
        if len(t) < 2:
            raise ValueError(f"{log.path}: fewer than two IMU samples")
        # the service's integrator and gap rule (vdm_aero.nav.imu_increments), sample by sample
        t_end, dth, dv, dt_step, closed = increments(t, log["imu_gyro_b_rad_s"], log["imu_accel_b_m_s2"],
                                                     filter_rate_hz)  # fmt: skip
        temp = log["imu_temperature_c"][closed]
        gt = log["gnss_t_s"]
        p_ned = (
            frame.to_ned(log["gnss_lat_deg"], log["gnss_lon_deg"], log["gnss_alt_m"]) if len(gt) else np.zeros((0, 3))
        )
        ail, ele, rud, thr = vehicle.servos.deflections_rad(log["servo_pwm_us"]) if len(log["servo_t_s"]) else (
            np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))  # fmt: skip
        s = cls(
            imu_t_s=t_end,
            dtheta_b=dth,
            dvel_b=dv,
            imu_dt_s=dt_step,
            imu_temperature_c=temp,
            gnss_t_valid_s=gt,
            gnss_t_s=gt + gnss_latency_s,
            gnss_p_ned_m=np.asarray(p_ned).reshape(-1, 3),
            gnss_v_ned_m_s=log["gnss_v_ned_m_s"],
            gnss_acc_m=np.column_stack(
                [log.arrays.get(k, np.full(len(gt), np.nan)) for k in ("gnss_h_acc_m", "gnss_v_acc_m")]
            ),
            baro_t_s=log["baro_t_s"],
            baro_pa=log["baro_pa"],
            mag_t_s=log["mag_t_s"],
            mag_b_ut=log["mag_field_b_t"] * T_TESLA_TO_UT,
            pitot_t_s=log["pitot_t_s"],
            pitot_dp_pa=log["pitot_dp_pa"],
            pitot_temperature_c=log["pitot_temperature_c"],
            servo_t_s=log["servo_t_s"],
            controls_rad=np.column_stack([ail, ele, rud]) if len(ail) else np.zeros((0, 3)),
            throttle=np.asarray(thr),
            ports_t_s=log["ports_t_s"],
            ports_dp_pa=log["ports_dp_pa"],
            ap_att_t_s=log.arrays.get("ap_att_t_s", np.zeros(0)),
            ap_att_q_nb=log.arrays.get("ap_att_q_nb", np.zeros((0, 4))),
            events=np.zeros((0, 2), dtype=np.int64),
            event_t_s=np.zeros(0),
        )
        times = [s.imu_t_s, s.gnss_t_s, s.baro_t_s, s.mag_t_s, s.pitot_t_s, s.servo_t_s, s.ports_t_s, s.ap_att_t_s]
        kinds = np.concatenate([np.full(len(tt), i) for i, tt in enumerate(times)])
        idx = np.concatenate([np.arange(len(tt)) for tt in times])
        order = np.lexsort((kinds, np.concatenate(times)))
        return dataclasses.replace(
            s,
            events=np.column_stack([kinds[order], idx[order]]).astype(np.int64),
            event_t_s=np.concatenate(times)[order],
        )


class LogRunner:
    """Drives filters through a :class:`NavStream` by way of a :class:`NavDriver` (module docstring)."""

    def __init__(self, stream: NavStream, filters: dict[str, NavFilter], frontend: PortFrontEnd | None) -> None:
        self.stream = stream
        self.driver = NavDriver(filters, frontend)
        self.pos = 0
        self.t_s = -math.inf
        self.gnss_blocked: list[tuple[float, float]] = []
        self.mag_blocked: list[tuple[float, float]] = []
        self.baro_blocked: list[tuple[float, float]] = []

    @property
    def filters(self) -> dict[str, NavFilter]:
        return self.driver.filters

    @property
    def frontend(self) -> PortFrontEnd | None:
        return self.driver.frontend

    def __deepcopy__(self, memo: dict[int, Any]) -> LogRunner:
        """A branch of the run: a copy of the driver (filters, front end), the same (read-only) stream."""
        out = copy.copy(self)
        out.driver = copy.deepcopy(self.driver, memo)
        out.gnss_blocked = list(self.gnss_blocked)
        out.mag_blocked = list(self.mag_blocked)
        out.baro_blocked = list(self.baro_blocked)
        return out

    def block_gnss(self, start_s: float, end_s: float) -> None:
        """Drop every GNSS fix valid in [start_s, end_s) (an outage)."""
        self.gnss_blocked.append((start_s, end_s))

    def block_mag(self, start_s: float, end_s: float) -> None:
        """Drop every magnetometer sample in [start_s, end_s) (with :meth:`block_baro`, the benchmark's
        free-inertial reference: nothing but the IMU through an outage)."""
        self.mag_blocked.append((start_s, end_s))

    def block_baro(self, start_s: float, end_s: float) -> None:
        """Drop every barometer sample in [start_s, end_s) (in turns the barometer sees the tilt through the
        vertical channel: a free INS has none)."""
        self.baro_blocked.append((start_s, end_s))

    def _gnss_ok(self, t_valid: float) -> bool:
        return not any(a <= t_valid < b for a, b in self.gnss_blocked)

    def run_until(self, t_end_s: float, on_step: Callable[[float], None] | None = None) -> None:
        """Process every event before ``t_end_s``; ``on_step(t)`` after each filter step."""
        s = self.stream
        times = s.event_t_s
        ev = s.events
        d = self.driver
        while self.pos < len(ev) and times[self.pos] < t_end_s:
            kind, i = int(ev[self.pos, 0]), int(ev[self.pos, 1])
            t = float(times[self.pos])
            self.pos += 1
            self.t_s = t
            if kind == _IMU:
                d.imu(t, ImuIncrement(s.dtheta_b[i], s.dvel_b[i], float(s.imu_dt_s[i])), float(s.imu_temperature_c[i]))
                if on_step is not None:
                    on_step(t)
            elif kind == _GNSS:
                tv = float(s.gnss_t_valid_s[i])
                if self._gnss_ok(tv):
                    d.gnss(tv, t, s.gnss_p_ned_m[i], s.gnss_v_ned_m_s[i], *(float(a) for a in s.gnss_acc_m[i]))
            elif kind == _BARO:
                if not any(a <= t < b for a, b in self.baro_blocked):
                    d.baro(t, float(s.baro_pa[i]))
            elif kind == _MAG:
                if not any(a <= t < b for a, b in self.mag_blocked):
                    d.mag(t, s.mag_b_ut[i])
            elif kind == _PITOT:
                d.pitot(t, float(s.pitot_dp_pa[i]), float(s.pitot_temperature_c[i]))
            elif kind == _SERVO:
                d.servo(t, s.controls_rad[i], float(s.throttle[i]))
            elif kind == _PORTS:
                d.ports(t, s.ports_dp_pa[i])
            elif kind == _ATT:
                d.ap_attitude(t, s.ap_att_q_nb[i])


class SolutionRecorder:
    """Every initialised filter's solution every ``every`` filter steps, per mode:
    (t [s], p_ned [m], v_ned [m/s], q_nb, air_motion_ned [m/s], P[0:9, 0:9], in_outage, wind_ned [m/s]).
    The benchmark and the replay record with it, so that both read errors at the same epochs."""

    def __init__(self, every: int) -> None:
        self.every = max(every, 1)
        self.steps = 0

    def __call__(self, t_s: float, filters: dict[str, NavFilter], store: dict[str, list[tuple[Any, ...]]]) -> None:
        self.steps += 1
        if self.steps % self.every:
            return
        for m, f in filters.items():
            if f.initialised and f.x is not None:
                x = f.x
                store[m].append((t_s, x.p_ned.copy(), x.v_ned.copy(), x.q_nb.copy(), x.air_motion_ned.copy(),
                                 f.P[0:9, 0:9].copy(), f.in_outage, x.wind_ned.copy()))  # fmt: skip
