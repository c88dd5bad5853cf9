"""Navigation contracts: analytic Jacobians against finite differences, ⊕/⊖, the INS transition, gating."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from vdm_aero.nav.contracts import ImuIncrement, evaluate_with_jacobian, jacobian_fd
from vdm_aero.nav.engine import EkfEngine
from vdm_aero.nav.ins import InsProcess
from vdm_aero.nav.measurements import (
    AutopilotAttitude,
    BaroAltitude,
    ClassicForce,
    ForceContext,
    GnssPosition,
    GnssVelocity,
    InsWindowFix,
    MagField,
    MagHeading,
    PitotAirspeed,
    PortAirData,
    PortForce,
    SyntheticSideslip,
)
from vdm_aero.nav.state import AERO_PARAMS, N_ERR, NavState
from vdm_aero.rotation import dcm_from_quat, quat_from_euler

JACOBIAN_RTOL = 1e-5  # relative to the Jacobian's largest entry: central differences at step 1e-6


def _state(rng: np.random.Generator) -> NavState:
    q = np.array(quat_from_euler(*rng.uniform([-0.6, -0.3, -math.pi], [0.6, 0.3, math.pi])))
    v_ned = dcm_from_quat(q) @ np.array([18.0, 1.0, 1.5]) + rng.normal(0.0, 4.0, 3) * [1, 1, 0.1]
    x = NavState(rng.normal(0.0, 100.0, 3), v_ned, q)
    x.wind_ned = v_ned - dcm_from_quat(q) @ (np.array([17.0, 1.2, 1.6]) + rng.normal(0, 0.5, 3))
    x.b_gyro_b = rng.normal(0.0, 0.01, 3)
    x.b_accel_b = rng.normal(0.0, 0.1, 3)
    x.b_mag_b_ut = rng.normal(0.0, 3.0, 3)
    x.b_baro_m = float(rng.normal(0.0, 3.0))
    x.b_gnss_ned = rng.normal(0.0, 1.0, 3)
    x.aero = np.array([0.01, -0.01, 1.03, 0.004, -0.003, 0.95, 0.9]) + rng.normal(0.0, 0.01, len(AERO_PARAMS))
    x.gnss_lag_s = float(rng.normal(0.0, 0.05))
    x.wind_gradient_ne_per_s = rng.normal(0.0, 0.01, 2)
    x.gyro_m_err_b = rng.normal(0.0, 0.01, (3, 3))
    x.accel_m_err_b = rng.normal(0.0, 0.01, (3, 3))  # the third column is no state: held, as the filter holds it
    return x


class _Derivs:
    """A smooth stand-in for the fitted derivatives (the test is of the chain rule, not of the fit)."""

    def coeffs_and_gradient(self, speed, alpha, beta, omega_b, controls):  # type: ignore[no-untyped-def]
        c = np.array(
            [-0.03 - 0.5 * alpha**2 + 0.01 * omega_b[1] / speed, -0.3 * beta, -0.3 - 4.8 * alpha + 2 * alpha**3]
        )
        g = np.array(
            [[-0.01 * omega_b[1] / speed**2, -1.0 * alpha, 0.0], [0.0, 0.0, -0.3], [0.0, -4.8 + 6 * alpha**2, 0.0]]
        )
        return c, g


CTX = ForceContext(rho_kg_m3=1.15, area_per_mass_m2_kg=0.39 / 2.5, mass_kg=2.5, thrust_a_n=8.0, thrust_b_n_s_m=-0.2)
CTX_AM = replace(CTX, accel_m_err=True)  # the accelerometer's scale and cross-axis errors in the prediction
MODELS = [
    GnssPosition(0.7, 1.0),
    GnssVelocity(0.2),
    GnssVelocity(0.2, horizontal_only=True),
    GnssVelocity(0.2, accel_ned_m_s2=np.array([3.1, -4.2, 0.7])),  # the latency error's a·lag
    GnssVelocity(0.2, horizontal_only=True, accel_ned_m_s2=np.array([-2.0, 5.5, 0.3])),
    InsWindowFix(3.0, 0.8),
    BaroAltitude(50.0, 1.0),
    MagField(np.array([20.1, -4.9, 46.5]), 1.5),
    MagHeading(0.07),
    PitotAirspeed(0.8),
    SyntheticSideslip(0.1),
    PortAirData(np.eye(3)),
    PortForce(np.array([-0.04, 0.01, -0.45]), CTX, np.ones(3)),
    ClassicForce(_Derivs(), np.array([0.1, -0.2, 0.05]), np.zeros(3), CTX, np.ones(3)),
    PortForce(np.array([-0.04, 0.01, -0.45]), CTX_AM, np.ones(3), name="aero_force_am"),
    ClassicForce(_Derivs(), np.array([0.1, -0.2, 0.05]), np.zeros(3), CTX_AM, np.ones(3), name="aero_force_classic_am"),
    # the autopilot's attitude 0.3 rad from the states': the exact Jacobian, not the small-angle −I
    AutopilotAttitude(quat_from_euler(0.2, -0.15, 1.1), np.array([0.035, 0.035, 0.087])),
]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_measurement_jacobians_match_finite_differences(model) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    for _ in range(5):
        x = _state(rng)
        analytic = model.jacobian(x)
        numeric = jacobian_fd(model, x)
        assert analytic.shape == (len(model.evaluate(x)), N_ERR)
        scale = max(float(np.abs(numeric).max()), 1e-9)
        worst = np.unravel_index(np.argmax(np.abs(analytic - numeric)), analytic.shape)
        assert np.abs(analytic - numeric).max() <= JACOBIAN_RTOL * scale, f"{model.name}: worst entry {worst}"


def test_plus_minus_round_trip() -> None:
    rng = np.random.default_rng(3)
    x = _state(rng)
    dx = rng.normal(0.0, 0.05, N_ERR)
    np.testing.assert_allclose(x.plus(dx).minus(x), dx, atol=1e-12)


def test_ins_transition_matches_finite_differences() -> None:
    # Φ predicts how an error at the start of a step shows at its end: compare with propagating x ⊕ δx
    rng = np.random.default_rng(11)
    ins = InsProcess()
    x = _state(rng)
    u = ImuIncrement(np.array([0.2, -0.1, 0.3]) * 0.02, np.array([1.0, 0.5, -9.5]) * 0.02, 0.02)
    phi = ins.transition(x, u)
    base = ins.propagate(x, u)
    for i in range(N_ERR):
        d = np.zeros(N_ERR)
        d[i] = 1e-6
        col = (ins.propagate(x.plus(d), u).minus(base) - ins.propagate(x.plus(-d), u).minus(base)) / 2e-6
        # first-order-hold Φ: exact to O(Δt³); the INS terms are ~1, the step 0.02 s
        np.testing.assert_allclose(phi[:, i], col, atol=2e-5, err_msg=f"column {i}")


def test_ins_transition_is_the_second_order_series_of_its_error_dynamics() -> None:
    """The block-by-block Φ equals I + FΔt + ½(FΔt)² with F assembled densely from the error dynamics of the
    module docstring (δv̇ = −Ĉ[f×]δθ − Ĉ(I − δMa)δb_a − Ĉ·δMa'·a with a the specific force read less the bias,
    δθ̇ = −[ω×]δθ − (I − δM)δb_g − δM'·u with u the rate less the bias, δM' and δMa' the scale and cross-axis
    errors' errors, Gauss–Markov GNSS error and gust, the horizontal wind following its gradient with height:
    δẇ_NE = −G·δv_D − v_D·δG)."""
    from vdm_aero.atmosphere import G0_M_S2
    from vdm_aero.nav.ins import skew
    from vdm_aero.nav.state import IDX
    from vdm_aero.rotation import dcm_from_quat, quat_exp, quat_multiply

    rng = np.random.default_rng(12)
    ins = InsProcess()
    for dt in (0.02, 0.0025, 0.02):  # Δt changes and comes back: the cached diagonal follows it
        x = _state(rng)
        u = ImuIncrement(rng.normal(0.0, 0.5, 3) * dt, (np.array([0.0, 0.0, -9.8]) + rng.normal(0, 2, 3)) * dt, dt)
        a_b, u_b = u.dvel_b / dt - x.b_accel_b, u.dtheta_b / dt - x.b_gyro_b
        f_b, w_b = a_b - x.accel_m_err_b @ a_b, u_b - x.gyro_m_err_b @ u_b
        c = dcm_from_quat(quat_multiply(x.q_nb, quat_exp(0.5 * w_b * dt)))
        f = np.zeros((N_ERR, N_ERR))
        f[IDX["p"], IDX["v"]] = np.eye(3)
        f[IDX["v"], IDX["theta"]] = -c @ skew(f_b)
        f[IDX["v"], IDX["ba"]] = -c @ (np.eye(3) - x.accel_m_err_b)
        f[IDX["theta"], IDX["theta"]] = -skew(w_b)
        f[IDX["theta"], IDX["bg"]] = -(np.eye(3) - x.gyro_m_err_b)
        for i in range(3):  # ∂(δM·u)_i/∂δM[i, j] = u_j; the states hold δM row by row
            for j in range(3):
                f[IDX["theta"].start + i, IDX["gm"].start + 3 * i + j] = -u_b[j]
                if j < 2:  # δMa's first two columns are states
                    f[IDX["v"], IDX["am"].start + 2 * i + j] = -c[:, i] * a_b[j]  # −Ĉ·(δMa·a), column by column
        f[IDX["gnss"], IDX["gnss"]] = -np.eye(3) / ins.noise_densities.gnss_tau_s
        f[IDX["gust"], IDX["gust"]] = -np.diag(1.0 / np.asarray(ins.noise_densities.gust_tau_s))
        wind_ne = slice(IDX["wind"].start, IDX["wind"].start + 2)
        vd_mid = x.v_ned[2] + 0.5 * dt * ((c @ f_b)[2] + G0_M_S2)  # the nominal v_D at mid-step
        f[wind_ne, IDX["v"].start + 2] = -x.wind_gradient_ne_per_s
        f[wind_ne, IDX["wg"]] = -vd_mid * np.eye(2)
        fdt = f * dt
        np.testing.assert_allclose(ins.transition(x, u), np.eye(N_ERR) + fdt + 0.5 * fdt @ fdt, rtol=0, atol=1e-13)


@pytest.mark.parametrize("frozen", [(), ("wind_gradient",), ("gyro_m_err", "accel_m_err"),
                                    ("wind_gradient", "gyro_m_err", "accel_m_err")])  # fmt: skip
def test_only_the_coupled_rows_of_the_ins_transition_leave_its_diagonal(frozen: tuple[str, ...]) -> None:
    """The engine's prediction scales every row of Φ but :attr:`InsProcess.coupled_rows` as a diagonal one, so
    an entry anywhere else would be lost without a word: Φ's off-diagonal entries must be in those rows, and
    (so the rows are not merely a superset) every one of them must have some."""
    rng = np.random.default_rng(13)
    ins = InsProcess()
    for name in frozen:
        getattr(ins, f"freeze_{name}")()
    for dt in (0.02, 0.0025):
        x = _state(rng)
        u = ImuIncrement(rng.normal(0.0, 0.5, 3) * dt, (np.array([0.0, 0.0, -9.8]) + rng.normal(0, 2, 3)) * dt, dt)
        phi = ins.transition(x, u)
        off = phi - np.diag(np.diag(phi))
        assert set(np.flatnonzero(np.any(off != 0.0, axis=1)).tolist()) == set(ins.coupled_rows.tolist())


def test_gate_rejects_a_300_m_jump_and_accepts_a_normal_fix() -> None:
    p0 = np.diag(np.full(N_ERR, 1.0))
    eng = EkfEngine(p0)
    h = np.zeros((3, N_ERR))
    h[:, :3] = np.eye(3)
    r = np.eye(3) * 0.5
    dx, res = eng.update(np.array([300.0, 0.0, 0.0]), h, r, 21.11)
    assert not res.accepted and res.nis > 1e4 and not dx.any()
    assert np.allclose(eng.P, p0)  # a rejected update leaves the covariance alone
    dx, res = eng.update(np.array([1.0, -0.5, 0.3]), h, r, 21.11)
    assert res.accepted and res.nis < 21.11
    np.testing.assert_allclose(dx[:3], np.array([1.0, -0.5, 0.3]) / 1.5, rtol=1e-12)  # K = P/(P+R)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_evaluate_with_jacobian_is_the_two_calls_bit_for_bit(model) -> None:  # type: ignore[no-untyped-def]
    # the filter fuses through the one call; the finite-difference test above checks the two
    rng = np.random.default_rng(11)
    for _ in range(3):
        x = _state(rng)
        z, h = evaluate_with_jacobian(model, x)
        np.testing.assert_array_equal(z, model.evaluate(x))
        np.testing.assert_array_equal(h, model.jacobian(x))
    air_models = (PortForce, PortAirData, ClassicForce, SyntheticSideslip)
    assert hasattr(model, "evaluate_with_jacobian") == isinstance(model, air_models)


def test_a_nan_innovation_or_a_singular_s_is_rejected_and_leaves_the_filter_as_it_was() -> None:
    # the gate reads filterpy's own S⁻¹ after its update and puts the prior back on a rejection
    rng = np.random.default_rng(3)
    a = rng.normal(size=(N_ERR, N_ERR))
    p0 = a @ a.T + np.eye(N_ERR)
    h = rng.normal(size=(2, N_ERR))
    r = np.eye(2) * 0.1
    eng = EkfEngine(p0.copy())
    dx, res = eng.update(np.array([np.nan, 0.1]), h, r, 1e9)
    assert not res.accepted and math.isnan(res.nis) and not dx.any()
    np.testing.assert_array_equal(eng.P, p0)
    dx, res = eng.update(np.array([0.2, 0.1]), np.zeros((2, N_ERR)), np.zeros((2, 2)), 1e9)  # S = 0
    assert not res.accepted and res.nis == math.inf and not dx.any()
    np.testing.assert_array_equal(eng.P, p0)
    # what it does next is what a fresh engine does: K = PHᵀS⁻¹, NIS = yᵀS⁻¹y with S = HPHᵀ + R
    y = np.array([0.2, 0.1])
    dx, res = eng.update(y, h, r, 1e9)
    s = h @ p0 @ h.T + r
    assert res.accepted and res.nis == pytest.approx(float(y @ np.linalg.solve(s, y)), rel=1e-10)
    np.testing.assert_allclose(dx, p0 @ h.T @ np.linalg.solve(s, y), rtol=1e-9, atol=1e-12)


def test_consider_update_keeps_considered_states_and_their_covariance_consistent() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(size=(N_ERR, N_ERR))
    p0 = a @ a.T + N_ERR * np.eye(N_ERR)
    consider = np.zeros(N_ERR, dtype=bool)
    consider[15:18] = True
    h = rng.normal(size=(2, N_ERR))
    r = np.eye(2)
    y = np.array([0.3, -0.2])
    eng = EkfEngine(p0)
    dx, res = eng.update(y, h, r, 1e9, consider)
    assert res.accepted and not dx[consider].any() and dx[~consider].any()
    # Schmidt: P+ = (I−KH)P(I−KH)ᵀ + KRKᵀ with the considered gain rows zero; the considered block is unchanged
    np.testing.assert_allclose(eng.P[15:18, 15:18], p0[15:18, 15:18], rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(eng.P) > 0.0)
    # and no larger than the prior anywhere on the diagonal
    assert np.all(np.diag(eng.P) <= np.diag(p0) + 1e-12)


def test_turbulence_intensity_recovers_a_gauss_markov_gust() -> None:
    # ĝ a first-order Gauss–Markov gust with known σ (τ 14 s, 50 Hz) and a filter variance P on top:
    # E[ĝ²] + P estimates σ² + P; over 3000 s (≈ 200 correlation times) the sampling error is about ±5 %
    from vdm_aero.nav.filter import TURBULENCE_SIGMA_BOUNDS_M_S, TurbulenceIntensity

    rng = np.random.default_rng(42)
    dt, tau = 0.02, 14.0
    sigma = np.array([1.3, 1.3, 0.8])
    phi = math.exp(-dt / tau)
    g = rng.normal(0.0, sigma)
    est = TurbulenceIntensity()
    p_gust = np.full(3, 0.8**2)  # large enough that leaving it out would show (0.8 → 1.13 m/s vertically)
    for _ in range(round(3000.0 / dt)):
        g = phi * g + math.sqrt(1.0 - phi * phi) * rng.normal(0.0, sigma)
        out = est.observe(g, p_gust, dt)
    np.testing.assert_allclose(out, np.sqrt(sigma**2 + p_gust), rtol=0.1)
    # still air: the estimate stops at the lower bound (the air data's own noise), it never reaches zero
    calm = TurbulenceIntensity()
    for _ in range(1000):
        out = calm.observe(np.zeros(3), np.zeros(3), dt)
    np.testing.assert_array_equal(out, TURBULENCE_SIGMA_BOUNDS_M_S[0])


def test_fads_polynomial_scalar_path_is_the_vector_one() -> None:
    from vdm_aero.nav.design_fit import _angle_terms

    rng = np.random.default_rng(7)
    for a, b in rng.uniform(-0.4, 0.4, size=(20, 2)):
        fast = _angle_terms(float(a), float(b))
        general = _angle_terms(np.array([a]), np.array([b]))
        for f, g in zip(fast, general, strict=True):
            np.testing.assert_allclose(f, g[0], rtol=1e-15, atol=1e-15)


def test_a_fix_carries_the_uncertainty_of_the_receivers_lag_along_the_track() -> None:
    """Fixes stamped with an assumed lag that is off by U(±60 ms) (the spread NavConfig states) land v·δt
    along the track: their scatter there is what the covariance says, and across the track unchanged."""
    from vdm_aero.nav.filter import NavConfig

    sigma_lag = NavConfig.__dataclass_fields__["gnss_latency_sigma_s"].default
    rng = np.random.default_rng(5)
    v_ned = np.array([18.0, -9.0, 1.0])
    white = (0.7, 1.0)
    dt = rng.uniform(-0.06, 0.06, 200_000)
    err = dt[:, None] * v_ned + rng.standard_normal((dt.size, 3)) * np.array([white[0], white[0], white[1]])
    r = GnssPosition(*white, timing_ned_m=sigma_lag * v_ned).covariance()
    along = v_ned / np.linalg.norm(v_ned)
    across = np.cross(along, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    for u in (along, across):
        np.testing.assert_allclose(float(np.var(err @ u)), float(u @ r @ u), rtol=0.02)
    assert float(along @ r @ along) > 1.5 * float(across @ r @ across)  # the lag term is not negligible here
