"""``bench``: latency and scale benchmarks (medians; ratios are what to compare across machines)."""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero.errors import UserInputError


def register(sub: Any) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks: aero (run-time latency), deim-select, fit-scale, nav-drift",
        description="aero: median single-sample latency of the run-time path (10 ports, 4x40 net); "
        "deim-select: DEIM over 300,000 candidates x 15 modes; fit-scale: POD + DEIM on a memory-mapped "
        "float32 snapshot set of --points x --snapshots (written to a temporary directory first, not timed); "
        "nav-drift: GNSS-outage drift of every navigation mode on the as-built aircraft (docs/navigation.md).",
    )
    p.add_argument("which", choices=("aero", "deim-select", "fit-scale", "nav-drift"))
    p.add_argument("--points", type=int, default=300_000, help="fit-scale: surface points N")
    p.add_argument("--snapshots", type=int, default=2_000, help="fit-scale: snapshots M")
    p.add_argument("--method", choices=("snapshots", "randomized"), default="snapshots", help="fit-scale: POD route")
    p.add_argument(
        "--workdir", type=Path, help="fit-scale: where to write the synthetic data set (default: a temp dir)"
    )
    p.add_argument("--json", action="store_true", help="print JSON only")
    p.add_argument("--ports", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    n = p.add_argument_group("nav-drift")
    n.add_argument("--scenario", default="survey", help="comma-separated: survey, wind-shear, loiter, no-airspeed, "
                   "pitot-blocked, pitot-icing, pitot-water, ports-blocked, manoeuvring, survey-calm, "
                   "rtl-wind-gradient, payload-release, link-bursts, or all")  # fmt: skip
    n.add_argument("--world", choices=("harsh", "kind"), default="harsh",
                   help="harsh (default): every sourced sensor, Earth and fleet effect, reported beside the kind "
                   "world in one run, with the cost-per-effect table; kind: the earlier, ideal world "
                   "alone")  # fmt: skip
    n.add_argument("--cost-seeds", type=int, default=5, help="harsh: seeds per effect of the cost table (0: none)")
    n.add_argument("--without", default="", metavar="EFFECTS",
                   help="harsh: comma-separated effects to switch off (docs/flight-sim.md lists them)")  # fmt: skip
    n.add_argument("--seeds", type=int, default=20, help="seeds per scenario")
    n.add_argument("--outage-s", default="30,60,120,300", help="outage lengths [s], comma-separated")
    n.add_argument("--modes", default="all", help="comma-separated navigation modes (default all), or the "
                   "ablations vdm-no-force, vdm-no-net, vdm-no-pitot, vdm-no-deviation, vdm-no-gradient, "
                   "vdm-no-gyro-scale, vdm-no-accel-scale, vdm-no-compass-check, vdm-no-throttle-range, "
                   "vdm-no-aided-fit, vdm-no-rewind")  # fmt: skip
    n.add_argument("--out", type=Path, default=Path("out/bench/nav-drift"), help="report directory")
    n.add_argument("--models", type=Path, help="directory with data/uav-envelope and models/ (default: built in --out)")
    n.add_argument("--calibration-minutes", type=float, default=10.0, help="in-flight calibration length [min]")
    n.add_argument("--jobs", type=int, help="local worker processes (default: one per core)")
    n.add_argument("--dask", metavar="ADDRESS", help="run the seeds on a dask.distributed scheduler instead")
    p.set_defaults(func=run_bench)


def _per_call_us(fn: Callable[[], Any], *, calls: int = 1000, batches: int = 30) -> float:
    """Median over batches of the mean time of one call [µs] (batched to keep timer overhead out)."""
    for _ in range(calls):
        fn()
    per = []
    for _ in range(batches):
        t0 = time.perf_counter_ns()
        for _ in range(calls):
            fn()
        per.append((time.perf_counter_ns() - t0) / calls / 1000.0)
    return statistics.median(per)


def bench_aero(n_ports: int = 10, seed: int = 0) -> dict[str, Any]:
    """Latency of AeroModel.predict for DEIM only and DEIM + a 4 × 40 ReLU net."""
    from vdm_aero.dataset import Reference
    from vdm_aero.model import AeroModel, LinearModel
    from vdm_aero.ports import Port

    try:
        from vdm_aero.train_correction import CorrectionNet, NetConfig, export_onnx
    except ImportError:
        raise UserInputError("bench aero builds its test net with PyTorch: install the 'train' extra") from None
    rng = np.random.default_rng(seed)
    n = n_ports
    linear = LinearModel(
        Us=rng.standard_normal((n, n)), mean_s=rng.standard_normal(n), SU=rng.standard_normal((6, n)),
        Smean=rng.standard_normal(6),
    )  # fmt: skip
    net = CorrectionNet(NetConfig(4, 40, 1e-6), np.zeros(n), np.ones(n), np.zeros(6), np.ones(6))
    ports = tuple(Port(f"p{i}", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)) for i in range(n))
    x = rng.standard_normal(n)
    with tempfile.TemporaryDirectory() as d:
        onnx_path = Path(d) / "net.onnx"
        onnx_path.write_bytes(export_onnx(net, n))
        ref = Reference(1.0, 1.0, 1.0)
        deim = AeroModel(linear=linear, ports=ports, reference=ref, meta={})
        full = AeroModel(linear=linear, ports=ports, reference=ref, meta={}, net_path=onnx_path)
        corr = full._net
        assert corr is not None
        timings = {
            "deim_predict_us": _per_call_us(lambda: deim.predict(x)),
            "deim_nn_predict_us": _per_call_us(lambda: full.predict(x)),
            "onnx_iobinding_us": _per_call_us(lambda: corr.predict_one(x)),
            "onnx_run_us": _per_call_us(lambda: corr.predict_one_run(x)),
            "batch_1000_per_sample_us": _per_call_us(lambda: full.predict_batch(np.tile(x, (1000, 1))), calls=5) / 1000,
        }
    res: dict[str, Any] = {k: round(v, 3) for k, v in timings.items()}
    res.update({"ports": n, "net": "4x40 ReLU", "target_deim_nn_us": 10.0, "method_reference_us": 81.0})
    return res


def bench_deim_select(seed: int = 0) -> dict[str, Any]:
    from vdm_aero.deim import deim_indices

    rng = np.random.default_rng(seed)
    u, _ = np.linalg.qr(rng.standard_normal((300_000, 15)))
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        deim_indices(u)
        times.append(time.perf_counter() - t0)
    return {
        "candidates": 300_000,
        "modes": 15,
        "median_seconds": round(statistics.median(times), 4),
        "bar_seconds": 2.0,
    }


def _list(text: str, known: Sequence[str], what: str) -> tuple[str, ...]:
    items = tuple(known) if text == "all" else tuple(x.strip() for x in text.split(",") if x.strip())
    bad = [x for x in items if x not in known]
    if bad or not items:
        raise UserInputError(f"bench nav-drift: --{what}: unknown {bad or text!r} (known: {', '.join(known)}, all)")
    return items


def run_nav_drift_cli(args: argparse.Namespace) -> int:
    from vdm_aero.nav.filter import ABLATIONS, MODES
    from vdm_aero_cli.nav_bench import (
        SCENARIOS,
        BenchSpec,
        NavArtifacts,
        _units,
        build_artifacts,
        run_nav_drift,
        write_report,
    )
    from vdm_aero_cli.progress import progress_bar

    try:
        outages = tuple(float(x) for x in args.outage_s.split(","))
    except ValueError:
        raise UserInputError(f"bench nav-drift: --outage-s: {args.outage_s!r} is not a list of seconds") from None
    if not outages or min(outages) <= 0.0 or max(outages) > 600.0:
        raise UserInputError("bench nav-drift: --outage-s: each outage must be in (0, 600] s")
    if args.seeds < 1:
        raise UserInputError("bench nav-drift: --seeds must be at least 1")
    scenarios = _list(args.scenario, list(SCENARIOS), "scenario")
    modes = tuple(MODES) if args.modes == "all" else _list(args.modes, [*MODES, *ABLATIONS], "modes")
    if args.cost_seeds < 0:
        raise UserInputError("bench nav-drift: --cost-seeds must be at least 0")
    harsh = "harsh"
    if args.without:
        from sim.flight.world_effects import WORLD_EFFECTS

        off = _list(args.without, list(WORLD_EFFECTS), "without")
        harsh = "harsh-without:" + "+".join(off)
    worlds = (harsh, "kind") if args.world == "harsh" else ("kind",)
    spec = BenchSpec(scenarios=scenarios, seeds=args.seeds, outages_s=outages, modes=modes, first_seed=args.seed,
                     worlds=worlds, cost_seeds=args.cost_seeds if args.world == "harsh" else 0)  # fmt: skip
    root = args.models or args.out
    if args.models is not None:
        art = NavArtifacts.under(root, args.calibration_minutes)
        for p in (art.dataset_dir / "dataset.yaml", art.deim_dir / "model.yaml", art.nn_dir / "model.yaml"):
            if not p.is_file():
                raise UserInputError(f"bench nav-drift: --models: {p} missing (run once without --models to build it)")
        from vdm_aero.model import AeroModel

        for d in (art.deim_dir, art.nn_dir):
            AeroModel.load(d)  # a model this version refuses fails now, not after the fleet's calibrations
    # --json: stdout carries the JSON alone; what the building steps print goes to stderr
    with contextlib.redirect_stdout(sys.stderr) if args.json else contextlib.nullcontext():
        if args.models is None:
            say = lambda s: print(f"building: {s}", flush=True)  # noqa: E731
            art = build_artifacts(root, calibration_minutes=args.calibration_minutes, progress=say)
        n_units = len(_units(spec))
        with progress_bar("nav-drift", n_units) as update:
            doc = run_nav_drift(spec, art, jobs=args.jobs, dask_address=args.dask, progress=update)
        paths = write_report(doc, args.out)
    if args.json:
        print(json.dumps({k: doc[k] for k in ("summary", "ins_theory", "wind_hold", "wall_s")}))
    else:
        print(paths["markdown"].read_text())
        print(f"report: {paths['markdown']}  json: {paths['json']}  wall {doc['wall_s']:.0f} s")
    return 0


def run_bench(args: argparse.Namespace) -> int:
    if args.which == "nav-drift":
        return run_nav_drift_cli(args)
    if args.which == "aero":
        res = bench_aero(args.ports, args.seed)
    elif args.which == "deim-select":
        res = bench_deim_select(args.seed)
    else:
        from vdm_aero.fit_scale import bench_fit_scale

        try:
            res = bench_fit_scale(args.points, args.snapshots, workdir=args.workdir, seed=args.seed, method=args.method)
        except ValueError as e:
            raise UserInputError(f"bench fit-scale: {e}") from None
        res = {k: v for k, v in res.items() if k not in ("sensors", "lines")}
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:28} {v}")
    return 0
