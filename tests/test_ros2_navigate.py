"""The bridge's NavigateToPose action server (services/ros2/navigate.py, action_server.py).

The pure parts, no zenoh: every action type's RIHS01 hash, as the bridge computes it from the
definitions, equals the one ROS's own generator wrote (tests/data/ros2_interfaces/nav2_msgs, made
by generate.py there) and, for action_msgs and unique_identifier_msgs, the type descriptions ROS
ships; the keys and QoS the bridge announces; the CDR it writes, read back with a typestore built
from ROS's type descriptions alone (tests/ros_client.py); UUIDs, frames, and the goals' states and
cancel policy as rcl_action keeps them.

End to end, against a fleet's bridges and a drive in goal mode: tests/test_ros2_fleet.py.
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
from schemas.messages import GoalFeedback, ScenarioOutcome, Time
from services.config import load_config
from services.planar import Pose
from services.ros2 import core, graph, interfaces, navigate
from services.ros2.graph import ActionService, ActionTopic, bridge_graph
from services.ros2.navigate import CancelCode, GoalBook, GoalStatus
from tests import ros_client

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
        assert bridge.key(entity) == ros_client.action_key(0, "/robot1/navigate_to_pose", endpoint)
        assert entity.qos.token_chunk() == "::,10:,:,:,,"
    for topic, endpoint in ((ActionTopic.FEEDBACK, "feedback"), (ActionTopic.STATUS, "status")):
        entity = graph.ACTION_TOPICS[topic]
        assert bridge.key(entity) == ros_client.action_key(0, "/robot1/navigate_to_pose", endpoint)
    assert graph.ACTION_TOPICS[ActionTopic.STATUS].qos.token_chunk() == ":1:,1:,:,:,,", "reliable, transient-local, 1"
    assert graph.ACTION_TOPICS[ActionTopic.FEEDBACK].qos.token_chunk() == "::,10:,:,:,,"
    assert bridge.key(graph.GOAL_POSE) == ros_client.topic_key(0, "/robot1/goal_pose", interfaces.POSE_STAMPED)
    assert bridge.name(graph.GOAL_POSE) == "/robot1/goal_pose"


def _read(message: object, name: str) -> object:
    """What a ROS node reads of the bridge's CDR (a typestore made from ROS's descriptions alone)."""
    return ros_client.action_decode(interfaces.serialize(message), name)


def test_the_bridges_cdr_reads_back_with_ross_own_type_descriptions():
    uuid = bytes(range(16))
    response = _read(
        navigate.send_goal_response(True, 2_500_000_000), f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Response"
    )
    assert response.accepted and (response.stamp.sec, response.stamp.nanosec) == (2, 500_000_000)
    goal = navigate.Goal(uuid, 1_000, GoalStatus.ABORTED, navigate.ErrorCode.TIMEOUT, "past its time limit")
    result = _read(navigate.result_response(goal), f"{interfaces.NAVIGATE_TO_POSE_GET_RESULT}_Response")
    assert (result.status, result.result.error_code, result.result.error_msg) == (6, 9003, "past its time limit")
    unknown = _read(navigate.result_response(None), f"{interfaces.NAVIGATE_TO_POSE_GET_RESULT}_Response")
    assert unknown.status == 0
    cancel = _read(navigate.cancel_response(CancelCode.NONE, [goal]), interfaces.CANCEL_GOAL_RESPONSE)
    assert cancel.return_code == 0 and bytes(bytearray(cancel.goals_canceling[0].goal_id.uuid)) == uuid
    array = navigate.status_array([goal, navigate.Goal(bytes(16), 5, GoalStatus.EXECUTING)])
    assert ros_client.goal_statuses(interfaces.serialize(array)) == {uuid: 6, bytes(16): 2}
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
    request = ros_client.send_goal_request(bytes(range(16)), ros_client.pose_stamped(1.5, 0.5, 1.57, "odom"), "bt.xml")
    decoded = interfaces.deserialize(request, f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Request")
    assert navigate.uuid_bytes(decoded.goal_id) == bytes(range(16)) and decoded.goal.behavior_tree == "bt.xml"
    assert decoded.goal.pose.header.frame_id == "odom" and decoded.goal.pose.pose.position.x == 1.5
    cancel = interfaces.deserialize(ros_client.cancel_request(bytes(16), 7), interfaces.CANCEL_GOAL_REQUEST)
    assert cancel.goal_info.stamp.nanosec == 7
    for malformed in (b"", request[:30], b"\x00\x01\x00\x00" + bytes(3), b"not cdr"):
        with pytest.raises(BadInput, match="malformed CDR"):
            interfaces.deserialize(malformed, f"{interfaces.NAVIGATE_TO_POSE_SEND_GOAL}_Request")


@given(st.binary(min_size=16, max_size=16))
def test_a_goal_uuid_is_the_drives_goal_id_in_32_hex_digits_and_back(uuid):
    goal_id = navigate.goal_id_of(uuid)
    assert len(goal_id) == 32 and goal_id == goal_id.lower() and navigate.uuid_of(goal_id) == uuid
    assert navigate.uuid_bytes(navigate.uuid_message(uuid)) == uuid


@pytest.mark.parametrize("goal_id", ["", "g3", "0" * 31, "z" * 32, "0" * 33])
def test_a_drive_goal_id_that_is_no_uuid_names_no_ros_goal(goal_id):
    assert navigate.uuid_of(goal_id) is None


FRAMES = navigate.GoalFrames("map", "odom")
coordinates = st.floats(-50.0, 50.0)
angles = st.floats(-math.pi, math.pi)


@given(coordinates, coordinates, angles)
def test_a_goal_in_map_is_sent_as_it_is_with_its_heading(x, y, theta):
    goal = navigate.goal_request(
        ros_client.pose_stamped(x, y, theta, "map", interfaces.messages()), FRAMES, None, "a", 1e3
    )
    assert (goal.x, goal.y, goal.frame, goal.id) == (x, y, "map", "a")
    assert abs(math.remainder(goal.theta - theta, math.tau)) < 1e-9


@given(st.builds(Pose, coordinates, coordinates, angles), coordinates, coordinates, angles)
def test_a_goal_in_odom_is_sent_in_map_through_the_bridges_map_to_odom(correction, x, y, theta):
    pose = ros_client.pose_stamped(x, y, theta, "odom", interfaces.messages())
    goal = navigate.goal_request(pose, FRAMES, correction, "a", 1e3)
    expected = core.compose(correction, Pose(x, y, theta))
    assert goal.frame == "map" and math.isclose(goal.x, expected.x, abs_tol=1e-9)
    assert math.isclose(goal.y, expected.y, abs_tol=1e-9)
    assert goal.theta is not None and abs(math.remainder(goal.theta - expected.theta, math.tau)) < 1e-9


def _pose(x: float = 1.0, y: float = 0.0, frame: str = "map", q: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0)) -> object:
    pose = ros_client.pose_stamped(x, y, 0.0, frame, interfaces.messages())
    qx, qy, qz, qw = q
    pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z, pose.pose.orientation.w = qx, qy, qz, qw
    return pose


@pytest.mark.parametrize(
    ("pose", "correction", "reason"),
    [
        (_pose(frame="base_link"), None, "frame 'base_link' is neither 'map' nor 'odom'"),
        (_pose(frame=""), None, "frame '' is neither"),
        (_pose(frame="rh0/odom"), Pose(0.0, 0.0, 0.0), "frame 'rh0/odom' is neither"),
        (_pose(frame="odom"), None, "before the bridge has map -> odom"),
        (_pose(x=math.nan), None, "not finite"),
        (_pose(y=math.inf), None, "not finite"),
        (_pose(x=1e9), None, "beyond input.max_coordinate"),
        (_pose(q=(0.0, 0.0, math.nan, 1.0)), None, "orientation .* is not finite"),
        (_pose(q=(0.0, 0.0, 0.0, 0.0)), None, "no rotation"),
    ],
)
def test_a_goal_in_another_frame_not_finite_or_absurd_is_refused_naming_why(pose, correction, reason):
    with pytest.raises(BadInput, match=reason):
        navigate.goal_request(pose, FRAMES, correction, "a", 1e3)


def test_an_unnormalised_quaternion_gives_its_heading():
    heading = navigate.yaw_of(_pose(q=(0.0, 0.0, 2.0, 2.0)).pose.orientation)  # type: ignore[attr-defined]
    assert math.isclose(heading, math.pi / 2)


def _outcome(goal_id: str, outcome: str, reason: str = "") -> ScenarioOutcome:
    return ScenarioOutcome(Time(1, 0), "goal", outcome, reason, 0, 1.0, goal_id=goal_id)  # type: ignore[arg-type]


def _uuid(k: int) -> bytes:
    return bytes([k]) * 16


def test_a_goal_goes_accepted_executing_succeeded_and_ends_with_its_result():
    book = GoalBook()
    book.send(_uuid(1))
    assert book.status_list() == [], "not listed while the drive has not answered"
    assert book.accepted(_uuid(1), 100)
    assert [goal.status for goal in book.status_list()] == [GoalStatus.ACCEPTED]
    assert book.executing(_uuid(1).hex()) and not book.executing(_uuid(1).hex())
    ended = book.ended(_outcome(_uuid(1).hex(), "completed"))
    assert ended is not None and (ended.status, ended.error_code) == (GoalStatus.SUCCEEDED, navigate.ErrorCode.NONE)
    assert book.ended(_outcome(_uuid(1).hex(), "aborted")) is None, "an ended goal ends once"
    assert not book.executing(_uuid(1).hex()) and not book.canceling(_uuid(1).hex())


@pytest.mark.parametrize(
    ("outcome", "status", "code"),
    [
        ("completed", GoalStatus.SUCCEEDED, 0),
        ("canceled", GoalStatus.CANCELED, 0),
        ("aborted", GoalStatus.ABORTED, 9000),
        ("timed_out", GoalStatus.ABORTED, 9003),
    ],
)
def test_each_drive_outcome_is_a_final_status_and_error_code(outcome, status, code):
    book = GoalBook()
    book.send(_uuid(1))
    book.accepted(_uuid(1), 1)
    goal = book.ended(_outcome(_uuid(1).hex(), outcome, "why"))
    assert goal is not None and (goal.status, int(goal.error_code)) == (status, code)
    assert goal.error_msg == "why"


def test_the_drives_events_may_come_before_its_reply_and_never_move_a_goal_back():
    book = GoalBook()
    book.send(_uuid(1))
    assert not book.executing(_uuid(1).hex()), "not listed yet: no status to publish"
    book.ended(_outcome(_uuid(1).hex(), "canceled"))
    assert book.accepted(_uuid(1), 5)
    assert [goal.status for goal in book.status_list()] == [GoalStatus.CANCELED]
    book.send(_uuid(2))
    book.accepted(_uuid(2), 6)
    assert book.canceling(_uuid(2).hex()) and not book.executing(_uuid(2).hex())
    assert book.get(_uuid(2)).status is GoalStatus.CANCELING  # type: ignore[union-attr]


def test_a_refused_goal_is_forgotten_and_a_known_uuid_is_refused():
    book = GoalBook()
    book.send(_uuid(1))
    with pytest.raises(BadInput, match="exists already"):
        book.send(_uuid(1))
    book.rejected(_uuid(1))
    assert _uuid(1) not in book
    book.send(_uuid(1))


def _book_with(*statuses: GoalStatus) -> GoalBook:
    """Goals 1, 2, ... accepted at 10, 20, ... with the given statuses."""
    book = GoalBook()
    for k, status in enumerate(statuses, start=1):
        book.send(_uuid(k))
        book.accepted(_uuid(k), 10 * k)
        book.get(_uuid(k)).status = status  # type: ignore[union-attr]
    return book


def test_cancel_follows_rcl_actions_policy():
    running, done = GoalStatus.EXECUTING, GoalStatus.SUCCEEDED
    code, goals = _book_with(running, done, running).cancel(bytes(16), 0)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1), _uuid(3)], "zero id and stamp: all"
    code, goals = _book_with(running, running, running).cancel(bytes(16), 20)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1), _uuid(2)], "at or before the stamp"
    code, goals = _book_with(running, running, running).cancel(_uuid(3), 10)
    assert [g.uuid for g in goals] == [_uuid(1), _uuid(3)], "the id and those before the stamp"
    book = _book_with(running, done)
    code, goals = book.cancel(_uuid(1), 0)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1)]
    assert book.get(_uuid(1)).status is GoalStatus.CANCELING  # type: ignore[union-attr]
    assert book.cancel(_uuid(2), 0) == (CancelCode.GOAL_TERMINATED, [])
    assert book.cancel(_uuid(9), 0) == (CancelCode.UNKNOWN_GOAL_ID, [])
    assert book.cancel(_uuid(1), 0) == (CancelCode.GOAL_TERMINATED, []), "canceling already: rcl says terminated"
    assert _book_with(done).cancel(bytes(16), 0) == (CancelCode.NONE, []), "nothing to cancel: none, and no goal"
    pending = GoalBook()
    pending.send(_uuid(1))
    assert pending.cancel(_uuid(1), 0) == (CancelCode.UNKNOWN_GOAL_ID, []), "not accepted yet: unknown to ROS"


events = st.lists(
    st.tuples(
        st.sampled_from(["send", "accept", "reject", "start", "cancel", "canceling", "end", "cancel_all"]),
        st.integers(1, 30),
        st.sampled_from(["completed", "canceled", "aborted", "timed_out"]),
    ),
    max_size=200,
)


def _apply(book: GoalBook, event: str, k: int, outcome: str) -> None:
    uuid, goal_id = _uuid(k), _uuid(k).hex()
    if event == "send":
        book.send(uuid)
    elif event == "accept":
        book.accepted(uuid, k)
    elif event == "reject":
        book.rejected(uuid)
    elif event == "start":
        book.executing(goal_id)
    elif event == "canceling":
        book.canceling(goal_id)
    elif event == "end":
        book.ended(_outcome(goal_id, outcome))
    else:
        book.cancel(uuid if event == "cancel" else bytes(16), 0)


@given(events)
def test_the_book_stays_bounded_and_no_goal_ever_moves_back(sequence):
    book = GoalBook(max_goals=12, max_ended=4)
    seen: dict[bytes, GoalStatus] = {}
    for event, k, outcome in sequence:
        try:
            _apply(book, event, k, outcome)
        except BadInput:
            assert event == "send"
        listed = book.status_list()
        assert sum(goal.status.terminal for goal in listed) <= 4
        assert len(listed) <= 12
        for goal in listed:
            before = seen.get(goal.uuid)
            if before is not None:
                assert goal.status >= before, (before, goal.status)
                assert not before.terminal or goal.status is before
            seen[goal.uuid] = goal.status
        for forgotten in [uuid for uuid in seen if uuid not in book]:
            del seen[forgotten]


def test_durations_are_whole_seconds_and_nanoseconds_never_negative():
    assert (navigate.duration(1.25).sec, navigate.duration(1.25).nanosec) == (1, 250_000_000)
    for value in (-1.0, math.nan, math.inf):
        assert (navigate.duration(value).sec, navigate.duration(value).nanosec) == (0, 0)
    assert np.array_equal(navigate.uuid_message(bytes(range(16))).uuid, np.arange(16, dtype=np.uint8))
