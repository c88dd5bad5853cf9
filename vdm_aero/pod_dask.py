"""The POD of :mod:`vdm_aero.pod` on ``dask.array``, for snapshot sets beyond one machine (extra ``dask``).

Importing this module needs ``dask[array]`` (install the ``dask`` extra); ``distributed`` is needed
only to run on a cluster (``Client(address)``); without a client dask's local threaded scheduler is used.
Nothing else in :mod:`vdm_aero` imports this module.

Same convention as :mod:`vdm_aero.pod`: the snapshots are the rows of an (M, N) array ``X``, the POD
modes are the right singular vectors of the mean-centred ``X_c = X − 1μᵀ``, i.e. the *left* singular
vectors of ``X_cᵀ`` (N × M). With M ≪ N, ``X_cᵀ`` is tall and skinny, which is what dask's
communication-avoiding TSQR (Benson, Gleich & Demmel 2013) is made for.

``method="tsqr"``
    Tall-skinny QR of ``X_cᵀ`` chunked along the points only (each chunk holds every snapshot of a
    range of points): one R-only QR per chunk, a tree of QRs of stacked M×M ``R`` factors, then the
    SVD of the final R (every singular value, the right singular vectors V) and a Rayleigh–Ritz pass
    ``Y = X_cᵀ V_k`` whose SVD gives the modes, as in :mod:`vdm_aero.pod`'s method of snapshots. The
    same maths as ``dask.array.linalg.svd`` on the tall-skinny ``X_cᵀ`` but without forming its N×M
    Q factor (as big as the data). Two passes over the data after the mean pass; exact up to rounding.
    Needs M×M blocks in a worker's memory (M ≲ 2·10⁴) and chunks of at least M points for efficiency.
    (With M > N the roles swap: TSQR of ``X_c`` chunked along the snapshots, modes = V.)
``method="compressed"``
    ``dask.array.linalg.svd_compressed`` (Halko, Martinsson & Tropp 2011) with ``n_modes +
    oversample`` test vectors, ``power_iters`` QR-orthonormalised power iterations and a seed drawn from
    the caller's :class:`numpy.random.Generator`. Works on arrays chunked along both axes (very large
    M too); gives only the leading singular values.

Both first compute the mean (float64, one pass) and then centre lazily per chunk. The result is a
:class:`vdm_aero.pod.PODResult` with the same fields, dtypes (float32 modes for float32/float16 input)
and sign convention (each mode's entry of largest magnitude is positive) as :func:`vdm_aero.pod.pod_basis`.
The mean (N,) and the modes (N, n_modes) are gathered on the client, so they must fit in its memory.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

try:
    import dask.array as da  # type: ignore[import-not-found, unused-ignore]  # the optional 'dask' extra
    from dask.base import tokenize  # type: ignore[import-not-found, unused-ignore]
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "vdm_aero.pod_dask needs the optional 'dask' extra: pip install 'vdm-aero[dask]' (dask[array], distributed)"
    ) from exc

from vdm_aero.pod import PODResult

__all__ = ["DASK_METHODS", "DEFAULT_CHUNK_BYTES", "NpyColumns", "open_dataset_dask", "pod_basis_dask"]

DASK_METHODS: Final = ("tsqr", "compressed")

DEFAULT_CHUNK_BYTES: Final = 128 << 20
"""Target bytes per chunk of :func:`open_dataset_dask` (dask's usual 100–200 MB sweet spot)."""


def pod_basis_dask(
    x: Any,
    n_modes: int,
    *,
    method: str = "tsqr",
    rng: np.random.Generator | None = None,
    oversample: int = 10,
    power_iters: int = 2,
    chunk_points: int | None = None,
) -> PODResult:
    """Leading ``n_modes`` POD modes of the (M, N) dask array ``x`` (rows = snapshots).

    Computed on the current dask scheduler (a ``distributed.Client`` if one is active).

    Args:
        x: (M, N) ``dask.array.Array`` (e.g. from :func:`open_dataset_dask`); any chunking (``"tsqr"``
            rechunks to whole snapshots × ``chunk_points`` points).
        n_modes: n_b, 1 ≤ n_b ≤ min(M, N).
        method: ``"tsqr"`` or ``"compressed"`` (module docstring).
        rng: Generator the ``"compressed"`` method's seed is drawn from (required by it).
        oversample: extra test vectors of ``"compressed"`` (≥ 0).
        power_iters: power iterations of ``"compressed"`` (≥ 0).
        chunk_points: points per chunk for ``"tsqr"`` (default: keep ``x``'s column chunks).

    Returns:
        The :class:`~vdm_aero.pod.PODResult` (``method`` = ``"dask-tsqr"`` or ``"dask-compressed"``).

    Raises:
        ValueError: on a non-dask or non-2-D input, a non-real dtype, a bad ``n_modes``/``method``/
            ``oversample``/``power_iters``/``chunk_points``, non-finite data, or ``"compressed"``
            without ``rng``.
    """
    if not isinstance(x, da.Array):
        raise ValueError(f"x must be a dask.array.Array, got {type(x).__name__} (use vdm_aero.pod.pod_basis)")
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(f"x: shape {x.shape}, expected a 2-D (M, N) snapshot array with M, N ≥ 1")
    if x.dtype.kind not in "fiu":
        raise ValueError(f"x: dtype {x.dtype}, expected a real numeric dtype")
    m, n = (int(v) for v in x.shape)
    if not (_is_int(n_modes) and 1 <= n_modes <= min(m, n)):
        raise ValueError(f"n_modes must be an integer in [1, min(M, N) = {min(m, n)}], got {n_modes!r}")
    k = int(n_modes)
    if method not in DASK_METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, DASK_METHODS))}, got {method!r}")
    if not (_is_int(oversample) and oversample >= 0):
        raise ValueError(f"oversample must be an integer ≥ 0, got {oversample!r}")
    if not (_is_int(power_iters) and power_iters >= 0):
        raise ValueError(f"power_iters must be an integer ≥ 0, got {power_iters!r}")
    if chunk_points is not None and not (_is_int(chunk_points) and chunk_points >= 1):
        raise ValueError(f"chunk_points must be an integer ≥ 1, got {chunk_points!r}")
    if method == "compressed":
        if rng is None:
            raise ValueError("method 'compressed' needs an explicit rng=np.random.default_rng(seed)")
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")

    work = np.dtype(np.float32) if x.dtype in (np.dtype(np.float32), np.dtype(np.float16)) else np.dtype(np.float64)
    xw = x.astype(work)  # a no-op for float32/float64 input
    # pass 1: the mean, on its own, so no chunk is held in memory waiting for the later passes
    mean = np.asarray(da.mean(xw, axis=0, dtype=np.float64).compute(), dtype=np.float64)
    if not np.isfinite(mean).all():  # a NaN/Inf anywhere in a column makes its float64 mean non-finite
        raise ValueError("x: contains NaN or Inf values (or values whose float64 sum overflows)")
    mean_d = da.from_array(mean.astype(work), chunks=(xw.chunks[1],))
    xc = xw - mean_d[None, :]  # X_c, centred lazily chunk by chunk; never stored

    if method == "tsqr":
        modes, leading, all_sv = _tsqr_pod(xc, k, work, chunk_points)
        total = float(np.sum(all_sv**2))  # ‖X_c‖_F² = Σ σ_i² over all min(M, N) of them
        all_out: NDArray[np.float64] | None = all_sv
    else:
        assert rng is not None
        seed = int(rng.integers(0, 2**32 - 1))
        xc_t = xc.T  # (N, M): tall and skinny when M ≪ N; any chunking works here
        # compute=True: each pass is computed (and the data re-read) on its own, so a cluster never
        # has to hold the whole snapshot matrix between passes
        u, s, _ = da.linalg.svd_compressed(
            xc_t, k, iterator="QR", n_power_iter=power_iters, n_oversamples=oversample, seed=seed, compute=True
        )
        u_np, s_np = da.compute(u, s)
        total = float(da.sum(da.square(xc.astype(np.float64))).compute())  # one more pass, exact
        modes = np.asarray(u_np)
        leading = np.asarray(s_np, dtype=np.float64)
        all_out = None
    return PODResult(
        mean=mean,
        modes=_fix_signs(np.ascontiguousarray(modes, dtype=work)),
        singular_values=leading,
        all_singular_values=all_out,
        total_energy=total,
        method=f"dask-{method}",
    )


def _tsqr_pod(
    xc: Any, k: int, work: np.dtype[Any], chunk_points: int | None
) -> tuple[NDArray[Any], NDArray[np.float64], NDArray[np.float64]]:
    """TSQR route: ``(modes (N, k), leading σ (k,), all σ)`` of the lazily centred (M, N) ``xc``.

    Only the R factor of the TSQR is computed (:func:`_tsqr_r`); the N×M Q factor, as big as the data,
    is never formed. R's small SVD gives every singular value and the right singular vectors; the
    modes then follow as in :mod:`vdm_aero.pod`'s method of snapshots.
    """
    m, n = xc.shape
    if m <= n:
        # X_cᵀ = Q R, R = U_r Σ V_rᵀ  ⇒  X_c = V_r Σ (Q U_r)ᵀ: the modes are Q U_r = X_cᵀ V_r Σ⁻¹
        tall = xc.T.rechunk({0: chunk_points if chunk_points is not None else xc.chunks[1], 1: -1})
        _, sv, vt = np.linalg.svd(_tsqr_r(tall, work))
        v_k = np.ascontiguousarray(vt[:k].T, dtype=work)
        # Rayleigh–Ritz pass: Y = X_cᵀ V_k = U_k Σ_k; its SVD makes the modes orthonormal to working
        # precision and gives the leading σ without squaring them (as vdm_aero.pod does)
        y = np.asarray((tall @ da.from_array(v_k, chunks=v_k.shape)).compute())
        q, s, _ = np.linalg.svd(y, full_matrices=False)
        return q, np.asarray(s, dtype=np.float64), np.asarray(sv, dtype=np.float64)
    # M > N: X_c itself is tall (chunked along the snapshots); X_c = Q R, R = U_r Σ V_rᵀ ⇒ modes = V_r
    _, sv, vt = np.linalg.svd(_tsqr_r(xc.rechunk({1: -1}), work))
    all_sv = np.asarray(sv, dtype=np.float64)
    return np.ascontiguousarray(vt[:k].T), all_sv[:k].copy(), all_sv


TSQR_GROUP: Final = 8
"""R factors stacked per node of the TSQR reduction tree (each node factors a (8·M) × M stack)."""


def _qr_r(block: NDArray[Any]) -> NDArray[Any]:
    """R factor of one block, ``min(rows, cols) × cols`` (LAPACK geqrf; Q is never formed)."""
    return np.asarray(np.linalg.qr(block, mode="r"))


def _tsqr_r(tall: Any, work: np.dtype[Any]) -> NDArray[np.float64]:
    """The R factor (float64) of a tall array chunked along its rows only, by a tree of R-only QRs.

    Unlike ``dask.array.linalg.tsqr``, which also builds the N×M Q factor (as big as the data, and
    held until the tree is done), each task factors one chunk, fused with its read and centring, and
    keeps only the cols×cols R. Groups of :data:`TSQR_GROUP` R factors are stacked and factored again
    until one is left: communication is R factors only (M²·itemsize bytes each).
    """
    cols = int(tall.shape[1])

    def r_rows(rows: tuple[int, ...]) -> tuple[int, ...]:
        return tuple(min(r, cols) for r in rows)

    rs = tall.map_blocks(_qr_r, chunks=(r_rows(tall.chunks[0]), (cols,)), dtype=work)
    while rs.numblocks[0] > 1:
        sizes = rs.chunks[0]
        stacks = tuple(sum(sizes[i : i + TSQR_GROUP]) for i in range(0, len(sizes), TSQR_GROUP))
        rs = rs.rechunk({0: stacks}).map_blocks(_qr_r, chunks=(r_rows(stacks), (cols,)), dtype=work)
    return np.asarray(rs.compute(), dtype=np.float64)


_MAPS: dict[tuple[str, int, int], NDArray[Any]] = {}
"""One read-only map per file and process, shared by every task and graph that reads it."""


class NpyColumns:
    """A lazily opened, read-only view of a 2-D ``.npy`` file that pickles as its path.

    ``dask.array.from_array`` accepts it like an array; every process (a worker on another host
    included) memory-maps the file on first access, so a graph never ships the data itself, only the
    path, which must be the same on every worker (shared storage). A process maps each file once
    (keyed by path, size and modification time): graphs are unpickled per ``compute``, and a map per
    copy would count the same cached pages once per map in the resident set.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = str(path)
        arr = np.load(self.path, mmap_mode="r", allow_pickle=False)  # maps, reads only the header
        if not isinstance(arr, np.ndarray) or arr.ndim != 2:
            raise ValueError(f"{self.path}: expected a 2-D (M, N) .npy array")
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"{self.path}: dtype {arr.dtype}, expected a real numeric dtype")
        st = os.stat(self.path)
        self.stamp = (int(st.st_size), int(st.st_mtime_ns))
        self.shape: tuple[int, int] = (int(arr.shape[0]), int(arr.shape[1]))
        self.dtype: np.dtype[Any] = arr.dtype
        self.ndim = 2
        self._arr: NDArray[Any] | None = None
        _MAPS.setdefault((self.path, *self.stamp), arr)

    def _array(self) -> NDArray[Any]:
        if self._arr is None:
            key = (self.path, *self.stamp)
            arr = _MAPS.get(key)
            if arr is None:
                arr = _MAPS.setdefault(key, np.load(self.path, mmap_mode="r", allow_pickle=False))
            if arr.shape != self.shape or arr.dtype != self.dtype:
                raise ValueError(f"{self.path}: now {arr.shape} {arr.dtype}, expected {self.shape} {self.dtype}")
            self._arr = arr
        return self._arr

    def __getitem__(self, key: Any) -> NDArray[Any]:
        return np.asarray(self._array()[key])  # a view: the map's pages are read on demand, file-backed

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "stamp": self.stamp, "shape": self.shape, "dtype": self.dtype.str}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path = state["path"]
        self.stamp = (int(state["stamp"][0]), int(state["stamp"][1]))
        self.shape = (int(state["shape"][0]), int(state["shape"][1]))
        self.dtype = np.dtype(state["dtype"])
        self.ndim = 2
        self._arr = None


def open_dataset_dask(path: str | os.PathLike[str], chunk_points: int | None = None) -> Any:
    """The (M, N) ``cp`` of a data set (or a bare ``.npy`` file) as a dask array chunked along the points.

    Each chunk holds every snapshot of ``chunk_points`` consecutive points (M × chunk_points), the
    layout :func:`pod_basis_dask` with ``"tsqr"`` wants. Data are read lazily from the memory-mapped
    ``.npy`` by whichever process runs the chunk's task (see :class:`NpyColumns`).

    Args:
        path: a ``vdm-aero-dataset/1`` directory (its ``cp.npy`` is used) or a 2-D ``.npy`` file.
        chunk_points: points per chunk (default: about :data:`DEFAULT_CHUNK_BYTES` per chunk, at least
            M points so each TSQR block is tall).

    Returns:
        A ``dask.array.Array`` of ``cp``'s shape and dtype.

    Raises:
        ValueError: on a path that is neither, or a bad ``chunk_points``.
    """
    p = Path(path)
    file = p / "cp.npy" if p.is_dir() else p
    if not file.is_file():
        raise ValueError(f"{file}: no such .npy file (expected a data set directory or a cp.npy file)")
    src = NpyColumns(file)
    m, n = src.shape
    if chunk_points is None:
        chunk_points = max(m, DEFAULT_CHUNK_BYTES // max(1, m * src.dtype.itemsize))
    elif not (_is_int(chunk_points) and chunk_points >= 1):
        raise ValueError(f"chunk_points must be an integer ≥ 1, got {chunk_points!r}")
    chunk_points = min(int(chunk_points), n)
    return da.from_array(
        src,
        chunks=(m, chunk_points),
        name="cp-" + tokenize(str(file.resolve()), src.stamp, m, n, src.dtype.str),
        lock=False,
        asarray=False,
        fancy=False,
        meta=np.empty((0, 0), dtype=src.dtype),
    )


def _fix_signs(modes: NDArray[Any]) -> NDArray[Any]:
    """Flip each mode (in place) so its entry of largest magnitude is positive (:mod:`vdm_aero.pod`'s rule)."""
    idx = np.argmax(np.abs(modes), axis=0)
    signs = np.sign(modes[idx, np.arange(modes.shape[1])])
    signs[signs == 0] = 1
    modes *= signs.astype(modes.dtype)
    return modes


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
