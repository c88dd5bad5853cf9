"""Control surfaces and throttle: first-order lag, rate limit, deflection limits, PWM outputs.

Channel order is ArduPlane's servo order: aileron, elevator, throttle, rudder (SERVO1..4). Deflections
are in radians with the sign convention of :class:`sim.airframe.vlm.FlightStates`:

* aileron > 0: right aileron trailing edge down (left up) → rolls LEFT;
* elevator > 0: trailing edge down → nose DOWN;
* rudder > 0: trailing edge to the left → nose LEFT;
* throttle: 0…1.

Each step of length Δ the position moves towards the (limit-clipped) command c along the exact
first-order response, δ* = c + (δ − c)·e^{−Δ/τ}, the step is bounded by the rate limit and the result by
the deflection limits; within a physics step the position is held (zero-order hold).

PWM: 1500 µs is zero deflection and ±500 µs the channel's deflection limit, with the same sign as the
deflection (so aileron PWM > 1500 rolls left); throttle maps 0…1 to 1000…2000 µs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array

__all__ = ["ACTUATORS", "CHANNELS", "ActuatorSetSpec", "ActuatorSpec", "Actuators"]

CHANNELS: Final = ("aileron", "elevator", "throttle", "rudder")
PWM_MID_US: Final = 1500.0
PWM_HALF_RANGE_US: Final = 500.0
PWM_MIN_US: Final = 1000.0


@dataclass(frozen=True)
class ActuatorSpec:
    """One channel: lag time constant [s], rate limit [unit/s] and position limits [unit] (rad for
    surfaces, 0…1 for throttle)."""

    tau_s: float
    rate_limit_per_s: float
    min_value: float
    max_value: float

    def __post_init__(self) -> None:
        if not (self.tau_s > 0.0 and self.rate_limit_per_s > 0.0 and self.max_value > self.min_value):
            raise ValueError(f"invalid actuator spec {self}")


@dataclass(frozen=True)
class ActuatorSetSpec:
    """The four channels of the aircraft and where their numbers come from."""

    aileron: ActuatorSpec
    elevator: ActuatorSpec
    throttle: ActuatorSpec
    rudder: ActuatorSpec
    source: str

    def channels(self) -> tuple[ActuatorSpec, ActuatorSpec, ActuatorSpec, ActuatorSpec]:
        return self.aileron, self.elevator, self.throttle, self.rudder


_SURFACE_LIMIT_RAD: Final = math.radians(20.0)
_SURFACE = ActuatorSpec(
    tau_s=0.025, rate_limit_per_s=math.radians(300.0), min_value=-_SURFACE_LIMIT_RAD, max_value=_SURFACE_LIMIT_RAD
)
ACTUATORS: Final = {
    "uav-2m-servos": ActuatorSetSpec(
        aileron=_SURFACE,
        elevator=_SURFACE,
        throttle=ActuatorSpec(tau_s=0.08, rate_limit_per_s=5.0, min_value=0.0, max_value=1.0),
        rudder=_SURFACE,
        source="digital mini servos (0.10 s/60° no-load at 6 V, i.e. 600°/s; halved for load and linkage: "
        "300°/s; position-loop lag 25 ms); ±20° surface throws, the range of the airframe's envelope data; "
        "throttle: spin-up of an 11-inch propeller on an outrunner, ~80 ms",
    ),
}
"""Named actuator sets."""


class Actuators:
    """The actuator states of the four channels (ArduPlane order), advanced once per physics step."""

    def __init__(self, spec: ActuatorSetSpec, initial: tuple[float, float, float, float]) -> None:
        self.spec = spec
        ch = spec.channels()
        self._lo = [c.min_value for c in ch]
        self._hi = [c.max_value for c in ch]
        self._tau = [c.tau_s for c in ch]
        self._rate = [c.rate_limit_per_s for c in ch]
        self.position = [min(max(v, lo), hi) for v, lo, hi in zip(initial, self._lo, self._hi, strict=True)]
        self.command = list(self.position)
        self._decay_dt = -1.0
        self._decay = [0.0] * 4

    def set_command(self, aileron: float, elevator: float, throttle: float, rudder: float) -> None:
        """New commands (clipped to the limits)."""
        self.command = [
            min(max(v, lo), hi)
            for v, lo, hi in zip((aileron, elevator, throttle, rudder), self._lo, self._hi, strict=True)
        ]

    def step(self, dt_s: float) -> None:
        """Advance the positions by ``dt_s``."""
        if dt_s != self._decay_dt:
            self._decay = [math.exp(-dt_s / t) for t in self._tau]
            self._decay_dt = dt_s
        pos = self.position
        for i in range(4):
            c = self.command[i]
            target = c + (pos[i] - c) * self._decay[i]
            lim = self._rate[i] * dt_s
            step = min(max(target - pos[i], -lim), lim)
            pos[i] = min(max(pos[i] + step, self._lo[i]), self._hi[i])

    def pwm_us(self) -> F64Array:
        """Servo outputs (4,) [µs] of the current positions (see the module docstring)."""
        return self.pwm_of(self.position)

    def pwm_of(self, values: Sequence[float]) -> F64Array:
        """Servo outputs (4,) [µs] of channel values (e.g. the commands) in ArduPlane order."""
        out = np.empty(4)
        for i, (v, lo, hi) in enumerate(zip(values, self._lo, self._hi, strict=True)):
            if i == 2:
                out[i] = PWM_MIN_US + 2.0 * PWM_HALF_RANGE_US * (v - lo) / (hi - lo)
            else:
                out[i] = PWM_MID_US + PWM_HALF_RANGE_US * v / max(abs(lo), abs(hi))
        return out
