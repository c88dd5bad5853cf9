"""DEIM / Q-DEIM port selection and the linear POD–DEIM force model."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import qr

from vdm_aero.coefficients import force_moment_matrix
from vdm_aero.dataset import Reference
from vdm_aero.deim import DEIMForceModel, deim_indices, projection_error, qdeim_indices
from vdm_aero.errors import NotFittedError
from vdm_aero.pod import pod_basis

# A 5×3 basis for the hand computation (columns u1, u2, u3; DEIM does not need orthonormal columns).
U_HAND = np.array(
    [
        [1.0, 2.0, 1.0],
        [3.0, 1.0, 0.0],
        [-4.0, 1.0, 2.0],
        [2.0, -1.0, 5.0],
        [0.0, 3.0, 1.0],
    ]
)


# --------------------------------------------------------------------------------------------------
# Synthetic vehicle: a stretched cylinder with smooth analytic pressure modes
# --------------------------------------------------------------------------------------------------


def cylinder(n_theta: int = 40, n_span: int = 15) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles θ, span stations y and the (6, N) force matrix of an elliptic cylinder (x–z section)."""
    th = (np.arange(n_theta) + 0.5) / n_theta * 2.0 * np.pi
    y = (np.arange(n_span) + 0.5) / n_span * 2.0 - 1.0
    tt, yy = (g.ravel() for g in np.meshgrid(th, y, indexing="ij"))
    pts = np.stack([0.3 * np.cos(tt), yy, 0.1 * np.sin(tt)], axis=1)
    nrm = -np.stack([np.cos(tt) / 0.3, np.zeros_like(tt), np.sin(tt) / 0.1], axis=1)  # into the body
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    areas = np.full(tt.size, 2.0 * np.pi * 0.2 / n_theta * 2.0 / n_span)
    s = force_moment_matrix(pts, nrm, areas, Reference(area_m2=2.0, chord_m=0.2, span_m=2.0))
    return tt, yy, s


def smooth_fields(rng: np.random.Generator, th: np.ndarray, y: np.ndarray, m: int, noise: float) -> np.ndarray:
    """(M, N) snapshots: a base Cp plus 4 smooth analytic modes with periodic amplitudes, plus noise."""
    t = np.linspace(0.0, 4.0 * np.pi, m)
    ph = rng.uniform(0.0, 2.0 * np.pi, 4)
    amp = np.stack(
        [
            np.sin(t + ph[0]),
            0.5 * np.cos(2.0 * t + ph[1]),
            0.3 * np.sin(3.0 * t + ph[2]),
            0.2 * np.cos(0.5 * t + ph[3]),
        ],
        axis=1,
    )
    amp += 0.05 * rng.standard_normal(amp.shape)
    shapes = np.stack([np.cos(th), np.sin(th) * (1 + 0.3 * y), np.cos(2 * th) * y, np.sin(2 * th) * (1 - y**2)], axis=1)
    base = 1.0 - 4.0 * np.sin(th) ** 2
    return base + amp @ shapes.T + noise * rng.standard_normal((m, th.size))


@pytest.fixture(scope="module")
def problem() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(train cp (300, 600), test cp (100, 600), S (6, 600)) with 1e-3 point noise."""
    th, y, s = cylinder()
    cp = smooth_fields(np.random.default_rng(0), th, y, 400, 1e-3)
    return cp[:300], cp[300:], s


# --------------------------------------------------------------------------------------------------
# DEIM / Q-DEIM selection
# --------------------------------------------------------------------------------------------------


def test_deim_hand_example() -> None:
    # l = 1: |u1| = [1, 3, 4, 2, 0]                        -> p1 = 2
    # l = 2: c = u2[2] / u1[2] = 1 / -4 = -1/4
    #        r = u2 + u1/4 = [2.25, 1.75, 0, -0.5, 3]       -> p2 = 4
    # l = 3: [[-4, 1], [0, 3]] c = [u3[2], u3[4]] = [2, 1]  -> c = [-5/12, 1/3]
    #        r = u3 + 5/12 u1 − 1/3 u2
    #          = [1 + 5/12 − 2/3, 0 + 15/12 − 1/3, 2 − 20/12 − 1/3, 5 + 10/12 + 1/3, 1 + 0 − 1]
    #          = [0.75, 0.9167, 0, 6.1667, 0]               -> p3 = 3
    np.testing.assert_array_equal(deim_indices(U_HAND), [2, 4, 3])
    # Candidates {0, 1, 2, 4}: same p1, p2; at l = 3 the residual over the candidates is
    # [0.75, 0.9167, 0, 0]                                  -> p3 = 1
    np.testing.assert_array_equal(deim_indices(U_HAND, np.array([0, 1, 2, 4])), [2, 4, 1])
    # Nested: the DEIM points of the leading two modes are the first two points.
    np.testing.assert_array_equal(deim_indices(U_HAND, n_sensors=2), [2, 4])
    assert deim_indices(U_HAND).dtype == np.int64


def test_deim_oversampling_is_greedy_d_optimal() -> None:
    rng = np.random.default_rng(1)
    u = rng.standard_normal((40, 4))
    picked = deim_indices(u, n_sensors=10)
    assert picked.size == 10
    assert np.unique(picked).size == 10  # never the same point twice
    np.testing.assert_array_equal(picked[:4], deim_indices(u))  # the first n_b are plain DEIM
    for k in range(4, 10):
        # brute force: the next point maximises det(U_pᵀU_p) over every unselected point
        def det_with(i: int, k: int = k) -> float:
            rows = u[np.append(picked[:k], i)]
            return float(np.linalg.det(rows.T @ rows))

        others = [i for i in range(40) if i not in picked[:k]]
        best = max(others, key=det_with)
        assert picked[k] == best
    q = qdeim_indices(u, n_sensors=7)
    assert np.unique(q).size == 7


def test_qdeim_equals_scipy_pivoted_qr() -> None:
    rng = np.random.default_rng(2)
    u, _ = np.linalg.qr(rng.standard_normal((500, 8)))
    _, _, piv = qr(u.T, pivoting=True)
    np.testing.assert_array_equal(qdeim_indices(u), piv[:8])
    np.testing.assert_array_equal(qdeim_indices(u, n_sensors=5), piv[:5])
    # on the hand basis too
    _, _, piv_h = qr(U_HAND.T, pivoting=True)
    np.testing.assert_array_equal(qdeim_indices(U_HAND), piv_h[:3])


@pytest.mark.parametrize("select", [deim_indices, qdeim_indices])
def test_candidates_restrict_the_selection(select: object) -> None:
    assert callable(select)
    rng = np.random.default_rng(3)
    u, _ = np.linalg.qr(rng.standard_normal((300, 6)))
    cand = np.sort(rng.choice(300, size=60, replace=False))
    picked = select(u, cand, n_sensors=9)
    assert np.isin(picked, cand).all()
    np.testing.assert_array_equal(picked, cand[select(u[cand], n_sensors=9)])
    mask = np.zeros(300, dtype=bool)
    mask[cand] = True
    np.testing.assert_array_equal(select(u, mask, n_sensors=9), picked)
    # the unrestricted choice differs (otherwise this test would prove nothing)
    assert not np.isin(select(u, n_sensors=9), cand).all()


def test_selection_validation() -> None:
    with pytest.raises(ValueError, match="out of range for N = 5"):
        deim_indices(U_HAND, [0, 5])
    with pytest.raises(ValueError, match="listed twice"):
        deim_indices(U_HAND, [0, 1, 1, 2])
    with pytest.raises(ValueError, match="n_sensors = 3 but only 2 candidate points"):
        deim_indices(U_HAND, [0, 1])
    with pytest.raises(ValueError, match="boolean mask of length 3"):
        qdeim_indices(U_HAND, np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="n_sensors must be an integer"):
        deim_indices(U_HAND, n_sensors=0)
    with pytest.raises(ValueError, match="expected a 2-D"):
        deim_indices(U_HAND[:, 0])
    # u1 and u3 agree on rows {0, 1, 2} up to scale: rank deficient there
    bad = np.array([[1.0, 0.0, 2.0], [2.0, 1.0, 4.0], [3.0, 5.0, 6.0], [9.0, 9.0, 9.0]])
    with pytest.raises(ValueError, match="rank deficient"):
        deim_indices(bad, [0, 1, 2])
    with pytest.raises(ValueError, match="rank deficient"):
        qdeim_indices(bad, [0, 1, 2])


def test_deim_scales_to_300k_candidates() -> None:
    # Timing is reported, not asserted: 300,000 × 15 took ≈ 0.15 s (DEIM) and ≈ 0.65 s (Q-DEIM) on the
    # 2-core development machine; 10 extra D-optimal ports add ≈ 0.01 s.
    rng = np.random.default_rng(4)
    u, _ = np.linalg.qr(rng.standard_normal((300_000, 15)))
    start = time.perf_counter()
    picked = deim_indices(u, n_sensors=25)
    elapsed = time.perf_counter() - start
    print(f"DEIM 300000 x 15 (+10 extra): {elapsed:.3f} s")
    assert np.unique(picked).size == 25
    assert np.isfinite(np.linalg.cond(u[picked[:15]]))
    np.testing.assert_array_equal(picked[:15], deim_indices(u))


# --------------------------------------------------------------------------------------------------
# The force model
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("method", ["deim", "qdeim"])
def test_square_deim_interpolates_the_ports_exactly(problem: tuple, dtype: type, method: str) -> None:
    train, test, s = problem
    model = DEIMForceModel(n_sensors=6, method=method).fit(train.astype(dtype), s)
    assert model.modes_.dtype == dtype
    assert model.Ms_.dtype == np.float64 and model.Ms_.shape == (6, 6)
    assert model.M0_.shape == (6,) and model.sensors_.shape == (6,)
    assert model.n_modes_ == model.n_sensors_ == 6
    ports = test[:, model.sensors_]
    rec = model.reconstruct(ports)
    assert rec.shape == test.shape
    np.testing.assert_allclose(rec[:, model.sensors_], ports, rtol=0, atol=1e-10)
    np.testing.assert_allclose(model.reconstruct(ports[0]), rec[0], atol=1e-12)


def test_oblique_projector(problem: tuple) -> None:
    train, _, s = problem
    model = DEIMForceModel(n_sensors=5).fit(train, s)
    u = np.asarray(model.modes_, dtype=np.float64)
    p = np.zeros((u.shape[0], 5))
    p[model.sensors_, np.arange(5)] = 1.0
    r = u @ np.linalg.inv(p.T @ u) @ p.T
    np.testing.assert_allclose(r @ r, r, atol=1e-10)
    np.testing.assert_allclose(r @ u, u, atol=1e-10)
    assert np.linalg.norm(r - r.T) > 1e-3  # oblique, not orthogonal
    np.testing.assert_allclose(model.port_pinv_, np.linalg.inv(p.T @ u), atol=1e-10)
    assert model.port_amplification_ == pytest.approx(np.linalg.norm(np.linalg.inv(p.T @ u), 2))


@pytest.mark.parametrize(("n_sensors", "n_modes"), [(6, None), (9, 4)])
def test_precomputed_matrices_equal_reconstruct_then_integrate(
    problem: tuple, n_sensors: int, n_modes: int | None
) -> None:
    train, test, s = problem
    model = DEIMForceModel(n_sensors=n_sensors, n_modes=n_modes).fit(train, s)
    ports = test[:, model.sensors_]
    via_field = model.reconstruct(ports) @ s.T
    pred = model.predict(ports)
    assert pred.shape == (test.shape[0], 6)
    np.testing.assert_allclose(pred, via_field, rtol=0, atol=1e-10)
    np.testing.assert_allclose(model.predict(ports[3]), pred[3], atol=1e-14)
    # and the formulas of the docstring
    u = model.modes_
    a = u[model.sensors_]
    np.testing.assert_allclose(model.Ms_, s @ u @ np.linalg.pinv(a), atol=1e-10)
    np.testing.assert_allclose(model.M0_, s @ model.mean_ - model.Ms_ @ model.mean_[model.sensors_], atol=1e-12)


@pytest.mark.parametrize(("n_sensors", "method"), [(4, "deim"), (7, "deim"), (7, "qdeim")])
def test_fields_in_the_span_are_reproduced_exactly(n_sensors: int, method: str) -> None:
    th, y, s = cylinder()
    rng = np.random.default_rng(5)
    cp = smooth_fields(rng, th, y, 200, 0.0)  # base + 4 modes exactly
    model = DEIMForceModel(n_sensors=n_sensors, n_modes=4, method=method).fit(cp, s)
    assert model.energy_ == pytest.approx(1.0, abs=1e-12)
    fresh = smooth_fields(np.random.default_rng(6), th, y, 50, 0.0)  # other amplitudes, same span
    truth = fresh @ s.T
    np.testing.assert_allclose(model.predict(fresh[:, model.sensors_]), truth, rtol=0, atol=1e-10)
    np.testing.assert_allclose(model.reconstruct(fresh[:, model.sensors_]), fresh, rtol=0, atol=1e-10)
    # a missing port changes nothing while the remaining ports still determine the 4 modes
    ports = fresh[:, model.sensors_].copy()
    if n_sensors > 4:
        ports[:, 2] = np.nan
        np.testing.assert_allclose(model.predict_gappy(ports), truth, rtol=0, atol=1e-10)


def test_gappy_with_one_missing_port_on_noisy_smooth_fields(problem: tuple) -> None:
    train, test, s = problem
    model = DEIMForceModel(n_sensors=8, n_modes=4).fit(train, s)
    truth = test @ s.T
    scale = float(np.abs(truth).max())  # 0.445 (CX, CZ dominate; CY is 0 by symmetry)
    ports = test[:, model.sensors_]
    full_err = float(np.abs(model.predict(ports) - truth).max()) / scale
    # Measured with 1e-3 point noise: 0.22 % of max|C| with all 8 ports, at worst 0.36 % with any
    # one port missing (ratio ≤ 1.6). Tolerances: 1 % absolute and 3× the all-ports error.
    assert full_err < 5e-3
    for k in range(8):
        gappy_ports = ports.copy()
        gappy_ports[:, k] = np.nan
        err = float(np.abs(model.predict_gappy(gappy_ports) - truth).max()) / scale
        assert err < 1e-2, f"port {k} missing: error {err:.2e} of max|C|"
        assert err < 3.0 * full_err
        present = np.ones(8, dtype=bool)
        present[k] = False
        ms, m0 = model.gappy(present)
        assert ms.shape == (6, 8) and m0.shape == (6,)
        np.testing.assert_array_equal(ms[:, k], 0.0)
        np.testing.assert_allclose(np.where(present, ports, 0.0) @ ms.T + m0, model.predict_gappy(gappy_ports))


def test_gappy_matrices(problem: tuple) -> None:
    train, _, s = problem
    model = DEIMForceModel(n_sensors=6, n_modes=4).fit(train, s)
    ms, m0 = model.gappy(np.ones(6, dtype=bool))
    np.testing.assert_allclose(ms, model.Ms_, atol=1e-12)
    np.testing.assert_allclose(m0, model.M0_, atol=1e-12)
    # three ports for four modes: the trailing mode is dropped (least squares on 3 modes)
    present = np.array([True, False, True, False, True, False])
    ms3, m03 = model.gappy(present)
    a = model.port_modes_[present, :3]
    expected = model.force_modes_[:, :3] @ np.linalg.inv(a)
    np.testing.assert_allclose(ms3[:, present], expected, atol=1e-10)
    np.testing.assert_array_equal(ms3[:, ~present], 0.0)
    np.testing.assert_allclose(m03, model.force_mean_ - expected @ model.mean_[model.sensors_[present]])
    ms3[:] = 0.0  # callers get copies: the cache is not corrupted
    np.testing.assert_allclose(model.gappy(present)[0][:, present], expected, atol=1e-10)


def test_predict_gappy_rows_with_different_patterns(problem: tuple) -> None:
    train, test, s = problem
    model = DEIMForceModel(n_sensors=7, n_modes=5).fit(train, s)
    ports = test[:4, model.sensors_].copy()
    ports[1, 0] = np.nan
    ports[2, [3, 5]] = np.nan
    ports[3, 6] = np.inf
    out = model.predict_gappy(ports)
    np.testing.assert_allclose(out[0], model.predict(ports[0]), atol=1e-14)
    for i in (1, 2, 3):
        present = np.isfinite(ports[i])
        ms, m0 = model.gappy(present)
        np.testing.assert_allclose(out[i], ms @ np.where(present, ports[i], 0.0) + m0, atol=1e-14)
        np.testing.assert_allclose(model.predict_gappy(ports[i]), out[i], atol=1e-14)
    ports[2] = np.nan
    with pytest.raises(ValueError, match="row 2 has every port missing"):
        model.predict_gappy(ports)
    with pytest.raises(ValueError, match="no port present"):
        model.gappy(np.zeros(7, dtype=bool))
    with pytest.raises(ValueError, match=r"expected \(7,\) bool"):
        model.gappy(np.ones(7, dtype=int))


def test_candidates_and_projection_error_in_the_model(problem: tuple) -> None:
    train, _, s = problem
    cand = np.arange(0, 600, 3)
    model = DEIMForceModel(n_sensors=6, candidates=cand).fit(train, s)
    assert np.isin(model.sensors_, cand).all()
    np.testing.assert_array_equal(model.sensors_, deim_indices(model.modes_, cand))
    errs = projection_error(train, model.pod_, [0, 2, 4, 6])
    assert errs[0] == pytest.approx(1.0)
    assert errs[2] < 0.05 and errs[3] <= errs[2]  # 4 smooth modes + 1e-3 noise


def test_randomized_pod_is_reproducible_without_a_seed(problem: tuple) -> None:
    train, _, s = problem
    a = DEIMForceModel(n_sensors=5, pod_method="randomized").fit(train, s)
    b = DEIMForceModel(n_sensors=5, pod_method="randomized").fit(train, s)
    np.testing.assert_array_equal(a.Ms_, b.Ms_)
    exact = DEIMForceModel(n_sensors=5, pod_method="exact").fit(train, s)
    np.testing.assert_array_equal(a.sensors_[:4], exact.sensors_[:4])


def test_not_fitted_error() -> None:
    model = DEIMForceModel(n_sensors=3)
    for call in (
        lambda: model.predict(np.zeros(3)),
        lambda: model.reconstruct(np.zeros(3)),
        lambda: model.gappy(np.ones(3, dtype=bool)),
        lambda: model.predict_gappy(np.zeros(3)),
    ):
        with pytest.raises(NotFittedError, match="not fitted yet: call fit"):
            call()


def test_fit_validation(problem: tuple) -> None:
    train, _, s = problem
    small = train[:5]
    cases: list[tuple[DEIMForceModel, tuple, str]] = [
        (DEIMForceModel(n_sensors=0), (train, s), "n_sensors must be an integer ≥ 1"),
        (DEIMForceModel(n_sensors=6, n_modes=6), (small, s), r"n_modes = 6 exceeds min\(M, N\) = 5"),
        (DEIMForceModel(n_sensors=3, n_modes=4), (train, s), "n_modes = 4 exceeds n_sensors = 3"),
        (DEIMForceModel(n_sensors=3, n_modes=0), (train, s), "n_modes must be an integer"),
        (DEIMForceModel(n_sensors=3, method="qr"), (train, s), "method must be one of"),
        (DEIMForceModel(n_sensors=3, candidates=[1, 600]), (train, s), "index 600 out of range for N = 600"),
        (DEIMForceModel(n_sensors=3, candidates=[1, 2]), (train, s), "n_sensors = 3 but only 2 candidate"),
        (DEIMForceModel(n_sensors=3), (train, s[:, :10]), r"force_matrix: shape \(6, 10\)"),
        (DEIMForceModel(n_sensors=3), (train[0], s), "cp: shape"),
        (DEIMForceModel(n_sensors=3), (train, s, np.zeros((7, 6))), r"truth: shape \(7, 6\)"),
        (DEIMForceModel(n_sensors=3, pod_method="svd"), (train, s), "method must be one of"),
    ]
    for model, args, message in cases:
        with pytest.raises(ValueError, match=message):
            model.fit(*args)
    fitted = DEIMForceModel(n_sensors=3).fit(train, s, train @ s.T)
    with pytest.raises(ValueError, match=r"expected \(3,\) or \(K, 3\)"):
        fitted.predict(np.zeros(4))
    with pytest.raises(ValueError, match=r"expected \(3,\) or \(K, 3\)"):
        fitted.reconstruct(np.zeros((2, 2, 3)))


def test_params_and_repr() -> None:
    model = DEIMForceModel(n_sensors=4, n_modes=2, method="qdeim", candidates=[1, 2, 3, 4, 5])
    assert model.get_params()["method"] == "qdeim"
    assert "candidates=<5 candidates>" in repr(model)
    assert not hasattr(model, "Ms_")


def test_fit_on_a_float32_memmap(tmp_path: Path, problem: tuple) -> None:
    train, test, s = problem
    path = tmp_path / "cp.npy"
    np.save(path, train.astype(np.float32))
    cp = np.load(path, mmap_mode="r")
    model = DEIMForceModel(n_sensors=6, n_modes=4, pod_method="snapshots").fit(cp, s)
    assert isinstance(cp, np.memmap)
    assert model.modes_.dtype == np.float32
    assert model.mean_.dtype == np.float64
    pod64 = pod_basis(train, 4)
    cosines = np.linalg.svd(pod64.modes.T @ model.modes_.astype(np.float64), compute_uv=False)
    assert cosines.min() > 1 - 1e-6  # the 4 signal modes: same subspace as the float64 POD
    truth = test @ s.T
    err = np.abs(model.predict(test[:, model.sensors_]) - truth).max() / np.abs(truth).max()
    assert err < 1e-2
