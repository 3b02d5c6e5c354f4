"""The likelihood field of a map (pure, numpy, scipy): for any point, the distance to the nearest
occupied cell, what the particle filter's sensor model reads at each ray's endpoint
(services/localization/amcl.py).

As nav2_amcl's map (``convertMap``, ``map_update_cspace``): a cell of 100 is occupied, of 0 free,
anything else unknown; distances are measured from occupied cells only, so an unknown cell has a
distance like a free one; each distance is capped at ``max_distance`` (nav2's
``laser_likelihood_max_dist``), and a point off the map is at ``max_distance``. A distance is that of
the point's cell's centre to the nearest occupied cell's centre (the exact Euclidean transform,
scipy's ``distance_transform_edt``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.ndimage import distance_transform_edt

from services.navigation.grid import FREE, OCCUPIED, Grid, GridGeometry

Floats = npt.NDArray[np.float64]
Indices = npt.NDArray[np.intp]


class LikelihoodField:
    """Distances to the nearest obstacle over a map, looked up for many points at once.

    :attr:`table` holds one distance per cell, row-major (``row * width + col``), then one more entry,
    ``max_distance``, for every point off the map: :meth:`indices` gives each point's entry, so that a
    caller may build a table of its own over the same cells (the particle filter's per-ray
    likelihood) and look it up with one ``take``.
    """

    def __init__(self, grid: Grid, max_distance: float) -> None:
        if not (math.isfinite(max_distance) and max_distance > 0.0):
            raise ValueError(f"max_distance {max_distance!r} must be finite and > 0")
        self.geometry: GridGeometry = grid.geometry
        self.max_distance = float(max_distance)
        occupied = grid.cells == OCCUPIED
        if occupied.any() and not occupied.all():
            # centre to centre, outside an obstacle and inside one, less half a cell: the distance
            # from a cell's centre to the nearest obstacle's surface, a cell boundary
            cells_away = np.where(occupied, distance_transform_edt(occupied), distance_transform_edt(~occupied))
            distance = np.minimum((cells_away - 0.5) * grid.geometry.resolution, self.max_distance)
        else:  # no obstacle, or nothing but: no surface, every point as far as the field reaches
            distance = np.full(grid.geometry.shape, self.max_distance)
        self.table: Floats = np.append(distance.ravel(), self.max_distance)
        self.table.flags.writeable = False
        self.off_map = grid.geometry.width * grid.geometry.height
        """The index of :attr:`table`'s last entry: every point off the map's."""
        self.free_cells: Indices = np.flatnonzero(grid.cells == FREE)
        """The free cells, as indices into :attr:`table` (where random particles may be drawn)."""
        self.free_cells.flags.writeable = False

    @property
    def distance(self) -> Floats:
        """The distances as a grid ``[row, col]`` (a read-only view)."""
        return self.table[: self.off_map].reshape(self.geometry.shape)

    def indices(self, xs: Floats, ys: Floats) -> Indices:
        """Each point's entry in :attr:`table`: its cell's, or :attr:`off_map` (a NaN is off the map)."""
        geometry = self.geometry
        on_map = (xs >= geometry.origin_x) & (xs < geometry.max_x) & (ys >= geometry.origin_y) & (ys < geometry.max_y)
        # as GridGeometry.cell: a point just below the far edge may round onto it, and takes the last
        # cell; casting only what is on the map avoids casting a NaN or a huge float to an integer
        columns = np.where(on_map, (xs - geometry.origin_x) / geometry.resolution, 0.0).astype(np.intp)
        rows = np.where(on_map, (ys - geometry.origin_y) / geometry.resolution, 0.0).astype(np.intp)
        row = np.minimum(rows, geometry.height - 1)
        column = np.minimum(columns, geometry.width - 1)
        return np.where(on_map, row * geometry.width + column, self.off_map)

    def distances(self, xs: npt.ArrayLike, ys: npt.ArrayLike) -> Floats:
        """The distance (m) from each point (``xs``, ``ys`` of one shape) to the nearest occupied
        cell, capped at :attr:`max_distance`; a point off the map, or not finite, is at it."""
        x = np.asarray(xs, dtype=np.float64)
        y = np.asarray(ys, dtype=np.float64)
        if x.shape != y.shape:
            raise ValueError(f"xs of shape {x.shape} and ys of shape {y.shape}")
        return self.table[self.indices(x, y)]

    def free_points(self, count: int, rng: np.random.Generator) -> tuple[Floats, Floats]:
        """``count`` points drawn uniformly over the free cells (a cell, then a point within it)."""
        if self.free_cells.size == 0:
            raise ValueError("the map has no free cell")
        cells = rng.choice(self.free_cells, size=count)
        rows, columns = np.divmod(cells, self.geometry.width)
        resolution = self.geometry.resolution
        xs = self.geometry.origin_x + (columns + rng.random(count)) * resolution
        ys = self.geometry.origin_y + (rows + rng.random(count)) * resolution
        return xs, ys
