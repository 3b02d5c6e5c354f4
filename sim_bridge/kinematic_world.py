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

    def extent(self) -> Point:
        """Half the width and height of the smallest axis-aligned box holding it, about its centre."""
        cos, sin = abs(math.cos(self.yaw)), abs(math.sin(self.yaw))
        return cos * self.half_x + sin * self.half_y, sin * self.half_x + cos * self.half_y


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

    def extent(self) -> Point:
        """Half the width and height of the smallest axis-aligned box holding it, about its centre."""
        return self.radius, self.radius


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


def _column(values: Array) -> Array:
    return values.reshape(-1, 1)


@dataclass(frozen=True)
class _Rectangles:
    """Rectangles as arrays, one element a rectangle: as columns (:meth:`columns`) to cast every ray
    at every rectangle at once, or one a ray (:meth:`take`) for each ray's own."""

    x: Array
    y: Array
    cos: Array
    sin: Array
    half_x: Array
    half_y: Array

    @classmethod
    def of(cls, shapes: Sequence[Rectangle]) -> _Rectangles:
        def values(numbers: Sequence[float]) -> Array:
            return np.array(numbers, dtype=np.float64)

        # math's cos and sin, not numpy's, which may differ in the last bit
        return cls(
            values([s.x for s in shapes]),
            values([s.y for s in shapes]),
            values([math.cos(s.yaw) for s in shapes]),
            values([math.sin(s.yaw) for s in shapes]),
            values([s.half_x for s in shapes]),
            values([s.half_y for s in shapes]),
        )

    def _arrays(self) -> tuple[Array, ...]:
        return self.x, self.y, self.cos, self.sin, self.half_x, self.half_y

    def take(self, rows: npt.NDArray[np.intp] | npt.NDArray[np.bool_]) -> _Rectangles:
        return _Rectangles(*(values[rows] for values in self._arrays()))

    def columns(self) -> _Rectangles:
        return _Rectangles(*(_column(values) for values in self._arrays()))

    def _slabs(self, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array, Array, Array, Array, Array]:
        """The fractions along each ray where it enters and leaves the slab between each pair of
        sides (x_in, x_out, y_in, y_out), and its direction in the rectangle's frame."""
        cos, sin, half_x, half_y = self.cos, self.sin, self.half_x, self.half_y
        ox, oy = sx - self.x, sy - self.y
        lx, ly = cos * ox + sin * oy, -sin * ox + cos * oy
        ldx, ldy = cos * dx + sin * dy, -sin * dx + cos * dy
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # near-parallel: +-inf, as the slabs want
            x1, x2 = (-half_x - lx) / ldx, (half_x - lx) / ldx
            y1, y2 = (-half_y - ly) / ldy, (half_y - ly) / ldy
        x_in, x_out = np.fmin(x1, x2), np.fmax(x1, x2)
        y_in, y_out = np.fmin(y1, y2), np.fmax(y1, y2)
        # a ray parallel to a pair of sides is inside that slab all along, or never (rare: checked first)
        if not ldx.all():
            along = ldx == 0.0
            x_in = np.where(along, np.where(np.abs(lx) < half_x, -np.inf, np.inf), x_in)
            x_out = np.where(along, np.inf, x_out)
        if not ldy.all():
            along = ldy == 0.0
            y_in = np.where(along, np.where(np.abs(ly) < half_y, -np.inf, np.inf), y_in)
            y_out = np.where(along, np.inf, y_out)
        return x_in, x_out, y_in, y_out, ldx, ldy

    def entries(self, sx: Array, sy: Array, dx: Array, dy: Array) -> Array:
        """The fraction along each ray where it enters the rectangle (inf: it does not)."""
        x_in, x_out, y_in, y_out, _, _ = self._slabs(sx, sy, dx, dy)
        enter, leave = np.maximum(x_in, y_in), np.minimum(x_out, y_out)
        return np.where((enter <= leave) & (enter > 0.0) & (enter <= 1.0), enter, np.inf)

    def normals(self, sx: Array, sy: Array, dx: Array, dy: Array) -> tuple[Array, Array]:
        """The normal where each ray enters the rectangle (it does)."""
        x_in, _, y_in, _, ldx, ldy = self._slabs(sx, sy, dx, dy)
        across_x = x_in >= y_in
        local_nx = np.where(across_x, -np.sign(ldx), 0.0)
        local_ny = np.where(across_x, 0.0, -np.sign(ldy))
        cos, sin = self.cos, self.sin
        return cos * local_nx - sin * local_ny, sin * local_nx + cos * local_ny


@dataclass(frozen=True)
class _Circles:
    """Circles as arrays, one element a circle (see :class:`_Rectangles`)."""

    x: Array
    y: Array
    radius: Array

    def take(self, rows: npt.NDArray[np.intp] | npt.NDArray[np.bool_]) -> _Circles:
        return _Circles(self.x[rows], self.y[rows], self.radius[rows])

    def columns(self) -> _Circles:
        return _Circles(_column(self.x), _column(self.y), _column(self.radius))

    def entries(self, sx: Array, sy: Array, dx: Array, dy: Array) -> Array:
        """The fraction along each ray where it enters the circle (inf: it does not)."""
        fx, fy = sx - self.x, sy - self.y
        a = dx * dx + dy * dy
        b = fx * dx + fy * dy
        c = fx * fx + fy * fy - self.radius * self.radius
        discriminant = b * b - a * c
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(discriminant)) / a
        hit = (discriminant >= 0.0) & (c > 0.0) & (t >= 0.0) & (t <= 1.0)
        return np.where(hit, t, np.inf)

    def normals(self, sx: Array, sy: Array, dx: Array, dy: Array, t: Array) -> tuple[Array, Array]:
        """The normal where each ray enters the circle, at fraction ``t``."""
        return (sx - self.x + t * dx) / self.radius, (sy - self.y + t * dy) / self.radius


@dataclass(frozen=True)
class _Nearest:
    """Each ray's first hit among the targets of one cast: the body's id (``NO_HIT``: none), the
    fraction along the ray (1.0: none), and its place among the targets (rectangles, then circles)."""

    bodies: npt.NDArray[np.int64]
    fractions: Array
    slots: npt.NDArray[np.intp]
    rectangles: _Rectangles
    circles: _Circles


class RayCaster:
    """Casts a robot's lidar rays against the obstacles and the other robots (each a circle of its
    body's radius, as tall as its body's top), in the plane of the rays. Body ids: the obstacles
    in :func:`world_shapes`' order, then the robots in the world's order (:attr:`names`).

    Every ray is cast at every body at once (a row a body, a column a ray), the nearest entry
    winning and the lower id on a tie: as casting at one body after another and keeping a hit only
    when it is nearer would (tests/test_kinematic_raycast.py holds them to the same bits)."""

    def __init__(self, obstacles: Sequence[Shape], robots: Sequence[tuple[str, float, float]]) -> None:
        """``robots``: each robot's name, body radius and the height of its body's top."""
        self.obstacles = tuple(obstacles)
        self.robots = tuple(robots)
        self.names = {index: shape.name for index, shape in enumerate(self.obstacles)}
        self.names.update({len(self.obstacles) + index: name for index, (name, _, _) in enumerate(self.robots)})
        rectangles = [(index, s) for index, s in enumerate(self.obstacles) if isinstance(s, Rectangle)]
        circles = [(index, s) for index, s in enumerate(self.obstacles) if isinstance(s, Circle)]
        self._rectangle_ids = np.array([index for index, _ in rectangles], dtype=np.intp)
        self._rectangles = _Rectangles.of([s for _, s in rectangles])
        # the circles: the round obstacles, then the robots (their centres where they are at each cast)
        robot_ids = [len(self.obstacles) + index for index in range(len(self.robots))]
        self._circle_ids = np.array([index for index, _ in circles] + robot_ids, dtype=np.intp)
        self._obstacle_circle_x = [s.x for _, s in circles]
        self._obstacle_circle_y = [s.y for _, s in circles]
        self._circle_radius = np.array([s.radius for _, s in circles] + [radius for _, radius, _ in self.robots])
        self._heights = np.zeros(len(self.names))
        self._heights[self._rectangle_ids] = [s.height for _, s in rectangles]
        self._heights[self._circle_ids] = [s.height for _, s in circles] + [top for _, _, top in self.robots]
        self._rectangles_first = not (rectangles and len(self._circle_ids)) or rectangles[-1][0] < self._circle_ids[0]
        """Whether every rectangle's id is below every circle's (as :func:`world_shapes` orders them)."""

    def _nearest(
        self, caster: int, positions: Sequence[Point], sx: Array, sy: Array, dx: Array, dy: Array, height: float
    ) -> _Nearest:
        if len(positions) != len(self.robots):
            raise ValueError(f"{len(positions)} positions for {len(self.robots)} robots")
        # the bodies the rays pass over or under, and the caster's own, are not hit
        seen = (self._heights >= height) & (height >= 0.0)
        if self.robots:
            seen[len(self.obstacles) + caster] = False
        rectangles, rectangle_ids = self._rectangles, self._rectangle_ids
        shown = seen[rectangle_ids]
        if not shown.all():
            rectangles, rectangle_ids = rectangles.take(shown), rectangle_ids[shown]
        circles = _Circles(
            np.array([*self._obstacle_circle_x, *(x for x, _ in positions)]),
            np.array([*self._obstacle_circle_y, *(y for _, y in positions)]),
            self._circle_radius,
        )
        shown = seen[self._circle_ids]
        circles, circle_ids = circles.take(shown), self._circle_ids[shown]
        count = len(sx)
        entries = []
        if len(rectangle_ids):
            entries.append(rectangles.columns().entries(sx, sy, dx, dy))
        if len(circle_ids):
            entries.append(circles.columns().entries(sx, sy, dx, dy))
        if not entries:
            return _Nearest(np.full(count, NO_HIT), np.ones(count), np.zeros(count, np.intp), rectangles, circles)
        t = np.concatenate(entries) if len(entries) > 1 else entries[0]
        ids = np.concatenate([rectangle_ids, circle_ids])
        order = None if self._rectangles_first else np.argsort(ids, kind="stable")
        # argmin takes the first of equal entries: the lowest id
        row = np.argmin(t if order is None else t[order], axis=0)
        slots = row if order is None else order[row]
        fractions = t[slots, np.arange(count)]
        hit = fractions != np.inf
        return _Nearest(np.where(hit, ids[slots], NO_HIT), np.where(hit, fractions, 1.0), slots, rectangles, circles)

    def first_hits(
        self, caster: int, positions: Sequence[Point], starts: Array, ends: Array
    ) -> tuple[npt.NDArray[np.int64], Array]:
        """Robot ``caster``'s rays from ``starts`` to ``ends`` (world, one row a ray, level), the
        robots at ``positions``: the body each hits first (``NO_HIT``: none) and how far along it
        (1.0: none)."""
        sx, sy = starts[:, 0], starts[:, 1]
        nearest = self._nearest(caster, positions, sx, sy, ends[:, 0] - sx, ends[:, 1] - sy, float(starts[0, 2]))
        return nearest.bodies, nearest.fractions

    def cast(self, caster: int, positions: Sequence[Point], starts: Array, ends: Array) -> list[RayHit]:
        """:meth:`first_hits`, with where and at what normal, as PyBullet's ``rayTestBatch`` reports them."""
        sx, sy, height = starts[:, 0], starts[:, 1], float(starts[0, 2])
        dx, dy = ends[:, 0] - sx, ends[:, 1] - sy
        nearest = self._nearest(caster, positions, sx, sy, dx, dy, height)
        hit, fractions = nearest.bodies != NO_HIT, nearest.fractions
        normal_x, normal_y = np.zeros(len(sx)), np.zeros(len(sx))
        rectangle_count = len(nearest.rectangles.x)
        on_rectangle = hit & (nearest.slots < rectangle_count)
        if on_rectangle.any():
            rays = on_rectangle
            normal_x[rays], normal_y[rays] = nearest.rectangles.take(nearest.slots[rays]).normals(
                sx[rays], sy[rays], dx[rays], dy[rays]
            )
        on_circle = hit & (nearest.slots >= rectangle_count)
        if on_circle.any():
            rays = on_circle
            normal_x[rays], normal_y[rays] = nearest.circles.take(nearest.slots[rays] - rectangle_count).normals(
                sx[rays], sy[rays], dx[rays], dy[rays], fractions[rays]
            )
        x, y = (sx + fractions * dx).tolist(), (sy + fractions * dy).tolist()
        return [
            _MISS if body == NO_HIT else (body, -1, t, (x[ray], y[ray], height), (nx, ny, 0.0))
            for ray, (body, t, nx, ny) in enumerate(
                zip(nearest.bodies.tolist(), fractions.tolist(), normal_x.tolist(), normal_y.tolist(), strict=True)
            )
        ]
