"""The stepping core of the sim bridge: one PyBullet world, no zenoh.

Vectors follow the wire contract (docs/protocol.md sections 2 and 6): wheel angles and torques are
indexed by wheel id (``robot.left_wheel_id``, ``robot.right_wheel_id``), their length is the
largest id + 1 and the other entries are 0; the body pose is x, y, z of the axle-centre frame
then its 3x3 rotation matrix row-major. Simulation time is ``step_index * step_ns``.

The per-step path (``wheel_angles``, ``body_pose``, ``set_torques``, ``step``) is kept lean:
the lockstep loop runs it thousands of times per second.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet as p

from schemas.messages import NANOSECONDS_PER_SECOND, ImuSample, LaserScan, Time
from services.body.geometry import robot_body
from services.config import ConfigError, ImuConfig, LidarConfig, RobotConfig, SimConfig
from sim_bridge.building import build_ground, build_obstacles
from sim_bridge.display import require_display
from sim_bridge.engine import Contact, Placement, WheelCommands, WorldOfRobots
from sim_bridge.ray_world import RayWorld
from sim_bridge.robot import RobotModel, build_robot
from sim_bridge.sensors import Imu, Lidar
from sim_bridge.world import World

GRAVITY = 9.81
"""m/s^2, along -z."""
_NO_CONTACTS: tuple[Contact, ...] = ()
_CONTACT_BODY_A = 1
_CONTACT_BODY_B = 2
_CONTACT_POSITION_ON_A = 5
_CONTACT_POSITION_ON_B = 6
_CONTACT_DISTANCE = 8
Position = tuple[float, float, float]


class SimulatedRobot(WheelCommands):
    """One robot's body in the world: its wheel angles, body pose and the torques of its next step."""

    def __init__(self, client: int, placement: Placement, sim: SimConfig, index: int) -> None:
        robot = placement.robot
        self.name = placement.name
        self.client = client
        super().__init__(robot.left_wheel_id, robot.right_wheel_id, sim.max_wheel_torque)
        self.model: RobotModel = build_robot(client, robot, sim, placement.pose)
        self.body = self.model.body
        self.wheels = self.model.wheel_joints
        self._motor_targets: tuple[float, float] | None = None
        """The targets the wheels' velocity motors hold in the physics client (braking: zero);
        None: they are off."""
        self.index = index
        """The robot's index in the world's placements."""
        reach = robot_body(robot, sim).reach
        self.lidar = None if placement.lidar is None else Lidar(placement.lidar, reach, index)
        self.imu = None if placement.imu is None else Imu(placement.imu, index)
        self.ray_world: RayWorld | None = None
        """Where the lidar casts its rays (the world's, once built; :mod:`sim_bridge.ray_world`)."""

    def wheel_angles(self) -> list[float]:
        """Wheel joint angles in rad (unwrapped), by wheel id."""
        left, right = p.getJointStates(self.body, self.wheels, physicsClientId=self.client)
        angles = [0.0] * self.wheel_count
        angles[self._left] = left[0]
        angles[self._right] = right[0]
        if self._motor_targets is not None and not self.braking:
            # the torques the velocity motors applied in the last step, for the status
            self.applied_torques[self._left], self.applied_torques[self._right] = left[3], right[3]
        return angles

    def body_pose(self) -> list[float]:
        """x, y, z of the axle centre, then its rotation matrix row-major (12 values)."""
        position, orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        return [*position, *p.getMatrixFromQuaternion(orientation)]

    def scan(self, tm: Time) -> LaserScan:
        """Cast the lidar's rays in the world as it is now (the robot has a lidar)."""
        lidar, rays = self.lidar, self.ray_world
        assert lidar is not None and rays is not None
        position, orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        rotation = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        starts, ends = lidar.rays(position, rotation)
        return lidar.scan(tm, rays.cast(self.index, starts, ends), rays.names)

    def imu_sample(self, tm: Time) -> ImuSample:
        """What the IMU reads now (the robot has an IMU)."""
        assert self.imu is not None
        client = self.client
        _, orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=client)
        linear, angular = p.getBaseVelocity(self.body, physicsClientId=client)
        x, y, z, w = orientation
        return self.imu.sample(tm, (x, y, z, w), p.getMatrixFromQuaternion(orientation), linear, angular)

    def apply(self) -> None:
        """Set this step's wheel motors in the physics client: the torques, the velocity targets, or the brakes."""
        client, body, wheels = self.client, self.body, self.wheels
        targets = (0.0, 0.0) if self.braking else self.velocity_targets
        if targets != self._motor_targets:
            # PyBullet's velocity motors brake and follow targets; force 0 turns them off again, for torque control.
            limit = 0.0 if targets is None else self.max_torque
            p.setJointMotorControlArray(
                body, wheels, p.VELOCITY_CONTROL, targetVelocities=targets or (0.0, 0.0), forces=(limit, limit),
                physicsClientId=client,
            )  # fmt: skip
            self._motor_targets = targets
        if targets is None:
            # PyBullet clears applied joint torques after every step: they must be set again each time.
            p.setJointMotorControlArray(body, wheels, p.TORQUE_CONTROL, forces=self.forces, physicsClientId=client)


def connect(gui: bool) -> int:
    """A physics client of its own: headless (DIRECT), or a GUI window when a display exists."""
    if gui:
        require_display()
    client = p.connect(p.GUI if gui else p.DIRECT)
    if client < 0:
        raise ConfigError("--gui: PyBullet could not open a window" if gui else "PyBullet could not start")
    return client


class Simulator(WorldOfRobots[SimulatedRobot]):
    """Diff-drive robots in a world, stepped together by :meth:`step`. One robot (``robot``, at the
    world's initial pose, with the sensors ``lidar`` and ``imu``) unless ``fleet`` places several; the single-robot methods
    (:meth:`wheel_angles`, :meth:`set_torques`, ...) are the first robot's."""

    def __init__(
        self,
        robot: RobotConfig,
        sim: SimConfig,
        world: World,
        *,
        gui: bool = False,
        fleet: Sequence[Placement] = (),
        lidar: LidarConfig | None = None,
        imu: ImuConfig | None = None,
    ) -> None:
        super().__init__(robot, sim, world, fleet, lidar, imu)
        self.client = connect(gui)
        self._build()

    def _build(self) -> None:
        client = self.client
        p.resetSimulation(physicsClientId=client)
        p.setPhysicsEngineParameter(
            fixedTimeStep=self.step_ns / NANOSECONDS_PER_SECOND,
            deterministicOverlappingPairs=1,
            physicsClientId=client,
        )
        p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
        ground = build_ground(client)
        p.changeDynamics(ground, -1, lateralFriction=self.world.ground.friction, physicsClientId=client)
        self._obstacles = build_obstacles(client, self.world)
        self.robots = tuple(
            SimulatedRobot(client, placement, self.sim_config, index) for index, placement in enumerate(self.placements)
        )
        self._ray_world: RayWorld | None = None
        if any(robot.lidar is not None for robot in self.robots):
            self._ray_world = RayWorld(
                client,
                self.world,
                self.sim_config,
                self.placements,
                [robot.body for robot in self.robots],
                [body for body, _ in self._obstacles],
            )
            for robot in self.robots:
                robot.ray_world = self._ray_world
        first = self.robots[0]
        self.model = first.model
        self.wheel_count = first.wheel_count
        self.max_torque = first.max_torque
        self.step_index = 0
        # Each pair (robot, obstacle) and each pair of robots, checked for a contact at every step.
        self._pairs = [
            (index, robot.body, obstacle, name, False)
            for index, robot in enumerate(self.robots)
            for obstacle, name in self._obstacles
        ] + [
            (index, robot.body, other.body, other.name, True)
            for index, robot in enumerate(self.robots)
            for other in self.robots[index + 1 :]
        ]
        self._last_contact_step: list[int | None] = [None] * len(self._pairs)
        self._index_of_body = {robot.body: index for index, robot in enumerate(self.robots)}
        # A contact point's (body A, body B) -> its pair, and which of the point's positions is on the
        # pair's robot and which on the other body (Bullet may name the pair's bodies either way round).
        self._pair_of_bodies: dict[tuple[int, int], tuple[int, int, int]] = {}
        for pair_index, (_, body, other, _, _) in enumerate(self._pairs):
            self._pair_of_bodies[body, other] = (pair_index, _CONTACT_POSITION_ON_A, _CONTACT_POSITION_ON_B)
            self._pair_of_bodies[other, body] = (pair_index, _CONTACT_POSITION_ON_B, _CONTACT_POSITION_ON_A)
        self._one_query = len(self._pairs) > len(self.robots)
        """Whether :meth:`_new_contacts` asks for all the world's contact points at once, not pair by pair."""

    def step(self) -> tuple[Contact, ...]:
        """Apply every robot's torques, advance one step; return the contacts that began in it
        (a contact between two robots once for each of them)."""
        for robot in self.robots:
            robot.apply()
        p.stepSimulation(physicsClientId=self.client)
        self.step_index += 1
        return self._new_contacts() if self._pairs else _NO_CONTACTS

    # A getContactPoints call costs about 1 us (1.4 us with a pair of bodies to filter by) plus 0.6 us
    # per point it returns, and each robot on the floor has 2 (its wheels'). So one query of every
    # point of the world (~1 + 1.2 N us for N robots) is cheaper than one per pair (~1.4 us each)
    # once there are more pairs than robots: N = 8 on the empty floor, 28 pairs, 39 -> 10.5 us a step;
    # with 4 boxes, 60 pairs, 85 -> 10.6 us. Below (2 robots, 1 pair; 1 robot, 1 box) the pairs are
    # cheaper. One query per robot (bodyA only) costs N calls and the same points (N = 8: 19 us); a
    # broad phase (getAABB of each link, getOverlappingObjects) costs as many calls or more (N = 8:
    # 15-18 us before any contact query).
    # Both ways give the same points, bit for bit: Bullet's filters only select the points of its
    # contact manifolds, in their order, and name the filter's body A first.

    def _new_contacts(self) -> tuple[Contact, ...]:
        touches = self._touches_in_one_query() if self._one_query else self._touches_pair_by_pair()
        if not touches:
            return _NO_CONTACTS
        began = []
        for pair_index, on_robot, on_other in touches:
            robot, _, other, name, other_is_robot = self._pairs[pair_index]
            last = self._last_contact_step[pair_index]
            if last is None or self.step_index - last > self._release_steps:
                began.append(Contact(robot, name, *on_other))
                if other_is_robot:
                    began.append(Contact(self._index_of_body[other], self.robots[robot].name, *on_robot))
            self._last_contact_step[pair_index] = self.step_index
        return tuple(began)

    def _touches_pair_by_pair(self) -> list[tuple[int, Position, Position]]:
        """Each touching pair's index and its first touching point on the robot and on the other body,
        in pair order. (Bullet also reports points within its contact margin, not yet touching.)"""
        touches = []
        for pair_index, (_, body, other, _, _) in enumerate(self._pairs):
            for point in p.getContactPoints(bodyA=body, bodyB=other, physicsClientId=self.client):
                if point[_CONTACT_DISTANCE] <= 0.0:
                    touches.append((pair_index, point[_CONTACT_POSITION_ON_A], point[_CONTACT_POSITION_ON_B]))
                    break
        return touches

    def _touches_in_one_query(self) -> list[tuple[int, Position, Position]]:
        """:meth:`_touches_pair_by_pair` from one query of every point of the world (the floor's too)."""
        first: dict[int, tuple[int, Position, Position]] = {}
        pair_of_bodies = self._pair_of_bodies
        for point in p.getContactPoints(physicsClientId=self.client):
            pair = pair_of_bodies.get((point[_CONTACT_BODY_A], point[_CONTACT_BODY_B]))
            if pair is not None and point[_CONTACT_DISTANCE] <= 0.0:
                pair_index, on_robot, on_other = pair
                if pair_index not in first:
                    first[pair_index] = (pair_index, point[on_robot], point[on_other])
        return sorted(first.values())

    def close(self) -> None:
        if self._ray_world is not None:
            self._ray_world.close()
        p.disconnect(physicsClientId=self.client)
