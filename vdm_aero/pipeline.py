"""Fit → train → evaluate on data sets: the offline workflow behind ``vdm-aero fit/train/evaluate``.

Fitting and evaluating need numpy only; training the correction net or the MLP baseline imports
:mod:`vdm_aero.train_correction` (torch) when called.

Baselines (:func:`fit_baselines`): a direct linear regression and a direct MLP from the same ports to the
coefficients, trained on the correction net's training cases (the MLP with its grid, seed, epoch budget and
validation cases), so every evaluation can say what DEIM and its net add over fitting the ports directly.
"""

from __future__ import annotations

import hashlib
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.dataset import Dataset
from vdm_aero.deim import DEIMForceModel
from vdm_aero.errors import UserInputError
from vdm_aero.evaluation import (
    add_port_noise,
    lift_drag_errors,
    linear_noise_floor,
    merge_methods,
    noise_amplification,
    port_noise_std,
)
from vdm_aero.model import AeroModel, LinearModel, load_diagnostics, read_model_yaml, write_model
from vdm_aero.pod import projection_error
from vdm_aero.ports import Port, candidates_nearest, match_ports

if TYPE_CHECKING:
    from vdm_aero.onnx_net import OnnxCorrection

PORT_TOLERANCE_CHORD = 0.01  # ports match data-set points within 1 % of the reference chord
MAX_DIAGNOSTIC_MODES = 30


def fit_model(
    ds: Dataset,
    out: Path,
    *,
    n_sensors: int,
    n_modes: int | None = None,
    method: str = "deim",
    cases: Sequence[int] | None = None,
    candidates_from: Dataset | None = None,
) -> AeroModel:
    """POD + DEIM on ``ds`` (optionally only ``cases``); writes the model directory ``out``."""
    if cases is not None:
        ds = ds.select_cases(cases)
    candidates = None
    if candidates_from is not None:
        candidates = candidates_nearest(ds.points, candidates_from.points)
        if len(candidates) < n_sensors:
            raise UserInputError(
                f"--candidates-from {candidates_from.name}: only {len(candidates)} distinct candidate points "
                f"for {n_sensors} sensors"
            )
    if not 1 <= n_sensors <= ds.n_points:
        raise UserInputError(f"--sensors: must be between 1 and {ds.n_points} (points of {ds.name})")
    if n_modes is not None and not 1 <= n_modes <= min(n_sensors, ds.n_snapshots):
        raise UserInputError(
            f"--modes: must be between 1 and min(--sensors, snapshots) = {min(n_sensors, ds.n_snapshots)}"
        )
    S = ds.force_matrix()
    est = DEIMForceModel(n_sensors=n_sensors, n_modes=n_modes, method=method, candidates=candidates)
    est.fit(ds.cp, S)
    sensors = np.asarray(est.sensors_, dtype=np.int64)
    m_snap = ds.n_snapshots
    pod = est.pod_
    kept = float(np.sum(np.asarray(est.singular_values_, dtype=np.float64) ** 2))
    linear = LinearModel(
        Us=np.asarray(est.port_modes_, dtype=np.float64),
        mean_s=np.asarray(est.mean_, dtype=np.float64)[sensors],
        SU=np.asarray(est.force_modes_, dtype=np.float64),
        Smean=np.asarray(est.force_mean_, dtype=np.float64),
        mode_std=np.asarray(est.singular_values_, dtype=np.float64) / np.sqrt(m_snap),
        tail_var=max(float(pod.total_energy) - kept, 0.0) / (m_snap * ds.n_points),
    )
    # diagnostics: scaled singular values and projection error vs n_b from a wider basis
    from vdm_aero.pod import pod_basis

    k = min(MAX_DIAGNOSTIC_MODES, ds.n_snapshots, ds.n_points)
    wide = pod_basis(ds.cp, k, rng=np.random.default_rng(0))
    nb = np.arange(1, k + 1)
    eps = projection_error(ds.cp, wide, nb)
    ports = tuple(Port(ds.point_names[i], _triple(ds.points[i]), _triple(ds.normals[i])) for i in sensors)
    meta: dict[str, Any] = {
        "name": f"{ds.name}-{method}{n_sensors}",
        "method": method,
        "n_sensors": int(n_sensors),
        "n_modes": int(est.n_modes_),
        "fit": {
            "dataset": ds.name,
            "source": ds.source,
            "cases": [int(c) for c in ds.case_ids()],
            "n_snapshots": ds.n_snapshots,
            "n_points": ds.n_points,
            "candidates": "all"
            if candidates is None
            else f"nearest to {candidates_from.name if candidates_from else ''}",
            "n_candidates": int(ds.n_points if candidates is None else len(candidates)),
            "energy": float(est.energy_),
            "port_amplification": float(est.port_amplification_),
            "projection_error": {int(n): float(e) for n, e in zip(nb, eps, strict=True)},
        },
    }
    write_model(
        out,
        linear=linear,
        sensors=sensors,
        ports=ports,
        reference=ds.reference,
        meta=meta,
        diagnostics={
            "singular_values": wide.singular_values,
            "projection_error": eps,
            "fit_points_b": ds.points,
            "fit_sensor_index": sensors,
        },
    )
    return AeroModel.load(out)


def _triple(v: Any) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64)
    return float(a[0]), float(a[1]), float(a[2])


def port_columns(model: AeroModel, ds: Dataset) -> np.ndarray:
    """Column of ``ds`` for each model port, matched by location."""
    tol = PORT_TOLERANCE_CHORD * model.reference.chord_m
    return match_ports(model.ports, ds.points, tolerance_m=tol, where=ds.name if ds.path is None else str(ds.path))


def ports_and_truth(model: AeroModel, ds: Dataset, cases: Sequence[int]) -> tuple[np.ndarray, np.ndarray, Dataset]:
    """(Cp at the model's ports (K, n_s), truth coefficients (K, 6), the selected data set)."""
    sub = ds.select_cases(cases)
    cols = port_columns(model, sub)
    return np.asarray(sub.cp[:, cols], dtype=np.float64), sub.truth_coeffs(), sub


def _training_samples(model: AeroModel, ds: Dataset, grid: str, train_cases: Sequence[int], val_cases: Sequence[int]
                      ) -> tuple[F64Array, F64Array, F64Array, F64Array]:  # fmt: skip
    """(port Cp, truth) of the training and validation cases, the one set the net and the baselines learn
    from; a grid name that is not known is a one-line error."""
    from vdm_aero.train_correction import GRIDS

    if grid not in GRIDS:
        raise UserInputError(f"--grid: unknown grid {grid!r} (known: {', '.join(GRIDS)})")
    x_tr, y_tr, _ = ports_and_truth(model, ds, train_cases)
    x_va, y_va, _ = ports_and_truth(model, ds, val_cases)
    return x_tr, y_tr, x_va, y_va


def train_model(
    model_dir: Path,
    ds: Dataset,
    *,
    train_cases: Sequence[int],
    val_cases: Sequence[int],
    grid: str = "quick",
    seed: int = 0,
    max_epochs: int = 3000,
    train_noise: float = 0.0,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Train the correction net on (truth − DEIM) and add it to the model directory.

    ``train_noise``: relative input-noise augmentation during training (see
    :func:`vdm_aero.train_correction.train_one`)."""
    from vdm_aero.train_correction import GRIDS, check_onnx_matches, export_onnx, grid_search

    if set(train_cases) & set(val_cases):
        raise UserInputError("--train-cases and --val-cases overlap: validation must be on unseen cases")
    model = AeroModel.load(model_dir).with_correction(None)
    x_tr, y_tr, x_va, y_va = _training_samples(model, ds, grid, train_cases, val_cases)
    r_tr = y_tr - model.predict_batch(x_tr, linear_only=True)
    r_va = y_va - model.predict_batch(x_va, linear_only=True)
    fingerprint = samples_sha256(x_tr, y_tr, x_va, y_va)
    best, table = grid_search(
        GRIDS[grid],
        x_tr,
        r_tr,
        x_va,
        r_va,
        seed=seed,
        max_epochs=max_epochs,
        input_noise=train_noise,
        linear_ms=model.linear.Ms,
        progress=progress,
    )
    onnx_bytes = export_onnx(best.net, model.n_ports)
    onnx_err = check_onnx_matches(onnx_bytes, best.net, np.vstack([x_tr, x_va]))
    summary = {
        "dataset": ds.name,
        # where the training data was and what it held: evaluate trains the baselines on the same samples
        "data_path": None if ds.path is None else str(ds.path.resolve()),
        "samples_sha256": fingerprint,
        "train_cases": [int(c) for c in train_cases],
        "val_cases": [int(c) for c in val_cases],
        "grid": grid,
        "seed": int(seed),
        "max_epochs": int(max_epochs),
        "train_noise": float(train_noise),
        "selected": {
            "hidden_layers": best.config.hidden_layers,
            "width": best.config.width,
            "weight_decay": best.config.weight_decay,
        },
        "val_mse": best.val_mse,
        "val_mse_deim_only": float(np.mean(r_va**2)),
        "onnx_vs_torch_max_abs": onnx_err,
        "candidates": table,
    }
    meta = read_model_yaml(model_dir)
    meta["training"] = summary
    diag = load_diagnostics(model_dir)
    sensors = np.load(model_dir / "deim.npz")["sensors"]
    write_model(
        model_dir,
        linear=model.linear,
        sensors=sensors,
        ports=model.ports,
        reference=model.reference,
        meta=meta,
        diagnostics=diag,
        net_onnx=onnx_bytes,
    )
    return summary


def samples_sha256(*arrays: FloatArray) -> str:
    """Fingerprint of training samples (port Cp and truth), to recognise the same data later.

    Values are rounded to 1e-10 first: the truth may come from a pressure integral whose last bits depend
    on the BLAS build."""
    h = hashlib.sha256()
    for a in arrays:
        v = np.round(np.asarray(a, dtype=np.float64), 10) + 0.0  # + 0.0: −0.0 and 0.0 hash alike
        h.update(repr(v.shape).encode())
        h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class Baselines:
    """Direct regressions from the model's ports to the body-axis coefficients (no DEIM in them).

    ``linear_w`` (n_s + 1, 6): least squares [1, Cp] → coefficients; ``mlp``: the selected MLP as an ONNX
    session (the run-time path of the correction net); ``summary``: what they were trained on and how."""

    linear_w: F64Array
    mlp: OnnxCorrection
    summary: dict[str, Any]

    def predict(self, x: FloatArray) -> dict[str, F64Array]:
        """Port Cp (K, n_s) → {"linear_regression": (K, 6), "mlp": (K, 6)}."""
        from vdm_aero.calibrate import apply_linear

        return {"linear_regression": apply_linear(self.linear_w, np.asarray(x)), "mlp": self.mlp.predict_batch(x)}


def fit_baselines(
    model: AeroModel,
    ds: Dataset,
    *,
    train_cases: Sequence[int],
    val_cases: Sequence[int],
    grid: str = "quick",
    seed: int = 0,
    max_epochs: int = 3000,
    train_noise: float = 0.0,
) -> Baselines:
    """The two baselines on the correction net's data: ``train_cases`` fit both, ``val_cases`` select the MLP.

    The linear regression is :func:`vdm_aero.calibrate.linear_baseline` (the in-flight calibration's
    baseline); the MLP is the correction net's grid search (:func:`vdm_aero.train_correction.grid_search`:
    same grid, seed, epoch budget, early stopping and input-noise augmentation) with the coefficients as its
    target instead of the DEIM residual."""
    from vdm_aero.calibrate import linear_baseline
    from vdm_aero.onnx_net import OnnxCorrection
    from vdm_aero.train_correction import GRIDS, check_onnx_matches, export_onnx, grid_search

    x_tr, y_tr, x_va, y_va = _training_samples(model, ds, grid, train_cases, val_cases)
    w = linear_baseline(x_tr, y_tr)
    # with input noise the target of a noisy sample stays the truth: a linear part M_s = 0 in the augmentation
    zero_ms = np.zeros((y_tr.shape[1], model.n_ports)) if train_noise > 0.0 else None
    best, table = grid_search(GRIDS[grid], x_tr, y_tr, x_va, y_va, seed=seed, max_epochs=max_epochs,
                              input_noise=train_noise, linear_ms=zero_ms)  # fmt: skip
    onnx_bytes = export_onnx(best.net, model.n_ports)
    onnx_err = check_onnx_matches(onnx_bytes, best.net, np.vstack([x_tr, x_va]))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "mlp.onnx"
        path.write_bytes(onnx_bytes)
        mlp = OnnxCorrection(path)  # the session holds the graph; the file may go
    summary = {
        "dataset": ds.name,
        "train_cases": [int(c) for c in train_cases],
        "val_cases": [int(c) for c in val_cases],
        "grid": grid,
        "seed": int(seed),
        "max_epochs": int(max_epochs),
        "train_noise": float(train_noise),
        "mlp_selected": {
            "hidden_layers": best.config.hidden_layers,
            "width": best.config.width,
            "weight_decay": best.config.weight_decay,
        },
        "mlp_val_mse": best.val_mse,
        "mlp_onnx_vs_torch_max_abs": onnx_err,
        "mlp_candidates": table,
    }
    return Baselines(linear_w=w, mlp=mlp, summary=summary)


def method_predictions(model: AeroModel, x: FloatArray, baselines: Baselines | None = None) -> dict[str, F64Array]:
    """Coefficients (K, 6) of every method from port Cp (K, n_s): DEIM, DEIM+NN (if a net), the baselines."""
    out = {"deim": model.predict_batch(x, linear_only=True)}
    if model.has_correction:
        out["deim_nn"] = model.predict_batch(x)
    if baselines is not None:
        out.update(baselines.predict(x))
    return out


def evaluate_model(
    model: AeroModel,
    ds: Dataset,
    cases: Sequence[int],
    *,
    noise: float = 0.0,
    seed: int = 0,
    baselines: Baselines | None = None,
) -> dict[str, Any]:
    """The method's table row: ℓ2/ℓ∞/α-at-ℓ∞ of C_L and C_D for DEIM, DEIM+NN (when the model has a net) and
    the ``baselines`` (when given), all on the same inputs.

    ``noise`` is the relative std of multiplicative Gaussian noise on the port inputs,
    Cp·(1 + noise·N(0,1)), drawn from ``numpy.random.default_rng(seed)``
    (:func:`vdm_aero.evaluation.add_port_noise`). With noise, ``noise_floor`` holds per coefficient the ℓ2
    floor of the linear maps (DEIM's M_s, and the linear regression's) for exactly that noise, every method's
    noise-free ℓ2 and its amplification: noisy ℓ2 / sqrt(noise-free ℓ2² + DEIM floor²).
    """
    x, truth, sub = ports_and_truth(model, ds, cases)

    def errors(inputs: FloatArray) -> dict[str, Any]:
        preds = method_predictions(model, inputs, baselines)
        return merge_methods({k: lift_drag_errors(p, truth, sub.alpha, sub.beta) for k, p in preds.items()})

    res: dict[str, Any] = {
        "n_sensors": model.n_ports,
        "noise": noise,
        "cases": [int(c) for c in cases],
        "dataset": ds.name,
    }
    if noise <= 0:
        res["metrics"] = errors(x)
        return res
    res["metrics"] = noisy = errors(add_port_noise(x, noise, np.random.default_rng(seed)))
    clean = errors(x)
    sigma = port_noise_std(x, noise)
    maps = {"deim": model.linear.Ms}
    if baselines is not None:
        maps["linear_regression"] = baselines.linear_w[1:].T
    floors = {k: linear_noise_floor(m, sigma, truth, sub.alpha, sub.beta) for k, m in maps.items()}
    res["noise_floor"] = {
        c: {
            "floor_l2": {k: f[c] for k, f in floors.items()},
            "noise_free_l2": {k: clean[c][k]["l2"] for k in clean[c]},
            "amplification": {
                k: noise_amplification(noisy[c][k]["l2"], clean[c][k]["l2"], floors["deim"][c]) for k in noisy[c]
            },
        }
        for c in noisy
    }
    return res


def predictions(
    model: AeroModel, ds: Dataset, cases: Sequence[int], baselines: Baselines | None = None
) -> dict[str, np.ndarray]:
    """Truth and every method's coefficient series (DEIM, DEIM+NN, baselines) with α and t (for plots)."""
    x, truth, sub = ports_and_truth(model, ds, cases)
    return {
        "alpha": sub.alpha,
        "t": sub.t,
        "case": sub.case,
        "truth": truth,
        **method_predictions(model, x, baselines),
    }
