"""The SITL mock autopilot: an ArduPlane-like (or, ``AutopilotOptions.firmware = "px4"``, a PX4-like) MAVLink 2
peer driven by a :class:`~sim.flight.contract.World`.

From a companion's side it behaves like ArduPlane in AUTO (see docs/sitl.md): HEARTBEAT at 1 Hz as a
fixed-wing ArduPilot, telemetry at SRx_-like stream rates, MAV_CMD_SET_MESSAGE_INTERVAL /
MAV_CMD_GET_MESSAGE_INTERVAL / MAV_CMD_REQUEST_MESSAGE / REQUEST_DATA_STREAM, TIMESYNC replies, the
pressure ports as NAMED_VALUE_FLOAT (and optionally DEBUG_FLOAT_ARRAY) only once the link has heard
from a remote component, GPS_INPUT and ODOMETRY recorded and judged by ArduPilot's EKF3 rules (ekf_judge.py,
extnav_judge.py), MAV_CMD_SET_EKF_SOURCE_SET, optional signing. It never imports ``firmware_bridge``: it is the
peer the bridge is tested against.

As PX4 it changes what PX4 does differently for a companion: HEARTBEAT as PX4 in AUTO.MISSION, HIGHRES_IMU
carrying the airspeed sensor's differential pressure, no MAV_CMD_SET_EKF_SOURCE_SET (UNSUPPORTED), and GPS_INPUT,
ODOMETRY and GLOBAL_POSITION_SENSOR judged by EKF2's rules (ekf2_judge.py) instead of EKF3's. The drift of its own
estimate through an outage is the same model.

Time: the autopilot's clock is the world time (it boots at world time 0). ``speed`` paces world steps
against the wall clock (1 = real time, 10 = ten times faster, 0 or inf = as fast as possible); all
rates are in autopilot time.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import TracebackType
from typing import TypedDict

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.ap_attitude import AutopilotAttitude
from sim.flight.contract import BaroSample, ImuSample, World, WorldTick
from sim.sitl.ekf2_judge import Ekf2Judge, Ekf2Rules
from sim.sitl.ekf_judge import Ekf3GpsRules, GpsInputJudge
from sim.sitl.extnav_judge import SOURCE_SET_COUNT, Ek3ExtNavRules, ExtNavJudge, SourceXY
from sim.sitl.faults import FaultSchedule
from sim.sitl.link import Link, MavlinkEndpoint, MavlinkMessage, SigningConfig, open_link
from sim.sitl.streams import (
    DEBUG_FLOAT_ARRAY_LEN,
    FIRMWARES,
    PLANE_LOOP_RATE_HZ,
    NavEstimate,
    SensorState,
    Stream,
    StreamScheduler,
    TelemetryEncoder,
    default_rates,
    message_name,
    to_time_usec,
)
from sim.sitl.tlog import GpsInputRecord, OdometryRecord, TlogWriter, TruthRecorder
from vdm_aero._typing import F64Array
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame

PORT_NAME_MAX_CHARS = 10
PORTS_ARRAY_NAME = "PORTS"
# messages that do not make a link "active" (ArduPilot: radio modems' own reports)
_PASSIVE_MESSAGES = frozenset({"RADIO", "RADIO_STATUS"})


@dataclass(frozen=True)
class DeadReckoningDrift:
    """Error growth of the autopilot's own position estimate while GNSS is out (seeded, reproducible).

    At the start of each outage a velocity error is drawn (1σ per axis), then random-walks; the position
    error integrates it. When the fix returns, the error decays with ``recovery_tau_s`` (the EKF
    converging back onto GNSS).
    """

    horizontal_velocity_sigma_m_s: float = 0.3
    vertical_velocity_sigma_m_s: float = 0.05
    velocity_random_walk_m_s_per_sqrt_s: float = 0.02
    recovery_tau_s: float = 2.0
    seed: int = 0


@dataclass(frozen=True)
class SecondSensors:
    """IMU 2 (SCALED_IMU2) and barometer 2 (SCALED_PRESSURE2). The worlds carry one IMU and one barometer, so
    each second sensor is the first's sample plus independent white noise drawn from the mock's own seeded
    :class:`numpy.random.Generator` (its biases are the first's: no second error model). σ per sample: the
    ICM-42688-P's noise densities at 400 Hz (70 µg/√Hz, 2.8 mdps/√Hz) and the MS5611's RMS resolution (1.2 Pa),
    the grades of sim/flight/sensors.py."""

    accel_sigma_m_s2: float = 70e-6 * 9.80665 * 20.0
    gyro_sigma_rad_s: float = math.radians(2.8e-3) * 20.0
    baro_sigma_pa: float = 1.2
    seed: int = 1


@dataclass(frozen=True)
class AutopilotOptions:
    """Identity and bookkeeping of the mock (the protocol-level options are :class:`MockAutopilot` arguments)."""

    system_id: int = 1
    component_id: int = 1
    firmware: str = "ardupilot"  # whose rules the mock follows: "ardupilot" or "px4" (streams.FIRMWARES)
    debug_array_id: int = 0  # DEBUG_FLOAT_ARRAY.array_id of the ports
    unix_time_at_boot_s: float | None = None  # SYSTEM_TIME/tlog epoch; None: the wall clock when run() starts
    drift: DeadReckoningDrift = field(default_factory=DeadReckoningDrift)
    truth_every_n_steps: int = 1  # decimation of the truth record
    # a ground station recording the tlog is on the link from the start (as MAVProxy logging a flight):
    # named values flow without waiting to hear from a companion, at the rates of ``stream_rates`` (what a GCS
    # asks for: streams.gcs_request_rates(), which ``vdm-aero sitl --gcs-recording`` passes)
    gcs_recording: bool = False
    faults: FaultSchedule | None = None  # scripted link and sensor faults (sim/sitl/faults.py)
    second_sensors: SecondSensors = field(default_factory=SecondSensors)
    loop_rate_hz: float = PLANE_LOOP_RATE_HZ  # SCHED_LOOP_RATE: no stream is sent faster (streams.py)
    ekf_rules: Ekf3GpsRules = field(default_factory=Ekf3GpsRules)  # how EKF3 takes GPS_INPUT (ekf_judge.py)
    extnav_rules: Ek3ExtNavRules = field(default_factory=Ek3ExtNavRules)  # EK3_SRCn_, VISO_ (extnav_judge.py)
    # a Lua script's ahrs:set_posvelyaw_source_set on GNSS loss: this set (1..3) at each outage's start, set 1 at its
    # end (None: no script; the companion's MAV_CMD_SET_EKF_SOURCE_SET only)
    source_set_on_gnss_loss: int | None = None
    ekf2_rules: Ekf2Rules = field(default_factory=Ekf2Rules)  # as PX4: how EKF2 takes them (ekf2_judge.py)
    # with ``ports_as_debug_array``: the ports as NAMED_VALUE_FLOAT too (False: the array alone, as the Lua script
    # sends them with VPP_MAV_CHAN set)
    ports_named_too: bool = True


class RunSummary(TypedDict):
    world_time_s: float
    wall_time_s: float
    steps: int
    max_lag_s: float  # how far the loop fell behind the wall-clock schedule (real-time modes)
    sent: dict[str, int]
    received: dict[str, int]
    gps_input: int
    odometry: int
    rejected_frames: int  # failed signature / unsigned while signing is required
    bad_frames: int  # CRC or framing errors
    link_active: bool
    link: str
    # the GPS_INPUT fixes ArduPilot's EKF3 would use, by verdict, and the mock's own horizontal error at each
    # outage's end with them and without them (sim/sitl/ekf_judge.py)
    gps_input_verdicts: dict[str, int]
    gps_input_outage_verdicts: dict[str, int]  # of the GPS_INPUT that came during GNSS outages
    outage_end_errors: list[dict[str, float]]
    # the ODOMETRY (and VISION_POSITION_ESTIMATE) ArduPilot would use as ExternalNav, by verdict, and each switch of
    # the EKF source set: {t_s, source_set (1..3), outage (index of the outage it fell in; -1 between outages)}
    odometry_verdicts: dict[str, int]
    odometry_outage_verdicts: dict[str, int]  # of the ODOMETRY that came during GNSS outages
    # per outage that had an ExternalNav position judged: the last one's error against the truth as it came
    # (odometry_n/e_m), the mock's estimate's then (estimate_n/e_m), its own dead reckoning's (free_n/e_m) [m], and
    # FuseVelPosNED's innovation variance then, P_N + P_E + 2R (innovation_var_m2) [m²]
    odometry_outage_end: list[dict[str, float]]
    source_set_switches: list[dict[str, float]]
    # as PX4: per message (GPS_INPUT, ODOMETRY, GLOBAL_POSITION_SENSOR) the verdicts of EKF2's rules, all and of
    # those that came during GNSS outages (sim/sitl/ekf2_judge.py); empty as ArduPilot
    ekf2_verdicts: dict[str, dict[str, int]]
    ekf2_outage_verdicts: dict[str, dict[str, int]]


class _DeadReckoning:
    """The mock's own estimate error: the drift of :class:`DeadReckoningDrift`, and (``judge``) the same drift
    with the GPS_INPUT fixes and (``extnav``, into the same state) the ODOMETRY ArduPilot's EKF3 would fuse
    (sim/sitl/ekf_judge.py, sim/sitl/extnav_judge.py)."""

    def __init__(self, cfg: DeadReckoningDrift, judge: GpsInputJudge, extnav: ExtNavJudge) -> None:
        self._cfg = cfg
        self._rng = np.random.default_rng(cfg.seed)
        self.judge = judge
        self.extnav = extnav
        self.error_ned_m = np.zeros(3)  # without the companion's fixes
        self.error_rate_ned_m_s = np.zeros(3)
        self._v_err = np.zeros(3)
        self._in_outage = False

    def update(self, dt_s: float, outage: bool) -> None:
        cfg = self._cfg
        if outage:
            if not self._in_outage:
                sig = np.array([cfg.horizontal_velocity_sigma_m_s] * 2 + [cfg.vertical_velocity_sigma_m_s])
                self._v_err = sig * self._rng.standard_normal(3)
                self.judge.outage_started(self._v_err)
                self.extnav.outage_started()
            dv = cfg.velocity_random_walk_m_s_per_sqrt_s * math.sqrt(dt_s) * self._rng.standard_normal(3)
            self._v_err = self._v_err + dv
            self.judge.propagate(dt_s, dv)
            self.error_ned_m = self.error_ned_m + self._v_err * dt_s
            self.error_rate_ned_m_s = self._v_err
        else:
            if self._in_outage:
                self.judge.outage_ended(self.error_ned_m)
                self.extnav.outage_ended(self.error_ned_m[:2])
            factor = math.exp(-dt_s / cfg.recovery_tau_s)
            decayed = self.error_ned_m * factor
            self.error_rate_ned_m_s = (decayed - self.error_ned_m) / dt_s
            self.error_ned_m = decayed
            self.judge.decay(factor)
        self._in_outage = outage

    @property
    def in_outage(self) -> bool:
        return self._in_outage

    @property
    def estimate_error_ned_m(self) -> F64Array:
        """What the mock flies on: horizontally the judge's (with the fixes it took), vertically the drift."""
        return np.array([*self.judge.p_err_m, self.error_ned_m[2]])

    @property
    def estimate_error_rate_ned_m_s(self) -> F64Array:
        if not self._in_outage:
            return self.error_rate_ned_m_s
        return np.array([*self.judge.v_err_m_s, self.error_rate_ned_m_s[2]])


class _SecondSensors:
    """Draws the second IMU's and barometer's samples (:class:`SecondSensors`), the IMU's noise in blocks."""

    BLOCK = 4096

    def __init__(self, cfg: SecondSensors) -> None:
        self._cfg = cfg
        self._rng = np.random.default_rng(cfg.seed)
        self._imu_sigma = np.array([cfg.accel_sigma_m_s2] * 3 + [cfg.gyro_sigma_rad_s] * 3)
        self._noise = np.empty((0, 6))
        self._i = 0

    def imu(self, first: ImuSample) -> ImuSample:
        if self._i >= len(self._noise):
            self._noise, self._i = self._rng.standard_normal((self.BLOCK, 6)) * self._imu_sigma, 0
        n = self._noise[self._i]
        self._i += 1
        return replace(first, accel_b_m_s2=first.accel_b_m_s2 + n[:3], gyro_b_rad_s=first.gyro_b_rad_s + n[3:])

    def baro(self, first: BaroSample) -> BaroSample:
        noise = self._cfg.baro_sigma_pa * float(self._rng.standard_normal())
        return replace(first, pressure_pa=first.pressure_pa + noise)


class MockAutopilot:
    """An ArduPlane-like (or PX4-like: ``options.firmware``) MAVLink autopilot fed by ``world``, on the transport
    ``url`` (or a ready :class:`Link`).

    The link is opened here (so a test can read a bound port or a pty path before ``run``) and released
    by ``close()`` / the context manager. ``run`` is blocking and may be called once; ``stop()`` from
    another thread ends it at the next world step.
    """

    def __init__(
        self,
        world: World,
        url: str | Link,
        *,
        speed: float = 1.0,
        stream_rates: Mapping[str, float] | None = None,
        signing_key: bytes | None = None,
        require_signing: bool = False,
        ports_as_debug_array: bool = False,
        tlog_path: Path | None = None,
        truth_path: Path | None = None,
        options: AutopilotOptions | None = None,
    ) -> None:
        if math.isnan(speed) or speed < 0.0:
            raise UserInputError(f"speed = {speed}: must be ≥ 0 (0 or inf: as fast as possible)")
        if require_signing and signing_key is None:
            raise UserInputError("require_signing needs a signing key")
        self._options = options or AutopilotOptions()
        on_loss = self._options.source_set_on_gnss_loss
        if on_loss is not None and not 1 <= on_loss <= SOURCE_SET_COUNT:
            raise UserInputError(f"source_set_on_gnss_loss = {on_loss}: a source set 1..{SOURCE_SET_COUNT}")
        if self._options.firmware not in FIRMWARES:
            raise UserInputError(f"firmware = {self._options.firmware!r}: one of {', '.join(FIRMWARES)}")
        self._px4 = self._options.firmware == "px4"
        if self._px4 and on_loss is not None:
            raise UserInputError("source_set_on_gnss_loss: EK3 source sets and Lua are ArduPilot's, not PX4's")
        self._world = world
        self._speed = speed
        self._realtime = 0.0 < speed < math.inf
        self._ports_as_debug_array = ports_as_debug_array
        self._tlog_path = tlog_path
        self._truth_path = truth_path
        self._scheduler = StreamScheduler(default_rates(stream_rates), loop_rate_hz=self._options.loop_rate_hz)
        signing = SigningConfig(signing_key, require=require_signing) if signing_key is not None else None
        self._owns_link = isinstance(url, str)
        self.link: Link = open_link(url) if isinstance(url, str) else url
        self._endpoint = MavlinkEndpoint(
            self.link,
            system_id=self._options.system_id,
            component_id=self._options.component_id,
            signing=signing,
            on_frame=self._log_frame,
        )
        self._encoder = TelemetryEncoder(self._endpoint.mav, firmware=self._options.firmware)
        home = (world.home_lat_deg, world.home_lon_deg, world.home_alt_m)
        self._frame = LocalFrame(*home)
        self._state = SensorState(home)
        d = self._options.drift
        judge = GpsInputJudge(self._options.ekf_rules, velocity_sigma_m_s=d.horizontal_velocity_sigma_m_s,
                              random_walk_m_s_per_sqrt_s=d.velocity_random_walk_m_s_per_sqrt_s)  # fmt: skip
        extnav = ExtNavJudge(self._options.extnav_rules, judge)
        self._drift = _DeadReckoning(d, judge, extnav)
        self._ekf2 = Ekf2Judge(self._options.ekf2_rules, judge)  # used only as PX4, into the same error state
        self._second = _SecondSensors(self._options.second_sensors)
        self._ap_attitude = AutopilotAttitude()  # its own attitude estimate (ATTITUDE), from the world's IMU
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._gps_inputs: list[GpsInputRecord] = []
        self._odometry: list[OdometryRecord] = []
        self._sent: Counter[str] = Counter()
        self._received: Counter[str] = Counter()
        self._active = self._options.gcs_recording
        self._ran = False
        self._closed = False
        self._tlog: TlogWriter | None = None
        self._recorder: TruthRecorder | None = None
        self._t_s = 0.0  # autopilot time of the last processed world step
        self._wall_at_t = time.monotonic()
        self._unix_boot_s: float | None = self._options.unix_time_at_boot_s

    # ------------------------------------------------------------------------------------ public API
    @property
    def active(self) -> bool:
        """True once the link has heard from a remote component (named values flow from then on)."""
        return self._active

    @property
    def gps_inputs(self) -> tuple[GpsInputRecord, ...]:
        with self._lock:
            return tuple(self._gps_inputs)

    @property
    def odometry(self) -> tuple[OdometryRecord, ...]:
        with self._lock:
            return tuple(self._odometry)

    def stream_interval_s(self, name: str) -> float | None:
        """The current interval of a streamed message (None: disabled)."""
        return self._scheduler.interval_s(name)

    def stop(self) -> None:
        """End ``run`` at the next world step (thread-safe)."""
        self._stop.set()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._owns_link:
            self.link.close()

    def __enter__(self) -> MockAutopilot:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def run(self, duration_s: float, on_second: Callable[[float], None] | None = None) -> RunSummary:
        """Fly ``duration_s`` of world time (or until ``stop()``), then write the truth file. Blocking.
        ``on_second(t)`` after each whole second of world time ``t`` [s] flown."""
        if self._ran:
            raise RuntimeError("MockAutopilot.run may be called once")
        if self._closed:
            raise RuntimeError("MockAutopilot is closed")
        self._ran = True
        dt = self._world.dt_s
        n_steps = math.ceil(duration_s / dt - 1e-9)
        steps_per_s = max(1, round(1.0 / dt))
        wall0 = time.monotonic()
        self._wall_at_t = wall0
        max_lag = 0.0
        steps = 0
        wall_end = wall0
        home = (self._world.home_lat_deg, self._world.home_lon_deg, self._world.home_alt_m)
        if self._truth_path is not None:
            self._recorder = TruthRecorder(home=home, every_n_steps=self._options.truth_every_n_steps)
        self._tlog = TlogWriter(self._tlog_path) if self._tlog_path is not None else None
        if self._unix_boot_s is None:  # the autopilot boots now, at world time 0
            self._unix_boot_s = time.time()
        self._state.unix_time_at_boot_us = round(self._unix_boot_s * 1e6)
        try:
            for k in range(n_steps):
                if self._stop.is_set():
                    break
                self._service(0.0)  # at least one look at the link per step, even when behind schedule
                if self._realtime:
                    target = wall0 + (k + 1) * dt / self._speed
                    while (remaining := target - time.monotonic()) > 0.0:
                        self._service(remaining)
                    max_lag = max(max_lag, time.monotonic() - target)
                self._process(self._world.step(), dt)
                steps += 1
                if on_second is not None and steps % steps_per_s == 0:
                    on_second(steps * dt)
            wall_end = time.monotonic()
        finally:
            if self._tlog is not None:
                self._tlog.close()
            if self._recorder is not None and self._truth_path is not None:
                self._recorder.write(self._truth_path, self.gps_inputs, self.odometry)
        return RunSummary(
            world_time_s=steps * dt,
            wall_time_s=wall_end - wall0,
            steps=steps,
            max_lag_s=max_lag,
            sent=dict(self._sent),
            received=dict(self._received),
            gps_input=len(self._gps_inputs),
            odometry=len(self._odometry),
            rejected_frames=self._endpoint.rejected_frames,
            bad_frames=self._endpoint.bad_frames,
            link_active=self._active,
            link=self.link.description,
            gps_input_verdicts=dict(self._drift.judge.verdicts),
            gps_input_outage_verdicts=dict(self._drift.judge.outage_verdicts),
            outage_end_errors=list(self._drift.judge.outage_end),
            odometry_verdicts=dict(self._drift.extnav.verdicts),
            odometry_outage_end=list(self._drift.extnav.outage_end),
            odometry_outage_verdicts=dict(self._drift.extnav.outage_verdicts),
            source_set_switches=list(self._drift.extnav.switches),
            ekf2_verdicts={k: dict(v) for k, v in self._ekf2.verdicts.items()},
            ekf2_outage_verdicts={k: dict(v) for k, v in self._ekf2.outage_verdicts.items()},
        )

    # ------------------------------------------------------------------------------------ the clock
    def _clock_s(self) -> float:
        """Autopilot time now: the last step's time, advanced by the wall clock between steps in real time."""
        if not self._realtime:
            return self._t_s
        elapsed = (time.monotonic() - self._wall_at_t) * self._speed
        return self._t_s + min(max(elapsed, 0.0), self._world.dt_s)

    def _log_frame(self, frame: bytes, sent: bool) -> None:
        if self._tlog is not None:
            self._tlog.write(self._state.unix_time_at_boot_us + to_time_usec(self._clock_s()), frame)

    def _send(self, msg: MavlinkMessage | None) -> None:
        if msg is None:
            return
        faults = self._options.faults
        copies = 1
        if faults is not None:
            if faults.link_silent(self._t_s):
                return
            copies = faults.copies(self._t_s)
        for _ in range(copies):
            self._endpoint.send(msg)
        self._sent[msg.get_type()] += copies

    # ------------------------------------------------------------------------------------ world side
    def _process(self, tick: WorldTick, dt: float) -> None:
        truth = tick.truth
        self._t_s = truth.t_s
        self._wall_at_t = time.monotonic()
        st = self._state
        st.truth = truth
        st.gnss_outage = tick.gnss_outage
        # samples hold until replaced (sensors run at their own rates)
        st.imu = tick.imu or st.imu
        if tick.imu is not None:
            st.imu2 = self._second.imu(tick.imu)
            self._ap_attitude.step(tick.imu, truth)
        # a fix lost is gone: after an outage GPS_RAW_INT waits for the receiver's next fix (ArduPilot's driver
        # does not report the last pre-outage fix again as if it were new)
        st.gnss = None if tick.gnss_outage else (tick.gnss or st.gnss)
        if self._options.faults is not None and tick.gnss is not None and st.gnss is not None:
            st.gnss = self._options.faults.gnss(tick.gnss, truth.t_s, self._frame)
        if tick.gnss is not None and st.gnss is not None:
            # GPS_RAW_INT.time_usec is when the autopilot received the fix (AP_GPS::send_mavlink_gps_raw sends
            # last_fix_time_ms; PX4 its sensor_gps timestamp), not the receiver's time of validity
            st.gnss = replace(st.gnss, t_s=truth.t_s)
        st.baro = tick.baro or st.baro
        if st.ground_pressure_pa is None and st.baro is not None:
            st.ground_pressure_pa = st.baro.pressure_pa
        if tick.baro is not None:
            st.baro2 = self._second.baro(tick.baro)
        st.mag = tick.mag or st.mag
        st.airspeed = tick.airspeed or st.airspeed
        st.servos = tick.servos or st.servos
        # the Lua script's switches, both counted in the outage (it starts in update, it ends after it)
        on_loss = self._options.source_set_on_gnss_loss
        loss_changed = on_loss is not None and tick.gnss_outage != self._drift.in_outage
        if loss_changed and not tick.gnss_outage:
            self._drift.extnav.set_source_set(1, truth.t_s)
        if self._px4 and tick.gnss_outage != self._drift.in_outage:  # EKF2's GNSS flags time out from the loss
            if tick.gnss_outage:
                self._ekf2.outage_started(truth.t_s)
            else:
                self._ekf2.outage_ended()
        self._drift.update(dt, tick.gnss_outage)
        if loss_changed and on_loss is not None and tick.gnss_outage:
            self._drift.extnav.set_source_set(on_loss, truth.t_s)
        err = self._drift.estimate_error_ned_m
        pos_est = truth.pos_ned_m + err
        lat, lon, alt = self._frame.to_geodetic(float(pos_est[0]), float(pos_est[1]), float(pos_est[2]))
        st.estimate = NavEstimate(
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            pos_ned_m=truth.pos_ned_m + err,
            v_ned_m_s=truth.v_ned_m_s + self._drift.estimate_error_rate_ned_m_s,
            error_ned_m=err.copy(),
            q_nb=self._ap_attitude.q_nb(truth),
            omega_b_rad_s=truth.omega_b_rad_s,
            airspeed_m_s=truth.airspeed_m_s,
        )
        if self._recorder is not None:
            self._recorder.add_truth(truth, gnss_outage=tick.gnss_outage, estimate_error_ned_m=err)
        if tick.ports is not None:
            self._emit_ports(tick)
        for name in self._scheduler.due(truth.t_s):
            msg = self._encoder.encode(name, st, truth.t_s)
            if msg is None:  # e.g. no baro sample yet: send at the first step that has one
                self._scheduler.defer(name, now_s=truth.t_s)
            self._send(msg)

    def _emit_ports(self, tick: WorldTick) -> None:
        ports = tick.ports
        assert ports is not None
        for name in ports.names:
            if not 0 < len(name) <= PORT_NAME_MAX_CHARS or not name.isascii():
                raise ValueError(f"port name {name!r}: NAMED_VALUE_FLOAT names are 1..10 ASCII characters")
        if self._recorder is not None:
            self._recorder.add_ports(ports)
        if not self._active:  # ArduPilot sends named values only on links that have heard from someone
            return
        faults = self._options.faults
        if self._ports_as_debug_array:
            if len(ports.names) > DEBUG_FLOAT_ARRAY_LEN:
                raise ValueError(f"{len(ports.names)} ports: DEBUG_FLOAT_ARRAY holds {DEBUG_FLOAT_ARRAY_LEN}")
            values = ports.dp_pa if faults is None else faults.port_values(ports)
            for name, dp in zip(ports.names, values, strict=True) if self._options.ports_named_too else ():
                self._send(self._encoder.named_value_float(ports.t_s, name, float(dp)))
            self._send(
                self._encoder.debug_float_array(ports.t_s, PORTS_ARRAY_NAME, self._options.debug_array_id, values)
            )
            return
        sent = zip(ports.names, ports.dp_pa, strict=True) if faults is None else faults.ports(ports)
        for name, dp in sent:
            self._send(self._encoder.named_value_float(ports.t_s, name, float(dp)))

    # ------------------------------------------------------------------------------------ link side
    def _service(self, timeout_s: float) -> None:
        msgs = self._endpoint.poll(timeout_s)
        if self._options.faults is not None and self._options.faults.link_silent(self._t_s):
            return  # the link is down both ways: what arrives is lost
        for msg in msgs:
            self._handle(msg)

    def _for_me(self, target_system: int, target_component: int) -> bool:
        return target_system in (0, self._endpoint.system_id) and target_component in (
            0,
            self._endpoint.component_id,
        )

    def _handle(self, msg: MavlinkMessage) -> None:
        kind = msg.get_type()
        self._received[kind] += 1
        own = (msg.get_srcSystem(), msg.get_srcComponent()) == (self._endpoint.system_id, self._endpoint.component_id)
        if own:
            return
        if kind not in _PASSIVE_MESSAGES:
            self._active = True
        now_s = self._clock_s()
        match kind:
            case "COMMAND_LONG" | "COMMAND_INT":
                if self._for_me(msg.target_system, msg.target_component):
                    self._command(msg, now_s)
            case "REQUEST_DATA_STREAM":
                if self._for_me(msg.target_system, msg.target_component):
                    self._request_data_stream(msg, now_s)
            case "TIMESYNC":
                if msg.tc1 == 0:  # a request; tc1 ≠ 0 would be a reply to us
                    self._send(self._endpoint.mav.timesync_encode(round(now_s * 1e9), msg.ts1))
            case "GPS_INPUT":
                self._record_gps_input(msg, now_s)
            case "ODOMETRY":
                self._record_odometry(msg, now_s)
            case "VISION_POSITION_ESTIMATE" if not self._px4:
                self._judge_vision_position(msg)
            case "GLOBAL_POSITION_SENSOR" if self._px4:
                self._judge_global_position_sensor(msg, now_s)
            case _:
                pass

    def _ack(self, msg: MavlinkMessage, result: int) -> None:
        self._send(
            self._endpoint.mav.command_ack_encode(
                msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _command(self, msg: MavlinkMessage, now_s: float) -> None:
        cmd = msg.command
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = message_name(round(msg.param1))
            if name is None:
                self._ack(msg, mavlink2.MAV_RESULT_FAILED)
                return
            interval_us = msg.param2
            if interval_us == 0:
                self._scheduler.reset(name, now_s=now_s)
            elif interval_us < 0:
                self._scheduler.set_rate(name, 0.0, now_s=now_s)
            else:
                self._scheduler.set_interval(name, interval_us * 1e-6, now_s=now_s)
            self._ack(msg, mavlink2.MAV_RESULT_ACCEPTED)
        elif cmd == mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL:
            msg_id = round(msg.param1)
            name = message_name(msg_id)
            interval = self._scheduler.interval_s(name) if name is not None else None
            interval_us = 0 if name is None else -1 if interval is None else round(interval * 1e6)
            self._send(self._endpoint.mav.message_interval_encode(msg_id, interval_us))
            self._ack(msg, mavlink2.MAV_RESULT_ACCEPTED)
        elif cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            name = message_name(round(msg.param1))
            if name is None:
                self._ack(msg, mavlink2.MAV_RESULT_FAILED)
                return
            self._ack(msg, mavlink2.MAV_RESULT_ACCEPTED)
            self._send(self._encoder.encode(name, self._state, now_s))
        elif cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(msg, mavlink2.MAV_RESULT_ACCEPTED)
            self._send(self._encoder.autopilot_version(self._state, now_s))
        elif cmd == mavlink2.MAV_CMD_SET_EKF_SOURCE_SET and not self._px4:  # ArduPilot's own command
            # GCS_Common.cpp handle_command_set_ekf_source_set: param1 = 1..3 (uint32_t cast: truncated), else DENIED
            p1 = float(msg.param1)
            number = math.trunc(p1) if math.isfinite(p1) else 0
            if not 1 <= number <= SOURCE_SET_COUNT:
                self._ack(msg, mavlink2.MAV_RESULT_DENIED)
                return
            self._drift.extnav.set_source_set(number, now_s)
            self._ack(msg, mavlink2.MAV_RESULT_ACCEPTED)
        else:
            self._ack(msg, mavlink2.MAV_RESULT_UNSUPPORTED)

    def _request_data_stream(self, msg: MavlinkMessage, now_s: float) -> None:
        hz = float(msg.req_message_rate) if msg.start_stop else 0.0
        if msg.req_stream_id == mavlink2.MAV_DATA_STREAM_ALL:
            for stream in Stream:
                self._scheduler.set_stream(stream, hz, now_s=now_s)
        elif msg.req_stream_id in {s.value for s in Stream}:
            self._scheduler.set_stream(Stream(msg.req_stream_id), hz, now_s=now_s)

    def _record_gps_input(self, msg: MavlinkMessage, now_s: float) -> None:
        rec = GpsInputRecord(
            received_t_s=now_s,
            time_usec=int(msg.time_usec),
            gps_id=int(msg.gps_id),
            ignore_flags=int(msg.ignore_flags),
            fix_type=int(msg.fix_type),
            lat_deg=msg.lat * 1e-7,
            lon_deg=msg.lon * 1e-7,
            alt_m=float(msg.alt),
            v_ned_m_s=np.array([msg.vn, msg.ve, msg.vd], dtype=np.float64),
            hdop=float(msg.hdop),
            vdop=float(msg.vdop),
            h_acc_m=float(msg.horiz_accuracy),
            v_acc_m=float(msg.vert_accuracy),
            speed_acc_m_s=float(msg.speed_accuracy),
            satellites=int(msg.satellites_visible),
            yaw_rad=math.radians(msg.yaw * 0.01) if msg.yaw else None,
        )
        with self._lock:
            self._gps_inputs.append(rec)
        truth = self._state.truth
        if self._px4:
            if truth is not None:
                p = np.asarray(self._frame.to_ned(rec.lat_deg, rec.lon_deg, rec.alt_m), dtype=np.float64).reshape(3)
                self._ekf2.gps_input(
                    t_s=now_s, fix_type=rec.fix_type, satellites=rec.satellites, hdop=rec.hdop, vdop=rec.vdop,
                    h_acc_m=rec.h_acc_m, v_acc_m=rec.v_acc_m, speed_acc_m_s=rec.speed_acc_m_s,
                    ignore_flags=rec.ignore_flags, fix_error_ne_m=(p - truth.pos_ned_m)[:2],
                    vel_error_ne_m_s=(rec.v_ned_m_s - truth.v_ned_m_s)[:2], gnss_outage=self._state.gnss_outage,
                )  # fmt: skip
            return
        extnav = self._drift.extnav
        if extnav.rules.sources.set(extnav.active_set).posxy != SourceXY.GPS:  # SelectVelPosFusion: not the source
            if truth is not None and self._state.gnss_outage:
                self._drift.judge.verdicts["source set: POSXY not GPS"] += 1
                self._drift.judge.outage_verdicts["source set: POSXY not GPS"] += 1
            return
        if truth is not None:  # judged outside outages too: GPS_AUTO_SWITCH decides whether the MAV instance counts
            p = np.asarray(self._frame.to_ned(rec.lat_deg, rec.lon_deg, rec.alt_m), dtype=np.float64).reshape(3)
            g = self._state.gnss  # the real receiver's last fix (None: lost, in an outage)
            self._drift.judge.gps_input(
                gps_id=rec.gps_id, fix_type=rec.fix_type, satellites=rec.satellites, ignore_flags=rec.ignore_flags,
                fix_error_ne_m=(p - truth.pos_ned_m)[:2], vel_error_ne_m_s=(rec.v_ned_m_s - truth.v_ned_m_s)[:2],
                h_acc_m=rec.h_acc_m, speed_acc_m_s=rec.speed_acc_m_s, airspeed_aiding=self._state.airspeed is not None,
                v_acc_m=rec.v_acc_m, t_s=now_s,
                real_fix_type=g.fix_type if g is not None else mavlink2.GPS_FIX_TYPE_NO_FIX,
                real_h_acc_m=g.h_acc_m if g is not None else None, real_v_acc_m=g.v_acc_m if g is not None else None,
                real_speed_acc_m_s=g.vel_acc_m_s if g is not None else None,
                real_age_s=now_s - g.t_s if g is not None else 0.0,
            )  # fmt: skip

    def _record_odometry(self, msg: MavlinkMessage, now_s: float) -> None:
        rec = OdometryRecord(
            received_t_s=now_s,
            time_usec=int(msg.time_usec),
            frame_id=int(msg.frame_id),
            child_frame_id=int(msg.child_frame_id),
            pos_m=np.array([msg.x, msg.y, msg.z], dtype=np.float64),
            q=np.asarray(msg.q, dtype=np.float64),
            vel_m_s=np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64),
            rates_rad_s=np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed], dtype=np.float64),
            pose_covariance=np.asarray(msg.pose_covariance, dtype=np.float64),
            velocity_covariance=np.asarray(msg.velocity_covariance, dtype=np.float64),
            reset_counter=int(msg.reset_counter),
            estimator_type=int(msg.estimator_type),
            quality=int(msg.quality),
        )
        with self._lock:
            self._odometry.append(rec)
        truth = self._state.truth
        if truth is not None and self._px4:
            self._ekf2.odometry(
                t_s=now_s, frame_id=rec.frame_id, child_frame_id=rec.child_frame_id, pos_m=rec.pos_m, q=rec.q,
                vel_m_s=rec.vel_m_s, pose_covariance=rec.pose_covariance, velocity_covariance=rec.velocity_covariance,
                reset_counter=rec.reset_counter, quality=rec.quality, truth_pos_ned_m=truth.pos_ned_m,
                truth_v_ned_m_s=truth.v_ned_m_s, gnss_outage=self._state.gnss_outage,
                estimator_type=rec.estimator_type, truth_q=truth.q_nb,
            )  # fmt: skip
        elif truth is not None:
            self._drift.extnav.odometry(
                time_usec=rec.time_usec, frame_id=rec.frame_id, child_frame_id=rec.child_frame_id, pos_m=rec.pos_m,
                q=rec.q, vel_m_s=rec.vel_m_s, pose_covariance=rec.pose_covariance, reset_counter=rec.reset_counter,
                quality=rec.quality, truth_pos_ned_m=truth.pos_ned_m, truth_v_ned_m_s=truth.v_ned_m_s,
                gnss_outage=self._state.gnss_outage,
            )  # fmt: skip

    def _judge_global_position_sensor(self, msg: MavlinkMessage, now_s: float) -> None:
        """GLOBAL_POSITION_SENSOR (296): degE7 and m AMSL, eph/epv [m], judged by EKF2's rules."""
        truth = self._state.truth
        if truth is None:
            return
        p = np.asarray(self._frame.to_ned(msg.lat * 1e-7, msg.lon * 1e-7, float(msg.alt)), dtype=np.float64)
        self._ekf2.global_position_sensor(
            t_s=now_s, fix_error_ne_m=(p.reshape(3) - truth.pos_ned_m)[:2], eph_m=float(msg.eph),
            epv_m=float(msg.epv), flags=int(msg.flags), gnss_outage=self._state.gnss_outage, sensor_id=int(msg.id),
        )  # fmt: skip

    def _judge_vision_position(self, msg: MavlinkMessage) -> None:
        truth = self._state.truth
        if truth is not None:
            self._drift.extnav.vision_position_estimate(
                usec=int(msg.usec), pos_m=np.array([msg.x, msg.y, msg.z], dtype=np.float64),
                covariance=np.asarray(msg.covariance, dtype=np.float64), reset_counter=int(msg.reset_counter),
                truth_pos_ned_m=truth.pos_ned_m, gnss_outage=self._state.gnss_outage,
            )  # fmt: skip


def run_sitl(
    world: World,
    url: str,
    *,
    speed: float,
    duration_s: float,
    tlog: Path | None = None,
    truth: Path | None = None,
    stream_rates: Mapping[str, float] | None = None,
    signing_key: bytes | None = None,
    require_signing: bool = False,
    ports_as_debug_array: bool = False,
    options: AutopilotOptions | None = None,
    on_ready: Callable[[str], None] | None = None,
    on_second: Callable[[float], None] | None = None,
) -> RunSummary:
    """Run the mock autopilot for the CLI: open ``url``, report it through ``on_ready``, fly, close.

    ``on_ready`` receives the link description (e.g. ``"pty /dev/pts/4"``, ``"udpin 0.0.0.0:14550"``) before
    the run starts, so a pty path or a bound port can be shown to the user; ``on_second`` receives the world
    time after each whole world second flown (a harness that acts at world times follows the world's clock, which
    falls behind ``speed`` × the wall clock on a machine too slow for that speed).
    """
    with MockAutopilot(
        world,
        url,
        speed=speed,
        stream_rates=stream_rates,
        signing_key=signing_key,
        require_signing=require_signing,
        ports_as_debug_array=ports_as_debug_array,
        tlog_path=tlog,
        truth_path=truth,
        options=options,
    ) as ap:
        if on_ready is not None:
            on_ready(ap.link.description)
        return ap.run(duration_s, on_second)
