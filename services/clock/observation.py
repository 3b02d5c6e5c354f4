"""Which simulation steps are *observed*, pure (no zenoh): docs/protocol.md section 2.7.

Only the control path runs at the step rate: the simulator's wheel angles, the motor's torque
and the wheel angles it passes on to odometry. What is observed rather than controlled (the
simulation clock ``sim/clock``, ``sim/body_pose``, the motor's simulated poses, odometry's pose)
goes out at the observed steps only, as diff_drive_controller publishes odometry at its
``publish_rate`` and Gazebo a sensor at its update rate. A step is observed when

- its index is a multiple of ``sim.observe_every`` (1: every step, the seeds' behaviour), or
- it takes a tick of a rate someone holds a token for: a lockstep participant's ticks
  (``<service>/ticks/<rate>``: it needs the clock and its inputs at each of its ticks) or an
  observer's (``<service>/observes/<rate>``: the ROS 2 bridge's ``publish_rate``).

Ticks are counted in simulation time on the grid ``round(k·1e9/rate)`` ns, each taken by the
first step at or after it (:class:`~services.clock.sim_time.PeriodicSchedule` anchored at 0), the
same grid a participant takes its own ticks on: whoever receives only the observed steps sees
the stamp of every tick of its rate. Nothing here depends on wall time, so which steps are
observed is the same on every run, and the samples a lockstep run computes do not depend on it.
"""

from __future__ import annotations

import math

from services.clock.sim_time import PeriodicSchedule


class ObservedSteps:
    """The simulator's side: call :meth:`observed` once per step, steps in order."""

    def __init__(self, every: int) -> None:
        if every < 1:
            raise ValueError(f"observe_every must be >= 1, got {every}")
        self.every = every
        self._schedules: dict[str, PeriodicSchedule] = {}
        """Per token key, the ticks of its rate after the present."""
        self._next_tick_ns: float = -1
        """No schedule has a tick before this stamp: :meth:`observed` answers the steps between
        without asking them (it runs at every step). -1 when the schedules have changed."""
        self.count = 0
        """Observed steps so far."""

    def add(self, token: str, rate_hz: float, now_ns: int | None = None) -> None:
        """A token asking for the ticks of ``rate_hz`` appeared while the present (the latest step)
        is ``now_ns`` (None before the first step): its ticks after the present are observed. A
        known token with the same rate keeps its schedule (liveliness may report it twice)."""
        known = self._schedules.get(token)
        if known is not None and known.rate_hz == rate_hz:
            return
        schedule = self._schedules[token] = PeriodicSchedule(rate_hz, 0)
        if now_ns is not None:
            schedule.due(now_ns)  # the tick the present took, or a late one: on the grid from the next
        self._next_tick_ns = -1

    def remove(self, token: str) -> None:
        self._schedules.pop(token, None)
        self._next_tick_ns = -1

    def observed(self, step_index: int, now_ns: int) -> bool:
        """Whether the step ``step_index``, at ``now_ns``, is observed. Every schedule is asked, so
        each moves past the present even when an earlier one already said yes."""
        due = step_index % self.every == 0
        if now_ns >= self._next_tick_ns:
            next_tick_ns = math.inf
            for schedule in self._schedules.values():
                due = schedule.due(now_ns) or due
                next_tick_ns = min(next_tick_ns, schedule.next_ns)
            self._next_tick_ns = next_tick_ns
        self.count += due
        return due

    def rates(self) -> dict[str, float]:
        """Per token key, its rate (for status)."""
        return {token: schedule.rate_hz for token, schedule in self._schedules.items()}
