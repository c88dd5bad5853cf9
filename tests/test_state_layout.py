"""The state layout per mode (vdm_aero.nav.engine's inert tail, ``NavFilter._active_states``): a mode that leaves
the last blocks of the error state out of its dynamics and measurements carries only the states before them, and
its arithmetic is the full engine's. The reference is the same engine carrying every state, which filterpy and
the Joseph form make exact for states that nothing moves: their rows of the gain are zero and their covariance
with the rest stays zero."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.aiding import AidingSensors
from vdm_aero.atmosphere import G0_M_S2
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.engine import EkfEngine
from vdm_aero.nav.filter import ABLATIONS, MODES, NavConfig, NavFilter
from vdm_aero.nav.state import IDX, N_ERR
from vdm_aero.vehicle import load_vehicle

N, NA = 12, 8  # a small state whose last four are inert


def _prior(rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=(NA, NA))
    p0 = np.zeros((N, N))
    p0[:NA, :NA] = a @ a.T + NA * np.eye(NA)
    p0[range(NA, N), range(NA, N)] = rng.uniform(0.5, 2.0, N - NA)
    return p0


def _inert_phi(rng: np.random.Generator) -> np.ndarray:
    phi = np.eye(N)
    phi[:NA, :NA] += 0.05 * rng.normal(size=(NA, NA))
    return phi


def _observing(rng: np.random.Generator, m: int) -> np.ndarray:
    h = np.zeros((m, N))
    h[:, :NA] = rng.normal(size=(m, NA))
    return h


def test_an_engine_with_an_inert_tail_does_what_the_full_engine_does() -> None:
    # predictions (dense and by coupled rows), Kalman and consider updates, a rejected one, a reset of an active
    # block and of a tail state, a clone and a measurement relative to it: the same covariance, corrections, NIS
    rng = np.random.default_rng(2026_12_02)
    p0 = _prior(rng)
    full, tail = EkfEngine(p0.copy()), EkfEngine(p0.copy(), NA)
    assert (full.n_active, tail.n_active) == (N, NA)
    consider = np.zeros(N, dtype=bool)
    consider[[2, 9]] = True
    q = np.diag(np.r_[rng.uniform(0.01, 0.1, NA), np.zeros(N - NA)])
    rows = np.arange(NA)  # the active block's rows are all coupled; the tail's are the identity's
    for k in range(6):
        phi = _inert_phi(rng)
        for eng in (full, tail):
            eng.predict(phi, q, rows if k % 2 else None)
        h, r = _observing(rng, 2), np.diag(rng.uniform(0.1, 1.0, 2))
        y = rng.normal(size=2) * (50.0 if k == 3 else 1.0)  # k = 3: a jump the gate rejects
        cons = consider if k >= 4 else None
        (dx_f, res_f), (dx_t, res_t) = (eng.update(y, h, r, 13.8, cons) for eng in (full, tail))
        assert res_f.accepted == res_t.accepted == (k != 3)
        assert res_t.nis == pytest.approx(res_f.nis, rel=1e-12)
        assert dx_t.shape == (N,) and not dx_t[NA:].any()
        np.testing.assert_allclose(dx_t, dx_f, rtol=1e-10, atol=1e-13)
        assert tail.nis(y, h, r) == pytest.approx(full.nis(y, h, r), rel=1e-12)
    sel = np.eye(2, N)
    for eng in (full, tail):
        eng.reset_states(slice(0, 2), np.eye(2) * 3.0)
        eng.reset_states(slice(NA + 1, NA + 2), np.array([[7.0]]))
        eng.clone(1.0, sel)
        eng.predict(_inert_phi(np.random.default_rng(1)), q)
    h, a, r = _observing(rng, 2), -np.eye(2), np.eye(2) * 0.2
    (dx_f, res_f), (dx_t, res_t) = (eng.update_relative(np.array([0.4, -0.3]), h, a, r, 1.0) for eng in (full, tail))
    np.testing.assert_allclose(dx_t, dx_f, rtol=1e-10, atol=1e-13)
    assert res_t.nis == pytest.approx(res_f.nis, rel=1e-12)
    np.testing.assert_allclose(tail.P, full.P, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(tail.variances(), np.diag(tail.P))
    assert tail.P[NA + 1, NA + 1] == 7.0 and not full.P[NA:, :NA].any()  # the reset tail state; still uncorrelated
    np.testing.assert_allclose(tail.projected(h), h @ full.P @ h.T, rtol=1e-10)


def test_an_inert_tail_must_start_uncorrelated_and_a_reset_may_not_straddle_it() -> None:
    p0 = _prior(np.random.default_rng(3))
    p0[0, NA] = p0[NA, 0] = 0.1
    with pytest.raises(ValueError, match="inert tail"):
        EkfEngine(p0, NA)
    with pytest.raises(ValueError, match="n_active"):
        EkfEngine(np.eye(N), N + 1)
    eng = EkfEngine(np.eye(N), NA)
    with pytest.raises(ValueError, match="straddle"):
        eng.reset_states(slice(NA - 1, NA + 1), np.eye(2))


def test_the_tails_covariance_set_through_p_keeps_its_diagonal_alone() -> None:
    # P with a tail is a new array: a change reaches the engine through the setter, and only what it can carry
    eng = EkfEngine(np.eye(N), NA)
    p = eng.P
    p[NA, NA], p[0, NA], p[NA, 0], p[1, 1] = 4.0, 0.5, 0.5, 2.0
    assert eng.P[1, 1] == 1.0  # not yet set
    eng.P = p
    assert eng.P[NA, NA] == 4.0 and eng.P[1, 1] == 2.0 and eng.P[0, NA] == 0.0


@pytest.mark.parametrize(
    ("mode", "active"),
    [
        ("ins", IDX["wg"].start),  # the wind's gradient and both scale blocks are inert
        ("airspeed-dr", IDX["wg"].start),
        ("vdm-deim-nn", IDX["wg"].start),
        ("vdm", N_ERR),
        ("vdm-no-accel-scale", IDX["am"].start),  # the accelerometer's block alone is the tail
        ("vdm-no-gyro-scale", N_ERR),  # the gyro's inert block sits before the accelerometer's live one
        ("vdm-no-gradient", N_ERR),
    ],
)
def test_each_mode_carries_the_states_up_to_its_last_live_block(mode: str, active: int) -> None:
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=0.0, mag_field_ned_ut=np.array([20.1, -4.9, 46.5]))
    f = NavFilter(mode, cfg, spec=MODES.get(mode) or ABLATIONS[mode])
    f.initialise(0.0, np.zeros(3), np.array([18.0, 0.0, 0.0]), np.array([0.0, 0.0, -G0_M_S2]), None)
    assert f.engine is not None and f.engine.n_active == active
    # every state keeps its prior in P, the inert ones too
    assert np.all(np.diag(f.P) > 0.0) and f.P.shape == (N_ERR, N_ERR)


class _FullLayout(NavFilter):
    """The filter carrying every state whatever its mode: the reference for the layout per mode."""

    def _active_states(self) -> int:
        return N_ERR


@pytest.mark.parametrize("mode", ["ins", "airspeed-dr"])
def test_a_mode_on_its_own_layout_flies_as_on_the_full_one(mode: str) -> None:
    # a straight flight with GNSS, baro, compass (and a pitot for airspeed-dr), then a 30-s outage in which the
    # filter's consider updates hold the slow states: the same estimate and covariance on both layouts
    mag_ned = np.array([20.1, -4.9, 46.5])
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=0.0, mag_field_ned_ut=mag_ned)
    filters = [cls(mode, cfg, spec=MODES[mode]) for cls in (NavFilter, _FullLayout)]
    dt, v = 0.02, np.array([18.0, 0.0, 0.0])
    f_b = np.array([0.0, 0.0, -G0_M_S2])
    for f in filters:
        f.initialise(0.0, np.array([0.0, 0.0, -100.0]), v, f_b, mag_ned)
    rngs = [np.random.default_rng(7) for _ in filters]  # the same draws for both
    aids = [AidingSensors(cfg, rng, dt) for rng in rngs]
    for k in range(1, 90 * 50 + 1):
        t = k * dt
        p = np.array([18.0 * t, 0.0, -100.0])
        for f, rng, aid in zip(filters, rngs, aids, strict=True):
            noise = cfg.noise
            f.imu(t, ImuIncrement(rng.normal(0.0, noise.gyro_rad_s * math.sqrt(dt), 3),
                                  f_b * dt + rng.normal(0.0, noise.accel_m_s2 * math.sqrt(dt), 3), dt))  # fmt: skip
            if t < 60.0:
                aid.step(f, k, t, p, v, mag_ned)
            elif k % 5 == 0:  # the outage: baro and compass go on
                f.baro(t, float(101325.0 * (1.0 - 2.25577e-5 * (100.0 + rng.normal(0.0, 1.0))) ** 5.25588))
                f.mag(t, mag_ned + rng.normal(0.0, 1.5, 3))
            if mode == "airspeed-dr" and k % 5 == 0:
                f.pitot(t, 0.5 * 1.225 * 18.0**2 + rng.normal(0.0, 5.0))  # q̄ [Pa] at sea level
    own, ref = filters
    assert own.engine is not None and ref.engine is not None
    assert (own.engine.n_active, ref.engine.n_active) == (IDX["wg"].start, N_ERR)
    assert own.in_outage and own.counts == ref.counts and own.rejected == ref.rejected
    assert own.x is not None and ref.x is not None
    np.testing.assert_allclose(own.x.p_ned, ref.x.p_ned, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(own.x.v_ned, ref.x.v_ned, rtol=0.0, atol=1e-8)
    np.testing.assert_allclose(own.P, ref.P, rtol=1e-7, atol=1e-14)
    assert np.abs(own.x.p_ned - np.array([18.0 * 90.0, 0.0, -100.0]))[:2].max() > 0.1  # the outage drifted
