"""What the sim bridge needs of a simulation engine (``sim.engine``): the surface the service's
loops, links and status use, as :class:`typing.Protocol` types both engines satisfy (mypy checks
it where the bridge builds one), and the plain values they share. Pure: no PyBullet, no zenoh.

- ``pybullet``: :class:`sim_bridge.simulator.Simulator`, rigid-body physics.
- ``kinematic``: :class:`sim_bridge.kinematic.KinematicSimulator`, each wheel a motor turning the
  robot's inertia with ideal rolling, bumps by geometry (docs/sim.md, "Engines").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, Self, TypeVar

from schemas.codec import BadInput
from schemas.messages import NANOSECONDS_PER_SECOND, ImuSample, LaserScan, Time
from services.config import ConfigError, ImuConfig, LidarConfig, RobotConfig, SimConfig, SimEngine
from sim_bridge.sensors import Imu, Lidar
from sim_bridge.world import InitialPose, World


@dataclass(frozen=True)
class Placement:
    """A robot of the world: its name, its description, where it starts, and its sensors (None:
    it has none)."""

    name: str
    robot: RobotConfig
    pose: InitialPose
    lidar: LidarConfig | None = None
    imu: ImuConfig | None = None


@dataclass(frozen=True)
class Contact:
    """Robot ``robot`` (its index in the engine's ``robots``) began touching ``obstacle`` (an
    obstacle's name, or another robot's) at world point (x, y, z), on the obstacle's surface."""

    robot: int
    obstacle: str
    x: float
    y: float
    z: float


class RobotPlant(Protocol):
    """One robot of an engine's world, as the bridge serves it (docs/protocol.md section 6)."""

    @property
    def name(self) -> str: ...
    @property
    def index(self) -> int:
        """The robot's index in the world's placements."""
        ...

    wheel_count: int

    @property
    def lidar(self) -> Lidar | None: ...
    @property
    def imu(self) -> Imu | None: ...
    @property
    def applied_torques(self) -> list[float]:
        """The torques applied during the next step, by wheel id (after saturation)."""
        ...

    braking: bool
    """The next step brakes the wheels to rest instead of applying torques."""

    def wheel_angles(self) -> list[float]:
        """Wheel angles in rad (unwrapped), by wheel id."""
        ...

    def body_pose(self) -> list[float]:
        """x, y, z of the axle centre, then its rotation matrix row-major (12 values)."""
        ...

    def scan(self, tm: Time) -> LaserScan: ...
    def imu_sample(self, tm: Time) -> ImuSample: ...
    def set_torques(self, torques: Sequence[float]) -> None:
        """Wheel torques in N·m by wheel id for the next step, saturated (BadInput: wrong length)."""
        ...

    def set_wheel_velocities(self, targets: Sequence[float]) -> None:
        """Wheel speed targets in rad/s by wheel id for the next step, which the engine's own
        velocity loop follows within the torque limit (BadInput: wrong length)."""
        ...

    def set_zero_torques(self) -> None: ...
    def brake(self) -> None: ...


class Engine(Protocol):
    """A world of robots stepped together (:class:`sim_bridge.simulator.Simulator` is the model)."""

    @property
    def step_ns(self) -> int: ...
    @property
    def step_index(self) -> int: ...
    @property
    def time_ns(self) -> int:
        """Simulation time of the current state: ``step_index * step_ns``."""
        ...

    @property
    def robots(self) -> Sequence[RobotPlant]: ...
    def step(self) -> tuple[Contact, ...]:
        """Apply every robot's torques, advance one step; the contacts that began in it."""
        ...

    def close(self) -> None: ...


RobotT = TypeVar("RobotT", bound=RobotPlant)


class WheelCommands:
    """What a robot's wheels take in its next step, as both engines' robots hold it: torques (saturated
    at ``max_torque``), wheel speed targets the plant's own loop follows, or the brakes; by wheel id in,
    left and right kept."""

    def __init__(self, left_wheel_id: int, right_wheel_id: int, max_torque: float) -> None:
        self.wheel_count = max(left_wheel_id, right_wheel_id) + 1
        self.max_torque = max_torque
        self._left, self._right = left_wheel_id, right_wheel_id
        self.forces = [0.0, 0.0]
        """Left and right torque of the next step, after saturation."""
        self.braking = False
        """The next step brakes the wheels to rest (at most ``max_torque``) instead of applying ``forces``."""
        self.velocity_targets: tuple[float, float] | None = None
        """Left and right wheel speed targets (rad/s) of the next step, followed within ``max_torque``;
        None: the torques apply."""
        self.applied_torques = [0.0] * self.wheel_count
        """The torques applied during the next step, by wheel id (after saturation)."""

    def set_torques(self, torques: Sequence[float]) -> None:
        """Wheel torques in N·m by wheel id for the next step, each saturated at ``max_torque``."""
        if len(torques) != self.wheel_count:
            raise BadInput(f"{len(torques)} torques, expected {self.wheel_count} (one per wheel id)")
        limit = self.max_torque
        left = min(max(torques[self._left], -limit), limit)
        right = min(max(torques[self._right], -limit), limit)
        self.forces[0] = self.applied_torques[self._left] = left
        self.forces[1] = self.applied_torques[self._right] = right
        self.braking = False
        self.velocity_targets = None

    def set_wheel_velocities(self, targets: Sequence[float]) -> None:
        """Wheel speed targets in rad/s by wheel id for the next step (BadInput: wrong length)."""
        if len(targets) != self.wheel_count:
            raise BadInput(f"{len(targets)} wheel speed targets, expected {self.wheel_count} (one per wheel id)")
        self.velocity_targets = (targets[self._left], targets[self._right])
        self.braking = False

    def set_zero_torques(self) -> None:
        self.forces[0] = self.forces[1] = 0.0
        self.applied_torques[self._left] = self.applied_torques[self._right] = 0.0
        self.braking = False
        self.velocity_targets = None

    def brake(self) -> None:
        """Brake the wheels to rest in the next step, as a motor driver does when its commands stop."""
        self.set_zero_torques()
        self.braking = True


class WorldOfRobots(Generic[RobotT]):
    """What both engines share: the step in integer ns, the placements (one robot at the world's
    initial pose with ``lidar`` and ``imu`` unless ``fleet`` places several), how many steps a
    contact stays the same bump, the simulation time, and the single-robot methods
    (:meth:`wheel_angles`, :meth:`set_torques`, ...), which are the first robot's. A subclass
    builds ``robots`` (in the placements' order), ``step`` and ``close``."""

    robots: tuple[RobotT, ...]
    step_index: int

    def __init__(
        self,
        robot: RobotConfig,
        sim: SimConfig,
        world: World,
        fleet: Sequence[Placement],
        lidar: LidarConfig | None,
        imu: ImuConfig | None,
    ) -> None:
        self.step_ns = round(sim.step * NANOSECONDS_PER_SECOND)
        if self.step_ns < 1:
            raise ConfigError(f"`sim.step`: {sim.step} s is shorter than 1 ns")
        self.robot_config, self.sim_config, self.world = robot, sim, world
        self.placements = tuple(fleet) or (Placement(robot.name, robot, world.initial_pose, lidar, imu),)
        self._release_steps = max(1, round(sim.bump_release * NANOSECONDS_PER_SECOND / self.step_ns))
        """Steps without a touch after which touching again is a new bump (``sim.bump_release``)."""

    @property
    def time_ns(self) -> int:
        """Simulation time of the current state."""
        return self.step_index * self.step_ns

    @property
    def applied_torques(self) -> list[float]:
        return self.robots[0].applied_torques

    def wheel_angles(self) -> list[float]:
        return self.robots[0].wheel_angles()

    def body_pose(self) -> list[float]:
        return self.robots[0].body_pose()

    def set_torques(self, torques: Sequence[float]) -> None:
        self.robots[0].set_torques(torques)

    def set_zero_torques(self) -> None:
        self.robots[0].set_zero_torques()

    def close(self) -> None:
        """Release what the engine holds (a physics client)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def check_gui(sim: SimConfig, gui: bool) -> None:
    """``--gui`` needs PyBullet's window: refused (exit 2) for an engine without one."""
    if gui and sim.engine != SimEngine.PYBULLET:
        raise ConfigError(f"--gui: the {sim.engine} engine has no window (it needs `sim.engine = pybullet`)")
