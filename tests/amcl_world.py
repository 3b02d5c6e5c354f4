"""A synthetic world for the particle filter's tests and benchmark: a room of rectangles (walls and
boxes, deliberately asymmetric), its map as a Grid, scans cast in it exactly (ray against rectangle),
a path driven around it and the odometry of wheels that are about 1 % off."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from services.config.sensors import LidarConfig
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry
from services.planar import Pose, wrap_angle

Rectangle = tuple[float, float, float, float]
"""x0, y0, x1, y1 (m, x0 < x1, y0 < y1)."""

WALL = 0.1
ROOM_WIDTH = 6.0
ROOM_DEPTH = 4.0
ROOM: tuple[Rectangle, ...] = (
    (-WALL, -WALL, ROOM_WIDTH + WALL, 0.0),  # the walls, outside [0, 6] × [0, 4]
    (-WALL, ROOM_DEPTH, ROOM_WIDTH + WALL, ROOM_DEPTH + WALL),
    (-WALL, 0.0, 0.0, ROOM_DEPTH),
    (ROOM_WIDTH, 0.0, ROOM_WIDTH + WALL, ROOM_DEPTH),
    (2.0, 1.6, 2.6, 2.4),  # a box off the middle, inside the path
    (0.0, 0.0, 0.7, 0.45),  # a cupboard in one corner
    (4.8, 3.6, 6.0, 4.0),  # a bench along the top wall, in the opposite corner
    (4.0, 0.0, 4.25, 0.5),  # a pillar against the bottom wall
    (0.0, 2.4, 0.3, 3.4),  # a shelf against the left wall
)
RESOLUTION = 0.05
MARGIN = 0.5
"""m of unknown cells around the room on the map."""
LIDAR = LidarConfig(noise=0.01)


def room_grid(rectangles: Sequence[Rectangle] = ROOM, resolution: float = RESOLUTION) -> Grid:
    """The map: cells whose centre lies in a rectangle occupied, the rest of the room free, unknown
    around it."""
    size_x, size_y = ROOM_WIDTH + 2 * MARGIN, ROOM_DEPTH + 2 * MARGIN
    geometry = GridGeometry(resolution, round(size_x / resolution), round(size_y / resolution), -MARGIN, -MARGIN)
    centres_x = geometry.origin_x + (np.arange(geometry.width) + 0.5) * resolution
    centres_y = geometry.origin_y + (np.arange(geometry.height) + 0.5) * resolution
    x, y = np.meshgrid(centres_x, centres_y)
    cells = np.full(geometry.shape, UNKNOWN, dtype=np.int8)
    cells[(x > 0) & (x < ROOM_WIDTH) & (y > 0) & (y < ROOM_DEPTH)] = FREE
    for x0, y0, x1, y1 in rectangles:
        cells[(x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)] = OCCUPIED
    return Grid(geometry, cells)


def cast(
    pose: Pose,
    rng: np.random.Generator | None = None,
    lidar: LidarConfig = LIDAR,
    rectangles: Sequence[Rectangle] = ROOM,
) -> npt.NDArray[np.float64]:
    """The lidar's scan at ``pose`` (the base's): each ray's range to the nearest rectangle (slab
    method), with the lidar's Gaussian noise if ``rng`` is given; inf beyond ``range_max``."""
    cos, sin = math.cos(pose.theta), math.sin(pose.theta)
    origin_x = pose.x + cos * lidar.x - sin * lidar.y
    origin_y = pose.y + sin * lidar.x + cos * lidar.y
    angles = pose.theta + lidar.yaw + lidar.angle_min + np.arange(lidar.rays) * lidar.angle_increment
    dx, dy = np.cos(angles), np.sin(angles)
    boxes = np.asarray(rectangles)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx0 = (boxes[:, None, 0] - origin_x) / dx
        tx1 = (boxes[:, None, 2] - origin_x) / dx
        ty0 = (boxes[:, None, 1] - origin_y) / dy
        ty1 = (boxes[:, None, 3] - origin_y) / dy
        enter = np.maximum(np.minimum(tx0, tx1), np.minimum(ty0, ty1))
        leave = np.minimum(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
    hit = (enter <= leave) & (leave > 0) & np.isfinite(enter)
    ranges = np.where(hit, np.maximum(enter, 0.0), np.inf).min(axis=0)
    if rng is not None:
        ranges = ranges + rng.normal(0.0, lidar.noise, ranges.size)
    return np.where(ranges < lidar.range_max, ranges, np.inf)


def loop_pose(distance: float) -> Pose:
    """The pose ``distance`` m along the path: an ellipse about the middle box, counter-clockwise,
    heading along it."""
    # parameterized by angle; the speed along it varies a little, which the tests do not mind
    centre_x, centre_y, a, b = 3.0, 2.0, 2.0, 1.15
    perimeter = math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))
    phase = 2 * math.pi * distance / perimeter - math.pi / 2
    x, y = centre_x + a * math.cos(phase), centre_y + b * math.sin(phase)
    heading = math.atan2(b * math.cos(phase), -a * math.sin(phase))
    return Pose(x, y, heading)


@dataclass
class WheelOdometry:
    """Dead reckoning from wheels whose radii and axle are off by the given fractions: each step of
    the true motion (a forward distance and a turn) is measured as the wheels would, then integrated."""

    axle: float = 0.3
    left_error: float = 0.01
    right_error: float = -0.005
    axle_error: float = 0.01
    pose: Pose = Pose(0.0, 0.0, 0.0)

    def step(self, true_start: Pose, true_end: Pose) -> Pose:
        forward = math.hypot(true_end.x - true_start.x, true_end.y - true_start.y)
        turn = wrap_angle(true_end.theta - true_start.theta)
        left = (forward - turn * self.axle / 2) * (1 + self.left_error)
        right = (forward + turn * self.axle / 2) * (1 + self.right_error)
        distance, rotation = (left + right) / 2, (right - left) / (self.axle * (1 + self.axle_error))
        heading = self.pose.theta + rotation / 2
        self.pose = Pose(
            self.pose.x + distance * math.cos(heading),
            self.pose.y + distance * math.sin(heading),
            wrap_angle(self.pose.theta + rotation),
        )
        return self.pose


def drive(
    seconds: float, speed: float = 0.2, period: float = 0.1, start: float = 0.0, odometry: WheelOdometry | None = None
) -> Iterator[tuple[Pose, Pose]]:
    """(true pose, odometry pose) at each scan along the loop, at ``speed`` m/s from ``start`` m along
    it; ``odometry`` continues from where it is (a kidnapped robot's wheels saw nothing of the jump)."""
    wheels = WheelOdometry() if odometry is None else odometry
    previous = loop_pose(start)
    for step in range(1, round(seconds / period) + 1):
        pose = loop_pose(start + speed * period * step)
        yield pose, wheels.step(previous, pose)
        previous = pose
