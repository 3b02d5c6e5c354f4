"""``invent up``: the whole closed loop, each service in its own process, and a run report.

Starts the router, then motor, odometry, localization and the drive with the scenario, waits
until they are alive and the drive and the localization hold their lockstep tokens, and
starts the sim last, so a lockstep run steps the whole loop from its first step and starts the
same way every time (services/clock/lockstep.py). A realtime run of one robot starts the sim and
the motor as one child, ``invent control``, in the motor's place (:func:`composes_control_path`):
its sim waits for the same tokens before its first step. Children's output is prefixed with their name. The
run ends when the drive ends its scenario, with an outcome (its exit code: completed, or given up,
aborted or timed out; services/drive/outcome.py), and the sim holds at the step of its last
command (``--until-drive-ends``): ``up`` then reads the services' status, publishes the
run's summary (``up/run``), stops every child with SIGINT, makes ``run.mcap`` of what they
published (:class:`RunRecorder`) and builds the report from it, as ``invent report run.mcap``
does (``--no-record``: no recording, no report, for benchmarks). A child that dies
early makes ``up`` say which one and how, stop the others and exit 1, unless the run's restart
policy (``--restart``, services/launch/restart.py) starts it again: then the run goes on, and its
summary and report name each restart (past the policy's limit, the run ends so). Ctrl-C stops everything cleanly
(exit 130). Either way, once the sim has started, the run's summary says why it ended early
(``ended_early``) and ``run.mcap`` and the report hold the run up to then. ``up`` exits with the outcome's
code (0, 3 aborted, 4 timed out; docs/protocol.md section 8.5). With ``--composed`` the same
services run in this one process instead (``services/launch/composition.py``).

:func:`run_up` is the one entry of every run and its one sequence, of one robot or (``--fleet``)
of a fleet: what the two do their own way is given to it (services/launch/robots.py's
:class:`~services.launch.robots.Robots`: ``services/launch/one_robot.py``, ``services/launch/fleet.py``).
"""

from __future__ import annotations

import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from schemas.keys import CONTROL, Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary, ServiceRestart, Time
from services.clock.lockstep import LOOP_BEFORE_FIRST_STEP
from services.config import ConfigError, SimMode
from services.errors import ChildDied, Interrupted
from services.extension.loader import Loaded, driving
from services.launch.children import ServiceDied, Supervisor, say
from services.launch.fleet import FleetRobots
from services.launch.one_robot import OneRobot
from services.launch.plan import UpPlan
from services.launch.recorder import RunRecorder
from services.launch.restart import RestartPlan
from services.launch.robots import Robot, Robots, robot_degradations
from services.launch.ros2_run import BagRecording
from services.launch.run import (
    MOTOR_STATE_FILE,
    RECORDING_FILE,
    SERVICES_BEFORE_DRIVE,
    Outcomes,
    Run,
    ViewProcess,
    early_end,
    ended_early,
    launch_services,
    outcome_exit_code,
    rt_flags,
    start,
    verdict,
)
from services.recording.report import degradation_line, restart_degradation, restarts_line
from services.recording.run_report import restart_entries
from services.runtime.inputs import Publisher
from services.security import Role
from services.service import ServiceParse


def run_up(plan: UpPlan, parse: ServiceParse) -> int:
    """``invent up``: the run ``plan`` asks for, of one robot or (``plan.fleet``) of a fleet; its exit status."""
    robots: Robots = FleetRobots(plan, plan.fleet) if plan.fleet else OneRobot(plan)
    drivers = {robot.name: driving(robot.extensions) for robot in robots.each}
    """Each robot's service of the user's own that drives in the built-in drive's place, if any."""
    if plan.fleet and any(drivers.values()):
        raise ConfigError("--fleet with a service that drives (its class's drives): one robot's run only")
    # a service that drives runs until Ctrl-C, or until it gives up or finishes, as the drive does
    until_interrupted = plan.until_interrupted or any(drivers.values())
    supervisor = Supervisor(_restart_plan(plan, robots, drivers))
    begun = start(plan, robots.access)
    report_dir, access, endpoint, common = begun.report_dir, begun.access, begun.endpoint, begun.common
    first = robots.each[0]
    # --teleop and --goals wait for someone to drive the robot: paced by the wall clock (--goals: unless --mode says)
    mode = (
        SimMode.REALTIME
        if plan.teleop
        else plan.mode or (SimMode.REALTIME if plan.goals and plan.goal_file is None else first.config.sim.mode)
    )
    # every child is told the run's mode: in lockstep their publishers block rather than drop (protocol §2.6)
    common = [*common, "--set", f"sim.mode={mode}"]
    robot_services = (*SERVICES_BEFORE_DRIVE, *((Service.ROS2,) if plan.ros2 else ()))
    control_path_composed = composes_control_path(plan, mode)
    # the journals: each robot's services', user services' and drive's, the sim's and up's own
    journals = len(robots.each) * (len(robot_services) + 1) + sum(len(_beside(r.extensions)) for r in robots.each) + 2
    record = first.config.record
    bag = BagRecording(report_dir, record, len(robots.each), first.config.ros2.distro) if plan.record_ros2 else None
    recording = not (plan.no_record or plan.teleop)
    recorder = RunRecorder(report_dir, record, journals) if recording else None
    health: dict[str, dict[str, Any]] = {}
    sim_started = False
    early: ServiceDied | Interrupted | None = None
    """Why a recorded run ended before its end, once the sim had started: it still leaves its report."""

    def journal(robot: Robot) -> list[str]:
        if recorder is None:
            return []
        directory = robot.folder(recorder.directory)
        directory.mkdir(exist_ok=True)
        return ["--journal", str(directory), *recorder.share]

    if plan.teleop:  # no drive: the sim steps on until Ctrl-C, waiting for each robot's torque only
        ending = ["--wait-for", str(Service.MOTOR)]
    else:
        # a localization without fixes (mode none) holds no ticks token: nothing to wait for
        waited = [
            service
            for service in LOOP_BEFORE_FIRST_STEP
            if service is not Service.LOCALIZATION
            or all(robot.config.localization.participates for robot in robots.each)
        ]
        ending = ["--until-drive-ends", "--wait-for", *(str(service) for service in waited)]
        # a user participant's name, where every robot has it (the sim waits for each name on every robot)
        ending += sorted(set.intersection(*(set(robot.participants) for robot in robots.each)))
    simulation = [*robots.sim_flags, "--mode", mode, *ending, *(["--gui"] if plan.gui else []), *rt_flags(plan)]
    if plan.sim_set:
        say(
            f"sim-set: the simulated robot differs from the description the other services read: {', '.join(plan.sim_set)}"
        )

    try:
        with (
            launch_services(plan, endpoint, parse, access, robots.assignment(), supervisor) as (launcher, session),
            ExitStack() as closing,
        ):
            run = Run(launcher, session, Keys(first.name), begun.interrupted)
            outcomes = Outcomes(session, [robot.name for robot in robots.each], launcher.bus)
            closing.callback(outcomes.close)
            summaries = {
                robot.name: Publisher(session, Keys(robot.name).run_summary, recorder.journal if recorder else None)
                for robot in robots.each
            }
            if recorder and robots.records_statuses:
                recorder.watch(session, run.keys)
            if plan.view is not None:
                live_view = ViewProcess([*common, *access.flags(Role.OBSERVER), *robots.view_flags], plan.view)
                closing.callback(live_view.close)
                live_view.wait_serving(run)
            for robot in robots.each:
                own = {
                    Service.MOTOR: [*_motor_flags(robot, report_dir), *rt_flags(plan)],
                    Service.ROS2: [*robot.bridge_flags, *(bag.flags if bag else [])],
                }
                for service in robot_services:
                    if service == Service.MOTOR and control_path_composed:
                        # invent control: the sim and the motor in one child, its sim waiting for the
                        # drive's and the participants' tokens (--wait-for) before its first step
                        control = [*common, *access.flags(Role.CONTROL), *(recorder.flags if recorder else [])]
                        control += [*simulation, *plan.sim_flags("--sim-set"), *_motor_flags(robot, report_dir)]
                        launcher.start(CONTROL, [CONTROL, *control])
                        continue
                    flags = [*common, *robot.credentials(access, Role(service)), *robot.flags, *journal(robot)]
                    launcher.start(robot.child(service), [str(service), *flags, *own.get(service, [])])
            for robot in robots.each:  # the user's own (--with), beside them, supervised as they are
                for user in _beside(robot.extensions):
                    flags = [*common, *robot.user_credentials(access, user.name), *robot.flags, *journal(robot)]
                    launcher.start(robot.child(user.name), ["service", user.spec, *flags])
            # Until the sim starts, any service that ends ends the run.
            run.wait_tokens(
                [Keys(robot.name).alive(service) for robot in robots.each for service in robot_services]
                + [Keys(robot.name).alive(user.name) for robot in robots.each for user in _beside(robot.extensions)]
            )
            driven = () if plan.teleop else robots.each
            drives = {}
            for robot in driven:
                flags = [*common, *robot.credentials(access, Role.DRIVE), *robot.flags, *journal(robot)]
                driver = drivers[robot.name]
                if driver is not None:  # in the drive's place, with the drive's credentials
                    drives[robot.name] = launcher.start(robot.child(driver.name), ["service", driver.spec, *flags])
                    continue
                flags += _drive_flags(plan, robot)
                drives[robot.name] = launcher.start(robot.child(Service.DRIVE), [str(Service.DRIVE), *flags])
            for tokens in robots.drive_waits(driven):
                run.wait_tokens(tokens)
            if plan.teleop:
                say(robots.teleop_line)
            if not control_path_composed:
                sim_session = [*common, *access.flags(Role.SIM), *(recorder.flags if recorder else [])]
                # the sim's own --set after the common ones: the later value of a key wins
                launcher.start(str(Service.SIM), [str(Service.SIM), *sim_session, *simulation, *plan.sim_flags()])
            sim_started = True
            started = time.monotonic()
            if started_line := robots.started_line(mode):
                say(started_line)
            watch = robots.watch(run, drives)
            try:
                watch.supervise(started, recorder.during if recorder else None, until_interrupted)
            except (ServiceDied, Interrupted) as error:
                if recorder is None:
                    raise
                # a run that ends early still ends as one that did not: its summary (saying why), its report
                say(f"{str(error) or 'interrupted'}: the run ends here, with its report")
                early = error
            wall_time_s = time.monotonic() - started
            if recorder:
                recorder.last_statuses()
            for robot in robots.each:
                sim_status, health[robot.name] = watch.health(robot.name)
                if recorder:
                    summaries[robot.name].put(
                        RunSummary(
                            tm=Time.from_nanoseconds(
                                0 if sim_status is None else round(sim_status.sim_time_s * NANOSECONDS_PER_SECOND)
                            ),
                            scenario=robot.scenario,
                            mode=mode,
                            composed=plan.composed,
                            wall_time_s=wall_time_s,
                            steps=0 if sim_status is None else sim_status.steps,
                            health=health[robot.name],
                            **(early_end(early) if early is not None else {}),
                            restarts=_restarts_of(robot, supervisor.restarted),
                        )
                    )
            ended = watch.outcomes(outcomes)
            died = early.service if isinstance(early, ServiceDied) else None
            stopped = launcher.stop().items()
            unclean = {name: code for name, code in stopped if code != 0 and not watch.ended(name) and name != died}
            if unclean:
                say(f"services that did not exit cleanly: {unclean}")
            named = {robot.name: robot for robot in robots.each}
            outcome_lines = [named[name].label(outcomes.line(name, outcome)) for name, outcome in ended.items()]
    except (ChildDied, Interrupted) as error:
        return ended_early(error)
    finally:
        if recorder:
            recorder.finish(sim_started, report_dir / RECORDING_FILE, first.config, robots.scene)
        if bag:
            bag.finish(sim_started)
    outcome_code = outcome_exit_code(list(ended.values()))
    not_completed = "the last goal did not complete" if plan.goal_mode else "the scenario was given up"
    if recorder is None:
        restarts = restart_entries(supervisor.restarted)
        degraded = [robot.label(reason) for robot in robots.each for reason in robot_degradations(health[robot.name])]
        degraded += map(restart_degradation, restarts)
        restarted = [restarts_line(restarts)] if restarts else []
        for line in [*outcome_lines, *robots.health_lines(health), *restarted, *map(degradation_line, degraded)]:
            print(line, flush=True)
        why = "--teleop" if plan.teleop else "--no-record"
        return verdict(plan.strict, degraded, f"done; no recording, no report ({why})", outcome_code, not_completed)
    degraded, written = robots.report(report_dir)
    if early is not None:
        say(written)
        return ended_early(early)
    return verdict(plan.strict, degraded, written, outcome_code, not_completed)


def _restart_plan(plan: UpPlan, robots: Robots, drivers: dict[str, Loaded | None]) -> RestartPlan:
    """The run's restart policy, each ``--restart SERVICE=`` checked against its services (ConfigError:
    exit 2). A drive (or the service that drives in its place) is never started again: the sim ends
    the run's steps when its token goes (``--until-drive-ends``), so a new one would drive nothing."""
    drives = {str(Service.DRIVE), *(driver.name for driver in drivers.values() if driver is not None)}
    users = {user.name for robot in robots.each for user in robot.extensions}
    # composed, only the user's own services are processes (services/launch/run.py, Beside)
    plan.restarts.check_services(users if plan.composed else {"router", CONTROL, *Service, *users})
    return plan.restarts.never(drives, "the sim ends the run's steps when the drive's token goes (--until-drive-ends)")


def _restarts_of(robot: Robot, restarted: list[ServiceRestart]) -> tuple[ServiceRestart, ...]:
    """The restarts a robot's summary names: its own services' and the run's (a fleet's router and sim)."""
    return tuple(
        restart
        for restart in restarted
        if not robot.in_fleet or "/" not in restart.service or restart.service.startswith(f"{robot.name}/")
    )


def _beside(extensions: tuple[Loaded, ...]) -> tuple[Loaded, ...]:
    """The services of the user's own that run beside the loop: all but the one that drives."""
    return tuple(user for user in extensions if user.service.drives is None)


def composes_control_path(plan: UpPlan, mode: SimMode) -> bool:
    """Whether the run's sim and motor are one child, ``invent control``, as docker compose runs
    them: in a realtime run of one robot in separate processes, unless ``--split``. A step's
    exchange then never leaves the process, and the other services' load (the ROS 2 bridge, the
    view) cannot make a step late by delaying the other process's wake-up (docs/realtime.md). A
    lockstep run has no late steps, and a fleet's sim is the fleet's."""
    return mode == SimMode.REALTIME and not (plan.fleet or plan.composed or plan.split)


def _motor_flags(robot: Robot, report_dir: Path) -> list[str]:
    """The motor's own: where it keeps its latched stop across restarts (docs/protocol.md)."""
    return ["--state", str(robot.folder(report_dir) / MOTOR_STATE_FILE)]


def _drive_flags(plan: UpPlan, robot: Robot) -> list[str]:
    """What ``robot``'s drive runs: goals (``--goals``), a goal file (``--goal-file``, or a fleet robot's
    own), or its scenario (``--loop``: over and over)."""
    if plan.goal_file is not None:
        return ["--goal-file", plan.goal_file]
    if plan.goals:
        return ["--goals"]
    if robot.goal_file is not None:
        return ["--goal-file", robot.goal_file]
    return ["--scenario", robot.scenario, *(["--loop"] if plan.loop else [])]
