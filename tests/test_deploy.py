"""The systemd deployment in deploy/: the unit passes systemd's own checker, install.sh plans every step and
changes nothing under --dry-run, keeps an operator's config, is idempotent for real, and lints clean."""

from __future__ import annotations

import configparser
import os
import shlex
import subprocess
import sys
from pathlib import Path, PurePosixPath

import pytest
import yaml

from tests.conftest import require_tool

REPO = Path(__file__).resolve().parents[1]
DEPLOY = REPO / "deploy"
INSTALL = DEPLOY / "install.sh"
UNIT = DEPLOY / "vdm-aero.service"
ROUTER_CONF = DEPLOY / "routers" / "mavlink-router.conf"
MAVPROXY_UNIT = DEPLOY / "routers" / "mavproxy.service"
TEMPLATE_PREFIX = "/opt/vdm-aero"


def _install(
    *args: str | Path, check: bool = True, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        ["bash", str(INSTALL), *map(str, args)], capture_output=True, text=True, timeout=600, check=False, env=env
    )
    if check:
        assert proc.returncode == 0, f"install.sh {args} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return proc


def _snapshot(top: Path) -> list[tuple[str, int, int, int]]:
    """Every path under ``top`` with mode, size and mtime: equal snapshots mean nothing was touched."""
    return sorted(
        (str(p.relative_to(top)), (st := p.lstat()).st_mode, st.st_size, st.st_mtime_ns) for p in top.rglob("*")
    )


def _parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """systemd's syntax line-wise: repeated keys accumulate (configparser would keep only the last After=)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        assert not line.endswith("\\"), f"continuation lines are not parsed here: {raw!r}"
        if line.startswith("["):
            current = sections.setdefault(line.strip("[]"), {})
            continue
        assert current is not None, f"key before any section: {raw!r}"
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {raw!r}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


def _verify(analyze: str, unit: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60, check=False)


def _inputs(tmp_path: Path) -> tuple[Path, Path, Path]:
    """An empty root, a models directory and a config, all under tmp_path."""
    root = tmp_path / "root"
    root.mkdir()
    models = tmp_path / "models"
    models.mkdir()
    (models / "net.onnx").write_bytes(b"onnx")
    config = tmp_path / "config.yaml"
    config.write_text("connection: udpin://127.0.0.1:14551\n")
    return root, models, config


def _plan(stdout: str) -> list[str]:
    return [line.removeprefix("would: ") for line in stdout.splitlines() if line.startswith("would: ")]


# A PEP 517 backend in the stand-in's own tree: pip builds it offline (no setuptools to fetch into the isolated
# build environment). The wheel holds one module and the vdm-aero console script.
_FAKE_BACKEND = """\
import base64, hashlib, os, zipfile

DIST = "vdm_aero-0.0.0.dist-info"


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    with open("fakevdm.py", "rb") as f:
        files = {"fakevdm.py": f.read()}
    files[DIST + "/METADATA"] = b"Metadata-Version: 2.1\\nName: vdm-aero\\nVersion: 0.0.0\\n"
    files[DIST + "/WHEEL"] = b"Wheel-Version: 1.0\\nGenerator: test\\nRoot-Is-Purelib: true\\nTag: py3-none-any\\n"
    files[DIST + "/entry_points.txt"] = b"[console_scripts]\\nvdm-aero = fakevdm:main\\n"
    record = ""
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record += f"{name},sha256={digest},{len(data)}\\n"
    files[DIST + "/RECORD"] = (record + DIST + "/RECORD,,\\n").encode()
    wheel = "vdm_aero-0.0.0-py3-none-any.whl"
    with zipfile.ZipFile(os.path.join(wheel_directory, wheel), "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return wheel
"""

# The stand-in's check: exit 2 with one line when the config says "bad", like `serve --check-config`.
_FAKE_CLI = """\
import sys


def main():
    with open(sys.argv[sys.argv.index("--config") + 1]) as f:
        if "bad" in f.read():
            print("config: bad value")
            sys.exit(2)
"""


def _fake_source(src: Path) -> Path:
    src.mkdir()
    (src / "pyproject.toml").write_text(
        '[build-system]\nrequires = []\nbuild-backend = "backend"\nbackend-path = ["."]\n'
    )
    (src / "backend.py").write_text(_FAKE_BACKEND)
    (src / "fakevdm.py").write_text(_FAKE_CLI)
    return src


def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    analyze = require_tool("systemd-analyze", "systemd")
    # verify checks that ExecStart's binary exists: render the unit as install.sh does, for a prefix in tmp_path
    # that holds an executable vdm-aero. Only the prefix differs from what lands in /etc/systemd/system.
    prefix = tmp_path / "prefix"
    exe = prefix / "venv" / "bin" / "vdm-aero"
    exe.parent.mkdir(parents=True)
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    rendered = _install("--print-unit", "--prefix", prefix).stdout
    assert f"ExecStart={exe} serve --config /etc/vdm-aero/config.yaml\n" in rendered
    assert TEMPLATE_PREFIX + "/" not in rendered
    unit = tmp_path / "vdm-aero.service"  # verify also checks the file name is a valid unit name
    unit.write_text(rendered)

    proc = _verify(analyze, unit)
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, "", "")

    # The check is not vacuous here: a misspelt key in the same file is reported.
    unit.write_text(rendered.replace("NoNewPrivileges=", "NoNewPrivilege="))
    assert "NoNewPrivilege" in _verify(analyze, unit).stderr


def test_prefix_must_be_a_plain_absolute_path() -> None:
    # It lands unquoted in ExecStart= and in a sed replacement.
    for bad in ("opt/vdm-aero", "/opt/vdm aero", "/opt/a|b", "/opt/a&b"):
        proc = _install("--print-unit", "--prefix", bad, check=False)
        assert (proc.returncode, proc.stdout) == (1, ""), bad
        assert "--prefix" in proc.stderr


def test_unit_has_the_service_contract_and_hardening() -> None:
    unit = _parse_unit(UNIT.read_text())
    service, deps = unit["Service"], unit["Unit"]
    expected = {
        "Type": ["notify"],
        "NotifyAccess": ["main"],
        "ExecStart": [f"{TEMPLATE_PREFIX}/venv/bin/vdm-aero serve --config /etc/vdm-aero/config.yaml"],
        "WatchdogSec": ["10"],
        "Restart": ["on-failure"],
        "RestartSec": ["2"],
        "RestartPreventExitStatus": ["2"],
        "User": ["vdm-aero"],
        "Group": ["vdm-aero"],
        "SupplementaryGroups": ["dialout"],
        "StateDirectory": ["vdm-aero"],
        "NoNewPrivileges": ["yes"],
        "ProtectSystem": ["strict"],
        "ProtectHome": ["yes"],
        "PrivateTmp": ["yes"],
        "Environment": ["PYTHONUNBUFFERED=1"],
    }
    assert {key: service.get(key) for key in expected} == expected
    # Saving state on SIGTERM takes a few seconds: a bounded stop, shorter than the 90 s default.
    assert len(service["TimeoutStopSec"]) == 1 and 3 <= int(service["TimeoutStopSec"][0]) < 90
    # sd_notify needs AF_UNIX; the MAVLink link needs IP.
    assert set(service["RestrictAddressFamilies"][0].split()) == {"AF_UNIX", "AF_INET", "AF_INET6"}
    # Would hide /dev/ttyAMA0 (PrivateDevices), turn on the device allow-list (ProtectClock), or kill
    # onnxruntime at model load (MemoryDenyWriteExecute).
    assert not {"PrivateDevices", "ProtectClock", "MemoryDenyWriteExecute", "DeviceAllow"} & service.keys()

    after = " ".join(deps["After"]).split()
    assert "network.target" in after and "mavlink-router.service" in after
    assert deps["Wants"] == ["mavlink-router.service"]
    # Only the weak dependency: a missing or failed router must not stop navigation from starting.
    assert not {"Requires", "Requisite", "BindsTo", "PartOf"} & deps.keys()
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


def test_dry_run_plans_every_step_and_changes_nothing(tmp_path: Path) -> None:
    root, models, config = _inputs(tmp_path)
    before = _snapshot(tmp_path)
    proc = _install("--dry-run", "--root", root, "--models", models, "--config", config)
    assert _snapshot(tmp_path) == before
    plan = _plan(proc.stdout)
    # An empty root has nothing installed: every line is an action.
    assert len(plan) == len(proc.stdout.splitlines()), proc.stdout

    opt, etc = f"{root}{TEMPLATE_PREFIX}", f"{root}/etc"
    useradd = next(line for line in plan if line.startswith("useradd "))
    for part in ("--system", "--no-create-home", "--shell /usr/sbin/nologin", "--groups dialout", f"--root {root}"):
        assert part in useradd
    assert useradd.endswith(" vdm-aero")
    assert any(line.endswith(f" -m venv {opt}/venv") for line in plan)
    # The source tree as a plain path: base dependencies only, no [extras] (no torch on the vehicle).
    assert f"{opt}/venv/bin/pip install --disable-pip-version-check --upgrade {REPO}" in plan
    # Models: copied beside, then renamed into place.
    assert f"cp -R {models} {opt}/.models.new" in plan
    assert f"mv -T {opt}/.models.new {opt}/models" in plan
    assert any(line.endswith(f" {config} {etc}/vdm-aero/config.yaml") for line in plan)
    check = f"{opt}/venv/bin/vdm-aero serve --check-config --config {etc}/vdm-aero/config.yaml"
    unit = f"render {UNIT} with prefix {TEMPLATE_PREFIX} to {etc}/systemd/system/vdm-aero.service"
    enable = f"systemctl --root {root} enable vdm-aero"
    # The config is checked before systemd hears of the service.
    assert plan.index(check) < plan.index(unit) < plan.index(enable)


def test_dry_run_keeps_an_operators_config(tmp_path: Path) -> None:
    root, models, config = _inputs(tmp_path)
    installed = root / "etc" / "vdm-aero" / "config.yaml"
    installed.parent.mkdir(parents=True)
    installed.write_text("connection: serial:///dev/ttyAMA0:921600  # the operator's edit\n")
    before = _snapshot(tmp_path)
    proc = _install("--dry-run", "--root", root, "--models", models, "--config", config)
    assert _snapshot(tmp_path) == before
    assert "keep: /etc/vdm-aero/config.yaml differs" in proc.stdout
    plan = _plan(proc.stdout)
    assert any(line.endswith(f" {config} {installed}.new") for line in plan)
    assert not any(line.endswith(f" {installed}") for line in plan if line.startswith("install "))
    # What gets checked is the config the service will read: the operator's.
    assert any(line.endswith(f"--check-config --config {installed}") for line in plan)


def test_first_install_without_models_is_refused(tmp_path: Path) -> None:
    root, _, config = _inputs(tmp_path)
    proc = _install("--dry-run", "--root", root, "--config", config, check=False)
    assert proc.returncode != 0
    assert "--models" in proc.stderr and proc.stdout == ""


def test_real_install_is_idempotent_and_stops_on_a_bad_config(tmp_path: Path) -> None:
    """A real run into a --root tree with a stand-in package (no dependencies; its vdm-aero's --check-config
    rejects 'bad'): the second run changes nothing, a failing check installs no unit."""
    if os.geteuid() != 0:
        reason = "install.sh creates users and chowns files: run as root (CI does)"
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    require_tool("useradd", "passwd")
    require_tool("systemctl", "systemd")
    root, models, config = _inputs(tmp_path)
    (root / "etc").mkdir()
    (root / "etc" / "passwd").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (root / "etc" / "group").write_text("root:x:0:\ndialout:x:20:\n")
    for name, line in (("shadow", "root:*:19000:0:99999:7:::\n"), ("gshadow", "root:*::\ndialout:*::\n")):
        (root / "etc" / name).write_text(line)
        (root / "etc" / name).chmod(0o600)
    source = _fake_source(tmp_path / "src")
    args = ("--root", root, "--source", source, "--models", models, "--config", config, "--python", sys.executable)

    # No index: the stand-in builds with its own in-tree backend, and nothing else may be fetched.
    env = {**os.environ, "PIP_NO_INDEX": "1"}
    first = _install(*args, env=env)
    assert "run: systemctl --root" in first.stdout
    assert "vdm-aero:" in (root / "etc" / "passwd").read_text()
    assert (root / "etc" / "group").read_text().count("vdm-aero") == 2  # its own group, and dialout
    assert (root / "opt" / "vdm-aero" / "models" / "net.onnx").read_bytes() == b"onnx"
    assert (root / "etc" / "vdm-aero" / "config.yaml").read_text() == config.read_text()
    unit = root / "etc" / "systemd" / "system" / "vdm-aero.service"
    assert unit.read_text() == UNIT.read_text()  # default prefix: rendered unchanged
    assert (unit.parent / "multi-user.target.wants" / "vdm-aero.service").is_symlink()

    before = _snapshot(root)
    second = _install(*args, env=env)
    assert _snapshot(root) == before
    actions = [line for line in second.stdout.splitlines() if not line.startswith("ok: ")]
    assert len(actions) == 1 and "--check-config" in actions[0], second.stdout  # the check always runs

    (root / "etc" / "vdm-aero" / "config.yaml").write_text("bad: yes\n")
    unit.unlink()
    failed = _install(*args, check=False, env=env)
    assert failed.returncode != 0
    assert "config check failed" in failed.stderr and "config: bad value" in failed.stderr
    assert not unit.exists()


def test_install_script_parses_and_passes_shellcheck() -> None:
    proc = subprocess.run(["bash", "-n", str(INSTALL)], capture_output=True, text=True, check=False)
    assert (proc.returncode, proc.stderr) == (0, "")
    shellcheck = require_tool("shellcheck", "shellcheck")
    proc = subprocess.run([shellcheck, str(INSTALL)], capture_output=True, text=True, timeout=60, check=False)
    assert (proc.returncode, proc.stdout + proc.stderr) == (0, "")


def test_mavproxy_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    analyze = require_tool("systemd-analyze", "systemd")
    text = MAVPROXY_UNIT.read_text()
    (exec_start,) = _parse_unit(text)["Service"]["ExecStart"]
    binary = shlex.split(exec_start)[0]
    stub = tmp_path / "bin" / "mavproxy.py"  # verify wants ExecStart's binary to exist: the same unit, another path
    stub.parent.mkdir()
    stub.write_text("#!/bin/sh\n")
    stub.chmod(0o755)
    unit = tmp_path / "mavproxy.service"
    unit.write_text(text.replace(binary, str(stub)))
    proc = _verify(analyze, unit)
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, "", "")


def _router_conf() -> configparser.ConfigParser:
    # No inline comments, like mavlink-router: a '#' after a value would be part of the value.
    conf = configparser.ConfigParser(interpolation=None)
    conf.read_string(ROUTER_CONF.read_text())
    return conf


def test_routers_send_where_the_shipped_config_listens() -> None:
    connection = yaml.safe_load((DEPLOY / "config.yaml").read_text())["connection"]
    assert connection == "udpin://127.0.0.1:14551"

    conf = _router_conf()
    assert conf.sections() == ["General", "UartEndpoint autopilot", "UdpEndpoint vdm-aero"]  # gcs: commented
    # Only keys that mavlink-router's config.sample documents (a misspelt key is ignored, not reported).
    known = {
        "General": {"tcpserverport", "reportstats", "debugloglevel"},
        "UartEndpoint": {"device", "baud", "flowcontrol"},
        "UdpEndpoint": {"mode", "address", "port"},
    }
    for name in conf.sections():
        assert set(conf[name]) <= known[name.split()[0]], name
        assert not any("#" in value for value in conf[name].values()), name
    assert conf["General"].getboolean("reportstats") is False
    udp = conf["UdpEndpoint vdm-aero"]
    assert (udp["mode"].lower(), f"udpin://{udp['address']}:{udp['port']}") == ("normal", connection)

    # MAVProxy: the same serial port and baud, sent to the same place.
    args = shlex.split(_parse_unit(MAVPROXY_UNIT.read_text())["Service"]["ExecStart"][0])
    uart = conf["UartEndpoint autopilot"]
    assert f"--master={uart['device']},{uart['baud']}" in args
    assert "--out=udpout:" + connection.removeprefix("udpin://") in args
    assert {"--daemon", "--non-interactive"} <= set(args)


def test_shipped_config_writes_only_to_the_state_directory() -> None:
    """ProtectSystem=strict leaves StateDirectory= the only writable place: a state or log path elsewhere would
    fail on the vehicle, not here. Models are read from the install prefix."""
    (state_dir,) = _parse_unit(UNIT.read_text())["Service"]["StateDirectory"]
    cfg = yaml.safe_load((DEPLOY / "config.yaml").read_text())
    writes = [cfg["state"]["file"], cfg["nav_log"]["file"]]
    assert writes[0] is not None
    for path in filter(None, writes):  # nav_log.file may be null (no log)
        assert PurePosixPath(path).is_relative_to(f"/var/lib/{state_dir}"), path
    reads = [cfg["models"][key] for key in ("design_data", "deim", "deim_nn")]
    for path in filter(None, reads):  # deim_nn may be null (no correction net)
        assert PurePosixPath(path).is_relative_to(f"{TEMPLATE_PREFIX}/models"), path
