"""What a run of ``invent up`` of one robot does its own way (the sequence is services/launch/up.py's,
the same as a fleet's): its checks before anything starts, its ``--secure`` profile, a watch that
ends the run when any of its services dies, and its flat ``report.json``."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from schemas.keys import Keys, Service, UserServiceName
from schemas.status import ServiceStatus, SimStatus, UserServiceStatus
from schemas.status_kinds import status_type
from services import interfaces
from services.config import Config, ConfigError
from services.drive.goal_file import load_goal_file
from services.drive.outcome import Outcome
from services.drive.scenarios import load_scenario
from services.errors import refuse_given
from services.extension.loader import Loaded, driving, load_all
from services.launch.children import say
from services.launch.plan import UpPlan
from services.launch.robots import Robot
from services.launch.ros2_run import check_ros2_flags
from services.launch.run import RECORDING_FILE, SECRETS_DIRECTORY, Access, Outcomes, Run, secure_listen
from services.recording.report import health_lines, loop_health, summary
from services.recording.run_report import write_run_report
from services.ros2.graph import bridge_graph
from services.security import Role, UserServiceGrant, write_profile
from sim_bridge.display import require_display
from sim_bridge.engine import check_gui
from sim_bridge.world import load_world


def check_before_start(plan: UpPlan, config: Config) -> None:
    """Refuse (ConfigError: exit 2) what a child would refuse once started, before any starts: a
    service that exits 2 would take the others down noisily and leave a run of nothing behind."""
    if plan.gui:
        check_gui(config.sim, plan.gui)
        require_display()
    if plan.workers is not None:
        raise ConfigError("--workers: it spreads a fleet's robots over processes (with --fleet --composed)")
    if plan.view == 0:
        raise ConfigError("--view: the view's port must be fixed (1..65535), for the address to open in Foxglove")
    check_ros2_flags(plan)
    if plan.goal_file is not None:
        load_goal_file(plan.goal_file)
    elif not (plan.teleop or plan.goal_mode):
        load_scenario(plan.scenario)
    load_world(config.sim.world)
    if plan.ros2:
        bridge_graph(config)  # $ROS_DOMAIN_ID


def check_driver(plan: UpPlan, driver: Loaded | None) -> None:
    """Refuse (ConfigError: exit 2) a service that drives beside what gives the robot the built-in drive."""
    if driver is None:
        return
    given = {
        "--scenario": plan.scenario_given,
        "--loop": plan.loop,
        "--goals": plan.goals,
        "--goal-file": plan.goal_file is not None,
        "--teleop": plan.teleop,
    }
    refuse_given(
        given,
        lambda named: (
            f"{driver.spec} drives the robot in the built-in drive's place, and {named} "
            "gives the robot the built-in drive: one velocity source per robot"
        ),
    )


def one_robot_access(plan: UpPlan, config: Config, report_dir: Path, extensions: tuple[Loaded, ...] = ()) -> Access:
    """The run's :class:`Access`; with ``--secure``, the profile is written before anything starts."""
    listen = secure_listen(plan)
    connection = plan.connection
    if listen is None:
        return Access(None, connection.zenoh_config)
    given = {"--composed": plan.composed, "--connect": connection.connect, "--zenoh-config": connection.zenoh_config}
    refuse_given(
        given,
        lambda named: (
            f"--secure with {named}: a secure run starts its own router and runs every "
            "service as a client of it, each with its role's credentials"
        ),
    )
    profile = write_profile(
        report_dir / SECRETS_DIRECTORY,
        Keys(config.robot.name),
        endpoint=listen[0],
        router_listen=listen,
        tls=plan.tls,
        ros=bridge_graph(config),
        # a service that drives connects with the drive's credentials: exactly the drive's rights
        user_services=[
            UserServiceGrant(user.name, user.service.calls, user.service.reads)
            for user in extensions
            if user.service.drives is None
        ],
        localization=config.localization.mode,
    )
    say(
        f"secure: usrpwd and access control on the router{', TLS' if profile.tls else ''}; every service a client; "
        f"credentials for each role in {profile.directory}/ (e.g. --zenoh-config {profile.client_config(Role.OBSERVER)})"
    )
    return Access(profile, None)


class OneRobot:
    """The robot of the run's own flags (:class:`~services.launch.robots.Robots`), checked before anything starts."""

    def __init__(self, plan: UpPlan) -> None:
        self.plan = plan
        self.config = plan.description.load()
        self.extensions = load_all(plan.with_services)
        self.driver = driving(self.extensions)
        """The service of the user's own that drives in the built-in drive's place, if any."""
        check_driver(plan, self.driver)
        check_before_start(plan, self.config)
        if plan.sim_set:
            plan.sim_config()  # the simulated robot's description, refused (exit 2) before anything starts
        runs = plan.drive_runs if self.driver is None else self.driver.name
        self.each: tuple[Robot, ...] = (Robot(self.config.robot.name, self.config, runs, extensions=self.extensions),)
        self.scene: tuple[Config, ...] = ()
        self.records_statuses = True
        self.view_flags: list[str] = []
        self.fleet_file: str | None = None
        self.teleop_line = (
            "teleop: the robot follows ROS 2's /cmd_vel (Twist or TwistStamped) until Ctrl-C; see docs/ros2.md"
        )

    def access(self, report_dir: Path) -> Access:
        return one_robot_access(self.plan, self.config, report_dir, self.extensions)

    def assignment(self) -> None:
        return None

    def drive_waits(self, driven: Sequence[Robot]) -> list[list[str]]:
        """Its drive (or the service that drives in its place) alive, then it and the localization
        holding their lockstep tokens."""
        if not driven:
            return []
        keys, config = Keys(self.config.robot.name), self.config
        drives = None if self.driver is None else self.driver.service.drives
        participants = interfaces.participants(keys, config, None if drives is None else drives.rate_hz)
        return [[keys.alive(Service.DRIVE)], [token for one in participants for token in one.ticks(keys)]]

    def started_line(self, mode: str) -> None:
        return None

    def watch(self, run: Run, drives: dict[str, Any]) -> OneRobotWatch:
        users = [user.name for user in self.extensions if user is not self.driver]
        return OneRobotWatch(run, drives.get(self.config.robot.name), users)

    def health_lines(self, health: dict[str, dict[str, Any]]) -> list[str]:
        return health_lines(health[self.config.robot.name])

    def report(self, report_dir: Path) -> tuple[list[str], str]:
        """``report.json`` and the plots, the report's summary printed."""
        recording = report_dir / RECORDING_FILE
        report, path, plots = write_run_report(recording, report_dir, self.config)
        print(summary(report), flush=True)
        return report["degraded"], f"recording: {recording}; report: {path}; plots: {', '.join(str(p) for p in plots)}"


class OneRobotWatch:
    """The one robot's run watched (:meth:`Run.supervise`): any of its services that dies ends the run."""

    def __init__(self, run: Run, drive: Any | None, user_services: Sequence[UserServiceName] = ()) -> None:
        self.run = run
        self.drive = drive
        self.user_services = user_services
        """The names of its services of the user's own (``--with``)."""
        self.outcome: Outcome | None = None

    def supervise(self, started: float, between_looks: Callable[[], None] | None, until_interrupted: bool) -> None:
        self.outcome = self.run.supervise(self.drive, started, between_looks, until_interrupted=until_interrupted)

    def health(self, robot: str) -> tuple[SimStatus | None, dict[str, Any]]:
        """From the services' status now, the sim's and the drive's last while they ran where they
        do not answer (the drive has exited at its end; a run that ended early, its dead service)."""
        run = self.run
        statuses: dict[str, ServiceStatus | None] = {
            str(service): run.status(service, status_type(service)) for service in Service if service != Service.DRIVE
        }
        statuses[str(Service.DRIVE)] = run.drive_status
        sim_now = statuses[str(Service.SIM)]
        sim_status = sim_now if isinstance(sim_now, SimStatus) else run.sim_status
        users = {
            str(name): run.statuses.get_with_own(run.keys.status(name), UserServiceStatus)
            for name in self.user_services
        }
        for name, user in users.items():
            statuses[name] = None if user is None else user[0]
        health = loop_health(sim_status, statuses)
        if users:
            health["user_services"] = {name: None if user is None else user[1] for name, user in users.items()}
        return sim_status, health

    def outcomes(self, published: Outcomes) -> dict[str, Outcome]:
        return {} if self.outcome is None else {self.run.keys.robot: self.outcome}

    def ended(self, child: str) -> bool:
        """A drive (or the service that drives in its place) that ended with an outcome exited as it
        should, whatever its code."""
        return self.drive is not None and child == self.drive.name and self.outcome is not None
