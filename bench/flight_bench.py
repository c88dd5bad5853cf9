"""Flight-simulator benchmark: minutes of 6-DOF flight with every sensor, in process, no sockets.

Bar (issue 6): 10 minutes of flight in ≤ 30 s on the 2-core development machine. The vehicle build
(airframe spec → pressure model, NeuralFoil separation calibration) happens once per process and is
reported separately; the timed part is ``FlightWorld`` construction (trim) plus stepping, with every
sample produced and counted (what a consumer of the ticks would receive).
"""

from __future__ import annotations

import time
from typing import Any

BAR_SECONDS_PER_10_MIN = 30.0
SCENARIO = "survey-wind8"  # all sensors on board (pitot, ports at 50 Hz), wind, light turbulence, an outage


def bench_flight(minutes: float = 10.0) -> dict[str, Any]:
    """Fly ``minutes`` of the survey-wind8 scenario; wall time, per-step cost and sample counts."""
    from sim.flight.scenario import load_scenario
    from sim.flight.world import FlightWorld, Vehicle

    scenario = load_scenario(SCENARIO)
    t0 = time.perf_counter()
    vehicle = Vehicle.build(scenario.vehicle)
    build_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    world = FlightWorld(scenario, vehicle)
    n_steps = round(minutes * 60.0 / world.dt_s)
    counts = {k: 0 for k in ("imu", "gnss", "baro", "mag", "airspeed", "ports", "servos")}
    for _ in range(n_steps):
        tick = world.step()
        for k in counts:
            if getattr(tick, k) is not None:
                counts[k] += 1
    seconds = time.perf_counter() - t0

    per_10_min = seconds * 10.0 / minutes
    return {
        "name": f"flight {SCENARIO}",
        "flight_minutes": minutes,
        "steps": n_steps,
        "physics_rate_hz": scenario.simulation.physics_rate_hz,
        "aero_rate_hz": scenario.simulation.aero_rate_hz,
        "aero_updates_per_s": round(world.aero.updates / (minutes * 60.0), 2),
        "seconds": round(seconds, 2),
        "seconds_per_10_min": round(per_10_min, 2),
        "us_per_step": round(seconds / n_steps * 1e6, 1),
        "realtime_factor": round(minutes * 60.0 / seconds, 1),
        "vehicle_build_seconds": round(build_s, 2),
        "samples": counts,
        "bar_seconds_per_10_min": BAR_SECONDS_PER_10_MIN,
        "meets_bar": per_10_min <= BAR_SECONDS_PER_10_MIN,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(bench_flight(), indent=2))
