"""The costmap (services/navigation/costmap.py): marking and raytrace clearing from scans, the static
layer, clipping at the grid's edge, bad origins, the inflation's radii, the unknown, the occupancy
translation (tests/test_costmap_shortcuts.py: the traversal, the windowed inflation and repeated scans
against brute force)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas.codec import BadInput
from schemas.messages import LaserScan, Time
from services.config import RobotConfig
from services.config.navigation import NavigationConfig
from services.navigation.costmap import (
    FREE,
    INSCRIBED,
    LETHAL,
    MAX_INFLATED,
    OCCUPANCY_OF_COST,
    Costmap,
)
from services.navigation.grid import OCCUPIED, UNKNOWN, GridGeometry

SETTINGS = NavigationConfig()
BODY = RobotConfig().radius_of_body_area  # 0.45 m: inscribed radius 0.5 m with the default padding
GEOMETRY = GridGeometry.centred(0.0, 0.0, 10.0, 0.05)  # 200 x 200 cells, from (-5, -5)
LIDAR = (0.003, 0.01, 0.0)
"""The lidar's pose: off the cell boundaries, so that a return at a round distance lies inside a cell
(x = 2.003 in the cell from 2.0 to 2.05)."""


def rays(ranges: list[float | None], angle_min: float = 0.0, increment: float = 0.01, **limits: float) -> LaserScan:
    return LaserScan(
        tm=Time(sec=0, nsec=0),
        angle_min=angle_min,
        angle_increment=increment,
        range_min=limits.get("range_min", 0.12),
        range_max=limits.get("range_max", 3.5),
        ranges=ranges,
    )


def one_ray(distance: float | None, angle: float = 0.0, **limits: float) -> LaserScan:
    return rays([distance], angle_min=angle, **limits)


def costmap(static: np.ndarray | None = None, geometry: GridGeometry = GEOMETRY, **changes) -> Costmap:
    settings = NavigationConfig(**changes) if changes else SETTINGS
    return Costmap(geometry, settings, BODY, static)


def cell_of(costmap: Costmap, x: float, y: float) -> tuple[int, int]:
    cell = costmap.geometry.cell(x, y)
    assert cell is not None
    return cell[1], cell[0]  # [row, col]


def empty_map(geometry: GridGeometry = GEOMETRY) -> np.ndarray:
    return np.zeros(geometry.shape, dtype=np.int8)


# -- marking and clearing ---------------------------------------------------------------------


def test_a_return_marks_its_cell_lethal_and_the_ray_clears_the_cells_before_it():
    costs = costmap()
    costs.mark_scan(one_ray(2.0), *LIDAR)
    assert costs.cost_at(2.01, 0.01) == LETHAL
    assert costs.status()["obstacle_cells"] == 1
    known = costs.known()
    for x in np.arange(0.01, 1.99, 0.05):
        assert known[cell_of(costs, x, 0.01)], x  # seen: cleared
    assert not known[cell_of(costs, 2.2, 0.01)], "beyond the return, never seen"


def test_an_obstacle_that_moved_away_is_forgotten_when_rays_pass_through_its_cell():
    costs = costmap()
    costs.mark_scan(one_ray(1.5), *LIDAR)
    assert costs.cost_at(1.51, 0.01) == LETHAL
    costs.mark_scan(one_ray(3.0), *LIDAR)  # what stood at 1.5 m is gone: the ray goes on to 3 m
    assert costs.cost_at(1.51, 0.01) != LETHAL
    assert costs.cost_at(3.01, 0.01) == LETHAL
    assert costs.status()["obstacle_cells"] == 1


def test_a_ray_with_no_return_clears_up_to_the_smaller_of_range_max_and_raytrace_range():
    costs = costmap()
    costs.mark_scan(one_ray(1.0), *LIDAR)
    costs.mark_scan(one_ray(2.9), *LIDAR)
    assert costs.status()["obstacle_cells"] == 1
    costs.mark_scan(one_ray(None, range_max=2.5), *LIDAR)  # nothing within 2.5 m: 2.9 m stays
    assert costs.cost_at(2.91, 0.01) == LETHAL
    costs.mark_scan(one_ray(None, range_max=5.0), *LIDAR)  # raytrace_range 3.5 m reaches it
    assert costs.status()["obstacle_cells"] == 0


def test_a_return_beyond_raytrace_range_clears_only_up_to_raytrace_range():
    costs = costmap(obstacle_range=3.0, raytrace_range=3.5)
    costs.mark_scan(one_ray(3.6, range_max=4.0), -0.1, 0.0, 0.0)  # beyond obstacle_range: not marked
    assert costs.status()["obstacle_cells"] == 0
    costs.mark_scan(one_ray(2.8, range_max=4.0), 0.81, 0.0, 0.0)  # an obstacle at x = 3.61
    assert costs.cost_at(3.62, 0.01) == LETHAL
    costs.mark_scan(one_ray(3.9, range_max=4.0), -0.1, 0.0, 0.0)  # passes it, but clears only to x = 3.4
    assert costs.cost_at(3.62, 0.01) == LETHAL


def test_returns_within_obstacle_range_mark_and_beyond_it_only_clear():
    costs = costmap(obstacle_range=2.0, raytrace_range=3.5)
    costs.mark_scan(rays([1.9, 2.5], angle_min=0.0, increment=math.pi / 2), *LIDAR)
    assert costs.cost_at(1.91, 0.01) == LETHAL
    assert costs.cost_at(0.01, 2.51) != LETHAL
    assert costs.status()["obstacle_cells"] == 1


def test_ranges_below_range_min_are_ignored_and_counted():
    costs = costmap()
    costs.mark_scan(one_ray(1.0), *LIDAR)
    before = costs.costs.copy()
    costs.mark_scan(one_ray(0.05, range_min=0.12), *LIDAR)
    assert costs.status()["rays_below_range_min"] == 1
    assert np.array_equal(costs.costs, before), "neither cleared nor marked"


def test_the_lidars_heading_and_position_place_the_returns_in_map():
    costs = costmap()
    costs.mark_scan(one_ray(1.02, angle=math.pi / 2), 1.0, -0.99, math.pi / 2)  # the ray points along -x
    assert costs.cost_at(-0.01, -0.99) == LETHAL


def test_static_cells_are_never_cleared_by_rays():
    static = empty_map()
    row, col = cell_of(costmap(), 1.01, 0.01)
    static[row, col] = OCCUPIED
    costs = costmap(static)
    costs.mark_scan(one_ray(3.0), *LIDAR)  # passes through the static cell
    assert costs.cost_at(1.01, 0.01) == LETHAL
    costs.clear_obstacles()
    assert costs.cost_at(1.01, 0.01) == LETHAL
    assert costs.status()["static_cells"] == 1


def test_a_map_cell_above_50_is_an_obstacle_and_50_is_not():
    static = empty_map()
    static[10, 10], static[20, 20] = 51, 50
    costs = costmap(static)
    assert costs.costs[10, 10] == LETHAL
    assert costs.costs[20, 20] != LETHAL


def test_clearing_the_obstacle_layer_forgets_what_the_lidar_marked():
    costs = costmap()
    costs.mark_scan(rays([1.0, 1.5, 2.0], increment=0.5), *LIDAR)
    assert costs.status()["obstacle_cells"] == 3
    costs.clear_obstacles()
    assert costs.status()["obstacle_cells"] == 0
    assert int(costs.costs.max()) == FREE


def test_a_ray_off_the_grid_is_clipped_at_its_edge_and_counted():
    costs = costmap()
    costs.mark_scan(one_ray(2.0), 4.0, 0.01, 0.0)  # the return at x = 6: off the 10 m grid
    status = costs.status()
    assert status["rays_clipped"] == 1
    assert status["obstacle_cells"] == 0
    known = costs.known()
    assert known[cell_of(costs, 4.99, 0.01)], "cleared up to the edge"
    costs.mark_scan(one_ray(None, range_max=3.5), 4.0, 0.01, math.pi)  # into the grid: not clipped
    assert costs.status()["rays_clipped"] == 1


@pytest.mark.parametrize(
    ("x", "y", "yaw"),
    [(5.5, 0.0, 0.0), (0.0, -5.01, 0.0), (math.nan, 0.0, 0.0), (0.0, 0.0, math.inf)],
    ids=["east", "south", "nan", "yaw"],
)
def test_a_lidar_off_the_grid_raises_bad_input_and_changes_nothing(x, y, yaw):
    costs = costmap()
    costs.mark_scan(one_ray(1.0), *LIDAR)
    before_costs, before_status, before_known = costs.costs.copy(), costs.status(), costs.known().copy()
    with pytest.raises(BadInput, match="not on the costmap"):
        costs.mark_scan(one_ray(1.0), x, y, yaw)
    assert np.array_equal(costs.costs, before_costs)
    assert costs.status() == before_status
    assert np.array_equal(costs.known(), before_known)


# -- inflation --------------------------------------------------------------------------------


def test_the_inflation_radii_around_one_obstacle():
    static = empty_map()
    static[100, 100] = OCCUPIED  # the cell centred on (0.025, 0.025)
    costs = costmap(static).costs
    inscribed = BODY + SETTINGS.footprint_padding  # 0.5 m, 10 cells
    assert costs[100, 100] == LETHAL
    assert costs[100, 101] == INSCRIBED
    assert costs[100, 110] == INSCRIBED, "10 cells away: on the inscribed radius"
    assert costs[107, 107] == INSCRIBED, "sqrt(98) < 10 cells"
    assert costs[100, 111] == math.floor(MAX_INFLATED * math.exp(-SETTINGS.cost_scaling_factor * (0.55 - inscribed)))
    assert costs[100, 114] == math.floor(MAX_INFLATED * math.exp(-SETTINGS.cost_scaling_factor * (0.70 - inscribed)))
    assert 1 <= costs[100, 120] < costs[100, 111], "decaying out to inflation_radius (1 m, 20 cells)"
    assert costs[100, 121] == FREE, "beyond the inflation radius"
    assert costs[115, 115] == FREE, "sqrt(450) cells = 1.06 m"
    along = [int(costs[100, col]) for col in range(111, 121)]
    assert along == sorted(along, reverse=True)


def test_the_decaying_cost_is_at_least_one_within_the_inflation_radius():
    static = empty_map()
    static[100, 100] = OCCUPIED
    costs = costmap(static, cost_scaling_factor=50.0).costs
    assert costs[100, 120] == 1
    assert costs[100, 121] == FREE


def test_inflation_follows_the_obstacle_layer_when_it_changes():
    costs = costmap()
    costs.mark_scan(one_ray(2.0), *LIDAR)
    assert costs.cost_at(2.01 - 0.3, 0.01) == INSCRIBED
    costs.mark_scan(one_ray(3.0), *LIDAR)
    assert costs.cost_at(2.01 - 0.3, 0.01) == FREE
    assert costs.cost_at(3.01 - 0.3, 0.01) == INSCRIBED


def test_a_scan_that_changes_nothing_costs_no_inflation():
    costs = costmap()
    costs.mark_scan(one_ray(2.0), *LIDAR)
    _ = costs.costs  # the inflation the scan caused
    inflations = costs.status()["inflations"]
    costs.mark_scan(one_ray(2.0), *LIDAR)
    _ = costs.costs
    assert costs.status()["inflations"] == inflations
    assert costs.status()["scans_changing"] == 1


def test_the_costs_are_read_only():
    with pytest.raises(ValueError, match="read-only"):
        costmap().costs[0, 0] = LETHAL


# -- the unknown and the published occupancy -------------------------------------------------


def test_unknown_cells_are_usable_and_published_unknown():
    costs = costmap()
    assert int(costs.costs.max()) == FREE
    assert costs.cost_at(1.0, 1.0) == FREE
    assert costs.line_cost(-4.0, -4.0, 4.0, 4.0) == FREE
    assert np.all(costs.occupancy().cells == UNKNOWN)


def test_off_the_grid_is_lethal():
    costs = costmap()
    assert costs.cost_at(5.0, 0.0) == LETHAL
    assert costs.cost_at(0.0, -5.01) == LETHAL
    assert costs.line_cost(0.0, 0.0, 6.0, 0.0) == LETHAL


def test_the_occupancy_translation_is_nav2s():
    assert OCCUPANCY_OF_COST[FREE] == 0
    assert OCCUPANCY_OF_COST[1] == 1
    assert OCCUPANCY_OF_COST[MAX_INFLATED] == 98
    assert OCCUPANCY_OF_COST[INSCRIBED] == 99
    assert OCCUPANCY_OF_COST[LETHAL] == 100
    assert list(OCCUPANCY_OF_COST[1 : MAX_INFLATED + 1]) == sorted(OCCUPANCY_OF_COST[1 : MAX_INFLATED + 1])


def test_the_occupancy_is_unknown_where_never_seen_and_not_on_the_map():
    static = np.full(GEOMETRY.shape, UNKNOWN, dtype=np.int8)
    static[:, :100] = 0  # the map knows the west half, free
    static[50, 50] = OCCUPIED
    costs = costmap(static)
    costs.mark_scan(one_ray(2.0), *LIDAR)  # sees along y = 0.01 east, up to x = 2
    grid = costs.occupancy()
    assert grid.geometry == GEOMETRY
    cells = grid.cells
    assert cells[50, 50] == 100
    assert cells[50, 51] == 99
    assert cells[60, 10] == 0, "on the map, free"
    assert cells[cell_of(costs, 0.5, 0.01)] == 0, "seen, free (1.5 m from the return)"
    assert cells[cell_of(costs, 2.01, 0.01)] == 100, "seen, an obstacle"
    assert cells[cell_of(costs, 1.76, 0.01)] == 99, "seen, within the inscribed radius"
    assert cells[cell_of(costs, 4.0, 4.0)] == UNKNOWN
    assert cells[cell_of(costs, 2.01, 0.31)] == UNKNOWN, "never seen, though inscribed: unknown"
    decaying = cells[cell_of(costs, 1.3, 0.01)]
    assert 1 <= decaying <= 98
    assert decaying == OCCUPANCY_OF_COST[costs.cost_at(1.3, 0.01)]
