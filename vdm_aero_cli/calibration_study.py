"""The as-built study: design-data DEIM against the built aircraft, and the in-flight calibration.

1. Simulate the design data set (``uav-envelope``), fit DEIM on its training cases and train the
   design-data correction net (train/validation cases).
2. Fly the as-built aircraft with the model's ports: the calibration flight and the test flights (other
   routes, winds, turbulence seeds and manoeuvres).
3. Calibrate the correction net on the first 2, 5 and 10 minutes of the calibration flight
   (:mod:`vdm_aero.calibrate`, sensors and the nominal vehicle description only).
4. On the test flights, the ℓ2 error of every coefficient against the as-built truth for DEIM, DEIM+NN
   (design data), DEIM+NN calibrated, and two baselines trained on the same calibration targets: a
   direct linear regression and a direct MLP from the same ports.

Only step 4 reads the truth files (evaluation), and only the world (step 2) knows the as-built model.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero._typing import COEFF_NAMES, F64Array
from vdm_aero.calibrate import (
    TargetSettings,
    apply_linear,
    calibrate_model,
    estimate_nuisance,
    form_targets,
    linear_baseline,
    time_block_split,
)
from vdm_aero.dataset import load_dataset
from vdm_aero.flightlog import SensorLog, load_sensor_log, load_truth
from vdm_aero.model import AeroModel
from vdm_aero.nav.design_fit import DesignFlightData, PortPressureModel
from vdm_aero.vehicle import VehicleDescription, load_vehicle

TEST_SCENARIOS = ("asbuilt-survey-test", "asbuilt-loiter-test", "asbuilt-cruise-test")
# outside the calibration flight's envelope (higher α and load, sideslip, other speeds): where a physics prior
# should extrapolate better than a regression fitted inside it
ENVELOPE_SCENARIOS = ("asbuilt-envelope-test",)
CALIBRATION_SCENARIO = "calibration-asbuilt"
CALIBRATION_START_S = 20.0  # the first cycle starts after 20 s of trimmed flight


def l2_errors(pred: F64Array, truth: F64Array) -> dict[str, float]:
    """Relative ℓ2 error ‖ŷ − y‖/‖y‖ per coefficient (the method's metric, :mod:`vdm_aero.evaluation`)."""
    return {
        name: float(np.linalg.norm(pred[:, i] - truth[:, i]) / np.linalg.norm(truth[:, i]))
        for i, name in enumerate(COEFF_NAMES)
    }


def design_models(
    out: Path, n_sensors: int, *, grid: str, seed: int, max_epochs: int, data_dir: Path | None = None
) -> tuple[Path, Path, dict[str, Any]]:
    """(DEIM model dir, DEIM+NN design-data model dir, held-out design-data errors)."""
    from vdm_aero.pipeline import fit_model, ports_and_truth, train_model
    from vdm_aero_cli.cmd_data import simulate_to
    from vdm_aero_cli.paper import case_roles

    ds_dir = data_dir or out / "data" / "uav-envelope"
    if not (ds_dir / "dataset.yaml").is_file():
        simulate_to("uav-envelope", ds_dir)
    ds = load_dataset(ds_dir)
    roles = case_roles(ds)
    deim_dir = out / "models" / f"deim{n_sensors}"
    fit_model(ds, deim_dir, n_sensors=n_sensors, cases=roles["train"])
    nn_dir = out / "models" / f"deim{n_sensors}-design-nn"
    if nn_dir.exists():
        shutil.rmtree(nn_dir)
    shutil.copytree(deim_dir, nn_dir)
    train_model(nn_dir, ds, train_cases=roles["train"], val_cases=roles["validation"], grid=grid, seed=seed,
                max_epochs=max_epochs)  # fmt: skip
    deim, nn = AeroModel.load(deim_dir), AeroModel.load(nn_dir)
    x, truth, _ = ports_and_truth(deim, ds, roles["test"])
    held_out = {
        "deim": l2_errors(deim.predict_batch(x, linear_only=True), truth),
        "deim_nn": l2_errors(nn.predict_batch(x), truth),
        "cases": roles["test"],
        "snapshots": len(x),
    }
    return deim_dir, nn_dir, held_out


def fly_flights(
    out: Path, model_dir: Path, calibration_s: float, test_s: float | None
) -> tuple[Path, list[Path], list[Path]]:
    """Fly the calibration flight, the test flights and the test flights outside the calibration envelope of
    the as-built aircraft with the model's ports."""
    from sim.flight.record import record_flight, with_model_ports
    from sim.flight.scenario import load_scenario
    from sim.flight.world import Vehicle

    vehicle = None
    logs = []
    flights = [(CALIBRATION_SCENARIO, calibration_s)] + [(n, test_s) for n in TEST_SCENARIOS + ENVELOPE_SCENARIOS]
    for name, dur in flights:
        sc = with_model_ports(load_scenario(name), model_dir)
        if vehicle is None:
            vehicle = Vehicle.build(sc.vehicle, sc.as_built_effects)
        logs.append(record_flight(sc, out / "flights" / name, vehicle, duration_s=dur))
    return logs[0], logs[1 : 1 + len(TEST_SCENARIOS)], logs[1 + len(TEST_SCENARIOS) :]


def _test_inputs(
    logs: Sequence[Path],
    vehicle: VehicleDescription,
    model: AeroModel,
    pressure: PortPressureModel,
    settings: TargetSettings,
) -> tuple[F64Array, F64Array]:
    """Port Cp (the ports' q̄, as at run time) at the target times of every test flight, and the truth
    coefficients there."""
    xs, ys = [], []
    for p in logs:
        data = form_targets(load_sensor_log(p), vehicle, model, pressure, settings)
        truth = load_truth(p)
        idx = np.searchsorted(truth["t_s"], data.t_s)
        if not np.allclose(truth["t_s"][idx], data.t_s, atol=1e-9):
            raise RuntimeError(f"{p}: truth and port times differ")
        xs.append(data.cp)
        ys.append(truth["coeffs"][idx])
    return np.vstack(xs), np.vstack(ys)


def _mlp_baseline(data_x: F64Array, y: F64Array, t_s: F64Array, *, grid: str, seed: int, max_epochs: int) -> Any:
    from vdm_aero.train_correction import GRIDS, grid_search

    tr, va = time_block_split(t_s)
    best, _ = grid_search(GRIDS[grid], data_x[tr], y[tr], data_x[va], y[va], seed=seed, max_epochs=max_epochs)
    return best.net


def _torch_predict(net: Any, x: F64Array) -> F64Array:
    import torch

    with torch.no_grad():
        return np.asarray(net(torch.tensor(x, dtype=torch.float32)).numpy(), dtype=np.float64)


def run_study(
    out: Path,
    *,
    n_sensors: int = 12,
    calibration_minutes: Sequence[float] = (2.0, 5.0, 10.0),
    test_duration_s: float | None = None,
    grid: str = "quick",
    seed: int = 0,
    max_epochs: int = 3000,
    settings: TargetSettings | None = None,
    data_dir: Path | None = None,
) -> dict[str, Any]:
    """The whole study (module docstring); writes ``out``/calibration.json, .md and the length plot."""
    st = settings or TargetSettings(rate_hz=10.0)
    out.mkdir(parents=True, exist_ok=True)
    deim_dir, nn_dir, held_out = design_models(
        out, n_sensors, grid=grid, seed=seed, max_epochs=max_epochs, data_dir=data_dir
    )
    longest = max(calibration_minutes)
    calib_log, test_logs, env_logs = fly_flights(out, deim_dir, CALIBRATION_START_S + 60.0 * longest, test_duration_s)
    vehicle = load_vehicle("uav-2m")
    deim = AeroModel.load(deim_dir)
    design_nn = AeroModel.load(nn_dir)
    ds_dir = data_dir or out / "data" / "uav-envelope"
    pressure = PortPressureModel.fit(DesignFlightData.load(ds_dir, deim.port_names))
    x_test, y_test = _test_inputs(test_logs, vehicle, deim, pressure, st)
    x_env, y_env = _test_inputs(env_logs, vehicle, deim, pressure, st)
    predict: dict[str, Any] = {
        "deim": lambda x: deim.predict_batch(x, linear_only=True),
        "deim_nn_design": design_nn.predict_batch,
    }
    full = load_sensor_log(calib_log)
    lengths: dict[str, dict[str, Any]] = {}
    for minutes in calibration_minutes:
        log = full.window(0.0, CALIBRATION_START_S + 60.0 * minutes)
        mdir = out / "models" / f"deim{n_sensors}-calibrated-{minutes:g}min"
        summary = calibrate_model(deim_dir, log, vehicle, mdir, design_data=ds_dir, grid=grid, seed=seed,
                                  max_epochs=max_epochs,
                                  settings=st)  # fmt: skip
        err = l2_errors(AeroModel.load(mdir).predict_batch(x_test), y_test)
        lengths[f"{minutes:g}"] = {"l2": err, "nuisance": summary["nuisance"], "samples": summary["flight"]["samples"]}
    predict["deim_nn_calibrated"] = AeroModel.load(
        out / "models" / f"deim{n_sensors}-calibrated-{longest:g}min"
    ).predict_batch
    # baselines on the same (longest) calibration targets
    log = full.window(0.0, CALIBRATION_START_S + 60.0 * longest)
    data = form_targets(log, vehicle, deim, pressure, st)
    targets = estimate_nuisance(data, deim).targets(data)
    linear = linear_baseline(data.cp, targets)
    predict["linear_regression"] = lambda x: apply_linear(linear, x)
    mlp = _mlp_baseline(data.cp, targets, data.t_s, grid=grid, seed=seed, max_epochs=max_epochs)
    predict["mlp"] = lambda x: _torch_predict(mlp, x)
    rows = {k: l2_errors(f(x_test), y_test) for k, f in predict.items()}
    envelope = {k: l2_errors(f(x_env), y_env) for k, f in predict.items()}
    # the gap: design DEIM on the built aircraft against design DEIM on held-out design data
    gap = {c: rows["deim"][c] / held_out["deim"][c] for c in COEFF_NAMES}
    doc = {
        "n_sensors": n_sensors,
        "ports": list(deim.port_names),
        "held_out_design": held_out,
        "test_flights": [str(p) for p in test_logs],
        "test_samples": len(x_test),
        "calibration_flight": str(calib_log),
        "test_l2": rows,
        "envelope_flights": [str(p) for p in env_logs],
        "envelope_samples": len(x_env),
        "envelope_l2": envelope,
        "calibration_length": lengths,
        "gap_ratio": gap,
        "target_rate_hz": st.rate_hz,
        "grid": grid,
        "max_epochs": max_epochs,
    }
    (out / "calibration.json").write_text(json.dumps(doc, indent=2))
    (out / "calibration.md").write_text(format_tables(doc))
    plot_length(doc, out / "calibration-length.png")
    return doc


def format_tables(doc: dict[str, Any]) -> str:
    """Markdown: the gap, the per-method test-flight errors and the calibration-length figures."""
    names = list(COEFF_NAMES)
    ho = doc["held_out_design"]
    lines = [
        f"## The gap: design-data DEIM (n_s = {doc['n_sensors']}), relative ℓ2",
        "",
        "| data | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
        "| held-out design data | " + " | ".join(f"{ho['deim'][c]:.3g}" for c in names) + " |",
        "| as-built test flights | " + " | ".join(f"{doc['test_l2']['deim'][c]:.3g}" for c in names) + " |",
        "| ratio | " + " | ".join(f"{doc['gap_ratio'][c]:.1f}×" for c in names) + " |",
        "",
        f"## As-built test flights ({doc['test_samples']} samples), relative ℓ2 against the truth",
        "",
        "| model | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    labels = {
        "deim": "DEIM (design data)",
        "deim_nn_design": "DEIM+NN (net on design data)",
        "deim_nn_calibrated": "DEIM+NN calibrated in flight",
        "linear_regression": "linear regression (calibration flight)",
        "mlp": "MLP (calibration flight)",
    }
    for k, label in labels.items():
        lines.append(f"| {label} | " + " | ".join(f"{doc['test_l2'][k][c]:.3g}" for c in names) + " |")
    d, c = doc["test_l2"]["deim"], doc["test_l2"]["deim_nn_calibrated"]
    lines += [
        "| DEIM / calibrated | " + " | ".join(f"{d[n] / c[n]:.1f}×" for n in names) + " |",
        "",
        f"## Outside the calibration envelope ({doc['envelope_samples']} samples: tight loiter at the bank limit, "
        "12 m/s and a commanded 29 m/s, 10° pitch and 14° yaw doublets), relative ℓ2",
        "",
        "| model | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for k, label in labels.items():
        lines.append(f"| {label} | " + " | ".join(f"{doc['envelope_l2'][k][c]:.3g}" for c in names) + " |")
    lines += [
        "",
        "## Calibrated DEIM+NN against calibration-flight length (manoeuvre time, minutes)",
        "",
        "| minutes | samples | " + " | ".join(names) + " | thrust factors | accel bias [m/s²] |",
        "|---" * (len(names) + 4) + "|",
    ]
    for m, r in doc["calibration_length"].items():
        nu = r["nuisance"]
        tf = ", ".join(f"{v:.3f}" for v in nu["thrust_factors"])
        ab = ", ".join(f"{v:+.3f}" for v in nu["accel_bias_b_m_s2"])
        lines.append(
            f"| {m} | {r['samples']} | " + " | ".join(f"{r['l2'][n]:.3g}" for n in names) + f" | {tf} | {ab} |"
        )
    return "\n".join(lines) + "\n"


def plot_length(doc: dict[str, Any], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mins = [float(m) for m in doc["calibration_length"]]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for c in COEFF_NAMES:
        ys = [doc["calibration_length"][m]["l2"][c] for m in doc["calibration_length"]]
        line = ax.plot(mins, ys, "o-", label=c)[0]
        ax.axhline(doc["test_l2"]["deim"][c], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("calibration flight [min of manoeuvres]")
    ax.set_ylabel("test-flight relative ℓ2 error")
    ax.set_yscale("log")
    ax.set_title("calibrated DEIM+NN (solid) vs DEIM on design data (dotted)")
    ax.legend(ncol=3, fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def mean_ratio(doc: dict[str, Any], a: str, b: str, coeffs: Sequence[str]) -> float:
    """Geometric mean over ``coeffs`` of error(a)/error(b) on the test flights."""
    r = [doc["test_l2"][a][c] / doc["test_l2"][b][c] for c in coeffs]
    return float(math.exp(np.mean(np.log(r))))


__all__ = ["format_tables", "l2_errors", "mean_ratio", "plot_length", "run_study"]
_ = SensorLog
