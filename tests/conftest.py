"""Fixtures shared across modules: the design data set of the reference UAV and its DEIM model (the user's
side of calibration and navigation), built once per session."""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest


def require_tool(tool: str, package: str) -> str:
    """Path of ``tool``; a missing tool fails CI (.ci/run installs it) and only skips a developer's run, who
    may not have the Debian package (the reason names it)."""
    import shutil

    path = shutil.which(tool)
    if path is None:
        reason = f"{tool} is not installed (Debian: apt-get install {package}; .ci/run installs it)"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    return path


# The modules that fly the mock and the service in real time (×4), then the longest CPU-bound one; the module
# that builds ``survey_service_run`` leads, so that its two other users find the flight built rather than wait.
# ``make test`` runs pytest-xdist's loadscope without its reordering by test count: that order put these
# one-test modules last, and a worker takes another module while it has ≤ 2 tests pending, so one worker took
# the last three flights in a row while the other stood idle (215 s of a 640 s run, 2026-11-28).
REAL_TIME_FIRST: tuple[str, ...] = (
    "test_replay.py",
    "test_service_odometry_e2e.py",
    "test_service_px4_e2e.py",
    "test_fault_suite.py",
    "test_service_e2e.py",
    "test_service_relay_e2e.py",
    "test_calibration.py",  # not real time, but the next longest (70 s)
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The real-time flights first (:data:`REAL_TIME_FIRST`), everything else after them as collected."""
    rank = {name: i for i, name in enumerate(REAL_TIME_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


def once_per_session(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], Any]) -> Any:
    """``build(directory)`` once per test session, also when pytest-xdist runs it in several workers: the
    first worker builds under a file lock in the session's shared temporary directory, the others read its
    pickled result (the pattern pytest-xdist documents for session fixtures)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return build(tmp_path_factory.mktemp(name))
    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp().parent  # this session's, common to its workers
    cache = shared / f"{name}.pickle"
    with FileLock(str(shared / f"{name}.lock")):
        if cache.is_file():
            return pickle.loads(cache.read_bytes())
        result = build(shared / name)
        cache.write_bytes(pickle.dumps(result))
        return result


@pytest.fixture(scope="session")
def design_deim12(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``uav-envelope`` simulated and DEIM fitted on 12 ports (training cases): {"data", "model"}."""
    from vdm_aero_cli.replay_golden import build_design_models

    def build(root: Path) -> dict[str, Path]:
        root.mkdir(parents=True, exist_ok=True)
        return build_design_models(root)

    result: dict[str, Path] = once_per_session(tmp_path_factory, "design", build)
    return result


PORT_FREE_AND_DEIM_MODES = ("ins", "airspeed-dr", "ports-airdata", "vdm-classic", "vdm-deim")
"""Every mode but vdm-deim-nn: its net is trained by a calibration (minutes), the demo and the bench run it."""


@pytest.fixture(scope="session")
def survey_service_run(design_deim12: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Survey seed 0 with a 60 s outage: the service (vdm-deim) against the mock autopilot as processes, the
    mock's tlog of it, and the in-process benchmark of the same flight for every mode but vdm-deim-nn. The
    service's end-to-end test and the replay's equivalence test share this flight (it takes a minute)."""
    from vdm_aero_cli.service_sitl import ServiceRun, bench_reference, run_service_sitl, site_mag_field_ut

    run = ServiceRun(design_deim12["data"], design_deim12["model"], None, mode="vdm-deim", scenario="survey",
                     seed=0, outage_s=60.0, speed=4.0)  # fmt: skip
    mag = site_mag_field_ut(run)

    def build(root: Path) -> dict[str, Any]:
        # the service flies in real time ×4 first, the benchmark (CPU-bound, ~35 s) after it: run beside it,
        # with the other test worker on the second core, the benchmark starved the real-time processes, and
        # late or dropped messages changed the flight the tlog recorded (two CI failures of 2026-11-26)
        res = run_service_sitl(run, root / "direct", mag_field_ned_ut=mag)
        ref = bench_reference(run, PORT_FREE_AND_DEIM_MODES)
        return {"run": run, "res": res, "mag_field_ned_ut": mag, "ref": ref}

    result: dict[str, Any] = once_per_session(tmp_path_factory, "survey-service", build)
    return result


SHARED_LOGS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "logs"


@pytest.fixture(scope="session")
def shared_logs() -> Path:
    """``../shared/data/logs``: the two real autopilot logs (a PX4 ULog, an ArduPlane DataFlash log) that the
    readers are developed against. CI has shared/ beside the checkout, so a missing folder fails there and
    only skips a developer's clone elsewhere."""
    import os

    if not (SHARED_LOGS / "px4-standard-vtol-cubeorange.ulg").is_file():
        reason = f"{SHARED_LOGS}: the shared real logs are not beside this checkout"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    return SHARED_LOGS
