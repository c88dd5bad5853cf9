"""The navigation filter: modes, delayed GNSS, gating, outages, fallback and health.

One :class:`NavFilter` per mode; every mode reads the same measurement stream (:mod:`vdm_aero.nav.stream`
for logs, the service for live MAVLink). Calls must come in time order; each takes its time of validity.

* **Delayed GNSS.** A fix arrives after its time of validity. The filter keeps a one-second buffer of its
  nominal position and velocity at every step; the innovation is formed against the buffered state at the
  fix's time of validity and the correction is applied to the current state (Larsen's approximation of
  fusing at the time of validity: exact while Φ ≈ I over the delay; EKF2 instead delays its whole filter
  horizon and runs an output predictor).
* **Gating.** Every update is NIS-gated at the χ² 99.99 % point of its dimension (:data:`GATE_CHI2`).
  GNSS position rejected for :data:`GNSS_RESET_S` seconds in a row while its velocity is accepted resets
  the position to the fix (counted). So does the first fix after an outage when the gate rejects it: the
  dead-reckoned position has drifted beyond its own uncertainty, and the fix wins (EKF2/EKF3 reset to
  GNSS on reacquisition after dead reckoning).
* **Outage.** No GNSS fix for :data:`GNSS_TIMEOUT_S` s: the wind, the magnetometer and baro offsets and the
  model parameters become *considered* states (estimated with GNSS, held without it).
* **Fallback.** A port mode whose ports give no air data (all lost) fuses the pitot and synthetic
  sideslip instead (airspeed dead reckoning) and says so in :meth:`NavFilter.health`.
"""

from __future__ import annotations

import copy
import functools
import math
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass, field, replace
from typing import Any, Concatenate, Final, ParamSpec, TypeVar

import numpy as np

from vdm_aero._typing import BoolArray, F64Array
from vdm_aero.atmosphere import G0_M_S2, density_kg_m3, pressure_altitude_m
from vdm_aero.nav.airdata_fdi import (
    PAIR_MAX_AGE_S,
    WIND_CHANGE_GUST_SIGMAS,
    WIND_RELEARN_S,
    AirDataFdi,
    WindChangeDetector,
    wind_change_threshold_m_s,
)
from vdm_aero.nav.compass_consistency import AidedCompassFit, CompassConsistency
from vdm_aero.nav.contracts import ImuIncrement, Measurement, evaluate_with_jacobian
from vdm_aero.nav.design_fit import StabilityDerivatives
from vdm_aero.nav.engine import EkfEngine, UpdateResult
from vdm_aero.nav.ins import InsProcess, ProcessNoise
from vdm_aero.nav.mag_deviation import MagDeviation
from vdm_aero.nav.measurements import (
    AutopilotAttitude,
    BaroAltitude,
    ClassicForce,
    ForceContext,
    GnssPosition,
    GnssVelocity,
    InsWindowFix,
    MagField,
    MagHeading,
    PitotAirspeed,
    PortAirData,
    PortForce,
    SyntheticSideslip,
)
from vdm_aero.nav.ports_frontend import PortFrame
from vdm_aero.nav.state import AERO_PARAMS, AERO_PRIOR, AERO_SLOT, IDX, N_ERR, NavState
from vdm_aero.rotation import dcm_from_quat, quat_exp, quat_from_euler, quat_log, quat_multiply
from vdm_aero.vehicle import VehicleDescription

__all__ = [
    "ABLATIONS",
    "AP_ATTITUDE_SIGMA_RAD",
    "GATE_CHI2",
    "IMU_DATASHEETS",
    "MODES",
    "SLOW_IMU_HZ",
    "ModeSpec",
    "NavConfig",
    "NavFilter",
    "mode_spec",
    "reads_ports",
]

GATE_CHI2: Final = {1: 15.14, 2: 18.42, 3: 21.11, 6: 27.86}
"""χ² 99.99 % points by measurement dimension (scipy.stats.chi2.ppf(0.9999, k))."""
TURBULENCE_AVERAGE_S: Final = 300.0  # averaging time of the measured turbulence (≈ 20 gust correlation times)
TURBULENCE_SIGMA_BOUNDS_M_S: Final = (0.15, 4.0)  # calm air's air-data noise … severe turbulence
TURBULENCE_AFTER_S: Final = 30.0  # aided time before the turbulence estimate starts (the wind has converged)
GNSS_TIMEOUT_S: Final = 1.0
GNSS_RESET_S: Final = 10.0
GNSS_LOCKOUT_S: Final = 10.0  # every fix rejected this long outside an outage: the pose is wrong, start again
NIS_WINDOW: Final = 1000
PORT_STALE_S: Final = 0.5  # no port frame this long: fallback, as for frames without air data
GAP_COAST_MAX_S: Final = 2.0  # a longer IMU gap with GNSS at hand re-initialises the pose at the next fix
GAP_STEP_S: Final = 0.1  # coasting step through an IMU gap
GAP_INTERPOLATE_MAX_S: Final = 0.5  # a shorter gap is bridged on the rates either side of it, a longer one coasts
GAP_MAX_STEPS: Final = 600  # longer gaps coast in longer steps (the state is a guess by then anyway)
GAP_ACCEL_SIGMA_M_S2: Final = 1.0  # unknown manoeuvre acceleration during a gap (1σ, white) [m/s²/√s]
GAP_RATE_SIGMA_RAD_S: Final = 0.05  # unknown turn-rate change during a gap [rad/s/√s]
# coasting level through a longer gap misses a whole manoeuvre: a survey turn at 20 m/s and 30° of bank is
# g·tan 30° = 5.7 m/s² and 0.28 rad/s, rolled into at up to 1 rad/s; half of each is the 1σ of a manoeuvre held
# through the gap (a ramp in velocity and attitude, not a random walk: a turn does not average out)
COAST_ACCEL_SIGMA_M_S2: Final = 3.0
COAST_RATE_SIGMA_RAD_S: Final = 0.3
BUFFER_S: Final = 1.0
_GnssArgs = tuple[float, float, F64Array, F64Array, float, float]  # NavFilter.gnss's, in order
PENDING_GNSS_MAX: Final = 20  # fixes waiting for the IMU (gnss): 2 s of a 10 Hz receiver, a gap that still coasts
# a measurement (a port frame, a pitot, compass, barometer or autopilot-attitude sample) valid more than this many
# IMU steps after the filter's time arrived in a hole of the IMU stream: it waits for the IMU (_wait_for_imu).
# Within it, it is the usual lag of a measurement behind the step the IMU has not finished yet
AHEAD_OF_IMU_STEPS: Final = 1.5
# The rotation over an IMU hole from the autopilot's ATTITUDE (_fuse_ap_rotation): the autopilot integrated its
# gyro through the hole at full rate, so its attitude's change from the last message before the hole to the first
# after it is the rotation the bridge can only guess. Its error over that span [rad, 1σ per axis]: the gyro offset
# the autopilot has not yet learnt (the filter's own offset σ stands for it) over the span, the gyro's sensitivity
# and cross-axis tolerances (±0.5 % and ±1.25 % in the parts' data sheets, TDK DS-000347 and Bosch
# BST-BMI088-DS000) on the angle turned, and its aiding's corrections meanwhile (assumed: 2 mrad)
AP_ROTATION_SCALE: Final = math.hypot(0.005, 0.0125)
AP_ROTATION_FLOOR_RAD: Final = 0.002
AP_ROTATION_WAIT_S: Final = 0.25  # the others wait this long for it: 2.5 periods of a 10 Hz ATTITUDE
AP_ROTATION_MAX_S: Final = 5.0  # an anchor older than this is not used: the coast was long, the offset's share large


@dataclass(frozen=True)
class ModeSpec:
    """What a mode fuses besides IMU, GNSS, barometer and magnetometer."""

    pitot: bool = False
    sideslip: bool = False
    ports_airdata: bool = False
    force: str | None = None  # "classic", the name of a port aero model ("deim", "deim-nn"), or "best" of those
    fdi: bool = False  # air-data fault detection and isolation (vdm_aero.nav.airdata_fdi)
    # the wind's noise grows with the height rate, and in an outage a wind change the air data agree on is
    # relearnt (the FDI's wind event) instead of held
    wind_relearn: bool = False
    # the magnetometer's soft-iron and motor deviation learnt while GNSS aids (vdm_aero.nav.mag_deviation)
    mag_deviation: bool = False
    # the wind's gradient with height as states (vdm_aero.nav.state): the wind follows a climb or a descent
    wind_gradient: bool = False
    # in an outage the compass corrects the heading only, never the tilt (:meth:`NavFilter.mag`)
    compass_heading_only: bool = False
    # in an outage, the compass's heading alone once its innovation along the field shows a field that changed
    # (vdm_aero.nav.compass_consistency)
    compass_check: bool = False
    # the same, once the throttle is held outside the throttles the swing learnt the motor's field on
    compass_throttle_range: bool = False
    # in an outage the compass at EKF3's σ once its innovations while GNSS aided it, since the swing's correction
    # applies, showed more than its tilt can be held with (vdm_aero.nav.compass_consistency.AidedCompassFit)
    compass_aided_fit: bool = False
    # the gyro's scale and cross-axis errors as states (vdm_aero.nav.state), learnt while GNSS aids through turns
    gyro_m_err: bool = False
    # the accelerometer's scale and cross-axis errors as states (vdm_aero.nav.state), learnt while GNSS aids
    accel_m_err: bool = False
    # the compass's 1σ [µT] when the mode stands for the autopilot's own filter (None: NavConfig.mag_sigma_ut)
    mag_sigma_ut: float | None = None
    # the compass's 1σ [µT] while GNSS aids, when looser than in an outage: with the gyro's scale states, GNSS
    # through the turns is the heading's teacher, and a compass held at 1.5 µT would teach them its residual
    # deviation instead (docs/navigation.md, "The gyro's scale and cross-axis errors")
    mag_sigma_aided_ut: float | None = None
    # a wind event in an outage goes back to the filter before the change and fuses the window again with the
    # wind live (NavFilter._rewind); without it, a free INS from a clone of the pose is fused once it is over
    wind_rewind: bool = False
    description: str = ""

    def force_model(self, available: Collection[str]) -> str | None:
        """The port force model to fuse among those a frame carries (``best``: the calibrated net if there is
        one, else the plain DEIM)."""
        if self.force == "best":
            return next((m for m in ("deim-nn", "deim") if m in available), None)
        return self.force if self.force in available else None


SLOW_STATES: Final = ("bg", "ba", "wind", "bm", "baro", "aero", "gm")
"""The states that outlive a pose: kept through long IMU gaps, autopilot reboots and service restarts. The gyro's
scale and cross-axis errors δM (``gm``) are the part's and its mounting's: a power cycle redraws the turn-on bias,
not them (the data sheets give them a tolerance and a temperature drift, no turn-on repeatability), and they are
learnt only in turns while GNSS aids, minutes that a reboot or a restart must not throw away."""


def slow_index() -> np.ndarray:
    """Error-state indices of :data:`SLOW_STATES`, in order."""
    return np.concatenate([np.arange(IDX[k].start, IDX[k].stop) for k in SLOW_STATES])


def _slow_offsets() -> dict[str, slice]:
    """Where each of :data:`SLOW_STATES` sits in the vector :meth:`NavFilter.slow_states` gives."""
    out, i = {}, 0
    for k in SLOW_STATES:
        n = IDX[k].stop - IDX[k].start
        out[k], i = slice(i, i + n), i + n
    return out


# The side-force bias (AERO_PRIOR's cy_bias: 0.01 for a model from the design data) of the calibrated net: its
# calibration fits the accelerometer's bias jointly with the net from a flight with turns (vdm_aero.calibrate), and
# the y bias's σ it reports (0.006 m/s² on the harsh fleet's four calibrations) is 2e-4 of CY at cruise q̄S/m
# (~30 m/s²); 0.001 leaves five times that for what moves between the calibration flight and this one. The design
# model's 0.01 given to the net was no better on 82 harsh flights, and the gradient's leaned worse (docs/navigation.md,
# "The force model's side-force bias").
CY_BIAS_SIGMA_CALIBRATED: Final = 0.001

# ArduPilot EKF3's compass noise, EK3_MAG_M_NSE (default 0.05 gauss = 5 µT, AP_NavEKF3.cpp MAG_M_NSE_DEFAULT for
# planes and copters alike): the baselines that stand for the autopilot fuse the compass as it does. It is 3.3×
# NavConfig's 1.5 µT, and it is what makes EKF3 tolerate an uncompensated compass: its residual deviation
# (soft iron, the motor's field) is a bias of a few µT that a tighter σ, fused at 10 Hz as if white, turns into
# tilt (docs/navigation.md, "The baselines fuse the compass as EKF3 does")
EKF3_MAG_SIGMA_UT: Final = 5.0

MODES: Final = {
    "ins": ModeSpec(mag_sigma_ut=EKF3_MAG_SIGMA_UT, description="IMU + baro + mag in the outage (no air data)"),
    "airspeed-dr": ModeSpec(
        pitot=True,
        sideslip=True,
        mag_sigma_ut=EKF3_MAG_SIGMA_UT,
        description="EKF3-like: pitot TAS + synthetic β = 0 + held wind, EKF3's compass noise",
    ),
    "ports-airdata": ModeSpec(ports_airdata=True, description="V, α, β from the ports (FADS), no force model"),
    "vdm-classic": ModeSpec(pitot=True, force="classic", description="pitot + polynomial stability derivatives"),
    "vdm-deim": ModeSpec(ports_airdata=True, force="deim", description="port air data + the DEIM force model"),
    "vdm-deim-nn": ModeSpec(ports_airdata=True, force="deim-nn", description="port air data + DEIM + calibrated net"),
    "vdm": ModeSpec(
        pitot=True,
        ports_airdata=True,
        force="best",
        fdi=True,
        wind_relearn=True,
        wind_rewind=True,
        mag_deviation=True,
        wind_gradient=True,
        compass_check=True,
        compass_throttle_range=True,
        compass_aided_fit=True,
        gyro_m_err=True,
        accel_m_err=True,
        mag_sigma_aided_ut=EKF3_MAG_SIGMA_UT,
        description="the product: pitot + port air data + force model, air-data FDI, wind relearnt (the window "
        "before a wind change fused again) with its gradient with height, the gyro's and the accelerometer's "
        "scale and cross-axis errors and the compass "
        "deviation learnt in flight, "
        "the compass at EKF3's σ while GNSS aids, the compass's heading alone in an outage once "
        "its field's strength is off or the throttle is held outside what the deviation was learnt on, and at "
        "EKF3's σ once its innovations while GNSS aided were past what the tilt can be held with",
    ),
}
# The product mode with one part taken away, for the benchmark's ablation table (not offered to serve or
# replay: each answers "does this part earn its place in vdm?")
_VDM: Final = MODES["vdm"]
ABLATIONS: Final = {
    "vdm-no-force": replace(_VDM, force=None, description="ablation: vdm without the force model"),
    "vdm-no-net": replace(_VDM, force="deim",
                          description="ablation: vdm with the DEIM force model alone (no correction net)"),
    "vdm-no-pitot": replace(_VDM, pitot=False, description="ablation: vdm without the pitot"),
    "vdm-no-deviation": replace(_VDM, mag_deviation=False,
                                description="ablation: vdm without the compass deviation learnt in flight"),
    "vdm-no-gyro-scale": replace(_VDM, gyro_m_err=False, mag_sigma_aided_ut=None,
                                 description="ablation: vdm without the gyro's scale and cross-axis error states "
                                 "(and the looser aided compass that goes with them)"),
    "vdm-no-accel-scale": replace(_VDM, accel_m_err=False,
                                  description="ablation: vdm without the accelerometer's scale and cross-axis error "
                                  "states"),
    "vdm-no-rewind": replace(_VDM, wind_rewind=False,
                             description="ablation: vdm whose wind event fuses a free INS from a clone of the pose "
                             "once the change is over, instead of fusing the window before it again"),
    "vdm-no-gradient": replace(_VDM, wind_gradient=False,
                               description="ablation: vdm without the wind's gradient with height (WIND_PSCALE)"),
    # not an ablation but the variant measured against it (docs/navigation.md, "The compass's heading alone")
    "vdm-compass-heading": replace(_VDM, compass_heading_only=True,
                                   description="variant: vdm whose compass gives the heading only in an outage"),
    "vdm-no-throttle-range": replace(_VDM, compass_throttle_range=False,
                                     description="ablation: vdm whose compass keeps its three axes through an "
                                     "outage at throttles its deviation was not learnt on"),
    "vdm-no-aided-fit": replace(_VDM, compass_aided_fit=False,
                                description="ablation: vdm whose compass keeps its σ in an outage whatever its "
                                "innovations while GNSS aided"),
    "vdm-no-compass-check": replace(_VDM, compass_check=False, compass_throttle_range=False,
                                    description="ablation: vdm whose compass keeps its three axes through an outage "
                                    "whatever its field's strength"),
}  # fmt: skip


def mode_spec(mode: str) -> ModeSpec:
    """A navigation mode's or an ablation's spec (ValueError naming the known ones)."""
    spec = MODES.get(mode) or ABLATIONS.get(mode)
    if spec is None:
        raise ValueError(f"unknown navigation mode {mode!r}; known: {', '.join([*MODES, *ABLATIONS])}")
    return spec


def reads_ports(mode: str) -> bool:
    """Whether ``mode`` reads the pressure ports (air data from them or a port force model): only then does a
    run need the port front end, which costs as much as the rest of a filter step."""
    spec = mode_spec(mode)
    return spec.ports_airdata or spec.force in ("deim", "deim-nn")


WIND_PSCALE: Final = 0.5  # wind noise × (1 + WIND_PSCALE·|ḣ|): EKF2/EKF3's WIND_PSCALE (default 0.5 per m/s)
WIND_RELEARN_SIGMA_M_S: Final = (3.0, 3.0, 0.5)  # the wind's σ reset on a wind event: a shear's size (N, E, D)
# the free INS over the wind detector's window (~10 s): its velocity from the filter's own at the window's start
# (σ ~0.3 m/s in an outage), drifting with the horizontal acceleration error of an in-flight-aligned INS (the
# accelerometer bias left after GNSS, ~20 mg turn-on tolerance largely estimated, and a few mrad of tilt·g)
INS_WINDOW_SIGMA_V_M_S: Final = 0.3
INS_WINDOW_SIGMA_P_M: Final = 1.0
INS_WINDOW_ACCEL_M_S2: Final = 0.05
INS_WINDOW_MAX_S: Final = 25.0  # the free INS's longest run (σ_v 1.3 m/s, σ_p 16 m by the figures above)
WIND_SETTLED_M_S: Final = 1.5  # |Δw| over 2 s under this: the change is over (turbulence: ~0.5–1 m/s)
HEADING_DOUBT_S: Final = 30.0  # a magnetometer gated out this recently: no free-INS fix
MAG_LEARN_AFTER_S: Final = 60.0  # the compass swing starts once the aided heading has converged
WIND_STEP_M_S: Final = 6.0  # |Δw| from before the change to its end: a step that stayed (the shear's 10.6 m/s)
# in an outage the pose is cloned this often, so a wind event finds one near its window's start to run the free INS
# from; a clone costs one n × 4 product per IMU step, and the window's start need not be exact
CLONE_EVERY_S: Final = 2.0
_WINDOW_POSE: Final = InsWindowFix(INS_WINDOW_SIGMA_P_M, INS_WINDOW_SIGMA_V_M_S)  # what is cloned: p, v north, east

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _input(method: Callable[Concatenate[NavFilter, _P], _R]) -> Callable[Concatenate[NavFilter, _P], _R]:
    """A sensor input from outside the filter: logged while a wind event could rewind to before it (a call
    from inside the filter, such as a fix released from its queue, is not an input), and a rewind asked for
    while it ran is done once it has returned (:meth:`NavFilter._rewind`)."""
    name = method.__name__

    @functools.wraps(method)
    def wrapper(self: NavFilter, *args: _P.args, **kw: _P.kwargs) -> _R:
        if self._input_depth:
            return method(self, *args, **kw)
        if self._checkpoints and not self._replaying:
            self._input_seq += 1
            kept = tuple(np.array(a) if isinstance(a, np.ndarray) else a for a in args)  # the caller may reuse its
            self._input_log.append((self._input_seq, name, kept, kw))
        self._input_depth = 1
        try:
            return method(self, *args, **kw)
        finally:
            self._input_depth = 0
            if self._rewind_request is not None:
                self._rewind()

    return wrapper


def _barrier(method: Callable[Concatenate[NavFilter, _P], _R]) -> Callable[Concatenate[NavFilter, _P], _R]:
    """A call that changes the filter other than by a sensor's reading (a reboot, a restore): no rewind
    crosses it."""

    @functools.wraps(method)
    def wrapper(self: NavFilter, *args: _P.args, **kw: _P.kwargs) -> _R:
        self._drop_checkpoints()
        return method(self, *args, **kw)

    return wrapper


@dataclass(frozen=True)
class NavConfig:
    """Everything a filter needs that is not a measurement (all from the user: nominal vehicle, WMM field
    at the site, sensor data sheets). Standard deviations in SI units (magnetometer µT)."""

    vehicle: VehicleDescription
    origin_alt_m: float
    mag_field_ned_ut: F64Array
    noise: ProcessNoise = field(default_factory=ProcessNoise)
    filter_rate_hz: float = 50.0
    aiding_rate_hz: float = 10.0
    gnss_latency_s: float = 0.1
    # how well that lag is known: the autopilots assume 110-120 ms for u-blox M8/M9 ("based on flight logs",
    # ArduPilot AP_GPS_UBLOX::get_lag; PX4 EKF2_GPS_DELAY), older parts 220 ms, and the serial link and the
    # receiver's load move it by tens of ms: ±60 ms uniform about the assumed lag, 1σ = 0.06/√3 s. That error
    # is the same for every fix: the prior of a state (``lag``), not noise per fix
    gnss_latency_sigma_s: float = 0.035
    # what moves from fix to fix about it: the receiver's solution time and the autopilot's serial read loop
    # (a u-blox NAV-PVT of 100 bytes takes 26 ms at 38,400 baud; its arrival moves by a fraction of that)
    gnss_jitter_sigma_s: float = 0.015
    gnss_pos_sigma_ne_m: float = 0.7
    gnss_pos_sigma_d_m: float = 1.0
    gnss_vel_sigma_m_s: float = 0.2
    baro_sigma_m: float = 1.0
    mag_sigma_ut: float = 1.5
    # the wind's gradient with height, d(w_N, w_E)/dh [1/s]: a power-law profile w ∝ h^α over open country
    # (Hellmann exponent α 0.1–0.3, Stull 1988) has dw/dh = α·w/h, 0.005–0.025 /s for a 10 m/s wind at 120 m
    wind_gradient_sigma_per_s: float = 0.01
    pitot_sigma_m_s: float = 0.8
    sideslip_sigma: float = 0.1
    force_sigma_m_s2: tuple[float, float, float] = (0.4, 0.4, 1.2)
    # the port force model is fused at this rate, and judged by the FDI at every port frame. Its error is a
    # function of the flight condition (α, β, the rates, the as-built airframe), so successive frames share it;
    # fused as white at the aiding rate (10 Hz) its correlated part was read as the accelerometer's bias, and
    # through the bias as tilt: on the kind world's manoeuvring flights 0.56–0.66° off against a σ of 0.29–0.30°
    # (`vdm-no-force` 0.21°), at 2.5 Hz 0.15° against 0.36° (docs/navigation.md, "The force model fused at the
    # rate its error decorrelates")
    force_fusion_rate_hz: float = 2.5
    classic_force_sigma_m_s2: tuple[float, float, float] = (0.6, 0.6, 2.0)
    airdata_sigma_floor: tuple[float, float, float] = (0.5, 0.02, 0.02)  # turbulence and lag: V, α, β
    # the autopilot's attitude, fused where the IMU is logged too slowly to integrate (None: never): body-axis
    # 1σ. No autopilot states its attitude accuracy; an EKF aided by GNSS holds roll and pitch to ~1° and the
    # heading to a few degrees in flight: 2°, 2°, 5°, and the estimate's errors are correlated in time, which a
    # white σ at 10 Hz overweights, so these are not tighter
    ap_attitude_sigma_rad: tuple[float, float, float] | None = None
    # the IMU is a decimated record of point samples (a ground station's 4 Hz RAW_IMU), each held over its
    # interval: the rate and specific force change in between, unseen (hold_noise below)
    imu_point_samples: bool = False
    # turn-on bias priors: 1.2× the IMU part's board-level initial tolerance (IMU_DATASHEETS)
    gyro_bias_sigma_rad_s: float = math.radians(0.6)
    # the gyro's scale and cross-axis errors δM (1σ, dimensionless): the fleet's parts allow ±0.5–1 % of
    # sensitivity and ±1–1.25 % of cross-axis (TDK DS-000347 tables 1–2, Bosch BST-BMI088-DS000 tables 4–5),
    # uniform within: tolerance/√3 at the larger; the level calibration (ArduPilot AHRS_TRIM) turns the gyro with
    # the accelerometer by up to the latter's ±1 % cross-axis, which adds to the gyro's own off the diagonal
    gyro_scale_sigma: float = 0.01 / math.sqrt(3.0)
    gyro_cross_axis_sigma: float = math.hypot(0.0125, 0.01) / math.sqrt(3.0)
    # the accelerometer's δMa (1σ): ±0.5 % of sensitivity after the user's calibration and ±0.5–1 % of cross-axis
    # (the same tables), uniform within. The level trim moves x's sensitivity to z onto z's to x, so that element
    # can reach twice the tolerance (state.py); the prior stays at the data sheets'
    accel_scale_sigma: float = 0.005 / math.sqrt(3.0)
    accel_cross_axis_sigma: float = 0.01 / math.sqrt(3.0)
    accel_bias_sigma_m_s2: float = 0.25

    @classmethod
    def for_imu(cls, part: str, **kw: Any) -> NavConfig:
        """A config whose bias priors come from the IMU part's data sheet (:data:`IMU_DATASHEETS`)."""
        if part not in IMU_DATASHEETS:
            raise ValueError(f"unknown IMU part {part!r} (known: {', '.join(IMU_DATASHEETS)})")
        gyro, accel = IMU_DATASHEETS[part]
        return cls(gyro_bias_sigma_rad_s=1.2 * gyro, accel_bias_sigma_m_s2=1.2 * accel, **kw)


# what a sample held over its interval misses of a manoeuvring small aircraft: angular acceleration and jerk
# (assumed 1σ: roll-ins of a 2 m aircraft reach several rad/s²; load-factor changes tens of m/s³)
HOLD_ANGULAR_ACCEL_RAD_S2: Final = 2.0
HOLD_JERK_M_S3: Final = 20.0


def _hold_noise(dt_s: float) -> F64Array:
    """Process noise [rad², (m/s)²] of one step integrated from a single held sample: the unseen change over the
    step, ½·(rate of change)·dt² in attitude and velocity."""
    q = np.zeros((N_ERR, N_ERR))
    q[IDX["theta"], IDX["theta"]] = np.eye(3) * (0.5 * HOLD_ANGULAR_ACCEL_RAD_S2 * dt_s**2) ** 2
    q[IDX["v"], IDX["v"]] = np.eye(3) * (0.5 * HOLD_JERK_M_S3 * dt_s**2) ** 2
    return q


AP_ATTITUDE_SIGMA_RAD: Final = (math.radians(2.0), math.radians(2.0), math.radians(5.0))  # NavConfig's note
SLOW_IMU_HZ: Final = 20.0  # an IMU logged slower than this is not integrated alone: the autopilot's attitude helps

IMU_DATASHEETS: Final = {
    # part: (gyro zero-rate offset [rad/s], accel zero-g offset [m/s²]) initial tolerances, board level
    "icm-42688-p": (math.radians(0.5), 0.020 * G0_M_S2),  # TDK DS-000347 rev 1.8, tables 1-2
    "bmi088": (math.radians(1.0), 0.020 * G0_M_S2),  # Bosch BST-BMI088-DS000-19, tables 4-5
    "laupre-2019": (math.radians(0.2), 0.008 * G0_M_S2),  # Laupré, Khaghani & Skaloud (2019)
}
"""What a user reads off the IMU's data sheet for the filter's turn-on bias priors."""


@dataclass
class _Inputs:
    """The latest side information: body rates, specific force, servo state, air density."""

    omega_b: F64Array = field(default_factory=lambda: np.zeros(3))
    f_b: F64Array = field(default_factory=lambda: np.array([0.0, 0.0, -9.80665]))
    controls_rad: F64Array = field(default_factory=lambda: np.zeros(3))
    throttle: float = 0.0
    rho_kg_m3: float = 1.225
    temperature_k: float = 288.15


class AdaptiveNoise:
    """Innovation-based measurement-noise adaptation (covariance matching, Mohamed & Schwarz 1999):
    R = max(R₀, E[yyᵀ] − HPHᵀ) on the diagonal, the expectations as exponential averages over
    ``time_constant`` updates. Used for the model-based measurements (aerodynamic force, port air data),
    whose error on the built aircraft no data sheet states; it adapts only while GNSS aids the filter
    (during an outage the innovations no longer separate model error from drift) and is then held."""

    def __init__(self, time_constant: float = 300.0) -> None:
        self.k = 1.0 / time_constant
        self._yy: dict[str, F64Array] = {}
        self._hph: dict[str, F64Array] = {}

    def observe(self, name: str, y: F64Array, hph_diag: F64Array) -> None:
        if name not in self._yy:
            self._yy[name], self._hph[name] = y * y, hph_diag.copy()
            return
        self._yy[name] += self.k * (y * y - self._yy[name])
        self._hph[name] += self.k * (hph_diag - self._hph[name])

    def covariance(self, name: str, r0: F64Array) -> F64Array:
        if name not in self._yy:
            return r0
        out = r0.copy()
        np.fill_diagonal(out, np.maximum(np.diagonal(r0), self._yy[name] - self._hph[name]))
        return out


_AIR_DATA: Final = frozenset({"pitot", "ports_airdata"})
"""The measurements that observe the air-relative velocity (and so, with GNSS, the wind and its gusts)."""


class TurbulenceIntensity:
    """The gust intensity the filter measures while GNSS and air data aid it.

    A fixed gust model is wrong somewhere. Measured on survey flights (``airspeed-dr``, 60 s outage): in
    still air σ = 0.2 m/s instead of 1.5 cuts the error from 29 m to 6 m; in moderate turbulence σ = 0.3
    instead of 1.5 makes it 83 m instead of 32 m (docs/navigation.md). So the filter measures it: with GNSS
    and air data the total wind is observed and the gust state ĝ is its fast part; E[g²] = E[ĝ²] + P_gg for
    a consistent filter. The second moment is
    averaged over :data:`TURBULENCE_AVERAGE_S` (a running mean until then), horizontally over N and E
    (the turbulence is isotropic there, its axes turn with the course), and held in an outage. It measures
    whatever makes the air-relative velocity wander (air-data model errors too), which is what the gust state
    must absorb."""

    def __init__(self) -> None:
        self.second_moment: F64Array | None = None
        self.seconds = 0.0

    def observe(self, gust_ned: F64Array, p_gust: F64Array, dt_s: float) -> F64Array:
        """One aided step: the gust estimate [m/s] and its variance; returns σ (N, E, D) [m/s]."""
        m2 = gust_ned * gust_ned + p_gust
        m2 = np.array([0.5 * (m2[0] + m2[1])] * 2 + [m2[2]])
        self.seconds += dt_s
        if self.second_moment is None:
            self.second_moment = m2
        else:
            k = dt_s / min(self.seconds, TURBULENCE_AVERAGE_S)
            self.second_moment = self.second_moment + k * (m2 - self.second_moment)
        lo, hi = TURBULENCE_SIGMA_BOUNDS_M_S
        return np.minimum(np.maximum(np.sqrt(self.second_moment), lo), hi)  # np.clip, without its wrapper's cost


class NavFilter:
    """The VDM navigation filter in one mode (module docstring)."""

    def __init__(self, mode: str, config: NavConfig, derivatives: StabilityDerivatives | None = None, *,
                 spec: ModeSpec | None = None) -> None:  # fmt: skip
        """``spec``: a variant of the mode for research (the benchmark's ablations are named modes)."""
        self.spec = spec or mode_spec(mode)
        self.mode = mode
        if self.spec.force == "classic" and derivatives is None:
            raise ValueError("vdm-classic needs the stability derivatives of the design data set")
        self.config = config
        self.derivatives = derivatives
        self.process = InsProcess(config.noise)
        self.x: NavState | None = None
        self.engine: EkfEngine | None = None
        self.t_s = math.nan
        self.inputs = _Inputs()
        # the delayed fixes' past: (t [s], p, v), each less the corrections the state had taken by then (_shift)
        self._buffer: deque[tuple[float, F64Array, F64Array]] = deque(maxlen=round(BUFFER_S * config.filter_rate_hz))
        # the corrections of p and v so far (_correct), as the past takes them: Σ(δp − δv·t_c) and Σδv
        self._shift = np.zeros(6)
        # GNSS fixes valid after the last IMU step, waiting for the IMU to reach them (gnss); their arguments
        self._pending_gnss: deque[_GnssArgs] = deque(maxlen=PENDING_GNSS_MAX)
        # likewise the first of each other kind of measurement that came ahead of the IMU (_wait_for_imu):
        # kind → (t [s], the name of the method that fuses it, its arguments)
        self._pending: dict[str, tuple[float, str, tuple[Any, ...]]] = {}
        self._imu_dt_s = 0.0
        self._imu_resumed_s = -math.inf  # when the IMU last came back from a hole
        # the last autopilot ATTITUDE and the filter's attitude then (t [s], q_ap, q̂), and the one before the IMU's
        # last hole, kept until an ATTITUDE after the hole turns it across (_fuse_ap_rotation)
        self._att_anchor: tuple[float, F64Array, F64Array] | None = None
        self._att_hole: tuple[float, F64Array, F64Array] | None = None
        self._hole_cov: F64Array | None = None  # the covariance the holes since then put in, propagated since
        self._last_gnss_s = -math.inf
        self._pos_rejected_since: float | None = None
        self._all_rejected_since: float | None = None
        self._next_aid: dict[str, float] = {}
        self._last_rejected_s: dict[str, float] = {}
        self._consider = np.zeros(N_ERR, dtype=bool)
        for k in ("wind", "bm", "baro", "gnss", "aero", "lag", "wg", "gm", "am"):
            self._consider[IDX[k]] = True
        self._wind_live = self._consider.copy()
        self._wind_live[IDX["wind"]] = False
        self._wind_live_until_s = -math.inf
        self._anchor_clone_s: float | None = None  # the clone the wind detector's free INS runs from
        # in an outage with the wind held: the whole filter every CLONE_EVERY_S, and the inputs since the oldest,
        # so that a wind event can go back to before the change and fuse the window again with the wind live
        self._checkpoints: deque[tuple[float, int, NavFilter]] = deque()  # (t [s], input sequence, filter)
        self._input_log: deque[tuple[int, str, tuple[Any, ...], dict[str, Any]]] = deque()
        self._input_seq = 0
        self._input_depth = 0
        self._rewind_request: float | None = None
        self._wind_change_seen_m_s = 0.0  # the detector's |Δw| at the last wind event [m/s]
        self._replaying = False
        self._rewound_anchor = False  # the detector's anchor is a rewind's: no free-INS fix at its end
        self._gnss_scale = (1.0, 1.0)  # the GNSS error model's scale from the receiver's accuracy (gnss)
        self.fdi = AirDataFdi() if self.spec.fdi else None
        self.wind_change = WindChangeDetector() if self.spec.wind_relearn else None
        self.mag_deviation = MagDeviation(config.mag_field_ned_ut) if self.spec.mag_deviation else None
        self.compass_check = CompassConsistency() if self.spec.compass_check else None
        self.compass_fit = AidedCompassFit() if self.spec.compass_aided_fit and self.spec.mag_deviation else None
        self._outage_misfit_counted_s = math.nan  # the outage (by its last fix) whose loosened compass was counted
        # with the wind's gradient as states, the wind follows a climb or a descent and its covariance grows
        # through Φ by the height changed times the gradient's σ: what EKF3's WIND_PSCALE stands in for
        if self.spec.wind_relearn and not self.spec.wind_gradient:
            self.process.wind_height_rate_scale = WIND_PSCALE
        if not self.spec.wind_gradient:
            self.process.freeze_wind_gradient()
        if not self.spec.gyro_m_err:
            self.process.freeze_gyro_m_err()
        if not self.spec.accel_m_err:
            self.process.freeze_accel_m_err()
        # (t [s], V [m/s], σ_V [m/s], α [rad], the usable ports' mask as bytes, α inside the airspeed table)
        self._ports_speed: tuple[float, float, float, float, bytes, bool] | None = None
        self.fallback = False
        self.port_health = (0, 0)
        self.counts: dict[str, int] = {}
        self.rejected: dict[str, int] = {}
        self.nis: dict[str, deque[float]] = {}  # the latest NIS_WINDOW per measurement: bounded in a long flight
        self.adaptive = AdaptiveNoise()
        self.turbulence = TurbulenceIntensity()
        self._last_airdata_s = -math.inf
        self._t_init_s = math.nan
        self._carried: tuple[F64Array, F64Array] | None = None
        # the force model the side-force bias was learnt for ("restored": the saved state's, same models)
        self._cy_model: str | None = None
        self._last_port_frame_s = -math.inf
        m = config.vehicle.mass.mass_kg
        self._area_per_mass = config.vehicle.reference.area_m2 / m

    def __deepcopy__(self, memo: dict[int, Any]) -> NavFilter:
        """A branch: its own state, covariance and counters; the same configuration and models."""
        out = copy.copy(self)
        out.x = None if self.x is None else self.x.copy()
        out.engine = copy.deepcopy(self.engine, memo)
        out.inputs = copy.deepcopy(self.inputs, memo)
        out._buffer = copy.deepcopy(self._buffer, memo)
        out._shift = self._shift.copy()
        out._pending_gnss = copy.deepcopy(self._pending_gnss, memo)
        out._pending = copy.deepcopy(self._pending, memo)
        out._next_aid, out._last_rejected_s = dict(self._next_aid), dict(self._last_rejected_s)
        out.counts, out.rejected = dict(self.counts), dict(self.rejected)
        out.nis = {k: deque(v, maxlen=NIS_WINDOW) for k, v in self.nis.items()}
        out.adaptive = copy.deepcopy(self.adaptive, memo)
        out.turbulence = copy.deepcopy(self.turbulence, memo)
        out.process = copy.deepcopy(self.process, memo)  # its gust intensity is the branch's own
        out.fdi = copy.deepcopy(self.fdi, memo)  # the air-data FDI's levels, exclusions and history
        out.wind_change = copy.deepcopy(self.wind_change, memo)
        out.mag_deviation = copy.deepcopy(self.mag_deviation, memo)
        out.compass_check = copy.deepcopy(self.compass_check, memo)
        out.compass_fit = copy.deepcopy(self.compass_fit, memo)
        out._carried = copy.deepcopy(self._carried, memo)
        out._checkpoints = deque((t, k, copy.deepcopy(c, memo)) for t, k, c in self._checkpoints)
        out._input_log = deque(self._input_log)
        return out

    # ------------------------------------------------------------------------------------- status
    @property
    def initialised(self) -> bool:
        return self.x is not None

    @property
    def in_outage(self) -> bool:
        return self.t_s - self._last_gnss_s > GNSS_TIMEOUT_S

    @property
    def P(self) -> F64Array:
        assert self.engine is not None
        return self.engine.P

    def horizontal_sigma_m(self) -> float:
        """1σ horizontal position uncertainty: √(largest eigenvalue of the NE covariance) [m]."""
        p = self.P[0:2, 0:2]
        return float(math.sqrt(max(np.linalg.eigvalsh(p)[-1], 0.0)))

    def health(self) -> dict[str, Any]:
        """Mode, aiding state and counters (the service's status line; the benchmark's report)."""
        lag = IDX["lag"].start
        return {
            "mode": self.mode,
            "initialised": self.initialised,
            "gnss": "outage" if self.in_outage else "aided",
            "fallback": "airspeed-dr (no port air data)" if self.fallback else None,
            "ports_ok": self.port_health[0],
            "ports": self.port_health[1],
            "horizontal_sigma_m": self.horizontal_sigma_m() if self.initialised else math.nan,
            "gust_sigma_m_s": [round(float(v), 3) for v in self.process.gust_sigma_m_s],
            "updates": dict(self.counts),
            "rejected": dict(self.rejected),
            "airdata_excluded": self.fdi.excluded() if self.fdi is not None else [],
            # the compass swing: samples learnt, and whether its correction is applied yet
            "compass_deviation": None if self.mag_deviation is None else {
                "samples": self.mag_deviation.n, "applied": self.mag_deviation.ready},
            # the compass's innovations while aided since then, rms across and along the field [µT], and whether an
            # outage fuses the compass at EKF3's σ for them
            "compass_aided_fit": None if (fit := self.compass_fit) is None or (rms := fit.rms_ut()) is None else {
                "across_rms_ut": round(rms[0], 2), "along_rms_ut": round(rms[1], 2),
                "ekf3_sigma_in_outage": fit.refuted},
            # the wind's change per 100 m of height (N, E) [m/s], as learnt (the modes that carry it)
            "wind_gradient_m_s_per_100m": None if self.x is None or not self.spec.wind_gradient else [
                round(100.0 * float(g), 2) for g in self.x.wind_gradient_ne_per_s],
            # the gyro's scale and cross-axis errors δM [%], row by row, as learnt in the aided turns (the modes that
            # carry them; a slow state, kept across a restart)
            "gyro_scale_misalignment_pct": None if self.x is None or not self.spec.gyro_m_err else [
                round(100.0 * float(m), 2) for m in self.x.gyro_m_err_b.ravel()],
            # the accelerometer's δMa [%], row by row, as learnt while aided (the modes that carry them; not kept
            # across a restart or a dropped pose, unlike the gyro's: learnt again in a few minutes' aided flight)
            "accel_scale_misalignment_pct": None if self.x is None or not self.spec.accel_m_err else [
                round(100.0 * float(m), 2) for m in self.x.accel_m_err_b.ravel()],
            # the receiver's latency the fixes' stamps miss (true − assumed), as learnt in the turns, and its 1σ
            "gnss_lag_error_ms": None if self.x is None else [
                round(1e3 * self.x.gnss_lag_s, 1), round(1e3 * math.sqrt(max(self.P[lag, lag], 0.0)), 1)],
        }  # fmt: skip

    # -------------------------------------------------------------------------------- initialise
    def _active_states(self) -> int:
        """How many of the error states the engine carries: all but the trailing blocks this mode leaves out of
        its dynamics and its measurements (the wind's gradient, the gyro's and the accelerometer's scale states:
        every mode but ``vdm`` and some of its ablations). Those stay at their prior, uncorrelated with the rest,
        and carrying them cost the baselines' steps their time (docs/performance.md, "A state layout per mode")."""
        inert = {"wg": not self.spec.wind_gradient, "gm": not self.spec.gyro_m_err, "am": not self.spec.accel_m_err}
        n = N_ERR
        for block in ("am", "gm", "wg"):  # the layout's last blocks, last first (vdm_aero.nav.state.IDX)
            if not inert[block] or IDX[block].stop != n:
                break
            n = IDX[block].start
        return n

    @_barrier
    def initialise(
        self, t_s: float, p_ned: F64Array, v_ned: F64Array, f_b: F64Array, mag_b_ut: F64Array | None
    ) -> None:
        """Start from a GNSS fix in straight flight: roll and pitch from the specific force (f ≈ −C_bn·g),
        heading from the magnetometer (tilt-compensated) or, without one, the GNSS course."""
        g = float(np.linalg.norm(f_b))
        pitch = math.asin(max(-1.0, min(1.0, float(f_b[0]) / g)))
        roll = math.atan2(-float(f_b[1]), -float(f_b[2]))
        yaw = math.atan2(float(v_ned[1]), float(v_ned[0]))
        if mag_b_ut is not None:
            c_nb0 = dcm_from_quat(quat_from_euler(roll, pitch, 0.0))
            m_lvl = c_nb0 @ mag_b_ut  # the body field levelled (yaw still unknown)
            ref = self.config.mag_field_ned_ut
            yaw = math.atan2(float(ref[1]), float(ref[0])) - math.atan2(float(m_lvl[1]), float(m_lvl[0]))
        q = np.array(quat_from_euler(roll, pitch, yaw))
        v0 = np.array(v_ned, dtype=float)
        v0[~np.isfinite(v0)] = 0.0  # no vertical speed from MAVLink's GPS_RAW_INT: level flight, σ 0.5 m/s
        self.x = NavState(np.array(p_ned, dtype=float), v0, q)
        sig = np.zeros(N_ERR)
        sig[IDX["p"]] = (3.0, 3.0, 5.0)
        sig[IDX["v"]] = 0.5
        sig[IDX["theta"]] = (math.radians(4.0), math.radians(4.0), math.radians(15.0))
        sig[IDX["bg"]] = self.config.gyro_bias_sigma_rad_s
        sig[IDX["ba"]] = self.config.accel_bias_sigma_m_s2
        sig[IDX["wind"]] = (6.0, 6.0, 0.5)
        sig[IDX["bm"]] = 6.0
        sig[IDX["baro"]] = 10.0
        n = self.config.noise
        sig[IDX["gnss"]] = (n.gnss_sigma_ne_m, n.gnss_sigma_ne_m, n.gnss_sigma_d_m)
        sig[IDX["gust"]] = n.gust_sigma_m_s
        sig[IDX["aero"]] = [AERO_PRIOR[k][1] for k in AERO_PARAMS]
        sig[IDX["lag"]] = self.config.gnss_latency_sigma_s
        sig[IDX["wg"]] = self.config.wind_gradient_sigma_per_s  # inert where the mode leaves it out of the dynamics
        sig[IDX["gm"]] = np.where(
            np.eye(3, dtype=bool), self.config.gyro_scale_sigma, self.config.gyro_cross_axis_sigma
        ).ravel()  # likewise
        sig[IDX["am"]] = np.where(
            np.eye(3, dtype=bool), self.config.accel_scale_sigma, self.config.accel_cross_axis_sigma
        )[:, :2].ravel()  # likewise
        self.engine = EkfEngine(np.diag(sig**2), self._active_states())
        self.t_s = t_s
        self._t_init_s = t_s
        self._last_gnss_s = t_s
        self._last_port_frame_s = max(self._last_port_frame_s, t_s)  # frames have PORT_STALE_S to arrive
        self._cy_model = None  # the side-force bias is at its prior again: its model's, at the first fusion
        if self._carried is not None:  # slow states kept through a long IMU gap
            self.restore_slow_states(*self._carried, keep_wind=True)
            self._carried = None

    # ------------------------------------------------------------------------------------ predict
    @_input
    def imu(self, t_s: float, inc: ImuIncrement, temperature_c: float | None = None) -> None:
        """One IMU increment ending at ``t_s`` (``temperature_c``: the outside-air temperature [°C] for the
        density, as :class:`~vdm_aero.nav.driver.NavDriver` picks it)."""
        gap = t_s - inc.dt_s - self.t_s
        if self.x is not None and gap > 2.0 * inc.dt_s:
            self._imu_resumed_s = t_s
            if gap > GAP_COAST_MAX_S and not self.in_outage:
                self._drop_pose(gap)  # GNSS will give a better pose than a long coast: start again from it
            else:
                if self._att_hole is None:  # holes in a row: the anchor before the first of them
                    self._att_hole = self._att_anchor
                self._bridge(gap, inc)
        self.inputs.omega_b = inc.dtheta_b / inc.dt_s
        self.inputs.f_b = inc.dvel_b / inc.dt_s
        self._imu_dt_s = inc.dt_s
        if temperature_c is not None:
            self.inputs.temperature_k = temperature_c + 273.15
        if self.x is None or self.engine is None:
            return
        x = self.x
        phi = self.process.transition(x, inc)
        qd = self.process.noise(x, inc)
        if self.config.imu_point_samples:
            qd = qd + _hold_noise(inc.dt_s)
        v0 = x.v_ned.copy() if self.wind_change is not None else None
        self.process.propagate_inplace(x, inc)
        if self.wind_change is not None and v0 is not None:
            self.wind_change.ins_step(t_s, float(x.v_ned[0] - v0[0]), float(x.v_ned[1] - v0[1]), inc.dt_s)
        self._predict(phi, qd)
        self.t_s = t_s
        self._remember(t_s)
        # no port frames at all (a dead transducer board, a lost script): as bad as frames without air data. Their
        # silence counts from the IMU's return after a hole of its own: a link that lost both lost no ports
        ports_silent_s = t_s - max(self._last_port_frame_s, self._imu_resumed_s)
        if self.uses_ports and ports_silent_s > PORT_STALE_S and not self.fallback:
            self.fallback = True
            self.port_health = (0, self.port_health[1])
            self.counts["ports_stale"] = self.counts.get("ports_stale", 0) + 1
        if not self._awaiting_rotation():  # its pseudo-measurements wait for the rotation as the others do
            self._model_aiding(t_s)
        if not self.in_outage and t_s - self._last_airdata_s < 1.0 and t_s - self._t_init_s > TURBULENCE_AFTER_S:
            p = self.engine.variances()[IDX["gust"]]
            self.process.set_gust_sigma(self.turbulence.observe(x.gust_ned, p, inc.dt_s))
        if self._att_hole is not None and not self._awaiting_rotation():
            self._att_hole, self._hole_cov = None, None  # no ATTITUDE after the hole in time: the rest go on
            self.counts["ap_rotation_missed"] = self.counts.get("ap_rotation_missed", 0) + 1
        self._release_pending()
        self._checkpoint(t_s)

    def _checkpoint(self, t_s: float) -> None:
        """In an outage with the wind held, keep the whole filter every :data:`CLONE_EVERY_S` as far back as a wind
        event's window reaches, and the inputs since the oldest kept (:meth:`_rewind`); otherwise none."""
        wc = self.wind_change
        if wc is None or not self.spec.wind_rewind or self._replaying:
            return
        if not self.in_outage or t_s < self._wind_live_until_s:
            self._drop_checkpoints()
            return
        cps = self._checkpoints
        if cps and t_s - cps[-1][0] < CLONE_EVERY_S - 1e-6:
            return
        while len(cps) > 1 and cps[1][0] <= t_s - wc.window_s - 2.0 * CLONE_EVERY_S:
            cps.popleft()
        while self._input_log and cps and self._input_log[0][0] <= cps[0][1]:
            self._input_log.popleft()
        kept, log = self._checkpoints, self._input_log
        self._checkpoints, self._input_log = deque(), deque()
        try:
            snap = copy.deepcopy(self)
        finally:
            self._checkpoints, self._input_log = kept, log
        kept.append((t_s, self._input_seq, snap))

    def _drop_checkpoints(self) -> None:
        self._checkpoints.clear()
        self._input_log.clear()

    def _rewind(self) -> None:
        """A wind event in an outage: go back to the filter as it was before the window the change was seen in,
        forget the wind there (σ a shear's size) and fuse every input since again with the wind live. Until the
        change was seen, the air data with the old wind pulled the velocity, the position and the attitude by
        the change, and the filter's σ knew nothing of it; fused again with the wind live, the air data move
        the wind, and the INS carries the pose through the window (Bar-Shalom, Li & Kirubarajan 2001, §11.8:
        reprocessing after a detected manoeuvre onset)."""
        t_event, self._rewind_request = self._rewind_request, None
        assert t_event is not None and self.wind_change is not None
        start = t_event - self.wind_change.window_s
        before = [c for c in self._checkpoints if c[0] <= start]
        t0, seq, snap = before[-1] if before else self._checkpoints[0]
        new = copy.deepcopy(snap)
        new._input_depth = 0  # it was taken inside an IMU step
        assert new.engine is not None
        new.engine.reset_states(IDX["wind"], np.diag(np.square(WIND_RELEARN_SIGMA_M_S)))
        new._wind_live_until_s = t_event + WIND_RELEARN_S
        # the change under way is a random walk of the wind whose σ over the detector's window is the change seen
        change = max(self._wind_change_seen_m_s, WIND_STEP_M_S)
        new.process.wind_change_m_s2 = change / math.sqrt(self.wind_change.window_s)
        new._replaying = True
        for k, name, args, kw in self._input_log:
            if k > seq:
                getattr(new, name)(*args, **kw)
        new._replaying = False
        # what happened stays as it happened: the counts (the replay counted the window's fusions again), the
        # events (the wind event itself is the first filter's) and the time
        new.counts = dict(self.counts)
        new.counts["wind_rewound"] = new.counts.get("wind_rewound", 0) + 1
        if new.fdi is not None and self.fdi is not None:
            new.fdi.events = list(self.fdi.events)
            new.fdi.last_wind_event_s = self.fdi.last_wind_event_s
        if new.wind_change is not None:
            new.wind_change.anchor(t0)  # the change's end is still awaited: then the gust hands it to the wind
            new._rewound_anchor = True
        self._drop_checkpoints()
        self.__dict__.update(new.__dict__)

    def _release_pending(self) -> None:
        """Fuse what waited for the IMU (or for the autopilot's rotation across a hole) and may go now."""
        if self._awaiting_rotation():
            kept = self._pending.get("ap_attitude")  # only the ATTITUDE it waits for may go
            if kept is not None and not self._ahead_of_imu(kept[0]):
                del self._pending["ap_attitude"]
                getattr(self, kept[1])(*kept[2])
            return
        while self._pending_gnss and self._pending_gnss[0][0] <= self.t_s + 0.5 / self.config.filter_rate_hz:
            self.gnss(*self._pending_gnss.popleft())
        for kind in list(self._pending) if self._pending else ():
            entry = self._pending.get(kind)  # a method called below may have released it already
            if entry is not None and not self._ahead_of_imu(entry[0]):
                del self._pending[kind]
                getattr(self, entry[1])(*entry[2])  # by name: a branch's copy calls its own method

    def _predict(self, phi: F64Array, qd: F64Array) -> None:
        assert self.engine is not None
        self.engine.predict(phi, qd, self.process.coupled_rows)
        if self._hole_cov is not None:  # everything since the hole's start that the autopilot's rotation measures
            self._hole_cov = phi @ self._hole_cov @ phi.T + qd

    def _ahead_of_imu(self, t_s: float) -> bool:
        return t_s - self.t_s > AHEAD_OF_IMU_STEPS * max(1.0 / self.config.filter_rate_hz, self._imu_dt_s)

    def _awaiting_rotation(self) -> bool:
        """After a hole of the IMU stream with the autopilot's ATTITUDE flowing, every other measurement waits
        (:data:`AP_ROTATION_WAIT_S` at most) for the first ATTITUDE after it: the rotation it gives is an update
        of the error the hole put in only while nothing else has been fused since (_fuse_ap_rotation)."""
        return (self._att_hole is not None and self.config.ap_attitude_sigma_rad is None
                and self.t_s - self._imu_resumed_s <= AP_ROTATION_WAIT_S)  # fmt: skip

    def _wait_for_imu(self, kind: str, t_s: float, method: str, *args: Any) -> bool:
        """Whether a measurement of ``kind`` at ``t_s`` [s] is ahead of the IMU by more than
        :data:`AHEAD_OF_IMU_STEPS`: it arrived in a hole of the IMU stream (a lossy link). Judged then, it would
        meet a state, rates and a specific force the hole's length old: in a turn, metres per second of velocity
        and a tenth of a radian of heading that the air data and the compass would be blamed for (a port or the
        force model excluded, a wind change seen, the compass called biased). The first of its kind waits until
        the IMU, or the hole's bridge, reaches it, and is then fused by ``method``; later ones are dropped
        meanwhile (``<kind>_ahead_of_imu`` in the counts)."""
        if not self._ahead_of_imu(t_s) and (kind == "ap_attitude" or not self._awaiting_rotation()):
            return False
        self._pending.setdefault(kind, (t_s, method, args))
        key = f"{kind}_ahead_of_imu"
        self.counts[key] = self.counts.get(key, 0) + 1
        return True

    def _drop_pose(self, gap_s: float, *, count: bool = True) -> None:
        """An IMU gap longer than GAP_COAST_MAX_S with GNSS at hand: forget the pose (it would be a guess),
        keep the slow states, and initialise again at the next fix as at the start."""
        self._carried = self.slow_states()
        self.x, self.engine = None, None
        self._buffer.clear()
        self._pending_gnss.clear()  # the next fix initialises the pose; those before it are older
        self._pending.clear()
        self._att_anchor = self._att_hole = self._hole_cov = None
        if count:
            self.counts["imu_gaps_reinitialised"] = self.counts.get("imu_gaps_reinitialised", 0) + 1

    @_barrier
    def autopilot_rebooted(self) -> None:
        """The autopilot rebooted in flight: its IMU stopped for a boot of unknown length (the first sample after
        it says only how long it has been up again) and was calibrated anew. With GNSS at hand the pose starts
        again from the next fix, as after a long IMU gap; in an outage it coasts over the gap the clock shows."""
        if self.x is not None and not self.in_outage:
            self._drop_pose(math.nan, count=False)
            self.counts["reboots_reinitialised"] = self.counts.get("reboots_reinitialised", 0) + 1
        self.imu_recalibrated()

    @_barrier
    def imu_recalibrated(self) -> None:
        """The autopilot rebooted: it measured new gyro offsets at boot (ArduPilot INS_GYR_CAL, PX4's
        startup calibration) and a power cycle redraws the IMU's turn-on biases, so the bias estimates no longer
        hold: back to their turn-on σ (the pose's own uncertainty grows over the reboot's gap)."""
        sig = {"bg": self.config.gyro_bias_sigma_rad_s, "ba": self.config.accel_bias_sigma_m_s2}
        if self.engine is not None:
            for k, s in sig.items():
                self.engine.reset_states(IDX[k], np.eye(3) * s**2)
        elif self._carried is not None:
            cov = self._carried[1]
            idx = list(slow_index())
            for k, s in sig.items():
                j = [idx.index(n) for n in range(IDX[k].start, IDX[k].stop)]
                cov[j, :] = 0.0
                cov[:, j] = 0.0
                cov[j, j] = s**2
        self._att_anchor = self._att_hole = self._hole_cov = None  # the autopilot's attitude starts again with it
        self.counts["imu_recalibrated"] = self.counts.get("imu_recalibrated", 0) + 1

    # ------------------------------------------------------------------------------- slow states
    def slow_states(self) -> tuple[F64Array, F64Array]:
        """The slow states (:data:`SLOW_STATES`: biases, wind, offsets, model parameters) and their
        covariance block, in the order of :func:`slow_index`."""
        x = self.x
        assert x is not None and self.engine is not None
        values = np.concatenate(
            [x.b_gyro_b, x.b_accel_b, x.wind_ned, x.b_mag_b_ut, [x.b_baro_m], x.aero, x.gyro_m_err_b.ravel()]
        )
        idx = slow_index()
        return values.astype(np.float64), self.engine.P[np.ix_(idx, idx)].copy()

    @_barrier
    def restore_slow_states(self, values: F64Array, cov: F64Array, *, keep_wind: bool, keep_aero: bool = True,
                            keep_gm: bool = True) -> list[str]:  # fmt: skip
        """Put slow states into an initialised filter, independent of its new pose; returns the names
        restored (the wind only with ``keep_wind``: an old wind is worse than none; the model corrections only
        with ``keep_aero``: they correct the models they were estimated with; the gyro's δM only with
        ``keep_gm``: a filter that did not estimate it holds only its prior)."""
        assert self.x is not None and self.engine is not None
        v = np.asarray(values, dtype=np.float64)
        idx = slow_index()
        at = _slow_offsets()
        x = self.x
        x.b_gyro_b, x.b_accel_b = v[at["bg"]].copy(), v[at["ba"]].copy()
        restored = ["bg", "ba", "bm", "baro"]
        if keep_wind:
            x.wind_ned = v[at["wind"]].copy()
            restored.insert(2, "wind")
        x.b_mag_b_ut, x.b_baro_m = v[at["bm"]].copy(), float(v[at["baro"]][0])
        if keep_aero:
            x.aero = v[at["aero"]].copy()
            restored.append("aero")
            self._cy_model = self._cy_model or "restored"
        if keep_gm:
            x.gyro_m_err_b = v[at["gm"]].reshape(3, 3).copy()
            restored.append("gm")
        p = self.engine.P
        old = p[np.ix_(idx, idx)]

        def block(k: str) -> np.ndarray:
            return np.isin(idx, np.arange(IDX[k].start, IDX[k].stop))

        take = (~block("wind") | keep_wind) & (~block("aero") | keep_aero) & (~block("gm") | keep_gm)
        p[np.ix_(idx, idx)] = np.where(np.outer(take, take), cov, np.where(np.outer(~take, ~take), old, 0.0))
        others = np.setdiff1d(np.arange(p.shape[0]), idx)
        p[np.ix_(idx, others)] = 0.0  # the restored states are independent of the new pose
        p[np.ix_(others, idx)] = 0.0
        self.engine.P = p
        return restored

    def _propagate_bridge(self, step: ImuIncrement, t_s: float) -> None:
        """One step of a gap's bridge ending at ``t_s`` [s]; the wind-change detector's INS takes its velocity
        change as it takes an IMU step's (without it, each hole of a lossy link in a turn reads as a wind change)."""
        assert self.x is not None
        v0 = self.x.v_ned.copy()
        self.process.propagate_inplace(self.x, step)
        if self.wind_change is not None:
            dv = self.x.v_ned - v0
            self.wind_change.ins_step(t_s, float(dv[0]), float(dv[1]), step.dt_s)

    def _bridge(self, gap_s: float, after: ImuIncrement) -> None:
        """No IMU data for ``gap_s`` (a link drop-out, an autopilot stall) before the increment ``after``.

        * **A short gap** (≤ :data:`GAP_INTERPOLATE_MAX_S`: a lossy link's burst, a router's stall) is bridged
          on rates and specific force interpolated linearly from the last increment before it to ``after``, in
          filter steps: a turn goes on turning through it. Coasting level instead reads a 0.2 s hole in a 30°
          banked turn as 0.06 rad of heading and 1.1 m/s of velocity that never happened, several σ of the
          white gap noise, so fixes after it are gated out and the error lands in the wind and the biases. The
          states inside the gap join the delayed-fix buffer, so a fix valid in the gap is fused, not stale.
        * **A longer gap** coasts at constant velocity and attitude (holding or interpolating rates over
          seconds would turn a momentary roll rate into a roll-over), and the buffer starts again after it.

        The covariance takes what the bridge cannot know, so the first fix after it is judged against an honest
        uncertainty, not gated away: the manoeuvres flown meanwhile, white over the gap
        (:data:`GAP_ACCEL_SIGMA_M_S2`, :data:`GAP_RATE_SIGMA_RAD_S`), and, coasting, a whole manoeuvre missed
        (:data:`COAST_ACCEL_SIGMA_M_S2`, :data:`COAST_RATE_SIGMA_RAD_S`, a ramp over the gap). Where the
        autopilot's rotation across the hole will measure it (:meth:`_fuse_ap_rotation`), that noise goes into the
        bridge's steps and is also kept apart; otherwise it is added at the gap's end."""
        assert self.x is not None and self.engine is not None
        if self._att_hole is not None and self._hole_cov is None:  # what the hole puts in, apart (_fuse_ap_rotation)
            self._hole_cov = np.zeros((N_ERR, N_ERR))
        sa, sw = GAP_ACCEL_SIGMA_M_S2, GAP_RATE_SIGMA_RAD_S
        ca, cw = (COAST_ACCEL_SIGMA_M_S2, COAST_RATE_SIGMA_RAD_S) if gap_s > GAP_INTERPOLATE_MAX_S else (0.0, 0.0)
        # what the bridge cannot know, as noise in each of its steps, so that the attitude it leaves uncertain is
        # correlated with the velocity it turned the specific force into: a random walk in velocity and attitude
        # (what interpolation misses) and, coasting, a manoeuvre held through the gap, whose ramp's variance at the
        # gap's end, (c·T)², a walk of intensity c²·T reaches too
        # Without a rotation to come, the noise goes in at the gap's end (the covariance of before: spread over
        # the steps, its share in the velocity made the aided error of tests/test_nav_filter.py's lossy flight 10 %
        # worse, with nothing to measure it by)
        spread = self._hole_cov is not None
        q_gap = np.zeros(N_ERR)
        q_gap[IDX["v"]] = sa**2 + ca**2 * gap_s
        q_gap[IDX["theta"]] = sw**2 + cw**2 * gap_s

        def noise(step: ImuIncrement) -> F64Array:  # the IMU's, and the gap's where it is spread
            qd = self.process.noise(self.x, step)  # type: ignore[arg-type]
            return qd + np.diag(q_gap * step.dt_s) if spread else qd

        if gap_s <= GAP_INTERPOLATE_MAX_S:
            n = max(math.ceil(gap_s / after.dt_s - 1e-9), 1)
            dt = gap_s / n
            w0, f0 = self.inputs.omega_b.copy(), self.inputs.f_b.copy()
            w1, f1 = after.dtheta_b / after.dt_s, after.dvel_b / after.dt_s
            for k in range(n):
                s = (k + 0.5) / n  # the midpoint of the sub-step on the line from before to after the gap
                step = ImuIncrement((w0 + s * (w1 - w0)) * dt, (f0 + s * (f1 - f0)) * dt, dt)
                self._predict(self.process.transition(self.x, step), noise(step))
                self._propagate_bridge(step, self.t_s + (k + 1) * dt)
                self._remember(self.t_s + (k + 1) * dt)
        else:
            n = min(max(math.ceil(gap_s / GAP_STEP_S), 1), GAP_MAX_STEPS)
            dt = gap_s / n
            f_level_b = dcm_from_quat(self.x.q_nb).T @ np.array([0.0, 0.0, -G0_M_S2])
            f_level_b = f_level_b + self.x.accel_m_err_b @ f_level_b + self.x.b_accel_b  # what it reads of −g
            held = ImuIncrement(self.x.b_gyro_b * dt, f_level_b * dt, dt)  # bias-corrected: ω = 0, f = −g
            for _ in range(n):
                self._predict(self.process.transition(self.x, held), noise(held))
                self.process.propagate_inplace(self.x, held)
            self._buffer.clear()  # the delayed-fix buffer holds no coasted guess
        if not spread:
            p = self.engine.P
            for i in range(3):
                iv, ip, ia = IDX["v"].start + i, IDX["p"].start + i, IDX["theta"].start + i
                p[iv, iv] += sa**2 * gap_s
                p[ip, ip] += sa**2 * gap_s**3 / 3.0
                p[ip, iv] += sa**2 * gap_s**2 / 2.0
                p[iv, ip] += sa**2 * gap_s**2 / 2.0
                p[ia, ia] += sw**2 * gap_s
                p[iv, iv] += (ca * gap_s) ** 2
                p[ip, ip] += (ca * gap_s**2 / 2.0) ** 2
                p[ip, iv] += ca**2 * gap_s**3 / 2.0
                p[iv, ip] += ca**2 * gap_s**3 / 2.0
                p[ia, ia] += (cw * gap_s) ** 2
            self.engine.P = p
        if self.wind_change is not None:  # the INS's velocity change over the gap, and the heading the air data turn by
            v_air = float(np.linalg.norm(self.x.v_ned - self.x.wind_ned))
            var_theta = sw**2 * gap_s + (cw * gap_s) ** 2
            self.wind_change.gap(self.t_s + gap_s, sa**2 * gap_s + (ca * gap_s) ** 2 + v_air**2 * var_theta)
        self.t_s += gap_s
        self.counts["imu_gaps"] = self.counts.get("imu_gaps", 0) + 1

    def _model_aiding(self, t_s: float) -> None:
        """The aiding that needs no sensor sample: synthetic sideslip and the state-based force model."""
        ports_out = self.fdi is not None and not self.fdi.fused("ports")  # β from the ports is gone: as fallback
        if (self.spec.sideslip or self.fallback or ports_out) and self._due("sideslip", t_s):
            self._fuse(Measurement(t_s, np.zeros(1), SyntheticSideslip(self.config.sideslip_sigma)))
        if self.spec.force == "classic" and self._due("classic", t_s):
            self._fuse(Measurement(t_s, self.inputs.f_b.copy(), self._classic_force()), adaptive=True)

    # ------------------------------------------------------------------------------------- update
    def _due(self, key: str, t_s: float, rate_hz: float | None = None) -> bool:
        """Whether ``key``'s next aiding is due at ``t_s`` [s] (at ``rate_hz``, by default the aiding rate)."""
        if t_s < self._next_aid.get(key, -math.inf):
            return False
        self._next_aid[key] = t_s + 1.0 / (self.config.aiding_rate_hz if rate_hz is None else rate_hz) - 1e-6
        return True

    def _fuse(
        self,
        meas: Measurement,
        state: NavState | None = None,
        consider: BoolArray | None = None,
        adaptive: bool = False,
        gate: float | None = None,
    ) -> UpdateResult:
        """Fuse one measurement (its innovation against ``state`` when given: the delayed-fusion path;
        ``adaptive``: its noise from :class:`AdaptiveNoise`; ``gate``: the χ² gate, by default the
        measurement dimension's)."""
        assert self.x is not None and self.engine is not None
        model = meas.model
        if state is None:
            z_hat, h = evaluate_with_jacobian(model, self.x)
        else:  # the innovation against the buffered state, the Jacobian at the current one
            z_hat, h = model.evaluate(state), model.jacobian(self.x)
        y = meas.z - z_hat
        dim = len(y)
        if gate is None:
            gate = GATE_CHI2.get(dim, float(dim + 6.0 * math.sqrt(2.0 * dim)))
        if consider is None and self.in_outage:
            consider = self._wind_live if meas.t_s < self._wind_live_until_s else self._consider
        r = model.covariance()
        if adaptive:
            if not self.in_outage:
                self.adaptive.observe(model.name, y, self.engine.projected(h).diagonal())
            r = self.adaptive.covariance(model.name, r)
        dx, res = self.engine.update(y, h, r, gate, consider)
        name = model.name
        self.nis.setdefault(name, deque(maxlen=NIS_WINDOW)).append(res.nis)
        if res.accepted:
            self._correct(dx)
            if state is not None:  # the buffered state takes the same correction: the next measurement of
                state.plus_inplace(dx)  # the same fix (position after velocity) must not count it twice
            self.counts[name] = self.counts.get(name, 0) + 1
            if name in _AIR_DATA:
                self._last_airdata_s = meas.t_s
        else:
            self.rejected[name] = self.rejected.get(name, 0) + 1
            self._last_rejected_s[name] = meas.t_s
        return res

    def _nis(self, meas: Measurement, *, adaptive: bool = False) -> float:
        """A measurement's normalised innovation squared against the current state, without fusing it."""
        assert self.x is not None and self.engine is not None
        model = meas.model
        z_hat, h = evaluate_with_jacobian(model, self.x)
        y = meas.z - z_hat
        r = self.adaptive.covariance(model.name, model.covariance()) if adaptive else model.covariance()
        return self.engine.nis(y, h, r)

    @_input
    def gnss(self, t_valid_s: float, t_s: float, p_ned: F64Array, v_ned: F64Array, h_acc_m: float = math.nan,
             v_acc_m: float = math.nan) -> None:  # fmt: skip
        """A GNSS fix valid at ``t_valid_s`` that arrived at ``t_s`` (local NED position [m], velocity [m/s];
        a NaN vertical velocity fuses the horizontal velocity only), with the receiver's own horizontal and
        vertical accuracy estimates [m] where it reports them (NaN: unknown)."""
        if self.x is None:
            return
        if t_valid_s > self.t_s + 0.5 / self.config.filter_rate_hz or self._awaiting_rotation():
            # valid after the last IMU step: the IMU stream has a hole this fix arrived in (a lossy link, a
            # stalled router). Fused now it would be judged against a state the hole's length old (20 m/s ×
            # 0.3 s = 6 m) and gated out; it waits until the IMU, or the gap's bridge, reaches its time (imu)
            self._pending_gnss.append((t_valid_s, t_s, np.array(p_ned, float), np.array(v_ned, float), h_acc_m,
                                       v_acc_m))  # fmt: skip
            self.counts["gnss_deferred"] = self.counts.get("gnss_deferred", 0) + 1
            return
        self._gnss_accuracy(h_acc_m, v_acc_m)
        if self._buffer and t_valid_s < self._buffer[0][0] - 0.5 / self.config.filter_rate_hz:
            # older than the state buffer reaches back: a stale fix (a link hiccup, a driver repeating its
            # last fix) cannot be fused at its time of validity, and fused now it would pull the position back
            self.rejected["gnss_stale"] = self.rejected.get("gnss_stale", 0) + 1
            return
        c = self.config
        was_outage = self.in_outage
        past = self._buffered(t_valid_s)
        v = np.asarray(v_ned, float)
        horizontal = not math.isfinite(float(v[2]))  # no vertical speed (MAVLink's GPS_RAW_INT)
        # a fix whose time of validity is off by the lag's error reads v·δt off in position, a·δt in velocity:
        # the lag state takes the error common to every fix, the jitter about it is noise of each
        at = past if past is not None else self.x
        a_ned = dcm_from_quat(self.x.q_nb) @ self.inputs.f_b + np.array([0.0, 0.0, G0_M_S2])
        vel_model = GnssVelocity(c.gnss_vel_sigma_m_s, horizontal, c.gnss_jitter_sigma_s * a_ned, a_ned)
        vel = self._fuse(Measurement(t_valid_s, v[:2] if horizontal else v, vel_model), past)
        s_ne, s_d = self._gnss_scale
        pos_model = GnssPosition(c.gnss_pos_sigma_ne_m * s_ne, c.gnss_pos_sigma_d_m * s_d,
                                 c.gnss_jitter_sigma_s * at.v_ned)  # fmt: skip
        pos = self._fuse(
            Measurement(t_valid_s, np.asarray(p_ned, float), pos_model),
            past,
            consider=np.zeros(N_ERR, dtype=bool),
        )
        if pos.accepted or vel.accepted or was_outage:
            self._all_rejected_since = None
        elif self._all_rejected_since is None:
            self._all_rejected_since = t_s
        elif t_s - self._all_rejected_since > GNSS_LOCKOUT_S:
            # position and velocity both rejected for this long with GNSS healthy: the filter's own pose is
            # what is wrong (an autopilot reboot mid-turn, a state restored into another flight), and its
            # confident covariance gates out the fixes that would correct it. Fixes are never locked out for
            # good: forget the pose, keep the slow states, initialise again from this fix
            self.counts["gnss_lockout_reinitialised"] = self.counts.get("gnss_lockout_reinitialised", 0) + 1
            self._all_rejected_since = None
            self._drop_pose(0.0, count=False)
            return
        if pos.accepted:
            self._pos_rejected_since = None
        elif was_outage:  # reacquisition after an outage: the fix wins over the dead-reckoned position
            self._reset_position(np.asarray(p_ned, float))
        elif vel.accepted:
            if self._pos_rejected_since is None:
                self._pos_rejected_since = t_s
            elif t_s - self._pos_rejected_since > GNSS_RESET_S:
                self._reset_position(np.asarray(p_ned, float))
        self._last_gnss_s = t_s

    def _gnss_accuracy(self, h_acc_m: float, v_acc_m: float) -> None:
        """Scale the GNSS error model by the receiver's reported accuracy, as EKF3 does (``FuseVelPosNED``: the
        position noise is the reported hAcc, floored at ``EK3_POSNE_M_NSE``): the scale is the report against
        this model's own total 1σ (white and Gauss–Markov), never below 1. It scales the white noise and the
        Gauss–Markov error's steady state; when it grows, the error's variance grows with it at once (a
        receiver reports a worse sky when its error already is worse), when it shrinks the error decays."""
        c, n = self.config, self.process.noise_densities
        nominal = (
            math.hypot(c.gnss_pos_sigma_ne_m, n.gnss_sigma_ne_m),
            math.hypot(c.gnss_pos_sigma_d_m, n.gnss_sigma_d_m),
        )
        new = tuple(max(a / nom, 1.0) if math.isfinite(a) and a > 0.0 else 1.0
                    for a, nom in zip((h_acc_m, v_acc_m), nominal, strict=True))  # fmt: skip
        if new == self._gnss_scale:
            return
        assert self.engine is not None
        old_ne, old_d = self._gnss_scale
        grow = np.square([n.gnss_sigma_ne_m, n.gnss_sigma_ne_m, n.gnss_sigma_d_m]) * np.clip(
            np.square([new[0], new[0], new[1]]) - np.square([old_ne, old_ne, old_d]), 0.0, None
        )
        if grow.any():
            i = np.arange(N_ERR)[IDX["gnss"]]
            p = self.engine.P
            p[i, i] += grow
            self.engine.P = p
        self._gnss_scale = (float(new[0]), float(new[1]))
        self.process.set_gnss_scale(*self._gnss_scale)

    def _reset_position(self, p_ned: F64Array) -> None:
        assert self.x is not None and self.engine is not None
        p_new = p_ned - self.x.b_gnss_ned
        self._shift[:3] += p_new - self.x.p_ned  # the buffered past moves with it (_correct)
        self.x.p_ned = p_new
        self.engine.reset_states(
            IDX["p"], np.diag([self.config.gnss_pos_sigma_ne_m**2] * 2 + [self.config.gnss_pos_sigma_d_m**2])
        )
        self.counts["gnss_position_reset"] = self.counts.get("gnss_position_reset", 0) + 1
        self._pos_rejected_since = None

    def _correct(self, dx: F64Array) -> None:
        """x ← x ⊕ δx, an update's correction, which the delayed fixes' buffered past takes too: the error it
        removes was the past's as well (the errors change little over the buffer's second). A fix judged against
        a past without it counts it twice: after a hole of the IMU stream whose rotation (_fuse_ap_rotation) put
        2.2 m/s back into the velocity, the next GNSS fix, valid in the hole, pulled the velocity on by as much
        again, and the fixes after it were gated out for a second (docs/navigation.md, "A lossy link")."""
        assert self.x is not None
        self.x.plus_inplace(dx)
        # a past state at t_k takes δv and δp − δv·(t_c − t_k): the velocity's error was its error then too
        t_c = self.t_s if math.isfinite(self.t_s) else 0.0  # before the first IMU step nothing is buffered
        self._shift[:3] += dx[IDX["p"]] - dx[IDX["v"]] * t_c
        self._shift[3:] += dx[IDX["v"]]
        if self._att_anchor is not None and self._att_hole is None:  # the anchor takes what its state takes
            t_a, q_ap_a, q_hat_a = self._att_anchor
            self._att_anchor = (t_a, q_ap_a, quat_multiply(q_hat_a, quat_exp(dx[IDX["theta"]])))

    def _remember(self, t_s: float) -> None:
        """Buffer the position and velocity at ``t_s`` [s] for the delayed fixes (:meth:`_buffered`)."""
        assert self.x is not None
        p_shift, v_shift = self._shift[:3] + t_s * self._shift[3:], self._shift[3:]
        self._buffer.append((t_s, self.x.p_ned - p_shift, self.x.v_ned - v_shift))

    def _buffered(self, t_valid_s: float) -> NavState | None:
        """The state at a past time of validity (position and velocity from the buffer, with every correction
        taken since), None if current."""
        assert self.x is not None
        if not self._buffer or t_valid_s >= self._buffer[-1][0] - 1e-9:
            return None
        times = [b[0] for b in self._buffer]
        i = int(np.argmin(np.abs(np.asarray(times) - t_valid_s)))
        past = self.x.copy()
        t_k, p_k, v_k = self._buffer[i]
        past.p_ned, past.v_ned = p_k + self._shift[:3] + t_k * self._shift[3:], v_k + self._shift[3:]
        return past

    @_input
    def baro(self, t_s: float, pressure_pa: float) -> None:
        """Static pressure [Pa]: the altitude measurement and the air density (with the outside-air
        temperature of :meth:`imu`)."""
        self.inputs.rho_kg_m3 = float(density_kg_m3(pressure_pa, self.inputs.temperature_k))
        if self.x is not None and not self._wait_for_imu("baro", t_s, "_fuse_baro", t_s, pressure_pa):
            self._fuse_baro(t_s, pressure_pa)

    def _fuse_baro(self, t_s: float, pressure_pa: float) -> None:
        if self.x is None or not self._due("baro", t_s):
            return
        z = np.array([float(pressure_altitude_m(pressure_pa))])
        if not self.counts.get("baro") and not self.rejected.get("baro"):
            self.x.b_baro_m = float(z[0]) - (self.config.origin_alt_m - float(self.x.p_ned[2]))
        self._fuse(Measurement(t_s, z, BaroAltitude(self.config.origin_alt_m, self.config.baro_sigma_m)))

    @_input
    def mag(self, t_s: float, field_b_ut: F64Array) -> None:
        """The body-frame magnetic field [µT], less the deviation learnt in flight when the mode learns it."""
        if self.x is not None and not self._wait_for_imu("mag", t_s, "_fuse_mag", t_s, field_b_ut):
            self._fuse_mag(t_s, field_b_ut)

    def _fuse_mag(self, t_s: float, field_b_ut: F64Array) -> None:
        if self.x is None or not self._due("mag", t_s):
            return
        m_b = np.asarray(field_b_ut, float)
        dev = self.mag_deviation
        if dev is not None:
            h_b = dcm_from_quat(self.x.q_nb).T @ self.config.mag_field_ned_ut
            if not self.in_outage and t_s - self._t_init_s > MAG_LEARN_AFTER_S:
                dev.observe(m_b, h_b, self.inputs.throttle)
            m_b = m_b - dev.correction_ut(h_b, self.inputs.throttle)
        field_ned = self.config.mag_field_ned_ut
        sigma = self.config.mag_sigma_ut if self.spec.mag_sigma_ut is None else self.spec.mag_sigma_ut
        fit = self.compass_fit
        if self.spec.mag_sigma_aided_ut is not None and not self.in_outage:
            sigma = max(sigma, self.spec.mag_sigma_aided_ut)
        if fit is not None and self.in_outage and fit.refuted:
            # its aided innovations showed more than σ holds the tilt with: in the outage the compass is fused as
            # the autopilot fuses it (docs/navigation.md, "The compass's aided fit")
            sigma = max(sigma, EKF3_MAG_SIGMA_UT)
            if self._outage_misfit_counted_s != self._last_gnss_s:
                self._outage_misfit_counted_s = self._last_gnss_s
                self.counts["compass_aided_misfit"] = self.counts.get("compass_aided_misfit", 0) + 1
        if self._compass_biased(t_s, m_b, field_ned, sigma) or (self.spec.compass_heading_only and self.in_outage):
            # the heading alone: the compass's residual deviation (soft iron and the motor's field beyond what
            # was learnt, a few µT against its 1.5-µT σ, changing with the throttle in a descent) would
            # otherwise tilt the attitude with no GNSS velocity to hold it, and g·tilt is the fastest drift there
            # is (a return through a gradient: 60 mrad of pitch in 40 s, 24 km off at 300 s). Weighted as the
            # field's σ across its horizontal part, the heading's weight in the three-axis fusion
            psi = MagHeading.measured(self.x, m_b, field_ned)
            self._fuse(Measurement(t_s, np.array([psi]), MagHeading(sigma / float(np.hypot(*field_ned[:2])))))
        else:
            model = MagField(field_ned, sigma)
            if fit is not None and not self.in_outage and dev is not None and dev.ready:
                fit.observe(m_b - model.evaluate(self.x), h_b)  # h_b: the swing's, the same field and attitude
            self._fuse(Measurement(t_s, m_b, model))

    def _compass_biased(self, t_s: float, m_b: F64Array, field_ned: F64Array, sigma: float) -> bool:
        """Whether the compass's three axes are to be left out for the rest of this outage
        (:class:`CompassConsistency`: its innovations against the filter's predicted σ)."""
        check = self.compass_check
        if check is None:
            return False
        if not self.in_outage:
            check.reset()
            return False
        if not check.biased:
            assert self.x is not None and self.engine is not None
            model = MagField(field_ned, sigma)
            h = model.jacobian(self.x)
            s = self.engine.projected(h) + model.covariance()
            earth_b = dcm_from_quat(self.x.q_nb).T @ field_ned
            dev = self.mag_deviation
            learnt = dev.throttle_range() if dev is not None and self.spec.compass_throttle_range else None
            if check.observe(t_s, m_b - model.evaluate(self.x), s, earth_b, self.inputs.throttle, learnt):
                key = "compass_biased" if check.reason == "field" else "compass_throttle_outside"
                self.counts[key] = self.counts.get(key, 0) + 1
        return check.biased

    @_input
    def ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        """The autopilot's own attitude estimate (body FRD → NED quaternion): fused where the config asks for it
        (:attr:`NavConfig.ap_attitude_sigma_rad`: a log whose IMU is too slow to integrate); otherwise its change
        across a hole of the IMU stream gives the rotation the hole's bridge could only guess (_fuse_ap_rotation)."""
        if self.x is not None and not self._wait_for_imu("ap_attitude", t_s, "_fuse_ap_attitude", t_s, q_nb):
            self._fuse_ap_attitude(t_s, q_nb)

    def _fuse_ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        if self.x is None or self.engine is None:
            return
        sigma = self.config.ap_attitude_sigma_rad
        q = np.asarray(q_nb, float)
        if sigma is None:
            # only an ATTITUDE of the filter's own time (not one that came in a hole of the IMU stream only and
            # waited: the state has gone on since) is turned across a hole or held as the next anchor
            if abs(t_s - self.t_s) <= AHEAD_OF_IMU_STEPS * max(1.0 / self.config.filter_rate_hz, self._imu_dt_s):
                self._fuse_ap_rotation(t_s, q)
                self._att_anchor = (t_s, q, self._attitude_at(t_s))
                self._release_pending()
            return
        if self._due("ap_attitude", t_s):
            self._fuse(Measurement(t_s, np.zeros(3), AutopilotAttitude(q, np.asarray(sigma))))

    def _rate_b(self) -> F64Array:
        """The body rate [rad/s] of the last IMU increment, less the gyro offset estimate."""
        assert self.x is not None
        return np.asarray(self.inputs.omega_b - self.x.b_gyro_b, dtype=np.float64)

    def _attitude_at(self, t_s: float) -> F64Array:
        """The state's attitude turned from the filter's time to ``t_s`` [s] (a step at most) at the last rate."""
        assert self.x is not None
        return quat_multiply(self.x.q_nb, quat_exp(self._rate_b() * (t_s - self.t_s)))

    def _fuse_ap_rotation(self, t_s: float, q_b: F64Array) -> None:
        """After a hole of the IMU stream: the filter's attitude at the last ATTITUDE before it (``t_a``), turned
        by the autopilot's own rotation from then to this ATTITUDE at ``t_s`` [s], measures the error the hole
        put in, and nothing else. The anchor shares the error the state had before the hole, which cancels in
        the residual y ≈ n_θ − v (n the hole's error, v the autopilot's own over the span,
        :data:`AP_ROTATION_SCALE`). So the update is n's: its covariance P_n is what the bridges added to the
        covariance, propagated since (nothing else has been fused meanwhile: the others wait for this,
        :meth:`_awaiting_rotation`), K = P_n·Hᵀ·(H·P_n·Hᵀ + R)⁻¹ and P ← P − K·H·P_n. (Fused as an ordinary
        attitude measurement with the anchor's covariance in its noise instead, it counted the anchor's
        information twice: on a third of the IMU lost in short holes the position's χ² left its bound.)"""
        hole, self._att_hole = self._att_hole, None
        p_n, self._hole_cov = self._hole_cov, None
        if hole is None or p_n is None or self.x is None or self.engine is None:
            return
        t_a, q_ap_a, q_hat_a = hole
        span = t_s - t_a
        if not 0.0 < span <= AP_ROTATION_MAX_S:
            return
        turn = quat_multiply(np.array([q_ap_a[0], -q_ap_a[1], -q_ap_a[2], -q_ap_a[3]]), q_b)  # a → b, body axes
        # the measurement is of the attitude at t_s; the state is at the filter's time, up to a step from it
        turn = quat_multiply(turn, quat_exp(self._rate_b() * (self.t_s - t_s)))
        q = self.x.q_nb
        y = quat_log(quat_multiply(np.array([q[0], -q[1], -q[2], -q[3]]), quat_multiply(q_hat_a, turn)))
        p = self.engine.P
        th = IDX["theta"]
        bg = float(np.sqrt(np.max(np.diag(p)[IDX["bg"]])))
        angle = float(np.linalg.norm(quat_log(turn)))
        r = ((bg * span) ** 2 + (AP_ROTATION_SCALE * angle) ** 2 + AP_ROTATION_FLOOR_RAD**2) * np.eye(3)
        pn_ht = p_n[:, th]  # P_n·Hᵀ, H the attitude's rows (y = δθ − …: ∂y/∂δθ = I)
        s = pn_ht[th, :] + r
        try:
            nis = float(y @ np.linalg.solve(s, y))
            gain = np.linalg.solve(s, pn_ht.T).T
        except np.linalg.LinAlgError:
            return
        self.nis.setdefault("ap_rotation", deque(maxlen=NIS_WINDOW)).append(nis)
        if not nis <= GATE_CHI2[3]:
            self.rejected["ap_rotation"] = self.rejected.get("ap_rotation", 0) + 1
            return
        self._correct(gain @ y)
        p_new = p - gain @ pn_ht.T
        self.engine.P = 0.5 * (p_new + p_new.T)
        self.counts["ap_rotation"] = self.counts.get("ap_rotation", 0) + 1

    @_input
    def servo(self, t_s: float, controls_rad: F64Array, throttle: float) -> None:
        self.inputs.controls_rad = np.asarray(controls_rad, float)
        self.inputs.throttle = throttle

    @_input
    def pitot(self, t_s: float, dp_pa: float) -> None:
        """Pitot differential pressure [Pa] (fused by the pitot modes, and by port modes in fallback)."""
        if self.x is None or not (self.spec.pitot or self.fallback) or not math.isfinite(dp_pa):
            return
        if not self._wait_for_imu("pitot", t_s, "_fuse_pitot", t_s, dp_pa):
            self._fuse_pitot(t_s, dp_pa)

    def _fuse_pitot(self, t_s: float, dp_pa: float) -> None:
        if self.x is None or not self._due("pitot", t_s):
            return
        tas = math.sqrt(2.0 * max(dp_pa, 0.0) / self.inputs.rho_kg_m3)
        meas = Measurement(t_s, np.array([tas]), PitotAirspeed(self.config.pitot_sigma_m_s))
        if self.fdi is not None and self._ports_speed is not None and t_s - self._ports_speed[0] <= PAIR_MAX_AGE_S:
            _, v_ports, sig_ports, alpha_ports, port_set, calibrated = self._ports_speed  # no state between the two
            self.fdi.observe_pair(t_s, tas - v_ports, math.hypot(self.config.pitot_sigma_m_s, sig_ports), tas,
                                  alpha_ports, port_set, elevator_rad=float(self.inputs.controls_rad[1]),
                                  judge=calibrated)  # fmt: skip
        # below the pitot's useful range (and on the ground) it is never fused, but a pitot reading near zero in
        # flight is what a blocked one does: the FDI judges it
        self._fuse_source("pitot", meas, fuse=tas >= 8.0)

    def _ctx(self) -> ForceContext:
        prop = self.config.vehicle.propulsion
        a, b = prop.thrust_regressors(self.inputs.throttle, 1.0, self.inputs.rho_kg_m3)
        return ForceContext(self.inputs.rho_kg_m3, self._area_per_mass, self.config.vehicle.mass.mass_kg, float(a),
                            float(b), self.spec.accel_m_err)  # fmt: skip

    def _classic_force(self) -> ClassicForce:
        assert self.derivatives is not None
        c = self.config
        return ClassicForce(self.derivatives, self.inputs.omega_b.copy(), self.inputs.controls_rad.copy(), self._ctx(),
                            np.asarray(c.classic_force_sigma_m_s2))  # fmt: skip

    @property
    def uses_ports(self) -> bool:
        return bool(self.spec.ports_airdata or (self.spec.force not in (None, "classic")))

    @_input
    def ports(self, frame: PortFrame) -> None:
        """A processed port frame (:class:`~vdm_aero.nav.ports_frontend.PortFrame`)."""
        self.port_health = (frame.n_ok, len(frame.ok))
        self._last_port_frame_s = frame.t_s
        if not self.uses_ports:
            return
        self.fallback = frame.airdata is None
        if self.x is None or not self._wait_for_imu("ports", frame.t_s, "_fuse_ports", frame):
            self._fuse_ports(frame)

    def _fuse_ports(self, frame: PortFrame) -> None:
        if self.x is None or frame.airdata is None or not self._due("ports", frame.t_s):
            return
        c = self.config
        if self.spec.ports_airdata:
            assert frame.airdata_cov is not None
            cov = frame.airdata_cov + np.diag(np.square(c.airdata_sigma_floor))
            self._ports_speed = (frame.t_s, float(frame.airdata[0]), math.sqrt(float(cov[0, 0])),
                                 float(frame.airdata[1]), np.asarray(frame.ok, dtype=bool).tobytes(),
                                 frame.within_calibration)  # fmt: skip
            self._fuse_source("ports", Measurement(frame.t_s, frame.airdata, PortAirData(cov)), adaptive=True)
        self._watch_wind(frame)
        force = self.spec.force_model(frame.coeffs)
        if force is not None and frame.n_ok < len(frame.ok):
            # A port left out (quiet, stuck, out of range, missing) is filled in by the gappy reconstruction from
            # the design data's POD prior. On the as-built airframe that is not the port's pressure, and the net
            # was calibrated on complete frames only. Fused with its noise inflated by n_ports/n_ok, as the FADS
            # solve's is, the force model cost `vdm` 1.5x its healthy error on the 20 ports-blocked surveys; so it
            # waits for a complete frame, while the FADS solve keeps its redundancy (docs/navigation.md, "A
            # blocked port group").
            self.counts["force_incomplete_frame"] = self.counts.get("force_incomplete_frame", 0) + 1
            force = None
        if force is not None:
            self._side_force_prior(force)
            coeffs = frame.coeffs[force][:3]
            sig = np.asarray(c.force_sigma_m_s2)
            self._fuse_source(
                "force",
                Measurement(frame.t_s, self.inputs.f_b.copy(), PortForce(coeffs, self._ctx(), sig)),
                adaptive=True,
                fuse=self._due("force", frame.t_s, c.force_fusion_rate_hz),
            )

    def _side_force_prior(self, force: str) -> None:
        """The side-force bias corrects the force model it was learnt with: at a model's first fusion (and at
        any change of model) it starts from that model's prior, :data:`CY_BIAS_SIGMA_CALIBRATED` for the
        calibrated net, ``AERO_PRIOR``'s for a model from the design data. A restored state keeps its value."""
        if force == self._cy_model:
            return
        if self._cy_model != "restored":
            assert self.x is not None and self.engine is not None
            sigma = CY_BIAS_SIGMA_CALIBRATED if force == "deim-nn" else AERO_PRIOR["cy_bias"][1]
            self.x.aero[AERO_SLOT["cy_bias"]] = AERO_PRIOR["cy_bias"][0]
            j = IDX["aero"].start + AERO_SLOT["cy_bias"]
            self.engine.reset_states(slice(j, j + 1), np.array([[sigma**2]]))
        self._cy_model = force

    def _fuse_source(self, source: str, meas: Measurement, *, adaptive: bool = False, fuse: bool = True) -> None:
        """Fuse one air-data measurement (if ``fuse``) unless the FDI has excluded its source; with FDI, its
        innovation is judged either way (an excluded source against the state the others keep)."""
        if self.fdi is None:
            if fuse:
                self._fuse(meas, adaptive=adaptive)
            return
        if fuse and self.fdi.fused(source):
            nis = self._fuse(meas, adaptive=adaptive).nis
        else:
            nis = self._nis(meas, adaptive=adaptive)
        event = self.fdi.observe(source, meas.t_s, nis, len(meas.z))
        if event is None:
            return
        self.counts[f"fdi_{event.source}_{event.what}"] = self.counts.get(f"fdi_{event.source}_{event.what}", 0) + 1
        if event.source == "wind" and self.spec.wind_relearn:
            self._relearn_wind(meas.t_s)

    def _watch_wind(self, frame: PortFrame) -> None:
        """The ports' air velocity in NED (their V, α, β less the state's corrections, rotated by the attitude)
        for the wind-change detector; in an outage a change it sees is relearnt."""
        if self.wind_change is None or self.x is None or frame.airdata is None:
            return
        if self.fdi is not None and not self.fdi.fused("ports"):
            return
        a = self.x.aero
        speed = float(frame.airdata[0]) / max(float(a[AERO_SLOT["airspeed_scale"]]), 0.5)
        alpha = float(frame.airdata[1]) - float(a[AERO_SLOT["alpha_bias_rad"]])
        beta = float(frame.airdata[2]) - float(a[AERO_SLOT["beta_bias_rad"]])
        v_b = speed * np.array([math.cos(alpha) * math.cos(beta), math.sin(beta), math.sin(alpha) * math.cos(beta)])
        v_n = dcm_from_quat(self.x.q_nb) @ v_b
        x = self.x
        change = self.wind_change.air(frame.t_s, float(v_n[0]), float(v_n[1]), (float(x.p_ned[0]), float(x.p_ned[1])),
                                      (float(x.v_ned[0]), float(x.v_ned[1])))  # fmt: skip
        self._clone_pose(frame.t_s)
        if self.wind_change.anchored_s is not None:
            self._settle_wind_change(frame.t_s)
        if change is None or not self.in_outage or frame.t_s < self._wind_live_until_s:
            return
        threshold = wind_change_threshold_m_s(self.process.gust_sigma_m_s)
        if change <= threshold + WIND_CHANGE_GUST_SIGMAS * self.wind_change.gap_sigma_m_s(frame.t_s):
            return
        if self.fdi is not None and self.fdi.wind_changed(frame.t_s, change) is None:
            return
        self.counts["fdi_wind_changed"] = self.counts.get("fdi_wind_changed", 0) + 1
        self._wind_change_seen_m_s = change
        self._relearn_wind(frame.t_s)

    def _clone_pose(self, t_s: float) -> None:
        """In an outage, clone the horizontal pose the wind detector has just recorded every
        :data:`CLONE_EVERY_S`, keeping those a wind event's window can start from (and the one anchored); out of
        an outage, none."""
        assert self.engine is not None and self.wind_change is not None
        if not self.in_outage:
            self.engine.drop_clones()
            return
        oldest = t_s - self.wind_change.window_s - 2.0 * CLONE_EVERY_S
        anchored = self._anchor_clone_s if self.wind_change.anchored_s is not None else None
        self.engine.drop_clones(lambda k: k >= oldest or k == anchored)
        keys = self.engine.clone_keys
        if not keys or t_s - keys[-1] >= CLONE_EVERY_S - 1e-6:
            assert self.x is not None
            self.engine.clone(t_s, _WINDOW_POSE.jacobian(self.x))

    def _relearn_wind(self, t_s: float) -> None:
        """The air data agree the wind has changed: forget the wind (σ back to a shear's size, uncorrelated) and
        let it be estimated for the FDI's relearning time, also in an outage. Until the change was seen, the air
        data with the old wind pulled the velocity (and so the position) off by the change: in an outage, once
        the change is over and has stayed, the horizontal pose a free INS gives from the filter's pose before
        it puts them back, and the gust state hands the new wind over (:meth:`_settle_wind_change`). Where a
        checkpoint from before the window is kept, the filter goes back to it instead once the input at hand
        has been taken (:meth:`_rewind`)."""
        assert self.engine is not None
        if self._checkpoints and self.in_outage and not self._replaying:
            self._rewind_request = t_s
            return
        self.engine.reset_states(IDX["wind"], np.diag(np.square(WIND_RELEARN_SIGMA_M_S)))
        self._wind_live_until_s = t_s + WIND_RELEARN_S
        self._rewound_anchor = False
        keys, wc = self.engine.clone_keys, self.wind_change
        if wc is not None and self.in_outage and keys:
            # the free INS starts from the cloned pose nearest the window's start, before the change
            at = min(keys, key=lambda k: abs(k - (t_s - wc.window_s)))
            wc.anchor(at)
            self._anchor_clone_s = at

    def _hand_gust_to_wind(self) -> None:
        """The gust state (zero-mean Gauss–Markov, live while the wind is held) has soaked up the new wind
        before the change was seen, and would hand it back only at its own decay: move its horizontal content
        into the wind, forget the wind (σ back to a shear's size) and restart the gust from its steady state,
        all uncorrelated."""
        assert self.engine is not None and self.x is not None
        x = self.x
        x.wind_ned[:2] += x.gust_ned[:2]
        x.gust_ned[:2] = 0.0
        self.engine.reset_states(IDX["wind"], np.diag(np.square(WIND_RELEARN_SIGMA_M_S)))
        self.engine.reset_states(IDX["gust"], np.diag(np.square(self.process.gust_sigma_m_s)))

    def _heading_sigma_rad(self) -> float:
        """The heading's σ [rad]: the attitude error (body frame) turned to NED, its down component."""
        assert self.engine is not None and self.x is not None
        c_nb = dcm_from_quat(self.x.q_nb)
        p_theta = np.asarray(self.engine.P)[IDX["theta"], IDX["theta"]]
        return math.sqrt(max(float((c_nb @ p_theta @ c_nb.T)[2, 2]), 0.0))

    def _settle_wind_change(self, t_s: float) -> None:
        """After a wind event in an outage: once the change is over (|Δw| over the last 2 s under
        :data:`WIND_SETTLED_M_S`) and has stayed (:data:`WIND_STEP_M_S` from before it), fuse the free INS's pose
        from before the change, once (:class:`InsWindowFix`; once: a second fix from the same start would count
        its errors twice), and hand the gust's content to the wind. A wind change is a step: it ends, and it
        stays; a gust goes back. A difference between the INS and the air data that is still growing after
        :data:`INS_WINDOW_MAX_S` is the INS drifting (vibration, clipping, scale errors in a climb), and the
        free INS is then the last thing to trust: no fix."""
        wc = self.wind_change
        assert wc is not None and self.engine is not None
        tau = wc.anchored_s
        if tau is None:
            return
        if tau >= INS_WINDOW_MAX_S:
            self.process.wind_change_m_s2, self._rewound_anchor = 0.0, False
            wc.release()
            self.counts["ins_window_abandoned"] = self.counts.get("ins_window_abandoned", 0) + 1
            return
        recent = wc.recent_change()
        if recent is None or recent > WIND_SETTLED_M_S:
            return
        step = wc.change_since_anchor()
        clone = self._anchor_clone_s
        fix = wc.ins_window(t_s) if self.in_outage and clone in self.engine.clone_keys else None
        turned = wc.ins_turned()
        wc.release()
        self.process.wind_change_m_s2 = 0.0  # the change is over
        # the free INS turns its increments to NED with the filter's heading: with the compass gated out lately
        # the heading is what is wrong, and the "change" is the INS and the air data turned apart by it
        heading_doubt = t_s - self._last_rejected_s.get("mag", -math.inf) < HEADING_DOUBT_S
        if self._rewound_anchor:
            # the rewind fused the window again with the wind live: no free INS to fuse, the gust's share to hand
            self._rewound_anchor = False
            if step is None or step < WIND_STEP_M_S:
                self.counts["ins_window_abandoned"] = self.counts.get("ins_window_abandoned", 0) + 1
                return
            self._hand_gust_to_wind()
            self._wind_live_until_s = max(self._wind_live_until_s, t_s + WIND_RELEARN_S)
            return
        if fix is None or clone is None or step is None or step < WIND_STEP_M_S or heading_doubt:
            # the change went back (a gust, turbulence with the INS's own error on top): no step to undo
            self.counts["ins_window_abandoned"] = self.counts.get("ins_window_abandoned", 0) + 1
            return
        (pn, pe), (vn, ve), tau = fix
        a = INS_WINDOW_ACCEL_M_S2
        # the free INS turns its increments with the filter's heading, so its heading error turns the velocity
        # change and its integral (Groves 2013, §5.7: δv̇ = −(f × δψ)); over a turn that, not the tilt, dominates
        dv_m_s, dp_m = turned if turned is not None else (0.0, 0.0)
        sig_psi = self._heading_sigma_rad()
        sig_v = math.hypot(INS_WINDOW_SIGMA_V_M_S, a * tau, sig_psi * dv_m_s)
        sig_p = math.hypot(INS_WINDOW_SIGMA_P_M, 0.5 * a * tau * tau, sig_psi * dp_m)
        # the free INS ran from the filter's own pose at the clone: its error is that pose's error plus the INS's
        # own, so the fix is relative to the clone (fused as if independent, every fix shrank the covariance:
        # a return through a gradient ended 24 km off with σ 9 m). No gate: the point is to move the state by
        # what the gate would call an outlier
        model = InsWindowFix(sig_p, sig_v)
        assert self.x is not None
        y = np.array([pn, pe, vn, ve]) - model.evaluate(self.x)
        consider = self._wind_live if t_s < self._wind_live_until_s else self._consider
        dx, res = self.engine.update_relative(y, model.jacobian(self.x), model.clone_jacobian(tau),
                                              model.covariance(), clone, consider)  # fmt: skip
        self.nis.setdefault(model.name, deque(maxlen=NIS_WINDOW)).append(res.nis)
        if res.accepted:
            self._correct(dx)
        self.counts["ins_window_fix"] = self.counts.get("ins_window_fix", 0) + int(res.accepted)
        self._hand_gust_to_wind()  # what the gust took of the change while it went on
        self._wind_live_until_s = max(self._wind_live_until_s, t_s + WIND_RELEARN_S)
