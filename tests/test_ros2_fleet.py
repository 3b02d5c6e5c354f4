"""A fleet in ROS 2, end to end, against the ROS node's side written apart from the bridge
(tests/ros_client.py): ``invent up --fleet FILE --ros2 --teleop``, two robots, each robot's bridge
its own process, the test a ROS node (a peer of the run's router). Every robot's topics, services and tokens are under its namespace (``rh0`` by default,
``robot1`` set in the fleet file), ``/clock`` once; a twist on the second robot's ``cmd_vel`` moves
it and not the first; the first robot's ``motor/stop`` stops only it; each namespace's
``robot_description`` reaches a late transient-local subscriber; malformed CDR on a namespaced
``cmd_vel`` is counted and the bridge lives on; ``invent record --ros2 --fleet`` records the graph
into a bag. One fleet run serves every test of the module. (What each robot's bridge may do with
its robot's credentials in a secure fleet is tests/test_security_fleet.py's.)
"""

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
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from schemas.keys import Keys, Service
from tests import ros_client
from tests.harness import (
    REPO,
    InventProcess,
    call,
    free_port,
    invent_command,
    peer_session,
    run_invent,
    running_router,
    wait_alive,
    wait_until,
)

pytestmark = pytest.mark.slow

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
CLOCK = ("/clock", "rosgraph_msgs/msg/Clock")
SUBSCRIBED = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")
SERVICES = ("motor/stop", "motor/clear", "motor/start", "motor/finish")
GOAL_POSE = ("goal_pose", "geometry_msgs/msg/PoseStamped")
ACTION = {"send_goal": "SS", "cancel_goal": "SS", "get_result": "SS", "feedback": "MP", "status": "MP"}
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


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    """The two-robot fleet in teleop, each service its own process; the test's session a ROS node's
    peer session, its domain's samples recorded from before the bridges start."""
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


def _mangled(name: str) -> str:
    return name.replace("/", "%")


def test_each_robot_is_a_node_in_its_namespace_with_its_topics_services_and_types_and_one_clock(fleet):
    per_node = len(PUBLISHED) + len(SUBSCRIBED) + 1 + len(SERVICES) + len(ACTION) + 1
    tokens = wait_until(
        lambda: (found := ros_client.graph_tokens(fleet.session, DOMAIN)) and len(found) >= 2 * per_node + 1 and found,
        10.0,
        "the tokens",
    )
    nodes = {chunks[7]: chunks for chunks in tokens if chunks[5] == "NN"}
    assert set(nodes) == {_mangled(ns) for ns in NAMESPACES.values()}
    assert all(node[8] == "invent_bridge" for node in nodes.values())
    entities: dict[str, set[tuple[str, str, str]]] = {}
    for chunks in tokens:
        if chunks[5] != "NN":
            entities.setdefault(chunks[7], set()).add((chunks[5], chunks[9], "/".join(chunks[10:12])))
    clock = ("MP", _mangled(CLOCK[0]), ros_client.key_type(CLOCK[1]))
    for robot, namespace in NAMESPACES.items():
        expected = {("MP", _mangled(f"{namespace}/{t}"), ros_client.key_type(i)) for t, i in PUBLISHED.items()}
        expected |= {("MS", _mangled(f"{namespace}/cmd_vel"), ros_client.key_type(i)) for i in SUBSCRIBED}
        expected |= {("SS", _mangled(f"{namespace}/{s}"), ros_client.TRIGGER_KEY_TYPE) for s in SERVICES}
        expected.add(("MS", _mangled(f"{namespace}/{GOAL_POSE[0]}"), ros_client.key_type(GOAL_POSE[1])))
        expected |= {
            (
                kind,
                _mangled(f"{namespace}/navigate_to_pose/_action/{endpoint}"),
                ros_client.action_key_type(ros_client.ACTION_ENDPOINTS[endpoint]),
            )
            for endpoint, kind in ACTION.items()
        }
        expected |= {clock} if robot == "rh0" else set()
        assert entities[_mangled(namespace)] == expected, robot

    topics = {ros_client.topic_key(DOMAIN, f"{ns}/{t}", i) for ns in NAMESPACES.values() for t, i in PUBLISHED.items()}
    topics.add(ros_client.topic_key(DOMAIN, *CLOCK))
    try:
        keys = wait_until(lambda: (seen := {sample.key for sample in fleet.recorder.take()}) >= topics and seen, 10.0)
    except AssertionError:
        raise AssertionError(f"missing {topics - {sample.key for sample in fleet.recorder.take()}}") from None
    assert keys == topics, "every sample on a namespaced topic, or /clock"
    by_topic = {(ns, topic): fleet.recorder.of(f"{ns}/{topic}") for ns in NAMESPACES.values() for topic in PUBLISHED}
    for (namespace, topic), received in by_topic.items():
        for sample in received:
            ros_client.TYPESTORE.deserialize_cdr(sample.payload, PUBLISHED[topic])
    for namespace in NAMESPACES.values():
        tf = ros_client.TYPESTORE.deserialize_cdr(by_topic[(namespace, "tf")][-1].payload, PUBLISHED["tf"])
        assert ("odom", "base_link") in {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}, (
            "in its own namespace's tf, a robot's frames are named as Nav2 expects them, unprefixed"
        )


def _shipped_hash(name: str) -> str:
    """The RIHS01 hash in the type description ROS ships for ``name`` (tests/data/ros2_interfaces)."""
    package, _msg, type_name = name.split("/")
    description = json.loads((SHIPPED / package / "msg" / f"{type_name}.json").read_text())
    return next(e["hash_string"] for e in description["type_hashes"] if e["type_name"] == name)


def test_each_robots_scan_and_imu_decode_with_ross_hashes_and_their_frames_are_in_its_tf_tree(fleet):
    """The simulator's lidar and IMU through each robot's bridge: ``/<ns>/scan`` and ``/<ns>/imu``
    on keys with the hashes ROS ships, decoded; ``base_scan`` and ``imu_link`` reach ``map`` through
    the robot's ``tf_static`` (from the bridge's cache, as a late tf2 listener gets it) and ``tf``."""
    for namespace in NAMESPACES.values():
        wait_until(lambda n=namespace: len(fleet.recorder.of(f"{n}/scan")) >= 3, 10.0, f"{namespace}/scan")
    with peer_session(fleet.endpoint) as session:
        topics = {f"{namespace}/tf_static": PUBLISHED["tf_static"] for namespace in NAMESPACES.values()}
        late = ros_client.cached_samples(session, DOMAIN, topics, 20.0)
    for robot, namespace in NAMESPACES.items():
        for topic in ("scan", "imu"):
            (key,) = {sample.key for sample in fleet.recorder.of(f"{namespace}/{topic}")}
            assert key.endswith(f"_/{_shipped_hash(PUBLISHED[topic])}"), key
        scan = ros_client.TYPESTORE.deserialize_cdr(
            fleet.recorder.of(f"{namespace}/scan")[-1].payload, PUBLISHED["scan"]
        )
        assert scan.header.frame_id == "base_scan" and len(scan.ranges) == 360 and len(scan.intensities) == 0
        assert (scan.range_max, scan.scan_time) == (3.5, pytest.approx(0.1))
        assert all(math.isinf(r) or 0.0 <= r < 3.5 for r in scan.ranges), robot
        imu = ros_client.TYPESTORE.deserialize_cdr(fleet.recorder.of(f"{namespace}/imu")[-1].payload, PUBLISHED["imu"])
        assert imu.header.frame_id == "imu_link" and imu.linear_acceleration.z == pytest.approx(9.81, abs=0.5)
        assert imu.orientation_covariance[0] > 0, "the simulator's orientation, flagged as known"
        parents = {}
        static = ros_client.TYPESTORE.deserialize_cdr(late[f"{namespace}/tf_static"], PUBLISHED["tf_static"])
        tf = ros_client.TYPESTORE.deserialize_cdr(fleet.recorder.of(f"{namespace}/tf")[-1].payload, PUBLISHED["tf"])
        for transform in (*static.transforms, *tf.transforms):
            parents[transform.child_frame_id] = transform.header.frame_id
        for frame in ("base_scan", "imu_link"):
            chain = [frame]
            while chain[-1] in parents:
                chain.append(parents[chain[-1]])
            assert chain == [frame, "base_link", "odom", "map"], (robot, chain)


def _drive(fleet: Fleet, namespace: str, vx: float, seconds: float) -> None:
    """Twists at 20 Hz on ``namespace``'s cmd_vel for ``seconds`` of wall time (teleop is realtime)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        fleet.node.put(f"{namespace}/cmd_vel", ros_client.twist(vx, 0.0))
        time.sleep(0.05)


def _moved(before: tuple[float, float], after: tuple[float, float]) -> float:
    return math.hypot(after[0] - before[0], after[1] - before[1])


def test_a_twist_on_the_second_robots_cmd_vel_moves_it_and_not_the_first(fleet):
    before = {robot: fleet.position(robot) for robot in NAMESPACES}
    _drive(fleet, NAMESPACES["rh1"], 0.3, 1.5)
    after = {robot: fleet.position(robot) for robot in NAMESPACES}
    assert _moved(before["rh1"], after["rh1"]) > 0.2, "rh1 follows /robot1/cmd_vel"
    assert _moved(before["rh0"], after["rh0"]) < 0.005, "rh0 does not"
    assert fleet.status("rh1", Service.ROS2)["cmd_vel"]["forwarded"] > 0
    assert fleet.status("rh0", Service.ROS2)["cmd_vel"]["received"] == 0


def test_the_first_robots_motor_stop_stops_only_it(fleet):
    answer = fleet.node.call_trigger(f"{NAMESPACES['rh0']}/motor/stop")
    assert answer is not None
    (success, message), _attachment, _sequence = answer
    assert success and "stopped" in message
    assert fleet.status("rh0", Service.MOTOR)["state"] == "stopped"
    assert fleet.status("rh1", Service.MOTOR)["state"] != "stopped"
    before = {robot: fleet.position(robot) for robot in NAMESPACES}
    for _ in range(20):
        for namespace in NAMESPACES.values():
            fleet.node.put(f"{namespace}/cmd_vel", ros_client.twist(0.3, 0.0))
        time.sleep(0.05)
    after = {robot: fleet.position(robot) for robot in NAMESPACES}
    assert _moved(before["rh0"], after["rh0"]) < 0.005, "the stopped robot ignores its twists"
    assert _moved(before["rh1"], after["rh1"]) > 0.1, "the other robot still follows its own"
    cleared = fleet.node.call_trigger(f"{NAMESPACES['rh0']}/motor/clear")
    assert cleared is not None and cleared[0][0]
    assert fleet.status("rh0", Service.MOTOR)["state"] != "stopped"


def test_each_namespaces_robot_description_reaches_a_late_transient_local_subscriber(fleet):
    """A ROS node started long after the bridges published their only robot_description (a session
    of its own) subscribes as rmw_zenoh's transient-local subscriptions do, and gets each from the
    bridge's cache."""
    topics = {f"{namespace}/robot_description": PUBLISHED["robot_description"] for namespace in NAMESPACES.values()}
    with peer_session(fleet.endpoint) as late:
        received = ros_client.cached_samples(late, DOMAIN, topics, 20.0)
    for topic, payload in received.items():
        urdf = ros_client.TYPESTORE.deserialize_cdr(payload, PUBLISHED["robot_description"]).data
        assert urdf.startswith("<?xml") and "left_wheel_joint" in urdf, topic


def test_malformed_cdr_on_a_namespaced_cmd_vel_is_bad_input_counted_and_the_bridge_lives_on(fleet):
    key = ros_client.topic_key(DOMAIN, f"{NAMESPACES['rh1']}/cmd_vel", "geometry_msgs/msg/Twist")
    motor_before = fleet.status("rh1", Service.MOTOR)["counters"]["target_velocity_samples"]
    forwarded = fleet.status("rh1", Service.ROS2)["cmd_vel"]["forwarded"]
    fleet.node.put_raw(key, b"\x00\x01\x00\x00\x01\x02", ros_client.attachment(1, fleet.node.gid))
    entry = wait_until(
        lambda: fleet.status("rh1", Service.ROS2)["bad_input"]["by_key"].get(key), 10.0, "the malformed twist counted"
    )
    assert entry["count"] == 1 and "malformed CDR" in entry["last_reason"]
    status = fleet.status("rh1", Service.ROS2)
    assert status["cmd_vel"]["forwarded"] == forwarded and status["internal_errors"] == 0
    assert fleet.status("rh1", Service.MOTOR)["counters"]["target_velocity_samples"] == motor_before
    before = fleet.position("rh1")
    _drive(fleet, NAMESPACES["rh1"], 0.3, 1.0)
    assert _moved(before, fleet.position("rh1")) > 0.1, "the bridge lives on: the next good twist moves the robot"
    assert key not in fleet.status("rh0", Service.ROS2)["bad_input"]["by_key"], "rh0's bridge never saw it"


def test_invent_record_ros2_records_the_fleets_graph_into_a_bag(fleet):
    bag = fleet.directory / "recorded"
    fleet_file = str(fleet.directory / "fleet.toml")
    result = run_invent(
        "record",
        "--ros2",
        "--fleet",
        fleet_file,
        "-o",
        str(bag),
        "--duration",
        "2",
        "--connect",
        fleet.endpoint,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    expected = {CLOCK[0]: CLOCK[1]} | {
        f"{namespace}/{topic}": interface for namespace in NAMESPACES.values() for topic, interface in PUBLISHED.items()
    }
    with Reader(bag) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == expected
        counts = {c.topic: c.msgcount for c in reader.connections}
        times: dict[str, list[int]] = {}
        clocks = []
        for connection, timestamp, raw in reader.messages():
            times.setdefault(connection.topic, []).append(timestamp)
            if connection.topic == CLOCK[0]:
                clock = ros_client.TYPESTORE.deserialize_cdr(raw, connection.msgtype).clock
                clocks.append(clock.sec * 1_000_000_000 + clock.nanosec)
    assert all(counts[f"{namespace}/{t}"] == 1 for namespace in NAMESPACES.values() for t in ("tf_static",))
    assert all(counts[f"{namespace}/robot_description"] == 1 for namespace in NAMESPACES.values()), (
        "the latched topics, from the bridges' caches though they were published long before"
    )
    assert clocks == times[CLOCK[0]], "each message at the simulation time it carries"
    assert clocks == sorted(clocks) and len(set(clocks)) == len(clocks), "/clock monotonic"
    assert (clocks[-1] - clocks[0]) / 1e9 > 1.0, "the graph recorded for a while (3 s of wall time, realtime)"
    rates = {CLOCK[0]: 100.0} | {f"{n}/{t}": 50.0 for n in NAMESPACES.values() for t in ("odom", "tf", "joint_states")}
    rates |= {f"{n}/{t}": rate for n in NAMESPACES.values() for t, rate in (("scan", 10.0), ("imu", 100.0))}
    for topic, rate_hz in rates.items():
        stamps = times[topic]
        assert abs(len(stamps) - (rate_hz * (stamps[-1] - stamps[0]) / 1e9 + 1)) <= 1, (
            f"{topic}: every message at {rate_hz:g} per simulated second over the time it was recorded"
        )
    decoded = 0
    for path in sorted(bag.glob("*.mcap")):
        with path.open("rb") as file:
            for _schema, _channel, _message, _ros in make_reader(
                file, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages():
                decoded += 1
    assert decoded == sum(counts.values())


def test_a_navigate_to_pose_goal_to_the_second_robot_moves_only_it(fleet):
    """Each robot's action server under its namespace sends goals to its own robot's drive: rh1's
    drive in goal mode (``invent drive --goals --robot rh1``, started here: a goal-mode drive
    commands zero between goals, which the teleop tests before would fight), a goal on
    ``/robot1/navigate_to_pose`` reached and SUCCEEDED, rh0 unmoved; rh0's action, whose robot has
    no goal-mode drive, refuses a goal (nothing reaches rh1's drive)."""
    with InventProcess("drive", "--goals", "--robot", "rh1", "--connect", fleet.endpoint, drain=True) as drive:
        wait_alive(fleet.session, Keys("rh1").alive(Service.DRIVE), STARTUP_TIMEOUT_S)
        start = fleet.status("rh1", Service.SIM)["pose"]
        before = {robot: fleet.position(robot) for robot in NAMESPACES}
        x, y, theta = start["x"] + 0.6 * math.cos(start["theta"]), start["y"] + 0.6 * math.sin(start["theta"]), 0.8
        client = ros_client.ActionClient(fleet.session, f"{NAMESPACES['rh1']}/navigate_to_pose")
        goal, reply = client.send_goal(x, y, theta)
        assert reply.response.accepted
        result = client.get_result(goal, timeout=60.0)
        assert result.response.status == 4, result.response
        after = {robot: fleet.position(robot) for robot in NAMESPACES}
        assert math.hypot(after["rh1"][0] - x, after["rh1"][1] - y) <= 0.05, "rh1 at its goal"
        assert _moved(before["rh0"], after["rh0"]) < 0.005, "rh0 did not move"
        other = ros_client.ActionClient(fleet.session, f"{NAMESPACES['rh0']}/navigate_to_pose")
        _goal, refused = other.send_goal(*after["rh0"], 0.0)
        assert not refused.response.accepted
        assert "no drive answered" in fleet.status("rh0", Service.ROS2)["navigate"]["last_rejection"]
        assert fleet.status("rh1", Service.DRIVE)["goals"]["accepted"] == 1, "rh1's drive got one goal, rh1's"
        code, _out, err = drive.stop()
    assert code == 0, err[-3000:]


def test_invent_ros2_fleet_runs_a_node_per_robot_on_one_session_each_with_ids_of_its_own(tmp_path):
    """``invent ros2 --fleet FILE``: one process, one session, a node per robot in its namespace,
    their nodes' and entities' ids drawn from one counter (rmw_zenoh's graph keys a node by its
    session and id), ``/clock`` from the first robot's only."""
    (tmp_path / "fleet.toml").write_text(FLEET)
    with running_router() as endpoint, peer_session(endpoint) as session:
        with InventProcess("ros2", "--fleet", str(tmp_path / "fleet.toml"), "--connect", endpoint) as bridges:
            per_node = len(PUBLISHED) + len(SUBSCRIBED) + 1 + len(SERVICES) + len(ACTION) + 1
            tokens = wait_until(
                lambda: (
                    (found := ros_client.graph_tokens(session, DOMAIN)) and len(found) == 2 * per_node + 1 and found
                ),
                30.0,
                "the tokens",
            )
            code, _out, err = bridges.stop()
        assert code == 0, err
    assert len({chunks[2] for chunks in tokens}) == 1, "one session"
    nodes = {chunks[7]: int(chunks[3]) for chunks in tokens if chunks[5] == "NN"}
    assert set(nodes) == {_mangled(namespace) for namespace in NAMESPACES.values()}
    ids = [int(chunks[4]) for chunks in tokens]
    assert sorted(ids) == list(range(len(tokens))), "one counter: every node and entity an id of its own"
    for chunks in tokens:
        assert int(chunks[3]) == nodes[chunks[7]], "each entity names its own node's id"
    clocks = [chunks[7] for chunks in tokens if chunks[5] == "MP" and chunks[9] == _mangled(CLOCK[0])]
    assert clocks == [_mangled(NAMESPACES["rh0"])]
