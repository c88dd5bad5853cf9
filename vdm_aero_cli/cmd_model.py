"""``fit``, ``train``, ``evaluate``: the DEIM + correction-net model on data sets."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vdm_aero.dataset import Dataset, load_dataset
from vdm_aero.errors import UserInputError
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
        help="ℓ2/ℓ∞ errors of C_L and C_D, DEIM vs DEIM+NN",
        description="Evaluate model M on the cases of D, optionally with multiplicative noise on the port inputs.",
    )
    e.add_argument("--model", type=Path, required=True, metavar="M")
    e.add_argument("--data", type=Path, required=True, metavar="D")
    e.add_argument("--cases", required=True, metavar="IDS")
    e.add_argument("--noise", type=float, default=0.0, help="relative noise std on port Cp (e.g. 0.015)")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--json", action="store_true", help="print JSON instead of a table")
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
    rows.append(f"{'':4} {'method':8} {'ℓ2':>9} {'ℓ∞':>9} {'α at ℓ∞':>9}")
    for coeff, methods in res["metrics"].items():
        for method, m in methods.items():
            name = "DEIM+NN" if method == "deim_nn" else "DEIM"
            rows.append(f"{coeff:4} {name:8} {m['l2']:9.3e} {m['linf']:9.3e} {m['alpha_at_linf_deg']:8.2f}°")
    return "\n".join(rows)


def run_evaluate(args: argparse.Namespace) -> int:
    from vdm_aero.pipeline import evaluate_model

    if not 0.0 <= args.noise < 0.5:
        raise UserInputError("--noise: must be in [0, 0.5)")
    ds = load_dataset(args.data)
    model = AeroModel.load(args.model)
    res = evaluate_model(model, ds, parse_ids(args.cases, ds, "--cases"), noise=args.noise, seed=args.seed)
    print(json.dumps(res, indent=2) if args.json else format_metrics_table(res))
    return 0
