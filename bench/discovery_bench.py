"""Discrepancy-workflow benchmarks: the hidden-effect matrix and the run time of a 10-case discovery."""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml


def hidden_effect_matrix() -> dict[str, Any]:
    """effect × named first? × parameter error × gap shrink, with the test suite's draws."""
    from sim.airfoil.effects import EFFECTS
    from tests.test_discovery import draw, explainable_gap, run_hidden

    rows = []
    for effect in EFFECTS:
        rng = np.random.default_rng(sorted(EFFECTS).index(effect) + 100)
        params = draw(effect, rng)
        t0 = time.perf_counter()
        result, disc, replay = run_hidden({effect: params})
        secs = time.perf_counter() - t0
        named = [e["name"] for e in result["effects"]]
        first = result["effects"][0] if result["effects"] else None
        err = (
            max(abs(first["params"].get(p, math.nan) - v) / abs(v) for p, v in params.items())
            if first and first["name"] == effect
            else math.nan
        )
        before = explainable_gap(disc, result, replay.base_effects)
        after = explainable_gap(disc, result, result["final_effects"])
        rows.append(
            {
                "effect": effect,
                "true_params": params,
                "named": named,
                "named_first": bool(named) and named[0] == effect,
                "fitted_params": first["params"] if first else {},
                "max_param_rel_error": err,
                "gap_shrink": 1.0 - after / before if before > 0 else math.nan,
                "seconds": round(secs, 2),
            }
        )
    return {"rows": rows, "all_named_first": all(r["named_first"] for r in rows)}


def ten_case_discovery() -> dict[str, Any]:
    """10 frequencies of the URANS preset seen through the tunnel's 36 taps with two hidden effects and
    1.5 % noise, discovered against the URANS preset itself (1316 panels). Bar: ≤ 120 s."""
    from sim.presets import preset_text
    from vdm_aero_cli.discover import discover
    from vdm_aero_cli.main import main

    urans = yaml.safe_load(preset_text("naca0015-urans"))
    tunnel = yaml.safe_load(preset_text("naca0015-tunnel"))
    meas = {**urans, "name": "urans-seen-by-taps", "taps": tunnel["taps"], "noise": {"cp_std_fraction": 0.015}}
    meas["effects"] = {**urans["effects"], "lift_slope_scale": {"scale": 0.9}, "port_bias": {"U07": 0.08}}
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "m.yaml").write_text(yaml.safe_dump(meas))
        main(["simulate", str(Path(d) / "m.yaml"), "--out", str(Path(d) / "meas")])
        t0 = time.perf_counter()
        rep = discover("naca0015-urans", Path(d) / "meas", Path(d) / "report")
        secs = time.perf_counter() - t0
    return {
        "cases": 10,
        "seconds": round(secs, 1),
        "bar_seconds": 120.0,
        "meets_bar": secs <= 120.0,
        "named": [(e["name"], e["params"]) for e in rep["effects"]],
        "simulations": rep["simulations"],
    }
