"""rosbag2 bags of the ROS 2 graph, MCAP storage, as ``ros2 bag`` writes and reads them (no zenoh).

A bag is a directory: ``metadata.yaml`` (what ``ros2 bag info`` reads: the topics, their types,
RIHS01 type hashes, offered QoS and message counts, the files) and ``<bag>_0.mcap``, ``<bag>_1.mcap``
... (channels of encoding ``cdr``, schemas ``ros2msg``). Each file is written by rosbags' rosbag2
writer (``rosbags.rosbag2.Writer``, version 8, the MCAP storage plugin), its message definitions
and hashes generated from the typestore the bridge speaks with (services/ros2/interfaces.py): no
type name or hash is typed here. A message's timestamp is the simulation time it carries, so the
bag's time is the simulation's and ``ros2 bag play --clock`` replays on it; ``/clock`` is in the
bag too.

:class:`BagWriter` keeps the bounds of ``[record]`` (docs/recording.md, "Rates and bounds"), as ``run.mcap``
does: a new file at ``split_size`` MB or every ``split_duration`` simulated seconds; the bag stops
(the robot never does) at ``max_size`` MB, after ``max_duration`` simulated seconds, or when its
disk has less than ``min_free_disk`` MB free, and ``metadata.yaml`` says why in its ``custom_data``.
With ``record.keep = "newest"`` it splits at ``record.rotation_size`` and removes its oldest files
at ``max_size`` instead, ``metadata.yaml`` listing those left and saying how many were removed.

Three sources fill one: the journals the bridges of ``invent up --record-ros2`` kept of what they
published (:func:`write_bag_from_journals`); a recording of the loop, replayed through the bridge's
own mapping (:func:`export_run`, ``invent export --ros2``); the wire (``invent record --ros2``,
services/recording/ros2_record.py).
"""

from __future__ import annotations

import heapq
import json
import logging
import os
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from io import StringIO
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from ruamel.yaml import YAML

from schemas.codec import BadInput, decode
from schemas.keys import Keys, parse_data_key
from schemas.messages import NANOSECONDS_PER_SECOND, ImuSample, LaserScan, TimedDoubleSeq, TimedPosition
from schemas.navigation import GoalPlan, OccupancyGrid
from schemas.topics import Topic
from services.config import Config, RecordConfig
from services.recording.mcap_files import read_run
from services.ros2 import interfaces, wire
from services.ros2.graph import PUBLICATIONS, BridgeGraph, Entity
from services.ros2.outputs import RosOutputs, WheelsTaken
from services.runtime.journal import DROPPED_KEY, MB, STOPPED_KEY, JournalEntry, JournalReader
from services.runtime.journal import SUFFIX as JOURNAL_SUFFIX
from services.runtime.logs import RateLimitedLog

if TYPE_CHECKING:
    from rosbags.interfaces import Qos

# rosbags (the [ros2] extra) is imported where a bag is written: `invent up` imports this module
# (through services/launch/ros2_run.py) also where it runs without the ROS 2 bridge.

log = logging.getLogger("invent.rosbag")

BAG_VERSION: Literal[8] = 8
"""rosbag2's metadata version that Jazzy's ``ros2 bag`` writes and every later release reads."""
INFINITE = (9_223_372_036, 854_775_807)
"""rmw's infinite duration (``INT64_MAX`` ns: seconds, nanoseconds) as rosbag2 writes a QoS's deadline, lifespan and lease."""
DISK_CHECK_BYTES = MB
"""How often (bytes of messages) a bag looks at its disk's free space."""
STOPPED_DATA = "invent.recording_stopped"
STOPPED_AT_DATA = "invent.recording_stopped_at_s"
"""``custom_data`` keys of ``metadata.yaml`` when the bag stopped before its run (a bound of ``[record]``)."""
DROPPED_DATA = "invent.recording_dropped_files"
"""``custom_data``: the files a bag that keeps the newest removed (JSON list, oldest first)."""


@dataclass(frozen=True)
class BagTopic:
    """One topic of a bag, as ``ros2 bag info`` lists it."""

    name: str
    """Absolute: ``/clock``, ``/rh0/odom``."""
    interface: str
    """``nav_msgs/msg/Odometry``."""
    qos: wire.Qos
    """What the bridge offers it with: ``ros2 bag play`` offers the same (a latched topic stays latched)."""


def bag_topic(bridge: BridgeGraph, entity: Entity) -> BagTopic:
    return BagTopic(bridge.name(entity), entity.interface, entity.qos)


def bag_topics(bridge: BridgeGraph) -> dict[str, BagTopic]:
    """The bag topics of everything ``bridge`` publishes, by data key."""
    return {bridge.key(entity): bag_topic(bridge, entity) for entity in bridge.publications.values()}


def topic_of_key(key: str) -> BagTopic:
    """The bag topic of a data key the bridge publishes on (``0/rh0/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_…``);
    BadInput for a key of another layout, type or hash, or a topic no bridge publishes."""
    _domain, name, interface, type_hash = wire.parse_data_key(key)
    entity = next(
        (e for e in PUBLICATIONS.values() if e.interface == interface and name.endswith(f"/{e.name.strip('/')}")),
        None,
    )
    if entity is None:
        raise BadInput(f"{name} ({interface}) is not a topic the bridge publishes")
    if type_hash not in (interfaces.interface(interface).type_hash, wire.TYPE_HASH_NOT_SUPPORTED):
        raise BadInput(f"type hash {type_hash} is not {interface}'s")
    return BagTopic(name, interface, entity.qos)


def offered_qos(qos: wire.Qos) -> Qos:
    """A topic's QoS as rosbag2 keeps it in ``offered_qos_profiles``."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(*INFINITE)
    return Qos(
        history=QosHistory(int(qos.history)),
        depth=qos.depth,
        reliability=QosReliability(int(qos.reliability)),
        durability=QosDurability(int(qos.durability)),
        deadline=infinite,
        lifespan=infinite,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=infinite,
        avoid_ros_namespace_conventions=False,
    )


@dataclass
class BagResult:
    """What a :class:`BagWriter` wrote."""

    path: Path
    files: list[Path]
    messages: int
    stopped: dict[str, Any] | None
    """Why the bag stopped before its source ended (``reason``, ``stopped_at_s``), or None."""
    counts: dict[str, int] = field(default_factory=dict)
    """Messages per topic."""


class _Part:
    """One file of the bag, written by rosbags' writer in a folder of its own until it is closed."""

    def __init__(self, bag: Path, index: int) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.name = f"{bag.name}_{index}"
        self.folder = bag / self.name
        self.writer = Writer(self.folder, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.connections: dict[BagTopic, Any] = {}
        self.message_bytes = 0
        self.first_stamp_ns: int | None = None

    def write(self, topic: BagTopic, payload: bytes, stamp_ns: int) -> None:
        connection = self.connections.get(topic)
        if connection is None:
            connection = self.connections[topic] = self.writer.add_connection(
                topic.name,
                topic.interface,
                typestore=interfaces.messages(),
                offered_qos_profiles=[offered_qos(topic.qos)],
            )
        self.writer.write(connection, stamp_ns, payload)
        self.message_bytes += len(payload)
        if self.first_stamp_ns is None:
            self.first_stamp_ns = stamp_ns

    def close(self) -> dict[str, Any]:
        """Close it, move its file into the bag, and return its own ``metadata.yaml`` (read)."""
        self.writer.close()
        metadata = _yaml().load((self.folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        (self.folder / f"{self.name}.mcap").replace(self.folder.parent / f"{self.name}.mcap")
        shutil.rmtree(self.folder)
        return metadata


def _yaml() -> YAML:
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    return yaml


class BagWriter:
    """A bag being written into the new directory ``path``, within ``record``'s bounds; :meth:`close`
    writes its ``metadata.yaml`` (``ros_distro``: ``distro``)."""

    def __init__(self, path: Path, record: RecordConfig | None = None, distro: str = "jazzy") -> None:
        if path.exists():
            raise FileExistsError(f"{path} exists: a bag is written into a new directory")
        path.mkdir(parents=True)
        self.path = path
        self.record = record = record or RecordConfig()
        self.distro = distro
        self._split_bytes = None if record.split_size is None else record.split_size * MB
        self._split_ns = None if record.split_duration is None else round(record.split_duration * 1e9)
        self._max_bytes = None if record.max_size is None else record.max_size * MB
        self._max_stamp_ns = None if record.max_duration is None else round(record.max_duration * 1e9)
        self._min_free_bytes = record.min_free_disk * MB
        self._newest = record.keeps_newest
        if self._newest:
            self._split_bytes = record.rotation_size * MB
        self._parts: list[dict[str, Any]] = []
        self._part_bytes: list[int] = []
        self.dropped: list[str] = []
        """With ``record.keep = "newest"``: the files removed, oldest first."""
        self._part = _Part(path, 0)
        self._files_begun = 1
        """Its own files, removed or not: the next one's number (the journals' removed files, also
        said in ``dropped``, are not the bag's)."""
        self._written = 0
        self._next_disk_check = 0
        self.messages = 0
        self.counts: dict[str, int] = {}
        self.latest_stamp_ns: int | None = None
        self.stopped: dict[str, Any] | None = None
        self._check_disk()

    def write(self, topic: BagTopic, payload: bytes, stamp_ns: int) -> bool:
        """Keep one message (CDR) of ``topic`` at simulation time ``stamp_ns``; False once the bag has stopped."""
        if self.stopped is not None:
            return False
        if self._max_stamp_ns is not None and stamp_ns > self._max_stamp_ns:
            self.stop(f"record.max_duration: nothing stamped after {self._max_stamp_ns / 1e9:.3f} s is recorded")
            return False
        if not self._newest and self._max_bytes is not None and self._written + len(payload) > self._max_bytes:
            self.stop(f"record.max_size: {self.record.max_size} MB written")
            return False
        if self._written >= self._next_disk_check:
            self._next_disk_check = self._written + DISK_CHECK_BYTES
            if not self._check_disk():
                return False
        self._split_before(stamp_ns)
        self._part.write(topic, payload, stamp_ns)
        self._written += len(payload)
        self.messages += 1
        self.counts[topic.name] = self.counts.get(topic.name, 0) + 1
        self.latest_stamp_ns = stamp_ns if self.latest_stamp_ns is None else max(self.latest_stamp_ns, stamp_ns)
        return True

    def _split_before(self, stamp_ns: int) -> None:
        part = self._part
        by_size = self._split_bytes is not None and part.message_bytes >= self._split_bytes
        by_time = (
            self._split_ns is not None
            and part.first_stamp_ns is not None
            and stamp_ns >= part.first_stamp_ns + self._split_ns
        )
        if by_size or by_time:
            self._parts.append(part.close())
            self._part_bytes.append(part.message_bytes)
            self._part = _Part(self.path, self._files_begun)
            self._files_begun += 1
            if self._newest:
                self._drop_oldest()

    def _drop_oldest(self) -> None:
        """Remove the oldest files while the closed ones hold more than ``max_size`` with room for the one begun."""
        assert self._max_bytes is not None and self._split_bytes is not None  # RecordConfig checks it
        while self._parts and sum(self._part_bytes) + self._split_bytes > self._max_bytes:
            oldest = self._parts.pop(0)
            self._part_bytes.pop(0)
            for file in oldest["files"]:
                (self.path / file["path"]).unlink()
                self.dropped.append(file["path"])
                log.info("record.keep = newest: the bag %s removed %s", self.path, file["path"])

    def _check_disk(self) -> bool:
        if self._min_free_bytes <= 0:
            return True
        disk = os.statvfs(self.path)
        free = disk.f_bavail * disk.f_frsize
        if free < self._min_free_bytes:
            self.stop(
                f"record.min_free_disk: {free / MB:.0f} MB free on the disk of {self.path}, "
                f"under {self._min_free_bytes / MB:.0f} MB"
            )
            return False
        return True

    def stop(self, reason: str, stopped_at_ns: int | None = None) -> None:
        """Keep nothing more; ``metadata.yaml`` will say why, and the simulation time of the last
        message kept (or ``stopped_at_ns``)."""
        if self.stopped is None:
            at_ns = self.latest_stamp_ns if stopped_at_ns is None else stopped_at_ns
            self.stopped = {"reason": reason, "stopped_at_s": None if at_ns is None else at_ns / NANOSECONDS_PER_SECOND}
            log.warning("the ROS 2 bag %s stopped: %s (the robot goes on)", self.path, reason)

    def close(self) -> BagResult:
        """The last file closed, and ``metadata.yaml`` of them all."""
        self._parts.append(self._part.close())
        (self.path / "metadata.yaml").write_text(self._metadata())
        files = [self.path / file["path"] for part in self._parts for file in part["files"]]
        return BagResult(self.path, files, self.messages, self.stopped, dict(self.counts))

    def _metadata(self) -> str:
        """The bag's ``metadata.yaml``: its files' own, merged (topics once, their counts summed)."""
        topics: dict[tuple[str, str], dict[str, Any]] = {}
        files = []
        for part in self._parts:
            for entry in part["topics_with_message_count"]:
                meta = entry["topic_metadata"]
                merged = topics.setdefault((meta["name"], meta["type"]), {"topic_metadata": meta, "message_count": 0})
                merged["message_count"] += entry["message_count"]
            files += part["files"]
        counted = [file for file in files if file["message_count"]]
        start = min((file["starting_time"]["nanoseconds_since_epoch"] for file in counted), default=0)
        end = max(
            (file["starting_time"]["nanoseconds_since_epoch"] + file["duration"]["nanoseconds"] for file in counted),
            default=0,
        )
        custom = (
            {STOPPED_DATA: self.stopped["reason"], STOPPED_AT_DATA: json.dumps(self.stopped["stopped_at_s"])}
            if self.stopped
            else {}
        )
        if self.dropped:
            custom[DROPPED_DATA] = json.dumps(self.dropped)
        information = {
            "version": BAG_VERSION,
            "storage_identifier": "mcap",
            "relative_file_paths": [file["path"] for file in files],
            "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(file["message_count"] for file in files),
            "topics_with_message_count": list(topics.values()),
            "compression_format": "",
            "compression_mode": "",
            "files": files,
            "custom_data": custom or None,
            "ros_distro": self.distro,
        }
        text = StringIO()
        _yaml().dump({"rosbag2_bagfile_information": information}, text)
        return text.getvalue()


def write_bag_from_journals(journals: Path, output: Path, record: RecordConfig, distro: str = "jazzy") -> BagResult:
    """The bag ``output`` of the journals the bridges kept in ``journals`` (``--bag-journal``: each
    entry a data key, its CDR payload and the simulation time it carries), merged in simulation-time
    order; stopped where the first journal stopped (a bound of ``[record]``, or its disk), if one did."""
    readers = [JournalReader(path) for path in sorted(journals.glob(f"*{JOURNAL_SUFFIX}"))]
    writer = BagWriter(output, record, distro)
    skipped = RateLimitedLog(log)
    try:
        for key, payload, stamp_ns in heapq.merge(*readers, key=_stamp):
            if key == STOPPED_KEY:
                writer.stop(json.loads(payload)["reason"])
                continue
            if key == DROPPED_KEY:  # the bridges' journal files removed (record.keep = "newest")
                writer.dropped.extend(json.loads(payload)["files"])
                continue
            try:
                topic = topic_of_key(key)
            except BadInput as error:
                skipped(key, logging.WARNING, "not in the bag: %s: %s", key, error)
                continue
            writer.write(topic, payload, stamp_ns)
    finally:
        result = writer.close()
    return result


def _stamp(entry: JournalEntry) -> int:
    return entry[2]


@dataclass(frozen=True)
class ExportedRobot:
    """One robot of a recording to export: its description, and its bridge (namespace, TF layout, /clock)."""

    config: Config
    bridge: BridgeGraph


def robots_in(messages: Iterable[Any]) -> list[str]:
    """The robots whose ``sim/clock`` a recording holds, in the order first seen."""
    robots: dict[str, None] = {}
    for message in messages:
        parsed = parse_data_key(message.topic)
        if parsed is not None and parsed[1] is Topic.SIM_CLOCK:
            robots.setdefault(parsed[0], None)
    return list(robots)


def export_run(
    recording: Path, output: Path, robots: Sequence[ExportedRobot], record: RecordConfig | None = None
) -> tuple[BagResult, dict[str, int]]:
    """The bag ``output`` of what the bridge of each of ``robots`` would have published during the
    run recorded in ``recording`` (``run.mcap`` and the files it was split into): each robot's
    ``sim/clock``, ``odometry/pose``, ``motor/torque``, ``sim/scan`` and ``sim/imu`` (those the
    recording holds) replayed in the order they were published
    through :class:`~services.ros2.outputs.RosOutputs`. Returns the result and, per key, the recorded
    samples refused as bad input (not taken, as the bridge would not)."""
    read = read_run(recording)
    outputs = {robot.config.robot.name: (RosOutputs(robot.config, robot.bridge), robot.bridge) for robot in robots}
    topics = {name: bag_topics(bridge) for name, (_outputs, bridge) in outputs.items()}
    writer = BagWriter(output, record, robots[0].config.ros2.distro if robots else "jazzy")
    refused: dict[str, int] = {}

    def write(name: str, bridge: BridgeGraph, outgoing: Sequence[Any]) -> None:
        for message in outgoing:
            entity = bridge.publications[message.topic]
            writer.write(topics[name][bridge.key(entity)], interfaces.serialize(message.message), message.stamp_ns)

    try:
        for name, (robot_outputs, bridge) in outputs.items():
            write(name, bridge, robot_outputs.latched())
        keys = {name: Keys(name) for name in outputs}
        handlers: dict[str, tuple[str, BridgeGraph, type[Any], Callable[[Any], Any]]] = {}
        for name, (robot_outputs, bridge) in outputs.items():
            handlers[keys[name].sim_clock] = (name, bridge, TimedDoubleSeq, robot_outputs.take_wheels)
            handlers[keys[name].odometry_pose] = (name, bridge, TimedPosition, robot_outputs.take_localized)
            handlers[keys[name].motor_torque] = (name, bridge, TimedDoubleSeq, robot_outputs.take_torque)
            handlers[keys[name].sim_scan] = (name, bridge, LaserScan, robot_outputs.take_scan)
            handlers[keys[name].sim_imu] = (name, bridge, ImuSample, robot_outputs.take_imu)
            handlers[keys[name].drive_map] = (name, bridge, OccupancyGrid, robot_outputs.take_map)
            handlers[keys[name].drive_costmap] = (name, bridge, OccupancyGrid, robot_outputs.take_costmap)
            handlers[keys[name].drive_plan] = (name, bridge, GoalPlan, robot_outputs.take_plan)
        for recorded in read.messages:
            handler = handlers.get(recorded.topic)
            if handler is None:
                continue
            name, bridge, message_type, take = handler
            try:
                taken = take(decode(message_type, recorded.data))
            except BadInput:
                refused[recorded.topic] = refused.get(recorded.topic, 0) + 1
                continue
            if taken is not None:
                write(name, bridge, taken.outgoing if isinstance(taken, WheelsTaken) else taken)
            if writer.stopped is not None:
                break
        if not read.complete:
            log.warning("%s was cut short: its whole chunks are in the bag", recording)
    finally:
        result = writer.close()
    return result, refused
