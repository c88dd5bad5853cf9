"""The world: aerodynamic truth, flight dynamics, sensors and the mock autopilot.

May use ``vdm_aero`` formats; never imports ``firmware_bridge``.
"""
