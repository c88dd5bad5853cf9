"""End to end: ``vdm-aero serve`` and the mock autopilot as separate processes over UDP loopback, directly
and through MAVProxy. The world's truth is read only to score. The service's error at the end of the GNSS
outage must match the in-process benchmark's on the same flight (same scenario, seed, mode and models):
|service − benchmark| ≤ 20 % of the benchmark + 3 m. The two differ by what MAVLink changes: float32
fields, GPS_RAW_INT's missing vertical velocity (the service fuses N/E only), held sensor samples, and
the stream timing of a real link."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vdm_aero_cli.service_sitl import (
    MAVPROXY,
    ServiceRun,
    run_service_sitl,
    score_service,
    site_mag_field_ut,
)

pytestmark = pytest.mark.slow
TOLERANCE_REL, TOLERANCE_M = 0.20, 3.0


def _run(design_deim12: dict[str, Path], **kw: object) -> ServiceRun:
    return ServiceRun(design_deim12["data"], design_deim12["model"], None, mode="vdm-deim", **kw)  # type: ignore[arg-type]


def test_service_against_the_mock_matches_the_benchmark(survey_service_run: dict[str, Any]) -> None:
    res = survey_service_run["res"]
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    svc = res["service"]
    assert svc["torch_loaded"] is False  # the run-time path never imports torch
    assert svc["handler_errors"] == {} and svc["bad_frames"] == 0, svc
    assert svc["port_frames"]["complete"] > 1000 and svc["port_frames"]["partial"] <= 5, svc["port_frames"]
    assert svc["stream_requests"] >= 5  # HIGHRES_IMU etc. are off until requested (as on ArduPlane)
    a, b = res["outage"]
    score = score_service(res)
    # GPS_INPUT at 5 Hz of autopilot time, only during the outage, with a fix the filter's health allows
    assert score["gps_input_count"] >= 0.9 * 5.0 * (b - a), score
    assert a <= score["gps_input_first_s"] < a + 2.0 and score["gps_input_last_s"] < b + 1.0
    assert set(score["gps_input_fix_types"]) <= {2, 3}
    # the mock judges each GPS_INPUT by ArduPilot's rules (sim/sitl/ekf_judge.py): EKF3 would use ≥ 90 % of them
    verdicts = res["mock"]["gps_input_outage_verdicts"]
    assert verdicts.get("used", 0) >= 0.9 * sum(verdicts.values()), verdicts
    ((end,),) = [res["mock"]["outage_end_errors"]]
    assert math.isfinite(end["with_service_m"]) and math.isfinite(end["without_m"])
    ref = survey_service_run["ref"]
    assert ref["t_out"] == pytest.approx(a, abs=0.01)  # the mock prints it to 10 ms
    err, ref_err = score["final_error_m"], ref["final_error_m"]
    assert math.isfinite(err)
    # judged against the truth with the σ the service itself reported at the outage end (its navigation log):
    # 3σ of a 2-D error holds 99 % of the time for a consistent filter
    assert err <= 3.0 * score["sigma_h_end_m"], (err, score["sigma_h_end_m"])
    assert abs(err - ref_err) <= TOLERANCE_REL * ref_err + TOLERANCE_M, (err, ref_err)
    assert abs(score["gps_input_final_error_m"] - err) < 5.0  # what the autopilot received is that solution
    assert score["error_after_reacquisition_m"] < 5.0, score  # GNSS back: the first fixes correct the drift
    # at most the reacquisition fix itself is rejected (then the position is reset to it): vdm-deim's covariance
    # is overconfident on the as-built aircraft (its NEES, docs/navigation.md), so the drift can exceed its gate.
    # The reacquisition overshoot this guards against rejected every fix for 10 s (52 on survey seed 0).
    assert svc["health"]["rejected"].get("gnss_pos", 0) <= 1, svc["health"]
    # honest accuracies: the error at the end is inside the (inflated) horizontal accuracy sent
    assert score["gps_input_final_error_m"] <= score["gps_input_h_acc_end_m"]
    assert "autopilot 1/1 heard" in res["serve_log"] and "status: vdm-deim gnss=" in res["serve_log"]


def test_through_mavproxy_sigterm_saves_and_a_restart_restores(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    if not MAVPROXY.exists():  # the Makefile installs it: missing in CI is a failure, on a bare venv a skip
        reason = f"MAVProxy is not installed ({MAVPROXY}; the Makefile installs MAVProxy==1.8.75)"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    work = tmp_path / "mavproxy"
    run = _run(design_deim12, scenario="survey", seed=2, speed=4.0, via_mavproxy=True, stop_after_s=70.0)
    mag = site_mag_field_ut(run)
    res = run_service_sitl(run, work, mag_field_ned_ut=mag)
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    assert res["service"]["health"]["initialised"], res["serve_log"][-3000:]
    assert "SIGTERM" in res["serve_log"]
    state = work / "state" / "filter-state.npz"
    with np.load(state) as z:
        saved_wind, saved_cov = z["values"][6:8].copy(), z["cov"][6:8, 6:8].copy()
    # the filter had found the wind: its saved mean wind (the gusts are a state of their own) against the world's
    # mean over the last 30 s before the stop, within the 2-D χ² 99.9 % bound of the saved covariance widened by
    # the truth's own spread in that window (turbulence: the 30 s mean is not the mean wind)
    with np.load(work / "truth.npz") as z:
        t, wind = z["t_s"], z["wind_ned_m_s"][:, :2]
    last = t > t[-1] - 30.0
    d = saved_wind - wind[last].mean(axis=0)
    bound = saved_cov + np.cov(wind[last].T)
    assert float(d @ np.linalg.solve(bound, d)) <= 13.8, (saved_wind, wind[last].mean(axis=0), saved_cov)
    # restart on the same state directory, directly on the mock this time
    again = run_service_sitl(_run(design_deim12, scenario="survey", seed=2, speed=4.0, stop_after_s=25.0), work,
                             mag_field_ned_ut=mag)  # fmt: skip
    assert "wind" in again["service"]["restored"], again["serve_log"][-3000:]
    assert "restored bg, ba, wind" in again["serve_log"]


def test_autopilot_reboot_debug_array_ports_and_sd_notify(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    """The autopilot reboots under a running service (a second mock process from boot time 0, every stream
    off until requested again); ports arrive as DEBUG_FLOAT_ARRAY; systemd's notify socket is a fake one."""
    import contextlib
    import json
    import socket
    import subprocess
    import threading
    import time

    from vdm_aero_cli.service_sitl import VDM_AERO, _terminate, free_udp_port, start_service, write_config

    run = _run(design_deim12, scenario="survey", seed=3, speed=4.0, ports_source="debug_float_array")
    work = tmp_path / "reboot"
    work.mkdir()
    port = free_udp_port()
    config = write_config(run, work, port, site_mag_field_ut(run))
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(work / "notify.sock"))
    notify.settimeout(0.2)
    msgs: list[str] = []
    done = threading.Event()

    def read_notify() -> None:  # as systemd does: read all the time (the queue holds 10 datagrams)
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                msgs.append(notify.recv(4096).decode())

    reader = threading.Thread(target=read_notify, daemon=True)
    reader.start()
    service = start_service(config, work, env={"NOTIFY_SOCKET": str(work / "notify.sock"), "WATCHDOG_USEC": "1000000"})
    try:
        deadline = time.monotonic() + 120.0  # the autopilot boots once the service said READY=1, as systemd orders
        while not msgs and service.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        for k in range(2):  # boot, fly 40 s, power off; boot again
            cmd = [
                *VDM_AERO,
                "sitl",
                "--nav-scenario",
                "survey",
                "--seed",
                "3",
                "--ports-model",
                str(run.deim),
                "--connect",
                f"udpout:127.0.0.1:{port}",
                "--speed",
                "4",
                "--duration-s",
                "40",
                "--ports-debug-array",
                "--truth",
                str(work / f"truth{k}.npz"),
            ]
            mock = subprocess.run(cmd, capture_output=True, timeout=300)
            assert mock.returncode == 0, mock.stderr.decode()[-2000:]
    finally:
        rc = _terminate(service)
        time.sleep(0.5)
        done.set()
        reader.join()
        notify.close()
    log = (work / "serve.log").read_text()
    assert rc == 0, log[-3000:]
    summary = json.loads((work / "summary.json").read_text())
    assert summary["autopilot_reboots"] == 1 and "autopilot reboot" in log, log[-3000:]
    assert summary["handler_errors"] == {}
    health = summary["health"]
    assert health["initialised"] and health["updates"]["ports_airdata"] > 100  # the array ports were fused
    assert summary["received"]["DEBUG_FLOAT_ARRAY"] > 1000 and summary["port_frames"]["complete"] == 0
    # the streams came back after the reboot: IMU in both halves of the flight, at ArduPlane's default loop rate
    # (this mock keeps SCHED_LOOP_RATE at 50 Hz: RAW_IMU is asked for at 400 Hz and comes at 50)
    assert 0.8 * 50 * 80 < summary["received"]["RAW_IMU"] < 1.1 * 50 * 80
    assert msgs[0].startswith("READY=1") and msgs[-1].startswith("STOPPING=1")
    assert sum(m == "WATCHDOG=1" for m in msgs) >= 20  # every 0.5 s of ~25 s
    assert any(m.startswith("STATUS=status: vdm-deim gnss=") for m in msgs)
    # the position after the reboot, against the second flight's truth (which starts its flight over: the aircraft
    # jumps ~330 m). The boot's IMU gap is of unknown length, so with GNSS at hand the filter started its pose
    # again from the next fix, and navigates within metres of the truth (GNSS-aided)
    from vdm_aero.geodesy import LocalFrame

    assert health["updates"].get("reboots_reinitialised", 0) == 1, health["updates"]

    z = np.load(work / "truth1.npz", allow_pickle=False)
    rows = np.array([[float(v) for v in r.split(",")[:5]] for r in (work / "state" / "nav.csv").read_text().splitlines()
                     if not r.startswith("#")])  # fmt: skip
    k = int(np.flatnonzero(np.diff(rows[:, 1]) < -1.0)[0]) + 1  # the first row after the autopilot's clock went back
    after = rows[k:]
    home = LocalFrame(float(z["home_lat_deg"]), float(z["home_lon_deg"]), float(z["home_alt_m"]))
    ne = np.asarray(home.to_ned(after[:, 2], after[:, 3], after[:, 4])).reshape(-1, 3)[:, :2]
    truth = np.column_stack([np.interp(after[:, 1], z["t_s"], z["pos_ned_m"][:, i]) for i in range(2)])
    err = np.linalg.norm(ne - truth, axis=1)
    settled = after[:, 1] > after[0, 1] + 10.0
    assert settled.sum() > 20 and float(err[settled].max()) < 10.0, float(err[settled].max())


def test_signing_required_on_both_sides(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    """Both ends sign and require signatures: the mock accepts everything the service sends (its HEARTBEAT,
    stream requests, TIMESYNC), the service everything the mock sends, and navigation runs."""
    key = bytes(range(32)).hex()
    run = _run(design_deim12, scenario="survey", seed=4, speed=4.0, stop_after_s=40.0, signing_key_hex=key)
    res = run_service_sitl(run, tmp_path / "signed", mag_field_ned_ut=site_mag_field_ut(run))
    svc, mock = res["service"], res["mock"]
    assert res["service_rc"] == 0, res["serve_log"][-3000:]
    assert mock["rejected_frames"] == 0 and mock["link_active"], mock
    assert mock["received"].get("COMMAND_LONG", 0) >= 5  # the signed stream requests were taken
    assert svc["rejected_unsigned"] == 0 and svc["health"]["initialised"], svc
    assert svc["port_frames"]["complete"] > 500
