"""The autopilot's own attitude estimate, as its ATTITUDE message reports it, from the world's IMU.

An autopilot integrates its gyro at the IMU's full rate, less its estimate of the gyro's offset (ArduPilot's EKF3
and PX4's EKF2 predict on every delta angle), and its aiding (gravity, the compass, GNSS) pulls the attitude back
towards the truth over seconds. So its estimate is the truth turned by an error ``e`` (body frame, rad) that the
gyro's own errors drive and the aiding bleeds off:

    q_ap = q_true ⊗ Exp(e),   ė = (ω_meas − b̂ − ω_true) − ω_true × e − e / τ_c

(the attitude error equation of a strapdown INS in the body frame, Groves 2013, *Principles of GNSS, Inertial,
and Multisensor Integrated Navigation Systems*, §5.3 and §14.2.2, with the aiding as a first-order pull). ``b̂``,
the autopilot's offset estimate, starts from the offset at its first sample (the gyro calibration at boot,
ArduPilot's INS_GYR_CAL) and follows the offset the world's gyro really has (its heating, its scale and
cross-axis errors in turns) with a lag ``τ_b``. Over a fraction of a second the error changes by what the gyro's
errors integrate to, which is what the estimate's change between two messages carries; over minutes it stays
within a degree or so, as an aided EKF's does.

The mock autopilot (:mod:`sim.sitl.autopilot`) reports this estimate in ATTITUDE and ATTITUDE_QUATERNION, and
:func:`sim.flight.record.fly` records it at :data:`AP_ATTITUDE_RATE_HZ`.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from sim.flight.contract import ImuSample, VehicleTruth
from vdm_aero._typing import F64Array
from vdm_aero.rotation import quat_exp, quat_multiply

__all__ = ["AP_ATTITUDE_RATE_HZ", "AutopilotAttitude"]

AP_ATTITUDE_RATE_HZ: Final = 10.0  # the rate the service asks ATTITUDE at (firmware_bridge.config's streams)
# assumed, the order of an aided EKF's: its attitude corrections act over ~10 s (EKF3's tilt and yaw
# alignment with GNSS and the compass), its gyro-offset states over minutes (their process noise, EK3_GBIAS_P_NSE,
# lets the offset move by ~0.1°/s in 100 s)
AP_CORRECTION_TAU_S: Final = 10.0
AP_GYRO_OFFSET_TAU_S: Final = 100.0


class AutopilotAttitude:
    """The autopilot's attitude error, stepped with the world's IMU samples (module docstring)."""

    def __init__(self, correction_tau_s: float = AP_CORRECTION_TAU_S,
                 offset_tau_s: float = AP_GYRO_OFFSET_TAU_S) -> None:  # fmt: skip
        self.correction_tau_s = correction_tau_s
        self.offset_tau_s = offset_tau_s
        # e and b̂ as Python floats: this runs at the IMU's rate in every world, and np.cross on 3-vectors costs
        # ~10 µs of checks (3 % of the test suite's CPU, 2026-12-01)
        self._e = (0.0, 0.0, 0.0)
        self._offset: tuple[float, float, float] | None = None  # b̂
        self._t_s: float | None = None

    @property
    def e_b_rad(self) -> F64Array:
        """The attitude error ``e`` [rad], body frame."""
        return np.array(self._e)

    def step(self, imu: ImuSample, truth: VehicleTruth) -> None:
        """One IMU sample, with the truth at its time."""
        wx, wy, wz = (float(w) for w in truth.omega_b_rad_s)
        gx, gy, gz = (float(g) for g in imu.gyro_b_rad_s)
        ox, oy, oz = gx - wx, gy - wy, gz - wz  # the gyro's offset now
        if self._offset is None or self._t_s is None:
            self._offset, self._t_s = (ox, oy, oz), imu.t_s
            return
        dt = imu.t_s - self._t_s
        self._t_s = imu.t_s
        if dt <= 0.0:
            return
        bx, by, bz = self._offset
        ex, ey, ez = self._e
        k = 1.0 / self.correction_tau_s
        # ė = (offset − b̂) − ω × e − e / τ_c
        self._e = (
            ex + (ox - bx - (wy * ez - wz * ey) - ex * k) * dt,
            ey + (oy - by - (wz * ex - wx * ez) - ey * k) * dt,
            ez + (oz - bz - (wx * ey - wy * ex) - ez * k) * dt,
        )
        a = dt / self.offset_tau_s
        self._offset = (bx + (ox - bx) * a, by + (oy - by) * a, bz + (oz - bz) * a)

    def q_nb(self, truth: VehicleTruth) -> F64Array:
        """The autopilot's attitude (body FRD → NED, scalar first) at the truth's time."""
        return quat_multiply(truth.q_nb, quat_exp(self.e_b_rad))
