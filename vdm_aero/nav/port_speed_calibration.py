"""The ports' airspeed calibrated in flight against the pitot: a position-error table in the ports' α.

The FADS solve (:class:`~vdm_aero.nav.design_fit.PortPressureModel`) inverts a port model fitted to the design
data set, the user's simulation of the nominal airframe. The built aircraft is not that airframe: its ports sit
a little off their drawn positions, its skin and its propwash differ. On the harsh world's four as-built airframes
the ports' airspeed read up to 2.3 m/s high (one airframe, at every α) and up to 2.7 m/s low (another, at α above
2°), and the error repeated from flight to flight: in 1° bands of α the flights' medians lay within 0.1–1.3 m/s
of each other, median 0.5 (docs/navigation.md, "The ports' airspeed calibrated in flight"). A systematic error
of one airframe is what a flight calibration removes: flush air-data systems are calibrated against a reference
in flight (Whitmore et al., NASA TM-104241; Whitmore, Davis & Fife, NASA Dryden, 1995), as a static source's
position error is tabulated against α or the lift coefficient (Gracey, NASA RP-1046, 1980; FAA AC 23-8C).

The reference here is the pitot of the calibration flight (the same flight the correction net is trained on,
:func:`vdm_aero.calibrate.calibrate_model`): the ratio V_pitot / V_ports is fitted as a piecewise-linear
function of the ports' own α, with knots every :data:`KNOT_STEP_DEG` over the α the flight covered and a
second-difference penalty so that sparsely flown knots follow their neighbours; outside that range the ratio
is held at its edge value (an extrapolated slope would be a guess). At run time the ports' airspeed is
multiplied by the ratio at their α: the table uses nothing but the ports, so the ports stay a view of the airflow
independent of the pitot, which the air-data FDI needs, with the pitot's calibration instead of the design
model's error. The pitot's own error on that flight (its ratio and position errors) is inherited; the filter's
speed-scale state takes what remains common to both.

Only the airspeed is corrected. The q̄ that normalises Cp for the aero models stays the solve's own, the
normalisation the correction net was trained with (:func:`vdm_aero.calibrate.form_targets`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from vdm_aero._typing import F64Array
from vdm_aero.errors import ModelError

__all__ = ["KNOT_STEP_DEG", "MIN_AIRSPEED_M_S", "MIN_SAMPLES", "PortSpeedCalibration"]

KNOT_STEP_DEG: Final = 1.0  # the table's α spacing: the as-built errors change by ~1 m/s over 2° of α
MIN_AIRSPEED_M_S: Final = 10.0  # calibration samples: the pitot's and the ports' Δp well above their noise
MIN_SAMPLES: Final = 50  # of a calibration flight: a few seconds at 10 Hz is not a calibration
# the knots' second difference, 1σ: the ratio bends by at most ~0.02 per knot² on the harsh fleet; against a
# sample's scatter of ~0.03 (turbulence, lag between the two sensors) it weighs like (0.03/0.02)² samples
_SCATTER: Final = 0.03
_BEND: Final = 0.02
_RATIO_RANGE: Final = (0.7, 1.4)  # a ratio outside this is not a position error but a broken sensor or file


@dataclass(frozen=True)
class PortSpeedCalibration:
    """V_pitot / V_ports at ``alpha_knots_rad`` (piecewise linear, held beyond the ends); fitted with
    :meth:`fit`, applied with :meth:`ratio` / :meth:`correct`. ``rms_before_m_s`` / ``rms_after_m_s``: the
    calibration flight's ports-less-pitot airspeed spread before and after, over ``samples`` samples."""

    alpha_knots_rad: tuple[float, ...]
    ratio_at_knots: tuple[float, ...]
    samples: int
    rms_before_m_s: float
    rms_after_m_s: float

    @classmethod
    def fit(cls, alpha_rad: F64Array, v_ports_m_s: F64Array, v_pitot_m_s: F64Array) -> PortSpeedCalibration:
        """Fit the table on a calibration flight's samples: the ports' α [rad] and airspeed [m/s] from the FADS
        solve, and the pitot's airspeed [m/s] at the same times. Samples with either airspeed under
        :data:`MIN_AIRSPEED_M_S` or not finite are left out. Raises :class:`ValueError` with fewer than
        :data:`MIN_SAMPLES` left."""
        a, vp, vr = (np.asarray(x, dtype=np.float64).ravel() for x in (alpha_rad, v_ports_m_s, v_pitot_m_s))
        ok = np.isfinite(a) & np.isfinite(vp) & np.isfinite(vr) & (vp >= MIN_AIRSPEED_M_S) & (vr >= MIN_AIRSPEED_M_S)
        if int(ok.sum()) < MIN_SAMPLES:
            raise ValueError(f"{int(ok.sum())} samples with both airspeeds over {MIN_AIRSPEED_M_S:g} m/s "
                             f"(at least {MIN_SAMPLES})")  # fmt: skip
        a, vp, vr = a[ok], vp[ok], vr[ok]
        step = math.radians(KNOT_STEP_DEG)
        lo, hi = np.percentile(a, [0.5, 99.5])
        k0, k1 = math.floor(lo / step), math.ceil(hi / step)
        knots = np.arange(k0, max(k1, k0 + 1) + 1) * step
        basis = _hats(knots, a)
        n = len(knots)
        lhs = basis.T @ basis
        if n >= 3:
            d2 = np.diff(np.eye(n), 2, axis=0)
            lhs += (_SCATTER / _BEND) ** 2 * d2.T @ d2
        lhs += 1e-9 * len(a) * np.eye(n)  # a knot no sample reaches is held by its neighbours, not singular
        ratio = np.linalg.solve(lhs, basis.T @ (vr / vp))
        after = vp * (basis @ ratio) - vr
        out = cls(tuple(knots.tolist()), tuple(ratio.tolist()), len(a), float(np.sqrt(np.mean((vp - vr) ** 2))),
                  float(np.sqrt(np.mean(after**2))))  # fmt: skip
        out.check("the calibration flight")
        return out

    def ratio(self, alpha_rad: float) -> float:
        """V_pitot / V_ports at the ports' ``alpha_rad`` (the edge value beyond the calibrated α)."""
        return float(np.interp(alpha_rad, self.alpha_knots_rad, self.ratio_at_knots))

    def correct(self, v_ports_m_s: float, alpha_rad: float) -> float:
        """The ports' airspeed [m/s] at their ``alpha_rad``, calibrated."""
        return v_ports_m_s * self.ratio(alpha_rad)

    def covers(self, alpha_rad: float) -> bool:
        """Whether ``alpha_rad`` lies within the α the calibration flight covered."""
        return self.alpha_knots_rad[0] <= alpha_rad <= self.alpha_knots_rad[-1]

    @property
    def alpha_range_deg(self) -> tuple[float, float]:
        return math.degrees(self.alpha_knots_rad[0]), math.degrees(self.alpha_knots_rad[-1])

    def check(self, where: str) -> None:
        """Raise :class:`ModelError` naming ``where`` unless the table is usable: increasing knots, finite
        ratios inside a position error's range."""
        k, r = np.asarray(self.alpha_knots_rad, float), np.asarray(self.ratio_at_knots, float)
        if len(k) < 2 or len(k) != len(r) or not np.all(np.isfinite(k)) or not np.all(np.diff(k) > 0.0):
            raise ModelError(f"{where}: port_speed: alpha_knots_deg must be ≥ 2 increasing numbers, one per ratio")
        if not np.all(np.isfinite(r)) or r.min() < _RATIO_RANGE[0] or r.max() > _RATIO_RANGE[1]:
            raise ModelError(f"{where}: port_speed: a ratio outside {_RATIO_RANGE[0]}–{_RATIO_RANGE[1]} "
                             f"({r.min():.3g}–{r.max():.3g}) is a broken sensor, not a position error")  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """For model.yaml (degrees, rounded: a table a user can read)."""
        return {"alpha_knots_deg": [round(math.degrees(x), 6) for x in self.alpha_knots_rad],
                "ratio": [round(x, 6) for x in self.ratio_at_knots], "samples": self.samples,
                "rms_before_m_s": round(self.rms_before_m_s, 4), "rms_after_m_s": round(self.rms_after_m_s, 4),
                "reference": "pitot"}  # fmt: skip

    @classmethod
    def from_dict(cls, d: Any, where: str) -> PortSpeedCalibration:
        """From :meth:`to_dict`'s mapping; :class:`ModelError` naming ``where`` and the key when malformed."""
        if not isinstance(d, dict):
            raise ModelError(f"{where}: port_speed must be a mapping")
        try:
            out = cls(tuple(math.radians(float(x)) for x in d["alpha_knots_deg"]),
                      tuple(float(x) for x in d["ratio"]), int(d.get("samples", 0)),
                      float(d.get("rms_before_m_s", math.nan)), float(d.get("rms_after_m_s", math.nan)))  # fmt: skip
        except KeyError as e:
            raise ModelError(f"{where}: port_speed: missing key {e.args[0]}") from None
        except (TypeError, ValueError) as e:
            raise ModelError(f"{where}: port_speed: {e}") from None
        out.check(where)
        return out


def _hats(knots: F64Array, x: F64Array) -> F64Array:
    """(len(x), len(knots)) piecewise-linear interpolation weights, held at the end knots."""
    xc = np.clip(x, knots[0], knots[-1])
    i = np.clip(np.searchsorted(knots, xc, side="right") - 1, 0, len(knots) - 2)
    w = (xc - knots[i]) / (knots[i + 1] - knots[i])
    out = np.zeros((len(x), len(knots)))
    rows = np.arange(len(x))
    out[rows, i] = 1.0 - w
    out[rows, i + 1] = w
    return out
