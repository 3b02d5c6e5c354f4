"""The particle filter in ROS 2 (services/ros2/graph.py, core.py, navigate.py, outputs.py,
service.py), as nav2_amcl offers it: ``localization/pose`` with a covariance as ``amcl_pose``
(geometry_msgs/PoseWithCovarianceStamped, latched), ``localization/particles`` as ``particle_cloud``
(geometry_msgs/PoseArray, sensor QoS), and ``initialpose`` (RViz's 2D Pose Estimate) as a query of
``localization/initial_pose``.

The pure mapping first (the 6 × 6 covariance's layout, a pose estimate in ``odom`` turned into
``map`` with its covariance, bad estimates refused); then on a real zenoh network the real
``invent ros2`` with ``localization.mode = "amcl"``, fed by a stand-in simulator clock and
localization (this test's session: forged ``localization/pose`` and ``localization/particles``, and
a queryable on ``localization/initial_pose`` answering as the particle filter does), against a ROS
node's side (tests/ros_client.py: its keys, attachments and CDR from rosbags' typestore, written
apart from the bridge).
"""

from __future__ import annotations

import math
import queue
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import zenoh

from schemas.codec import BadInput, decode, encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from schemas.navigation import InitialPose, LocalizationReply, ParticleCloud
from services.config import load_config
from services.planar import Pose
from services.ros2 import graph, interfaces, navigate, wire
from services.ros2.graph import bridge_graph
from services.ros2.outputs import RosOutputs
from tests import ros_client
from tests.harness import InventProcess, call, peer_session, running_router, status_reply, wait_until

MS = 1_000_000
S = 1_000 * MS
DOMAIN = 0
KEYS = Keys()
AMCL = {"localization.mode": "amcl", "navigation.map": "unused-by-the-bridge.yaml"}
"""The bridge reads ``localization.mode`` only; a particle filter's configuration needs a map's name."""
POSE_WITH_COVARIANCE = interfaces.POSE_WITH_COVARIANCE_STAMPED
COVARIANCE = [0.04, 0.01, 0.002, 0.09, -0.003, 0.05]
"""xx, xy, xθ, yy, yθ, θθ."""
FRAMES = navigate.GoalFrames("map", "odom")


def _outputs(**overrides: Any) -> RosOutputs:
    config = load_config(overrides={**AMCL, **overrides})
    return RosOutputs(config, bridge_graph(config, environ={}))


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * S + int(stamp.nanosec)


def _yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


def _estimate(stamp_ns: int, x: float, y: float, theta: float, error: list[float]) -> TimedPosition:
    return TimedPosition(tm=Time.from_nanoseconds(stamp_ns), id=[], x=x, y=y, theta=theta, error=error)


def _covariance_36(xx: float, xy: float, xt: float, yy: float, yt: float, tt: float) -> np.ndarray:
    """A ROS pose covariance with the planar entries at (x, y, yaw) = axes (0, 1, 5)."""
    matrix = np.zeros((6, 6))
    for (a, b), value in {(0, 0): xx, (0, 1): xy, (0, 5): xt, (1, 1): yy, (1, 5): yt, (5, 5): tt}.items():
        matrix[a, b] = matrix[b, a] = value
    return matrix.reshape(36)


def pose_estimate(
    x: float,
    y: float,
    yaw: float,
    frame: str = "map",
    covariance: np.ndarray | None = None,
    orientation: tuple[float, float, float, float] | None = None,
) -> Any:
    """geometry_msgs/PoseWithCovarianceStamped as RViz's 2D Pose Estimate publishes it (ROS's types)."""
    types = ros_client.TYPESTORE.types
    qx, qy, qz, qw = orientation or (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    return types[POSE_WITH_COVARIANCE](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame
        ),
        pose=types["geometry_msgs/msg/PoseWithCovariance"](
            pose=types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
            ),
            covariance=_covariance_36(0.25, 0.0, 0.0, 0.25, 0.0, 0.0685) if covariance is None else covariance,
        ),
    )


# -- the graph ---------------------------------------------------------------------------------


def test_the_localization_topics_are_nav2_amcls_names_and_qos_and_only_with_the_particle_filter():
    bridge = bridge_graph(load_config(overrides={**AMCL, "ros2.namespace": "rh1"}), environ={})
    amcl_pose, particles = bridge.publications["amcl_pose"], bridge.publications["particle_cloud"]
    assert (bridge.name(amcl_pose), amcl_pose.interface) == ("/rh1/amcl_pose", POSE_WITH_COVARIANCE)
    assert amcl_pose.qos.token_chunk() == ":1:,1:,:,:,,", "reliable, transient local, keep-last 1 (nav2_amcl's)"
    assert (bridge.name(particles), particles.interface) == ("/rh1/particle_cloud", interfaces.POSE_ARRAY)
    assert particles.qos.token_chunk() == "2::,5:,:,:,,", "SensorDataQoS (nav2_amcl's)"
    assert graph.INITIAL_POSE in bridge.subscriptions and bridge.name(graph.INITIAL_POSE) == "/rh1/initialpose"
    assert graph.INITIAL_POSE.qos == wire.SYSTEM_DEFAULT, "nav2_amcl subscribes it with SystemDefaultsQoS"
    for entity in (amcl_pose, particles, graph.INITIAL_POSE):
        assert bridge.key(entity) == ros_client.topic_key(0, bridge.name(entity), entity.interface), "ROS's hash"
    assert graph.INITIAL_POSE in graph.SUBSCRIPTIONS, "what the secure profile grants"
    stub = bridge_graph(load_config(overrides={"ros2.namespace": "rh1"}), environ={})
    assert not set(graph.LOCALIZATION_TOPICS) & set(stub.publications)
    assert graph.INITIAL_POSE not in stub.subscriptions


# -- amcl_pose and particle_cloud ----------------------------------------------------------------


def test_an_estimate_with_a_covariance_is_an_amcl_pose_its_6x6_filled_at_x_y_and_yaw():
    outputs = _outputs()
    (out,) = outputs.take_amcl_pose(_estimate(1_250 * MS, 1.5, -0.5, 0.75, COVARIANCE))
    assert (out.topic, out.stamp_ns) == ("amcl_pose", 1_250 * MS)
    decoded = ros_client.TYPESTORE.deserialize_cdr(interfaces.serialize(out.message), POSE_WITH_COVARIANCE)
    assert (decoded.header.frame_id, _stamp_ns(decoded.header.stamp)) == ("map", 1_250 * MS)
    pose = decoded.pose.pose
    assert (pose.position.x, pose.position.y, pose.position.z) == (1.5, -0.5, 0.0)
    assert (pose.orientation.x, pose.orientation.y) == (0.0, 0.0) and _yaw(pose.orientation) == pytest.approx(0.75)
    matrix = np.asarray(decoded.pose.covariance).reshape(6, 6)
    xx, xy, xt, yy, yt, tt = COVARIANCE
    expected = np.zeros((6, 6))
    expected[0, 0], expected[1, 1], expected[5, 5] = xx, yy, tt
    expected[0, 1] = expected[1, 0] = xy
    expected[0, 5] = expected[5, 0] = xt
    expected[1, 5] = expected[5, 1] = yt
    assert np.array_equal(matrix, expected), "row-major (x, y, z, roll, pitch, yaw); z, roll, pitch zero"
    assert (matrix[0, 5], matrix[5, 1], matrix[5, 5]) == (0.002, -0.003, 0.05), "indices 5, 31 and 35"


def test_an_estimate_without_a_covariance_is_no_amcl_pose_and_a_bad_one_is_bad_input():
    outputs = _outputs()
    assert outputs.take_amcl_pose(_estimate(S, 0.0, 0.0, 0.0, [])) == [], "the stub's fix: no /amcl_pose"
    with pytest.raises(BadInput, match="neither none nor a covariance's 6"):
        outputs.take_amcl_pose(_estimate(S, 0.0, 0.0, 0.0, [0.1, 0.1, 0.1]))
    assert outputs.take_amcl_pose(_estimate(2 * S, 0.0, 0.0, 0.0, COVARIANCE))
    with pytest.raises(BadInput, match="before the last amcl_pose's"):
        outputs.take_amcl_pose(_estimate(S, 0.0, 0.0, 0.0, COVARIANCE))
    stub = RosOutputs(load_config(), bridge_graph(load_config(), environ={}))
    assert stub.take_amcl_pose(_estimate(S, 0.0, 0.0, 0.0, COVARIANCE)) == [], "no particle filter configured"


def test_the_particles_are_a_pose_array_in_map():
    outputs = _outputs()
    cloud = ParticleCloud(
        tm=Time.from_nanoseconds(3 * S), x=[0.0, 1.0, -2.0], y=[0.5, 0.0, 3.0], theta=[0.0, math.pi / 2, -3.0],
        weight=[0.5, 0.25, 0.25],
    )  # fmt: skip
    (out,) = outputs.take_particles(cloud)
    assert (out.topic, out.stamp_ns) == ("particle_cloud", 3 * S)
    decoded = ros_client.TYPESTORE.deserialize_cdr(interfaces.serialize(out.message), interfaces.POSE_ARRAY)
    assert (decoded.header.frame_id, _stamp_ns(decoded.header.stamp)) == ("map", 3 * S)
    assert [(p.position.x, p.position.y) for p in decoded.poses] == [(0.0, 0.5), (1.0, 0.0), (-2.0, 3.0)]
    assert [_yaw(p.orientation) for p in decoded.poses] == pytest.approx([0.0, math.pi / 2, -3.0])


# -- initialpose ---------------------------------------------------------------------------------


def test_a_pose_estimate_in_map_becomes_an_initial_pose_with_its_planar_covariance():
    covariance = _covariance_36(0.25, 0.01, 0.02, 0.16, -0.03, 0.07)
    request = navigate.initial_pose_request(pose_estimate(1.0, 2.0, 0.5, covariance=covariance), FRAMES, None, 50.0)
    assert (request.x, request.y, request.theta) == (1.0, 2.0, pytest.approx(0.5))
    assert request.covariance == [0.25, 0.01, 0.02, 0.16, -0.03, 0.07], "xx, xy, xθ, yy, yθ, θθ"
    zero = navigate.initial_pose_request(pose_estimate(1.0, 2.0, 0.5, covariance=np.zeros(36)), FRAMES, None, 50.0)
    assert zero.covariance == [], "no covariance given: the localization's own initial spread"


def test_a_pose_estimate_in_odom_is_turned_into_map_with_its_covariance():
    map_to_odom = Pose(1.0, -1.0, math.pi / 2)
    covariance = _covariance_36(0.04, 0.0, 0.01, 0.01, 0.0, 0.02)
    request = navigate.initial_pose_request(
        pose_estimate(2.0, 0.0, 0.0, frame="odom", covariance=covariance), FRAMES, map_to_odom, 50.0
    )
    assert (request.x, request.y, request.theta) == pytest.approx((1.0, 1.0, math.pi / 2))
    xx, xy, xt, yy, yt, tt = request.covariance
    assert (xx, xy, yy, tt) == pytest.approx((0.01, 0.0, 0.04, 0.02)), "x and y swap under a quarter turn"
    assert (xt, yt) == pytest.approx((0.0, 0.01)), "the x-yaw term turns with them"
    with pytest.raises(BadInput, match="before the bridge has map -> odom"):
        navigate.initial_pose_request(pose_estimate(0.0, 0.0, 0.0, frame="odom"), FRAMES, None, 50.0)


@pytest.mark.parametrize(
    ("estimate", "reason"),
    [
        (pose_estimate(0.0, 0.0, 0.0, frame="base_link"), "neither 'map' nor 'odom'"),
        (pose_estimate(math.nan, 0.0, 0.0), "not finite"),
        (pose_estimate(0.0, 51.0, 0.0), "beyond input.max_coordinate"),
        (pose_estimate(0.0, 0.0, 0.0, orientation=(0.2, 0.0, 0.0, 0.98)), "not a turn about z"),
        (pose_estimate(0.0, 0.0, 0.0, orientation=(0.0, 0.0, 0.0, 0.0)), "no rotation"),
        (pose_estimate(0.0, 0.0, 0.0, orientation=(0.0, 0.0, math.inf, 1.0)), "not finite"),
        (pose_estimate(0.0, 0.0, 0.0, covariance=_covariance_36(math.nan, 0, 0, 1, 0, 1)), "not finite"),
        (pose_estimate(0.0, 0.0, 0.0, covariance=_covariance_36(-1.0, 0, 0, 1, 0, 1)), "non-negative"),
    ],
)
def test_a_bad_pose_estimate_is_refused(estimate, reason):
    with pytest.raises(BadInput, match=reason):
        navigate.initial_pose_request(estimate, FRAMES, Pose(0.0, 0.0, 0.0), 50.0)


# -- the bridge on a zenoh network ---------------------------------------------------------------


@dataclass
class Stand:
    """The test's session: the stand-in simulator's clock and localization, a ROS node, and the
    localization's ``initial_pose`` queryable (its queries kept, its replies chosen by the test)."""

    session: zenoh.Session
    recorder: ros_client.Recorder
    node: ros_client.RosNode
    initial_poses: queue.Queue[InitialPose]
    replies: list[LocalizationReply]
    clock_ns: int = 0

    def tick(self, steps: int = 1) -> int:
        for _ in range(steps):
            self.clock_ns += 10 * MS
            payload = encode(TimedDoubleSeq(tm=Time.from_nanoseconds(self.clock_ns), data=[0.0, 0.0]))
            self.session.put(KEYS.sim_clock, payload)
            time.sleep(0.002)  # a pace, as a simulator's steps come
        return self.clock_ns

    def status(self) -> dict[str, Any]:
        return status_reply(self.session, KEYS, Service.ROS2)

    def received(self, topic: str, interface: str) -> list[Any]:
        key = ros_client.topic_key(DOMAIN, topic, interface)
        return [
            ros_client.TYPESTORE.deserialize_cdr(s.payload, interface) for s in self.recorder.take() if s.key == key
        ]

    def bad_input(self, key: str) -> dict[str, Any]:
        return self.status()["bad_input"]["by_key"].get(key, {"count": 0, "last_reason": ""})


@pytest.fixture(scope="module")
def stand() -> Iterator[Stand]:
    """``invent ros2 --set localization.mode=amcl`` on a router of the module's own."""
    overrides = [arg for key, value in AMCL.items() for arg in ("--set", f"{key}={value}")]
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        initial_poses: queue.Queue[InitialPose] = queue.Queue()
        replies: list[LocalizationReply] = []

        def answer(query: zenoh.Query) -> None:
            initial_poses.put(decode(InitialPose, query.payload.to_bytes() if query.payload else b""))
            reply = replies.pop(0) if replies else LocalizationReply(True)
            query.reply(KEYS.localization_initial_pose, encode(reply))

        queryable = session.declare_queryable(KEYS.localization_initial_pose, answer)
        with InventProcess("ros2", "--connect", endpoint, *overrides, drain=True) as process:
            state = Stand(session, recorder, ros_client.RosNode(session), initial_poses, replies)
            wait_until(lambda: call(session, KEYS.status(Service.ROS2))[0], 30.0, "the bridge")
            wait_until(lambda: _subscribed(session, "%initialpose"), 10.0, "the bridge's initialpose subscription")
            state.tick(3)
            yield state
            code, _out, err = process.stop()
        queryable.undeclare()
        recorder.close()
    assert code == 0, err[-3000:]


def _subscribed(session: zenoh.Session, name: str) -> bool:
    return any(chunks[5] == "MS" and chunks[9] == name for chunks in ros_client.graph_tokens(session, DOMAIN))


@pytest.mark.slow
def test_a_forged_estimate_with_a_covariance_reaches_ros_as_amcl_pose_and_a_stub_fix_does_not(stand):
    now_ns = stand.tick()
    stand.session.put(KEYS.localization_pose, encode(_estimate(now_ns, 0.0, 0.0, 0.0, [])))
    later_ns = stand.tick()
    stand.session.put(KEYS.localization_pose, encode(_estimate(later_ns, 2.0, 1.0, -0.5, COVARIANCE)))
    (estimate,) = wait_until(lambda: stand.received("/amcl_pose", POSE_WITH_COVARIANCE), 10.0, "/amcl_pose")
    assert (estimate.header.frame_id, _stamp_ns(estimate.header.stamp)) == ("map", later_ns), "not the stub's fix"
    assert (estimate.pose.pose.position.x, estimate.pose.pose.position.y) == (2.0, 1.0)
    assert _yaw(estimate.pose.pose.orientation) == pytest.approx(-0.5)
    matrix = np.asarray(estimate.pose.covariance).reshape(6, 6)
    assert matrix[np.ix_((0, 1, 5), (0, 1, 5))].tolist() == [
        [0.04, 0.01, 0.002],
        [0.01, 0.09, -0.003],
        [0.002, -0.003, 0.05],
    ]
    assert not matrix[2:5].any() and not matrix[:, 2:5].any(), "z, roll and pitch zero"
    late = ros_client.cached_samples(stand.session, DOMAIN, {"/amcl_pose": POSE_WITH_COVARIANCE}, 10.0)
    cached = ros_client.TYPESTORE.deserialize_cdr(late["/amcl_pose"], POSE_WITH_COVARIANCE)
    assert _stamp_ns(cached.header.stamp) == later_ns, "latched: a late subscriber gets the last"
    assert stand.status()["published"]["/amcl_pose"] == 1


@pytest.mark.slow
def test_forged_particles_reach_ros_as_the_particle_cloud(stand):
    now_ns = stand.tick()
    count = 200
    cloud = ParticleCloud(
        tm=Time.from_nanoseconds(now_ns),
        x=[0.01 * i for i in range(count)],
        y=[-0.02 * i for i in range(count)],
        theta=[math.pi * (i / count - 0.5) for i in range(count)],
        weight=[1.0 / count] * count,
    )
    stand.session.put(KEYS.localization_particles, encode(cloud))
    stand.tick()  # the bridge takes the newest particles when its clock wakes it
    (poses,) = wait_until(lambda: stand.received("/particle_cloud", interfaces.POSE_ARRAY), 10.0, "/particle_cloud")
    assert (poses.header.frame_id, _stamp_ns(poses.header.stamp)) == ("map", now_ns)
    assert [(p.position.x, p.position.y) for p in poses.poses] == list(zip(cloud.x, cloud.y, strict=True))
    assert [_yaw(p.orientation) for p in poses.poses] == pytest.approx(cloud.theta)


@pytest.mark.slow
def test_an_initialpose_becomes_a_query_of_the_localization_and_its_refusal_is_counted(stand):
    covariance = _covariance_36(0.25, 0.02, 0.01, 0.16, -0.01, 0.0685)
    stand.node.put("initialpose", pose_estimate(1.5, -2.0, 1.0, covariance=covariance))
    request = stand.initial_poses.get(timeout=10.0)
    assert (request.x, request.y, request.theta) == (1.5, -2.0, pytest.approx(1.0))
    assert request.covariance == pytest.approx([0.25, 0.02, 0.01, 0.16, -0.01, 0.0685])
    wait_until(lambda: stand.status()["initial_pose"]["accepted"] == 1, 10.0, "the localization's acceptance")
    stand.replies.append(LocalizationReply(False, "refused: (40, 0) is outside the map"))
    stand.node.put("initialpose", pose_estimate(40.0, 0.0, 0.0))
    assert stand.initial_poses.get(timeout=10.0).x == 40.0
    status = wait_until(lambda: (s := stand.status())["initial_pose"]["refused"] == 1 and s, 10.0, "the refusal")
    assert status["initial_pose"]["last_refusal"] == "refused: (40, 0) is outside the map"
    assert status["initial_pose"]["received"] == 2 and status["initial_pose"]["waiting"] == 0


@pytest.mark.slow
def test_a_bad_initialpose_is_counted_and_never_queried_and_the_bridge_lives_on(stand):
    key = bridge_graph(load_config(overrides=AMCL), environ={}).key(graph.INITIAL_POSE)
    good = ros_client.cdr(pose_estimate(0.0, 0.0, 0.0))
    attachment = ros_client.attachment(1, bytes(16))
    forgeries = [
        (ros_client.cdr(pose_estimate(0.0, 0.0, 0.0, frame="base_link")), attachment, "neither 'map' nor 'odom'"),
        (ros_client.cdr(pose_estimate(0.0, 0.0, 0.0, orientation=(0.0, 0.3, 0.0, 0.95))), attachment, "about z"),
        (ros_client.cdr(pose_estimate(math.inf, 0.0, 0.0)), attachment, "not finite"),
        (ros_client.cdr(pose_estimate(0.0, 1e6, 0.0)), attachment, "max_coordinate"),
        (good[:40], attachment, "malformed CDR"),
        (good, None, "no attachment"),
        (good + bytes(8192), attachment, "more than a pose estimate's"),
    ]
    for payload, attached, reason in forgeries:
        counted = stand.bad_input(key)["count"]
        stand.node.put_raw(key, payload, attached)
        entry = wait_until(lambda c=counted: (e := stand.bad_input(key))["count"] > c and e, 10.0, reason)
        assert reason in entry["last_reason"], entry
    assert stand.initial_poses.empty(), "nothing reached the localization"
    status = stand.status()
    assert status["internal_errors"] == 0
    stand.node.put("initialpose", pose_estimate(0.5, 0.5, 0.0))
    assert stand.initial_poses.get(timeout=10.0).x == 0.5, "the next good one goes through"
