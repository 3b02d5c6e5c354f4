"""The collision monitor's geometry (docs/protocol.md section 4.10, docs/motor.md "Collision
monitor"): pure, no zenoh; numpy, since it runs once per scan or per change of the command, never
per control cycle.

A scan becomes points in the base frame (:class:`ScanPoints`, through the lidar's mount); a
commanded body velocity (vx, w) sweeps the footprint, a circle of radius ``body + margin`` about
the axle centre, along the arc its centre follows for a given length (:func:`in_swept_zone`);
:func:`judge` says whether at least ``min_points`` points lie in the stop zone (``stop_distance`` of
sweep), else in the slow-down zone (``slow_distance``), else the way is clear: fewer, a stray return
or two, do not act (Nav2's ``min_points``).

The swept zone is exact: a point is in it when its distance to the centre's path (an arc of
radius ρ = vx/w about (0, ρ), or a segment when w ≈ 0) is at most the footprint's radius, i.e.
the annulus sector about the arc, and the two discs (end caps) at its ends; a turn in place
(vx = 0) sweeps the footprint alone; a backward command sweeps backwards. A zero command moves
nothing and has no zone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from schemas.messages import NO_HIT, LaserScan
from services.config import RobotConfig
from services.config.sensors import CollisionMonitorConfig, LidarConfig

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

STRAIGHT_TURN = 1e-6
"""Below this turn (rad) over the swept length, the path is taken for a straight line: the arc
strays less than length × 5·10⁻⁷ from it (and ρ = vx/w would lose precision far away)."""


class Zone(StrEnum):
    CLEAR = "clear"
    SLOW = "slow"
    STOP = "stop"


@dataclass(frozen=True)
class MonitorGeometry:
    """What the monitor needs of the robot description: the footprint and zones, the lidar's mount."""

    body_radius: float
    margin: float
    stop_distance: float
    slow_distance: float
    lidar_x: float = 0.0
    lidar_y: float = 0.0
    lidar_yaw: float = 0.0
    min_points: int = 1
    """How many points in a zone make it act (``collision_monitor.min_points``); 1, any point, in a
    geometry built by hand."""

    def __post_init__(self) -> None:
        if self.min_points < 1:
            raise ValueError(f"min_points = {self.min_points} must be at least 1")

    @classmethod
    def of(cls, robot: RobotConfig, lidar: LidarConfig, monitor: CollisionMonitorConfig) -> MonitorGeometry:
        return cls(
            robot.radius_of_body_area,
            monitor.margin,
            monitor.stop_distance,
            monitor.slow_distance,
            lidar.x,
            lidar.y,
            lidar.yaw,
            monitor.min_points,
        )

    @property
    def footprint_radius(self) -> float:
        return self.body_radius + self.margin


@dataclass(frozen=True)
class Obstacle:
    """One point of a scan: where it is in the base frame, what the ray hit ("" when the scan
    does not say) and its clearance, the distance from the body's edge (negative: inside it)."""

    x: float
    y: float
    body: str
    clearance: float


class ScanPoints:
    """A scan's points in the base frame: one per ray whose range is within [range_min, range_max)
    (a range below range_min is not a measurement, as REP 117 has it; None is nothing seen)."""

    def __init__(self, x: Floats, y: Floats, body: npt.NDArray[np.intp], bodies: list[str], body_radius: float):
        self.x, self.y = x, y
        self._body, self._bodies = body, bodies
        self.clearance: Floats = np.hypot(x, y) - body_radius

    @classmethod
    def from_scan(cls, scan: LaserScan, geometry: MonitorGeometry) -> ScanPoints:
        count = len(scan.ranges)
        ranges = np.array([math.nan if value is None else value for value in scan.ranges], dtype=np.float64)
        valid = (ranges >= scan.range_min) & (ranges < scan.range_max)  # NaN (None) fails both
        index = np.flatnonzero(valid)
        angles = geometry.lidar_yaw + scan.angle_min + index * scan.angle_increment
        r = ranges[index]
        x = geometry.lidar_x + r * np.cos(angles)
        y = geometry.lidar_y + r * np.sin(angles)
        hits = np.array(scan.hits, dtype=np.intp) if scan.hits else np.full(count, NO_HIT, dtype=np.intp)
        return cls(x, y, hits[index], list(scan.bodies), geometry.body_radius)

    def __len__(self) -> int:
        return int(self.x.size)

    def obstacle(self, i: int) -> Obstacle:
        hit = int(self._body[i])
        return Obstacle(
            float(self.x[i]), float(self.y[i]), self._bodies[hit] if hit != NO_HIT else "", float(self.clearance[i])
        )

    def nearest(self, mask: Bools | None = None) -> Obstacle | None:
        """The point of least clearance (among ``mask``'s); None when there is none."""
        candidates = np.flatnonzero(mask) if mask is not None else np.arange(len(self))
        if candidates.size == 0:
            return None
        return self.obstacle(int(candidates[np.argmin(self.clearance[candidates])]))


def in_swept_zone(x: Floats, y: Floats, vx: float, w: float, radius: float, length: float) -> Bools:
    """Which points (x, y) (base frame) the footprint, a circle of ``radius`` about the axle centre,
    covers as the centre travels ``length`` along the path of (vx, w): forward for vx > 0, backward
    for vx < 0, an arc of radius vx/w (a straight line when it turns less than :data:`STRAIGHT_TURN`);
    for vx = 0 the footprint alone (a turn in place, or no motion)."""
    reach = radius * radius
    if vx == 0.0 or length == 0.0:
        return (x * x + y * y) <= reach
    turn = length * abs(w) / abs(vx)
    if turn < STRAIGHT_TURN:
        sign = math.copysign(1.0, vx)
        dx = x - sign * np.clip(sign * x, 0.0, length)  # from the nearest point of the segment
        return (dx * dx + y * y) <= reach
    rho = vx / w  # signed: the centre of rotation is (0, rho), left for rho > 0
    about = abs(rho)
    px, py = x, y - rho
    # The centre starts at angle -π/2·sign(rho) about (0, rho) and turns by sign(w)·turn.
    start = -math.copysign(math.pi / 2.0, rho)
    direction = math.copysign(1.0, w)
    if turn >= 2.0 * math.pi:
        within = np.ones(x.shape, dtype=np.bool_)
    else:
        angle = np.arctan2(py, px)
        swept = np.mod((angle - start) * direction, 2.0 * math.pi)  # how far along the arc, as an angle
        within = swept <= turn
    ring = np.abs(np.hypot(px, py) - about)
    in_sector = within & (ring * ring <= reach)
    end_angle = start + direction * turn
    ex, ey = about * math.cos(end_angle), rho + about * math.sin(end_angle)
    in_caps = ((x * x + y * y) <= reach) | (((x - ex) ** 2 + (y - ey) ** 2) <= reach)
    return in_sector | in_caps


@dataclass(frozen=True)
class Verdict:
    """What the scan says of a command: its zone and, unless clear, the nearest of the points in
    that zone (at least ``min_points`` of them)."""

    zone: Zone
    obstacle: Obstacle | None = None

    def describe(self, vx: float) -> str:
        """``obstacle 'box' in the stop zone, 0.31 m ahead at (0.76, 0.02) in base_link``."""
        obstacle = self.obstacle
        if obstacle is None:
            return ""
        what = f"obstacle {obstacle.body!r}" if obstacle.body else "an obstacle"
        side = "ahead" if vx > 0 else "behind" if vx < 0 else "from the body"
        return (
            f"{what} in the {self.zone} zone, {max(obstacle.clearance, 0.0):.2f} m {side} "
            f"at ({obstacle.x:.2f}, {obstacle.y:.2f}) in base_link"
        )


CLEAR = Verdict(Zone.CLEAR)


def judge(points: ScanPoints, vx: float, w: float, geometry: MonitorGeometry) -> Verdict:
    """The zone of the command (vx, w) given the scan's ``points``: ``stop`` if at least
    ``geometry.min_points`` points lie in the stop zone, else ``slow`` if as many lie in the
    slow-down zone (when ``slow_distance`` > 0; it holds the stop zone, so the points in that count
    too), else ``clear``; a zero command is always clear (nothing moves)."""
    min_points = geometry.min_points
    if (vx == 0.0 and w == 0.0) or len(points) < min_points:
        return CLEAR
    radius = geometry.footprint_radius
    for zone, length in ((Zone.STOP, geometry.stop_distance), (Zone.SLOW, geometry.slow_distance)):
        if zone is Zone.SLOW and length <= 0.0:
            break
        mask = in_swept_zone(points.x, points.y, vx, w, radius, length)
        if np.count_nonzero(mask) >= min_points:
            return Verdict(zone, points.nearest(mask))
    return CLEAR
