"""The client side of a ROS 2 node's services and actions over rmw_zenoh, written for the tests
independently of services/ros2 (as tests/ros_client.py, whose keys and attachments it uses):
NavigateToPose as rclcpp_action's client lays it out (its three services, its two topics, rcl_action's
goal state machine) and ros2_controllers' odometry services, their types and RIHS01 hashes from ROS's
own type descriptions alone."""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from tests.harness import wait_until
from tests.ros_client import INTERFACES, attachment, read_attachment, typestore_of

ACTION_DESCRIPTIONS = (
    INTERFACES / "nav2_msgs" / "action" / "NavigateToPose.json",
    INTERFACES / "action_msgs" / "srv" / "CancelGoal.json",
    INTERFACES / "action_msgs" / "msg" / "GoalStatusArray.json",
)
"""The type descriptions ROS's generator wrote (NavigateToPose) and ROS ships (action_msgs):
tests/data/ros2_interfaces/README.md says where each came from."""

ACTION_TYPESTORE, ROS_HASHES = typestore_of(ACTION_DESCRIPTIONS)
"""What a ROS node of Jazzy knows of NavigateToPose and action_msgs: their types and RIHS01 hashes."""
ODOMETRY_SERVICES_TYPESTORE, ODOMETRY_SERVICES_HASHES = typestore_of(
    (INTERFACES / "std_srvs" / "srv" / "Empty.json", INTERFACES / "control_msgs" / "srv" / "SetOdometry.json")
)
"""ros2_controllers' odometry services as ROS describes them: std_srvs/srv/Empty (as ROS ships it) and
control_msgs/srv/SetOdometry (as ROS's generator writes it): their types and RIHS01 hashes."""


def odometry_service_key_type(name: str) -> str:
    """``std_srvs/srv/Empty`` -> ``std_srvs::srv::dds_::Empty_/RIHS01_<ROS's hash>``."""
    package, kind, type_name = name.split("/")
    return f"{package}::{kind}::dds_::{type_name}_/{ODOMETRY_SERVICES_HASHES[name]}"


NAVIGATE = "nav2_msgs/action/NavigateToPose"
STATUS_CODES = {
    "unknown": 0,
    "accepted": 1,
    "executing": 2,
    "canceling": 3,
    "succeeded": 4,
    "canceled": 5,
    "aborted": 6,
}


def action_key_type(name: str) -> str:
    """``nav2_msgs/action/NavigateToPose_SendGoal`` -> ``nav2_msgs::action::dds_::NavigateToPose_SendGoal_/RIHS01_<ROS's hash>``."""
    package, kind, type_name = name.split("/")
    return f"{package}::{kind}::dds_::{type_name}_/{ROS_HASHES[name]}"


ACTION_ENDPOINTS = {
    "send_goal": f"{NAVIGATE}_SendGoal",
    "cancel_goal": "action_msgs/srv/CancelGoal",
    "get_result": f"{NAVIGATE}_GetResult",
    "feedback": f"{NAVIGATE}_FeedbackMessage",
    "status": "action_msgs/msg/GoalStatusArray",
}
"""rcl_action's five endpoints of an action (``<action>/_action/<endpoint>``) and their types."""


def action_key(domain: int, action: str, endpoint: str) -> str:
    return f"{domain}/{action.strip('/')}/_action/{endpoint}/{action_key_type(ACTION_ENDPOINTS[endpoint])}"


def action_message(name: str, **fields: Any) -> Any:
    return ACTION_TYPESTORE.types[name](**fields)


def action_cdr(value: Any) -> bytes:
    return bytes(ACTION_TYPESTORE.serialize_cdr(value, value.__msgtype__))


def action_decode(data: bytes, name: str) -> Any:
    return ACTION_TYPESTORE.deserialize_cdr(data, name)


def _uuid(value: bytes) -> Any:
    return action_message("unique_identifier_msgs/msg/UUID", uuid=np.frombuffer(value, dtype=np.uint8).copy())


def _time(stamp_ns: int = 0) -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return action_message("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def pose_stamped(x: float, y: float, yaw: float, frame: str = "map", typestore: Any = None) -> Any:
    """geometry_msgs/PoseStamped at (x, y) heading ``yaw``, in ``frame``."""
    store = typestore or ACTION_TYPESTORE
    types = store.types
    return types["geometry_msgs/msg/PoseStamped"](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame
        ),
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2)),
        ),
    )


def send_goal_request(goal_id: bytes, pose: Any, behavior_tree: str = "") -> bytes:
    goal = action_message(f"{NAVIGATE}_Goal", pose=pose, behavior_tree=behavior_tree)
    return action_cdr(action_message(f"{NAVIGATE}_SendGoal_Request", goal_id=_uuid(goal_id), goal=goal))


def cancel_request(goal_id: bytes = bytes(16), stamp_ns: int = 0) -> bytes:
    info = action_message("action_msgs/msg/GoalInfo", goal_id=_uuid(goal_id), stamp=_time(stamp_ns))
    return action_cdr(action_message("action_msgs/srv/CancelGoal_Request", goal_info=info))


def result_request(goal_id: bytes) -> bytes:
    return action_cdr(action_message(f"{NAVIGATE}_GetResult_Request", goal_id=_uuid(goal_id)))


@dataclass
class ServiceReply:
    """A service's reply to an rmw_zenoh client: the decoded response, or the error reply's text."""

    response: Any
    error: str | None
    attachment: tuple[int, int, bytes] | None
    sequence_number: int
    """The request's, which the reply must echo."""


@dataclass
class ActionClient:
    """The client side of a NavigateToPose action, as rclcpp_action's client and rmw_zenoh lay it
    out: each of the three services a zenoh query with the attachment, the two topics subscribed."""

    session: zenoh.Session
    action: str
    """``/navigate_to_pose`` or ``/robot1/navigate_to_pose``."""
    domain: int = 0
    gid: bytes = field(default_factory=lambda: os.urandom(16))
    _sequence: Any = field(default_factory=lambda: itertools.count(1))

    def key(self, endpoint: str) -> str:
        return action_key(self.domain, self.action, endpoint)

    def call(self, endpoint: str, payload: bytes, timeout: float = 10.0, with_attachment: bool = True) -> ServiceReply:
        """One call of ``endpoint``, once its queryable is there; its single reply (AssertionError if none)."""
        key = self.key(endpoint)
        querier = self.session.declare_querier(key, timeout=timeout)
        try:
            wait_until(lambda: querier.matching_status.matching, 10.0, f"a service on {key}")
            sequence_number = next(self._sequence)
            extra = {"attachment": attachment(sequence_number, self.gid)} if with_attachment else {}
            replies = list(querier.get(payload=payload, **extra))
        finally:
            querier.undeclare()
        assert len(replies) == 1, f"{key}: {len(replies)} replies"
        (reply,) = replies
        if reply.ok is None:
            return ServiceReply(None, reply.err.payload.to_bytes().decode(errors="replace"), None, sequence_number)
        response_type = f"{ACTION_ENDPOINTS[endpoint]}_Response"
        return ServiceReply(
            action_decode(reply.ok.payload.to_bytes(), response_type),
            None,
            read_attachment(reply.ok.attachment.to_bytes()) if reply.ok.attachment is not None else None,
            sequence_number,
        )

    def send_goal(self, x: float, y: float, yaw: float, frame: str = "map") -> tuple[bytes, ServiceReply]:
        """A new goal (a fresh UUID, as rclcpp_action makes one): its UUID and the reply."""
        goal_id = os.urandom(16)
        return goal_id, self.call("send_goal", send_goal_request(goal_id, pose_stamped(x, y, yaw, frame)))

    def get_result(self, goal_id: bytes, timeout: float = 60.0) -> ServiceReply:
        """As rclcpp_action asks for it once the goal is accepted: the reply comes when the goal ends."""
        return self.call("get_result", result_request(goal_id), timeout=timeout)

    def cancel(self, goal_id: bytes = bytes(16), stamp_ns: int = 0) -> ServiceReply:
        return self.call("cancel_goal", cancel_request(goal_id, stamp_ns))


def goal_statuses(payload: bytes) -> dict[bytes, int]:
    """A GoalStatusArray's goals: UUID -> status code."""
    array = action_decode(payload, "action_msgs/msg/GoalStatusArray")
    return {bytes(bytearray(s.goal_info.goal_id.uuid)): int(s.status) for s in array.status_list}


GOAL_STATE_MACHINE = {(1, 2), (1, 3), (2, 3), (2, 4), (2, 6), (3, 4), (3, 5), (3, 6)}
"""rcl_action's goal state machine (``rcl_action/src/rcl_action/goal_state_machine.c``): from
accepted, execute or cancel; from executing, cancel, succeed or abort; from canceling, succeed,
canceled or abort. A goal is listed first as accepted (1); a terminal state is never left."""


def status_paths(payloads: list[bytes]) -> list[tuple[bytes, list[int]]]:
    """Each goal's statuses in a run of ``_action/status`` samples, in order, repeats left out; a
    goal that leaves the list (its result no longer kept) and comes back (its UUID taken again) is
    a new goal."""
    paths: list[tuple[bytes, list[int]]] = []
    listed: dict[bytes, list[int]] = {}
    for payload in payloads:
        statuses = goal_statuses(payload)
        listed = {uuid: path for uuid, path in listed.items() if uuid in statuses}
        for uuid, status in statuses.items():
            path = listed.get(uuid)
            if path is None:
                path = listed[uuid] = []
                paths.append((uuid, path))
            if not path or path[-1] != status:
                path.append(status)
    return paths


def state_machine_deviations(path: list[int]) -> list[str]:
    """What in one goal's statuses (as :func:`status_paths` gives them) rcl_action never does."""
    deviations = [] if path[:1] == [1] else [f"listed first as {path[:1]}, not accepted (1)"]
    deviations += [f"{a} -> {b}" for a, b in itertools.pairwise(path) if (a, b) not in GOAL_STATE_MACHINE]
    return deviations
