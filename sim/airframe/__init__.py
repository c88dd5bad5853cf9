"""3-D surface-pressure model of a small fixed-wing UAV (see docs/airframe.md).

Layers: :mod:`~sim.airframe.geometry` (airframe, surface discretisation, mass properties),
:mod:`~sim.airframe.vlm` (Weissinger vortex lattice with unit solutions), :mod:`~sim.airframe.pressure`
(strip-wise 2-D section pressures from :mod:`sim.airfoil.flow`, spheroid fuselage, truth coefficients),
:mod:`~sim.airframe.spec` and :mod:`~sim.airframe.simulate` (``kind: airframe`` specs → data sets).
"""

from sim.airframe.geometry import AirframeDesign, AirframeGeometry, build_geometry, default_design, surface_for
from sim.airframe.pressure import AirframePressureModel, benchmark_states_per_second
from sim.airframe.simulate import simulate_airframe, simulate_airframe_spec, write_airframe_dataset
from sim.airframe.spec import AirframeSpec, load_airframe_spec, parse_airframe_spec
from sim.airframe.vlm import STATE_COLUMNS, FlightStates, VlmResolution, VortexLattice

__all__ = [
    "STATE_COLUMNS",
    "AirframeDesign",
    "AirframeGeometry",
    "AirframePressureModel",
    "AirframeSpec",
    "FlightStates",
    "VlmResolution",
    "VortexLattice",
    "benchmark_states_per_second",
    "build_geometry",
    "default_design",
    "load_airframe_spec",
    "parse_airframe_spec",
    "simulate_airframe",
    "simulate_airframe_spec",
    "surface_for",
    "write_airframe_dataset",
]
