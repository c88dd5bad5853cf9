"""The offline fit at scale, scaled down: synthetic writer, subprocess fit, honest RSS, fitted model."""

from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from vdm_aero.dataset import load_dataset
from vdm_aero.fit_scale import (
    bench_fit_scale,
    ellipsoid_area,
    ellipsoid_surface,
    make_synthetic_snapshots,
    run_fit_scale,
)

N_POINTS = 30_000
N_SNAPSHOTS = 300
SNAPSHOT_MB = N_POINTS * N_SNAPSHOTS * 4 / 2**20  # float32


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The scaled-down 3-D data set (34 MB float32), written once for the module."""
    out = tmp_path_factory.mktemp("fit-scale") / "synthetic"
    return make_synthetic_snapshots(out, n_points=N_POINTS, n_snapshots=N_SNAPSHOTS, rng=np.random.default_rng(0))


# --------------------------------------------------------------------------------------------------
# The synthetic body and data set
# --------------------------------------------------------------------------------------------------


def test_ellipsoid_area_matches_closed_forms() -> None:
    assert ellipsoid_area((2.0, 2.0, 2.0)) == pytest.approx(4.0 * math.pi * 4.0, rel=1e-13)
    a, b = 1.0, 0.25  # prolate spheroid: A = 2πb²(1 + a/(b e) asin e), e² = 1 − b²/a²
    e = math.sqrt(1.0 - b**2 / a**2)
    assert ellipsoid_area((a, b, b)) == pytest.approx(
        2.0 * math.pi * b**2 * (1.0 + a / (b * e) * math.asin(e)), rel=1e-12
    )
    assert ellipsoid_area((b, a, b)) == pytest.approx(ellipsoid_area((a, b, b)), rel=1e-12)  # axis order is irrelevant


def test_ellipsoid_surface_is_a_closed_body_with_inward_normals() -> None:
    axes = (1.0, 0.25, 0.2)
    points, normals, areas, sphere = ellipsoid_surface(5000, axes)
    assert points.shape == normals.shape == sphere.shape == (5000, 3)
    np.testing.assert_allclose(np.sum((points / np.array(axes)) ** 2, axis=1), 1.0, atol=1e-12)  # on the surface
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert (np.einsum("ij,ij->i", normals, points) < 0.0).all()  # convex body centred at 0: inward ⇔ n·r < 0
    assert (areas > 0.0).all()
    assert float(areas.sum()) == pytest.approx(ellipsoid_area(axes), rel=1e-12)
    # a closed surface: Σ n dA = 0 (to quadrature accuracy) and every octant is populated
    assert np.linalg.norm(normals.T @ areas) < 1e-3 * float(areas.sum())
    assert len({tuple(v) for v in (points > 0)}) == 8
    # the Fibonacci cells are quasi-uniform: areas vary only with the body's curvature
    assert areas.max() / areas.min() < 6.0


def test_synthetic_dataset_is_valid_and_written_chunk_by_chunk(tmp_path: Path) -> None:
    n, m = 20_000, 400
    tracemalloc.start()
    try:
        path = make_synthetic_snapshots(
            tmp_path / "ds", n_points=n, n_snapshots=m, n_modes_true=10, rng=np.random.default_rng(3),
            chunk_elements=200_000,  # 10 rows per chunk: 40 chunks
        )  # fmt: skip
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # numpy reports its buffers to tracemalloc: the (M, N) matrix (32 MB in float32) is never held, only
    # the (K, N) modes, the surface arrays, the area quadrature's grids (~8 MB in all) and one chunk
    assert peak < 0.35 * m * n * 4
    ds = load_dataset(path, mmap=True, check_values=True)  # full validation, NaN scan included
    assert ds.cp.shape == (m, n)
    assert ds.cp.dtype == np.float32
    assert isinstance(ds.cp, np.memmap)
    assert len(ds.cases) == 2  # clamp(M // 200, 1, 10)
    assert set(np.unique(ds.case)) == {c.id for c in ds.cases}
    assert np.all(np.abs(np.rad2deg(ds.alpha)) < 20.0)
    cp = np.asarray(ds.cp, dtype=np.float64)
    # stagnation at the nose: Cp ≈ 1 at the most forward point, about 1 − 9/4 at the equator
    nose = int(np.argmax(ds.points[:, 0]))
    assert float(np.mean(cp[:, nose])) == pytest.approx(1.0, abs=0.6)
    # a decaying spectrum of 10 smooth modes, then a floor of 1e-3 noise (σ ≈ 1e-3 (√N + √M) ≈ 0.16)
    xc = cp - cp.mean(axis=0)
    s = np.sqrt(np.clip(np.linalg.eigvalsh(xc @ xc.T)[::-1], 0.0, None))  # singular values via the Gram
    assert np.all(np.diff(s[:10]) < 0.0)
    assert s[0] > 3.0 * s[9]
    assert s[9] > 30.0 * s[10]
    assert s[10] == pytest.approx(1e-3 * (math.sqrt(n) + math.sqrt(m)), rel=0.3)
    # reproducible from the Generator; another chunk size draws the same noise (only BLAS rounding of
    # the mode products differs, ~1 ulp, where a different noise stream would differ by ~1e-3)
    same = make_synthetic_snapshots(
        tmp_path / "same", n_points=n, n_snapshots=m, n_modes_true=10, rng=np.random.default_rng(3),
        chunk_elements=200_000,
    )  # fmt: skip
    np.testing.assert_array_equal(np.load(same / "cp.npy"), np.load(path / "cp.npy"))
    other = make_synthetic_snapshots(
        tmp_path / "other", n_points=n, n_snapshots=m, n_modes_true=10, rng=np.random.default_rng(3)
    )
    np.testing.assert_allclose(np.load(other / "cp.npy"), np.load(path / "cp.npy"), rtol=0, atol=2e-6)


def test_synthetic_dataset_rejects_bad_arguments(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="n_points"):
        make_synthetic_snapshots(tmp_path / "a", n_points=3, n_snapshots=5, rng=rng)
    with pytest.raises(ValueError, match="n_snapshots"):
        make_synthetic_snapshots(tmp_path / "a", n_points=100, n_snapshots=0, rng=rng)
    with pytest.raises(ValueError, match="Generator"):
        make_synthetic_snapshots(tmp_path / "a", n_points=100, n_snapshots=5, rng=0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_cases"):
        make_synthetic_snapshots(tmp_path / "a", n_points=100, n_snapshots=5, rng=rng, n_cases=6)
    with pytest.raises(ValueError, match="semi_axes"):
        make_synthetic_snapshots(tmp_path / "a", n_points=100, n_snapshots=5, rng=rng, semi_axes=(1.0, 0.0, 1.0))
    assert not (tmp_path / "a").exists()


# --------------------------------------------------------------------------------------------------
# The measured fit in a subprocess
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("method", "blas_threads"), [("snapshots", None), ("randomized", 1)])
def test_fit_in_a_subprocess_measures_and_reproduces_the_forces(
    synthetic: Path, tmp_path: Path, method: str, blas_threads: int | None
) -> None:
    model_file = tmp_path / "model.npz"
    res = run_fit_scale(
        synthetic, n_sensors=15, method=method, rng=np.random.default_rng(1), save_model=model_file,
        blas_threads=blas_threads,
    )  # fmt: skip
    for key in ("seconds", "peak_rss_mb", "snapshot_mb", "points", "snapshots", "method", "deim_seconds"):
        assert key in res
    assert (res["points"], res["snapshots"], res["method"], res["dtype"]) == (N_POINTS, N_SNAPSHOTS, method, "float32")
    assert res["snapshot_mb"] == pytest.approx(SNAPSHOT_MB, abs=0.1)
    assert res["blas_threads"] == ("default" if blas_threads is None else blas_threads)
    assert 0.0 < res["seconds"] < 60.0
    assert 0.0 <= res["deim_seconds"] <= res["seconds"]

    # memory: measured in the child (the pytest parent is far bigger than this), anonymous part too
    assert res["baseline_rss_mb"] <= res["peak_rss_mb"]
    assert res["peak_anon_mb"] is not None
    assert res["peak_anon_mb"] <= res["peak_rss_mb"]
    # no float64 copy of the snapshots (that alone would be 2 × snapshot_mb of anonymous memory)
    assert res["peak_anon_mb"] - res["baseline_anon_mb"] < 1.5 * SNAPSHOT_MB
    # the memory map's pages that were read are resident, file-backed, once each
    assert res["rss_file_mb_end"] < SNAPSHOT_MB + 64.0

    # time breakdown: the phases add up to the POD, which is almost all of the fit
    bd = res["breakdown"]
    pod_phases = sum(v for k, v in bd.items() if k.startswith("pod_") and k != "pod_total")
    assert pod_phases == pytest.approx(bd["pod_total"], abs=1e-3)
    assert bd["pod_setup_and_dispatch"] < 0.2  # the rest is attributed to lines of the POD routine
    assert bd["pod_total"] + bd["deim_selection"] + bd["model_matrices_and_checks"] <= res["seconds"] + 1e-3
    if method == "snapshots":
        assert {"pod_gram_accumulation", "pod_eigendecomposition", "pod_mode_formation"} <= set(bd)
    else:
        assert {"pod_mean_pass", "pod_passes_over_x"} <= set(bd)
    assert res["lines"] and all({"function", "source", "seconds"} <= set(row) for row in res["lines"])

    # the fitted model: orthonormal float32 modes; reproduces the held-in forces
    model = np.load(model_file)
    modes = model["modes"]
    assert modes.shape == (N_POINTS, 15)
    assert modes.dtype == np.float32
    np.testing.assert_allclose(modes.T.astype(np.float64) @ modes, np.eye(15), atol=1e-5)
    assert list(model["sensors"]) == res["sensors"]
    ds = load_dataset(synthetic)
    cp = np.asarray(ds.cp, dtype=np.float64)
    truth = cp @ ds.force_matrix().T  # (M, 6) pressure-integral coefficients
    pred = cp[:, model["sensors"]] @ model["Ms"].T + model["M0"]
    rel_rms = np.sqrt(np.mean((pred - truth) ** 2, axis=0)) / np.std(truth, axis=0)
    # 15 of 40 smooth modes plus 1e-3 noise: measured ≤ 0.4 % per coefficient; the bar is 2 %
    assert rel_rms.max() < 0.02, rel_rms


def test_fit_reports_a_failed_child(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match=r"missing|does not exist"):
        run_fit_scale(tmp_path / "nowhere", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="method"):
        run_fit_scale(tmp_path, method="exact", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="blas_threads"):
        run_fit_scale(tmp_path, rng=np.random.default_rng(0), blas_threads=0)


def test_bench_fit_scale_cleans_up_unless_kept(tmp_path: Path) -> None:
    res = bench_fit_scale(20_000, 100, workdir=tmp_path, seed=1, n_sensors=10, page_cache="cold")
    for key in ("seconds", "peak_rss_mb", "snapshot_mb", "write_seconds", "loadavg_before", "meets_bar"):
        assert key in res
    assert res["page_cache"] == "cold"
    assert res["dataset"] is None
    assert isinstance(res["meets_bar"], bool)
    assert res["bar_peak_rss_mb"] == pytest.approx(2.0 * res["snapshot_mb"], abs=0.1)
    assert list(tmp_path.iterdir()) == []  # the 7.6 MB data set is gone
    kept = bench_fit_scale(2_000, 40, workdir=tmp_path, keep=True, n_sensors=5, page_cache="warm")
    assert kept["dataset"] is not None
    assert load_dataset(kept["dataset"]).cp.shape == (40, 2_000)
    with pytest.raises(ValueError, match="page_cache"):
        bench_fit_scale(2_000, 40, workdir=tmp_path, page_cache="hot")
    with pytest.raises(ValueError, match="n_sensors"):
        bench_fit_scale(2_000, 40, workdir=tmp_path, n_sensors=41)
