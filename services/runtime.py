"""The service runtime every service stands on.

A :class:`Node` wraps one service's zenoh declarations: a liveliness token, a ``status``
queryable, typed subscriptions, queryables and publishers. Zenoh callbacks only hand their
sample or query to the node's own queue; the service's thread drains it with
:meth:`Node.spin_once`, so decoding, the control core, publishing and replying all happen on
one thread, never inside a zenoh callback (calling zenoh from there can deadlock).

Bad input (SPEC section 8) never kills a service: the node drops it, logs one line naming the
key and the reason (at most one line per key per second), and counts it in ``status``.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import msgspec
import zenoh

from schemas.codec import ENCODING, BadInput, decode, encode
from schemas.keys import Keys, Service

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where services connect and ``invent router`` listens by default (rmw_zenoh's convention)."""

ZENOH_CONFIG_VARIABLE = "ZENOH_CONFIG"
BAD_INPUT_LOG_INTERVAL_S = 1.0
MessageT = TypeVar("MessageT", bound=msgspec.Struct)

log = logging.getLogger("invent")


def session_config(
    *, connect: Iterable[str] = (), listen: Iterable[str] = (), mode: str = "peer"
) -> zenoh.Config:
    """The zenoh configuration of a service or tool.

    Default: ``mode`` (peer), multicast scouting off, connect to :data:`DEFAULT_ENDPOINT`.
    A file named by ``$ZENOH_CONFIG`` replaces the default; ``connect``/``listen`` endpoints
    override either.
    """
    connect, listen = list(connect), list(listen)
    path = os.environ.get(ZENOH_CONFIG_VARIABLE)
    if path:
        config = zenoh.Config.from_file(path)
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
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    return config


@dataclass
class _KeyErrors:
    count: int = 0
    last_reason: str = ""
    last_logged: float = float("-inf")
    suppressed: int = 0


@dataclass
class BadInputCounter:
    """Counts bad input per key and logs at most one line per key per interval."""

    service: str
    interval_s: float = BAD_INPUT_LOG_INTERVAL_S
    by_key: dict[str, _KeyErrors] = field(default_factory=dict)

    def record(self, key: str, reason: str) -> None:
        entry = self.by_key.setdefault(key, _KeyErrors())
        entry.count += 1
        entry.last_reason = reason
        now = time.monotonic()
        if now - entry.last_logged < self.interval_s:
            entry.suppressed += 1
            return
        more = f" ({entry.suppressed} more since the last line)" if entry.suppressed else ""
        log.getChild(self.service).warning("bad input on %s: %s; dropped%s", key, reason, more)
        entry.last_logged, entry.suppressed = now, 0

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


class Publisher:
    """A zenoh publisher of one message type, encoding with the project's codec."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self._publisher = session.declare_publisher(key, encoding=zenoh.Encoding(ENCODING))

    def put(self, message: msgspec.Struct) -> None:
        self._publisher.put(encode(message))

    @property
    def matched(self) -> bool:
        """True once at least one subscriber matches this key."""
        return self._publisher.matching_status.matching

    def undeclare(self) -> None:
        self._publisher.undeclare()


_QueryHandler = Callable[[bytes], Any]

SAMPLING_POLL_S = 0.001
"""How long a sampling service waits for a queued event between two looks at its sampled inputs."""


class LatestSample(Generic[MessageT]):
    """The newest sample of one key, kept by zenoh's ring channel of one and decoded when taken.

    For inputs a service needs only at its own pace (a clock, a pose): the simulator publishes
    them at its step rate, several kHz of wall time in lockstep, and through the node's queue
    every sample would cost a Python callback, while a service starved of CPU for a moment would
    then work through a backlog of stale samples. Here no Python runs per sample, and a busy
    service always acts on the present. (A bad sample overwritten before it is taken is never
    seen, so never counted.)
    """

    def __init__(self, node: Node, key: str, message_type: type[MessageT]) -> None:
        self.key = key
        self._node = node
        self._type = message_type
        self._subscriber = node.session.declare_subscriber(key, zenoh.handlers.RingChannel(1))

    def take(self, handler: Callable[[MessageT], None]) -> bool:
        """Call ``handler`` with the sample that arrived since the last take, if any; True if one did.

        An undecodable sample, or one the handler refuses with BadInput, is dropped and counted
        in the node's bad-input counters like any other bad input.
        """
        sample = self._subscriber.try_recv()
        if sample is None:
            return False
        self._node._guard(self.key, lambda payload: handler(decode(self._type, payload)), sample.payload.to_bytes())
        return True

    def undeclare(self) -> None:
        self._subscriber.undeclare()


class Executor:
    """The event queue of one service thread: zenoh callbacks post, the thread handles.

    A node gets an executor of its own; services composed in one process may share one, so a
    single thread handles all their events in arrival order, with no thread switch between
    them (as a ROS 2 single-threaded executor does).
    """

    def __init__(self) -> None:
        self._events: queue.SimpleQueue[tuple[Callable[[Any], None], Any]] = queue.SimpleQueue()

    def post(self, handle: Callable[[Any], None], item: Any) -> None:
        """Queue ``handle(item)``; thread-safe, and cheap enough for a zenoh callback."""
        self._events.put((handle, item))

    def spin_once(self, timeout: float | None) -> bool:
        """Handle one queued event, waiting up to ``timeout`` seconds; False if none came."""
        try:
            handle, item = self._events.get(timeout=timeout) if timeout != 0 else self._events.get_nowait()
        except queue.Empty:
            return False
        handle(item)
        return True


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
        self._status = status
        self.executor = executor or Executor()
        self._declarations: list[Any] = []
        self._publishers: list[Publisher] = []
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
            "bad_input": self.bad_inputs.as_dict(),
            "internal_errors": self.internal_errors,
        }

    def subscribe(self, key: str, message_type: type[MessageT], handler: Callable[[MessageT], None]) -> None:
        """Call ``handler(message)`` on the service thread for every sample of ``key`` that decodes."""

        def on_payload(payload: bytes) -> None:
            handler(decode(message_type, payload))

        self.subscribe_raw(key, on_payload)

    def subscribe_raw(self, key: str, handler: Callable[[bytes], None]) -> None:
        """Call ``handler(payload)`` on the service thread; it may raise BadInput."""

        def dispatch(payload: bytes) -> None:
            self._guard(key, handler, payload)

        post = self.executor.post
        self._declarations.append(
            self.session.declare_subscriber(key, lambda sample: post(dispatch, sample.payload.to_bytes()))
        )

    def queryable(self, key: str, handler: _QueryHandler) -> None:
        """Answer queries on ``key`` from the service thread.

        ``handler(payload)`` returns a JSON-encodable reply, or raises BadInput, which
        becomes a ``reply_err`` naming the reason. The query is finalized right after the
        reply, so the caller's ``get`` returns at once.
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
                except Exception as error:  # a bug must not kill the service; it is logged and counted
                    self._internal_error(key, error)
                    query.reply_err(json.dumps({"error": f"internal error: {error}"}), encoding=zenoh.Encoding(ENCODING))
                    return
                query.reply(key, msgspec.json.encode(reply), encoding=zenoh.Encoding(ENCODING))
            finally:
                query.drop()

        post = self.executor.post
        self._declarations.append(self.session.declare_queryable(key, lambda query: post(answer, query)))

    def latest(self, key: str, message_type: type[MessageT]) -> LatestSample[MessageT]:
        """Sample ``key`` at the service's own pace instead of handling every sample (see LatestSample)."""
        sampled = LatestSample(self, key, message_type)
        self._declarations.append(sampled)
        return sampled

    def publisher(self, key: str) -> Publisher:
        publisher = Publisher(self.session, key)
        self._publishers.append(publisher)
        return publisher

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

    def spin_once(self, timeout: float | None) -> bool:
        """Handle one queued event, waiting up to ``timeout`` seconds; False if none came."""
        return self.executor.spin_once(timeout)

    def spin(self, stop: threading.Event, poll_s: float = 0.1) -> None:
        """Handle events until ``stop`` is set."""
        while not stop.is_set():
            self.spin_once(poll_s)

    def drain(self) -> None:
        """Handle every event already queued, without waiting."""
        while self.spin_once(0):
            pass

    def _guard(self, key: str, handler: Callable[[bytes], None], payload: bytes) -> None:
        try:
            handler(payload)
        except BadInput as error:
            self.bad_inputs.record(key, str(error))
        except Exception as error:  # a bug must not kill the service; it is logged and counted
            self._internal_error(key, error)

    def _internal_error(self, key: str, error: Exception) -> None:
        self.internal_errors += 1
        self.log.exception("internal error handling %s: %s", key, error)

    def close(self) -> None:
        """Withdraw the liveliness token and undeclare everything (the session stays open)."""
        for declaration in reversed(self._declarations):
            declaration.undeclare()
        for publisher in self._publishers:
            publisher.undeclare()
        self._declarations.clear()
        self._publishers.clear()


@contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    session = zenoh.open(config)
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
