"""``invent up``: the whole loop and its report; its flags become an
:class:`~services.launch.plan.UpPlan` for :func:`services.launch.up.run_up`, one robot or a fleet."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from services.cli.flags import (
    connection_from_args,
    description_from_args,
    engine_flag,
    fleet_flag,
    port_number,
    positive_int,
    positive_seconds,
)
from services.config import SIM_BODY_KEYS, ConfigError, RecordRate, SimMode, TfLayout
from services.launch.plan import DEFAULT_SCENARIO, DEPLOYMENT_SETTINGS, UpPlan
from services.launch.restart import (
    DEFAULT_FIRST_DELAY_S,
    DEFAULT_LIMIT,
    MAX_DELAY_S,
    STABLE_AFTER_S,
    RestartPlan,
    parse_restarts,
)
from services.launch.ros2_run import BAG_DIRECTORY
from services.launch.run import RECORDING_FILE, SECRETS_DIRECTORY
from services.launch.stack import plan_from_stack, read_stack, stack_from_plan, stack_toml
from services.launch.up import run_up
from services.navigation.map_file import read_map
from services.recording import view
from services.runtime.session import DEFAULT_ENDPOINT


def run(args: argparse.Namespace) -> int:
    plan = plan_from_stack(read_stack(args.stack)) if args.stack is not None else plan_from_args(args)
    if args.stack is not None:
        _refuse_flags_beside_the_stack(args)
        plan.check()
    if args.print_stack:
        print(stack_toml(stack_from_plan(plan)), end="")
        return 0
    return run_up(plan)


def _refuse_flags_beside_the_stack(args: argparse.Namespace) -> None:
    """ConfigError naming a run flag given with ``--stack``: the file says the whole run."""
    # imported here: services.cli.main imports this module
    from services.cli.main import build_parser

    defaults = vars(build_parser("up").parse_args(["up"]))
    given = sorted(
        name for name, value in vars(args).items() if name not in _NOT_OF_THE_RUN and value != defaults.get(name)
    )
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise ConfigError(f"--stack {args.stack} with {flags}: the stack file says the whole run (docs/stack.md)")


_NOT_OF_THE_RUN = {"stack", "print_stack", "command", "handler"}


def plan_from_args(args: argparse.Namespace) -> UpPlan:
    """The run the flags ask for; ``--record-full-rate``, ``--tf`` and ``--engine`` become ``--set`` settings, for
    every service of the run (the robot description's [record] and [ros2])."""
    description = description_from_args(args)
    goal_mode = args.goals or args.goal_file is not None
    if goal_mode:
        given = {"--scenario": args.scenario is not None, "--loop": args.loop, "--teleop": args.teleop}
        conflicting = [flag for flag, value in given.items() if value]
        if conflicting:
            raise ConfigError(
                f"{'--goals' if args.goals else '--goal-file'} with {', '.join(conflicting)}: in goal mode each drive "
                "takes goals (invent goto X Y [THETA], or the goal file) instead of running a scenario"
            )
    if args.split and args.composed:
        raise ConfigError(
            "--split with --composed: --split runs a realtime run's sim and motor as two processes, --composed "
            "every service in one"
        )
    if args.mapping and not goal_mode:
        raise ConfigError("--mapping builds the map as goals are driven: give --goals or --goal-file")
    if args.mapping and args.map is not None:
        raise ConfigError("--mapping with --map: --mapping builds the map, --map loads one (give one or the other)")
    if args.map is not None:
        read_map(args.map)  # a map that does not load is refused before anything starts
    settings = [
        # a deployment's run keeps the newest of its recording (a --set record.keep given overrides it)
        *(DEPLOYMENT_SETTINGS if goal_mode or args.loop else ()),
        *description.settings,
        *([f"navigation.map={Path(args.map).resolve()}"] if args.map is not None else []),
        *(["navigation.mapping=true"] if args.mapping else []),
        *([f"record.rate={RecordRate.EVERY_STEP}"] if args.record_full_rate else []),
        *([f"ros2.tf={args.tf}"] if args.tf else []),
        *([f"sim.engine={args.engine}"] if args.engine else []),
    ]
    plan = UpPlan(
        connection=connection_from_args(args),
        description=dataclasses.replace(description, settings=tuple(settings)),
        scenario=args.scenario if args.scenario is not None else DEFAULT_SCENARIO,
        scenario_given=args.scenario is not None,
        fleet=args.fleet,
        mode=args.mode,
        report=Path(args.report) if args.report else None,
        no_record=args.no_record,
        gui=args.gui,
        view=args.view,
        strict=args.strict,
        loop=args.loop,
        secure=args.secure,
        tls=args.tls,
        ros2=args.ros2,
        record_ros2=args.record_ros2,
        teleop=args.teleop,
        goals=args.goals and args.goal_file is None,  # both: the goal file's goals
        goal_file=args.goal_file,
        composed=args.composed,
        split=args.split,
        workers=args.workers,
        intra_process=not args.no_intra_process,
        with_services=tuple(args.with_services or ()),
        restarts=RestartPlan(*parse_restarts(args.restart or ()), args.restart_limit, args.restart_backoff),
        sim_set=tuple(args.sim_set or ()),
    )
    plan.check()
    return plan


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stack",
        metavar="FILE.toml",
        help="run the stack this file describes (what drives, how the services are placed in processes, what is "
        "recorded, who watches; docs/stack.md), and no other flag of the run: a key it does not know, or a "
        "choice no run can make, exits 2 naming it",
    )
    parser.add_argument(
        "--print-stack",
        action="store_true",
        help="print the stack of the flags given (or of --stack) as such a file, and run nothing: "
        "invent up FLAGS --print-stack > s.toml; invent up --stack s.toml runs what the flags would",
    )
    parser.add_argument(
        "--scenario",
        help=f"built-in scenario or TOML file (default {DEFAULT_SCENARIO}); with --fleet, of the robots that name none",
    )
    parser.add_argument(
        "--goals",
        action="store_true",
        help="no scenario: each robot's drive waits for goals (invent goto X Y [THETA] --robot R, ROS 2's "
        "NavigateToPose), in realtime unless --mode says otherwise, until Ctrl-C; records run.mcap and writes the "
        "report as a scenario run does, at Ctrl-C (exit 0). Not with --scenario, --loop or --teleop",
    )
    parser.add_argument(
        "--goal-file",
        metavar="FILE",
        help="goal mode with goals (and cancels) sent at fixed simulation times from FILE (invent drive --goal-file; "
        "docs/drive.md, Goals): the run ends when the last goal has, with its outcome, in the configured mode "
        "(lockstep by default); one robot only",
    )
    parser.add_argument(
        "--map",
        metavar="MAP.yaml",
        help="goals navigate on this map (map_server's YAML and PGM; invent map --world FILE -o MAP.yaml makes one): "
        "its obstacles are the costmap's static layer, its extent the costmap's; published on drive/map and, "
        "with --ros2, /map (the same as --set navigation.map=MAP.yaml; docs/navigation.md)",
    )
    parser.add_argument(
        "--mapping",
        action="store_true",
        help="goal mode on a new floor: the drive builds a map from the lidar as the robot drives (each scan "
        "matched to the map so far, correcting the odometry's drift) and publishes it on drive/map (with --ros2, "
        "/map) as it grows (the same as --set navigation.mapping=true; docs/localization.md); "
        "invent map --from run.mcap makes the map file after the run",
    )
    fleet_flag(
        parser,
        "run every robot of this fleet file in one world, each with its own motor, odometry, localization "
        "and drive; report.json has each robot's report under robots.<name> and a fleet summary (docs/fleet.md)",
    )
    parser.add_argument(
        "--mode",
        choices=list(SimMode),
        help="sim mode (default: sim.mode of the robot description, lockstep)",
    )
    report = parser.add_mutually_exclusive_group()
    report.add_argument(
        "--report",
        metavar="DIR",
        help=f"where the recording ({RECORDING_FILE}), report.json and the plots go (default runs/<timestamp>/)",
    )
    report.add_argument(
        "--no-record",
        action="store_true",
        help=f"record nothing, so write no report (it is built from {RECORDING_FILE}): for long runs and benchmarks",
    )
    parser.add_argument(
        "--record-full-rate",
        action="store_true",
        help="record every simulation step (the control path, the poses), not only the observed steps the report "
        "needs: about ten times the size, for debugging the loop (the same as --set record.rate=every_step; "
        "the [record] table caps and splits a recording: docs/recording.md, Rates and bounds)",
    )
    parser.add_argument(
        "--gui", action="store_true", help="open the PyBullet window (needs a display and the pybullet engine)"
    )
    engine_flag(parser)
    parser.add_argument(
        "--view",
        nargs="?",
        const=view.DEFAULT_PORT,
        type=port_number,
        metavar="PORT",
        help=f"serve the run live to Foxglove with `invent view` on ws://{view.DEFAULT_HOST}:PORT (default port "
        f"{view.DEFAULT_PORT}); a lockstep run is over in seconds: add --mode realtime or --loop to watch it",
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 when the run degraded (late or missing torques above 1 %% of the steps, a lockstep timeout, "
        "an internal error, dropped events): for CI",
    )
    parser.add_argument(
        "--loop",
        action="store_true",
        help="repeat the scenario until Ctrl-C, or until a pass is given up (its outcome and exit status: "
        "docs/drive.md, Outcomes); a long-running stack to watch and probe; its recording keeps the newest "
        "files within record.max_size (record.keep = newest), and its report is written at the end",
    )
    parser.add_argument(
        "--secure",
        action="store_true",
        help="usrpwd authentication and access control on the router, every service a client with its role's "
        f"fresh credentials, written first to <report dir>/{SECRETS_DIRECTORY}/<role>.json5 (see docs/security.md)",
    )
    parser.add_argument(
        "--tls", action="store_true", help="with --secure: TLS on every link, a local CA and router certificate"
    )
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="start `invent ros2` beside the loop: the robot in the ROS 2 graph over rmw_zenoh (/odom, /tf, "
        "/joint_states, /scan, /imu, /clock, /robot_description, /cmd_vel, the motor's Trigger services; docs/ros2.md); with "
        "--fleet, one bridge per robot, each in its namespace (/rh0/odom, /rh0/cmd_vel, ...), /clock once",
    )
    parser.add_argument(
        "--tf",
        choices=list(TfLayout),
        help="with --ros2 and a namespace (every robot of a fleet has one): namespaced (default), each robot's "
        "TF on /<NS>/tf and /<NS>/tf_static, frames as named (Nav2's multi-robot bringup); prefixed, every robot "
        "on the shared /tf and /tf_static, frames <NS>/odom, <NS>/base_link, ... under map, for one RViz (the "
        "same as --set ros2.tf=...; docs/ros2.md, A fleet)",
    )
    parser.add_argument(
        "--record-ros2",
        action="store_true",
        help=f"with --ros2: also record what the ROS 2 bridges publish into a rosbag2 bag (MCAP storage) beside "
        f"run.mcap, <report dir>/{BAG_DIRECTORY}/, stamped in simulation time, /clock included, within the bounds "
        "of [record] (`ros2 bag info`, `ros2 bag play --clock`, Foxglove: docs/ros2.md, Bags)",
    )
    parser.add_argument(
        "--teleop",
        action="store_true",
        help="with --ros2: no scenario; the loop runs in realtime, the robot (with --fleet, each robot) following "
        "/cmd_vel from ROS 2 (teleop_twist_keyboard, Nav2) until Ctrl-C; records nothing, prints the run's health "
        "at the end",
    )
    parser.add_argument(
        "--composed",
        action="store_true",
        help="run the services in this one process on one zenoh session (no network hop between them; "
        "the session is the router, so outside zenoh tools still see every key)",
    )
    parser.add_argument(
        "--split",
        action="store_true",
        help="in a realtime run, the sim and the motor as two processes; by default they are one, invent control "
        "(no network hop between them: a step is not made late by the other services' load; docs/realtime.md). "
        "A lockstep run keeps them apart anyway",
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="with --fleet --composed: spread the robots' services over N processes, this one (with the "
        "simulator) and N - 1 workers, each robot's services together (default 1: every service in this "
        "process, which measured faster on two cores: docs/fleet.md)",
    )
    parser.add_argument(
        "--no-intra-process",
        action="store_true",
        help="with --composed: the services' messages go through the zenoh session, not handed over as they are "
        "(intra-process delivery, the default: zenoh then carries a message only to subscribers outside the "
        "process); for measuring and debugging",
    )
    parser.add_argument(
        "--sim-set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        help="the simulated robot differs from the description the other services read by this (repeatable; "
        "after every --set, for the sim alone), e.g. --sim-set robot.radius_of_right_wheel=0.105 (the true "
        "wheel 5 %% larger than the odometry believes) --sim-set lidar.noise=0.01; a key not of the body or "
        "its sensors' noise, or a value the sim's description refuses, exits 2 before anything starts "
        "(not with --fleet). Keys: " + ", ".join(SIM_BODY_KEYS),
    )
    parser.add_argument(
        "--restart",
        action="append",
        metavar="POLICY|SERVICE=POLICY",
        help="restart policy, as docker's (repeatable): on-failure, every service that fails (exits non-zero "
        "other than 2, or is killed) is started again with the same flags, taking its state back (the motor's "
        "latched stop from its state file), within --restart-limit and after --restart-backoff; SERVICE=POLICY "
        "for one service (motor=on-failure; router, control, a --with service's name too), over the other; never "
        "the drive (the sim ends the run's steps when its token goes); "
        "never (the default): a service that ends ends the run. The report names every restart "
        "(docs/deploy.md, Restarts); with --composed, only the services beside it (--with)",
    )
    parser.add_argument(
        "--restart-limit",
        type=positive_int,
        default=DEFAULT_LIMIT,
        metavar="N",
        help=f"with --restart: at most N restarts of each service; past them it ends the run as without a policy "
        f"(default {DEFAULT_LIMIT})",
    )
    parser.add_argument(
        "--restart-backoff",
        type=positive_seconds,
        default=DEFAULT_FIRST_DELAY_S,
        metavar="SECONDS",
        help=f"with --restart: the delay before a service's first restart, doubled at each restart in a row, at "
        f"most {MAX_DELAY_S:g} s, back to this one after the service ran {STABLE_AFTER_S:g} s (default {DEFAULT_FIRST_DELAY_S:g} s, "
        "as docker's)",
    )
    parser.add_argument(
        "--with",
        dest="with_services",
        action="append",
        metavar="FILE.py:NAME",
        help="also run this service of your own (a UserService subclass; docs/extending.md) beside the loop, "
        "supervised as the built-ins are, a process of its own also beside a --composed run (repeatable; a fleet "
        "file says it with `with`); one whose "
        "class drives runs in the built-in drive's place until Ctrl-C (not with --scenario, --loop, --goals, "
        "--goal-file, --teleop)",
    )


HELP = "run the whole loop (router, sim, motor, odometry, localization, drive) and write a report"
DESCRIPTION = (
    "Start every service as its own process in this terminal (in a realtime run of one robot the sim and the "
    "motor as one, invent control, unless --split), drive a scenario, then stop "
    "everything and write a run report (report.json, trajectory.png, wheel_speeds.png). "
    f"--listen sets where its router listens (default {DEFAULT_ENDPOINT}); --connect joins an existing router "
    "instead. Ctrl-C stops everything."
)
GROUPS: tuple[str, ...] = ("connection", "description", "rt")
