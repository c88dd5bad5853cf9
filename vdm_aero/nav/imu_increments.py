"""IMU samples → filter-rate increments (Δθ, Δv): the one integrator, with one gap rule, for the live service
(:mod:`firmware_bridge.service`, sample by sample as they arrive) and the log replay and the benchmark
(:meth:`vdm_aero.nav.stream.NavStream.from_log`, over a log's arrays).

* Each sample holds until the next (rectangle rule, what the autopilots' own delta-angle logs assume between
  samples), summed until a filter step is full.
* **A gap** is an interval longer than :func:`gap_limit_s`: ``IMU_GAP_S`` or ``IMU_GAP_FACTOR`` typical
  intervals, whichever is longer (a 400 Hz link that pauses 0.1 s has lost samples; a 4 Hz ground-station
  log's 0.25 s is its normal rate). Nothing is integrated across a gap: the open increment is dropped and
  the next starts after it (the filter then bridges the gap, growing its covariance).
* **A sample no IMU can give** (non-finite, or beyond :data:`GYRO_MAX_RAD_S` / :data:`ACCEL_MAX_M_S2`) is
  refused and counted; its neighbours integrate across it, so one bad sample costs one sample, not the
  filter (a NaN increment would make the state non-finite).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array, IntArray
from vdm_aero.nav.contracts import ImuIncrement

__all__ = ["ACCEL_MAX_M_S2", "GYRO_MAX_RAD_S", "IMU_GAP_FACTOR", "IMU_GAP_S", "ImuIntegrator", "gap_limit_s",
           "increments"]  # fmt: skip

IMU_GAP_S: Final = 0.1  # at any rate, a pause this long has lost samples
IMU_GAP_FACTOR: Final = 5.0  # ... or five typical intervals, for low-rate streams (ground-station logs: 4–10 Hz)
FIRST_GAP_S: Final = 1.0  # before the rate is known: a 1 Hz IMU is no IMU
TYPICAL_GAIN: Final = 0.05  # the typical interval: an exponential average over ~20 accepted intervals
GYRO_MAX_RAD_S: Final = 100.0  # 5730 °/s: nearly 3× the widest MEMS gyro range (2000 °/s)
ACCEL_MAX_M_S2: Final = 2000.0  # ≈ 200 g: far beyond a navigation accelerometer's range (16–32 g)

Vec3 = Sequence[float]


def gap_limit_s(typical_dt_s: float) -> float:
    """The longest interval [s] integrated across, for a stream whose typical interval is ``typical_dt_s``."""
    return max(IMU_GAP_S, IMU_GAP_FACTOR * typical_dt_s) if math.isfinite(typical_dt_s) else FIRST_GAP_S


class ImuIntegrator:
    """Sums IMU samples over one filter step (module docstring). Plain floats, not arrays: the service adds
    400 samples a second, and numpy per sample costs more than the sums."""

    def __init__(self, filter_rate_hz: float) -> None:
        self.step_s = 1.0 / filter_rate_hz
        self._prev: tuple[float, Vec3, Vec3] | None = None
        self._sum = [0.0] * 6  # Δθ (3), Δv (3)
        self._dt = 0.0
        self.typical_dt_s = math.nan
        self.gaps = 0
        self.rejected = 0

    def reset(self) -> None:
        """Start again at the next sample (a reboot, another IMU): nothing open is carried over."""
        self._prev = None
        self._sum = [0.0] * 6
        self._dt = 0.0

    def add(self, t_s: float, gyro_b_rad_s: Vec3, accel_b_m_s2: Vec3) -> tuple[float, ImuIncrement] | None:
        """One sample at ``t_s`` [s] (rad/s, m/s²); returns (end time [s], increment) when a step is full."""
        w, f = gyro_b_rad_s, accel_b_m_s2
        if not (
            abs(w[0]) <= GYRO_MAX_RAD_S
            and abs(w[1]) <= GYRO_MAX_RAD_S
            and abs(w[2]) <= GYRO_MAX_RAD_S
            and abs(f[0]) <= ACCEL_MAX_M_S2
            and abs(f[1]) <= ACCEL_MAX_M_S2
            and abs(f[2]) <= ACCEL_MAX_M_S2
        ):
            self.rejected += 1  # NaN fails every comparison: refused too
            return None
        prev, self._prev = self._prev, (t_s, w, f)
        if prev is None:
            return None
        dt = t_s - prev[0]
        if not 0.0 < dt <= gap_limit_s(self.typical_dt_s):
            self.gaps += 1
            self.reset()
            self._prev = (t_s, w, f)
            return None
        td = self.typical_dt_s
        self.typical_dt_s = dt if math.isnan(td) else td + TYPICAL_GAIN * (dt - td)
        acc = self._sum
        w, f = prev[1], prev[2]
        acc[0] += w[0] * dt
        acc[1] += w[1] * dt
        acc[2] += w[2] * dt
        acc[3] += f[0] * dt
        acc[4] += f[1] * dt
        acc[5] += f[2] * dt
        self._dt += dt
        if self._dt < self.step_s - 0.5 * dt:
            return None
        inc = ImuIncrement(np.array(acc[:3]), np.array(acc[3:]), self._dt)
        self._sum = [0.0] * 6
        self._dt = 0.0
        return t_s, inc


def increments(t_s: F64Array, gyro_b_rad_s: F64Array, accel_b_m_s2: F64Array, filter_rate_hz: float
               ) -> tuple[F64Array, F64Array, F64Array, F64Array, IntArray]:  # fmt: skip
    """A log's IMU samples (N,), (N, 3), (N, 3) through :class:`ImuIntegrator`: the increments' end times [s],
    Δθ (M, 3) [rad], Δv (M, 3) [m/s], their lengths [s], and the index of the sample that closed each."""
    regular = _regular_increments(t_s, gyro_b_rad_s, accel_b_m_s2, filter_rate_hz)
    if regular is not None:
        return regular
    integ = ImuIntegrator(filter_rate_hz)
    t_end, dth, dv, dt, closed = [], [], [], [], []
    for i, (t, w, f) in enumerate(zip(t_s.tolist(), gyro_b_rad_s.tolist(), accel_b_m_s2.tolist(), strict=True)):
        if (step := integ.add(t, w, f)) is not None:
            t_end.append(step[0])
            dth.append(step[1].dtheta_b)
            dv.append(step[1].dvel_b)
            dt.append(step[1].dt_s)
            closed.append(i)
    if not t_end:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    return np.array(t_end), np.array(dth), np.array(dv), np.array(dt), np.array(closed, dtype=np.int64)


def _regular_increments(t_s: F64Array, gyro_b_rad_s: F64Array, accel_b_m_s2: F64Array, filter_rate_hz: float
                        ) -> tuple[F64Array, F64Array, F64Array, F64Array, IntArray] | None:  # fmt: skip
    """:func:`increments` of a stream with no gap and no refused sample (every interval in (0, ``IMU_GAP_S``],
    which no typical interval makes a gap), None otherwise: what :class:`ImuIntegrator` gives, to the last bit,
    with numpy doing the sums. The step boundaries still come from a loop (each depends on the running Δt since
    the last), but over Δt alone; each step's sums are then taken in the integrator's order, one sample column at
    a time over all steps. A log's 400 Hz stream sample by sample was 15 % of ``ins``'s benchmark flight
    (docs/performance.md); ``tests/test_imu_increments.py`` holds the two paths to each other."""
    n = len(t_s)
    if n < 2:
        return None
    dt = np.diff(t_s)
    w, f = np.asarray(gyro_b_rad_s, dtype=np.float64), np.asarray(accel_b_m_s2, dtype=np.float64)
    if not (np.all(dt > 0.0) and np.all(dt <= IMU_GAP_S)
            and np.all(np.abs(w) <= GYRO_MAX_RAD_S) and np.all(np.abs(f) <= ACCEL_MAX_M_S2)):  # fmt: skip
        return None
    step_s = 1.0 / filter_rate_hz
    closed, lengths = [], []
    acc_dt = 0.0
    for i, d in enumerate(dt.tolist(), start=1):  # interval i ends at sample i; sample i − 1 holds over it
        acc_dt += d
        if not acc_dt < step_s - 0.5 * d:
            closed.append(i)
            lengths.append(acc_dt)
            acc_dt = 0.0
    if not closed:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    ends = np.array(closed, dtype=np.int64)
    firsts = np.concatenate([[1], ends[:-1] + 1])  # each step's first interval
    width = int((ends - firsts).max()) + 1
    x = np.concatenate([w[:-1], f[:-1]], axis=1) * dt[:, None]  # interval i − 1 of the array: sample i − 1 × Δt_i
    sums = np.zeros((len(ends), 6))
    for k in range(width):  # the k-th interval of every step that has one, added in the integrator's order
        idx = firsts + k
        inside = idx <= ends
        sums[inside] += x[idx[inside] - 1]
    return t_s[ends].astype(np.float64), sums[:, :3], sums[:, 3:], np.array(lengths, dtype=np.float64), ends
