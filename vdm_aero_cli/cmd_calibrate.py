"""``fly``, ``calibrate`` and ``calibration-study``: the as-built aircraft and the in-flight calibration."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from vdm_aero.errors import UserInputError
from vdm_aero_cli.progress import progress_bar


def register(sub: Any) -> None:
    f = sub.add_parser(
        "fly",
        help="fly a scenario in process and write its flight log (sensors + truth)",
        description="Fly a flight scenario (a shipped name or a YAML file) in the 6-DOF world and write a "
        "vdm-aero-flightlog/1 directory: sensors.npz (what the aircraft logs) and truth.npz (evaluation only).",
    )
    f.add_argument("scenario", help="scenario name (vdm-aero sitl --list) or YAML file")
    f.add_argument("--out", type=Path, required=True, metavar="DIR", help="flight-log directory to write")
    f.add_argument("--ports-from-model", type=Path, metavar="M", help="fly the ports of model directory M")
    f.add_argument("--duration", type=float, metavar="S", help="seconds to fly (default: the scenario's)")
    f.set_defaults(func=run_fly)

    c = sub.add_parser(
        "calibrate",
        help="train the correction net from a calibration flight's sensors",
        description="Form aerodynamic force and moment targets from a flight's IMU, pitot, barometer and servo "
        "outputs with the nominal vehicle description (Cp normalised by the ports' own air-data q̄, as at run "
        "time), estimate the thrust, torque and accelerometer-bias "
        "nuisances jointly, train the correction net on (ports → target − DEIM) and write model M2.",
    )
    c.add_argument("--flight", type=Path, required=True, metavar="LOG",
                   help="the calibration flight: a flight-log directory, or an autopilot log with the ports "
                   "(.tlog; DataFlash .bin and ULog .ulg carry no ports)")  # fmt: skip
    c.add_argument("--model", type=Path, required=True, metavar="M", help="the DEIM model (design data)")
    c.add_argument("--design-data", type=Path, required=True, metavar="D",
                   help="the design data set: its FADS port model normalises Cp as the run time does")  # fmt: skip
    c.add_argument("--vehicle", required=True, metavar="V", help="nominal vehicle description (file or name)")
    c.add_argument("--out", type=Path, required=True, metavar="M2", help="calibrated model directory to write")
    c.add_argument("--window", metavar="START:END", help="use only this part of the flight [s]")
    c.add_argument("--grid", choices=("paper", "quick"), default="quick")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--max-epochs", type=int, default=3000)
    c.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="target rate (default 10 Hz)")
    c.add_argument("--json", action="store_true", help="print the calibration summary as JSON")
    c.set_defaults(func=run_calibrate)

    s = sub.add_parser(
        "calibration-study",
        help="the as-built gap and the calibration table (design data → flights → calibration → test flights)",
        description="Simulate the design data set, fit DEIM, train the design net, fly the as-built calibration "
        "and test flights, calibrate on 2, 5 and 10 minutes, and report the test-flight errors of DEIM, DEIM+NN "
        "(design), DEIM+NN (calibrated) and the linear/MLP baselines.",
    )
    s.add_argument("--out", type=Path, required=True, metavar="DIR")
    s.add_argument("--sensors", type=int, default=12)
    s.add_argument("--minutes", default="2,5,10", help="calibration lengths [min], comma separated")
    s.add_argument("--test-duration", type=float, metavar="S", help="seconds of each test flight (default all)")
    s.add_argument("--grid", choices=("paper", "quick"), default="quick")
    s.add_argument("--max-epochs", type=int, default=3000)
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=run_study_cmd)


def run_fly(args: argparse.Namespace) -> int:
    from sim.flight.record import record_flight, with_model_ports
    from sim.flight.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if args.ports_from_model is not None:
        sc = with_model_ports(sc, args.ports_from_model)
    if args.duration is not None and not args.duration > 0:
        raise UserInputError(f"--duration: must be > 0 s, got {args.duration}")
    with progress_bar(f"flying {sc.name}", 100) as update:
        out = record_flight(sc, args.out, duration_s=args.duration, progress=lambda f: update(int(100 * f), 100))
    print(f"wrote {out} ({sc.name}, vehicle {sc.vehicle.name}, {len(sc.ports.names)} ports)")
    return 0


def parse_window(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise UserInputError(f"--window: expected START:END in seconds, got {text!r}") from None
    if not b > a >= 0.0:
        raise UserInputError(f"--window: expected 0 ≤ START < END, got {text!r}")
    return a, b


def read_flight(path: Path, model_dir: Path) -> Any:
    """A flight-log directory as it is, or an autopilot log read into the same SI stream (the ports in the
    model's order); the log's warnings go to stderr."""
    from vdm_aero.flightlog import load_sensor_log

    if path.is_dir():
        return load_sensor_log(path)
    from firmware_bridge.logs import read_log
    from vdm_aero.model import AeroModel

    read = read_log(path, AeroModel.load(model_dir).port_names)
    for w in read.report.warnings:
        print(f"vdm-aero calibrate: warning: {w}", file=sys.stderr)
    if not len(read.log["ports_t_s"]):
        raise UserInputError(f"{path}: no port values in the log: the correction net learns from the ports")
    return read.log


def run_calibrate(args: argparse.Namespace) -> int:
    from vdm_aero.calibrate import TargetSettings, calibrate_model
    from vdm_aero.vehicle import load_vehicle

    log = read_flight(args.flight, args.model)
    if args.window:
        log = log.window(*parse_window(args.window))
    vehicle = load_vehicle(args.vehicle)
    if not 1.0 <= args.rate <= 100.0:
        raise UserInputError(f"--rate: expected 1–100 Hz, got {args.rate}")
    with progress_bar("training the correction net", 1) as update:
        summary = calibrate_model(args.model, log, vehicle, args.out, design_data=args.design_data,
                                  grid=args.grid, seed=args.seed,
                                  max_epochs=args.max_epochs, settings=TargetSettings(rate_hz=args.rate),
                                  progress=update)  # fmt: skip
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    nu = summary["nuisance"]
    print(f"calibrated on {summary['flight']['samples']} samples of {log.path} → {args.out}")
    print(f"  thrust factors {nu['thrust_factors'][0]:.3f}, {nu['thrust_factors'][1]:.3f}; "
          f"torque factor {nu['torque_factor']:.3f}; accel bias "
          + ", ".join(f"{v:+.3f}" for v in nu["accel_bias_b_m_s2"]) + " m/s²")  # fmt: skip
    print(f"  net {summary['selected']}, validation MSE {summary['val_mse']:.3g} (DEIM alone "
          f"{summary['val_mse_deim_only']:.3g})")  # fmt: skip
    ps = summary["port_speed"]
    print(f"  ports' airspeed against the pitot: {ps['rms_before_m_s']:.2f} → {ps['rms_after_m_s']:.2f} m/s rms, "
          f"table over α {ps['alpha_knots_deg'][0]:g}…{ps['alpha_knots_deg'][-1]:g}°")  # fmt: skip
    return 0


def run_study_cmd(args: argparse.Namespace) -> int:
    from vdm_aero_cli.calibration_study import run_study

    try:
        minutes = [float(v) for v in args.minutes.split(",")]
    except ValueError:
        raise UserInputError(f"--minutes: expected numbers separated by commas, got {args.minutes!r}") from None
    if not minutes or min(minutes) < 1.0 or max(minutes) > 10.0:
        raise UserInputError("--minutes: each length must be within 1–10 minutes (the calibration flight's length)")
    run_study(args.out, n_sensors=args.sensors, calibration_minutes=minutes, test_duration_s=args.test_duration,
              grid=args.grid, seed=args.seed, max_epochs=args.max_epochs)  # fmt: skip
    print((args.out / "calibration.md").read_text())
    print(f"plot: {args.out / 'calibration-length.png'}")
    return 0
