"""Periodic outputs on the autopilot's clock, sampled only when an IMU message arrives.

Why the phase is kept: the clock is read at irregular instants (each IMU message; streams at 50–400 Hz, with
gaps), so "next = now + period" loses part of a sample interval every period: at 5 Hz on a 100 Hz stream the
outputs came at ~4.75 Hz. Here the next due time is the previous one plus the period, so the mean rate is the
rate asked for whatever the sampling; after a stall longer than a period it re-anchors on the clock instead of
sending the missed ones in a burst, and a clock that went back (an autopilot reboot) starts it afresh.
"""

from __future__ import annotations

import math

__all__ = ["ClockSchedule"]


class ClockSchedule:
    """Named periodic tasks on an external clock [s]."""

    def __init__(self) -> None:
        self._next: dict[str, float] = {}

    def due(self, key: str, t_s: float, period_s: float) -> bool:
        """True when ``key`` is due at clock time ``t_s`` (and schedules its next time)."""
        if not math.isfinite(t_s):
            return False
        nxt = self._next.get(key, -math.inf)
        if nxt - t_s > 2.0 * period_s:  # the clock went back (a reboot)
            nxt = -math.inf
        if t_s < nxt:
            return False
        # keep the phase while on time; re-anchor on the clock after a stall of more than a period
        self._next[key] = (nxt if t_s - nxt < period_s else t_s) + period_s
        return True
