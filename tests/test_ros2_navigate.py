"""The bridge's NavigateToPose action server (services/ros2/navigate.py, action_server.py).

The pure parts, no zenoh: every action type's RIHS01 hash, as the bridge computes it from the
definitions, equals the one ROS's own generator wrote (tests/data/ros2_interfaces/nav2_msgs, made
by generate.py there) and, for action_msgs and unique_identifier_msgs, the type descriptions ROS
ships; the keys and QoS the bridge announces; the CDR it writes, read back with a typestore built
from ROS's type descriptions alone (tests/ros_client.py); UUIDs, and goals in any frame of the
bridge's TF tree (services/ros2/tf_tree.py) turned into ``map``. The goals' states:
tests/test_ros2_goal_book.py.

End to end, against a fleet's bridges and a drive in goal mode: tests/test_ros2_fleet.py; each of
rcl_action's and Nav2's rules over the wire: tests/test_ros2_action_rules.py.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import Time
from schemas.navigation import GoalFeedback
from services.config import load_config
from services.planar import Pose
from services.ros2 import core, goal_book, graph, interfaces, navigate
from services.ros2.goal_book import CancelCode, ErrorCode, Goal, GoalStatus
from services.ros2.graph import ActionService, ActionTopic, bridge_graph
from services.ros2.tf_tree import Rigid, TfTree, TransformError, unit_quaternion
from tests import ros_client, ros_services
from tests.test_ros2_localization import pose_estimate

DATA = Path(__file__).parent / "data" / "ros2_interfaces"
GENERATED = DATA / "nav2_msgs" / "action" / "NavigateToPose.json"
SHIPPED = [
    DATA / "action_msgs" / "msg" / "GoalInfo.json",
    DATA / "action_msgs" / "msg" / "GoalStatus.json",
    DATA / "action_msgs" / "msg" / "GoalStatusArray.json",
    DATA / "action_msgs" / "srv" / "CancelGoal.json",
    DATA / "unique_identifier_msgs" / "msg" / "UUID.json",
]


def _hashes(path: Path) -> dict[str, str]:
    return {entry["type_name"]: entry["hash_string"] for entry in json.loads(path.read_text())["type_hashes"]}


GENERATED_HASHES = _hashes(GENERATED)
SHIPPED_HASHES = {name: digest for path in SHIPPED for name, digest in _hashes(path).items()}
ACTION_TYPES = sorted(name for name in GENERATED_HASHES if name.startswith(interfaces.NAVIGATE_TO_POSE))


def test_the_generators_output_covers_the_action_and_every_type_derived_from_it():
    suffixes = {name.removeprefix(interfaces.NAVIGATE_TO_POSE) for name in ACTION_TYPES}
    assert suffixes == {
        "",
        "_Goal",
        "_Result",
        "_Feedback",
        "_FeedbackMessage",
        *(
            f"_{service}{part}"
            for service in ("SendGoal", "GetResult")
            for part in ("", "_Request", "_Response", "_Event")
        ),
    }


@pytest.mark.parametrize("name", ACTION_TYPES)
def test_every_action_types_hash_equals_the_one_ross_generator_computed(name):
    assert interfaces.interface(name).type_hash == GENERATED_HASHES[name]


@pytest.mark.parametrize("name", sorted(SHIPPED_HASHES))
def test_the_action_msgs_hashes_equal_the_type_descriptions_ros_ships(name):
    """action_msgs' GoalInfo, GoalStatus, GoalStatusArray, CancelGoal (and its Request, Response and
    Event, built on ServiceEventInfo with ROS's ``uint8`` GID), UUID, Time, ServiceEventInfo."""
    assert interfaces.interface(name).type_hash == SHIPPED_HASHES[name]


def test_the_types_the_generator_included_agree_with_what_ros_ships_and_rosbags_computes():
    for name in set(GENERATED_HASHES) & set(SHIPPED_HASHES):
        assert GENERATED_HASHES[name] == SHIPPED_HASHES[name], name
    for name in ("geometry_msgs/msg/PoseStamped", "builtin_interfaces/msg/Duration", "std_msgs/msg/Header"):
        assert interfaces.interface(name).type_hash == GENERATED_HASHES[name]


def test_the_bridges_action_definition_is_navigation2_jazzys_text_unchanged():
    vendored = (DATA / "nav2_msgs" / "action" / "NavigateToPose.action").read_text()
    assert interfaces.NAVIGATE_TO_POSE_ACTION == vendored


def test_the_bridge_announces_the_action_in_its_namespace_with_rcl_actions_names_types_and_qos():
    bridge = bridge_graph(load_config(overrides={"ros2.namespace": "robot1"}), environ={})
    expected = {
        ActionService.SEND_GOAL: "send_goal",
        ActionService.CANCEL_GOAL: "cancel_goal",
        ActionService.GET_RESULT: "get_result",
    }
    for service, endpoint in expected.items():
        entity = graph.ACTION_SERVICES[service]
        assert bridge.key(entity) == ros_services.action_key(0, "/robot1/navigate_to_pose", endpoint)
        assert entity.qos.token_chunk() == "::,10:,:,:,,"
    for topic, endpoint in ((ActionTopic.FEEDBACK, "feedback"), (ActionTopic.STATUS, "status")):
        entity = graph.ACTION_TOPICS[topic]
        assert bridge.key(entity) == ros_services.action_key(0, "/robot1/navigate_to_pose", endpoint)
    assert graph.ACTION_TOPICS[ActionTopic.STATUS].qos.token_chunk() == ":1:,1:,:,:,,", "reliable, transient-local, 1"
    assert graph.ACTION_TOPICS[ActionTopic.FEEDBACK].qos.token_chunk() == "::,10:,:,:,,"
    assert bridge.key(graph.GOAL_POSE) == ros_client.topic_key(0, "/robot1/goal_pose", interfaces.POSE_STAMPED)
    assert bridge.name(graph.GOAL_POSE) == "/robot1/goal_pose"


def _read(message: object, name: str) -> object:
    """What a ROS node reads of the bridge's CDR (a typestore made from ROS's descriptions alone)."""
    return ros_services.action_decode(interfaces.serialize(message), name)


def test_the_bridges_cdr_reads_back_with_ross_own_type_descriptions():
    uuid = bytes(range(16))
    response = _read(
        navigate.send_goal_response(True, 2_500_000_000), f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Response"
    )
    assert response.accepted and (response.stamp.sec, response.stamp.nanosec) == (2, 500_000_000)
    goal = Goal(uuid, 1_000, GoalStatus.ABORTED, ErrorCode.TIMEOUT, "past its time limit")
    result = _read(navigate.result_response(goal), f"{interfaces.NAVIGATE_TO_POSE_GET_RESULT}_Response")
    assert (result.status, result.result.error_code, result.result.error_msg) == (6, 9003, "past its time limit")
    unknown = _read(navigate.result_response(None), f"{interfaces.NAVIGATE_TO_POSE_GET_RESULT}_Response")
    assert unknown.status == 0
    cancel = _read(navigate.cancel_response(CancelCode.NONE, [goal]), interfaces.CANCEL_GOAL_RESPONSE)
    assert cancel.return_code == 0 and bytes(bytearray(cancel.goals_canceling[0].goal_id.uuid)) == uuid
    array = navigate.status_array([goal, Goal(bytes(16), 5, GoalStatus.EXECUTING)])
    assert ros_services.goal_statuses(interfaces.serialize(array)) == {uuid: 6, bytes(16): 2}
    shown = navigate.status_array([goal], {uuid: GoalStatus.EXECUTING})
    assert ros_services.goal_statuses(interfaces.serialize(shown)) == {uuid: 2}, "a step it passes through"
    feedback = GoalFeedback(Time(3, 0), uuid.hex(), "executing", 1.0, 2.0, 0.5, 1.25, 3.5, 4.75)
    message = _read(navigate.feedback_message(uuid, feedback, "map"), f"{interfaces.NAVIGATE_TO_POSE}_FeedbackMessage")
    current = message.feedback.current_pose
    assert current.header.frame_id == "map" and current.header.stamp.sec == 3
    assert (current.pose.position.x, current.pose.position.y) == (1.0, 2.0)
    assert math.isclose(2 * math.atan2(current.pose.orientation.z, current.pose.orientation.w), 0.5)
    assert (message.feedback.navigation_time.sec, message.feedback.navigation_time.nanosec) == (3, 500_000_000)
    assert message.feedback.estimated_time_remaining.sec == 4 and message.feedback.number_of_recoveries == 0
    assert message.feedback.distance_remaining == pytest.approx(1.25)
    recovering = msgspec.structs.replace(feedback, recoveries=3)
    again = _read(navigate.feedback_message(uuid, recovering, "map"), f"{interfaces.NAVIGATE_TO_POSE}_FeedbackMessage")
    assert again.feedback.number_of_recoveries == 3, "the navigation's recoveries, counted"


def test_a_ros_clients_requests_decode_and_malformed_ones_are_bad_input():
    request = ros_services.send_goal_request(
        bytes(range(16)), ros_services.pose_stamped(1.5, 0.5, 1.57, "odom"), "bt.xml"
    )
    decoded = interfaces.deserialize(request, f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Request")
    assert navigate.uuid_bytes(decoded.goal_id) == bytes(range(16)) and decoded.goal.behavior_tree == "bt.xml"
    assert decoded.goal.pose.header.frame_id == "odom" and decoded.goal.pose.pose.position.x == 1.5
    cancel = interfaces.deserialize(ros_services.cancel_request(bytes(16), 7), interfaces.CANCEL_GOAL_REQUEST)
    assert cancel.goal_info.stamp.nanosec == 7
    for malformed in (b"", request[:30], b"\x00\x01\x00\x00" + bytes(3), b"not cdr"):
        with pytest.raises(BadInput, match="malformed CDR"):
            interfaces.deserialize(malformed, f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Request")


@given(st.binary(min_size=16, max_size=16))
def test_a_goal_uuid_is_the_drives_goal_id_in_32_hex_digits_and_back(uuid):
    goal_id = goal_book.goal_id_of(uuid)
    assert len(goal_id) == 32 and goal_id == goal_id.lower() and goal_book.uuid_of(goal_id) == uuid
    assert navigate.uuid_bytes(navigate.uuid_message(uuid)) == uuid


@pytest.mark.parametrize("goal_id", ["", "g3", "0" * 31, "z" * 32, "0" * 33])
def test_a_drive_goal_id_that_is_no_uuid_names_no_ros_goal(goal_id):
    assert goal_book.uuid_of(goal_id) is None


coordinates = st.floats(-50.0, 50.0)
angles = st.floats(-math.pi, math.pi)
poses = st.builds(Pose, coordinates, coordinates, angles)


def _tree(map_to_odom: Pose | None = None, odom_to_base: Pose | None = None) -> TfTree:
    """The bridge's tree: map -> odom -> base_link -> base_scan (0.1 m ahead, 0.2 up) and a wheel
    turned by 1 rad about its axle (+y), each edge only if given."""
    tree = TfTree()
    for parent, child, pose in (("map", "odom", map_to_odom), ("odom", "base_link", odom_to_base)):
        if pose is not None:
            tree.set(
                parent,
                child,
                Rigid.of((pose.x, pose.y, 0.0), (0.0, 0.0, math.sin(pose.theta / 2), math.cos(pose.theta / 2))),
            )
    tree.set("base_link", "base_scan", Rigid.of((0.1, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0)))
    tree.set("base_link", "wheel_left_link", Rigid.of((0.0, 0.15, 0.0), (0.0, math.sin(0.5), 0.0, math.cos(0.5))))
    return tree


def _goal(x: float, y: float, theta: float, frame: str, tree: TfTree) -> object:
    return navigate.goal_request(
        ros_services.pose_stamped(x, y, theta, frame, interfaces.messages()), tree, "map", "a", 1e3
    )


def _close(goal: object, expected: Pose) -> bool:
    return (
        math.isclose(goal.x, expected.x, abs_tol=1e-9)  # type: ignore[attr-defined]
        and math.isclose(goal.y, expected.y, abs_tol=1e-9)  # type: ignore[attr-defined]
        and abs(math.remainder(goal.theta - expected.theta, math.tau)) < 1e-9  # type: ignore[attr-defined]
    )


@given(coordinates, coordinates, angles)
def test_a_goal_in_map_is_sent_as_it_is_with_its_heading(x, y, theta):
    goal = _goal(x, y, theta, "map", TfTree())
    assert (goal.x, goal.y, goal.frame, goal.id) == (x, y, "map", "a")  # type: ignore[attr-defined]
    assert _close(goal, Pose(x, y, theta))


@given(poses, coordinates, coordinates, angles)
def test_a_goal_in_odom_is_sent_in_map_through_the_bridges_map_to_odom(correction, x, y, theta):
    goal = _goal(x, y, theta, "odom", _tree(correction))
    assert goal.frame == "map" and _close(goal, core.compose(correction, Pose(x, y, theta)))  # type: ignore[attr-defined]


@given(poses, poses, st.floats(-5.0, 5.0), st.floats(-5.0, 5.0), angles)
def test_a_goal_in_base_link_is_relative_to_the_robot_through_odom_and_map(correction, robot, x, y, theta):
    """Nav2's relative goal: ``base_link`` (1, 0) is a metre ahead of the robot, wherever it is."""
    goal = _goal(x, y, theta, "base_link", _tree(correction, robot))
    assert _close(goal, core.compose(core.compose(correction, robot), Pose(x, y, theta)))


def test_a_goal_in_a_sensors_or_a_turned_wheels_frame_goes_through_its_3d_transform():
    robot = Pose(1.0, 2.0, math.pi / 2)
    scan = _goal(1.0, 0.0, 0.0, "base_scan", _tree(Pose(0.0, 0.0, 0.0), robot))
    assert _close(scan, Pose(1.0, 2.0 + 1.1, math.pi / 2)), "the lidar 0.1 m ahead: 1.1 m ahead of the robot"
    wheel = _goal(1.0, 0.0, 0.0, "wheel_left_link", _tree(Pose(0.0, 0.0, 0.0), Pose(0.0, 0.0, 0.0)))
    assert math.isclose(wheel.x, math.cos(1.0), abs_tol=1e-9), "its x axis turned 1 rad about the axle"  # type: ignore[attr-defined]
    assert math.isclose(wheel.y, 0.15, abs_tol=1e-9) and abs(wheel.theta) < 1e-9  # type: ignore[attr-defined]


@given(poses, poses, st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_a_lookup_and_its_reverse_are_inverses_and_compose_through_any_frame(correction, robot, lift, tilt):
    tree = _tree(correction, robot)
    tree.set("base_link", "tilted", Rigid.of((0.0, 0.0, lift), (math.sin(tilt), 0.0, 0.0, math.cos(tilt))))
    there, back = tree.lookup("map", "tilted"), tree.lookup("tilted", "map")
    identity = there.compose(back)
    assert np.allclose(identity.translation, 0.0, atol=1e-9) and abs(abs(identity.rotation[3]) - 1.0) < 1e-9
    through = tree.lookup("map", "odom").compose(tree.lookup("odom", "tilted"))
    assert np.allclose(through.translation, there.translation, atol=1e-9)


@pytest.mark.parametrize(
    ("frame", "tree", "reason"),
    [
        ("earth", _tree(Pose(0, 0, 0), Pose(0, 0, 0)), "frame 'earth' is not in the bridge's TF tree"),
        ("", _tree(Pose(0, 0, 0), Pose(0, 0, 0)), "frame '' is not in"),
        ("base_link", _tree(None, Pose(0, 0, 0)), "frame 'base_link' is not connected to 'map'"),
        ("odom", _tree(None, Pose(0, 0, 0)), "frame 'odom' is not connected to 'map'"),
    ],
)
def test_a_goal_in_a_frame_the_tree_cannot_turn_into_map_is_a_transform_error_naming_why(frame, tree, reason):
    with pytest.raises(TransformError, match=reason):
        _goal(1.0, 0.0, 0.0, frame, tree)


def _pose(x: float = 1.0, y: float = 0.0, frame: str = "map", q: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)) -> object:
    pose = ros_services.pose_stamped(x, y, 0.0, frame, interfaces.messages())
    qx, qy, qz, qw = q
    pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z, pose.pose.orientation.w = qx, qy, qz, qw
    return pose


@pytest.mark.parametrize(
    ("pose", "reason"),
    [
        (_pose(x=math.nan), "not finite"),
        (_pose(y=math.inf), "not finite"),
        (_pose(x=1e9), "beyond input.max_coordinate"),
        (_pose(x=900.0, frame="odom"), "in 'map' is beyond input.max_coordinate"),
        (_pose(q=(0.0, 0.0, math.nan, 1.0)), "orientation .* is not finite"),
        (_pose(q=(0.0, 0.0, 0.0, 0.0)), "no rotation"),
    ],
)
def test_a_goal_not_finite_or_absurd_is_refused_naming_why(pose, reason):
    with pytest.raises(BadInput, match=reason):
        navigate.goal_request(pose, _tree(Pose(500.0, 0.0, 0.0)), "map", "a", 1e3)


def test_an_unnormalised_quaternion_gives_its_heading():
    heading = navigate.yaw_of(_pose(q=(0.0, 0.0, 2.0, 2.0)).pose.orientation)  # type: ignore[attr-defined]
    assert math.isclose(heading, math.pi / 2)


HUGE_AND_TINY_TURNS = [(0.0, 0.0, 1e300, 1e300), (0.0, 0.0, 1e-300, 1e-300), (0.0, 0.0, 5e-324, 5e-324)]
"""A turn of pi/2 about z whose squares overflow, underflow, or are subnormal."""


@pytest.mark.parametrize("q", HUGE_AND_TINY_TURNS)
def test_a_goal_whose_quaternion_squares_overflow_keeps_its_heading(q):
    """(0, 0, 1e300, 1e300) is a valid quaternion of yaw pi/2: normalised before use, never NaN."""
    goal = navigate.goal_request(_pose(q=q), TfTree(), "map", "a", 1e3)
    assert goal.theta is not None and math.isclose(goal.theta, math.pi / 2)
    odom = navigate.goal_request(_pose(frame="odom", q=q), _tree(Pose(1.0, 2.0, 0.5)), "map", "a", 1e3)
    assert odom.theta is not None and math.isclose(odom.theta, math.pi / 2 + 0.5)


@pytest.mark.parametrize("q", HUGE_AND_TINY_TURNS)
def test_a_pose_estimate_whose_quaternion_squares_overflow_keeps_its_heading(q):
    request = navigate.initial_pose_request(
        pose_estimate(1.0, 2.0, 0.0, orientation=q), navigate.GoalFrames("map", "odom"), None, 50.0
    )
    assert math.isclose(request.theta, math.pi / 2)


@given(
    st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: max(map(abs, q)) > 1e-3),
    st.sampled_from([1e-300, 1e-150, 1.0, 1e150, 1e300]),
)
def test_a_quaternion_of_any_finite_length_is_normalised_as_its_unit_one(q, scale):
    unit = unit_quaternion(q)
    assert math.isclose(float(unit @ unit), 1.0)
    assert np.allclose(unit_quaternion(tuple(value * scale for value in q)), unit, atol=1e-12)


def test_durations_are_whole_seconds_and_nanoseconds_never_negative():
    assert (navigate.duration(1.25).sec, navigate.duration(1.25).nanosec) == (1, 250_000_000)
    for value in (-1.0, math.nan, math.inf):
        assert (navigate.duration(value).sec, navigate.duration(value).nanosec) == (0, 0)
    for value in (1e300, 3e9):  # a peer's feedback: an int32's most seconds, never an overflow
        assert (navigate.duration(value).sec, navigate.duration(value).nanosec) == (navigate.MAX_DURATION_S, 0)
    assert np.array_equal(navigate.uuid_message(bytes(range(16))).uuid, np.arange(16, dtype=np.uint8))
