"""What the bridge publishes, from what the loop publishes (pure, no zenoh): the one mapping that the
bridge (services/ros2/service.py) and ``invent export --ros2`` (services/recording/rosbag.py) share,
so a bag exported from a run's ``run.mcap`` holds the messages the bridge would have published.

Each wheel-angle sample of ``sim/clock`` is integrated into the continuous odometry
(:class:`~services.ros2.core.ContinuousOdometry`), and on the grids of ``ros2.clock_rate`` and
``ros2.publish_rate`` (simulation time anchored at 0, as the simulator's observed steps are) it
yields ``/clock``, and ``odom``, ``tf`` and ``joint_states``, each stamped with the sample's time;
``odometry/pose`` moves ``map -> odom``, ``motor/torque`` the wheels' efforts. ``tf`` carries
``odom -> base_link``, ``map -> odom`` and the wheels, each unless its ``ros2.enable_*_tf`` switch
hands it to a node of ROS's own; every transform the bridge computes, published or not, is kept in
its TF tree (:attr:`RosOutputs.tree`), in which NavigateToPose goals are given. Each ``sim/scan``
and ``sim/imu`` is one ``scan`` and one ``imu`` (services/ros2/sensors.py), at the time it carries.
Each of the drive's ``drive/map``, ``drive/costmap`` and ``drive/plan`` is one ``map``,
``global_costmap/costmap`` and ``plan`` (nav_msgs OccupancyGrid, OccupancyGrid and Path in
``ros2.map_frame``, services/ros2/core.py), at the time it carries. With the particle filter
(``localization.mode = "amcl"``), each ``localization/pose`` with a covariance is one ``amcl_pose``
(geometry_msgs/PoseWithCovarianceStamped) and each ``localization/particles`` one ``particle_cloud``
(geometry_msgs/PoseArray), both in ``map``, as nav2_amcl publishes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from schemas.codec import BadInput
from schemas.messages import ImuSample, LaserScan, TimedDoubleSeq, TimedPosition
from schemas.navigation import GoalPlan, OccupancyGrid, ParticleCloud
from services.body.geometry import robot_body
from services.clock.sim_time import PeriodicSchedule, StampClock
from services.config import Config
from services.planar import Pose, compose, inverse
from services.ros2 import core, sensors
from services.ros2.graph import BridgeGraph
from services.ros2.tf_tree import TfTree
from services.ros2.urdf import robot_urdf


@dataclass(frozen=True)
class Outgoing:
    """One message the bridge publishes."""

    topic: str
    """Its short name, a key of :attr:`BridgeGraph.publications` (``odom``, ``tf``, ...)."""
    message: Any
    stamp_ns: int
    """The simulation time it carries (a bag's timestamp for it)."""


@dataclass(frozen=True)
class WheelsTaken:
    """What a ``sim/clock`` sample gave: whether it started a new time base (a new simulator), and
    the messages due at its time."""

    restarted: bool
    outgoing: list[Outgoing]


class RosOutputs:
    """The bridge's messages of one robot (``config``), as the bridge ``graph`` names and frames them."""

    def __init__(self, config: Config, graph: BridgeGraph) -> None:
        self.config = config
        self.settings = config.ros2
        self.topics = frozenset(graph.publications)
        self.prefix = graph.frame_prefix
        """Of the robot's frames (``odom``, ``base_link``, wheels, casters) on a shared ``/tf``."""
        self.body = robot_body(config.robot, config.sim)
        self.sensor_frames = sensors.sensor_frames(config)
        self.sensor_stamps = sensors.SensorStamps(config.input.stamp_horizon_ns)
        self.navigation_stamps = sensors.SensorStamps(config.input.stamp_horizon_ns)
        """Of the drive's map, costmap and plan: each in order, none far ahead of the clock."""
        self.localization_stamps = sensors.SensorStamps(config.input.stamp_horizon_ns)
        """Of the particle filter's estimate and particles, likewise."""
        self.clock = StampClock(config.input.stamp_horizon_ns)
        self.odometry = core.ContinuousOdometry(config)
        self.map_to_odom: tuple[int, Pose] | None = None
        """(stamp of the localized pose it comes from, ``map -> odom``)."""
        self.efforts: tuple[float, float] | None = None
        self.tree = TfTree()
        """Every transform the bridge computes, the newest of each (``tf`` and ``tf_static``'s, and
        those the ``ros2.enable_*_tf`` switches keep off ``tf``)."""
        self._schedules: tuple[PeriodicSchedule, PeriodicSchedule] | None = None
        self._wheel_ids = (config.robot.left_wheel_id, config.robot.right_wheel_id)

    @property
    def base_frame(self) -> str:
        return self.prefix + self.settings.base_frame

    def latched(self, stamp_ns: int = 0) -> list[Outgoing]:
        """What is published once, for late subscribers too: ``tf_static`` (the casters and the
        sensors' frames) and ``robot_description`` (the URDF, its links named as in the body,
        unprefixed: RViz's RobotModel and robot_state_publisher add a TF prefix themselves)."""
        transforms = core.static_transforms(stamp_ns, self.base_frame, self.body, self.prefix)
        transforms += sensors.static_transforms(stamp_ns, self.base_frame, self.sensor_frames, self.prefix)
        self.tree.update(transforms)
        static = core.tf_message(transforms)
        urdf = robot_urdf(self.config.robot.name, self.settings.base_frame, self.body, self.sensor_frames)
        return [Outgoing("tf_static", static, stamp_ns), Outgoing("robot_description", core.string(urdf), stamp_ns)]

    def take_wheels(self, message: TimedDoubleSeq) -> WheelsTaken:
        """A ``sim/clock`` sample: integrate its wheel angles, and what is due at its time. BadInput
        (nothing published) for a stamp the clock refuses or angles the odometry refuses."""
        now_ns = message.tm.to_nanoseconds()
        restarted = self.clock.advance(now_ns)
        if restarted:
            self._restart()
        wheels = self.odometry.take(message)
        moved = self.odometry.moved
        if moved is not None and self.map_to_odom is not None:
            # odom was set: map -> odom takes the change, so map -> base_link does not move.
            self.map_to_odom = (now_ns, compose(self.map_to_odom[1], inverse(moved)))
        if self._schedules is None:
            # On the simulator's grid (anchored at 0), whose observed steps the observer tokens ask for.
            self._schedules = (
                PeriodicSchedule(self.settings.clock_rate, 0),
                PeriodicSchedule(self.settings.publish_rate, 0),
            )
        clock_schedule, publish_schedule = self._schedules
        outgoing = []
        if "clock" in self.topics and clock_schedule.due(now_ns):
            outgoing.append(Outgoing("clock", core.clock(now_ns), now_ns))
        if publish_schedule.due(now_ns):
            outgoing += self._state(now_ns, wheels)
        return WheelsTaken(restarted, outgoing)

    def _state(self, now_ns: int, wheels: core.WheelSample) -> list[Outgoing]:
        settings, prefix = self.settings, self.prefix
        odom_frame = prefix + settings.odom_frame
        odom_to_base = [core.planar_transform(now_ns, odom_frame, self.base_frame, self.odometry.pose)]
        wheel_transforms = core.wheel_transforms(now_ns, self.base_frame, self.body, wheels.angles, prefix)
        map_to_odom = []
        if self.map_to_odom is not None:
            stamp_ns, correction = self.map_to_odom
            map_to_odom.append(core.planar_transform(stamp_ns, settings.map_frame, odom_frame, correction))
        computed = (
            (odom_to_base, settings.enable_odom_tf),
            (wheel_transforms, settings.enable_wheel_tf),
            (map_to_odom, settings.enable_map_odom_tf),
        )
        transforms = [transform for group, enabled in computed if enabled for transform in group]
        self.tree.update(transform for group, _ in computed for transform in group)
        return [
            Outgoing("odom", core.odometry_message(now_ns, self.odometry, settings, prefix), now_ns),
            *([Outgoing("tf", core.tf_message(transforms), now_ns)] if "tf" in self.topics else []),
            Outgoing("joint_states", core.joint_state(now_ns, self.body, wheels, self.efforts), now_ns),
        ]

    def take_localized(self, message: TimedPosition) -> None:
        """An ``odometry/pose``: ``map -> odom`` at its stamp (kept until the next)."""
        correction = core.map_to_odom(message, self.odometry)
        if correction is not None:
            self.map_to_odom = (message.tm.to_nanoseconds(), correction)

    def take_torque(self, message: TimedDoubleSeq) -> None:
        """A ``motor/torque``: the wheels' efforts of ``joint_states``."""
        left, right = self._wheel_ids
        if len(message.data) <= max(left, right):
            raise BadInput(f"{len(message.data)} torques, wheel ids {left} and {right}")
        self.efforts = (message.data[left], message.data[right])

    def take_scan(self, message: LaserScan) -> list[Outgoing]:
        """A ``sim/scan``: the ``scan`` of it (none for a robot without a lidar); BadInput for one
        out of order or that ROS's LaserScan cannot hold."""
        if "scan" not in self.topics:
            return []
        stamp_ns = message.tm.to_nanoseconds()
        scan = sensors.laser_scan(message, self.prefix + self.settings.scan_frame, self.config.lidar.rate)
        self.sensor_stamps.check("scan", stamp_ns, self.clock.last_ns)
        return [Outgoing("scan", scan, stamp_ns)]

    def take_imu(self, message: ImuSample) -> list[Outgoing]:
        """A ``sim/imu``: the ``imu`` of it (none for a robot without one); BadInput for one out of order."""
        if "imu" not in self.topics:
            return []
        stamp_ns = message.tm.to_nanoseconds()
        imu = self.config.imu
        self.sensor_stamps.check("imu", stamp_ns, self.clock.last_ns)
        return [
            Outgoing(
                "imu",
                sensors.imu(message, self.prefix + self.settings.imu_frame, imu.gyro_noise, imu.accel_noise),
                stamp_ns,
            )
        ]

    def take_map(self, message: OccupancyGrid) -> list[Outgoing]:
        """A ``drive/map`` (the map the drive loaded): the ``map`` of it, in ``map`` as map_server's,
        its ``map_load_time`` its stamp. BadInput for one stamped before the last map or that ROS's
        OccupancyGrid cannot hold."""
        return [self._grid("map", message, latched=True)]

    def take_costmap(self, message: OccupancyGrid) -> list[Outgoing]:
        """A ``drive/costmap``: the ``global_costmap/costmap`` of it, in ``map``, its
        ``map_load_time`` 0 as Nav2's costmap publisher leaves it. BadInput for one not after the
        last costmap or that ROS's OccupancyGrid cannot hold."""
        return [self._grid("costmap", message, latched=False)]

    def _grid(self, topic: str, message: OccupancyGrid, latched: bool) -> Outgoing:
        """``latched`` (the map): its ``map_load_time`` its stamp, and taken again with the same
        stamp (the latched message sent again); else (the costmap, periodic) each after the last."""
        stamp_ns = message.tm.to_nanoseconds()
        grid = core.occupancy_grid(message, self.settings.map_frame, stamp_ns if latched else 0)
        self.navigation_stamps.check(topic, stamp_ns, self.clock.last_ns, repeat=latched)
        return Outgoing(topic, grid, stamp_ns)

    def take_plan(self, message: GoalPlan) -> list[Outgoing]:
        """A ``drive/plan`` (the running goal's, at each replan; empty when it ends): the ``plan`` of
        it, in ``map``, each pose oriented along the path. BadInput for one stamped before the last."""
        stamp_ns = message.tm.to_nanoseconds()
        plan = core.path(message, self.settings.map_frame)
        self.navigation_stamps.check("plan", stamp_ns, self.clock.last_ns, repeat=True)
        return [Outgoing("plan", plan, stamp_ns)]

    def take_amcl_pose(self, message: TimedPosition) -> list[Outgoing]:
        """A ``localization/pose``: the ``amcl_pose`` of it, in ``map``, if it carries a covariance
        (the particle filter's; none for the stub's or for a bridge without the particle filter).
        BadInput for one stamped before the last or whose ``error`` is no covariance."""
        if "amcl_pose" not in self.topics:
            return []
        estimate = core.amcl_pose(message, self.settings.map_frame)
        if estimate is None:
            return []
        stamp_ns = message.tm.to_nanoseconds()
        self.localization_stamps.check("amcl_pose", stamp_ns, self.clock.last_ns, repeat=True)
        return [Outgoing("amcl_pose", estimate, stamp_ns)]

    def take_particles(self, message: ParticleCloud) -> list[Outgoing]:
        """A ``localization/particles``: the ``particle_cloud`` of it, in ``map`` (none for a bridge
        without the particle filter). BadInput for one stamped before the last."""
        if "particle_cloud" not in self.topics:
            return []
        stamp_ns = message.tm.to_nanoseconds()
        self.localization_stamps.check("particle_cloud", stamp_ns, self.clock.last_ns, repeat=True)
        return [Outgoing("particle_cloud", core.particle_poses(message, self.settings.map_frame), stamp_ns)]

    def _restart(self) -> None:
        """A new simulator, whose clock started again: ``odom`` starts again at the origin, the
        sensors' stamps too, and the drive's map, costmap and plan's."""
        self.navigation_stamps.restart()
        self.localization_stamps.restart()
        self.sensor_stamps.restart()
        self.odometry.restart()
        self._schedules = None
        self.map_to_odom = None
        self.tree.forget(self.prefix + self.settings.odom_frame)
        self.efforts = None
