"""The compass's consistency test in an outage (``vdm``'s, issue 22; ``vdm-no-compass-check`` is the ablation
without it, ``vdm-no-throttle-range`` without its throttle part, ``vdm-no-aided-fit`` without the aided fit): the
exponentially weighted means of its normalised innovations and of the throttle against the windows' analytic
figures, the throttles the swing reports it learnt on, the aided innovations' rms per axis, and the filter fusing
the heading alone once it latches."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from tests.test_compass_heading import MAG_NED_UT, _in_outage
from vdm_aero.atmosphere import G0_M_S2
from vdm_aero.nav.compass_consistency import TAU_S, THRESHOLD, THROTTLE_MARGIN, THROTTLE_TAU_S, CompassConsistency
from vdm_aero.nav.contracts import ImuIncrement, Measurement
from vdm_aero.nav.engine import UpdateResult
from vdm_aero.nav.state import IDX
from vdm_aero.rotation import dcm_from_quat, euler_from_quat

RATE_HZ = 10.0


FIELD_B_UT = np.array([20.1, -4.9, 46.5])  # level, heading north
U = FIELD_B_UT / np.linalg.norm(FIELD_B_UT)
S = np.eye(3) * 2.25  # µT²: σ 1.5 µT on each axis


def _across(v: np.ndarray) -> np.ndarray:
    """``v`` less its component along the field: what an attitude error can make."""
    return v - (v @ U) * U


def test_a_consistent_compass_never_latches_and_its_mean_spreads_as_the_window_says() -> None:
    # white unit-variance innovations at 10 Hz: the EWMA with weight a = Δt/τ has the stationary σ √(a / (2 − a))
    rng = np.random.default_rng(11)
    check = CompassConsistency()
    means = []
    for k in range(round(1200 * RATE_HZ)):
        assert not check.observe(k / RATE_HZ, rng.standard_normal(3) * 1.5, S, FIELD_B_UT)
        means.append(check.mean)
    a = 1.0 / (RATE_HZ * TAU_S)
    spread = float(np.std(means[round(10 * TAU_S * RATE_HZ) :]))
    assert spread == pytest.approx(math.sqrt(a / (2.0 - a)), rel=0.15)
    assert not check.biased


def test_a_tilt_never_latches_a_field_change_does_when_the_window_says() -> None:
    # an innovation across the field, of any size, is what an attitude error makes: never the compass's fault
    check = CompassConsistency()
    tilt = _across(np.array([6.0, -4.0, 3.0]))
    assert np.linalg.norm(tilt) > 5.0
    assert not any(check.observe(k / RATE_HZ, tilt, S, FIELD_B_UT) for k in range(600))
    # a field 4.5 µT stronger (z = 3 along it, with a tilt-like part besides): the mean after n samples is
    # z·(1 − (1 − a)ⁿ), past the threshold at n = ⌈ln(1 − thr/z) / ln(1 − a)⌉
    check.reset()
    a = 1.0 / (RATE_HZ * TAU_S)
    n = math.ceil(math.log(1.0 - THRESHOLD / 3.0) / math.log(1.0 - a))
    nu = 4.5 * U + tilt
    latched = [k for k in range(600) if check.observe(k / RATE_HZ, nu, S, FIELD_B_UT)]
    assert latched == [n - 1] and check.biased_at_s == pytest.approx((n - 1) / RATE_HZ)
    check.observe(60.0, np.zeros(3), S, FIELD_B_UT)
    assert check.biased  # latched: the heading fusion that follows no longer tests the field
    check.reset()
    assert not check.biased and check.mean == 0.0
    # a weaker field latches too: the test is two-sided
    assert any(check.observe(k / RATE_HZ, -4.5 * U, S, FIELD_B_UT) for k in range(600))


def _fly_outage(mode: str, deviation_b_ut: np.ndarray, seconds: float) -> tuple[float, dict[str, int], list[str]]:
    """An aligned filter (attitude σ 2 mrad, hard iron σ 0.5 µT, as after an aided flight) in an outage, flying
    level north with a compass carrying ``deviation_b_ut``: its pitch [rad] after ``seconds``, its counts, and the
    measurement model of each compass sample fused, in order."""
    return _fly_outage_from(_in_outage(mode), deviation_b_ut, seconds)


def _fly_outage_from(f: Any, deviation_b_ut: np.ndarray, seconds: float) -> tuple[float, dict[str, int], list[str]]:
    fused: list[str] = []
    fuse = f._fuse

    def spy(meas: Measurement, *args: Any, **kwargs: Any) -> UpdateResult:
        if meas.model.name == "mag":
            fused.append(type(meas.model).__name__)
        return fuse(meas, *args, **kwargs)

    f._fuse = spy  # type: ignore[method-assign]
    assert f.x is not None and f.engine is not None
    p = f.engine.P
    for key, sigma in (("theta", 0.002), ("bm", 0.5)):
        idx = IDX[key]
        p[idx, :] = 0.0
        p[:, idx] = 0.0
        p[idx, idx] = np.eye(3) * sigma**2
    f_b = np.array([0.0, 0.0, -G0_M_S2])
    inc = ImuIncrement(np.zeros(3), f_b * 0.02, 0.02)
    t0 = f.t_s
    for k in range(1, round(seconds / 0.02) + 1):
        t = t0 + k * 0.02
        f.imu(t, inc)
        if k % 5 == 0:
            f.mag(t, dcm_from_quat(np.array([1.0, 0.0, 0.0, 0.0])).T @ MAG_NED_UT + deviation_b_ut)
    return float(euler_from_quat(f.x.q_nb)[1]), dict(f.counts), fused


def test_in_an_outage_a_field_that_changed_is_caught_and_then_gives_the_heading_only() -> None:
    # a field 5 µT stronger along itself (a motor's field at a throttle the swing did not learn): the three axes
    # tilt the attitude to explain what they can of it; the check sees it within seconds, and from then on every
    # compass sample is fused as a heading (the heading's own effect on the tilt is test_compass_heading.py's)
    stronger = 5.0 * MAG_NED_UT / np.linalg.norm(MAG_NED_UT)
    _, counts, fused = _fly_outage("vdm-no-compass-check", stronger, 20.0)
    assert "compass_biased" not in counts and set(fused) == {"MagField"}
    _, counts, fused = _fly_outage("vdm", stronger, 20.0)
    assert counts.get("compass_biased") == 1
    first = fused.index("MagHeading")
    assert (
        3 <= first <= 5 * TAU_S * RATE_HZ
        and set(fused[:first]) == {"MagField"}
        and set(fused[first:]) == {"MagHeading"}
    )


@pytest.mark.parametrize("deviation_b_ut", [np.zeros(3), 5.0 * _across(np.array([0.0, 1.0, 0.0]))])
def test_in_an_outage_a_compass_whose_field_kept_its_strength_keeps_its_three_axes(deviation_b_ut: np.ndarray) -> None:
    # no deviation, and ~5 µT across the field (mostly east, level and heading north), which reads as an attitude
    # error the three axes turn the attitude by: neither is a field that changed
    pitch, counts, fused = _fly_outage("vdm", deviation_b_ut, 20.0)
    assert "compass_biased" not in counts and len(fused) >= 150 and set(fused) == {"MagField"}
    if not deviation_b_ut.any():
        assert abs(pitch) < 0.002


def test_the_swing_reports_the_throttles_it_learnt_on_without_a_turns_brief_cut() -> None:
    # throttles uniform on [0.6, 0.9] with 0.5 % of the samples at 0 (a turn's cut): the 1st and 99th percentiles
    # of the uniform part are 0.603 and 0.897, which the histogram's 2 % bins give as 0.60 and 0.90
    from vdm_aero.nav.mag_deviation import LEARN_AFTER_N, MagDeviation

    dev = MagDeviation(MAG_NED_UT)
    rng = np.random.default_rng(5)
    h_b = MAG_NED_UT
    for k in range(4000):
        if k == LEARN_AFTER_N - 1:
            assert dev.throttle_range() is None  # nothing is applied, nor tested, before it is ready
        thr = 0.0 if k % 200 == 0 else float(rng.uniform(0.6, 0.9))
        dev.observe(h_b, h_b, thr)
    lo, hi = dev.throttle_range()  # type: ignore[misc]
    assert lo == pytest.approx(0.60) and hi == pytest.approx(0.90)


def test_a_throttle_held_outside_the_learnt_range_latches_when_the_window_says_a_cut_does_not() -> None:
    learnt = (0.6, 0.9)
    check = CompassConsistency()
    # the throttle's mean starts mid-range (0.75) and decays towards a closed throttle by b = 0.1 s / τ a sample:
    # 0.75·(1 − b)ᵏ after k samples, below 0.6 − margin at k = ⌈ln((0.6 − margin) / 0.75) / ln(1 − b)⌉
    b = 1.0 / (RATE_HZ * THROTTLE_TAU_S)
    k = math.ceil(math.log((learnt[0] - THROTTLE_MARGIN) / 0.75) / math.log(1.0 - b))
    quiet = np.zeros(3)
    latched = [j for j in range(600) if check.observe(j / RATE_HZ, quiet, S, FIELD_B_UT, 0.0, learnt)]
    assert latched == [k - 1] and check.reason == "throttle"
    # a cut of 3 s in a turn, then the cruise again: the mean dips to 0.75·(1 − b)³⁰ = 0.55, inside the margin
    check.reset()
    thr = [0.0] * 30 + [0.75] * 570
    assert not any(check.observe(j / RATE_HZ, quiet, S, FIELD_B_UT, thr[j], learnt) for j in range(600))
    assert check.reason is None and 0.75 * (1.0 - b) ** 30 > learnt[0] - THROTTLE_MARGIN
    # full throttle above a range that never reached it latches too; no range (the swing not ready): never
    check.reset()
    assert any(check.observe(j / RATE_HZ, quiet, S, FIELD_B_UT, 1.0, (0.2, 0.5)) for j in range(600))
    check.reset()
    assert not any(check.observe(j / RATE_HZ, quiet, S, FIELD_B_UT, 0.0, None) for j in range(600))


@pytest.mark.parametrize(("mode", "throttle", "switched"),
                         [("vdm", 0.0, True), ("vdm", 0.8, False), ("vdm-no-throttle-range", 0.0, False)])  # fmt: skip
def test_in_an_outage_a_glide_below_the_learnt_throttles_gives_the_heading_only(
    mode: str, throttle: float, switched: bool
) -> None:
    # the swing learnt on throttles 0.7–0.9 (a compass that agreed with the attitude: nothing to correct); the
    # outage then flies with the throttle closed, or at the cruise's, with a compass whose field never changed, so
    # the along-field test alone would never latch
    from vdm_aero.nav.mag_deviation import LEARN_AFTER_N

    f = _in_outage(mode)
    assert f.mag_deviation is not None and f.x is not None
    h_b = dcm_from_quat(f.x.q_nb).T @ MAG_NED_UT
    rng = np.random.default_rng(3)
    for _ in range(2 * LEARN_AFTER_N):
        f.mag_deviation.observe(h_b, h_b, float(rng.uniform(0.7, 0.9)))
    f.servo(f.t_s, np.zeros(3), throttle)
    _, counts, fused = _fly_outage_from(f, np.zeros(3), 30.0)
    assert "compass_biased" not in counts  # the field's strength never changed
    if switched:
        first = fused.index("MagHeading")
        assert counts.get("compass_throttle_outside") == 1 and set(fused[first:]) == {"MagHeading"}
        # the mean from 0.8 (mid-range) to below 0.7 − margin, sample by sample as the unit test above counts
        b = 1.0 / (RATE_HZ * THROTTLE_TAU_S)
        assert first == math.ceil(math.log((0.7 - THROTTLE_MARGIN) / 0.8) / math.log(1.0 - b)) - 1
    else:
        assert "compass_throttle_outside" not in counts and set(fused) == {"MagField"}


def test_the_aided_fit_splits_the_innovations_across_and_along_the_field_and_judges_after_its_minimum() -> None:
    from vdm_aero.nav.compass_consistency import AIDED_ACROSS_RMS_MAX_UT, AIDED_MIN_N, AidedCompassFit

    w = _across(np.array([0.0, 1.0, 0.0]))
    w /= np.linalg.norm(w)
    # ±(c·w + a·u), alternating: the rms across the field is exactly c, along it exactly a
    for c, a, refuted in ((0.95 * AIDED_ACROSS_RMS_MAX_UT, 3.0, False), (1.05 * AIDED_ACROSS_RMS_MAX_UT, 0.2, True)):
        fit = AidedCompassFit()
        assert fit.rms_ut() is None and not fit.refuted
        for k in range(AIDED_MIN_N):
            assert not fit.refuted  # too few samples to judge
            fit.observe((-1.0) ** k * (c * w + a * U), FIELD_B_UT)
        assert fit.rms_ut() == pytest.approx((c, a)) and fit.refuted is refuted


def _aided_then_outage(
    mode: str, deviation_b_ut: np.ndarray
) -> tuple[dict[str, int], list[tuple[str, float]], dict[str, Any]]:
    """A filter flying level north at 19 m/s, its swing ready (learnt on a compass that agreed with the attitude),
    aided by GNSS at 5 Hz for 30 s with a compass off by ±``deviation_b_ut`` µT, alternately (zero mean: the hard iron
    cannot take it), then 10 s of outage with a clean compass: its counts, the model and σ [µT]
    of each compass sample fused in the outage, and its health at the outage's start."""
    from vdm_aero.nav.filter import GNSS_TIMEOUT_S, NavConfig, NavFilter
    from vdm_aero.nav.mag_deviation import LEARN_AFTER_N
    from vdm_aero.vehicle import load_vehicle

    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=MAG_NED_UT)
    f = NavFilter(mode, cfg)
    f_b = np.array([0.0, 0.0, -G0_M_S2])
    v = np.array([19.0, 0.0, 0.0])
    f.initialise(0.0, np.zeros(3), v, f_b, MAG_NED_UT)
    assert f.mag_deviation is not None
    for _ in range(2 * LEARN_AFTER_N):
        f.mag_deviation.observe(MAG_NED_UT, MAG_NED_UT, 0.7)
    f.servo(0.0, np.zeros(3), 0.7)
    inc = ImuIncrement(np.zeros(3), f_b * 0.02, 0.02)
    for k in range(1, 1501):  # 30 s aided
        t = k * 0.02
        f.imu(t, inc)
        if k % 10 == 0:
            f.gnss(t, t, v * t, v)
        if k % 5 == 0:
            sign = (-1.0) ** (k // 5)
            f.mag(t, MAG_NED_UT + sign * deviation_b_ut)
    for k in range(1, round((GNSS_TIMEOUT_S + 0.5) / 0.02) + 1):
        f.imu(30.0 + k * 0.02, inc)
    assert f.in_outage
    health = f.health()
    fused: list[tuple[str, float]] = []
    fuse = f._fuse

    def spy(meas: Measurement, *args: Any, **kwargs: Any) -> UpdateResult:
        if meas.model.name == "mag":
            fused.append((type(meas.model).__name__, float(getattr(meas.model, "sigma_ut", math.nan))))
        return fuse(meas, *args, **kwargs)

    f._fuse = spy  # type: ignore[method-assign]
    for k in range(1, 501):  # 10 s of outage, a clean compass
        t = f.t_s + 0.02
        f.imu(t, inc)
        if k % 5 == 0:
            f.mag(t, dcm_from_quat(np.array([1.0, 0.0, 0.0, 0.0])).T @ MAG_NED_UT)
    return dict(f.counts), fused, health


X_2UT = np.array([2.0, 0.0, 0.0])  # level and heading north: 1.84 µT across the field, 0.79 µT along it


@pytest.mark.parametrize(("mode", "deviation_b_ut", "loosened"),
                         [("vdm", X_2UT, True), ("vdm", X_2UT / 4.0, False), ("vdm", 3.0 * U, False),
                          ("vdm-no-aided-fit", X_2UT, False)])  # fmt: skip
def test_a_compass_whose_aided_innovations_across_the_field_passed_the_bar_is_fused_at_ekf3s_sigma_in_the_outage(
    mode: str, deviation_b_ut: np.ndarray, loosened: bool
) -> None:
    from vdm_aero.nav.filter import EKF3_MAG_SIGMA_UT, NavConfig

    counts, fused, health = _aided_then_outage(mode, deviation_b_ut)
    # the compass's three axes throughout (the field's strength and the throttle never latch the heading alone),
    # at EKF3's σ where the aided fit was refuted, at the configured σ elsewhere: 3 µT along the field (a compass
    # whose strength is off, which no attitude error makes) is not a refutation
    sigma = EKF3_MAG_SIGMA_UT if loosened else NavConfig.mag_sigma_ut
    assert len(fused) >= 90 and set(fused) == {("MagField", sigma)}
    assert counts.get("compass_aided_misfit") == (1 if loosened else None)
    fit = health["compass_aided_fit"]
    if mode == "vdm":
        # every aided sample counted: the innovation is the deviation, less what the filter took of it
        across = float(np.linalg.norm(_across(deviation_b_ut)))
        along = float(abs(deviation_b_ut @ U))
        assert fit["ekf3_sigma_in_outage"] is loosened
        assert 0.7 * across - 0.05 < fit["across_rms_ut"] < 1.05 * across + 0.05
        assert 0.7 * along - 0.05 < fit["along_rms_ut"] < 1.05 * along + 0.05
    else:
        assert fit is None
