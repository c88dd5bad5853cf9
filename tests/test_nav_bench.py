"""The nav-drift benchmark's scoring and plumbing: metrics against an analytic drift, the blocked-pitot
fault's physics, and the dask path (seeds on a cluster) returning every unit."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from vdm_aero.atmosphere import G0_M_S2, isa
from vdm_aero_cli import nav_bench
from vdm_aero_cli.nav_bench import BenchSpec, NavArtifacts, _apply_fault, _metrics, run_nav_drift

T0_S, LENGTH_S = 100.0, 60.0
GROUND_SPEED_M_S = 20.0
WIND_ERROR_M_S = 0.5


def _straight_flight() -> tuple[list[tuple[Any, ...]], dict[str, np.ndarray]]:
    """North at 20 m/s in a steady 5 m/s east wind. The estimate holds a wind 0.5 m/s too far east from the
    outage start, so it drifts east at 0.5 m/s; GNSS resets it 1 s after the outage."""
    t = np.arange(0.0, 200.0, 0.02)
    wind = np.tile([0.0, 5.0, 0.0], (len(t), 1))
    truth = {
        "t_s": t,
        "pos_ned_m": np.column_stack([GROUND_SPEED_M_S * t, np.zeros_like(t), np.full_like(t, -100.0)]),
        "v_ned_m_s": np.tile([GROUND_SPEED_M_S, 0.0, 0.0], (len(t), 1)),
        "q_nb": np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1)),
        "wind_ned_m_s": wind,
    }
    rows = []
    for tk in np.arange(0.2, 190.0, 0.2):
        drifting = T0_S <= tk < T0_S + LENGTH_S + 1.0
        e_east = WIND_ERROR_M_S * (min(tk, T0_S + LENGTH_S) - T0_S) if drifting else 0.0
        held = T0_S - 5.0 <= tk < T0_S + LENGTH_S + 1.0  # the wrong wind, learnt 5 s before the outage
        w_est = np.array([0.0, 5.0 + (WIND_ERROR_M_S if held else 0.0), 0.0])
        v = np.array([GROUND_SPEED_M_S, WIND_ERROR_M_S if drifting else 0.0, 0.0])  # the air velocity is right
        rows.append((tk, np.array([GROUND_SPEED_M_S * tk, e_east, -100.0]), v, np.array([1.0, 0.0, 0.0, 0.0]),
                     w_est.copy(), np.eye(9), drifting, w_est.copy()))  # fmt: skip
    return rows, truth


def test_metrics_of_an_analytic_drift() -> None:
    rows, truth = _straight_flight()
    m = _metrics(rows, truth, T0_S, LENGTH_S, SimpleNamespace(fallback=False, rejected={}))  # type: ignore[arg-type]
    drift_end = WIND_ERROR_M_S * (LENGTH_S - 0.2)  # the last record inside the outage is 0.2 s before its end
    assert m["final_error_m"] == pytest.approx(drift_end, abs=1e-6)
    assert m["max_error_m"] == pytest.approx(drift_end, abs=1e-6)
    assert m["distance_m"] == pytest.approx(GROUND_SPEED_M_S * LENGTH_S, rel=1e-3)
    assert m["final_error_pct"] == pytest.approx(100.0 * drift_end / (GROUND_SPEED_M_S * LENGTH_S), rel=1e-3)
    b = m["budget"]
    assert b["wind_m"] == pytest.approx(WIND_ERROR_M_S * LENGTH_S, rel=1e-9)  # held-wind error × T
    assert b["heading_m"] == pytest.approx(0.0, abs=1e-9)
    assert b["turbulence_floor_m"] == pytest.approx(0.0, abs=1e-9)  # steady wind: nothing to integrate
    assert m["floor_ratio"] == pytest.approx(drift_end / b["floor_m"], rel=1e-9)
    assert 0.95 < m["floor_ratio"] <= 1.0
    assert not m["covered_2sigma"]  # σ_h = 1 m claimed against 30 m of error
    # the fix after the outage pulls the 30 m error back: the jump is the drift, not the flight's motion
    assert m["reacquisition_jump_m"] == pytest.approx(WIND_ERROR_M_S * LENGTH_S, abs=1e-6)


def test_blocked_pitot_reads_like_an_altimeter() -> None:
    # a blocked total port with a live static port: Δp = Δp₀ + p_s(t₀) − p_s(t), so a 30 m climb reads as
    # about 350 Pa more dynamic pressure (≈ +12 m/s at 19 m/s), the classic air-data failure
    t = np.arange(0.0, 40.0, 0.1)
    height = np.where(t < 10.0, 100.0, 100.0 + (t - 10.0))
    p_s = np.array([isa(h)[0] for h in height])
    sensors = {"pitot_t_s": t, "pitot_dp_pa": np.full_like(t, 220.0), "baro_t_s": t, "baro_pa": p_s}
    out = _apply_fault(sensors, "pitot-blocked", 10.0)["pitot_dp_pa"]
    np.testing.assert_array_equal(out[t < 10.0], 220.0)
    climb = p_s[np.argmax(t >= 10.0)] - p_s[-1]
    assert climb == pytest.approx(isa(115.0)[2] * G0_M_S2 * 29.9, rel=1e-3)  # hydrostatic: ρ g Δh
    assert out[-1] == pytest.approx(220.0 + climb, rel=1e-9)
    assert math.sqrt(2 * out[-1] / 1.2) - math.sqrt(2 * 220.0 / 1.2) > 10.0
    assert sensors["pitot_dp_pa"][-1] == 220.0  # the caller's log is not modified


def _fake_unit(flight: str, seed: int, members: list[tuple[str, str | None]], spec: BenchSpec,
               artifacts: NavArtifacts) -> list[dict[str, Any]]:  # fmt: skip
    """A stand-in for one flight (the real one takes a minute): rows whose numbers depend on the unit."""
    rows = []
    for name, _ in members:
        outages = {}
        for length in spec.outages_s:
            per = {}
            for i, mode in enumerate(spec.modes):
                e = float(seed + 10 * i + length)
                per[mode] = {"final_error_m": e, "max_error_m": e + 1.0, "final_error_pct": e / 100.0,
                             "covered_2sigma": seed % 2 == 0, "nees_in_band": 0.9, "reacquisition_jump_m": 1.0,
                             "budget": {"wind_m": 1.0, "floor_m": 2.0}, "floor_ratio": e / 2.0}  # fmt: skip
            outages[f"{length:g}"] = per
        rows.append({"scenario": name, "seed": seed, "flight": flight, "outages": outages,
                     "filter_cpu_s_per_flight_s": {f"{x:g}": 0.01 for x in spec.outages_s}})  # fmt: skip
    return rows


def test_seeds_on_a_dask_cluster_give_every_unit_once(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> None:
    distributed = pytest.importorskip("distributed", reason="the optional 'dask' extra is not installed")
    monkeypatch.setattr(nav_bench, "run_unit", _fake_unit)
    spec = BenchSpec(scenarios=("survey", "no-airspeed", "loiter"), seeds=4, outages_s=(60.0, 120.0),
                     modes=("ins", "vdm-deim-nn"))  # fmt: skip
    art = NavArtifacts(tmp_path, tmp_path, tmp_path)
    local = run_nav_drift(spec, art, jobs=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cl:
        seen: list[tuple[int, int]] = []
        remote = run_nav_drift(spec, art, dask_address=cl.scheduler_address, progress=lambda i, n: seen.append((i, n)))
    # survey and no-airspeed fly the same survey (one unit per seed), loiter its own: 8 units, 12 rows
    assert seen[-1] == (8, 8)
    assert sorted((r["scenario"], r["seed"]) for r in remote["runs"]) == sorted(
        (s, k) for s in spec.scenarios for k in range(4)
    )
    assert remote["summary"] == local["summary"]
    assert remote["summary"]["loiter/120"]["vdm-deim-nn"]["median_m"] == pytest.approx(np.median([130, 131, 132, 133]))


def _mode_summary(median_m: float, pct: float = 1.0) -> dict[str, Any]:
    return {"median_m": median_m, "pct_distance_median": pct, "floor_ratio_median": 1.0, "nees_in_band": 0.95,
            "covered_2sigma": 1.0, "cpu_s_per_flight_s": 0.004}  # fmt: skip


def test_bars_compare_the_right_runs() -> None:
    summary = {
        "survey/120": {
            "ins": _mode_summary(900.0),
            "airspeed-dr": _mode_summary(60.0),
            "vdm-classic": _mode_summary(50.0),
            "vdm-deim": _mode_summary(45.0),
            "vdm-deim-nn": _mode_summary(40.0, pct=0.8),
        },
        "pitot-blocked/120": {"airspeed-dr": _mode_summary(300.0), "vdm-deim-nn": _mode_summary(52.0)},
    }
    got = {b: (m, ok) for b, m, ok in nav_bench.bars(summary)}
    assert got["survey 120 s: vdm-deim-nn median ≤ 1 % of distance"] == ("0.80 %", True)
    assert got["survey 120 s: vdm-deim-nn ≤ 0.7× airspeed-dr"] == ("0.67×", True)
    assert got["survey 120 s: ins ≥ 20× worse than vdm-deim-nn"] == ("22.5×", True)
    assert got["pitot blocked 120 s: vdm-deim-nn ≤ 1.2× its healthy-pitot error"] == ("1.30×", False)
    assert got["pitot blocked 120 s: airspeed-dr degrades (> 1×)"] == ("5.00×", True)
    assert got["survey 120 s: vdm-deim-nn ≤ vdm-deim ≤ vdm-classic"][1]
    assert got["vdm-deim-nn: ≥ 50× real time (benchmark run, per mode, front end shared)"] == ("250×", True)
    assert not any(b.startswith("no airspeed") for b in got)  # not run: not judged
