"""A service's view of the simulator (docs/protocol.md section 8.6): whether its liveliness token is
there, and, through one :class:`~services.clock.sim_time.ClockRestart`, when its clock starts again.

Every consumer of the simulator's stamps (motor, odometry, localization, drive) follows the same
rule: the token's appearance lets the next sample of the clock decide whether a new time base
starts. An input stamped in the simulator's time that comes meanwhile waits for that sample
(:meth:`SimulatorWatch.stamped`), since the old time base cannot judge it: a new run's first
target or fix would look older than the history kept, or, after a short run, be taken as a late
input of the old one. The one exception is an input the service is waiting for in lockstep (the
motor's target for a held sample, odometry's fix, the drive's pose for a pending tick): what
waits for it came before the token, so the input is of the old time base, and holding it back
would stall the loop (the simulator waits for the service, which would wait for the next sample).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, Protocol

from schemas.keys import Service
from schemas.messages import NANOSECONDS_PER_SECOND, TimedDoubleSeq
from services.clock.lockstep import Hold, StepMark, decode_mark
from services.clock.sim_time import ClockRestart
from services.runtime.node import Node

HeldSample = tuple[TimedDoubleSeq, bytes | None, StepMark | None, int]
"""A wheel-angle sample, its attachment, the mark decoded from it and its stamp in ns, as a
:class:`Hold` keeps it (a plain tuple: one is made at every step)."""


class TimeBase(Protocol):
    """A core that integrates the wheel-angle clock (the motor's, odometry's)."""

    @property
    def time_ns(self) -> int | None:
        """The stamp of the last sample taken; None before the first (or a restart)."""

    def restart_time_base(self) -> None:
        """The next sample initialises, like the very first."""


class SimulatorWatch:
    """Declared by a service (it watches ``sim/alive`` through its node); its handlers wrap the
    service's own: :meth:`clock` or :meth:`held_clock` for the simulator's clock input,
    :meth:`stamped` for the other inputs stamped in the simulator's time."""

    def __init__(self, node: Node, restart: ClockRestart) -> None:
        self.alive = False
        """Whether the simulator's liveliness token is there."""
        self.restart = restart
        self._node = node
        self._waiting: dict[str, Callable[[], None]] = {}
        """Per key, the newest input that came while the clock was deciding."""
        node.watch(Service.SIM, self._on_token)

    def _on_token(self, alive: bool) -> None:
        # Every appearance, not a disappearance then an appearance: zenoh shows a new token on the
        # same key only once the old one is gone, and a disappearance says nothing about the
        # stamps to come.
        self.alive = alive
        if alive:
            self.restart.simulator_appeared()

    def clock(self, handler: Callable[..., None]) -> Callable[..., None]:
        """``handler`` of the simulator's clock input, which calls ``restart.decide`` (directly or
        through a :class:`~services.clock.sim_time.StampClock`) before it takes a sample; the inputs
        that waited for the decision are handled right after the sample that made it."""

        def handle(*args: Any) -> None:
            try:
                handler(*args)
            finally:  # a sample that decided, then proved bad input, decided all the same
                self._take_waiting()

        return handle

    def _take_waiting(self) -> None:
        """Handle the inputs that waited for the clock to decide, once it has."""
        waiting = self._waiting
        if waiting and not self.restart.deciding:
            handles = list(waiting.values())
            waiting.clear()
            for handle_waiting in handles:
                handle_waiting()

    def held_clock(self, hold: Hold[HeldSample], time_base: TimeBase, kept: str) -> Callable[..., None]:
        """The handler of a wheel-angle input whose samples go through a lockstep ``hold`` before
        ``time_base`` takes them (motor, odometry).

        Whether a sample starts a new time base is decided when it arrives, not when it is taken:
        in lockstep it may be held, and the new run's first target or fix must not be judged by the
        old time base meanwhile. A new time base drops the held samples; the INFO line says what is
        ``kept``. The inputs that waited for the decision are handled right after, even when the
        sample taken at once proves bad input (it reaches the input's handler, which counts it).
        This runs at every step, so it checks before it calls: a decision only while one is
        pending, the waiting inputs only if there are any."""
        log = self._node.log
        restart, waiting = self.restart, self._waiting

        def handle(sample: TimedDoubleSeq, attachment: bytes | None) -> None:
            stamp_ns = sample.tm.to_nanoseconds()
            mark = decode_mark(attachment, stamp_ns)
            owed = None if mark is None else mark.owed
            if restart.deciding and restart.decide(stamp_ns, time_base.time_ns):
                hold.forget()
                time_base.restart_time_base()
                log.info(
                    "simulation time went back to %.3f s (a new simulator): a new time base (%s)",
                    stamp_ns / NANOSECONDS_PER_SECOND,
                    kept,
                )
            try:
                hold.offer((sample, attachment, mark, stamp_ns), owed)
            finally:
                if waiting:
                    self._take_waiting()

        return handle

    def stamped(self, key: str, handler: Callable[..., None], awaited: Callable[[], bool]) -> Callable[..., None]:
        """``handler`` of an input stamped in the simulator's time (``key``), other than the clock:
        while the clock decides, the newest such input waits for the sample that decides, unless
        ``awaited()``: the service waits for this very input to go on."""
        node, restart, waiting = self._node, self.restart, self._waiting

        def handle(*args: Any) -> None:
            if restart.deciding and not awaited():
                waiting[key] = partial(node.guard, key, handler, *args)
            else:
                handler(*args)

        return handle
