"""The Earth's magnetic field at a site and date: the World Magnetic Model (pygeomag), the model autopilots'
declination tables come from. The one place the project evaluates it."""

from __future__ import annotations

import datetime as dt
from functools import cache
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array

__all__ = ["decimal_year", "earth_field_ned_ut"]

WMM_EPOCHS = (2010, 2015, 2020, 2025)  # the coefficient files pygeomag ships; each valid for five years
NT_TO_UT = 1e-3
M_TO_KM = 1e-3


@cache
def _model(epoch: int) -> Any:
    from pygeomag import GeoMag

    return GeoMag(coefficients_file=f"wmm/WMM_{epoch}.COF")


def decimal_year(unix_s: float) -> float:
    """UTC Unix time [s] → decimal year (e.g. 2026.9)."""
    t = dt.datetime.fromtimestamp(unix_s, tz=dt.UTC)
    start = dt.datetime(t.year, 1, 1, tzinfo=dt.UTC)
    end = dt.datetime(t.year + 1, 1, 1, tzinfo=dt.UTC)
    return t.year + (t - start) / (end - start)


def earth_field_ned_ut(lat_deg: float, lon_deg: float, alt_m: float, year: float) -> tuple[F64Array, str]:
    """The main field at a site (WGS-84 latitude/longitude [deg], altitude [m]) and decimal year: (NED [µT],
    which model). Outside 2010–2030 the nearest model is extrapolated, and the description says so."""
    epoch = max((e for e in WMM_EPOCHS if e <= year), default=WMM_EPOCHS[0])
    inside = epoch <= year < epoch + 5
    r = _model(epoch).calculate(glat=lat_deg, glon=lon_deg, alt=alt_m * M_TO_KM, time=year,
                                allow_date_outside_lifespan=True)  # fmt: skip
    field = np.array([r.x, r.y, r.z]) * NT_TO_UT
    note = "" if inside else f", extrapolated: {year:.1f} is outside WMM{epoch}'s 5 years"
    return field, f"WMM{epoch} at {lat_deg:.4f}, {lon_deg:.4f}, {alt_m:.0f} m, {year:.2f}{note}"
