"""``invent up --fleet FILE``: every robot of a fleet in one world, each with its own services.

Starts the router, then for each robot its motor, odometry and localization (``--robot`` its name,
its overrides and start pose as ``--set``), then each robot's drive with its scenario, waits until
every robot's services are alive and its drive and localization hold their lockstep tokens, and
starts one ``invent sim --fleet FILE`` last: the sim steps when every robot's torque and every
participant's tick output has arrived, so a fleet run repeats bit for bit as a one-robot run does.

A robot whose service dies degrades only its own part of the run: the sim steps on without waiting
for what is gone (a dead motor's robot gets zero torque, a dead drive counts as ended), the other
robots go on, and the report names the robot and the service. The run ends when every robot's
drive has ended its scenario with an outcome (completed, aborted or timed out: each robot has its
own) or lost a service; ``up`` exits 3 if any robot aborted, else 4 if any timed out, else as a
one-robot run; ``run.mcap`` then holds every robot's keys, ``report.json`` each robot's report under
``robots.<name>`` (the one-robot report's fields) and a fleet summary (closest approach between two
robots, their bumps into each other), and ``<report dir>/<robot>/`` its plots.
"""

from __future__ import annotations

import time
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from typing import Any

from schemas.codec import decode
from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, BumpEvent, RunSummary, Time
from services.clock.lockstep import LOOP_BEFORE_FIRST_STEP
from services.config import Config, ConfigError, SimMode
from services.drive.outcome import OUTCOME_OF_EXIT_CODE, Outcome
from services.drive.scenarios import load_scenario
from services.errors import ChildDied, Interrupted
from services.fleet.description import Fleet, FleetRobot, bridge_flags, fleet_configs, load_fleet, robot_flags
from services.fleet.summary import bumps_between, closest_approach
from services.launch.children import say
from services.launch.plan import UpPlan
from services.launch.recorder import RunRecorder
from services.launch.ros2_run import BagRecording, check_ros2_flags, fleet_bridge_graphs, fleet_bridges
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
from services.launch.worker import assign
from services.recording.mcap_files import read_run, robot_report
from services.recording.report import (
    degradation_line,
    degradations,
    loop_health,
    summary,
    write_plots,
    write_report,
)
from services.runtime.inputs import Publisher
from services.security import Role, write_fleet_profile
from services.service import ServiceParse
from sim_bridge.world import load_world

PROGRESS_INTERVAL_S = 1.0
LOOK_INTERVAL_S = 0.05
UNSUPPORTED = {
    "--robot": "the robots are the fleet file's",
    "--loop": "a fleet runs each robot's scenario once",
    "--gui": "the PyBullet window is not offered for a fleet yet",
    "--connect": "a fleet run starts its own router",
}


def check_fleet(plan: UpPlan, path: str) -> tuple[Fleet, dict[str, Config]]:
    """The fleet of the file at ``path`` and each robot's description; ConfigError (exit 2) for
    anything a child would refuse once started, before any starts."""
    given = {
        "--robot": plan.description.robot,
        "--loop": plan.loop,
        "--gui": plan.gui,
        "--connect": plan.connection.connect,
    }
    wrong = [f"{flag} ({UNSUPPORTED[flag]})" for flag, value in given.items() if value]
    if wrong:
        raise ConfigError(f"--fleet with {', '.join(wrong)}")
    if plan.workers is not None and (plan.workers < 1 or not plan.composed):
        raise ConfigError(f"--workers {plan.workers}: a number of processes >= 1, with --composed")
    check_ros2_flags(plan)
    fleet = load_fleet(path)
    description = plan.description
    configs = fleet_configs(fleet, description.config, description.overrides())
    if plan.ros2:
        fleet_bridges(fleet, description.config, description.overrides())
    for robot in fleet.robots if not plan.teleop else ():
        try:
            load_scenario(_scenario(robot, plan))
        except ConfigError as error:
            raise ConfigError(f"fleet robot {robot.name!r}: {error}") from None
    load_world(fleet.world or configs[fleet.robots[0].name].sim.world)
    return fleet, configs


def fleet_access(plan: UpPlan, fleet: Fleet, report_dir: Path) -> Access:
    """The run's :class:`Access`; with ``--secure`` a fresh fleet profile (services/security.py): a
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
    )
    say(f"secure: a user per robot and service, credentials in {profile.directory}/")
    return Access(profile, None)


def role_flags(access: Access, role: Role, robot: str | None = None) -> list[str]:
    """How a service of ``robot`` (None: the fleet-wide sim) connects: its robot's role's file when secure."""
    if access.profile is None:
        return access.flags(role)
    return ["--zenoh-config", str(access.profile.client_config(role, robot))]


def _scenario(robot: FleetRobot, plan: UpPlan) -> str:
    """A robot's scenario: its own, else ``--scenario``."""
    return robot.scenario or plan.scenario


class FleetRun:
    """One fleet run: its launcher, session, and which robot lost which service."""

    def __init__(self, run: Run, fleet: Fleet) -> None:
        self.run = run
        """The run as ``up`` watches one robot's: its launcher, session, queries, start-up waits."""
        self.launcher = run.launcher
        self.fleet = fleet
        self.lost: dict[str, dict[str, str]] = {name: {} for name in fleet.names}
        """Per robot, the services that ended before the run did, and how."""
        self._drives = {f"{name}/{Service.DRIVE}" for name in fleet.names}
        self.drive_statuses: dict[str, dict[str, Any] | None] = dict.fromkeys(fleet.names)
        """Each robot's drive's last status, taken while it runs: it exits at the end of its scenario."""
        self.outcomes: dict[str, Outcome] = {}
        """Each robot whose drive has ended its scenario, and how (its exit code)."""

    def look(self) -> None:
        """Ctrl-C raises Interrupted, a dead router or sim ChildDied; a robot's dead service is noted
        (once) for that robot only, and a drive that ended its scenario (with any outcome) is not dead."""
        if self.run.interrupted.is_set():
            raise Interrupted
        for name, (code, how) in self.launcher.exits().items():
            robot, _, service = name.partition("/")
            if not service:
                raise ChildDied(f"{name} exited unexpectedly ({how})")
            if name in self._drives and code in OUTCOME_OF_EXIT_CODE:
                self.outcomes[robot] = OUTCOME_OF_EXIT_CODE[code]
                continue
            if service in self.lost[robot]:
                continue
            self.lost[robot][service] = how
            say(f"{robot}: {service} ended ({how}): only {robot} degrades, the others go on")

    def ended(self, child: str) -> bool:
        """Whether ``child`` (``robot/service``) ended before the run did: lost, or a drive with an outcome."""
        robot, _, service = child.partition("/")
        return service in self.lost.get(robot, {}) or (child in self._drives and robot in self.outcomes)

    def status(self, keys: Keys, service: Service) -> dict[str, Any] | None:
        return self.run.query(keys.status(service))

    def _over(self) -> bool:
        """Whether every robot is done though the sim is not holding: a robot that lost a service
        cannot finish its scenario (a robot whose motor died never reaches its next waypoint), so
        the run is over once each robot has either ended its scenario or lost a service."""
        if not any(self.lost.values()):
            return False
        for name in self.fleet.names:
            if self.lost[name]:
                continue
            status = self.status(Keys(name), Service.SIM)
            if not (status and status.get("drive_ended")):
                return False
        return True

    def supervise(self, started: float, until_interrupted: bool = False) -> dict[str, Any] | None:
        """Until the sim holds at the last robot's last command (or every robot is done, some having
        lost a service), or, ``until_interrupted`` (``--teleop``: no scenario), until Ctrl-C; progress
        every second. The sim's last status (of the first robot: the world's part is the same for
        every robot)."""
        first = Keys(self.fleet.robots[0].name)
        sim_status: dict[str, Any] | None = None
        next_progress = time.monotonic()
        while True:
            if until_interrupted and self.run.interrupted.is_set():
                return self.status(first, Service.SIM) or sim_status
            self.look()
            if time.monotonic() >= next_progress:
                for name in self.fleet.names:
                    if f"{name}/{Service.DRIVE}" not in self.launcher.exits():
                        self.drive_statuses[name] = self.status(Keys(name), Service.DRIVE) or self.drive_statuses[name]
                sim_status = self.status(first, Service.SIM) or sim_status
                next_progress = time.monotonic() + PROGRESS_INTERVAL_S
                if sim_status:
                    if sim_status.get("state") == "finished" or self._over():
                        return sim_status
                    wall = time.monotonic() - started
                    sim_time = sim_status.get("sim_time_s", 0.0)
                    say(f"sim {sim_time:7.2f} s | {sim_time / wall if wall > 0 else 0:5.2f}x real time")
            time.sleep(LOOK_INTERVAL_S)


def run_fleet(plan: UpPlan, fleet_file: str, parse: ServiceParse) -> int:
    """``invent up --fleet FILE``: services/launch/up.py's :func:`~services.launch.up.run_up` comes here."""
    fleet, configs = check_fleet(plan, fleet_file)
    begun = start(plan, partial(fleet_access, plan, fleet))
    report_dir, access, endpoint, common = begun.report_dir, begun.access, begun.endpoint, begun.common
    first = configs[fleet.robots[0].name]
    mode = SimMode.REALTIME if plan.teleop else plan.mode or first.sim.mode
    robot_services = (*SERVICES_BEFORE_DRIVE, *((Service.ROS2,) if plan.ros2 else ()))
    # each robot's services and drive, the sim, up
    journals = len(fleet.robots) * (len(robot_services) + 1) + 2
    bag = BagRecording(report_dir, first.record, len(fleet.robots), first.ros2.distro) if plan.record_ros2 else None
    recorder = None if plan.no_record or plan.teleop else RunRecorder(report_dir, first.record, journals)
    sim_started = False
    health: dict[str, dict[str, Any]] = {}
    try:
        assignment = assign(fleet.names, plan.workers or 1) if plan.composed else None
        with (
            launch_services(plan, endpoint, parse, access, assignment) as (launcher, session),
            ExitStack() as closing,
        ):
            run = FleetRun(Run(launcher, session, Keys(fleet.names[0]), begun.interrupted), fleet)
            outcomes = Outcomes(session, fleet.names, launcher.bus)
            closing.callback(outcomes.close)
            if plan.view is not None:
                live_view = ViewProcess(
                    [*common, *role_flags(access, Role.OBSERVER), "--robot", fleet.names[0], "--fleet", fleet_file],
                    plan.view,
                )
                closing.callback(live_view.close)
                live_view.wait_serving(run.run)
            publishers = {
                name: Publisher(session, Keys(name).run_summary, recorder.journal if recorder else None)
                for name in fleet.names
            }

            def journal(robot: str) -> list[str]:
                if recorder is None:
                    return []
                directory = recorder.directory / robot
                directory.mkdir(exist_ok=True)
                return ["--journal", str(directory), *recorder.share]

            for robot in fleet.robots:
                state = report_dir / robot.name / MOTOR_STATE_FILE
                own = {
                    Service.MOTOR: ["--state", str(state), *rt_flags(plan)],
                    Service.ROS2: [*bridge_flags(fleet, robot), *(bag.flags if bag else [])],
                }
                for service in robot_services:
                    flags = [*common, *role_flags(access, Role(service), robot.name), *robot_flags(robot)]
                    flags += journal(robot.name)
                    launcher.start(f"{robot.name}/{service}", [str(service), *flags, *own.get(service, [])])
            # Until the sim starts, any service that ends ends the run, as in a one-robot run.
            run.run.wait_tokens([Keys(name).alive(service) for name in fleet.names for service in robot_services])
            driven = () if plan.teleop else fleet.robots
            for robot in driven:
                flags = [*common, *role_flags(access, Role.DRIVE, robot.name), *robot_flags(robot)]
                flags += journal(robot.name)
                launcher.start(f"{robot.name}/drive", ["drive", *flags, "--scenario", _scenario(robot, plan)])
            tokens = []
            for name in (robot.name for robot in driven):
                keys, config = Keys(name), configs[name]
                tokens += [
                    keys.alive(Service.DRIVE),
                    keys.ticks(Service.DRIVE, config.drive.rate),
                    keys.ticks(Service.LOCALIZATION, config.localization.rate),
                ]
            run.run.wait_tokens(tokens)
            wait_for = [str(service) for service in LOOP_BEFORE_FIRST_STEP]
            sim_flags = ["--fleet", fleet_file, "--mode", mode, "--until-drive-ends", "--wait-for", *wait_for]
            if plan.teleop:  # no drive: the sim steps on until Ctrl-C, waiting for each robot's torque only
                sim_flags = ["--fleet", fleet_file, "--mode", mode, "--wait-for", str(Service.MOTOR)]
                say("teleop: each robot follows ROS 2's /<namespace>/cmd_vel until Ctrl-C; see docs/ros2.md")
            sim_flags += rt_flags(plan)
            launcher.start(
                "sim",
                ["sim", *common, *role_flags(access, Role.SIM), *(recorder.flags if recorder else []), *sim_flags],
            )
            sim_started = True
            started = time.monotonic()
            say(f"fleet of {len(fleet.robots)}: {', '.join(fleet.names)}; {mode} mode")
            sim_status = run.supervise(started, until_interrupted=plan.teleop)
            wall_time_s = time.monotonic() - started
            for name in fleet.names:
                keys = Keys(name)
                statuses = {
                    str(service): None if str(service) in run.lost[name] else run.status(keys, service)
                    for service in SERVICES_BEFORE_DRIVE
                }
                statuses[str(Service.DRIVE)] = run.status(keys, Service.DRIVE) or run.drive_statuses[name]
                robot_sim = run.status(keys, Service.SIM) or sim_status
                health[name] = loop_health(robot_sim, statuses)
                health[name]["lost_services"] = dict(run.lost[name])
                if recorder:
                    publishers[name].put(
                        RunSummary(
                            tm=Time.from_nanoseconds(
                                round((robot_sim or {}).get("sim_time_s", 0.0) * NANOSECONDS_PER_SECOND)
                            ),
                            scenario=_scenario(fleet.robot(name), plan),
                            mode=mode,
                            composed=plan.composed,
                            wall_time_s=wall_time_s,
                            steps=int(robot_sim["steps"]) if robot_sim else 0,
                            health=health[name],
                        )
                    )
            for name, published in outcomes.of.items():  # a drive that ended as the sim stopped
                run.outcomes.setdefault(name, Outcome(published.outcome))
            unclean = {name: code for name, code in launcher.stop().items() if code != 0 and not run.ended(name)}
            if unclean:
                say(f"services that did not exit cleanly: {unclean}")
            outcome_lines = [f"{name}: {outcomes.line(name, outcome)}" for name, outcome in run.outcomes.items()]
    except (ChildDied, Interrupted) as error:
        return ended_early(error)
    finally:
        if recorder:
            recorder.finish(sim_started, report_dir / RECORDING_FILE, first, tuple(configs.values()))
        if bag:
            bag.finish(sim_started)
    outcome_code = outcome_exit_code(list(run.outcomes.values()))
    if recorder is None:
        degraded = [f"{name}: {reason}" for name in fleet.names for reason in _degradations(health[name])]
        for line in [*outcome_lines, *map(degradation_line, degraded)]:
            print(line, flush=True)
        why = "--teleop" if plan.teleop else "--no-record"
        return verdict(plan.strict, degraded, f"done; no recording, no report ({why})", outcome_code)
    report = fleet_report(report_dir, fleet, configs)
    for name, robot in report["robots"].items():
        print(f"--- {name} ---\n{summary(robot)}", flush=True)
    print(fleet_summary_line(report["fleet"]), flush=True)
    return verdict(
        plan.strict, report["degraded"], f"recording: {report_dir / RECORDING_FILE}; report: {report_dir}", outcome_code
    )


def _degradations(health: dict[str, Any]) -> list[str]:
    """What degraded a robot's part of the run: its services that ended early, then the loop's health."""
    lost = [f"{service} ended early ({how})" for service, how in health.get("lost_services", {}).items()]
    return [*lost, *degradations(health)]


def fleet_report(report_dir: Path, fleet: Fleet, configs: dict[str, Config]) -> dict[str, Any]:
    """``report.json`` of a fleet run from its ``run.mcap``: each robot's report (and plots in its
    folder), the fleet summary, and what degraded, each reason prefixed with its robot."""
    path = report_dir / RECORDING_FILE
    messages = read_run(path).messages
    robots: dict[str, dict[str, Any]] = {}
    tracks: dict[str, list[tuple[float, float, float]]] = {}
    bumps: dict[str, list[tuple[float, str]]] = {}
    for name in fleet.names:
        report, recording = robot_report(path, messages, configs[name])
        report["degraded"] = _degradations(report["health"])
        robots[name] = report
        (report_dir / name).mkdir(parents=True, exist_ok=True)
        write_plots(recording, report.get("planned_path"), configs[name].geometry, report_dir / name)
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
