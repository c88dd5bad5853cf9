"""Third-party conformance of the mock autopilot: real MAVLink tools accept it as an ArduPlane.

* MAVProxy (a subprocess) connects to the mock and routes its stream to a second UDP endpoint that
  this test reads with pymavlink. MAVProxy's own HEARTBEATs are what unlock the named values.
* MAVSDK (mavsdk ≥ 4: the native C++ library through ctypes, in-process, no ``mavsdk_server``)
  discovers the mock as an ArduPilot fixed-wing and reads position and attitude.

Loopback only (127.0.0.1, OS-chosen ports), bounded waits, subprocesses ended in ``finally``; each
test finishes well under 60 s. Skipped, with the reason, when the tool is not installed.
"""

from __future__ import annotations

import importlib.util
import math
import queue
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.sitl.autopilot import MockAutopilot, RunSummary
from sim.sitl.link import MavlinkEndpoint, MavlinkMessage, UdpLink
from sim.sitl.scripted_world import ScriptedWorld, scenario_config
from vdm_aero.rotation import euler_from_quat

WAIT_S = 20.0  # any single wait for a message or a discovery
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
ATOL_POSITION_DEG = 1e-6
ATOL_ANGLE_DEG = 1e-3  # float32 angles through MAVLink


class _Runner:
    """``ap.run`` in a worker thread; ``finish`` stops it and returns the summary (or re-raises)."""

    def __init__(self, ap: MockAutopilot, duration_s: float) -> None:
        self._ap = ap
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mock-autopilot")
        self._future = self._pool.submit(ap.run, duration_s)

    def finish(self) -> RunSummary:
        self._ap.stop()
        try:
            return self._future.result(WAIT_S)
        finally:
            self._pool.shutdown(wait=False)


class _TappedLink:
    """A UDP link that also decodes what the mock sends (to compare a tool's view with the wire)."""

    def __init__(self, inner: UdpLink) -> None:
        self.inner = inner
        self.description = inner.description
        self._parser = mavlink2.MAVLink(None)
        self._lock = threading.Lock()
        self._sent: list[MavlinkMessage] = []

    def send(self, data: bytes) -> None:
        self.inner.send(data)
        with self._lock:
            self._sent.extend(self._parser.parse_buffer(data) or [])

    def recv(self, timeout_s: float) -> bytes:
        return self.inner.recv(timeout_s)

    def close(self) -> None:
        self.inner.close()

    def sent(self, kind: str) -> list[MavlinkMessage]:
        with self._lock:
            return [m for m in self._sent if m.get_type() == kind]


def _from_autopilot(msg: MavlinkMessage) -> bool:
    return (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 1)


def _world() -> ScriptedWorld:
    return ScriptedWorld(scenario_config("circle_noiseless"))


def _step_time_s(world: ScriptedWorld, time_boot_ms: int) -> float:
    """The world step a (truncated) MAVLink millisecond stamp came from: the first step at or after it."""
    return math.ceil(time_boot_ms * 1e-3 / world.dt_s - 1e-9) * world.dt_s


# ------------------------------------------------------------------------------------------- MAVProxy
def test_mavproxy_routes_heartbeat_and_named_values(tmp_path: Path) -> None:
    if not MAVPROXY.exists():
        pytest.skip(f"MAVProxy is not installed ({MAVPROXY} missing; pip install MAVProxy==1.8.75)")
    out = UdpLink("127.0.0.1", 0, listen=True)  # where MAVProxy forwards to; bound before MAVProxy starts
    reader = MavlinkEndpoint(out, system_id=1, component_id=mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER)
    with MockAutopilot(_world(), "udpin:127.0.0.1:0", speed=1.0) as ap:
        _, port = ap.link.local_address  # type: ignore[attr-defined]
        runner = _Runner(ap, 120.0)
        proc = subprocess.Popen(
            [
                sys.executable,
                str(MAVPROXY),
                f"--master=udpout:127.0.0.1:{port}",  # MAVProxy sends first: the mock's udpin learns its address
                f"--out=udpout:127.0.0.1:{out.local_address[1]}",
                "--daemon",
                "--non-interactive",
                "--no-state",
            ],
            cwd=tmp_path,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        try:
            hb = reader.recv_match("HEARTBEAT", WAIT_S, _from_autopilot)
            assert hb.type == mavlink2.MAV_TYPE_FIXED_WING
            assert hb.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
            names = {reader.recv_match("NAMED_VALUE_FLOAT", WAIT_S, _from_autopilot).name for _ in range(30)}
            assert names <= {f"P{i:02d}" for i in range(10)} and len(names) >= 5
            reader.recv_match("GLOBAL_POSITION_INT", WAIT_S, _from_autopilot)
        finally:
            proc.terminate()
            try:
                log, _ = proc.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                log, _ = proc.communicate()
            summary = runner.finish()
            out.close()
    assert summary["link_active"], log.decode(errors="replace")
    assert summary["received"]["HEARTBEAT"] >= 1  # MAVProxy's, which unlocked the named values
    assert b"Detected vehicle 1:1" in log, log.decode(errors="replace")


# --------------------------------------------------------------------------------------------- MAVSDK
def _mavsdk_or_skip() -> Any:
    spec = importlib.util.find_spec("mavsdk")
    if spec is None or spec.origin is None:
        pytest.skip("mavsdk is not installed (pip install mavsdk==4.1.0)")
    lib = Path(spec.origin).parent / "lib" / "libcmavsdk.so"
    if not lib.exists():
        pytest.skip(f"mavsdk without its native library ({lib} missing): mavsdk<4 is the gRPC wrapper, unsupported")
    import mavsdk  # type: ignore[import-untyped]

    return mavsdk


def test_mavsdk_discovers_the_mock_and_reads_position_and_attitude() -> None:
    mavsdk = _mavsdk_or_skip()
    from mavsdk.plugins.telemetry import Telemetry  # type: ignore[import-untyped]

    world = _world()
    link = _TappedLink(UdpLink("127.0.0.1", 0, listen=True))
    _, port = link.inner.local_address
    positions: queue.Queue[Any] = queue.Queue()
    attitudes: queue.Queue[Any] = queue.Queue()
    with MockAutopilot(world, link, speed=1.0) as ap:
        runner = _Runner(ap, 120.0)
        config = mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
        drone = mavsdk.Mavsdk(config)
        try:
            drone.add_any_connection_with_handle(f"udpout://127.0.0.1:{port}")  # MAVSDK 4 URL spelling
            system = drone.first_autopilot(WAIT_S)
            assert system is not None, "MAVSDK did not discover the mock autopilot"
            assert system.autopilot_type() == mavsdk.Autopilot.ARDUPILOT
            assert system.vehicle_type() == mavsdk.Vehicle.FIXED_WING
            assert system.get_system_id() == 1 and system.is_connected()
            telemetry = Telemetry(system)
            telemetry.subscribe_position(lambda p, _: positions.put(p))
            telemetry.subscribe_attitude_euler(lambda a, _: attitudes.put(a))
            position = positions.get(timeout=WAIT_S)
            attitude = attitudes.get(timeout=WAIT_S)
        finally:
            drone.destroy()
            runner.finish()
            link.close()
    # the position MAVSDK reports is a GLOBAL_POSITION_INT the mock sent, and that one is the truth
    sent = min(
        link.sent("GLOBAL_POSITION_INT"),
        key=lambda m: abs(m.lat * 1e-7 - position.latitude_deg) + abs(m.lon * 1e-7 - position.longitude_deg),
    )
    assert abs(sent.lat * 1e-7 - position.latitude_deg) < 1e-9 and abs(sent.lon * 1e-7 - position.longitude_deg) < 1e-9
    truth = world.truth_at(_step_time_s(world, sent.time_boot_ms))
    assert abs(position.latitude_deg - truth.lat_deg) < ATOL_POSITION_DEG
    assert abs(position.longitude_deg - truth.lon_deg) < ATOL_POSITION_DEG
    assert position.absolute_altitude_m == pytest.approx(truth.alt_m, abs=0.01)
    assert position.relative_altitude_m == pytest.approx(truth.alt_m - world.home_alt_m, abs=0.01)
    # attitude carries ATTITUDE.time_boot_ms (in µs)
    truth = world.truth_at(_step_time_s(world, round(attitude.timestamp_us / 1e3)))
    expected = np.degrees(euler_from_quat(truth.q_nb))
    got = np.array([attitude.roll_deg, attitude.pitch_deg, attitude.yaw_deg])
    np.testing.assert_allclose(got, expected, atol=ATOL_ANGLE_DEG)
    assert math.isfinite(attitude.roll_deg) and abs(attitude.roll_deg) > 5.0  # a banked turn, not zeros
