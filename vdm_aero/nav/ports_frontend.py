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

Faulty ports are NaN for the models: the FADS solve drops their rows and its noise is inflated by n_ports/n_ok; the
aero model fills them by its gappy (MAP) reconstruction, which the filter does not fuse (the frame's ``ok`` says
which ports were left out).
"""

from __future__ import annotations

import copy
import math
import statistics
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vdm_aero._typing import BoolArray, F64Array
from vdm_aero.model import AeroModel
from vdm_aero.nav.design_fit import PortPressureModel
from vdm_aero.nav.imu_increments import TYPICAL_GAIN, gap_limit_s
from vdm_aero.nav.port_speed_calibration import PortSpeedCalibration

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
    :data:`BACK_SHARE` for :data:`BACK_S` where it could be called quiet (below: a learnt band, α steady).

    A port's share depends on the flow it sees, so it is learnt, and judged, per band of the air data's α
    (:data:`BAND_DEG`): a port near the zero of its Cp(α) breathes little in slow flight at high α and much in
    cruise. The α that picks the band is averaged like the activity (over :data:`ACTIVITY_TAU_S`), because the
    activity is the flow of the last seconds, and a verdict also needs the instant α in that band: judged by the
    instant α alone, a port that had breathed little in a band barely flown was called quiet a second after a
    pitch-down into a learnt band, its activity still the last band's (manoeuvring, 3 healthy ports in 5.6 h,
    2026-11-30). A band first flown starts from the nearest learnt band's shares and gives no verdict on a port until
    it has learnt that port there for :data:`BAND_LEARNT_S`. Nor is anything judged while α itself moves more
    than :data:`MANOEUVRE_RATIO` times its usual activity (learnt the same way): a pitch manoeuvre drives the ports
    most sensitive to α, and those least sensitive fall to a small share of the common activity with nothing
    wrong with them. A blocked line waits for the next steady flight in a learnt band to be called quiet.

    Set on the harsh world's survey (4 flights of 535 s, 4 airframes, light and moderate turbulence, each flown
    healthy and with 1–3 ports blocked, 2026-11-27): healthy ports went as low as 0.05–0.1 of their share (three
    ports together for ~2 s in one light-turbulence flight: some manoeuvres move some ports little), blocked ones
    fell under 0.05 within 5.9–8.3 s of the blocking and stayed there (``docs/navigation.md``, "A blocked port
    group"). A port left out for a few seconds costs the solve one row of twelve; a blocked one kept in bends it.
    With one share for every condition, healthy ports were called quiet 40 times in 2.76 h of the benchmark's
    manoeuvring flights (none in 21 h of survey and return flight); the bands and the manoeuvre hold were set on
    recordings of those flights (``docs/navigation.md``, "Quiet ports in a manoeuvre").
    """

    CHANGE_S = 0.1
    ACTIVITY_TAU_S = 2.0
    SHARE_TAU_S = 60.0  # the share's learning (log-averaged), and the α activity's
    WARMUP_S = 60.0  # of active flow before any verdict
    QUIET_SHARE = 0.05  # under the lowest healthy share seen (0.05–0.1)
    BACK_SHARE = 0.2
    BACK_S = 5.0
    ACTIVE_NOISE_RATIO = 100.0  # the common activity over the change's noise variance, 2σ_n²
    BAND_DEG = 2.0  # of the air data's α, for the learnt shares
    BAND_LO_DEG = -6.0  # the lowest band's lower edge; α outside the bands counts in the edge band
    N_BANDS = 14
    BAND_LEARNT_S = 60.0  # of a port's learning in a band before a verdict on it there
    MANOEUVRE_RATIO = 3.0  # α's activity over its usual level: a manoeuvre, no verdict
    MANOEUVRE_LEARN_S = 300.0  # the usual level's learning above that ratio

    def __init__(self, n_ports: int, noise_pa: float) -> None:
        self.noise_var_pa2 = 2.0 * noise_pa**2  # of a difference of two noisy readings
        self.quiet = np.zeros(n_ports, dtype=bool)
        self._prev: F64Array | None = None
        self._t_prev = math.nan
        self._t_frame = math.nan  # the last frame's time, and the frames' typical interval (the IMU's gap rule)
        self._frame_dt_s = math.nan
        self._activity = np.full(n_ports, math.nan)
        self._log_share = np.full((self.N_BANDS, n_ports), math.nan)  # per α band
        self._learnt_s = np.zeros((self.N_BANDS, n_ports))
        self._active_s = 0.0
        self._back_since = np.full(n_ports, math.nan)
        self._alpha_prev = math.nan
        self._alpha_mean_rad = math.nan  # α averaged like the activity: the band the activity belongs to
        self._alpha_activity = math.nan
        self._log_alpha_activity = math.nan  # its usual level

    def observe(self, t_s: float, dp_pa: F64Array, alpha_rad: float) -> None:
        """One frame at ``t_s`` [s] (NaN: a missing reading), with the latest air data's α [rad] (NaN: none,
        and no verdict)."""
        dt_frame, self._t_frame = t_s - self._t_frame, t_s
        if dt_frame > gap_limit_s(self._frame_dt_s):
            # a hole in the frames (a lossy link): a change across it is one over a longer time, larger the more
            # the flow wandered meanwhile, and differently so from port to port, not the activity the shares
            # were learnt on. The next change starts after it
            self._prev = None
        elif dt_frame > 0.0:
            fd = self._frame_dt_s
            self._frame_dt_s = dt_frame if math.isnan(fd) else fd + TYPICAL_GAIN * (dt_frame - fd)
        prev, t_prev = self._prev, self._t_prev
        if prev is not None and len(prev) == len(dp_pa) and 0.0 <= t_s - t_prev < self.CHANGE_S:
            return  # the next change is taken CHANGE_S after this one's start
        self._prev, self._t_prev = dp_pa.copy(), t_s
        if prev is None or len(prev) != len(dp_pa) or not t_s > t_prev:
            self._alpha_prev = alpha_rad
            return
        dt = t_s - t_prev
        a = min(dt / self.ACTIVITY_TAU_S, 1.0)
        steady = self._alpha_steady(alpha_rad, dt, a)
        am = self._alpha_mean_rad
        self._alpha_mean_rad = alpha_rad if not math.isfinite(am) else am + a * (alpha_rad - am)
        d2 = (dp_pa - prev) ** 2
        fresh = np.isfinite(d2)
        act = self._activity
        act[fresh & np.isnan(act)] = d2[fresh & np.isnan(act)]
        self._activity = act = np.where(fresh, act + a * (d2 - act), act)
        known = act[np.isfinite(act)].tolist()  # a dozen values: a Python sort is ~10× cheaper than np.nanmedian
        common = statistics.median(known) if known else math.nan
        if not common > self.ACTIVE_NOISE_RATIO * self.noise_var_pa2 or not math.isfinite(alpha_rad):
            return  # calm flow (or none), or no air data: no port can be told from a blocked one
        self._active_s += dt
        band = self._band(self._alpha_mean_rad)
        share = act / common
        ok_share = fresh & (share > 0.0)
        log_share = np.log(np.where(ok_share, share, 1.0))
        ls = self._band_log_share(band)
        learn = ok_share & ~self.quiet
        first = learn & np.isnan(ls)
        ls[first] = log_share[first]
        if self._active_s < self.WARMUP_S:  # the warm-up's plain mean, then a moving one
            w = dt / self._active_s
            self._log_share[band] = np.where(learn, ls + w * (log_share - ls), ls)
            self._learnt_s[band] += np.where(learn, dt, 0.0)
            return
        rel = np.where(ok_share & np.isfinite(ls), share / np.exp(np.nan_to_num(ls)), 0.0)
        # a port under its own share teaches nothing: a slow blockage must not become its new normal
        learn &= rel > self.BACK_SHARE
        self._log_share[band] = np.where(learn, ls + min(dt / self.SHARE_TAU_S, 1.0) * (log_share - ls), ls)
        self._learnt_s[band] += np.where(learn, dt, 0.0)
        # and α now in that band too: just after a pitch-up the others' swing fills the common activity at once
        settled = steady and self._band(alpha_rad) == band
        judged = settled & (self._learnt_s[band] >= self.BAND_LEARNT_S)
        newly = fresh & ~self.quiet & judged & (rel < self.QUIET_SHARE)
        self.quiet |= newly
        self._back_since[newly] = math.nan
        for i in np.flatnonzero(self.quiet & ~newly):
            # coming back is a verdict too: in a band not yet learnt the share is the nearest band's, and a
            # blocked port's leak read 0.3–0.45 of it there (the benchmark's blocked ports, 2026-11-30)
            if not (judged[i] and rel[i] > self.BACK_SHARE):
                self._back_since[i] = math.nan
            elif math.isnan(self._back_since[i]):
                self._back_since[i] = t_s
            elif t_s - self._back_since[i] >= self.BACK_S:
                self.quiet[i] = False

    def _band(self, alpha_rad: float) -> int:
        """The α band of ``alpha_rad`` (α outside the bands counts in the edge band)."""
        return min(max(int((math.degrees(alpha_rad) - self.BAND_LO_DEG) // self.BAND_DEG), 0), self.N_BANDS - 1)

    def _alpha_steady(self, alpha_rad: float, dt: float, a: float) -> bool:
        """Update α's activity with this change; False while it is above :data:`MANOEUVRE_RATIO` times its
        usual level, or unknown."""
        d2 = (alpha_rad - self._alpha_prev) ** 2
        self._alpha_prev = alpha_rad
        if not math.isfinite(d2):
            return False
        act = self._alpha_activity = d2 if math.isnan(self._alpha_activity) else self._alpha_activity + a * (
            d2 - self._alpha_activity)  # fmt: skip
        if not act > 0.0:
            return False
        log_act, usual = math.log(act), self._log_alpha_activity
        if math.isnan(usual):
            self._log_alpha_activity = log_act
            return False
        steady = log_act - usual <= math.log(self.MANOEUVRE_RATIO)
        # a manoeuvre's seconds barely teach it; lasting stronger turbulence becomes the usual within minutes
        tau_s = self.SHARE_TAU_S if steady else self.MANOEUVRE_LEARN_S
        self._log_alpha_activity = usual + min(dt / tau_s, 1.0) * (log_act - usual)
        return steady

    def _band_log_share(self, band: int) -> F64Array:
        """The band's learnt log shares (a view), a port never learnt there starting from the nearest band's."""
        ls = self._log_share[band]
        for i in np.flatnonzero(np.isnan(ls)):
            known = np.flatnonzero(np.isfinite(self._log_share[:, i]))
            if len(known):
                ls[i] = self._log_share[known[np.argmin(np.abs(known - band))], i]
        return ls


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
    # the air data inside what the ports' airspeed table was calibrated on: its α range and every port (always,
    # without a table: the design model is all there is); outside it the airspeed is a guess
    within_calibration: bool = True

    @property
    def n_ok(self) -> int:
        return int(np.count_nonzero(self.ok))


class PortFrontEnd:
    """Health checks, the FADS solve and the aero models (``models``: name → :class:`AeroModel`, all on
    the same ports in the same order); with ``speed_calibration``, the solve's airspeed calibrated in flight
    (:mod:`vdm_aero.nav.port_speed_calibration`)."""

    def __init__(
        self,
        pressure_model: PortPressureModel,
        models: dict[str, AeroModel],
        *,
        range_pa: float,
        noise_pa: float,
        stuck_frames: int = 10,
        speed_calibration: PortSpeedCalibration | None = None,
    ) -> None:
        self.pressure_model = pressure_model
        self.models = models
        self.speed_calibration = speed_calibration
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
        # every frame (100 Hz in the service): NaN compares false, so |Δp| < range and Δp == last hold only for
        # finite readings without masking them first
        dp = np.asarray(dp_pa, dtype=np.float64)
        in_range = np.abs(dp) < 0.995 * self.range_pa
        if self._last is None or len(self._last) != len(dp):
            self._same = np.zeros(len(dp), dtype=np.int64)
        else:
            self._same = (self._same + 1) * (dp == self._last)
        self._last = dp.copy()
        stuck = self._same >= self.stuck_frames
        qc = self.quiet_check
        if math.isfinite(t_s) and len(qc.quiet) == len(dp):
            was = qc.quiet.copy()
            qc.observe(t_s, np.where(in_range, dp, np.nan), self._start[1] if self._start else math.nan)
            if (qc.quiet != was).any():
                self.events += [(t_s, int(i), "quiet") for i in np.flatnonzero(qc.quiet & ~was)]
                self.events += [(t_s, int(i), "breathing again") for i in np.flatnonzero(was & ~qc.quiet)]
        quiet = qc.quiet if len(qc.quiet) == len(dp) else np.zeros(len(dp), dtype=bool)
        usable = in_range & ~stuck
        c = self.counts
        c["frames"] += 1
        n_finite = int(np.count_nonzero(np.isfinite(dp)))
        c["nan"] += len(dp) - n_finite
        c["out_of_range"] += n_finite - int(np.count_nonzero(in_range))
        c["stuck"] += int(np.count_nonzero(in_range & stuck))
        c["quiet"] += int(np.count_nonzero(usable & quiet))
        return np.asarray(usable & ~quiet)

    def air_data(
        self, dp_pa: F64Array, rho_kg_m3: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[F64Array, F64Array, float] | None:
        """The FADS solve of one frame (NaN marks an unusable port), warm-started from the last frame's:
        ((V [m/s], α, β [rad]), its covariance (3, 3), q̄ [Pa]), or None with no air data (too few ports, no
        convergence, or q̄ below :data:`MIN_QBAR_PA`). Calibration normalises Cp with this same q̄, the solve's
        own; V is the calibrated airspeed when the front end has a speed calibration."""
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
        if self.speed_calibration is not None:
            r = self.speed_calibration.ratio(float(vab[1]))
            scale = np.array([r, 1.0, 1.0])
            vab, cov = vab * scale, cov * np.outer(scale, scale)
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
        # the table was fitted on every port: a subset's solve has its own airspeed error, which it does not know
        cal = self.speed_calibration
        inside = cal is None or (bool(ok.all()) and cal.covers(float(vab[1])))
        return PortFrame(t_s, ok, vab, cov * (len(ok) / max(int(ok.sum()), 1)), qbar, coeffs, inside)
