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

import dataclasses
import time
from contextlib import ExitStack
from typing import Any

from schemas.keys import CONTROL, Keys, Service, ServiceName, UserServiceName
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary, ServiceRestart, Time
from services import interfaces
from services.clock.lockstep import OUTPUTS
from services.config import ConfigError, SimMode
from services.drive.options import DriveOptions, goal_options, scenario_options
from services.drive.service import COMMAND as DRIVE
from services.errors import ChildDied, Interrupted
from services.extension.hosting import UserOptions
from services.extension.hosting import command as hosted
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
    start,
    verdict,
)
from services.launch.service_plans import (
    BUILT_IN,
    ChildPlan,
    ControlPlan,
    connection_flags,
    description_flags,
    sim_options,
)
from services.motor.service import MotorOptions
from services.recording.report import degradation_line, restart_degradation, restarts_line
from services.recording.run_report import restart_entries
from services.runtime.inputs import Publisher
from services.security import Role
from services.service import Journaling, ServiceCommand
from sim_bridge.bridge import COMMAND as SIM


def run_up(plan: UpPlan) -> int:
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
    report_dir, access, endpoint = begun.report_dir, begun.access, begun.endpoint
    first = robots.each[0]
    # --teleop and --goals wait for someone to drive the robot: paced by the wall clock (--goals: unless --mode says)
    mode = (
        SimMode.REALTIME
        if plan.teleop
        else plan.mode or (SimMode.REALTIME if plan.goals and plan.goal_file is None else first.config.sim.mode)
    )
    # every child is told the run's mode: in lockstep their publishers block rather than drop (protocol §2.6);
    # --rt goes to the control path's children alone, the rt.* settings to all
    described = plan.description
    description = dataclasses.replace(described, settings=(*described.settings, f"sim.mode={mode}"), rt=False)
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

    def journaling(robot: Robot | None = None) -> Journaling:
        """Where a service keeps its journal: a robot's in its folder, the sim's and control's in the run's."""
        if recorder is None:
            return Journaling()
        if robot is None:
            return recorder.journaling()
        directory = robot.folder(recorder.directory)
        directory.mkdir(exist_ok=True)
        return recorder.journaling(directory)

    def child(
        robot: Robot, name: str, command: ServiceCommand[Any], options: Any, credentials: str | None
    ) -> ChildPlan[Any]:
        """``robot``'s service ``name`` as the run starts it, connecting with ``credentials``."""
        connection = dataclasses.replace(begun.connection, zenoh_config=credentials)
        return ChildPlan(
            robot.child(name), command, options, robot.description(description), journaling(robot), connection
        )

    def robot_service(robot: Robot, service: Service) -> ChildPlan[Any]:
        """``robot``'s ``service`` started before its drive: a motor keeps its state in the run's folder and
        is given ``--rt``, a bridge its namespace and frames, and its bag's journal."""
        command, options_type = BUILT_IN[service]
        planned = child(robot, service, command, options_type(), robot.credentials(access, Role(service)))
        if service == Service.MOTOR:
            state = MotorOptions(state=robot.folder(report_dir) / MOTOR_STATE_FILE)
            return dataclasses.replace(_described(planned, rt=described.rt), options=state)
        if service == Service.ROS2:
            bridge = _described(planned, settings=(*planned.description.settings, *robot.bridge_settings))
            return dataclasses.replace(bridge, options=bag.options) if bag else bridge
        return planned

    if plan.teleop:  # no drive: the sim steps on until Ctrl-C, waiting for each robot's torque only
        waited: tuple[ServiceName, ...] = (Service.MOTOR,)
    else:
        # the motor, and the loop's participants every robot has (a localization without fixes, mode
        # none, holds no ticks token: nothing to wait for)
        participating = [
            {one.service for one in interfaces.participants(Keys(robot.name), robot.config)} for robot in robots.each
        ]
        waited = (Service.MOTOR, *(service for service in OUTPUTS if all(service in p for p in participating)))
        # a user participant's name, where every robot has it (the sim waits for each name on every robot)
        participants: set[UserServiceName] = set.intersection(*(set(robot.participants) for robot in robots.each))
        waited += tuple(sorted(participants))
    simulation = sim_options(
        description, robots.fleet_file, until_drive_ends=not plan.teleop, wait_for=waited, gui=plan.gui
    )
    # the sim's own settings after the common ones: the later value of a key wins
    sim_description = dataclasses.replace(description, settings=(*description.settings, *plan.sim_set), rt=described.rt)
    if plan.sim_set:
        say(
            f"sim-set: the simulated robot differs from the description the other services read: {', '.join(plan.sim_set)}"
        )

    try:
        with (
            launch_services(plan, endpoint, access, robots.assignment(), supervisor) as (launcher, session),
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
                observer = dataclasses.replace(begun.connection, zenoh_config=access.config_file(Role.OBSERVER))
                view_flags = [*connection_flags(observer), *description_flags(description), *robots.view_flags]
                live_view = ViewProcess(view_flags, plan.view)
                closing.callback(live_view.close)
                live_view.wait_serving(run)
            for robot in robots.each:
                for service in robot_services:
                    planned = robot_service(robot, service)
                    if service == Service.MOTOR and control_path_composed:
                        # invent control: the sim and the motor in one child, its sim waiting for the
                        # drive's and the participants' tokens (--wait-for) before its first step; such a
                        # run's services are processes, so the supervisor is its launcher
                        credentials = access.config_file(Role.CONTROL)
                        connection = dataclasses.replace(planned.connection, zenoh_config=credentials)
                        control = dataclasses.replace(planned, journaling=journaling(), connection=connection)
                        supervisor.start_service(ControlPlan(control, simulation, plan.sim_set))
                    else:
                        launcher.start_service(planned)
            for robot in robots.each:  # the user's own (--with), beside them, supervised as they are
                for user in _beside(robot.extensions):
                    credentials = robot.user_credentials(access, user.name)
                    launcher.start_service(child(robot, user.name, hosted(user), UserOptions(user), credentials))
            # Until the sim starts, any service that ends ends the run.
            run.wait_tokens(
                [Keys(robot.name).alive(service) for robot in robots.each for service in robot_services]
                + [Keys(robot.name).alive(user.name) for robot in robots.each for user in _beside(robot.extensions)]
            )
            driven = () if plan.teleop else robots.each
            drives = {}
            for robot in driven:
                credentials = robot.credentials(access, Role.DRIVE)
                driver = drivers[robot.name]
                if driver is not None:  # in the drive's place, with the drive's credentials
                    drives[robot.name] = launcher.start_service(
                        child(robot, driver.name, hosted(driver), UserOptions(driver), credentials)
                    )
                    continue
                drive = child(robot, Service.DRIVE, DRIVE, _drive_options(plan, robot), credentials)
                drives[robot.name] = launcher.start_service(drive)
            for tokens in robots.drive_waits(driven):
                run.wait_tokens(tokens)
            if plan.teleop:
                say(robots.teleop_line)
            if not control_path_composed:
                sim_connection = dataclasses.replace(begun.connection, zenoh_config=access.config_file(Role.SIM))
                sim = ChildPlan(str(Service.SIM), SIM, simulation, sim_description, journaling(), sim_connection)
                launcher.start_service(sim)
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


def _described(child: ChildPlan[Any], **changes: Any) -> ChildPlan[Any]:
    """``child`` with its description changed as ``changes`` say (``settings``, ``rt``)."""
    return dataclasses.replace(child, description=dataclasses.replace(child.description, **changes))


def _drive_options(plan: UpPlan, robot: Robot) -> DriveOptions:
    """What ``robot``'s drive runs: goals (``--goals``), a goal file (``--goal-file``, or a fleet robot's
    own), or its scenario (``--loop``: over and over)."""
    if plan.goal_file is not None:
        return goal_options(plan.goal_file)
    if plan.goals:
        return goal_options()
    if robot.goal_file is not None:
        return goal_options(robot.goal_file)
    return scenario_options(robot.scenario, plan.loop)
