"""Port frames → what the filter fuses: port health, air data (FADS) and aerodynamic coefficients.

Everything here is measurement-side (no filter state), so one front end serves every mode of a run.

Port faults, per frame:

* missing or NaN;
* out of range: |Δp| at the transducer's full scale (a saturated reading is not a measurement);
* stuck: the same value, bit for bit, for :attr:`PortFrontEnd.stuck_frames` frames (a live transducer's
  noise never repeats exactly; a frozen driver or a blocked tube with a dead sensor does).

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
        self.counts = {"frames": 0, "nan": 0, "out_of_range": 0, "stuck": 0, "no_airdata": 0}

    def __deepcopy__(self, memo: dict[int, Any]) -> PortFrontEnd:
        """A branch of a run: its own health counters and warm start, the same (read-only) models."""
        out = copy.copy(self)
        out._last = None if self._last is None else self._last.copy()
        out._same = self._same.copy()
        out.counts = dict(self.counts)
        return out

    def health(self, dp_pa: F64Array) -> BoolArray:
        """Usable ports of this frame (updates the stuck-port counters)."""
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
        c = self.counts
        c["frames"] += 1
        c["nan"] += int((~finite).sum())
        c["out_of_range"] += int((finite & ~in_range).sum())
        c["stuck"] += int((in_range & stuck).sum())
        return np.asarray(in_range & ~stuck)

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
            ok = self.health(dp_pa)
        dp = np.where(ok, np.asarray(dp_pa, dtype=np.float64), np.nan)
        solved = self.air_data(dp, rho_kg_m3, omega_b, controls_rad)
        if solved is None:
            self.counts["no_airdata"] += 1
            return PortFrame(t_s, ok, None, None, math.nan)
        vab, cov, qbar = solved
        cp = dp / qbar
        coeffs = {name: m.predict(cp) for name, m in self.models.items()}
        return PortFrame(t_s, ok, vab, cov * (len(ok) / max(int(ok.sum()), 1)), qbar, coeffs)
