"""The flight environment: ISA atmosphere, steady wind, Dryden turbulence, the local Earth frame.

* **Atmosphere**: the International Standard Atmosphere troposphere (ISO 2533:1975 / ICAO Doc 7488),
  T = T0 + ΔT − L·h, p = p0·((T0 − L·h)/T0)^(g0/(R·L)), ρ = p/(R·T), with an optional temperature offset
  ΔT (an "ISA + ΔT" day keeps the standard pressure–height relation and changes the density).
* **Steady wind**: speed and the direction it blows FROM (meteorological convention), horizontal.
* **Turbulence**: the Dryden form of MIL-F-8785C §3.7 (also MIL-HDBK-1797 Appendix A), low-altitude
  model (h < 1000 ft): σ_w = 0.1·W20, σ_u/σ_w = σ_v/σ_w = 1/(0.177 + 0.000823·h)^0.4, L_w = h,
  L_u = L_v = h/(0.177 + 0.000823·h)^1.2 (h in feet; h clamped to [10, 1000] ft, the model's range).
  W20 (wind speed at 20 ft) is 15 kt for light and 30 kt for moderate turbulence (MIL-F-8785C Fig. 10).
  Spectra in spatial frequency Ω [rad/m]: Φ_u = σ_u²·(2L_u/π)/(1 + (L_u·Ω)²),
  Φ_v = σ_v²·(L_v/π)·(1 + 3(L_v·Ω)²)/(1 + (L_v·Ω)²)² (Φ_w likewise with L_w, σ_w). The turbulence
  axes at low altitude are aligned with the mean wind (u along it, v to its right, w down; north when
  there is no steady wind); the spatial field is swept past the aircraft at its airspeed (Taylor's
  frozen-turbulence hypothesis). Rotational gust components (p_g, q_g, r_g) are not modelled: for a
  2 m span they are small next to the linear gusts' effect on α and β.
* **Local Earth frame**: NED positions map to latitude/longitude with the WGS-84 meridian and prime
  vertical radii of curvature at the home latitude (flat Earth: errors < 1 m within ~10 km of home).

The Dryden filters are discretised exactly for any step Δ (see :class:`DrydenTurbulence`), so the
variance and correlation of the gusts are right at every integration rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import G0_M_S2, TROPOPAUSE_M, isa

__all__ = [
    "G0_M_S2",
    "TURBULENCE_LEVELS",
    "Atmosphere",
    "DrydenTurbulence",
    "SteadyWind",
    "WindProfile",
    "dryden_length_scales_m",
    "dryden_sigmas_m_s",
]

# ISA (ISO 2533:1975) lives in vdm_aero.atmosphere; g0 is also the (constant) gravity of the dynamics


FT_M: Final = 0.3048
KT_M_S: Final = 0.514444
TURBULENCE_LEVELS: Final = {"none": 0.0, "light": 15.0 * KT_M_S, "moderate": 30.0 * KT_M_S}
"""Turbulence level → W20, the wind speed at 20 ft [m/s] (MIL-F-8785C Fig. 10: 15 kt light, 30 kt moderate)."""
_DRYDEN_H_MIN_FT: Final = 10.0
_DRYDEN_H_MAX_FT: Final = 1000.0


@dataclass(frozen=True)
class Atmosphere:
    """ISA troposphere with a temperature offset ``isa_delta_t_k`` [K] (0 = standard day)."""

    isa_delta_t_k: float

    def at(self, alt_msl_m: float) -> tuple[float, float, float]:
        """(static pressure [Pa], temperature [K], density [kg/m³]) at geopotential altitude ``alt_msl_m``."""
        if not -500.0 <= alt_msl_m <= TROPOPAUSE_M:
            raise ValueError(f"altitude {alt_msl_m:.1f} m is outside the ISA troposphere model [-500, 11000] m")
        return isa(alt_msl_m, self.isa_delta_t_k)


@dataclass(frozen=True)
class SteadyWind:
    """A horizontal steady wind of ``speed_m_s`` blowing FROM ``from_deg`` (0 = from north, 90 = from east)."""

    speed_m_s: float
    from_deg: float

    @property
    def ned_m_s(self) -> F64Array:
        """The wind velocity (air motion over ground) in NED [m/s]."""
        a = math.radians(self.from_deg)
        return np.array([-self.speed_m_s * math.cos(a), -self.speed_m_s * math.sin(a), 0.0])

    @property
    def to_heading_rad(self) -> float:
        """Direction the air moves towards [rad from north]; north when there is no wind."""
        if self.speed_m_s <= 0.0:
            return 0.0
        return math.radians(self.from_deg) + math.pi


@dataclass(frozen=True)
class WindShear:
    """A change of the steady wind: from ``start_s`` it ramps linearly over ``ramp_s`` to ``speed_m_s``
    FROM ``from_deg`` (a front or a shear layer crossed; ArduPilot PR #23999's case for dead reckoning)."""

    start_s: float
    ramp_s: float
    to: SteadyWind

    def wind_ned(self, before: SteadyWind, t_s: float) -> F64Array:
        """The steady wind NED [m/s] at ``t_s``."""
        if t_s <= self.start_s:
            return before.ned_m_s
        k = min((t_s - self.start_s) / max(self.ramp_s, 1e-9), 1.0)
        return np.asarray((1.0 - k) * before.ned_m_s + k * self.to.ned_m_s)


@dataclass(frozen=True)
class WindProfile:
    """The steady wind's change with height in the atmospheric boundary layer: the speed follows the power law
    V(h) = V_ref·(h/h_ref)^exponent and the direction veers (turns clockwise seen from above, in the northern
    hemisphere) by ``veer_deg_per_100m`` with height. The scenario's steady wind is the wind at h_ref.

    Sources: the power law with the Hellmann exponent, 0.10 (open water) … 0.15 (level grass) … 0.25
    (trees, buildings, hills) and up to 0.4 in a stable night-time layer (Stull 1988, *An Introduction to
    Boundary Layer Meteorology*, §9.7; the 1/7 neutral value over open land); the surface wind crosses the
    isobars at about 30° over land (Ekman veer, 45° in pure Ekman theory; Stull §8.5), turned through the
    lowest ~1 km: 2–5° per 100 m."""

    reference_height_m: float
    exponent: float
    veer_deg_per_100m: float

    def wind_ned(self, reference: SteadyWind, height_m: float) -> F64Array:
        """The steady wind NED [m/s] at ``height_m`` above ground (held at its 2 m value below 2 m)."""
        h = max(height_m, 2.0)
        speed = reference.speed_m_s * (h / self.reference_height_m) ** self.exponent
        turned = reference.from_deg + self.veer_deg_per_100m * (h - self.reference_height_m) / 100.0
        return SteadyWind(speed, turned).ned_m_s


def _dryden_height_ft(height_m: float) -> float:
    return min(max(height_m / FT_M, _DRYDEN_H_MIN_FT), _DRYDEN_H_MAX_FT)


def dryden_sigmas_m_s(level: str, height_m: float) -> tuple[float, float, float]:
    """MIL-F-8785C low-altitude turbulence intensities (σ_u, σ_v, σ_w) [m/s] at ``height_m`` above ground."""
    w20 = TURBULENCE_LEVELS[level]
    h = _dryden_height_ft(height_m)
    s_w = 0.1 * w20
    s_uv = s_w / (0.177 + 0.000823 * h) ** 0.4
    return s_uv, s_uv, s_w


def dryden_length_scales_m(height_m: float) -> tuple[float, float, float]:
    """MIL-F-8785C low-altitude Dryden scale lengths (L_u, L_v, L_w) [m] at ``height_m`` above ground."""
    h = _dryden_height_ft(height_m)
    l_uv = h / (0.177 + 0.000823 * h) ** 1.2
    return l_uv * FT_M, l_uv * FT_M, h * FT_M


class DrydenTurbulence:
    """Dryden gusts (u_g, v_g, w_g) [m/s] in turbulence axes with a seeded generator.

    Exact discretisation over a step Δ with r = V·Δ/L (a component's spatial step in scale lengths):

    * u: an Ornstein–Uhlenbeck process x ← e^{−r}·x + √(1 − e^{−2r})·n, gust = σ_u·x (correlation e^{−ξ/L}).
    * v, w: the shaping filter (1 + √3·T·s)/(1 + T·s)², T = L/V, realised in the state coordinates whose
      stationary covariance is the identity: Φ = e^{−r}·[[1 + r, r], [−r, 1 − r]], process noise
      covariance I − ΦΦᵀ (exact for a stationary linear system), gust = σ·(x₁ + √3·x₂)/2. Its spectrum
      is the Dryden Φ_v shape and its variance σ² at every Δ, V and L.

    σ and L follow the height and the airspeed as they change (the normalised states keep unit variance,
    so a change of scale never produces a variance transient). Normal deviates are drawn in blocks.
    """

    _BLOCK: Final = 4096

    def __init__(self, level: str, rng: np.random.Generator) -> None:
        if level not in TURBULENCE_LEVELS:
            raise ValueError(f"unknown turbulence level {level!r} (known: {', '.join(TURBULENCE_LEVELS)})")
        self.level = level
        self.rng = rng
        # normalised states u, v1, v2, w1, w2: start from the stationary distribution, not from calm air
        self._x = [float(v) for v in rng.standard_normal(5)]
        self._noise: list[float] = []
        self._i = 0

    def _draw(self) -> list[float]:
        if self._i + 5 > len(self._noise):
            self._noise = self.rng.standard_normal(5 * self._BLOCK).tolist()
            self._i = 0
        i = self._i
        self._i = i + 5
        return self._noise[i : i + 5]

    @staticmethod
    def _second_order(x1: float, x2: float, r: float, n1: float, n2: float) -> tuple[float, float]:
        e = math.exp(-r)
        p11, p12, p21, p22 = e * (1.0 + r), e * r, -e * r, e * (1.0 - r)
        # Q = I − ΦΦᵀ, Cholesky factor [[a, 0], [b, c]]
        q11 = 1.0 - (p11 * p11 + p12 * p12)
        q12 = -(p11 * p21 + p12 * p22)
        q22 = 1.0 - (p21 * p21 + p22 * p22)
        a = math.sqrt(max(q11, 0.0))
        b = q12 / a if a > 1e-300 else 0.0
        c = math.sqrt(max(q22 - b * b, 0.0))
        return p11 * x1 + p12 * x2 + a * n1, p21 * x1 + p22 * x2 + b * n1 + c * n2

    def step(self, dt_s: float, airspeed_m_s: float, height_m: float) -> tuple[float, float, float]:
        """Advance by ``dt_s`` at the given airspeed [m/s] and height above ground [m]; the new gusts
        (u_g, v_g, w_g) [m/s] in turbulence axes."""
        if self.level == "none":
            return 0.0, 0.0, 0.0
        s_u, s_v, s_w = dryden_sigmas_m_s(self.level, height_m)
        l_u, l_v, l_w = dryden_length_scales_m(height_m)
        dist = max(airspeed_m_s, 0.0) * dt_s
        n = self._draw()
        x = self._x
        e = math.exp(-dist / l_u)
        x[0] = e * x[0] + math.sqrt(1.0 - e * e) * n[0]
        x[1], x[2] = self._second_order(x[1], x[2], dist / l_v, n[1], n[2])
        x[3], x[4] = self._second_order(x[3], x[4], dist / l_w, n[3], n[4])
        half_root3 = 0.5 * math.sqrt(3.0)
        return s_u * x[0], s_v * (0.5 * x[1] + half_root3 * x[2]), s_w * (0.5 * x[3] + half_root3 * x[4])
