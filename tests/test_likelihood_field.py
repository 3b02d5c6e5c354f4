"""The likelihood field (services/localization/likelihood.py): distances to the nearest obstacle's
surface, capped, off the map at the cap, against a brute force on small random grids."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from services.localization.likelihood import LikelihoodField
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry

RESOLUTION = 0.05


def grid_of(cells: np.ndarray, origin: tuple[float, float] = (0.0, 0.0)) -> Grid:
    height, width = cells.shape
    return Grid(GridGeometry(RESOLUTION, width, height, *origin), cells.astype(np.int8))


def wall_grid() -> Grid:
    """10 × 10 cells, free but for an occupied column 5 and an unknown corner cell."""
    cells = np.full((10, 10), FREE, dtype=np.int8)
    cells[:, 5] = OCCUPIED
    cells[0, 0] = UNKNOWN
    return grid_of(cells)


def test_a_cell_beside_the_wall_is_half_a_cell_from_its_surface() -> None:
    field = LikelihoodField(wall_grid(), 2.0)
    centres_x = (np.arange(10) + 0.5) * RESOLUTION
    distances = field.distances(centres_x, np.full(10, 0.275))
    expected = np.abs(np.arange(10) - 5) * RESOLUTION - RESOLUTION / 2
    expected[5] = RESOLUTION / 2  # inside the one-cell wall: half a cell from either face
    np.testing.assert_allclose(distances, expected)


def test_unknown_cells_have_distances_as_free_ones() -> None:
    field = LikelihoodField(wall_grid(), 2.0)
    assert field.distances([0.025], [0.025])[0] == pytest.approx(4.5 * RESOLUTION)
    assert field.free_cells.size == 10 * 10 - 10 - 1


def test_distances_are_capped_and_off_the_map_or_not_finite_at_the_cap() -> None:
    field = LikelihoodField(wall_grid(), 0.1)
    assert field.distances([0.025], [0.2])[0] == 0.1
    off = field.distances([-0.01, 0.6, 0.2, math.nan, math.inf, 1e300], [0.2, 0.2, -1e-9, 0.2, 0.2, 0.2])
    np.testing.assert_array_equal(off, np.full(6, 0.1))


def test_a_map_without_obstacles_is_everywhere_at_the_cap() -> None:
    field = LikelihoodField(grid_of(np.zeros((4, 6))), 2.0)
    np.testing.assert_array_equal(field.distance, np.full((4, 6), 2.0))


def test_the_arrays_must_agree_and_the_cap_be_positive() -> None:
    field = LikelihoodField(wall_grid(), 2.0)
    with pytest.raises(ValueError, match="shape"):
        field.distances([0.1, 0.2], [0.1])
    with pytest.raises(ValueError, match="max_distance"):
        LikelihoodField(wall_grid(), 0.0)


def brute_force(grid: Grid, x: float, y: float, cap: float) -> float:
    """Centre to centre to the nearest cell across the surface, less half a cell, capped."""
    geometry = grid.geometry
    cell = geometry.cell(x, y)
    occupied = grid.cells == OCCUPIED
    if cell is None or occupied.all() or not occupied.any():
        return cap
    col, row = cell
    rows, cols = np.nonzero(occupied != occupied[row, col])
    nearest = np.hypot(rows - row, cols - col).min()
    return min((nearest - 0.5) * geometry.resolution, cap)


@settings(max_examples=60, deadline=None)
@given(
    cells=arrays(np.int8, st.tuples(st.integers(1, 12), st.integers(1, 12)), elements=st.sampled_from([-1, 0, 100])),
    points=st.lists(st.tuples(st.floats(-0.2, 0.8), st.floats(-0.2, 0.8)), min_size=1, max_size=20),
    cap=st.floats(0.01, 1.0),
)
def test_distances_match_a_brute_force(cells: np.ndarray, points: list[tuple[float, float]], cap: float) -> None:
    grid = grid_of(cells, origin=(-0.1, -0.05))
    field = LikelihoodField(grid, cap)
    xs, ys = np.array(points).T
    expected = [brute_force(grid, x, y, cap) for x, y in points]
    np.testing.assert_allclose(field.distances(xs, ys), expected, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 200))
def test_free_points_fall_in_free_cells(seed: int, count: int) -> None:
    field = LikelihoodField(wall_grid(), 2.0)
    xs, ys = field.free_points(count, np.random.default_rng(seed))
    cells = field.indices(xs, ys)
    assert np.isin(cells, field.free_cells).all()
