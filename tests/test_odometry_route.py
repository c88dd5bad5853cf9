"""ArduPilot's ExternalNav route: the ODOMETRY encoder read back as ``GCS_MAVLINK::handle_odometry`` reads it
(libraries/GCS_MAVLink/GCS_Common.cpp, AP_VisualOdom_MAV.cpp), the ``outputs.source_switch`` config and its
one-line errors, and the EKF3 source-set switch (MAV_CMD_SET_EKF_SOURCE_SET, 42007) driven by a fake clock:
alone, and wired into the service with a feed transport.

The expected numbers are worked out by hand in the comments, not by the code under test."""

from __future__ import annotations

import itertools
import math
import random
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from firmware_bridge.config import ConfigError, SourceSwitchConfig, load_config
from firmware_bridge.outputs import Solution, ardupilot_odometry, odometry_quality, set_ekf_source_set
from firmware_bridge.service import EkfSourceSwitch
from tests.test_service_parts import _config, _roundtrip

MAV_FRAME_LOCAL_FRD = 20  # the only frame_id handle_odometry takes
MAV_FRAME_BODY_FRD = 12  # the only child_frame_id it takes
SET_EKF_SOURCE_SET = 42007


def _solution(**kw: Any) -> Solution:
    base = Solution(boot_s=212.5, unix_s=1_790_000_000.25, lat_deg=42.2830335, lon_deg=-71.3500307, alt_m=155.6,
                    p_ned_m=np.array([10.0, -20.0, -105.0]), v_ned_m_s=np.array([18.0, -3.0, 0.5]),
                    q_nb=np.array([1.0, 0.0, 0.0, 0.0]), sigma_h_m=12.0, sigma_v_m=2.0, sigma_vel_m_s=0.8,
                    wind_ned_m_s=np.array([-6.0, 6.0, 0.0]), sigma_wind_m_s=0.5, fix_type=3)  # fmt: skip
    return replace(base, **kw)


def _rotate(q: list[float], v: tuple[float, float, float]) -> tuple[float, float, float]:
    """q ⊗ v ⊗ q*, written out (ArduPilot's ``vel = q * vel``), independent of vdm_aero.rotation."""
    w, x, y, z = q
    vx, vy, vz = v
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty, vy + w * ty + z * tx - x * tz, vz + w * tz + x * ty - y * tx)


# ---------------------------------------------------------------------------------------------- encoder
@pytest.mark.parametrize(
    ("q_nb", "v_body"),
    [
        # level, heading north: the body axes are NED's
        ([1.0, 0.0, 0.0, 0.0], (18.0, -3.0, 0.5)),
        # heading east (yaw 90°): body x is east, body y south → v_b = (ve, −vn, vd)
        ([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], (-3.0, -18.0, 0.5)),
        # rolled 90° right, heading north: body y is down, body z west → v_b = (vn, vd, −ve)
        ([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0], (18.0, 0.5, 3.0)),
    ],
    ids=["level-north", "yaw-90", "roll-90"],
)
def test_odometry_decodes_as_handle_odometry_reads_it(q_nb: list[float], v_body: tuple[float, ...]) -> None:
    mav = mavlink2.MAVLink(None, 1, 191)
    s = _solution(q_nb=np.array(q_nb))
    p_ekf = np.array([-95.25, 40.5, -3.75])  # NED from the EKF origin, not the solution's own p_ned_m
    m = _roundtrip(ardupilot_odometry(mav, s, p_ned_m=p_ekf, k=2.0, quality=96, reset_counter=300,
                                      sigma_att_rad=(0.02, 0.03, 0.1)))  # fmt: skip
    assert m.get_type() == "ODOMETRY"  # type: ignore[attr-defined]
    o: Any = m
    assert (o.frame_id, o.child_frame_id) == (MAV_FRAME_LOCAL_FRD, MAV_FRAME_BODY_FRD)
    assert (o.x, o.y, o.z) == pytest.approx((-95.25, 40.5, -3.75))  # exact in float32
    assert list(o.q) == pytest.approx(q_nb, abs=1e-7)
    assert (o.vx, o.vy, o.vz) == pytest.approx(v_body, abs=1e-5)
    # ArduPilot rotates the body velocity back with the message's own quaternion: the NED velocity returns
    assert _rotate(list(o.q), (o.vx, o.vy, o.vz)) == pytest.approx((18.0, -3.0, 0.5), abs=1e-5)
    assert all(math.isnan(r) for r in (o.rollspeed, o.pitchspeed, o.yawspeed))
    assert o.time_usec == 212_500_000 and o.time_usec > 0
    # 300 mod 256 = 44 (uint8); quality as given; no estimator type claims to be ours
    assert (o.reset_counter, o.quality, o.estimator_type) == (44, 96, mavlink2.MAV_ESTIMATOR_TYPE_UNKNOWN)
    # σ inflated by k = 2: horizontal (2·12)² = 576 on x and y, vertical (2·2)² = 16, velocity (2·0.8)² = 2.56
    c = o.pose_covariance
    assert (c[0], c[6], c[11]) == pytest.approx((576.0, 576.0, 16.0))
    assert (c[15], c[18], c[20]) == pytest.approx((0.0004, 0.0009, 0.01), rel=1e-6)  # attitude σ², not inflated
    assert (o.velocity_covariance[0], o.velocity_covariance[6], o.velocity_covariance[11]) == pytest.approx(
        (2.56, 2.56, 2.56))  # fmt: skip
    # what handle_odometry derives: posErr = ∛(576² + 576² + 16²) = ∛663808 = 87.24 m, angErr finite
    pos_err = (c[0] ** 2 + c[6] ** 2 + c[11] ** 2) ** (1.0 / 3.0)
    ang_err = (c[15] ** 2 + c[18] ** 2 + c[20] ** 2) ** (1.0 / 3.0)
    assert pos_err == pytest.approx(87.24, abs=0.01) and math.isfinite(ang_err)


def test_quality_follows_the_filters_health() -> None:
    # 100·(1 − σ_h/300): σ 12 m → 96; σ 150 m → 50; σ 299 m → 0.33 → 1 (the worst a solution gets)
    assert odometry_quality(_solution(sigma_h_m=12.0), max_sigma_m=300.0, fallback=False) == 96
    assert odometry_quality(_solution(sigma_h_m=150.0), max_sigma_m=300.0, fallback=False) == 50
    assert odometry_quality(_solution(sigma_h_m=299.0), max_sigma_m=300.0, fallback=False) == 1
    assert odometry_quality(_solution(sigma_h_m=0.5), max_sigma_m=300.0, fallback=False) == 100
    # no port air data: at most 50, as GPS_INPUT's 2-D fix at most
    assert odometry_quality(_solution(sigma_h_m=12.0), max_sigma_m=300.0, fallback=True) == 50
    # no solution: −1 (failed), which ArduPilot's VISO_QUAL_MIN (default 0) refuses
    assert odometry_quality(_solution(fix_type=1), max_sigma_m=300.0, fallback=False) == -1  # GPS_FIX_TYPE_NO_FIX
    assert odometry_quality(_solution(fix_type=0), max_sigma_m=300.0, fallback=False) == -1
    assert odometry_quality(_solution(sigma_h_m=math.nan), max_sigma_m=300.0, fallback=False) == -1


def test_set_ekf_source_set_command() -> None:
    mav = mavlink2.MAVLink(None, 1, 191)
    c: Any = _roundtrip(set_ekf_source_set(mav, target=(1, 1), source_set=2, confirmation=3))
    assert (c.get_type(), c.command, c.param1, c.confirmation) == ("COMMAND_LONG", SET_EKF_SOURCE_SET, 2.0, 3)
    assert (c.target_system, c.target_component) == (1, 1)
    assert (c.param2, c.param3, c.param4, c.param5, c.param6, c.param7) == (0, 0, 0, 0, 0, 0)


# ----------------------------------------------------------------------------------------------- config
SWITCH = {"gnss_set": 1, "extnav_set": 2, "gnss_hold_s": 8, "retry_s": 0.5, "max_tries": 3}


def test_odometry_route_config_reads(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path, {"outputs.solution": "odometry", "outputs.source_switch": dict(SWITCH)}))
    assert cfg.outputs.solution == "odometry"
    assert cfg.outputs.source_switch == SourceSwitchConfig(gnss_set=1, extnav_set=2, gnss_hold_s=8.0, retry_s=0.5,
                                                           max_tries=3)  # fmt: skip
    defaults = load_config(_config(tmp_path, {"outputs.solution": "odometry", "outputs.source_switch": {
        "extnav_set": 3}}))  # fmt: skip
    assert defaults.outputs.source_switch == SourceSwitchConfig(1, 3, 10.0, 1.0, 5)
    for off in (None, False):  # YAML's unquoted ``off`` is false
        assert load_config(_config(tmp_path, {"outputs.source_switch": off})).outputs.source_switch is None


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (
            {"outputs.source_switch": dict(SWITCH)},
            "outputs.source_switch: switches EKF3 to ExternalNav, which "
            "needs outputs.solution: odometry (not gps_input)",
        ),
        (
            {"autopilot": "px4", "outputs.solution": "odometry", "outputs.source_switch": dict(SWITCH)},
            "outputs.source_switch: MAV_CMD_SET_EKF_SOURCE_SET (EK3_SRCn_* source sets) is ArduPilot's only",
        ),
        (
            {"outputs.solution": "odometry", "outputs.source_switch": {**SWITCH, "extnav_set": 4}},
            "outputs.source_switch.extnav_set: expected an integer in [1, 3], got 4",
        ),
        (
            {"outputs.solution": "odometry", "outputs.source_switch": {**SWITCH, "extnav_set": 1}},
            "outputs.source_switch.extnav_set: is the GNSS set (1)",
        ),
        (
            {"outputs.solution": "odometry", "outputs.source_switch": {**SWITCH, "retries": 3}},
            "outputs.source_switch.retries: unknown key",
        ),
        (
            {"outputs.solution": "odometry", "outputs.source_switch": {"gnss_set": 1}},
            "outputs.source_switch.extnav_set: missing required key",
        ),
        (
            {"outputs.solution": "odometry", "outputs.source_switch": {**SWITCH, "retry_s": 0.01}},
            "outputs.source_switch.retry_s: 0.01 is outside [0.2, 10]",
        ),
        ({"outputs.solution": "odometry", "outputs.source_switch": "on"}, "outputs.source_switch: expected null"),
        ({"outputs.solution": "odometry", "outputs.source_switch": True}, "outputs.source_switch: expected null"),
        ({"outputs.solution": "global_position_sensor"}, "outputs.solution: expected one of gps_input, odometry, none"),
    ],
    ids=[
        "needs-odometry",
        "px4",
        "set-4",
        "same-set",
        "unknown-key",
        "missing-set",
        "retry-too-fast",
        "string",
        "true",
        "px4-output-on-ardupilot",
    ],
)
def test_bad_source_switch_is_one_line_naming_the_key(tmp_path: Path, edit: dict[str, Any], needle: str) -> None:
    path = _config(tmp_path, edit)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg, msg
    line = int(msg.split(":")[1])  # "<file>:<line>: key: what"
    key = needle.split(":")[0].split(".")[-1]
    if "missing required key" in msg:  # a key not there: the line of its section
        key = "source_switch"
    assert key in path.read_text().splitlines()[line - 1], (msg, line)


def test_cli_bad_source_switch_exits_2_with_one_line(tmp_path: Path) -> None:
    path = _config(tmp_path, {"outputs.solution": "odometry", "outputs.source_switch": {**SWITCH, "max_tries": 0}})
    r = subprocess.run([sys.executable, "-m", "vdm_aero_cli.main", "serve", "--check-config", "--config", str(path)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "outputs.source_switch.max_tries: expected an integer in [1, 20]" in r.stderr


# ---------------------------------------------------------------------------------- the switch, alone
class _Bench:
    """An EkfSourceSwitch on a fake clock (autopilot clock = local clock here), with what it sends kept."""

    def __init__(self, cfg: SourceSwitchConfig | None = None) -> None:
        cfg = cfg or SourceSwitchConfig(1, 2, 10.0, 1.0, 4)
        self.sent: list[tuple[float, int, int]] = []  # (local time, set, confirmation)
        self.said: list[str] = []
        self.t = 0.0
        self.sw = EkfSourceSwitch(cfg, lambda s, c: self.sent.append((self.t, s, c)), self.said.append)

    def start(self) -> None:
        """GNSS steady from 0.2 s: the GNSS set sent at 10.2 s (the autopilot's set unknown) and accepted."""
        self.fly(10.25, fixes=True)
        assert [(s, c) for _, s, c in self.sent] == [(1, 0)]
        self.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)

    def fly(self, until_s: float, *, fixes: bool, solution_ok: bool = True, dt: float = 0.05) -> None:
        """Advance to ``until_s``: fixes at 5 Hz when ``fixes``, the switch updated every ``dt``."""
        while self.t < until_s - 1e-9:
            self.t = round(self.t + dt, 6)
            if fixes and round(self.t / 0.2, 6).is_integer():
                self.sw.gnss_fix(self.t)
            self.sw.update(self.t, self.t, solution_ok=solution_ok)


def test_switch_sent_once_on_gnss_loss_stopped_by_ack_and_back_after_the_hold() -> None:
    b = _Bench()
    b.fly(10.15, fixes=True)
    assert b.sent == []  # the first fix at 0.2 s: GNSS not yet steady for 10 s, nothing wanted
    b.fly(10.25, fixes=True)
    assert [(s, c) for _, s, c in b.sent] == [(1, 0)]  # the autopilot's set is unknown at start: GNSS asked for
    assert b.sent[0][0] == pytest.approx(10.2)
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    b.fly(20.0, fixes=True)
    assert len(b.sent) == 1 and b.sw.active == 1
    # GNSS lost after the fix at 20.0: lost once more than 1 s has gone without a fix
    b.fly(21.0, fixes=False)
    assert len(b.sent) == 1
    b.fly(21.1, fixes=False)
    assert [(s, c) for _, s, c in b.sent[1:]] == [(2, 0)] and b.sent[1][0] == pytest.approx(21.05)
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    b.fly(60.0, fixes=False)
    assert len(b.sent) == 2 and b.sw.active == 2  # acknowledged: never sent again during the outage
    # GNSS back at 60.2: the ExternalNav set is held for gnss_hold_s of steady fixes, then the GNSS set
    b.fly(70.15, fixes=True)
    assert len(b.sent) == 2
    b.fly(70.25, fixes=True)
    assert [(s, c) for _, s, c in b.sent[2:]] == [(1, 0)] and b.sent[2][0] == pytest.approx(70.2)
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    b.fly(90.0, fixes=True)
    assert len(b.sent) == 3 and b.sw.active == 1
    assert b.sw.summary() == {"active": 1, "wanted": 1, "pending": None, "sent": 3, "accepted": 3, "refused": 0,
                                   "in_progress": 0, "gave_up": 0, "unmatched_acks": 0, "to_extnav": 1,
                                   "to_gnss": 2}  # fmt: skip


def test_no_ack_is_retried_every_retry_s_at_most_max_tries_then_given_up() -> None:
    b = _Bench()
    b.start()
    b.fly(13.0, fixes=True)
    b.fly(30.0, fixes=False)  # last fix at 13.0: lost from 14.05 (more than 1 s); no ACK ever comes
    ext = [(t, s, c) for t, s, c in b.sent if s == 2]
    assert [c for _, _, c in ext] == [0, 1, 2, 3]  # max_tries = 4, confirmation counted up
    assert [t for t, _, _ in ext] == pytest.approx([14.05, 15.05, 16.05, 17.05])  # retry_s = 1 apart
    assert b.sw.counts["gave_up"] == 1 and b.sw.active is None  # carried out or not: unknown
    assert any("NOT switched: no COMMAND_ACK ACCEPTED after 4 transmissions" in line for line in b.said)
    b.fly(60.0, fixes=False)
    assert len([s for _, s, _ in b.sent if s == 2]) == 4  # given up: no flood
    # GNSS back from 60.2: a new wish at 70.2, a new round (the autopilot's set is unknown, so it is sent)
    b.fly(70.15, fixes=True)
    assert len(b.sent) == 5
    b.fly(70.25, fixes=True)
    assert [(s, c) for _, s, c in b.sent[5:]] == [(1, 0)] and b.sent[5][0] == pytest.approx(70.2)
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    assert b.sw.active == 1


def test_a_link_dropout_gives_a_silent_switch_a_new_round_but_not_a_refused_one() -> None:
    b = _Bench()
    b.start()
    b.fly(13.0, fixes=True)
    b.fly(20.0, fixes=False)  # 4 tries from 14.05, no ACK: given up
    assert len(b.sent) == 5 and b.sw.counts["gave_up"] == 1
    b.sw.link_back()
    b.fly(20.1, fixes=False)
    assert [(s, c) for _, s, c in b.sent[5:]] == [(2, 0)]
    b.sw.ack(mavlink2.MAV_RESULT_DENIED)  # refused: final, a drop-out does not retry it
    b.sw.link_back()
    b.fly(40.0, fixes=False)
    assert len(b.sent) == 6 and b.sw.counts["gave_up"] == 2


def test_refusals_in_progress_and_stray_acks() -> None:
    b = _Bench()
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)  # nothing pending: counted, not acted on
    assert (b.sw.counts["unmatched_acks"], b.sw.active) == (1, None)
    b.fly(10.25, fixes=True)  # (1, 0) sent at 10.2
    b.sw.ack(mavlink2.MAV_RESULT_TEMPORARILY_REJECTED)  # retried within the bound
    b.fly(11.25, fixes=True)
    assert [c for _, _, c in b.sent] == [0, 1]
    assert [t for t, _, _ in b.sent] == pytest.approx([10.2, 11.2])
    b.sw.ack(mavlink2.MAV_RESULT_IN_PROGRESS)  # at 11.25: the next try waits a full period from now, to 12.25
    b.fly(12.2, fixes=True)
    assert len(b.sent) == 2
    b.fly(12.3, fixes=True)
    assert len(b.sent) == 3 and b.sent[2][0] == pytest.approx(12.25)
    b.sw.ack(mavlink2.MAV_RESULT_FAILED)  # final: no more tries for this wish
    b.fly(40.0, fixes=True)
    assert len(b.sent) == 3 and b.sw.active is None
    assert (b.sw.counts["refused"], b.sw.counts["in_progress"], b.sw.counts["gave_up"]) == (2, 1, 1)
    assert any("NOT switched: refused: MAV_RESULT 4" in line for line in b.said)
    b.sw.ack(200)  # a result no MAV_RESULT has, after giving up: counted, harmless
    b.sw.ack(-1)
    assert b.sw.counts["unmatched_acks"] == 3


def test_no_switch_to_extnav_without_a_solution_and_a_reboot_is_set_1() -> None:
    b = _Bench()
    b.start()
    b.fly(13.0, fixes=True)
    b.fly(20.0, fixes=False, solution_ok=False)  # GNSS lost, but no usable ODOMETRY: stay on the GNSS set
    assert [s for _, s, _ in b.sent] == [1]
    b.fly(21.0, fixes=False, solution_ok=True)
    assert [s for _, s, _ in b.sent] == [1, 2]
    b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    b.sw.autopilot_rebooted()  # EKF3 boots in EK3_SRC1_*: the outage goes on, so ExternalNav is asked again
    assert b.sw.active == 1
    b.fly(21.2, fixes=False)
    assert [s for _, s, _ in b.sent] == [1, 2, 2]


def test_a_flickering_receiver_never_floods() -> None:
    """GNSS dropping in and out at random (seeded): never two commands closer than retry_s, at most max_tries
    per change of wish, and the wish changes only after a whole gnss_hold_s of fixes."""
    rng = random.Random(20261126)
    b = _Bench(SourceSwitchConfig(1, 2, 5.0, 1.0, 3))
    wishes = []
    while b.t < 600.0:
        b.fly(b.t + rng.uniform(0.2, 8.0), fixes=rng.random() < 0.6)
        wishes.append(b.sw.wanted)
        if b.sent and rng.random() < 0.5:  # the ACK comes back half the time
            b.sw.ack(mavlink2.MAV_RESULT_ACCEPTED)
    times = [t for t, _, _ in b.sent]
    assert len(times) >= 4  # the flight did make it switch
    same = [(t1, t0) for (t0, s0, _), (t1, s1, _) in zip(b.sent, b.sent[1:], strict=False) if s0 == s1]
    assert all(t1 - t0 >= 1.0 - 1e-9 for t1, t0 in same)
    changes = sum(1 for a, c in itertools.pairwise(wishes) if a != c) + 1
    assert len(b.sent) <= 3 * changes
    assert b.sw.counts["sent"] == len(b.sent)


# ----------------------------------------------------------------------------- wired into the service
@pytest.fixture(scope="module")
def models(design_deim12: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Any:
    from tests.test_fault_inputs import _service_config
    from vdm_aero.nav.models import NavModels

    cfg = _service_config(tmp_path_factory.mktemp("odometry-models"), design_deim12, "models", {})
    return NavModels.load(cfg.design_data, cfg.deim_model, None, cfg.vehicle)


def test_the_service_sends_odometry_in_the_ekf_origins_frame_and_switches_on_gnss_loss(
    design_deim12: dict[str, Path], models: Any, tmp_path: Path
) -> None:
    """A service (ardupilot, solution: odometry, source_switch) flown on a fake autopilot: it asks for the EKF
    origin, sends no ODOMETRY before it has it, then ODOMETRY at 5 Hz in that origin's NED frame; GNSS lost
    → MAV_CMD_SET_EKF_SOURCE_SET 2 to the autopilot, once the ACK comes no more; a missing ACK is retried."""
    from tests.test_fault_inputs import WARM_T0_S, _Autopilot, _FeedLink, _service_config, _warm_service

    cfg = _service_config(tmp_path, design_deim12, "odom", {
        "outputs.solution": "odometry", "outputs.source_switch": {"gnss_set": 1, "extnav_set": 2, "gnss_hold_s": 0,
                                                                  "retry_s": 1.0, "max_tries": 3}})  # fmt: skip
    ap = _Autopilot()
    svc = _warm_service(cfg, models, ap)
    link = _FeedLink()
    svc.transport.close()
    svc.ep.transport = link
    svc.transport = link
    rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    m = ap.tx
    t = [WARM_T0_S + 0.3]
    now = [WARM_T0_S + 0.3]  # the local clock (the warm-up's heartbeat was heard at WARM_T0_S − 0.01 on it)

    def sent() -> list[Any]:
        out = [x for x in (rx.parse_buffer(b"".join(link.sent)) or [])]
        link.sent.clear()
        return out

    def fly(seconds: float, *, fixes: bool) -> list[Any]:
        """IMU at 50 Hz, baro at 10 Hz, fixes at 5 Hz (18 m/s north), the upkeep every 20 ms of local time."""
        got = []
        for _ in range(round(seconds * 50)):
            t[0] = round(t[0] + 0.02, 6)
            now[0] += 0.02
            svc._dispatch(ap(m.raw_imu_encode(round(t[0] * 1e6), 0, 0, -1000, 0, 0, 0, 200, -49, 465, 0, 2500)), now[0])
            if round(t[0] * 50) % 50 == 0:  # 1 Hz: the autopilot stays heard
                hb = m.heartbeat_encode(mavlink2.MAV_TYPE_FIXED_WING, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
                svc._dispatch(ap(hb), now[0])
            if round(t[0] * 50) % 5 == 0:
                svc._dispatch(ap(m.scaled_pressure_encode(round(t[0] * 1e3), 1000.0, 2.0, 2500)), now[0])
            if fixes and round(t[0] * 50) % 10 == 0:
                north_e7 = round((t[0] - WARM_T0_S) * 18.0 / 111_320.0 * 1e7)
                svc._dispatch(ap(m.gps_raw_int_encode(round(t[0] * 1e6), 3, 422830335 + north_e7, -713500307,
                                                      155600, 80, 120, 1800, 0, 14)), now[0])  # fmt: skip
            svc._periodic(now[0])
            got += sent()
        return got

    try:
        assert svc.filter is not None and svc.filter.initialised
        first = fly(1.0, fixes=True)
        asks = [x for x in first if x.get_type() == "COMMAND_LONG" and x.command == mavlink2.MAV_CMD_REQUEST_MESSAGE]
        assert [(a.param1, a.target_system, a.target_component) for a in asks] == [(49.0, 1, 1)]
        assert not [x for x in first if x.get_type() == "ODOMETRY"]
        assert svc.summary()["odometry_without_origin"] >= 4
        cmds = [x for x in first if x.get_type() == "COMMAND_LONG" and x.command == SET_EKF_SOURCE_SET]
        assert [(c.param1, c.target_system, c.target_component) for c in cmds] == [(1.0, 1, 1)]  # unknown at start
        svc._dispatch(ap(m.command_ack_encode(SET_EKF_SOURCE_SET, mavlink2.MAV_RESULT_ACCEPTED, 0, 0, 1, 191)), now[0])
        assert svc.summary()["source_switch"]["active"] == 1
        # the EKF origin 100 m (0.000898° of latitude) south of ours and 10 m lower
        svc._dispatch(ap(m.gps_global_origin_encode(422830335 - 8983, -713500307, 145600, 0)), now[0])
        got = fly(2.0, fixes=True)
        odo = [x for x in got if x.get_type() == "ODOMETRY"]
        assert len(odo) == 10  # 5 Hz on the autopilot's clock, GNSS or not
        o = odo[-1]
        assert (o.frame_id, o.child_frame_id) == (MAV_FRAME_LOCAL_FRD, MAV_FRAME_BODY_FRD)
        # north: 100 m from the origin offset + 18 m/s × (t − t0), ±3 m of filter and fix noise; down ≈ −10 m
        along = (o.time_usec * 1e-6 - WARM_T0_S) * 18.0
        assert o.x == pytest.approx(100.0 + along, abs=3.0) and o.y == pytest.approx(0.0, abs=3.0)
        assert o.z == pytest.approx(-10.0, abs=3.0)
        assert 1 <= o.quality <= 100 and o.reset_counter == 0
        assert not [x for x in got if x.get_type() == "COMMAND_LONG" and x.command == SET_EKF_SOURCE_SET]
        # GNSS lost: ExternalNav asked for after 1 s without a fix; no ACK for 1 s: sent again
        lost = fly(2.6, fixes=False)
        cmds = [x for x in lost if x.get_type() == "COMMAND_LONG" and x.command == SET_EKF_SOURCE_SET]
        assert [(c.param1, c.confirmation) for c in cmds] == [(2.0, 0), (2.0, 1)]
        # an ACK for a ground station's command is not ours; a garbage result is counted, nothing crashes
        svc._dispatch(ap(m.command_ack_encode(SET_EKF_SOURCE_SET, mavlink2.MAV_RESULT_ACCEPTED, 0, 0, 255, 190)),
                      now[0])  # fmt: skip
        assert svc.summary()["source_switch"]["active"] == 1
        svc._dispatch(ap(m.command_ack_encode(SET_EKF_SOURCE_SET, mavlink2.MAV_RESULT_ACCEPTED, 0, 0, 1, 191)), now[0])
        svc._dispatch(ap(m.command_ack_encode(SET_EKF_SOURCE_SET, 177, 0, 0, 1, 191)), now[0])
        quiet = fly(3.0, fixes=False)
        assert not [x for x in quiet if x.get_type() == "COMMAND_LONG" and x.command == SET_EKF_SOURCE_SET]
        assert len([x for x in quiet if x.get_type() == "ODOMETRY"]) == 15
        s = svc.summary()
        sw = s["source_switch"]
        assert (sw["active"], sw["sent"], sw["accepted"], sw["unmatched_acks"], sw["to_extnav"]) == (2, 3, 2, 1, 1)
        assert not s["handler_errors"], s["handler_errors"]
        assert "EKF source set 2 (ExternalNav)" in svc.status_line()
    finally:
        link.close()
