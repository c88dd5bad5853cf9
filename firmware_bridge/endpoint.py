"""A MAVLink 2 endpoint on a transport: pymavlink's generated ``ardupilotmega`` codec, constructed here
(not through ``mavutil``: no dialect globals, no environment variables), with optional signing.

Frames that fail the CRC are counted (``bad_frames``); with signing required, unsigned or badly signed
frames are counted (``rejected_unsigned``) and never reach the service.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.transport import Transport
from vdm_aero.errors import UserInputError

__all__ = ["MavEndpoint", "MavlinkMessage", "SigningKey", "load_signing_key"]

MavlinkMessage = Any  # pymavlink messages are untyped
SIGNING_KEY_BYTES = 32
SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01T00:00:00Z: the origin of MAVLink signing timestamps
SIGNING_TICKS_PER_S = 100_000  # 10 µs


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


class MavEndpoint:
    """Encode, sign and send; receive, check and decode. ``system_id``/``component_id`` are ours."""

    def __init__(self, transport: Transport, *, system_id: int, component_id: int, signing: SigningKey | None) -> None:
        self.transport = transport
        self.mav = mavlink2.MAVLink(self, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.bad_frames = 0
        self.rejected_unsigned = 0
        self.sent: dict[str, int] = {}
        self.received_at = 0.0
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
        """Messages decoded from what arrived within ``timeout_s`` (returns as soon as bytes arrive)."""
        data = self.transport.recv(timeout_s)
        self.received_at = time.monotonic()  # before decoding: latency is counted from the bytes' arrival
        if not data:
            return []
        out = []
        for msg in self.mav.parse_buffer(data) or ():
            if msg.get_type() == "BAD_DATA":
                if "signature" in str(getattr(msg, "reason", "")):
                    self.rejected_unsigned += 1
                else:
                    self.bad_frames += 1
                continue
            out.append(msg)
        return out
