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
