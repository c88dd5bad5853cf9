"""CPU per 50 Hz filter step of each navigation mode: the figure of issue 25, measured the same way on any
version of the code.

Run as a script with a checkout first on ``PYTHONPATH`` (``bench/baseline.py`` does that for the code before
issue 25), so the one measurement compares two versions side by side. It uses only interfaces both have: the
benchmark's flight and models (``vdm_aero_cli.nav_bench``), ``NavStream.from_log``, ``LogRunner``,
``NavFilter``, ``PortFrontEnd``. The stream is built once; what is timed is ``LogRunner.run_until``: the
filter with the driver in front of it, and the port front end only for a mode that reads the ports (what the
service and the replay run per mode).

    python bench/filter_speed_probe.py ARTIFACTS_DIR --seconds 120 --repeats 5 --modes ins,vdm

``--engine-share`` times, in the same runs, the calls into filterpy's ``ExtendedKalmanFilter.predict`` and
``update`` (the engine issue 25 keeps) and reports their share of the step: a step cannot get faster than
that share allows while those calls stay in it, whatever the rest of the code costs (docs/performance.md,
"The ceiling filterpy sets").
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

FILTER_RATE_HZ = 50.0


@contextmanager
def engine_clock() -> Iterator[dict[str, float]]:
    """CPU seconds and calls spent inside filterpy's EKF ``predict`` and ``update`` while the block runs (the
    class's methods are wrapped for its duration and put back after)."""
    from filterpy.kalman import ExtendedKalmanFilter

    acc = {"cpu_s": 0.0, "calls": 0.0}
    originals = {name: getattr(ExtendedKalmanFilter, name) for name in ("predict", "update")}

    def timed(method: Callable[..., Any]) -> Callable[..., Any]:
        def call(self: Any, *args: Any, **kwargs: Any) -> Any:
            t0 = time.process_time()
            try:
                return method(self, *args, **kwargs)
            finally:
                acc["cpu_s"] += time.process_time() - t0
                acc["calls"] += 1

        return call

    try:
        for name, method in originals.items():
            setattr(ExtendedKalmanFilter, name, timed(method))
        yield acc
    finally:
        for name, method in originals.items():
            setattr(ExtendedKalmanFilter, name, method)


def _front_end(nav: Any) -> Any:
    """A port front end for one run, as each version builds it: ``NavModels.front_end`` where the checkout has it
    (it adds the ports' airspeed calibration), else the ``PortFrontEnd`` constructor as the code before issue 25
    calls it (``make bench`` runs this script on both: an AttributeError there stopped it from 2026-11-30 to
    2026-12-02)."""
    if hasattr(nav, "front_end"):
        return nav.front_end(range_pa=500.0, noise_pa=0.2)
    from vdm_aero.nav.ports_frontend import PortFrontEnd

    return PortFrontEnd(nav.pressure_model, dict(nav.models), range_pa=500.0, noise_pa=0.2)


def measure(artifacts_dir: Path, seconds: float, repeats: int, modes: list[str], *,
            engine_share: bool = False) -> dict[str, Any]:  # fmt: skip
    from vdm_aero.geodesy import LocalFrame
    from vdm_aero.nav.filter import MODES, NavConfig, NavFilter, mode_spec
    from vdm_aero.nav.replay import SensorLog
    from vdm_aero.nav.stream import LogRunner, NavStream
    from vdm_aero_cli.nav_bench import NavArtifacts, _flight, _nav

    art = NavArtifacts.under(artifacts_dir, 10.0)
    sensors, _truth, meta, _ = _flight("survey", 0, art, seconds)
    nav = _nav(art)
    home = meta["home"]
    frame = LocalFrame(home["lat_deg"], home["lon_deg"], home["alt_m"])
    log = SensorLog(path=Path("<probe>"), meta={"duration_s": meta["duration_s"]}, port_names=(), arrays=sensors)
    cfg = NavConfig.for_imu(meta.get("imu_part", "icm-42688-p"), vehicle=nav.vehicle, origin_alt_m=home["alt_m"],
                            mag_field_ned_ut=np.asarray(meta["mag_field_ned_t"]) * 1e6)  # fmt: skip
    stream = NavStream.from_log(log, nav.vehicle, frame, filter_rate_hz=cfg.filter_rate_hz,
                                gnss_latency_s=cfg.gnss_latency_s)  # fmt: skip
    steps = (seconds - 1.0) * FILTER_RATE_HZ
    out: dict[str, Any] = {}
    for m in modes or list(MODES):
        spec = mode_spec(m)
        reads_ports = spec.ports_airdata or spec.force in ("deim", "deim-nn")
        times, shares, calls = [], [], []
        for _ in range(repeats):
            fe = _front_end(nav) if reads_ports else None
            runner = LogRunner(stream, {m: NavFilter(m, cfg, nav.derivatives)}, fe)
            if engine_share:
                with engine_clock() as engine:
                    t0 = time.process_time()
                    runner.run_until(seconds - 1.0)
                    cpu_s = time.process_time() - t0
                shares.append(engine["cpu_s"] / cpu_s)
                calls.append(engine["calls"] / steps)
                continue
            t0 = time.process_time()
            runner.run_until(seconds - 1.0)
            times.append(time.process_time() - t0)
        if engine_share:
            out[m] = {
                "engine_share": round(statistics.median(shares), 3),
                "runs_engine_share": [round(v, 3) for v in shares],
                "engine_calls_per_step": round(statistics.median(calls), 2),
            }
            continue
        cpu = statistics.median(times)
        out[m] = {"us_per_step": round(1e6 * cpu / steps, 1), "x_real_time": round((seconds - 1.0) / cpu, 1),
                  "runs_us_per_step": [round(1e6 * t / steps, 1) for t in times]}  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("artifacts", type=Path)
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--modes", default="")
    ap.add_argument(
        "--engine-share",
        action="store_true",
        help="report the share of each step spent in filterpy's predict and update instead of the time",
    )
    args = ap.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    json.dump(measure(args.artifacts, args.seconds, args.repeats, modes, engine_share=args.engine_share), sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
