"""The offline service probe (bench/service_work_probe.py) hands the service what the link carried, in the
bursts it arrived in: checked on a real ArduPlane telemetry log, not on one of our own recordings."""

from __future__ import annotations

import itertools
from pathlib import Path

from pymavlink import mavutil

from bench.service_work_probe import SERVICE_COMPONENT, ReplayTransport, recorded_bursts


def _messages(tlog: Path, seconds: float) -> list[tuple[str, int]]:
    m = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    out, t0 = [], None
    while (msg := m.recv_match()) is not None:
        if msg.get_srcComponent() == SERVICE_COMPONENT:
            continue
        t0 = msg._timestamp if t0 is None else t0
        if msg._timestamp - t0 >= seconds:
            break
        out.append((msg.get_type(), msg.get_seq()))
    return out


def test_the_bursts_carry_every_message_once_in_order_and_apart(shared_logs: Path) -> None:
    tlog = shared_logs / "arduplane-sitl-gcs.tlog"
    burst_s = 0.05
    bursts = recorded_bursts(tlog, 30.0, burst_s)
    parser = mavutil.mavlink.MAVLink(None)
    parser.robust_parsing = True
    got = [(msg.get_type(), msg.get_seq()) for _, data in bursts for msg in (parser.parse_buffer(data) or [])]
    assert got == _messages(tlog, 30.0)
    starts = [t for t, _ in bursts]
    assert starts[0] == 0.0 and starts[-1] < 30.0
    assert all(b - a >= burst_s for a, b in itertools.pairwise(starts))
    assert len(bursts) < len(got)  # a GCS log's streams go out together: some bursts hold several messages


def test_the_replayed_link_keeps_the_recordings_clock_and_then_falls_quiet() -> None:
    bursts = [(0.0, b"a"), (0.0025, b"b"), (0.01, b"c")]
    link = ReplayTransport(bursts, paced=False, wall=lambda: 0.0)
    seen = []
    while (data := link.recv(0.02)) != b"":
        seen.append((data, link.now))
    assert seen == [(b"a", 1000.0), (b"b", 1000.0025), (b"c", 1000.01)]
    assert link.recv(0.02) == b"" and link.now == 1000.01
