"""A world's obstacles made into an occupancy grid (pure, numpy; docs/navigation.md): what
``invent map`` writes as a map file.

A cell is occupied (100) where its square overlaps an obstacle's footprint, free (0) elsewhere:
never unknown, since a world file says where everything is. The test is exact: a box's rectangle
(turned by its yaw) against the cell's square by the separating axis theorem, a cylinder's circle
against the square by the distance from its centre to the square. Overlap means more than touching:
a cell whose edge only runs along an obstacle's face (as a box's face on a cell boundary does)
stays free, so that an obstacle aligned with the grid takes exactly its own cells. Heights are
ignored: every obstacle stands on the floor, in the robot's way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from schemas.messages import Obstacle
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE
from services.navigation.grid import FREE, OCCUPIED, Grid, GridGeometry, Occupancy

MIN_MAP_SIZE = 10.0
"""The shortest side a rasterised map has, m: a world smaller than this (or with no obstacle at all)
gets a map this wide around what it holds, room for goals around the robot."""
TOUCH = 1e-6
"""Overlap thinner than this fraction of a cell is touching, not overlapping (floating-point noise
on a cell boundary)."""

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]
Bounds = tuple[float, float, float, float]
"""``(min_x, min_y, max_x, max_y)``."""


def rasterize(
    obstacles: Sequence[Obstacle],
    resolution: float,
    *,
    include: Sequence[tuple[float, float]] = (),
    margin: float = 1.0,
    min_size: float = MIN_MAP_SIZE,
) -> Grid:
    """The occupancy grid of ``obstacles`` at ``resolution`` (m a cell).

    The grid spans every obstacle and every ``include`` point (the world's initial pose) with
    ``margin`` more on every side, and at least ``min_size`` along each axis (grown evenly on both
    sides; a world with neither obstacles nor points: a square of ``max(2·margin, min_size)``
    centred on the origin). Its cell edges lie on multiples of ``resolution``. ValueError for a
    resolution, margin, size or point that is not finite and positive as it must be, for an
    obstacle of a size ≤ 0, and for a grid of more than
    :data:`~services.config.navigation.MAX_COSTMAP_CELLS_PER_SIDE` cells a side."""
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise ValueError(f"resolution {resolution!r} must be finite and > 0")
    if not (math.isfinite(margin) and margin >= 0.0):
        raise ValueError(f"margin {margin!r} must be finite and >= 0")
    if not (math.isfinite(min_size) and min_size >= 0.0):
        raise ValueError(f"min_size {min_size!r} must be finite and >= 0")
    for x, y in include:
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"included point ({x!r}, {y!r}) must be finite")
    for obstacle in obstacles:
        if obstacle.size[0] <= 0.0 or obstacle.size[1] <= 0.0:
            raise ValueError(f"obstacle {obstacle.name!r}: size {obstacle.size} must be > 0")
    geometry = grid_geometry([bounds(obstacle) for obstacle in obstacles], include, resolution, margin, min_size)
    cells = np.full(geometry.shape, FREE, dtype=np.int8)
    for obstacle in obstacles:
        _mark(cells, geometry, obstacle)
    return Grid(geometry, cells)


def bounds(obstacle: Obstacle) -> Bounds:
    """The axis-aligned box around an obstacle's footprint."""
    if obstacle.shape == "cylinder":
        half_x = half_y = obstacle.size[0] / 2.0
    else:
        c, s = abs(math.cos(obstacle.yaw)), abs(math.sin(obstacle.yaw))
        hx, hy = obstacle.size[0] / 2.0, obstacle.size[1] / 2.0
        half_x, half_y = hx * c + hy * s, hx * s + hy * c
    return obstacle.x - half_x, obstacle.y - half_y, obstacle.x + half_x, obstacle.y + half_y


def grid_geometry(
    extents: Sequence[Bounds],
    include: Sequence[tuple[float, float]],
    resolution: float,
    margin: float,
    min_size: float,
) -> GridGeometry:
    """The grid over ``extents`` and ``include`` (see :func:`rasterize`); ValueError beyond the bound."""
    boxes = [*extents, *((x, y, x, y) for x, y in include)] or [(0.0, 0.0, 0.0, 0.0)]
    low = [min(box[0] for box in boxes) - margin, min(box[1] for box in boxes) - margin]
    high = [max(box[2] for box in boxes) + margin, max(box[3] for box in boxes) + margin]
    origin: list[float] = []
    cells: list[int] = []
    for axis in (0, 1):
        grow = max(0.0, min_size - (high[axis] - low[axis])) / 2.0
        lo, hi = low[axis] - grow, high[axis] + grow
        count = math.inf
        if math.isfinite(lo / resolution) and math.isfinite(hi - lo):
            first = math.floor(lo / resolution)
            count = (hi - first * resolution) / resolution
        if not count - TOUCH <= MAX_COSTMAP_CELLS_PER_SIDE:
            raise ValueError(
                f"a map of {hi - lo:.6g} m along {'xy'[axis]} at {resolution} m a cell is more than "
                f"{MAX_COSTMAP_CELLS_PER_SIDE} cells a side: a coarser resolution, or a smaller world"
            )
        corner = first * resolution
        tidy = round(corner, 9)  # -3.05, not -3.0500000000000003, in the map file: where that moves no edge
        origin.append(tidy if abs(tidy - corner) < TOUCH * resolution / 1000.0 else corner)
        cells.append(max(1, math.ceil(count - TOUCH)))
    return GridGeometry(resolution, cells[0], cells[1], origin[0], origin[1])


def _mark(cells: Occupancy, geometry: GridGeometry, obstacle: Obstacle) -> None:
    """Sets the cells an obstacle overlaps to occupied (only those of its bounding box are tested)."""
    min_x, min_y, max_x, max_y = bounds(obstacle)
    resolution = geometry.resolution
    col_0 = max(0, math.floor((min_x - geometry.origin_x) / resolution))
    row_0 = max(0, math.floor((min_y - geometry.origin_y) / resolution))
    col_1 = min(geometry.width, math.ceil((max_x - geometry.origin_x) / resolution))
    row_1 = min(geometry.height, math.ceil((max_y - geometry.origin_y) / resolution))
    if col_0 >= col_1 or row_0 >= row_1:
        return
    centre_x = geometry.origin_x + (np.arange(col_0, col_1, dtype=np.float64) + 0.5) * resolution
    centre_y = geometry.origin_y + (np.arange(row_0, row_1, dtype=np.float64) + 0.5) * resolution
    dx: Floats = centre_x[np.newaxis, :] - obstacle.x
    dy: Floats = centre_y[:, np.newaxis] - obstacle.y
    half = resolution / 2.0
    touch = TOUCH * resolution
    if obstacle.shape == "cylinder":
        overlaps = _circle_overlaps(dx, dy, half, obstacle.size[0] / 2.0, touch)
    else:
        overlaps = _rectangle_overlaps(
            dx, dy, half, obstacle.size[0] / 2.0, obstacle.size[1] / 2.0, obstacle.yaw, touch
        )
    cells[row_0:row_1, col_0:col_1][overlaps] = OCCUPIED


def _rectangle_overlaps(dx: Floats, dy: Floats, half: float, hx: float, hy: float, yaw: float, touch: float) -> Bools:
    """Which squares of half side ``half`` centred (``dx``, ``dy``) from a rectangle's centre overlap
    it (half lengths ``hx``, ``hy`` along its own axes, turned by ``yaw``): no separating axis among
    the square's two and the rectangle's two."""
    c, s = math.cos(yaw), math.sin(yaw)
    ac, as_ = abs(c), abs(s)
    along_x = np.abs(dx) < half + hx * ac + hy * as_ - touch
    along_y = np.abs(dy) < half + hx * as_ + hy * ac - touch
    square_reach = half * (ac + as_)
    along_u = np.abs(dx * c + dy * s) < hx + square_reach - touch
    along_v = np.abs(-dx * s + dy * c) < hy + square_reach - touch
    overlaps: Bools = along_x & along_y & along_u & along_v
    return overlaps


def _circle_overlaps(dx: Floats, dy: Floats, half: float, radius: float, touch: float) -> Bools:
    """Which squares of half side ``half`` centred (``dx``, ``dy``) from a circle's centre overlap it:
    the square's nearest point to the centre lies inside the circle."""
    gap_x = np.maximum(np.abs(dx) - half, 0.0)
    gap_y = np.maximum(np.abs(dy) - half, 0.0)
    overlaps: Bools = gap_x**2 + gap_y**2 < (radius - touch) ** 2
    return overlaps
