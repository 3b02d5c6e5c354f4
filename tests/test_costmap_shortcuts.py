"""The costmap's shortcuts against brute force (services/navigation/costmap.py): line costs and the
grid traversal, the windowed inflation against one over the whole grid, scans against a plain
per-ray trace (hypothesis), repeated scans not traced again (tests/test_costmap.py: the layers, the
inflation's radii, the occupancy).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from schemas.messages import LaserScan
from services.config.navigation import NavigationConfig
from services.navigation.costmap import (
    FREE,
    INSCRIBED,
    LETHAL,
    SAME_SCAN_M,
    Costmap,
)
from services.navigation.grid import OCCUPIED, UNKNOWN, GridGeometry
from services.navigation.traversal import crossed_cells
from tests.test_costmap import GEOMETRY, LIDAR, costmap, empty_map, rays

# -- line costs and the traversal -------------------------------------------------------------


def test_line_cost_is_the_highest_cost_the_segment_crosses():
    static = empty_map()
    static[100, 100] = OCCUPIED
    costs = costmap(static)
    assert costs.line_cost(-1.0, 0.025, 1.0, 0.025) == LETHAL
    assert costs.line_cost(-1.0, 0.4, 1.0, 0.4) == INSCRIBED
    assert costs.line_cost(-1.0, 2.0, 1.0, 2.0) == FREE
    assert costs.line_cost(0.0, 2.0, 0.0, 2.0) == FREE, "a point"


def test_a_segment_through_a_corner_counts_the_cells_beside_it():
    static = empty_map()
    static[101, 100] = OCCUPIED  # north of the cell (100, 100); the diagonal from (99, 99) to (101, 101) touches it
    costs = costmap(static)
    x0, y0 = GEOMETRY.centre(99, 99)
    x1, y1 = GEOMETRY.centre(101, 101)
    assert costs.line_cost(x0, y0, x1, y1) == LETHAL


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, 30.0),
    st.floats(0.0, 30.0),
    st.floats(0.0, 30.0),
    st.floats(0.0, 30.0),
)
def test_the_traversal_holds_every_cell_a_point_of_the_segment_lies_in_and_no_cell_far_from_it(u0, v0, u1, v1):
    _, cols, rows = crossed_cells(np.array([u0]), np.array([v0]), np.array([u1]), np.array([v1]))
    found = set(zip(cols.tolist(), rows.tolist(), strict=True))
    nudges = (-1e-9, 0.0, 1e-9)  # a sample's own rounding may put it across a grid line
    for t in np.linspace(0.0, 1.0, 2001):
        u, v = u0 * (1.0 - t) + u1 * t, v0 * (1.0 - t) + v1 * t
        cells = {(math.floor(u + du), math.floor(v + dv)) for du in nudges for dv in nudges}
        assert cells & found, (u, v)
    length = math.hypot(u1 - u0, v1 - v0)
    t = np.linspace(0.0, 1.0, 4001)
    u, v = u0 + t * (u1 - u0), v0 + t * (v1 - v0)
    for col, row in found:
        # the distance from the segment to the cell's box is (nearly) zero
        outside_u = np.maximum(np.maximum(col - u, 0.0), u - col - 1)
        outside_v = np.maximum(np.maximum(row - v, 0.0), v - row - 1)
        closest = float(np.hypot(outside_u, outside_v).min())
        assert closest <= length / 4000 + 1e-6, (col, row)


def full_costs(costs: Costmap, static: np.ndarray | None) -> np.ndarray:
    """The costs computed from scratch: the layers' union, one distance transform over the whole grid."""
    lethal = costs.obstacles.copy()
    if static is not None:
        lethal |= static > 50
    if not lethal.any():
        return np.zeros(lethal.shape, dtype=np.uint8)
    return costs.cost_of_distance(ndimage.distance_transform_edt(~lethal, sampling=costs.geometry.resolution))


SMALL = GridGeometry(0.1, 60, 50, -3.0, -2.5)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-2.9, 2.9),
            st.floats(-2.4, 2.4),
            st.floats(-math.pi, math.pi),
            st.lists(st.one_of(st.none(), st.floats(0.0, 4.0)), min_size=1, max_size=40),
        ),
        min_size=1,
        max_size=6,
    ),
    st.booleans(),
    st.booleans(),
)
def test_the_windowed_inflation_equals_one_over_the_whole_grid(scans, with_map, clear_between):
    static = None
    if with_map:
        static = np.zeros(SMALL.shape, dtype=np.int8)
        static[10:12, 5:40] = OCCUPIED
    costs = Costmap(SMALL, NavigationConfig(inflation_radius=0.6), 0.2, static)
    for index, (x, y, yaw, ranges) in enumerate(scans):
        costs.mark_scan(rays(ranges, angle_min=-math.pi, increment=2 * math.pi / len(ranges)), x, y, yaw)
        if clear_between and index == 1:
            costs.clear_obstacles()
        assert np.array_equal(costs.costs, full_costs(costs, static))


# -- the vectorised trace against a plain one --------------------------------------------------


def plain_traversal(u0: float, v0: float, u1: float, v1: float) -> list[tuple[int, int]]:
    """One segment's cells ``(col, row)``, plainly: the start cell, then the cell entered at each grid
    line crossed (both cells beside a corner), the same arithmetic as the vectorised traversal's."""
    cells = [(math.floor(u0), math.floor(v0))]
    for along0, across0, along1, across1, swapped in ((u0, v0, u1, v1, False), (v0, u0, v1, u1, True)):
        first, last = math.floor(along0), math.floor(along1)
        delta_along, delta_across = along1 - along0, across1 - across0
        for step in range(1, abs(last - first) + 1):
            entered = first + step if delta_along > 0.0 else first - step
            line = entered if delta_along > 0.0 else entered + 1
            at = across0 + (line - along0) / delta_along * delta_across
            for across in {math.floor(at - 1e-9), math.floor(at + 1e-9)}:
                cells.append((across, entered) if swapped else (entered, across))
    return cells


class PlainCostmap:
    """The layers a scan leaves, traced ray by ray with no shortcut (no repeat skipped, no window), for
    :class:`Costmap` to be compared with; the costs are :func:`full_costs`'s."""

    def __init__(self, geometry: GridGeometry, settings: NavigationConfig, static: np.ndarray | None) -> None:
        self.geometry, self.settings = geometry, settings
        self.obstacles = np.zeros(geometry.shape, dtype=np.bool_)
        self.seen = np.zeros(geometry.shape, dtype=np.bool_)
        self.known = np.zeros(geometry.shape, dtype=np.bool_) if static is None else static != UNKNOWN
        self.counted = {"scans": 0, "rays": 0, "rays_clipped": 0, "rays_below_range_min": 0}

    def mark_scan(self, scan: LaserScan, x: float, y: float, yaw: float) -> None:
        geometry, settings = self.geometry, self.settings
        resolution, width, height = geometry.resolution, geometry.width, geometry.height
        u0, v0 = (x - geometry.origin_x) / resolution, (y - geometry.origin_y) / resolution
        angles = yaw + scan.angle_min + scan.angle_increment * np.arange(len(scan.ranges))
        cosines, sines = np.cos(angles).tolist(), np.sin(angles).tolist()  # numpy's, as the costmap's
        cleared, marked = [], []
        self.counted["scans"] += 1
        self.counted["rays"] += len(scan.ranges)
        for value, cos, sin in zip(scan.ranges, cosines, sines, strict=True):
            no_return = value is None or math.isnan(value) or value > scan.range_max
            if not no_return and value < scan.range_min:
                self.counted["rays_below_range_min"] += 1
                continue
            length = min(min(scan.range_max, settings.raytrace_range) if no_return else value, settings.raytrace_range)
            length /= resolution
            exits = [
                (cells - start) / d if d > 0.0 else -start / d
                for start, d, cells in ((u0, cos, width), (v0, sin, height))
                if d != 0.0
            ]
            exit_at = min(exits, default=math.inf)
            clipped = length >= exit_at
            self.counted["rays_clipped"] += clipped
            if clipped:
                length = max(exit_at - 1e-9, 0.0)
            u1, v1 = u0 + length * cos, v0 + length * sin
            keeps_end = not no_return and value <= settings.raytrace_range and not clipped
            end = (math.floor(u1), math.floor(v1)) if keeps_end else None
            for col, row in plain_traversal(u0, v0, u1, v1):
                cell = (min(max(col, 0), width - 1), min(max(row, 0), height - 1))
                if cell != end:
                    cleared.append(cell)
            if not no_return and value <= settings.obstacle_range:
                col = math.floor((x + value * cos - geometry.origin_x) / resolution)
                row = math.floor((y + value * sin - geometry.origin_y) / resolution)
                if 0 <= col < width and 0 <= row < height:
                    marked.append((col, row))
        for col, row in cleared:
            self.obstacles[row, col] = False
            self.seen[row, col] = True
        for col, row in marked:
            self.obstacles[row, col] = True
            self.seen[row, col] = True


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.0, 60.0), st.floats(0.0, 50.0), st.floats(-30.0, 90.0), st.floats(-30.0, 80.0)),
        min_size=1,
        max_size=20,
    ),
    st.integers(0, 2),
)
def test_the_traversal_is_the_plain_one_segment_by_segment(segments, rounding):
    # rounded ends put crossings on grid corners, where the tolerance counts both cells
    ends = (
        np.round(np.array(segments, dtype=np.float64) * 2**rounding) / 2**rounding if rounding else np.array(segments)
    )
    segment, cols, rows = crossed_cells(*ends.T.copy())
    found = sorted(zip(segment.tolist(), cols.tolist(), rows.tolist(), strict=True))
    plain = sorted((index, col, row) for index, end in enumerate(ends.tolist()) for col, row in plain_traversal(*end))
    assert found == plain


POSITIONS = st.one_of(st.floats(-2.95, 2.95), st.integers(-29, 29).map(lambda k: k / 10))
"""Lidar positions on and off the grid lines (SMALL's cells are 0.1 m)."""


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(
            POSITIONS,
            POSITIONS.map(lambda y: y * 2.4 / 2.95),
            st.one_of(st.floats(-math.pi, math.pi), st.integers(-4, 4).map(lambda k: k * math.pi / 4)),
            st.lists(st.one_of(st.none(), st.floats(0.0, 4.0), st.sampled_from([0.05, 0.1, 1.0, 3.5])), max_size=40),
            st.integers(1, 3),
        ),
        min_size=1,
        max_size=6,
    ),
    st.booleans(),
    st.integers(-1, 5),
)
def test_scans_leave_the_layers_and_costs_of_a_plain_trace(scans, with_map, clear_after):
    """The costmap's shortcuts (the vectorised traversal, a repeated scan skipped, the inflation in
    windows around clusters of changes) against a plain trace of every scan and one inflation of the
    whole grid: the same obstacles, known cells, counts and costs after every scan."""
    static = None
    if with_map:
        static = np.zeros(SMALL.shape, dtype=np.int8)
        static[10:12, 5:40] = OCCUPIED
        static[30:45, 50:52] = OCCUPIED
        static[40:, :10] = UNKNOWN
    settings_ = NavigationConfig(inflation_radius=0.6, obstacle_range=2.5, raytrace_range=3.0)
    costs = Costmap(SMALL, settings_, 0.2, static)
    plain = PlainCostmap(SMALL, settings_, static)
    for index, (x, y, yaw, ranges, times) in enumerate(scans):
        scan = rays(ranges, angle_min=-math.pi, increment=2 * math.pi / max(len(ranges), 1))
        for _ in range(times):  # the same scan from the same pose again: a robot at rest
            costs.mark_scan(scan, x, y, yaw)
            plain.mark_scan(scan, x, y, yaw)
        if index == clear_after:
            costs.clear_obstacles()
            plain.obstacles[:] = False
        assert np.array_equal(costs.obstacles, plain.obstacles)
        assert np.array_equal(costs.known(), plain.known | plain.seen)
        assert np.array_equal(costs.costs, full_costs(costs, static))
        status = costs.status()
        assert {name: status[name] for name in plain.counted} == plain.counted


def test_a_repeated_scan_is_counted_not_traced_and_after_a_clear_marks_again():
    costs = costmap()
    scan = rays([2.0, 1.0, None], increment=math.pi / 2)
    costs.mark_scan(scan, *LIDAR)
    costs.mark_scan(scan, *LIDAR)
    assert costs.status()["scans_repeated"] == 1
    assert costs.status()["scans"] == 2
    costs.clear_obstacles()
    costs.mark_scan(scan, *LIDAR)
    assert costs.status()["scans_repeated"] == 1, "after a clear the same scan marks anew"
    assert costs.status()["obstacle_cells"] == 2
    costs.mark_scan(scan, LIDAR[0] + 0.01, LIDAR[1], LIDAR[2])
    assert costs.status()["scans_repeated"] == 1, "from another pose: traced"


def test_a_scan_within_a_micron_of_the_last_traced_is_a_repeat_and_one_beyond_is_traced():
    """A robot at rest creeps by nanometres: its scans repeat to within ``SAME_SCAN_M``, measured from
    the last scan traced (a creep that adds up past it is traced again)."""
    costs = costmap()
    costs.mark_scan(rays([2.0, 1.0, None], increment=math.pi / 2), *LIDAR)
    near = SAME_SCAN_M / 2
    costs.mark_scan(
        rays([2.0 + near, 1.0 - near, None], increment=math.pi / 2), LIDAR[0] + near, LIDAR[1], LIDAR[2] - near
    )
    assert costs.status()["scans_repeated"] == 1
    costs.mark_scan(rays([2.0, 1.0, None], increment=math.pi / 2), LIDAR[0] + 3 * near, LIDAR[1], LIDAR[2])
    assert costs.status()["scans_repeated"] == 1, "1.5 microns from the last scan traced: traced"
    costs.mark_scan(rays([2.0, 1.0, 1.0], increment=math.pi / 2), LIDAR[0] + 3 * near, LIDAR[1], LIDAR[2])
    assert costs.status()["scans_repeated"] == 1, "a ray that now returns: traced"
    assert costs.status()["scans"] == 4


def test_changes_on_walls_far_apart_are_inflated_in_separate_windows():
    costs = costmap()
    _ = costs.costs  # the first inflation, of the whole grid
    before = costs.status()["inflations"]
    costs.mark_scan(rays([3.0, 3.0], angle_min=0.0, increment=math.pi), *LIDAR)  # east and west, 6 m apart
    _ = costs.costs
    assert costs.status()["inflations"] - before == 2
    assert costs.cost_at(3.01 - 0.3, 0.01) == INSCRIBED
    assert costs.cost_at(-2.99 + 0.3, 0.01) == INSCRIBED
