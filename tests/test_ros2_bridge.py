"""``invent ros2`` against a client speaking rmw_zenoh's wire format (tests/ros_client.py, written
apart from the bridge): the graph's tokens, every sample decoded with rosbags, the attachments,
latched topics for a late subscriber, ``/cmd_vel`` moving the robot and ``/motor/stop`` stopping
it, bad input counted and never moving the robot (tests/test_ros2_clock.py: a lockstep run's
``/clock`` and stamps).

One ``invent up --ros2 --teleop`` (realtime, no scenario) serves the tests.
"""

from __future__ import annotations

import math
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh
import zenoh.ext

from schemas.codec import decode
from schemas.keys import Keys, Service
from schemas.messages import TimedPosition
from tests import ros_client, ros_services
from tests.harness import (
    at_rest,
    call,
    invent_command,
    peer_session,
    running_router,
    status_reply,
    wait_alive,
    wait_until,
)

pytestmark = pytest.mark.slow

KEYS = Keys()
DOMAIN = 0
PUBLISHED = {
    "clock": ("rosgraph_msgs/msg/Clock", "2::,1:,:,:,,"),
    "odom": ("nav_msgs/msg/Odometry", "::,10:,:,:,,"),
    "tf": ("tf2_msgs/msg/TFMessage", "::,100:,:,:,,"),
    "tf_static": ("tf2_msgs/msg/TFMessage", ":1:,1:,:,:,,"),
    "joint_states": ("sensor_msgs/msg/JointState", "::,10:,:,:,,"),
    "robot_description": ("std_msgs/msg/String", ":1:,1:,:,:,,"),
    "scan": ("sensor_msgs/msg/LaserScan", "2::,5:,:,:,,"),
    "imu": ("sensor_msgs/msg/Imu", "2::,5:,:,:,,"),
}
"""Topic (relative, no namespace) -> (type, QoS chunk of its token), as rmw_zenoh writes them."""
SUBSCRIBED = {
    ("cmd_vel", "geometry_msgs/msg/Twist"),
    ("cmd_vel", "geometry_msgs/msg/TwistStamped"),
    ("goal_pose", "geometry_msgs/msg/PoseStamped"),
}
SERVICES = ("motor/stop", "motor/clear", "motor/start", "motor/finish")
ODOMETRY_SERVICES = {
    "invent_bridge/reset_odometry": "std_srvs/srv/Empty",
    "invent_bridge/set_odometry": "control_msgs/srv/SetOdometry",
}
"""ros2_controllers' odometry services, private names of the node (tests/test_ros2_odometry_services.py)."""
ACTION = {
    "send_goal": ("SS", "::,10:,:,:,,"),
    "cancel_goal": ("SS", "::,10:,:,:,,"),
    "get_result": ("SS", "::,10:,:,:,,"),
    "feedback": ("MP", "::,10:,:,:,,"),
    "status": ("MP", ":1:,1:,:,:,,"),
}
"""The NavigateToPose action's endpoints (``navigate_to_pose/_action/<endpoint>``), their kinds and
QoS: rcl_action's, the status reliable and transient-local, depth 1 (the action at work:
tests/test_ros2_fleet.py)."""
STARTUP_TIMEOUT_S = 60.0


@dataclass
class Loop:
    endpoint: str
    session: zenoh.Session
    recorder: ros_client.Recorder
    up: subprocess.Popen[str]
    output: Path

    def status(self, service: Service) -> dict[str, Any]:
        return status_reply(self.session, KEYS, service)

    def ground_truth(self) -> tuple[float, float, float]:
        """The simulated body's (x, y, yaw) now."""
        pose = self.status(Service.SIM)["pose"]
        return pose["x"], pose["y"], pose["theta"]


@pytest.fixture(scope="module")
def teleop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Loop]:
    """``invent up --ros2 --teleop`` on a router of the module's own, its ROS samples recorded from
    before the bridge starts (so each publisher's first sample is seen)."""
    directory = tmp_path_factory.mktemp("teleop")
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        output = directory / "up.log"
        with output.open("w") as log:
            up = subprocess.Popen(
                invent_command("up", "--ros2", "--teleop", "--connect", endpoint),
                cwd=directory,
                stdout=log,
                stderr=subprocess.STDOUT,
                text=True,
            )
            loop = Loop(endpoint, session, recorder, up, output)
            try:
                wait_alive(session, KEYS.alive(Service.ROS2), STARTUP_TIMEOUT_S)
                wait_alive(session, KEYS.alive(Service.SIM), STARTUP_TIMEOUT_S)
                wait_until(lambda: loop.recorder.of("odom"), STARTUP_TIMEOUT_S, "the first /odom")
                yield loop
            finally:
                up.send_signal(2)
                try:
                    up.wait(60)
                except subprocess.TimeoutExpired:
                    up.kill()
                recorder.close()
    assert up.returncode == 0, output.read_text()[-3000:]


def test_a_realtime_run_composes_its_sim_and_motor_in_one_control_process(teleop):
    """``invent up`` in realtime (here --teleop) starts ``invent control``, not a sim and a motor
    apart (docs/realtime.md): one child, whose own status carries both services' statuses."""
    ok, status = call(teleop.session, KEYS.control_status)
    assert ok, status
    assert set(status["services"]) == {str(Service.MOTOR), str(Service.SIM)}, status
    assert status["state"] == teleop.status(Service.MOTOR)["state"]
    log = teleop.output.read_text()
    assert "started control (pid" in log and "started sim (pid" not in log and "started motor (pid" not in log


def test_the_graph_shows_one_node_with_its_publishers_subscriptions_and_services(teleop):
    bridge = teleop.status(Service.ROS2)
    entities = len(PUBLISHED) + len(SUBSCRIBED) + len(SERVICES) + len(ODOMETRY_SERVICES) + len(ACTION)
    tokens = wait_until(
        lambda: (found := ros_client.graph_tokens(teleop.session, DOMAIN)) and len(found) > entities and found,
        10.0,
        "tokens",
    )
    assert {chunks[2] for chunks in tokens} == {bridge["zid"]}, "every entity of the bridge's session"
    (node,) = [chunks for chunks in tokens if chunks[5] == "NN"]
    assert node == ["@ros2_lv", str(DOMAIN), bridge["zid"], "0", "0", "NN", "%", "%", "invent_bridge"]
    entities = [chunks for chunks in tokens if chunks[5] != "NN"]
    assert all(len(chunks) == 13 and chunks[3] == "0" and chunks[6:9] == node[6:] for chunks in entities)
    ids = [int(chunks[4]) for chunks in entities]
    assert len(set(ids)) == len(ids) and min(ids) == 1, "one id per entity, after the node's own"
    by_kind: dict[str, set[tuple[str, ...]]] = {}
    for chunks in entities:
        by_kind.setdefault(chunks[5], set()).add((chunks[9], chunks[10], chunks[11], chunks[12]))
    expected_publishers = {
        (f"%{topic}", *ros_client.key_type(interface).split("/"), qos) for topic, (interface, qos) in PUBLISHED.items()
    }
    action = {
        kind: {
            (
                f"%navigate_to_pose%_action%{endpoint}",
                *ros_services.action_key_type(ros_services.ACTION_ENDPOINTS[endpoint]).split("/"),
                qos,
            )
            for endpoint, (endpoint_kind, qos) in ACTION.items()
            if endpoint_kind == kind
        }
        for kind in ("MP", "SS")
    }
    assert by_kind["MP"] == expected_publishers | action["MP"]
    assert by_kind["MS"] == {
        (f"%{topic}", *ros_client.key_type(interface).split("/"), "::,10:,:,:,,") for topic, interface in SUBSCRIBED
    }
    assert (
        by_kind["SS"]
        == {
            ("%" + service.replace("/", "%"), *ros_client.TRIGGER_KEY_TYPE.split("/"), "::,10:,:,:,,")
            for service in SERVICES
        }
        | {
            (
                "%" + service.replace("/", "%"),
                *ros_services.odometry_service_key_type(interface).split("/"),
                "::,10:,:,:,,",
            )
            for service, interface in ODOMETRY_SERVICES.items()
        }
        | action["SS"]
    )
    assert set(by_kind) == {"MP", "MS", "SS"}


def test_every_sample_decodes_with_rosbags_and_carries_rmw_zenohs_attachment(teleop):
    # every topic at least once (/scan comes at 10 Hz, later than the first 20 /joint_states on a loaded machine)
    wait_until(
        lambda: len(teleop.recorder.of("joint_states")) >= 20 and all(teleop.recorder.of(topic) for topic in PUBLISHED),
        30.0,
        "20 /joint_states and every published topic",
    )
    samples = teleop.recorder.take()
    by_key: dict[str, list[ros_client.Received]] = {}
    for sample in samples:
        by_key.setdefault(sample.key, []).append(sample)
    published_keys = {
        ros_client.topic_key(DOMAIN, topic, interface): topic for topic, (interface, _) in PUBLISHED.items()
    }
    assert set(by_key) == set(published_keys), "each sample on its topic's key, with rosbags' type hash"
    gids = set()
    for key, received in by_key.items():
        interface = PUBLISHED[published_keys[key]][0]
        for sample in received:
            ros_client.TYPESTORE.deserialize_cdr(sample.payload, interface)
            assert sample.attachment is not None and len(sample.attachment) == 33, key
        attachments = [ros_client.read_attachment(sample.attachment) for sample in received]  # type: ignore[arg-type]
        numbers = [number for number, _stamp, _gid in attachments]
        assert numbers == list(range(1, len(numbers) + 1)), f"{key}: sequence numbers from 1, +1 per sample"
        assert len({gid for _n, _s, gid in attachments}) == 1 and len(attachments[0][2]) == 16, key
        assert all(abs(stamp - sample.received_ns) < 60e9 for (_n, stamp, _g), sample in zip(attachments, received))
        gids.add(attachments[0][2])
    assert len(gids) == len(by_key), "one GID per publisher"
    description = ros_client.TYPESTORE.deserialize_cdr(
        by_key[_key("robot_description")][0].payload, PUBLISHED["robot_description"][0]
    )
    assert description.data.startswith("<?xml") and 'name="base_link"' in description.data
    (static,) = [
        ros_client.TYPESTORE.deserialize_cdr(s.payload, PUBLISHED["tf_static"][0]) for s in by_key[_key("tf_static")]
    ]
    assert {t.child_frame_id for t in static.transforms} == {"front_caster", "rear_caster", "base_scan", "imu_link"}
    tf = ros_client.TYPESTORE.deserialize_cdr(by_key[_key("tf")][-1].payload, PUBLISHED["tf"][0])
    pairs = {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}
    assert {("odom", "base_link"), ("map", "odom"), ("base_link", "left_wheel"), ("base_link", "right_wheel")} <= pairs


def _key(topic: str) -> str:
    return ros_client.topic_key(DOMAIN, topic, PUBLISHED[topic][0])


def test_a_late_subscriber_gets_the_latched_topics(teleop):
    """Transient-local as rmw_zenoh does it: an advanced subscriber with history, declared long
    after the only sample, still gets it from the publisher's cache."""
    received: list[bytes] = []
    subscribers = [
        zenoh.ext.declare_advanced_subscriber(
            teleop.session,
            _key(topic),
            lambda sample: received.append(sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )
        for topic in ("robot_description", "tf_static")
    ]
    try:
        wait_until(lambda: len(received) >= 2, 10.0, "the cached /robot_description and /tf_static")
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
    texts = [payload for payload in received if b"<?xml" in payload]
    assert texts and b"left_wheel_joint" in texts[0]


def _drive(loop: Loop, node: ros_client.RosNode, value: Any, seconds: float) -> None:
    """Publish ``value`` on /cmd_vel at 20 Hz for ``seconds`` of wall time (teleop is realtime)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        node.put("cmd_vel", value)
        time.sleep(0.05)


def test_cmd_vel_moves_the_robot_and_the_stop_service_stops_it(teleop):
    node = ros_client.RosNode(teleop.session)
    start = teleop.ground_truth()
    _drive(teleop, node, ros_client.twist(0.3, 0.0), 2.0)
    forward = teleop.ground_truth()
    heading = start[2]
    travelled = (forward[0] - start[0]) * math.cos(heading) + (forward[1] - start[1]) * math.sin(heading)
    assert travelled > 0.25, f"Twist 0.3 m/s for 2 s: {travelled:.3f} m forward"
    _drive(teleop, node, ros_client.twist(0.0, 0.6, stamped=True), 2.0)
    turned = teleop.ground_truth()
    assert math.remainder(turned[2] - forward[2], math.tau) > 0.6, "TwistStamped 0.6 rad/s for 2 s turns left"
    odometry = decode(TimedPosition, call_latest(teleop, KEYS.odometry_pose))
    assert math.hypot(odometry.x - turned[0], odometry.y - turned[1]) < 0.05, "odometry follows the ground truth"
    odom = ros_client.TYPESTORE.deserialize_cdr(teleop.recorder.of("odom")[-1].payload, PUBLISHED["odom"][0])
    assert odom.pose.pose.position.x > 0.25

    answer = node.call_trigger("/motor/stop")
    assert answer is not None, "the stop service answers"
    (success, message), (sequence_number, _stamp, gid), sent = answer
    assert success and "stopped" in message
    assert (sequence_number, gid) == (sent, node.gid), "the reply echoes the request's sequence number and GID"
    assert teleop.status(Service.MOTOR)["state"] == "stopped"
    stopped = wait_until(lambda: at_rest(teleop.ground_truth), 10.0, "the robot at rest")
    _drive(teleop, node, ros_client.twist(0.3, 0.0), 1.0)
    still = teleop.ground_truth()
    assert math.hypot(still[0] - stopped[0], still[1] - stopped[1]) < 0.01, "a stopped robot stays stopped"
    assert teleop.status(Service.MOTOR)["state"] == "stopped"
    cleared = node.call_trigger("/motor/clear")
    assert cleared is not None and cleared[0][0]
    assert teleop.status(Service.ROS2)["service_calls"]["answered"] >= 2


def _bad_input_entry(loop: Loop, key: str) -> dict[str, Any] | None:
    return loop.status(Service.ROS2)["bad_input"]["by_key"].get(key)


def _bad_inputs(loop: Loop, key: str) -> int:
    entry = _bad_input_entry(loop, key)
    return entry["count"] if entry else 0


def call_latest(loop: Loop, key: str) -> bytes:
    """The next sample of ``key``."""
    received: list[bytes] = []
    subscriber = loop.session.declare_subscriber(key, lambda sample: received.append(sample.payload.to_bytes()))
    try:
        wait_until(lambda: received, 10.0, key)
    finally:
        subscriber.undeclare()
    return received[0]


def test_bad_input_on_cmd_vel_and_the_services_is_counted_and_moves_nothing(teleop):
    node = ros_client.RosNode(teleop.session)
    twist_key = ros_client.topic_key(DOMAIN, "cmd_vel", "geometry_msgs/msg/Twist")
    stamped_key = ros_client.topic_key(DOMAIN, "cmd_vel", "geometry_msgs/msg/TwistStamped")
    before = teleop.status(Service.ROS2)
    motor_before = teleop.status(Service.MOTOR)["counters"]["target_velocity_samples"]
    good = ros_client.cdr(ros_client.twist(0.3, 0.0))
    nan = ros_client.cdr(ros_client.twist(math.nan, 0.0))
    implausible = ros_client.cdr(ros_client.twist(1000.0, 0.0))
    forgeries = [
        (twist_key, b"\x00\x01\x00\x00\x01\x02", ros_client.attachment(1, node.gid), "malformed CDR"),
        (twist_key, b"not cdr at all", ros_client.attachment(2, node.gid), "malformed CDR"),
        (twist_key, good, ros_client.attachment(3, node.gid)[:-1], "attachment of 32 bytes"),
        (twist_key, good, ros_client.attachment(4, node.gid) + b"\x00", "attachment of 34 bytes"),
        (twist_key, good, None, "no attachment"),  # a plain zenoh put
        (twist_key, nan, ros_client.attachment(5, node.gid), "not finite"),
        (twist_key, implausible, ros_client.attachment(6, node.gid), "max_wheel_speed"),
        (stamped_key, good, ros_client.attachment(7, node.gid), "malformed CDR"),  # a Twist on the TwistStamped key
        (twist_key, good + bytes(5000), ros_client.attachment(8, node.gid), "more than a twist's"),
    ]
    for key, payload, attachment_bytes, reason in forgeries:
        counted = _bad_inputs(teleop, key)
        node.put_raw(key, payload, attachment_bytes)
        entry = wait_until(
            lambda key=key, counted=counted: (e := _bad_input_entry(teleop, key)) and e["count"] > counted and e,
            10.0,
            reason,
        )
        assert reason in entry["last_reason"], entry
    status = teleop.status(Service.ROS2)
    assert status["cmd_vel"]["forwarded"] == before["cmd_vel"]["forwarded"], "no forgery became a target"
    assert teleop.status(Service.MOTOR)["counters"]["target_velocity_samples"] == motor_before

    # A Trigger call without an attachment: counted, unanswered, nothing done.
    stop_key = f"{DOMAIN}/motor/stop/{ros_client.TRIGGER_KEY_TYPE}"
    replies = list(teleop.session.get(stop_key, payload=ros_client.TRIGGER_REQUEST, timeout=1.0))
    assert not [reply for reply in replies if reply.ok is not None]
    assert teleop.status(Service.MOTOR)["state"] != "stopped"
    wait_until(lambda: stop_key in teleop.status(Service.ROS2)["bad_input"]["by_key"], 10.0, "the call counted")

    # A flood: at most cmd_vel_rate targets per simulated second, the rest coalesced and counted.
    started = teleop.status(Service.ROS2)
    flood = 2000
    for _ in range(flood):
        node.put("cmd_vel", ros_client.twist(0.0, 0.0))
    # The ring channel holds 256: a bridge slower than the flood takes at least that many.
    flooded = wait_until(
        lambda: (
            (status := teleop.status(Service.ROS2))["cmd_vel"]["received"] - started["cmd_vel"]["received"] >= 256
            and status
        ),
        20.0,
        "the flood taken",
    )
    received, forwarded, coalesced = (
        flooded["cmd_vel"][name] - started["cmd_vel"][name] for name in ("received", "forwarded", "coalesced")
    )
    assert abs(received - forwarded - coalesced) <= 1, "each twist forwarded or coalesced (but one pending)"
    assert coalesced > forwarded > 0 and flooded["internal_errors"] == 0
