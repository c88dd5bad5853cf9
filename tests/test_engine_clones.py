"""The engine's stochastic clones and gain maps (vdm_aero.nav.engine), against the filter they stand for: a
Kalman filter whose state is augmented by the clone, written out here with plain numpy; and the compass
that, in the product mode's outage, turns the heading and never the tilt."""

from __future__ import annotations

import numpy as np
import pytest

from vdm_aero.nav.engine import EkfEngine

N, K = 6, 2  # a small state; a clone of its first two components
SEL = np.eye(K, N)  # the clone: the state's first K components


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


class _Augmented:
    """The textbook reference: the clone as K more states, constant in the prediction, corrected by every
    update like any other state (Roumeliotis & Burdick, ICRA 2002)."""

    def __init__(self, x: np.ndarray, p: np.ndarray, sel: np.ndarray) -> None:
        self.x = np.concatenate([x, sel @ x])
        t = np.vstack([np.eye(len(x)), sel])
        self.p = t @ p @ t.T

    def predict(self, phi: np.ndarray, q: np.ndarray) -> None:
        f = np.eye(len(self.x))
        f[:N, :N] = phi
        qa = np.zeros_like(self.p)
        qa[:N, :N] = q
        self.x = f @ self.x
        self.p = f @ self.p @ f.T + qa

    def update(self, z: np.ndarray, h: np.ndarray, a: np.ndarray, r: np.ndarray,
               consider: np.ndarray | None = None) -> None:  # fmt: skip
        """``consider``: the main states whose gain rows are zero (Schmidt); P in Joseph form, valid for any gain."""
        ha = np.hstack([h, a])
        s = ha @ self.p @ ha.T + r
        k = self.p @ ha.T @ np.linalg.inv(s)
        if consider is not None:
            k[:N][consider] = 0.0
        self.x = self.x + k @ (z - ha @ self.x)
        ikh = np.eye(len(self.x)) - k @ ha
        self.p = ikh @ self.p @ ikh.T + k @ r @ k.T


@pytest.mark.parametrize("considered", [False, True], ids=["kalman", "consider"])
def test_a_relative_measurement_through_a_clone_is_the_augmented_filters_update(considered: bool) -> None:
    # a linear system, predictions and absolute updates after the clone, then one measurement of the state
    # relative to the clone: the clone engine (which keeps the clone's corrections beside the value the caller
    # took) and the augmented filter (whose clone states every update corrects) must end with the same
    # estimate and covariance; also when the updates hold a state as considered (the filter's outage)
    rng = np.random.default_rng(17)
    consider = np.zeros(N, dtype=bool)
    consider[4] = considered
    x0 = rng.normal(size=N)
    p0 = _spd(rng, N)
    eng = EkfEngine(p0.copy())
    x = x0.copy()
    clone_estimate = SEL @ x  # what the caller took from the state when it cloned
    eng.clone(3.0, SEL)
    ref = _Augmented(x0, p0, SEL)
    for step in range(6):
        phi = np.eye(N) + 0.1 * rng.normal(size=(N, N))
        q = 0.05 * _spd(rng, N)
        eng.predict(phi, q)
        x = phi @ x
        ref.predict(phi, q)
        if step % 2:  # an absolute measurement of two states
            h = rng.normal(size=(2, N))
            r = 0.3 * np.eye(2)
            z = rng.normal(size=2)
            dx, res = eng.update(z - h @ x, h, r, np.inf, consider)
            assert res.accepted
            x = x + dx
            ref.update(z, h, np.zeros((2, K)), r, consider)
    h = np.hstack([np.eye(K), np.zeros((K, N - K))])
    a = -np.eye(K)
    r = 0.2 * np.eye(K)
    z = rng.normal(size=K)
    dx, res = eng.update_relative(z - h @ x - a @ clone_estimate, h, a, r, 3.0, consider)
    assert res.accepted
    ref.update(z, h, a, r, consider)
    np.testing.assert_allclose(x + dx, ref.x[:N], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(eng.P, ref.p[:N, :N], rtol=1e-9, atol=1e-12)
    assert eng.clone_keys == ()  # spent: the clones' covariances with each other were never carried


def test_a_pose_relative_to_its_own_clone_is_no_news() -> None:
    # nothing has happened since the clone (no prediction, no update): the state's first components are the
    # clone, so a measurement of their difference, however precise, says nothing and moves nothing. Fused as
    # an independent fix of the state — what the free-INS fix did before it was made relative — it would
    # shrink their variance to the measurement's
    rng = np.random.default_rng(3)
    p0 = _spd(rng, N)
    eng = EkfEngine(p0.copy())
    eng.clone(0.0, SEL)
    h = SEL.copy()
    dx, res = eng.update_relative(np.array([0.5, -0.2]), h, -np.eye(K), 1e-6 * np.eye(K), 0.0)
    assert res.accepted
    np.testing.assert_allclose(dx, 0.0, atol=1e-9)
    np.testing.assert_allclose(eng.P, p0, rtol=1e-9)
    independent = EkfEngine(p0.copy())
    independent.update(np.array([0.5, -0.2]), h, 1e-6 * np.eye(K), np.inf)
    assert np.all(np.diag(independent.P)[:K] < 1e-5)


def test_resetting_a_state_forgets_its_covariance_with_the_clones_and_dropping_keeps_the_rest() -> None:
    rng = np.random.default_rng(8)
    p_before = _spd(rng, N)
    eng = EkfEngine(p_before.copy())
    eng.clone(1.0, SEL)
    eng.clone(2.0, SEL[::-1])  # states 1 and 0, in that order
    eng.reset_states(slice(0, 1), np.array([[4.0]]))
    assert eng.P[0, 0] == 4.0 and not eng.P[0, 1:].any()
    eng.drop_clones(lambda key: key > 1.5)
    assert eng.clone_keys == (2.0,)
    # state 0 was reset: a fresh draw, uncorrelated with what it was at the clone, so a measurement of it
    # relative to its cloned value has S = 4 + var(clone) + R
    h = np.zeros((1, N))
    h[0, 0] = 1.0
    _, res = eng.update_relative(np.array([1.0]), h, np.array([[0.0, -1.0]]), np.array([[0.5]]), 2.0)
    assert res.nis == pytest.approx(1.0 / (4.0 + p_before[0, 0] + 0.5), rel=1e-12)


def test_the_prediction_by_coupled_rows_is_filterpys_dense_one() -> None:
    """A Φ diagonal but for a few rows (the INS's shape: the pose and the wind couple, the rest decay), predicted
    by those rows, and with a clone carried: the same P and clone covariances as filterpy's dense ΦPΦᵀ + Q."""
    rng = np.random.default_rng(23)
    n, rows = 12, np.array([0, 1, 2, 7])
    p0 = _spd(rng, n)
    dense, by_rows = EkfEngine(p0.copy()), EkfEngine(p0.copy())
    for eng in (dense, by_rows):
        eng.clone(1.0, np.eye(2, n))
    for _ in range(5):
        phi = np.diag(rng.uniform(0.9, 1.0, n))
        phi[rows] += 0.1 * rng.normal(size=(len(rows), n))
        q = np.diag(rng.uniform(0.0, 0.1, n))
        dense.predict(phi, q)
        by_rows.predict(phi, q, rows)
    np.testing.assert_allclose(by_rows.P, dense.P, rtol=1e-13, atol=0)
    np.testing.assert_allclose(by_rows._cross, dense._cross, rtol=1e-13, atol=0)
    phi[5, 3] = 0.5  # an entry outside the rows it is told of is not carried: the contract has no slack
    by_rows.predict(phi, q, rows)
    dense.predict(phi, q)
    assert not np.allclose(by_rows.P, dense.P, rtol=1e-6)
