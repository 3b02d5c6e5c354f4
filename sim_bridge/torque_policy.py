"""The torque policy of the sim bridge: which torque a robot's step applies when torques come late,
not at all, or too old (docs/sim.md). Pure: no zenoh, no runtime, no PyBullet. The bridge's link
hands it each ``motor/torque`` (:meth:`TorquePolicy.on_torque`, the input's own callback) and its
loop asks it at each step; it applies its choice to the robot's :class:`Wheels` and tells its
:class:`TorqueEvents` what the log should say.

- **lockstep**: a step waits for the torque whose ``tm`` is its own (:meth:`~TorquePolicy.begin_wait`);
  a torque with any other ``tm``, or a second one, is stale (counted, ignored). The wait happens
  only while a motor control is alive (its liveliness token), and then for as long as it takes:
  past ``sim.lockstep_timeout`` it is only said (:meth:`~TorquePolicy.still_waiting`, counted once
  per step). A motor control that comes after the first step is *silent* until it answers the
  step waited for in time (it may have missed that step's wheel angles, or the drive's command
  a step's mark owes): each step then waits only one real-time period
  (``sim.step / sim.realtime_factor``). The ``final`` state of a finite run takes its torque
  without applying it.
- **realtime**: each step applies the newest torque, or none when the newest is older than
  ``sim.torque_max_age``; a torque stamped after the latest step published is from the future
  (bad input). A step whose own torque has not arrived when it is stepped counts as late.
- **no torque**: zero torque, or the brakes once there has been none for ``sim.brake_after``
  (the motor control gone, silent, or cut off by a link down).

A motor with ``motor.output = "velocity"`` answers with wheel speed targets
(``motor/wheel_velocity``, :meth:`TorquePolicy.on_wheel_velocity`) instead: the same rules, the
targets handed to the wheels' own velocity loop (:meth:`Wheels.set_wheel_velocities`); a target
not finite or beyond ``input.max_wheel_speed`` is bad input.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, TimedDoubleSeq
from services.config import SimConfig, SimMode
from sim_bridge.latency import TorqueLatency
from sim_bridge.progress import RunProgress

TORQUE_COUNTERS = (
    "torques_applied",
    "long_waits",
    "missing_torques",
    "stale_torques",
    "realtime_late_steps",
    "braked_steps",
)
"""The counters of ``sim/status`` the policy counts (docs/sim.md explains each)."""


class Wheels(Protocol):
    """A robot's wheels as the policy drives them (:class:`sim_bridge.simulator.SimulatedRobot`)."""

    wheel_count: int
    braking: bool

    def set_torques(self, torques: Sequence[float]) -> None: ...

    def set_wheel_velocities(self, targets: Sequence[float]) -> None: ...

    def set_zero_torques(self) -> None: ...

    def brake(self) -> None: ...


class TorqueEvents(Protocol):
    """What the policy has the log say (the bridge's link words each line)."""

    def waiting(self, tm_ns: int, waited_s: float) -> None:
        """The step at ``tm_ns`` has waited ``waited_s`` (another ``sim.lockstep_timeout``) for its
        torque, and waits on: its motor control is alive."""
        ...

    def silent(self) -> None:
        """A motor control came after the first step: steps at real-time pace until it answers."""
        ...

    def answering(self) -> None:
        """The silent motor control answers: steps wait for its torques."""
        ...

    def braking(self) -> None:
        """The wheels begin to brake: no torque for ``sim.brake_after``."""
        ...


def brake_steps(brake_after: float | None, step_ns: int) -> int | None:
    """Steps without a torque after which the wheels are braked (``sim.brake_after``); None: never."""
    return None if brake_after is None else max(1, round(brake_after * NANOSECONDS_PER_SECOND / step_ns))


class TorquePolicy:
    """One robot's torque state: the lockstep wait for its step's torque, the newest torque
    (realtime), whether the motor control is silent (come after the first step, not answering
    yet), the last step a torque was applied at (for the brakes)."""

    def __init__(
        self,
        wheels: Wheels,
        sim: SimConfig,
        step_ns: int,
        *,
        progress: RunProgress,
        counters: dict[str, int],
        latency: TorqueLatency,
        events: TorqueEvents,
        now_ns: Callable[[], int],
        max_wheel_speed: float = math.inf,
    ) -> None:
        self._wheels = wheels
        self.max_wheel_speed = max_wheel_speed
        """rad/s: a wheel speed target beyond it is bad input (``input.max_wheel_speed``)."""
        self._progress = progress
        self._counters = counters
        """Holds (at least) :data:`TORQUE_COUNTERS`: the link's status counters."""
        self._latency = latency
        self._events = events
        self._now_ns = now_ns
        """The clock of the torque latency (``time.perf_counter_ns``)."""
        self.lockstep = sim.mode == SimMode.LOCKSTEP
        """The mode, as the per-step code asks it (an enum comparison costs more than the attribute)."""
        self.silent_wait_s = sim.step / sim.realtime_factor
        """Lockstep, the motor control silent: how long a step waits for its torque (one real-time period)."""
        self.max_age_ns = round(sim.torque_max_age * NANOSECONDS_PER_SECOND)
        self.brake_steps = brake_steps(sim.brake_after, step_ns)
        self.motor_alive = False
        self.silent = False
        """Lockstep: alive since after the first step, and no step answered in time yet: it may have
        subscribed too late for a step's wheel angles or for the output a mark owes (which it would
        hold the step for), so steps go at real-time pace until it answers one."""
        self.awaited_ns = -1
        self.answered = False
        self.waited_long = False
        """This step's wait has passed ``sim.lockstep_timeout`` (counted once in ``long_waits``)."""
        self.newest_torque: Sequence[float] | None = None
        """The newest answer (torques, or wheel speed targets: :attr:`newest_apply` says which)."""
        self.newest_apply: Callable[[Sequence[float]], None] = wheels.set_torques
        self.newest_ns = -1
        self.torque_step = 0
        """The step at which a torque of the motor control was last applied (or the run began)."""

    def on_torque(self, torque: TimedDoubleSeq, _attachment: bytes | None) -> None:
        # Taken with its (unused) attachment: the input then calls this directly, at every step.
        wheels = self._wheels
        if len(torque.data) != wheels.wheel_count:
            raise BadInput(f"{len(torque.data)} torques, expected {wheels.wheel_count} (one per wheel id)")
        self._answer(torque, wheels.set_torques)

    def on_wheel_velocity(self, targets: TimedDoubleSeq, _attachment: bytes | None) -> None:
        """A ``motor/wheel_velocity``: the step's answer, as a torque is, but wheel speed targets."""
        wheels = self._wheels
        if len(targets.data) != wheels.wheel_count:
            raise BadInput(f"{len(targets.data)} wheel speed targets, expected {wheels.wheel_count} (one per wheel id)")
        limit = self.max_wheel_speed
        for target in targets.data:
            if not abs(target) <= limit:  # a NaN fails it too
                raise BadInput(f"wheel speed target {target!r} rad/s beyond input.max_wheel_speed = {limit:g} rad/s")
        self._answer(targets, wheels.set_wheel_velocities)

    def _answer(self, torque: TimedDoubleSeq, apply: Callable[[Sequence[float]], None]) -> None:
        tm_ns = torque.tm.to_nanoseconds()
        self._latency.answered(tm_ns, self._now_ns())
        if self.lockstep:
            if tm_ns != self.awaited_ns or self.answered:
                self._counters["stale_torques"] += 1
                return
            # The step waited for, answered in time: the motor control is in step with the loop
            # (it holds no sample for an output it subscribed too late to get), so steps wait for it.
            self._set_silent(False)
            apply(torque.data)
            self.answered = True
        elif tm_ns > self._progress.published_ns:
            published_ns = self._progress.published_ns
            raise BadInput(
                f"torque stamped t = {tm_ns / NANOSECONDS_PER_SECOND:.6f} s, after the latest step "
                f"(t = {published_ns / NANOSECONDS_PER_SECOND:.6f} s): from the future"
            )
        elif tm_ns > self.newest_ns:
            self.newest_torque, self.newest_ns, self.newest_apply = torque.data, tm_ns, apply

    def set_motor_alive(self, alive: bool) -> None:
        """A motor control came or went. In lockstep one that comes after the first step is silent
        until it answers; one there before is waited for from the first step (the start-up
        handshakes make sure it sees the first wheel angles)."""
        self.motor_alive = alive
        self._set_silent(self.lockstep and alive and self._progress.started)

    def _set_silent(self, silent: bool) -> None:
        if silent == self.silent:
            return
        self.silent = silent
        if silent:
            self._events.silent()
        elif self.motor_alive:
            self._events.answering()

    # --- lockstep ---

    def begin_wait(self, tm_ns: int) -> None:
        self.awaited_ns, self.answered, self.waited_long = tm_ns, False, False

    def settled(self) -> bool:
        """The wait for this step's torque is over: it came, or the motor has gone."""
        return self.answered or not self.motor_alive

    def still_waiting(self, tm_ns: int, waited_s: float) -> None:
        """The step at ``tm_ns`` has waited ``waited_s`` for its torque (another
        ``sim.lockstep_timeout``) and waits on: said each time, counted once per step."""
        if not self.waited_long:
            self.waited_long = True
            self._counters["long_waits"] += 1
        self._events.waiting(tm_ns, waited_s)

    def silent_wait_ran_out(self, final: bool) -> None:
        """A silent motor control's one real-time period passed without this step's torque: it is
        missing (but for the ``final`` state's, which is never applied)."""
        if not final:
            self._counters["missing_torques"] += 1

    def not_awaited(self, final: bool) -> None:
        """The step went on without waiting (no motor control alive): unless a torque came
        anyway, the step's is missing (but for the ``final`` state's, which is never applied)."""
        if not (self.answered or final):
            self._counters["missing_torques"] += 1

    def end_wait(self, step_index: int, final: bool) -> None:
        """After the wait for this step's torque: count it, or apply zero torque (or brake). The
        ``final`` state's torque is taken, never applied: the run ends there."""
        self.awaited_ns = -1
        if final:
            return
        if self.answered:
            self._counters["torques_applied"] += 1
            self.torque_step = step_index
        else:
            self._no_torque(step_index)

    # --- realtime ---

    def realtime(self, tm_ns: int, step_index: int) -> None:
        """Set the torque of the step at ``tm_ns``: the newest, unless it is older than ``sim.torque_max_age``."""
        if self.newest_ns != tm_ns:
            self._counters["realtime_late_steps"] += 1
        newest = self.newest_torque
        if newest is not None and 0 <= tm_ns - self.newest_ns <= self.max_age_ns:
            self.newest_apply(newest)
            self._counters["torques_applied"] += 1
            self.torque_step = step_index
        else:
            self._no_torque(step_index)
            self._counters["missing_torques"] += 1

    # --- both ---

    def _no_torque(self, step_index: int) -> None:
        """No torque for this step: zero torque, or the brakes once there has been none for
        ``sim.brake_after`` (the motor control gone, silent, or cut off by a link down)."""
        if self.brake_steps is not None and step_index - self.torque_step >= self.brake_steps:
            if not self._wheels.braking:
                self._events.braking()
            self._wheels.brake()
            self._counters["braked_steps"] += 1
        else:
            self._wheels.set_zero_torques()
