"""A composed fleet over several processes: its robots' services spread over worker processes.

Services composed in one process (services/launch/composition.py) share one thread, so a composed
fleet keeps one core busy whatever the machine has. With ``invent up --fleet FILE --composed
--workers N``, ``up``'s own process runs the simulator (one world, as ever) and the robots given to
it, and N - 1 worker processes (``invent worker``, a child each) run the others, each robot's
services together in one worker, handing each other their messages directly (intra-process
delivery). The simulator and a worker exchange a step's wheel angles and torques over zenoh; the
lockstep protocol is the same, so the run is the same bit for bit however its robots are spread.
On two cores one process measured faster (every step then pays a round trip between processes,
longer than the control it moves off the simulator's core: docs/fleet.md), so ``up``'s default
is one.

On a machine of its own, ``invent worker --fleet FILE --robots R1,R2`` runs the services of those
robots of the fleet file composed in one process, as ``up`` would start them: one process per service
host for its robots (docs/deploy.md). Started by ``up``, a worker takes its services on its
standard input instead, one plan per line (a JSON array:
services/launch/service_plans.py's :func:`~services.launch.service_plans.encode_plan`), builds each
in its composition and says so on its standard output (:data:`WORKER_PREFIX` lines); it says too
when a service ends by itself (a drive at the end of its scenario, with its exit code), and every
service's exit code when it stops (SIGINT, or its standard input closed: ``up`` is gone).
:class:`Workers` is ``up``'s side: a :class:`~services.launch.children.Launcher` that starts a
robot's services where :func:`assign` put the robot.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from schemas.keys import Service
from services.drive.options import goal_options, scenario_options
from services.errors import ChildDied
from services.fleet.description import Fleet, robot_settings
from services.launch.children import Supervisor, describe_exit
from services.launch.composition import Composition
from services.launch.plan import DEFAULT_SCENARIO, Description
from services.launch.service_plans import BUILT_IN, ChildPlan, decode_plan, encode_plan
from services.runtime.executor import STOP_POLL_S

WORKER_PREFIX = "@worker "
STARTED, FAILED, ENDED, STOPPED = "started", "failed", "ended", "stopped"
START_TIMEOUT_S = 60.0


def assign(robots: Sequence[str], workers: int) -> dict[str, int]:
    """Which process runs each robot's services: 0 is ``up``'s own (it runs the simulator too),
    1..workers-1 the worker processes. Robots are dealt in turn from the last process to the first,
    so ``up``'s gets the fewest when they do not divide evenly."""
    count = max(1, min(workers, len(robots)))
    order = list(range(count - 1, -1, -1))
    return {robot: order[index % count] for index, robot in enumerate(robots)}


def _say(kind: str, *fields: Any) -> None:
    print(WORKER_PREFIX + json.dumps([kind, *fields]), flush=True)


ROBOT_SERVICES = (Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION, Service.DRIVE)


def robot_plans(fleet: Fleet, robots: Sequence[str]) -> list[ChildPlan[Any]]:
    """The services of ``robots`` (names in ``fleet``) as ``invent up --fleet`` starts them: a
    service host's one process for its robots (docs/deploy.md). A robot's drive runs its goal file,
    else its scenario, else ``up``'s default scenario."""
    plans: list[ChildPlan[Any]] = []
    for name in robots:
        robot = fleet.robot(name)
        description = Description(robot=name, settings=robot_settings(robot))
        drive = goal_options(robot.goals) if robot.goals else scenario_options(robot.scenario or DEFAULT_SCENARIO)
        for service in ROBOT_SERVICES:
            command, options_type = BUILT_IN[service]
            options = drive if service is Service.DRIVE else options_type()
            plans.append(ChildPlan(f"{name}/{service}", command, options, description))
    return plans


def run_worker(
    session: zenoh.Session,
    stop: threading.Event,
    *,
    intra_process: bool = True,
    plans: Sequence[ChildPlan[Any]] = (),
) -> int:
    """``invent worker``: compose ``plans``, then the services ``up`` sends on standard input
    (none given), until stopped."""
    composition = Composition(session, intra_process=intra_process)

    def start(child: ChildPlan[Any]) -> None:
        try:
            composition.start_service(child)
        except BaseException as error:  # noqa: BLE001 (reported to up, which ends the run saying why)
            _say(FAILED, child.name, f"{type(error).__name__}: {error}")
            return
        _say(STARTED, child.name)

    def read_plans() -> None:
        for line in sys.stdin:
            if line.strip():
                composition.post(start, decode_plan(line))
        stop.set()  # up is gone, or done with us

    for child in plans:
        start(child)
    if not plans:
        threading.Thread(target=read_plans, name="invent-worker-plans", daemon=True).start()
    reported: set[str] = set()
    try:
        while not stop.is_set():
            composition.spin(STOP_POLL_S)
            for name, (code, how) in composition.exits().items():
                if name not in reported:
                    reported.add(name)
                    _say(ENDED, name, code, how)
    finally:
        _say(STOPPED, composition.stop())
    return 0


class _Worker:
    """``up``'s view of one worker process: what it has started, what has ended, how it stopped."""

    def __init__(self, index: int, supervisor: Supervisor, connection: Sequence[str]) -> None:
        self.name = f"worker{index}"
        self.started: dict[str, str | None] = {}
        """Services asked for: None until the worker answers, then ``started`` or why it failed."""
        self.ended: dict[str, tuple[int, str]] = {}
        self.stopped: dict[str, int] | None = None
        self._answered = threading.Condition()
        self.child = supervisor.start(self.name, ["worker", *connection], on_line=self._on_line, stdin=True)

    def _on_line(self, line: str) -> bool:
        if not line.startswith(WORKER_PREFIX):
            return False
        kind, *fields = json.loads(line[len(WORKER_PREFIX) :])
        with self._answered:
            if kind == STARTED:
                self.started[fields[0]] = STARTED
            elif kind == FAILED:
                self.started[fields[0]] = fields[1]
            elif kind == ENDED:
                self.ended[fields[0]] = (int(fields[1]), str(fields[2]))
            elif kind == STOPPED:
                self.stopped = {name: int(code) for name, code in fields[0].items()}
            self._answered.notify_all()
        return True

    def start(self, child: ChildPlan[Any]) -> None:
        name = child.name
        stdin = self.child.process.stdin
        assert stdin is not None
        self.started[name] = None
        stdin.write(encode_plan(child).decode() + "\n")
        stdin.flush()
        deadline = time.monotonic() + START_TIMEOUT_S
        with self._answered:
            while self.started[name] is None:
                code = self.child.finished()
                if code is not None:
                    raise ChildDied(f"{self.name} exited while starting {name} ({describe_exit(code)})")
                if time.monotonic() > deadline:
                    raise ChildDied(f"{self.name} did not start {name} within {START_TIMEOUT_S} s")
                self._answered.wait(0.05)
        if self.started[name] != STARTED:
            raise ChildDied(f"{name} could not start in {self.name}: {self.started[name]}")

    def exits(self) -> dict[str, tuple[int, str]]:
        code = self.child.finished()
        if code is None or self.stopped is not None:
            return dict(self.ended)
        died = f"{self.name} {describe_exit(code)}"
        return {name: self.ended.get(name, (1, died)) for name in self.started}

    def close_requests(self) -> None:
        stdin = self.child.process.stdin
        if stdin is not None and not stdin.closed:
            stdin.close()


class Workers:
    """A composed fleet's launcher: the simulator and the robots :func:`assign` gives process 0 in
    this process's :class:`Composition`, the other robots' services in worker processes."""

    def __init__(self, composition: Composition, assignment: dict[str, int], connection: Sequence[str]) -> None:
        self.composition = composition
        self.bus = composition.bus
        self.assignment = assignment
        self._connection = list(connection)
        self._supervisor = Supervisor()
        self._workers: dict[int, _Worker] = {}

    def start_service(self, child: ChildPlan[Any]) -> Any:
        name = child.name
        index = self.assignment.get(name.partition("/")[0], 0) if "/" in name else 0
        if index == 0:
            return self.composition.start_service(child)
        if index not in self._workers:
            self._workers[index] = _Worker(index, self._supervisor, self._connection)
        self._workers[index].start(child)
        return None

    def exits(self) -> dict[str, tuple[int, str]]:
        ended = self.composition.exits()
        for worker in self._workers.values():
            ended.update(worker.exits())
        return ended

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None:
        for name, (code, how) in self.exits().items():
            if name != exclude:
                return name, code, how
        return None

    def idle(self) -> None:
        self.composition.idle()

    def stop(self) -> dict[str, int]:
        codes = self.composition.stop()
        for worker in self._workers.values():
            worker.close_requests()
        self._supervisor.stop()
        for worker in self._workers.values():
            stopped = worker.stopped or {}
            for name in worker.started:
                codes[name] = stopped.get(name, worker.ended.get(name, (1, ""))[0])
        return codes
