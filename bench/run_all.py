"""``make bench``: benchmarks with JSON results (medians of repeats; this machine is shared and noisy).

Never part of ``make test``. Each benchmark states its bar; the JSON records the measurement and
whether the bar was met, so regressions are visible without making CI flaky.
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import reliability_bench


def _median_seconds(fn: Callable[[], Any], repeats: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def bench_simulate_urans(repeats: int) -> dict[str, Any]:
    """The 10-frequency URANS preset (3 cycles × 128 samples, 1316 points); bar: < 10 s."""
    import yaml

    from sim.airfoil.simulate import simulate_spec
    from sim.airfoil.spec import parse_spec
    from sim.presets import preset_text

    spec = parse_spec(yaml.safe_load(preset_text("naca0015-urans")))
    # first call includes the NeuralFoil import and calibration; report both
    t0 = time.perf_counter()
    ds = simulate_spec(spec)
    cold = time.perf_counter() - t0
    med, times = _median_seconds(lambda: simulate_spec(spec), repeats)
    return {
        "name": "simulate naca0015-urans",
        "snapshots": ds.n_snapshots,
        "points": ds.n_points,
        "cold_seconds": round(cold, 3),
        "median_seconds": round(med, 3),
        "all_seconds": [round(t, 3) for t in times],
        "bar_seconds": 10.0,
        "meets_bar": cold < 10.0,
    }


def bench_panel_solve(repeats: int) -> dict[str, Any]:
    """Panel-method solve (two unit solutions) at the presets' 1316 panels; bar < 1 s."""
    from sim.airfoil.naca import naca4_nodes
    from sim.airfoil.panel import solve_panels

    nodes = naca4_nodes("0015", 1316)
    med, _ = _median_seconds(lambda: solve_panels(nodes), repeats)
    return {"panels": 1316, "median_seconds": round(med, 4), "bar_seconds": 1.0, "meets_bar": med < 1.0}


def bench_aero(repeats: int) -> dict[str, Any]:
    """Run-time latency, 10 ports + 4x40 net; bar: DEIM+NN ≤ 10 µs (the method: 81 µs on a Xeon 6148)."""
    from vdm_aero_cli.cmd_bench import bench_aero as run

    res = run(10, 0)
    res["meets_bar"] = res["deim_nn_predict_us"] <= 10.0
    res["speedup_vs_method"] = round(81.0 / res["deim_nn_predict_us"], 1)
    return res


def bench_deim_select(repeats: int) -> dict[str, Any]:
    """DEIM over 300,000 candidates × 15 modes; bar ≤ 2 s."""
    from vdm_aero_cli.cmd_bench import bench_deim_select as run

    res = run(0)
    res["meets_bar"] = res["median_seconds"] <= 2.0
    return res


def bench_fit_scale(repeats: int) -> dict[str, Any]:
    """POD + DEIM on 300,000 points x 2,000 float32 snapshots, memory-mapped; bars ≤ 60 s, peak RSS ≤ 2x."""
    from vdm_aero.fit_scale import bench_fit_scale as run

    res = run(300_000, 2_000)
    return {k: v for k, v in res.items() if k not in ("sensors", "lines")}


def bench_flight_10min(repeats: int) -> dict[str, Any]:
    """10 minutes of flight with all sensors, in process without sockets; bar ≤ 30 s."""
    from bench.flight_bench import bench_flight

    return bench_flight(minutes=10)


def bench_discovery_matrix(repeats: int) -> dict[str, Any]:
    from bench.discovery_bench import hidden_effect_matrix

    return hidden_effect_matrix()


def bench_discovery_10_cases(repeats: int) -> dict[str, Any]:
    from bench.discovery_bench import ten_case_discovery

    return ten_case_discovery()


NAV_SPEED_ROUNDS = 6  # the lowest and highest of six paired rounds hold their median ratio with 96.9 % confidence


def paired_round_ratios(before: list[float], after: list[float]) -> dict[str, Any]:
    """Speed-up from rounds that timed both versions back to back: each round's before ÷ after, their median,
    and the lowest and highest ratio, a distribution-free interval for the median (the sign test's: it misses
    only when every round falls on one side, probability 2 · 0.5ⁿ). A paired ratio cancels what the machine's
    speed does between rounds, which on this shared machine moves single times by tens of percent."""
    if len(before) != len(after) or not before:
        raise ValueError("paired_round_ratios: one before and one after per round")
    r = sorted(b / a for b, a in zip(before, after, strict=True))
    n = len(r)
    return {"speedup": round(statistics.median(r), 3), "speedup_interval": [round(r[0], 3), round(r[-1], 3)],
            "interval_confidence": round(1.0 - 2.0 * 0.5**n, 4), "rounds": n,
            "rounds_faster": sum(v > 1.0 for v in r)}  # fmt: skip


def bench_nav_speed(repeats: int) -> dict[str, Any]:
    """The navigation filter alone, per mode, on 120 s of a 400 Hz IMU flight, today's code beside the code
    before issue 25 (bench/baseline.py). Each round times both versions back to back, in turn first
    (``max(repeats, 6)`` rounds), and the speed-up is the median of the rounds' paired ratios with the interval
    their spread gives (:func:`paired_round_ratios`). Bars (issue 25): each mode ≥ 5× faster than before;
    ``vdm`` ≥ 250× real time. Beside them, the share of today's step spent in filterpy's predict and update
    (the engine the issue keeps) and the ratio to the code before that a step would reach if everything else
    in it cost nothing: the ceiling that engine sets."""
    from bench.baseline import REPO, baseline_checkout, run_python
    from vdm_aero_cli.nav_bench import build_artifacts

    art_root = Path("out/bench/nav-artifacts").resolve()
    build_artifacts(art_root)
    probe = str(REPO / "bench" / "filter_speed_probe.py")
    trees = {"after": REPO, "before": baseline_checkout()}
    rounds: dict[str, list[dict[str, Any]]] = {"after": [], "before": []}
    for k in range(max(repeats, NAV_SPEED_ROUNDS)):
        for name in ("after", "before") if k % 2 == 0 else ("before", "after"):
            rounds[name].append(
                json.loads(run_python(trees[name], [probe, str(art_root), "--seconds", "120", "--repeats", "2"]))
            )
    share_args = [probe, str(art_root), "--seconds", "120", "--repeats", "3", "--engine-share"]
    shares = json.loads(run_python(REPO, share_args))
    modes: dict[str, Any] = {}
    for m in rounds["after"][0]:
        after = [r[m]["us_per_step"] for r in rounds["after"]]
        before = [r[m]["us_per_step"] for r in rounds["before"]]
        paired = paired_round_ratios(before, after)
        a_med = statistics.median(after)
        share = shares[m]["engine_share"]
        modes[m] = {"us_per_step_before": statistics.median(before), "us_per_step_after": a_med, **paired,
                    "x_real_time_after": round(1e6 / (50.0 * a_med), 1), "filterpy_share": share,
                    "speedup_ceiling_with_filterpy": round(paired["speedup"] / share, 2),
                    "rounds_us_per_step_before": before, "rounds_us_per_step_after": after}  # fmt: skip
    return {"flight_s": 120.0, "imu_rate_hz": 400.0, "baseline": "bench/baseline.py BASELINE_REF", "modes": modes,
            "bars": {"speedup_each_mode": 5.0, "vdm_x_real_time": 250.0},
            "meets_bar": {"speedup_each_mode": all(v["speedup"] >= 5.0 for v in modes.values()),
                          "vdm_x_real_time": modes["vdm"]["x_real_time_after"] >= 250.0},
            "reachable_with_filterpy": {"speedup_each_mode": all(v["speedup_ceiling_with_filterpy"] >= 5.0
                                                                 for v in modes.values())}}  # fmt: skip


def bench_nav_drift(repeats: int) -> dict[str, Any]:
    """``vdm-aero bench nav-drift --scenario all --seeds 20 --outage-s 60,120,300``: the harsh world beside the
    kind one, and the cost of each effect alone (5 seeds each); hours on 2 cores (docs/navigation.md)."""
    from vdm_aero.nav.filter import MODES
    from vdm_aero_cli.nav_bench import SCENARIOS, BenchSpec, build_artifacts, run_nav_drift, write_report

    art = build_artifacts(Path("out/bench/nav-artifacts"))
    spec = BenchSpec(scenarios=tuple(SCENARIOS), seeds=20, outages_s=(60.0, 120.0, 300.0), modes=tuple(MODES),
                     worlds=("harsh", "kind"), cost_seeds=5)  # fmt: skip
    doc = run_nav_drift(spec, art)
    write_report(doc, Path("out/bench/nav-drift"))
    return {"wall_s": doc["wall_s"], "summary": doc["summary"], "ins_theory": doc["ins_theory"]}


# what the service imports that it cannot do without: the issue-25 memory floor
FLOOR_IMPORTS = "import numpy, onnxruntime, pymavlink.dialects.v20.ardupilotmega, filterpy.kalman"
CGROUP_CPU = Path("/sys/fs/cgroup/cpu")  # cgroup v1 cpu controller (cfs quota); v2: cpu.max


def _floor_rss_mb() -> float:
    """Peak RSS [MB] of a bare Python that imports only the service's libraries."""
    import subprocess
    import sys

    code = f"{FLOOR_IMPORTS}\nprint(open('/proc/self/status').read().split('VmHWM:')[1].split()[0])"
    return int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout) / 1024


def _cpu_quota_wrap(pct: float) -> tuple[list[str], str | None]:
    """A command prefix that runs a process in a cgroup limited to ``pct`` % of one core, or ([], why not)."""
    grp = CGROUP_CPU / "vdm-aero-bench"
    try:
        grp.mkdir(exist_ok=True)
        (grp / "cpu.cfs_period_us").write_text("100000")
        (grp / "cpu.cfs_quota_us").write_text(str(round(1000.0 * pct)))
    except OSError as e:
        return [], f"no writable cgroup v1 cpu controller at {CGROUP_CPU} ({e.strerror})"
    return ["sh", "-c", f'echo $$ > {grp / "cgroup.procs"} && exec "$@"', "sh"], None


def bench_service(repeats: int) -> dict[str, Any]:
    """``vdm-aero serve`` against the mock in real time, 400 Hz IMU (RAW_IMU, the auto streams) + 12 ports at
    100 Hz over UDP loopback, 90 s: today's service beside the code before issue 25 (bench/baseline.py), the
    service pinned to core 1 and the mock to core 0 (taskset); then both under the CPU quota of one Raspberry
    Pi 4 core, this core's share that does the Pi core's work (bench/pi_ratio.py, a cited Pi figure).
    Bars (issue 25): p99 last port message in → outputs sent ≤ 1 ms, CPU ≤ 3 % of one core, peak RSS ≤ 1.3×
    the floor (a Python that imports only numpy, onnxruntime, pymavlink and filterpy). Today's service counts the
    latency from the kernel's arrival stamp of the last port message's datagram; the code before counted it from
    its read, which leaves out the wait in the socket (docs/performance.md). Beside the real-time CPU, the offline
    replay of each version's recorded link (bench/service_work_probe.py): its own work, and that work paced as
    the link delivers it. A round flies one seed with both versions back to back, the first alternating, and
    beside the medians the CPU's and p99's before ÷ after come paired by round (:func:`paired_round_ratios`)."""
    import subprocess
    import sys

    from bench.baseline import REPO, baseline_checkout, run_python
    from vdm_aero_cli.nav_bench import build_artifacts
    from vdm_aero_cli.service_sitl import ServiceRun, run_service_sitl, site_mag_field_ut

    art = build_artifacts(Path("out/bench/nav-artifacts").resolve())
    ratio = json.loads(subprocess.run([sys.executable, str(REPO / "bench" / "pi_ratio.py")], capture_output=True,
                                      text=True, check=True).stdout)  # fmt: skip
    pi_core_pct = 100.0 / ratio["pi4_slower_x"]
    quota_wrap, no_quota = _cpu_quota_wrap(pi_core_pct)
    floor = _floor_rss_mb()
    trees = {"after": None, "before": baseline_checkout()}
    setups = {"one core": []} | ({"one pi4 core (quota)": quota_wrap} if quota_wrap else {})
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {k: {"after": [], "before": []} for k in setups}
    for k in range(max(repeats // 2, 1)):
        for setup, quota in setups.items():
            # both versions fly round k's seed back to back, the first alternating (paired_round_ratios)
            for name in ("after", "before") if k % 2 == 0 else ("before", "after"):
                tree = trees[name]
                run = ServiceRun(art.dataset_dir, art.deim_dir, art.nn_dir, seed=k, speed=1.0, stop_after_s=90.0,
                                 ports_rate_hz=100.0)  # fmt: skip
                # the other checkout's code: first on PYTHONPATH, and the working directory (``python -m`` puts it
                # ahead of PYTHONPATH, and this one's is this checkout)
                env = {"PYTHONPATH": str(tree)} if tree is not None else None
                cd = ["env", f"--chdir={tree}"] if tree is not None else []
                res = run_service_sitl(run, Path(f"out/bench/service/{setup.split()[1]}-{name}-{k}").resolve(),
                                       mag_field_ned_ut=site_mag_field_ut(run), service_env=env,
                                       service_wrap=[*cd, "taskset", "-c", "1", *quota],
                                       mock_wrap=["taskset", "-c", "0"],
                                       config_template=(tree or REPO) / "deploy" / "config.yaml")  # fmt: skip
                svc = res["service"]
                runs[setup][name].append({
                    "latency_p50_ms": svc["latency_ms"]["p50"], "latency_p99_ms": svc["latency_ms"]["p99"],
                    "latency_max_ms": svc["latency_ms"]["max"], "frames": svc["port_frames"],
                    "imu_msgs": svc["received"].get("RAW_IMU", 0), "cpu_pct_one_core": res["service_cpu_pct"],
                    "peak_rss_mb": res["service_peak_rss_mb"], "wall_s": res["wall_s"]})  # fmt: skip
    # the same link replayed offline (bench/service_work_probe.py): the service's own work, and the work with the
    # link's wake-ups, from the first pinned run of each version (its recorded tlog and its own config)
    probe = str(REPO / "bench" / "service_work_probe.py")
    work: dict[str, dict[str, Any]] = {}
    for name, tree in trees.items():
        run_dir = str(Path(f"out/bench/service/core-{name}-0").resolve())
        go = functools.partial(run_python, tree or REPO)
        back_to_back = [json.loads(go([probe, run_dir, "--seconds", "60"])) for _ in range(3)]
        paced = json.loads(go([probe, run_dir, "--seconds", "60", "--paced"]))
        work[name] = {"work_cpu_pct": statistics.median(r["cpu_pct_one_core"] for r in back_to_back),
                      "paced_cpu_pct": paced["cpu_pct_one_core"], "wake_ups_per_s": round(
                          paced["wake_ups"] / paced["flight_s"], 1), "messages_per_s": round(
                          paced["messages"] / paced["flight_s"], 1),
                      "empty_wake_up_cpu_us": paced["empty_wake_up_cpu_us"]}  # fmt: skip
    keys = ("latency_p99_ms", "cpu_pct_one_core", "peak_rss_mb")
    median = {s: {n: {k: statistics.median(r[k] for r in rs) for k in keys} for n, rs in by.items()}
              for s, by in runs.items()}  # fmt: skip
    # before ÷ after of each round's pair (a round flies one seed with both versions back to back)
    paired = {s: {k: paired_round_ratios([r[k] for r in by["before"]], [r[k] for r in by["after"]])
                  for k in ("latency_p99_ms", "cpu_pct_one_core")} for s, by in runs.items()}  # fmt: skip
    bars = {"latency_p99_ms": 1.0, "cpu_pct_one_core": 3.0, "peak_rss_mb": round(1.3 * floor, 1)}
    after = median["one core"]["after"]
    return {"runs": runs, "median": median, "paired_ratio_before_over_after": paired, "offline_work": work,
            "floor_rss_mb": round(floor, 1), "pi4": ratio,
            "pi4_core_pct_of_this_core": round(pi_core_pct, 1), "quota_skipped": no_quota, "bars": bars,
            "meets_bar": {k: after[k] <= b for k, b in bars.items()}}  # fmt: skip


def bench_replay(repeats: int) -> dict[str, Any]:
    """``vdm-aero replay`` of the survey (seed 0, 60 s outage) as the mock autopilot records it: 400 Hz
    HIGHRES_IMU, 12 ports at 50 Hz, 231 s; every mode (the 10-minute calibrated net), then vdm-deim-nn alone.
    Bar: ≥ 20× real time. Also the in-process benchmark's errors on the same flight, for comparison."""
    import subprocess
    import sys

    from vdm_aero.nav.filter import MODES
    from vdm_aero.nav.models import NavModels
    from vdm_aero_cli.nav_bench import AFTER_S, OUTAGE_START_S, _flight, build_artifacts, run_filters
    from vdm_aero_cli.replay_golden import LOOP_RATE_HZ, STREAMS

    art = build_artifacts(Path("out/bench/nav-artifacts"))
    work = Path("out/bench/replay")
    tlog, truth = work / "survey0.tlog", work / "survey0-truth.npz"
    cli = [sys.executable, "-m", "vdm_aero_cli.main"]
    if not tlog.is_file():
        rates = [a for k, hz in STREAMS.items() for a in ("--stream-rate", f"{k}={hz:g}")]
        subprocess.run([*cli, "sitl", "--nav-scenario", "survey", "--seed", "0", "--outage-s", "60", "--ports-model",
                        str(art.deim_dir), "--connect", "null", "--speed", "0", "--gcs-recording", *rates,
                        "--loop-rate-hz", f"{LOOP_RATE_HZ:g}", "--tlog",
                        str(tlog), "--truth", str(truth)], check=True, capture_output=True)  # fmt: skip
    sensors, truth_arr, meta, t_out = _flight("survey", 0, art, OUTAGE_START_S[1] + 60.0 + AFTER_S + 5.0)
    mag = ",".join(f"{v * 1e6:.4f}" for v in meta["mag_field_ned_t"])
    bench = run_filters(sensors, truth_arr, meta, t_out, [60.0], tuple(MODES),
                        NavModels.load(art.dataset_dir, art.deim_dir, art.nn_dir))["outages"]["60"]  # fmt: skip

    def replay(modes: str) -> dict[str, Any]:
        r = subprocess.run([*cli, "replay", str(tlog), "--model", str(art.nn_dir), "--design-data",
                            str(art.dataset_dir), "--truth", str(truth), "--outage", f"{t_out}:{t_out + 60.0}",
                            "--mag-field", mag, "--modes", modes, "--json", "--out", str(work / "report")],
                           check=True, capture_output=True, text=True)  # fmt: skip
        return dict(json.loads(r.stdout))

    runs = [replay(",".join(MODES)) for _ in range(max(repeats // 2, 3))]
    one = [replay("vdm-deim-nn") for _ in range(max(repeats // 2, 3))]
    x_all = statistics.median(r["speed"]["x_real_time"] for r in runs)
    x_one = statistics.median(r["speed"]["x_real_time"] for r in one)
    per = runs[0]["outages"][0]["modes"]
    return {"flight_s": runs[0]["speed"]["flight_s"], "imu_rate_hz": runs[0]["speed"]["imu_rate_hz"],
            "x_real_time_all_modes": {"median": x_all, "runs": [r["speed"]["x_real_time"] for r in runs]},
            "x_real_time_vdm_deim_nn": {"median": x_one, "runs": [r["speed"]["x_real_time"] for r in one]},
            "read_wall_s": statistics.median(r["speed"]["read_wall_s"] for r in runs),
            "errors_m": {m: {"replay_final": v["final_error_m"], "bench_final": bench[m]["final_error_m"],
                             "replay_max": v["max_error_m"], "bench_max": bench[m]["max_error_m"]}
                         for m, v in per.items()},
            "bar_x_real_time": 20.0, "meets_bar": x_all >= 20.0}  # fmt: skip


BENCHES: dict[str, Callable[[int], dict[str, Any]]] = {
    "simulate-urans": bench_simulate_urans,
    "panel-solve": bench_panel_solve,
    "aero": bench_aero,
    "deim-select": bench_deim_select,
    "fit-scale": bench_fit_scale,
    "flight-10min": bench_flight_10min,
    "discovery-matrix": bench_discovery_matrix,
    "discovery-10-cases": bench_discovery_10_cases,
    "nav-speed": bench_nav_speed,
    "nav-drift": bench_nav_drift,
    "service": bench_service,
    "replay": bench_replay,
    "reliability-faults": reliability_bench.bench_faults,
    "reliability-link-60s": reliability_bench.bench_link_60s,
    "reliability-gnss-drift": reliability_bench.bench_gnss_drift,
    "reliability-long-outage": reliability_bench.bench_long_outage,
    "reliability-load": reliability_bench.bench_load,
    "reliability-soak": reliability_bench.bench_soak,
    "relay-cases": reliability_bench.bench_relay_cases,
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", nargs="*", choices=sorted(BENCHES))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name, fn in BENCHES.items():
        if args.only and name not in args.only:
            continue
        res = fn(args.repeats)
        results[name] = res
        (args.out / f"{name}.json").write_text(json.dumps(res, indent=2))
        print(json.dumps(res))
    (args.out / "all.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
