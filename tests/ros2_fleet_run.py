"""The fleet run tests/test_ros2_fleet.py shares among its tests (``invent up --fleet FILE --ros2 --teleop``
and, for the NavigateToPose tests, rh1's drive in goal mode), with what those tests share: the fleet
file, what each robot's bridge offers, driving a robot and its goals through ROS."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.keys import Keys, Service
from services.planar import Pose
from tests import ros_client, ros_services
from tests.harness import (
    REPO,
    InventProcess,
    call,
    free_port,
    invent_command,
    peer_session,
    wait_alive,
    wait_until,
)

DOMAIN = 0
NAMESPACES = {"rh0": "/rh0", "rh1": "/robot1"}
"""Each robot's namespace: rh0's its name (the default), rh1's set in the fleet file."""
FLEET = """world = "empty"
[[robots]]
name = "rh0"
start = { x = 0.0, y = 0.0, theta = 0.0 }
[[robots]]
name = "rh1"
namespace = "robot1"
start = { x = 0.0, y = 3.0, theta = 0.0 }
"""
PUBLISHED = {
    "odom": "nav_msgs/msg/Odometry",
    "tf": "tf2_msgs/msg/TFMessage",
    "tf_static": "tf2_msgs/msg/TFMessage",
    "joint_states": "sensor_msgs/msg/JointState",
    "robot_description": "std_msgs/msg/String",
    "scan": "sensor_msgs/msg/LaserScan",
    "imu": "sensor_msgs/msg/Imu",
}
"""What each robot's bridge publishes in its namespace (Nav2's multi-robot layout: tf in the namespace)."""
PUBLISHED_ONCE = {
    f"{ns}/{topic}": PUBLISHED[topic] for ns in NAMESPACES.values() for topic in ("tf_static", "robot_description")
}
"""The topics each bridge publishes once, at its start (transient local: a late node gets them from
the bridge's cache). The fleet starts its own router, so the test's session may join after them."""
CLOCK = ("/clock", "rosgraph_msgs/msg/Clock")
SUBSCRIBED = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")
SERVICES = ("motor/stop", "motor/clear", "motor/start", "motor/finish")
GOAL_POSE = ("goal_pose", "geometry_msgs/msg/PoseStamped")
ACTION_ENDPOINTS = {"send_goal": "SS", "cancel_goal": "SS", "get_result": "SS", "feedback": "MP", "status": "MP"}
"""Each robot's NavigateToPose action (``<ns>/navigate_to_pose/_action/<endpoint>``), by kind of token."""
STARTUP_TIMEOUT_S = 90.0
SHIPPED = REPO / "tests" / "data" / "ros2_interfaces"


@dataclass
class Fleet:
    endpoint: str
    session: zenoh.Session
    recorder: ros_client.Recorder
    node: ros_client.RosNode
    directory: Path

    def status(self, robot: str, service: Service) -> dict[str, Any]:
        ok, status = call(self.session, Keys(robot).status(service))
        assert ok
        return status

    def position(self, robot: str) -> tuple[float, float]:
        pose = self.status(robot, Service.SIM)["pose"]
        return pose["x"], pose["y"]


@pytest.fixture(scope="module", name="fleet")
def fleet_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    """The two-robot fleet in teleop, each service its own process; the test's session a ROS node's
    peer session, its domain's samples recorded from when it joins the fleet's router (a fleet starts
    its own: what the bridges published before, :data:`PUBLISHED_ONCE`, is in their caches)."""
    directory = tmp_path_factory.mktemp("ros2-fleet")
    (directory / "fleet.toml").write_text(FLEET)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = (directory / "up.log").open("w")
    flags = ["--fleet", str(directory / "fleet.toml"), "--ros2", "--teleop", "--listen", endpoint]
    up = subprocess.Popen(
        invent_command("up", *flags, "--report", str(directory / "report")),
        cwd=REPO,
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        with peer_session(endpoint) as session:
            recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
            for robot in NAMESPACES:
                wait_alive(session, Keys(robot).alive(Service.ROS2), STARTUP_TIMEOUT_S)
            wait_alive(session, Keys("rh0").alive(Service.SIM), STARTUP_TIMEOUT_S)
            for namespace in NAMESPACES.values():
                wait_until(lambda n=namespace: recorder.of(f"{n}/odom"), STARTUP_TIMEOUT_S, f"{namespace}/odom")
            yield Fleet(endpoint, session, recorder, ros_client.RosNode(session), directory)
            recorder.close()
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait()
        log.close()
    assert up.returncode == 0, (directory / "up.log").read_text()[-3000:]


def mangled(name: str) -> str:
    return name.replace("/", "%")


def shipped_hash(name: str) -> str:
    """The RIHS01 hash in the type description ROS ships for ``name`` (tests/data/ros2_interfaces)."""
    package, _msg, type_name = name.split("/")
    description = json.loads((SHIPPED / package / "msg" / f"{type_name}.json").read_text())
    return next(e["hash_string"] for e in description["type_hashes"] if e["type_name"] == name)


def drive(fleet: Fleet, namespace: str, vx: float, seconds: float) -> None:
    """Twists at 20 Hz on ``namespace``'s cmd_vel for ``seconds`` of wall time (teleop is realtime)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        fleet.node.put(f"{namespace}/cmd_vel", ros_client.twist(vx, 0.0))
        time.sleep(0.05)


def moved_by(before: tuple[float, float], after: tuple[float, float]) -> float:
    return math.hypot(after[0] - before[0], after[1] - before[1])


GOAL_ROBOT = "rh1"
"""The robot whose drive runs in goal mode for the goal tests (rh0 has none: its goals are refused)."""
NEAR_M, NEAR_RAD = 0.1, 0.3
"""How near the simulated body must end to a goal the drive completed. The drive holds a goal to its
tolerances (5 cm, 0.1 rad) by ``odometry/pose``, not the ground truth: here, on a loaded machine
(load average 9 to 12 on two cores), the body ended 0.107 and 0.216 rad off a completed goal's
heading; a goal sent wrong (frame, robot, heading) misses by far more. What the bridge sent is
checked exactly, on the drive's ``drive/goal``."""
GOAL_ACTION = f"{NAMESPACES[GOAL_ROBOT]}/navigate_to_pose"
FEEDBACK, STATUS = f"{GOAL_ACTION}/_action/feedback", f"{GOAL_ACTION}/_action/status"


@dataclass
class Goals:
    """rh1's action as a ROS client sees it, and what the test reads of the fleet."""

    fleet: Fleet
    client: ros_services.ActionClient
    drive: InventProcess

    def ground_truth(self, robot: str = GOAL_ROBOT) -> Pose:
        pose = self.fleet.status(robot, Service.SIM)["pose"]
        return Pose(pose["x"], pose["y"], pose["theta"])

    def ahead(self, distance: float, turn: float = 0.0) -> tuple[float, float, float]:
        """A goal (in map) ``distance`` ahead of rh1, its heading turned by ``turn``."""
        pose = self.ground_truth()
        return pose.x + distance * math.cos(pose.theta), pose.y + distance * math.sin(pose.theta), pose.theta + turn

    def statuses(self, uuid: bytes) -> list[int]:
        """The goal's status in each ``_action/status`` sample that lists it, repeats left out."""
        seen: list[int] = []
        for sample in self.fleet.recorder.of(STATUS):
            status = ros_services.goal_statuses(sample.payload).get(uuid)
            if status is not None and (not seen or seen[-1] != status):
                seen.append(status)
        return seen

    def wait_status(self, uuid: bytes, status: int, timeout: float = 30.0) -> list[int]:
        return wait_until(
            lambda: (seen := self.statuses(uuid)) and seen[-1] == status and seen, timeout, f"status {status}"
        )

    def feedback(self, uuid: bytes) -> list[Any]:
        messages = (
            ros_services.action_decode(sample.payload, f"{ros_services.NAVIGATE}_FeedbackMessage")
            for sample in self.fleet.recorder.of(FEEDBACK)
        )
        return [message.feedback for message in messages if bytes(bytearray(message.goal_id.uuid)) == uuid]

    def started(self, uuid: bytes) -> dict[str, Any]:
        """The goal rh1's drive started last (``drive/goal``, latched): it must be ``uuid``'s."""
        ok, target = call(self.fleet.session, Keys(GOAL_ROBOT).drive_goal)
        assert ok and target["id"] == uuid.hex(), target
        return target

    def near(self, x: float, y: float, theta: float) -> bool:
        truth = self.ground_truth()
        return (
            math.hypot(truth.x - x, truth.y - y) <= NEAR_M
            and abs(math.remainder(truth.theta - theta, math.tau)) <= NEAR_RAD
        )

    def bad_inputs(self, key: str) -> int:
        entry = self.fleet.status(GOAL_ROBOT, Service.ROS2)["bad_input"]["by_key"].get(key)
        return entry["count"] if entry else 0

    def goal_pose(self, pose: Pose) -> bytes:
        """Publish ``pose`` (in odom) on rh1's ``goal_pose`` as RViz does; the UUID the bridge gave its goal."""
        listed = self.fleet.recorder.of(STATUS)
        before = set(ros_services.goal_statuses(listed[-1].payload)) if listed else set()
        topic = f"{NAMESPACES[GOAL_ROBOT]}/goal_pose"
        self.fleet.node.put(topic, ros_services.pose_stamped(pose.x, pose.y, pose.theta, "odom", ros_client.TYPESTORE))
        return wait_until(
            lambda: (
                (listed := self.fleet.recorder.of(STATUS))
                and next(iter(set(ros_services.goal_statuses(listed[-1].payload)) - before), None)
            ),
            10.0,
            "a new goal in the status",
        )


@pytest.fixture(scope="module", name="goals")
def goals_run(fleet: Fleet) -> Iterator[Goals]:
    """rh1's drive in goal mode (``invent drive --goals --robot rh1``), started once the teleop tests
    before are done (a goal-mode drive commands zero between goals, which twists would fight)."""
    with InventProcess("drive", "--goals", "--robot", GOAL_ROBOT, "--connect", fleet.endpoint, drain=True) as drive:
        wait_alive(fleet.session, Keys(GOAL_ROBOT).alive(Service.DRIVE), STARTUP_TIMEOUT_S)
        # the drive's queryable reaches the bridge's session asynchronously: a goal before it is refused
        wait_until(
            lambda: fleet.status(GOAL_ROBOT, Service.ROS2)["navigate"]["drive_serves_goals"],
            STARTUP_TIMEOUT_S,
            "rh1's bridge to see the drive's goal queryable",
        )
        yield Goals(fleet, ros_services.ActionClient(fleet.session, GOAL_ACTION), drive)
        code, _out, err = drive.stop()
    assert code == 0, err[-3000:]
