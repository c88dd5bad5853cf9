"""The replay's outputs: the reference it is judged against, the report (markdown + JSON), the error-vs-time
plot and the navigation solution as CSV. Where the log holds the autopilot's own position estimate, the report
puts its error beside the modes' outside the outages (:func:`vdm_aero.nav.replay.compare_autopilot`)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from firmware_bridge.logs import ReadReport, TruthTrack
from vdm_aero.flightlog import SensorLog
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.filter import MODES
from vdm_aero.nav.replay import Reference, ReplayRun, autopilot_estimate, compare_autopilot, score, solution_table

__all__ = ["autopilot_source", "reference_of", "write_replay_report"]

# the messages an autopilot's own position estimate is read from, for a reader that does not name its source
AP_POSITION_MESSAGES = ("GLOBAL_POSITION_INT", "POS", "XKF1", "NKF1", "vehicle_global_position",
                        "vehicle_local_position")  # fmt: skip
AP_NOT_COMPARABLE = ("not comparable inside the outages: the autopilot had GNSS throughout the real flight (the "
                     "outages are cut out of the log only for the replay)")  # fmt: skip
AP_NONE = ("none in the log (no GLOBAL_POSITION_INT, POS, XKF1/NKF1 with ORGN, vehicle_global_position or "
           "vehicle_local_position with a global reference)")  # fmt: skip


def reference_of(log: SensorLog, truth: TruthTrack | None, origin: tuple[float, float, float]) -> Reference:
    """The truth when there is one, else the log's GNSS fixes, in the replay's local frame."""
    frame = LocalFrame(*origin)
    if truth is not None:
        alt = np.where(np.isfinite(truth.alt_m), truth.alt_m, origin[2])
        p = np.asarray(frame.to_ned(truth.lat_deg, truth.lon_deg, alt)).reshape(-1, 3)
        p[~np.isfinite(truth.alt_m), 2] = math.nan
        return Reference(f"truth: {truth.source}", truth.t_s, p)
    p = np.asarray(frame.to_ned(log["gnss_lat_deg"], log["gnss_lon_deg"], log["gnss_alt_m"])).reshape(-1, 3)
    return Reference("the log's own GNSS (not seen by the filters inside the outages)", log["gnss_t_s"], p)


def autopilot_source(log: SensorLog, rep: ReadReport) -> str | None:
    """The message the log's autopilot position estimate came from (None: the log has none): the reader's
    ``meta["ap_estimate"]``, else the known message it converted (the tlog reader counts GLOBAL_POSITION_INT)."""
    if not len(log.arrays.get("ap_pos_t_s", ())):
        return None
    named = (log.meta.get("ap_estimate") or {}).get("position")
    return str(named) if named else next((k for k in AP_POSITION_MESSAGES if rep.used.get(k)), "the log")


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return _jsonable(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_replay_report(out: Path, log: SensorLog, rep: ReadReport, run: ReplayRun, ref: Reference, *,
                        skipped: dict[str, str], speed: dict[str, float], mag: tuple[np.ndarray, str],
                        models: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    sc = score(run, ref)
    source = autopilot_source(log, rep)
    ap = autopilot_estimate(log, run.origin, source) if source is not None else None
    autopilot = ({**compare_autopilot(run, ref, ap), "inside_outages": AP_NOT_COMPARABLE} if ap is not None
                 else {"source": None, "note": AP_NONE})  # fmt: skip
    doc = {
        "log": rep.to_dict(),
        "rates_hz": log.meta.get("rates_hz"),
        "duration_s": log.duration_s,
        "models": models,
        "mag_field_ned_ut": [float(v) for v in mag[0]],
        "mag_field_source": mag[1],
        "origin": list(run.origin),
        "filter_rate_hz": run.filter_rate_hz,
        "modes": list(run.modes),
        "skipped_modes": skipped,
        "reference": sc["reference"],
        "outages": sc["outages"],
        "autopilot": autopilot,
        "port_counts": run.port_counts,
        "rejected": run.rejected,
        "speed": speed,
    }
    doc = _jsonable(doc)
    (out / "replay.json").write_text(json.dumps(doc, indent=1))
    (out / "replay.md").write_text(format_markdown(doc))
    header, rows = solution_table(run, LocalFrame(*run.origin))
    with (out / "solution.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    plot_errors(sc["curves"], run.outages, ref.source, out / "replay-error.png")
    return doc


def format_markdown(doc: dict[str, Any]) -> str:
    lg = doc["log"]
    sp = doc["speed"]
    ap = doc["autopilot"]
    rates = doc["rates_hz"] or {}
    lines = [
        f"# Replay of {Path(lg['path']).name}",
        "",
        f"{lg['format']} log, {doc['duration_s']:.1f} s, time base {lg['time_base']}. Rates: "
        + ", ".join(f"{k} {v:.1f} Hz" for k, v in rates.items() if v)
        + f". Filter at {doc['filter_rate_hz']:.0f} Hz. Judged against {doc['reference']}.",
        "",
        f"Magnetic field {', '.join(f'{v:.2f}' for v in doc['mag_field_ned_ut'])} µT NED ({doc['mag_field_source']}).",
        f"Models: {doc['models']['model'] or 'none'}; design data {doc['models']['design_data'] or 'none'}; "
        f"vehicle {doc['models']['vehicle']}.",
        "",
    ]
    if lg["truncated_at_byte"] is not None:
        lines += [f"**Truncated file**: read up to byte {lg['truncated_at_byte']} of {lg['file_bytes']} (the last "
                  f"whole record, at {lg['last_time_s']:.3f} s).", ""]  # fmt: skip
    for w in lg["warnings"]:
        lines.append(f"- warning: {w}")
    for m, why in doc["skipped_modes"].items():
        lines.append(f"- {m} not run: {why}")
    if lg["malformed"]:
        lines.append(f"- {lg['malformed']} malformed records skipped")
    if lg["warnings"] or doc["skipped_modes"] or lg["malformed"]:
        lines.append("")
    for o in doc["outages"]:
        a, b = o["start_s"], o["end_s"]
        lines += [f"## GNSS outage {a:.1f} … {b:.1f} s ({b - a:.0f} s)", "",
                  "| mode | error at the end [m] | max in the outage [m] | % of distance | σh at the end [m] "
                  "| 2σ covers |", "|---|---|---|---|---|---|"]  # fmt: skip
        for m, r in o["modes"].items():
            if r is None:
                lines.append(f"| {m} | not initialised before the outage | | | | |")
                continue

            def f(v: float | None, fmt: str = ".1f") -> str:
                return "n/a" if v is None else format(v, fmt)

            cov = {True: "yes", False: "no", None: "n/a"}[r["covered_2sigma"]]
            lines.append(f"| {m} | {f(r['final_error_m'])} | {f(r['max_error_m'])} | {f(r['final_error_pct'], '.2f')} "
                         f"| {f(r['sigma_h_end_m'])} | {cov} |")  # fmt: skip
        dist = next((r["distance_m"] for r in o["modes"].values() if r), None)
        lines += ["", f"Distance flown in the outage: {dist:.0f} m." if dist else "", ""]
        if ap["source"] is not None:
            lines += [f"The autopilot's own estimate ({ap['source']}) is {AP_NOT_COMPARABLE}: not in this table.", ""]
    lines += _autopilot_markdown(ap)
    lines += [
        "## Read",
        "",
        "Converted: " + ", ".join(f"{k} {v}" for k, v in lg["used"].items()) + ".",
        "",
        "Skipped: " + (", ".join(f"{k} {v}" for k, v in sorted(lg["unknown"].items())) or "none") + ".",
        "",
        f"Speed: {sp['flight_s']:.0f} s of flight in {sp['wall_s']:.1f} s ({sp['x_real_time']:.1f}× real time; "
        f"reading {sp['read_wall_s']:.1f} s, {sp['modes']} modes {sp['filters_cpu_s']:.1f} s CPU).",
        "",
        "Files: `replay.json`, `replay-error.png`, `solution.csv`.",
        "",
    ]
    return "\n".join(lines)


def _autopilot_markdown(ap: dict[str, Any]) -> list[str]:
    """The section that puts the autopilot's own estimate beside the modes, outside the outages."""
    head = ["## Beside the autopilot's own estimate, outside the outages", ""]
    if ap["source"] is None:
        return [*head, f"The autopilot's own position estimate: {ap['note']}.", ""]
    lines = [*head, f"The autopilot's own position estimate: {ap['source']}. Outside the outages it had GNSS, as the "
             f"replayed filters had; judged against {ap['reference']}, over the same {ap['epochs']} epochs "
             f"({ap['seconds']:.1f} s) for every row; the modes' largest errors are those just after an outage, "
             "before the fixes pull them back.", ""]  # fmt: skip
    if not ap["epochs"]:
        return [*lines, "No epoch outside the outages has the reference, the autopilot's estimate and every mode.", ""]
    lines += ["| | median error [m] | 95th percentile [m] | max [m] |", "|---|---|---|---|"]
    rows = {"autopilot (its own estimate)": ap["autopilot"], **ap["modes"]}
    for name, r in rows.items():
        lines.append(f"| {name} | {r['median_error_m']:.2f} | {r['p95_error_m']:.2f} | {r['max_error_m']:.2f} |")
    return [*lines, ""]


def plot_errors(curves: dict[str, Any], outages: tuple[tuple[float, float], ...], ref: str, path: Path) -> None:
    from vdm_aero_cli.plots import _pyplot

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 5))
    for m in MODES:
        if m not in curves:
            continue
        c = curves[m]
        (line,) = ax.plot(c["t_s"], c["error_m"], lw=1.2, label=m)
        ax.plot(c["t_s"], 2.0 * c["sigma_h_m"], ls=":", lw=0.8, color=line.get_color())
    for i, (a, b) in enumerate(outages):
        ax.axvspan(a, b, color="tab:red", alpha=0.1, label="GNSS outage" if i == 0 else None)
    lo = min(a for a, _ in outages) - 30.0
    hi = max(b for _, b in outages) + 30.0
    ax.set_xlim(lo, hi)
    vals = [np.nanmax(np.where((c["t_s"] >= lo) & (c["t_s"] <= hi), c["error_m"], np.nan), initial=0.0)
            for c in curves.values() if len(c["t_s"])]  # fmt: skip
    top = max([v for v in vals if math.isfinite(v)], default=1.0)
    ax.set_ylim(0.0, 1.2 * top + 1.0)
    ax.set(xlabel="log time [s]", ylabel="horizontal error [m]",
           title=f"error vs time (solid) and 2σ (dotted); reference: {ref.split(' (')[0]}")  # fmt: skip
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
