"""The path tracker, pure (services/navigation/tracker.py): regulated pure pursuit along a plan, on an
ideal unicycle."""

from __future__ import annotations

import math

from hypothesis import example, given, settings
from hypothesis import strategies as st

from services.config import DriveConfig, NavigationConfig
from services.drive.path_following import Command
from services.drive.scenarios import distance_to_path
from services.navigation.tracker import PathTracker, TrackerPhase
from services.planar import Pose
from tests.test_path_following import unicycle

DRIVE = DriveConfig()
NAVIGATION = NavigationConfig()
DT = 1.0 / DRIVE.rate


def drive_along(
    points: list[tuple[float, float]], pose: Pose, cost: int = 0, max_ticks: int = 20_000
) -> tuple[PathTracker, list[Pose], list[Command]]:
    tracker = PathTracker(points, DRIVE, NAVIGATION)
    poses, commands = [pose], []
    for _ in range(max_ticks):
        command = tracker.step(pose, DT, cost)
        commands.append(command)
        pose = unicycle(pose, command, DT)
        poses.append(pose)
        if tracker.done:
            return tracker, poses, commands
    raise AssertionError("the tracker never ended")


def test_a_straight_plan_is_driven_to_its_end_at_cruise_speed() -> None:
    tracker, poses, commands = drive_along([(0.0, 0.0), (3.0, 0.0)], Pose(0.0, 0.0, 0.0))
    end = poses[-1]
    assert math.hypot(end.x - 3.0, end.y) <= DRIVE.goal_tolerance
    assert max(command.vx for command in commands) == DRIVE.cruise_speed
    assert max(abs(pose.y) for pose in poses) < 1e-9
    assert tracker.phase is TrackerPhase.DONE and commands[-1] == Command(0.0, 0.0)


def test_a_bending_plan_is_followed_closely() -> None:
    plan = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (4.0, 2.0)]
    _, poses, _ = drive_along(plan, Pose(0.0, 0.0, 0.0))
    worst = max(distance_to_path((pose.x, pose.y), plan) for pose in poses)
    assert worst < 0.15, f"strayed {worst:.3f} m from the plan"
    assert math.hypot(poses[-1].x - 4.0, poses[-1].y - 2.0) <= DRIVE.goal_tolerance


def test_a_plan_behind_the_robot_is_turned_to_in_place_first() -> None:
    tracker = PathTracker([(0.0, 0.0), (-2.0, 0.0)], DRIVE, NAVIGATION)
    pose = Pose(0.0, 0.0, 0.0)
    command = tracker.step(pose, DT)
    assert tracker.phase is TrackerPhase.ROTATE
    while tracker.phase is TrackerPhase.ROTATE:
        assert command.vx == 0.0, "turning in place does not move the robot"
        pose = unicycle(pose, command, DT)
        command = tracker.step(pose, DT)
    assert abs(abs(pose.theta) - math.pi) <= NAVIGATION.rotate_to_heading_angle
    assert math.hypot(pose.x, pose.y) < 1e-9


def test_it_slows_down_near_obstacles_and_in_tight_turns() -> None:
    def top_speed(points: list[tuple[float, float]], cost: int) -> float:
        _, _, commands = drive_along(points, Pose(0.0, 0.0, 0.0), cost)
        return max(command.vx for command in commands)

    straight = [(0.0, 0.0), (4.0, 0.0)]
    assert top_speed(straight, 0) == DRIVE.cruise_speed
    near = top_speed(straight, 252)
    assert near == DRIVE.cruise_speed * NAVIGATION.near_obstacle_speed
    tight = [(0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5), (0.0, 1.0), (0.5, 1.0)]
    _, _, commands = drive_along(tight, Pose(0.0, 0.0, 0.0))
    turning = [c for c in commands if c.vx > 0.0 and abs(c.w / c.vx) > 1.0 / NAVIGATION.regulated_min_radius]
    assert turning, "the tight plan has turns tighter than regulated_min_radius"
    assert all(c.vx < DRIVE.cruise_speed for c in turning)


def test_repeated_points_do_not_hold_the_projection_back() -> None:
    # Found by CI's hypothesis run: five points at the start left the projection's window on
    # zero-length segments, so the robot circled the goal without ever being done.
    plan = [(0.0, 0.0)] * 5 + [(0.0, 1.0)]
    tracker, poses, _ = drive_along(plan, Pose(0.0, 0.0, 0.0))
    assert tracker.points == [(0.0, 0.0), (0.0, 1.0)]
    assert math.hypot(poses[-1].x, poses[-1].y - 1.0) <= DRIVE.goal_tolerance


points = st.tuples(st.floats(-4.0, 4.0), st.floats(-4.0, 4.0))


@given(plan=st.lists(points, min_size=1, max_size=5), heading=st.floats(-math.pi, math.pi))
# Found by hypothesis: a plan that doubles back within a lookahead, behind a point a hair from the
# start, put the carrot under the robot; a hairpin made the carrot jump between its two sides. The
# robot turned in place for ever.
@example(plan=[(0.0, 2e-27), (0.0, 0.0), (0.125, 0.0), (0.0, 0.0), (-1.0, 0.0)], heading=0.0)
@example(plan=[(-2.0, 2.0), (0.25, 0.0), (0.0, 0.0), (-1.0, 2.0)], heading=0.0)
@settings(max_examples=60, deadline=None)
def test_the_limits_hold_on_any_plan(plan: list[tuple[float, float]], heading: float) -> None:
    start = Pose(0.0, 0.0, heading)
    tracker = PathTracker([(0.0, 0.0), *plan], DRIVE, NAVIGATION)
    pose, previous = start, Command(0.0, 0.0)
    for _ in range(30_000):  # 600 s: four legs of up to 11 m at 0.3 m/s, and the turns
        command = tracker.step(pose, DT)
        assert 0.0 <= command.vx <= DRIVE.cruise_speed + 1e-12
        assert abs(command.w) <= DRIVE.max_turn_rate + 1e-12
        assert abs(command.vx - previous.vx) <= DRIVE.max_acceleration * DT + 1e-12
        assert abs(command.w - previous.w) <= DRIVE.max_angular_acceleration * DT + 1e-12
        previous = command
        pose = unicycle(pose, command, DT)
        if tracker.done:
            break
    assert tracker.done, "every plan on a free floor ends"
    assert math.hypot(pose.x - tracker.points[-1][0], pose.y - tracker.points[-1][1]) <= 0.1
