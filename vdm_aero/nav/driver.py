"""One measurement stream in SI units → the filters: the code path the log replay, the drift benchmark and
the companion service share.

:class:`NavDriver` takes time-ordered sensor events (IMU increments, GNSS fixes, barometer, magnetometer,
pitot, servo outputs and port frames) and hands them to every filter, keeping what several measurements
need (the latest body rates and specific force, servo deflections, the magnetometer sample for the
initial heading, the air density from the best temperature the aircraft has). The port front end runs
once per frame for all filters.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import density_kg_m3, outside_air_temperature_c
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.filter import NavFilter
from vdm_aero.nav.ports_frontend import PortFrame, PortFrontEnd

__all__ = ["PORT_SOLVE_HZ", "NavDriver"]

PORT_SOLVE_HZ = 10.0  # FADS and the aero models run at the aiding rate; port health sees every frame
CELSIUS_TO_KELVIN = 273.15
AIRSPEED_TEMPERATURE_STALE_S = 10.0  # as ArduPilot's external temperature: older than this, the fallback


class NavDriver:
    """Feeds sensor events to ``filters`` (mode → :class:`NavFilter`); ``frontend`` solves port frames."""

    def __init__(self, filters: dict[str, NavFilter], frontend: PortFrontEnd | None) -> None:
        self.filters = filters
        self.frontend = frontend
        self.last_frame: PortFrame | None = None
        self.t_s = -math.inf
        self._omega_b = np.zeros(3)
        self._f_b = np.array([0.0, 0.0, -9.80665])
        self._controls_rad = np.zeros(3)
        self._rho_kg_m3 = 1.225
        self._temp_k = 288.15
        self._board_c = 15.0
        self._airspeed_temp = (-math.inf, math.nan)  # (t [s], airspeed sensor temperature [°C])
        self._mag_b_ut: F64Array | None = None
        self._next_port_solve = -math.inf

    def __deepcopy__(self, memo: dict[int, Any]) -> NavDriver:
        """A branch of a run: copies of the filters and the front end (their models stay shared)."""
        out = copy.copy(self)
        out.filters = copy.deepcopy(self.filters, memo)
        out.frontend = copy.deepcopy(self.frontend, memo)
        return out

    def imu(self, t_s: float, inc: ImuIncrement, temperature_c: float) -> None:
        """An IMU increment ending at ``t_s`` [s] (IMU die temperature [°C]: the air density's fallback when
        no airspeed sensor reports its temperature, :func:`outside_air_temperature_c`)."""
        self.t_s = t_s
        self._omega_b, self._f_b = inc.dtheta_b / inc.dt_s, inc.dvel_b / inc.dt_s
        self._board_c = temperature_c
        t_air, air_c = self._airspeed_temp
        air_c = float(outside_air_temperature_c(air_c if t_s - t_air < AIRSPEED_TEMPERATURE_STALE_S else math.nan,
                                                temperature_c))  # fmt: skip
        self._temp_k = air_c + CELSIUS_TO_KELVIN
        for f in self.filters.values():
            f.imu(t_s, inc, air_c)

    def gnss(self, t_valid_s: float, t_s: float, p_ned_m: F64Array, v_ned_m_s: F64Array, h_acc_m: float = math.nan,
             v_acc_m: float = math.nan) -> None:  # fmt: skip
        """A GNSS fix valid at ``t_valid_s`` that arrived at ``t_s`` (local NED [m], [m/s]) with the receiver's
        accuracy [m] (NaN: not reported); the first one initialises each filter (attitude from the specific
        force and the magnetometer)."""
        self.t_s = t_s
        for f in self.filters.values():
            if not f.initialised:
                f.initialise(t_s, p_ned_m, v_ned_m_s, self._f_b, self._mag_b_ut)
            else:
                f.gnss(t_valid_s, t_s, p_ned_m, v_ned_m_s, h_acc_m, v_acc_m)

    def baro(self, t_s: float, pressure_pa: float) -> None:
        """Static pressure [Pa]."""
        self.t_s = t_s
        self._rho_kg_m3 = float(density_kg_m3(pressure_pa, self._temp_k))
        for f in self.filters.values():
            f.baro(t_s, pressure_pa)

    def mag(self, t_s: float, field_b_ut: F64Array) -> None:
        """Magnetic field, body FRD [µT]."""
        self.t_s = t_s
        self._mag_b_ut = np.asarray(field_b_ut, dtype=np.float64)
        for f in self.filters.values():
            f.mag(t_s, self._mag_b_ut)

    def ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        """The autopilot's own attitude estimate (body FRD → NED quaternion)."""
        self.t_s = t_s
        for f in self.filters.values():
            f.ap_attitude(t_s, q_nb)

    def pitot(self, t_s: float, dp_pa: float, temperature_c: float = math.nan) -> None:
        """Pitot differential pressure [Pa], and the airspeed sensor's temperature [°C] (NaN: not reported),
        the air density's temperature while it reports."""
        self.t_s = t_s
        if math.isfinite(temperature_c):
            self._airspeed_temp = (t_s, temperature_c)
        for f in self.filters.values():
            f.pitot(t_s, dp_pa)

    def servo(self, t_s: float, controls_rad: F64Array, throttle: float) -> None:
        """Control-surface deflections (aileron, elevator, rudder) [rad] and throttle (0..1)."""
        self.t_s = t_s
        self._controls_rad = np.asarray(controls_rad, dtype=np.float64)
        for f in self.filters.values():
            f.servo(t_s, self._controls_rad, throttle)

    def ports(self, t_s: float, dp_pa: F64Array) -> PortFrame | None:
        """One port frame (Δp [Pa] in the models' port order, NaN for missing ports): :meth:`solve_ports`,
        then :meth:`fuse_ports`. Returns the solved frame (None for frames only checked, or without a front
        end)."""
        frame = self.solve_ports(t_s, dp_pa)
        if frame is not None:
            self.fuse_ports(frame)
        return frame

    def solve_ports(self, t_s: float, dp_pa: F64Array) -> PortFrame | None:
        """Port health on every frame; the air data and force models at :data:`PORT_SOLVE_HZ` (the solved
        frame is returned, None otherwise). The aerodynamic outputs need only this, not the filter."""
        self.t_s = t_s
        fe = self.frontend
        if fe is None:
            return None
        ok = fe.health(dp_pa, t_s)
        if t_s < self._next_port_solve:
            return None
        self._next_port_solve = t_s + 1.0 / PORT_SOLVE_HZ - 1e-6
        frame = fe.process(t_s, dp_pa, self._rho_kg_m3, self._omega_b, self._controls_rad, ok)
        self.last_frame = frame
        return frame

    def fuse_ports(self, frame: PortFrame) -> None:
        """Fuse a solved frame into every filter."""
        for f in self.filters.values():
            f.ports(frame)
