"""The costmap (pure: numpy, scipy.ndimage; docs/navigation.md): what the planner and the path tracker
read of the world, a cost per cell of the ``map`` frame in Nav2's convention.

Two layers of obstacles: the **static** layer (a map's cells above 50, never cleared) and the
**obstacle** layer (what the lidar marked, cleared by the rays that pass through it, forgotten all at
once by :meth:`Costmap.clear_obstacles`). Their union is inflated (Nav2's inflation layer) about the
axle centre: ``LETHAL`` at an obstacle's own cell, ``INSCRIBED`` within the inscribed radius
(the body's radius plus ``footprint_padding``) of one, where the body would touch it, then a cost
decaying from ``MAX_INFLATED`` as ``252·exp(−cost_scaling_factor·(d − inscribed))`` (at least 1) out to
``inflation_radius``, ``FREE`` beyond. Distances are between cell centres. A cell never seen nor on a
map counts as free: the planner may plan through the unknown (and the lidar sees it on the way).

A scan (:meth:`Costmap.mark_scan`) is traced in one vectorised pass: every ray's cells are the cells
its segment crosses (exact grid traversal, a cell touched at a corner counted), cleared first for all
the rays, then every return within ``obstacle_range`` marked; a scan that repeats the last one traced,
from the same pose to within ``SAME_SCAN_M`` (a robot at rest, a lidar without noise), is not traced
again.
The inflation is recomputed lazily, when :attr:`Costmap.costs` is read after a change, and only over
the windows the change can reach (the bounding box of each cluster of changed cells grown by the
inflation radius, its distances taken from a window grown by the radius again): a scan changes cells
within ``raytrace_range`` of the lidar, mostly on a few walls, not the whole grid.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from schemas.codec import BadInput
from schemas.messages import LaserScan
from services.config.navigation import NavigationConfig
from services.navigation.grid import UNKNOWN, Grid, GridGeometry, Occupancy
from services.navigation.traversal import crossed_cells

FREE = 0
"""No cost (Nav2's ``FREE_SPACE``)."""
TracedScan = tuple[npt.NDArray[np.float64], tuple[float, ...], npt.NDArray[np.float64], dict[str, int]]
"""The last scan traced: the lidar's pose, the scan's angles and limits, its ranges (NaN: no return), its counters."""
SAME_SCAN_M = 1e-6
"""A scan whose lidar position (m), heading (rad) and every range (m) are within this of the last scan
traced is that scan again, and is not traced. A robot at rest creeps by nanometres while its wheel
control settles, so its scans are never bit for bit the same. A micron in a 5 cm cell: a ray's end
crosses a cell's edge about once in 25,000 rays (by that ratio), and the next scan traced from
farther sets it right."""
MAX_INFLATED = 252
"""The highest cost of the decaying inflation, just outside the inscribed radius."""
INSCRIBED = 253
"""The axle centre here puts the body (radius + footprint_padding) onto an obstacle
(Nav2's ``INSCRIBED_INFLATED_OBSTACLE``)."""
LETHAL = 254
"""An obstacle's own cell (Nav2's ``LETHAL_OBSTACLE``)."""

STATIC_OBSTACLE_ABOVE = 50
"""A map's cell above this occupancy is a static obstacle (map_server's thresholded maps hold 100)."""

DISTANCE_TOLERANCE = 1e-9
"""m: a cell centre this close to a radius counts as within it (cell distances are multiples of the
resolution, which floating point does not hold exactly)."""

Costs = npt.NDArray[np.uint8]
Floats = npt.NDArray[np.float64]
Indices = npt.NDArray[np.intp]
Bools = npt.NDArray[np.bool_]
Box = tuple[int, int, int, int]
"""Rows [r0, r1) and columns [c0, c1) of the grid."""


def _occupancy_table() -> npt.NDArray[np.int8]:
    """nav2 costmap_2d's translation of a cost to an occupancy: 0 → 0, 1..252 → 1..98, 253 → 99,
    254 → 100 (255, no information, is handled by the caller)."""
    table = np.full(256, UNKNOWN, dtype=np.int8)
    table[FREE] = 0
    costs = np.arange(1, MAX_INFLATED + 1)
    table[1 : MAX_INFLATED + 1] = 1 + (97 * (costs - 1)) // 251
    table[INSCRIBED] = 99
    table[LETHAL] = 100
    return table


OCCUPANCY_OF_COST = _occupancy_table()


class Costmap:
    """The costs over ``geometry`` for a body of radius ``body_radius`` (m): a map's obstacles
    (``static``: an occupancy array on exactly ``geometry``, None: no map), the lidar's, inflated.

    Read :attr:`costs` (``[row, col]``, uint8), :meth:`cost_at` and :meth:`line_cost`; feed it
    :meth:`mark_scan`; publish :meth:`occupancy`. Not thread-safe: one thread owns it."""

    def __init__(
        self,
        geometry: GridGeometry,
        settings: NavigationConfig,
        body_radius: float,
        static: Occupancy | None = None,
    ) -> None:
        if not (math.isfinite(body_radius) and body_radius > 0.0):
            raise ValueError(f"body radius {body_radius!r} must be finite and > 0")
        self.geometry = geometry
        self.settings = settings
        self.body_radius = body_radius
        self.inscribed_radius = body_radius + settings.footprint_padding
        """The radius within which the axle centre puts the body (and its padding) onto an obstacle."""
        shape = geometry.shape
        if static is None:
            self._static = np.zeros(shape, dtype=np.bool_)
            self._map_known = np.zeros(shape, dtype=np.bool_)
        else:
            if static.shape != shape:
                raise ValueError(f"a static map of shape {static.shape} on a costmap of {shape}")
            self._static = static > STATIC_OBSTACLE_ABOVE
            self._map_known = static != UNKNOWN
        self._obstacles = np.zeros(shape, dtype=np.bool_)
        self._seen = np.zeros(shape, dtype=np.bool_)
        self._costs = np.zeros(shape, dtype=np.uint8)
        self._reach = math.ceil(max(settings.inflation_radius, self.inscribed_radius) / geometry.resolution) + 1
        """Cells beyond which an obstacle changes no cost."""
        self._dirty: list[Box] = [(0, shape[0], 0, shape[1])]
        """Boxes of rows [r0, r1) and columns [c0, c1) whose obstacles changed since the last inflation."""
        self._last_scan: TracedScan | None = None
        """The last scan traced (its pose and limits, its ranges) and what it counted, while tracing it
        again would change nothing."""
        self._counters = {
            "scans": 0,
            "rays": 0,
            "rays_clipped": 0,
            "rays_below_range_min": 0,
            "scans_changing": 0,
            "scans_repeated": 0,
            "clears": 0,
            "inflations": 0,
            "inflated_cells": 0,
        }

    # -- the obstacle layer ------------------------------------------------------------------

    def mark_scan(self, scan: LaserScan, lidar_x: float, lidar_y: float, lidar_yaw: float) -> None:
        """Trace a scan taken from the lidar's pose (``lidar_x``, ``lidar_y``, ``lidar_yaw``) in ``map``.

        Every ray clears the cells it crosses up to its return (the return's own cell excepted) or up
        to ``raytrace_range`` (a ray with no return: up to ``min(range_max, raytrace_range)``); then
        every return within [``range_min``, ``obstacle_range``] marks its cell an obstacle. Ranges
        below ``range_min`` are ignored, ranges above ``range_max`` read as no return. A ray's far end
        off the grid is clipped at the grid's edge (``rays_clipped``). A lidar off the grid (or a
        pose that is not finite) raises BadInput and changes nothing. The static layer is never cleared."""
        geometry = self.geometry
        if not (math.isfinite(lidar_yaw) and geometry.contains(lidar_x, lidar_y)):
            raise BadInput(
                f"the lidar's pose ({lidar_x!r}, {lidar_y!r}, {lidar_yaw!r}) is not on the costmap "
                f"(extent {describe_extent(geometry)})"
            )
        ranges = np.array(scan.ranges, dtype=np.float64)  # None (no return) reads as NaN
        lidar = np.array((lidar_x, lidar_y, lidar_yaw))
        frame = (scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max)
        if self._last_scan is not None and self._repeats(self._last_scan, lidar, frame, ranges):
            # tracing a scan is idempotent: the same rays again clear and mark the same cells to the same end
            for name, value in self._last_scan[3].items():
                self._counters[name] += value
            self._counters["scans_repeated"] += 1
            return
        settings = self.settings
        resolution = geometry.resolution
        count = len(scan.ranges)
        no_return = np.isnan(ranges) | (ranges > scan.range_max)
        below = ~no_return & (ranges < scan.range_min)
        used = ~below
        returned = used & ~no_return
        clear_length = np.where(no_return, min(scan.range_max, settings.raytrace_range), ranges)
        clear_length = np.minimum(clear_length, settings.raytrace_range)
        angles = lidar_yaw + scan.angle_min + scan.angle_increment * np.arange(count)
        cos, sin = np.cos(angles), np.sin(angles)
        # in cells from the grid's origin
        u0 = (lidar_x - geometry.origin_x) / resolution
        v0 = (lidar_y - geometry.origin_y) / resolution
        exit_t = np.minimum(_exit(u0, cos, geometry.width), _exit(v0, sin, geometry.height))
        length = clear_length[used] / resolution
        exits = exit_t[used]
        clipped = length >= exits
        length = np.where(clipped, np.maximum(exits - 1e-9, 0.0), length)
        u1 = u0 + length * cos[used]
        v1 = v0 + length * sin[used]
        segment, cols, rows = crossed_cells(np.full(u1.shape, u0), np.full(v1.shape, v0), u1, v1)
        _clip_cells(geometry, cols, rows)
        flat = rows * geometry.width + cols
        # a return within raytrace_range (and on the grid) keeps its own cell: it holds what was hit
        end_cell = np.full(u1.shape, -1, dtype=np.intp)
        keeps_end = returned[used] & (ranges[used] <= settings.raytrace_range) & ~clipped
        end_cell[keeps_end] = np.floor(v1[keeps_end]).astype(np.intp) * geometry.width + np.floor(u1[keeps_end]).astype(
            np.intp
        )
        cleared = flat[flat != end_cell[segment]]
        marks = returned & (ranges <= settings.obstacle_range)
        hit_x = lidar_x + ranges[marks] * cos[marks]
        hit_y = lidar_y + ranges[marks] * sin[marks]
        hit_cols, hit_rows, on_grid = geometry.cells_of(hit_x, hit_y)
        marked = hit_rows[on_grid] * geometry.width + hit_cols[on_grid]

        obstacles = self._obstacles.reshape(-1)
        seen = self._seen.reshape(-1)
        # what may change: the obstacles on the cleared cells (few), and the marked cells
        touched = np.concatenate((cleared[obstacles[cleared]], marked))
        before = obstacles[touched]
        obstacles[cleared] = False
        obstacles[marked] = True
        changed = touched[obstacles[touched] != before]
        changed = changed[~self._static.reshape(-1)[changed]]  # under a static obstacle: the costs stay
        seen[cleared] = True
        seen[marked] = True
        counted = {
            "scans": 1,
            "rays": count,
            "rays_below_range_min": int(np.count_nonzero(below)),
            "rays_clipped": int(np.count_nonzero(clipped)),
        }
        for name, value in counted.items():
            self._counters[name] += value
        self._last_scan = (lidar, frame, ranges, counted)
        if changed.size:
            self._counters["scans_changing"] += 1
            rows_changed, cols_changed = np.divmod(changed, geometry.width)
            for box in _clusters(rows_changed, cols_changed, 2 * self._reach):
                self._touch(box)

    @staticmethod
    def _repeats(
        last: TracedScan,
        lidar: npt.NDArray[np.float64],
        frame: tuple[float, ...],
        ranges: npt.NDArray[np.float64],
    ) -> bool:
        """Whether a scan is the ``last`` one traced again, to within ``SAME_SCAN_M`` (the same rays
        returning, the same ones not)."""
        last_lidar, last_frame, last_ranges, _ = last
        return (
            last_frame == frame
            and last_ranges.shape == ranges.shape
            and bool(np.all(np.abs(last_lidar - lidar) <= SAME_SCAN_M))
            and bool(np.allclose(last_ranges, ranges, rtol=0.0, atol=SAME_SCAN_M, equal_nan=True))
        )

    def clear_obstacles(self) -> None:
        """Forget the obstacle layer (a recovery); the static layer stays."""
        self._counters["clears"] += 1
        self._last_scan = None  # the same scan again would mark anew
        forgotten = self._obstacles & ~self._static
        self._obstacles[:] = False
        if forgotten.any():
            rows, cols = np.nonzero(forgotten)
            self._touch((int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1))

    def _touch(self, box: Box) -> None:
        """Add a box of changed cells to those waiting for the inflation, merged with any whose reach it
        shares (one window rather than two overlapping ones)."""
        r0, r1, c0, c1 = box
        near = 2 * self._reach
        apart = []
        for d0, d1, e0, e1 in self._dirty:
            if d0 - near < r1 and r0 < d1 + near and e0 - near < c1 and c0 < e1 + near:
                r0, r1, c0, c1 = min(r0, d0), max(r1, d1), min(c0, e0), max(c1, e1)
            else:
                apart.append((d0, d1, e0, e1))
        apart.append((r0, r1, c0, c1))
        self._dirty = apart

    # -- costs -------------------------------------------------------------------------------

    @property
    def costs(self) -> Costs:
        """The costs ``[row, col]`` (read-only): :data:`LETHAL` at obstacles (static or seen),
        :data:`INSCRIBED` within the inscribed radius of one, the decaying inflation out to
        ``inflation_radius``, :data:`FREE` beyond; unknown cells count as free."""
        for box in self._dirty:
            self._inflate(*box)
        self._dirty = []
        view = self._costs.view()
        view.flags.writeable = False
        return view

    def _inflate(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Recompute the costs of every cell an obstacle change within rows [r0, r1) and columns
        [c0, c1) can reach, from the obstacles within reach of those."""
        height, width = self.geometry.shape
        reach = self._reach
        ur0, ur1, uc0, uc1 = max(r0 - reach, 0), min(r1 + reach, height), max(c0 - reach, 0), min(c1 + reach, width)
        ir0, ir1, ic0, ic1 = max(ur0 - reach, 0), min(ur1 + reach, height), max(uc0 - reach, 0), min(uc1 + reach, width)
        lethal = self._static[ir0:ir1, ic0:ic1] | self._obstacles[ir0:ir1, ic0:ic1]
        window = (slice(ur0 - ir0, ur1 - ir0), slice(uc0 - ic0, uc1 - ic0))
        self._counters["inflations"] += 1
        self._counters["inflated_cells"] += (ur1 - ur0) * (uc1 - uc0)
        if not lethal.any():
            self._costs[ur0:ur1, uc0:uc1] = FREE
            return
        distance = ndimage.distance_transform_edt(~lethal, sampling=self.geometry.resolution)[window]
        self._costs[ur0:ur1, uc0:uc1] = self.cost_of_distance(distance)

    def cost_of_distance(self, distance: Floats) -> Costs:
        """The cost of cells at ``distance`` (m, centre to centre) from the nearest obstacle."""
        settings = self.settings
        inscribed = self.inscribed_radius
        decay = MAX_INFLATED * np.exp(-settings.cost_scaling_factor * (distance - inscribed))
        costs = np.maximum(np.floor(np.minimum(decay, MAX_INFLATED)), 1.0).astype(np.uint8)
        costs[distance > settings.inflation_radius + DISTANCE_TOLERANCE] = FREE
        costs[distance <= inscribed + DISTANCE_TOLERANCE] = INSCRIBED
        costs[distance == 0.0] = LETHAL
        return costs

    def cost_at(self, x: float, y: float) -> int:
        """The cost of the cell holding (``x``, ``y``); :data:`LETHAL` off the grid."""
        cell = self.geometry.cell(x, y)
        if cell is None:
            return LETHAL
        col, row = cell
        return int(self.costs[row, col])

    def line_cost(self, x0: float, y0: float, x1: float, y1: float) -> int:
        """The highest cost of the cells the segment (``x0``, ``y0``) → (``x1``, ``y1``) crosses (a cell
        touched at a corner counts); :data:`LETHAL` if any part of it is off the grid."""
        return int(self.line_costs(np.array([x0]), np.array([y0]), np.array([x1]), np.array([y1]))[0])

    def line_costs(self, x0: Floats, y0: Floats, x1: Floats, y1: Floats) -> Costs:
        """:meth:`line_cost` of many segments at once (arrays of their ends, in ``map``)."""
        geometry = self.geometry
        on_grid = _on_grid(geometry, x0, y0) & _on_grid(geometry, x1, y1)  # the grid is convex
        highest = np.full(x0.shape, LETHAL, dtype=np.uint8)
        if not on_grid.any():
            return highest
        resolution = geometry.resolution
        segment, cols, rows = crossed_cells(
            (x0[on_grid] - geometry.origin_x) / resolution,
            (y0[on_grid] - geometry.origin_y) / resolution,
            (x1[on_grid] - geometry.origin_x) / resolution,
            (y1[on_grid] - geometry.origin_y) / resolution,
        )
        _clip_cells(geometry, cols, rows)
        worst = np.zeros(int(np.count_nonzero(on_grid)), dtype=np.uint8)
        np.maximum.at(worst, segment, self.costs.reshape(-1)[rows * geometry.width + cols])
        highest[on_grid] = worst
        return highest

    # -- what is published and counted ----------------------------------------------------------

    @property
    def obstacles(self) -> Bools:
        """The obstacle layer ``[row, col]`` (read-only): the cells the lidar marked and no ray cleared since."""
        view = self._obstacles.view()
        view.flags.writeable = False
        return view

    def known(self) -> Bools:
        """Which cells are known: on the map (not -1 there) or seen by the lidar."""
        return self._map_known | self._seen

    def occupancy(self) -> Grid:
        """The costmap as ROS publishes one (nav2 costmap_2d's translation): cost 0 → 0, 1..252 →
        1..98, :data:`INSCRIBED` → 99, :data:`LETHAL` → 100; a cell never seen and not on a map → -1."""
        cells = OCCUPANCY_OF_COST[self.costs]
        cells[~self.known()] = UNKNOWN
        return Grid(self.geometry, cells)

    def status(self) -> dict[str, Any]:
        """Counters: scans traced, rays, rays clipped at the grid's edge, rays below ``range_min``,
        scans that changed an obstacle, scans that repeated the last one from the same pose (not traced
        again), clears, inflations and the cells they recomputed; the cells of each layer now."""
        return {
            **self._counters,
            "obstacle_cells": int(np.count_nonzero(self._obstacles)),
            "static_cells": int(np.count_nonzero(self._static)),
            "known_cells": int(np.count_nonzero(self.known())),
            "cells": self.geometry.width * self.geometry.height,
        }


def _clusters(rows: Indices, cols: Indices, gap: int) -> list[Box]:
    """The bounding boxes of groups of cells (``rows``, ``cols``), split where more than ``gap`` rows,
    then within a band more than ``gap`` columns, lie between them: a scan's changes on walls on either
    side of the robot are inflated in two small windows rather than one spanning both."""
    boxes = []
    by_row = np.argsort(rows, kind="stable")
    rows, cols = rows[by_row], cols[by_row]
    row_breaks = np.flatnonzero(np.diff(rows) > gap) + 1
    for band_rows, band_cols in zip(np.split(rows, row_breaks), np.split(cols, row_breaks), strict=True):
        by_col = np.argsort(band_cols, kind="stable")
        band_rows, band_cols = band_rows[by_col], band_cols[by_col]
        col_breaks = np.flatnonzero(np.diff(band_cols) > gap) + 1
        for group_rows, group_cols in zip(
            np.split(band_rows, col_breaks), np.split(band_cols, col_breaks), strict=True
        ):
            boxes.append(
                (int(group_rows.min()), int(group_rows.max()) + 1, int(group_cols[0]), int(group_cols[-1]) + 1)
            )
    return boxes


def _exit(start: float, direction: Floats, cells: int) -> Floats:
    """The distance (in cells) along each ray from ``start`` to the grid's edge on one axis."""
    with np.errstate(divide="ignore", invalid="ignore"):
        forward = (cells - start) / direction
        backward = -start / direction
    return np.where(direction > 0.0, forward, np.where(direction < 0.0, backward, np.inf))


def _on_grid(geometry: GridGeometry, x: Floats, y: Floats) -> Bools:
    """Which points lie on the grid (:meth:`GridGeometry.contains`, for arrays)."""
    return (x >= geometry.origin_x) & (x < geometry.max_x) & (y >= geometry.origin_y) & (y < geometry.max_y)


def _clip_cells(geometry: GridGeometry, cols: Indices, rows: Indices) -> None:
    """Cells a traversal on the grid counted just past its edge (a corner within the tolerance) back
    onto it, in place."""
    np.minimum(cols, geometry.width - 1, out=cols)
    np.maximum(cols, 0, out=cols)
    np.minimum(rows, geometry.height - 1, out=rows)
    np.maximum(rows, 0, out=rows)


def describe_extent(geometry: GridGeometry) -> str:
    """The grid's extent in ``map``, as reasons name it."""
    return f"x {geometry.origin_x:.2f} to {geometry.max_x:.2f}, y {geometry.origin_y:.2f} to {geometry.max_y:.2f}"
