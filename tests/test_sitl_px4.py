"""The mock autopilot as PX4 (``AutopilotOptions.firmware = "px4"``), through its link: what PX4 sends a companion
differently from ArduPilot, and the companion's navigation messages judged by EKF2's rules (sim/sitl/ekf2_judge.py)
instead of EKF3's."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.flight.contract import WorldTick
from sim.sitl.autopilot import AutopilotOptions, DeadReckoningDrift, MockAutopilot, RunSummary
from sim.sitl.ekf2_judge import Ekf2Rules
from sim.sitl.link import MavlinkEndpoint, MavlinkMessage, MemoryLinkPair
from sim.sitl.scripted_world import OutageWindow, ScriptedWorld, scenario_config
from vdm_aero.errors import UserInputError
from vdm_aero.geodesy import LocalFrame
from vdm_aero.rotation import dcm_from_quat

COMPANION = {"system_id": 1, "component_id": mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER}
OFFSET_NE_M = np.array([50.0, -30.0])  # the companion's local origin is not the autopilot's
SIGMA_M = 0.3  # the companion's position noise (σ), reported honestly


def _cov(var: float) -> np.ndarray:
    cov = np.full(21, np.nan)
    cov[0] = cov[6] = cov[11] = var
    return cov


class _Px4Companion:
    """A world whose step also plays a companion of a PX4: at 10 Hz an ODOMETRY (LOCAL_NED of its own origin, body
    velocity) or a GLOBAL_POSITION_SENSOR of the tick's truth plus seeded noise, all flight; one GPS_INPUT of the truth
    (12 satellites, a perfect 3-D fix) and one MAV_CMD_SET_EKF_SOURCE_SET at 5 s."""

    def __init__(self, inner: ScriptedWorld, ep: MavlinkEndpoint, message: str, seed: int) -> None:
        self.inner, self.ep, self.message = inner, ep, message
        self.dt_s = inner.dt_s
        self.home_lat_deg, self.home_lon_deg, self.home_alt_m = inner.home_lat_deg, inner.home_lon_deg, inner.home_alt_m
        self.frame = LocalFrame(inner.home_lat_deg, inner.home_lon_deg, inner.home_alt_m)
        self.rng = np.random.default_rng(seed)
        self.k = 0

    def step(self) -> WorldTick:
        tick = self.inner.step()
        tr, t = tick.truth, tick.truth.t_s
        if self.k == round(5.0 / self.dt_s):
            self.ep.send(self.ep.mav.gps_input_encode(round(t * 1e6), 1, 0, 0, 0, 3, round(tr.lat_deg * 1e7),
                                                      round(tr.lon_deg * 1e7), tr.alt_m, 0.7, 1.0, *tr.v_ned_m_s,
                                                      0.2, 0.5, 1.0, 12, 0))  # fmt: skip
            self.ep.send(self.ep.mav.command_long_encode(1, 1, mavlink2.MAV_CMD_SET_EKF_SOURCE_SET, 0,
                                                         2, 0, 0, 0, 0, 0, 0))  # fmt: skip
        if self.k % round(0.1 / self.dt_s) == 0:
            noise = SIGMA_M * self.rng.standard_normal(2)
            if self.message == "ODOMETRY":
                q = np.asarray(tr.q_nb, dtype=np.float64)
                pos = tr.pos_ned_m + np.array([*(OFFSET_NE_M + noise), 0.0])
                v_b = dcm_from_quat(q).T @ tr.v_ned_m_s
                self.ep.send(self.ep.mav.odometry_encode(
                    round(t * 1e6), mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_FRD, *pos, q, *v_b,
                    math.nan, math.nan, math.nan, _cov(SIGMA_M**2), _cov(0.1**2), 0, mavlink2.MAV_ESTIMATOR_TYPE_VIO,
                    80))  # fmt: skip
            else:
                n, e, d = tr.pos_ned_m + np.array([*noise, 0.0])
                lat, lon, alt = self.frame.to_geodetic(float(n), float(e), float(d))
                self.ep.send(self.ep.mav.global_position_sensor_encode(
                    1, 1, 1, round(t * 1e6), 0, 0, 0, round(lat * 1e7), round(lon * 1e7), math.nan, alt, SIGMA_M,
                    1.0))  # fmt: skip
        self.k += 1
        return tick


def _fly(message: str, rules: Ekf2Rules | None = None) -> tuple[RunSummary, list[MavlinkMessage]]:
    cfg = replace(scenario_config("circle_noiseless"), gnss_outages=(OutageWindow(20.0, 40.0),))
    inner = ScriptedWorld(cfg)
    pair = MemoryLinkPair()
    ep = MavlinkEndpoint(pair.companion_end, **COMPANION)
    world = _Px4Companion(inner, ep, message, seed=7)
    opts = AutopilotOptions(firmware="px4", drift=DeadReckoningDrift(horizontal_velocity_sigma_m_s=1.0, seed=2),
                            ekf2_rules=rules or Ekf2Rules())  # fmt: skip
    rates = {"HIGHRES_IMU": 50.0, "SCALED_PRESSURE": 10.0}
    with MockAutopilot(world, pair.autopilot_end, speed=math.inf, stream_rates=rates, options=opts) as ap:  # type: ignore[arg-type]
        summary = ap.run(41.0)
    msgs: list[MavlinkMessage] = []
    while got := ep.poll(0.05):
        msgs.extend(got)
    return summary, msgs


@pytest.fixture(scope="module")
def odometry_flight() -> tuple[RunSummary, list[MavlinkMessage]]:
    return _fly("ODOMETRY")


def test_px4_says_it_is_px4_and_sends_its_airspeed_sensor_in_highres_imu(
    odometry_flight: tuple[RunSummary, list[MavlinkMessage]],
) -> None:
    """HEARTBEAT: MAV_AUTOPILOT_PX4 in AUTO.MISSION (px4_custom_mode.h); HIGHRES_IMU's diff_pressure is the airspeed
    sensor's (PX4's HIGHRES_IMU stream), the Δp SCALED_PRESSURE carries, not ArduPilot's barometer less its ground
    pressure (a few hPa at the circuit's height, of the other sign)."""
    _, msgs = odometry_flight
    hb = [m for m in msgs if m.get_type() == "HEARTBEAT"]
    assert hb and {(m.autopilot, m.custom_mode) for m in hb} == {(mavlink2.MAV_AUTOPILOT_PX4, (4 << 16) | (4 << 24))}
    imu = [m for m in msgs if m.get_type() == "HIGHRES_IMU" and m.fields_updated & 0x400]
    sp = [m for m in msgs if m.get_type() == "SCALED_PRESSURE"]
    assert len(imu) > 100 and sp
    dp = np.array([m.diff_pressure for m in imu])
    # a 2 m circuit at ~20 m/s: q ≈ ½ρV² ≈ 2.5 hPa, inside the range SCALED_PRESSURE's Δp spans in the same flight
    lo, hi = min(m.press_diff for m in sp), max(m.press_diff for m in sp)
    assert np.all(dp > 0.5) and lo - 0.3 <= np.median(dp) <= hi + 0.3, (np.median(dp), lo, hi)


def test_px4_refuses_ardupilots_source_set_command_and_never_reads_gps_input(
    odometry_flight: tuple[RunSummary, list[MavlinkMessage]],
) -> None:
    """MAV_CMD_SET_EKF_SOURCE_SET is ArduPilot's (UNSUPPORTED); GPS_INPUT has no handler in PX4's mavlink receiver,
    so not even a perfect 12-satellite fix is used."""
    summary, msgs = odometry_flight
    acks = [m for m in msgs if m.get_type() == "COMMAND_ACK" and m.command == mavlink2.MAV_CMD_SET_EKF_SOURCE_SET]
    assert [a.result for a in acks] == [mavlink2.MAV_RESULT_UNSUPPORTED]
    assert summary["source_set_switches"] == [] and summary["gps_input_verdicts"] == {}
    assert summary["ekf2_verdicts"]["GPS_INPUT"] == {"PX4 v1.16: no handler for message 232": 1}


def test_px4_learns_the_companions_origin_with_gnss_and_flies_the_outage_on_its_odometry(
    odometry_flight: tuple[RunSummary, list[MavlinkMessage]],
) -> None:
    """EKF2's EV bias estimator learns the 58 m between the companion's origin and its own while it fuses GNSS, resets
    onto EV − bias when GNSS is lost, then fuses the ODOMETRY: at the outage's end the mock is within the companion's
    noise of the truth, where its own dead reckoning is metres off."""
    summary, _ = odometry_flight
    v = summary["ekf2_outage_verdicts"]["ODOMETRY"]
    came = sum(v.values())
    assert came >= 0.95 * 10 * 20.0 and v.get("used", 0) >= 0.9 * came, v
    assert sum(n for k, n in v.items() if k.startswith("reset")) == 1, v
    ((end,),) = [summary["outage_end_errors"]]
    assert end["without_m"] > 5.0 and end["with_service_m"] < 3.0 * SIGMA_M, end


@pytest.mark.parametrize(("release", "used"), [("v1.16", False), ("main", True)])
def test_px4_takes_global_position_sensor_only_where_it_has_a_handler(release: str, used: bool) -> None:
    """GLOBAL_POSITION_SENSOR (296): no handler in v1.16, so nothing is used and the mock flies on its own drift; main
    (2026) fuses it as auxiliary global position (EKF2_AGP0_ID = the message's id)."""
    summary, _ = _fly("GLOBAL_POSITION_SENSOR", Ekf2Rules(release=release, agp_handler=release == "main"))
    v = summary["ekf2_outage_verdicts"]["GLOBAL_POSITION_SENSOR"]
    ((end,),) = [summary["outage_end_errors"]]
    if used:
        assert v.get("used", 0) >= 0.9 * sum(v.values()) and end["with_service_m"] < 3.0 * SIGMA_M, (v, end)
    else:
        assert set(v) == {"PX4 v1.16: no handler for message 296"}, v
        assert end["with_service_m"] == pytest.approx(end["without_m"], rel=1e-9)


def test_px4_has_no_lua_to_switch_source_sets() -> None:
    world = ScriptedWorld(scenario_config("circle_noiseless"))
    with pytest.raises(UserInputError, match="ArduPilot's, not PX4's"):
        MockAutopilot(world, MemoryLinkPair().autopilot_end,
                      options=AutopilotOptions(firmware="px4", source_set_on_gnss_loss=2))  # fmt: skip
    with pytest.raises(UserInputError, match="firmware = 'inav'"):
        MockAutopilot(world, MemoryLinkPair().autopilot_end, options=AutopilotOptions(firmware="inav"))
