"""How the drive approaches one goal (pure, no zenoh), for :class:`~services.drive.goals.Goals`, which
keeps the goals' books: the phases of a running goal (approach, align, settle, cancel), the command
of each tick, when the robot has come to rest, and how far it still has to go.

A goal is reached with the scenarios' path follower (turn toward it if it lies far off the heading,
drive, stop) or, with a costmap, by its navigator (services/navigation/); then a turn in place to its
heading; then zero until the pose stays still for :data:`SETTLE_S`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import DriveConfig, NavigationConfig
from services.drive.path_following import STOPPED, Command, PathFollower, limit_rate
from services.drive.scenarios import goal_duration
from services.navigation.costmap import Costmap
from services.navigation.navigator import Navigator, NavigatorPhase
from services.planar import Pose, wrap_angle

SETTLE_S = 0.2
"""Simulated seconds the robot's pose must stay still, the command zero, before the drive judges
where it came to rest."""
STILL_M = 0.001
STILL_RAD = 0.002
"""How far the pose may move between two ticks and still count as still (a wheel the motor is
still braking turns the body on after the command is zero)."""


class Phase(StrEnum):
    APPROACH = "approach"
    """Following the straight path from where the robot is to the goal's position."""
    ALIGN = "align"
    """Turning in place to the goal's heading."""
    SETTLE = "settle"
    """Commanding zero until the robot is at rest, then judging."""
    CANCELING = "canceling"
    """Braking to a stop after a cancel."""


@dataclass(frozen=True)
class Goal:
    """An accepted goal, its pose already in ``map``."""

    id: str
    x: float
    y: float
    theta: float | None
    frame: str
    position_tolerance: float
    heading_tolerance: float
    time_limit: float | None
    """The caller's limit (simulated s); None: the drive's rule, from the pose the goal starts at."""


@dataclass
class RunningGoal:
    goal: Goal
    start_ns: int
    time_limit_s: float | None
    phase: Phase = Phase.APPROACH
    attempts: int = 1
    follower: PathFollower | None = None
    navigator: Navigator | None = None
    """The goal's navigation while it approaches (None: the straight line, or not approaching)."""
    settle_since_ns: int | None = None
    """Since when the pose has been still, with the command zero, while settling."""
    settle_pose: Pose | None = None
    cancel_reason: str = ""


@dataclass(frozen=True)
class GoalApproach:
    """The drive's way to a goal: its limits, and the costmap goals navigate on (None: the
    straight line to each)."""

    drive: DriveConfig
    costmap: Costmap | None = None
    navigation: NavigationConfig | None = None

    def step(
        self, running: RunningGoal, last: Command, now_ns: int, pose: Pose | None, dt: float, held_by: str
    ) -> Command:
        """The command from ``now_ns`` until the next tick for ``running``, ``last`` the one before
        (``dt`` s ago), ``pose`` the robot's (None: none fresh), ``held_by`` why the collision
        monitor holds the robot; it moves ``running`` on through its phases."""
        params = self.drive
        if running.phase is Phase.CANCELING:
            return limit_rate(last, STOPPED, dt, params.max_acceleration, params.max_angular_acceleration)
        if pose is None:  # no fresh pose: hold still, and drive on with a ramp from rest
            if running.follower is not None:
                running.follower.command = STOPPED
            return STOPPED
        goal = running.goal
        if running.phase is Phase.APPROACH and self.costmap is not None:
            assert self.navigation is not None
            if running.navigator is None:
                running.navigator = Navigator((goal.x, goal.y), self.costmap, params, self.navigation, last)
            command = running.navigator.step(now_ns, pose, dt, held_by)
            if running.navigator.phase is not NavigatorPhase.ARRIVED:
                return command
            running.phase = Phase.ALIGN if goal.theta is not None else Phase.SETTLE
        if running.phase is Phase.APPROACH:
            if running.follower is None:
                running.follower = PathFollower([(goal.x, goal.y)], params, last)
            command = running.follower.step(pose, dt)
            if not running.follower.done:
                return command
            running.follower = None
            running.phase = Phase.ALIGN if goal.theta is not None else Phase.SETTLE
        if running.phase is Phase.ALIGN:
            assert goal.theta is not None
            error = wrap_angle(goal.theta - pose.theta)
            target = STOPPED
            if abs(error) > params.heading_tolerance:
                rate = min(params.max_turn_rate, math.sqrt(params.max_angular_acceleration * abs(error)))
                target = Command(0.0, math.copysign(rate, error))
            command = limit_rate(last, target, dt, params.max_acceleration, params.max_angular_acceleration)
            if target == STOPPED and command == STOPPED:
                running.phase = Phase.SETTLE
            else:
                return command
        previous = running.settle_pose
        moved = previous is None or (
            math.hypot(pose.x - previous.x, pose.y - previous.y) > STILL_M
            or abs(wrap_angle(pose.theta - previous.theta)) > STILL_RAD
        )
        running.settle_pose = pose
        if running.settle_since_ns is None or moved or last != STOPPED:
            running.settle_since_ns = now_ns
        return limit_rate(last, STOPPED, dt, params.max_acceleration, params.max_angular_acceleration)

    @staticmethod
    def settled(running: RunningGoal, now_ns: int) -> bool:
        """The pose has been still, the command zero, for :data:`SETTLE_S`: time to judge."""
        since = running.settle_since_ns
        return since is not None and now_ns - since >= round(SETTLE_S * NANOSECONDS_PER_SECOND)

    def remaining(self, running: RunningGoal, pose: Pose) -> tuple[float, float]:
        """(m, simulated s) still to go from ``pose``: along the plan while the goal navigates, else
        straight to it; the time by the drive's plan (turn, drive, turn)."""
        goal = running.goal
        distance = math.hypot(goal.x - pose.x, goal.y - pose.y)
        estimate = goal_duration(pose, goal.x, goal.y, goal.theta, self.drive)
        tracker = None if running.navigator is None else running.navigator.tracker
        if tracker is not None:
            along = math.dist((pose.x, pose.y), tracker.remaining_points()[0]) + tracker.remaining
            estimate += (along - distance) / self.drive.cruise_speed
            distance = along
        return distance, estimate
