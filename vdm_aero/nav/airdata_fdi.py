"""Air-data fault detection and isolation (FDI) for the product mode ``vdm``.

The aircraft has several views of the airflow: the pitot (airspeed), the ports' air data (V, α, β from the
FADS solve), the ports' force model (the body force the IMU must feel at that airflow) and the INS with the
wind (v − w). Each fused source is checked against the state the others keep, in the spirit of a χ²
innovation test (Brumback & Srinath's residual χ² test; avionics' analytic redundancy of three air-data
computers): the normalised innovation squared of every measurement, NIS/dim, is smoothed with a time
constant of :data:`TAU_S`; a healthy, consistent source stays near 1.

* **Detect**: a source whose smoothed NIS/dim passes :data:`DETECT` disagrees with the state. Gated-out
  measurements count: a pitot that suddenly reads zero is rejected by the gate every time and seen at once.
* **Sensor or wind?** The pitot and the ports' airspeed are also compared with each other directly (their
  difference less its healthy line in α, below, over its σ, smoothed alike: the *pair*), which no state
  estimate enters. When the pair disagrees, one of the two is wrong: the one further from the state is
  excluded. When the pair agrees but both disagree with the state, the state is wrong, not a sensor: the
  wind has changed (a shear, a gradient crossed in a climb), and the filter relearns it (``wind`` event)
  instead of excluding anything.
  Without the pair (no pitot, or no port air data) the worst source is excluded.
* **A pitot that reads low, slowly**: icing, a blocked ram inlet, water or a leak in the line all lower the
  pitot's Δp, and grow from nothing. The pair's level above is scaled by the σ the filter assumes (2.4–2.8 m/s,
  conservative) and needs ~4.5 m/s; a pitot icing over tens of seconds under-reads by only 0.3–5 m/s 10 s in.
  So the pair also runs a one-sided CUSUM (Page 1954; Basseville & Nikiforov 1993, §2.2) on the pitot's
  under-read against the ports, in m/s: its healthy difference (each airframe's pitot and ports see sideslip,
  propwash and load differently: −1.5 … +0.7 m/s at cruise on the harsh fleet, the ports' airspeed error
  grows with α and moves with the elevator) learnt as a plane in the ports' α and the elevator's deflection over
  :data:`DRIFT_BIAS_TAU_S` while the pair agrees, the
  residual smoothed over :data:`TAU_S`, the excess over :data:`DRIFT_K_M_S`
  accumulated until it passes :data:`DRIFT_H_M`. The line belongs to the ports' solve from one set of usable
  ports: another set (ports left out) solves another airspeed, so a new set starts a new line
  (:data:`DRIFT_RELEARN_S`). Its alarm excludes the pitot: the ports' airspeed is a
  least-squares solve over twelve ports whose own residuals and per-port health the front end checks, the
  pitot has no check of its own. It is one-sided because the pitot's failures read low; the healthy
  disagreement's excursions in manoeuvres go both ways (docs/navigation.md has the figures).
* **Where the ports' airspeed is a guess**: with the ports' airspeed calibrated in flight against the pitot
  (:mod:`vdm_aero.nav.port_speed_calibration`) the pair's healthy difference is nearly flat, but only over the
  α the calibration flight reached; beyond it (a pull-up past that α) the ports' airspeed is the design model's,
  off by metres per second, and neither the pair's level nor the under-read test's sum moves there (``judge``).
* **Isolate**: one source at a time is excluded (never fused again until re-admitted); the others keep the
  state honest, and its innovations are still computed against that state.
* **Re-admit**: an excluded source whose smoothed NIS/dim stays under :data:`READMIT` for
  :data:`READMIT_HOLD_S` agrees again and is fused again (the pitot also only once the under-read test has
  cleared).

What this cannot do: tell a source that is wrong from a state that is wrong when only one source is left;
see a pitot under-read smaller than the healthy pair's own disagreement (~1 m/s); or, without the ports'
airspeed, see a fault that grows slower than the state follows it (a slowly icing pitot pulls a live wind
with it). Nor tell a pitot that starts to read low from a change of the flight the plane in α and the elevator
does not explain. A payload dropped moves the CG, so the elevator trims anew at the same α, and the ports read
0.2–0.9 m/s higher there; with a line in α alone that excluded a healthy pitot on 1 of 20 flights (docs/navigation.md,
"A payload drop moves the elevator, not α"). Manoeuvring flight did on 3 of 20 until the ports' airspeed was
calibrated in flight, and on none of 40 since ("The ports' airspeed calibrated in flight").
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from vdm_aero._typing import F64Array

__all__ = [
    "DETECT",
    "DRIFT_BIAS_TAU_S",
    "DRIFT_ELEVATOR_RANGE_SIGMAS",
    "DRIFT_ELEVATOR_SLOPE_PRIOR_M_S_PER_RAD",
    "DRIFT_H_M",
    "DRIFT_K_M_S",
    "DRIFT_MIN_AIRSPEED_M_S",
    "DRIFT_RELEARN_S",
    "DRIFT_SLOPE_PRIOR_M_S_PER_RAD",
    "DRIFT_WARMUP_S",
    "PAIR_DETECT",
    "PAIR_MAX_AGE_S",
    "READMIT",
    "READMIT_HOLD_S",
    "RELEARN_AFTER_S",
    "SOURCES",
    "TAU_S",
    "WIND_CHANGE_GUST_SIGMAS",
    "WIND_RELEARN_S",
    "AirDataFdi",
    "FdiEvent",
    "wind_change_threshold_m_s",
]

SOURCES: Final = ("pitot", "ports", "force")
TAU_S: Final = 2.0  # smoothing of NIS/dim: a few aiding updates at 10 Hz, short against a 10 s detection bar
# Thresholds on the smoothed NIS/dim, set from healthy flights, not from χ² tables: the air-data noise the filter
# assumes is conservative, so healthy levels sit near 0.1, not 1. On the harsh world's survey (3 seeds × 8 min,
# turbulence, manoeuvres, the whole outage) the highest healthy levels were: pitot 1.0, ports 0.55, force 3.4,
# pair 1.2 (docs/navigation.md). DETECT and PAIR_DETECT keep a margin of 1.8–2.5× over those.
DETECT: Final = 6.0
PAIR_DETECT: Final = 3.0
READMIT: Final = 1.0
READMIT_HOLD_S: Final = 10.0
MIN_FUSED: Final = 1  # never exclude the last fused source: with nothing left to compare, a fault is unisolable
PAIR_MAX_AGE_S: Final = 0.5  # the pair's two readings at most this far apart
WIND_RELEARN_S: Final = 30.0  # after a wind event the wind is learnt for this long; no second event meanwhile
WIND_LEVEL: Final = 3.0  # both airspeeds this far from the state while agreeing with each other: the wind moved
SETTLE_S: Final = 5.0  # after an exclusion the state follows the others again: no second exclusion meanwhile
# The pitot's under-read test (module docstring). Set on the harsh world's healthy flights (20 surveys and 20
# returns home through a wind gradient, 5.9 h, 2026-11-27): the pitot less the ports, less its learnt bias and
# smoothed over TAU_S, never read lower than −1.0 m/s, and with K = 0.75 m/s the CUSUM never passed 0.40 m·s/s;
# H keeps a 2× margin. A step of under-read of 1 m/s is then flagged in ~10 s, one of 2 m/s in ~3 s.
DRIFT_K_M_S: Final = 0.75
DRIFT_H_M: Final = 0.8  # [m/s · s]
DRIFT_BIAS_TAU_S: Final = 60.0  # the pair's healthy bias: long against a manoeuvre, short against a flight
DRIFT_WARMUP_S: Final = 120.0  # of airborne pair readings before the bias is trusted (two bias time constants)
DRIFT_MIN_AIRSPEED_M_S: Final = 8.0  # the pitot's useful range (the filter fuses it from there)
# A new set of usable ports: its line is a running mean of this long before the test judges again (ten smoothing
# time constants: the mean of ~200 readings); a set must last RELEARN_AFTER_S to count (one lost frame does not)
DRIFT_RELEARN_S: Final = 20.0
RELEARN_AFTER_S: Final = 1.0
# the healthy difference's slope in the ports' α: a weak prior of none (3.5 m/s per degree, 1σ), so the line is
# defined before α has varied; set offline on 47 recorded harsh flights (docs/navigation.md), where 4× weaker
# or stronger changed nothing
DRIFT_SLOPE_PRIOR_M_S_PER_RAD: Final = 3.5 * 180.0 / math.pi
# ... and in the elevator's deflection, by the same convention (300 m/s per rad). Both priors enter the sums
# normalised to weights of one, so each weighs like a spread of its variable: 1/300 rad (0.19°) of the elevator.
# On the harsh fleet's 20 payload-drop flights the elevator's spread before the drop was 0.3–1.25° (1σ), which
# keeps 72–98 % of the slope fitted there, −34 … +12 m/s per rad, the same within ±5 on each airframe's five
# flights (docs/navigation.md, "A payload drop moves the elevator, not α")
DRIFT_ELEVATOR_SLOPE_PRIOR_M_S_PER_RAD: Final = 300.0
# The plane is judged only within the elevator it learnt over: its mean ± this many of its spread (the spread at
# least the prior's). A slope learnt in cruise (elevator −5 … 0°) said the pitot should read 0.5–1 m/s over the
# ports in a slow pull-up at −8 … −16°, where the ports read 2 m/s over it: a healthy pitot excluded (manoeuvring
# seed 13, 2026-11-30). Beyond the spread the plane is a guess, as the ports' airspeed table is beyond its α
DRIFT_ELEVATOR_RANGE_SIGMAS: Final = 3.0


@dataclass(frozen=True)
class FdiEvent:
    """A change of a source's status: ``excluded`` or ``readmitted`` at ``t_s`` with its smoothed NIS/dim."""

    t_s: float
    source: str
    what: str
    nis_per_dim: float


@dataclass
class _Source:
    level: float = 1.0
    last_t_s: float = -math.inf
    excluded: bool = False
    agree_since_s: float | None = None


@dataclass
class PitotUnderRead:
    """The one-sided CUSUM on the pitot's under-read against the ports (module docstring). Feed the pitot's
    airspeed less the ports' with :meth:`observe`; :attr:`alarm` says the pitot reads low.

    The healthy difference is a plane in the ports' α and the elevator's deflection, not one bias: the ports'
    airspeed error depends on the flight condition (on the harsh fleet up to ~1.9 m/s low at 13 m/s and α ≈ 4°,
    ~0.1 m/s at 22 m/s), and a bias learnt in one condition took a speed change for a pitot starting to read
    low; a line in α alone took a payload dropped (the elevator trimmed anew at the same α) for one. The plane
    is a least-squares fit with exponential forgetting (the bias's time constant; with α and the elevator
    constant it is exactly that running mean) and a weak prior of a flat plane, so it is defined before either
    has varied. Without servo outputs the elevator stays 0 and the plane is the line in α."""

    k_m_s: float = DRIFT_K_M_S
    h_m: float = DRIFT_H_M
    bias_tau_s: float = DRIFT_BIAS_TAU_S
    smooth_tau_s: float = TAU_S
    warmup_s: float = DRIFT_WARMUP_S
    slope_prior_m_s_per_rad: float = DRIFT_SLOPE_PRIOR_M_S_PER_RAD
    elevator_slope_prior_m_s_per_rad: float = DRIFT_ELEVATOR_SLOPE_PRIOR_M_S_PER_RAD
    residual_m_s: float = 0.0  # smoothed, less the bias; negative: the pitot reads low
    cusum_m: float = 0.0
    first_t_s: float | None = None
    last_t_s: float | None = None
    alpha_rad: float = 0.0  # the latest α the line was evaluated at
    elevator_rad: float = 0.0  # the latest elevator deflection (trailing edge down positive)
    # the forgetting least squares in (1, α, δe): normal matrix and right-hand side, the prior on the slopes apart
    _ata: F64Array = field(default_factory=lambda: np.zeros((3, 3)))
    _atb: F64Array = field(default_factory=lambda: np.zeros(3))
    # its solution (intercept, slopes), solved again only after the sums move: the pair and the under-read test
    # both read the plane at every pitot sample, and a 3 × 3 solve costs as much as a measurement's Jacobian
    _line: tuple[float, float, float] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def alarm(self) -> bool:
        return self.cusum_m > self.h_m

    def bias_at(self, alpha_rad: float, elevator_rad: float = math.nan) -> float:
        """The healthy difference [m/s] at ``alpha_rad`` and ``elevator_rad`` (NaN: the latest); 0 before the
        first observation."""
        if self.first_t_s is None:
            return 0.0
        if self._line is None:
            prior = np.diag([0.0, self.slope_prior_m_s_per_rad**-2, self.elevator_slope_prior_m_s_per_rad**-2])
            intercept, slope, slope_e = np.linalg.solve(self._ata + prior, self._atb)
            self._line = (float(intercept), float(slope), float(slope_e))
        intercept, slope, slope_e = self._line
        elevator = elevator_rad if math.isfinite(elevator_rad) else self.elevator_rad
        return intercept + slope * alpha_rad + slope_e * elevator

    @property
    def bias_m_s(self) -> float:
        """The healthy difference [m/s] at the latest α and elevator."""
        return self.bias_at(self.alpha_rad)

    def observe(self, t_s: float, difference_m_s: float, *, alpha_rad: float = math.nan,
                elevator_rad: float = math.nan, learn: bool = True, judge: bool = True) -> None:  # fmt: skip
        """The pitot's airspeed less the ports' [m/s] at ``t_s``, with the ports' ``alpha_rad`` and the
        elevator's ``elevator_rad`` (NaN: as before); ``learn``: both are fused, so a healthy difference may
        move the plane; ``judge``: the ports' airspeed is calibrated at this α, so an under-read may add to the
        sum. Where it is not, or the elevator lies outside what the plane learnt over (:meth:`covers`), the
        smoothed residual and the sum are held: a sample not judged must not carry into the next ones that are."""
        if not math.isfinite(difference_m_s):
            return
        if math.isfinite(alpha_rad):
            self.alpha_rad = alpha_rad
        if math.isfinite(elevator_rad):
            self.elevator_rad = elevator_rad
        x = np.array([1.0, self.alpha_rad, self.elevator_rad])
        if self.first_t_s is None or self.last_t_s is None:
            self.first_t_s = self.last_t_s = t_s
            self._ata, self._atb, self._line = np.outer(x, x), difference_m_s * x, None
            self.residual_m_s, self.cusum_m = 0.0, 0.0
            return
        dt = max(t_s - self.last_t_s, 0.0)
        self.last_t_s = t_s
        age = t_s - self.first_t_s
        judge = judge and self.covers(self.elevator_rad)
        if judge:
            a = math.exp(-dt / self.smooth_tau_s)
            self.residual_m_s = a * self.residual_m_s + (1.0 - a) * (difference_m_s - self.bias_m_s)
        if age < self.warmup_s:
            self.cusum_m = 0.0  # the line is still a short average
        else:
            # capped: once the pitot reads true again the alarm clears within ~h/k, not after as long as it lasted
            grown = min(max(0.0, self.cusum_m + (-self.residual_m_s - self.k_m_s) * dt), 2.0 * self.h_m)
            self.cusum_m = grown if judge else min(grown, self.cusum_m)
        if learn and self.cusum_m < 0.25 * self.h_m:  # a growing under-read must not teach the line
            b = math.exp(-dt / min(self.bias_tau_s, max(age, dt)))  # a running mean until the time constant
            self._ata = b * self._ata + (1.0 - b) * np.outer(x, x)
            self._atb = b * self._atb + (1.0 - b) * difference_m_s * x
            self._line = None

    def covers(self, elevator_rad: float) -> bool:
        """Whether ``elevator_rad`` lies within :data:`DRIFT_ELEVATOR_RANGE_SIGMAS` of the elevator the plane
        learnt over (its forgetting mean and spread; True before the first observation)."""
        if self.first_t_s is None:
            return True
        w = self._ata[0, 0]
        mean = self._ata[0, 2] / w
        spread = math.sqrt(max(self._ata[2, 2] / w - mean * mean, 0.0))
        return abs(elevator_rad - mean) <= DRIFT_ELEVATOR_RANGE_SIGMAS * max(
            spread, 1.0 / self.elevator_slope_prior_m_s_per_rad
        )

    def restart(self) -> None:
        """After the pitot's exclusion: the sum starts again (the bias is kept: it is the healthy pair's)."""
        self.cusum_m = 0.0

    def relearn(self) -> None:
        """Another set of ports: a new line from the next reading, judged after :data:`DRIFT_RELEARN_S`."""
        self.first_t_s = self.last_t_s = None
        self.warmup_s = min(self.warmup_s, DRIFT_RELEARN_S)


@dataclass
class AirDataFdi:
    """The monitor of :data:`SOURCES` (module docstring). Feed every innovation with :meth:`observe`; ask
    :meth:`fused` before fusing; :attr:`events` is the history."""

    detect: float = DETECT
    pair_detect: float = PAIR_DETECT
    readmit: float = READMIT
    readmit_hold_s: float = READMIT_HOLD_S
    tau_s: float = TAU_S
    sources: dict[str, _Source] = field(default_factory=lambda: {s: _Source() for s in SOURCES})
    pair: _Source = field(default_factory=_Source)
    under_read: PitotUnderRead = field(default_factory=PitotUnderRead)
    events: list[FdiEvent] = field(default_factory=list)
    last_wind_event_s: float = -math.inf
    last_exclusion_s: float = -math.inf
    _line_port_set: bytes | None = None  # the ports' set the under-read line was learnt on
    _port_set_since_s: float | None = None  # another set's first reading

    def fused(self, source: str) -> bool:
        """Whether ``source`` may be fused now."""
        return not self.sources[source].excluded

    def excluded(self) -> list[str]:
        return [s for s, st in self.sources.items() if st.excluded]

    def level(self, source: str) -> float:
        """The smoothed NIS/dim of ``source``."""
        return self.sources[source].level

    def _smooth(self, st: _Source, t_s: float, x: float) -> None:
        x = min(x, 1e4) if math.isfinite(x) else 1e4  # one wild sample cannot saturate the level
        dt = t_s - st.last_t_s if math.isfinite(st.last_t_s) else self.tau_s
        a = math.exp(-max(dt, 0.0) / self.tau_s)
        st.level = a * st.level + (1.0 - a) * x
        st.last_t_s = t_s

    def observe_pair(self, t_s: float, difference_m_s: float, sigma_m_s: float,
                     airspeed_m_s: float | None = None, alpha_rad: float = math.nan,
                     port_set: bytes | None = None, *, elevator_rad: float = math.nan,
                     judge: bool = True) -> None:  # fmt: skip
        """The pitot's airspeed less the ports' [m/s] at ``t_s``, with the σ of that difference; with the
        pitot's ``airspeed_m_s`` in its useful range, also the under-read test (at the ports' ``alpha_rad`` and
        the elevator's ``elevator_rad``),
        whose line belongs to the ports' solve from ``port_set`` (any hashable mark of the usable ports). The
        pair's level judges the difference less the under-read test's healthy line at this α: in a slow pull-up
        the ports' airspeed reads 2–6 m/s under a healthy pitot on the harsh fleet, the line knows it, and the
        raw difference over σ took it for a fault of one of the two (docs/navigation.md). ``judge``: False where
        the ports' α lies outside the α their airspeed was calibrated over in flight
        (:mod:`vdm_aero.nav.port_speed_calibration`): the pair's level and the under-read test's sum are then
        held (the test still learns its line), since there the ports' airspeed is the design model's guess
        with the table's edge value, not a measurement to judge the pitot by (on the harsh fleet 4–5 m/s low
        at α 13° in a pull-up, where the calibration flight reached 7°). Held too where the elevator lies
        outside what the line learnt over (:meth:`PitotUnderRead.covers`)."""
        ur = self.under_read
        judge = judge and (not math.isfinite(elevator_rad) or ur.covers(elevator_rad))
        if judge:
            line = ur.bias_at(alpha_rad if math.isfinite(alpha_rad) else ur.alpha_rad, elevator_rad)
            self._smooth(self.pair, t_s, ((difference_m_s - line) / sigma_m_s) ** 2)
        else:  # the pair is still known (both airspeeds are there), its level is held
            self.pair.last_t_s = t_s
        if airspeed_m_s is None or airspeed_m_s < DRIFT_MIN_AIRSPEED_M_S:
            return
        both = self.fused("pitot") and self.fused("ports")
        if port_set is not None and port_set != self._line_port_set:
            # another set of ports solves another airspeed: on the harsh fleet two ports left out moved it by up
            # to 3 m/s, which the line learnt on the old set takes for a pitot reading low. A set that lasts
            # RELEARN_AFTER_S starts a new line while both are fused; an excluded pitot is judged on the old line
            # as before (a new line would learn its fault), and the new one starts once it is back
            if self._line_port_set is None:
                self._line_port_set = port_set
            else:
                self._port_set_since_s = t_s if self._port_set_since_s is None else self._port_set_since_s
                if t_s - self._port_set_since_s < RELEARN_AFTER_S:
                    return  # neither learnt nor judged on a passing set
                if both:
                    self.under_read.relearn()
                    self._line_port_set, self._port_set_since_s = port_set, None
        else:
            self._port_set_since_s = None
        self.under_read.observe(
            t_s, difference_m_s, alpha_rad=alpha_rad, elevator_rad=elevator_rad, learn=both, judge=judge
        )

    def _pair_known(self, t_s: float) -> bool:
        both = self.fused("pitot") and self.fused("ports")
        return both and t_s - self.pair.last_t_s <= max(PAIR_MAX_AGE_S, 2.0 * self.tau_s)

    def observe(self, source: str, t_s: float, nis: float, dim: int) -> FdiEvent | None:
        """One innovation of ``source`` at ``t_s`` (its NIS over ``dim`` components, fused or not); returns the
        status change it caused, if any: an exclusion, a re-admission, or a ``wind`` event (the state's wind
        is what disagrees: relearn it)."""
        st = self.sources[source]
        self._smooth(st, t_s, nis / max(dim, 1))
        if st.excluded:
            if st.level < self.readmit and not (source == "pitot" and self.under_read.alarm):
                st.agree_since_s = t_s if st.agree_since_s is None else st.agree_since_s
                if t_s - st.agree_since_s >= self.readmit_hold_s:
                    st.excluded, st.agree_since_s = False, None
                    return self._event(t_s, source, "readmitted")
            else:
                st.agree_since_s = None
            return None
        if t_s - self.last_exclusion_s < SETTLE_S:
            return None  # the state still settling after the last exclusion
        if source == "pitot" and self.under_read.alarm and self._pair_known(t_s):
            self.under_read.restart()
            st.excluded, st.agree_since_s = True, None
            return self._event(t_s, source, "excluded")
        if self._pair_known(t_s) and source in ("pitot", "ports"):
            other = "ports" if source == "pitot" else "pitot"
            if self.pair.level > self.pair_detect:  # the airspeeds disagree: the one further from the state is wrong
                if self.sources[other].level > st.level:
                    return None
                st.excluded, st.agree_since_s = True, None
                return self._event(t_s, source, "excluded")
            if self.pair.level < self.readmit and min(st.level, self.level(other)) > WIND_LEVEL:
                # both airspeeds agree with each other, not with the state: the wind has changed
                if t_s - self.last_wind_event_s < WIND_RELEARN_S:
                    return None
                self.last_wind_event_s = t_s
                return self._event(t_s, "wind", "changed")
            return None
        if st.level <= self.detect:
            return None
        if self._pair_known(t_s):  # the force model off while the airspeeds agree with the state and each other
            if max(self.level("pitot"), self.level("ports")) > self.readmit:
                return None
            st.excluded, st.agree_since_s = True, None
            return self._event(t_s, source, "excluded")
        fused = [s for s, o in self.sources.items() if not o.excluded and math.isfinite(o.last_t_s)]
        if len(fused) <= MIN_FUSED:
            return None
        worst = max(fused, key=lambda s: self.sources[s].level)
        if worst != source:
            return None  # the worse one goes first; this one is judged again once that one is out
        st.excluded, st.agree_since_s = True, None
        return self._event(t_s, source, "excluded")

    def wind_changed(self, t_s: float, change_m_s: float) -> FdiEvent | None:
        """A wind change of ``change_m_s`` seen by :class:`WindChangeDetector`: a ``wind`` event, at most one
        per :data:`WIND_RELEARN_S`."""
        if t_s - self.last_wind_event_s < WIND_RELEARN_S:
            return None
        self.last_wind_event_s = t_s
        e = FdiEvent(t_s, "wind", "changed", change_m_s)
        self.events.append(e)
        return e

    def _event(self, t_s: float, source: str, what: str) -> FdiEvent:
        if what == "excluded":
            self.last_exclusion_s = t_s
        level = self.sources[source].level if source in self.sources else self.pair.level
        e = FdiEvent(t_s, source, what, level)
        self.events.append(e)
        return e


WIND_CHANGE_WINDOW_S: Final = 10.0
# |Δw| over the window that is a wind change, not turbulence or the INS's own error: on the harsh world's survey
# (turbulence, 180° turns) healthy flight reached 5.5–7.5 m/s; the wind-shear scenario's change (+4 m/s and
# 60° over 10 s, |Δw| ≈ 10.6 m/s) read 11.3 m/s (docs/navigation.md). A small margin: a shear under ~8 m/s in
# 10 s is not caught, and an alarm in healthy flight costs 30 s of a live wind.
WIND_CHANGE_M_S: Final = 8.0
# ... and in turbulence, this many of the gust σ the filter measures in flight (per horizontal axis): the
# turbulence itself changes the wind by that much in 10 s, and a change seen in a gust relearns the wind from
# the gust and holds it for the rest of the outage. On 8 of the harsh world's surveys (2026-11-27; σ measured
# 0.95–2.0 m/s) healthy flight's 10-s change reached 4.1–5.5 σ in moderate turbulence, and under the 8 m/s
# threshold alone 3–6 of 20 surveys had a false wind event (those flights ended 1.5–3× worse,
# docs/navigation.md); on 8 wind-shear flights the shear's change read 4.0–10.8 σ. A 10 m/s shear in 10 s within
# moderate turbulence is then not always told from the turbulence's own changes: 2 of those 8 go unseen. The
# flights are the benchmark's own seeds: its figures with this threshold are in-sample.
WIND_CHANGE_GUST_SIGMAS: Final = 6.0
AIR_SMOOTH_S: Final = 1.0  # the ports' air velocity smoothed over this (their noise, single gusts)


def wind_change_threshold_m_s(gust_sigma_m_s: F64Array | Sequence[float]) -> float:
    """The |Δw| over :data:`WIND_CHANGE_WINDOW_S` [m/s] that is a wind change, for the gust σ (N, E, D) [m/s]
    measured in flight: :data:`WIND_CHANGE_M_S`, or :data:`WIND_CHANGE_GUST_SIGMAS` of the horizontal σ."""
    sigma_h = math.sqrt(0.5 * (float(gust_sigma_m_s[0]) ** 2 + float(gust_sigma_m_s[1]) ** 2))
    return max(WIND_CHANGE_M_S, WIND_CHANGE_GUST_SIGMAS * sigma_h)


@dataclass
class WindChangeDetector:
    """A wind change the held wind misses, from the accelerometers against the air data: over the last
    :data:`WIND_CHANGE_WINDOW_S`, the INS's own velocity change (the IMU increments rotated to NED, no
    measurement in it) less the change of the air velocity the ports measure (rotated to NED alike) is the
    wind's change; an aircraft flying through a shear feels it in its airspeed, its ground velocity follows
    only through the airframe's dynamics. Both are smoothed alike (the same lag: in a turn the velocity turns
    at several m/s²).

    It also keeps what a free INS started at the window's start would say now (:meth:`ins_window`): until a
    change is seen, the air data with the old wind have pulled the filter's velocity away from the truth by
    the change itself, and the INS alone, over a few seconds, has not drifted."""

    window_s: float = WIND_CHANGE_WINDOW_S
    _cum: tuple[float, float] = (0.0, 0.0)
    _cum_p: tuple[float, float] = (0.0, 0.0)  # ∫ of the INS's velocity change [m]
    _t: list[float] = field(default_factory=list)
    _v: list[tuple[float, float, float, float]] = field(default_factory=list)  # smoothed air N, E and INS N, E
    # raw per sample: INS velocity change N, E, its integral N, E, and the filter's position N, E and velocity N, E
    _pose: list[tuple[float, ...]] = field(default_factory=list)
    _last_t_s: float = -math.inf
    # the IMU gaps the filter bridged in the last window: (t [s], the velocity variance the bridge added [m²/s²])
    _gaps: list[tuple[float, float]] = field(default_factory=list)
    _anchor: tuple[float, tuple[float, ...], tuple[float, ...]] | None = None  # (t [s], pose, smoothed) at the start

    def ins_step(self, t_s: float, dv_n: float, dv_e: float, dt_s: float = 0.0) -> None:
        """One IMU step's velocity change, north and east [m/s] (gravity and the bias estimate applied), over
        ``dt_s`` [s]."""
        (vn, ve), (pn, pe) = self._cum, self._cum_p
        self._cum = (vn + dv_n, ve + dv_e)
        self._cum_p = (pn + (vn + 0.5 * dv_n) * dt_s, pe + (ve + 0.5 * dv_e) * dt_s)  # trapezoid

    def air(
        self,
        t_s: float,
        v_air_n: float,
        v_air_e: float,
        p_ne_m: tuple[float, float] = (math.nan, math.nan),
        v_ne_m_s: tuple[float, float] = (math.nan, math.nan),
    ) -> float | None:
        """The ports' air velocity, north and east [m/s], at ``t_s`` (with the filter's horizontal position [m]
        and velocity [m/s] then); the horizontal wind change over the window [m/s], once the window is full."""
        dt = t_s - self._last_t_s
        now = (v_air_n, v_air_e, *self._cum)
        if self._v and dt < 5.0:
            a = math.exp(-dt / AIR_SMOOTH_S)
            now = tuple(a * p + (1.0 - a) * c for p, c in zip(self._v[-1], now, strict=True))  # type: ignore[assignment]
        else:
            self._t.clear()
            self._v.clear()
            self._pose.clear()
        self._last_t_s = t_s
        self._t.append(t_s)
        self._v.append(now)
        self._pose.append((*self._cum, *self._cum_p, *p_ne_m, *v_ne_m_s))
        k = 0
        while k < len(self._t) and self._t[k] < t_s - self.window_s - 2.0:
            k += 1
        if k:
            del self._t[:k], self._v[:k], self._pose[:k]
        if self._t[0] > t_s - self.window_s + 0.5:
            return None
        old = self._v[_index_at(self._t, t_s - self.window_s)]
        d_air = (now[0] - old[0], now[1] - old[1])
        d_ins = (now[2] - old[2], now[3] - old[3])
        return math.hypot(d_ins[0] - d_air[0], d_ins[1] - d_air[1])

    def gap(self, t_s: float, velocity_var_m2_s2: float) -> None:
        """An IMU gap ending at ``t_s`` [s] that the filter bridged or coasted through, adding
        ``velocity_var_m2_s2`` per axis to its velocity: the INS's velocity change over the window holds that
        guess (:meth:`gap_sigma_m_s`)."""
        self._gaps.append((t_s, velocity_var_m2_s2))
        while self._gaps and self._gaps[0][0] < t_s - self.window_s:
            del self._gaps[0]

    def gap_sigma_m_s(self, t_s: float) -> float:
        """The σ per axis [m/s] the gaps bridged in the window before ``t_s`` add to the INS's velocity change
        there: a lossy link's holes in a turn read as a wind change unless the threshold carries them."""
        return math.sqrt(sum(v for t, v in self._gaps if t >= t_s - self.window_s))

    def anchor(self, at_s: float | None = None) -> None:
        """Hold the pose at the window's start (before the change just seen), or at the sample nearest ``at_s``
        [s], as the free INS's start, until :meth:`release`."""
        if self._t:
            k = _index_at(self._t, self._t[-1] - self.window_s if at_s is None else at_s)
            self._anchor = (self._t[k], self._pose[k], self._v[k])

    def release(self) -> None:
        self._anchor = None

    def ins_turned(self) -> tuple[float, float] | None:
        """Since the anchor: the size of the INS's horizontal velocity change [m/s] and of its integral [m]. A
        heading error δψ turns both, so the free INS is off by δψ times each: in a 160° turn (a 37 m/s change
        in 11 s) a 3° heading error is 2 m/s and tens of metres, beside which the tilt's share is small."""
        if self._anchor is None or not self._pose:
            return None
        t0, a, _ = self._anchor
        b = self._pose[-1]
        tau = self._t[-1] - t0
        return math.hypot(b[0] - a[0], b[1] - a[1]), math.hypot(b[2] - a[2] - a[0] * tau, b[3] - a[3] - a[1] * tau)

    @property
    def anchored_s(self) -> float | None:
        """How long ago [s] the anchor's pose was (None without an anchor)."""
        return None if self._anchor is None or not self._t else self._t[-1] - self._anchor[0]

    def change_since_anchor(self) -> float | None:
        """|Δw| from the anchor to now [m/s] (as :meth:`air` computes it): a step in the wind stays, a gust
        goes back."""
        if self._anchor is None or not self._v:
            return None
        old, now = self._anchor[2], self._v[-1]
        return math.hypot(now[2] - old[2] - (now[0] - old[0]), now[3] - old[3] - (now[1] - old[1]))

    def recent_change(self, span_s: float = 2.0) -> float | None:
        """|Δw| over the last ``span_s`` [m/s] (as :meth:`air` computes it over the window): a change still
        going on, or over."""
        if not self._t or self._t[0] > self._t[-1] - span_s + 0.25:
            return None
        old, now = self._v[_index_at(self._t, self._t[-1] - span_s)], self._v[-1]
        return math.hypot(now[2] - old[2] - (now[0] - old[0]), now[3] - old[3] - (now[1] - old[1]))

    def ins_window(self, t_s: float) -> tuple[tuple[float, float], tuple[float, float], float] | None:
        """A free INS from the filter's pose at the anchor (else at the window's start), now: (position N, E [m],
        velocity N, E [m/s], its length [s]); None before half a window of samples, or when the last sample is
        not from ``t_s`` (within 0.5 s: the detector is fed only while the ports' air data are fused)."""
        if not self._t or t_s - self._t[-1] > 0.5:
            return None
        if self._anchor is not None:
            t0, a, _ = self._anchor
        else:
            k = _index_at(self._t, self._t[-1] - self.window_s)
            t0, a = self._t[k], self._pose[k]
        tau = self._t[-1] - t0
        b = self._pose[-1]
        if tau < 0.5 * self.window_s or not all(math.isfinite(v) for v in a[4:]):
            return None
        v = (a[6] + b[0] - a[0], a[7] + b[1] - a[1])
        p = (a[4] + (a[6] - a[0]) * tau + b[2] - a[2], a[5] + (a[7] - a[1]) * tau + b[3] - a[3])
        return p, v, tau


def _index_at(t: list[float], t_s: float) -> int:
    """The index of the sample nearest ``t_s`` in the increasing times ``t``."""
    k = bisect.bisect_left(t, t_s)
    if k == 0:
        return 0
    if k >= len(t):
        return len(t) - 1
    return k if t[k] - t_s < t_s - t[k - 1] else k - 1
