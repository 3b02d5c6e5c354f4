"""Grids over the ``map`` frame (pure, numpy; docs/navigation.md): where each cell lies, and an
occupancy grid as a value (the map a file or a world gives, the costmap as published).

Cell (col, row) covers x in [origin_x + col·resolution, origin_x + (col + 1)·resolution) and y the
same from origin_y; arrays are indexed ``[row, col]``, row 0 the lowest y (as nav_msgs/OccupancyGrid's
data, row-major from the origin). Occupancy values are ROS's: 0 free to 100 occupied, -1 unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.messages import Time
from schemas.navigation import OCCUPANCY_UNKNOWN, OccupancyGrid

OCCUPIED = 100
FREE = 0
UNKNOWN = OCCUPANCY_UNKNOWN

Occupancy = npt.NDArray[np.int8]
"""An occupancy array ``[row, col]``: -1, or 0 to 100."""


@dataclass(frozen=True)
class GridGeometry:
    """Where a grid's cells lie in ``map``: ``width`` × ``height`` cells of ``resolution`` m from the
    lower-left corner (``origin_x``, ``origin_y``)."""

    resolution: float
    width: int
    height: int
    origin_x: float
    origin_y: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0.0):
            raise ValueError(f"resolution {self.resolution!r} must be finite and > 0")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"{self.width} x {self.height} cells: a grid has at least one")
        if not (math.isfinite(self.origin_x) and math.isfinite(self.origin_y)):
            raise ValueError(f"origin ({self.origin_x!r}, {self.origin_y!r}) must be finite")

    @classmethod
    def centred(cls, x: float, y: float, size: float, resolution: float) -> GridGeometry:
        """A square grid of side ``size`` (rounded up to whole cells) centred on (``x``, ``y``)."""
        cells = max(1, math.ceil(size / resolution - 1e-9))
        half = cells * resolution / 2.0
        return cls(resolution, cells, cells, x - half, y - half)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``: an array's shape over this grid."""
        return self.height, self.width

    @property
    def max_x(self) -> float:
        return self.origin_x + self.width * self.resolution

    @property
    def max_y(self) -> float:
        return self.origin_y + self.height * self.resolution

    def contains(self, x: float, y: float) -> bool:
        """Whether the point lies on the grid."""
        return self.origin_x <= x < self.max_x and self.origin_y <= y < self.max_y

    def cell(self, x: float, y: float) -> tuple[int, int] | None:
        """``(col, row)`` of the cell holding the point; None off the grid."""
        if not self.contains(x, y):
            return None
        col = min(int((x - self.origin_x) / self.resolution), self.width - 1)
        row = min(int((y - self.origin_y) / self.resolution), self.height - 1)
        return col, row

    def centre(self, col: int, row: int) -> tuple[float, float]:
        """The map-frame point at the centre of cell (``col``, ``row``)."""
        return (
            self.origin_x + (col + 0.5) * self.resolution,
            self.origin_y + (row + 0.5) * self.resolution,
        )

    def cells_of(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.bool_]]:
        """``(cols, rows, on_grid)`` of points given as arrays: their cells, and which lie on the grid
        (the cells of the others are clipped to the edge and mean nothing)."""
        cols = np.floor((x - self.origin_x) / self.resolution).astype(np.intp)
        rows = np.floor((y - self.origin_y) / self.resolution).astype(np.intp)
        on_grid = (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.height)
        return np.clip(cols, 0, self.width - 1), np.clip(rows, 0, self.height - 1), on_grid


@dataclass(frozen=True)
class Grid:
    """An occupancy grid: its geometry and its cells (``[row, col]``, -1 or 0 to 100)."""

    geometry: GridGeometry
    cells: Occupancy

    def __post_init__(self) -> None:
        if self.cells.shape != self.geometry.shape:
            raise ValueError(f"cells of shape {self.cells.shape} on a grid of {self.geometry.shape}")
        if self.cells.dtype != np.int8:
            raise ValueError(f"cells of {self.cells.dtype}, not int8")

    def message(self, tm: Time) -> OccupancyGrid:
        """The grid as ``drive/map`` or ``drive/costmap`` carries it."""
        geometry = self.geometry
        return OccupancyGrid(
            tm=tm,
            resolution=geometry.resolution,
            width=geometry.width,
            height=geometry.height,
            origin_x=geometry.origin_x,
            origin_y=geometry.origin_y,
            data=self.cells.tobytes(),
        )

    @classmethod
    def of_message(cls, message: OccupancyGrid) -> Grid:
        geometry = GridGeometry(message.resolution, message.width, message.height, message.origin_x, message.origin_y)
        cells = np.frombuffer(message.data, dtype=np.int8).reshape(geometry.shape).copy()
        return cls(geometry, cells)
