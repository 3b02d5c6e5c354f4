"""The ROS 2 bridge's pure core: messages built from the loop's, frames (REP 105), twists to
targets, and the URDF from the body the simulator builds. No zenoh."""

from __future__ import annotations

import math
from xml.etree import ElementTree

import pybullet as p
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.body.geometry import robot_body
from services.config import Config, load_config
from services.odometry.core import Odometry
from services.planar import Pose
from services.ros2 import core, interfaces
from services.ros2.urdf import robot_urdf
from sim_bridge.robot import build_robot
from sim_bridge.world import InitialPose

CONFIG = Config()
BODY = robot_body(CONFIG.robot, CONFIG.sim)
MS = 1_000_000
coordinates = st.floats(-100.0, 100.0)
angles = st.floats(-math.pi, math.pi)
poses = st.builds(Pose, coordinates, coordinates, angles)


def _close(a: Pose, b: Pose, tolerance: float = 1e-9) -> bool:
    return (
        math.isclose(a.x, b.x, abs_tol=tolerance)
        and math.isclose(a.y, b.y, abs_tol=tolerance)
        and abs(math.remainder(a.theta - b.theta, math.tau)) <= tolerance
    )


@given(poses)
def test_a_pose_composed_with_its_inverse_is_the_identity(pose):
    assert _close(core.compose(pose, core.inverse(pose)), Pose(0.0, 0.0, 0.0), 1e-9)


@given(poses, poses)
def test_map_to_odom_carries_odom_onto_the_localized_pose(localized, continuous):
    correction = core.compose(localized, core.inverse(continuous))
    assert _close(core.compose(correction, continuous), localized, 1e-7)


def _wheels(stamp_ns: int, left: float, right: float) -> TimedDoubleSeq:
    return TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), [left, right])


def test_continuous_odometry_is_the_odometry_core_without_fixes_and_keeps_poses_by_stamp():
    odometry, reference = core.ContinuousOdometry(CONFIG), Odometry(CONFIG.robot, CONFIG.odometry)
    for k in range(0, 200, 4):  # the bridge takes every fourth sample of a left turn
        sample = _wheels(k * MS, 0.003 * k, 0.005 * k)
        wheels = odometry.take(sample)
        reference.step(k * MS, sample.data)
    assert odometry.pose == reference.pose and odometry.velocity == reference.velocity
    assert wheels.angles == (0.003 * 196, 0.005 * 196)
    assert wheels.velocities == pytest.approx((3.0, 5.0))
    assert odometry.pose_at(196 * MS) == reference.pose
    assert odometry.pose_at(197 * MS) == reference.pose, "the newest at or before the stamp"
    assert odometry.pose_at(-1) is None
    odometry.restart()
    assert odometry.pose == Pose(0.0, 0.0, 0.0) and odometry.pose_at(196 * MS) is None
    odometry.take(_wheels(5 * MS, 1.0, 1.0))  # a new simulator's clock, from wherever its wheels are


def test_map_to_odom_is_none_without_a_pose_of_that_time():
    odometry = core.ContinuousOdometry(CONFIG)
    localized = TimedPosition(Time.from_nanoseconds(10 * MS), [], 1.0, 2.0, 0.5, [])
    assert core.map_to_odom(localized, odometry) is None
    odometry.take(_wheels(10 * MS, 0.0, 0.0))
    assert core.map_to_odom(localized, odometry) == Pose(1.0, 2.0, 0.5)


def test_the_odometry_message_is_in_odom_with_the_twist_in_base_link():
    odometry = core.ContinuousOdometry(CONFIG)
    odometry.take(_wheels(0, 0.0, 0.0))
    odometry.take(_wheels(20 * MS, 0.1, 0.1))  # 5 rad/s each wheel: 0.5 m/s straight
    message = core.odometry_message(20 * MS, odometry, CONFIG.ros2)
    assert message.__msgtype__ == interfaces.ODOMETRY
    assert (message.header.frame_id, message.child_frame_id) == ("odom", "base_link")
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (0, 20 * MS)
    assert message.pose.pose.position.x == pytest.approx(0.01)
    assert message.twist.twist.linear.x == pytest.approx(0.5) and message.twist.twist.angular.z == 0.0
    covariance = list(message.pose.covariance)
    assert covariance[0] == 0.001 and covariance[35] == 0.01 and covariance[1] == 0.0 and len(covariance) == 36
    decoded = interfaces.deserialize(interfaces.serialize(message), interfaces.ODOMETRY)
    assert decoded.pose.pose.position.x == pytest.approx(0.01)


def test_wheel_and_static_transforms_follow_the_body():
    left, right = core.wheel_transforms(5, "base_link", BODY, (math.pi, 0.0))
    assert (left.header.frame_id, left.child_frame_id) == ("base_link", "left_wheel")
    assert left.transform.translation.y == BODY.wheels[0].y > 0 > right.transform.translation.y
    assert left.transform.rotation.y == pytest.approx(1.0) and right.transform.rotation.w == 1.0
    front, rear = core.static_transforms(0, "base_link", BODY)
    assert (front.child_frame_id, front.transform.translation.x) == ("front_caster", BODY.casters[0].x)
    assert rear.transform.translation.z == BODY.casters[1].z < 0


def test_joint_states_name_the_urdfs_wheel_joints():
    state = core.joint_state(7, BODY, core.WheelSample(7, (1.0, 2.0), (3.0, 4.0)), (0.5, -0.5))
    assert list(state.name) == ["left_wheel_joint", "right_wheel_joint"]
    assert list(state.position) == [1.0, 2.0] and list(state.velocity) == [3.0, 4.0]
    assert list(state.effort) == [0.5, -0.5]
    assert list(core.joint_state(7, BODY, core.WheelSample(7, (1.0, 2.0), (0.0, 0.0)), None).effort) == []


def _twist(vx: float, w: float, stamped: bool = False):
    vector = interfaces.message_class("geometry_msgs/msg/Vector3")
    twist = interfaces.message_class(interfaces.TWIST)(linear=vector(vx, 0.7, 0.0), angular=vector(0.3, 0.0, w))
    if not stamped:
        return twist
    header = interfaces.message_class("std_msgs/msg/Header")(stamp=core.ros_time(123), frame_id="base_link")
    return interfaces.message_class(interfaces.TWIST_STAMPED)(header=header, twist=twist)


@pytest.mark.parametrize("stamped", [False, True], ids=["Twist", "TwistStamped"])
def test_a_twist_becomes_linear_x_and_angular_z(stamped):
    assert core.target_from_twist(_twist(0.4, -0.2, stamped), CONFIG) == (0.4, -0.2)


@pytest.mark.parametrize(
    ("vx", "w", "reason"),
    [(math.nan, 0.0, "not finite"), (0.0, math.inf, "not finite"), (100.0, 0.0, "max_wheel_speed")],
)
def test_a_twist_not_finite_or_implausible_is_bad_input(vx, w, reason):
    with pytest.raises(BadInput, match=reason):
        core.target_from_twist(_twist(vx, w), CONFIG)


def test_the_urdf_is_the_body_the_simulator_builds(tmp_path):
    """PyBullet loads the URDF: the same joints, axes, positions, masses and inertias as the
    multibody the simulator builds from the same robot description."""
    config = load_config(overrides={"robot.length_of_axle": 0.5, "sim.wheel_mass": 1.5})
    body = robot_body(config.robot, config.sim)
    text = robot_urdf("rh0", "base_link", body)
    root = ElementTree.fromstring(text)
    assert root.get("name") == "rh0" and root.find("link").get("name") == "base_link"
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    client = p.connect(p.DIRECT)
    try:
        loaded = p.loadURDF(str(path), flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        built = build_robot(client, config.robot, config.sim, InitialPose(0.0, 0.0, 0.0)).body
        for joint in range(4):
            from_urdf = p.getJointInfo(loaded, joint, physicsClientId=client)
            from_sim = p.getJointInfo(built, joint, physicsClientId=client)
            assert from_urdf[2] == from_sim[2], "joint type"
            assert from_urdf[13] == pytest.approx(from_sim[13]), "axis"
            assert from_urdf[14] == pytest.approx(from_sim[14]), "position in the base"
            urdf_dynamics = p.getDynamicsInfo(loaded, joint, physicsClientId=client)
            sim_dynamics = p.getDynamicsInfo(built, joint, physicsClientId=client)
            assert urdf_dynamics[0] == pytest.approx(sim_dynamics[0]), "mass"
        assert p.getDynamicsInfo(loaded, -1, physicsClientId=client)[0] == pytest.approx(config.sim.body_mass)
        assert p.getDynamicsInfo(loaded, -1, physicsClientId=client)[2] == pytest.approx(body.body_inertia)
        names = [p.getJointInfo(loaded, joint, physicsClientId=client)[1].decode() for joint in range(2)]
        assert names == ["left_wheel_joint", "right_wheel_joint"]
    finally:
        p.disconnect(client)
