"""In-flight calibration: aerodynamic targets from a flight's sensors, and the correction net trained on them.

A user has no wind tunnel; the aircraft's own sensors weigh the aerodynamics in flight (Newton–Euler):

* force  F_aero = m·f_IMU − T(δ_t, V, ρ)·x̂_b,
* moment M_aero = I·ω̇ + ω × (I·ω) − M_prop,  M_prop = r_hub × T·x̂_b − spin·Q·x̂_b,

with m, I, the propeller and the servo map from the **nominal vehicle description** (never the as-built
truth), f_IMU and ω from the IMU (smoothed; ω̇ from a Savitzky–Golay derivative), the dynamic pressure
from the pitot, ρ from the barometer and the best temperature the aircraft has (the airspeed sensor's, else
the IMU's clamped to 35 °C: :func:`~vdm_aero.atmosphere.outside_air_temperature_c`). Dividing by q̄·S
(·b, c, b) gives the coefficient targets at the port sample times.

**Cp at the ports is Δp / q̄_FADS**, with q̄ from the ports' own air-data solve (the FADS port model of the
design data set, :class:`vdm_aero.nav.ports_frontend.PortFrontEnd`), exactly as at run time: the force model
must keep working when the pitot fails, so its inputs may not lean on the pitot. Normalising by the pitot's
q̄ here and by the FADS q̄ at run time fed the net inputs scaled by q̄_pitot/q̄_FADS, an error of the pitot's
calibration and of the as-built ports that it never saw in training.

**Nuisance parameters estimated jointly.** The propeller's installed thrust (two factors on the nominal
thrust terms ρk_t0·n² and −ρk_t1·n·u), its torque (one factor) and the accelerometer bias (three) are
unknown. They enter the targets linearly, so one least-squares problem per coefficient fits them together
with a linear-in-ports model of the DEIM residual (ridge on the port weights). What one flight identifies
is discussed in docs/aero-model.md: the thrust factors only through throttle changes at similar
aerodynamic states (the calibration scenario's throttle steps), the accelerometer bias through the
1/q̄ dependence of its coefficient (speed sweeps).

**The ports' airspeed against the pitot.** The same flight also calibrates the FADS solve's airspeed: the
ratio V_pitot / V_ports as a table in the ports' α (:mod:`vdm_aero.nav.port_speed_calibration`), written into
the model's ``calibration.port_speed``; the navigation's port front end applies it at run time. Cp keeps the
solve's own q̄ (above), so the net's inputs do not depend on it.

The correction net is then trained on (ports → target − DEIM) with the same recipe and ONNX export as
``vdm-aero train`` (:mod:`vdm_aero.train_correction`, imported only when training).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vdm_aero._typing import COEFF_NAMES, F64Array
from vdm_aero.atmosphere import density_kg_m3, outside_air_temperature_c
from vdm_aero.errors import ModelError, UserInputError
from vdm_aero.flightlog import SensorLog
from vdm_aero.model import AeroModel, load_diagnostics, read_model_yaml, sha256_file, write_model
from vdm_aero.nav.design_fit import DesignFlightData, PortPressureModel
from vdm_aero.nav.port_speed_calibration import PortSpeedCalibration
from vdm_aero.nav.ports_frontend import PortFrontEnd
from vdm_aero.vehicle import VehicleDescription

__all__ = [
    "CalibrationData",
    "NuisanceFit",
    "TargetSettings",
    "calibrate_model",
    "estimate_nuisance",
    "form_targets",
    "linear_baseline",
    "time_block_split",
]

NUISANCE_PRIOR: dict[str, tuple[float, float]] = {
    # (mean, σ): what a user knows before the flight. Thrust and torque factors: the installed propeller
    # within ±20 % of its data sheet (fuselage blockage, battery sag); accelerometer turn-on bias: the
    # ICM-42688-P's ±20 mg initial tolerance as 1σ (0.2 m/s²). A parameter the flight cannot identify stays
    # at its prior (its posterior σ ≈ the prior σ, reported), instead of absorbing model error.
    "thrust_a": (1.0, 0.2),
    "thrust_b": (1.0, 0.2),
    "torque": (1.0, 0.3),
    "bias_x": (0.0, 0.2),
    "bias_y": (0.0, 0.2),
    # z: an accelerometer z bias is m·b_z/(q̄S) in CZ, the same 1/q̄ shape as the lift of level flight
    # (−m·g/(q̄S)); one flight cannot separate them, so b_z stays at its prior (the autopilot's EKF estimates
    # it with GNSS; measured: left free it absorbed ~1 m/s² of model error and made CZ worse on test flights)
    "bias_z": (0.0, 0.001),
}
MIN_QBAR_PA = 60.0  # below ~10 m/s the ports' Cp is noise-dominated (SDP31: 0.1 Pa / 60 Pa ≈ 0.2 %)
RIDGE = 1e-6  # relative ridge on the port weights of the joint fit (the nuisance terms are not penalised)


@dataclass(frozen=True)
class TargetSettings:
    """How targets are formed: the output rate [Hz] (port samples are decimated to it), the smoothing
    half-window of the IMU [s], the polynomial order of the Savitzky–Golay fit, and the port transducers'
    noise 1σ [Pa] that weighs the FADS solve (the service's ``ports.noise_pa``)."""

    rate_hz: float = 25.0
    half_window_s: float = 0.06
    order: int = 2
    port_noise_pa: float = 0.2


@dataclass(frozen=True, eq=False)
class CalibrationData:
    """Per sample (K at the target rate): time [s], port Cp (K, n_s) = Δp / q̄_FADS, the pitot's dynamic
    pressure [Pa] that scales the targets, density
    [kg/m³], airspeed [m/s], throttle, specific force f_b [m/s²], rates ω_b [rad/s], ω̇_b [rad/s²], and
    the regressors that carry the nuisance parameters (per coefficient, see :func:`estimate_nuisance`)."""

    t_s: F64Array
    cp: F64Array
    qbar_pa: F64Array
    rho_kg_m3: F64Array
    airspeed_m_s: F64Array
    throttle: F64Array
    f_b: F64Array
    omega_b: F64Array
    omega_dot_b: F64Array
    kinematic: F64Array  # (K, 6): m·f and I·ω̇ + ω × Iω as coefficients (before propulsion)
    thrust_terms: F64Array  # (K, 2): the two nominal thrust terms as CX contributions
    torque_term: F64Array  # (K,): the nominal propeller torque as a Croll contribution
    mass_term: F64Array  # (K,): m/(q̄S): a unit accelerometer bias as a force coefficient
    ports_airspeed_m_s: F64Array  # (K,): the ports' air-data solve, uncalibrated (the airspeed table's input)
    ports_alpha_rad: F64Array  # (K,): its α

    def __len__(self) -> int:
        return len(self.t_s)


def _savgol(t: F64Array, y: F64Array, t_out: F64Array, half_s: float, order: int) -> tuple[F64Array, F64Array]:
    """Local polynomial (Savitzky–Golay) value and first derivative of y(t) at ``t_out`` (uniform t)."""
    dt = float(np.median(np.diff(t)))
    h = max(round(half_s / dt), order)
    k = np.arange(-h, h + 1) * dt
    vander = np.vander(k, order + 1, increasing=True)
    coef = np.linalg.pinv(vander)  # rows: value, slope, ...
    idx = np.clip(np.searchsorted(t, t_out), h, len(t) - h - 1)
    windows = np.stack([y[i - h : i + h + 1] for i in idx])  # (K, 2h+1, d)
    # the window is centred on sample idx; move the evaluation from t[idx] to t_out with the slope
    val = np.einsum("w,kwd->kd", coef[0], windows)
    slope = np.einsum("w,kwd->kd", coef[1], windows)
    return val + slope * (t_out - t[idx])[:, None], slope


def _hold(t: F64Array, y: F64Array, t_out: F64Array) -> F64Array:
    """Zero-order hold of samples (t, y) at ``t_out`` (the last sample at or before each time)."""
    i = np.clip(np.searchsorted(t, t_out, side="right") - 1, 0, len(t) - 1)
    return np.asarray(y[i])


def ports_air_data(
    pressure_model: PortPressureModel,
    dp_pa: F64Array,
    rho_kg_m3: F64Array,
    omega_b: F64Array,
    controls_rad: F64Array,
    noise_pa: float,
) -> F64Array:
    """The ports' air-data solve at each sample, (K, 4): V [m/s], α, β [rad] and q̄ [Pa], NaN where it has
    none: the same solve, warm start and limits as the run time's :class:`PortFrontEnd` (uncalibrated: this is
    what the airspeed table is fitted to)."""
    fe = PortFrontEnd(pressure_model, {}, range_pa=math.inf, noise_pa=noise_pa)
    out = np.full((len(dp_pa), 4), math.nan)
    for i in range(len(dp_pa)):
        solved = fe.air_data(dp_pa[i], float(rho_kg_m3[i]), omega_b[i], controls_rad[i])
        if solved is not None:
            out[i, :3], out[i, 3] = solved[0], solved[2]
    return out


def form_targets(
    log: SensorLog,
    vehicle: VehicleDescription,
    model: AeroModel,
    pressure_model: PortPressureModel,
    settings: TargetSettings | None = None,
) -> CalibrationData:
    """Aerodynamic coefficient targets from a flight's sensors (see the module docstring); Cp normalised by
    the q̄ of ``pressure_model``'s air-data solve, as at run time."""
    st = settings or TargetSettings()
    where = str(log.path)
    names = model.port_names
    missing = [n for n in names if n not in log.port_names]
    if missing:
        raise UserInputError(f"{where}: the flight has no port {missing[0]} of the model ({len(missing)} missing)")
    if not log.has_pitot:
        raise UserInputError(f"{where}: no pitot stream: calibration takes the dynamic pressure from the pitot")
    cols = [log.port_names.index(n) for n in names]
    t_p = log["ports_t_s"]
    if len(t_p) < 10 or len(log["imu_t_s"]) < 100:
        raise UserInputError(f"{where}: too short to calibrate on ({len(t_p)} port samples)")
    step = max(round(1.0 / (st.rate_hz * float(np.median(np.diff(t_p))))), 1)
    t_imu = log["imu_t_s"]
    guard = st.half_window_s + 0.1
    sel = np.arange(0, len(t_p), step)
    sel = sel[(t_p[sel] > t_imu[0] + guard) & (t_p[sel] < t_imu[-1] - guard)]
    t = t_p[sel]
    dp = log["ports_dp_pa"][sel][:, cols]
    qbar = np.interp(t, log["pitot_t_s"], log["pitot_dp_pa"])
    p_static = np.interp(t, log["baro_t_s"], log["baro_pa"])
    board_c = np.interp(t, t_imu, log["imu_temperature_c"])
    airspeed_c = np.interp(t, log["pitot_t_s"], log["pitot_temperature_c"])
    rho = density_kg_m3(p_static, outside_air_temperature_c(airspeed_c, board_c) + 273.15)
    f_b, _ = _savgol(t_imu, log["imu_accel_b_m_s2"], t, st.half_window_s, st.order)
    omega, omega_dot = _savgol(t_imu, log["imu_gyro_b_rad_s"], t, st.half_window_s, st.order)
    pwm = _hold(log["servo_t_s"], log["servo_pwm_us"], t)
    *surfaces, throttle = (np.asarray(v, dtype=np.float64) for v in vehicle.servos.deflections_rad(pwm))
    controls = np.stack(surfaces, axis=1)
    air = ports_air_data(pressure_model, dp, rho, omega, controls, st.port_noise_pa)
    q_ports = air[:, 3]
    keep = (qbar > MIN_QBAR_PA) & (q_ports > MIN_QBAR_PA)
    if int(keep.sum()) < 10:
        raise UserInputError(f"{where}: fewer than 10 samples with the pitot and the ports' air data above "
                             f"{MIN_QBAR_PA:g} Pa: nothing to calibrate on")  # fmt: skip
    t, dp, qbar, q_ports, rho, throttle, air = (x[keep] for x in (t, dp, qbar, q_ports, rho, throttle, air))
    f_b, omega, omega_dot = f_b[keep], omega[keep], omega_dot[keep]
    v_air = np.sqrt(2.0 * qbar / rho)

    ref = model.reference
    qs = qbar * ref.area_m2
    lref = np.array([ref.span_m, ref.chord_m, ref.span_m])
    m = vehicle.mass.mass_kg
    inertia = np.asarray(vehicle.mass.inertia_kg_m2, dtype=np.float64)
    h = omega @ inertia.T
    m_kin = omega_dot @ inertia.T + np.cross(omega, h)
    kin = np.hstack([m * f_b / qs[:, None], m_kin / (qs[:, None] * lref)])
    prop = vehicle.propulsion
    # axial airspeed ≈ V: the port-derived α, β are what the correction corrects, and cos α·cos β > 0.98
    r1, r2 = prop.thrust_regressors(throttle, v_air, rho)
    thrust_terms = np.column_stack([r1, r2]) / qs[:, None]
    _, torque = prop.thrust_torque(throttle, v_air, rho)
    hub = np.asarray(prop.thrust_point_b_m, dtype=np.float64)
    if abs(hub[1]) > 1e-9 or abs(hub[2]) > 1e-9:
        raise UserInputError(f"{vehicle.origin}: propulsion.thrust_point_b_m off the x axis is not supported yet")
    torque_term = -prop.spin * np.asarray(torque) / (qs * ref.span_m)
    return CalibrationData(
        t_s=t,
        cp=dp / q_ports[:, None],
        qbar_pa=qbar,
        rho_kg_m3=rho,
        airspeed_m_s=v_air,
        throttle=throttle,
        f_b=f_b,
        omega_b=omega,
        omega_dot_b=omega_dot,
        kinematic=kin,
        thrust_terms=thrust_terms,
        torque_term=np.asarray(torque_term),
        mass_term=m / qs,
        ports_airspeed_m_s=air[:, 0],
        ports_alpha_rad=air[:, 1],
    )


@dataclass(frozen=True)
class NuisanceFit:
    """Estimated nuisance parameters: thrust factors on the two nominal thrust terms, the torque factor,
    the accelerometer bias [m/s²] (body axes), and their 1σ from the least-squares covariance."""

    thrust_factors: tuple[float, float]
    torque_factor: float
    accel_bias_b_m_s2: tuple[float, float, float]
    sigma: dict[str, float]

    def targets(self, data: CalibrationData) -> F64Array:
        """Coefficient targets (K, 6) with these parameters."""
        y = data.kinematic.copy()
        a, b = self.thrust_factors
        y[:, 0] -= a * data.thrust_terms[:, 0] + b * data.thrust_terms[:, 1]
        for i in range(3):
            y[:, i] -= self.accel_bias_b_m_s2[i] * data.mass_term
        y[:, 3] -= self.torque_factor * data.torque_term
        return y

    def to_dict(self) -> dict[str, Any]:
        return {
            "thrust_factors": list(self.thrust_factors),
            "torque_factor": self.torque_factor,
            "accel_bias_b_m_s2": list(self.accel_bias_b_m_s2),
            "sigma": dict(self.sigma),
        }


def _features(cp: F64Array) -> F64Array:
    return np.hstack([np.ones((len(cp), 1)), cp])


def estimate_nuisance(data: CalibrationData, model: AeroModel) -> NuisanceFit:
    """Joint MAP least squares per coefficient: kinematic target − DEIM = nuisance terms + W·[1, Cp], with
    the Gaussian priors of :data:`NUISANCE_PRIOR` on the nuisance terms (weighted by the residual scale
    of an unregularised first pass) and a small ridge on W."""
    deim = model.predict_batch(data.cp, linear_only=True)
    phi = _features(data.cp)
    sol: dict[str, float] = {}
    sig: dict[str, float] = {}
    for i in range(6):
        extra: list[tuple[str, F64Array]] = []
        # kinematic − DEIM = nuisance terms + the aerodynamic residual (see NuisanceFit.targets)
        if i == 0:
            extra = [("thrust_a", data.thrust_terms[:, 0]), ("thrust_b", data.thrust_terms[:, 1])]
        if i < 3:
            extra.append((f"bias_{'xyz'[i]}", data.mass_term))
        if i == 3:
            extra.append(("torque", data.torque_term))
        a_mat = np.column_stack([e for _, e in extra] + [phi])
        y = data.kinematic[:, i] - deim[:, i]
        # column scaling, then a small ridge on the port weights only
        scale = np.linalg.norm(a_mat, axis=0)
        scale[scale == 0.0] = 1.0
        an = a_mat / scale
        reg = np.zeros(an.shape[1])
        reg[len(extra) :] = RIDGE * float(np.trace(an.T @ an)) / an.shape[1]
        dof = max(len(y) - a_mat.shape[1], 1)
        coef0 = np.linalg.solve(an.T @ an + np.diag(reg), an.T @ y)
        s2 = float(np.sum((y - an @ coef0) ** 2)) / dof  # residual variance: the scale of the priors
        prior_w = np.zeros(an.shape[1])
        prior_b = np.zeros(an.shape[1])
        for j, (name, _) in enumerate(extra):
            mu, sd = NUISANCE_PRIOR[name]
            prior_w[j] = s2 / (sd * scale[j]) ** 2  # prior on θ_j = coef_j/scale_j
            prior_b[j] = prior_w[j] * mu * scale[j]
        lhs = an.T @ an + np.diag(reg + prior_w)
        coef = np.linalg.solve(lhs, an.T @ y + prior_b) / scale
        cov = np.linalg.inv(lhs) * s2
        for j, (name, _) in enumerate(extra):
            sol[name] = float(coef[j])
            sig[name] = float(np.sqrt(cov[j, j])) / float(scale[j])
    return NuisanceFit(
        thrust_factors=(sol["thrust_a"], sol["thrust_b"]),
        torque_factor=sol["torque"],
        accel_bias_b_m_s2=(sol["bias_x"], sol["bias_y"], sol["bias_z"]),
        sigma=sig,
    )


def time_block_split(t_s: F64Array, block_s: float = 20.0, every: int = 5) -> tuple[F64Array, F64Array]:
    """Boolean masks (train, validation): every ``every``-th block of ``block_s`` seconds validates, so
    validation samples are not the training samples' immediate neighbours."""
    block = np.floor((t_s - t_s[0]) / block_s).astype(np.int64)
    val = block % every == every - 1
    return ~val, val


def linear_baseline(x: F64Array, y: F64Array) -> F64Array:
    """A direct linear regression [1, Cp] → coefficients (least squares): (n_s + 1, 6) weights."""
    phi = _features(x)
    w, *_ = np.linalg.lstsq(phi, y, rcond=None)
    return np.asarray(w)


def apply_linear(w: F64Array, x: F64Array) -> F64Array:
    return np.asarray(_features(x) @ w)


def calibrate_model(
    model_dir: Path,
    log: SensorLog,
    vehicle: VehicleDescription,
    out: Path,
    *,
    design_data: Path,
    grid: str = "quick",
    seed: int = 0,
    max_epochs: int = 3000,
    settings: TargetSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Train the correction net of ``model_dir``'s DEIM model on ``log`` and write the model ``out``
    (``design_data``: the design data set, whose FADS port model normalises Cp as at run time)."""
    from vdm_aero.train_correction import GRIDS, check_onnx_matches, export_onnx, grid_search

    if grid not in GRIDS:
        raise UserInputError(f"--grid: unknown grid {grid!r} (known: {', '.join(GRIDS)})")
    model = AeroModel.load(model_dir).with_correction(None)
    vehicle.check_reference(model.reference)
    pressure = PortPressureModel.fit(DesignFlightData.load(design_data, model.port_names))
    data = form_targets(log, vehicle, model, pressure, settings)
    try:
        port_speed = PortSpeedCalibration.fit(data.ports_alpha_rad, data.ports_airspeed_m_s, data.airspeed_m_s)
    except (ValueError, ModelError) as e:
        raise UserInputError(f"{log.path}: the ports' airspeed against the pitot: {e}") from None
    fit = estimate_nuisance(data, model)
    y = fit.targets(data)
    resid = y - model.predict_batch(data.cp, linear_only=True)
    tr, va = time_block_split(data.t_s)
    best, table = grid_search(
        GRIDS[grid],
        data.cp[tr],
        resid[tr],
        data.cp[va],
        resid[va],
        seed=seed,
        max_epochs=max_epochs,
        progress=progress,
    )
    onnx_bytes = export_onnx(best.net, model.n_ports)
    onnx_err = check_onnx_matches(onnx_bytes, best.net, data.cp)
    summary: dict[str, Any] = {
        "flight": {
            "path": str(log.path),
            "name": str(log.meta.get("name", "")),
            # a flight-log directory's sensors, or the autopilot log file itself (tlog, DataFlash, ULog)
            "sensors_sha256": sha256_file(log.path / "sensors.npz" if log.path.is_dir() else log.path),
            "duration_s": log.duration_s,
            "window_s": log.meta.get("window_s"),
            "samples": len(data),
            "source": log.meta.get("source"),
        },
        "vehicle": vehicle.name,
        "targets": {
            "rate_hz": (settings or TargetSettings()).rate_hz,
            "half_window_s": (settings or TargetSettings()).half_window_s,
            "qbar": "pitot",  # the targets' q̄
            "cp_qbar": "ports",  # Cp = Δp / q̄ of the ports' air-data solve, as at run time
            "port_noise_pa": (settings or TargetSettings()).port_noise_pa,
            "design_data": str(design_data),
        },
        "nuisance": fit.to_dict(),
        "port_speed": port_speed.to_dict(),
        "grid": grid,
        "seed": int(seed),
        "selected": {"hidden_layers": best.config.hidden_layers, "width": best.config.width},
        "val_mse": best.val_mse,
        "val_mse_deim_only": float(np.mean(resid[va] ** 2)),
        "onnx_vs_torch_max_abs": onnx_err,
        "candidates": table,
        "coefficients": list(COEFF_NAMES),
    }
    meta = read_model_yaml(model_dir)
    meta.pop("training", None)
    meta["calibration"] = summary
    meta["name"] = f"{meta.get('name', 'model')}-calibrated"
    write_model(
        out,
        linear=model.linear,
        sensors=np.load(model_dir / "deim.npz")["sensors"],
        ports=model.ports,
        reference=model.reference,
        meta=meta,
        diagnostics=load_diagnostics(model_dir),
        net_onnx=onnx_bytes,
    )
    return summary
