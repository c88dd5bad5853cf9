"""``vdm-aero bench nav-drift``: how far each navigation mode drifts through a GNSS outage.

The world flies the **as-built** aircraft (sim.flight); the filters know only what a user knows: the design
data set, the nominal vehicle description (``uav-2m``), the aero models built from the design data and
calibrated in flight, and the sensor streams. The world's truth is read only to score.

Per scenario and seed the world draws the wind (speed, direction), the turbulence level, the sensor errors
and the outage start. Every mode runs on the same sensor streams in one pass; at the outage start the run
is copied once per outage length, so one converged filter serves every length.

Scenarios: ``survey``, ``wind-shear`` (the wind turns by 60° and strengthens by 4 m/s during the outage),
``loiter``, ``no-airspeed`` (the survey flights without their pitot), ``pitot-blocked`` (the pitot's total
port blocks at the outage start: the trapped pressure then reads Δp₀ + p_s(t₀) − p_s(t)) and
``manoeuvring`` (45° banks, slow flight at high α, doublets); ``survey-calm`` flies the survey's draws in
still air, so that the difference to ``survey`` is what turbulence costs.
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.flightlog import SensorLog
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.filter import MODES, NavConfig, NavFilter
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.stream import LogRunner, NavStream, SolutionRecorder
from vdm_aero.rotation import euler_from_quat, quat_log, quat_multiply

__all__ = ["SCENARIOS", "BenchSpec", "NavArtifacts", "format_report", "run_nav_drift"]

SCENARIOS: Final = {
    # name: (flight preset, wind speed range [m/s], turbulence levels, sensor-stream fault)
    "survey": ("nav-survey", (8.0, 10.0), ("light", "moderate"), None),
    "wind-shear": ("nav-survey", (6.0, 10.0), ("light", "moderate"), "shear"),
    "loiter": ("nav-loiter", (0.0, 12.0), ("light", "moderate"), None),
    "no-airspeed": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "no-airspeed"),
    "pitot-blocked": ("nav-survey", (8.0, 10.0), ("light", "moderate"), "pitot-blocked"),
    "manoeuvring": ("nav-manoeuvring", (0.0, 12.0), ("light", "moderate"), None),
    # the survey's flights (same winds, sensor errors and outage starts) in still air: what turbulence costs
    "survey-calm": ("nav-survey", (8.0, 10.0), ("none",), None),
}
OUTAGE_START_S: Final = (150.0, 210.0)  # after the filter has converged (wind, biases, model parameters)
AFTER_S: Final = 20.0  # flown after each outage: the reacquisition
RECORD_HZ: Final = 5.0
CONVERGED_AFTER_S: Final = 60.0  # NEES epochs: GNSS-aided, this long after the filter started
NEES_DOF: Final = 9
NEES_BAND_95: Final = (2.700, 19.023)  # χ²(9) 2.5 % and 97.5 % points
WIND_AVERAGE_S: Final = 30.0  # the "best held wind": the true wind averaged over this long before the outage


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


# ------------------------------------------------------------------------------------ the world side
def _flight_key(name: str) -> tuple[str, bool, tuple[str, ...]]:
    """What makes a flight: the preset, a wind shear or not, the turbulence levels (faults are injected into
    the sensor streams afterwards, so scenarios differing only by a fault share one flight)."""
    preset, _, levels, fault = SCENARIOS[name]
    return preset, fault == "shear", levels


def _draws_of(name: str) -> str:
    """The scenario whose random draws a flight uses: the first with the same preset and shear, so the
    fault scenarios and ``survey-calm`` fly the survey's winds, sensor errors and outage starts (paired)."""
    preset, shear, _ = _flight_key(name)
    return next(n for n in SCENARIOS if _flight_key(n)[:2] == (preset, shear))


def bench_scenario(name: str, seed: int, deim_dir: Path, duration_s: float) -> tuple[Any, dict[str, Any], float]:
    """One seed of a scenario as the world flies it: (``sim.flight.scenario.Scenario``, meta, outage start).

    The scenario has no GNSS outage of its own: the benchmark removes the fixes in the filter's stream, and
    the SITL run (``vdm-aero sitl --nav-scenario``) adds the outage window to the world's receiver.
    """
    from sim.flight.environment import SteadyWind, WindShear
    from sim.flight.record import with_model_ports
    from sim.flight.scenario import load_scenario

    preset, shear, levels = _flight_key(name)
    draws = _draws_of(name)
    _, (w_lo, w_hi), draw_levels, _ = SCENARIOS[draws]
    rng = np.random.default_rng([list(SCENARIOS).index(draws), seed])
    wind = SteadyWind(speed_m_s=float(rng.uniform(w_lo, w_hi)), from_deg=float(rng.uniform(0.0, 360.0)))
    level = str(levels[min(int(rng.integers(len(draw_levels))), len(levels) - 1)])
    t_out = float(rng.uniform(*OUTAGE_START_S))
    sc = with_model_ports(load_scenario(preset), deim_dir)
    wind_shear = None
    if shear:
        wind_shear = WindShear(start_s=t_out + 20.0, ramp_s=10.0,
                          to=SteadyWind(wind.speed_m_s + 4.0, wind.from_deg + 60.0))  # fmt: skip
    sc = replace(sc, seed=int(rng.integers(2**31)), wind=wind, turbulence=level, wind_shear=wind_shear,
                 duration_s=duration_s)  # fmt: skip
    meta = {
        "home": {"lat_deg": sc.home_lat_deg, "lon_deg": sc.home_lon_deg, "alt_m": sc.home_alt_m},
        "mag_field_ned_t": [float(v) for v in sc.magnetic_field.ned_t],
        "wind_m_s": wind.speed_m_s,
        "wind_from_deg": wind.from_deg,
        "turbulence": level,
        "sim_seed": sc.seed,
        "duration_s": duration_s,
    }
    return sc, meta, t_out


def _flight(name: str, seed: int, artifacts: NavArtifacts, duration_s: float
            ) -> tuple[dict[str, F64Array], dict[str, F64Array], dict[str, Any], float]:  # fmt: skip
    """Fly one seed of a scenario: (sensor arrays, truth arrays, meta, outage start)."""
    from sim.flight.record import fly

    sc, meta, t_out = bench_scenario(name, seed, artifacts.deim_dir, duration_s)
    sensors, truth, _ = fly(sc, duration_s=duration_s)
    meta["alpha_max_deg"] = float(np.degrees(truth["alpha_rad"].max()))
    meta["bank_max_deg"] = float(np.degrees(np.max(np.abs([euler_from_quat(q)[0] for q in truth["q_nb"][::10]]))))
    return sensors, truth, meta, t_out


def _apply_fault(sensors: dict[str, F64Array], fault: str | None, t_out: float) -> dict[str, F64Array]:
    """Sensor-stream faults injected into the log (as a replay of a real log would)."""
    s = dict(sensors)
    if fault == "no-airspeed":
        s["pitot_t_s"], s["pitot_dp_pa"] = np.zeros(0), np.zeros(0)
    elif fault == "pitot-blocked":
        t, dp = s["pitot_t_s"], s["pitot_dp_pa"].copy()
        after = t >= t_out
        if after.any():
            i0 = int(np.argmax(after))
            p_static = np.interp(t, s["baro_t_s"], s["baro_pa"])
            dp[after] = dp[i0] + p_static[i0] - p_static[after]  # trapped total pressure, live static
        s["pitot_dp_pa"] = dp
    return s


# ----------------------------------------------------------------------------------- the filter side
_NAV_CACHE: dict[Path, NavModels] = {}


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
    from vdm_aero.nav.ports_frontend import PortFrontEnd

    home = meta["home"]
    frame = LocalFrame(home["lat_deg"], home["lon_deg"], home["alt_m"])
    log = SensorLog(path=Path("<bench>"), meta={"duration_s": meta["duration_s"]}, port_names=(), arrays=sensors)
    cfg = NavConfig(vehicle=nav.vehicle, origin_alt_m=home["alt_m"],
                    mag_field_ned_ut=np.asarray(meta["mag_field_ned_t"]) * 1e6)  # fmt: skip
    stream = NavStream.from_log(log, nav.vehicle, frame, filter_rate_hz=cfg.filter_rate_hz,
                                gnss_latency_s=cfg.gnss_latency_s)  # fmt: skip
    fe = PortFrontEnd(nav.pressure_model, dict(nav.models), range_pa=500.0, noise_pa=0.2) if len(
        sensors["ports_t_s"]) else None  # fmt: skip
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
        results["outages"][f"{length:g}"] = {
            m: _metrics(store[m], truth, t_out, length, branch.filters[m]) for m in modes
        }
    results["port_counts"] = dict(fe.counts) if fe is not None else None
    return results


def _metrics(rows: list[tuple[Any, ...]], truth: dict[str, F64Array], t0: float, length: float, f: NavFilter
             ) -> dict[str, Any]:  # fmt: skip
    t = np.array([r[0] for r in rows])
    p = np.array([r[1] for r in rows])
    v = np.array([r[2] for r in rows])
    q = np.array([r[3] for r in rows])
    w = np.array([r[4] for r in rows])
    cov = np.array([r[5] for r in rows])
    aided = np.array([not r[6] for r in rows])
    w_mean = np.array([r[7] for r in rows])  # the mean-wind state: what the filter holds in an outage
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
    i0 = max(int(np.searchsorted(t, t0)) - 1, 0)
    # NEES over GNSS-aided, converged epochs before the outage
    sel = aided & (t > t[0] + CONVERGED_AFTER_S) & (t < t0)
    nees = np.array([float(e @ np.linalg.solve(c, e)) for e, c in zip(err9[sel], cov[sel], strict=True)])
    in_band = float(np.mean((nees >= NEES_BAND_95[0]) & (nees <= NEES_BAND_95[1]))) if len(nees) else math.nan
    # distance flown over the ground during the outage
    tt = truth["t_s"]
    m = (tt >= t0) & (tt < t1)
    dist = float(np.sum(np.linalg.norm(np.diff(truth["pos_ned_m"][m][:, :2], axis=0), axis=1)))
    # drift budget (module docstring of docs/navigation.md): errors at the outage start × the outage length
    w_true = truth["wind_ned_m_s"]
    best = (tt >= t0 - WIND_AVERAGE_S) & (tt < t0)
    w_best = w_true[best].mean(axis=0) if best.any() else w_true[0]
    dt_truth = float(np.median(np.diff(tt)))
    floor = float(np.linalg.norm(np.sum(w_true[m][:, :2] - w_best[:2], axis=0) * dt_truth))
    yaw_err = float(np.angle(np.exp(1j * (euler_from_quat(q[i0])[2] - euler_from_quat(q_t[i0])[2]))))
    v_air_true = v_t[inside] - _truth_at(truth, "wind_ned_m_s", t[inside])
    airspeed = float(np.mean(np.linalg.norm(v_air_true[:, :2], axis=1))) if inside.any() else 0.0
    v_air_est = v[inside] - w[inside] if inside.any() else np.zeros((0, 3))
    air_err = float(np.linalg.norm(np.mean(np.linalg.norm(v_air_est[:, :2], axis=1) - np.linalg.norm(
        v_air_true[:, :2], axis=1)))) if inside.any() else 0.0  # fmt: skip
    budget = {
        "wind_m": float(np.linalg.norm(w_mean[i0, :2] - w_best[:2])) * length,
        "heading_m": abs(yaw_err) * airspeed * length,
        "airspeed_m": air_err * length,
        "turbulence_floor_m": floor,
    }
    # the floor the mode's own errors at the outage start imply: the terms are independent, so they add in
    # quadrature; a mode near 1× does as well as its start allows, far above it loses something in the outage
    budget["floor_m"] = float(math.sqrt(sum(v * v for v in budget.values())))
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
        "floor_ratio": float(e_h[i_end]) / max(budget["floor_m"], 1e-9),
        "sigma_h_end_m": float(sig_h[i_end]),
        "covered_2sigma": bool(e_h[i_end] <= 2.0 * sig_h[i_end]),
        "nees_in_band": in_band,
        "nees_median": float(np.median(nees)) if len(nees) else math.nan,
        "reacquisition_jump_m": jump,
        "budget": budget,
        "fallback": f.fallback,
        "rejected": dict(f.rejected),
        "error_curve": {"t_s": (t[inside] - t0).round(2).tolist(), "e_m": e_h[inside].round(2).tolist()},
    }


# ----------------------------------------------------------------------------------------- one unit
def run_unit(flight: str, seed: int, scen_faults: list[tuple[str, str | None]], spec: BenchSpec,
             artifacts: NavArtifacts) -> list[dict[str, Any]]:  # fmt: skip
    """Fly one seed of a flight (named by its first scenario) once and score every scenario sharing it."""
    duration = OUTAGE_START_S[1] + max(spec.outages_s) + AFTER_S + 5.0
    sensors, truth, meta, t_out = _flight(flight, seed, artifacts, duration)
    nav = _nav(artifacts)
    out = []
    for name, fault in scen_faults:
        s = _apply_fault(sensors, fault if fault != "shear" else None, t_out)
        res = run_filters(s, truth, meta, t_out, spec.outages_s, spec.modes, nav)
        out.append({"scenario": name, "seed": seed, "outage_start_s": t_out, "wind_m_s": meta["wind_m_s"],
                    "wind_from_deg": meta["wind_from_deg"], "turbulence": meta["turbulence"],
                    "alpha_max_deg": meta["alpha_max_deg"], "bank_max_deg": meta["bank_max_deg"], **res})  # fmt: skip
    return out


def _units(spec: BenchSpec) -> list[tuple[str, int, list[tuple[str, str | None]]]]:
    """Work units: scenarios flying the same preset with the same seed draws share one flight."""
    groups: dict[tuple[str, bool, tuple[str, ...]], list[tuple[str, str | None]]] = {}
    for name in spec.scenarios:
        groups.setdefault(_flight_key(name), []).append((name, SCENARIOS[name][3]))
    return [(members[0][0], seed, members) for members in groups.values()
            for seed in range(spec.first_seed, spec.first_seed + spec.seeds)]  # fmt: skip


def run_nav_drift(spec: BenchSpec, artifacts: NavArtifacts, *, jobs: int | None = None, dask_address: str | None = None,
                  progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Every unit in parallel (local processes, or a dask.distributed cluster); the aggregated report."""
    units = _units(spec)
    rows: list[dict[str, Any]] = []
    wall0 = time.perf_counter()
    if dask_address is not None:
        from dask.distributed import Client, as_completed

        client = Client(dask_address)
        futs = [client.submit(run_unit, u[0], u[1], u[2], spec, artifacts, pure=False) for u in units]
        for i, fut in enumerate(as_completed(futs)):
            rows.extend(fut.result())
            if progress:
                progress(i + 1, len(units))
        client.close()
    elif (jobs or os.cpu_count() or 1) > 1 and len(units) > 1:
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures import as_completed as done

        with ProcessPoolExecutor(max_workers=jobs or os.cpu_count()) as ex:
            futs2 = [ex.submit(run_unit, u[0], u[1], u[2], spec, artifacts) for u in units]
            for i, f2 in enumerate(done(futs2)):
                rows.extend(f2.result())
                if progress:
                    progress(i + 1, len(units))
    else:
        for i, u in enumerate(units):
            rows.extend(run_unit(u[0], u[1], u[2], spec, artifacts))
            if progress:
                progress(i + 1, len(units))
    rows.sort(key=lambda r: (spec.scenarios.index(r["scenario"]), r["seed"]))
    return {"spec": {"scenarios": list(spec.scenarios), "seeds": spec.seeds, "outages_s": list(spec.outages_s),
                     "modes": list(spec.modes), "first_seed": spec.first_seed},
            "wall_s": time.perf_counter() - wall0, "runs": rows, "summary": summarise(rows, spec)}  # fmt: skip


# ------------------------------------------------------------------------------------------ report
def summarise(rows: list[dict[str, Any]], spec: BenchSpec) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for sc in spec.scenarios:
        runs = [r for r in rows if r["scenario"] == sc]
        for length in spec.outages_s:
            key = f"{length:g}"
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
                    "budget_median_m": {b: float(np.median([x["budget"][b] for x in ms])) for b in ms[0]["budget"]},
                    "floor_ratio_median": float(np.median([x["floor_ratio"] for x in ms])),
                    "cpu_s_per_flight_s": float(np.median([r["filter_cpu_s_per_flight_s"][key] for r in runs])),
                }
            out[f"{sc}/{key}"] = per
    return out


_HEADER: Final = (
    "| mode | median [m] | p95 [m] | max [m] | % of distance | max during [m] | 2σ covers | NEES in band "
    "| reacq. jump [m] | budget wind / heading / airspeed / turbulence [m] | budget floor [m] | error / floor "
    "| filter CPU / flight s |"
)


SPEED_BAR_X_REAL_TIME: Final = 50.0


def bars(summary: dict[str, Any]) -> list[tuple[str, str, bool]]:
    """The issue's bars, each as (bar, what was measured, met), for whatever the run covered."""
    out: list[tuple[str, str, bool]] = []

    def med(key: str, mode: str) -> float | None:
        return summary.get(key, {}).get(mode, {}).get("median_m")

    nn, dr = "vdm-deim-nn", "airspeed-dr"
    s120 = summary.get("survey/120", {})
    if nn in s120:
        pct = s120[nn]["pct_distance_median"]
        out.append(("survey 120 s: vdm-deim-nn median ≤ 1 % of distance", f"{pct:.2f} %", pct <= 1.0))
        if dr in s120:
            r = s120[nn]["median_m"] / s120[dr]["median_m"]
            out.append(("survey 120 s: vdm-deim-nn ≤ 0.7× airspeed-dr", f"{r:.2f}×", r <= 0.7))
        if "ins" in s120:
            r = s120["ins"]["median_m"] / s120[nn]["median_m"]
            out.append(("survey 120 s: ins ≥ 20× worse than vdm-deim-nn", f"{r:.1f}×", r >= 20.0))
    for sc in ("survey", "survey-calm"):
        per = summary.get(f"{sc}/60", {})
        if nn in per:
            m, f = per[nn]["median_m"], per[nn]["floor_ratio_median"]
            out.append((f"{sc} 60 s: vdm-deim-nn median ≤ 10 m", f"{m:.1f} m", m <= 10.0))
            out.append((f"{sc} 60 s: vdm-deim-nn within 1.5× of its budget floor", f"{f:.2f}×", f <= 1.5))
    if (m := med("no-airspeed/120", nn)) is not None:
        out.append(("no airspeed 120 s: vdm-deim-nn median ≤ 50 m", f"{m:.1f} m", m <= 50.0))
    for length in ("60", "120"):
        blocked, healthy = summary.get(f"pitot-blocked/{length}", {}), summary.get(f"survey/{length}", {})
        if nn in blocked and nn in healthy:
            r = blocked[nn]["median_m"] / healthy[nn]["median_m"]
            out.append((f"pitot blocked {length} s: vdm-deim-nn ≤ 1.2× its healthy-pitot error", f"{r:.2f}×", r <= 1.2))
        if dr in blocked and dr in healthy:
            r = blocked[dr]["median_m"] / healthy[dr]["median_m"]
            out.append((f"pitot blocked {length} s: airspeed-dr degrades (> 1×)", f"{r:.2f}×", r > 1.0))
    order = ("vdm-deim-nn", "vdm-deim", "vdm-classic")
    if all(m in s120 for m in order):
        v = [s120[m]["median_m"] for m in order]
        out.append(("survey 120 s: vdm-deim-nn ≤ vdm-deim ≤ vdm-classic",
                    " ≤ ".join(f"{x:.1f}" for x in v) + " m", v[0] <= v[1] <= v[2]))  # fmt: skip
    modes = sorted({m for per in summary.values() for m in per}, key=list(MODES).index)
    for mode in modes:
        keyed = [(k, per[mode]) for k, per in summary.items() if mode in per]
        k_n, worst_n = min(keyed, key=lambda kv: kv[1]["nees_in_band"])
        k_c, worst_c = min(keyed, key=lambda kv: kv[1]["covered_2sigma"])
        out.append((f"{mode}: NEES in the 95 % band ≥ 90 % of aided epochs (worst scenario)",
                    f"{100 * worst_n['nees_in_band']:.0f} % ({k_n.split('/')[0]})",
                    worst_n["nees_in_band"] >= 0.9))  # fmt: skip
        out.append((f"{mode}: 2σ covers the error at outage end ≥ 90 % of seeds (worst)",
                    f"{100 * worst_c['covered_2sigma']:.0f} % ({k_c})", worst_c["covered_2sigma"] >= 0.9))  # fmt: skip
        cpu = max(st["cpu_s_per_flight_s"] for _, st in keyed)
        out.append((f"{mode}: ≥ {SPEED_BAR_X_REAL_TIME:g}× real time (benchmark run, per mode, front end shared)",
                    f"{1.0 / cpu:.0f}×", 1.0 / cpu >= SPEED_BAR_X_REAL_TIME))  # fmt: skip
    return out


def format_report(doc: dict[str, Any]) -> str:
    spec = doc["spec"]
    lines = [f"# Navigation drift: {len(doc['runs'])} runs, modes {', '.join(spec['modes'])}", ""]
    for key, per in doc["summary"].items():
        sc, length = key.split("/")
        lines += [f"## {sc}, {length} s outage ({spec['seeds']} seeds)", "", _HEADER, "|---" * 13 + "|"]
        for m, s in per.items():
            b = s["budget_median_m"]
            lines.append(
                f"| {m} | {s['median_m']:.1f} | {s['p95_m']:.1f} | {s['max_m']:.1f} | {s['pct_distance_median']:.2f} "
                f"| {s['max_during_median_m']:.1f} | {100 * s['covered_2sigma']:.0f} % "
                f"| {100 * s['nees_in_band']:.0f} % | {s['reacquisition_jump_median_m']:.1f} "
                f"| {b['wind_m']:.0f} / {b['heading_m']:.0f} / {b['airspeed_m']:.0f} / {b['turbulence_floor_m']:.0f} "
                f"| {b['floor_m']:.0f} | {s['floor_ratio_median']:.2f} | {1e3 * s['cpu_s_per_flight_s']:.1f} ms |"
            )
        lines.append("")
    checks = bars(doc["summary"])
    if checks:
        lines += ["## Bars (docs/navigation.md)", "", "| bar | measured | met |", "|---|---|---|"]
        lines += [f"| {b} | {m} | {'yes' if ok else '**no**'} |" for b, m, ok in checks]
        lines.append("")
    return "\n".join(lines)


def plot_report(doc: dict[str, Any], out: Path) -> list[Path]:
    """Error vs time per mode (median and 10–90 % band over seeds), final-error CDF, drift-budget bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    spec = doc["spec"]
    for key in doc["summary"]:
        sc, length = key.split("/")
        runs = [r for r in doc["runs"] if r["scenario"] == sc]
        fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
        for m in spec["modes"]:
            curves = [r["outages"][length][m]["error_curve"] for r in runs]
            if not curves:
                continue
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
        axes[0].set(
            xlabel="time in outage [s]", ylabel="horizontal error [m]", title=f"{sc}, {length} s: median, 10–90 %"
        )
        axes[1].set(xlabel="error at outage end [m]", ylabel="fraction of seeds", title="final-error CDF")
        axes[1].set_xscale("log")
        per = doc["summary"][key]
        names = ["wind_m", "heading_m", "airspeed_m", "turbulence_floor_m", "floor_m"]
        x = np.arange(len(per))
        for j, b in enumerate(names):
            axes[2].bar(x + 0.16 * j, [per[m]["budget_median_m"][b] for m in per], width=0.16, label=b)
        axes[2].scatter(x + 0.32, [per[m]["median_m"] for m in per], color="k", zorder=3, label="actual median")
        axes[2].set_xticks(x + 0.32, list(per), rotation=30, ha="right")
        axes[2].set_yscale("log")
        axes[2].set(ylabel="[m]", title="drift budget (medians)")
        for ax in axes:
            ax.legend(fontsize=7)
        fig.tight_layout()
        p = out / f"nav-drift-{sc}-{length}s.png"
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
    from vdm_aero.calibrate import TargetSettings, calibrate_model
    from vdm_aero.flightlog import load_sensor_log
    from vdm_aero.vehicle import load_vehicle
    from vdm_aero_cli.calibration_study import CALIBRATION_START_S, design_models

    art = NavArtifacts.under(out, calibration_minutes)
    deim_dir, nn_dir, data_dir = art.deim_dir, art.nn_dir, art.dataset_dir
    if (nn_dir / "model.yaml").is_file() and (deim_dir / "model.yaml").is_file():
        return art
    if progress:
        progress("design data set, DEIM and the design net")
    deim_dir, _, _ = design_models(out, 12, grid="quick", seed=seed, max_epochs=max_epochs)
    if progress:
        progress("calibration flight of the as-built aircraft")
    from sim.flight.record import record_flight, with_model_ports
    from sim.flight.scenario import load_scenario

    sc = with_model_ports(load_scenario("calibration-asbuilt"), deim_dir)
    log_dir = record_flight(
        sc, out / "flights" / "calibration", duration_s=CALIBRATION_START_S + 60.0 * calibration_minutes
    )
    if progress:
        progress("in-flight calibration of the correction net")
    calibrate_model(deim_dir, load_sensor_log(log_dir), load_vehicle("uav-2m"), nn_dir, grid="quick", seed=seed,
                    max_epochs=max_epochs, settings=TargetSettings(rate_hz=10.0))  # fmt: skip
    return NavArtifacts(data_dir, deim_dir, nn_dir)


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
