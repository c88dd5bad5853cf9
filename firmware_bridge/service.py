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
from firmware_bridge.config import ServiceConfig, SourceSwitchConfig
from firmware_bridge.decode import AUTOPILOT_LOST_S, IMU_SOURCES, MESSAGES, MavlinkDecoder
from firmware_bridge.endpoint import MavEndpoint, MavlinkMessage, load_signing_key
from firmware_bridge.inputs import PortFrameIn
from firmware_bridge.periodic import ClockSchedule
from firmware_bridge.persist import FilterStateStore, NavLog
from firmware_bridge.sd_notify import SdNotify
from firmware_bridge.transport import open_transport
from vdm_aero._typing import F64Array
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.driver import NavDriver
from vdm_aero.nav.filter import AP_ATTITUDE_SIGMA_RAD, GNSS_TIMEOUT_S, SLOW_IMU_HZ, NavConfig, NavFilter
from vdm_aero.nav.imu_increments import ImuIntegrator
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.ports_frontend import PortFrame
from vdm_aero.nav.state import IDX
from vdm_aero.rotation import euler_from_quat

__all__ = ["CompanionService", "EkfSourceSwitch", "ServiceStats", "port_names"]

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
ORIGIN_REQUEST_S = 5.0  # GPS_GLOBAL_ORIGIN asked for this often until it comes (ArduPilot has none before its EKF
# has one: GCS_MAVLINK::send_gps_global_origin sends nothing then, and the request is still ACCEPTED)
ARDUPILOT_BOOT_SOURCE_SET = 1  # AP_NavEKF_Source::init: EKF3 starts every boot with EK3_SRC1_*


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
    odometry_without_origin: int = 0  # ArduPilot ODOMETRY due but the EKF origin not yet known: not sent
    origin_requests: int = 0
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


class EkfSourceSwitch:
    """ArduPilot's EKF3 source set, switched by MAV_CMD_SET_EKF_SOURCE_SET (``outputs.source_switch``).

    * **Wanted**: the ExternalNav set once no 3-D fix has come for GNSS_TIMEOUT_S (the filter's own outage
      test: GPS_RAW_INT without a 3-D fix is skipped by the decoder, and a silent stream is the same) *and* the
      service sends a solution ArduPilot can use (ODOMETRY with quality ≥ 1); the GNSS set once fixes have come
      without such a gap for ``gnss_hold_s``. In between the wish is held (a flickering receiver does not
      toggle the EKF's sources). At start the autopilot's set is unknown (the service may restart mid-flight):
      the first wish is sent even when it is the GNSS set.
    * **Sent** on the autopilot's clock of the wish, then again every ``retry_s`` of local time with
      ``confirmation`` + 1 until COMMAND_ACK ACCEPTED, at most ``max_tries`` times; then given up (counted and
      said) until the wish changes or the autopilot reboots. IN_PROGRESS waits one more period;
      TEMPORARILY_REJECTED is retried within the same bound; any other result (DENIED or FAILED: not a set 1..3,
      UNSUPPORTED: a build without it) is final for this wish. An ACK with nothing pending is counted, never
      acted on.
    * **A reboot** of the autopilot puts EKF3 back in set 1 (AP_NavEKF_Source::init). Nothing is sent while
      the autopilot is not heard; after a link drop-out a switch given up for want of an ACK is tried again.

    Times: ``t_s`` the autopilot's clock (the filter's), ``now_s`` the local monotonic clock (the link's)."""

    NAMES = ("GNSS", "ExternalNav")

    def __init__(self, cfg: SourceSwitchConfig, send: Callable[[int, int], None], say: Callable[[str], None]
                 ) -> None:  # fmt: skip
        self.cfg = cfg
        self._send, self._say = send, say
        self.active: int | None = None  # the set the autopilot confirmed; None: unknown
        self.wanted: int | None = None
        self.pending: int | None = None  # the set asked for and not yet confirmed
        self.tries = 0
        self._next_try_s = -math.inf
        self._given_up: int | None = None  # the wish given up on (no ACK, or refused)
        self._silent = False  # given up for want of an ACK (a link drop-out gives it a new round)
        self._last_fix_s = -math.inf
        self._fixes_since_s = math.inf  # start of the current run of fixes without a GNSS_TIMEOUT_S gap
        self._now_s = -math.inf
        self.counts: dict[str, int] = {"sent": 0, "accepted": 0, "refused": 0, "in_progress": 0, "gave_up": 0,
                                       "unmatched_acks": 0, "to_extnav": 0, "to_gnss": 0}  # fmt: skip

    def name(self, source_set: int | None) -> str:
        if source_set is None:
            return "unknown"
        kind = self.NAMES[1] if source_set == self.cfg.extnav_set else self.NAMES[0]
        return f"{source_set} ({kind})"

    def gnss_fix(self, t_s: float) -> None:
        """A 3-D fix arrived at ``t_s`` (autopilot clock)."""
        if t_s - self._last_fix_s > GNSS_TIMEOUT_S:
            self._fixes_since_s = t_s
        self._last_fix_s = max(self._last_fix_s, t_s)

    def gnss_lost(self, t_s: float) -> bool:
        """A fix seen, and none for GNSS_TIMEOUT_S since (before the first fix GNSS is not lost: not yet had)."""
        return math.isfinite(self._last_fix_s) and t_s - self._last_fix_s > GNSS_TIMEOUT_S

    def update(self, t_s: float, now_s: float, *, solution_ok: bool) -> None:
        """Decide the wish at ``t_s`` and send what is due at ``now_s``."""
        self._now_s = now_s
        if not math.isfinite(t_s):
            return
        c = self.cfg
        if self.gnss_lost(t_s):
            if solution_ok:
                self.wanted = c.extnav_set
        elif t_s - self._fixes_since_s >= c.gnss_hold_s:
            self.wanted = c.gnss_set
        want = self.wanted
        if want is None or (want == self.active and self.pending is None):
            return
        if want != self.pending:  # a new wish: a new command, counted from its first transmission
            if self.pending is not None:  # the last one may have been carried out with its ACK lost
                self.active = None
            self.pending, self.tries, self._next_try_s = want, 0, now_s
            self._given_up = None
            if want == self.active:  # back to what the autopilot already has: nothing to send
                self.pending = None
                return
        if self._given_up == want or now_s < self._next_try_s:
            return
        if self.tries >= c.max_tries:
            self.active = None  # carried out with every ACK lost, or not at all: unknown
            self._give_up(f"no COMMAND_ACK ACCEPTED after {self.tries} transmissions")
            self._silent = True
            return
        self._send(want, self.tries)
        self.tries += 1
        self.counts["sent"] += 1
        self._next_try_s = now_s + c.retry_s

    def ack(self, result: int) -> None:
        """COMMAND_ACK of MAV_CMD_SET_EKF_SOURCE_SET from the autopilot."""
        if self.pending is None or self._given_up == self.pending:
            self.counts["unmatched_acks"] += 1
            return
        if result == mavlink2.MAV_RESULT_ACCEPTED:
            self.active, self.pending = self.pending, None
            self.counts["accepted"] += 1
            self.counts["to_extnav" if self.active == self.cfg.extnav_set else "to_gnss"] += 1
            self._say(f"vdm-aero serve: EKF3 source set {self.name(self.active)} accepted by the autopilot")
        elif result == mavlink2.MAV_RESULT_IN_PROGRESS:
            self.counts["in_progress"] += 1
            self._next_try_s = self._now_s + self.cfg.retry_s
        elif result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED:
            self.counts["refused"] += 1  # retried at the next period, within max_tries
        else:
            self.counts["refused"] += 1
            self._give_up(f"refused: MAV_RESULT {result}")

    def _give_up(self, why: str) -> None:
        self._given_up, self._silent = self.pending, False
        self.counts["gave_up"] += 1
        self._say(f"vdm-aero serve: EKF3 source set {self.name(self.pending)} NOT switched: {why}; the autopilot "
                  f"stays in {self.name(self.active)} until the next change")  # fmt: skip

    def autopilot_rebooted(self) -> None:
        self.active, self.pending, self._given_up, self.tries = ARDUPILOT_BOOT_SOURCE_SET, None, None, 0

    def link_back(self) -> None:
        """After a link drop-out: a switch given up for want of an ACK gets a new round (a refused one does not)."""
        if self._given_up is not None and self._silent:
            self._given_up, self.tries, self._silent = None, 0, False

    def summary(self) -> dict[str, Any]:
        return {"active": self.active, "wanted": self.wanted, "pending": self.pending, **self.counts}


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
        self._ap_schedule = ClockSchedule()
        self._error_logged: dict[str, float] = {}
        self._force_streams = False
        self._streams_asked: set[str] = set()  # asked for at the last check
        self.stream_caps_hz: dict[str, float] = {}  # streams the autopilot sends slower than asked, at that rate
        self._inflation = outputs.inflation(cfg.outputs.solution_hz)
        # ArduPilot's ExternalNav route: ODOMETRY in the NED frame of its EKF origin, and its source sets
        self._extnav = cfg.autopilot == "ardupilot" and cfg.outputs.solution == "odometry"
        self._px4_vision = cfg.autopilot == "px4" and cfg.outputs.solution == "odometry"  # EKF2 external vision
        self.ekf_origin: LocalFrame | None = None  # GPS_GLOBAL_ORIGIN
        self.pose_resets = 0  # ODOMETRY.reset_counter: our pose jumped (re-initialised, or reset to a fix)
        self._odometry_quality = outputs.QUALITY_FAILED  # of the last ODOMETRY sent
        self._odometry_at_s = -math.inf  # the autopilot's time of the last ODOMETRY sent
        sw = cfg.outputs.source_switch
        self.source_switch = (EkfSourceSwitch(sw, self._send_source_set, self._print) if sw is not None
                              else None)  # fmt: skip
        # what is not sensor data (the sensor data go through the decoder)
        self._handlers: dict[str, Callable[[MavlinkMessage, float], None]] = {
            "TIMESYNC": self._on_timesync,
            "COMMAND_ACK": self._on_command_ack,
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
            "GPS_GLOBAL_ORIGIN": self._on_gps_global_origin,
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
                msgs = self.ep.poll(self.poll_timeout(time.monotonic()))
                for msg, t_in in zip(msgs, self.ep.arrived, strict=True):
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

    def poll_timeout(self, now: float) -> float:
        """How long the loop may wait for the link [s]: until the next periodic work that is due later, at most
        POLL_MAX_S. Work whose due time has passed but that is not done in this state (TIMESYNC and stream checks
        while the autopilot is lost) must not make it 0: the loop then spun a core whenever the link went quiet."""
        later = [t for t in self._next.values() if t > now]
        return max(min(POLL_MAX_S, min(later, default=now + POLL_MAX_S) - now), 0.0)

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
        if self.source_switch is not None:
            self.source_switch.link_back()
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
        return self._ap_schedule.due(key, self._boot_now_s, period_s)

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
        self.ekf_origin = None  # the new boot's EKF sets its origin afresh
        self._odometry_at_s = -math.inf
        if self.source_switch is not None:
            self.source_switch.autopilot_rebooted()

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
        if self.source_switch is not None:
            self.source_switch.gnss_fix(t_arrived_s)
        if self.frame is None:  # the first 3-D fix sets the local origin; the next ones initialise the filter
            self._start_filter(fix)
            return
        assert self.driver is not None
        p = self.frame.to_ned(fix.lat_deg, fix.lon_deg, fix.alt_m)
        t_now = max(self.clock.filter_s(self._boot_now_s), t_arrived_s)
        f = self.filter
        was = f is not None and f.initialised
        resets = f.counts.get("gnss_position_reset", 0) if f is not None else 0
        self.driver.gnss(t_valid_s, t_now, np.asarray(p, dtype=np.float64).reshape(3), fix.v_ned_m_s, fix.h_acc_m,
                         fix.v_acc_m)  # fmt: skip
        # the pose jumps when it starts again (a reboot, a long IMU gap, a GNSS lock-out, divergence) and when the
        # position is reset to a fix (reacquisition): ODOMETRY's reset_counter tells the autopilot
        restarted = not was and math.isfinite(self._t_initialised_s)  # initialised before: this is a restart
        if f is not None and f.initialised and (restarted or f.counts.get("gnss_position_reset", 0) > resets):
            self.pose_resets += 1
        if not was and f is not None and f.initialised:
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
        fe = m.front_end(range_pa=self.cfg.ports.range_pa, noise_pa=self.cfg.ports.noise_pa)
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
        if (self.source_switch is not None and msg.command == outputs.MAV_CMD_SET_EKF_SOURCE_SET
                and self._from_autopilot(msg) and self._for_us(msg)):  # fmt: skip
            self.source_switch.ack(int(msg.result))

    def _for_us(self, msg: MavlinkMessage) -> bool:
        """A COMMAND_ACK addressed to us, or to nobody (target 0/0: MAVLink 1, or an autopilot that fills none);
        an ACK routed to us for a ground station's command is not ours."""
        target = (getattr(msg, "target_system", 0), getattr(msg, "target_component", 0))
        return target in ((0, 0), (self.cfg.system_id, self.cfg.component_id))

    def _on_gps_global_origin(self, msg: MavlinkMessage, t_in: float) -> None:
        """The autopilot's EKF origin: degE7, altitude AMSL [mm] (GCS_MAVLINK::send_gps_global_origin)."""
        if not self._from_autopilot(msg):
            return
        lat, lon, alt = msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
        if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and math.isfinite(alt)):
            raise ValueError(f"GPS_GLOBAL_ORIGIN off the globe: {lat}, {lon}")
        origin = LocalFrame(lat, lon, alt)
        if self.ekf_origin is not None and origin != self.ekf_origin:
            self.pose_resets += 1  # the same aircraft, other coordinates: a jump to the autopilot
        if origin != self.ekf_origin:
            self._print(f"vdm-aero serve: the autopilot's EKF origin {lat:.7f}, {lon:.7f}, {alt:.1f} m: ODOMETRY "
                        "is sent in its NED frame")  # fmt: skip
        self.ekf_origin = origin

    def _request_origin(self) -> None:
        """MAV_CMD_REQUEST_MESSAGE GPS_GLOBAL_ORIGIN (49), until it comes."""
        assert self.autopilot is not None
        sysid, compid = self.autopilot
        msg_id = mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN
        self.ep.send(self.ep.mav.command_long_encode(sysid, compid, mavlink2.MAV_CMD_REQUEST_MESSAGE, 0, msg_id,
                                                     0, 0, 0, 0, 0, 0))  # fmt: skip
        self.stats.origin_requests += 1

    def _send_source_set(self, source_set: int, confirmation: int) -> None:
        if self.autopilot is None:
            return
        self.ep.send(outputs.set_ekf_source_set(self.ep.mav, target=self.autopilot, source_set=source_set,
                                                confirmation=confirmation))  # fmt: skip

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
        if self._extnav:  # not only in outages: ArduPilot needs ExternalNav data flowing before the switch
            self._send_extnav(f)
            return
        if self._px4_vision:  # not only in outages: EKF2 learns the offset of our frame while it fuses GNSS
            self._send_px4_odometry(f)
            return
        if o.solution == "none" or f is None or not f.initialised or not f.in_outage or self.autopilot is None:
            return
        s = self._due_solution()
        if s is None:
            return
        k = self._inflation
        if o.solution == "gps_input":
            self.ep.send(outputs.gps_input(self.ep.mav, s, gps_id=o.gps_id, k=k))
            if o.external_wind and self._due_ap("wind", 1.0):
                self.ep.send(outputs.external_wind(self.ep.mav, s, target=self.autopilot))
        else:
            self.ep.send(outputs.global_position_sensor(self.ep.mav, s, target=self.autopilot, k=k))
        self.stats.solutions_sent += 1

    def _due_solution(self) -> outputs.Solution | None:
        """The solution, when one is due at ``outputs.solution_hz`` on the autopilot's clock (else None)."""
        if not self._due_ap("solution", 1.0 / self.cfg.outputs.solution_hz):
            return None
        return self.solution()

    def _send_extnav(self, f: NavFilter | None) -> None:
        """ArduPilot's ExternalNav: ODOMETRY at ``solution_hz`` whenever the filter has a solution, in the NED
        frame of the EKF origin (not sent, counted, before GPS_GLOBAL_ORIGIN came). In set 1 EKF3 does not fuse
        it (EK3_SRC_OPTIONS = 0, docs/service.md), but VisualOdom is healthy (a sample within 300 ms:
        AP_VisualOdom_Backend::healthy) and the EKF has data the moment the source set switches."""
        o = self.cfg.outputs
        if f is None or not f.initialised or self.autopilot is None:
            return
        s = self._due_solution()
        if s is None:
            return
        if self.ekf_origin is None:
            self.stats.odometry_without_origin += 1
            return
        p = np.array(self.ekf_origin.to_ned(s.lat_deg, s.lon_deg, s.alt_m), dtype=np.float64).reshape(3)
        sig = np.sqrt(np.maximum(np.diag(f.P)[IDX["theta"]], 0.0))  # attitude error 1σ [rad], body axes
        sigma_att = (float(sig[0]), float(sig[1]), float(sig[2]))
        self._odometry_quality = outputs.odometry_quality(s, max_sigma_m=o.max_sigma_m, fallback=f.fallback)
        self.ep.send(outputs.ardupilot_odometry(self.ep.mav, s, p_ned_m=p, k=self._inflation,
                                                quality=self._odometry_quality, reset_counter=self.pose_resets,
                                                sigma_att_rad=sigma_att))  # fmt: skip
        self.stats.solutions_sent += 1
        self._odometry_at_s = s.boot_s
        if o.external_wind and f.in_outage and self._due_ap("wind", 1.0):
            self.ep.send(outputs.external_wind(self.ep.mav, s, target=self.autopilot))

    def _send_px4_odometry(self, f: NavFilter | None) -> None:
        """PX4's external vision: ODOMETRY at ``solution_hz`` whenever the filter has a solution, in our local NED
        frame. While EKF2 fuses GNSS its bias estimator learns the offset between that frame and its own
        (ev_pos_control.cpp, ``_ev_pos_b_est``), and keeps it when GNSS is lost; sent only from the loss on, it would
        start EV fusion on our frame's origin. EV fusion starts only on samples less than 200 ms apart
        (ev_control.cpp, EV_MAX_INTERVAL), hence solution_hz above 5 (firmware_bridge/config.py)."""
        if f is None or not f.initialised or self.autopilot is None:
            return
        s = self._due_solution()
        if s is None:
            return
        quality = outputs.odometry_quality(s, max_sigma_m=self.cfg.outputs.max_sigma_m, fallback=f.fallback)
        self.ep.send(outputs.odometry(self.ep.mav, s, k=self._inflation, quality=quality,
                                      reset_counter=self.pose_resets))  # fmt: skip
        self.stats.solutions_sent += 1

    def _switch_sources(self, now: float) -> None:
        sw = self.source_switch
        if sw is None or self.autopilot is None or not math.isfinite(self._boot_now_s):
            return
        if now - self._last_ap_heartbeat >= AUTOPILOT_LOST_S:
            return  # no command into a dead link: its tries would be spent on nothing
        # ODOMETRY ArduPilot will fuse is flowing: the last one had quality ≥ 1 and is no older than 3 periods
        fresh = self._boot_now_s - self._odometry_at_s <= 3.0 / self.cfg.outputs.solution_hz
        sw.update(self.clock.filter_s(self._boot_now_s), now, solution_ok=fresh and self._odometry_quality >= 1)

    # ----------------------------------------------------------------------------------- periodic
    def _periodic(self, now: float) -> None:
        try:
            self._upkeep(now)
        except Exception as e:  # noqa: BLE001 - an output built from bad input must not stop navigation
            self._count_error("periodic", e)

    def _upkeep(self, now: float) -> None:
        # judged on the link's read horizon, not the clock: the rest of a frame that came in time may still wait
        # in the socket while the service was busy (a relay's second route splits every read in two)
        self.decoder.expire_ports(min(now, self.ep.read_horizon()))
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
            if self._extnav and self.ekf_origin is None and self._due("origin", now, ORIGIN_REQUEST_S):
                self._request_origin()
        self._send_solution(now)
        self._switch_sources(now)
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
                + (f", EKF source set {self.source_switch.name(self.source_switch.active)}"
                   if self.source_switch is not None else "")
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
            "odometry_without_origin": self.stats.odometry_without_origin,
            "origin_requests": self.stats.origin_requests,
            "ekf_origin": (
                None
                if self.ekf_origin is None
                else [self.ekf_origin.lat_deg, self.ekf_origin.lon_deg, self.ekf_origin.alt_m]
            ),
            "pose_resets": self.pose_resets,
            "source_switch": self.source_switch.summary() if self.source_switch is not None else None,
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
