"""The SITL mock autopilot (sim/sitl): ArduPlane-like behaviour seen from a companion.

Fast and deterministic: a noiseless scripted world, in-memory links at unlimited or high ``speed``, and
loopback sockets (127.0.0.1, ports chosen by the OS). Waits are bounded polls on message receipt, never
sleeps; assertions on rates use the autopilot's own timestamps (world time) unless wall time is the point.
"""

from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
from collections import Counter
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.contract import WorldTick
from sim.sitl.autopilot import AutopilotOptions, DeadReckoningDrift, MockAutopilot, RunSummary, run_sitl
from sim.sitl.link import (
    MavlinkEndpoint,
    MavlinkMessage,
    MemoryLinkPair,
    SigningConfig,
    TcpClientLink,
    UdpLink,
    open_link,
)
from sim.sitl.scripted_world import (
    GRAVITY_M_S2,
    OutageWindow,
    ScriptedWorld,
    ScriptedWorldConfig,
    isa_density_kg_m3,
    isa_pressure_pa,
    make_scenario_world,
    scenario_config,
    scenario_names,
)
from sim.sitl.streams import to_time_boot_ms
from vdm_aero.errors import UserInputError
from vdm_aero.rotation import euler_from_quat

WAIT_S = 10.0  # upper bound of any single wait for a message (wall clock)
COMPANION = {"system_id": 1, "component_id": mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER}
KEY = bytes(range(32))
ATOL_DEG_E7 = 0.6e-7  # degE7 quantisation (half a unit) plus float error
ATOL_FLOAT32_REL = 1e-6


# ------------------------------------------------------------------------------------------- helpers
def noiseless(**overrides: object) -> ScriptedWorldConfig:
    return replace(scenario_config("circle_noiseless"), **overrides)  # type: ignore[arg-type]


class RecordingWorld:
    """Wraps a world and keeps every tick, indexed by the autopilot's time_boot_ms."""

    def __init__(self, inner: ScriptedWorld) -> None:
        self.inner = inner
        self.dt_s = inner.dt_s
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = inner.home_lat_deg, inner.home_lon_deg, inner.home_alt_m
        self.by_ms: dict[int, WorldTick] = {}
        self._lock = threading.Lock()

    def step(self) -> WorldTick:
        tick = self.inner.step()
        with self._lock:
            self.by_ms[to_time_boot_ms(tick.truth.t_s)] = tick
        return tick

    def at_ms(self, ms: int) -> WorldTick:
        with self._lock:
            return self.by_ms[ms]


class Runner:
    """Runs ``ap.run`` in a worker thread; ``join`` returns its summary or re-raises its exception."""

    def __init__(self, ap: MockAutopilot, duration_s: float) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mock-autopilot")
        self._future = self._pool.submit(ap.run, duration_s)

    def join(self, timeout_s: float = WAIT_S) -> RunSummary:
        try:
            return self._future.result(timeout_s)
        finally:
            self._pool.shutdown(wait=False)


@contextmanager
def running(ap: MockAutopilot, duration_s: float) -> Iterator[Runner]:
    """Fly in the background (``duration_s`` is an upper bound: the block's end stops the autopilot)."""
    runner = Runner(ap, duration_s)
    try:
        yield runner
    finally:
        ap.stop()
        runner.join()
        ap.close()


def companion(pair: MemoryLinkPair, signing: SigningConfig | None = None) -> MavlinkEndpoint:
    return MavlinkEndpoint(pair.companion_end, signing=signing, **COMPANION)


def heartbeat(ep: MavlinkEndpoint) -> None:
    ep.send(
        ep.mav.heartbeat_encode(
            mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
        )
    )


def command_long(ep: MavlinkEndpoint, command: int, *params: float) -> None:
    p = [*params, *([0.0] * (7 - len(params)))]
    ep.send(ep.mav.command_long_encode(1, 1, command, 0, *p))


def drain(ep: MavlinkEndpoint, timeout_s: float = 0.2) -> list[MavlinkMessage]:
    """Everything queued for the companion (after a run has finished)."""
    out: list[MavlinkMessage] = []
    while msgs := ep.poll(timeout_s):
        out.extend(msgs)
    return out


def run_to_end(world: object, pair: MemoryLinkPair, duration_s: float, **kwargs: object) -> RunSummary:
    with MockAutopilot(world, pair.autopilot_end, speed=math.inf, **kwargs) as ap:  # type: ignore[arg-type]
        return ap.run(duration_s)


# ------------------------------------------------------------------------------------- the world
def test_scripted_world_truth_is_kinematically_consistent() -> None:
    for path in ("circle", "figure_eight"):
        world = ScriptedWorld(noiseless(path=path, climb_amplitude_m=10.0, climb_period_s=20.0))
        ticks = [world.step() for _ in range(2000)]
        dt = world.dt_s
        pos = np.array([t.truth.pos_ned_m for t in ticks])
        vel = np.array([t.truth.v_ned_m_s for t in ticks])
        q = np.array([t.truth.q_nb for t in ticks])
        # velocity is the derivative of position; acceleration − g is the specific force in NED
        assert np.abs((pos[2:] - pos[:-2]) / (2 * dt) - vel[1:-1]).max() < 1e-4, path
        acc = (vel[2:] - vel[:-2]) / (2 * dt)
        for i in range(1, len(ticks) - 1, 97):
            tr = ticks[i].truth
            c_nb = ScriptedWorld._c_nb(tr.q_nb)
            f_ned = acc[i - 1] - np.array([0.0, 0.0, GRAVITY_M_S2])
            np.testing.assert_allclose(c_nb @ tr.specific_force_b_m_s2, f_ned, atol=1e-3, err_msg=f"{path} @ {tr.t_s}")
            # body rates: q̇ = ½ q ⊗ (0, ω)
            q_dot = (q[i + 1] - q[i - 1]) / (2 * dt)
            w, x, y, z = tr.q_nb
            omega = 2.0 * np.array([[-x, w, z, -y], [-y, -z, w, x], [-z, y, -x, w]]) @ q_dot
            np.testing.assert_allclose(omega, tr.omega_b_rad_s, atol=1e-4, err_msg=f"{path} @ {tr.t_s}")
            assert abs(tr.beta_rad) < 1e-9 and abs(tr.specific_force_b_m_s2[1]) < 1e-9  # coordinated
            v_air = np.linalg.norm(tr.v_ned_m_s - tr.wind_ned_m_s)
            assert tr.airspeed_m_s == pytest.approx(v_air)
        np.testing.assert_allclose(np.linalg.norm(vel[:, :2], axis=1), 22.0, atol=1e-6)


def test_scripted_world_sensor_rates_outages_and_ports() -> None:
    cfg = noiseless(gnss_outages=(OutageWindow(0.4, 0.6),))
    world = ScriptedWorld(cfg)
    ticks = [world.step() for _ in range(400)]  # one second
    counts = Counter(
        name
        for t in ticks
        for name in ("imu", "gnss", "baro", "mag", "airspeed", "ports", "servos")
        if getattr(t, name)
    )
    assert counts == {"imu": 400, "gnss": 4, "baro": 50, "mag": 50, "airspeed": 50, "ports": 50, "servos": 50}
    assert all(t.gnss is None and t.gnss_outage for t in ticks if 0.4 <= t.truth.t_s < 0.6)
    # delivered at 5 Hz except at 0.4 s (inside the window), valid one latency earlier
    assert [round(t.gnss.t_s, 9) for t in ticks if t.gnss is not None] == [0.1, 0.5, 0.7, 0.9]
    ports = next(t.ports for t in ticks if t.ports is not None)
    assert ports.names == tuple(f"P{i:02d}" for i in range(10))
    q_pa = 0.5 * isa_density_kg_m3(ticks[7].truth.alt_m) * ticks[7].truth.airspeed_m_s ** 2
    assert 0.9 * q_pa < ports.dp_pa[0] <= q_pa  # the tip tap sees nearly the dynamic pressure
    assert ports.dp_pa.min() > -1.26 * q_pa  # the sphere's minimum Cp is −1.25


def test_scripted_world_is_deterministic_and_seeded() -> None:
    a = make_scenario_world("figure8", seed=7)
    b = make_scenario_world("figure8", seed=7)
    c = make_scenario_world("figure8", seed=8)
    ta, tb, tc = ([w.step() for _ in range(100)] for w in (a, b, c))
    assert all(np.array_equal(x.imu.accel_b_m_s2, y.imu.accel_b_m_s2) for x, y in zip(ta, tb, strict=True))  # type: ignore[union-attr]
    assert not np.array_equal(ta[-1].imu.accel_b_m_s2, tc[-1].imu.accel_b_m_s2)  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="Generator"):
        ScriptedWorld(scenario_config("circle"))
    with pytest.raises(UserInputError, match="unknown"):
        scenario_config("loop")
    assert "circle_outage" in scenario_names()


# ------------------------------------------------------------------------------------- heartbeat
def test_heartbeat_is_a_fixed_wing_arduplane_in_auto_at_1_hz() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 10.0)
    hbs = [m for m in drain(ep) if m.get_type() == "HEARTBEAT"]
    assert summary["sent"]["HEARTBEAT"] == len(hbs)
    assert 10 <= len(hbs) <= 11  # 1 Hz over 10 s of world time
    hb = hbs[0]
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert hb.type == mavlink2.MAV_TYPE_FIXED_WING
    assert hb.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.custom_mode == mavlink2.PLANE_MODE_AUTO
    assert hb.base_mode & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink2.MAV_STATE_ACTIVE
    assert hb.get_header().mlen and hbs[0].get_msgbuf()[0] == 0xFD  # MAVLink 2 framing


# ------------------------------------------------------------------------------------ named values
def test_named_values_only_after_the_companion_is_heard_and_equal_the_world() -> None:
    world = RecordingWorld(ScriptedWorld(noiseless()))
    pair = MemoryLinkPair()
    ep = companion(pair)
    with MockAutopilot(world, pair.autopilot_end, speed=20.0) as ap, running(ap, 3600.0):
        seen: Counter[str] = Counter()
        while seen["HEARTBEAT"] < 2:  # ≥ 1 s of world time with a silent companion
            seen.update(m.get_type() for m in ep.poll(WAIT_S))
        assert seen["NAMED_VALUE_FLOAT"] == 0 and not ap.active
        heartbeat(ep)
        first = ep.recv_match("NAMED_VALUE_FLOAT", WAIT_S)
        group = [first]
        while len(group) < 20:
            group.append(ep.recv_match("NAMED_VALUE_FLOAT", WAIT_S))
        assert ap.active
    by_time: dict[int, dict[str, float]] = {}
    for m in group:
        by_time.setdefault(m.time_boot_ms, {})[m.name] = m.value
    complete = [ms for ms, values in by_time.items() if len(values) == 10]
    assert complete, by_time.keys()
    for ms in complete:
        ports = world.at_ms(ms).ports
        assert ports is not None and to_time_boot_ms(ports.t_s) == ms  # all ports share the sample's time
        sent = np.array([by_time[ms][name] for name in ports.names])
        np.testing.assert_array_equal(sent, ports.dp_pa.astype(np.float32))


def test_ports_as_debug_float_array() -> None:
    world = RecordingWorld(ScriptedWorld(noiseless()))
    pair = MemoryLinkPair()
    ep = companion(pair)
    heartbeat(ep)
    run_to_end(world, pair, 1.0, ports_as_debug_array=True, options=AutopilotOptions(debug_array_id=7))
    msgs = drain(ep)
    arrays = [m for m in msgs if m.get_type() == "DEBUG_FLOAT_ARRAY"]
    assert len(arrays) == 50 and sum(m.get_type() == "NAMED_VALUE_FLOAT" for m in msgs) == 500
    for m in arrays[:5]:
        assert m.name == "PORTS" and m.array_id == 7
        ports = world.at_ms(m.time_usec // 1000).ports
        assert ports is not None and m.time_usec == round(ports.t_s * 1e6)
        np.testing.assert_array_equal(np.array(m.data[:10], dtype=np.float32), ports.dp_pa.astype(np.float32))
        assert not any(m.data[10:])


def test_ports_as_the_array_alone_as_the_lua_script_sends_them_with_a_mavlink_channel() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    heartbeat(ep)
    run_to_end(ScriptedWorld(noiseless()), pair, 1.0, ports_as_debug_array=True,
               options=AutopilotOptions(ports_named_too=False))  # fmt: skip
    kinds = [m.get_type() for m in drain(ep)]
    assert kinds.count("DEBUG_FLOAT_ARRAY") == 50 and "NAMED_VALUE_FLOAT" not in kinds


# -------------------------------------------------------------------------------------- commands
def test_set_message_interval_changes_a_rate_mid_flight_and_is_acked() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)  # silent but for commands: no named-value flood to keep up with at speed 50
    with MockAutopilot(ScriptedWorld(noiseless()), pair.autopilot_end, speed=50.0) as ap, running(ap, 3600.0):
        before = [ep.recv_match("ATTITUDE", WAIT_S).time_boot_ms for _ in range(3)]
        assert np.diff(before).tolist() == [1000, 1000]  # default EXTRA1 rate, 1 Hz
        command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 40_000)
        ack = ep.recv_match("COMMAND_ACK", WAIT_S)
        assert (ack.command, ack.result) == (mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_ACCEPTED)
        assert (ack.target_system, ack.target_component) == (1, COMPANION["component_id"])
        after = [ep.recv_match("ATTITUDE", WAIT_S).time_boot_ms for _ in range(26)]
        intervals = np.diff(after[1:])
        assert np.all(np.abs(intervals - 40) <= 3), intervals  # 25 Hz, on the 2.5 ms world grid
        assert ap.stream_interval_s("ATTITUDE") == pytest.approx(0.04)
        command_long(ep, mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE)
        interval = ep.recv_match("MESSAGE_INTERVAL", WAIT_S)
        assert (interval.message_id, interval.interval_us) == (mavlink2.MAVLINK_MSG_ID_ATTITUDE, 40_000)
        command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 0)  # default
        ack = ep.recv_match("COMMAND_ACK", WAIT_S, lambda m: m.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL)
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        assert ap.stream_interval_s("ATTITUDE") == pytest.approx(1.0)


def test_set_message_interval_enables_disables_and_rejects() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU, 10_000)  # 100 Hz
    command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_VFR_HUD, -1)  # off
    command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 12345, 1000)  # no such message
    command_long(ep, mavlink2.MAV_CMD_DO_FLIGHTTERMINATION, 1)  # not supported here
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 2.0)
    msgs = drain(ep)
    acks = [(m.command, m.result) for m in msgs if m.get_type() == "COMMAND_ACK"]
    assert acks == [
        (mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_ACCEPTED),
        (mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_ACCEPTED),
        (mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_FAILED),
        (mavlink2.MAV_CMD_DO_FLIGHTTERMINATION, mavlink2.MAV_RESULT_UNSUPPORTED),
    ]
    # 100 Hz asked for, 50 Hz sent: no stream is faster than ArduPlane's default loop (SCHED_LOOP_RATE 50)
    assert 99 <= summary["sent"]["HIGHRES_IMU"] <= 101
    assert "VFR_HUD" not in summary["sent"]


def test_a_request_for_the_rate_a_stream_has_keeps_its_phase() -> None:
    """As ArduPilot's deferred-message buckets do: asking again for a stream's interval leaves its send times where
    they were (a late companion request does not change what the autopilot sends); a new interval starts now."""
    from sim.sitl.streams import StreamScheduler

    sched = StreamScheduler({"GPS_RAW_INT": 5.0}, loop_rate_hz=400.0)
    dt = 0.0025
    sent = [k * dt for k in range(400) if "GPS_RAW_INT" in sched.due(k * dt)]
    sched.set_rate("GPS_RAW_INT", 5.0, now_s=1.0 + 3 * dt)  # the same rate, asked mid-interval
    sent += [k * dt for k in range(400, 800) if "GPS_RAW_INT" in sched.due(k * dt)]
    assert np.allclose(np.diff(sent), 0.2) and sent[0] == 0.0
    sched.set_rate("GPS_RAW_INT", 10.0, now_s=2.0 + 3 * dt)  # a new rate: from the request on
    later = [k * dt for k in range(800, 1200) if "GPS_RAW_INT" in sched.due(k * dt)]
    assert later[0] == pytest.approx(2.0 + 3 * dt) and np.allclose(np.diff(later), 0.1)


def test_no_stream_is_faster_than_the_loop_rate() -> None:
    """A faster loop (SCHED_LOOP_RATE raised, as on a QuadPlane) lets the 100 Hz asked for through."""
    pair = MemoryLinkPair()
    ep = companion(pair)
    command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_RAW_IMU, 2_500)  # 400 Hz
    command_long(ep, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU, 10_000)  # 100 Hz
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 2.0, options=AutopilotOptions(loop_rate_hz=200.0))
    assert 199 <= summary["sent"]["HIGHRES_IMU"] <= 201
    assert 399 <= summary["sent"]["RAW_IMU"] <= 401  # capped at 200 Hz


def test_request_data_stream_sets_group_rates() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    rds = ep.mav.request_data_stream_encode
    ep.send(rds(1, 1, mavlink2.MAV_DATA_STREAM_EXTRA1, 10, 1))  # ATTITUDE, AOA_SSA at 10 Hz
    ep.send(rds(1, 1, mavlink2.MAV_DATA_STREAM_RAW_SENSORS, 10, 0))  # stop RAW_IMU, SCALED_PRESSURE
    ep.send(rds(1, 1, mavlink2.MAV_DATA_STREAM_POSITION, 4, 1))
    ep.send(rds(2, 1, mavlink2.MAV_DATA_STREAM_EXTRA2, 20, 1))  # another system: ignored
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 5.0)
    sent = summary["sent"]
    assert 50 <= sent["ATTITUDE"] <= 51 and 50 <= sent["AOA_SSA"] <= 51
    assert 20 <= sent["GLOBAL_POSITION_INT"] <= 21
    assert "RAW_IMU" not in sent and "SCALED_PRESSURE" not in sent
    assert sent["VFR_HUD"] <= 6
    times = [m.time_boot_ms for m in drain(ep) if m.get_type() == "ATTITUDE"]
    assert set(np.diff(times[1:]).tolist()) == {100}  # [0] at the first step, then on the 10 Hz grid


def test_request_data_stream_all() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    ep.send(ep.mav.request_data_stream_encode(1, 1, mavlink2.MAV_DATA_STREAM_ALL, 4, 1))
    sent = run_to_end(ScriptedWorld(noiseless()), pair, 5.0)["sent"]
    for name in ("RAW_IMU", "GPS_RAW_INT", "SERVO_OUTPUT_RAW", "GLOBAL_POSITION_INT", "ATTITUDE", "VFR_HUD", "WIND"):
        assert 19 <= sent[name] <= 21, (name, sent[name])
    assert 5 <= sent["HEARTBEAT"] <= 6  # not a stream group


def test_request_message_and_autopilot_version() -> None:
    world = ScriptedWorld(noiseless())
    pair = MemoryLinkPair()
    ep = companion(pair)
    command_long(ep, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    command_long(ep, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_HOME_POSITION)
    run_to_end(world, pair, 0.1)
    msgs = [m for m in drain(ep) if m.get_type() in {"COMMAND_ACK", "AUTOPILOT_VERSION", "HOME_POSITION"}]
    assert [m.get_type() for m in msgs] == ["COMMAND_ACK", "AUTOPILOT_VERSION", "COMMAND_ACK", "HOME_POSITION"]
    assert msgs[1].capabilities & mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert msgs[3].latitude == round(world.home_lat_deg * 1e7) and msgs[3].altitude == round(world.home_alt_m * 1e3)


def test_timesync_is_answered_with_the_autopilot_clock() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    with MockAutopilot(ScriptedWorld(noiseless()), pair.autopilot_end, speed=20.0) as ap, running(ap, 3600.0):
        t_ms = ep.recv_match("SYSTEM_TIME", WAIT_S, lambda m: m.time_boot_ms >= 2000).time_boot_ms
        ep.send(ep.mav.timesync_encode(0, 123_456_789))
        reply = ep.recv_match("TIMESYNC", WAIT_S)
        later_ms = ep.recv_match("SYSTEM_TIME", WAIT_S).time_boot_ms
    assert reply.ts1 == 123_456_789
    assert t_ms * 1e6 <= reply.tc1 <= later_ms * 1e6  # nanoseconds of the autopilot's boot clock


# ------------------------------------------------------------------------------------------- GNSS
def test_gnss_fix_is_lost_in_an_outage_window_and_comes_back() -> None:
    cfg = noiseless(gnss_outages=(OutageWindow(3.0, 5.0),), gnss_latency_s=0.0)
    world = RecordingWorld(ScriptedWorld(cfg))
    pair = MemoryLinkPair()
    ep = companion(pair)
    drift = DeadReckoningDrift(horizontal_velocity_sigma_m_s=1.0, seed=1)
    run_to_end(
        world, pair, 8.0, stream_rates={"GPS_RAW_INT": 5.0, "POSITION": 10.0}, options=AutopilotOptions(drift=drift)
    )
    msgs = drain(ep)
    gps = [m for m in msgs if m.get_type() == "GPS_RAW_INT"]
    assert len(gps) >= 39
    for m in gps:
        t = m.time_usec * 1e-6
        if 3.0 <= t < 5.0:
            assert m.fix_type == mavlink2.GPS_FIX_TYPE_NO_FIX and m.lat == m.lon == m.alt == 0, t
            assert m.eph == m.epv == 65535
        elif t >= 5.0 or 0.2 <= t < 3.0:  # the first sample is at 0.2 s (5 Hz)
            assert m.fix_type == mavlink2.GPS_FIX_TYPE_3D_FIX, t
            truth = world.inner.truth_at(t)
            assert abs(m.lat * 1e-7 - truth.lat_deg) < ATOL_DEG_E7 and abs(m.lon * 1e-7 - truth.lon_deg) < ATOL_DEG_E7
            assert abs(m.alt * 1e-3 - truth.alt_m) <= 1e-3
    # GLOBAL_POSITION_INT keeps flowing from the autopilot's estimate: it drifts in the outage, then reconverges
    err_m = {}  # by time_boot_ms
    for m in (m for m in msgs if m.get_type() == "GLOBAL_POSITION_INT"):
        truth = world.at_ms(m.time_boot_ms).truth
        north = (m.lat * 1e-7 - truth.lat_deg) * 111_000.0
        east = (m.lon * 1e-7 - truth.lon_deg) * 111_000.0 * math.cos(math.radians(truth.lat_deg))
        err_m[m.time_boot_ms] = math.hypot(north, east)
    assert len(err_m) >= 79  # 10 Hz throughout, outage or not
    assert max(e for ms, e in err_m.items() if ms < 3000) < 0.02  # degE7 quantisation only

    def err_near(ms: int) -> float:
        return err_m[min(err_m, key=lambda k: abs(k - ms))]

    assert err_near(4900) > 0.5 and err_near(4900) > 2.5 * err_near(3500)  # seeded dead-reckoning drift grows
    assert err_near(7900) < 0.5 * err_near(4900)  # and decays once the fix is back (τ = 2 s)


# --------------------------------------------------------------------------------- companion inputs
def test_gps_input_and_odometry_are_recorded(tmp_path: Path) -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    ep.send(
        ep.mav.gps_input_encode(
            1_000_000, 0, 0, 0, 0, 3, -353632610, 1491652300, 684.5, 0.8, 1.2, 1.0, -2.0, 0.5, 0.2, 0.7, 1.1, 12, 9000
        )
    )
    cov = [0.1 * i for i in range(21)]
    ep.send(
        ep.mav.odometry_encode(
            2_000_000, mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_FRD, 1.0, 2.0, -3.0,
            [1.0, 0.0, 0.0, 0.0], 4.0, 5.0, 6.0, 0.1, 0.2, 0.3, cov, cov, 0, mavlink2.MAV_ESTIMATOR_TYPE_VIO, 80,
        )
    )  # fmt: skip
    truth_path = tmp_path / "truth.npz"
    with MockAutopilot(ScriptedWorld(noiseless()), pair.autopilot_end, speed=0.0, truth_path=truth_path) as ap:
        summary = ap.run(1.0)
        (gps,), (odo,) = ap.gps_inputs, ap.odometry
    assert summary["gps_input"] == summary["odometry"] == 1
    assert gps.lat_deg == pytest.approx(-35.363261) and gps.lon_deg == pytest.approx(149.16523)
    assert gps.alt_m == pytest.approx(684.5) and gps.fix_type == 3 and gps.satellites == 12
    np.testing.assert_allclose(gps.v_ned_m_s, [1.0, -2.0, 0.5])
    assert gps.yaw_rad == pytest.approx(math.radians(90.0)) and gps.received_t_s == 0.0
    np.testing.assert_allclose(odo.pos_m, [1.0, 2.0, -3.0])
    np.testing.assert_allclose(odo.vel_m_s, [4.0, 5.0, 6.0])
    assert odo.quality == 80 and odo.child_frame_id == mavlink2.MAV_FRAME_BODY_FRD
    data = np.load(truth_path)
    assert data["gps_input_lat_deg"][0] == pytest.approx(-35.363261)
    np.testing.assert_allclose(data["odometry_pose_covariance"][0], cov, rtol=1e-6)
    assert data["odometry_time_usec"][0] == 2_000_000


# ------------------------------------------------------------------------------------------- signing
def test_signed_companion_is_accepted_when_signing_is_required() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair, SigningConfig(KEY))
    heartbeat(ep)
    command_long(ep, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 1.0, signing_key=KEY, require_signing=True)
    msgs = drain(ep)
    assert summary["link_active"] and summary["rejected_frames"] == 0
    assert any(m.get_type() == "COMMAND_ACK" for m in msgs)
    assert sum(m.get_type() == "NAMED_VALUE_FLOAT" for m in msgs) == 500
    assert all(m.get_signed() for m in msgs)  # verified against the key by the companion's parser
    assert ep.rejected_frames == 0


@pytest.mark.parametrize("companion_key", [None, bytes(32)], ids=["unsigned", "wrong-key"])
def test_unsigned_companion_is_rejected_when_signing_is_required(companion_key: bytes | None) -> None:
    pair = MemoryLinkPair()
    ep = companion(pair, SigningConfig(companion_key) if companion_key is not None else None)
    heartbeat(ep)
    command_long(ep, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 1.0, signing_key=KEY, require_signing=True)
    msgs = drain(ep)
    assert not summary["link_active"] and summary["rejected_frames"] == 2 and summary["received"] == {}
    assert not any(m.get_type() in {"COMMAND_ACK", "NAMED_VALUE_FLOAT"} for m in msgs)


def test_signing_without_requirement_accepts_unsigned() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    heartbeat(ep)
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 0.5, signing_key=KEY)
    assert summary["link_active"] and summary["rejected_frames"] == 0


# ---------------------------------------------------------------------------------- unit conversions
def test_unit_conversions_round_trip_against_the_truth() -> None:
    world = RecordingWorld(ScriptedWorld(noiseless(climb_amplitude_m=10.0, climb_period_s=20.0)))
    pair = MemoryLinkPair()
    ep = companion(pair)
    rates = {name: 10.0 for name in ("HIGHRES_IMU", "SCALED_IMU", "ATTITUDE_QUATERNION", "EXTRA1", "EXTRA2")}
    rates |= {"POSITION": 10.0, "RAW_SENS": 10.0, "EXT_STAT": 5.0, "RC_CHAN": 10.0, "EXTRA3": 10.0}
    run_to_end(world, pair, 5.0, stream_rates=rates, options=AutopilotOptions(unix_time_at_boot_s=1.7e9))
    msgs = drain(ep)
    kinds = Counter(m.get_type() for m in msgs)
    assert all(kinds[k] >= 25 for k in ("HIGHRES_IMU", "SCALED_IMU", "GPS_RAW_INT", "VFR_HUD", "WIND")), kinds
    for m in msgs:
        kind = m.get_type()
        if kind == "GLOBAL_POSITION_INT":
            tr = world.at_ms(m.time_boot_ms).truth
            assert abs(m.lat * 1e-7 - tr.lat_deg) < ATOL_DEG_E7 and abs(m.lon * 1e-7 - tr.lon_deg) < ATOL_DEG_E7
            assert abs(m.alt * 1e-3 - tr.alt_m) <= 0.5e-3 + 1e-9
            assert abs(m.relative_alt * 1e-3 - (tr.alt_m - world.home_alt_m)) <= 0.5e-3 + 1e-9
            np.testing.assert_allclose([m.vx, m.vy, m.vz], tr.v_ned_m_s * 100.0, atol=0.5 + 1e-9)
            assert abs(m.hdg - math.degrees(euler_from_quat(tr.q_nb)[2]) * 100.0 % 36000) <= 0.5 + 1e-6
        elif kind == "ATTITUDE":
            tr = world.at_ms(m.time_boot_ms).truth
            np.testing.assert_allclose([m.roll, m.pitch, m.yaw], euler_from_quat(tr.q_nb), atol=1e-6)
            np.testing.assert_allclose([m.rollspeed, m.pitchspeed, m.yawspeed], tr.omega_b_rad_s, atol=1e-6)
        elif kind == "ATTITUDE_QUATERNION":
            tr = world.at_ms(m.time_boot_ms).truth
            np.testing.assert_allclose([m.q1, m.q2, m.q3, m.q4], tr.q_nb, atol=1e-6)
        elif kind == "LOCAL_POSITION_NED":
            tr = world.at_ms(m.time_boot_ms).truth
            np.testing.assert_allclose([m.x, m.y, m.z], tr.pos_ned_m, rtol=1e-6, atol=1e-4)
        elif kind == "HIGHRES_IMU":
            tick = world.at_ms(m.time_usec // 1000)
            assert tick.imu is not None and m.time_usec == round(tick.imu.t_s * 1e6)
            np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], tick.imu.accel_b_m_s2, rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], tick.imu.gyro_b_rad_s, rtol=1e-6, atol=1e-7)
            if tick.truth.t_s < 0.02:  # mag and baro sample at 50 Hz: not there at the first step
                assert m.fields_updated == 0x003F
                continue
            assert m.fields_updated == 0x1FFF
            # as ArduPilot's send_highres_imu: barometer 1, its temperature, and diff_pressure = its pressure less
            # the ground pressure (its first reading), not the airspeed sensor's
            baro = world.at_ms(m.time_usec // 20_000 * 20).baro  # the latest barometer sample (50 Hz)
            assert baro is not None and m.temperature == pytest.approx(baro.temperature_c, abs=1e-4)
            ground_hpa = world.at_ms(20).baro.pressure_pa / 100.0  # type: ignore[union-attr]
            assert m.diff_pressure == pytest.approx(m.abs_pressure - ground_hpa, abs=1e-3)
            assert m.abs_pressure == pytest.approx(isa_pressure_pa(tick.truth.alt_m) / 100.0, abs=0.1)  # hPa
            assert m.pressure_alt == pytest.approx(tick.truth.alt_m, abs=2.0)  # ISA world, ISA pressure altitude
            mag_t = np.array([m.xmag, m.ymag, m.zmag]) * 1e-4  # gauss → T
            assert 50e-6 < np.linalg.norm(mag_t) < 60e-6
        elif kind in ("RAW_IMU", "SCALED_IMU"):
            ms = m.time_usec // 1000 if kind == "RAW_IMU" else m.time_boot_ms
            imu = world.at_ms(ms).imu
            assert imu is not None
            acc_mg = imu.accel_b_m_s2 / GRAVITY_M_S2 * 1e3
            np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], acc_mg, atol=0.5 + 1e-9)
            np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], imu.gyro_b_rad_s * 1e3, atol=0.5 + 1e-9)
            assert m.temperature == 3500  # cdegC
            if ms >= 20:  # the first mag sample (50 Hz)
                assert 500 < np.linalg.norm([m.xmag, m.ymag, m.zmag]) < 600  # mgauss (57 µT = 570 mG)
        elif kind == "SCALED_PRESSURE":
            tick = world.at_ms(m.time_boot_ms)
            assert tick.baro is not None and tick.airspeed is not None
            assert m.press_abs == pytest.approx(tick.baro.pressure_pa / 100.0, rel=ATOL_FLOAT32_REL)
            assert m.press_diff == pytest.approx(tick.airspeed.dp_pa / 100.0, rel=ATOL_FLOAT32_REL)
            assert m.temperature == round(tick.baro.temperature_c * 100.0)
        elif kind == "GPS_RAW_INT":
            if m.fix_type == mavlink2.GPS_FIX_TYPE_NO_FIX:  # only before the first GNSS sample (at 0.2 s)
                assert m.time_usec < 200_000 and m.lat == 0
                continue
            # stamped when the autopilot received it (ArduPilot's last_fix_time_ms): valid one latency earlier
            tr = world.inner.truth_at(m.time_usec * 1e-6 - world.inner.config.gnss_latency_s)
            assert m.fix_type == 3
            assert abs(m.lat * 1e-7 - tr.lat_deg) < ATOL_DEG_E7 and abs(m.alt * 1e-3 - tr.alt_m) <= 1e-3
            assert abs(m.vel - math.hypot(*tr.v_ned_m_s[:2]) * 100.0) <= 0.5 + 1e-6  # cm/s
            cog_cdeg = math.degrees(math.atan2(tr.v_ned_m_s[1], tr.v_ned_m_s[0])) * 100.0 % 36000
            assert min(abs(m.cog - cog_cdeg), 36000 - abs(m.cog - cog_cdeg)) <= 0.5 + 1e-6
            assert (m.eph, m.epv, m.h_acc, m.v_acc, m.satellites_visible) == (70, 110, 500, 800, 14)
        elif kind == "VFR_HUD":
            pass  # checked below against the pitot sample of the same tick
        elif kind == "WIND":
            # wind (3, −2, 0) m/s NED blows towards the north-west, so it comes from 146° (south-east)
            assert m.direction == pytest.approx(math.degrees(math.atan2(2.0, -3.0)), abs=1e-4)
            assert m.speed == pytest.approx(math.hypot(3.0, 2.0), rel=1e-6)
        elif kind == "SYSTEM_TIME":
            assert 0 <= m.time_unix_usec - (1_700_000_000_000_000 + m.time_boot_ms * 1000) < 1000
        elif kind == "SERVO_OUTPUT_RAW":
            servos = world.at_ms(m.time_usec // 1000).servos
            assert servos is not None
            assert [m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw] == servos.pwm_us.astype(int).tolist()
        elif kind == "AOA_SSA":
            tr = world.at_ms(m.time_usec // 1000).truth
            assert pytest.approx(math.degrees(tr.alpha_rad), rel=1e-6) == m.AOA
    hud = [m for m in msgs if m.get_type() == "VFR_HUD"]
    tas = np.mean([t.truth.airspeed_m_s for t in world.by_ms.values()])
    eas = tas * math.sqrt(isa_density_kg_m3(world.home_alt_m + 100.0) / 1.225)
    assert all(abs(m.airspeed - eas) < 2.0 for m in hud)  # equivalent airspeed from the pitot Δp
    assert all(abs(m.groundspeed - 22.0) < 1e-4 for m in hud)


# ---------------------------------------------------------------------------------------- files
def test_tlog_is_read_back_by_pymavlink_with_the_expected_rates(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pymavlink import mavutil  # the reference reader; its dialect switching is undone below

    monkeypatch.setattr(mavutil, "mavlink", mavutil.mavlink)
    monkeypatch.setattr(mavutil, "current_dialect", mavutil.current_dialect)
    monkeypatch.setenv("MAVLINK20", "1")  # restored after the test (mavutil writes it when it sees MAVLink 2)
    mavutil.set_dialect("ardupilotmega")
    pair = MemoryLinkPair()
    ep = companion(pair)
    heartbeat(ep)
    tlog = tmp_path / "run.tlog"
    summary = run_to_end(ScriptedWorld(noiseless()), pair, 10.0, tlog_path=tlog)
    log = mavutil.mavlink_connection(str(tlog))
    times: dict[str, list[float]] = {}
    sources: Counter[tuple[str, int]] = Counter()
    try:
        while (msg := log.recv_match()) is not None:
            times.setdefault(msg.get_type(), []).append(msg._timestamp)
            sources[(msg.get_type(), msg.get_srcComponent())] += 1
    finally:
        log.close()
    assert sources[("HEARTBEAT", COMPANION["component_id"])] == 1  # what was received is logged too
    assert sum(len(v) for v in times.values()) == sum(summary["sent"].values()) + 1
    hb = np.diff(times["HEARTBEAT"][1:])  # [0] is the companion's
    assert len(hb) == 9 and np.all(np.abs(hb - 1.0) <= 1e-6), hb  # 1 Hz: 10 heartbeats in 10 s
    nvf = np.array(times["NAMED_VALUE_FLOAT"])
    assert len(nvf) == 10 * 50 * 10  # 10 ports at 50 Hz for 10 s
    assert (nvf[-1] - nvf[0]) == pytest.approx(10.0 - 0.02, abs=1e-3)
    for name in ("ATTITUDE", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "SYSTEM_TIME"):
        assert np.median(np.diff(times[name])) == pytest.approx(1.0, abs=1e-3), name


def test_truth_file_format(tmp_path: Path) -> None:
    world = ScriptedWorld(noiseless(gnss_outages=(OutageWindow(0.5, 0.7),)))
    pair = MemoryLinkPair()
    path = tmp_path / "truth.npz"
    run_to_end(world, pair, 1.0, truth_path=path)
    data = np.load(path)
    assert str(data["format"]) == "vdm-aero-sitl-truth/1"
    assert data["t_s"].shape == (400,) and data["q_nb"].shape == (400, 4) and data["pos_ned_m"].shape == (400, 3)
    np.testing.assert_allclose(data["t_s"], np.arange(1, 401) * world.dt_s)
    assert data["gnss_outage"].dtype == bool and 80 <= data["gnss_outage"].sum() <= 81
    assert data["ports_dp_pa"].shape == (50, 10) and data["port_names"].tolist()[0] == "P00"
    assert float(data["home_alt_m"]) == world.home_alt_m
    tr = world.truth_at(0.5)
    np.testing.assert_allclose(data["lat_deg"][199], tr.lat_deg, rtol=0, atol=1e-12)
    assert data["gps_input_lat_deg"].shape == (0,) and data["odometry_pos_m"].shape == (0, 3)


# ------------------------------------------------------------------------------------------ speed
def test_accelerated_mode_runs_ten_seconds_in_about_one() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    heartbeat(ep)
    with MockAutopilot(ScriptedWorld(noiseless()), pair.autopilot_end, speed=10.0) as ap:
        summary = ap.run(10.0)
    assert summary["world_time_s"] == pytest.approx(10.0)
    # never faster than the schedule; slower only by what the loop itself measured as lag (a starved
    # process on a shared machine), plus scheduling slack
    assert 1.0 <= summary["wall_time_s"] < 1.0 + summary["max_lag_s"] + 0.2, summary
    assert summary["sent"]["NAMED_VALUE_FLOAT"] == 5000
    assert len(drain(ep)) == sum(summary["sent"].values())


def test_stop_from_another_thread_ends_a_long_run() -> None:
    pair = MemoryLinkPair()
    ep = companion(pair)
    ap = MockAutopilot(ScriptedWorld(noiseless()), pair.autopilot_end, speed=1.0)
    runner = Runner(ap, 3600.0)
    ep.recv_match("HEARTBEAT", WAIT_S)
    ap.stop()
    summary = runner.join()
    ap.close()
    assert summary["world_time_s"] < 5.0


# -------------------------------------------------------------------------------------- transports
def test_udp_loopback_in_real_time_heartbeat_named_values_and_timesync() -> None:
    world = ScriptedWorld(noiseless())
    with MockAutopilot(world, "udpin:127.0.0.1:0", speed=1.0) as ap:
        host, port = ap.link.local_address  # type: ignore[attr-defined]
        ep = MavlinkEndpoint(UdpLink(host, port, listen=False), **COMPANION)
        try:
            with running(ap, 30.0):
                heartbeat(ep)  # udpin learns where to reply from this
                arrivals: list[float] = []
                while len(arrivals) < 5:
                    ep.recv_match("HEARTBEAT", WAIT_S)
                    arrivals.append(time.monotonic())
                gaps = np.diff(arrivals)
                # 1 Hz in wall time. The median, because this machine is shared: a starved process delivers
                # one beat late and the loop catches up on schedule; no beat may be lost or doubled.
                assert abs(float(np.median(gaps)) - 1.0) < 0.05, gaps
                assert np.all((gaps > 0.3) & (gaps < 1.7)), gaps
                nvf = ep.recv_match("NAMED_VALUE_FLOAT", WAIT_S)
                assert nvf.name.startswith("P")
                ep.send(ep.mav.timesync_encode(0, 42))
                reply = ep.recv_match("TIMESYNC", WAIT_S)
                assert reply.ts1 == 42 and reply.tc1 > 2_000_000_000  # > 2 s of autopilot time, in ns
        finally:
            ep.link.close()


def test_tcp_server_loopback() -> None:
    with MockAutopilot(ScriptedWorld(noiseless()), "tcpin:127.0.0.1:0", speed=10.0) as ap:
        host, port = ap.link.local_address  # type: ignore[attr-defined]
        client = TcpClientLink(host, port)
        ep = MavlinkEndpoint(client, **COMPANION)
        try:
            with running(ap, 60.0):
                assert client.connected
                ep.recv_match("HEARTBEAT", WAIT_S)
                heartbeat(ep)
                ep.recv_match("NAMED_VALUE_FLOAT", WAIT_S)
        finally:
            client.close()


def test_tcp_client_connects_to_a_companion_server() -> None:
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    try:
        port = server.getsockname()[1]
        with MockAutopilot(ScriptedWorld(noiseless()), f"tcp:127.0.0.1:{port}", speed=10.0) as ap:
            readable, _, _ = select.select([server], [], [], WAIT_S)
            assert readable
            conn, _ = server.accept()
            try:
                with running(ap, 60.0):
                    conn.settimeout(WAIT_S)
                    parser = mavlink2.MAVLink(None)
                    msgs: list[MavlinkMessage] = []
                    while not any(m.get_type() == "HEARTBEAT" for m in msgs):
                        msgs.extend(parser.parse_buffer(conn.recv(4096)) or [])
            finally:
                conn.close()
    finally:
        server.close()


class _FdLink:
    """The companion's side of a pty, as a serial port would be opened."""

    description = "pty-companion"

    def __init__(self, path: str) -> None:
        self._fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)

    def send(self, data: bytes) -> None:
        os.write(self._fd, data)

    def recv(self, timeout_s: float) -> bytes:
        readable, _, _ = select.select([self._fd], [], [], max(timeout_s, 0.0))
        return os.read(self._fd, 65536) if readable else b""

    def close(self) -> None:
        os.close(self._fd)


def test_pty_serial_link() -> None:
    with MockAutopilot(ScriptedWorld(noiseless()), "pty", speed=10.0) as ap:
        path = ap.link.slave_path  # type: ignore[attr-defined]
        assert ap.link.description == f"pty {path}"
        port = _FdLink(path)
        ep = MavlinkEndpoint(port, **COMPANION)
        try:
            with running(ap, 60.0):
                heartbeat(ep)
                nvf = ep.recv_match("NAMED_VALUE_FLOAT", WAIT_S)
                assert nvf.name in {f"P{i:02d}" for i in range(10)}
        finally:
            port.close()


def test_bad_configuration_is_a_user_error() -> None:
    world = ScriptedWorld(noiseless())
    with pytest.raises(UserInputError, match="unknown scheme"):
        open_link("serial:/dev/ttyS0")
    with pytest.raises(UserInputError, match="HOST:PORT"):
        open_link("udpin:14550")
    with pytest.raises(UserInputError, match="unknown message or group"):
        MockAutopilot(world, "null", stream_rates={"ATTITUDES": 10.0})
    with pytest.raises(UserInputError, match="signing key"):
        MockAutopilot(world, "null", require_signing=True)
    with pytest.raises(UserInputError, match="32"):
        MockAutopilot(world, "null", signing_key=b"short")
    with pytest.raises(UserInputError, match="speed"):
        MockAutopilot(world, "null", speed=-1.0)


def test_run_sitl_reports_the_link_and_writes_files(tmp_path: Path) -> None:
    ready: list[str] = []
    summary = run_sitl(
        make_scenario_world("circle_outage", seed=3),
        "null",
        speed=0.0,
        duration_s=2.0,
        tlog=tmp_path / "a.tlog",
        truth=tmp_path / "a.npz",
        on_ready=ready.append,
    )
    assert ready == ["null"] and summary["link"] == "null" and not summary["link_active"]
    assert "NAMED_VALUE_FLOAT" not in summary["sent"]  # nobody was heard on a null link
    assert (tmp_path / "a.tlog").stat().st_size > 0 and np.load(tmp_path / "a.npz")["t_s"].shape == (800,)
