"""This machine's single-core Python speed against a Raspberry Pi 4's, from one published measurement.

The reference: C. Mehta, "Performance Analysis of Languages on Raspberry Pi"
(https://chaitanyamehta.github.io/projects/performance-analysis-of-programming-languages): the N-body benchmark
(the Computer Language Benchmarks Game's gravitational simulation of the Sun and the four giant planets),
five million steps, in CPython on a Raspberry Pi 4 Model B (Cortex-A72, 1.5 GHz, performance governor): 158.263 s.
The page does not give its program, so this is the Benchmarks Game's algorithm in plain Python (pairs of
bodies, ``advance`` with ``dt`` = 0.01); the ratio is indicative (±30 % for a different but equivalent
program) and the Pi's Python version is unknown. A Compute Module 4 has the same cores and clock.

    python bench/pi_ratio.py [--steps 5000000]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

PI4_SECONDS_5M_STEPS = 158.263  # the reference's CPython figure, performance governor
SOLAR_MASS = 4.0 * math.pi * math.pi
DAYS_PER_YEAR = 365.24


def _bodies() -> list[list[float]]:
    """[x, y, z, vx, vy, vz, mass] of the Sun, Jupiter, Saturn, Uranus and Neptune (AU, AU/year)."""
    d = DAYS_PER_YEAR
    planets = [
        [4.84143144246472090e00, -1.16032004402742839e00, -1.03622044471123109e-01, 1.66007664274403694e-03 * d,
         7.69901118419740425e-03 * d, -6.90460016972063023e-05 * d, 9.54791938424326609e-04 * SOLAR_MASS],
        [8.34336671824457987e00, 4.12479856412430479e00, -4.03523417114321381e-01, -2.76742510726862411e-03 * d,
         4.99852801234917238e-03 * d, 2.30417297573763929e-05 * d, 2.85885980666130812e-04 * SOLAR_MASS],
        [1.28943695621391310e01, -1.51111514016986312e01, -2.23307578892655734e-01, 2.96460137564761618e-03 * d,
         2.37847173959480950e-03 * d, -2.96589568540237556e-05 * d, 4.36624404335156298e-05 * SOLAR_MASS],
        [1.53796971148509165e01, -2.59193146099879641e01, 1.79258772950371181e-01, 2.68067772490389322e-03 * d,
         1.62824170038242295e-03 * d, -9.51592254519715870e-05 * d, 5.15138902046611451e-05 * SOLAR_MASS],
    ]  # fmt: skip
    sun = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, SOLAR_MASS]
    px = sum(b[3] * b[6] for b in planets)
    py = sum(b[4] * b[6] for b in planets)
    pz = sum(b[5] * b[6] for b in planets)
    sun[3], sun[4], sun[5] = -px / SOLAR_MASS, -py / SOLAR_MASS, -pz / SOLAR_MASS
    return [sun, *planets]


def energy(bodies: list[list[float]]) -> float:
    e = 0.0
    for i, a in enumerate(bodies):
        e += 0.5 * a[6] * (a[3] * a[3] + a[4] * a[4] + a[5] * a[5])
        for b in bodies[i + 1 :]:
            e -= a[6] * b[6] / math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)
    return e


def advance(bodies: list[list[float]], dt: float, steps: int) -> None:
    pairs = [(bodies[i], bodies[j]) for i in range(len(bodies)) for j in range(i + 1, len(bodies))]
    for _ in range(steps):
        for a, b in pairs:
            dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
            mag = dt / ((dx * dx + dy * dy + dz * dz) ** 1.5)
            bm, am = b[6] * mag, a[6] * mag
            a[3] -= dx * bm
            a[4] -= dy * bm
            a[5] -= dz * bm
            b[3] += dx * am
            b[4] += dy * am
            b[5] += dz * am
        for body in bodies:
            body[0] += dt * body[3]
            body[1] += dt * body[4]
            body[2] += dt * body[5]


def measure(steps: int = 5_000_000) -> dict[str, float]:
    """CPU seconds for ``steps`` here, scaled to 5 M, and the Pi 4's time over it (how many times slower)."""
    bodies = _bodies()
    e0 = energy(bodies)
    t0 = time.process_time()
    advance(bodies, 0.01, steps)
    cpu = time.process_time() - t0
    here_5m = cpu * 5_000_000 / steps
    return {"steps": steps, "cpu_s": round(cpu, 2), "seconds_5m_steps_here": round(here_5m, 2),
            "pi4_seconds_5m_steps": PI4_SECONDS_5M_STEPS, "pi4_slower_x": round(PI4_SECONDS_5M_STEPS / here_5m, 2),
            "energy_before": e0, "energy_after": energy(bodies)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=5_000_000)
    json.dump(measure(ap.parse_args(argv).steps), sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
