"""The odometry core (docs/protocol.md section 5) against hand-computed values and analytic motion
(tests/test_odometry_core_fixes.py: fixes, bad input, properties)."""

from __future__ import annotations

import math

import pytest

from services.config import CalibratedGeometry, Config, InputConfig, load_config
from services.odometry.core import Branch, Odometry, Step, wrap_angle
from services.planar import Pose

NS = 1_000_000_000
SMALL_ANGLE_TOLERANCE_PER_METRE = 2e-5
"""The bound of the small-angle branch (arc length for chord): border²/24 = 1.3e-5 < 2e-5."""
CHORD_TOLERANCE = 1e-9
DEFAULT_BORDER = math.pi / 180.0


def parameters(**overrides: float | str) -> Config:
    """The robot description; ``overrides`` use dotted config keys with '__' for '.'."""
    return load_config(overrides={key.replace("__", "."): value for key, value in overrides.items()})


def calibrated(p: Config) -> CalibratedGeometry:
    return CalibratedGeometry.of(p.robot, p.odometry)


ANY_INPUT = InputConfig(stamp_horizon=1e9, max_wheel_speed=1e300)
"""The integration is tested on whatever input reaches it; the input policy has tests of its own."""


def law_odometry(parameters: Config, start: Pose = Pose(0.0, 0.0, 0.0)) -> Odometry:
    return Odometry(parameters.robot, parameters.odometry, start, ANY_INPUT)


def simple() -> Config:
    """r = 0.1 m both wheels, b = 0.2 m: easy numbers to compute by hand."""
    return parameters(robot__length_of_axle=0.4)


def angle_error(a: float, b: float) -> float:
    return abs(wrap_angle(a - b))


def analytic_pose(start: Pose, v: float, omega: float, duration: float) -> Pose:
    """Exact pose after ``duration`` s at constant (v, omega): the chord in the mean heading.

    Written with sin(h)/h so that it stays exact as omega -> 0 (no R = v/omega cancellation).
    """
    half = omega * duration / 2.0
    chord = v * duration * (math.sin(half) / half if half != 0.0 else 1.0)
    heading = start.theta + half
    return Pose(
        start.x + chord * math.cos(heading),
        start.y + chord * math.sin(heading),
        wrap_angle(start.theta + omega * duration),
    )


def body_velocity(p: Config, left_rate: float, right_rate: float) -> tuple[float, float]:
    """(V, Omega) of wheels turning at ``left_rate``, ``right_rate`` rad/s."""
    g = calibrated(p)
    v_left, v_right = g.left_radius * left_rate, g.right_radius * right_rate
    return (v_right + v_left) / 2.0, (v_right - v_left) / (2.0 * g.half_axle)


def drive(
    odometry: Odometry, start: Pose, left_rate: float, right_rate: float, duration_ns: int, steps: int
) -> list[Step]:
    """Constant wheel rates for ``duration_ns`` in ``steps`` samples, from ``start``, in steady motion.

    A warm-up step at the same rates first (then a reset to ``start``) sets V_old = V, as for
    a robot already moving (only the seed's straight trapezoid reads V_old).
    """
    warm_up_ns = NS
    odometry.step(0, [-left_rate, -right_rate])
    odometry.step(warm_up_ns, [0.0, 0.0])
    odometry.reset(*start)
    taken = []
    for k in range(1, steps + 1):
        elapsed_ns = k * duration_ns // steps
        seconds = elapsed_ns / NS
        taken.append(odometry.step(warm_up_ns + elapsed_ns, [left_rate * seconds, right_rate * seconds]))
    return taken


def assert_pose_close(actual: Pose, expected: Pose, tolerance: float) -> None:
    distance = math.hypot(actual.x - expected.x, actual.y - expected.y)
    assert distance <= tolerance, f"{actual} is {distance} m from {expected} (tolerance {tolerance})"
    assert angle_error(actual.theta, expected.theta) <= 1e-9, f"{actual} heading differs from {expected}"


# --- wrap ------------------------------------------------------------------------------------------


# --- parameters ------------------------------------------------------------------------------------


def test_parameters_come_from_the_robot_description_with_calibration() -> None:
    p = parameters(
        robot__radius_of_left_wheel=0.2,
        robot__radius_of_right_wheel=0.3,
        robot__length_of_axle=0.5,
        odometry__left_radius_scale=1.5,
        odometry__right_radius_scale=0.5,
        odometry__axle_scale=2.0,
    )
    assert calibrated(p) == pytest.approx((0.3, 0.15, 0.5))


def test_default_parameters_are_the_seeds() -> None:
    p = parameters()
    assert (p.robot.left_wheel_id, p.robot.right_wheel_id) == (0, 1)
    assert calibrated(p) == (0.1, 0.1, 0.2205)
    assert p.odometry.rotation_angle_border == DEFAULT_BORDER
    assert p.odometry.rho_border == 10000.0


# --- first sample, hand-computed steps ---------------------------------------------------------


def test_first_sample_initialises_and_reports_the_starting_pose() -> None:
    odometry = law_odometry(simple())
    assert not odometry.initialised
    first = odometry.step(5 * NS, [3.0, 7.0])
    assert first.branch is Branch.INITIAL
    assert first.pose == Pose(0.0, 0.0, 0.0)
    assert odometry.initialised
    assert odometry.velocity == (0.0, 0.0)
    # The angles of the first sample are the reference: no motion yet, so nothing moves.
    assert odometry.step(6 * NS, [3.0, 7.0]).pose == Pose(0.0, 0.0, 0.0)


def test_localized_pose_before_the_first_sample_is_the_starting_pose() -> None:
    odometry = law_odometry(simple())
    odometry.reset(1.0, -2.0, 0.5)
    assert odometry.step(0, [0.0, 0.0]).pose == Pose(1.0, -2.0, 0.5)


def test_chord_step_by_hand() -> None:
    # r = 0.1, b = 0.2, dt = 0.1: vL = 1, vR = 3, V = 2, Omega = 5, dphi = 0.5, rho = 0.4.
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    step = odometry.step(NS // 10, [1.0, 3.0])
    assert step.branch is Branch.CHORD
    assert (step.dt, step.v_left, step.v_right, step.v, step.omega) == pytest.approx((0.1, 1.0, 3.0, 2.0, 5.0))
    assert (step.dphi, step.rho) == pytest.approx((0.5, 0.4))
    chord = 2 * 0.4 * math.sin(0.25)
    assert step.dl == pytest.approx(chord)
    assert step.pose == pytest.approx((chord * math.cos(0.25), chord * math.sin(0.25), 0.5))
    assert odometry.velocity == pytest.approx((2.0, 5.0))


def test_small_angle_step_by_hand() -> None:
    # dt = 1: vL = 0.1, vR = 0.101, Omega = 0.0025 rad/s, dphi = 0.0025 < pi/180, rho = 40.2.
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    step = odometry.step(NS, [1.0, 1.01])
    assert step.branch is Branch.SMALL_ANGLE
    assert (step.dphi, step.rho) == pytest.approx((0.0025, 40.2))
    assert step.dl == pytest.approx(40.2 * 0.0025)
    assert step.pose == pytest.approx((0.1005 * math.cos(0.00125), 0.1005 * math.sin(0.00125), 0.0025))


def test_straight_step_is_the_mean_wheel_travel() -> None:
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    first = odometry.step(NS, [2.0, 2.0])  # r = 0.1: each wheel travels 0.2 m
    assert first.branch is Branch.STRAIGHT
    assert first.rho is None
    assert first.dl == pytest.approx(0.2)
    second = odometry.step(2 * NS, [6.0, 6.0])  # 0.4 m more
    assert second.dl == pytest.approx(0.4)
    assert second.pose == pytest.approx((0.6, 0.0, 0.0))


def test_seed_straight_step_is_the_trapezoid_of_v_and_v_old() -> None:
    odometry = law_odometry(parameters(robot__length_of_axle=0.4, odometry__straight_step="seed"))
    odometry.step(0, [0.0, 0.0])
    first = odometry.step(NS, [2.0, 2.0])  # V = 0.2, V_old = 0 (at rest before)
    assert first.branch is Branch.STRAIGHT
    assert first.dl == pytest.approx(0.1)
    second = odometry.step(2 * NS, [6.0, 6.0])  # V = 0.4, V_old = 0.2
    assert second.dl == pytest.approx(0.3)
    assert second.pose == pytest.approx((0.4, 0.0, 0.0))


def test_wheels_are_picked_by_their_ids() -> None:
    odometry = law_odometry(parameters(robot__left_wheel_id=2, robot__right_wheel_id=0, robot__length_of_axle=0.4))
    odometry.step(0, [0.0, 99.0, 0.0])
    step = odometry.step(NS // 10, [3.0, -50.0, 1.0])  # left = data[2] = 1, right = data[0] = 3
    assert (step.q_left, step.q_right) == (1.0, 3.0)
    assert (step.v_left, step.v_right) == pytest.approx((1.0, 3.0))


def test_calibration_multipliers_scale_radii_and_axle() -> None:
    odometry = law_odometry(
        parameters(
            robot__length_of_axle=0.4,
            odometry__left_radius_scale=2.0,
            odometry__right_radius_scale=0.5,
            odometry__axle_scale=1.25,
        )
    )
    odometry.step(0, [0.0, 0.0])
    step = odometry.step(NS, [1.0, 4.0])
    # r_L = 0.2, r_R = 0.05, b = 0.25: vL = vR = 0.2, so straight; V = 0.2.
    assert (step.v_left, step.v_right, step.omega) == pytest.approx((0.2, 0.2, 0.0))
    spin = odometry.step(2 * NS, [0.0, 8.0])  # vL = -0.2, vR = 0.2: Omega = 0.4 / 0.5
    assert spin.omega == pytest.approx(0.8)


# --- analytic motion -------------------------------------------------------------------------------


def test_straight_line_from_rest_is_exact() -> None:
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    dt_ns, rate = NS // 100, 2.0  # V = 0.2 m/s
    for k in range(1, 101):
        step = odometry.step(k * dt_ns, [rate * k / 100, rate * k / 100])
        assert step.branch is Branch.STRAIGHT
    assert odometry.pose.x == pytest.approx(0.2, rel=1e-9)
    assert (odometry.pose.y, odometry.pose.theta) == (0.0, 0.0)


def test_seed_straight_line_from_rest_loses_half_a_first_step() -> None:
    odometry = law_odometry(parameters(robot__length_of_axle=0.4, odometry__straight_step="seed"))
    odometry.step(0, [0.0, 0.0])
    dt_ns, rate = NS // 100, 2.0
    for k in range(1, 101):
        odometry.step(k * dt_ns, [rate * k / 100, rate * k / 100])
    # The trapezoid with V_old = 0 on the first step: x = V (T - dt/2).
    assert odometry.pose == pytest.approx((0.2 * (1.0 - 0.005), 0.0, 0.0), abs=1e-12)


def test_straight_line_is_exact_when_speed_and_dt_change_together() -> None:
    """0.2 m/s on 1 ms steps alternating with 0.6 m/s on 3 ms steps, 3.0 m in all: the seed's
    trapezoid drifted 0.60 m here."""
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    time_ns, angle, travelled = 0, 0.0, 0.0
    for k in range(2000):
        slow = k % 2 == 0
        dt_ns, speed = (1_000_000, 0.2) if slow else (3_000_000, 0.6)
        time_ns += dt_ns
        angle += speed * dt_ns / NS / 0.1
        travelled += speed * dt_ns / NS
        step = odometry.step(time_ns, [angle, angle])
        assert step.branch is Branch.STRAIGHT
    assert travelled == pytest.approx(2.0)
    assert odometry.pose.x == pytest.approx(travelled, rel=1e-9)


def test_a_fix_with_the_wheels_still_stays_where_it_was_put() -> None:
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    odometry.step(NS // 100, [0.1, 0.1])  # moving at 1 m/s just before the fix
    odometry.reset(2.0, 3.0, 0.5)
    for k in range(2, 12):
        assert odometry.step(k * NS // 100, [0.1, 0.1]).pose == Pose(2.0, 3.0, 0.5)


def test_straight_line_in_steady_motion_is_exact() -> None:
    start = Pose(1.0, 2.0, 0.7)
    steps = drive(law_odometry(simple()), start, 3.0, 3.0, 2 * NS, 200)
    assert {s.branch for s in steps} == {Branch.STRAIGHT}
    assert_pose_close(steps[-1].pose, analytic_pose(start, 0.3, 0.0, 2.0), 1e-12)


def test_arc_in_small_angle_steps_is_within_the_arc_length_bound() -> None:
    p = simple()
    left, right = 4.0, 5.0  # V = 0.45 m/s, Omega = 0.25 rad/s, rho = 1.8 m
    v, omega = body_velocity(p, left, right)
    duration = 10.0
    steps = drive(law_odometry(p), Pose(0.0, 0.0, 0.0), left, right, int(duration * NS), 500)
    assert {s.branch for s in steps} == {Branch.SMALL_ANGLE}
    assert_pose_close(
        steps[-1].pose, analytic_pose(Pose(0, 0, 0), v, omega, duration), SMALL_ANGLE_TOLERANCE_PER_METRE * v * duration
    )


def test_arc_in_chord_steps_is_exact() -> None:
    p = simple()
    left, right = 2.0, 8.0  # V = 0.5 m/s, Omega = 1.5 rad/s: 0.03 rad (> pi/180) per 20 ms step
    v, omega = body_velocity(p, left, right)
    start = Pose(-1.0, 0.5, 3.0)
    steps = drive(law_odometry(p), start, left, right, 5 * NS, 250)
    assert {s.branch for s in steps} == {Branch.CHORD}
    assert_pose_close(steps[-1].pose, analytic_pose(start, v, omega, 5.0), CHORD_TOLERANCE)


def test_spin_in_place_turns_without_moving_and_wraps() -> None:
    p = simple()
    odometry = law_odometry(p)
    steps = drive(odometry, Pose(0.5, 0.5, 0.0), -4.0, 4.0, 3 * NS, 300)  # Omega = 2 rad/s for 3 s
    assert {s.rho for s in steps} == {0.0}
    assert odometry.pose.x == 0.5 and odometry.pose.y == 0.5
    assert odometry.pose.theta == pytest.approx(6.0 - 2 * math.pi, abs=1e-9)


def test_reverse_straight_and_reverse_arc() -> None:
    p = simple()
    straight = drive(law_odometry(p), Pose(0.0, 0.0, 0.0), -2.0, -2.0, NS, 100)
    assert_pose_close(straight[-1].pose, Pose(-0.2, 0.0, 0.0), 1e-12)
    left, right = -2.0, -8.0
    v, omega = body_velocity(p, left, right)
    assert v < 0
    start = Pose(0.0, 0.0, 0.3)
    arc = drive(law_odometry(p), start, left, right, 4 * NS, 200)
    assert {s.branch for s in arc} == {Branch.CHORD}
    assert_pose_close(arc[-1].pose, analytic_pose(start, v, omega, 4.0), CHORD_TOLERANCE)


# --- branch boundaries -----------------------------------------------------------------------------


def step_with(p: Config, dphi: float, rho: float, dt: float = 0.01) -> Step:
    """One step (after a first sample) whose wheel increments give ``dphi`` and ``rho``."""
    g = calibrated(p)
    b = g.half_axle
    difference = 2.0 * b * dphi / dt  # vR - vL
    total = rho * difference / b  # vR + vL
    v_left, v_right = (total - difference) / 2.0, (total + difference) / 2.0
    odometry = law_odometry(p)
    odometry.step(0, [0.0, 0.0])
    return odometry.step(round(dt * NS), [v_left * dt / g.left_radius, v_right * dt / g.right_radius])


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_dphi_just_under_the_border_takes_arc_length(sign: float) -> None:
    step = step_with(simple(), sign * DEFAULT_BORDER * (1 - 1e-6), rho=2.0)
    assert abs(step.dphi) < DEFAULT_BORDER
    assert step.branch is Branch.SMALL_ANGLE
    assert step.dl == pytest.approx(step.rho * step.dphi, rel=1e-15)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_dphi_just_over_the_border_takes_the_chord(sign: float) -> None:
    step = step_with(simple(), sign * DEFAULT_BORDER * (1 + 1e-6), rho=2.0)
    assert abs(step.dphi) > DEFAULT_BORDER
    assert step.branch is Branch.CHORD
    assert step.dl == pytest.approx(2 * step.rho * math.sin(step.dphi / 2), rel=1e-15)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_rho_just_under_the_border_integrates_the_arc(sign: float) -> None:
    step = step_with(simple(), 1e-6, rho=sign * 10000.0 * (1 - 1e-6))
    assert abs(step.rho) < 10000.0
    assert step.branch is Branch.SMALL_ANGLE


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_rho_just_over_the_border_is_clamped_and_integrates_straight(sign: float) -> None:
    step = step_with(simple(), 1e-6, rho=sign * 10000.0 * (1 + 1e-6))
    assert step.branch is Branch.RHO_BORDER
    assert step.rho == sign * 10000.0
    assert step.dl == pytest.approx(step.v * step.dt, rel=1e-12)  # the mean wheel travel
    assert step.theta == pytest.approx(step.dphi)  # the heading still turns


def test_borders_come_from_the_parameters() -> None:
    p = parameters(robot__length_of_axle=0.4, odometry__rotation_angle_border=0.1, odometry__rho_border=5.0)
    assert step_with(p, 0.09, rho=2.0).branch is Branch.SMALL_ANGLE
    assert step_with(p, 0.11, rho=2.0).branch is Branch.CHORD
    assert step_with(p, 0.05, rho=5.1).branch is Branch.RHO_BORDER
