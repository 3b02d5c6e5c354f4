"""A ROS 2 node's side of rmw_zenoh that runs on older zenoh releases: what
tests/test_ros2_zenoh_releases.py runs with the python of a side venv holding only eclipse-zenoh
(1.6.2, 1.9.0: the releases rmw_zenoh bundles) and rosbags, so it imports nothing of the project
and only the zenoh API every 1.x release since 1.6 has (peer session, plain subscribers,
publishers and queriers with their matching status, attachments, zenoh-ext serialisation, an
advanced subscriber's history).

It is written apart from tests/ros_client.py (which needs the project's harness): keys and
attachments as rmw_zenoh lays them out, CDR and type hashes from rosbags'
Jazzy typestore, NavigateToPose's types and hashes from the type descriptions ROS's generator wrote
(tests/data/ros2_interfaces). One phase per run, its findings one JSON object on stdout::

    python tests/zenoh_release_client.py tcp/127.0.0.1:7447 teleop     # invent up --ros2 --teleop
    python tests/zenoh_release_client.py tcp/127.0.0.1:7447 navigate   # and a drive in goal mode
"""

from __future__ import annotations

import argparse
import importlib.metadata
import itertools
import json
import math
import os
import queue
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

DOMAIN = 0
TIMEOUT_S = 20.0
"""The longest any one thing is waited for (the first /odom, a service's queryable, a reply)."""
RESULT_TIMEOUT_S = 60.0
"""How long ``get_result`` may be held: until the goal ends."""
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
INTERFACES = Path(__file__).parent / "data" / "ros2_interfaces"
TRIGGER = "std_srvs::srv::dds_::Trigger_/RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
"""std_srvs/srv/Trigger in a key as ROS 2 Jazzy names and hashes it (rosbags has no service types)."""
TRIGGER_REQUEST = b"\x00\x01\x00\x00\x00"
"""An empty Trigger request in CDR: the encapsulation header and its one placeholder byte."""
NAVIGATE = "nav2_msgs/action/NavigateToPose"
TERMINAL = {4: "succeeded", 5: "canceled", 6: "aborted"}
"""action_msgs/GoalStatus's terminal codes."""
DRIVE_VX = 0.3
"""m/s forward on /cmd_vel."""
GOAL_AHEAD_M = 0.3
T = TypeVar("T")


def wait_for(predicate: Callable[[], T], what: str, timeout: float = TIMEOUT_S) -> T:
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"no {what} within {timeout} s")
        time.sleep(0.01)
    return value


# -- types and keys ----------------------------------------------------------------------------

_SCALARS = {2: "int8", 3: "uint8", 4: "int16", 5: "uint16", 6: "int32", 7: "uint32", 8: "int64", 9: "uint64"}
_SCALARS |= {10: "float32", 11: "float64", 15: "bool", 16: "byte", 17: "string"}
"""type_description_interfaces/FieldType's scalar ids (1: nested; +48 array, +96 bounded, +144 sequence)."""


def _msg_text(description: dict[str, Any]) -> str:
    """A type description as ``.msg`` text for rosbags."""
    lines = []
    for entry in description["fields"]:
        kind = entry["type"]
        type_id, suffix = kind["type_id"], ""
        for offset, form in ((144, "[]"), (96, f"[<={kind['capacity']}]"), (48, f"[{kind['capacity']}]")):
            if type_id > offset:
                type_id, suffix = type_id - offset, form
                break
        base = kind["nested_type_name"] if type_id == 1 else _SCALARS[type_id]
        lines.append(f"{base}{suffix} {entry['name']}")
    return "\n".join(lines)


def _action_types() -> tuple[Any, dict[str, str]]:
    """A typestore of NavigateToPose's and GoalStatusArray's types, and the RIHS01 hashes ROS wrote."""
    store = get_typestore(Stores.EMPTY)
    hashes: dict[str, str] = {}
    for path in (
        INTERFACES / "nav2_msgs/action/NavigateToPose.json",
        INTERFACES / "action_msgs/msg/GoalStatusArray.json",
    ):
        content = json.loads(path.read_text())
        message = content["type_description_msg"]
        for description in (message["type_description"], *message["referenced_type_descriptions"]):
            if description["type_name"] not in store.fielddefs:
                store.register(get_types_from_msg(_msg_text(description), description["type_name"]))
        hashes |= {entry["type_name"]: entry["hash_string"] for entry in content["type_hashes"]}
    return store, hashes


ACTION_TYPES, ACTION_HASHES = _action_types()


def topic_key(topic: str, name: str) -> str:
    """``/odom``, ``nav_msgs/msg/Odometry`` -> rmw_zenoh's key, the hash from rosbags."""
    package, kind, type_name = name.split("/")
    return f"{DOMAIN}/{topic.strip('/')}/{package}::{kind}::dds_::{type_name}_/{TYPESTORE.hash_rihs01(name)}"


def action_key(endpoint: str, name: str) -> str:
    """rcl_action's ``navigate_to_pose/_action/<endpoint>`` with ROS's hash of ``name``."""
    package, kind, type_name = name.split("/")
    return f"{DOMAIN}/navigate_to_pose/_action/{endpoint}/{package}::{kind}::dds_::{type_name}_/{ACTION_HASHES[name]}"


class Node:
    """A ROS node's publishers and service clients: every sample and request carries rmw_zenoh's
    33-byte attachment (the entity's sequence number from 1, a source timestamp, its GID),
    zenoh-ext serialised; one entity per key, each with its GID and sequence."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._entities: dict[str, tuple[bytes, Iterator[int]]] = {}

    def attachment(self, key: str) -> bytes:
        gid, sequence = self._entities.setdefault(key, (os.urandom(16), itertools.count(1)))
        fields = (zenoh.ext.Int64(next(sequence)), zenoh.ext.Int64(time.time_ns()), gid)
        return bytes(zenoh.ext.z_serialize(fields).to_bytes())

    def call(self, key: str, request: bytes, timeout: float = TIMEOUT_S) -> bytes:
        """A service call once its queryable is there: the one reply's payload."""
        querier = self.session.declare_querier(key, timeout=timeout)
        try:
            wait_for(lambda: querier.matching_status.matching, f"service on {key}")
            replies = list(querier.get(payload=request, attachment=self.attachment(key)))
        finally:
            querier.undeclare()
        answers = [reply.ok for reply in replies if reply.ok is not None]
        if len(answers) != 1:
            raise RuntimeError(f"{key}: {len(replies)} replies, {len(answers)} answers")
        return bytes(answers[0].payload.to_bytes())

    def trigger(self, service: str) -> dict[str, Any]:
        """A std_srvs/Trigger call: its response's success and message, read from CDR by hand."""
        data = self.call(f"{DOMAIN}/{service.strip('/')}/{TRIGGER}", TRIGGER_REQUEST)
        length = int.from_bytes(data[8:12], "little")
        return {"success": data[4] == 1, "message": data[12 : 12 + length - 1].decode()}


class Topic:
    """Every sample of a topic, queued from zenoh's thread for this one (nothing else is done there)."""

    def __init__(self, session: zenoh.Session, key: str, name: str, store: Any = TYPESTORE) -> None:
        self.samples: queue.Queue[tuple[bytes, bytes | None]] = queue.Queue()
        self.taken: list[Any] = []
        self.attachment_sizes: set[int] = set()
        self._name, self._store = name, store
        self._subscriber = session.declare_subscriber(
            key,
            lambda s: self.samples.put(
                (s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment is not None else None)
            ),
        )

    def take(self) -> list[Any]:
        """Every sample so far, decoded."""
        while not self.samples.empty():
            payload, attachment = self.samples.get_nowait()
            self.attachment_sizes.add(len(attachment or b""))
            self.taken.append(self._store.deserialize_cdr(payload, self._name))
        return self.taken

    def latest(self) -> Any:
        return wait_for(lambda: (taken := self.take()) and taken[-1], f"sample of {self._name}")

    def close(self) -> None:
        self._subscriber.undeclare()


# -- the phases ---------------------------------------------------------------------------------


def _xy(odometry: Any) -> tuple[float, float]:
    return odometry.pose.pose.position.x, odometry.pose.pose.position.y


def _yaw(odometry: Any) -> float:
    q = odometry.pose.pose.orientation
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def _distance(a: Any, b: Any) -> float:
    return math.dist(_xy(a), _xy(b))


def _drive(node: Node, cmd_vel: Any, seconds: float) -> None:
    """``DRIVE_VX`` forward for ``seconds``, a twist every 50 ms (well within the motor's 0.5 s timeout)."""
    vector = TYPESTORE.types["geometry_msgs/msg/Vector3"]
    twist = TYPESTORE.types["geometry_msgs/msg/Twist"](linear=vector(DRIVE_VX, 0.0, 0.0), angular=vector(0, 0, 0.0))
    payload = bytes(TYPESTORE.serialize_cdr(twist, twist.__msgtype__))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        cmd_vel.put(payload, attachment=node.attachment(str(cmd_vel.key_expr)))
        time.sleep(0.05)


def _next(odom: Topic) -> Any:
    """The first odometry that comes after the samples so far."""
    after = len(odom.take())
    return wait_for(lambda: (taken := odom.take()) and len(taken) > after and taken[-1], "next odometry")


def _settled(odom: Topic) -> Any:
    """The odometry once ten more samples came, the robot's speed zero in the last: a robot at rest."""
    after = len(odom.take())
    return wait_for(
        lambda: (
            (taken := odom.take())
            and len(taken) >= after + 10
            and abs(taken[-1].twist.twist.linear.x) < 1e-3
            and taken[-1]
        ),
        "odometry at rest",
    )


def late_robot_description(session: zenoh.Session) -> str:
    """``/robot_description`` (transient local) as a subscriber started long after its one
    publication gets it, rmw_zenoh's way: an advanced subscriber asking late publishers' caches."""
    cached: queue.Queue[bytes] = queue.Queue()
    subscriber = zenoh.ext.declare_advanced_subscriber(
        session,
        topic_key("/robot_description", "std_msgs/msg/String"),
        lambda sample: cached.put(sample.payload.to_bytes()),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
    )
    try:
        data: str = TYPESTORE.deserialize_cdr(cached.get(timeout=TIMEOUT_S), "std_msgs/msg/String").data
        return data
    finally:
        subscriber.undeclare()


def teleop(node: Node) -> dict[str, Any]:
    """``/odom`` and ``/scan`` received; a late ``/robot_description``; ``/cmd_vel`` moves the robot;
    after ``/motor/stop`` twists no longer do; ``/motor/clear`` lets them again."""
    odom = Topic(node.session, topic_key("/odom", "nav_msgs/msg/Odometry"), "nav_msgs/msg/Odometry")
    scan = Topic(node.session, topic_key("/scan", "sensor_msgs/msg/LaserScan"), "sensor_msgs/msg/LaserScan")
    cmd_vel = node.session.declare_publisher(topic_key("/cmd_vel", "geometry_msgs/msg/Twist"))
    try:
        start = odom.latest()
        last_scan = scan.latest()
        description = late_robot_description(node.session)
        wait_for(lambda: cmd_vel.matching_status.matching, "subscriber of /cmd_vel")
        _drive(node, cmd_vel, 1.0)
        driven = _next(odom)
        stop = node.trigger("/motor/stop")
        stopped = _settled(odom)
        _drive(node, cmd_vel, 0.5)
        while_stopped = _settled(odom)
        clear = node.trigger("/motor/clear")
        _drive(node, cmd_vel, 0.5)
        after_clear = _settled(odom)
        return {
            "odom": {
                "samples": len(odom.take()),
                "attachment_bytes": sorted(odom.attachment_sizes),
                "frames": [start.header.frame_id, start.child_frame_id],
            },
            "scan": {"samples": len(scan.take()), "frame": last_scan.header.frame_id, "rays": len(last_scan.ranges)},
            "robot_description": description[: len("<?xml")],
            "cmd_vel_moved_m": _distance(start, driven),
            "motor_stop": stop,
            "moved_while_stopped_m": _distance(stopped, while_stopped),
            "motor_clear": clear,
            "moved_after_clear_m": _distance(while_stopped, after_clear),
        }
    finally:
        cmd_vel.undeclare()
        odom.close()
        scan.close()


def _uuid(goal_id: bytes) -> Any:
    return ACTION_TYPES.types["unique_identifier_msgs/msg/UUID"](uuid=np.frombuffer(goal_id, dtype=np.uint8).copy())


def _goal_request(goal_id: bytes, x: float, y: float, yaw: float, frame: str) -> bytes:
    types = ACTION_TYPES.types
    pose = types["geometry_msgs/msg/PoseStamped"](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame
        ),
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        ),
    )
    goal = types[f"{NAVIGATE}_Goal"](pose=pose, behavior_tree="")
    request = types[f"{NAVIGATE}_SendGoal_Request"](goal_id=_uuid(goal_id), goal=goal)
    return bytes(ACTION_TYPES.serialize_cdr(request, request.__msgtype__))


def _statuses(status: Topic, goal_id: bytes) -> list[int]:
    """The goal's status in each ``_action/status`` sample listing it, repeats left out."""
    seen: list[int] = []
    for array in status.take():
        for entry in array.status_list:
            if bytes(bytearray(entry.goal_info.goal_id.uuid)) == goal_id and (not seen or seen[-1] != entry.status):
                seen.append(int(entry.status))
    return seen


def navigate(node: Node) -> dict[str, Any]:
    """A NavigateToPose goal ``GOAL_AHEAD_M`` ahead of the robot in ``odom``, as rclpy's action client
    sends it: ``send_goal``, then ``get_result`` held until the goal ends; its states on ``_action/status``."""
    odom = Topic(node.session, topic_key("/odom", "nav_msgs/msg/Odometry"), "nav_msgs/msg/Odometry")
    status_name = "action_msgs/msg/GoalStatusArray"
    status = Topic(node.session, action_key("status", status_name), status_name, ACTION_TYPES)
    try:
        here = odom.latest()
        (x, y), yaw = _xy(here), _yaw(here)
        goal = (x + GOAL_AHEAD_M * math.cos(yaw), y + GOAL_AHEAD_M * math.sin(yaw), yaw)
        goal_id = os.urandom(16)
        sent = node.call(action_key("send_goal", f"{NAVIGATE}_SendGoal"), _goal_request(goal_id, *goal, "odom"))
        accepted = ACTION_TYPES.deserialize_cdr(sent, f"{NAVIGATE}_SendGoal_Response").accepted
        result: dict[str, Any] = {"accepted": bool(accepted)}
        if accepted:
            request = ACTION_TYPES.types[f"{NAVIGATE}_GetResult_Request"](goal_id=_uuid(goal_id))
            reply = node.call(
                action_key("get_result", f"{NAVIGATE}_GetResult"),
                bytes(ACTION_TYPES.serialize_cdr(request, request.__msgtype__)),
                RESULT_TIMEOUT_S,
            )
            response = ACTION_TYPES.deserialize_cdr(reply, f"{NAVIGATE}_GetResult_Response")
            ended = int(response.status)
            statuses = wait_for(
                lambda: (seen := _statuses(status, goal_id)) and seen[-1] == ended and seen,
                f"status {ended} on _action/status",
            )
            result |= {
                "result_status": TERMINAL.get(ended, str(ended)),
                "error_code": int(response.result.error_code),
                "statuses": statuses,
                "from_goal_m": math.dist(_xy(odom.latest()), goal[:2]),
            }
        return result
    finally:
        odom.close()
        status.close()


PHASES = {"teleop": teleop, "navigate": navigate}


@contextmanager
def open_peer(endpoint: str) -> Iterator[zenoh.Session]:
    """A peer session (a ROS node's mode under rmw_zenoh) connected to ``endpoint``."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    session = zenoh.open(config)
    try:
        yield session
    finally:
        session.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("endpoint", help="the router a ROS node connects to, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("phase", choices=sorted(PHASES))
    args = parser.parse_args()
    with open_peer(args.endpoint) as session:
        wait_for(lambda: list(session.info.routers_zid()), f"router at {args.endpoint}")
        found = PHASES[args.phase](Node(session))
        found |= {
            "zenoh": importlib.metadata.version("eclipse-zenoh"),
            "routers": len(list(session.info.routers_zid())),
            "peers": len(list(session.info.peers_zid())),
        }
        print(json.dumps(found))
    return 0


if __name__ == "__main__":
    sys.exit(main())
