"""The one adapter around filterpy's ``ExtendedKalmanFilter`` (filterpy is imported nowhere else).

The filter is an error-state EKF: filterpy holds the error state δx (zero between updates) and its
covariance P, and does the covariance prediction and the Joseph-form update. This adapter adds what an
aircraft filter needs around it:

* NIS gating before every update (χ² of the innovation against its covariance S);
* Schmidt "consider" updates: the states listed as considered keep their estimate (their Kalman gain rows
  are zeroed) while their uncertainty still enters every other state's covariance. The wind and the model
  parameters are considered during a GNSS outage (docs/navigation.md). filterpy has no consider update,
  so that one is written here, in the same Joseph form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter  # filterpy ≥ 2: the maintained line, numpy 2 support

from vdm_aero._typing import BoolArray, F64Array

__all__ = ["EkfEngine", "UpdateResult"]


@dataclass(frozen=True)
class UpdateResult:
    """The outcome of one update: accepted or rejected by the gate, the NIS and the gate threshold."""

    accepted: bool
    nis: float
    gate: float


class EkfEngine:
    """Covariance bookkeeping of an error-state EKF of dimension ``n`` (filterpy underneath)."""

    def __init__(self, p0: F64Array) -> None:
        n = p0.shape[0]
        self._kf = ExtendedKalmanFilter(dim_x=n, dim_z=1)
        self._kf.x = np.zeros((n, 1))
        self._kf.P = np.array(p0, dtype=np.float64)
        self._n = n

    @property
    def P(self) -> F64Array:
        return np.asarray(self._kf.P)

    @P.setter
    def P(self, value: F64Array) -> None:
        self._kf.P = np.array(value, dtype=np.float64)

    def predict(self, phi: F64Array, qd: F64Array) -> None:
        """P ← ΦPΦᵀ + Q_d (δx stays zero: the nominal state carries the propagation)."""
        kf = self._kf
        kf.F = phi
        kf.Q = qd
        kf.predict()

    def nis(self, innovation: F64Array, h: F64Array, r: F64Array) -> float:
        """The normalised innovation squared yᵀS⁻¹y of a measurement, S = HPHᵀ + R, without fusing it."""
        return self._s_and_nis(innovation, h, r)[1]

    def _s_and_nis(self, innovation: F64Array, h: F64Array, r: F64Array) -> tuple[F64Array, float]:
        s = h @ self._kf.P @ h.T + r
        try:
            return s, float(innovation @ np.linalg.solve(s, innovation))
        except np.linalg.LinAlgError:
            return s, float("inf")

    def update(
        self,
        innovation: F64Array,
        h: F64Array,
        r: F64Array,
        gate: float,
        consider: BoolArray | None = None,
    ) -> tuple[F64Array, UpdateResult]:
        """Fuse one measurement given its innovation y = z − h(x̂), Jacobian H and noise R. Returns the
        correction δx (to inject into the nominal state; zero when rejected) and the gate outcome."""
        kf = self._kf
        p = kf.P
        s, nis = self._s_and_nis(innovation, h, r)
        if not nis <= gate:
            return np.zeros(self._n), UpdateResult(False, nis, gate)
        if consider is None or not consider.any():
            y = innovation.reshape(-1, 1)
            kf.x = np.zeros((self._n, 1))
            kf.update(y, lambda _x: h, lambda _x: np.zeros((len(innovation), 1)), R=r)
            dx = np.asarray(kf.x).ravel().copy()
        else:
            k = np.linalg.solve(s, h @ p).T
            k[consider] = 0.0
            ikh = np.eye(self._n) - k @ h
            kf.P = ikh @ p @ ikh.T + k @ r @ k.T
            dx = k @ innovation
        kf.x = np.zeros((self._n, 1))
        return dx, UpdateResult(True, nis, gate)
