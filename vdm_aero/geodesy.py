"""WGS-84 geodetic ↔ local NED at a home point: the one implementation (simulator truth, sensors, the mock
autopilot's GNSS and the estimator side).

The local NED frame is the tangent plane at home (pymap3d's ``ned`` convention): a point's NED coordinates
are its ECEF offset from home rotated into north/east/down at home. Geodetic → NED uses pymap3d
(``geodetic2ned``). NED → geodetic runs every 400 Hz physics step in the flight simulator, where
pymap3d's scalar ``ned2geodetic`` costs ~150 µs per call (measured on this machine) against a step budget
of ~80 µs; :meth:`LocalFrame.to_geodetic` therefore does the same conversion in plain floats (a fixed
rotation to ECEF, then Bowring's closed-form ECEF → geodetic, ~3 µs). ``tests/test_shared_math.py`` holds
it to pymap3d within 1 mm and 1e-9° over ±20 km.

The flat-earth approximation used before (WGS-84 radii at home) was 0.7 m off in height at 3 km and 16 m
at 14 km (the Earth's curvature, d²/2R), measured against pymap3d.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import pymap3d

from vdm_aero._typing import F64Array, FloatArray

__all__ = ["EARTH_RATE_RAD_S", "WGS84_A_M", "WGS84_E2", "LocalFrame", "earth_rate_ned", "normal_gravity_m_s2"]

WGS84_A_M: Final = 6378137.0  # semi-major axis
WGS84_F: Final = 1.0 / 298.257223563
WGS84_E2: Final = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared
_B_M: Final = WGS84_A_M * (1.0 - WGS84_F)
_EP2: Final = (WGS84_A_M**2 - _B_M**2) / _B_M**2  # second eccentricity squared

# WGS-84 (NIMA TR8350.2, 3rd ed., tables 3.1 and 3.4): Earth's rotation rate, normal gravity at the equator
# and the pole, and the Somigliana constant k = (b·γ_p)/(a·γ_e) − 1
EARTH_RATE_RAD_S: Final = 7.292115e-5
WGS84_GAMMA_E_M_S2: Final = 9.7803253359
WGS84_GAMMA_P_M_S2: Final = 9.8321849378
WGS84_SOMIGLIANA_K: Final = 0.00193185265241
WGS84_GM_M3_S2: Final = 3.986004418e14


def normal_gravity_m_s2(lat_deg: float, height_m: float) -> float:
    """WGS-84 normal gravity [m/s²] at geodetic latitude and ellipsoidal height: Somigliana's closed formula
    on the ellipsoid (TR8350.2 eq. 4-1) and the second-order free-air reduction above it (eq. 4-3)."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    g0 = WGS84_GAMMA_E_M_S2 * (1.0 + WGS84_SOMIGLIANA_K * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
    m = EARTH_RATE_RAD_S**2 * WGS84_A_M**2 * _B_M / WGS84_GM_M3_S2
    h = height_m
    return g0 * (1.0 - 2.0 / WGS84_A_M * (1.0 + WGS84_F + m - 2.0 * WGS84_F * s2) * h + 3.0 / WGS84_A_M**2 * h * h)


def earth_rate_ned(lat_deg: float) -> F64Array:
    """The Earth's rotation ω_ie resolved in local NED at latitude [rad/s] (Groves 2013, eq. 2.123)."""
    lat = math.radians(lat_deg)
    return np.array([EARTH_RATE_RAD_S * math.cos(lat), 0.0, -EARTH_RATE_RAD_S * math.sin(lat)])


@dataclass(frozen=True)
class LocalFrame:
    """The NED tangent frame at home: geodetic latitude/longitude [deg], altitude above the ellipsoid [m]
    (the project's ``alt_m``; the difference to MSL is a constant offset at one place)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    _c: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        phi, lam = math.radians(self.lat_deg), math.radians(self.lon_deg)
        sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
        n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * sp * sp)
        x0 = (n + self.alt_m) * cp * cl
        y0 = (n + self.alt_m) * cp * sl
        z0 = (n * (1.0 - WGS84_E2) + self.alt_m) * sp
        # columns of R (NED → ECEF): north, east, down at home
        object.__setattr__(self, "_c", (x0, y0, z0, -sp * cl, -sp * sl, cp, -sl, cl, 0.0, -cp * cl, -cp * sl, -sp))

    @property
    def radii_m(self) -> tuple[float, float]:
        """(meridian radius M, prime-vertical radius N) of WGS-84 at the home latitude [m]."""
        s = math.sin(math.radians(self.lat_deg))
        w = math.sqrt(1.0 - WGS84_E2 * s * s)
        return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w

    def to_geodetic(self, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
        """(latitude [deg], longitude [deg], altitude [m]) of a NED position [m] (plain floats, see the
        module docstring)."""
        x0, y0, z0, nx, ny, nz, ex, ey, _, dx, dy, dz = self._c
        x = x0 + nx * north_m + ex * east_m + dx * down_m
        y = y0 + ny * north_m + ey * east_m + dy * down_m
        z = z0 + nz * north_m + dz * down_m
        p = math.hypot(x, y)
        # Bowring (1976): one evaluation is sub-millimetre near the Earth's surface
        th = math.atan2(z * WGS84_A_M, p * _B_M)
        st, ct = math.sin(th), math.cos(th)
        lat = math.atan2(z + _EP2 * _B_M * st * st * st, p - WGS84_E2 * WGS84_A_M * ct * ct * ct)
        sl = math.sin(lat)
        n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * sl * sl)
        cl = math.cos(lat)
        alt = p / cl - n if abs(cl) > 1e-3 else z / sl - n * (1.0 - WGS84_E2)
        return math.degrees(lat), math.degrees(math.atan2(y, x)), alt

    def to_geodetic_array(self, ned_m: FloatArray) -> tuple[F64Array, F64Array, F64Array]:
        """Vectorised :meth:`to_geodetic` of (K, 3) NED positions (pymap3d)."""
        a = np.asarray(ned_m, dtype=np.float64).reshape(-1, 3)
        lat, lon, alt = pymap3d.ned2geodetic(a[:, 0], a[:, 1], a[:, 2], self.lat_deg, self.lon_deg, self.alt_m)
        return np.asarray(lat), np.asarray(lon), np.asarray(alt)

    def to_ned(self, lat_deg: FloatArray | float, lon_deg: FloatArray | float, alt_m: FloatArray | float) -> F64Array:
        """NED position(s) [m] of geodetic point(s): (3,) or (K, 3)."""
        n, e, d = pymap3d.geodetic2ned(lat_deg, lon_deg, alt_m, self.lat_deg, self.lon_deg, self.alt_m)
        out = np.stack(
            [np.asarray(n, dtype=np.float64), np.asarray(e, dtype=np.float64), np.asarray(d, dtype=np.float64)], axis=-1
        )
        return np.asarray(out)

    def offset(
        self, lat_deg: float, lon_deg: float, alt_m: float, d_ned_m: FloatArray | tuple[float, float, float]
    ) -> tuple[float, float, float]:
        """The geodetic point ``d_ned_m`` [m] away from a point near home (the tangent frame's axes)."""
        base = self.to_ned(lat_deg, lon_deg, alt_m)
        d = np.asarray(d_ned_m, dtype=np.float64)
        return self.to_geodetic(float(base[0] + d[0]), float(base[1] + d[1]), float(base[2] + d[2]))
