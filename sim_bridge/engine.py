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
