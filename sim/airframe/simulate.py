"""Run an airframe spec into a ``vdm-aero-dataset/1`` data set, in memory or streamed to disk.

Besides the format's files the data set directory carries ``states.npy``: float64 (M, 10), the flight
state of every snapshot in :data:`sim.airframe.vlm.STATE_COLUMNS` order (airspeed [m/s], α, β [rad],
p, q, r [rad/s], α̇ [rad/s], aileron, elevator, rudder [rad]); ``dataset.yaml`` names it under
``extra.states`` and records the mass properties under ``extra.mass_properties``.
:func:`write_airframe_dataset` writes it (and fills ``cp.npy`` chunk by chunk through a memory map, so N
can be in the hundreds of thousands); :func:`simulate_airframe_spec` returns the in-memory data set
without it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from sim.airfoil.effects import effect_defaults
from sim.airfoil.flow import AirfoilFlow
from sim.airfoil.separation import complete_effects
from sim.airframe.geometry import AirframeGeometry, build_geometry, surface_for
from sim.airframe.pressure import BLOCK_STATES, AirframePressureModel, ScratchBuffers, SurfaceField
from sim.airframe.spec import ENVELOPE_VARIABLES, AirframeSpec, EnvelopeMotion, PitchMotion
from sim.airframe.vlm import STATE_COLUMNS, FlightStates
from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.dataset import STATES_FILE, Case, Dataset, create_dataset_memmap, default_point_names
from vdm_aero.lag import lag_coefficients

__all__ = [
    "GENERATOR",
    "STATES_FILE",
    "AirframeSimulator",
    "PlannedCase",
    "complete_airframe_effects",
    "simulate_airframe",
    "simulate_airframe_spec",
    "write_airframe_dataset",
]

GENERATOR: Final = "vdm-aero sim.airframe 0.1"
_CHUNK_ELEMENTS: Final = 1 << 22  # Cp values per written chunk (32 MiB in float64)


def complete_airframe_effects(spec: AirframeSpec) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, float]]]:
    """(Every switched-on effect with every parameter filled in, the static separation fit per airfoil).

    The separation fit of each section family is taken from ``separation_calibration`` when the spec has
    it (a re-simulated data set), else calibrated from NeuralFoil's polar at the family's Reynolds number
    (nominal speed, mean chord of the surfaces using it); parameters given under
    ``effects.trailing_edge_separation`` override both, for every family.
    """
    effects: dict[str, dict[str, Any]] = {}
    for name, params in spec.effects.items():
        effects[name] = dict(params) if name == "port_bias" else {**effect_defaults(name), **params}
    separation: dict[str, dict[str, float]] = {}
    if "trailing_edge_separation" in spec.effects:
        user = dict(spec.effects["trailing_edge_separation"])
        d = spec.design
        chords: dict[str, list[float]] = {}
        for s in (d.wing, d.htail, d.vtail):
            chords.setdefault(s.airfoil.lower(), []).append(0.5 * (s.root_chord_m + s.tip_chord_m))
        for af, cs in sorted(chords.items()):
            if af in spec.separation_calibration:
                separation[af] = {**spec.separation_calibration[af], **user}
                continue
            chord = float(np.mean(cs))

            def factory(eff: Mapping[str, Mapping[str, Any]], af: str = af, chord: float = chord) -> AirfoilFlow:
                return AirfoilFlow(
                    airfoil=af,
                    n_panels=spec.section_panels,
                    chord_m=chord,
                    span_m=1.0,
                    pivot_x_c=0.25,
                    speed_m_s=spec.speed_m_s,
                    effects=eff,
                )

            full = complete_effects(
                {"trailing_edge_separation": user}, airfoil=af, reynolds=spec.reynolds(chord), flow_factory=factory
            )
            separation[af] = {k: float(v) for k, v in full["trailing_edge_separation"].items()}
        effects["trailing_edge_separation"] = {**effect_defaults("trailing_edge_separation"), **user}
    return effects, separation


@dataclass(frozen=True, eq=False)
class PlannedCase:
    """One case of the data set: its metadata, sample times, flight states and how it is simulated
    (``warmup`` leading samples time-marched and dropped, or independent quasi-steady states)."""

    case: Case
    t: F64Array
    states: FlightStates
    warmup: int
    marched: bool

    @property
    def n_kept(self) -> int:
        return len(self.t) - self.warmup


class AirframeSimulator:
    """A spec made runnable: geometry, completed effects, pressure model and the case plan, built once."""

    def __init__(self, spec: AirframeSpec) -> None:
        self.spec = spec
        self.effects, self.separation = complete_airframe_effects(spec)
        self.geometry: AirframeGeometry = build_geometry(spec.design, surface_for(spec.surface_points))
        self.reference = spec.reference or self.geometry.default_reference()
        self.model = AirframePressureModel(
            self.geometry,
            effects=self.effects,
            separation=self.separation,
            reference=self.reference,
            vlm_resolution=spec.lattice,
            section_panels=spec.section_panels,
            speed_m_s=spec.speed_m_s,
        )
        self.cases = self._plan()

    @property
    def n_snapshots(self) -> int:
        return sum(c.n_kept for c in self.cases)

    def completed_spec(self) -> dict[str, Any]:
        """The spec with every effect parameter and the separation fit filled in (what re-simulation
        needs without NeuralFoil)."""
        d = self.spec.to_dict()
        # the separation fit lives per airfoil under separation_calibration; effects keep the user's
        # overrides of it (re-parsed, they would override the calibration for every family)
        d["effects"] = {
            k: dict(self.spec.effects[k] if k == "trailing_edge_separation" else v) for k, v in self.effects.items()
        }
        if self.separation:
            d["separation_calibration"] = {k: dict(v) for k, v in self.separation.items()}
        return d

    # -------------------------------------------------------------------------------------- plan
    def _plan(self) -> list[PlannedCase]:
        m = self.spec.motion
        if isinstance(m, PitchMotion):
            return [
                self._pitch_case(i, f, role) for i, (f, role) in enumerate(zip(m.freqs_hz, m.case_roles, strict=True))
            ]
        return self._envelope_cases(m)

    def _pitch_case(self, i: int, freq_hz: float, role: str) -> PlannedCase:
        m = self.spec.motion
        assert isinstance(m, PitchMotion)
        spc = m.samples_per_cycle
        t = np.arange((m.cycles + 1) * spc) / (freq_hz * spc)
        w = 2.0 * math.pi * freq_hz
        a0, amp = math.radians(m.alpha0_deg), math.radians(m.amplitude_deg)
        alpha = a0 + amp * np.sin(w * t)
        rate = amp * w * np.cos(w * t)  # the stream is fixed and the aircraft rotates: q = α̇
        states = FlightStates.make(
            m.speed_m_s, alpha_rad=alpha, beta_rad=math.radians(m.beta_deg), q_rad_s=rate, alpha_dot_rad_s=rate
        )
        meta = {
            "freq_hz": freq_hz,
            "alpha0_deg": m.alpha0_deg,
            "amplitude_deg": m.amplitude_deg,
            "speed_m_s": m.speed_m_s,
            "beta_deg": m.beta_deg,
            "reduced_frequency": math.pi * freq_hz * self.reference.chord_m / m.speed_m_s,
            "role": role,
        }
        return PlannedCase(Case(id=i, name=f"f{freq_hz:.3f}Hz", meta=meta), t, states, warmup=spc, marched=True)

    def _envelope_cases(self, m: EnvelopeMotion) -> list[PlannedCase]:
        out: list[PlannedCase] = []

        def states_from(values: Mapping[str, F64Array]) -> FlightStates:
            kw = {ENVELOPE_VARIABLES[v][0]: np.asarray(x) * ENVELOPE_VARIABLES[v][1] for v, x in values.items()}
            return FlightStates(**kw)

        for var in m.sweeps:
            lo, hi = m.ranges[var]
            vals = {v: np.full(m.sweep_points, m.base[v]) for v in ENVELOPE_VARIABLES}
            vals[var] = np.linspace(lo, hi, m.sweep_points)
            meta = {"role": "train", "sweep": var, "range": [lo, hi], "speed_m_s": m.base["speed_m_s"]}
            if var == "speed_m_s":
                meta["speed_m_s"] = None
            out.append(self._quasi_case(len(out), f"sweep-{var}", meta, states_from(vals)))
        rng = np.random.default_rng(self.spec.seed)
        for role, n in m.random_counts.items():
            if n == 0:
                continue
            vals = {v: rng.uniform(*m.ranges[v], n) for v in ENVELOPE_VARIABLES}
            out.append(self._quasi_case(len(out), f"random-{role}", {"role": role}, states_from(vals)))
        return out

    def _quasi_case(self, i: int, name: str, meta: dict[str, Any], states: FlightStates) -> PlannedCase:
        m = self.spec.motion
        assert isinstance(m, EnvelopeMotion)
        t = np.arange(len(states), dtype=np.float64) * m.sample_interval_s  # nominal: the states are independent
        return PlannedCase(Case(id=i, name=name, meta=meta), t, states, warmup=0, marched=False)

    # --------------------------------------------------------------------------------------- run
    def field(self, planned: PlannedCase) -> SurfaceField:
        """The surface field of a case's kept samples."""
        if planned.marched:
            return self.model.field_marched(planned.t, planned.states, warmup=planned.warmup)
        return self.model.field_quasi_steady(planned.states)

    def rows_per_chunk(self) -> int:
        return max(1, min(BLOCK_STATES, _CHUNK_ELEMENTS // self.geometry.n_points))

    def run(
        self,
        sink: Callable[[int, FloatArray], None],
        *,
        progress: Callable[[int, int], None] | None = None,
    ) -> dict[str, Any]:
        """Simulate every case, handing float32 Cp row blocks to ``sink(first_row, block)``; returns the
        small arrays (alpha, beta, t, case, coeffs, states) and the cases."""
        spec = self.spec
        rng = np.random.default_rng(spec.seed)
        n = self.geometry.n_points
        eff = self.effects
        names = {name: i for i, name in enumerate(default_point_names(n))} if "port_bias" in eff else {}
        bias = [(names[k], float(v)) for k, v in eff.get("port_bias", {}).items()]
        chunk = self.rows_per_chunk()
        buf = np.empty((chunk, n))
        scratch = ScratchBuffers()
        coeffs, states, ts, case_ids = [], [], [], []
        row = 0
        for ic, planned in enumerate(self.cases):
            field = self.field(planned)
            k = len(field)
            c = np.empty((k, 6))
            lag = _RowLag(float(eff["port_lag"]["tau_s"])) if "port_lag" in eff else None
            t_kept = planned.t[planned.warmup :]
            for a in range(0, k, chunk):
                rows = slice(a, min(a + chunk, k))
                blk = buf[: rows.stop - rows.start]
                c[rows] = self.model.evaluate(field, rows, out=blk, buf=scratch)[1]
                if lag is not None:
                    lag.apply(t_kept[rows], blk)
                for j, b in bias:
                    blk[:, j] += b
                out = blk.astype(np.float32)
                if spec.cp_std_fraction > 0.0:
                    out *= 1.0 + spec.cp_std_fraction * rng.standard_normal(out.shape, dtype=np.float32)
                sink(row + a, out)
            row += k
            coeffs.append(c)
            states.append(field.states.to_array())
            ts.append(t_kept - t_kept[0])
            case_ids.append(np.full(k, planned.case.id, dtype=np.int64))
            if progress is not None:
                progress(ic + 1, len(self.cases))
        st = np.concatenate(states)
        return {
            "cases": tuple(p.case for p in self.cases),
            "alpha": st[:, STATE_COLUMNS.index("alpha_rad")],
            "beta": st[:, STATE_COLUMNS.index("beta_rad")],
            "t": np.concatenate(ts),
            "case": np.concatenate(case_ids),
            "coeffs": np.concatenate(coeffs),
            "states": st,
        }

    def extra(self) -> dict[str, Any]:
        """The ``dataset.yaml`` extra keys: completed spec, generator, state table, mass properties."""
        g = self.geometry
        return {
            "spec": self.completed_spec(),
            "generator": GENERATOR,
            "states": {
                "file": STATES_FILE,
                "columns": list(STATE_COLUMNS),
                "note": "float64 (M, 10) flight state of every snapshot; SI units (rad, rad/s, m/s)",
            },
            "mass_properties": {
                "mass_kg": g.mass_kg,
                "cg_b": [0.0, 0.0, 0.0],
                "inertia_kg_m2": [[float(v) for v in row] for row in g.inertia_kg_m2],
            },
            "surface_resolution": {k: int(v) for k, v in vars(g.resolution).items()},
        }


class _RowLag:
    """First-order lag of every column along the rows (port tubing), carried across row chunks; exact for
    inputs linear between samples (first-order hold), starting at rest on the first sample."""

    def __init__(self, tau_s: float) -> None:
        self.tau = tau_s
        self.t_prev: float | None = None
        self.x_prev: F64Array | None = None
        self.y_prev: F64Array | None = None

    def apply(self, t: F64Array, x: F64Array) -> None:
        for i in range(len(t)):
            xi = x[i].copy()
            if self.t_prev is None or self.x_prev is None or self.y_prev is None:
                y = xi
            else:
                e, a, b = (float(c) for c in lag_coefficients(float(t[i]) - self.t_prev, self.tau))
                y = e * self.y_prev + a * self.x_prev + b * xi
            x[i] = y
            self.t_prev, self.x_prev, self.y_prev = float(t[i]), xi, y


def simulate_airframe(
    spec: AirframeSpec, *, progress: Callable[[int, int], None] | None = None
) -> tuple[Dataset, F64Array]:
    """Simulate every case into an in-memory data set (Cp float32) and the (M, 10) state table."""
    sim = AirframeSimulator(spec)
    cp = np.empty((sim.n_snapshots, sim.geometry.n_points), dtype=np.float32)

    def sink(start: int, block: FloatArray) -> None:
        cp[start : start + len(block)] = block

    r = sim.run(sink, progress=progress)
    ds = Dataset(cp=cp, **_dataset_fields(spec, sim, r))
    return ds, r["states"]


def _dataset_fields(spec: AirframeSpec, sim: AirframeSimulator, r: Mapping[str, Any]) -> dict[str, Any]:
    """Everything of the data set but Cp: shared by the in-memory and the streamed writer."""
    g = sim.geometry
    return {
        "name": spec.name,
        "source": f"{GENERATOR}: {spec.source}",
        "reference": sim.reference,
        "cases": r["cases"],
        "points": g.points_b,
        "normals": g.normals_b,
        "areas": g.areas_m2,
        "alpha": r["alpha"],
        "t": r["t"],
        "case": r["case"],
        "coeffs": r["coeffs"],
        "beta": r["beta"],
        "extra": sim.extra(),
    }


def simulate_airframe_spec(spec: AirframeSpec, *, progress: Callable[[int, int], None] | None = None) -> Dataset:
    """Simulate every case of ``spec`` and return the data set (not yet written; no ``states.npy``)."""
    return simulate_airframe(spec, progress=progress)[0]


def write_airframe_dataset(
    spec: AirframeSpec, out: str | Path, *, progress: Callable[[int, int], None] | None = None
) -> Path:
    """Simulate ``spec`` straight into the data set directory ``out`` (Cp float32 through a memory map,
    bounded memory for any N) and add ``states.npy``. Returns the directory."""
    sim = AirframeSimulator(spec)
    g = sim.geometry
    dest = Path(out)
    with create_dataset_memmap(dest, n_snapshots=sim.n_snapshots, n_points=g.n_points) as w:

        def sink(start: int, block: FloatArray) -> None:
            w.cp[start : start + len(block)] = block

        r = sim.run(sink, progress=progress)
        w.finish(**_dataset_fields(spec, sim, r))
    np.save(dest / STATES_FILE, np.ascontiguousarray(r["states"], dtype=np.float64))
    return dest
