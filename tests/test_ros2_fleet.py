"""A fleet in ROS 2, end to end, against the ROS node's side written apart from the bridge
(tests/ros_client.py): ``invent up --fleet FILE --ros2 --teleop``, two robots, each robot's bridge
its own process, the test a ROS node (a peer of the run's router). Every robot's topics, services and tokens are under its namespace (``rh0`` by default,
``robot1`` set in the fleet file), ``/clock`` once; a twist on the second robot's ``cmd_vel`` moves
it and not the first; the first robot's ``motor/stop`` stops only it; each namespace's
``robot_description`` reaches a late transient-local subscriber; malformed CDR on a namespaced
``cmd_vel`` is counted and the bridge lives on; ``invent record --ros2 --fleet`` records the graph
into a bag. Then, with rh1's drive in goal mode (``invent drive --goals --robot rh1``), each robot's
NavigateToPose action: a goal on ``/robot1/navigate_to_pose`` reached with feedback and SUCCEEDED,
rh0 unmoved (rh0's action refuses goals: its robot has no goal-mode drive); goals canceled by id
and canceled all CANCELED in the status, a preempted one ABORTED (Nav2's); ``/robot1/goal_pose``
in odom; hostile requests refused while a goal runs. One fleet run (tests/ros2_fleet_run.py) serves every test
of the module; what each robot's bridge may do in a secure fleet is tests/test_security_fleet.py's.
"""

from __future__ import annotations

import math
import os
import time

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from schemas.keys import Service
from services.planar import Pose
from services.ros2 import core
from tests import ros_client, ros_services
from tests.harness import InventProcess, at_rest, peer_session, run_invent, running_router, wait_until
from tests.ros2_fleet_run import (  # noqa: F401 (the fixtures fleet and goals)  # what the tests share
    ACTION_ENDPOINTS,
    CLOCK,
    DOMAIN,
    FLEET,
    GOAL_ACTION,
    GOAL_POSE,
    GOAL_ROBOT,
    NAMESPACES,
    PUBLISHED,
    PUBLISHED_ONCE,
    SERVICES,
    STATUS,
    SUBSCRIBED,
    drive,
    fleet_run,
    goals_run,
    mangled,
    moved_by,
    shipped_hash,
)

pytestmark = pytest.mark.slow


def test_each_robot_is_a_node_in_its_namespace_with_its_topics_services_and_types_and_one_clock(fleet):
    per_node = len(PUBLISHED) + len(SUBSCRIBED) + 1 + len(SERVICES) + 2 + len(ACTION_ENDPOINTS) + 1
    tokens = wait_until(
        lambda: (found := ros_client.graph_tokens(fleet.session, DOMAIN)) and len(found) >= 2 * per_node + 1 and found,
        10.0,
        "the tokens",
    )
    nodes = {chunks[7]: chunks for chunks in tokens if chunks[5] == "NN"}
    assert set(nodes) == {mangled(ns) for ns in NAMESPACES.values()}
    assert all(node[8] == "invent_bridge" for node in nodes.values())
    entities: dict[str, set[tuple[str, str, str]]] = {}
    for chunks in tokens:
        if chunks[5] != "NN":
            entities.setdefault(chunks[7], set()).add((chunks[5], chunks[9], "/".join(chunks[10:12])))
    clock = ("MP", mangled(CLOCK[0]), ros_client.key_type(CLOCK[1]))
    for robot, namespace in NAMESPACES.items():
        expected = {("MP", mangled(f"{namespace}/{t}"), ros_client.key_type(i)) for t, i in PUBLISHED.items()}
        expected |= {("MS", mangled(f"{namespace}/cmd_vel"), ros_client.key_type(i)) for i in SUBSCRIBED}
        expected |= {("SS", mangled(f"{namespace}/{s}"), ros_client.TRIGGER_KEY_TYPE) for s in SERVICES}
        expected |= {
            ("SS", mangled(f"{namespace}/invent_bridge/{s}"), ros_services.odometry_service_key_type(i))
            for s, i in (("reset_odometry", "std_srvs/srv/Empty"), ("set_odometry", "control_msgs/srv/SetOdometry"))
        }
        expected.add(("MS", mangled(f"{namespace}/{GOAL_POSE[0]}"), ros_client.key_type(GOAL_POSE[1])))
        expected |= {
            (
                kind,
                mangled(f"{namespace}/navigate_to_pose/_action/{endpoint}"),
                ros_services.action_key_type(ros_services.ACTION_ENDPOINTS[endpoint]),
            )
            for endpoint, kind in ACTION_ENDPOINTS.items()
        }
        expected |= {clock} if robot == "rh0" else set()
        assert entities[mangled(namespace)] == expected, robot

    topics = {ros_client.topic_key(DOMAIN, f"{ns}/{t}", i) for ns in NAMESPACES.values() for t, i in PUBLISHED.items()}
    topics.add(ros_client.topic_key(DOMAIN, *CLOCK))
    live = topics - {ros_client.topic_key(DOMAIN, topic, name) for topic, name in PUBLISHED_ONCE.items()}
    try:
        keys = wait_until(lambda: (seen := {sample.key for sample in fleet.recorder.take()}) >= live and seen, 10.0)
    except AssertionError:
        raise AssertionError(f"missing {live - {sample.key for sample in fleet.recorder.take()}}") from None
    assert keys <= topics, "every sample on a namespaced topic, or /clock"
    for topic, payload in ros_client.cached_samples(fleet.session, DOMAIN, PUBLISHED_ONCE, 20.0).items():
        ros_client.TYPESTORE.deserialize_cdr(payload, PUBLISHED_ONCE[topic])
    by_topic = {(ns, topic): fleet.recorder.of(f"{ns}/{topic}") for ns in NAMESPACES.values() for topic in PUBLISHED}
    for (namespace, topic), received in by_topic.items():
        for sample in received:
            ros_client.TYPESTORE.deserialize_cdr(sample.payload, PUBLISHED[topic])
    for namespace in NAMESPACES.values():
        tf = ros_client.TYPESTORE.deserialize_cdr(by_topic[(namespace, "tf")][-1].payload, PUBLISHED["tf"])
        assert ("odom", "base_link") in {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}, (
            "in its own namespace's tf, a robot's frames are named as Nav2 expects them, unprefixed"
        )


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
            assert key.endswith(f"_/{shipped_hash(PUBLISHED[topic])}"), key
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


def test_a_twist_on_the_second_robots_cmd_vel_moves_it_and_not_the_first(fleet):
    before = {robot: fleet.position(robot) for robot in NAMESPACES}
    drive(fleet, NAMESPACES["rh1"], 0.3, 1.5)
    after = {robot: fleet.position(robot) for robot in NAMESPACES}
    assert moved_by(before["rh1"], after["rh1"]) > 0.2, "rh1 follows /robot1/cmd_vel"
    assert moved_by(before["rh0"], after["rh0"]) < 0.005, "rh0 does not"
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
    assert moved_by(before["rh0"], after["rh0"]) < 0.005, "the stopped robot ignores its twists"
    assert moved_by(before["rh1"], after["rh1"]) > 0.1, "the other robot still follows its own"
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
    drive(fleet, NAMESPACES["rh1"], 0.3, 1.0)
    assert moved_by(before, fleet.position("rh1")) > 0.1, "the bridge lives on: the next good twist moves the robot"
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


# -- goals: each robot's NavigateToPose action and goal_pose, against rh1's drive in goal mode ------


def test_a_navigate_to_pose_goal_to_the_second_robot_is_reached_with_feedback_and_moves_only_it(goals):
    """A ROS client on ``/robot1/navigate_to_pose``: the goal accepted (the reply echoing the request's
    sequence number and GID), feedback in ``map`` while it drives, its plan on ``/robot1/plan``, the
    result SUCCEEDED with rh1 at
    the goal within its tolerances and rh0 unmoved; the status ACCEPTED, EXECUTING, SUCCEEDED, also for
    a late subscriber; rh0's action, whose robot has no goal-mode drive, refuses a goal."""
    fleet = goals.fleet
    rh0_before = goals.ground_truth("rh0")
    x, y, theta = goals.ahead(0.6, turn=0.8)
    uuid, reply = goals.client.send_goal(x, y, theta)
    assert reply.error is None and reply.response.accepted, fleet.status(GOAL_ROBOT, Service.ROS2)["navigate"]
    assert reply.attachment is not None and reply.attachment[0] == reply.sequence_number
    assert reply.attachment[2] == goals.client.gid, "the reply echoes the request's sequence number and GID"
    result = goals.client.get_result(uuid, timeout=60.0)
    assert (result.response.status, result.response.result.error_code) == (4, 0), result.response
    target = goals.started(uuid)
    assert (target["x"], target["y"], target["frame"]) == (pytest.approx(x), pytest.approx(y), "map")
    assert abs(math.remainder(target["theta"] - theta, math.tau)) < 1e-9, "the goal as sent, its heading the yaw"
    assert goals.near(x, y, theta), (goals.ground_truth(), (x, y, theta))
    rh0_after = goals.ground_truth("rh0")
    assert math.hypot(rh0_after.x - rh0_before.x, rh0_after.y - rh0_before.y) < 0.005, "rh0 did not move"
    statuses = goals.wait_status(uuid, 4)
    # ACCEPTED is published only if the drive's reply reaches the bridge before the goal's start
    # (drive/goal): a drive that starts it at its very next tick may win the race, and the goal is
    # EXECUTING first (tests/test_ros2_navigate.py: its events never move a goal back)
    assert statuses[0] in (1, 2) and 2 in statuses and statuses[-1] == 4, "(accepted,) executing, then succeeded"
    feedback = wait_until(lambda: len(goals.feedback(uuid)) >= 5 and goals.feedback(uuid), 10.0, "feedback")
    assert {f.current_pose.header.frame_id for f in feedback} == {"map"}
    times = [f.navigation_time.sec + f.navigation_time.nanosec / 1e9 for f in feedback]
    assert times == sorted(times) and times[-1] > times[0]
    assert feedback[0].distance_remaining > feedback[-1].distance_remaining
    assert all(f.number_of_recoveries == 0 and f.estimated_time_remaining.sec >= 0 for f in feedback)
    last = feedback[-1].current_pose.pose.position
    assert math.hypot(last.x - x, last.y - y) < 0.3, "the robot's pose, in map"
    plans = [
        ros_client.nav_decode(sample.payload, "nav_msgs/msg/Path")
        for sample in fleet.recorder.of(f"{NAMESPACES[GOAL_ROBOT]}/plan")
    ]
    assert plans and plans[0].poses, "the goal's plan on /robot1/plan while it ran (nav_msgs/Path)"
    assert plans[0].header.frame_id == "map" and plans[-1].poses == [], "cleared once the goal ended"
    end = plans[0].poses[-1].pose.position
    assert (end.x, end.y) == (pytest.approx(x), pytest.approx(y)), "the plan ends at the goal"
    navigate = fleet.status(GOAL_ROBOT, Service.ROS2)["navigate"]
    assert navigate["action"] == GOAL_ACTION and navigate["goals"][uuid.hex()] == "succeeded"
    assert fleet.status(GOAL_ROBOT, Service.DRIVE)["goals"]["accepted"] == 1, "rh1's drive got one goal, rh1's"
    with peer_session(fleet.endpoint) as late:  # a node started after the goal ended: the cached status
        cached = ros_client.cached_samples(late, DOMAIN, {STATUS: "action_msgs/msg/GoalStatusArray"}, 10.0)
    assert ros_services.goal_statuses(cached[STATUS])[uuid] == 4

    other = ros_services.ActionClient(fleet.session, f"{NAMESPACES['rh0']}/navigate_to_pose")
    _goal, refused = other.send_goal(rh0_after.x + 0.5, rh0_after.y, 0.0)
    assert not refused.response.accepted
    rh0 = fleet.status("rh0", Service.ROS2)["navigate"]
    assert "no drive answered" in rh0["last_rejection"] and not rh0["drive_serves_goals"]
    assert fleet.status(GOAL_ROBOT, Service.DRIVE)["goals"]["accepted"] == 1, "rh0's goal never reached rh1's drive"


def test_goals_canceled_by_id_and_canceled_all_end_canceled_and_a_preempted_one_aborted(goals):
    second, reply = goals.client.send_goal(*goals.ahead(3.0))
    assert reply.response.accepted
    goals.wait_status(second, 2)
    canceled = goals.client.cancel(second)
    assert canceled.response.return_code == 0
    assert [bytes(bytearray(g.goal_id.uuid)) for g in canceled.response.goals_canceling] == [second]
    result = goals.client.get_result(second, timeout=30.0)
    assert result.response.status == 5 and result.response.result.error_code == 0
    assert goals.wait_status(second, 5)[-2:] == [3, 5], "canceling, then canceled"
    assert goals.client.cancel(second).response.return_code == 3, "already terminated"
    assert goals.client.cancel(os.urandom(16)).response.return_code == 2, "an unknown goal"
    assert goals.client.get_result(os.urandom(16)).response.status == 0, "an unknown goal's result: unknown, at once"

    third, _ = goals.client.send_goal(*goals.ahead(3.0))
    goals.wait_status(third, 2)
    fourth, reply = goals.client.send_goal(*goals.ahead(3.0))
    assert reply.response.accepted
    preempted = goals.client.get_result(third, timeout=30.0).response
    assert preempted.status == 6 and fourth.hex() in preempted.result.error_msg, "preempted by the newer goal"
    goals.wait_status(fourth, 2)
    everything = goals.client.cancel()
    assert everything.response.return_code == 0, "a zero id and stamp: cancel all"
    assert [bytes(bytearray(g.goal_id.uuid)) for g in everything.response.goals_canceling] == [fourth]
    goals.wait_status(fourth, 5)
    wait_until(lambda: at_rest(goals.ground_truth), 10.0, "the robot at rest")
    assert goals.client.cancel().response.return_code == 0, "cancel all with none running: none, no error"


def test_goal_pose_sends_goals_in_odom_whose_status_and_feedback_show_one_succeed_and_one_canceled(goals):
    """RViz's 2D Goal Pose: a PoseStamped on ``/robot1/goal_pose`` in ``odom`` (RViz's fixed frame):
    rh1's bridge turns it into ``map`` with its own map -> odom (rh1 started at (0, 3): its bridge's
    odom is there) and sends it; no client waits for a result: it shows in the status and feedback."""
    x, y, theta = goals.ahead(0.4, turn=-0.5)
    tf_topic = f"{NAMESPACES[GOAL_ROBOT]}/tf"
    tf = ros_client.TYPESTORE.deserialize_cdr(goals.fleet.recorder.of(tf_topic)[-1].payload, PUBLISHED["tf"])
    (map_to_odom,) = [t.transform for t in tf.transforms if (t.header.frame_id, t.child_frame_id) == ("map", "odom")]
    correction = Pose(
        map_to_odom.translation.x,
        map_to_odom.translation.y,
        2 * math.atan2(map_to_odom.rotation.z, map_to_odom.rotation.w),
    )
    assert abs(correction.y - 3.0) < 0.05, "rh1's odom is where its bridge started: (0, 3) in map"
    uuid = goals.goal_pose(core.compose(core.inverse(correction), Pose(x, y, theta)))
    assert goals.wait_status(uuid, 4, timeout=60.0)[-1] == 4
    assert goals.feedback(uuid), "its feedback on the action's topic"
    target = goals.started(uuid)
    assert target["frame"] == "map", "sent in map"
    assert math.hypot(target["x"] - x, target["y"] - y) < 0.01, "in map through the bridge's map -> odom"
    assert abs(math.remainder(target["theta"] - theta, math.tau)) < 0.01
    assert goals.near(x, y, theta), (goals.ground_truth(), (x, y, theta))
    # a second one, far: an action client's cancel-all cancels it as any goal of the action
    far = goals.goal_pose(core.compose(core.inverse(correction), Pose(*goals.ahead(3.0))))
    goals.wait_status(far, 2)
    canceled = goals.client.cancel().response
    assert canceled.return_code == 0 and [bytes(bytearray(g.goal_id.uuid)) for g in canceled.goals_canceling] == [far]
    assert goals.wait_status(far, 5)[-2:] == [3, 5]


def test_hostile_requests_are_refused_in_the_reply_counted_and_the_running_goal_goes_on(goals):
    fleet = goals.fleet
    x, y, theta = goals.ahead(0.5)
    running, reply = goals.client.send_goal(x, y, theta)
    assert reply.response.accepted
    goals.wait_status(running, 2)
    sent_before = fleet.status(GOAL_ROBOT, Service.ROS2)["navigate"]["sent"]
    good = ros_services.send_goal_request(os.urandom(16), ros_services.pose_stamped(1.0, 0.0, 0.0))
    send_key, cancel_key, result_key = (goals.client.key(e) for e in ("send_goal", "cancel_goal", "get_result"))
    goal_pose_key = ros_client.topic_key(DOMAIN, f"{NAMESPACES[GOAL_ROBOT]}/goal_pose", "geometry_msgs/msg/PoseStamped")
    refused_goals = [
        (ros_services.send_goal_request(os.urandom(16), ros_services.pose_stamped(math.nan, 0.0, 0.0)), "not finite"),
        (ros_services.send_goal_request(running, ros_services.pose_stamped(1.0, 0.0, 0.0)), "exists already"),
        (b"\x00\x01\x00\x00" + b"\x07" * 9, "malformed CDR"),
        (good + bytes(5000), "more than a send_goal request's"),
    ]
    for payload, reason in refused_goals:
        answer = goals.client.call("send_goal", payload)
        assert answer.response is not None and not answer.response.accepted, reason
        assert reason in fleet.status(GOAL_ROBOT, Service.ROS2)["navigate"]["last_rejection"]
    assert goals.bad_inputs(send_key) >= 3
    unattached = goals.client.call("send_goal", good, with_attachment=False)
    assert unattached.error is not None and "no attachment" in unattached.error, "an error reply: nothing to echo"
    assert goals.client.call("cancel_goal", b"\x00\x01\x00\x00\x01").response.return_code == 1
    assert goals.client.call("cancel_goal", ros_services.cancel_request() + bytes(100)).response.return_code == 1
    assert goals.client.call("get_result", b"\x00\x01\x00\x00").response.status == 0
    assert goals.bad_inputs(cancel_key) == 2 and goals.bad_inputs(result_key) == 1
    for payload, attached in (
        (b"\x00\x01\x00\x00\x02", True),
        (ros_client.cdr(ros_services.pose_stamped(math.inf, 0.0, 0.0, "map", ros_client.TYPESTORE)), True),
        (ros_client.cdr(ros_services.pose_stamped(1.0, 0.0, 0.0, "map", ros_client.TYPESTORE)), False),
        (bytes(5000), True),
    ):
        counted = goals.bad_inputs(goal_pose_key)
        fleet.node.put_raw(goal_pose_key, payload, ros_client.attachment(1, fleet.node.gid) if attached else None)
        wait_until(lambda c=counted: goals.bad_inputs(goal_pose_key) > c, 10.0, "the goal pose counted")
    status = fleet.status(GOAL_ROBOT, Service.ROS2)
    assert status["navigate"]["sent"] == sent_before, "nothing reached the drive"
    assert status["internal_errors"] == 0
    result = goals.client.get_result(running, timeout=60.0)
    assert result.response.status == 4, "the running goal went on, untouched"
    goals.started(running)
    assert goals.near(x, y, theta), (goals.ground_truth(), (x, y, theta))


def test_invent_ros2_fleet_runs_a_node_per_robot_on_one_session_each_with_ids_of_its_own(tmp_path):
    """``invent ros2 --fleet FILE``: one process, one session, a node per robot in its namespace,
    their nodes' and entities' ids drawn from one counter (rmw_zenoh's graph keys a node by its
    session and id), ``/clock`` from the first robot's only."""
    (tmp_path / "fleet.toml").write_text(FLEET)
    with running_router() as endpoint, peer_session(endpoint) as session:
        with InventProcess("ros2", "--fleet", str(tmp_path / "fleet.toml"), "--connect", endpoint) as bridges:
            per_node = len(PUBLISHED) + len(SUBSCRIBED) + 1 + len(SERVICES) + 2 + len(ACTION_ENDPOINTS) + 1
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
    assert set(nodes) == {mangled(namespace) for namespace in NAMESPACES.values()}
    ids = [int(chunks[4]) for chunks in tokens]
    assert sorted(ids) == list(range(len(tokens))), "one counter: every node and entity an id of its own"
    for chunks in tokens:
        assert int(chunks[3]) == nodes[chunks[7]], "each entity names its own node's id"
    clocks = [chunks[7] for chunks in tokens if chunks[5] == "MP" and chunks[9] == mangled(CLOCK[0])]
    assert clocks == [mangled(NAMESPACES["rh0"])]
