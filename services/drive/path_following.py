"""A waypoint follower for a differential-drive robot: pure pursuit with turn-in-place (pure).

The path is a polyline from where the robot stands when following begins through the
waypoints. The follower tracks one segment at a time:

- **follow**: pure pursuit on the current segment's line. The lookahead point lies
  ``lookahead`` metres ahead of the robot's projection on that line (the line extends past
  the segment's end, so the aim stays steady up to the corner). Curvature κ = 2·sin(α)/L_d
  (α: heading error to the lookahead point, L_d: distance to it), w = v·κ; when |w| would
  exceed ``max_turn_rate``, v shrinks instead, so the curve stays the same.
- Speed is ``cruise_speed``, capped by √(a·d), d the distance along the path to the next
  **stop** (the last waypoint, or a corner sharper than ``turn_in_place_angle``), a =
  ``max_acceleration``: the approach brakes at a/2, keeping the other half for the final stop
  once the waypoint is reached and as margin for the robot's lag behind its commands.
- A waypoint is **reached** within ``goal_tolerance`` of it, or once the robot has passed it
  along the segment; following moves on to the next segment.
- **turn**: when the heading error exceeds ``turn_in_place_angle`` (a sharp corner, or a start
  facing away) the robot stops and turns in place, w = ±min(max_turn_rate, √(2·α_max·|α|)),
  until the error is below ``heading_tolerance``.
- **stop**: after the last waypoint, the command ramps down to zero; then **done**.

Every command goes through an acceleration limiter (``max_acceleration``,
``max_angular_acceleration``): a step in wheel speed makes the wheels slip.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import NamedTuple

from services.config import DriveConfig
from services.planar import Pose, wrap_angle

Point = tuple[float, float]


class Command(NamedTuple):
    """A body velocity: vx in m/s (forward), w in rad/s (counter-clockwise)."""

    vx: float
    w: float


STOPPED = Command(0.0, 0.0)


class Phase(StrEnum):
    FOLLOW = "follow"
    TURN = "turn"
    STOP = "stop"
    DONE = "done"


def limit_rate(previous: Command, target: Command, dt: float, max_acceleration: float, max_angular: float) -> Command:
    """``target``, moved no further from ``previous`` than the accelerations allow in ``dt`` seconds."""

    def toward(old: float, new: float, max_step: float) -> float:
        return old + min(max(new - old, -max_step), max_step)

    return Command(
        toward(previous.vx, target.vx, max_acceleration * dt), toward(previous.w, target.w, max_angular * dt)
    )


@dataclass(frozen=True)
class _Segment:
    start: Point
    end: Point
    ux: float
    uy: float
    length: float
    waypoint_index: int
    """Index of ``end`` in the caller's waypoint list."""
    stop_at_end: bool


def _segments(origin: Point, waypoints: Sequence[Point], params: DriveConfig) -> list[_Segment]:
    """The path's segments, skipping waypoints within ``goal_tolerance`` of the point before them."""
    points: list[tuple[Point, int]] = [(origin, -1)]
    for index, point in enumerate(waypoints):
        if math.dist(points[-1][0], point) > params.goal_tolerance:
            points.append((point, index))
    segments: list[_Segment] = []
    for (start, _), (end, index) in itertools.pairwise(points):
        length = math.dist(start, end)
        segments.append(
            _Segment(start, end, (end[0] - start[0]) / length, (end[1] - start[1]) / length, length, index, True)
        )
    for i in range(len(segments) - 1):
        here, after = segments[i], segments[i + 1]
        corner = abs(wrap_angle(math.atan2(after.uy, after.ux) - math.atan2(here.uy, here.ux)))
        segments[i] = replace(here, stop_at_end=corner > params.turn_in_place_angle)
    return segments


class PathFollower:
    """Follows ``waypoints`` (world frame, m); call :meth:`step` once per control period.

    ``command`` is the robot's current command, where the acceleration limiter starts from.
    """

    def __init__(self, waypoints: Sequence[Point], params: DriveConfig, command: Command = STOPPED) -> None:
        if not waypoints:
            raise ValueError("a path needs at least one waypoint")
        self.waypoints = [(float(x), float(y)) for x, y in waypoints]
        self.params = params
        self.command = command
        self.phase = Phase.FOLLOW
        self._segments: list[_Segment] | None = None
        self._index = 0

    @property
    def done(self) -> bool:
        return self.phase is Phase.DONE

    @property
    def waypoint_index(self) -> int:
        """Index of the waypoint being approached (the last one once done)."""
        if not self._segments:
            return len(self.waypoints) - 1
        return self._segments[self._index].waypoint_index

    def step(self, pose: Pose, dt: float) -> Command:
        """The command for the next ``dt`` seconds, given the robot's ``pose`` now."""
        if self._segments is None:
            self._segments = _segments((pose.x, pose.y), self.waypoints, self.params)
            if not self._segments:
                self.phase = Phase.STOP
        if self.phase is Phase.DONE:
            return STOPPED
        target = self._target(pose)
        p = self.params
        self.command = limit_rate(self.command, target, dt, p.max_acceleration, p.max_angular_acceleration)
        if self.phase is Phase.STOP and self.command == STOPPED:
            self.phase = Phase.DONE
        return self.command

    def _target(self, pose: Pose) -> Command:
        if self.phase is Phase.STOP:
            return STOPPED
        assert self._segments is not None
        while True:
            segment = self._segments[self._index]
            along = (pose.x - segment.start[0]) * segment.ux + (pose.y - segment.start[1]) * segment.uy
            reached = along >= segment.length or math.dist((pose.x, pose.y), segment.end) <= self.params.goal_tolerance
            if self.phase is not Phase.FOLLOW or not reached:
                break
            if self._index == len(self._segments) - 1:
                self.phase = Phase.STOP
                return STOPPED
            self._index += 1
        aim = along + self.params.lookahead
        aim_x, aim_y = segment.start[0] + segment.ux * aim, segment.start[1] + segment.uy * aim
        error = wrap_angle(math.atan2(aim_y - pose.y, aim_x - pose.x) - pose.theta)
        if self.phase is Phase.TURN and abs(error) <= self.params.heading_tolerance:
            self.phase = Phase.FOLLOW
        elif self.phase is Phase.FOLLOW and abs(error) > self.params.turn_in_place_angle:
            self.phase = Phase.TURN
        if self.phase is Phase.TURN:
            return self._turn(error)
        return self._pursue(error, math.hypot(aim_x - pose.x, aim_y - pose.y), segment.length - along)

    def _turn(self, error: float) -> Command:
        rate = min(self.params.max_turn_rate, math.sqrt(2.0 * self.params.max_angular_acceleration * abs(error)))
        return Command(0.0, math.copysign(rate, error))

    def _pursue(self, error: float, aim_distance: float, remaining: float) -> Command:
        p = self.params
        to_stop = remaining + self._length_after_current_to_stop()
        approach_deceleration = p.max_acceleration / 2.0
        speed = min(p.cruise_speed, math.sqrt(2.0 * approach_deceleration * max(to_stop, 0.0)))
        curvature = 2.0 * math.sin(error) / aim_distance
        if abs(speed * curvature) > p.max_turn_rate:
            speed = p.max_turn_rate / abs(curvature)
        return Command(speed, speed * curvature)

    def _length_after_current_to_stop(self) -> float:
        assert self._segments is not None
        length = 0.0
        for index in range(self._index, len(self._segments) - 1):
            if self._segments[index].stop_at_end:
                break
            length += self._segments[index + 1].length
        return length
