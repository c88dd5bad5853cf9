"""Error metrics as in the method's tables.

For a coefficient time series y (C_L or C_D over the evaluated snapshots) and its prediction ŷ:
  ℓ2  = ‖ŷ − y‖₂ / ‖y‖₂          (relative, over all evaluated snapshots)
  ℓ∞  = max|ŷ − y| / max|y|       (relative)
  α at ℓ∞ = the recorded incidence [deg] of the snapshot with the largest |ŷ − y|.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vdm_aero._typing import FloatArray
from vdm_aero.coefficients import lift_drag


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
    """{"deim": {"CL": m, "CD": m}, "deim_nn": {...}} → {"CL": {"deim": m, "deim_nn": m}, "CD": {...}}."""
    out: dict[str, Any] = {}
    for method, coeffs in per_method.items():
        for name, m in coeffs.items():
            out.setdefault(name, {})[method] = m
    return out
