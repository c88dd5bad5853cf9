"""vdm-aero core library: pure math and file formats (no MAVLink, no sockets, no global state)."""

__version__ = "0.1.0"
