"""The service's own CPU per flight second, replayed offline from a real-time run's recorded link: the same
datagrams, in the same bursts, through the service's endpoint, decoder, filter and outputs, with a transport
that hands them over from memory instead of a socket.

Why: ``vdm-aero serve`` against the mock in real time wakes ~400 times a second (one wake-up per burst the
autopilot's 400 Hz loop sends), and on this development machine (a virtual machine) a wake-up costs 20–60 µs
of CPU before any Python runs (docs/performance.md). The real-time figure is then mostly the machine's wake-up
price, which a Raspberry Pi does not pay in the same amount. This probe separates the two:

* ``work``: the datagrams fed back to back (no sleeping): what the service's code costs;
* ``paced``: the same, each burst handed over at its recorded time (the process sleeps in between, as it does
  on the link): work plus what the wake-ups cost on this machine.

Run as a script with a checkout first on ``PYTHONPATH`` (``bench/baseline.py`` does that for the code before
issue 25); it uses only interfaces both versions have (``load_config``, ``CompanionService``, its ``ep`` and
``transport``).

    python bench/service_work_probe.py RUN_DIR --seconds 60 [--paced]

``RUN_DIR`` is a ``run_service_sitl`` work directory (its ``config.yaml`` and the mock's ``mock.tlog``).
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

SERVICE_COMPONENT = 191  # the service's own frames in the mock's tlog (it logs both directions)
BURST_S = 5e-4  # datagrams this close to a burst's first arrive together: one wake-up, joined as UdpTransport does


def recorded_bursts(tlog: Path, seconds: float, burst_s: float = BURST_S) -> list[tuple[float, bytes]]:
    """The autopilot's side of the link over its first ``seconds`` as (time from the first [s], the burst's
    bytes): messages under ``burst_s`` after a burst's first join it."""
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    bursts: list[tuple[float, bytes]] = []
    t0 = None
    while (msg := m.recv_match()) is not None:
        if msg.get_srcComponent() == SERVICE_COMPONENT:
            continue
        t0 = msg._timestamp if t0 is None else t0
        t = msg._timestamp - t0
        if t >= seconds:
            break
        if bursts and t - bursts[-1][0] < burst_s:
            bursts[-1] = (bursts[-1][0], bursts[-1][1] + bytes(msg.get_msgbuf()))
        else:
            bursts.append((t, bytes(msg.get_msgbuf())))
    return bursts


class ReplayTransport:
    """A transport that returns one recorded burst per ``recv``; the service's monotonic clock follows the
    recording (so its periodic work runs at the flight's pace), and with ``paced`` each burst waits for its
    recorded time in a sleep, as the service waits for the socket."""

    description = "recorded link"
    connected = True
    dropped_sends = 0
    reconnects = 0
    last_sender = ("127.0.0.1", 14550)

    def __init__(self, bursts: list[tuple[float, bytes]], paced: bool, wall: Any) -> None:
        self.bursts, self.paced, self._wall = bursts, paced, wall
        self.i = 0
        self.sent = 0
        self.now = 0.0
        self.start = 0.0

    def send(self, data: bytes) -> None:
        self.sent += 1

    def recv(self, timeout_s: float) -> bytes:
        if self.i >= len(self.bursts):
            return b""
        t, data = self.bursts[self.i]
        self.i += 1
        self.now = 1000.0 + t
        if self.paced and (wait := self.start + t - self._wall()) > 0.0:
            time.sleep(wait)
        return data

    def confirm_peer(self) -> None:
        pass

    def close(self) -> None:
        pass


def wake_up_cost_us(period_s: float = 2.5e-3, n: int = 800) -> float:
    """CPU [µs] of one empty sleep of ``period_s`` and the wake-up after it: this machine's price of a wake-up
    with no work in it (the service sleeps between bursts the same way, in ``select``)."""
    c0 = time.process_time()
    for _ in range(n):
        time.sleep(period_s)
    return 1e6 * (time.process_time() - c0) / n


def measure(run_dir: Path, seconds: float, paced: bool, burst_s: float = BURST_S) -> dict[str, Any]:
    from firmware_bridge.config import load_config
    from firmware_bridge.service import CompanionService

    bursts = recorded_bursts(run_dir / "mock.tlog", seconds, burst_s)
    wall = time.monotonic
    link = ReplayTransport(bursts, paced, wall)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(run_dir / "config.yaml")
        cfg = replace(cfg, state_file=Path(tmp) / "state.npz", nav_log_file=Path(tmp) / "nav.csv")
        svc = CompanionService(cfg, out=io.StringIO())
        svc.transport.close()
        svc.transport = svc.ep.transport = link
        time.monotonic = lambda: link.now  # the service's clock is the recording's (restored below)
        try:
            link.start = wall()
            c0 = time.process_time()
            svc.run(lambda: link.i >= len(bursts))
            cpu_s = time.process_time() - c0
        finally:
            time.monotonic = wall
    flight_s = bursts[-1][0]
    wake_us = round(wake_up_cost_us(), 1) if paced else None
    return {"paced": paced, "empty_wake_up_cpu_us": wake_us, "flight_s": round(flight_s, 2), "wake_ups": len(bursts),
            "messages": int(sum(svc.stats.received.values())), "outputs_sent": link.sent,
            "cpu_s": round(cpu_s, 3), "cpu_pct_one_core": round(100.0 * cpu_s / flight_s, 2)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--paced", action="store_true")
    ap.add_argument("--burst-s", type=float, default=BURST_S, help="join messages this close into one wake-up")
    args = ap.parse_args(argv)
    json.dump(measure(args.run_dir, args.seconds, args.paced, args.burst_s), sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
