"""The ROS 2 bridge's pure core: what it publishes, built from what the loop publishes, and what a
``/cmd_vel`` becomes. No zenoh here.

Frames (REP 105). ``odometry/pose`` is this stack's localized pose: odometry integrated from the
wheel angles and reset by every localization fix, so it is the robot in ``map``, and it jumps
(a little) at each fix. ROS wants two poses: ``map -> base_link`` may jump, ``odom -> base_link``
must not. So the bridge integrates the wheel angles itself, with the odometry service's own core
and no fixes (:class:`ContinuousOdometry`): that is ``odom -> base_link`` and ``/odom``, continuous,
from (0, 0, 0) where the bridge started. ``map -> odom`` is the correction between the two at
the localized pose's stamp: ``map_T_odom = map_T_base(t) * inverse(odom_T_base(t))``, constant
between fixes up to the difference of the two integrations (the odometry service integrates
every step, the bridge the steps it takes), moving at each fix.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, TimedDoubleSeq, TimedPosition
from schemas.navigation import COVARIANCE_LENGTH, GoalPlan, OccupancyGrid, ParticleCloud
from services.body.geometry import RobotBody
from services.config import Config, Ros2Config
from services.motor.core import check_target_velocity
from services.odometry.core import Odometry
from services.planar import Pose, check_coordinates, compose, inverse
from services.ros2 import interfaces

POSE_HISTORY = 4096
"""Poses of the continuous odometry kept, by stamp, to meet a localized pose of the same stamp."""


def ros_time(stamp_ns: int) -> Any:
    sec, nanosec = divmod(stamp_ns, NANOSECONDS_PER_SECOND)
    return interfaces.message_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame: str) -> Any:
    """std_msgs/Header: the simulation time ``stamp_ns`` in ``frame``."""
    return interfaces.message_class("std_msgs/msg/Header")(stamp=ros_time(stamp_ns), frame_id=frame)


def quaternion(x: float = 0.0, y: float = 0.0, z: float = 0.0, w: float = 1.0) -> Any:
    return interfaces.message_class("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w)


def yaw_rotation(theta: float) -> Any:
    """The quaternion of a turn by ``theta`` about z."""
    return quaternion(z=math.sin(theta / 2.0), w=math.cos(theta / 2.0))


def vector(x: float = 0.0, y: float = 0.0, z: float = 0.0, kind: str = "Vector3") -> Any:
    return interfaces.message_class(f"geometry_msgs/msg/{kind}")(x=x, y=y, z=z)


def transform(stamp_ns: int, parent: str, child: str, x: float, y: float, z: float, rotation: Any) -> Any:
    """geometry_msgs/TransformStamped ``parent -> child``."""
    return interfaces.message_class("geometry_msgs/msg/TransformStamped")(
        header=header(stamp_ns, parent),
        child_frame_id=child,
        transform=interfaces.message_class("geometry_msgs/msg/Transform")(
            translation=vector(x, y, z), rotation=rotation
        ),
    )


def planar_transform(stamp_ns: int, parent: str, child: str, pose: Pose) -> Any:
    return transform(stamp_ns, parent, child, pose.x, pose.y, 0.0, yaw_rotation(pose.theta))


def tf_message(transforms: list[Any]) -> Any:
    return interfaces.message_class(interfaces.TF_MESSAGE)(transforms=transforms)


def clock(stamp_ns: int) -> Any:
    return interfaces.message_class(interfaces.CLOCK)(clock=ros_time(stamp_ns))


def string(text: str) -> Any:
    return interfaces.message_class(interfaces.STRING)(data=text)


def planar_pose(x: float, y: float, theta: float = 0.0) -> Any:
    """geometry_msgs/Pose at (x, y, 0), turned by ``theta`` about z."""
    return interfaces.message_class("geometry_msgs/msg/Pose")(
        position=vector(x, y, 0.0, kind="Point"), orientation=yaw_rotation(theta)
    )


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def occupancy_grid(grid: OccupancyGrid, frame: str, load_time_ns: int = 0) -> Any:
    """nav_msgs/OccupancyGrid of ``grid`` in ``frame``, stamped with its ``tm``: ``info.origin`` at
    (``origin_x``, ``origin_y``, 0) with the identity orientation, the cells as they are (row-major
    from the lowest-y row, the byte 255 as -1: nav_msgs' order and int8), ``info.map_load_time``
    ``load_time_ns`` (map_server's the map's; Nav2's costmap leaves it 0). BadInput for a resolution
    that ROS's float32 holds as no positive number."""
    resolution = grid.resolution
    if not 0.0 < resolution <= _FLOAT32_MAX or np.float32(resolution) == 0.0:
        raise BadInput(f"resolution {resolution} m is no positive float32")
    stamp_ns = grid.tm.to_nanoseconds()
    return interfaces.message_class(interfaces.OCCUPANCY_GRID)(
        header=header(stamp_ns, frame),
        info=interfaces.message_class("nav_msgs/msg/MapMetaData")(
            map_load_time=ros_time(load_time_ns),
            resolution=float(np.float32(resolution)),
            width=grid.width,
            height=grid.height,
            origin=planar_pose(grid.origin_x, grid.origin_y),
        ),
        data=np.frombuffer(grid.data, dtype=np.int8),
    )


PATH_POINTS_APART = 1e-4
"""m: two points of a plan closer than this along both x and y give no direction (Nav2's smoother's rule)."""


def path_headings(points: list[tuple[float, float]]) -> list[float]:
    """The heading along a path at each of its points, as Nav2's planners orient their plans: the
    direction to the next point (one apart from it, :data:`PATH_POINTS_APART`), the last point's the
    direction it is reached in (Nav2's ``use_final_approach_orientation``: a plan has no goal
    heading here). 0 for a path with no two points apart."""
    count = len(points)
    headings: list[float | None] = [None] * count
    following: float | None = None
    for index in range(count - 2, -1, -1):
        (x0, y0), (x1, y1) = points[index], points[index + 1]
        if abs(x1 - x0) >= PATH_POINTS_APART or abs(y1 - y0) >= PATH_POINTS_APART:
            following = math.atan2(y1 - y0, x1 - x0)
        headings[index] = following
    approach = 0.0
    for index in range(count):
        heading = headings[index]
        if heading is None:
            headings[index] = approach
        else:
            approach = heading
    return [0.0 if heading is None else heading for heading in headings]


def path(plan: GoalPlan, frame: str) -> Any:
    """nav_msgs/Path of ``plan`` in ``frame``, stamped with its ``tm``: each point a
    geometry_msgs/PoseStamped with the same header, oriented along the path
    (:func:`path_headings`); no poses for an empty plan (the goal ended)."""
    stamp_ns = plan.tm.to_nanoseconds()
    stamped = interfaces.message_class("geometry_msgs/msg/PoseStamped")
    return interfaces.message_class(interfaces.PATH)(
        header=header(stamp_ns, frame),
        poses=[
            stamped(header=header(stamp_ns, frame), pose=planar_pose(x, y, heading))
            for (x, y), heading in zip(plan.points, path_headings(plan.points), strict=True)
        ],
    )


@dataclass(frozen=True)
class WheelSample:
    """The newest wheel angles the bridge took, and the wheel speeds since the one before."""

    stamp_ns: int
    angles: tuple[float, float]
    velocities: tuple[float, float]


class ContinuousOdometry:
    """``odom -> base_link``: the wheel angles integrated with the odometry service's own core
    (the same geometry, calibration and branches) and no fix, so it never jumps. Its poses of the
    last :data:`POSE_HISTORY` stamps are kept, to meet a localized pose of the same stamp."""

    def __init__(self, config: Config) -> None:
        self._odometry = Odometry(config.robot, config.odometry, limits=config.input)
        self._left, self._right = config.robot.left_wheel_id, config.robot.right_wheel_id
        self._poses: deque[tuple[int, Pose]] = deque(maxlen=POSE_HISTORY)
        self.wheels: WheelSample | None = None
        self._max_coordinate = config.input.max_coordinate
        self._requested: Pose | None = None
        self.moved: Pose | None = None
        """The change of frame a pose set made at the last sample taken (new ``odom`` from old), or None."""

    @property
    def pose(self) -> Pose:
        return self._odometry.pose

    @property
    def velocity(self) -> tuple[float, float]:
        """(V in m/s, Ω in rad/s) over the last interval integrated."""
        return self._odometry.velocity

    def take(self, angles: TimedDoubleSeq) -> WheelSample:
        """Integrate a wheel-angle sample (BadInput, nothing changed, for one the core refuses)."""
        stamp_ns = angles.tm.to_nanoseconds()
        previous = self.wheels
        self._odometry.step(stamp_ns, angles.data)
        pair = (angles.data[self._left], angles.data[self._right])
        velocities = (0.0, 0.0)
        if previous is not None:
            dt = (stamp_ns - previous.stamp_ns) / NANOSECONDS_PER_SECOND
            velocities = ((pair[0] - previous.angles[0]) / dt, (pair[1] - previous.angles[1]) / dt)
        self.wheels = WheelSample(stamp_ns, pair, velocities)
        self.moved = None
        if self._requested is not None:
            before, requested, self._requested = self._odometry.pose, self._requested, None
            self.moved = compose(self._odometry.reset(*requested), inverse(before))
            # The poses kept, in the new frame: a localized pose of an earlier stamp meets them there.
            self._poses = deque(((stamp, compose(self.moved, pose)) for stamp, pose in self._poses), POSE_HISTORY)
        self._poses.append((stamp_ns, self._odometry.pose))
        return self.wheels

    def set_pose(self, x: float, y: float, theta: float) -> None:
        """``~/set_odometry`` (``~/reset_odometry``: (0, 0, 0)): ``odom -> base_link`` is this pose at the
        next sample taken (a tick of the bridge), the motion from there on top of it. BadInput for a
        pose not finite or beyond ``input.max_coordinate``; a second request before that sample
        replaces the first."""
        if not math.isfinite(theta):
            raise BadInput(f"pose ({x}, {y}, {theta}) is not finite")
        check_coordinates(x, y, self._max_coordinate)
        self._requested = Pose(x, y, theta)

    def restart(self) -> None:
        """A new simulator: its clock starts again, and so does ``odom`` (at the origin)."""
        self._odometry.restart_time_base()
        self._odometry.reset(0.0, 0.0, 0.0)
        self._poses.clear()
        self.wheels = None

    def pose_at(self, stamp_ns: int) -> Pose | None:
        """The pose integrated up to ``stamp_ns`` (the newest at or before it), if still kept."""
        for stamp, pose in reversed(self._poses):
            if stamp <= stamp_ns:
                return pose
        return None


def map_to_odom(localized: TimedPosition, odometry: ContinuousOdometry) -> Pose | None:
    """``map -> odom`` from a localized pose and the continuous odometry at its stamp (None when
    the bridge has no pose of that time)."""
    continuous = odometry.pose_at(localized.tm.to_nanoseconds())
    if continuous is None:
        return None
    return compose(Pose(localized.x, localized.y, localized.theta), inverse(continuous))


def _covariance(diagonal: tuple[float, ...]) -> np.ndarray:
    """A row-major 6x6 ``float64[36]`` with ``diagonal`` on its diagonal."""
    return np.diag(np.array(diagonal, dtype=np.float64)).reshape(36)


PLANAR_AXES = (0, 1, 5)
"""Where x, y and yaw sit among a ROS pose covariance's six axes (x, y, z, roll, pitch, yaw)."""
_UPPER_TRIANGLE = tuple((row, col) for row in range(3) for col in range(row, 3))
"""The 3 × 3 planar covariance's entries as ``localization/pose`` sends them: xx, xy, xθ, yy, yθ, θθ."""


def pose_covariance(values: list[float]) -> np.ndarray:
    """A ROS pose covariance (row-major 6 × 6 ``float64[36]``) from the planar one's upper triangle
    (xx, xy, xθ, yy, yθ, θθ): the x, y and yaw rows and columns filled, symmetric; z, roll and pitch
    zero, as nav2_amcl leaves them."""
    matrix = np.zeros((6, 6), dtype=np.float64)
    for (row, col), value in zip(_UPPER_TRIANGLE, values, strict=True):
        a, b = PLANAR_AXES[row], PLANAR_AXES[col]
        matrix[a, b] = matrix[b, a] = value
    return matrix.reshape(36)


def planar_covariance(covariance: Any) -> np.ndarray:
    """The 3 × 3 covariance over (x, y, yaw) of a ROS pose covariance (36 values, row-major 6 × 6);
    BadInput for one of another length or not finite."""
    values = np.asarray(covariance, dtype=np.float64)
    if values.shape != (36,):
        raise BadInput(f"a pose covariance of {values.size} values, not 36")
    if not np.all(np.isfinite(values)):
        raise BadInput("the pose covariance is not finite")
    return values.reshape(6, 6)[np.ix_(PLANAR_AXES, PLANAR_AXES)]


def upper_triangle(matrix: np.ndarray) -> list[float]:
    """A 3 × 3 covariance as ``localization/pose`` and ``localization/initial_pose`` carry it."""
    return [float(matrix[row, col]) for row, col in _UPPER_TRIANGLE]


def amcl_pose(message: TimedPosition, frame: str) -> Any | None:
    """geometry_msgs/PoseWithCovarianceStamped of a ``localization/pose`` in ``frame``, stamped with
    its ``tm``, as nav2_amcl publishes ``amcl_pose``: None for a pose without a covariance (the
    stub's, the ``none`` mode's: ``error`` empty); BadInput for an ``error`` that is neither empty
    nor the covariance's :data:`~schemas.messages.COVARIANCE_LENGTH` values."""
    if not message.error:
        return None
    if len(message.error) != COVARIANCE_LENGTH:
        raise BadInput(f"error has {len(message.error)} values, neither none nor a covariance's {COVARIANCE_LENGTH}")
    return interfaces.message_class(interfaces.POSE_WITH_COVARIANCE_STAMPED)(
        header=header(message.tm.to_nanoseconds(), frame),
        pose=interfaces.message_class("geometry_msgs/msg/PoseWithCovariance")(
            pose=planar_pose(message.x, message.y, message.theta), covariance=pose_covariance(message.error)
        ),
    )


def particle_poses(cloud: ParticleCloud, frame: str) -> Any:
    """geometry_msgs/PoseArray of the particles (``localization/particles``) in ``frame``, stamped
    with the cloud's ``tm``: one pose a particle, at (x, y, 0) turned by its heading (PoseArray has
    no weights: nav2_msgs/ParticleCloud's has)."""
    return interfaces.message_class(interfaces.POSE_ARRAY)(
        header=header(cloud.tm.to_nanoseconds(), frame),
        poses=[planar_pose(x, y, theta) for x, y, theta in zip(cloud.x, cloud.y, cloud.theta, strict=True)],
    )


def odometry_message(stamp_ns: int, odometry: ContinuousOdometry, settings: Ros2Config, prefix: str = "") -> Any:
    """nav_msgs/Odometry: the continuous pose in ``odom``, the body twist in ``base_link`` (both
    frames with ``prefix`` on a shared ``/tf``)."""
    pose = odometry.pose
    v, omega = odometry.velocity
    return interfaces.message_class(interfaces.ODOMETRY)(
        header=header(stamp_ns, prefix + settings.odom_frame),
        child_frame_id=prefix + settings.base_frame,
        pose=interfaces.message_class("geometry_msgs/msg/PoseWithCovariance")(
            pose=planar_pose(pose.x, pose.y, pose.theta),
            covariance=_covariance(settings.pose_covariance),
        ),
        twist=interfaces.message_class("geometry_msgs/msg/TwistWithCovariance")(
            twist=interfaces.message_class(interfaces.TWIST)(linear=vector(v), angular=vector(z=omega)),
            covariance=_covariance(settings.twist_covariance),
        ),
    )


def wheel_transforms(
    stamp_ns: int, base_frame: str, body: RobotBody, angles: tuple[float, float], prefix: str = ""
) -> list[Any]:
    """``base_link -> <wheel>``: each wheel turned about +y by its angle (its link's name after ``prefix``)."""
    return [
        transform(
            stamp_ns,
            base_frame,
            prefix + wheel.link,
            0.0,
            wheel.y,
            0.0,
            quaternion(y=math.sin(a / 2.0), w=math.cos(a / 2.0)),
        )
        for wheel, a in zip(body.wheels, angles, strict=True)
    ]


def static_transforms(stamp_ns: int, base_frame: str, body: RobotBody, prefix: str = "") -> list[Any]:
    """``base_link -> <caster>``: what never moves (``/tf_static``; each link's name after ``prefix``)."""
    return [
        transform(stamp_ns, base_frame, prefix + caster.link, caster.x, 0.0, caster.z, quaternion())
        for caster in body.casters
    ]


def joint_state(stamp_ns: int, body: RobotBody, wheels: WheelSample, efforts: tuple[float, float] | None) -> Any:
    """sensor_msgs/JointState of the wheel joints: angle (rad), velocity (rad/s), torque (N m)."""
    return interfaces.message_class(interfaces.JOINT_STATE)(
        header=header(stamp_ns, ""),
        name=[wheel.joint for wheel in body.wheels],
        position=_array(wheels.angles),
        velocity=_array(wheels.velocities),
        effort=_array(efforts) if efforts is not None else _array(()),
    )


def _array(values: tuple[float, ...]) -> np.ndarray:
    """A ``float64[]`` field: rosbags takes numpy arrays for sequences of numbers."""
    return np.array(values, dtype=np.float64)


def stamp_of(message: Any) -> int | None:
    """The simulation time a message the bridge publishes carries, in ns: a ``/clock``'s time, a
    header's stamp, the newest of a TFMessage's transforms; None for one without (the URDF)."""
    if message.__msgtype__ == interfaces.CLOCK:
        return _nanoseconds(message.clock)
    if message.__msgtype__ == interfaces.TF_MESSAGE:
        return max((_nanoseconds(t.header.stamp) for t in message.transforms), default=None)
    header = getattr(message, "header", None)
    return None if header is None else _nanoseconds(header.stamp)


def _nanoseconds(time: Any) -> int:
    return int(time.sec) * NANOSECONDS_PER_SECOND + int(time.nanosec)


MAX_TWIST_PAYLOAD = 4096
"""Bytes: a ``/cmd_vel`` sample larger than this is bad input, refused before it is decoded (a
Twist is 52 bytes of CDR, a TwistStamped with a frame id a few more)."""


def twist_of(message: Any) -> tuple[float, float]:
    """(vx, w) of a geometry_msgs Twist or TwistStamped: ``linear.x`` and ``angular.z`` (a diff drive
    cannot move sideways or tilt; like diff_drive_controller, the other components are ignored)."""
    twist = message.twist if message.__msgtype__ == interfaces.TWIST_STAMPED else message
    return float(twist.linear.x), float(twist.angular.z)


def target_from_twist(message: Any, config: Config) -> tuple[float, float]:
    """The target (vx, w) a twist asks for; BadInput for one that is not finite or implies a wheel
    speed beyond ``input.max_wheel_speed`` (the motor's own rule, so it never sees it)."""
    vx, w = twist_of(message)
    if not (math.isfinite(vx) and math.isfinite(w)):
        raise BadInput(f"twist (linear.x {vx}, angular.z {w}) is not finite")
    check_target_velocity(vx, w, config.robot, config.input)
    return vx, w
