"""services/recording/scene.py: the Foxglove messages of the robot's loop, built from its decoded samples
(a pure module: no zenoh, no server, no file). Each message is read back through its protobuf
encoding with Foxglove's own compiled schemas, as Foxglove reads it."""

import importlib
import itertools
import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput, encode
from schemas.keys import Keys
from schemas.messages import Obstacle, PlannedPath, SimWorld, Time, TimedDoubleSeq, TimedPosition, TimedVelocity
from schemas.topics import Topic
from services.config import Config, load_config
from services.recording.record import SceneBuilder, Sink
from services.recording.scene import (
    LOCALIZATION_TOPIC,
    ODOMETRY_TOPIC,
    POSE_PERIOD_NS,
    ROBOT_FRAME,
    SCENE_PERIOD_NS,
    SCENE_TOPIC,
    TRAIL_POINTS,
    TRAIL_SPACING_M,
    TRANSFORMS_TOPIC,
    WHEEL_SPEEDS_TOPIC,
    WORLD_FRAME,
    Scene,
)
from services.recording.scene_shapes import rotation_quaternion, yaw_quaternion

CONFIG = Config()
ROBOT = CONFIG.robot
MS = 1_000_000


def _body_pose(stamp_ns: int, x: float, y: float, yaw: float) -> TimedDoubleSeq:
    c, s = math.cos(yaw), math.sin(yaw)
    return TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), [x, y, 0.05, c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0])


def _position(stamp_ns: int, x: float, y: float, theta: float) -> TimedPosition:
    return TimedPosition(tm=Time.from_nanoseconds(stamp_ns), id=[], x=x, y=y, theta=theta, error=[])


def _angles(stamp_ns: int, left: float, right: float) -> TimedDoubleSeq:
    data = [0.0] * (max(ROBOT.left_wheel_id, ROBOT.right_wheel_id) + 1)
    data[ROBOT.left_wheel_id], data[ROBOT.right_wheel_id] = left, right
    return TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), data)


def _decoded(message: Any) -> Any:
    """A foxglove-sdk message (which exposes no fields) as Foxglove decodes its protobuf encoding."""
    name = type(message).__name__
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name).FromString(message.encode())


def _topics(shown: list) -> list[str]:
    return [topic for topic, _message in shown]


def _entity(update, entity_id: str):
    return next(entity for entity in update.entities if entity.id == entity_id)


@given(st.floats(-math.pi, math.pi))
def test_the_quaternion_of_a_yaw_rotation_matrix_is_the_yaw_quaternion(yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    x, y, z, w = rotation_quaternion([c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0])
    expected = _decoded(yaw_quaternion(yaw))
    sign = 1.0 if w * expected.w + z * expected.z >= 0.0 else -1.0  # q and -q are the same rotation
    assert (x, y) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert (sign * z, sign * w) == pytest.approx((expected.z, expected.w), abs=1e-12)


def test_ground_truth_is_the_world_to_base_link_transform_at_most_every_pose_period():
    scene = Scene(ROBOT, CONFIG.sim)
    first = scene.add(Topic.SIM_BODY_POSE, _body_pose(0, 1.0, 2.0, math.pi / 2))
    assert _topics(first) == [TRANSFORMS_TOPIC, SCENE_TOPIC]
    transform = _decoded(first[0][1]).transforms[0]
    assert (transform.parent_frame_id, transform.child_frame_id) == (WORLD_FRAME, ROBOT_FRAME)
    assert (transform.translation.x, transform.translation.y) == (1.0, 2.0)
    assert (transform.rotation.z, transform.rotation.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    assert scene.add(Topic.SIM_BODY_POSE, _body_pose(POSE_PERIOD_NS - MS, 1.0, 2.0, 0.0)) == []
    assert _topics(scene.add(Topic.SIM_BODY_POSE, _body_pose(POSE_PERIOD_NS, 1.0, 2.0, 0.0))) == [TRANSFORMS_TOPIC]
    later = scene.add(Topic.SIM_BODY_POSE, _body_pose(SCENE_PERIOD_NS, 1.0, 2.0, 0.0))
    assert _topics(later) == [TRANSFORMS_TOPIC, SCENE_TOPIC]


def test_a_clock_that_starts_again_is_shown_at_once():
    scene = Scene(ROBOT, CONFIG.sim)
    scene.add(Topic.SIM_BODY_POSE, _body_pose(5_000 * MS, 0.0, 0.0, 0.0))
    assert TRANSFORMS_TOPIC in _topics(scene.add(Topic.SIM_BODY_POSE, _body_pose(0, 0.0, 0.0, 0.0)))


def test_the_scene_has_the_robot_the_obstacles_the_path_and_both_trails():
    scene = Scene(ROBOT, CONFIG.sim)
    world = SimWorld(
        Time(0, 0),
        [
            Obstacle("crate", "box", 2.0, 0.0, 0.3, (0.4, 0.5, 0.6)),
            Obstacle("post", "cylinder", 0.0, 2.0, 0.0, (0.2, 0.2, 1.0)),
        ],
    )
    assert scene.add(Topic.SIM_WORLD, world) == []
    assert scene.add(Topic.DRIVE_PATH, PlannedPath(Time(0, 0), "square", [(0.0, 0.0), (1.0, 0.0)])) == []
    steps = SCENE_PERIOD_NS // MS
    for step in range(steps + 1):
        scene.add(Topic.ODOMETRY_POSE, _position(step * MS, step * 0.001, 0.0, 0.0))
        shown = dict(scene.add(Topic.SIM_BODY_POSE, _body_pose(step * MS, step * 0.001, 0.0, 0.0)))
    update = _decoded(shown[SCENE_TOPIC])
    robot = _entity(update, "robot")
    assert robot.frame_id == ROBOT_FRAME and robot.frame_locked
    assert len(robot.cylinders) == 3 and len(robot.spheres) == 2, "the body, two wheels, the casters"
    obstacles = _entity(update, "obstacles")
    assert [(c.pose.position.x, c.size.z) for c in obstacles.cubes] == [(2.0, 0.6)]
    assert [(c.pose.position.y, c.size.z) for c in obstacles.cylinders] == [(2.0, 1.0)]
    assert [(p.x, p.y) for p in _entity(update, "planned_path").lines[0].points] == [(0.0, 0.0), (1.0, 0.0)]
    truth, odometry = _entity(update, "trails").lines
    for trail in (truth, odometry):
        xs = [point.x for point in trail.points]
        assert xs[0] == 0.0 and xs[-1] > steps * 0.001 - 2 * TRAIL_SPACING_M, "the whole way driven"
        assert all(TRAIL_SPACING_M <= b - a < TRAIL_SPACING_M + 0.0011 for a, b in itertools.pairwise(xs)), xs


def test_ten_minutes_of_driving_cost_the_scene_no_more_per_update_than_its_first_minutes():
    """The trail keeps its newest TRAIL_POINTS points: every update carries the whole scene, so a
    trail that grew with the run made a recording grow with the square of its length."""
    scene = Scene(ROBOT, CONFIG.sim)
    scene.add(
        Topic.DRIVE_PATH, PlannedPath(Time(0, 0), "circle", [(math.cos(a / 10), math.sin(a / 10)) for a in range(63)])
    )
    sizes: list[tuple[float, int]] = []
    speed, radius = 0.3, 1.0
    duration_s = 600
    for stamp_ns in range(0, duration_s * 1000 * MS, POSE_PERIOD_NS):
        angle = speed * stamp_ns / 1e9 / radius
        x, y = radius * math.cos(angle), radius * math.sin(angle)
        scene.add(Topic.ODOMETRY_POSE, _position(stamp_ns, x, y, angle))
        for topic, message in scene.add(Topic.SIM_BODY_POSE, _body_pose(stamp_ns, x, y, angle)):
            if topic == SCENE_TOPIC:
                sizes.append((stamp_ns / 1e9, len(message.encode())))
    full_after_s = 2 * TRAIL_POINTS * TRAIL_SPACING_M / speed
    steady = [size for t, size in sizes if t > full_after_s]
    assert len(sizes) == duration_s * 1e9 / SCENE_PERIOD_NS
    assert max(steady) - min(steady) < 0.02 * max(steady), "the scene stops growing once the trails are full"
    assert max(size for _, size in sizes) < 40_000, "bytes per update"


def test_estimates_are_poses_in_the_world_frame_odometry_at_most_every_pose_period():
    scene = Scene(ROBOT, CONFIG.sim)
    ((topic, shown),) = scene.add(Topic.ODOMETRY_POSE, _position(0, 1.0, 2.0, math.pi))
    pose = _decoded(shown)
    assert topic == ODOMETRY_TOPIC and pose.frame_id == WORLD_FRAME
    assert (pose.pose.position.x, pose.pose.position.y, pose.pose.orientation.z) == pytest.approx((1.0, 2.0, 1.0))
    assert scene.add(Topic.ODOMETRY_POSE, _position(MS, 1.0, 2.0, 0.0)) == []
    assert _topics(scene.add(Topic.LOCALIZATION_POSE, _position(MS, 1.0, 2.0, 0.0))) == [LOCALIZATION_TOPIC]


def test_wheel_speeds_are_the_angle_rates_beside_the_commanded_ones():
    scene = Scene(ROBOT, CONFIG.sim)
    scene.add(Topic.DRIVE_TARGET_VELOCITY, TimedVelocity(tm=Time(0, 0), id=[], vx=0.2, vy=0.0, w=1.0, error=[]))
    assert scene.add(Topic.MOTOR_WHEEL_ANGLES, _angles(0, 0.0, 0.0)) == []
    ((topic, speeds),) = scene.add(Topic.MOTOR_WHEEL_ANGLES, _angles(10 * MS, 0.01, 0.03))
    assert topic == WHEEL_SPEEDS_TOPIC
    assert speeds["measured"] == pytest.approx({"left": 1.0, "right": 3.0})
    b = ROBOT.half_axle
    assert speeds["commanded"] == pytest.approx(
        {"left": (0.2 - b) / ROBOT.radius_of_left_wheel, "right": (0.2 + b) / ROBOT.radius_of_right_wheel}
    )


def test_wrong_samples_are_bad_input_not_a_crash():
    scene = Scene(ROBOT, CONFIG.sim)
    with pytest.raises(BadInput):
        scene.add(Topic.SIM_BODY_POSE, TimedDoubleSeq(Time(0, 0), [1.0, 2.0]))
    with pytest.raises(BadInput):
        scene.add(Topic.MOTOR_WHEEL_ANGLES, TimedDoubleSeq(Time(0, 0), []))
    scene.add(Topic.MOTOR_WHEEL_ANGLES, _angles(0, 0.0, 0.0))
    with pytest.raises(BadInput, match="not finite"):
        scene.add(Topic.MOTOR_WHEEL_ANGLES, _angles(1, 1e308, -1e308))


def test_a_fleets_scene_names_each_robots_frame_topics_and_entities_after_the_robot():
    fleet = [load_config(overrides={"robot.name": name}) for name in ("rh0", "rh1")]
    shown: list[tuple[str, Any]] = []
    builder = SceneBuilder(
        fleet[0], Sink(lambda *_sample: None, lambda topic, message, *_: shown.append((topic, message))), fleet
    )
    for index, name in enumerate(("rh0", "rh1")):
        keys, tm = Keys(name), Time.from_nanoseconds(0)
        pose = [float(index), 3.0 * index, 0.1, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        builder.take(keys.sim_body_pose, encode(TimedDoubleSeq(tm=tm, data=pose)), 0)
        builder.take(keys.odometry_pose, encode(TimedPosition(tm, [], float(index), 3.0 * index, 0.0, [])), 0)
    frames = [
        t.child_frame_id for topic, message in shown if topic == TRANSFORMS_TOPIC for t in _decoded(message).transforms
    ]
    assert frames == ["rh0/base_link", "rh1/base_link"]
    entities = {e.id for topic, message in shown if topic == SCENE_TOPIC for e in _decoded(message).entities}
    assert {"rh0/robot", "rh1/robot", "rh0/trails", "rh1/trails", "obstacles"} <= entities
    assert {topic for topic, _ in shown} >= {"/rh0/odometry/pose", "/rh1/odometry/pose", TRANSFORMS_TOPIC, SCENE_TOPIC}


def test_one_robots_scene_keeps_the_plain_names():
    scene = Scene(ROBOT, CONFIG.sim)
    assert scene.frame == "base_link" and scene.topics[ODOMETRY_TOPIC] == ODOMETRY_TOPIC
