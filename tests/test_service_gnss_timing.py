"""The service's GNSS timing (issue 22): GPS_RAW_INT is stamped when the autopilot received the fix, so the
service fuses it at that stamp less the receiver's latency, as ArduPilot's EKF3 (GPS_DELAY_MS, the u-blox
driver's lag) and PX4's EKF2 (EKF2_GPS_DELAY) do."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from firmware_bridge.config import ConfigError
from firmware_bridge.units import GNSS_LATENCY_DEFAULT_S
from tests.test_fault_inputs import WARM_S, WARM_T0_S, _Autopilot, _close, _service_config, _warm_service

CASES = [
    ({}, 0.12),
    ({"navigation.gnss_latency_s": 0.2}, 0.2),
    ({"autopilot": "px4", "outputs.solution": "odometry", "outputs.solution_hz": 10}, 0.11),
]


@pytest.mark.parametrize(("edits", "latency_s"), CASES)
def test_a_fix_is_fused_at_its_stamp_less_the_receiver_latency(
    design_deim12: dict[str, Path], tmp_path: Path, edits: dict[str, Any], latency_s: float
) -> None:
    from vdm_aero.nav.models import NavModels

    if "navigation.gnss_latency_s" not in edits:
        assert GNSS_LATENCY_DEFAULT_S[edits.get("autopilot", "ardupilot")] == latency_s
    cfg = _service_config(tmp_path, design_deim12, "gnss", edits)
    models = NavModels.load(cfg.design_data, cfg.deim_model, None, cfg.vehicle)
    ap = _Autopilot()
    svc = _warm_service(cfg, models, ap)
    try:
        assert svc.filter is not None and svc.filter.initialised
        calls: list[tuple[float, float]] = []
        real = svc.driver.gnss
        svc.driver.gnss = lambda t_valid, t_now, p, v, *acc: (
            calls.append((t_valid, t_now)),
            real(t_valid, t_now, p, v, *acc),
        )
        t = WARM_T0_S + WARM_S + 0.2
        svc._dispatch(ap(ap.tx.gps_raw_int_encode(round(t * 1e6), 3, 422830335 + 4900, -713500307, 155600, 80, 120,
                                                   1800, 0, 14)), t + 0.05)  # fmt: skip
        assert len(calls) == 1
        t_valid, t_now = calls[0]
        stamp = svc.clock.filter_s(t)
        assert t_valid == pytest.approx(stamp - latency_s, abs=1e-9)
        assert t_now >= stamp
    finally:
        _close(svc)


def test_a_latency_out_of_range_is_one_line(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"navigation\.gnss_latency_s: 0\.9 is outside \[0, 0\.5\]"):
        _service_config(tmp_path, design_deim12, "bad", {"navigation.gnss_latency_s": 0.9})
