"""The golden replay: a short mock-autopilot flight with a GNSS outage, replayed through every mode that needs
no trained net, its navigation history committed as a small CSV (tests/golden/replay-survey.csv).

As PX4's ECL replays a recorded flight in CI: any numerical change to the readers, the filter or the models
shows up as a diff of that file, reviewed and regenerated on purpose with ``vdm-aero replay --update-golden``.
The flight is regenerated from its seed (the world and the mock are deterministic), never committed.
"""

from __future__ import annotations

import csv
import math
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np

from firmware_bridge.config import DEFAULT_STREAMS

__all__ = ["GOLDEN_COLUMNS", "TOLERANCES", "build_design_models", "fly_golden", "golden_rows", "update_golden"]

SCENARIO: Final = "survey"
SEED: Final = 0
FLIGHT_S: Final = 100.0
OUTAGE_S: Final = (60.0, 80.0)
MODES: Final = ("ins", "airspeed-dr", "ports-airdata", "vdm-classic", "vdm-deim")
EVERY_S: Final = 2.0  # decimation of the committed history: 5 modes × ~50 rows
UNIX_TIME_AT_BOOT_S: Final = 1.8e9  # a fixed SYSTEM_TIME epoch, so the tlog is the same bytes on every run
STREAMS: Final = dict(DEFAULT_STREAMS["ardupilot"])
"""What the service asks ArduPilot for (deploy/config.yaml's ``streams: auto``)."""
LOOP_RATE_HZ: Final = 400.0  # SCHED_LOOP_RATE raised from ArduPlane's 50 Hz, as docs/service.md asks
GOLDEN_COLUMNS: Final = ("mode", "t_s", "n_m", "e_m", "d_m", "vn_m_s", "ve_m_s", "vd_m_s", "roll_deg", "pitch_deg",
                         "yaw_deg", "sigma_h_m")  # fmt: skip
TOLERANCES: Final = {"position_m": 0.01, "velocity_m_s": 0.002, "attitude_deg": 0.01, "sigma_h_m": 0.005}
"""How far a replay may stray from the golden history and still be the same numerics: rounding in BLAS and
libm differs between machines by ~1e-12 and grows through the filter to well below these."""


def build_design_models(root: Path) -> dict[str, Path]:
    """The design data set of the reference UAV (``uav-envelope``) and DEIM on 12 ports fitted on its training
    cases: {"data", "model"} (a minute; the tests build the same once per session)."""
    from vdm_aero.dataset import load_dataset
    from vdm_aero.pipeline import fit_model
    from vdm_aero_cli.cmd_data import simulate_to
    from vdm_aero_cli.paper import case_roles

    ds_dir = simulate_to("uav-envelope", root / "env", quiet=True)
    ds = load_dataset(ds_dir)
    model_dir = root / "deim12"
    fit_model(ds, model_dir, n_sensors=12, cases=case_roles(ds)["train"])
    return {"data": ds_dir, "model": model_dir}


def fly_golden(work: Path, deim_dir: Path) -> dict[str, Any]:
    """The golden flight by the mock autopilot with a ground station recording: {"tlog", "truth", "mag"}."""
    from sim.flight.sensors import TimeWindow
    from sim.flight.world import FlightWorld
    from sim.sitl.autopilot import AutopilotOptions, run_sitl
    from vdm_aero_cli.nav_bench import bench_scenario

    sc, meta, _ = bench_scenario(SCENARIO, SEED, deim_dir, FLIGHT_S)
    sc = replace(sc, gnss=replace(sc.gnss, outages=(TimeWindow(*OUTAGE_S),)), duration_s=FLIGHT_S)
    work.mkdir(parents=True, exist_ok=True)
    tlog, truth = work / "golden.tlog", work / "golden-truth.npz"
    run_sitl(FlightWorld(sc), "null", speed=math.inf, duration_s=FLIGHT_S, tlog=tlog, truth=truth,
             stream_rates=STREAMS, options=AutopilotOptions(gcs_recording=True, loop_rate_hz=LOOP_RATE_HZ,
                                                            unix_time_at_boot_s=UNIX_TIME_AT_BOOT_S))  # fmt: skip
    return {"tlog": tlog, "truth": truth, "mag": np.asarray(meta["mag_field_ned_t"]) * 1e6}


def golden_rows(tlog: Path, design_data: Path, deim_dir: Path, mag_field_ned_ut: np.ndarray) -> list[list[Any]]:
    """Replay the golden tlog (one process) and decimate the history to :data:`EVERY_S`."""
    from firmware_bridge.logs import read_log
    from vdm_aero.nav.models import NavModels
    from vdm_aero.nav.replay import RECORD_HZ, replay_log, sigma_h_m
    from vdm_aero.rotation import euler_from_quat

    models = NavModels.from_model(design_data, deim_dir)
    log = read_log(tlog, models.port_names).log
    run = replay_log(log, models.vehicle, models, modes=MODES, outages=[OUTAGE_S], mag_field_ned_ut=mag_field_ned_ut)
    rows = []
    every = round(EVERY_S * RECORD_HZ)
    for m in MODES:
        for t, p, v, q, _, cov, _, _ in run.rows[m][::every]:
            att = [math.degrees(a) for a in euler_from_quat(q)]
            rows.append([m, round(t, 3), *map(float, p), *map(float, v), *att, sigma_h_m(cov)])
    return rows


def read_golden(path: Path) -> list[list[Any]]:
    with path.open() as f:
        body = [r for r in csv.reader(line for line in f if not line.startswith("#"))]
    if not body or tuple(body[0]) != GOLDEN_COLUMNS:
        raise ValueError(f"{path}: header is not {GOLDEN_COLUMNS}")
    return [[r[0], *map(float, r[1:])] for r in body[1:]]


def write_golden(path: Path, rows: list[list[Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        f.write(f"# golden replay: {SCENARIO} seed {SEED}, {FLIGHT_S:g} s by the mock autopilot, GNSS outage "
                f"{OUTAGE_S[0]:g}-{OUTAGE_S[1]:g} s; regenerate with `vdm-aero replay --update-golden`\n")  # fmt: skip
        w = csv.writer(f)
        w.writerow(GOLDEN_COLUMNS)
        for r in rows:
            w.writerow([r[0], f"{r[1]:.3f}", *(f"{v:.6f}" for v in r[2:])])


def update_golden(path: Path) -> Path:
    """Build the design models, fly the golden flight, replay it and write ``path``."""
    with tempfile.TemporaryDirectory(prefix="vdm-aero-golden-") as tmp:
        root = Path(tmp)
        design = build_design_models(root / "design")
        flight = fly_golden(root / "flight", design["model"])
        write_golden(path, golden_rows(flight["tlog"], design["data"], design["model"], flight["mag"]))
    return path
