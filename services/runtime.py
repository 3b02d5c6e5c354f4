"""The service runtime every service stands on.

A :class:`Node` wraps one service's zenoh declarations: a liveliness token, a ``status``
queryable, typed subscriptions, queryables and publishers. Zenoh callbacks only hand their
sample or query to the node's own queue, and the samples of the inputs that pace a service
wait in zenoh channels (:class:`ChannelInput`); the service's thread takes both with
:meth:`Node.spin_once`, so decoding, the control core, publishing and replying all happen on
one thread, never inside a zenoh callback (calling zenoh from there can deadlock).

Bad input (SPEC section 8) never kills a service: the node drops it, logs one line naming the
key and the reason (at most one line per key per second), and counts it in ``status``. Every
queue is bounded (:data:`CHANNEL_CAPACITY`, :data:`EVENT_CAPACITY`).
"""

from __future__ import annotations

import collections
import json
import logging
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar

import msgspec
import zenoh

from schemas.codec import ENCODING, BadInput, decode, encode
from schemas.keys import Keys, Service
from services.config import ConfigError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where services connect and ``invent router`` listens by default (rmw_zenoh's convention)."""
LOOPBACK_LISTEN = "tcp/127.0.0.1:0"
"""Where a peer listens unless told otherwise: a free port on loopback, so peers on one host still
talk directly while nothing off the host can connect (zenoh's own default is every interface)."""

ZENOH_CONFIG_VARIABLE = "ZENOH_CONFIG"
LOW_LATENCY_VARIABLE = "INVENT_ZENOH_LOWLATENCY"
"""Set to 1 to use :data:`LOW_LATENCY` (opt-in: see its caveats)."""
LOW_LATENCY = {
    "transport/unicast/lowlatency": "true",
    "transport/unicast/qos/enabled": "false",
    "scouting/gossip/autoconnect_strategy": json.dumps({"peer": {"to_router": "always", "to_peer": "greater-zid"}}),
}
"""Zenoh's low-latency unicast transport: a put writes to the socket itself, no batching thread
(it needs QoS off). The separate-process lockstep loop gains about 15-20 % from it
(benchmarks/README.md), but it is not the default, for what else was measured here with
zenoh 1.10.2: no batching, so a loaded subscriber of a 1 kHz key falls further behind; no
fragmentation, so a publication that does not fit in one batch is dropped (48 kB pass, 56 kB do
not); with both peers of a pair connecting at once, declarations were lost at start-up (about
one start in six; hence peers connecting one way only, to the greater id, which cured it); and
once, the whole loop stalled in puts and a declaration for minutes. A peer or router without
these settings (zenohd's defaults) still talks to these, over the ordinary transport."""
LOG_INTERVAL_S = 1.0
"""At most one line per kind (bad input per key, internal errors per key, ...) per interval."""
STOP_POLL_S = 0.1
"""Longest a service thread waits without looking at its stop event (SIGINT/SIGTERM)."""
LIVELINESS_QUERY_TIMEOUT_S = 1.0
"""Upper bound on a start-up liveliness query (the router answers at once)."""
MessageT = TypeVar("MessageT", bound=msgspec.Struct)

log = logging.getLogger("invent")


def session_config(
    *, connect: Iterable[str] = (), listen: Iterable[str] = (), mode: str = "peer", file: str | None = None
) -> zenoh.Config:
    """The zenoh configuration of a service or tool.

    Default: ``mode`` (peer), multicast scouting off, connect to :data:`DEFAULT_ENDPOINT`;
    with ``$INVENT_ZENOH_LOWLATENCY=1`` also the :data:`LOW_LATENCY` transport. A zenoh config
    ``file`` (``--zenoh-config``), else one named by ``$ZENOH_CONFIG``, replaces the default;
    ``connect`` endpoints override either's. A peer listens on :data:`LOOPBACK_LISTEN` plus any
    ``listen`` endpoints (unless its file names its own); a router on ``listen``, else its file's
    or :data:`DEFAULT_ENDPOINT`; a client listens on nothing unless told. A file that zenoh cannot
    read is a :class:`ConfigError`.
    """
    connect, listen = list(connect), list(listen)
    path = file or os.environ.get(ZENOH_CONFIG_VARIABLE)
    if path:
        try:
            config = zenoh.Config.from_file(path)
        except zenoh.ZError as error:
            raise ConfigError(f"zenoh config {path}: {error}") from None
    else:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("scouting/multicast/enabled", "false")
        if mode == "router":
            listen = listen or [DEFAULT_ENDPOINT]
            # With multicast scouting off a router has nothing to scout: don't wait 0.5 s for it.
            config.insert_json5("scouting/delay", "0")
        else:
            connect = connect or [DEFAULT_ENDPOINT]
        if os.environ.get(LOW_LATENCY_VARIABLE) == "1":
            for path_in_config, value in LOW_LATENCY.items():
                config.insert_json5(path_in_config, value)
    if json.loads(config.get_json("mode")) == "peer" and not _listens_explicitly(config):
        listen = [LOOPBACK_LISTEN, *listen]
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    return config


def _listens_explicitly(config: zenoh.Config) -> bool:
    """False while ``listen/endpoints`` is zenoh's default, a table by mode whose peer entry is
    every interface (``tcp/[::]:0``)."""
    return isinstance(json.loads(config.get_json("listen/endpoints")), list)


class RateLimitedLog:
    """One log line per key per interval at most; the lines left out are counted and said with
    the next. For anything a sender can make happen at will: bad input, internal errors, late
    torques (at 1 kHz, a line per occurrence would fill the log)."""

    def __init__(self, logger: logging.Logger, interval_s: float = LOG_INTERVAL_S) -> None:
        self._logger = logger
        self._interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def __call__(self, key: str, level: int, message: str, *args: Any, exc_info: bool = False) -> None:
        now = time.monotonic()
        if now - self._last.get(key, -math.inf) < self._interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        suppressed = self._suppressed.pop(key, 0)
        more = f" ({suppressed} more since the last line)" if suppressed else ""
        self._logger.log(level, message + more, *args, exc_info=exc_info)
        self._last[key] = now


@dataclass
class _KeyErrors:
    count: int = 0
    last_reason: str = ""


@dataclass
class BadInputCounter:
    """Counts bad input per key and logs at most one line per key per interval."""

    service: str
    by_key: dict[str, _KeyErrors] = field(default_factory=dict)
    _log: RateLimitedLog = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._log = RateLimitedLog(log.getChild(self.service))

    def record(self, key: str, reason: str) -> None:
        entry = self.by_key.setdefault(key, _KeyErrors())
        entry.count += 1
        entry.last_reason = reason
        self._log(key, logging.WARNING, "bad input on %s: %s; dropped", key, reason)

    @property
    def total(self) -> int:
        return sum(entry.count for entry in self.by_key.values())

    def reset(self) -> None:
        self.by_key.clear()

    def as_dict(self) -> dict[str, Any]:
        return {
            "total": self.total,
            "by_key": {key: {"count": e.count, "last_reason": e.last_reason} for key, e in self.by_key.items()},
        }


def has_match(entity: zenoh.Publisher | zenoh.Querier) -> bool:
    """Whether ``entity`` has a subscriber (publisher) or queryable (querier) now."""
    # zenoh-python 1.10's stub types matching_status as bool; it returns a MatchingStatus.
    status: Any = entity.matching_status
    return bool(status.matching)


class Publisher:
    """A zenoh publisher of one message type, encoding with the project's codec."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._publisher = session.declare_publisher(key, encoding=zenoh.Encoding(ENCODING))

    def put(self, message: msgspec.Struct, attachment: bytes | None = None) -> None:
        self._publisher.put(encode(message), attachment=attachment)

    @property
    def matched(self) -> bool:
        """True once at least one subscriber matches this key."""
        return has_match(self._publisher)

    def declare_matching_listener(self, callback: Callable[[zenoh.MatchingStatus], None]) -> Any:
        return self._publisher.declare_matching_listener(callback)

    def undeclare(self) -> None:
        self._publisher.undeclare()


class LatchedPublisher:
    """See :meth:`Node.latched_publisher`."""

    def __init__(self, publisher: Publisher) -> None:
        self._publisher = publisher
        self.last: msgspec.Struct | None = None

    def put(self, message: msgspec.Struct) -> None:
        self.last = message
        self._publisher.put(message)


_QueryHandler = Callable[[bytes], Any]

SAMPLING_POLL_S = 0.001
"""How often, at most, an executor looks at its sampled inputs while it has other things to do,
and how long it waits at most between two looks when it has nothing else."""


_Dispatch = Callable[[bytes, "bytes | None"], None]
"""Handles one sample's payload and attachment."""


def _contents(sample: zenoh.Sample) -> tuple[bytes, bytes | None]:
    attachment = sample.attachment
    return sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()


def _decoding(message_type: type[MessageT], handler: Callable[..., None], with_attachment: bool) -> _Dispatch:
    """A dispatch decoding the payload for ``handler(message)``, or ``handler(message, attachment)``."""
    if with_attachment:
        return lambda payload, attachment: handler(decode(message_type, payload), attachment)
    return lambda payload, _attachment: handler(decode(message_type, payload))


CHANNEL_CAPACITY = 256
"""Samples a channel input holds; when full, the oldest is dropped (zenoh's ring channel), so a
flood bounds the memory it takes and never blocks zenoh's receiving thread. Lockstep has one
sample in flight; in realtime a sample 256 steps old is useless anyway."""
NEWEST_CAPACITY = 2
"""Samples an input that needs only its newest one holds: two, not one, so the wake sample
(:meth:`NodeInput.wake`) pushes out the older of two, never the newest."""
EVENT_CAPACITY = 4096
"""Posted events (queries, callback samples, liveliness changes) an executor holds; beyond, a
new one is dropped and counted (a query dropped so is finalized with no reply)."""
WAKE_PERIOD_S = 0.01
"""How often a service thread blocked in a channel receive is checked: woken once its wait is
over (at once when an event is posted). Waits shorter than this are timed waits."""
_WAKE = b"invent-wake"
"""The attachment of the session-local sample that wakes a blocked channel receive."""


def _is_wake(sample: zenoh.Sample) -> bool:
    attachment = sample.attachment
    return attachment is not None and attachment.to_bytes() == _WAKE


class NodeInput:
    """A subscription whose samples wait in a zenoh ring channel until the service thread takes them.

    No Python runs in zenoh's thread and no thread switch happens on the way: the service thread,
    idle, waits in the channel's receive itself, where a callback would hand each sample over
    through zenoh-python's own thread (at thousands of samples per second those hand-offs cost
    more than the work; benchmarks/README.md).
    """

    def __init__(self, session: zenoh.Session, key: str, dispatch: _Dispatch, capacity: int) -> None:
        self.key = key
        self._session = session
        self._dispatch = dispatch
        self._subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))

    def receive(self) -> zenoh.Sample:
        """The next sample, waiting as long as it takes (a wake sample included)."""
        return self._subscriber.recv()

    def handle(self, sample: zenoh.Sample) -> None:
        self._dispatch(*_contents(sample))

    def take(self) -> bool:
        """Handle what waits, as this kind of input does; True if a sample was handled."""
        raise NotImplementedError

    def wake(self) -> None:
        """End a :meth:`receive` in progress: an empty sample delivered to this session only."""
        self._session.put(self.key, b"", attachment=_WAKE, allowed_destination=zenoh.Locality.SESSION_LOCAL)

    def undeclare(self) -> None:
        self._subscriber.undeclare()


class ChannelInput(NodeInput):
    """An input whose every sample is handled, in order (up to its capacity): for the inputs that
    pace a service (the simulator's torque, the motor's wheel angles). An executor waits in its
    first channel input's receive unless told which input to wait in (``waiting_for``); the
    samples of any other wait until the thread next wakes."""

    def __init__(self, session: zenoh.Session, key: str, dispatch: _Dispatch, capacity: int = CHANNEL_CAPACITY) -> None:
        super().__init__(session, key, dispatch, capacity)

    def take(self) -> bool:
        """Handle the next waiting sample, if any; True if one was handled."""
        while (sample := self._subscriber.try_recv()) is not None:
            payload, attachment = _contents(sample)
            if attachment != _WAKE:
                self._dispatch(payload, attachment)
                return True
        return False


class LatestSample(NodeInput):
    """An input of which only the newest sample counts, decoded when taken (:meth:`Node.sample`).

    For inputs a service needs only at its own pace (a clock, a pose): the simulator publishes
    them at its step rate, several kHz of wall time in lockstep, and handing every sample to
    Python would cost more than the work, while a service starved of CPU for a moment would then
    work through a backlog of stale samples. Here no Python runs per sample, and a busy service
    always acts on the present. (A bad sample overwritten before it is taken is never seen, so
    never counted.)
    """

    def __init__(self, session: zenoh.Session, key: str, dispatch: _Dispatch) -> None:
        super().__init__(session, key, dispatch, NEWEST_CAPACITY)
        self._received: zenoh.Sample | None = None

    def put_back(self, sample: zenoh.Sample) -> None:
        """Keep ``sample``, which a blocking receive took out of the ring, for the next take: it
        competes there with what came after it, so a newer sample is never followed by an older one."""
        self._received = sample

    def take(self) -> bool:
        """Handle the newest sample that arrived since the last take, if any; True if one did."""
        newest, self._received = self._received, None
        while (sample := self._subscriber.try_recv()) is not None:
            if not _is_wake(sample):
                newest = sample
        if newest is None:
            return False
        self.handle(newest)
        return True


class Executor:
    """The event queue of one service thread: zenoh callbacks post, the thread handles.

    A node gets an executor of its own; services composed in one process may share one, so a
    single thread handles all their events in arrival order, with no thread switch between
    them (as a ROS 2 single-threaded executor does). Besides posted events, the thread takes
    the samples of its :class:`ChannelInput` s itself: first the posted events, then the
    channel inputs in the order they were added. Sampled inputs (:class:`LatestSample`) are looked
    at when nothing else waits, and at least every :data:`SAMPLING_POLL_S` while things do: in a
    shared executor the loop never runs dry, and a clock or a pose needs no more than that.

    Not a ``queue.SimpleQueue``: on CPython 3.11 its ``get(timeout)`` can wait forever (deaf to
    signals too) when the thread is descheduled for longer than the timeout at the wrong moment,
    which a loaded machine and millisecond polls make happen. A deque plus a lock that
    :meth:`post` releases has no such window: ``Lock.acquire(timeout)`` recomputes its deadline.
    """

    def __init__(self) -> None:
        self._events: collections.deque[tuple[Callable[[Any], None], Any]] = collections.deque()
        self.dropped_events = 0
        """Events not queued because :data:`EVENT_CAPACITY` were waiting."""
        self._posted = threading.Lock()
        """Held while the thread has seen every event; a post releases it to wake the thread."""
        self._posted.acquire()
        self._inputs: list[NodeInput] = []
        self._sampled: list[LatestSample] = []
        self._next_sampling = 0.0
        """When the sampled inputs are looked at even though other things wait (monotonic seconds)."""
        self._received: tuple[NodeInput, zenoh.Sample] | None = None
        """A sample a blocking receive returned, handled after the events posted before it."""
        self._blocked_until: float | None = None
        """While the thread waits in a channel receive: when that wait is over (monotonic seconds)."""
        self._blocked_in: NodeInput | None = None
        """The input in whose receive the thread waits (meaningful while ``_blocked_until`` is set)."""
        self._waker: threading.Thread | None = None
        self._waker_stop = threading.Event()
        self._waker_call = threading.Event()
        """Set by a post while the thread is blocked in a receive: the waker wakes it at once."""

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

    def add_input(self, channel_input: NodeInput) -> None:
        """Take ``channel_input``'s samples after those of the inputs added before it."""
        self._inputs.append(channel_input)
        self._start_waker()

    def add_sampled(self, sampled: LatestSample) -> None:
        self._sampled.append(sampled)
        self._start_waker()

    def remove_input(self, removed: NodeInput) -> None:
        if removed in self._inputs:
            self._inputs.remove(removed)
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

        A thread with nothing to take waits in its first channel input's receive, so a sample of
        another input waits until the thread wakes: ``waiting_for`` names the input to wait in
        instead, when the service knows which sample it needs next. A sampled input named so is
        the only one that counts meanwhile: the others are not polled while the thread waits."""
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

    def _take(self) -> bool:
        if self._sampled and time.monotonic() >= self._next_sampling and self._take_sampled():
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
        """Wait for something to take: in an input's receive (``waiting_for``, else the first
        channel input), or on posted events.

        With sampled inputs (unless ``waiting_for`` is one) the wait is never longer than
        :data:`SAMPLING_POLL_S` and always on posted events, so a channel sample from another
        process may then wait that long (in a composition, the one executor with both, channel
        samples come from its own thread)."""
        if self._sampled and waiting_for not in self._sampled:
            remaining = SAMPLING_POLL_S if remaining is None else min(remaining, SAMPLING_POLL_S)
        blocking_in = waiting_for if waiting_for is not None else (self._inputs[0] if self._inputs else None)
        if blocking_in is None or (remaining is not None and remaining < WAKE_PERIOD_S):
            self._posted.acquire(True, -1 if remaining is None else remaining)
            return
        self._blocked_in = blocking_in
        self._blocked_until = math.inf if remaining is None else time.monotonic() + remaining
        if self._events:  # posted after the last look: the waker may have checked before the mark
            self._blocked_until = None
            return
        sample = blocking_in.receive()
        self._blocked_until = None
        if _is_wake(sample):
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
            if until is not None and blocked_in is not None and (self._events or time.monotonic() >= until):
                blocked_in.wake()


class InputTaken(msgspec.Struct):
    """What a service took of one input, in its ``status`` (``inputs``, by key): a tool feeding it
    (``invent replay --rate 0``) waits on ``samples`` so that it never sends faster than the
    service takes."""

    every_sample: bool
    """False for an input of which only the newest sample counts (skipped samples are not taken)."""
    samples: int = 0
    """Samples handed to the service, bad ones included."""


class Node:
    """One service's presence on zenoh. See the module docstring.

    ``status`` is called on the service thread to build the ``status`` reply; the node adds
    the service and robot names and the bad-input counters.
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        service: Service,
        status: Callable[[], dict[str, Any]] = dict,
        executor: Executor | None = None,
    ) -> None:
        self.session = session
        self.keys = keys
        self.service = service
        self.log = log.getChild(str(service))
        self.bad_inputs = BadInputCounter(str(service))
        self.internal_errors = 0
        self.participating = False
        """Whether it holds a lockstep participant's token (:meth:`participate`)."""
        self._internal_error_log = RateLimitedLog(self.log)
        self._status = status
        self.executor = executor or Executor()
        self._declarations: list[Any] = []
        self._inputs: list[NodeInput] = []
        self._publishers: list[Publisher] = []
        self._taken: dict[str, InputTaken] = {}
        self._started = time.monotonic()
        self.queryable(keys.status(service), lambda _payload: self.status())
        self._declarations.append(session.liveliness().declare_token(keys.alive(service)))

    def set_status(self, status: Callable[[], dict[str, Any]]) -> None:
        self._status = status

    def status(self) -> dict[str, Any]:
        return {
            "service": str(self.service),
            "robot": self.keys.robot,
            "uptime_s": round(time.monotonic() - self._started, 3),
            **self._status(),
            "inputs": dict(self._taken),
            "bad_input": self.bad_inputs.as_dict(),
            "internal_errors": self.internal_errors,
            "dropped_events": self.executor.dropped_events,
        }

    def subscribe(
        self,
        key: str,
        message_type: type[MessageT],
        handler: Callable[..., None],
        *,
        channel: bool = False,
        newest_only: bool = False,
        with_attachment: bool = False,
    ) -> NodeInput | None:
        """Call ``handler(message)`` on the service thread for every sample of ``key`` that decodes
        (``handler(message, attachment)`` ``with_attachment``: the sample's attachment bytes or None).
        The handler may raise BadInput. Returns the input if it waits in a channel (for ``waiting_for``).

        ``channel=True`` for the inputs that pace the service (the simulator's torque, the motor's
        wheel angles): see :class:`ChannelInput`. ``newest_only=True`` for a command whose newest
        value is all that counts (the motor's target): a :class:`LatestSample` taken after the
        channel inputs declared before it (not polled), so a flood of it is one sample and delays none.
        """
        dispatch = self._guarded_dispatch(key, message_type, handler, with_attachment, every_sample=not newest_only)
        if channel or newest_only:
            channel_input = (
                LatestSample(self.session, key, dispatch) if newest_only else ChannelInput(self.session, key, dispatch)
            )
            self.executor.add_input(channel_input)
            self._inputs.append(channel_input)
            return channel_input
        post = self.executor.post
        self._declarations.append(
            self.session.declare_subscriber(
                key, lambda sample: post(lambda contents: dispatch(*contents), _contents(sample))
            )
        )
        return None

    def queryable(self, key: str, handler: _QueryHandler, *, mutates: bool = False) -> None:
        """Answer queries on ``key`` from the service thread.

        ``handler(payload)`` returns a JSON-encodable reply (None: no reply), or raises BadInput,
        which becomes a ``reply_err`` naming the reason. The query is finalized right after the
        reply, so the caller's ``get`` returns at once.

        Looking never acts: a wildcard or prefix query (``invent/rh0/**``, what zenoh tools and
        the REST plugin send to look around) reaches every queryable its key expression
        intersects. A handler that ``mutates`` state therefore runs only for a query on exactly
        ``key``; any other query is dropped in zenoh's callback, which finalizes it with no reply.
        Read-only handlers (``status``) answer wildcards.
        """

        def answer(query: zenoh.Query) -> None:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                try:
                    reply = handler(payload)
                except BadInput as error:
                    self.bad_inputs.record(key, str(error))
                    query.reply_err(json.dumps({"error": str(error)}), encoding=zenoh.Encoding(ENCODING))
                    return
                except Exception as error:  # noqa: BLE001 (a bug must not kill the service; it is logged and counted)
                    self._internal_error(key, error)
                    query.reply_err(
                        json.dumps({"error": f"internal error: {error}"}), encoding=zenoh.Encoding(ENCODING)
                    )
                    return
                if reply is not None:
                    query.reply(key, msgspec.json.encode(reply), encoding=zenoh.Encoding(ENCODING))
            finally:
                query.drop()

        post = self.executor.post

        def on_query(query: zenoh.Query) -> None:
            if not mutates or str(query.key_expr) == key:
                post(answer, query)

        self._declarations.append(self.session.declare_queryable(key, on_query))

    def sample(
        self, key: str, message_type: type[MessageT], handler: Callable[..., None], *, with_attachment: bool = False
    ) -> LatestSample:
        """Call ``handler(message)`` (``handler(message, attachment)`` ``with_attachment``) on the
        service thread with the newest sample of ``key``, at most every :data:`SAMPLING_POLL_S` while
        the thread is busy, at once when it is idle: for inputs that clock a service at its own pace
        rather than pacing it (see LatestSample). Returns the input (for ``waiting_for``)."""
        sampled = LatestSample(
            self.session, key, self._guarded_dispatch(key, message_type, handler, with_attachment, every_sample=False)
        )
        self.executor.add_sampled(sampled)
        self._inputs.append(sampled)
        return sampled

    def _guarded_dispatch(
        self,
        key: str,
        message_type: type[MessageT],
        handler: Callable[..., None],
        with_attachment: bool,
        *,
        every_sample: bool,
    ) -> _Dispatch:
        """Decode and handle a sample of ``key``, counting it (``inputs`` in the status) and its
        bad input (see :meth:`guard`)."""
        decoding = _decoding(message_type, handler, with_attachment)
        taken = self._taken[key] = InputTaken(every_sample)

        def dispatch(payload: bytes, attachment: bytes | None) -> None:
            taken.samples += 1
            self.guard(key, lambda: decoding(payload, attachment))

        return dispatch

    def publisher(self, key: str) -> Publisher:
        publisher = Publisher(self.session, key)
        self._publishers.append(publisher)
        return publisher

    def latched_publisher(self, key: str) -> LatchedPublisher:
        """A publisher whose last message also answers queries on its key, for what changes
        rarely and a late subscriber needs at once (the sim's world, the drive's path): a viewer
        started mid-run gets it with a ``get``, as from a zenoh storage."""
        latched = LatchedPublisher(self.publisher(key))
        self.queryable(key, lambda _payload: latched.last)
        return latched

    def post(self, callback: Callable[[], None]) -> None:
        """Run ``callback()`` on the service thread (thread-safe; usable from zenoh callbacks)."""
        self.executor.post(lambda _: callback(), None)

    def watch(self, service: Service, on_change: Callable[[bool], None]) -> None:
        """Call ``on_change(alive)`` on the service thread whenever ``service``'s liveliness token
        appears (True; also for one already there) or goes (False): a neighbour that dies and
        comes back is then picked up again (SPEC section 8)."""
        post = self.executor.post
        self._declarations.append(
            self.session.liveliness().declare_subscriber(
                self.keys.alive(service),
                lambda sample: post(on_change, sample.kind == zenoh.SampleKind.PUT),
                history=True,
            )
        )

    def participate(self, publisher: Publisher, rate_hz: float) -> None:
        """Take part in lockstep (services/lockstep.py), outputting on ``publisher`` at ``rate_hz``
        ticks per second of simulation time: hold the token ``Keys.ticks`` once ``publisher`` has a
        subscriber (before, the outputs would reach no one, and waiting for them would only time out)."""
        post = self.executor.post

        def on_matching(matched: bool) -> None:
            if matched and not self.participating:
                self._declarations.append(
                    self.session.liveliness().declare_token(self.keys.ticks(self.service, rate_hz))
                )
                self.participating = True

        self._declarations.append(
            publisher.declare_matching_listener(lambda status: post(on_matching, status.matching))
        )

    def alive_now(self, service: Service, timeout: float = LIVELINESS_QUERY_TIMEOUT_S) -> bool:
        """Whether ``service``'s liveliness token exists now: one query, answered by the router
        or peers at once (for a decision at start-up, before any watch has reported)."""
        replies = self.session.liveliness().get(self.keys.alive(service), timeout=timeout)
        return any(reply.ok is not None for reply in replies)

    def spin_once(self, timeout: float | None, waiting_for: NodeInput | None = None) -> bool:
        """Handle one queued event, waiting up to ``timeout`` seconds; False if none came (see
        :meth:`Executor.spin_once` for ``waiting_for``)."""
        return self.executor.spin_once(timeout, waiting_for)

    def spin(
        self,
        stop: threading.Event,
        done: Callable[[], bool] = lambda: False,
        waiting_for: Callable[[], NodeInput | None] = lambda: None,
    ) -> None:
        """Handle events until ``stop`` is set or ``done()`` is true, waiting in ``waiting_for()``'s receive."""
        while not stop.is_set() and not done():
            self.spin_once(STOP_POLL_S, waiting_for())

    def drain(self) -> None:
        """Handle every event already queued, without waiting."""
        while self.spin_once(0):
            pass

    def guard(self, key: str, action: Callable[[], None]) -> None:
        """Run ``action`` (handling an input of ``key``) so that bad input is counted and a bug
        logged and counted, never raised: the service lives on."""
        try:
            action()
        except BadInput as error:
            self.bad_inputs.record(key, str(error))
        except Exception as error:  # noqa: BLE001 (a bug must not kill the service; it is logged and counted)
            self._internal_error(key, error)

    def _internal_error(self, key: str, error: Exception) -> None:
        self.internal_errors += 1
        self._internal_error_log(key, logging.ERROR, "internal error handling %s: %s", key, error, exc_info=True)

    def close(self) -> None:
        """Withdraw the liveliness token and undeclare everything (the session stays open)."""
        for node_input in self._inputs:
            self.executor.remove_input(node_input)
            node_input.undeclare()
        self._inputs.clear()
        for declaration in reversed(self._declarations):
            declaration.undeclare()
        for publisher in self._publishers:
            publisher.undeclare()
        self._declarations.clear()
        self._publishers.clear()


class SessionFailed(RuntimeError):
    """A zenoh session could not be opened: the router is unreachable or refused the credentials."""


@contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    try:
        session = zenoh.open(config)
    except zenoh.ZError as error:
        endpoints = json.loads(config.get_json("connect/endpoints"))
        raise SessionFailed(
            f"cannot open a zenoh session connecting to {', '.join(map(str, endpoints)) or 'nothing'}: "
            f"{str(error).split(' at ')[0]} (is the router running, and are the credentials right?)"
        ) from None
    try:
        yield session
    finally:
        session.close()


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (the service then shuts down cleanly, exit 0)."""
    stop = threading.Event()

    def handle(_signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handle)
    signal.signal(signal.SIGTERM, handle)
    return stop


def configure_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s.%(msecs)03d %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
