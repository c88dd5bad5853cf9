"""Is the compass's field still the one the filter was aided with? A persistent-innovation test for an outage.

Why: in an outage the three-axis compass holds the tilt as well as the heading, which pays while its field is
the field the filter was aligned with (the survey, a wind shear: the air data relearn the wind while the
compass holds the attitude). A field change that nothing models (the motor's field at a throttle the in-flight
swing learnt wrong, a glide home with the throttle closed) reads the same as a tilt: with no GNSS velocity to
hold it, the filter turns its pitch to explain the field, and g·tilt is the fastest drift there is
(docs/navigation.md, seed 19 of the gradient: 60 mrad of pitch in 40 s, 24 km at 300 s).

What tells a field change from a tilt: a rotation cannot change the field's strength. A tilt or heading
error δθ makes the innovation [ĥ_b×]·δθ, across the predicted field ĥ_b; a field that changed (the motor's, a
soft iron the swing learnt wrong) has in general a part along it. So the test reads only the innovation's
component along ĥ_b, which no attitude error can make — the component ArduPilot's compass checks read as the
field's length (the calibration's field radius, EKF3's field-strength consistency). A wind shear, which pulls
the attitude through the air data while the compass is as it was, leaves it alone.

The test is the innovation-mean test of the fault-detection literature (Mehra & Peschon, "An innovations
approach to fault detection and diagnosis in dynamic systems", Automatica 7, 1971): that component,
normalised by its predicted σ (√(uᵀSu): the hard iron's uncertainty and the sensor's noise), is averaged with
an exponential window of :data:`TAU_S`. While the compass agrees with the filter the mean is that of a zero-mean
unit-variance sequence, σ ≈ √(Δt / 2τ) ≈ 0.1 at 10 Hz; but the compass's σ stands mostly for the deviation the
swing leaves, a bias, and healthy flights start an outage with a mean near 1, a glide home with the throttle
closed near 3. Past :data:`THRESHOLD` the compass is *biased* for the rest of the outage, and the filter fuses
its heading alone (:class:`vdm_aero.nav.measurements.MagHeading`, as ArduPilot EKF3 and PX4 EKF2 fuse a compass
they do not trust for the tilt): latched, because the heading fusion no longer tests the field.

The along-field test misses a field change that lies across the field: the same innovation as a tilt (harsh
gradient seed 1: the motor's field gone in the glide, 2.4 µT along the body's x axis, across a mostly vertical
field, read as a tilt that turned the pitch by 28 mrad within 20 s, and 315 m off at 60 s). What is known
without the innovation is *when* the compass's correction has no data behind it: the in-flight swing learnt
the motor's field on the throttles of the aided flight, so a throttle held outside them
(:meth:`vdm_aero.nav.mag_deviation.MagDeviation.throttle_range`) is an extrapolation of k·throttle. The same latch
takes it: the throttle's mean over :data:`THROTTLE_TAU_S` (a turn's brief throttle cut is not a glide) more
than :data:`THROTTLE_MARGIN` outside the learnt range.

Both tests watch the outage. What the aided flight already showed is the third (:class:`AidedCompassFit`): once
the swing's correction applies, the three axes' innovations while GNSS aids are what the corrected compass leaves
against an attitude the GNSS velocity holds, and their part across the predicted field is the part an attitude
error makes, the part the three axes turn the attitude by. On the survey, the loiter and the payload drop that part
is a few tenths of a µT (at most 0.79 µT rms on the flights read); in manoeuvring flight it reached 1.25–3.1 µT
where the three axes held an attitude that was already wrong (harsh manoeuvring seed 9: 6.9° of heading and
1.5° of pitch off at the outage start, against a 1σ of 0.3° and 0.1°, then 27 m/s of ground velocity in three
minutes, the gust state taking up the air data's disagreement; docs/navigation.md, "Manoeuvring read against the
truth"). A compass whose aided innovations across the field passed :data:`AIDED_ACROSS_RMS_MAX_UT` is fused in the
outage as the autopilot fuses it, at EKF3's 5-µT σ (EK3_MAG_M_NSE), the two tests above still watching it. The
part along the field is left out of the verdict: no attitude error makes it, and a compass whose field's strength
is off in flight (airframe 0 of this benchmark's fleet: 1–2.2 µT along it on some surveys) holds the tilt well.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array

__all__ = ["AidedCompassFit", "CompassConsistency"]

TAU_S: Final = 5.0  # the mean's window [s]: a throttle change settles in seconds, turbulence averages out
# |mean normalised innovation|: a field error twice the σ the filter gives the compass, which R does not cover.
# Not the white-noise figure (the mean of white innovations has σ 0.1): the compass's 1.5-µT σ stands mostly
# for deviation left after the swing, a bias, and at an outage's start healthy flights carry a mean of ~1
THRESHOLD: Final = 2.0
THROTTLE_TAU_S: Final = 10.0  # the throttle's mean [s]: a glide holds it for a minute, a turn's cut for seconds
# beyond the learnt throttles, as a fraction of full throttle: a quarter of the motor's field where ArduPilot accepts
# 30 % of the Earth's at full throttle is ~4 µT, past the compass's 1.5-µT σ. Set on this benchmark's flights
# (gradient 1: a glide at 0 below a learnt 0.57; survey 1: a 10-s mean dipping to 0.47 below a learnt 0.67)
THROTTLE_MARGIN: Final = 0.3
# the rms [µT] of the aided innovations' part across the predicted field past which an outage fuses the compass at
# EKF3's σ. Set on this benchmark's flights: at most 0.79 µT on surveys, loiters and payload drops, 0.44–1.05 µT on
# the manoeuvring flights whose 1.5-µT compass did as well as a looser one in the outage, 1.25–3.1 µT on those where
# it lost (and 1.27–2.39 µT on three manoeuvring flights and a wind shear that the looser compass made worse)
AIDED_ACROSS_RMS_MAX_UT: Final = 1.2
AIDED_MIN_N: Final = 100  # samples (10 s at 10 Hz) before the aided fit is judged


def _weight(dt_s: float, tau_s: float) -> float:
    """An exponential mean's weight for a sample ``dt_s`` after the last; the first sample's is that of a 10 Hz one,
    so that a mean starts where it was set, not at one sample."""
    return min(dt_s / tau_s, 1.0) if dt_s > 0.0 else 0.1 / tau_s


@dataclass
class AidedCompassFit:
    """The three-axis compass's innovations [µT] while GNSS aids it and the swing's correction applies (module
    docstring): the mean squares of their parts across and along the predicted field over the flight,
    :meth:`observe` each sample, :attr:`refuted` once the rms across is past :data:`AIDED_ACROSS_RMS_MAX_UT` after
    :data:`AIDED_MIN_N` samples."""

    across_sq_ut2: float = 0.0
    along_sq_ut2: float = 0.0
    n: int = 0

    def observe(self, innovation_ut: F64Array, field_b_ut: F64Array) -> None:
        """One sample's innovation [µT] and the Earth's field it was predicted against, in the body axes [µT]."""
        u = np.asarray(field_b_ut, dtype=np.float64)
        u = u / np.linalg.norm(u)
        along = float(u @ innovation_ut)
        self.along_sq_ut2 += along * along
        self.across_sq_ut2 += max(float(innovation_ut @ innovation_ut) - along * along, 0.0)
        self.n += 1

    def rms_ut(self) -> tuple[float, float] | None:
        """The innovations' rms across and along the field [µT] (None before the first sample)."""
        if not self.n:
            return None
        return float(np.sqrt(self.across_sq_ut2 / self.n)), float(np.sqrt(self.along_sq_ut2 / self.n))

    @property
    def refuted(self) -> bool:
        return self.n >= AIDED_MIN_N and self.across_sq_ut2 > AIDED_ACROSS_RMS_MAX_UT**2 * self.n


@dataclass
class CompassConsistency:
    """The exponentially weighted means of the compass's normalised innovation along the field and of the throttle
    in an outage (module docstring): :meth:`observe` each sample, :attr:`biased` once the first passes
    :data:`THRESHOLD` or the second leaves the learnt throttles by :data:`THROTTLE_MARGIN` (:attr:`reason` says
    which)."""

    tau_s: float = TAU_S
    threshold: float = THRESHOLD
    mean: float = 0.0
    biased: bool = False
    biased_at_s: float | None = None
    reason: str | None = None  # "field" (along the field) or "throttle" (outside the learnt throttles)
    throttle_mean: float | None = None
    _t_s: float | None = None

    def reset(self) -> None:
        """A new outage (or GNSS back): the compass is trusted again."""
        self.mean = 0.0
        self.biased, self.biased_at_s, self.reason, self.throttle_mean, self._t_s = False, None, None, None, None

    def observe(self, t_s: float, innovation: F64Array, s: F64Array, field_b_ut: F64Array,
                throttle: float | None = None, throttle_range: tuple[float, float] | None = None) -> bool:  # fmt: skip
        """One sample's innovation [µT], its predicted covariance S [µT²] and the field it was predicted
        against (the Earth's field in the body axes) [µT], with the throttle [0–1] and the throttles the swing
        learnt on (None: not tested); True when this sample latches :attr:`biased`."""
        if self.biased:
            return False
        dt = 0.0 if self._t_s is None else max(t_s - self._t_s, 0.0)
        self._t_s = t_s
        if throttle is not None and throttle_range is not None and np.isfinite(throttle):
            lo, hi = throttle_range
            # the mean starts inside the learnt range, as the field's at zero: an outage that begins in a turn's
            # throttle cut is not a glide
            if self.throttle_mean is None:
                self.throttle_mean = 0.5 * (lo + hi)
            self.throttle_mean += _weight(dt, THROTTLE_TAU_S) * (throttle - self.throttle_mean)
            if not lo - THROTTLE_MARGIN <= self.throttle_mean <= hi + THROTTLE_MARGIN:
                self.biased, self.biased_at_s, self.reason = True, t_s, "throttle"
                return True
        u = np.asarray(field_b_ut, dtype=np.float64)
        u = u / np.linalg.norm(u)
        z = float(u @ innovation) / float(np.sqrt(u @ s @ u))
        self.mean += _weight(dt, self.tau_s) * (z - self.mean)
        if abs(self.mean) > self.threshold:
            self.biased, self.biased_at_s, self.reason = True, t_s, "field"
            return True
        return False
