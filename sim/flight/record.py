"""Fly a scenario in process and record its sensor streams (and truth) as a ``vdm-aero-flightlog/1``.

The sensors are what the aircraft would log; the truth (coefficients about the true CG, states) goes to a
separate file that only evaluation reads (:mod:`vdm_aero.flightlog`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from sim.flight.ap_attitude import AP_ATTITUDE_RATE_HZ, AutopilotAttitude
from sim.flight.scenario import Scenario
from sim.flight.world import FlightWorld, Vehicle
from vdm_aero.errors import ModelError, SpecError
from vdm_aero.flightlog import SENSOR_KEYS, write_flight_log
from vdm_aero.model import read_model_yaml

__all__ = ["fly", "record_flight", "with_model_ports"]


def with_model_ports(scenario: Scenario, model_dir: str | Path) -> Scenario:
    """The scenario flying the ports of an aero model directory (names and locations of its ``model.yaml``)."""
    root = Path(model_dir)
    try:
        meta = read_model_yaml(root)
        names = tuple(str(p["name"]) for p in meta["ports"])
        points = tuple((float(p["point_b"][0]), float(p["point_b"][1]), float(p["point_b"][2])) for p in meta["ports"])
    except (KeyError, TypeError, ValueError) as e:
        raise ModelError(f"{root / 'model.yaml'}: ports: {e}") from None
    for n in names:
        if not 0 < len(n) <= 10:
            raise SpecError(f"{root}: port name {n!r} does not fit a MAVLink NAMED_VALUE_FLOAT (1..10 characters)")
    return replace(scenario, ports=replace(scenario.ports, names=names, points_b=points, layout_source=f"model {root}"))


def fly(
    scenario: Scenario,
    vehicle: Vehicle | None = None,
    *,
    duration_s: float | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], FlightWorld]:
    """Fly ``scenario`` and return (sensor arrays, truth arrays at the port times, the world)."""
    world = FlightWorld(scenario, vehicle)
    n = round((scenario.duration_s if duration_s is None else duration_s) / world.dt_s)
    rec: dict[str, list[Any]] = {k: [] for k in SENSOR_KEYS}
    tr: dict[str, list[Any]] = {
        k: []
        for k in (
            "t_s", "coeffs", "qbar_pa", "airspeed_m_s", "alpha_rad", "beta_rad", "pos_ned_m", "v_ned_m_s", "q_nb",
            "omega_b_rad_s", "wind_ned_m_s", "thrust_n", "rho_kg_m3",
        )
    }  # fmt: skip
    every = max(n // 100, 1)
    ap_att, next_att_s = AutopilotAttitude(), -np.inf
    for i in range(n):
        tick = world.step()
        if (imu := tick.imu) is not None:
            rec["imu_t_s"].append(imu.t_s)
            rec["imu_accel_b_m_s2"].append(imu.accel_b_m_s2)
            rec["imu_gyro_b_rad_s"].append(imu.gyro_b_rad_s)
            rec["imu_temperature_c"].append(imu.temperature_c)
            ap_att.step(imu, tick.truth)
            if imu.t_s >= next_att_s:  # the autopilot's ATTITUDE, at the rate the service asks for it
                next_att_s = imu.t_s + 1.0 / AP_ATTITUDE_RATE_HZ - 1e-9
                rec["ap_att_t_s"].append(imu.t_s)
                rec["ap_att_q_nb"].append(ap_att.q_nb(tick.truth))
        if (g := tick.gnss) is not None and g.fix_type >= 3:
            rec["gnss_t_s"].append(g.t_s)
            rec["gnss_lat_deg"].append(g.lat_deg)
            rec["gnss_lon_deg"].append(g.lon_deg)
            rec["gnss_alt_m"].append(g.alt_m)
            rec["gnss_v_ned_m_s"].append(g.v_ned_m_s)
            rec["gnss_h_acc_m"].append(g.h_acc_m)
            rec["gnss_v_acc_m"].append(g.v_acc_m)
        if (b := tick.baro) is not None:
            rec["baro_t_s"].append(b.t_s)
            rec["baro_pa"].append(b.pressure_pa)
        if (m := tick.mag) is not None:
            rec["mag_t_s"].append(m.t_s)
            rec["mag_field_b_t"].append(m.field_b_t)
        if (a := tick.airspeed) is not None:
            rec["pitot_t_s"].append(a.t_s)
            rec["pitot_dp_pa"].append(a.dp_pa)
            rec["pitot_temperature_c"].append(a.temperature_c)
        if (s := tick.servos) is not None:
            rec["servo_t_s"].append(s.t_s)
            rec["servo_pwm_us"].append(s.pwm_us)
        if (p := tick.ports) is not None:
            rec["ports_t_s"].append(p.t_s)
            rec["ports_dp_pa"].append(p.dp_pa)
            t = tick.truth
            rho = world._rho
            tr["t_s"].append(t.t_s)
            tr["coeffs"].append(world.aero_coeffs())
            tr["qbar_pa"].append(0.5 * rho * t.airspeed_m_s**2)
            tr["rho_kg_m3"].append(rho)
            tr["airspeed_m_s"].append(t.airspeed_m_s)
            tr["alpha_rad"].append(t.alpha_rad)
            tr["beta_rad"].append(t.beta_rad)
            tr["pos_ned_m"].append(t.pos_ned_m)
            tr["v_ned_m_s"].append(t.v_ned_m_s)
            tr["q_nb"].append(t.q_nb)
            tr["omega_b_rad_s"].append(t.omega_b_rad_s)
            tr["wind_ned_m_s"].append(t.wind_ned_m_s)
            tr["thrust_n"].append(world.aux.thrust)
        if progress is not None and i % every == 0:
            progress((i + 1) / n)
    n_ports = len(world.ports)
    empty_cols = {"imu_accel_b_m_s2": 3, "imu_gyro_b_rad_s": 3, "ports_dp_pa": n_ports, "servo_pwm_us": 4,
                  "gnss_v_ned_m_s": 3, "mag_field_b_t": 3, "ap_att_q_nb": 4}  # fmt: skip
    sensors = {
        k: (np.asarray(v, dtype=np.float64) if v else np.zeros((0, empty_cols[k]) if k in empty_cols else 0))
        for k, v in rec.items()
    }
    truth = {k: np.asarray(v, dtype=np.float64) for k, v in tr.items()}
    return sensors, truth, world


def record_flight(
    scenario: Scenario,
    out: str | Path,
    vehicle: Vehicle | None = None,
    *,
    duration_s: float | None = None,
    progress: Callable[[float], None] | None = None,
) -> Path:
    """Fly and write the flight log directory ``out``."""
    sensors, truth, world = fly(scenario, vehicle, duration_s=duration_s, progress=progress)
    meta = {
        "name": scenario.name,
        "source": {
            "simulator": "sim.flight",
            "scenario": scenario.name,
            "scenario_origin": scenario.origin,
            "vehicle": scenario.vehicle.name,
            "as_built_effects": sorted(scenario.as_built_effects),
            "seed": scenario.seed,
        },
        "duration_s": float(world.t_s),
        "home": {"lat_deg": scenario.home_lat_deg, "lon_deg": scenario.home_lon_deg, "alt_m": scenario.home_alt_m},
    }
    return write_flight_log(out, meta=meta, port_names=tuple(world.ports.names), sensors=sensors, truth=truth)
