"""Error metrics as in the method's tables.

For a coefficient time series y (C_L or C_D over the evaluated snapshots) and its prediction ŷ:
  ℓ2  = ‖ŷ − y‖₂ / ‖y‖₂          (relative, over all evaluated snapshots)
  ℓ∞  = max|ŷ − y| / max|y|       (relative)
  α at ℓ∞ = the recorded incidence [deg] of the snapshot with the largest |ŷ − y|.

With noisy port inputs, the noise floor of a linear map (:func:`linear_noise_floor`) is the ℓ2 error the
noise alone causes through it, and :func:`noise_amplification` compares a model's noisy error with it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.coefficients import lift_drag

METHOD_LABELS = {"deim": "DEIM", "deim_nn": "DEIM+NN", "linear_regression": "linear", "mlp": "MLP"}
"""Display names of the methods' result keys (DEIM, DEIM + correction net, and the two port baselines)."""


def series_errors(pred: FloatArray, truth: FloatArray, alpha_rad: FloatArray) -> dict[str, float]:
    """ℓ2, ℓ∞ (both relative) and α [deg] at the ℓ∞ error of one coefficient series."""
    p, t = np.asarray(pred, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    err = p - t
    i = int(np.argmax(np.abs(err)))
    return {
        "l2": float(np.linalg.norm(err) / np.linalg.norm(t)),
        "linf": float(np.abs(err[i]) / np.max(np.abs(t))),
        "alpha_at_linf_deg": float(math.degrees(float(np.asarray(alpha_rad)[i]))),
    }


def lift_drag_errors(
    pred_coeffs: FloatArray,
    truth_coeffs: FloatArray,
    alpha_rad: FloatArray,
    beta_rad: FloatArray | None = None,
) -> dict[str, dict[str, float]]:
    """{"CL": {...}, "CD": {...}} from body-axis coefficient arrays (K, ≥3)."""
    cl_p, cd_p = lift_drag(pred_coeffs, alpha_rad, beta_rad)
    cl_t, cd_t = lift_drag(truth_coeffs, alpha_rad, beta_rad)
    return {
        "CL": series_errors(cl_p, cl_t, alpha_rad),
        "CD": series_errors(cd_p, cd_t, alpha_rad),
    }


def merge_methods(per_method: dict[str, dict[str, dict[str, float]]]) -> dict[str, Any]:
    """{"deim": {"CL": m, "CD": m}, "deim_nn": {...}, …} → {"CL": {"deim": m, "deim_nn": m, …}, "CD": {...}}."""
    out: dict[str, Any] = {}
    for method, coeffs in per_method.items():
        for name, m in coeffs.items():
            out.setdefault(name, {})[method] = m
    return out


# ------------------------------------------------------------------------------------- port noise
# The sensor-noise model of ``vdm-aero evaluate --noise σ`` and of the training augmentation
# (:func:`vdm_aero.train_correction.train_one`): multiplicative, independent per port and per sample,
# Cp·(1 + σ·N(0,1)). Its std at port i of sample k is σ·|Cp_ki| — a fraction of the local Cp, not of q̄.


def add_port_noise(x: FloatArray, noise: float, rng: np.random.Generator) -> F64Array:
    """Port Cp (K, n_s) with multiplicative noise Cp·(1 + noise·N(0,1)), one draw per port and sample."""
    xa = np.asarray(x, dtype=np.float64)
    return np.asarray(xa * (1.0 + noise * rng.standard_normal(xa.shape)))


def port_noise_std(x: FloatArray, noise: float) -> F64Array:
    """The std σ_ki = noise·|Cp_ki| of the noise :func:`add_port_noise` puts on the noise-free Cp ``x``."""
    return np.asarray(noise * np.abs(np.asarray(x, dtype=np.float64)))


def linear_noise_floor(
    ms: FloatArray,
    sigma: FloatArray,
    truth_coeffs: FloatArray,
    alpha_rad: FloatArray,
    beta_rad: FloatArray | None = None,
) -> dict[str, float]:
    """The noise a linear map C = M_s·Cp + M_0 propagates from independent zero-mean port noise, in ℓ2.

    ``ms`` (≥3, n_s) maps port Cp to body-axis coefficients (its first three rows CX, CY, CZ), ``sigma``
    (K, n_s) is the port noise std of each sample. C_L and C_D of sample k are linear in C at fixed α, β, so
    their noise variance is Σ_i (g_ki)² σ_ki² with g_ki the C_L (C_D) of column i of M_s at that sample's α, β.
    Returns {"CL": f, "CD": f} with f = sqrt(E‖δ‖²)/‖y‖ over the K samples — the relative ℓ2 error the
    noise alone would cause, in the metric of :func:`series_errors`.
    """
    m = np.asarray(ms, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    k, n_s = s.shape
    if m.shape[1] != n_s:
        raise ValueError(f"ms has {m.shape[1]} columns, sigma {n_s} ports")
    a = np.asarray(alpha_rad, dtype=np.float64)
    b = None if beta_rad is None else np.asarray(beta_rad, dtype=np.float64)[:, None]
    gain_l, gain_d = lift_drag(np.broadcast_to(m.T, (k, n_s, m.shape[0])), a[:, None], b)  # (K, n_s) each
    cl_t, cd_t = lift_drag(truth_coeffs, a, beta_rad)
    return {
        "CL": float(np.sqrt(np.sum((gain_l * s) ** 2)) / np.linalg.norm(cl_t)),
        "CD": float(np.sqrt(np.sum((gain_d * s) ** 2)) / np.linalg.norm(cd_t)),
    }


def noise_amplification(noisy_l2: float, noise_free_l2: float, floor_l2: float) -> float:
    """Noisy error over what a noise-neutral model would give, sqrt(noise-free² + floor²).

    Noise independent of the noise-free error adds in quadrature in expectation, so ≈ 1 means the model
    passes the port noise on like the linear map whose ``floor_l2`` it is, > 1 that it amplifies it, < 1
    that it filters some of it."""
    return float(noisy_l2 / math.hypot(noise_free_l2, floor_l2))
