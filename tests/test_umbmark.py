"""UMBmark's pure core (services/calibration/umbmark.py) and the file of hand-measured return
positions (services/calibration/measured.py), without zenoh or a simulator.

The formulas' signs are checked against an ideal differential-drive robot (no slip) with known
wheel radii and wheelbase, driven round the square by its odometry: each leg both wheels turn
so that the odometry sees a straight line of the side's length, each corner they turn in
opposite directions so that it sees 90°; the robot really moves by the exact arcs its true
wheels make. Its return position error is then where it stopped (the odometry believes it is
back at the start)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.calibration.measured import parse_measured_csv, parse_measured_toml
from services.calibration.umbmark import (
    CONVERGED,
    Calibration,
    Direction,
    Point,
    Umbmark,
    centre_of_gravity,
    correction,
    evaluate,
    return_error,
    square,
)
from services.config import ConfigError, OdometryConfig

Wheels = tuple[float, float, float]
"""(left radius, right radius, wheelbase), m."""


def _move(pose: tuple[float, float, float], left: float, right: float, wheelbase: float) -> tuple[float, float, float]:
    """The exact motion of wheels that travel ``left`` and ``right`` metres at constant speeds."""
    x, y, theta = pose
    turn = (right - left) / wheelbase
    mean = (right + left) / 2.0
    chord = mean if turn == 0.0 else 2.0 * mean / turn * math.sin(turn / 2.0)
    return x + chord * math.cos(theta + turn / 2.0), y + chord * math.sin(theta + turn / 2.0), theta + turn


def drive_square(side: float, direction: Direction, true: Wheels, believed: Wheels) -> Point:
    """The return position error of the ideal robot with ``true`` wheels whose odometry takes
    ``believed`` ones, driven round the square (4 legs, turning on the spot between them)."""
    (true_left, true_right, true_base), (left, right, base) = true, believed
    pose = (0.0, 0.0, 0.0)
    for leg in range(4):
        if leg:
            arc = direction.turn * (math.pi / 2.0) * base / 2.0  # each wheel's travel, as the odometry sees it
            pose = _move(pose, true_left * (-arc / left), true_right * (arc / right), true_base)
        pose = _move(pose, true_left * (side / left), true_right * (side / right), true_base)
    return return_error((pose[0], pose[1]), (0.0, 0.0))


def true_wheels(ed: float, eb: float, radius: float, wheelbase: float) -> Wheels:
    """Wheels whose diameter ratio D_R/D_L is ``ed`` and wheelbase ``eb`` times ``wheelbase``, the
    mean radius ``radius`` (UMBmark cannot see a common scale)."""
    left = 2.0 * radius / (ed + 1.0)
    return left, left * ed, wheelbase * eb


def benchmark(side: float, true: Wheels, calibration: Calibration, radius: float, wheelbase: float) -> Umbmark:
    """One run each way of the ideal robot whose odometry takes the nominal ``radius`` and
    ``wheelbase`` under ``calibration``, evaluated."""
    believed = (
        radius * calibration.left_radius_scale,
        radius * calibration.right_radius_scale,
        wheelbase * calibration.axle_scale,
    )
    return evaluate(
        side,
        believed[2],
        [drive_square(side, Direction.CW, true, believed)],
        [drive_square(side, Direction.CCW, true, believed)],
    )


def test_the_square_starts_along_x_and_turns_left_counter_clockwise_right_clockwise():
    assert square(2.0, Direction.CCW) == [(2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)]
    assert square(2.0, Direction.CW) == [(2.0, 0.0), (2.0, -2.0), (0.0, -2.0), (0.0, 0.0)]


def test_a_perfect_robot_returns_to_its_start_and_needs_no_correction():
    true = (0.1, 0.1, 0.441)
    result = benchmark(4.0, true, Calibration(), 0.1, 0.441)
    assert result.e_max_syst < 1e-12
    assert result.ed == pytest.approx(1.0, abs=1e-12) and result.eb == pytest.approx(1.0, abs=1e-12)
    assert result.correction.deviation() < 1e-12 and math.isinf(result.radius)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_longer_wheelbase_turns_short_and_a_larger_right_wheel_curves_left(sign: float):
    """The signs of this frame: α > 0 is each turn short (the wheelbase longer than the odometry
    takes), β > 0 each leg curved left (the right wheel the larger), as the paper's formulas read."""
    wheelbase_only = benchmark(4.0, (0.1, 0.1, 0.441 * (1.0 + sign * 1e-3)), Calibration(), 0.1, 0.441)
    assert math.copysign(1.0, wheelbase_only.alpha) == sign and abs(wheelbase_only.beta) < 1e-12
    assert math.copysign(1.0, wheelbase_only.eb - 1.0) == sign
    radius_only = benchmark(4.0, (0.1, 0.1 * (1.0 + sign * 1e-4), 0.441), Calibration(), 0.1, 0.441)
    assert math.copysign(1.0, radius_only.beta) == sign and math.copysign(1.0, radius_only.ed - 1.0) == sign
    assert math.copysign(1.0, radius_only.correction.right_radius_scale - 1.0) == sign
    assert math.copysign(1.0, radius_only.radius) == sign


deviation = st.floats(1e-5, 1e-3).flatmap(lambda size: st.sampled_from([size, -size]))


@settings(max_examples=200, deadline=None)
@given(
    ed_deviation=deviation,
    eb_deviation=deviation,
    side=st.floats(1.0, 10.0),
    wheelbase=st.floats(0.2, 0.6),
    radius=st.floats(0.03, 0.3),
)
def test_an_ideal_robot_with_small_errors_gives_them_back(
    ed_deviation: float, eb_deviation: float, side: float, wheelbase: float, radius: float
):
    """The first-order formulas return Ed and Eb within 20 % of the injected deviation, up to the
    second-order terms of the angles they neglect (each turn short by α, each leg curved by β)."""
    ed, eb = 1.0 + ed_deviation, 1.0 + eb_deviation
    true = true_wheels(ed, eb, radius, wheelbase)
    result = benchmark(side, true, Calibration(), radius, wheelbase)
    alpha = math.pi / 2.0 * (1.0 - 1.0 / eb)
    beta = (true[1] - true[0]) * side / radius / true[2]  # the heading a leg turns by
    second_order = 2.0 * (alpha**2 + beta**2)
    assert abs(result.ed - ed) <= 0.2 * abs(ed - 1.0) + second_order
    assert abs(result.eb - eb) <= 0.2 * abs(eb - 1.0) + second_order


def calibrate_ideal(side: float, true: Wheels, passes: int) -> tuple[Calibration, float, list[float]]:
    """The tool's procedure on the ideal robot: benchmark, correct, benchmark again, up to ``passes``
    corrections while the next would change a multiplier by CONVERGED or more. (calibration, E_max
    before, E_max after each pass)."""
    radius, wheelbase = 0.1, 0.441
    calibration = Calibration()
    result = benchmark(side, true, calibration, radius, wheelbase)
    before, after = result.e_max_syst, []
    for _ in range(passes):
        calibration = calibration.then(result.correction)
        result = benchmark(side, true, calibration, radius, wheelbase)
        after.append(result.e_max_syst)
        if result.correction.deviation() < CONVERGED:
            break
    return calibration, before, after


radius_error = st.floats(0.003, 0.01).flatmap(lambda size: st.sampled_from([size, -size]))
axle_error = st.floats(0.01, 0.03).flatmap(lambda size: st.sampled_from([size, -size]))


@settings(max_examples=100, deadline=None)
@given(radius_error=radius_error, axle_error=axle_error, right=st.booleans(), side=st.floats(1.0, 4.0))
def test_at_most_two_passes_correct_the_issues_errors_tenfold(
    radius_error: float, axle_error: float, right: bool, side: float
):
    """One wheel 0.3-1 % off, the axle 1-3 % off, either way: within two passes E_max,syst falls
    tenfold and the corrections hold Ed within 20 % of its deviation, Eb (relative to the mean
    radius, all UMBmark can see of it) too."""
    left_radius, right_radius = (0.1, 0.1 * (1.0 + radius_error)) if right else (0.1 * (1.0 + radius_error), 0.1)
    true = (left_radius, right_radius, 0.441 * (1.0 + axle_error))
    calibration, before, after = calibrate_ideal(side, true, passes=2)
    assert after[-1] <= before / 10.0
    ed_true = right_radius / left_radius
    eb_seen = (1.0 + axle_error) / ((left_radius + right_radius) / 0.2)
    ed = calibration.right_radius_scale / calibration.left_radius_scale
    assert abs(ed - ed_true) <= 0.2 * abs(ed_true - 1.0)
    assert abs(calibration.axle_scale - eb_seen) <= 0.2 * abs(eb_seen - 1.0)


def test_the_papers_wheel_factors_taken_as_written_make_the_curve_worse_in_this_frame():
    """c_L = 2/(1/Ed + 1) on the left wheel (the paper's letters) with Ed = D_R/D_L computed here
    grows the smaller wheel: the square's error grows instead of shrinking."""
    true = true_wheels(1.003, 1.0, 0.1, 0.441)
    before = benchmark(4.0, true, Calibration(), 0.1, 0.441)
    ours = before.correction
    papers = Calibration(ours.right_radius_scale, ours.left_radius_scale, ours.axle_scale)
    assert benchmark(4.0, true, ours, 0.1, 0.441).e_max_syst < before.e_max_syst / 10.0
    assert benchmark(4.0, true, papers, 0.1, 0.441).e_max_syst > before.e_max_syst


# The worked example of docs/odometry.md: a 4 m square, the default robot (b = 0.441 m), 5 runs each way.
WORKED_CW = [(-0.112, -0.095), (-0.097, -0.108), (-0.105, -0.099), (-0.090, -0.093), (-0.096, -0.105)]
WORKED_CCW = [(0.034, -0.027), (0.025, -0.036), (0.031, -0.029), (0.028, -0.030), (0.032, -0.028)]


def test_the_worked_example_by_hand():
    # centres of gravity: the sums are -0.500, -0.500 and 0.150, -0.150 over 5 runs
    x_cw, y_cw, x_ccw, y_ccw = -0.100, -0.100, 0.030, -0.030
    alpha = (x_cw + x_ccw) / (-4 * 4.0)  # -0.070 / -16
    assert alpha == pytest.approx(0.004375)
    beta = (x_cw - x_ccw) / (-4 * 4.0)  # -0.130 / -16
    assert beta == pytest.approx(0.008125)
    # R = (L/2)/sin(β/2) = 2/sin(0.0040625) = 2/0.00406249 = 492.309 m
    # Ed = (R + b/2)/(R − b/2) = 492.5295/492.0885 = 1.000896
    # Eb = (π/2)/(π/2 − α) = 1.570796/1.566421 = 1.002793
    # right = 2/(1/Ed + 1) = 1.000448, left = 2/(Ed + 1) = 0.999552
    # E_max,syst = max(√(0.1² + 0.1²), √(0.03² + 0.03²)) = 0.141421 m
    result = evaluate(4.0, 0.441, WORKED_CW, WORKED_CCW)
    assert result.cg_cw == pytest.approx((x_cw, y_cw)) and result.cg_ccw == pytest.approx((x_ccw, y_ccw))
    assert result.alpha == pytest.approx(0.004375) and result.beta == pytest.approx(0.008125)
    assert result.radius == pytest.approx(492.309, abs=1e-3)
    assert result.ed == pytest.approx(1.000896, abs=1e-6) and result.eb == pytest.approx(1.002793, abs=1e-6)
    assert result.correction.right_radius_scale == pytest.approx(1.000448, abs=1e-6)
    assert result.correction.left_radius_scale == pytest.approx(0.999552, abs=1e-6)
    assert result.correction.axle_scale == pytest.approx(1.002793, abs=1e-6)
    assert result.e_max_syst == pytest.approx(0.141421, abs=1e-6)


def test_a_calibration_composes_with_the_one_it_corrects():
    start = Calibration.of(OdometryConfig(left_radius_scale=1.01, right_radius_scale=0.99, axle_scale=1.05))
    corrected = start.then(correction(1.002, 0.98))
    assert corrected.left_radius_scale == pytest.approx(1.01 * 2.0 / 2.002)
    assert corrected.right_radius_scale == pytest.approx(0.99 * 2.0 / (1.0 / 1.002 + 1.0))
    assert corrected.axle_scale == pytest.approx(1.05 * 0.98)
    assert corrected.overrides() == {
        "odometry.left_radius_scale": corrected.left_radius_scale,
        "odometry.right_radius_scale": corrected.right_radius_scale,
        "odometry.axle_scale": corrected.axle_scale,
    }


@settings(max_examples=100, deadline=None)
@given(ed=st.floats(0.9, 1.1))
def test_the_wheel_corrections_keep_the_mean_radius_and_take_the_ratio(ed: float):
    wheels = correction(ed, 1.0)
    assert (wheels.left_radius_scale + wheels.right_radius_scale) / 2.0 == pytest.approx(1.0)
    assert wheels.right_radius_scale / wheels.left_radius_scale == pytest.approx(ed)


def test_centre_of_gravity_and_return_error():
    assert centre_of_gravity([(1.0, 2.0), (3.0, -4.0)]) == (2.0, -1.0)
    assert return_error((0.5, -0.25), (0.125, 0.25)) == (0.375, -0.5)
    with pytest.raises(ValueError, match="no return positions"):
        centre_of_gravity([])


@pytest.mark.parametrize(
    ("side", "wheelbase", "cw", "ccw", "reason"),
    [
        (0.0, 0.441, [(0.0, 0.0)], [(0.0, 0.0)], "side must be a positive length"),
        (4.0, -1.0, [(0.0, 0.0)], [(0.0, 0.0)], "wheelbase must be a positive length"),
        (4.0, 0.441, [], [(0.0, 0.0)], "no cw return positions"),
        (4.0, 0.441, [(math.nan, 0.0)], [(0.0, 0.0)], "cw return position is not finite"),
        (4.0, 0.441, [(-20.0, 0.0)], [(-20.0, 0.0)], "are they in metres"),
        (0.1, 0.441, [(-0.4, 0.0)], [(0.4, 0.0)], "tighter than half the wheelbase"),
    ],
)
def test_input_the_formulas_cannot_take_is_refused_saying_why(side, wheelbase, cw, ccw, reason):
    with pytest.raises(ValueError, match=reason):
        evaluate(side, wheelbase, cw, ccw)


def test_a_measured_toml_file_gives_the_errors_of_its_runs():
    measured = parse_measured_toml(
        "side = 4.0\n"
        "cw = [{ x = -0.112, y = -0.095 }, { x = -0.097, y = -0.108 }]\n"
        "[[ccw]]\nx = 0.034\ny = -0.027\nodometry_x = 0.004\nodometry_y = -0.002\n",
        "runs.toml",
    )
    assert measured.side == 4.0
    assert measured.errors[Direction.CW] == [(-0.112, -0.095), (-0.097, -0.108)]
    assert measured.errors[Direction.CCW] == [pytest.approx((0.030, -0.025))]


def test_a_measured_csv_file_gives_the_errors_of_its_runs():
    measured = parse_measured_csv(
        "# the tape's\ndirection,x,y,odometry_x,odometry_y\ncw,-0.112,-0.095,0,0\n\nCCW,0.034,-0.027,0.004,-0.002\n",
        "runs.csv",
    )
    assert measured.side is None
    assert measured.errors == {Direction.CW: [(-0.112, -0.095)], Direction.CCW: [pytest.approx((0.030, -0.025))]}
    short = parse_measured_csv("direction,x,y\ncw,1,2\nccw,3,4\n", "runs.csv")
    assert short.errors == {Direction.CW: [(1.0, 2.0)], Direction.CCW: [(3.0, 4.0)]}


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("cw = [{ x = 1.0, y = 0.0 }]\n", "ccw"),
        ("cw = []\nccw = [{ x = 1.0, y = 0.0 }]\n", "cw"),
        ("side = -1.0\ncw = [{ x = 1.0, y = 0.0 }]\nccw = [{ x = 1.0, y = 0.0 }]\n", "side"),
        ("cw = [{ x = 1.0, y = 0.0, z = 1.0 }]\nccw = [{ x = 1.0, y = 0.0 }]\n", "z"),
        ("cw = [{ x = nan, y = 0.0 }]\nccw = [{ x = 1.0, y = 0.0 }]\n", "finite"),
        ("cw = [{ x = 1.0 y = 0.0 }]\n", "runs.toml"),
    ],
)
def test_a_bad_toml_file_is_a_config_error_naming_what(text: str, reason: str):
    with pytest.raises(ConfigError, match=reason):
        parse_measured_toml(text, "runs.toml")


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("", "empty"),
        ("dir,x,y\ncw,1,2\n", "line 1: the columns must be"),
        ("direction,x,y\ncw,1,2\nup,1,2\n", "line 3: direction 'up' must be cw or ccw"),
        ("direction,x,y\ncw,1,two\n", "line 2: 1,two must be numbers"),
        ("direction,x,y\ncw,1,inf\nccw,1,2\n", "line 2: the values must be finite"),
        ("direction,x,y\ncw,1\n", "line 2: 2 values, expected 3"),
        ("direction,x,y\ncw,1,2\n", "no ccw runs"),
    ],
)
def test_a_bad_csv_file_is_a_config_error_naming_the_line(text: str, reason: str):
    with pytest.raises(ConfigError, match=reason):
        parse_measured_csv(text, "runs.csv")
