"""``invent record``: every sample of some keys into an MCAP file (services/recording.py says what
the file holds), with the Foxglove scene of the robot beside them; and the loop shared with
``invent view``, which shows the same channels live.

The samples wait in zenoh FIFO channels (no Python runs in zenoh's threads); the loop takes
them, stamps each with the time it took it (``log_time``), and hands it on. In ``invent up
--composed`` the observer is in the loop's own process and only buffers samples while the loop
runs (a recorder process would make that session encode and send every sample: the loop ran
at half its speed); the samples then carry the router-session's publication timestamps. Every
:data:`STATUS_PERIOD_S` it asks the robot's services for their ``status`` (a read-only query)
and records each reply on its key: the motor's state and the sim's late/missing torque
counters then plot beside the data.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import zenoh

from schemas.codec import BadInput, decode
from schemas.keys import LATCHED_TOPICS, TOPIC_TYPES, Keys, Topic, TopicMessage
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary
from services.config import Config
from services.recording import LATEST_STAMP_NS, McapWriter
from services.runtime.logs import RateLimitedLog
from services.runtime.session import has_match
from services.scene import WHEEL_SPEEDS_SCHEMA, WHEEL_SPEEDS_TOPIC, Scene

log = logging.getLogger("invent.record")

SAMPLE_CAPACITY = 1 << 20
"""Samples a subscription holds until the loop takes them: seconds of the loop (a full channel
would make zenoh wait, and with it the loop's publishers)."""
TAKE_PERIOD_S = 0.02
"""How often a recorder or a live view takes what waits in its subscriptions (zenoh's channels
hold a loop's samples meanwhile). Taking each sample as it came kept the process polling at every
step of the loop, on the loop's CPUs: that cost the loop more than the recording itself."""
STATUS_PERIOD_S = 0.5
RUN_END_TIMEOUT_S = 10.0
"""``--until-run-ends``: how long to wait, after the summary, for the data up to its time."""


@dataclass(frozen=True)
class Sink:
    """Where the loop hands what it takes: each zenoh sample, and each Foxglove message of the scene."""

    sample: Callable[[str, bytes, int, int | None], None]
    """(key, payload, log time ns, the message's stamp in ns if the observer decoded it)"""
    shown: Callable[[str, Any, int, int], None]
    """(topic, Foxglove message or JSON value, stamp ns, log time ns)"""


class Observer:
    """Takes every sample of ``key_exprs`` and every status reply of ``keys.robot``'s services, and
    builds the Foxglove scene from the robot's own keys."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, key_exprs: Sequence[str], config: Config, sink: Sink
    ) -> None:
        self._session = session
        self._keys = keys
        self._sink = sink
        self._scene = Scene(config.robot, config.sim)
        self._horizon_ns = config.input.stamp_horizon_ns
        self._not_shown = RateLimitedLog(log)
        self._topics = {keys.topic(topic): topic for topic in Topic}
        self._subscribers = [
            session.declare_subscriber(expr, zenoh.handlers.FifoChannel(SAMPLE_CAPACITY)) for expr in key_exprs
        ]
        self._status_key = keys.every_status
        self._status_replies: Any = None
        self._next_status = 0.0
        self.latest_ns: dict[str, int] = {}
        """The newest stamp taken on each of the robot's data keys, each at most the stamp horizon
        (``input.stamp_horizon``) past the one before, as the services take them: a forged
        far-future stamp does not end a recording ``--until-run-ends``."""
        self.run_summary: RunSummary | None = None
        self._buffered: list[tuple[zenoh.Sample, int]] = []
        """Samples taken from the subscriptions, each with the time it was taken (Unix ns)."""
        self._latched_queriers = [
            session.declare_querier(keys.topic(topic), timeout=STATUS_PERIOD_S) for topic in LATCHED_TOPICS
        ]
        self._unasked = list(self._latched_queriers)
        self._latched_replies: list[Any] = []

    def _ask_latched(self) -> None:
        """What a latched key's publisher last published (the world, the path), so that a recorder or
        a view started mid-run has them: asked once the publisher's queryable has reached this
        session (a query sent before would reach nothing), and taken unless its key was already."""
        for querier in [querier for querier in self._unasked if has_match(querier)]:
            self._unasked.remove(querier)
            self._latched_replies.append(querier.get())
        for replies in list(self._latched_replies):
            try:
                while (reply := replies.try_recv()) is not None:
                    if reply.ok is not None and str(reply.ok.key_expr) not in self.latest_ns:
                        self._buffered.append((reply.ok, time.time_ns()))
            except zenoh.ZError:  # every reply taken, and the query is over
                self._latched_replies.remove(replies)

    def spin_once(self) -> bool:
        """Take what waits (and what :meth:`buffer` kept); False if nothing did."""
        self.buffer()
        taken = bool(self._buffered)
        for sample, taken_ns in self._buffered:
            self._take(str(sample.key_expr), sample.payload.to_bytes(), _log_time(sample, taken_ns))
        self._buffered.clear()
        return taken

    def buffer(self) -> None:
        """Keep the samples that wait, untouched, for the next :meth:`spin_once`: for a loop in this
        very process (``invent up --composed``), with which this then shares the interpreter as
        little as it can while the loop runs (the status replies, a few every 0.5 s, go through)."""
        now_ns = time.time_ns()
        for subscriber in self._subscribers:
            while (sample := subscriber.try_recv()) is not None:
                self._buffered.append((sample, now_ns))
        self._ask_latched()
        self._poll_status()

    def _poll_status(self) -> None:
        if self._status_replies is not None:
            try:
                while (reply := self._status_replies.try_recv()) is not None:
                    if reply.ok is not None:
                        self._sink.sample(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.time_ns(), None)
            except zenoh.ZError:  # every reply taken, and the query is over
                self._status_replies = None
        now = time.monotonic()
        if now >= self._next_status:
            self._next_status = now + STATUS_PERIOD_S
            self._status_replies = self._session.get(self._status_key, timeout=STATUS_PERIOD_S)

    def _take(self, key: str, payload: bytes, log_time_ns: int) -> None:
        topic = self._topics.get(key)
        message = None if topic is None else _decoded(TOPIC_TYPES[topic], payload)
        stamp_ns = None if message is None else message.tm.to_nanoseconds()
        if topic is None or message is None or stamp_ns is None or stamp_ns > LATEST_STAMP_NS:
            self._sink.sample(key, payload, log_time_ns, None)
            return
        self._sink.sample(key, payload, log_time_ns, stamp_ns)
        latest_ns = self.latest_ns.get(key)
        if latest_ns is None or latest_ns < stamp_ns <= latest_ns + self._horizon_ns:
            self.latest_ns[key] = stamp_ns
        if isinstance(message, RunSummary):
            self.run_summary = message
        try:
            shown_messages = self._scene.add(topic, message)
        except ValueError as error:  # well-formed but wrong (BadInput): recorded as it is, not shown
            self._not_shown(key, logging.WARNING, "not shown in the scene: %s: %s", key, error)
            return
        for shown_topic, shown in shown_messages:
            self._sink.shown(shown_topic, shown, stamp_ns, log_time_ns)

    def reached(self, until_ns: int) -> bool:
        """Whether the ground truth and the odometry taken reach ``until_ns`` of simulation time
        (what the loop published up to then: the two series a report compares)."""
        return all(
            self.latest_ns.get(key, -1) >= until_ns for key in (self._keys.sim_body_pose, self._keys.odometry_pose)
        )

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        for querier in self._latched_queriers:
            querier.undeclare()


def _decoded(message_type: type[TopicMessage], payload: bytes) -> TopicMessage | None:
    try:
        return decode(message_type, payload)
    except BadInput:
        return None


def _log_time(sample: zenoh.Sample, taken_ns: int) -> int:
    """When the sample was published, in Unix ns, if a router stamped it (the session of ``up
    --composed`` is the router: its own samples are stamped as they are published), else when the
    observer took it from its subscription (``taken_ns``)."""
    stamp = sample.timestamp
    if stamp is None:
        return taken_ns
    return stamp.get_time_as_ntp64().as_nanos()


class SceneWriter(Protocol):
    """What a :class:`Sink` writes into, one channel per key or topic: the MCAP file
    (:class:`McapWriter`) or the live view's channels (``services.view.FoxgloveChannels``)."""

    def write_sample(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: int | None) -> None: ...

    def write_json(self, topic: str, value: Any, schema: dict[str, Any], stamp_ns: int, log_time_ns: int) -> None: ...

    def write_foxglove(self, topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None: ...


def writer_sink(writer: SceneWriter) -> Sink:
    """Each sample on its key's channel; the scene's wheel speeds as JSON of
    :data:`WHEEL_SPEEDS_SCHEMA`, its other messages as Foxglove's well-known messages."""

    def shown(topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None:
        if topic == WHEEL_SPEEDS_TOPIC:
            writer.write_json(topic, message, WHEEL_SPEEDS_SCHEMA, stamp_ns, log_time_ns)
        else:
            writer.write_foxglove(topic, message, stamp_ns, log_time_ns)

    return Sink(writer.write_sample, shown)


def run_record(
    session: zenoh.Session,
    keys: Keys,
    key_exprs: Sequence[str],
    output: Path,
    config: Config,
    stop: threading.Event,
    duration_s: float | None = None,
    until_run_ends: bool = False,
) -> int:
    """Record until ``stop``, ``duration_s`` of wall time, or (``until_run_ends``) the run's summary
    and the data up to its time; the file is closed properly in every case."""
    writer = McapWriter(output)
    observer = Observer(session, keys, key_exprs or [keys.everything], config, writer_sink(writer))
    log.info("recording %s into %s", ", ".join(key_exprs or [keys.everything]), output)
    deadline = None if duration_s is None else time.monotonic() + duration_s
    run_end_deadline: float | None = None
    try:
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            observer.spin_once()
            summary = observer.run_summary
            if until_run_ends and summary is not None:
                run_end_deadline = run_end_deadline or time.monotonic() + RUN_END_TIMEOUT_S
                if observer.reached(summary.tm.to_nanoseconds()):
                    break
                if time.monotonic() > run_end_deadline:
                    log.warning(
                        "the data did not reach t = %.3f s within %g s of the run's end; closing the file",
                        summary.tm.to_nanoseconds() / NANOSECONDS_PER_SECOND,
                        RUN_END_TIMEOUT_S,
                    )
                    break
            stop.wait(TAKE_PERIOD_S)
        observer.spin_once()
    finally:
        observer.close()
        writer.close()
    log.info("recorded %d messages into %s", writer.messages, output)
    return 0
