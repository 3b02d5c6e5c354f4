"""The odometry core (docs/protocol.md section 5): localized poses (fixes, late and early), a restarted
simulator, bad input, properties (hypothesis) and the input policy; tests/test_odometry_core.py has
the hand-computed steps, the analytic motion and the helpers.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.config import load_config
from services.odometry.core import Branch, Odometry
from services.planar import Pose
from tests.test_odometry_core import (
    CHORD_TOLERANCE,
    NS,
    SMALL_ANGLE_TOLERANCE_PER_METRE,
    analytic_pose,
    assert_pose_close,
    body_velocity,
    drive,
    law_odometry,
    parameters,
    simple,
)

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
