"""The kinematic engine (``sim.engine = "kinematic"``): the sim bridge's world without physics and
without PyBullet. Each robot is a :class:`~sim_bridge.kinematic_model.DiffDrivePlant` (each wheel a
motor turning the robot's inertia, ideal rolling), its footprint a disc of the robot's reach
(:attr:`services.body.geometry.RobotBody.reach`: the circle holding every part of the robot seen
from above, the same disc outside which its lidar's rays start), the world's obstacles rotated
rectangles and circles (:mod:`sim_bridge.kinematic_world`). docs/sim.md, "Engines", says what
differs from PyBullet.

Bumps by geometry: a step that would take a robot's footprint further into an obstacle or another
robot's footprint is not taken: the robot stays where it was, its wheels stopped (it stops against
the obstacle, at most one step's travel short of touching it). Such a blocked step, or a footprint
overlapping an obstacle at all, is a touch; a touch *begins* (a :class:`~sim_bridge.engine.Contact`)
as in PyBullet: when the pair has not touched for ``sim.bump_release``. The contact point is the
point of the obstacle's outline nearest the robot's centre, at axle height (at most the
obstacle's height). Obstacles never move.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from schemas.messages import NANOSECONDS_PER_SECOND, ImuSample, LaserScan, Time
from services.body.geometry import robot_body
from services.config import ImuConfig, LidarConfig, RobotConfig, SimConfig
from sim_bridge.engine import Contact, Placement, WheelCommands, WorldOfRobots
from sim_bridge.kinematic_model import DiffDrivePlant, DriveModel
from sim_bridge.kinematic_world import RayCaster, footprint_gap, world_shapes
from sim_bridge.sensors import Imu, Lidar
from sim_bridge.world import World

_NO_CONTACTS: tuple[Contact, ...] = ()
_FAR_MARGIN = 1e-6
"""m: a footprint this much further than an obstacle's bounding box is surely clear of it (the
distance's rounding is far smaller), so the obstacle's exact distance is not needed."""


class KinematicRobot(WheelCommands):
    """One robot of the kinematic world: its plant, sensors and the torques of its next step (the
    surface of :class:`sim_bridge.simulator.SimulatedRobot`)."""

    def __init__(self, placement: Placement, sim: SimConfig, index: int) -> None:
        robot = placement.robot
        self.name = placement.name
        self.index = index
        super().__init__(robot.left_wheel_id, robot.right_wheel_id, sim.max_wheel_torque)
        body = robot_body(robot, sim)
        self.axle_height = body.axle_height
        self.reach = body.reach
        self.body_radius = body.body_radius
        self.body_top = body.axle_height + body.body_height
        pose = placement.pose
        self.plant = DiffDrivePlant(DriveModel.from_description(robot, sim), pose.x, pose.y, pose.theta)
        self.lidar = None if placement.lidar is None else Lidar(placement.lidar, self.reach, index)
        self.imu = None if placement.imu is None else Imu(placement.imu, index)
        self.world: KinematicSimulator | None = None
        """The world it is in, for its rays (set by the world)."""

    def wheel_angles(self) -> list[float]:
        angles = [0.0] * self.wheel_count
        angles[self._left], angles[self._right] = self.plant.wheel_angles
        return angles

    def rotation(self) -> list[float]:
        """The body's rotation matrix, row-major: level, turned by its heading."""
        cos, sin = math.cos(self.plant.theta), math.sin(self.plant.theta)
        return [cos, -sin, 0.0, sin, cos, 0.0, 0.0, 0.0, 1.0]

    def body_pose(self) -> list[float]:
        plant = self.plant
        return [plant.x, plant.y, self.axle_height, *self.rotation()]

    def scan(self, tm: Time) -> LaserScan:
        lidar, world = self.lidar, self.world
        assert lidar is not None and world is not None
        plant = self.plant
        rotation = np.array(self.rotation()).reshape(3, 3)
        starts, ends = lidar.rays((plant.x, plant.y, self.axle_height), rotation)
        positions = [(robot.plant.x, robot.plant.y) for robot in world.robots]
        bodies, fractions = world.rays.first_hits(self.index, positions, starts, ends)
        return lidar.scan_of(tm, bodies, fractions, world.rays.names)

    def imu_sample(self, tm: Time) -> ImuSample:
        assert self.imu is not None
        plant = self.plant
        half = plant.theta / 2.0
        orientation = (0.0, 0.0, math.sin(half), math.cos(half))
        return self.imu.sample(tm, orientation, self.rotation(), plant.linear_velocity, plant.angular_velocity)

    def show_applied(self) -> None:
        """After a step that followed wheel speed targets: the torques the plant chose, for the status."""
        self.applied_torques[self._left], self.applied_torques[self._right] = self.plant.applied


class KinematicSimulator(WorldOfRobots[KinematicRobot]):
    """Diff-drive robots in a world without physics, stepped together by :meth:`step`: the
    surface of :class:`sim_bridge.simulator.Simulator` (:class:`sim_bridge.engine.Engine`)."""

    def __init__(
        self,
        robot: RobotConfig,
        sim: SimConfig,
        world: World,
        *,
        fleet: Sequence[Placement] = (),
        lidar: LidarConfig | None = None,
        imu: ImuConfig | None = None,
    ) -> None:
        super().__init__(robot, sim, world, fleet, lidar, imu)
        self.step_s = self.step_ns / NANOSECONDS_PER_SECOND
        self.robots = tuple(KinematicRobot(placement, sim, index) for index, placement in enumerate(self.placements))
        self.obstacles = world_shapes(world)
        self._bounds = tuple(
            (shape.x, shape.y, half_width + _FAR_MARGIN, half_height + _FAR_MARGIN)
            for shape in self.obstacles
            for half_width, half_height in [shape.extent()]
        )
        """Each obstacle's centre and the half sizes of its bounding box, widened by ``_FAR_MARGIN``."""
        self.rays = RayCaster(self.obstacles, [(r.name, r.body_radius, r.body_top) for r in self.robots])
        for body in self.robots:
            body.world = self
        self.step_index = 0
        self._last_touch: dict[tuple[int, int], int] = {}
        """(robot, obstacle index; or robot, len(obstacles) + other robot) -> the step it last touched."""

    def step(self) -> tuple[Contact, ...]:
        """Move every robot by its torques (in the world's order), but not into an obstacle or
        another robot; return the contacts that began in this step (a contact between two robots
        once for each of them)."""
        touches: list[tuple[int, int, float, float, float]] = []
        for body in self.robots:
            plant = body.plant
            before = (plant.x, plant.y, plant.theta, plant.wheel_angles)
            targets = body.velocity_targets
            if body.braking:
                plant.brake()
            elif targets is not None:
                plant.follow(*targets)
            plant.step(body.forces[0], body.forces[1], self.step_s)
            if targets is not None:
                body.show_applied()
            if self._blocked(body, before[0], before[1], touches):
                plant.x, plant.y, plant.theta, plant.wheel_angles = before
                plant.wheel_velocities = (0.0, 0.0)
        self.step_index += 1
        return self._began(touches) if touches else _NO_CONTACTS

    def _blocked(
        self, body: KinematicRobot, x0: float, y0: float, touches: list[tuple[int, int, float, float, float]]
    ) -> bool:
        """Whether ``body``'s step from (x0, y0) goes further into something; each thing its
        footprint touches (overlaps, or would go further into) is added to ``touches``."""
        x, y, reach = body.plant.x, body.plant.y, body.reach
        blocked = False
        for index, (shape, (cx, cy, half_width, half_height)) in enumerate(zip(self.obstacles, self._bounds)):
            if abs(x - cx) > half_width + reach or abs(y - cy) > half_height + reach:
                continue
            gap, (px, py) = footprint_gap(shape, x, y, reach)
            if gap <= 0.0:
                deeper = gap < footprint_gap(shape, x0, y0, reach)[0]
                blocked = blocked or deeper
                touches.append((body.index, index, px, py, min(body.axle_height, shape.height)))
        for other in self.robots:
            if other is body:
                continue
            ox, oy = other.plant.x, other.plant.y
            reaches = reach + other.reach
            distance = math.hypot(x - ox, y - oy)
            if distance - reaches <= 0.0:
                blocked = blocked or distance < math.hypot(x0 - ox, y0 - oy)
                scale = other.reach / distance if distance > 0.0 else 0.0
                point = (ox + (x - ox) * scale, oy + (y - oy) * scale, other.axle_height)
                touches.append((body.index, len(self.obstacles) + other.index, *point))
        return blocked

    def _began(self, touches: list[tuple[int, int, float, float, float]]) -> tuple[Contact, ...]:
        began: list[Contact] = []
        obstacle_count = len(self.obstacles)
        for robot, other, x, y, z in touches:
            if other >= obstacle_count:
                # a pair of robots touches once, whichever of them moved into the other
                pair = (min(robot, other - obstacle_count), obstacle_count + max(robot, other - obstacle_count))
            else:
                pair = (robot, other)
            last = self._last_touch.get(pair)
            self._last_touch[pair] = self.step_index
            if last == self.step_index or not (last is None or self.step_index - last > self._release_steps):
                continue
            if other < obstacle_count:
                began.append(Contact(robot, self.obstacles[other].name, x, y, z))
            else:
                mate = self.robots[other - obstacle_count]
                mover = self.robots[robot]
                began.append(Contact(robot, mate.name, x, y, z))
                began.append(Contact(mate.index, mover.name, *self._outline_point(mover, mate)))
        return tuple(began)

    @staticmethod
    def _outline_point(body: KinematicRobot, toward: KinematicRobot) -> tuple[float, float, float]:
        """The point of ``body``'s footprint nearest ``toward``'s centre, at axle height."""
        dx, dy = toward.plant.x - body.plant.x, toward.plant.y - body.plant.y
        distance = math.hypot(dx, dy)
        scale = body.reach / distance if distance > 0.0 else 0.0
        return body.plant.x + dx * scale, body.plant.y + dy * scale, body.axle_height
