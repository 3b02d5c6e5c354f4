"""The pieces of every run of ``invent up`` (its sequence is ``services/launch/up.py``), for one
robot and a fleet alike: where its files go and where its children connect (:class:`Start`), how its sessions are configured (:class:`Access`, :func:`secure_listen`),
how its services are launched (:func:`launch_services`), how it watches them (:class:`Run`), its
live view, and how it ends: each robot's scenario outcome (:class:`Outcomes`) and the run's exit
status (:func:`verdict`)."""

from __future__ import annotations

import datetime
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import zenoh

from schemas.drive_status import DriveStatus
from schemas.keys import Keys, Service, ServiceName
from schemas.messages import ScenarioOutcome
from schemas.status import SimStatus, StatusT, ViewStatus
from services.config import ConfigError
from services.drive.outcome import OUTCOME_OF_EXIT_CODE, Outcome
from services.errors import ChildDied, Interrupted
from services.exits import ExitStatus
from services.extension.hosting import UserOptions
from services.launch.children import Launcher, ServiceDied, Supervisor, describe_exit, say
from services.launch.composition import Composition
from services.launch.plan import Connection, UpPlan
from services.launch.service_plans import ChildPlan
from services.launch.worker import Workers
from services.runtime.discovery import StatusReader
from services.runtime.intraprocess import LocalBus, Watch
from services.runtime.realtime import apply_realtime
from services.runtime.session import DEFAULT_ENDPOINT, ROUTER_LISTENING, open_session, session_config, stop_on_signals
from services.security import Profile, Role

STARTUP_TIMEOUT_S = 60.0
END_TIMEOUT_S = 10.0
"""How long the sim may take to hold at the drive's last command once the drive has ended."""
PROGRESS_INTERVAL_S = 1.0
LOOK_INTERVAL_S = 0.05
"""How often a run looks at its children and the sim's status while it waits."""
SECRETS_DIRECTORY = "secrets"
RECORDING_FILE = "run.mcap"
MOTOR_STATE_FILE = "motor-state.json"
"""The run's own motor state file (latches, gains), in the report directory: a run starts afresh."""
SERVICES_BEFORE_DRIVE = (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION)


def secure_listen(plan: UpPlan) -> list[str] | None:
    """With ``--secure``, where the run's own router listens (its profile's endpoints); None without."""
    if plan.tls and not plan.secure:
        raise ConfigError("--tls: it is an option of --secure (use both)")
    if not plan.secure:
        return None
    return list(plan.connection.listen) or [DEFAULT_ENDPOINT]


@dataclass(frozen=True)
class Start:
    """What a run has settled before it launches anything: where its files go, how its sessions
    are configured, where its services connect (and their log level), and Ctrl-C."""

    report_dir: Path
    access: Access
    endpoint: str
    connection: Connection
    interrupted: threading.Event


def start(plan: UpPlan, access: Callable[[Path], Access]) -> Start:
    """The run's :class:`Start`; ``access`` makes its :class:`Access` for its report directory
    (with ``--secure`` it writes the profile there, before anything starts)."""
    report_dir = plan.report or default_report_dir()
    made = access(report_dir)
    endpoint = run_endpoint(plan, made)
    connection = Connection((endpoint,), log_level=plan.connection.log_level)
    return Start(report_dir, made, endpoint, connection, stop_on_signals())


def ended_early(error: ChildDied | Interrupted) -> int:
    """Say why a run ended before its end (everything is stopped by then) and its exit status."""
    if isinstance(error, Interrupted):
        say("interrupted; stopped everything")
        return ExitStatus.INTERRUPTED
    say(f"{error}; stopped everything")
    return ExitStatus.FAILURE


def early_end(error: ServiceDied | Interrupted) -> dict[str, Any]:
    """The run summary's fields (``RunSummary``) saying why the run ended before its scenario did."""
    if isinstance(error, Interrupted):
        return {"ended_early": "interrupted"}
    return {"ended_early": "service_died", "service": error.service, "exit_code": error.exit_code}


def run_endpoint(plan: UpPlan, access: Access) -> str:
    """Where the run's services connect: its secure router, else ``--connect``, else its own router's ``--listen``."""
    if access.profile:
        return access.profile.endpoint
    return (plan.connection.connect or plan.connection.listen or (DEFAULT_ENDPOINT,))[0]


def default_report_dir() -> Path:
    return Path("runs") / datetime.datetime.now().strftime("%Y%m%d-%H%M%S")


@dataclass(frozen=True)
class Access:
    """How the run's sessions are configured: ``--zenoh-config`` (or zenoh's defaults) for all, or
    with ``--secure`` a fresh profile: the router's file and one client file per role."""

    profile: Profile | None
    zenoh_config: str | None

    def config_file(self, role: Role, robot: str | None = None) -> str | None:
        """The file a service of ``role`` connects with (of ``robot``'s in a secure fleet; None: the
        one robot's, or a fleet's fleet-wide sim), or None for zenoh's defaults."""
        return str(self.profile.client_config(role, robot)) if self.profile else self.zenoh_config

    def user_service_file(self, name: str, robot: str | None = None) -> str | None:
        """The file user service ``name`` (of ``robot``'s, in a secure fleet) connects with: its own
        credentials when secure (services/extension/)."""
        return str(self.profile.user_service_config(name, robot)) if self.profile else self.zenoh_config

    def router_flags(self, endpoint: str) -> list[str]:
        return ["--config", str(self.profile.router_config)] if self.profile else ["--listen", endpoint]


class Beside:
    """A composed run with the user's own services (``--with``) beside it: each a process of its own,
    supervised as in a run of separate processes (the run's restart policy), connected to the
    composed session; the loop's services composed in this process."""

    def __init__(self, composition: Composition, supervisor: Supervisor) -> None:
        self.composition = composition
        self.supervisor = supervisor
        self.bus = composition.bus

    def start_service(self, child: ChildPlan[Any]) -> Any:
        """A service of the user's own as a child process; any other service composed."""
        if isinstance(child.options, UserOptions):
            return self.supervisor.start_service(child)
        return self.composition.start_service(child)

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None:
        return self.composition.exited(exclude) or self.supervisor.exited(exclude)

    def exits(self) -> dict[str, tuple[int, str]]:
        return {**self.composition.exits(), **self.supervisor.exits()}

    def stop(self) -> dict[str, int]:
        """The processes first (they are connected to the composed session), then the composition."""
        codes = self.supervisor.stop()
        return {**codes, **self.composition.stop()}

    def idle(self) -> None:
        self.composition.idle()


@contextmanager
def launch_services(
    plan: UpPlan,
    endpoint: str,
    access: Access,
    assignment: dict[str, int] | None = None,
    supervisor: Supervisor | None = None,
) -> Iterator[tuple[Launcher, zenoh.Session]]:
    """The launcher and the session ``up`` watches through: separate processes around a router
    child (or the router at ``--connect``), ``supervisor``'s (with the run's restart policy), or one
    composed process whose session is itself the router (so outside zenoh tools still see every
    key); a composed fleet's robots spread over worker processes as ``assignment`` says
    (services/launch/worker.py)."""
    connection = plan.connection
    if plan.composed:
        # One process runs the whole loop: it is the control path.
        apply_realtime(plan.description.load().rt, "invent up --composed", control_path=True, composed=True)
        mode_config = (
            session_config(connect=[endpoint], file=access.config_file(Role.OPERATOR), timestamping=plan.ros2)
            if connection.connect
            else session_config(listen=[endpoint], mode="router", timestamping=plan.ros2)
        )
        with open_session(mode_config) as session:
            composition = Composition(session, intra_process=plan.intra_process)
            launcher: Launcher = composition
            if plan.with_services:
                launcher = Beside(composition, supervisor or Supervisor())
            if assignment and max(assignment.values()) > 0:
                worker_flags = ["--connect", endpoint, "--log-level", connection.log_level]
                worker_flags += [] if plan.intra_process else ["--no-intra-process"]
                launcher = Workers(composition, assignment, worker_flags)
            try:
                yield launcher, session
            finally:
                launcher.stop()
        return
    supervisor = supervisor or Supervisor()
    try:
        if not connection.connect:
            settings = plan.description.settings
            rt_settings = [flag for text in settings if text.startswith("rt.") for flag in ("--set", text)]
            router_flags = [
                "router",
                *access.router_flags(endpoint),
                "--log-level",
                connection.log_level,
                *(["--rt"] if plan.description.rt else []),
                *rt_settings,
            ]
            # Nothing connects before the router listens: a router that cannot (its port taken)
            # ends the run at once, saying why, before any service has started.
            supervisor.start("router", router_flags, ready_line=ROUTER_LISTENING).wait_ready(STARTUP_TIMEOUT_S)
        with open_session(session_config(connect=[endpoint], file=access.config_file(Role.OPERATOR))) as session:
            yield supervisor, session
    finally:
        supervisor.stop()


@dataclass
class Run:
    """One ``invent up`` run: the launcher, its session, Ctrl-C, and the sim's and the drive's last
    status while it ran (kept however it ends)."""

    launcher: Launcher
    session: zenoh.Session
    keys: Keys
    interrupted: threading.Event
    sim_status: SimStatus | None = None
    drive_status: DriveStatus | None = None
    """The drive's, taken at every look while it runs: it exits at the end of its scenario."""
    statuses: StatusReader = field(init=False)
    """Its status queries: a bad reply is taken as none, and counted."""

    def __post_init__(self) -> None:
        self.statuses = StatusReader(self.session)

    def check(self, expected_to_finish: str | None = None) -> None:
        """Raise Interrupted on Ctrl-C, ServiceDied when a service other than ``expected_to_finish`` ended."""
        if self.interrupted.is_set():
            raise Interrupted
        exited = self.launcher.exited(exclude=expected_to_finish)
        if exited is not None:
            raise ServiceDied(*exited)

    def wait_alive(self, services: Sequence[Service]) -> None:
        self.wait_tokens([self.keys.alive(service) for service in services])

    def wait_tokens(self, keys: Sequence[str]) -> None:
        """Wait until every liveliness token of ``keys`` is there."""
        alive: set[str] = set()
        subscribers = [
            self.session.liveliness().declare_subscriber(key, lambda s: alive.add(str(s.key_expr)), history=True)
            for key in keys
        ]
        try:
            deadline = time.monotonic() + STARTUP_TIMEOUT_S
            while len(alive) < len(keys):
                self.check()
                self.launcher.idle()
                if time.monotonic() > deadline:
                    missing = sorted(set(keys) - alive)
                    raise ChildDied(f"not there after {STARTUP_TIMEOUT_S} s: {', '.join(missing)}")
                time.sleep(0.02)
        finally:
            for subscriber in subscribers:
                subscriber.undeclare()

    def status(self, service: ServiceName, status_type: type[StatusT]) -> StatusT | None:
        """``service``'s status, or None when it does not answer or its reply does not decode as ``status_type``."""
        return self.statuses.get(self.keys.status(service), status_type)

    def sim_at_end(self, drive: str = str(Service.DRIVE)) -> None:
        """Until the sim holds at the last command of ``drive`` (the drive's child, or the service that
        drives in its place: ``--until-drive-ends``), its status kept."""
        deadline = time.monotonic() + END_TIMEOUT_S
        while time.monotonic() < deadline:
            self.check(expected_to_finish=drive)
            self.sim_status = self.status(Service.SIM, SimStatus) or self.sim_status
            if self.sim_status is not None and self.sim_status.state == "finished":
                return
            time.sleep(0.02)
        say(f"the sim did not stop at the drive's last command within {END_TIMEOUT_S} s")

    def supervise(
        self,
        drive: Any | None,
        started: float,
        between_looks: Callable[[], None] | None,
        until_interrupted: bool = False,
    ) -> Outcome | None:
        """Wait for the drive to end its scenario, with an outcome (its exit code), or, with
        ``until_interrupted``, for Ctrl-C too (a ``--loop`` run ends when the drive gives a pass up,
        a ``--teleop`` run, which has no drive, only on Ctrl-C), printing progress, calling
        ``between_looks`` and keeping the sim's and the drive's last status; return the outcome
        (None: interrupted). ServiceDied or Interrupted when the run ends before that."""
        next_progress = time.monotonic()
        while True:
            if until_interrupted and self.interrupted.is_set():
                self.sim_status = self.status(Service.SIM, SimStatus) or self.sim_status
                self.drive_status = self.status(Service.DRIVE, DriveStatus) or self.drive_status
                return None
            self.check(expected_to_finish=drive.name if drive else None)
            code = drive.finished() if drive else None
            if drive and code is None:
                self.drive_status = self.status(Service.DRIVE, DriveStatus) or self.drive_status
            if time.monotonic() >= next_progress or code is not None:
                self.sim_status = self.status(Service.SIM, SimStatus) or self.sim_status
                next_progress = time.monotonic() + PROGRESS_INTERVAL_S
                if self.sim_status is not None:
                    _progress(self.sim_status, time.monotonic() - started)
            if drive is not None and code in OUTCOME_OF_EXIT_CODE:
                self.sim_at_end(drive.name)
                return OUTCOME_OF_EXIT_CODE[code]
            if drive is not None and code is not None:
                raise ServiceDied(drive.name, code, describe_exit(code))
            if between_looks:
                between_looks()
            time.sleep(LOOK_INTERVAL_S)


class Outcomes:
    """Each robot's scenario outcome as its drive publishes it on ``drive/outcome`` with its last
    command (the reason; the drive's exit code says the outcome even if this sample is lost): from
    zenoh, and from the ``bus`` of the services composed in this process (their messages do not
    come back through its own session)."""

    def __init__(self, session: zenoh.Session, robots: Sequence[str], bus: LocalBus | None = None) -> None:
        self.of: dict[str, ScenarioOutcome] = {}
        self._watches = [
            Watch(session, Keys(robot).drive_outcome, ScenarioOutcome, partial(self.of.__setitem__, robot), bus)
            for robot in robots
        ]

    def line(self, robot: str, outcome: Outcome) -> str:
        """``outcome: aborted (bumped into 'box' ...)``, the reason when the drive's sample came."""
        published = self.of.get(robot)
        reason = published.reason if published is not None and published.outcome == outcome else ""
        return f"outcome: {outcome}" + (f" ({reason})" if reason else "")

    def close(self) -> None:
        for watch in self._watches:
            watch.close()


def outcome_exit_code(outcomes: Sequence[Outcome | None]) -> int:
    """The run's exit code from its robots' outcomes: aborted if any robot aborted, else timed out
    if any timed out, else canceled if any ended so (a goal file's last goal), else 0 (every robot
    completed; an interrupted robot, or one of a ``--goals`` run, has None)."""
    for worst in (Outcome.ABORTED, Outcome.TIMED_OUT, Outcome.CANCELED):
        if worst in outcomes:
            return worst.exit_code
    return ExitStatus.OK


class ViewProcess:
    """``invent view`` as a child (``up --view``): the run live in Foxglove. Another process in
    both modes: a view is for watching, so it may cost the loop zenoh's delivery of every sample."""

    def __init__(self, flags: list[str], port: int) -> None:
        self._children = Supervisor()
        self._port = port
        self._child = self._children.start("view", ["view", *flags, "--port", str(port)])

    def wait_serving(self, run: Run) -> None:
        """Until the view answers on ``view/status``, which it serves once its WebSocket server
        listens, so the address printed works at once. (Opening a connection to the port instead
        would be a client that never speaks, whose failed handshake the server logs as an error.)"""
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while (status := run.statuses.get(run.keys.view_status, ViewStatus)) is None:
            run.check()
            self._child.check_running()
            if time.monotonic() > deadline:
                raise ChildDied(f"the view did not serve on port {self._port} within {STARTUP_TIMEOUT_S} s")
            time.sleep(LOOK_INTERVAL_S)
        say(f"Foxglove live view: {status.url} (Foxglove → Open connection)")

    def close(self) -> None:
        code = self._children.stop()["view"]
        if code != 0:
            say(f"view did not exit cleanly ({describe_exit(code)})")


def verdict(
    strict: bool,
    degraded: list[str],
    done: str,
    outcome_code: int = 0,
    not_completed: str = "the scenario was given up",
) -> int:
    """Say what was written; a scenario given up (a goal file's last goal not completed: say so in
    ``not_completed``) exits with its outcome's code, else under ``--strict`` a degraded run exits 1."""
    say(done)
    if outcome_code:
        say(f"{not_completed}: exit {outcome_code}")
        return outcome_code
    if degraded and strict:
        status = ExitStatus.FAILURE
        say(f"--strict: the run degraded ({len(degraded)} reason{'s' * (len(degraded) > 1)}): exit {status}")
        return status
    return ExitStatus.OK


def _progress(sim_status: SimStatus, wall_s: float) -> None:
    sim_time, pose = sim_status.sim_time_s, sim_status.pose
    say(
        f"sim {sim_time:7.2f} s | {sim_time / wall_s if wall_s > 0 else 0:5.2f}x real time | "
        f"pose x {pose.x:+.3f} y {pose.y:+.3f} theta {pose.theta:+.3f}"
    )
