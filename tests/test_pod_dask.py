"""POD on dask.array (the optional ``dask`` extra) equals vdm_aero.pod on a small local cluster."""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

da = pytest.importorskip("dask.array", reason="the optional 'dask' extra (dask[array]) is not installed")
distributed = pytest.importorskip("distributed", reason="the optional 'dask' extra (distributed) is not installed")

from scipy.linalg import subspace_angles  # noqa: E402

from vdm_aero.fit_scale import make_synthetic_snapshots  # noqa: E402
from vdm_aero.pod import PODResult, pod_basis  # noqa: E402
from vdm_aero.pod_dask import NpyColumns, open_dataset_dask, pod_basis_dask  # noqa: E402

N_POINTS = 3_000
N_SNAPSHOTS = 80
N_MODES = 8


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small float64 synthetic data set: 12 smooth modes + 1e-3 noise on the 3-D ellipsoid."""
    out = tmp_path_factory.mktemp("pod-dask") / "synthetic"
    return make_synthetic_snapshots(
        out, n_points=N_POINTS, n_snapshots=N_SNAPSHOTS, n_modes_true=12, rng=np.random.default_rng(0),
        dtype=np.float64,
    )  # fmt: skip


@pytest.fixture(scope="module")
def exact(data_dir: Path) -> PODResult:
    return pod_basis(np.load(data_dir / "cp.npy"), N_MODES, method="exact")


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    """Two single-threaded workers in this process (fast to start; processes=True is tested below).

    ``dashboard_address=":0"``: the HTTP server always binds; a random port never clashes on a shared host.
    """
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cl,
        distributed.Client(cl) as c,
    ):
        yield c


def max_angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.max(subspace_angles(np.asarray(u, np.float64), np.asarray(v, np.float64))))


def assert_same_pod(got: PODResult, ref: PODResult, *, sv_rtol: float, angle: float) -> None:
    assert got.modes.shape == ref.modes.shape
    np.testing.assert_allclose(got.mean, ref.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.singular_values, ref.singular_values, rtol=sv_rtol)
    assert max_angle(got.modes, ref.modes) < angle
    np.testing.assert_allclose(got.modes.T.astype(np.float64) @ got.modes, np.eye(got.n_modes), atol=10 * angle)
    # same sign convention as vdm_aero.pod: the modes themselves agree, not only the subspace
    np.testing.assert_allclose(got.modes, ref.modes, atol=10 * angle)
    assert got.total_energy == pytest.approx(ref.total_energy, rel=max(sv_rtol, 1e-10))


@pytest.mark.parametrize(
    ("chunk_points", "n_chunks"),
    [(400, 8), (50, 60)],  # 8 chunks: one stack of R factors; 60 chunks of fewer points than snapshots: two levels
)
def test_tsqr_on_a_local_cluster_equals_the_exact_svd(
    client: Any, data_dir: Path, exact: PODResult, chunk_points: int, n_chunks: int
) -> None:
    x = open_dataset_dask(data_dir, chunk_points=chunk_points)
    assert x.numblocks == (1, n_chunks)
    with distributed.get_task_stream(client) as ts:
        pod = pod_basis_dask(x, N_MODES, method="tsqr")
    assert ts.data, "the POD ran on the cluster's workers"
    assert {t["worker"] for t in ts.data} <= set(client.scheduler_info()["workers"])
    assert pod.method == "dask-tsqr"
    assert pod.modes.dtype == np.float64
    assert_same_pod(pod, exact, sv_rtol=1e-10, angle=1e-9)
    assert pod.all_singular_values is not None and exact.all_singular_values is not None
    np.testing.assert_allclose(
        pod.all_singular_values, exact.all_singular_values, rtol=0, atol=1e-10 * exact.all_singular_values[0]
    )


def test_compressed_on_a_local_cluster_is_reproducible(client: Any, data_dir: Path, exact: PODResult) -> None:
    x = open_dataset_dask(data_dir, chunk_points=1000)
    a = pod_basis_dask(x, N_MODES, method="compressed", rng=np.random.default_rng(5))
    b = pod_basis_dask(x, N_MODES, method="compressed", rng=np.random.default_rng(5))
    assert a.method == "dask-compressed"
    assert a.all_singular_values is None
    # 8 + 10 test vectors and 2 power iterations on a spectrum that drops to the noise after 12 modes
    assert_same_pod(a, exact, sv_rtol=1e-8, angle=1e-6)
    np.testing.assert_allclose(a.modes, b.modes, rtol=0, atol=1e-12)  # the seed comes from the Generator


def test_more_snapshots_than_points_uses_tsqr_on_the_snapshot_axis(client: Any, data_dir: Path) -> None:
    cp = np.load(data_dir / "cp.npy")[:, :50]  # M = 80 > N = 50
    x = da.from_array(cp, chunks=(20, 50))
    pod = pod_basis_dask(x, 5)
    assert_same_pod(pod, pod_basis(cp, 5, method="exact"), sv_rtol=1e-10, angle=1e-9)


def test_float32_stays_float32(client: Any, tmp_path: Path) -> None:
    path = make_synthetic_snapshots(
        tmp_path / "f32", n_points=2_000, n_snapshots=60, n_modes_true=10, rng=np.random.default_rng(1)
    )
    x = open_dataset_dask(path / "cp.npy", chunk_points=500)
    assert x.dtype == np.float32
    cp = np.load(path / "cp.npy")
    ref = pod_basis(cp.astype(np.float64), 5, method="exact")
    for method in ("tsqr", "compressed"):
        pod = pod_basis_dask(x, 5, method=method, rng=np.random.default_rng(0))
        assert pod.modes.dtype == np.float32
        assert pod.mean.dtype == pod.singular_values.dtype == np.float64
        np.testing.assert_allclose(pod.singular_values, ref.singular_values, rtol=1e-4)  # float32 rounding
        assert max_angle(pod.modes, ref.modes) < 1e-3


def test_worker_processes_read_the_file_by_path(data_dir: Path, exact: PODResult) -> None:
    # what a real cluster does: the graph carries the path, each worker process maps the file itself
    src = NpyColumns(data_dir / "cp.npy")
    blob = pickle.dumps(src)
    assert len(blob) < 1_000  # not the 1.9 MB of data
    np.testing.assert_array_equal(pickle.loads(blob)[:, 5:9], np.load(data_dir / "cp.npy")[:, 5:9])
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cl,
        distributed.Client(cl),
    ):
        pod = pod_basis_dask(open_dataset_dask(data_dir, chunk_points=750), N_MODES)
    assert_same_pod(pod, exact, sv_rtol=1e-10, angle=1e-9)


def test_open_dataset_dask_default_chunks_and_errors(data_dir: Path, tmp_path: Path) -> None:
    x = open_dataset_dask(data_dir)
    assert x.shape == (N_SNAPSHOTS, N_POINTS)
    assert x.numblocks == (1, 1)  # ≈ 128 MiB per chunk: this small set is one chunk
    np.testing.assert_array_equal(x[:, 7:9].compute(scheduler="synchronous"), np.load(data_dir / "cp.npy")[:, 7:9])
    assert open_dataset_dask(data_dir, chunk_points=10**9).numblocks == (1, 1)
    with pytest.raises(ValueError, match="no such"):
        open_dataset_dask(tmp_path / "missing")
    with pytest.raises(ValueError, match="chunk_points"):
        open_dataset_dask(data_dir, chunk_points=0)
    np.save(tmp_path / "one_d.npy", np.zeros(5))
    with pytest.raises(ValueError, match="2-D"):
        open_dataset_dask(tmp_path / "one_d.npy")


def test_pod_basis_dask_rejects_bad_input(data_dir: Path) -> None:
    x = open_dataset_dask(data_dir, chunk_points=1000)
    with pytest.raises(ValueError, match=r"dask\.array"):
        pod_basis_dask(np.ones((4, 5)), 2)
    with pytest.raises(ValueError, match="n_modes"):
        pod_basis_dask(x, N_SNAPSHOTS + 1)
    with pytest.raises(ValueError, match="method"):
        pod_basis_dask(x, 2, method="exact")
    with pytest.raises(ValueError, match="rng"):
        pod_basis_dask(x, 2, method="compressed")
    bad = np.load(data_dir / "cp.npy")
    bad[3, 17] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        pod_basis_dask(da.from_array(bad, chunks=(N_SNAPSHOTS, 1000)), 2, method="tsqr")
