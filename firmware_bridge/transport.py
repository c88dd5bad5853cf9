"""Byte transports of the companion service, named by one URL string (as MAVSDK does).

==========================================  ===============================================================
``serial:///dev/ttyAMA0:921600``            a UART (pyserial); reopened with backoff when the device goes away
``udpin://0.0.0.0:14551``                   bind; replies go to the autopilot's sender (a router's ``udpout``)
``udpout://127.0.0.1:14550``                send to HOST:PORT; accept replies from anyone
``tcp://127.0.0.1:5760``                    TCP client; reconnects with backoff while the server is down
==========================================  ===============================================================

``udpin`` replies go to the sender of the last datagram that carried the autopilot's frames (signed ones, when
signing is required): the endpoint decides and says so (:meth:`UdpTransport.confirm_peer`), so a ground
station, a radio's RADIO_STATUS or a stranger sending to the same port never takes the service's outputs.
``udpin:HOST:PORT`` (pymavlink's spelling, no ``//``) is accepted too. Reconnection backs off exponentially
from :data:`BACKOFF_MIN_S` to :data:`BACKOFF_MAX_S` so a missing autopilot costs no CPU, and resets on
success. What cannot be sent (no peer yet, a full socket) is dropped and counted: the service's outputs are
periodic, so the next one replaces a lost one.

A UDP datagram carries the time the kernel received it (``SO_TIMESTAMPNS``): :attr:`UdpTransport.arrivals` gives
that time on the monotonic clock for each datagram of the last ``recv``, so the service's latency counts the
time a datagram waited in the socket while the service was busy, not only the time from its ``recv``. Stream
transports cannot tell (no arrivals).
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import struct
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

from vdm_aero.errors import UserInputError

__all__ = ["BACKOFF_MAX_S", "BACKOFF_MIN_S", "Transport", "TransportUrl", "open_transport", "parse_url"]

BACKOFF_MIN_S = 0.5
BACKOFF_MAX_S = 8.0
RECV_BYTES = 65536
RECV_QUEUE_MAX = 512  # datagrams read per select: bounded, the socket's own buffer holds the rest
# Linux's SO_TIMESTAMPNS (asm-generic socket.h, also on ARM): CPython does not export the name
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@ll")  # struct timespec: the native long's size (32-bit Raspberry Pi OS too)
ARRIVAL_MAX_AGE_S = 1.0  # an arrival stamp older than this is a wall-clock step, not a wait: use the recv time
SCHEMES = ("serial", "udpin", "udpout", "tcp")


@dataclass(frozen=True)
class TransportUrl:
    scheme: str
    host: str  # the device path for serial
    port: int  # the baud rate for serial

    def __str__(self) -> str:
        return f"{self.scheme}://{self.host}:{self.port}"


def parse_url(url: str) -> TransportUrl:
    """``SCHEME://HOST:PORT`` (or ``serial://DEVICE:BAUD``) → :class:`TransportUrl`; one-line error otherwise."""
    scheme, sep, rest = url.partition(":")
    if not sep or scheme not in SCHEMES:
        raise UserInputError(f"connection {url!r}: unknown scheme, use one of {', '.join(s + '://' for s in SCHEMES)}")
    rest = rest.removeprefix("//")
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit():
        what = "serial://DEVICE:BAUD" if scheme == "serial" else f"{scheme}://HOST:PORT"
        raise UserInputError(f"connection {url!r}: expected {what}")
    n = int(port)
    if scheme == "serial" and not 1200 <= n <= 12_000_000:
        raise UserInputError(f"connection {url!r}: baud rate {n} out of range")
    if scheme != "serial" and not 0 <= n <= 65535:
        raise UserInputError(f"connection {url!r}: port {n} out of range")
    return TransportUrl(scheme, host, n)


class Transport(Protocol):
    """A byte link; ``recv`` waits at most ``timeout_s`` and never raises for link trouble (it reconnects)."""

    description: str
    dropped_sends: int
    reconnects: int

    @property
    def connected(self) -> bool: ...

    @property
    def arrivals(self) -> list[tuple[int, float]]:
        """Per datagram of the last ``recv``: (its end's offset in the bytes returned, the monotonic time [s] it
        reached this host); empty when the link cannot tell."""
        ...

    def read_horizon(self) -> float:
        """The monotonic time [s] before which everything that reached this host has been returned by ``recv``:
        what has not come by then is missing, not waiting in a backlog the service has yet to read."""
        ...

    def send(self, data: bytes) -> None: ...

    def recv(self, timeout_s: float) -> bytes: ...

    def close(self) -> None: ...


class _Backoff:
    """Exponential backoff between connection attempts."""

    def __init__(self) -> None:
        self.delay_s = BACKOFF_MIN_S
        self.next_try = 0.0

    def due(self) -> bool:
        return time.monotonic() >= self.next_try

    def failed(self) -> None:
        self.next_try = time.monotonic() + self.delay_s
        self.delay_s = min(2.0 * self.delay_s, BACKOFF_MAX_S)

    def succeeded(self) -> None:
        self.delay_s = BACKOFF_MIN_S

    def wait_s(self) -> float:
        return max(self.next_try - time.monotonic(), 0.0)


class UdpTransport:
    """``udpin`` (bound; replies to the autopilot's sender, :meth:`confirm_peer`) or ``udpout`` (fixed peer)."""

    def __init__(self, url: TransportUrl) -> None:
        self.description = str(url)
        self.dropped_sends = 0
        self.reconnects = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)  # bursts of 400 Hz IMU + ports
        self._peer: tuple[str, int] | None = None
        self._queue: deque[tuple[tuple[str, int], bytes, float]] = deque()  # (sender, datagram, arrival [s])
        self.last_sender: tuple[str, int] | None = None
        self._arrivals: list[tuple[int, float]] = []
        # the read horizon (read_horizon): when the socket was last found empty, or the arrival of the last
        # datagram read when a bounded drain left the rest in the socket
        self._horizon = time.monotonic()
        with contextlib.suppress(OSError):  # not Linux: no stamps, the recv time stands for the arrival
            self._sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        if url.scheme == "udpin":
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                self._sock.bind((url.host, url.port))
            except OSError as e:
                self._sock.close()
                raise UserInputError(f"connection {url}: cannot bind: {e.strerror or e}") from None
        else:
            self._peer = (url.host, url.port)
        self._sock.setblocking(False)

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def connected(self) -> bool:
        return self._peer is not None

    def send(self, data: bytes) -> None:
        if self._peer is None:
            self.dropped_sends += 1
            return
        try:
            self._sock.sendto(data, self._peer)
        except OSError:  # full buffer, or ICMP port unreachable reported on a later send
            self.dropped_sends += 1

    def recv(self, timeout_s: float) -> bytes:
        """What arrived, from one sender (``last_sender``): datagrams from others wait for the next call, so
        the endpoint can tell who sent the frames it accepts (:meth:`confirm_peer`). :attr:`arrivals`: where
        each of them ends, and when the kernel received it."""
        if not self._queue:
            readable, _, _ = select.select([self._sock], [], [], max(timeout_s, 0.0))
            if not readable:
                self._horizon = time.monotonic()
                return b""
            while True:
                if len(self._queue) >= RECV_QUEUE_MAX:
                    self._horizon = self._queue[-1][2]  # the rest waits in the socket: it came later
                    break
                tried_at = time.monotonic()
                try:
                    data, anc, _flags, addr = self._sock.recvmsg(RECV_BYTES, 64)
                except (BlockingIOError, ConnectionRefusedError):
                    self._horizon = tried_at  # empty: everything that came before this has been read
                    break
                self._queue.append(((str(addr[0]), int(addr[1])), data, self._arrival(anc)))
        if not self._queue:
            return b""
        sender = self._queue[0][0]
        chunks, self._arrivals, end = [], [], 0
        while self._queue and self._queue[0][0] == sender:
            _, data, arrived = self._queue.popleft()
            chunks.append(data)
            end += len(data)
            self._arrivals.append((end, arrived))
        self.last_sender = sender
        return b"".join(chunks)

    @property
    def arrivals(self) -> list[tuple[int, float]]:
        return self._arrivals

    def read_horizon(self) -> float:
        """Datagrams still queued (another sender's turn: :meth:`recv` returns one sender's run at a time) came
        after every datagram returned before them; with none queued, the socket's own horizon."""
        return self._queue[0][2] if self._queue else self._horizon

    def _arrival(self, anc: list[tuple[int, int, bytes]]) -> float:
        """The monotonic time a datagram reached the kernel, from its ``SO_TIMESTAMPNS`` (wall-clock) stamp; the
        time now when it has none or the wall clock stepped meanwhile."""
        now = time.monotonic()
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
                sec, nsec = _TIMESPEC.unpack_from(data)
                waited = time.time() - (sec + 1e-9 * nsec)
                if 0.0 <= waited <= ARRIVAL_MAX_AGE_S and math.isfinite(waited):
                    return now - waited
        return now

    def confirm_peer(self) -> None:
        """The last recv held a frame of the autopilot (the endpoint's rule, :mod:`firmware_bridge.endpoint`:
        its system and component, signed when signing is required): ``udpin`` replies go to that sender from
        now on. Garbage, a rogue's unsigned frames, a ground station's or a radio's never steer them."""
        if self.description.startswith("udpin") and self.last_sender is not None:
            self._peer = self.last_sender

    def close(self) -> None:
        self._sock.close()


class _StreamTransport:
    """A reconnecting byte stream (TCP client, serial port); subclasses open and wrap the handle."""

    description: str

    def __init__(self) -> None:
        self.dropped_sends = 0
        self.reconnects = 0
        self._backoff = _Backoff()
        self._handle: Any = None
        self._ever_connected = False
        self._horizon = time.monotonic()

    @property
    def connected(self) -> bool:
        return self._handle is not None

    @property
    def arrivals(self) -> list[tuple[int, float]]:
        return []  # a byte stream has no arrival stamps: the endpoint takes its recv time

    def read_horizon(self) -> float:
        """When a read last left nothing behind (a wait that timed out, or fewer bytes than asked for); a read
        that filled its buffer leaves a backlog, and the horizon stays where it was."""
        return self._horizon

    def _open(self) -> Any:  # returns the handle, or raises OSError
        raise NotImplementedError

    def _write(self, data: bytes) -> None:
        raise NotImplementedError

    def _read(self, timeout_s: float) -> bytes:  # b"" on timeout; OSError or EOFError when the link is gone
        raise NotImplementedError

    def _ensure(self) -> bool:
        if self._handle is not None:
            return True
        if not self._backoff.due():
            return False
        try:
            self._handle = self._open()
        except OSError:
            self._backoff.failed()
            return False
        self._backoff.succeeded()
        if self._ever_connected:
            self.reconnects += 1
        self._ever_connected = True
        return True

    def _drop(self) -> None:
        if self._handle is not None:
            with contextlib.suppress(OSError):  # closing a dead handle: nothing left to release
                self._handle.close()
            self._handle = None
            self._backoff.failed()

    def send(self, data: bytes) -> None:
        if not self._ensure():
            self.dropped_sends += 1
            return
        try:
            self._write(data)
        except OSError:
            self.dropped_sends += 1
            self._drop()

    def recv(self, timeout_s: float) -> bytes:
        if not self._ensure():
            time.sleep(min(max(timeout_s, 0.0), self._backoff.wait_s()))
            self._horizon = time.monotonic()  # no link: nothing is waiting
            return b""
        asked_at = time.monotonic()
        try:
            data = self._read(timeout_s)
        except (OSError, EOFError):
            self._drop()
            self._horizon = time.monotonic()
            return b""
        if not data:
            self._horizon = time.monotonic()
        elif len(data) < RECV_BYTES:
            self._horizon = asked_at  # what had come by the time of asking was all returned
        return data

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


class TcpTransport(_StreamTransport):
    def __init__(self, url: TransportUrl) -> None:
        super().__init__()
        self.description = str(url)
        self._address = (url.host, url.port)

    def _open(self) -> socket.socket:
        sock = socket.create_connection(self._address, timeout=BACKOFF_MIN_S)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(BACKOFF_MIN_S)  # a send to a stalled peer fails (and reconnects) instead of hanging
        return sock

    def _write(self, data: bytes) -> None:
        self._handle.sendall(data)

    def _read(self, timeout_s: float) -> bytes:
        readable, _, _ = select.select([self._handle], [], [], max(timeout_s, 0.0))
        if not readable:
            return b""
        data: bytes = self._handle.recv(RECV_BYTES)
        if not data:
            raise EOFError("TCP peer closed")
        return data


class SerialTransport(_StreamTransport):
    def __init__(self, url: TransportUrl) -> None:
        super().__init__()
        self.description = str(url)
        self._device, self._baud = url.host, url.port

    def _open(self) -> Any:
        import serial  # pyserial: only a serial link needs it

        try:
            return serial.Serial(self._device, self._baud, timeout=0, write_timeout=BACKOFF_MIN_S, exclusive=True)
        except serial.SerialException as e:  # a missing or busy device: retried with backoff
            raise OSError(str(e)) from None

    def _write(self, data: bytes) -> None:
        import serial

        try:
            self._handle.write(data)
        except serial.SerialException as e:
            raise OSError(str(e)) from None

    def _read(self, timeout_s: float) -> bytes:
        import serial

        try:
            readable, _, _ = select.select([self._handle.fileno()], [], [], max(timeout_s, 0.0))
            if not readable:
                return b""
            data: bytes = self._handle.read(self._handle.in_waiting or 1)
        except serial.SerialException as e:  # unplugged: pyserial reports readiness without data
            raise OSError(str(e)) from None
        return data


def open_transport(url: str) -> UdpTransport | TcpTransport | SerialTransport:
    """Open the transport named by ``url`` (module docstring). Stream transports connect lazily."""
    u = parse_url(url)
    if u.scheme in ("udpin", "udpout"):
        return UdpTransport(u)
    if u.scheme == "tcp":
        return TcpTransport(u)
    return SerialTransport(u)
