"""Package borders (docs/design.md), enforced by parsing every module's imports."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _full_imports(package: str) -> dict[str, set[str]]:
    """Full dotted module names imported by each file of ``package``."""
    out: dict[str, set[str]] = {}
    for path in (ROOT / package).rglob("*.py"):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module)  # and what may be submodules of it (``from firmware_bridge import units``)
                names |= {f"{node.module}.{a.name}" for a in node.names}
        out[str(path.relative_to(ROOT))] = names
    return out


def imports_of(package: str) -> dict[str, set[str]]:
    """Top-level module names imported by each file of ``package`` (including lazy imports)."""
    return {path: {n.split(".")[0] for n in names} for path, names in _full_imports(package).items()}


def test_core_library_is_pure() -> None:
    forbidden = {"sim", "firmware_bridge", "vdm_aero_cli", "pymavlink", "socket", "serial"}
    for path, names in imports_of("vdm_aero").items():
        assert not names & forbidden, f"{path} imports {sorted(names & forbidden)}"


def test_torch_only_in_the_offline_trainer() -> None:
    # run time never imports torch (tests/test_model.py checks sys.modules after a prediction)
    users = sorted(p for p, names in imports_of("vdm_aero").items() if "torch" in names)
    assert users == ["vdm_aero/train_correction.py"], users


def test_onnxruntime_lives_behind_one_door() -> None:
    users = [p for p, names in imports_of("vdm_aero").items() if "onnxruntime" in names]
    assert len(users) <= 1, users
    for pkg in ("sim", "firmware_bridge", "vdm_aero_cli"):
        assert not [p for p, n in imports_of(pkg).items() if "onnxruntime" in n]


def test_simulator_never_imports_the_bridge() -> None:
    for path, names in imports_of("sim").items():
        assert not names & {"firmware_bridge", "vdm_aero_cli"}, f"{path} imports {names}"


def test_only_the_bridge_and_the_world_touch_mavlink() -> None:
    for path, names in imports_of("vdm_aero_cli").items():
        assert "pymavlink" not in names, f"{path}: the CLI wires, it does not speak MAVLink"


def test_no_import_time_side_effects_in_library_modules() -> None:
    # pymavlink's counter-example: no os.environ writes at import time anywhere in our packages
    for pkg in ("vdm_aero", "sim", "firmware_bridge"):
        for path in (ROOT / pkg).rglob("*.py"):
            assert "os.environ[" not in path.read_text(), f"{path} writes the environment"


def test_the_world_owns_its_contract() -> None:
    # sim.flight is the world: it takes nothing from the mock autopilot that consumes it
    for path, names in _full_imports("sim/flight").items():
        assert not [n for n in names if n.startswith("sim.sitl")], f"{path} imports {sorted(names)}"


def test_geodesy_behind_one_door() -> None:
    users = [p for pkg in ("vdm_aero", "sim", "vdm_aero_cli", "firmware_bridge") for p, n in imports_of(pkg).items()
             if "pymap3d" in n]  # fmt: skip
    assert users == ["vdm_aero/geodesy.py"], users


def test_one_copy_of_the_shared_constants() -> None:
    # WGS-84, ISA and the quaternion formulas live in vdm_aero (geodesy, atmosphere, rotation)
    for pkg in ("sim", "vdm_aero_cli", "firmware_bridge"):
        for path in (ROOT / pkg).rglob("*.py"):
            text = path.read_text()
            for marker in ("6378137", "101325", "288.15", "def quat_to_dcm", "def euler_zyx"):
                assert marker not in text, f"{path} has its own copy of {marker}"


def test_filterpy_behind_one_adapter() -> None:
    users = [p for pkg in ("vdm_aero", "sim", "vdm_aero_cli", "firmware_bridge") for p, n in imports_of(pkg).items()
             if "filterpy" in n]  # fmt: skip
    assert users == ["vdm_aero/nav/engine.py"], users


def test_navigation_knows_nothing_of_the_world() -> None:
    # no inverse crime: the filter and what it uses never import the simulator (its truth or its parameters)
    for path, names in _full_imports("vdm_aero/nav").items():
        assert not [n for n in names if n.split(".")[0] in {"sim", "vdm_aero_cli", "firmware_bridge"}], path


def test_the_bridge_is_the_aircraft_side() -> None:
    # firmware_bridge runs on the companion computer: no world, no CLI, no training stack
    for path, names in imports_of("firmware_bridge").items():
        assert not names & {"sim", "vdm_aero_cli", "torch", "onnx", "matplotlib"}, f"{path} imports {sorted(names)}"


def test_service_and_replay_drive_the_same_filter_code() -> None:
    # one code path from SI measurements to the filters: the service, the log replay and the benchmark
    full = {**_full_imports("firmware_bridge"), **_full_imports("vdm_aero/nav")}
    assert "vdm_aero.nav.driver" in full["firmware_bridge/service.py"]
    assert "vdm_aero.nav.driver" in full["vdm_aero/nav/stream.py"]
    assert "vdm_aero.nav.stream" in _full_imports("vdm_aero_cli")["vdm_aero_cli/nav_bench.py"]


def test_replay_reads_logs_as_the_service_reads_the_link() -> None:
    # the replay runs the benchmark's runner; the service and the tlog reader decode MAVLink with one decoder,
    # and only the decoder calls the converters of firmware_bridge.units (one table, message type → SI)
    full = {**_full_imports("firmware_bridge"), **_full_imports("vdm_aero/nav")}
    assert "vdm_aero.nav.stream" in full["vdm_aero/nav/replay.py"]
    assert "firmware_bridge.decode" in full["firmware_bridge/service.py"]
    assert "firmware_bridge.decode" in full["firmware_bridge/logs/tlog.py"]
    assert "vdm_aero.nav.replay" in _full_imports("vdm_aero_cli")["vdm_aero_cli/cmd_replay.py"]
    converters = sorted(
        str(p.relative_to(ROOT))
        for p in (ROOT / "firmware_bridge").rglob("*.py")
        if p.name != "units.py" and ("units.from_" in p.read_text() or "import from_" in p.read_text())
    )
    assert converters == ["firmware_bridge/decode.py"], converters


def test_log_formats_and_the_magnetic_model_behind_one_door_each() -> None:
    users: dict[str, list[str]] = {"pyulog": [], "pygeomag": []}
    for pkg in ("vdm_aero", "sim", "vdm_aero_cli", "firmware_bridge"):
        for p, n in imports_of(pkg).items():
            for lib in users:
                if lib in n:
                    users[lib].append(p)
    assert users == {"pyulog": ["firmware_bridge/logs/ulog.py"], "pygeomag": ["vdm_aero/geomagnetism.py"]}, users
    dfreader = [
        p
        for pkg in ("vdm_aero", "sim", "vdm_aero_cli", "firmware_bridge")
        for p in (ROOT / pkg).rglob("*.py")
        if "DFReader" in p.read_text() and p.name != "__init__.py"
    ]
    assert [str(p.relative_to(ROOT)) for p in dfreader] == ["firmware_bridge/logs/dataflash.py"], dfreader


def test_the_real_time_flights_named_first_exist_and_make_test_keeps_their_order() -> None:
    # a renamed flight module would silently fall back to the end of the queue, where one worker took the last
    # flights in a row while the other idled; xdist's reordering by test count would undo the order altogether
    from tests.conftest import REAL_TIME_FIRST

    missing = [name for name in REAL_TIME_FIRST if not (ROOT / "tests" / name).is_file()]
    assert not missing, missing
    test_rule = (ROOT / "Makefile").read_text().split("\ntest:", 1)[1].split("\n\n", 1)[0]
    assert "--dist loadscope" in test_rule and "--no-loadscope-reorder" in test_rule, test_rule
