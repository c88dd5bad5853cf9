"""The vdm-aero command: subcommands, help, and one-line user errors with exit code 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from vdm_aero.dataset import load_dataset
from vdm_aero_cli.main import main

SPEC = """\
kind: airfoil
name: hand-written-0012
airfoil: naca0012
chord_m: 0.25
span_m: 0.5
surface_points: 160
speed_m_s: 18.0
density_kg_m3: 1.2
kinematic_viscosity_m2_s: 1.5e-5
motion: {type: sinusoidal_pitch, alpha0_deg: 10.0, amplitude_deg: 5.0, pivot_x_c: 0.3,
         freqs_hz: [1.5, 2.5], cycles: 1, samples_per_cycle: 24}
effects:
  circulation_lag: {}
  added_mass: {}
  trailing_edge_separation: {alpha1_deg: 13.0, s1_deg: 1.5, s2_deg: 4.0, slope_factor: 0.9}
  separation_lag: {}
  viscous_drag: {}
taps: {x_c: [0.0, 0.05, 0.2, 0.6, 0.05, 0.2, 0.6], surface: [upper, upper, upper, upper, lower, lower, lower]}
noise: {cp_std_fraction: 0.01}
seed: 1
"""


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "vdm_aero_cli.main", *args], capture_output=True, text=True, timeout=120
    )


def test_simulate_hand_written_spec_and_plot(tmp_path: Path) -> None:
    spec = tmp_path / "my.yaml"
    spec.write_text(SPEC)
    assert main(["simulate", str(spec), "--out", str(tmp_path / "ds")]) == 0
    ds = load_dataset(tmp_path / "ds")
    assert ds.cp.shape == (48, 7) and ds.reference.area_m2 == pytest.approx(0.125)
    assert np.all(np.isfinite(ds.cp))
    assert main(["plot-dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_list_and_print_spec(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--list"]) == 0
    names = capsys.readouterr().out.split()
    assert "naca0015-urans" in names and "naca0015-tunnel" in names
    assert main(["simulate", "--print-spec", "naca0015-tunnel"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["name"] == "naca0015-tunnel" and len(printed["taps"]["x_c"]) == 36


@pytest.mark.parametrize(
    ("args", "phrase"),
    [
        (["simulate", "no-such-preset", "--out", "x"], "no-such-preset: no such preset"),
        (["simulate", "--print-spec", "nope"], "nope: no such preset"),
        (["plot-dataset", "/nonexistent/ds", "--out", "x.png"], "/nonexistent/ds"),
        (["bench", "nav-drift", "--scenario", "bogus"], "--scenario: unknown ['bogus']"),
        (["bench", "nav-drift", "--modes", "ins,warp"], "--modes: unknown ['warp']"),
        (["bench", "nav-drift", "--outage-s", "60,x"], "--outage-s: '60,x' is not a list of seconds"),
        (["bench", "nav-drift", "--models", "/nonexistent/m"], "/nonexistent/m/data/uav-envelope/dataset.yaml missing"),
    ],
)
def test_user_errors_are_one_line_exit_2(args: list[str], phrase: str) -> None:
    r = run_cli(*args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdm-aero: error: ") and phrase in lines[0]
    assert "Traceback" not in r.stderr


def test_bad_spec_file_is_one_line_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(SPEC.replace("speed_m_s: 18.0", "speed_m_s: fast"))
    r = run_cli("simulate", str(bad), "--out", str(tmp_path / "o"))
    assert r.returncode == 2
    assert r.stderr.strip() == f"vdm-aero: error: {bad}: speed_m_s: expected a number, got 'fast'"
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_malformed_dataset_is_one_line_exit_2(tmp_path: Path) -> None:
    spec = tmp_path / "my.yaml"
    spec.write_text(SPEC)
    assert main(["simulate", str(spec), "--out", str(tmp_path / "ds")]) == 0
    np.save(tmp_path / "ds" / "alpha.npy", np.zeros(3))
    r = run_cli("plot-dataset", str(tmp_path / "ds"), "--out", str(tmp_path / "p.png"))
    assert r.returncode == 2 and "alpha.npy" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_every_subcommand_has_help() -> None:
    for cmd in ("simulate", "plot-dataset", "demo"):
        r = run_cli(cmd, "--help")
        assert r.returncode == 0 and "usage: vdm-aero" in r.stdout
