"""``invent calibrate umbmark``: UMBmark in the simulator, or from return positions measured by hand.

In the simulator, each run drives the square with the loop composed in this process in lockstep
(``services/launch/umbmark_runs.py``), the sim's body alone changed by ``--sim-set``; the return
position error is the sim's ground truth minus the odometry's pose where the run ends. After the
benchmark (``--runs`` each way) the corrections are applied to every service but the sim and the
benchmark runs again: a pass. Another pass (up to ``--passes``) runs only while the correction
the benchmark after the last gives would still change a multiplier by :data:`CONVERGED` or more
(the paper's first-order formulas leave a few per cent of large errors: docs/odometry.md). The
loop is deterministic in lockstep, so the runs of one direction of a benchmark end at the same
place: the spread the paper averages over (the floor, the wheels' contact) is not simulated, only
the systematic part UMBmark measures.

``--measured FILE`` evaluates return positions measured with a tape on the robot instead
(``services/calibration/measured.py``): no simulator, one benchmark, the corrections.

Either way the arithmetic is ``services/calibration/`` (the formulas, the benchmarks, what they
conclude), ``-o FILE`` writes the robot description given (``--config`` and ``--set``) with the
corrected ``odometry.*_scale``, and ``--report DIR`` (default ``runs/<timestamp>/``) gets
``report.json`` (``services/recording/calibration_report.py``), the paper's figure ``umbmark.png``
and, from the simulator, the runs' paths for Foxglove in ``umbmark.mcap``
(``services/recording/calibration.py``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from services.calibration.benchmark import Benchmark, RunPaths, conclude, true_body, wheelbase
from services.calibration.measured import read_measured
from services.calibration.settings import UmbmarkSettings
from services.calibration.umbmark import CONVERGED, Calibration, Direction, Umbmark, evaluate
from services.config import ConfigError
from services.errors import ChildDied, Interrupted, RunFailed
from services.exits import ExitStatus
from services.launch.umbmark_runs import Simulation, check_sim_config, say
from services.recording.calibration import write_figure, write_paths_recording
from services.recording.calibration_report import (
    FIGURE_FILE,
    RECORDING_FILE,
    REPORT_FILE,
    benchmark_line,
    make_report_dir,
    report,
    summary,
    write_description,
)
from services.runtime.session import stop_on_signals


def run_umbmark(settings: UmbmarkSettings) -> int:
    """Calibrate as ``settings`` say: from the measured file, else in the simulator. The exit
    status; ConfigError for what the flags cannot give."""
    start = Calibration.of(settings.config.odometry)
    if settings.measured is not None:
        return _from_measured(settings, settings.measured, start)
    return _in_simulation(settings, start)


def _from_measured(settings: UmbmarkSettings, path: Path, start: Calibration) -> int:
    measured = read_measured(path)
    if measured.side is not None and settings.side_given and measured.side != settings.side:
        raise ConfigError(f"--side {settings.side:g} and the side of {path} ({measured.side:g} m) differ")
    side = measured.side or settings.side
    try:
        result = evaluate(
            side, wheelbase(settings.config, start), measured.errors[Direction.CW], measured.errors[Direction.CCW]
        )
    except ValueError as error:
        raise ConfigError(f"--measured {path}: {error}") from None
    benchmark = Benchmark("measured", start, result)
    say(benchmark_line(benchmark))
    inputs = {"source": "measured", "measured": str(path), "side": side}
    return _finish(settings, side, start, [benchmark], passes=1, inputs=inputs)


def _in_simulation(settings: UmbmarkSettings, start: Calibration) -> int:
    """The benchmark before, then passes: each applies the last benchmark's correction and runs the
    benchmark again, until ``--passes`` or until the next correction would be below :data:`CONVERGED`."""
    check_sim_config(settings)
    make_report_dir(settings.report_dir)
    interrupted = stop_on_signals()
    simulation = Simulation(settings, interrupted)
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
        return ExitStatus.FAILURE
    except RunFailed as error:
        say(str(error))
        return ExitStatus.FAILURE
    except Interrupted:
        say("interrupted; stopped")
        return ExitStatus.INTERRUPTED
    recording = settings.report_dir / RECORDING_FILE
    write_paths_recording(recording, settings.side, [_paths_of(benchmark) for benchmark in benchmarks])
    inputs = {
        "source": "simulation",
        "side": settings.side,
        "runs": settings.runs,
        "max_passes": settings.passes,
        "sim_set": settings.sim_set,
        "true_body": true_body(settings.config, settings.sim_set, start),
        "scenarios": {str(direction): str(path) for direction, path in simulation.scenarios.items()},
    }
    return _finish(settings, settings.side, start, benchmarks, passes=passes, inputs=inputs, recording=recording)


def _paths_of(benchmark: Benchmark) -> tuple[str, list[RunPaths]]:
    return benchmark.label, [lap.paths for lap in benchmark.laps]


def _points_of(benchmark: Benchmark) -> tuple[str, Umbmark]:
    return benchmark.label, benchmark.result


def _finish(
    settings: UmbmarkSettings,
    side: float,
    start: Calibration,
    benchmarks: list[Benchmark],
    *,
    passes: int,
    inputs: dict[str, Any],
    recording: Path | None = None,
) -> int:
    """The figure, the calibrated description (``-o``) and ``report.json`` written, the summary printed."""
    conclusion = conclude(start, benchmarks)
    make_report_dir(settings.report_dir)
    figure = write_figure(settings.report_dir / FIGURE_FILE, side, [_points_of(b) for b in benchmarks])
    files = {"report": str(settings.report_dir / REPORT_FILE), "figure": str(figure)}
    if recording is not None:
        files["recording"] = str(recording)
    if settings.output is not None:
        files["robot_description"] = str(write_description(settings.output, settings.description, conclusion))
    written = report(settings.config, start, benchmarks, conclusion, passes=passes, inputs=inputs, files=files)
    (settings.report_dir / REPORT_FILE).write_text(json.dumps(written, indent=2) + "\n")
    for line in summary(conclusion, passes, files):
        say(line)
    return ExitStatus.OK
