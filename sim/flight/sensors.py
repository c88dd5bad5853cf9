"""Sensor models: IMU, GNSS, barometer, magnetometer, pitot airspeed, pressure ports, servo outputs.

Every sensor class owns its seeded :class:`numpy.random.Generator` (never a shared or global one) and
draws its normal deviates in blocks (one generator call per few thousand samples, which is what keeps
ten minutes of 400 Hz data cheap). Noise parameters come from named grades (``*_GRADES``) that state
their source; installation-specific numbers (IMU vibration, magnetometer hard iron, port tubing lag and
rate) come from the scenario. Sample types are those of :mod:`sim.flight.contract`.

Noise-model conventions:

* White noise of density N [unit/√Hz] sampled at f_s has per-sample σ = N·√f_s, so the Allan
  deviation is N/√τ at short τ (IEEE Std 952 angle/velocity random walk).
* Turn-on bias: drawn once per sensor instance, N(0, σ²).
* Bias instability: a first-order Gauss–Markov process of stationary σ and correlation time T,
  discretised exactly: b ← e^{−Δ/T}·b + σ·√(1 − e^{−2Δ/T})·n, started from its stationary distribution.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import scipy.signal

from sim.flight.contract import (
    AirspeedSample,
    BaroSample,
    GnssSample,
    ImuSample,
    MagSample,
    PortsSample,
    ServoSample,
)
from sim.flight.world_effects import (
    GNSS_ACC_LOG_SIGMA,
    GNSS_ACC_TAU_S,
    GNSS_JITTER_S,
    IMU_PARTS,
    BaroInstallation,
    ImuInstallation,
    MagInstallation,
    PitotInstallation,
)
from vdm_aero._typing import F64Array
from vdm_aero.geodesy import LocalFrame
from vdm_aero.lag import FirstOrderLag

__all__ = [
    "BARO_GRADES",
    "GNSS_GRADES",
    "IMU_GRADES",
    "MAG_GRADES",
    "PITOT_GRADES",
    "PORT_GRADES",
    "BaroGrade",
    "Barometer",
    "Gnss",
    "GnssGlitch",
    "GnssGrade",
    "Imu",
    "ImuGrade",
    "MagGrade",
    "Magnetometer",
    "PitotAirspeed",
    "PitotGrade",
    "PortGrade",
    "PressurePorts",
    "ServoOutputs",
    "TimeWindow",
]

G_M_S2: Final = 9.80665
DEG: Final = math.pi / 180.0
_BLOCK: Final = 4096


def _gauss_markov(rng: np.random.Generator, n: int, sigma: F64Array, decay: F64Array, state: F64Array) -> F64Array:
    """n samples (n, k) of k independent Gauss–Markov processes continuing from ``state`` (k,), updated in place."""
    out = np.empty((n, len(sigma)))
    w = rng.standard_normal((n, len(sigma)))
    for j in range(len(sigma)):
        a = float(decay[j])
        gain = float(sigma[j]) * math.sqrt(max(1.0 - a * a, 0.0))
        out[:, j] = scipy.signal.lfilter([gain], [1.0, -a], w[:, j], zi=[a * float(state[j])])[0]
        state[j] = out[-1, j]
    return out


# ------------------------------------------------------------------------------------------- IMU
@dataclass(frozen=True)
class ImuGrade:
    """Accelerometer and gyroscope error model (SI units; ``*_density`` per √Hz)."""

    name: str
    accel_noise_density_m_s2: float
    accel_turn_on_sigma_m_s2: float
    accel_gm_sigma_m_s2: float
    accel_gm_tau_s: float
    gyro_noise_density_rad_s: float
    gyro_turn_on_sigma_rad_s: float
    gyro_gm_sigma_rad_s: float
    gyro_gm_tau_s: float
    source: str


_UG: Final = 1e-6 * G_M_S2
_MG: Final = 1e-3 * G_M_S2
_DEG_H: Final = DEG / 3600.0
IMU_GRADES: Final = {
    "icm-42688-p": ImuGrade(
        name="icm-42688-p",
        accel_noise_density_m_s2=70.0 * _UG,
        accel_turn_on_sigma_m_s2=20.0 * _MG,
        accel_gm_sigma_m_s2=0.3 * _MG,
        accel_gm_tau_s=200.0,
        gyro_noise_density_rad_s=0.0028 * DEG,
        gyro_turn_on_sigma_rad_s=0.5 * DEG,
        gyro_gm_sigma_rad_s=0.01 * DEG,
        gyro_gm_tau_s=200.0,
        source="TDK InvenSense ICM-42688-P datasheet DS-000347: noise 70 µg/√Hz and 2.8 mdps/√Hz (low-noise mode); "
        "turn-on bias σ = the board-level initial tolerances ±20 mg and ±0.5 °/s; the datasheet gives no bias "
        "instability, so the Gauss–Markov σ is the zero-offset temperature coefficients (0.15 mg/°C, 0.005 °/s/°C) "
        "times a 2 K in-flight temperature excursion, with T = 200 s (assumption)",
    ),
    "laupre-2019": ImuGrade(
        name="laupre-2019",
        accel_noise_density_m_s2=67.0 * _UG,
        accel_turn_on_sigma_m_s2=8.0 * _MG,
        accel_gm_sigma_m_s2=0.15 * _MG,
        accel_gm_tau_s=200.0,
        gyro_noise_density_rad_s=0.005 * DEG,
        gyro_turn_on_sigma_rad_s=720.0 * _DEG_H,
        gyro_gm_sigma_rad_s=31.0 * _DEG_H,
        gyro_gm_tau_s=200.0,
        source="Laupré, Khaghani & Skaloud (2019), MEMS IMU model of their VDM-based navigation study: accel "
        "67 µg/√Hz, bias σ 8 mg, GM 0.15 mg (T = 200 s); gyro 0.005 °/s/√Hz, bias σ 720 °/h, GM 31 °/h (T = 200 s)",
    ),
    "bmi088": ImuGrade(
        name="bmi088",
        accel_noise_density_m_s2=175.0 * _UG,
        accel_turn_on_sigma_m_s2=20.0 * _MG,
        accel_gm_sigma_m_s2=0.4 * _MG,
        accel_gm_tau_s=200.0,
        gyro_noise_density_rad_s=0.014 * DEG,
        gyro_turn_on_sigma_rad_s=1.0 * DEG,
        gyro_gm_sigma_rad_s=0.03 * DEG,
        gyro_gm_tau_s=200.0,
        source="Bosch BMI088 data sheet BST-BMI088-DS000-19, tables 4-5: accel noise 160 (x, y) and 190 (z) µg/√Hz "
        "(175 taken for all axes), zero-g offset 20 mg, gyro noise 0.014 °/s/√Hz, zero-rate offset ±1 °/s; bias "
        "instability as for the ICM-42688-P: the offset tempcos (0.2 mg/K, 0.015 °/s/K) times 2 K, T = 200 s "
        "(assumption)",
    ),
}
"""Named IMU grades."""


class Imu:
    """A 6-axis IMU sampled once per world step (``rate_hz``): ideal specific force and body rates plus
    turn-on bias, Gauss–Markov bias and white noise. The white-noise density is multiplied by
    ``1 + (vibration_multiplier − 1)·throttle`` (motor vibration folded into broadband noise, at its
    installed level at full throttle)."""

    def __init__(
        self,
        grade: ImuGrade,
        rate_hz: float,
        vibration_multiplier: float,
        rng: np.random.Generator,
        installation: ImuInstallation | None = None,
    ) -> None:
        """``installation``: the harsh world's per-airframe errors (sim.flight.world_effects); None = ideal part."""
        if installation is not None and installation.vibration_multiplier is not None:
            vibration_multiplier = installation.vibration_multiplier
        if vibration_multiplier < 1.0:
            raise ValueError(f"vibration_multiplier must be ≥ 1, got {vibration_multiplier}")
        self.grade = grade
        self.rate_hz = rate_hz
        self.vibration_multiplier = vibration_multiplier
        self.rng = rng
        g = grade
        dt = 1.0 / rate_hz
        self._white_sigma = np.array([g.accel_noise_density_m_s2] * 3 + [g.gyro_noise_density_rad_s] * 3) * math.sqrt(
            rate_hz
        )
        self._gm_sigma = np.array([g.accel_gm_sigma_m_s2] * 3 + [g.gyro_gm_sigma_rad_s] * 3)
        self._gm_decay = np.exp(-dt / np.array([g.accel_gm_tau_s] * 3 + [g.gyro_gm_tau_s] * 3))
        self.turn_on_bias = rng.standard_normal(6) * np.array(
            [g.accel_turn_on_sigma_m_s2] * 3 + [g.gyro_turn_on_sigma_rad_s] * 3
        )
        self._gm_state = rng.standard_normal(6) * self._gm_sigma
        self._bias: list[list[float]] = []
        self._white: list[list[float]] = []
        self._i = 0
        self.installation = installation
        self.board_c: float | None = None  # the board's temperature (harsh world: imu-thermal)
        self._board_ref_c = 0.0
        self._dt = dt

    def _refill(self) -> None:
        gm = _gauss_markov(self.rng, _BLOCK, self._gm_sigma, self._gm_decay, self._gm_state)
        self._bias = (gm + self.turn_on_bias).tolist()
        self._white = (self.rng.standard_normal((_BLOCK, 6)) * self._white_sigma).tolist()
        self._i = 0

    def errors(self, throttle: F64Array) -> F64Array:
        """The errors (n, 6) [accel m/s², gyro rad/s] of the next n samples at throttles (n,): what
        :meth:`sample` adds, consumed from the same stream."""
        if self.installation is not None:
            raise ValueError(
                "errors() is the ideal part's additive model; an installed IMU's errors depend on the truth"
            )
        thr = np.asarray(throttle, dtype=np.float64)
        out = np.empty((len(thr), 6))
        for k, t in enumerate(thr):
            if self._i >= len(self._bias):
                self._refill()
            m = 1.0 + (self.vibration_multiplier - 1.0) * float(t)
            b, w = self._bias[self._i], self._white[self._i]
            out[k] = [bj + m * wj for bj, wj in zip(b, w, strict=True)]
            self._i += 1
        return out

    def sample(
        self,
        t_s: float,
        specific_force_b: Sequence[float],
        omega_b: Sequence[float],
        throttle: float,
        temperature_c: float,
    ) -> ImuSample:
        """One measurement of the true specific force [m/s²] and body rates [rad/s] at ``t_s``; the outside
        air's ``temperature_c`` is what the sensor reports unless the board heats it (imu-thermal)."""
        if self.installation is not None:
            return self._sample_installed(t_s, specific_force_b, omega_b, throttle, temperature_c)
        if self._i >= len(self._bias):
            self._refill()
        m = 1.0 + (self.vibration_multiplier - 1.0) * throttle
        b, w = self._bias[self._i], self._white[self._i]
        self._i += 1
        fx, fy, fz = specific_force_b
        p, q, r = omega_b
        return ImuSample(
            t_s=t_s,
            accel_b_m_s2=np.array((fx + b[0] + m * w[0], fy + b[1] + m * w[1], fz + b[2] + m * w[2])),
            gyro_b_rad_s=np.array((p + b[3] + m * w[3], q + b[4] + m * w[4], r + b[5] + m * w[5])),
            temperature_c=temperature_c,
        )

    def _sample_installed(
        self,
        t_s: float,
        specific_force_b: Sequence[float],
        omega_b: Sequence[float],
        throttle: float,
        air_c: float,
    ) -> ImuSample:
        """The harsh world's sample: M·(true) + g-sensitivity + biases (turn-on, Gauss–Markov, thermal)
        + noise, clipped at the ranges; the temperature is the board's."""
        inst = self.installation
        assert inst is not None
        if self._i >= len(self._bias):
            self._refill()
        m = 1.0 + (self.vibration_multiplier - 1.0) * throttle
        b, w = np.asarray(self._bias[self._i]), np.asarray(self._white[self._i])
        self._i += 1
        f = np.asarray(specific_force_b, dtype=np.float64)
        om = np.asarray(omega_b, dtype=np.float64)
        acc = inst.accel_m @ f if inst.accel_m is not None else f.copy()
        gyr = inst.gyro_m @ om if inst.gyro_m is not None else om.copy()
        if inst.gyro_g_sens is not None:
            gyr += inst.gyro_g_sens @ f
        temp_c = air_c
        if inst.thermal is not None:
            if self.board_c is None:
                self.board_c = inst.thermal.start_c(air_c)
                self._board_ref_c = self.board_c  # biases are the turn-on biases at the boot temperature
            else:
                self.board_c = inst.thermal.step(self.board_c, air_c, self._dt)
            temp_c = self.board_c
            dtemp = self.board_c - self._board_ref_c
            if inst.accel_tempco_m_s2_k is not None:
                acc += inst.accel_tempco_m_s2_k * dtemp
            if inst.gyro_tempco_rad_s_k is not None:
                gyr += inst.gyro_tempco_rad_s_k * dtemp
        acc += b[:3] + m * w[:3]
        gyr += b[3:] + m * w[3:]
        if inst.saturate and (part := IMU_PARTS.get(inst.part or self.grade.name)) is not None:
            acc = np.clip(acc, -part.accel_range_m_s2, part.accel_range_m_s2)
            gyr = np.clip(gyr, -part.gyro_range_rad_s, part.gyro_range_rad_s)
        return ImuSample(t_s=t_s, accel_b_m_s2=acc, gyro_b_rad_s=gyr, temperature_c=temp_c)


# ------------------------------------------------------------------------------------------ GNSS
@dataclass(frozen=True)
class GnssGrade:
    """GNSS receiver: output rate [Hz], latency [s], per-axis position error = white + Gauss–Markov
    (horizontal, vertical) [m], velocity white noise [m/s] and the reported constellation figures."""

    name: str
    rate_hz: float
    latency_s: float
    h_white_sigma_m: float
    v_white_sigma_m: float
    h_gm_sigma_m: float
    v_gm_sigma_m: float
    gm_tau_s: float
    h_vel_sigma_m_s: float
    v_vel_sigma_m_s: float
    satellites: int
    hdop: float
    vdop: float
    source: str


GNSS_GRADES: Final = {
    "ublox-neo-m9n": GnssGrade(
        name="ublox-neo-m9n",
        rate_hz=5.0,
        latency_s=0.1,
        h_white_sigma_m=0.5,
        v_white_sigma_m=0.8,
        h_gm_sigma_m=1.6,
        v_gm_sigma_m=2.5,
        gm_tau_s=120.0,
        h_vel_sigma_m_s=0.05,
        v_vel_sigma_m_s=0.08,
        satellites=16,
        hdop=0.8,
        vdop=1.2,
        source="u-blox NEO-M9N data sheet: 2.0 m CEP horizontal (per-axis σ 1.7 m, split into a slow Gauss–Markov "
        "part, T = 120 s, and 0.5 m white), 0.05 m/s velocity; vertical 1.5× horizontal; 100 ms output latency, "
        "16 satellites, HDOP 0.8 (assumptions typical of open sky)",
    ),
}
"""Named GNSS receiver grades."""


@dataclass(frozen=True)
class TimeWindow:
    """[start_s, end_s) of world time."""

    start_s: float
    end_s: float

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


@dataclass(frozen=True)
class GnssGlitch:
    """A scripted position jump: ``offset_ned_m`` added to every fix valid inside the window."""

    window: TimeWindow
    offset_ned_m: tuple[float, float, float]


class Gnss:
    """GNSS fixes at ``grade.rate_hz``: each fix is valid at a multiple of the period and delivered
    ``latency_s`` later. Outage windows drop every fix whose validity or delivery time falls inside one;
    glitch windows shift the position of fixes valid inside them."""

    def __init__(
        self,
        grade: GnssGrade,
        frame: LocalFrame,
        outages: Sequence[TimeWindow],
        glitches: Sequence[GnssGlitch],
        rng: np.random.Generator,
        *,
        true_latency_s: float | None = None,
        varying_accuracy: bool = False,
    ) -> None:
        """``true_latency_s`` (harsh world, gnss-latency): the receiver's real latency; fixes then arrive after
        it (plus jitter) and carry the time an autopilot would log: arrival − the grade's assumed latency.
        ``varying_accuracy`` (gnss-accuracy): the error σ and the reported hAcc follow a slow log-normal
        scale (sim.flight.world_effects.GNSS_ACC_SOURCE)."""
        self.grade = grade
        self.true_latency_s = true_latency_s
        self.varying_accuracy = varying_accuracy
        # the sky's accuracy scale, started from its stationary distribution as every Gauss–Markov process here
        self._acc_log = float(rng.standard_normal()) * GNSS_ACC_LOG_SIGMA if varying_accuracy else 0.0
        self.frame = frame
        self.outages = tuple(outages)
        self.glitches = tuple(glitches)
        self.rng = rng
        g = grade
        self.period_s = 1.0 / g.rate_hz
        self._decay = math.exp(-self.period_s / g.gm_tau_s)
        self._gm_sigma = np.array([g.h_gm_sigma_m, g.h_gm_sigma_m, g.v_gm_sigma_m])
        self._gm = rng.standard_normal(3) * self._gm_sigma
        self._queue: deque[tuple[float, GnssSample | None]] = deque()
        self.h_acc_m = math.hypot(g.h_white_sigma_m, g.h_gm_sigma_m)
        self.v_acc_m = math.hypot(g.v_white_sigma_m, g.v_gm_sigma_m)

    def in_outage(self, t_s: float) -> bool:
        # an explicit loop, not any(generator): this runs every physics step
        for w in self.outages:  # noqa: SIM110
            if w.start_s <= t_s < w.end_s:
                return True
        return False

    def measure(self, t_valid_s: float, pos_ned_m: Sequence[float], v_ned_m_s: Sequence[float]) -> None:
        """Take a fix valid at ``t_valid_s`` (the caller calls this once per period) and queue it."""
        g = self.grade
        # the error processes run whether or not the fix is delivered (the receiver keeps tracking)
        self._gm = self._decay * self._gm + math.sqrt(1.0 - self._decay**2) * self._gm_sigma * self.rng.standard_normal(
            3
        )
        n = self.rng.standard_normal(6)
        scale = 1.0
        if self.varying_accuracy:
            a = math.exp(-self.period_s / GNSS_ACC_TAU_S)
            self._acc_log = a * self._acc_log + math.sqrt(1.0 - a * a) * GNSS_ACC_LOG_SIGMA * float(
                self.rng.standard_normal()
            )
            scale = math.exp(self._acc_log)
        t_deliver = t_valid_s + g.latency_s
        t_stamp = t_valid_s
        if self.true_latency_s is not None:
            t_deliver = t_valid_s + self.true_latency_s + abs(GNSS_JITTER_S * float(self.rng.standard_normal()))
            t_stamp = t_deliver - g.latency_s  # the autopilot's log: arrival less its assumed lag
        if self.in_outage(t_valid_s) or self.in_outage(t_deliver):
            self._queue.append((t_deliver, None))
            return
        pos = np.asarray(pos_ned_m, dtype=np.float64) + self._gm * scale
        pos += n[:3] * np.array([g.h_white_sigma_m, g.h_white_sigma_m, g.v_white_sigma_m]) * scale
        for gl in self.glitches:
            if gl.window.contains(t_valid_s):
                pos += np.asarray(gl.offset_ned_m)
        vel = np.asarray(v_ned_m_s, dtype=np.float64) + n[3:] * np.array(
            [g.h_vel_sigma_m_s, g.h_vel_sigma_m_s, g.v_vel_sigma_m_s]
        )
        lat, lon, alt = self.frame.to_geodetic(float(pos[0]), float(pos[1]), float(pos[2]))
        sample = GnssSample(
            t_s=t_stamp,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            v_ned_m_s=vel,
            fix_type=3,
            satellites=g.satellites,
            hdop=g.hdop,
            vdop=g.vdop,
            h_acc_m=self.h_acc_m * scale,
            v_acc_m=self.v_acc_m * scale,
            vel_acc_m_s=g.h_vel_sigma_m_s,
        )
        self._queue.append((t_deliver, sample))

    def deliver(self, t_s: float) -> GnssSample | None:
        """The newest fix due for delivery at world time ``t_s`` (None when nothing is due)."""
        out = None
        eps = 1e-9
        while self._queue and self._queue[0][0] <= t_s + eps:
            s = self._queue.popleft()[1]
            if s is not None:
                out = s
        return out


# ------------------------------------------------------------------------------------ barometer
@dataclass(frozen=True)
class BaroGrade:
    """Static-pressure sensor: rate [Hz], white noise [Pa], Gauss–Markov drift [Pa] with T [s], resolution [Pa]."""

    name: str
    rate_hz: float
    noise_pa: float
    gm_sigma_pa: float
    gm_tau_s: float
    resolution_pa: float
    source: str


BARO_GRADES: Final = {
    "ms5611": BaroGrade(
        name="ms5611",
        rate_hz=50.0,
        noise_pa=1.2,
        gm_sigma_pa=5.0,
        gm_tau_s=300.0,
        resolution_pa=1.0,
        source="TE MS5611-01BA03 data sheet: RMS resolution 0.012 mbar at OSR 4096 (≈ 9 ms per conversion, 50 Hz "
        "pressure + temperature), output in 0.01 mbar steps; thermal drift as a 5 Pa (≈ 0.4 m) Gauss–Markov, "
        "T = 300 s (assumption)",
    ),
}
"""Named barometer grades."""


class Barometer:
    """Static pressure at the vehicle's altitude plus drift, noise and output resolution."""

    def __init__(
        self, grade: BaroGrade, rng: np.random.Generator, installation: BaroInstallation | None = None
    ) -> None:
        """``installation`` (harsh world, baro-static-error): the static source's position error."""
        self.grade = grade
        self.rng = rng
        self.installation = installation
        self._decay = math.exp(-1.0 / (grade.rate_hz * grade.gm_tau_s))
        self._gm = float(rng.standard_normal()) * grade.gm_sigma_pa

    def sample(
        self, t_s: float, pressure_pa: float, temperature_c: float, qbar_pa: float = 0.0, alpha_rad: float = 0.0
    ) -> BaroSample:
        """Static pressure [Pa]; the dynamic pressure and α matter only with a static-source error."""
        g = self.grade
        n1, n2 = self.rng.standard_normal(2)
        self._gm = self._decay * self._gm + math.sqrt(1.0 - self._decay**2) * g.gm_sigma_pa * float(n1)
        p = pressure_pa + self._gm + g.noise_pa * float(n2)
        if (inst := self.installation) is not None:
            p += qbar_pa * (inst.static_cp + inst.static_cp_per_rad * alpha_rad)
        return BaroSample(
            t_s=t_s, pressure_pa=round(p / g.resolution_pa) * g.resolution_pa, temperature_c=temperature_c
        )


# --------------------------------------------------------------------------------- magnetometer
@dataclass(frozen=True)
class MagGrade:
    """Magnetometer: rate [Hz] and white noise per axis [T]."""

    name: str
    rate_hz: float
    noise_t: float
    source: str


MAG_GRADES: Final = {
    "rm3100": MagGrade(
        name="rm3100",
        rate_hz=50.0,
        noise_t=15e-9,
        source="PNI RM3100 data sheet: 15 nT noise at cycle count 200 (single-axis rate ~440 Hz, three axes at 50 Hz)",
    ),
}
"""Named magnetometer grades."""


class Magnetometer:
    """The Earth field of the scenario rotated into the body, plus the installation's hard-iron offset and noise;
    in the harsh world also soft iron, (I + S)·field, and the motor's field, proportional to throttle."""

    def __init__(
        self,
        grade: MagGrade,
        earth_field_ned_t: F64Array,
        hard_iron_b_t: F64Array,
        rng: np.random.Generator,
        installation: MagInstallation | None = None,
    ) -> None:
        self.grade = grade
        self.earth_field_ned_t = np.asarray(earth_field_ned_t, dtype=np.float64)
        self.hard_iron_b_t = np.asarray(hard_iron_b_t, dtype=np.float64)
        self.rng = rng
        self.installation = installation

    def sample(self, t_s: float, dcm_nb: F64Array, throttle: float = 0.0) -> MagSample:
        """``dcm_nb`` (3, 3) rotates body vectors into NED; ``throttle`` (0…1) sets the motor's field."""
        field = dcm_nb.T @ self.earth_field_ned_t
        if (inst := self.installation) is not None:
            if inst.soft_iron is not None:
                field = field + inst.soft_iron @ field
            if inst.motor_field_b_t is not None:
                field = field + inst.motor_field_b_t * throttle
        b = field + self.hard_iron_b_t + self.grade.noise_t * self.rng.standard_normal(3)
        return MagSample(t_s=t_s, field_b_t=b)


# ------------------------------------------------------------------------------------ airspeed
@dataclass(frozen=True)
class PitotGrade:
    """Differential-pressure airspeed sensor: rate [Hz], noise [Pa], residual offset after the boot-time
    zeroing (turn-on, σ [Pa]) and output resolution [Pa]."""

    name: str
    rate_hz: float
    noise_pa: float
    offset_sigma_pa: float
    resolution_pa: float
    source: str


PITOT_GRADES: Final = {
    "ms4525do-001d": PitotGrade(
        name="ms4525do-001d",
        rate_hz=50.0,
        noise_pa=1.5,
        offset_sigma_pa=2.0,
        resolution_pa=6894.76 * 2.0 / (0.8 * 16383.0),
        source="TE MS4525DO-DS5AI001DP (±1 psi, 14-bit over 10–90 % of the range: 1.05 Pa per count); noise 1.5 Pa "
        "and 2 Pa residual offset after the autopilot's boot-time zeroing (assumptions)",
    ),
}
"""Named pitot-static sensor grades."""


class PitotAirspeed:
    """Pitot-static differential pressure ½ρV² plus offset, noise and resolution. In the harsh world
    (``installation``) the probe's Δp is q̄·(1 + ratio error)·(1 − k·θ²) − q̄·(c0 + cα·α) (θ the flow's angle
    to the probe: total-pressure loss at incidence; c the static source's position error), through the
    tubing's first-order lag."""

    def __init__(
        self, grade: PitotGrade, rng: np.random.Generator, installation: PitotInstallation | None = None
    ) -> None:
        self.grade = grade
        self.rng = rng
        self.offset_pa = float(rng.standard_normal()) * grade.offset_sigma_pa
        self.installation = installation
        self._lag = (
            FirstOrderLag(1.0 / grade.rate_hz, np.array([installation.lag_s]))
            if installation is not None and installation.lag_s > 0.0
            else None
        )

    def probe_dp_pa(self, dynamic_pressure_pa: float, alpha_rad: float, beta_rad: float) -> float:
        """The probe's Δp before the tubing [Pa] (the installed errors; q̄ itself when there are none)."""
        inst = self.installation
        if inst is None:
            return dynamic_pressure_pa
        a, b = alpha_rad - inst.mount_rad[0], beta_rad - inst.mount_rad[1]
        cos_theta = min(math.cos(a) * math.cos(b), 1.0)
        theta2 = math.acos(cos_theta) ** 2
        total = 1.0 - inst.incidence_k * theta2
        static = inst.static_cp + inst.static_cp_per_rad * alpha_rad
        return dynamic_pressure_pa * ((1.0 + inst.ratio_error) * total - static)

    def sample(
        self, t_s: float, dynamic_pressure_pa: float, temperature_c: float, alpha_rad: float = 0.0,
        beta_rad: float = 0.0,
    ) -> AirspeedSample:  # fmt: skip
        g = self.grade
        x = self.probe_dp_pa(dynamic_pressure_pa, alpha_rad, beta_rad)
        if self._lag is not None:
            x = float(self._lag.step(np.array([x]))[0])
        dp = x + self.offset_pa + g.noise_pa * float(self.rng.standard_normal())
        warm = self.installation.temperature_offset_k if self.installation is not None else 0.0
        return AirspeedSample(t_s=t_s, dp_pa=round(dp / g.resolution_pa) * g.resolution_pa,
                              temperature_c=temperature_c + warm)  # fmt: skip


# ------------------------------------------------------------------------------- pressure ports
@dataclass(frozen=True)
class PortGrade:
    """Differential-pressure transducer of a port: full-scale range ±``range_pa``, resolution (quantisation
    step) [Pa], white noise [Pa] and turn-on zero offset σ [Pa]."""

    name: str
    range_pa: float
    resolution_pa: float
    noise_pa: float
    offset_sigma_pa: float
    source: str


PORT_GRADES: Final = {
    "sdp31": PortGrade(
        name="sdp31",
        range_pa=500.0,
        resolution_pa=1.0 / 60.0,
        noise_pa=0.1,
        offset_sigma_pa=0.2,
        source="Sensirion SDP31 data sheet: ±500 Pa, scale factor 60 counts/Pa, zero-point accuracy 0.2 Pa; "
        "0.1 Pa white noise at 50–100 Hz (assumption from the 0.1 % repeatability)",
    ),
}
"""Named pressure-port transducer grades."""


class PressurePorts:
    """Δp = p_port − p_static [Pa] of every port through its tubing (first-order pneumatic lag τ, discretised
    exactly for an input linear between samples), plus zero offset, noise, quantisation and range clipping.
    The lag starts settled on the first sample."""

    def __init__(
        self,
        grade: PortGrade,
        names: Sequence[str],
        rate_hz: float,
        lag_s: float | Sequence[float] | F64Array,
        rng: np.random.Generator,
    ) -> None:
        """``lag_s``: one tubing lag for every port, or one per port (an as-built installation whose tubes
        differ in length) [s]."""
        self.names = tuple(names)
        lag = np.broadcast_to(np.asarray(lag_s, dtype=np.float64), (len(self.names),)).copy()
        if np.any(lag < 0.0):
            raise ValueError(f"lag_s must be ≥ 0, got {lag_s}")
        self.grade = grade
        self.rate_hz = rate_hz
        self.lag_s = lag
        self.rng = rng
        self.offset_pa = rng.standard_normal(len(self.names)) * grade.offset_sigma_pa
        self._tubing = FirstOrderLag(1.0 / rate_hz, lag)  # per port, exact for a first-order hold

    def sample(self, t_s: float, dp_true_pa: F64Array) -> PortsSample:
        x = np.asarray(dp_true_pa, dtype=np.float64)
        y = self._tubing.step(x)
        g = self.grade
        meas = y + self.offset_pa + g.noise_pa * self.rng.standard_normal(len(x))
        meas = np.clip(np.round(meas / g.resolution_pa) * g.resolution_pa, -g.range_pa, g.range_pa)
        return PortsSample(t_s=t_s, names=self.names, dp_pa=meas)


# -------------------------------------------------------------------------------- servo outputs
class ServoOutputs:
    """The autopilot's servo outputs (ArduPlane order: aileron, elevator, throttle, rudder) [µs], reported
    at the control rate with the time they were computed (no noise: they are the autopilot's own numbers)."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz

    def sample(self, t_s: float, pwm_us: F64Array) -> ServoSample:
        return ServoSample(t_s=t_s, pwm_us=np.asarray(pwm_us, dtype=np.float64).copy())
