"""Run an airfoil spec into a ``vdm-aero-dataset/1`` data set (simulation or tunnel-like taps)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.airfoil.flow import AirfoilFlow, EvalSurface
from sim.airfoil.naca import locate_taps, taps_geometry
from sim.airfoil.separation import complete_effects
from sim.airfoil.spec import AirfoilSpec
from vdm_aero._typing import F64Array
from vdm_aero.dataset import Case, Dataset
from vdm_aero.lag import first_order_lag

GENERATOR = "vdm-aero sim.airfoil 0.1"


@dataclass(frozen=True)
class CaseRun:
    """One simulated case: observed Cp at the output points and the truth coefficients."""

    t: F64Array  # (K,) [s]
    alpha: F64Array  # (K,) recorded incidence [rad]
    cp: F64Array  # (K, n_out)
    coeffs: F64Array  # (K, 6)


class AirfoilSimulator:
    """A spec made runnable: panel solution, completed effects and output points, built once."""

    def __init__(self, spec: AirfoilSpec) -> None:
        self.spec = spec

        def factory(effects: Mapping[str, Mapping[str, Any]]) -> AirfoilFlow:
            return AirfoilFlow(
                airfoil=spec.airfoil,
                n_panels=spec.surface_points,
                chord_m=spec.chord_m,
                span_m=spec.span_m,
                pivot_x_c=spec.motion.pivot_x_c,
                speed_m_s=spec.speed_m_s,
                effects=effects,
            )

        self.effects = complete_effects(
            spec.effects, airfoil=spec.airfoil, reynolds=spec.reynolds, flow_factory=factory
        )
        self.flow = factory(self.effects)
        g = self.flow.geometry
        if spec.taps is None:
            self.out_surface: EvalSurface = self.flow.panel_surface
            self.points, self.normals, self.areas = g.points_b, g.normals_b, g.areas_m2
            self.point_names: tuple[str, ...] = tuple(f"p{i:04d}" for i in range(len(g.areas_m2)))
        else:
            s_taps = locate_taps(self.flow.nodes, spec.taps.x_c, spec.taps.upper)
            self.out_surface = self.flow.surface_at(np.asarray(s_taps, dtype=np.float64))
            self.points, self.normals, self.areas = taps_geometry(
                self.flow.nodes,
                s_taps,
                chord_m=spec.chord_m,
                span_m=spec.span_m,
                pivot_x_c=spec.motion.pivot_x_c,
            )
            self.point_names = spec.taps.names

    def completed_spec(self) -> dict[str, Any]:
        """The spec with every effect parameter filled in (what re-simulation needs)."""
        d = self.spec.to_dict()
        d["effects"] = self.effects
        return d

    def run_motion(
        self,
        t: F64Array,
        alpha: F64Array,
        alpha_dot: F64Array,
        alpha_ddot: F64Array,
        *,
        warmup: int = 0,
        rng: np.random.Generator | None = None,
    ) -> CaseRun:
        """Simulate a prescribed α(t). The first ``warmup`` samples settle the lags and are dropped."""
        flow = self.flow
        st = flow.march(t, alpha, alpha_dot, alpha_ddot)
        cp_panels, coeffs = flow.panel_cp_and_truth(st)
        cp = cp_panels if self.spec.taps is None else flow.cp(st, self.out_surface)
        if "port_lag" in self.effects:
            cp = first_order_lag(t, cp, float(self.effects["port_lag"]["tau_s"]))
        if "port_bias" in self.effects:
            idx = {n: i for i, n in enumerate(self.point_names)}
            for name, bias in self.effects["port_bias"].items():
                cp[:, idx[name]] += float(bias)
        cp, coeffs = cp[warmup:], coeffs[warmup:]
        if self.spec.cp_std_fraction > 0.0:
            if rng is None:
                raise ValueError("a noisy spec needs an explicit numpy Generator")
            cp = cp * (1.0 + self.spec.cp_std_fraction * rng.standard_normal(cp.shape))
        return CaseRun(t=t[warmup:] - t[warmup], alpha=alpha[warmup:], cp=cp, coeffs=coeffs)

    def run_frequency(self, freq_hz: float, rng: np.random.Generator | None = None) -> CaseRun:
        """Harmonic pitch at ``freq_hz`` with one warm-up cycle."""
        m = self.spec.motion
        spc = m.samples_per_cycle
        n = (m.cycles + 1) * spc
        t = np.arange(n) / (freq_hz * spc)
        w = 2.0 * math.pi * freq_hz
        a0, amp = math.radians(m.alpha0_deg), math.radians(m.amplitude_deg)
        alpha = a0 + amp * np.sin(w * t)
        return self.run_motion(t, alpha, amp * w * np.cos(w * t), -amp * w * w * np.sin(w * t), warmup=spc, rng=rng)


def simulate_spec(spec: AirfoilSpec, *, progress: Callable[[int, int], None] | None = None) -> Dataset:
    """Simulate every case of ``spec`` and return the data set (not yet written)."""
    sim = AirfoilSimulator(spec)
    rng = np.random.default_rng(spec.seed)
    m = spec.motion
    cps, coeffs, alphas, ts, case_ids, cases = [], [], [], [], [], []
    for i, (f, role) in enumerate(zip(m.freqs_hz, m.case_roles, strict=True)):
        run = sim.run_frequency(f, rng)
        cps.append(run.cp)
        coeffs.append(run.coeffs)
        alphas.append(run.alpha)
        ts.append(run.t)
        case_ids.append(np.full(len(run.t), i, dtype=np.int64))
        cases.append(
            Case(
                id=i,
                name=f"f{f:.3f}Hz",
                meta={
                    "freq_hz": f,
                    "alpha0_deg": m.alpha0_deg,
                    "amplitude_deg": m.amplitude_deg,
                    "speed_m_s": spec.speed_m_s,
                    "pivot_x_c": m.pivot_x_c,
                    "reduced_frequency": math.pi * f * spec.chord_m / spec.speed_m_s,
                    "role": role,
                },
            )
        )
        if progress is not None:
            progress(i + 1, len(m.freqs_hz))
    return Dataset(
        name=spec.name,
        source=f"{GENERATOR}: {spec.source}",
        reference=sim.flow.reference,
        cases=tuple(cases),
        cp=np.concatenate(cps),
        points=np.asarray(sim.points, dtype=np.float64),
        normals=np.asarray(sim.normals, dtype=np.float64),
        areas=np.asarray(sim.areas, dtype=np.float64),
        alpha=np.concatenate(alphas),
        t=np.concatenate(ts),
        case=np.concatenate(case_ids),
        coeffs=np.concatenate(coeffs),
        beta=None,
        point_names=sim.point_names,
        extra={"spec": sim.completed_spec(), "generator": GENERATOR},
        path=None,
    )
