"""Synthetic worlds for the mapping's tests and benchmark: walls as line segments, a numpy lidar
cast in them, a robot driven through them and a differential-drive odometry whose left wheel is
off by a factor, and the measure of a map's quality (the share of its occupied cells near a wall)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.messages import LaserScan, Time
from services.navigation.grid import OCCUPIED, Grid
from services.planar import Pose, wrap_angle

Floats = npt.NDArray[np.float64]
Segments = Floats
"""``[n, 4]``: x0, y0, x1, y1 of each wall segment."""

AXLE = 0.441
"""m: the default robot's axle (services/config/sections.py's ``length_of_axle``)."""
WHEEL_RADIUS = 0.1
"""m: the default robot's wheels (``radius_of_left_wheel``, ``radius_of_right_wheel``)."""
ODOMETRY_PERIOD_NS = 20_000_000
SCAN_PERIOD_NS = 100_000_000


def box(x: float, y: float, width: float, height: float) -> list[tuple[float, float, float, float]]:
    """The four sides of an axis-aligned box centred on (x, y)."""
    x0, x1, y0, y1 = x - width / 2, x + width / 2, y - height / 2, y + height / 2
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def three_rooms() -> Segments:
    """sim_bridge/worlds/three_rooms.toml's walls (0.1 m thick boxes), with a pillar in room 2."""
    boxes = [
        (4.0, -2.0, 12.1, 0.1),
        (4.0, 2.0, 12.1, 0.1),
        (-2.0, 0.0, 0.1, 4.1),
        (10.0, 0.0, 0.1, 4.1),
        (2.0, -0.9, 0.1, 2.1),
        (6.0, 0.9, 0.1, 2.1),
        (4.0, -1.0, 0.3, 0.3),
    ]
    return np.array([side for b in boxes for side in box(*b)], dtype=np.float64)


THREE_ROOMS_TOUR = [
    (0.0, 0.0),
    (1.0, 1.0),
    (3.0, 1.0),
    (5.0, -1.0),
    (8.0, -1.0),
    (8.0, 1.0),
    (5.0, -1.2),
    (3.0, 1.0),
    (0.0, -1.0),
]
"""Waypoints from room 1 to room 3 and back, through both doors."""


def cast(segments: Segments, x: float, y: float, angles: Floats, range_max: float) -> Floats:
    """The range along each angle from (x, y) to the nearest segment; inf past ``range_max``."""
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    sx, sy = (segments[:, 2] - segments[:, 0])[None, :], (segments[:, 3] - segments[:, 1])[None, :]
    ox, oy = (segments[:, 0] - x)[None, :], (segments[:, 1] - y)[None, :]
    denominator = dx * sy - dy * sx
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ox * sy - oy * sx) / denominator
        u = (ox * dy - oy * dx) / denominator
    valid = (np.abs(denominator) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    ranges = np.where(valid, t, np.inf).min(axis=1)
    return np.where(ranges <= range_max, ranges, np.inf)


def scan_at(
    segments: Segments, pose: Pose, stamp_ns: int, rng: np.random.Generator, noise: float = 0.01, rays: int = 360
) -> LaserScan:
    """A scan of ``rays`` all round from a lidar at the base's origin, ranges with Gaussian noise."""
    increment = 2.0 * math.pi / rays
    angle_min = -math.pi
    angles = (pose.theta + angle_min + increment * np.arange(rays)).astype(np.float64)
    ranges = cast(segments, pose.x, pose.y, angles, 3.5)
    ranges = ranges + rng.normal(0.0, noise, rays)
    return LaserScan(
        tm=Time.from_nanoseconds(stamp_ns),
        angle_min=angle_min,
        angle_increment=increment,
        range_min=0.12,
        range_max=3.5,
        ranges=[None if not math.isfinite(r) else max(float(r), 0.0) for r in ranges],
    )


@dataclass(frozen=True)
class Step:
    """One odometry period: when, where the robot truly is, and what the odometry says."""

    stamp_ns: int
    truth: Pose
    odometry: Pose
    wheel_angles: tuple[float, float] = (0.0, 0.0)
    """rad: what the encoders read (left, right), the left as long as the odometry takes it."""


def drive(
    waypoints: list[tuple[float, float]],
    left_scale: float = 1.01,
    speed: float = 0.3,
    turn_rate: float = 0.8,
    laps: int = 1,
) -> Iterator[Step]:
    """The robot turning on the spot towards each waypoint then driving to it, every 20 ms; the
    odometry integrates wheel travel with the left wheel's read ``left_scale`` times too long."""
    truth = odometry = Pose(waypoints[0][0], waypoints[0][1], 0.0)
    dt = ODOMETRY_PERIOD_NS / 1e9
    stamp = 0
    angle_left = angle_right = 0.0
    yield Step(stamp, truth, odometry)
    for target in [w for _ in range(laps) for w in waypoints[1:]]:
        while True:
            heading = math.atan2(target[1] - truth.y, target[0] - truth.x)
            error = wrap_angle(heading - truth.theta)
            distance = math.hypot(target[0] - truth.x, target[1] - truth.y)
            if distance < speed * dt:
                break
            if abs(error) > 0.02:
                v, w = 0.0, math.copysign(min(turn_rate, abs(error) / dt), error)
            else:
                v, w = min(speed, distance / dt), error / dt
            left, right = (v - w * AXLE / 2) * dt, (v + w * AXLE / 2) * dt
            truth = _integrate(truth, left, right)
            odometry = _integrate(odometry, left * left_scale, right)
            angle_left += left * left_scale / WHEEL_RADIUS
            angle_right += right / WHEEL_RADIUS
            stamp += ODOMETRY_PERIOD_NS
            yield Step(stamp, truth, odometry, (angle_left, angle_right))


def _integrate(pose: Pose, left: float, right: float) -> Pose:
    forward, turn = (left + right) / 2, (right - left) / AXLE
    middle = pose.theta + turn / 2
    return Pose(pose.x + forward * math.cos(middle), pose.y + forward * math.sin(middle), wrap_angle(pose.theta + turn))


def run_of(
    segments: Segments, steps: list[Step], seed: int, noise: float = 0.01, rays: int = 360
) -> Iterator[tuple[Step, LaserScan | None]]:
    """Each odometry step with the scan taken at it (every 100 ms), or None."""
    rng = np.random.default_rng(seed)
    for step in steps:
        at_scan = step.stamp_ns % SCAN_PERIOD_NS == 0
        scan = scan_at(segments, step.truth, step.stamp_ns, rng, noise, rays) if at_scan else None
        yield step, scan


def distances_to_walls(segments: Segments, x: Floats, y: Floats) -> Floats:
    """Each point's distance to the nearest segment."""
    x0, y0 = segments[:, 0][None, :], segments[:, 1][None, :]
    sx, sy = (segments[:, 2] - segments[:, 0])[None, :], (segments[:, 3] - segments[:, 1])[None, :]
    px, py = x[:, None] - x0, y[:, None] - y0
    t = np.clip((px * sx + py * sy) / (sx * sx + sy * sy), 0.0, 1.0)
    return np.hypot(px - t * sx, py - t * sy).min(axis=1)


def share_near_walls(grid: Grid, segments: Segments, tolerance: float = 0.10) -> float:
    """The share of the map's occupied cells whose centre is within ``tolerance`` of a wall."""
    rows, cols = np.nonzero(grid.cells == OCCUPIED)
    if not len(rows):
        return 0.0
    geometry = grid.geometry
    x = (geometry.origin_x + (cols + 0.5) * geometry.resolution).astype(np.float64)
    y = (geometry.origin_y + (rows + 0.5) * geometry.resolution).astype(np.float64)
    return float(np.mean(distances_to_walls(segments, x, y) <= tolerance))
