"""The filter's contracts (navlie style): a process model and measurement models, each with an analytic
Jacobian that :func:`jacobian_fd` checks by finite differences on the ⊕ manifold.

A :class:`Measurement` carries its value, its time of validity and the model that predicts it; the model
instance holds whatever side information that one sample needs (port coefficients, thrust, ρ), so the
filter never knows what a measurement is, only how to fuse it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.nav.state import N_ERR, NavState

__all__ = ["ImuIncrement", "Measurement", "MeasurementModel", "ProcessModel", "evaluate_with_jacobian", "jacobian_fd"]


@dataclass(frozen=True)
class ImuIncrement:
    """IMU samples summed over one filter step: Δθ = Σω·δt [rad], Δv = Σf·δt [m/s] (body FRD), step Δt [s]."""

    dtheta_b: F64Array
    dvel_b: F64Array
    dt_s: float


class ProcessModel(Protocol):
    """x_{k+1} = f(x_k, u_k, Δt), its error-state transition Φ and discrete process noise Q_d."""

    def propagate(self, x: NavState, u: ImuIncrement) -> NavState: ...

    def transition(self, x: NavState, u: ImuIncrement) -> F64Array: ...

    def noise(self, x: NavState, u: ImuIncrement) -> F64Array: ...


class MeasurementModel(Protocol):
    """z = h(x) + v, v ~ N(0, R)."""

    @property
    def name(self) -> str: ...

    def evaluate(self, x: NavState) -> F64Array: ...

    def jacobian(self, x: NavState) -> F64Array:
        """∂h/∂δx (m, N_ERR) at x."""
        ...

    def covariance(self) -> F64Array: ...


@dataclass(frozen=True)
class Measurement:
    """A value z with its time of validity [s] and the model that predicts it."""

    t_s: float
    z: F64Array
    model: MeasurementModel


def evaluate_with_jacobian(model: MeasurementModel, x: NavState) -> tuple[F64Array, F64Array]:
    """h(x) and ∂h/∂δx at the same x: the model's own ``evaluate_with_jacobian`` where it has one (navlie's
    contract has the same optional method; the air-data models share their kinematics between the two, a third
    of a port frame's fusion), else its two calls."""
    both = getattr(model, "evaluate_with_jacobian", None)
    if both is not None:
        z, h = both(x)
        return z, h
    return model.evaluate(x), model.jacobian(x)


def jacobian_fd(model: MeasurementModel, x: NavState, step: float = 1e-6) -> F64Array:
    """Central finite-difference ∂h/∂δx through ⊕ (the reference for every analytic Jacobian)."""
    z0 = model.evaluate(x)
    out = np.zeros((len(z0), N_ERR))
    for i in range(N_ERR):
        d = np.zeros(N_ERR)
        d[i] = step
        out[:, i] = (model.evaluate(x.plus(d)) - model.evaluate(x.plus(-d))) / (2.0 * step)
    return out
