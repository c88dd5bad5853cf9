"""``demo``: the most complete pipeline that exists, on embedded defaults, no network."""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Dataset, load_dataset
from vdm_aero.discrepancy import MAX_EFFECTS
from vdm_aero_cli.plots import plot_dataset


def register(sub: Any) -> None:
    p = sub.add_parser(
        "demo",
        help="run the whole pipeline on the shipped presets",
        description="Simulate the URANS-like and tunnel-like NACA 0015 presets, fit the DEIM model, train "
        "the correction net (quick grid), evaluate both of the method's cases, print the tables, and run the "
        "discrepancy workflow (URANS preset against the tunnel preset), the 3-D UAV pitching case, a SITL "
        "flight of the survey scenario behind the mock autopilot, the as-built aircraft's in-flight "
        "calibration (short), every navigation mode through a GNSS outage (3 seeds), and the companion service "
        "against the mock autopilot as separate processes over UDP.",
    )
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    p.add_argument("--quick", action="store_true",
                   help="a first look in about a minute: every stage, each at reduced size (one sensor count, "
                   "short training, two discovery rounds, shorter flights, one seed, a 30 s outage)")  # fmt: skip
    p.set_defaults(func=run_demo)


@dataclass(frozen=True)
class DemoSize:
    """How big each stage runs: ``FULL`` is the demo, ``QUICK`` the first look of ``make demo QUICK=1``."""

    grid: str
    spec_motion: dict[str, Any] | None  # overrides of the presets' motion (None: as shipped)
    uav_points: int | None
    airfoil_sensors: tuple[int, ...]
    uav_sensors: tuple[int, ...]
    max_epochs: int
    discovery_effects: int
    sitl_duration_s: float | None  # None: the scenario's own
    calibration_minutes: float
    calibration_test_s: float
    calibration_epochs: int
    nav_seeds: int
    outage_s: float
    service_speed: float


FULL = DemoSize("quick", None, None, (5, 8, 10), (5, 10, 15), 3000, MAX_EFFECTS, None, 2.0, 90.0, 500, 3, 60.0, 4.0)
QUICK = DemoSize("single", {"cycles": 1, "samples_per_cycle": 48}, 4000, (8,), (10,), 300, 1, 120.0, 2.0, 60.0,
                 150, 1, 30.0, 8.0)  # fmt: skip


def reduced_presets(size: DemoSize, out: Path) -> dict[str, str]:
    """The presets at ``size`` (fewer cycles and samples, a coarser UAV surface) as spec files in ``out``."""
    import yaml

    from sim.presets import preset_text

    if size.spec_motion is None:
        return {}
    out.mkdir(parents=True, exist_ok=True)
    sources = {}
    for name in ("naca0015-urans", "naca0015-tunnel", "uav-pitch"):
        spec = yaml.safe_load(preset_text(name))
        spec["motion"].update(size.spec_motion)
        if spec["kind"] == "airframe" and size.uav_points is not None:
            spec["surface_points"] = size.uav_points
        path = out / f"{name}.yaml"
        path.write_text(yaml.safe_dump(spec, sort_keys=False))
        sources[name] = str(path)
    return sources


class _Stages:
    """Numbers the demo's stages and prints each one's wall time, so a user sees where the minutes go."""

    def __init__(self, total: int) -> None:
        self.total, self.k, self.t0, self.name = total, 0, time.perf_counter(), ""

    def __call__(self, name: str) -> None:
        self.done()
        self.k, self.name, self.t0 = self.k + 1, name, time.perf_counter()
        print(f"\n=== stage {self.k}/{self.total}: {name}", flush=True)

    def done(self) -> None:
        if self.name:
            print(f"=== {self.name}: {time.perf_counter() - self.t0:.0f} s", flush=True)
            self.name = ""


def stall_summary(ds: Dataset) -> list[tuple[str, float, float, bool, float]]:
    """Per case: (name, max C_L, α at max C_L [deg], on the upstroke?, loop area ∮C_L dα [rad])."""
    cl, _ = lift_drag(ds.truth_coeffs(), ds.alpha, ds.beta)
    rows = []
    for case in ds.cases:
        m = np.flatnonzero(ds.case == case.id)
        a = ds.alpha[m]
        i = int(np.argmax(cl[m]))
        upstroke = bool(np.gradient(a)[i] > 0)
        closed_a = np.append(a, a[0])
        closed_cl = np.append(cl[m], cl[m][0])
        area = float(np.sum(0.5 * (closed_cl[1:] + closed_cl[:-1]) * np.diff(closed_a)))
        rows.append((case.name, float(cl[m][i]), float(np.degrees(a[i])), upstroke, area))
    return rows


def run_demo(args: argparse.Namespace) -> int:
    from vdm_aero_cli.paper import run_airfoil_tables

    out: Path = args.out
    size = QUICK if getattr(args, "quick", False) else FULL
    stage, t_start = _Stages(8), time.perf_counter()
    stage("airfoil: simulate both presets, DEIM, correction net, baselines, evaluation")
    # 1-4. simulate both presets → fit DEIM (both of the method's cases, n_s = 5, 8, 10) → train the
    # correction net (quick grid) → evaluate on the held-out tunnel case, with and without noise
    sources = reduced_presets(size, out / "specs")
    doc = run_airfoil_tables(out, sensors=list(size.airfoil_sensors), grid=size.grid, seed=0,
                             max_epochs=size.max_epochs, train_noise=0.0, sources=sources)  # fmt: skip
    for preset in ("naca0015-urans", "naca0015-tunnel"):
        ds = load_dataset(out / "data" / preset)
        png = out / f"{preset}.png"
        plot_dataset(ds, png)
        print(f"\n{preset}: {ds.n_snapshots} snapshots x {ds.n_points} points, plot {png}")
        print(f"  {'case':>10} {'CL max':>7} {'at α':>7} {'stroke':>6} {'∮CL dα':>8}")
        for name, clmax, a_deg, up, area in stall_summary(ds):
            print(f"  {name:>10} {clmax:7.3f} {a_deg:6.1f}° {'up' if up else 'down':>6} {area:8.3f}")
    print()
    print((out / "tables.md").read_text())
    print(f"models in {out / 'models'}, tables and plots in {out} ({len(doc['results'])} table rows)")
    # 5. discrepancy workflow: what does the URANS-like simulation miss against the tunnel-like data?
    from vdm_aero_cli.discover import discover

    stage("discrepancy workflow")
    rep = discover(sources.get("naca0015-urans", "naca0015-urans"), out / "data" / "naca0015-tunnel", out / "discovery",
                   max_effects=size.discovery_effects)  # fmt: skip
    print("\ndiscrepancy workflow: naca0015-urans (simulation) against naca0015-tunnel (measurement)")
    if rep["unexplained"]:
        print("  unexplained: no library effect explains the gap; hot spots:")
        for h in rep["hotspots"][:5]:
            print(f"    {h['kind']:6} {h['label']:28} {h['share']:6.1%}")
    for e in rep["effects"]:
        params = ", ".join(f"{k} = {v:.4g}" for k, v in e["params"].items())
        print(f"  named {e['name']}: {params} (held-out gain {e['heldout_gain']:.1%}, "
              f"inclusion {e['inclusion_probability']:.2f})")  # fmt: skip
    b, a = rep["gap_before"], rep["gap_after"]
    print(f"  held-out gap before → after (cases {rep['heldout_cases']}):")
    for k in b["coeff_rms"]:
        print(f"    RMS {k:3} {b['coeff_rms'][k]:.4f} → {a['coeff_rms'][k]:.4f}")
    print(f"    RMS Cp  {b['cp_rms']:.4f} → {a['cp_rms']:.4f}")
    print(f"  report {out / 'discovery' / 'report.md'}, updated spec {out / 'discovery' / 'spec.yaml'}")
    # 6. the 3-D UAV: pitching airframe, DEIM over every surface point, correction net, the method's 3-D table
    from vdm_aero_cli.paper import run_uav_tables

    stage("3-D UAV: simulate, DEIM, correction net, evaluation")
    run_uav_tables(out / "uav", sensors=list(size.uav_sensors), grid=size.grid, seed=0, max_epochs=size.max_epochs,
                   train_noise=0.0, sources=sources)  # fmt: skip
    print()
    print((out / "uav" / "tables.md").read_text())
    print(f"3-D ports and Cp snapshot: {out / 'uav' / 'uav-ns15-ports.png'}")
    # 7. software in the loop: the 6-DOF flight behind the mock autopilot (no socket: a null link)
    from sim.flight.scenario import load_scenario
    from sim.flight.world import FlightWorld
    from sim.sitl.autopilot import run_sitl
    from vdm_aero_cli.cmd_sitl import plot_flight

    stage("SITL: the 6-DOF flight behind the mock autopilot")
    scenario = load_scenario("survey-wind8")
    (out / "flight").mkdir(parents=True, exist_ok=True)
    sitl_s = size.sitl_duration_s or scenario.duration_s
    summary = run_sitl(FlightWorld(scenario), "null", speed=float("inf"), duration_s=sitl_s,
                       truth=out / "flight" / "truth.npz", tlog=out / "flight" / "flight.tlog")  # fmt: skip
    plot_flight(out / "flight" / "truth.npz", out / "flight" / "trajectory.png")
    print(f"\nSITL: flew {scenario.name} for {summary['world_time_s']:.0f} s of world time in "
          f"{summary['wall_time_s']:.1f} s; {sum(summary['sent'].values())} MAVLink messages; "
          f"trajectory with its GNSS outage in {out / 'flight' / 'trajectory.png'}")  # fmt: skip
    # 8. the as-built aircraft: design-data DEIM against the built aircraft, and a short in-flight calibration
    #    (2 minutes of manoeuvres, 90 s of each test flight; `vdm-aero calibration-study` runs the full one)
    from vdm_aero_cli.calibration_study import run_study

    stage("as-built aircraft and in-flight calibration")
    run_study(out / "calibration", n_sensors=12, calibration_minutes=(size.calibration_minutes,),
              test_duration_s=size.calibration_test_s, grid=size.grid, seed=0,
              max_epochs=size.calibration_epochs)  # fmt: skip
    print("\nas-built aircraft and in-flight calibration (short run):")
    print((out / "calibration" / "calibration.md").read_text())
    # 9. navigation through a GNSS outage: every mode on the same sensor streams, 3 seeds of the survey with
    #    one 60 s outage in the harsh world (a fleet airframe per seed, each calibrated from its own flight)
    #    and the kind one, the models of step 8 (`vdm-aero bench nav-drift` runs the full benchmark)
    from vdm_aero.nav.filter import MODES
    from vdm_aero_cli.nav_bench import BenchSpec, NavArtifacts, run_nav_drift, write_report

    stage("navigation: every mode through a GNSS outage")
    art = NavArtifacts.under(out / "calibration", calibration_minutes=size.calibration_minutes)
    spec = BenchSpec(scenarios=("survey",), seeds=size.nav_seeds, outages_s=(size.outage_s,), modes=tuple(MODES),
                     worlds=("harsh", "kind"), calibration_epochs=size.calibration_epochs)  # fmt: skip
    paths = write_report(run_nav_drift(spec, art), out / "navigation")
    print(f"\nnavigation through a {size.outage_s:g} s GNSS outage (survey, {size.nav_seeds} seed(s)), harsh and "
          "kind worlds:")  # fmt: skip
    print(paths["markdown"].read_text())
    print(f"error vs time: {paths[f'nav-drift-harsh-survey-{size.outage_s:g}s']}")
    # 10. the product: `vdm-aero serve` and the mock autopilot as separate processes over UDP loopback, the same
    #     survey flight (seed 0) with its GNSS outage in the world's receiver; scored against the truth and the
    #     in-process benchmark figure of step 9 for the same seed
    from vdm_aero_cli.service_sitl import (
        ServiceRun,
        bench_reference,
        run_service_sitl,
        score_service,
        site_mag_field_ut,
        write_service_report,
    )

    stage("the companion service against the mock autopilot")
    run = ServiceRun(art.dataset_dir, art.deim_dir, art.nn_dir, seed=0, outage_s=size.outage_s,
                     speed=size.service_speed)  # fmt: skip
    print(f"\nthe companion service against the mock autopilot (separate processes, UDP loopback, "
          f"{size.service_speed:g}x real time):")  # fmt: skip
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    # the in-process benchmark of the same flight (CPU-bound) runs on the second core while the service flies
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as ex:
        ref_job = ex.submit(bench_reference, run)
        res = run_service_sitl(run, out / "service" / "run", mag_field_ned_ut=site_mag_field_ut(run))
        score, ref = score_service(res), ref_job.result()
    svc_paths = write_service_report(run, res, score, ref, out / "service")
    print(svc_paths["markdown"].read_text())
    print(f"service log {res['work'] / 'serve.log'}, navigation log {res['work'] / 'state' / 'nav.csv'}, "
          f"plot {svc_paths['plot']}")  # fmt: skip
    # 11. the log replay: the tlog the mock autopilot wrote during step 10 (the service's streams and the ports),
    #     every mode through the same outage, judged against the mock's truth file
    from vdm_aero.nav.filter import MODES as ALL_MODES
    from vdm_aero_cli.cmd_replay import replay

    stage("log replay of the service's flight")
    a, b = res["outage"]
    replay(res["tlog"], model=art.nn_dir, design_data=art.dataset_dir, vehicle="uav-2m", outages=[(a, b)],
           modes=tuple(ALL_MODES), truth=res["work"] / "truth.npz", mag_field_ned_ut=np.asarray(site_mag_field_ut(run)),
           out=out / "replay", jobs=os.cpu_count() or 1)  # fmt: skip
    print("\nthe same flight replayed from the mock autopilot's tlog (`vdm-aero replay`):")
    print((out / "replay" / "replay.md").read_text())
    stage.done()
    print(f"\ndemo{' (quick)' if size is QUICK else ''} done in {time.perf_counter() - t_start:.0f} s; everything "
          f"is in {out}")  # fmt: skip
    return 0
