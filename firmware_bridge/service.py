"""``vdm-aero serve``: the companion service.

One thread, one loop: read what the link delivers, convert it to SI once (:mod:`firmware_bridge.units`),
hand it to the same :class:`~vdm_aero.nav.driver.NavDriver` the log replay and the drift benchmark use, and
do the periodic work: HEARTBEAT (1 Hz), TIMESYNC, stream requests (re-sent while a stream is missing, so an
autopilot reboot or a lost command heals itself), outputs, the status line, the state file and the
systemd watchdog.

Bad input never stops the service: malformed frames are counted by the codec, a message whose handling
fails is counted and logged (its type and the error, rate-limited) and skipped, and a diverged filter
(non-finite state) is re-initialised at the next fix. Only a bad configuration or unreadable models stop it,
at start, with exit code 2.
"""

from __future__ import annotations

import hashlib
import math
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import outputs, units
from firmware_bridge.config import ServiceConfig
from firmware_bridge.decode import AUTOPILOT_LOST_S, IMU_SOURCES, MESSAGES, MavlinkDecoder
from firmware_bridge.endpoint import MavEndpoint, MavlinkMessage, load_signing_key
from firmware_bridge.inputs import PortFrameIn
from firmware_bridge.persist import FilterStateStore, NavLog
from firmware_bridge.sd_notify import SdNotify
from firmware_bridge.transport import open_transport
from vdm_aero._typing import F64Array
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.driver import NavDriver
from vdm_aero.nav.filter import AP_ATTITUDE_SIGMA_RAD, SLOW_IMU_HZ, NavConfig, NavFilter
from vdm_aero.nav.imu_increments import ImuIntegrator
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.ports_frontend import PortFrame, PortFrontEnd
from vdm_aero.nav.state import IDX
from vdm_aero.rotation import euler_from_quat

__all__ = ["CompanionService", "ServiceStats", "port_names"]

HEARTBEAT_S = 1.0
TIMESYNC_S = 2.0
STREAM_CHECK_S = 3.0
STREAM_MIN_FRACTION = 0.5  # a stream arriving at under half its requested rate is requested again
SOLUTION_STALE_S = 0.5  # a filter this far behind the autopilot's clock has no solution to give
LINK_GAP_S = 0.5  # the IMU (50-400 Hz) silent this long in the autopilot's time: a link gap, reported
POLL_MAX_S = 0.02
PERIODIC_S = 0.005
ERROR_LOG_EVERY_S = 10.0
LATENCY_WINDOW = 20000
RESTORE_WAIT_S = 3.0  # how long a restore waits for SYSTEM_TIME's boot instant before going without it


def models_identity(cfg: ServiceConfig) -> str:
    """The identity (sha256) of what the model corrections were estimated with: the design data set's and the
    models' manifests (each lists the sha256 of its files) and the vehicle description."""
    h = hashlib.sha256()
    for p in (cfg.design_data / "dataset.yaml", cfg.deim_model / "model.yaml",
              cfg.nn_model / "model.yaml" if cfg.nn_model is not None else None):  # fmt: skip
        if p is not None and p.is_file():
            h.update(p.read_bytes())
        h.update(b"\0")
    h.update(cfg.vehicle.encode())
    return h.hexdigest()


@dataclass
class ServiceStats:
    """Counters for the status line, the journal and the tests."""

    received: dict[str, int] = field(default_factory=dict)
    handler_errors: dict[str, int] = field(default_factory=dict)
    stream_requests: int = 0
    command_acks: dict[str, int] = field(default_factory=dict)
    commands_refused: int = 0  # COMMAND_LONG/INT addressed to us, answered MAV_RESULT_UNSUPPORTED
    solutions_sent: int = 0
    named_values_sent: int = 0
    filter_resets: int = 0
    link_gaps: list[dict[str, float]] = field(default_factory=list)  # {"wall_s", "autopilot_s"} per gap
    storage_errors: dict[str, int] = field(default_factory=dict)  # "state"/"nav_log" → failed writes
    last_storage_error: str = ""
    restored: list[str] = field(default_factory=list)
    latency_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))

    def latency_percentiles_ms(self) -> dict[str, float]:
        if not self.latency_s:
            return {"p50": math.nan, "p99": math.nan, "max": math.nan, "n": 0}
        a = np.asarray(self.latency_s) * 1e3
        return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
                "n": len(a)}  # fmt: skip


def port_names(cfg: ServiceConfig, models: NavModels) -> tuple[str, ...]:
    """The ports in the order the autopilot sends them: ``ports.names``, or the model's; the same set as the
    model's or a one-line error."""
    names = cfg.ports.names or models.port_names
    if set(names) != set(models.port_names):
        raise UserInputError(f"{cfg.path}: ports.names {list(names)} are not the model's ports "
                             f"{list(models.port_names)}")  # fmt: skip
    return tuple(names)


class CompanionService:
    """The service: ``run(should_stop)`` until ``should_stop()`` is true; see the module docstring."""

    def __init__(self, cfg: ServiceConfig, *, notify: SdNotify | None = None, out: TextIO = sys.stdout,
                 watchdog_s: float | None = None, models: NavModels | None = None) -> None:  # fmt: skip
        self.cfg = cfg
        self.out = out
        self.notify = notify or SdNotify(None)
        self.watchdog_s = watchdog_s
        self.models = models or NavModels.load(cfg.design_data, cfg.deim_model, cfg.nn_model, cfg.vehicle)
        self.port_names = port_names(cfg, self.models)
        self._port_order = np.array([self.port_names.index(n) for n in self.models.port_names])
        signing = None
        if cfg.signing_key_file is not None:
            signing = load_signing_key(cfg.signing_key_file, require=cfg.signing_require)
        self.store = FilterStateStore(cfg.state_file)
        self._saved = self.store.load()
        self.models_id = models_identity(cfg)
        self._fdi_reported = 0
        self._t_initialised_s = math.inf
        self.transport = open_transport(cfg.connection)
        self.ep = MavEndpoint(self.transport, system_id=cfg.system_id, component_id=cfg.component_id,
                              signing=signing)  # fmt: skip
        self.navlog = (NavLog(cfg.nav_log_file, max_bytes=cfg.nav_log_max_bytes, backups=cfg.nav_log_backups)
                       if cfg.nav_log_file is not None else None)  # fmt: skip
        self.stats = ServiceStats()
        # the one MAVLink decoder, shared with the tlog reader: its converters, its choice of streams, its clock
        self.decoder = MavlinkDecoder(self, system_id=cfg.system_id, port_names=self.port_names,
                                      ports_source=cfg.ports.source, ports_array_id=cfg.ports.debug_array_id,
                                      port_frame_timeout_s=cfg.ports.frame_timeout_s,
                                      gnss_latency_s=cfg.gnss_latency_s,
                                      imu_sources=[k for k in IMU_SOURCES if k in cfg.streams] or None)  # fmt: skip
        self.clock = self.decoder.clock
        assert self.decoder.assembler is not None
        self.assembler = self.decoder.assembler
        self.imu_int = ImuIntegrator(cfg.filter_rate_hz)
        self.frame: LocalFrame | None = None
        self.driver: NavDriver | None = None
        self.filter: NavFilter | None = None
        self._last_ap_heartbeat = -math.inf
        self._unix_minus_boot_s: float | None = None
        self._last_imu_in = math.nan  # local time the latest IMU sample arrived
        self._boot_now_s = -math.inf  # the autopilot's time of the latest IMU sample
        self._stream_seen: dict[str, int] = dict.fromkeys(cfg.streams, 0)
        self._next: dict[str, float] = {}
        self._next_ap: dict[str, float] = {}
        self._error_logged: dict[str, float] = {}
        self._force_streams = False
        self._streams_asked: set[str] = set()  # asked for at the last check
        self.stream_caps_hz: dict[str, float] = {}  # streams the autopilot sends slower than asked, at that rate
        self._inflation = outputs.inflation(cfg.outputs.solution_hz)
        # what is not sensor data (the sensor data go through the decoder)
        self._handlers: dict[str, Callable[[MavlinkMessage, float], None]] = {
            "TIMESYNC": self._on_timesync,
            "COMMAND_ACK": self._on_command_ack,
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
        }

    # ---------------------------------------------------------------------------------------- loop
    def run(self, should_stop: Callable[[], bool]) -> dict[str, Any]:
        """Serve until ``should_stop()``; saves the state and returns the final summary."""
        self.notify.notify(ready=1, status=f"listening on {self.transport.description}")
        self._print(f"vdm-aero serve: {self.cfg.mode} on {self.transport.description}, {len(self.port_names)} "
                    f"ports via {self.cfg.ports.source}, solution output {self.cfg.outputs.solution}")  # fmt: skip
        next_periodic = 0.0
        try:
            while not should_stop():
                now = time.monotonic()
                timeout = max(min(POLL_MAX_S, min(self._next.values(), default=now) - now), 0.0)
                msgs = self.ep.poll(timeout)
                t_in = self.ep.received_at
                for msg in msgs:
                    self._dispatch(msg, t_in)
                self.ep.autopilot = self.decoder.autopilot  # only its frames name the reply address (udpin)
                now = time.monotonic()
                if now >= next_periodic:  # ~1000 polls a second at 400 Hz IMU: the upkeep needs 200
                    next_periodic = now + PERIODIC_S
                    self._periodic(now)
        finally:
            self.notify.notify(stopping=1, status="saving the filter state")
            self._print(f"vdm-aero serve: {self._save_state()}")
            if self.navlog is not None:
                self.navlog.close()
            self.transport.close()
        return self.summary()

    def _dispatch(self, msg: MavlinkMessage, t_in: float) -> None:
        kind = msg.get_type()
        self.stats.received[kind] = self.stats.received.get(kind, 0) + 1
        if kind in self._stream_seen and self._from_autopilot(msg):
            self._stream_seen[kind] += 1  # the requested streams' rates, checked every STREAM_CHECK_S
        handler = self.decoder.feed if kind in MESSAGES else self._handlers.get(kind)
        if handler is None:
            return
        try:
            handler(msg, t_in)
        except Exception as e:  # noqa: BLE001 - one bad message must not stop navigation; counted and logged
            self._count_error(kind, e)

    def _count_error(self, kind: str, e: Exception) -> None:
        """Count a failed message handler (or the periodic upkeep), logged at most every ERROR_LOG_EVERY_S."""
        self.stats.handler_errors[kind] = self.stats.handler_errors.get(kind, 0) + 1
        now = time.monotonic()
        if now - self._error_logged.get(kind, -math.inf) > ERROR_LOG_EVERY_S:
            self._error_logged[kind] = now
            where = traceback.extract_tb(e.__traceback__)[-1]
            self._print(f"vdm-aero serve: {kind} skipped: {type(e).__name__}: {e} "
                        f"({where.filename.rsplit('/', 1)[-1]}:{where.lineno}); "
                        f"{self.stats.handler_errors[kind]} so far")  # fmt: skip

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot, once its HEARTBEAT is heard."""
        return self.decoder.autopilot

    def _from_autopilot(self, msg: MavlinkMessage) -> bool:
        return self.decoder.from_autopilot(msg)

    def _link_gap(self, boot_s: float, t_in: float) -> None:
        """The IMU resumes after ≥ LINK_GAP_S of the autopilot's time: a link drop-out (the autopilot's clock
        ran on, ours saw nothing). Reported and counted; the streams are requested again (a router or radio
        that dropped out may have lost the requests); the filter coasts through the gap (NavFilter)."""
        gap = {"autopilot_s": boot_s - self._boot_now_s, "wall_s": t_in - self._last_imu_in, "at_boot_s": boot_s}
        self.stats.link_gaps.append(gap)
        self._force_streams = True
        self._next.pop("streams", None)
        self._print(f"vdm-aero serve: link back after {gap['autopilot_s']:.1f} s of autopilot time without data "
                    f"({gap['wall_s']:.1f} s here); re-requesting streams; "
                    f"{len(self.stats.link_gaps)} gap(s) so far")  # fmt: skip

    def _due(self, key: str, now: float, period_s: float) -> bool:
        """Periodic work on the local clock (link upkeep, status, watchdog)."""
        if now < self._next.get(key, -math.inf):
            return False
        self._next[key] = now + period_s
        return True

    def _due_ap(self, key: str, period_s: float) -> bool:
        """Periodic outputs on the autopilot's clock: their rates hold in faster-than-real-time SITL too."""
        t = self._boot_now_s
        if not math.isfinite(t):
            return False
        nxt = self._next_ap.get(key, -math.inf)
        if nxt - t > 2.0 * period_s:  # the autopilot's clock went back (a reboot)
            nxt = -math.inf
        if t < nxt:
            return False
        self._next_ap[key] = t + period_s - 1e-6
        return True

    # --------------------------------------------------------------- the decoder's sink (DecodedSink)
    def on_autopilot(self, src: tuple[int, int], new: bool, t_in: float) -> None:
        if new:
            self._print(f"vdm-aero serve: autopilot {src[0]}/{src[1]} heard; requesting streams")
            self._next.pop("streams", None)  # request the streams now (a new or rebooted autopilot)
        self._last_ap_heartbeat = t_in

    def on_reboot(self, boot_s: float) -> None:
        self._print(f"vdm-aero serve: autopilot reboot (boot time {boot_s:.1f} s); re-requesting streams")
        if self.driver is not None:
            for f in self.driver.filters.values():
                f.autopilot_rebooted()
        self.imu_int.reset()
        self._force_streams = True  # every stream is back at the autopilot's defaults (RAW_IMU at 1 Hz): ask now
        self._next.pop("streams", None)
        self._boot_now_s = -math.inf  # a reboot is not a link gap

    def on_imu_source(self, kind: str) -> None:
        self._print(f"vdm-aero serve: IMU from {kind}")
        self.imu_int.reset()  # increments never mix two IMUs

    def on_imu(self, t_s: float, s: units.ImuSample, t_in: float) -> None:
        if math.isfinite(self._boot_now_s) and s.t_s - self._boot_now_s >= LINK_GAP_S:
            self._link_gap(s.t_s, t_in)
        self._last_imu_in = t_in
        self._boot_now_s = s.t_s
        step = self.imu_int.add(s.t_s, s.gyro_b_rad_s, s.accel_b_m_s2)
        if step is not None and self.driver is not None:
            t_end, inc = step
            self.driver.imu(self.clock.filter_s(t_end), inc, s.temperature_c)
            self._check_finite()

    def on_mag(self, t_s: float, field_b_ut: tuple[float, float, float]) -> None:
        if self.driver is not None:
            self.driver.mag(t_s, np.array(field_b_ut))

    def on_baro(self, t_s: float, static_pa: float) -> None:
        if self.driver is not None:
            self.driver.baro(t_s, static_pa)

    def on_pitot(self, t_s: float, dp_pa: float, temperature_c: float) -> None:
        if self.driver is not None:
            self.driver.pitot(t_s, dp_pa, temperature_c)

    def on_gnss(self, t_valid_s: float, t_arrived_s: float, fix: units.GnssFix) -> None:
        # the time of validity is the decoder's: GPS_RAW_INT is stamped when the autopilot received the fix,
        # less the configured receiver latency (what ArduPilot's GPS_DELAY_MS and PX4's EKF2_GPS_DELAY subtract)
        if not math.isfinite(self._boot_now_s):
            return
        if self.frame is None:  # the first 3-D fix sets the local origin; the next ones initialise the filter
            self._start_filter(fix)
            return
        assert self.driver is not None
        p = self.frame.to_ned(fix.lat_deg, fix.lon_deg, fix.alt_m)
        t_now = max(self.clock.filter_s(self._boot_now_s), t_arrived_s)
        was = self.filter is not None and self.filter.initialised
        self.driver.gnss(t_valid_s, t_now, np.asarray(p, dtype=np.float64).reshape(3), fix.v_ned_m_s)
        if not was and self.filter is not None and self.filter.initialised:
            self._t_initialised_s = t_now
        self._restore_state(t_now)

    def on_servo(self, t_s: float, pwm_us: F64Array) -> None:
        if self.driver is None or not math.isfinite(self._boot_now_s):
            return
        servos = self.models.vehicle.servos
        ail, ele, rud, thr = servos.deflections_rad(servos.surfaces_pwm_us(pwm_us[None, :]))
        self.driver.servo(t_s, np.array([ail[0], ele[0], rud[0]]), float(thr[0]))

    def on_ports(self, t_s: float, frame: PortFrameIn) -> None:
        if self.driver is None:
            return
        solved = self.driver.solve_ports(t_s, frame.dp_pa[self._port_order])
        if solved is None:
            return
        # the aerodynamic outputs first (they need the solved frame, not the filter), then the filter update
        self._outputs(solved)
        self.stats.latency_s.append(time.monotonic() - frame.arrived_at)
        self.driver.fuse_ports(solved)

    def on_system_time(self, unix_minus_boot_s: float) -> None:
        self._unix_minus_boot_s = unix_minus_boot_s
        if math.isfinite(self._boot_now_s):  # the clock has started
            self._restore_state(self.clock.filter_s(self._boot_now_s))

    def on_truth(self, kind: str, msg: MavlinkMessage, t_in: float) -> None:
        pass  # SITL's truth is for replay reports, not for navigating

    def on_ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        # fused only by a filter started on an IMU too slow to integrate alone (NavConfig.ap_attitude_sigma_rad)
        if self.driver is not None and math.isfinite(self._boot_now_s):
            self.driver.ap_attitude(t_s, q_nb)

    def on_ap_position(self, t_s: float, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        pass  # the autopilot's estimate is what the service is compared with, not an input

    def _restore_state(self, t_s: float) -> None:
        """The saved slow states into the initialised filter, once the autopilot's boot instant is known
        (SYSTEM_TIME, 1 Hz: at most RESTORE_WAIT_S after the filter started, then without it)."""
        f = self.filter
        if f is None or not f.initialised or self._saved is None:
            return
        if self._unix_minus_boot_s is None and t_s - self._t_initialised_s < RESTORE_WAIT_S:
            return
        boot = self._unix_minus_boot_s if self._unix_minus_boot_s is not None else math.nan
        self.stats.restored = FilterStateStore.restore(f, self._saved, models_id=self.models_id,
                                                       autopilot_boot_unix_s=boot)  # fmt: skip
        self._saved = None
        kept = [r for r in self.stats.restored if not r.startswith("-")]
        held = {"-aero": "model corrections (another mode or other models)",
                "-bias-sigma": "bias certainty (the autopilot has booted since)"}  # fmt: skip
        back = [held[r] for r in self.stats.restored if r in held]
        self._print(f"vdm-aero serve: restored {', '.join(kept)} from {self.store.path}"
                    + (f"; not restored: {'; '.join(back)}" if back else ""))  # fmt: skip

    def _start_filter(self, fix: units.GnssFix) -> None:
        m = self.models
        self.frame = LocalFrame(fix.lat_deg, fix.lon_deg, fix.alt_m)
        # an IMU too slow to integrate alone (a radio link, a ground station's rates): its samples are points, not
        # averages, and the autopilot's ATTITUDE, from its IMU at full rate, is fused beside it (as replay does)
        imu_hz = 1.0 / self.imu_int.typical_dt_s
        slow = imu_hz < SLOW_IMU_HZ
        cfg = NavConfig(vehicle=m.vehicle, origin_alt_m=fix.alt_m, filter_rate_hz=self.cfg.filter_rate_hz,
                        gnss_latency_s=self.cfg.gnss_latency_s, mag_field_ned_ut=np.asarray(self.cfg.mag_field_ned_ut),
                        ap_attitude_sigma_rad=AP_ATTITUDE_SIGMA_RAD if slow else None,
                        imu_point_samples=slow)  # fmt: skip
        if slow:
            fused = "its ATTITUDE is fused" if "ATTITUDE" in self.cfg.streams else "no ATTITUDE is asked for"
            self._print(f"vdm-aero serve: IMU at {imu_hz:.1f} Hz, too slow to integrate alone (< {SLOW_IMU_HZ:g} "
                        f"Hz): {fused}; expect a poorer solution than on a full-rate IMU")  # fmt: skip
        self.filter = NavFilter(self.cfg.mode, cfg, m.derivatives)
        fe = PortFrontEnd(m.pressure_model, dict(m.models), range_pa=self.cfg.ports.range_pa,
                          noise_pa=self.cfg.ports.noise_pa)  # fmt: skip
        self.driver = NavDriver({self.cfg.mode: self.filter}, fe)
        self._print(f"vdm-aero serve: origin {fix.lat_deg:.7f}, {fix.lon_deg:.7f}, {fix.alt_m:.1f} m")

    def _report_fdi(self) -> None:
        """Each air-data FDI status change once, in the journal (with the autopilot time of the change)."""
        f = self.filter
        if f is None or f.fdi is None:
            return
        for e in f.fdi.events[self._fdi_reported :]:
            what = "excluded: it disagrees with the others" if e.what == "excluded" else "re-admitted: it agrees again"
            self._print(f"vdm-aero serve: air data: {e.source} {what} (NIS/dim {e.nis_per_dim:.1f}, "
                        f"boot time {self.clock.boot_s(e.t_s):.1f} s)")  # fmt: skip
        self._fdi_reported = len(f.fdi.events)

    def _check_finite(self) -> None:
        f = self.filter
        if f is None or f.x is None:
            return
        if not (np.all(np.isfinite(f.x.p_ned)) and np.all(np.isfinite(f.x.v_ned)) and np.all(np.isfinite(f.P))):
            self.stats.filter_resets += 1
            self._print("vdm-aero serve: the filter diverged (non-finite state); re-initialising at the next fix")
            f.x = None
            f.engine = None

    def _on_timesync(self, msg: MavlinkMessage, t_in: float) -> None:
        """The autopilot's reply to our request (tc1 ≠ 0), or its request (tc1 = 0: ArduPilot and PX4 both ask
        their companions): answered with our monotonic clock [ns] and its ts1 echoed, as the MAVLink timesync
        protocol says."""
        if not self._from_autopilot(msg):
            return
        if msg.tc1 != 0:
            self.clock.timesync(int(msg.tc1), int(msg.ts1), time.monotonic_ns())
        else:
            self.ep.send(self.ep.mav.timesync_encode(time.monotonic_ns(), int(msg.ts1)))

    def _on_command(self, msg: MavlinkMessage, t_in: float) -> None:
        """A command addressed to us: the MAVLink command protocol wants an answer, and the service carries out
        none (nothing can be injected): MAV_RESULT_UNSUPPORTED, to the sender (commands to others are not ours)."""
        if (msg.target_system, msg.target_component) != (self.cfg.system_id, self.cfg.component_id):
            return
        self.stats.commands_refused += 1
        self.ep.send(self.ep.mav.command_ack_encode(msg.command, mavlink2.MAV_RESULT_UNSUPPORTED, 0, 0,
                                                    msg.get_srcSystem(), msg.get_srcComponent()))  # fmt: skip

    def _on_command_ack(self, msg: MavlinkMessage, t_in: float) -> None:
        key = f"{msg.command}:{msg.result}"
        self.stats.command_acks[key] = self.stats.command_acks.get(key, 0) + 1

    # ------------------------------------------------------------------------------------ outputs
    def solution(self) -> outputs.Solution | None:
        """The current navigation solution (None before the filter is initialised)."""
        f = self.filter
        if f is None or f.x is None or self.frame is None or not math.isfinite(self._boot_now_s):
            return None
        if self.clock.filter_s(self._boot_now_s) - f.t_s > SOLUTION_STALE_S:
            return None  # the IMU resumed after a gap and the filter has not caught up: its pose is old
        x = f.x
        lat, lon, alt = self.frame.to_geodetic(float(x.p_ned[0]), float(x.p_ned[1]), float(x.p_ned[2]))
        p = f.P
        sig_h = f.horizontal_sigma_m()
        w = IDX["wind"]
        wind_var = float(np.max(np.linalg.eigvalsh(p[w, w][:2, :2])))
        unix = (self._unix_minus_boot_s + self._boot_now_s) if self._unix_minus_boot_s is not None else time.time()
        o = self.cfg.outputs
        fix = outputs.fix_type_from(sig_h, healthy=f.initialised, max_sigma_3d_m=o.max_sigma_3d_m,
                                    max_sigma_m=o.max_sigma_m)  # fmt: skip
        if f.fallback:  # the ports give no air data: airspeed dead reckoning at best, a 2-D fix at most
            fix = min(fix, mavlink2.GPS_FIX_TYPE_2D_FIX)
        return outputs.Solution(
            boot_s=self._boot_now_s, unix_s=unix, lat_deg=lat, lon_deg=lon, alt_m=alt, p_ned_m=x.p_ned.copy(),
            v_ned_m_s=x.v_ned.copy(), q_nb=x.q_nb.copy(), sigma_h_m=sig_h, sigma_v_m=math.sqrt(max(p[2, 2], 0.0)),
            sigma_vel_m_s=math.sqrt(max(float(np.max(np.diag(p)[3:6])), 0.0)), wind_ned_m_s=x.wind_ned.copy(),
            sigma_wind_m_s=math.sqrt(max(wind_var, 0.0)), fix_type=fix,
        )  # fmt: skip

    def _outputs(self, frame: PortFrame) -> None:
        o = self.cfg.outputs
        if o.named_values_hz > 0 and self._due_ap("named", 1.0 / o.named_values_hz):
            self._send_named_values(frame)

    def _send_named_values(self, frame: PortFrame) -> None:
        f = self.filter
        pre = self.cfg.outputs.prefix + "_"
        vals: dict[str, float] = {}
        model = (f.spec.force if f is not None and f.spec.force in frame.coeffs else None) or next(iter(frame.coeffs),
                                                                                                    None)  # fmt: skip
        if model is not None and math.isfinite(frame.qbar_pa):
            s_ref = self.models.vehicle.reference.area_m2
            fx, fy, fz = (float(v) * frame.qbar_pa * s_ref for v in frame.coeffs[model][:3])
            vals.update({pre + "FX": fx, pre + "FY": fy, pre + "FZ": fz})
        if frame.airdata is not None:
            vals.update({pre + "TAS": float(frame.airdata[0]), pre + "AOA": float(frame.airdata[1]),
                         pre + "SSA": float(frame.airdata[2])})  # fmt: skip
        if f is not None and f.x is not None:
            vals.update({pre + "WN": float(f.x.wind_ned[0]), pre + "WE": float(f.x.wind_ned[1]),
                         pre + "SIGH": f.horizontal_sigma_m()})  # fmt: skip
        vals[pre + "HLTH"] = float(self._health_code())
        for m in outputs.named_values(self.ep.mav, self._boot_now_s, vals):
            self.ep.send(m)
            self.stats.named_values_sent += 1

    def _health_code(self) -> int:
        """Bit field: 1 initialised, 2 GNSS outage, 4 fallback (no port air data), 8 ports missing; the air-data
        sources the FDI has excluded (mode vdm): 16 pitot, 32 port air data, 64 force model."""
        f = self.filter
        if f is None or not f.initialised:
            return 0
        ok, n = f.port_health
        code = 1 | (2 if f.in_outage else 0) | (4 if f.fallback else 0) | (8 if ok < n else 0)
        for bit, source in ((16, "pitot"), (32, "ports"), (64, "force")):
            if f.fdi is not None and not f.fdi.fused(source):
                code |= bit
        return code

    def _send_solution(self, now: float) -> None:
        o = self.cfg.outputs
        f = self.filter
        if o.solution == "none" or f is None or not f.initialised or not f.in_outage or self.autopilot is None:
            return
        if not self._due_ap("solution", 1.0 / o.solution_hz):
            return
        s = self.solution()
        if s is None:
            return
        k = self._inflation
        if o.solution == "gps_input":
            self.ep.send(outputs.gps_input(self.ep.mav, s, gps_id=o.gps_id, k=k))
            if o.external_wind and self._due_ap("wind", 1.0):
                self.ep.send(outputs.external_wind(self.ep.mav, s, target=self.autopilot))
        elif o.solution == "global_position_sensor":
            self.ep.send(outputs.global_position_sensor(self.ep.mav, s, target=self.autopilot, k=k))
        else:
            self.ep.send(outputs.odometry(self.ep.mav, s, k=k))
        self.stats.solutions_sent += 1

    # ----------------------------------------------------------------------------------- periodic
    def _periodic(self, now: float) -> None:
        try:
            self._upkeep(now)
        except Exception as e:  # noqa: BLE001 - an output built from bad input must not stop navigation
            self._count_error("periodic", e)

    def _upkeep(self, now: float) -> None:
        self.decoder.expire_ports(now)
        self._report_fdi()
        if self._due("heartbeat", now, HEARTBEAT_S):
            hb = self.ep.mav.heartbeat_encode(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID,
                                              0, 0, mavlink2.MAV_STATE_ACTIVE)  # fmt: skip
            self.ep.send(hb)
        if self.autopilot is not None and now - self._last_ap_heartbeat < AUTOPILOT_LOST_S:
            if self._due("timesync", now, TIMESYNC_S):
                self.ep.send(self.ep.mav.timesync_encode(0, time.monotonic_ns()))
            if self._due("streams", now, STREAM_CHECK_S):
                self._request_streams()
        self._send_solution(now)
        if self.navlog is not None and self._due_ap("navlog", 1.0 / self.cfg.nav_log_hz):
            self._log_solution()
        if self._due("status", now, self.cfg.status_every_s):
            line = self.status_line()
            self._print(line)
            self.notify.notify(status=line)
        if self.watchdog_s is not None and self._due("watchdog", now, 0.5 * self.watchdog_s):
            self.notify.notify(watchdog=1)
        if self._due("save", now, self.cfg.state_save_every_s):
            self._save_state()

    def _request_streams(self) -> None:
        """SET_MESSAGE_INTERVAL for every configured stream that is missing or slow since the last check.

        A stream that keeps coming, but slower than asked, after it was asked for is capped by the autopilot
        (ArduPilot sends nothing faster than its loop, SCHED_LOOP_RATE: 50 Hz on ArduPlane unless raised): said
        once, and from then on judged against the rate it comes at, so a reboot's 1 Hz default still heals."""
        assert self.autopilot is not None
        force, self._force_streams = self._force_streams, False
        asked, self._streams_asked = self._streams_asked, set()
        for name, hz in self.cfg.streams.items():
            seen = self._stream_seen.get(name, 0)
            self._stream_seen[name] = 0
            rate = seen / STREAM_CHECK_S
            if name in asked and 0 < rate < STREAM_MIN_FRACTION * hz and name not in self.stream_caps_hz:
                self.stream_caps_hz[name] = rate
                self._print(f"vdm-aero serve: {name} comes at {rate:.0f} Hz of the {hz:g} Hz asked for: the autopilot "
                            "caps it (ArduPilot: no faster than SCHED_LOOP_RATE; docs/service.md)")  # fmt: skip
            want = min(hz, self.stream_caps_hz.get(name, math.inf))
            if not force and hz > 0 and seen >= STREAM_MIN_FRACTION * want * STREAM_CHECK_S:
                continue
            msg_id = getattr(mavlink2, f"MAVLINK_MSG_ID_{name}")
            interval_us = 1e6 / hz if hz > 0 else -1
            self.ep.send(self.ep.mav.command_long_encode(self.autopilot[0], self.autopilot[1],
                                                         mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                                         interval_us, 0, 0, 0, 0, 0))  # fmt: skip
            self.stats.stream_requests += 1
            self._streams_asked.add(name)

    def _storage_failed(self, what: str, e: OSError) -> None:
        """A write to the state directory failed (full disk, read-only, removed): navigation goes on; counted,
        in the status line, and logged when it starts failing and every ERROR_LOG_EVERY_S after."""
        n = self.stats.storage_errors[what] = self.stats.storage_errors.get(what, 0) + 1
        self.stats.last_storage_error = f"{what}: {e.strerror or e}"
        now = time.monotonic()
        if now - self._error_logged.get("storage:" + what, -math.inf) > ERROR_LOG_EVERY_S:
            self._error_logged["storage:" + what] = now
            self._print(f"vdm-aero serve: cannot write the {what.replace('_', ' ')}: {e.strerror or e} "
                        f"({getattr(e, 'filename', None) or ''}); navigation goes on; {n} failed write(s)")  # fmt: skip

    def _log_solution(self) -> None:
        s = self.solution()
        f = self.filter
        if s is None or f is None or self.navlog is None:
            return
        roll, pitch, yaw = euler_from_quat(s.q_nb)
        try:
            self._write_nav_row(s, f, roll, pitch, yaw)
        except OSError as e:
            self._storage_failed("nav_log", e)

    def _write_nav_row(self, s: outputs.Solution, f: NavFilter, roll: float, pitch: float, yaw: float) -> None:
        assert self.navlog is not None
        self.navlog.write([s.unix_s, s.boot_s, s.lat_deg, s.lon_deg, s.alt_m, *map(float, s.p_ned_m),
                           *map(float, s.v_ned_m_s), roll, pitch, yaw, s.sigma_h_m, float(s.wind_ned_m_s[0]),
                           float(s.wind_ned_m_s[1]), "outage" if f.in_outage else "aided", f.mode,
                           f.port_health[0], self._health_code()])  # fmt: skip

    def _save_state(self) -> str:
        """Save the filter's slow states; returns what happened, in words (the shutdown line says it)."""
        f = self.filter
        if f is None or f.x is None or f.engine is None:
            return "no filter state to save (the filter is not initialised)"
        try:
            boot = self._unix_minus_boot_s if self._unix_minus_boot_s is not None else math.nan
            saved = self.store.save(f, models_id=self.models_id, autopilot_boot_unix_s=boot)
        except OSError as e:
            self._storage_failed("state", e)
            return f"filter state NOT saved to {self.store.path}: {e.strerror or e}"
        if not saved:
            return "filter state not saved: it is not finite (the last good state file stays)"
        return f"filter state saved to {self.store.path}"

    # ------------------------------------------------------------------------------------- status
    def status_line(self) -> str:
        f = self.filter
        if f is None or not f.initialised:
            ap = "autopilot heard" if self.autopilot else "waiting for the autopilot"
            return f"status: {ap}, filter not initialised (no GNSS fix yet); {sum(self.stats.received.values())} msgs"
        h = f.health()
        x = f.x
        assert x is not None
        wind = math.hypot(float(x.wind_ned[0]), float(x.wind_ned[1]))
        lat = self.stats.latency_percentiles_ms()
        fb = f", FALLBACK {h['fallback']}" if h["fallback"] else ""
        return (f"status: {h['mode']} gnss={h['gnss']} ports {h['ports_ok']}/{h['ports']}{fb} "
                f"σh={h['horizontal_sigma_m']:.1f} m wind={wind:.1f} m/s frames {self.assembler.counts['complete']}"
                f"+{self.assembler.counts['partial']} partial, rejected unsigned {self.ep.rejected_unsigned}"
                + (f" and replayed {self.ep.rejected_replayed}" if self.ep.rejected_replayed else "")
                + f", bad frames {self.ep.bad_frames}, lost {getattr(self.ep, 'lost_frames', 0)}, "
                f"duplicated {self.ep.duplicate_frames}, "
                f"errors {sum(self.stats.handler_errors.values())}, latency p99 {lat['p99']:.2f} ms"
                + (f", link gaps {len(self.stats.link_gaps)}" if self.stats.link_gaps else "")
                + (f", STORAGE FAILING ({self.stats.last_storage_error})"
                   if self.stats.storage_errors else ""))  # fmt: skip

    def summary(self) -> dict[str, Any]:
        f = self.filter
        return {
            "received": dict(self.stats.received),
            "sent": dict(self.ep.sent),
            "handler_errors": dict(self.stats.handler_errors),
            "rejected_unsigned": self.ep.rejected_unsigned,
            "rejected_replayed": self.ep.rejected_replayed,
            "bad_frames": self.ep.bad_frames,
            "port_frames": dict(self.assembler.counts),
            "stream_requests": self.stats.stream_requests,
            "commands_refused": self.stats.commands_refused,
            "stream_caps_hz": dict(self.stream_caps_hz),
            "solutions_sent": self.stats.solutions_sent,
            "named_values_sent": self.stats.named_values_sent,
            "filter_resets": self.stats.filter_resets,
            "duplicates": sum(self.decoder.duplicates.get(k, 0) for k in IMU_SOURCES),
            "stale_imu_frames": sum(self.decoder.stale.values()),  # older than their stream's latest: dropped
            "lost_frames": getattr(self.ep, "lost_frames", 0),
            "duplicate_frames": self.ep.duplicate_frames,
            "link_gaps": list(self.stats.link_gaps),
            "storage_errors": dict(self.stats.storage_errors),
            "dropped_sends": self.transport.dropped_sends,
            "reconnects": self.transport.reconnects,
            "autopilot_reboots": self.clock.reboots,
            "restored": list(self.stats.restored),
            "state_saves": self.store.saves,
            "latency_ms": self.stats.latency_percentiles_ms(),
            "timesync_offset_s": self.clock.offset_s,
            "health": f.health() if f is not None else None,
        }

    def _print(self, line: str) -> None:
        print(line, file=self.out, flush=True)
