"""Exact potential flow about Joukowski airfoils (conformal mapping) — the panel method's reference.

The circle |ζ − μ| = R through ζ = a (R = |a − μ|) maps by z = ζ + a²/ζ onto an airfoil with a cusped
trailing edge at z = 2a. With a freestream V∞·e^{iα} and the clockwise circulation fixed by the Kutta
condition at the cusp, Γ = 4π V∞ R sin(α + β) with β = asin(Im μ / R), the complex velocity on the circle
ζ = μ + R e^{iθ} is

    dF/dζ = i e^{−iθ} [2 V∞ sin(θ − α) + Γ/(2πR)]

and in the airfoil plane w = (dF/dζ)/(dz/dζ), dz/dζ = 1 − a²/ζ². Lift per span is ρV∞Γ in both planes,
so c_l = 2Γ/(V∞ c). Everything here is independent of :mod:`sim.airfoil.panel`.

Normalisation: the contour is shifted and scaled (not rotated) so the leading edge (the point of
minimum x) is at x = 0 and the trailing edge at x = 1; c is therefore the x-extent of the mapped
airfoil, and α is measured from the x axis in both planes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize_scalar

from vdm_aero._typing import F64Array

__all__ = ["JoukowskiAirfoil", "joukowski_airfoil"]


@dataclass(frozen=True, eq=False)
class JoukowskiAirfoil:
    """A Joukowski airfoil sampled at circle angles ``theta`` (n+1,), from the TE (θ = −β) once round
    counterclockwise back to the TE, so ``nodes`` (n+1, 2) run TE → upper → LE → lower → TE like
    :func:`sim.airfoil.naca.naca4_nodes`. ``chord`` is the x-extent in the un-normalised z plane and
    ``x_le`` its minimum x; ``nodes`` are normalised to x ∈ [0, 1]."""

    center: complex
    a: float
    radius: float
    beta: float
    chord: float
    x_le: float
    theta: F64Array
    nodes: F64Array

    def _zeta(self, theta: ArrayLike) -> np.ndarray:
        return self.center + self.radius * np.exp(1j * np.asarray(theta, dtype=np.float64))

    def points(self, theta: ArrayLike) -> F64Array:
        """Normalised airfoil coordinates (K, 2) of circle angles ``theta`` (K,)."""
        zeta = self._zeta(np.atleast_1d(theta))
        z = zeta + self.a**2 / zeta
        return np.column_stack(((z.real - self.x_le) / self.chord, z.imag / self.chord))

    def circulation(self, alpha: float) -> float:
        """Clockwise circulation Γ/V∞ (un-normalised z-plane units) satisfying the Kutta condition."""
        return float(4.0 * np.pi * self.radius * np.sin(alpha + self.beta))

    def cl(self, alpha: float) -> float:
        """Exact lift coefficient c_l = 2Γ/(V∞ c) based on the x-extent chord."""
        return 2.0 * self.circulation(alpha) / self.chord

    def velocity(self, alpha: float, theta: ArrayLike | None = None) -> F64Array:
        """Surface speed |w|/V∞ at circle angles ``theta`` (default: the node angles). The cusp
        (θ = −β mod 2π) is a removable 0/0 singularity and returns NaN: skip it."""
        th = self.theta if theta is None else np.atleast_1d(np.asarray(theta, dtype=np.float64))
        zeta = self._zeta(th)
        dfdzeta = 2.0 * np.sin(th - alpha) + self.circulation(alpha) / (2.0 * np.pi * self.radius)
        dzdzeta = 1.0 - self.a**2 / zeta**2
        at_cusp = np.abs(np.angle(np.exp(1j * (th + self.beta)))) < 1e-9
        speed = np.abs(dfdzeta) / np.where(at_cusp, 1.0, np.abs(dzdzeta))
        return np.where(at_cusp, np.nan, speed)

    def cp(self, alpha: float, theta: ArrayLike | None = None) -> F64Array:
        """Exact surface Cp = 1 − (|w|/V∞)² at circle angles ``theta`` (default: nodes); NaN at the cusp."""
        return 1.0 - self.velocity(alpha, theta) ** 2

    def stagnation_theta(self, alpha: float) -> float:
        """Circle angle of the front stagnation point: sin(θ − α) = −sin(α + β), θ ≠ −β."""
        return float(np.mod(np.pi + 2.0 * alpha + self.beta, 2.0 * np.pi))


def joukowski_airfoil(center: complex, a: float = 1.0, *, n: int) -> JoukowskiAirfoil:
    """Joukowski airfoil from circle centre ``center`` (Re < 0 for thickness, Im > 0 for camber) and
    map constant ``a``, sampled at ``n`` panels (n+1 points) uniformly spaced in circle angle (which
    clusters points at the LE and TE in x)."""
    if n < 8:
        raise ValueError(f"n must be >= 8 panels, got {n}")
    if a <= 0.0:
        raise ValueError(f"a must be positive, got {a}")
    mu = complex(center)
    radius = abs(a - mu)
    if not mu.real < 0.0:
        # ζ = −a must lie inside the circle for a one-to-one map with a finite-thickness section
        raise ValueError(f"center {center!r} gives no thick airfoil: need Re(center) < 0")
    beta = float(np.arcsin(mu.imag / radius))
    theta = -beta + np.linspace(0.0, 2.0 * np.pi, n + 1)

    def x_of(th: float) -> float:
        zeta = mu + radius * np.exp(1j * th)
        return float((zeta + a**2 / zeta).real)

    res = minimize_scalar(x_of, bracket=(np.pi - 0.5, np.pi, np.pi + 0.5), tol=1e-12)
    x_le = float(res.fun)
    chord = 2.0 * a - x_le
    zeta = mu + radius * np.exp(1j * theta)
    z = zeta + a**2 / zeta
    nodes = np.column_stack(((z.real - x_le) / chord, z.imag / chord))
    nodes[0] = nodes[-1] = (1.0, 0.0)  # the exact cusp (z = 2a), free of round-off
    return JoukowskiAirfoil(
        center=mu, a=float(a), radius=radius, beta=beta, chord=chord, x_le=x_le, theta=theta, nodes=nodes
    )
