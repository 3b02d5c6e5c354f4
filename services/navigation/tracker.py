"""The path tracker: regulated pure pursuit along a plan (pure, no zenoh; docs/navigation.md).

As Nav2's Regulated Pure Pursuit: the carrot is the first point of the plan, ahead of the robot's
projection on it, a lookahead away from the robot; the lookahead grows with the speed (``lookahead_time`` × |vx|, within [``min_lookahead``,
``max_lookahead``]); the curvature to the carrot is κ = 2·sin(α)/L (α: the carrot's bearing, L: its
distance), w = vx·κ. The speed is regulated:

- by the curvature: below a turning radius of ``regulated_min_radius`` the speed scales with the radius;
- by the costmap: where the cost under the robot is high (close to an obstacle) the speed scales down
  linearly, to ``near_obstacle_speed`` × ``cruise_speed`` at the highest cost short of lethal;
- by the approach: at most √(a·d), d the distance along the plan to its end and a =
  ``drive.max_acceleration`` (it brakes at half the limit, as the scenarios' path follower does);
- by the turn rate: where |w| would exceed ``drive.max_turn_rate`` the speed shrinks instead, so the
  curve is kept.

When the carrot lies further than ``rotate_to_heading_angle`` off the heading (a plan that turns behind
the robot, a start facing away) the robot turns in place toward it until it is within
``drive.heading_tolerance``. The plan is done once the robot is within ``drive.goal_tolerance`` of its
last point or has passed it; the command then ramps to zero. Every command passes the drive's
acceleration limiter (a step in wheel speed slips).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from enum import StrEnum

from services.config import DriveConfig, NavigationConfig
from services.drive.path_following import STOPPED, Command, limit_rate
from services.planar import Pose, wrap_angle

Point = tuple[float, float]

INSCRIBED_COST = 253
"""The costmap's cost where the body would touch (services/navigation/costmap.py's ``INSCRIBED``):
the speed regulation's scale ends below it."""
PROJECTION_REACH = 2.0
"""How far along the plan, in lookaheads (``max_lookahead``), the search for the robot's projection
reaches ahead of where it was: it never jumps further (a plan that passes near itself is not
short-cut), however short the segments in between."""


def _without_repeats(points: Sequence[Point]) -> list[Point]:
    """The plan without a point equal to the one before it: a zero-length segment would take a place
    in the projection's search window and could hold the projection back from the plan's end."""
    kept = [(float(points[0][0]), float(points[0][1]))]
    for x, y in points[1:]:
        if (float(x), float(y)) != kept[-1]:
            kept.append((float(x), float(y)))
    return kept


class TrackerPhase(StrEnum):
    FOLLOW = "follow"
    ROTATE = "rotate"
    STOP = "stop"
    DONE = "done"


class PathTracker:
    """Follows one plan (map frame, from where the robot stood when it was made to the goal); call
    :meth:`step` once per control period. ``command`` is the robot's current command, where the
    acceleration limiter starts from."""

    def __init__(
        self, points: Sequence[Point], drive: DriveConfig, settings: NavigationConfig, command: Command = STOPPED
    ) -> None:
        if not points:
            raise ValueError("a plan has at least one point")
        self.points = _without_repeats(points)
        self.drive = drive
        self.settings = settings
        self.command = command
        self.phase = TrackerPhase.FOLLOW
        self._lengths = [math.dist(a, b) for a, b in itertools.pairwise(self.points)]
        self._index = 0
        """The segment the robot's projection is on."""
        self._along = 0.0
        """How far along that segment."""
        self.remaining = sum(self._lengths)
        self._carrot_at = (0, 0.0)
        """Where the last carrot was along the plan (segment, metres along it)."""
        """Metres along the plan from the robot's projection to its end."""

    @property
    def done(self) -> bool:
        return self.phase is TrackerPhase.DONE

    def step(self, pose: Pose, dt: float, cost_here: int = 0) -> Command:
        """The command for the next ``dt`` seconds from ``pose``, ``cost_here`` the costmap's cost
        under the robot (0 to 252; higher is treated as 252)."""
        if self.phase is TrackerPhase.DONE:
            return STOPPED
        target = self._target(pose, cost_here)
        drive = self.drive
        self.command = limit_rate(self.command, target, dt, drive.max_acceleration, drive.max_angular_acceleration)
        if self.phase is TrackerPhase.STOP and self.command == STOPPED:
            self.phase = TrackerPhase.DONE
        return self.command

    def _target(self, pose: Pose, cost_here: int) -> Command:
        if self.phase is TrackerPhase.STOP:
            return STOPPED
        self._project(pose)
        goal = self.points[-1]
        if math.dist((pose.x, pose.y), goal) <= self.drive.goal_tolerance or self._passed_end(pose):
            self.phase = TrackerPhase.STOP
            return STOPPED
        carrot = self._carrot(pose, self._lookahead())
        distance = math.hypot(carrot[0] - pose.x, carrot[1] - pose.y)
        bearing = wrap_angle(math.atan2(carrot[1] - pose.y, carrot[0] - pose.x) - pose.theta)
        if self.phase is TrackerPhase.ROTATE and abs(bearing) <= self.drive.heading_tolerance:
            self.phase = TrackerPhase.FOLLOW
        elif self.phase is TrackerPhase.FOLLOW and abs(bearing) > self.settings.rotate_to_heading_angle:
            self.phase = TrackerPhase.ROTATE
        if self.phase is TrackerPhase.ROTATE:
            drive = self.drive
            rate = min(drive.max_turn_rate, math.sqrt(2.0 * drive.max_angular_acceleration * abs(bearing)))
            return Command(0.0, math.copysign(rate, bearing))
        return self._pursue(bearing, distance, cost_here)

    def _pursue(self, bearing: float, distance: float, cost_here: int) -> Command:
        drive, settings = self.drive, self.settings
        curvature = 2.0 * math.sin(bearing) / max(distance, 1e-6)
        speed = drive.cruise_speed
        if curvature != 0.0:
            radius = 1.0 / abs(curvature)
            if radius < settings.regulated_min_radius:
                speed *= radius / settings.regulated_min_radius
        near = min(max(cost_here, 0), INSCRIBED_COST - 1) / (INSCRIBED_COST - 1)
        speed *= 1.0 - (1.0 - settings.near_obstacle_speed) * near
        speed = max(speed, min(settings.min_speed, drive.cruise_speed))
        speed = min(speed, math.sqrt(drive.max_acceleration * max(self.remaining, 0.0)))
        if abs(speed * curvature) > drive.max_turn_rate:
            speed = drive.max_turn_rate / abs(curvature)
        return Command(speed, speed * curvature)

    def _lookahead(self) -> float:
        settings = self.settings
        return min(max(abs(self.command.vx) * settings.lookahead_time, settings.min_lookahead), settings.max_lookahead)

    def _project(self, pose: Pose) -> None:
        """Move the projection to the point of the plan nearest the robot, searching up to
        ``PROJECTION_REACH`` lookaheads along the plan ahead of where it was, never back."""
        if not self._lengths:
            return
        best: tuple[float, int, float] | None = None
        reach = PROJECTION_REACH * self.settings.max_lookahead + self._along
        for index in range(self._index, len(self._lengths)):
            if index > self._index and reach < 0.0:
                break
            reach -= self._lengths[index]
            (ax, ay), (bx, by) = self.points[index], self.points[index + 1]
            length = self._lengths[index]  # never 0: repeated points were dropped
            along = ((pose.x - ax) * (bx - ax) + (pose.y - ay) * (by - ay)) / length
            along = min(max(along, 0.0), length)
            if index == self._index:
                along = max(along, self._along)
            fraction = along / length
            gap = math.hypot(ax + (bx - ax) * fraction - pose.x, ay + (by - ay) * fraction - pose.y)
            if best is None or gap < best[0] - 1e-9:
                best = (gap, index, along)
        if best is not None:
            _, self._index, self._along = best
        self.remaining = self._lengths[self._index] - self._along + sum(self._lengths[self._index + 1 :])

    def remaining_points(self) -> list[Point]:
        """What is left of the plan: the robot's projection on it, then the points ahead."""
        if not self._lengths:
            return [self.points[0]]
        (ax, ay), (bx, by) = self.points[self._index], self.points[self._index + 1]
        length = self._lengths[self._index]
        fraction = self._along / length
        return [(ax + (bx - ax) * fraction, ay + (by - ay) * fraction), *self.points[self._index + 1 :]]

    def _passed_end(self, pose: Pose) -> bool:
        """Whether the robot is past the plan's end along its last segment."""
        if not self._lengths or self._index < len(self._lengths) - 1:
            return not self._lengths
        (ax, ay), (bx, by) = self.points[-2], self.points[-1]
        length = self._lengths[-1]
        return ((pose.x - ax) * (bx - ax) + (pose.y - ay) * (by - ay)) / length >= length

    def _carrot(self, pose: Pose, lookahead: float) -> Point:
        """As Nav2's: the first point of the plan ahead of the robot's projection that lies
        ``lookahead`` metres or more from the robot (on the segment that crosses that circle), or the
        plan's end when all of it is nearer. Measured from the robot, not along the plan, so a plan
        that doubles back never puts the carrot under the robot; and never behind the last carrot, so
        a hairpin cannot make it jump from one side to the other and back."""
        index, along = max((self._index, self._along), self._carrot_at)
        while index < len(self._lengths):
            (ax, ay), (bx, by) = self.points[index], self.points[index + 1]
            length = self._lengths[index]
            dx, dy = (bx - ax) / length, (by - ay) / length
            fx, fy = ax + dx * along - pose.x, ay + dy * along - pose.y
            if math.hypot(fx, fy) >= lookahead:
                break
            if math.hypot(bx - pose.x, by - pose.y) >= lookahead:
                # |f + s·d| = lookahead, s ≥ 0 along the unit direction d: f is inside, b is not.
                half_b = fx * dx + fy * dy
                along += -half_b + math.sqrt(max(half_b * half_b - (fx * fx + fy * fy - lookahead * lookahead), 0.0))
                along = min(along, length)
                break
            index, along = index + 1, 0.0
        else:
            return self.points[-1]
        self._carrot_at = (index, along)
        (ax, ay), (bx, by) = self.points[index], self.points[index + 1]
        fraction = along / self._lengths[index]
        return ax + (bx - ax) * fraction, ay + (by - ay) * fraction
