"""The one IMU integrator and its gap rule (vdm_aero.nav.imu_increments), at a link's 400 Hz and at a
ground-station log's 4 Hz, against exact integrals of constant rates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vdm_aero.nav.imu_increments import IMU_GAP_S, ImuIntegrator, _regular_increments, gap_limit_s, increments

W = (0.1, -0.2, 0.3)  # rad/s
F = (0.5, 0.0, -9.8)  # m/s²


def test_a_ground_station_rate_is_integrated_not_taken_for_gaps() -> None:
    t = np.arange(41) * 0.25  # ArduPilot's default 4 Hz RAW_IMU in a GCS tlog, 10 s
    t_end, dth, dv, dt, closed = increments(t, np.tile(W, (41, 1)), np.tile(F, (41, 1)), 50.0)
    assert len(t_end) == 40 and np.allclose(dt, 0.25)  # each sample is a step: the filter runs at the IMU's rate
    np.testing.assert_allclose(dth.sum(axis=0), np.array(W) * 10.0, rtol=1e-12)
    np.testing.assert_allclose(dv.sum(axis=0), np.array(F) * 10.0, rtol=1e-12)
    assert list(closed) == list(range(1, 41)) and t_end[-1] == pytest.approx(10.0)


def test_a_pause_in_a_fast_stream_is_a_gap_and_nothing_is_integrated_across_it() -> None:
    integ = ImuIntegrator(50.0)
    steps = [s for k in range(81) if (s := integ.add(k / 400.0, W, F)) is not None]  # 0.2 s at 400 Hz
    assert len(steps) == 10 and integ.typical_dt_s == pytest.approx(0.0025)
    assert gap_limit_s(integ.typical_dt_s) == IMU_GAP_S
    assert integ.add(0.2 + 0.15, W, F) is None and integ.gaps == 1  # 0.15 s silent: samples were lost
    after = [s for k in range(1, 9) if (s := integ.add(0.35 + k / 400.0, W, F)) is not None]
    ((t_end, inc),) = after  # the first step after the gap starts at the gap's end
    assert t_end == pytest.approx(0.37) and inc.dt_s == pytest.approx(0.02)
    np.testing.assert_allclose(inc.dtheta_b, np.array(W) * 0.02, rtol=1e-9)


def test_an_impossible_sample_costs_one_sample_not_the_step() -> None:
    integ = ImuIntegrator(50.0)
    out = []
    for k in range(9):
        w = (math.nan, 0.0, 0.0) if k == 4 else W
        if (s := integ.add(k / 400.0, w, F)) is not None:
            out.append(s)
    assert integ.rejected == 1 and integ.gaps == 0
    ((t_end, inc),) = out  # samples 3 and 5 bridge the refused one: the step still covers 0.02 s
    assert t_end == pytest.approx(0.02) and inc.dt_s == pytest.approx(0.02)
    np.testing.assert_allclose(inc.dvel_b, np.array(F) * 0.02, rtol=1e-9)
    assert np.isfinite(inc.dtheta_b).all()


def _sample_by_sample(t: np.ndarray, w: np.ndarray, f: np.ndarray) -> list[np.ndarray]:
    integ = ImuIntegrator(50.0)
    steps = [(i, s) for i, (tk, wk, fk) in enumerate(zip(t.tolist(), w.tolist(), f.tolist(), strict=True))
             if (s := integ.add(tk, wk, fk)) is not None]  # fmt: skip
    return [np.array([s[0] for _, s in steps]), np.array([s[1].dtheta_b for _, s in steps]),
            np.array([s[1].dvel_b for _, s in steps]), np.array([s[1].dt_s for _, s in steps]),
            np.array([i for i, _ in steps])]  # fmt: skip


@pytest.mark.parametrize("flaw", [None, "gap", "nan", "spike"])
def test_a_log_is_summed_as_the_live_integrator_sums_it_to_the_last_bit(flaw: str | None) -> None:
    """A log's stream takes the array path when it has no gap and no refused sample, the loop otherwise; either
    way its increments are the live integrator's, bit for bit (a 400 Hz clock with jitter, so steps of 7–9
    samples, and rates that change every sample)."""
    rng = np.random.default_rng(7)
    n = 4000
    t = np.cumsum(rng.uniform(0.0020, 0.0030, n))
    w, f = rng.normal(0.0, 0.5, (n, 3)), rng.normal(0.0, 9.8, (n, 3))
    if flaw == "gap":
        t[2000:] += 0.3
    elif flaw == "nan":
        w[1234, 1] = math.nan
    elif flaw == "spike":
        f[777, 2] = 5000.0
    assert (_regular_increments(t, w, f, 50.0) is None) == (flaw is not None)
    got, want = increments(t, w, f, 50.0), _sample_by_sample(t, w, f)
    assert len(got[0]) > 150 and len(set(np.diff(got[4]).tolist())) >= 2  # steps of more than one length
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
