"""In-flight calibration: the reality gap is real, and a calibration flight closes much of it.

Design data (uav-envelope) → DEIM → the as-built aircraft flies a calibration flight and a test flight
(other scenario, wind, turbulence seed and manoeuvres) → ``vdm-aero calibrate`` from the sensors and the
nominal vehicle description only → errors against the truth on the test flight.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sim.flight.record import record_flight, with_model_ports
from sim.flight.scenario import VEHICLES, load_scenario
from sim.flight.world import FlightWorld, Vehicle
from vdm_aero.calibrate import TargetSettings, estimate_nuisance, form_targets
from vdm_aero.errors import UserInputError
from vdm_aero.flightlog import FlightLogError, load_sensor_log, load_truth
from vdm_aero.model import AeroModel
from vdm_aero.nav.design_fit import DesignFlightData, PortPressureModel
from vdm_aero.nav.models import NavModels
from vdm_aero.vehicle import load_vehicle
from vdm_aero_cli.calibration_study import l2_errors

SETTINGS = TargetSettings(rate_hz=10.0)


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory, design_deim12: dict[str, Path]) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("calibration")
    ds_dir, model_dir = design_deim12["data"], design_deim12["model"]
    vehicle = Vehicle.build("uav-2m-asbuilt")
    calib = with_model_ports(load_scenario("calibration-asbuilt"), model_dir)
    test = with_model_ports(load_scenario("asbuilt-survey-test"), model_dir)
    out = {
        "data": ds_dir,
        "model": model_dir,
        "calib": record_flight(calib, root / "calib", vehicle, duration_s=140.0),
        "test": record_flight(test, root / "test", vehicle, duration_s=90.0),
        # the same test flight by the design aircraft: what the data set's own truth would give
        "test_design": record_flight(
            replace(test, vehicle=VEHICLES["uav-2m"], as_built_effects=frozenset()), root / "test-design",
            duration_s=90.0,
        ),
        "root": root,
    }  # fmt: skip
    return out


@pytest.fixture(scope="module")
def pressure(study: dict[str, Path]) -> PortPressureModel:
    """The FADS port model of the design data set: what normalises Cp in calibration and at run time."""
    return PortPressureModel.fit(DesignFlightData.load(study["data"], AeroModel.load(study["model"]).port_names))


def _test_set(log_dir: Path, model: AeroModel, pressure: PortPressureModel) -> tuple[np.ndarray, np.ndarray]:
    data = form_targets(load_sensor_log(log_dir), load_vehicle("uav-2m"), model, pressure, SETTINGS)
    truth = load_truth(log_dir)
    idx = np.searchsorted(truth["t_s"], data.t_s)
    assert np.allclose(truth["t_s"][idx], data.t_s)
    return data.cp, truth["coeffs"][idx]


def test_the_reality_gap_is_real(study: dict[str, Path], pressure: PortPressureModel) -> None:
    model = AeroModel.load(study["model"])
    x_b, y_b = _test_set(study["test"], model, pressure)
    x_d, y_d = _test_set(study["test_design"], model, pressure)
    built = np.sqrt(np.mean((model.predict_batch(x_b, linear_only=True) - y_b) ** 2, axis=0))
    designed = np.sqrt(np.mean((model.predict_batch(x_d, linear_only=True) - y_d) ** 2, axis=0))
    # same route, wind and seed: the built aircraft's RMS error exceeds the design aircraft's in lift (rigging,
    # slipstream, payload), drag (rough skin, slipstream) and roll (washout asymmetry, aileron offset). The
    # 12-port design DEIM is itself coarse in flight (docs/flight-sim.md gives both figures), so the gap is
    # measured against the same flight of the design aircraft, not only against held-out design data.
    assert built[2] > 1.2 * designed[2], ("CZ", built[2], designed[2])
    assert built[0] > 1.1 * designed[0], ("CX", built[0], designed[0])
    assert built[3] > 3.0 * designed[3], ("Croll", built[3], designed[3])


def _calibrate(flight: Path, model: Path, data: Path, out: Path, *, as_json: bool = True
               ) -> subprocess.CompletedProcess[str]:  # fmt: skip
    return subprocess.run(
        [sys.executable, "-m", "vdm_aero_cli.main", "calibrate", "--flight", str(flight), "--model", str(model),
         "--design-data", str(data), "--vehicle", "uav-2m", "--out", str(out), "--max-epochs", "300"]
        + (["--json"] if as_json else []),
        capture_output=True, text=True, check=False,
    )  # fmt: skip


@pytest.fixture(scope="module")
def calibrated(study: dict[str, Path]) -> Path:
    """``vdm-aero calibrate`` on the calibration flight's log directory."""
    out = study["root"] / "calibrated"
    r = _calibrate(study["calib"], study["model"], study["data"], out, as_json=False)
    assert r.returncode == 0, r.stderr
    assert "ports' airspeed against the pitot: " in r.stdout and " m/s rms, table over α " in r.stdout, r.stdout
    return out


def test_calibration_flight_beats_design_deim(study: dict[str, Path], calibrated: Path,
                                              pressure: PortPressureModel) -> None:  # fmt: skip
    out = calibrated
    cal = AeroModel.load(out)
    assert cal.has_correction and cal.meta["calibration"]["flight"]["samples"] > 500
    assert cal.meta["calibration"]["flight"]["path"] == str(study["calib"])
    deim = AeroModel.load(study["model"])
    x, y = _test_set(study["test"], deim, pressure)
    e_deim = l2_errors(deim.predict_batch(x, linear_only=True), y)
    e_cal = l2_errors(cal.predict_batch(x), y)
    # two minutes of calibration already cut the test-flight error of drag, pitch and roll moments
    for c in ("CX", "Cpitch", "Croll"):
        assert e_cal[c] < 0.7 * e_deim[c], (c, e_cal[c], e_deim[c])
    # and the net learnt something that holds on calibration blocks it did not train on
    m = cal.meta["calibration"]
    assert m["val_mse"] < 0.2 * m["val_mse_deim_only"]


def test_the_ports_airspeed_is_calibrated_against_the_pitot(study: dict[str, Path], calibrated: Path,
                                                              pressure: PortPressureModel) -> None:  # fmt: skip
    """The calibration flight also fits the ports' airspeed table; on the test flight (another route, wind and
    turbulence) it brings the as-built ports' airspeed nearer the truth."""
    cal = NavModels.from_model(study["data"], calibrated).port_speed
    assert cal is not None and cal.samples > 500 and cal.rms_after_m_s < cal.rms_before_m_s
    data = form_targets(load_sensor_log(study["test"]), load_vehicle("uav-2m"), AeroModel.load(study["model"]),
                        pressure, SETTINGS)  # fmt: skip
    truth = load_truth(study["test"])
    v_true = truth["airspeed_m_s"][np.searchsorted(truth["t_s"], data.t_s)]
    ok = np.isfinite(data.ports_airspeed_m_s)
    v, a = data.ports_airspeed_m_s[ok], data.ports_alpha_rad[ok]
    before = np.sqrt(np.mean((v - v_true[ok]) ** 2))
    after = np.sqrt(np.mean((np.array([cal.correct(x, y) for x, y in zip(v, a, strict=True)]) - v_true[ok]) ** 2))
    assert after < 0.7 * before, (after, before)


def test_nuisance_estimates_stay_physical(study: dict[str, Path], pressure: PortPressureModel) -> None:
    model = AeroModel.load(study["model"])
    data = form_targets(load_sensor_log(study["calib"]), load_vehicle("uav-2m"), model, pressure, SETTINGS)
    fit = estimate_nuisance(data, model)
    # the installed propeller is weaker than its data sheet: the static-thrust factor comes out below 1
    assert 0.3 < fit.thrust_factors[0] < 1.0
    assert all(s > 0 for s in fit.sigma.values())
    # targets carry the known physics: CZ ≈ −m·g/(q̄S) in level flight on average (1 g through the wing)
    level = np.abs(data.omega_b[:, 1]) < 0.05
    mg = load_vehicle("uav-2m").mass.mass_kg * 9.80665
    cz_1g = -mg / (data.qbar_pa[level] * model.reference.area_m2)
    assert np.median(fit.targets(data)[level, 2] / cz_1g) == pytest.approx(1.0, abs=0.15)


def test_cp_is_normalised_as_at_run_time_not_by_the_pitot(study: dict[str, Path], pressure: PortPressureModel,
                                                           calibrated: Path, tmp_path: Path) -> None:  # fmt: skip
    """The net's inputs in calibration are the run time's: Cp = Δp / q̄ of the ports' air-data solve. A pitot
    that reads 20 % low (a bad ARSPD_RATIO) scales the targets, never the Cp."""
    log = load_sensor_log(study["calib"])
    model = AeroModel.load(study["model"])
    low = replace(log, arrays={**log.arrays, "pitot_dp_pa": 0.8 * log["pitot_dp_pa"]})
    a = form_targets(log, load_vehicle("uav-2m"), model, pressure, SETTINGS)
    b = form_targets(low, load_vehicle("uav-2m"), model, pressure, SETTINGS)
    both = np.isin(a.t_s, b.t_s)
    np.testing.assert_allclose(b.cp, a.cp[both], rtol=1e-9)
    assert np.median(b.kinematic[:, 2] / a.kinematic[both, 2]) == pytest.approx(1.25, rel=1e-6)
    # a model calibrated the old way (Cp by the pitot's q̄) is refused with one line naming its file
    old = tmp_path / "old"
    import shutil

    import yaml

    shutil.copytree(calibrated, old)
    meta = yaml.safe_load((old / "model.yaml").read_text())
    del meta["calibration"]["targets"]["cp_qbar"]
    (old / "model.yaml").write_text(yaml.safe_dump(meta))
    from vdm_aero.errors import ModelError

    with pytest.raises(ModelError, match=r"old/model\.yaml: calibration: .*calibrate it again"):
        AeroModel.load(old)


def test_calibrate_needs_a_pitot_and_the_model_ports(study: dict[str, Path], pressure: PortPressureModel,
                                                     tmp_path: Path) -> None:  # fmt: skip
    log = load_sensor_log(study["calib"])
    model = AeroModel.load(study["model"])
    no_pitot = replace(log, arrays={**log.arrays, "pitot_t_s": np.zeros(0), "pitot_dp_pa": np.zeros(0)})
    with pytest.raises(UserInputError, match="no pitot"):
        form_targets(no_pitot, load_vehicle("uav-2m"), model, pressure)
    renamed = replace(log, port_names=tuple(f"x{i}" for i in range(len(log.port_names))))
    with pytest.raises(UserInputError, match="no port p"):
        form_targets(renamed, load_vehicle("uav-2m"), model, pressure)
    (tmp_path / "flight.yaml").write_text("format: something-else\n")
    with pytest.raises(FlightLogError, match=r"flight\.yaml: format"):
        load_sensor_log(tmp_path)
    r = subprocess.run(
        [sys.executable, "-m", "vdm_aero_cli.main", "calibrate", "--flight", str(tmp_path), "--model",
         str(study["model"]), "--design-data", str(study["data"]), "--vehicle", "uav-2m", "--out",
         str(tmp_path / "m")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "flight.yaml" in r.stderr


def test_calibration_from_a_mock_tlog_trains_the_same_correction(
    study: dict[str, Path], calibrated: Path, pressure: PortPressureModel, tmp_path: Path
) -> None:
    """The same calibration flight recorded by the mock autopilot as a tlog (the streams the service asks for,
    the ports as named values): ``calibrate --flight X.tlog`` trains a correction that is the log directory's
    within a quarter of the correction's own size on the test flight, and as good against the truth."""
    import math

    from sim.sitl.autopilot import AutopilotOptions, run_sitl
    from vdm_aero_cli.replay_golden import LOOP_RATE_HZ, STREAMS, UNIX_TIME_AT_BOOT_S

    calib = with_model_ports(load_scenario("calibration-asbuilt"), study["model"])
    tlog = tmp_path / "calib.tlog"
    run_sitl(FlightWorld(calib), "null", speed=math.inf, duration_s=140.0, tlog=tlog, stream_rates=STREAMS,
             options=AutopilotOptions(gcs_recording=True, unix_time_at_boot_s=UNIX_TIME_AT_BOOT_S,
                                      loop_rate_hz=LOOP_RATE_HZ))  # fmt: skip
    r = _calibrate(tlog, study["model"], study["data"], tmp_path / "cal-tlog")
    assert r.returncode == 0, r.stderr
    import json

    # the ports' airspeed table from the tlog's named values is the log directory's
    tab_t, tab_d = json.loads(r.stdout)["port_speed"], AeroModel.load(calibrated).meta["calibration"]["port_speed"]
    assert tab_t["samples"] > 500
    for a_deg in (0.0, 2.0, 4.0):
        r_t = np.interp(a_deg, tab_t["alpha_knots_deg"], tab_t["ratio"])
        r_d = np.interp(a_deg, tab_d["alpha_knots_deg"], tab_d["ratio"])
        assert r_t == pytest.approx(r_d, abs=0.02), (a_deg, r_t, r_d)
    from_tlog, from_dir = AeroModel.load(tmp_path / "cal-tlog"), AeroModel.load(calibrated)
    meta = from_tlog.meta["calibration"]
    assert meta["flight"]["path"] == str(tlog) and meta["flight"]["samples"] > 500
    nu_t, nu_d = meta["nuisance"], from_dir.meta["calibration"]["nuisance"]
    assert np.allclose(nu_t["thrust_factors"], nu_d["thrust_factors"], rtol=0.05), (nu_t, nu_d)
    deim = AeroModel.load(study["model"])
    x, y = _test_set(study["test"], deim, pressure)
    c_t, c_d, c_0 = from_tlog.predict_batch(x), from_dir.predict_batch(x), deim.predict_batch(x, linear_only=True)
    e_t, e_d = l2_errors(c_t, y), l2_errors(c_d, y)
    for j, c in enumerate(("CX", "CY", "CZ", "Croll", "Cpitch", "Cyaw")):
        size = float(np.sqrt(np.mean((c_d[:, j] - c_0[:, j]) ** 2)))
        gap = float(np.sqrt(np.mean((c_t[:, j] - c_d[:, j]) ** 2)))
        assert gap <= 0.25 * size, (c, gap, size)
        assert e_t[c] <= 1.15 * e_d[c], (c, e_t[c], e_d[c])
