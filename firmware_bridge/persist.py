"""What survives a restart of the service: the filter's slow states, and the navigation output log.

**Filter state** (:class:`FilterStateStore`): the wind, the gyro/accelerometer biases, the magnetometer
and baro offsets, the model-correction parameters (by name), the gyro's scale and cross-axis errors δM, their
covariance block, and the measured turbulence; saved atomically (temporary file, fsync, rename) periodically
and on SIGTERM. A restarted service initialises position, velocity and attitude from the first GNSS fix as
always, then takes the saved slow states; their covariance is doubled in σ (the aircraft may have been powered
down and the biases moved), and a wind older than :data:`WIND_MAX_AGE_S` is not restored. What is restored is checked
against what was saved:

* the model corrections only into the same mode with the same models (their sha256 identity): they correct
  the models they were estimated with, and mean nothing to others;
* the IMU biases keep their saved values but get their turn-on σ back when the autopilot has booted since
  the save (its boot instant, wall clock less boot time, moved by more than :data:`BOOT_MATCH_S`): a power
  cycle redraws the turn-on biases and the autopilot measured new gyro offsets at boot;
* δM only into a mode that estimates it, from a mode that did (format 4 on): it is the gyro's, whatever the
  mode and the models, and a power cycle does not redraw it (:data:`~vdm_aero.nav.filter.SLOW_STATES`).

**Navigation log** (:class:`NavLog`): an append-only CSV of the solution, rotated by size
(``logging.handlers.RotatingFileHandler``).
"""

from __future__ import annotations

import io
import logging
import logging.handlers
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero.errors import UserInputError
from vdm_aero.nav.filter import NavFilter, slow_index
from vdm_aero.nav.state import AERO_PARAMS, AERO_PRIOR, IDX

__all__ = ["NAV_LOG_COLUMNS", "FilterStateStore", "NavLog"]

FORMAT = "vdm-aero-filter-state/4"
FORMAT_V3 = "vdm-aero-filter-state/3"  # without δM (before 2026-12-01's twenty-ninth session)
FORMAT_V2 = "vdm-aero-filter-state/2"  # without the aero parameters' names: those of AERO_PARAMS_V2
FORMAT_V1 = "vdm-aero-filter-state/1"  # without mode/models/boot checks: read, restored as from another boot
AERO_PARAMS_V2 = ("alpha_bias_rad", "beta_bias_rad", "airspeed_scale", "cx_bias", "cz_scale", "thrust_scale")
"""The model-correction parameters of formats 1 and 2 (before ``cy_bias``, 2026-12-01)."""
WIND_MAX_AGE_S = 600.0
RESTORE_SIGMA_FACTOR = 2.0
BOOT_MATCH_S = 5.0  # wall clock against the autopilot's boot time: NTP steps and link latency stay below
_N_GM = IDX["gm"].stop - IDX["gm"].start
_N_BEFORE_AERO = len(slow_index()) - len(AERO_PARAMS) - _N_GM  # SLOW_STATES ends with the aero block, then δM


class FilterStateStore:
    """Saves and restores a filter's slow states (module docstring) in ``path`` (an ``.npz``)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.saves = 0

    def save(self, f: NavFilter, *, models_id: str = "", autopilot_boot_unix_s: float = math.nan) -> bool:
        """Save ``f``'s slow states with the identity of the models they go with and the autopilot boot
        (wall-clock instant [s] of its boot) they were estimated in."""
        if f.x is None or f.engine is None:
            return False
        values, cov = f.slow_states()
        if not np.all(np.isfinite(values)):
            return False  # never persist a diverged filter
        buf = io.BytesIO()
        gust = np.asarray(f.process.gust_sigma_m_s)
        np.savez(buf, format=np.array(FORMAT), mode=np.array(f.mode), saved_unix_s=np.array(time.time()),
                 values=values, cov=cov, gust_sigma_m_s=gust, models_id=np.array(models_id),
                 autopilot_boot_unix_s=np.array(autopilot_boot_unix_s), aero_params=np.array(AERO_PARAMS),
                 gm_estimated=np.array(f.spec.gyro_m_err))  # fmt: skip
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        try:
            with open(tmp, "wb") as fh:
                fh.write(buf.getvalue())
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except OSError:
            tmp.unlink(missing_ok=True)  # a full disk: the last good state file stays, the partial one goes
            raise
        self.saves += 1
        return True

    def load(self) -> dict[str, Any] | None:
        """The saved state, or None when there is none; a corrupt file is a one-line error."""
        if not self.path.exists():
            return None
        try:
            with np.load(self.path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise UserInputError(f"{self.path}: not a filter state file ({e}); delete it to start afresh") from None
        fmt = str(d.get("format"))
        if fmt not in (FORMAT, FORMAT_V3, FORMAT_V2, FORMAT_V1) or "values" not in d or "cov" not in d:
            raise UserInputError(f"{self.path}: not a {FORMAT} file; delete it to start afresh")
        names = tuple(str(a) for a in d["aero_params"]) if "aero_params" in d else AERO_PARAMS_V2
        has_gm = fmt == FORMAT
        n_saved = _N_BEFORE_AERO + len(names) + (_N_GM if has_gm else 0)
        shapes = d["values"].shape == (n_saved,) and d["cov"].shape == (n_saved, n_saved)
        if not shapes or not set(names) <= set(AERO_PARAMS):
            raise UserInputError(f"{self.path}: not a {FORMAT} file; delete it to start afresh")
        d["values"], d["cov"] = _to_current_layout(d["values"], d["cov"], names, has_gm=has_gm)
        d["gm_estimated"] = has_gm and bool(d.get("gm_estimated", False))
        return d

    @staticmethod
    def restore(f: NavFilter, saved: dict[str, Any], *, models_id: str = "",
                autopilot_boot_unix_s: float = math.nan) -> list[str]:  # fmt: skip
        """Put saved slow states into an initialised filter running ``models_id`` in an autopilot booted at
        ``autopilot_boot_unix_s`` (module docstring); returns the names restored, and what was held back as
        ``-name`` (``-aero``: another mode or other models; ``-bias-sigma``: the autopilot has booted since)."""
        age = time.time() - float(saved["saved_unix_s"])
        keep_wind = 0.0 <= age <= WIND_MAX_AGE_S
        same_models = (str(saved.get("mode", "")) == f.mode and bool(models_id)
                       and str(saved.get("models_id", "")) == models_id)  # fmt: skip
        boot = float(saved.get("autopilot_boot_unix_s", math.nan))
        same_boot = abs(boot - autopilot_boot_unix_s) <= BOOT_MATCH_S  # False when either is unknown (NaN)
        cov = np.asarray(saved["cov"], dtype=np.float64) * RESTORE_SIGMA_FACTOR**2
        keep_gm = bool(saved.get("gm_estimated", False)) and f.spec.gyro_m_err
        restored = f.restore_slow_states(np.asarray(saved["values"], dtype=np.float64), cov, keep_wind=keep_wind,
                                         keep_aero=same_models, keep_gm=keep_gm)  # fmt: skip
        if not same_models:
            restored.append("-aero")
        if not same_boot:
            f.imu_recalibrated()
            restored.append("-bias-sigma")
        gs = np.asarray(saved["gust_sigma_m_s"], dtype=np.float64)
        if gs.shape == (3,) and np.all(np.isfinite(gs)):
            f.process.set_gust_sigma(gs)
        return restored


def _to_current_layout(values: np.ndarray, cov: np.ndarray, names: tuple[str, ...], *, has_gm: bool
                       ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Slow states saved with the aero parameters ``names`` (with δM after them when ``has_gm``) in today's layout
    of :func:`slow_index`: a parameter the file does not hold starts at its prior, uncorrelated, so that an upgrade
    that adds one keeps every state the file does hold; a δM the file does not hold is zero with no covariance,
    and is not restored (``gm_estimated`` is false)."""
    n_other = _N_BEFORE_AERO
    src = list(range(n_other)) + [n_other + names.index(k) if k in names else -1 for k in AERO_PARAMS]
    src += [n_other + len(names) + j if has_gm else -1 for j in range(_N_GM)]
    prior = np.array([AERO_PRIOR[k] for k in AERO_PARAMS])
    out_v = np.concatenate([values[:n_other], prior[:, 0], np.zeros(_N_GM)])
    out_c = np.diag(np.concatenate([np.zeros(n_other), np.square(prior[:, 1]), np.zeros(_N_GM)]))
    have = np.array([i for i, j in enumerate(src) if j >= 0])
    take = np.array([src[i] for i in have])
    out_v[have] = values[take]
    out_c[np.ix_(have, have)] = cov[np.ix_(take, take)]
    return out_v, out_c


NAV_LOG_COLUMNS = (
    "unix_s,boot_s,lat_deg,lon_deg,alt_m,north_m,east_m,down_m,vn_m_s,ve_m_s,vd_m_s,roll_rad,pitch_rad,yaw_rad,"
    "sigma_h_m,wind_n_m_s,wind_e_m_s,gnss,mode,ports_ok,health"
)


class _RaisingRotatingHandler(logging.handlers.RotatingFileHandler):
    """logging swallows a failed write (it prints a traceback to stderr): keep the error for NavLog to raise."""

    error: OSError | None = None

    def handleError(self, record: logging.LogRecord) -> None:
        e = sys.exc_info()[1]
        self.error = e if isinstance(e, OSError) else OSError(str(e))


class NavLog:
    """Append-only, size-rotated CSV of the navigation solution (columns :data:`NAV_LOG_COLUMNS`)."""

    def __init__(self, path: Path, *, max_bytes: int, backups: int) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._handler = _RaisingRotatingHandler(path, maxBytes=max_bytes, backupCount=backups)
        self._handler.setFormatter(logging.Formatter("%(message)s"))
        self._logger = logging.Logger(f"vdm-aero.navlog.{path}")  # not registered globally: no shared state
        self._logger.propagate = False
        self._logger.addHandler(self._handler)
        self._logger.info("# " + NAV_LOG_COLUMNS)

    def write(self, row: list[Any]) -> None:
        """Append a row; raises the OSError of a failed write (a full disk) for the caller to count."""
        self._handler.error = None
        self._logger.info(",".join(f"{v:.9g}" if isinstance(v, float) and math.isfinite(v) else str(v) for v in row))
        if self._handler.error is not None:
            raise self._handler.error

    def close(self) -> None:
        self._handler.close()
