"""Sparse pressure ports by (Q-)DEIM and the linear POD–DEIM force model.

The method (Duan, Wang & Hesthaven): with POD modes ``U`` (N, n_b) and mean ``μ`` of the training
pressure snapshots, choose n_s ≥ n_b port indices ``p`` (``P`` = the N×n_s selection matrix) and
reconstruct a full pressure field from its port values by the oblique (gappy) projection

    Cp ≈ μ + U (PᵀU)⁺ (Cp_s − μ_s),          Cp_s = Pᵀ Cp,  μ_s = Pᵀ μ,

which interpolates the ports exactly when n_s = n_b ((PᵀU)⁺ = (PᵀU)⁻¹) and is the least-squares
(gappy POD) fit when n_s > n_b. The body-axis coefficients are the linear map ``C = S Cp`` (``S`` the
(6, N) force/moment matrix of :func:`vdm_aero.coefficients.force_moment_matrix`), so

    C ≈ M_s Cp_s + M_0,        M_s = S U (PᵀU)⁺ (6, n_s),    M_0 = S μ − M_s μ_s (6,),

precomputed in float64 at fit time: run time is one (6, n_s) matrix–vector product.

Port selection
    :func:`deim_indices` is the greedy DEIM of Chaturantabut & Sorensen (2010), the method's
    Algorithm 1; :func:`qdeim_indices` is Q-DEIM (Drmač & Gugercin 2016), the first n_b column pivots
    of the pivoted QR of Uᵀ. Both take an optional candidate set (ports may only go where a port can
    be drilled) and break ties by the lowest candidate position (``argmax``).

Oversampling rule (n_s > n_b), the same for both selectors
    Pivoted QR of the n_b×N matrix Uᵀ yields only n_b meaningful pivots (the residual is zero
    afterwards), and the DEIM residual is zero at the ports once all modes are used. Further ports are
    therefore added greedily by **D-optimal design**: the next port is the unselected candidate ``i``
    of largest leverage ``h_i = u_iᵀ (U_pᵀ U_p)⁻¹ u_i`` (``u_i`` the i-th row of U, ``U_p = PᵀU``). By
    the matrix determinant lemma ``det(U_pᵀU_p + u_i u_iᵀ) = det(U_pᵀU_p)(1 + h_i)``, so each step is
    the exact greedy maximiser of ``det(U_pᵀU_p)``; ``h_i`` is also the variance of the gappy
    reconstruction at point i under unit white port noise, so the port goes where the current ports
    reconstruct worst. ``U_pᵀU_p`` only grows (Loewner order), so ``‖(PᵀU)⁺‖₂`` never increases.

Only :func:`qdeim_indices` needs scipy (imported when it is called); fitting with ``method="deim"``
and every run-time method (``predict``, ``reconstruct``, ``gappy``, ``predict_gappy``) need numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike

from vdm_aero._typing import BoolArray, F64Array, FloatArray, IntArray
from vdm_aero.errors import NotFittedError
from vdm_aero.pod import PODResult, pod_basis, projection_error

__all__ = ["DEIMForceModel", "deim_indices", "projection_error", "qdeim_indices"]

SELECTION_METHODS: Final = ("deim", "qdeim")

_RANK_TOL: Final = 100.0 * float(np.finfo(np.float64).eps)
"""A pivot ≤ this times the largest entry of its mode means the basis is rank deficient on the candidates."""

_GAPPY_CACHE_SIZE: Final = 256


# --------------------------------------------------------------------------------------------------
# Port selection
# --------------------------------------------------------------------------------------------------


def deim_indices(
    modes: ArrayLike,
    candidates: IntArray | BoolArray | Sequence[int] | None = None,
    *,
    n_sensors: int | None = None,
) -> IntArray:
    """Greedy DEIM point selection (Chaturantabut & Sorensen 2010, Algorithm 1 of the method).

    ``p_1 = argmax |u_1|``; for l = 2..n_b solve ``U[p, :l−1] c = U[p, l−1]``, form the interpolation
    residual ``r = u_l − U[:, :l−1] c`` and take ``p_l = argmax |r|``. All maxima run over the candidate
    rows only, already selected rows are excluded explicitly (their residual is zero in exact
    arithmetic), and ties go to the lowest candidate position. Cost O(|candidates|·n_b²).

    Args:
        modes: (N, n_b) basis ``U`` (need not be orthonormal; any float dtype, used in float64).
        candidates: allowed point indices (1-D, unique, in [0, N), their order breaks ties) or an
            (N,) boolean mask; ``None`` means every point.
        n_sensors: number of indices (default n_b). Fewer than n_b gives the DEIM points of the
            leading ``n_sensors`` modes (the greedy is nested); more continues with the D-optimal rule
            of the module docstring.

    Returns:
        (n_sensors,) int64 point indices into the N rows of ``modes``, in selection order.

    Raises:
        ValueError: on bad shapes or candidates, too few candidates, or a basis that is (numerically)
            rank deficient on the candidate rows.
    """
    u_c, cand, n_s = _prepare_selection(modes, candidates, n_sensors)
    n_b = u_c.shape[1]
    n_deim = min(n_b, n_s)
    picked = np.empty(n_deim, dtype=np.int64)
    for ell in range(n_deim):
        col = u_c[:, ell]
        if ell == 0:
            resid = col.copy()
        else:
            p = picked[:ell]
            coef = np.linalg.solve(u_c[p, :ell], col[p])
            resid = col - u_c[:, :ell] @ coef
        score = np.abs(resid)
        score[picked[:ell]] = -1.0
        best = int(np.argmax(score))
        scale = float(np.max(np.abs(col)))
        if not (np.isfinite(score[best]) and score[best] > _RANK_TOL * scale):
            raise ValueError(
                f"modes: DEIM residual of mode {ell + 1} vanishes on the candidate points; "
                "the basis is rank deficient there (fewer independent candidates than modes?)"
            )
        picked[ell] = best
    if n_s > n_b:
        picked = _extend_d_optimal(u_c, picked, n_s - n_b)
    return cand[picked]


def qdeim_indices(
    modes: ArrayLike,
    candidates: IntArray | BoolArray | Sequence[int] | None = None,
    *,
    n_sensors: int | None = None,
) -> IntArray:
    """Q-DEIM point selection (Drmač & Gugercin 2016): column pivots of the pivoted QR of ``U[cand]ᵀ``.

    The first ``min(n_sensors, n_b)`` pivots of ``scipy.linalg.qr(U[cand].T, pivoting=True)`` (LAPACK
    geqp3), mapped back to point indices; further ports (``n_sensors > n_b``) by the D-optimal rule of
    the module docstring. Arguments, return value and errors as :func:`deim_indices`.
    """
    from scipy.linalg import qr  # fit-time only: the run-time install has no scipy

    u_c, cand, n_s = _prepare_selection(modes, candidates, n_sensors)
    n_b = u_c.shape[1]
    r, piv = qr(u_c.T, mode="r", pivoting=True)
    n_q = min(n_b, n_s)
    diag = np.abs(np.diagonal(r)[:n_q])
    scale = float(np.abs(u_c).max())
    if not (np.isfinite(diag).all() and (diag > _RANK_TOL * scale).all()):
        raise ValueError(
            "modes: the pivoted QR of the basis on the candidate points is rank deficient "
            "(fewer independent candidates than modes?)"
        )
    picked = np.asarray(piv[:n_q], dtype=np.int64)
    if n_s > n_b:
        picked = _extend_d_optimal(u_c, picked, n_s - n_b)
    return cand[picked]


def _extend_d_optimal(u_c: F64Array, picked: IntArray, n_extra: int) -> IntArray:
    """Add ``n_extra`` rows of ``u_c`` greedily by largest leverage ``h_i = u_iᵀ (U_pᵀU_p)⁻¹ u_i``.

    The leverages are computed once from a QR of ``U_p`` and then updated by Sherman–Morrison after
    each added row ``j`` (``h_i ← h_i − (u_iᵀ G⁻¹ u_j)² / (1 + h_j)``): O(|candidates|·n_b) per port.
    """
    chosen = [int(i) for i in picked]
    _, r = np.linalg.qr(u_c[chosen])  # U_pᵀU_p = RᵀR, R (n_b, n_b) upper triangular, invertible
    z = np.linalg.solve(r.T, u_c.T)  # R⁻ᵀ u_i for every candidate, (n_b, n_c)
    lev = np.einsum("ij,ij->j", z, z)
    del z
    r_inv = np.linalg.inv(r)
    g_inv = r_inv @ r_inv.T  # (U_pᵀU_p)⁻¹
    for _ in range(n_extra):
        score = lev.copy()
        score[chosen] = -np.inf
        j = int(np.argmax(score))
        chosen.append(j)
        w = g_inv @ u_c[j]
        denom = 1.0 + lev[j]
        lev -= (u_c @ w) ** 2 / denom
        g_inv -= np.outer(w, w) / denom
    return np.asarray(chosen, dtype=np.int64)


def _prepare_selection(
    modes: ArrayLike, candidates: IntArray | BoolArray | Sequence[int] | None, n_sensors: int | None
) -> tuple[F64Array, IntArray, int]:
    u = np.asarray(modes)
    if u.ndim != 2 or u.shape[0] < 1 or u.shape[1] < 1:
        raise ValueError(f"modes: shape {u.shape}, expected a 2-D (N, n_b) basis with N, n_b ≥ 1")
    if u.dtype.kind not in "fiu":
        raise ValueError(f"modes: dtype {u.dtype}, expected a real numeric dtype")
    n_pts, n_b = u.shape
    cand = _check_candidates(candidates, n_pts)
    n_s = n_b if n_sensors is None else n_sensors
    if not (_is_int(n_s) and n_s >= 1):
        raise ValueError(f"n_sensors must be an integer ≥ 1, got {n_sensors!r}")
    n_s = int(n_s)
    if n_s > cand.size:
        raise ValueError(f"n_sensors = {n_s} but only {cand.size} candidate points")
    u_c = np.asarray(u[cand], dtype=np.float64)
    if not np.isfinite(u_c).all():
        raise ValueError("modes: contains NaN or Inf values on the candidate points")
    return u_c, cand, n_s


def _check_candidates(candidates: ArrayLike | None, n_pts: int) -> IntArray:
    if candidates is None:
        return np.arange(n_pts, dtype=np.int64)
    c = np.asarray(candidates)
    if c.ndim != 1:
        raise ValueError(f"candidates: shape {c.shape}, expected 1-D indices or an (N,) boolean mask")
    if c.dtype.kind == "b":
        if c.shape[0] != n_pts:
            raise ValueError(f"candidates: boolean mask of length {c.shape[0]}, expected N = {n_pts}")
        c = np.flatnonzero(c)
    elif c.size and c.dtype.kind not in "iu":
        raise ValueError(f"candidates: dtype {c.dtype}, expected integer indices or a boolean mask")
    idx = c.astype(np.int64)
    if idx.size == 0:
        raise ValueError("candidates: empty, expected at least one candidate point")
    bad = (idx < 0) | (idx >= n_pts)
    if bad.any():
        raise ValueError(f"candidates: index {int(idx[bad][0])} out of range for N = {n_pts}")
    uniq, counts = np.unique(idx, return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"candidates: index {int(uniq[counts > 1][0])} listed twice")
    return idx


# --------------------------------------------------------------------------------------------------
# The force model
# --------------------------------------------------------------------------------------------------


class DEIMForceModel:
    """POD + (Q-)DEIM linear map from n_s pressure ports to the 6 body-axis coefficients.

    A scikit-learn style estimator: constructor arguments are stored as given and validated by
    :meth:`fit`; fitted attributes end in ``_``.

    Args:
        n_sensors: n_s, the number of pressure ports (≥ 1).
        n_modes: n_b, the number of POD modes (1 ≤ n_b ≤ min(n_s, M, N)); default n_s (square DEIM,
            exact interpolation at the ports). n_s > n_b gives a least-squares (gappy POD) fit.
        method: port selection, ``"deim"`` (greedy DEIM) or ``"qdeim"`` (pivoted QR).
        candidates: point indices (or an (N,) boolean mask) where ports may be placed; default all.
        pod_method: :func:`vdm_aero.pod.pod_basis` ``method`` (``"auto"``, ``"exact"``,
            ``"snapshots"`` or ``"randomized"``).
        random_state: seed of the Generator of the randomized POD; ``None`` means seed 0, so every
            fit is reproducible (no other step is random).

    Fitted attributes:
        mean_: (N,) float64 mean pressure snapshot μ.
        modes_: (N, n_b) POD modes U (float32 for float32 ``cp``, else float64).
        singular_values_: (n_b,) float64.
        energy_: fraction of the centred snapshot energy captured by the n_b modes.
        pod_: the :class:`~vdm_aero.pod.PODResult`.
        sensors_: (n_s,) int64 port indices (into the N points) in selection order; the port values
            passed to :meth:`predict` follow this order.
        port_modes_: (n_s, n_b) float64 PᵀU.
        port_pinv_: (n_b, n_s) float64 (PᵀU)⁺.
        force_modes_: (6, n_b) float64 S U.
        force_mean_: (6,) float64 S μ.
        Ms_: (6, n_s) float64 port-to-coefficient matrix.
        M0_: (6,) float64 offset.
        n_modes_, n_sensors_, n_points_: n_b, n_s, N.
        port_amplification_: ``‖(PᵀU)⁺‖₂``, the factor by which the sensor selection can amplify the
            projection error (DEIM error bound ``‖x − x̂‖ ≤ ‖(PᵀU)⁺‖ ‖(I − UUᵀ)(x − μ)‖``).

    The ``truth`` argument of :meth:`fit` is accepted for API symmetry with the correction net (which
    learns ``truth − predict``); this linear model only checks that it has M rows and stores nothing
    from it. ``S`` is normally 6×N (:meth:`vdm_aero.dataset.Dataset.force_matrix`); any (K, N) matrix
    works and the outputs then have K columns.
    """

    def __init__(
        self,
        n_sensors: int,
        n_modes: int | None = None,
        method: str = "deim",
        candidates: IntArray | BoolArray | Sequence[int] | None = None,
        pod_method: str = "auto",
        random_state: int | None = None,
    ) -> None:
        self.n_sensors = n_sensors
        self.n_modes = n_modes
        self.method = method
        self.candidates = candidates
        self.pod_method = pod_method
        self.random_state = random_state

    def get_params(self) -> dict[str, Any]:
        """The constructor arguments (scikit-learn convention)."""
        return {
            "n_sensors": self.n_sensors,
            "n_modes": self.n_modes,
            "method": self.method,
            "candidates": self.candidates,
            "pod_method": self.pod_method,
            "random_state": self.random_state,
        }

    def __repr__(self) -> str:
        cand = None if self.candidates is None else f"<{np.asarray(self.candidates).size} candidates>"
        return (
            f"DEIMForceModel(n_sensors={self.n_sensors!r}, n_modes={self.n_modes!r}, method={self.method!r}, "
            f"candidates={cand}, pod_method={self.pod_method!r}, random_state={self.random_state!r})"
        )

    # -- fitting -------------------------------------------------------------------------------------

    def fit(self, cp: ArrayLike, force_matrix: ArrayLike, truth: ArrayLike | None = None) -> DEIMForceModel:
        """Compute the POD basis, choose the ports and precompute ``Ms_`` and ``M0_``.

        Args:
            cp: (M, N) training pressure snapshots (float32 memmap welcome; read block by block).
            force_matrix: (6, N) ``S`` with ``C = S @ cp`` (``Dataset.force_matrix()``).
            truth: optional (M, 6) coefficients; checked for M rows, otherwise unused (see the class doc).

        Returns:
            ``self``.

        Raises:
            ValueError: on wrong shapes, a bad ``n_sensors``/``n_modes``/``method``/``candidates``, or
                non-finite values.
        """
        x = np.asarray(cp) if not isinstance(cp, np.ndarray) else cp
        if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
            raise ValueError(f"cp: shape {x.shape}, expected a 2-D (M, N) snapshot matrix")
        m, n_pts = x.shape
        s = np.asarray(force_matrix, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != n_pts or s.shape[0] < 1:
            raise ValueError(f"force_matrix: shape {s.shape}, expected (6, N) with N = {n_pts} to match cp")
        if not np.isfinite(s).all():
            raise ValueError("force_matrix: contains NaN or Inf values")
        if truth is not None:
            t = np.asarray(truth)
            if t.ndim != 2 or t.shape[0] != m:
                raise ValueError(f"truth: shape {t.shape}, expected (M, 6) with M = {m} to match cp")
        n_s = self.n_sensors
        if not (_is_int(n_s) and n_s >= 1):
            raise ValueError(f"n_sensors must be an integer ≥ 1, got {n_s!r}")
        n_s = int(n_s)
        n_b = n_s if self.n_modes is None else self.n_modes
        if not (_is_int(n_b) and n_b >= 1):
            raise ValueError(f"n_modes must be an integer ≥ 1 or None, got {self.n_modes!r}")
        n_b = int(n_b)
        if n_b > min(m, n_pts):
            raise ValueError(f"n_modes = {n_b} exceeds min(M, N) = {min(m, n_pts)} (cp has shape {x.shape})")
        if n_b > n_s:
            raise ValueError(f"n_modes = {n_b} exceeds n_sensors = {n_s}: the port system PᵀU would be underdetermined")
        if self.method not in SELECTION_METHODS:
            raise ValueError(f"method must be one of {', '.join(map(repr, SELECTION_METHODS))}, got {self.method!r}")
        cand = _check_candidates(self.candidates, n_pts)
        if cand.size < n_s:
            raise ValueError(f"n_sensors = {n_s} but only {cand.size} candidate points")
        seed = 0 if self.random_state is None else self.random_state
        pod = pod_basis(x, n_b, method=self.pod_method, rng=np.random.default_rng(seed))
        select = deim_indices if self.method == "deim" else qdeim_indices
        sensors = select(pod.modes, cand, n_sensors=n_s)

        port_modes = np.asarray(pod.modes[sensors], dtype=np.float64)
        port_pinv = np.asarray(np.linalg.pinv(port_modes), dtype=np.float64)
        force_modes = np.asarray(s @ np.asarray(pod.modes, dtype=np.float64), dtype=np.float64)
        force_mean = np.asarray(s @ pod.mean, dtype=np.float64)
        ms = force_modes @ port_pinv
        m0 = force_mean - ms @ pod.mean[sensors]

        self.pod_: PODResult = pod
        self.mean_: F64Array = pod.mean
        self.modes_: FloatArray = pod.modes
        self.singular_values_: F64Array = pod.singular_values
        self.energy_ = pod.energy
        self.sensors_: IntArray = sensors
        self.port_modes_: F64Array = port_modes
        self.port_pinv_: F64Array = port_pinv
        self.port_amplification_ = float(np.linalg.norm(port_pinv, 2))
        self.force_modes_: F64Array = force_modes
        self.force_mean_: F64Array = force_mean
        self.Ms_: F64Array = ms
        self.M0_: F64Array = m0
        self.n_modes_ = n_b
        self.n_sensors_ = n_s
        self.n_points_ = n_pts
        self.__dict__.pop("_gappy_cache", None)  # matrices of a previous fit
        return self

    # -- prediction ----------------------------------------------------------------------------------

    def predict(self, cp_ports: ArrayLike) -> F64Array:
        """Coefficients ``Ms_ @ cp_s + M0_`` from port values (in ``sensors_`` order).

        Args:
            cp_ports: (n_s,) or (K, n_s) port pressure coefficients.

        Returns:
            (6,) or (K, 6) float64 ``[CX, CY, CZ, Croll, Cpitch, Cyaw]``. NaN ports give NaN outputs;
            use :meth:`predict_gappy` for missing ports.
        """
        self._check_fitted()
        xs = self._ports(cp_ports)
        return np.asarray(xs @ self.Ms_.T + self.M0_, dtype=np.float64)

    def reconstruct(self, cp_ports: ArrayLike) -> F64Array:
        """Full pressure field ``μ + U (PᵀU)⁺ (cp_s − μ_s)`` from port values.

        Args:
            cp_ports: (n_s,) or (K, n_s) port pressure coefficients (``sensors_`` order).

        Returns:
            (N,) or (K, N) float64 (K·N·8 bytes: reconstruct in batches for big K).
        """
        self._check_fitted()
        xs = self._ports(cp_ports)
        coef = (xs - self.mean_[self.sensors_]) @ self.port_pinv_.T
        return np.asarray(self.mean_ + coef @ np.asarray(self.modes_, dtype=np.float64).T, dtype=np.float64)

    def gappy(self, present_mask: ArrayLike) -> tuple[F64Array, F64Array]:
        """Port-to-coefficient matrices when only the ports with ``present_mask`` are available.

        Least squares with the present rows of PᵀU: ``Ms' = S U_k (P_presentᵀ U_k)⁺`` and
        ``M0' = S μ − Ms' μ_present``, where U_k keeps the leading ``k = min(n_b, #present)`` modes —
        with fewer present ports than modes the trailing (least energetic) modes are dropped so the
        fit stays well posed. A present subset on which the kept modes are still rank deficient is
        handled by the pseudo-inverse (``numpy.linalg.pinv`` cut-off), which drops the unobservable
        directions. Results are cached per mask.

        Args:
            present_mask: (n_s,) bool, True where the port value is available (``sensors_`` order).

        Returns:
            ``(Ms', M0')``: (6, n_s) float64 with zero columns at the missing ports, and (6,) float64;
            ``Ms' @ where(present, cp_s, 0) + M0'`` is the prediction.

        Raises:
            ValueError: on a mask of the wrong shape or dtype, or when no port is present.
        """
        self._check_fitted()
        mask = np.asarray(present_mask)
        if mask.dtype.kind != "b" or mask.shape != (self.n_sensors_,):
            raise ValueError(f"present_mask: shape {mask.shape} dtype {mask.dtype}, expected ({self.n_sensors_},) bool")
        cache: dict[bytes, tuple[F64Array, F64Array]] = self.__dict__.setdefault("_gappy_cache", {})
        key = mask.tobytes()
        hit = cache.get(key)
        if hit is not None:
            return hit[0].copy(), hit[1].copy()
        present = np.flatnonzero(mask)
        if present.size == 0:
            raise ValueError("present_mask: no port present, cannot predict")
        k = min(self.n_modes_, present.size)
        pinv = np.linalg.pinv(self.port_modes_[present, :k])  # (k, #present)
        ms = np.zeros_like(self.Ms_)
        ms[:, present] = self.force_modes_[:, :k] @ pinv
        m0 = self.force_mean_ - ms[:, present] @ self.mean_[self.sensors_[present]]
        if len(cache) >= _GAPPY_CACHE_SIZE:
            cache.pop(next(iter(cache)))
        cache[key] = (ms, m0)
        return ms.copy(), m0.copy()

    def predict_gappy(self, cp_ports: ArrayLike) -> F64Array:
        """Like :meth:`predict`, with NaN (or ±Inf) marking missing ports; see :meth:`gappy`.

        Args:
            cp_ports: (n_s,) or (K, n_s); each row may miss a different set of ports.

        Returns:
            (6,) or (K, 6) float64.

        Raises:
            ValueError: on a wrong shape or a row with every port missing.
        """
        self._check_fitted()
        xs = self._ports(cp_ports)
        single = xs.ndim == 1
        rows = xs[None, :] if single else xs
        missing = ~np.isfinite(rows)
        out = np.empty((rows.shape[0], self.Ms_.shape[0]), dtype=np.float64)
        if rows.shape[0]:
            patterns, inverse = np.unique(missing, axis=0, return_inverse=True)
            inverse = inverse.reshape(-1)
            filled = np.where(missing, 0.0, rows)
            for j, pattern in enumerate(patterns):
                sel = inverse == j
                if pattern.all():
                    raise ValueError(f"cp_ports: row {int(np.flatnonzero(sel)[0])} has every port missing")
                ms, m0 = (self.Ms_, self.M0_) if not pattern.any() else self.gappy(~pattern)
                out[sel] = filled[sel] @ ms.T + m0
        return out[0] if single else out

    # -- helpers -------------------------------------------------------------------------------------

    def _check_fitted(self) -> None:
        if not hasattr(self, "Ms_"):
            raise NotFittedError("this DEIMForceModel is not fitted yet: call fit(cp, force_matrix) before using it")

    def _ports(self, cp_ports: ArrayLike) -> F64Array:
        xs = np.asarray(cp_ports, dtype=np.float64)
        if xs.ndim not in (1, 2) or xs.shape[-1] != self.n_sensors_:
            raise ValueError(
                f"cp_ports: shape {xs.shape}, expected ({self.n_sensors_},) or (K, {self.n_sensors_}) "
                "port values in sensors_ order"
            )
        return xs


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
