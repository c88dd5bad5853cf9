"""Propeller thrust and torque as functions of throttle and airspeed.

Model: a fixed-pitch propeller whose rotational speed follows the throttle linearly,
n = n_max·δ_t [rev/s] (an electronic speed controller in open loop on a lightly loaded motor; the
motor's spin-up lag is the throttle actuator's first-order lag), with thrust and power coefficients
linear in the advance ratio J = u/(n·D) (u the axial airspeed, body x):

    C_T(J) = C_T0·(1 − J/J_T),   C_P(J) = C_P0·(1 − J/J_P),
    T = ρ n² D⁴ C_T(J) = ρ D⁴ C_T0 n² − ρ D³ (C_T0/J_T) n u,
    Q = ρ n² D⁵ C_P(J)/(2π).

Written in n and u the forms are smooth through n = 0: a stopped (folded) propeller gives exactly zero
thrust and torque, which the glide test relies on; beyond J_T the propeller brakes (negative thrust), as
a real one windmilling at low throttle does. The linear C_T(J) is the classic shape of fixed-pitch
propeller data between static and zero thrust (e.g. the UIUC Propeller Data Site, Brandt & Selig 2011,
AIAA 2011-1255); the coefficients of the shipped preset are representative values for an 11×7 thin
electric propeller read off the shape of such curves, not a fit to a particular data file.

Not modelled: slipstream over the tail, the propeller's normal force at incidence, gyroscopic moments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

__all__ = ["PROPELLERS", "PropellerSpec", "PropulsionSpec"]


@dataclass(frozen=True)
class PropellerSpec:
    """A fixed-pitch propeller: diameter [m], static thrust and power coefficients and the advance
    ratios where thrust (``j_zero_thrust``) and power (``j_zero_power``) vanish; ``source`` says where
    the numbers come from."""

    name: str
    diameter_m: float
    ct0: float
    j_zero_thrust: float
    cp0: float
    j_zero_power: float
    source: str

    def __post_init__(self) -> None:
        for k in ("diameter_m", "ct0", "j_zero_thrust", "cp0", "j_zero_power"):
            if not getattr(self, k) > 0.0:
                raise ValueError(f"propeller {self.name}: {k} must be > 0, got {getattr(self, k)}")


PROPELLERS: Final = {
    "apc-11x7e": PropellerSpec(
        name="apc-11x7e",
        diameter_m=11 * 0.0254,
        ct0=0.11,
        j_zero_thrust=0.78,
        cp0=0.050,
        j_zero_power=0.95,
        source="representative 11x7 thin-electric propeller: linear C_T(J), C_P(J) with the static values and "
        "zero crossings read off UIUC Propeller Data Site curves (Brandt & Selig 2011); not a fit",
    ),
}
"""Named propellers."""


@dataclass(frozen=True)
class PropulsionSpec:
    """The installed propulsion: the propeller, its speed at full throttle ``max_rev_s`` [rev/s] (motor
    Kv × battery voltage under load / 60), the thrust point (propeller hub) in body axes [m] (thrust
    acts along body +x) and the spin direction (+1: clockwise seen from behind, so the airframe feels
    the reaction torque −Q about body x)."""

    propeller: PropellerSpec
    max_rev_s: float
    thrust_point_b: tuple[float, float, float]
    spin: int

    def __post_init__(self) -> None:
        if not self.max_rev_s > 0.0:
            raise ValueError(f"max_rev_s must be > 0, got {self.max_rev_s}")
        if self.spin not in (-1, 1):
            raise ValueError(f"spin must be +1 or -1, got {self.spin}")

    def constants(self) -> tuple[float, float, float, float]:
        """(k_t0, k_t1, k_q0, k_q1) with T = ρ(k_t0 n² − k_t1 n u), Q = ρ(k_q0 n² − k_q1 n u) [SI]."""
        p = self.propeller
        d = p.diameter_m
        return (
            d**4 * p.ct0,
            d**3 * p.ct0 / p.j_zero_thrust,
            d**5 * p.cp0 / (2.0 * math.pi),
            d**4 * p.cp0 / (2.0 * math.pi * p.j_zero_power),
        )

    def thrust_torque(self, throttle: float, u_axial_m_s: float, rho_kg_m3: float) -> tuple[float, float]:
        """Thrust [N] along body +x and shaft torque [N·m] (the airframe feels ``−spin·Q`` about x) at
        ``throttle`` (0…1), axial airspeed [m/s] and air density [kg/m³]."""
        kt0, kt1, kq0, kq1 = self.constants()
        n = self.max_rev_s * throttle
        return rho_kg_m3 * (kt0 * n * n - kt1 * n * u_axial_m_s), rho_kg_m3 * (kq0 * n * n - kq1 * n * u_axial_m_s)
