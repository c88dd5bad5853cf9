"""``demo``: the most complete pipeline that exists, on embedded defaults, no network."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Dataset, load_dataset
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
    p.set_defaults(func=run_demo)


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
    # 1-4. simulate both presets → fit DEIM (both of the method's cases, n_s = 5, 8, 10) → train the
    # correction net (quick grid) → evaluate on the held-out tunnel case, with and without noise
    doc = run_airfoil_tables(out, sensors=[5, 8, 10], grid="quick", seed=0, max_epochs=3000, train_noise=0.0)
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

    rep = discover("naca0015-urans", out / "data" / "naca0015-tunnel", out / "discovery")
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

    run_uav_tables(out / "uav", sensors=[5, 10, 15], grid="quick", seed=0, max_epochs=3000, train_noise=0.0)
    print()
    print((out / "uav" / "tables.md").read_text())
    print(f"3-D ports and Cp snapshot: {out / 'uav' / 'uav-ns15-ports.png'}")
    # 7. software in the loop: the 6-DOF flight behind the mock autopilot (no socket: a null link)
    from sim.flight.scenario import load_scenario
    from sim.flight.world import FlightWorld
    from sim.sitl.autopilot import run_sitl
    from vdm_aero_cli.cmd_sitl import plot_flight

    scenario = load_scenario("survey-wind8")
    (out / "flight").mkdir(parents=True, exist_ok=True)
    summary = run_sitl(FlightWorld(scenario), "null", speed=float("inf"), duration_s=scenario.duration_s,
                       truth=out / "flight" / "truth.npz", tlog=out / "flight" / "flight.tlog")  # fmt: skip
    plot_flight(out / "flight" / "truth.npz", out / "flight" / "trajectory.png")
    print(f"\nSITL: flew {scenario.name} for {summary['world_time_s']:.0f} s of world time in "
          f"{summary['wall_time_s']:.1f} s; {sum(summary['sent'].values())} MAVLink messages; "
          f"trajectory with its GNSS outage in {out / 'flight' / 'trajectory.png'}")  # fmt: skip
    # 8. the as-built aircraft: design-data DEIM against the built aircraft, and a short in-flight calibration
    #    (2 minutes of manoeuvres, 90 s of each test flight; `vdm-aero calibration-study` runs the full one)
    from vdm_aero_cli.calibration_study import run_study

    run_study(out / "calibration", n_sensors=12, calibration_minutes=(2.0,), test_duration_s=90.0, grid="quick",
              seed=0, max_epochs=500)  # fmt: skip
    print("\nas-built aircraft and in-flight calibration (short run):")
    print((out / "calibration" / "calibration.md").read_text())
    # 9. navigation through a GNSS outage: every mode on the same sensor streams, 3 seeds of the survey with
    #    one 60 s outage, the models of step 8 (`vdm-aero bench nav-drift` runs the full benchmark)
    from vdm_aero.nav.filter import MODES
    from vdm_aero_cli.nav_bench import BenchSpec, NavArtifacts, run_nav_drift, write_report

    art = NavArtifacts.under(out / "calibration", calibration_minutes=2.0)
    spec = BenchSpec(scenarios=("survey",), seeds=3, outages_s=(60.0,), modes=tuple(MODES))
    paths = write_report(run_nav_drift(spec, art), out / "navigation")
    print("\nnavigation through a 60 s GNSS outage (survey, 3 seeds):")
    print(paths["markdown"].read_text())
    print(f"error vs time: {paths['nav-drift-survey-60s']}")
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

    run = ServiceRun(art.dataset_dir, art.deim_dir, art.nn_dir, seed=0, outage_s=60.0, speed=4.0)
    print("\nthe companion service against the mock autopilot (separate processes, UDP loopback, 4x real time):")
    res = run_service_sitl(run, out / "service" / "run", mag_field_ned_ut=site_mag_field_ut(run))
    score, ref = score_service(res), bench_reference(run)
    svc_paths = write_service_report(run, res, score, ref, out / "service")
    print(svc_paths["markdown"].read_text())
    print(f"service log {res['work'] / 'serve.log'}, navigation log {res['work'] / 'state' / 'nav.csv'}, "
          f"plot {svc_paths['plot']}")  # fmt: skip
    # 11. the log replay: the tlog the mock autopilot wrote during step 10 (the service's streams and the ports),
    #     every mode through the same outage, judged against the mock's truth file
    from vdm_aero.nav.filter import MODES as ALL_MODES
    from vdm_aero_cli.cmd_replay import replay

    a, b = res["outage"]
    replay(res["tlog"], model=art.nn_dir, design_data=art.dataset_dir, vehicle="uav-2m", outages=[(a, b)],
           modes=tuple(ALL_MODES), truth=res["work"] / "truth.npz", mag_field_ned_ut=np.asarray(site_mag_field_ut(run)),
           out=out / "replay", jobs=os.cpu_count() or 1)  # fmt: skip
    print("\nthe same flight replayed from the mock autopilot's tlog (`vdm-aero replay`):")
    print((out / "replay" / "replay.md").read_text())
    return 0
