"""Port frames → what the filter fuses: port health, air data (FADS) and aerodynamic coefficients.

Everything here is measurement-side (no filter state), so one front end serves every mode of a run.

Port faults, per frame:

* missing or NaN;
* out of range: |Δp| at the transducer's full scale (a saturated reading is not a measurement);
* stuck: the same value, bit for bit, for :attr:`PortFrontEnd.stuck_frames` frames (a live transducer's
  noise never repeats exactly; a frozen driver or a blocked tube with a dead sensor does);
* quiet: a port that no longer breathes with the flow (:class:`QuietPorts`). A line blocked at its orifice
  (ice, water, an insect) holds the air it trapped and reads plausible, slowly changing values that no check
  above sees, but the turbulence and the manoeuvres that move every other port's reading from frame to frame
  no longer reach it.

Faulty ports are NaN for the models: the FADS solve drops their rows, the aero model fills them by its
gappy (MAP) reconstruction, and the noise of both outputs is inflated by n_ports/n_ok.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vdm_aero._typing import BoolArray, F64Array
from vdm_aero.model import AeroModel
from vdm_aero.nav.design_fit import PortPressureModel

__all__ = ["PortFrame", "PortFrontEnd"]

MIN_QBAR_PA = 30.0  # below ~7 m/s the ports' Δp is noise-dominated: no air data


class QuietPorts:
    """The quiet-port check: each port's activity, the mean square of its reading's change over
    :data:`CHANGE_S` (whatever the frame rate: at 100 Hz a frame-to-frame change is half the 50 Hz one's and
    the transducer's noise is not), averaged over :data:`ACTIVITY_TAU_S`, against the ports' common activity
    (the median over the ports, which a few blocked ones cannot move) and against the share of it this port has
    shown in healthy flight (learnt: a port at the stagnation point breathes more than one on the shoulder). A
    port whose activity falls under :data:`QUIET_SHARE` of its own share, while the common activity is well above
    the transducers' noise (:data:`ACTIVE_NOISE_RATIO`), no longer sees the flow; it is back once above
    :data:`BACK_SHARE` for :data:`BACK_S`.

    Set on the harsh world's survey (4 flights of 535 s, 4 airframes, light and moderate turbulence, each flown
    healthy and with 1–3 ports blocked, 2026-11-27): healthy ports went as low as 0.05–0.1 of their share (three
    ports together for ~2 s in one light-turbulence flight: some manoeuvres move some ports little), blocked ones
    fell under 0.05 within 5.9–8.3 s of the blocking and stayed there (``docs/navigation.md``, "A blocked port
    group"). A port left out for a few seconds costs the solve one row of twelve; a blocked one kept in bends it.
    The share is learnt in the condition the aircraft flies: in slow flight at high α some ports' share falls
    under the threshold and healthy ports are called quiet (40 times in 2.76 h of the benchmark's manoeuvring
    flights, none in 21 h of survey and return flight).
    """

    CHANGE_S = 0.1
    ACTIVITY_TAU_S = 2.0
    SHARE_TAU_S = 60.0  # the share's learning (log-averaged)
    WARMUP_S = 60.0  # of active flow before any verdict
    QUIET_SHARE = 0.05  # under the lowest healthy share seen (0.05–0.1)
    BACK_SHARE = 0.2
    BACK_S = 5.0
    ACTIVE_NOISE_RATIO = 100.0  # the common activity over the change's noise variance, 2σ_n²

    def __init__(self, n_ports: int, noise_pa: float) -> None:
        self.noise_var_pa2 = 2.0 * noise_pa**2  # of a difference of two noisy readings
        self.quiet = np.zeros(n_ports, dtype=bool)
        self._prev: F64Array | None = None
        self._t_prev = math.nan
        self._activity = np.full(n_ports, math.nan)
        self._log_share = np.full(n_ports, math.nan)
        self._active_s = 0.0
        self._back_since = np.full(n_ports, math.nan)

    def observe(self, t_s: float, dp_pa: F64Array) -> None:
        """One frame at ``t_s`` [s] (NaN: a missing reading)."""
        prev, t_prev = self._prev, self._t_prev
        if prev is not None and len(prev) == len(dp_pa) and 0.0 <= t_s - t_prev < self.CHANGE_S:
            return  # the next change is taken CHANGE_S after this one's start
        self._prev, self._t_prev = dp_pa.copy(), t_s
        if prev is None or len(prev) != len(dp_pa) or not t_s > t_prev:
            return
        dt = t_s - t_prev
        d2 = (dp_pa - prev) ** 2
        fresh = np.isfinite(d2)
        a = min(dt / self.ACTIVITY_TAU_S, 1.0)
        act = self._activity
        act[fresh & np.isnan(act)] = d2[fresh & np.isnan(act)]
        self._activity = act = np.where(fresh, act + a * (d2 - act), act)
        common = float(np.nanmedian(act)) if np.isfinite(act).any() else math.nan
        if not common > self.ACTIVE_NOISE_RATIO * self.noise_var_pa2:
            return  # calm flow (or none): no port can be told from a blocked one
        self._active_s += dt
        share = act / common
        ok_share = fresh & (share > 0.0)
        log_share = np.log(np.where(ok_share, share, 1.0))
        ls = self._log_share
        learn = ok_share & ~self.quiet
        ls[learn & np.isnan(ls)] = log_share[learn & np.isnan(ls)]
        if self._active_s < self.WARMUP_S:  # the warm-up's plain mean, then a moving one
            w = dt / self._active_s
            self._log_share = np.where(learn, ls + w * (log_share - ls), ls)
            return
        rel = np.where(ok_share, share / np.exp(ls), 0.0)
        # a port under its own share teaches nothing: a slow blockage must not become its new normal
        learn &= rel > self.BACK_SHARE
        self._log_share = np.where(learn, ls + min(dt / self.SHARE_TAU_S, 1.0) * (log_share - ls), ls)
        newly = fresh & ~self.quiet & (rel < self.QUIET_SHARE)
        self.quiet |= newly
        self._back_since[newly] = math.nan
        for i in np.flatnonzero(self.quiet & ~newly):
            if not rel[i] > self.BACK_SHARE:
                self._back_since[i] = math.nan
            elif math.isnan(self._back_since[i]):
                self._back_since[i] = t_s
            elif t_s - self._back_since[i] >= self.BACK_S:
                self.quiet[i] = False


@dataclass(frozen=True)
class PortFrame:
    """One processed port frame at ``t_s``: usable-port mask, air data ((V [m/s], α, β [rad]) and its
    covariance, or None), dynamic pressure [Pa] and body coefficients (6,) per named aero model."""

    t_s: float
    ok: BoolArray
    airdata: F64Array | None
    airdata_cov: F64Array | None
    qbar_pa: float
    coeffs: dict[str, F64Array] = field(default_factory=dict)

    @property
    def n_ok(self) -> int:
        return int(self.ok.sum())

    @property
    def inflation(self) -> float:
        """Noise inflation for lost ports: n_ports / n_ok (∞ when none is left)."""
        return len(self.ok) / self.n_ok if self.n_ok else math.inf


class PortFrontEnd:
    """Health checks, the FADS solve and the aero models (``models``: name → :class:`AeroModel`, all on
    the same ports in the same order)."""

    def __init__(
        self,
        pressure_model: PortPressureModel,
        models: dict[str, AeroModel],
        *,
        range_pa: float,
        noise_pa: float,
        stuck_frames: int = 10,
    ) -> None:
        self.pressure_model = pressure_model
        self.models = models
        self.range_pa = range_pa
        self.noise_pa = noise_pa
        self.stuck_frames = stuck_frames
        self._last: F64Array | None = None
        self._same = np.zeros(0, dtype=np.int64)
        self._start: tuple[float, float, float] | None = None
        self.quiet_check = QuietPorts(len(pressure_model.cp_rms), noise_pa)
        self.counts = {"frames": 0, "nan": 0, "out_of_range": 0, "stuck": 0, "quiet": 0, "no_airdata": 0}
        self.events: list[tuple[float, int, str]] = []  # (t [s], port, "quiet" | "breathing again")

    def __deepcopy__(self, memo: dict[int, Any]) -> PortFrontEnd:
        """A branch of a run: its own health counters and warm start, the same (read-only) models."""
        out = copy.copy(self)
        out._last = None if self._last is None else self._last.copy()
        out._same = self._same.copy()
        out.counts = dict(self.counts)
        out.quiet_check = copy.deepcopy(self.quiet_check, memo)
        out.events = list(self.events)
        return out

    def health(self, dp_pa: F64Array, t_s: float = math.nan) -> BoolArray:
        """Usable ports of the frame at ``t_s`` [s] (updates the stuck-port counters; the quiet-port check needs
        the time)."""
        dp = np.asarray(dp_pa, dtype=np.float64)
        finite = np.isfinite(dp)
        in_range = finite & (np.abs(np.where(finite, dp, 0.0)) < 0.995 * self.range_pa)
        if self._last is None or len(self._last) != len(dp):
            self._same = np.zeros(len(dp), dtype=np.int64)
        else:
            same = finite & (dp == self._last)
            self._same = np.where(same, self._same + 1, 0)
        self._last = dp.copy()
        stuck = self._same >= self.stuck_frames
        qc = self.quiet_check
        if math.isfinite(t_s) and len(qc.quiet) == len(dp):
            was = qc.quiet.copy()
            qc.observe(t_s, np.where(in_range, dp, np.nan))
            self.events += [(t_s, int(i), "quiet") for i in np.flatnonzero(qc.quiet & ~was)]
            self.events += [(t_s, int(i), "breathing again") for i in np.flatnonzero(was & ~qc.quiet)]
        quiet = qc.quiet if len(qc.quiet) == len(dp) else np.zeros(len(dp), dtype=bool)
        c = self.counts
        c["frames"] += 1
        c["nan"] += int((~finite).sum())
        c["out_of_range"] += int((finite & ~in_range).sum())
        c["stuck"] += int((in_range & stuck).sum())
        c["quiet"] += int((in_range & ~stuck & quiet).sum())
        return np.asarray(in_range & ~stuck & ~quiet)

    def air_data(
        self, dp_pa: F64Array, rho_kg_m3: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[F64Array, F64Array, float] | None:
        """The FADS solve of one frame (NaN marks an unusable port), warm-started from the last frame's:
        ((V [m/s], α, β [rad]), its covariance (3, 3), q̄ [Pa]), or None with no air data (too few ports, no
        convergence, or q̄ below :data:`MIN_QBAR_PA`). Calibration normalises Cp with this same q̄."""
        sol = self.pressure_model.solve(dp_pa, rho_kg_m3, omega_b, controls_rad, noise_pa=self.noise_pa,
                                        start=self._start)  # fmt: skip
        if sol is None and self._start is not None:  # a bad warm start (after a gap): try cold
            sol = self.pressure_model.solve(dp_pa, rho_kg_m3, omega_b, controls_rad, noise_pa=self.noise_pa)
        if sol is None:
            self._start = None
            return None
        vab, cov, _ = sol
        qbar = 0.5 * rho_kg_m3 * float(vab[0]) ** 2
        if qbar < MIN_QBAR_PA:
            self._start = None
            return None
        self._start = (qbar, float(vab[1]), float(vab[2]))
        return vab, cov, qbar

    def process(
        self,
        t_s: float,
        dp_pa: F64Array,
        rho_kg_m3: float,
        omega_b: F64Array,
        controls_rad: F64Array,
        ok: BoolArray | None = None,
    ) -> PortFrame:
        """Solve one frame (``ok``: the mask :meth:`health` gave for it; checked here when None). Cp = Δp / q̄
        with the FADS solve's q̄, the normalisation the models were calibrated with (:func:`form_targets`):
        the pitot's q̄ would tie the force model to the very sensor whose failures it must outlive."""
        if ok is None:
            ok = self.health(dp_pa, t_s)
        dp = np.where(ok, np.asarray(dp_pa, dtype=np.float64), np.nan)
        solved = self.air_data(dp, rho_kg_m3, omega_b, controls_rad)
        if solved is None:
            self.counts["no_airdata"] += 1
            return PortFrame(t_s, ok, None, None, math.nan)
        vab, cov, qbar = solved
        cp = dp / qbar
        coeffs = {name: m.predict(cp) for name, m in self.models.items()}
        return PortFrame(t_s, ok, vab, cov * (len(ok) / max(int(ok.sum()), 1)), qbar, coeffs)
