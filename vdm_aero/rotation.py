"""Attitude: scalar-first unit quaternions body → NED, direction-cosine matrices and ZYX Euler angles; the
one implementation (the simulator's hot loop spells the same DCM out in floats, tested against this).

Conventions: q = (q0, q1, q2, q3), v_ned = R(q)·v_b; Euler (roll φ, pitch θ, yaw ψ) in the aerospace ZYX
sequence, R = R_z(ψ)·R_y(θ)·R_x(φ). ⊕ for an error-state filter: q ⊕ δθ = q ⊗ exp(δθ) (body-frame
perturbation), ⊖ its inverse.
"""

from __future__ import annotations

import math

import numpy as np

from vdm_aero._typing import F64Array, FloatArray

__all__ = [
    "dcm_from_quat",
    "euler_from_quat",
    "quat_exp",
    "quat_from_dcm",
    "quat_from_euler",
    "quat_log",
    "quat_multiply",
]

Quat = tuple[float, float, float, float]


def _floats4(q: FloatArray | tuple[float, ...]) -> tuple[float, float, float, float]:
    """Four Python floats: ``tolist`` for arrays (the navigation filter's hot path calls this ~10⁵ times a
    flight minute; the per-element generator costs three times as much)."""
    if isinstance(q, np.ndarray):
        a, b, c, d = q.tolist()
        return a, b, c, d
    a, b, c, d = (float(v) for v in q)
    return a, b, c, d


def dcm_from_quat(q: FloatArray | tuple[float, ...]) -> F64Array:
    """Rotation matrix (3, 3) body → NED of a scalar-first unit quaternion."""
    q0, q1, q2, q3 = _floats4(q)
    return np.array(
        [
            [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
            [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
            [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
        ]
    )


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """Scalar-first quaternion body → NED of ZYX Euler angles [rad]."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q: FloatArray | tuple[float, ...]) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] of a scalar-first quaternion body → NED."""
    q0, q1, q2, q3 = (float(v) for v in q)
    roll = math.atan2(2.0 * (q0 * q1 + q2 * q3), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (q0 * q2 - q3 * q1))))
    yaw = math.atan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 * q2 + q3 * q3))
    return roll, pitch, yaw


def quat_from_dcm(c_nb: FloatArray) -> F64Array:
    """Scalar-first unit quaternion(s) (q0 ≥ 0) of rotation matrices body → NED, (3, 3) → (4,) or
    (n, 3, 3) → (n, 4). Shepperd's method: the largest of the four squared components is formed first, so the
    division is always well conditioned."""
    c = np.asarray(c_nb, dtype=np.float64)
    single = c.ndim == 2
    m = c.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = np.stack(
        [
            np.stack([1.0 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1),
            np.stack(
                [m[:, 2, 1] - m[:, 1, 2], 1.0 + 2 * m[:, 0, 0] - tr, m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0]],
                axis=1,
            ),
            np.stack(
                [m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1.0 + 2 * m[:, 1, 1] - tr, m[:, 1, 2] + m[:, 2, 1]],
                axis=1,
            ),
            np.stack(
                [m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1], 1.0 + 2 * m[:, 2, 2] - tr],
                axis=1,
            ),
        ],
        axis=1,
    )  # (n, 4 candidates, 4)
    pick = np.argmax(np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1), axis=1)
    q = cand[np.arange(len(pick)), pick]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    return q[0] if single else q


def quat_multiply(a: FloatArray | tuple[float, ...], b: FloatArray | tuple[float, ...]) -> F64Array:
    """Hamilton product a ⊗ b (scalar first): rotating by b, then by a."""
    a0, a1, a2, a3 = _floats4(a)
    b0, b1, b2, b3 = _floats4(b)
    return np.array(
        [
            a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
        ]
    )


def quat_exp(rotvec: FloatArray) -> F64Array:
    """Unit quaternion of a rotation vector [rad] (axis × angle)."""
    v = np.asarray(rotvec, dtype=np.float64)
    th = math.sqrt(float(v @ v))  # np.linalg.norm's own sum, without its overhead (a filter step calls this 3×)
    if th < 1e-12:
        return np.array([1.0, 0.5 * v[0], 0.5 * v[1], 0.5 * v[2]]) / math.sqrt(1.0 + 0.25 * th * th)
    s = math.sin(0.5 * th) / th
    return np.array([math.cos(0.5 * th), s * v[0], s * v[1], s * v[2]])


def quat_log(q: FloatArray | tuple[float, ...]) -> F64Array:
    """Rotation vector [rad] of a unit quaternion (the shorter of ±q, angle ≤ π)."""
    a = np.asarray(q, dtype=np.float64)
    if a[0] < 0.0:
        a = -a
    vn = float(np.linalg.norm(a[1:]))
    if vn < 1e-12:
        return np.asarray(2.0 * a[1:] / a[0])
    return np.asarray(2.0 * math.atan2(vn, float(a[0])) / vn * a[1:])
