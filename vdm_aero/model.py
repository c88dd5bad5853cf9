"""The aerodynamic model artifact ``vdm-aero-model/1`` and its run-time predictor :class:`AeroModel`.

A model directory holds ``model.yaml`` (ports, reference geometry, method, training summary and
metrics, sha256 of every other file), ``deim.npz`` (the linear DEIM force model) and optionally
``correction.onnx`` (the correction net). Loading verifies versions, shapes and hashes and refuses a
tampered or incompatible model with one clear line: a file that matches its hash but is damaged anyway
(the hashes re-written over it) is refused by its content: not an archive, arrays of the wrong kind,
shape or with non-finite values, a reference geometry that is not positive, duplicate port names. Run
time needs numpy and onnxruntime only.

Prediction: C = M_s·Cp_s + M_0 (+ net(Cp_s)), body-axis ``[CX, CY, CZ, Croll, Cpitch, Cyaw]``.
Missing ports (NaN) are filled from the gappy least-squares reconstruction of the pressure field
(remaining ports, trailing modes dropped when fewer ports than modes remain), which gives exactly the
gappy linear prediction and a complete input for the net.
"""

from __future__ import annotations

import hashlib
import math
import shutil
import tempfile
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from vdm_aero._typing import COEFF_NAMES, F64Array, FloatArray
from vdm_aero.atomic import install_directory
from vdm_aero.dataset import Reference, to_plain
from vdm_aero.errors import ModelError
from vdm_aero.ports import Port

MODEL_FORMAT = "vdm-aero-model/1"
DEIM_FILE = "deim.npz"
NET_FILE = "correction.onnx"
_DEIM_ARRAYS = ("Us", "mean_s", "SU", "Smean", "sensors")
_PRIOR_ARRAYS = ("mode_std", "tail_var")  # optional: the gappy prior


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class LinearModel:
    """The DEIM force model restricted to the ports: everything run time needs.

    ``Us`` (n_s, n_b) the POD modes at the ports, ``mean_s`` (n_s,) the snapshot mean at the ports,
    ``SU`` (6, n_b) and ``Smean`` (6,) the force operator applied to the modes and to the mean.
    """

    Us: F64Array
    mean_s: F64Array
    SU: F64Array
    Smean: F64Array
    mode_std: F64Array | None = None  # (n_b,) std of each POD coefficient over the fit snapshots, σ_i/√M
    tail_var: float = 0.0  # per-point variance the truncated modes leave, Σ_{i>n_b} σ_i² / (M·N)
    Ms: F64Array = field(init=False)
    M0: F64Array = field(init=False)

    def __post_init__(self) -> None:
        ms = self.SU @ np.linalg.pinv(self.Us)
        object.__setattr__(self, "Ms", np.ascontiguousarray(ms))
        object.__setattr__(self, "M0", np.ascontiguousarray(self.Smean - ms @ self.mean_s))

    @property
    def n_ports(self) -> int:
        return int(self.Us.shape[0])

    @property
    def n_modes(self) -> int:
        return int(self.Us.shape[1])

    def fill_matrix(self, present: np.ndarray) -> tuple[F64Array, F64Array]:
        """(A, b) with cp_missing = A·(cp_present − mean_present) + b: the gappy reconstruction.

        With the POD statistics (``mode_std``, ``tail_var``) it is the MAP estimate of all n_b mode
        coefficients under their snapshot prior, a = (U_pᵀU_p + tail_var·diag(1/mode_std²))⁻¹ U_pᵀ y:
        well-posed with fewer ports than modes and it shrinks poorly observed modes towards the mean
        instead of extrapolating them. Without them, plain least squares on the leading modes."""
        n_present = int(present.sum())
        if n_present == 0:
            raise ValueError("no port present: nothing to reconstruct from")
        if self.mode_std is not None and self.tail_var > 0.0:
            u_p = self.Us[present]
            prior = self.tail_var / np.maximum(self.mode_std, 1e-300) ** 2
            a_map = np.linalg.solve(u_p.T @ u_p + np.diag(prior), u_p.T)
            return self.Us[~present] @ a_map, self.mean_s[~present]
        k = min(self.n_modes, n_present)
        a = self.Us[~present, :k] @ np.linalg.pinv(self.Us[present, :k])
        return a, self.mean_s[~present]


class AeroModel:
    """Run-time aerodynamic model: port Cp → body-axis force and moment coefficients.

    Not thread-safe (the single-sample path reuses buffers): one instance per thread.
    """

    def __init__(
        self,
        *,
        linear: LinearModel,
        ports: tuple[Port, ...],
        reference: Reference,
        meta: Mapping[str, Any],
        net_path: Path | None = None,
        path: Path | None = None,
    ) -> None:
        self.linear = linear
        self.ports = ports
        self.reference = reference
        self.meta = dict(meta)
        self.path = path
        self._fill_cache: dict[bytes, tuple[np.ndarray, F64Array, F64Array]] = {}
        self._net = None
        if net_path is not None:
            from vdm_aero.onnx_net import OnnxCorrection

            self._net = OnnxCorrection(net_path)
            if (self._net.n_in, self._net.n_out) != (linear.n_ports, 6):
                raise ModelError(
                    f"{net_path}: net maps {self._net.n_in} → {self._net.n_out}, "
                    f"expected {linear.n_ports} ports → 6 coefficients"
                )
        self._ms, self._m0 = linear.Ms, linear.M0

    # ------------------------------------------------------------------------------------ properties
    @property
    def n_ports(self) -> int:
        return self.linear.n_ports

    @property
    def port_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.ports)

    @property
    def has_correction(self) -> bool:
        return self._net is not None

    # ------------------------------------------------------------------------------------ prediction
    def _fill(self, cp: F64Array) -> F64Array:
        missing = np.isnan(cp)
        key = missing.tobytes()
        if key not in self._fill_cache:
            present = ~missing
            a, b = self.linear.fill_matrix(present)
            self._fill_cache[key] = (present, a, b)
        present, a, b = self._fill_cache[key]
        out = cp.copy()
        out[~present] = a @ (cp[present] - self.linear.mean_s[present]) + b
        return out

    def predict(self, cp_ports: FloatArray) -> F64Array:
        """One sample: port Cp (n_s,) in port order (NaN = missing) → coefficients (6,)."""
        x = np.asarray(cp_ports, dtype=np.float64)
        if x.shape != (self.n_ports,):
            raise ValueError(f"expected {self.n_ports} port values, got shape {x.shape}")
        if np.isnan(x).any():
            x = self._fill(x)
        y = self._ms @ x + self._m0
        if self._net is not None:
            y += self._net.predict_one(x)
        return y

    def predict_linear(self, cp_ports: FloatArray) -> F64Array:
        """DEIM only (no correction): (n_s,) or (K, n_s) → (6,) or (K, 6)."""
        x = np.asarray(cp_ports, dtype=np.float64)
        return np.asarray(x @ self._ms.T + self._m0)

    def predict_batch(self, cp_ports: FloatArray, *, linear_only: bool = False) -> F64Array:
        """(K, n_s) → (K, 6). Rows with NaN use the gappy fill-in."""
        x = np.array(cp_ports, dtype=np.float64, ndmin=2)
        if x.shape[1] != self.n_ports:
            raise ValueError(f"expected {self.n_ports} port columns, got {x.shape[1]}")
        for i in np.flatnonzero(np.isnan(x).any(axis=1)):
            x[i] = self._fill(x[i])
        y = x @ self._ms.T + self._m0
        if self._net is not None and not linear_only:
            y += self._net.predict_batch(x)
        return np.asarray(y)

    def predict_from_pressure(self, dp_pa: FloatArray, qbar_pa: float) -> F64Array:
        """Ports as they arrive over MAVLink: Δp = p_port − p_static [Pa] and dynamic pressure [Pa]."""
        if not qbar_pa > 0.0:
            raise ValueError(f"dynamic pressure must be > 0 Pa, got {qbar_pa}")
        return self.predict(np.asarray(dp_pa, dtype=np.float64) / qbar_pa)

    def forces_moments_b(self, coeffs: FloatArray, qbar_pa: float) -> tuple[F64Array, F64Array]:
        """Dimensional body-frame force [N] and moment [N·m] from coefficients and dynamic pressure."""
        c = np.asarray(coeffs, dtype=np.float64)
        ref = self.reference
        qs = qbar_pa * ref.area_m2
        force = qs * c[..., :3]
        moment = qs * c[..., 3:] * np.array([ref.span_m, ref.chord_m, ref.span_m])
        return force, moment

    def with_correction(self, net_path: Path | None) -> AeroModel:
        """A copy using another correction net (or none)."""
        return AeroModel(
            linear=self.linear,
            ports=self.ports,
            reference=self.reference,
            meta=self.meta,
            net_path=net_path,
            path=self.path,
        )

    # ------------------------------------------------------------------------------------------ I/O
    @classmethod
    def load(cls, path: str | Path) -> AeroModel:
        """Load and verify a model directory."""
        root = Path(path)
        if not root.is_dir():
            raise ModelError(f"{root}: no such model directory")
        meta = read_model_yaml(root)
        files = meta.get("files")
        if not isinstance(files, Mapping) or DEIM_FILE not in files:
            raise ModelError(f"{root / 'model.yaml'}: files: must list {DEIM_FILE} with its sha256")
        for name, digest in files.items():
            f = root / str(name)
            if not f.is_file():
                raise ModelError(f"{f}: listed in model.yaml but missing")
            if sha256_file(f) != digest:
                raise ModelError(f"{f}: sha256 does not match model.yaml (file changed after the model was written)")
        try:
            with np.load(root / DEIM_FILE, allow_pickle=False) as z:
                arrays = {k: np.asarray(z[k]) for k in _DEIM_ARRAYS}
                prior = {k: np.asarray(z[k]) for k in _PRIOR_ARRAYS if k in z.files}
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            reason = " ".join(str(e).split()) or type(e).__name__
            raise ModelError(f"{root / DEIM_FILE}: unreadable or incomplete ({reason})") from None
        for k, a in {**arrays, **prior}.items():
            if a.dtype.kind not in "fiu" or not np.isfinite(a).all():
                raise ModelError(f"{root / DEIM_FILE}: {k} holds {a.dtype} values that are not all finite numbers")
        n_s, n_b = arrays["Us"].shape if arrays["Us"].ndim == 2 else (-1, -1)
        shapes_ok = (
            n_s > 0
            and arrays["mean_s"].shape == (n_s,)
            and arrays["SU"].shape == (6, n_b)
            and arrays["Smean"].shape == (6,)
        )
        if not shapes_ok:
            raise ModelError(f"{root / DEIM_FILE}: inconsistent array shapes for {n_s} ports and {n_b} modes")
        ports = _parse_ports(meta, root)
        if len(ports) != n_s:
            raise ModelError(f"{root / 'model.yaml'}: lists {len(ports)} ports but {DEIM_FILE} has {n_s}")
        ref = meta.get("reference", {})
        try:
            reference = Reference(float(ref["area_m2"]), float(ref["chord_m"]), float(ref["span_m"]))
        except (KeyError, TypeError, ValueError, OverflowError):
            raise ModelError(f"{root / 'model.yaml'}: reference: needs area_m2, chord_m, span_m") from None
        if not all(math.isfinite(v) and v > 0.0 for v in (reference.area_m2, reference.chord_m, reference.span_m)):
            raise ModelError(f"{root / 'model.yaml'}: reference: area_m2, chord_m, span_m must be positive")
        mode_std = prior.get("mode_std")
        if mode_std is not None and mode_std.shape != (n_b,):
            raise ModelError(f"{root / DEIM_FILE}: mode_std has shape {mode_std.shape}, expected ({n_b},)")
        tail_var = prior.get("tail_var", np.float64(0.0))
        if tail_var.shape != () or tail_var < 0.0 or (mode_std is not None and np.any(mode_std < 0.0)):
            raise ModelError(f"{root / DEIM_FILE}: tail_var must be one number ≥ 0 and mode_std ≥ 0")
        with np.errstate(all="ignore"):  # overflow is checked below
            try:
                linear = LinearModel(
                    Us=arrays["Us"].astype(np.float64),
                    mean_s=arrays["mean_s"].astype(np.float64),
                    SU=arrays["SU"].astype(np.float64),
                    Smean=arrays["Smean"].astype(np.float64),
                    mode_std=None if mode_std is None else mode_std.astype(np.float64),
                    tail_var=float(tail_var),
                )
            except np.linalg.LinAlgError:
                raise ModelError(f"{root / DEIM_FILE}: the port basis Us cannot be inverted") from None
        if not (np.isfinite(linear.Ms).all() and np.isfinite(linear.M0).all()):
            raise ModelError(f"{root / DEIM_FILE}: the force operator overflows (values out of any physical range)")
        cal = meta.get("calibration")
        if isinstance(cal, Mapping) and (cal.get("targets") or {}).get("cp_qbar") != "ports":
            # calibrated before Cp was normalised by the ports' own q̄: its net expects Δp / q̄_pitot inputs
            raise ModelError(f"{root / 'model.yaml'}: calibration: its net was trained on Cp = Δp / q̄_pitot, "
                             "the run time feeds Δp / q̄ of the ports' air data: calibrate it again")  # fmt: skip
        net = root / NET_FILE if NET_FILE in files else None
        return cls(linear=linear, ports=ports, reference=reference, meta=meta, net_path=net, path=root)


def read_model_yaml(root: Path) -> dict[str, Any]:
    p = root / "model.yaml"
    try:
        meta = yaml.safe_load(p.read_bytes().decode("utf-8"))
    except OSError:
        raise ModelError(f"{p}: missing (not a vdm-aero model directory)") from None
    except UnicodeDecodeError:
        raise ModelError(f"{p}: not UTF-8 text") from None
    except (yaml.YAMLError, ValueError, RecursionError):  # ValueError: a number beyond 4300 digits, a bad date
        raise ModelError(f"{p}: YAML syntax error") from None
    if not isinstance(meta, dict):
        raise ModelError(f"{p}: expected a mapping")
    if meta.get("format") != MODEL_FORMAT:
        raise ModelError(f"{p}: format {meta.get('format')!r} is not supported (expected {MODEL_FORMAT})")
    return meta


def _parse_ports(meta: Mapping[str, Any], root: Path) -> tuple[Port, ...]:
    raw = meta.get("ports")
    if not isinstance(raw, list) or not raw:
        raise ModelError(f"{root / 'model.yaml'}: ports: expected a non-empty list")
    out = []
    for i, p in enumerate(raw):
        try:
            pt = tuple(float(v) for v in p["point_b"])
            nb = tuple(float(v) for v in p["normal_b"])
            if len(pt) != 3 or len(nb) != 3 or not all(map(math.isfinite, pt + nb)):
                raise ValueError
            out.append(Port(str(p["name"]), (pt[0], pt[1], pt[2]), (nb[0], nb[1], nb[2])))
        except (KeyError, TypeError, ValueError, OverflowError):
            raise ModelError(f"{root / 'model.yaml'}: ports[{i}]: needs name, point_b [3], normal_b [3]") from None
    names = [p.name for p in out]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ModelError(f"{root / 'model.yaml'}: ports: {dup!r} is listed twice")
    return tuple(out)


def write_model(
    path: str | Path,
    *,
    linear: LinearModel,
    sensors: np.ndarray,
    ports: tuple[Port, ...],
    reference: Reference,
    meta: Mapping[str, Any],
    diagnostics: Mapping[str, np.ndarray] | None = None,
    net_onnx: bytes | None = None,
) -> Path:
    """Write a model directory atomically (a sibling temp dir renamed into place)."""
    root = Path(path)
    if root.exists() and not (root / "model.yaml").is_file() and (not root.is_dir() or any(root.iterdir())):
        raise ModelError(f"{root}: exists and is not a vdm-aero model directory; refusing to overwrite")
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        arrays: dict[str, Any] = {k: np.asarray(v) for k, v in (diagnostics or {}).items()}
        arrays.update(
            Us=linear.Us,
            mean_s=linear.mean_s,
            SU=linear.SU,
            Smean=linear.Smean,
            sensors=np.asarray(sensors, np.int64),
        )
        if linear.mode_std is not None:
            arrays.update(mode_std=linear.mode_std, tail_var=np.float64(linear.tail_var))
        np.savez(tmp / DEIM_FILE, **arrays)
        if net_onnx is not None:
            (tmp / NET_FILE).write_bytes(net_onnx)
        doc: dict[str, Any] = {
            "format": MODEL_FORMAT,
            **{k: v for k, v in meta.items() if k not in ("format", "files", "ports", "reference")},
            "coefficients": list(COEFF_NAMES),
            "reference": {
                "area_m2": reference.area_m2,
                "chord_m": reference.chord_m,
                "span_m": reference.span_m,
            },
            "ports": [{"name": p.name, "point_b": list(p.point_b), "normal_b": list(p.normal_b)} for p in ports],
            "files": {f.name: sha256_file(f) for f in sorted(tmp.iterdir())},
        }
        (tmp / "model.yaml").write_text(yaml.safe_dump(to_plain(doc), sort_keys=False, allow_unicode=True))
        install_directory(tmp, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return root


def load_diagnostics(path: str | Path) -> dict[str, np.ndarray]:
    """Offline extras stored in deim.npz (singular values, projection error, basis at ports…)."""
    with np.load(Path(path) / DEIM_FILE, allow_pickle=False) as z:
        return {k: np.asarray(z[k]) for k in z.files if k not in _DEIM_ARRAYS + _PRIOR_ARRAYS}
