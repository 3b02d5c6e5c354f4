"""``invent up``: the whole closed loop, each service in its own process, and a run report.

Starts the router, then motor, odometry and localization, waits until they are alive, starts
the sim (so lockstep waits for the motor from the first step) and finally the drive with the
scenario. Children's output is prefixed with their name. The run ends when the drive finishes
its scenario (exit 0): ``up`` then records the services' status, stops every child with
SIGINT and writes the report. A child that dies early makes ``up`` say which one, stop the
others and exit 1. Ctrl-C stops everything cleanly (exit 130).
"""

from __future__ import annotations

import argparse
import ctypes
import datetime
import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from schemas.keys import Keys, Service
from services.config import Config
from services.recording import Recorder
from services.report import build_report, summary, write_plots, write_report
from services.runtime import DEFAULT_ENDPOINT, open_session, session_config

EXIT_CHILD_DIED = 1
EXIT_INTERRUPTED = 130
STARTUP_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0
PROGRESS_INTERVAL_S = 1.0
SERVICES_BEFORE_SIM = (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION)

_PR_SET_PDEATHSIG = 1


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


class Supervisor:
    """The children of one ``invent up`` run, their prefixed output, and their orderly stop."""

    def __init__(self) -> None:
        self.children: list[Child] = []
        self.interrupted = threading.Event()
        self._width = max(len(str(service)) for service in Service)

    def start(self, name: str, argv: Sequence[str]) -> Child:
        process = subprocess.Popen(
            [sys.executable, "-m", "services.cli", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            preexec_fn=_die_with_parent if sys.platform == "linux" else None,
        )
        pump = threading.Thread(target=self._pump, args=(name, process), daemon=True)
        pump.start()
        child = Child(name, process, pump)
        self.children.append(child)
        self.say(f"started {name} (pid {process.pid}): invent {' '.join(argv)}")
        return child

    def say(self, text: str) -> None:
        print(f"[{'up':<{self._width}}] {text}", flush=True)

    def _pump(self, name: str, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            sys.stdout.write(f"[{name:<{self._width}}] {line}")
            sys.stdout.flush()

    def first_exited(self) -> Child | None:
        return next((child for child in self.children if child.process.poll() is not None), None)

    def check(self, expected_to_finish: str | None = None) -> None:
        """Raise Interrupted on Ctrl-C, ChildDied when a child other than ``expected_to_finish`` has exited."""
        if self.interrupted.is_set():
            raise Interrupted
        for child in self.children:
            if child.name != expected_to_finish and child.process.poll() is not None:
                raise ChildDied(f"{child.name} exited unexpectedly ({_describe_exit(child.process.returncode)})")

    def stop(self) -> dict[str, int]:
        """SIGINT every child, newest first; kill what does not stop in time. Returns exit codes."""
        for child in reversed(self.children):
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGINT)
                try:
                    child.process.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    self.say(f"{child.name} did not stop within {STOP_TIMEOUT_S} s; killing it")
                    child.process.kill()
                    child.process.wait()
            child.pump.join(timeout=2.0)
        return {child.name: child.process.returncode for child in self.children}


def _describe_exit(code: int) -> str:
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


def _wait_alive(session: zenoh.Session, keys: Keys, services: Sequence[Service], supervisor: Supervisor) -> None:
    alive: set[str] = set()
    subscribers = [
        session.liveliness().declare_subscriber(keys.alive(service), lambda s: alive.add(str(s.key_expr)), history=True)
        for service in services
    ]
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while len(alive) < len(services):
            supervisor.check()
            if time.monotonic() > deadline:
                missing = sorted(set(map(keys.alive, services)) - alive)
                raise ChildDied(f"not alive after {STARTUP_TIMEOUT_S} s: {', '.join(missing)}")
            time.sleep(0.02)
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()


def _status(session: zenoh.Session, keys: Keys, service: Service) -> dict[str, Any] | None:
    for reply in session.get(keys.status(service), timeout=2.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


def _child_args(args: argparse.Namespace, endpoint: str) -> list[str]:
    common = ["--connect", endpoint, "--log-level", args.log_level]
    if args.robot:
        common += ["--robot", args.robot]
    if args.config:
        common += ["--config", args.config]
    for override in args.set or ():
        common += ["--set", override]
    return common


def _default_report_dir() -> Path:
    return Path("runs") / datetime.datetime.now().strftime("%Y%m%d-%H%M%S")


def run_up(args: argparse.Namespace, config: Config) -> int:
    from services.scenarios import planned_path_for

    keys = Keys(config.robot.name)
    endpoint = (args.connect or args.listen or [DEFAULT_ENDPOINT])[0]
    common = _child_args(args, endpoint)
    report_dir = Path(args.report) if args.report else _default_report_dir()
    mode = args.mode or config.sim.mode
    supervisor = Supervisor()
    signal.signal(signal.SIGINT, lambda *_: supervisor.interrupted.set())
    signal.signal(signal.SIGTERM, lambda *_: supervisor.interrupted.set())
    outcome = 0
    try:
        if not args.connect:
            supervisor.start("router", ["router", "--listen", endpoint, "--log-level", args.log_level])
        with open_session(session_config(connect=[endpoint])) as session:
            recorder = Recorder(session, keys, config.robot)
            for service in SERVICES_BEFORE_SIM:
                supervisor.start(str(service), [str(service), *common])
            _wait_alive(session, keys, SERVICES_BEFORE_SIM, supervisor)
            sim_flags = ["--mode", mode] + (["--gui"] if args.gui else [])
            supervisor.start("sim", ["sim", *common, *sim_flags])
            _wait_alive(session, keys, (Service.SIM,), supervisor)
            started = time.monotonic()
            drive = supervisor.start("drive", ["drive", *common, "--scenario", args.scenario])
            sim_status = _supervise(session, keys, supervisor, drive, started)
            wall_time_s = time.monotonic() - started
            statuses = {str(service): _status(session, keys, service) for service in Service if service != Service.DRIVE}
            recorder.close()
        exit_codes = supervisor.stop()
        unclean = {name: code for name, code in exit_codes.items() if code != 0}
        if unclean:
            supervisor.say(f"children that did not exit cleanly: {unclean}")
        recording = recorder.recording(until=sim_status.get("sim_time_s") if sim_status else None)
        report = build_report(
            recording,
            scenario=args.scenario,
            mode=mode,
            planned_path=planned_path_for(args.scenario, recording.ground_truth[0][1] if recording.ground_truth else None),
            wall_time_s=wall_time_s,
            steps=int(sim_status["steps"]) if sim_status else 0,
            bad_inputs={name: status["bad_input"]["total"] for name, status in statuses.items() if status},
        )
        path = write_report(report, report_dir)
        plots = write_plots(recording, report.get("planned_path"), config.robot, report_dir)
        print(summary(report), flush=True)
        supervisor.say(f"report: {path}; plots: {', '.join(str(p) for p in plots)}")
    except ChildDied as error:
        supervisor.say(f"{error}; stopping everything")
        outcome = EXIT_CHILD_DIED
    except Interrupted:
        supervisor.say("interrupted; stopping everything")
        outcome = EXIT_INTERRUPTED
    finally:
        supervisor.stop()
    return outcome


def _supervise(
    session: zenoh.Session,
    keys: Keys,
    supervisor: Supervisor,
    drive: Child,
    started: float,
) -> dict[str, Any] | None:
    """Wait for the drive to finish its scenario, printing progress; return the sim's last status."""
    sim_status: dict[str, Any] | None = None
    next_progress = time.monotonic()
    while True:
        supervisor.check(expected_to_finish=drive.name)
        if time.monotonic() >= next_progress or drive.process.poll() is not None:
            sim_status = _status(session, keys, Service.SIM) or sim_status
            next_progress = time.monotonic() + PROGRESS_INTERVAL_S
            if sim_status:
                _progress(supervisor, sim_status, time.monotonic() - started)
        code = drive.process.poll()
        if code == 0:
            return sim_status
        if code is not None:
            raise ChildDied(f"drive exited unexpectedly ({_describe_exit(code)})")
        time.sleep(0.05)


def _progress(supervisor: Supervisor, sim_status: dict[str, Any], wall_s: float) -> None:
    sim_time = sim_status.get("sim_time_s", 0.0)
    pose = sim_status.get("pose") or {}
    supervisor.say(
        f"sim {sim_time:7.2f} s | {sim_time / wall_s if wall_s > 0 else 0:5.2f}x real time | "
        f"pose x {pose.get('x', 0.0):+.3f} y {pose.get('y', 0.0):+.3f} theta {pose.get('theta', 0.0):+.3f}"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="square", help="built-in scenario or TOML file (default square)")
    parser.add_argument(
        "--mode", choices=["lockstep", "realtime"], help="sim mode (default: sim.mode of the robot description, lockstep)"
    )
    parser.add_argument("--report", metavar="DIR", help="report directory (default runs/<timestamp>/)")
    parser.add_argument("--gui", action="store_true", help="open the PyBullet window (needs a display)")

