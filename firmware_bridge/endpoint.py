"""A MAVLink 2 endpoint on a transport: pymavlink's generated ``ardupilotmega`` codec, constructed here
(not through ``mavutil``: no dialect globals, no environment variables), with optional signing.

**Framing** is ours, the decoding (CRC, signature, fields) pymavlink's. pymavlink's own parser trusts the
length byte of anything that starts with a magic byte: one stray ``0xFD`` in line noise swallows the next
255 + 12 bytes, valid frames included, and a frame of an unknown message id is returned without a CRC check.
Here a candidate frame that fails (unknown message id, bad flags, bad CRC) is skipped by one byte only and
the search for the next magic byte starts again, as a C parser that resynchronises does: every intact
frame after garbage is decoded. A candidate is held until its declared length has arrived, at most
:data:`MAX_FRAME_BYTES`.

**Duplicates.** A router with two routes to one endpoint (MAVProxy with two outputs, a mesh) delivers the
very same frame twice; a second copy of a port value would close its port frame early. A frame byte for
byte identical to one accepted from the same (system, component) with the same sequence number within
:data:`DUPLICATE_WINDOW_S` is dropped before it is decoded (so a signed copy is not taken for a forgery). A
frame with a reused sequence number (it wraps every 256 frames) but other bytes is a new frame, and so is an
identical one after the window (a 1 Hz HEARTBEAT can repeat its bytes and sequence number a second later).

**Counters.** ``bad_frames``: stretches of bytes between two good frames that are not a frame (garbage,
a truncated or corrupted frame, a frame of a message id we do not know: its CRC cannot be checked); each
stretch counts once. ``rejected_unsigned``: frames with a valid CRC but no or a bad signature while signing
is required; they never reach the service. ``rejected_replayed``: frames with a valid signature that
MAVLink signing's replay check refuses: a timestamp not newer than the last of their stream (a replay older
than the duplicate window, a frame overtaken on the link), or a new stream's a minute or more behind ours (a
signer whose clock is wrong). ``duplicate_frames``: copies dropped as above.
``lost_frames``: frames missing from the sequence numbers of each (system, component) source
(``lost_by_source``), as MAVProxy's link statistics count them: n numbers skipped (mod 256) count n; a
source's first frame counts nothing, and a duplicate never reaches the count. An old frame sent again late
(a buffering radio) is delivered (the decoder tells it is stale) and, from the sequence numbers alone, looks
like a gap: each one adds up to 255 to ``lost_frames``.

**Whose address replies go to** (``udpin``, where the peer is whoever sent; see
:meth:`MavEndpoint.poll`): the sender of a datagram that carried a frame of the autopilot — ``autopilot``,
its (system, component) as the owner of the endpoint identified it, or before that a vehicle's HEARTBEAT of
our own system id — and, with signing required, a signed one. A ground station, another companion, a
radio's RADIO_STATUS (allowed unsigned) or a stranger never steers them.

Limits: a candidate whose declared length reaches past the bytes received waits for them (a valid frame
behind a stray magic byte is decoded once up to 280 more bytes have come); a signed frame cut inside its
13-byte signature block, on a link without the key, takes that many bytes of the next frame as its
signature (the CRC does not cover the block): that next frame is lost, not the cut one. pymavlink checked
a signature only after storing its timestamp: one forged frame with a later timestamp locked the genuine
stream out; :class:`_Codec` compares the signature first.
"""

from __future__ import annotations

import bisect
import hashlib
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.transport import Transport
from vdm_aero.errors import UserInputError

__all__ = ["MAX_FRAME_BYTES", "MavEndpoint", "MavlinkMessage", "SigningKey", "load_signing_key"]

MavlinkMessage = Any  # pymavlink messages are untyped
SIGNING_KEY_BYTES = 32
SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01T00:00:00Z: the origin of MAVLink signing timestamps
SIGNING_TICKS_PER_S = 100_000  # 10 µs
SIGNATURE_BYTES = 6  # the signature proper: the last 6 of the 13-byte signature block
CRC_BYTES = 2
MAX_FRAME_BYTES = mavlink2.HEADER_LEN_V2 + 255 + CRC_BYTES + mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN  # 280
SEQ_MODULO = 256
# two routes' copies come milliseconds apart; a genuine frame with the bytes and the sequence number of one in
# the window would need a message without a time stamp (HEARTBEAT, RADIO_STATUS) sent faster than 2 Hz, alike,
# 256 frames of its source apart. Older copies (a radio re-sending a second late) are the decoder's stale frames
DUPLICATE_WINDOW_S = 0.5
DUPLICATE_MEMORY = 4096  # (source, seq) keys remembered, over all sources: 256 per source at most, by the seq
_NOT_VEHICLES = (mavlink2.MAV_TYPE_GCS, mavlink2.MAV_TYPE_ONBOARD_CONTROLLER)  # as the decoder's rule
_FRAME_START = re.compile(b"[\xfd\xfe]")  # MAVLink 2, MAVLink 1 magic
_REJECTED = object()  # a well-framed frame refused by the signature check


@dataclass(frozen=True)
class SigningKey:
    key: bytes
    require: bool
    link_id: int = 0


def load_signing_key(path: Path, *, require: bool) -> SigningKey:
    """A 32-byte key file: 32 raw bytes, or 64 hex digits (whitespace ignored)."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise UserInputError(f"{path}: cannot read the signing key: {e.strerror or e}") from None
    key = raw
    if len(raw) != SIGNING_KEY_BYTES:
        try:
            key = bytes.fromhex(raw.decode("ascii").strip())
        except (UnicodeDecodeError, ValueError):
            key = b""
    if len(key) != SIGNING_KEY_BYTES:
        raise UserInputError(f"{path}: a MAVLink 2 signing key is 32 raw bytes or 64 hex digits")
    return SigningKey(key, require)


def _signing_now() -> int:
    return int(max(time.time() - SIGNING_EPOCH_UNIX_S, 0.0) * SIGNING_TICKS_PER_S)


class _Codec(mavlink2.MAVLink):
    stale_signature = False  # the last signature checked was right but its timestamp not newer (a replay)

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:
        """pymavlink stores a stream's timestamp before it compares the signature: one frame with a bad
        signature and a far-future timestamp would then lock the genuine stream out. Compare first."""
        key = self.signing.secret_key
        assert key is not None
        signature = hashlib.sha256(key + bytes(msgbuf[:-SIGNATURE_BYTES])).digest()[:SIGNATURE_BYTES]
        self.stale_signature = False
        if signature != msgbuf[-SIGNATURE_BYTES:]:
            return False
        ok = bool(super().check_signature(msgbuf, srcSystem, srcComponent))
        self.stale_signature = not ok  # the key signed it: only the timestamp check can have refused it
        return ok


class MavEndpoint:
    """Encode, sign and send; receive, frame, check and decode. ``system_id``/``component_id`` are ours."""

    def __init__(self, transport: Transport, *, system_id: int, component_id: int, signing: SigningKey | None) -> None:
        self.transport = transport
        self.mav = _Codec(self, srcSystem=system_id, srcComponent=component_id)
        self.bad_frames = 0
        self.rejected_unsigned = 0
        self.rejected_replayed = 0
        self.duplicate_frames = 0
        self.lost_frames = 0
        self.lost_by_source: dict[tuple[int, int], int] = {}
        self.sent: dict[str, int] = {}
        self.received_at = 0.0  # when the first bytes of the last poll arrived (monotonic [s])
        self.arrived: list[float] = []  # when each message the last poll returned arrived (monotonic [s])
        # (system, component) of the autopilot, set by the endpoint's owner once identified: only its frames
        # name the address replies go to (module docstring)
        self.autopilot: tuple[int, int] | None = None
        self._require_signed = signing is not None and signing.require
        self._rx = bytearray()  # bytes of a frame not complete yet (at most MAX_FRAME_BYTES - 1)
        self._in_sync = True  # False from the first byte of a bad stretch to the next good frame
        self._last_seq: dict[tuple[int, int], int] = {}
        # (system, component, seq) → (the frame, its arrival time), oldest first, of accepted frames
        self._recent: dict[tuple[int, int, int], tuple[bytes, float]] = {}
        if signing is not None:
            s = self.mav.signing
            s.secret_key = signing.key
            s.sign_outgoing = True
            s.link_id = signing.link_id
            s.timestamp = _signing_now()
            require = signing.require
            # ArduPilot's rule: RADIO_STATUS from a radio may come unsigned
            s.allow_unsigned_callback = lambda _mav, msg_id: (
                not require or msg_id == mavlink2.MAVLINK_MSG_ID_RADIO_STATUS
            )

    @property
    def pending_bytes(self) -> int:
        """Bytes received but not decided yet: the start of a frame still arriving (< MAX_FRAME_BYTES)."""
        return len(self._rx)

    def write(self, frame: bytes) -> None:
        """The file-like sink of ``MAVLink.send``."""
        self.transport.send(bytes(frame))

    def send(self, msg: MavlinkMessage) -> None:
        if self.mav.signing.sign_outgoing:
            self.mav.signing.timestamp = max(self.mav.signing.timestamp, _signing_now())
        self.mav.send(msg)
        kind = msg.get_type()
        self.sent[kind] = self.sent.get(kind, 0) + 1

    def poll(self, timeout_s: float) -> list[MavlinkMessage]:
        """Messages decoded from what arrived within ``timeout_s`` (returns as soon as bytes arrive).

        When they include a frame of the autopilot (module docstring), the transport is told that their
        sender is the peer (``confirm_peer``: ``udpin`` replies go there from now on)."""
        data = self.transport.recv(timeout_s)
        # latency is counted from the bytes' arrival: the kernel's stamp of each datagram where the link has them
        # (the time they waited in the socket while the service was busy counts), else now, before decoding
        marks: list[tuple[int, float]] = getattr(self.transport, "arrivals", None) or []
        self.received_at = marks[0][1] if marks else time.monotonic()
        self.arrived = []
        if not data:
            return []
        buf = self._rx
        base = len(buf)  # bytes of an earlier read still waiting for the rest of their frame
        buf += data
        out = []
        i, n = 0, len(buf)
        while i < n:
            if buf[i] != mavlink2.PROTOCOL_MARKER_V2 and buf[i] != mavlink2.PROTOCOL_MARKER_V1:
                m = _FRAME_START.search(buf, i)
                i = m.start() if m is not None else n
                self._lost_sync()
                continue
            size = _frame_size(buf, i, n)
            if size is None:
                break  # the rest of this frame has not arrived yet
            frame = buf[i : i + size]
            key = self._key(frame) if size else (0, 0, 0)
            if size and self._duplicate(frame, key):  # before decoding: a signed copy is not a forgery
                self.duplicate_frames += 1
                self._in_sync = True
                i += size
                continue
            msg = self._decode(frame) if size else None
            if msg is None:  # not a frame: resynchronise from the next byte
                self._lost_sync()
                i += 1
                continue
            self._in_sync = True
            i += size
            if msg is not _REJECTED:
                self._count_sequence(key)
                self._remember(frame, key)
                out.append(msg)
                self.arrived.append(self._arrival(marks, i - base))
        del buf[:i]
        if any(map(self._names_the_peer, out)):
            confirm: Callable[[], None] | None = getattr(self.transport, "confirm_peer", None)
            if confirm is not None:
                confirm()
        return out

    def read_horizon(self) -> float:
        """The monotonic time [s] before which everything that reached this host has been decoded: a port frame
        still missing values by then is partial; after it, its values may be waiting in a backlog (a busy
        service, a second route's turn). A link that cannot tell (a test double) says now."""
        horizon: Callable[[], float] | None = getattr(self.transport, "read_horizon", None)
        return horizon() if horizon is not None else time.monotonic()

    def _arrival(self, marks: list[tuple[int, float]], end: int) -> float:
        """When the datagram holding the frame that ends at byte ``end`` of this read arrived."""
        k = bisect.bisect_left(marks, end, key=lambda m: m[0])
        return marks[k][1] if k < len(marks) else self.received_at

    def _names_the_peer(self, msg: MavlinkMessage) -> bool:
        """Whether ``msg`` is the autopilot's, so that its sender's address is the one to reply to."""
        if self._require_signed and not msg.get_signed():
            return False  # RADIO_STATUS, allowed unsigned, never steers replies
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.autopilot is not None:
            return src == self.autopilot
        # not identified yet: the autopilot component's HEARTBEAT in our system (a companion joins its vehicle's
        # system)
        return (
            msg.get_type() == "HEARTBEAT"
            and src == (self.mav.srcSystem, mavlink2.MAV_COMP_ID_AUTOPILOT1)
            and msg.type not in _NOT_VEHICLES
            and msg.autopilot != mavlink2.MAV_AUTOPILOT_INVALID
        )

    @staticmethod
    def _key(frame: bytearray) -> tuple[int, int, int]:
        """(system, component, seq) from a frame's header."""
        if frame[0] == mavlink2.PROTOCOL_MARKER_V2:
            return frame[5], frame[6], frame[4]
        return frame[3], frame[4], frame[2]

    def _duplicate(self, frame: bytearray, key: tuple[int, int, int]) -> bool:
        """Whether ``frame`` (header :meth:`_key`) is a copy of one accepted within :data:`DUPLICATE_WINDOW_S`
        (module docstring)."""
        seen = self._recent.get(key)
        return seen is not None and seen[0] == frame and self.received_at - seen[1] <= DUPLICATE_WINDOW_S

    def _remember(self, frame: bytearray, key: tuple[int, int, int]) -> None:
        self._recent.pop(key, None)  # re-inserted last: the dict stays in arrival order
        self._recent[key] = (bytes(frame), self.received_at)
        if len(self._recent) > DUPLICATE_MEMORY:
            del self._recent[next(iter(self._recent))]

    def _lost_sync(self) -> None:
        if self._in_sync:
            self._in_sync = False
            self.bad_frames += 1

    def _decode(self, frame: bytearray) -> MavlinkMessage | None:
        """The message; :data:`_REJECTED` for a frame refused by the signature check; None if not a frame."""
        self.mav.stale_signature = False  # an unsigned frame is never checked: no verdict of an earlier one
        try:
            return self.mav.decode(frame)
        except mavlink2.MAVError as e:
            if e.message == "Invalid signature":  # raised only after the CRC has passed: a frame, refused
                if self.mav.stale_signature:
                    self.rejected_replayed += 1
                else:
                    self.rejected_unsigned += 1
                return _REJECTED
            return None

    def _count_sequence(self, key: tuple[int, int, int]) -> None:
        """Frames lost from a source, from an accepted frame's header (system, component, sequence)."""
        src, seq = key[:2], key[2]
        last = self._last_seq.get(src)
        self._last_seq[src] = seq
        if last is None or seq == last:
            return
        gap = (seq - last - 1) % SEQ_MODULO
        if gap:
            self.lost_frames += gap
            self.lost_by_source[src] = self.lost_by_source.get(src, 0) + gap


def _frame_size(buf: bytearray, i: int, n: int) -> int | None:
    """The length of the candidate frame at ``buf[i]`` (a magic byte): 0 when its header rules out a frame
    (flags we do not know, a message id not in the dialect, a MAVLink 1 payload longer than the message),
    None while its header or body is incomplete. MAVLink 2 payloads may be longer than our definition of the
    message (extension fields a newer dialect added): they are decoded, the unknown fields dropped."""
    if buf[i] == mavlink2.PROTOCOL_MARKER_V2:
        if n - i < mavlink2.HEADER_LEN_V2:
            return None
        flags = buf[i + 2]
        msg_id = buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16
        if flags & ~mavlink2.MAVLINK_IFLAG_SIGNED or msg_id not in mavlink2.mavlink_map:
            return 0
        size = mavlink2.HEADER_LEN_V2 + buf[i + 1] + CRC_BYTES
        if flags & mavlink2.MAVLINK_IFLAG_SIGNED:
            size += mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN
    else:
        if n - i < mavlink2.HEADER_LEN_V1:
            return None
        msg_type = mavlink2.mavlink_map.get(buf[i + 5])
        if msg_type is None or buf[i + 1] > msg_type.unpacker.size:  # MAVLink 1 carries no extension fields
            return 0
        size = mavlink2.HEADER_LEN_V1 + buf[i + 1] + CRC_BYTES
    return size if n - i >= size else None
