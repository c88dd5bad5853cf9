"""Proper orthogonal decomposition (POD) of a snapshot matrix, sized for memory-mapped float32 data.

Convention (see :mod:`vdm_aero._typing`): snapshots are the rows of an (M, N) matrix ``X`` (M snapshots,
N surface points). POD works on the mean-centred matrix ``X_c = X − 1 μᵀ`` with ``μ`` the mean snapshot
(mean over the rows). Its thin SVD is ``X_c = V Σ Uᵀ``; the POD modes are the columns of ``U`` (N, n_b)
and a snapshot is approximated by ``μ + U Uᵀ (x − μ)``.

Three algorithms (``method=``) give the same modes up to sign and rounding:

``"exact"``
    LAPACK SVD (``numpy.linalg.svd``, gesdd) of the whole centred matrix. Makes one copy of ``X`` in the
    working dtype; use it for small problems only. Gives every singular value.
``"snapshots"``
    The blockwise Gram ("method of snapshots", Sirovich 1987) on the *smaller* side, exact up to the
    rounding of the working dtype:

    * M ≤ N: ``G = X_c X_cᵀ`` (M×M, float64 accumulator) summed over column blocks of ``X`` (each
      block holds every snapshot, so its column means are exact and are computed in the same pass);
      ``G = V Λ Vᵀ``; then a second pass forms ``Y = X_cᵀ V_n`` (N×n_b) block by block and the modes
      are the left singular vectors of ``Y`` (a Rayleigh–Ritz step, which makes them orthonormal to
      working precision and gives the leading singular values without squaring them).
    * M > N: the spatial covariance ``C = X_cᵀ X_c`` (N×N) summed over row blocks after a mean pass,
      and its leading eigenvectors.

    Memory O(min(M, N)² + N·n_b) plus one block; never a float64 copy of ``X``. Gives every singular
    value as ``sqrt(max(λ, 0))`` (the small ones only to absolute accuracy ≈ eps·σ₁).
``"randomized"``
    Randomized SVD (Halko, Martinsson & Tropp 2011, Alg. 4.4 + 5.1) with ``n_b + oversample`` Gaussian
    test vectors drawn from an explicit :class:`numpy.random.Generator`, ``power_iters`` orthonormalised
    power iterations, every product computed over column blocks. 2 + 2·power_iters passes over ``X``
    plus a mean pass. Gives only the leading singular values.

``"auto"`` picks ``"exact"`` when ``M·N ≤`` :data:`EXACT_MAX_ELEMENTS` (2·10⁶; above it the
Gram route is ≈3× faster for the same leading modes), else ``"snapshots"`` when
``min(M, N) ≤`` :data:`GRAM_MAX_SIZE`, else ``"randomized"`` (which then needs ``rng``).

Dtypes: float32 (and float16) input is processed in float32 — blocks, products and modes stay float32,
only the Gram/covariance accumulator, the mean, the singular values and the energies are float64.
Every other input is processed in float64. Modes have a deterministic sign: the entry of largest
magnitude of each mode is positive.

The module needs numpy only (no scipy), so it runs on the companion computer.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vdm_aero._typing import F64Array, FloatArray, IntArray

__all__ = [
    "EXACT_MAX_ELEMENTS",
    "GRAM_MAX_SIZE",
    "POD_CHUNK_ELEMENTS",
    "PODResult",
    "pod_basis",
    "projection_error",
    "projection_error_from_singular_values",
]

EXACT_MAX_ELEMENTS: Final = 2_000_000
"""``method="auto"`` uses the exact SVD up to this many elements ``M·N``."""

GRAM_MAX_SIZE: Final = 16_384
"""``method="auto"`` uses the Gram route while ``min(M, N)`` is at most this (Gram ≤ 2 GiB float64)."""

POD_CHUNK_ELEMENTS: Final = 1 << 22
"""Default elements of ``X`` per block (4 Mi elements: 16 MiB in float32)."""

_METHODS: Final = ("auto", "exact", "snapshots", "randomized")


@dataclass(frozen=True, eq=False)
class PODResult:
    """A POD basis of mean-centred snapshots.

    Attributes:
        mean: (N,) float64 mean snapshot ``μ``.
        modes: (N, n_modes) orthonormal POD modes, float32 for float32 input else float64.
        singular_values: (n_modes,) float64 leading singular values of ``X_c``, descending.
        all_singular_values: every singular value (``min(M, N)`` of them, descending, float64) for the
            ``"exact"`` and ``"snapshots"`` methods, ``None`` for ``"randomized"``.
        total_energy: ``‖X_c‖_F²`` (float64, computed from the data).
        method: the algorithm actually used (``"exact"``, ``"snapshots"`` or ``"randomized"``).
    """

    mean: F64Array
    modes: FloatArray
    singular_values: F64Array
    all_singular_values: F64Array | None
    total_energy: float
    method: str

    @property
    def n_modes(self) -> int:
        """n_b, the number of modes kept."""
        return int(self.modes.shape[1])

    @property
    def n_points(self) -> int:
        """N, the length of a snapshot."""
        return int(self.modes.shape[0])

    @property
    def energy(self) -> float:
        """Fraction of ``‖X_c‖_F²`` captured by the modes, ``Σ_{i≤n_b} σ_i² / ‖X_c‖_F²`` (1 if X_c = 0)."""
        if self.total_energy <= 0.0:
            return 1.0
        return float(min(1.0, np.sum(self.singular_values**2) / self.total_energy))


# --------------------------------------------------------------------------------------------------
# POD
# --------------------------------------------------------------------------------------------------


def pod_basis(
    snapshots: ArrayLike,
    n_modes: int,
    *,
    method: str = "auto",
    rng: np.random.Generator | None = None,
    oversample: int = 10,
    power_iters: int = 2,
    chunk_elements: int | None = None,
) -> PODResult:
    """Return the leading ``n_modes`` POD modes of the mean-centred (M, N) ``snapshots``.

    Args:
        snapshots: (M, N) snapshot matrix (rows = snapshots), e.g. a read-only float32 ``np.memmap``;
            it is read block by block and never modified.
        n_modes: n_b, 1 ≤ n_b ≤ min(M, N).
        method: ``"auto"``, ``"exact"``, ``"snapshots"`` or ``"randomized"`` (see the module docstring).
        rng: the Generator of the randomized method (required by it, unused otherwise).
        oversample: extra random test vectors of the randomized method (≥ 0).
        power_iters: power iterations of the randomized method (≥ 0).
        chunk_elements: elements of ``snapshots`` per block (default :data:`POD_CHUNK_ELEMENTS`); a
            block is ``max(1, chunk_elements // M)`` columns (or ``// N`` rows on the row-block paths).

    Returns:
        The :class:`PODResult`.

    Raises:
        ValueError: on a non-2-D or empty input, non-finite values, a bad ``n_modes``/``method``/
            ``oversample``/``power_iters``/``chunk_elements``, or a randomized run without ``rng``.
    """
    x = _as_2d(snapshots)
    m, n = x.shape
    k = _check_n_modes(n_modes, m, n)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, _METHODS))}, got {method!r}")
    if not (_is_int(oversample) and oversample >= 0):
        raise ValueError(f"oversample must be an integer ≥ 0, got {oversample!r}")
    if not (_is_int(power_iters) and power_iters >= 0):
        raise ValueError(f"power_iters must be an integer ≥ 0, got {power_iters!r}")
    chunk = _check_chunk(chunk_elements)
    work = _work_dtype(x.dtype)
    if method == "auto":
        if m * n <= EXACT_MAX_ELEMENTS:
            method = "exact"
        elif min(m, n) <= GRAM_MAX_SIZE:
            method = "snapshots"
        else:
            method = "randomized"
    if method == "exact":
        return _pod_exact(x, k, work)
    if method == "snapshots":
        if m <= n:
            return _pod_snapshots(x, k, work, chunk)
        return _pod_covariance(x, k, work, chunk)
    if rng is None:
        raise ValueError(f"method 'randomized' (M = {m}, N = {n}) needs an explicit rng=np.random.default_rng(seed)")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return _pod_randomized(x, k, work, chunk, rng, oversample, power_iters)


def _pod_exact(x: NDArray[Any], k: int, work: np.dtype[Any]) -> PODResult:
    mean = np.asarray(np.mean(x, axis=0, dtype=np.float64), dtype=np.float64)
    xc = np.asarray(x, dtype=work) - mean.astype(work)  # always a new array: x is never modified
    _check_finite(xc, "snapshots")
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    del xc
    all_sv = np.asarray(s, dtype=np.float64)
    modes = _fix_signs(np.ascontiguousarray(vt[:k].T))
    return PODResult(
        mean=mean,
        modes=modes,
        singular_values=all_sv[:k].copy(),
        all_singular_values=all_sv,
        total_energy=float(np.sum(all_sv**2)),
        method="exact",
    )


def _pod_snapshots(x: NDArray[Any], k: int, work: np.dtype[Any], chunk: int) -> PODResult:
    """Method of snapshots (M ≤ N): M×M Gram over column blocks, eigh, Rayleigh–Ritz pass."""
    m, n = x.shape
    mean = np.empty(n, dtype=np.float64)
    gram = np.zeros((m, m), dtype=np.float64)
    for cols in _col_blocks(m, n, chunk):
        block = np.asarray(x[:, cols], dtype=work)  # a view when the dtype already matches
        _check_finite(block, "snapshots")
        mu = np.mean(block, axis=0, dtype=np.float64)
        mean[cols] = mu
        centred = block - mu.astype(work)
        del block
        gram += centred @ centred.T  # numpy calls BLAS syrk for A·Aᵀ
        del centred
    lam, vecs = np.linalg.eigh(gram)
    total = float(np.trace(gram))
    del gram
    lam = lam[::-1]
    all_sv = np.sqrt(np.clip(lam, 0.0, None))
    v_k = np.ascontiguousarray(vecs[:, ::-1][:, :k], dtype=work)
    del vecs
    mean_w = mean.astype(work)
    y = np.empty((n, k), dtype=work)
    for cols in _col_blocks(m, n, chunk):
        centred = np.asarray(x[:, cols], dtype=work) - mean_w[cols]
        y[cols] = centred.T @ v_k
        del centred
    # Rayleigh–Ritz: Y = X_cᵀ V_k = U_k Σ_k when V_k is exact; its SVD makes the modes orthonormal.
    q, s, _ = np.linalg.svd(y, full_matrices=False)
    del y
    return PODResult(
        mean=mean,
        modes=_fix_signs(np.ascontiguousarray(q, dtype=work)),
        singular_values=np.asarray(s, dtype=np.float64),
        all_singular_values=all_sv,
        total_energy=total,
        method="snapshots",
    )


def _pod_covariance(x: NDArray[Any], k: int, work: np.dtype[Any], chunk: int) -> PODResult:
    """The Gram route when M > N: N×N spatial covariance over row blocks."""
    m, n = x.shape
    mean = _column_mean(x, work, chunk)
    mean_w = mean.astype(work)
    cov = np.zeros((n, n), dtype=np.float64)
    for rows in _row_blocks(m, n, chunk):
        centred = np.asarray(x[rows], dtype=work) - mean_w
        cov += centred.T @ centred
        del centred
    lam, vecs = np.linalg.eigh(cov)
    total = float(np.trace(cov))
    del cov
    lam = lam[::-1]
    all_sv = np.sqrt(np.clip(lam, 0.0, None))
    modes = np.ascontiguousarray(vecs[:, ::-1][:, :k], dtype=work)
    return PODResult(
        mean=mean,
        modes=_fix_signs(modes),
        singular_values=all_sv[:k].copy(),
        all_singular_values=all_sv,
        total_energy=total,
        method="snapshots",
    )


def _pod_randomized(
    x: NDArray[Any],
    k: int,
    work: np.dtype[Any],
    chunk: int,
    rng: np.random.Generator,
    oversample: int,
    power_iters: int,
) -> PODResult:
    """Halko et al. randomized SVD of X_c with a range finder on the snapshot side (M × l)."""
    m, n = x.shape
    ell = min(k + oversample, m, n)
    mean = _column_mean(x, work, chunk)
    mean_w = mean.astype(work)
    omega = rng.standard_normal((n, ell), dtype=np.float64).astype(work)  # same draws for any dtype

    def times(mat: NDArray[Any], norm: bool = False) -> tuple[F64Array, float]:
        """Return ``(X_c @ mat, ‖X_c‖_F² if norm else 0)`` for an (N, l) ``mat``, over column blocks."""
        acc = np.zeros((m, mat.shape[1]), dtype=np.float64)
        sq = 0.0
        for cols in _col_blocks(m, n, chunk):
            centred = np.asarray(x[:, cols], dtype=work) - mean_w[cols]
            acc += centred @ mat[cols]
            if norm:
                sq += float(np.sum(np.square(centred), dtype=np.float64))
            del centred
        return acc, sq

    def t_times(mat: NDArray[Any]) -> NDArray[Any]:
        """Return ``X_cᵀ @ mat`` (N, l) for an (M, l) ``mat``, over column blocks."""
        out = np.empty((n, mat.shape[1]), dtype=work)
        mat_w = np.asarray(mat, dtype=work)
        for cols in _col_blocks(m, n, chunk):
            centred = np.asarray(x[:, cols], dtype=work) - mean_w[cols]
            out[cols] = centred.T @ mat_w
            del centred
        return out

    y, total = times(omega, norm=True)
    del omega
    q, _ = np.linalg.qr(y)
    for _ in range(power_iters):
        z, _ = np.linalg.qr(t_times(q))
        y, _ = times(z)
        del z
        q, _ = np.linalg.qr(y)
    b = t_times(q).T  # (l, N) = Qᵀ X_c, in the working dtype
    _, s, vt = np.linalg.svd(b, full_matrices=False)
    del b
    modes = np.ascontiguousarray(vt[:k].T, dtype=work)
    return PODResult(
        mean=mean,
        modes=_fix_signs(modes),
        singular_values=np.asarray(s[:k], dtype=np.float64),
        all_singular_values=None,
        total_energy=total,
        method="randomized",
    )


# --------------------------------------------------------------------------------------------------
# Projection error
# --------------------------------------------------------------------------------------------------


def projection_error(
    snapshots: ArrayLike,
    pod: PODResult,
    n_modes_list: int | Sequence[int] | IntArray,
    *,
    chunk_elements: int | None = None,
) -> F64Array:
    """Relative projection error ``ε_proj(n) = ‖X_c − U_n U_nᵀ X_c‖_F / ‖X_c‖_F`` computed directly.

    ``X_c`` is ``snapshots`` centred with ``pod.mean`` (so held-out snapshots may be passed too) and
    ``U_n`` the first ``n`` modes. Computed over row blocks in float64 (one block at a time), the
    residual itself is formed (no ``‖X‖² − ‖UᵀX‖²`` cancellation).

    Args:
        snapshots: (M, N) snapshot matrix.
        pod: a basis with N points.
        n_modes_list: ``n`` or a sequence of them, each 0 ≤ n ≤ ``pod.n_modes``.
        chunk_elements: elements per block (default :data:`POD_CHUNK_ELEMENTS`).

    Returns:
        (len(n_modes_list),) float64 errors in the given order (a scalar ``n`` gives shape (1,));
        all zeros when ``X_c = 0``.
    """
    x = _as_2d(snapshots)
    m, n_pts = x.shape
    if n_pts != pod.n_points:
        raise ValueError(f"snapshots: shape {x.shape}, expected N = {pod.n_points} columns to match the POD")
    ns = _n_list(n_modes_list, pod.n_modes, "pod.n_modes")
    chunk = _check_chunk(chunk_elements)
    steps = np.unique(ns)
    n_max = int(steps[-1])
    u = np.asarray(pod.modes[:, :n_max], dtype=np.float64)
    err2 = np.zeros(steps.size, dtype=np.float64)
    total = 0.0
    for rows in _row_blocks(m, n_pts, chunk):
        resid = np.array(x[rows], dtype=np.float64)  # a copy: subtracted in place below
        resid -= pod.mean
        total += float(np.sum(resid**2))
        coeff = resid @ u
        prev = 0
        for j, step in enumerate(steps):
            s = int(step)
            if s > prev:
                resid -= coeff[:, prev:s] @ u[:, prev:s].T
                prev = s
            err2[j] += float(np.sum(resid**2))
        del resid
    if total <= 0.0:
        return np.zeros(ns.size, dtype=np.float64)
    by_step = np.sqrt(err2 / total)
    return np.asarray(by_step[np.searchsorted(steps, ns)], dtype=np.float64)


def projection_error_from_singular_values(pod: PODResult, n_modes_list: int | Sequence[int] | IntArray) -> F64Array:
    """``ε_proj(n) = sqrt(Σ_{i>n} σ_i² / Σ_i σ_i²)`` from ``pod.all_singular_values``.

    Equals :func:`projection_error` on the snapshots the POD was computed from (to rounding); each
    ``n`` may go up to ``len(pod.all_singular_values)``.

    Raises:
        ValueError: if the POD does not hold every singular value (randomized method) or on a bad ``n``.
    """
    if pod.all_singular_values is None:
        raise ValueError(
            f"the {pod.method!r} POD keeps only the leading singular values; "
            "use projection_error(snapshots, pod, ...) or method 'exact'/'snapshots'"
        )
    sv2 = np.asarray(pod.all_singular_values, dtype=np.float64) ** 2
    ns = _n_list(n_modes_list, sv2.size, "the number of singular values")
    tails = np.concatenate([np.cumsum(sv2[::-1])[::-1], [0.0]])  # tails[i] = Σ_{j ≥ i} σ_j²
    if tails[0] <= 0.0:
        return np.zeros(ns.size, dtype=np.float64)
    return np.asarray(np.sqrt(tails[ns] / tails[0]), dtype=np.float64)


# --------------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------------


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _as_2d(snapshots: ArrayLike) -> NDArray[Any]:
    x = snapshots if isinstance(snapshots, np.ndarray) else np.asarray(snapshots)
    if x.ndim != 2:
        raise ValueError(f"snapshots: shape {x.shape}, expected a 2-D (M, N) matrix")
    if x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(f"snapshots: shape {x.shape}, expected at least one snapshot and one point")
    if x.dtype.kind not in "fiu":
        raise ValueError(f"snapshots: dtype {x.dtype}, expected a real numeric dtype")
    return x


def _check_n_modes(n_modes: object, m: int, n: int) -> int:
    limit = min(m, n)
    if not (_is_int(n_modes) and 1 <= int(n_modes) <= limit):  # type: ignore[call-overload]
        raise ValueError(f"n_modes must be an integer in [1, min(M, N) = {limit}] (M = {m}, N = {n}), got {n_modes!r}")
    return int(n_modes)  # type: ignore[call-overload]


def _check_chunk(chunk_elements: int | None) -> int:
    if chunk_elements is None:
        return POD_CHUNK_ELEMENTS
    if not (_is_int(chunk_elements) and chunk_elements >= 1):
        raise ValueError(f"chunk_elements must be an integer ≥ 1, got {chunk_elements!r}")
    return int(chunk_elements)


def _n_list(values: int | Sequence[int] | IntArray, limit: int, what: str) -> IntArray:
    arr = np.atleast_1d(np.asarray(values))
    if arr.ndim != 1 or arr.size == 0 or arr.dtype.kind not in "iu":
        raise ValueError(f"n_modes_list must be an integer or a non-empty 1-D list of integers, got {values!r}")
    ns = arr.astype(np.int64)
    bad = (ns < 0) | (ns > limit)
    if bad.any():
        raise ValueError(f"n_modes_list: {int(ns[bad][0])} is outside [0, {what} = {limit}]")
    return ns


def _work_dtype(dtype: np.dtype[Any]) -> np.dtype[Any]:
    if dtype in (np.dtype(np.float32), np.dtype(np.float16)):
        return np.dtype(np.float32)
    return np.dtype(np.float64)


def _check_finite(block: NDArray[Any], what: str) -> None:
    if not np.isfinite(block).all():
        raise ValueError(f"{what}: contains NaN or Inf values")


def _col_blocks(m: int, n: int, chunk: int) -> Iterator[slice]:
    step = max(1, chunk // max(m, 1))
    for start in range(0, n, step):
        yield slice(start, min(start + step, n))


def _row_blocks(m: int, n: int, chunk: int) -> Iterator[slice]:
    step = max(1, chunk // max(n, 1))
    for start in range(0, m, step):
        yield slice(start, min(start + step, m))


def _column_mean(x: NDArray[Any], work: np.dtype[Any], chunk: int) -> F64Array:
    """Mean over the rows in float64, one row block at a time; rejects NaN/Inf."""
    m, n = x.shape
    acc = np.zeros(n, dtype=np.float64)
    for rows in _row_blocks(m, n, chunk):
        block = np.asarray(x[rows], dtype=work)
        _check_finite(block, "snapshots")
        acc += np.sum(block, axis=0, dtype=np.float64)
    return acc / m


def _fix_signs(modes: NDArray[Any]) -> NDArray[Any]:
    """Flip each mode (in place) so that its entry of largest magnitude is positive."""
    if modes.shape[0] == 0:
        return modes
    idx = np.argmax(np.abs(modes), axis=0)
    signs = np.sign(modes[idx, np.arange(modes.shape[1])])
    signs[signs == 0] = 1
    modes *= signs.astype(modes.dtype)
    return modes
