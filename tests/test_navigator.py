"""The navigator, pure (services/navigation/navigator.py): one goal's way there on a costmap, replans and
recoveries, on an ideal unicycle. The costmaps here are static maps of rasterised obstacles (the lidar's
part of the costmap is tested in tests/test_costmap.py, the whole loop in tests/test_navigation_loop.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas.messages import LaserScan, Obstacle, Time
from services.config import DriveConfig, NavigationConfig
from services.drive.path_following import STOPPED
from services.navigation.costmap import INSCRIBED, Costmap
from services.navigation.navigator import Navigator, NavigatorPhase, Recovery
from services.navigation.rasterize import rasterize
from services.planar import Pose
from tests.test_path_following import unicycle

DRIVE = DriveConfig()
NAVIGATION = NavigationConfig()
BODY = 0.45
TICK_NS = round(1e9 / DRIVE.rate)
DT = TICK_NS / 1e9


def box(name: str, x: float, y: float, sx: float, sy: float) -> Obstacle:
    return Obstacle(name, "box", x, y, 0.0, (sx, sy, 0.5))


def static_costmap(obstacles: list[Obstacle], include: list[tuple[float, float]]) -> Costmap:
    grid = rasterize(obstacles, NAVIGATION.resolution, include=include, margin=2.0)
    return Costmap(grid.geometry, NAVIGATION, BODY, grid.cells)


class Run:
    """A navigator driving an ideal unicycle, tick by tick; ``held`` says when the monitor holds it."""

    def __init__(self, navigator: Navigator, pose: Pose) -> None:
        self.navigator = navigator
        self.pose = pose
        self.now_ns = 0
        self.poses = [pose]
        self.held_by = ""

    def step(self) -> None:
        command = self.navigator.step(self.now_ns, self.pose, DT, self.held_by)
        if not self.held_by or command.vx <= 0.0:  # held: the motor lets no forward motion through
            self.pose = unicycle(self.pose, command, DT)
        self.poses.append(self.pose)
        self.now_ns += TICK_NS

    def until_finished(self, max_s: float = 300.0) -> None:
        while not self.navigator.finished:
            assert self.now_ns < max_s * 1e9, f"not finished in {max_s} s: {self.navigator.status()}"
            self.step()

    def worst_cost(self) -> int:
        costmap = self.navigator.costmap
        return max(costmap.cost_at(p.x, p.y) for p in self.poses)


def test_a_goal_behind_a_wall_is_reached_around_it_never_where_the_body_would_touch() -> None:
    costmap = static_costmap([box("wall", 2.0, 0.0, 0.2, 3.0)], [(0.0, 0.0), (4.0, 0.0)])
    run = Run(Navigator((4.0, 0.0), costmap, DRIVE, NAVIGATION), Pose(0.0, 0.0, 0.0))
    run.until_finished()
    assert run.navigator.phase is NavigatorPhase.ARRIVED, run.navigator.status()
    assert math.hypot(run.pose.x - 4.0, run.pose.y) <= DRIVE.goal_tolerance
    assert run.worst_cost() < INSCRIBED, "the axle centre stayed where the body touches nothing"
    assert max(abs(p.y) for p in run.poses) > 1.5, "it went around the wall's end"
    assert run.navigator.recoveries == 0


def test_a_goal_in_a_closed_pen_fails_naming_no_path_after_its_recoveries() -> None:
    pen = [
        box("pen_s", 4.0, -1.05, 2.2, 0.1),
        box("pen_n", 4.0, 1.05, 2.2, 0.1),
        box("pen_w", 2.95, 0.0, 0.1, 2.2),
        box("pen_e", 5.05, 0.0, 0.1, 2.2),
    ]
    costmap = static_costmap(pen, [(0.0, 0.0)])
    run = Run(Navigator((4.0, 0.0), costmap, DRIVE, NAVIGATION), Pose(0.0, 0.0, 0.0))
    run.until_finished()
    navigator = run.navigator
    assert navigator.phase is NavigatorPhase.FAILED
    assert navigator.failure.startswith("no path to (4.00, 0.00): "), navigator.failure
    assert f"({NAVIGATION.max_recoveries} recoveries tried)" in navigator.failure
    assert navigator.recoveries == NAVIGATION.max_recoveries
    assert run.worst_cost() < INSCRIBED
    assert run.now_ns < 240e9, "within 4 simulated minutes"


@pytest.mark.parametrize(
    ("goal", "says"),
    [((2.0, 0.0), "is in an obstacle"), ((2.0, 0.45), "the robot cannot stand there")],
)
def test_a_goal_in_or_beside_an_obstacle_of_the_map_fails_at_once_without_driving(goal, says) -> None:
    costmap = static_costmap([box("block", 2.0, 0.0, 0.4, 0.4)], [(0.0, 0.0)])
    run = Run(Navigator(goal, costmap, DRIVE, NAVIGATION), Pose(0.0, 0.0, 0.0))
    run.until_finished()
    assert run.navigator.phase is NavigatorPhase.FAILED
    assert says in run.navigator.failure, run.navigator.failure
    assert run.navigator.recoveries == 1, "the obstacle layer cleared once: the map's obstacle stays"
    assert max(abs(p.x) + abs(p.y) for p in run.poses) < 1e-9, "never a drive to some other cell"


def test_a_robot_held_by_the_monitor_recovers_in_turn_then_fails_naming_the_obstacle() -> None:
    costmap = static_costmap([], [(0.0, 0.0), (4.0, 0.0)])
    run = Run(Navigator((4.0, 0.0), costmap, DRIVE, NAVIGATION), Pose(0.0, 0.0, 0.0))
    run.held_by = "obstacle 'crate' in the stop zone, 0.30 m ahead at (0.80, 0.00) in base_link"
    kinds = []
    while not run.navigator.finished:
        recovery = run.navigator.recovery
        if recovery is not None and (not kinds or kinds[-1] != recovery):
            kinds.append(recovery)
        run.step()
    failure = run.navigator.failure
    assert failure.startswith("blocked by 'crate' for "), failure
    assert failure.endswith(f"({NAVIGATION.max_recoveries} recoveries tried)"), failure
    assert kinds[:4] == [str(kind) for kind in (Recovery.CLEAR, Recovery.WAIT, Recovery.BACK_UP, Recovery.SPIN)]


def _scan_of_wall(x_wall: float, pose: Pose) -> LaserScan:
    """A 360-ray scan (1 degree apart) from ``pose`` of an infinite wall at x = ``x_wall``."""
    angles = np.radians(np.arange(360) - 180.0)
    ranges: list[float | None] = []
    for angle in angles:
        direction = math.cos(pose.theta + angle)
        distance = (x_wall - pose.x) / direction if direction > 1e-9 else math.inf
        ranges.append(float(distance) if distance < 3.5 else None)
    return LaserScan(Time(0, 0), -math.pi, math.radians(1.0), 0.12, 3.5, ranges)


def test_a_plan_blocked_by_what_the_lidar_sees_is_replaced_at_once() -> None:
    costmap = static_costmap([], [(0.0, 0.0), (6.0, 0.0)])
    navigator = Navigator((6.0, 0.0), costmap, DRIVE, NAVIGATION)
    pose = Pose(0.0, 0.0, 0.0)
    navigator.step(0, pose, DT)
    assert navigator.phase is NavigatorPhase.FOLLOW and navigator.plan_version == 1
    costmap.mark_scan(_scan_of_wall(2.0, pose), pose.x, pose.y, pose.theta)
    navigator.costmap_updated()
    navigator.step(TICK_NS, pose, DT)
    assert navigator.plan_version == 2, "replanned at the next tick, not at the replan rate"


def test_a_navigator_that_failed_commands_a_stop() -> None:
    costmap = static_costmap([box("block", 2.0, 0.0, 0.4, 0.4)], [(0.0, 0.0)])
    run = Run(Navigator((2.0, 0.0), costmap, DRIVE, NAVIGATION), Pose(0.0, 0.0, 0.0))
    run.until_finished()
    assert run.navigator.step(run.now_ns, run.pose, DT) == STOPPED
