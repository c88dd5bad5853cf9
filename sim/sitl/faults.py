"""Scripted faults of the mock autopilot, in autopilot (world) time.

What ArduPilot's SITL does with its ``SIM_*`` fault parameters (``SIM_GPS1_GLTCH_X``, ``SIM_GPS1_ENABLE``,
``SIM_ARSPD_FAIL`` …), done here to the streams the mock sends, so a companion can be tested against link
and sensor failures without touching its code:

=====================  ==================================================================================
``link_silence``       nothing is sent and everything received is dropped (a radio or cable drop-out)
``gnss_jump``          GPS_RAW_INT positions offset by ``offset_ned_m`` (a multipath glitch, SIM_GPS_GLITCH)
``gnss_drift``         positions offset by ``rate_ned_m_s`` × time in the window, velocities by the rate
                       (a consistent, spoofing-like drift); the offset vanishes when the window ends
``port_stuck``         the ``ports`` hold the value they had when the window opened
``port_nan``           the ``ports`` read NaN
``port_missing``       the ``ports`` are not sent
``port_out_of_range``  the ``ports`` read ``value_pa`` (a saturated or failed transducer)
``flood``              every message is sent ``factor`` times (load: the same bytes as a busy link carries)
=====================  ==================================================================================

``ports: ["*"]`` means every port. A schedule is a YAML file ``faults: [{kind, start_s, duration_s, ...}]``;
a bad one is a one-line :class:`~vdm_aero.errors.UserInputError` naming the file and the entry.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.contract import GnssSample, PortsSample
from vdm_aero._typing import F64Array
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame

__all__ = ["FAULT_KINDS", "Fault", "FaultSchedule", "load_faults", "rogue_sender"]

FAULT_KINDS = ("link_silence", "gnss_jump", "gnss_drift", "port_stuck", "port_nan", "port_missing",
               "port_out_of_range", "flood")  # fmt: skip
_PORT_KINDS = ("port_stuck", "port_nan", "port_missing", "port_out_of_range")
_KEYS = {"kind", "start_s", "duration_s", "ports", "offset_ned_m", "rate_ned_m_s", "value_pa", "factor"}
MAX_FLOOD_FACTOR = 100
ROGUE_HZ = 50.0


@dataclass(frozen=True)
class Fault:
    """One fault over autopilot time ``[start_s, start_s + duration_s)``."""

    kind: str
    start_s: float
    duration_s: float
    ports: tuple[str, ...] = ()
    offset_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rate_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    value_pa: float = 1.0e5
    factor: int = 10

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s

    def applies_to(self, port: str) -> bool:
        return "*" in self.ports or port in self.ports

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": self.kind, "start_s": self.start_s, "duration_s": self.duration_s}
        if self.kind in _PORT_KINDS:
            d["ports"] = list(self.ports)
        extra = {"gnss_jump": "offset_ned_m", "gnss_drift": "rate_ned_m_s", "port_out_of_range": "value_pa",
                 "flood": "factor"}.get(self.kind)  # fmt: skip
        if extra is not None:
            v = getattr(self, extra)
            d[extra] = list(v) if isinstance(v, tuple) else v
        return d


class FaultSchedule:
    """Applies :class:`Fault` s to what the mock sends; state (a stuck port's value) lives here."""

    def __init__(self, faults: tuple[Fault, ...]) -> None:
        self.faults = faults
        self._stuck: dict[tuple[int, str], float] = {}
        self.applied: dict[str, int] = dict.fromkeys({f.kind for f in faults}, 0)

    def _active(self, kind: str, t_s: float) -> list[tuple[int, Fault]]:
        return [(i, f) for i, f in enumerate(self.faults) if f.kind == kind and f.active(t_s)]

    def link_silent(self, t_s: float) -> bool:
        silent = bool(self._active("link_silence", t_s))
        if silent:
            self.applied["link_silence"] += 1
        return silent

    def copies(self, t_s: float) -> int:
        """How many times a message is sent now (``flood``)."""
        active = self._active("flood", t_s)
        if not active:
            return 1
        self.applied["flood"] += 1
        return max(f.factor for _, f in active)

    def gnss(self, sample: GnssSample, t_s: float, frame: LocalFrame) -> GnssSample:
        """The fix as the faulty receiver reports it."""
        offset, dv = np.zeros(3), np.zeros(3)
        for _, f in self._active("gnss_jump", t_s):
            offset += np.asarray(f.offset_ned_m)
            self.applied["gnss_jump"] += 1
        for _, f in self._active("gnss_drift", t_s):
            rate = np.asarray(f.rate_ned_m_s)
            offset += rate * (t_s - f.start_s)
            dv += rate
            self.applied["gnss_drift"] += 1
        if not offset.any() and not dv.any():
            return sample
        p = np.asarray(frame.to_ned(sample.lat_deg, sample.lon_deg, sample.alt_m), dtype=np.float64).reshape(3)
        p += offset
        lat, lon, alt = frame.to_geodetic(float(p[0]), float(p[1]), float(p[2]))
        return replace(sample, lat_deg=lat, lon_deg=lon, alt_m=alt, v_ned_m_s=np.asarray(sample.v_ned_m_s) + dv)

    def ports(self, sample: PortsSample) -> list[tuple[str, float]]:
        """(name, Δp [Pa]) as sent: faulty values, missing ports left out."""
        t = sample.t_s
        active = [(i, f) for i, f in enumerate(self.faults) if f.kind in _PORT_KINDS and f.active(t)]
        # a window that closed forgets its stuck values (the transducer recovered)
        self._stuck = {k: v for k, v in self._stuck.items() if self.faults[k[0]].active(t)}
        out: list[tuple[str, float]] = []
        for name, dp in zip(sample.names, sample.dp_pa, strict=True):
            value: float | None = float(dp)
            for i, f in active:
                if not f.applies_to(name):
                    continue
                self.applied[f.kind] += 1
                if f.kind == "port_stuck":
                    value = self._stuck.setdefault((i, name), float(dp))
                elif f.kind == "port_nan":
                    value = math.nan
                elif f.kind == "port_missing":
                    value = None
                else:
                    value = f.value_pa
            if value is not None:
                out.append((name, value))
        return out

    def port_values(self, sample: PortsSample) -> F64Array:
        """All ports as an array (NaN for a missing one), for DEBUG_FLOAT_ARRAY."""
        sent = dict(self.ports(sample))
        return np.array([sent.get(n, math.nan) for n in sample.names])


def _triple(v: Any, where: str) -> tuple[float, float, float]:
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, int | float) for x in v)):
        raise UserInputError(f"{where}: expected [north, east, down]")
    a, b, c = (float(x) for x in v)
    if not all(math.isfinite(x) for x in (a, b, c)):
        raise UserInputError(f"{where}: must be finite")
    return a, b, c


def _fault(raw: Any, where: str) -> Fault:
    if not isinstance(raw, dict):
        raise UserInputError(f"{where}: expected a mapping with kind, start_s, duration_s")
    unknown = set(raw) - _KEYS
    if unknown:
        raise UserInputError(f"{where}.{sorted(unknown)[0]}: unknown key")
    kind = raw.get("kind")
    if kind not in FAULT_KINDS:
        raise UserInputError(f"{where}.kind: {kind!r} is not one of {', '.join(FAULT_KINDS)}")
    times = []
    for key in ("start_s", "duration_s"):
        v = raw.get(key)
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v) or v < 0:
            raise UserInputError(f"{where}.{key}: expected a number ≥ 0 [s]")
        times.append(float(v))
    f = Fault(kind, times[0], times[1])
    if kind in _PORT_KINDS:
        ports = raw.get("ports")
        if not (isinstance(ports, list) and ports and all(isinstance(p, str) and p for p in ports)):
            raise UserInputError(f'{where}.ports: expected a list of port names (or ["*"] for all)')
        f = replace(f, ports=tuple(ports))
    if kind == "gnss_jump":
        f = replace(f, offset_ned_m=_triple(raw.get("offset_ned_m"), f"{where}.offset_ned_m"))
    if kind == "gnss_drift":
        f = replace(f, rate_ned_m_s=_triple(raw.get("rate_ned_m_s"), f"{where}.rate_ned_m_s"))
    if kind == "port_out_of_range" and "value_pa" in raw:
        v = raw["value_pa"]
        if not isinstance(v, int | float) or isinstance(v, bool):
            raise UserInputError(f"{where}.value_pa: expected a number [Pa]")
        f = replace(f, value_pa=float(v))
    if kind == "flood" and "factor" in raw:
        v = raw["factor"]
        if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= MAX_FLOOD_FACTOR:
            raise UserInputError(f"{where}.factor: expected an integer 1..{MAX_FLOOD_FACTOR}")
        f = replace(f, factor=v)
    return f


def parse_faults(doc: Any, origin: str) -> FaultSchedule:
    """``{faults: [...]}`` → :class:`FaultSchedule`; ``origin`` names the source in errors."""
    if not isinstance(doc, dict) or set(doc) != {"faults"} or not isinstance(doc["faults"], list):
        raise UserInputError(f"{origin}: expected one key, faults: [a list of faults]")
    return FaultSchedule(tuple(_fault(raw, f"{origin}: faults[{i}]") for i, raw in enumerate(doc["faults"])))


def load_faults(path: Path) -> FaultSchedule:
    """Read a fault schedule (module docstring); one-line errors naming the file and the entry."""
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as e:
        raise UserInputError(f"{path}: cannot read: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise UserInputError(f"{path}{line}: not YAML: {getattr(e, 'problem', e)}") from None
    return parse_faults(doc, str(path))


def rogue_sender(port: int, stop: threading.Event, counts: dict[str, int], system_id: int) -> None:
    """An unsigned sender posing as the autopilot: port values, a GNSS fix 1 km off, a reboot command; counts
    what it sent, and in ``replies_received`` what the service sent back to it."""
    mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        k = 0
        while not stop.wait(1.0 / ROGUE_HZ):
            k += 1
            msgs = [
                ("ports", mav.named_value_float_encode(k * 20, b"P00", 5000.0)),
                ("gnss", mav.gps_raw_int_encode(k * 20000, 3, 480000000, 80000000, 100000, 100, 100, 2000, 0, 12)),
                (
                    "commands",
                    mav.command_long_encode(
                        system_id, 191, mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 0, 1, 1, 0, 0, 0, 0, 0
                    ),
                ),
            ]
            for what, m in msgs:
                s.sendto(m.pack(mav), ("127.0.0.1", port))
                counts[what] = counts.get(what, 0) + 1
            s.setblocking(False)
            with contextlib.suppress(BlockingIOError):
                while s.recv(65536):  # anything the service sends here: it took the rogue for its peer
                    counts["replies_received"] = counts.get("replies_received", 0) + 1
            s.setblocking(True)
