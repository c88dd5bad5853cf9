"""The service configuration: ``deploy/config.yaml`` documents every key.

Read once at start into frozen dataclasses. Any fault, an unknown or misspelt key, a wrong type, a value out
of range, a path that does not exist, is one :class:`ConfigError` line naming the file, the dotted key and its
line, and the CLI exits with 2 (systemd's ``RestartPreventExitStatus=2``: a bad config is not restarted).
Relative paths are relative to the config file's directory. Whatever the file holds (binary bytes, a
number of 5000 digits, a YAML tag, a duplicate key, brackets nested 10,000 deep), the answer is the config or
that one line, never another exception.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import units
from firmware_bridge.transport import parse_url
from vdm_aero.errors import UserInputError

__all__ = ["ConfigError", "ServiceConfig", "SourceSwitchConfig", "load_config"]

AUTOPILOTS = ("ardupilot", "px4")
SOLUTION_OUTPUTS = {"ardupilot": ("gps_input", "odometry", "none"),
                    "px4": ("global_position_sensor", "odometry", "none")}  # fmt: skip
PX4_EV_MIN_HZ = 5.0  # EKF2's EV_MAX_INTERVAL (200 ms, strictly): ODOMETRY for PX4 faster than this [Hz]
EKF_SOURCE_SETS = (1, 2, 3)  # EK3_SRC1_* … EK3_SRC3_* (AP_NavEKF_Source: AP_NAKEKF_SOURCE_SET_MAX = 3)
PORT_SOURCES = ("named_value_float", "debug_float_array")
# What ``streams: auto`` asks each autopilot for [Hz] (MAV_CMD_SET_MESSAGE_INTERVAL), from what each one sends:
# * ArduPilot: RAW_IMU (in every build, already scaled; HIGHRES_IMU is built only where flash allows,
#   AP_MAVLINK_MSG_HIGHRES_IMU_ENABLED, and its diff_pressure is not the airspeed sensor's). No stream goes out
#   faster than the main loop, SCHED_LOOP_RATE, 50 Hz on ArduPlane unless raised (AP_Scheduler.cpp): 400 is
#   asked for and the service takes what comes, saying so once (docs/service.md: raise the loop rate).
#   SCALED_PRESSURE carries barometer 1 and airspeed sensor 1 (GCS_MAVLINK::send_scaled_pressure_instance).
# * PX4: HIGHRES_IMU at its IMU integration rate (IMU_INTEG_RATE, 200 Hz); it carries the barometer and the
#   differential pressure (fields_updated bits 9 and 10).
# * Both: ATTITUDE, the autopilot's own, fused only when the IMU arrives too slowly to integrate (< 20 Hz).
DEFAULT_STREAMS: Final[dict[str, dict[str, float]]] = {
    "ardupilot": {"RAW_IMU": 400.0, "SCALED_PRESSURE": 50.0, "GPS_RAW_INT": 5.0, "SERVO_OUTPUT_RAW": 50.0,
                  "SYSTEM_TIME": 1.0, "ATTITUDE": 10.0},
    "px4": {"HIGHRES_IMU": 200.0, "GPS_RAW_INT": 5.0, "SERVO_OUTPUT_RAW": 50.0, "SYSTEM_TIME": 1.0,
            "ATTITUDE": 10.0},
}  # fmt: skip
NAME_MAX = 10  # NAMED_VALUE_FLOAT name length
_SHOW = reprlib.Repr()
_SHOW.maxstring = _SHOW.maxother = _SHOW.maxlong = 60


class ConfigError(UserInputError):
    """A bad service configuration (one line, exit code 2)."""


@dataclass(frozen=True)
class PortsConfig:
    source: str
    names: tuple[str, ...]  # empty: the model's port names
    debug_array_id: int
    frame_timeout_s: float
    range_pa: float
    noise_pa: float


@dataclass(frozen=True)
class SourceSwitchConfig:
    """ArduPilot's EKF3 source set for GNSS and for ExternalNav (MAV_CMD_SET_EKF_SOURCE_SET), the time GNSS
    must be back before the GNSS set is asked for [s], the retry period without COMMAND_ACK [s], and the
    number of transmissions per switch."""

    gnss_set: int
    extnav_set: int
    gnss_hold_s: float
    retry_s: float
    max_tries: int


@dataclass(frozen=True)
class OutputsConfig:
    named_values_hz: float
    prefix: str
    solution: str
    solution_hz: float
    gps_id: int
    max_sigma_3d_m: float
    max_sigma_m: float
    external_wind: bool
    source_switch: SourceSwitchConfig | None = None  # None: the service switches no source set


@dataclass(frozen=True)
class ServiceConfig:
    path: Path
    connection: str
    system_id: int
    component_id: int
    autopilot: str
    signing_key_file: Path | None
    signing_require: bool
    design_data: Path
    deim_model: Path
    nn_model: Path | None
    vehicle: str
    mode: str
    mag_field_ned_ut: tuple[float, float, float]
    filter_rate_hz: float
    gnss_latency_s: float
    ports: PortsConfig
    streams: dict[str, float]
    outputs: OutputsConfig
    status_every_s: float
    state_file: Path
    state_save_every_s: float
    nav_log_file: Path | None
    nav_log_hz: float
    nav_log_max_bytes: int
    nav_log_backups: int


def _show(v: Any) -> str:
    """A value in a one-line message: its repr, shortened (a value may be a 4000-digit number or a long list)."""
    return _SHOW.repr(v)


def _text(s: str) -> str:
    """A key or a path in a one-line message: as it is, or its repr when it holds a newline or control byte."""
    return s if s.isprintable() else repr(s)


def _finite(v: float) -> bool:
    """``math.isfinite`` that also takes integers too large for a float (False)."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


class _Node:
    """A YAML mapping with the line of every key, typed getters, and unknown-key checks."""

    def __init__(self, node: yaml.Node, origin: Path, path: str, line: int | None = None) -> None:
        self.origin, self.path = origin, path
        self.line = node.start_mark.line + 1 if line is None else line  # a section's: its key's line
        if not isinstance(node, yaml.MappingNode):
            raise ConfigError(f"{origin}:{self.line}: {path or 'config'}: expected a mapping")
        self.items: dict[str, tuple[yaml.Node, int]] = {}
        for k, v in node.value:
            name, line = str(k.value) if isinstance(k, yaml.ScalarNode) else f"<{k.id}>", k.start_mark.line + 1
            if name in self.items:  # YAML would silently take the last one: the operator edited one of them
                raise ConfigError(f"{origin}:{line}: {_text(self.key(name))}: duplicate key (first on line "
                                  f"{self.items[name][1]})")  # fmt: skip
            self.items[name] = (v, line)
        self.used: set[str] = set()

    def key(self, k: str) -> str:
        return f"{self.path}.{k}" if self.path else k

    def fail(self, k: str, msg: str) -> ConfigError:
        line = self.items[k][1] if k in self.items else self.line
        return ConfigError(f"{self.origin}:{line}: {_text(self.key(k))}: {msg}")

    def value(self, k: str, default: Any = ...) -> Any:
        self.used.add(k)
        if k not in self.items:
            if default is ...:
                raise self.fail(k, "missing required key")
            return default
        try:
            return yaml.SafeLoader("").construct_object(self.items[k][0], deep=True)
        except yaml.YAMLError as e:  # a tag (!!python/name:...), a recursive alias
            raise self.fail(k, f"not a plain YAML value: {_one_line(e)}") from None
        except (ValueError, OverflowError) as e:  # a number beyond 4300 digits, a date like 2024-13-45
            raise self.fail(k, f"unreadable value: {_one_line(e)}") from None
        except RecursionError:
            raise self.fail(k, "value nested too deeply") from None

    def sub(self, k: str) -> _Node:
        self.used.add(k)
        if k not in self.items:
            raise self.fail(k, "missing required section")
        return _Node(self.items[k][0], self.origin, self.key(k), self.items[k][1])

    def has(self, k: str) -> bool:
        return k in self.items

    def num(self, k: str, default: Any = ..., *, lo: float = -math.inf, hi: float = math.inf) -> float:
        v = self.value(k, default)
        if isinstance(v, bool) or not isinstance(v, int | float) or not _finite(v):
            raise self.fail(k, f"expected a number, got {_show(v)}")
        if not lo <= v <= hi:
            raise self.fail(k, f"{v} is outside [{lo:g}, {hi:g}]")
        return float(v)

    def integer(self, k: str, default: Any = ..., *, lo: int, hi: int) -> int:
        v = self.value(k, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise self.fail(k, f"expected an integer in [{lo}, {hi}], got {_show(v)}")
        return int(v)

    def boolean(self, k: str, default: Any = ...) -> bool:
        v = self.value(k, default)
        if not isinstance(v, bool):
            raise self.fail(k, f"expected true or false, got {_show(v)}")
        return v

    def choice(self, k: str, options: tuple[str, ...], default: Any = ...) -> str:
        v = self.value(k, default)
        if v not in options:
            raise self.fail(k, f"expected one of {', '.join(options)}, got {_show(v)}")
        return str(v)

    def text(self, k: str, default: Any = ...) -> str:
        v = self.value(k, default)
        if not isinstance(v, str) or not v:
            raise self.fail(k, f"expected a non-empty string, got {_show(v)}")
        return v

    def path_(self, k: str, default: Any = ..., *, exists: bool = True) -> Path | None:
        v = self.value(k, default)
        if v is None:
            return None
        if not isinstance(v, str) or not v or "\0" in v:
            raise self.fail(k, f"expected a path, got {_show(v)}")
        p = Path(v) if Path(v).is_absolute() else (self.origin.parent / v)
        try:
            missing = exists and not p.exists()
        except OSError as e:  # a name too long for the file system
            raise self.fail(k, f"{_text(str(p))}: {e.strerror or e}") from None
        if missing:
            raise self.fail(k, f"{_text(str(p))} does not exist")
        return p

    def finish(self) -> None:
        for k in self.items:
            if k not in self.used:
                raise self.fail(k, "unknown key")


def _one_line(e: BaseException) -> str:
    """An exception's message on one line (PyYAML's span several: problem, context and a source excerpt)."""
    text = getattr(e, "problem", None) or str(e) or type(e).__name__
    return " ".join(str(text).split())


def load_config(path: Path) -> ServiceConfig:
    """Read and validate the service configuration (module docstring)."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the config: {e.strerror or e}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        bad_line = raw.count(b"\n", 0, e.start) + 1
        raise ConfigError(f"{path}:{bad_line}: not UTF-8 text") from None
    try:
        root_node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        if mark is not None:
            line = str(mark.line + 1)
        elif isinstance(e, yaml.reader.ReaderError):  # a control character: the reader knows its offset
            line = str(text.count("\n", 0, e.position) + 1)
        else:
            line = "?"
        raise ConfigError(f"{path}:{line}: YAML syntax error: {_one_line(e)}") from None
    except RecursionError:
        raise ConfigError(f"{path}: YAML nested too deeply") from None
    if root_node is None:
        raise ConfigError(f"{path}: empty config")
    try:
        return _read(_Node(root_node, path, ""))
    except yaml.YAMLError as e:  # anything the per-key reading has not already named
        raise ConfigError(f"{path}: {_one_line(e)}") from None


def _source_switch(o: _Node, autopilot: str, solution: str) -> SourceSwitchConfig | None:
    """``outputs.source_switch``: null or false (YAML's ``off`` too) for none, or the mapping of
    :class:`SourceSwitchConfig`; only with ArduPilot's ExternalNav route."""
    given = o.value("source_switch", None)
    if given is None or given is False:
        return None
    if not isinstance(given, dict):
        raise o.fail("source_switch", f"expected null (off) or a mapping of gnss_set, extnav_set, gnss_hold_s, "
                                      f"retry_s, max_tries, got {_show(given)}")  # fmt: skip
    if autopilot != "ardupilot":
        raise o.fail("source_switch", "MAV_CMD_SET_EKF_SOURCE_SET (EK3_SRCn_* source sets) is ArduPilot's only")
    if solution != "odometry":
        raise o.fail("source_switch", f"switches EKF3 to ExternalNav, which needs outputs.solution: odometry "
                                      f"(not {solution})")  # fmt: skip
    sw = o.sub("source_switch")
    lo, hi = EKF_SOURCE_SETS[0], EKF_SOURCE_SETS[-1]
    cfg = SourceSwitchConfig(
        gnss_set=sw.integer("gnss_set", 1, lo=lo, hi=hi),
        extnav_set=sw.integer("extnav_set", lo=lo, hi=hi),
        gnss_hold_s=sw.num("gnss_hold_s", 10.0, lo=0.0, hi=600.0),
        retry_s=sw.num("retry_s", 1.0, lo=0.2, hi=10.0),
        max_tries=sw.integer("max_tries", 5, lo=1, hi=20),
    )
    if cfg.extnav_set == cfg.gnss_set:
        raise sw.fail("extnav_set", f"is the GNSS set ({cfg.gnss_set}): the switch would change nothing")
    sw.finish()
    return cfg


def _read(r: _Node) -> ServiceConfig:
    from vdm_aero.nav.filter import MODES

    url = r.text("connection")
    try:
        parse_url(url)
    except UserInputError as e:
        raise r.fail("connection", str(e)) from None
    autopilot = r.choice("autopilot", AUTOPILOTS)
    sig = r.sub("signing")
    signing_key = sig.path_("key_file", None)
    signing_require = sig.boolean("require", False)
    if signing_require and signing_key is None:
        raise sig.fail("require", "signing is required but no key_file is given")
    sig.finish()
    m = r.sub("models")
    design, deim = m.path_("design_data"), m.path_("deim")
    nn = m.path_("deim_nn", None)
    vehicle = m.text("vehicle", "uav-2m")
    m.finish()
    nav = r.sub("navigation")
    mode = nav.choice("mode", tuple(MODES))
    if MODES[mode].force == "deim-nn" and nn is None:
        raise nav.fail("mode", f"{mode} needs models.deim_nn")
    mag = nav.value("mag_field_ned_ut")
    if not (isinstance(mag, list) and len(mag) == 3
            and all(isinstance(v, int | float) and not isinstance(v, bool) and _finite(v) for v in mag)):  # fmt: skip
        raise nav.fail("mag_field_ned_ut", "expected [north, east, down] in µT (the WMM field at the site)")
    if not 10.0 < math.hypot(*mag) < 80.0:
        raise nav.fail("mag_field_ned_ut", f"|B| = {math.hypot(*mag):.1f} µT is not an Earth field (25..65 µT)")
    filter_rate = nav.num("filter_rate_hz", 50.0, lo=10.0, hi=400.0)
    gnss_latency = units.GNSS_LATENCY_DEFAULT_S[autopilot]
    if nav.value("gnss_latency_s", None) is not None:  # null: the autopilot's default
        gnss_latency = nav.num("gnss_latency_s", lo=0.0, hi=0.5)
    nav.finish()
    p = r.sub("ports")
    names = p.value("names", [])
    if not isinstance(names, list) or not all(
        isinstance(n, str) and 0 < len(n) <= NAME_MAX and n.isascii() for n in names
    ):
        raise p.fail("names", f"expected a list of port names of 1..{NAME_MAX} ASCII characters")
    if len(set(names)) != len(names):
        raise p.fail("names", "duplicate port name")
    ports = PortsConfig(
        source=p.choice("source", PORT_SOURCES, "named_value_float"),
        names=tuple(names),
        debug_array_id=p.integer("debug_array_id", 0, lo=0, hi=65535),
        frame_timeout_s=p.num("frame_timeout_s", 0.05, lo=0.001, hi=1.0),
        range_pa=p.num("range_pa", 500.0, lo=1.0, hi=1e5),
        noise_pa=p.num("noise_pa", 0.2, lo=1e-4, hi=1e3),
    )
    p.finish()
    given = r.value("streams", "auto")
    if given == "auto":
        streams = dict(DEFAULT_STREAMS[autopilot])
    elif not isinstance(given, dict):
        raise r.fail("streams", f"expected auto or a mapping of MAVLink message: rate [Hz], got {_show(given)}")
    else:
        s = r.sub("streams")
        streams = {}
        for name in list(s.items):
            if getattr(mavlink2, f"MAVLINK_MSG_ID_{name}", None) is None:
                raise s.fail(name, "unknown MAVLink message")
            streams[name] = s.num(name, lo=0.0, hi=1000.0)
        s.finish()
    o = r.sub("outputs")
    prefix = o.value("prefix", "VDM")
    if not isinstance(prefix, str) or not 0 < len(prefix) <= 4 or not prefix.isascii():
        raise o.fail("prefix", "expected 1..4 ASCII characters (names are prefix + up to 6)")
    outputs = OutputsConfig(
        named_values_hz=o.num("named_values_hz", 2.0, lo=0.0, hi=50.0),
        prefix=prefix,
        solution=o.choice("solution", SOLUTION_OUTPUTS[autopilot]),
        solution_hz=o.num("solution_hz", 5.0, lo=0.2, hi=50.0),
        gps_id=o.integer("gps_id", 1, lo=0, hi=3),
        max_sigma_3d_m=o.num("max_sigma_3d_m", 30.0, lo=0.1),
        max_sigma_m=o.num("max_sigma_m", 300.0, lo=0.1),
        external_wind=o.boolean("external_wind", False),
    )
    if outputs.external_wind and autopilot != "ardupilot":
        raise o.fail("external_wind", "MAV_CMD_EXTERNAL_WIND_ESTIMATE is handled by ArduPilot only")
    switch = _source_switch(o, autopilot, outputs.solution)
    if autopilot == "px4" and outputs.solution == "odometry" and outputs.solution_hz <= PX4_EV_MIN_HZ:
        # ev_control.cpp: EV fusion starts only on a sample less than EV_MAX_INTERVAL (200 ms) after the last one
        raise o.fail("solution_hz", f"PX4's EKF2 starts external-vision fusion only on ODOMETRY less than 200 ms "
                                    f"apart: above {PX4_EV_MIN_HZ:g} Hz (10), got {outputs.solution_hz:g}")  # fmt: skip
    if switch is not None:
        outputs = replace(outputs, source_switch=switch)
    o.finish()
    st = r.sub("state")
    state_file = st.path_("file", exists=False)
    if state_file is None:
        raise st.fail("file", "expected a path (the state file is not optional)")
    state_every = st.num("save_every_s", 30.0, lo=1.0)
    st.finish()
    lg = r.sub("nav_log")
    log_file = lg.path_("file", None, exists=False)
    log = (log_file, lg.num("hz", 5.0, lo=0.1, hi=100.0), lg.integer("max_bytes", 10_000_000, lo=10_000, hi=2**40),
           lg.integer("backups", 5, lo=1, hi=1000))  # fmt: skip
    lg.finish()
    cfg = ServiceConfig(
        path=r.origin,
        connection=url,
        system_id=r.integer("system_id", 1, lo=1, hi=255),
        component_id=r.integer("component_id", mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER, lo=1, hi=255),
        autopilot=autopilot,
        signing_key_file=signing_key,
        signing_require=signing_require,
        design_data=design,  # type: ignore[arg-type]
        deim_model=deim,  # type: ignore[arg-type]
        nn_model=nn,
        vehicle=vehicle,
        mode=mode,
        mag_field_ned_ut=(float(mag[0]), float(mag[1]), float(mag[2])),
        filter_rate_hz=filter_rate,
        gnss_latency_s=gnss_latency,
        ports=ports,
        streams=streams,
        outputs=outputs,
        status_every_s=r.num("status_every_s", 5.0, lo=0.5),
        state_file=state_file,
        state_save_every_s=state_every,
        nav_log_file=log[0],
        nav_log_hz=log[1],
        nav_log_max_bytes=log[2],
        nav_log_backups=log[3],
    )
    r.finish()
    return cfg
