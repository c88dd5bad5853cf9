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
from sim.flight.world import Vehicle
from vdm_aero.calibrate import TargetSettings, estimate_nuisance, form_targets
from vdm_aero.errors import UserInputError
from vdm_aero.flightlog import FlightLogError, load_sensor_log, load_truth
from vdm_aero.model import AeroModel
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


def _test_set(log_dir: Path, model: AeroModel) -> tuple[np.ndarray, np.ndarray]:
    data = form_targets(load_sensor_log(log_dir), load_vehicle("uav-2m"), model, SETTINGS)
    truth = load_truth(log_dir)
    idx = np.searchsorted(truth["t_s"], data.t_s)
    assert np.allclose(truth["t_s"][idx], data.t_s)
    return data.cp, truth["coeffs"][idx]


def test_the_reality_gap_is_real(study: dict[str, Path]) -> None:
    model = AeroModel.load(study["model"])
    x_b, y_b = _test_set(study["test"], model)
    x_d, y_d = _test_set(study["test_design"], model)
    built = np.sqrt(np.mean((model.predict_batch(x_b, linear_only=True) - y_b) ** 2, axis=0))
    designed = np.sqrt(np.mean((model.predict_batch(x_d, linear_only=True) - y_d) ** 2, axis=0))
    # same route, wind and seed: the built aircraft's RMS error exceeds the design aircraft's in lift (rigging,
    # slipstream, payload), drag (rough skin, slipstream) and roll (washout asymmetry, aileron offset). The
    # 12-port design DEIM is itself coarse in flight (docs/flight-sim.md gives both figures), so the gap is
    # measured against the same flight of the design aircraft, not only against held-out design data.
    assert built[2] > 1.2 * designed[2], ("CZ", built[2], designed[2])
    assert built[0] > 1.1 * designed[0], ("CX", built[0], designed[0])
    assert built[3] > 3.0 * designed[3], ("Croll", built[3], designed[3])


def test_calibration_flight_beats_design_deim(study: dict[str, Path]) -> None:
    out = study["root"] / "calibrated"
    r = subprocess.run(
        [sys.executable, "-m", "vdm_aero_cli.main", "calibrate", "--flight", str(study["calib"]), "--model",
         str(study["model"]), "--vehicle", "uav-2m", "--out", str(out), "--max-epochs", "300", "--json"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    cal = AeroModel.load(out)
    assert cal.has_correction and cal.meta["calibration"]["flight"]["samples"] > 500
    assert cal.meta["calibration"]["flight"]["path"] == str(study["calib"])
    deim = AeroModel.load(study["model"])
    x, y = _test_set(study["test"], deim)
    e_deim = l2_errors(deim.predict_batch(x, linear_only=True), y)
    e_cal = l2_errors(cal.predict_batch(x), y)
    # two minutes of calibration already cut the test-flight error of drag, pitch and roll moments
    for c in ("CX", "Cpitch", "Croll"):
        assert e_cal[c] < 0.7 * e_deim[c], (c, e_cal[c], e_deim[c])
    # and the net learnt something that holds on calibration blocks it did not train on
    m = cal.meta["calibration"]
    assert m["val_mse"] < 0.2 * m["val_mse_deim_only"]


def test_nuisance_estimates_stay_physical(study: dict[str, Path]) -> None:
    model = AeroModel.load(study["model"])
    data = form_targets(load_sensor_log(study["calib"]), load_vehicle("uav-2m"), model, SETTINGS)
    fit = estimate_nuisance(data, model)
    # the installed propeller is weaker than its data sheet: the static-thrust factor comes out below 1
    assert 0.3 < fit.thrust_factors[0] < 1.0
    assert all(s > 0 for s in fit.sigma.values())
    # targets carry the known physics: CZ ≈ −m·g/(q̄S) in level flight on average (1 g through the wing)
    level = np.abs(data.omega_b[:, 1]) < 0.05
    mg = load_vehicle("uav-2m").mass.mass_kg * 9.80665
    cz_1g = -mg / (data.qbar_pa[level] * model.reference.area_m2)
    assert np.median(fit.targets(data)[level, 2] / cz_1g) == pytest.approx(1.0, abs=0.15)


def test_calibrate_needs_a_pitot_and_the_model_ports(study: dict[str, Path], tmp_path: Path) -> None:
    log = load_sensor_log(study["calib"])
    model = AeroModel.load(study["model"])
    no_pitot = replace(log, arrays={**log.arrays, "pitot_t_s": np.zeros(0), "pitot_dp_pa": np.zeros(0)})
    with pytest.raises(UserInputError, match="no pitot"):
        form_targets(no_pitot, load_vehicle("uav-2m"), model)
    renamed = replace(log, port_names=tuple(f"x{i}" for i in range(len(log.port_names))))
    with pytest.raises(UserInputError, match="no port p"):
        form_targets(renamed, load_vehicle("uav-2m"), model)
    (tmp_path / "flight.yaml").write_text("format: something-else\n")
    with pytest.raises(FlightLogError, match=r"flight\.yaml: format"):
        load_sensor_log(tmp_path)
    r = subprocess.run(
        [sys.executable, "-m", "vdm_aero_cli.main", "calibrate", "--flight", str(tmp_path), "--model",
         str(study["model"]), "--vehicle", "uav-2m", "--out", str(tmp_path / "m")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "flight.yaml" in r.stderr
