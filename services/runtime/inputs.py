"""Publishers, and the inputs a service declares with their :class:`Delivery`.

Zenoh callbacks never run service code: a sample either waits in a zenoh channel until the
service thread takes it (:class:`ChannelInput`, :class:`LatestSample`), or a callback posts it to
the executor's queue (:attr:`Delivery.QUEUED`). Either way decoding, the control core, publishing
and replying happen on the service's one thread, never in zenoh's (calling zenoh from there can
deadlock). Every queue is bounded.
"""

from __future__ import annotations

import collections
from collections import deque
from collections.abc import Callable
from enum import StrEnum
from typing import Any, NamedTuple

import msgspec
import zenoh

from schemas.codec import ENCODING, encode
from services.runtime.intraprocess import LocalBus, LocalSink, Tap
from services.runtime.journal import Journal
from services.runtime.session import has_match

LOCKSTEP_CONGESTION = zenoh.CongestionControl.BLOCK
"""A lockstep run's publishers wait for room in zenoh's transmit queue rather than drop a sample:
the run's time is the simulation's, so a slow reader (or a sending task descheduled on a loaded
machine) may slow the run but never changes what any reader gets. zenoh's default, DROP, drops a
sample after 1 ms without room (eclipse-zenoh/zenoh#847): measured, outside recorders of loaded
lockstep runs missed samples so. A realtime run keeps DROP: a reader must never delay the loop."""


def congestion(lockstep: bool) -> zenoh.CongestionControl:
    """What a run's publishers do when zenoh's transmit queue is full (:data:`LOCKSTEP_CONGESTION`)."""
    return LOCKSTEP_CONGESTION if lockstep else zenoh.CongestionControl.DROP


class Delivery(StrEnum):
    """How a service takes an input's samples: named at every ``Node.subscribe``."""

    QUEUED = "queued"
    """Every sample, posted by zenoh's callback to the executor's queue and handled in arrival
    order with the queries and liveliness changes: for rare inputs (a localized pose)."""
    EVERY = "every"
    """Every sample, in order (up to :data:`CHANNEL_CAPACITY`), from a ring channel the service
    thread takes itself, no Python in zenoh's thread: for the inputs that pace a service (the
    simulator's torque, the motor's wheel angles). See :class:`ChannelInput`."""
    NEWEST = "newest"
    """Only the newest sample, taken in turn with the ``EVERY`` inputs declared before it: a
    command whose newest value is all that counts (the motor's target); a flood of it is one
    sample and delays nothing. See :class:`LatestSample`."""
    SAMPLED = "sampled"
    """Only the newest sample, looked at when the thread is idle and at least every
    ``SAMPLING_POLL_S`` while it is busy: what clocks a service at its own pace rather than
    pacing it (the drive's clock and pose, the localization's simulated pose)."""

    @property
    def every_sample(self) -> bool:
        return self in (Delivery.QUEUED, Delivery.EVERY)


class _Matching(NamedTuple):
    """What a matching listener's callback gets (as zenoh's ``MatchingStatus``)."""

    matching: bool


class _MatchingListener:
    """A publisher's matching within the process and beyond it, as one listener."""

    def __init__(self, publisher: Publisher, bus: LocalBus, callback: Callable[[_Matching], None]) -> None:
        self._publisher, self._bus, self._callback = publisher, bus, callback
        self._local = False
        self._seen_remote = False
        self.remote: Any = None
        """zenoh's matching listener of the publisher (subscribers outside the process)."""
        bus.watch(publisher.key, self._on_local)

    def _on_local(self, matched: bool) -> None:
        self._local = matched
        self._callback(_Matching(matched or self._seen_remote))

    def on_remote(self, status: zenoh.MatchingStatus) -> None:
        self._seen_remote = status.matching
        self._callback(_Matching(status.matching or self._local))

    def undeclare(self) -> None:
        self._bus.unwatch(self._publisher.key, self._on_local)
        if self.remote is not None:
            self.remote.undeclare()


class Publisher:
    """A zenoh publisher of one message type, encoding with the project's codec; each message it
    puts is also kept in ``journal``, if given (``invent up``'s recording).

    With a ``bus`` (services composed in one process: services/runtime/intraprocess.py), a message
    goes to the process's own inputs of the key as it is, and through zenoh (encoded) only while a
    subscriber outside the process matches.

    ``congestion``: what zenoh does with a sample when its transmit queue is full (a reader or the
    sending task slow): :data:`LOCKSTEP_CONGESTION` or zenoh's default, DROP (docs/protocol.md §2.6)."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        journal: Journal | None = None,
        bus: LocalBus | None = None,
        congestion: zenoh.CongestionControl = zenoh.CongestionControl.DROP,
    ) -> None:
        self.key = key
        self._journal = journal
        self._bus = bus
        encoding = zenoh.Encoding(ENCODING)
        if bus is None:
            self._local: list[LocalSink | Tap] | None = None
            self._publisher = session.declare_publisher(key, encoding=encoding, congestion_control=congestion)
            self._remote = True
            return
        self._local = bus.sinks(key)
        self._publisher = session.declare_publisher(
            key, encoding=encoding, congestion_control=congestion, allowed_destination=zenoh.Locality.REMOTE
        )
        self._remote_watch = self._publisher.declare_matching_listener(self._on_remote)
        self._remote = has_match(self._publisher)

    def _on_remote(self, status: zenoh.MatchingStatus) -> None:
        self._remote = status.matching  # an attribute set in zenoh's thread, read by the service's

    def put(self, message: msgspec.Struct, attachment: bytes | None = None, *, keep: bool = True) -> None:
        """Publish ``message``; keep it in the journal too unless not ``keep`` (a control-path
        sample of a step that is not observed, in a run recorded at the observed steps)."""
        local, journal = self._local, self._journal if keep else None
        if local is not None:
            for sink in local:
                sink.offer(message, attachment)
            if not self._remote and journal is None:
                return
        payload = encode(message)
        if self._remote:
            self._publisher.put(payload, attachment=attachment)
        if journal is not None:
            journal.write(self.key, payload, stamp_ns=_stamp_ns(message))

    def record(self, message: msgspec.Struct) -> None:
        """Keep ``message`` in the journal (if any) without publishing it: an output computed at a
        step that is not observed, for a run recorded at every step (docs/protocol.md section 2.7)."""
        if self._journal is not None:
            self._journal.write(self.key, encode(message), stamp_ns=_stamp_ns(message))

    @property
    def congestion_control(self) -> zenoh.CongestionControl:
        return self._publisher.congestion_control

    @property
    def remote_subscribers(self) -> bool:
        """Whether a subscriber outside the process matches (always true of a publisher with no bus:
        all its messages go through zenoh)."""
        return self._remote

    @property
    def matched(self) -> bool:
        """True once at least one subscriber matches this key (of this process's, with a bus)."""
        if self._bus is not None:
            return bool(self._local) or self._remote
        return has_match(self._publisher)

    def declare_matching_listener(self, callback: Callable[[Any], None]) -> Any:
        """``callback(status)`` whenever ``status.matching`` (a subscriber matches) changes; with a
        bus, a subscriber of this process counts as one outside it does. Call it in no zenoh callback."""
        if self._bus is None:
            return self._publisher.declare_matching_listener(callback)
        listener = _MatchingListener(self, self._bus, callback)
        listener.remote = self._publisher.declare_matching_listener(listener.on_remote)
        return listener

    def undeclare(self) -> None:
        if self._bus is not None:
            self._remote_watch.undeclare()
        self._publisher.undeclare()


def _stamp_ns(message: msgspec.Struct) -> int | None:
    """A data message's stamp (every data key's message has its ``tm``), for the journal's limits."""
    tm = getattr(message, "tm", None)
    return None if tm is None else tm.to_nanoseconds()


class LatchedPublisher:
    """See :meth:`Node.latched_publisher`."""

    def __init__(self, publisher: Publisher) -> None:
        self._publisher = publisher
        self.last: msgspec.Struct | None = None

    def put(self, message: msgspec.Struct) -> None:
        self.last = message
        self._publisher.put(message)


Dispatch = Callable[[bytes, "bytes | None"], None]
"""Decodes and handles one sample's payload and attachment (built by the node)."""
DispatchMessage = Callable[[msgspec.Struct, "bytes | None"], None]
"""Handles one message, as a publisher of the same process offered it, and its attachment."""

CHANNEL_CAPACITY = 256
"""Samples a channel input holds; when full, the oldest is dropped (zenoh's ring channel), so a
flood bounds the memory it takes and never blocks zenoh's receiving thread. Lockstep has one
sample in flight; in realtime a sample 256 steps old is useless anyway."""
NEWEST_CAPACITY = 2
"""Samples an input that needs only its newest one holds: two, not one, so the wake sample
(:meth:`NodeInput.wake`) pushes out the older of two, never the newest."""
_WAKE = b"invent-wake"
"""The attachment of the session-local sample that wakes a blocked channel receive."""


def contents(sample: zenoh.Sample) -> tuple[bytes, bytes | None]:
    """A sample's payload and attachment as bytes."""
    attachment = sample.attachment
    return sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()


def is_wake(sample: zenoh.Sample) -> bool:
    """Whether ``sample`` is the one :meth:`NodeInput.wake` put (not an input)."""
    attachment = sample.attachment
    return attachment is not None and attachment.to_bytes() == _WAKE


class NodeInput:
    """A subscription whose samples wait in a zenoh ring channel until the service thread takes them.

    No Python runs in zenoh's thread and no thread switch happens on the way: the service thread,
    idle, waits in the channel's receive itself, where a callback would hand each sample over
    through zenoh-python's own thread (at thousands of samples per second those hand-offs cost
    more than the work; benchmarks/README.md).
    """

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        dispatch: Dispatch,
        capacity: int,
        dispatch_message: DispatchMessage | None = None,
        on_sample: Callable[[zenoh.Sample], None] | None = None,
    ) -> None:
        """``on_sample``: a callback that takes each sample from zenoh instead of a ring channel."""
        self.key = key
        self._session = session
        self._dispatch = dispatch
        self._dispatch_message = dispatch_message
        """Handles a message a publisher of this process offered as it is (services/runtime/intraprocess.py)."""
        self._subscriber: zenoh.Subscriber[Any] = session.declare_subscriber(
            key, on_sample if on_sample is not None else zenoh.handlers.RingChannel(capacity)
        )
        self.blocks = True
        """Whether the executor's thread may wait in :meth:`receive` (its samples wait in a ring channel)."""
        self.ready: collections.deque[NodeInput] | None = None
        """Its executor's queue of inputs with a message of this process to take (set by the
        executor; None for a sampled input, which the executor looks at at its own pace)."""

    def accept_local(self, message: msgspec.Struct, attachment: bytes | None) -> None:
        """Keep a message a publisher of this process offered, for the next take (executor's thread)."""
        raise NotImplementedError

    def take_local(self) -> bool:
        """Handle a message of this process if one waits; True if one was handled."""
        raise NotImplementedError

    def receive(self) -> zenoh.Sample:
        """The next sample, waiting as long as it takes (a wake sample included)."""
        return self._subscriber.recv()

    def handle(self, sample: zenoh.Sample) -> None:
        self._dispatch(*contents(sample))

    def take(self) -> bool:
        """Handle what waits, as this kind of input does; True if a sample was handled."""
        raise NotImplementedError

    def wake(self) -> None:
        """End a :meth:`receive` in progress: an empty sample delivered to this session only."""
        self._session.put(self.key, b"", attachment=_WAKE, allowed_destination=zenoh.Locality.SESSION_LOCAL)

    def undeclare(self) -> None:
        self._subscriber.undeclare()


class ChannelInput(NodeInput):
    """An input whose every sample is handled, in order (up to its capacity): :attr:`Delivery.EVERY`."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        dispatch: Dispatch,
        capacity: int = CHANNEL_CAPACITY,
        dispatch_message: DispatchMessage | None = None,
        post: Callable[[Callable[[Any], None], Any], None] | None = None,
    ) -> None:
        """``post``: with a bus (services composed in one process), the samples from outside the
        process are posted to the executor as they come, their bytes copied out, and the thread never
        waits in this input's receive: several inputs of a composition are paced by other processes
        (a fleet's worker: every robot's wheel angles, from the simulator), and a thread can wait
        in only one receive, while a posted sample wakes it whichever input it is for."""
        on_sample = None
        if post is not None:

            def on_sample(sample: zenoh.Sample) -> None:
                if not is_wake(sample):
                    post(self._dispatch_posted, contents(sample))

        super().__init__(session, key, dispatch, capacity, dispatch_message, on_sample)
        self._local: deque[tuple[msgspec.Struct, bytes | None]] = deque(maxlen=capacity)
        self.blocks = post is None

    def _dispatch_posted(self, payload_and_attachment: tuple[bytes, bytes | None]) -> None:
        self._dispatch(*payload_and_attachment)

    def accept_local(self, message: msgspec.Struct, attachment: bytes | None) -> None:
        self._local.append((message, attachment))
        if self.ready is not None:
            self.ready.append(self)

    def take_local(self) -> bool:
        local = self._local
        if local and self._dispatch_message is not None:
            self._dispatch_message(*local.popleft())
            return True
        return False

    def take(self) -> bool:
        """Handle the next waiting message of this process, else sample, if any; True if one was handled."""
        if self.take_local():
            return True
        if not self.blocks:
            return False
        while (sample := self._subscriber.try_recv()) is not None:
            payload, attachment = contents(sample)
            if attachment != _WAKE:
                self._dispatch(payload, attachment)
                return True
        return False


class LatestSample(NodeInput):
    """An input of which only the newest sample counts, decoded when taken: :attr:`Delivery.NEWEST`
    and :attr:`Delivery.SAMPLED`.

    For inputs a service needs only at its own pace (a clock, a pose): the simulator publishes
    them at its step rate, several kHz of wall time in lockstep, and handing every sample to
    Python would cost more than the work, while a service starved of CPU for a moment would then
    work through a backlog of stale samples. Here no Python runs per sample, and a busy service
    always acts on the present. (A bad sample overwritten before it is taken is never seen, so
    never counted.)
    """

    def __init__(
        self, session: zenoh.Session, key: str, dispatch: Dispatch, dispatch_message: DispatchMessage | None = None
    ) -> None:
        super().__init__(session, key, dispatch, NEWEST_CAPACITY, dispatch_message)
        self._received: zenoh.Sample | None = None
        self._local_newest: tuple[msgspec.Struct, bytes | None] | None = None

    def accept_local(self, message: msgspec.Struct, attachment: bytes | None) -> None:
        if self._local_newest is None and self.ready is not None:
            self.ready.append(self)
        self._local_newest = (message, attachment)

    def take_local(self) -> bool:
        local, self._local_newest = self._local_newest, None
        if local is not None and self._dispatch_message is not None:
            self._dispatch_message(*local)
            return True
        return False

    def put_back(self, sample: zenoh.Sample) -> None:
        """Keep ``sample``, which a blocking receive took out of the ring, for the next take: it
        competes there with what came after it, so a newer sample is never followed by an older one."""
        self._received = sample

    def take(self) -> bool:
        """Handle the newest message of this process offered since the last take, else the newest
        sample that arrived, if any; True if one was handled."""
        if self.take_local():
            return True
        newest, self._received = self._received, None
        while (sample := self._subscriber.try_recv()) is not None:
            if not is_wake(sample):
                newest = sample
        if newest is None:
            return False
        self.handle(newest)
        return True
