"""``invent up``: the whole closed loop, each service in its own process, and a run report.

Starts the router, then motor, odometry, localization and the drive with the scenario, waits
until they are alive and the drive and the localization hold their lockstep tokens, and
starts the sim last, so a lockstep run steps the whole loop from its first step and starts the
same way every time (services/clock/lockstep.py). Children's output is prefixed with their name. The
run ends when the drive finishes its scenario (exit 0) and the sim holds at the step of its
last command (``--until-drive-ends``): ``up`` then reads the services' status, publishes the
run's summary (``up/run``), stops every child with SIGINT, makes ``run.mcap`` of what they
published (:class:`RunRecorder`) and builds the report from it, as ``invent report run.mcap``
does (``--no-record``: no recording, no report, for long runs and benchmarks). A child that dies
early makes ``up`` say which one, stop the others and exit 1. Ctrl-C stops everything cleanly
(exit 130). Either way ``run.mcap`` holds the run up to then. With ``--composed`` the same
services run in this one process instead (``services/cli/composition.py``).
"""

from __future__ import annotations

import argparse
import ctypes
import datetime
import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import zenoh

from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, RunSummary, Time
from services.cli.composition import Composition
from services.clock.lockstep import LOOP_BEFORE_FIRST_STEP
from services.config import Config, ConfigError, SimMode
from services.drive.scenarios import load_scenario
from services.recording import view
from services.recording.mcap_files import write_run_report
from services.recording.record import StatusPoll, write_run_recording
from services.recording.report import degradation_line, degradations, health_lines, loop_health, summary
from services.ros2.graph import bridge_graph
from services.runtime.inputs import Publisher
from services.runtime.journal import Journal, journal_path
from services.runtime.session import DEFAULT_ENDPOINT, open_session, session_config, stop_on_signals
from services.security import Profile, Role, write_profile
from services.service import port_number
from sim_bridge.display import require_display
from sim_bridge.world import load_world

EXIT_CHILD_DIED = 1
EXIT_DEGRADED = 1
EXIT_INTERRUPTED = 130
STARTUP_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0
PROGRESS_INTERVAL_S = 1.0
SECRETS_DIRECTORY = "secrets"
RECORDING_FILE = "run.mcap"
JOURNALS_DIRECTORY = "journals"
"""Where the services keep what they publish while the run lasts (made into ``run.mcap`` at its end)."""
MOTOR_STATE_FILE = "motor-state.json"
"""The run's own motor state file (latches, gains), in the report directory: a run starts afresh."""
SERVICES_BEFORE_DRIVE = (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION)
TELEOP = "teleop"
"""The scenario name of a ``--teleop`` run (ROS 2 drives it)."""

_PR_SET_PDEATHSIG = 1
NAME_WIDTH = max(len(str(service)) for service in Service)


def say(text: str) -> None:
    print(f"[{'up':<{NAME_WIDTH}}] {text}", flush=True)


def _die_with_parent() -> None:
    """Runs in the child before exec: SIGTERM it if ``invent up`` itself dies (Linux)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


class ChildDied(RuntimeError):
    pass


class Interrupted(RuntimeError):
    pass


@dataclass
class Child:
    name: str
    process: subprocess.Popen[str]
    pump: threading.Thread

    def finished(self) -> int | None:
        return self.process.poll()

    def check_running(self, unless_exit_code: int | None = None) -> None:
        """Raise ChildDied if it has ended (with any exit code other than ``unless_exit_code``)."""
        code = self.finished()
        if code is not None and code != unless_exit_code:
            raise ChildDied(f"{self.name} exited unexpectedly ({_describe_exit(code)})")


class Supervisor:
    """The children of one ``invent up`` run, their prefixed output, and their orderly stop."""

    def __init__(self) -> None:
        self.children: list[Child] = []

    def start(self, name: str, argv: Sequence[str]) -> Child:
        process = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            # prctl only, no Python objects: the hazard of preexec_fn with threads does not arise.
            preexec_fn=_die_with_parent if sys.platform == "linux" else None,  # noqa: PLW1509
        )
        pump = threading.Thread(target=self._pump, args=(name, process), daemon=True)
        pump.start()
        child = Child(name, process, pump)
        self.children.append(child)
        say(f"started {name} (pid {process.pid}): invent {' '.join(argv)}")
        return child

    def _pump(self, name: str, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            sys.stdout.write(f"[{name:<{NAME_WIDTH}}] {line}")
            sys.stdout.flush()

    def exited(self, exclude: str | None = None) -> tuple[str, str] | None:
        """(name, reason) of a child other than ``exclude`` that has exited, or None."""
        for child in self.children:
            code = child.process.poll()
            if child.name != exclude and code is not None:
                return child.name, _describe_exit(code)
        return None

    def exits(self) -> dict[str, tuple[int, str]]:
        """Every child that has exited: its (exit code, how it ended), by name."""
        return {
            child.name: (code, _describe_exit(code))
            for child in self.children
            if (code := child.process.poll()) is not None
        }

    def stop(self) -> dict[str, int]:
        """SIGINT every child, newest first; kill what does not stop in time. Returns exit codes."""
        for child in reversed(self.children):
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGINT)
                try:
                    child.process.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    say(f"{child.name} did not stop within {STOP_TIMEOUT_S} s; killing it")
                    child.process.kill()
                    child.process.wait()
            child.pump.join(timeout=2.0)
        return {child.name: child.process.returncode for child in self.children}

    def idle(self) -> None:
        """Each child has its own thread."""


def _describe_exit(code: int) -> str:
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


class Launcher(Protocol):
    """How ``up`` runs services: as processes (:class:`Supervisor`) or composed in this process."""

    def start(self, name: str, argv: Sequence[str]) -> Any: ...

    def exited(self, exclude: str | None = None) -> tuple[str, str] | None: ...

    def exits(self) -> dict[str, tuple[int, str]]: ...

    def stop(self) -> dict[str, int]: ...

    def idle(self) -> None:
        """Called while ``up`` waits for the services to start: let them handle their events."""


@dataclass
class Run:
    """One ``invent up`` run: the launcher, its session, and Ctrl-C."""

    launcher: Launcher
    session: zenoh.Session
    keys: Keys
    interrupted: threading.Event

    def check(self, expected_to_finish: str | None = None) -> None:
        """Raise Interrupted on Ctrl-C, ChildDied when a service other than ``expected_to_finish`` ended."""
        if self.interrupted.is_set():
            raise Interrupted
        exited = self.launcher.exited(exclude=expected_to_finish)
        if exited is not None:
            raise ChildDied(f"{exited[0]} exited unexpectedly ({exited[1]})")

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

    def status(self, service: Service) -> dict[str, Any] | None:
        return self.query(self.keys.status(service))

    def query(self, key: str) -> dict[str, Any] | None:
        """The first JSON reply to a query on ``key`` (a status), or None when nothing answers."""
        for reply in self.session.get(key, timeout=2.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def sim_at_end(self, sim_status: dict[str, Any] | None) -> dict[str, Any] | None:
        """The sim's status once it holds at the drive's last command (``--until-drive-ends``)."""
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while time.monotonic() < deadline:
            self.check(expected_to_finish=str(Service.DRIVE))
            sim_status = self.status(Service.SIM) or sim_status
            if sim_status and sim_status.get("state") == "finished":
                return sim_status
            time.sleep(0.02)
        say(f"the sim did not stop at the drive's last command within {STOP_TIMEOUT_S} s")
        return sim_status

    def supervise(
        self,
        drive: Any | None,
        started: float,
        between_looks: Callable[[], None] | None,
        until_interrupted: bool = False,
    ) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
        """Wait for the drive to finish its scenario (or, ``until_interrupted``, for Ctrl-C: the end
        of a ``--loop`` or ``--teleop`` run, which has no drive), printing progress and calling
        ``between_looks``; return the sim's last status and the drive's (taken at every look while it
        runs: it exits at the end)."""
        sim_status: dict[str, Any] | None = None
        drive_status: dict[str, Any] | None = None
        next_progress = time.monotonic()
        while True:
            if until_interrupted and self.interrupted.is_set():
                return self.status(Service.SIM) or sim_status, self.status(Service.DRIVE) or drive_status
            self.check(expected_to_finish=drive.name if drive else None)
            code = drive.finished() if drive else None
            if drive and code is None:
                drive_status = self.status(Service.DRIVE) or drive_status
            if time.monotonic() >= next_progress or code is not None:
                sim_status = self.status(Service.SIM) or sim_status
                next_progress = time.monotonic() + PROGRESS_INTERVAL_S
                if sim_status:
                    _progress(sim_status, time.monotonic() - started)
            if code == 0:
                return self.sim_at_end(sim_status), drive_status
            if code is not None:
                raise ChildDied(f"drive exited unexpectedly ({_describe_exit(code)})")
            if between_looks:
                between_looks()
            time.sleep(0.05)


class RunRecorder:
    """The run's recording, made where the samples already are (services/recording/record.py): each service
    keeps what it publishes in a journal in ``<report dir>/journals/``, and this, in ``up``'s own
    journal, the services' status replies and the run's summary. :meth:`write` makes ``run.mcap``
    of them once every service has stopped (and closed its journal)."""

    def __init__(self, report_dir: Path) -> None:
        self.directory = report_dir / JOURNALS_DIRECTORY
        self._made = [
            directory for directory in (self.directory, report_dir, *report_dir.parents) if not directory.exists()
        ]
        """The directories this run makes, deepest first: a run that never starts removes them again."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.journal = Journal(journal_path(self.directory, "up"))
        except OSError as error:
            raise ConfigError(f"--report {report_dir}: {error.strerror}") from None
        self.flags = ["--journal", str(self.directory)]
        """What a service needs to keep its journal here."""
        self._statuses: StatusPoll | None = None

    def watch(self, session: zenoh.Session, keys: Keys) -> None:
        """Record the services' status from now on, at each :meth:`during`."""
        self._statuses = StatusPoll(session, keys, self.journal.write)

    def during(self) -> None:
        if self._statuses is not None:
            self._statuses.poll()

    def write(self, path: Path, config: Config, fleet: Sequence[Config] = ()) -> None:
        """``run.mcap`` with the scene of ``config``'s robot, or of every robot of ``fleet``."""
        self._statuses = None
        self.journal.close()
        say(f"writing {path} from what the services published")
        for journal in write_run_recording(self.directory, path, config, fleet):
            say(f"{journal.name} was cut short (its service was killed): {path} lacks its last samples")
        shutil.rmtree(self.directory)

    def finish(self, started: bool, path: Path, config: Config, fleet: Sequence[Config] = ()) -> None:
        """At the run's end, however it ended: ``run.mcap`` of what was published (:meth:`write`),
        or, for a run that never started (the sim did not), nothing left behind (:meth:`discard`)."""
        if started:
            self.write(path, config, fleet)
        else:
            self.discard()
            say("the run never started (the sim did not): nothing recorded")

    def discard(self) -> None:
        """A run that never started (the sim never did): no recording of nothing, and the
        directories this run made are removed unless something else was put in them."""
        self._statuses = None
        self.journal.close()
        shutil.rmtree(self.directory)
        for directory in self._made[1:]:
            try:
                directory.rmdir()
            except OSError:  # not empty: the run's secrets, or someone else's files
                break


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
        while (status := run.query(run.keys.view_status)) is None:
            run.check()
            self._child.check_running()
            if time.monotonic() > deadline:
                raise ChildDied(f"the view did not serve on port {self._port} within {STARTUP_TIMEOUT_S} s")
            time.sleep(0.05)
        say(f"Foxglove live view: {status['url']} (Foxglove → Open connection)")

    def close(self) -> None:
        code = self._children.stop()["view"]
        if code != 0:
            say(f"view did not exit cleanly ({_describe_exit(code)})")


def _child_args(args: argparse.Namespace, endpoint: str) -> list[str]:
    common = ["--connect", endpoint, "--log-level", args.log_level]
    if args.robot:
        common += ["--robot", args.robot]
    if args.config:
        common += ["--config", args.config]
    for override in args.set or ():
        common += ["--set", override]
    return common


def default_report_dir() -> Path:
    return Path("runs") / datetime.datetime.now().strftime("%Y%m%d-%H%M%S")


@contextmanager
def launch_services(
    args: argparse.Namespace, endpoint: str, parser: argparse.ArgumentParser, access: Access
) -> Iterator[tuple[Launcher, zenoh.Session]]:
    """The launcher and the session ``up`` watches through: separate processes around a router
    child (or the router at ``--connect``), or one composed process whose session is itself the
    router (so outside zenoh tools still see every key)."""
    if args.composed:
        mode_config = (
            session_config(connect=[endpoint], file=access.config_file(Role.OPERATOR), timestamping=args.ros2)
            if args.connect
            else session_config(listen=[endpoint], mode="router", timestamping=args.ros2)
        )
        with open_session(mode_config) as session:
            composition = Composition(session, parser)
            try:
                yield composition, session
            finally:
                composition.stop()
        return
    supervisor = Supervisor()
    try:
        if not args.connect:
            supervisor.start("router", ["router", *access.router_flags(endpoint), "--log-level", args.log_level])
        with open_session(session_config(connect=[endpoint], file=access.config_file(Role.OPERATOR))) as session:
            yield supervisor, session
    finally:
        supervisor.stop()


@dataclass(frozen=True)
class Access:
    """How the run's sessions are configured: ``--zenoh-config`` (or zenoh's defaults) for all, or
    with ``--secure`` a fresh profile: the router's file and one client file per role."""

    profile: Profile | None
    zenoh_config: str | None

    def config_file(self, role: Role) -> str | None:
        return str(self.profile.client_config(role)) if self.profile else self.zenoh_config

    def flags(self, role: Role) -> list[str]:
        path = self.config_file(role)
        return ["--zenoh-config", path] if path else []

    def router_flags(self, endpoint: str) -> list[str]:
        return ["--config", str(self.profile.router_config)] if self.profile else ["--listen", endpoint]


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
    if args.view == 0:
        raise ConfigError("--view: the view's port must be fixed (1..65535), for the address to open in Foxglove")
    if args.teleop:
        given = {"--ros2": not args.ros2, "--mode lockstep": args.mode == SimMode.LOCKSTEP, "--loop": args.loop}
        wrong = [flag for flag, conflicting in given.items() if conflicting]
        if wrong:
            raise ConfigError(
                f"--teleop ({', '.join(wrong)}): it runs the loop in realtime with no scenario, the robot following "
                "ROS 2's /cmd_vel through the bridge, so it needs --ros2 and takes neither --mode lockstep nor --loop"
            )
    else:
        load_scenario(args.scenario)
    load_world(config.sim.world)
    if args.ros2:
        bridge_graph(config)  # $ROS_DOMAIN_ID


def run_up(args: argparse.Namespace, config: Config, parser: argparse.ArgumentParser) -> int:
    if args.fleet:
        from services.fleet.launch import run_fleet  # it builds on this module

        return run_fleet(args, parser)
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
    recorder = RunRecorder(report_dir) if recording else None
    journal_flags = recorder.flags if recorder else []
    sim_started = False
    try:
        with launch_services(args, endpoint, parser, access) as (launcher, session), ExitStack() as closing:
            run = Run(launcher, session, keys, interrupted)
            summary_publisher = Publisher(session, keys.run_summary, recorder.journal if recorder else None)
            if recorder:
                recorder.watch(session, keys)
            if args.view is not None:
                live_view = ViewProcess([*common, *access.flags(Role.OBSERVER)], args.view)
                closing.callback(live_view.close)
                live_view.wait_serving(run)
            own_flags = {Service.MOTOR: ["--state", str(report_dir / MOTOR_STATE_FILE)]}
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
            sim_flags += ["--gui"] if args.gui else []
            if args.teleop:
                say("teleop: the robot follows ROS 2's /cmd_vel (Twist or TwistStamped) until Ctrl-C; see docs/ros2.md")
            launcher.start("sim", ["sim", *common, *access.flags(Role.SIM), *journal_flags, *sim_flags])
            sim_started = True
            started = time.monotonic()
            sim_status, drive_status = run.supervise(
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
            unclean = {name: code for name, code in launcher.stop().items() if code != 0}
            if unclean:
                say(f"services that did not exit cleanly: {unclean}")
    except ChildDied as error:
        say(f"{error}; stopped everything")
        return EXIT_CHILD_DIED
    except Interrupted:
        say("interrupted; stopped everything")
        return EXIT_INTERRUPTED
    finally:
        if recorder:
            recorder.finish(sim_started, report_dir / RECORDING_FILE, config)
    if not recorder:
        degraded = degradations(health)
        print("\n".join([*health_lines(health), *map(degradation_line, degraded)]), flush=True)
        return verdict(
            args,
            degraded,
            "done; no recording, no report ("
            + ("--teleop" if args.teleop else "--loop" if args.loop else "--no-record")
            + ")",
        )
    report, path, plots = write_run_report(report_dir / RECORDING_FILE, report_dir, config)
    print(summary(report), flush=True)
    return verdict(
        args,
        report["degraded"],
        f"recording: {report_dir / RECORDING_FILE}; report: {path}; plots: {', '.join(str(p) for p in plots)}",
    )


def verdict(args: argparse.Namespace, degraded: list[str], done: str) -> int:
    """Say what was written; under ``--strict`` a degraded run exits 1."""
    say(done)
    if degraded and args.strict:
        say(f"--strict: the run degraded ({len(degraded)} reason{'s' * (len(degraded) > 1)}): exit {EXIT_DEGRADED}")
        return EXIT_DEGRADED
    return 0


def _progress(sim_status: dict[str, Any], wall_s: float) -> None:
    sim_time = sim_status.get("sim_time_s", 0.0)
    pose = sim_status.get("pose") or {}
    say(
        f"sim {sim_time:7.2f} s | {sim_time / wall_s if wall_s > 0 else 0:5.2f}x real time | "
        f"pose x {pose.get('x', 0.0):+.3f} y {pose.get('y', 0.0):+.3f} theta {pose.get('theta', 0.0):+.3f}"
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
        help="repeat the scenario until Ctrl-C (a long-running stack to watch and probe); records nothing, so "
        "memory stays flat, and prints the run's health at the end",
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
        "/joint_states, /clock, /robot_description, /cmd_vel, the motor's Trigger services; docs/ros2.md)",
    )
    parser.add_argument(
        "--teleop",
        action="store_true",
        help="with --ros2: no scenario; the loop runs in realtime, the robot following /cmd_vel from ROS 2 "
        "(teleop_twist_keyboard, Nav2) until Ctrl-C; records nothing, prints the run's health at the end",
    )
    parser.add_argument(
        "--composed",
        action="store_true",
        help="run the services in this one process on one zenoh session (no network hop between them; "
        "the session is the router, so outside zenoh tools still see every key)",
    )
