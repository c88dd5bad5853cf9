"""Replay an airfoil spec along a measured data set: its own α(t), speed and port locations.

Used by the discrepancy workflow. Applies to any pitching data set, including ones this project did
not produce: ports are matched to the spec's airfoil surface by location, α̇ and α̈ come from a
harmonic fit when the case gives ``freq_hz`` (exact derivatives, robust to noise) and otherwise from
a smoothing-spline derivative, and the lags are settled by a warm-up (one period prepended for
periodic cases, else the whole series is run twice).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.airfoil.effects import EFFECTS, effect_defaults
from sim.airfoil.flow import AirfoilFlow, EvalSurface, FlowState
from sim.airfoil.naca import locate_taps, taps_geometry
from sim.airfoil.simulate import AirfoilSimulator
from sim.airfoil.spec import AirfoilSpec
from vdm_aero._typing import F64Array
from vdm_aero.dataset import Dataset
from vdm_aero.discrepancy import Candidate, MeasuredCase, PortInfo
from vdm_aero.errors import UserInputError
from vdm_aero.lag import first_order_lag

HARMONICS = 4  # harmonics of the pitch motion fitted to α(t) when the frequency is known
PORT_TOLERANCE_CHORD = 0.01


@dataclass(frozen=True)
class _Motion:
    t: F64Array
    alpha: F64Array
    alpha_dot: F64Array
    alpha_ddot: F64Array
    warmup: int
    speed_m_s: float


def harmonic_fit(t: F64Array, alpha: F64Array, freq_hz: float) -> tuple[Callable[[F64Array, int], F64Array], float]:
    """Least-squares Fourier fit of α(t) with ``HARMONICS`` harmonics of ``freq_hz``.

    Returns ``evaluate(t, d)`` giving the d-th time derivative (d = 0, 1, 2) and the RMS residual [rad]."""
    w = 2 * math.pi * freq_hz
    k = np.arange(1, HARMONICS + 1)
    basis = np.column_stack([np.ones_like(t), np.cos(np.outer(t, k) * w), np.sin(np.outer(t, k) * w)])
    c, *_ = np.linalg.lstsq(basis, alpha, rcond=None)
    a0, ac, as_ = c[0], c[1 : HARMONICS + 1], c[HARMONICS + 1 :]

    def evaluate(tt: F64Array, d: int) -> F64Array:
        ph = np.outer(tt, k) * w
        kw = (k * w) ** d
        if d == 0:
            return np.asarray(a0 + np.cos(ph) @ ac + np.sin(ph) @ as_)
        if d == 1:
            return np.asarray(-np.sin(ph) @ (ac * kw) + np.cos(ph) @ (as_ * kw))
        return np.asarray(-np.cos(ph) @ (ac * kw) - np.sin(ph) @ (as_ * kw))

    return evaluate, float(np.sqrt(np.mean((basis @ c - alpha) ** 2)))


class AirfoilReplay:
    """Implements :class:`vdm_aero.discrepancy.ReplaySimulator` for an airfoil spec and a measured data set."""

    def __init__(self, spec: AirfoilSpec, measured: Dataset) -> None:
        self.spec = spec
        base = AirfoilSimulator(spec)  # completes the effect parameters (static-separation calibration)
        self.base_effects: dict[str, dict[str, Any]] = base.effects
        self.flow: AirfoilFlow = base.flow
        self.measured = measured
        self.ports, self.surface = self._match_ports(measured)
        self.motions = {c.id: self._motion(measured, c.id) for c in measured.cases}
        self.truth = measured.truth_coeffs()
        self.separation_start: dict[str, Any] | None = None  # NeuralFoil-calibrated static separation (cached)

    # ------------------------------------------------------------------------------------- set-up
    def _match_ports(self, ds: Dataset) -> tuple[tuple[PortInfo, ...], EvalSurface]:
        c = self.spec.chord_m
        xp = self.spec.motion.pivot_x_c
        x_c = np.clip(xp - ds.points[:, 0] / c, 0.0, 1.0)
        upper = ds.normals[:, 2] >= 0.0  # inward normal points down (+z, FRD) on the upper surface
        s = locate_taps(self.flow.nodes, x_c.tolist(), upper.tolist())
        geo = taps_geometry(self.flow.nodes, s, chord_m=c, span_m=self.spec.span_m, pivot_x_c=xp)
        dist = np.linalg.norm(np.asarray(geo.points_b)[:, [0, 2]] - ds.points[:, [0, 2]], axis=1)
        tol = PORT_TOLERANCE_CHORD * c
        if np.any(dist > tol):
            i = int(np.argmax(dist))
            raise UserInputError(
                f"{ds.path or ds.name}: port {ds.point_names[i]} lies {dist[i] * 1e3:.1f} mm from the "
                f"{self.spec.airfoil} surface of the spec (tolerance {tol * 1e3:.1f} mm): geometry or origin mismatch"
            )
        ports = tuple(PortInfo(ds.point_names[i], float(x_c[i]), bool(upper[i])) for i in range(ds.n_points))
        return ports, self.flow.surface_at(np.asarray(s, dtype=np.float64))

    def _motion(self, ds: Dataset, cid: int) -> _Motion:
        m = ds.case == cid
        t, a = np.asarray(ds.t[m], dtype=np.float64), np.asarray(ds.alpha[m], dtype=np.float64)
        case = next(c for c in ds.cases if c.id == cid)
        speed = case.speed_m_s or self.spec.speed_m_s
        f = case.freq_hz
        if f:
            evaluate, rms = harmonic_fit(t, a, f)
            if rms < math.radians(0.25):  # periodic: prepend one period from the fit to settle the lags
                dt = t[1] - t[0]
                tw = np.concatenate([np.arange(t[0] - 1.0 / f, t[0] - 0.5 * dt, dt), t])
                n_w = len(tw) - len(t)
                a_full = np.concatenate([evaluate(tw[:n_w], 0), a])  # recorded α on the kept samples
                return _Motion(tw, a_full, evaluate(tw, 1), evaluate(tw, 2), n_w, speed)
        from scipy.interpolate import make_smoothing_spline

        spline = make_smoothing_spline(t, a)
        ad, add = spline.derivative(1)(t), spline.derivative(2)(t)
        dt_end = t[-1] - t[0] + (t[1] - t[0])
        return _Motion(
            np.concatenate([t - dt_end, t]),
            np.concatenate([a, a]),
            np.concatenate([ad, ad]),
            np.concatenate([add, add]),
            len(t),
            speed,
        )

    def measured_cases(self) -> list[MeasuredCase]:
        out = []
        for c in self.measured.cases:
            m = self.measured.case == c.id
            k = c.meta.get("reduced_frequency")
            if k is None and c.freq_hz:
                k = math.pi * c.freq_hz * self.spec.chord_m / (c.speed_m_s or self.spec.speed_m_s)
            out.append(
                MeasuredCase(
                    case_id=c.id,
                    alpha=np.asarray(self.measured.alpha[m], dtype=np.float64),
                    t=np.asarray(self.measured.t[m], dtype=np.float64),
                    cp=np.asarray(self.measured.cp[m], dtype=np.float64),
                    coeffs=self.truth[m],
                    reduced_frequency=float(k) if k is not None else math.nan,
                )
            )
        return out

    # ---------------------------------------------------------------------------------- simulate
    def simulate(
        self, effects: Mapping[str, Mapping[str, Any]], cases: Sequence[int], stride: int = 1
    ) -> dict[int, tuple[F64Array, F64Array]]:
        """{case: (port Cp, truth coefficients)} on every ``stride``-th kept sample."""
        flow = self.flow.with_effects(effects)
        names = {p.name: i for i, p in enumerate(self.ports)}
        out = {}
        for cid in cases:
            mo = self.motions[cid]
            flow.speed_m_s = mo.speed_m_s
            st = flow.march(mo.t, mo.alpha, mo.alpha_dot, mo.alpha_ddot)
            lagged = None
            if "port_lag" in effects:  # the lag needs every sample, warm-up included
                lagged = first_order_lag(mo.t, flow.cp(st, self.surface), float(effects["port_lag"]["tau_s"]))
            keep = np.arange(mo.warmup, len(mo.t), stride)
            st = FlowState(**{k: np.asarray(getattr(st, k))[keep] for k in FlowState.__dataclass_fields__})
            cp = flow.cp(st, self.surface) if lagged is None else lagged[keep]
            _, coeffs = flow.panel_cp_and_truth(st)
            for name, bias in effects.get("port_bias", {}).items():
                if name in names:
                    cp[:, names[name]] += float(bias)
            out[cid] = (cp, coeffs)
        return out


def candidate_source(replay: AirfoilReplay, *, extra: Sequence[Candidate] = ()
                     ) -> Callable[[Mapping[str, Mapping[str, Any]]], list[Candidate]]:  # fmt: skip
    """The candidates as a function of the effects named so far (what :class:`Discovery` rebuilds each round)."""
    return lambda current: candidate_library(replay, extra=extra, current=current)


def candidate_library(replay: AirfoilReplay, *, extra: Sequence[Candidate] = (),
                      current: Mapping[str, Mapping[str, Any]] | None = None) -> list[Candidate]:  # fmt: skip
    """The candidates given the effects in the simulation so far (``current``, default the spec's): every effect
    whose required effects are in it, with start values from it (or defaults, or the NeuralFoil calibration for
    static separation) and bounds = the documented physical range; and for every effect whose one missing
    requirement is itself a candidate, the pair "requirement+effect", fitted together."""
    base = replay.base_effects if current is None else current
    singles: dict[str, Candidate] = {}
    for name, info in EFFECTS.items():
        if any(req not in base for req in info.requires):
            continue
        if name == "port_bias":
            singles[name] = Candidate(name, {}, kind="port_bias")
            continue
        singles[name] = Candidate(name, _bounded(name, _start(replay, name, base)))
    pairs = []
    for name, info in EFFECTS.items():
        missing = [req for req in info.requires if req not in base]
        if len(missing) != 1 or missing[0] not in singles or singles[missing[0]].kind != "continuous":
            continue
        pre = singles[missing[0]]
        own = _bounded(name, _start(replay, name, base))
        params = {f"{pre.name}.{k}": v for k, v in pre.params.items()} | {f"{name}.{k}": v for k, v in own.items()}
        pairs.append(Candidate(f"{pre.name}+{name}", params, kind="pair"))
    return [*singles.values(), *pairs, *extra]


def _start(replay: AirfoilReplay, name: str, current: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Start values: the current simulation's, else static separation calibrated on NeuralFoil (once per
    replay), else the effect's defaults."""
    if name in current:
        return dict(current[name])
    if name == "trailing_edge_separation":
        if replay.separation_start is None:
            from sim.airfoil.separation import calibrate_static_separation

            probe = replay.flow.with_effects({name: effect_defaults(name)})
            replay.separation_start = calibrate_static_separation(probe, replay.spec.airfoil, replay.spec.reynolds)
        return dict(replay.separation_start)
    return {}


def _bounded(name: str, start: Mapping[str, Any]) -> dict[str, tuple[float, float, float]]:
    params = {}
    for p, pi in EFFECTS[name].params.items():
        x0 = float(start.get(p, pi.default))
        params[p] = (x0, min(pi.low, x0), max(pi.high, x0))
    return params
