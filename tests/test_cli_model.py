"""CLI: fit → train → evaluate, and paper-tables, on small data in tmp_path."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
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


METHODS = {"deim", "deim_nn", "linear_regression", "mlp"}


@pytest.fixture(scope="module")
def trained(data: Path) -> Path:
    """DEIM (5 ports, cases 0-2) with its correction net trained on cases 0, 1 and selected on case 2."""
    m = data / "model"
    assert main(["fit", "--data", str(data / "ds"), "--sensors", "5", "--cases", "0,1,2", "--out", str(m)]) == 0
    tr = ["train", "--model", str(m), "--data", str(data / "ds"), "--train-cases", "0,1", "--val-cases", "2"]
    assert main([*tr, "--grid", "quick", "--seed", "3", "--max-epochs", "40"]) == 0
    return m


def test_fit_train_evaluate(data: Path, trained: Path, capsys: pytest.CaptureFixture[str]) -> None:
    m = data / "model-deim"
    assert main(["fit", "--data", str(data / "ds"), "--sensors", "5", "--cases", "0,1,2", "--out", str(m)]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--model", str(m), "--data", str(data / "ds"), "--cases", "3", "--json"]) == 0
    out = capsys.readouterr()
    res = json.loads(out.out)
    assert res["n_sensors"] == 5 and res["noise"] == 0.0
    assert set(res["metrics"]) == {"CL", "CD"} and set(res["metrics"]["CL"]) == {"deim"}
    assert set(res["metrics"]["CL"]["deim"]) == {"l2", "linf", "alpha_at_linf_deg"}
    # no net, no recorded training data: said in one line, evaluated without baselines
    assert res["baselines"]["skipped"] == out.err.strip() and "no correction net" in out.err
    ev = ["evaluate", "--model", str(trained), "--data", str(data / "ds"), "--cases", "3", "--json"]
    assert main(ev) == 0
    clean = json.loads(capsys.readouterr().out)
    assert set(clean["metrics"]["CD"]) == METHODS and "noise_floor" not in clean
    b = clean["baselines"]
    assert (b["dataset"], b["train_cases"], b["val_cases"]) == ("cli-0015", [0, 1], [2])
    assert (b["grid"], b["seed"], b["max_epochs"]) == ("quick", 3, 40)
    assert main([*ev, "--noise", "0.015", "--seed", "2"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["noise"] == 0.015 and set(res["metrics"]["CD"]) == METHODS
    for c in ("CL", "CD"):
        nf = res["noise_floor"][c]
        assert set(nf["floor_l2"]) == {"deim", "linear_regression"} and nf["floor_l2"]["deim"] > 0
        assert set(nf["amplification"]) == METHODS
        for k in METHODS:  # the noise-free figures are those of the noise-free run (same data, same seeds)
            assert nf["noise_free_l2"][k] == pytest.approx(clean["metrics"][c][k]["l2"], rel=1e-9)
            expected = res["metrics"][c][k]["l2"] / math.hypot(nf["noise_free_l2"][k], nf["floor_l2"]["deim"])
            assert nf["amplification"][k] == pytest.approx(expected, rel=1e-12)
    # the table: every method, the floor next to the noisy figures; --no-baselines skips them in one line
    ev[-1] = "--no-baselines"
    assert main([*ev, "--noise", "0.015"]) == 0
    out = capsys.readouterr()
    assert (
        "CL   DEIM+NN " in out.out and "CL   MLP " not in out.out and out.err.strip() == "no baselines (--no-baselines)"
    )
    assert "CD   noise floor ℓ2 of the linear map: DEIM " in out.out and "amplif." in out.out


def test_evaluate_finds_only_the_nets_training_data(
    data: Path, trained: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vdm_aero.dataset import load_dataset, write_dataset

    ds = load_dataset(data / "ds")
    other = write_dataset(tmp_path / "other", dataclasses.replace(ds, cp=np.asarray(ds.cp) * 1.1))  # same name
    ev = ["evaluate", "--model", str(trained), "--cases", "3", "--json"]
    assert main([*ev, "--data", str(data / "ds"), "--baseline-data", str(other)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--baseline-data {other}: not the net's training data" in err, err
    # the recorded path gone and D another data set: no baselines, said in one line
    moved = tmp_path / "model"
    shutil.copytree(trained, moved)
    meta = yaml.safe_load((moved / "model.yaml").read_text())
    meta["training"]["data_path"] = str(tmp_path / "gone")
    (moved / "model.yaml").write_text(yaml.safe_dump(meta, sort_keys=False, allow_unicode=True))
    ev[2] = str(moved)
    assert main([*ev, "--data", str(other)]) == 0
    out = capsys.readouterr()
    res = json.loads(out.out)
    assert set(res["metrics"]["CL"]) == {"deim", "deim_nn"} and len(out.err.strip().splitlines()) == 1
    assert res["baselines"]["skipped"] == out.err.strip()
    assert "the net's training data (cli-0015, cases [0, 1] + [2]) is not available" in out.err
    assert f"{tmp_path / 'gone'}: gone" in out.err and "pass --baseline-data" in out.err


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
    for r in doc["results"]:
        assert set(r["metrics"]["CL"]) == METHODS and r["baselines"]["train_cases"] == [0, 1, 2, 3]
        assert ("noise_floor" in r) == (r["noise"] > 0)
        if r["noise"] > 0:
            assert (
                r["noise_floor"]["CD"]["floor_l2"]["deim"] > 0 and "deim_nn" in r["noise_floor"]["CD"]["amplification"]
            )
    md = (out / "tables.md").read_text()
    assert "## Case 2" in md and "| 5 | CL |" in md
    assert "| linear ℓ2 | linear ℓ∞ | MLP ℓ2 | MLP ℓ∞ | best ℓ2 | floor ℓ2 | DEIM+NN amplif. |" in md
    for png in ("case1-ns5-predictions.png", "case2-ns5-sensors.png", "case1-errors.png", "case2-errors.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def test_paper_tables_uav_smoke(tmp_path: Path) -> None:
    out = tmp_path / "uav"
    assert main(["paper-tables", "--case", "uav", "--out", str(out), "--sensors", "5", "--grid", "quick",
                 "--max-epochs", "20"]) == 0  # fmt: skip
    doc = json.loads((out / "tables.json").read_text())
    assert {(r["case"], r["noise"], r["n_sensors"]) for r in doc["results"]} == {(3, 0.0, 5), (3, 0.015, 5)}
    assert all(set(r["metrics"]["CD"]) == METHODS for r in doc["results"])
    assert "| 5 | CD |" in (out / "tables.md").read_text()
    for png in ("uav-ns5-ports.png", "uav-errors.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"
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
