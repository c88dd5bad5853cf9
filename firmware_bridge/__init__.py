"""The only package that touches MAVLink: the companion service, log replay and the autopilot-side script.

Units are converted to SI once per message type, at this boundary.
"""
