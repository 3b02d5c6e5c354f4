"""``invent record``: every sample of some keys into an MCAP file (services/recording/mcap_files.py says what
the file holds), with the Foxglove scene of the robot beside them; the loop shared with ``invent
view``, which shows the same channels live; and ``invent up``'s ``run.mcap``, the same file made
of what its services published.

The samples wait in zenoh FIFO channels (no Python runs in zenoh's threads); the loop takes
them, stamps each with the time it took it (``log_time``; with the time it passed the router, if
the router stamped it), and hands it on. Every :data:`STATUS_PERIOD_S` it asks the robot's
services for their ``status`` (a read-only query) and records each reply on its key: the motor's
state and the sim's late/missing torque counters then plot beside the data.

``invent up`` records its run without a recorder process: each of its services keeps what it
publishes in a journal (services/runtime/journal.py) and ``up`` its status replies and summary in
its own; at the end :func:`write_run_recording` makes ``run.mcap`` of them, with the same scene,
``log_time`` then the time of publication. A recorder in another process would cost the loop
zenoh's delivery of every sample to it (benchmarks/README.md, "What recording costs"); a run's
recording holds what the run's own processes published, and ``invent record`` whatever anyone
publishes.
"""

from __future__ import annotations

import heapq
import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import zenoh

from schemas.codec import BadInput, decode
from schemas.keys import Keys
from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.topics import LATCHED_TOPICS, TOPIC_TYPES, Topic
from services import interfaces
from services.config import Config, RecordConfig
from services.recording.mcap_files import (
    LATEST_STAMP_NS,
    MB,
    RECORDING_ROTATED_SCHEMA,
    RECORDING_ROTATED_TOPIC,
    RECORDING_STOPPED_SCHEMA,
    RECORDING_STOPPED_TOPIC,
    McapWriter,
    SplitWriter,
)
from services.recording.scene import WHEEL_SPEEDS_SCHEMA, WHEEL_SPEEDS_TOPIC, Scene
from services.runtime.journal import ALWAYS_KEPT, DROPPED_KEY, STOPPED_KEY, JournalEntry, JournalReader
from services.runtime.journal import SUFFIX as JOURNAL_SUFFIX
from services.runtime.logs import BadInputCounter, RateLimitedLog
from services.runtime.session import has_match

log = logging.getLogger("invent.record")

SAMPLE_CAPACITY = 1 << 20
"""Samples a subscription holds until the loop takes them: seconds of the loop (a full channel
would make zenoh wait, and with it the loop's publishers)."""
TAKE_PERIOD_S = 0.02
"""How often a recorder or a live view takes what waits in its subscriptions (zenoh's channels
hold a loop's samples meanwhile). Taking each sample as it came kept the process polling at every
step of the loop, on the loop's CPUs: that cost the loop more than the recording itself."""
TAKE_BUDGET_S = 0.1
"""Most wall time one :meth:`Observer.spin_once` spends taking samples: a loop that publishes faster
than a recorder or view takes would otherwise keep it taking for ever, deaf to its stop."""
FINAL_TAKE_BUDGET_S = 2.0
"""What a stopping recorder may spend taking the samples that wait (those that came before its stop)."""
STATUS_PERIOD_S = 0.5


@dataclass(frozen=True)
class Sink:
    """Where the loop hands what it takes: each zenoh sample, and each Foxglove message of the scene."""

    sample: Callable[[str, bytes, int, int | None], None]
    """(key, payload, log time ns, the message's stamp in ns if the builder decoded it)"""
    shown: Callable[[str, Any, int, int], None]
    """(topic, Foxglove message or JSON value, stamp ns, log time ns)"""


class SceneBuilder:
    """Hands each sample on to a sink, and the Foxglove scene it builds from the robot's own keys
    (no zenoh here: the samples come from an :class:`Observer`, or from journals).

    A sample of the project's key space that does not decode as its key's type, or that the scene
    refuses (well-formed but wrong: :class:`~schemas.codec.BadInput`), is bad input: a recorder
    keeps it on its key as it was published (a recording is the evidence of what was) and shows
    nothing of it; given ``bad_input`` (the live view), it is dropped altogether and counted there."""

    def __init__(
        self, config: Config, sink: Sink, fleet: Sequence[Config] = (), bad_input: BadInputCounter | None = None
    ) -> None:
        """The scene of ``config``'s robot, or of every robot of ``fleet`` (each robot's description)."""
        self._sink = sink
        robots = tuple(fleet) or (config,)
        self._scenes = {
            robot.robot.name: Scene(
                robot.robot, robot.sim, fleet=bool(fleet), geometry=robot.geometry, lidar=robot.lidar
            )
            for robot in robots
        }
        self._not_shown = RateLimitedLog(log)
        self._bad_input = bad_input
        self._topics = {
            Keys(robot.robot.name).topic(topic): (topic, self._scenes[robot.robot.name])
            for robot in robots
            for topic in Topic
        }
        self.keys_taken: set[str] = set()

    def take(self, key: str, payload: bytes, log_time_ns: int) -> None:
        self.keys_taken.add(key)
        topic, scene = self._topics.get(key, (None, None))
        if topic is None or scene is None:
            self._sink.sample(key, payload, log_time_ns, None)
            return
        try:
            message = decode(TOPIC_TYPES[topic], payload)
        except BadInput as error:
            self._refused(key, payload, log_time_ns, None, error)
            return
        stamp_ns = message.tm.to_nanoseconds()
        if stamp_ns > LATEST_STAMP_NS:
            self._sink.sample(key, payload, log_time_ns, None)
            return
        try:
            shown_messages = scene.add(topic, message)
        except ValueError as error:  # well-formed but wrong (BadInput)
            self._refused(key, payload, log_time_ns, stamp_ns, error)
            return
        self._sink.sample(key, payload, log_time_ns, stamp_ns)
        for shown_topic, shown in shown_messages:
            self._sink.shown(shown_topic, shown, stamp_ns, log_time_ns)

    def _refused(self, key: str, payload: bytes, log_time_ns: int, stamp_ns: int | None, error: ValueError) -> None:
        if self._bad_input is not None:
            self._bad_input.record(key, str(error))
            return
        self._sink.sample(key, payload, log_time_ns, stamp_ns)
        self._not_shown(key, logging.WARNING, "not shown in the scene: %s: %s", key, error)


class StatusPoll:
    """Asks every service of the robot for its ``status`` (a read-only query) every
    :data:`STATUS_PERIOD_S`, and hands each reply to ``record(key, payload, time taken in Unix ns)``."""

    def __init__(self, session: zenoh.Session, keys: Keys, record: Callable[[str, bytes, int], None]) -> None:
        self._session = session
        self._key = keys.every_status
        self._record = record
        self._replies: Any = None
        self._next = 0.0

    def poll(self) -> None:
        """Take the replies that have come, and ask again when it is time (never waits)."""
        if self._replies is not None:
            try:
                while (reply := self._replies.try_recv()) is not None:
                    if reply.ok is not None:
                        self._record(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.time_ns())
            except zenoh.ZError:  # every reply taken, and the query is over
                self._replies = None
        now = time.monotonic()
        if now >= self._next:
            self._next = now + STATUS_PERIOD_S
            self._replies = self._session.get(self._key, timeout=STATUS_PERIOD_S)

    def last(self) -> None:
        """Ask once more and take every reply (at most :data:`STATUS_PERIOD_S`): the services' status at
        the end of the run, which a run shorter than a period would otherwise not hold at all."""
        for reply in self._session.get(self._key, timeout=STATUS_PERIOD_S):
            if reply.ok is not None:
                self._record(str(reply.ok.key_expr), reply.ok.payload.to_bytes(), time.time_ns())


class Observer:
    """Takes every sample of ``key_exprs`` and every status reply of ``keys.robot``'s services into
    a :class:`SceneBuilder`."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        key_exprs: Sequence[str],
        config: Config,
        sink: Sink,
        fleet: Sequence[Config] = (),
        bad_input: BadInputCounter | None = None,
    ) -> None:
        """``fleet``: the scene of each of these robots (their descriptions), not only ``keys.robot``'s;
        ``bad_input``: where bad input is counted, dropped (:class:`SceneBuilder`)."""
        self._builder = SceneBuilder(config, sink, fleet, bad_input)
        self._subscribers = [
            session.declare_subscriber(expr, zenoh.handlers.FifoChannel(SAMPLE_CAPACITY)) for expr in key_exprs
        ]
        self._status = StatusPoll(session, keys, lambda key, payload, now_ns: sink.sample(key, payload, now_ns, None))
        robots = [Keys(robot.robot.name) for robot in fleet] or [keys]
        self._latched_queriers = [
            session.declare_querier(robot.topic(topic), timeout=STATUS_PERIOD_S)
            for robot in robots
            for topic in LATCHED_TOPICS
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
                    key = str(reply.ok.key_expr) if reply.ok is not None else None
                    if key is not None and key not in self._builder.keys_taken:
                        self._builder.take(key, reply.ok.payload.to_bytes(), time.time_ns())
            except zenoh.ZError:  # every reply taken, and the query is over
                self._latched_replies.remove(replies)

    def spin_once(self, budget_s: float = TAKE_BUDGET_S) -> bool:
        """Take what waits in the subscriptions, for at most ``budget_s`` of wall time, then the
        latched replies and the status replies. False when samples were still waiting at the end of
        the budget (this observer is behind the loop)."""
        now_ns = time.time_ns()
        deadline = time.monotonic() + budget_s
        caught_up = True
        for subscriber in self._subscribers:
            while (sample := subscriber.try_recv()) is not None:
                self._builder.take(str(sample.key_expr), sample.payload.to_bytes(), _log_time(sample, now_ns))
                if time.monotonic() > deadline:
                    caught_up = False
                    break
        self._ask_latched()
        self._status.poll()
        return caught_up

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        for querier in self._latched_queriers:
            querier.undeclare()


def _log_time(sample: zenoh.Sample, taken_ns: int) -> int:
    """When the sample passed the router, in Unix ns, if the router stamped it, else when the
    observer took it from its subscription (``taken_ns``)."""
    stamp = sample.timestamp
    if stamp is None:
        return taken_ns
    return stamp.get_time_as_ntp64().as_nanos()


class SceneWriter(Protocol):
    """What a :class:`Sink` writes into, one channel per key or topic: the MCAP file
    (:class:`McapWriter`) or the live view's channels (``services.recording.view.FoxgloveChannels``)."""

    def write_sample(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: int | None) -> None: ...

    def write_json(self, topic: str, value: Any, schema: dict[str, Any], stamp_ns: int, log_time_ns: int) -> None: ...

    def write_foxglove(self, topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None: ...


def writer_sink(writer: SceneWriter) -> Sink:
    """Each sample on its key's channel; the scene's wheel speeds as JSON of
    :data:`WHEEL_SPEEDS_SCHEMA`, its other messages as Foxglove's well-known messages."""

    def shown(topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None:
        if topic.endswith(WHEEL_SPEEDS_TOPIC):  # a fleet's robots' too: /<robot>/plot/wheel_speeds
            writer.write_json(topic, message, WHEEL_SPEEDS_SCHEMA, stamp_ns, log_time_ns)
        else:
            writer.write_foxglove(topic, message, stamp_ns, log_time_ns)

    return Sink(writer.write_sample, shown)


def take_until_stopped(
    spin_once: Callable[[float], bool],
    stop: threading.Event,
    duration_s: float | None = None,
    ended: Callable[[], bool] = lambda: False,
) -> bool:
    """A recorder's loop: ``spin_once(budget_s)`` takes what waits (False: samples still waited at
    the end of the budget), every :data:`TAKE_PERIOD_S` or at once while behind, until ``stop``,
    ``duration_s`` of wall time or ``ended()`` (the recording's own bound); then what still waits,
    within :data:`FINAL_TAKE_BUDGET_S`. False when samples still waited at the end (they are not
    recorded)."""
    deadline = None if duration_s is None else time.monotonic() + duration_s
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline) and not ended():
        if spin_once(TAKE_BUDGET_S):
            stop.wait(TAKE_PERIOD_S)
    return spin_once(FINAL_TAKE_BUDGET_S)


def run_record(
    session: zenoh.Session,
    keys: Keys,
    key_exprs: Sequence[str],
    output: Path,
    config: Config,
    stop: threading.Event,
    duration_s: float | None = None,
) -> int:
    """Record until ``stop`` or ``duration_s`` of wall time; the file is closed properly in every case."""
    writer = McapWriter(output, interfaces.published(keys, config))
    observer = Observer(session, keys, key_exprs or [keys.everything], config, writer_sink(writer))
    log.info("recording %s into %s", ", ".join(key_exprs or [keys.everything]), output)
    try:
        if not take_until_stopped(observer.spin_once, stop, duration_s):
            log.warning("stopped behind the loop: the samples still waiting at the end are not in %s", output)
    finally:
        observer.close()
        writer.close()
    log.info("recorded %d messages into %s", writer.messages, output)
    return 0


@dataclass
class RunRecording:
    """What :func:`write_run_recording` wrote."""

    parts: list[Path]
    """The files, ``run.mcap`` first (more when ``record.split_*`` split it)."""
    cut_short: list[Path]
    """The journals whose publisher was killed (they lack their last samples)."""
    stopped: dict[str, Any] | None
    """Why the recording stopped before the run ended (a limit of ``[record]``), or None."""
    rotated: dict[str, Any] | None = None
    """With ``record.keep = "newest"``, once older files were removed: which, and the span kept
    (:data:`RECORDING_ROTATED_SCHEMA`); None when nothing was."""


def write_run_recording(
    journals: Path, output: Path, config: Config, fleet: Sequence[Config] = (), record: RecordConfig | None = None
) -> RunRecording:
    """``output`` (``invent up``'s ``run.mcap``) from the journals (services/runtime/journal.py) in
    ``journals`` and below it (a fleet's robots have a folder each), merged in publication order a
    frame at a time, with the scene, as :func:`run_record` would have recorded them (each file with a
    channel for every key the loop's services declare they publish, from its start), within
    ``record``'s bounds: split into ``<stem>_1.mcap``, ... by ``split_size`` and ``split_duration``;
    stopped (but for what says how the run ended, :data:`ALWAYS_KEPT`) at ``max_size``, or where the
    first journal stopped (its limit, or a disk running low), which the last file then says on
    :data:`RECORDING_STOPPED_TOPIC`. With ``record.keep = "newest"`` the oldest files are removed
    instead (the journals' during the run, the recording's here), which the last file says on
    :data:`RECORDING_ROTATED_TOPIC`."""
    record = record or RecordConfig()
    readers = [JournalReader(path) for path in sorted(journals.rglob(f"*{JOURNAL_SUFFIX}"))]
    declared = [key for robot in (fleet or (config,)) for key in interfaces.published(Keys(robot.robot.name), robot)]
    writer = SplitWriter(output, record, declared)
    stopped: dict[str, Any] | None = None
    latest_stamp_ns: int | None = None
    dropped_journals: list[dict[str, Any]] = []
    last_kept: dict[str, bytes] = {}
    """Each journal file begins with the last of each :data:`ALWAYS_KEPT` key: taken once."""
    rotated: dict[str, Any] | None = None
    try:
        builder = SceneBuilder(config, writer_sink(writer), fleet)
        for key, payload, published_ns in heapq.merge(*readers, key=_publication_time):
            if key == DROPPED_KEY:
                dropped_journals.append(json.loads(payload))
                continue
            if key.endswith(ALWAYS_KEPT):
                if last_kept.get(key) == payload:
                    continue
                last_kept[key] = payload
            if stopped is None:
                if key == STOPPED_KEY:
                    stopped = json.loads(payload)
                elif writer.full:
                    stopped = {"reason": f"record.max_size: {record.max_size} MB written", "journal": ""}
            if key == STOPPED_KEY or (stopped is not None and not key.endswith(ALWAYS_KEPT)):
                continue
            builder.take(key, payload, published_ns)
            if stopped is None:
                latest_stamp_ns = writer.latest_stamp_ns
        if stopped is not None:
            stopped["stopped_at_s"] = None if latest_stamp_ns is None else latest_stamp_ns / NANOSECONDS_PER_SECOND
            writer.write_json(RECORDING_STOPPED_TOPIC, stopped, RECORDING_STOPPED_SCHEMA, latest_stamp_ns or 0, 0)
        if dropped_journals or writer.dropped:
            rotated = _rotation(writer, dropped_journals)
            writer.write_json(
                RECORDING_ROTATED_TOPIC, rotated, RECORDING_ROTATED_SCHEMA, writer.latest_stamp_ns or 0, 0
            )
    finally:
        writer.close()
    cut_short = [reader.path for reader in readers if not reader.complete]
    return RunRecording(writer.parts, cut_short, stopped, rotated)


def _rotation(writer: SplitWriter, dropped_journals: list[dict[str, Any]]) -> dict[str, Any]:
    """What a recording that keeps the newest removed (the journals' files during the run, the
    recording's own here, as each was named then) and the span it still covers."""
    files = [name for dropped in dropped_journals for name in dropped["files"]] + [p.path.name for p in writer.dropped]
    dropped_bytes = sum(dropped["bytes"] for dropped in dropped_journals) + sum(p.message_bytes for p in writer.dropped)
    first, last = writer.first_stamp_ns, writer.latest_stamp_ns
    return {
        "dropped_files": files,
        "dropped_mb": round(dropped_bytes / MB, 3),
        "from_s": None if first is None else first / NANOSECONDS_PER_SECOND,
        "to_s": None if last is None else last / NANOSECONDS_PER_SECOND,
    }


def _publication_time(entry: JournalEntry) -> int:
    return entry[2]
