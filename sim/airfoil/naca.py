"""NACA 4-digit geometry, panelled surfaces and pressure-tap placement for the 2D airfoil simulator.

Coordinates. *Airfoil frame*: chord-normalised, x from the leading edge (0) to the trailing edge (1),
y up. *Body frame*: FRD with the origin at the pivot (a point on the chord line at ``pivot_x_c``):
``x_b = (pivot_x_c − x/c)·c`` (forward positive), ``y_b = 0`` (spanwise, the 2D section),
``z_b = −(y/c)·c`` (down positive). An airfoil-frame vector ``(vx, vy)`` maps to ``(−vx, 0, −vy)``.

Node order (Selig/XFOIL): start at the trailing edge, run along the UPPER surface to the leading edge,
then along the LOWER surface back to the trailing edge. The contour is counterclockwise: the interior
lies on the LEFT of the direction of travel, so the left normal of a panel points into the body.

The leading-edge node of an arbitrary contour is the node of minimum x (first one on ties). For
cambered NACA sections the upper surface bulges slightly ahead of the camber-line origin, so this can
be a node a few 1e-5 chords ahead of (0, 0); with this choice x varies monotonically along each side,
which makes tap placement by x/c unique.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from vdm_aero._typing import BoolArray, F64Array, FloatArray

__all__ = [
    "SurfaceGeometry",
    "TapsGeometry",
    "camber_line",
    "leading_edge_index",
    "locate_taps",
    "naca4_nodes",
    "naca4_params",
    "surface_geometry",
    "taps_geometry",
]

_CODE_RE = re.compile(r"^(?:naca)?[\s_-]*(\d)(\d)(\d\d)$")
_MIN_PANELS = 8
# Thickness polynomial coefficients of the 4-digit series (Abbott & von Doenhoff 1959, §6.4); the last one
# is -0.1015 for the original open trailing edge, -0.1036 for the usual closed-TE modification.
_THICK_COEFFS = (0.2969, -0.1260, -0.3516, 0.2843)
_TE_COEFF_CLOSED = -0.1036
_TE_COEFF_OPEN = -0.1015


def naca4_params(code: str) -> tuple[float, float, float]:
    """Parse a NACA 4-digit designation into ``(m, p, t)``: max camber, its x/c position, thickness.

    Accepts ``'2412'``, ``'naca2412'``, ``'NACA 2412'`` (case-insensitive). Raises ``ValueError`` for
    anything else, for zero thickness, and for a cambered section whose camber position digit is 0.
    """
    if not isinstance(code, str):
        raise ValueError(f"NACA code must be a string such as '2412' or 'naca0012', got {code!r}")
    match = _CODE_RE.match(code.strip().lower())
    if match is None:
        raise ValueError(f"not a NACA 4-digit designation: {code!r} (expected e.g. '0012', '2412', 'naca0015')")
    m = int(match.group(1)) / 100.0
    p = int(match.group(2)) / 10.0
    t = int(match.group(3)) / 100.0
    if t <= 0.0:
        raise ValueError(f"NACA {code!r}: thickness digits '00' give a zero-thickness section")
    if m > 0.0 and p == 0.0:
        raise ValueError(
            f"NACA {code!r}: cambered section (first digit {match.group(1)}) needs a camber position digit 1-9, got 0"
        )
    if m == 0.0:
        p = 0.0  # symmetric: the position digit is meaningless
    return m, p, t


def camber_line(x: F64Array, m: float, p: float) -> tuple[F64Array, F64Array]:
    """Standard 4-digit mean line ``y_c(x)`` and slope ``dy_c/dx`` at chord fractions ``x`` in [0, 1]."""
    x = np.asarray(x, dtype=np.float64)
    if m == 0.0:
        return np.zeros_like(x), np.zeros_like(x)
    fwd = x < p
    yc = np.where(fwd, m / p**2 * (2.0 * p * x - x**2), m / (1.0 - p) ** 2 * ((1.0 - 2.0 * p) + 2.0 * p * x - x**2))
    dyc = np.where(fwd, 2.0 * m / p**2 * (p - x), 2.0 * m / (1.0 - p) ** 2 * (p - x))
    return yc, dyc


def _half_thickness(x: F64Array, t: float, closed_te: bool) -> F64Array:
    a0, a1, a2, a3 = _THICK_COEFFS
    a4 = _TE_COEFF_CLOSED if closed_te else _TE_COEFF_OPEN
    yt = 5.0 * t * (a0 * np.sqrt(x) + x * (a1 + x * (a2 + x * (a3 + x * a4))))
    if closed_te:
        yt = np.where(x >= 1.0, 0.0, yt)  # the coefficients sum to 0 only up to round-off
    return np.asarray(yt, dtype=np.float64)


def naca4_nodes(code: str, n_panels: int, *, closed_te: bool = True) -> F64Array:
    """Panel nodes ``(n_panels+1, 2)`` of a NACA 4-digit section, chord-normalised, Selig/XFOIL order.

    Cosine spacing in x (dense at LE and TE). The upper surface gets ``n_panels // 2`` panels and the
    lower surface the rest (one more for odd counts). Thickness is applied perpendicular to the camber
    line. With ``closed_te`` (default) the closed-TE coefficient −0.1036 is used and the first and last
    nodes are identical, both exactly (1, 0); otherwise the original open TE (−0.1015) is used.
    """
    m, p, t = naca4_params(code)
    if isinstance(n_panels, bool) or not isinstance(n_panels, (int, np.integer)):
        raise ValueError(f"n_panels must be an integer, got {n_panels!r}")
    if n_panels < _MIN_PANELS:
        raise ValueError(f"n_panels must be >= {_MIN_PANELS}, got {n_panels}")
    n_upper = int(n_panels) // 2
    n_lower = int(n_panels) - n_upper
    x_up = 0.5 * (1.0 - np.cos(np.linspace(np.pi, 0.0, n_upper + 1)))  # TE -> LE
    x_lo = 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, n_lower + 1)[1:]))  # after LE -> TE
    x_up[0], x_up[-1], x_lo[-1] = 1.0, 0.0, 1.0

    def surface(x: F64Array, sign: float) -> F64Array:
        yc, dyc = camber_line(x, m, p)
        yt = _half_thickness(x, t, closed_te)
        theta = np.arctan(dyc)
        return np.column_stack((x - sign * yt * np.sin(theta), yc + sign * yt * np.cos(theta)))

    nodes = np.vstack((surface(x_up, 1.0), surface(x_lo, -1.0)))
    if closed_te:
        nodes[-1] = nodes[0]
    return np.ascontiguousarray(nodes, dtype=np.float64)


def _check_nodes(nodes: F64Array) -> F64Array:
    arr = np.asarray(nodes, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 4:
        raise ValueError(f"nodes must be an (n+1, 2) array with n >= 3 panels, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("nodes contain non-finite values")
    lengths = np.hypot(*np.diff(arr, axis=0).T)
    if np.any(lengths <= 0.0):
        raise ValueError(f"nodes contain {int(np.sum(lengths <= 0.0))} zero-length panel(s)")
    return arr


def leading_edge_index(nodes: F64Array) -> int:
    """Index of the leading-edge node: the node of minimum x (the first one on ties)."""
    return int(np.argmin(np.asarray(nodes, dtype=np.float64)[:, 0]))


def _arc_length(nodes: F64Array) -> tuple[F64Array, F64Array]:
    """Panel lengths ``(N,)`` and node arc-length coordinates ``(N+1,)`` from the first node."""
    lengths = np.hypot(*np.diff(nodes, axis=0).T)
    return lengths, np.concatenate(([0.0], np.cumsum(lengths)))


def _panel_normals_in(nodes: F64Array, lengths: F64Array) -> F64Array:
    """Unit inward (left) normals ``(N, 2)`` of the panels in the airfoil frame."""
    tang = np.diff(nodes, axis=0) / lengths[:, None]
    return np.column_stack((-tang[:, 1], tang[:, 0]))


def _to_body_points(xy: F64Array, chord_m: float, pivot_x_c: float) -> F64Array:
    return np.column_stack(((pivot_x_c - xy[:, 0]) * chord_m, np.zeros(len(xy)), -xy[:, 1] * chord_m))


def _to_body_vectors(v: F64Array) -> F64Array:
    return np.column_stack((-v[:, 0], np.zeros(len(v)), -v[:, 1]))


def _check_dims(chord_m: float, span_m: float, pivot_x_c: float) -> None:
    if not (np.isfinite(chord_m) and chord_m > 0.0):
        raise ValueError(f"chord_m must be a positive finite length, got {chord_m!r}")
    if not (np.isfinite(span_m) and span_m > 0.0):
        raise ValueError(f"span_m must be a positive finite length, got {span_m!r}")
    if not np.isfinite(pivot_x_c):
        raise ValueError(f"pivot_x_c must be finite, got {pivot_x_c!r}")


def _readonly(a: F64Array | BoolArray) -> None:
    a.flags.writeable = False


@dataclass(frozen=True, eq=False)
class SurfaceGeometry:
    """Per-panel geometry of a panelled airfoil (N panels), in chord units and in the body frame [m].

    ``mid_xc`` (N, 2) panel midpoints, ``length_c`` (N,) panel lengths and ``s_c`` (N,) arc-length
    coordinate of the midpoints measured from the first node (TE, upper side), all in chord units;
    ``upper`` (N,) True for panels before the leading-edge node; ``points_b`` (N, 3) midpoints in the
    body frame [m]; ``normals_b`` (N, 3) unit normals pointing INTO the body (body frame); ``areas_m2``
    (N,) panel length × span. ``perimeter_c`` is the contour length in chord units.
    """

    mid_xc: F64Array
    length_c: F64Array
    s_c: F64Array
    upper: BoolArray
    points_b: F64Array
    normals_b: F64Array
    areas_m2: F64Array
    perimeter_c: float
    chord_m: float
    span_m: float
    pivot_x_c: float


def surface_geometry(nodes: F64Array, *, chord_m: float, span_m: float, pivot_x_c: float) -> SurfaceGeometry:
    """Build the :class:`SurfaceGeometry` of the panels between consecutive ``nodes`` (chord units)."""
    arr = _check_nodes(nodes)
    _check_dims(chord_m, span_m, pivot_x_c)
    lengths, s_nodes = _arc_length(arr)
    mid = 0.5 * (arr[:-1] + arr[1:])
    n_in = _panel_normals_in(arr, lengths)
    upper = np.arange(len(lengths)) < leading_edge_index(arr)
    geo = SurfaceGeometry(
        mid_xc=mid,
        length_c=lengths,
        s_c=s_nodes[:-1] + 0.5 * lengths,
        upper=upper,
        points_b=_to_body_points(mid, chord_m, pivot_x_c),
        normals_b=_to_body_vectors(n_in),
        areas_m2=lengths * chord_m * span_m,
        perimeter_c=float(s_nodes[-1]),
        chord_m=float(chord_m),
        span_m=float(span_m),
        pivot_x_c=float(pivot_x_c),
    )
    for a in (geo.mid_xc, geo.length_c, geo.s_c, geo.upper, geo.points_b, geo.normals_b, geo.areas_m2):
        _readonly(a)
    return geo


def locate_taps(nodes: F64Array, x_c: Sequence[float] | FloatArray, upper: Sequence[bool] | BoolArray) -> F64Array:
    """Arc-length coordinates ``(K,)`` (chord units, from the first node) of taps given by x/c and side.

    Each tap is the point of its side (upper: nodes from the TE to the leading-edge node; lower: from
    the leading-edge node to the TE) where x equals ``x_c``, linearly interpolated along the panels.
    If x is not monotonic along a side, the crossing nearest the leading edge is used. Requests inside
    [0, 1] but beyond the discretised extent of the side (e.g. x/c = 0 when no node lies exactly at the
    LE) snap to the side's extreme. Raises ``ValueError`` if any ``x_c`` is outside [0, 1] or if the
    two sequences differ in length.
    """
    arr = _check_nodes(nodes)
    xq = np.asarray(x_c, dtype=np.float64).reshape(-1)
    up = np.asarray(upper, dtype=bool).reshape(-1)
    if xq.shape != up.shape:
        raise ValueError(f"x_c has {xq.size} entries but upper has {up.size}")
    if not np.all(np.isfinite(xq)) or np.any((xq < 0.0) | (xq > 1.0)):
        bad = xq[~(np.isfinite(xq) & (xq >= 0.0) & (xq <= 1.0))]
        raise ValueError(f"tap x/c must lie in [0, 1], got {bad.tolist()}")
    _, s_nodes = _arc_length(arr)
    i_le = leading_edge_index(arr)
    out = np.empty_like(xq)
    # Each side as a node sequence running FROM the LE, so "nearest the LE" is the first crossing.
    for side_upper, idx in ((True, np.arange(i_le, -1, -1)), (False, np.arange(i_le, len(arr)))):
        sel = up == side_upper
        if not np.any(sel):
            continue
        if len(idx) < 2:
            raise ValueError(f"the {'upper' if side_upper else 'lower'} side has no panels")
        xs, ss = arr[idx, 0], s_nodes[idx]
        q = np.clip(xq[sel], xs.min(), xs.max())[:, None]  # (k, 1)
        xa, xb = xs[:-1][None, :], xs[1:][None, :]
        hit = (np.minimum(xa, xb) <= q) & (q <= np.maximum(xa, xb))  # (k, segments)
        seg = np.argmax(hit, axis=1)  # first crossing from the LE; always exists after clipping
        x0, x1 = xs[seg], xs[seg + 1]
        dx = x1 - x0
        frac = np.divide(q[:, 0] - x0, dx, out=np.zeros_like(dx), where=dx != 0.0)
        out[sel] = ss[seg] + frac * (ss[seg + 1] - ss[seg])
    return out


class TapsGeometry(NamedTuple):
    """Body-frame geometry of K pressure taps: points [m], unit inward normals, tributary areas [m²]."""

    points_b: F64Array
    normals_b: F64Array
    areas_m2: F64Array


def taps_geometry(
    nodes: F64Array,
    s_c_taps: Sequence[float] | FloatArray,
    *,
    chord_m: float,
    span_m: float,
    pivot_x_c: float,
) -> TapsGeometry:
    """Geometry of taps at arc-length positions ``s_c_taps`` (chord units, from the first node).

    Points are interpolated linearly along the panels; normals are the node normals (the normalised
    mean of the two adjacent panel normals; the end nodes take their single panel's normal) interpolated
    in arc length and renormalised, pointing into the body. Each tap's tributary area is half the
    arc-length distance to each of its two neighbouring taps along the closed contour (wrapping through
    the TE) × span, so the areas sum to perimeter × span. Raises ``ValueError`` for positions outside
    [0, perimeter].
    """
    arr = _check_nodes(nodes)
    _check_dims(chord_m, span_m, pivot_x_c)
    sq = np.asarray(s_c_taps, dtype=np.float64).reshape(-1)
    lengths, s_nodes = _arc_length(arr)
    perim = float(s_nodes[-1])
    tol = 1e-12 * perim
    if sq.size == 0:
        raise ValueError("no tap positions given")
    if not np.all(np.isfinite(sq)) or np.any((sq < -tol) | (sq > perim + tol)):
        raise ValueError(f"tap arc-length positions must lie in [0, {perim:.6g}] (the perimeter), got {sq}")
    sq = np.clip(sq, 0.0, perim)
    pts = np.column_stack((np.interp(sq, s_nodes, arr[:, 0]), np.interp(sq, s_nodes, arr[:, 1])))
    n_pan = _panel_normals_in(arr, lengths)
    n_node = np.vstack((n_pan[:1], n_pan[:-1] + n_pan[1:], n_pan[-1:]))
    n_node /= np.linalg.norm(n_node, axis=1, keepdims=True)
    nrm = np.column_stack((np.interp(sq, s_nodes, n_node[:, 0]), np.interp(sq, s_nodes, n_node[:, 1])))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    order = np.argsort(sq, kind="stable")
    s_sorted = sq[order]
    gaps = np.append(np.diff(s_sorted), perim - s_sorted[-1] + s_sorted[0])  # gap after each sorted tap
    tributary = np.empty_like(sq)
    tributary[order] = 0.5 * (gaps + np.roll(gaps, 1))
    return TapsGeometry(
        points_b=_to_body_points(pts, chord_m, pivot_x_c),
        normals_b=_to_body_vectors(nrm),
        areas_m2=tributary * chord_m * span_m,
    )
