"""What ``invent up --fleet FILE`` does its own way: every robot of a fleet in one world, each with
its own services (the sequence is services/launch/up.py's, the same as one robot's).

Each robot's motor, odometry and localization are given ``--robot`` its name, its overrides and
start pose as ``--set``, its drive its own scenario or its goal file (the fleet file's ``goals``);
``up`` waits until every robot's services are alive and its drive and localization hold their
lockstep tokens, and starts one ``invent sim --fleet FILE`` last: the sim steps when every robot's
torque and every participant's tick output has arrived, so a fleet run repeats bit for bit as a
one-robot run does.

A robot whose service dies degrades only its own part of the run (:class:`FleetRun`): the sim steps
on without waiting for what is gone (a dead motor's robot gets zero torque, a dead drive counts as
ended), the other robots go on, and the report names the robot and the service. The run ends when
every robot's drive has ended its scenario with an outcome (completed, aborted or timed out: each
robot has its own; a goal file's drive ends by itself with its last goal's) or lost a service;
``up`` exits 3 if any robot aborted, else 4 if any timed out, else as a one-robot run; ``run.mcap``
then holds every robot's keys, ``report.json`` each robot's report under ``robots.<name>`` (the
one-robot report's fields) and a fleet summary (closest approach between two robots, their bumps
into each other), and ``<report dir>/<robot>/`` its plots (:func:`fleet_report`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from schemas.codec import decode
from schemas.drive_status import DriveStatus
from schemas.keys import Keys, Service, ServiceName, UserServiceName
from schemas.messages import BumpEvent
from schemas.status import ServiceStatus, SimStatus, StatusT, UserServiceStatus
from schemas.status_kinds import status_type
from services import interfaces
from services.config import Config, ConfigError
from services.drive.goal_file import load_goal_file
from services.drive.outcome import OUTCOME_OF_EXIT_CODE, Outcome
from services.drive.scenarios import load_scenario
from services.errors import Interrupted, refuse_given
from services.extension.loader import Loaded, load_all
from services.fleet.description import (
    Fleet,
    FleetRobot,
    bridge_settings,
    fleet_configs,
    load_fleet,
    robot_settings,
)
from services.fleet.summary import bumps_between, closest_approach
from services.launch.children import ServiceDied, say
from services.launch.plan import UpPlan
from services.launch.robots import Robot, robot_degradations
from services.launch.ros2_run import check_ros2_flags, fleet_bridge_graphs, fleet_bridges
from services.launch.run import (
    LOOK_INTERVAL_S,
    PROGRESS_INTERVAL_S,
    RECORDING_FILE,
    SECRETS_DIRECTORY,
    SERVICES_BEFORE_DRIVE,
    Access,
    Outcomes,
    Run,
    secure_listen,
)
from services.launch.worker import assign
from services.recording.mcap_files import read_run
from services.recording.report import loop_health, summary, write_plots, write_report
from services.recording.run_report import robot_report
from services.security import UserServiceGrant, write_fleet_profile
from sim_bridge.world import load_world

UNSUPPORTED = {
    "--robot": "the robots are the fleet file's",
    "--loop": "a fleet runs each robot's scenario once",
    "--gui": "the PyBullet window is not offered for a fleet yet",
    "--connect": "a fleet run starts its own router",
    "--goal-file": "a goal file is one robot's: name each robot's in the fleet file (`goals = FILE`)",
}


def check_fleet(plan: UpPlan, path: str) -> tuple[Fleet, dict[str, Config]]:
    """The fleet of the file at ``path`` and each robot's description; ConfigError (exit 2) for
    anything a child would refuse once started, before any starts."""
    given = {
        "--robot": plan.description.robot,
        "--loop": plan.loop,
        "--gui": plan.gui,
        "--connect": plan.connection.connect,
        "--goal-file": plan.goal_file,
    }
    refuse_given({f"{flag} ({UNSUPPORTED[flag]})": value for flag, value in given.items()}, "--fleet with {}".format)
    if plan.workers is not None and (plan.workers < 1 or not plan.composed):
        raise ConfigError(f"--workers {plan.workers}: a number of processes >= 1, with --composed")
    check_ros2_flags(plan)
    fleet = load_fleet(path)
    description = plan.description
    configs = fleet_configs(fleet, description.config, description.overrides())
    if plan.ros2:
        fleet_bridges(fleet, description.config, description.overrides())
    for robot in fleet.robots if not (plan.teleop or plan.goal_mode) else ():
        try:
            if robot.goals is not None:
                load_goal_file(robot.goals)
            else:
                load_scenario(_scenario(robot, plan))
        except ConfigError as error:
            raise ConfigError(f"fleet robot {robot.name!r}: {error}") from None
    load_world(fleet.world or configs[fleet.robots[0].name].sim.world)
    return fleet, configs


def fleet_access(
    plan: UpPlan,
    fleet: Fleet,
    report_dir: Path,
    extensions: Mapping[str, Sequence[Loaded]] | None = None,
    configs: Mapping[str, Config] | None = None,
) -> Access:
    """The run's :class:`Access`; with ``--secure`` a fresh fleet profile (``write_fleet_profile``): a
    user per robot and service, each allowed only its own robot's keys, written before anything starts."""
    listen = secure_listen(plan)
    if listen is None:
        return Access(None, plan.connection.zenoh_config)
    if plan.composed or plan.connection.zenoh_config:
        raise ConfigError(
            "--secure with --composed or --zenoh-config: a secure fleet starts its own router and runs every "
            "service as a client of it, each with its robot's and role's credentials"
        )
    profile = write_fleet_profile(
        report_dir / SECRETS_DIRECTORY,
        fleet.names,
        endpoint=listen[0],
        router_listen=listen,
        tls=plan.tls,
        bridges=fleet_bridge_graphs(fleet, plan.description.config, plan.description.overrides()),
        user_services={
            robot: [UserServiceGrant(user.name, user.service.calls, user.service.reads) for user in users]
            for robot, users in (extensions or {}).items()
        },
        # each robot's localization granted what its mode reads (only the stub reads a ground truth)
        localization={name: config.localization.mode for name, config in (configs or {}).items()},
    )
    say(f"secure: a user per robot and service, credentials in {profile.directory}/")
    return Access(profile, None)


def _extensions(plan: UpPlan, fleet: Fleet, robot: str) -> tuple[Loaded, ...]:
    """Robot ``robot``'s services of one's own: ``--with`` (every robot's), the fleet file's
    fleet-wide ``with``, then its own; ConfigError naming the robot for a bad one."""
    specs = (*plan.with_services, *fleet.services_of(robot))
    if specs and plan.composed:
        raise ConfigError(
            "--with (or a fleet file's `with`) with --composed: a user service runs as a process of its own"
        )
    try:
        return load_all(specs)
    except ConfigError as error:
        raise ConfigError(f"fleet robot {robot!r}: {error}") from None


def _scenario(robot: FleetRobot, plan: UpPlan) -> str:
    """What a robot's drive runs, as the run's summary names it: its goal file, its scenario, else
    ``--scenario``; in goal mode, goals (the fleet file's scenarios and goal files unused)."""
    if plan.goal_mode:
        return plan.drive_runs
    return robot.goals or robot.scenario or plan.scenario


class FleetRobots:
    """Every robot of a fleet file (:class:`~services.launch.robots.Robots`), each under its name,
    checked before anything starts; one sim for them all."""

    def __init__(self, plan: UpPlan, fleet_file: str) -> None:
        self.plan = plan
        self.fleet, self.configs = check_fleet(plan, fleet_file)
        fleet = self.fleet
        self.extensions = {robot.name: _extensions(plan, fleet, robot.name) for robot in fleet.robots}
        self.each: tuple[Robot, ...] = tuple(
            Robot(
                robot.name,
                self.configs[robot.name],
                _scenario(robot, plan),
                robot_settings(robot),
                bridge_settings(fleet, robot),
                in_fleet=True,
                goal_file=None if plan.goal_mode else robot.goals,
                extensions=self.extensions[robot.name],
            )
            for robot in fleet.robots
        )
        self.scene = tuple(self.configs.values())
        self.records_statuses = False
        self.view_flags = ["--robot", fleet.names[0], "--fleet", fleet_file]
        self.fleet_file: str | None = fleet_file
        self.teleop_line = "teleop: each robot follows ROS 2's /<namespace>/cmd_vel until Ctrl-C; see docs/ros2.md"

    def access(self, report_dir: Path) -> Access:
        return fleet_access(self.plan, self.fleet, report_dir, self.extensions, self.configs)

    def assignment(self) -> dict[str, int] | None:
        return assign(self.fleet.names, self.plan.workers or 1) if self.plan.composed else None

    def drive_waits(self, driven: Sequence[Robot]) -> list[list[str]]:
        """Every driven robot's drive alive and its drive and localization holding their lockstep tokens, at once."""
        tokens = []
        for robot in driven:
            keys = Keys(robot.name)
            tokens.append(keys.alive(Service.DRIVE))
            tokens += [token for one in interfaces.participants(keys, robot.config) for token in one.ticks(keys)]
        return [tokens]

    def started_line(self, mode: str) -> str:
        return f"fleet of {len(self.fleet.robots)}: {', '.join(self.fleet.names)}; {mode} mode"

    def watch(self, run: Run, drives: dict[str, Any]) -> FleetRun:
        return FleetRun(
            run, self.fleet, {name: [user.name for user in users] for name, users in self.extensions.items()}
        )

    def health_lines(self, health: dict[str, dict[str, Any]]) -> list[str]:
        """None: each robot's degradations say what matters."""
        return []

    def report(self, report_dir: Path) -> tuple[list[str], str]:
        """``report.json`` with each robot's report and the fleet summary, each printed."""
        report = fleet_report(report_dir, self.fleet, self.configs)
        for name, robot in report["robots"].items():
            print(f"--- {name} ---\n{summary(robot)}", flush=True)
        print(fleet_summary_line(report["fleet"]), flush=True)
        return report["degraded"], f"recording: {report_dir / RECORDING_FILE}; report: {report_dir}"


class FleetRun:
    """One fleet run: its launcher, session, and which robot lost which service."""

    def __init__(
        self, run: Run, fleet: Fleet, user_services: Mapping[str, Sequence[UserServiceName]] | None = None
    ) -> None:
        self.run = run
        self.user_services = user_services or {}
        """Per robot, the names of its services of one's own."""
        """The run as ``up`` watches one robot's: its launcher, session, queries, start-up waits."""
        self.launcher = run.launcher
        self.fleet = fleet
        self.lost: dict[str, dict[str, str]] = {name: {} for name in fleet.names}
        """Per robot, the services that ended before the run did, and how."""
        self._drives = {f"{name}/{Service.DRIVE}" for name in fleet.names}
        self.drive_statuses: dict[str, DriveStatus | None] = dict.fromkeys(fleet.names)
        """Each robot's drive's last status, taken while it runs: it exits at the end of its scenario."""
        self.outcomes_of: dict[str, Outcome] = {}
        """Each robot whose drive has ended its scenario, and how (its exit code)."""
        self.sim_status: SimStatus | None = None
        """The sim's last status while it ran."""

    def look(self) -> None:
        """Ctrl-C raises Interrupted, a dead router or sim ServiceDied; a robot's dead service is noted
        (once) for that robot only, and a drive that ended its scenario (with any outcome) is not dead."""
        if self.run.interrupted.is_set():
            raise Interrupted
        for name, (code, how) in self.launcher.exits().items():
            robot, _, service = name.partition("/")
            if not service:
                raise ServiceDied(name, code, how)
            if name in self._drives and code in OUTCOME_OF_EXIT_CODE:
                self.outcomes_of[robot] = OUTCOME_OF_EXIT_CODE[code]
                continue
            if service in self.lost[robot]:
                continue
            self.lost[robot][service] = how
            say(f"{robot}: {service} ended ({how}): only {robot} degrades, the others go on")

    def ended(self, child: str) -> bool:
        """Whether ``child`` (``robot/service``) ended before the run did: lost, or a drive with an outcome."""
        robot, _, service = child.partition("/")
        return service in self.lost.get(robot, {}) or (child in self._drives and robot in self.outcomes_of)

    def status(self, keys: Keys, service: ServiceName, status_type: type[StatusT]) -> StatusT | None:
        return self.run.statuses.get(keys.status(service), status_type)

    def _over(self) -> bool:
        """Whether every robot is done though the sim is not holding: a robot that lost a service
        cannot finish its scenario (a robot whose motor died never reaches its next waypoint), so
        the run is over once each robot has either ended its scenario or lost a service."""
        if not any(self.lost.values()):
            return False
        for name in self.fleet.names:
            if self.lost[name]:
                continue
            status = self.status(Keys(name), Service.SIM, SimStatus)
            if status is None or not status.drive_ended:
                return False
        return True

    def supervise(self, started: float, between_looks: Callable[[], None] | None, until_interrupted: bool) -> None:
        """Until the sim holds at the last robot's last command (or every robot is done, some having
        lost a service), or, ``until_interrupted`` (``--teleop``: no scenario), until Ctrl-C; progress
        every second. Keeps the sim's last status (of the first robot: the world's part is the same
        for every robot)."""
        first = Keys(self.fleet.robots[0].name)
        next_progress = time.monotonic()
        while True:
            if until_interrupted and self.run.interrupted.is_set():
                self.sim_status = self.status(first, Service.SIM, SimStatus) or self.sim_status
                return
            self.look()
            if time.monotonic() >= next_progress:
                for name in self.fleet.names:
                    if f"{name}/{Service.DRIVE}" not in self.launcher.exits():
                        drive = self.status(Keys(name), Service.DRIVE, DriveStatus)
                        self.drive_statuses[name] = drive or self.drive_statuses[name]
                self.sim_status = self.status(first, Service.SIM, SimStatus) or self.sim_status
                next_progress = time.monotonic() + PROGRESS_INTERVAL_S
                if self.sim_status is not None:
                    if self.sim_status.state == "finished" or self._over():
                        return
                    wall = time.monotonic() - started
                    sim_time = self.sim_status.sim_time_s
                    say(f"sim {sim_time:7.2f} s | {sim_time / wall if wall > 0 else 0:5.2f}x real time")
            if between_looks:
                between_looks()
            time.sleep(LOOK_INTERVAL_S)

    def health(self, robot: str) -> tuple[SimStatus | None, dict[str, Any]]:
        """``robot``'s own sim status (else the fleet's last) and its health, with the services it lost."""
        keys, lost = Keys(robot), self.lost[robot]
        statuses: dict[str, ServiceStatus | None] = {
            str(service): None if str(service) in lost else self.status(keys, service, status_type(service))
            for service in SERVICES_BEFORE_DRIVE
        }
        statuses[str(Service.DRIVE)] = self.status(keys, Service.DRIVE, DriveStatus) or self.drive_statuses[robot]
        users = {
            str(name): None
            if str(name) in lost
            else self.run.statuses.get_with_own(keys.status(name), UserServiceStatus)
            for name in self.user_services.get(robot, ())
        }
        for name, user in users.items():
            statuses[name] = None if user is None else user[0]
        robot_sim = self.status(keys, Service.SIM, SimStatus) or self.sim_status
        health = loop_health(robot_sim, statuses)
        if users:
            health["user_services"] = {name: None if user is None else user[1] for name, user in users.items()}
        health["lost_services"] = dict(self.lost[robot])
        return robot_sim, health

    def outcomes(self, published: Outcomes) -> dict[str, Outcome]:
        """Each robot's outcome: its drive's exit code, else (a drive that ended as the sim stopped) its sample."""
        for name, sample in published.of.items():
            self.outcomes_of.setdefault(name, Outcome(sample.outcome))
        return self.outcomes_of


def fleet_report(report_dir: Path, fleet: Fleet, configs: dict[str, Config]) -> dict[str, Any]:
    """``report.json`` of a fleet run from its ``run.mcap``: each robot's report (and plots in its
    folder), the fleet summary, and what degraded, each reason prefixed with its robot."""
    path = report_dir / RECORDING_FILE
    read = read_run(path)
    messages = read.messages
    robots: dict[str, dict[str, Any]] = {}
    tracks: dict[str, list[tuple[float, float, float]]] = {}
    bumps: dict[str, list[tuple[float, str]]] = {}
    for name in fleet.names:
        report, recording = robot_report(path, read, configs[name])
        report["degraded"] = robot_degradations(report["health"])
        robots[name] = report
        (report_dir / name).mkdir(parents=True, exist_ok=True)
        write_plots(recording, report.get("planned_path"), configs[name].geometry, report_dir / name, report["goals"])
        tracks[name] = [(t, pose.x, pose.y) for t, pose in recording.ground_truth]
        bump_key = Keys(name).sim_bump
        bumps[name] = [
            (event.tm.to_seconds(), event.obstacle)
            for event in (decode(BumpEvent, m.data) for m in messages if m.topic == bump_key)
        ]
        robots[name]["bumps"] = [{"t_s": t, "obstacle": obstacle} for t, obstacle in bumps[name]]
    report = {
        "fleet": {
            "robots": list(fleet.names),
            "world": fleet.world,
            "closest_approach": closest_approach(tracks),
            "bumps_between_robots": bumps_between(bumps, fleet.names),
        },
        "robots": robots,
        "degraded": [f"{name}: {reason}" for name, robot in robots.items() for reason in robot["degraded"]],
    }
    write_report(report, report_dir)
    return report


def fleet_summary_line(fleet: dict[str, Any]) -> str:
    closest = fleet["closest_approach"]
    approach = (
        f"closest approach {closest['distance_m']:.3f} m ({' and '.join(closest['robots'])}, t = {closest['t_s']:.3f} s)"
        if closest
        else "one robot"
    )
    bumps = fleet["bumps_between_robots"]
    between = "; ".join(f"{b['robot']} bumped {b['other']} at t = {b['t_s']:.3f} s" for b in bumps) or "no bumps"
    return f"fleet: {approach}; {between}"
