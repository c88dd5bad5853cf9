"""The ``vdm-aero`` command: the composition root that wires vdm_aero, sim and firmware_bridge together."""
