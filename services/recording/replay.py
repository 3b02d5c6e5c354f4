"""``invent replay``: a recording's samples published again, for a changed odometry,
localization or drive to run on yesterday's inputs (services/recording/mcap_files.py chooses and orders them).

Paced by the recorded simulation time scaled by ``--rate``; at ``--rate 0`` as fast as the
consumers take them: every service that takes every sample of a replayed key says in its
``status`` how many it took (``inputs``), and the replay never has more than
:data:`FLOW_WINDOW` samples of a key on their way to it (a service's input holds
:data:`~services.runtime.inputs.CHANNEL_CAPACITY`; beyond, it would drop the oldest). At any rate, a
service that takes several replayed keys gets them in the recorded order: before it is sent a
sample of another key than the last, the replay waits until it took what it was sent. It ends,
exit 0, once those consumers have taken every sample.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

import zenoh

from schemas.codec import ENCODING
from schemas.keys import Keys
from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.status import ServiceStatus, decode_status
from schemas.topics import Topic
from services.config import ConfigError
from services.errors import ConsumerStalled
from services.exits import ExitStatus
from services.recording.mcap_files import Replayed
from services.runtime.discovery import service_statuses
from services.runtime.inputs import CHANNEL_CAPACITY
from services.runtime.session import has_match

log = logging.getLogger("invent.replay")

FLOW_WINDOW = CHANNEL_CAPACITY // 4
"""Samples of one key a ``--rate 0`` replay lets wait in its consumers' inputs before it asks how far they are."""
CONSUMER_TIMEOUT_S = 10.0
"""How long a consumer may take nothing of what waits for it before the replay gives up (exit 1)."""
DISCOVERY_TIMEOUT_S = 2.0
STATUS_POLL_S = 0.001


@dataclass
class _Consumer:
    """One service that takes every sample of one replayed key."""

    service: str
    key: str
    querier: zenoh.Querier
    taken_before: int
    taken: int = 0

    def poll(self) -> None:
        for reply in self.querier.get():
            # a bad reply (one that does not decode, or without this input) is taken as none
            status = None if reply.ok is None else decode_status(ServiceStatus, reply.ok.payload.to_bytes())
            taken = None if status is None else status.inputs.get(self.key)
            if taken is not None:
                self.taken = taken.samples - self.taken_before


class _Consumers:
    """What the robot's services took of each replayed key, from their status."""

    def __init__(self, session: zenoh.Session, keys: Keys, replayed_keys: set[str]) -> None:
        self._by_key: dict[str, list[_Consumer]] = {key: [] for key in replayed_keys}
        self.sent = dict.fromkeys(replayed_keys, 0)
        self._last_key: dict[str, str] = {}
        """The key each consumer was last sent a sample of, by service."""
        for _robot, service, status, _reply in service_statuses(session, keys.every_alive, DISCOVERY_TIMEOUT_S):
            for key, taken in ({} if status is None else status.inputs).items():
                if key in self._by_key and taken.every_sample:
                    querier = session.declare_querier(keys.status(service), timeout=DISCOVERY_TIMEOUT_S)
                    self._by_key[key].append(_Consumer(str(service), key, querier, taken.samples))

    @property
    def consumed_keys(self) -> set[str]:
        return {key for key, consumers in self._by_key.items() if consumers}

    def describe(self) -> str:
        named = [
            f"{key} → {', '.join(c.service for c in consumers)}" for key, consumers in self._by_key.items() if consumers
        ]
        return "; ".join(named) if named else "none found"

    def before_sending(self, key: str, window: int | None, stop: threading.Event) -> None:
        """Wait, if need be, before a sample of ``key`` is sent: until every consumer took all it was
        sent when one of them last got another key (zenoh keeps the order of one key's samples,
        not across keys: a service's inputs are separate queues), or, with a ``window``, when that
        many samples of ``key`` wait for the slowest of its consumers (as last polled)."""
        consumers = self._by_key[key]
        switching = any(self._last_key.get(c.service, key) != key for c in consumers)
        behind = self.sent[key] - min(c.taken for c in consumers) if consumers else 0
        if switching or (window is not None and behind >= window):
            self.wait_taken(stop)
        for consumer in consumers:
            self._last_key[consumer.service] = key

    def wait_taken(self, stop: threading.Event) -> None:
        """Until every consumer took every sample sent. ConsumerStalled when one took nothing for
        :data:`CONSUMER_TIMEOUT_S`."""
        consumers = [c for key_consumers in self._by_key.values() for c in key_consumers]
        progress = {id(c): c.taken for c in consumers}
        last_progress = time.monotonic()
        while not stop.is_set():
            waiting = [c for c in consumers if c.taken < self.sent[c.key]]
            if not waiting:
                return
            for consumer in waiting:
                consumer.poll()
            if any(c.taken != progress[id(c)] for c in waiting):
                progress = {id(c): c.taken for c in consumers}
                last_progress = time.monotonic()
            elif time.monotonic() - last_progress > CONSUMER_TIMEOUT_S:
                stalled = waiting[0]
                raise ConsumerStalled(
                    f"{stalled.service} took {stalled.taken} of the {self.sent[stalled.key]} samples sent on "
                    f"{stalled.key} and nothing more for {CONSUMER_TIMEOUT_S:g} s"
                )
            stop.wait(STATUS_POLL_S)

    def close(self) -> None:
        for consumers in self._by_key.values():
            for consumer in consumers:
                consumer.querier.undeclare()


def run_replay(session: zenoh.Session, schedule: list[Replayed], keys: Keys, rate: float, stop: threading.Event) -> int:
    """Publish ``schedule`` on ``keys``' robot; 0 once its consumers took it all, 1 if one stalled."""
    topics = sorted({replayed.topic for replayed in schedule})
    publishers = {
        topic: session.declare_publisher(
            keys.topic(topic),
            encoding=zenoh.Encoding(ENCODING),
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
        )
        for topic in topics
    }
    consumers = _Consumers(session, keys, {keys.topic(topic) for topic in topics})
    log.info(
        "replaying %d samples of %s onto %s at %s; consumers: %s",
        len(schedule),
        ", ".join(topics),
        keys.prefix,
        "the consumers' pace" if rate == 0 else f"{rate:g}× the recorded simulation time",
        consumers.describe(),
    )
    started = time.monotonic()
    first_stamp_ns = schedule[0].stamp_ns if schedule else 0
    try:
        for topic, publisher in publishers.items():
            if keys.topic(topic) in consumers.consumed_keys:
                _wait_matching(publisher, keys.topic(topic), stop)
        for replayed in schedule:
            if stop.is_set():
                break
            key = keys.topic(replayed.topic)
            if rate > 0:
                due = started + (replayed.stamp_ns - first_stamp_ns) / NANOSECONDS_PER_SECOND / rate
                stop.wait(max(0.0, due - time.monotonic()))
            consumers.before_sending(key, FLOW_WINDOW if rate == 0 else None, stop)
            publishers[replayed.topic].put(replayed.data)
            consumers.sent[key] += 1
        consumers.wait_taken(stop)
    except ConsumerStalled as stalled:
        log.error("replay stopped: %s", stalled)
        return ExitStatus.FAILURE
    finally:
        consumers.close()
        for publisher in publishers.values():
            publisher.undeclare()
    log.info("replayed %d samples in %.2f s", sum(consumers.sent.values()), time.monotonic() - started)
    return 0


def _wait_matching(publisher: zenoh.Publisher, key: str, stop: threading.Event) -> None:
    """Until the consumers' subscriptions reached this session (declarations travel on their own)."""
    deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
    while not has_match(publisher):
        if stop.is_set():
            return
        if time.monotonic() > deadline:
            raise ConsumerStalled(f"no subscription to {key} reached the replay within {DISCOVERY_TIMEOUT_S:g} s")
        stop.wait(STATUS_POLL_S)


def parse_topics(suffixes: list[str]) -> list[Topic]:
    """``--keys`` (keys relative to the robot) as topics; ConfigError naming the valid ones."""
    valid = {str(topic) for topic in Topic}
    unknown = [suffix for suffix in suffixes if suffix not in valid]
    if unknown:
        raise ConfigError(f"--keys: {', '.join(unknown)} is not a data key; data keys: {', '.join(sorted(valid))}")
    return [Topic(suffix) for suffix in suffixes]
