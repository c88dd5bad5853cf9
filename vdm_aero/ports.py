"""Pressure ports: identified by name and body-frame location, matched between data sets by location."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vdm_aero._typing import F64Array, FloatArray, IntArray
from vdm_aero.errors import UserInputError

_CHUNK = 4096  # query points per distance block (bounded memory for 300k-point surfaces)


@dataclass(frozen=True)
class Port:
    """One pressure port: name, position [m] and unit inward normal in the body frame FRD."""

    name: str
    point_b: tuple[float, float, float]
    normal_b: tuple[float, float, float]


def nearest_points(surface_b: FloatArray, query_b: FloatArray) -> tuple[IntArray, F64Array]:
    """Index of the nearest surface point to each query point, and the distance [m]."""
    surface = np.asarray(surface_b, dtype=np.float64)
    query = np.atleast_2d(np.asarray(query_b, dtype=np.float64))
    idx = np.empty(len(query), dtype=np.int64)
    dist = np.empty(len(query))
    s2 = np.einsum("ij,ij->i", surface, surface)
    for lo in range(0, len(query), _CHUNK):
        q = query[lo : lo + _CHUNK]
        # |s − q|² = |s|² − 2 s·q + |q|², one (chunk × N) block at a time
        d2 = s2[None, :] - 2.0 * q @ surface.T + np.einsum("ij,ij->i", q, q)[:, None]
        k = np.argmin(d2, axis=1)
        idx[lo : lo + len(q)] = k
        dist[lo : lo + len(q)] = np.sqrt(np.maximum(d2[np.arange(len(q)), k], 0.0))
    return idx, dist


def candidates_nearest(fit_points_b: FloatArray, other_points_b: FloatArray) -> IntArray:
    """Candidate indices (unique, sorted) of the fit surface nearest to each point of another data set,
    as the method did with the mesh centres nearest to the wind-tunnel taps."""
    idx, _ = nearest_points(fit_points_b, other_points_b)
    return np.unique(idx)


def match_ports(
    ports: list[Port] | tuple[Port, ...], points_b: FloatArray, *, tolerance_m: float, where: str
) -> IntArray:
    """Index into ``points_b`` of each port, by location; a clear error when one has no point close enough."""
    pos = np.array([p.point_b for p in ports], dtype=np.float64)
    idx, dist = nearest_points(points_b, pos)
    bad = np.flatnonzero(dist > tolerance_m)
    if bad.size:
        p = ports[int(bad[0])]
        raise UserInputError(
            f"{where}: port {p.name} at ({', '.join(f'{v:.4f}' for v in p.point_b)}) m has no point within "
            f"{tolerance_m * 1e3:.1f} mm (nearest {dist[bad[0]] * 1e3:.1f} mm)"
            + (f"; {bad.size - 1} more ports unmatched" if bad.size > 1 else "")
        )
    if len(np.unique(idx)) != len(idx):
        raise UserInputError(f"{where}: two ports match the same point; the tolerance is too loose for its spacing")
    return idx
