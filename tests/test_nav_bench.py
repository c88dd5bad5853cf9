"""The nav-drift benchmark's scoring and plumbing: metrics against an analytic drift, the blocked-pitot
fault's physics, and the dask path (seeds on a cluster) returning every unit."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

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
    assert not m["covered_2sigma"]  # σ_h = 1 m claimed against 30 m of error
    # the fix after the outage pulls the 30 m error back: the jump is the drift, not the flight's motion
    assert m["reacquisition_jump_m"] == pytest.approx(WIND_ERROR_M_S * LENGTH_S, abs=1e-6)


def test_the_nees_splits_into_the_block_the_filter_is_too_sure_of() -> None:
    """Aided epochs whose attitude is 0.02 rad off in yaw with a claimed σ of 0.01 rad, velocity 0.5 m/s off
    with σ 0.5 m/s, position exact: the attitude's 3-dof NEES is (0.02 / 0.01)² = 4, the velocity's 1, the
    position's 0, and the 9-dof NEES their sum."""
    rows, truth = _straight_flight()
    yaw = 0.02
    cov = np.diag([4.0] * 3 + [0.25] * 3 + [1e-4] * 3)
    q = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    rows = [(r[0], r[1], r[2] + (0.0 if r[6] else np.array([0.5, 0.0, 0.0])), q, r[4], cov, *r[6:]) for r in rows]
    m = _metrics(rows, truth, T0_S, LENGTH_S, SimpleNamespace(fallback=False, rejected={}))  # type: ignore[arg-type]
    blocks = m["nees_block_median"]
    assert blocks["attitude"] == pytest.approx(4.0, rel=1e-6)
    assert blocks["velocity"] == pytest.approx(1.0, rel=1e-6)
    assert blocks["position"] == pytest.approx(0.0, abs=1e-9)
    assert m["nees_median"] == pytest.approx(5.0, rel=1e-6)


def _pitot_log() -> dict[str, np.ndarray]:
    t = np.arange(0.0, 100.0, 0.02)
    return {"pitot_t_s": t, "pitot_dp_pa": np.full_like(t, 220.0)}


def test_blocked_pitot_with_the_drain_open_vents_towards_zero() -> None:
    # FAA-H-8083-25B ch. 8: ram inlet blocked, drain open: the line vents and the reading falls towards zero
    sensors = _pitot_log()
    t = sensors["pitot_t_s"]
    out = _apply_fault(sensors, "pitot-blocked", 10.0, np.random.default_rng(3))["pitot_dp_pa"]
    np.testing.assert_array_equal(out[t < 10.0], 220.0)
    after = out[t >= 10.0]
    assert np.all(np.diff(after) < 0.0) and after[-1] >= 0.0
    tau = nav_bench.BLOCKED_DRAIN_TAU_S
    # an exponential with a time constant inside the sourced range: at onset + τ_max it is at most e⁻¹
    assert out[np.argmax(t >= 10.0 + tau[1])] <= 220.0 * math.exp(-1.0) + 1e-9
    assert out[np.argmax(t >= 10.0 + tau[0])] >= 220.0 * math.exp(-1.0) - 1e-9
    assert sensors["pitot_dp_pa"][-1] == 220.0  # the caller's log is not modified


def test_iced_pitot_under_reads_more_and_more_within_the_sourced_depth() -> None:
    sensors = _pitot_log()
    t = sensors["pitot_t_s"]
    out = _apply_fault(sensors, "pitot-icing", 10.0, np.random.default_rng(5))["pitot_dp_pa"]
    np.testing.assert_array_equal(out[t < 10.0], 220.0)
    assert np.all(np.diff(out[t >= 10.0]) <= 0.0)
    depth = 1.0 - out[-1] / 220.0  # fully grown after at most 60 s of the 90 s
    lo, hi = nav_bench.ICING_UNDER_READ
    assert lo <= depth <= hi


def test_water_in_the_pitot_line_is_intermittent_and_erratic() -> None:
    sensors = _pitot_log()
    t = sensors["pitot_t_s"]
    out = _apply_fault(sensors, "pitot-water", 10.0, np.random.default_rng(8))["pitot_dp_pa"]
    np.testing.assert_array_equal(out[t < 10.0], 220.0)
    bad = out[t >= 10.0] != 220.0
    assert 0.05 < bad.mean() < 0.95  # episodes, not a permanent failure
    assert np.ptp(out[t >= 10.0][bad]) > 100.0  # erratic: readings spread over 0–150 % of the true one
    assert np.all(out >= 0.0) and np.all(out <= 1.5 * 220.0)


def test_a_lossy_link_loses_bursts_of_every_stream_alike_from_the_outage_start() -> None:
    t_imu, t_gnss = np.arange(0.0, 100.0, 0.0025), np.arange(0.0, 100.0, 0.2)  # 400 Hz, 5 Hz
    sensors = {"imu_t_s": t_imu, "imu_gyro_b_rad_s": np.tile(t_imu[:, None], (1, 3)),
               "imu_temperature_c": t_imu.copy(), "gnss_t_s": t_gnss, "gnss_lat_deg": t_gnss.copy()}  # fmt: skip
    out = _apply_fault(sensors, "link-bursts", 40.0, np.random.default_rng(6))
    ti = out["imu_t_s"]
    np.testing.assert_array_equal(ti[ti < 40.0], t_imu[t_imu < 40.0])  # nothing lost before the start
    np.testing.assert_array_equal(out["imu_gyro_b_rad_s"][:, 0], ti)  # every array of a stream loses the same rows
    np.testing.assert_array_equal(out["imu_temperature_c"], ti)
    np.testing.assert_array_equal(out["gnss_lat_deg"], out["gnss_t_s"])
    kept = len(ti[ti >= 40.0]) / np.sum(t_imu >= 40.0)
    assert 0.2 < kept < 0.99  # bursts, not the whole stream
    holes = np.diff(ti[ti >= 40.0])
    assert np.sum(holes >= 0.1) >= 5  # holes a filter step cannot hide
    # and no more of them than the fastest channel allows (a hole and a delivered spell at their shortest means)
    assert np.sum(holes > 0.003) <= 1.5 * 60.0 / (nav_bench.LINK_HOLE_MEAN_S[0] + nav_bench.LINK_GOOD_MEAN_S[0])
    # the link's bursts, not each sensor's: a GNSS sample is lost only inside an IMU hole
    lost_gnss = np.setdiff1d(t_gnss, out["gnss_t_s"])
    assert len(lost_gnss) and all(np.sum((ti > g - 0.0025) & (ti < g + 0.0025)) == 0 for g in lost_gnss)


def test_a_lossy_link_loses_what_its_channels_renewal_theory_says() -> None:
    # a Gilbert-Elliott channel held for exponential spells of means b (lost) and g (delivered): in the long run it
    # loses b / (b + g) of the samples, in 1 / (b + g) holes a second, and a hole outlasts 0.1 s with probability
    # exp(-0.1 / b) (renewal-reward theorem; a hole shorter than the 2.5-ms sample interval loses nothing)
    t = np.arange(0.0, 3000.0, 0.0025)
    # the measured link: means of 0.3 s lost and 0.2 s delivered
    kept = nav_bench._link_bursts({"imu_t_s": t.copy()}, 0.0, np.random.default_rng(3), means_s=(0.3, 0.2))["imu_t_s"]
    # 6000 holes: the lost share's sampling σ is about 0.6 % of the flight, the rate's about 1.3 %
    assert abs((1.0 - len(kept) / len(t)) - 0.3 / 0.5) < 0.02
    holes = np.diff(kept)
    assert abs(np.sum(holes > 0.0026) / 3000.0 - 1.0 / 0.5) < 0.1
    assert abs(np.sum(holes >= 0.1) / np.sum(holes > 0.0026) - np.exp(-0.1 / 0.3)) < 0.03
    assert kept[-1] > 2999.0  # the channel runs to the end of the flight


def test_a_scenarios_place_in_the_table_keeps_its_draws() -> None:
    # a scenario's index seeds its flight's and its fault's draws: a new scenario inserted before an old one
    # would fly that one's seeds with other winds and faults, and its published figures would no longer repeat
    assert list(nav_bench.SCENARIOS)[:10] == [
        "survey", "wind-shear", "loiter", "no-airspeed", "pitot-blocked", "pitot-icing", "pitot-water",
        "manoeuvring", "survey-calm", "rtl-wind-gradient",
    ]  # fmt: skip
    assert nav_bench._draws_of("ports-blocked") == "survey"  # the fault flies the survey's flights
    assert nav_bench._draws_of("payload-release") == "survey"  # and so does the release, until it drops
    assert nav_bench._draws_of("link-bursts") == "survey"  # and the lossy link


def test_the_payload_is_released_at_the_outage_start_of_the_surveys_flight(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Any
) -> None:
    import sim.flight.record

    monkeypatch.setattr(sim.flight.record, "with_model_ports", lambda sc, _d: sc)
    survey, _, t_out = nav_bench.bench_scenario("survey", 2, tmp_path, 2.0, "harsh")
    drop, _, t_drop = nav_bench.bench_scenario("payload-release", 2, tmp_path, 2.0, "harsh")
    assert t_drop == t_out and survey.payload_release_s is None
    assert replace(drop, payload_release_s=None) == survey  # the same flight up to the release
    assert drop.payload_release_s == t_out
    assert nav_bench._flight_key("payload-release")[1] == "payload"  # a separate flight: the world changes


def test_blocked_ports_hold_their_trapped_air_follow_the_static_pressure_and_leak() -> None:
    # a line blocked at its orifice keeps the air it trapped, which leaks into the fuselage (≈ the static pressure
    # of the transducers' reference side): the reading decays from the blocking moment's Δp towards zero, as the
    # pitot's vents through its drain, and follows no change of the flow
    t = np.arange(0.0, 200.0, 0.01)
    level = {"t_s": t, "pos_ned_m": np.column_stack([np.zeros_like(t), np.zeros_like(t), np.full_like(t, -100.0)])}
    lo, hi = nav_bench.PORTS_BLOCKED_LEAK_TAU_S
    dp = np.full((len(t), 12), 200.0)
    out = _apply_fault({"ports_t_s": t, "ports_dp_pa": dp}, "ports-blocked", 10.0, np.random.default_rng(4), level,
                       0.0)["ports_dp_pa"]  # fmt: skip
    np.testing.assert_array_equal(out[t < 10.0], 200.0)
    blocked = np.flatnonzero(np.any(out[t >= 10.0] != 200.0, axis=0))
    assert nav_bench.PORTS_BLOCKED_N[0] <= len(blocked) <= nav_bench.PORTS_BLOCKED_N[1]
    np.testing.assert_array_equal(np.delete(out, blocked, axis=1), 200.0)  # the others untouched
    assert np.all(dp == 200.0)  # the caller's log is not modified

    def at(y: np.ndarray, s: float) -> float:  # a 1 s mean: the transducer's noise out
        return float(np.mean(y[(t >= s - 0.5) & (t < s + 0.5)]))

    for k in blocked:  # an exponential with a time constant inside the stated range
        assert at(out[:, k], 10.0 + hi) <= 200.0 * math.exp(-1.0) * math.exp(0.5 / hi) + 0.2
        assert at(out[:, k], 10.0 + lo) >= 200.0 * math.exp(-1.0) * math.exp(-0.5 / lo) - 0.2
    # blocked at a zero reading, then a 2 m/s climb from 50 s: the static pressure falls by ~23.5 Pa/s (ISA near
    # sea level) and the line's trapped air cannot follow it, so the reading rises towards τ·23.5 Pa, while the
    # flow's ±3 Pa swing, seen by the healthy ports, no longer shows in it
    swing = 3.0 * np.sin(2.0 * np.pi * (t - 10.0) / 7.0)
    down = np.where(t < 50.0, -100.0, -100.0 - 2.0 * (t - 50.0))
    climb = {"t_s": t, "pos_ned_m": np.column_stack([np.zeros_like(t), np.zeros_like(t), down])}
    out = _apply_fault({"ports_t_s": t, "ports_dp_pa": np.tile(swing[:, None], (1, 12))}, "ports-blocked", 10.0,
                       np.random.default_rng(4), climb, 0.0)["ports_dp_pa"]  # fmt: skip
    for k in blocked:  # the same draws
        y = out[:, k]
        assert np.std(y[(t >= 12.0) & (t < 49.0)]) < 0.3  # level: held at zero, noise only
        rise = at(y, 99.0)
        assert 0.9 * 23.5 * lo * (1.0 - math.exp(-49.0 / lo)) <= rise <= 1.1 * 23.5 * hi * (1.0 - math.exp(-49.0 / hi))


def _fake_unit(world: str, flight: str, seed: int, members: list[tuple[str, str | None]], spec: BenchSpec,
               artifacts: NavArtifacts, outages_s: tuple[float, ...]) -> list[dict[str, Any]]:  # fmt: skip
    """A stand-in for one flight (the real one takes a minute): rows whose numbers depend on the unit."""
    rows = []
    for name, _ in members:
        outages = {}
        for length in outages_s:
            per = {}
            for i, mode in enumerate(spec.modes):
                e = float(seed + 10 * i + length)
                per[mode] = {"final_error_m": e, "max_error_m": e + 1.0, "final_error_pct": e / 100.0,
                             "covered_2sigma": seed % 2 == 0, "nees_in_band": 0.9,
                             "reacquisition_jump_m": 1.0,
                             "error_curve": {"t_s": [0.0, length], "e_m": [0.0, e]}}  # fmt: skip
            outages[f"{length:g}"] = per
        rows.append({"world": world, "scenario": name, "seed": seed, "flight": flight, "outages": outages,
                     "imu_part": "icm-42688-p",
                     "filter_cpu_s_per_flight_s": {f"{x:g}": 0.01 for x in outages_s}})  # fmt: skip
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
    assert remote["summary"]["kind/loiter/120"]["vdm-deim-nn"]["median_m"] == pytest.approx(
        np.median([130, 131, 132, 133])
    )


def test_the_report_puts_every_mode_against_the_product_on_the_same_flights(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Any
) -> None:
    monkeypatch.setattr(nav_bench, "run_unit", _fake_unit)
    spec = BenchSpec(scenarios=("survey",), seeds=5, outages_s=(60.0,), modes=("ins", "airspeed-dr", "vdm"))
    doc = run_nav_drift(spec, NavArtifacts(tmp_path, tmp_path, tmp_path), jobs=1)
    per = doc["summary"]["kind/survey/60"]
    # _fake_unit: seed + 10·(the mode's place) + 60 m, seeds 0–4: medians 62, 72 and 82 m
    assert per["ins"]["ratio_to_product"] == pytest.approx(62.0 / 82.0)
    lo, hi = per["ins"]["ratio_to_product_ci95"]
    assert lo < 62.0 / 82.0 < hi < 1.0  # ins is better on every flight: the seeds resolve it
    assert "ratio_to_product" not in per["vdm"]
    lines = nav_bench.format_report(doc).splitlines()
    assert lines[lines.index(nav_bench._HEADER) + 2].endswith(f"| 0.76 ({lo:.2f}–{hi:.2f}) |")
    assert next(x for x in lines if x.startswith("| vdm |")).endswith("| — |")


def test_the_harsh_run_flies_both_worlds_and_each_effect_alone(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> None:
    monkeypatch.setattr(nav_bench, "run_unit", _fake_unit)
    monkeypatch.setattr(nav_bench, "calibrate_airframe", lambda *a: tmp_path)
    spec = BenchSpec(scenarios=("survey", "pitot-icing"), seeds=2, outages_s=(120.0, 300.0), modes=("ins",),
                     worlds=("harsh", "kind"), cost_seeds=2, cost_effects=("mag-motor", "fleet"))  # fmt: skip
    doc = run_nav_drift(spec, NavArtifacts(tmp_path, tmp_path, tmp_path), jobs=1)
    keys = set(doc["summary"])
    assert {"harsh/survey/300", "kind/pitot-icing/300", "only:mag-motor/survey/120", "only:fleet/survey/120"} <= keys
    assert "only:fleet/survey/300" not in keys  # the cost table is at its one outage length
    costs = dict(nav_bench.cost_table(doc["runs"], spec.modes))
    assert next(iter(costs)) == "kind" and list(costs)[-1] == "harsh"
    report = nav_bench.format_report(doc)
    assert "## What each effect costs" in report and "| only:fleet |" in report
    assert report.startswith(f"# Navigation drift: {len(doc['runs'])} runs, modes ins, seeds 0–1\n")
    doc["spec"]["first_seed"] = 20  # a run on unseen seeds says so
    assert "seeds 20–21" in nav_bench.format_report(doc).splitlines()[0]
    # the fleet's airframes are calibrated in their own world; the preset airframe needs none
    assert nav_bench._calibrations(nav_bench._units(spec)) == [
        ("harsh", 0),
        ("harsh", 1),
        ("only:fleet", 0),
        ("only:fleet", 1),
    ]


def _mode_summary(median_m: float, nees: float = 0.95) -> dict[str, Any]:
    return {"median_m": median_m, "nees_in_band": nees, "covered_2sigma": 1.0, "cpu_s_per_flight_s": 0.004}


def test_bars_compare_things_that_can_differ() -> None:
    summary = {
        "harsh/survey/120": {
            "ins": _mode_summary(900.0),
            "airspeed-dr": _mode_summary(60.0),
            "vdm-deim-nn": _mode_summary(40.0),
        },
        "harsh/pitot-blocked/120": {"airspeed-dr": _mode_summary(300.0), "vdm-deim-nn": _mode_summary(160.0)},
        "harsh/rtl-wind-gradient/300": {"ins": _mode_summary(500.0), "vdm-deim-nn": _mode_summary(400.0, 0.5)},
        "only:mag-motor/survey/120": {"ins": _mode_summary(5000.0)},
    }
    theory = [
        {
            "world": "harsh",
            "imu_part": "bmi088",
            "outage_s": 120.0,
            "ratio": 2.5,
            "free_median_m": 900.0,
            "theory_median_m": 360.0,
            "calibrated_start_median_m": 120.0,
            "ratio_calibrated": 7.5,
            "seeds": 3,
        },
        {
            "world": "kind",
            "imu_part": "icm-42688-p",
            "outage_s": 120.0,
            "ratio": 0.2,
            "free_median_m": 70.0,
            "theory_median_m": 350.0,
            "calibrated_start_median_m": 100.0,
            "ratio_calibrated": 0.7,
            "seeds": 3,
        },
    ]
    got = {b: (m, ok) for b, m, ok, why in nav_bench.bars(summary, theory)}
    assert got["harsh survey 120 s: vdm-deim-nn ≤ airspeed-dr (the ports beat the autopilot's pitot DR)"] == (
        "40.0 / 60.0 m = 0.67×", True)  # fmt: skip
    assert got["harsh pitot-blocked 120 s: vdm-deim-nn ≤ 0.5× airspeed-dr (the ports shine when the pitot fails)"] == (
        "0.53×", False)  # fmt: skip
    assert got["harsh pitot-blocked 120 s: the fault hurts airspeed-dr (> 1.2× its healthy survey)"] == ("5.00×", True)
    assert got["harsh rtl-wind-gradient 300 s: vdm-deim-nn ≤ ins (a wind change must not make air data worse)"] == (
        "0.80×", True)  # fmt: skip
    bar = "free INS within 2× of the data sheet's theory along the flown trajectory (calibrated start ÷ 2 … budget × 2)"
    # above twice the budget: a world worse than its data sheet
    assert got[f"harsh bmi088 120 s: {bar}"] == ("900 m in 120 … 360 m: 7.50× / 2.50× (3 seeds)", False)
    # below the budget but above half the calibrated start: inside the bracket
    assert got[f"kind icm-42688-p 120 s: {bar}"] == ("70 m in 100 … 350 m: 0.70× / 0.20× (3 seeds)", True)
    assert got["vdm-deim-nn: NEES in the 95 % band ≥ 90 % of aided epochs (worst scenario)"] == (
        "50 % (harsh/rtl-wind-gradient)", False)  # fmt: skip
    assert got["vdm-deim-nn: ≥ 50× real time (benchmark run, per mode, front end shared)"] == ("250×", True)
    # the cost table's single-effect worlds are not judged, and no bar compares a mode with itself
    assert not any(b.startswith("only:") for b in got)
    assert all(why for _, _, _, why in nav_bench.bars(summary, theory))


def test_free_inertial_theory_terms_grow_as_their_powers_of_time() -> None:
    a, b = nav_bench.free_inertial_sigma_m("icm-42688-p", 60.0), nav_bench.free_inertial_sigma_m("icm-42688-p", 120.0)
    assert b["accel_bias_m"] / a["accel_bias_m"] == pytest.approx(4.0)
    assert b["gyro_bias_m"] / a["gyro_bias_m"] == pytest.approx(8.0)
    assert b["vrw_m"] / a["vrw_m"] == pytest.approx(2.0**1.5)
    assert b["arw_m"] / a["arw_m"] == pytest.approx(2.0**2.5)
    # g·ω·t³/6 with the grade's 0.01 °/s instability at 60 s
    assert a["gyro_bias_m"] == pytest.approx(9.80665 * math.radians(0.01) * 60.0**3 / 6.0)
    # the BMI088's larger figures give the larger drift
    assert nav_bench.free_inertial_sigma_m("bmi088", 60.0)["rss_m"] > a["rss_m"]


def _legs(t: np.ndarray, leg_s: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Level flight at 19 m/s heading 0.3 rad, reversing every ``leg_s`` (None: one straight leg)."""
    from vdm_aero.rotation import quat_from_euler

    yaw = np.full_like(t, 0.3) if leg_s is None else np.where((t // leg_s) % 2 == 0, 0.3, 0.3 + math.pi)
    q = np.array([quat_from_euler(0.0, 0.0, y) for y in yaw])
    return q, np.column_stack([19.0 * np.cos(yaw), 19.0 * np.sin(yaw), np.zeros_like(t)])


@pytest.mark.parametrize("part", ["icm-42688-p", "bmi088"])
@pytest.mark.parametrize("t_end", [60.0, 300.0])
def test_trajectory_theory_is_the_closed_form_in_straight_level_flight(part: str, t_end: float) -> None:
    # the covariance analysis along a trajectory against the closed-form integrals (an independent derivation):
    # per axis, the held-bias budget is the root sum of ½bt², ½g(b/g)t², gωt³/6, VRW and ARW; the calibrated
    # start is the Gauss–Markov wander integral
    t = np.arange(0.0, t_end + 1e-9, 0.5)
    q, v = _legs(t, None)
    closed = nav_bench.free_inertial_sigma_m(part, t_end)
    budget = nav_bench.free_inertial_along(part, t, q, v)
    cal = nav_bench.free_inertial_along(part, t, q, v, calibrated_start=True)
    assert np.sqrt(np.diag(budget)) == pytest.approx([closed["rss_m"]] * 2, rel=0.01)
    assert np.sqrt(np.diag(cal)) == pytest.approx([closed["calibrated_start_rss_m"]] * 2, rel=0.01)


def test_heading_reversals_undo_part_of_a_body_frame_bias() -> None:
    # a survey's 63 s legs: the gyro bias's tilt is undone on the way back, so the budget grows slower than t³;
    # on the first leg nothing has turned yet
    t = np.arange(0.0, 300.0 + 1e-9, 0.5)
    straight = nav_bench.free_inertial_along("icm-42688-p", t, *_legs(t, None))
    survey = nav_bench.free_inertial_along("icm-42688-p", t, *_legs(t, 63.0))
    assert np.trace(survey) < 0.25 * np.trace(straight)
    first = t <= 60.0
    on_leg = nav_bench.free_inertial_along("icm-42688-p", t[first], *_legs(t[first], 63.0))
    leg_rss = nav_bench.free_inertial_sigma_m("icm-42688-p", 60.0)["rss_m"]
    assert np.trace(on_leg) == pytest.approx(2.0 * leg_rss**2, rel=0.02)


def test_median_horizontal_error_is_the_hoyt_median() -> None:
    # isotropic: Rayleigh's median σ·√(2 ln 2); one axis only: the half-normal's median 0.6745σ
    assert nav_bench.median_horizontal_error_m(np.eye(2) * 4.0) == pytest.approx(
        2.0 * math.sqrt(2 * math.log(2)), rel=0.01
    )
    assert nav_bench.median_horizontal_error_m(np.diag([9.0, 0.0])) == pytest.approx(3.0 * 0.67449, rel=0.01)


def test_a_consistent_filters_two_sigma_coverage_is_the_2d_one() -> None:
    # analytic: a round 2-D Gaussian is inside 2σ with 1 − e⁻², a flat one (1-D) with erf(√2)
    assert nav_bench.two_sigma_coverage_if_consistent(np.eye(2) * 25.0) == pytest.approx(1.0 - math.exp(-2.0), abs=1e-9)
    assert nav_bench.two_sigma_coverage_if_consistent(np.diag([25.0, 0.0])) == pytest.approx(math.erf(math.sqrt(2.0)),
                                                                                             abs=1e-3)  # fmt: skip
    # and the same by sampling an oblique covariance, judged as _metrics judges (major axis)
    rng = np.random.default_rng(3)
    cov = np.array([[40.0, 12.0], [12.0, 10.0]])
    e = rng.multivariate_normal(np.zeros(2), cov, size=200_000)
    share = np.mean(np.linalg.norm(e, axis=1) <= 2.0 * math.sqrt(np.linalg.eigvalsh(cov)[-1]))
    assert nav_bench.two_sigma_coverage_if_consistent(cov) == pytest.approx(share, abs=3e-3)


def test_how_often_a_share_is_reached_is_the_binomial_tail() -> None:
    from scipy.stats import binom  # the third-party reference for equal probabilities

    assert nav_bench.share_reached_probability([0.865] * 20, 0.9) == pytest.approx(binom.sf(17, 20, 0.865), rel=1e-9)
    assert nav_bench.share_reached_probability([1.0, 0.0], 0.5) == pytest.approx(1.0)
    assert nav_bench.share_reached_probability([1.0, 0.0], 1.0) == pytest.approx(0.0)


def test_the_filters_know_only_what_a_user_knows(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> None:
    # no inverse crime: the bench hands the filters the WMM value at the site and the IMU part's name, never
    # the world's true field or its installation draws
    import sim.flight.asbuilt
    import sim.flight.record
    from sim.flight.world import FlightWorld

    monkeypatch.setattr(sim.flight.record, "with_model_ports", lambda sc, _d: sc)
    sc, meta, _ = nav_bench.bench_scenario("survey", 3, tmp_path, 2.0, "harsh")
    assert set(meta) == {"home", "mag_field_ned_t", "wind_m_s", "wind_from_deg", "turbulence", "sim_seed",
                         "duration_s", "world", "airframe", "imu_part"}  # fmt: skip
    assert meta["mag_field_ned_t"] == list(sc.magnetic_field.ned_t)  # the scenario's field is the WMM's
    assert meta["airframe"] == 3 and meta["imu_part"] == "bmi088"  # airframe 3 of the fleet carries a BMI088
    world = FlightWorld(sc)
    assert not np.allclose(world.mag.earth_field_ned_t, sc.magnetic_field.ned_t)  # the site's true field differs
    assert world.vehicle.as_built != sim.flight.asbuilt.AS_BUILT_PRESETS["uav-2m-asbuilt"]  # a fleet airframe
    assert nav_bench.world_effects("harsh-without:fleet+mag-motor") == world.scenario.world_effects - {
        "fleet",
        "mag-motor",
    }


def test_bench_json_prints_json_only(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                     tmp_path: Any) -> None:  # fmt: skip
    from vdm_aero_cli.main import main

    def noisy_build(out: Any, **_: Any) -> NavArtifacts:
        print(f"wrote {out}/data/uav-envelope: 2510 snapshots")  # what the data-set step prints
        return NavArtifacts(tmp_path, tmp_path, tmp_path)

    monkeypatch.setattr(nav_bench, "build_artifacts", noisy_build)
    monkeypatch.setattr(nav_bench, "run_unit", _fake_unit)
    monkeypatch.setattr(nav_bench, "calibrate_airframe", lambda *a: tmp_path)
    code = main(["bench", "nav-drift", "--json", "--seeds", "1", "--outage-s", "60", "--cost-seeds", "0",
                 "--modes", "ins", "--jobs", "1", "--out", str(tmp_path / "out")])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0
    doc = json.loads(out.out)  # nothing but the JSON on stdout
    assert set(doc["summary"]) == {"harsh/survey/60", "kind/survey/60"}
    assert "wrote" in out.err


def test_fdi_summary_counts_detections_and_false_alarms() -> None:
    runs = [
        {"fdi_events": [[4.4, "pitot", "excluded"]], "recorded_s": [-200.0, 320.0]},
        {"fdi_events": [[-50.0, "force", "excluded"], [45.1, "pitot", "excluded"]], "recorded_s": [-150.0, 320.0]},
        {"fdi_events": [], "recorded_s": [-160.0, 320.0]},
    ]
    got = nav_bench.fdi_summary(runs, faulty=True)
    assert got["fdi_detect_s"] == [4.4, 45.1, None]
    assert got["fdi_detect_median_s"] == pytest.approx((4.4 + 45.1) / 2)
    assert got["fdi_flagged_10s"] == pytest.approx(1 / 3)
    # healthy flight is what came before the fault: one false alarm in 510 s
    assert got["fdi_false_alarms"] == 1 and got["fdi_healthy_h"] == pytest.approx(510.0 / 3600.0)
    healthy = nav_bench.fdi_summary(runs[:1], faulty=False)
    assert healthy["fdi_false_alarms"] == 1 and healthy["fdi_healthy_h"] == pytest.approx(520.0 / 3600.0)
    # from each fault's first symptom: the third showed none, so it is not counted; the second was flagged 5.1 s
    # after its symptom (45.1 s after its start)
    seen = nav_bench.fdi_summary(runs, faulty=True, symptoms_s=[2.0, 40.0, None])
    assert seen["fdi_flagged_10s_after_symptom"] == 1.0
    assert seen["fdi_after_symptom_median_s"] == pytest.approx((2.4 + 5.1) / 2)
    assert seen["fdi_symptom_by_10s"] == pytest.approx(1 / 3)
    assert seen["fdi_flagged_10s"] == pytest.approx(1 / 3)  # the bar's own figure is unchanged


def test_wind_alarms_where_the_wind_does_not_change_are_counted_against_the_outage_hours() -> None:
    ms = [
        {"fdi_events": [[-30.0, "wind", "changed"], [12.0, "wind", "changed"], [70.0, "wind", "changed"]],
         "final_error_m": 300.0},
        {"fdi_events": [[5.0, "pitot", "excluded"]], "final_error_m": 40.0},
        {"fdi_events": None, "final_error_m": 60.0},
    ]  # fmt: skip
    got = nav_bench.wind_alarm_summary(ms, 60.0)  # only the one at 12 s is in the outage
    assert got["wind_alarms"] == 1 and got["wind_alarm_flights"] == 1
    assert got["wind_alarm_outage_h"] == pytest.approx(3 * 60.0 / 3600.0)
    assert got["median_with_wind_alarm_m"] == 300.0 and got["median_without_wind_alarm_m"] == 50.0
    summary = {"harsh/survey/60": {"vdm": {"median_m": 60.0, **got}}}
    line = next(b for b in nav_bench.product_bars(summary) if "wind-change alarms" in b[0])
    assert line[1].startswith("1 in 0.05 h") and "survey/60 300 against 50 m (1)" in line[1] and line[2] is False


def test_a_faults_first_symptom_is_its_first_metre_per_second_off_the_healthy_pitot() -> None:
    sensors = _pitot_log()
    t = sensors["pitot_t_s"]
    truth = {"t_s": t, "airspeed_m_s": np.full_like(t, 19.0)}
    iced = dict(sensors, pitot_dp_pa=sensors["pitot_dp_pa"] * (1.0 - 0.02 * np.clip(t - 10.0, 0.0, None)))
    # 19 · (1 − √(1 − 0.02 τ)) = 1 m/s at τ = (1 − (18/19)²) / 0.02 = 5.12 s
    assert nav_bench.fault_symptom_s(sensors, iced, truth, 10.0) == pytest.approx(5.12, abs=0.11)
    assert nav_bench.fault_symptom_s(sensors, sensors, truth, 10.0) is None


def test_product_bars_judge_vdm_against_the_autopilots_baselines() -> None:
    def st(m: float, **kw: Any) -> dict[str, Any]:
        return {"median_m": m, **kw}

    summary = {
        "harsh/survey/300": {"ins": st(1700.0), "airspeed-dr": st(150.0),
                             "vdm": st(125.0, fdi_false_alarms=0, fdi_healthy_h=0.5)},
        "harsh/pitot-icing/300": {"ins": st(1700.0), "airspeed-dr": st(780.0),
                                  "vdm": st(190.0, fdi_false_alarms=1, fdi_healthy_h=0.2, fdi_flagged_10s=0.5,
                                            fdi_detect_median_s=26.0)},
        "harsh/wind-shear/300": {"ins": st(2000.0), "airspeed-dr": st(2200.0), "vdm": st(2150.0)},
    }  # fmt: skip
    got = {b: (m, ok) for b, m, ok, _ in nav_bench.product_bars(summary)}
    assert got["harsh survey 300 s: vdm ≤ 1.05× the best of ins and airspeed-dr"] == ("125 / 150 m = 0.83×", True)
    assert got["harsh survey 300 s: ins ≥ 10× vdm"] == ("13.6×", True)
    assert got["harsh pitot-icing 300 s: vdm ≤ 0.5× airspeed-dr"] == ("0.24×", True)
    assert got["harsh pitot-icing 300 s: vdm ≤ 1.3× its healthy survey"] == ("1.52×", False)
    assert got["harsh pitot-icing 300 s: vdm flags the pitot within 10 s of the fault (≥ 90 % of seeds)"] == (
        "50 % (median 26.0 s)", False)  # fmt: skip
    assert got["harsh wind-shear 300 s: vdm ≤ 0.5× airspeed-dr and ≤ 1.0× ins"] == ("0.98× / 1.07×", False)
    assert got["vdm: FDI false alarms < 1 per 10 h of healthy flight"] == (
        "1 in 0.70 h (95 % interval 0.36–79.59 per 10 h)", False)  # fmt: skip
    # the held-wind dead reckoner beside the order-of-magnitude bar: what holding the wind could reach at best
    held = {b: m for b, m, _, _ in nav_bench.product_bars(summary, {"harsh/survey/300": {"median_m": 272.0}})}
    assert held["harsh survey 300 s: ins ≥ 10× vdm"].endswith("true wind of the minute before: 6.2×")


def test_the_ratio_interval_covers_the_true_ratio_and_uses_the_shared_weather() -> None:
    # 20 flights per trial, every mode in the same weather (a shared heavy-tailed factor, as the seeds' turbulence
    # and wind are), each mode's own error on top: the population medians' ratio is exactly r. A 95 % interval
    # should cover r in at least about 95 % of trials (the percentile bootstrap of a median of 20 is
    # conservative, ~98 % here), with finite ends. Drawn in pairs, the shared weather cancels: the interval is
    # about half as wide as scipy's unpaired bootstrap of the same statistic on the same flights
    from scipy.stats import bootstrap

    def ratio(a: np.ndarray, b: np.ndarray, c: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.asarray(np.median(a, axis=axis) / np.minimum(np.median(b, axis=axis), np.median(c, axis=axis)))

    rng = np.random.default_rng(7)
    r, trials, covered, width, unpaired = 1.3, 200, 0, [], []
    for k in range(trials):
        weather = rng.lognormal(0.0, 1.0, 20)
        vdm = r * weather * rng.lognormal(0.0, 0.3, 20)
        dr, ins = weather * rng.lognormal(0.0, 0.3, 20), 5.0 * weather * rng.lognormal(0.0, 0.3, 20)
        ci = nav_bench.median_ratio_interval(vdm, ins, dr)
        assert ci is not None and 0.0 < ci[0] <= ci[1] < math.inf
        covered += ci[0] <= r <= ci[1]
        width.append(math.log(ci[1] / ci[0]))
        if k < 40:
            ref = bootstrap((vdm, ins, dr), ratio, vectorized=True, n_resamples=2000, method="percentile",
                            rng=np.random.default_rng(k)).confidence_interval  # fmt: skip
            unpaired.append(math.log(ref.high / ref.low))
    assert covered / trials >= 0.93
    assert np.median(width[:40]) < 0.6 * np.median(unpaired)
    # a product error exactly proportional to the baseline's has no spread to resample
    dr = rng.lognormal(4.0, 1.0, 20)
    assert nav_bench.median_ratio_interval(1.2 * dr, dr) == pytest.approx((1.2, 1.2))
    assert nav_bench.median_ratio_interval([1.0, 2.0], [1.0, 1.0]) is None  # two seeds: no interval


def test_an_alarm_rate_interval_is_garwoods() -> None:
    # the exact Poisson 95 % limits tabulated by Garwood (1936) and in every table since (e.g. Ulm 1990): 0 → (0,
    # 3.689), 1 → (0.0253, 5.572), 5 → (1.624, 11.668) events, here over 2 h
    for k, lo, hi in ((0, 0.0, 3.689), (1, 0.0253, 5.572), (5, 1.624, 11.668)):
        assert nav_bench.rate_interval(k, 2.0) == pytest.approx((lo / 2.0, hi / 2.0), rel=2e-3, abs=1e-9)
    # so no alarm in 26.5 h (the healthy hours measured) does not show a rate under 1 per 10 h; 4 in 10.7 h shows
    # one over it
    assert "do not resolve it" in nav_bench.resolved([10.0 * r for r in nav_bench.rate_interval(0, 26.5)], 1.0)
    assert "lies above 1" in nav_bench.resolved([10.0 * r for r in nav_bench.rate_interval(4, 10.7)], 1.0)
    # and what shows it: the table's 3.689 events over 0.1 per hour; after that many hours the interval clears it
    need = nav_bench.hours_to_show(0, 0.1)
    assert need == pytest.approx(36.89, rel=1e-3)
    assert "lies below 1" in nav_bench.resolved([10.0 * r for r in nav_bench.rate_interval(0, 1.01 * need)], 1.0)


def test_the_bars_say_whether_the_seeds_resolve_them() -> None:
    dr = [60.0, 80.0, 100.0, 150.0, 500.0, 70.0, 40.0]
    err = {"vdm": [50.0, 90.0, 120.0, 200.0, 400.0, 60.0, 75.0], "ins": [10.0 * d for d in dr], "airspeed-dr": dr}
    u = nav_bench.product_ratio_uncertainty(err)
    assert u["better_than_best_seeds"] == 3  # against airspeed-dr, the baseline with the lower median
    lo, hi = u["ratio_ci95_best"]
    assert lo < 90.0 / 80.0 < hi and u["ratio_ci95_airspeed-dr"] == [lo, hi]
    assert u["ratio_ci95_ins"][1] < 0.5  # a tenth of ins's error on every flight
    per = {"ins": {"median_m": 800.0}, "airspeed-dr": {"median_m": 80.0},
           "vdm": {"median_m": 90.0, "seeds": 7, **u}}  # fmt: skip
    bar = next(b for b in nav_bench.product_bars({"harsh/survey/300": per}) if "1.05×" in b[0])
    assert bar[1].startswith(f"90 / 80 m = 1.12× (95 % interval {lo:.2f}–{hi:.2f}×, better on 3 of 7 flights)")
    assert not bar[2] and "do not resolve it" in bar[3]
    shear = next(b for b in nav_bench.product_bars({"harsh/wind-shear/300": per}) if "0.5×" in b[0])
    assert "against ins: the seeds resolve it: the 95 % interval lies below 1×" in shear[3]


def test_the_held_wind_costs_what_the_winds_change_integrates_to() -> None:
    # before the outage 5 m/s east with a 10-s oscillation (six whole periods in the minute, so its mean is 5 m/s);
    # from the outage start the wind turns north at k m/s²: a dead reckoner that holds the minute's mean wind and
    # knows its air velocity is off by ∫k·t dt = ½·k·L² north at the end (the trapezoid is exact on a ramp, and
    # on whole periods of a sinusoid; 1/32 s is exact in binary, so the minute's edges fall on samples)
    t = np.arange(0.0, 400.0, 1.0 / 32.0)
    t0, k = 200.0, 0.01
    east = 5.0 + np.where(t < t0, 0.8 * np.sin(2.0 * np.pi * t / 10.0), 0.0)
    north = np.where(t >= t0, k * (t - t0), 0.0)
    truth = {"t_s": t, "wind_ned_m_s": np.column_stack([north, east, np.full_like(t, 0.3)])}
    for length in (60.0, 120.0):
        assert nav_bench.wind_hold_error_m(truth, t0, length) == pytest.approx(0.5 * k * length**2, rel=1e-9)
    # a steady wind costs nothing, however strong; an outage without the minute before it is refused
    _, steady = _straight_flight()
    assert nav_bench.wind_hold_error_m(steady, T0_S, LENGTH_S) == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="no truth in the 60 s before"):
        nav_bench.wind_hold_error_m(truth, -100.0, 60.0)
    # the report's table and its median over seeds
    rows = [
        {"world": "harsh", "scenario": "survey", "outages": {}, "wind_hold_m": {"300": v}}
        for v in (100.0, 300.0, 250.0)
    ]
    hold = nav_bench.wind_hold_summary(rows)
    assert hold == {"harsh/survey/300": {"median_m": 250.0, "seeds": 3.0}}
    full = {"p95_m": 1.0, "max_m": 1.0, "seeds": 3, "pct_distance_median": 1.0, "max_during_median_m": 1.0,
            "reacquisition_jump_median_m": 1.0}  # fmt: skip
    medians = {"ins": 1700.0, "airspeed-dr": 370.0, "vdm": 200.0}
    summary = {"harsh/survey/300": {m: {**_mode_summary(v), **full} for m, v in medians.items()}}
    doc = {"spec": {"modes": list(medians), "seeds": 3}, "runs": rows, "wind_hold": hold, "summary": summary}
    report = nav_bench.format_report(doc)
    assert "| harsh | survey | 300 | 3 | 250.0 | 1700.0 | 370.0 | 200.0 | 6.8× |" in report
