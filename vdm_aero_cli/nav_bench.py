"""``vdm-aero bench nav-drift``: how far each navigation mode drifts through a GNSS outage.

The world flies the **as-built** aircraft (sim.flight); the filters know only what a user knows: the design
data set, the nominal vehicle description (``uav-2m``), the aero models built from the design data and
calibrated in flight, and the sensor streams. The world's truth is read only to score.

Per scenario and seed the world draws the wind (speed, direction), the turbulence level, the sensor errors
and the outage start. Every mode runs on the same sensor streams in one pass; at the outage start the run
is copied once per outage length, so one converged filter serves every length.

Scenarios: ``survey``, ``wind-shear`` (the wind turns by 60° and strengthens by 4 m/s during the outage),
``loiter``, ``no-airspeed`` (the survey flights without their pitot), the pitot failures at the outage start
(``pitot-blocked``: the ram inlet blocks with the drain open, so the reading decays towards zero;
``pitot-icing``: a growing under-read; ``pitot-water``: water in the line, intermittent and erratic),
``ports-blocked`` (one to three ports' lines blocked at the outage start: each holds the air it trapped),
``payload-release`` (the airframe's payload dropped at the outage start: the force model calibrated with it on
board no longer fits), ``link-bursts`` (from the outage start the link to the companion loses bursts of every
stream, as a router or MAVProxy short of CPU does; the IMU's holes are the filter's to bridge),
``manoeuvring`` (45° banks, slow flight at high α, doublets), ``rtl-wind-gradient`` (out at 300 m, home at
120 m and up again, through a power-law wind profile with veer) and ``survey-calm``, the survey's draws in
still air, so that the difference to ``survey`` is what turbulence costs.

Worlds (``--world``): ``harsh`` switches on every effect of :mod:`sim.flight.world_effects` (sensors as
they are, the Earth as it is, a fleet of as-built airframes each calibrated from its own calibration
flight); ``kind`` is the world of earlier benchmarks (ideal sensor installation, flat non-rotating Earth, one
airframe). The cost-per-effect table flies the survey with each effect alone.
"""

from __future__ import annotations

import copy
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.atmosphere import isa
from vdm_aero.flightlog import SensorLog
from vdm_aero.geodesy import LocalFrame
from vdm_aero.lag import first_order_lag
from vdm_aero.nav.filter import ABLATIONS, MODES, NavConfig, NavFilter, reads_ports
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.stream import LogRunner, NavStream, SolutionRecorder
from vdm_aero.rotation import dcm_from_quat, euler_from_quat, quat_log, quat_multiply

__all__ = ["SCENARIOS", "BenchSpec", "NavArtifacts", "format_report", "run_nav_drift"]

SCENARIOS: Final = {
    # name: (flight preset, wind speed range [m/s], turbulence levels, sensor-stream fault)
    "survey": ("nav-survey", (8.0, 10.0), ("light", "moderate"), None),
    "wind-shear": ("nav-survey", (6.0, 10.0), ("light", "moderate"), "shear"),
    "loiter": ("nav-loiter", (0.0, 12.0), ("light", "moderate"), None),
    "no-airspeed": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "no-airspeed"),
    "pitot-blocked": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "pitot-blocked"),
    "pitot-icing": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "pitot-icing"),
    "pitot-water": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "pitot-water"),
    "manoeuvring": ("nav-manoeuvring", (0.0, 12.0), ("light", "moderate"), None),
    # the survey's flights (same winds, sensor errors and outage starts) in still air: what turbulence costs
    "survey-calm": ("nav-survey", (8.0, 10.0), ("none",), None),
    "rtl-wind-gradient": ("nav-rtl", (6.0, 10.0), ("light", "moderate"), "gradient"),
    # last: a scenario's place in this table seeds its draws, so a new one is appended
    "ports-blocked": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "ports-blocked"),
    "payload-release": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "payload"),
    "link-bursts": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "link-bursts"),
}
_WIND_MODS: Final = ("shear", "gradient")  # flights whose wind changes: their own draws
_FLIGHT_MODS: Final = (*_WIND_MODS, "payload")  # "faults" that change the flight itself, not the sensor stream
WORLDS: Final = ("harsh", "kind")
AIRFRAMES: Final = 4  # the harsh world's fleet: seed k flies airframe k mod AIRFRAMES
COST_SCENARIO: Final = "survey"
COST_OUTAGE_S: Final = 120.0
# the wind profile of rtl-wind-gradient (sim.flight.environment.WindProfile's sources): Hellmann exponent from
# open land (0.1) to a stable layer (0.3), veer 2–5° per 100 m, the drawn wind at the 120 m survey height
GRADIENT_EXPONENT: Final = (0.1, 0.3)
GRADIENT_VEER_DEG_PER_100M: Final = (2.0, 5.0)
# pitot failures (the onset at the outage start). Icing: the AF447 pitots under-read by up to ~80 % within a
# minute (BEA final report, 2012); a 20–60 % under-read reached over 10–60 s. Blocked ram inlet with the
# drain open: the line vents through the drain and reads towards zero (FAA-H-8083-25B, ch. 8, "Blockage of the
# Pitot-Static System"); its time constant 2–10 s (assumption: a drain hole of ~1 mm). Water in the line:
# intermittent episodes (0.1–0.3 per second, 0.5–3 s long) of readings 0–150 % of the true one (assumption:
# the erratic airspeed ArduPilot's ARSPD_OPTIONS health checks exist to catch)
ICING_UNDER_READ: Final = (0.2, 0.6)
ICING_GROWTH_S: Final = (10.0, 60.0)
BLOCKED_DRAIN_TAU_S: Final = (2.0, 10.0)
WATER_EPISODES_PER_S: Final = (0.1, 0.3)
WATER_EPISODE_S: Final = (0.5, 3.0)
# a lossy link to the companion: bursts of frames lost, every stream alike (a burst is the link's, not a sensor's).
# Measured (docs/navigation.md, "A lossy link"): MAVProxy 1.8.75 forwarding the mock autopilot at 4x real time on a
# busy 2-core machine delivered 39 % of RAW_IMU, with 88-177 holes of 0.1 s or more in 70 s of flight (1.3-2.5 a
# second) and link silences of up to 1.0 s. The link is a Gilbert-Elliott channel (Gilbert 1960, Elliott 1963: the
# standard model of bursty loss), a good state and a bad one taking turns, each held for an exponential time of a
# mean drawn per flight: bad (a hole) LINK_HOLE_MEAN_S, good LINK_GOOD_MEAN_S. Means of 0.3 s lost and 0.2 s delivered
# give the measurement (42 % delivered, 1.3-1.5 holes of 0.1 s or more a second, silences up to 1.4-1.8 s in 70 s);
# the harshest draw, 0.3 and 0.15 s, keeps 35 %, the mildest, 0.05 and 1.0 s, 95 %
LINK_HOLE_MEAN_S: Final = (0.05, 0.3)
LINK_GOOD_MEAN_S: Final = (0.15, 1.0)
# a port group's lines blocked at the orifice (ice, water, an insect): each line holds the air it trapped, which
# leaks through the tubing's joints into the fuselage, at about the static pressure of the transducers' reference
# side; the reading starts at the blocking moment's Δp, decays towards zero and, in a climb or descent, follows
# the static pressure the line no longer sees (the pitot's same failure: FAA-H-8083-25B, ch. 8; a flush air-data
# system robust to port failures: Whitmore, Davis & Fife, the RT-FADS flight demonstration, NASA Dryden 1995).
# 1–3 ports drawn at random, the leak's time constant 10–120 s (assumption: tubing joints, not a hole)
PORTS_BLOCKED_N: Final = (1, 3)
PORTS_BLOCKED_LEAK_TAU_S: Final = (10.0, 120.0)
OUTAGE_START_S: Final = (150.0, 210.0)  # after the filter has converged (wind, biases, model parameters)
AFTER_S: Final = 20.0  # flown after each outage: the reacquisition
RECORD_HZ: Final = 5.0
CONVERGED_AFTER_S: Final = 60.0  # NEES epochs: GNSS-aided, this long after the filter started
NEES_DOF: Final = 9
NEES_BAND_95: Final = (2.700, 19.023)  # χ²(9) 2.5 % and 97.5 % points
# the 9-dof NEES split into its three blocks (each against its own marginal covariance, 3 dof): which of
# position, velocity and attitude the filter is too sure of. A consistent block's median is χ²(3)'s
NEES_BLOCKS: Final = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9)}
NEES_BLOCK_MEDIAN_CONSISTENT: Final = 2.366  # χ²(3) median


@dataclass(frozen=True)
class NavArtifacts:
    """What the filters are built from: the design data set and the aero models (DEIM, DEIM+NN)."""

    dataset_dir: Path
    deim_dir: Path
    nn_dir: Path

    @classmethod
    def under(cls, root: Path, calibration_minutes: float) -> NavArtifacts:
        """The layout :func:`build_artifacts` and the calibration study write below ``root``."""
        return cls(root / "data" / "uav-envelope", root / "models" / "deim12",
                   root / "models" / f"deim12-calibrated-{calibration_minutes:g}min")  # fmt: skip


@dataclass(frozen=True)
class BenchSpec:
    scenarios: tuple[str, ...]
    seeds: int
    outages_s: tuple[float, ...]
    modes: tuple[str, ...]
    first_seed: int = 0
    worlds: tuple[str, ...] = ("kind",)
    cost_seeds: int = 0  # the cost-per-effect table: survey, 120 s, this many seeds per effect (0: none)
    cost_effects: tuple[str, ...] = ()  # default: every effect
    calibration_epochs: int = 1000  # training budget of each fleet airframe's net


# ------------------------------------------------------------------------------------ the world side
def _flight_key(name: str) -> tuple[str, str | None, tuple[str, ...]]:
    """What makes a flight: the preset, a change of the flight's wind (shear, gradient) or not, the turbulence
    levels (faults are injected into the sensor streams afterwards, so scenarios differing only by a fault
    share one flight)."""
    preset, _, levels, fault = SCENARIOS[name]
    return preset, fault if fault in _FLIGHT_MODS else None, levels


def world_effects(world: str) -> frozenset[str]:
    """A world's effects: ``harsh`` (all), ``harsh-without:<effect>+<effect>`` (all but those), ``kind`` (none)
    or ``only:<effect>`` (the cost table's)."""
    from sim.flight.world_effects import HARSH, KIND, check_world_effects

    if world == "harsh":
        return HARSH
    if world.startswith("harsh-without:"):
        return HARSH - check_world_effects(tuple(world.split(":", 1)[1].split("+")), "--without")
    if world == "kind":
        return KIND
    if world.startswith("only:"):
        return check_world_effects((world[5:],), "--world")
    raise ValueError(f"unknown world {world!r} (harsh, kind, only:<effect>)")


def airframe_of(world: str, seed: int) -> int:
    """Which airframe flies a seed: the fleet's k mod N in a world with effects, the one preset airframe else."""
    return seed % AIRFRAMES if world_effects(world) else 0


def _draws_of(name: str) -> str:
    """The scenario whose random draws a flight uses: the first with the same preset and change of wind, so
    the fault scenarios (the payload release too) and ``survey-calm`` fly the survey's winds, sensor errors and
    outage starts (paired)."""

    def key(n: str) -> tuple[str, str | None]:
        preset, mod, _ = _flight_key(n)
        return preset, mod if mod in _WIND_MODS else None

    return next(n for n in SCENARIOS if key(n) == key(name))


def bench_scenario(name: str, seed: int, deim_dir: Path, duration_s: float, world: str = "kind"
                   ) -> tuple[Any, dict[str, Any], float]:  # fmt: skip
    """One seed of a scenario as the world flies it: (``sim.flight.scenario.Scenario``, meta, outage start).

    The scenario has no GNSS outage of its own: the benchmark removes the fixes in the filter's stream, and
    the SITL run (``vdm-aero sitl --nav-scenario``) adds the outage window to the world's receiver. ``meta``
    holds only what a user knows (home, the WMM field at the site, the airframe's IMU part, the weather
    draws for the report); the world's installation draws stay in the world.
    """
    from sim.flight.environment import SteadyWind, WindProfile, WindShear
    from sim.flight.record import with_model_ports
    from sim.flight.scenario import load_scenario, with_world

    preset, mod, levels = _flight_key(name)
    draws = _draws_of(name)
    _, (w_lo, w_hi), draw_levels, _ = SCENARIOS[draws]
    rng = np.random.default_rng([list(SCENARIOS).index(draws), seed])
    wind = SteadyWind(speed_m_s=float(rng.uniform(w_lo, w_hi)), from_deg=float(rng.uniform(0.0, 360.0)))
    level = str(levels[min(int(rng.integers(len(draw_levels))), len(levels) - 1)])
    t_out = float(rng.uniform(*OUTAGE_START_S))
    sc = with_model_ports(load_scenario(preset), deim_dir)
    wind_shear = None
    if mod == "shear":
        wind_shear = WindShear(start_s=t_out + 20.0, ramp_s=10.0,
                          to=SteadyWind(wind.speed_m_s + 4.0, wind.from_deg + 60.0))  # fmt: skip
    profile = sc.wind_profile
    if mod == "gradient":
        profile = WindProfile(reference_height_m=120.0, exponent=float(rng.uniform(*GRADIENT_EXPONENT)),
                              veer_deg_per_100m=float(rng.uniform(*GRADIENT_VEER_DEG_PER_100M)))  # fmt: skip
    sc = replace(sc, seed=int(rng.integers(2**31)), wind=wind, turbulence=level, wind_shear=wind_shear,
                 wind_profile=profile, duration_s=duration_s,
                 payload_release_s=t_out if mod == "payload" else None)  # fmt: skip
    airframe = airframe_of(world, seed)
    sc = with_world(sc, world_effects(world), airframe)
    imu_part = sc.imu.grade.name
    if "imu-grade" in sc.world_effects:
        from sim.flight.world_effects import IMU_PARTS

        imu_part = list(IMU_PARTS)[airframe % len(IMU_PARTS)]
    meta = {
        "home": {"lat_deg": sc.home_lat_deg, "lon_deg": sc.home_lon_deg, "alt_m": sc.home_alt_m},
        "mag_field_ned_t": [float(v) for v in sc.magnetic_field.ned_t],
        "wind_m_s": wind.speed_m_s,
        "wind_from_deg": wind.from_deg,
        "turbulence": level,
        "sim_seed": sc.seed,
        "duration_s": duration_s,
        "world": world,
        "airframe": airframe,
        "imu_part": imu_part,
    }
    return sc, meta, t_out


def _flight(name: str, seed: int, artifacts: NavArtifacts, duration_s: float, world: str = "kind",
            fly_after_outage_s: float | None = None
            ) -> tuple[dict[str, F64Array], dict[str, F64Array], dict[str, Any], float]:  # fmt: skip
    """Fly one seed of a scenario: (sensor arrays, truth arrays, meta, outage start). The winds and turbulence
    are drawn for ``duration_s``; ``fly_after_outage_s``: the flight stops that long after the outage start."""
    from sim.flight.record import fly

    sc, meta, t_out = bench_scenario(name, seed, artifacts.deim_dir, duration_s, world)
    flown_s = duration_s if fly_after_outage_s is None else min(duration_s, t_out + fly_after_outage_s)
    sensors, truth, _ = fly(sc, duration_s=flown_s)
    meta["alpha_max_deg"] = float(np.degrees(truth["alpha_rad"].max()))
    meta["bank_max_deg"] = float(np.degrees(np.max(np.abs([euler_from_quat(q)[0] for q in truth["q_nb"][::10]]))))
    return sensors, truth, meta, t_out


def _apply_fault(sensors: dict[str, F64Array], fault: str | None, t_out: float,
                 rng: np.random.Generator | None = None, truth: dict[str, F64Array] | None = None,
                 home_alt_m: float = 0.0) -> dict[str, F64Array]:  # fmt: skip
    """Sensor-stream faults injected into the log from ``t_out`` on (as a replay of a real log would); the
    failures' parameters are drawn from ``rng`` within the ranges of the module's sources. ``ports-blocked``
    needs the ``truth`` altitude (above ``home_alt_m``) for the static pressure the blocked lines no longer see."""
    s = dict(sensors)
    if fault == "ports-blocked":
        return _block_ports(s, t_out, rng if rng is not None else np.random.default_rng(0), truth, home_alt_m)
    if fault == "no-airspeed":
        s["pitot_t_s"], s["pitot_dp_pa"], s["pitot_temperature_c"] = np.zeros(0), np.zeros(0), np.zeros(0)
        return s
    if fault == "link-bursts":
        return _link_bursts(s, t_out, rng if rng is not None else np.random.default_rng(0))
    if fault not in ("pitot-blocked", "pitot-icing", "pitot-water"):
        return s
    rng = rng if rng is not None else np.random.default_rng(0)
    t, dp = s["pitot_t_s"], s["pitot_dp_pa"].copy()
    after = t >= t_out
    if not after.any():
        return s
    i0 = int(np.argmax(after))
    ta = t[after] - t_out
    if fault == "pitot-blocked":  # ram inlet blocked, drain open: the line vents towards zero
        dp[after] = dp[i0] * np.exp(-ta / rng.uniform(*BLOCKED_DRAIN_TAU_S))
    elif fault == "pitot-icing":  # a growing under-read
        depth, growth = rng.uniform(*ICING_UNDER_READ), rng.uniform(*ICING_GROWTH_S)
        dp[after] *= 1.0 - depth * np.minimum(ta / growth, 1.0)
    else:  # water in the line: episodes of erratic readings
        rate, span = rng.uniform(*WATER_EPISODES_PER_S), ta[-1] if len(ta) else 0.0
        starts = np.cumsum(rng.exponential(1.0 / rate, max(int(3 * rate * span) + 5, 5)))
        sel = np.zeros(len(ta), dtype=bool)
        for t0 in starts[starts < span]:
            sel |= (ta >= t0) & (ta < t0 + rng.uniform(*WATER_EPISODE_S))
        idx = np.flatnonzero(after)[sel]
        dp[idx] *= rng.uniform(0.0, 1.5, len(idx))
    s["pitot_dp_pa"] = dp
    return s


def _link_bursts(s: dict[str, F64Array], t_out: float, rng: np.random.Generator,
                 means_s: tuple[float, float] | None = None) -> dict[str, F64Array]:  # fmt: skip
    """Bursts of every stream's samples lost from ``t_out`` on (:data:`LINK_HOLE_MEAN_S`'s comment): each stream
    ``<name>_t_s`` loses its samples inside the holes, with every array of the same prefix and length.
    ``means_s``: the channel's mean spells (lost, delivered) [s], instead of drawn."""
    t_end = max((float(v[-1]) for k, v in s.items() if k.endswith("_t_s") and len(v)), default=t_out)
    bad_s, good_s = means_s or (rng.uniform(*LINK_HOLE_MEAN_S), rng.uniform(*LINK_GOOD_MEAN_S))
    # the channel starts good at t_out; enough turns to pass t_end with room (a sum of n exponentials of mean m
    # falls short of n·m/2 with a negligible probability for n of tens or more)
    n = 2 * int((t_end - t_out) / (bad_s + good_s)) + 20
    good, bad = rng.exponential(good_s, n), rng.exponential(bad_s, n)
    starts = t_out + np.cumsum(good + bad) - bad  # each hole begins after the good spell before it
    ends = starts + bad
    for key in [k for k in s if k.endswith("_t_s")]:
        t = s[key]
        i = np.searchsorted(starts, t, side="right") - 1  # the last hole starting at or before each sample
        lost = (i >= 0) & (t < ends[np.clip(i, 0, None)])
        if not lost.any():
            continue
        prefix = key[: -len("t_s")]
        for k in [k for k in s if k.startswith(prefix) and len(s[k]) == len(t)]:
            s[k] = s[k][~lost]
    return s


def _block_ports(s: dict[str, F64Array], t_out: float, rng: np.random.Generator, truth: dict[str, F64Array] | None,
                 home_alt_m: float) -> dict[str, F64Array]:  # fmt: skip
    """:data:`PORTS_BLOCKED_N` ports blocked from ``t_out`` on (their comment): the line's pressure relaxes from
    the port's at the blocking towards the static pressure (ISA, from the truth altitude) through a first-order
    leak, τ·ṗ_line = p_static − p_line; the reading is p_line − p_static, with the transducer's noise and
    quantisation."""
    from sim.flight.sensors import PORT_GRADES

    if truth is None:
        raise ValueError("ports-blocked needs the truth altitude")
    t, dp = s["ports_t_s"], s["ports_dp_pa"].copy()
    after = t >= t_out
    if not after.any():
        return s
    i0 = int(np.argmax(after))
    n = int(rng.integers(PORTS_BLOCKED_N[0], PORTS_BLOCKED_N[1] + 1))
    ports = rng.choice(dp.shape[1], size=n, replace=False)
    tau = rng.uniform(*PORTS_BLOCKED_LEAK_TAU_S, n)
    alt = home_alt_m - np.interp(t[after], truth["t_s"], truth["pos_ned_m"][:, 2])
    p_static = np.array([isa(float(h))[0] for h in alt])
    ta = t[after] - t_out
    g = PORT_GRADES["sdp31"]
    for k, port in enumerate(ports):
        # p_line = lag(p_static) (settled at the start) + its start's excess Δp₀ decaying: the lag is linear
        held = (dp[i0, port] * np.exp(-ta / tau[k]) + first_order_lag(ta, p_static, float(tau[k])) - p_static
                + g.noise_pa * rng.standard_normal(len(ta)))  # fmt: skip
        dp[after, port] = np.clip(np.round(held / g.resolution_pa) * g.resolution_pa, -g.range_pa, g.range_pa)
    s["ports_dp_pa"] = dp
    return s


# ----------------------------------------------------------------------------------- the filter side
_NAV_CACHE: dict[Path, NavModels] = {}


# A pitot fault's first symptom: its airspeed this far off the healthy reading. It is the size of the healthy
# pitot–ports disagreement: smoothed about its bias, that never went below −1.0 m/s on 5.9 h of the harsh world's
# healthy flights (20 surveys, 20 returns home; docs/navigation.md), so a smaller under-read is not a fault any
# comparison of the two can see. Reported beside the bar, which counts from the fault's start.
SYMPTOM_M_S: Final = 1.0


def fault_symptom_s(healthy: dict[str, F64Array], faulty: dict[str, F64Array], truth: dict[str, F64Array],
                    t_out: float) -> float | None:  # fmt: skip
    """Seconds from the fault's start (``t_out``) to the first pitot sample whose airspeed is :data:`SYMPTOM_M_S`
    off the healthy one (the judge's truth airspeed scales the Δp ratio); None if it never is."""
    t, dp0, dp1 = healthy["pitot_t_s"], healthy["pitot_dp_pa"], faulty["pitot_dp_pa"]
    if not len(t):
        return None
    v = np.interp(t, truth["t_s"], truth["airspeed_m_s"])
    off = v * np.abs(1.0 - np.sqrt(np.clip(dp1, 0.0, None) / np.maximum(dp0, 1e-9)))
    hit = (t >= t_out) & (off >= SYMPTOM_M_S)
    return float(t[int(np.argmax(hit))] - t_out) if hit.any() else None


def _nav(artifacts: NavArtifacts) -> NavModels:
    """The filter ingredients, loaded once per worker."""
    if artifacts.nn_dir not in _NAV_CACHE:
        _NAV_CACHE[artifacts.nn_dir] = NavModels.load(artifacts.dataset_dir, artifacts.deim_dir, artifacts.nn_dir)
    return _NAV_CACHE[artifacts.nn_dir]


def _truth_at(truth: dict[str, F64Array], key: str, t: F64Array) -> F64Array:
    tt = truth["t_s"]
    v = truth[key]
    return np.column_stack([np.interp(t, tt, v[:, i]) for i in range(v.shape[1])])


def run_filters(
    sensors: dict[str, F64Array],
    truth: dict[str, F64Array],
    meta: dict[str, Any],
    t_out: float,
    outages_s: Sequence[float],
    modes: Sequence[str],
    nav: NavModels,
) -> dict[str, Any]:
    """All modes through one flight, branching at the outage start: per outage and mode the recorded
    history (t, position, σ_h, NEES) and the metrics."""

    home = meta["home"]
    frame = LocalFrame(home["lat_deg"], home["lon_deg"], home["alt_m"])
    log = SensorLog(path=Path("<bench>"), meta={"duration_s": meta["duration_s"]}, port_names=(), arrays=sensors)
    # what a user knows: the vehicle description, the WMM field at the site, the IMU part's data sheet
    cfg = NavConfig.for_imu(meta.get("imu_part", "icm-42688-p"), vehicle=nav.vehicle, origin_alt_m=home["alt_m"],
                            mag_field_ned_ut=np.asarray(meta["mag_field_ned_t"]) * 1e6)  # fmt: skip
    stream = NavStream.from_log(log, nav.vehicle, frame, filter_rate_hz=cfg.filter_rate_hz,
                                gnss_latency_s=cfg.gnss_latency_s)  # fmt: skip
    fe = None  # the port front end only where a mode reads the ports (a filter's speed is its own)
    if len(sensors["ports_t_s"]) and any(reads_ports(m) for m in modes):
        fe = nav.front_end(range_pa=500.0, noise_pa=0.2)
    filters = {m: NavFilter(m, cfg, nav.derivatives) for m in modes}
    runner = LogRunner(stream, filters, fe)
    rec: dict[str, list[tuple[Any, ...]]] = {m: [] for m in modes}
    record = SolutionRecorder(round(cfg.filter_rate_hz / RECORD_HZ))

    def recorder(r: LogRunner, store: dict[str, list[tuple[Any, ...]]], rec_: SolutionRecorder
                 ) -> Callable[[float], None]:  # fmt: skip
        return lambda t: rec_(t, r.filters, store)

    cpu0 = time.process_time()
    runner.run_until(t_out, recorder(runner, rec, record))
    pre_cpu = time.process_time() - cpu0
    pre_flight = runner.t_s
    results: dict[str, Any] = {"outages": {}, "filter_cpu_s_per_flight_s": {}}
    for length in outages_s:
        branch = copy.deepcopy(runner)
        branch.block_gnss(t_out, t_out + length)
        store = {m: list(v) for m, v in rec.items()}
        c0 = time.process_time()
        # each branch records at the epochs one straight run would (its own copy of the step count)
        branch.run_until(t_out + length + AFTER_S, recorder(branch, store, copy.copy(record)))
        cpu = pre_cpu + time.process_time() - c0
        flown = pre_flight + (branch.t_s - t_out)
        results["filter_cpu_s_per_flight_s"][f"{length:g}"] = cpu / max(flown, 1e-9) / max(len(modes), 1)
        results["outages"][f"{length:g}"] = scored = {
            m: _metrics(store[m], truth, t_out, length, branch.filters[m]) for m in modes
        }
        if branch.frontend is not None:  # the front end's port verdicts, beside each port mode's air-data FDI
            ports = [[round(t - t_out, 2), "port", "excluded" if w == "quiet" else "readmitted"]
                     for t, _, w in branch.frontend.events]  # fmt: skip
            for mode in modes:
                if reads_ports(mode) and scored[mode]["fdi_events"] is not None:
                    scored[mode]["fdi_events"] = sorted(scored[mode]["fdi_events"] + ports)
            results.setdefault("port_events", {})[f"{length:g}"] = [
                [round(t - t_out, 2), i, w] for t, i, w in branch.frontend.events]  # fmt: skip
    if "ins" in modes:  # the free-inertial reference for the theory check: ins on its IMU alone
        results["free_inertial"] = {}
        solo = copy.deepcopy(runner)
        solo.driver.filters = {"ins": solo.driver.filters["ins"]}
        solo.driver.frontend = None
        for length in outages_s:
            branch = copy.deepcopy(solo)
            branch.block_gnss(t_out, t_out + length)
            branch.block_mag(t_out, t_out + length)
            branch.block_baro(t_out, t_out + length)
            store = {"ins": list(rec["ins"])}
            branch.run_until(t_out + length + AFTER_S, recorder(branch, store, copy.copy(record)))
            m = _metrics(store["ins"], truth, t_out, length, branch.filters["ins"])
            results["free_inertial"][f"{length:g}"] = {k: m[k] for k in ("final_error_m", "sigma_h_end_m")}
            # the data sheet's theory along this flight's own trajectory (the judge's check of the world)
            tt = truth["t_s"]
            sel = (tt >= t_out) & (tt <= t_out + length)
            args = (meta.get("imu_part", "icm-42688-p"), tt[sel] - t_out, truth["q_nb"][sel], truth["v_ned_m_s"][sel])
            results["free_inertial"][f"{length:g}"] |= {
                "budget_median_m": median_horizontal_error_m(free_inertial_along(*args)),
                "calibrated_start_median_m": median_horizontal_error_m(
                    free_inertial_along(*args, calibrated_start=True)
                ),
            }
    results["port_counts"] = dict(fe.counts) if fe is not None else None
    return results


def _metrics(rows: list[tuple[Any, ...]], truth: dict[str, F64Array], t0: float, length: float, f: NavFilter
             ) -> dict[str, Any]:  # fmt: skip
    t = np.array([r[0] for r in rows])
    p = np.array([r[1] for r in rows])
    v = np.array([r[2] for r in rows])
    q = np.array([r[3] for r in rows])
    cov = np.array([r[5] for r in rows])
    aided = np.array([not r[6] for r in rows])
    p_t, v_t = _truth_at(truth, "pos_ned_m", t), _truth_at(truth, "v_ned_m_s", t)
    k = np.clip(np.searchsorted(truth["t_s"], t), 0, len(truth["t_s"]) - 1)
    q_t = truth["q_nb"][k]
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    dth = np.array([quat_log(quat_multiply(c, qt)) for c, qt in zip(conj, q_t, strict=True)])
    err9 = np.hstack([p - p_t, v - v_t, -dth])  # x̂ ⊖ x: attitude error of the estimate relative to the truth
    e_h = np.linalg.norm(p[:, :2] - p_t[:, :2], axis=1)
    sig_h = np.sqrt(np.array([np.linalg.eigvalsh(c[:2, :2])[-1] for c in cov]))
    t1 = t0 + length
    inside = (t >= t0) & (t < t1)
    i_end = max(int(np.searchsorted(t, t1)) - 1, 0)
    # NEES over GNSS-aided, converged epochs before the outage
    sel = aided & (t > t[0] + CONVERGED_AFTER_S) & (t < t0)
    nees = np.array([float(e @ np.linalg.solve(c, e)) for e, c in zip(err9[sel], cov[sel], strict=True)])
    in_band = float(np.mean((nees >= NEES_BAND_95[0]) & (nees <= NEES_BAND_95[1]))) if len(nees) else math.nan
    blocks = {}
    for name, b in NEES_BLOCKS.items():
        e_b, c_b = err9[sel][:, b], cov[sel][:, b, b]
        quad = np.einsum("ki,ki->k", e_b, np.linalg.solve(c_b, e_b[..., None])[..., 0])  # eᵀ·P⁻¹·e per epoch
        blocks[name] = float(np.median(quad)) if len(nees) else math.nan
    # distance flown over the ground during the outage
    tt = truth["t_s"]
    m = (tt >= t0) & (tt < t1)
    dist = float(np.sum(np.linalg.norm(np.diff(truth["pos_ned_m"][m][:, :2], axis=0), axis=1)))
    # reacquisition: the correction applied in the first 5 s of GNSS after the outage
    j0 = int(np.searchsorted(t, t1))
    j1 = int(np.searchsorted(t, t1 + 5.0))
    jump = math.nan
    if j1 < len(t) and j0 < len(t):
        jump = float(np.linalg.norm((p[j1, :2] - p[j0, :2]) - (p_t[j1, :2] - p_t[j0, :2])))
    return {
        "final_error_m": float(e_h[i_end]),
        "max_error_m": float(e_h[inside].max()) if inside.any() else math.nan,
        "distance_m": dist,
        "final_error_pct": 100.0 * float(e_h[i_end]) / max(dist, 1e-9),
        "sigma_h_end_m": float(sig_h[i_end]),
        "covered_2sigma": bool(e_h[i_end] <= 2.0 * sig_h[i_end]),
        "covered_2sigma_if_consistent": two_sigma_coverage_if_consistent(cov[i_end][:2, :2]),
        "nees_in_band": in_band,
        "nees_median": float(np.median(nees)) if len(nees) else math.nan,
        "nees_block_median": blocks,
        "reacquisition_jump_m": jump,
        "fallback": f.fallback,
        "rejected": dict(f.rejected),
        # the air-data FDI's status changes, in seconds from the outage start (a fault starts there)
        "fdi_events": [[round(e.t_s - t0, 2), e.source, e.what] for e in fdi.events]
        if (fdi := getattr(f, "fdi", None))
        else None,
        "recorded_s": [round(float(t[0] - t0), 2), round(float(t[-1] - t0), 2)] if len(t) else [0.0, 0.0],
        "error_curve": {"t_s": (t[inside] - t0).round(2).tolist(), "e_m": e_h[inside].round(2).tolist()},
    }


WIND_HOLD_BEFORE_S: Final = 60.0  # the wind a perfect estimate holds: the truth's mean over the last minute aided


def wind_hold_error_m(truth: dict[str, F64Array], t0: float, length: float,
                      before_s: float = WIND_HOLD_BEFORE_S) -> float:  # fmt: skip
    """The judge's measure of what the wind's own change over an outage costs [m]: the horizontal error at the
    outage end of a dead reckoner that knows its air-relative velocity exactly and holds the wind at the truth's
    mean over the ``before_s`` seconds before the outage, |∫(w(t) − w̄) dt| over [t0, t0 + length] (trapezoidal on
    the truth's samples; w the wind at the aircraft, turbulence and shear included). It reads the truth, so no
    filter can have it. Not a bound: a filter that follows part of the wind's change through the outage (the INS
    sees the ground velocity change that the air data do not, and a gust state takes its fast part) does better."""
    t, w = truth["t_s"], truth["wind_ned_m_s"][:, :2]
    pre = (t >= t0 - before_s) & (t <= t0)
    if pre.sum() < 2:
        raise ValueError(f"wind_hold_error_m: no truth in the {before_s:g} s before the outage at {t0:g} s")
    w_bar = np.trapezoid(w[pre], t[pre], axis=0) / (t[pre][-1] - t[pre][0])
    sel = (t >= t0) & (t <= t0 + length)
    return float(np.linalg.norm(np.trapezoid(w[sel] - w_bar, t[sel], axis=0)))


# ----------------------------------------------------------------------------------------- one unit
def models_for(artifacts: NavArtifacts, world: str, airframe: int) -> NavArtifacts:
    """The models the filters of a (world, airframe) use: a fleet airframe has its own calibrated net (from its
    own calibration flight in that world); the preset airframe uses the base calibration."""
    if "fleet" not in world_effects(world):
        return artifacts
    tag = world.replace(":", "-")
    return replace(artifacts, nn_dir=artifacts.nn_dir.with_name(f"{artifacts.nn_dir.name}-{tag}-af{airframe}"))


def run_unit(world: str, flight: str, seed: int, scen_faults: list[tuple[str, str | None]], spec: BenchSpec,
             artifacts: NavArtifacts, outages_s: Sequence[float] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Fly one seed of a flight (named by its first scenario) in a world once and score every scenario
    sharing it."""
    lengths = tuple(outages_s or spec.outages_s)
    duration = OUTAGE_START_S[1] + max(lengths) + AFTER_S + 5.0
    sensors, truth, meta, t_out = _flight(flight, seed, artifacts, duration, world)
    nav = _nav(models_for(artifacts, world, meta["airframe"]))
    out = []
    for name, fault in scen_faults:
        rng = np.random.default_rng([list(SCENARIOS).index(name), seed, 99])
        s = _apply_fault(sensors, fault if fault not in _FLIGHT_MODS else None, t_out, rng, truth,
                         meta["home"]["alt_m"])  # fmt: skip
        res = run_filters(s, truth, meta, t_out, lengths, spec.modes, nav)
        symptom = fault_symptom_s(sensors, s, truth, t_out) if name.startswith("pitot-") else None
        out.append({"world": world, "scenario": name, "seed": seed, "outage_start_s": t_out, "fault_symptom_s": symptom,
                    "wind_m_s": meta["wind_m_s"], "wind_from_deg": meta["wind_from_deg"],
                    "turbulence": meta["turbulence"], "airframe": meta["airframe"], "imu_part": meta["imu_part"],
                    "alpha_max_deg": meta["alpha_max_deg"], "bank_max_deg": meta["bank_max_deg"],
                    "wind_hold_m": {f"{x:g}": wind_hold_error_m(truth, t_out, x) for x in lengths}, **res})  # fmt: skip
    return out


Unit = tuple[str, str, int, list[tuple[str, str | None]], tuple[float, ...]]


def _units(spec: BenchSpec) -> list[Unit]:
    """Work units: scenarios flying the same preset with the same seed draws share one flight, per world; the
    cost table's worlds fly the survey at its outage length."""
    groups: dict[tuple[str, str | None, tuple[str, ...]], list[tuple[str, str | None]]] = {}
    for name in spec.scenarios:
        groups.setdefault(_flight_key(name), []).append((name, SCENARIOS[name][3]))
    seeds = range(spec.first_seed, spec.first_seed + spec.seeds)
    out: list[Unit] = [(w, members[0][0], seed, members, spec.outages_s) for w in spec.worlds
                       for members in groups.values() for seed in seeds]  # fmt: skip
    if spec.cost_seeds:
        from sim.flight.world_effects import WORLD_EFFECTS

        for e in spec.cost_effects or tuple(WORLD_EFFECTS):
            for seed in range(spec.first_seed, spec.first_seed + spec.cost_seeds):
                out.append((f"only:{e}", COST_SCENARIO, seed, [(COST_SCENARIO, None)], (COST_OUTAGE_S,)))
    return out


def _calibrations(units: list[Unit]) -> list[tuple[str, int]]:
    """The (world, airframe) pairs whose nets must be calibrated before the units run."""
    need = {(u[0], airframe_of(u[0], u[2])) for u in units if "fleet" in world_effects(u[0])}
    return sorted(need)


def _pool_map(fn: Callable[..., Any], calls: list[tuple[Any, ...]], jobs: int | None, dask_address: str | None,
              progress: Callable[[int, int], None] | None) -> list[Any]:  # fmt: skip
    """``fn(*call)`` for every call: on a dask.distributed scheduler, local processes, or in this process."""
    out: list[Any] = []
    if dask_address is not None:
        from dask.distributed import Client, as_completed

        client = Client(dask_address)
        futs = [client.submit(fn, *c, pure=False) for c in calls]
        for i, fut in enumerate(as_completed(futs)):
            out.append(fut.result())
            if progress:
                progress(i + 1, len(calls))
        client.close()
    elif (jobs or os.cpu_count() or 1) > 1 and len(calls) > 1:
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures import as_completed as done

        # spawn, not fork: a parent that has run PyTorch (the demo trains nets before this) leaves OpenMP's
        # thread pool in a state a forked child deadlocks on when it trains a net (a fleet calibration)
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs or os.cpu_count(), mp_context=ctx) as ex:
            futs2 = [ex.submit(fn, *c) for c in calls]
            for i, f2 in enumerate(done(futs2)):
                out.append(f2.result())
                if progress:
                    progress(i + 1, len(calls))
    else:
        for i, c in enumerate(calls):
            out.append(fn(*c))
            if progress:
                progress(i + 1, len(calls))
    return out


def run_nav_drift(spec: BenchSpec, artifacts: NavArtifacts, *, jobs: int | None = None, dask_address: str | None = None,
                  progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Every unit in parallel (local processes, or a dask.distributed cluster); the aggregated report. The
    fleet's airframes are calibrated first (cached in the models directory)."""
    units = _units(spec)
    wall0 = time.perf_counter()
    cals = [(artifacts, w, k, spec.calibration_epochs) for w, k in _calibrations(units)]
    _pool_map(calibrate_airframe, cals, jobs, dask_address, None)
    cal_s = time.perf_counter() - wall0
    rows: list[dict[str, Any]] = []
    calls = [(u[0], u[1], u[2], u[3], spec, artifacts, u[4]) for u in units]
    for r in _pool_map(run_unit, calls, jobs, dask_address, progress):
        rows.extend(r)
    order = {w: i for i, w in enumerate(dict.fromkeys(u[0] for u in units))}
    rows.sort(key=lambda r: (order[r["world"]], list(SCENARIOS).index(r["scenario"]), r["seed"]))
    return {"spec": {"scenarios": list(spec.scenarios), "seeds": spec.seeds, "outages_s": list(spec.outages_s),
                     "modes": list(spec.modes), "first_seed": spec.first_seed, "worlds": list(spec.worlds),
                     "cost_seeds": spec.cost_seeds},
            "wall_s": time.perf_counter() - wall0, "calibration_wall_s": cal_s, "runs": rows,
            "summary": summarise(rows, spec), "ins_theory": ins_theory(rows),
            "wind_hold": wind_hold_summary(rows)}  # fmt: skip


# ------------------------------------------------------------------------------------------ report
def summarise(rows: list[dict[str, Any]], spec: BenchSpec) -> dict[str, Any]:
    """Per world, scenario and outage length (``world/scenario/length``): each mode's statistics over seeds."""
    out: dict[str, Any] = {}
    keys = dict.fromkeys((r["world"], r["scenario"], k) for r in rows for k in r["outages"])
    for world, sc, key in keys:
        runs = [r for r in rows if r["world"] == world and r["scenario"] == sc and key in r["outages"]]
        per: dict[str, Any] = {}
        for m in spec.modes:
            ms = [r["outages"][key][m] for r in runs]
            if not ms:
                continue
            fe = np.array([x["final_error_m"] for x in ms])
            per[m] = {
                "median_m": float(np.median(fe)),
                "p95_m": float(np.percentile(fe, 95)),
                "max_m": float(fe.max()),
                "max_during_median_m": float(np.median([x["max_error_m"] for x in ms])),
                "pct_distance_median": float(np.median([x["final_error_pct"] for x in ms])),
                "covered_2sigma": float(np.mean([x["covered_2sigma"] for x in ms])),
                "nees_in_band": float(np.nanmean([x["nees_in_band"] for x in ms])),  # pooled: equal epochs per run
                "reacquisition_jump_median_m": float(np.nanmedian([x["reacquisition_jump_m"] for x in ms])),
                "cpu_s_per_flight_s": float(np.median([r["filter_cpu_s_per_flight_s"][key] for r in runs])),
                "seeds": len(ms),
            }
            if all("nees_block_median" in x for x in ms):  # not in reports written before 2026-12-01
                per[m]["nees_block_median"] = {b: float(np.nanmedian([x["nees_block_median"][b] for x in ms]))
                                               for b in NEES_BLOCKS}  # fmt: skip
            if all("covered_2sigma_if_consistent" in x for x in ms):  # not in reports written before 2026-11-27
                # what a consistent filter would score with these σ, and how often it would reach the bar's 90 %
                ideal = [x["covered_2sigma_if_consistent"] for x in ms]
                per[m]["covered_2sigma_if_consistent"] = float(np.mean(ideal))
                per[m]["coverage_bar_pass_if_consistent"] = share_reached_probability(ideal, COVERAGE_BAR)
            if ms[0].get("fdi_events") is not None:
                per[m] |= fdi_summary(ms, faulty=sc in FAULT_SOURCES, sources=FAULT_SOURCES.get(sc, ()),
                                      symptoms_s=[r.get("fault_symptom_s") for r in runs])  # fmt: skip
                if SCENARIOS[sc][3] not in _WIND_MODS:
                    per[m] |= wind_alarm_summary(ms, float(key))
        if PRODUCT in per and {"ins", "airspeed-dr"} <= per.keys():
            err = {m: [r["outages"][key][m]["final_error_m"] for r in runs] for m in (PRODUCT, "ins", "airspeed-dr")}
            per[PRODUCT] |= product_ratio_uncertainty(err)
        if PRODUCT in per:  # every other mode and ablation against the product, on the same flights
            product = [r["outages"][key][PRODUCT]["final_error_m"] for r in runs]
            for m in per.keys() - {PRODUCT}:
                per[m]["ratio_to_product"] = per[m]["median_m"] / per[PRODUCT]["median_m"]
                ci = median_ratio_interval([r["outages"][key][m]["final_error_m"] for r in runs], product)
                if ci is not None:
                    per[m]["ratio_to_product_ci95"] = list(ci)
        out[f"{world}/{sc}/{key}"] = per
    return out


BOOTSTRAP_RESAMPLES: Final = 4000
BOOTSTRAP_SEED: Final = 22  # the report's own draws, fixed: the same runs give the same report
RATIO_LEVEL: Final = 0.95


def median_ratio_interval(num: Sequence[float] | F64Array, *dens: Sequence[float] | F64Array
                          ) -> tuple[float, float] | None:  # fmt: skip
    """The 95 % interval of median(``num``) ÷ min over ``dens`` of median(den), the ratio a bar judges, from the
    paired percentile bootstrap over seeds (``scipy.stats.bootstrap``, ``paired=True``: a seed's flights are
    drawn together, since every mode flew the same weather, and their errors move together). None under
    three seeds. A median of a few heavy-tailed errors moves by tens of percent with the draw of seeds: the
    interval says whether the seeds flown can tell a bar's verdict from that."""
    n = len(num)
    if n < 3 or any(len(d) != n for d in dens):
        return None
    from scipy.stats import bootstrap  # the benchmark's extra (sim), not the service's

    def ratio(a: F64Array, *b: F64Array, axis: int = -1) -> F64Array:
        best = np.min([np.median(x, axis=axis) for x in b], axis=0)
        return np.asarray(np.median(a, axis=axis) / best)

    res = bootstrap((np.asarray(num, float), *(np.asarray(d, float) for d in dens)), ratio, paired=True,
                    vectorized=True, n_resamples=BOOTSTRAP_RESAMPLES, confidence_level=RATIO_LEVEL,
                    method="percentile", rng=np.random.default_rng(BOOTSTRAP_SEED))  # fmt: skip
    ci = res.confidence_interval
    return float(ci.low), float(ci.high)


def product_ratio_uncertainty(err: Mapping[str, Sequence[float]]) -> dict[str, Any]:
    """What the seeds say of the product's ratios (``err``: each mode's final errors, the same flights in the
    same order): the 95 % intervals of its median over the best baseline's and over each baseline's, and on how
    many flights it ended nearer the truth than the baseline with the lower median."""
    v, ins, dr = (np.asarray(err[m], float) for m in (PRODUCT, "ins", "airspeed-dr"))
    best = ins if np.median(ins) < np.median(dr) else dr
    out: dict[str, Any] = {"better_than_best_seeds": int((v < best).sum())}
    for name, dens in (("best", (ins, dr)), ("airspeed-dr", (dr,)), ("ins", (ins,))):
        ci = median_ratio_interval(v, *dens)
        if ci is not None:
            out[f"ratio_ci95_{name}"] = list(ci)
    return out


def rate_interval(count: int, exposure: float) -> tuple[float, float]:
    """The exact (Garwood) 95 % interval of a Poisson rate seen ``count`` times in ``exposure`` (hours, say): the
    χ² quantiles of 2k and 2k + 2 degrees of freedom, halved. Zero alarms in 26.5 h still allow 1.4 per 10 h."""
    from scipy.stats import chi2  # the benchmark's extra (sim), not the service's

    lo = 0.0 if count == 0 else float(chi2.ppf(0.5 - RATIO_LEVEL / 2.0, 2 * count)) / 2.0
    return lo / exposure, float(chi2.ppf(0.5 + RATIO_LEVEL / 2.0, 2 * count + 2)) / 2.0 / exposure


def hours_to_show(count: int, rate_bar: float) -> float:
    """The exposure (hours, say) over which ``count`` alarms put :func:`rate_interval`'s upper limit at
    ``rate_bar`` (per hour): what a rate bar needs flown before it can be shown met. 0 alarms under 0.1 per hour:
    36.9 h."""
    return rate_interval(count, 1.0)[1] / rate_bar


def resolved(ci: Sequence[float] | None, bar: float, unit: str = "×", what: str = "seeds") -> str:
    """Whether an interval (:func:`median_ratio_interval`, :func:`rate_interval`) lies clear of its bar: the
    verdict the ``what`` flown can give."""
    if ci is None:
        return f"the {what} are too few for an interval"
    if ci[0] <= bar <= ci[1]:
        return f"the {what} do not resolve it: {bar:g}{unit} is inside the 95 % interval"
    return f"the {what} resolve it: the 95 % interval lies {'below' if ci[1] < bar else 'above'} {bar:g}{unit}"


def wind_hold_summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per ``world/scenario/length``: the median over seeds of :func:`wind_hold_error_m` (runs written before
    2026-11-30 have none)."""
    out: dict[str, dict[str, float]] = {}
    for world, sc, key in dict.fromkeys((r["world"], r["scenario"], k) for r in rows for k in r.get("wind_hold_m", {})):
        v = [r["wind_hold_m"][key] for r in rows if (r["world"], r["scenario"]) == (world, sc) and key in r.get(
            "wind_hold_m", {})]  # fmt: skip
        out[f"{world}/{sc}/{key}"] = {"median_m": float(np.median(v)), "seeds": float(len(v))}
    return out


DETECT_BAR_S: Final = 10.0
# the sources whose exclusion flags each sensor fault: a blocked port is flagged by the front end's per-port check
# ("port"), or by the air-data FDI excluding the ports' air data or the force model they feed
FAULT_SOURCES: Final = {"pitot-blocked": ("pitot",), "pitot-icing": ("pitot",), "pitot-water": ("pitot",),
                        "ports-blocked": ("port", "ports", "force"), "payload-release": ("force",)}  # fmt: skip


def wind_alarm_summary(ms: Sequence[dict[str, Any]], length_s: float) -> dict[str, Any]:
    """The wind-change alarms of flights whose wind does not change (no shear, no gradient): each one is
    false, and relearns the wind from a gust. Counted in the outage (where the detector acts) over its hours,
    with the median final error of the flights that had one and of those that had none."""
    n = np.array([sum(1 for t, s, _ in (x["fdi_events"] or []) if s == "wind" and 0.0 <= t <= length_s) for x in ms])
    fe = np.array([x["final_error_m"] for x in ms])
    h = n > 0
    return {"wind_alarms": int(n.sum()), "wind_alarm_outage_h": len(ms) * length_s / 3600.0,
            "wind_alarm_flights": int(h.sum()),
            "median_with_wind_alarm_m": float(np.median(fe[h])) if h.any() else math.nan,
            "median_without_wind_alarm_m": float(np.median(fe[~h])) if (~h).any() else math.nan}  # fmt: skip


def fdi_summary(ms: Sequence[dict[str, Any]], *, faulty: bool, symptoms_s: Sequence[float | None] = (),
                sources: Sequence[str] = ("pitot",)) -> dict[str, Any]:  # fmt: skip
    """The air-data FDI over the seeds of one scenario and outage: the time to the first exclusion of one of the
    faulty ``sources`` after the fault starts (at the outage start), the share of seeds flagged within
    :data:`DETECT_BAR_S`, and the exclusions of
    healthy flight (before a fault, or all of a healthy scenario's flight) over its hours. With each seed's
    first symptom (:func:`fault_symptom_s`), also the time from it and the share flagged within the bar of it,
    over the seeds whose fault showed one in the outage."""
    detect, false_alarms, healthy_s = [], 0, 0.0
    for x in ms:
        ev = x["fdi_events"] or []
        t0, t1 = x["recorded_s"]
        healthy_s += -t0 if faulty else t1 - t0
        false_alarms += sum(1 for t, s, w in ev if w == "excluded" and (t < 0.0 or not faulty))
        if faulty:
            hits = [t for t, s, w in ev if s in sources and w == "excluded" and t >= 0.0]
            detect.append(hits[0] if hits else math.nan)
    out: dict[str, Any] = {"fdi_false_alarms": false_alarms, "fdi_healthy_h": healthy_s / 3600.0}
    if faulty:
        d = np.array(detect)
        out |= {"fdi_detect_s": [None if math.isnan(v) else v for v in d.tolist()],
                "fdi_detect_median_s": float(np.nanmedian(d)) if np.isfinite(d).any() else math.nan,
                "fdi_flagged_10s": float(np.mean(np.nan_to_num(d, nan=np.inf) <= DETECT_BAR_S))}  # fmt: skip
        span = [x["recorded_s"][1] for x in ms]
        after = [dd - s if s is not None else math.nan for dd, s in zip(d, symptoms_s, strict=False)]
        shown = [s is not None and s <= t1 for s, t1 in zip(symptoms_s, span, strict=False)]
        if any(shown):
            a = np.array([v for v, ok in zip(after, shown, strict=True) if ok])
            out |= {
                "fdi_symptom_s": list(symptoms_s),
                "fdi_after_symptom_median_s": float(np.nanmedian(a)) if np.isfinite(a).any() else math.nan,
                "fdi_flagged_10s_after_symptom": float(np.mean(np.nan_to_num(a, nan=np.inf) <= DETECT_BAR_S)),
                "fdi_symptom_by_10s": float(np.mean([s is not None and s <= DETECT_BAR_S for s in symptoms_s])),
            }
    return out


def free_inertial_sigma_m(part: str, t_s: float, vibration_multiplier: float = 1.0) -> dict[str, float]:
    """The analytic free-inertial horizontal position error per axis (1σ) [m] after ``t_s`` of coasting, from
    the IMU part's data-sheet figures (sim.flight.sensors grades), each term and their root sum of squares.

    Short-time error propagation (t ≪ the 84-minute Schuler period; Groves 2013, §14.2.4; Titterton & Weston
    2004, ch. 12): accelerometer bias b → ½·b·t²; tilt δθ → ½·g·δθ·t², with δθ = b/g, the levelling limit of
    an aided alignment; gyro bias ω → g·ω·t³/6; velocity random walk N_a → N_a·t^{3/2}/√3; angle random walk
    N_g → g·N_g·t^{5/2}/√20. The biases are the in-run instability (the turn-on part is estimated while GNSS
    aids) and the temperature coefficient times a 2 K excursion (the grades' own assumption)."""
    from sim.flight.sensors import IMU_GRADES

    g = IMU_GRADES[part]
    b = g.accel_gm_sigma_m_s2
    w = g.gyro_gm_sigma_rad_s
    grav = 9.80665
    terms = {
        "accel_bias_m": 0.5 * b * t_s**2,
        "tilt_m": 0.5 * grav * (b / grav) * t_s**2,
        "gyro_bias_m": grav * w * t_s**3 / 6.0,
        "vrw_m": g.accel_noise_density_m_s2 * vibration_multiplier * t_s**1.5 / math.sqrt(3.0),
        "arw_m": grav * g.gyro_noise_density_rad_s * vibration_multiplier * t_s**2.5 / math.sqrt(20.0),
    }
    terms["rss_m"] = math.sqrt(sum(v * v for v in terms.values()))
    # the other bound: biases known exactly at the outage start (GNSS-aided calibration), then wandering as
    # their Gauss–Markov processes: Cov(b(s₁) − b(0), b(s₂) − b(0)) = R(s₁ − s₂) − R(s₁) − R(s₂) + R(0),
    # R(d) = σ²·e^(−|d|/T); p = ∫(t − s)·δb ds for the accelerometer, g·∫(t − s)²/2·δω ds for the gyro
    s_ = np.linspace(0.0, t_s, 241)
    ds = s_[1] - s_[0]

    def wander(sigma: float, tau: float, kernel: F64Array) -> float:
        d = np.abs(s_[:, None] - s_[None, :])
        cov = sigma**2 * (np.exp(-d / tau) - np.exp(-s_[:, None] / tau) - np.exp(-s_[None, :] / tau) + 1.0)
        return float(math.sqrt(max(float(kernel @ cov @ kernel), 0.0)) * ds)

    acc = wander(b, g.accel_gm_tau_s, t_s - s_)
    gyr = wander(w, g.gyro_gm_tau_s, grav * (t_s - s_) ** 2 / 2.0)
    terms["calibrated_start_rss_m"] = math.sqrt(acc**2 + gyr**2 + terms["vrw_m"] ** 2 + terms["arw_m"] ** 2)
    return terms


def free_inertial_along(
    part: str, t_s: F64Array, q_nb: F64Array, v_ned: F64Array, *, calibrated_start: bool = False, dt_s: float = 0.1
) -> F64Array:
    """The free-inertial horizontal position error covariance (2, 2) [m²] at the end of a coasting flight along
    a flown trajectory (``t_s`` from the outage start, attitude ``q_nb`` body → NED and ``v_ned`` [m/s] sampled
    at those times), from the IMU part's data-sheet figures: a linear covariance analysis of the short-time
    (no Schuler, no Earth rate) psi-angle error model (Groves 2013, §14.2):

        δṗ = δv,   δv̇ = −[f_n×]·ψ + C_bn·b_a + w_a,   ψ̇ = −C_bn·b_g + w_g,

    with the specific force f_n from the trajectory. The body-frame biases turn with the aircraft, so a heading
    reversal partly undoes what a bias did on the leg before, which the straight-line formula of
    :func:`free_inertial_sigma_m` cannot see; in straight and level flight the two agree term by term. The
    budget (default) holds each bias at its instability for the whole outage with the tilt at its levelling
    limit b/g; ``calibrated_start`` knows the biases and tilt at the start, holds those estimates and lets the
    true biases wander as their stationary Gauss–Markov processes (the bias error b(s) − b(0) reverts towards
    −b(0), so b(0) rides along as a state)."""
    from sim.flight.sensors import IMU_GRADES

    g = IMU_GRADES[part]
    grav = 9.80665
    t = np.arange(0.0, float(t_s[-1]) + 1e-9, dt_s)
    v = np.column_stack([np.interp(t, t_s, v_ned[:, i]) for i in range(3)])
    f_n = np.gradient(v, t, axis=0) - np.array([0.0, 0.0, grav])  # what an accelerometer reads, in NED
    k = np.clip(np.searchsorted(t_s, t), 0, len(t_s) - 1)
    # state: δp, δv, ψ (NED), the bias errors b_a, b_g (body), the biases at the start b_a0, b_g0 (body)
    p = np.zeros((21, 21))
    sa, sg = g.accel_gm_sigma_m_s2, g.gyro_gm_sigma_rad_s
    if not calibrated_start:
        p[6:8, 6:8] = np.eye(2) * (sa / grav) ** 2
        p[9:12, 9:12] = np.eye(3) * sa**2
        p[12:15, 12:15] = np.eye(3) * sg**2
    else:
        p[15:18, 15:18] = np.eye(3) * sa**2
        p[18:21, 18:21] = np.eye(3) * sg**2
    q = np.zeros(21)
    q[3:6] = g.accel_noise_density_m_s2**2
    q[6:9] = g.gyro_noise_density_rad_s**2
    if calibrated_start:
        q[9:12] = 2.0 * sa**2 / g.accel_gm_tau_s
        q[12:15] = 2.0 * sg**2 / g.gyro_gm_tau_s
    eye = np.eye(21)
    for i in range(len(t) - 1):
        c = dcm_from_quat(q_nb[k[i]])
        fx = f_n[i]
        a = np.zeros((21, 21))
        a[0:3, 3:6] = np.eye(3)
        a[3:6, 6:9] = -np.array([[0.0, -fx[2], fx[1]], [fx[2], 0.0, -fx[0]], [-fx[1], fx[0], 0.0]])
        a[3:6, 9:12] = c
        a[6:9, 12:15] = -c
        if calibrated_start:
            for j, tau in ((9, g.accel_gm_tau_s), (12, g.gyro_gm_tau_s)):  # ė = −(e + b0)/τ + w
                a[j : j + 3, j : j + 3] = a[j : j + 3, j + 6 : j + 9] = -np.eye(3) / tau
        ad = a * dt_s
        phi = eye + ad + 0.5 * ad @ ad + ad @ ad @ ad / 6.0
        p = phi @ p @ phi.T + np.diag(q) * dt_s
    return p[0:2, 0:2]


def horizontal_error_cdf(cov_ne: F64Array) -> Callable[[float], float]:
    """P(|e| ≤ r) for a zero-mean 2-D Gaussian error of covariance ``cov_ne`` (2, 2) [m²], r [m] (the Hoyt
    distribution). With the error ρ·(√λ₁ cos θ, √λ₂ sin θ), ρ Rayleigh and θ uniform:
    P(|e| ≤ r) = 1 − mean_θ exp(−r²/2s(θ)²), s² = λ₁cos²θ + λ₂sin²θ, the mean over a periodic grid."""
    lam = np.clip(np.linalg.eigvalsh(cov_ne), 0.0, None)
    th = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)
    s2 = lam[0] * np.cos(th) ** 2 + lam[1] * np.sin(th) ** 2

    def cdf(r: float) -> float:
        if not np.any(s2 > 0.0):
            return 1.0
        with np.errstate(divide="ignore"):
            return 1.0 - float(np.mean(np.exp(-(r * r) / (2.0 * s2))))

    return cdf


def median_horizontal_error_m(cov_ne: F64Array) -> float:
    """The median length of a zero-mean 2-D Gaussian error of covariance ``cov_ne`` (2, 2) [m²]: the root of
    :func:`horizontal_error_cdf` by bisection."""
    lam_max = float(np.clip(np.linalg.eigvalsh(cov_ne), 0.0, None).max())
    if lam_max <= 0.0:
        return 0.0
    cdf = horizontal_error_cdf(cov_ne)
    lo, hi = 0.0, 10.0 * math.sqrt(lam_max)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < 0.5 else (lo, mid)
    return 0.5 * (lo + hi)


def two_sigma_coverage_if_consistent(cov_ne: F64Array) -> float:
    """The probability that the report's test "|e| ≤ 2σ_h" (σ_h the major axis's σ, as :func:`_metrics` takes it)
    passes for an error drawn from the filter's own covariance ``cov_ne`` [m²]: what a consistent filter
    scores. A 2-D error is not a 1-D one: 1 − e⁻² = 86.5 % for a round covariance, up to 95.4 % for a flat one."""
    return horizontal_error_cdf(cov_ne)(2.0 * math.sqrt(float(np.clip(np.linalg.eigvalsh(cov_ne), 0.0, None).max())))


def share_reached_probability(p: Sequence[float], share: float) -> float:
    """The probability that independent trials of success probabilities ``p`` succeed in at least ``share`` of
    them (the Poisson-binomial distribution, by convolution): how often a consistent filter passes a coverage
    bar over this many seeds."""
    dist = np.array([1.0])
    for pi in p:
        dist = np.convolve(dist, [1.0 - pi, pi])
    need = math.ceil(share * len(p) - 1e-9)
    return float(dist[need:].sum())


MEDIAN_RAYLEIGH: Final = math.sqrt(2.0 * math.log(2.0))  # median |e| of a 2-D error of σ per axis, in σ


def ins_theory(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The free-inertial reference's median horizontal error at outage end (``ins`` with its magnetometer
    and barometer dropped for the outage: the IMU alone), per world, IMU part and outage length, against the
    data sheet's theory along each seed's flown trajectory (:func:`free_inertial_along`; median over seeds of each
    seed's median): the budget (biases held at their instability) and the calibrated start (biases known at
    the start, then wandering), which bracket what a GNSS-aided start knows. The straight-line formula
    (:func:`free_inertial_sigma_m`) and the aided ``ins`` mode beside them."""
    out = []
    sel = [r for r in rows if r["scenario"] == "survey" and "free_inertial" in r]
    for world, part, key in dict.fromkeys((r["world"], r["imu_part"], k) for r in sel for k in r["free_inertial"]):
        mine = [r for r in sel if (r["world"], r["imu_part"]) == (world, part) and key in r["free_inertial"]]

        def med(field: str, mine: list[dict[str, Any]] = mine, key: str = key) -> float:
            return float(np.median([r["free_inertial"][key][field] for r in mine]))

        free, budget, cal = med("final_error_m"), med("budget_median_m"), med("calibrated_start_median_m")
        aided = float(np.median([r["outages"][key]["ins"]["final_error_m"] for r in mine]))
        straight = free_inertial_sigma_m(part, float(key))
        out.append({"world": world, "imu_part": part, "outage_s": float(key), "seeds": len(mine),
                    "free_median_m": free, "ins_median_m": aided, "theory_median_m": budget,
                    "calibrated_start_median_m": cal, "ratio": free / budget, "ratio_calibrated": free / cal,
                    "straight_median_m": MEDIAN_RAYLEIGH * straight["rss_m"], "terms_m": straight})  # fmt: skip
    return out


_HEADER: Final = (
    "| mode | median [m] | p95 [m] | max [m] | % of distance | max during [m] | 2σ covers | NEES in band "
    "| reacq. jump [m] | filter CPU / flight s | ÷ vdm (95 % interval) |"
)


SPEED_BAR_X_REAL_TIME: Final = 50.0
COVERAGE_BAR: Final = 0.9  # issue 22: 2σ covers the outage-end error in ≥ 90 % of seeds


def bars(summary: dict[str, Any], theory: Sequence[dict[str, Any]] = (),
         wind_hold: dict[str, dict[str, float]] | None = None) -> list[tuple[str, str, bool, str]]:  # fmt: skip
    """The report's bars, each as (bar, what was measured, met, how the number could come out wrong), for
    whatever the run covered. Every bar compares two things that can differ. ``wind_hold``
    (:func:`wind_hold_summary`) puts the held-wind dead reckoner beside the order-of-magnitude bar."""
    out: list[tuple[str, str, bool, str]] = []

    def med(key: str, mode: str) -> float | None:
        return summary.get(key, {}).get(mode, {}).get("median_m")

    nn, dr = "vdm-deim-nn", "airspeed-dr"
    worlds = dict.fromkeys(k.split("/")[0] for k in summary if not k.startswith("only:"))  # harsh(-without), kind
    for w in worlds:
        for key in [k for k in summary if k.startswith(f"{w}/")]:
            _, sc, length = key.split("/")
            a, b = med(key, nn), med(key, dr)
            if a is not None and b is not None and sc in ("survey", "survey-calm", "loiter", "manoeuvring"):
                out.append((f"{w} {sc} {length} s: {nn} ≤ {dr} (the ports beat the autopilot's pitot DR)",
                            f"{a:.1f} / {b:.1f} m = {a / b:.2f}×", a <= b,
                            "both read the same flights; the seeds are few for a median"))  # fmt: skip
            if sc.startswith("pitot-") and a is not None and b is not None:
                out.append((f"{w} {sc} {length} s: {nn} ≤ 0.5× {dr} (the ports shine when the pitot fails)",
                            f"{a / b:.2f}×", a <= 0.5 * b,
                            f"{dr} reads the failed pitot, {nn} never does: a fault too mild to matter "
                            "passes"))  # fmt: skip
            healthy = med(f"{w}/survey/{length}", dr)
            if sc.startswith("pitot-") and b is not None and healthy is not None:
                out.append((f"{w} {sc} {length} s: the fault hurts {dr} (> 1.2× its healthy survey)",
                            f"{b / healthy:.2f}×", b > 1.2 * healthy,
                            "the same flights with and without the fault: if the fault is not felt the scenario "
                            "tests nothing"))  # fmt: skip
            ins = med(key, "ins")
            if sc in ("wind-shear", "rtl-wind-gradient") and a is not None and ins is not None:
                out.append(
                    (
                        f"{w} {sc} {length} s: {nn} ≤ ins (a wind change must not make air data worse)",
                        f"{a / ins:.2f}×",
                        a <= ins,
                        "the held wind is the weak point of every air-data mode",
                    )
                )
    out += product_bars(summary, wind_hold or {})
    for th in theory:
        lo, hi = th["calibrated_start_median_m"], th["theory_median_m"]
        out.append((f"{th['world']} {th['imu_part']} {th['outage_s']:g} s: free INS within 2× of the data sheet's "
                    "theory along the flown trajectory (calibrated start ÷ 2 … budget × 2)",
                    f"{th['free_median_m']:.0f} m in {lo:.0f} … {hi:.0f} m: {th['ratio_calibrated']:.2f}× / "
                    f"{th['ratio']:.2f}× ({th['seeds']} seeds)", 0.5 * lo <= th["free_median_m"] <= 2.0 * hi,
                    "the theory is linear, small-angle and drops the magnetometer-free heading's start error; "
                    "a median of few seeds of a Hoyt-distributed error is itself uncertain by tens of %"))  # fmt: skip
    modes = sorted({m for per in summary.values() for m in per}, key=[*MODES, *ABLATIONS].index)
    for mode in modes:
        keyed = [(k, per[mode]) for k, per in summary.items() if mode in per and not k.startswith("only:")]
        if not keyed:
            continue
        k_n, worst_n = min(keyed, key=lambda kv: kv[1]["nees_in_band"])
        k_c, worst_c = min(keyed, key=lambda kv: kv[1]["covered_2sigma"])
        out.append((f"{mode}: NEES in the 95 % band ≥ 90 % of aided epochs (worst scenario)",
                    f"{100 * worst_n['nees_in_band']:.0f} % ({k_n.rsplit('/', 1)[0]})",
                    worst_n["nees_in_band"] >= 0.9, "the filter's own σ against the truth"))  # fmt: skip
        ideal = ""
        if "covered_2sigma_if_consistent" in worst_c:
            ideal = (f"; a consistent filter with these σ: {100 * worst_c['covered_2sigma_if_consistent']:.0f} %, "
                     f"reaching {100 * COVERAGE_BAR:.0f} % in "
                     f"{100 * worst_c['coverage_bar_pass_if_consistent']:.0f} % of such runs")  # fmt: skip
        out.append((f"{mode}: 2σ covers the error at outage end ≥ {100 * COVERAGE_BAR:.0f} % of seeds (worst)",
                    f"{100 * worst_c['covered_2sigma']:.0f} % ({k_c}){ideal}",
                    worst_c["covered_2sigma"] >= COVERAGE_BAR,
                    "few seeds: one miss in ten is the bar; a 2-D error inside 2σ of its major axis is 86.5–95.4 %, "
                    "not 95 %"))  # fmt: skip
        cpu = max(st["cpu_s_per_flight_s"] for _, st in keyed)
        out.append((f"{mode}: ≥ {SPEED_BAR_X_REAL_TIME:g}× real time (benchmark run, per mode, front end shared)",
                    f"{1.0 / cpu:.0f}×", 1.0 / cpu >= SPEED_BAR_X_REAL_TIME, "a shared, noisy machine"))  # fmt: skip
    return out


PRODUCT: Final = "vdm"
HEALTHY_SCENARIOS: Final = ("survey", "survey-calm", "loiter", "manoeuvring")


def interval(ci: Sequence[float] | None, per: dict[str, Any] | None = None) -> str:
    """A ratio's 95 % interval as the bars print it (and, from ``per``, the flights the product won), or ""."""
    if ci is None:
        return ""
    won = "" if per is None else f", better on {per['better_than_best_seeds']} of {per['seeds']} flights"
    return f" (95 % interval {ci[0]:.2f}–{ci[1]:.2f}×{won})"


def product_bars(summary: dict[str, Any], wind_hold: dict[str, dict[str, float]] | None = None
                 ) -> list[tuple[str, str, bool, str]]:  # fmt: skip
    """Issue 22's bars for the product mode (when the run has it): never worse than what the autopilot has,
    better when the pitot fails or the wind changes, an order of magnitude over inertial coasting, and an FDI
    that flags a failed pitot fast without crying wolf in healthy flight."""
    out: list[tuple[str, str, bool, str]] = []
    v, dr = PRODUCT, "airspeed-dr"

    def med(key: str, mode: str) -> float | None:
        return summary.get(key, {}).get(mode, {}).get("median_m")

    false_alarms, hours = 0, 0.0
    wind_alarms, outage_h, with_alarm = 0, 0.0, []
    for key, per in summary.items():
        if v in per and not key.startswith("only:") and "wind_alarms" in per[v]:
            wind_alarms += per[v]["wind_alarms"]
            outage_h += per[v]["wind_alarm_outage_h"]
            if per[v]["wind_alarm_flights"] and key.split("/")[1] == COST_SCENARIO:
                with_alarm.append(
                    f"{key.split('/', 1)[1]} {per[v]['median_with_wind_alarm_m']:.0f} against "
                    f"{per[v]['median_without_wind_alarm_m']:.0f} m ({per[v]['wind_alarm_flights']})"
                )
        if v not in per or key.startswith("only:"):
            continue
        w, sc, length = key.split("/")
        a, b, ins = med(key, v), med(key, dr), med(key, "ins")
        false_alarms += per[v].get("fdi_false_alarms", 0)
        hours += per[v].get("fdi_healthy_h", 0.0)
        if a is not None and b is not None and ins is not None:
            best = min(b, ins)
            ci = per[v].get("ratio_ci95_best")
            out.append((f"{w} {sc} {length} s: {v} ≤ 1.05× the best of ins and {dr}",
                        f"{a:.0f} / {best:.0f} m = {a / best:.2f}×{interval(ci, per[v])}", a <= 1.05 * best,
                        f"the same flights; {resolved(ci, 1.05)}"))  # fmt: skip
        if sc in FAULT_SOURCES and length in ("120", "300") and a is not None and b is not None:
            if sc.startswith("pitot-"):
                ci = per[v].get("ratio_ci95_airspeed-dr")
                out.append((f"{w} {sc} {length} s: {v} ≤ 0.5× {dr}", f"{a / b:.2f}×{interval(ci)}", a <= 0.5 * b,
                            f"{dr} reads the failed pitot; a fault too mild to matter passes; "
                            f"{resolved(ci, 0.5)}"))  # fmt: skip
            healthy = med(f"{w}/survey/{length}", v)
            if healthy is not None:
                out.append((f"{w} {sc} {length} s: {v} ≤ 1.3× its healthy survey", f"{a / healthy:.2f}×",
                            a <= 1.3 * healthy, "the same flights with and without the fault"))  # fmt: skip
            flagged = per[v].get("fdi_flagged_10s")
            if flagged is not None:
                seen = ""
                if "fdi_flagged_10s_after_symptom" in per[v]:
                    seen = (f"; its first {SYMPTOM_M_S:g} m/s off came within {DETECT_BAR_S:g} s in "
                            f"{100 * per[v]['fdi_symptom_by_10s']:.0f} %, flagged within {DETECT_BAR_S:g} s of that in "
                            f"{100 * per[v]['fdi_flagged_10s_after_symptom']:.0f} % (median "
                            f"{per[v]['fdi_after_symptom_median_s']:.1f} s)")  # fmt: skip
                out.append((f"{w} {sc} {length} s: {v} flags the {' or '.join(FAULT_SOURCES[sc])} within "
                            f"{DETECT_BAR_S:g} s of the fault (≥ 90 % of seeds)",
                            f"{100 * flagged:.0f} % (median {per[v]['fdi_detect_median_s']:.1f} s){seen}",
                            flagged >= 0.9, "the fault starts at the outage start; a slow icing ramp may be "
                            "harmless for its first seconds"))  # fmt: skip
        if sc in ("wind-shear", "rtl-wind-gradient") and length == "300" and None not in (a, b, ins):
            assert a is not None and b is not None and ins is not None
            ci_dr, ci_ins = per[v].get("ratio_ci95_airspeed-dr"), per[v].get("ratio_ci95_ins")
            out.append((f"{w} {sc} 300 s: {v} ≤ 0.5× {dr} and ≤ 1.0× ins",
                        f"{a / b:.2f}×{interval(ci_dr)} / {a / ins:.2f}×{interval(ci_ins)}",
                        a <= 0.5 * b and a <= ins, f"the held wind is what a wind change breaks; against {dr}: "
                        f"{resolved(ci_dr, 0.5)}; against ins: {resolved(ci_ins, 1.0)}"))  # fmt: skip
        if sc == "survey" and length == "300" and a is not None and ins is not None:
            hold = (wind_hold or {}).get(key, {}).get("median_m")
            held = "" if hold is None else (f"; ins ÷ a dead reckoner with the exact air velocity that holds the "
                                            f"true wind of the minute before: {ins / hold:.1f}×")  # fmt: skip
            out.append((f"{w} survey 300 s: ins ≥ 10× {v}", f"{ins / a:.1f}×{held}", ins >= 10.0 * a,
                        "the harsh world's INS; a kind IMU would shrink the ratio"))  # fmt: skip
    if hours > 0.0:
        rate = false_alarms / hours
        ci = [10.0 * r for r in rate_interval(false_alarms, hours)]
        out.append((f"{v}: FDI false alarms < 1 per 10 h of healthy flight",
                    f"{false_alarms} in {hours:.2f} h (95 % interval {ci[0]:.2f}–{ci[1]:.2f} per 10 h)", rate < 0.1,
                    f"{resolved(ci, 1.0, ' per 10 h', 'hours')}; zero alarms need {hours_to_show(0, 0.1):.0f} h to "
                    "show a rate under 1 per 10 h"))  # fmt: skip
    if outage_h > 0.0:
        seen = f"; {COST_SCENARIO} median error with one / without (flights with one): " if with_alarm else ""
        ci = [10.0 * r for r in rate_interval(wind_alarms, outage_h)]
        out.append((f"{v}: wind-change alarms < 1 per 10 h of outage flight where the wind does not change",
                    f"{wind_alarms} in {outage_h:.2f} h (95 % interval {ci[0]:.2f}–{ci[1]:.2f} per 10 h)"
                    f"{seen}{'; '.join(with_alarm)}",
                    wind_alarms / outage_h < 0.1, "each relearns the wind from a gust; the survey and the pitot "
                    f"faults share their flights, so one gust can count in each; "
                    f"{resolved(ci, 1.0, ' per 10 h', 'hours')}"))  # fmt: skip
    return out


def cost_table(rows: Sequence[dict[str, Any]], modes: Sequence[str], stat: str = "final_error_m"
               ) -> list[tuple[str, dict[str, float]]]:  # fmt: skip
    """What each effect costs: (world, per mode the median final error, or with ``stat="nees_in_band"`` the
    mean NEES share in band) on the survey at the cost table's outage length, for the kind world, each
    effect alone and the harsh world(s), every world over the same seeds: those the single-effect runs flew
    (a median over other seeds would compare the weather, not the effect)."""
    key = f"{COST_OUTAGE_S:g}"
    at = [r for r in rows if r["scenario"] == COST_SCENARIO and key in r["outages"]]
    seeds = {r["seed"] for r in at if r["world"].startswith("only:")}
    out = []
    for w in dict.fromkeys(r["world"] for r in at):
        mine = [r for r in at if r["world"] == w and (not seeds or r["seed"] in seeds)]
        if not mine:
            continue
        per = {}
        for m in modes:
            vals = [r["outages"][key][m][stat] for r in mine if m in r["outages"][key]]
            if vals:
                per[m] = float(np.median(vals)) if stat == "final_error_m" else float(np.nanmean(vals))
        out.append((w, per))
    order = {"kind": 0}
    return sorted(out, key=lambda r: (order.get(r[0], 2 if r[0].startswith("harsh") else 1), r[0]))


def _to_product(stats: dict[str, Any]) -> str:
    """A mode's median over the product's on the same flights, with its 95 % interval (the report's last
    column): above 1 with the interval above 1 too, the product's win over that mode is one the seeds resolve."""
    if "ratio_to_product" not in stats:
        return "—"
    ci = stats.get("ratio_to_product_ci95")
    return f"{stats['ratio_to_product']:.2f}" + ("" if ci is None else f" ({ci[0]:.2f}–{ci[1]:.2f})")


def _nees_blocks(med: dict[str, float]) -> str:
    return " / ".join(f"{med[b]:.1f}" for b in NEES_BLOCKS)


def format_report(doc: dict[str, Any]) -> str:
    spec = doc["spec"]
    first = int(spec.get("first_seed", 0))  # a run on other seeds says which: a threshold's unseen-seed check
    lines = [f"# Navigation drift: {len(doc['runs'])} runs, modes {', '.join(spec['modes'])}, seeds {first}–"
             f"{first + int(spec['seeds']) - 1}", ""]  # fmt: skip
    for key, per in doc["summary"].items():
        world, sc, length = key.split("/")
        if world.startswith("only:"):
            continue
        n = max((s["seeds"] for s in per.values()), default=0)
        lines += [f"## {world} world: {sc}, {length} s outage ({n} seeds)", "", _HEADER, "|---" * 11 + "|"]
        for m, s in per.items():
            lines.append(
                f"| {m} | {s['median_m']:.1f} | {s['p95_m']:.1f} | {s['max_m']:.1f} | {s['pct_distance_median']:.2f} "
                f"| {s['max_during_median_m']:.1f} | {100 * s['covered_2sigma']:.0f} % "
                f"| {100 * s['nees_in_band']:.0f} % | {s['reacquisition_jump_median_m']:.1f} "
                f"| {1e3 * s['cpu_s_per_flight_s']:.1f} ms | {_to_product(s)} |"
            )
        blocks = [f"{m} {_nees_blocks(s['nees_block_median'])}" for m, s in per.items() if "nees_block_median" in s]
        if blocks:
            lines += ["", "NEES by block, the median over the runs of each run's aided median (position / velocity / "
                      f"attitude; {NEES_BLOCK_MEDIAN_CONSISTENT} if consistent): {'; '.join(blocks)}."]  # fmt: skip
        lines.append("")
    costs = cost_table(doc["runs"], spec["modes"])
    if any(w.startswith("only:") for w, _ in costs):
        seeds = sorted({r["seed"] for r in doc["runs"] if r["world"].startswith("only:")})
        lines += [f"## What each effect costs: {COST_SCENARIO}, {COST_OUTAGE_S:g} s outage, median final error [m]",
                  "", f"Each effect alone on the kind world; the harsh world has them all. Every row flies the same "
                  f"seeds ({', '.join(map(str, seeds))}): the same winds, turbulence and outage starts.", "",
                  "| world | " + " | ".join(spec["modes"]) + " |", "|---" * (len(spec["modes"]) + 1) + "|"]  # fmt: skip
        for w, per in costs:
            lines.append(f"| {w} | " + " | ".join(f"{per.get(m, math.nan):.1f}" for m in spec["modes"]) + " |")
        lines += ["", "What each effect does to consistency: NEES in the 95 % band, share of aided epochs", "",
                  "| world | " + " | ".join(spec["modes"]) + " |", "|---" * (len(spec["modes"]) + 1) + "|"]  # fmt: skip
        for w, per in cost_table(doc["runs"], spec["modes"], "nees_in_band"):
            lines.append(f"| {w} | " + " | ".join(f"{100 * per.get(m, math.nan):.0f} %" for m in spec["modes"]) + " |")
        lines.append("")
    if doc.get("ins_theory"):
        lines += ["## INS coasting against the free-inertial theory (survey, median final error)", "",
                  "Free INS: the `ins` filter with its magnetometer and barometer dropped for the outage (the IMU "
                  "alone); `ins` keeps both.", "",
                  "The theory is the data sheet's error model propagated along each seed's flown trajectory (a "
                  "linear covariance analysis): the budget holds each bias at its instability for the whole outage, "
                  "the calibrated start knows the biases at the outage start and lets them wander. A GNSS-aided "
                  "start lies between the two. The straight-line budget is the closed form for one heading: the "
                  "survey's turns undo part of what a body-frame bias did on the leg before.", "",
                  "| world | IMU | outage [s] | seeds | free INS [m] | calibrated start [m] | budget [m] "
                  "| free / budget | straight-line budget [m] | ins [m] "
                  "| straight-line terms: accel bias / tilt / gyro bias / VRW / ARW [m] |",
                  "|---" * 11 + "|"]  # fmt: skip
        for th in doc["ins_theory"]:
            t = th["terms_m"]
            lines.append(f"| {th['world']} | {th['imu_part']} | {th['outage_s']:g} | {th['seeds']} "
                         f"| {th['free_median_m']:.1f} | {th['calibrated_start_median_m']:.1f} "
                         f"| {th['theory_median_m']:.1f} | {th['ratio']:.2f} | {th['straight_median_m']:.1f} "
                         f"| {th['ins_median_m']:.1f} | {t['accel_bias_m']:.1f} / {t['tilt_m']:.1f} / "
                         f"{t['gyro_bias_m']:.1f} / {t['vrw_m']:.2f} / {t['arw_m']:.2f} |")  # fmt: skip
        lines.append("")
    if doc.get("wind_hold"):
        show = [m for m in ("ins", "airspeed-dr", PRODUCT) if m in spec["modes"]]
        lines += ["## The wind's own change (median final error [m])", "",
                  "Held wind: a dead reckoner that knows its air-relative velocity exactly and holds the wind at the "
                  f"truth's mean over the last {WIND_HOLD_BEFORE_S:g} s before the outage (the judge's measure of what "
                  "the wind's change, turbulence included, costs whoever holds it; it reads the truth, so no filter "
                  "has it). A mode below it follows the wind through the outage.", "",
                  "| world | scenario | outage [s] | seeds | held wind | " + " | ".join(show)
                  + " | ins ÷ held wind |", "|---" * (len(show) + 6) + "|"]  # fmt: skip
        for key, hold in doc["wind_hold"].items():
            world, sc, length = key.split("/")
            if world.startswith("only:"):
                continue
            per = doc["summary"].get(key, {})
            meds = [per.get(m, {}).get("median_m", math.nan) for m in show]
            ratio = per.get("ins", {}).get("median_m", math.nan) / hold["median_m"]
            lines.append(f"| {world} | {sc} | {length} | {hold['seeds']:.0f} | {hold['median_m']:.1f} | "
                         + " | ".join(f"{x:.1f}" for x in meds) + f" | {ratio:.1f}× |")  # fmt: skip
        lines.append("")
    checks = bars(doc["summary"], doc.get("ins_theory", ()), doc.get("wind_hold", {}))
    if checks:
        lines += ["## Bars", "", "| bar | measured | met | how it could come out wrong |", "|---|---|---|---|"]
        lines += [f"| {b} | {m} | {'yes' if ok else '**no**'} | {why} |" for b, m, ok, why in checks]
        lines.append("")
    return "\n".join(lines)


def plot_report(doc: dict[str, Any], out: Path) -> list[Path]:
    """Error vs time per mode (median and 10–90 % band over seeds) and the final-error CDF, per world, scenario
    and outage length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    spec = doc["spec"]
    for key in doc["summary"]:
        world, sc, length = key.split("/")
        if world.startswith("only:"):
            continue
        runs = [r for r in doc["runs"] if r["scenario"] == sc and r["world"] == world and length in r["outages"]]
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
        for m in spec["modes"]:
            curves = [r["outages"][length][m]["error_curve"] for r in runs]
            grid = np.linspace(0.0, float(length), 121)
            e = np.array([np.interp(grid, c["t_s"], c["e_m"]) for c in curves if c["t_s"]])
            if not len(e):
                continue
            med = np.median(e, axis=0)
            (line,) = axes[0].plot(grid, med, label=m)
            axes[0].fill_between(grid, np.percentile(e, 10, axis=0), np.percentile(e, 90, axis=0), alpha=0.15,
                                 color=line.get_color())  # fmt: skip
            fe = np.sort([r["outages"][length][m]["final_error_m"] for r in runs])
            axes[1].step(fe, np.arange(1, len(fe) + 1) / len(fe), where="post", label=m)
        axes[0].set(xlabel="time in outage [s]", ylabel="horizontal error [m]",
                    title=f"{world}: {sc}, {length} s: median, 10–90 %")  # fmt: skip
        axes[1].set(xlabel="error at outage end [m]", ylabel="fraction of seeds", title="final-error CDF")
        axes[1].set_xscale("log")
        for ax in axes:
            ax.legend(fontsize=7)
        fig.tight_layout()
        p = out / f"nav-drift-{world}-{sc}-{length}s.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def write_report(doc: dict[str, Any], out: Path) -> dict[str, Path]:
    out.mkdir(parents=True, exist_ok=True)
    slim = {**doc, "runs": [{**r, "outages": {k: {m: {kk: vv for kk, vv in v.items() if kk != "error_curve"}
                                                      for m, v in o.items()} for k, o in r["outages"].items()}}
                            for r in doc["runs"]]}  # fmt: skip
    (out / "nav-drift.json").write_text(json.dumps(slim, indent=1))
    (out / "nav-drift.md").write_text(format_report(doc))
    plots = plot_report(doc, out)
    return {"json": out / "nav-drift.json", "markdown": out / "nav-drift.md", **{p.stem: p for p in plots}}


def default_modes() -> tuple[str, ...]:
    return tuple(MODES)


def build_artifacts(out: Path, *, calibration_minutes: float = 10.0, max_epochs: int = 1000, seed: int = 0,
                    progress: Callable[[str], None] | None = None) -> NavArtifacts:  # fmt: skip
    """The user's side of the benchmark, from scratch: the design data set, DEIM on 12 ports, and the
    correction net calibrated on a flight of the as-built aircraft (the calibration issue's workflow).
    Reused when ``out`` already holds them."""
    from vdm_aero_cli.calibration_study import design_models

    art = NavArtifacts.under(out, calibration_minutes)
    if _cached(art.nn_dir) and _cached(art.deim_dir):
        return art
    if progress:
        progress("design data set, DEIM and the design net")
    design_models(out, 12, grid="quick", seed=seed, max_epochs=max_epochs)
    if progress:
        progress("calibration flight of the as-built aircraft and the in-flight calibration of the net")
    _calibrate(art, "kind", 0, art.nn_dir, calibration_minutes, max_epochs, seed)
    return art


def _cached(model_dir: Path) -> bool:
    """A model left by an earlier run that this version still loads (one calibrated by an older version is
    refused by :meth:`AeroModel.load`, and made again)."""
    from vdm_aero.errors import ModelError
    from vdm_aero.model import AeroModel

    if not (model_dir / "model.yaml").is_file():
        return False
    try:
        AeroModel.load(model_dir)
    except ModelError:
        return False
    return True


# another day's weather for each airframe's calibration flight: wind 2–8 m/s from anywhere, ISA ± 10 K
CALIBRATION_WIND_M_S: Final = (2.0, 8.0)
CALIBRATION_ISA_DELTA_K: Final = (-10.0, 10.0)


def calibrate_airframe(artifacts: NavArtifacts, world: str, airframe: int, max_epochs: int = 1000,
                       seed: int = 0) -> Path:  # fmt: skip
    """A fleet airframe's calibrated net, from its own calibration flight in ``world`` on another day's weather
    (cached: an existing model is reused). The calibration length is the base calibration's."""
    nn_dir = models_for(artifacts, world, airframe).nn_dir
    if not _cached(nn_dir):
        minutes = float(artifacts.nn_dir.name.rsplit("-", 1)[1].removesuffix("min"))
        _calibrate(artifacts, world, airframe, nn_dir, minutes, max_epochs, seed)
    return nn_dir


def _calibrate(art: NavArtifacts, world: str, airframe: int, nn_dir: Path, minutes: float, max_epochs: int,
               seed: int) -> None:  # fmt: skip
    from sim.flight.environment import Atmosphere, SteadyWind
    from sim.flight.record import record_flight, with_model_ports
    from sim.flight.scenario import load_scenario, with_world
    from vdm_aero.calibrate import TargetSettings, calibrate_model
    from vdm_aero.flightlog import load_sensor_log
    from vdm_aero.vehicle import load_vehicle
    from vdm_aero_cli.calibration_study import CALIBRATION_START_S

    sc = with_model_ports(load_scenario("calibration-asbuilt"), art.deim_dir)
    flights = nn_dir.parent.parent / "flights"
    if world_effects(world):
        rng = np.random.default_rng([7, airframe])
        sc = replace(sc, seed=int(rng.integers(2**31)),
                     wind=SteadyWind(float(rng.uniform(*CALIBRATION_WIND_M_S)), float(rng.uniform(0.0, 360.0))),
                     atmosphere=Atmosphere(float(rng.uniform(*CALIBRATION_ISA_DELTA_K))))  # fmt: skip
        sc = with_world(sc, world_effects(world), airframe)
        log_dir = flights / f"calibration-{nn_dir.name}"
    else:
        log_dir = flights / "calibration"
    record_flight(sc, log_dir, duration_s=CALIBRATION_START_S + 60.0 * minutes)
    calibrate_model(art.deim_dir, load_sensor_log(log_dir), load_vehicle("uav-2m"), nn_dir,
                    design_data=art.dataset_dir, grid="quick", seed=seed,
                    max_epochs=max_epochs, settings=TargetSettings(rate_hz=10.0))  # fmt: skip


def filter_speed(artifacts: NavArtifacts, *, seconds: float = 120.0, repeats: int = 3) -> dict[str, Any]:
    """CPU per filter step and real-time ratio of each mode alone on ``seconds`` of a survey flight
    (400 Hz IMU, 50 Hz filter): medians over ``repeats``."""
    import statistics

    sensors, truth, meta, _ = _flight("survey", 0, artifacts, seconds)
    nav = _nav(artifacts)
    out: dict[str, Any] = {"flight_s": seconds, "imu_rate_hz": 400.0, "modes": {}}
    for m in MODES:
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            run_filters(sensors, truth, meta, seconds - 1.0, (0.5,), (m,), nav)
            times.append(time.process_time() - t0)
        cpu = statistics.median(times)
        out["modes"][m] = {"cpu_s": round(cpu, 3), "x_real_time": round(seconds / cpu, 1),
                           "us_per_filter_step": round(1e6 * cpu / (seconds * 50.0), 1)}  # fmt: skip
    out["meets_bar"] = all(v["x_real_time"] >= 50.0 for v in out["modes"].values())
    return out
