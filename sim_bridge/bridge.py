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
  while a motor control is alive (its liveliness token ``motor/alive``): with none, steps run
  without waiting, zero torque. An answer later than ``sim.lockstep_timeout`` means zero
  torque, a (rate-limited) warning and the next step. After ``sim.lockstep_max_late`` late
  answers in a row the motor control counts as silent: each step then waits only one
  real-time period for its torque (the sim runs at real-time pace, zero torque, slow enough
  for a motor control to work off its backlog) until a torque from it arrives again.
  The whole loop is in lockstep too (services/clock/lockstep.py): at each tick of a participant (the
  drive, the localization: liveliness tokens ``<service>/ticks/<rate>``) the step also waits for
  its output, and the marks of the steps' wheel angles say what the motor and odometry hold
  their samples for. ``--wait-for`` and ``--until-drive-ends`` make a run start and end at
  the same step every time.
- **realtime**: steps paced to the wall clock times ``sim.realtime_factor``; each applies the
  newest torque, or zero when the newest is older than ``sim.torque_max_age``. A step whose own
  torque (the answer to its wheel angles) has not arrived when it is stepped counts as late.

In both modes the status reports the torque latency (wheel angles published -> the torque with
their ``tm`` received) as percentiles over the most recent steps (:mod:`sim_bridge.latency`).

When the robot begins touching an obstacle it publishes ``sim/bump`` and calls
``motor/bump/stop`` without waiting for the answer (the reply is only counted).

The service's rooms: this module (``SimService``: the world, its links, the run; the flags),
:mod:`sim_bridge.link` (one robot's keys, publishers and inputs), :mod:`sim_bridge.liveness`
(who is there), :mod:`sim_bridge.torque_policy` (which torque a step applies; pure),
:mod:`sim_bridge.loops` (the lockstep and realtime loops), :mod:`sim_bridge.handshakes` (before the
first step), :mod:`sim_bridge.status` (status and summary; pure).
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from typing import Any

from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, SimWorld, Time
from services.config import Config, SimConfig, SimMode
from services.fleet.description import load_fleet, robot_config
from services.runtime.node import Node
from services.service import ServiceCommand, overrides_from_args, positive_seconds
from sim_bridge.handshakes import (
    START_HANDSHAKE_TIMEOUT_S,
    await_motor_subscriptions,
    await_participants,
    await_services,
)
from sim_bridge.link import RobotLink
from sim_bridge.loops import Loop
from sim_bridge.progress import RunProgress
from sim_bridge.status import RunStatus
from sim_bridge.world import DEFAULT_WORLD, InitialPose, builtin_worlds, obstacles, read_world, resolve_world


class SimService:
    def __init__(self, node: Node, config: Config, args: argparse.Namespace) -> None:
        self.node = node
        self.parameters = config.sim
        self.mode = config.sim.mode
        self.duration: float | None = args.duration
        self.wait_for: list[Service] = args.wait_for or []
        self.finished = False
        self.exit_code = 0
        self.progress = RunProgress()
        # Imported here, not at the top: every `invent` command imports this module for its flags,
        # and importing PyBullet prints its build banner.
        from sim_bridge.simulator import Placement, Simulator

        self.fleet = load_fleet(args.fleet) if args.fleet else None
        self.world_file = resolve_world(config.sim.world)
        self.world = read_world(self.world_file)
        placements: list[Placement] = []
        if self.fleet is not None:
            overrides = overrides_from_args(COMMAND, args)
            for robot in self.fleet.robots:
                start = robot.start
                description = robot_config(robot, args.config, overrides).robot
                placements.append(
                    Placement(robot.name, description, InitialPose(x=start.x, y=start.y, theta=start.theta))
                )
        self.sim = Simulator(config.robot, config.sim, self.world, gui=args.gui, fleet=placements)
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
            if args.duration is None
            else round(args.duration * NANOSECONDS_PER_SECOND / self.sim.step_ns),
            until_drive_ends=args.until_drive_ends,
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
            "simulating %s in %s mode, step %g s%s%s",
            self.world_file,
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

    def world_status(self) -> dict[str, Any]:
        """The part of every robot's ``sim/status`` that is the world's."""
        return self.run_status.world_status(self.finished)

    def status(self) -> dict[str, Any]:
        return self.links[0].status()

    def close(self) -> None:
        for link in reversed(self.links):
            link.close()
            if link.node is not self.node:
                link.node.close()
        self.links.clear()
        self.sim.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = SimConfig()
    group = parser.add_argument_group("simulation")
    group.add_argument("--mode", choices=list(SimMode), help=f"(default {defaults.mode})")
    group.add_argument(
        "--step", type=positive_seconds, metavar="S", help=f"simulated seconds per step (default {defaults.step:g})"
    )
    group.add_argument("--duration", type=positive_seconds, metavar="S", help="simulate S seconds, then exit 0")
    group.add_argument(
        "--wait-for",
        nargs="+",
        type=Service,
        choices=[service for service in Service if service is not Service.SIM],
        metavar="SERVICE",
        help=f"before the first step, wait (at most {START_HANDSHAKE_TIMEOUT_S:g} s) until these services are there "
        "(motor: alive; drive, localization: holding their lockstep token), so a lockstep run starts the same way "
        "every time (invent up uses it)",
    )
    group.add_argument(
        "--until-drive-ends",
        action="store_true",
        help="stop stepping at the drive's last target (the end of its scenario) and hold there, answering "
        "status, until stopped: a lockstep run then ends at the same step every time (invent up uses it)",
    )
    group.add_argument(
        "--realtime-factor",
        type=positive_seconds,
        metavar="F",
        help=f"realtime mode: simulated seconds per wall second (default {defaults.realtime_factor:g})",
    )
    group.add_argument(
        "--world",
        metavar="FILE",
        help=f"world TOML file, or a built-in world ({', '.join(builtin_worlds())}); default: {DEFAULT_WORLD}",
    )
    group.add_argument("--gui", action="store_true", help="open a PyBullet window (needs a display)")
    group.add_argument(
        "--fleet",
        metavar="FILE",
        help="simulate every robot of this fleet file in one world, each robot's keys under its name "
        "(docs/fleet.md); its world is the fleet's unless --world is given; --robot is then the fleet's",
    )


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    fleet = load_fleet(args.fleet) if args.fleet else None
    return {
        "sim.mode": args.mode,
        "sim.step": args.step,
        "sim.realtime_factor": args.realtime_factor,
        "sim.world": args.world or (fleet.world if fleet else None),
        "robot.name": fleet.robots[0].name if fleet else None,
    }


COMMAND = ServiceCommand(
    service=Service.SIM,
    help="the PyBullet simulator: wheel angles and body pose out, wheel torques in",
    description="Plays OpenHRP3 and its controller bridge with PyBullet: each step publishes sim/wheel_angles and "
    "sim/body_pose stamped with simulation time, applies the motor/torque answer and steps. Lockstep (default) "
    "waits for the torque of each step while a motor control is alive; realtime paces steps to the wall clock. "
    "A contact with an obstacle publishes sim/bump and calls motor/bump/stop. Parameters: [robot] geometry and "
    "[sim] in the robot description; worlds are TOML files (docs/sim.md).",
    add_arguments=add_arguments,
    overrides=overrides,
    factory=SimService,
)
