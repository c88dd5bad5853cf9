"""A deterministic scripted :class:`~sim.flight.contract.World`: a coordinated circle or figure-eight.

It stands in for the flight simulator in tests and lets the mock autopilot run before ``sim.flight`` is
wired. The truth is kinematically consistent:

* the horizontal path is flown at a constant ground speed (a circle, or a lemniscate of Gerono
  reparametrised by arc length), optionally with a sinusoidal altitude oscillation;
* position, velocity and acceleration are analytic; the specific force is ``a − g``;
* the attitude is that of a coordinated flight (no lateral specific force, β = 0) with the angle of
  attack proportional to the load factor, ``α = α_1g · |f| / g``, nose along the air velocity
  (ground velocity − a steady wind);
* body rates come from the attitude's time derivative (central difference, h = 1e-4 s);
* latitude/longitude map from NED on a local tangent plane at home with WGS-84 radii of curvature.

Sensors are the truth plus seeded white noise (zero noise needs no generator): IMU 400 Hz, GNSS 5 Hz
(with a latency and scripted outage windows), baro/mag/airspeed/ports/servos 50 Hz. Pressures follow the
ISA troposphere; the pressure ports are taps on a hemispherical nose (potential flow over a sphere,
``Cp = 1 − 9/4 sin²γ``), Δp = q·Cp. Servo outputs are a plausible function of the truth, not a controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from sim.flight.contract import (
    AirspeedSample,
    BaroSample,
    GnssSample,
    ImuSample,
    MagSample,
    PortsSample,
    ServoSample,
    VehicleTruth,
    WorldTick,
)
from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import G0_M_S2 as GRAVITY_M_S2
from vdm_aero.atmosphere import isa
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame
from vdm_aero.rotation import quat_from_dcm

ATTITUDE_DIFF_STEP_S = 1e-4  # central-difference step for the body rates
BLOCK_STEPS = 400  # truth is computed vectorised over this many world steps
ARC_TABLE_POINTS = 20001  # arc-length table of the figure-eight (per period)
PORT_NAME_MAX_CHARS = 10  # NAMED_VALUE_FLOAT.name


def isa_pressure_pa(alt_m: float) -> float:
    """ISA troposphere static pressure at geometric altitude ``alt_m`` (geopotential ≈ geometric here)."""
    return isa(alt_m)[0]


def isa_temperature_k(alt_m: float) -> float:
    return isa(alt_m)[1]


def isa_density_kg_m3(alt_m: float) -> float:
    return isa(alt_m)[2]


@dataclass(frozen=True)
class OutageWindow:
    """GNSS outage over world time ``[start_s, end_s)``: no GNSS sample, ``WorldTick.gnss_outage`` set."""

    start_s: float
    end_s: float


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of white sensor noise (0 = noiseless)."""

    accel_m_s2: float = 0.0
    gyro_rad_s: float = 0.0
    gnss_horizontal_m: float = 0.0
    gnss_vertical_m: float = 0.0
    gnss_velocity_m_s: float = 0.0
    baro_pa: float = 0.0
    mag_t: float = 0.0
    airspeed_pa: float = 0.0
    ports_pa: float = 0.0

    def any(self) -> bool:
        return any(v > 0.0 for v in vars(self).values())


def default_port_names() -> tuple[str, ...]:
    return tuple(f"P{i:02d}" for i in range(10))


@dataclass(frozen=True)
class ScriptedWorldConfig:
    """The script. Home, wind and the magnetic field have no defaults: a scenario chooses them."""

    path: Literal["circle", "figure_eight"]
    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float  # above mean sea level
    size_m: float  # circle radius, or half-length of the figure-eight along north
    ground_speed_m_s: float  # constant horizontal ground speed
    height_m: float  # above home
    wind_ned_m_s: tuple[float, float, float]
    mag_field_ned_t: tuple[float, float, float]  # Earth field at home [T]
    alpha_1g_rad: float = math.radians(4.0)  # angle of attack in 1-g flight
    climb_amplitude_m: float = 0.0  # sinusoidal altitude oscillation
    climb_period_s: float = 60.0
    turn_direction: Literal["cw", "ccw"] = "cw"  # circle: seen from above; the figure-eight has both
    imu_rate_hz: float = 400.0
    gnss_rate_hz: float = 5.0
    baro_rate_hz: float = 50.0
    mag_rate_hz: float = 50.0
    airspeed_rate_hz: float = 50.0
    ports_rate_hz: float = 50.0
    servo_rate_hz: float = 50.0
    gnss_latency_s: float = 0.0  # the sample delivered at t is valid at t − latency
    gnss_outages: tuple[OutageWindow, ...] = ()
    imu_temperature_c: float = 35.0
    gnss_satellites: int = 14
    gnss_hdop: float = 0.7
    gnss_vdop: float = 1.1
    gnss_h_acc_m: float = 0.5
    gnss_v_acc_m: float = 0.8
    gnss_vel_acc_m_s: float = 0.1
    port_names: tuple[str, ...] = field(default_factory=default_port_names)
    noise: SensorNoise = field(default_factory=SensorNoise)

    @property
    def dt_s(self) -> float:
        return 1.0 / self.imu_rate_hz


def port_normals_b(n_ports: int) -> F64Array:
    """Outward unit normals (body FRD) of the taps on the hemispherical nose, in port order.

    P00 at the tip, then rings at 30°, 60°, 90° off the axis, each with taps at the azimuths up, right,
    down, left (10 ports: the tip, two full rings and the top of the 90° ring).
    """
    azimuths = ((0.0, -1.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0))  # (y, z) of up, right, down, left
    normals = [(1.0, 0.0, 0.0)]
    for i in range(n_ports - 1):
        cone = math.radians(min(30.0 * (i // 4 + 1), 90.0))
        y, z = azimuths[i % 4]
        normals.append((math.cos(cone), math.sin(cone) * y, math.sin(cone) * z))
    return np.asarray(normals, dtype=np.float64)


def sphere_cp(cos_gamma: F64Array) -> F64Array:
    """Potential-flow pressure coefficient on a sphere, ``1 − 9/4 sin²γ``; leeward taps hold the minimum."""
    c = np.clip(cos_gamma, 0.0, 1.0)
    return 1.0 - 2.25 * (1.0 - c * c)


@dataclass(frozen=True)
class _Kinematics:
    """Vectorised truth over a block of times."""

    t_s: F64Array  # (n,)
    pos_ned_m: F64Array  # (n, 3)
    v_ned_m_s: F64Array  # (n, 3)
    a_ned_m_s2: F64Array  # (n, 3)
    c_nb: F64Array  # (n, 3, 3)
    alpha_rad: F64Array  # (n,)


class _HorizontalPath:
    """p(φ) with analytic p′, p″ and a constant-ground-speed time law φ(t)."""

    def __init__(self, cfg: ScriptedWorldConfig) -> None:
        self._cfg = cfg
        phi = np.linspace(0.0, 2.0 * math.pi, ARC_TABLE_POINTS)
        speed = np.linalg.norm(self._d1(phi), axis=1)
        # arc length by Simpson's rule on each table interval (midpoint speed evaluated exactly)
        mid = np.linalg.norm(self._d1(0.5 * (phi[1:] + phi[:-1])), axis=1)
        seg = (speed[1:] + 4.0 * mid + speed[:-1]) / 6.0 * np.diff(phi)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        self.period_s = float(arc[-1]) / cfg.ground_speed_m_s
        self._t_table = arc / cfg.ground_speed_m_s
        self._phi_table = phi
        self._phi_rate_table = cfg.ground_speed_m_s / speed

    def _p(self, phi: F64Array) -> F64Array:
        s = self._cfg.size_m
        if self._cfg.path == "circle":
            sign = 1.0 if self._cfg.turn_direction == "cw" else -1.0
            return np.stack([s * np.sin(phi), sign * s * (1.0 - np.cos(phi))], axis=1)
        return np.stack([s * np.sin(phi), 0.5 * s * np.sin(2.0 * phi)], axis=1)

    def _d1(self, phi: F64Array) -> F64Array:
        s = self._cfg.size_m
        if self._cfg.path == "circle":
            sign = 1.0 if self._cfg.turn_direction == "cw" else -1.0
            return np.stack([s * np.cos(phi), sign * s * np.sin(phi)], axis=1)
        return np.stack([s * np.cos(phi), s * np.cos(2.0 * phi)], axis=1)

    def _d2(self, phi: F64Array) -> F64Array:
        s = self._cfg.size_m
        if self._cfg.path == "circle":
            sign = 1.0 if self._cfg.turn_direction == "cw" else -1.0
            return np.stack([-s * np.sin(phi), sign * s * np.cos(phi)], axis=1)
        return np.stack([-s * np.sin(phi), -2.0 * s * np.sin(2.0 * phi)], axis=1)

    def evaluate(self, t_s: F64Array) -> tuple[F64Array, F64Array, F64Array]:
        """Horizontal (n, 2) position, velocity and acceleration (north, east) at times ``t_s``."""
        v = self._cfg.ground_speed_m_s
        cycles = np.floor(t_s / self.period_s)
        tau = t_s - cycles * self.period_s
        # cubic Hermite interpolation of φ(t) with the exact slopes dφ/dt = V/|p′(φ)| at the nodes, so that
        # the analytic velocity below is the time derivative of the position to O(h³)
        i = np.clip(np.searchsorted(self._t_table, tau, side="right") - 1, 0, len(self._t_table) - 2)
        t0, t1 = self._t_table[i], self._t_table[i + 1]
        f0, f1 = self._phi_table[i], self._phi_table[i + 1]
        h = t1 - t0
        m0, m1 = self._phi_rate_table[i] * h, self._phi_rate_table[i + 1] * h
        s = (tau - t0) / h
        s2, s3 = s * s, s * s * s
        phi = (2 * s3 - 3 * s2 + 1) * f0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * f1 + (s3 - s2) * m1
        d1, d2 = self._d1(phi), self._d2(phi)
        norm = np.linalg.norm(d1, axis=1)
        phi_dot = v / norm
        # d/dt φ̇ = −V (p′·p″)/|p′|³ · φ̇
        phi_ddot = -v * np.einsum("ij,ij->i", d1, d2) / norm**3 * phi_dot
        pos = self._p(phi)
        vel = d1 * phi_dot[:, None]
        acc = d2 * (phi_dot**2)[:, None] + d1 * phi_ddot[:, None]
        return pos, vel, acc


class ScriptedWorld:
    """A :class:`~sim.flight.contract.World` flying the scripted path. Deterministic for a given config and rng.

    ``rng`` is required when the config has sensor noise. ``truth_at`` evaluates the noise-free truth at
    any time (tests compare the autopilot's messages with it).
    """

    def __init__(self, config: ScriptedWorldConfig, rng: np.random.Generator | None = None) -> None:
        if config.noise.any() and rng is None:
            raise ValueError("ScriptedWorld: the config has sensor noise, pass an explicit numpy Generator")
        for name in config.port_names:
            if not 0 < len(name) <= PORT_NAME_MAX_CHARS or not name.isascii():
                raise UserInputError(f"port name {name!r}: must be 1..{PORT_NAME_MAX_CHARS} ASCII characters")
        self.config = config
        self.dt_s = config.dt_s
        self.home_lat_deg = config.home_lat_deg
        self.home_lon_deg = config.home_lon_deg
        self.home_alt_m = config.home_alt_m
        self._rng = rng
        self._path = _HorizontalPath(config)
        self._decimation = {
            name: self._steps_per_sample(name, rate)
            for name, rate in (
                ("gnss", config.gnss_rate_hz),
                ("baro", config.baro_rate_hz),
                ("mag", config.mag_rate_hz),
                ("airspeed", config.airspeed_rate_hz),
                ("ports", config.ports_rate_hz),
                ("servos", config.servo_rate_hz),
            )
        }
        self._frame = LocalFrame(config.home_lat_deg, config.home_lon_deg, config.home_alt_m)
        self._wind_ned = np.asarray(config.wind_ned_m_s, dtype=np.float64)
        self._mag_ned = np.asarray(config.mag_field_ned_t, dtype=np.float64)
        self._port_normals_b = port_normals_b(len(config.port_names))
        self._step_index = 0
        self._block: list[VehicleTruth] = []
        self._block_start = 1

    def _steps_per_sample(self, name: str, rate_hz: float) -> int:
        ratio = self.config.imu_rate_hz / rate_hz
        if rate_hz <= 0.0 or abs(ratio - round(ratio)) > 1e-9:
            raise UserInputError(f"{name}_rate_hz = {rate_hz}: must divide imu_rate_hz = {self.config.imu_rate_hz}")
        return round(ratio)

    @property
    def path_period_s(self) -> float:
        """Time to fly the closed path once."""
        return self._path.period_s

    # ----------------------------------------------------------------------------------------- truth
    def _kinematics(self, t_s: F64Array) -> _Kinematics:
        cfg = self.config
        hpos, hvel, hacc = self._path.evaluate(t_s)
        n = len(t_s)
        w = 2.0 * math.pi / cfg.climb_period_s
        amp = cfg.climb_amplitude_m
        height = cfg.height_m + amp * np.sin(w * t_s)
        pos = np.column_stack([hpos, -height])
        vel = np.column_stack([hvel, -amp * w * np.cos(w * t_s)])
        acc = np.column_stack([hacc, amp * w * w * np.sin(w * t_s)])
        f_ned = acc - np.array([0.0, 0.0, GRAVITY_M_S2])
        v_air = vel - self._wind_ned
        x_w = v_air / np.linalg.norm(v_air, axis=1, keepdims=True)
        y_w = np.cross(x_w, f_ned)
        y_w /= np.linalg.norm(y_w, axis=1, keepdims=True)
        z_w = np.cross(x_w, y_w)
        alpha = cfg.alpha_1g_rad * np.linalg.norm(f_ned, axis=1) / GRAVITY_M_S2
        ca, sa = np.cos(alpha)[:, None], np.sin(alpha)[:, None]
        x_b = ca * x_w - sa * z_w
        z_b = sa * x_w + ca * z_w
        c_nb = np.stack([x_b, y_w, z_b], axis=2)  # columns are the body axes in NED
        assert c_nb.shape == (n, 3, 3)
        return _Kinematics(t_s=t_s, pos_ned_m=pos, v_ned_m_s=vel, a_ned_m_s2=acc, c_nb=c_nb, alpha_rad=alpha)

    def _truth_block(self, t_s: F64Array) -> list[VehicleTruth]:
        h = ATTITUDE_DIFF_STEP_S
        k = self._kinematics(t_s)
        c_dot = (self._kinematics(t_s + h).c_nb - self._kinematics(t_s - h).c_nb) / (2.0 * h)
        omega_x = np.einsum("nji,njk->nik", k.c_nb, c_dot)  # Cᵀ Ċ = [ω×]
        omega_b = np.stack([omega_x[:, 2, 1], omega_x[:, 0, 2], omega_x[:, 1, 0]], axis=1)
        q_nb = quat_from_dcm(k.c_nb)
        f_ned = k.a_ned_m_s2 - np.array([0.0, 0.0, GRAVITY_M_S2])
        f_b = np.einsum("nji,nj->ni", k.c_nb, f_ned)
        v_air_b = np.einsum("nji,nj->ni", k.c_nb, k.v_ned_m_s - self._wind_ned)
        tas = np.linalg.norm(v_air_b, axis=1)
        alpha = np.arctan2(v_air_b[:, 2], v_air_b[:, 0])
        beta = np.arcsin(np.clip(v_air_b[:, 1] / tas, -1.0, 1.0))
        lat, lon, alt = self._frame.to_geodetic_array(k.pos_ned_m)
        speed_h = np.linalg.norm(k.v_ned_m_s, axis=1)
        tangential = np.einsum("ni,ni->n", k.a_ned_m_s2, k.v_ned_m_s) / speed_h
        climb_term = GRAVITY_M_S2 * (-k.v_ned_m_s[:, 2]) / speed_h
        throttle = np.clip(0.45 + 0.5 * (tangential + climb_term) / GRAVITY_M_S2, 0.0, 1.0)
        wind = self._wind_ned
        return [
            VehicleTruth(
                t_s=float(t_s[i]),
                lat_deg=float(lat[i]),
                lon_deg=float(lon[i]),
                alt_m=float(alt[i]),
                pos_ned_m=k.pos_ned_m[i],
                v_ned_m_s=k.v_ned_m_s[i],
                q_nb=q_nb[i],
                omega_b_rad_s=omega_b[i],
                specific_force_b_m_s2=f_b[i],
                airspeed_m_s=float(tas[i]),
                alpha_rad=float(alpha[i]),
                beta_rad=float(beta[i]),
                wind_ned_m_s=wind,
                throttle=float(throttle[i]),
            )
            for i in range(len(t_s))
        ]

    def truth_at(self, t_s: float) -> VehicleTruth:
        """The noise-free truth at world time ``t_s``."""
        return self._truth_block(np.array([t_s], dtype=np.float64))[0]

    # --------------------------------------------------------------------------------------- sensors
    def _noise(self, sigma: float, size: int | None = None) -> F64Array:
        if sigma <= 0.0:
            return np.zeros(size or 1, dtype=np.float64)
        assert self._rng is not None  # checked in __init__
        return sigma * self._rng.standard_normal(size or 1)

    def _in_outage(self, t_s: float) -> bool:
        return any(w.start_s <= t_s < w.end_s for w in self.config.gnss_outages)

    def _gnss(self, t_s: float) -> GnssSample:
        cfg = self.config
        t_valid = t_s - cfg.gnss_latency_s
        truth = self.truth_at(t_valid)
        n_h = self._noise(cfg.noise.gnss_horizontal_m, 2)
        n_v = float(self._noise(cfg.noise.gnss_vertical_m)[0])
        lat, lon, _ = self._frame.offset(truth.lat_deg, truth.lon_deg, truth.alt_m, (n_h[0], n_h[1], 0.0))
        return GnssSample(
            t_s=t_valid,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=truth.alt_m + n_v,
            v_ned_m_s=truth.v_ned_m_s + self._noise(cfg.noise.gnss_velocity_m_s, 3),
            fix_type=3,
            satellites=cfg.gnss_satellites,
            hdop=cfg.gnss_hdop,
            vdop=cfg.gnss_vdop,
            h_acc_m=cfg.gnss_h_acc_m,
            v_acc_m=cfg.gnss_v_acc_m,
            vel_acc_m_s=cfg.gnss_vel_acc_m_s,
        )

    @staticmethod
    def _c_nb(q: F64Array) -> F64Array:
        w, x, y, z = q
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )

    def _ports(self, truth: VehicleTruth) -> PortsSample:
        c_nb = self._c_nb(truth.q_nb)
        v_air_b = c_nb.T @ (truth.v_ned_m_s - truth.wind_ned_m_s)
        u = v_air_b / np.linalg.norm(v_air_b)
        q_pa = 0.5 * isa_density_kg_m3(truth.alt_m) * truth.airspeed_m_s**2
        dp = q_pa * sphere_cp(self._port_normals_b @ u)
        dp = dp + self._noise(self.config.noise.ports_pa, len(dp))
        return PortsSample(t_s=truth.t_s, names=self.config.port_names, dp_pa=dp)

    def _servos(self, truth: VehicleTruth) -> ServoSample:
        p = float(truth.omega_b_rad_s[0])
        aileron = 1500.0 + 250.0 * p / 0.5
        elevator = 1500.0 - 250.0 * (truth.alpha_rad - self.config.alpha_1g_rad) / self.config.alpha_1g_rad
        throttle = 1100.0 + 800.0 * truth.throttle
        rudder = 1500.0 + 100.0 * truth.beta_rad
        pwm = np.clip(np.array([aileron, elevator, throttle, rudder]), 1000.0, 2000.0)
        return ServoSample(t_s=truth.t_s, pwm_us=np.round(pwm))

    def _samples_at(self, k: int, truth: VehicleTruth) -> WorldTick:
        cfg = self.config
        t = truth.t_s
        noise = cfg.noise

        def due(name: str) -> bool:
            return k % self._decimation[name] == 0

        imu = ImuSample(
            t_s=t,
            accel_b_m_s2=truth.specific_force_b_m_s2 + self._noise(noise.accel_m_s2, 3),
            gyro_b_rad_s=truth.omega_b_rad_s + self._noise(noise.gyro_rad_s, 3),
            temperature_c=cfg.imu_temperature_c,
        )
        outage = self._in_outage(t)
        gnss = self._gnss(t) if due("gnss") and not outage else None
        air_t_c = isa_temperature_k(truth.alt_m) - 273.15
        baro = None
        if due("baro"):
            p = isa_pressure_pa(truth.alt_m) + float(self._noise(noise.baro_pa)[0])
            baro = BaroSample(t_s=t, pressure_pa=p, temperature_c=air_t_c)
        mag = None
        if due("mag"):
            field_b = self._c_nb(truth.q_nb).T @ self._mag_ned + self._noise(noise.mag_t, 3)
            mag = MagSample(t_s=t, field_b_t=field_b)
        airspeed = None
        if due("airspeed"):
            q_pa = 0.5 * isa_density_kg_m3(truth.alt_m) * truth.airspeed_m_s**2
            airspeed = AirspeedSample(
                t_s=t, dp_pa=q_pa + float(self._noise(noise.airspeed_pa)[0]), temperature_c=air_t_c
            )
        ports = self._ports(truth) if due("ports") else None
        servos = self._servos(truth) if due("servos") else None
        return WorldTick(
            truth=truth,
            imu=imu,
            gnss=gnss,
            baro=baro,
            mag=mag,
            airspeed=airspeed,
            ports=ports,
            servos=servos,
            gnss_outage=outage,
        )

    def step(self) -> WorldTick:
        """Advance one step (the k-th call returns world time k·dt) and return what happened."""
        self._step_index += 1
        k = self._step_index
        offset = k - self._block_start
        if not 0 <= offset < len(self._block):
            self._block_start = k
            t = np.arange(k, k + BLOCK_STEPS, dtype=np.float64) * self.dt_s
            self._block = self._truth_block(t)
            offset = 0
        return self._samples_at(k, self._block[offset])


# ------------------------------------------------------------------------------------------- scenarios
# CMAC, ArduPilot SITL's default home (Canberra Model Aircraft Club); the field is an approximate
# WMM value there (|B| ≈ 57 µT, declination ≈ +12°, inclination ≈ −66°), chosen for plausibility,
# not taken from a magnetic model.
_CMAC = (-35.363261, 149.165230, 584.0)
_CMAC_FIELD_NED_T = (22.7e-6, 4.8e-6, -52.1e-6)


def scenario_names() -> tuple[str, ...]:
    return ("circle", "figure8", "circle_outage", "figure8_outage", "circle_noiseless")


def realistic_noise() -> SensorNoise:
    """Noise of a small-UAV sensor set (MEMS IMU, u-blox class GNSS, MS5611 class baro, MS4525 pitot)."""
    return SensorNoise(
        accel_m_s2=0.05,
        gyro_rad_s=0.003,
        gnss_horizontal_m=0.5,
        gnss_vertical_m=0.8,
        gnss_velocity_m_s=0.05,
        baro_pa=2.0,
        mag_t=0.3e-6,
        airspeed_pa=1.5,
        ports_pa=1.0,
    )


def scenario_config(name: str) -> ScriptedWorldConfig:
    """The named scenario (see ``scenario_names``); ``UserInputError`` for an unknown name."""
    lat, lon, alt = _CMAC
    circle = ScriptedWorldConfig(
        path="circle",
        home_lat_deg=lat,
        home_lon_deg=lon,
        home_alt_m=alt,
        size_m=150.0,
        ground_speed_m_s=22.0,
        height_m=100.0,
        wind_ned_m_s=(3.0, -2.0, 0.0),
        mag_field_ned_t=_CMAC_FIELD_NED_T,
        gnss_latency_s=0.1,
        noise=realistic_noise(),
    )
    figure8 = replace(circle, path="figure_eight", size_m=300.0, climb_amplitude_m=10.0, climb_period_s=40.0)
    outages = (OutageWindow(20.0, 35.0), OutageWindow(80.0, 90.0))
    match name:
        case "circle":
            return circle
        case "circle_noiseless":
            return replace(circle, noise=SensorNoise())
        case "circle_outage":
            return replace(circle, gnss_outages=outages)
        case "figure8":
            return figure8
        case "figure8_outage":
            return replace(figure8, gnss_outages=outages)
        case _:
            raise UserInputError(f"scenario {name!r}: unknown, choose one of {', '.join(scenario_names())}")


def make_scenario_world(name: str, *, seed: int) -> ScriptedWorld:
    """A scripted world for the named scenario, its sensor noise drawn from ``numpy.random.default_rng(seed)``."""
    return ScriptedWorld(scenario_config(name), np.random.default_rng(seed))
