"""A service's presence on zenoh (:class:`Node`), and the life of a reactive service (:meth:`Node.serve`).

A node declares a service's liveliness token, its ``status`` queryable, its inputs (each with its
:class:`~services.runtime.inputs.Delivery`), queryables and publishers, all handled on its
executor's thread. A reactive service (motor, odometry, localization, drive) only declares: the
runtime runs it (:meth:`Node.serve`, or the thread of a composition). Only a service that owns a
clock (the simulator) has a loop of its own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, TypeVar

import msgspec
import zenoh

from schemas.codec import BadInput, decode
from schemas.interface import Interface
from schemas.keys import Keys, Service, ServiceName
from schemas.status import InputTaken, ServiceStatus
from services.runtime.declared import DeclaredKeys
from services.runtime.executor import STOP_POLL_S, Executor
from services.runtime.inputs import (
    ChannelInput,
    Delivery,
    Dispatch,
    DispatchMessage,
    LatchedPublisher,
    LatestSample,
    NodeInput,
    Publisher,
    contents,
)
from services.runtime.intraprocess import LocalBus, LocalSink
from services.runtime.journal import Journal
from services.runtime.logs import BadInputCounter, RateLimitedLog, log
from services.runtime.memory import status as memory_status
from services.runtime.queries import answer
from services.runtime.realtime import status as realtime_status

LIVELINESS_QUERY_TIMEOUT_S = 1.0
"""Upper bound on a start-up liveliness query (the router answers at once)."""
MessageT = TypeVar("MessageT", bound=msgspec.Struct)
ContentT = TypeVar("ContentT")
"""A sample's payload (bytes), or a message a publisher of this process offered as it is."""


@dataclass(frozen=True)
class Wait:
    """What a reactive service's thread waits for next (see :meth:`Node.serve`)."""

    input: NodeInput | None = None
    """The input whose sample the service needs next (None: its waking input)."""
    until: float | None = None
    """A time (``time.monotonic()``) at which the service has something to settle, if any."""


class Node:
    """One service's presence on zenoh. See the module docstring. ``status`` builds the ``status`` reply
    (schemas/status.py) on the service thread; the node fills in the service and robot names and the counters."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        service: ServiceName,
        status: Callable[[], ServiceStatus] = ServiceStatus,
        executor: Executor | None = None,
        journal: Journal | None = None,
        bus: LocalBus | None = None,
        congestion: zenoh.CongestionControl = zenoh.CongestionControl.DROP,
        interface: Interface | None = None,
    ) -> None:
        """``interface``: the service's declaration; a key of ``invent/`` it does not hold is refused."""
        self.session = session
        self.declared = DeclaredKeys(interface, keys)
        self.bus = bus
        """The process's intra-process delivery, when its services are composed (services/runtime/intraprocess.py)."""
        self.congestion = congestion  # its publishers': BLOCK in lockstep (inputs.LOCKSTEP_CONGESTION)
        self.keys = keys
        self.service = service
        self.log = log.getChild(str(service))
        self.bad_inputs = BadInputCounter(str(service))
        self.internal_errors = 0
        self.participating = False
        """Whether it holds a lockstep participant's token (:meth:`participate`)."""
        self._internal_error_log = RateLimitedLog(self.log)
        self._status = status
        self._own_status: Callable[[], dict[str, Any]] | None = None
        self.executor = executor or Executor()
        self._declarations: list[Any] = []
        self._inputs: list[NodeInput] = []
        self._local_sinks: list[tuple[str, LocalSink]] = []
        self._publishers: list[Publisher] = []
        self._journal = journal
        # Attributes, not properties: the control path asks at every step, and the journal is the node's for life.
        self.recording = journal is not None
        """Whether the node keeps a journal of what it publishes (``invent up``'s recording)."""
        self.recording_every_step = journal is not None and journal.every_step
        """Whether the run is recorded at every simulation step (``record.rate = "every_step"``):
        the observed outputs are then computed and kept at every step, and the control path's
        samples of every step kept too; else only the observed steps' are."""
        self._taken: dict[str, InputTaken] = {}
        self._started = time.monotonic()
        self._next_wait: Callable[[], Wait] = Wait
        self.queryable(keys.status(service), lambda _payload: self._status_reply())
        self._declarations.append(session.liveliness().declare_token(keys.alive(service)))

    @property
    def journal(self) -> Journal | None:
        """The journal of what the node publishes, if it keeps one: another node of the same
        process (the fleet simulator's, one per robot) may write to it too."""
        return self._journal

    def set_status(self, status: Callable[[], ServiceStatus], own: Callable[[], dict[str, Any]] | None = None) -> None:
        """``own``: a user service's own fields, free-form, merged over the typed reply's on the wire."""
        self._status, self._own_status = status, own

    def status(self) -> ServiceStatus:
        return msgspec.structs.replace(
            self._status(),
            service=str(self.service),
            robot=self.keys.robot,
            uptime_s=round(time.monotonic() - self._started, 3),
            inputs=dict(self._taken),
            bad_input=self.bad_inputs.status(),
            internal_errors=self.internal_errors,
            dropped_events=self.executor.dropped_events,
            congestion="block" if self.congestion == zenoh.CongestionControl.BLOCK else "drop",
            rt=realtime_status(),
            memory=memory_status(),
        )

    def _status_reply(self) -> ServiceStatus | dict[str, Any]:
        status = self.status()
        return status if self._own_status is None else {**msgspec.to_builtins(status), **self._own_status()}

    def subscribe(
        self,
        key: str,
        message_type: type[MessageT],
        handler: Callable[..., None],
        delivery: Delivery,
        *,
        wakes: bool = False,
        with_attachment: bool = False,
    ) -> NodeInput | None:
        """Call ``handler(message)`` on the service thread for the samples of ``key`` that
        ``delivery`` hands over and that decode (``handler(message, attachment)``
        ``with_attachment``: the sample's attachment bytes or None). The handler may raise
        BadInput. ``wakes``: the thread, idle, waits in this input's receive (an ``EVERY`` input
        that paces the service). Returns the input, for ``waiting_for`` (None for ``QUEUED``)."""

        def handle_without_attachment(message: msgspec.Struct, _attachment: bytes | None) -> None:
            handler(message)

        # A handler that takes the attachment is called as it is: one call less on the control path.
        handle_message = handler if with_attachment else handle_without_attachment

        def handle(payload: bytes, attachment: bytes | None) -> None:
            handle_message(decode(message_type, payload), attachment)

        dispatch_message = self._dispatch(key, handle_message, delivery) if self.bus is not None else None
        return self._subscribe(key, self._dispatch(key, handle, delivery), delivery, wakes, dispatch_message)

    def subscribe_bytes(
        self, key: str, handler: Callable[[bytes, bytes | None], None], delivery: Delivery, *, wakes: bool = False
    ) -> NodeInput | None:
        """:meth:`subscribe` for payloads that are not the project's JSON (ROS 2's CDR):
        ``handler(payload, attachment)`` decodes them itself, raising BadInput for bad ones."""
        return self._subscribe(key, self._dispatch(key, handler, delivery), delivery, wakes)

    def _subscribe(
        self,
        key: str,
        dispatch: Dispatch,
        delivery: Delivery,
        wakes: bool,
        dispatch_message: DispatchMessage | None = None,
    ) -> NodeInput | None:
        """``dispatch_message``: for the messages of this process's publishers (with a bus)."""
        self.declared.subscribe(key)
        if delivery is Delivery.QUEUED:
            post = self.executor.post
            if dispatch_message is not None:
                # posted, in arrival order with the queries and events, as a sample from zenoh is
                self._attach(
                    key, lambda message, attachment: post(lambda item: dispatch_message(*item), (message, attachment))
                )

            def dispatch_contents(payload_and_attachment: tuple[bytes, bytes | None]) -> None:
                dispatch(*payload_and_attachment)

            # The bytes are copied out here, in zenoh's thread: a queued zenoh sample would keep the
            # whole receive batch it arrived in (about 50 kB, even for a 100-byte torque) until the
            # service thread took it, and a sim that fell 200 samples behind held 10 MB that the
            # allocator kept once freed (the sim's memory growing in the soak, benchmarks/README.md).
            self._declarations.append(
                self.session.declare_subscriber(key, lambda s: post(dispatch_contents, contents(s)))
            )
            return None
        node_input: NodeInput
        if delivery is Delivery.EVERY:
            post_remote = self.executor.post if self.bus is not None else None
            node_input = ChannelInput(self.session, key, dispatch, dispatch_message=dispatch_message, post=post_remote)
            self.executor.add_input(node_input, wakes)
        else:
            node_input = LatestSample(self.session, key, dispatch, dispatch_message)
            if delivery is Delivery.SAMPLED:
                self.executor.add_sampled(node_input)
            else:
                self.executor.add_input(node_input, wakes)
        self._inputs.append(node_input)
        if dispatch_message is not None:
            self._attach(key, node_input.accept_local)
        return node_input

    def _attach(self, key: str, accept: Callable[[msgspec.Struct, bytes | None], None]) -> None:
        """Take the messages this process's publishers put on ``key`` as they are (with a bus):
        ``accept`` runs on the executor's thread."""
        assert self.bus is not None
        sink = LocalSink(self.executor, accept)
        self.bus.attach(key, sink)
        self._local_sinks.append((key, sink))

    def subscribe_latched(self, key: str, message_type: type[MessageT], handler: Callable[[MessageT], None]) -> None:
        """Every sample of a latched key (:meth:`latched_publisher`), as :attr:`Delivery.QUEUED`
        hands them, and first the last message its publisher put before this node subscribed: it is
        asked once the publisher's queryable is reachable, and handed over unless a sample came
        first (a sample is never older than the reply)."""
        sampled = False

        def on_sample(message: MessageT) -> None:
            nonlocal sampled
            sampled = True
            handler(message)

        def on_reply(payload: bytes, _attachment: bytes | None) -> None:
            if not sampled:
                on_sample(decode(message_type, payload))

        self.subscribe(key, message_type, on_sample, Delivery.QUEUED)
        dispatch_reply = self._dispatch(key, on_reply, Delivery.QUEUED, count=False)
        querier = self.querier(key)
        post = self.executor.post
        asked = False

        def take_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                post(lambda payload: dispatch_reply(payload, None), reply.ok.payload.to_bytes())

        def ask(matching: bool) -> None:
            nonlocal asked
            if matching and not asked:
                asked = True
                querier.get(take_reply)

        self._declarations.append(querier)
        self._declarations.append(querier.declare_matching_listener(lambda status: post(ask, status.matching)))

    def queryable(self, key: str, handler: Callable[[bytes], Any], *, mutates: bool = False) -> None:
        """Answer queries on ``key`` from the service thread.

        ``handler(payload)`` returns a JSON-encodable reply (None: no reply), or raises BadInput,
        which becomes a ``reply_err`` naming the reason (services/runtime/queries.py).

        Looking never acts: a wildcard or prefix query (``invent/rh0/**``, what zenoh tools and
        the REST plugin send to look around) reaches every queryable its key expression
        intersects. A handler that ``mutates`` state therefore runs only for a query on exactly
        ``key``; any other query is dropped in zenoh's callback, which finalizes it with no reply.
        Read-only handlers (``status``) answer wildcards.
        """

        self.declared.serve(key)
        answer_query = partial(
            answer, key=key, handler=handler, bad_inputs=self.bad_inputs, internal_error=self._internal_error
        )
        post = self.executor.post

        def on_query(query: zenoh.Query) -> None:
            if not mutates or str(query.key_expr) == key:
                post(answer_query, query)

        self._declarations.append(self.session.declare_queryable(key, on_query))

    def _dispatch(
        self, key: str, handle: Callable[[ContentT, bytes | None], None], delivery: Delivery, *, count: bool = True
    ) -> Callable[[ContentT, bytes | None], None]:
        """Count (``inputs`` in the status, unless not ``count``) and handle (decode included) a
        sample of ``key`` (or a message of this process's publishers); bad input and bugs are
        counted, never raised (:meth:`guard`)."""
        taken = self._taken.setdefault(key, InputTaken(delivery.every_sample)) if count else None
        failed = self._failed

        def dispatch(content: ContentT, attachment: bytes | None) -> None:
            if taken is not None:
                taken.samples += 1
            try:
                handle(content, attachment)
            except Exception as error:  # noqa: BLE001 (bad input and bugs alike must not kill the service)
                failed(key, error)

        return dispatch

    def publisher(self, key: str) -> Publisher:
        self.declared.publish(key)
        publisher = Publisher(self.session, key, self._journal, self.bus, self.congestion)
        self._publishers.append(publisher)
        return publisher

    def latched_publisher(self, key: str) -> LatchedPublisher:
        """A publisher whose last message also answers queries on its key, for what changes
        rarely and a late subscriber needs at once (the sim's world, the drive's path): a viewer
        started mid-run gets it with a ``get``, as from a zenoh storage."""
        latched = LatchedPublisher(self.publisher(key))
        self.queryable(key, lambda _payload: latched.last)
        return latched

    def querier(self, key: str, timeout: float | None = None) -> zenoh.Querier:
        """A querier of another service's queryable ``key`` (declared in its interface's ``queries``)."""
        self.declared.query(key)
        return (
            self.session.declare_querier(key) if timeout is None else self.session.declare_querier(key, timeout=timeout)
        )

    def post(self, callback: Callable[[], None]) -> None:
        """Run ``callback()`` on the service thread (thread-safe; usable from zenoh callbacks)."""
        self.executor.post(lambda _: callback(), None)

    def watch(self, service: ServiceName, on_change: Callable[[bool], None]) -> None:
        """Call ``on_change(alive)`` on the service thread whenever ``service``'s liveliness token
        appears (True; also for one already there) or goes (False): a neighbour that dies and
        comes back is then picked up again."""
        post = self.executor.post
        self._declarations.append(
            self.session.liveliness().declare_subscriber(
                self.keys.alive(service),
                lambda sample: post(on_change, sample.kind == zenoh.SampleKind.PUT),
                history=True,
            )
        )

    def participate(self, publisher: Publisher, rate_hz: float, output: str | None = None) -> None:
        """Take part in lockstep (services/clock/lockstep.py), outputting on ``publisher`` at ``rate_hz``
        ticks per second of simulation time: hold the token ``Keys.ticks`` once ``publisher`` has a
        subscriber (before, the outputs would reach no one, and waiting for them would only time out).
        A user service names its ``output`` (a key under its name) in the token, held at once: the
        simulator subscribes that output when it sees the token (``Keys.ticks_with_output``)."""
        if output is not None:
            if isinstance(self.service, Service):
                raise ValueError(f"{self.service}: a built-in participant's output is fixed (OUTPUTS)")
            token = self.keys.ticks_with_output(self.service, rate_hz, output)
            self._declarations.append(self.session.liveliness().declare_token(token))
            self.participating = True
            return
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

    def observe(self, rate_hz: float) -> None:
        """Take what the loop observes (``sim/clock``, the poses) at ``rate_hz`` per second of
        simulation time: hold the token ``Keys.observes``, so the simulator marks the steps of that
        grid observed (services/clock/observation.py). Nothing waits for this service."""
        self._declarations.append(self.session.liveliness().declare_token(self.keys.observes(self.service, rate_hz)))

    def alive_now(self, service: ServiceName, timeout: float = LIVELINESS_QUERY_TIMEOUT_S) -> bool:
        """Whether ``service``'s liveliness token exists now: one query, answered by the router
        or peers at once (for a decision at start-up, before any watch has reported)."""
        replies = self.session.liveliness().get(self.keys.alive(service), timeout=timeout)
        return any(reply.ok is not None for reply in replies)

    def spin_once(self, timeout: float | None, waiting_for: NodeInput | None = None) -> bool:
        """Handle one queued event, waiting up to ``timeout`` seconds; False if none came (see
        :meth:`Executor.spin_once` for ``waiting_for``)."""
        return self.executor.spin_once(timeout, waiting_for)

    def wait_with(self, next_wait: Callable[[], Wait]) -> None:
        """Say what the thread waits for next when it runs this reactive service (:meth:`serve`):
        ``next_wait()`` runs on the service thread between events, and may first settle what has
        come due (the drive's lockstep tick whose pose wait is over). Default: the waking input."""
        self._next_wait = next_wait

    def serve(self, stop: threading.Event, finished: Callable[[], bool]) -> None:
        """Run a reactive service: handle its events and inputs until ``stop`` is set or ``finished()``."""
        while not stop.is_set():
            wait = self._next_wait()
            if finished():
                return
            timeout = STOP_POLL_S if wait.until is None else max(0.0, min(STOP_POLL_S, wait.until - time.monotonic()))
            self.spin_once(timeout, wait.input)

    def drain(self) -> None:
        """Handle every event already queued, without waiting."""
        while self.spin_once(0):
            pass

    def guard(self, key: str, action: Callable[..., None], *args: Any) -> None:
        """Run ``action(*args)`` (handling an input of ``key``) so that bad input is counted and a
        bug logged and counted, never raised: the service lives on."""
        try:
            action(*args)
        except Exception as error:  # noqa: BLE001 (bad input and bugs alike must not kill the service)
            self._failed(key, error)

    def _failed(self, key: str, error: Exception) -> None:
        if isinstance(error, BadInput):
            self.bad_inputs.record(key, str(error))
        else:
            self._internal_error(key, error)

    def _internal_error(self, key: str, error: Exception) -> None:
        self.internal_errors += 1
        self._internal_error_log(key, logging.ERROR, "internal error handling %s: %s", key, error, exc_info=True)

    def close(self) -> None:
        """Withdraw the liveliness token and undeclare everything (the session stays open); the
        journal of what it published, if it keeps one, is then complete."""
        for key, sink in self._local_sinks:
            assert self.bus is not None
            self.bus.detach(key, sink)
        self._local_sinks.clear()
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
        if self._journal is not None:
            self._journal.close()
