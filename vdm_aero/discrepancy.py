"""Discrepancy workflow: where do simulation and measurement disagree, which named physical effect is
missing, with which parameters, and how much of the gap does adding it close on unseen cases.

Pure analysis: the simulator is injected through :class:`ReplaySimulator` (``sim`` implements it), so
this module never imports ``sim``.

Objective (whitened). Channels are the P port Cp and the integrated coefficients C_L, C_D, C_m. Each
channel's residual r (measured − simulated) is divided by its scale σ = max(σ_noise, ``MODEL_TOLERANCE`` ×
spread of the measured channel), with σ_noise from second differences of the baseline residual on the
training cases (noise is white, model error is smooth in time: σ = median|Δ²r| / (0.6745·√6), robust to
the sparse sharp features of model error). Then

    J = ½·mean_ports((r/σ)²) + ½·mean_coeffs((r/σ)²)     (averaged over samples)

so both kinds of evidence count equally, a localised fault (one port) is judged against that port's
noise, and the part of J that no model can remove, J_floor = ½·mean(σ_noise²/σ²) + ½·…, is known.

Naming. Each candidate effect is switched on (or re-fitted, if the spec already has it) on top of the
current model and its parameters are fitted by bounded least squares on the *training* cases
(multi-parameter effects from two starts); it is scored by its held-out gain, the drop in held-out J
as a share of the explainable J that remains (J_current − J_floor). Greedy forward selection adds the
best candidate (gains within ``PARSIMONY_TOL`` are a tie, won by the candidate with fewer parameters:
several library effects can mimic each other, and the simpler explanation is preferred) while its gain
is at least ``MIN_HELDOUT_GAIN``, its absolute drop in J at least ``MIN_ABSOLUTE_GAIN`` × J_floor, its
bootstrap inclusion probability at least ``MIN_INCLUSION``, and the remaining explainable J is
significant (≥ ``MIN_REMAINING`` of the floor), up to ``MAX_EFFECTS``. The result is named only if the
selected effects together explain at least ``MIN_EXPLAINED_SHARE`` of the explainable held-out J;
otherwise the report says ``unexplained`` with the hot spots and names nothing. Inclusion
probabilities come from a block bootstrap of the held-out samples (no refits: the per-sample residual
energies of every fitted candidate are resampled).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.coefficients import lift_drag

MIN_HELDOUT_GAIN = 0.05  # each named effect must cut the remaining explainable held-out J by ≥ 5 %
MIN_REMAINING = 0.05  # another round only while J − J_floor ≥ 5 % of J_floor (a systematic residual is left)
MODEL_TOLERANCE = 0.01  # channel scale floor: 1 % of the channel's spread is not worth explaining
MIN_ABSOLUTE_GAIN = 0.1  # ... and cut it by ≥ 10 % of the noise floor J_floor (significance, not fiddling)
MIN_INCLUSION = 0.5  # ... and win in ≥ 50 % of the bootstrap resamples
PARSIMONY_TOL = 0.01  # gains within 1 % (of the remaining explainable J) are a tie: fewer parameters win
MIN_EXPLAINED_SHARE = 0.5  # named effects must explain ≥ 50 % of the explainable J, else "unexplained"
PROBES = 16  # Sobol points probed for the second start of a multi-parameter fit
MAX_EFFECTS = 8  # every library effect could be named: the rules, not a count, end the rounds
BOOTSTRAP_SAMPLES = 200
BOOTSTRAP_BLOCK = 16  # samples per bootstrap block (keeps the within-cycle correlation)
PORT_BIAS_MIN_CP = 0.01  # a per-port offset below this is treated as zero
PORT_BIAS_MAD_FACTOR = 6.0  # ... and so is one within 6 robust spreads of the other ports' offsets
COEFFS = ("CL", "CD", "Cm")

Effects = Mapping[str, Mapping[str, Any]]


class ReplaySimulator(Protocol):
    """Simulates a spec's effect set along the measured cases, at the measured ports."""

    def simulate(self, effects: Effects, cases: Sequence[int]) -> dict[int, tuple[F64Array, F64Array]]:
        """{case id: (port Cp (K, P), body-axis coefficients (K, 6))} for ``effects``."""
        ...


@dataclass(frozen=True)
class Candidate:
    """A named effect with its fitted parameters' start value and bounds: {param: (x0, low, high)}.

    ``kind="port_bias"``: the parameters are per-port Cp offsets, estimated in closed form.
    ``kind="pair"``: a prerequisite and an effect that requires it, fitted together (``name`` is
    ``"prerequisite+dependent"``, parameters ``"effect.param"``), so that the dependent can win a round its
    prerequisite alone would not.
    """

    name: str
    params: Mapping[str, tuple[float, float, float]]
    kind: str = "continuous"

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(self.name.split("+")) if self.kind == "pair" else (self.name,)


CandidateSource = Sequence[Candidate] | Callable[[Mapping[str, Mapping[str, Any]]], Sequence[Candidate]]
"""A fixed candidate list, or a function of the effects named so far (candidates rebuilt every round)."""
BOUND_TOLERANCE = 0.01  # a fitted parameter within 1 % of its range from a bound is reported as at the bound


@dataclass(frozen=True)
class MeasuredCase:
    """One measured case: incidence [rad], time [s], port Cp (K, P), coefficients (K, 6), and its
    reduced frequency (NaN when unknown)."""

    case_id: int
    alpha: F64Array
    t: F64Array
    cp: F64Array
    coeffs: F64Array
    reduced_frequency: float


@dataclass(frozen=True)
class PortInfo:
    name: str
    x_c: float
    upper: bool


@dataclass
class Fit:
    name: str
    params: dict[str, float]
    effects: dict[str, dict[str, Any]]
    train_j: float
    heldout_j: float
    gain: float = 0.0
    n_params: int = 0
    sample_energy: dict[int, F64Array] = field(default_factory=dict)  # held-out per-sample energy
    at_bounds: dict[str, str] = field(default_factory=dict)  # param → "low" / "high" (within BOUND_TOLERANCE)


def _lcm(coeffs: F64Array, alpha: F64Array) -> F64Array:
    """(K, 3): C_L, C_D, C_m (pitching moment about the reference point)."""
    cl, cd = lift_drag(coeffs, alpha)
    return np.column_stack([cl, cd, coeffs[:, 4]])


class Discovery:
    """One discovery run over measured cases split into training and held-out sets."""

    def __init__(
        self,
        sim: ReplaySimulator,
        cases: Sequence[MeasuredCase],
        ports: Sequence[PortInfo],
        *,
        train: Sequence[int],
        heldout: Sequence[int],
        base_effects: Effects,
        candidates: CandidateSource,
        seed: int = 0,
        progress: Callable[[str], None] | None = None,
        max_effects: int = MAX_EFFECTS,
    ) -> None:
        if not train or not heldout or set(train) & set(heldout):
            raise ValueError("training and held-out cases must be non-empty and disjoint")
        self.sim = sim
        self.cases = {c.case_id: c for c in cases}
        self.ports = tuple(ports)
        self.train, self.heldout = list(train), list(heldout)
        self.base_effects = {k: dict(v) for k, v in base_effects.items()}
        self.candidates = candidates if callable(candidates) else list(candidates)
        self.rng = np.random.default_rng(seed)
        self.probe_rng = np.random.default_rng([seed, 1])  # the fits' start probes: apart from the bootstrap's
        self.max_effects = max_effects  # fewer only for a first look (`demo --quick`): the rules end the rounds
        self.progress = progress or (lambda _msg: None)
        self.meas_lcm = {cid: _lcm(c.coeffs, c.alpha) for cid, c in self.cases.items()}
        tr_cp = np.concatenate([self.cases[c].cp for c in self.train])
        tr_lcm = np.concatenate([self.meas_lcm[c] for c in self.train])
        self.spread_cp = np.maximum(np.std(tr_cp, axis=0), 1e-12)
        self.spread_c = np.maximum(np.std(tr_lcm, axis=0), 1e-12)
        # until the noise is estimated (first call of run/calibrate_scales), scale by the spread
        self.s_cp, self.s_c = self.spread_cp.copy(), self.spread_c.copy()
        self.floor_cp, self.floor_c = np.zeros_like(self.s_cp), np.zeros_like(self.s_c)
        self.n_evals = 0

    # ------------------------------------------------------------------------------- residual algebra
    def residuals(self, effects: Effects, cases: Sequence[int]) -> dict[int, tuple[F64Array, F64Array]]:
        """{case: (Cp residual (K, P), coefficient residual (K, 3))}, measured − simulated."""
        self.n_evals += 1
        sim = self.sim.simulate(effects, cases)
        out = {}
        for cid in cases:
            cp, co = sim[cid]
            c = self.cases[cid]
            out[cid] = (c.cp - cp, self.meas_lcm[cid] - _lcm(co, c.alpha))
        return out

    def sample_energy(self, res: Mapping[int, tuple[F64Array, F64Array]]) -> dict[int, F64Array]:
        """Per-sample contribution to J (mean over samples of it is J)."""
        return {
            cid: 0.5 * np.mean((rcp / self.s_cp) ** 2, axis=1) + 0.5 * np.mean((rc / self.s_c) ** 2, axis=1)
            for cid, (rcp, rc) in res.items()
        }

    def calibrate_scales(self) -> None:
        """Channel scales from the noise of the baseline residual on the training cases."""
        res = self.residuals(self.base_effects, self.train)
        d2cp = np.concatenate([np.diff(r[0], n=2, axis=0) for r in res.values()])
        d2c = np.concatenate([np.diff(r[1], n=2, axis=0) for r in res.values()])
        # median, not mean square: model error has sparse sharp features (a separation point sweeping
        # past a tap) that a mean square would count as noise. For white Gaussian noise Δ²r ~ N(0, 6σ²).
        noise_cp = np.median(np.abs(d2cp), axis=0) / (0.6745 * math.sqrt(6.0))
        noise_c = np.median(np.abs(d2c), axis=0) / (0.6745 * math.sqrt(6.0))
        self.s_cp = np.maximum(noise_cp, MODEL_TOLERANCE * self.spread_cp)
        self.s_c = np.maximum(noise_c, MODEL_TOLERANCE * self.spread_c)
        self.floor_cp, self.floor_c = (noise_cp / self.s_cp) ** 2, (noise_c / self.s_c) ** 2

    @property
    def j_floor(self) -> float:
        """J of the measurement noise alone (what no model can explain)."""
        return float(0.5 * np.mean(self.floor_cp) + 0.5 * np.mean(self.floor_c))

    @staticmethod
    def j_of(energy: Mapping[int, F64Array]) -> float:
        return float(np.mean(np.concatenate(list(energy.values()))))

    def _vector(self, res: Mapping[int, tuple[F64Array, F64Array]]) -> F64Array:
        """Residual vector whose squared norm is J (for least squares)."""
        cp = np.concatenate([(r[0] / self.s_cp).ravel() for r in res.values()])
        cc = np.concatenate([(r[1] / self.s_c).ravel() for r in res.values()])
        return np.concatenate([cp * math.sqrt(0.5 / cp.size), cc * math.sqrt(0.5 / cc.size)])

    # ----------------------------------------------------------------------------------------- gaps
    def gap(self, effects: Effects, cases: Sequence[int]) -> dict[str, Any]:
        res = self.residuals(effects, cases)
        rcp = np.concatenate([r[0] for r in res.values()])
        rc = np.concatenate([r[1] for r in res.values()])
        return {
            "coeff_rms": {n: float(np.sqrt(np.mean(rc[:, i] ** 2))) for i, n in enumerate(COEFFS)},
            "cp_rms": float(np.sqrt(np.mean(rcp**2))),
            "port_cp_rms": {p.name: float(np.sqrt(np.mean(rcp[:, i] ** 2))) for i, p in enumerate(self.ports)},
            "objective": self.j_of(self.sample_energy(res)),
        }

    # ------------------------------------------------------------------------------------- hot spots
    def hotspots(self, effects: Effects, cases: Sequence[int], top: int | None = 12) -> list[dict[str, Any]]:
        """Where the residual lives: by port, surface region, α bin × stroke, and case (reduced frequency).

        ``share`` is the fraction of that kind's residual energy; ``concentration`` = share ÷ the share a
        uniform spread would give (so a hot spot among many small bins ranks above a broad one); ``rms`` is
        the gap there in absolute terms: RMS Cp residual of the spot's ports, and for α bins and cases also
        the RMS C_L, C_D, C_m residual of the spot's samples. ``top=None`` returns every spot."""
        res = self.residuals(effects, cases)
        energy = self.sample_energy(res)
        spots: list[dict[str, Any]] = []

        def add(kind: str, labels: list[str], values: F64Array, rms: list[dict[str, float]]) -> None:
            tot = float(values.sum())
            if tot <= 0:
                return
            for lab, v, r in zip(labels, values, rms, strict=True):
                share = float(v / tot)
                spots.append(
                    {"kind": kind, "label": lab, "share": share, "concentration": share * len(values), "rms": r}
                )

        def rms_of(rcp_s: F64Array, rc_s: F64Array | None) -> dict[str, float]:
            out = {"Cp": float(np.sqrt(np.mean(rcp_s**2)))}
            if rc_s is not None:
                out |= {n: float(np.sqrt(np.mean(rc_s[:, i] ** 2))) for i, n in enumerate(COEFFS)}
            return out

        rcp = np.concatenate([res[c][0] for c in cases])
        rc = np.concatenate([res[c][1] for c in cases])
        add("port", [p.name for p in self.ports], np.sum(rcp**2, axis=0), [rms_of(rcp[:, i], None) for i in
                                                                            range(len(self.ports))])  # fmt: skip
        regions: dict[str, list[int]] = {}
        for i, p in enumerate(self.ports):
            zone = "leading edge" if p.x_c < 0.1 else ("mid chord" if p.x_c < 0.6 else "aft")
            regions.setdefault(f"{'upper' if p.upper else 'lower'} {zone}", []).append(i)
        e_port = np.sum(rcp**2, axis=0)
        add(
            "region",
            list(regions),
            np.array([e_port[idx].sum() / len(idx) for idx in regions.values()]),
            [rms_of(rcp[:, idx], None) for idx in regions.values()],
        )
        alpha = np.concatenate([self.cases[c].alpha for c in cases])
        upstroke = np.concatenate([np.gradient(self.cases[c].alpha) > 0 for c in cases])
        e_all = np.concatenate([energy[c] for c in cases])
        a_deg = np.degrees(alpha)
        edges = np.arange(math.floor(a_deg.min() / 2) * 2, a_deg.max() + 2.0, 2.0)
        labels, vals, rmss = [], [], []
        for lo in edges[:-1]:
            for up, name in ((True, "upstroke"), (False, "downstroke")):
                m = (a_deg >= lo) & (a_deg < lo + 2) & (upstroke == up)
                if m.any():
                    labels.append(f"α {lo:.0f}–{lo + 2:.0f}° {name}")
                    vals.append(e_all[m].sum() / max(1, m.sum()) * m.sum())
                    rmss.append(rms_of(rcp[m], rc[m]))
        add("alpha", labels, np.array(vals), rmss)
        add(
            "case",
            [f"case {c} (k = {self.cases[c].reduced_frequency:.3f})" for c in cases],
            np.array([energy[c].sum() for c in cases]),
            [rms_of(res[c][0], res[c][1]) for c in cases],
        )
        spots.sort(key=lambda s: -s["concentration"] * s["share"])
        return spots if top is None else spots[:top]

    def remaining_gap(
        self, before: Effects, after: Effects, cases: Sequence[int], top: int = 12
    ) -> list[dict[str, Any]]:
        """The ``top`` hot spots of ``before`` with their absolute gap (``rms``) before and after ``after``."""
        after_by = {(s["kind"], s["label"]): s["rms"] for s in self.hotspots(after, cases, top=None)}
        return [
            {"kind": s["kind"], "label": s["label"], "share_before": s["share"], "rms_before": s["rms"],
             "rms_after": after_by.get((s["kind"], s["label"]), {})}
            for s in self.hotspots(before, cases, top=top)
        ]  # fmt: skip

    # --------------------------------------------------------------------------------------- fitting
    def _with(self, effects: Effects, name: str, params: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
        """``effects`` with ``name``'s parameters set; for a pair ("a+b") the ``"a.p"`` parameters go to a."""
        out = {k: dict(v) for k, v in effects.items()}
        if "+" not in name:
            out[name] = {**out.get(name, {}), **params}
            return out
        for part in name.split("+"):
            own = {k.split(".", 1)[1]: v for k, v in params.items() if k.split(".", 1)[0] == part}
            out[part] = {**out.get(part, {}), **own}
        return out

    def candidates_for(self, current: Effects, named: Sequence[str]) -> list[Candidate]:
        """This round's candidates: rebuilt from the effects named so far, without those already named."""
        cands = self.candidates(current) if callable(self.candidates) else self.candidates
        return [c for c in cands if not set(c.effect_names) & set(named)]

    def fit_candidate(self, cand: Candidate, current: Effects) -> Fit:
        """Fit the candidate's parameters on the training cases, on top of ``current``."""
        if cand.kind == "port_bias":
            return self._fit_port_bias(cand, current)
        from scipy.optimize import least_squares

        names = list(cand.params)
        x0 = np.array([cand.params[n][0] for n in names], dtype=float)
        lo = np.array([cand.params[n][1] for n in names], dtype=float)
        hi = np.array([cand.params[n][2] for n in names], dtype=float)
        x0 = np.clip(x0, lo, hi)

        def fun(x: F64Array) -> F64Array:
            eff = self._with(current, cand.name, dict(zip(names, map(float, x), strict=True)))
            return self._vector(self.residuals(eff, self.train))

        starts = [x0]
        if len(names) > 1:
            # a second start from the best of a scrambled Sobol probe of the box (and its centre): coupled
            # parameters (a vortex's onset, travel and decay times) have local minima a start at the
            # defaults alone does not leave
            from scipy.stats import qmc

            probe = [0.5 * (lo + hi), *(lo + (hi - lo) * qmc.Sobol(len(names), seed=self.probe_rng).random(PROBES))]
            starts.append(min(probe, key=lambda p: float(np.sum(fun(p) ** 2))))
        sols = [
            least_squares(fun, s0, bounds=(lo, hi), x_scale=hi - lo, diff_step=1e-3, max_nfev=60, xtol=1e-5)
            for s0 in starts
        ]
        sol = min(sols, key=lambda r: float(np.sum(r.fun**2)))
        params = {n: float(v) for n, v in zip(names, sol.x, strict=True)}
        eff = self._with(current, cand.name, params)
        fit = self._score(cand.name, params, eff, train_j=float(np.sum(sol.fun**2)))
        tol = BOUND_TOLERANCE * (hi - lo)
        for n, v, a, b, t in zip(names, sol.x, lo, hi, tol, strict=True):
            if v <= a + t or v >= b - t:  # the effect's shape or its range may not fit the data
                fit.at_bounds[n] = "low" if v <= a + t else "high"
        return fit

    def _fit_port_bias(self, cand: Candidate, current: Effects) -> Fit:
        res = self.residuals(current, self.train)
        mean_r = np.mean(np.concatenate([r[0] for r in res.values()]), axis=0)
        spread = 1.4826 * float(np.median(np.abs(mean_r - np.median(mean_r))))
        keep = (np.abs(mean_r) > PORT_BIAS_MIN_CP) & (
            np.abs(mean_r - np.median(mean_r)) > PORT_BIAS_MAD_FACTOR * spread
        )
        params = {self.ports[i].name: float(np.clip(mean_r[i], -0.2, 0.2)) for i in np.flatnonzero(keep)}
        merged = {**dict(current.get("port_bias", {})), **params}
        eff = {k: dict(v) for k, v in current.items()}
        eff["port_bias"] = merged
        train_j = self.j_of(self.sample_energy(self.residuals(eff, self.train)))
        return self._score(cand.name, params, eff, train_j=train_j)

    def _score(self, name: str, params: dict[str, float], eff: dict[str, dict[str, Any]], *, train_j: float) -> Fit:
        e = self.sample_energy(self.residuals(eff, self.heldout))
        return Fit(name, params, eff, train_j, self.j_of(e), n_params=len(params), sample_energy=e)

    # ------------------------------------------------------------------------------------- selection
    @staticmethod
    def pick(gains: F64Array, n_params: Sequence[int]) -> int:
        """Index of the winner: the best gain, ties within PARSIMONY_TOL going to fewer parameters."""
        tied = np.flatnonzero(gains >= gains.max() - PARSIMONY_TOL)
        return int(min(tied.tolist(), key=lambda i: (n_params[i], -gains[i])))

    def bootstrap_inclusion(
        self, fits: Sequence[Fit], reference: Mapping[int, F64Array], explainable: Mapping[int, F64Array]
    ) -> dict[str, float]:
        """P(candidate is the best and clears MIN_HELDOUT_GAIN) under a block bootstrap of held-out samples.

        ``explainable`` is the per-sample explainable energy of the baseline (its energy minus the floor)."""
        blocks = []
        for cid in self.heldout:
            k = len(reference[cid])
            blocks += [(cid, lo, min(lo + BOOTSTRAP_BLOCK, k)) for lo in range(0, k, BOOTSTRAP_BLOCK)]
        ref_b = np.array([reference[c][a:b].sum() for c, a, b in blocks])
        exp_b = np.array([explainable[c][a:b].sum() for c, a, b in blocks])
        fit_b = np.array([[f.sample_energy[c][a:b].sum() for c, a, b in blocks] for f in fits])
        wins = np.zeros(len(fits))
        for _ in range(BOOTSTRAP_SAMPLES):
            pick = self.rng.integers(0, len(blocks), len(blocks))
            denom = max(float(exp_b[pick].sum()), 1e-300)
            gains = (ref_b[pick].sum() - fit_b[:, pick].sum(axis=1)) / denom
            best = self.pick(gains, [f.n_params for f in fits])
            if gains[best] >= MIN_HELDOUT_GAIN:
                wins[best] += 1
        return {f.name: float(w / BOOTSTRAP_SAMPLES) for f, w in zip(fits, wins, strict=True)}

    @staticmethod
    def _named(f: Fit, inclusion: float) -> list[dict[str, Any]]:
        """The report's entries of a round's winner: one per effect (a pair names two, ``named_with`` each other)."""
        parts = f.name.split("+")

        def own(k: str) -> str:  # a pair's parameters are "effect.param"
            return k.split(".", 1)[1] if len(parts) > 1 else k

        out = []
        for part in parts:
            mine = [k for k in f.params if len(parts) == 1 or k.split(".", 1)[0] == part]
            e: dict[str, Any] = {"name": part, "params": {own(k): f.params[k] for k in mine},
                                 "inclusion_probability": inclusion, "heldout_gain": f.gain,
                                 "at_bounds": {own(k): f.at_bounds[k] for k in mine if k in f.at_bounds}}  # fmt: skip
            if len(parts) > 1:
                e["named_with"] = [p for p in parts if p != part]
            out.append(e)
        return out

    def run(self) -> dict[str, Any]:
        current = {k: dict(v) for k, v in self.base_effects.items()}
        self.calibrate_scales()
        base_e = self.sample_energy(self.residuals(current, self.heldout))
        base_j = self.j_of(base_e)
        floor = min(self.j_floor, base_j)
        explainable = max(base_j - floor, 1e-300)
        ref_e, ref_j = base_e, base_j
        rounds: list[dict[str, Any]] = []
        chosen: list[Fit] = []
        inclusion: dict[str, float] = {}
        named: list[str] = []
        for rnd in range(self.max_effects):
            remaining = self.candidates_for(current, named)
            remaining_j = ref_j - floor
            if rnd > 0 and remaining_j < MIN_REMAINING * floor:
                break  # what is left is noise
            fits = []
            for cand in remaining:
                self.progress(f"round {rnd + 1}: fitting {cand.name}")
                f = self.fit_candidate(cand, current)
                f.gain = (ref_j - f.heldout_j) / max(remaining_j, 1e-300)
                fits.append(f)
            if not fits:
                break
            fits.sort(key=lambda f: -f.gain)
            win = self.pick(np.array([f.gain for f in fits]), [f.n_params for f in fits])
            fits.insert(0, fits.pop(win))
            incl = self.bootstrap_inclusion(fits, ref_e, {c: np.maximum(e - floor, 0.0) for c, e in ref_e.items()})
            rounds.append(
                {
                    "round": rnd + 1,
                    "ranking": [
                        {
                            "name": f.name,
                            "heldout_gain": f.gain,
                            "params": f.params,
                            "inclusion_probability": incl[f.name],
                            "at_bounds": dict(f.at_bounds),
                        }
                        for f in fits
                    ],
                }
            )
            best = fits[0]
            significant = (ref_j - best.heldout_j) >= MIN_ABSOLUTE_GAIN * floor
            if best.gain < MIN_HELDOUT_GAIN or not significant or incl[best.name] < MIN_INCLUSION:
                break
            chosen.append(best)
            inclusion[best.name] = incl[best.name]
            current = best.effects
            ref_e, ref_j = best.sample_energy, best.heldout_j
            named += best.name.split("+")
        explained = (base_j - ref_j) / explainable
        unexplained = not chosen or explained < MIN_EXPLAINED_SHARE
        final = self.base_effects if unexplained else current
        return {
            "effects": [] if unexplained else [e for f in chosen for e in self._named(f, inclusion[f.name])],
            "explained_share": explained,
            "unexplained": unexplained,
            "rounds": rounds,
            "final_effects": final,
            "baseline_heldout_objective": base_j,
            "noise_floor_objective": floor,
        }
