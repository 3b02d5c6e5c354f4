"""The waypoint follower, closed around a simulated unicycle (pure Python, exact arc integration)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.config import DriveConfig
from services.drive.path_following import STOPPED, Command, PathFollower, Phase, limit_rate
from services.drive.scenarios import distance_to_path
from services.planar import Pose, wrap_angle

PARAMS = DriveConfig()
CONTROL_DT = 1.0 / DriveConfig().rate
PLANT_SUBSTEPS = 20
"""The plant is integrated (and the trajectory sampled) at 1 ms within each 20 ms control period."""
TRACKING_BOUND_M = 0.02
"""How far from the planned polyline the robot may stray: a tenth of the robot's half axle."""
SQUARE = [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]


def unicycle(pose: Pose, command: Command, dt: float) -> Pose:
    """Exact motion at constant (vx, w) for dt seconds (straight when the turn is below rounding:
    a subnormal w would make the radius infinite)."""
    if abs(command.w * dt) < 1e-12:
        distance = command.vx * dt
        return Pose(pose.x + distance * math.cos(pose.theta), pose.y + distance * math.sin(pose.theta), pose.theta)
    theta = pose.theta + command.w * dt
    radius = command.vx / command.w
    return Pose(
        pose.x + radius * (math.sin(theta) - math.sin(pose.theta)),
        pose.y - radius * (math.cos(theta) - math.cos(pose.theta)),
        wrap_angle(theta),
    )


@dataclass
class Run:
    follower: PathFollower
    trajectory: list[Pose] = field(default_factory=list)
    ticks: list[tuple[Pose, Command, Phase]] = field(default_factory=list)
    """(pose at the tick, command, phase after the step)."""

    @property
    def final(self) -> Pose:
        return self.trajectory[-1]


def follow(
    waypoints: list[tuple[float, float]],
    start: Pose = Pose(0.0, 0.0, 0.0),
    params: DriveConfig = PARAMS,
    plant: Callable[[Command], Command] = lambda command: command,
    max_time: float = 60.0,
) -> Run:
    """Run the follower until done; ``plant`` maps a command to the motion the robot really makes."""
    run = Run(PathFollower(waypoints, params))
    pose = start
    run.trajectory.append(pose)
    for _ in range(round(max_time / CONTROL_DT)):
        command = run.follower.step(pose, CONTROL_DT)
        run.ticks.append((pose, command, run.follower.phase))
        if run.follower.done:
            return run
        for _ in range(PLANT_SUBSTEPS):
            pose = unicycle(pose, plant(command), CONTROL_DT / PLANT_SUBSTEPS)
            run.trajectory.append(pose)
    raise AssertionError(f"not done after {max_time} s; at {pose}")


def tracking_error(run: Run, path: list[tuple[float, float]]) -> float:
    return max(distance_to_path((p.x, p.y), path) for p in run.trajectory)


def test_straight_line_stays_on_the_line_and_stops_at_the_goal() -> None:
    run = follow([(2.0, 0.0)])
    assert tracking_error(run, [(0.0, 0.0), (2.0, 0.0)]) < TRACKING_BOUND_M
    assert math.dist((run.final.x, run.final.y), (2.0, 0.0)) <= PARAMS.goal_tolerance
    assert run.ticks[-1][1] == STOPPED and run.follower.done
    assert max(command.vx for _p, command, _ph in run.ticks) == pytest.approx(PARAMS.cruise_speed)
    assert all(phase is not Phase.TURN for _p, _c, phase in run.ticks), "no corner, no turn in place"


def test_square_is_traced_within_the_bound_and_closes_at_the_start() -> None:
    run = follow(SQUARE)
    assert tracking_error(run, [(0.0, 0.0), *SQUARE]) < TRACKING_BOUND_M
    assert math.dist((run.final.x, run.final.y), (0.0, 0.0)) <= PARAMS.goal_tolerance
    assert run.follower.done and run.follower.waypoint_index == len(SQUARE) - 1


@pytest.mark.parametrize("corner", SQUARE[:3])
def test_square_corners_are_turned_in_place(corner: tuple[float, float]) -> None:
    run = follow(SQUARE)
    turning = [(pose, command) for pose, command, phase in run.ticks if phase is Phase.TURN]
    here = [(pose, command) for pose, command in turning if math.dist((pose.x, pose.y), corner) < 0.05]
    assert here, f"no turn in place at {corner}"
    turned = sum(command.w for _pose, command in here) * CONTROL_DT
    assert turned == pytest.approx(math.pi / 2, abs=math.radians(5)), "the 90° corner is turned in the turn phase"
    # The corner is reached goal_tolerance before it; the turn begins while braking, then rotates on the spot.
    spinning = [(pose, command) for pose, command in here if command.vx == 0.0]
    assert sum(command.w for _pose, command in spinning) * CONTROL_DT > math.radians(60)
    assert len({(pose.x, pose.y) for pose, _command in spinning}) == 1, "a pure rotation does not move the robot"
    spot = spinning[0][0]
    assert math.dist((spot.x, spot.y), corner) < PARAMS.goal_tolerance


def test_a_start_facing_away_turns_in_place_before_driving() -> None:
    run = follow([(1.0, 0.0)], start=Pose(0.0, 0.0, 2.5))
    first_phases = [phase for _p, _c, phase in run.ticks[:5]]
    assert first_phases[0] is Phase.TURN
    assert tracking_error(run, [(0.0, 0.0), (1.0, 0.0)]) < TRACKING_BOUND_M
    assert math.dist((run.final.x, run.final.y), (1.0, 0.0)) <= PARAMS.goal_tolerance


def test_a_gentle_corner_is_driven_through_without_stopping() -> None:
    path = [(1.0, 0.0), (2.0, 0.3)]  # a 17° bend, under turn_in_place_angle
    run = follow(path)
    assert all(phase is not Phase.TURN for _p, _c, phase in run.ticks)
    near_bend = [command.vx for pose, command, _ph in run.ticks if math.dist((pose.x, pose.y), (1.0, 0.0)) < 0.05]
    assert min(near_bend) > 0.5 * PARAMS.cruise_speed
    assert math.dist((run.final.x, run.final.y), path[-1]) <= PARAMS.goal_tolerance


def test_the_loop_is_closed_a_biased_robot_still_traces_the_square() -> None:
    """The robot turns 10 % less than commanded, drifts left and is 5 % slow: feedback corrects it."""

    def biased(command: Command) -> Command:
        return Command(0.95 * command.vx, 0.9 * command.w + 0.03)

    run = follow(SQUARE, plant=biased)
    assert tracking_error(run, [(0.0, 0.0), *SQUARE]) < 0.05
    assert math.dist((run.final.x, run.final.y), (0.0, 0.0)) <= 0.05


def test_commands_respect_speed_turn_rate_and_acceleration_limits() -> None:
    run = follow(SQUARE)
    commands = [STOPPED] + [command for _p, command, _ph in run.ticks]
    for before, after in itertools.pairwise(commands):
        assert abs(after.vx - before.vx) <= PARAMS.max_acceleration * CONTROL_DT + 1e-12
        assert abs(after.w - before.w) <= PARAMS.max_angular_acceleration * CONTROL_DT + 1e-12
        assert 0.0 <= after.vx <= PARAMS.cruise_speed + 1e-12
        assert abs(after.w) <= PARAMS.max_turn_rate + 1e-12


def test_waypoint_index_advances_through_the_path() -> None:
    run = follow(SQUARE)
    assert run.follower.waypoint_index == 3
    indices = []
    follower = PathFollower(SQUARE, PARAMS)
    pose = Pose(0.0, 0.0, 0.0)
    while not follower.done:
        command = follower.step(pose, CONTROL_DT)
        if not indices or indices[-1] != follower.waypoint_index:
            indices.append(follower.waypoint_index)
        pose = unicycle(pose, command, CONTROL_DT)
    assert indices == [0, 1, 2, 3]


def test_waypoints_already_reached_finish_at_once() -> None:
    follower = PathFollower([(0.005, 0.0), (0.0, 0.01)], PARAMS)
    assert follower.step(Pose(0.0, 0.0, 0.0), CONTROL_DT) == STOPPED
    assert follower.done


def test_stopping_ramps_down_from_the_current_command() -> None:
    follower = PathFollower([(0.0, 0.0)], PARAMS, command=Command(0.3, 0.0))
    first = follower.step(Pose(0.0, 0.0, 0.0), CONTROL_DT)
    assert first.vx == pytest.approx(0.3 - PARAMS.max_acceleration * CONTROL_DT)
    assert not follower.done and follower.phase is Phase.STOP


def test_a_faster_cruise_speed_is_honoured() -> None:
    fast = DriveConfig(cruise_speed=0.6, max_acceleration=1.0)
    run = follow([(3.0, 0.0)], params=fast)
    assert max(command.vx for _p, command, _ph in run.ticks) == pytest.approx(0.6)
    assert math.dist((run.final.x, run.final.y), (3.0, 0.0)) <= fast.goal_tolerance


def test_limit_rate_hand_values() -> None:
    assert limit_rate(Command(0.0, 0.0), Command(1.0, -1.0), 0.1, 0.5, 2.0) == Command(0.05, -0.2)
    assert limit_rate(Command(0.3, 0.1), Command(0.3, 0.0), 0.1, 0.5, 2.0) == Command(0.3, 0.0)
    assert limit_rate(Command(0.3, 0.0), STOPPED, 0.0, 0.5, 2.0) == Command(0.3, 0.0)


def test_an_empty_path_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one waypoint"):
        PathFollower([], PARAMS)


coordinate = st.floats(min_value=-5.0, max_value=5.0)


@settings(max_examples=200, deadline=None)
@given(
    pose=st.builds(Pose, coordinate, coordinate, st.floats(min_value=-math.pi, max_value=math.pi)),
    waypoints=st.lists(st.tuples(coordinate, coordinate), min_size=1, max_size=5),
    previous=st.builds(Command, st.floats(min_value=0.0, max_value=0.3), st.floats(min_value=-1.0, max_value=1.0)),
    steps=st.integers(min_value=1, max_value=30),
)
def test_any_pose_and_path_give_bounded_rate_limited_commands(pose, waypoints, previous, steps) -> None:
    follower = PathFollower(waypoints, PARAMS, command=previous)
    before = previous
    for _ in range(steps):
        command = follower.step(pose, CONTROL_DT)
        assert all(math.isfinite(value) for value in command)
        assert abs(command.vx - before.vx) <= PARAMS.max_acceleration * CONTROL_DT + 1e-9
        assert abs(command.w - before.w) <= PARAMS.max_angular_acceleration * CONTROL_DT + 1e-9
        assert -1e-9 <= command.vx <= max(PARAMS.cruise_speed, previous.vx) + 1e-9
        assert abs(command.w) <= max(PARAMS.max_turn_rate, abs(previous.w)) + 1e-9
        before = command
        pose = unicycle(pose, command, CONTROL_DT)
