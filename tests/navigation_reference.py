"""The yardstick of the navigation tests (issue 51): how long the shortest path from a start to a
goal is that keeps ``clearance`` from every obstacle of a world, and how far a robot drove.

A navigated goal passes when the distance driven is at most 1.5 times :func:`shortest_clear_path`.
This module computes that length on its own, from the world file's shapes, without the project's
planner (which it measures): each obstacle grown by ``clearance`` (a box becomes a rectangle with
round corners, a cylinder a disc of its radius plus ``clearance``) is approximated by a convex
polygon, and the shortest path among polygons runs straight between their vertices (a visibility
graph, then Dijkstra). The polygons circumscribe the grown shapes (each corner's quarter circle is
replaced by :data:`SEGMENTS_PER_QUARTER` segments tangent to it), so a path that avoids them keeps
at least ``clearance`` from every obstacle, and it is at most ``tan(a) / a`` (``a = pi / 4 /
SEGMENTS_PER_QUARTER``: 1.0032 for 8 segments, +0.33 %) longer than the true shortest one where
it wraps around a corner, exact along straight stretches (a corner's polygon bulges out by at most
``clearance * (1 / cos(a) - 1)``, 2.4 mm at 0.5 m: a way between two corners up to twice that too
narrow counts as closed). Inscribed polygons (``outer=False``) give a length at most the true one:
the two bracket it (``tests/test_navigation_reference.py`` checks both against analytic lengths:
free space, around a cylinder, around a wall, turned or not).

The whole plane is the floor: a goal is unreachable (None) only when the grown obstacles close it
off, or when the start or the goal is itself closer than ``clearance`` to an obstacle. Pure numpy.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from sim_bridge.world import Box, Cylinder, World

Point = tuple[float, float]
Polygon = NDArray[np.float64]
"""A convex polygon's vertices, counterclockwise, shape (n, 2)."""

SEGMENTS_PER_QUARTER = 8
"""Segments replacing a quarter circle of a grown corner (a cylinder's circle has four times as many)."""
TOUCH_M = 1e-9
"""How far a path may reach into a grown obstacle and still count as touching it, not entering it."""


def grown_polygons(
    world: World, clearance: float = 0.5, *, outer: bool = True, segments_per_quarter: int = SEGMENTS_PER_QUARTER
) -> list[Polygon]:
    """Every obstacle of ``world`` grown by ``clearance``, as a convex polygon that contains the grown
    shape (``outer``) or that it contains (not ``outer``)."""
    if clearance < 0.0:
        raise ValueError(f"clearance {clearance} < 0")
    boxes = [_grown_box(box, clearance, outer, segments_per_quarter) for box in world.boxes]
    discs = [_grown_disc(cylinder, clearance, outer, segments_per_quarter) for cylinder in world.cylinders]
    return boxes + discs


def _arc(
    centre: NDArray[np.float64], radius: float, start: float, span: float, segments: int, outer: bool
) -> NDArray[np.float64]:
    """The vertices replacing the arc of ``radius`` about ``centre`` from angle ``start`` over ``span``
    (counterclockwise): ``segments`` segments tangent to it (``outer``, the arc's end points on the
    polygon's neighbouring edges) or ``segments`` chords of it (the end points included)."""
    step = span / segments
    if outer:
        angles = start + step * (np.arange(segments) + 0.5)
        radius = radius / math.cos(step / 2.0)
    else:
        angles = start + step * np.arange(segments + 1)
    return centre + radius * np.column_stack((np.cos(angles), np.sin(angles)))


def _grown_box(box: Box, clearance: float, outer: bool, segments_per_quarter: int) -> Polygon:
    half = np.array(box.size[:2]) / 2.0
    turn = np.array([[math.cos(box.yaw), -math.sin(box.yaw)], [math.sin(box.yaw), math.cos(box.yaw)]])
    signs = np.array([[1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]])  # counterclockwise
    corners = (signs * half) @ turn.T + np.array([box.x, box.y])
    if clearance == 0.0:
        return corners
    # at corner i the grown boundary turns from the normal of the edge before it (i - 1 -> i) to
    # the normal of the edge after it, a quarter turn counterclockwise
    arcs = []
    for index, corner in enumerate(corners):
        before = corner - corners[index - 1]
        normal_before = math.atan2(-before[0], before[1])  # the edge's direction turned clockwise: outward
        arcs.append(_arc(corner, clearance, normal_before, math.pi / 2.0, segments_per_quarter, outer))
    return np.vstack(arcs)


def _grown_disc(cylinder: Cylinder, clearance: float, outer: bool, segments_per_quarter: int) -> Polygon:
    segments = 4 * segments_per_quarter
    circle = _arc(np.array([cylinder.x, cylinder.y]), cylinder.radius + clearance, 0.0, math.tau, segments, outer)
    return circle if outer else circle[:-1]  # the chords' last end point is the first


def _half_planes(polygon: Polygon) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``normals`` (n, 2) and ``offsets`` (n,): the polygon is where ``normals @ p <= offsets``."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    normals = np.column_stack((edges[:, 1], -edges[:, 0]))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, np.einsum("ij,ij->i", normals, polygon)


def _inside(points: NDArray[np.float64], polygon: Polygon) -> NDArray[np.bool_]:
    """Whether each point is further than :data:`TOUCH_M` inside ``polygon``."""
    normals, offsets = _half_planes(polygon)
    return np.all(points @ normals.T < offsets - TOUCH_M, axis=1)


def _crosses(starts: NDArray[np.float64], ends: NDArray[np.float64], polygon: Polygon) -> NDArray[np.bool_]:
    """Whether each segment from ``starts[i]`` to ``ends[i]`` enters ``polygon`` shrunk by
    :data:`TOUCH_M` (Cyrus-Beck clipping): running along its edge or touching a vertex does not."""
    crossing = np.zeros(len(starts), dtype=bool)
    low, high = polygon.min(axis=0) - TOUCH_M, polygon.max(axis=0) + TOUCH_M
    near = np.all((np.minimum(starts, ends) <= high) & (np.maximum(starts, ends) >= low), axis=1)
    if not near.any():
        return crossing
    a, b = starts[near], ends[near]
    normals, offsets = _half_planes(polygon)
    room = (offsets - TOUCH_M)[None, :] - a @ normals.T  # how far each start is inside each edge's line
    rate = (b - a) @ normals.T  # how fast the segment leaves it, per unit of its parameter
    leaving, entering, parallel = rate > 1e-15, rate < -1e-15, np.abs(rate) <= 1e-15
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = room / rate
    enter = np.max(np.where(entering, ratio, 0.0), axis=1, initial=0.0)
    leave = np.min(np.where(leaving, ratio, 1.0), axis=1, initial=1.0)
    outside = np.any(parallel & (room < 0.0), axis=1)
    crossing[near] = ~outside & (enter < leave)
    return crossing


def shortest_clear_route(
    world: World,
    start: Point,
    goal: Point,
    clearance: float = 0.5,
    *,
    outer: bool = True,
    segments_per_quarter: int = SEGMENTS_PER_QUARTER,
) -> list[Point] | None:
    """The shortest polyline from ``start`` to ``goal`` that keeps ``clearance`` from every obstacle of
    ``world`` (with ``outer``; see the module), its corners on the grown obstacles; None when there is none."""
    polygons = grown_polygons(world, clearance, outer=outer, segments_per_quarter=segments_per_quarter)
    ends = np.array([start, goal], dtype=float)
    if any(_inside(ends, polygon).any() for polygon in polygons):
        return None
    corners = np.vstack([ends, *polygons]) if polygons else ends
    free = np.ones(len(corners), dtype=bool)
    for polygon in polygons:
        free &= ~_inside(corners, polygon)
    nodes = corners[free]
    count = len(nodes)
    first, second = np.triu_indices(count, k=1)
    visible = np.ones(len(first), dtype=bool)
    for polygon in polygons:
        visible &= ~_crosses(nodes[first], nodes[second], polygon)
    weights = np.full((count, count), np.inf)
    lengths = np.linalg.norm(nodes[second] - nodes[first], axis=1)
    weights[first[visible], second[visible]] = lengths[visible]
    weights[second[visible], first[visible]] = lengths[visible]
    previous = _dijkstra(weights, source=0)
    if previous[1] < 0:
        return None
    route = [1]
    while route[-1] != 0:
        route.append(int(previous[route[-1]]))
    return [(float(nodes[i, 0]), float(nodes[i, 1])) for i in reversed(route)]


def _dijkstra(weights: NDArray[np.float64], source: int) -> NDArray[np.int64]:
    """Each node's predecessor on its shortest path from ``source`` (-1: unreachable; the source's own: itself)."""
    count = len(weights)
    distance = np.full(count, np.inf)
    distance[source] = 0.0
    previous = np.full(count, -1, dtype=np.int64)
    previous[source] = source
    done = np.zeros(count, dtype=bool)
    for _ in range(count):
        candidates = np.where(done, np.inf, distance)
        node = int(np.argmin(candidates))
        if not math.isfinite(candidates[node]):
            break
        done[node] = True
        through = distance[node] + weights[node]
        better = (through < distance) & ~done
        distance[better] = through[better]
        previous[better] = node
    return previous


def route_length(route: Sequence[Point]) -> float:
    """The length of a polyline."""
    return sum(math.dist(a, b) for a, b in itertools.pairwise(route))


def shortest_clear_path(world: World, start: Point, goal: Point, clearance: float = 0.5) -> float | None:
    """The length (m) of the shortest path from ``start`` to ``goal`` keeping ``clearance`` from every
    obstacle of ``world`` (at most 0.33 % over the true one with the default segments; see the
    module); None when no path keeps that clearance (the goal closed off, or the start or the goal
    itself closer than ``clearance`` to an obstacle)."""
    route = shortest_clear_route(world, start, goal, clearance)
    return None if route is None else route_length(route)


def distance_driven(poses: Iterable[Sequence[float]]) -> float:
    """The length of the track through ``poses``, each ``(x, y)`` or ``(x, y, ...)`` (a heading
    after them is ignored), in order: the sum of the straight steps between consecutive poses."""
    points = [(float(pose[0]), float(pose[1])) for pose in poses]
    return route_length(points)
