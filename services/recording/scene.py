"""What Foxglove shows of the loop: well-known Foxglove messages built from the loop's samples.

Pure (no zenoh): :class:`Scene` takes each decoded sample and returns the messages to show,
for the live view (``invent view``) and the recording (``run.mcap``) alike, so a recording
opened in Foxglove shows the scene the live view showed:

- ``/tf`` (``foxglove.FrameTransforms``): ``world`` → ``base_link``, the ground truth;
- ``/odometry/pose``, ``/localization/pose`` (``foxglove.PoseInFrame`` in ``world``);
- ``/scene`` (``foxglove.SceneUpdate``): the robot (body, wheels, casters) on ``base_link``, the
  world's obstacles, the planned path, the trails of ground truth and odometry, and in goal mode
  the drive's goals: the running one's pose, tolerances and progress, the path driven to it, the
  ended ones with their outcomes (:mod:`services.recording.goal_scene`), and the running goal's
  plan (``drive/plan``, entity ``plan``: drawn as the planned path is, in violet);
- ``/map`` and ``/costmap`` (``foxglove.Grid`` in ``world``): the drive's map (``drive/map``) and
  costmap (``drive/costmap``), one ``INT8`` field a cell (:mod:`services.recording.navigation_scene`);
- ``/localization/particles`` and ``/localization/covariance`` (``foxglove.SceneUpdate``): the particle
  filter's particles and its estimate's 2σ ellipse and heading wedge (:mod:`services.recording.localization_scene`);
- ``/plot/wheel_speeds`` (JSON): commanded and measured wheel speeds, rad/s;
- ``/scan`` (``foxglove.LaserScan``): every lidar scan (``sim/scan``, at ``lidar.rate``: 10 Hz)
  in the lidar's frame ``base_scan``, which ``/tf`` places on ``base_link`` at the ``[lidar]``
  mount with each scan; a ray that saw nothing (``null``) is +inf, as ROS has it.

Poses and transforms are shown at most every :data:`POSE_PERIOD_NS` of simulation time, the
scene every :data:`SCENE_PERIOD_NS` (the loop publishes at its step rate, kHz, which no viewer
needs); a scan is shown as it comes, at its own rate; the costmap as it comes, at most every
:data:`~services.recording.navigation_scene.COSTMAP_PERIOD_NS`, and the map (published once) again
every :data:`~services.recording.navigation_scene.MAP_PERIOD_NS`, for a client that joins a live
view late. A trail keeps a point every :data:`TRAIL_SPACING_M`, the newest :data:`TRAIL_POINTS`. Each
scene update carries the whole scene (a viewer that seeks, or joins late, needs only the last one),
so what bounds a recording's growth is the trail's length: the scene costs at most about 30 kB per
update however long the run (benchmarks/README.md, "What recording costs"), about 42 kB with a
goal's path full and the ended goals drawn (tests/test_goal_scene.py); a goal's plan adds about
29 bytes a point drawn, at most 15 kB (tests/test_navigation_scene.py).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from foxglove.messages import (
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    LaserScan,
    LinePrimitive,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    Vector3,
)

from schemas.codec import BadInput
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    ScenarioOutcome,
    SimWorld,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.messages import LaserScan as ScanMessage
from schemas.navigation import GoalFeedback, GoalPlan, GoalTarget
from schemas.topics import Topic
from services.config import CalibratedGeometry, LidarConfig, OdometryConfig, RobotConfig, SimConfig
from services.recording.goal_scene import GoalDrawing
from services.recording.localization_scene import COVARIANCE_TOPIC, PARTICLES_TOPIC, LocalizationDrawing
from services.recording.navigation_scene import COSTMAP_TOPIC, MAP_TOPIC, NavigationDrawing
from services.recording.report import pose_from_body_pose
from services.recording.scene_shapes import (
    foxglove_pose,
    ground_line,
    robot_entity,
    rotation_quaternion,
    timestamp,
    yaw_quaternion,
)

WORLD_FRAME = "world"
ROBOT_FRAME = "base_link"
LIDAR_FRAME = "base_scan"
"""The lidar's frame, on ``base_link`` at the ``[lidar]`` mount (TurtleBot3's name for it)."""
TRANSFORMS_TOPIC = "/tf"
ODOMETRY_TOPIC = "/odometry/pose"
LOCALIZATION_TOPIC = "/localization/pose"
SCENE_TOPIC = "/scene"
WHEEL_SPEEDS_TOPIC = "/plot/wheel_speeds"
SCAN_TOPIC = "/scan"

POSE_PERIOD_NS = 20_000_000
SCENE_PERIOD_NS = 500_000_000
TRAIL_SPACING_M = 0.02
TRAIL_POINTS = 500
"""10 m of the newest path: a trail of 20,000 points resent at every update made an hour's
recording grow with the square of its length (1 GB after six minutes of a circle)."""
GOAL_PATH_SPACING_M = 2 * TRAIL_SPACING_M
GOAL_PATH_POINTS = TRAIL_POINTS // 2
"""The path driven to a goal: its newest 10 m, at half the trails' points (it is drawn over the
ground truth's trail, in every update while its goal is the last one)."""

WHEEL_SPEEDS_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "invent.WheelSpeeds",
    "description": "Commanded (from drive/target_velocity) and measured (from motor/wheel_angles) wheel speeds, rad/s",
    "properties": {
        name: {"type": "object", "properties": {"left": {"type": "number"}, "right": {"type": "number"}}}
        for name in ("commanded", "measured")
    },
}

_OBSTACLE = Color(r=0.8, g=0.4, b=0.2, a=0.9)
_PATH = Color(r=0.2, g=0.5, b=1.0, a=1.0)
PLAN_COLOR = Color(r=0.7, g=0.3, b=0.95, a=1.0)
"""The running goal's plan (``drive/plan``): violet, where the scenario's planned path is blue."""
_TRUTH = Color(r=0.1, g=0.7, b=0.2, a=1.0)
_ODOMETRY = Color(r=0.9, g=0.2, b=0.2, a=1.0)


class _Trail:
    """A polyline that keeps a point every :data:`TRAIL_SPACING_M`, the newest :data:`TRAIL_POINTS`."""

    def __init__(self) -> None:
        self.points: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)

    def add(self, x: float, y: float) -> None:
        if not self.points or math.dist(self.points[-1], (x, y)) >= TRAIL_SPACING_M:
            self.points.append((x, y))

    def line(self, color: Color) -> LinePrimitive:
        return ground_line(self.points, color, 0.02)


class Scene:
    """The Foxglove messages of one robot's loop; see the module docstring. In a fleet
    (``fleet=True``) every name is the robot's own, so several scenes share one recording or view:
    its frame ``<robot>/base_link``, its topics ``/<robot>/odometry/pose``, ... and its entities
    ``<robot>/robot``, ``<robot>/planned_path``, ``<robot>/trails``, ``<robot>/goal``, ``<robot>/plan``,
    ... and its grids ``/<robot>/map``, ``/<robot>/costmap`` (``/tf`` and ``/scene`` are shared;
    the obstacles are the world's, one entity)."""

    def __init__(
        self,
        robot: RobotConfig,
        sim: SimConfig,
        *,
        fleet: bool = False,
        geometry: CalibratedGeometry | None = None,
        lidar: LidarConfig | None = None,
    ) -> None:
        """``geometry``: the calibrated lengths the motor turns commands into wheel speeds with
        (``Config.geometry``); None, the robot's own. ``lidar``: where the lidar sits (None: the
        default ``[lidar]``)."""
        self._robot = robot
        self._geometry = geometry or CalibratedGeometry.of(robot, OdometryConfig())
        prefix = f"{robot.name}/" if fleet else ""
        self.frame = prefix + ROBOT_FRAME
        self.lidar_frame = prefix + LIDAR_FRAME
        self._lidar = lidar or LidarConfig()
        self._ids = {
            entity: prefix + entity
            for entity in (
                *("robot", "planned_path", "trails", "goal", "goal_path", "goals_ended", "plan"),
                *("particles", "covariance"),
            )
        }
        self.topics = {
            topic: f"/{prefix}{topic.lstrip('/')}"
            for topic in (ODOMETRY_TOPIC, LOCALIZATION_TOPIC, WHEEL_SPEEDS_TOPIC, SCAN_TOPIC, MAP_TOPIC, COSTMAP_TOPIC)
            + (PARTICLES_TOPIC, COVARIANCE_TOPIC)
        }
        self._robot_entity = robot_entity(robot, sim)
        self._cylinders: list[CylinderPrimitive] = []
        self._cubes: list[CubePrimitive] = []
        self._path: list[tuple[float, float]] = []
        self._truth = _Trail()
        self._odometry = _Trail()
        self.goals = GoalDrawing(self._ids, GOAL_PATH_SPACING_M, GOAL_PATH_POINTS)
        self.navigation = NavigationDrawing(self.topics, WORLD_FRAME, timestamp)
        self.localization = LocalizationDrawing(self.topics, self._ids, WORLD_FRAME, timestamp)
        self._next_transform_ns = 0
        self._next_odometry_ns = 0
        self._next_scene_ns = 0
        self._scene_changed = True
        self._commanded = (0.0, 0.0)
        self._last_angles: tuple[int, float, float] | None = None

    def add(self, topic: Topic, message: Any) -> list[tuple[str, Any]]:
        """The (topic, message) pairs to show for one decoded sample of ``topic`` (often none)."""
        if topic is Topic.SIM_BODY_POSE:
            return self._body_pose(message)
        if topic is Topic.ODOMETRY_POSE:
            return self._odometry_pose(message)
        if topic is Topic.LOCALIZATION_POSE:
            return [*self.localization.pose(message), (self.topics[LOCALIZATION_TOPIC], _pose_in_world(message))]
        if topic is Topic.LOCALIZATION_PARTICLES:
            return self.localization.particles(message)
        if topic is Topic.MOTOR_WHEEL_ANGLES:
            return self._wheel_angles(message)
        if topic is Topic.SIM_SCAN:
            return self._scan(message)
        if topic is Topic.DRIVE_MAP:
            return self.navigation.map(message)
        if topic is Topic.DRIVE_COSTMAP:
            return self.navigation.costmap(message)
        if topic is Topic.DRIVE_TARGET_VELOCITY:
            self._target(message)
        elif topic is Topic.SIM_WORLD:
            self._world(message)
        elif topic is Topic.DRIVE_PATH:
            self._path = list(message.points)
            self._scene_changed = True
        elif topic is Topic.DRIVE_GOAL:
            self._goal(message)
        elif topic is Topic.DRIVE_GOAL_FEEDBACK:
            self._goal_feedback(message)
        elif topic is Topic.DRIVE_OUTCOME:
            self._outcome(message)
        elif topic is Topic.DRIVE_PLAN:
            self._plan(message)
        return []

    def _plan(self, message: GoalPlan) -> None:
        """Drawn at once (with the next ground truth), as a new path is."""
        self.navigation.set_plan(message.points)
        self._scene_changed = True

    def _goal(self, message: GoalTarget) -> None:
        self.goals.start(message)
        self._scene_changed = True

    def _goal_feedback(self, message: GoalFeedback) -> None:
        """Shown in the goal's label at the next scene update (every :data:`SCENE_PERIOD_NS`): a
        scene update at every feedback would cost the recording a whole scene each time."""
        self.goals.feedback(message)

    def _outcome(self, message: ScenarioOutcome) -> None:
        if self.goals.end(message):
            self._scene_changed = True

    def _body_pose(self, message: TimedDoubleSeq) -> list[tuple[str, Any]]:
        stamp_ns = message.tm.to_nanoseconds()
        pose = pose_from_body_pose(message.data)
        self._truth.add(pose.x, pose.y)
        self.goals.track(stamp_ns, pose.x, pose.y)
        shown: list[tuple[str, Any]] = []
        if stamp_ns >= self._next_transform_ns or stamp_ns < self._next_transform_ns - POSE_PERIOD_NS:
            self._next_transform_ns = stamp_ns + POSE_PERIOD_NS
            x, y, z = message.data[:3]
            qx, qy, qz, qw = rotation_quaternion(message.data[3:12])
            transform = FrameTransform(
                timestamp=timestamp(message.tm),
                parent_frame_id=WORLD_FRAME,
                child_frame_id=self.frame,
                translation=Vector3(x=x, y=y, z=z),
                rotation=Quaternion(x=qx, y=qy, z=qz, w=qw),
            )
            shown.append((TRANSFORMS_TOPIC, FrameTransforms(transforms=[transform])))
        if stamp_ns >= self._next_scene_ns or stamp_ns < self._next_scene_ns - SCENE_PERIOD_NS or self._scene_changed:
            self._next_scene_ns = stamp_ns + SCENE_PERIOD_NS
            self._scene_changed = False
            shown.append((SCENE_TOPIC, self._scene_update(message.tm)))
        shown += self.navigation.tick(message.tm)
        return shown

    def _odometry_pose(self, message: TimedPosition) -> list[tuple[str, Any]]:
        self._odometry.add(message.x, message.y)
        stamp_ns = message.tm.to_nanoseconds()
        if self._next_odometry_ns - POSE_PERIOD_NS <= stamp_ns < self._next_odometry_ns:
            return []
        self._next_odometry_ns = stamp_ns + POSE_PERIOD_NS
        return [(self.topics[ODOMETRY_TOPIC], _pose_in_world(message))]

    def _target(self, message: TimedVelocity) -> None:
        left_radius, right_radius, b = self._geometry
        self._commanded = ((message.vx - b * message.w) / left_radius, (message.vx + b * message.w) / right_radius)

    def _wheel_angles(self, message: TimedDoubleSeq) -> list[tuple[str, Any]]:
        robot = self._robot
        stamp_ns = message.tm.to_nanoseconds()
        if len(message.data) <= max(robot.left_wheel_id, robot.right_wheel_id):
            raise BadInput(
                f"{len(message.data)} wheel angles, wheel ids {robot.left_wheel_id} and {robot.right_wheel_id}"
            )
        left, right = message.data[robot.left_wheel_id], message.data[robot.right_wheel_id]
        previous, self._last_angles = self._last_angles, (stamp_ns, left, right)
        if previous is None or stamp_ns <= previous[0]:
            return []
        dt = (stamp_ns - previous[0]) / NANOSECONDS_PER_SECOND
        measured = ((left - previous[1]) / dt, (right - previous[2]) / dt)
        if not all(map(math.isfinite, (*measured, *self._commanded))):
            raise BadInput(f"wheel speeds {measured}, commanded {self._commanded} are not finite")
        speeds = {
            "commanded": {"left": self._commanded[0], "right": self._commanded[1]},
            "measured": {"left": measured[0], "right": measured[1]},
        }
        return [(self.topics[WHEEL_SPEEDS_TOPIC], speeds)]

    def _scan(self, message: ScanMessage) -> list[tuple[str, Any]]:
        """The scan in the lidar's frame, and that frame on the robot's, at the scan's stamp: the
        mount is fixed, but a transform sent once would be missing for a viewer that joins late."""
        stamp = timestamp(message.tm)
        count = len(message.ranges)
        end_angle = message.angle_min + max(count - 1, 0) * message.angle_increment
        if not math.isfinite(end_angle):
            raise BadInput(f"the last ray's angle {end_angle} is not finite")
        lidar = self._lidar
        mount = FrameTransform(
            timestamp=stamp,
            parent_frame_id=self.frame,
            child_frame_id=self.lidar_frame,
            translation=Vector3(x=lidar.x, y=lidar.y, z=lidar.z),
            rotation=yaw_quaternion(lidar.yaw),
        )
        scan = LaserScan(
            timestamp=stamp,
            frame_id=self.lidar_frame,
            pose=foxglove_pose(0.0, 0.0, 0.0),
            start_angle=message.angle_min,
            end_angle=end_angle,
            ranges=message.ranges_or_inf(),
            intensities=[],
        )
        return [(TRANSFORMS_TOPIC, FrameTransforms(transforms=[mount])), (self.topics[SCAN_TOPIC], scan)]

    def _world(self, message: SimWorld) -> None:
        self._cubes = [
            CubePrimitive(
                pose=foxglove_pose(o.x, o.y, o.size[2] / 2.0, yaw_quaternion(o.yaw)),
                size=Vector3(x=o.size[0], y=o.size[1], z=o.size[2]),
                color=_OBSTACLE,
            )
            for o in message.obstacles
            if o.shape == "box"
        ]
        self._cylinders = [
            CylinderPrimitive(
                pose=foxglove_pose(o.x, o.y, o.size[2] / 2.0),
                size=Vector3(x=o.size[0], y=o.size[1], z=o.size[2]),
                bottom_scale=1.0,
                top_scale=1.0,
                color=_OBSTACLE,
            )
            for o in message.obstacles
            if o.shape == "cylinder"
        ]
        self._scene_changed = True

    def _path_entity(
        self, stamp: Timestamp, entity: str, points: list[tuple[float, float]], color: Color
    ) -> SceneEntity:
        """A path on the ground of the world (the scenario's planned path, a goal's plan), 5 mm up;
        no points, an empty entity (a viewer that seeks back before it shows none)."""
        return SceneEntity(
            timestamp=stamp,
            frame_id=WORLD_FRAME,
            id=self._ids[entity],
            lines=[ground_line(points, color, 0.01, z=0.005)] if points else [],
        )

    def _scene_update(self, tm: Time) -> SceneUpdate:
        stamp = timestamp(tm)
        entities = [
            SceneEntity(
                timestamp=stamp, frame_id=self.frame, id=self._ids["robot"], frame_locked=True, **self._robot_entity
            ),
            SceneEntity(
                timestamp=stamp, frame_id=WORLD_FRAME, id="obstacles", cubes=self._cubes, cylinders=self._cylinders
            ),
            self._path_entity(stamp, "planned_path", self._path, _PATH),
            SceneEntity(
                timestamp=stamp,
                frame_id=WORLD_FRAME,
                id=self._ids["trails"],
                lines=[self._truth.line(_TRUTH), self._odometry.line(_ODOMETRY)],
            ),
            *self.goals.entities(stamp, WORLD_FRAME),
            self._path_entity(stamp, "plan", self.navigation.plan, PLAN_COLOR),
        ]
        return SceneUpdate(entities=entities)


def _pose_in_world(message: TimedPosition) -> PoseInFrame:
    return PoseInFrame(
        timestamp=timestamp(message.tm),
        frame_id=WORLD_FRAME,
        pose=foxglove_pose(message.x, message.y, 0.0, yaw_quaternion(message.theta)),
    )
