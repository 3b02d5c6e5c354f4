"""The odometry core (docs/protocol.md section 5) against hand-computed values and analytic motion."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput
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


# --- localization reset ----------------------------------------------------------------------------


def test_localized_pose_overwrites_the_pose_before_the_next_step() -> None:
    p = simple()
    odometry = law_odometry(p)
    odometry.step(0, [0.0, 0.0])
    odometry.step(NS // 10, [1.0, 3.0])
    assert odometry.reset(5.0, -1.0, 3.0 * math.pi) == Pose(5.0, -1.0, math.pi)
    assert odometry.pose == Pose(5.0, -1.0, math.pi)
    step = odometry.step(2 * NS // 10, [2.0, 6.0])  # the same chord step as the first one
    v, omega = body_velocity(p, 10.0, 30.0)
    assert_pose_close(step.pose, analytic_pose(Pose(5.0, -1.0, math.pi), v, omega, 0.1), CHORD_TOLERANCE)


def test_localized_pose_must_be_finite() -> None:
    odometry = law_odometry(simple())
    for bad in [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, -math.inf)]:
        with pytest.raises(BadInput, match="not finite"):
            odometry.reset(*bad)
    assert odometry.pose == Pose(0.0, 0.0, 0.0)


# --- a restarted simulator ------------------------------------------------------------------------


def test_restart_time_base_initialises_again_from_the_kept_pose() -> None:
    odometry = law_odometry(simple())
    odometry.step(0, [0.0, 0.0])
    odometry.step(NS, [2.0, 2.0])  # x = 0.2
    odometry.step(2 * NS, [4.0, 4.0])  # x = 0.4
    with pytest.raises(BadInput, match="<= 0"):
        odometry.step(0, [0.0, 0.0])
    odometry.restart_time_base()
    assert not odometry.initialised and odometry.time_ns is None and odometry.velocity == (0.0, 0.0)
    first = odometry.step(0, [50.0, -7.0])
    assert first.branch is Branch.INITIAL and first.pose == pytest.approx((0.4, 0.0, 0.0))
    # the new angles are the new reference: 2 rad more on each wheel is 0.2 m
    step = odometry.step(NS, [52.0, -5.0])
    assert step.dl == pytest.approx(0.2) and step.pose == pytest.approx((0.6, 0.0, 0.0))


def test_restart_time_base_before_any_sample_changes_nothing() -> None:
    odometry = law_odometry(simple())
    odometry.reset(1.0, 2.0, 0.5)
    odometry.restart_time_base()
    assert odometry.step(7 * NS, [1.0, 1.0]).pose == Pose(1.0, 2.0, 0.5)


# --- bad input leaves the state unchanged ----------------------------------------------------------


@pytest.mark.parametrize(
    ("time_ns", "angles", "reason"),
    [
        (NS, [5.0, 5.0], "dt = 0 s <= 0"),
        (NS // 2, [5.0, 5.0], "dt = -0.5 s <= 0"),
        (2 * NS, [5.0], "need at least 2"),
        (2 * NS, [], "need at least 2"),
        (2 * NS, [math.nan, 1.0], "not finite"),
        (2 * NS, [1.0, math.inf], "not finite"),
        (NS + 1, [1e308, -1e308], "wheel speeds"),
    ],
)
def test_bad_sample_is_rejected_and_changes_nothing(time_ns: int, angles: list[float], reason: str) -> None:
    p = simple()
    odometry, reference = law_odometry(p), law_odometry(p)
    for o in (odometry, reference):
        o.step(0, [0.0, 0.0])
        o.step(NS, [1.0, 3.0])
    with pytest.raises(BadInput, match=reason):
        odometry.step(time_ns, angles)
    assert odometry.step(3 * NS, [2.0, 5.0]) == reference.step(3 * NS, [2.0, 5.0])


def test_short_sample_for_high_wheel_ids_is_rejected() -> None:
    odometry = law_odometry(parameters(robot__left_wheel_id=4, robot__right_wheel_id=1))
    with pytest.raises(BadInput, match="4 wheel angles, wheel ids 4 and 1 need at least 5"):
        odometry.step(0, [0.0] * 4)
    assert not odometry.initialised


# --- properties ------------------------------------------------------------------------------------

wheel_rates = st.floats(min_value=-20.0, max_value=20.0, allow_subnormal=False)
coordinates = st.floats(min_value=-100.0, max_value=100.0)
headings = st.floats(min_value=-math.pi, max_value=math.pi)


@settings(max_examples=150, deadline=None)
@given(
    left=wheel_rates,
    right=wheel_rates,
    duration_ms=st.integers(min_value=10, max_value=5000),
    steps=st.integers(min_value=2, max_value=300),
    start=st.builds(Pose, coordinates, coordinates, headings),
    geometry=st.tuples(
        st.floats(min_value=0.03, max_value=0.5),
        st.floats(min_value=0.03, max_value=0.5),
        st.floats(min_value=0.1, max_value=1.0),
    ),
)
def test_constant_curvature_in_n_steps_or_one_lands_on_the_same_pose(
    left: float, right: float, duration_ms: int, steps: int, start: Pose, geometry: tuple[float, float, float]
) -> None:
    p = parameters(
        robot__radius_of_left_wheel=geometry[0],
        robot__radius_of_right_wheel=geometry[1],
        robot__length_of_axle=geometry[2],
    )
    v, omega = body_velocity(p, left, right)
    duration_ns = duration_ms * 1_000_000
    travelled = abs(v) * duration_ms / 1000
    tolerance = SMALL_ANGLE_TOLERANCE_PER_METRE * travelled + CHORD_TOLERANCE
    expected = analytic_pose(start, v, omega, duration_ns / NS)
    many = drive(law_odometry(p), start, left, right, duration_ns, steps)[-1].pose
    one = drive(law_odometry(p), start, left, right, duration_ns, 1)[-1].pose
    assert_pose_close(many, expected, tolerance)
    assert_pose_close(one, expected, tolerance)
    assert_pose_close(many, one, tolerance)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.tuples(st.just("step"), st.integers(1, 10**9), st.floats(-50, 50), st.floats(-50, 50)),
            st.tuples(st.just("reset"), coordinates, coordinates, st.floats(-1e4, 1e4)),
        ),
        max_size=60,
    )
)
def test_heading_is_always_in_the_half_open_interval(events: list[tuple]) -> None:
    odometry = law_odometry(simple())
    time_ns, q_left, q_right = 0, 0.0, 0.0
    odometry.step(time_ns, [q_left, q_right])
    for kind, a, b, c in events:
        if kind == "reset":
            odometry.reset(a, b, c)
        else:
            time_ns, q_left, q_right = time_ns + a, q_left + b, q_right + c
            step = odometry.step(time_ns, [q_left, q_right])
            assert -math.pi < step.theta <= math.pi
        assert -math.pi < odometry.pose.theta <= math.pi


MS = 1_000_000


def _driven(vr_per_step: float, vl_per_step: float, steps: int) -> Odometry:
    """Odometry after ``steps`` samples 1 ms apart, the wheels turning by the given angles per step."""
    odometry = law_odometry(load_config())
    for k in range(steps + 1):
        odometry.step(k * MS, [vl_per_step * k, vr_per_step * k])
    return odometry


def test_a_fix_stamped_now_is_the_seed_overwrite():
    odometry = _driven(0.01, 0.01, 100)
    assert odometry.reset_at(100 * MS, 2.0, -1.0, 0.5) == Pose(2.0, -1.0, 0.5)


def test_a_late_fix_keeps_the_motion_integrated_since_its_stamp():
    odometry = _driven(0.01, 0.01, 100)  # 1 mm per step along +x: x = 0.1 at 100 ms
    pose = odometry.reset_at(50 * MS, 0.06, 0.0, 0.0)  # at 50 ms the robot was really at 0.06
    assert pose.x == pytest.approx(0.06 + 0.05, abs=1e-12)
    assert (pose.y, pose.theta) == (pytest.approx(0.0, abs=1e-12), 0.0)


def test_a_late_fix_turns_the_motion_since_its_stamp_with_its_heading():
    odometry = _driven(0.01, 0.01, 100)
    pose = odometry.reset_at(50 * MS, 1.0, 2.0, math.pi / 2)  # the fix says: facing +y
    assert (pose.x, pose.y, pose.theta) == (pytest.approx(1.0), pytest.approx(2.05), pytest.approx(math.pi / 2))


def test_a_fix_from_the_future_waits_for_its_time():
    """It replaces the pose integrated up to its stamp, before the next sample's step."""
    odometry = _driven(0.01, 0.01, 10)
    before = odometry.pose
    assert odometry.reset_at(12 * MS, 5.0, 5.0, 0.0) == before
    odometry.step(11 * MS, [0.11, 0.11])
    odometry.step(12 * MS, [0.12, 0.12])
    assert odometry.pose.x == pytest.approx(before.x + 0.002)
    odometry.step(13 * MS, [0.13, 0.13])
    assert odometry.pose.x == pytest.approx(5.0 + 0.001) and odometry.pose.y == 5.0


@settings(max_examples=50)
@given(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02), st.integers(1, 50), st.integers(0, 2))
def test_a_fix_gives_the_same_poses_whichever_comes_first_the_fix_or_the_sample_of_its_time(
    left, right, fix_step, arrival
):
    """Lockstep: a fix stamped t arrives before sample t, right after it, or before any sample;
    the poses are the same, bit for bit."""

    def run(fix_before: int) -> list:
        odometry = law_odometry(load_config())
        poses = []
        for k in range(fix_step + 10):
            if k == fix_before:
                odometry.reset_at(fix_step * MS, 1.0, 2.0, 0.5)
            odometry.step(k * MS, [left * k, right * k])
            poses.append(odometry.pose)
        return poses

    arrivals = {"before any sample": 0, "before its sample": fix_step, "right after its sample": fix_step + 1}
    results = {name: run(k) for name, k in arrivals.items()}
    assert results["before any sample"] == results["before its sample"] == results["right after its sample"]


@settings(max_examples=50)
@given(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02), st.integers(1, 200), st.integers(0, 200))
def test_a_late_fix_equal_to_the_odometry_of_its_time_changes_nothing(left, right, steps, back):
    odometry = law_odometry(load_config())
    poses = []
    for k in range(steps + 1):
        odometry.step(k * MS, [left * k, right * k])
        poses.append(odometry.pose)
    stamp = max(0, steps - back)
    now = odometry.pose
    after = odometry.reset_at(stamp * MS, *poses[stamp])
    assert after.x == pytest.approx(now.x, abs=1e-9)
    assert after.y == pytest.approx(now.y, abs=1e-9)
    assert math.remainder(after.theta - now.theta, math.tau) == pytest.approx(0.0, abs=1e-9)


# --- the input policy, with its defaults --------------------------------------------------------


def moving_odometry() -> Odometry:
    """Default input policy; ten seconds at 0.2 m/s straight on 1 ms steps, so a full history."""
    odometry = Odometry(simple().robot, simple().odometry)
    for k in range(10_001):
        odometry.step(k * NS // 1000, [0.002 * k, 0.002 * k])
    return odometry


def test_a_far_future_stamp_is_bad_and_the_next_genuine_sample_is_taken():
    odometry = moving_odometry()
    before = odometry.pose
    for forged_ns in (10 * NS + 2 * NS, 100_000 * NS, 10**29 * NS):
        with pytest.raises(BadInput, match="ahead of the time base"):
            odometry.step(forged_ns, [20.002, 20.002])
    assert odometry.pose == before
    assert odometry.step(10 * NS + NS // 1000, [20.004, 20.004]).pose.x == pytest.approx(2.0004, rel=1e-9)


def test_an_implausible_wheel_angle_jump_is_bad_input():
    odometry = moving_odometry()
    before = odometry.pose
    with pytest.raises(BadInput, match="max_wheel_speed"):
        odometry.step(10 * NS + 50 * NS // 1000, [1e6, 1e6])
    assert odometry.pose == before


@pytest.mark.parametrize(
    ("stamp_ns", "x", "reason"),
    [
        (0, 5.0, "older than"),  # 10 s back, beyond the ~4 s history
        (10 * NS + 2 * NS, 5.0, "ahead of the wheel-angle time"),
        (10 * NS, 1e308, "max_coordinate"),
    ],
)
def test_a_fix_outside_the_history_or_implausible_is_refused(stamp_ns: int, x: float, reason: str):
    odometry = moving_odometry()
    before = odometry.pose
    with pytest.raises(BadInput, match=reason):
        odometry.reset_at(stamp_ns, x, 0.0, 0.0)
    assert odometry.pose == before
    assert odometry.reset_at(9 * NS, 1.8, 0.5, 0.0) == pytest.approx((2.0, 0.5, 0.0)), (
        "a fix within the history applies"
    )
