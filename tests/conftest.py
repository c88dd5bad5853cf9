"""Fixtures shared across modules: the design data set of the reference UAV and its DEIM model (the user's
side of calibration and navigation), built once per session."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def design_deim12(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``uav-envelope`` simulated and DEIM fitted on 12 ports (training cases): {"data", "model"}."""
    from vdm_aero.dataset import load_dataset
    from vdm_aero.pipeline import fit_model
    from vdm_aero_cli.cmd_data import simulate_to
    from vdm_aero_cli.paper import case_roles

    root = tmp_path_factory.mktemp("design")
    ds_dir = simulate_to("uav-envelope", root / "env", quiet=True)
    ds = load_dataset(ds_dir)
    model_dir = root / "deim12"
    fit_model(ds, model_dir, n_sensors=12, cases=case_roles(ds)["train"])
    return {"data": ds_dir, "model": model_dir}
