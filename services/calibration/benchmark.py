"""A UMBmark benchmark's runs and what the benchmarks of a calibration conclude: the arithmetic
of ``invent calibrate umbmark`` around the paper's formulas (``umbmark.py``). Pure: no zenoh.

A run (:class:`Lap`) is one square, its paths and where the sim (the ground truth) and the
odometry say it ended; a :class:`Benchmark` the runs each way under one calibration and their
evaluation; :func:`conclude` takes the benchmarks of one calibration (the first before any
correction, each next with the last one's correction applied) to the calibration to use, the
errors (Ed, Eb) it estimates and E_max,syst before and after.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from services.calibration.umbmark import Calibration, Direction, Point, Umbmark, return_error
from services.config import Config

PathPoint = tuple[float, float]


@dataclass(frozen=True)
class RunPaths:
    """One run's paths in the world frame (m), as the sim and the odometry traced them, and where
    each says the run ended."""

    name: str
    """The run's name in the figure and the recording (e.g. ``cw 1``)."""
    direction: Direction
    truth: tuple[PathPoint, ...]
    """The robot as the simulator saw it (its ground truth), a point every centimetre or more."""
    odometry: tuple[PathPoint, ...]
    """The odometry's pose over the run, a point every centimetre or more."""
    truth_end: PathPoint
    """Where the robot really stopped."""
    odometry_end: PathPoint
    """Where the odometry says it stopped: the return position error is ``truth_end - odometry_end``."""


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


def wheelbase(config: Config, calibration: Calibration) -> float:
    """The wheelbase the odometry integrates with under ``calibration``."""
    return config.robot.length_of_axle * calibration.axle_scale


def total(start: Calibration, final: Calibration) -> tuple[float, float]:
    """(Ed, Eb) that ``final`` estimates relative to ``start``: the diameter ratio and wheelbase
    it takes, over those ``start`` took."""
    ed = (final.right_radius_scale / final.left_radius_scale) / (start.right_radius_scale / start.left_radius_scale)
    return ed, final.axle_scale / start.axle_scale


def true_body(config: Config, sim_set: Mapping[str, Any], start: Calibration) -> dict[str, float]:
    """The simulated body (``config``'s robot changed by ``sim_set``) against what the odometry
    takes under ``start``: its diameter ratio (Ed), wheelbase (Eb) and mean wheel radius, each
    relative. UMBmark sees Ed, and Eb over the mean radius (a common scale of the wheels turns the
    robot on the spot as a shorter wheelbase does)."""
    robot = config.robot
    left = float(sim_set.get("robot.radius_of_left_wheel", robot.radius_of_left_wheel))
    right = float(sim_set.get("robot.radius_of_right_wheel", robot.radius_of_right_wheel))
    axle = float(sim_set.get("robot.length_of_axle", robot.length_of_axle))
    assumed_left = robot.radius_of_left_wheel * start.left_radius_scale
    assumed_right = robot.radius_of_right_wheel * start.right_radius_scale
    return {
        "ed": (right / left) / (assumed_right / assumed_left),
        "eb": axle / wheelbase(config, start),
        "mean_radius": (left + right) / (assumed_left + assumed_right),
    }


@dataclass(frozen=True)
class Conclusion:
    """What the benchmarks of one calibration conclude."""

    final: Calibration
    """The calibration to use: the last benchmark's, or with one benchmark alone (measured by
    hand) the start corrected by it."""
    ed: float
    eb: float
    """(Ed, Eb) that :attr:`final` estimates relative to the start (:func:`total`)."""
    e_before: float
    """m: E_max,syst of the first benchmark."""
    e_after: float | None
    """m: E_max,syst of the last, None with one benchmark alone (nothing measured after)."""

    @property
    def reduction(self) -> float | None:
        """E_max,syst before over after; None with nothing after, or nothing left after."""
        return self.e_before / self.e_after if self.e_after else None


def conclude(start: Calibration, benchmarks: Sequence[Benchmark]) -> Conclusion:
    """The conclusion of ``benchmarks`` (at least one) run from the calibration ``start``."""
    before, after = benchmarks[0], benchmarks[-1]
    final = after.calibration if len(benchmarks) > 1 else start.then(before.result.correction)
    ed, eb = total(start, final)
    return Conclusion(
        final=final,
        ed=ed,
        eb=eb,
        e_before=before.result.e_max_syst,
        e_after=after.result.e_max_syst if len(benchmarks) > 1 else None,
    )
