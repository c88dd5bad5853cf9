"""Linear-strength vortex panel method for steady 2D incompressible potential flow (inviscid).

Formulation (XFOIL's inviscid solver, Drela 1989; the linear-vortex panels of Katz & Plotkin,
*Low-Speed Aerodynamics*, 2nd ed., §11.4): a vortex sheet on the N panels between N+1 nodes, its
strength γ varying linearly along each panel and continuous at the nodes. The unknowns — the N+1 node
strengths and the stream function value Ψ₀ of the body — are fixed by ψ = Ψ₀ at the nodes (the
contour is a streamline and the fluid inside is at rest), the Kutta condition ``γ_first + γ_last = 0``
(equal speeds leaving the trailing edge) and, for a closed TE, XFOIL's zero internal velocity along the
TE bisector (node N duplicates node 0 there). The dense influence matrix is built by numpy
broadcasting and LU-factorised once; two unit problems are solved together (freestream V∞ = 1 at
α = 0 and at α = 90°), so any angle of attack is the superposition
``cos α·(α = 0 solution) + sin α·(α = 90° solution)`` — never a re-solve.

Conventions (airfoil frame: chord-normalised, x from LE to TE, y up; node order TE → upper → LE →
lower → TE, counterclockwise, see :mod:`sim.airfoil.naca`):

* Freestream ``V∞·(cos α, sin α)``; positive α raises the nose into the wind (lift up).
* γ is positive counterclockwise. With the fluid inside the contour at rest, the outer surface
  velocity equals γ, **signed along the node traversal direction**. Hence at positive lift the upper
  surface (traversed TE → LE while the flow runs LE → TE) has *negative* ``ut`` and the lower surface
  positive ``ut``; ``ut`` changes sign from − to + at the front stagnation point. Speeds and Cp use
  ``|ut|`` (``cp = 1 − ut²``), so the sign matters only for the flow direction.
* Circulation is reported **clockwise-positive** (the lift-producing sense): ``Γ = −∮ γ ds``, and
  ``c_l = 2Γ/(V∞ c)`` (Kutta–Joukowski) with c = 1.
* Moments are positive nose-up about a reference point on the chord line.

Midpoint surface velocities are the panel means of the linear γ, ``(γ_j + γ_j+1)/2``, so
:meth:`PanelSolution.interpolate` (linear in arc length between node γ's) reproduces them exactly at
the midpoints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from sim.airfoil.naca import leading_edge_index
from vdm_aero._typing import F64Array

__all__ = ["PanelSolution", "solve_panels"]

_TWO_PI = 2.0 * np.pi
_TINY = 1e-300
_SHARP_GAP = 1e-4  # largest TE gap [chord] accepted as a closed (sharp) TE, XFOIL's criterion
_BISECTOR_FRACTION = 0.1  # XFOIL's BWT: internal TE control point distance / shorter TE panel length


def _geometry(nodes: F64Array) -> tuple[F64Array, F64Array, F64Array, F64Array]:
    """Panel lengths (N,), unit tangents (N, 2), inward (left) normals (N, 2), midpoints (N, 2)."""
    d = np.diff(nodes, axis=0)
    lengths = np.hypot(d[:, 0], d[:, 1])
    tang = d / lengths[:, None]
    normal = np.column_stack((-tang[:, 1], tang[:, 0]))
    return lengths, tang, normal, 0.5 * (nodes[:-1] + nodes[1:])


def _local_coords(points: F64Array, nodes: F64Array) -> tuple[F64Array, F64Array, F64Array, F64Array, F64Array]:
    """Panel frames and the local coordinates (P, N) of ``points`` (P, 2) relative to every panel:
    ξ along the panel tangent from its start node, η along its left (inward) normal."""
    lengths, tang, normal, _ = _geometry(nodes)
    rel = points[:, None, :] - nodes[None, :-1, :]
    xi = rel[..., 0] * tang[None, :, 0] + rel[..., 1] * tang[None, :, 1]
    eta = rel[..., 0] * normal[None, :, 0] + rel[..., 1] * normal[None, :, 1]
    return lengths, tang, normal, xi, eta


def _streamfunction_influence(points: F64Array, nodes: F64Array) -> F64Array:
    """Stream function at ``points`` (P, 2) per unit node strength γ_k: matrix (P, N+1).

    A counterclockwise sheet γ(s) = γ_a(1 − s/L) + γ_b·s/L on panel j (local coordinates ξ, η of the
    field point; r₁, r₂ distances to the panel ends; θ₁ = atan2(η, ξ), θ₂ = atan2(η, ξ − L)) has
    ψ = −(1/2π)∫γ(s) ln r ds = −[γ_a (K₀ − K₁/L) + γ_b K₁/L]/2π with::

        K₀ = ∫ ln r ds   = (L − ξ) ln r₂ + ξ ln r₁ − L + η (θ₂ − θ₁)
        K₁ = ∫ s ln r ds = ξ K₀ + ½(r₂² ln r₂ − r₁² ln r₁) − ¼(r₂² − r₁²)

    The r ln r terms vanish at the panel ends (field point on a node), handled by flooring r². Distances
    and polar angles are computed once per (point, node) pair and shared by the two panels meeting at
    the node: θ₂ − θ₁ is the difference of the global polar angles of the two panel ends, wrapped to
    (−π, π] (the angle the panel subtends at the point).
    """
    lengths, tang, normal, _ = _geometry(nodes)
    rel = points[:, None, :] - nodes[None, :, :]  # (P, N+1, 2)
    rx, ry = rel[..., 0], rel[..., 1]
    r_sq = rx * rx + ry * ry
    ln_r = 0.5 * np.log(np.maximum(r_sq, _TINY))
    phi = np.arctan2(ry, rx)
    dtheta = np.mod(phi[:, 1:] - phi[:, :-1] + np.pi, _TWO_PI) - np.pi
    xi = rx[:, :-1] * tang[None, :, 0] + ry[:, :-1] * tang[None, :, 1]
    eta = rx[:, :-1] * normal[None, :, 0] + ry[:, :-1] * normal[None, :, 1]
    ell = lengths[None, :]
    r1sq, r2sq = r_sq[:, :-1], r_sq[:, 1:]
    ln_r1, ln_r2 = ln_r[:, :-1], ln_r[:, 1:]
    k0 = (ell - xi) * ln_r2 + xi * ln_r1 - ell + eta * dtheta
    k1 = xi * k0 + 0.5 * (r2sq * ln_r2 - r1sq * ln_r1) - 0.25 * (r2sq - r1sq)
    k1 /= ell
    out = np.zeros((len(points), len(lengths) + 1))
    out[:, :-1] -= (k0 - k1) / _TWO_PI
    out[:, 1:] -= k1 / _TWO_PI
    return out


def _velocity_influence(points: F64Array, nodes: F64Array) -> F64Array:
    """Velocity (P, N+1, 2) induced at ``points`` OFF the sheet per unit node strength γ_k.

    With I₀ = θ₂ − θ₁ and I₁ = ln(r₁/r₂), the sheet of :func:`_streamfunction_influence` induces the
    local components u = −[γ_a (I₀ − J₀) + γ_b J₀]/2π along the panel and
    v = [γ_a (I₁ − J₁) + γ_b J₁]/2π along its left normal, J₀ = (ξI₀ − ηI₁)/L, J₁ = (ξI₁ − L + ηI₀)/L.
    """
    lengths, tang, normal, xi, eta = _local_coords(points, nodes)
    ell = lengths[None, :]
    i0 = np.arctan2(eta, xi - ell) - np.arctan2(eta, xi)
    i1 = 0.5 * np.log((xi * xi + eta * eta) / ((xi - ell) ** 2 + eta * eta))
    j0 = (xi * i0 - eta * i1) / ell
    j1 = (xi * i1 - ell + eta * i0) / ell
    ua, ub = -(i0 - j0) / _TWO_PI, -j0 / _TWO_PI
    va, vb = (i1 - j1) / _TWO_PI, j1 / _TWO_PI
    out = np.zeros((len(points), len(lengths) + 1, 2))
    out[:, :-1, :] += ua[..., None] * tang[None, :, :] + va[..., None] * normal[None, :, :]
    out[:, 1:, :] += ub[..., None] * tang[None, :, :] + vb[..., None] * normal[None, :, :]
    return out


def _te_gap(nodes: F64Array) -> float:
    return float(np.hypot(*(nodes[-1] - nodes[0])))


def _system(nodes: F64Array) -> tuple[F64Array, F64Array]:
    """The (N+2)×(N+2) system matrix for the unknowns [γ_0 … γ_N, Ψ₀] of a closed contour, and the
    right-hand-side map R (N+2, 2): the RHS for V∞ = (cos α, sin α) is ``R @ (cos α, sin α)``.

    Rows 0…N−1: ψ(node_i) = Ψ₀ (node N coincides with node 0, its equation would be a duplicate);
    row N: the Kutta condition γ_0 + γ_N = 0; row N+1: zero internal velocity along the TE bisector at
    a point 0.1 × (shorter TE panel) inside the TE — XFOIL's sharp-TE closure, which also removes the
    otherwise nearly singular mode of equal and opposite γ on the two TE panels of a cusped edge.
    """
    n = len(nodes) - 1
    lengths, tang, _, _ = _geometry(nodes)
    a = np.empty((n + 2, n + 2))
    rmap = np.zeros((n + 2, 2))
    a[:n, : n + 1] = _streamfunction_influence(nodes[:n], nodes)
    a[:n, n + 1] = -1.0
    # the freestream stream function ψ∞ = y cos α − x sin α moves to the right-hand side
    rmap[:n, 0] = -nodes[:n, 1]
    rmap[:n, 1] = nodes[:n, 0]
    a[n:, :] = 0.0
    a[n, 0] = a[n, n] = 1.0  # Kutta
    bis = tang[0] - tang[-1]  # into the body, halfway between the two TE panels
    bis /= np.hypot(*bis)
    p_int = nodes[0] + _BISECTOR_FRACTION * min(lengths[0], lengths[-1]) * bis
    a[n + 1, : n + 1] = _velocity_influence(p_int[None, :], nodes)[0] @ bis
    rmap[n + 1] = -bis
    return a, rmap


def _alpha_1d(alpha: ArrayLike) -> F64Array:
    al = np.atleast_1d(np.asarray(alpha, dtype=np.float64))
    if al.ndim != 1:
        raise ValueError(f"alpha must be a scalar or a 1-D array [rad], got shape {al.shape}")
    return al


@dataclass(frozen=True, eq=False)
class PanelSolution:
    """The two unit solutions (V∞ = 1 at α = 0 and at α = 90°) of a panelled airfoil. Build with
    :func:`solve_panels`. All lengths are in chord units (nodes are chord-normalised, c = 1).

    Arrays: ``nodes`` (N+1, 2); ``s_nodes`` (N+1,) node arc length from the first node; ``s_c`` (N,)
    midpoint arc length; ``mid_xc`` (N, 2); ``length_c`` (N,); ``normals`` (N, 2) unit, into the body;
    ``gamma0``/``gamma90`` (N+1,) node strengths; ``ut0``/``ut90`` (N,) midpoint tangential velocity
    per unit V∞, signed along the traversal direction (see the module docstring);
    ``circulation0``/``circulation90`` clockwise-positive circulation per unit V∞ and chord;
    ``i_le`` index of the leading-edge node (minimum x, see :func:`sim.airfoil.naca.leading_edge_index`).
    Methods accepting ``alpha`` [rad] take a scalar or a 1-D array of M angles and always return
    arrays with a leading M axis (M = 1 for a scalar).
    """

    nodes: F64Array
    s_nodes: F64Array
    s_c: F64Array
    mid_xc: F64Array
    length_c: F64Array
    normals: F64Array
    i_le: int
    gamma0: F64Array
    gamma90: F64Array
    ut0: F64Array
    ut90: F64Array
    circulation0: float
    circulation90: float

    @property
    def n_panels(self) -> int:
        return len(self.length_c)

    @property
    def perimeter_c(self) -> float:
        return float(self.s_nodes[-1])

    def surface_velocity(self, alpha: ArrayLike) -> F64Array:
        """Signed tangential surface velocity / V∞ at the midpoints, (M, N): cos α·ut0 + sin α·ut90."""
        al = _alpha_1d(alpha)
        return np.cos(al)[:, None] * self.ut0[None, :] + np.sin(al)[:, None] * self.ut90[None, :]

    def cp(self, alpha: ArrayLike) -> F64Array:
        """Pressure coefficient at the midpoints, (M, N): 1 − (u_t/V∞)²."""
        return 1.0 - self.surface_velocity(alpha) ** 2

    def circulation(self, alpha: ArrayLike) -> F64Array:
        """Clockwise-positive circulation Γ/(V∞ c), (M,)."""
        al = _alpha_1d(alpha)
        return np.cos(al) * self.circulation0 + np.sin(al) * self.circulation90

    def cl(self, alpha: ArrayLike) -> F64Array:
        """Lift coefficient from Kutta–Joukowski, c_l = 2Γ/(V∞ c), (M,)."""
        return 2.0 * self.circulation(alpha)

    def alpha_zero_lift(self) -> float:
        """Angle of attack [rad] at which the circulation (hence c_l) vanishes."""
        return float(np.arctan2(-self.circulation0, self.circulation90))

    def _pressure_force(self, alpha: ArrayLike) -> F64Array:
        """Pressure force coefficients per unit span (M, 2) in the airfoil frame (x aft, y up)."""
        # pressure pushes along the inward normal: dF = p·n_in·ds, in coefficient form Σ Cp·L·n_in
        return self.cp(alpha) @ (self.length_c[:, None] * self.normals)

    def cl_pressure(self, alpha: ArrayLike) -> F64Array:
        """Lift coefficient (M,) from integrating Cp over the panels (force ⟂ freestream)."""
        al = _alpha_1d(alpha)
        force = self._pressure_force(al)
        return -force[:, 0] * np.sin(al) + force[:, 1] * np.cos(al)

    def cd_pressure(self, alpha: ArrayLike) -> F64Array:
        """Pressure drag coefficient (M,) (force ∥ freestream); ≈ 0 in potential flow (d'Alembert)."""
        al = _alpha_1d(alpha)
        force = self._pressure_force(al)
        return force[:, 0] * np.cos(al) + force[:, 1] * np.sin(al)

    def cm_pressure(self, alpha: ArrayLike, x_ref_c: float = 0.25) -> F64Array:
        """Pitching-moment coefficient (M,), positive nose-up, about (x_ref_c, 0), from Cp."""
        cp = self.cp(alpha)
        fx = self.length_c * self.normals[:, 0]  # per unit Cp
        fy = self.length_c * self.normals[:, 1]
        arm_x = self.mid_xc[:, 0] - x_ref_c
        arm_y = self.mid_xc[:, 1]
        # nose-up = clockwise in (x aft, y up): −(r × F)_z = y·F_x − (x − x_ref)·F_y
        return cp @ (arm_y * fx - arm_x * fy)

    @overload
    def interpolate(self, s_c_query: ArrayLike, which: Literal["both"] = "both") -> tuple[F64Array, F64Array]: ...

    @overload
    def interpolate(self, s_c_query: ArrayLike, which: Literal["ut0", "ut90"]) -> F64Array: ...

    def interpolate(
        self, s_c_query: ArrayLike, which: Literal["both", "ut0", "ut90"] = "both"
    ) -> tuple[F64Array, F64Array] | F64Array:
        """Unit-solution tangential velocities at arbitrary arc-length positions (chord units, from the
        first node), e.g. pressure taps between midpoints.

        On a linear-vortex panel the outer tangential velocity is the local γ, so the node γ's are
        interpolated linearly in arc length (exact within the discretisation; at a midpoint this is
        ``ut0``/``ut90``). ``which="both"`` returns ``(ut0_q, ut90_q)``; ``"ut0"`` or ``"ut90"`` returns
        that one array. Shapes follow ``s_c_query`` flattened to 1-D. Raises ``ValueError`` outside
        [0, perimeter].
        """
        sq = np.atleast_1d(np.asarray(s_c_query, dtype=np.float64)).reshape(-1)
        perim = self.perimeter_c
        tol = 1e-12 * perim
        if not np.all(np.isfinite(sq)) or np.any((sq < -tol) | (sq > perim + tol)):
            raise ValueError(f"arc-length positions must lie in [0, {perim:.6g}] (the perimeter)")
        sq = np.clip(sq, 0.0, perim)
        if which == "ut0":
            return np.interp(sq, self.s_nodes, self.gamma0)
        if which == "ut90":
            return np.interp(sq, self.s_nodes, self.gamma90)
        if which == "both":
            return np.interp(sq, self.s_nodes, self.gamma0), np.interp(sq, self.s_nodes, self.gamma90)
        raise ValueError(f"which must be 'both', 'ut0' or 'ut90', got {which!r}")

    def stagnation_s_c(self, alpha: ArrayLike) -> F64Array:
        """Arc length (M,) of the front stagnation point: where the node-interpolated u_t changes sign
        from − (upper-side flow toward the TE) to + ; of several such crossings, the one nearest the
        leading-edge node. NaN if there is none."""
        al = _alpha_1d(alpha)
        g = np.cos(al)[:, None] * self.gamma0[None, :] + np.sin(al)[:, None] * self.gamma90[None, :]
        ga, gb = g[:, :-1], g[:, 1:]
        cross = (ga <= 0.0) & (gb >= 0.0) & (ga != gb)
        frac = np.divide(ga, ga - gb, out=np.zeros_like(ga), where=cross)
        s_cross = self.s_nodes[None, :-1] + frac * self.length_c[None, :]
        dist = np.where(cross, np.abs(s_cross - self.s_nodes[self.i_le]), np.inf)
        k = np.argmin(dist, axis=1)
        rows = np.arange(al.size)
        return np.where(np.isfinite(dist[rows, k]), s_cross[rows, k], np.nan)

    def solve_direct(self, alpha: float) -> F64Array:
        """Testing aid: rebuild the system and solve it once with the freestream at ``alpha`` [rad],
        returning the midpoint ``u_t`` (N,) without using the unit solutions."""
        a, rmap = _system(np.array(self.nodes))
        rhs = rmap @ np.array([np.cos(alpha), np.sin(alpha)])
        gamma = np.linalg.solve(a, rhs)[:-1]
        return 0.5 * (gamma[:-1] + gamma[1:])


def solve_panels(nodes: F64Array) -> PanelSolution:
    """Solve the two unit problems for an airfoil given by chord-normalised ``nodes`` (N+1, 2) in
    TE → upper → LE → lower → TE order.

    The trailing edge must be closed: first and last nodes closer than 1e-4 chord (XFOIL's sharp-TE
    criterion), as from ``naca4_nodes(..., closed_te=True)``; the method has no base panel for a blunt
    TE. Raises ``ValueError`` for an open TE and for malformed nodes (shape, non-finite values,
    zero-length panels).
    """
    arr = np.array(nodes, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 4:
        raise ValueError(f"nodes must be an (N+1, 2) array with N >= 3 panels, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("nodes contain non-finite values")
    if np.any(np.hypot(*np.diff(arr, axis=0).T) <= 0.0):
        raise ValueError("nodes contain zero-length panel(s) (repeated consecutive nodes)")
    lengths, _, normal, mid = _geometry(arr)
    gap = _te_gap(arr)
    if gap >= _SHARP_GAP:
        raise ValueError(
            f"open trailing edge (gap {gap:.3g} chord between the first and last node): the panel method "
            f"needs a closed TE (gap < {_SHARP_GAP:g}); use naca4_nodes(..., closed_te=True)"
        )
    a, rmap = _system(arr)
    lu = scipy.linalg.lu_factor(a, overwrite_a=True, check_finite=False)
    sol_2 = scipy.linalg.lu_solve(lu, rmap, check_finite=False)  # columns: α = 0 and α = 90°
    gam = sol_2[:-1]  # drop Ψ₀
    ut = 0.5 * (gam[:-1] + gam[1:])
    circ = -(lengths @ ut)  # clockwise-positive Γ = −∮γ ds (exact for linear γ)
    s_nodes = np.concatenate(([0.0], np.cumsum(lengths)))
    sol = PanelSolution(
        nodes=arr,
        s_nodes=s_nodes,
        s_c=s_nodes[:-1] + 0.5 * lengths,
        mid_xc=mid,
        length_c=lengths,
        normals=normal,
        i_le=leading_edge_index(arr),
        gamma0=np.ascontiguousarray(gam[:, 0]),
        gamma90=np.ascontiguousarray(gam[:, 1]),
        ut0=np.ascontiguousarray(ut[:, 0]),
        ut90=np.ascontiguousarray(ut[:, 1]),
        circulation0=float(circ[0]),
        circulation90=float(circ[1]),
    )
    for field in (sol.nodes, sol.s_nodes, sol.s_c, sol.mid_xc, sol.length_c, sol.normals):
        field.flags.writeable = False
    for field in (sol.gamma0, sol.gamma90, sol.ut0, sol.ut90):
        field.flags.writeable = False
    return sol
