"""``paper-tables --case airfoil``: the method's two NACA 0015 table pairs, end to end from the presets.

Case 1: DEIM built on experiment (tunnel) data, candidates = the 36 taps.
Case 2: DEIM built on simulation (URANS) data with candidates nearest the taps, applied to experiment
inputs. In both, the correction net is trained on the tunnel training cases, selected on the
validation case, and everything is evaluated on the held-out test case, without noise and with 1.5 %
noise on the port inputs. Two baselines trained on the same cases sit next to DEIM and DEIM+NN: a linear
regression and an MLP (same grid, seed and epoch budget as the net) straight from the same ports; the noisy
tables give the noise floor of the DEIM linear map and the net's amplification of it.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vdm_aero.dataset import Dataset, load_dataset
from vdm_aero.errors import UserInputError
from vdm_aero.evaluation import METHOD_LABELS
from vdm_aero.model import AeroModel
from vdm_aero_cli.cmd_data import simulate_to
from vdm_aero_cli.progress import progress_bar

if TYPE_CHECKING:
    from vdm_aero.pipeline import Baselines

NOISE = 0.015
AIRFOIL_CASES = (1, 2)
CASES = {
    1: "DEIM on experiment data",
    2: "DEIM on simulation data, candidates nearest the taps, experiment inputs",
    3: "3-D UAV: DEIM on simulation data, every surface point a candidate",
}


def register(sub: Any) -> None:
    p = sub.add_parser(
        "paper-tables",
        help="reproduce the method's error tables end to end",
        description="Simulate the presets, fit, train and evaluate both of the method's cases for each n_s, "
        "and write tables (Markdown + JSON) and plots.",
    )
    p.add_argument("--case", choices=("airfoil", "uav"), required=True, help="which test case of the method")
    p.add_argument("--out", type=Path, required=True, metavar="DIR")
    p.add_argument("--sensors", help="comma-separated n_s values (default 5,8,10 airfoil; 5,10,15 uav)")
    p.add_argument("--grid", choices=("paper", "quick"), default="paper")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-epochs", type=int, default=3000)
    p.add_argument("--train-noise", type=float, default=0.0, help="input-noise augmentation while training")
    p.set_defaults(func=run_paper_tables)


def case_roles(ds: Dataset) -> dict[str, list[int]]:
    roles: dict[str, list[int]] = {"train": [], "validation": [], "test": []}
    for c in ds.cases:
        r = c.meta.get("role")
        if r in roles:
            roles[str(r)].append(c.id)
    if not all(roles.values()):
        raise UserInputError(f"{ds.name}: cases need roles train, validation and test (dataset.yaml cases[].role)")
    return roles


def train_and_evaluate(
    mdir: Path, ds: Dataset, roles: dict[str, list[int]], case: int, train: dict[str, Any]
) -> tuple[AeroModel, Baselines, list[dict[str, Any]]]:
    """Train the correction net of a fitted model and the two baselines on ``ds``'s training cases (selected
    on its validation cases) and evaluate all on its test cases without and with noise: the rows of one
    table line."""
    from vdm_aero.pipeline import evaluate_model, fit_baselines, train_model

    train_model(mdir, ds, train_cases=roles["train"], val_cases=roles["validation"], **train)
    model = AeroModel.load(mdir)
    baselines = fit_baselines(model, ds, train_cases=roles["train"], val_cases=roles["validation"], **train)
    summary = {k: v for k, v in baselines.summary.items() if k != "mlp_candidates"}
    rows = []
    for noise in (0.0, NOISE):
        r = evaluate_model(model, ds, roles["test"], noise=noise, seed=train["seed"], baselines=baselines)
        r["case"] = case
        r["selected_net"] = model.meta["training"]["selected"]
        r["baselines"] = summary
        rows.append(r)
    return model, baselines, rows


def run_airfoil_tables(
    out: Path,
    *,
    sensors: list[int],
    grid: str,
    seed: int,
    max_epochs: int,
    train_noise: float,
    quiet: bool = False,
    sources: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """``sources``: a spec file to simulate instead of a preset (e.g. a reduced one for ``demo --quick``)."""
    from vdm_aero.pipeline import fit_model, predictions
    from vdm_aero_cli.plots import plot_method_errors, plot_model_diagnostics, plot_predictions

    data = out / "data"
    src = dict(sources or {})
    urans = load_dataset(simulate_to(src.get("naca0015-urans", "naca0015-urans"), data / "naca0015-urans",
                                     quiet=quiet))  # fmt: skip
    tunnel = load_dataset(simulate_to(src.get("naca0015-tunnel", "naca0015-tunnel"), data / "naca0015-tunnel",
                                      quiet=quiet))  # fmt: skip
    roles = case_roles(tunnel)
    train = {"grid": grid, "seed": seed, "max_epochs": max_epochs, "train_noise": train_noise}
    results: list[dict[str, Any]] = []
    jobs = [(case, n) for case in AIRFOIL_CASES for n in sensors]
    with progress_bar("paper tables", len(jobs)) as update:
        for k, (case, n) in enumerate(jobs):
            mdir = out / "models" / f"case{case}-ns{n}"
            if case == 1:
                fit_model(tunnel, mdir, n_sensors=n, cases=roles["train"])
            else:
                fit_model(urans, mdir, n_sensors=n, candidates_from=tunnel)
            model, baselines, rows = train_and_evaluate(mdir, tunnel, roles, case, train)
            results += rows
            if n == max(sensors):
                plot_predictions(predictions(model, tunnel, roles["test"], baselines),
                                 out / f"case{case}-ns{n}-predictions.png",
                                 title=f"case {case}, n_s = {n}, test case {roles['test']}")  # fmt: skip
                plot_model_diagnostics(mdir, out / f"case{case}-ns{n}-sensors.png", title=f"case {case}")
            update(k + 1, len(jobs))
    doc = {"case": "airfoil", "grid": grid, "seed": seed, "train_noise": train_noise, "results": results}
    out.mkdir(parents=True, exist_ok=True)
    (out / "tables.json").write_text(json.dumps(doc, indent=2))
    (out / "tables.md").write_text(tables_markdown(doc))
    for case in AIRFOIL_CASES:
        plot_method_errors(doc, case, out / f"case{case}-errors.png", title=f"case {case}: {CASES[case]}")
    return doc


def run_uav_tables(
    out: Path,
    *,
    sensors: list[int],
    grid: str,
    seed: int,
    max_epochs: int,
    train_noise: float,
    quiet: bool = False,
    sources: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The method's 3-D case: DEIM on the simulated pitching UAV (every surface point a candidate), the
    net trained on the training frequencies, selected on the validation one, evaluated on the test one."""
    from vdm_aero.pipeline import fit_model, predictions
    from vdm_aero_cli.plots import plot_method_errors, plot_ports_3d, plot_predictions

    ds = load_dataset(simulate_to(dict(sources or {}).get("uav-pitch", "uav-pitch"), out / "data" / "uav-pitch",
                                  quiet=quiet))  # fmt: skip
    roles = case_roles(ds)
    train = {"grid": grid, "seed": seed, "max_epochs": max_epochs, "train_noise": train_noise}
    results: list[dict[str, Any]] = []
    with progress_bar("paper tables (uav)", len(sensors)) as update:
        for k, n in enumerate(sensors):
            mdir = out / "models" / f"uav-ns{n}"
            fit_model(ds, mdir, n_sensors=n, cases=roles["train"])
            model, baselines, rows = train_and_evaluate(mdir, ds, roles, 3, train)
            results += rows
            if n == max(sensors):
                plot_predictions(predictions(model, ds, roles["test"], baselines), out / f"uav-ns{n}-predictions.png",
                                 title=f"UAV pitching, n_s = {n}, test case {roles['test']}")  # fmt: skip
                plot_ports_3d(ds, model, out / f"uav-ns{n}-ports.png")
            update(k + 1, len(sensors))
    doc = {"case": "uav", "grid": grid, "seed": seed, "train_noise": train_noise, "results": results}
    out.mkdir(parents=True, exist_ok=True)
    (out / "tables.json").write_text(json.dumps(doc, indent=2))
    (out / "tables.md").write_text(tables_markdown(doc))
    plot_method_errors(doc, 3, out / "uav-errors.png", title=f"case 3: {CASES[3]}")
    return doc


def _cells(m: dict[str, float] | None, alpha: bool = True) -> list[str]:
    if m is None:
        return ["–"] * (3 if alpha else 2)
    return [f"{m['l2']:.3e}", f"{m['linf']:.3e}"] + ([f"{m['alpha_at_linf_deg']:.2f}°"] if alpha else [])


def tables_markdown(doc: dict[str, Any]) -> str:
    lines = [
        "# Method tables: "
        + ("pitching NACA 0015" if doc["case"] == "airfoil" else "pitching 3-D UAV")
        + " (vdm-aero presets)",
        "",
        "Errors on the held-out test case: ℓ2 = ‖ŷ−y‖₂/‖y‖₂, ℓ∞ = max|ŷ−y|/max|y|, α at the ℓ∞ error.",
        f"Correction-net grid: {doc['grid']}; seed {doc['seed']}; training input noise {doc['train_noise']:g}.",
        "Baselines from the same ports, trained on the net's training cases: linear = least squares [1, Cp] → "
        "coefficients; MLP = the net's grid search, seed and epoch budget with the coefficients as target.",
        "With noise (Cp·(1 + σ·N(0,1)) per port and sample): floor = ℓ2 error the noise alone causes through the "
        "DEIM linear map M_s; amplif. = DEIM+NN ℓ2 / sqrt(its noise-free ℓ2² + floor²) (≈ 1: no amplification).",
        "",
    ]
    for case, title in CASES.items():
        for noise in (0.0, NOISE):
            rows = [r for r in doc["results"] if r["case"] == case and r["noise"] == noise]
            if not rows:
                continue
            head = ["n_s", "coeff", "DEIM ℓ2", "DEIM ℓ∞", "DEIM α@ℓ∞", "DEIM+NN ℓ2", "DEIM+NN ℓ∞", "DEIM+NN α@ℓ∞",
                    "ℓ2 ratio", "linear ℓ2", "linear ℓ∞", "MLP ℓ2", "MLP ℓ∞", "best ℓ2"]  # fmt: skip
            if noise > 0:
                head += ["floor ℓ2", "DEIM+NN amplif."]
            lines += [
                f"## Case {case}: {title}; noise {noise * 100:g} %",
                "",
                "| " + " | ".join(head) + " |",
                "|---" * len(head) + "|",
            ]
            for r in rows:
                for coeff in ("CL", "CD"):
                    ms = r["metrics"][coeff]
                    d, nn = ms["deim"], ms.get("deim_nn")
                    cells = [str(r["n_sensors"]), coeff, *_cells(d), *_cells(nn)]
                    cells.append(f"{d['l2'] / nn['l2']:.1f}×" if nn else "–")
                    cells += _cells(ms.get("linear_regression"), alpha=False) + _cells(ms.get("mlp"), alpha=False)
                    cells.append(METHOD_LABELS[min(ms, key=lambda k: ms[k]["l2"])])
                    if noise > 0:
                        f = r["noise_floor"][coeff]
                        cells.append(f"{f['floor_l2']['deim']:.3e}")
                        cells.append(f"{f['amplification']['deim_nn']:.2f}" if nn else "–")
                    lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
    return "\n".join(lines)


def run_paper_tables(args: argparse.Namespace) -> int:
    text = args.sensors or ("5,8,10" if args.case == "airfoil" else "5,10,15")
    try:
        sensors = sorted({int(x) for x in text.split(",")})
    except ValueError:
        raise UserInputError(f"--sensors: expected comma-separated integers, got {text!r}") from None
    limit = 36 if args.case == "airfoil" else 200
    if not sensors or min(sensors) < 1 or max(sensors) > limit:
        raise UserInputError(f"--sensors: each n_s must be between 1 and {limit}")
    run = run_airfoil_tables if args.case == "airfoil" else run_uav_tables
    doc = run(
        args.out,
        sensors=sensors,
        grid=args.grid,
        seed=args.seed,
        max_epochs=args.max_epochs,
        train_noise=args.train_noise,
    )
    print((args.out / "tables.md").read_text())
    print(f"wrote {args.out / 'tables.md'}, {args.out / 'tables.json'} and plots ({len(doc['results'])} rows)")
    return 0
