"""The compass fused for heading only in an outage (the variant ``vdm-compass-heading``, issue 22): it turns
the heading and does not read its own deviation as tilt. The three-axis field fusion (every mode, and the variant
while GNSS aids) explains a field error by the attitude that best fits it, tilt included; with no GNSS velocity
to hold the tilt, g·tilt then drives the velocity off (a return through a gradient, seed 19: 60 mrad of pitch
in 40 s, 24 km off at 300 s)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vdm_aero.atmosphere import G0_M_S2
from vdm_aero.nav.contracts import ImuIncrement
from vdm_aero.nav.filter import GNSS_TIMEOUT_S, NavConfig, NavFilter
from vdm_aero.nav.measurements import MagHeading
from vdm_aero.nav.state import IDX, NavState
from vdm_aero.rotation import dcm_from_quat, euler_from_quat, quat_from_euler
from vdm_aero.vehicle import load_vehicle

MAG_NED_UT = np.array([20.1, -4.9, 46.5])
DEVIATION_B_UT = np.array([4.0, 0.0, -3.0])  # what a compass swing leaves: a few µT, here mostly along x and z


def _in_outage(mode: str) -> NavFilter:
    """A filter initialised level, flying north at 19 m/s, IMU only until GNSS has timed out."""
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=MAG_NED_UT)
    f = NavFilter(mode, cfg)
    f_b = np.array([0.0, 0.0, -G0_M_S2])
    f.initialise(0.0, np.zeros(3), np.array([19.0, 0.0, 0.0]), f_b, MAG_NED_UT)
    inc = ImuIncrement(np.zeros(3), f_b * 0.02, 0.02)
    for k in range(1, round((GNSS_TIMEOUT_S + 0.5) / 0.02) + 1):
        f.imu(k * 0.02, inc)
    assert f.in_outage and f.x is not None
    return f


def test_in_an_outage_the_heading_compass_turns_the_heading_and_not_the_tilt() -> None:
    # one compass sample with a deviation the filter does not know, fused from the same prior: vdm's three
    # axes tilt the attitude by tens of mrad to explain it; the variant's heading fusion turns the
    # heading by the deviation's heading content, and roll and pitch only by their small correlation with the
    # heading in the covariance
    moved, gain = {}, {}
    for mode in ("vdm-compass-heading", "vdm"):
        f = _in_outage(mode)
        assert f.x is not None and f.engine is not None
        before = np.array(euler_from_quat(f.x.q_nb))
        p_yaw = f.engine.P[IDX["theta"].start + 2, IDX["theta"].start + 2]  # level: body z is the yaw axis
        gain[mode] = p_yaw / (p_yaw + (f.config.mag_sigma_ut / math.hypot(*MAG_NED_UT[:2])) ** 2)
        f.mag(f.t_s, dcm_from_quat(f.x.q_nb).T @ MAG_NED_UT + DEVIATION_B_UT)
        assert f.counts.get("mag") == 1
        moved[mode] = np.array(euler_from_quat(f.x.q_nb)) - before
    assert abs(moved["vdm"][1]) > 0.02  # tens of mrad of pitch from a 5-µT deviation
    assert np.abs(moved["vdm-compass-heading"][:2]).max() < 0.05 * np.abs(moved["vdm"][:2]).max()
    # level and heading north, the deviation's 4 µT along x add to the field's north part: the levelled field
    # points atan2(E, N + 4) instead of atan2(E, N), and the heading moves by the gain's share of that
    heading_error = math.atan2(MAG_NED_UT[1], MAG_NED_UT[0]) - math.atan2(MAG_NED_UT[1], MAG_NED_UT[0] + 4.0)
    assert moved["vdm-compass-heading"][2] == pytest.approx(gain["vdm-compass-heading"] * heading_error, rel=0.01)


def test_while_gnss_aids_the_heading_compass_fuses_the_three_axes() -> None:
    # aided, the tilt is held by the GNSS velocity and the three axes also learn the hard iron: no change there
    cfg = NavConfig(vehicle=load_vehicle("uav-2m"), origin_alt_m=50.0, mag_field_ned_ut=MAG_NED_UT)
    f = NavFilter("vdm-compass-heading", cfg)
    f_b = np.array([0.0, 0.0, -G0_M_S2])
    f.initialise(0.0, np.zeros(3), np.array([19.0, 0.0, 0.0]), f_b, MAG_NED_UT)
    assert not f.in_outage and f.x is not None
    before = np.array(euler_from_quat(f.x.q_nb))
    f.mag(0.0, dcm_from_quat(f.x.q_nb).T @ MAG_NED_UT + DEVIATION_B_UT)
    assert abs(np.array(euler_from_quat(f.x.q_nb))[1] - before[1]) > 0.01


@pytest.mark.parametrize("roll_pitch_yaw_deg", [(0.0, 0.0, 30.0), (35.0, -10.0, -120.0), (-50.0, 20.0, 179.0)])
def test_the_compass_heading_is_the_true_heading_whatever_the_bank_and_pitch(
    roll_pitch_yaw_deg: tuple[float, float, float],
) -> None:
    # an undeviated field at a known attitude, the estimate's tilt right: the levelled field gives the yaw,
    # across ±π (the 179° case) and with the hard-iron estimate taken off
    roll, pitch, yaw = np.radians(roll_pitch_yaw_deg)
    x = NavState(np.zeros(3), np.zeros(3), np.asarray(quat_from_euler(roll, pitch, yaw)))
    x.b_mag_b_ut = np.array([3.0, -7.0, 2.0])
    field_b = dcm_from_quat(x.q_nb).T @ MAG_NED_UT + x.b_mag_b_ut
    # the estimate's heading 0.3 rad off: the measurement is the truth, within ±π of the estimate
    est = x.copy()
    est.q_nb = np.asarray(quat_from_euler(roll, pitch, yaw + 0.3))
    psi = MagHeading.measured(est, field_b, MAG_NED_UT)
    assert math.remainder(psi - yaw, 2.0 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert abs(psi - euler_from_quat(est.q_nb)[2]) <= math.pi
