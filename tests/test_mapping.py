"""Maps from scans (services/mapping/): the log-odds grid's tracing and growth, the scan matcher
correcting a drifted prior, and the builder's map of a synthetic three-room run with odometry 1 %
off against the true walls (tests/mapping_world.py), plus its bookkeeping of odometry and scans."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from schemas.messages import LaserScan, Time
from services.mapping.builder import ANCHOR_SETTINGS, LidarMount, MapBuilder, scan_points
from services.mapping.matcher import MatcherSettings, SurfaceField, match
from services.mapping.occupancy import LogOddsGrid
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid
from services.planar import Pose, inverse
from tests.mapping_world import (
    THREE_ROOMS_TOUR,
    box,
    drive,
    run_of,
    scan_at,
    share_near_walls,
    three_rooms,
)

ROOM = np.array(box(0.0, 0.0, 4.0, 3.0) + box(0.8, -0.6, 0.4, 0.3), dtype=np.float64)
"""A 4 m x 3 m room with a box off its centre: no pose of the lidar sees the same as another."""


def cell_value(grid: LogOddsGrid, x: float, y: float) -> int:
    built = grid.grid()
    found = built.geometry.cell(x, y)
    assert found is not None, f"({x}, {y}) is off the grid"
    return int(built.cells[found[1], found[0]])


def test_a_ray_frees_its_cells_marks_its_hit_and_leaves_the_rest_unknown():
    grid = LogOddsGrid(0.1)
    assert grid.cover(-1.0, -1.0, 2.0, 2.0)
    grid.insert(0.05, 0.05, np.array([1.05]), np.array([0.05]), np.array([True]))
    assert [cell_value(grid, x + 0.05, 0.05) for x in np.arange(0.0, 1.0, 0.1)] == [FREE] * 10
    assert cell_value(grid, 1.05, 0.05) == OCCUPIED
    assert cell_value(grid, 1.15, 0.05) == UNKNOWN
    assert cell_value(grid, 0.05, 0.55) == UNKNOWN


def test_a_ray_without_return_clears_up_to_range_max_and_marks_nothing():
    grid = LogOddsGrid(0.1)
    assert grid.cover(-1.0, -1.0, 2.0, 2.0)
    grid.insert(0.05, 0.05, np.array([0.05]), np.array([1.05]), np.array([False]))
    assert cell_value(grid, 0.05, 1.05) == FREE
    assert cell_value(grid, 0.05, 1.15) == UNKNOWN
    assert not (grid.grid().cells == OCCUPIED).any()


@settings(max_examples=40, deadline=None)
@example(origin=(0.0, 0.0), rays=[(0.0, 2.75, True), (0.0, 2.734375, True)])  # a hit on a cell's edge
@given(
    origin=st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)),
    rays=st.lists(st.tuples(st.floats(-math.pi, math.pi), st.floats(0.2, 3.0), st.booleans()), min_size=1, max_size=40),
)
def test_after_one_scan_the_log_odds_hold_its_hit_cells_and_only_those_and_the_map_no_other(origin, rays):
    grid = LogOddsGrid(0.05)
    angles, lengths, hit = (np.array(column) for column in zip(*rays, strict=True))
    end_x, end_y = origin[0] + lengths * np.cos(angles), origin[1] + lengths * np.sin(angles)
    assert grid.cover(
        min(end_x.min(), origin[0]),
        min(end_y.min(), origin[1]),
        max(end_x.max(), origin[0]),
        max(end_y.max(), origin[1]),
    )
    grid.insert(origin[0], origin[1], end_x, end_y, hit.astype(bool))
    built = grid.grid()
    cols, rows, on = built.geometry.cells_of(end_x[hit.astype(bool)], end_y[hit.astype(bool)])
    assert on.all()
    expected = np.zeros(built.cells.shape, dtype=bool)
    expected[rows, cols] = True
    assert np.array_equal(grid.occupied(), expected), "the log odds: every hit's cell, and only those"
    # the map: a hit's cell may be drawn free (in front of its surface), no other cell occupied
    assert not ((built.cells == OCCUPIED) & ~expected).any()
    lidar = built.geometry.cell(*origin)
    assert lidar is not None and built.cells[lidar[1], lidar[0]] != UNKNOWN


@settings(max_examples=40, deadline=None)
@given(boxes=st.lists(st.tuples(st.integers(-200, 200), st.integers(-200, 200)), min_size=1, max_size=6))
def test_growing_keeps_every_cell_where_it_was(boxes):
    grid = LogOddsGrid(0.1)
    marks: list[tuple[float, float]] = []
    for col, row in boxes:
        x, y = col * 0.1 + 0.05, row * 0.1 + 0.05  # cell centres: a point on a cell's edge could go either way
        assert grid.cover(x - 0.5, y - 0.5, x + 0.5, y + 0.5)
        grid.insert(x, y, np.array([x + 0.3]), np.array([y]), np.array([True]))
        marks.append((x + 0.3, y))
        for mark_x, mark_y in marks:
            assert cell_value(grid, mark_x, mark_y) == OCCUPIED


def test_a_grid_refuses_to_grow_past_its_bound_and_stays_as_it_was():
    grid = LogOddsGrid(0.1, max_cells_per_side=100)
    assert grid.cover(0.0, 0.0, 1.0, 1.0)
    shape = grid.log_odds.shape
    assert max(shape) <= 100
    assert not grid.cover(0.0, 0.0, 10.5, 1.0)
    assert grid.log_odds.shape == shape
    assert grid.cover(0.0, 0.0, 9.5, 1.0)
    assert max(grid.log_odds.shape) <= 100


def room_map(poses: list[Pose], seed: int) -> LogOddsGrid:
    """ROOM mapped from known poses."""
    rng = np.random.default_rng(seed)
    grid = LogOddsGrid(0.05)
    for pose in poses:
        traced(grid, pose, scan_at(ROOM, pose, 0, rng))
    return grid


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    offset=st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-math.radians(3), math.radians(3))),
)
def test_the_matcher_corrects_a_drifted_prior(seed, offset):
    """With a prior as loose as the drift (the anchor's: a scan's own motion trusts the wheels more)."""
    grid = room_map([Pose(-0.5, 0.3, 0.0), Pose(0.5, -0.2, 1.0), Pose(-1.0, -0.8, 2.5)], seed)
    truth = Pose(0.1, 0.2, 0.4)
    ends, hit = scan_points(scan_at(ROOM, truth, 0, np.random.default_rng(seed + 1)), LidarMount())
    prior = Pose(truth.x + offset[0], truth.y + offset[1], truth.theta + offset[2])
    settings_ = ANCHOR_SETTINGS
    field = SurfaceField.around(grid, prior.x, prior.y, 3.6, settings_.max_distance)
    assert field is not None
    found = match(ends[hit], (0.0, 0.0), prior, field, settings_)
    assert found.trusted(settings_)
    assert math.hypot(found.pose.x - truth.x, found.pose.y - truth.y) < 0.02
    assert abs(found.pose.theta - truth.theta) < math.radians(0.5)


def test_a_scan_off_the_map_is_not_trusted():
    grid = room_map([Pose(0.0, 0.0, 0.0)], 1)
    settings_ = MatcherSettings()
    field = SurfaceField.around(grid, 0.0, 0.0, 3.6, settings_.max_distance)
    assert field is not None
    elsewhere = np.array(box(0.0, 0.0, 1.0, 7.0), dtype=np.float64)
    ends, hit = scan_points(scan_at(elsewhere, Pose(0.0, 0.0, 0.0), 0, np.random.default_rng(2)), LidarMount())
    assert not match(ends[hit], (0.0, 0.0), Pose(0.0, 0.0, 0.0), field, settings_).trusted(settings_)


def traced(grid: LogOddsGrid, pose: Pose, scan: LaserScan) -> None:
    """``scan`` traced into ``grid`` from ``pose``, uncorrected."""
    ends, hit = scan_points(scan, LidarMount())
    cos, sin = math.cos(pose.theta), math.sin(pose.theta)
    end_x = pose.x + cos * ends[:, 0] - sin * ends[:, 1]
    end_y = pose.y + sin * ends[:, 0] + cos * ends[:, 1]
    low_x, low_y = min(end_x.min(), pose.x), min(end_y.min(), pose.y)
    assert grid.cover(low_x, low_y, max(end_x.max(), pose.x), max(end_y.max(), pose.y))
    grid.insert(pose.x, pose.y, end_x, end_y, hit)


@settings(max_examples=1, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_a_run_through_rooms_with_odometry_1_percent_off_maps_within_10_cm(seed):
    walls = three_rooms()
    steps = list(drive([(0.0, 0.0), (1.0, 1.0), (3.0, 1.0), (3.5, 0.0), (1.0, 0.5)]))
    builder = MapBuilder()
    odometry_only = LogOddsGrid(0.05)
    for step, scan in run_of(walls, steps, seed, rays=180):
        builder.add_odometry(step.stamp_ns, step.odometry)
        if scan is not None:
            builder.add_scan(scan)
            traced(odometry_only, step.odometry, scan)
    assert max(math.hypot(s.odometry.x - s.truth.x, s.odometry.y - s.truth.y) for s in steps) > 0.2
    assert share_near_walls(odometry_only.grid(), walls) < 0.8  # the drift matters
    assert share_near_walls(builder.grid(), walls) >= 0.9
    truth = {step.stamp_ns: step.truth for step in steps}
    errors = [
        math.hypot(p.corrected.x - truth[p.stamp_ns].x, p.corrected.y - truth[p.stamp_ns].y) for p in builder.poses
    ]
    assert max(errors) < 0.1


def scan(stamp_ns: int, ranges: list[float | None]) -> LaserScan:
    return LaserScan(
        tm=Time.from_nanoseconds(stamp_ns),
        angle_min=0.0,
        angle_increment=2 * math.pi / len(ranges),
        range_min=0.1,
        range_max=3.5,
        ranges=ranges,
    )


def test_a_scan_takes_the_odometry_pose_interpolated_at_its_stamp_and_waits_for_it():
    builder = MapBuilder()
    builder.add_scan(scan(0, [1.0] * 8))
    assert builder.counters.before_odometry == 1
    builder.add_odometry(1_000_000_000, Pose(0.0, 0.0, 0.0))
    builder.add_scan(scan(2_000_000_000, [1.0] * 8))
    assert builder.poses == []  # waits for the odometry to reach its stamp
    builder.add_odometry(3_000_000_000, Pose(1.0, 0.5, 0.2))
    assert len(builder.poses) == 1
    odometry = builder.poses[0].odometry
    assert odometry.x == 0.5 and odometry.y == 0.25 and math.isclose(odometry.theta, 0.1)
    builder.add_scan(scan(3_100_000_000, [1.0] * 8))
    builder.add_scan(scan(3_900_000_000, [1.0] * 8))
    builder.finish()
    assert len(builder.poses) == 2 and builder.poses[1].odometry == Pose(1.0, 0.5, 0.2)
    assert builder.counters.after_odometry == 1


def test_an_odometry_step_no_robot_drives_is_a_reset_taken_out_of_the_motion():
    builder = MapBuilder()
    for step in range(5):
        builder.add_odometry(step * 20_000_000, Pose(0.006 * step, 0.0, 0.0))
    # a localization fix moved the odometry 0.3 m and 0.2 rad in 20 ms: the wheels did not
    builder.add_odometry(100_000_000, Pose(0.33, 0.1, 0.2))
    builder.add_odometry(120_000_000, Pose(0.33 + 0.006 * math.cos(0.2), 0.1 + 0.006 * math.sin(0.2), 0.2))
    builder.add_scan(scan(120_000_000, [1.0] * 8))
    assert builder.counters.odometry_resets == 1
    odometry = builder.poses[0].odometry
    assert math.isclose(odometry.x, 0.024 + 0.006, abs_tol=1e-9) and math.isclose(odometry.y, 0.0, abs_tol=1e-9)
    assert math.isclose(odometry.theta, 0.0, abs_tol=1e-12)


def test_rays_below_range_min_are_left_out_and_a_scan_of_none_is_counted_empty():
    builder = MapBuilder()
    builder.add_odometry(0, Pose(0.0, 0.0, 0.0))
    builder.add_scan(scan(0, [0.05] * 8))
    assert builder.counters.empty == 1
    assert builder.counters.scans == 0


def test_a_scan_past_the_grids_bound_is_counted_and_skipped():
    builder = MapBuilder(resolution=0.1, max_cells_per_side=80)
    builder.add_odometry(0, Pose(0.0, 0.0, 0.0))
    builder.add_scan(scan(0, [None] * 16))
    builder.add_odometry(100_000_000_000, Pose(20.0, 0.0, 0.0))  # 100 s at 0.2 m/s
    builder.add_scan(scan(100_000_000_000, [None] * 16))
    assert builder.counters.scans == 1 and builder.counters.outside == 1
    assert max(builder.grid().cells.shape) <= 80


def occupied_xy(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """The x and y of the centres of ``grid``'s occupied cells."""
    rows, cols = np.nonzero(grid.cells == OCCUPIED)
    geometry = grid.geometry
    return geometry.origin_x + (cols + 0.5) * geometry.resolution, geometry.origin_y + (
        rows + 0.5
    ) * geometry.resolution


@settings(max_examples=1, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_passing_the_doors_of_thin_walls_loses_no_length_along_the_rooms(seed):
    # three_rooms: thin (0.1 m) inner walls at x = 2 and 6 with doors, the outer walls' inner faces at
    # x = -1.95 and 9.95, so the cells holding them are centred on -1.975 and 9.975: 11.95 apart. A
    # match pulled by the far face of a thin wall or by a jamb's end lost 1 to 3 cm at each door
    # (11.90 to 11.91 apart); the room seen through a door still costs about 1 cm.
    walls = three_rooms()
    steps = list(drive(THREE_ROOMS_TOUR))
    builder = MapBuilder()
    for step, scan in run_of(walls, steps, seed, rays=360):
        builder.add_odometry(step.stamp_ns, step.odometry)
        if scan is not None:
            builder.add_scan(scan)
    x, y = occupied_xy(builder.grid())
    inside = np.abs(y) < 1.8
    east, west = x[inside & (x > 9.5)], x[inside & (x < -1.5)]
    assert abs(float(west.mean()) + 1.975) < 0.02
    assert abs(float(east.mean() - west.mean()) - 11.95) < 0.035
    assert share_near_walls(builder.grid(), walls) >= 0.99


def _wall_seen_from_the_left(wall_x: float, seed: int, scans: int = 20) -> LogOddsGrid:
    """A wall along y at ``wall_x``, seen by a lidar σ = 1 cm at x = 0.2 over ``scans`` scans."""
    rng = np.random.default_rng(seed)
    grid = LogOddsGrid(0.05)
    assert grid.cover(0.0, -1.0, 1.5, 1.0)
    for _ in range(scans):
        ys = rng.uniform(-0.6, 0.6, 40)
        bearing = np.arctan2(ys, wall_x - 0.2)
        ranges = (wall_x - 0.2) / np.cos(bearing) + rng.normal(0.0, 0.01, ys.size)
        grid.insert(0.2, 0.0, 0.2 + ranges * np.cos(bearing), ranges * np.sin(bearing), np.ones(ys.size, dtype=bool))
    return grid


@settings(max_examples=30, deadline=None)
@given(depth=st.floats(0.0, 0.0499), seed=st.integers(0, 2**32 - 1))
def test_a_wall_anywhere_in_a_cell_is_drawn_within_a_cell_of_it_and_never_lost(depth, seed):
    """Whichever cell the front of the wall falls in, the wall is drawn at most a cell nearer than it is
    and at most the noise (3σ) deeper: the rule frees a cell in front only for one behind it."""
    wall_x = 1.0 + depth  # 1.0 is a cell boundary
    built = _wall_seen_from_the_left(wall_x, seed).grid()
    geometry = built.geometry
    for y in np.arange(-0.3, 0.3, 0.05):
        row = geometry.cell(0.2, y)
        assert row is not None
        columns = np.flatnonzero(built.cells[row[1]] == OCCUPIED)
        assert len(columns), f"the wall is lost at y = {y:.2f}"
        near_edge = geometry.origin_x + columns[0] * geometry.resolution
        assert -geometry.resolution <= near_edge - wall_x <= 0.03, f"y = {y:.2f}"


def test_a_wall_on_a_cell_boundary_is_drawn_behind_it_not_a_cell_nearer():
    grid = _wall_seen_from_the_left(1.0, seed=3)
    assert grid.occupied()[grid.geometry.cell(0.975, 0.0)[::-1]], "the cell in front took enough hits"
    assert grid.in_front_of_its_surface()[grid.geometry.cell(0.975, 0.0)[::-1]]
    assert cell_value(grid, 0.975, 0.0) == FREE and cell_value(grid, 1.025, 0.0) == OCCUPIED


def test_anchoring_puts_a_map_moved_off_its_start_back_where_the_run_started():
    """The map a run's first scans, matched against few scans, moved by a centimetre: anchored, its
    poses lie nearer their truth; moved again by a known turn and shift, the anchor finds the move
    back from the first scans."""
    walls = three_rooms()
    steps = list(drive([(0.0, 0.0), (1.0, 1.0), (3.0, 1.0)], left_scale=1.0))
    builder = MapBuilder()
    scans = []
    for step, scan in run_of(walls, steps, seed=5, rays=180):
        builder.add_odometry(step.stamp_ns, step.odometry)
        if scan is not None:
            builder.add_scan(scan)
            scans.append(scan)
    builder.finish()
    truth = {step.stamp_ns: step.truth for step in steps}

    def errors() -> np.ndarray:
        return np.array(
            [
                math.hypot(p.corrected.x - truth[p.stamp_ns].x, p.corrected.y - truth[p.stamp_ns].y)
                for p in builder.poses
            ]
        )

    unanchored = float(np.sqrt(np.mean(errors() ** 2)))
    assert builder.anchor(scans) is not None
    anchored = float(np.sqrt(np.mean(errors() ** 2)))
    assert anchored < unanchored / 2, (anchored, unanchored)
    off = Pose(0.03, -0.02, math.radians(0.5))
    builder.retrace(off, scans)
    assert errors().max() > 0.03
    move = builder.anchor(scans)
    assert move is not None
    back = inverse(off)
    assert math.hypot(move.x - back.x, move.y - back.y) < 0.003 and abs(move.theta - back.theta) < math.radians(0.1)
    assert float(np.sqrt(np.mean(errors() ** 2))) < anchored + 0.002
    assert share_near_walls(builder.grid(), walls) >= 0.9
