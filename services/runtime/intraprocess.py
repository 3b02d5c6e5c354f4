"""Intra-process delivery: services composed in one process hand each other their messages directly.

As rclcpp's intra-process communication does between the nodes of one process: a message published
on a key that a node of the same process takes goes straight to that node's input, as the message
object itself (no encoding, no decoding, no zenoh); zenoh carries it only when something outside
the process subscribes (its publisher is declared for remote subscribers only, and puts only while
one matches). Messages are frozen msgspec structs, so sharing one among consumers is safe.

A :class:`LocalBus` is the process's table of those inputs, by key; a composition makes one and
gives it to every node on its shared executor (services/launch/composition.py). A node's input
registers a :class:`LocalSink` on its key; a :class:`~services.runtime.inputs.Publisher` of the
bus offers each message to the sinks of its key, in the order they registered. What watches a key
in the process without being a node (``up``'s outcomes, the calibration's paths) is a
:class:`Watch`: a subscriber of the process's own session would not see these messages, which
zenoh carries only out of it, so it also registers a :class:`Tap` on the bus.

Offered on the executor's own thread (every composed service runs there), a message waits in the
input until the thread takes it, as a sample in a ring channel would; offered from another thread,
it is posted to the executor, which wakes the thread (:meth:`LocalSink.offer`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar

import msgspec
import zenoh

from schemas.codec import BadInput, decode

Offer = Callable[[msgspec.Struct, "bytes | None"], None]
"""Hands one message and its attachment to an input."""


class Spinner(Protocol):
    """The executor an input is taken on (services/runtime/executor.py)."""

    spinning_thread: int | None
    """The thread that last began to handle its events and inputs (``threading.get_ident()``)."""

    def post(self, handle: Callable[[Any], None], item: Any) -> None: ...


class LocalSink:
    """One input's end of the bus: ``accept(message, attachment)`` keeps the message where the
    input's take finds it, on the executor's thread."""

    def __init__(self, executor: Spinner, accept: Offer) -> None:
        self._executor = executor
        self._accept = accept

    def offer(self, message: msgspec.Struct, attachment: bytes | None) -> None:
        if self._executor.spinning_thread == threading.get_ident():
            self._accept(message, attachment)
        else:
            self._executor.post(self._accept_posted, (message, attachment))

    def _accept_posted(self, item: tuple[msgspec.Struct, bytes | None]) -> None:
        self._accept(*item)


class Tap:
    """A sink that hands each message to ``handler(message)`` at once, on the publishing thread:
    for what watches a key in this process without being a service (``up``'s outcomes, a tool's
    paths). ``handler`` must be quick and must not call zenoh."""

    def __init__(self, handler: Callable[[msgspec.Struct], None]) -> None:
        self._handler = handler

    def offer(self, message: msgspec.Struct, attachment: bytes | None) -> None:
        self._handler(message)


class LocalBus:
    """The inputs of one process's nodes, by key: what its publishers hand messages to directly."""

    def __init__(self) -> None:
        self._sinks: dict[str, list[LocalSink | Tap]] = {}
        self._watchers: dict[str, list[Callable[[bool], None]]] = {}

    def sinks(self, key: str) -> list[LocalSink | Tap]:
        """The sinks of ``key``: the list itself, which later subscriptions join (a publisher keeps it)."""
        return self._sinks.setdefault(key, [])

    def attach(self, key: str, sink: LocalSink | Tap) -> None:
        sinks = self.sinks(key)
        sinks.append(sink)
        if len(sinks) == 1:
            self._tell(key, True)

    def detach(self, key: str, sink: LocalSink | Tap) -> None:
        sinks = self.sinks(key)
        if sink in sinks:
            sinks.remove(sink)
            if not sinks:
                self._tell(key, False)

    def watch(self, key: str, on_change: Callable[[bool], None]) -> None:
        """Call ``on_change(True)`` when ``key`` gets its first local input (at once if it has one),
        ``on_change(False)`` when it loses its last: a publisher's matching, within the process."""
        self._watchers.setdefault(key, []).append(on_change)
        if self._sinks.get(key):
            on_change(True)

    def unwatch(self, key: str, on_change: Callable[[bool], None]) -> None:
        watchers = self._watchers.get(key, [])
        if on_change in watchers:
            watchers.remove(on_change)

    def _tell(self, key: str, matched: bool) -> None:
        for on_change in list(self._watchers.get(key, ())):
            on_change(matched)


Message = TypeVar("Message", bound=msgspec.Struct)


class Watch(Generic[Message]):
    """``handler(message)`` for each ``message_type`` published on ``key``: from zenoh (decoded; what
    does not decode is not the publisher's and is skipped) and, with a ``bus``, from the services
    composed in this process (tapped). ``handler`` runs in a zenoh callback or on the publishing
    thread: it must be quick and must not call zenoh."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        message_type: type[Message],
        handler: Callable[[Message], None],
        bus: LocalBus | None = None,
    ) -> None:
        self._type, self._handler = message_type, handler
        self._key, self._bus = key, bus
        self._subscriber = session.declare_subscriber(key, self._on_sample)
        self._tap = Tap(self._on_message)
        if bus is not None:
            bus.attach(key, self._tap)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            message = decode(self._type, sample.payload.to_bytes())
        except BadInput:
            return
        self._handler(message)

    def _on_message(self, message: msgspec.Struct) -> None:
        if isinstance(message, self._type):
            self._handler(message)

    def close(self) -> None:
        self._subscriber.undeclare()
        if self._bus is not None:
            self._bus.detach(self._key, self._tap)
