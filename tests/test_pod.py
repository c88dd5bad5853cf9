"""POD: the exact, method-of-snapshots and randomized routes agree; chunked memmaps stay small."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import subspace_angles

from vdm_aero.pod import (
    PODResult,
    pod_basis,
    projection_error,
    projection_error_from_singular_values,
)


def low_rank(
    rng: np.random.Generator,
    m: int,
    n: int,
    sv: np.ndarray,
    noise: float,
    dtype: type[np.floating] = np.float64,
) -> tuple[np.ndarray, np.ndarray]:
    """Snapshots ``2 + sin + A diag(sv) Bᵀ + noise`` (A, B orthonormal, centred A); returns (X, B)."""
    r = sv.size
    a = rng.standard_normal((m, r))
    a -= a.mean(axis=0)  # centred coefficients: the mean snapshot is exactly the offset below
    a, _ = np.linalg.qr(a)
    b, _ = np.linalg.qr(rng.standard_normal((n, r)))
    offset = 2.0 + np.sin(np.linspace(0.0, 3.0, n))
    x = offset + (a * sv) @ b.T + noise * rng.standard_normal((m, n))
    return x.astype(dtype), b


def max_angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.max(subspace_angles(np.asarray(u, np.float64), np.asarray(v, np.float64))))


SV = np.array([100.0, 50.0, 25.0, 12.0, 6.0, 3.0])


# --------------------------------------------------------------------------------------------------
# Agreement between the routes
# --------------------------------------------------------------------------------------------------


def test_exact_matches_numpy_svd_and_is_orthonormal() -> None:
    rng = np.random.default_rng(0)
    x, _ = low_rank(rng, 40, 90, SV, 1e-3)
    pod = pod_basis(x, 4, method="exact")
    xc = x - x.mean(axis=0)
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    assert pod.method == "exact"
    assert pod.modes.shape == (90, 4)
    assert pod.modes.dtype == np.float64
    np.testing.assert_allclose(pod.mean, x.mean(axis=0), rtol=0, atol=1e-13)
    np.testing.assert_allclose(pod.singular_values, s[:4], rtol=1e-12)
    np.testing.assert_allclose(pod.all_singular_values, s, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(pod.modes.T @ pod.modes, np.eye(4), atol=1e-12)
    # same vectors up to sign, and the sign convention makes the largest entry positive
    np.testing.assert_allclose(np.abs(pod.modes.T @ vt[:4].T), np.eye(4), atol=1e-10)
    assert (pod.modes[np.argmax(np.abs(pod.modes), axis=0), np.arange(4)] > 0).all()
    assert pod.total_energy == pytest.approx(float(np.sum(xc**2)), rel=1e-12)
    assert pod.energy == pytest.approx(float(np.sum(s[:4] ** 2) / np.sum(s**2)), rel=1e-12)


@pytest.mark.parametrize(("m", "n"), [(60, 400), (400, 60)])  # M×M Gram and N×N covariance routes
@pytest.mark.parametrize("method", ["snapshots", "randomized"])
def test_methods_agree_with_exact_svd_float64(m: int, n: int, method: str) -> None:
    rng = np.random.default_rng(1)
    x, _ = low_rank(rng, m, n, SV, 1e-3)
    exact = pod_basis(x, 5, method="exact")
    other = pod_basis(x, 5, method=method, rng=np.random.default_rng(7))
    assert other.method == method
    assert max_angle(other.modes, exact.modes) < 1e-6
    np.testing.assert_allclose(other.singular_values, exact.singular_values, rtol=1e-4)
    np.testing.assert_allclose(other.mean, exact.mean, atol=1e-12)
    np.testing.assert_allclose(other.modes.T @ other.modes, np.eye(5), atol=1e-10)
    assert other.total_energy == pytest.approx(exact.total_energy, rel=1e-10)
    # same sign convention: the modes themselves agree, not just the subspace
    np.testing.assert_allclose(other.modes, exact.modes, atol=1e-6)
    if method == "snapshots":
        assert other.all_singular_values is not None
        np.testing.assert_allclose(other.all_singular_values[:6], exact.all_singular_values[:6], rtol=1e-8)
    else:
        assert other.all_singular_values is None


@pytest.mark.parametrize("method", ["exact", "snapshots", "randomized"])
def test_float32_input_stays_float32(method: str) -> None:
    rng = np.random.default_rng(2)
    x, _ = low_rank(rng, 50, 300, SV, 1e-3, dtype=np.float32)
    pod = pod_basis(x, 4, method=method, rng=np.random.default_rng(0))
    ref = pod_basis(x.astype(np.float64), 4, method="exact")
    assert pod.modes.dtype == np.float32
    assert pod.mean.dtype == np.float64
    assert pod.singular_values.dtype == np.float64
    assert x.dtype == np.float32  # input untouched
    np.testing.assert_allclose(pod.modes.T @ pod.modes, np.eye(4), atol=1e-5)
    assert max_angle(pod.modes, ref.modes) < 1e-4  # float32 rounding only
    np.testing.assert_allclose(pod.singular_values, ref.singular_values, rtol=1e-4)


def test_randomized_is_reproducible_from_the_generator() -> None:
    rng = np.random.default_rng(3)
    x, _ = low_rank(rng, 30, 200, SV, 1e-1)
    a = pod_basis(x, 3, method="randomized", rng=np.random.default_rng(5), power_iters=0, oversample=2)
    b = pod_basis(x, 3, method="randomized", rng=np.random.default_rng(5), power_iters=0, oversample=2)
    c = pod_basis(x, 3, method="randomized", rng=np.random.default_rng(6), power_iters=0, oversample=2)
    np.testing.assert_array_equal(a.modes, b.modes)
    assert not np.array_equal(a.modes, c.modes)


def test_chunk_size_does_not_change_the_result() -> None:
    rng = np.random.default_rng(4)
    x, _ = low_rank(rng, 30, 500, SV, 1e-2)
    big = pod_basis(x, 4, method="snapshots")
    tiny = pod_basis(x, 4, method="snapshots", chunk_elements=7)  # 1 column per block
    cov_big = pod_basis(x.T.copy(), 4, method="snapshots")
    cov_tiny = pod_basis(x.T.copy(), 4, method="snapshots", chunk_elements=777)  # 1 row per block
    np.testing.assert_allclose(tiny.modes, big.modes, atol=1e-10)
    np.testing.assert_allclose(tiny.singular_values, big.singular_values, rtol=1e-12)
    np.testing.assert_allclose(cov_tiny.modes, cov_big.modes, atol=1e-10)
    rnd_big = pod_basis(x, 4, method="randomized", rng=np.random.default_rng(1))
    rnd_tiny = pod_basis(x, 4, method="randomized", rng=np.random.default_rng(1), chunk_elements=300)
    np.testing.assert_allclose(rnd_tiny.modes, rnd_big.modes, atol=1e-10)


def test_auto_picks_exact_when_small() -> None:
    x, _ = low_rank(np.random.default_rng(5), 20, 50, SV, 1e-3)
    assert pod_basis(x, 2).method == "exact"


# --------------------------------------------------------------------------------------------------
# Projection error
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["exact", "snapshots"])
def test_projection_error_direct_equals_singular_values(method: str) -> None:
    rng = np.random.default_rng(6)
    x, _ = low_rank(rng, 40, 120, SV, 1e-2)
    pod = pod_basis(x, 8, method=method)
    ns = [0, 1, 3, 8, 5]
    direct = projection_error(x, pod, ns, chunk_elements=500)  # several row blocks
    from_sv = projection_error_from_singular_values(pod, ns)
    np.testing.assert_allclose(direct, from_sv, rtol=1e-8, atol=1e-12)
    assert direct[0] == pytest.approx(1.0)
    assert np.all(np.diff(direct[:4]) < 0)  # order kept, error decreasing in n
    # the definition, written out for one n
    u = pod.modes[:, :3]
    xc = x - pod.mean
    expected = np.linalg.norm(xc - xc @ u @ u.T) / np.linalg.norm(xc)
    assert direct[2] == pytest.approx(expected, rel=1e-10)


def test_projection_error_from_singular_values_needs_all_of_them() -> None:
    x, _ = low_rank(np.random.default_rng(7), 20, 60, SV, 1e-3)
    pod = pod_basis(x, 3, method="randomized", rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="leading singular values"):
        projection_error_from_singular_values(pod, [1])
    with pytest.raises(ValueError, match=r"outside \[0, pod.n_modes = 3\]"):
        projection_error(x, pod, [4])
    with pytest.raises(ValueError, match="expected N = 60"):
        projection_error(x[:, :10], pod, [1])


def test_projection_error_of_data_in_the_span_is_zero() -> None:
    rng = np.random.default_rng(8)
    x, _ = low_rank(rng, 30, 80, SV[:3], 0.0)
    pod = pod_basis(x, 3)
    assert projection_error(x, pod, 3)[0] < 1e-12
    const = np.ones((5, 80))
    pod0 = pod_basis(const, 1)
    np.testing.assert_array_equal(projection_error(const, pod0, [0, 1]), [0.0, 0.0])
    assert pod0.energy == 1.0


# --------------------------------------------------------------------------------------------------
# Big memory-mapped float32 input
# --------------------------------------------------------------------------------------------------


def test_memmap_float32_is_processed_in_chunks(tmp_path: Path) -> None:
    m, n, r = 2000, 20000, 5
    rng = np.random.default_rng(9)
    basis, _ = np.linalg.qr(rng.standard_normal((n, r)))
    coeffs = rng.standard_normal((m, r)) * np.array([40.0, 20.0, 10.0, 5.0, 2.5])
    offset = 1.0 - np.cos(np.linspace(0.0, 2.0, n))
    path = tmp_path / "cp.npy"
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(m, n))
    for start in range(0, m, 250):
        stop = start + 250
        block = offset + coeffs[start:stop] @ basis.T + 1e-4 * rng.standard_normal((stop - start, n))
        out[start:stop] = block
    out.flush()
    del out
    cp = np.load(path, mmap_mode="r")
    float64_copy = m * n * 8

    tracemalloc.start()
    try:
        pod = pod_basis(cp, r)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()

    assert isinstance(cp, np.memmap)
    assert pod.method == "snapshots"  # M·N = 4·10⁷ > the exact-SVD limit
    assert pod.modes.dtype == np.float32
    # Peak traced allocation: the 2000² float64 Gram (32 MB) and its eigenvectors (32 MB) plus one
    # 16 MB block — measured 65 MB, 20 % of the 320 MB float64 copy (LAPACK/BLAS work buffers are not
    # traced by tracemalloc). A float64 copy of the matrix would fail this.
    assert peak < float64_copy / 4, f"peak {peak / 1e6:.0f} MB vs float64 copy {float64_copy / 1e6:.0f} MB"
    assert max_angle(pod.modes, basis) < 1e-3
    np.testing.assert_allclose(pod.modes.T @ pod.modes, np.eye(r), atol=1e-5)
    np.testing.assert_allclose(pod.mean, offset + coeffs.mean(axis=0) @ basis.T, atol=1e-4)


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------


def test_bad_arguments_raise_value_error() -> None:
    x = np.random.default_rng(10).standard_normal((6, 9))
    with pytest.raises(ValueError, match=r"n_modes must be an integer in \[1, min\(M, N\) = 6\]"):
        pod_basis(x, 7)
    with pytest.raises(ValueError, match="n_modes"):
        pod_basis(x, 0)
    with pytest.raises(ValueError, match="expected a 2-D"):
        pod_basis(x[0], 1)
    with pytest.raises(ValueError, match="method must be one of"):
        pod_basis(x, 2, method="svd")
    with pytest.raises(ValueError, match="needs an explicit rng"):
        pod_basis(x, 2, method="randomized")
    with pytest.raises(ValueError, match="chunk_elements"):
        pod_basis(x, 2, chunk_elements=0)
    bad = x.copy()
    bad[2, 3] = np.nan
    for method in ("exact", "snapshots"):
        with pytest.raises(ValueError, match="NaN or Inf"):
            pod_basis(bad, 2, method=method)
    with pytest.raises(ValueError, match="NaN or Inf"):
        pod_basis(bad, 2, method="randomized", rng=np.random.default_rng(0))


def test_result_properties() -> None:
    x, _ = low_rank(np.random.default_rng(11), 12, 30, SV, 1e-3)
    pod = pod_basis(x, 2)
    assert isinstance(pod, PODResult)
    assert (pod.n_modes, pod.n_points) == (2, 30)
    assert 0.0 < pod.energy < 1.0
