"""CLI: fit → train → evaluate, and paper-tables, on small data in tmp_path."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from tests.test_cli import run_cli
from vdm_aero_cli.main import main

SPEC = {
    "kind": "airfoil",
    "name": "cli-0015",
    "airfoil": "naca0015",
    "chord_m": 0.3,
    "span_m": 0.075,
    "surface_points": 160,
    "speed_m_s": 30.0,
    "motion": {"type": "sinusoidal_pitch", "alpha0_deg": 15.0, "amplitude_deg": 6.0,
               "freqs_hz": [1.0, 2.0, 3.0, 2.5], "cycles": 1, "samples_per_cycle": 48},
    "effects": {"circulation_lag": {}, "trailing_edge_separation":
                {"alpha1_deg": 12.1, "s1_deg": 0.8, "s2_deg": 5.5, "slope_factor": 0.87}},
}  # fmt: skip


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("cli")
    (d / "spec.yaml").write_text(yaml.safe_dump(SPEC))
    assert main(["simulate", str(d / "spec.yaml"), "--out", str(d / "ds")]) == 0
    return d


def test_fit_train_evaluate(data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m = data / "model"
    assert main(["fit", "--data", str(data / "ds"), "--sensors", "5", "--cases", "0,1,2", "--out", str(m)]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--model", str(m), "--data", str(data / "ds"), "--cases", "3", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["n_sensors"] == 5 and res["noise"] == 0.0
    assert set(res["metrics"]) == {"CL", "CD"} and "deim_nn" not in res["metrics"]["CL"]
    assert set(res["metrics"]["CL"]["deim"]) == {"l2", "linf", "alpha_at_linf_deg"}
    tr = ["train", "--model", str(m), "--data", str(data / "ds"), "--train-cases", "0,1", "--val-cases", "2"]
    assert main([*tr, "--grid", "quick", "--seed", "3", "--max-epochs", "40"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--model", str(m), "--data", str(data / "ds"), "--cases", "3", "--noise", "0.015",
                 "--seed", "2", "--json"]) == 0  # fmt: skip
    res = json.loads(capsys.readouterr().out)
    assert res["noise"] == 0.015 and "deim_nn" in res["metrics"]["CD"]


def test_qdeim_and_modes_options(data: Path) -> None:
    m = data / "qdeim"
    assert main(["fit", "--data", str(data / "ds"), "--sensors", "6", "--modes", "4", "--method", "qdeim",
                 "--out", str(m)]) == 0  # fmt: skip
    meta = yaml.safe_load((m / "model.yaml").read_text())
    assert (meta["method"], meta["n_sensors"], meta["n_modes"]) == ("qdeim", 6, 4)


@pytest.mark.parametrize(
    ("args", "phrase"),
    [
        (["--cases", "0,9"], "--cases: case id(s) [9] not in cli-0015"),
        (["--cases", "a,b"], "--cases: expected comma-separated case ids"),
        (["--sensors", "0"], "--sensors: must be between 1 and 160"),
    ],
)
def test_fit_user_errors(data: Path, args: list[str], phrase: str) -> None:
    base = {"--data": str(data / "ds"), "--sensors": "5", "--out": str(data / "x")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    r = run_cli("fit", *[x for kv in base.items() for x in kv])
    assert r.returncode == 2 and phrase in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_train_rejects_overlapping_cases(data: Path) -> None:
    m = data / "model2"
    assert main(["fit", "--data", str(data / "ds"), "--sensors", "4", "--out", str(m)]) == 0
    r = run_cli("train", "--model", str(m), "--data", str(data / "ds"), "--train-cases", "0,1", "--val-cases", "1")
    assert r.returncode == 2 and "overlap" in r.stderr


def test_paper_tables_smoke(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    assert main(["paper-tables", "--case", "airfoil", "--out", str(out), "--sensors", "5", "--grid", "quick",
                 "--max-epochs", "30"]) == 0  # fmt: skip
    doc = json.loads((out / "tables.json").read_text())
    assert {(r["case"], r["noise"]) for r in doc["results"]} == {(1, 0.0), (1, 0.015), (2, 0.0), (2, 0.015)}
    md = (out / "tables.md").read_text()
    assert "## Case 2" in md and "| 5 | CL |" in md
    for png in ("case1-ns5-predictions.png", "case2-ns5-sensors.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def test_paper_tables_uav_smoke(tmp_path: Path) -> None:
    out = tmp_path / "uav"
    assert main(["paper-tables", "--case", "uav", "--out", str(out), "--sensors", "5", "--grid", "quick",
                 "--max-epochs", "20"]) == 0  # fmt: skip
    doc = json.loads((out / "tables.json").read_text())
    assert {(r["case"], r["noise"], r["n_sensors"]) for r in doc["results"]} == {(3, 0.0, 5), (3, 0.015, 5)}
    assert (out / "uav-ns5-ports.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "data" / "uav-pitch" / "states.npy").is_file()


def test_simulate_airframe_preset_streams_to_disk(tmp_path: Path) -> None:
    from vdm_aero.dataset import load_dataset

    assert main(["simulate", "uav-envelope", "--out", str(tmp_path / "env")]) == 0
    ds = load_dataset(tmp_path / "env")
    assert ds.cp.dtype.name == "float32" and ds.coeffs is not None and ds.coeffs.shape == (ds.n_snapshots, 6)
    import numpy as np

    states = np.load(tmp_path / "env" / "states.npy")
    assert states.shape == (ds.n_snapshots, 10)
    np.testing.assert_allclose(states[:, 1], ds.alpha)
