"""The one adapter around filterpy's ``ExtendedKalmanFilter`` (filterpy is imported nowhere else).

The filter is an error-state EKF: filterpy holds the error state δx (zero between updates) and its
covariance P, and does the Joseph-form update. The covariance prediction is this adapter's, by the rows of Φ
that couple states (:meth:`EkfEngine.predict`; filterpy's own is the reference it is tested against). This
adapter adds what an aircraft filter needs around it:

* NIS gating before every update (χ² of the innovation against its covariance S);
* Schmidt "consider" updates: the states listed as considered keep their estimate (their Kalman gain rows
  are zeroed) while their uncertainty still enters every other state's covariance. The wind and the model
  parameters are considered during a GNSS outage (docs/navigation.md). filterpy has no consider update,
  so that one is written here, in the same Joseph form;
* stochastic clones (Roumeliotis & Burdick, ICRA 2002): a linear combination of the error state remembered at
  one time, whose covariance with the error state is carried through every later prediction and update, so
  that a measurement *relative* to that time (a free INS run from the filter's own pose then) is fused as the
  news it is and not as an independent fix. filterpy has no clones either;
* an inert tail: the last states of a layout that a mode leaves out of its dynamics and its measurements (the
  wind's gradient and the IMU's scale states in every mode but ``vdm``) keep their prior variance and are never
  correlated with the rest, so filterpy carries only the states before them. The filter's arithmetic is then
  that of the active states alone, with what the tail holds put back at the edges (:attr:`EkfEngine.P`, the
  corrections :meth:`EkfEngine.update` returns).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter  # filterpy ≥ 2: the maintained line, numpy 2 support

from vdm_aero._typing import BoolArray, F64Array, IntArray

__all__ = ["EkfEngine", "UpdateResult"]


@dataclass(frozen=True)
class UpdateResult:
    """The outcome of one update: accepted or rejected by the gate, the NIS and the gate threshold."""

    accepted: bool
    nis: float
    gate: float


class EkfEngine:
    """Covariance bookkeeping of an error-state EKF of dimension ``n`` (filterpy underneath).

    ``n_active``: the states ``n_active`` … ``n − 1`` are an inert tail (the module docstring). The caller
    promises that every Φ it predicts with is the identity there with no noise, and that every Jacobian it
    updates with has zero columns there; the engine then reads only the first ``n_active`` rows and columns of
    what it is given. ``p0`` must be diagonal in the tail and uncorrelated with the rest."""

    def __init__(self, p0: F64Array, n_active: int | None = None) -> None:
        p0 = np.array(p0, dtype=np.float64)
        n = p0.shape[0]
        na = n if n_active is None else int(n_active)
        if not 0 < na <= n:
            raise ValueError(f"n_active {na} outside 1 … {n}")
        tail_var = p0.diagonal()[na:].copy()
        if p0[:na, na:].any() or p0[na:, :na].any() or np.count_nonzero(p0[na:, na:] - np.diag(tail_var)):
            raise ValueError("the inert tail's prior covariance must be diagonal and uncorrelated with the rest")
        self._kf = ExtendedKalmanFilter(dim_x=na, dim_z=1)
        self._kf.x = np.zeros((na, 1))
        self._kf.P = p0[:na, :na].copy()
        self._n = n
        self._na = na
        self._tail_var = tail_var
        # clones: their keys, each one's own covariance (k × k) and their covariances with the error state,
        # side by side (n × k per clone: one product per prediction however many there are), and the
        # corrections the updates since have made to them (k per clone, side by side)
        self._clone_keys: list[float] = []
        self._clone_cov = np.zeros((0, 0, 0))  # clones × k × k
        self._cross = np.zeros((na, 0))
        self._clone_dx = np.zeros(0)

    @property
    def n_active(self) -> int:
        """The states filterpy carries: the first ``n_active`` of ``n`` (the rest an inert tail)."""
        return self._na

    @property
    def P(self) -> F64Array:
        """The covariance, n × n. Without an inert tail it is filterpy's own array; with one, a new array (the
        tail's prior variances on its diagonal), so a change to it must be set back through the setter."""
        p = np.asarray(self._kf.P)
        if self._na == self._n:
            return p
        full = np.zeros((self._n, self._n))
        full[: self._na, : self._na] = p
        tail = np.arange(self._na, self._n)
        full[tail, tail] = self._tail_var
        return full

    @P.setter
    def P(self, value: F64Array) -> None:
        """Set the covariance (n × n). An inert tail takes only its diagonal: its covariance with the active
        states is not carried (nothing the filter fuses or predicts could read it)."""
        value = np.asarray(value, dtype=np.float64)
        self._kf.P = np.array(value[: self._na, : self._na])
        self._tail_var = value.diagonal()[self._na :].copy()

    def variances(self) -> F64Array:
        """The diagonal of :attr:`P` (n), without forming P."""
        return np.concatenate([np.asarray(self._kf.P).diagonal(), self._tail_var])

    def projected(self, h: F64Array) -> F64Array:
        """H·P·Hᵀ for a Jacobian ``h`` (m × n) that does not observe the inert tail."""
        ha = h[:, : self._na]
        return np.asarray(ha @ self._kf.P @ ha.T)

    def _full(self, dx: F64Array) -> F64Array:
        """A correction of the active states as one of all n (the inert tail's part zero)."""
        if self._na == self._n:
            return dx
        out = np.zeros(self._n)
        out[: self._na] = dx
        return out

    def predict(self, phi: F64Array, qd: F64Array, rows: IntArray | None = None) -> None:
        """P ← ΦPΦᵀ + Q_d (δx stays zero: the nominal state carries the propagation).

        ``rows``: the only rows of Φ with entries off its diagonal, every other row being diagonal (the INS's
        Φ: the pose's nine rows and the wind's two, :attr:`~vdm_aero.nav.ins.InsProcess.coupled_rows`). ΦPΦᵀ is
        then a row scaling, a column scaling and two products with those rows, instead of filterpy's two dense
        n × n products and its copies: 25.6 → 16.0 µs at n = 53 (docs/performance.md). Without ``rows``,
        filterpy's own ``predict``: the reference the tests hold this one to."""
        kf = self._kf
        if self._na < self._n:
            phi, qd = phi[: self._na, : self._na], qd[: self._na, : self._na]
        if rows is None:
            kf.F = phi
            kf.Q = qd
            kf.predict()
            if self._clone_keys:
                self._cross = phi @ self._cross  # a clone is a constant: its error does not propagate
            return
        d = phi.diagonal()
        coupled = phi[rows]
        m = d[:, None] * kf.P  # ΦP: the diagonal rows scaled ...
        m[rows] = coupled @ kf.P  # ... the coupled ones in full
        p = m * d  # (ΦP)Φᵀ the same way, by columns
        p[:, rows] = m @ coupled.T
        p += qd
        kf.P = p
        if self._clone_keys:
            cross = d[:, None] * self._cross
            cross[rows] = coupled @ self._cross
            self._cross = cross

    def nis(self, innovation: F64Array, h: F64Array, r: F64Array) -> float:
        """The normalised innovation squared yᵀS⁻¹y of a measurement, S = HPHᵀ + R, without fusing it."""
        return self._s_and_nis(innovation, h[:, : self._na], r)[1]

    def _s_and_nis(self, innovation: F64Array, h: F64Array, r: F64Array) -> tuple[F64Array, float]:
        s = h @ self._kf.P @ h.T + r
        try:
            return s, float(innovation @ np.linalg.solve(s, innovation))
        except np.linalg.LinAlgError:
            return s, float("inf")

    def update(
        self,
        innovation: F64Array,
        h: F64Array,
        r: F64Array,
        gate: float,
        consider: BoolArray | None = None,
    ) -> tuple[F64Array, UpdateResult]:
        """Fuse one measurement given its innovation y = z − h(x̂), Jacobian H and noise R. Returns the
        correction δx (to inject into the nominal state; zero when rejected) and the gate outcome."""
        kf = self._kf
        p = kf.P
        na = self._na
        h = h[:, :na]
        if consider is not None:
            consider = consider[:na]
        if consider is None or not consider.any():
            # filterpy forms S and S⁻¹ for its gain anyway: the gate reads its S⁻¹, and a rejected update puts the
            # prior back (filterpy assigns a new P, the prior array is untouched). Gating first would form S twice
            # for every accepted update, the common case (docs/performance.md, third round)
            kf.x = np.zeros((na, 1))
            try:
                kf.update(innovation.reshape(-1, 1), lambda _x: h, lambda _x: np.zeros((len(innovation), 1)), R=r)
                nis = float(innovation @ kf.SI @ innovation)
            except np.linalg.LinAlgError:  # a singular S
                nis = float("inf")
            except ValueError:  # a non-finite S (scipy's inverse checks it)
                nis = float("nan")
            if not nis <= gate:
                kf.P, kf.x = p, np.zeros((na, 1))
                return np.zeros(self._n), UpdateResult(False, nis, gate)
            dx = np.asarray(kf.x).ravel().copy()
            if self._clone_keys:
                self._update_clones(p, h, np.asarray(kf.S), np.asarray(kf.K), innovation, optimal=True)
        else:
            s, nis = self._s_and_nis(innovation, h, r)
            if not nis <= gate:
                return np.zeros(self._n), UpdateResult(False, nis, gate)
            k = np.linalg.solve(s, h @ p).T
            k[consider] = 0.0
            ikh = np.eye(na) - k @ h
            kf.P = ikh @ p @ ikh.T + k @ r @ k.T
            dx = k @ innovation
            if self._clone_keys:
                self._update_clones(p, h, s, k, innovation)
        kf.x = np.zeros((na, 1))
        return self._full(dx), UpdateResult(True, nis, gate)

    def reset_states(self, idx: slice, cov: F64Array) -> None:
        """Forget what is known of the states ``idx``: covariance ``cov``, uncorrelated with every other state
        and with the clones (a reset makes them a fresh draw)."""
        if idx.start >= self._na:  # an inert tail's: its variance alone
            self._tail_var[idx.start - self._na : idx.stop - self._na] = np.diagonal(cov)
            return
        if idx.stop > self._na:
            raise ValueError(f"states {idx.start} … {idx.stop - 1} straddle the inert tail at {self._na}")
        p = self._kf.P
        p[idx, :] = 0.0
        p[:, idx] = 0.0
        p[idx, idx] = cov
        self._kf.P = p
        self._cross[idx, :] = 0.0

    # ------------------------------------------------------------------------------- clones
    @property
    def clone_keys(self) -> tuple[float, ...]:
        return tuple(self._clone_keys)

    def clone(self, key: float, sel: F64Array) -> None:
        """Remember ``sel``·x now (``sel`` k × n) under ``key``, as k more states of the filter: constant in
        the prediction, corrected by every update like the others (the caller keeps the value it took now; the
        engine keeps the corrections and applies them in :meth:`update_relative`)."""
        sel = sel[:, : self._na]
        p = np.asarray(self._kf.P)
        self._clone_keys.append(key)
        cov = (sel @ p @ sel.T)[None]
        self._clone_cov = np.concatenate([self._clone_cov, cov]) if self._clone_cov.size else cov
        self._cross = np.hstack([self._cross, p @ sel.T])
        self._clone_dx = np.concatenate([self._clone_dx, np.zeros(sel.shape[0])])

    def _update_clones(self, p: F64Array, h: F64Array, s: F64Array, gain: F64Array, y: F64Array,
                       optimal: bool = False) -> None:  # fmt: skip
        """The clones' share of an update whose prior covariance was ``p``, innovation covariance ``s`` and
        gain ``gain`` (any gain: a consider update's too): the clones take their optimal gain
        K_c = Cᵀ·Hᵀ·S⁻¹, so Cov(clone) ← Cov(clone) − K_c·S·K_cᵀ and C ← C − K·H·C − (P·Hᵀ − K·S)·K_cᵀ, whose
        last term vanishes for the ``optimal`` gain (P·Hᵀ = K·S)."""
        c = self._cross
        hc = h @ c
        kc = np.linalg.solve(s, hc).T  # (k·clones) × m; S is symmetric
        self._cross = c - gain @ hc if optimal else c - gain @ hc - (p @ h.T - gain @ s) @ kc.T
        self._clone_dx = self._clone_dx + kc @ y
        kc3 = kc.reshape(self._clone_cov.shape[0], self._clone_cov.shape[1], -1)  # clones × k × m
        self._clone_cov = self._clone_cov - np.einsum("jam,mn,jbn->jab", kc3, s, kc3)

    def drop_clones(self, keep: Callable[[float], bool] = lambda _key: False) -> None:
        """Forget the clones whose key ``keep`` rejects (by default all)."""
        if not self._clone_keys:
            return
        k = self._cross.shape[1] // len(self._clone_keys)
        kept = [j for j, key in enumerate(self._clone_keys) if keep(key)]
        self._clone_keys = [self._clone_keys[j] for j in kept]
        self._clone_cov = self._clone_cov[kept] if kept else np.zeros((0, 0, 0))
        cols = [c for j in kept for c in range(j * k, (j + 1) * k)]
        self._cross = self._cross[:, cols]
        self._clone_dx = self._clone_dx[cols]

    def update_relative(
        self,
        innovation: F64Array,
        h: F64Array,
        a: F64Array,
        r: F64Array,
        key: float,
        consider: BoolArray | None = None,
    ) -> tuple[F64Array, UpdateResult]:
        """Fuse a measurement relative to the clone ``key``: y = H·δx + A·δx_clone + v, v ~ N(0, R) (A m × k),
        ``innovation`` taken against the clone's value as the caller took it (the engine adds the corrections
        since). The gain is the augmented filter's (the clone as k more states), P is updated in the form
        valid for any gain (the considered states' gain rows are zeroed), and the clones are spent: their
        covariances with each other were never carried, so none is left. No gate: the caller fuses what it
        means to fuse."""
        h = h[:, : self._na]
        if consider is not None:
            consider = consider[: self._na]
        j = self._clone_keys.index(key)
        k = self._clone_cov[j].shape[0]
        c, paa = self._cross[:, j * k : (j + 1) * k], self._clone_cov[j]
        innovation = innovation - a @ self._clone_dx[j * k : (j + 1) * k]
        p = np.asarray(self._kf.P)
        pyt = p @ h.T + c @ a.T  # cov(δx, y)
        s = h @ pyt + a @ c.T @ h.T + a @ paa @ a.T + r
        try:
            gain = np.linalg.solve(s, pyt.T).T
            nis = float(innovation @ np.linalg.solve(s, innovation))
        except np.linalg.LinAlgError:
            return np.zeros(self._n), UpdateResult(False, float("inf"), float("inf"))
        if consider is not None:
            gain[consider] = 0.0
        kpt = gain @ pyt.T
        p_new = p - kpt - kpt.T + gain @ s @ gain.T
        self._kf.P = 0.5 * (p_new + p_new.T)
        self.drop_clones()
        return self._full(gain @ innovation), UpdateResult(True, nis, float("inf"))
