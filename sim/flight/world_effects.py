"""The harsh world: sensor, installation and Earth effects that real aircraft have and no estimator assumes.

Every effect has a name (:data:`WORLD_EFFECTS`), a physical model and parameter values from a cited source
(the ``source`` next to each value; docs/flight-sim.md lists them all). A scenario switches effects on by
name (``world_effects``); none is on in the shipped scenarios, so ``--world kind`` is today's world, and
``harsh`` (:data:`HARSH`) switches all of them on. Where a source gives a range, the draw is uniform in it.

Draws come in two lifetimes, as on a real fleet:

* **per airframe** (:func:`draw_installation`, from the airframe's own generator): what the build fixes:
  IMU part, its scale factors, misalignment, g-sensitivity and temperature coefficients, the board's
  heater and thermal time constant, the vibration of the mount, the magnetometer's soft iron and motor
  field, the pitot's position error, ratio error after the user's calibration and tubing lag, the static
  source of the barometer, the GNSS receiver's latency;
* **per flight** (inside the sensors, from the flight's seed): turn-on biases, noise, the site's magnetic
  anomaly, the sky's GNSS accuracy.

The estimator side never imports this module: it knows the data sheets (the grade's nominal figures), the
WMM and its own logs, never the draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.errors import SpecError

__all__ = [
    "FLEET_SEED",
    "HARSH",
    "IMU_INSTALLATION_EFFECTS",
    "IMU_PARTS",
    "KIND",
    "WORLD_EFFECTS",
    "BaroInstallation",
    "BoardThermal",
    "ImuInstallation",
    "Installation",
    "MagInstallation",
    "PitotInstallation",
    "check_world_effects",
    "draw_installation",
    "site_field_anomaly_ned_t",
]

DEG: Final = math.pi / 180.0
G_M_S2: Final = 9.80665

WORLD_EFFECTS: Final = {
    "mag-soft-iron": "magnetometer soft iron: a symmetric matrix (I + S) on the body field, residual after calibration",
    "mag-motor": "magnetometer field proportional to motor current (throttle), ArduPilot compass-motor interference",
    "mag-site-field": "the site's true field differs from the WMM by the model's stated uncertainty",
    "imu-grade": "the fleet flies two IMU parts: ICM-42688-P and BMI088 (alternate airframes)",
    "imu-thermal": "board temperature with its own dynamics (heater, warm-up); bias follows it by the tempco",
    "imu-scale-misalignment": "accelerometer and gyro scale-factor errors and cross-axis sensitivity",
    "imu-g-sensitivity": "gyro rate error proportional to specific force (linear-acceleration sensitivity)",
    "imu-vibration": "broadband vibration level drawn per airframe, scaled with throttle",
    "imu-saturation": "accelerometer and gyro range clipping",
    "pitot-ratio": "airspeed ratio error left after the user's calibration",
    "pitot-position": "pitot-static position error varying with incidence and sideslip",
    "pitot-lag": "pneumatic tubing lag of the pitot lines",
    "pitot-temperature": "the airspeed sensor's die reads above the outside air (its dissipation, the avionics bay)",
    "gnss-latency": "receiver latency differs from the autopilot's assumed delay, with jitter",
    "gnss-accuracy": "accuracy varying with the sky (multipath, geometry), reported hAcc following it",
    "baro-static-error": "static-source error of the barometer varying with dynamic pressure and incidence",
    "earth-gravity": "WGS-84 normal gravity with latitude and height (the filters assume g0)",
    "earth-rotation": "Earth rotation: Coriolis on the flight path, Earth rate in the gyros",
    "fleet": "each seed flies one of N as-built airframes drawn from the build tolerances",
}
"""Every harsh-world effect: name → what it is (docs/flight-sim.md gives each source)."""

HARSH: Final = frozenset(WORLD_EFFECTS)
KIND: Final = frozenset[str]()
IMU_INSTALLATION_EFFECTS: Final = frozenset(
    {"imu-grade", "imu-thermal", "imu-scale-misalignment", "imu-g-sensitivity", "imu-vibration", "imu-saturation"}
)
FLEET_SEED: Final = 20261125  # the fleet's generator: airframe k's build is default_rng([FLEET_SEED, k])


def check_world_effects(names: frozenset[str] | set[str] | tuple[str, ...], where: str) -> frozenset[str]:
    bad = sorted(set(names) - set(WORLD_EFFECTS))
    if bad:
        raise SpecError(f"{where}: unknown world effects {bad} (known: {', '.join(WORLD_EFFECTS)})")
    return frozenset(names)


# ------------------------------------------------------------------------------------------- sources
@dataclass(frozen=True)
class ImuPart:
    """The data-sheet tolerances of an IMU part (± ranges: the draw is uniform in them)."""

    name: str
    accel_scale_tol: float  # sensitivity tolerance after the user's accelerometer calibration (fraction)
    gyro_scale_tol: float  # gyro sensitivity tolerance (ArduPilot does not calibrate gyro scale)
    accel_cross_axis: float  # cross-axis sensitivity (fraction)
    gyro_cross_axis: float
    accel_tempco_m_s2_k: float  # zero-g offset change with temperature
    gyro_tempco_rad_s_k: float  # zero-rate offset change with temperature
    gyro_g_sens_rad_s_per_m_s2: float  # linear-acceleration sensitivity of the gyro
    accel_range_m_s2: float  # configured full scale
    gyro_range_rad_s: float
    source: str


IMU_PARTS: Final = {
    "icm-42688-p": ImuPart(
        name="icm-42688-p",
        accel_scale_tol=0.005,
        gyro_scale_tol=0.005,
        accel_cross_axis=0.01,
        gyro_cross_axis=0.0125,
        accel_tempco_m_s2_k=0.15e-3 * G_M_S2,
        gyro_tempco_rad_s_k=0.005 * DEG,
        gyro_g_sens_rad_s_per_m_s2=0.1 * DEG / G_M_S2,
        accel_range_m_s2=16.0 * G_M_S2,
        gyro_range_rad_s=2000.0 * DEG,
        source="TDK ICM-42688-P data sheet DS-000347 rev 1.8, tables 1-2: sensitivity scale-factor tolerance "
        "±0.5 % (gyro and accel; accel taken as after the user's 6-point calibration, which leaves about that), "
        "cross-axis ±1.25 % gyro / ±1 % accel, ZRO tempco ±0.005 °/s/°C, zero-g tempco ±0.15 mg/°C, ranges "
        "±2000 °/s and ±16 g; the sheet states no g-sensitivity: 0.1 °/s/g, the InvenSense MPU-6000 sheet's "
        "linear-acceleration sensitivity (PS-MPU-6000A, table 6.1), is used",
    ),
    "bmi088": ImuPart(
        name="bmi088",
        accel_scale_tol=0.005,
        gyro_scale_tol=0.01,
        accel_cross_axis=0.005,
        gyro_cross_axis=0.01,
        accel_tempco_m_s2_k=0.2e-3 * G_M_S2,
        gyro_tempco_rad_s_k=0.015 * DEG,
        gyro_g_sens_rad_s_per_m_s2=0.1 * DEG / G_M_S2,
        accel_range_m_s2=24.0 * G_M_S2,
        gyro_range_rad_s=2000.0 * DEG,
        source="Bosch BMI088 data sheet BST-BMI088-DS000-19 (rev 1.9), tables 4-5: gyro sensitivity tolerance "
        "±1 %, cross-axis ±1 % (gyro) / ±0.5 % (accel), gyro zero-rate offset tempco ±0.015 °/s/K, accel offset "
        "tempco < 0.2 mg/K, gyro g-sensitivity 0.1 °/s/g (max), ranges ±2000 °/s and ±24 g (ArduPilot's "
        "setting); the sheet gives no accel sensitivity tolerance: ±0.5 % after the user's calibration "
        "(assumption as for the ICM-42688-P)",
    ),
}
"""The IMU parts the fleet flies (data-sheet tolerances)."""

# board heating: ArduPilot BRD_HEAT_TARG (default 45 °C on boards with an IMU heater, e.g. CubeOrange);
# boards without a heater run above the outside air by their electronics' self-heating
HEATER_TARGET_C: Final = 45.0
SELF_HEATING_K: Final = (5.0, 20.0)
THERMAL_TAU_S: Final = (300.0, 1200.0)
THERMAL_SOURCE: Final = (
    "ArduPilot BRD_HEAT_TARG: HAL_IMU_TEMP_DEFAULT 45 °C on Cube boards (hwdef), arming refused more than 5 °C "
    "below it; PX4 SENS_IMU_TEMP 55 °C; unheated boards run above the outside air by their self-heating (5–20 K; "
    "a Matek H743's processor warms its board towards 60 °C); warm-up time constant 5–20 min (assumption: the "
    "ArduPilot airspeed-calibration wiki asks for at least a minute of warm-up, 'preferably longer')"
)
VIBRATION_MULTIPLIER: Final = (1.5, 5.0)
VIBRATION_SOURCE: Final = (
    "broadband noise density × 1.5–5 at full throttle: ArduPilot 'Measuring Vibration' calls VIBE < 30 m/s² "
    "acceptable, and well-mounted planes log 5–15 m/s²; after the IMU's anti-alias filter and the delta-velocity "
    "integration what remains in band is taken as this multiple of the data-sheet density (assumption)"
)
SOFT_IRON_DIAG: Final = 0.03
SOFT_IRON_OFFDIAG: Final = 0.03
SOFT_IRON_SOURCE: Final = (
    "residual soft iron after calibration: ±3 % diagonal and off-diagonal. ArduPilot's CompassCalibrator "
    "accepts a fit whose residual is up to COMPASS_CAL_FIT = 16 mGauss RMS (≈ 3 % of a 500 mGauss field), the "
    "size of the matrix error it can leave; the issue's measurement used 3 %"
)
MOTOR_INTERFERENCE: Final = (0.05, 0.30)
MOTOR_SOURCE: Final = (
    "ArduPilot compass-motor calibration (COMPASS_MOT, 'Compass Motor Interference Compensation' wiki): "
    "interference below 30 % of the Earth field at full throttle is acceptable, 31–60 % grey, above 60 % bad; "
    "drawn 5–30 %, uncompensated (the filters have no throttle term)"
)
WMM_SIGMA_NT: Final = (138.0, 89.0, 165.0)
WMM_SOURCE: Final = (
    "WMM2025 technical report (NOAA NCEI / BGS, 2024), error model: 1σ uncertainty X 138 nT, Y 89 nT, "
    "Z 165 nT (crustal and disturbance fields the main-field model cannot hold)"
)
PITOT_RATIO_ERROR: Final = (-0.04, 0.04)
PITOT_RATIO_SOURCE: Final = (
    "ArduPilot airspeed calibration: ARSPD_RATIO from the in-flight auto-calibration or a GNSS/wind run "
    "settles within a few per cent of the true ratio; drawn ±4 % on Δp (±2 % on airspeed, the issue's figure)"
)
PITOT_STATIC_CP: Final = (-0.02, 0.02)
PITOT_STATIC_CP_PER_RAD: Final = (-0.05, 0.05)
PITOT_INCIDENCE_K_PER_RAD2: Final = (0.05, 0.15)
PITOT_MOUNT_DEG: Final = 2.0
PITOT_POSITION_SOURCE: Final = (
    "Gracey, NASA RP-1046 (1980) and NACA TR-1303 (1957): a pitot-static head's static-source error is a few "
    "per cent of q̄ and changes with incidence; the total-pressure tube reads within 1 % to about ±10–15° "
    "(Δp_t/q̄ = −k·θ², k 0.05–0.15 /rad²); the probe is mounted within ±2° of the body axis"
)
PITOT_TEMPERATURE_OFFSET_K: Final = (0.0, 8.0)
PITOT_TEMPERATURE_SOURCE: Final = (
    "TE MS4525DO data sheet: an 11-bit temperature output (−50…150 °C) from the die of a package mounted in the "
    "fuselage beside the probe; it reads above the outside air by its own dissipation and the avionics bay's "
    "warmth: 0–8 K drawn (assumption). ArduPilot's AP_Baro::get_external_temperature() prefers it to the "
    "board's, which 'tends to read high, often 30 degrees above the actual temperature'"
)
PITOT_LAG_S: Final = (0.005, 0.05)
PITOT_LAG_SOURCE: Final = (
    "pneumatic lag of the pitot lines (Sinclair & Robins, NACA TN 2793, 1952; Whitmore et al., NASA TM-4171, "
    "1990): λ = 128·μ·L·V/(π·d⁴·p) gives 1–2 ms for 0.5–1 m of 1.5 mm tube into the sensor's cavity, plus the "
    "acoustic delay; longer runs, narrower tube and a water trap reach tens of ms: drawn 5–50 ms"
)
GNSS_LATENCY_S: Final = (0.06, 0.18)
GNSS_JITTER_S: Final = 0.01
GNSS_LATENCY_SOURCE: Final = (
    "ArduPilot AP_GPS_UBLOX::get_lag: 120 ms for M8/M9 ('based on flight logs'), 220 ms for older parts; PX4 "
    "EKF2_GPS_DELAY 110 ms; ArduPilot stamps GPS_RAW_INT with the fix's arrival, so an autopilot's log carries "
    "arrival − assumed lag as validity: the true lag is drawn 60–180 ms with 10 ms jitter per fix (serial "
    "link and the receiver's load)"
)
GNSS_ACC_LOG_SIGMA: Final = 0.35
GNSS_ACC_TAU_S: Final = 300.0
GNSS_ACC_SOURCE: Final = (
    "u-blox M9 data sheet: 1.5–2.0 m CEP open sky, several times worse with obstructions and multipath; "
    "modelled as a log-normal scale (σ_ln 0.35, T 300 s) on the error σ that the receiver's hAcc follows"
)
BARO_STATIC_CP: Final = (-0.05, 0.05)
BARO_STATIC_CP_PER_RAD: Final = (-0.2, 0.2)
BARO_STATIC_SOURCE: Final = (
    "a barometer inside the fuselage senses the cabin's static pressure: a position error ΔP/q̄ of a few per "
    "cent changing with incidence (Gracey RP-1046 ch. 12; ArduPilot's EK3/BARO1_WCF_* wind coefficients exist "
    "for this): drawn ±5 % of q̄ and ±0.2 q̄/rad"
)


# ---------------------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class BoardThermal:
    """The autopilot board's temperature: first order towards a target with time constant ``tau_s``.
    Heated: the target is the heater's set point (or above it when the air and electronics are warmer);
    unheated: the outside air plus the electronics' self-heating. ``start_fraction``: how far the board had
    warmed towards its target at the start of the log."""

    heated: bool
    self_heating_k: float
    tau_s: float
    start_fraction: float

    def target_c(self, air_c: float) -> float:
        warm = air_c + self.self_heating_k
        return max(HEATER_TARGET_C, warm) if self.heated else warm

    def start_c(self, air_c: float) -> float:
        return air_c + self.start_fraction * (self.target_c(air_c) - air_c)

    def step(self, board_c: float, air_c: float, dt_s: float) -> float:
        """The temperature ``dt_s`` later (exact for a constant target over the step)."""
        target = self.target_c(air_c)
        return target + (board_c - target) * math.exp(-dt_s / self.tau_s)


@dataclass(frozen=True)
class ImuInstallation:
    """An airframe's IMU: its part, scale-and-misalignment matrices (measured = M·true), gyro g-sensitivity
    [rad/s per m/s²], temperature coefficients of the biases, board thermal model, vibration multiplier and
    whether the ranges clip. ``None`` fields are effects that are off."""

    part: str | None
    accel_m: F64Array | None
    gyro_m: F64Array | None
    gyro_g_sens: F64Array | None
    accel_tempco_m_s2_k: F64Array | None
    gyro_tempco_rad_s_k: F64Array | None
    thermal: BoardThermal | None
    vibration_multiplier: float | None
    saturate: bool


@dataclass(frozen=True)
class MagInstallation:
    """Soft-iron matrix (measured = (I + S)·field) and the motor field at full throttle [T] (body)."""

    soft_iron: F64Array | None
    motor_field_b_t: F64Array | None


@dataclass(frozen=True)
class PitotInstallation:
    """Ratio error on Δp, static-source error Δp_s/q̄ = c0 + cα·α, total-pressure incidence loss k·θ² with
    θ the flow angle to the probe (mounted ``mount_rad`` (pitch, yaw) off the body axis), tubing lag [s], and
    the sensor's temperature reading above the outside air [K]."""

    ratio_error: float
    static_cp: float
    static_cp_per_rad: float
    incidence_k: float
    mount_rad: tuple[float, float]
    lag_s: float
    temperature_offset_k: float = 0.0  # the airspeed sensor's temperature reading above the outside air


@dataclass(frozen=True)
class BaroInstallation:
    """Static-source error of the barometer: ΔP = q̄·(c0 + cα·α) [Pa]."""

    static_cp: float
    static_cp_per_rad: float


@dataclass(frozen=True)
class Installation:
    """Everything one airframe's build fixes about its sensors (effects that are off are ``None``)."""

    imu: ImuInstallation
    mag: MagInstallation
    pitot: PitotInstallation | None
    baro: BaroInstallation | None
    gnss_latency_s: float | None


LEVEL_TRIM_RESIDUAL_RAD: Final = 0.1 * DEG  # the level calibration's own accuracy (assumption: a hand-levelled
# airframe on the bench, the order of ArduPilot's 0.1° arming check on the trim's change)


def _level_trim(accel_m: F64Array, rng: np.random.Generator) -> F64Array:
    """The rotation the level calibration applies. ArduPilot's ``AP_InertialSensor::_calculate_trim`` takes the
    accelerometer's sample with the airframe level on the bench, a = M·(0, 0, −g) (offsets and scales already
    calibrated), and trims pitch = atan2(a_x, |(a_y, a_z)|) and roll = atan2(−a_y, −a_z): the whole gravity
    column of M, its cross-axis terms included, not only the misalignment rotation, so after it the
    accelerometer reads level at rest. A residual of :data:`LEVEL_TRIM_RESIDUAL_RAD` per axis stays; yaw is not
    observable on the bench and stays untrimmed."""
    a = accel_m @ np.array([0.0, 0.0, -1.0])
    trim_roll = math.atan2(-a[1], -a[2])
    trim_pitch = math.atan2(a[0], math.hypot(a[1], a[2]))
    # the rotation (I − [r×]) that turns the measured gravity onto the z axis: r = (−roll, −pitch, 0) trims
    r = np.array([-trim_roll, -trim_pitch, 0.0]) - rng.uniform(-1.0, 1.0, 3) * np.array(
        [LEVEL_TRIM_RESIDUAL_RAD, LEVEL_TRIM_RESIDUAL_RAD, 0.0]
    )
    return np.asarray(np.eye(3) - np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]]))


def _scale_misalignment(rng: np.random.Generator, scale_tol: float, cross: float) -> F64Array:
    m = np.eye(3) + np.diag(rng.uniform(-scale_tol, scale_tol, 3))
    off = rng.uniform(-cross, cross, (3, 3))
    np.fill_diagonal(off, 0.0)
    return np.asarray(m + off)


def draw_installation(effects: frozenset[str], rng: np.random.Generator, *, part_index: int) -> Installation:
    """One airframe's sensor installation, drawn for ``effects``. The draws are made in a fixed order whatever
    is on, so switching one effect off leaves every other draw as it was. ``part_index``: which IMU part the
    airframe carries when ``imu-grade`` is on (the fleet alternates parts)."""
    e = effects
    parts = list(IMU_PARTS)
    part = IMU_PARTS[parts[part_index % len(parts)]] if "imu-grade" in e else IMU_PARTS["icm-42688-p"]
    accel_m = _scale_misalignment(rng, part.accel_scale_tol, part.accel_cross_axis)
    gyro_m = _scale_misalignment(rng, part.gyro_scale_tol, part.gyro_cross_axis)
    # the user's level calibration (ArduPilot AHRS_TRIM_X/Y, part of the accelerometer calibration) rotates
    # both sensors so that the accelerometer reads level when the airframe is level: it removes the roll and
    # pitch part of the accelerometer's misalignment rotation, to within its own accuracy
    level = _level_trim(accel_m, rng)
    accel_m, gyro_m = level @ accel_m, level @ gyro_m
    g_sens = rng.uniform(-1.0, 1.0, (3, 3)) * part.gyro_g_sens_rad_s_per_m_s2
    a_tc = rng.uniform(-1.0, 1.0, 3) * part.accel_tempco_m_s2_k
    g_tc = rng.uniform(-1.0, 1.0, 3) * part.gyro_tempco_rad_s_k
    thermal = BoardThermal(
        heated=bool(rng.integers(2)),
        self_heating_k=float(rng.uniform(*SELF_HEATING_K)),
        tau_s=float(rng.uniform(*THERMAL_TAU_S)),
        start_fraction=float(rng.uniform(0.3, 0.9)),
    )
    vib = float(rng.uniform(*VIBRATION_MULTIPLIER))
    soft = rng.uniform(-SOFT_IRON_OFFDIAG, SOFT_IRON_OFFDIAG, (3, 3))
    soft = 0.5 * (soft + soft.T)
    np.fill_diagonal(soft, rng.uniform(-SOFT_IRON_DIAG, SOFT_IRON_DIAG, 3))
    motor_dir = rng.standard_normal(3)
    motor_dir /= np.linalg.norm(motor_dir)
    motor_frac = float(rng.uniform(*MOTOR_INTERFERENCE))
    pitot = PitotInstallation(
        ratio_error=float(rng.uniform(*PITOT_RATIO_ERROR)),
        static_cp=float(rng.uniform(*PITOT_STATIC_CP)),
        static_cp_per_rad=float(rng.uniform(*PITOT_STATIC_CP_PER_RAD)),
        incidence_k=float(rng.uniform(*PITOT_INCIDENCE_K_PER_RAD2)),
        mount_rad=(
            float(rng.uniform(-1.0, 1.0)) * PITOT_MOUNT_DEG * DEG,
            float(rng.uniform(-1.0, 1.0)) * PITOT_MOUNT_DEG * DEG,
        ),
        lag_s=float(rng.uniform(*PITOT_LAG_S)),
    )
    baro = BaroInstallation(
        static_cp=float(rng.uniform(*BARO_STATIC_CP)), static_cp_per_rad=float(rng.uniform(*BARO_STATIC_CP_PER_RAD))
    )
    latency = float(rng.uniform(*GNSS_LATENCY_S))
    pitot_warm_k = float(rng.uniform(*PITOT_TEMPERATURE_OFFSET_K))  # drawn last: the earlier draws stay as they were
    # the Earth's field magnitude sets the motor field's size: 50 µT, the order of the field anywhere the
    # fleet flies (the interference is a fraction of it by definition)
    motor_field = motor_dir * motor_frac * 50e-6
    on = any(k in e for k in ("pitot-ratio", "pitot-position", "pitot-lag", "pitot-temperature"))
    return Installation(
        imu=ImuInstallation(
            part=part.name if "imu-grade" in e else None,
            accel_m=accel_m if "imu-scale-misalignment" in e else None,
            gyro_m=gyro_m if "imu-scale-misalignment" in e else None,
            gyro_g_sens=g_sens if "imu-g-sensitivity" in e else None,
            accel_tempco_m_s2_k=a_tc if "imu-thermal" in e else None,
            gyro_tempco_rad_s_k=g_tc if "imu-thermal" in e else None,
            thermal=thermal if "imu-thermal" in e else None,
            vibration_multiplier=vib if "imu-vibration" in e else None,
            saturate="imu-saturation" in e,
        ),
        mag=MagInstallation(
            soft_iron=soft if "mag-soft-iron" in e else None,
            motor_field_b_t=motor_field if "mag-motor" in e else None,
        ),
        pitot=PitotInstallation(
            ratio_error=pitot.ratio_error if "pitot-ratio" in e else 0.0,
            static_cp=pitot.static_cp if "pitot-position" in e else 0.0,
            static_cp_per_rad=pitot.static_cp_per_rad if "pitot-position" in e else 0.0,
            incidence_k=pitot.incidence_k if "pitot-position" in e else 0.0,
            mount_rad=pitot.mount_rad if "pitot-position" in e else (0.0, 0.0),
            lag_s=pitot.lag_s if "pitot-lag" in e else 0.0,
            temperature_offset_k=pitot_warm_k if "pitot-temperature" in e else 0.0,
        )
        if on
        else None,
        baro=baro if "baro-static-error" in e else None,
        gnss_latency_s=latency if "gnss-latency" in e else None,
    )


def site_field_anomaly_ned_t(rng: np.random.Generator) -> F64Array:
    """The difference between the site's true field and the WMM [T] (NED), drawn from the WMM error model."""
    return np.asarray(rng.standard_normal(3) * np.array(WMM_SIGMA_NT) * 1e-9)
