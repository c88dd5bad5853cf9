"""Geometry, surface discretisation and mass properties of a small fixed-wing UAV.

Body frame FRD (x forward, y right, z down) with its origin at the centre of gravity, which is also
the moment reference point: every position in an :class:`AirframeDesign` is given relative to it, and
the battery is placed (solved for) so that the aircraft balances exactly there.

Components: a tapered, twisted wing with dihedral (NACA 4-digit sections) on top of a
prolate-spheroid fuselage, a horizontal tail (tailplane) and a vertical tail (fin). Ailerons, elevator
and rudder are plain flaps given as a chord fraction and a spanwise extent.

Section frame of a lifting surface (per spanwise station): ``e_c`` runs along the chord from the
leading to the trailing edge, ``e_u`` is the airfoil's "upper" direction (airfoil-frame +y), both in the
body frame. A section at incidence i (leading edge up positive) has ``e_c = cos i·e_c0 − sin i·e_u0``
and ``e_u = sin i·e_c0 + cos i·e_u0`` with ``e_c0 = −x``, ``e_u0`` = up (−z) tilted by the dihedral for the
wing and tailplane, and ``e_u0 = −y`` for the fin (so a fin's positive section incidence is air coming
from the right, i.e. positive sideslip, and its lift points left). Airfoil-frame coordinates (x/c, y/c)
map to ``r_LE + c·(x/c·e_c + y/c·e_u)``. The left halves are exact mirror images (y → −y) of the right.

Surface points are quad centroids of structured grids: (spanwise stations × airfoil contour nodes) for
the lifting surfaces, (rings × azimuth) for the fuselage. The area vector of a quad is half the cross
product of its diagonals, so every closed contour strip and the closed fuselage sum to exactly zero
area vector (a uniform pressure exerts no force on them). Normals point INTO the body.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from numpy.typing import DTypeLike, NDArray

from sim.airfoil.naca import leading_edge_index, naca4_nodes, naca4_params
from vdm_aero._typing import BoolArray, F64Array, IntArray
from vdm_aero.dataset import Reference

__all__ = [
    "COMPONENT_NAMES",
    "FUSELAGE",
    "HTAIL_L",
    "HTAIL_R",
    "VTAIL",
    "WING_L",
    "WING_R",
    "AirframeDesign",
    "AirframeGeometry",
    "ControlDesign",
    "FuselageDesign",
    "LiftingPart",
    "LiftingSurfaceDesign",
    "PointMass",
    "SectionFrames",
    "SurfaceResolution",
    "build_geometry",
    "default_design",
    "section_nodes",
    "span_stations",
    "surface_for",
]

WING_R, WING_L, HTAIL_R, HTAIL_L, VTAIL, FUSELAGE = range(6)
COMPONENT_NAMES: Final = ("wing_right", "wing_left", "htail_right", "htail_left", "vtail", "fuselage")

# Share of the surface points per component (wing both halves, tailplane both halves, fin, fuselage):
# roughly the wetted areas, with a little more on the tails where pressure gradients are steep.
_POINT_SHARE: Final = (0.55, 0.14, 0.09, 0.22)
# chordwise / spanwise panel-count ratio of the lifting-surface grids (pressure varies fastest chordwise)
_CHORD_SPAN_RATIO: Final = (2.0, 2.0, 2.0)
_MIN_CHORD_PANELS: Final = 8
_MIN_STRIPS: Final = 2
_MIN_RINGS: Final = 4
_MIN_AZIMUTH: Final = 8
_ROOT_CLEARANCE_M: Final = 0.002  # gap between the fuselage skin and the first tail strip
_MASS_GRID: Final = (40, 10)  # spanwise × chordwise mass points per lifting part (resolution-independent)
_FINE_CONTOUR_PANELS: Final = 4000  # the exact NACA contour that surface grids are resampled from


# --------------------------------------------------------------------------------------------- design
@dataclass(frozen=True)
class ControlDesign:
    """A plain trailing-edge flap: hinge at ``1 − chord_fraction`` of the local chord, spanning
    ``eta_start … eta_end`` of the semispan (of the height for the fin)."""

    chord_fraction: float
    eta_start: float
    eta_end: float


@dataclass(frozen=True)
class LiftingSurfaceDesign:
    """A straight-tapered lifting surface. For the wing and tailplane ``span_m`` is the projected
    tip-to-tip span and ``dihedral_deg`` applies; for the fin ``span_m`` is its height and dihedral is
    ignored. ``x_m``, ``z_m`` locate the root quarter-chord point [m] (body frame, origin = CG);
    ``incidence_deg`` is the root incidence to the body x axis (LE up positive), ``twist_deg`` the tip
    incidence minus the root incidence (negative = washout), linear in span; ``sweep_deg`` the
    quarter-chord sweep (positive = tips aft)."""

    airfoil: str
    span_m: float
    root_chord_m: float
    tip_chord_m: float
    x_m: float
    z_m: float
    incidence_deg: float = 0.0
    twist_deg: float = 0.0
    dihedral_deg: float = 0.0
    sweep_deg: float = 0.0
    mass_kg: float = 0.0
    control: ControlDesign | None = None
    left_twist_offset_deg: float = 0.0

    @property
    def area_m2(self) -> float:
        """Projected planform area [m²] (both halves for wing/tailplane; the fin's side area)."""
        return 0.5 * (self.root_chord_m + self.tip_chord_m) * self.span_m

    @property
    def mac_m(self) -> float:
        """Mean aerodynamic chord [m] of the straight-tapered planform."""
        lam = self.tip_chord_m / self.root_chord_m
        return 2.0 / 3.0 * self.root_chord_m * (1.0 + lam + lam * lam) / (1.0 + lam)


@dataclass(frozen=True)
class FuselageDesign:
    """A prolate spheroid: ``length_m`` (nose to tail), maximum ``diameter_m``, nose at ``x_nose_m``;
    ``mass_kg`` is the shell mass (spread over the surface)."""

    length_m: float
    diameter_m: float
    x_nose_m: float
    mass_kg: float

    @property
    def centre_x_m(self) -> float:
        return self.x_nose_m - 0.5 * self.length_m

    def radius_at(self, x_m: F64Array | float) -> F64Array:
        """Fuselage radius [m] at body x [m] (0 outside the body)."""
        xi = (np.asarray(x_m, dtype=np.float64) - self.centre_x_m) / (0.5 * self.length_m)
        return np.asarray(0.5 * self.diameter_m * np.sqrt(np.clip(1.0 - xi * xi, 0.0, None)))


@dataclass(frozen=True)
class PointMass:
    """Equipment modelled as a uniform box of ``size_m`` (x, y, z) [m] centred at (x_m, 0, z_m)."""

    name: str
    mass_kg: float
    x_m: float
    z_m: float
    size_m: tuple[float, float, float] = (0.05, 0.05, 0.05)


@dataclass(frozen=True)
class AirframeDesign:
    """The aircraft: components, equipment and total mass. The battery takes the remaining mass and
    is placed where the aircraft balances at the body-frame origin (the CG)."""

    wing: LiftingSurfaceDesign
    htail: LiftingSurfaceDesign
    vtail: LiftingSurfaceDesign
    fuselage: FuselageDesign
    equipment: tuple[PointMass, ...]
    mass_kg: float
    battery_size_m: tuple[float, float, float] = (0.15, 0.05, 0.04)
    battery_z_m: float = 0.01


def default_design() -> AirframeDesign:
    """The reference UAV: 2.0 m span, 2.5 kg, NACA 2412 wing (0.39 m²), NACA 0009 tails, CG at 35 % MAC.

    Sized like the fixed-wing airframes flown with companion computers (e.g. 2 m foam/composite
    mapping planes): wing loading 6.3 kg/m², stall ≈ 10 m/s, cruise 15–22 m/s.
    """
    return AirframeDesign(
        wing=LiftingSurfaceDesign(
            airfoil="naca2412",
            span_m=2.0,
            root_chord_m=0.26,
            tip_chord_m=0.13,
            x_m=0.02,  # quarter chord 2 cm ahead of the CG: CG at 35 % MAC
            z_m=-0.08,  # high wing sitting on the fuselage
            incidence_deg=2.0,
            twist_deg=-2.0,
            dihedral_deg=3.0,
            mass_kg=0.45,
            control=ControlDesign(chord_fraction=0.25, eta_start=0.55, eta_end=0.95),
        ),
        htail=LiftingSurfaceDesign(
            airfoil="naca0009",
            span_m=0.56,
            root_chord_m=0.15,
            tip_chord_m=0.11,
            x_m=-0.72,
            z_m=0.0,
            incidence_deg=-0.5,
            mass_kg=0.06,
            control=ControlDesign(chord_fraction=0.35, eta_start=0.0, eta_end=1.0),
        ),
        vtail=LiftingSurfaceDesign(
            airfoil="naca0009",
            span_m=0.24,
            root_chord_m=0.20,
            tip_chord_m=0.11,
            x_m=-0.70,
            z_m=-0.03,
            sweep_deg=25.0,
            mass_kg=0.05,
            control=ControlDesign(chord_fraction=0.35, eta_start=0.05, eta_end=1.0),
        ),
        fuselage=FuselageDesign(length_m=1.25, diameter_m=0.13, x_nose_m=0.42, mass_kg=0.35),
        equipment=(
            PointMass("motor", 0.22, 0.43, 0.0, (0.04, 0.04, 0.04)),
            PointMass("camera", 0.30, 0.25, 0.02, (0.08, 0.06, 0.06)),
            PointMass("avionics", 0.25, 0.13, 0.0, (0.10, 0.06, 0.03)),
            PointMass("servos", 0.08, -0.10, 0.0, (0.06, 0.04, 0.02)),
        ),
        mass_kg=2.5,
    )


# ---------------------------------------------------------------------------------------- resolution
@dataclass(frozen=True)
class SurfaceResolution:
    """Grid sizes of the surface discretisation. Strips are per half for wing and tailplane;
    chordwise counts are panels around the closed section contour (upper + lower)."""

    wing_strips: int
    wing_chord_panels: int
    htail_strips: int
    htail_chord_panels: int
    vtail_strips: int
    vtail_chord_panels: int
    fuselage_rings: int
    fuselage_azimuth: int

    @property
    def n_points(self) -> int:
        """N, the number of surface points."""
        return (
            2 * self.wing_strips * self.wing_chord_panels
            + 2 * self.htail_strips * self.htail_chord_panels
            + self.vtail_strips * self.vtail_chord_panels
            + self.fuselage_rings * self.fuselage_azimuth
        )


def _even(x: float, lo: int) -> int:
    return max(lo, 2 * round(x / 2.0))


def _grid(n_target: float, ratio: float) -> tuple[int, int]:
    """(strips, chord panels) with chord/strips ≈ ratio and product ≈ n_target."""
    n_c = _even(math.sqrt(max(n_target, 1.0) * ratio), _MIN_CHORD_PANELS)
    n_s = max(_MIN_STRIPS, round(n_target / n_c))
    return n_s, n_c


def surface_for(n_points_target: int) -> SurfaceResolution:
    """A resolution with N within a few per cent of ``n_points_target`` (≥ 300 advised; any size up to
    millions). Lifting-surface chordwise counts are even so that symmetric sections are mirror-symmetric."""
    if n_points_target < 100:
        raise ValueError(f"n_points_target must be ≥ 100, got {n_points_target}")
    n = float(n_points_target)
    w_s, w_c = _grid(n * _POINT_SHARE[0] / 2.0, _CHORD_SPAN_RATIO[0])
    h_s, h_c = _grid(n * _POINT_SHARE[1] / 2.0, _CHORD_SPAN_RATIO[1])
    v_s, v_c = _grid(n * _POINT_SHARE[2], _CHORD_SPAN_RATIO[2])
    lifting = 2 * w_s * w_c + 2 * h_s * h_c + v_s * v_c
    n_fus = max(n - lifting, n * _POINT_SHARE[3] / 2.0)
    az = _even(math.sqrt(n_fus * 0.6), _MIN_AZIMUTH)
    rings = max(_MIN_RINGS, round(n_fus / az))
    return SurfaceResolution(w_s, w_c, h_s, h_c, v_s, v_c, rings, az)


# ---------------------------------------------------------------------------------------- the parts
@dataclass(frozen=True, eq=False)
class SectionFrames:
    """Section frames at M spanwise stations: quarter-chord point (M, 3) [m], chord (M,) [m],
    incidence (M,) [rad], unit chord direction ``e_c`` (M, 3) and upper direction ``e_u`` (M, 3)."""

    r_qc: F64Array
    chord: F64Array
    incidence: F64Array
    e_c: F64Array
    e_u: F64Array

    @property
    def r_le(self) -> F64Array:
        """Leading-edge points (M, 3) [m]."""
        return np.asarray(self.r_qc - 0.25 * self.chord[:, None] * self.e_c)


@dataclass(frozen=True, eq=False)
class LiftingPart:
    """One lifting half-surface (or the fin): its design, whether it is the mirrored (left) half,
    and where its exposed surface starts (``eta_root``, fraction of the semispan)."""

    component: int
    design: LiftingSurfaceDesign
    vertical: bool
    mirror: bool
    eta_root: float
    offset_b: tuple[float, float, float] = (0.0, 0.0, 0.0)  # design datum → body frame (CG origin) [m]
    twist_offset_deg: float = 0.0  # added to the design twist (the left half of an asymmetric build)

    @property
    def name(self) -> str:
        return COMPONENT_NAMES[self.component]

    @property
    def semispan_m(self) -> float:
        """Length of the quarter-chord line projected on the spanwise direction [m]."""
        d = self.design
        if self.vertical:
            return d.span_m
        return 0.5 * d.span_m / math.cos(math.radians(d.dihedral_deg))

    def axes(self) -> tuple[F64Array, F64Array, F64Array]:
        """Unmirrored spanwise ``e_s``, chord ``e_c0`` and upper ``e_u0`` directions at zero incidence."""
        if self.vertical:
            return np.array([0.0, 0.0, -1.0]), np.array([-1.0, 0.0, 0.0]), np.array([0.0, -1.0, 0.0])
        g = math.radians(self.design.dihedral_deg)
        e_s = np.array([0.0, math.cos(g), -math.sin(g)])
        return e_s, np.array([-1.0, 0.0, 0.0]), np.array([0.0, -math.sin(g), -math.cos(g)])

    def frames(self, eta: F64Array) -> SectionFrames:
        """Section frames at spanwise stations ``eta`` (0 root … 1 tip)."""
        d = self.design
        eta = np.asarray(eta, dtype=np.float64)
        e_s, e_c0, e_u0 = self.axes()
        s = eta * self.semispan_m
        r_qc = (
            (np.array([d.x_m, 0.0, d.z_m]) + np.asarray(self.offset_b))[None, :]
            + s[:, None] * e_s[None, :]
            - (s * math.tan(math.radians(d.sweep_deg)))[:, None] * np.array([1.0, 0.0, 0.0])[None, :]
        )
        chord = d.root_chord_m + (d.tip_chord_m - d.root_chord_m) * eta
        inc = np.radians(d.incidence_deg + (d.twist_deg + self.twist_offset_deg) * eta)
        ci, si = np.cos(inc)[:, None], np.sin(inc)[:, None]
        e_c = ci * e_c0[None, :] - si * e_u0[None, :]
        e_u = si * e_c0[None, :] + ci * e_u0[None, :]
        if self.mirror:
            flip = np.array([1.0, -1.0, 1.0])
            r_qc, e_c, e_u = r_qc * flip, e_c * flip, e_u * flip
        return SectionFrames(r_qc=r_qc, chord=chord, incidence=inc, e_c=e_c, e_u=e_u)

    def section_normal(self) -> F64Array:
        """Unit normal of the section plane, ``e_u × e_c`` (rotation about it raises the LE)."""
        f = self.frames(np.zeros(1))
        n = np.cross(f.e_u[0], f.e_c[0])
        return np.asarray(n / np.linalg.norm(n))


def _parts(design: AirframeDesign, offset_b: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[LiftingPart, ...]:
    fus = design.fuselage

    def exposed_root(d: LiftingSurfaceDesign, vertical: bool) -> float:
        # first exposed station: where the fuselage skin under the root chord ends (design z is from the axis)
        x = np.linspace(d.x_m + 0.25 * d.root_chord_m, d.x_m - 0.75 * d.root_chord_m, 41)
        r = float(np.max(fus.radius_at(x)))
        if vertical:
            reach, semispan = r - abs(d.z_m), d.span_m  # fin root z_m above the axis
        else:
            reach, semispan = math.sqrt(max(r * r - d.z_m * d.z_m, 0.0)), 0.5 * d.span_m
        return float(np.clip((reach + _ROOT_CLEARANCE_M) / semispan, 0.0, 0.5)) if reach > 0.0 else 0.0

    w, h, v = design.wing, design.htail, design.vtail
    eh = exposed_root(h, False)
    return (
        LiftingPart(WING_R, w, False, False, 0.0, offset_b),  # high wing: the whole span is exposed
        LiftingPart(WING_L, w, False, True, 0.0, offset_b, w.left_twist_offset_deg),
        LiftingPart(HTAIL_R, h, False, False, eh, offset_b),
        LiftingPart(HTAIL_L, h, False, True, eh, offset_b, h.left_twist_offset_deg),
        LiftingPart(VTAIL, v, True, False, exposed_root(v, True), offset_b),
    )


def span_stations(n: int, eta_root: float = 0.0) -> F64Array:
    """n+1 spanwise stations from ``eta_root`` to 1, refined towards the tip (η = sin(π/2·k/n))."""
    k = np.arange(n + 1) / n
    return np.asarray(eta_root + (1.0 - eta_root) * np.sin(0.5 * np.pi * k))


# ------------------------------------------------------------------------------------------ geometry
@dataclass(frozen=True, eq=False)
class AirframeGeometry:
    """The discretised aircraft surface and its mass properties (body frame FRD, origin = CG).

    Per point (N): ``points_b`` (N, 3) [m], ``normals_b`` (N, 3) unit INTO the body, ``areas_m2``,
    ``tangents_b`` (N, 3) unit tangent along the section contour in its node order (TE → upper → LE →
    lower → TE) for lifting points and along the meridian (nose → tail) for the fuselage;
    ``component`` (index into :data:`COMPONENT_NAMES`); ``strip`` surface-strip index within the
    component (fuselage: ring); ``chord_index`` contour panel index (fuselage: azimuth panel);
    ``eta`` spanwise coordinate of the strip centre (fuselage: 0); ``x_c`` chordwise station of the
    panel midpoint (fuselage: 0); ``upper`` on the section's upper side. Points of one component are
    contiguous, strip-major. ``mass_kg``, ``inertia_kg_m2`` (3, 3) about the CG in body axes,
    ``battery_b`` where the battery was placed to balance the aircraft.
    """

    design: AirframeDesign
    resolution: SurfaceResolution
    parts: tuple[LiftingPart, ...]
    points_b: F64Array
    normals_b: F64Array
    areas_m2: F64Array
    tangents_b: F64Array
    component: IntArray
    strip: IntArray
    chord_index: IntArray
    eta: F64Array
    x_c: F64Array
    upper: BoolArray
    strip_eta: tuple[F64Array, ...]  # per lifting part: centre η of its surface strips
    chord_x_c: tuple[F64Array, ...]  # per lifting part: x/c of its contour panel midpoints
    chord_upper: tuple[BoolArray, ...]  # per lifting part: upper flag of its contour panels
    mass_kg: float
    inertia_kg_m2: F64Array
    battery_b: F64Array
    fuselage_axis_z_m: float
    slices: tuple[slice, ...] = field(default=())

    @property
    def n_points(self) -> int:
        return int(self.areas_m2.shape[0])

    def default_reference(self) -> Reference:
        """Wing planform area, mean aerodynamic chord and span."""
        w = self.design.wing
        return Reference(area_m2=w.area_m2, chord_m=w.mac_m, span_m=w.span_m)

    def component_slice(self, component: int) -> slice:
        """The contiguous point range of one component."""
        return self.slices[component]


def section_nodes(airfoil: str, n_panels: int) -> F64Array:
    """Closed contour nodes (n_panels+1, 2) of a NACA 4-digit section for the surface grid: TE → upper →
    LE → lower → TE, spaced in arc length as sin(π/2·t) from each trailing edge, i.e. clustered at the
    leading edge where the suction peak is. Midpoint integration of the pressure then stays accurate
    (leading-edge thrust) at coarse resolutions, where cosine spacing in x under-resolves the nose."""
    code = airfoil.lower().removeprefix("naca")
    fine = naca4_nodes(code, _FINE_CONTOUR_PANELS)
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(fine, axis=0).T))))
    i_le = leading_edge_index(fine)
    s_le, perim = float(s[i_le]), float(s[-1])
    n_up = n_panels // 2
    t_up = np.linspace(0.0, 1.0, n_up + 1)
    t_lo = np.linspace(0.0, 1.0, n_panels - n_up + 1)[1:]
    stations = np.concatenate(
        (s_le * np.sin(0.5 * np.pi * t_up), s_le + (perim - s_le) * (1.0 - np.cos(0.5 * np.pi * t_lo)))
    )
    nodes = np.column_stack((np.interp(stations, s, fine[:, 0]), np.interp(stations, s, fine[:, 1])))
    nodes[0] = nodes[-1] = fine[0]
    return nodes


def _lifting_surface(part: LiftingPart, n_strips: int, n_chord: int) -> dict[str, F64Array]:
    """Quad grid of one unmirrored lifting half (mirroring is applied by the caller)."""
    nodes = section_nodes(part.design.airfoil, n_chord)  # (n_chord+1, 2), closed TE
    i_le = leading_edge_index(nodes)
    eta = span_stations(n_strips, part.eta_root)
    right = LiftingPart(
        part.component, part.design, part.vertical, False, part.eta_root, twist_offset_deg=part.twist_offset_deg
    )
    f = right.frames(eta)
    # contour nodes in 3D: (stations, nodes, 3)
    p = f.r_le[:, None, :] + f.chord[:, None, None] * (
        nodes[None, :, 0, None] * f.e_c[:, None, :] + nodes[None, :, 1, None] * f.e_u[:, None, :]
    )
    p00, p01, p10, p11 = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    centre = 0.25 * (p00 + p01 + p10 + p11)
    avec = 0.5 * np.cross(p11 - p00, p01 - p10)
    # orientation: the 2-D inward normal (left of the contour direction) mapped to 3-D
    d2 = np.diff(nodes, axis=0)
    n2 = np.column_stack((-d2[:, 1], d2[:, 0]))
    fm = right.frames(0.5 * (eta[:-1] + eta[1:]))
    n3 = n2[None, :, 0, None] * fm.e_c[:, None, :] + n2[None, :, 1, None] * fm.e_u[:, None, :]
    if float(np.sum(avec * n3)) < 0.0:
        avec = -avec
    area = np.linalg.norm(avec, axis=-1)
    tang = 0.5 * ((p01 - p00) + (p11 - p10))
    tang /= np.linalg.norm(tang, axis=-1, keepdims=True)
    mid_x = np.clip(0.5 * (nodes[:-1, 0] + nodes[1:, 0]), 0.0, 1.0)
    ns, nc = n_strips, n_chord
    return {
        "points": centre.reshape(-1, 3),
        "normals": (avec / area[..., None]).reshape(-1, 3),
        "areas": area.reshape(-1),
        "tangents": tang.reshape(-1, 3),
        "strip": np.repeat(np.arange(ns), nc),
        "chord_index": np.tile(np.arange(nc), ns),
        "eta": np.repeat(0.5 * (eta[:-1] + eta[1:]), nc),
        "x_c": np.tile(mid_x, ns),
        "upper": np.tile(np.arange(nc) < i_le, ns),
        "strip_eta": 0.5 * (eta[:-1] + eta[1:]),
        "chord_x_c": mid_x,
        "chord_upper": np.arange(nc) < i_le,
    }


def _mirror(d: dict[str, F64Array]) -> dict[str, F64Array]:
    flip = np.array([1.0, -1.0, 1.0])
    out = dict(d)
    for k in ("points", "normals", "tangents"):
        out[k] = d[k] * flip
    return out


def _fuselage_surface(fus: FuselageDesign, n_rings: int, n_az: int, z_axis: float = 0.0) -> dict[str, F64Array]:
    a, b = 0.5 * fus.length_m, 0.5 * fus.diameter_m
    xi = np.cos(np.pi * np.arange(n_rings + 1) / n_rings)  # +1 nose … −1 tail, refined at both ends
    x = fus.centre_x_m + a * xi
    r = b * np.sqrt(np.clip(1.0 - xi * xi, 0.0, None))
    phi = 2.0 * np.pi * np.arange(n_az + 1) / n_az  # 0 on top, +π/2 on the right
    p = np.stack(
        [
            np.broadcast_to(x[:, None], (n_rings + 1, n_az + 1)),
            r[:, None] * np.sin(phi)[None, :],
            z_axis - r[:, None] * np.cos(phi)[None, :],
        ],
        axis=-1,
    )
    p00, p01, p10, p11 = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    centre = 0.25 * (p00 + p01 + p10 + p11)
    avec = 0.5 * np.cross(p11 - p00, p01 - p10)
    # inward = towards the axis
    radial = (centre - np.array([0.0, 0.0, z_axis])) * np.array([0.0, 1.0, 1.0])
    if float(np.sum(avec * radial)) > 0.0:
        avec = -avec
    area = np.linalg.norm(avec, axis=-1)
    tang = 0.5 * ((p10 - p00) + (p11 - p01))
    tang /= np.maximum(np.linalg.norm(tang, axis=-1, keepdims=True), 1e-300)
    return {
        "points": centre.reshape(-1, 3),
        "normals": (avec / area[..., None]).reshape(-1, 3),
        "areas": area.reshape(-1),
        "tangents": tang.reshape(-1, 3),
        "strip": np.repeat(np.arange(n_rings), n_az),
        "chord_index": np.tile(np.arange(n_az), n_rings),
        "eta": np.zeros(n_rings * n_az),
        "x_c": np.zeros(n_rings * n_az),
        "upper": np.zeros(n_rings * n_az, dtype=bool),
    }


def _box_inertia(m: float, size: tuple[float, float, float]) -> F64Array:
    lx, ly, lz = size
    return np.diag([m * (ly * ly + lz * lz) / 12.0, m * (lx * lx + lz * lz) / 12.0, m * (lx * lx + ly * ly) / 12.0])


def _point_inertia(m: F64Array, r: F64Array) -> F64Array:
    """Σ m (|r|² I − r rᵀ) for point masses m (n,) at r (n, 3)."""
    rr = np.einsum("n,ni,nj->ij", m, r, r)
    return np.asarray(np.trace(rr) * np.eye(3) - rr)


def _mass_properties(design: AirframeDesign) -> tuple[float, F64Array, F64Array, F64Array]:
    """Total mass, inertia about the CG, the CG and the battery position, all in the design datum frame
    (x from the CG station, z from the fuselage axis). The battery x is solved so that the CG lies at
    x = 0; its z is ``battery_z_m``.

    Assumptions: lifting surfaces have uniform areal density on their chord plane (mass split evenly
    between the halves); the fuselage is a uniform thin shell; equipment and battery are uniform boxes.
    """
    ms: list[F64Array] = []
    rs: list[F64Array] = []
    ns, nc = _MASS_GRID
    for part in _parts(design):
        n_halves = 1 if part.vertical else 2
        eta = (np.arange(ns) + 0.5) / ns
        f = part.frames(eta)
        xc = (np.arange(nc) + 0.5) / nc
        r = f.r_le[:, None, :] + (f.chord[:, None] * xc[None, :])[..., None] * f.e_c[:, None, :]
        w = np.repeat(f.chord / nc, nc)
        ms.append(part.design.mass_kg / n_halves * w / w.sum())
        rs.append(r.reshape(-1, 3))
    fus = _fuselage_surface(design.fuselage, 120, 24)
    ms.append(design.fuselage.mass_kg * fus["areas"] / fus["areas"].sum())
    rs.append(fus["points"])
    for e in design.equipment:
        ms.append(np.array([e.mass_kg]))
        rs.append(np.array([[e.x_m, 0.0, e.z_m]]))
    m_all, r_all = np.concatenate(ms), np.concatenate(rs)
    m_batt = design.mass_kg - float(m_all.sum())
    if m_batt <= 0.0:
        raise ValueError(
            f"mass_kg = {design.mass_kg} kg leaves no mass for the battery (components and equipment weigh "
            f"{float(m_all.sum()):.3f} kg)"
        )
    r_batt = np.array([-float(m_all @ r_all[:, 0]) / m_batt, 0.0, design.battery_z_m])
    half = 0.5 * np.asarray(design.battery_size_m)
    fus_r = float(np.min(design.fuselage.radius_at(r_batt[0] + np.array([-half[0], half[0]]))))
    if math.hypot(half[1], abs(r_batt[2]) + half[2]) > fus_r:
        raise ValueError(
            f"the battery ({m_batt:.3f} kg) would have to sit at x = {r_batt[0]:.3f} m to balance the aircraft "
            f"at x = 0, where it does not fit inside the fuselage: move the wing or the equipment"
        )
    m = np.concatenate([m_all, [m_batt]])
    r_all = np.vstack([r_all, r_batt])
    cg = (m @ r_all) / float(m.sum())
    cg[0:2] = 0.0  # x by construction, y by symmetry (exactly)
    inertia = _point_inertia(m, r_all - cg) + _box_inertia(m_batt, design.battery_size_m)
    for e in design.equipment:
        inertia += _box_inertia(e.mass_kg, e.size_m)
    # the halves are mirror images, so the exact inertia has Ixy = Iyz = 0; the mass points agree to rounding
    inertia[0, 1] = inertia[1, 0] = inertia[1, 2] = inertia[2, 1] = 0.0
    return float(m.sum()), np.asarray(inertia), np.asarray(cg), r_batt


def build_geometry(design: AirframeDesign, resolution: SurfaceResolution) -> AirframeGeometry:
    """Discretise the aircraft surface at ``resolution`` and compute its mass properties."""
    for d in (design.wing, design.htail, design.vtail):
        naca4_params(d.airfoil.lower().removeprefix("naca"))
    mass, inertia, cg, r_batt = _mass_properties(design)
    offset = (0.0, 0.0, -float(cg[2]))  # body origin = CG
    parts = _parts(design, offset)
    res = resolution
    counts = {
        WING_R: (res.wing_strips, res.wing_chord_panels),
        HTAIL_R: (res.htail_strips, res.htail_chord_panels),
        VTAIL: (res.vtail_strips, res.vtail_chord_panels),
    }
    blocks: list[dict[str, F64Array]] = []
    strip_eta: list[F64Array] = []
    chord_x_c: list[F64Array] = []
    chord_upper: list[BoolArray] = []
    right_cache: dict[tuple[int, float], dict[str, F64Array]] = {}
    for part in parts:
        base = {WING_L: WING_R, HTAIL_L: HTAIL_R}.get(part.component, part.component)
        key = (base, part.twist_offset_deg)  # an asymmetric left half is built, not mirrored from the right
        if key not in right_cache:
            right_cache[key] = _lifting_surface(part, *counts[base])
        blk = _mirror(right_cache[key]) if part.mirror else right_cache[key]
        blocks.append(blk)
        strip_eta.append(np.asarray(blk["strip_eta"]))
        chord_x_c.append(np.asarray(blk["chord_x_c"]))
        chord_upper.append(np.asarray(blk["chord_upper"], dtype=bool))
    blocks.append(_fuselage_surface(design.fuselage, res.fuselage_rings, res.fuselage_azimuth, offset[2]))
    sizes = [len(b["areas"]) for b in blocks]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    slices = tuple(slice(int(starts[i]), int(starts[i + 1])) for i in range(len(blocks)))
    comp = np.concatenate([np.full(n, i, dtype=np.int64) for i, n in enumerate(sizes)])

    def cat(key: str, dtype: DTypeLike = np.float64) -> NDArray[Any]:
        arr = np.ascontiguousarray(np.concatenate([b[key] for b in blocks]), dtype=dtype)
        arr.flags.writeable = False
        return arr

    geo = AirframeGeometry(
        design=design,
        resolution=res,
        parts=parts,
        points_b=cat("points"),
        normals_b=cat("normals"),
        areas_m2=cat("areas"),
        tangents_b=cat("tangents"),
        component=comp,
        strip=cat("strip", np.int64),
        chord_index=cat("chord_index", np.int64),
        eta=cat("eta"),
        x_c=cat("x_c"),
        upper=cat("upper", np.bool_),
        strip_eta=tuple(strip_eta),
        chord_x_c=tuple(chord_x_c),
        chord_upper=tuple(chord_upper),
        mass_kg=mass,
        inertia_kg_m2=inertia,
        battery_b=np.asarray(r_batt + np.asarray(offset)),
        fuselage_axis_z_m=offset[2],
        slices=slices,
    )
    return geo
