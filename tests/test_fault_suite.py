"""The service's fault suite: `vdm-aero serve` (no capabilities) and the mock autopilot as processes, one
survey flight with every fault in its own window (vdm_aero_cli/fault_suite.py), scored against the world's
truth. docs/reliability.md gives the figures; `make bench` runs the long ones (60 s silence, GNSS drift,
10x load, soak)."""

from __future__ import annotations

import math
import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vdm_aero_cli.fault_suite import SETTLE_S, WorldClock, fly_faults, nav_log_health, score_windows, suite_flight
from vdm_aero_cli.service_sitl import ServiceRun, ServiceTrack, site_mag_field_ut

SIGNING_KEY_HEX = "5a" * 32
ROW_PERIOD_S = 0.2  # the navigation log's rows at its default 5 Hz (firmware_bridge/config.py, nav_log.hz)


@pytest.fixture(scope="module")
def fault_flight(design_deim12: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    from vdm_aero.nav.models import NavModels
    from vdm_aero_cli.nav_bench import bench_scenario

    # the full-disk fault mounts a 2 MB tmpfs under the state directory, which needs root: CI runs as root on
    # this machine, so under CI the flight always runs (and a missing privilege fails it); a developer's
    # unprivileged run skips it with this reason instead of failing on something that is not the service's
    if os.geteuid() != 0 and not os.environ.get("CI"):
        pytest.skip("the full-disk fault mounts a small tmpfs: run as root (CI does)")
    # real time ×4, as the survey-service flight: at ×6 the service fell behind the link beside the other test
    # worker on this 2-core machine when it ran at half its usual speed (2026-11-27: the 10 s link silence went
    # unreported in three CI runs of this code and under a CPU load of the code before it too; at ×4 it passes)
    run = ServiceRun(design_deim12["data"], design_deim12["model"], None, mode="vdm-deim", scenario="survey", seed=0,
                     outage_s=60.0, speed=4.0, signing_key_hex=SIGNING_KEY_HEX)  # fmt: skip
    ports = NavModels.load(run.design_data, run.deim, None).port_names
    t_out = bench_scenario("survey", 0, run.deim, 300.0)[2]
    flight, windows = suite_flight(run, ports, t_out)
    res = fly_faults(flight, tmp_path_factory.mktemp("faults"), mag_field_ned_ut=site_mag_field_ut(run))
    return {"res": res, "windows": windows, "scores": score_windows(res["work"], windows), "ports": ports}


def test_the_service_survives_every_fault_and_stops_cleanly(fault_flight: dict[str, Any]) -> None:
    res = fault_flight["res"]
    assert res["service_rc"] == 0, res["serve_log"][-3000:]  # SIGTERM at the end: a clean exit
    assert res["supervisor"]["restarts"] == 1 and res["supervisor"]["kill_exit_codes"] == [-9]
    svc = res["service"]
    assert svc["handler_errors"] == {} and svc["bad_frames"] == 0, svc
    assert res["state_saved_at_end"] and res["nav_rows"]["broken"] == 0 and res["nav_rows"]["whole"] > 600
    applied = res["faults_applied"]  # every scripted fault reached the link
    assert set(applied) == {"port_stuck", "port_nan", "port_missing", "port_out_of_range", "link_silence",
                            "gnss_jump"} and min(applied.values()) > 0  # fmt: skip
    # unprivileged: no capability at all, and none to gain
    assert res["capabilities"]["CapEff"] == res["capabilities"]["CapPrm"] == res["capabilities"]["CapBnd"] == 0
    assert res["capabilities"]["NoNewPrivs"] == 1


def test_sockets_are_the_configured_endpoint_only(fault_flight: dict[str, Any]) -> None:
    socks = fault_flight["res"]["sockets"]
    inet = [s for s in socks if s["proto"] != "unix"]
    assert len(inet) == 1 and inet[0]["proto"] == "udp" and inet[0]["local"].startswith("127.0.0.1:"), socks
    assert not any(s["state"] == "LISTEN" for s in socks)


def test_port_faults_flag_health_and_keep_the_error_small(fault_flight: dict[str, Any]) -> None:
    work, w, sc = fault_flight["res"]["work"], fault_flight["windows"], fault_flight["scores"]
    t, ok, health = nav_log_health(work)
    n = len(fault_flight["ports"])
    for name, expect_ok in (("port stuck (1 port)", n - 1), ("port NaN (1 port)", n - 1),
                            ("ports missing (3 of 12)", n - 3), ("port out of range (1 port)", n - 1)):  # fmt: skip
        a, b = w[name]
        m = (t > a + 1.0) & (t < b)  # the stuck detector needs 10 equal frames (0.2 s)
        assert m.sum() > 20 and set(ok[m]) == {expect_ok}, (name, set(ok[m]))
        assert set(health[m]) == {1 | 8}, (name, set(health[m]))  # initialised, ports missing, no fallback
        assert sc[name]["max_error_m"] < 6.0, (name, sc[name])  # GNSS-aided: the faults cost nothing visible
    a, b = w["all ports lost (in the outage)"]
    m = (t > a + 1.0) & (t < b)
    assert set(ok[m]) == {0} and set(health[m]) == {1 | 2 | 4 | 8}  # outage, FALLBACK, ports missing
    assert "FALLBACK airspeed-dr" in fault_flight["res"]["serve_log"]
    after = (t > b + 1.0) & (t < b + 10.0)
    assert set(ok[after]) == {n} and not any(health[after] & 4)  # the ports came back: fallback ends


def test_gnss_jump_is_gated_and_reacquisition_stays_within_the_reported_uncertainty(
    fault_flight: dict[str, Any],
) -> None:
    w, sc = fault_flight["windows"], fault_flight["scores"]
    assert sc["GNSS jump 300 m (5 s)"]["max_error_m"] < 6.0, sc["GNSS jump 300 m (5 s)"]  # 300 m rejected
    tr = ServiceTrack.read(fault_flight["res"]["work"])
    b = w["GNSS outage 60 s"][1]
    before = (tr.boot_s > b - 1.0) & (tr.boot_s < b)
    sigma_end = float(tr.sigma_h_m[before][-1])
    err_end = float(tr.error_m[before][-1])
    assert err_end < 3.0 * sigma_end, (err_end, sigma_end)  # the outage's error is inside its own 3σ
    # the position moves at reacquisition by about the error; never by more than 3σ of what it reported
    after = (tr.boot_s > b) & (tr.boot_s < b + SETTLE_S)
    assert float(tr.error_m[after][-1]) < 6.0


def test_link_silence_is_reported_streams_rerequested_and_navigation_resumes(fault_flight: dict[str, Any]) -> None:
    res, sc = fault_flight["res"], fault_flight["scores"]
    gaps = [float(g) for g in re.findall(r"link back after ([0-9.]+) s of autopilot time", res["serve_log"])]
    assert gaps == pytest.approx([1.0, 10.0], abs=0.1), gaps
    # the mock received the stream requests again after each gap (every stream at start, after each gap, and
    # after the restart: at least 4 rounds)
    from firmware_bridge.config import DEFAULT_STREAMS

    assert res["mock"]["received"]["COMMAND_LONG"] >= 4 * len(DEFAULT_STREAMS["ardupilot"])
    for name in ("link silent 1 s", "link silent 10 s"):
        assert sc[name]["max_error_m"] < 6.0, (name, sc[name])


def test_kill_restart_restores_and_a_full_disk_is_survived(fault_flight: dict[str, Any]) -> None:
    res, sc = fault_flight["res"], fault_flight["scores"]
    log = res["serve_log"]
    assert "restored bg, ba, wind, bm, baro, aero from" in log  # the saved state, ≤ 1 s old at the kill
    assert sc["kill -9, restart"]["max_error_m"] < 8.0, sc["kill -9, restart"]
    assert "cannot write the state: No space left on device" in log and "navigation goes on" in log
    assert "STORAGE FAILING" in log  # in the status line while the disk is full
    assert sc["state directory full"]["max_error_m"] < 6.0
    # the disk filled and was freed at its window's world times: the harness follows the mock's own clock (a wall
    # clock × the speed ran ahead of a world that could not keep the speed, and put the full disk into a port
    # fault's window). The navigation log's longest gap around the window is the full disk's: it starts within
    # the window's first 4 s (the log's last page still takes up to 4 KB of rows: 18 rows of ~220 bytes at 5 Hz,
    # 3.7 s) and ends within 2 s of the window's end. A row is stamped with the autopilot's time as the service
    # last heard it, which trails the world clock the harness frees the disk on by the link's and the service's
    # latency (× the speed): a row stamped up to one row period (0.2 s at 5 Hz) before the free can be written
    # after it (a CI run, 2026-12-02: the first row after the gap stamped 89.98 s, the window ending at 90 s)
    t, _, _ = nav_log_health(res["work"])
    a, b = fault_flight["windows"]["state directory full"]
    near = t[(t > a - 3.0) & (t < b + 3.0)]
    j = int(np.argmax(np.diff(near)))
    assert a <= near[j] < a + 4.0 and b - ROW_PERIOD_S <= near[j + 1] < b + 2.0, (near[j], near[j + 1])


def test_the_harness_clock_is_the_worlds_own() -> None:
    """The mock's ``--progress`` lines set the clock the outside faults wait for; every other line is kept."""
    r, w = os.pipe()
    with os.fdopen(r, "rb") as reader, os.fdopen(w, "wb") as writer:
        clock = WorldClock(reader)
        writer.write(b"world time 1 s\nfaults applied: {}\nworld time 2 s\n")
        writer.flush()
        deadline = time.monotonic() + 5.0
        while clock.now_s < 2.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert clock.now_s == 2.0
        writer.write(b'{"steps": 3}\n')
        writer.close()
        clock.join(timeout_s=5.0)
    assert clock.lines == [b"faults applied: {}\n", b'{"steps": 3}\n']


def test_an_unsigned_rogue_sender_injects_nothing(fault_flight: dict[str, Any]) -> None:
    res, sc = fault_flight["res"], fault_flight["scores"]
    sent = res["rogue_sent"]
    assert min(sent[k] for k in ("ports", "gnss", "commands")) > 500
    # the restarted service saw the rogue for ≥ 45 s of its life: everything unsigned was dropped and counted
    assert res["service"]["rejected_unsigned"] >= 0.5 * sum(sent.values())
    assert "reboot" not in res["serve_log"].lower()  # the command did nothing
    # its GNSS (1 km off) and port values never reached the filter: the aided error stayed small, and the
    # autopilot kept receiving the service's solution (the rogue did not take over the reply address)
    assert sc["kill -9, restart"]["max_error_m"] < 8.0
    assert sent.get("replies_received", 0) == 0  # the service never took the rogue for its peer
    a, b = fault_flight["windows"]["GNSS outage 60 s"]
    tr = ServiceTrack.read(res["work"])  # the autopilot kept receiving the solution all through the outage
    t = tr.gps_input_s[(tr.gps_input_s > a) & (tr.gps_input_s < b)]
    assert t[0] < a + 2.0 and t[-1] > b - 1.0 and float(np.diff(t).max()) < 1.0, (t[0], t[-1], np.diff(t).max())
    assert math.isfinite(sc["rogue unsigned sender"]["max_error_m"])


def test_fault_figures_are_finite(fault_flight: dict[str, Any]) -> None:
    """Every window was scored from the navigation log (the figures docs/reliability.md reports)."""
    sc = fault_flight["scores"]
    missing = [k for k, v in sc.items() if not (v["log_rows"] > 0 and np.isfinite(v["max_error_m"]))]
    assert missing == [], missing
