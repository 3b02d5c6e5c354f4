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
services run in this one process instead (``services/launch/composition.py``).

:func:`run_up` is the one entry of every run, of one robot or (``--fleet``) of a fleet, whose run
is ``services/launch/fleet.py``.
"""

from __future__ import annotations

import time
from contextlib import ExitStack
from functools import partial
from pathlib import Path

from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary, Time
from services.clock.lockstep import LOOP_BEFORE_FIRST_STEP
from services.config import Config, ConfigError, SimMode
from services.drive.scenarios import load_scenario
from services.errors import ChildDied, Interrupted
from services.launch.children import say
from services.launch.fleet import run_fleet
from services.launch.plan import UpPlan
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
    ended_early,
    launch_services,
    outcome_exit_code,
    rt_flags,
    secure_listen,
    start,
    verdict,
)
from services.recording.mcap_files import write_run_report
from services.recording.report import degradation_line, degradations, health_lines, loop_health, summary
from services.ros2.graph import bridge_graph
from services.runtime.inputs import Publisher
from services.security import Role, write_profile
from services.service import ServiceParse
from sim_bridge.display import require_display
from sim_bridge.world import load_world

TELEOP = "teleop"
"""The scenario name of a ``--teleop`` run (ROS 2 drives it)."""


def _access(plan: UpPlan, config: Config, report_dir: Path) -> Access:
    """The run's :class:`Access`; with ``--secure``, the profile is written before anything starts."""
    listen = secure_listen(plan)
    connection = plan.connection
    if listen is None:
        return Access(None, connection.zenoh_config)
    given = {"--composed": plan.composed, "--connect": connection.connect, "--zenoh-config": connection.zenoh_config}
    conflicting = [flag for flag, value in given.items() if value]
    if conflicting:
        raise ConfigError(
            f"--secure with {', '.join(conflicting)}: a secure run starts its own router and runs every "
            "service as a client of it, each with its role's credentials"
        )
    profile = write_profile(
        report_dir / SECRETS_DIRECTORY,
        Keys(config.robot.name),
        endpoint=listen[0],
        router_listen=listen,
        tls=plan.tls,
        ros=bridge_graph(config),
    )
    say(
        f"secure: usrpwd and access control on the router{', TLS' if profile.tls else ''}; every service a client; "
        f"credentials for each role in {profile.directory}/ (e.g. --zenoh-config {profile.client_config(Role.OBSERVER)})"
    )
    return Access(profile, None)


def check_before_start(plan: UpPlan, config: Config) -> None:
    """Refuse (ConfigError: exit 2) what a child would refuse once started, before any starts: a
    service that exits 2 would take the others down noisily and leave a run of nothing behind."""
    if plan.gui:
        require_display()
    if plan.workers is not None:
        raise ConfigError("--workers: it spreads a fleet's robots over processes (with --fleet --composed)")
    if plan.view == 0:
        raise ConfigError("--view: the view's port must be fixed (1..65535), for the address to open in Foxglove")
    check_ros2_flags(plan)
    if not plan.teleop:
        load_scenario(plan.scenario)
    load_world(config.sim.world)
    if plan.ros2:
        bridge_graph(config)  # $ROS_DOMAIN_ID


def run_up(plan: UpPlan, parse: ServiceParse) -> int:
    """``invent up``: the run ``plan`` asks for, of one robot or (``plan.fleet``) of a fleet; its exit status."""
    if plan.fleet:
        return run_fleet(plan, plan.fleet, parse)
    config = plan.description.load()
    check_before_start(plan, config)
    keys = Keys(config.robot.name)
    begun = start(plan, partial(_access, plan, config))
    report_dir, access, endpoint, common = begun.report_dir, begun.access, begun.endpoint, begun.common
    mode = SimMode.REALTIME if plan.teleop else plan.mode or config.sim.mode
    scenario = TELEOP if plan.teleop else plan.scenario
    recording = not (plan.no_record or plan.loop or plan.teleop)
    # the journals: the services', the drive's, the sim's and up's own
    journals = len(SERVICES_BEFORE_DRIVE) + plan.ros2 + 3
    bag = BagRecording(report_dir, config.record, 1, config.ros2.distro) if plan.record_ros2 else None
    recorder = RunRecorder(report_dir, config.record, journals) if recording else None
    journal_flags = recorder.flags if recorder else []
    sim_started = False
    try:
        with launch_services(plan, endpoint, parse, access) as (launcher, session), ExitStack() as closing:
            run = Run(launcher, session, keys, begun.interrupted)
            outcomes = Outcomes(session, [keys.robot], launcher.bus)
            closing.callback(outcomes.close)
            summary_publisher = Publisher(session, keys.run_summary, recorder.journal if recorder else None)
            if recorder:
                recorder.watch(session, keys)
            if plan.view is not None:
                live_view = ViewProcess([*common, *access.flags(Role.OBSERVER)], plan.view)
                closing.callback(live_view.close)
                live_view.wait_serving(run)
            own_flags = {
                Service.MOTOR: ["--state", str(report_dir / MOTOR_STATE_FILE), *rt_flags(plan)],
                Service.ROS2: bag.flags if bag else [],
            }
            before_drive = (*SERVICES_BEFORE_DRIVE, *((Service.ROS2,) if plan.ros2 else ()))
            for service in before_drive:
                flags = [*common, *access.flags(Role(service)), *journal_flags, *own_flags.get(service, [])]
                launcher.start(str(service), [str(service), *flags])
            run.wait_alive(before_drive)
            drive = None
            if plan.teleop:
                sim_flags = ["--mode", mode, "--wait-for", str(Service.MOTOR)]
            else:
                drive_flags = ["--scenario", plan.scenario, *(["--loop"] if plan.loop else [])]
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
            sim_flags += [*(["--gui"] if plan.gui else []), *rt_flags(plan)]
            if plan.teleop:
                say("teleop: the robot follows ROS 2's /cmd_vel (Twist or TwistStamped) until Ctrl-C; see docs/ros2.md")
            launcher.start("sim", ["sim", *common, *access.flags(Role.SIM), *journal_flags, *sim_flags])
            sim_started = True
            started = time.monotonic()
            sim_status, drive_status, outcome = run.supervise(
                drive, started, recorder.during if recorder else None, until_interrupted=plan.loop or plan.teleop
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
                        composed=plan.composed,
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
    except (ChildDied, Interrupted) as error:
        return ended_early(error)
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
            plan.strict,
            degraded,
            "done; no recording, no report ("
            + ("--teleop" if plan.teleop else "--loop" if plan.loop else "--no-record")
            + ")",
            outcome_exit_code([outcome]),
        )
    report, path, plots = write_run_report(report_dir / RECORDING_FILE, report_dir, config)
    print(summary(report), flush=True)
    return verdict(
        plan.strict,
        report["degraded"],
        f"recording: {report_dir / RECORDING_FILE}; report: {path}; plots: {', '.join(str(p) for p in plots)}",
        outcome_exit_code([outcome]),
    )
