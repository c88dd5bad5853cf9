"""``fit``, ``train``, ``evaluate``: the DEIM + correction-net model on data sets."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from vdm_aero.dataset import Dataset, load_dataset
from vdm_aero.errors import UserInputError
from vdm_aero.evaluation import METHOD_LABELS
from vdm_aero.model import AeroModel
from vdm_aero_cli.progress import progress_bar


def parse_ids(text: str, ds: Dataset, flag: str) -> list[int]:
    """Comma-separated case ids of ``ds`` (one clear error for anything else)."""
    try:
        ids = [int(x) for x in text.split(",") if x.strip() != ""]
    except ValueError:
        raise UserInputError(f"{flag}: expected comma-separated case ids, got {text!r}") from None
    known = set(ds.case_ids())
    unknown = [i for i in ids if i not in known]
    if not ids or unknown:
        raise UserInputError(
            f"{flag}: case id(s) {unknown or text!r} not in {ds.name} (ids: {', '.join(map(str, sorted(known)))})"
        )
    return ids


def register(sub: Any) -> None:
    p = sub.add_parser(
        "fit",
        help="POD + DEIM sensor selection and the linear force model",
        description="Fit the POD basis on D, choose N ports by DEIM (or Q-DEIM) and write the model directory M.",
    )
    p.add_argument("--data", type=Path, required=True, metavar="D", help="data set to fit on")
    p.add_argument("--sensors", type=int, required=True, metavar="N", help="number of ports n_s")
    p.add_argument("--modes", type=int, metavar="N", help="POD modes n_b (default n_s; fewer → gappy least squares)")
    p.add_argument("--method", choices=("deim", "qdeim"), default="deim")
    p.add_argument("--candidates-from", type=Path, metavar="D2", help="candidates: points of D nearest to D2's points")
    p.add_argument("--cases", metavar="IDS", help="fit only these case ids (default all)")
    p.add_argument("--out", type=Path, required=True, metavar="M", help="model directory to write")
    p.set_defaults(func=run_fit)

    t = sub.add_parser(
        "train",
        help="train the correction net on (truth − DEIM) and add it to a model",
        description="Train the ReLU correction net (grid search on the validation cases), export it to ONNX, "
        "verify onnxruntime ≡ torch and add it to the model directory M.",
    )
    t.add_argument("--model", type=Path, required=True, metavar="M")
    t.add_argument("--data", type=Path, required=True, metavar="D")
    t.add_argument("--train-cases", required=True, metavar="IDS")
    t.add_argument("--val-cases", required=True, metavar="IDS")
    t.add_argument("--grid", choices=("paper", "quick"), default="paper")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--max-epochs", type=int, default=3000)
    t.add_argument(
        "--train-noise",
        type=float,
        default=0.0,
        help="relative input-noise augmentation during training (e.g. 0.015)",
    )
    t.set_defaults(func=run_train)

    e = sub.add_parser(
        "evaluate",
        help="ℓ2/ℓ∞ errors of C_L and C_D: DEIM, DEIM+NN and two baselines",
        description="Evaluate model M on the cases of D, optionally with multiplicative noise on the port inputs. "
        "Next to DEIM and DEIM+NN: a linear regression and an MLP straight from the same ports, trained on the "
        "correction net's recorded training data (the data set it was trained on, found by its recorded path, "
        "by D, or by --baseline-data, and checked against its recorded fingerprint) with the same grid, seed "
        "and epoch budget. With noise: the noise floor of the DEIM linear map and each method's amplification.",
    )
    e.add_argument("--model", type=Path, required=True, metavar="M")
    e.add_argument("--data", type=Path, required=True, metavar="D")
    e.add_argument("--cases", required=True, metavar="IDS")
    e.add_argument("--noise", type=float, default=0.0, help="relative noise std on port Cp (e.g. 0.015)")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--json", action="store_true", help="print JSON instead of a table")
    e.add_argument(
        "--baseline-data",
        type=Path,
        metavar="D2",
        help="the data set the net was trained on, if neither its recorded path nor D is it",
    )
    e.add_argument("--no-baselines", action="store_true", help="skip the baselines (their MLP trains like the net)")
    e.set_defaults(func=run_evaluate)


def run_fit(args: argparse.Namespace) -> int:
    from vdm_aero.pipeline import fit_model

    ds = load_dataset(args.data)
    cand = load_dataset(args.candidates_from) if args.candidates_from else None
    cases = parse_ids(args.cases, ds, "--cases") if args.cases else None
    model = fit_model(
        ds,
        args.out,
        n_sensors=args.sensors,
        n_modes=args.modes,
        method=args.method,
        cases=cases,
        candidates_from=cand,
    )
    fit = model.meta["fit"]
    print(
        f"wrote {args.out}: {model.n_ports} ports ({', '.join(model.port_names)}), "
        f"{model.meta['n_modes']} modes, energy {fit['energy']:.6f}"
    )
    return 0


def run_train(args: argparse.Namespace) -> int:
    from vdm_aero.pipeline import train_model
    from vdm_aero.train_correction import GRIDS

    ds = load_dataset(args.data)
    tr = parse_ids(args.train_cases, ds, "--train-cases")
    va = parse_ids(args.val_cases, ds, "--val-cases")
    if not 0.0 <= args.train_noise < 0.5:
        raise UserInputError("--train-noise: must be in [0, 0.5)")
    with progress_bar(f"train ({args.grid} grid)", len(GRIDS[args.grid])) as update:
        s = train_model(
            args.model,
            ds,
            train_cases=tr,
            val_cases=va,
            grid=args.grid,
            seed=args.seed,
            max_epochs=args.max_epochs,
            train_noise=args.train_noise,
            progress=update,
        )
    sel = s["selected"]
    print(
        f"selected {sel['hidden_layers']}x{sel['width']} wd={sel['weight_decay']:g}: validation MSE "
        f"{s['val_mse']:.3e} (DEIM alone {s['val_mse_deim_only']:.3e}); onnx vs torch {s['onnx_vs_torch_max_abs']:.1e}"
    )
    return 0


def format_metrics_table(res: dict[str, Any]) -> str:
    rows = [f"n_s = {res['n_sensors']}, noise = {res['noise']:g}, cases {res['cases']} of {res['dataset']}"]
    floor = res.get("noise_floor")
    head = f"{'':4} {'method':8} {'ℓ2':>9} {'ℓ∞':>9} {'α at ℓ∞':>9}"
    rows.append(head + (f" {'ℓ2 no noise':>11} {'amplif.':>7}" if floor else ""))
    for coeff, methods in res["metrics"].items():
        for method, m in methods.items():
            line = f"{coeff:4} {METHOD_LABELS[method]:8} {m['l2']:9.3e} {m['linf']:9.3e} {m['alpha_at_linf_deg']:8.2f}°"
            if floor:
                f = floor[coeff]
                line += f" {f['noise_free_l2'][method]:11.3e} {f['amplification'][method]:6.2f}×"
            rows.append(line)
        if floor:
            lin = ", ".join(f"{METHOD_LABELS[k]} {v:.3e}" for k, v in floor[coeff]["floor_l2"].items())
            rows.append(f"{coeff:4} noise floor ℓ2 of the linear map: {lin}")
    if floor:
        rows.append("amplif. = ℓ2 / sqrt(ℓ2 no noise² + DEIM floor²): ≈ 1 passes the noise on like DEIM's linear map")
    return "\n".join(rows)


def _not_the_training_data(model: AeroModel, ds: Dataset, training: dict[str, Any]) -> str | None:
    """Why ``ds`` is not the data the net was trained on (None when it is: name, cases and samples)."""
    from vdm_aero.pipeline import ports_and_truth, samples_sha256

    if ds.name != training["dataset"]:
        return f"data set {ds.name!r}, not {training['dataset']!r}"
    cases = [int(c) for c in training["train_cases"] + training["val_cases"]]
    missing = sorted(set(cases) - set(ds.case_ids()))
    if missing:
        return f"no case(s) {missing}"
    try:
        x_tr, y_tr, _ = ports_and_truth(model, ds, training["train_cases"])
        x_va, y_va, _ = ports_and_truth(model, ds, training["val_cases"])
    except UserInputError as e:
        return str(e)
    if samples_sha256(x_tr, y_tr, x_va, y_va) != training["samples_sha256"]:
        return "its training cases differ from the samples the net was trained on (sha256)"
    return None


def baseline_training_data(
    model: AeroModel, eval_ds: Dataset, explicit: Path | None
) -> tuple[Dataset | None, str | None]:
    """The data set the correction net was trained on, for the baselines, or (None, why not, in one line).

    Candidates: ``explicit`` (--baseline-data) alone; else the recorded path, then the evaluation data set.
    A candidate is the training data when it has the recorded name and cases and its training samples match
    the recorded fingerprint. An explicit candidate that is not raises :class:`UserInputError`."""
    training = model.meta.get("training")
    if not isinstance(training, dict):
        if not model.has_correction:
            return None, "no baselines: the model has no correction net, so no training data to train them on"
        if "calibration" in model.meta:
            return None, "no baselines: the net was calibrated from a flight (calibration-study has its baselines)"
        return None, "no baselines: the model records no training data for its net"
    if "samples_sha256" not in training or "max_epochs" not in training:
        return None, "no baselines: the model's training record predates them (no data fingerprint); retrain it"
    if explicit is not None:
        ds = load_dataset(explicit)
        why = _not_the_training_data(model, ds, training)
        if why:
            raise UserInputError(f"--baseline-data {explicit}: not the net's training data: {why}")
        return ds, None
    tried = []
    recorded = training.get("data_path")
    if recorded and (eval_ds.path is None or Path(recorded).resolve() != eval_ds.path.resolve()):
        if (Path(recorded) / "dataset.yaml").is_file():
            try:  # a recorded path that no longer loads is one more place the data is not
                ds = load_dataset(recorded)
                why = _not_the_training_data(model, ds, training)
            except UserInputError as e:
                why = str(e)
            else:
                if why is None:
                    return ds, None
            tried.append(f"{recorded}: {why}")
        else:
            tried.append(f"{recorded}: gone")
    why = _not_the_training_data(model, eval_ds, training)
    if why is None:
        return eval_ds, None
    tried.append(f"{eval_ds.path or eval_ds.name}: {why}")
    return None, (
        f"no baselines: the net's training data ({training['dataset']}, cases {training['train_cases']} + "
        f"{training['val_cases']}) is not available ({'; '.join(tried)}); pass --baseline-data D2"
    )


def run_evaluate(args: argparse.Namespace) -> int:
    from vdm_aero.pipeline import Baselines, evaluate_model, fit_baselines

    if not 0.0 <= args.noise < 0.5:
        raise UserInputError("--noise: must be in [0, 0.5)")
    ds = load_dataset(args.data)
    model = AeroModel.load(args.model)
    cases = parse_ids(args.cases, ds, "--cases")
    baselines: Baselines | None = None
    note: str | None = "no baselines (--no-baselines)"
    if not args.no_baselines:
        train_ds, note = baseline_training_data(model, ds, args.baseline_data)
        if train_ds is not None:
            t = model.meta["training"]
            baselines = fit_baselines(model, train_ds, train_cases=t["train_cases"], val_cases=t["val_cases"],
                                      grid=t["grid"], seed=t["seed"], max_epochs=t["max_epochs"],
                                      train_noise=t.get("train_noise", 0.0))  # fmt: skip
    res = evaluate_model(model, ds, cases, noise=args.noise, seed=args.seed, baselines=baselines)
    res["baselines"] = baselines.summary if baselines is not None else {"skipped": note}
    if note and baselines is None:
        print(note, file=sys.stderr)
    print(json.dumps(res, indent=2) if args.json else format_metrics_table(res))
    return 0
