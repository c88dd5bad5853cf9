"""Flight-log readers: MAVLink telemetry logs (``.tlog``), ArduPilot DataFlash (``.bin``) and PX4 ULog
(``.ulg``), each producing the SI measurement stream the service builds from the live link
(:mod:`firmware_bridge.logs.common`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from firmware_bridge.logs.common import LogFormatError, LogRead, ReadReport, TruthTrack

__all__ = ["LogFormatError", "LogRead", "ReadReport", "TruthTrack", "log_format", "read_log", "read_truth_file"]

DATAFLASH_MAGIC = b"\xa3\x95"
ULOG_MAGIC = b"ULog\x01\x12\x35"
MOCK_TRUTH_FORMAT = "vdm-aero-sitl-truth/1"


def log_format(path: Path) -> str:
    """ "tlog", "dataflash" or "ulog", from the file's first bytes (the extension only breaks a tie)."""
    try:
        with path.open("rb") as f:
            head = f.read(16)
    except OSError as e:
        raise LogFormatError(f"{path}: cannot read ({e.strerror})") from None
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if len(head) > 8 and head[8] in (0xFD, 0xFE):
        return "tlog"
    suffix = path.suffix.lower()
    known = {".tlog": "tlog", ".bin": "dataflash", ".ulg": "ulog"}
    if suffix in known and head:
        return known[suffix]  # a damaged start: let the reader resynchronise and report
    raise LogFormatError(f"{path}: not a telemetry log (.tlog), DataFlash log (.bin) or ULog (.ulg)")


def read_log(path: Path, port_names: Sequence[str] = (), *, system_id: int | None = None,
             gnss_latency_s: float | None = None, progress: Callable[[float], None] | None = None
             ) -> LogRead:  # fmt: skip
    """Read any supported log; ``port_names`` order the port columns (tlogs carry the ports);
    ``gnss_latency_s``: a tlog's receiver latency (default: its autopilot's default)."""
    path = Path(path)
    fmt = log_format(path)
    if fmt == "tlog":
        from firmware_bridge.logs.tlog import read_tlog

        return read_tlog(path, port_names, system_id=system_id, gnss_latency_s=gnss_latency_s, progress=progress)
    if fmt == "dataflash":
        from firmware_bridge.logs.dataflash import read_dataflash

        return read_dataflash(path, port_names, progress=progress)
    from firmware_bridge.logs.ulog import read_ulog

    return read_ulog(path, port_names, progress=progress)


def read_truth_file(path: Path) -> TruthTrack:
    """The mock autopilot's truth file (``vdm-aero sitl --truth``, docs/sitl.md): its times are the autopilot's
    boot time, the clock of the tlog it flew with."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["format"]) != MOCK_TRUTH_FORMAT:
                raise LogFormatError(f"{path}: format {str(z['format'])!r} is not {MOCK_TRUTH_FORMAT}")
            return TruthTrack("the mock autopilot's truth file", z["t_s"], z["lat_deg"], z["lon_deg"], z["alt_m"],
                              z["v_ned_m_s"], z["q_nb"])  # fmt: skip
    except (OSError, ValueError, KeyError) as e:
        raise LogFormatError(f"{path}: not a SITL truth file ({e})") from None
