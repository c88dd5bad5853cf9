"""Figures (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Dataset


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_dataset(ds: Dataset, out: Path) -> None:
    """CL and CD versus α loops for every case, and Cp along the chord at three phases."""
    plt = _pyplot()
    coeffs = ds.truth_coeffs()
    cl, cd = lift_drag(coeffs, ds.alpha, ds.beta)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    cmap = plt.get_cmap("viridis")
    for k, case in enumerate(ds.cases):
        m = ds.case == case.id
        colour = cmap(k / max(1, len(ds.cases) - 1))
        label = case.name
        axes[0].plot(np.degrees(ds.alpha[m]), cl[m], color=colour, lw=1, label=label)
        axes[1].plot(np.degrees(ds.alpha[m]), cd[m], color=colour, lw=1)
    axes[0].set(xlabel="α [deg]", ylabel="C_L", title=f"{ds.name}: lift")
    axes[1].set(xlabel="α [deg]", ylabel="C_D", title="drag")
    axes[0].legend(fontsize=7, ncol=2)
    # Cp snapshots of the first case at min α, max α and mid-upstroke, against x/c
    m = np.flatnonzero(ds.case == ds.cases[0].id)
    chord = ds.reference.chord_m
    x_c = (ds.points[:, 0].max() - ds.points[:, 0]) / chord
    picks = {
        "α min": m[np.argmin(ds.alpha[m])],
        "α max": m[np.argmax(ds.alpha[m])],
        "upstroke": m[len(m) // 4 // 2],
    }
    for label, row in picks.items():
        cp = np.asarray(ds.cp[row], dtype=np.float64)
        axes[2].scatter(x_c, cp, s=4, label=f"{label} ({np.degrees(ds.alpha[row]):.1f}°)")
    axes[2].invert_yaxis()
    axes[2].set(xlabel="x/c", ylabel="C_p", title=f"C_p snapshots, {ds.cases[0].name}")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


STYLE = {
    "truth": ("k", "-", "truth"),
    "deim": ("tab:blue", "--", "DEIM"),
    "deim_nn": ("tab:red", ":", "DEIM+NN"),
    "linear_regression": ("tab:green", "-.", "linear (ports)"),
    "mlp": ("tab:purple", (0, (5, 1, 1, 1)), "MLP (ports)"),
}


def plot_predictions(pred: dict[str, np.ndarray], out: Path, *, title: str) -> None:
    """C_L and C_D versus α and versus t: truth, DEIM, DEIM+NN and the port baselines present in ``pred``."""
    plt = _pyplot()
    alpha_deg = np.degrees(pred["alpha"])
    series = {k: lift_drag(pred[k], pred["alpha"]) for k in STYLE if k in pred}
    fig, axes = plt.subplots(2, 2, figsize=(13, 8))
    for j, coeff in enumerate(("C_L", "C_D")):
        for key, (cl, cd) in series.items():
            colour, ls, label = STYLE[key]
            y = cl if j == 0 else cd
            axes[j, 0].plot(alpha_deg, y, color=colour, ls=ls, lw=1.2, label=label)
            axes[j, 1].plot(pred["t"], y, color=colour, ls=ls, lw=1.2, label=label)
        axes[j, 0].set(xlabel="α [deg]", ylabel=coeff)
        axes[j, 1].set(xlabel="t [s]", ylabel=coeff)
    axes[0, 0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_method_errors(doc: dict[str, Any], case: int, out: Path, *, title: str) -> None:
    """Relative ℓ2 of C_L and C_D against n_s for every method of a paper-tables ``doc`` (one case), without
    and with noise; the noisy panels add the DEIM linear map's noise floor."""
    plt = _pyplot()
    rows = [r for r in doc["results"] if r["case"] == case]
    noises = sorted({r["noise"] for r in rows})
    fig, axes = plt.subplots(2, len(noises), figsize=(6.5 * len(noises), 8), squeeze=False)
    for j, noise in enumerate(noises):
        sel = sorted((r for r in rows if r["noise"] == noise), key=lambda r: r["n_sensors"])
        ns = [r["n_sensors"] for r in sel]
        for i, coeff in enumerate(("CL", "CD")):
            ax = axes[i, j]
            for key in ("deim", "deim_nn", "linear_regression", "mlp"):
                if all(key in r["metrics"][coeff] for r in sel):
                    colour, ls, label = STYLE[key]
                    ax.plot(ns, [r["metrics"][coeff][key]["l2"] for r in sel], "o", color=colour, ls=ls, label=label)
            if noise > 0:
                floor = [r["noise_floor"][coeff]["floor_l2"]["deim"] for r in sel]
                ax.plot(ns, floor, "k_", ls="-", lw=0.8, ms=12, label="noise floor (DEIM map)")
            ax.set_yscale("log")
            ax.set(xlabel="n_s", ylabel=f"{coeff} relative ℓ2", title=f"{coeff}, noise {noise * 100:g} %")
            ax.set_xticks(ns)
            ax.grid(True, which="both", alpha=0.3)
    for ax in axes[0]:
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_model_diagnostics(model_dir: Path, out: Path, *, title: str) -> None:
    """Ports on the fit surface numbered in DEIM order, scaled singular values, projection error vs n_b."""
    from vdm_aero.model import load_diagnostics

    plt = _pyplot()
    d = load_diagnostics(model_dir)
    pts, idx = d["fit_points_b"], d["fit_sensor_index"]
    fig, axes = plt.subplots(1, 3, figsize=(18, 4.5), gridspec_kw={"width_ratios": [2.2, 1, 1]})
    # body frame FRD: plot chordwise (−x, aft positive) against −z (up)
    axes[0].plot(-pts[:, 0], -pts[:, 2], ".", ms=1.5, color="0.6")
    for k, i in enumerate(idx):
        axes[0].plot(-pts[i, 0], -pts[i, 2], "o", color="tab:red", ms=5)
        axes[0].annotate(str(k + 1), (-pts[i, 0], -pts[i, 2]), textcoords="offset points", xytext=(3, 5), fontsize=9)
    axes[0].set(xlabel="−x_b [m] (aft)", ylabel="−z_b [m] (up)", title=f"{title}: ports in DEIM order")
    axes[0].set_aspect("equal")
    sv = d["singular_values"]
    axes[1].semilogy(np.arange(1, len(sv) + 1), sv / sv[0], "o-", ms=3)
    axes[1].set(xlabel="mode", ylabel="σ_k / σ_1", title="scaled singular values")
    eps = d["projection_error"]
    axes[2].semilogy(np.arange(1, len(eps) + 1), eps, "o-", ms=3)
    axes[2].set(xlabel="n_b", ylabel="ε_proj", title="projection error")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_ports_3d(ds: Dataset, model: Any, out: Path, *, max_points: int = 40_000) -> None:
    """The selected ports on the 3-D surface, numbered in DEIM order, and a Cp surface snapshot."""
    from vdm_aero.pipeline import port_columns

    plt = _pyplot()
    pts = np.asarray(ds.points)
    step = max(1, len(pts) // max_points)
    sub = slice(None, None, step)
    cols = port_columns(model, ds)
    row = int(np.argmax(np.asarray(ds.alpha)))  # the highest-incidence snapshot
    cp = np.asarray(ds.cp[row], dtype=np.float64)
    fig = plt.figure(figsize=(16, 6.5))
    for j, (title, colour) in enumerate(
        (("ports in DEIM order", None), (f"C_p at α = {np.degrees(ds.alpha[row]):.1f}°", cp))
    ):
        ax = fig.add_subplot(1, 2, j + 1, projection="3d")
        # FRD → plot x forward, y right, up = −z
        if colour is None:
            ax.scatter(pts[sub, 0], pts[sub, 1], -pts[sub, 2], s=0.3, c="0.7", alpha=0.4)
            ax.scatter(pts[cols, 0], pts[cols, 1], -pts[cols, 2], s=30, c="tab:red", depthshade=False)
            for k, i in enumerate(cols):
                ax.text(pts[i, 0], pts[i, 1], -pts[i, 2] + 0.02, str(k + 1), fontsize=9, color="k")
        else:
            sc = ax.scatter(pts[sub, 0], pts[sub, 1], -pts[sub, 2], s=0.6, c=colour[sub], cmap="RdBu",
                            vmin=-2.5, vmax=1.0)  # fmt: skip
            fig.colorbar(sc, ax=ax, shrink=0.6, label="C_p")
        ax.set(xlabel="x_b [m]", ylabel="y_b [m]", zlabel="−z_b [m]", title=title)
        ax.set_box_aspect((np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), max(np.ptp(pts[:, 2]), 0.2)))
        ax.view_init(elev=35, azim=-125)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
