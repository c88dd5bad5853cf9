"""The flight simulator's door to the airframe pressure model: exact strip-level evaluation and a local
Taylor model between evaluations.

**Why an adapter.** Ten minutes of flight at 400 Hz with RK4 are 960,000 force evaluations; the full
surface field (N points) per evaluation is out of the question, and even the pressure model's N-independent
strip field costs ~1 ms per call in Python (its cost is numpy call overhead, nearly flat in the number of
states evaluated together). So:

* :class:`StripAero` evaluates, for K flight states, only what flight needs: the six truth coefficients
  (each lifting group's strip Cp and skin-friction traction times the pressure model's precomputed
  strip-level force operators, plus the fuselage's pressure integral and friction) and Cp at the
  pressure-port points (a lifting-surface port is the spanwise interpolation of two strip Cp values,
  exactly as the full field is assembled; a fuselage port is one point of the fuselage field, which the
  coefficient integral needs anyway). The result equals the pressure model's full-field integral plus
  friction and its full field at the ports (``tests/test_flight.py`` checks both to 1e-12).
* :class:`LinearizedAero` calls it at the aerodynamic update rate on a batch of 16 states around the
  current one and between updates evaluates the Taylor model
  ``C(z) ≈ C0 + J·(z − z0) + Σ_(i,j) H_ij·Δz_i·Δz_j`` over the pairs of :data:`QUADRATIC_TERMS` (and the
  same for the port Cp). Its variables are ``z = (V, α, β, p/V, q/V, r/V, α̇/V, δa, δe, δr)``: the
  quasi-steady coefficients depend on the rates only through the reduced rates (the lattice and the
  fuselage flow are linear in [u, v, w, p, q, r]/V), so in z the V × rate cross terms of the raw state
  vanish exactly. The second-order terms are the ones that matter along real flights (measured on the
  survey scenario): α² (separation onset), β² (drag rise in sideslip), and roll rate and aileron — each
  squared and their product — whose symmetric effect (one wing towards separation, the other away) is
  the largest drag and lift nonlinearity in turning flight; everything else is first order.
  Because the model is a function of the state between updates, the aerodynamic damping and stiffness
  act at the full integration rate: holding forces constant between updates would not even be stable
  (the roll subsidence time constant is ~16 ms: L_p ≈ −60 /s at 18 m/s). The model is re-expanded at the
  nominal rate and early when the state leaves :class:`ReexpansionBounds`. The accuracy against
  re-expanding at every step is measured in ``tests/test_flight.py`` and reported in
  ``docs/flight-sim.md``.

**Private members used.** The strip field with reusable scratch buffers (``_field_quasi_steady``) and the
fuselage field (``_fuselage``) of :class:`~sim.airframe.pressure.AirframePressureModel`, and its lifting
``groups`` (strip-level force operators, spanwise interpolation). They are used here and nowhere else in
``sim.flight``; the agreement test fails loudly if they change meaning.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np

from sim.airframe.geometry import FUSELAGE, AirframeGeometry
from sim.airframe.pressure import AirframePressureModel, ScratchBuffers
from sim.airframe.vlm import STATE_COLUMNS, FlightStates
from vdm_aero._typing import F64Array, IntArray
from vdm_aero.ports import nearest_points

__all__ = [
    "N_FEATURES",
    "QUADRATIC_TERMS",
    "LinearizationSteps",
    "LinearizedAero",
    "PortLayout",
    "ReexpansionBounds",
    "StateLike",
    "StripAero",
    "flight_state",
    "resolve_ports",
    "taylor_variables",
]

N_STATE: Final = len(STATE_COLUMNS)  # 10: V, α, β, p, q, r, α̇, δa, δe, δr
_RATES: Final = tuple(STATE_COLUMNS.index(c) for c in ("p_rad_s", "q_rad_s", "r_rad_s", "alpha_dot_rad_s"))
_I_ALPHA: Final = STATE_COLUMNS.index("alpha_rad")
_I_BETA: Final = STATE_COLUMNS.index("beta_rad")
_I_P: Final = STATE_COLUMNS.index("p_rad_s")
_I_AIL: Final = STATE_COLUMNS.index("aileron_rad")
_CONTROL: Final = frozenset(STATE_COLUMNS.index(c) for c in ("aileron_rad", "elevator_rad", "rudder_rad"))
_NO_FUSELAGE_EFFECT: Final = _CONTROL | {STATE_COLUMNS.index("airspeed_m_s")}
"""Variables of z the fuselage field does not depend on: the control deflections, and V, since the spheroid
flow, its separation, apparent mass and friction are all functions of the velocity, rates and CG
acceleration divided by V (resp. V²), i.e. of the other components of z."""
QUADRATIC_TERMS: Final = ((_I_ALPHA, _I_ALPHA), (_I_BETA, _I_BETA), (_I_P, _I_P), (_I_AIL, _I_AIL), (_I_P, _I_AIL))
"""Second-order terms of the Taylor model, as pairs of indices into z (the hot loop of
:mod:`sim.flight.rigid_body` spells the same five products out)."""
N_FEATURES: Final = 1 + N_STATE + len(QUADRATIC_TERMS)
"""Taylor-model features: [1, Δz (10), Δα², Δβ², Δp̂², Δδa², Δp̂·Δδa]."""
_CENTRAL: Final = tuple(sorted({i for i, j in QUADRATIC_TERMS if i == j}))
Perturbation = tuple[tuple[int, float], ...]
StateLike = Sequence[float] | F64Array
"""A flight state: 10 values in :data:`STATE_COLUMNS` order."""


def _batch() -> tuple[Perturbation, ...]:
    """The states of one expansion as perturbations ((variable, step sign), ...): the expansion point, one
    forward step per variable, backward steps for the squared variables, one joint step per cross term;
    rows that perturb a variable in :data:`_NO_FUSELAGE_EFFECT` come after all others (they share the
    fuselage field of the row without that step)."""
    rows: list[Perturbation] = [()]
    rows += [((i, 1.0),) for i in range(N_STATE)]
    rows += [((i, -1.0),) for i in _CENTRAL]
    rows += [((i, 1.0), (j, 1.0)) for i, j in QUADRATIC_TERMS if i != j]
    return tuple(sorted(rows, key=lambda r: any(i in _NO_FUSELAGE_EFFECT for i, _ in r)))


_BATCH: Final = _batch()


def _fuselage_source(row: Perturbation) -> Perturbation:
    """The row whose fuselage field ``row`` can use: the same perturbation without the steps in variables
    the fuselage does not depend on."""
    return tuple((i, s) for i, s in row if i not in _NO_FUSELAGE_EFFECT)


@dataclass(frozen=True)
class PortLayout:
    """Pressure ports on the surface: names, the surface point each one sits on and how far its
    requested location was from that point [m]."""

    names: tuple[str, ...]
    point_index: IntArray
    snap_distance_m: F64Array

    def __len__(self) -> int:
        return len(self.names)


def resolve_ports(
    geometry: AirframeGeometry, names: Sequence[str], points_b: F64Array, tolerance_m: float, where: str
) -> PortLayout:
    """Snap requested port locations (n, 3) [m] to the nearest surface points of ``geometry``.

    Raises ValueError naming ``where`` and the port when a location is farther than ``tolerance_m``
    from every surface point, or when two ports land on the same point.
    """
    pts = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    if len(names) != len(pts):
        raise ValueError(f"{where}: {len(names)} names for {len(pts)} points")
    idx, dist = nearest_points(geometry.points_b, pts)
    for name, d in zip(names, dist, strict=True):
        if d > tolerance_m:
            raise ValueError(
                f"{where}: port {name} is {d * 1e3:.1f} mm from the nearest surface point "
                f"(tolerance {tolerance_m * 1e3:.1f} mm)"
            )
    uniq, counts = np.unique(idx, return_counts=True)
    if np.any(counts > 1):
        dup = [n for n, i in zip(names, idx, strict=True) if i == uniq[counts > 1][0]]
        raise ValueError(f"{where}: ports {', '.join(dup)} land on the same surface point")
    return PortLayout(names=tuple(names), point_index=idx.astype(np.int64), snap_distance_m=dist)


@dataclass(frozen=True, eq=False)
class _GroupPorts:
    """Ports of one lifting group: output columns and the strip-field gather (group-local strips)."""

    columns: IntArray
    i0: IntArray
    i1: IntArray
    w0: F64Array
    w1: F64Array
    chord: IntArray


class StripAero:
    """Exact quasi-steady truth coefficients and port Cp of K flight states at strip level."""

    def __init__(self, model: AirframePressureModel, ports: PortLayout) -> None:
        self.model = model
        self.ports = ports
        g = model.geometry
        self._buf = ScratchBuffers()
        comp = g.component[ports.point_index]
        self._group_ports: list[_GroupPorts] = []
        for grp in model.groups:
            cols, i0s, i1s, w0s, w1s, chords = [], [], [], [], [], []
            for k_part, ip in enumerate(grp.parts):
                c = g.parts[ip].component
                i0, i1, w0, w1 = grp.interp[k_part]
                for col in np.flatnonzero(comp == c):
                    pi = int(ports.point_index[col])
                    js = int(g.strip[pi])  # surface strip within the component
                    cols.append(int(col))
                    i0s.append(int(i0[js]))
                    i1s.append(int(i1[js]))
                    w0s.append(float(w0[js]))
                    w1s.append(float(w1[js]))
                    chords.append(int(g.chord_index[pi]))
            self._group_ports.append(
                _GroupPorts(
                    columns=np.asarray(cols, dtype=np.int64),
                    i0=np.asarray(i0s, dtype=np.int64),
                    i1=np.asarray(i1s, dtype=np.int64),
                    w0=np.asarray(w0s, dtype=np.float64),
                    w1=np.asarray(w1s, dtype=np.float64),
                    chord=np.asarray(chords, dtype=np.int64),
                )
            )
        fus = g.component_slice(FUSELAGE)
        on_fus = np.flatnonzero(comp == FUSELAGE)
        self._fus_cols = on_fus.astype(np.int64)
        self._fus_local = (ports.point_index[on_fus] - fus.start).astype(np.int64)
        covered = sum(len(p.columns) for p in self._group_ports) + len(on_fus)
        if covered != len(ports):
            raise ValueError(f"{len(ports) - covered} ports are on no known component")

    @property
    def n_ports(self) -> int:
        return len(self.ports)

    @property
    def has_slipstream(self) -> bool:
        """Whether :meth:`outputs` carries the slipstream rows (per unit thrust coefficient); see
        :class:`sim.flight.asbuilt.AsBuiltStripAero`."""
        return False

    def outputs(self, states: FlightStates, *, fuselage_index: IntArray | None = None) -> F64Array:
        """What the Taylor model expands: (K, 6 + n_ports) = coefficients then port Cp (subclasses may
        append rows, see :attr:`has_slipstream`)."""
        coeffs, cp = self.evaluate(states, fuselage_index=fuselage_index)
        return np.hstack([coeffs, cp])

    def evaluate(self, states: FlightStates, *, fuselage_index: IntArray | None = None) -> tuple[F64Array, F64Array]:
        """Truth coefficients (K, 6) (pressure integral + skin friction, body axes about the CG) and port
        Cp (K, n_ports) on the freestream dynamic pressure.

        ``fuselage_index`` (K,): state j takes the fuselage field of state ``fuselage_index[j]``; the
        fuselage is evaluated only for the leading states with ``fuselage_index[j] == j``. The caller
        guarantees that j differs from its source only in control deflections (the fuselage flow is the
        spheroid's own motion) or in airspeed at equal α, β and reduced rates p/V, q/V, r/V, α̇/V.
        """
        m = self.model
        k = len(states)
        field = m._field_quasi_steady(states, self._buf)
        coeffs = np.zeros((k, 6))
        cp_ports = np.empty((k, self.n_ports))
        for grp, cpg, trg, gp in zip(m.groups, field.strip_cp, field.strip_traction, self._group_ports, strict=True):
            coeffs += cpg.reshape(k, -1) @ grp.pressure_agg
            coeffs += trg.reshape(k, -1) @ grp.friction_agg
            if len(gp.columns):
                cp_ports[:, gp.columns] = gp.w0 * cpg[:, gp.i0, gp.chord] + gp.w1 * cpg[:, gp.i1, gp.chord]
        if fuselage_index is None:
            cp_f, c_f = m._fuselage(field, slice(None), self._buf)
        else:
            src = np.asarray(fuselage_index, dtype=np.int64)
            n_f = int(np.max(src)) + 1
            if src.shape != (k,) or np.any(src[:n_f] != np.arange(n_f)) or np.any(src[n_f:] >= n_f):
                raise ValueError(
                    "fuselage_index: the leading states must be their own source, the others point to them"
                )
            cp_f, c_f = m._fuselage(field, slice(0, n_f), self._buf)
            cp_f, c_f = cp_f[src], c_f[src]
        coeffs += c_f
        if len(self._fus_cols):
            cp_ports[:, self._fus_cols] = cp_f[:, self._fus_local]
        return coeffs, cp_ports


@dataclass(frozen=True)
class ReexpansionBounds:
    """How far the flight state may move from the expansion point before the Taylor model is re-expanded
    early (between the regular updates): the model's remainder grows with the square of the distance, and
    a turn entry moves the ailerons by tens of degrees within one 0.1 s update interval."""

    airspeed_m_s: float = 1.0
    angle_rad: float = math.radians(1.0)
    rate_rad_s: float = 0.15
    alpha_dot_rad_s: float = 0.5
    control_rad: float = math.radians(2.0)

    def vector(self) -> F64Array:
        a, r, c = self.angle_rad, self.rate_rad_s, self.control_rad
        return np.array([self.airspeed_m_s, a, a, r, r, r, self.alpha_dot_rad_s, c, c, c])


@dataclass(frozen=True)
class LinearizationSteps:
    """Finite-difference steps of the Taylor model, in :data:`STATE_COLUMNS` order (SI units). Small
    enough that truncation error is far below the model's variation over an update interval, large enough
    that rounding in the strip field (~1e-15 relative) stays negligible."""

    airspeed_m_s: float = 0.05
    angle_rad: float = math.radians(0.1)
    rate_rad_s: float = 0.01
    alpha_dot_rad_s: float = 0.02
    control_rad: float = math.radians(0.1)

    def vector(self) -> F64Array:
        a, r, c = self.angle_rad, self.rate_rad_s, self.control_rad
        return np.array([self.airspeed_m_s, a, a, r, r, r, self.alpha_dot_rad_s, c, c, c])


def taylor_variables(x: StateLike) -> F64Array:
    """The Taylor model's variables z of a flight state x (:data:`STATE_COLUMNS` order): the rates p, q, r
    and α̇ divided by the airspeed [rad/m], everything else unchanged."""
    z = np.array(x, dtype=np.float64)
    z[list(_RATES)] /= z[0]
    return z


def flight_state(z: F64Array) -> F64Array:
    """The inverse of :func:`taylor_variables` (rows of z → rows of x)."""
    x = np.array(z, dtype=np.float64)
    x[..., list(_RATES)] *= x[..., :1]
    return x


class LinearizedAero:
    """Local Taylor model of :class:`StripAero` (see the module docstring), refreshed by :meth:`update`.

    ``matrix`` (6 + n_ports, :data:`N_FEATURES`) maps the features ``[1, Δz, Δz_i·Δz_j ...]`` (z: see
    :func:`taylor_variables`, expanded about ``z0``; products: :data:`QUADRATIC_TERMS`) to the
    coefficients (first 6 rows) and the port Cp (the remaining rows). With a slipstream (an as-built
    evaluator, :attr:`StripAero.has_slipstream`) a second block of as many rows holds the change per unit
    thrust coefficient T_c = T/(q̄·A_disk): C = (coeff_matrix + T_c·slip_coeff_matrix)·features.
    ``sep_deficit`` [rad] (the separation lag of an as-built aircraft) is subtracted from Δα in the α²
    feature only: the quadratic term carries the separation onset, which lags the attached flow.
    """

    def __init__(
        self, exact: StripAero, steps: LinearizationSteps | None = None, bounds: ReexpansionBounds | None = None
    ) -> None:
        self.exact = exact
        self.steps = (steps or LinearizationSteps()).vector()
        self._bounds = (bounds or ReexpansionBounds()).vector().tolist()
        self.z0: tuple[float, ...] = ()
        self.x0: tuple[float, ...] = ()
        n = 6 + exact.n_ports
        self.has_slipstream = exact.has_slipstream
        self.matrix = np.zeros((2 * n if self.has_slipstream else n, N_FEATURES))
        self.coeff_matrix = self.matrix[:6]
        self.port_matrix = self.matrix[6:n]
        self.slip_coeff_matrix = self.matrix[n : n + 6]
        self.slip_port_matrix = self.matrix[n + 6 :]
        # the hot loop's one product: coefficients, then (with a slipstream) their change per unit T_c
        self.force_rows = np.zeros((12 if self.has_slipstream else 6, N_FEATURES))
        self.updates = 0
        index = {row: j for j, row in enumerate(_BATCH)}
        self._fuselage_index = np.array([index[_fuselage_source(row)] for row in _BATCH], dtype=np.int64)

    def update(self, x0: StateLike) -> None:
        """Re-expand around the flight state ``x0`` (10 values in :data:`STATE_COLUMNS` order)."""
        z = taylor_variables(x0)
        h = self.steps.copy()
        h[list(_RATES)] /= z[0]  # the physical rate steps, in reduced-rate units
        batch = np.tile(z, (len(_BATCH), 1))
        for j, row in enumerate(_BATCH):
            for i, sign in row:
                batch[j, i] += sign * h[i]
        states = FlightStates.from_array(flight_state(batch))
        y = self.exact.outputs(states, fuselage_index=self._fuselage_index)  # (rows, 6 + P [+ 6 + P])
        at = {row: y[j] for j, row in enumerate(_BATCH)}
        y0 = at[()]
        mat = np.empty((y.shape[1], N_FEATURES))
        mat[:, 0] = y0
        for i in range(N_STATE):
            plus = at[((i, 1.0),)]
            if i in _CENTRAL:
                mat[:, 1 + i] = (plus - at[((i, -1.0),)]) / (2.0 * h[i])
            else:
                mat[:, 1 + i] = (plus - y0) / h[i]
        for k, (i, j) in enumerate(QUADRATIC_TERMS):
            col = 1 + N_STATE + k
            if i == j:
                mat[:, col] = 0.5 * (at[((i, 1.0),)] - 2.0 * y0 + at[((i, -1.0),)]) / (h[i] * h[i])
            else:
                mat[:, col] = (at[((i, 1.0), (j, 1.0))] - at[((i, 1.0),)] - at[((j, 1.0),)] + y0) / (h[i] * h[j])
        self.matrix[...] = mat
        self.force_rows[:6] = self.coeff_matrix
        if self.has_slipstream:
            self.force_rows[6:] = self.slip_coeff_matrix
        self.z0 = tuple(float(v) for v in z)
        self.x0 = tuple(float(v) for v in x0)
        self.updates += 1

    def out_of_bounds(self, x: StateLike) -> bool:
        """Whether flight state ``x`` is farther from the expansion point than :class:`ReexpansionBounds`."""
        # an explicit loop, not any(generator): this runs every physics step
        for a, b, lim in zip(x, self.x0, self._bounds, strict=True):  # noqa: SIM110
            if abs(a - b) > lim:
                return True
        return False

    def features(self, x: StateLike, sep_deficit: float = 0.0) -> F64Array:
        """The feature vector [1, Δz, Δz_i·Δz_j ...] of a flight state relative to the expansion point
        (``sep_deficit`` [rad]: see the class docstring)."""
        f = np.empty(N_FEATURES)
        f[0] = 1.0
        d = taylor_variables(x) - np.asarray(self.z0)
        f[1 : N_STATE + 1] = d
        for k, (i, j) in enumerate(QUADRATIC_TERMS):
            if i == j == _I_ALPHA:
                f[1 + N_STATE + k] = (d[i] - sep_deficit) ** 2
            else:
                f[1 + N_STATE + k] = d[i] * d[j]
        return f

    def coeffs(self, x: StateLike, thrust_coeff: float = 0.0, sep_deficit: float = 0.0) -> F64Array:
        """Taylor-model coefficients (6,) at flight state ``x`` and thrust coefficient T_c (slipstream)."""
        f = self.features(x, sep_deficit)
        c = self.coeff_matrix @ f
        if self.has_slipstream:
            c = c + thrust_coeff * (self.slip_coeff_matrix @ f)
        return np.asarray(c)

    def ports_cp(self, x: StateLike, thrust_coeff: float = 0.0, sep_deficit: float = 0.0) -> F64Array:
        """Taylor-model port Cp (n_ports,) at flight state ``x`` and thrust coefficient T_c."""
        f = self.features(x, sep_deficit)
        cp = self.port_matrix @ f
        if self.has_slipstream:
            cp = cp + thrust_coeff * (self.slip_port_matrix @ f)
        return np.asarray(cp)
