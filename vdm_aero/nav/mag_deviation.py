"""The magnetometer's deviation, learnt in flight while GNSS holds the heading: a compass swing.

Why: on the as-built aircraft the magnetometer's largest errors are not its hard-iron offset (a filter state)
but what the user's ground calibration leaves or never measured:

* soft iron, a matrix on the body field whose heading error goes round with the heading (the classical
  deviation coefficients B, C, D, E of a compass swing: Bowditch, *The American Practical Navigator*,
  ch. 6; ArduPilot's CompassCalibrator accepts fits leaving ~3 % of the field, COMPASS_CAL_FIT);
* the motors' field, proportional to the current: ArduPilot's own model is COMPASS_MOT_x × throttle
  (COMPASS_MOTCT = 1), measured on the ground with the propeller on, which a fixed-wing user rarely does.

Both are linear in what the filter already has, so while GNSS aids the filter (its heading then comes from
the GNSS velocity through the turns, not from the magnetometer alone) the residual of the raw field
against the field the attitude predicts is regressed on

    r_b = m_b − Ĉ_bn·m_ned = S·(Ĉ_bn·m_ned) + k·throttle + c      [µT, per body axis]

(S 3×3, k and c 3-vectors: five regressors shared by the three axes), a Bayesian linear regression whose
prior is the calibration's own tolerance (S within ±3 %, k within the 30 % of the Earth field that
ArduPilot calls acceptable at full throttle). The corrected field m_b − S·ĥ_b − k·throttle is what the
filter fuses; the constant c stays with the filter's hard-iron state, which keeps tracking slow changes.
Learning stops in an outage (the heading then rests on the magnetometer: learning would chase its own
drift); the correction stays.

The motor's term is learnt on the throttles the aided flight used, and nowhere else: a glide home with the
throttle closed, below every throttle of the climb and the cruise, takes k·throttle where the fit has no data,
so :meth:`MagDeviation.throttle_range` gives the throttles it learnt on (their 1st and 99th percentiles, from a
histogram) for the compass's check in an outage (:mod:`vdm_aero.nav.compass_consistency`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array

__all__ = ["MagDeviation"]

SOFT_IRON_PRIOR: Final = 0.03  # 1σ of each matrix element: what a passed compass calibration may leave
MOTOR_PRIOR_UT: Final = 15.0  # 1σ of the motor field at full throttle [µT]: 30 % of a 50 µT field
OFFSET_PRIOR_UT: Final = 50.0  # the constant: loosely held (the filter's hard-iron state is the authority)
RESIDUAL_SIGMA_UT: Final = 2.0  # one sample's residual: the sensor's noise and the aided attitude's error
LEARN_AFTER_N: Final = 600  # samples (a minute at 10 Hz) before the correction is applied
SOLVE_EVERY_N: Final = 50
THROTTLE_BINS: Final = 50  # the learnt throttles' histogram over [0, 1]: 2 % bins
THROTTLE_QUANTILE: Final = 0.01  # the range's ends: a brief throttle cut in a turn is not what it learnt on


@dataclass
class MagDeviation:
    """Online regression of the magnetometer residual (module docstring). ``observe`` while aided,
    :meth:`correction_ut` always: a fit/predict estimator in the manner of pysensors."""

    field_ned_ut: F64Array
    info: F64Array = field(init=False)
    rhs: F64Array = field(init=False)
    n: int = 0

    def __post_init__(self) -> None:
        self.field_ned_ut = np.asarray(self.field_ned_ut, dtype=np.float64)
        b = float(np.linalg.norm(self.field_ned_ut))
        # the soft-iron prior in µT of residual per µT of field: its elements scaled by the field's size so
        # that the information matrix is well conditioned
        prior = np.array([SOFT_IRON_PRIOR * b] * 3 + [MOTOR_PRIOR_UT, OFFSET_PRIOR_UT])
        self._scale = np.array([1.0 / b] * 3 + [1.0, 1.0])  # regressors: ĥ/|B|, throttle, 1
        self.info = np.diag(1.0 / np.square(prior))
        self.rhs = np.zeros((5, 3))
        self._beta: F64Array | None = None
        self._phi_sum = np.zeros(5)
        self._solved_n = 0
        self._throttle_hist = np.zeros(THROTTLE_BINS)

    def _phi(self, h_b_ut: F64Array, throttle: float) -> F64Array:
        return np.array([h_b_ut[0], h_b_ut[1], h_b_ut[2], throttle, 1.0]) * self._scale

    def observe(self, field_b_ut: F64Array, h_b_ut: F64Array, throttle: float) -> None:
        """One raw field sample [µT] against the field the aided attitude predicts, ``h_b_ut`` = Ĉ_bn·m_ned."""
        phi = self._phi(h_b_ut, throttle)
        w = 1.0 / RESIDUAL_SIGMA_UT**2
        self.info += w * np.outer(phi, phi)
        self.rhs += w * np.outer(phi, np.asarray(field_b_ut, dtype=np.float64) - h_b_ut)
        self._phi_sum += phi
        if np.isfinite(throttle):
            self._throttle_hist[min(max(int(throttle * THROTTLE_BINS), 0), THROTTLE_BINS - 1)] += 1.0
        self.n += 1

    def throttle_range(self) -> tuple[float, float] | None:
        """The throttles the motor's term was learnt on: the 1st and 99th percentiles of the learnt samples (bin
        edges: the low end of the lowest bin, the high end of the highest); None until :attr:`ready`."""
        seen = float(self._throttle_hist.sum())
        if not self.ready or seen == 0.0:
            return None
        cdf = np.cumsum(self._throttle_hist) / seen
        lo = int(np.searchsorted(cdf, THROTTLE_QUANTILE))
        hi = int(np.searchsorted(cdf, 1.0 - THROTTLE_QUANTILE))
        return lo / THROTTLE_BINS, min(hi + 1, THROTTLE_BINS) / THROTTLE_BINS

    @property
    def ready(self) -> bool:
        return self.n >= LEARN_AFTER_N

    def coefficients(self) -> F64Array:
        """The posterior mean (5 × 3): rows S (per unit of ĥ/|B|, three rows), k [µT], c [µT]; solved again
        every :data:`SOLVE_EVERY_N` samples (the estimate moves slowly and the service runs it at 10 Hz)."""
        if self._beta is None or self.n - self._solved_n >= SOLVE_EVERY_N:
            self._beta = np.asarray(np.linalg.solve(self.info, self.rhs))
            self._solved_n = self.n
        return self._beta

    def correction_ut(self, h_b_ut: F64Array, throttle: float) -> F64Array:
        """S·(ĥ − ĥ̄) + k·(throttle − throttlē) [µT], about the means of the flight it learnt on: what to
        take off the raw field (zero until :attr:`ready`). Centred, so that the correction adds nothing on
        average to what the filter's hard-iron state already holds: an uncentred S·ĥ or k·throttle, whose
        constant part the regression cannot tell from c, would shift the field at the moment it is applied
        and, in an outage where the hard-iron state is held, turn the heading."""
        if not self.ready:
            return np.zeros(3)
        dphi = self._phi(h_b_ut, throttle) - self._phi_sum / self.n
        dphi[4] = 0.0
        return np.asarray(dphi @ self.coefficients())
