"""Assembling the autopilot's streams into what the navigation driver takes.

* :class:`PortAssembler`: NAMED_VALUE_FLOAT port values → frames. A frame is every configured port sharing
  one ``time_boot_ms`` (within :attr:`PortAssembler.merge_ms`: ArduPilot stamps each ``send_named_float``
  with ``millis()`` at the call, so the ports of one script update can straddle a millisecond). A frame is
  complete when every port has arrived; a partial one is closed after ``timeout_s`` with NaN for the missing
  ports (they then go to the gappy model) and counted. A value older than the open frame, or than the last
  closed one, is late (a straggler, or a frame a buffering radio sends again a second later): dropped and
  counted, so it never closes the open frame early nor opens one of its own; so is a value of the frame just
  closed (a straggler of a frame the timeout closed, or a copy the endpoint's duplicate check let through);
  after an autopilot reboot (:meth:`PortAssembler.restart`) the times start again.
* :class:`AutopilotClock`: the autopilot's boot time → a continuous filter time across autopilot reboots,
  and TIMESYNC: the offset between the autopilot's clock and ours.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vdm_aero._typing import F64Array

__all__ = ["AutopilotClock", "PortAssembler", "PortFrameIn"]

REBOOT_BACKSTEP_S = 1.0  # the autopilot's boot time stepping back this far is a reboot


@dataclass(frozen=True)
class PortFrameIn:
    t_s: float  # autopilot time [s]
    dp_pa: F64Array  # in the configured port order, NaN for ports that did not arrive
    complete: bool
    arrived_at: float  # local monotonic time the last value of the frame was received [s]


class PortAssembler:
    """Groups named port values into frames (module docstring)."""

    def __init__(self, names: Sequence[str], *, timeout_s: float, merge_ms: int = 2) -> None:
        self.names = tuple(names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.timeout_s = timeout_s
        self.merge_ms = merge_ms
        self._ms: int | None = None
        self._last_ms: int | None = None  # the time of the last frame closed
        # plain lists: a value arrives 1200 times a second (12 ports at 100 Hz); numpy per value costs more
        self._values = [math.nan] * len(self.names)
        self._seen = [False] * len(self.names)
        self._n_seen = 0
        self._opened_at = 0.0
        self._last_at = 0.0
        self.counts = {"complete": 0, "partial": 0, "unknown_name": 0, "late": 0}

    def _close(self, complete: bool) -> PortFrameIn:
        assert self._ms is not None
        out = PortFrameIn(self._ms * 1e-3, np.array(self._values, dtype=np.float64), complete, self._last_at)
        self.counts["complete" if complete else "partial"] += 1
        self._last_ms = self._ms
        self._ms = None
        n = len(self.names)
        self._values = [math.nan] * n
        self._seen = [False] * n
        self._n_seen = 0
        return out

    def add(self, time_boot_ms: int, name: str, value: float, now: float) -> list[PortFrameIn]:
        """One NAMED_VALUE_FLOAT (``now``: local monotonic receive time [s]); returns the frames it closes."""
        i = self.index.get(name)
        if i is None:
            self.counts["unknown_name"] += 1
            return []
        out = []
        if self._ms is not None:
            stale = time_boot_ms < self._ms - self.merge_ms
        else:  # no frame open: a value of the frame just closed (a straggler, a copy) must not open one of its own
            stale = self._last_ms is not None and time_boot_ms <= self._last_ms + self.merge_ms
        if stale:
            self.counts["late"] += 1  # a straggler of a closed frame, or one sent again late
            return []
        if self._ms is not None and (self._seen[i] or abs(time_boot_ms - self._ms) > self.merge_ms):
            out.append(self._close(False))
        if self._ms is None:
            self._ms, self._opened_at = time_boot_ms, now
        self._values[i] = value if math.isfinite(value) else math.nan
        self._seen[i] = True
        self._n_seen += 1
        self._last_at = now
        if self._n_seen == len(self._seen):
            out.append(self._close(True))
        return out

    def restart(self) -> None:
        """The autopilot rebooted: its times start again (an open frame is dropped: it is from before)."""
        self._ms = self._last_ms = None
        n = len(self.names)
        self._values = [math.nan] * n
        self._seen = [False] * n
        self._n_seen = 0

    def expire(self, now: float) -> PortFrameIn | None:
        """Close a partial frame that has waited ``timeout_s``."""
        if self._ms is not None and now - self._opened_at > self.timeout_s:
            return self._close(False)
        return None


class AutopilotClock:
    """Filter time = autopilot boot time + an epoch that grows at each autopilot reboot, so the filter's
    clock never runs backwards and its state (wind, biases, corrections) survives the reboot."""

    def __init__(self) -> None:
        self.epoch_s = 0.0
        self.reboots = 0
        self._last_boot_s = -math.inf
        self.offset_s: float | None = None  # autopilot boot time − local monotonic time, from TIMESYNC
        self.rtt_s: float | None = None

    def observe_boot_s(self, boot_s: float) -> bool:
        """The boot time of a frequent stream (the IMU); True when it shows a reboot."""
        rebooted = boot_s < self._last_boot_s - REBOOT_BACKSTEP_S
        if rebooted:
            # the autopilot was down at least as long as it has been up again: the filter's clock moves on by
            # that much (not by a millisecond), so the filter sees a gap and grows its covariance over it
            self.epoch_s += self._last_boot_s + max(boot_s, 1e-3) - boot_s
            self.reboots += 1
            self.offset_s = None
        self._last_boot_s = max(boot_s, self._last_boot_s) if not rebooted else boot_s
        return rebooted

    def filter_s(self, boot_s: float) -> float:
        return boot_s + self.epoch_s

    def boot_s(self, filter_s: float) -> float:
        return filter_s - self.epoch_s

    def timesync(self, tc1_ns: int, ts1_ns: int, now_ns: int) -> None:
        """A TIMESYNC reply to our request sent at local ``ts1_ns``, received at ``now_ns``."""
        rtt = (now_ns - ts1_ns) * 1e-9
        if not 0.0 <= rtt < 1.0:
            return  # not ours, or stale
        offset = tc1_ns * 1e-9 - 0.5 * (ts1_ns + now_ns) * 1e-9
        if self.offset_s is None or self.rtt_s is None or rtt <= 2.0 * self.rtt_s:
            self.offset_s = offset if self.offset_s is None else self.offset_s + 0.2 * (offset - self.offset_s)
            self.rtt_s = rtt if self.rtt_s is None else self.rtt_s + 0.2 * (rtt - self.rtt_s)
