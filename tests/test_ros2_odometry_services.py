"""The bridge's ``~/reset_odometry`` (std_srvs/srv/Empty) and ``~/set_odometry``
(control_msgs/srv/SetOdometry), as ros2_controllers offers them (services/ros2/odometry_services.py,
``ContinuousOdometry.set_pose`` in core.py, the frames in outputs.py).

The pure part first: the pose set at the next tick, ``map -> odom`` taking the change so that
``map -> base_link`` does not move, a localized pose of an earlier stamp meeting the poses kept in
the new frame. Then the real ``invent ros2``, fed by a stand-in simulator clock (this test's
session), called by a ROS node's side (tests/ros_client.py: keys, attachments, and the services'
types and hashes from ROS's own type descriptions, apart from the bridge's), as
diff_drive_controller's ``odometry_set_service`` test calls its service: move, set, the next update
reports the pose set, moving on goes on from it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import zenoh

from schemas.codec import BadInput, encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.config import load_config
from services.planar import Pose, compose
from services.ros2.graph import bridge_graph
from services.ros2.outputs import RosOutputs
from tests import ros_client, ros_services
from tests.harness import InventProcess, call, peer_session, running_router, wait_until

MS = 1_000_000
DOMAIN = 0
KEYS = Keys()
EMPTY, SET_ODOMETRY = "std_srvs/srv/Empty", "control_msgs/srv/SetOdometry"
SERVICES = {"reset_odometry": EMPTY, "set_odometry": SET_ODOMETRY}


def wheels(stamp_ns: int, left: float, right: float) -> TimedDoubleSeq:
    return TimedDoubleSeq(tm=Time.from_nanoseconds(stamp_ns), data=[left, right])


def outputs() -> RosOutputs:
    config = load_config()
    return RosOutputs(config, bridge_graph(config, environ={}))


# -- pure: the continuous odometry and the frames --------------------------------------------------


def test_the_pose_set_is_odoms_at_the_next_tick_and_the_motion_goes_on_from_it():
    ros = outputs()
    ros.take_wheels(wheels(0, 0.0, 0.0))
    ros.take_wheels(wheels(10 * MS, 0.25, 0.25))
    assert ros.odometry.pose.x == pytest.approx(0.025)
    ros.odometry.set_pose(5.0, -2.0, math.pi / 2)
    assert ros.odometry.pose.x == pytest.approx(0.025), "not before the next tick"
    ros.take_wheels(wheels(20 * MS, 0.25, 0.25))
    assert ros.odometry.pose == Pose(5.0, -2.0, math.pi / 2)
    ros.take_wheels(wheels(30 * MS, 0.5, 0.5))
    assert ros.odometry.pose.x == pytest.approx(5.0) and ros.odometry.pose.y == pytest.approx(-1.975)


def test_a_reset_is_the_origin_at_the_next_tick():
    ros = outputs()
    ros.take_wheels(wheels(0, 0.0, 0.0))
    ros.take_wheels(wheels(10 * MS, 0.25, 0.1))
    ros.odometry.set_pose(0.0, 0.0, 0.0)
    ros.take_wheels(wheels(20 * MS, 0.25, 0.1))
    assert ros.odometry.pose == Pose(0.0, 0.0, 0.0)


def test_map_to_odom_takes_the_change_so_map_to_base_link_does_not_move():
    ros = outputs()
    ros.take_wheels(wheels(0, 0.0, 0.0))
    ros.take_wheels(wheels(10 * MS, 0.25, 0.4))
    ros.take_localized(TimedPosition(tm=Time.from_nanoseconds(10 * MS), id=[], x=3.0, y=4.0, theta=0.5, error=[]))
    assert ros.map_to_odom is not None
    map_to_base = compose(ros.map_to_odom[1], ros.odometry.pose)
    ros.odometry.set_pose(-1.0, 2.0, -2.0)
    ros.take_wheels(wheels(20 * MS, 0.25, 0.4))  # the wheels still: the robot has not moved
    stamp_ns, correction = ros.map_to_odom
    assert stamp_ns == 20 * MS, "stamped at the tick it changed"
    after = compose(correction, ros.odometry.pose)
    assert (after.x, after.y) == pytest.approx((map_to_base.x, map_to_base.y))
    assert math.remainder(after.theta - map_to_base.theta, math.tau) == pytest.approx(0.0, abs=1e-12)
    # A localized pose of a stamp before the set meets the kept poses in the new frame: same map -> odom.
    ros.take_localized(TimedPosition(tm=Time.from_nanoseconds(10 * MS), id=[], x=3.0, y=4.0, theta=0.5, error=[]))
    again = ros.map_to_odom[1]
    assert (again.x, again.y) == pytest.approx((correction.x, correction.y))
    assert math.remainder(again.theta - correction.theta, math.tau) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(("x", "y", "theta"), [(math.nan, 0.0, 0.0), (0.0, 0.0, math.inf), (1e9, 0.0, 0.0)])
def test_a_pose_not_finite_or_beyond_the_coordinates_is_refused(x, y, theta):
    ros = outputs()
    ros.take_wheels(wheels(0, 0.0, 0.0))
    with pytest.raises(BadInput):
        ros.odometry.set_pose(x, y, theta)
    ros.take_wheels(wheels(10 * MS, 0.0, 0.0))
    assert ros.odometry.pose == Pose(0.0, 0.0, 0.0)


# -- the bridge on a zenoh network ---------------------------------------------------------------


@dataclass
class Stand:
    """The test's session: the stand-in simulator's clock (its wheel angles), and a ROS node."""

    session: zenoh.Session
    recorder: ros_client.Recorder
    node: ros_client.RosNode
    clock_ns: int = 0
    angle: float = 0.0

    def tick(self, steps: int = 1, turn: float = 0.0) -> int:
        """``steps`` simulator steps of 10 ms, both wheels turning by ``turn`` rad each."""
        for _ in range(steps):
            self.clock_ns += 10 * MS
            self.angle += turn
            self.session.put(KEYS.sim_clock, encode(wheels(self.clock_ns, self.angle, self.angle)))
            time.sleep(0.002)  # a pace, as a simulator's steps come
        return self.clock_ns

    def odom(self, after_ns: int) -> Pose:
        """The pose of the first ``/odom`` stamped after ``after_ns`` (ticking until it comes)."""
        key = ros_client.topic_key(DOMAIN, "odom", "nav_msgs/msg/Odometry")

        def published() -> Any:
            for sample in self.recorder.take():
                if sample.key == key:
                    message = ros_client.TYPESTORE.deserialize_cdr(sample.payload, "nav_msgs/msg/Odometry")
                    if message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec > after_ns:
                        return message
            self.tick()
            return None

        message = wait_until(published, 10.0, f"an /odom after {after_ns} ns")
        pose, q = message.pose.pose.position, message.pose.pose.orientation
        return Pose(pose.x, pose.y, 2.0 * math.atan2(q.z, q.w))

    def call(self, service: str, request: Any, with_attachment: bool = True) -> ros_services.ServiceReply:
        """One call as an rmw_zenoh client: the request's CDR and attachment; the reply decoded."""
        interface = SERVICES[service]
        key = f"{DOMAIN}/invent_bridge/{service}/{ros_services.odometry_service_key_type(interface)}"
        querier = self.session.declare_querier(key, timeout=5.0)
        try:
            wait_until(lambda: querier.matching_status.matching, 10.0, f"a service on {key}")
            sequence_number = next(self.node._sequence)
            extra = {"attachment": ros_client.attachment(sequence_number, self.node.gid)} if with_attachment else {}
            payload = request if isinstance(request, bytes) else _cdr(request)
            replies = list(querier.get(payload=payload, **extra))
        finally:
            querier.undeclare()
        assert len(replies) == 1, f"{key}: {len(replies)} replies"
        (reply,) = replies
        if reply.ok is None:
            return ros_services.ServiceReply(None, reply.err.payload.to_bytes().decode(), None, sequence_number)
        store = ros_services.ODOMETRY_SERVICES_TYPESTORE
        return ros_services.ServiceReply(
            store.deserialize_cdr(reply.ok.payload.to_bytes(), f"{interface}_Response"),
            None,
            ros_client.read_attachment(reply.ok.attachment.to_bytes()),
            sequence_number,
        )

    def status(self) -> dict[str, Any]:
        ok, status = call(self.session, KEYS.status(Service.ROS2))
        assert ok
        return status


def _cdr(value: Any) -> bytes:
    return bytes(ros_services.ODOMETRY_SERVICES_TYPESTORE.serialize_cdr(value, value.__msgtype__))


def set_request(x: float, y: float, yaw: float, z: float = 0.0) -> Any:
    request = ros_services.ODOMETRY_SERVICES_TYPESTORE.types[f"{SET_ODOMETRY}_Request"]
    return request(x=x, y=y, z=z, roll=0.0, pitch=0.0, yaw=yaw)


def reset_request() -> Any:
    return ros_services.ODOMETRY_SERVICES_TYPESTORE.types[f"{EMPTY}_Request"]()


@pytest.fixture(scope="module")
def stand() -> Iterator[Stand]:
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        with InventProcess("ros2", "--connect", endpoint, drain=True) as process:
            state = Stand(session, recorder, ros_client.RosNode(session))
            wait_until(lambda: call(session, KEYS.status(Service.ROS2))[0], 30.0, "the bridge")
            state.tick(3)
            yield state
            code, _out, err = process.stop()
        recorder.close()
    assert code == 0, err[-3000:]


@pytest.mark.slow
def test_the_services_are_the_nodes_own_with_ross_types_and_hashes(stand):
    tokens = wait_until(
        lambda: (
            [c for c in ros_client.graph_tokens(stand.session, DOMAIN) if c[5] == "SS" and "odometry" in c[9]] or None
        ),
        10.0,
        "the odometry services' tokens",
    )
    assert {(c[9], c[10], c[11]) for c in tokens} == {
        (f"%invent_bridge%{service}", *ros_services.odometry_service_key_type(interface).split("/"))
        for service, interface in SERVICES.items()
    }


@pytest.mark.slow
def test_set_odometry_as_diff_drive_controller_tests_it(stand):
    """Move, set (5, −2, 90°): the reply accepts it, echoing the request's sequence number and GID;
    the next /odom reports the pose set; moving forward then goes along +y."""
    moved = stand.tick(5, turn=0.25)
    assert stand.odom(moved - 20 * MS).x > 0.0
    reply = stand.call("set_odometry", set_request(5.0, -2.0, math.pi / 2, z=3.0))
    assert (reply.response.success, reply.response.message) == (True, "Odometry set request accepted")
    assert reply.attachment is not None and reply.attachment[0] == reply.sequence_number
    assert reply.attachment[2] == stand.node.gid
    now = stand.clock_ns
    pose = stand.odom(now)
    assert (pose.x, pose.y, pose.theta) == pytest.approx((5.0, -2.0, math.pi / 2), abs=1e-9), "z is ignored"
    later = stand.tick(2, turn=0.25)
    after = stand.odom(later - 10 * MS)
    assert after.y > -2.0 and after.x == pytest.approx(5.0, abs=1e-9)
    assert stand.status()["odometry_services"]["set"] >= 1


@pytest.mark.slow
def test_reset_odometry_zeroes_odom(stand):
    moved = stand.tick(3, turn=0.25)
    assert stand.odom(moved - 20 * MS) != Pose(0.0, 0.0, 0.0)
    reply = stand.call("reset_odometry", reset_request())
    assert reply.error is None and reply.attachment is not None and reply.attachment[0] == reply.sequence_number
    assert stand.odom(stand.clock_ns) == Pose(0.0, 0.0, 0.0), "the wheels still since: the origin"
    assert stand.status()["odometry_services"]["reset"] >= 1


@pytest.mark.slow
@pytest.mark.parametrize(
    ("service", "request_", "with_attachment", "refusal"),
    [
        ("set_odometry", set_request(math.nan, 0.0, 0.0), True, "success false"),
        ("set_odometry", set_request(1e9, 0.0, 0.0), True, "success false"),
        ("set_odometry", b"\x00\x01\x00\x00\x01", True, "success false"),
        ("set_odometry", set_request(1.0, 1.0, 0.0), False, "error"),
        ("reset_odometry", b"\x00\x01\x00\x00" + bytes(100), True, "error"),
        ("reset_odometry", reset_request(), False, "error"),
    ],
    ids=["nan", "beyond_max_coordinate", "truncated_cdr", "no_attachment", "oversized", "reset_no_attachment"],
)
def test_a_bad_call_is_refused_counted_and_moves_nothing(stand, service, request_, with_attachment, refusal):
    stand.tick(1)
    before = stand.odom(stand.clock_ns - 10 * MS)
    key = f"{DOMAIN}/invent_bridge/{service}/{ros_services.odometry_service_key_type(SERVICES[service])}"
    counted = stand.status()["bad_input"]["by_key"].get(key, {"count": 0})["count"]
    reply = stand.call(service, request_, with_attachment=with_attachment)
    if refusal == "success false":
        assert reply.response.success is False and reply.response.message.startswith("refused")
    else:
        assert reply.error, "an error reply"
    assert stand.status()["bad_input"]["by_key"][key]["count"] == counted + 1
    assert stand.odom(stand.clock_ns) == before, "odom did not move"


@pytest.mark.slow
def test_a_wildcard_query_sets_nothing(stand):
    stand.tick(1)
    before = stand.odom(stand.clock_ns - 10 * MS)
    replies = list(
        stand.session.get(f"{DOMAIN}/invent_bridge/**", payload=_cdr(set_request(9.0, 9.0, 0.0)), timeout=1.0)
    )
    assert [reply for reply in replies if reply.ok is not None] == []
    assert stand.odom(stand.clock_ns) == before
