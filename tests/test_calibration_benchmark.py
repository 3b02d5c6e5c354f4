"""The arithmetic of ``invent calibrate umbmark`` around the paper's formulas
(services/calibration/benchmark.py): a run's error and record, the wheelbase the odometry takes,
the total estimate over the passes, the simulated body against the odometry's, and what the
benchmarks conclude. Pure: no zenoh, no simulator."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.calibration.benchmark import Benchmark, Lap, RunPaths, conclude, total, true_body, wheelbase
from services.calibration.umbmark import Calibration, Direction, correction, evaluate
from services.config import config_from_description

CONFIG = config_from_description({})
"""The default robot: wheels of 0.1 m, an axle of 0.441 m."""
scale = st.floats(0.9, 1.1)
calibrations = st.builds(Calibration, scale, scale, scale)


def lap(direction: Direction, truth_end: tuple[float, float], odometry_end: tuple[float, float]) -> Lap:
    paths = RunPaths(f"{direction} 1", direction, ((0.0, 0.0),), ((0.0, 0.0),), truth_end, odometry_end)
    return Lap(direction=direction, index=1, sim_time_s=62.1, wall_s=2.4, paths=paths)


def test_a_laps_error_is_where_it_stopped_minus_where_its_odometry_says():
    run = lap(Direction.CW, (-0.0027, -0.0054), (0.0, -0.0023))
    assert run.error == pytest.approx((-0.0027, -0.0031))
    assert run.as_dict() == {
        "direction": "cw",
        "index": 1,
        "truth_end": [-0.0027, -0.0054],
        "odometry_end": [0.0, -0.0023],
        "error": [pytest.approx(-0.0027), pytest.approx(-0.0031)],
        "sim_time_s": 62.1,
        "wall_s": 2.4,
    }


def test_a_benchmark_reports_its_calibration_its_evaluation_and_its_runs():
    runs = (lap(Direction.CW, (-0.1, -0.1), (0.0, 0.0)), lap(Direction.CCW, (0.03, -0.03), (0.0, 0.0)))
    result = evaluate(4.0, 0.441, [runs[0].error], [runs[1].error])
    written = Benchmark("before", Calibration(), result, runs).as_dict()
    assert written["label"] == "before" and written["calibration"] == Calibration().as_dict()
    assert written["ed"] == result.ed and written["e_max_syst"] == result.e_max_syst
    assert [run["direction"] for run in written["runs"]] == ["cw", "ccw"]
    assert Benchmark("measured", Calibration(), result).as_dict()["runs"] == []


def test_the_wheelbase_is_the_axle_times_its_multiplier():
    assert wheelbase(CONFIG, Calibration(axle_scale=1.01)) == pytest.approx(0.441 * 1.01)


@settings(max_examples=100, deadline=None)
@given(start=calibrations, ed=st.floats(0.95, 1.05), eb=st.floats(0.95, 1.05))
def test_the_total_of_a_correction_is_the_ed_and_eb_it_corrects(start: Calibration, ed: float, eb: float):
    """Whatever the calibration it starts from, the correction computed from (Ed, Eb) estimates them
    back; the start alone estimates no error."""
    assert total(start, start.then(correction(ed, eb))) == pytest.approx((ed, eb))
    assert total(start, start) == pytest.approx((1.0, 1.0))


def test_the_true_body_is_the_sims_against_the_odometrys():
    sim_set = {"robot.radius_of_right_wheel": 0.1005, "robot.length_of_axle": 0.44982}
    assert true_body(CONFIG, sim_set, Calibration()) == pytest.approx({"ed": 1.005, "eb": 1.02, "mean_radius": 1.0025})
    assert true_body(CONFIG, {}, Calibration()) == {"ed": 1.0, "eb": 1.0, "mean_radius": 1.0}


@settings(max_examples=100, deadline=None)
@given(left=scale, right=scale, axle=scale)
def test_an_odometry_calibrated_to_the_simulated_body_sees_no_error(left: float, right: float, axle: float):
    sim_set = {"robot.radius_of_left_wheel": 0.1 * left, "robot.radius_of_right_wheel": 0.1 * right}
    sim_set["robot.length_of_axle"] = 0.441 * axle
    assert true_body(CONFIG, sim_set, Calibration(left, right, axle)) == pytest.approx(
        {"ed": 1.0, "eb": 1.0, "mean_radius": 1.0}
    )


def benchmark(label: str, calibration: Calibration, error: float) -> Benchmark:
    """A benchmark whose runs both way return ``error`` m off along x."""
    return Benchmark(label, calibration, evaluate(4.0, 0.441, [(-error, 0.0)], [(error / 2, 0.0)]))


def test_one_benchmark_concludes_the_start_corrected_with_nothing_measured_after():
    start = Calibration(axle_scale=1.01)
    measured = benchmark("measured", start, 0.1)
    concluded = conclude(start, [measured])
    assert concluded.final == start.then(measured.result.correction)
    assert (concluded.ed, concluded.eb) == total(start, concluded.final)
    assert concluded.e_before == measured.result.e_max_syst
    assert concluded.e_after is None and concluded.reduction is None


def test_passes_conclude_the_last_calibration_and_the_reduction_of_the_error():
    start = Calibration()
    before = benchmark("before", start, 0.1)
    first = benchmark("after pass 1", start.then(before.result.correction), 0.01)
    second = benchmark("after pass 2", first.calibration.then(first.result.correction), 0.004)
    concluded = conclude(start, [before, first, second])
    assert concluded.final == second.calibration
    assert (concluded.ed, concluded.eb) == total(start, second.calibration)
    assert concluded.e_before == pytest.approx(0.1) and concluded.e_after == pytest.approx(0.004)
    assert concluded.reduction == pytest.approx(25.0)
    assert conclude(start, [before, benchmark("after pass 1", start, 0.0)]).reduction is None
