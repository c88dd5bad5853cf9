"""The service's MAVLink link as links really are (issue 23, "links as they are"): a router that duplicates
frames, a signed frame replayed, a second sender on the service's UDP port, the autopilot's TIMESYNC
requests, and a shutdown that says what it saved.

The endpoint tests feed bytes through a stand-in transport; the service tests run a
:class:`~firmware_bridge.service.CompanionService` on its ``udpin`` socket, with the autopilot, a second route
and a stranger as UDP sockets of the test."""

from __future__ import annotations

import io
import socket
import threading
import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge import endpoint
from firmware_bridge.endpoint import MavEndpoint, SigningKey
from tests.test_fault_inputs import _Autopilot, _drain, _FeedLink, _service_config, _warm_service

SIGNING_EPOCH_UNIX_S = 1420070400  # MAVLink signing time: 10 µs ticks since 2015-01-01
KEY = bytes(range(32))
AUTOPILOT = (1, 1)
SERVICE = (1, 191)


def _signer(src: tuple[int, int], key: bytes | None = None) -> Any:
    """A MAVLink 2 codec sending as ``src``; signing its frames with ``key`` when given."""
    mav = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    if key is not None:
        s = mav.signing
        s.secret_key, s.sign_outgoing = key, True
        s.timestamp = int((time.time() - SIGNING_EPOCH_UNIX_S) * 100_000)
    return mav


def _pack(mav: Any, msg: Any) -> bytes:
    """``msg`` as ``mav`` sends it: packed with its next sequence number (``pack`` alone does not count)."""
    frame = bytes(msg.pack(mav))
    mav.seq = (mav.seq + 1) % 256
    return frame


def _vehicle_heartbeat(mav: Any) -> Any:
    return mav.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)


# ------------------------------------------------------------------------------------------- arrival
def test_a_frame_that_waited_in_the_socket_counts_its_wait() -> None:
    """The service's latency runs from a frame's arrival at this host: a frame that waited in the socket while
    the service was busy (here 150 ms) is stamped with the kernel's arrival time, not the time it was read."""
    from firmware_bridge.transport import open_transport

    link = open_transport("udpin://127.0.0.1:0")
    ep = MavEndpoint(link, system_id=1, component_id=191, signing=None)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mav = _signer(AUTOPILOT)
        # the kernel turns receive stamping on a moment after the first socket asks (a deferred static key):
        # until then it stamps a datagram when it is read. The service's socket lives for hours; warm up
        tx.sendto(_pack(mav, _vehicle_heartbeat(mav)), link.local_address)
        ep.poll(1.0)
        time.sleep(0.05)
        sent_at = time.monotonic()
        tx.sendto(_pack(mav, _vehicle_heartbeat(mav)), link.local_address)
        time.sleep(0.15)  # busy elsewhere
        msgs = ep.poll(1.0)
        read_at = time.monotonic()
        assert [m.get_type() for m in msgs] == ["HEARTBEAT"]
        assert sent_at - 0.005 <= ep.received_at <= sent_at + 0.05 < read_at - 0.1
        assert ep.arrived == [ep.received_at]
        # two datagrams read together: each message is stamped with its own datagram's arrival
        tx.sendto(_pack(mav, _vehicle_heartbeat(mav)), link.local_address)
        time.sleep(0.1)
        two = [_pack(mav, mav.named_value_float_encode(1000, f"P0{k}".encode(), 1.0)) for k in range(2)]
        tx.sendto(b"".join(two), link.local_address)  # two frames in one datagram, as a router may pack them
        time.sleep(0.05)
        msgs = ep.poll(1.0)
        assert [m.get_type() for m in msgs] == ["HEARTBEAT", "NAMED_VALUE_FLOAT", "NAMED_VALUE_FLOAT"]
        first, second, third = ep.arrived
        assert ep.received_at == first and 0.09 <= second - first <= 0.15 and third == second
        assert time.monotonic() - second >= 0.04
    finally:
        tx.close()
        link.close()


# ------------------------------------------------------------------------------------------- duplicates
def test_a_duplicating_router_delivers_each_frame_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """300 port values (12 ports, 25 frames: the 8-bit sequence number wraps), each delivered by two routes,
    the second 0-4 frames later, cut at arbitrary read boundaries: each is decoded once, in order, and the
    copies are counted as duplicates, not as lost, bad or unsigned frames. Value k and value k + 256 share a
    sequence number and differ: both are kept. An identical frame after the duplicate window (a 1 Hz HEARTBEAT
    can repeat its bytes and sequence number a second later) is a new frame too."""
    ap = _signer(AUTOPILOT)
    n = 300
    frames = [
        _pack(ap, ap.named_value_float_encode(10_000 + 10 * (k // 12), f"P{k % 12:02d}".encode(), float(k)))
        for k in range(n)
    ]
    # (arrival slot, route, frame): route A delivers frame k in slot k, route B in slot k + k % 5
    events = sorted([(k, 0, f) for k, f in enumerate(frames)] + [(k + k % 5, 1, f) for k, f in enumerate(frames)])
    data = b"".join(f for _, _, f in events)
    link = _FeedLink([data[a : a + 97] for a in range(0, len(data), 97)])  # frames cut across reads
    ep = MavEndpoint(link, system_id=1, component_id=191, signing=None)
    got = _drain(ep, link)
    assert [m.value for m in got] == [float(k) for k in range(n)]
    assert got[0].get_seq() == got[256].get_seq() and got[0].value != got[256].value  # the wrap: both kept
    assert ep.duplicate_frames == n
    assert (ep.lost_frames, ep.bad_frames, ep.rejected_unsigned, ep.pending_bytes) == (0, 0, 0, 0)

    # the same bytes again after the window: a genuine frame whose sequence number came round again, kept
    clock = [1000.0]
    monkeypatch.setattr(endpoint, "time", types.SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    hb_only = _signer((1, 2))
    hb_only.seq = 7
    hb = bytes(_vehicle_heartbeat(hb_only).pack(hb_only))
    link.chunks = [hb, hb]
    assert len(_drain(ep, link)) == 1 and ep.duplicate_frames == n + 1  # a copy within the window
    clock[0] += 1.0  # > DUPLICATE_WINDOW_S
    link.chunks = [hb]
    assert len(_drain(ep, link)) == 1 and ep.duplicate_frames == n + 1


def test_a_replayed_signed_frame_is_a_duplicate_or_a_replay_never_unsigned(monkeypatch: pytest.MonkeyPatch) -> None:
    """Signing required: a byte-identical copy of an accepted signed frame is counted in ``duplicate_frames``
    (found before the signature check, which would refuse its timestamp); replayed after the duplicate window
    it is refused by signing's replay check and counted in ``rejected_replayed``. Only frames without a
    valid signature are ``rejected_unsigned``."""
    clock = [50.0]
    monkeypatch.setattr(endpoint, "time", types.SimpleNamespace(monotonic=lambda: clock[0], time=time.time))
    link = _FeedLink()
    ep = MavEndpoint(link, system_id=1, component_id=191, signing=SigningKey(KEY, require=True))
    ap = _signer(AUTOPILOT, KEY)
    signed = _pack(ap, ap.named_value_float_encode(1000, b"P00", 12.5))
    link.chunks = [signed, signed]
    (msg,) = _drain(ep, link)
    assert msg.value == 12.5 and msg.get_signed()
    assert (ep.duplicate_frames, ep.rejected_unsigned, ep.rejected_replayed) == (1, 0, 0)
    clock[0] += 10.0  # long after the window: no longer a duplicate, a replay
    link.chunks = [signed]
    assert _drain(ep, link) == []
    assert (ep.duplicate_frames, ep.rejected_unsigned, ep.rejected_replayed) == (1, 0, 1)
    unsigned = _signer(AUTOPILOT)
    link.chunks = [bytes(unsigned.named_value_float_encode(1000, b"P00", 12.5).pack(unsigned))]
    assert _drain(ep, link) == []
    assert (ep.duplicate_frames, ep.rejected_unsigned, ep.rejected_replayed) == (1, 1, 1)
    assert ep.lost_frames == 0


# ------------------------------------------------------------------------------------ the service's link
@pytest.fixture(scope="module")
def models(design_deim12: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Any:
    from vdm_aero.nav.models import NavModels

    cfg = _service_config(tmp_path_factory.mktemp("links-models"), design_deim12, "models", {})
    return NavModels.load(cfg.design_data, cfg.deim_model, None, cfg.vehicle)


@pytest.fixture
def udp() -> Iterator[dict[str, socket.socket]]:
    """The autopilot, a second route to the service and a stranger: UDP sockets on the loopback."""
    socks = {name: socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for name in ("ap", "route2", "stranger")}
    for s in socks.values():
        s.bind(("127.0.0.1", 0))
    yield socks
    for s in socks.values():
        s.close()


def _discard_queued(sock: socket.socket) -> None:
    sock.setblocking(False)
    try:
        while True:
            sock.recv(512)
    except BlockingIOError:
        return


def _wait(cond: Any, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


def test_duplicated_port_values_never_split_a_port_frame(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path, udp: dict[str, socket.socket]
) -> None:
    """A router with two routes to the service's UDP port delivers every port value twice: every port frame
    is assembled complete, none is closed early as partial, and the copies are counted."""
    from firmware_bridge.service import CompanionService

    cfg = _service_config(tmp_path, design_deim12, "dup", {})
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    try:
        to = ("127.0.0.1", svc.transport.local_address[1])
        ap = _signer(AUTOPILOT)
        udp["ap"].sendto(_pack(ap, _vehicle_heartbeat(ap)), to)
        n_frames = 20
        for j in range(n_frames):
            for name in svc.port_names:
                f = _pack(ap, ap.named_value_float_encode(20_000 + 10 * j, name.encode(), -50.0 + j))
                udp["ap"].sendto(f, to)
                udp["route2"].sendto(f, to)
        got, expected = 0, 1 + n_frames * len(svc.port_names)
        end = time.monotonic() + 5.0
        while time.monotonic() < end:  # everything sent, and 0.3 s more for any copy still on its way
            msgs = svc.ep.poll(0.05)
            for m in msgs:
                svc._dispatch(m, svc.ep.received_at)
            got += len(msgs)
            if got >= expected:
                end = min(end, time.monotonic() + 0.3)
        counts = svc.assembler.counts
        assert (counts["complete"], counts["partial"]) == (n_frames, 0), counts
        assert got == expected
        assert svc.ep.duplicate_frames == n_frames * len(svc.port_names)
        s = svc.summary()
        assert s["duplicate_frames"] == svc.ep.duplicate_frames and s["lost_frames"] == 0
    finally:
        svc.transport.close()


def test_the_udp_read_horizon_stops_at_the_oldest_datagram_not_yet_returned(udp: dict[str, socket.socket]) -> None:
    """Two senders interleaved: ``recv`` returns one sender's run, and the horizon is the arrival of the
    datagram left queued, however long the reader took; once all is read and the socket is found empty, it is
    the time of that look."""
    from firmware_bridge.transport import open_transport

    link = open_transport("udpin://127.0.0.1:0")
    try:
        # the kernel stamps datagrams on arrival a moment after the first socket asks (see above): warm up
        udp["ap"].sendto(b"warm", link.local_address)
        _wait(lambda: link.recv(0.05) == b"warm", 2.0, "the first datagram")
        time.sleep(0.05)
        sent_at = time.monotonic()
        udp["ap"].sendto(b"a1", link.local_address)
        udp["route2"].sendto(b"b1", link.local_address)
        udp["ap"].sendto(b"a2", link.local_address)
        time.sleep(0.2)  # the reader busy elsewhere
        read_at = time.monotonic()
        assert link.recv(0.5) == b"a1"
        assert sent_at <= link.read_horizon() <= sent_at + 0.05 < read_at - 0.1  # b1 waits: it came then
        assert link.recv(0.5) == b"b1" and link.recv(0.5) == b"a2"
        # all returned: the horizon is when the first read found the socket empty behind the three
        assert read_at <= link.read_horizon() <= read_at + 0.05
        before = time.monotonic()
        assert link.recv(0.01) == b""
        assert before <= link.read_horizon() <= time.monotonic()
    finally:
        link.close()


def test_a_backlog_never_splits_a_port_frame(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path, udp: dict[str, socket.socket]
) -> None:
    """A frame's values all came within a millisecond by two routes, while the service was busy four times the
    frame timeout: read one datagram at a time (each route's turn), with the loop's upkeep between reads, the
    frame is complete (it was closed as partial when the timeout was judged on the clock). A frame whose last
    value never comes is still closed partial once the link has been read past its timeout."""
    from firmware_bridge.service import CompanionService

    cfg = _service_config(tmp_path, design_deim12, "backlog", {})
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    timeout_s = cfg.ports.frame_timeout_s

    def serve(seconds: float) -> None:  # the service's loop: poll, dispatch, upkeep
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for m, t_in in zip(svc.ep.poll(0.01), svc.ep.arrived, strict=True):
                svc._dispatch(m, t_in)
            svc._upkeep(time.monotonic())

    try:
        to = ("127.0.0.1", svc.transport.local_address[1])
        ap = _signer(AUTOPILOT)
        udp["ap"].sendto(_pack(ap, _vehicle_heartbeat(ap)), to)
        serve(0.2)
        for name in svc.port_names:
            f = _pack(ap, ap.named_value_float_encode(30_000, name.encode(), -40.0))
            udp["ap"].sendto(f, to)
            udp["route2"].sendto(f, to)
        time.sleep(4.0 * timeout_s)
        serve(0.3)
        counts = svc.assembler.counts
        assert (counts["complete"], counts["partial"]) == (1, 0), counts
        assert svc.ep.duplicate_frames == len(svc.port_names)
        for name in svc.port_names[:-1]:  # the next frame's last port never comes
            udp["ap"].sendto(_pack(ap, ap.named_value_float_encode(30_010, name.encode(), -40.0)), to)
        serve(4.0 * timeout_s)
        assert (counts["complete"], counts["partial"]) == (1, 1), counts
    finally:
        svc.transport.close()


@pytest.mark.parametrize("signing", [False, True], ids=["unsigned-link", "signing-required"])
def test_outputs_go_only_to_the_autopilots_address(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path, udp: dict[str, socket.socket], signing: bool
) -> None:
    """The autopilot is heard from one UDP port; then a stranger sends from another: a ground station's
    HEARTBEAT, a radio's RADIO_STATUS (unsigned: signing allows it, as ArduPilot does), a NAMED_VALUE_FLOAT
    of another system and a vehicle HEARTBEAT of component 2 claiming to be the autopilot — with signing
    required, all but the RADIO_STATUS signed with the link's key, as a ground station on the link has it.
    The service's next outputs still go to the autopilot's address; nothing is ever sent to the stranger."""
    from firmware_bridge.service import CompanionService

    edits: dict[str, Any] = {}
    key = None
    if signing:
        key_file = tmp_path / "key"
        key_file.write_text(KEY.hex())
        edits = {"signing.key_file": str(key_file), "signing.require": True}
        key = KEY
    cfg = _service_config(tmp_path, design_deim12, "peer", edits)
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    to = ("127.0.0.1", svc.transport.local_address[1])
    stop = threading.Event()
    worker = threading.Thread(target=svc.run, args=(stop.is_set,), daemon=True)
    worker.start()
    try:
        ap_sock, stranger = udp["ap"], udp["stranger"]
        ap = _signer(AUTOPILOT, key)
        ap_sock.sendto(_pack(ap, _vehicle_heartbeat(ap)), to)
        ap_sock.settimeout(3.0)
        assert ap_sock.recv(512)  # the service answers the autopilot (stream requests, HEARTBEAT)
        _wait(lambda: svc.decoder.autopilot == AUTOPILOT, 2.0, "the service to identify the autopilot")

        before = sum(svc.stats.received.values()) + svc.ep.rejected_unsigned
        gcs, radio, other, comp2 = (
            _signer((255, 190), key),
            _signer((51, 68)),
            _signer((2, 1), key),
            _signer((1, 2), key),
        )
        for f in (
            _pack(gcs, gcs.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 4)),
            _pack(radio, radio.radio_status_encode(200, 190, 100, 40, 45, 0, 0)),
            _pack(other, other.named_value_float_encode(1000, b"P00", 99.0)),
            _pack(comp2, _vehicle_heartbeat(comp2)),
        ):
            stranger.sendto(f, to)
        _wait(lambda: sum(svc.stats.received.values()) + svc.ep.rejected_unsigned >= before + 4, 3.0,
              "the service to read the stranger's frames")  # fmt: skip
        assert svc.stats.received.get("RADIO_STATUS") == 1 and svc.ep.rejected_unsigned == 0

        _discard_queued(ap_sock)  # what the service sent before the stranger spoke
        ap_sock.settimeout(2.0)  # the next output: at least the 1 Hz HEARTBEAT
        rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        (msg,) = rx.parse_buffer(ap_sock.recv(512))
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == SERVICE
        stranger.settimeout(0.2)
        with pytest.raises(TimeoutError):
            stranger.recv(512)
    finally:
        stop.set()
        worker.join(5.0)
    assert not worker.is_alive()


# ------------------------------------------------------------------------------------------------ TIMESYNC
def test_a_timesync_request_of_the_autopilot_is_answered(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path
) -> None:
    """TIMESYNC with tc1 = 0 from the autopilot (ArduPilot and PX4 send these) is answered: tc1 our monotonic
    clock [ns], ts1 echoed. A request of another component is not; the autopilot's reply to our own request
    (tc1 ≠ 0) still sets the clock offset and is not answered."""
    from firmware_bridge.service import CompanionService

    cfg = _service_config(tmp_path, design_deim12, "timesync", {})
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    link = _FeedLink()
    svc.ep.transport = link  # what the endpoint sends, kept
    try:
        ap = _Autopilot()
        svc._dispatch(ap(_vehicle_heartbeat(ap.tx)), 1.0)
        ts1 = 123_456_789_000
        t0 = time.monotonic_ns()
        svc._dispatch(ap(ap.tx.timesync_encode(0, ts1)), 1.1)
        t1 = time.monotonic_ns()
        rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        (reply,) = [m for m in rx.parse_buffer(b"".join(link.sent)) or [] if m.get_type() == "TIMESYNC"]
        assert reply.ts1 == ts1 and t0 <= reply.tc1 <= t1
        assert (reply.get_srcSystem(), reply.get_srcComponent()) == SERVICE
        n = len(link.sent)
        svc._dispatch(ap(ap.tx.timesync_encode(0, ts1), src=(255, 190)), 1.2)  # a ground station's request
        ours = time.monotonic_ns() - 5_000_000  # our request, sent 5 ms ago
        svc._dispatch(ap(ap.tx.timesync_encode(42_000_000_000, ours)), 1.3)
        assert len(link.sent) == n
        assert svc.clock.offset_s is not None and svc.clock.offset_s == pytest.approx(42.0 - ours * 1e-9, abs=0.1)
    finally:
        svc.transport.close()


def test_a_command_to_the_service_is_answered_unsupported(design_deim12: dict[str, Path], models: Any,
                                                          tmp_path: Path) -> None:  # fmt: skip
    """A COMMAND_LONG or COMMAND_INT addressed to the service (system 1, component 191) gets a COMMAND_ACK
    MAV_RESULT_UNSUPPORTED back to its sender (the service carries out no command); one to another
    component gets nothing."""
    from firmware_bridge.service import CompanionService

    cfg = _service_config(tmp_path, design_deim12, "commands", {})
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    link = _FeedLink()
    svc.ep.transport = link
    try:
        ap = _Autopilot()
        reboot = mavlink2.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
        svc._dispatch(ap(ap.tx.command_long_encode(1, 191, reboot, 0, 1, 0, 0, 0, 0, 0, 0), src=(255, 190)), 1.0)
        svc._dispatch(ap(ap.tx.command_int_encode(1, 191, 0, mavlink2.MAV_CMD_DO_SET_MODE, 0, 0, 0, 0, 0, 0,
                                                  0, 0, 0)), 1.1)  # fmt: skip
        svc._dispatch(ap(ap.tx.command_long_encode(1, 1, reboot, 0, 1, 0, 0, 0, 0, 0, 0), src=(255, 190)), 1.2)
        rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        acks = [m for m in rx.parse_buffer(b"".join(link.sent)) or [] if m.get_type() == "COMMAND_ACK"]
        assert [(a.command, a.result, a.target_system, a.target_component) for a in acks] == [
            (reboot, mavlink2.MAV_RESULT_UNSUPPORTED, 255, 190),
            (mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_RESULT_UNSUPPORTED, 1, 1),
        ]
        assert svc.summary()["commands_refused"] == 2
    finally:
        svc.transport.close()


# ---------------------------------------------------------------------------------------- the state file
def test_shutdown_says_saved_only_when_the_state_file_was_written(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path
) -> None:
    """At shutdown the service says what happened to the filter state: nothing to save when the filter
    never initialised (no file written), saved when it was written, NOT saved when the write failed."""
    from firmware_bridge.service import CompanionService

    cfg = _service_config(tmp_path, design_deim12, "never", {})
    log = io.StringIO()
    svc = CompanionService(cfg, out=log, models=models)
    svc.run(lambda: True)
    out = log.getvalue()
    assert "no filter state to save (the filter is not initialised)" in out and "state saved" not in out
    assert not cfg.state_file.exists() and svc.summary()["state_saves"] == 0

    results = {}
    for case in ("writable", "blocked"):
        cfg = _service_config(tmp_path, design_deim12, case, {})
        svc = _warm_service(cfg, models, _Autopilot())
        assert svc.filter is not None and svc.filter.initialised
        if case == "blocked":  # the state directory is a file: the write fails
            (tmp_path / "not-a-dir").write_text("")
            svc.store.path = tmp_path / "not-a-dir" / "state.npz"
        svc.run(lambda: True)
        results[case] = (svc.out.getvalue(), svc.store.path, svc.summary()["state_saves"])
    out, path, saves = results["writable"]
    assert f"vdm-aero serve: filter state saved to {path}" in out and path.is_file() and saves == 1
    out, path, saves = results["blocked"]
    assert "filter state NOT saved to" in out and "filter state saved" not in out and saves == 0
    assert not path.exists()


def test_a_quiet_link_after_the_autopilot_is_lost_does_not_spin_the_loop(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path, udp: dict[str, socket.socket]
) -> None:
    """An autopilot heard, its periodic link upkeep (TIMESYNC, stream checks) scheduled, then silent: those
    tasks stop being done while it is lost, and their passed due times must not make the loop poll with a zero
    timeout (it spun at 60 % of a core, measured, until the service was stopped)."""
    from firmware_bridge.service import AUTOPILOT_LOST_S, POLL_MAX_S, CompanionService

    cfg = _service_config(tmp_path, design_deim12, "quiet", {})
    svc = CompanionService(cfg, out=io.StringIO(), models=models)
    to = ("127.0.0.1", svc.transport.local_address[1])
    ap = _signer(AUTOPILOT)
    udp["ap"].sendto(_pack(ap, _vehicle_heartbeat(ap)), to)
    _wait(lambda: [svc._dispatch(m, svc.ep.received_at) for m in svc.ep.poll(0.05)] and svc.autopilot is not None,
          5.0, "the autopilot's HEARTBEAT")  # fmt: skip
    now = time.monotonic()
    svc._periodic(now)  # TIMESYNC and the stream check scheduled (due again in 1 s and 3 s)
    assert {"timesync", "streams"} <= set(svc._next)
    svc._last_ap_heartbeat = now - AUTOPILOT_LOST_S - 1.0  # lost: those two are no longer done
    later = now + 10.0
    assert svc.poll_timeout(later) == pytest.approx(POLL_MAX_S)
    end = time.monotonic() + 1.0
    cpu0 = time.thread_time()
    svc.run(lambda: time.monotonic() > end)  # one second of a quiet link, in this thread
    assert time.thread_time() - cpu0 < 0.3, "the loop spun while the link was quiet"
