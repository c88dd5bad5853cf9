"""Navigation through GNSS outages: an error-state EKF with the vehicle-dynamic (aerodynamic) model.

Pure math (no sockets, no MAVLink): the service, log replay and the drift benchmark drive the same
:class:`~vdm_aero.nav.filter.NavFilter` with time-ordered measurements in SI units.

Modules, contracts first (navlie style):

* :mod:`~vdm_aero.nav.state`: the nominal state, the error-state layout and ⊕/⊖;
* :mod:`~vdm_aero.nav.contracts`: ``ProcessModel`` and ``MeasurementModel``;
* :mod:`~vdm_aero.nav.ins`: the INS mechanisation (the IMU is the process input);
* :mod:`~vdm_aero.nav.measurements`: GNSS, barometer, magnetometer, pitot, synthetic sideslip, port air
  data and the aerodynamic specific-force models, each with an analytic Jacobian;
* :mod:`~vdm_aero.nav.design_fit`: what the filter learns from the design data set: the FADS port model
  and solve (ports → V, α, β) and the polynomial stability derivatives of ``vdm-classic``;
* :mod:`~vdm_aero.nav.ports_frontend`: port health (NaN, out of range, stuck), air data and coefficients;
* :mod:`~vdm_aero.nav.engine`: the one adapter around filterpy's ``ExtendedKalmanFilter``;
* :mod:`~vdm_aero.nav.filter`: modes, the delayed-GNSS buffer, gating, outages and health;
* :mod:`~vdm_aero.nav.driver`: SI sensor events → the filters (shared by the service, replay and benchmark);
* :mod:`~vdm_aero.nav.stream`: a flight log as a time-ordered measurement stream.
"""
