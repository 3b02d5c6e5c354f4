"""Drive scenarios: what ``invent drive`` plays, in simulation time (pure, no zenoh).

A :class:`Scenario` is an ordered list of segments, each either

- ``constant``: a body velocity (vx m/s, w rad/s) held for ``duration`` simulated seconds, or
- ``waypoints``: a path through points of the world frame (m), followed by
  :class:`~services.drive.path_following.PathFollower` on the robot's pose.

Built-ins: ``straight``, ``circle``, ``square``, ``figure8`` (:data:`BUILTIN_SCENARIOS`).
A scenario file is TOML, loaded strictly (an unknown key, a wrong type or a value out of range
is a :class:`~services.config.ConfigError` naming the field)::

    name = "out and back"

    [[segments]]
    type = "waypoints"
    waypoints = [[1.0, 0.0], [0.0, 0.0]]

    [[segments]]
    type = "constant"
    vx = 0.0
    w = 0.5
    duration = 2.0

:class:`ScenarioRunner` plays a scenario tick by tick; :func:`planned_path` and
:func:`distance_to_path` give the path a scenario means to trace, for run reports.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import msgspec

from schemas.messages import NANOSECONDS_PER_SECOND
from schemas.navigation import MAX_GOAL_SECONDS
from services.config import ConfigError, DriveConfig, convert_toml
from services.drive.path_following import STOPPED, Command, PathFollower, Phase, Point
from services.planar import Pose, wrap_angle

PositiveSeconds = Annotated[float, msgspec.Meta(gt=0.0, le=MAX_GOAL_SECONDS)]  # 1e308 overflowed the drive's ns
PATH_SAMPLE_S = 0.05
"""Time step at which :func:`planned_path` samples a constant-velocity segment."""
PATH_SEGMENT_SAMPLES = 1000
"""The most points :func:`planned_path` gives one constant-velocity segment (a longer arc is
sampled more coarsely): a scenario of hours must not cost the drive seconds when it starts."""


def _require_finite(**values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"`{name}` must be finite, got {value}")


class ConstantSegment(msgspec.Struct, frozen=True, forbid_unknown_fields=True, tag="constant", tag_field="type"):
    """Hold the body velocity (vx, w) for ``duration`` seconds of simulation time."""

    vx: float
    w: float
    duration: PositiveSeconds

    def __post_init__(self) -> None:
        _require_finite(vx=self.vx, w=self.w, duration=self.duration)


class WaypointSegment(msgspec.Struct, frozen=True, forbid_unknown_fields=True, tag="waypoints", tag_field="type"):
    """Follow a path from wherever the robot is through ``waypoints`` ([x, y] in m, world frame)."""

    waypoints: Annotated[list[tuple[float, float]], msgspec.Meta(min_length=1)]

    def __post_init__(self) -> None:
        for index, (x, y) in enumerate(self.waypoints):
            _require_finite(**{f"waypoints[{index}].x": x, f"waypoints[{index}].y": y})


Segment = ConstantSegment | WaypointSegment


class Scenario(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    name: str = ""
    time_limit: PositiveSeconds | None = None
    """Simulated seconds one pass may last before the drive gives it up (``timed_out``); None: by
    the drive's rule (``drive.time_limit_factor`` × :func:`planned_duration` + ``drive.time_limit_margin``)."""
    segments: Annotated[list[Segment], msgspec.Meta(min_length=1)]


def _circle(name: str, speed: float, radius: float, turns: Sequence[int]) -> Scenario:
    """Full circles of ``radius`` at ``speed``, one per entry of ``turns`` (+1 left, -1 right)."""
    rate = speed / radius
    return Scenario(
        name=name,
        segments=[ConstantSegment(vx=speed, w=turn * rate, duration=2.0 * math.pi / rate) for turn in turns],
    )


BUILTIN_SCENARIOS: dict[str, Scenario] = {
    "straight": Scenario(name="straight", segments=[WaypointSegment(waypoints=[(2.0, 0.0)])]),
    "circle": _circle("circle", speed=0.25, radius=0.5, turns=[1]),
    "square": Scenario(
        name="square", segments=[WaypointSegment(waypoints=[(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)])]
    ),
    "figure8": _circle("figure8", speed=0.25, radius=0.5, turns=[1, -1]),
}
"""Paths from the initial pose (0, 0, 0): a 2 m straight line along +x, a circle of radius
0.5 m to the left, a 1 m square by waypoints back to the start, and a figure eight of two such
circles, left then right."""


def is_builtin(scenario: Scenario) -> bool:
    """Whether ``scenario`` is one of :data:`BUILTIN_SCENARIOS` (not a file's, even of that name)."""
    return any(scenario is builtin for builtin in BUILTIN_SCENARIOS.values())


def placed(scenario: Scenario, start: Pose) -> Scenario:
    """``scenario`` moved from the origin to ``start``: its waypoints turned by ``start.theta`` and
    shifted to (``start.x``, ``start.y``); constant segments are relative already. A built-in runs
    so from wherever its robot starts (a fleet's robots each from their own start)."""
    if (start.x, start.y, start.theta) == (0.0, 0.0, 0.0):
        return scenario
    cos, sin = math.cos(start.theta), math.sin(start.theta)

    def moved(segment: Segment) -> Segment:
        if isinstance(segment, ConstantSegment):
            return segment
        waypoints = [(start.x + cos * x - sin * y, start.y + sin * x + cos * y) for x, y in segment.waypoints]
        return WaypointSegment(waypoints=waypoints)

    return msgspec.structs.replace(scenario, segments=[moved(segment) for segment in scenario.segments])


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name, else a scenario TOML file; ConfigError naming what is wrong."""
    if name_or_path in BUILTIN_SCENARIOS:
        return BUILTIN_SCENARIOS[name_or_path]
    path = Path(name_or_path)
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(
            f"scenario {name_or_path!r} is neither a built-in ({', '.join(BUILTIN_SCENARIOS)}) "
            f"nor a readable file ({error.strerror})"
        ) from None
    return parse_scenario(text, source=str(path), default_name=path.stem)


def parse_scenario(text: str, source: str = "scenario", default_name: str = "") -> Scenario:
    """Parse scenario TOML; the name defaults to ``default_name`` when the file gives none."""
    scenario = convert_toml(text, Scenario, source)
    return scenario if scenario.name else msgspec.structs.replace(scenario, name=default_name)


def parse_waypoints(text: str) -> list[Point]:
    """``"1,0 1,1 0,1 0,0"`` -> [(1.0, 0.0), (1.0, 1.0), ...]; ConfigError naming the bad point."""
    points: list[Point] = []
    for index, item in enumerate(text.split()):
        parts = item.split(",")
        try:
            x, y = (float(part) for part in parts)
        except ValueError:
            raise ConfigError(f"waypoint {index + 1} {item!r} must be X,Y (two numbers)") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ConfigError(f"waypoint {index + 1} {item!r} must be finite")
        points.append((x, y))
    if not points:
        raise ConfigError("waypoints: give at least one X,Y")
    return points


class ScenarioRunner:
    """Plays a scenario: call :meth:`step` at every control tick with the simulation time.

    Time starts at the first step. A constant segment holds its command on the ticks in
    [start, start + duration); a waypoint segment waits (stopped) for a pose, then follows
    until done. ``loop`` starts over after the last segment, forever; otherwise the runner is
    then ``done`` and commands zero.
    """

    def __init__(self, scenario: Scenario, params: DriveConfig, loop: bool = False) -> None:
        self.scenario = scenario
        self.params = params
        self.loop = loop
        self.segment_index = 0
        self.iteration = 0
        self.done = False
        self.command = STOPPED
        self.waiting_for_pose = False
        self.start_ns: int | None = None
        self.now_ns: int | None = None
        self.pass_start_ns: int | None = None
        """When the current pass (iteration) began."""
        self._segment_start_ns: int | None = None
        self._follower: PathFollower | None = None

    @property
    def segment(self) -> Segment:
        return self.scenario.segments[self.segment_index]

    @property
    def elapsed_s(self) -> float:
        """Simulated seconds since the first step."""
        if self.start_ns is None or self.now_ns is None:
            return 0.0
        return (self.now_ns - self.start_ns) / NANOSECONDS_PER_SECOND

    @property
    def pass_elapsed_ns(self) -> int:
        """Simulated ns since the current pass began (0 before the first step)."""
        if self.pass_start_ns is None or self.now_ns is None:
            return 0
        return self.now_ns - self.pass_start_ns

    def give_up(self) -> None:
        """End the scenario where it is: from now on the runner is ``done`` and commands zero."""
        self.done = True
        self.waiting_for_pose = False
        self._follower = None
        self.command = STOPPED

    @property
    def waypoint_index(self) -> int | None:
        """Index of the waypoint the current waypoint segment approaches; None otherwise."""
        return self._follower.waypoint_index if self._follower is not None else None

    @property
    def phase(self) -> Phase | None:
        return self._follower.phase if self._follower is not None else None

    def step(self, now_ns: int, pose: Pose | None) -> Command:
        """The command from ``now_ns`` (simulation time, ns) until the next tick."""
        dt = 0.0 if self.now_ns is None else (now_ns - self.now_ns) / NANOSECONDS_PER_SECOND
        if self.start_ns is None:
            self.start_ns = self._segment_start_ns = self.pass_start_ns = now_ns
        self.now_ns = now_ns
        # Each segment that ends hands the same tick to the next, the current one plus one full
        # pass at most, so a looping scenario whose segments are all already done cannot spin.
        for _ in range(len(self.scenario.segments) + 1):
            if self.done:
                break
            command = self._segment_command(now_ns, pose, dt)
            if command is not None:
                self.command = command
                return command
            self._next_segment(now_ns)
        self.command = STOPPED
        return STOPPED

    def _segment_command(self, now_ns: int, pose: Pose | None, dt: float) -> Command | None:
        """The current segment's command, or None when the segment is over."""
        segment = self.segment
        assert self._segment_start_ns is not None
        if isinstance(segment, ConstantSegment):
            if now_ns - self._segment_start_ns < round(segment.duration * NANOSECONDS_PER_SECOND):
                return Command(segment.vx, segment.w)
            return None
        self.waiting_for_pose = pose is None
        if pose is None:
            if self._follower is not None:
                self._follower.command = STOPPED  # so following resumes with a ramp from rest
            return STOPPED
        if self._follower is None:
            self._follower = PathFollower(segment.waypoints, self.params, self.command)
        command = self._follower.step(pose, dt)
        return None if self._follower.done else command

    def _next_segment(self, now_ns: int) -> None:
        self._follower = None
        self.waiting_for_pose = False
        self._segment_start_ns = now_ns
        if self.segment_index + 1 < len(self.scenario.segments):
            self.segment_index += 1
        elif self.loop:
            self.segment_index = 0
            self.iteration += 1
            self.pass_start_ns = now_ns
        else:
            self.done = True


def _advance(pose: Pose, vx: float, w: float, dt: float) -> Pose:
    """Exact unicycle motion over ``dt`` at constant (vx, w)."""
    if w == 0.0:
        return Pose(pose.x + vx * dt * math.cos(pose.theta), pose.y + vx * dt * math.sin(pose.theta), pose.theta)
    theta = pose.theta + w * dt
    radius = vx / w
    return Pose(
        pose.x + radius * (math.sin(theta) - math.sin(pose.theta)),
        pose.y - radius * (math.cos(theta) - math.cos(pose.theta)),
        wrap_angle(theta),
    )


def planned_path(scenario: Scenario, start: Pose) -> list[Point]:
    """The path one pass of ``scenario`` means to trace from ``start``, as a polyline.

    A waypoint segment contributes its waypoints (the robot then faces along its last leg); a
    constant segment its arc, sampled every :data:`PATH_SAMPLE_S` simulated seconds.
    """
    pose = start
    path: list[Point] = [(start.x, start.y)]
    for segment in scenario.segments:
        if isinstance(segment, ConstantSegment):
            for elapsed in _arc_samples(segment):
                path.append(_xy(_advance(pose, segment.vx, segment.w, elapsed)))
            pose = _advance(pose, segment.vx, segment.w, segment.duration)
        else:
            heading = pose.theta
            for x, y in segment.waypoints:
                last_x, last_y = path[-1]
                if (x, y) != (last_x, last_y):
                    heading = math.atan2(y - last_y, x - last_x)
                path.append((x, y))
            pose = Pose(path[-1][0], path[-1][1], heading)
    return path


def planned_duration(scenario: Scenario, start: Pose, params: DriveConfig) -> float:
    """Simulated seconds one pass of ``scenario`` from ``start`` needs by its plan: a constant
    segment its duration; a waypoint segment each leg at ``cruise_speed`` (plus the time speeding
    up to it and braking from it, ``cruise_speed``/``max_acceleration``), and each corner sharper
    than ``turn_in_place_angle`` turned in place at ``max_turn_rate``. An estimate: the drive's
    time limit is a multiple of it, with a margin."""
    pose = start
    total = 0.0
    for segment in scenario.segments:
        if isinstance(segment, ConstantSegment):
            total += segment.duration
            pose = _advance(pose, segment.vx, segment.w, segment.duration)
            continue
        heading, here = pose.theta, (pose.x, pose.y)
        for point in segment.waypoints:
            length = math.dist(here, point)
            if length <= params.goal_tolerance:
                continue
            leg_heading = math.atan2(point[1] - here[1], point[0] - here[0])
            turn = abs(wrap_angle(leg_heading - heading))
            if turn > params.turn_in_place_angle:
                total += turn / params.max_turn_rate
            total += length / params.cruise_speed + params.cruise_speed / params.max_acceleration
            heading, here = leg_heading, point
        pose = Pose(here[0], here[1], heading)
    return total


def goal_duration(pose: Pose, x: float, y: float, theta: float | None, params: DriveConfig) -> float:
    """Simulated seconds the drive's plan needs from ``pose`` to a goal (services/drive/goals.py):
    :func:`planned_duration` of the one leg to (``x``, ``y``), then the turn in place to ``theta``."""
    leg = Scenario(segments=[WaypointSegment(waypoints=[(x, y)])])
    heading = pose.theta
    if math.hypot(x - pose.x, y - pose.y) > params.goal_tolerance:
        heading = math.atan2(y - pose.y, x - pose.x)
    turn = 0.0 if theta is None else abs(wrap_angle(theta - heading)) / params.max_turn_rate
    return planned_duration(leg, pose, params) + turn


def _arc_samples(segment: ConstantSegment) -> list[float]:
    """The times into ``segment`` at which its path is sampled: a straight line needs its end
    only; an arc every :data:`PATH_SAMPLE_S` over one turn at most (beyond, it retraces the
    circle), at most :data:`PATH_SEGMENT_SAMPLES` of them, and its end."""
    if segment.w == 0.0:
        return [segment.duration]
    traced = min(segment.duration, 2.0 * math.pi / abs(segment.w))
    samples = min(PATH_SEGMENT_SAMPLES, max(1, math.ceil(traced / PATH_SAMPLE_S)))
    times = [traced * index / samples for index in range(1, samples + 1)]
    return times if traced == segment.duration else [*times, segment.duration]


def planned_path_for(name_or_path: str, start: tuple[float, float, float] | None = None) -> list[Point]:
    """:func:`planned_path` of a built-in (:func:`placed` at ``start``) or a scenario file, from
    ``start`` (x, y, θ; default the origin)."""
    scenario = load_scenario(name_or_path)
    pose = Pose(*start) if start is not None else Pose(0.0, 0.0, 0.0)
    return planned_path(placed(scenario, pose) if is_builtin(scenario) else scenario, pose)


def _xy(pose: Pose) -> Point:
    return (pose.x, pose.y)


def distance_to_path(point: Point, path: Sequence[Point]) -> float:
    """Shortest distance from ``point`` to the polyline ``path`` (to the point itself if it has one)."""
    if not path:
        raise ValueError("empty path")
    if len(path) == 1:
        return math.dist(point, path[0])
    return min(_distance_to_segment(point, a, b) for a, b in itertools.pairwise(path))


def _distance_to_segment(point: Point, a: Point, b: Point) -> float:
    dx, dy = b[0] - a[0], b[1] - a[1]
    length_squared = dx * dx + dy * dy
    t = 0.0
    if length_squared > 0.0:
        t = min(1.0, max(0.0, ((point[0] - a[0]) * dx + (point[1] - a[1]) * dy) / length_squared))
    return math.dist(point, (a[0] + t * dx, a[1] + t * dy))


def describe(scenario: Scenario) -> str:
    """One line per segment, for ``--help``-style listings and logs."""
    lines = []
    for index, segment in enumerate(scenario.segments):
        if isinstance(segment, ConstantSegment):
            lines.append(f"{index}: constant vx={segment.vx:g} m/s w={segment.w:g} rad/s for {segment.duration:g} s")
        else:
            lines.append(f"{index}: waypoints {json.dumps(segment.waypoints)}")
    return "\n".join(lines)
