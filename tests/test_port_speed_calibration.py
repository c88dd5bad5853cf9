"""The ports' airspeed table: fitted from a calibration flight's ports and pitot, held beyond its α, applied by
the port front end to V alone, and refused with one line naming the file when malformed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from vdm_aero.errors import ModelError
from vdm_aero.nav.design_fit import DesignFlightData, PortPressureModel
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.port_speed_calibration import MIN_SAMPLES, PortSpeedCalibration
from vdm_aero.nav.ports_frontend import PortFrontEnd


def _true_ratio(alpha_rad: np.ndarray) -> np.ndarray:
    """An as-built position error like the harsh fleet's airframe 1: none at low α, the ports reading ~14 % low
    from 3° up (a smooth step)."""
    return 1.0 + 0.14 / (1.0 + np.exp(-(np.degrees(alpha_rad) - 2.0) / 0.6))


def _flight(rng: np.random.Generator, n: int = 6000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    alpha = np.radians(rng.uniform(-2.0, 7.0, n))
    v_true = rng.uniform(12.0, 26.0, n)
    # the pitot: the reference, with its own noise; the ports: the true airspeed over the position error, with
    # turbulence-and-lag scatter of 3 % (what the harsh calibration flights show)
    v_pitot = v_true + rng.normal(0.0, 0.2, n)
    v_ports = v_true / _true_ratio(alpha) * (1.0 + rng.normal(0.0, 0.03, n))
    return alpha, v_ports, v_pitot


def test_the_fit_recovers_a_known_position_error() -> None:
    rng = np.random.default_rng(7)
    alpha, v_ports, v_pitot = _flight(rng)
    cal = PortSpeedCalibration.fit(alpha, v_ports, v_pitot)
    assert cal.alpha_range_deg == pytest.approx((-2.0, 7.0))
    inner = np.radians(np.linspace(-1.5, 6.5, 33))
    got = np.array([cal.ratio(a) for a in inner])
    # the step is 0.14 high; the table keeps it within 0.012 (a knot every degree cannot draw a 0.6° step exactly)
    assert np.max(np.abs(got - _true_ratio(inner))) < 0.012
    # the flight's own spread falls from the position error's to the scatter's
    assert cal.rms_before_m_s > 1.0
    assert cal.rms_after_m_s < 0.75 * cal.rms_before_m_s
    assert cal.samples == int(np.sum((v_ports >= 10.0) & (v_pitot >= 10.0)))  # the pitot's useful range


def test_the_table_is_held_beyond_the_flown_alpha_and_corrects_only_there_where_flown() -> None:
    rng = np.random.default_rng(8)
    cal = PortSpeedCalibration.fit(*_flight(rng))
    edge_lo, edge_hi = cal.ratio_at_knots[0], cal.ratio_at_knots[-1]
    assert cal.ratio(math.radians(-10.0)) == edge_lo
    assert cal.ratio(math.radians(15.0)) == edge_hi
    assert cal.correct(15.0, math.radians(15.0)) == pytest.approx(15.0 * edge_hi)


def test_a_flight_without_airspeed_is_no_calibration() -> None:
    rng = np.random.default_rng(9)
    alpha, v_ports, v_pitot = _flight(rng, MIN_SAMPLES + 10)
    v_pitot[:20] = 5.0  # below the pitot's useful range
    with pytest.raises(ValueError, match="samples with both airspeeds"):
        PortSpeedCalibration.fit(alpha, v_ports, v_pitot)
    # a "calibration" whose ratio is no position error is a broken sensor, refused
    alpha, _, v_pitot = _flight(rng, 2 * MIN_SAMPLES)
    with pytest.raises(ModelError, match="broken sensor"):
        PortSpeedCalibration.fit(alpha, 1.6 * v_pitot, v_pitot)


def test_the_table_round_trips_and_a_bad_one_names_its_file() -> None:
    cal = PortSpeedCalibration.fit(*_flight(np.random.default_rng(10)))
    back = PortSpeedCalibration.from_dict(yaml.safe_load(yaml.safe_dump(cal.to_dict())), "m/model.yaml")
    assert back.ratio_at_knots == pytest.approx(cal.ratio_at_knots, abs=1e-6)
    assert back.alpha_knots_rad == pytest.approx(cal.alpha_knots_rad, abs=1e-9)
    d = cal.to_dict()
    for bad, match in (({k: v for k, v in d.items() if k != "ratio"}, "missing key ratio"),
                       ({**d, "ratio": d["ratio"][:-1]}, "one per ratio"),
                       ({**d, "alpha_knots_deg": list(reversed(d["alpha_knots_deg"]))}, "increasing"),
                       ({**d, "ratio": ["x"] * len(d["ratio"])}, "m/model.yaml: port_speed"),
                       ({**d, "ratio": [3.0] * len(d["ratio"])}, "broken sensor"),
                       ("table", "must be a mapping")):  # fmt: skip
        with pytest.raises(ModelError, match=match) as e:
            PortSpeedCalibration.from_dict(bad, "m/model.yaml")
        assert str(e.value).startswith("m/model.yaml: ") and "\n" not in str(e.value)


def _design_frame(model_dir: Path, data_dir: Path) -> tuple[PortPressureModel, np.ndarray]:
    """The design data's FADS model and one frame of port Δp at 18 m/s, α 4°, from that model itself."""
    names = NavModels.from_model(data_dir, model_dir).port_names
    pm = PortPressureModel.fit(DesignFlightData.load(data_dir, names))
    cp = pm.cp(math.radians(4.0), 0.0, 18.0, np.zeros(3), np.zeros(3))[0]
    return pm, 0.5 * 1.2 * 18.0**2 * cp


def test_the_front_end_calibrates_the_airspeed_and_leaves_cp_alone(design_deim12: dict[str, Path]) -> None:
    pm, dp = _design_frame(design_deim12["model"], design_deim12["data"])
    cal = PortSpeedCalibration((math.radians(0.0), math.radians(8.0)), (1.0, 1.16), 1000, 1.0, 0.5)
    plain = PortFrontEnd(pm, {}, range_pa=500.0, noise_pa=0.2)
    calibrated = PortFrontEnd(pm, {}, range_pa=500.0, noise_pa=0.2, speed_calibration=cal)
    a = plain.air_data(dp, 1.2, np.zeros(3), np.zeros(3))
    b = calibrated.air_data(dp, 1.2, np.zeros(3), np.zeros(3))
    assert a is not None and b is not None
    (v0, al0, be0), cov0, q0 = a
    (v1, al1, be1), cov1, q1 = b
    assert v0 == pytest.approx(18.0, rel=1e-3) and al0 == pytest.approx(math.radians(4.0), abs=1e-4)
    r = cal.ratio(al0)
    assert r == pytest.approx(1.08, rel=1e-3)
    assert v1 == pytest.approx(r * v0) and (al1, be1) == (al0, be0)
    assert cov1[0, 0] == pytest.approx(r * r * cov0[0, 0]) and cov1[1:, 1:] == pytest.approx(cov0[1:, 1:])
    # the q̄ that normalises Cp for the aero models is the solve's own, as the net was trained
    assert q1 == q0


def test_a_calibrated_model_carries_its_table_to_the_filters(design_deim12: dict[str, Path], tmp_path: Path) -> None:
    import shutil

    model = tmp_path / "m"
    shutil.copytree(design_deim12["model"], model)
    assert NavModels.from_model(design_deim12["data"], model).port_speed is None  # the design model has none
    meta = yaml.safe_load((model / "model.yaml").read_text())
    cal = PortSpeedCalibration((math.radians(-2.0), math.radians(6.0)), (0.95, 1.1), 1000, 1.0, 0.5)
    meta["calibration"] = {"targets": {"cp_qbar": "ports"}, "port_speed": cal.to_dict()}  # as calibrate writes
    (model / "model.yaml").write_text(yaml.safe_dump(meta))
    nav = NavModels.from_model(design_deim12["data"], model)
    assert nav.port_speed is not None
    assert nav.port_speed.ratio(math.radians(2.0)) == pytest.approx(1.025)
    assert nav.front_end(range_pa=500.0, noise_pa=0.2).speed_calibration is nav.port_speed
    meta["calibration"]["port_speed"]["ratio"] = [0.95]
    (model / "model.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(ModelError, match=r"m/model\.yaml: port_speed: alpha_knots_deg"):
        NavModels.from_model(design_deim12["data"], model)


def test_the_front_end_says_whether_the_alpha_lies_inside_the_calibration(design_deim12: dict[str, Path]) -> None:
    pm, dp = _design_frame(design_deim12["model"], design_deim12["data"])  # a frame at α 4°

    def frame(cal: PortSpeedCalibration | None, ok: np.ndarray | None = None) -> bool:
        fe = PortFrontEnd(pm, {}, range_pa=500.0, noise_pa=0.2, speed_calibration=cal)
        f = fe.process(0.0, dp, 1.2, np.zeros(3), np.zeros(3), ok)
        assert f.airdata is not None
        return f.within_calibration

    spanning = PortSpeedCalibration((math.radians(-2.0), math.radians(7.0)), (1.0, 1.1), 1000, 1.0, 0.5)
    assert frame(None)  # no table: the design model is all there is
    assert frame(spanning)
    assert not frame(PortSpeedCalibration((math.radians(5.0), math.radians(9.0)), (1.0, 1.1), 1000, 1.0, 0.5))
    # the table was fitted on every port: with one left out (blocked, quiet) the solve's error is another one
    subset = np.ones(len(dp), dtype=bool)
    subset[0] = False
    assert frame(spanning, np.ones(len(dp), dtype=bool))
    assert not frame(spanning, subset)
    assert frame(None, subset)
