"""``vdm-aero replay LOG``: a recorded flight through the navigation filters with GNSS cut out of it.

The log is read by its format's reader (``firmware_bridge.logs``) into the SI stream the service builds from
the live link, then every navigation mode the log allows runs through it on the filter path the benchmark
and the service share, with the GNSS fixes removed inside each ``--outage`` window. Each mode's horizontal
error is judged against a truth when there is one (SIMSTATE/SIM in ArduPilot SITL logs, ``--truth`` for the
mock autopilot's), else against the log's own GNSS, which the filters did not see inside the windows. Where the
log holds the autopilot's own position estimate, its error against the same reference is put beside the modes'
outside the windows, where it had GNSS as the filters had (inside them it is no comparison).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from functools import cache
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Final

import numpy as np

from vdm_aero.errors import UserInputError

DEFAULT_OUTAGE_S = 60.0
GOLDEN = Path(__file__).resolve().parent.parent / "tests" / "golden" / "replay-survey.csv"


def register(sub: Any) -> None:
    p = sub.add_parser(
        "replay",
        help="replay a flight log (.tlog, DataFlash .bin, ULog .ulg) with GNSS outages through every nav mode",
        description="Read a flight log, remove GNSS inside each outage window and run the navigation modes the log "
        "allows (ports: the port modes; none: ins, airspeed-dr, vdm-classic). Errors are judged against the log's "
        "truth (ArduPilot SITL SIMSTATE/SIM, or --truth) or else its own GNSS; the autopilot's own estimate, where the "
        "log holds it, beside them outside the outages. Writes a report (markdown, JSON), the error-vs-time plot and "
        "the navigation solution (CSV) to --out.",
    )
    p.add_argument("log", type=Path, nargs="?", metavar="LOG", help="the flight log")
    p.add_argument("--model", type=Path, metavar="M", help="aero model directory (DEIM, or DEIM + correction net)")
    p.add_argument("--design-data", type=Path, metavar="D", help="the design data set (FADS and derivatives)")
    p.add_argument("--vehicle", default="uav-2m", metavar="V", help="nominal vehicle description (default uav-2m)")
    p.add_argument("--outage", action="append", default=[], metavar="START:END",
                   help="GNSS outage window on the log's clock [s], repeatable (default: 60 s mid-flight)")  # fmt: skip
    p.add_argument("--modes", metavar="M1,M2", help="navigation modes (default: every mode the log allows)")
    p.add_argument("--truth", type=Path, metavar="FILE", help="the mock autopilot's truth file for this log")
    p.add_argument("--mag-field", metavar="N,E,D", help="Earth field at the site [µT] (default: WMM at the "
                   "first fix and the log's date)")  # fmt: skip
    p.add_argument(
        "--jobs",
        type=int,
        default=os.cpu_count() or 1,
        metavar="N",
        help="processes to share the modes among (default: one per CPU)",
    )
    p.add_argument("--system-id", type=int, help="the autopilot's MAVLink system id in a tlog (default: first heard)")
    p.add_argument("--gnss-latency-s", type=float, metavar="S", help="a tlog's GNSS receiver latency: GPS_RAW_INT is "
                   "stamped this long after the fix's validity (default: the autopilot's own default, ArduPilot "
                   "0.12, PX4 0.11; set your GPS_DELAY_MS / EKF2_GPS_DELAY)")  # fmt: skip
    p.add_argument("--out", type=Path, metavar="DIR", help="report directory (default out/replay/<log name>)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--update-golden", action="store_true", help="regenerate tests/golden/replay-survey.csv: fly "
                   "the golden mock flight, replay it and write the decimated solution (review the diff)")  # fmt: skip
    p.set_defaults(func=run_replay_cmd)


def _floats(text: str, n: int, what: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise UserInputError(f"{what}: expected {n} numbers separated by commas, got {text!r}")
    return vals


# CPU per mode relative to ins, and of the port front end a group shares, measured on the mock survey tlog
# (400 Hz IMU, 12 ports at 50 Hz): what the modes are dealt to processes by
MODE_COST: Final = {"ins": 1.0, "airspeed-dr": 1.4, "ports-airdata": 1.4, "vdm-classic": 1.8, "vdm-deim": 1.8,
                    "vdm-deim-nn": 1.9, "vdm": 2.3}  # fmt: skip
FRONT_END_COST: Final = 0.8


def mode_groups(modes: tuple[str, ...], jobs: int) -> list[tuple[str, ...]]:
    """The modes dealt to ``jobs`` processes so that the groups take about as long: costliest first, each to the
    group that would then finish first (the port modes of a group share one front end)."""
    from vdm_aero.nav.filter import MODES

    n = max(min(jobs, len(modes)), 1)
    groups: list[list[str]] = [[] for _ in range(n)]

    def load(g: list[str], extra: str | None = None) -> float:
        ms = [*g, extra] if extra else g
        ports = any(m in ("ports-airdata", "vdm-deim", "vdm-deim-nn", "vdm") for m in ms)
        return sum(MODE_COST.get(m, 2.0) for m in ms) + (FRONT_END_COST if ports else 0.0)

    for m in sorted(modes, key=lambda m: -MODE_COST.get(m, 2.0)):
        min(groups, key=lambda g: load(g, m)).append(m)
    return [tuple(sorted(g, key=list(MODES).index)) for g in groups if g]


@cache
def _load_models(design_data: Path | None, model: Path | None, vehicle: str | Path) -> tuple[Any, Any]:
    """(NavModels or None, the vehicle), once per process: a worker loads them while the parent reads the log."""
    from vdm_aero.nav.models import NavModels
    from vdm_aero.vehicle import load_vehicle

    models = NavModels.from_model(design_data, model, vehicle) if model is not None and design_data else None
    return models, models.vehicle if models is not None else load_vehicle(vehicle)


def _replay_group(log: Any, design_data: Path | None, model: Path | None, vehicle: str | Path,
                  modes: tuple[str, ...], outages: list[tuple[float, float]], mag: np.ndarray) -> Any:  # fmt: skip
    """One process's share of the modes."""
    from vdm_aero.nav.replay import replay_log

    models, veh = _load_models(design_data, model, vehicle)
    return replay_log(log, veh, models, modes=modes, outages=outages, mag_field_ned_ut=mag)


def parse_outage(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise UserInputError(f"--outage: expected START:END in seconds, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and b > a):
        raise UserInputError(f"--outage: expected START < END, got {text!r}")
    return a, b


def run_replay_cmd(args: argparse.Namespace) -> int:
    if args.update_golden:
        from vdm_aero_cli.replay_golden import update_golden

        path = update_golden(GOLDEN)
        print(f"wrote {path}: review the diff (git diff {path.relative_to(GOLDEN.parents[2])})")
        return 0
    if args.log is None:
        raise UserInputError("replay: give LOG (or --update-golden)")
    from vdm_aero.nav.filter import MODES

    modes = tuple(MODES)
    if args.modes:
        modes = tuple(m.strip() for m in args.modes.split(","))
        for m in modes:
            if m not in MODES:
                raise UserInputError(f"--modes: unknown mode {m!r}; known: {', '.join(MODES)}")
    if args.gnss_latency_s is not None and not 0.0 <= args.gnss_latency_s <= 0.5:
        raise UserInputError(f"--gnss-latency-s: {args.gnss_latency_s:g} is outside [0, 0.5] s")
    if args.jobs < 1:
        raise UserInputError(f"--jobs: must be ≥ 1, got {args.jobs}")
    if (args.model is None) != (args.design_data is None):
        raise UserInputError("--model and --design-data go together (the port front end needs both)")
    outages = [parse_outage(o) for o in args.outage]
    mag = np.array(_floats(args.mag_field, 3, "--mag-field")) if args.mag_field else None
    out = args.out or Path("out") / "replay" / args.log.stem
    doc = replay(args.log, model=args.model, design_data=args.design_data, vehicle=args.vehicle, outages=outages,
                 modes=modes, truth=args.truth, mag_field_ned_ut=mag, system_id=args.system_id, out=out,
                 jobs=args.jobs, gnss_latency_s=args.gnss_latency_s)  # fmt: skip
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        print((out / "replay.md").read_text())
        print(f"wrote {out}/replay.md, replay.json, replay-error.png, solution.csv")
    return 0


def replay(log_path: Path, *, model: Path | None, design_data: Path | None, vehicle: str | Path,
           outages: list[tuple[float, float]], modes: tuple[str, ...], truth: Path | None = None,
           mag_field_ned_ut: np.ndarray | None = None, system_id: int | None = None, out: Path,
           jobs: int = 1, gnss_latency_s: float | None = None) -> dict[str, Any]:  # fmt: skip
    """Read, replay, score and write the report; returns the JSON document."""
    from firmware_bridge.logs import read_log, read_truth_file
    from vdm_aero.geomagnetism import decimal_year, earth_field_ned_ut
    from vdm_aero.nav.replay import available_modes, merge_runs, replay_log
    from vdm_aero_cli.progress import progress_bar

    wall0, cpu0 = time.perf_counter(), time.process_time()
    workers = min(jobs, len(modes)) - 1
    # spawned, not forked: the parent holds onnxruntime sessions, whose thread pools do not survive a fork; the
    # workers start and load the models while the parent reads the log
    pool = ProcessPoolExecutor(workers, mp_context=get_context("spawn")) if workers > 0 else None
    try:
        warm = [pool.submit(_load_models, design_data, model, vehicle) for _ in range(workers)] if pool else []
        models, veh = _load_models(design_data, model, vehicle)
        names = models.port_names if models is not None else ()
        with progress_bar(f"reading {log_path.name}", 1000) as update:
            read = read_log(log_path, names, system_id=system_id, gnss_latency_s=gnss_latency_s,
                            progress=lambda f: update(int(1000 * f), 1000))  # fmt: skip
        wall_read = time.perf_counter() - wall0
        log, rep = read.log, read.report
        if len(log["imu_t_s"]) < 2:
            raise UserInputError(f"{log_path}: fewer than two IMU samples: nothing to navigate with")
        if not len(log["gnss_t_s"]):
            raise UserInputError(f"{log_path}: no 3-D GNSS fix: the filter has nothing to start from")
        gt = log["gnss_t_s"]
        if not outages:
            span = float(gt[-1] - gt[0])
            length = min(DEFAULT_OUTAGE_S, 0.25 * span)
            start = float(gt[0]) + 0.5 * span - 0.5 * length
            outages = [(round(start, 1), round(start + length, 1))]
        for a, b in outages:
            if b <= gt[0] or a >= gt[-1]:
                raise UserInputError(f"--outage {a:g}:{b:g}: outside the log's GNSS ({gt[0]:.1f} … {gt[-1]:.1f} s)")
        run_modes, skipped = available_modes(modes, log, models)
        if not run_modes:
            why = "; ".join(skipped.values())
            raise UserInputError(f"{log_path}: none of the modes {', '.join(modes)} can run ({why})")
        if mag_field_ned_ut is not None:
            mag, mag_source = mag_field_ned_ut, "given (--mag-field)"
        else:
            year = decimal_year(read.unix_time_at_boot_s + float(gt[0])) if read.unix_time_at_boot_s else None
            if year is None:
                year = decimal_year(time.time())
                rep.warn(f"{log_path.name}: the log has no UTC time: the magnetic field is the WMM's for today")
            mag, mag_source = earth_field_ned_ut(float(log["gnss_lat_deg"][0]), float(log["gnss_lon_deg"][0]),
                                                 float(log["gnss_alt_m"][0]), year)  # fmt: skip
        for w in rep.warnings:
            print(f"vdm-aero replay: warning: {w}", file=sys.stderr)
        for m, why in skipped.items():
            print(f"vdm-aero replay: {m} not run: {why}", file=sys.stderr)
        with progress_bar(f"replaying {len(run_modes)} modes", 1000) as update:
            cpu1 = time.process_time()
            groups = mode_groups(run_modes, workers + 1)
            futs = [pool.submit(_replay_group, log, design_data, model, vehicle, g, outages, mag)  # type: ignore[union-attr]
                    for g in groups[1:]]  # fmt: skip
            runs = [replay_log(log, veh, models, modes=groups[0], outages=outages, mag_field_ned_ut=mag,
                               progress=lambda f: update(int(1000 * f), 1000))]  # fmt: skip
            runs += [f.result() for f in futs]
            run = merge_runs(runs, run_modes)
            cpu_filters = time.process_time() - cpu1
        del warm
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    truth_track = read_truth_file(truth) if truth is not None else read.truth
    from vdm_aero_cli.replay_report import reference_of, write_replay_report

    ref = reference_of(log, truth_track, run.origin)
    wall = time.perf_counter() - wall0
    speed = {"flight_s": log.duration_s, "wall_s": wall, "read_wall_s": wall_read,
             "cpu_s": time.process_time() - cpu0, "filters_cpu_s": cpu_filters,
             "x_real_time": log.duration_s / max(wall, 1e-9), "modes": len(run_modes),
             "imu_rate_hz": log.meta["rates_hz"]["imu"]}  # fmt: skip
    return write_replay_report(out, log, rep, run, ref, skipped=skipped, speed=speed, mag=(mag, mag_source),
                               models={"model": str(model) if model else None,
                                       "design_data": str(design_data) if design_data else None,
                                       "vehicle": veh.name})  # fmt: skip
