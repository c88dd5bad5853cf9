"""Byte transports for the mock autopilot, and a MAVLink 2 endpoint on top of any of them.

A :class:`Link` moves bytes; :class:`MavlinkEndpoint` frames them with pymavlink's generated
``ardupilotmega`` MAVLink 2 codec (constructed here, not through ``mavutil``: no dialect globals, no
environment variables). Transports by URL (:func:`open_link`):

===============================  ==========================================================================
``udpin:HOST:PORT``              bind and listen; replies go to the last sender (nothing is sent before one)
``udpout:HOST:PORT``             send datagrams to HOST:PORT; accept replies from anyone
``tcp:HOST:PORT``                TCP client (reconnects every 0.5 s while the server is down)
``tcpin:HOST:PORT``              TCP server; the latest client wins
``pty``                          a pseudo-terminal pair: the companion opens ``PtyLink.slave_path``
``null``                         discards everything, never receives (speed tests)
===============================  ==========================================================================

``udpin://HOST:PORT`` (MAVSDK's spelling) is accepted too. Port 0 binds a free port: read it back from
``UdpLink.local_address`` / ``TcpServerLink.local_address``. In-process pairs come from
:class:`MemoryLinkPair`. Stream transports (TCP, pty) buffer what the peer cannot take yet, up to
``MAX_PENDING_BYTES``, and drop whole frames beyond that, as a full UART would.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from vdm_aero.errors import UserInputError

MAX_PENDING_BYTES = 1 << 20  # per stream link: ~2 s of a 4 Mbit/s link
RECV_CHUNK_BYTES = 65536
TCP_RECONNECT_INTERVAL_S = 0.5
SIGNING_KEY_BYTES = 32
SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01T00:00:00Z, the MAVLink signing timestamp origin
SIGNING_TICKS_PER_S = 100_000  # signing timestamps count 10 µs

MavlinkMessage = Any  # pymavlink messages are untyped (mavlink2.MAVLink_message subclasses)


class Link(Protocol):
    """A bidirectional byte transport."""

    @property
    def description(self) -> str:
        """Human-readable endpoint, e.g. ``udpin 0.0.0.0:14550`` or ``pty /dev/pts/3``."""
        ...

    def send(self, data: bytes) -> None:
        """Send one MAVLink frame (dropped when the link has no peer or is full)."""
        ...

    def recv(self, timeout_s: float) -> bytes:
        """Bytes received within ``timeout_s`` (returns as soon as any arrive; ``b""`` on timeout)."""
        ...

    def close(self) -> None: ...


class NullLink:
    """Discards what is sent, never receives; ``recv`` waits out its timeout."""

    description = "null"

    def __init__(self) -> None:
        self._closed = threading.Event()

    def send(self, data: bytes) -> None:
        return None

    def recv(self, timeout_s: float) -> bytes:
        if timeout_s > 0.0:
            self._closed.wait(timeout_s)
        return b""

    def close(self) -> None:
        self._closed.set()


class _Pipe:
    """One direction of a memory link: a thread-safe queue of byte chunks."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._chunks: deque[bytes] = deque()
        self._closed = False

    def put(self, data: bytes) -> None:
        with self._cond:
            if not self._closed:
                self._chunks.append(bytes(data))
                self._cond.notify_all()

    def get(self, timeout_s: float) -> bytes:
        with self._cond:
            if not self._chunks and timeout_s > 0.0 and not self._closed:
                self._cond.wait(timeout_s)
            out = b"".join(self._chunks)
            self._chunks.clear()
            return out

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class MemoryLink:
    """One end of a :class:`MemoryLinkPair`."""

    def __init__(self, inbox: _Pipe, outbox: _Pipe, description: str) -> None:
        self._inbox = inbox
        self._outbox = outbox
        self.description = description

    def send(self, data: bytes) -> None:
        self._outbox.put(data)

    def recv(self, timeout_s: float) -> bytes:
        return self._inbox.get(timeout_s)

    def close(self) -> None:
        self._outbox.close()
        self._inbox.close()


class MemoryLinkPair:
    """Two connected in-process links: ``autopilot_end`` for the mock, ``companion_end`` for a test."""

    def __init__(self) -> None:
        to_companion, to_autopilot = _Pipe(), _Pipe()
        self.autopilot_end = MemoryLink(to_autopilot, to_companion, "memory:autopilot")
        self.companion_end = MemoryLink(to_companion, to_autopilot, "memory:companion")


class UdpLink:
    """UDP: ``listen=True`` is ``udpin`` (reply to the last sender), otherwise ``udpout``."""

    def __init__(self, host: str, port: int, *, listen: bool) -> None:
        self._listen = listen
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._peer: tuple[str, int] | None = None
        if listen:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((host, port))
        else:
            self._peer = (host, port)
        self._sock.setblocking(False)
        self.dropped_frames = 0

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def peer(self) -> tuple[str, int] | None:
        return self._peer

    @property
    def description(self) -> str:
        if self._listen:
            host, port = self.local_address
            return f"udpin {host}:{port}"
        assert self._peer is not None
        return f"udpout {self._peer[0]}:{self._peer[1]}"

    def send(self, data: bytes) -> None:
        if self._peer is None:
            self.dropped_frames += 1
            return
        try:
            self._sock.sendto(data, self._peer)
        except (BlockingIOError, ConnectionRefusedError):
            self.dropped_frames += 1

    def recv(self, timeout_s: float) -> bytes:
        readable, _, _ = select.select([self._sock], [], [], max(timeout_s, 0.0))
        if not readable:
            return b""
        chunks: list[bytes] = []
        while True:
            try:
                data, addr = self._sock.recvfrom(RECV_CHUNK_BYTES)
            except (BlockingIOError, ConnectionRefusedError):
                break
            chunks.append(data)
            if self._listen:
                self._peer = (str(addr[0]), int(addr[1]))
        return b"".join(chunks)

    def close(self) -> None:
        self._sock.close()


class _PendingWriter:
    """Non-blocking writes to a stream fd with a bounded backlog; whole frames are dropped when full."""

    def __init__(self) -> None:
        self.pending = bytearray()
        self.dropped_frames = 0

    def queue(self, data: bytes) -> None:
        if len(self.pending) + len(data) > MAX_PENDING_BYTES:
            self.dropped_frames += 1
            return
        self.pending += data

    def flush(self, write: Callable[[bytes], int]) -> None:
        while self.pending:
            try:
                n = write(bytes(self.pending))
            except BlockingIOError:
                return
            del self.pending[:n]

    def clear(self) -> None:
        self.pending.clear()


class TcpServerLink:
    """``tcpin``: accept TCP clients; the latest one is the peer."""

    def __init__(self, host: str, port: int) -> None:
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, port))
        self._listener.listen(1)
        self._listener.setblocking(False)
        self._client: socket.socket | None = None
        self._out = _PendingWriter()

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._listener.getsockname()[:2]
        return str(host), int(port)

    @property
    def description(self) -> str:
        host, port = self.local_address
        return f"tcpin {host}:{port}"

    @property
    def dropped_frames(self) -> int:
        return self._out.dropped_frames

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
            self._out.clear()

    def send(self, data: bytes) -> None:
        if self._client is None:
            self._out.dropped_frames += 1
            return
        self._out.queue(data)
        self._flush()

    def _flush(self) -> None:
        if self._client is None:
            return
        try:
            self._out.flush(self._client.send)
        except (BrokenPipeError, ConnectionResetError):
            self._drop_client()

    def recv(self, timeout_s: float) -> bytes:
        watch: list[socket.socket] = [self._listener] + ([self._client] if self._client else [])
        writers = [self._client] if self._client is not None and self._out.pending else []
        readable, writable, _ = select.select(watch, writers, [], max(timeout_s, 0.0))
        if self._listener in readable:
            conn, _ = self._listener.accept()
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._drop_client()
            self._client = conn
            return b""
        if writable:
            self._flush()
        if self._client is None or self._client not in readable:
            return b""
        try:
            data = self._client.recv(RECV_CHUNK_BYTES)
        except (BlockingIOError, ConnectionResetError):
            data = b""
        if not data:
            self._drop_client()
        return data

    def close(self) -> None:
        self._drop_client()
        self._listener.close()


class TcpClientLink:
    """``tcp``: connect to a TCP server, reconnecting every ``TCP_RECONNECT_INTERVAL_S`` while it is down."""

    def __init__(self, host: str, port: int) -> None:
        self._address = (host, port)
        self._sock: socket.socket | None = None
        self._next_attempt = 0.0
        self._out = _PendingWriter()
        self._closed = threading.Event()
        self._connect()

    @property
    def description(self) -> str:
        return f"tcp {self._address[0]}:{self._address[1]}"

    @property
    def connected(self) -> bool:
        return self._sock is not None

    @property
    def dropped_frames(self) -> int:
        return self._out.dropped_frames

    def _connect(self) -> None:
        now = time.monotonic()
        if self._sock is not None or now < self._next_attempt:
            return
        self._next_attempt = now + TCP_RECONNECT_INTERVAL_S
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.settimeout(TCP_RECONNECT_INTERVAL_S)
        try:
            sock.connect(self._address)
        except (ConnectionRefusedError, TimeoutError):
            sock.close()
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock

    def _drop(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            self._out.clear()

    def send(self, data: bytes) -> None:
        if self._sock is None:
            self._out.dropped_frames += 1
            return
        self._out.queue(data)
        try:
            self._out.flush(self._sock.send)
        except (BrokenPipeError, ConnectionResetError):
            self._drop()

    def recv(self, timeout_s: float) -> bytes:
        self._connect()
        if self._sock is None:  # wait out the timeout (bounded by the reconnect interval), or until close()
            self._closed.wait(min(max(timeout_s, 0.0), TCP_RECONNECT_INTERVAL_S))
            return b""
        writers = [self._sock] if self._out.pending else []
        readable, writable, _ = select.select([self._sock], writers, [], max(timeout_s, 0.0))
        if writable:
            try:
                self._out.flush(self._sock.send)
            except (BrokenPipeError, ConnectionResetError):
                self._drop()
                return b""
        if not readable:
            return b""
        try:
            data = self._sock.recv(RECV_CHUNK_BYTES)
        except (BlockingIOError, ConnectionResetError):
            data = b""
        if not data:
            self._drop()
        return data

    def close(self) -> None:
        self._closed.set()
        self._drop()


class PtyLink:
    """A pseudo-terminal pair in raw mode: the mock holds the master, the companion opens ``slave_path``.

    The mock keeps the slave open too, so the master never sees a hang-up when the companion closes it.
    """

    def __init__(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no line discipline: a serial line
        os.set_blocking(self._master, False)
        self.slave_path = os.ttyname(self._slave)
        self._out = _PendingWriter()

    @property
    def description(self) -> str:
        return f"pty {self.slave_path}"

    @property
    def dropped_frames(self) -> int:
        return self._out.dropped_frames

    def _write(self, data: bytes) -> int:
        return os.write(self._master, data)

    def send(self, data: bytes) -> None:
        self._out.queue(data)
        self._out.flush(self._write)

    def recv(self, timeout_s: float) -> bytes:
        writers = [self._master] if self._out.pending else []
        readable, writable, _ = select.select([self._master], writers, [], max(timeout_s, 0.0))
        if writable:
            self._out.flush(self._write)
        if not readable:
            return b""
        try:
            return os.read(self._master, RECV_CHUNK_BYTES)
        except BlockingIOError:
            return b""
        except OSError as e:  # EIO: no slave side open (cannot happen while we hold it; kept explicit)
            if e.errno == errno.EIO:
                return b""
            raise

    def close(self) -> None:
        os.close(self._master)
        os.close(self._slave)


def _host_port(url: str, rest: str) -> tuple[str, int]:
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UserInputError(f"connection URL {url!r}: expected SCHEME:HOST:PORT")
    return host, int(port)


def open_link(url: str) -> UdpLink | TcpClientLink | TcpServerLink | PtyLink | NullLink:
    """Open the transport named by ``url`` (see the module docstring)."""
    scheme, _, rest = url.partition(":")
    rest = rest.removeprefix("//")
    match scheme:
        case "udpin":
            return UdpLink(*_host_port(url, rest), listen=True)
        case "udpout":
            return UdpLink(*_host_port(url, rest), listen=False)
        case "tcp" | "tcpout":
            return TcpClientLink(*_host_port(url, rest))
        case "tcpin":
            return TcpServerLink(*_host_port(url, rest))
        case "pty" if not rest:
            return PtyLink()
        case "null" if not rest:
            return NullLink()
        case _:
            raise UserInputError(
                f"connection URL {url!r}: unknown scheme, use udpin:, udpout:, tcp:, tcpin:HOST:PORT, pty or null"
            )


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 signing: sign everything sent; with ``require`` reject unsigned incoming frames.

    Like ArduPilot, RADIO_STATUS is accepted unsigned even when signing is required.
    """

    key: bytes
    require: bool = False
    link_id: int = 0

    def __post_init__(self) -> None:
        if len(self.key) != SIGNING_KEY_BYTES:
            raise UserInputError(f"signing key: {len(self.key)} bytes, MAVLink 2 signing needs {SIGNING_KEY_BYTES}")


def signing_timestamp_now() -> int:
    """The MAVLink signing timestamp of the wall clock: 10 µs ticks since 2015-01-01."""
    return int(max(time.time() - SIGNING_EPOCH_UNIX_S, 0.0) * SIGNING_TICKS_PER_S)


class MavlinkEndpoint:
    """A MAVLink 2 endpoint (pymavlink ``ardupilotmega`` codec) on a :class:`Link`.

    ``on_frame(frame, sent)`` sees every frame sent and every frame accepted (for the tlog). Frames that
    fail the CRC or the signature check are counted (``bad_frames``, ``rejected_frames``), never raised.
    """

    def __init__(
        self,
        link: Link,
        *,
        system_id: int,
        component_id: int,
        signing: SigningConfig | None = None,
        on_frame: Callable[[bytes, bool], None] | None = None,
    ) -> None:
        self.link = link
        self._on_frame = on_frame
        self.mav = mavlink2.MAVLink(self, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.bad_frames = 0
        self.rejected_frames = 0
        self._backlog: deque[MavlinkMessage] = deque()
        if signing is not None:
            self.mav.signing.secret_key = signing.key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.link_id = signing.link_id
            self.mav.signing.timestamp = signing_timestamp_now()
            require = signing.require
            self.mav.signing.allow_unsigned_callback = lambda _mav, msg_id: (
                not require or msg_id == mavlink2.MAVLINK_MSG_ID_RADIO_STATUS
            )

    @property
    def system_id(self) -> int:
        return int(self.mav.srcSystem)

    @property
    def component_id(self) -> int:
        return int(self.mav.srcComponent)

    def write(self, frame: bytes) -> None:
        """File-like sink of pymavlink's ``MAVLink.send`` (one packed frame)."""
        self.link.send(frame)
        if self._on_frame is not None:
            self._on_frame(bytes(frame), True)

    def send(self, msg: MavlinkMessage) -> None:
        if self.mav.signing.sign_outgoing:
            self.mav.signing.timestamp = max(self.mav.signing.timestamp, signing_timestamp_now())
        self.mav.send(msg)

    def _parse(self, data: bytes) -> list[MavlinkMessage]:
        out: list[MavlinkMessage] = []
        for msg in self.mav.parse_buffer(data) or ():
            if msg.get_type() == "BAD_DATA":
                if "signature" in str(getattr(msg, "reason", "")):
                    self.rejected_frames += 1
                else:
                    self.bad_frames += 1
                continue
            if self._on_frame is not None:
                self._on_frame(bytes(msg.get_msgbuf()), False)
            out.append(msg)
        return out

    def poll(self, timeout_s: float) -> list[MavlinkMessage]:
        """Messages that arrived within ``timeout_s`` (returns as soon as at least one has)."""
        if self._backlog:
            out = list(self._backlog)
            self._backlog.clear()
            return out
        deadline = time.monotonic() + max(timeout_s, 0.0)
        while True:
            msgs = self._parse(self.link.recv(max(deadline - time.monotonic(), 0.0)))
            if msgs or time.monotonic() >= deadline:
                return msgs

    def recv_match(
        self,
        types: str | Iterable[str],
        timeout_s: float,
        condition: Callable[[MavlinkMessage], bool] | None = None,
    ) -> MavlinkMessage:
        """The next message of one of ``types`` (and satisfying ``condition``); ``TimeoutError`` past the deadline.

        Messages read past the match are kept for the next ``poll``/``recv_match``; others are dropped.
        """
        wanted = {types} if isinstance(types, str) else set(types)
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0 and not self._backlog:
                raise TimeoutError(f"no {'/'.join(sorted(wanted))} within {timeout_s:g} s on {self.link.description}")
            msgs = self.poll(max(remaining, 0.0))
            for i, msg in enumerate(msgs):
                if msg.get_type() in wanted and (condition is None or condition(msg)):
                    self._backlog.extend(msgs[i + 1 :])
                    return msg
