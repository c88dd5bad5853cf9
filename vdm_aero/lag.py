"""The first-order lag τ·ẏ + y = x, discretised exactly for an input linear between samples (first-order
hold): the one implementation (tubing lag of pressure ports, port lag of the airfoil data sets, servo and
row lags of the simulators).

    y_k = e·y_{k−1} + (1 − e − g)·x_{k−1} + g·x_k,   e = exp(−Δ/τ),   g = 1 − (τ/Δ)(1 − e),

which is exact for a piecewise-linear x (a ramp is followed with the steady lag τ·ẋ) and gives y = x for τ = 0.
"""

from __future__ import annotations

import numpy as np

from vdm_aero._typing import F64Array, FloatArray

__all__ = ["FirstOrderLag", "first_order_lag", "lag_coefficients"]


def lag_coefficients(dt_s: FloatArray | float, tau_s: FloatArray | float) -> tuple[F64Array, F64Array, F64Array]:
    """(e, 1 − e − g, g) of the recursion for steps ``dt_s`` and time constants ``tau_s`` [s] (broadcast;
    τ = 0 gives (0, 0, 1))."""
    dt = np.asarray(dt_s, dtype=np.float64)
    tau = np.asarray(tau_s, dtype=np.float64)
    safe = np.where(tau > 0.0, tau, 1.0)
    e = np.where(tau > 0.0, np.exp(-dt / safe), 0.0)
    g = np.where(tau > 0.0, 1.0 - safe / dt * (1.0 - e), 1.0)
    return e, 1.0 - e - g, g


def first_order_lag(t_s: FloatArray, x: FloatArray, tau_s: float) -> F64Array:
    """The lagged series of samples ``x`` (K, ...) at times ``t_s`` (K,), starting settled (y_0 = x_0)."""
    t = np.asarray(t_s, dtype=np.float64)
    xs = np.asarray(x, dtype=np.float64)
    y = np.empty_like(xs)
    y[0] = xs[0]
    if tau_s <= 0.0:
        y[:] = xs
        return y
    e, a, b = lag_coefficients(np.diff(t), tau_s)
    for k in range(1, len(t)):
        y[k] = e[k - 1] * y[k - 1] + a[k - 1] * xs[k - 1] + b[k - 1] * xs[k]
    return y


class FirstOrderLag:
    """A lag over a fixed step with one time constant per channel [s]; starts settled on the first input."""

    def __init__(self, dt_s: float, tau_s: FloatArray | float) -> None:
        self.coef = lag_coefficients(dt_s, tau_s)
        self._x: F64Array | None = None
        self._y: F64Array | None = None

    def step(self, x: FloatArray) -> F64Array:
        xs = np.asarray(x, dtype=np.float64)
        if self._x is None or self._y is None:
            y = xs.copy()
        else:
            e, a, b = self.coef
            y = e * self._y + a * self._x + b * xs
        self._x, self._y = xs.copy(), y
        return y
