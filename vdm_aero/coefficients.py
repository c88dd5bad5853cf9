"""Pressure integration and axis transforms of aerodynamic coefficients.

Conventions (see ``docs/formats.md``): SI units, body frame FRD (x forward, y right, z down) with its
origin at the moment reference point, and surface normals pointing INTO the body, so a positive
pressure coefficient pushes the surface along its normal.

For a snapshot of pressure coefficients ``cp`` (N,) the body-axis coefficients are the linear map
``C = S @ cp`` with the (6, N) force/moment matrix ``S`` of :func:`force_moment_matrix`::

    [CX, CY, CZ]            = Σ_i cp_i n_i S_i / A_ref
    [Croll, Cpitch, Cyaw]   = Σ_i cp_i (r_i × n_i) S_i / (A_ref · l_ref)

with ``l_ref`` = span for roll and yaw and chord for pitch.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from vdm_aero._typing import F64Array

__all__ = ["ReferenceLike", "body_to_wind", "force_moment_matrix", "lift_drag"]


class ReferenceLike(Protocol):
    """Anything carrying the reference geometry (e.g. :class:`vdm_aero.dataset.Reference`)."""

    @property
    def area_m2(self) -> float:
        """Reference area A_ref [m²]."""
        ...

    @property
    def chord_m(self) -> float:
        """Reference chord (pitching-moment length) [m]."""
        ...

    @property
    def span_m(self) -> float:
        """Reference span (rolling- and yawing-moment length) [m]."""
        ...


def force_moment_matrix(points: ArrayLike, normals: ArrayLike, areas: ArrayLike, reference: ReferenceLike) -> F64Array:
    """Return the (6, N) matrix ``S`` that maps pressure coefficients to body-axis coefficients.

    Args:
        points: (N, 3) surface point positions [m] in the body frame (FRD, origin = moment reference).
        normals: (N, 3) unit normals pointing INTO the body [-].
        areas: (N,) surface area of each point [m²].
        reference: reference area [m²], chord [m] and span [m].

    Returns:
        ``S`` (6, N) float64, rows ``[CX, CY, CZ, Croll, Cpitch, Cyaw]``, so that ``C = S @ cp``
        (``cp`` dimensionless) and ``C_all = cp_matrix @ S.T`` for an (M, N) snapshot matrix.

    Raises:
        ValueError: on inconsistent shapes or a non-positive reference quantity (programming errors;
            data set files are validated by :mod:`vdm_aero.dataset` before they get here).
    """
    r = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    s = np.asarray(areas, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 3:
        raise ValueError(f"points: shape {r.shape}, expected (N, 3)")
    if n.shape != r.shape:
        raise ValueError(f"normals: shape {n.shape}, expected {r.shape} to match points")
    if s.shape != (r.shape[0],):
        raise ValueError(f"areas: shape {s.shape}, expected ({r.shape[0]},) to match points")
    a_ref = float(reference.area_m2)
    chord = float(reference.chord_m)
    span = float(reference.span_m)
    for key, value in (("area_m2", a_ref), ("chord_m", chord), ("span_m", span)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"reference.{key} must be a positive finite number, got {value!r}")

    ns = n * s[:, None]  # (N, 3) area-weighted normals [m²]
    out = np.empty((6, r.shape[0]), dtype=np.float64)
    out[0:3] = ns.T / a_ref
    moment_arm = np.cross(r, ns)  # (N, 3) [m³]
    lengths = np.array([span, chord, span], dtype=np.float64)
    out[3:6] = moment_arm.T / (a_ref * lengths[:, None])
    return out


def body_to_wind(
    coeffs: ArrayLike, alpha: ArrayLike, beta: ArrayLike | None = None
) -> tuple[F64Array, F64Array, F64Array]:
    """Rotate body-axis force coefficients into wind axes.

    The freestream seen in body axes (FRD) is ``v = V (cos α cos β, sin β, sin α cos β)``. Wind axes:
    ``x_w = v̂``, ``y_w = (-cos α sin β, cos β, -sin α sin β)``, ``z_w = (-sin α, 0, cos α)``.

    Args:
        coeffs: (..., ≥3) body-axis coefficients whose first three columns are ``[CX, CY, CZ]``.
        alpha: angle of attack [rad], broadcastable to ``coeffs[..., 0]``.
        beta: sideslip [rad], broadcastable likewise; ``None`` means zero sideslip.

    Returns:
        ``(CL, CD, CYw)`` float64 arrays: lift (positive up, ``-C·z_w``), drag (positive against the
        freestream, ``-C·x_w``) and wind-axis side force (positive to the right, ``C·y_w``).
    """
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim == 0 or c.shape[-1] < 3:
        raise ValueError(f"coeffs: shape {c.shape}, expected (..., 3) or wider ([CX, CY, CZ, ...])")
    a = np.asarray(alpha, dtype=np.float64)
    b = np.zeros_like(a) if beta is None else np.asarray(beta, dtype=np.float64)
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    ca, sa = np.cos(a), np.sin(a)
    cb, sb = np.cos(b), np.sin(b)
    cd = -(cx * ca * cb + cy * sb + cz * sa * cb)
    cl = cx * sa - cz * ca
    cyw = -cx * ca * sb + cy * cb - cz * sa * sb
    return (
        np.asarray(cl, dtype=np.float64),
        np.asarray(cd, dtype=np.float64),
        np.asarray(cyw, dtype=np.float64),
    )


def lift_drag(coeffs: ArrayLike, alpha: ArrayLike, beta: ArrayLike | None = None) -> tuple[F64Array, F64Array]:
    """Return ``(CL, CD)`` from body-axis coefficients (FRD).

    ``CL = CX sin α − CZ cos α`` and ``CD = −(CX cos α cos β + CY sin β + CZ sin α cos β)``; at α = 0
    this is ``CL = −CZ, CD = −CX``. ``alpha`` and ``beta`` are in [rad]; see :func:`body_to_wind`.
    """
    cl, cd, _ = body_to_wind(coeffs, alpha, beta)
    return cl, cd
