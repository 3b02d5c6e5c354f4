"""Simulation time as the services see it: stamps in integer nanoseconds (pure, no zenoh).

The simulator stamps every sample with its own clock. Services that act "every so many
seconds" (localization fixes, drive commands) count those stamps, never the wall clock, so a
lockstep run faster than real time behaves exactly like a real-time one.
"""

from __future__ import annotations

import math

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND


class StampClock:
    """Accepts a stream of strictly increasing stamps; anything else is bad input.

    A restarted simulator's clock starts again (at 0): after :meth:`allow_restart` (its
    liveliness token appeared), a next stamp that is not after the last one starts a new time
    base instead of being bad input. A stamp that is later just goes on: a simulator that only
    reconnected keeps its clock, and a running scenario or fix schedule is not disturbed.
    """

    def __init__(self) -> None:
        self.first_ns: int | None = None
        """The first stamp of the current time base."""
        self.last_ns: int | None = None
        self.restarts = 0
        """Time bases started again since the first."""
        self._restart_allowed = False

    def allow_restart(self) -> None:
        """Let the next stamp start a new time base if it is not after the last one."""
        self._restart_allowed = True

    def advance(self, stamp_ns: int) -> bool:
        """Take ``stamp_ns`` as the new time; True if it started a new time base.

        Raises BadInput (state unchanged) if the stamp is not later and no restart is allowed.
        """
        last_ns = self.last_ns
        restarted = False
        if last_ns is not None and stamp_ns <= last_ns:
            if not self._restart_allowed:
                raise BadInput(f"stamp {stamp_ns} ns is not after the previous one ({last_ns} ns)")
            self.first_ns, restarted = None, True
            self.restarts += 1
        self._restart_allowed = False
        if self.first_ns is None:
            self.first_ns = stamp_ns
        self.last_ns = stamp_ns
        return restarted


class PeriodicSchedule:
    """Ticks at ``start_ns + round(k·1e9/rate)`` for k = 0, 1, 2, ...

    The grid is anchored at ``start_ns`` (no drift from rounding), and a tick is taken by the
    first stamp at or after it. After a gap longer than a period the missed ticks are skipped:
    one stamp takes at most one tick.
    """

    def __init__(self, rate_hz: float, start_ns: int) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate must be finite and > 0, got {rate_hz}")
        self.rate_hz = rate_hz
        self.start_ns = start_ns
        self.index = 0
        """The index k of the next tick."""

    def _tick_ns(self, index: int) -> int:
        return self.start_ns + round(index * NANOSECONDS_PER_SECOND / self.rate_hz)

    @property
    def next_ns(self) -> int:
        return self._tick_ns(self.index)

    def due(self, now_ns: int) -> bool:
        """True when ``now_ns`` takes a tick; the schedule then moves past ``now_ns``."""
        if now_ns < self.next_ns:
            return False
        index = max(self.index + 1, math.floor((now_ns - self.start_ns) * self.rate_hz / NANOSECONDS_PER_SECOND))
        while self._tick_ns(index) <= now_ns:
            index += 1
        while index - 1 > self.index and self._tick_ns(index - 1) > now_ns:
            index -= 1
        self.index = index
        return True
