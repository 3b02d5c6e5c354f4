"""The kinematic engine's world by geometry (:mod:`sim_bridge.kinematic`): the obstacles of a world
file as shapes seen from above (a box a rotated rectangle, a cylinder a circle), how far a robot's
footprint (a disc) is from each, and where a lidar's rays first hit them or another robot. Pure:
numpy, no PyBullet, no zenoh. The obstacles do not move: a box or cylinder with a mass stays where
the world file puts it (PyBullet would push it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.messages import NO_HIT
from sim_bridge.sensors import RayHit
from sim_bridge.world import World

Array = npt.NDArray[np.float64]
Point = tuple[float, float]
_MISS: RayHit = (NO_HIT, -1, 1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
"""A ray that hits nothing, as PyBullet's ``rayTestBatch`` reports it."""


@dataclass(frozen=True)
class Rectangle:
    """A box seen from above: centre, yaw, half lengths, and its height above the floor."""

    name: str
    x: float
    y: float
    yaw: float
    half_x: float
    half_y: float
    height: float

    def nearest(self, x: float, y: float) -> tuple[float, Point]:
        """The signed distance from (x, y) to the rectangle (negative inside) and the nearest
        point of its outline."""
        cos, sin = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy = x - self.x, y - self.y
        lx, ly = cos * dx + sin * dy, -sin * dx + cos * dy
        qx, qy = abs(lx) - self.half_x, abs(ly) - self.half_y
        if qx > 0.0 or qy > 0.0:
            distance = math.hypot(max(qx, 0.0), max(qy, 0.0))
            px, py = min(max(lx, -self.half_x), self.half_x), min(max(ly, -self.half_y), self.half_y)
        else:
            distance = max(qx, qy)
            px, py = (math.copysign(self.half_x, lx), ly) if qx > qy else (lx, math.copysign(self.half_y, ly))
        return distance, (self.x + cos * px - sin * py, self.y + sin * px + cos * py)


@dataclass(frozen=True)
class Circle:
    """An upright cylinder seen from above (or a robot's body, for the rays): centre, radius, and
    its height above the floor."""

    name: str
    x: float
    y: float
    radius: float
    height: float

    def nearest(self, x: float, y: float) -> tuple[float, Point]:
        dx, dy = x - self.x, y - self.y
        centre = math.hypot(dx, dy)
        if centre == 0.0:
            dx, dy, centre = 1.0, 0.0, 1.0
        scale = self.radius / centre
        return centre - self.radius, (self.x + dx * scale, self.y + dy * scale)


Shape = Rectangle | Circle


def world_shapes(world: World) -> tuple[Shape, ...]:
    """The world's obstacles, boxes first then cylinders (the order of ``sim/world`` and PyBullet's)."""
    boxes: list[Shape] = [
        Rectangle(box.name, box.x, box.y, box.yaw, box.size[0] / 2.0, box.size[1] / 2.0, box.size[2])
        for box in world.boxes
    ]
    cylinders: list[Shape] = [Circle(c.name, c.x, c.y, c.radius, c.height) for c in world.cylinders]
    return (*boxes, *cylinders)


def footprint_gap(shape: Shape, x: float, y: float, reach: float) -> tuple[float, Point]:
    """How far a footprint of radius ``reach`` centred on (x, y) is from ``shape`` (negative: it
    overlaps it by that much), and the point of the shape's outline nearest its centre."""
    distance, point = shape.nearest(x, y)
    return distance - reach, point


def _circle_hits(shape: Circle, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array, Array]:
    """Each ray's fraction where it enters the circle (inf: it does not), and the normal there."""
    fx, fy = sx - shape.x, sy - shape.y
    a = dx * dx + dy * dy
    b = fx * dx + fy * dy
    c = fx * fx + fy * fy - shape.radius * shape.radius
    discriminant = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(discriminant)) / a
    hit = (discriminant >= 0.0) & (c > 0.0) & (t >= 0.0) & (t <= 1.0)
    at = np.where(hit, t, 0.0)
    return np.where(hit, t, np.inf), (fx + at * dx) / shape.radius, (fy + at * dy) / shape.radius


def _rectangle_hits(shape: Rectangle, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array, Array]:
    """Each ray's fraction where it enters the rectangle (slabs; inf: it does not), and the normal there."""
    cos, sin = math.cos(shape.yaw), math.sin(shape.yaw)
    lx, ly = cos * (sx - shape.x) + sin * (sy - shape.y), -sin * (sx - shape.x) + cos * (sy - shape.y)
    ldx, ldy = cos * dx + sin * dy, -sin * dx + cos * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        x1, x2 = (-shape.half_x - lx) / ldx, (shape.half_x - lx) / ldx
        y1, y2 = (-shape.half_y - ly) / ldy, (shape.half_y - ly) / ldy
    x_in, x_out = np.fmin(x1, x2), np.fmax(x1, x2)
    y_in, y_out = np.fmin(y1, y2), np.fmax(y1, y2)
    # a ray parallel to a pair of sides is inside that slab all along, or never
    x_in = np.where(ldx == 0.0, np.where(np.abs(lx) < shape.half_x, -np.inf, np.inf), x_in)
    y_in = np.where(ldy == 0.0, np.where(np.abs(ly) < shape.half_y, -np.inf, np.inf), y_in)
    x_out = np.where(ldx == 0.0, np.inf, x_out)
    y_out = np.where(ldy == 0.0, np.inf, y_out)
    enter, leave = np.maximum(x_in, y_in), np.minimum(x_out, y_out)
    t = np.where((enter <= leave) & (enter > 0.0) & (enter <= 1.0), enter, np.inf)
    across_x = x_in >= y_in
    local_nx = np.where(across_x, -np.sign(ldx), 0.0)
    local_ny = np.where(across_x, 0.0, -np.sign(ldy))
    return t, cos * local_nx - sin * local_ny, sin * local_nx + cos * local_ny


class RayCaster:
    """Casts a robot's lidar rays against the obstacles and the other robots (each a circle of its
    body's radius, as tall as its body's top), in the plane of the rays. Body ids: the obstacles
    in :func:`world_shapes`' order, then the robots in the world's order (:attr:`names`)."""

    def __init__(self, obstacles: Sequence[Shape], robots: Sequence[tuple[str, float, float]]) -> None:
        """``robots``: each robot's name, body radius and the height of its body's top."""
        self.obstacles = tuple(obstacles)
        self.robots = tuple(robots)
        self.names = {index: shape.name for index, shape in enumerate(self.obstacles)}
        self.names.update({len(self.obstacles) + index: name for index, (name, _, _) in enumerate(self.robots)})

    def cast(self, caster: int, positions: Sequence[Point], starts: Array, ends: Array) -> list[RayHit]:
        """Robot ``caster``'s rays from ``starts`` to ``ends`` (world, one row a ray, level), the
        robots at ``positions``: the first hit of each, as PyBullet's ``rayTestBatch`` reports it."""
        sx, sy, height = starts[:, 0], starts[:, 1], float(starts[0, 2])
        dx, dy = ends[:, 0] - sx, ends[:, 1] - sy
        best = np.full(len(sx), np.inf)
        body = np.full(len(sx), NO_HIT)
        nx, ny = np.zeros(len(sx)), np.zeros(len(sx))
        targets: list[tuple[int, Shape]] = list(enumerate(self.obstacles))
        for index, ((name, radius, top), (x, y)) in enumerate(zip(self.robots, positions, strict=True)):
            if index != caster:
                targets.append((len(self.obstacles) + index, Circle(name, x, y, radius, top)))
        for body_id, shape in targets:
            if not 0.0 <= height <= shape.height:
                continue
            if isinstance(shape, Circle):
                t, hit_nx, hit_ny = _circle_hits(shape, sx, sy, dx, dy)
            else:
                t, hit_nx, hit_ny = _rectangle_hits(shape, sx, sy, dx, dy)
            nearer = t < best
            best = np.where(nearer, t, best)
            body = np.where(nearer, body_id, body)
            nx, ny = np.where(nearer, hit_nx, nx), np.where(nearer, hit_ny, ny)
        results: list[RayHit] = []
        for ray, (hit, t) in enumerate(zip(body.tolist(), best.tolist(), strict=True)):
            if hit == NO_HIT:
                results.append(_MISS)
            else:
                position = (float(sx[ray] + t * dx[ray]), float(sy[ray] + t * dy[ray]), height)
                results.append((hit, -1, t, position, (float(nx[ray]), float(ny[ray]), 0.0)))
        return results
