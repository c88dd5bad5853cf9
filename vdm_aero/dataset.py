"""The data set format ``vdm-aero-dataset/1``: load, validate, write.

A data set is a directory holding ``dataset.yaml`` and ``.npy`` arrays (full contract in
``docs/formats.md``). SI units everywhere; body frame FRD (x forward, y right, z down) with its origin at
the moment reference point; surface normals point INTO the body.

=================  =============================  =====================================================
file               dtype, shape                   meaning
=================  =============================  =====================================================
``cp.npy``         float32/float64 (M, N)         pressure coefficient per snapshot and surface point
``points.npy``     float64 (N, 3)                 surface point positions [m]
``normals.npy``    float64 (N, 3)                 unit normals pointing INTO the body
``areas.npy``      float64 (N,)                   surface area of each point [m²]
``alpha.npy``      float64 (M,)                   angle of attack [rad]
``t.npy``          float64 (M,)                   time within its case [s]
``case.npy``       int64 (M,)                     case id of each snapshot
``coeffs.npy``     float64 (M, 3) or (M, 6)       optional ground-truth body-axis coefficients
``beta.npy``       float64 (M,)                   optional sideslip [rad]
=================  =============================  =====================================================

Readers are strict about the dtype *kind* (floating point for float arrays, integer for ``case.npy``) but
accept any width: float32 arrays are upcast to float64 (``cp`` keeps its own dtype and stays
memory-mapped), int32 case ids are upcast to int64.

Every fault a user can cause raises :class:`~vdm_aero.errors.DatasetError` with a one-line message
that names the file and the fault.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Final

import numpy as np
import yaml
from numpy.typing import ArrayLike, DTypeLike, NDArray

from vdm_aero._typing import BoolArray, F64Array, FloatArray, IntArray
from vdm_aero.atomic import install_directory
from vdm_aero.coefficients import force_moment_matrix
from vdm_aero.errors import DatasetError

__all__ = [
    "FORMAT",
    "Case",
    "Dataset",
    "DatasetMemmapWriter",
    "Reference",
    "create_dataset_memmap",
    "default_point_names",
    "load_dataset",
    "read_columns",
    "validate_dataset",
    "write_dataset",
]

FORMAT: Final = "vdm-aero-dataset/1"
"""The value of ``format:`` in ``dataset.yaml``."""

YAML_FILE: Final = "dataset.yaml"
REQUIRED_ARRAYS: Final = ("cp", "points", "normals", "areas", "alpha", "t", "case")
OPTIONAL_ARRAYS: Final = ("coeffs", "beta")

NORMAL_TOLERANCE: Final = 1e-6
"""Largest accepted | ‖n‖ − 1 | of a surface normal."""

CHUNK_ELEMENTS: Final = 1 << 21
"""Elements of ``cp`` processed per chunk (2 Mi elements = 16 MiB in float64), bounding memory use."""

_RESERVED_KEYS: Final = ("format", "name", "source", "reference", "cases", "point_names")
_REFERENCE_KEYS: Final = ("area_m2", "chord_m", "span_m")
_CASE_FLOAT_KEYS: Final = ("freq_hz", "alpha0_deg", "amplitude_deg", "speed_m_s")

AIRFRAME_STATE_COLUMNS: Final = (
    "airspeed_m_s",
    "alpha_rad",
    "beta_rad",
    "p_rad_s",
    "q_rad_s",
    "r_rad_s",
    "alpha_dot_rad_s",
    "aileron_rad",
    "elevator_rad",
    "rudder_rad",
)
"""Column order of the flight-state table ``states.npy`` of an airframe data set (docs/formats.md)."""
STATES_FILE: Final = "states.npy"


# --------------------------------------------------------------------------------------------------
# Value types
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reference:
    """Reference geometry for coefficients: area [m²], chord [m] (pitch) and span [m] (roll, yaw)."""

    area_m2: float
    chord_m: float
    span_m: float

    def to_dict(self) -> dict[str, float]:
        """Return the ``reference:`` mapping of ``dataset.yaml``."""
        return {"area_m2": float(self.area_m2), "chord_m": float(self.chord_m), "span_m": float(self.span_m)}


@dataclass(frozen=True)
class Case:
    """One case (a run of snapshots, e.g. one pitch oscillation) listed in ``dataset.yaml``.

    ``meta`` holds every key of the case other than ``id`` and ``name``; it is preserved verbatim on a
    round trip. The well-known keys are exposed as properties.
    """

    id: int
    name: str
    meta: Mapping[str, Any] = field(default_factory=dict)

    @property
    def freq_hz(self) -> float | None:
        """Oscillation frequency [Hz], if given."""
        return _opt_float(self.meta.get("freq_hz"))

    @property
    def alpha0_deg(self) -> float | None:
        """Mean angle of attack [deg], if given."""
        return _opt_float(self.meta.get("alpha0_deg"))

    @property
    def amplitude_deg(self) -> float | None:
        """Oscillation amplitude of the angle of attack [deg], if given."""
        return _opt_float(self.meta.get("amplitude_deg"))

    @property
    def speed_m_s(self) -> float | None:
        """Freestream speed [m/s], if given."""
        return _opt_float(self.meta.get("speed_m_s"))

    def to_dict(self) -> dict[str, Any]:
        """Return the case as its ``dataset.yaml`` mapping: ``id``, ``name`` then ``meta`` in order."""
        return {"id": self.id, "name": self.name, **self.meta}


def default_point_names(n_points: int) -> tuple[str, ...]:
    """Names used when ``dataset.yaml`` has no ``point_names``: ``p0000``, ``p0001``, … (≥ 4 digits)."""
    width = max(4, len(str(max(n_points - 1, 0))))
    return tuple(f"p{i:0{width}d}" for i in range(n_points))


@dataclass(frozen=True, eq=False)
class Dataset:
    """A ``vdm-aero-dataset/1`` data set in memory (``cp`` possibly memory-mapped).

    Construction only normalises types (lists to tuples, float arrays other than ``cp`` to float64,
    integer case ids to int64, empty ``point_names`` to the defaults); it does not validate. Call
    :func:`validate_dataset` (done by :func:`load_dataset` and :func:`write_dataset`).

    Attributes:
        name: data set name.
        source: provenance text (free form).
        reference: reference area/chord/span.
        cases: the cases listed in ``dataset.yaml``.
        cp: (M, N) pressure coefficients, float32 or float64, possibly a read-only ``np.memmap``.
        points: (N, 3) surface point positions [m] (FRD, origin = moment reference point).
        normals: (N, 3) unit normals pointing INTO the body.
        areas: (N,) surface area of each point [m²].
        alpha: (M,) angle of attack [rad].
        t: (M,) time within its case [s].
        case: (M,) case id of each snapshot.
        coeffs: ``None`` or (M, 3)/(M, 6) ground-truth body-axis coefficients (incl. viscous parts).
        beta: ``None`` or (M,) sideslip [rad].
        point_names: (N,) names of the surface points / pressure ports.
        extra: unknown top-level ``dataset.yaml`` keys, preserved on a round trip.
        path: the directory the data set was loaded from, or ``None``.
    """

    name: str
    source: str
    reference: Reference
    cases: tuple[Case, ...]
    cp: FloatArray
    points: F64Array
    normals: F64Array
    areas: F64Array
    alpha: F64Array
    t: F64Array
    case: IntArray
    coeffs: F64Array | None = None
    beta: F64Array | None = None
    point_names: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "cases", tuple(self.cases))
        set_(self, "extra", dict(self.extra))
        if self.path is not None:
            set_(self, "path", Path(self.path))
        if not isinstance(self.cp, np.ndarray):
            set_(self, "cp", np.asarray(self.cp))
        for key in ("points", "normals", "areas", "alpha", "t", "coeffs", "beta"):
            value = getattr(self, key)
            if value is not None:
                set_(self, key, _as_float64(value))
        set_(self, "case", _as_int64(self.case))
        names = tuple(self.point_names)
        if not names:
            names = default_point_names(self.points.shape[0] if self.points.ndim >= 1 else 0)
        set_(self, "point_names", names)

    # -- sizes ---------------------------------------------------------------------------------------

    @property
    def n_snapshots(self) -> int:
        """M, the number of snapshots (rows of ``cp``)."""
        return int(self.cp.shape[0])

    @property
    def n_points(self) -> int:
        """N, the number of surface points (columns of ``cp``)."""
        return int(self.cp.shape[1])

    # -- cases ---------------------------------------------------------------------------------------

    def case_ids(self) -> tuple[int, ...]:
        """Ids of the cases listed in ``dataset.yaml``, in their listed order."""
        return tuple(c.id for c in self.cases)

    def case_mask(self, ids: Iterable[int]) -> BoolArray:
        """Return the (M,) mask of the snapshots that belong to any of ``ids``.

        Raises:
            DatasetError: if an id is not a case of this data set.
        """
        wanted = self._known_ids(ids)
        return np.isin(self.case, np.asarray(wanted, dtype=np.int64))

    def select_cases(self, ids: Sequence[int]) -> Dataset:
        """Return the data set restricted to the snapshots (rows) and case entries of ``ids``.

        Rows keep their order. When the selected rows are contiguous, ``cp`` stays a view (memory-mapped
        if it was); otherwise the selected rows are copied into memory. The result has ``path=None``.

        Raises:
            DatasetError: naming the ids that are not cases of this data set, or if the selection is empty.
        """
        wanted = set(self._known_ids(ids))
        if not wanted:
            raise DatasetError(f"{self._label(YAML_FILE)}: no case ids selected")
        rows = _rows_indexer(np.isin(self.case, np.fromiter(wanted, dtype=np.int64)))
        if isinstance(rows, slice) and rows.start == rows.stop:
            raise DatasetError(
                f"{self._label('case.npy')}: selected case ids {_fmt_ids(sorted(wanted))} have no snapshots"
            )
        return dataclasses.replace(
            self,
            cases=tuple(c for c in self.cases if c.id in wanted),
            cp=self.cp[rows],
            alpha=self.alpha[rows],
            t=self.t[rows],
            case=self.case[rows],
            coeffs=None if self.coeffs is None else self.coeffs[rows],
            beta=None if self.beta is None else self.beta[rows],
            path=None,
        )

    # -- points --------------------------------------------------------------------------------------

    def point_indices(self, names: Iterable[str]) -> IntArray:
        """Return the indices of the points called ``names`` (in the given order).

        Raises:
            DatasetError: naming the first unknown point name.
        """
        lookup = {n: i for i, n in enumerate(self.point_names)}
        out: list[int] = []
        for name in names:
            if name not in lookup:
                raise DatasetError(f"{self._label(YAML_FILE)}: unknown point name {name!r}")
            out.append(lookup[name])
        return np.asarray(out, dtype=np.int64)

    def select_points(self, idx: ArrayLike) -> Dataset:
        """Return the data set restricted to the surface points ``idx`` (columns of ``cp``).

        Args:
            idx: point indices (0 ≤ i < N, no duplicates; the order is kept) or an (N,) boolean mask.

        The subset's ``coeffs`` is set to this data set's :meth:`truth_coeffs` (M, 6), so the truth
        still describes the whole vehicle rather than the pressure integral over the selected points
        (computing it costs one chunked pass over ``cp``). The result has ``path=None``.

        Raises:
            DatasetError: on an out-of-range or duplicate index, a mask of the wrong length or an
                empty selection.
        """
        sel = np.asarray(idx)
        label = self._label("points.npy")
        n = self.n_points
        if sel.ndim != 1:
            raise DatasetError(f"{label}: point selection must be 1-D, got shape {sel.shape}")
        if sel.dtype.kind == "b":
            if sel.shape[0] != n:
                raise DatasetError(f"{label}: point mask has {sel.shape[0]} entries, expected N = {n}")
            sel = np.flatnonzero(sel)
        elif sel.size == 0:
            sel = sel.astype(np.int64)
        elif sel.dtype.kind not in "iu":
            raise DatasetError(f"{label}: point indices must be integers, got dtype {sel.dtype}")
        sel = sel.astype(np.int64)
        if sel.size == 0:
            raise DatasetError(f"{label}: no points selected")
        bad = (sel < 0) | (sel >= n)
        if bad.any():
            raise DatasetError(f"{label}: point index {int(sel[bad][0])} out of range for N = {n}")
        uniq, counts = np.unique(sel, return_counts=True)
        if (counts > 1).any():
            raise DatasetError(f"{label}: point index {int(uniq[counts > 1][0])} selected twice")
        return dataclasses.replace(
            self,
            cp=np.ascontiguousarray(self.cp[:, sel]),
            points=self.points[sel],
            normals=self.normals[sel],
            areas=self.areas[sel],
            coeffs=self.truth_coeffs(),
            point_names=tuple(self.point_names[int(i)] for i in sel),
            path=None,
        )

    # -- coefficients --------------------------------------------------------------------------------

    def force_matrix(self) -> F64Array:
        """The (6, N) float64 matrix ``S`` with ``coeffs = cp @ S.T`` (see :mod:`vdm_aero.coefficients`)."""
        return force_moment_matrix(self.points, self.normals, self.areas, self.reference)

    def pressure_coeffs(self, chunk_rows: int | None = None) -> F64Array:
        """Body-axis coefficients from the pressure integral, (M, 6) float64 ``cp @ S.T``.

        Computed ``chunk_rows`` rows at a time (default: about :data:`CHUNK_ELEMENTS` elements per
        chunk) so a memory-mapped float32 ``cp`` is never copied to float64 as a whole.
        """
        s_t = self.force_matrix().T  # (N, 6)
        m = self.n_snapshots
        step = _chunk_rows(self.n_points, chunk_rows)
        out = np.empty((m, 6), dtype=np.float64)
        for start in range(0, m, step):
            stop = min(start + step, m)
            block = np.asarray(self.cp[start:stop], dtype=np.float64)
            out[start:stop] = block @ s_t
            del block  # release before the next chunk is converted: peak memory ≈ one chunk
        return out

    def truth_coeffs(self, chunk_rows: int | None = None) -> F64Array:
        """Ground-truth body-axis coefficients, (M, 6) float64.

        ``coeffs`` when it has 6 columns; when it has 3, its forces with the pressure-integral moments;
        when absent, :meth:`pressure_coeffs` (the pressure integral is the truth).
        """
        if self.coeffs is None:
            return self.pressure_coeffs(chunk_rows)
        if self.coeffs.shape[1] == 6:
            return np.array(self.coeffs, dtype=np.float64)
        out = self.pressure_coeffs(chunk_rows)
        out[:, :3] = self.coeffs
        return out

    # -- helpers -------------------------------------------------------------------------------------

    def _label(self, filename: str) -> str:
        return _label(self.path, filename)

    def _known_ids(self, ids: Iterable[int]) -> list[int]:
        wanted = [int(i) for i in ids]
        known = set(self.case_ids())
        unknown = sorted({i for i in wanted if i not in known})
        if unknown:
            word = "id" if len(unknown) == 1 else "ids"
            raise DatasetError(
                f"{self._label(YAML_FILE)}: unknown case {word} {_fmt_ids(unknown)} "
                f"(data set {self.name!r} has case ids {_fmt_ids(sorted(known))})"
            )
        return wanted


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------


def validate_dataset(ds: Dataset, *, check_values: bool = True) -> None:
    """Check a data set in memory against the ``vdm-aero-dataset/1`` contract.

    Messages name the file (``cp.npy``, ``dataset.yaml`` …, prefixed with ``ds.path`` when set).

    Args:
        ds: the data set.
        check_values: when False, skip the NaN/Inf scan of ``cp`` (the only O(M·N) check); every other
            check (metadata, dtypes, shapes, finite small arrays, unit normals, areas ≥ 0, case ids) runs.

    Raises:
        DatasetError: on the first fault found.
    """
    _validate_metadata(ds)
    _validate_arrays(ds, check_values=check_values)
    _validate_point_names(ds)


def _validate_metadata(ds: Dataset) -> None:
    label = _label(ds.path, YAML_FILE)
    if not isinstance(ds.name, str) or not ds.name:
        raise DatasetError(f"{label}: name must be a non-empty string, got {ds.name!r}")
    if not isinstance(ds.source, str):
        raise DatasetError(f"{label}: source must be a string, got {type(ds.source).__name__}")
    if not isinstance(ds.reference, Reference):
        raise DatasetError(f"{label}: reference must be a Reference, got {type(ds.reference).__name__}")
    for key in _REFERENCE_KEYS:
        _positive(label, f"reference.{key}", getattr(ds.reference, key))
    if not ds.cases:
        raise DatasetError(f"{label}: cases is empty, expected at least one case")
    seen: set[int] = set()
    for i, c in enumerate(ds.cases):
        where = f"cases[{i}]"
        if not isinstance(c, Case):
            raise DatasetError(f"{label}: {where} must be a Case, got {type(c).__name__}")
        if not _is_int(c.id):
            raise DatasetError(f"{label}: {where}.id must be an integer, got {c.id!r}")
        if not isinstance(c.name, str):
            raise DatasetError(f"{label}: {where}.name must be a string, got {c.name!r}")
        _check_case_meta(label, where, c.meta)
        if c.id in seen:
            raise DatasetError(f"{label}: duplicate case id {c.id} in cases")
        seen.add(c.id)
    for key in ds.extra:
        if not isinstance(key, str):
            raise DatasetError(f"{label}: top-level key {key!r} is not a string")
        if key in _RESERVED_KEYS:
            raise DatasetError(f"{label}: extra key {key!r} clashes with a format key")


def _check_case_meta(label: str, where: str, meta: Mapping[str, Any]) -> None:
    if not isinstance(meta, Mapping):
        raise DatasetError(f"{label}: {where} meta must be a mapping, got {type(meta).__name__}")
    for key, value in meta.items():
        if not isinstance(key, str):
            raise DatasetError(f"{label}: {where} key {key!r} is not a string")
        if key in ("id", "name"):
            raise DatasetError(f"{label}: {where} meta must not contain {key!r}")
        if key in _CASE_FLOAT_KEYS and value is not None and _to_float(value) is None:
            raise DatasetError(f"{label}: {where}.{key} must be a number, got {value!r}")


def _validate_arrays(ds: Dataset, *, check_values: bool) -> None:
    def lab(name: str) -> str:
        return _label(ds.path, f"{name}.npy")

    # dtype kinds first: a wrong kind makes the other messages misleading
    for name in ("points", "normals", "areas", "alpha", "t", "cp", "coeffs", "beta"):
        arr = getattr(ds, name)
        if arr is not None and (not isinstance(arr, np.ndarray) or arr.dtype.kind != "f"):
            dtype = arr.dtype if isinstance(arr, np.ndarray) else type(arr).__name__
            raise DatasetError(f"{lab(name)}: dtype {dtype}, expected a floating-point array (float32 or float64)")
    if not isinstance(ds.case, np.ndarray) or ds.case.dtype.kind not in "iu":
        dtype = ds.case.dtype if isinstance(ds.case, np.ndarray) else type(ds.case).__name__
        raise DatasetError(f"{lab('case')}: dtype {dtype}, expected an integer array (int32 or int64)")

    _check_ndim(lab("points"), ds.points, 2, "(N, 3)")
    if ds.points.shape[1] != 3:
        raise DatasetError(f"{lab('points')}: shape {ds.points.shape}, expected (N, 3)")
    n = ds.points.shape[0]
    if n == 0:
        raise DatasetError(f"{lab('points')}: no surface points (shape {ds.points.shape})")
    _check_ndim(lab("cp"), ds.cp, 2, "(M, N)")
    m = ds.cp.shape[0]
    if ds.cp.shape[1] != n:
        raise DatasetError(f"{lab('cp')}: shape {ds.cp.shape}, expected (M, N) = {(m, n)} to match points.npy")
    if m == 0:
        raise DatasetError(f"{lab('cp')}: no snapshots (shape {ds.cp.shape})")
    _check_shape(lab("normals"), ds.normals, (n, 3), "(N, 3)", "points.npy")
    _check_shape(lab("areas"), ds.areas, (n,), "(N,)", "points.npy")
    _check_shape(lab("alpha"), ds.alpha, (m,), "(M,)", "cp.npy")
    _check_shape(lab("t"), ds.t, (m,), "(M,)", "cp.npy")
    _check_shape(lab("case"), ds.case, (m,), "(M,)", "cp.npy")
    if ds.beta is not None:
        _check_shape(lab("beta"), ds.beta, (m,), "(M,)", "cp.npy")
    if ds.coeffs is not None:
        _check_ndim(lab("coeffs"), ds.coeffs, 2, "(M, 3) or (M, 6)")
        if ds.coeffs.shape not in ((m, 3), (m, 6)):
            raise DatasetError(
                f"{lab('coeffs')}: shape {ds.coeffs.shape}, expected (M, 3) or (M, 6) with M = {m} to match cp.npy"
            )

    for name in ("points", "normals", "areas", "alpha", "t", "coeffs", "beta"):
        arr = getattr(ds, name)
        if arr is not None:
            _check_finite(lab(name), arr)
    if check_values:
        _check_finite_chunked(lab("cp"), ds.cp)

    norms = np.linalg.norm(ds.normals, axis=1)
    dev = np.abs(norms - 1.0)
    bad = dev > NORMAL_TOLERANCE
    if bad.any():
        worst = int(np.argmax(dev))
        count = int(bad.sum())
        what = "normal is" if count == 1 else "normals are"
        raise DatasetError(
            f"{lab('normals')}: {count} {what} not unit length (worst |n| = {norms[worst]:.6g} at index {worst})"
        )
    negative = ds.areas < 0.0
    if negative.any():
        first = int(np.argmax(negative))
        count = int(negative.sum())
        what = "negative area" if count == 1 else "negative areas"
        raise DatasetError(f"{lab('areas')}: {count} {what} (first at index {first}: {ds.areas[first]:.6g})")

    known = np.asarray([c.id for c in ds.cases], dtype=np.int64)
    unlisted = ~np.isin(ds.case, known)
    if unlisted.any():
        ids = sorted({int(i) for i in np.unique(ds.case[unlisted])})
        first = int(np.argmax(unlisted))
        what = f"case id {ids[0]} is" if len(ids) == 1 else f"case ids {_fmt_ids(ids)} are"
        raise DatasetError(f"{lab('case')}: {what} not listed in dataset.yaml cases (first at index {first})")


def _validate_point_names(ds: Dataset) -> None:
    label = _label(ds.path, YAML_FILE)
    n = ds.n_points
    if len(ds.point_names) != n:
        raise DatasetError(
            f"{label}: point_names has {len(ds.point_names)} entries, expected N = {n} to match points.npy"
        )
    first_index: dict[str, int] = {}
    for i, name in enumerate(ds.point_names):
        if not isinstance(name, str) or not name:
            raise DatasetError(f"{label}: point_names[{i}] must be a non-empty string, got {name!r}")
        if name in first_index:
            raise DatasetError(
                f"{label}: duplicate point name {name!r} in point_names (indices {first_index[name]} and {i})"
            )
        first_index[name] = i


def _check_ndim(label: str, arr: NDArray[Any], ndim: int, desc: str) -> None:
    if arr.ndim != ndim:
        raise DatasetError(f"{label}: {arr.ndim}-D array with shape {arr.shape}, expected {ndim}-D {desc}")


def _check_shape(label: str, arr: NDArray[Any], expected: tuple[int, ...], desc: str, other: str) -> None:
    _check_ndim(label, arr, len(expected), desc)
    if arr.shape != expected:
        raise DatasetError(f"{label}: shape {arr.shape}, expected {desc} = {expected} to match {other}")


def _fmt_index(index: Sequence[int]) -> str:
    return str(int(index[0])) if len(index) == 1 else "(" + ", ".join(str(int(i)) for i in index) + ")"


def _nonfinite_message(label: str, count: int, first: Sequence[int]) -> str:
    what = "NaN/Inf value" if count == 1 else "NaN/Inf values"
    return f"{label}: {count} {what} (first at index {_fmt_index(first)})"


def _check_finite(label: str, arr: FloatArray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        first = np.argwhere(bad)[0]
        raise DatasetError(_nonfinite_message(label, int(bad.sum()), [int(i) for i in first]))


def _check_finite_chunked(label: str, cp: FloatArray) -> None:
    """NaN/Inf scan of an (M, N) array, a bounded number of rows at a time."""
    m, n = cp.shape
    step = _chunk_rows(n, None)
    count = 0
    first: list[int] | None = None
    for start in range(0, m, step):
        finite = np.isfinite(cp[start : start + step])
        k = finite.size - int(np.count_nonzero(finite))
        if k:
            if first is None:
                row, col = np.argwhere(~finite)[0]
                first = [start + int(row), int(col)]
            count += k
        del finite
    if first is not None:
        raise DatasetError(_nonfinite_message(label, count, first))


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------


def load_dataset(path: str | os.PathLike[str], *, mmap: bool = True, check_values: bool = True) -> Dataset:
    """Load and validate a ``vdm-aero-dataset/1`` directory.

    Args:
        path: the data set directory.
        mmap: memory-map ``cp.npy`` read-only (the other arrays are small and loaded fully).
        check_values: scan ``cp`` for NaN/Inf (in row chunks; see :func:`validate_dataset`).

    Returns:
        The data set; float arrays other than ``cp`` are float64, ``case`` is int64, ``cp`` keeps its
        dtype (and is a read-only ``np.memmap`` when ``mmap``).

    Raises:
        DatasetError: one line naming the file and the fault.
    """
    root = Path(path)
    if not root.exists():
        raise DatasetError(f"{root}: data set directory does not exist")
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory (a data set is a directory with {YAML_FILE})")
    yaml_path = root / YAML_FILE
    if not yaml_path.is_file():
        raise DatasetError(f"{yaml_path}: missing required file")
    meta = _parse_yaml(_read_yaml(yaml_path), str(yaml_path))

    for name in REQUIRED_ARRAYS:
        file = root / f"{name}.npy"
        if not file.is_file():
            raise DatasetError(f"{file}: missing required file")
    arrays = {name: _load_npy(root / f"{name}.npy", mmap=mmap and name == "cp") for name in REQUIRED_ARRAYS}
    optional = {
        name: _load_npy(root / f"{name}.npy", mmap=False) if (root / f"{name}.npy").exists() else None
        for name in OPTIONAL_ARRAYS
    }
    ds = Dataset(
        name=meta["name"],
        source=meta["source"],
        reference=meta["reference"],
        cases=meta["cases"],
        cp=arrays["cp"],
        points=arrays["points"],
        normals=arrays["normals"],
        areas=arrays["areas"],
        alpha=arrays["alpha"],
        t=arrays["t"],
        case=arrays["case"],
        coeffs=optional["coeffs"],
        beta=optional["beta"],
        point_names=meta["point_names"],
        extra=meta["extra"],
        path=root,
    )
    validate_dataset(ds, check_values=check_values)
    return ds


def _read_yaml(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read ({_one_line(exc)})") from exc
    try:
        return yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = exc.problem or exc.context or "invalid YAML"
        raise DatasetError(f"{path}: YAML syntax error{where}: {_one_line(problem)}") from exc
    except yaml.YAMLError as exc:
        raise DatasetError(f"{path}: YAML syntax error: {_one_line(exc)}") from exc


def _parse_yaml(doc: Any, label: str) -> dict[str, Any]:
    """Turn the parsed ``dataset.yaml`` into typed metadata, checking its structure."""
    if doc is None:
        raise DatasetError(f"{label}: file is empty, expected a mapping with format: {FORMAT}")
    if not isinstance(doc, dict):
        raise DatasetError(f"{label}: top level must be a mapping, got {type(doc).__name__}")
    for key in doc:
        if not isinstance(key, str):
            raise DatasetError(f"{label}: top-level key {key!r} is not a string")
    if "format" not in doc:
        raise DatasetError(f"{label}: missing required key format (expected {FORMAT})")
    if doc["format"] != FORMAT:
        raise DatasetError(f"{label}: format {doc['format']!r} is not supported (expected {FORMAT})")
    for key in ("name", "reference", "cases"):
        if key not in doc:
            raise DatasetError(f"{label}: missing required key {key}")

    name = doc["name"]
    if not isinstance(name, str) or not name:
        raise DatasetError(f"{label}: name must be a non-empty string, got {name!r}")
    source = doc.get("source")
    if source is None:
        source = ""
    if not isinstance(source, str):
        raise DatasetError(f"{label}: source must be a string, got {type(source).__name__}")

    reference = _parse_reference(doc["reference"], label)

    raw_cases = doc["cases"]
    if not isinstance(raw_cases, list):
        raise DatasetError(f"{label}: cases must be a list, got {type(raw_cases).__name__}")
    cases = tuple(_parse_case(raw, f"cases[{i}]", label) for i, raw in enumerate(raw_cases))

    point_names: tuple[str, ...] = ()
    raw_names = doc.get("point_names")
    if raw_names is not None:
        if not isinstance(raw_names, list):
            raise DatasetError(f"{label}: point_names must be a list, got {type(raw_names).__name__}")
        for i, item in enumerate(raw_names):
            if not isinstance(item, str) or not item:
                raise DatasetError(f"{label}: point_names[{i}] must be a non-empty string, got {item!r}")
        point_names = tuple(raw_names)
        if not point_names:
            raise DatasetError(f"{label}: point_names is empty (omit the key for default names)")

    extra = {k: v for k, v in doc.items() if k not in _RESERVED_KEYS}
    return {
        "name": name,
        "source": source,
        "reference": reference,
        "cases": cases,
        "point_names": point_names,
        "extra": extra,
    }


def _parse_reference(raw: Any, label: str) -> Reference:
    if not isinstance(raw, Mapping):
        raise DatasetError(f"{label}: reference must be a mapping with {', '.join(_REFERENCE_KEYS)}")
    for key in raw:
        if key not in _REFERENCE_KEYS:
            raise DatasetError(f"{label}: unknown key reference.{key} (expected {', '.join(_REFERENCE_KEYS)})")
    values: dict[str, float] = {}
    for key in _REFERENCE_KEYS:
        if key not in raw:
            raise DatasetError(f"{label}: missing required key reference.{key}")
        values[key] = _positive(label, f"reference.{key}", raw[key])
    return Reference(**values)


def _parse_case(raw: Any, where: str, label: str) -> Case:
    if isinstance(raw, Case):
        return raw
    if not isinstance(raw, Mapping):
        raise DatasetError(f"{label}: {where} must be a mapping with id and name, got {type(raw).__name__}")
    for key in ("id", "name"):
        if key not in raw:
            raise DatasetError(f"{label}: {where}: missing required key {key}")
    case_id = raw["id"]
    if not _is_int(case_id):
        raise DatasetError(f"{label}: {where}.id must be an integer, got {case_id!r}")
    name = raw["name"]
    if not isinstance(name, str):
        raise DatasetError(f"{label}: {where}.name must be a string, got {name!r}")
    meta = {k: v for k, v in raw.items() if k not in ("id", "name")}
    _check_case_meta(label, where, meta)
    return Case(id=int(case_id), name=name, meta=meta)


def _load_npy(path: Path, *, mmap: bool) -> NDArray[Any]:
    try:
        try:
            arr = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
        except ValueError:
            if not mmap:
                raise
            arr = np.load(path, allow_pickle=False)  # e.g. an empty array cannot be memory-mapped
    except (OSError, ValueError, EOFError) as exc:
        raise DatasetError(f"{path}: not a readable .npy file ({_one_line(exc)})") from exc
    if not isinstance(arr, np.ndarray):
        if hasattr(arr, "close"):
            arr.close()
        raise DatasetError(f"{path}: not a readable .npy file (an .npz archive, not an .npy array)")
    return arr


def read_columns(path: str | os.PathLike[str], columns: IntArray, *, chunk_rows: int = 256) -> NDArray[Any]:
    """Columns ``columns`` of a 2-D ``.npy`` array (rows × columns), read in chunks of rows with plain reads.

    Why not a memory map: every page of a mapped file that the process touches counts in its resident memory
    until the map is closed, and the columns of a row-major ``cp`` are spread over every page of it. The
    service reads twelve port columns of a 50 MB design data set: mapped, that was its peak RSS (+48 MB,
    docs/performance.md); read in chunks, +5 MB at most.

    Raises:
        DatasetError: naming the file, when it is not a readable 2-D .npy array or a column is out of range.
    """
    path = Path(path)
    cols = np.asarray(columns, dtype=np.int64)
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            if len(shape) != 2 or dtype.hasobject:
                raise DatasetError(f"{path}: expected a 2-D numeric array, got shape {shape} of {dtype}")
            n_rows, n_cols = shape
            if cols.size and (cols.min() < 0 or cols.max() >= n_cols):
                raise DatasetError(f"{path}: column {int(cols.max())} out of range ({n_cols} columns)")
            start, item = f.tell(), dtype.itemsize
            out = np.empty((n_rows, cols.size), dtype=dtype)
            if fortran:  # a column is contiguous
                for j, c in enumerate(cols):
                    f.seek(start + int(c) * n_rows * item)
                    col = np.fromfile(f, dtype=dtype, count=n_rows)
                    if col.size != n_rows:
                        raise DatasetError(f"{path}: truncated (column {int(c)} of {n_cols})")
                    out[:, j] = col
            else:
                for r0 in range(0, n_rows, chunk_rows):
                    r1 = min(r0 + chunk_rows, n_rows)
                    f.seek(start + r0 * n_cols * item)
                    block = np.fromfile(f, dtype=dtype, count=(r1 - r0) * n_cols)
                    if block.size != (r1 - r0) * n_cols:
                        raise DatasetError(f"{path}: truncated (row {r0 + block.size // max(n_cols, 1)} of {n_rows})")
                    out[r0:r1] = block.reshape(r1 - r0, n_cols)[:, cols]
    except (OSError, ValueError, EOFError) as exc:
        raise DatasetError(f"{path}: not a readable .npy file ({_one_line(exc)})") from exc
    return out


# --------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------


def write_dataset(path: str | os.PathLike[str], ds_or_fields: Dataset | Mapping[str, Any]) -> Path:
    """Validate and write a data set directory atomically.

    The files are written into a temporary sibling directory that is then renamed into place. An
    existing ``path`` is replaced only if it is itself a ``vdm-aero-dataset/1`` data set (or an empty
    directory); anything else is refused. Writing a data set back over the directory it is
    memory-mapped from is safe.

    Args:
        path: destination directory (parents are created).
        ds_or_fields: a :class:`Dataset`, or a mapping of its fields where ``reference`` may be a mapping
            and ``cases`` a list of mappings (as in ``dataset.yaml``).

    Returns:
        The destination directory.

    Raises:
        DatasetError: if the data set is invalid, the destination is not replaceable, or writing fails.
    """
    ds = ds_or_fields if isinstance(ds_or_fields, Dataset) else _dataset_from_fields(ds_or_fields)
    validate_dataset(ds)
    dest = Path(path)
    _check_destination(dest)
    tmp = _make_temp_dir(dest, "tmp")
    try:
        _write_cp(tmp / "cp.npy", ds.cp)
        _write_small_files(tmp, ds)
        install_directory(tmp, dest)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise DatasetError(f"{dest}: cannot write data set ({_one_line(exc)})") from exc
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest


def _dataset_from_fields(fields: Mapping[str, Any]) -> Dataset:
    data = dict(fields)
    for key in ("name", "reference", "cases", *REQUIRED_ARRAYS):
        if key not in data:
            raise DatasetError(f"missing data set field {key!r}")
    unknown = set(data) - {f.name for f in dataclasses.fields(Dataset)}
    if unknown:
        raise DatasetError(f"unknown data set field(s) {', '.join(sorted(unknown))}")
    data.setdefault("source", "")
    reference = data["reference"]
    if not isinstance(reference, Reference):
        data["reference"] = _parse_reference(reference, YAML_FILE)
    cases = data["cases"]
    if not isinstance(cases, Sequence) or isinstance(cases, str):
        raise DatasetError(f"{YAML_FILE}: cases must be a list, got {type(cases).__name__}")
    data["cases"] = tuple(_parse_case(c, f"cases[{i}]", YAML_FILE) for i, c in enumerate(cases))
    if data.get("point_names") is None:
        data["point_names"] = ()
    if data.get("extra") is None:
        data["extra"] = {}
    return Dataset(**data)


def _is_our_dataset(path: Path) -> bool:
    try:
        doc = yaml.safe_load((path / YAML_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT


def _check_destination(dest: Path) -> None:
    if not (dest.exists() or dest.is_symlink()):
        return
    if not dest.is_dir():
        raise DatasetError(f"{dest}: exists and is not a directory; refusing to overwrite it")
    if not any(dest.iterdir()) or _is_our_dataset(dest):
        return
    raise DatasetError(
        f"{dest}: refusing to overwrite an existing directory that is not a {FORMAT} data set "
        f"(no {YAML_FILE} with format: {FORMAT})"
    )


def _make_temp_dir(dest: Path, kind: str) -> Path:
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{dest.name}.{kind}-", dir=dest.parent))
    except OSError as exc:
        raise DatasetError(f"{dest}: cannot create a temporary directory ({_one_line(exc)})") from exc


def _native_float_dtype(dtype: np.dtype[Any]) -> np.dtype[Any]:
    return np.dtype(f"f{dtype.itemsize}")


def _write_cp(file: Path, cp: FloatArray) -> None:
    """Write ``cp`` keeping its float width, copying a bounded number of rows at a time."""
    m, n = cp.shape
    out = np.lib.format.open_memmap(file, mode="w+", dtype=_native_float_dtype(cp.dtype), shape=(m, n))
    try:
        step = _chunk_rows(n, None)
        for start in range(0, m, step):
            out[start : start + step] = cp[start : start + step]
        out.flush()
    finally:
        del out


def _yaml_document(ds: Dataset) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "format": FORMAT,
        "name": ds.name,
        "source": ds.source,
        "reference": ds.reference.to_dict(),
        "cases": [c.to_dict() for c in ds.cases],
    }
    if ds.point_names != default_point_names(ds.n_points):
        doc["point_names"] = list(ds.point_names)
    doc.update(ds.extra)
    return doc


def _write_small_files(directory: Path, ds: Dataset) -> None:
    """Write ``dataset.yaml`` and every array except ``cp.npy`` into ``directory``."""
    try:
        text = yaml.safe_dump(
            to_plain(_yaml_document(ds)), sort_keys=False, default_flow_style=False, allow_unicode=True
        )
    except yaml.YAMLError as exc:
        raise DatasetError(f"{YAML_FILE}: metadata cannot be written as YAML ({_one_line(exc)})") from exc
    (directory / YAML_FILE).write_text(text, encoding="utf-8")
    for name in ("points", "normals", "areas", "alpha", "t", "coeffs", "beta"):
        arr = getattr(ds, name)
        if arr is not None:
            np.save(directory / f"{name}.npy", np.ascontiguousarray(arr, dtype=np.float64))
    np.save(directory / "case.npy", np.ascontiguousarray(ds.case, dtype=np.int64))


class DatasetMemmapWriter:
    """Writes a data set too big for memory: fill ``cp`` row chunk by row chunk, then :meth:`finish`.

    Created by :func:`create_dataset_memmap`. ``cp.npy`` lives in a temporary sibling directory of the
    destination until :meth:`finish` validates everything and renames the directory into place.
    Use it as a context manager (or call :meth:`abort`) so an unfinished write leaves nothing behind.
    """

    def __init__(self, path: Path, n_snapshots: int, n_points: int, dtype: DTypeLike) -> None:
        self.path = path
        self._tmp: Path | None = _make_temp_dir(path, "tmp")
        self._cp: np.memmap[Any, np.dtype[Any]] | None
        try:
            self._cp = np.lib.format.open_memmap(
                self._tmp / "cp.npy", mode="w+", dtype=np.dtype(dtype), shape=(n_snapshots, n_points)
            )
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise

    @property
    def cp(self) -> np.memmap[Any, np.dtype[Any]]:
        """The writable (M, N) ``cp`` memory map; assign row blocks, e.g. ``w.cp[i:j] = block``."""
        if self._cp is None:
            raise RuntimeError(f"{self.path}: the data set writer is already finished or aborted")
        return self._cp

    def write_rows(self, start: int, rows: ArrayLike) -> int:
        """Write a (k, N) block of pressure coefficients at rows ``start:start+k``; return ``start+k``."""
        block = np.asarray(rows)
        cp = self.cp
        if block.ndim != 2 or block.shape[1] != cp.shape[1] or not 0 <= start <= cp.shape[0] - block.shape[0]:
            raise DatasetError(
                f"cp.npy: cannot write a block of shape {block.shape} at row {start} into shape {cp.shape}"
            )
        cp[start : start + block.shape[0]] = block
        return start + block.shape[0]

    def finish(
        self,
        *,
        name: str,
        reference: Reference | Mapping[str, float],
        cases: Sequence[Case | Mapping[str, Any]],
        points: ArrayLike,
        normals: ArrayLike,
        areas: ArrayLike,
        alpha: ArrayLike,
        t: ArrayLike,
        case: ArrayLike,
        source: str = "",
        coeffs: ArrayLike | None = None,
        beta: ArrayLike | None = None,
        point_names: Sequence[str] | None = None,
        extra: Mapping[str, Any] | None = None,
        check_values: bool = True,
    ) -> Path:
        """Write the metadata and small arrays, validate, and rename the data set into place.

        Arguments are the :class:`Dataset` fields (units as documented there). On a validation error
        nothing is installed and the writer stays usable (fix and call again, or :meth:`abort`).

        Returns:
            The destination directory.
        """
        cp = self.cp
        assert self._tmp is not None
        cp.flush()
        fields: dict[str, Any] = {
            "name": name,
            "source": source,
            "reference": reference,
            "cases": cases,
            "cp": cp,
            "points": np.asarray(points),
            "normals": np.asarray(normals),
            "areas": np.asarray(areas),
            "alpha": np.asarray(alpha),
            "t": np.asarray(t),
            "case": np.asarray(case),
            "coeffs": None if coeffs is None else np.asarray(coeffs),
            "beta": None if beta is None else np.asarray(beta),
            "point_names": () if point_names is None else tuple(point_names),
            "extra": {} if extra is None else dict(extra),
        }
        ds = _dataset_from_fields(fields)
        validate_dataset(ds, check_values=check_values)
        _check_destination(self.path)
        try:
            _write_small_files(self._tmp, ds)
            del ds, fields, cp
            self._cp = None  # drop our map of cp.npy before the directory moves
            install_directory(self._tmp, self.path)
        except OSError as exc:
            self.abort()
            raise DatasetError(f"{self.path}: cannot write data set ({_one_line(exc)})") from exc
        self._tmp = None
        return self.path

    def abort(self) -> None:
        """Discard the unfinished data set (no-op after :meth:`finish`)."""
        self._cp = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> DatasetMemmapWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.abort()


def create_dataset_memmap(
    path: str | os.PathLike[str], *, n_snapshots: int, n_points: int, dtype: DTypeLike = np.float32
) -> DatasetMemmapWriter:
    """Start writing a (possibly huge) data set whose ``cp`` is filled chunk by chunk.

    Example::

        with create_dataset_memmap(out, n_snapshots=m, n_points=n) as w:
            for start, block in blocks():
                w.cp[start : start + len(block)] = block
            w.finish(name=..., reference=..., cases=..., points=..., normals=..., areas=...,
                     alpha=..., t=..., case=...)

    Args:
        path: destination directory; refused early if it exists and is not a data set.
        n_snapshots: M ≥ 1.
        n_points: N ≥ 1.
        dtype: floating dtype of ``cp.npy`` (float32 by default).

    Raises:
        DatasetError: on a bad size or dtype or a destination that may not be replaced.
    """
    dest = Path(path)
    if not (_is_int(n_snapshots) and n_snapshots >= 1 and _is_int(n_points) and n_points >= 1):
        raise DatasetError(f"cp.npy: sizes must be positive integers, got M = {n_snapshots!r}, N = {n_points!r}")
    try:
        kind = np.dtype(dtype).kind
    except TypeError as exc:
        raise DatasetError(f"cp.npy: invalid dtype {dtype!r}") from exc
    if kind != "f":
        raise DatasetError(f"cp.npy: dtype {np.dtype(dtype)}, expected a floating-point dtype")
    _check_destination(dest)
    return DatasetMemmapWriter(dest, int(n_snapshots), int(n_points), dtype)


# --------------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------------


def _label(base: Path | None, filename: str) -> str:
    return filename if base is None else str(base / filename)


def _one_line(value: object) -> str:
    return " ".join(str(value).split())


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _to_float(value: object) -> float | None:
    """A YAML number (also ``'1e-3'``, which YAML 1.1 loads as a string) as float, else ``None``."""
    if isinstance(value, bool | np.bool_):
        return None
    if isinstance(value, int | float | np.integer | np.floating):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return None
    return None


def _opt_float(value: object) -> float | None:
    return None if value is None else _to_float(value)


def _positive(label: str, key: str, value: object) -> float:
    number = _to_float(value)
    if number is None or not math.isfinite(number) or number <= 0.0:
        raise DatasetError(f"{label}: {key} must be a positive finite number, got {value!r}")
    return number


def _fmt_ids(ids: Sequence[int], limit: int = 20) -> str:
    shown = ", ".join(str(i) for i in ids[:limit])
    return shown + (f", … ({len(ids)} in all)" if len(ids) > limit else "")


def _chunk_rows(n_points: int, chunk_rows: int | None) -> int:
    if chunk_rows is not None:
        if chunk_rows < 1:
            raise ValueError(f"chunk_rows must be ≥ 1, got {chunk_rows}")
        return chunk_rows
    return max(1, CHUNK_ELEMENTS // max(n_points, 1))


def _rows_indexer(mask: BoolArray) -> slice | IntArray:
    """A slice when the selected rows are contiguous (keeps memory maps as views), else indices."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return slice(0, 0)
    if idx[-1] - idx[0] + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _as_float64(value: Any) -> NDArray[Any]:
    """Float arrays of any width become float64; other kinds are left for validation to report."""
    arr = value if isinstance(value, np.ndarray) else np.asarray(value)
    if arr.dtype.kind == "f" and arr.dtype != np.float64:
        return arr.astype(np.float64)
    if arr.dtype.kind == "f" and isinstance(arr, np.memmap):
        return np.array(arr)
    return arr


def _as_int64(value: Any) -> NDArray[Any]:
    """Integer arrays of any width become int64; other kinds are left for validation to report."""
    arr = value if isinstance(value, np.ndarray) else np.asarray(value)
    if arr.dtype.kind in "iu" and arr.dtype != np.int64:
        return arr.astype(np.int64)
    return arr


def to_plain(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples to plain Python for ``yaml.safe_dump`` / ``json.dumps``."""
    if isinstance(value, Mapping):
        return {to_plain(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value
