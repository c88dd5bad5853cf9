"""The filter benchmark's paired rounds (bench/run_all.py): the speed-up a round reports and the interval
the rounds give, against the order statistics' own coverage from scipy's binomial distribution."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from bench.run_all import paired_round_ratios


def test_each_round_is_paired_and_the_spread_is_the_median_interval() -> None:
    before = [110.0, 90.0, 240.0, 100.0, 130.0, 115.0]
    after = [100.0, 100.0, 200.0, 100.0, 100.0, 100.0]  # ratios 1.1, 0.9, 1.2, 1.0, 1.3, 1.15
    res = paired_round_ratios(before, after)
    assert res["speedup"] == pytest.approx(1.125)
    assert res["speedup_interval"] == pytest.approx([0.9, 1.3])
    assert res["rounds"] == 6 and res["rounds_faster"] == 4
    # [lowest, highest] of n paired ratios misses their median only if all n fall on one side of it
    assert res["interval_confidence"] == pytest.approx(1.0 - 2.0 * binom.pmf(6, 6, 0.5), abs=1e-4)


def test_a_machine_that_slows_between_rounds_does_not_move_the_paired_ratio() -> None:
    # the code before is 1.4x slower; the machine's speed changes 2.5x from round to round
    speed = np.random.default_rng(7).uniform(1.0, 2.5, 6)
    res = paired_round_ratios(list(140.0 * speed), list(100.0 * speed))
    assert res["speedup"] == pytest.approx(1.4) and res["speedup_interval"] == pytest.approx([1.4, 1.4])


def test_unpaired_rounds_are_refused() -> None:
    with pytest.raises(ValueError, match="one before and one after per round"):
        paired_round_ratios([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="one before and one after per round"):
        paired_round_ratios([], [])
