"""One MAVLink → SI decoder, shared by the live service and the telemetry-log reader.

The service (:mod:`firmware_bridge.service`) and replay of a ``.tlog`` (:mod:`firmware_bridge.logs.tlog`)
differ only in where the messages come from and where the SI samples go: both feed every decoded message to
:class:`MavlinkDecoder`, which hands what it makes of it to a :class:`DecodedSink`. So a flight that replays
well from its tlog tells the user how the service would have read the same link.

What the decoder decides, once for both:

* **whose messages**: the autopilot is the first vehicle HEARTBEAT heard (``system_id``, when given, must
  match; a ground station's or an onboard computer's heartbeat never is), by system *and* component id;
  another takes over only after :data:`AUTOPILOT_LOST_S` without the first;
* **the units**: the table :data:`CONVERTERS`, message type → converter of :mod:`firmware_bridge.units`;
* **which of several streams** of one quantity: the IMU from the best of :data:`IMU_SOURCES` heard (the
  autopilots' own order: PX4's float HIGHRES_IMU, then ArduPilot's first IMU — RAW_IMU, already scaled, read so
  only from ArduPilot — then the first, second and third SCALED_IMU), the barometer and the airspeed sensor
  from the best of :data:`PRESSURE_SOURCES` (PX4's ALTITUDE last: its barometric altitude, made a pressure
  again); a worse-ranked stream is used only while the better ones have
  been silent for :data:`SOURCE_LOST_S` (a sensor or its stream failing), and a switch is announced to the
  sink (the IMU's increments must restart);
* **the clock**: autopilot boot time made continuous across reboots (:class:`~firmware_bridge.inputs.
  AutopilotClock`), from the IMU in use; a sample whose stamp repeats is a repeated frame and dropped;
  SERVO_OUTPUT_RAW's 32-bit µs stamp unwrapped against the IMU's clock; GPS_RAW_INT stamped in Unix time
  mapped through SYSTEM_TIME; a fix's time of validity is its stamp less the receiver latency (configured, or
  the heard autopilot's default, :data:`firmware_bridge.units.GNSS_LATENCY_DEFAULT_S`);
* **the ports**: NAMED_VALUE_FLOAT values assembled into frames, or DEBUG_FLOAT_ARRAY frames.

A converter that refuses a message (an impossible static pressure, a UTC no GNSS clock can hold) raises
``ValueError``; the caller counts it: the service logs it and goes on, the reader lists it in its report.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.endpoint import MavlinkMessage
from firmware_bridge.inputs import REBOOT_BACKSTEP_S, AutopilotClock, PortAssembler, PortFrameIn
from vdm_aero._typing import F64Array

__all__ = [
    "AUTOPILOT_LOST_S",
    "CONVERTERS",
    "IMU_SOURCES",
    "PRESSURE_SOURCES",
    "SOURCE_LOST_S",
    "DecodedSink",
    "MavlinkDecoder",
]

# An autopilot's reboot against a stale frame (one sample a buffering radio or router sends again late): the
# first samples after a reboot are a run of new samples older than the last before it, near boot
REBOOT_RUN: Final = 2  # samples in a row (at the 1 Hz a rebooted ArduPilot streams before it is asked again)
REBOOT_UPTIME_S: Final = 60.0  # ... starting this near the autopilot's boot
REBOOT_RUN_S: Final = 2.0  # ... or going on this long (an autopilot first heard again long after its boot)
REBOOT_RUN_GAP_S: Final = 2.0  # samples of one run are at most this far apart (a 1 Hz stream's, with jitter)
# A run only this far behind the stream's latest is what a buffering radio's late re-sends also make: two of
# them back to back came 2.4 times a minute at 1 % re-sent 0.7–1.2 s late at 400 Hz (make bench relay-cases,
# measured: two false reboots in one flight). A reboot's first samples are the new boot's uptime, seconds behind
# an autopilot up for minutes; one this close needs a longer run.
REBOOT_NEAR_S: Final = 5.0
REBOOT_RUN_NEAR: Final = 4
AUTOPILOT_LOST_S: Final = 3.0  # no autopilot HEARTBEAT this long: another vehicle may take over
SOURCE_LOST_S: Final = 1.0  # a better-ranked stream silent this long: the next one heard is used
IMU_SOURCES: Final = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
PRESSURE_SOURCES: Final = ("SCALED_PRESSURE", "HIGHRES_IMU", "SCALED_PRESSURE2", "SCALED_PRESSURE3", "ALTITUDE")
UNIX_USEC_MIN: Final = 10**15  # a GPS_RAW_INT time_usec above this is Unix time (2001+), not time since boot
UNIX_PLAUSIBLE_S: Final = (1_420_070_400.0, 4_102_444_800.0)  # 2015-01-01 … 2100-01-01: what GNSS can set
UINT32_WRAP_S: Final = 2**32 * 1e-6  # SERVO_OUTPUT_RAW.time_usec is a uint32: it wraps every 71.6 min
BARO_MOVED_HPA: Final = 1.0  # ~8 m of climb: enough to tell a barometer-relative press_diff from a pitot
BARO_RELATIVE_TOL_HPA: Final = 0.3  # 30 Pa: a pitot's reading varies by more in flight; the ground stays put
_NOT_VEHICLES: Final = (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_TYPE_ONBOARD_CONTROLLER)

# message type → converter to SI (firmware_bridge.units): the one table both the service and replay use
CONVERTERS: Final[dict[str, Callable[[MavlinkMessage], Any]]] = {
    "HIGHRES_IMU": units.from_highres_imu,
    "RAW_IMU": units.from_raw_imu,
    "SCALED_IMU": units.from_scaled_imu,
    "SCALED_IMU2": units.from_scaled_imu,
    "SCALED_IMU3": units.from_scaled_imu,
    "SCALED_PRESSURE": units.from_scaled_pressure,
    "SCALED_PRESSURE2": units.from_scaled_pressure,
    "SCALED_PRESSURE3": units.from_scaled_pressure,
    "GPS_RAW_INT": units.from_gps_raw_int,
    "SERVO_OUTPUT_RAW": units.from_servo_output_raw,
    "ALTITUDE": units.from_altitude,
    "ATTITUDE": units.from_attitude,
    "GLOBAL_POSITION_INT": units.from_global_position_int,
}
# what the decoder reads: a log reader decodes only these and counts the rest undecoded
MESSAGES: Final = frozenset(CONVERTERS) | {
    "HEARTBEAT", "NAMED_VALUE_FLOAT", "DEBUG_FLOAT_ARRAY", "SYSTEM_TIME", "SIMSTATE", "SIM_STATE",
}  # fmt: skip


class DecodedSink(Protocol):
    """Where the decoded SI samples go. Times ``t_s`` are the continuous filter clock (autopilot boot time
    plus the reboots' epochs); ``t_in`` the local receive time (the service's monotonic clock, a tlog's
    stamp)."""

    def on_autopilot(self, src: tuple[int, int], new: bool, t_in: float) -> None:
        """Every HEARTBEAT of the autopilot; ``new`` when it is the first heard (or another took over)."""

    def on_reboot(self, boot_s: float) -> None:
        """The autopilot rebooted (its boot time stepped back); it is at ``boot_s`` now."""

    def on_imu_source(self, kind: str) -> None:
        """From now on the IMU comes from ``kind`` (one of :data:`IMU_SOURCES`): restart any increment."""

    def on_imu(self, t_s: float, s: units.ImuSample, t_in: float) -> None: ...

    def on_mag(self, t_s: float, field_b_ut: tuple[float, float, float]) -> None: ...

    def on_baro(self, t_s: float, static_pa: float) -> None: ...

    def on_pitot(self, t_s: float, dp_pa: float, temperature_c: float) -> None: ...

    def on_gnss(self, t_valid_s: float, t_arrived_s: float, fix: units.GnssFix) -> None: ...

    def on_servo(self, t_s: float, pwm_us: F64Array) -> None: ...

    def on_ports(self, t_s: float, frame: PortFrameIn) -> None: ...

    def on_system_time(self, unix_minus_boot_s: float) -> None: ...

    def on_ap_attitude(self, t_s: float, q_nb: F64Array) -> None:
        """The autopilot's own attitude estimate (ATTITUDE)."""

    def on_ap_position(self, t_s: float, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        """The autopilot's own position estimate (GLOBAL_POSITION_INT, AMSL)."""

    def on_truth(self, kind: str, msg: MavlinkMessage, t_in: float) -> None:
        """SITL's SIMSTATE / SIM_STATE (no autopilot time in them: the sink maps ``t_in``)."""


@dataclass
class _Choice:
    """The best-ranked of several streams of one quantity that is alive (module docstring)."""

    ranked: tuple[str, ...]
    current: str | None = None
    heard_at: float = -math.inf

    def admit(self, kind: str, t_in: float) -> bool | None:
        """Whether a sample of ``kind`` is used: True, False, or None when it is used and replaces the stream
        used so far."""
        if kind == self.current:
            self.heard_at = t_in
            return True
        better = self.current is None or self.ranked.index(kind) < self.ranked.index(self.current)
        if better or t_in - self.heard_at > SOURCE_LOST_S:
            self.current, self.heard_at = kind, t_in
            return None
        return False


@dataclass
class _BaroRelative:
    """Whether SCALED_PRESSURE2/3's ``press_diff`` is an airspeed sensor's. Recent ArduPilot sends airspeed
    sensor n's there; earlier ArduPilot sent barometer n's pressure less its ground pressure (a 2018 SITL tlog
    of ArduPlane in shared/data/logs does). That one keeps press_abs − press_diff at the ground pressure,
    a constant, while the aircraft climbs; an airspeed sensor's moves it with every gust. Undecided (not
    used) until the barometer has moved :data:`BARO_MOVED_HPA` or the difference has."""

    ground_hpa: float = math.nan
    first_abs_hpa: float = math.nan
    verdict: bool | None = None
    why: str = "undecided: barometer-relative or airspeed?"

    def is_airspeed(self, press_abs_hpa: float, press_diff_hpa: float) -> bool:
        if self.verdict is None:
            ground = press_abs_hpa - press_diff_hpa
            if math.isnan(self.ground_hpa):
                self.ground_hpa, self.first_abs_hpa = ground, press_abs_hpa
            elif abs(ground - self.ground_hpa) > BARO_RELATIVE_TOL_HPA:
                self.verdict, self.why = True, "airspeed"
            elif abs(press_abs_hpa - self.first_abs_hpa) > BARO_MOVED_HPA:
                self.verdict = False
                self.why = "barometer less its ground pressure (earlier ArduPilot), not an airspeed sensor"
        return bool(self.verdict)


class MavlinkDecoder:
    """MAVLink messages → SI samples for a :class:`DecodedSink` (module docstring).

    ``port_names``: the port columns' order; ``ports_source``: "named_value_float", "debug_float_array" or
    None for either (named values win when both come); ``gnss_latency_s``: the receiver latency [s], None for
    the autopilot's default; ``imu_sources``: the IMU streams that may be used (default all of
    :data:`IMU_SOURCES`; the service gives those it asks the autopilot for, so that a low-rate stream the
    autopilot sends on its own after a reboot is never integrated in their place)."""

    def __init__(self, sink: DecodedSink, *, system_id: int | None = None, port_names: Sequence[str] = (),
                 ports_source: str | None = None, ports_array_id: int = 0, port_frame_timeout_s: float = 0.05,
                 gnss_latency_s: float | None = None, imu_sources: Sequence[str] | None = None) -> None:  # fmt: skip
        self.sink = sink
        self.system_id = system_id
        self.autopilot: tuple[int, int] | None = None
        self.autopilot_type: int | None = None
        self._heartbeat_at = -math.inf
        self.clock = AutopilotClock()
        self.imu = _Choice(tuple(k for k in IMU_SOURCES if imu_sources is None or k in imu_sources))
        self.baro = _Choice(PRESSURE_SOURCES)
        self.pitot = _Choice(PRESSURE_SOURCES)
        self.imu_switches: list[str] = []  # every IMU stream used, in order
        self.latency_given = gnss_latency_s
        self.gnss_latency_s = gnss_latency_s if gnss_latency_s is not None else units.GNSS_LATENCY_DEFAULT_S[
            "ardupilot"]  # fmt: skip
        self.ports_source = ports_source
        self.ports_array_id = ports_array_id
        self.n_ports = len(port_names)
        self.assembler = PortAssembler(port_names, timeout_s=port_frame_timeout_s) if port_names else None
        self.dfa_frames = 0
        self.boot_now_s = -math.inf  # the autopilot time of the latest IMU sample [s]
        self.unix_minus_boot_s: float | None = None
        self._stamps: dict[str, int] = {}  # the last stamp of each stream: a repeat is the same sample again
        self._last_mag: tuple[float, float, float] | None = None
        self._second_pitot: dict[str, _BaroRelative] = {}
        self.duplicates: dict[str, int] = {}
        self.stale: dict[str, int] = {}  # IMU frames older than their stream's latest, not a reboot: discarded
        self._older_run: list[Any] | None = None  # [stream, first, last boot time [s], samples] of older samples
        self.used: dict[str, int] = {}
        self.skipped: dict[str, int] = {}  # "TYPE (why)" → count
        imu, pressure = self._on_scaled_imu, self._on_scaled_pressure
        self._handlers: dict[str, Callable[[MavlinkMessage, str, float], bool | None]] = {
            "HIGHRES_IMU": self._on_highres_imu, "RAW_IMU": self._on_raw_imu,
            "SCALED_IMU": imu, "SCALED_IMU2": imu, "SCALED_IMU3": imu,
            "SCALED_PRESSURE": pressure, "SCALED_PRESSURE2": pressure, "SCALED_PRESSURE3": pressure,
            "GPS_RAW_INT": self._on_gps_raw_int, "SERVO_OUTPUT_RAW": self._on_servo_output_raw,
            "NAMED_VALUE_FLOAT": self._on_named_value_float, "DEBUG_FLOAT_ARRAY": self._on_debug_float_array,
            "SYSTEM_TIME": self._on_system_time, "SIMSTATE": self._on_truth, "SIM_STATE": self._on_truth,
            "ATTITUDE": self._on_estimate, "GLOBAL_POSITION_INT": self._on_estimate, "ALTITUDE": self._on_altitude,
        }  # fmt: skip

    # ------------------------------------------------------------------------------------------ entry
    def from_autopilot(self, msg: MavlinkMessage) -> bool:
        return self.autopilot is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == self.autopilot

    def feed(self, msg: MavlinkMessage, t_in: float) -> None:
        """One decoded message received at local time ``t_in`` [s]. ValueError: a message no autopilot sends
        (the caller counts it)."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._heartbeat(msg, t_in)
            return
        if kind not in MESSAGES:
            return
        if not self.from_autopilot(msg):
            self._skip(f"{kind} (not from the autopilot)")
            return
        if self._handlers[kind](msg, kind, t_in) is not False:
            self.used[kind] = self.used.get(kind, 0) + 1

    def expire_ports(self, now: float) -> None:
        """Close a partial port frame that waited its timeout (``now``: the clock of ``t_in``)."""
        if self.assembler is not None and (fr := self.assembler.expire(now)) is not None:
            self.sink.on_ports(self.clock.filter_s(fr.t_s), fr)

    @property
    def imu_source(self) -> str | None:
        return self.imu.current

    # ----------------------------------------------------------------------------------- internals
    def _skip(self, why: str) -> bool:
        self.skipped[why] = self.skipped.get(why, 0) + 1
        return False

    def _reboot_run(self, kind: str, boot_s: float) -> bool:
        """An IMU sample older than its stream's latest: one stale frame (a buffering radio or router sending
        it again late), discarded and counted, or the first samples of a rebooted autopilot. A reboot is a run:
        :data:`REBOOT_RUN` samples in a row (:data:`REBOOT_RUN_NEAR` when under :data:`REBOOT_NEAR_S` behind the
        stream's latest, where late re-sends also come), each newer than the one before and all a reboot's step
        older than the stream's latest, starting near boot (under :data:`REBOOT_UPTIME_S`) — or lasting
        :data:`REBOOT_RUN_S`, for an autopilot heard again long after its boot. True when this sample
        confirms one."""
        run = self._older_run
        if run is None or run[0] != kind or not run[2] < boot_s <= run[2] + REBOOT_RUN_GAP_S:
            run = self._older_run = [kind, boot_s, boot_s, 0]
        run[2], run[3] = boot_s, int(run[3]) + 1
        behind = self.boot_now_s - boot_s
        need = REBOOT_RUN if behind >= REBOOT_NEAR_S else REBOOT_RUN_NEAR
        far = behind > REBOOT_BACKSTEP_S
        if far and run[3] >= need and (float(run[1]) < REBOOT_UPTIME_S or boot_s - float(run[1]) >= REBOOT_RUN_S):
            self._older_run = None
            self._stamps.pop(kind, None)
            return True
        self.stale[kind] = self.stale.get(kind, 0) + 1
        return False

    def _repeat(self, kind: str, stamp: int) -> bool:
        """Whether ``stamp`` repeats the stream's last one (a repeated frame, or a stream faster than its
        sensor); counted."""
        if self._stamps.get(kind) == stamp:
            self.duplicates[kind] = self.duplicates.get(kind, 0) + 1
            return True
        self._stamps[kind] = stamp
        return False

    def _heartbeat(self, msg: MavlinkMessage, t_in: float) -> None:
        if msg.type in _NOT_VEHICLES or msg.autopilot == mavlink2.MAV_AUTOPILOT_INVALID:
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.system_id is not None and src[0] != self.system_id:
            return
        if src[1] != mavlink2.MAV_COMP_ID_AUTOPILOT1:
            # ArduPilot and PX4 are component 1 (MAV_COMP_ID_AUTOPILOT1); another component calling itself a
            # vehicle's autopilot (a gimbal, a second companion, an impostor on the link) is never taken for it
            self._skip("HEARTBEAT (a vehicle's, but not from MAV_COMP_ID_AUTOPILOT1)")
            return
        new = self.autopilot is None or (src != self.autopilot and t_in - self._heartbeat_at > AUTOPILOT_LOST_S)
        if src != self.autopilot and not new:
            return  # a second vehicle component while the first is alive: not the autopilot
        lost = t_in - self._heartbeat_at > AUTOPILOT_LOST_S
        self.autopilot, self._heartbeat_at = src, t_in
        if new:
            self.autopilot_type = int(msg.autopilot)
            if self.latency_given is None:
                self.gnss_latency_s = units.gnss_latency_default_s(self.autopilot_type)
        self.used["HEARTBEAT"] = self.used.get("HEARTBEAT", 0) + 1
        self.sink.on_autopilot(src, new or lost, t_in)

    def _on_highres_imu(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        used = self._imu(msg, kind, msg.time_usec, t_in)
        try:  # PX4's barometer and airspeed sensor ride along when fields_updated says they are new
            p = units.from_highres_pressure(msg)
        except ValueError:
            return self._skip("HIGHRES_IMU (static pressure out of range)") or used
        if p is not None and self.autopilot_type == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
            # ArduPilot's diff_pressure is the barometer less its ground pressure (GCS_MAVLINK::send_highres_imu),
            # not the airspeed sensor's: its pitot is in SCALED_PRESSURE
            p = dataclasses.replace(p, pitot_dp_pa=math.nan)
        if p is not None:
            self._pressure(p, kind, t_in)
        return used

    def _on_raw_imu(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        if self.autopilot_type != mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
            return self._skip("RAW_IMU (raw sensor counts: only ArduPilot's are scaled)")
        return self._imu(msg, kind, msg.time_usec, t_in)

    def _on_scaled_imu(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        return self._imu(msg, kind, msg.time_boot_ms, t_in)

    def _imu(self, msg: MavlinkMessage, kind: str, stamp: int, t_in: float) -> bool | None:
        if kind not in self.imu.ranked:
            return self._skip(f"{kind} (not an IMU stream asked for)")
        use = self.imu.admit(kind, t_in)
        if use is False:
            return self._skip(f"{kind} ({self.imu.current} used)")
        if use is None:
            self.imu_switches.append(kind)
            self.sink.on_imu_source(kind)
        last = self._stamps.get(kind)
        if last is not None and stamp == last:
            return not self._repeat(kind, stamp)  # False: the same sample again, counted
        s: units.ImuSample = CONVERTERS[kind](msg)
        if last is not None and stamp < last and not self._reboot_run(kind, s.t_s):
            return False  # a stale frame (discarded, counted), or a reboot not confirmed yet
        self._stamps[kind] = stamp
        self._older_run = None
        if self.clock.observe_boot_s(s.t_s):
            if self.assembler is not None:
                self.assembler.restart()
            self._stamps.clear()
            self._stamps[kind] = stamp
            self.sink.on_reboot(s.t_s)
        self.boot_now_s = s.t_s
        t = self.clock.filter_s(s.t_s)
        if s.mag_b_ut is not None and s.mag_b_ut != self._last_mag:
            self._last_mag = s.mag_b_ut  # HIGHRES_IMU repeats a slower magnetometer's sample: pass new ones
            self.sink.on_mag(t, s.mag_b_ut)
        self.sink.on_imu(t, s, t_in)
        return True

    def _on_scaled_pressure(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        if self._repeat(kind, msg.time_boot_ms):
            return False
        p: units.BaroPitotSample = CONVERTERS[kind](msg)
        if kind != "SCALED_PRESSURE" and math.isfinite(p.pitot_dp_pa):
            check = self._second_pitot.setdefault(kind, _BaroRelative())
            if not check.is_airspeed(msg.press_abs, msg.press_diff):
                self._skip(f"{kind}.press_diff ({check.why})")
                p = dataclasses.replace(p, pitot_dp_pa=math.nan)
        return self._pressure(p, kind, t_in) or self._skip(f"{kind} ({self.baro.current} used)")

    def _pressure(self, p: units.BaroPitotSample, kind: str, t_in: float) -> bool:
        t = self.clock.filter_s(p.t_s)
        used = False
        if math.isfinite(p.static_pa) and self.baro.admit(kind, t_in) is not False:
            self.sink.on_baro(t, p.static_pa)
            used = True
        if math.isfinite(p.pitot_dp_pa) and self.pitot.admit(kind, t_in) is not False:
            self.sink.on_pitot(t, p.pitot_dp_pa, p.pitot_temperature_c)
            used = True
        return used

    def _on_altitude(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        p = CONVERTERS[kind](msg)
        if p is None:
            return self._skip("ALTITUDE (no barometric altitude)")
        if self._repeat(kind, msg.time_usec):
            return False
        return self._pressure(p, kind, t_in) or self._skip(f"{kind} ({self.baro.current} used)")

    def _on_gps_raw_int(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        fix: units.GnssFix | None = CONVERTERS[kind](msg)
        if fix is None:
            return self._skip("GPS_RAW_INT (no 3-D fix)")
        boot = fix.t_s
        if msg.time_usec > UNIX_USEC_MIN:  # some autopilots stamp fixes in Unix time
            if self.unix_minus_boot_s is None:
                return self._skip("GPS_RAW_INT (Unix time before SYSTEM_TIME)")
            boot -= self.unix_minus_boot_s
        if self._repeat(kind, msg.time_usec):
            return False
        t_arrived = self.clock.filter_s(boot)
        self.sink.on_gnss(t_arrived - self.gnss_latency_s, t_arrived, fix)
        return True

    def _on_servo_output_raw(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        pwm: units.ServoPwm = CONVERTERS[kind](msg)
        t = pwm.t_s
        if math.isfinite(self.boot_now_s):  # unwrap the uint32 µs against the IMU's clock
            t += round((self.boot_now_s - t) / UINT32_WRAP_S) * UINT32_WRAP_S
        self.sink.on_servo(self.clock.filter_s(t), pwm.pwm_us)
        return True

    def _on_named_value_float(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        if self.assembler is None:
            return self._skip("NAMED_VALUE_FLOAT (no port names given)")
        if self.ports_source not in (None, "named_value_float"):
            return self._skip("NAMED_VALUE_FLOAT (not the port source)")
        name = msg.name if isinstance(msg.name, str) else msg.name.decode("ascii", "replace")
        for fr in self.assembler.add(int(msg.time_boot_ms), name.rstrip("\0"), float(msg.value), t_in):
            self.sink.on_ports(self.clock.filter_s(fr.t_s), fr)
        return True

    def _on_debug_float_array(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        if (
            self.n_ports == 0
            or self.ports_source not in (None, "debug_float_array")
            or (msg.array_id != self.ports_array_id)
        ):
            return self._skip("DEBUG_FLOAT_ARRAY (not the ports)")
        self.dfa_frames += 1
        if self.ports_source is None and self.assembler is not None and self.assembler.counts["complete"] > 0:
            return False  # named values win when both come
        fr = PortFrameIn(msg.time_usec * 1e-6, np.asarray(msg.data[: self.n_ports], dtype=np.float64), True, t_in)
        self.sink.on_ports(self.clock.filter_s(fr.t_s), fr)
        return True

    def _on_system_time(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        if msg.time_unix_usec <= 0:
            return self._skip("SYSTEM_TIME (no UTC yet)")  # 0: the autopilot has no UTC yet
        unix_s = msg.time_unix_usec * 1e-6
        if not UNIX_PLAUSIBLE_S[0] <= unix_s <= UNIX_PLAUSIBLE_S[1]:
            raise ValueError(f"SYSTEM_TIME time_unix_usec {msg.time_unix_usec}: not a UTC time between 2015 and 2100")
        self.unix_minus_boot_s = unix_s - msg.time_boot_ms * 1e-3
        self.sink.on_system_time(self.unix_minus_boot_s)
        return True

    def _on_estimate(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        """What the autopilot's own estimator says: for comparison, and its attitude as a measurement where
        the IMU comes too slowly to integrate."""
        e = CONVERTERS[kind](msg)
        if e is None:
            return self._skip(f"{kind} (no estimate)")
        if self._repeat(kind, msg.time_boot_ms):
            return False
        t = self.clock.filter_s(e.t_s)
        if isinstance(e, units.ApAttitude):
            self.sink.on_ap_attitude(t, e.q_nb)
        else:
            self.sink.on_ap_position(t, e.lat_deg, e.lon_deg, e.alt_m)
        return True

    def _on_truth(self, msg: MavlinkMessage, kind: str, t_in: float) -> bool | None:
        self.sink.on_truth(kind, msg, t_in)
        return False  # the sink counts what it could use
