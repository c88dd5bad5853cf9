"""The 3-D fixed-wing UAV surface-pressure model (sim.airframe): geometry, lattice, pressures, specs,
data sets. Small surfaces (N ≈ 600–2,000) and explicit separation fits keep it fast and offline."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from sim.airframe.geometry import (
    FUSELAGE,
    HTAIL_L,
    HTAIL_R,
    VTAIL,
    WING_L,
    WING_R,
    build_geometry,
    default_design,
    surface_for,
)
from sim.airframe.pressure import BLOCK_STATES, AirframePressureModel, ScratchBuffers
from sim.airframe.simulate import STATES_FILE, simulate_airframe, write_airframe_dataset
from sim.airframe.spec import parse_airframe_spec
from sim.airframe.vlm import STATE_COLUMNS, FlightStates, VlmResolution, VortexLattice
from sim.presets import preset_names, preset_text
from vdm_aero.coefficients import lift_drag
from vdm_aero.dataset import Reference, load_dataset, validate_dataset, write_dataset
from vdm_aero.errors import SpecError

# explicit static-separation fits (no NeuralFoil in the tests)
SEP = {
    "naca2412": {"alpha1_deg": 12.0, "s1_deg": 2.5, "s2_deg": 4.0, "slope_factor": 0.92},
    "naca0009": {"alpha1_deg": 9.0, "s1_deg": 2.0, "s2_deg": 1.5, "slope_factor": 0.95},
}
FULL_QS = {"trailing_edge_separation": {}, "added_mass": {"scale": 1.0}, "viscous_drag": {"cf": 0.004}}
LIFTING = (WING_R, WING_L, HTAIL_R, HTAIL_L, VTAIL)


@pytest.fixture(scope="module")
def geo2000() -> Any:
    return build_geometry(default_design(), surface_for(2000))


@pytest.fixture(scope="module")
def potential(geo2000: Any) -> AirframePressureModel:
    """Attached potential flow: no separation, no friction."""
    return AirframePressureModel(geo2000)


@pytest.fixture(scope="module")
def viscous(geo2000: Any) -> AirframePressureModel:
    return AirframePressureModel(geo2000, effects=FULL_QS, separation=SEP)


# ------------------------------------------------------------------------------------------ geometry
@pytest.mark.parametrize("target", [300, 2000, 20000, 300000])
def test_surface_resolution_hits_the_requested_point_count(target: int) -> None:
    res = surface_for(target)
    assert abs(res.n_points - target) <= 0.05 * target
    if target <= 2000:
        geo = build_geometry(default_design(), res)
        assert geo.n_points == res.n_points
    if target == 300000:  # build the big one too (no evaluation): shapes and unit normals
        geo = build_geometry(default_design(), res)
        assert geo.points_b.shape == (res.n_points, 3)
        assert np.allclose(np.linalg.norm(geo.normals_b, axis=1), 1.0, atol=1e-9)


def test_geometry_is_closed_mirror_symmetric_and_balanced(geo2000: Any) -> None:
    g = geo2000
    assert np.allclose(np.linalg.norm(g.normals_b, axis=1), 1.0, atol=1e-12)
    assert np.all(g.areas_m2 > 0.0)
    # a uniform pressure exerts no force on the closed fuselage nor on any closed section strip
    fus = g.component_slice(FUSELAGE)
    avec = g.normals_b * g.areas_m2[:, None]
    assert np.abs(avec[fus].sum(axis=0)).max() < 1e-12
    wing = g.component_slice(WING_R)
    per_strip = np.zeros((g.resolution.wing_strips, 3))
    np.add.at(per_strip, g.strip[wing], avec[wing])
    e_s = g.parts[0].axes()[0]
    per_strip -= np.outer(per_strip @ e_s, e_s)  # only the open strip ends (normal to the span) remain
    assert np.abs(per_strip).max() < 1e-12
    # the left halves mirror the right
    for right, left in ((WING_R, WING_L), (HTAIL_R, HTAIL_L)):
        pr, pl = g.points_b[g.component_slice(right)], g.points_b[g.component_slice(left)]
        assert np.array_equal(pr * [1, -1, 1], pl)
    # normals point into the body: the fuselage's towards its axis, the wing's upper side down
    r_perp = g.points_b[fus] - [0.0, 0.0, g.fuselage_axis_z_m]
    assert np.all(np.einsum("ij,ij->i", r_perp[:, 1:], g.normals_b[fus, 1:]) < 0.0)
    up = (g.component == WING_R) & g.upper & (g.x_c > 0.3)
    assert np.all(g.normals_b[up, 2] > 0.0)
    # mass properties: 2.5 kg, CG at the origin, positive-definite inertia with Ixy = Iyz = 0
    assert g.mass_kg == pytest.approx(2.5)
    eig = np.linalg.eigvalsh(g.inertia_kg_m2)
    assert np.all(eig > 0.0)
    assert 0.05 < g.inertia_kg_m2[0, 0] < 0.5 and g.inertia_kg_m2[2, 2] > g.inertia_kg_m2[1, 1]
    assert g.inertia_kg_m2[0, 1] == 0.0 and g.inertia_kg_m2[1, 2] == 0.0
    ref = g.default_reference()
    assert ref.area_m2 == pytest.approx(0.39) and ref.span_m == pytest.approx(2.0)


# ---------------------------------------------------------------------------------------- symmetry
def test_symmetric_flight_gives_no_lateral_loads(viscous: AirframePressureModel) -> None:
    alpha = np.radians(np.linspace(-4.0, 24.0, 8))
    states = FlightStates.make(20.0, alpha_rad=alpha, q_rad_s=0.7, alpha_dot_rad_s=-0.4, elevator_rad=np.radians(5.0))
    cp, c = viscous.evaluate_states(states)
    scale = np.abs(c).max()
    assert np.abs(c[:, [1, 3, 5]]).max() <= 1e-10 * scale
    # and the pressure field itself is mirror-symmetric
    g = viscous.geometry
    assert np.allclose(cp[:, g.component_slice(WING_R)], cp[:, g.component_slice(WING_L)], rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------ control signs
def _delta(model: AirframePressureModel, **kw: float) -> np.ndarray:
    base = FlightStates.make(18.0, alpha_rad=math.radians(3.0))
    moved = FlightStates.make(18.0, alpha_rad=math.radians(3.0), **kw)
    return model.evaluate_states(moved)[1][0] - model.evaluate_states(base)[1][0]


@pytest.mark.parametrize("model_name", ["potential", "viscous"])
def test_control_deflections_give_moments_of_the_documented_sign(model_name: str, request: Any) -> None:
    model = request.getfixturevalue(model_name)
    d = math.radians(10.0)
    elev = _delta(model, elevator_rad=d)
    assert elev[4] < -0.1  # TE down → nose down (Cpitch < 0), and more lift (CZ more negative)
    assert elev[2] < 0.0
    ail = _delta(model, aileron_rad=d)
    assert ail[3] < -0.02  # right TE down / left TE up → roll left (Croll < 0)
    assert abs(ail[4]) < abs(ail[3]) and abs(ail[2]) < 0.01
    rud = _delta(model, rudder_rad=d)
    assert rud[1] > 0.005 and rud[5] < -0.002 and rud[3] > 0.0  # TE left → force right, nose left
    # stability derivatives: weathercock, dihedral effect, damping in roll, pitch and yaw
    beta = _delta(model, beta_rad=math.radians(5.0))
    assert beta[1] < 0.0 and beta[5] > 0.0 and beta[3] < 0.0
    assert _delta(model, p_rad_s=1.0)[3] < 0.0
    assert _delta(model, q_rad_s=0.5)[4] < 0.0
    assert _delta(model, r_rad_s=0.5)[5] < 0.0


# ------------------------------------------------------------------------------------ lift slope
def test_whole_aircraft_lift_slope_matches_lifting_line_with_tail_downwash(potential: AirframePressureModel) -> None:
    """Pressure-integrated C_Lα against Helmbold's wing + tail with the classical downwash gradient
    dε/dα = 2·a_w/(π·AR) (tail dynamic-pressure ratio 1, no fuselage lift): within 10 %."""
    m = potential
    al = np.radians([0.0, 2.0])
    c = m.evaluate_states(FlightStates.make(20.0, alpha_rad=al))[1]
    cl = lift_drag(c, al)[0]
    slope = float(np.diff(cl)[0] / np.diff(al)[0])
    d = m.geometry.design
    a0w = m.flows["naca2412"].cn_alpha
    a0h = m.flows["naca0009"].cn_alpha

    def helmbold(a0: float, ar: float) -> float:
        k = a0 / (math.pi * ar)
        return a0 / (math.sqrt(1.0 + k * k) + k)

    s_w, s_h = d.wing.area_m2, d.htail.area_m2
    a_w = helmbold(a0w, d.wing.span_m**2 / s_w)
    a_h = helmbold(a0h, d.htail.span_m**2 / s_h)
    deps = 2.0 * a_w / (math.pi * d.wing.span_m**2 / s_w)
    estimate = (a_w * s_w + a_h * s_h * (1.0 - deps)) / m.reference.area_m2
    assert slope == pytest.approx(estimate, rel=0.10)
    # the lattice's own downwash gradient at the tail is the classical one within 25 %
    vlm_deps = m.vlm.downwash_gradient()
    assert np.mean(vlm_deps[vlm_deps > 0]) == pytest.approx(deps, rel=0.25)


def test_lattice_agrees_with_aerosandbox_vlm_on_the_wing() -> None:
    """Cross-check against AeroSandbox's vortex lattice (camber-line panels, thin-airfoil sections): our
    lattice with a0 = 2π and the thin-airfoil zero-lift angle of NACA 2412; wing alone."""
    asb = pytest.importorskip("aerosandbox")
    d = default_design()
    wing = dataclasses.replace(d.wing, x_m=0.0, z_m=0.0)
    geo = build_geometry(dataclasses.replace(d, wing=wing), surface_for(600))
    parts = [p for p in geo.parts if p.component in (WING_R, WING_L)]
    a0l = math.radians(-2.0772)  # thin-airfoil zero-lift angle of NACA 2412
    lattice = VortexLattice(parts, {WING_R: (2 * math.pi, a0l), WING_L: (2 * math.pi, a0l)}, VlmResolution(24))
    ref = Reference(area_m2=wing.area_m2, chord_m=wing.mac_m, span_m=wing.span_m)
    al = np.radians([0.0, 4.0])
    ours = lift_drag(lattice.loads(FlightStates.make(20.0, alpha_rad=al), ref), al)[0]
    g = math.radians(wing.dihedral_deg)
    xsecs = [
        asb.WingXSec(
            xyz_le=[0.25 * (wing.root_chord_m - c), y, y * math.tan(g)],
            chord=c,
            twist=wing.incidence_deg + wing.twist_deg * eta,
            airfoil=asb.Airfoil("naca2412"),
        )
        for eta in (0.0, 1.0)
        for c, y in [(wing.root_chord_m + (wing.tip_chord_m - wing.root_chord_m) * eta, eta * wing.span_m / 2)]
    ]
    plane = asb.Airplane(wings=[asb.Wing(symmetric=True, xsecs=xsecs)], s_ref=ref.area_m2, c_ref=ref.chord_m, b_ref=2.0)
    theirs = np.array(
        [
            asb.VortexLatticeMethod(
                airplane=plane,
                op_point=asb.OperatingPoint(velocity=20.0, alpha=math.degrees(a)),
                spanwise_resolution=16,
                chordwise_resolution=6,
            ).run()["CL"]
            for a in al
        ]
    )
    slope_ours, slope_theirs = np.diff(ours)[0], np.diff(theirs)[0]
    assert slope_ours == pytest.approx(slope_theirs, rel=0.03)
    assert ours[1] == pytest.approx(theirs[1], rel=0.05)


# ------------------------------------------------------------------------- pressures vs lattice
def test_pressure_integral_matches_the_lattice_in_attached_flow(potential: AirframePressureModel) -> None:
    """Lifting-surface pressure C_L within 4 % of the lattice's Kutta–Joukowski C_L, and the wing's
    spanwise loading c·c_n from the pressures follows the lattice's 2Γ/V within 4 % (RMS/mean)."""
    m = potential
    al = np.radians([2.0, 4.0, 6.0])
    states = FlightStates.make(20.0, alpha_rad=al)
    cp = m.cp_quasi_steady(states)
    lift_pts = np.isin(m.geometry.component, LIFTING)
    cl_p = lift_drag(cp[:, lift_pts] @ m.force_matrix[:, lift_pts].T, al)[0]
    cl_v = lift_drag(m.vlm_coeffs(states), al)[0]
    np.testing.assert_allclose(cl_p, cl_v, rtol=0.04)

    g = m.geometry
    sl = g.component_slice(WING_R)
    eta = g.strip_eta[0]
    stations = np.sin(0.5 * np.pi * np.arange(g.resolution.wing_strips + 1) / g.resolution.wing_strips)
    width = np.diff(stations) * g.parts[0].semispan_m  # along the quarter-chord line [m]
    strips = m.vlm.strips_of(0)
    v_air = m.vlm.air_velocity(states, m.vlm.mid_b[strips[:1]])[:, 0]
    f_dir = np.cross(v_air, m.vlm.bound_dir[strips[0]])
    f_dir /= np.linalg.norm(f_dir, axis=1, keepdims=True)  # Kutta–Joukowski force direction
    load = np.zeros((len(al), len(eta)))
    for k in range(len(al)):
        per_point = cp[k, sl] * g.areas_m2[sl] * (g.normals_b[sl] @ f_dir[k])
        np.add.at(load[k], g.strip[sl], per_point)
    loading_p = load / width  # force per unit span / q [m]
    gamma = m.vlm.circulation(states)[:, strips]
    loading_v = np.array([np.interp(eta, m.vlm.eta[strips], 2.0 * gamma[k] / 20.0) for k in range(len(al))])
    inner = eta < 0.9  # the lattice's outermost strip centre: compare where both resolve the loading
    rms = np.sqrt(np.mean((loading_p[:, inner] - loading_v[:, inner]) ** 2, axis=1))
    assert np.all(rms / loading_v[:, inner].mean(axis=1) < 0.04)


def test_truth_is_the_pressure_integral_plus_friction(
    potential: AirframePressureModel, viscous: AirframePressureModel
) -> None:
    states = FlightStates.make(
        np.array([15.0, 22.0]),
        alpha_rad=np.radians([3.0, 14.0]),
        beta_rad=np.radians([4.0, -6.0]),
        p_rad_s=[0.5, -0.3],
        r_rad_s=[0.2, 0.1],
        aileron_rad=np.radians([5.0, -8.0]),
        rudder_rad=np.radians([-3.0, 6.0]),
    )
    cp, c = potential.evaluate_states(states)
    np.testing.assert_allclose(c, cp @ potential.force_matrix.T, rtol=0, atol=1e-12)
    cp, c = viscous.evaluate_states(states)
    np.testing.assert_allclose(viscous.coeffs(states, cp), c, rtol=0, atol=1e-12)
    friction = c - cp @ viscous.force_matrix.T
    _, cd = lift_drag(friction, states.alpha_rad, states.beta_rad)
    assert np.all(cd > 0.005) and np.all(cd < 0.03)  # cf·S_wet/S_ref: drag the ports cannot see


def test_in_place_section_pressure_is_the_airfoil_models(viscous: AirframePressureModel) -> None:
    """The quasi-steady fast path evaluates AirfoilFlow.cp's formula in place: equal to cp() itself."""
    states = FlightStates.make(18.0, alpha_rad=np.radians([2.0, 12.0, 18.0, 30.0]), q_rad_s=0.3, alpha_dot_rad_s=0.5)
    m = viscous
    fs = m.flow_states(states)
    kin = m.vlm.kinematics(fs)
    kin = dataclasses.replace(kin, speed_ratio=np.ones_like(kin.speed_ratio), flap=np.zeros_like(kin.flap))
    for grp in m.groups:
        a_e = kin.alpha_eff[:, grp.strips].reshape(-1)
        nc_a = np.linspace(-0.05, 0.05, a_e.size)
        st = m._static_state(grp.flow, a_e, nc_a)
        ours, _ = m._strip_stage(grp, st, kin, len(states), ScratchBuffers())
        ref = grp.flow.cp(st, grp.surface).reshape(ours.shape)
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12)


def test_fuselage_potential_flow_gives_munk_moment(potential: AirframePressureModel) -> None:
    """Zero net force and Munk's moment q·2(k2 − k1)·Vol·sin α cos α on the closed spheroid (below the
    crossflow-separation onset)."""
    m = potential
    al = np.radians([0.0, 2.0, 3.0])
    cp = m.cp_quasi_steady(FlightStates.make(20.0, alpha_rad=al))
    fus = m.geometry.component_slice(FUSELAGE)
    c = cp[:, fus] @ m.force_matrix[:, fus].T
    f = m.geometry.design.fuselage
    vol = 4.0 / 3.0 * math.pi * (0.5 * f.length_m) * (0.5 * f.diameter_m) ** 2
    munk = 2.0 * (m.k2 - m.k1) * vol * np.sin(al) * np.cos(al) / (m.reference.area_m2 * m.reference.chord_m)
    assert np.abs(c[:, :3]).max() < 1e-12
    np.testing.assert_allclose(c[1:, 4], munk[1:], rtol=0.05)
    assert abs(c[0, 4]) < 1e-12


def test_stagnation_pressure_is_the_upper_bound(viscous: AirframePressureModel) -> None:
    states = FlightStates.make(
        np.full(6, 20.0),
        alpha_rad=np.radians([-6.0, 0.0, 8.0, 16.0, 25.0, 35.0]),
        beta_rad=np.radians([0.0, 8.0, -8.0, 0.0, 5.0, 0.0]),
        elevator_rad=np.radians([0.0, 20.0, -20.0, 0.0, 10.0, 0.0]),
        aileron_rad=np.radians([0.0, 0.0, 15.0, -20.0, 0.0, 0.0]),
    )
    cp = viscous.cp_quasi_steady(states)
    assert cp.max() <= 1.0 + 1e-9
    assert np.isfinite(cp).all() and cp.min() > -30.0


def test_evaluation_cost_is_linear_in_n() -> None:
    """Structural proxy for the cost (timings are measured by benchmark_states_per_second): per state,
    the work arrays scale like N — the point assembly is two weighted gathers per lifting point and a
    fixed closed form per fuselage point; the strip stage grows only with the chordwise count (~√N)."""
    sizes = {}
    for n in (1000, 16000):
        geo = build_geometry(default_design(), surface_for(n))
        m = AirframePressureModel(geo, effects=FULL_QS, separation=SEP)
        buf = ScratchBuffers()
        field = m._field_quasi_steady(FlightStates.make(np.full(BLOCK_STATES, 18.0)), buf)
        m.evaluate(field, buf=buf)
        work = sum(a.size for a in buf._flat.values()) + geo.n_points * BLOCK_STATES
        sizes[n] = work / (geo.n_points * BLOCK_STATES)
    assert sizes[16000] <= sizes[1000] * 1.05  # no super-linear term


# ------------------------------------------------------------------------------------- specs/data
def tiny_spec(**over: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "kind": "airframe",
        "name": "tiny-uav",
        "surface_points": 600,
        "lattice": {"wing_strips": 6, "htail_strips": 3, "vtail_strips": 3},
        "section_panels": 80,
        "motion": {
            "type": "envelope",
            "speed_m_s": 18.0,
            "sweeps": ["alpha_deg", "rudder_deg"],
            "sweep_points": 5,
            "random": {"train": 6, "validation": 2, "test": 2},
        },
        "effects": {"trailing_edge_separation": {}, "viscous_drag": {}, "port_bias": {"p0007": 0.05}},
        "separation_calibration": SEP,
        "noise": {"cp_std_fraction": 0.01},
        "seed": 4,
    }
    d.update(over)
    return d


def tiny_pitch(**over: Any) -> dict[str, Any]:
    return tiny_spec(
        motion={
            "type": "sinusoidal_pitch",
            "speed_m_s": 20.0,
            "alpha0_deg": 15.0,
            "amplitude_deg": 10.0,
            "freqs_hz": [6.0],
            "random_freqs": {"low_hz": 4.0, "high_hz": 8.0, "test": 1},
            "cycles": 1,
            "samples_per_cycle": 32,
        },
        effects={
            "circulation_lag": {},
            "added_mass": {},
            "trailing_edge_separation": {},
            "separation_lag": {},
            "leading_edge_vortex": {},
            "viscous_drag": {},
            "port_lag": {"tau_s": 0.003},
        },
        **over,
    )


@pytest.mark.parametrize(
    ("mutate", "phrase"),
    [
        (lambda d: d.pop("kind"), "kind: missing required key"),
        (lambda d: d.update(kind="airfoil"), "kind: 'airfoil' is not an airframe spec"),
        (lambda d: d.update(surface_pionts=5), "surface_pionts: unknown key"),
        (lambda d: d.update(surface_points=10), "surface_points: must be in"),
        (lambda d: d.update(airframe={"wing": {"airfoil": "clarky"}}), "airframe.wing.airfoil: expected a NACA"),
        (lambda d: d.update(airframe={"vtail": {"airfoil": "naca2412"}}), "airframe.vtail.airfoil: the fin"),
        (lambda d: d.update(airframe={"wing": {"spna_m": 2}}), "airframe.wing.spna_m: unknown key"),
        (
            lambda d: d.update(airframe={"wing": {"control": {"eta_start": 0.9, "eta_end": 0.5}}}),
            "airframe.wing.control.eta_end",
        ),
        (lambda d: d.update(airframe={"mass_kg": 1.0}), "airframe: mass_kg = 1.0 kg leaves no mass"),
        (lambda d: d.update(airframe={"wing": {"x_m": 2.0}}), "airframe: the battery"),
        (lambda d: d.update(reference={"area_m2": -1, "chord_m": 0.3, "span_m": 2}), "reference.area_m2: must be > 0"),
        (lambda d: d["motion"].update(type="spiral"), "motion.type: 'spiral' is not supported"),
        (lambda d: d["motion"].update(sweeps=["alpha"]), "motion.sweeps: unknown variable 'alpha'"),
        (lambda d: d["motion"].update(ranges={"beta_deg": [5, -5]}), "motion.ranges.beta_deg"),
        (lambda d: d["motion"].update(random={"trian": 3}), "motion.random.trian: unknown key"),
        (lambda d: d["effects"].update(circulation_lag={}), "effects.circulation_lag: needs a time history"),
        (lambda d: d["effects"].update(port_bias={"p99999": 0.1}), "effects.port_bias.p99999: no surface point"),
        (lambda d: d["effects"].update(viscous_drag={"cf": 1.0}), "effects.viscous_drag.cf: 1.0"),
        (
            lambda d: d.update(separation_calibration={"naca2412": {"alpha1_deg": 12}}),
            "separation_calibration.naca2412.s1_deg: missing",
        ),
    ],
)
def test_spec_errors_name_the_key(mutate: Any, phrase: str) -> None:
    d = tiny_spec()
    mutate(d)
    with pytest.raises(SpecError, match=phrase.replace("(", r"\(").replace(".", r"\.")):
        parse_airframe_spec(d, origin="t.yaml")


def test_pitch_spec_errors_name_the_key() -> None:
    d = tiny_pitch()
    d["motion"]["case_roles"] = ["train", "tset"]
    with pytest.raises(SpecError, match=r"motion\.case_roles"):
        parse_airframe_spec(d)
    d = tiny_pitch()
    d["motion"]["random_freqs"] = {"low_hz": 8.0, "high_hz": 4.0}
    with pytest.raises(SpecError, match=r"motion\.random_freqs\.high_hz"):
        parse_airframe_spec(d)


def test_presets_parse_and_carry_the_method_conditions() -> None:
    assert {"uav-pitch", "uav-envelope"} <= set(preset_names())
    pitch = parse_airframe_spec(yaml.safe_load(preset_text("uav-pitch")))
    m = pitch.motion
    assert m.type == "sinusoidal_pitch"
    assert (m.speed_m_s, m.alpha0_deg, m.amplitude_deg) == (20.0, 20.0, 15.0)
    assert pitch.reference == Reference(area_m2=0.39, chord_m=0.3, span_m=2.0)
    roles = list(m.case_roles)
    assert roles.count("train") == 9 and roles.count("validation") == 1 and roles.count("test") == 1
    np.testing.assert_allclose(m.freqs_hz[:9], np.linspace(4.0, 8.0, 9))
    assert all(4.0 <= f <= 8.0 for f in m.freqs_hz)
    assert parse_airframe_spec(yaml.safe_load(preset_text("uav-pitch"))).motion == m  # drawn from the seed
    assert parse_airframe_spec(pitch.to_dict()) == pitch
    env = parse_airframe_spec(yaml.safe_load(preset_text("uav-envelope")))
    assert env.motion.type == "envelope" and 300 <= env.surface_points <= 300_000
    assert parse_airframe_spec(env.to_dict()) == env


def test_envelope_data_set_validates_round_trips_and_carries_states(tmp_path: Path) -> None:
    spec = parse_airframe_spec(tiny_spec())
    ds, states = simulate_airframe(spec)
    validate_dataset(ds)
    assert len(ds.cases) == spec.n_cases == 5
    assert ds.cp.dtype == np.float32 and ds.coeffs is not None and ds.beta is not None
    assert ds.n_snapshots == 2 * 5 + 10 and states.shape == (ds.n_snapshots, len(STATE_COLUMNS))
    assert [c.meta["role"] for c in ds.cases] == ["train", "train", "train", "validation", "test"]
    np.testing.assert_array_equal(ds.alpha, states[:, 1])
    out = write_dataset(tmp_path / "mem", ds)
    back = load_dataset(out)
    np.testing.assert_array_equal(np.asarray(back.cp), ds.cp)
    np.testing.assert_array_equal(back.coeffs, ds.coeffs)
    assert back.extra["spec"]["separation_calibration"]["naca2412"] == SEP["naca2412"]
    # streamed to disk (memmap): the same numbers, plus states.npy
    path = write_airframe_dataset(spec, tmp_path / "disk")
    disk = load_dataset(path)
    np.testing.assert_array_equal(np.asarray(disk.cp), ds.cp)
    np.testing.assert_array_equal(np.load(path / STATES_FILE), states)
    assert disk.extra["states"]["columns"] == list(STATE_COLUMNS)
    assert disk.extra["mass_properties"]["mass_kg"] == pytest.approx(2.5)
    # the stored spec re-simulates the same data set without NeuralFoil
    again = simulate_airframe(parse_airframe_spec(disk.extra["spec"]))[0]
    np.testing.assert_array_equal(again.cp, ds.cp)


def test_pitch_data_set_shows_dynamic_stall_hysteresis() -> None:
    spec = parse_airframe_spec(tiny_pitch())
    assert spec.motion.case_roles == ("train", "test")
    ds, states = simulate_airframe(spec)
    validate_dataset(ds)
    assert ds.n_snapshots == 2 * 32
    assert np.isfinite(ds.cp).all()
    np.testing.assert_allclose(states[:, STATE_COLUMNS.index("q_rad_s")], states[:, 6])  # q = α̇
    c0 = ds.case == 0
    cl = lift_drag(ds.coeffs[c0], ds.alpha[c0])[0]
    rate = states[c0, 6]
    a = np.degrees(ds.alpha[c0])
    near = np.abs(a - 15.0) < 2.5
    up, down = cl[near & (rate > 0)].mean(), cl[near & (rate < 0)].mean()
    assert up - down > 0.1  # lift overshoot on the upstroke, lost lift on the downstroke
    assert ds.cases[0].meta["reduced_frequency"] == pytest.approx(math.pi * 6.0 * 0.2022 / 20.0, rel=1e-3)
