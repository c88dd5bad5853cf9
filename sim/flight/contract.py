"""The world contract (``sim.flight`` is the world): truth and sensor samples, SI units.

The world (``sim.flight``) produces one :class:`WorldTick` per simulation step; the mock autopilot turns
the samples into MAVLink messages (its own unit conversions: it is the peer under test, independent
of ``firmware_bridge``). Every sample carries the world time of its measurement; a sensor that has no
new sample at a tick is ``None`` (sensors run at their own rates; a GNSS outage is ``None`` too).
Frames: body FRD (``_b``), navigation NED (``_ned``); quaternions are scalar-first (w, x, y, z) and
rotate body vectors into NED.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from vdm_aero._typing import F64Array


@dataclass(frozen=True)
class VehicleTruth:
    """The true vehicle state at world time ``t_s``."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # above mean sea level
    pos_ned_m: F64Array  # (3,) from the home position
    v_ned_m_s: F64Array  # (3,) ground velocity
    q_nb: F64Array  # (4,) attitude, body → NED, scalar first
    omega_b_rad_s: F64Array  # (3,) body rates p, q, r
    specific_force_b_m_s2: F64Array  # (3,) what an ideal accelerometer reads
    airspeed_m_s: float  # true airspeed
    alpha_rad: float
    beta_rad: float
    wind_ned_m_s: F64Array  # (3,) total wind at the vehicle (steady + turbulence)
    throttle: float  # 0..1


@dataclass(frozen=True)
class ImuSample:
    t_s: float
    accel_b_m_s2: F64Array  # (3,)
    gyro_b_rad_s: F64Array  # (3,)
    temperature_c: float


@dataclass(frozen=True)
class GnssSample:
    t_s: float  # time of validity (the sample is delivered after the receiver latency)
    lat_deg: float
    lon_deg: float
    alt_m: float
    v_ned_m_s: F64Array  # (3,)
    fix_type: int  # 0-1 no fix, 2 = 2D, 3 = 3D (GPS_FIX_TYPE)
    satellites: int
    hdop: float
    vdop: float
    h_acc_m: float
    v_acc_m: float
    vel_acc_m_s: float


@dataclass(frozen=True)
class BaroSample:
    t_s: float
    pressure_pa: float  # static pressure
    temperature_c: float


@dataclass(frozen=True)
class MagSample:
    t_s: float
    field_b_t: F64Array  # (3,) magnetic flux density [T] in the body frame, hard iron included


@dataclass(frozen=True)
class AirspeedSample:
    t_s: float
    dp_pa: float  # pitot differential pressure
    temperature_c: float


@dataclass(frozen=True)
class PortsSample:
    """One sample of all pressure ports: Δp = p_port − p_static [Pa], sharing one timestamp."""

    t_s: float
    names: tuple[str, ...]
    dp_pa: F64Array  # (n,)


@dataclass(frozen=True)
class ServoSample:
    t_s: float
    pwm_us: F64Array  # (n,) servo outputs [µs], ArduPlane order: 1 aileron, 2 elevator, 3 throttle, 4 rudder


@dataclass(frozen=True)
class WorldTick:
    """Everything that happened in one world step. Sensor fields are None when no new sample."""

    truth: VehicleTruth
    imu: ImuSample | None = None
    gnss: GnssSample | None = None
    baro: BaroSample | None = None
    mag: MagSample | None = None
    airspeed: AirspeedSample | None = None
    ports: PortsSample | None = None
    servos: ServoSample | None = None
    gnss_outage: bool = False  # inside a scripted outage window


class World(Protocol):
    """A steppable world: the flight simulator, or a test's scripted world."""

    dt_s: float  # world step [s]
    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float

    def step(self) -> WorldTick:
        """Advance one step and return what happened."""
        ...
