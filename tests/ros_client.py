"""A ROS 2 node's side of rmw_zenoh, written for the tests independently of services/ros2: keys
and attachments as rmw_zenoh's sources lay them out, CDR and type hashes from rosbags' typestore,
the attachment serialised by zenoh-ext (what rmw_zenoh uses). What the bridge sends is checked
against this, and what this sends is what a ROS node would send the bridge.

Run as a script, it checks a running bridge from a peer session of whatever zenoh it is run with
(it needs only zenoh and rosbags), so another zenoh release, such as the one an rmw_zenoh release
bundles, can be checked against this project's (docs/ros2.md)::

    invent up --ros2 --teleop                            # the project, its zenoh
    python3 -m venv /tmp/z && /tmp/z/bin/pip install eclipse-zenoh==1.6.2 rosbags
    /tmp/z/bin/python tests/ros_client.py tcp/127.0.0.1:7447
"""

from __future__ import annotations

import itertools
import json
import os
import queue
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tests.harness import wait_until

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
INTERFACES = Path(__file__).parent / "data" / "ros2_interfaces"
TRIGGER_KEY_TYPE = (
    "std_srvs::srv::dds_::Trigger_/RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
)
"""std_srvs/srv/Trigger in a key, as ROS 2 Jazzy names and hashes it (rosbags has no service types)."""
TRIGGER_REQUEST = b"\x00\x01\x00\x00\x00"
"""A Trigger request in CDR: the encapsulation header, then its one placeholder byte."""


def key_type(name: str) -> str:
    """``pkg/msg/Type`` -> ``pkg::msg::dds_::Type_/RIHS01_<hash>`` (the hash from rosbags)."""
    package, kind, type_name = name.split("/")
    return f"{package}::{kind}::dds_::{type_name}_/{TYPESTORE.hash_rihs01(name)}"


def topic_key(domain: int, topic: str, name: str) -> str:
    return f"{domain}/{topic.strip('/')}/{key_type(name)}"


def attachment(sequence_number: int, gid: bytes, timestamp_ns: int | None = None) -> bytes:
    stamp = time.time_ns() if timestamp_ns is None else timestamp_ns
    return zenoh.ext.z_serialize((zenoh.ext.Int64(sequence_number), zenoh.ext.Int64(stamp), gid)).to_bytes()


def read_attachment(data: bytes) -> tuple[int, int, bytes]:
    sequence_number, stamp, gid = zenoh.ext.z_deserialize(
        tuple[zenoh.ext.Int64, zenoh.ext.Int64, bytes], zenoh.ZBytes(data)
    )
    return int(sequence_number), int(stamp), gid


def message(name: str, **fields: Any) -> Any:
    return TYPESTORE.types[name](**fields)


def cdr(value: Any) -> bytes:
    return bytes(TYPESTORE.serialize_cdr(value, value.__msgtype__))


def twist(vx: float, w: float, stamped: bool = False) -> Any:
    vector = TYPESTORE.types["geometry_msgs/msg/Vector3"]
    body = message("geometry_msgs/msg/Twist", linear=vector(vx, 0.0, 0.0), angular=vector(0.0, 0.0, w))
    if not stamped:
        return body
    header = message(
        "std_msgs/msg/Header",
        stamp=message("builtin_interfaces/msg/Time", sec=0, nanosec=0),
        frame_id="base_link",
    )
    return message("geometry_msgs/msg/TwistStamped", header=header, twist=body)


@dataclass
class Received:
    """A sample the client took: its key, payload, attachment, and when it came (wall ns)."""

    key: str
    payload: bytes
    attachment: bytes | None
    received_ns: int


@dataclass
class RosNode:
    """The publishing and calling side of a ROS node on one zenoh session."""

    session: zenoh.Session
    domain: int = 0
    gid: bytes = field(default_factory=lambda: os.urandom(16))
    _sequence: Any = field(default_factory=lambda: itertools.count(1))

    def put(self, topic: str, value: Any, *, with_attachment: bool = True) -> None:
        key = topic_key(self.domain, topic, value.__msgtype__)
        extra = {"attachment": attachment(next(self._sequence), self.gid)} if with_attachment else {}
        self.session.put(key, cdr(value), **extra)

    def put_raw(self, key: str, payload: bytes, attachment_bytes: bytes | None) -> None:
        extra = {} if attachment_bytes is None else {"attachment": attachment_bytes}
        self.session.put(key, payload, **extra)

    def call_trigger(
        self, service: str, timeout: float = 5.0
    ) -> tuple[tuple[bool, str], tuple[int, int, bytes], int] | None:
        """Call a std_srvs/Trigger service as an rmw_zenoh client: the response, the reply's
        attachment and the request's sequence number, or None when no reply came."""
        key = f"{self.domain}/{service.strip('/')}/{TRIGGER_KEY_TYPE}"
        querier = self.session.declare_querier(key, timeout=timeout)
        try:
            wait_until(lambda: querier.matching_status.matching, timeout, f"a service on {key}")
            sequence_number = next(self._sequence)
            replies = list(querier.get(payload=TRIGGER_REQUEST, attachment=attachment(sequence_number, self.gid)))
        finally:
            querier.undeclare()
        answered = [reply.ok for reply in replies if reply.ok is not None]
        if not answered:
            return None
        (sample,) = answered
        return (
            trigger_response(sample.payload.to_bytes()),
            read_attachment(sample.attachment.to_bytes()),
            sequence_number,
        )


# -- types from ROS's own type descriptions --------------------------------------------------

_FIELD_TYPES = {
    2: "int8",
    3: "uint8",
    4: "int16",
    5: "uint16",
    6: "int32",
    7: "uint32",
    8: "int64",
    9: "uint64",
    10: "float32",
    11: "float64",
    15: "bool",
    16: "byte",
    17: "string",
}
"""type_description_interfaces/FieldType's ids of the scalar types; +48 an array, +96 a bounded
sequence, +144 a sequence; 1 a nested type (its ``nested_type_name``)."""


def _msg_text(description: dict[str, Any]) -> str:
    """A type description (``type_description_msg``'s form) as ``.msg`` text for rosbags."""
    lines = []
    for entry in description["fields"]:
        kind = entry["type"]
        base_id, suffix = kind["type_id"], ""
        if base_id > 144:
            base_id, suffix = base_id - 144, "[]"
        elif base_id > 96:
            base_id, suffix = base_id - 96, f"[<={kind['capacity']}]"
        elif base_id > 48:
            base_id, suffix = base_id - 48, f"[{kind['capacity']}]"
        base = kind["nested_type_name"] if base_id == 1 else _FIELD_TYPES[base_id]
        lines.append(f"{base}{suffix} {entry['name']}")
    return "\n".join(lines)


def _ros_names(value: Any) -> Any:
    if isinstance(value, str):
        return value.replace("/srv/msg/", "/srv/")
    if isinstance(value, tuple | list):
        return type(value)(_ros_names(item) for item in value)
    if isinstance(value, dict):
        return {_ros_names(key): _ros_names(item) for key, item in value.items()}
    return value


def typestore_of(descriptions: tuple[Path, ...]) -> Any:
    """A rosbags typestore holding every type of ``descriptions``, built from the descriptions
    alone (not from the bridge's definitions), and the hashes ROS computed."""
    store = get_typestore(Stores.EMPTY)
    hashes: dict[str, str] = {}
    for path in descriptions:
        content = json.loads(path.read_text())
        message = content["type_description_msg"]
        for description in (message["type_description"], *message["referenced_type_descriptions"]):
            name = description["type_name"]
            if name not in store.fielddefs:
                # rosbags reads ``pkg/srv/Type`` as ``pkg/srv/msg/Type``: ROS's names are kept.
                store.register(_ros_names(get_types_from_msg(_msg_text(description), name)))
        hashes.update({entry["type_name"]: entry["hash_string"] for entry in content["type_hashes"]})
    return store, hashes


def graph_tokens(session: zenoh.Session, domain: int) -> list[list[str]]:
    """Every rmw_zenoh graph liveliness token of ``domain`` (nodes, publishers, subscriptions,
    services), each split into its key's chunks."""
    replies = session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=2.0)
    return [str(reply.ok.key_expr).split("/") for reply in replies if reply.ok is not None]


def cached_samples(
    session: zenoh.Session,
    domain: int,
    topics: dict[str, str],
    timeout: float,
    key_of: Callable[[int, str, str], str] = topic_key,
) -> dict[str, bytes]:
    """The first sample of each transient-local topic (name -> its type), as a ROS node started
    after its only publication gets it: from the publisher's cache, rmw_zenoh's way (an advanced
    subscriber that detects late publishers). ``key_of(domain, topic, type)``: the topic's key
    (:func:`nav_key` for ROS's shipped hashes)."""
    received: dict[str, list[bytes]] = {topic: [] for topic in topics}
    subscribers = [
        zenoh.ext.declare_advanced_subscriber(
            session,
            key_of(domain, topic, name),
            lambda sample, t=topic: received[t].append(sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        for topic, name in topics.items()
    ]
    try:
        wait_until(lambda: all(received.values()), timeout, f"a cached sample of each of {list(topics)}")
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
    return {topic: samples[0] for topic, samples in received.items()}


# -- the map, costmap and plan: nav_msgs, from the type descriptions ROS ships -------------------

NAV_DESCRIPTIONS = (
    INTERFACES / "nav_msgs" / "msg" / "OccupancyGrid.json",
    INTERFACES / "nav_msgs" / "msg" / "Path.json",
)
"""The type descriptions of nav_msgs/msg/OccupancyGrid and Path that ROS ships (the ``ros-nav-msgs``
wheel: tests/data/ros2_interfaces/README.md)."""
NAV_TYPESTORE, NAV_HASHES = typestore_of(NAV_DESCRIPTIONS)
"""What a ROS node of Jazzy knows of OccupancyGrid and Path (and the types they hold): their types
and RIHS01 hashes, as RViz's Map and Path displays and Nav2's nodes subscribe them."""


def nav_key(domain: int, topic: str, name: str) -> str:
    """The key of ``topic`` of type ``name`` (``nav_msgs/msg/OccupancyGrid``) with ROS's shipped hash."""
    package, kind, type_name = name.split("/")
    return f"{domain}/{topic.strip('/')}/{package}::{kind}::dds_::{type_name}_/{NAV_HASHES[name]}"


def nav_decode(data: bytes, name: str) -> Any:
    return NAV_TYPESTORE.deserialize_cdr(data, name)


def trigger_response(data: bytes) -> tuple[bool, str]:
    """A Trigger response's (success, message), read from its CDR by hand (rosbags has no services)."""
    assert data[:4] == b"\x00\x01\x00\x00"
    success = data[4] == 1
    length = int.from_bytes(data[8:12], "little")
    return success, data[12 : 12 + length - 1].decode()


class Recorder:
    """Every sample of ``key_expr`` (``0/**``: the whole domain), kept in order for the test."""

    def __init__(self, session: zenoh.Session, key_expr: str) -> None:
        self.samples: queue.Queue[Received] = queue.Queue()
        self._subscriber = session.declare_subscriber(
            key_expr,
            lambda sample: self.samples.put(
                Received(
                    str(sample.key_expr),
                    sample.payload.to_bytes(),
                    sample.attachment.to_bytes() if sample.attachment is not None else None,
                    time.time_ns(),
                )
            ),
        )
        self.taken: list[Received] = []

    def take(self) -> list[Received]:
        while True:
            try:
                self.taken.append(self.samples.get_nowait())
            except queue.Empty:
                return self.taken

    def of(self, topic: str) -> list[Received]:
        prefix = f"/{topic.strip('/')}/"
        return [sample for sample in self.take() if f"/{sample.key.split('/', 1)[1]}".startswith(prefix)]

    def close(self) -> None:
        self._subscriber.undeclare()


def check_bridge(endpoint: str) -> dict[str, Any]:
    """As a peer of ``endpoint`` (a ROS node's mode): the graph's tokens, ``/odom`` with its
    attachment, a late ``/robot_description``, ``/cmd_vel`` moving the robot, ``/motor/stop``
    stopping it (then ``/motor/clear``)."""
    config = zenoh.Config()
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", f'["{endpoint}"]')
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    session = zenoh.open(config)
    try:
        odometry: queue.Queue[tuple[bytes, bytes | None]] = queue.Queue()
        session.declare_subscriber(
            topic_key(0, "odom", "nav_msgs/msg/Odometry"),
            lambda s: odometry.put((s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else None)),
        )
        payload, first_attachment = odometry.get(timeout=20.0)
        start = TYPESTORE.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
        late: queue.Queue[bytes] = queue.Queue()
        description = zenoh.ext.declare_advanced_subscriber(
            session,
            topic_key(0, "robot_description", "std_msgs/msg/String"),
            lambda s: late.put(s.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        urdf = TYPESTORE.deserialize_cdr(late.get(timeout=10.0), "std_msgs/msg/String").data
        node = RosNode(session)
        for _ in range(40):
            node.put("cmd_vel", twist(0.3, 0.0))
            time.sleep(0.05)
        while not odometry.empty():
            payload, _ = odometry.get()
        moved = (
            TYPESTORE.deserialize_cdr(payload, "nav_msgs/msg/Odometry").pose.pose.position.x
            - start.pose.pose.position.x
        )
        stopped = node.call_trigger("/motor/stop")
        node.call_trigger("/motor/clear")
        description.undeclare()
        return {
            "graph tokens": len([r for r in session.liveliness().get("@ros2_lv/0/**", timeout=2.0) if r.ok]),
            "/odom attachment bytes": len(first_attachment or b""),
            "/odom frames": (start.header.frame_id, start.child_frame_id),
            "late /robot_description": urdf.startswith("<?xml"),
            "/cmd_vel 0.3 m/s for 2 s moved (m)": round(moved, 3),
            "/motor/stop": stopped[0] if stopped else None,
        }
    finally:
        session.close()


if __name__ == "__main__":
    import importlib.metadata
    import sys

    print(f"eclipse-zenoh {importlib.metadata.version('eclipse-zenoh')}")
    for name, value in check_bridge(sys.argv[1] if len(sys.argv) > 1 else "tcp/127.0.0.1:7447").items():
        print(f"{name}: {value}")
