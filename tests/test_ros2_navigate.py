"""The bridge's NavigateToPose action server (services/ros2/navigate.py, action_server.py).

First the pure parts, no zenoh: every action type's RIHS01 hash, as the bridge computes it from the
definitions, equals the one ROS's own generator wrote (tests/data/ros2_interfaces/nav2_msgs, made
by generate.py there) and, for action_msgs and unique_identifier_msgs, the type descriptions ROS
ships; the keys and QoS the bridge announces; the CDR it writes, read back with a typestore built
from ROS's type descriptions alone (tests/ros_client.py); UUIDs, frames, and the goals' states and
cancel policy as rcl_action keeps them.

Then, end to end, one run of the loop (``invent up --ros2 --teleop``, realtime) with the drive in
goal mode beside it (``invent drive --goals``) serves every slow test, a ROS client on rmw_zenoh's
wire format the test's session: the action in the graph; a goal reached with feedback and its
result; goals canceled, preempted and canceled all; goals through ``goal_pose``; hostile requests
refused while a goal runs. A fleet's goals are tests/test_ros2_fleet.py's.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.keys import Keys, Service
from schemas.messages import GoalFeedback, ScenarioOutcome, Time
from services.config import GoalsConfig, load_config
from services.planar import Pose
from services.ros2 import core, graph, interfaces, navigate
from services.ros2.graph import ActionService, ActionTopic, bridge_graph
from services.ros2.navigate import CancelCode, GoalBook, GoalStatus
from tests import ros_client
from tests.harness import InventProcess, call, invent_command, peer_session, running_router, wait_alive, wait_until

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


# -- end to end: the loop, its drive in goal mode, and a ROS client on rmw_zenoh's wire format ---

DOMAIN = 0
STARTUP_TIMEOUT_S = 60.0
KEYS = Keys()
GOALS = GoalsConfig()
FEEDBACK, STATUS = "navigate_to_pose/_action/feedback", "navigate_to_pose/_action/status"


@dataclass
class GoalLoop:
    endpoint: str
    session: zenoh.Session
    recorder: ros_client.Recorder
    client: ros_client.ActionClient
    node: ros_client.RosNode

    def status(self, service: Service) -> dict[str, Any]:
        ok, status = call(self.session, KEYS.status(service))
        assert ok
        return status

    def ground_truth(self) -> Pose:
        pose = self.status(Service.SIM)["pose"]
        return Pose(pose["x"], pose["y"], pose["theta"])

    def statuses(self, uuid: bytes) -> list[int]:
        """The goal's status in each ``_action/status`` sample that lists it, repeats left out."""
        seen: list[int] = []
        for sample in self.recorder.of(STATUS):
            status = ros_client.goal_statuses(sample.payload).get(uuid)
            if status is not None and (not seen or seen[-1] != status):
                seen.append(status)
        return seen

    def wait_status(self, uuid: bytes, status: int, timeout: float = 30.0) -> list[int]:
        return wait_until(
            lambda: (seen := self.statuses(uuid)) and seen[-1] == status and seen, timeout, f"status {status}"
        )

    def feedback(self, uuid: bytes) -> list[Any]:
        messages = (
            ros_client.action_decode(sample.payload, f"{ros_client.NAVIGATE}_FeedbackMessage")
            for sample in self.recorder.of(FEEDBACK)
        )
        return [message.feedback for message in messages if bytes(bytearray(message.goal_id.uuid)) == uuid]

    def ahead(self, distance: float, turn: float = 0.0) -> tuple[float, float, float]:
        """A goal ``distance`` ahead of the robot, its heading turned by ``turn``."""
        pose = self.ground_truth()
        return (
            pose.x + distance * math.cos(pose.theta),
            pose.y + distance * math.sin(pose.theta),
            pose.theta + turn,
        )

    def bad_inputs(self, key: str) -> int:
        entry = self.status(Service.ROS2)["bad_input"]["by_key"].get(key)
        return entry["count"] if entry else 0


@pytest.fixture(scope="module")
def loop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GoalLoop]:
    """The loop in realtime with the ROS 2 bridge (``invent up --ros2 --teleop``) and the drive in
    goal mode (``invent drive --goals``) beside it; the test's session a ROS node's peer, the
    domain's samples recorded from before the bridge starts."""
    directory = tmp_path_factory.mktemp("navigate")
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        with (directory / "up.log").open("w") as log:
            up = subprocess.Popen(
                invent_command("up", "--ros2", "--teleop", "--connect", endpoint),
                cwd=directory,
                stdout=log,
                stderr=subprocess.STDOUT,
                text=True,
            )
            try:
                wait_alive(session, KEYS.alive(Service.ROS2), STARTUP_TIMEOUT_S)
                wait_alive(session, KEYS.alive(Service.SIM), STARTUP_TIMEOUT_S)
                with InventProcess("drive", "--goals", "--connect", endpoint, drain=True) as drive:
                    wait_alive(session, KEYS.alive(Service.DRIVE), STARTUP_TIMEOUT_S)
                    client = ros_client.ActionClient(session, "/navigate_to_pose")
                    yield GoalLoop(endpoint, session, recorder, client, ros_client.RosNode(session))
                    code, _out, err = drive.stop()
                    assert code == 0, err[-3000:]
            finally:
                up.send_signal(signal.SIGINT)
                try:
                    up.wait(60)
                except subprocess.TimeoutExpired:
                    up.kill()
                recorder.close()
    assert up.returncode == 0, (directory / "up.log").read_text()[-3000:]


def _at_rest(loop: GoalLoop) -> bool:
    """Whether the robot moved less than a millimetre in a tenth of a second of wall time."""
    before = loop.ground_truth()
    time.sleep(0.1)
    after = loop.ground_truth()
    return math.hypot(after.x - before.x, after.y - before.y) < 0.001


def _token_entities(tokens: list[list[str]], kind: str) -> set[tuple[str, str, str, str]]:
    return {(chunks[9], chunks[10], chunks[11], chunks[12]) for chunks in tokens if chunks[5] == kind}


@pytest.mark.slow
def test_the_graph_shows_the_actions_services_and_topics_and_goal_pose_with_ross_hashes(loop):
    """What ``ros2 action list -t`` and ``ros2 action info`` read: the action's three services (SS)
    and two topics (MP) in the tokens, with the types and hashes of ROS's own descriptions."""
    tokens = wait_until(
        lambda: (found := ros_client.graph_tokens(loop.session, DOMAIN)) and len(found) > 20 and found, 10.0
    )
    services = {
        (
            f"%navigate_to_pose%_action%{endpoint}",
            *ros_client.action_key_type(ros_client.ACTION_ENDPOINTS[endpoint]).split("/"),
            "::,10:,:,:,,",
        )
        for endpoint in ("send_goal", "cancel_goal", "get_result")
    }
    assert services <= _token_entities(tokens, "SS")
    topics = {
        (
            f"%navigate_to_pose%_action%{endpoint}",
            *ros_client.action_key_type(ros_client.ACTION_ENDPOINTS[endpoint]).split("/"),
            qos,
        )
        for endpoint, qos in (("feedback", "::,10:,:,:,,"), ("status", ":1:,1:,:,:,,"))
    }
    assert topics <= _token_entities(tokens, "MP")
    goal_pose = ("%goal_pose", *ros_client.key_type("geometry_msgs/msg/PoseStamped").split("/"), "::,10:,:,:,,")
    assert goal_pose in _token_entities(tokens, "MS")


@pytest.mark.slow
def test_a_navigate_to_pose_goal_is_reached_with_feedback_and_its_result_succeeded(loop):
    x, y, theta = loop.ahead(0.6, turn=0.8)
    uuid, reply = loop.client.send_goal(x, y, theta)
    assert reply.error is None and reply.response.accepted
    assert reply.attachment is not None and reply.attachment[0] == reply.sequence_number
    assert reply.attachment[2] == loop.client.gid, "the reply echoes the request's sequence number and GID"
    result = loop.client.get_result(uuid, timeout=60.0)
    assert (result.response.status, result.response.result.error_code) == (4, 0), result.response
    truth = loop.ground_truth()
    assert math.hypot(truth.x - x, truth.y - y) <= GOALS.position_tolerance
    assert abs(math.remainder(truth.theta - theta, math.tau)) <= GOALS.heading_tolerance
    statuses = loop.wait_status(uuid, 4)
    assert statuses[0] == 1 and 2 in statuses and statuses[-1] == 4, "accepted, executing, then succeeded"
    feedback = wait_until(lambda: len(loop.feedback(uuid)) >= 5 and loop.feedback(uuid), 10.0, "feedback")
    assert {f.current_pose.header.frame_id for f in feedback} == {"map"}
    times = [f.navigation_time.sec + f.navigation_time.nanosec / 1e9 for f in feedback]
    assert times == sorted(times) and times[-1] > times[0]
    assert feedback[0].distance_remaining > feedback[-1].distance_remaining
    assert all(f.number_of_recoveries == 0 and f.estimated_time_remaining.sec >= 0 for f in feedback)
    last = feedback[-1].current_pose.pose.position
    assert math.hypot(last.x - x, last.y - y) < 0.3, "the robot's pose, in map"
    navigate_status = loop.status(Service.ROS2)["navigate"]
    assert navigate_status["goals"][uuid.hex()] == "succeeded" and navigate_status["succeeded"] >= 1
    # a ROS node started after the goal ended gets the status from the bridge's cache (transient-local, as rcl's)
    with peer_session(loop.endpoint) as late:
        status = "/navigate_to_pose/_action/status"
        cached = ros_client.cached_samples(late, DOMAIN, {status: "action_msgs/msg/GoalStatusArray"}, 10.0)
    assert ros_client.goal_statuses(cached[status])[uuid] == 4


@pytest.mark.slow
def test_goals_canceled_by_id_preempted_and_canceled_all_end_canceled_in_the_status(loop):
    far = loop.ahead(3.0)
    second, reply = loop.client.send_goal(*far)
    assert reply.response.accepted
    loop.wait_status(second, 2)
    canceled = loop.client.cancel(second)
    assert canceled.response.return_code == 0
    assert [bytes(bytearray(g.goal_id.uuid)) for g in canceled.response.goals_canceling] == [second]
    result = loop.client.get_result(second, timeout=30.0)
    assert result.response.status == 5 and result.response.result.error_code == 0
    statuses = loop.wait_status(second, 5)
    assert statuses[-2:] == [3, 5], "canceling, then canceled"
    assert loop.client.cancel(second).response.return_code == 3, "already terminated"
    assert loop.client.cancel(os.urandom(16)).response.return_code == 2, "an unknown goal"
    assert loop.client.get_result(os.urandom(16)).response.status == 0, "an unknown goal's result: unknown, at once"

    third, _ = loop.client.send_goal(*loop.ahead(3.0))
    loop.wait_status(third, 2)
    fourth, reply = loop.client.send_goal(*loop.ahead(3.0))
    assert reply.response.accepted
    preempted = loop.client.get_result(third, timeout=30.0).response
    assert preempted.status == 5 and fourth.hex() in preempted.result.error_msg, "preempted by the newer goal"
    loop.wait_status(fourth, 2)
    everything = loop.client.cancel()
    assert everything.response.return_code == 0, "a zero id and stamp: cancel all"
    assert [bytes(bytearray(g.goal_id.uuid)) for g in everything.response.goals_canceling] == [fourth]
    loop.wait_status(fourth, 5)
    wait_until(lambda: _at_rest(loop), 10.0, "the robot at rest")
    assert loop.client.cancel().response.return_code == 0, "cancel all with none running: none, no error"


@pytest.mark.slow
def test_goal_pose_sends_goals_in_odom_whose_status_and_feedback_show_one_succeed_and_one_canceled(loop):
    """RViz's 2D Goal Pose: a PoseStamped on ``/goal_pose``, in ``odom`` (RViz's fixed frame): the
    bridge turns it into ``map`` with its own map -> odom and sends it; no client waits for a result."""
    x, y, theta = loop.ahead(0.4, turn=-0.5)  # in map; the bridge's odom is the robot's start, here map's origin
    tf = ros_client.TYPESTORE.deserialize_cdr(loop.recorder.of("tf")[-1].payload, "tf2_msgs/msg/TFMessage")
    (map_to_odom,) = [t.transform for t in tf.transforms if (t.header.frame_id, t.child_frame_id) == ("map", "odom")]
    correction = Pose(
        map_to_odom.translation.x,
        map_to_odom.translation.y,
        2 * math.atan2(map_to_odom.rotation.z, map_to_odom.rotation.w),
    )
    uuid = _goal_pose(loop, core.compose(core.inverse(correction), Pose(x, y, theta)))
    assert loop.wait_status(uuid, 4, timeout=60.0)[-1] == 4
    assert loop.feedback(uuid), "its feedback on the action's topic"
    truth = loop.ground_truth()
    assert math.hypot(truth.x - x, truth.y - y) <= GOALS.position_tolerance + 0.01
    assert abs(math.remainder(truth.theta - theta, math.tau)) <= GOALS.heading_tolerance
    # a second one, far: an action client's cancel-all cancels it as any goal of the action
    far = _goal_pose(loop, core.compose(core.inverse(correction), Pose(*loop.ahead(3.0))))
    loop.wait_status(far, 2)
    canceled = loop.client.cancel().response
    assert canceled.return_code == 0 and [bytes(bytearray(g.goal_id.uuid)) for g in canceled.goals_canceling] == [far]
    assert loop.wait_status(far, 5)[-2:] == [3, 5]


def _goal_pose(loop: GoalLoop, pose: Pose) -> bytes:
    """Publish ``pose`` (in odom) on ``goal_pose`` as RViz does; the UUID the bridge gave its goal."""
    listed = loop.recorder.of(STATUS)
    before = set(ros_client.goal_statuses(listed[-1].payload)) if listed else set()
    loop.node.put("goal_pose", ros_client.pose_stamped(pose.x, pose.y, pose.theta, "odom", ros_client.TYPESTORE))
    return wait_until(
        lambda: (
            (listed := loop.recorder.of(STATUS))
            and next(iter(set(ros_client.goal_statuses(listed[-1].payload)) - before), None)
        ),
        10.0,
        "a new goal in the status",
    )


@pytest.mark.slow
def test_hostile_requests_are_refused_in_the_reply_counted_and_the_running_goal_goes_on(loop):
    x, y, theta = loop.ahead(0.8)
    running, reply = loop.client.send_goal(x, y, theta)
    assert reply.response.accepted
    loop.wait_status(running, 2)
    sent_before = loop.status(Service.ROS2)["navigate"]["sent"]
    good = ros_client.send_goal_request(os.urandom(16), ros_client.pose_stamped(1.0, 0.0, 0.0))
    send_key, cancel_key, result_key = (loop.client.key(e) for e in ("send_goal", "cancel_goal", "get_result"))
    goal_pose_key = ros_client.topic_key(DOMAIN, "goal_pose", "geometry_msgs/msg/PoseStamped")
    refused_goals = [
        (ros_client.send_goal_request(os.urandom(16), ros_client.pose_stamped(math.nan, 0.0, 0.0)), "not finite"),
        (
            ros_client.send_goal_request(os.urandom(16), ros_client.pose_stamped(1.0, 0.0, 0.0, "base_link")),
            "frame 'base_link'",
        ),
        (ros_client.send_goal_request(running, ros_client.pose_stamped(1.0, 0.0, 0.0)), "exists already"),
        (b"\x00\x01\x00\x00" + b"\x07" * 9, "malformed CDR"),
        (good + bytes(5000), "more than a send_goal request's"),
    ]
    for payload, reason in refused_goals:
        answer = loop.client.call("send_goal", payload)
        assert answer.response is not None and not answer.response.accepted, reason
        assert reason in loop.status(Service.ROS2)["navigate"]["last_rejection"]
    assert loop.bad_inputs(send_key) >= 4
    unattached = loop.client.call("send_goal", good, with_attachment=False)
    assert unattached.error is not None and "no attachment" in unattached.error, "an error reply: nothing to echo"
    assert loop.client.call("cancel_goal", b"\x00\x01\x00\x00\x01").response.return_code == 1
    assert loop.client.call("cancel_goal", ros_client.cancel_request() + bytes(100)).response.return_code == 1
    assert loop.client.call("get_result", b"\x00\x01\x00\x00").response.status == 0
    assert loop.bad_inputs(cancel_key) == 2 and loop.bad_inputs(result_key) == 1
    for payload, attached in (
        (b"\x00\x01\x00\x00\x02", True),
        (ros_client.cdr(ros_client.pose_stamped(math.inf, 0.0, 0.0, "map", ros_client.TYPESTORE)), True),
        (ros_client.cdr(ros_client.pose_stamped(1.0, 0.0, 0.0, "earth", ros_client.TYPESTORE)), True),
        (ros_client.cdr(ros_client.pose_stamped(1.0, 0.0, 0.0, "map", ros_client.TYPESTORE)), False),
        (bytes(5000), True),
    ):
        counted = loop.bad_inputs(goal_pose_key)
        loop.node.put_raw(goal_pose_key, payload, ros_client.attachment(1, loop.node.gid) if attached else None)
        wait_until(lambda c=counted: loop.bad_inputs(goal_pose_key) > c, 10.0, "the goal pose counted")
    status = loop.status(Service.ROS2)
    assert status["navigate"]["sent"] == sent_before, "nothing reached the drive"
    assert status["internal_errors"] == 0
    result = loop.client.get_result(running, timeout=60.0)
    assert result.response.status == 4, "the running goal went on, untouched"
    truth = loop.ground_truth()
    assert math.hypot(truth.x - x, truth.y - y) <= GOALS.position_tolerance
