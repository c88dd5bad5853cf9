"""NACA 4-digit geometry, panel geometry in the body frame and pressure-tap placement."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path

from sim.airfoil.naca import (
    leading_edge_index,
    locate_taps,
    naca4_nodes,
    surface_geometry,
    taps_geometry,
)

CHORD_M = 0.3
SPAN_M = 0.8
PIVOT = 0.25


def _signed_area(nodes: np.ndarray) -> float:
    x, y = nodes[:, 0], nodes[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def _body_polygon(nodes: np.ndarray) -> Path:
    """The airfoil outline in the body (x_b, z_b) plane, built here from the documented mapping."""
    return Path(np.column_stack(((PIVOT - nodes[:, 0]) * CHORD_M, -nodes[:, 1] * CHORD_M)))


# --- naca4_nodes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n_panels", [8, 37, 200, 1316])
@pytest.mark.parametrize("code", ["0012", "2412", "naca4415"])
def test_node_count_order_and_closed_te(code: str, n_panels: int) -> None:
    nodes = naca4_nodes(code, n_panels)
    assert nodes.shape == (n_panels + 1, 2)
    assert nodes.dtype == np.float64
    # closed TE: first and last nodes are the same point, exactly (1, 0)
    np.testing.assert_array_equal(nodes[0], [1.0, 0.0])
    np.testing.assert_array_equal(nodes[-1], [1.0, 0.0])
    # the upper surface gets n//2 panels (odd counts put the extra panel on the lower surface), so
    # the camber-line origin (0, 0) is node n//2
    np.testing.assert_array_equal(nodes[n_panels // 2], [0.0, 0.0])
    # counterclockwise (interior on the left): positive shoelace area
    assert _signed_area(nodes) > 0.0
    # x falls monotonically from the TE to the LE region on the upper side, rises on the lower side
    assert np.all(np.diff(nodes[n_panels // 2 :, 0]) > 0.0)


def test_naca0012_max_thickness_and_area() -> None:
    nodes = naca4_nodes("0012", 400)
    upper = nodes[:201][::-1]  # LE -> TE
    lower = nodes[200:]  # LE -> TE
    np.testing.assert_allclose(upper[:, 0], lower[:, 0], rtol=0, atol=1e-15)  # same stations both sides
    thickness = upper[:, 1] - lower[:, 1]
    k = int(np.argmax(thickness))
    # 12 % thick at x ≈ 0.30 (analytic maximum at x = 0.2998); node sampling near x = 0.3 is
    # ~0.006 chord, the closed-TE coefficient lowers the maximum by ~1e-5
    assert thickness[k] == pytest.approx(0.12, abs=2e-4)
    assert upper[k, 0] == pytest.approx(0.30, abs=0.01)
    # cross-section area of a 4-digit section is 0.685·t·c² (Abbott & von Doenhoff): within 1 %
    assert _signed_area(nodes) == pytest.approx(0.685 * 0.12, rel=0.01)


def test_cosine_spacing_is_dense_at_le_and_te() -> None:
    nodes = naca4_nodes("0012", 100)
    beta = np.linspace(np.pi, 0.0, 51)
    np.testing.assert_allclose(nodes[:51, 0], 0.5 * (1.0 - np.cos(beta)), atol=1e-15)
    lengths = np.hypot(*np.diff(nodes, axis=0).T)
    mid_chord = lengths[20:30].mean()
    assert lengths[0] < 0.3 * mid_chord  # TE
    assert lengths[49] < 0.3 * mid_chord  # LE


def test_naca2412_camber_line() -> None:
    nodes = naca4_nodes("2412", 400)
    upper = nodes[:201][::-1]
    lower = nodes[200:]
    # thickness is applied perpendicular to the camber line, so the upper/lower pair of a station
    # averages exactly to the camber point: max camber 2 % at x = 0.4
    mean = 0.5 * (upper + lower)
    k = int(np.argmax(mean[:, 1]))
    assert mean[k, 1] == pytest.approx(0.02, abs=1e-5)
    assert mean[k, 0] == pytest.approx(0.4, abs=0.01)
    np.testing.assert_allclose(mean[:, 0], 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, 201))), atol=1e-15)
    # the upper-minus-lower vector is perpendicular to the mean line (slope of the 2412 mean line,
    # m = 0.02, p = 0.4, written out here independently of the module)
    x = mean[:, 0]
    slope = np.where(x < 0.4, 2 * 0.02 / 0.4**2 * (0.4 - x), 2 * 0.02 / 0.6**2 * (0.4 - x))
    d = upper - lower
    np.testing.assert_allclose(d[:, 0] + slope * d[:, 1], 0.0, atol=1e-15)
    assert np.all(d[1:-1, 1] > 0.0)
    # the upper surface bulges ahead of the camber-line origin: the min-x node is an upper-side node
    assert leading_edge_index(nodes) < 200
    assert nodes[:, 0].min() < 0.0


def test_open_te_gap() -> None:
    nodes = naca4_nodes("0012", 100, closed_te=False)
    # the original coefficient -0.1015 leaves y_t(1) = 5·t·0.0021 on each side
    gap = np.hypot(*(nodes[0] - nodes[-1]))
    assert gap == pytest.approx(2 * 5 * 0.12 * 0.0021, rel=1e-9)


def test_code_spellings_are_equivalent() -> None:
    ref = naca4_nodes("0015", 50)
    for spelling in ("naca0015", "NACA0015", " NACA 0015 "):
        np.testing.assert_array_equal(naca4_nodes(spelling, 50), ref)


@pytest.mark.parametrize("code", ["12", "00120", "naca23012", "abcd", "naca", "", "2012", "0000"])
def test_bad_codes_raise(code: str) -> None:
    with pytest.raises(ValueError, match=r"NACA|digit|thickness"):
        naca4_nodes(code, 50)


def test_too_few_panels_raise() -> None:
    with pytest.raises(ValueError, match="n_panels"):
        naca4_nodes("0012", 7)


# --- surface_geometry ------------------------------------------------------------------------------


@pytest.mark.parametrize("code", ["0012", "2412"])
def test_surface_geometry_normals_point_into_the_body(code: str) -> None:
    nodes = naca4_nodes(code, 200)
    geo = surface_geometry(nodes, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    np.testing.assert_allclose(np.linalg.norm(geo.normals_b, axis=1), 1.0, atol=1e-12)
    assert np.all(geo.normals_b[:, 1] == 0.0)
    poly = _body_polygon(nodes)
    # a step of 5 % of the panel length fits inside even the thin TE wedge (local thickness ≈ 13 %
    # of the TE panel length for a 15° TE angle); stepping the other way must leave the body
    step = 0.05 * geo.length_c[:, None] * CHORD_M
    pts = geo.points_b[:, [0, 2]]
    n_xz = geo.normals_b[:, [0, 2]]
    assert np.all(poly.contains_points(pts + step * n_xz))
    assert not np.any(poly.contains_points(pts - step * n_xz))


def test_surface_geometry_fields() -> None:
    nodes = naca4_nodes("0012", 200)
    geo = surface_geometry(nodes, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    n = 200
    lengths = np.hypot(*np.diff(nodes, axis=0).T)
    perimeter = float(lengths.sum())
    assert geo.mid_xc.shape == (n, 2)
    assert geo.points_b.shape == geo.normals_b.shape == (n, 3)
    # areas: panel length × span, so they add up to perimeter × span
    assert geo.areas_m2.sum() == pytest.approx(perimeter * CHORD_M * SPAN_M, rel=1e-12)
    assert geo.perimeter_c == pytest.approx(perimeter, rel=1e-12)
    # arc length of midpoints from the first node
    assert geo.s_c[0] == pytest.approx(0.5 * lengths[0], rel=1e-12)
    assert geo.s_c[-1] == pytest.approx(perimeter - 0.5 * lengths[-1], rel=1e-12)
    assert np.all(np.diff(geo.s_c) > 0.0)
    # upper = panels before the LE node; for the symmetric section exactly half, all with y > 0
    assert geo.upper.sum() == n // 2
    assert np.all(geo.mid_xc[geo.upper, 1] > 0.0)
    assert np.all(geo.mid_xc[~geo.upper, 1] < 0.0)
    # body frame FRD: upper surface is up, i.e. negative z_b; x_b = (pivot − x/c)·c
    assert np.all(geo.points_b[geo.upper, 2] < 0.0)
    assert np.all(geo.points_b[~geo.upper, 2] > 0.0)
    np.testing.assert_allclose(geo.points_b[:, 0], (PIVOT - geo.mid_xc[:, 0]) * CHORD_M, rtol=0, atol=1e-15)
    # inward normal at mid-chord on the upper surface points down (+z_b), on the lower surface up
    mid_up = geo.upper & (np.abs(geo.mid_xc[:, 0] - 0.5) < 0.02)
    mid_lo = ~geo.upper & (np.abs(geo.mid_xc[:, 0] - 0.5) < 0.02)
    assert np.all(geo.normals_b[mid_up, 2] > 0.99)
    assert np.all(geo.normals_b[mid_lo, 2] < -0.99)
    # frozen arrays: the geometry cannot be edited by accident
    with pytest.raises(ValueError, match="read-only"):
        geo.areas_m2[0] = 1.0


def test_surface_geometry_rejects_bad_dimensions() -> None:
    nodes = naca4_nodes("0012", 50)
    with pytest.raises(ValueError, match="chord_m"):
        surface_geometry(nodes, chord_m=0.0, span_m=1.0, pivot_x_c=0.25)
    with pytest.raises(ValueError, match="span_m"):
        surface_geometry(nodes, chord_m=1.0, span_m=-1.0, pivot_x_c=0.25)
    with pytest.raises(ValueError, match="nodes"):
        surface_geometry(nodes[:, :1], chord_m=1.0, span_m=1.0, pivot_x_c=0.25)


# --- locate_taps / taps_geometry ---------------------------------------------------------------------


@pytest.mark.parametrize("code", ["0012", "2412"])
def test_locate_taps_round_trip(code: str) -> None:
    nodes = naca4_nodes(code, 200)
    x_c = [0.0, 0.005, 0.05, 0.3, 0.7, 0.99, 1.0, 0.0, 0.01, 0.2, 0.5, 0.95, 1.0]
    upper = [True] * 7 + [False] * 6
    s = locate_taps(nodes, x_c, upper)
    taps = taps_geometry(nodes, s, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    x_back = PIVOT - taps.points_b[:, 0] / CHORD_M
    np.testing.assert_allclose(x_back, x_c, rtol=0, atol=1e-12)
    up = np.array(upper)
    inner = (np.array(x_c) > 0.0) & (np.array(x_c) < 1.0)
    assert np.all(taps.points_b[up & inner, 2] < 0.0)  # upper side: up = negative z_b
    assert np.all(taps.points_b[~up & inner, 2] > 0.0)
    # along each side, s runs opposite ways: decreasing with x/c on the upper side, increasing below
    assert np.all(np.diff(s[:7]) < 0.0)
    assert np.all(np.diff(s[7:]) > 0.0)
    perimeter = float(np.hypot(*np.diff(nodes, axis=0).T).sum())
    assert s[6] == pytest.approx(0.0, abs=1e-15)  # upper TE is the first node
    assert s[-1] == pytest.approx(perimeter, rel=1e-12)  # lower TE is the last node


def test_leading_edge_tap_maps_to_pivot_distance() -> None:
    nodes = naca4_nodes("0012", 200)
    s = locate_taps(nodes, [0.0, 0.0], [True, False])
    s_le = float(np.hypot(*np.diff(nodes[:101], axis=0).T).sum())
    np.testing.assert_allclose(s, s_le, rtol=1e-12)
    taps = taps_geometry(nodes, s[:1], chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    # the LE lies on the chord line, pivot·c ahead of the body origin
    assert taps.points_b[0, 0] == pytest.approx(PIVOT * CHORD_M, abs=1e-15)
    assert taps.points_b[0, 2] == pytest.approx(0.0, abs=1e-15)
    # the inward normal at the LE of a symmetric section points aft: −x_b
    np.testing.assert_allclose(taps.normals_b[0], [-1.0, 0.0, 0.0], atol=1e-12)


def test_locate_taps_rejects_bad_input() -> None:
    nodes = naca4_nodes("0012", 50)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        locate_taps(nodes, [-0.01], [True])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        locate_taps(nodes, [1.01], [False])
    with pytest.raises(ValueError, match="entries"):
        locate_taps(nodes, [0.1, 0.2], [True])


def test_tributary_areas_by_hand() -> None:
    nodes = naca4_nodes("0012", 100)
    perimeter = float(np.hypot(*np.diff(nodes, axis=0).T).sum())
    # taps given out of order at s = 0.5P, 0.1P, 0.6P: sorted gaps 0.4P, 0.1P and 0.5P (through the TE)
    s = np.array([0.5, 0.1, 0.6]) * perimeter
    taps = taps_geometry(nodes, s, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    expected = np.array([0.5 * (0.4 + 0.1), 0.5 * (0.5 + 0.4), 0.5 * (0.1 + 0.5)]) * perimeter
    np.testing.assert_allclose(taps.areas_m2, expected * CHORD_M * SPAN_M, rtol=1e-12)
    # a single tap owns the whole contour
    one = taps_geometry(nodes, [0.3 * perimeter], chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    assert one.areas_m2[0] == pytest.approx(perimeter * CHORD_M * SPAN_M, rel=1e-12)


def test_taps_geometry_normals_and_area_sum() -> None:
    nodes = naca4_nodes("2412", 200)
    rng = np.random.default_rng(3)
    x_c = rng.uniform(0.01, 0.9, 40)
    upper = rng.uniform(size=40) < 0.5
    s = locate_taps(nodes, x_c, upper)
    taps = taps_geometry(nodes, s, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    perimeter = float(np.hypot(*np.diff(nodes, axis=0).T).sum())
    assert taps.areas_m2.sum() == pytest.approx(perimeter * CHORD_M * SPAN_M, rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(taps.normals_b, axis=1), 1.0, atol=1e-12)
    poly = _body_polygon(nodes)
    step = 1e-3 * CHORD_M  # well inside: local thickness ≥ 1.5 % chord for x/c in [0.01, 0.9]
    assert np.all(poly.contains_points(taps.points_b[:, [0, 2]] + step * taps.normals_b[:, [0, 2]]))
    # the interpolated normal agrees with the normal of the panel holding the tap (within ~2.6°)
    geo = surface_geometry(nodes, chord_m=CHORD_M, span_m=SPAN_M, pivot_x_c=PIVOT)
    s_nodes = np.concatenate(([0.0], np.cumsum(geo.length_c)))
    panel = np.searchsorted(s_nodes, s) - 1
    cos_angle = np.sum(taps.normals_b * geo.normals_b[panel], axis=1)
    assert np.all(cos_angle > 0.999)


def test_taps_geometry_rejects_positions_off_the_contour() -> None:
    nodes = naca4_nodes("0012", 50)
    perimeter = float(np.hypot(*np.diff(nodes, axis=0).T).sum())
    with pytest.raises(ValueError, match="perimeter"):
        taps_geometry(nodes, [perimeter * 1.01], chord_m=1.0, span_m=1.0, pivot_x_c=0.25)
    with pytest.raises(ValueError, match="perimeter"):
        taps_geometry(nodes, [-0.01], chord_m=1.0, span_m=1.0, pivot_x_c=0.25)
