"""A log-odds occupancy grid that grows as scans come (pure: numpy).

Each cell holds the log-odds of being occupied, ``log(p / (1 − p))``, 0 until a ray reaches it. A ray
from the lidar to its end adds :data:`LOG_ODDS_FREE` to every cell it crosses (the exact grid
traversal of :func:`services.navigation.costmap.crossed_cells`) but its end's, and
:data:`LOG_ODDS_HIT` to its end's cell when it hit something; a ray with no return clears up to
``range_max`` and marks nothing. Within one scan a cell is updated once, however many rays cross it
(the rays fan out from one point: the cells near the lidar would otherwise count tens of times), and a
cell some ray of the scan hit is not cleared by another ray of the same scan grazing it. The sums are
clamped to [:data:`LOG_ODDS_MIN`, :data:`LOG_ODDS_MAX`] so that a cell can change its mind when the
world does (or when a first pose was wrong) after a bounded number of scans.

The grid starts empty and grows (by whole cells, so that no cell moves) to cover each scan with
:data:`GROWTH_MARGIN` to spare, up to ``max_cells_per_side`` cells a side: a scan that would need more
is refused (:meth:`LogOddsGrid.cover` is False) and the caller counts it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry
from services.navigation.traversal import crossed_cells

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

LOG_ODDS_HIT = 0.85
"""Added at a ray's return: p = 0.7 that a cell a ray ended in is occupied."""
LOG_ODDS_FREE = -0.4
"""Added along a ray: p = 0.4 that a cell a ray crossed is occupied."""
LOG_ODDS_MIN = -2.0
LOG_ODDS_MAX = 3.5
FACINGS = 4
"""Which way the rays that hit a cell travelled: bit k of a cell's facing for :func:`facing_bits`."""
FACING_COMPONENT = math.cos(math.radians(67.5))
"""A ray marks each axis direction its direction has at least this component along: one or two, so
that a ray matched later by its dominant axis (:func:`dominant_facing`) finds the cells it would mark."""
GROWTH_MARGIN = 2.0
"""m: a grid grown to cover a scan covers this much more on each side it grew on, so that it grows
every few metres of travel rather than at every scan."""


class LogOddsGrid:
    """Log-odds occupancy of cells of ``resolution`` m, growing to cover what it is given."""

    def __init__(self, resolution: float, max_cells_per_side: int = MAX_COSTMAP_CELLS_PER_SIDE) -> None:
        if not (math.isfinite(resolution) and resolution > 0.0):
            raise ValueError(f"resolution {resolution!r} must be finite and > 0")
        if max_cells_per_side < 1:
            raise ValueError(f"max_cells_per_side {max_cells_per_side} must be at least 1")
        self.resolution = resolution
        self.max_cells_per_side = max_cells_per_side
        # The grid's lower-left cell, counted in cells from (0, 0): whole cells keep every cell in place
        # as the grid grows.
        self._col0 = 0
        self._row0 = 0
        self._used: tuple[int, int, int, int] | None = None
        """The cells every covered box spans: ``(col0, row0, col1, row1)``, the ends excluded."""
        self.log_odds = np.zeros((0, 0), dtype=np.float32)
        self.seen = np.zeros((0, 0), dtype=np.bool_)
        self.facing = np.zeros((0, 0), dtype=np.uint8)
        """Per cell, the directions the rays that hit it travelled (:func:`facing_bits`): a thin wall's
        two faces, hit from opposite sides, are told apart by a matcher."""
        self.hit_sums = np.zeros((0, 0, 2), dtype=np.float64)
        """Per cell, the sum of its hits' offsets from its centre (x, y): with :attr:`hit_counts`, where
        in the cell the surface lies, finer than the cell."""
        self.hit_counts = np.zeros((0, 0), dtype=np.float64)
        self.view_sums = np.zeros((0, 0, 2), dtype=np.float64)
        """Per cell, the sum of the unit vectors from its hits back to the lidar: the side its surface
        was seen from (a matcher keeps a point off the other face of a thin wall)."""

    @property
    def empty(self) -> bool:
        return self.log_odds.size == 0

    @property
    def geometry(self) -> GridGeometry:
        """Where the cells lie (the grid must not be :attr:`empty`)."""
        height, width = self.log_odds.shape
        return GridGeometry(self.resolution, width, height, self._col0 * self.resolution, self._row0 * self.resolution)

    def cover(self, min_x: float, min_y: float, max_x: float, max_y: float) -> bool:
        """Grow the grid (if need be) to hold the box; False, and nothing changed, when the box and
        every box covered before would then span more than ``max_cells_per_side`` cells a side."""
        resolution = self.resolution
        box = (
            math.floor(min_x / resolution),
            math.floor(min_y / resolution),
            math.floor(max_x / resolution) + 1,
            math.floor(max_y / resolution) + 1,
        )
        height, width = self.log_odds.shape
        allocated = (self._col0, self._row0, self._col0 + width, self._row0 + height)
        used = box if self._used is None else _union(self._used, box)
        if used[2] - used[0] > self.max_cells_per_side or used[3] - used[1] > self.max_cells_per_side:
            return False
        self._used = used
        if not self.empty and _union(allocated, box) == allocated:
            return True
        # what is used, with a margin to grow into, as far as the bound allows
        margin = math.ceil(GROWTH_MARGIN / resolution)
        limit = self.max_cells_per_side
        col0, col1 = _within_limit(used[0] - margin, used[2] + margin, used[0], used[2], limit)
        row0, row1 = _within_limit(used[1] - margin, used[3] + margin, used[1], used[3], limit)
        arrays: tuple[npt.NDArray[Any], ...] = (
            self.log_odds,
            self.seen,
            self.facing,
            self.hit_sums,
            self.hit_counts,
            self.view_sums,
        )
        grown: list[npt.NDArray[Any]] = [
            np.zeros((row1 - row0, col1 - col0, *array.shape[2:]), dtype=array.dtype) for array in arrays
        ]
        # the old cells on both grids: all the used ones (a margin may fall off past the bound)
        c0, c1 = max(col0, allocated[0]), min(col1, allocated[2])
        r0, r1 = max(row0, allocated[1]), min(row1, allocated[3])
        if not self.empty and c0 < c1 and r0 < r1:
            for new, old in zip(grown, arrays, strict=True):
                new[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0] = old[
                    r0 - allocated[1] : r1 - allocated[1], c0 - allocated[0] : c1 - allocated[0]
                ]
        self.log_odds, self.seen, self.facing, self.hit_sums, self.hit_counts, self.view_sums = grown
        self._col0, self._row0 = col0, row0
        return True

    def insert(self, origin_x: float, origin_y: float, end_x: Floats, end_y: Floats, hit: Bools) -> None:
        """Trace rays from the lidar at (``origin_x``, ``origin_y``) to their ends (``map`` frame); ``hit``
        says which ended on a return. The grid must already :meth:`cover` them all."""
        geometry = self.geometry
        resolution, width = geometry.resolution, geometry.width
        u0 = (origin_x - geometry.origin_x) / resolution
        v0 = (origin_y - geometry.origin_y) / resolution
        u1 = (end_x - geometry.origin_x) / resolution
        v1 = (end_y - geometry.origin_y) / resolution
        _, cols, rows = crossed_cells(np.full(u1.shape, u0), np.full(v1.shape, v0), u1, v1)
        # the traversal may count a cell just past the grid at a corner: the grid covers the rays, so clip
        np.clip(cols, 0, geometry.width - 1, out=cols)
        np.clip(rows, 0, geometry.height - 1, out=rows)
        crossed = np.unique(rows * width + cols)
        hit_cols = np.clip(np.floor(u1[hit]).astype(np.intp), 0, geometry.width - 1)
        hit_rows = np.clip(np.floor(v1[hit]).astype(np.intp), 0, geometry.height - 1)
        hit_cells = hit_rows * width + hit_cols
        hits = np.unique(hit_cells)
        cleared = crossed[~np.isin(crossed, hits, assume_unique=True)]
        log_odds = self.log_odds.reshape(-1)
        log_odds[cleared] = np.maximum(log_odds[cleared] + LOG_ODDS_FREE, LOG_ODDS_MIN)
        log_odds[hits] = np.minimum(log_odds[hits] + LOG_ODDS_HIT, LOG_ODDS_MAX)
        seen = self.seen.reshape(-1)
        seen[crossed] = True
        seen[hits] = True
        ray_x, ray_y = end_x[hit] - origin_x, end_y[hit] - origin_y
        np.bitwise_or.at(self.facing.reshape(-1), hit_cells, facing_bits(ray_x, ray_y))
        length = np.maximum(np.hypot(ray_x, ray_y), 1e-12)
        np.add.at(self.view_sums.reshape(-1, 2), hit_cells, np.stack((-ray_x / length, -ray_y / length), axis=1))
        offsets = np.stack(((u1[hit] - hit_cols - 0.5) * resolution, (v1[hit] - hit_rows - 0.5) * resolution), axis=1)
        np.add.at(self.hit_sums.reshape(-1, 2), hit_cells, offsets)
        np.add.at(self.hit_counts.reshape(-1), hit_cells, 1.0)

    def occupied(self) -> Bools:
        """The cells more likely occupied than not."""
        return self.log_odds > 0.0

    def grid(self) -> Grid:
        """The map: :data:`OCCUPIED` where more likely occupied than not, :data:`FREE` where seen and not,
        :data:`UNKNOWN` where no ray reached; one unknown cell at the origin while nothing was inserted.
        An occupied cell :meth:`in_front_of_its_surface` is :data:`FREE`: the surface is its boundary
        with the cell behind."""
        if self.empty:
            return Grid(GridGeometry(self.resolution, 1, 1, 0.0, 0.0), np.full((1, 1), UNKNOWN, dtype=np.int8))
        cells = np.full(self.log_odds.shape, UNKNOWN, dtype=np.int8)
        cells[self.seen] = FREE
        cells[self.seen & self.occupied() & ~self.in_front_of_its_surface()] = OCCUPIED
        return Grid(self.geometry, cells)

    def in_front_of_its_surface(self) -> Bools:
        """The occupied cells whose hits lie in their far half, seen from where the rays came (along the
        axis nearer their mean view), with an occupied cell behind them on that axis.

        A surface on a cell's boundary splits a noisy lidar's hits between the cell in front of it and
        the cell behind it, and both come out occupied: the surface drawn a cell nearer than it is, and
        a localization on such a map reads every wall a cell short (measured: 5.2 cm RMS on a made map
        of the three_rooms tour, 3.6 cm with these cells free, as on the world's own map). A surface
        inside a cell leaves the cell behind free and the cell drawn."""
        occupied = self.occupied()
        counts = np.maximum(self.hit_counts, 1.0)
        view_x, view_y = self.view_sums[:, :, 0], self.view_sums[:, :, 1]
        along_x = np.abs(view_x) >= np.abs(view_y)
        # hits deeper than the centre, away from the side they were seen from
        deep_x = view_x * self.hit_sums[:, :, 0] / counts < 0.0
        deep_y = view_y * self.hit_sums[:, :, 1] / counts < 0.0
        behind = np.zeros_like(occupied)
        seen_from_plus_x = along_x & (view_x > 0.0)
        seen_from_minus_x = along_x & (view_x < 0.0)
        seen_from_plus_y = ~along_x & (view_y > 0.0)
        seen_from_minus_y = ~along_x & (view_y < 0.0)
        behind[:, 1:] |= seen_from_plus_x[:, 1:] & occupied[:, :-1]
        behind[:, :-1] |= seen_from_minus_x[:, :-1] & occupied[:, 1:]
        behind[1:, :] |= seen_from_plus_y[1:, :] & occupied[:-1, :]
        behind[:-1, :] |= seen_from_minus_y[:-1, :] & occupied[1:, :]
        return occupied & behind & np.where(along_x, deep_x, deep_y)


def facing_bits(dx: Floats, dy: Floats) -> npt.NDArray[np.uint8]:
    """The facing bits of rays travelling along (dx, dy): bit 0 +x, 1 −x, 2 +y, 3 −y, each set where the
    direction's component along it is at least :data:`FACING_COMPONENT`."""
    norm = np.maximum(np.hypot(dx, dy), 1e-12)
    ux, uy = dx / norm, dy / norm
    bits = (
        (ux >= FACING_COMPONENT).astype(np.uint8)
        | ((ux <= -FACING_COMPONENT).astype(np.uint8) << 1)
        | ((uy >= FACING_COMPONENT).astype(np.uint8) << 2)
        | ((uy <= -FACING_COMPONENT).astype(np.uint8) << 3)
    )
    return bits.astype(np.uint8)


def dominant_facing(dx: Floats, dy: Floats) -> npt.NDArray[np.intp]:
    """The one facing (0 +x, 1 −x, 2 +y, 3 −y) of rays along (dx, dy): their largest component's."""
    return np.argmax(np.stack((dx, -dx, dy, -dy)), axis=0)


def _union(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


def _within_limit(low: int, high: int, need_low: int, need_high: int, limit: int) -> tuple[int, int]:
    """[``low``, ``high``) shrunk towards [``need_low``, ``need_high``) to at most ``limit`` cells."""
    excess = (high - low) - limit
    if excess <= 0:
        return low, high
    spare_low, spare_high = need_low - low, high - need_high
    take_low = max(excess - spare_high, min(spare_low, (excess + 1) // 2))
    low += take_low
    high -= excess - take_low
    return low, high
