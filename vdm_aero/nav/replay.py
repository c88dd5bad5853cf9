"""Replaying a flight log through the navigation filters with GNSS removed inside outage windows, and scoring
each mode's horizontal error against a reference: a truth when the log has one, else the log's own GNSS.

The filters run on the :class:`~vdm_aero.nav.stream.NavStream` of the log through a
:class:`~vdm_aero.nav.stream.LogRunner`, the path the drift benchmark and the service share. The solution
is recorded at :data:`RECORD_HZ` (the benchmark's rate), so errors at an outage's end are read at the same
epochs in both.

Where the log holds the autopilot's own position estimate (what the autopilot flew on), it is judged against
the same reference beside the modes, outside the outages only (:func:`compare_autopilot`): there it had GNSS,
as the replayed filters had; inside them it still had GNSS (the outages are cut out of the log afterwards),
so it is no comparison for the modes' dead reckoning there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.flightlog import SensorLog
from vdm_aero.geodesy import LocalFrame
from vdm_aero.nav.filter import AP_ATTITUDE_SIGMA_RAD, MODES, SLOW_IMU_HZ, NavConfig, NavFilter, mode_spec, reads_ports
from vdm_aero.nav.models import NavModels
from vdm_aero.nav.stream import LogRunner, NavStream, SolutionRecorder
from vdm_aero.rotation import euler_from_quat
from vdm_aero.vehicle import VehicleDescription

__all__ = ["RECORD_HZ", "AutopilotEstimate", "Reference", "ReplayRun", "autopilot_estimate", "available_modes",
           "compare_autopilot", "merge_runs", "replay_log", "score"]  # fmt: skip

RECORD_HZ = 5.0
MAX_FILTER_RATE_HZ = 50.0
MAX_INTERP_GAP_S = 1.0  # a track (reference, autopilot) is not interpolated across a gap longer than this
PORT_RANGE_PA = 500.0  # the port transducers' full scale and noise: deploy/config.yaml's defaults (SDP31)
PORT_NOISE_PA = 0.2
_PORT_MODES = frozenset(m for m in MODES if reads_ports(m))


@dataclass(frozen=True, eq=False)
class Reference:
    """Where the error is measured against: positions in the replay's local frame (NED from the first fix)."""

    source: str  # "truth: ..." or "the log's GNSS"
    t_s: F64Array
    p_ned_m: F64Array  # (N, 3); D NaN when the reference has no altitude (SIMSTATE)


@dataclass(frozen=True, eq=False)
class AutopilotEstimate:
    """The autopilot's own position estimate in the replay's local frame (NED from the first fix) [m]."""

    source: str  # the message it came from: "GLOBAL_POSITION_INT", "POS", "vehicle_global_position", ...
    t_s: F64Array
    p_ned_m: F64Array  # (N, 3)


def autopilot_estimate(log: SensorLog, origin: tuple[float, float, float], source: str
                       ) -> AutopilotEstimate | None:  # fmt: skip
    """The log's ``ap_pos`` stream in the local frame at ``origin``; None when the log has none. A row without
    altitude (NaN) is put at the origin's: only its horizontal position is compared."""
    t = log.arrays.get("ap_pos_t_s")
    if t is None or not len(t):
        return None
    alt = np.where(np.isfinite(log["ap_pos_alt_m"]), log["ap_pos_alt_m"], origin[2])
    p = np.asarray(LocalFrame(*origin).to_ned(log["ap_pos_lat_deg"], log["ap_pos_lon_deg"], alt)).reshape(-1, 3)
    return AutopilotEstimate(source, np.asarray(t, dtype=np.float64), p)


@dataclass
class ReplayRun:
    """What a replay produced: the recorded solution per mode and what was run."""

    modes: tuple[str, ...]
    outages: tuple[tuple[float, float], ...]
    origin: tuple[float, float, float]  # lat [deg], lon [deg], alt [m] of the local frame
    filter_rate_hz: float
    rows: dict[str, list[tuple[Any, ...]]]  # per mode: the records of :class:`SolutionRecorder`
    skipped_modes: dict[str, str] = field(default_factory=dict)  # mode → why it did not run
    port_counts: dict[str, int] | None = None
    rejected: dict[str, dict[str, int]] = field(default_factory=dict)

    def history(self, mode: str) -> dict[str, F64Array]:
        r = self.rows[mode]
        return {
            "t_s": np.array([x[0] for x in r]),
            "p_ned_m": np.array([x[1] for x in r]).reshape(-1, 3),
            "v_ned_m_s": np.array([x[2] for x in r]).reshape(-1, 3),
            "q_nb": np.array([x[3] for x in r]).reshape(-1, 4),
            "sigma_h_m": np.array([sigma_h_m(x[5]) for x in r]),
            "in_outage": np.array([x[6] for x in r], dtype=bool),
            "wind_ned_m_s": np.array([x[7] for x in r]).reshape(-1, 3),
        }


def sigma_h_m(cov: F64Array) -> float:
    """1σ horizontal position uncertainty of a recorded covariance: √(largest eigenvalue of its NE block) [m]
    (as :meth:`NavFilter.horizontal_sigma_m`)."""
    return float(math.sqrt(max(np.linalg.eigvalsh(cov[0:2, 0:2])[-1], 0.0)))


def available_modes(requested: Sequence[str], log: SensorLog, models: NavModels | None
                    ) -> tuple[tuple[str, ...], dict[str, str]]:  # fmt: skip
    """The requested modes the log and the models allow, and why the others cannot run."""
    run, skipped = [], {}
    has_ports = len(log["ports_t_s"]) > 0 and np.isfinite(log["ports_dp_pa"]).any()
    for m in requested:
        spec = mode_spec(m)
        if m in _PORT_MODES and not has_ports:
            skipped[m] = "the log has no port values"
        elif (m in _PORT_MODES or spec.force == "classic") and models is None:
            skipped[m] = "no aero model and design data set given (--model, --design-data)"
        elif spec.force == "deim-nn" and models is not None and "deim-nn" not in models.models:
            skipped[m] = "the model has no correction net"
        else:
            run.append(m)
    return tuple(run), skipped


def replay_log(
    log: SensorLog,
    vehicle: VehicleDescription,
    models: NavModels | None,
    *,
    modes: Sequence[str],
    outages: Sequence[tuple[float, float]],
    mag_field_ned_ut: F64Array,
    progress: Callable[[float], None] | None = None,
) -> ReplayRun:
    """Run ``modes`` through ``log`` with GNSS removed in ``outages`` ([start, end) on the log's clock [s])."""
    if not len(log["gnss_t_s"]):
        raise ValueError(f"{log.path}: no 3-D GNSS fix in the log (the filter starts at the first fix)")
    origin = (float(log["gnss_lat_deg"][0]), float(log["gnss_lon_deg"][0]), float(log["gnss_alt_m"][0]))
    frame = LocalFrame(*origin)
    imu_hz = 1.0 / float(np.median(np.diff(log["imu_t_s"])))
    rate = min(MAX_FILTER_RATE_HZ, imu_hz)
    # a fix arrives its receiver latency after its time of validity: the reader's, when it had to assume one
    latency = float(log.meta.get("gnss_latency_s", NavConfig.gnss_latency_s))
    # an IMU logged too slowly to integrate (a ground station's 4-10 Hz): the autopilot's own attitude, from its
    # IMU at full rate, is fused as a measurement where the log has it (the report says so)
    slow_imu = imu_hz < SLOW_IMU_HZ and len(log.arrays.get("ap_att_t_s", ())) > 0
    cfg = NavConfig(vehicle=vehicle, origin_alt_m=origin[2], mag_field_ned_ut=np.asarray(mag_field_ned_ut, float),
                    filter_rate_hz=rate, aiding_rate_hz=min(10.0, rate), gnss_latency_s=latency,
                    ap_attitude_sigma_rad=AP_ATTITUDE_SIGMA_RAD if slow_imu else None,
                    imu_point_samples=imu_hz < SLOW_IMU_HZ)  # fmt: skip
    stream = NavStream.from_log(log, vehicle, frame, filter_rate_hz=rate, gnss_latency_s=cfg.gnss_latency_s)
    fe = None
    if models is not None and any(m in _PORT_MODES for m in modes):
        fe = models.front_end(range_pa=PORT_RANGE_PA, noise_pa=PORT_NOISE_PA)
    derivatives = models.derivatives if models is not None else None
    filters = {m: NavFilter(m, cfg, derivatives) for m in modes}
    runner = LogRunner(stream, filters, fe)
    for a, b in outages:
        runner.block_gnss(a, b)
    rows: dict[str, list[tuple[Any, ...]]] = {m: [] for m in modes}
    record = SolutionRecorder(round(rate / RECORD_HZ))
    t0, t1 = float(stream.event_t_s[0]), float(stream.event_t_s[-1])
    next_progress = [t0]

    def on_step(t: float) -> None:
        record(t, runner.filters, rows)
        if progress is not None and t >= next_progress[0]:
            progress((t - t0) / max(t1 - t0, 1e-9))
            next_progress[0] = t + 0.01 * (t1 - t0)

    runner.run_until(math.inf, on_step)
    return ReplayRun(
        modes=tuple(modes), outages=tuple(outages), origin=origin, filter_rate_hz=rate, rows=rows,
        port_counts=dict(fe.counts) if fe is not None else None,
        rejected={m: dict(f.rejected) for m, f in runner.filters.items()},
    )  # fmt: skip


def merge_runs(runs: Sequence[ReplayRun], modes: Sequence[str]) -> ReplayRun:
    """Runs of the same log and outages with disjoint modes (one per process) as one run, modes in ``modes``
    order."""
    first = runs[0]
    rows = {m: r.rows[m] for r in runs for m in r.modes}
    return ReplayRun(
        modes=tuple(m for m in modes if m in rows), outages=first.outages, origin=first.origin,
        filter_rate_hz=first.filter_rate_hz, rows=rows,
        port_counts=next((r.port_counts for r in runs if r.port_counts is not None), None),
        rejected={m: v for r in runs for m, v in r.rejected.items()},
    )  # fmt: skip


def score(run: ReplayRun, ref: Reference) -> dict[str, Any]:
    """Per outage and mode: the horizontal error at the outage's end (the last record before it), the largest
    in it, the distance flown (by the reference), σ_h at the end and whether 2σ covers the error; and per mode
    the error history inside the outages (for the plot)."""
    out: dict[str, Any] = {"reference": ref.source, "outages": [], "curves": {}}
    rt = ref.t_s
    hist = {m: run.history(m) for m in run.modes}  # each mode's history and error, once for every outage
    err = {m: _error_h(h, ref) for m, h in hist.items()}
    for a, b in run.outages:
        inside_ref = (rt >= a) & (rt < b)
        ne = ref.p_ned_m[inside_ref, :2]
        dist = float(np.sum(np.linalg.norm(np.diff(ne, axis=0), axis=1))) if len(ne) > 1 else math.nan
        per: dict[str, Any] = {}
        for m in run.modes:
            h, e = hist[m], err[m]
            t = h["t_s"]
            if not len(t) or t[0] >= b:
                per[m] = None
                continue
            i_end = int(np.searchsorted(t, b)) - 1
            inside = (t >= a) & (t < b) & np.isfinite(e)
            fin = float(e[i_end]) if i_end >= 0 and t[i_end] >= a and math.isfinite(e[i_end]) else math.nan
            sig = float(h["sigma_h_m"][i_end]) if i_end >= 0 else math.nan
            per[m] = {
                "final_error_m": fin,
                "max_error_m": float(e[inside].max()) if inside.any() else math.nan,
                "distance_m": dist,
                "final_error_pct": 100.0 * fin / dist if dist > 0 else math.nan,
                "sigma_h_end_m": sig,
                "covered_2sigma": bool(fin <= 2.0 * sig) if math.isfinite(fin) else None,
            }
        out["outages"].append({"start_s": a, "end_s": b, "modes": per})
    for m in run.modes:
        out["curves"][m] = {"t_s": hist[m]["t_s"], "error_m": err[m], "sigma_h_m": hist[m]["sigma_h_m"]}
    return out


def compare_autopilot(run: ReplayRun, ref: Reference, ap: AutopilotEstimate) -> dict[str, Any]:
    """The autopilot's horizontal error and each mode's against ``ref`` outside the outages, at the same epochs:
    the record epochs every mode has, outside every outage, where the reference, the autopilot's estimate and
    every mode's error exist. Per row the median, 95th percentile and largest error [m]; ``epochs`` and
    ``seconds`` say how much was compared (none: the statistics are None)."""
    hist = {m: run.history(m) for m in run.modes}
    t = hist[run.modes[0]]["t_s"] if run.modes else np.zeros(0)
    for h in hist.values():
        t = np.intersect1d(t, h["t_s"])  # one recorder for every mode: the same epochs once each is running
    keep = np.ones(len(t), dtype=bool)
    for a, b in run.outages:
        keep &= ~((t >= a) & (t < b))
    ref_ne = _track_at(t, ref.t_s, ref.p_ned_m)
    errors = {"autopilot": np.hypot(*(_track_at(t, ap.t_s, ap.p_ned_m) - ref_ne).T)}
    for m, h in hist.items():
        e = _error_h(h, ref)
        errors[m] = e[np.searchsorted(h["t_s"], t)] if len(t) else np.zeros(0)
    for e in errors.values():
        keep &= np.isfinite(e)
    n = int(keep.sum())

    def stats(e: F64Array) -> dict[str, float] | None:
        if not n:
            return None
        x = e[keep]
        return {"median_error_m": float(np.median(x)), "p95_error_m": float(np.percentile(x, 95.0)),
                "max_error_m": float(x.max())}  # fmt: skip

    return {"source": ap.source, "reference": ref.source, "epochs": n, "seconds": n / RECORD_HZ,
            "autopilot": stats(errors.pop("autopilot")), "modes": {m: stats(e) for m, e in errors.items()}}  # fmt: skip


def _track_at(t: F64Array, track_t: F64Array, track_p: F64Array) -> F64Array:
    """A track's (north, east) [m] interpolated to ``t`` (K, 2): NaN where it has no sample within
    :data:`MAX_INTERP_GAP_S`, outside its span, and inside a longer gap farther than half that from either end
    (its gaps are not bridged)."""
    out = np.full((len(t), 2), math.nan)
    if not len(t) or len(track_t) < 2:
        return out
    for j in (0, 1):
        out[:, j] = np.interp(t, track_t, track_p[:, j])
    k = np.clip(np.searchsorted(track_t, t), 1, len(track_t) - 1)
    near = np.minimum(np.abs(track_t[k] - t), np.abs(track_t[k - 1] - t))
    gap = (track_t[k] - track_t[k - 1]) > MAX_INTERP_GAP_S
    far = (near > MAX_INTERP_GAP_S) | (gap & (near > 0.5 * MAX_INTERP_GAP_S))
    out[far | (t < track_t[0]) | (t > track_t[-1])] = math.nan
    return out


def _error_h(h: dict[str, F64Array], ref: Reference) -> F64Array:
    """Horizontal error of the recorded solution against the reference, interpolated to the solution's
    epochs (NaN where the reference has no sample within a second: its gaps are not bridged)."""
    ne = _track_at(h["t_s"], ref.t_s, ref.p_ned_m)
    return np.asarray(np.hypot(h["p_ned_m"][:, 0] - ne[:, 0], h["p_ned_m"][:, 1] - ne[:, 1]))


def solution_table(run: ReplayRun, frame: LocalFrame) -> tuple[list[str], list[list[Any]]]:
    """The navigation solution as CSV rows: per mode and record, time, geodetic and NED position, velocity,
    attitude (roll, pitch, yaw [deg]), σ_h, wind and the GNSS state."""
    header = ["mode", "t_s", "lat_deg", "lon_deg", "alt_m", "n_m", "e_m", "d_m", "vn_m_s", "ve_m_s", "vd_m_s",
              "roll_deg", "pitch_deg", "yaw_deg", "sigma_h_m", "wind_n_m_s", "wind_e_m_s", "gnss"]  # fmt: skip
    out = []
    for m in run.modes:
        for t, p, v, q, _, cov, outage, w in run.rows[m]:
            sig = sigma_h_m(cov)
            lat, lon, alt = frame.to_geodetic(float(p[0]), float(p[1]), float(p[2]))
            r, pi, y = (math.degrees(a) for a in euler_from_quat(q))
            out.append([m, t, lat, lon, alt, *map(float, p), *map(float, v), r, pi, y, sig, float(w[0]), float(w[1]),
                        "outage" if outage else "aided"])  # fmt: skip
    return header, out
