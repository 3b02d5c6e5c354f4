"""UMBmark's runs in the simulator: each run drives the square (``services/calibration/umbmark.py``,
``square``) with the loop composed in this process in lockstep, as ``invent up --composed`` runs
it, but with no localization: motor, odometry, the drive following the square on the odometry's
pose, and the sim, whose body alone takes ``--sim-set`` (the "true" robot; every other service
keeps the robot description). Each run ends with the robot standing still where its odometry says
the square ends, and its paths are watched on the way (ground truth and odometry, for Foxglove).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from schemas.keys import Keys, Service
from schemas.messages import TimedDoubleSeq, TimedPosition
from schemas.status import MotorStatus, OdometryStatus, SimStatus
from schemas.topics import Topic
from services.calibration.benchmark import Benchmark, Lap, PathPoint, RunPaths, wheelbase
from services.calibration.settings import UmbmarkSettings
from services.calibration.umbmark import Calibration, Direction, evaluate, square
from services.config import NONE, ConfigError, apply_overrides, config_from_description
from services.drive.options import scenario_options
from services.drive.outcome import OUTCOME_OF_EXIT_CODE, Outcome
from services.drive.service import COMMAND as DRIVE
from services.errors import RunFailed
from services.launch.composition import Composition
from services.launch.plan import Description
from services.launch.run import LOOK_INTERVAL_S, Outcomes, Run
from services.launch.service_plans import ChildPlan
from services.motor.service import COMMAND as MOTOR
from services.motor.service import MotorOptions
from services.odometry.service import COMMAND as ODOMETRY
from services.odometry.service import OdometryOptions
from services.recording.calibration_report import benchmark_line
from services.recording.report import degradations, loop_health
from services.runtime.intraprocess import LocalBus, Watch
from services.runtime.session import free_port, open_session, session_config
from sim_bridge.bridge import COMMAND as SIM
from sim_bridge.bridge import SimOptions

RUN_SETTINGS: dict[str, Any] = {
    "sim.world": NONE,
    "sim.mode": "lockstep",
    "odometry.initial_x": 0.0,
    "odometry.initial_y": 0.0,
    "odometry.initial_theta": 0.0,
}
"""Every service of a run takes these over the description: an empty floor, lockstep, and the
odometry starting where the sim's robot stands, at the origin facing +x."""
SETTLE_S = 1.0
"""Simulated seconds of zero command after the square, so the robot stands still when it is read."""
PROGRESS_S = 10.0
"""Wall seconds between two progress lines within one run."""
PATH_SPACING_M = 0.01
PATH_POINTS = 20_000
"""A run's paths keep a point every :data:`PATH_SPACING_M`, at most this many each."""


def say(text: str) -> None:
    print(f"[umbmark] {text}", flush=True)


def check_sim_config(settings: UmbmarkSettings) -> None:
    """The sim's description, checked before any run: ConfigError naming a bad ``--sim-set`` value."""
    description = apply_overrides(copy.deepcopy(settings.description), {**RUN_SETTINGS, **settings.sim_set})
    try:
        config_from_description(description)
    except ConfigError as error:
        raise ConfigError(f"--sim-set: {error}") from None


@dataclass
class _PathWatch:
    """A run's ground truth (``sim/body_pose``) and odometry (``odometry/pose``) paths, from
    callbacks that only append (a point every :data:`PATH_SPACING_M`, bounded)."""

    session: zenoh.Session
    keys: Keys
    bus: LocalBus | None
    """The composition's intra-process delivery: its services' poses come from it, not the session."""
    truth: deque[PathPoint] = field(default_factory=lambda: deque(maxlen=PATH_POINTS))
    odometry: deque[PathPoint] = field(default_factory=lambda: deque(maxlen=PATH_POINTS))

    def __post_init__(self) -> None:
        self._watches: list[Watch[Any]] = [
            Watch(self.session, self.keys.topic(Topic.SIM_BODY_POSE), TimedDoubleSeq, self._body_pose, self.bus),
            Watch(self.session, self.keys.topic(Topic.ODOMETRY_POSE), TimedPosition, self._odometry_pose, self.bus),
        ]

    def _body_pose(self, pose: TimedDoubleSeq) -> None:
        if len(pose.data) >= 2:
            _add(self.truth, pose.data[0], pose.data[1])

    def _odometry_pose(self, pose: TimedPosition) -> None:
        _add(self.odometry, pose.x, pose.y)

    def close(self) -> None:
        for watch in self._watches:
            watch.close()


def _add(path: deque[PathPoint], x: float, y: float) -> None:
    if not path or math.dist(path[-1], (x, y)) >= PATH_SPACING_M:
        path.append((x, y))


class Simulation:
    """Runs of the square, each the loop composed in this process (a session of its own per run)."""

    def __init__(self, settings: UmbmarkSettings, interrupted: threading.Event) -> None:
        self._settings = settings
        self._interrupted = interrupted
        self._listen = settings.listen
        self._keys = Keys(settings.config.robot.name)
        run_settings = (*settings.sets, *(f"{key}={value}" for key, value in RUN_SETTINGS.items()))
        config_file = None if settings.config_file is None else str(settings.config_file)
        self._description = Description(settings.robot, config_file, run_settings)
        self._sim_set = tuple(f"{key}={value!r}" for key, value in settings.sim_set.items())
        self.scenarios = {direction: self._write_scenario(direction) for direction in Direction}

    def _write_scenario(self, direction: Direction) -> Path:
        """The run's scenario: the square, then :data:`SETTLE_S` standing still (a file ``invent up``
        takes too)."""
        path = self._settings.report_dir / f"umbmark_{direction}.toml"
        waypoints = ", ".join(f"[{x!r}, {y!r}]" for x, y in square(self._settings.side, direction))
        path.write_text(
            f'name = "umbmark {direction}"\n\n[[segments]]\ntype = "waypoints"\nwaypoints = [{waypoints}]\n\n'
            f'[[segments]]\ntype = "constant"\nvx = 0.0\nw = 0.0\nduration = {SETTLE_S!r}\n'
        )
        return path

    def benchmark(self, label: str, calibration: Calibration) -> Benchmark:
        settings = self._settings
        say(
            f"{label}: {settings.runs} run{'s' * (settings.runs > 1)} each way round a {settings.side:g} m square, "
            "odometry " + ", ".join(f"{name} {value:.6f}" for name, value in calibration.as_dict().items())
        )
        laps = tuple(
            self._lap(label, direction, index, calibration)
            for direction in Direction
            for index in range(1, settings.runs + 1)
        )
        try:
            result = evaluate(
                settings.side,
                wheelbase(settings.config, calibration),
                [lap.error for lap in laps if lap.direction is Direction.CW],
                [lap.error for lap in laps if lap.direction is Direction.CCW],
            )
        except ValueError as error:
            raise RunFailed(f"{label}: UMBmark cannot take these runs: {error}") from None
        benchmark = Benchmark(label, calibration, result, laps)
        say(benchmark_line(benchmark))
        return benchmark

    def _lap(self, label: str, direction: Direction, index: int, calibration: Calibration) -> Lap:
        name = f"{label}: {direction} run {index}/{self._settings.runs}"
        calibrated = (
            *self._description.settings,
            *(f"{key}={value!r}" for key, value in calibration.overrides().items()),
        )
        description = dataclasses.replace(self._description, settings=calibrated)
        sim_description = dataclasses.replace(description, settings=(*calibrated, *self._sim_set))
        listen = self._listen or f"tcp/127.0.0.1:{free_port()}"
        started = time.monotonic()
        with open_session(session_config(listen=[listen], mode="router")) as session:
            composition = Composition(session)
            paths = _PathWatch(session, self._keys, composition.bus)
            outcomes = Outcomes(session, [self._keys.robot], composition.bus)
            try:
                run = Run(composition, session, self._keys, self._interrupted)
                composition.start_service(ChildPlan("motor", MOTOR, MotorOptions(), description))
                composition.start_service(ChildPlan("odometry", ODOMETRY, OdometryOptions(), description))
                run.wait_alive((Service.MOTOR, Service.ODOMETRY))
                scenario = scenario_options(str(self.scenarios[direction]))
                drive = composition.start_service(ChildPlan("drive", DRIVE, scenario, description))
                run.wait_alive((Service.DRIVE,))
                run.wait_tokens([self._keys.ticks(Service.DRIVE, self._settings.config.drive.rate)])
                waits = SimOptions(until_drive_ends=True, wait_for=(Service.MOTOR, Service.DRIVE))
                composition.start_service(ChildPlan("sim", SIM, waits, sim_description))
                code = self._wait_for_drive(run, drive.finished, name, started)
                outcome = OUTCOME_OF_EXIT_CODE.get(code)
                if outcome is not Outcome.COMPLETED:
                    reason = outcomes.line(self._keys.robot, outcome) if outcome else f"exit code {code}"
                    raise RunFailed(f"{name}: the drive did not complete the square ({reason})")
                run.sim_at_end()
                sim_status = run.sim_status
                odometry = run.status(Service.ODOMETRY, OdometryStatus)
                if sim_status is None or odometry is None:
                    raise RunFailed(f"{name}: the sim's or the odometry's status did not come")
                statuses = {str(Service.MOTOR): run.status(Service.MOTOR, MotorStatus), str(Service.ODOMETRY): odometry}
                for reason in degradations(loop_health(sim_status, statuses)):
                    say(f"WARNING: {name} degraded: {reason}")
            finally:
                composition.stop()
                outcomes.close()
                paths.close()
        lap = Lap(
            direction=direction,
            index=index,
            sim_time_s=sim_status.sim_time_s,
            wall_s=time.monotonic() - started,
            paths=RunPaths(
                f"{direction} {index}",
                direction,
                tuple(paths.truth),
                tuple(paths.odometry),
                truth_end=(sim_status.pose.x, sim_status.pose.y),
                odometry_end=(odometry.pose.x, odometry.pose.y),
            ),
        )
        (x, y), (odometry_x, odometry_y), (error_x, error_y) = lap.truth_end, lap.odometry_end, lap.error
        say(
            f"{name}: stopped at ({x:+.4f}, {y:+.4f}) m, odometry ({odometry_x:+.4f}, {odometry_y:+.4f}) m: "
            f"error ({error_x * 1000:+.1f}, {error_y * 1000:+.1f}) mm "
            f"[{lap.sim_time_s:.1f} s simulated in {lap.wall_s:.1f} s]"
        )
        return lap

    def _wait_for_drive(self, run: Run, finished: Any, name: str, started: float) -> int:
        next_progress = started + PROGRESS_S
        while (code := finished()) is None:
            run.check(expected_to_finish=str(Service.DRIVE))
            if time.monotonic() >= next_progress:
                status = run.status(Service.SIM, SimStatus)
                if status is not None:
                    say(
                        f"{name}: {status.sim_time_s:.1f} s simulated, at "
                        f"({status.pose.x:+.3f}, {status.pose.y:+.3f}) m"
                    )
                next_progress = time.monotonic() + PROGRESS_S
            time.sleep(LOOK_INTERVAL_S)
        return int(code)
