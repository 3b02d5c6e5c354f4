"""``invent record --ros2``: the ROS 2 graph of a running robot or fleet, as the bridges publish it on
the wire (rmw_zenoh's keys), into a rosbag2 bag (services/recording/rosbag.py), as ``ros2 bag record``
would with ``use_sim_time``: each message at the simulation time it carries.

It subscribes exactly the topics the bridges of the robot description (or of each robot of a
fleet file) publish; the latched ones (``tf_static``, ``robot_description``) as a transient-local
subscriber does, so a recorder started late still gets them from the bridge's cache. The samples
wait in zenoh FIFO channels and the loop takes them, as ``invent record`` does. A sample is bad
input, dropped, counted and logged once a second per key, when it lacks rmw_zenoh's attachment,
is not CDR of its topic's type, or carries a stamp that is not a time (nanoseconds beyond a
second) or runs more than ``input.stamp_horizon`` ahead of the one before on its key (the first on
a key, or after the simulator restarted, is taken as it comes): a message someone else put on a
bridge's key does not stretch the bag.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import RecordConfig
from services.recording.record import SAMPLE_CAPACITY, TAKE_BUDGET_S, take_until_stopped
from services.recording.rosbag import BagResult, BagTopic, BagWriter, bag_topic
from services.ros2 import core, interfaces, wire
from services.ros2.graph import BridgeGraph
from services.runtime.logs import RateLimitedLog

log = logging.getLogger("invent.record")


@dataclass
class _Subscription:
    key: str
    topic: BagTopic
    subscriber: Any


class GraphRecorder:
    """Takes every sample the ``bridges`` publish into a :class:`BagWriter`."""

    def __init__(self, session: zenoh.Session, bridges: Sequence[BridgeGraph], writer: BagWriter, horizon_ns: int):
        self.writer = writer
        self._horizon_ns = horizon_ns
        self.refused: dict[str, int] = {}
        """Bad input by key."""
        self._last_stamp_ns: dict[str, int] = {}
        self._log = RateLimitedLog(log)
        self._subscriptions: list[_Subscription] = []
        for bridge in bridges:
            for entity in bridge.publications.values():
                key = bridge.key(entity)
                channel: zenoh.handlers.FifoChannel[zenoh.Sample] = zenoh.handlers.FifoChannel(SAMPLE_CAPACITY)
                subscriber: Any = (
                    zenoh.ext.declare_advanced_subscriber(
                        session, key, channel, history=zenoh.ext.HistoryConfig(detect_late_publishers=True)
                    )
                    if entity.qos.transient_local
                    else session.declare_subscriber(key, channel)
                )
                self._subscriptions.append(_Subscription(key, bag_topic(bridge, entity), subscriber))

    def spin_once(self, budget_s: float = TAKE_BUDGET_S) -> bool:
        """Take what waits, for at most ``budget_s``; False when samples still waited at the end."""
        deadline = time.monotonic() + budget_s
        for subscription in self._subscriptions:
            while (sample := subscription.subscriber.try_recv()) is not None:
                attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
                self.take(subscription.key, subscription.topic, sample.payload.to_bytes(), attachment)
                if time.monotonic() > deadline:
                    return False
        return True

    def take(self, key: str, topic: BagTopic, payload: bytes, attachment: bytes | None) -> None:
        """One sample of ``topic`` (on ``key``) into the bag, or counted as bad input."""
        try:
            wire.Attachment.decode(attachment)
            stamp_ns = self._stamp(key, interfaces.deserialize(payload, topic.interface))
        except BadInput as error:
            self.refused[key] = self.refused.get(key, 0) + 1
            self._log(key, logging.WARNING, "bad input on %s, not recorded: %s", key, error)
            return
        self._last_stamp_ns[key] = stamp_ns
        self.writer.write(topic, payload, stamp_ns)

    def _stamp(self, key: str, message: Any) -> int:
        """The simulation time ``message`` carries (the newest recorded for one that carries none);
        BadInput for one that is not a time, or runs ahead of the one before on ``key``."""
        stamp_ns = core.stamp_of(message)
        if stamp_ns is None:
            return self.writer.latest_stamp_ns or 0
        if stamp_ns < 0 or _nanosec_invalid(message):
            raise BadInput(f"stamp {stamp_ns} ns is not a time")
        last_ns = self._last_stamp_ns.get(key)
        if last_ns is not None and stamp_ns - last_ns > self._horizon_ns:
            raise BadInput(
                f"stamp {stamp_ns / NANOSECONDS_PER_SECOND:.3f} s is more than input.stamp_horizon ahead of the "
                f"one before, {last_ns / NANOSECONDS_PER_SECOND:.3f} s"
            )
        return stamp_ns

    def close(self) -> None:
        for subscription in self._subscriptions:
            subscription.subscriber.undeclare()


def _nanosec_invalid(message: Any) -> bool:
    """Whether a stamp of ``message`` has nanoseconds of a second or more (not a time ROS writes)."""
    stamps = [message.clock] if message.__msgtype__ == interfaces.CLOCK else []
    stamps += [t.header.stamp for t in getattr(message, "transforms", ())]
    header = getattr(message, "header", None)
    stamps += [header.stamp] if header is not None else []
    return any(not 0 <= int(stamp.nanosec) < NANOSECONDS_PER_SECOND for stamp in stamps)


def run_record_ros2(
    session: zenoh.Session,
    bridges: Sequence[BridgeGraph],
    output: Path,
    record: RecordConfig,
    distro: str,
    horizon_ns: int,
    stop: threading.Event,
    duration_s: float | None = None,
) -> BagResult:
    """Record until ``stop``, ``duration_s`` of wall time, or the bag's own bound; the bag is closed
    (its ``metadata.yaml`` written) in every case."""
    writer = BagWriter(output, record, distro)
    recorder = GraphRecorder(session, bridges, writer, horizon_ns)
    names = sorted({bridge.name(entity) for bridge in bridges for entity in bridge.publications.values()})
    log.info("recording %s into the bag %s", ", ".join(names), output)
    try:
        if not take_until_stopped(recorder.spin_once, stop, duration_s, lambda: writer.stopped is not None):
            log.warning("stopped behind the bridges: the samples still waiting at the end are not in %s", output)
    finally:
        recorder.close()
        result = writer.close()
    for key, count in sorted(recorder.refused.items()):
        log.warning("%d samples on %s were bad input, not recorded", count, key)
    return result
