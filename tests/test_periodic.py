"""The service's periodic outputs on the autopilot's clock (firmware_bridge.periodic)."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_bridge.periodic import ClockSchedule


@pytest.mark.parametrize(("stream_hz", "rate_hz"), [(100.0, 5.0), (50.0, 10.0), (400.0, 10.0), (37.0, 5.0)])
def test_the_mean_rate_is_the_rate_asked_whatever_the_clock_sampling(stream_hz: float, rate_hz: float) -> None:
    # the clock is read when an IMU message arrives: a stream with ±30 % jitter on its interval and lost messages
    rng = np.random.default_rng(3)
    dt = rng.uniform(0.7, 1.3, int(200 * stream_hz)) / stream_hz
    t = np.cumsum(dt)[rng.uniform(size=len(dt)) > 0.05]
    t = t[t < 120.0]
    s = ClockSchedule()
    fired = np.array([ti for ti in t if s.due("solution", float(ti), 1.0 / rate_hz)])
    span = fired[-1] - fired[0]
    # 120 s at rate_hz: exact to one sample, where "next = now + period" lost up to one stream interval a period
    assert abs(len(fired) - 120.0 * rate_hz) <= 1
    assert (len(fired) - 1) / span == pytest.approx(rate_hz, rel=0.005)
    # an output late by a stream gap is followed by one on time: never closer than a period less the longest gap
    assert np.diff(fired).min() >= 1.0 / rate_hz - np.diff(t).max() - 1e-9


def test_a_stall_re_anchors_without_a_burst_and_a_reboot_starts_afresh() -> None:
    s = ClockSchedule()
    t = np.arange(0.0, 10.0, 0.01)
    assert sum(s.due("k", float(ti), 0.2) for ti in t) == 50
    # 3 s without data: one output when the clock comes back, then the rate again
    after = np.arange(13.0, 14.0, 0.01)
    fired = [ti for ti in after if s.due("k", float(ti), 0.2)]
    assert fired[0] == pytest.approx(13.0) and len(fired) == 5 and np.diff(fired).min() > 0.19
    # the autopilot rebooted: its clock starts near zero, and the output is due at once
    assert s.due("k", 0.5, 0.2)
    assert not s.due("k", 0.55, 0.2) and s.due("k", 0.7, 0.2)
    # a clock not started yet (−inf before the first IMU sample) is never due
    assert not ClockSchedule().due("k", float("-inf"), 0.2)
