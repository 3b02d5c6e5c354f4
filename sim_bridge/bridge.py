"""``invent sim``: the PyBullet simulator bridge (docs/protocol.md section 6), a thin shell around the simulator core.

Every step publishes ``sim/wheel_angles`` stamped with simulation time, applies the wheel
torques and steps. The observed steps (services/clock/observation.py: every ``sim.observe_every``-th
step and each tick of a rate someone holds a token for) also publish ``sim/clock`` and
``sim/body_pose``; a recorded run publishes the body pose at every step. Each step's wheel angles
carry its :class:`~services.clock.lockstep.StepMark`: whether it is observed, and in lockstep
what it owes. A finite run (``--duration S``) ends by publishing the state at S, observed, and
(in lockstep) taking the torque that answers it without applying it.

- **lockstep** (default): before stepping, wait for the ``motor/torque`` whose ``tm`` is this
  step's; a torque with any other ``tm`` is stale (counted, ignored). The wait happens only
  while a motor control is alive (its liveliness token ``motor/alive``), however long it takes
  (each ``sim.lockstep_timeout`` it goes on is said): with none, steps run without waiting, zero
  torque. A motor control that comes after the first step is silent until its first torque:
  each step then waits only one real-time period for its torque (the sim runs at real-time pace,
  zero torque, slow enough for a motor control to work off its backlog).
  The whole loop is in lockstep too (services/clock/lockstep.py): at each tick of a participant (the
  drive, the localization: liveliness tokens ``<service>/ticks/<rate>``) the step also waits for
  its output, as long as its token lives (one whose token goes is dropped at once, named in the
  status), and the marks of the steps' wheel angles say what the motor and odometry hold
  their samples for. ``--wait-for`` and ``--until-drive-ends`` make a run start and end at
  the same step every time.
- **realtime**: steps paced to the wall clock times ``sim.realtime_factor``; each applies the
  newest torque, or zero when the newest is older than ``sim.torque_max_age``. A step whose own
  torque (the answer to its wheel angles) has not arrived when it is stepped counts as late.

In both modes the status reports the torque latency (wheel angles published -> the torque with
their ``tm`` received) as percentiles over the most recent steps (:mod:`sim_bridge.latency`).

When the robot begins touching an obstacle it publishes ``sim/bump`` and calls
``motor/bump/stop`` (the reply is only counted); in lockstep the next step waits until the call
has finished, so the motor latches at the contact's step in every run.

The service's rooms: this module (``SimService``: the world, its links, the run; ``SimOptions``),
:mod:`sim_bridge.link` (one robot's keys, publishers and inputs), :mod:`sim_bridge.liveness`
(who is there), :mod:`sim_bridge.torque_policy` (which torque a step applies; pure),
:mod:`sim_bridge.loops` (the lockstep and realtime loops), :mod:`sim_bridge.handshakes` (before the
first step), :mod:`sim_bridge.status` (status and summary; pure).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

from schemas.keys import Keys, Service, ServiceName
from schemas.messages import NANOSECONDS_PER_SECOND, SimWorld, Time
from schemas.status import SimStatus, SimWorldStatus
from services import interfaces
from services.config import Config, ImuConfig, LidarConfig, SimEngine, SimMode
from services.fleet.description import Fleet
from services.runtime.node import Node
from services.service import ServiceCommand
from sim_bridge.engine import Engine, Placement, check_gui
from sim_bridge.handshakes import (
    await_motor_subscriptions,
    await_participants,
    await_services,
)
from sim_bridge.link import MotorSeam, RobotLink
from sim_bridge.loops import Loop
from sim_bridge.progress import RunProgress
from sim_bridge.status import RunStatus
from sim_bridge.world import InitialPose, World, load_world, obstacles, read_world, resolve_world


@dataclass(frozen=True)
class SimOptions:
    """``invent sim``'s own options beside the robot description."""

    duration: float | None = None
    """Simulate this many seconds, then exit 0 (None: until stopped)."""
    until_drive_ends: bool = False
    """Hold at the drive's last target, answering status, until stopped (``invent up``'s)."""
    wait_for: tuple[ServiceName, ...] = ()
    """The services to wait for before the first step."""
    gui: bool = False
    fleet: Fleet | None = None
    """Every robot of this fleet in one world, each robot's keys under its name."""
    fleet_file: str | None = None
    """The file ``fleet`` was read from, as given (``--fleet``)."""
    fleet_robots: tuple[Config, ...] = ()
    """With ``fleet``: each robot's description, in the fleet's order."""


def sensors(config: Config) -> tuple[LidarConfig | None, ImuConfig | None]:
    """The lidar and the IMU a robot description gives its robot (None: turned off)."""
    return (config.lidar if config.lidar.enabled else None, config.imu if config.imu.enabled else None)


def build_engine(
    config: Config,
    world: World,
    gui: bool,
    fleet: list[Placement],
    lidar: LidarConfig | None,
    imu: ImuConfig | None,
) -> Engine:
    """The engine ``sim.engine`` names (:mod:`sim_bridge.engine`). Each is imported here, not at
    the top: every `invent` command imports this module (services/cli/sim.py for its command and
    options), importing PyBullet prints its build banner, and the kinematic engine runs where
    PyBullet is not installed."""
    check_gui(config.sim, gui)
    if config.sim.engine == SimEngine.KINEMATIC:
        from sim_bridge.kinematic import KinematicSimulator

        return KinematicSimulator(config.robot, config.sim, world, fleet=fleet, lidar=lidar, imu=imu)
    from sim_bridge.simulator import Simulator

    return Simulator(config.robot, config.sim, world, gui=gui, fleet=fleet, lidar=lidar, imu=imu)


class SimService:
    def __init__(self, node: Node, config: Config, options: SimOptions) -> None:
        self.node = node
        self.parameters = config.sim
        self.mode = config.sim.mode
        self.duration: float | None = options.duration
        self.wait_for: list[ServiceName] = list(options.wait_for)
        self.finished = False
        self.exit_code = 0
        self.progress = RunProgress()
        self.fleet = options.fleet
        self.world_file = resolve_world(config.sim.world)
        self.world = read_world(self.world_file)
        placements: list[Placement] = []
        if self.fleet is not None:
            for robot, description in zip(self.fleet.robots, options.fleet_robots, strict=True):
                start = robot.start
                placements.append(
                    Placement(
                        robot.name,
                        description.robot,
                        InitialPose(x=start.x, y=start.y, theta=start.theta),
                        *sensors(description),
                    )
                )
        lidar, imu = sensors(config)
        seams = [
            MotorSeam(description.motor.output, description.input.max_wheel_speed)
            for description in (options.fleet_robots if self.fleet is not None else (config,))
        ]
        self.sim = build_engine(config, self.world, options.gui, placements, lidar, imu)
        self.run_status = RunStatus(
            sim=self.sim,
            parameters=config.sim,
            progress=self.progress,
            world_file=self.world_file,
            duration=self.duration,
            fleet=None if self.fleet is None else [body.name for body in self.sim.robots],
        )
        self.links: list[RobotLink] = []
        try:
            for index, body in enumerate(self.sim.robots):
                robot_node = (
                    node
                    if index == 0
                    else Node(
                        node.session,
                        Keys(body.name),
                        Service.SIM,
                        executor=node.executor,
                        journal=node.journal,
                        bus=node.bus,
                        congestion=node.congestion,
                        interface=interfaces.sim(Keys(body.name), config),
                    )
                )
                self.links.append(
                    RobotLink(
                        robot_node,
                        body,
                        config.sim,
                        step_ns=self.sim.step_ns,
                        progress=self.progress,
                        prefix=f"{body.name}: " if self.fleet is not None else "",
                        world_status=self.world_status,
                        seam=seams[index],
                    )
                )
        except BaseException:
            self.close()
            raise
        self.loop = Loop(
            sim=self.sim,
            node=node,
            links=self.links,
            parameters=config.sim,
            progress=self.progress,
            end_step=math.inf
            if options.duration is None
            else round(options.duration * NANOSECONDS_PER_SECOND / self.sim.step_ns),
            until_drive_ends=options.until_drive_ends,
        )

    def run(self, stop: threading.Event) -> int:
        # Asked once at start, so the first steps already know whether to wait.
        for link in self.links:
            link.liveness.set_motor_alive(link.node.alive_now(Service.MOTOR))
        self.node.drain()
        await_services(self.node, self.links, self.wait_for, stop)
        lockstep = self.mode == SimMode.LOCKSTEP
        if lockstep and any(link.torque.motor_alive for link in self.links):
            await_motor_subscriptions(self.node, self.links, self.parameters.lockstep_timeout)
        if lockstep:
            await_participants(self.node, self.links)
        self.node.log.info(
            "simulating %s on the %s engine in %s mode, step %g s%s%s",
            self.world_file,
            self.parameters.engine,
            self.mode,
            self.parameters.step,
            "" if self.duration is None else f", for {self.duration:g} s",
            "" if self.fleet is None else f", robots {', '.join(link.name for link in self.links)}",
        )
        world = SimWorld(Time.from_nanoseconds(self.sim.time_ns), obstacles(self.world))
        for link in self.links:
            link.world_publisher.put(world)
        loop = self.loop
        self.run_status.started_at = time.monotonic()
        self.progress.started = True
        {SimMode.LOCKSTEP: loop.run_lockstep, SimMode.REALTIME: loop.run_realtime}[self.mode](stop)
        self.finished = loop.final() or loop.ended()
        self.run_status.stopped_at = time.monotonic()
        summary = self.run_status.summary([link.summary() for link in self.links])
        self.node.log.info("%s: %s", "finished" if self.finished else "stopped", summary)
        if loop.ended():
            self.node.log.info("the drive's scenario ended: holding at this step until stopped")
            self.node.serve(stop, finished=lambda: False)
        return 0

    def world_status(self) -> SimWorldStatus:
        """The part of every robot's ``sim/status`` that is the world's."""
        return self.run_status.world_status(self.finished)

    def status(self) -> SimStatus:
        return self.links[0].status()

    def close(self) -> None:
        for link in reversed(self.links):
            link.close()
            if link.node is not self.node:
                link.node.close()
        self.links.clear()
        self.sim.close()


def check(config: Config, options: SimOptions) -> None:
    """A window the engine has not, a world file that does not load: exit 2 before anything starts."""
    check_gui(config.sim, options.gui)
    load_world(config.sim.world)


COMMAND = ServiceCommand(service=Service.SIM, factory=SimService, check=check)
