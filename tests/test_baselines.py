"""The evaluation's baselines (direct linear regression and MLP from the ports) and the noise floor."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vdm_aero.calibrate import apply_linear, linear_baseline
from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Case, Dataset, Reference
from vdm_aero.evaluation import add_port_noise, linear_noise_floor, port_noise_std
from vdm_aero.model import AeroModel
from vdm_aero.pipeline import evaluate_model, fit_baselines, fit_model, ports_and_truth
from vdm_aero.train_correction import GRIDS

N_POINTS, N_PORTS, PER_CASE = 8, 5, 40


def _synthetic(seed: int = 0) -> Dataset:
    """8 points on a circle (78 mm apart: port matching is unambiguous), 4 cases of 40 random snapshots."""
    rng = np.random.default_rng(seed)
    phi = np.linspace(0.0, 2.0 * np.pi, N_POINTS, endpoint=False)
    points = 0.1 * np.column_stack([np.cos(phi), np.zeros(N_POINTS), np.sin(phi)])
    m = 4 * PER_CASE
    return Dataset(
        name="synthetic",
        source="test",
        reference=Reference(0.1, 0.3, 0.5),
        cases=tuple(Case(i, f"c{i}") for i in range(4)),
        cp=rng.standard_normal((m, N_POINTS)) + 6.0 * np.cos(phi) - 0.5,  # a mean load: DEIM's output is not small
        points=points,
        normals=-points / 0.1,
        areas=np.full(N_POINTS, 0.01),
        alpha=rng.uniform(0.0, 0.4, m),
        t=np.tile(np.arange(PER_CASE) * 0.01, 4),
        case=np.repeat(np.arange(4), PER_CASE),
    )


@pytest.fixture(scope="module")
def deim5(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, AeroModel]:
    """DEIM with 5 of the 8 points as ports: its truth (the pressure integral) is not linear in the ports."""
    ds = _synthetic()
    return ds, fit_model(ds, tmp_path_factory.mktemp("deim5") / "m", n_sensors=N_PORTS, cases=[0, 1, 2])


def _affine_truth(ds: Dataset, model: AeroModel, noise: float, seed: int) -> tuple[Dataset, np.ndarray]:
    """``ds`` whose truth is an affine map of the model's port Cp (plus optional noise), and that map."""
    rng = np.random.default_rng(seed)
    w = np.vstack([[1.0, -2.0, 3.0, 0.5, -0.7, 0.2], rng.standard_normal((N_PORTS, 6))])
    x, _, _ = ports_and_truth(model, ds, ds.case_ids())
    y = apply_linear(w, x) + noise * rng.standard_normal((len(x), 6))
    return dataclasses.replace(ds, coeffs=y), w


def test_linear_baseline_recovers_an_exact_affine_map(deim5: tuple[Dataset, AeroModel]) -> None:
    ds, w_true = _affine_truth(*deim5, noise=0.0, seed=1)
    model = deim5[1]
    x, y, _ = ports_and_truth(model, ds, [0, 1])
    w = linear_baseline(x, y)
    np.testing.assert_allclose(w, w_true, rtol=0, atol=1e-10)
    x3, y3, _ = ports_and_truth(model, ds, [3])
    np.testing.assert_allclose(apply_linear(w, x3), y3, rtol=0, atol=1e-10)


def test_fit_baselines_on_the_training_cases_and_evaluate(deim5: tuple[Dataset, AeroModel]) -> None:
    ds, w_true = _affine_truth(*deim5, noise=0.05, seed=2)
    model = deim5[1]
    b = fit_baselines(model, ds, train_cases=[0, 1], val_cases=[2], grid="quick", seed=0, max_epochs=5)
    # reference: least squares on the training cases only, built here with numpy's lstsq
    x, y, _ = ports_and_truth(model, ds, [0, 1])
    ref, *_ = np.linalg.lstsq(np.column_stack([np.ones(len(x)), x]), y, rcond=None)
    np.testing.assert_allclose(b.linear_w, ref, rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(b.linear_w - w_true)) < 0.1  # 80 samples, noise 0.05: the map is recovered
    s = b.summary
    assert (s["train_cases"], s["val_cases"], s["grid"], s["max_epochs"]) == ([0, 1], [2], "quick", 5)
    assert any(dataclasses.asdict(c) == s["mlp_selected"] for c in GRIDS["quick"])
    assert s["mlp_onnx_vs_torch_max_abs"] <= 1e-5
    # the MLP learns the coefficients (their mean offset w_true[0]), not a residual of DEIM
    x3, y3, _ = ports_and_truth(model, ds, [3])
    mlp = b.predict(x3)["mlp"]
    resid = y3 - model.predict_batch(x3, linear_only=True)
    assert np.linalg.norm(mlp.mean(0) - y3.mean(0)) < np.linalg.norm(mlp.mean(0) - resid.mean(0))
    res = evaluate_model(model, ds, [3], baselines=b)
    for c in ("CL", "CD"):
        assert set(res["metrics"][c]) == {"deim", "linear_regression", "mlp"}
        # the truth is affine in the ports up to 0.05 noise: the regression beats DEIM, whose truth it is not
        assert res["metrics"][c]["linear_regression"]["l2"] < res["metrics"][c]["deim"]["l2"]


def test_noise_floor_matches_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    k, n_s, noise = 60, 6, 0.015
    ms = rng.standard_normal((6, n_s))
    x = rng.standard_normal((k, n_s)) - 0.3
    alpha, beta = rng.uniform(-0.2, 0.5, k), rng.uniform(-0.1, 0.1, k)
    truth = rng.standard_normal((k, 6)) + 1.0
    floor = linear_noise_floor(ms, port_noise_std(x, noise), truth, alpha, beta)
    draws = 2000
    sq: dict[str, list[float]] = {"CL": [], "CD": []}
    for _ in range(draws):
        dc = (add_port_noise(x, noise, rng) - x) @ ms.T  # the linear map's output noise (M_0 cancels)
        dl, dd = lift_drag(dc, alpha, beta)
        sq["CL"].append(float(np.sum(dl**2)))
        sq["CD"].append(float(np.sum(dd**2)))
    cl_t, cd_t = lift_drag(truth, alpha, beta)
    for c, norm in (("CL", np.linalg.norm(cl_t)), ("CD", np.linalg.norm(cd_t))):
        v = np.asarray(sq[c])
        se = v.std(ddof=1) / math.sqrt(draws)
        assert se < 0.02 * v.mean()  # the Monte Carlo resolves the floor to ~2 %
        assert abs(v.mean() - (floor[c] * norm) ** 2) < 4.0 * se, (c, v.mean(), (floor[c] * norm) ** 2, se)


def test_evaluate_reports_the_floor_of_the_noise_it_applies(deim5: tuple[Dataset, AeroModel]) -> None:
    # truth = DEIM's own linear prediction, so the noisy error is the propagated noise alone: over noise draws
    # of evaluate_model itself, the mean of ℓ2² is the reported floor² (a wrong σ_i would miss it)
    ds, model = deim5
    x, _, _ = ports_and_truth(model, ds, ds.case_ids())
    ds = dataclasses.replace(ds, coeffs=model.predict_batch(x, linear_only=True))
    seeds = 300
    runs = [evaluate_model(model, ds, [3], noise=0.015, seed=s) for s in range(seeds)]
    for c in ("CL", "CD"):
        nf = runs[0]["noise_floor"][c]
        floor = nf["floor_l2"]["deim"]
        assert floor > 0 and nf["noise_free_l2"]["deim"] < 1e-12
        assert all(r["noise_floor"][c]["floor_l2"]["deim"] == floor for r in runs)
        sq = np.array([r["metrics"][c]["deim"]["l2"] ** 2 for r in runs])
        se = sq.std(ddof=1) / math.sqrt(seeds)
        assert se < 0.02 * floor**2  # enough draws to resolve the floor to ~2 %
        assert abs(sq.mean() - floor**2) < 4.0 * se, (c, sq.mean(), floor**2, se)
        amp = np.array([r["noise_floor"][c]["amplification"]["deim"] for r in runs])
        np.testing.assert_allclose(amp, np.sqrt(sq) / math.hypot(nf["noise_free_l2"]["deim"], floor), rtol=1e-9)


def test_tables_markdown_has_the_baselines_and_the_floor() -> None:
    from vdm_aero_cli.paper import tables_markdown

    m = {"l2": 0.1, "linf": 0.2, "alpha_at_linf_deg": 10.0}
    row = {
        "case": 1,
        "n_sensors": 5,
        "noise": 0.015,
        "metrics": {
            c: {
                "deim": m,
                "deim_nn": {**m, "l2": 0.05},
                "linear_regression": {**m, "l2": 0.08},
                "mlp": {**m, "l2": 0.04},
            }
            for c in ("CL", "CD")
        },
        "noise_floor": {c: {"floor_l2": {"deim": 0.01}, "amplification": {"deim_nn": 1.25}} for c in ("CL", "CD")},
    }
    md = tables_markdown({"case": "airfoil", "grid": "quick", "seed": 0, "train_noise": 0.0, "results": [row]})
    line = next(ln for ln in md.splitlines() if ln.startswith("| 5 | CL |"))
    cells = [x.strip() for x in line.strip(" |").split("|")]
    assert len(cells) == 16
    assert (cells[8], cells[9], cells[11]) == ("2.0×", "8.000e-02", "4.000e-02")
    assert cells[13:] == ["MLP", "1.000e-02", "1.25"]
    assert "| linear ℓ2 | linear ℓ∞ | MLP ℓ2 | MLP ℓ∞ | best ℓ2 | floor ℓ2 | DEIM+NN amplif. |" in md
