"""A UDP relay between the mock autopilot and the service that does what real links do (issue 23): a router with
two routes to the service (every datagram arrives twice, from two addresses), a buffering radio that sends a
datagram again 0.7–1.2 s late, and a stranger on the service's port (a ground station's HEARTBEAT, a radio's
RADIO_STATUS, another system's named values, a second component of our system calling itself the autopilot).
Whatever the service sends to the stranger is counted.

Part of the world, as the mock autopilot is: a thread in the caller's process (the end-to-end test, the relay
cases of ``make bench``), randomness from a seeded numpy Generator."""

from __future__ import annotations

import select
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["Impairments", "UdpRelay"]

RECV_BYTES = 65536
FIXED_WING, ARDUPILOT = mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA


@dataclass(frozen=True)
class Impairments:
    duplicate: bool = True  # every autopilot datagram also through a second route (another source address)
    stale_probability: float = 0.001  # ... sent again 0.7–1.2 s late with this probability
    stale_delay_s: tuple[float, float] = (0.7, 1.2)
    stranger_hz: float = 2.0  # a second sender's messages per second (0: none)
    seed: int = 0


@dataclass
class RelayStats:
    forwarded: int = 0
    duplicated: int = 0
    stale_sent: int = 0
    stranger_sent: int = 0
    stranger_received_bytes: int = 0
    replies: int = 0
    late: list[tuple[float, bytes]] = field(default_factory=list)


class UdpRelay:
    """Listens on ``listen_port`` for the mock (its ``udpout``) and forwards to the service on ``service_port``
    (its ``udpin``); the service's replies go back to the mock. ``close()`` stops it."""

    def __init__(self, listen_port: int, service_port: int, impairments: Impairments | None = None) -> None:
        self.imp = impairments or Impairments()
        self.stats = RelayStats()
        self._rng = np.random.default_rng(self.imp.seed)
        self._service = ("127.0.0.1", service_port)
        self._ap = self._udp(("127.0.0.1", listen_port))
        self._routes = [self._udp(("127.0.0.1", 0)) for _ in range(2 if self.imp.duplicate else 1)]
        self._stranger = self._udp(("127.0.0.1", 0))
        self._mock_addr: tuple[str, int] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    @staticmethod
    def _udp(addr: tuple[str, int]) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(addr)
        s.setblocking(False)
        return s

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for s in (self._ap, *self._routes, self._stranger):
            s.close()

    def _loop(self) -> None:
        imp, st = self.imp, self.stats
        gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)  # a ground station
        radio = mavlink2.MAVLink(None, srcSystem=51, srcComponent=68)  # a SiK radio's RADIO_STATUS
        other = mavlink2.MAVLink(None, srcSystem=2, srcComponent=1)  # another vehicle's named values
        imposter = mavlink2.MAVLink(None, srcSystem=1, srcComponent=2)  # a second "autopilot" in our system
        next_stranger = time.monotonic() + 1.0
        socks = [self._ap, *self._routes, self._stranger]
        while not self._stop.is_set():
            readable, _, _ = select.select(socks, [], [], 0.01)
            now = time.monotonic()
            for s in readable:
                while True:
                    try:
                        data, addr = s.recvfrom(RECV_BYTES)
                    except BlockingIOError:
                        break
                    if s is self._ap:  # the mock → the service, by every route
                        self._mock_addr = addr
                        for k, route in enumerate(self._routes):
                            route.sendto(data, self._service)
                            st.forwarded += k == 0
                            st.duplicated += k > 0
                        if self._rng.random() < imp.stale_probability:
                            st.late.append((now + float(self._rng.uniform(*imp.stale_delay_s)), data))
                    elif s is self._stranger:
                        st.stranger_received_bytes += len(data)
                    elif self._mock_addr is not None:  # the service → the mock
                        self._ap.sendto(data, self._mock_addr)
                        st.replies += 1
            due = [d for d in st.late if d[0] <= now]
            if due:
                st.late = [d for d in st.late if d[0] > now]
                for _, data in due:
                    self._routes[0].sendto(data, self._service)
                    st.stale_sent += 1
            if imp.stranger_hz > 0 and now >= next_stranger:
                next_stranger = now + 1.0 / imp.stranger_hz
                for msg, mav in (
                    (gcs.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0), gcs),
                    (radio.radio_status_encode(200, 190, 100, 40, 45, 0, 0), radio),
                    (other.named_value_float_encode(int(now * 1e3) & 0xFFFFFFFF, b"P00", 123.0), other),
                    (imposter.heartbeat_encode(FIXED_WING, ARDUPILOT, 0, 0, 4), imposter),
                ):
                    self._stranger.sendto(bytes(msg.pack(mav)), self._service)
                    st.stranger_sent += 1
