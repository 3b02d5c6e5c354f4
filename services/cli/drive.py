"""``invent drive``: its flags, and what to drive they make (:class:`~services.drive.service.DriveOptions`)."""

from __future__ import annotations

import argparse
from typing import Any

from services.cli.flags import finite_number, given_as, parsed_by, positive_seconds
from services.cli.serve import ServiceCli
from services.config import ConfigError, DriveConfig
from services.drive.goal_file import load_goal_file
from services.drive.options import DriveOptions, goal_options, scenario_options
from services.drive.scenarios import (
    BUILTIN_SCENARIOS,
    ConstantSegment,
    Scenario,
    WaypointSegment,
    load_scenario,
    parse_waypoints,
)
from services.drive.service import COMMAND, TWIST_PASS_S


def add_arguments(parser: argparse.ArgumentParser) -> None:
    what = parser.add_argument_group(
        "what to drive (exactly one of --for, --twist, --scenario, --waypoints, --goals, --goal-file)"
    )
    mode = what.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--for",
        dest="duration",
        type=positive_seconds,
        metavar="S",
        help="constant velocity (--vx, --w) for S seconds of simulation time",
    )
    mode.add_argument(
        "--twist",
        nargs=2,
        type=finite_number,
        metavar=("VX", "W"),
        help="hold the velocity VX m/s, W rad/s until Ctrl-C: a target by hand, stamped with simulation time "
        "(the motor refuses a target stamped otherwise, e.g. 0.0, once the simulation is past "
        "motor.command_timeout)",
    )
    mode.add_argument(
        "--scenario",
        type=parsed_by(given_as(load_scenario)),
        metavar="NAME|FILE",
        help=f"a built-in scenario ({', '.join(BUILTIN_SCENARIOS)}) or a scenario TOML file (docs/drive.md)",
    )
    mode.add_argument(
        "--waypoints",
        type=parsed_by(parse_waypoints),
        metavar='"X,Y X,Y ..."',
        help='follow a path through these points (world frame, m), e.g. "1,0 1,1 0,1 0,0"',
    )
    mode.add_argument(
        "--goals",
        action="store_true",
        help="goal mode: no scenario; wait for goals on drive/goal/send (invent goto X Y [THETA], ROS 2's "
        "NavigateToPose), drive to each, publish feedback and each goal's outcome, until Ctrl-C",
    )
    mode.add_argument(
        "--goal-file",
        type=parsed_by(given_as(load_goal_file)),
        metavar="FILE",
        help="goal mode with goals (and cancels) sent at fixed simulation times from a TOML file; ends once the "
        "last has ended, with its outcome's exit code (docs/drive.md, Goals)",
    )
    what.add_argument("--vx", type=finite_number, metavar="M/S", help="with --for: forward speed (default 0)")
    what.add_argument("--w", type=finite_number, metavar="RAD/S", help="with --for: turn rate (default 0)")
    what.add_argument(
        "--loop", action="store_true", help="start the scenario over when it ends, until a pass is given up"
    )
    parser.add_argument(
        "--map",
        metavar="MAP.yaml",
        help="goal mode: navigate on this map (map_server's YAML and its PGM; invent map makes one from a world "
        "file): its obstacles are the costmap's static layer, its extent the costmap's (navigation.map; "
        "docs/navigation.md)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help=f"commands per second of simulation time (drive.rate, default {DriveConfig().rate:g})",
    )


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {"drive.rate": args.rate, "navigation.map": args.map}


def options(args: argparse.Namespace) -> DriveOptions:
    """What the flags drive: a constant velocity for a duration, a twist held, a scenario or waypoints."""
    if args.duration is None and (args.vx is not None or args.w is not None):
        raise ConfigError("--vx and --w go with --for (a constant velocity for a duration); --twist VX W holds one")
    if args.goals or args.goal_file is not None:
        if args.loop:
            raise ConfigError("--loop goes with a scenario or waypoints, not with goals")
        return goal_options(args.goal_file)
    if args.twist is not None:
        vx, w = args.twist
        twist = Scenario(name="twist", segments=[ConstantSegment(vx=vx, w=w, duration=TWIST_PASS_S)])
        return DriveOptions("twist", twist, loop=True)
    if args.scenario is not None:
        return scenario_options(args.scenario, args.loop)
    if args.waypoints is not None:
        waypoints = Scenario(name="waypoints", segments=[WaypointSegment(waypoints=args.waypoints)])
        return DriveOptions("waypoints", waypoints, args.loop)
    segment = ConstantSegment(vx=args.vx or 0.0, w=args.w or 0.0, duration=args.duration)
    return DriveOptions("constant", Scenario(name="constant", segments=[segment]), args.loop)


CLI = ServiceCli(
    command=COMMAND,
    help="publish target velocities: a constant, a scenario, a waypoint path, or goals (sim time)",
    description="Publish drive/target_velocity at drive.rate per second of simulation time (clock: the "
    "stamps on sim/clock). Waypoint paths are followed (pure pursuit, turn-in-place at sharp "
    "corners) on odometry/pose. Publishes zero velocity at the end, then its outcome on drive/outcome, and "
    "exits with it: 0 completed; 3 aborted (the motor stayed latched stopped for drive.give_up_after_stop); "
    "4 timed out (a pass past its time limit). --loop ends only when a pass is given up. "
    "--goals waits for goals (drive/goal/send, drive/goal/cancel; feedback on drive/goal/feedback, each result "
    "on drive/outcome, 5 canceled) until Ctrl-C; --goal-file sends them at fixed simulation times. Goals navigate "
    "(navigation.enabled): a costmap from sim/scan (and --map), a plan around what stands in the way, "
    "recoveries when blocked (docs/navigation.md). "
    "Examples: invent drive --vx 0.3 --w 0.1 --for 5; invent drive --twist 0.2 0.5 (until Ctrl-C); "
    "invent drive --scenario square; invent drive --goals; "
    'invent drive --waypoints "1,0 1,1 0,1 0,0". See docs/drive.md.',
    add_arguments=add_arguments,
    options=options,
    overrides=overrides,
)
