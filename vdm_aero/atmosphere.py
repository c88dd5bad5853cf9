"""The International Standard Atmosphere troposphere (ISO 2533:1975 / ICAO Doc 7488): the one copy.

Used by the flight simulator's truth, the scripted SITL world and the estimator side (density from the
barometer and a temperature). Altitudes are geopotential (≈ geometric below a few km: 0.05 % at 3 km).
"""

from __future__ import annotations

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


def pressure_altitude_m(pressure_pa: X) -> X:
    """ISA pressure altitude [m] of a static pressure (the inverse of :func:`isa`'s pressure)."""
    return T0_K / LAPSE_K_M * (1.0 - np.power(np.asarray(pressure_pa) / P0_PA, 1.0 / ISA_EXPONENT))  # type: ignore[return-value]
