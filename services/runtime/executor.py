"""The executor: the one thread that handles a service's events and takes its inputs.

Zenoh callbacks post events (queries, queued samples, liveliness changes) to its queue; the thread
handles them and takes the samples waiting in its inputs' channels itself. Idle, it waits in the
receive of its *waking* input (named at ``Node.subscribe(..., wakes=True)``, or per wait with
``waiting_for``), so a pacing sample reaches the service with no thread switch; a waker thread
ends that wait when an event is posted or the wait is over.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from services.runtime.inputs import LatestSample, NodeInput, is_wake
from services.runtime.memory import trim_when_due
from services.runtime.realtime import collect_when_idle

STOP_POLL_S = 0.1
"""Longest a service thread waits without looking at its stop event (SIGINT/SIGTERM)."""

SAMPLING_POLL_S = 0.001
"""How often, at most, an executor looks at its sampled inputs while it has other things to do,
and how long it waits at most between two looks when it has nothing else."""
EVENT_CAPACITY = 4096
"""Posted events (queries, callback samples, liveliness changes) an executor holds; beyond, a
new one is dropped and counted (a query dropped so is finalized with no reply)."""
WAKE_PERIOD_S = 0.01
"""How often a service thread blocked in a channel receive is checked: woken once its wait is
over (at once when an event is posted). Waits shorter than this are timed waits."""


class Executor:
    """The event queue of one service thread: zenoh callbacks post, the thread handles.

    A node gets an executor of its own; services composed in one process may share one, so a
    single thread handles all their events in arrival order, with no thread switch between
    them (as a ROS 2 single-threaded executor does). Besides posted events, the thread takes
    the samples of its channel inputs (:attr:`Delivery.EVERY`, :attr:`Delivery.NEWEST`) itself:
    first the posted events, then the channel inputs in the order they were added. Sampled inputs (:class:`LatestSample`) are looked
    at when nothing else waits, and at least every :data:`SAMPLING_POLL_S` while things do: in a
    shared executor the loop never runs dry, and a clock or a pose needs no more than that.

    Not a ``queue.SimpleQueue``: on CPython 3.11 its ``get(timeout)`` can wait forever (deaf to
    signals too) when the thread is descheduled for longer than the timeout at the wrong moment,
    which a loaded machine and millisecond polls make happen. A deque plus a lock that
    :meth:`post` releases has no such window: ``Lock.acquire(timeout)`` recomputes its deadline.
    """

    def __init__(self) -> None:
        self._events: collections.deque[tuple[Callable[[Any], None], Any]] = collections.deque()
        self.spinning_thread: int | None = None
        """The thread that last began to handle events and inputs: a message a publisher of this
        process offers on it waits in its input; from any other thread, it is posted
        (services/runtime/intraprocess.py)."""
        self.dropped_events = 0
        """Events not queued because :data:`EVENT_CAPACITY` were waiting."""
        self._posted = threading.Lock()
        """Held while the thread has seen every event; a post releases it to wake the thread."""
        self._posted.acquire()
        self._inputs: list[NodeInput] = []
        self._ready: collections.deque[NodeInput] = collections.deque(maxlen=EVENT_CAPACITY)
        """Inputs a publisher of this process has just handed a message to (intra-process delivery,
        services/runtime/intraprocess.py), in the order it did: taken without looking at every
        input. Bounded: an input whose entry was pushed out is still found by the scan."""
        self._next_scan = 0.0
        """When the inputs are scanned for what came through zenoh even though messages of this
        process wait (monotonic seconds): at most every ``SAMPLING_POLL_S`` while busy."""
        self._waking: list[NodeInput] = []
        """The inputs declared to wake the thread; it waits in the first (unless told otherwise)."""
        self._sampled: list[LatestSample] = []
        self._next_sampling = 0.0
        """When the sampled inputs are looked at even though other things wait (monotonic seconds)."""
        self._received: tuple[NodeInput, zenoh.Sample] | None = None
        """A sample a blocking receive returned, handled after the events posted before it."""
        self._blocked_until: float | None = None
        """While the thread waits in a channel receive: when that wait is over (monotonic seconds)."""
        self._blocked_in: NodeInput | None = None
        """The input in whose receive the thread waits (meaningful while ``_blocked_until`` is set)."""
        self._woken = False
        """Whether the waker has already ended the receive in progress. Once is enough, and more
        would harm: while a loaded machine keeps the thread from running, every further wake sample
        would push a real one out of a newest-only input's two-sample ring (a lockstep tick's clock
        sample was lost so, and the loop waited out its timeout)."""
        self._waker: threading.Thread | None = None
        self._waker_stop = threading.Event()
        self._waker_call = threading.Event()
        """Set by a post while the thread is blocked in a receive: the waker wakes it at once."""

    @property
    def queued(self) -> int:
        """Events posted and not yet handled."""
        return len(self._events)

    def post(self, handle: Callable[[Any], None], item: Any) -> None:
        """Queue ``handle(item)``; thread-safe, and cheap enough for a zenoh callback. Dropped
        (and counted) when :data:`EVENT_CAPACITY` events wait already."""
        if len(self._events) >= EVENT_CAPACITY:
            self.dropped_events += 1
            return
        self._events.append((handle, item))
        try:
            self._posted.release()
        except RuntimeError:  # already released by an earlier post the thread has not woken for yet
            pass
        # The thread marks itself blocked before it looks at the events a last time, so an event
        # it did not see finds the mark here.
        if self._blocked_until is not None:
            self._waker_call.set()

    def add_input(self, channel_input: NodeInput, wakes: bool = False) -> None:
        """Take ``channel_input``'s samples after those of the inputs added before it; ``wakes``: an
        idle thread waits in its receive (in the first such input, when several services share this
        executor)."""
        self._inputs.append(channel_input)
        channel_input.ready = self._ready
        if wakes:
            self._waking.append(channel_input)
        self._start_waker()

    def add_sampled(self, sampled: LatestSample) -> None:
        self._sampled.append(sampled)
        self._start_waker()

    def remove_input(self, removed: NodeInput) -> None:
        for inputs in (self._inputs, self._waking):
            if removed in inputs:
                inputs.remove(removed)
        for _ in range(len(self._ready)):
            waiting = self._ready.popleft()
            if waiting is not removed:
                self._ready.append(waiting)
        if isinstance(removed, LatestSample) and removed in self._sampled:
            self._sampled.remove(removed)
        if self._received is not None and self._received[0] is removed:
            self._received = None
        if not self._inputs and not self._sampled and self._waker is not None:
            self._waker_stop.set()
            self._waker_call.set()
            self._waker.join()
            self._waker = None

    def _start_waker(self) -> None:
        if self._waker is None:
            self._waker_stop.clear()
            self._waker = threading.Thread(target=self._wake_blocked, name="invent-waker", daemon=True)
            self._waker.start()

    @property
    def receiving(self) -> bool:
        """True while the thread waits in a channel input's receive."""
        return self._blocked_until is not None

    def spin_once(self, timeout: float | None, waiting_for: NodeInput | None = None) -> bool:
        """Handle one event or sample, waiting up to ``timeout`` seconds; False if none came.

        A thread with nothing to take waits in its waking input's receive, so a sample of
        another input waits until the thread wakes: ``waiting_for`` names the input to wait in
        instead, when the service knows which sample it needs next. A sampled input named so is
        the only one that counts meanwhile: the others are not polled while the thread waits."""
        self.spinning_thread = threading.get_ident()
        if self._take():
            return True
        if timeout == 0:
            return False
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return False
            self._wait(remaining, waiting_for)
            if self._take():
                return True

    def spin_until(self, done: Callable[[], bool], timeout: float, waiting_for: NodeInput | None = None) -> bool:
        """Handle events and samples (as :meth:`spin_once` does, one at a time) until ``done()``:
        True then; False once ``timeout`` seconds have passed without it.

        For a wait that several messages of the same process end, as the simulator's for its
        torque (the motor's wheel angles, then the torque): one call, not a ``spin_once`` and its
        caller's checks for each message."""
        self.spinning_thread = threading.get_ident()
        deadline = time.monotonic() + timeout
        while not done():
            if self._take():
                if time.monotonic() < deadline:
                    continue
                return done()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self._wait(remaining, waiting_for)
        return True

    def _take(self) -> bool:
        # One look at the clock serves both polls: a take runs several times per lockstep step.
        now = time.monotonic()
        if self._sampled and now >= self._next_sampling and self._take_sampled():
            return True
        events = self._events
        if events:
            handle, item = events.popleft()
            handle(item)
            return True
        received = self._received
        if received is not None:
            self._received = None
            receiving_input, sample = received
            receiving_input.handle(sample)
            return True
        ready = self._ready
        if ready and now < self._next_scan:
            while ready:
                if ready.popleft().take_local():
                    return True
        self._next_scan = now + SAMPLING_POLL_S
        for channel_input in self._inputs:
            if channel_input.take():
                return True
        return bool(self._sampled) and self._take_sampled()

    def _take_sampled(self) -> bool:
        """Hand every sampled input's new sample, if any, to its handler; True if one was handled."""
        self._next_sampling = time.monotonic() + SAMPLING_POLL_S
        taken = False
        for sampled in self._sampled:
            taken = sampled.take() or taken
        return taken

    def _wait(self, remaining: float | None, waiting_for: NodeInput | None) -> None:
        """Wait for something to take: in an input's receive (``waiting_for``, else the waking
        input), or on posted events.

        With sampled inputs (unless ``waiting_for`` is one) the wait is never longer than
        :data:`SAMPLING_POLL_S` and always on posted events, so a channel sample from another
        process may then wait that long (in a composition, the one executor with both, channel
        samples come from its own thread)."""
        collect_when_idle()
        trim_when_due()
        if self._sampled and waiting_for not in self._sampled:
            remaining = SAMPLING_POLL_S if remaining is None else min(remaining, SAMPLING_POLL_S)
        blocking_in = waiting_for if waiting_for is not None else (self._waking[0] if self._waking else None)
        if blocking_in is None or not blocking_in.blocks or (remaining is not None and remaining < WAKE_PERIOD_S):
            self._posted.acquire(True, -1 if remaining is None else remaining)
            return
        self._blocked_in = blocking_in
        self._woken = False
        self._blocked_until = math.inf if remaining is None else time.monotonic() + remaining
        if self._events:  # posted after the last look: the waker may have checked before the mark
            self._blocked_until = None
            return
        sample = blocking_in.receive()
        self._blocked_until = None
        if is_wake(sample):
            return
        if isinstance(blocking_in, LatestSample):
            blocking_in.put_back(sample)
        else:
            self._received = (blocking_in, sample)

    def _wake_blocked(self) -> None:
        """The waker thread: ends a blocking receive whose wait is over, and at once one that
        events wait behind (a post calls it; it may not call zenoh itself, being in a callback)."""
        while True:
            self._waker_call.wait(WAKE_PERIOD_S)
            self._waker_call.clear()
            if self._waker_stop.is_set():
                return
            until, blocked_in = self._blocked_until, self._blocked_in
            if (
                until is not None
                and blocked_in is not None
                and not self._woken
                and (self._events or time.monotonic() >= until)
            ):
                self._woken = True
                blocked_in.wake()
