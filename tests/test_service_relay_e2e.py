"""End to end through a link as real links are (issue 23): the flight of ``survey_service_run`` (survey seed 0,
60 s outage, vdm-deim) flown again with a relay between the mock and the service that sends every datagram by
two routes, sends some again 0.7–1.2 s late, and puts a stranger on the service's port (sim/sitl/udp_relay.py).
Against the clean run: the outage-end error within 1.2×, the fixes ArduPilot's rules would use (the mock's
judge) in ≥ 90 % of the outage, and nothing sent to the stranger."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from sim.sitl.udp_relay import Impairments, UdpRelay
from vdm_aero_cli.service_sitl import run_service_sitl, score_service

pytestmark = pytest.mark.slow


def test_duplicates_stale_frames_and_a_stranger_change_nothing_that_matters(
    survey_service_run: dict[str, Any], tmp_path: Path
) -> None:
    run, clean_res = survey_service_run["run"], survey_service_run["res"]
    imp = Impairments(seed=1)
    res = run_service_sitl(run, tmp_path / "relay", mag_field_ned_ut=survey_service_run["mag_field_ned_ut"],
                           relay=lambda listen, service: UdpRelay(listen, service, imp))  # fmt: skip
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    relay, svc = res["relay"], res["service"]
    # the relay did what it says: every datagram twice, some again late, the stranger talking all flight
    assert relay.duplicated == relay.forwarded > 10_000 and relay.stale_sent > 20 and relay.stranger_sent > 100
    assert relay.stranger_received_bytes == 0  # nothing the service sent went to the stranger
    assert svc["handler_errors"] == {}
    assert svc["duplicate_frames"] >= 0.95 * relay.duplicated  # a copy never reaches the handlers ...
    assert svc["port_frames"]["partial"] <= 5, svc["port_frames"]  # ... so none splits a port frame
    assert svc["stale_imu_frames"] >= 1 and svc["autopilot_reboots"] == 0  # a late frame is not a reboot
    assert svc["port_frames"]["late"] >= 1  # a port value sent again late is dropped, not a frame of its own
    assert "autopilot 1/2" not in res["serve_log"]  # the second "autopilot" component never took over
    clean, impaired = score_service(clean_res), score_service(res)
    assert math.isfinite(impaired["final_error_m"])
    assert impaired["final_error_m"] <= 1.2 * clean["final_error_m"], (impaired, clean)
    verdicts = res["mock"]["gps_input_verdicts"]
    a, b = res["outage"]
    assert verdicts.get("used", 0) >= 0.9 * 5.0 * (b - a), verdicts  # GPS_INPUT at 5 Hz, used by EKF3's rules
