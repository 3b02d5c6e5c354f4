"""A driving user service's commands as the drive's own (docs/extending.md, A service that drives),
pure: which stamps take its ticks, the limits its velocities are held to, when it gives up and how
it ends. The shell (services/extension/drive_output.py) publishes what :meth:`DrivingCore.tick` returns.

The rules are the drive's (services/drive/service.py): the ticks are the grid ``round(k·1e9/rate)`` ns,
each taken by the first stamp at or after it, and a command is stamped with that stamp; the motor
latched stopped (a bump, an emergency stop) or held by its collision monitor for
``drive.give_up_after_stop`` gives up (``aborted``); the end is :data:`FINAL_ZERO_TICKS` ticks of zero
velocity, the last marked final, then the outcome.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND
from services.clock.sim_time import PeriodicSchedule
from services.config.sections import DriveConfig
from services.drive.outcome import GiveUp, GiveUpRule, Outcome
from services.drive.path_following import STOPPED, Command, limit_rate

FINAL_ZERO_TICKS = 3
"""Ticks of zero velocity a driving service ends with, as the drive's (the stop is not lost)."""


@dataclass(frozen=True)
class TickCommand:
    """What to publish at a tick: the command stamped ``stamp_ns``; ``final``: the last one, after
    which the service ends with ``outcome``."""

    stamp_ns: int
    command: Command
    final: bool = False
    outcome: GiveUp | None = None


def limit_command(wanted: Command, drive: DriveConfig) -> Command:
    """``wanted`` within the drive's speed and turn rate (``drive.cruise_speed``, ``drive.max_turn_rate``)."""
    return Command(
        max(-drive.cruise_speed, min(drive.cruise_speed, wanted.vx)),
        max(-drive.max_turn_rate, min(drive.max_turn_rate, wanted.w)),
    )


class DrivingCore:
    """One driving service's ticks at ``rate_hz`` per second of simulation time, with the drive's
    limits and give-up rule (``drive``: its section of the robot description)."""

    def __init__(self, drive: DriveConfig, rate_hz: float) -> None:
        self.drive = drive
        self.rate_hz = rate_hz
        self.schedule = PeriodicSchedule(rate_hz, 0)
        self.give_up = GiveUpRule(drive, None)
        self.command = STOPPED
        """The last command published."""
        self.first_tick_ns: int | None = None
        self.last_tick_ns: int | None = None
        self.outcome: GiveUp | None = None
        """How it ends, once it is ending (given up, or finished by the service)."""
        self.final_zeros = 0
        self.commands = 0
        self.restarts = 0

    @property
    def done(self) -> bool:
        return self.final_zeros >= FINAL_ZERO_TICKS

    @property
    def elapsed_s(self) -> float:
        """Simulated seconds from its first tick to its latest."""
        if self.first_tick_ns is None or self.last_tick_ns is None:
            return 0.0
        return (self.last_tick_ns - self.first_tick_ns) / NANOSECONDS_PER_SECOND

    def finish(self, reason: str = "") -> None:
        """End with ``completed`` at the next ticks (its zeros), unless it is ending already."""
        if self.outcome is None:
            self.outcome = GiveUp(Outcome.COMPLETED, reason)

    def tick(self, stamp_ns: int, vx: float, w: float) -> TickCommand | None:
        """The command to publish if ``stamp_ns`` takes a tick, else None. BadInput, before any
        state changes, for a velocity that is not finite or a stamp that is negative."""
        if not (math.isfinite(vx) and math.isfinite(w)):
            raise BadInput(f"velocity not finite: vx {vx}, w {w}")
        if stamp_ns < 0:
            raise BadInput(f"stamp before the simulation's start: {stamp_ns} ns")
        if self.last_tick_ns is not None and stamp_ns < self.last_tick_ns:
            self._restart(stamp_ns)
        if self.done or not self.schedule.due(stamp_ns):
            return None
        dt_s = 0.0 if self.last_tick_ns is None else (stamp_ns - self.last_tick_ns) / NANOSECONDS_PER_SECOND
        if self.first_tick_ns is None:
            self.first_tick_ns = stamp_ns
        self.last_tick_ns = stamp_ns
        if self.outcome is None:
            self.outcome = self.give_up.check(stamp_ns, 0)
        if self.outcome is not None:
            self.final_zeros += 1
            self.command = STOPPED
        else:
            drive = self.drive
            self.command = limit_rate(
                self.command,
                limit_command(Command(vx, w), drive),
                dt_s,
                drive.max_acceleration,
                drive.max_angular_acceleration,
            )
        self.commands += 1
        return TickCommand(stamp_ns, self.command, self.done, self.outcome if self.done else None)

    def _restart(self, stamp_ns: int) -> None:
        """A new simulator (its time went back): the ticks start over from ``stamp_ns``'s grid."""
        self.schedule = PeriodicSchedule(self.rate_hz, 0)
        self.give_up.restart(stamp_ns)
        self.command = STOPPED
        self.first_tick_ns = self.last_tick_ns = None
        if not self.done:
            self.outcome = None
        self.restarts += 1
