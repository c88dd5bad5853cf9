"""``discover``: name the physical effect the simulation misses, add it, show the gap shrink."""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Dataset, load_dataset, to_plain
from vdm_aero.discrepancy import (
    COEFFS,
    MAX_EFFECTS,
    MIN_ABSOLUTE_GAIN,
    MIN_EXPLAINED_SHARE,
    MIN_HELDOUT_GAIN,
    MIN_INCLUSION,
    PARSIMONY_TOL,
    Discovery,
)
from vdm_aero.errors import SpecError


def register(sub: Any) -> None:
    p = sub.add_parser(
        "discover",
        help="find, name and add the effect the simulation misses",
        description="Compare a simulation spec with a measured data set case by case (driven by each case's "
        "own alpha(t)), localise the disagreement, name the missing effect(s) from the simulator's library by "
        "re-simulation and held-out gain, and write the updated spec and a report.",
    )
    p.add_argument("--sim", type=str, required=True, metavar="SPEC.yaml", help="spec file or preset name")
    p.add_argument("--measured", type=Path, required=True, metavar="DATASET")
    p.add_argument("--out", type=Path, required=True, metavar="REPORT_DIR")
    p.add_argument("--json", action="store_true", help="print report.json instead of the summary")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.set_defaults(func=run_discover)


def split_cases(ds: Dataset) -> tuple[list[int], list[int]]:
    """Training / held-out cases: the data set's roles when given (train vs the rest), else every other
    case in order of reduced frequency (so both halves span the range)."""
    roles = {c.id: c.meta.get("role") for c in ds.cases}
    train = [c for c, r in roles.items() if r == "train"]
    held = [c for c, r in roles.items() if r in ("validation", "test")]
    if train and held:
        return train, held
    order = sorted(ds.cases, key=lambda c: (c.meta.get("reduced_frequency") or c.freq_hz or 0.0, c.id))
    ids = [c.id for c in order]
    if len(ids) < 2:
        raise SpecError(f"{ds.path or ds.name}: discovery needs at least two cases (training and held-out)")
    return ids[0::2], ids[1::2]


def discover(
    spec_source: str, measured_path: Path, out: Path, *, seed: int = 0, max_effects: int = MAX_EFFECTS
) -> dict[str, Any]:
    """Run the whole workflow and write REPORT_DIR; returns report.json's content."""
    from sim.airfoil.replay import AirfoilReplay, candidate_source
    from vdm_aero_cli.cmd_data import load_any_spec

    t0 = time.perf_counter()
    spec = load_any_spec(spec_source)
    measured = load_dataset(measured_path)
    replay = AirfoilReplay(spec, measured)
    train, held = split_cases(measured)
    disc = Discovery(
        replay,
        replay.measured_cases(),
        replay.ports,
        train=train,
        heldout=held,
        base_effects=replay.base_effects,
        candidates=candidate_source(replay),
        seed=seed,
        max_effects=max_effects,
    )
    result = disc.run()
    base, final = replay.base_effects, result["final_effects"]
    gap_before, gap_after = disc.gap(base, held), disc.gap(final, held)
    all_cases = [c.id for c in measured.cases]
    hot = disc.hotspots(base, all_cases)
    hot_after = disc.hotspots(final, all_cases)
    remaining = disc.remaining_gap(base, final, all_cases)
    out.mkdir(parents=True, exist_ok=True)
    new_spec = spec.to_dict()
    new_spec["effects"] = {k: dict(v) for k, v in final.items()}
    new_spec["source"] = f"{spec.source} + discovered against {measured.name}: " + (
        ", ".join(e["name"] for e in result["effects"]) or "nothing named"
    )
    (out / "spec.yaml").write_text(yaml.safe_dump(to_plain(new_spec), sort_keys=False, allow_unicode=True))
    report = {
        "effects": result["effects"],
        "gap_before": _gap(gap_before),
        "gap_after": _gap(gap_after),
        "unexplained": result["unexplained"],
        "hotspots": hot,
        "hotspots_after": hot_after,
        "remaining_gap": remaining,
        "explained_share": result["explained_share"],
        "noise_floor_objective": result["noise_floor_objective"],
        "baseline_heldout_objective": result["baseline_heldout_objective"],
        "rules": {
            "min_heldout_gain": MIN_HELDOUT_GAIN,
            "min_absolute_gain_of_floor": MIN_ABSOLUTE_GAIN,
            "min_inclusion_probability": MIN_INCLUSION,
            "parsimony_tolerance": PARSIMONY_TOL,
            "min_explained_share": MIN_EXPLAINED_SHARE,
        },
        "train_cases": train,
        "heldout_cases": held,
        "rounds": result["rounds"],
        "sim": spec_source,
        "measured": str(measured_path),
        "simulations": disc.n_evals,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    (out / "report.json").write_text(json.dumps(to_plain(report), indent=2))
    (out / "report.md").write_text(report_markdown(report))
    _plots(replay, disc, base, final, held, out)
    return report


def _gap(g: dict[str, Any]) -> dict[str, Any]:
    return {"coeff_rms": g["coeff_rms"], "cp_rms": g["cp_rms"], "port_cp_rms": g["port_cp_rms"]}


def report_markdown(r: dict[str, Any]) -> str:
    lines = ["# Discrepancy report", "", f"Simulation: `{r['sim']}`; measurement: `{r['measured']}`.", ""]
    if r["unexplained"]:
        lines += [
            f"**Unexplained**: no combination of library effects explains ≥ {MIN_EXPLAINED_SHARE:.0%} of the "
            f"explainable held-out residual (best: {r['explained_share']:.0%}). Nothing is named.",
            "",
        ]
    else:
        lines += [
            "## Named effects",
            "",
            "| effect | parameters | held-out gain | inclusion probability |",
            "|---|---|---|---|",
        ]
        bounded = []
        for e in r["effects"]:
            params = ", ".join(f"{k} = {v:.4g}" + (f" (at its {e['at_bounds'][k]} bound)" if k in e.get("at_bounds", {})
                                                   else "") for k, v in e["params"].items())  # fmt: skip
            together = f" (named with {', '.join(e['named_with'])})" if e.get("named_with") else ""
            lines.append(f"| `{e['name']}`{together} | {params} | {e['heldout_gain']:.1%} "
                         f"| {e['inclusion_probability']:.2f} |")  # fmt: skip
            bounded += [f"`{e['name']}`.{k}" for k in e.get("at_bounds", {})]
        lines += ["", f"Together they explain {r['explained_share']:.1%} of the explainable held-out residual.", ""]
        if bounded:
            lines += [f"**At a bound** (within 1 % of the documented range): {', '.join(bounded)}. The effect's "
                      "shape or its range may not fit the data: read its parameters as a direction, not a value.",
                      ""]  # fmt: skip
    b, a = r["gap_before"], r["gap_after"]
    lines += [
        f"## Gap on the held-out cases {r['heldout_cases']} (trained on {r['train_cases']})",
        "",
        "| | before | after | shrink |",
        "|---|---|---|---|",
    ]
    for k in b["coeff_rms"]:
        bk, ak = b["coeff_rms"][k], a["coeff_rms"][k]
        lines.append(f"| RMS {k} | {bk:.4g} | {ak:.4g} | {_shrink(bk, ak)} |")
    lines.append(f"| RMS port Cp | {b['cp_rms']:.4g} | {a['cp_rms']:.4g} | {_shrink(b['cp_rms'], a['cp_rms'])} |")
    lines += [
        "",
        "## Where the disagreement lived, and the gap left there",
        "",
        "The hot spots of the simulation before discovery, over all measured cases, with the RMS residual "
        "there before and after (ports and regions: Cp; α bins and cases: C_L, C_D, C_m). The spots of the "
        "final simulation are in `report.json` → `hotspots_after`.",
        "",
        "| kind | where | share before | RMS before | RMS after |",
        "|---|---|---|---|---|",
    ]
    for h in r.get("remaining_gap", []):
        lines.append(f"| {h['kind']} | {h['label']} | {h['share_before']:.1%} | {_rms_cell(h['rms_before'])} "
                     f"| {_rms_cell(h['rms_after'])} |")  # fmt: skip
    lines += ["", "## Candidate ranking per round", ""]
    for rnd in r["rounds"]:
        lines.append(
            f"Round {rnd['round']}: " + ", ".join(f"`{c['name']}` {c['heldout_gain']:.1%}" for c in rnd["ranking"][:6])
        )
        lines.append("")
    lines += [f"{r['simulations']} simulations, {r['seconds']} s.", "", "Plots: `residuals.png`, `loops.png`.", ""]
    return "\n".join(lines)


def _rms_cell(rms: dict[str, float]) -> str:
    """'C_L 0.31, C_D 0.12, C_m 0.05' for a bin, 'Cp 0.21' for a port or region."""
    keys = [k for k in COEFFS if k in rms] or ["Cp"]
    return ", ".join(f"{k} {rms[k]:.3g}" for k in keys if k in rms) or "–"


def _shrink(before: float, after: float) -> str:
    return f"{(1 - after / before):.0%}" if before > 0 else "–"


def _plots(replay: Any, disc: Discovery, base: Any, final: Any, held: list[int], out: Path) -> None:
    from vdm_aero_cli.plots import _pyplot

    plt = _pyplot()
    sims = {"before": replay.simulate(base, held), "after": replay.simulate(final, held)}
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    fig2, axes2 = plt.subplots(1, len(held), figsize=(5 * len(held), 4.2), squeeze=False)
    for j, cid in enumerate(held):
        c = disc.cases[cid]
        cl_m = lift_drag(c.coeffs, c.alpha)[0]
        a_deg = np.degrees(c.alpha)
        axes2[0, j].plot(a_deg, cl_m, "k-", lw=1.5, label="measured")
        for (label, sim), colour in zip(sims.items(), ("tab:blue", "tab:red"), strict=True):
            cp, co = sim[cid]
            cl = lift_drag(co, c.alpha)[0]
            axes[0].plot(a_deg, cl_m - cl, ".", ms=2, color=colour, label=label if j == 0 else None)
            axes[1].plot(a_deg, np.sqrt(np.mean((c.cp - cp) ** 2, axis=1)), ".", ms=2, color=colour,
                         label=label if j == 0 else None)  # fmt: skip
            axes2[0, j].plot(a_deg, cl, "--" if label == "before" else ":", color=colour, lw=1.2, label=label)
        k = c.reduced_frequency
        axes2[0, j].set(
            xlabel="α [deg]", ylabel="C_L", title=f"case {cid}" + ("" if math.isnan(k) else f", k = {k:.3f}")
        )
        axes2[0, j].legend(fontsize=8)
    axes[0].set(xlabel="α [deg]", ylabel="C_L measured − simulated", title="lift residual, held-out cases")
    axes[1].set(xlabel="α [deg]", ylabel="RMS port Cp residual", title="port residual, held-out cases")
    axes[0].legend()
    for f, name in ((fig, "residuals.png"), (fig2, "loops.png")):
        f.tight_layout()
        f.savefig(out / name, dpi=110)
        plt.close(f)


def run_discover(args: argparse.Namespace) -> int:
    report = discover(args.sim, args.measured, args.out, seed=args.seed)
    if args.json:
        print(json.dumps(to_plain(report), indent=2))
        return 0
    named = ", ".join(
        f"{e['name']} ({', '.join(f'{k}={v:.4g}' for k, v in e['params'].items())})" for e in report["effects"]
    )
    print(f"named: {named or 'nothing (unexplained)'}; explained share {report['explained_share']:.1%}")
    b, a = report["gap_before"], report["gap_after"]
    for k in b["coeff_rms"]:
        print(f"  RMS {k:3}: {b['coeff_rms'][k]:.4g} → {a['coeff_rms'][k]:.4g}")
    print(f"  RMS Cp : {b['cp_rms']:.4g} → {a['cp_rms']:.4g}")
    print(f"wrote {args.out / 'report.md'}, report.json, spec.yaml, residuals.png, loops.png ({report['seconds']} s)")
    return 0
