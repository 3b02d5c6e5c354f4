"""``invent up``: the whole closed loop, each service in its own process, and a run report.

Starts the router, then motor, odometry, localization and the drive with the scenario, waits
until they are alive and the drive and the localization hold their lockstep tokens, and
starts the sim last, so a lockstep run steps the whole loop from its first step and starts the
same way every time (services/clock/lockstep.py). Children's output is prefixed with their name. The
run ends when the drive ends its scenario, with an outcome (its exit code: completed, or given up,
aborted or timed out; services/drive/outcome.py), and the sim holds at the step of its last
command (``--until-drive-ends``): ``up`` then reads the services' status, publishes the
run's summary (``up/run``), stops every child with SIGINT, makes ``run.mcap`` of what they
published (:class:`RunRecorder`) and builds the report from it, as ``invent report run.mcap``
does (``--no-record``: no recording, no report, for long runs and benchmarks). A child that dies
early makes ``up`` say which one, stop the others and exit 1. Ctrl-C stops everything cleanly
(exit 130). Either way ``run.mcap`` holds the run up to then. ``up`` exits with the outcome's
code (0, 3 aborted, 4 timed out; docs/protocol.md section 8.5). With ``--composed`` the same
services run in this one process instead (``services/launch/composition.py``); a fleet's run is ``services/launch/fleet.py``.
"""

from __future__ import annotations

import argparse
import time
from contextlib import ExitStack
from pathlib import Path

from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary, Time
from services.clock.lockstep import LOOP_BEFORE_FIRST_STEP
from services.config import Config, ConfigError, SimMode
from services.drive.scenarios import load_scenario
from services.errors import ChildDied, Interrupted
from services.exits import ExitStatus
from services.launch import ros2_run
from services.launch.children import say
from services.launch.recorder import RunRecorder
from services.launch.ros2_run import BagRecording, check_ros2_flags
from services.launch.run import (
    MOTOR_STATE_FILE,
    RECORDING_FILE,
    SECRETS_DIRECTORY,
    SERVICES_BEFORE_DRIVE,
    Access,
    Outcomes,
    Run,
    ViewProcess,
    default_report_dir,
    launch_services,
    outcome_exit_code,
    rt_flags,
    verdict,
)
from services.recording import view
from services.recording.mcap_files import write_run_report
from services.recording.report import degradation_line, degradations, health_lines, loop_health, summary
from services.ros2.graph import bridge_graph
from services.runtime.inputs import Publisher
from services.runtime.session import DEFAULT_ENDPOINT, stop_on_signals
from services.security import Role, write_profile
from services.service import port_number
from sim_bridge.display import require_display
from sim_bridge.world import load_world

TELEOP = "teleop"
"""The scenario name of a ``--teleop`` run (ROS 2 drives it)."""


def _child_args(args: argparse.Namespace, endpoint: str) -> list[str]:
    common = ["--connect", endpoint, "--log-level", args.log_level]
    if args.robot:
        common += ["--robot", args.robot]
    if args.config:
        common += ["--config", args.config]
    for override in args.set or ():
        common += ["--set", override]
    return common


def _access(args: argparse.Namespace, config: Config, report_dir: Path) -> Access:
    """The run's :class:`Access`; with ``--secure``, the profile is written before anything starts."""
    if args.tls and not args.secure:
        raise ConfigError("--tls: it is an option of --secure (use both)")
    if not args.secure:
        return Access(None, args.zenoh_config)
    given = {"--composed": args.composed, "--connect": args.connect, "--zenoh-config": args.zenoh_config}
    conflicting = [flag for flag, value in given.items() if value]
    if conflicting:
        raise ConfigError(
            f"--secure with {', '.join(conflicting)}: a secure run starts its own router and runs every "
            "service as a client of it, each with its role's credentials"
        )
    listen = args.listen or [DEFAULT_ENDPOINT]
    profile = write_profile(
        report_dir / SECRETS_DIRECTORY,
        Keys(config.robot.name),
        endpoint=listen[0],
        router_listen=listen,
        tls=args.tls,
        ros=bridge_graph(config),
    )
    say(
        f"secure: usrpwd and access control on the router{', TLS' if profile.tls else ''}; every service a client; "
        f"credentials for each role in {profile.directory}/ (e.g. --zenoh-config {profile.client_config(Role.OBSERVER)})"
    )
    return Access(profile, None)


def check_before_start(args: argparse.Namespace, config: Config) -> None:
    """Refuse (ConfigError: exit 2) what a child would refuse once started, before any starts: a
    service that exits 2 would take the others down noisily and leave a run of nothing behind."""
    if args.gui:
        require_display()
    if args.workers is not None:
        raise ConfigError("--workers: it spreads a fleet's robots over processes (with --fleet --composed)")
    if args.view == 0:
        raise ConfigError("--view: the view's port must be fixed (1..65535), for the address to open in Foxglove")
    check_ros2_flags(args)
    if not args.teleop:
        load_scenario(args.scenario)
    load_world(config.sim.world)
    if args.ros2:
        bridge_graph(config)  # $ROS_DOMAIN_ID


def run_up(args: argparse.Namespace, config: Config, parser: argparse.ArgumentParser) -> int:
    check_before_start(args, config)
    keys = Keys(config.robot.name)
    report_dir = Path(args.report) if args.report else default_report_dir()
    access = _access(args, config, report_dir)
    endpoint = access.profile.endpoint if access.profile else (args.connect or args.listen or [DEFAULT_ENDPOINT])[0]
    common = _child_args(args, endpoint)
    mode = SimMode.REALTIME if args.teleop else args.mode or config.sim.mode
    scenario = TELEOP if args.teleop else args.scenario
    interrupted = stop_on_signals()
    recording = not (args.no_record or args.loop or args.teleop)
    # the journals: the services', the drive's, the sim's and up's own
    journals = len(SERVICES_BEFORE_DRIVE) + args.ros2 + 3
    bag = BagRecording(report_dir, config.record, 1, config.ros2.distro) if args.record_ros2 else None
    recorder = RunRecorder(report_dir, config.record, journals) if recording else None
    journal_flags = recorder.flags if recorder else []
    sim_started = False
    try:
        with launch_services(args, endpoint, parser, access) as (launcher, session), ExitStack() as closing:
            run = Run(launcher, session, keys, interrupted)
            outcomes = Outcomes(session, [keys.robot], launcher.bus)
            closing.callback(outcomes.close)
            summary_publisher = Publisher(session, keys.run_summary, recorder.journal if recorder else None)
            if recorder:
                recorder.watch(session, keys)
            if args.view is not None:
                live_view = ViewProcess([*common, *access.flags(Role.OBSERVER)], args.view)
                closing.callback(live_view.close)
                live_view.wait_serving(run)
            own_flags = {
                Service.MOTOR: ["--state", str(report_dir / MOTOR_STATE_FILE), *rt_flags(args)],
                Service.ROS2: bag.flags if bag else [],
            }
            before_drive = (*SERVICES_BEFORE_DRIVE, *((Service.ROS2,) if args.ros2 else ()))
            for service in before_drive:
                flags = [*common, *access.flags(Role(service)), *journal_flags, *own_flags.get(service, [])]
                launcher.start(str(service), [str(service), *flags])
            run.wait_alive(before_drive)
            drive = None
            if args.teleop:
                sim_flags = ["--mode", mode, "--wait-for", str(Service.MOTOR)]
            else:
                drive_flags = ["--scenario", args.scenario, *(["--loop"] if args.loop else [])]
                drive = launcher.start(
                    "drive", ["drive", *common, *access.flags(Role.DRIVE), *journal_flags, *drive_flags]
                )
                run.wait_alive((Service.DRIVE,))
                run.wait_tokens(
                    [
                        keys.ticks(Service.DRIVE, config.drive.rate),
                        keys.ticks(Service.LOCALIZATION, config.localization.rate),
                    ]
                )
                wait_for = [str(service) for service in LOOP_BEFORE_FIRST_STEP]
                sim_flags = ["--mode", mode, "--until-drive-ends", "--wait-for", *wait_for]
            sim_flags += [*(["--gui"] if args.gui else []), *rt_flags(args)]
            if args.teleop:
                say("teleop: the robot follows ROS 2's /cmd_vel (Twist or TwistStamped) until Ctrl-C; see docs/ros2.md")
            launcher.start("sim", ["sim", *common, *access.flags(Role.SIM), *journal_flags, *sim_flags])
            sim_started = True
            started = time.monotonic()
            sim_status, drive_status, outcome = run.supervise(
                drive, started, recorder.during if recorder else None, until_interrupted=args.loop or args.teleop
            )
            wall_time_s = time.monotonic() - started
            statuses = {str(service): run.status(service) for service in Service if service != Service.DRIVE}
            statuses[str(Service.DRIVE)] = drive_status
            health = loop_health(sim_status, statuses)
            if recorder:
                summary_publisher.put(
                    RunSummary(
                        tm=Time.from_nanoseconds(
                            round((sim_status or {}).get("sim_time_s", 0.0) * NANOSECONDS_PER_SECOND)
                        ),
                        scenario=scenario,
                        mode=mode,
                        composed=args.composed,
                        wall_time_s=wall_time_s,
                        steps=int(sim_status["steps"]) if sim_status else 0,
                        health=health,
                    )
                )
            unclean = {
                name: code
                for name, code in launcher.stop().items()
                if code != 0 and not (name == str(Service.DRIVE) and outcome is not None)
            }
            if unclean:
                say(f"services that did not exit cleanly: {unclean}")
            outcome_line = None if outcome is None else outcomes.line(keys.robot, outcome)
    except ChildDied as error:
        say(f"{error}; stopped everything")
        return ExitStatus.FAILURE
    except Interrupted:
        say("interrupted; stopped everything")
        return ExitStatus.INTERRUPTED
    finally:
        if recorder:
            recorder.finish(sim_started, report_dir / RECORDING_FILE, config)
        if bag:
            bag.finish(sim_started)
    if not recorder:
        degraded = degradations(health)
        lines = [*([outcome_line] if outcome_line else []), *health_lines(health), *map(degradation_line, degraded)]
        print("\n".join(lines), flush=True)
        return verdict(
            args,
            degraded,
            "done; no recording, no report ("
            + ("--teleop" if args.teleop else "--loop" if args.loop else "--no-record")
            + ")",
            outcome_exit_code([outcome]),
        )
    report, path, plots = write_run_report(report_dir / RECORDING_FILE, report_dir, config)
    print(summary(report), flush=True)
    return verdict(
        args,
        report["degraded"],
        f"recording: {report_dir / RECORDING_FILE}; report: {path}; plots: {', '.join(str(p) for p in plots)}",
        outcome_exit_code([outcome]),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        default="square",
        help="built-in scenario or TOML file (default square); with --fleet, of the robots that name none",
    )
    parser.add_argument(
        "--fleet",
        metavar="FILE",
        help="run every robot of this fleet file in one world, each with its own motor, odometry, localization "
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
        "the [record] table caps and splits a recording: README, Rates and bounds)",
    )
    parser.add_argument("--gui", action="store_true", help="open the PyBullet window (needs a display)")
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
        "docs/drive.md, Outcomes); a long-running stack to watch and probe; records nothing, so memory stays "
        "flat, and prints the run's health at the end",
    )
    parser.add_argument(
        "--secure",
        action="store_true",
        help="usrpwd authentication and access control on the router, every service a client with its role's "
        f"fresh credentials, written first to <report dir>/{SECRETS_DIRECTORY}/<role>.json5 (see README, Security)",
    )
    parser.add_argument(
        "--tls", action="store_true", help="with --secure: TLS on every link, a local CA and router certificate"
    )
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="start `invent ros2` beside the loop: the robot in the ROS 2 graph over rmw_zenoh (/odom, /tf, "
        "/joint_states, /clock, /robot_description, /cmd_vel, the motor's Trigger services; docs/ros2.md); with "
        "--fleet, one bridge per robot, each in its namespace (/rh0/odom, /rh0/cmd_vel, ...), /clock once",
    )
    ros2_run.add_arguments(parser)
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
