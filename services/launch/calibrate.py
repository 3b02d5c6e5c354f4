"""``invent calibrate umbmark``: UMBmark in the simulator, or from return positions measured by hand.

In the simulator, each run drives the square (``services/calibration/umbmark.py``, ``square``)
with the loop composed in this process in lockstep, as ``invent up --composed`` runs it, but with
no localization: motor, odometry, the drive following the square on the odometry's pose, and the
sim, whose body alone takes ``--sim-set`` (the "true" robot; every other service keeps the robot
description). Each run ends with the robot standing still where its odometry says the square
ends; the return position error is the sim's ground truth minus the odometry's pose there. After
the benchmark (``--runs`` each way) the corrections are applied to every service but the sim and
the benchmark runs again: a pass. Another pass (up to ``--passes``) runs only while the correction
the benchmark after the last gives would still change a multiplier by :data:`CONVERGED` or more
(the paper's first-order formulas leave a few per cent of large errors: docs/odometry.md). The
loop is deterministic in lockstep, so the runs of one direction of a benchmark end at the same
place: the spread the paper averages over (the floor, the wheels' contact) is not simulated, only
the systematic part UMBmark measures.

``--measured FILE`` evaluates return positions measured with a tape on the robot instead
(``services/calibration/measured.py``): no simulator, one benchmark, the corrections.

Either way ``-o FILE`` writes the robot description given (``--config`` and ``--set``) with the
corrected ``odometry.*_scale``, and ``--report DIR`` (default ``runs/<timestamp>/``) gets
``report.json``, the paper's figure ``umbmark.png`` and, from the simulator, the runs' paths for
Foxglove in ``umbmark.mcap`` (``services/recording/calibration.py``).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from schemas.keys import Keys, Service, Topic
from schemas.messages import TimedDoubleSeq, TimedPosition
from services.calibration.measured import read_measured
from services.calibration.umbmark import (
    CONVERGED,
    DEFAULT_RUNS,
    DEFAULT_SIDE,
    Calibration,
    Direction,
    Point,
    Umbmark,
    evaluate,
    return_error,
    square,
)
from services.cli.flags import finite_number, overrides_from_args
from services.config import (
    NONE,
    Config,
    ConfigError,
    config_from_description,
    description_toml,
    parse_override,
    read_description,
)
from services.drive.outcome import OUTCOME_OF_EXIT_CODE, Outcome
from services.errors import ChildDied, Interrupted
from services.launch.composition import Composition
from services.launch.run import EXIT_CHILD_DIED, EXIT_INTERRUPTED, Outcomes, Run, default_report_dir
from services.recording.calibration import PathPoint, RunPaths, write_figure, write_paths_recording
from services.recording.report import degradations, loop_health
from services.runtime.intraprocess import LocalBus, Watch
from services.runtime.session import free_port, open_session, session_config, stop_on_signals

SIM_BODY_KEYS = (
    "robot.radius_of_left_wheel",
    "robot.radius_of_right_wheel",
    "robot.length_of_axle",
    "robot.radius_of_body_area",
    "sim.body_mass",
    "sim.body_height",
    "sim.wheel_mass",
    "sim.wheel_width",
    "sim.caster_mass",
    "sim.wheel_friction",
    "sim.max_wheel_torque",
)
"""What ``--sim-set`` may change: the simulated body, not the loop."""
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
DEFAULT_PASSES = 2
PROGRESS_S = 10.0
"""Wall seconds between two progress lines within one run."""
PATH_SPACING_M = 0.01
PATH_POINTS = 20_000
"""A run's paths keep a point every :data:`PATH_SPACING_M`, at most this many each."""
REPORT_FILE = "report.json"
FIGURE_FILE = "umbmark.png"
RECORDING_FILE = "umbmark.mcap"
EXIT_RUN_FAILED = 1


class RunFailed(RuntimeError):
    """A run did not drive its square to the end (the drive gave it up), or the runs' return
    positions are beyond what the formulas take."""


def say(text: str) -> None:
    print(f"[umbmark] {text}", flush=True)


@dataclass(frozen=True)
class Lap:
    """One run round the square in the simulator."""

    direction: Direction
    index: int
    sim_time_s: float
    wall_s: float
    paths: RunPaths
    """Its paths and where the sim and the odometry say it ended."""

    @property
    def truth_end(self) -> Point:
        return self.paths.truth_end

    @property
    def odometry_end(self) -> Point:
        return self.paths.odometry_end

    @property
    def error(self) -> Point:
        return return_error(self.truth_end, self.odometry_end)

    def as_dict(self) -> dict[str, Any]:
        return {
            "direction": str(self.direction),
            "index": self.index,
            "truth_end": list(self.truth_end),
            "odometry_end": list(self.odometry_end),
            "error": list(self.error),
            "sim_time_s": self.sim_time_s,
            "wall_s": self.wall_s,
        }


@dataclass(frozen=True)
class Benchmark:
    """The runs each way with one calibration, and UMBmark's evaluation of them."""

    label: str
    calibration: Calibration
    result: Umbmark
    laps: tuple[Lap, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "calibration": self.calibration.as_dict(),
            **self.result.as_dict(),
            "runs": [lap.as_dict() for lap in self.laps],
        }


@dataclass(frozen=True)
class Settings:
    side: float
    runs: int
    passes: int
    sim_set: dict[str, Any]
    description: dict[str, Any]
    """The robot description given (``--config``, ``--set``), as written: what ``-o`` extends."""
    config: Config
    report_dir: Path
    output: Path | None


def wheelbase(config: Config, calibration: Calibration) -> float:
    """The wheelbase the odometry integrates with under ``calibration``."""
    return config.robot.length_of_axle * calibration.axle_scale


def total(start: Calibration, final: Calibration) -> tuple[float, float]:
    """(Ed, Eb) that ``final`` estimates relative to ``start``: the diameter ratio and wheelbase
    it takes, over those ``start`` took."""
    ed = (final.right_radius_scale / final.left_radius_scale) / (start.right_radius_scale / start.left_radius_scale)
    return ed, final.axle_scale / start.axle_scale


def _settings(args: argparse.Namespace) -> Settings:
    if args.measured:
        given = [
            flag
            for flag, value in (("--runs", args.runs), ("--passes", args.passes), ("--sim-set", args.sim_set))
            if value
        ]
        if given:
            raise ConfigError(f"{', '.join(given)}: --measured computes from a file, with no simulator to run")
    sim_set = {}
    for text in args.sim_set or ():
        try:
            path, value = parse_override(text)
        except ConfigError:
            raise ConfigError(f"--sim-set {text!r} must be KEY=VALUE") from None
        key = ".".join(path)
        if key not in SIM_BODY_KEYS:
            raise ConfigError(
                f"--sim-set {key}: only the simulated body may differ from the description: " + ", ".join(SIM_BODY_KEYS)
            )
        sim_set[key] = value
    output = Path(args.output) if args.output else None
    if output is not None and not output.parent.is_dir():
        raise ConfigError(f"-o {output}: no directory {output.parent} to write it in")
    overrides = overrides_from_args(None, args)
    description = read_description(args.config, overrides)
    config = config_from_description(description)
    return Settings(
        side=args.side or DEFAULT_SIDE,
        runs=args.runs or DEFAULT_RUNS,
        passes=args.passes or DEFAULT_PASSES,
        sim_set=sim_set,
        description=description,
        config=config,
        report_dir=Path(args.report) if args.report else default_report_dir(),
        output=output,
    )


def run_umbmark(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    settings = _settings(args)
    start = Calibration.of(settings.config.odometry)
    if args.measured:
        return _from_measured(args, settings, start)
    return _in_simulation(args, parser, settings, start)


def _from_measured(args: argparse.Namespace, settings: Settings, start: Calibration) -> int:
    measured = read_measured(Path(args.measured))
    if measured.side is not None and args.side is not None and measured.side != args.side:
        raise ConfigError(f"--side {args.side:g} and the side of {args.measured} ({measured.side:g} m) differ")
    side = measured.side or settings.side
    try:
        result = evaluate(
            side, wheelbase(settings.config, start), measured.errors[Direction.CW], measured.errors[Direction.CCW]
        )
    except ValueError as error:
        raise ConfigError(f"--measured {args.measured}: {error}") from None
    benchmark = Benchmark("measured", start, result)
    say(_benchmark_line(benchmark))
    inputs = {"source": "measured", "measured": str(args.measured), "side": side}
    return _finish(settings, side, start, [benchmark], passes=1, inputs=inputs)


def _in_simulation(
    args: argparse.Namespace, parser: argparse.ArgumentParser, settings: Settings, start: Calibration
) -> int:
    """The benchmark before, then passes: each applies the last benchmark's correction and runs the
    benchmark again, until ``--passes`` or until the next correction would be below :data:`CONVERGED`."""
    _check_sim_config(args, settings)
    _make_report_dir(settings.report_dir)
    interrupted = stop_on_signals()
    simulation = Simulation(args, parser, settings, interrupted)
    try:
        benchmarks = [simulation.benchmark("before", start)]
        calibration, passes = start, 0
        while True:
            calibration = calibration.then(benchmarks[-1].result.correction)
            passes += 1
            benchmarks.append(simulation.benchmark(f"after pass {passes}", calibration))
            deviation = benchmarks[-1].result.correction.deviation()
            if passes >= settings.passes or deviation < CONVERGED:
                break
            say(f"the next correction still changes a multiplier by {deviation:.2%}: pass {passes + 1}")
    except ChildDied as error:
        say(f"{error}; stopped")
        return EXIT_CHILD_DIED
    except RunFailed as error:
        say(str(error))
        return EXIT_RUN_FAILED
    except Interrupted:
        say("interrupted; stopped")
        return EXIT_INTERRUPTED
    recording = settings.report_dir / RECORDING_FILE
    write_paths_recording(recording, settings.side, [_paths_of(benchmark) for benchmark in benchmarks])
    inputs = {
        "source": "simulation",
        "side": settings.side,
        "runs": settings.runs,
        "max_passes": settings.passes,
        "sim_set": settings.sim_set,
        "true_body": simulation.true_body(start),
        "scenarios": {str(direction): str(path) for direction, path in simulation.scenarios.items()},
    }
    return _finish(settings, settings.side, start, benchmarks, passes=passes, inputs=inputs, recording=recording)


def _make_report_dir(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"--report {path}: {error.strerror}") from None


def _paths_of(benchmark: Benchmark) -> tuple[str, list[RunPaths]]:
    return benchmark.label, [lap.paths for lap in benchmark.laps]


def _check_sim_config(args: argparse.Namespace, settings: Settings) -> None:
    """The sim's description, checked before any run: ConfigError naming a bad ``--sim-set`` value."""
    description = read_description(args.config, {**overrides_from_args(None, args), **RUN_SETTINGS})
    for key, value in settings.sim_set.items():
        section, name = key.split(".")
        description.setdefault(section, {})[name] = value
    try:
        config_from_description(description)
    except ConfigError as error:
        raise ConfigError(f"--sim-set: {error}") from None


def _finish(
    settings: Settings,
    side: float,
    start: Calibration,
    benchmarks: list[Benchmark],
    *,
    passes: int,
    inputs: dict[str, Any],
    recording: Path | None = None,
) -> int:
    before, after = benchmarks[0], benchmarks[-1]
    final = after.calibration if len(benchmarks) > 1 else start.then(before.result.correction)
    ed, eb = total(start, final)
    _make_report_dir(settings.report_dir)
    figure = write_figure(settings.report_dir / FIGURE_FILE, side, [_points_of(b) for b in benchmarks])
    files = {"report": str(settings.report_dir / REPORT_FILE), "figure": str(figure)}
    if recording is not None:
        files["recording"] = str(recording)
    e_before = before.result.e_max_syst
    e_after = after.result.e_max_syst if len(benchmarks) > 1 else None
    if settings.output is not None:
        files["robot_description"] = str(_write_description(settings, final, (ed, eb), e_before, e_after))
    report = {
        "method": "umbmark",
        "inputs": {
            **inputs,
            "robot": {
                "radius_of_left_wheel": settings.config.robot.radius_of_left_wheel,
                "radius_of_right_wheel": settings.config.robot.radius_of_right_wheel,
                "length_of_axle": settings.config.robot.length_of_axle,
            },
            "calibration": start.as_dict(),
        },
        "benchmarks": [benchmark.as_dict() for benchmark in benchmarks],
        "passes": passes,
        "ed": ed,
        "eb": eb,
        "corrections": final.as_dict(),
        "e_max_syst": {
            "before": e_before,
            "after": e_after,
            "reduction": e_before / e_after if e_after else None,
        },
        "files": files,
    }
    (settings.report_dir / REPORT_FILE).write_text(json.dumps(report, indent=2) + "\n")
    for line in _summary(ed, eb, final, passes, e_before, e_after, files):
        say(line)
    return 0


def _points_of(benchmark: Benchmark) -> tuple[str, Umbmark]:
    return benchmark.label, benchmark.result


def _write_description(
    settings: Settings, final: Calibration, estimated: tuple[float, float], e_before: float, e_after: float | None
) -> Path:
    """``-o``: the description given, with the corrected multipliers (checked to load)."""
    assert settings.output is not None
    description = copy.deepcopy(settings.description)
    description.setdefault("odometry", {}).update(final.as_dict())
    config_from_description(description)
    header = [
        "# The robot description with the odometry calibrated by UMBmark (invent calibrate umbmark): "
        + f"Ed {estimated[0]:.6f}, Eb {estimated[1]:.6f};",
        f"# E_max,syst {e_before * 1000:.1f} mm before"
        + ("" if e_after is None else f", {e_after * 1000:.1f} mm after")
        + ". Run the robot with --config FILE.",
    ]
    try:
        settings.output.write_text("\n".join(header) + "\n" + description_toml(description))
    except OSError as error:
        raise ConfigError(f"-o {settings.output}: {error.strerror}") from None
    return settings.output


def _summary(
    ed: float,
    eb: float,
    final: Calibration,
    passes: int,
    e_before: float,
    e_after: float | None,
    files: dict[str, str],
) -> list[str]:
    lines = [
        f"estimated: Ed = D_R/D_L = {ed:.6f}, Eb = b_actual/b_nominal = {eb:.6f} ({passes} pass{'es' * (passes > 1)})",
        "corrections: " + ", ".join(f"odometry.{name} = {value:.6f}" for name, value in final.as_dict().items()),
    ]
    if e_after is None:
        lines.append(f"E_max,syst {e_before * 1000:.1f} mm (measure again with the corrections applied)")
    else:
        ratio = e_before / e_after if e_after else math.inf
        lines.append(f"E_max,syst {e_before * 1000:.1f} mm before, {e_after * 1000:.1f} mm after: {ratio:.1f}x smaller")
    lines.append("written: " + ", ".join(files.values()))
    return lines


def _benchmark_line(benchmark: Benchmark) -> str:
    result = benchmark.result
    (cw_x, cw_y), (ccw_x, ccw_y) = result.cg_cw, result.cg_ccw
    return (
        f"{benchmark.label}: centres of gravity cw ({cw_x * 1000:+.1f}, {cw_y * 1000:+.1f}) mm, "
        f"ccw ({ccw_x * 1000:+.1f}, {ccw_y * 1000:+.1f}) mm; E_max,syst {result.e_max_syst * 1000:.1f} mm; "
        f"alpha {result.alpha:+.6f} rad, beta {result.beta:+.6f} rad; Ed {result.ed:.6f}, Eb {result.eb:.6f}"
    )


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

    def __init__(
        self,
        args: argparse.Namespace,
        parser: argparse.ArgumentParser,
        settings: Settings,
        interrupted: threading.Event,
    ) -> None:
        self._parser = parser
        self._settings = settings
        self._interrupted = interrupted
        self._listen = args.listen
        self._keys = Keys(settings.config.robot.name)
        self._common = ["--log-level", args.log_level]
        if args.robot:
            self._common += ["--robot", args.robot]
        if args.config:
            self._common += ["--config", args.config]
        for override in [*(args.set or ()), *(f"{key}={value}" for key, value in RUN_SETTINGS.items())]:
            self._common += ["--set", override]
        self._sim_flags = [flag for key, value in settings.sim_set.items() for flag in ("--set", f"{key}={value!r}")]
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

    def true_body(self, start: Calibration) -> dict[str, float]:
        """The simulated body against what the odometry takes under ``start``: its diameter ratio
        (Ed), wheelbase (Eb) and mean wheel radius, each relative. UMBmark sees Ed, and Eb over the
        mean radius (a common scale of the wheels turns the robot on the spot as a shorter wheelbase does)."""
        robot = self._settings.config.robot
        sim_set = self._settings.sim_set
        left = float(sim_set.get("robot.radius_of_left_wheel", robot.radius_of_left_wheel))
        right = float(sim_set.get("robot.radius_of_right_wheel", robot.radius_of_right_wheel))
        axle = float(sim_set.get("robot.length_of_axle", robot.length_of_axle))
        assumed_left = robot.radius_of_left_wheel * start.left_radius_scale
        assumed_right = robot.radius_of_right_wheel * start.right_radius_scale
        return {
            "ed": (right / left) / (assumed_right / assumed_left),
            "eb": axle / wheelbase(self._settings.config, start),
            "mean_radius": (left + right) / (assumed_left + assumed_right),
        }

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
        say(_benchmark_line(benchmark))
        return benchmark

    def _lap(self, label: str, direction: Direction, index: int, calibration: Calibration) -> Lap:
        name = f"{label}: {direction} run {index}/{self._settings.runs}"
        common = [
            *self._common,
            *(f for key, value in calibration.overrides().items() for f in ("--set", f"{key}={value!r}")),
        ]
        listen = self._listen or f"tcp/127.0.0.1:{free_port()}"
        started = time.monotonic()
        with open_session(session_config(listen=[listen], mode="router")) as session:
            composition = Composition(session, self._parser)
            paths = _PathWatch(session, self._keys, composition.bus)
            outcomes = Outcomes(session, [self._keys.robot], composition.bus)
            try:
                run = Run(composition, session, self._keys, self._interrupted)
                for service in (Service.MOTOR, Service.ODOMETRY):
                    composition.start(str(service), [str(service), *common])
                run.wait_alive((Service.MOTOR, Service.ODOMETRY))
                drive = composition.start("drive", ["drive", *common, "--scenario", str(self.scenarios[direction])])
                run.wait_alive((Service.DRIVE,))
                run.wait_tokens([self._keys.ticks(Service.DRIVE, self._settings.config.drive.rate)])
                sim_argv = ["sim", *common, *self._sim_flags, "--until-drive-ends", "--wait-for", "motor", "drive"]
                composition.start("sim", sim_argv)
                code = self._wait_for_drive(run, drive.finished, name, started)
                outcome = OUTCOME_OF_EXIT_CODE.get(code)
                if outcome is not Outcome.COMPLETED:
                    reason = outcomes.line(self._keys.robot, outcome) if outcome else f"exit code {code}"
                    raise RunFailed(f"{name}: the drive did not complete the square ({reason})")
                sim_status = run.sim_at_end(None)
                statuses = {str(service): run.status(service) for service in (Service.MOTOR, Service.ODOMETRY)}
                odometry = statuses[str(Service.ODOMETRY)]
                if not sim_status or not odometry:
                    raise RunFailed(f"{name}: the sim's or the odometry's status did not come")
                for reason in degradations(loop_health(sim_status, statuses)):
                    say(f"WARNING: {name} degraded: {reason}")
            finally:
                composition.stop()
                outcomes.close()
                paths.close()
        lap = Lap(
            direction=direction,
            index=index,
            sim_time_s=sim_status["sim_time_s"],
            wall_s=time.monotonic() - started,
            paths=RunPaths(
                f"{direction} {index}",
                direction,
                tuple(paths.truth),
                tuple(paths.odometry),
                truth_end=(sim_status["pose"]["x"], sim_status["pose"]["y"]),
                odometry_end=(odometry["pose"]["x"], odometry["pose"]["y"]),
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
                status = run.status(Service.SIM) or {}
                pose = status.get("pose") or {}
                say(
                    f"{name}: {status.get('sim_time_s', 0.0):.1f} s simulated, at "
                    f"({pose.get('x', 0.0):+.3f}, {pose.get('y', 0.0):+.3f}) m"
                )
                next_progress = time.monotonic() + PROGRESS_S
            time.sleep(0.05)
        return int(code)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--side",
        type=_positive_length,
        metavar="M",
        help=f"the square's side in metres (default {DEFAULT_SIDE:g}, the paper's; with --measured, the file's if it "
        "gives one)",
    )
    parser.add_argument(
        "--runs",
        type=_positive_int,
        metavar="N",
        help=f"runs in each direction per benchmark (default {DEFAULT_RUNS}, the paper's); in lockstep the runs of "
        "one direction end at the same place",
    )
    parser.add_argument(
        "--passes",
        type=_positive_int,
        metavar="N",
        help=f"at most N corrections (default {DEFAULT_PASSES}), each followed by the benchmark with it applied; a "
        f"further one only while the correction that benchmark gives would change a multiplier by {CONVERGED * 100:g} %% "
        "or more (the paper's first-order formulas leave a few per cent of large errors)",
    )
    parser.add_argument(
        "--sim-set",
        metavar="KEY=VALUE",
        action="append",
        help="the simulated body differs from the description by this (repeatable), e.g. "
        "--sim-set robot.radius_of_right_wheel=0.1005 --sim-set robot.length_of_axle=0.45: the 'true' robot; "
        "every other service keeps the description. Keys: " + ", ".join(SIM_BODY_KEYS),
    )
    parser.add_argument(
        "--measured",
        metavar="FILE",
        help="no simulator: the return positions measured by hand on the robot, a TOML or CSV file "
        "(docs/odometry.md, Measuring by hand)",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="FILE",
        help="write the robot description given (--config, --set) with the corrected odometry.*_scale: run the "
        "robot with --config FILE",
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help=f"where {REPORT_FILE}, {FIGURE_FILE} (the paper's figure) and {RECORDING_FILE} (the runs' paths, "
        "for Foxglove) go (default runs/<timestamp>/)",
    )
    parser.add_argument(
        "--listen",
        metavar="EP",
        help="where each run's session (a router, as invent up --composed's) listens, e.g. to watch a run with "
        "invent view --connect EP (default a free port on 127.0.0.1)",
    )
    parser.add_argument(
        "--log-level",
        default="warning",
        choices=["debug", "info", "warning", "error"],
        help="the services' log level (default warning: the calibration's own lines only)",
    )


def _positive_length(text: str) -> float:
    value = finite_number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive length in metres")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be at least 1")
    return value
