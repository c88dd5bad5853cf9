"""The offline POD/DEIM fit at the method's 3-D scale, measured honestly on one machine.

The method's 3-D case has N ≈ 3·10⁵ surface points and M ≈ 2·10³ snapshots: 2.4 GB in float32.
This module

* writes a realistic synthetic ``vdm-aero-dataset/1`` data set of any size straight to disk
  (:func:`make_synthetic_snapshots`): a closed ellipsoidal body, a potential-flow mean pressure, smooth
  spatial modes with a decaying spectrum and white noise, filled row chunk by row chunk through
  :func:`vdm_aero.dataset.create_dataset_memmap` (never the whole (M, N) matrix in memory);
* fits :class:`vdm_aero.deim.DEIMForceModel` on the memory-mapped float32 ``cp.npy`` in a fresh
  subprocess and reports wall time, peak resident memory and where the time went
  (:func:`run_fit_scale`); and
* ties both together for ``vdm-aero bench fit-scale`` (:func:`bench_fit_scale`).

Memory is measured in the fitting subprocess, so neither the writer nor the pytest/CLI parent is
counted: its ``VmHWM`` is the peak resident set of the fit, numpy/BLAS buffers included (tracemalloc
would miss those); ``ru_maxrss`` is reported too, but on Linux it inherits the parent's peak at exec.
Pages of the memory-mapped ``cp.npy`` that were read are resident *file-backed* pages and count
towards that peak although the kernel can drop them at any time; the anonymous (heap) part is
sampled separately from ``/proc/self/status`` so both numbers can be judged (``docs/pod-at-scale.md``).

Linux-only where noted (``/proc``, ``posix_fadvise``); elsewhere those fields are ``None``.
"""

from __future__ import annotations

import json
import math
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from types import CodeType, FrameType
from typing import Any, Final

import numpy as np
from numpy.typing import DTypeLike

from vdm_aero._typing import F64Array

__all__ = [
    "DEFAULT_SEMI_AXES",
    "bench_fit_scale",
    "drop_page_cache",
    "ellipsoid_area",
    "ellipsoid_surface",
    "fit_here",
    "make_synthetic_snapshots",
    "run_fit_scale",
]

DEFAULT_SEMI_AXES: Final = (1.0, 0.25, 0.2)
"""Semi-axes (x, y, z) [m] of the synthetic body: a 2 m long, 0.5 m wide, 0.4 m tall ellipsoid."""

SYNTH_CHUNK_ELEMENTS: Final = 1 << 23
"""Elements of ``cp`` generated per row chunk (8 Mi = 32 MiB in float32)."""

METHODS: Final = ("snapshots", "randomized")

BAR_SECONDS: Final = 60.0
"""Issue 5 bar: the 300,000 × 2,000 float32 fit in at most this wall time."""

BAR_RSS_RATIO: Final = 2.0
"""Issue 5 bar: peak RSS of the fit at most this multiple of the snapshot matrix size."""

_RESULT_TAG: Final = "VDM_FIT_SCALE_RESULT "
_RSS_SAMPLE_PERIOD_S: Final = 0.005


# --------------------------------------------------------------------------------------------------
# Synthetic 3-D body and snapshots
# --------------------------------------------------------------------------------------------------


def ellipsoid_area(semi_axes: tuple[float, float, float] = DEFAULT_SEMI_AXES) -> float:
    """Surface area [m²] of the ellipsoid x²/a² + y²/b² + z²/c² = 1 to ~1e-13 relative.

    ``A = ∮ a b c · sqrt(sx²/a² + sy²/b² + sz²/c²) dΩ`` over the unit sphere ``s`` (the area scale of
    the map ``s ↦ diag(a, b, c) s``), by Gauss–Legendre in ``sx`` and the (spectrally accurate,
    periodic) trapezoidal rule in the azimuth: numpy only, no elliptic integrals needed.
    """
    a, b, c = _check_semi_axes(semi_axes)
    mu, w = np.polynomial.legendre.leggauss(256)
    phi = np.linspace(0.0, 2.0 * np.pi, 512, endpoint=False)
    r = np.sqrt(1.0 - mu**2)[:, None]
    sx = mu[:, None]
    sy = r * np.cos(phi)[None, :]
    sz = r * np.sin(phi)[None, :]
    scale = a * b * c * np.sqrt((sx / a) ** 2 + (sy / b) ** 2 + (sz / c) ** 2)
    return float(np.sum(w[:, None] * scale) * (2.0 * np.pi / phi.size))


def ellipsoid_surface(
    n_points: int, semi_axes: tuple[float, float, float] = DEFAULT_SEMI_AXES
) -> tuple[F64Array, F64Array, F64Array, F64Array]:
    """Quasi-uniform surface points of an ellipsoid centred on the moment reference point.

    Points are the Fibonacci lattice on the unit sphere (equal-area cells of 4π/N, polar axis = body
    x so the nose is at +x) mapped by ``diag(a, b, c)``; each point's area is its cell's area scaled
    by the map's area factor and then renormalised so the areas sum to :func:`ellipsoid_area`.

    Args:
        n_points: N ≥ 4.
        semi_axes: (a, b, c) [m] along body x (forward), y (right), z (down).

    Returns:
        ``(points (N, 3) [m], normals (N, 3) unit, INTO the body, areas (N,) [m²], sphere (N, 3))``,
        all float64; ``sphere`` is the unit-sphere parameter of each point (used for smooth fields).
    """
    if not (_is_int(n_points) and n_points >= 4):
        raise ValueError(f"n_points must be an integer ≥ 4, got {n_points!r}")
    a, b, c = _check_semi_axes(semi_axes)
    i = np.arange(n_points, dtype=np.float64) + 0.5
    sx = 1.0 - 2.0 * i / n_points
    r = np.sqrt(1.0 - sx**2)
    phi = np.pi * (3.0 - math.sqrt(5.0)) * i  # golden angle: no two points share an azimuth
    sphere = np.stack([sx, r * np.cos(phi), r * np.sin(phi)], axis=1)
    axes = np.array([a, b, c])
    points = sphere * axes
    grad = sphere / axes  # outward normal direction ∝ (x/a², y/b², z/c²) = s/(a, b, c)
    gnorm = np.linalg.norm(grad, axis=1)
    normals = -grad / gnorm[:, None]  # the format's normals point INTO the body
    areas = (4.0 * np.pi / n_points) * a * b * c * gnorm
    areas *= ellipsoid_area((a, b, c)) / float(np.sum(areas))
    return points, normals, areas, sphere


def make_synthetic_snapshots(
    path: str | os.PathLike[str],
    *,
    n_points: int,
    n_snapshots: int,
    n_modes_true: int = 40,
    rng: np.random.Generator,
    dtype: DTypeLike = np.float32,
    noise_std: float = 1e-3,
    n_cases: int | None = None,
    semi_axes: tuple[float, float, float] = DEFAULT_SEMI_AXES,
    chunk_elements: int = SYNTH_CHUNK_ELEMENTS,
) -> Path:
    """Write a synthetic ``vdm-aero-dataset/1`` data set of N points × M snapshots directly to disk.

    ``Cp(t, s) = Cp₀(s) + Σ_k a_k(t) φ_k(s) + ε``:

    * ``Cp₀ = 1 − (9/4) sin²θ``, potential flow round a sphere with θ from the nose (+x), evaluated on
      the sphere parameter of the ellipsoid (stagnation Cp = 1 at the nose);
    * ``φ_k(s) = cos(κ_k d_k·s + ψ_k)``, smooth plane waves on the sphere parameter with random unit
      directions ``d_k``, wavenumbers ``κ_k = π (1/2 + k/4)`` that grow with k, random phases;
    * ``a_k(t) = σ_k √2 sin(2π h_k f_c t + ψ_{k,c})`` with ``σ_k = 0.3 e^{−k/6}`` (a decaying singular
      spectrum), harmonic ``h_k = 1 + k mod 4`` of the case's pitch frequency ``f_c`` and a random
      phase per mode and case;
    * ``ε`` white noise of standard deviation ``noise_std``.

    Snapshots are split into ``n_cases`` contiguous pitch-oscillation cases (α = α₀ + A sin 2πf t,
    64 samples per cycle) whose ``alpha``/``t``/``case`` arrays and case metadata are written too.
    Rows are generated ``chunk_elements // N`` at a time and written into the memory map, so memory
    stays at the (n_modes_true, N) mode matrix plus one chunk. File writing is not part of any
    benchmark.

    Args:
        path: destination data set directory (replaced only if it is a data set; see
            :func:`vdm_aero.dataset.create_dataset_memmap`).
        n_points: N ≥ 4.
        n_snapshots: M ≥ 1.
        n_modes_true: number of spatial modes in the signal (≥ 1).
        rng: the only source of randomness.
        dtype: floating dtype of ``cp.npy``.
        noise_std: standard deviation of the additive white noise (≥ 0).
        n_cases: number of cases (default ``clamp(M // 200, 1, 10)``).
        semi_axes: (a, b, c) [m] of the body.
        chunk_elements: elements of ``cp`` per generated chunk (≥ 1).

    Returns:
        The data set directory.
    """
    from vdm_aero.dataset import create_dataset_memmap

    if not (_is_int(n_snapshots) and n_snapshots >= 1):
        raise ValueError(f"n_snapshots must be an integer ≥ 1, got {n_snapshots!r}")
    if not (_is_int(n_modes_true) and n_modes_true >= 1):
        raise ValueError(f"n_modes_true must be an integer ≥ 1, got {n_modes_true!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if not (math.isfinite(noise_std) and noise_std >= 0.0):
        raise ValueError(f"noise_std must be a finite number ≥ 0, got {noise_std!r}")
    if not (_is_int(chunk_elements) and chunk_elements >= 1):
        raise ValueError(f"chunk_elements must be an integer ≥ 1, got {chunk_elements!r}")
    m = int(n_snapshots)
    k = int(n_modes_true)
    n_c = max(1, min(10, m // 200)) if n_cases is None else n_cases
    if not (_is_int(n_c) and 1 <= n_c <= m):
        raise ValueError(f"n_cases must be an integer in [1, n_snapshots = {m}], got {n_cases!r}")
    points, normals, areas, sphere = ellipsoid_surface(n_points, semi_axes)
    n = points.shape[0]
    a_ax, b_ax, c_ax = _check_semi_axes(semi_axes)

    # spatial part: (K, N), held once (48 MB at K = 40, N = 300,000 in float32)
    work = np.dtype(dtype)
    cp0 = (1.0 - 2.25 * (1.0 - sphere[:, 0] ** 2)).astype(work)
    dirs = rng.standard_normal((k, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    kappa = np.pi * (0.5 + np.arange(k) / 4.0)
    psi = rng.uniform(0.0, 2.0 * np.pi, k)
    modes = np.cos(kappa[:, None] * (dirs @ sphere.T) + psi[:, None]).astype(work)

    # temporal part: (M, K) coefficients of contiguous pitch-oscillation cases
    bounds = np.linspace(0, m, n_c + 1).round().astype(np.int64)
    freqs = np.round(rng.uniform(0.5, 5.0, n_c), 3)
    alpha0 = np.round(rng.uniform(0.0, 10.0, n_c), 2)
    ampl = np.round(rng.uniform(2.0, 6.0, n_c), 2)
    phases = rng.uniform(0.0, 2.0 * np.pi, (n_c, k))
    sigma = 0.3 * np.exp(-np.arange(k) / 6.0)
    harm = 1.0 + (np.arange(k) % 4)
    t = np.empty(m)
    alpha = np.empty(m)
    case = np.empty(m, dtype=np.int64)
    coeff = np.empty((m, k))
    for ci in range(n_c):
        rows = slice(int(bounds[ci]), int(bounds[ci + 1]))
        tc = np.arange(rows.stop - rows.start) / (64.0 * freqs[ci])
        t[rows] = tc
        alpha[rows] = np.deg2rad(alpha0[ci] + ampl[ci] * np.sin(2.0 * np.pi * freqs[ci] * tc))
        case[rows] = ci
        arg = 2.0 * np.pi * freqs[ci] * harm[None, :] * tc[:, None] + phases[ci][None, :]
        coeff[rows] = sigma * math.sqrt(2.0) * np.sin(arg)
    coeff_w = coeff.astype(work)

    step = max(1, chunk_elements // n)
    with create_dataset_memmap(path, n_snapshots=m, n_points=n, dtype=work) as writer:
        cp = writer.cp
        for start in range(0, m, step):
            stop = min(start + step, m)
            block = coeff_w[start:stop] @ modes
            block += cp0
            if noise_std > 0.0:
                noise = rng.standard_normal((stop - start, n), dtype=np.float64 if work.itemsize > 4 else np.float32)
                noise *= noise_std
                block += noise.astype(work, copy=False)
                del noise
            cp[start:stop] = block
            del block
        cases = [
            {
                "id": ci,
                "name": f"pitch-{ci:02d}",
                "freq_hz": float(freqs[ci]),
                "alpha0_deg": float(alpha0[ci]),
                "amplitude_deg": float(ampl[ci]),
                "speed_m_s": 20.0,
            }
            for ci in range(n_c)
        ]
        return writer.finish(
            name=f"synthetic-ellipsoid-{n}x{m}",
            source=(
                f"vdm_aero.fit_scale.make_synthetic_snapshots: ellipsoid {a_ax}x{b_ax}x{c_ax} m, "
                f"{k} smooth modes, sigma_k = 0.3 exp(-k/6), noise std {noise_std}"
            ),
            reference={"area_m2": math.pi * b_ax * c_ax, "chord_m": 2.0 * a_ax, "span_m": 2.0 * b_ax},
            cases=cases,
            points=points,
            normals=normals,
            areas=areas,
            alpha=alpha,
            t=t,
            case=case,
            check_values=False,  # generated finite; the O(M·N) scan would only cost time
        )


# --------------------------------------------------------------------------------------------------
# The measured fit
# --------------------------------------------------------------------------------------------------


def run_fit_scale(
    dataset_path: str | os.PathLike[str],
    *,
    n_sensors: int = 15,
    n_modes: int | None = None,
    method: str = "snapshots",
    rng: np.random.Generator,
    profile: bool = True,
    save_model: str | os.PathLike[str] | None = None,
    blas_threads: int | None = None,
    timeout_s: float | None = None,
) -> dict[str, Any]:
    """Fit :class:`~vdm_aero.deim.DEIMForceModel` on a memory-mapped data set in a fresh subprocess.

    The child process (``python -c``, same interpreter) loads the data set with
    ``load_dataset(path, mmap=True, check_values=False)``, builds the force matrix, fits
    ``DEIMForceModel(n_sensors, n_modes, pod_method=method)`` and reports its own peak memory, so only
    the fit (plus the interpreter, numpy and the small data set arrays) is counted.

    Args:
        dataset_path: a ``vdm-aero-dataset/1`` directory.
        n_sensors: n_s, number of ports.
        n_modes: n_b (default n_s).
        method: ``"snapshots"`` (blockwise Gram, exact) or ``"randomized"`` POD.
        rng: source of the randomized POD's seed (the only random step).
        profile: attribute the fit's wall time to source lines of the POD routine and of
            ``DEIMForceModel.fit`` with a line tracer (overhead: a few hundred line events, < 0.1 %);
            fills ``breakdown`` and ``deim_seconds``.
        save_model: optional ``.npz`` path where the child stores ``sensors``, ``Ms``, ``M0``, ``mean``,
            ``modes``, ``singular_values`` (after the measurement; for checks).
        blas_threads: BLAS/OpenMP threads of the child (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``,
            ``MKL_NUM_THREADS`` in its environment); ``None`` keeps the library default (one per core).
            On a shared machine whose cores are busy, 1 can be much faster: OpenBLAS threads spin-wait
            on each other and a descheduled one stalls the rest (``docs/pod-at-scale.md``).
        timeout_s: kill the child after this many seconds.

    Returns:
        A JSON-ready dict: ``seconds`` (fit wall time), ``peak_rss_mb`` (the child's ``VmHWM``: peak
        resident set, anonymous + file-backed, since the child's exec), ``snapshot_mb``
        (M·N·itemsize / 2²⁰), ``points``, ``snapshots``, ``method``, ``deim_seconds``, ``peak_anon_mb``
        (sampled peak ``RssAnon``), ``rss_file_mb_end``/``rss_anon_mb_end``, ``ru_maxrss_mb`` (see
        below), ``baseline_rss_mb``/``baseline_anon_mb`` (before the fit), ``cpu_seconds``,
        ``load_seconds``, ``breakdown`` and ``lines`` (when ``profile``), ``energy``,
        ``port_amplification``, ``sensors``, ``blas_threads`` and system facts.

    ``ru_maxrss`` of an exec'd child is not the child's own peak on Linux: at ``execve`` the kernel
    folds the old address space's high-water mark (with ``vfork``, the *parent's*) into the child's
    rusage. ``peak_rss_mb`` is therefore ``VmHWM``, which belongs to the child's new address space
    alone; ``ru_maxrss_mb`` is reported next to it and used only where ``/proc`` is missing.

    Raises:
        ValueError: on a bad ``method`` or ``rng``.
        RuntimeError: if the child fails (its stderr tail is in the message).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if blas_threads is not None and not (_is_int(blas_threads) and blas_threads >= 1):
        raise ValueError(f"blas_threads must be an integer ≥ 1 or None, got {blas_threads!r}")
    request = {
        "dataset": str(Path(dataset_path).resolve()),
        "n_sensors": n_sensors,
        "n_modes": n_modes,
        "method": method,
        "seed": int(rng.integers(0, 2**31 - 1)),
        "profile": bool(profile),
        "save_model": None if save_model is None else str(Path(save_model).resolve()),
    }
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])  # importable even from an uninstalled checkout
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    if blas_threads is not None:  # read by the BLAS libraries when numpy loads them in the child
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = str(int(blas_threads))
    code = "import sys; from vdm_aero.fit_scale import _child_main; _child_main(sys.argv[1])"
    proc = subprocess.run(
        [sys.executable, "-c", code, json.dumps(request)],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout_s,
        check=False,
    )
    tagged = [line for line in proc.stdout.splitlines() if line.startswith(_RESULT_TAG)]
    if proc.returncode != 0 or not tagged:
        tail = "\n".join(proc.stderr.strip().splitlines()[-15:])
        raise RuntimeError(f"fit subprocess failed with exit code {proc.returncode}:\n{tail}")
    result: dict[str, Any] = json.loads(tagged[-1][len(_RESULT_TAG) :])
    result["blas_threads"] = blas_threads if blas_threads is not None else "default"
    return result


def _child_main(request_json: str) -> None:
    """Entry point of the fitting subprocess: one tagged JSON line on stdout."""
    req = json.loads(request_json)
    res = fit_here(
        req["dataset"],
        n_sensors=req["n_sensors"],
        n_modes=req["n_modes"],
        method=req["method"],
        seed=req["seed"],
        profile=req["profile"],
        save_model=req["save_model"],
    )
    sys.stdout.write(_RESULT_TAG + json.dumps(res) + "\n")
    sys.stdout.flush()


def fit_here(
    dataset_path: str | os.PathLike[str],
    *,
    n_sensors: int = 15,
    n_modes: int | None = None,
    method: str = "snapshots",
    seed: int = 0,
    profile: bool = True,
    save_model: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """The measurement itself, in *this* process (use :func:`run_fit_scale` for an honest peak RSS).

    Arguments and result as :func:`run_fit_scale` (``seed`` is the randomized POD's seed). The peak
    RSS fields describe this process's whole life, so they mean "the fit" only in a fresh process.
    """
    from vdm_aero.dataset import load_dataset
    from vdm_aero.deim import DEIMForceModel

    t0 = time.perf_counter()
    ds = load_dataset(dataset_path, mmap=True, check_values=False)
    s = ds.force_matrix()
    load_seconds = time.perf_counter() - t0
    m, n = ds.cp.shape
    baseline = _proc_status_mb()

    est = DEIMForceModel(n_sensors, n_modes=n_modes, pod_method=method, random_state=seed)
    tracer = _LineTimer() if profile and sys.gettrace() is None else None
    sampler = _AnonSampler()
    cpu0 = _cpu_seconds()
    sampler.start()
    if tracer is not None:
        tracer.start()
    t1 = time.perf_counter()
    try:
        est.fit(ds.cp, s)
    finally:
        seconds = time.perf_counter() - t1
        if tracer is not None:
            tracer.stop()
        sampler.stop()
    cpu = _cpu_seconds() - cpu0
    ru_maxrss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
    end = _proc_status_mb()
    # VmHWM is this address space's own peak; ru_maxrss also keeps the *parent's* peak RSS, which the
    # kernel copies into the child's rusage at exec (fs/exec.c), so it is only the fallback
    peak_mb = end.get("VmHWM", ru_maxrss_mb)

    result: dict[str, Any] = {
        "seconds": round(seconds, 3),
        "peak_rss_mb": round(peak_mb, 1),
        "snapshot_mb": round(m * n * ds.cp.dtype.itemsize / 2**20, 1),
        "points": int(n),
        "snapshots": int(m),
        "dtype": str(ds.cp.dtype),
        "method": method,
        "n_sensors": int(est.n_sensors_),
        "n_modes": int(est.n_modes_),
        "deim_seconds": None,
        "peak_anon_mb": _round(sampler.peak_anon_mb),
        "rss_anon_mb_end": _round(end.get("RssAnon")),
        "rss_file_mb_end": _round(end.get("RssFile")),
        "ru_maxrss_mb": round(ru_maxrss_mb, 1),
        "baseline_rss_mb": _round(baseline.get("VmRSS")),
        "baseline_anon_mb": _round(baseline.get("RssAnon")),
        "cpu_seconds": round(cpu, 3),
        "load_seconds": round(load_seconds, 3),
        "energy": float(est.energy_),
        "port_amplification": float(est.port_amplification_),
        "sensors": [int(i) for i in est.sensors_],
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "numpy": np.__version__,
    }
    if tracer is not None:
        breakdown, lines = tracer.report()
        result["breakdown"] = breakdown
        result["lines"] = lines
        result["deim_seconds"] = breakdown.get("deim_selection")
    if save_model is not None:
        np.savez(
            save_model,
            sensors=est.sensors_,
            Ms=est.Ms_,
            M0=est.M0_,
            mean=est.mean_,
            modes=est.modes_,
            singular_values=est.singular_values_,
        )
    return result


def bench_fit_scale(
    points: int,
    snapshots: int,
    *,
    workdir: str | os.PathLike[str] | None = None,
    keep: bool = False,
    seed: int = 0,
    method: str = "snapshots",
    n_sensors: int = 15,
    page_cache: str = "cold",
    blas_threads: int | None = None,
) -> dict[str, Any]:
    """``vdm-aero bench fit-scale``: write a synthetic float32 data set, then time the fit of it.

    The data set (``make_synthetic_snapshots`` with ``default_rng(seed)``) goes to a fresh temporary
    directory under ``workdir`` (default: the system temp dir) and is deleted afterwards unless
    ``keep``. Writing it is timed separately (``write_seconds``) and is not part of ``seconds``.

    Args:
        points: N.
        snapshots: M.
        workdir: parent directory of the temporary data set.
        keep: keep the data set (its path is returned as ``dataset``).
        seed: seed of the data and of the randomized POD.
        method: ``"snapshots"`` or ``"randomized"``.
        n_sensors: ports (= modes) of the fitted model.
        page_cache: ``"cold"`` evicts ``cp.npy`` from the page cache before the fit
            (``posix_fadvise(DONTNEED)``, only this file, no root needed) so the fit reads from disk as
            it would a data set written earlier; ``"warm"`` leaves the just-written pages cached.
        blas_threads: see :func:`run_fit_scale`.

    Returns:
        :func:`run_fit_scale`'s dict plus ``write_seconds``, ``page_cache``, ``loadavg_before``/``_after``
        (1/5/15 min), the bars and ``meets_bar``.

    Raises:
        ValueError: on bad sizes/arguments or too little free disk space.
    """
    if page_cache not in ("cold", "warm"):
        raise ValueError(f"page_cache must be 'cold' or 'warm', got {page_cache!r}")
    if not (_is_int(points) and points >= 4 and _is_int(snapshots) and snapshots >= 1):
        raise ValueError(f"need points ≥ 4 and snapshots ≥ 1, got points = {points!r}, snapshots = {snapshots!r}")
    if not 1 <= n_sensors <= min(points, snapshots):
        raise ValueError(f"n_sensors must be in [1, min(points, snapshots)], got {n_sensors!r}")
    parent = Path(tempfile.gettempdir() if workdir is None else workdir)
    parent.mkdir(parents=True, exist_ok=True)
    need = points * snapshots * 4 + points * 64 + (64 << 20)
    free = shutil.disk_usage(parent).free
    if free < need:
        raise ValueError(f"{parent}: {free / 2**30:.1f} GiB free, the data set needs {need / 2**30:.1f} GiB")
    rng = np.random.default_rng(seed)
    tmp = Path(tempfile.mkdtemp(prefix="vdm-fit-scale-", dir=parent))
    try:
        ds_path = tmp / "synthetic"
        t0 = time.perf_counter()
        make_synthetic_snapshots(ds_path, n_points=points, n_snapshots=snapshots, rng=rng)
        write_seconds = time.perf_counter() - t0
        if page_cache == "cold":
            drop_page_cache(ds_path / "cp.npy")
        load_before = _loadavg()
        res = run_fit_scale(ds_path, n_sensors=n_sensors, method=method, rng=rng, blas_threads=blas_threads)
        res["loadavg_before"] = load_before
        res["loadavg_after"] = _loadavg()
        res["write_seconds"] = round(write_seconds, 3)
        res["page_cache"] = page_cache
        res["bar_seconds"] = BAR_SECONDS
        res["bar_peak_rss_mb"] = round(BAR_RSS_RATIO * res["snapshot_mb"], 1)
        res["meets_bar"] = bool(res["seconds"] <= BAR_SECONDS and res["peak_rss_mb"] <= res["bar_peak_rss_mb"])
        res["dataset"] = str(ds_path) if keep else None
        return res
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)


def drop_page_cache(path: str | os.PathLike[str]) -> bool:
    """Ask the kernel to evict one file's clean cached pages (``fsync`` + ``posix_fadvise(DONTNEED)``).

    Affects only this file (other users' caches are untouched) and needs no privileges. Returns False
    where ``posix_fadvise`` does not exist (non-Linux), True otherwise.
    """
    if not hasattr(os, "posix_fadvise"):
        return False
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)  # dirty pages cannot be dropped: write them back first
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)
    return True


# --------------------------------------------------------------------------------------------------
# Measurement helpers
# --------------------------------------------------------------------------------------------------


def _proc_status_mb() -> dict[str, float]:
    """Memory lines of ``/proc/self/status`` in MiB (empty where there is no /proc)."""
    out: dict[str, float] = {}
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                key, _, rest = line.partition(":")
                if key.startswith(("Vm", "Rss")) and rest.strip().endswith("kB"):
                    out[key] = int(rest.split()[0]) / 1024.0
    except OSError:
        return {}
    return out


class _AnonSampler:
    """Samples ``RssAnon`` every few ms in a daemon thread; the kernel keeps no peak of it.

    BLAS releases the GIL, so the thread runs during the big products; a spike shorter than the period
    can be missed, which is why ``peak_rss_mb`` (kernel-kept, exact) is the headline number.
    """

    def __init__(self, period_s: float = _RSS_SAMPLE_PERIOD_S) -> None:
        self.period_s = period_s
        self.peak_anon_mb: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss-anon-sampler", daemon=True)

    def _sample(self) -> None:
        anon = _proc_status_mb().get("RssAnon")
        if anon is not None and (self.peak_anon_mb is None or anon > self.peak_anon_mb):
            self.peak_anon_mb = anon

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def start(self) -> None:
        self._sample()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()


class _LineTimer:
    """Wall time per source line of the POD routines (``vdm_aero.pod._pod_*``) and ``DEIMForceModel.fit``.

    A ``sys.settrace`` tracer that traces only those frames: at each line event the time since the
    previous event is charged to the previous line, so a line's time includes everything it calls.
    Only the top-level routine frames are traced (their callees are not), so no time is counted twice
    within a routine; the POD frame's total is, by construction, part of ``fit``'s ``pod_basis`` line.
    """

    def __init__(self) -> None:
        from vdm_aero import deim, pod

        self._pod_file = pod.__file__
        self._deim_file = deim.__file__
        self.seconds: defaultdict[tuple[str, str, int], float] = defaultdict(float)
        self.hits: defaultdict[tuple[str, str, int], int] = defaultdict(int)
        self.first_line: dict[str, int] = {}

    def _wanted(self, code: CodeType) -> bool:
        if code.co_filename == self._pod_file:
            return code.co_name.startswith("_pod_")
        return code.co_filename == self._deim_file and code.co_name == "fit"

    def _global(self, frame: FrameType, event: str, arg: object) -> Callable[..., Any] | None:
        if event != "call" or not self._wanted(frame.f_code):
            return None
        code = frame.f_code
        self.first_line.setdefault(code.co_name, code.co_firstlineno)
        state: dict[str, Any] = {"line": None, "t": time.perf_counter()}

        def local(frame: FrameType, event: str, arg: object) -> Callable[..., Any] | None:
            now = time.perf_counter()
            prev = state["line"]
            if prev is not None:
                key = (code.co_filename, code.co_name, prev)
                self.seconds[key] += now - state["t"]
                self.hits[key] += 1
            state["line"] = frame.f_lineno if event == "line" else None
            state["t"] = time.perf_counter()  # the tracer's own time is not charged
            return local

        return local

    def start(self) -> None:
        sys.settrace(self._global)

    def stop(self) -> None:
        sys.settrace(None)

    def report(self, top: int = 12) -> tuple[dict[str, float], list[dict[str, Any]]]:
        """``(phases, lines)``: seconds per phase and the ``top`` most expensive source lines."""
        import linecache

        phases: defaultdict[str, float] = defaultdict(float)
        rows: list[dict[str, Any]] = []
        eigh_line: dict[str, int] = {}
        for (file, func, line), _ in self.seconds.items():
            if "linalg.eigh(" in linecache.getline(file, line):
                eigh_line[func] = min(line, eigh_line.get(func, line))
        for (file, func, line), sec in self.seconds.items():
            src = linecache.getline(file, line).strip()
            rows.append({"function": func, "line": line, "source": src, "seconds": round(sec, 4)})
            phases[_phase(func, src, line, eigh_line.get(func))] += sec
        if "pod_total" in phases:  # pod_basis's own argument checks and dispatch (first calls: ~20 ms)
            inner = sum(v for key, v in phases.items() if key.startswith("pod_") and key != "pod_total")
            phases["pod_setup_and_dispatch"] = max(0.0, phases["pod_total"] - inner)
        rows.sort(key=lambda r: -r["seconds"])
        phase_out = {key: round(val, 4) for key, val in sorted(phases.items(), key=lambda kv: -kv[1])}
        return phase_out, rows[:top]


def _phase(func: str, src: str, line: int, eigh_at: int | None) -> str:
    """Name the phase a source line belongs to (see :class:`_LineTimer`)."""
    if func == "fit":
        if "pod_basis(" in src:
            return "pod_total"
        if "select(" in src:
            return "deim_selection"
        return "model_matrices_and_checks"
    if "linalg.eigh(" in src:
        return "pod_eigendecomposition"
    if "_column_mean(" in src:
        return "pod_mean_pass"
    if "times(" in src:  # the randomized route's block products X_c·Ω, X_cᵀ·Q (also inside a qr(...) call)
        return "pod_passes_over_x"
    if "linalg.svd(" in src or "linalg.qr(" in src:
        return "pod_small_dense_factorisations"
    if eigh_at is not None:  # Gram routes: everything before eigh is the accumulation pass
        return "pod_gram_accumulation" if line < eigh_at else "pod_mode_formation"
    if func == "_pod_randomized":
        return "pod_passes_over_x"
    return "pod_other"


def _cpu_seconds() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return float(ru.ru_utime + ru.ru_stime)


def _loadavg() -> list[float] | None:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def _round(value: float | None, digits: int = 1) -> float | None:
    return None if value is None else round(value, digits)


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _check_semi_axes(semi_axes: tuple[float, float, float]) -> tuple[float, float, float]:
    vals = tuple(float(v) for v in semi_axes)
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0.0 for v in vals):
        raise ValueError(f"semi_axes must be three positive finite lengths [m], got {semi_axes!r}")
    return vals[0], vals[1], vals[2]
