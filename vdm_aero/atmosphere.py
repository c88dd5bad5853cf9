"""The International Standard Atmosphere troposphere (ISO 2533:1975 / ICAO Doc 7488): the one copy.

Used by the flight simulator's truth, the scripted SITL world and the estimator side (density from the
barometer and a temperature). Altitudes are geopotential (≈ geometric below a few km: 0.05 % at 3 km).
"""

from __future__ import annotations

import math
from typing import Final, TypeVar

import numpy as np

from vdm_aero._typing import FloatArray

__all__ = [
    "G0_M_S2",
    "LAPSE_K_M",
    "P0_PA",
    "R_AIR_J_KG_K",
    "T0_K",
    "TROPOPAUSE_M",
    "density_kg_m3",
    "isa",
    "outside_air_temperature_c",
    "pressure_altitude_m",
]

G0_M_S2: Final = 9.80665  # standard gravity
R_AIR_J_KG_K: Final = 287.05287  # specific gas constant of dry air
T0_K: Final = 288.15
P0_PA: Final = 101325.0
LAPSE_K_M: Final = 0.0065  # troposphere temperature lapse rate
ISA_EXPONENT: Final = G0_M_S2 / (R_AIR_J_KG_K * LAPSE_K_M)  # 5.25588
TROPOPAUSE_M: Final = 11000.0

X = TypeVar("X", float, FloatArray)

# The outside-air temperature an aircraft has, as ArduPilot's AP_Baro::get_external_temperature() picks it:
# the airspeed sensor's (its die sits in or near the airflow), else the board's clamped to 35 °C, because a
# board sensor "tends to read high, often 30 degrees above the actual temperature" (its comment).
BOARD_TEMPERATURE_CLAMP_C: Final = 35.0  # ArduPilot INTERNAL_TEMPERATURE_CLAMP
AIRSPEED_TEMPERATURE_RANGE_C: Final = (-40.0, 85.0)  # a reading outside the sensors' operating range is a fault


def isa(alt_m: float, isa_delta_t_k: float = 0.0) -> tuple[float, float, float]:
    """(static pressure [Pa], temperature [K], density [kg/m³]) at geopotential altitude ``alt_m`` on a day
    ``isa_delta_t_k`` warmer than standard (the offset shifts temperature and density, not the
    pressure–height law, as the scenario docs state)."""
    t_std = T0_K - LAPSE_K_M * alt_m
    p = P0_PA * (t_std / T0_K) ** ISA_EXPONENT
    t = t_std + isa_delta_t_k
    return p, t, p / (R_AIR_J_KG_K * t)


def density_kg_m3(pressure_pa: X, temperature_k: X) -> X:
    """Dry-air density from static pressure [Pa] and temperature [K] (ideal gas)."""
    return pressure_pa / (R_AIR_J_KG_K * temperature_k)


def outside_air_temperature_c(airspeed_sensor_c: X, board_c: X) -> X:
    """The best outside-air temperature [°C]: the airspeed sensor's where it reads (finite and within
    :data:`AIRSPEED_TEMPERATURE_RANGE_C`; NaN: no reading), else the board's (IMU or barometer die) clamped
    to :data:`BOARD_TEMPERATURE_CLAMP_C`. Element-wise for arrays."""
    lo, hi = AIRSPEED_TEMPERATURE_RANGE_C
    if isinstance(airspeed_sensor_c, float) and isinstance(board_c, float):  # the filter's every IMU step
        ok = math.isfinite(airspeed_sensor_c) and lo <= airspeed_sensor_c <= hi
        return airspeed_sensor_c if ok else min(board_c, BOARD_TEMPERATURE_CLAMP_C)
    a = np.asarray(airspeed_sensor_c, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(a) & (a >= lo) & (a <= hi)
    out = np.where(ok, a, np.minimum(np.asarray(board_c, dtype=np.float64), BOARD_TEMPERATURE_CLAMP_C))
    return out if out.ndim else float(out)  # type: ignore[return-value]


def pressure_altitude_m(pressure_pa: X) -> X:
    """ISA pressure altitude [m] of a static pressure (the inverse of :func:`isa`'s pressure)."""
    return T0_K / LAPSE_K_M * (1.0 - np.power(np.asarray(pressure_pa) / P0_PA, 1.0 / ISA_EXPONENT))  # type: ignore[return-value]
