"""Worlds rasterised into maps (services/navigation/rasterize.py): a world's obstacles made into cells
against the shapes' own geometry, the map's extent and bounds, and ``invent map`` through the real
entry point (tests/test_navigation_map.py: the map files).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.messages import Obstacle
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE, NavigationConfig
from services.navigation.grid import FREE, OCCUPIED, Grid, GridGeometry
from services.navigation.map_file import read_map, write_map
from services.navigation.rasterize import MIN_MAP_SIZE, rasterize
from sim_bridge.world import load_world, obstacles
from tests.harness import refused, run_invent

# --- rasterising -----------------------------------------------------------------------------------


def box_distance(x: np.ndarray, y: np.ndarray, box: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """(distance from the rectangle, depth inside it) of points: the rectangle's own geometry."""
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    local_x = np.abs((x - box.x) * c + (y - box.y) * s)
    local_y = np.abs(-(x - box.x) * s + (y - box.y) * c)
    out_x, out_y = local_x - box.size[0] / 2, local_y - box.size[1] / 2
    outside = np.hypot(np.maximum(out_x, 0.0), np.maximum(out_y, 0.0))
    return outside, -np.maximum(out_x, out_y)


def cylinder_distance(x: np.ndarray, y: np.ndarray, cylinder: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    centre = np.hypot(x - cylinder.x, y - cylinder.y)
    radius = cylinder.size[0] / 2
    return np.maximum(centre - radius, 0.0), radius - centre


def distances(grid: Grid, obstacle: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """Each cell centre's distance from the obstacle and depth inside it, ``[row, col]``."""
    geometry = grid.geometry
    x = geometry.origin_x + (np.arange(geometry.width) + 0.5) * geometry.resolution
    y = geometry.origin_y + (np.arange(geometry.height) + 0.5) * geometry.resolution
    xs, ys = np.meshgrid(x, y)
    measure = box_distance if obstacle.shape == "box" else cylinder_distance
    return measure(xs, ys, obstacle)


def check_against_the_shape(grid: Grid, obstacle: Obstacle, area: float, perimeter: float) -> None:
    """A cell whose square lies inside the shape is occupied, one whose square lies outside is free, and
    the occupied area lies between the shape's and that of the shape grown by a cell's diagonal."""
    resolution = grid.geometry.resolution
    half_diagonal = resolution / math.sqrt(2.0)
    outside, depth = distances(grid, obstacle)
    occupied = grid.cells == OCCUPIED
    inside_cells = depth > half_diagonal + 1e-9
    outside_cells = outside > half_diagonal + 1e-9
    assert inside_cells.any()
    assert occupied[inside_cells].all()
    assert not occupied[outside_cells].any()
    assert set(np.unique(grid.cells)) <= {FREE, OCCUPIED}
    occupied_area = np.count_nonzero(occupied) * resolution**2
    diagonal = resolution * math.sqrt(2.0)
    assert area - 1e-9 <= occupied_area <= area + perimeter * diagonal + math.pi * diagonal**2


def test_a_turned_box_occupies_its_cells_and_no_others() -> None:
    box = Obstacle("box", "box", 0.3, -0.2, 0.5, (1.2, 0.4, 0.5))
    grid = rasterize([box], 0.05)
    check_against_the_shape(grid, box, 1.2 * 0.4, 2 * (1.2 + 0.4))
    # a point just inside the box's corner and one just outside its long side
    corner = (0.3 + 0.6 * math.cos(0.5) - 0.2 * math.sin(0.5), -0.2 + 0.6 * math.sin(0.5) + 0.2 * math.cos(0.5))
    inward = (corner[0] - 0.01 * math.cos(0.5), corner[1] - 0.01 * math.sin(0.5))
    col, row = grid.geometry.cell(*inward) or (-1, -1)
    assert grid.cells[row, col] == OCCUPIED
    beside = (0.3 - 0.35 * math.sin(0.5), -0.2 + 0.35 * math.cos(0.5))  # 0.15 m off the long side
    col, row = grid.geometry.cell(*beside) or (-1, -1)
    assert grid.cells[row, col] == FREE


def test_a_cylinder_occupies_its_cells_and_no_others() -> None:
    cylinder = Obstacle("post", "cylinder", -1.03, 0.52, 0.0, (0.6, 0.6, 1.0))
    grid = rasterize([cylinder], 0.05)
    check_against_the_shape(grid, cylinder, math.pi * 0.3**2, 2 * math.pi * 0.3)


@settings(max_examples=80, deadline=None)
@given(
    shape=st.sampled_from(["box", "cylinder"]),
    x=st.floats(-3.0, 3.0),
    y=st.floats(-3.0, 3.0),
    yaw=st.floats(-math.pi, math.pi),
    length=st.floats(0.05, 2.0),
    width=st.floats(0.05, 2.0),
    resolution=st.floats(0.02, 0.3),
)
def test_any_shape_occupies_what_lies_inside_it_and_nothing_outside(
    shape: str, x: float, y: float, yaw: float, length: float, width: float, resolution: float
) -> None:
    if shape == "box":
        obstacle = Obstacle("o", "box", x, y, yaw, (length, width, 1.0))
        area, perimeter = length * width, 2 * (length + width)
    else:
        obstacle = Obstacle("o", "cylinder", x, y, 0.0, (length, length, 1.0))
        area, perimeter = math.pi * (length / 2) ** 2, math.pi * length
    grid = rasterize([obstacle], resolution)
    outside, depth = distances(grid, obstacle)
    half_diagonal = resolution / math.sqrt(2.0)
    occupied = grid.cells == OCCUPIED
    assert occupied[depth > half_diagonal + 1e-9].all()
    assert not occupied[outside > half_diagonal + 1e-9].any()
    # the cell holding the shape's centre always overlaps it
    col, row = grid.geometry.cell(x, y) or (-1, -1)
    assert occupied[row, col]
    occupied_area = np.count_nonzero(occupied) * resolution**2
    diagonal = resolution * math.sqrt(2.0)
    assert area - 1e-9 <= occupied_area <= area + perimeter * diagonal + math.pi * diagonal**2


def test_a_box_on_cell_boundaries_takes_exactly_its_own_cells() -> None:
    box = Obstacle("b", "box", 0.5, 0.25, 0.0, (0.4, 0.3, 1.0))  # x in [0.3, 0.7], y in [0.1, 0.4]
    grid = rasterize([box], 0.1)
    assert np.count_nonzero(grid.cells == OCCUPIED) == 4 * 3
    rows, cols = np.nonzero(grid.cells == OCCUPIED)
    centres = [grid.geometry.centre(int(col), int(row)) for row, col in zip(rows, cols, strict=True)]
    assert min(cx for cx, _ in centres) == pytest.approx(0.35)
    assert max(cx for cx, _ in centres) == pytest.approx(0.65)
    assert min(cy for _, cy in centres) == pytest.approx(0.15)
    assert max(cy for _, cy in centres) == pytest.approx(0.35)


def test_a_cylinder_inscribed_in_a_cell_takes_that_cell_alone() -> None:
    # its circle touches the cell's four edges, and the four neighbours' at one point each
    grid = rasterize([Obstacle("c", "cylinder", 0.05, 0.05, 0.0, (0.1, 0.1, 1.0))], 0.1)
    rows, cols = np.nonzero(grid.cells == OCCUPIED)
    assert len(rows) == 1
    assert grid.geometry.centre(int(cols[0]), int(rows[0])) == pytest.approx((0.05, 0.05))


def test_the_bump_world_is_its_box_in_a_ten_metre_map_around_the_start() -> None:
    world = load_world("bump")
    grid = rasterize(obstacles(world), 0.05, include=[(world.initial_pose.x, world.initial_pose.y)])
    geometry = grid.geometry
    # the box: x in [0.9, 1.1], y in [-0.5, 0.5]: 4 x 20 cells exactly
    rows, cols = np.nonzero(grid.cells == OCCUPIED)
    assert len(rows) == 80
    assert geometry.centre(int(cols.min()), int(rows.min())) == pytest.approx((0.925, -0.475))
    assert geometry.centre(int(cols.max()), int(rows.max())) == pytest.approx((1.075, 0.475))
    assert geometry.width * 0.05 == pytest.approx(MIN_MAP_SIZE, abs=0.051)
    assert geometry.height * 0.05 == pytest.approx(MIN_MAP_SIZE, abs=0.051)
    assert geometry.contains(-1.0, 0.0) and geometry.contains(2.1, 1.5)
    assert round(geometry.origin_x / 0.05) * 0.05 == pytest.approx(geometry.origin_x)
    assert round(geometry.origin_y / 0.05) * 0.05 == pytest.approx(geometry.origin_y)


def test_the_map_spans_every_obstacle_and_included_point_with_the_margin() -> None:
    far = Obstacle("far", "cylinder", -20.0, 3.0, 0.0, (1.0, 1.0, 1.0))
    grid = rasterize([far], 0.1, include=[(15.0, -4.0)], margin=2.0)
    geometry = grid.geometry
    # x from -20.5 - 2 to 15 + 2, y from -4 - 2 to 3.5 + 2: both beyond the 10 m minimum, not grown
    assert geometry.origin_x <= -22.5 and geometry.max_x >= 17.0
    assert geometry.origin_y <= -6.0 and geometry.max_y >= 5.5
    assert geometry.width in (395, 396) and geometry.height in (115, 116)


def test_an_empty_world_is_a_ten_metre_square_around_the_origin_or_twice_the_margin() -> None:
    grid = rasterize([], 0.05)
    assert grid.geometry == GridGeometry(0.05, 200, 200, -5.0, -5.0)
    assert not grid.cells.any()
    wide = rasterize([], 0.5, margin=8.0)
    assert wide.geometry == GridGeometry(0.5, 32, 32, -8.0, -8.0)


@pytest.mark.parametrize(
    ("arguments", "problem"),
    [
        ({"resolution": 0.0}, "resolution"),
        ({"resolution": -0.1}, "resolution"),
        ({"resolution": math.nan}, "resolution"),
        ({"resolution": math.inf}, "resolution"),
        ({"resolution": 0.05, "margin": -1.0}, "margin"),
        ({"resolution": 0.05, "margin": math.nan}, "margin"),
        ({"resolution": 0.05, "include": [(math.inf, 0.0)]}, "included point"),
    ],
)
def test_bad_arguments_are_refused(arguments: dict[str, object], problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        rasterize([], **arguments)  # type: ignore[arg-type]


def test_a_map_beyond_the_cell_bound_is_refused() -> None:
    side = MAX_COSTMAP_CELLS_PER_SIDE * 0.05  # 102.4 m: with the margin, more cells than the bound
    wall = Obstacle("wall", "box", 0.0, 0.0, 0.0, (side, 0.1, 1.0))
    with pytest.raises(ValueError, match=f"more than {MAX_COSTMAP_CELLS_PER_SIDE} cells a side"):
        rasterize([wall], 0.05)
    assert rasterize([wall], 0.1).geometry.width <= MAX_COSTMAP_CELLS_PER_SIDE
    with pytest.raises(ValueError, match="cells a side"):
        rasterize([], 1e-300)


def test_a_rasterised_world_written_and_read_back_is_the_same_grid(tmp_path: Path) -> None:
    world = load_world("room")
    grid = rasterize(obstacles(world), 0.05, include=[(0.0, 0.0)])
    write_map(grid, tmp_path / "room.yaml")
    back = read_map(tmp_path / "room.yaml")
    assert back.geometry == grid.geometry
    np.testing.assert_array_equal(back.cells, grid.cells)


# --- invent map ------------------------------------------------------------------------------------


def test_invent_map_writes_a_map_that_reads_back_as_the_worlds_cells(tmp_path: Path) -> None:
    result = run_invent("map", "--world", "bump", "-o", str(tmp_path / "bump.yaml"))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 1
    assert str(tmp_path / "bump.yaml") in lines[0] and str(tmp_path / "bump.pgm") in lines[0]
    assert "200 x 200 cells of 0.05 m" in lines[0] and "10 x 10 m" in lines[0] and "80 occupied" in lines[0]
    grid = read_map(tmp_path / "bump.yaml")
    world = load_world("bump")
    expected = rasterize(obstacles(world), NavigationConfig().resolution, include=[(0.0, 0.0)])
    assert grid.geometry == expected.geometry
    np.testing.assert_array_equal(grid.cells, expected.cells)


def test_invent_map_takes_a_world_file_a_resolution_and_a_margin(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = tmp_path / "posts.toml"
    world.write_text(
        "[initial_pose]\nx = -8.0\ny = 1.0\n\n"
        '[[cylinders]]\nname = "post"\nx = 4.0\ny = 1.0\nradius = 0.5\nheight = 1.0\n'
    )
    # in this process (a second process would cost a second of imports): the same entry point
    code, out, err = refused(
        capsys, "map", "--world", str(world), "-o", str(tmp_path / "posts.yaml"), "--resolution", "0.1", "--margin", "2"
    )
    assert code == 0, err
    grid = read_map(tmp_path / "posts.yaml")
    assert grid.geometry.resolution == 0.1
    assert grid.geometry.contains(-10.0 + 0.01, 1.0) and grid.geometry.contains(6.5 - 0.01, 1.0)
    post = Obstacle("post", "cylinder", 4.0, 1.0, 0.0, (1.0, 1.0, 1.0))
    check_against_the_shape(grid, post, math.pi * 0.25, math.pi)
    assert "occupied" in out


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (("--resolution", "0"), "--resolution"),
        (("--resolution", "-0.05"), "--resolution"),
        (("--resolution", "nan"), "--resolution"),
        (("--resolution", "inf"), "--resolution"),
        (("--resolution", "11"), "--resolution"),
        (("--resolution", "0.001"), "--resolution"),
        (("--margin", "-1"), "--margin"),
        (("--world", "no_such_world"), "--world"),
    ],
)
def test_invent_map_refuses_bad_flags_with_exit_2_naming_the_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: tuple[str, ...], named: str
) -> None:
    arguments = {"--world": "bump", "-o": str(tmp_path / "m.yaml")}
    for flag, value in zip(flags[::2], flags[1::2], strict=True):
        arguments[flag] = value
    code, _out, err = refused(capsys, "map", *(part for pair in arguments.items() for part in pair))
    assert code == 2
    assert named in err
    assert not (tmp_path / "m.yaml").exists() and not (tmp_path / "m.pgm").exists()


def test_invent_map_refuses_an_unwritable_output_with_exit_2_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "folder").mkdir()
    for output in (tmp_path / "missing" / "m.yaml", tmp_path / "m.pgm", tmp_path / "folder"):
        code, _out, err = refused(capsys, "map", "--world", "bump", "-o", str(output))
        assert code == 2
        assert str(output) in err
    assert not (tmp_path / "folder.pgm").exists()


def test_invent_map_needs_a_world_and_an_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert refused(capsys, "map", "-o", str(tmp_path / "m.yaml"))[0] == 2
    assert refused(capsys, "map", "--world", "bump")[0] == 2


def test_invent_map_help_explains_the_format_and_invent_up_map(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _err = refused(capsys, "map", "--help")
    assert code == 0
    text = " ".join(out.split())
    assert "map_server" in text and "PGM" in text and "invent up --map" in text
    assert f"default: navigation.resolution, {NavigationConfig().resolution}" in text
