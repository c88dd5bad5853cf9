"""``vdm-aero sitl`` end to end: the real flight simulator behind the mock autopilot, a MAVLink client on loopback."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_sitl_flies_a_scenario_in_real_time_against_a_client(tmp_path: Path) -> None:
    port = _free_udp_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "vdm_aero_cli.main",
            "sitl",
            "--scenario",
            "survey-wind8",
            "--connect",
            f"udpin:127.0.0.1:{port}",
            "--speed",
            "1",
            "--duration-s",
            "6",
            "--tlog",
            str(tmp_path / "f.tlog"),
            "--truth",
            str(tmp_path / "truth"),
            "--json",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(0.2)
    link = mav.MAVLink(None, srcSystem=255, srcComponent=mav.MAV_COMP_ID_ONBOARD_COMPUTER)
    link.robust_parsing = True
    hb = link.heartbeat_encode(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(link)
    seen: dict[str, list[object]] = {}
    try:
        deadline = time.monotonic() + 30.0
        next_hb = 0.0
        while time.monotonic() < deadline and proc.poll() is None:
            if time.monotonic() >= next_hb:  # a companion announces itself, as a real one would
                sock.sendto(hb, ("127.0.0.1", port))
                next_hb = time.monotonic() + 1.0
            try:
                data, _ = sock.recvfrom(65535)
            except TimeoutError:
                continue
            for m in link.parse_buffer(data) or []:
                seen.setdefault(m.get_type(), []).append(m)
            if len(seen.get("NAMED_VALUE_FLOAT", [])) >= 50 and len(seen.get("HEARTBEAT", [])) >= 2:
                break
        _, err = proc.communicate(timeout=30)
    finally:
        sock.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    beats = seen.get("HEARTBEAT", [])
    assert beats and all(b.type == mav.MAV_TYPE_FIXED_WING for b in beats)  # type: ignore[attr-defined]
    nvf = seen.get("NAMED_VALUE_FLOAT", [])
    assert len(nvf) >= 50
    # all ports of one sample share time_boot_ms; values are differential pressures of a flying aircraft [Pa]
    first = nvf[0].time_boot_ms  # type: ignore[attr-defined]
    same = [m for m in nvf if m.time_boot_ms == first]  # type: ignore[attr-defined]
    assert len(same) >= 2 and len({m.name for m in same}) == len(same)  # type: ignore[attr-defined]
    assert all(abs(m.value) < 5000.0 for m in nvf)  # type: ignore[attr-defined]
    assert any(abs(m.value) > 1.0 for m in nvf)  # type: ignore[attr-defined]
    assert "GLOBAL_POSITION_INT" in seen and "ATTITUDE" in seen
    assert (tmp_path / "f.tlog").stat().st_size > 0


def test_plot_flight_from_a_fast_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from vdm_aero_cli.main import main

    truth = tmp_path / "truth.npz"
    assert main(["sitl", "--scenario", "loiter-outage300", "--connect", "null", "--speed", "0", "--duration-s", "20",
                 "--truth", str(truth), "--progress"]) == 0  # fmt: skip
    # --progress: the world's own clock, one line per second flown (a harness acts on it, not on the wall clock)
    ticks = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("world time ")]
    assert ticks == [f"world time {t} s" for t in range(1, 21)]
    assert main(["plot-flight", str(truth), "--out", str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_sitl_user_errors_are_one_line(tmp_path: Path) -> None:
    for args, phrase in (
        (["sitl", "--scenario", "nope"], "nope: no such scenario"),
        (["sitl", "--scenario", "survey-wind8", "--signing-key", "abc"], "--signing-key: expected 64 hex digits"),
        (["sitl", "--scenario", "survey-wind8", "--viso", "VEL_NSE=1"], "--viso: expected NAME=VALUE"),
        (["sitl", "--scenario", "survey-wind8", "--viso", "VEL_M_NSE=nan"], "--viso: expected NAME=VALUE"),
        (["plot-flight", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "x.png")], "not a SITL truth file"),
    ):
        r = subprocess.run([sys.executable, "-m", "vdm_aero_cli.main", *args], capture_output=True, text=True,
                           timeout=120)  # fmt: skip
        assert r.returncode == 2, r.stderr
        assert phrase in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_gcs_recording_writes_a_replayable_tlog_without_a_companion(tmp_path: Path) -> None:
    """``--gcs-recording`` on a null link: the streams asked for with --stream-rate and the named port values are in
    the tlog from the start; without it a silent link gets no named values (ArduPilot waits for a peer)."""
    from firmware_bridge.logs import read_log

    def fly(name: str, *extra: str) -> Path:
        tlog = tmp_path / f"{name}.tlog"
        subprocess.run([sys.executable, "-m", "vdm_aero_cli.main", "sitl", "--scenario", "survey-wind8", "--connect",
                        "null", "--speed", "0", "--duration-s", "3", "--stream-rate", "HIGHRES_IMU=400",
                        "--stream-rate", "GPS_RAW_INT=5", "--tlog", str(tlog), *extra], check=True,
                       capture_output=True)  # fmt: skip
        return tlog

    rec = read_log(fly("rec", "--gcs-recording", "--loop-rate-hz", "400"), ("P00", "P01"))
    assert rec.log.meta["rates_hz"]["imu"] > 390.0 and len(rec.log["ports_t_s"]) > 50
    plane = read_log(fly("plane", "--gcs-recording"), ("P00", "P01"))  # ArduPlane's default loop: 50 Hz at most
    assert 49.0 < plane.log.meta["rates_hz"]["imu"] < 51.0
    silent = read_log(fly("silent"), ("P00", "P01"))
    assert len(silent.log["ports_t_s"]) == 0 and any("no port values" in w for w in silent.report.warnings)


def test_viso_parameters_reach_the_externalnav_judge_as_ardupilot_names_them() -> None:
    """--viso takes ArduPilot's names, with or without the VISO_ prefix, into the judge's VisoParams; QUAL_MIN and
    TYPE are integers there as on the autopilot."""
    from sim.sitl.extnav_judge import VisoParams
    from vdm_aero_cli.cmd_sitl import _viso

    got = _viso(["VISO_VEL_M_NSE=1.95", "qual_min=1"])
    assert got == {"vel_m_nse": 1.95, "qual_min": 1} and isinstance(got["qual_min"], int)
    viso = VisoParams(**got)  # type: ignore[arg-type]
    assert (viso.vel_m_nse, viso.qual_min, viso.pos_m_nse) == (1.95, 1, VisoParams().pos_m_nse)
