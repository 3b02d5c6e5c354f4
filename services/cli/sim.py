"""``invent sim``: its flags, and the simulator's options and config keys they make."""

from __future__ import annotations

import argparse
from typing import Any

from schemas.keys import Service, ServiceName, service_name
from services.cli.flags import engine_flag, fleet_flag, overrides_from_args, parsed_by, positive_seconds
from services.cli.serve import ServiceCli
from services.config import Config, ConfigError, SimConfig, SimMode
from services.fleet.description import load_fleet, robot_config, sim_overrides
from sim_bridge.bridge import COMMAND, SimOptions
from sim_bridge.handshakes import START_HANDSHAKE_TIMEOUT_S
from sim_bridge.world import DEFAULT_WORLD, builtin_worlds


def waited_service(text: str) -> ServiceName:
    """A service ``--wait-for`` may name: a built-in other than the sim, or a user service's name."""
    try:
        service = service_name(text)
    except ValueError as error:
        raise ConfigError(f"--wait-for: {error}") from None
    if service is Service.SIM:
        raise ConfigError("--wait-for: the sim does not wait for itself")
    return service


def add_arguments(parser: argparse.ArgumentParser) -> None:
    defaults = SimConfig()
    group = parser.add_argument_group("simulation")
    group.add_argument("--mode", choices=list(SimMode), help=f"(default {defaults.mode})")
    engine_flag(group)
    group.add_argument(
        "--step", type=positive_seconds, metavar="S", help=f"simulated seconds per step (default {defaults.step:g})"
    )
    group.add_argument("--duration", type=positive_seconds, metavar="S", help="simulate S seconds, then exit 0")
    group.add_argument(
        "--wait-for",
        nargs="+",
        type=parsed_by(waited_service),
        metavar="SERVICE",
        help=f"before the first step, wait (at most {START_HANDSHAKE_TIMEOUT_S:g} s) until these services are there "
        "(motor: alive; drive, localization, a user service taking part in lockstep: holding its lockstep token), "
        "so a lockstep run starts the same way every time (invent up uses it)",
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
    group.add_argument(
        "--gui", action="store_true", help="open a PyBullet window (needs a display and the pybullet engine)"
    )
    fleet_flag(
        group,
        "simulate every robot of this fleet file in one world, each robot's keys under its name "
        "(docs/fleet.md); its world is the fleet's unless --world is given; --robot is then the fleet's",
    )


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    of_fleet = sim_overrides(load_fleet(args.fleet)) if args.fleet else {}
    return {
        **of_fleet,
        "sim.engine": args.engine,
        "sim.mode": args.mode,
        "sim.step": args.step,
        "sim.realtime_factor": args.realtime_factor,
        "sim.world": args.world or of_fleet.get("sim.world"),
    }


def options(args: argparse.Namespace) -> SimOptions:
    fleet = load_fleet(args.fleet) if args.fleet else None
    robots: tuple[Config, ...] = ()
    if fleet is not None:
        given = overrides_from_args(CLI, args)
        robots = tuple(robot_config(robot, args.config, given) for robot in fleet.robots)
    return SimOptions(
        duration=args.duration,
        until_drive_ends=args.until_drive_ends,
        wait_for=tuple(args.wait_for or ()),
        gui=args.gui,
        fleet=fleet,
        fleet_file=args.fleet,
        fleet_robots=robots,
    )


CLI = ServiceCli(
    command=COMMAND,
    help="the simulator (PyBullet, or the kinematic engine): wheel angles and body pose out, wheel torques "
    "(or wheel speed targets) in",
    description="Plays OpenHRP3 and its controller bridge with PyBullet (or, with --engine kinematic, a model of the "
    "wheels' motors and the robot's inertia with ideal rolling, no PyBullet): each step publishes sim/wheel_angles and "
    "sim/body_pose stamped with simulation time, applies the motor/torque answer (motor/wheel_velocity with "
    "motor.output = velocity: the wheels' own loop follows its targets) and steps. Lockstep (default) "
    "waits for the motor's answer of each step while a motor control is alive; realtime paces steps to the wall clock. "
    "A contact with an obstacle publishes sim/bump and calls motor/bump/stop. Each robot's 2D lidar publishes "
    "sim/scan (10 Hz) and its IMU sim/imu (100 Hz) of simulation time. Parameters: [robot] geometry, [sim], "
    "[lidar] and [imu] in the robot description; worlds are TOML files (docs/sim.md).",
    add_arguments=add_arguments,
    options=options,
    overrides=overrides,
)
