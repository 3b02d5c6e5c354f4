"""Setting and resetting the odometry at runtime (``Odometry.set_pose``: the queryable
``odometry/set_pose``), as diff_drive_controller's ``odometry_set_service`` test checks its
``~/set_odometry``: move, set, the next update reports the pose set, then moving goes on from it.
Pure: no zenoh (the queryable is tests/test_odometry_service.py's)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.config import InputConfig, load_config
from services.odometry.core import FIX_HISTORY_STEPS, PENDING_POSES, Odometry
from services.planar import Pose

MS = 1_000_000


def odometry(wheel_radius: float = 0.1, axle: float = 0.4) -> Odometry:
    config = load_config(
        overrides={
            "robot.radius_of_left_wheel": wheel_radius,
            "robot.radius_of_right_wheel": wheel_radius,
            "robot.length_of_axle": axle,
        }
    )
    return Odometry(config.robot, config.odometry, limits=InputConfig(stamp_horizon=10.0, max_wheel_speed=1e6))


def test_odometry_set_service_as_diff_drive_controller():
    """diff_drive_controller's test: wheel radius 1 m, separation 0.4 m; move, set (5, −2, 90°),
    the next update reports it, and moving forward then goes along +y."""
    odom = odometry(wheel_radius=1.0)
    odom.step(0, [0.0, 0.0])
    odom.step(100 * MS, [0.1, 0.1])
    assert odom.pose.x > 0.0
    assert odom.set_pose(5.0, -2.0, 1.57079632679) == 100 * MS, "stamped with the last update"
    odom.step(200 * MS, [0.1, 0.1])
    assert odom.pose.x == pytest.approx(5.0, abs=1e-6)
    assert odom.pose.y == pytest.approx(-2.0, abs=1e-6)
    assert odom.pose.theta == pytest.approx(1.57079632679, abs=1e-5)
    odom.step(300 * MS, [0.2, 0.2])
    assert odom.pose.y > -2.0
    assert odom.pose.x == pytest.approx(5.0, abs=1e-6)


def test_reset_odometry_zeroes_the_pose():
    """A reset (tricycle_controller's ``~/reset_odometry``): the pose (0, 0, 0), the wheels kept."""
    odom = odometry()
    odom.step(0, [0.0, 0.0])
    odom.step(10 * MS, [0.05, 0.03])
    assert odom.pose != Pose(0.0, 0.0, 0.0)
    odom.set_pose(0.0, 0.0, 0.0)
    assert odom.pose == Pose(0.0, 0.0, 0.0)
    odom.step(20 * MS, [0.05, 0.03])
    assert odom.pose == Pose(0.0, 0.0, 0.0), "the wheels did not move since: it stays at zero"


def test_before_any_sample_it_sets_the_starting_pose():
    odom = odometry()
    assert odom.set_pose(1.0, 2.0, 0.5) is None
    odom.step(0, [0.0, 0.0])
    assert odom.pose == Pose(1.0, 2.0, 0.5)


def test_a_pose_stamped_ahead_waits_for_the_first_sample_after_its_stamp():
    odom = odometry()
    odom.step(0, [0.0, 0.0])
    assert odom.set_pose(3.0, 0.0, 0.0, stamp_ns=5 * MS) == 5 * MS
    odom.step(5 * MS, [0.01, 0.01])
    assert odom.pose.x == pytest.approx(0.001), "not yet: its stamp is this sample's"
    odom.step(6 * MS, [0.02, 0.02])
    assert odom.pose.x == pytest.approx(3.001), "set at 5 ms, then this step's 1 mm"


def test_poses_waiting_apply_in_stamp_order_and_none_replaces_another():
    """A fix and a set pose both waiting: each at its own stamp, whichever arrived first."""
    odom = odometry()
    odom.step(0, [0.0, 0.0])
    odom.set_pose(2.0, 0.0, 0.0, stamp_ns=4 * MS)
    odom.reset_at(2 * MS, 1.0, 0.0, 0.0)
    odom.step(3 * MS, [0.0, 0.0])
    assert odom.pose.x == 1.0
    odom.step(5 * MS, [0.0, 0.0])
    assert odom.pose.x == 2.0


def test_bad_requests_are_refused_and_change_nothing():
    odom = odometry()
    odom.step(0, [0.0, 0.0])
    for k in range(1, FIX_HISTORY_STEPS + 2):
        odom.step(k * MS, [0.0, 0.0])
    before = odom.pose
    refused = [
        (math.nan, 0.0, 0.0, None),
        (0.0, 0.0, math.inf, None),
        (1e9, 0.0, 0.0, None),  # beyond input.max_coordinate
        (0.0, 0.0, 0.0, 0),  # older than the history kept
        (0.0, 0.0, 0.0, (FIX_HISTORY_STEPS + 1) * MS + 11_000 * MS),  # beyond the stamp horizon
    ]
    for x, y, theta, stamp_ns in refused:
        with pytest.raises(BadInput):
            odom.set_pose(x, y, theta, stamp_ns)
        assert odom.pose == before
    last = (FIX_HISTORY_STEPS + 1) * MS
    for k in range(PENDING_POSES):
        odom.set_pose(1.0, 0.0, 0.0, stamp_ns=last + (k + 1) * MS)
    with pytest.raises(BadInput, match="wait"):
        odom.set_pose(1.0, 0.0, 0.0, stamp_ns=last + 100 * MS)


wheel_steps = st.lists(st.tuples(st.floats(-0.02, 0.02), st.floats(-0.02, 0.02)), min_size=2, max_size=30)


@given(
    steps=wheel_steps,
    stamp_at=st.integers(0, 29),
    arrives_after=st.integers(0, 29),
    pose=st.tuples(st.floats(-10, 10), st.floats(-10, 10), st.floats(-3, 3)),
)
def test_a_stamped_set_gives_the_same_poses_whenever_it_arrives(steps, stamp_at, arrives_after, pose):
    """Lockstep's rule: a pose set stamped t lands on the same poses, bit for bit up to rounding,
    whether it arrives before the sample of t or any number of samples after it."""
    stamp_at %= len(steps)
    arrives_after %= len(steps)
    stamp_ns = (stamp_at + 1) * MS

    def run(arrive_before_sample: int) -> list[Pose]:
        odom = odometry()
        odom.step(0, [0.0, 0.0])
        angles = [0.0, 0.0]
        poses = []
        for k, (left, right) in enumerate(steps, start=1):
            if k == arrive_before_sample:
                odom.set_pose(*pose, stamp_ns=stamp_ns)
            angles = [angles[0] + left, angles[1] + right]
            odom.step(k * MS, angles)
            poses.append(odom.pose)
        return poses

    early = run(1)
    late = run(max(stamp_at + 2, arrives_after + 1))
    settled = max(stamp_at + 1, arrives_after)
    for a, b in zip(early[settled:], late[settled:], strict=True):
        assert a.x == pytest.approx(b.x, abs=1e-9)
        assert a.y == pytest.approx(b.y, abs=1e-9)
        assert math.remainder(a.theta - b.theta, math.tau) == pytest.approx(0.0, abs=1e-9)
