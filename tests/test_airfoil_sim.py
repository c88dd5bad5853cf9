"""Spec parsing, presets and the spec → data set driver."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from sim.airfoil.simulate import AirfoilSimulator, simulate_spec
from sim.airfoil.spec import load_spec, parse_spec
from sim.presets import preset_names, preset_text
from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import load_dataset, validate_dataset, write_dataset
from vdm_aero.errors import SpecError

SEP = {"alpha1_deg": 12.1, "s1_deg": 0.8, "s2_deg": 5.5, "slope_factor": 0.87}


def tiny_spec(**over: object) -> dict:
    d: dict = {
        "kind": "airfoil",
        "name": "tiny-0012",
        "airfoil": "naca0012",
        "chord_m": 0.2,
        "span_m": 0.1,
        "surface_points": 120,
        "speed_m_s": 15.0,
        "motion": {
            "type": "sinusoidal_pitch",
            "alpha0_deg": 8.0,
            "amplitude_deg": 6.0,
            "freqs_hz": [1.0, 3.0],
            "cycles": 1,
            "samples_per_cycle": 32,
        },
        "effects": {"circulation_lag": {}, "trailing_edge_separation": SEP, "viscous_drag": {}},
        "seed": 3,
    }
    d.update(over)
    return d


@pytest.mark.parametrize(
    ("mutate", "phrase"),
    [
        (lambda d: d.pop("chord_m"), "chord_m: missing required key"),
        (lambda d: d.update(chrod_m=1.0), "chrod_m: unknown key"),
        (lambda d: d.update(kind="wing"), "kind: 'wing' is not an airfoil spec"),
        (lambda d: d.update(airfoil="clarky"), "airfoil: expected a NACA 4-digit"),
        (lambda d: d.update(speed_m_s=-3), "speed_m_s: must be > 0"),
        (lambda d: d["motion"].update(freqs_hz=[]), "motion.freqs_hz"),
        (lambda d: d["effects"].update(dynamic_stall={}), "effects.dynamic_stall: unknown effect"),
        (lambda d: d["effects"].update(added_mass={"scael": 1}), "effects.added_mass.scael: unknown param"),
        (lambda d: d["effects"].update(viscous_drag={"cf": 5.0}), "far outside the physical range"),
        (lambda d: d["effects"].update(separation_lag={}) or d["effects"].pop("trailing_edge_separation"),
         "requires effect 'trailing_edge_separation'"),
        (lambda d: d.update(taps={"x_c": [0.1, 1.2], "surface": ["upper", "lower"]}), "taps.x_c"),
        (lambda d: d.update(noise={"cp_std": 0.1}), "noise.cp_std: unknown key"),
        (lambda d: d["effects"].update(port_bias={"p9999": 0.05}) or
         d.update(taps={"x_c": [0.1], "surface": ["upper"]}), "no tap of that name"),
    ],
)  # fmt: skip
def test_bad_specs_name_the_key(mutate, phrase: str) -> None:
    d = tiny_spec()
    mutate(d)
    with pytest.raises(SpecError, match=None) as e:
        parse_spec(d, origin="my.yaml")
    msg = str(e.value)
    assert msg.startswith("my.yaml: ") and phrase in msg and "\n" not in msg


def test_yaml_syntax_error_names_file_and_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("kind: airfoil\nmotion: [1, 2\n")
    with pytest.raises(SpecError, match=r"bad\.yaml: YAML syntax error at line \d"):
        load_spec(p)


def test_spec_round_trips_through_yaml() -> None:
    spec = parse_spec(tiny_spec())
    again = parse_spec(yaml.safe_load(yaml.safe_dump(spec.to_dict())))
    assert again == spec


def test_presets_parse_and_have_the_method_conditions() -> None:
    assert {"naca0015-urans", "naca0015-tunnel"} <= set(preset_names())
    urans = parse_spec(yaml.safe_load(preset_text("naca0015-urans")))
    tunnel = parse_spec(yaml.safe_load(preset_text("naca0015-tunnel")))
    for s in (urans, tunnel):
        assert (s.motion.alpha0_deg, s.motion.amplitude_deg, s.speed_m_s, s.chord_m) == (20.0, 8.0, 30.0, 0.3)
        assert s.density_kg_m3 == 1.146 and s.kinematic_viscosity_m2_s == 1.655e-5
        assert s.chord_m * s.span_m == pytest.approx(0.0225)
    assert urans.surface_points == 1316 and urans.taps is None
    np.testing.assert_allclose(urans.motion.freqs_hz, np.linspace(0.5, 5.0, 10))
    assert tunnel.taps is not None and len(tunnel.taps.x_c) == 36
    roles = dict(zip(tunnel.motion.freqs_hz, tunnel.motion.case_roles, strict=True))
    assert roles == {0.796: "train", 2.387: "train", 3.183: "train", 4.775: "train", 1.592: "validation",
                     3.979: "test"}  # fmt: skip
    # the tunnel carries effects the simulation side lacks
    assert {"incidence_offset", "lift_slope_scale", "port_lag", "port_bias"} <= set(tunnel.effects) - set(urans.effects)


def test_simulated_dataset_is_valid_and_reproducible(tmp_path: Path) -> None:
    spec = parse_spec(tiny_spec(noise={"cp_std_fraction": 0.01}))
    a, b = simulate_spec(spec), simulate_spec(spec)
    validate_dataset(a)
    np.testing.assert_array_equal(a.cp, b.cp)  # same seed, same draws
    c = simulate_spec(parse_spec(tiny_spec(noise={"cp_std_fraction": 0.01}, seed=4)))
    assert not np.array_equal(a.cp, c.cp)
    np.testing.assert_array_equal(a.coeffs, c.coeffs)  # noise is on the ports, never on the truth
    assert a.cp.shape == (64, 120) and a.n_snapshots == 64
    path = write_dataset(tmp_path / "ds", a)
    back = load_dataset(path)
    np.testing.assert_array_equal(np.asarray(back.cp), a.cp)
    assert back.extra["spec"]["effects"]["trailing_edge_separation"] == SEP
    # t restarts per case; case ids and metadata are consistent
    assert back.t[back.case == 1][0] == 0.0
    assert back.cases[1].freq_hz == 3.0
    assert back.cases[1].meta["reduced_frequency"] == pytest.approx(math.pi * 3.0 * 0.2 / 15.0)


def test_taps_dataset_holds_only_the_taps_and_truth_from_full_surface() -> None:
    taps = {"x_c": [0.0, 0.1, 0.5, 0.1, 0.5], "surface": ["upper", "upper", "upper", "lower", "lower"]}
    full = simulate_spec(parse_spec(tiny_spec()))
    tapped = simulate_spec(parse_spec(tiny_spec(taps=taps)))
    assert tapped.cp.shape == (64, 5)
    np.testing.assert_allclose(tapped.coeffs, full.coeffs)  # truth = full-resolution surface + friction
    # a tap Cp equals the full-surface Cp interpolated at the same station (0.1 c upper)
    s = AirfoilSimulator(parse_spec(tiny_spec()))
    xc, up = s.flow.panel_surface.x_c, s.flow.panel_surface.upper
    order = np.argsort(xc[up])
    cp_interp = [np.interp(0.1, xc[up][order], row[up][order]) for row in full.cp]
    np.testing.assert_allclose(tapped.cp[:, 1], cp_interp, atol=0.01)


def test_port_bias_offsets_only_the_named_tap() -> None:
    taps = {"x_c": [0.05, 0.3], "surface": ["upper", "lower"], "names": ["A", "B"]}
    base = simulate_spec(parse_spec(tiny_spec(taps=taps)))
    d = tiny_spec(taps=taps)
    d["effects"]["port_bias"] = {"B": 0.07}
    biased = simulate_spec(parse_spec(d))
    np.testing.assert_allclose(biased.cp[:, 1] - base.cp[:, 1], 0.07, atol=1e-12)
    np.testing.assert_array_equal(biased.cp[:, 0], base.cp[:, 0])
    np.testing.assert_array_equal(biased.coeffs, base.coeffs)


def test_stagnation_pressure_is_one_in_attached_flow() -> None:
    ds = simulate_spec(parse_spec(tiny_spec(effects={}, surface_points=400)))
    assert np.max(ds.cp) == pytest.approx(1.0, abs=5e-3)


def test_naca0015_presets_show_dynamic_stall() -> None:
    spec = parse_spec(yaml.safe_load(preset_text("naca0015-urans")))
    sim = AirfoilSimulator(spec)
    for f in (3.0, 5.0):
        run = sim.run_frequency(f)
        cl, _ = lift_drag(run.coeffs, run.alpha)
        i = int(np.argmax(cl))
        assert np.gradient(run.alpha)[i] > 0, "max lift must be on the upstroke"
        assert 23.0 < math.degrees(run.alpha[i]) < 28.0
        # hysteresis: upstroke lift exceeds downstroke lift at the same α in the stall range
        a_deg = np.degrees(run.alpha)
        up, down = np.gradient(run.alpha) > 0, np.gradient(run.alpha) < 0
        near = np.abs(a_deg - 24.0) < 0.5
        assert cl[up & near].mean() - cl[down & near].mean() > 0.2
        assert cl.max() > 1.4  # above the static C_L,max of ≈ 1.3
