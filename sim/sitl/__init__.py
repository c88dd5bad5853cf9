"""Software-in-the-loop: the mock autopilot (an ArduPlane-like MAVLink peer) fed by the simulated world."""
