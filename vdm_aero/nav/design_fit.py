"""What the filter learns from the design data set (never from the world): the port pressure model of the
FADS solve and the polynomial stability derivatives of ``vdm-classic``.

Both are least-squares fits over every snapshot of an airframe data set (its ``states.npy`` gives the
flight state of each snapshot, docs/formats.md): the user's own simulation, the same data the DEIM model
was built from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from vdm_aero._typing import BoolArray, F64Array
from vdm_aero.dataset import AIRFRAME_STATE_COLUMNS, STATES_FILE, Dataset, load_dataset, read_columns
from vdm_aero.errors import DatasetError

__all__ = ["CRUISE_ENVELOPE", "DesignFlightData", "PortPressureModel", "StabilityDerivatives", "cruise_rows"]

_COL = {name: i for i, name in enumerate(AIRFRAME_STATE_COLUMNS)}
_RIDGE = 1e-8  # relative ridge of the regressions (the sweeps make some columns nearly collinear)


@dataclass(frozen=True)
class DesignFlightData:
    """Per design snapshot: flight state (M, 10) in :data:`AIRFRAME_STATE_COLUMNS` order, Cp at the named
    ports (M, n), body coefficients (M, 6) and the reference span and chord [m]."""

    states: F64Array
    cp_ports: F64Array
    coeffs: F64Array
    span_m: float
    chord_m: float

    @classmethod
    def load(cls, path: str | Path, port_names: tuple[str, ...]) -> DesignFlightData:
        # cp is read as its port columns only, and checked there (the fits use nothing else of it): a full
        # check or a mapped gather touches all of cp.npy, the service's peak memory (read_columns)
        ds: Dataset = load_dataset(path, check_values=False)
        states_path = Path(path) / STATES_FILE
        if not states_path.is_file():
            raise DatasetError(
                f"{states_path}: missing (the navigation fits need an airframe data set's flight states)"
            )
        try:
            states = np.load(states_path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:  # truncated or not an .npy
            raise DatasetError(f"{states_path}: not a readable .npy array ({e})") from None
        if not isinstance(states, np.ndarray) or states.dtype.kind not in "fiu":
            raise DatasetError(f"{states_path}: expected a numeric array")
        if states.shape != (ds.n_snapshots, len(AIRFRAME_STATE_COLUMNS)):
            raise DatasetError(f"{states_path}: shape {states.shape}, expected ({ds.n_snapshots}, 10)")
        if not np.all(np.isfinite(states)):
            raise DatasetError(f"{states_path}: non-finite flight states")
        if ds.coeffs is None or ds.coeffs.shape[1] != 6:
            raise DatasetError(f"{path}: the navigation fits need six body coefficients per snapshot")
        idx = ds.point_indices(port_names)
        cp_path = Path(path) / "cp.npy"
        cp_ports = np.asarray(read_columns(cp_path, idx), dtype=np.float64)
        if cp_ports.shape[0] != ds.n_snapshots or not np.all(np.isfinite(cp_ports)):
            raise DatasetError(f"{cp_path}: non-finite or missing values in the port columns")
        return cls(
            states=np.asarray(states, dtype=np.float64),
            cp_ports=cp_ports,
            coeffs=np.asarray(ds.coeffs, dtype=np.float64),
            span_m=ds.reference.span_m,
            chord_m=ds.reference.chord_m,
        )


def _lstsq(a: F64Array, y: F64Array) -> tuple[F64Array, F64Array]:
    """Ridge least squares: (θ (k, m), residual RMS (m,))."""
    scale = np.maximum(np.linalg.norm(a, axis=0), 1e-12)
    an = a / scale
    lam = _RIDGE * float(np.trace(an.T @ an))
    theta = np.linalg.solve(an.T @ an + lam * np.eye(an.shape[1]), an.T @ y) / scale[:, None]
    rms = np.sqrt(np.mean((a @ theta - y) ** 2, axis=0))
    return theta, rms


def _rates_hat(speed: F64Array | float, omega_b: F64Array, span: float, chord: float) -> F64Array:
    """Normalised rates (p̂, q̂, r̂) = (pb, qc, rb)/(2V), (..., 3)."""
    v2 = 2.0 * np.asarray(speed)[..., None]
    return np.asarray(omega_b) * np.array([span, chord, span]) / v2


CRUISE_ENVELOPE: Final[dict[str, float]] = {
    # The fits weigh the flight the filter meets (docs/navigation.md): the design data set also spans stall,
    # full deflections and 2 rad/s roll rates, where a polynomial of this order cannot follow the separated
    # flow (measured: Cp residual 0.2–0.8 over the whole set against 0.01–0.13 inside this envelope).
    "alpha_min_deg": -4.0,
    "alpha_max_deg": 14.0,
    "beta_deg": 10.0,
    "control_deg": 12.0,
    "p_rad_s": 1.2,
    "qr_rad_s": 0.8,
    "alpha_dot_rad_s": 0.3,
}


def cruise_rows(states: F64Array) -> BoolArray:
    """Design snapshots inside :data:`CRUISE_ENVELOPE`."""
    e = CRUISE_ENVELOPE
    a = np.degrees(states[:, _COL["alpha_rad"]])
    return np.asarray(
        (a >= e["alpha_min_deg"])
        & (a <= e["alpha_max_deg"])
        & (np.abs(np.degrees(states[:, _COL["beta_rad"]])) <= e["beta_deg"])
        & (np.abs(np.degrees(states[:, 7:10])).max(axis=1) <= e["control_deg"])
        & (np.abs(states[:, _COL["p_rad_s"]]) <= e["p_rad_s"])
        & (np.abs(states[:, 4:6]).max(axis=1) <= e["qr_rad_s"])
        & (np.abs(states[:, _COL["alpha_dot_rad_s"]]) <= e["alpha_dot_rad_s"])
    )


def _control_terms(alpha: F64Array | float, controls: F64Array) -> tuple[F64Array, F64Array]:
    """Control terms δ, δ², α·δ (..., 9) and their α derivative."""
    c = np.asarray(controls, dtype=np.float64)
    a = np.asarray(alpha, dtype=np.float64)[..., None]
    zero = np.zeros_like(c)
    return np.concatenate([c, c * c, a * c], axis=-1), np.concatenate([zero, zero, c], axis=-1)


# ------------------------------------------------------------------------------------------- FADS
def _angle_rows(x: float, y: float) -> F64Array:
    """The cubic in (α, β) of one point and its α and β derivatives as the rows of one (3, 10) array: the FADS
    solve's hot path takes all three through the port model in one product."""
    return np.array([[1.0, x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3],
                     [0.0, 1.0, 0.0, 2 * x, y, 0.0, 3 * x * x, 2 * x * y, y * y, 0.0],
                     [0.0, 0.0, 1.0, 0.0, x, 2 * y, 0.0, x * x, 2 * x * y, 3 * y * y]])  # fmt: skip


def _angle_terms(alpha: F64Array | float, beta: F64Array | float) -> tuple[F64Array, F64Array, F64Array]:
    """Cubic polynomial in (α, β): values (..., 10) and their α and β derivatives."""
    if isinstance(alpha, float) and isinstance(beta, float):  # one point: the rows of :func:`_angle_rows`
        rows = _angle_rows(alpha, beta)
        return rows[0], rows[1], rows[2]
    a, b = np.asarray(alpha, dtype=np.float64), np.asarray(beta, dtype=np.float64)
    one, zero = np.ones_like(a), np.zeros_like(a)
    val = np.stack([one, a, b, a * a, a * b, b * b, a**3, a * a * b, a * b * b, b**3], axis=-1)
    da = np.stack([zero, one, zero, 2 * a, b, zero, 3 * a * a, 2 * a * b, b * b, zero], axis=-1)
    db = np.stack([zero, zero, one, zero, a, 2 * b, zero, a * a, 2 * a * b, 3 * b * b], axis=-1)
    return val, da, db


class PortPressureModel:
    """Cp at each port as a cubic in (α, β) plus normalised-rate and control terms (δ, δ², α·δ), fitted to
    the design data inside :data:`CRUISE_ENVELOPE`; :meth:`solve` inverts it for (q̄, α, β) from port Δp
    (a flush air-data system solve, FADS: Whitmore et al., NASA TM-104241, with a regression model of the
    ports instead of a potential-flow one)."""

    def __init__(self, theta: F64Array, cp_rms: F64Array, span_m: float, chord_m: float) -> None:
        self.theta = theta  # (22, n_ports)
        self.cp_rms = cp_rms  # (n_ports,) regression residual: the model's own Cp error
        self.span_m, self.chord_m = span_m, chord_m

    @classmethod
    def fit(cls, data: DesignFlightData) -> PortPressureModel:
        s = data.states[cruise_rows(data.states)]
        val, _, _ = _angle_terms(s[:, _COL["alpha_rad"]], s[:, _COL["beta_rad"]])
        hat = _rates_hat(s[:, 0], s[:, 3:6], data.span_m, data.chord_m)
        ctl, _ = _control_terms(s[:, 1], s[:, 7:10])
        theta, rms = _lstsq(np.hstack([val, hat, ctl]), data.cp_ports[cruise_rows(data.states)])
        return cls(theta, rms, data.span_m, data.chord_m)

    def cp(
        self, alpha: float, beta: float, speed_m_s: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[F64Array, F64Array, F64Array]:
        """Cp at the ports (n,) and its α and β derivatives."""
        val, da, db = _angle_terms(alpha, beta)
        hat = _rates_hat(max(speed_m_s, 1.0), omega_b, self.span_m, self.chord_m)
        ctl, dctl = _control_terms(alpha, controls_rad)
        th = self.theta
        return val @ th[:10] + hat @ th[10:13] + ctl @ th[13:], da @ th[:10] + dctl @ th[13:], db @ th[:10]

    def _grid_start(
        self, dp: F64Array, ok: BoolArray, rho: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[float, float, float]:
        """Cold start: the best (q̄, α, β) on a coarse angle grid, q̄ by linear least squares at each node."""
        best = (math.inf, 50.0, 0.05, 0.0)
        for a in np.radians([-2.0, 2.0, 6.0, 10.0, 14.0]):
            for b in np.radians([-8.0, -3.0, 0.0, 3.0, 8.0]):
                c = self.cp(float(a), float(b), 18.0, omega_b, controls_rad)[0][ok]
                q = float(c @ dp) / max(float(c @ c), 1e-9)
                err = float(np.sum((dp - q * c) ** 2))
                if q > 1.0 and err < best[0]:
                    best = (err, q, float(a), float(b))
        return best[1], best[2], best[3]

    def solve(
        self,
        dp_pa: F64Array,
        rho_kg_m3: float,
        omega_b: F64Array,
        controls_rad: F64Array,
        *,
        noise_pa: float,
        start: tuple[float, float, float] | None = None,
        iterations: int = 6,
    ) -> tuple[F64Array, F64Array, float] | None:
        """Weighted Gauss–Newton on Δp_i = q̄·Cp_i(α, β): ((V [m/s], α, β [rad]), their covariance (3, 3),
        the normalised residual χ²/dof), or None when fewer than four ports are usable (NaN marks a
        missing port). The covariance is scaled by χ²/dof when it exceeds 1 (the model then fits the
        measurement worse than its stated errors)."""
        ok = np.isfinite(dp_pa)
        n = int(ok.sum())
        if n < 4:
            return None
        dp = dp_pa[ok]
        q, a, b = start if start is not None else self._grid_start(dp, ok, rho_kg_m3, omega_b, controls_rad)
        # what :meth:`cp` recomputes each iteration but is fixed for this frame, on the usable ports: the
        # rate terms ∝ 1/V, the controls' δ and δ² terms and the α·δ terms' slope (the profile's FADS cost)
        th = self.theta[:, ok]
        th_angle = th[:10]
        c = np.asarray(controls_rad, dtype=np.float64)
        rate_per_v = (np.asarray(omega_b) * np.array([self.span_m, self.chord_m, self.span_m]) / 2.0) @ th[10:13]
        ctl_fixed = c @ th[13:16] + (c * c) @ th[16:19]
        ctl_alpha = c @ th[19:22]
        cp_rms = self.cp_rms[ok]
        noise_var = noise_pa**2
        for _ in range(iterations):
            speed = math.sqrt(2.0 * max(q, 1.0) / rho_kg_m3)
            # rows: Cp and its α and β derivatives at the ports, from one product of the angle terms
            m = _angle_rows(a, b) @ th_angle
            m[0] += rate_per_v / max(speed, 1.0) + ctl_fixed + a * ctl_alpha
            m[1] += ctl_alpha
            w = 1.0 / (noise_var + (max(q, 1.0) * cp_rms) ** 2)
            r = dp - q * m[0]
            m[1:] *= q  # ∂(q̄·Cp)/∂(q̄, α, β), one row each
            jw = m * w
            info = jw @ m.T
            try:
                info_inv = np.linalg.inv(info)  # one 3×3 inverse: the step and the convergence test's 1σ
            except np.linalg.LinAlgError:
                return None
            dq, da, db = (info_inv @ (jw @ r)).tolist()
            q, a, b = q + dq, a + da, b + db
            if not (q > 1.0 and abs(a) < 0.6 and abs(b) < 0.6):
                return None
            # converged when the step is 1 % of the solution's own 1σ (the weights depend on q̄: the iteration
            # converges linearly, ~×0.2 a step; the last 1e-4 rad would cost three more iterations for nothing)
            v_q, v_a, v_b = info_inv.diagonal().tolist()
            if dq * dq < 1e-4 * v_q and da * da < 1e-4 * v_a and db * db < 1e-4 * v_b:
                break
        speed = math.sqrt(2.0 * q / rho_kg_m3)
        cp = _angle_rows(a, b)[0] @ th_angle + rate_per_v / max(speed, 1.0) + ctl_fixed + a * ctl_alpha
        r = dp - q * cp
        chi2 = float(np.sum(r * r * w)) / max(n - 3, 1)
        cov_qab = info_inv * max(chi2, 1.0)
        d = np.diag([1.0 / (rho_kg_m3 * speed), 1.0, 1.0])  # ∂(V, α, β)/∂(q̄, α, β)
        return np.array([speed, a, b]), d @ cov_qab @ d, chi2


# ----------------------------------------------------------------------------------- stability derivs
def _classic_terms(alpha: F64Array | float, beta: F64Array | float, hat: F64Array, controls: F64Array) -> F64Array:
    a, b = np.asarray(alpha, dtype=np.float64), np.asarray(beta, dtype=np.float64)
    one = np.ones_like(a)
    ctl, _ = _control_terms(a, controls)
    return np.concatenate([np.stack([one, a, a * a, a**3, b, b * b, a * b], axis=-1), np.asarray(hat), ctl], axis=-1)


class StabilityDerivatives:
    """Body force coefficients CX, CY, CZ as polynomial stability derivatives,
    C = C0 + C_α α + C_α² α² + C_α³ α³ + C_β β + C_β² β² + C_αβ αβ + C_p p̂ + C_q q̂ + C_r r̂ + Σ_δ (C_δ δ + C_δ² δ²
    + C_αδ αδ) over aileron, elevator and rudder, identified by least squares from the design data set inside
    :data:`CRUISE_ENVELOPE` (the model of the VDM literature, e.g. Mwenegoha et al. 2021; α̇ terms are left
    out: the filter has no α̇ measurement)."""

    def __init__(self, theta: F64Array, rms: F64Array, span_m: float, chord_m: float) -> None:
        self.theta = theta  # (19, 3)
        self.rms = rms  # (3,) fit residual on the design data
        self.span_m, self.chord_m = span_m, chord_m

    @classmethod
    def fit(cls, data: DesignFlightData) -> StabilityDerivatives:
        rows = cruise_rows(data.states)
        s = data.states[rows]
        hat = _rates_hat(s[:, 0], s[:, 3:6], data.span_m, data.chord_m)
        a = _classic_terms(s[:, 1], s[:, 2], hat, s[:, 7:10])
        theta, rms = _lstsq(a, data.coeffs[rows, :3])
        return cls(theta, rms, data.span_m, data.chord_m)

    def coeffs_and_gradient(
        self, speed_m_s: float, alpha_rad: float, beta_rad: float, omega_b: F64Array, controls_rad: F64Array
    ) -> tuple[F64Array, F64Array]:
        """(CX, CY, CZ) and ∂C/∂(V, α, β) (3, 3)."""
        hat = _rates_hat(speed_m_s, omega_b, self.span_m, self.chord_m)
        a, b = alpha_rad, beta_rad
        phi = _classic_terms(a, b, hat, controls_rad)
        th = self.theta
        c = phi @ th
        d_a = np.array([0.0, 1.0, 2 * a, 3 * a * a, 0.0, 0.0, b]) @ th[:7] + controls_rad @ th[16:19]
        d_b = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 2 * b, a]) @ th[:7]
        d_v = (-hat / speed_m_s) @ th[7:10]
        return c, np.stack([d_v, d_a, d_b], axis=1)
