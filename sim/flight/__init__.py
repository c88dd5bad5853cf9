"""The 6-DOF flight simulator: rigid body, aerodynamics from the airframe pressure model, propulsion,
actuators, environment (ISA, wind, Dryden turbulence), sensors, guidance and scenarios. ``FlightWorld``
implements :class:`sim.flight.contract.World`; see docs/flight-sim.md."""
