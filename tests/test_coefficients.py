"""Pressure integration and wind-axis transforms against hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from vdm_aero.coefficients import body_to_wind, force_moment_matrix, lift_drag
from vdm_aero.dataset import Reference

REF = Reference(area_m2=2.0, chord_m=0.5, span_m=4.0)


def closed_cube(k: int, center: tuple[float, float, float], half: float) -> tuple[np.ndarray, ...]:
    """A cube of side 2·half split into k×k panels per face; normals point INTO the cube."""
    c = np.asarray(center, dtype=np.float64)
    u = (np.arange(k) + 0.5) / k * 2.0 * half - half  # panel centres along one face edge
    g1, g2 = np.meshgrid(u, u, indexing="ij")
    pts, nrm = [], []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sign in (-1.0, 1.0):
            p = np.zeros((k * k, 3))
            p[:, axis] = sign * half
            p[:, others[0]] = g1.ravel()
            p[:, others[1]] = g2.ravel()
            n = np.zeros((k * k, 3))
            n[:, axis] = -sign  # outward is +sign, so inward is -sign
            pts.append(p + c)
            nrm.append(n)
    areas = np.full(6 * k * k, (2.0 * half / k) ** 2)
    return np.concatenate(pts), np.concatenate(nrm), areas


def test_force_matrix_shape_and_dtype() -> None:
    pts, nrm, areas = closed_cube(3, (0.0, 0.0, 0.0), 0.5)
    s = force_moment_matrix(pts.astype(np.float32), nrm, areas, REF)
    assert s.shape == (6, pts.shape[0])
    assert s.dtype == np.float64


def test_closed_cube_uniform_cp_gives_zero_force_and_moment() -> None:
    pts, nrm, areas = closed_cube(5, (0.3, -1.2, 0.7), 0.4)  # off-origin: moments must cancel too
    s = force_moment_matrix(pts, nrm, areas, REF)
    cp = np.full(pts.shape[0], 1.7)
    np.testing.assert_allclose(s @ cp, np.zeros(6), atol=1e-12)
    # the uniform field is the null space: a single face alone does not cancel
    assert abs((s[:, :25] @ cp[:25])[0]) > 0.1


def test_discretised_sphere_uniform_cp_gives_zero_force() -> None:
    rng = np.random.default_rng(7)
    n_th, n_ph = 40, 80
    th = (np.arange(n_th) + 0.5) * np.pi / n_th
    ph = (np.arange(n_ph) + 0.5) * 2.0 * np.pi / n_ph
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    out = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1).reshape(-1, 3)
    areas = (np.sin(tt) * (np.pi / n_th) * (2.0 * np.pi / n_ph)).ravel()
    center = rng.normal(size=3)
    s = force_moment_matrix(out + center, -out, areas, REF)
    np.testing.assert_allclose(s @ np.full(out.shape[0], -0.8), np.zeros(6), atol=1e-12)


def test_closed_cube_linear_cp_obeys_gauss_theorem() -> None:
    # Cp = x: ∮ Cp n_in dS = −∫∇Cp dV = −V x̂ and ∮ Cp r×n_in dS = −V c × x̂ = (0, −V c_z, V c_y)
    center = (0.2, -0.5, 0.9)
    half = 0.25
    pts, nrm, areas = closed_cube(4, center, half)
    vol = (2 * half) ** 3
    c = (force_moment_matrix(pts, nrm, areas, REF) @ pts[:, 0]).tolist()
    a, chord, span = REF.area_m2, REF.chord_m, REF.span_m
    expected = [-vol / a, 0.0, 0.0, 0.0, -vol * center[2] / (a * chord), vol * center[1] / (a * span)]
    np.testing.assert_allclose(c, expected, atol=1e-12)


def flat_plate(nx: int, ny: int, x0: float, chord: float, span: float) -> tuple[np.ndarray, ...]:
    """A thin plate in the plane z = 0 from x0 to x0+chord; top and bottom panels, normals INTO it."""
    xs = x0 + (np.arange(nx) + 0.5) * chord / nx
    ys = -span / 2 + (np.arange(ny) + 0.5) * span / ny
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    surf = np.stack([gx.ravel(), gy.ravel(), np.zeros(nx * ny)], axis=1)
    top_n = np.tile([0.0, 0.0, 1.0], (nx * ny, 1))  # top faces −z (up); into the plate is +z
    pts = np.concatenate([surf, surf])
    nrm = np.concatenate([top_n, -top_n])
    areas = np.full(2 * nx * ny, chord * span / (nx * ny))
    return pts, nrm, areas


def test_flat_plate_suction_on_top_gives_upward_force_and_hand_pitching_moment() -> None:
    chord, span = 0.4, 2.0
    x0 = -0.3  # plate from x = −0.3 (trailing edge) to +0.1 (leading edge): centroid at x = −0.1
    pts, nrm, areas = flat_plate(8, 5, x0, chord, span)
    ref = Reference(area_m2=chord * span, chord_m=chord, span_m=span)
    k = pts.shape[0] // 2
    cp = np.concatenate([np.full(k, -1.0), np.full(k, 1.0)])  # suction on top, pressure below
    c = force_moment_matrix(pts, nrm, areas, ref) @ cp
    # F_z = Σ cp n_z S = (−1)(+1)·cS + (+1)(−1)·cS = −2 c s  →  CZ = −2 (upward, FRD)
    assert c[2] == pytest.approx(-2.0)
    # M_y = Σ (z F_x − x F_z) = −x_c F_z = −(−0.1)(−2 c s) = −0.2 c s  →  Cpitch = −0.2 c s / (A c) = −0.5
    x_c = x0 + chord / 2
    expected_pitch = -x_c * (-2.0 * chord * span) / (ref.area_m2 * chord)
    assert expected_pitch == pytest.approx(-0.5)  # lift behind the origin pitches nose down
    assert c[4] == pytest.approx(expected_pitch)
    np.testing.assert_allclose(c[[0, 1, 3, 5]], 0.0, atol=1e-12)


def test_flat_plate_asymmetric_load_gives_roll_moment() -> None:
    chord, span = 1.0, 2.0
    pts, nrm, areas = flat_plate(2, 4, -0.5, chord, span)
    ref = Reference(area_m2=chord * span, chord_m=chord, span_m=span)
    cp = np.where(pts[:, 1] > 0, 1.0, 0.0) * np.where(nrm[:, 2] < 0, 1.0, 0.0)  # push up on right half only
    c = force_moment_matrix(pts, nrm, areas, ref) @ cp
    # F_z = −(right half area) = −1 m²; L = Σ y F_z = −(y_c = 0.5)·1 → Croll = −0.5/(A b) = −0.125
    assert c[2] == pytest.approx(-1.0 / ref.area_m2)
    assert c[3] == pytest.approx(-0.5 / (ref.area_m2 * span))


@pytest.mark.parametrize(
    ("points", "normals", "areas"),
    [
        (np.zeros((4, 2)), np.zeros((4, 2)), np.ones(4)),
        (np.zeros((4, 3)), np.zeros((3, 3)), np.ones(4)),
        (np.zeros((4, 3)), np.zeros((4, 3)), np.ones(5)),
    ],
)
def test_force_matrix_rejects_bad_shapes(points: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> None:
    with pytest.raises(ValueError, match="expected"):
        force_moment_matrix(points, normals, areas, REF)


def test_force_matrix_rejects_nonpositive_reference() -> None:
    with pytest.raises(ValueError, match=r"reference\.chord_m"):
        force_moment_matrix(np.zeros((1, 3)), np.ones((1, 3)), np.ones(1), Reference(1.0, 0.0, 1.0))


def test_lift_drag_at_zero_alpha() -> None:
    rng = np.random.default_rng(1)
    c = rng.normal(size=(10, 6))
    cl, cd = lift_drag(c, np.zeros(10))
    np.testing.assert_allclose(cl, -c[:, 2])
    np.testing.assert_allclose(cd, -c[:, 0])


def test_lift_drag_at_ninety_degrees_swaps_axes() -> None:
    rng = np.random.default_rng(2)
    c = rng.normal(size=(10, 3))
    cl, cd = lift_drag(c, np.full(10, np.pi / 2))
    np.testing.assert_allclose(cl, c[:, 0], atol=1e-12)
    np.testing.assert_allclose(cd, -c[:, 2], atol=1e-12)


def test_force_against_freestream_is_pure_drag() -> None:
    rng = np.random.default_rng(3)
    alpha = rng.uniform(-0.5, 0.5, 20)
    beta = rng.uniform(-0.3, 0.3, 20)
    v_hat = np.stack([np.cos(alpha) * np.cos(beta), np.sin(beta), np.sin(alpha) * np.cos(beta)], axis=1)
    drag = rng.uniform(0.01, 0.2, 20)
    cl, cd, cyw = body_to_wind(-drag[:, None] * v_hat, alpha, beta)
    np.testing.assert_allclose(cd, drag, atol=1e-12)
    np.testing.assert_allclose(cl, 0.0, atol=1e-12)
    np.testing.assert_allclose(cyw, 0.0, atol=1e-12)


def test_body_to_wind_is_a_rotation() -> None:
    rng = np.random.default_rng(4)
    c = rng.normal(size=(50, 6))
    alpha = rng.uniform(-1.0, 1.0, 50)
    beta = rng.uniform(-0.5, 0.5, 50)
    cl, cd, cyw = body_to_wind(c, alpha, beta)
    np.testing.assert_allclose(cl**2 + cd**2 + cyw**2, np.sum(c[:, :3] ** 2, axis=1))
    # β = None is zero sideslip, where the wind side force is the body CY
    cl0, cd0, cy0 = body_to_wind(c, alpha)
    np.testing.assert_allclose(cy0, c[:, 1])
    np.testing.assert_allclose(lift_drag(c, alpha)[0], cl0)
    np.testing.assert_allclose(lift_drag(c, alpha)[1], cd0)


def test_positive_alpha_lift_is_upward_force() -> None:
    # a force straight up (−z body) at small positive α is mostly lift, tilted back: a little drag
    cl, cd = lift_drag(np.array([[0.0, 0.0, -1.0]]), np.array([0.1]))
    assert cl[0] == pytest.approx(np.cos(0.1))
    assert cd[0] == pytest.approx(np.sin(0.1))


def test_body_to_wind_rejects_too_few_columns() -> None:
    with pytest.raises(ValueError, match="coeffs"):
        body_to_wind(np.zeros((3, 2)), np.zeros(3))
