"""Map files and rasterised worlds: map_server's format read and written
(services/navigation/map_file.py) on hand-made images and hypothesis's grids, every bad file refused
naming its field; a world's obstacles made into cells (services/navigation/rasterize.py) against the
shapes' own geometry; and ``invent map`` through the real entry point."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from schemas.messages import Obstacle
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE, NavigationConfig
from services.errors import ConfigError
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry
from services.navigation.map_file import read_map, write_map
from services.navigation.rasterize import MIN_MAP_SIZE, rasterize
from sim_bridge.world import load_world, obstacles
from tests.harness import refused, run_invent

GOOD_YAML = {
    "image": "map.pgm",
    "resolution": 0.05,
    "origin": [-1.0, 2.0, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}


def yaml_text(fields: dict[str, object]) -> str:
    return "".join(f"{key}: {value}\n" for key, value in fields.items())


def write_files(folder: Path, image: bytes, fields: dict[str, object] | None = None, name: str = "map.yaml") -> Path:
    """A map's YAML (GOOD_YAML changed by ``fields``; a None value drops the key) and its image."""
    merged = {**GOOD_YAML, **(fields or {})}
    (folder / "map.pgm").write_bytes(image)
    path = folder / name
    path.write_text(yaml_text({key: value for key, value in merged.items() if value is not None}))
    return path


def p5(rows: list[list[int]], maxval: int = 255, header: str | None = None) -> bytes:
    """A binary PGM of these rows (the first on top)."""
    height, width = len(rows), len(rows[0])
    head = header if header is not None else f"P5\n{width} {height}\n{maxval}\n"
    return head.encode("ascii") + bytes(value for row in rows for value in row)


def p2(rows: list[list[int]], maxval: int = 255) -> bytes:
    height, width = len(rows), len(rows[0])
    body = "\n".join(" ".join(str(value) for value in row) for row in rows)
    return f"P2\n# a plain PGM\n{width} {height}\n{maxval}\n{body}\n".encode("ascii")


# --- round trip ----------------------------------------------------------------------------------

cells_strategy = st.tuples(st.integers(1, 40), st.integers(1, 40)).flatmap(
    lambda shape: hnp.arrays(np.int8, shape, elements=st.sampled_from([UNKNOWN, FREE, OCCUPIED]))
)
coordinate = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(
    cells=cells_strategy,
    resolution=st.floats(1e-4, 10.0, allow_nan=False),
    origin_x=coordinate,
    origin_y=coordinate,
)
def test_a_grid_of_unknown_free_and_occupied_cells_written_then_read_is_the_same_grid(
    cells: np.ndarray, resolution: float, origin_x: float, origin_y: float
) -> None:
    height, width = cells.shape
    grid = Grid(GridGeometry(resolution, width, height, origin_x, origin_y), cells)
    with tempfile.TemporaryDirectory() as folder:
        image = write_map(grid, Path(folder) / "round.yaml")
        assert image == Path(folder) / "round.pgm"
        back = read_map(Path(folder) / "round.yaml")
    assert back.geometry == grid.geometry
    np.testing.assert_array_equal(back.cells, grid.cells)


def test_the_written_files_are_map_savers_yaml_and_p5_image_with_the_top_row_first(tmp_path: Path) -> None:
    # row 0 (lowest y): occupied, free, unknown; row 1 (top): all free but the last, occupied
    cells = np.array([[OCCUPIED, FREE, UNKNOWN], [FREE, FREE, OCCUPIED]], dtype=np.int8)
    grid = Grid(GridGeometry(0.1, 3, 2, -1.5, 1e-05), cells)
    image = write_map(grid, tmp_path / "floor.yaml")
    written = (tmp_path / "floor.yaml").read_text()
    # PyYAML reads YAML 1.1, as ROS's Python tools do: the numbers are numbers there too
    assert yaml.safe_load(written) == {
        "image": "floor.pgm",
        "mode": "trinary",
        "resolution": 0.1,
        "origin": [-1.5, 1e-05, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    data = image.read_bytes()
    assert data.startswith(b"P5\n")
    assert data.endswith(b"\n3 2\n255\n" + bytes([254, 254, 0, 0, 254, 205]))


def test_cells_between_free_and_occupied_are_written_as_map_saver_thresholds_them(tmp_path: Path) -> None:
    cells = np.array([[0, 25, 26, 64, 65, 100, -1]], dtype=np.int8)
    write_map(Grid(GridGeometry(0.05, 7, 1, 0.0, 0.0), cells), tmp_path / "m.yaml")
    assert (tmp_path / "m.pgm").read_bytes()[-7:] == bytes([254, 254, 205, 205, 0, 0, 205])
    np.testing.assert_array_equal(read_map(tmp_path / "m.yaml").cells, [[0, 0, -1, -1, 100, 100, -1]])


def test_an_image_name_yaml_would_misread_is_written_quoted_and_read_back(tmp_path: Path) -> None:
    cells = np.array([[OCCUPIED, FREE]], dtype=np.int8)
    grid = Grid(GridGeometry(0.05, 2, 1, 0.0, 0.0), cells)
    image = write_map(grid, tmp_path / "floor: #1 [west].yaml")
    assert image.name == "floor: #1 [west].pgm"
    assert yaml.safe_load((tmp_path / "floor: #1 [west].yaml").read_text())["image"] == image.name
    np.testing.assert_array_equal(read_map(tmp_path / "floor: #1 [west].yaml").cells, cells)


def test_a_yaml_named_pgm_is_refused_rather_than_overwritten_by_its_image(tmp_path: Path) -> None:
    grid = Grid(GridGeometry(0.05, 1, 1, 0.0, 0.0), np.zeros((1, 1), dtype=np.int8))
    with pytest.raises(ConfigError, match=r"map\.pgm"):
        write_map(grid, tmp_path / "map.pgm")


def test_an_unwritable_path_is_refused_naming_it(tmp_path: Path) -> None:
    grid = Grid(GridGeometry(0.05, 1, 1, 0.0, 0.0), np.zeros((1, 1), dtype=np.int8))
    with pytest.raises(ConfigError, match="nowhere"):
        write_map(grid, tmp_path / "nowhere" / "map.yaml")


# --- map_server's semantics ------------------------------------------------------------------------


def test_trinary_thresholds_are_strict_and_dark_is_occupied(tmp_path: Path) -> None:
    # occupied_thresh 0.6: p = (255 - v)/255 > 0.6 for v < 102; v = 102 is p = 0.6 exactly: unknown.
    # free_thresh 0.2: p < 0.2 for v > 204; v = 204 is p = 0.2 exactly: unknown.
    pixels = [[0, 101, 102, 150, 204, 205, 255]]
    path = write_files(tmp_path, p5(pixels), {"occupied_thresh": 0.6, "free_thresh": 0.2})
    np.testing.assert_array_equal(read_map(path).cells, [[100, 100, -1, -1, -1, 0, 0]])


def test_map_savers_unknown_grey_reads_as_unknown_and_its_white_as_free(tmp_path: Path) -> None:
    path = write_files(tmp_path, p5([[0, 205, 254]]))
    np.testing.assert_array_equal(read_map(path).cells, [[100, -1, 0]])


def test_negate_makes_white_occupied(tmp_path: Path) -> None:
    # negate 1: p = v/255; 0.65 < p for v >= 166, p < 0.196 for v <= 49
    pixels = [[0, 49, 50, 165, 166, 255]]
    path = write_files(tmp_path, p5(pixels), {"negate": 1})
    np.testing.assert_array_equal(read_map(path).cells, [[0, 0, -1, -1, 100, 100]])


def test_a_plain_p2_image_reads_as_its_binary_twin(tmp_path: Path) -> None:
    rows = [[0, 100, 205, 254], [255, 30, 180, 90]]
    binary = write_files(tmp_path, p5(rows), name="binary.yaml")
    binary_cells = read_map(binary).cells
    plain = write_files(tmp_path, p2(rows), name="plain.yaml")
    np.testing.assert_array_equal(read_map(plain).cells, binary_cells)
    # the bottom row first: 255 free, 30 occupied (p 0.88), 180 and 90 (p 0.29, 0.647) unknown
    np.testing.assert_array_equal(binary_cells, [[0, 100, -1, -1], [100, -1, -1, 0]])


def test_a_maxval_below_255_scales_the_thresholds(tmp_path: Path) -> None:
    # maxval 10: p = (10 - v)/10; > 0.65 for v <= 3, < 0.196 for v >= 9
    path = write_files(tmp_path, p2([[0, 3, 4, 8, 9, 10]], maxval=10))
    np.testing.assert_array_equal(read_map(path).cells, [[100, 100, -1, -1, 0, 0]])


def test_the_images_first_row_is_the_top_of_the_map_and_the_origin_its_lower_left_corner(tmp_path: Path) -> None:
    top, bottom = [0, 254, 254], [254, 254, 0]
    path = write_files(tmp_path, p5([top, [254, 254, 254], bottom]), {"origin": [-1.0, 2.0, 0.0], "resolution": 0.5})
    grid = read_map(path)
    assert grid.geometry == GridGeometry(0.5, 3, 3, -1.0, 2.0)
    assert grid.cells[2, 0] == OCCUPIED  # the image's top-left pixel: the largest y, the smallest x
    assert grid.cells[0, 2] == OCCUPIED  # its bottom-right one: row 0, the lowest y
    assert grid.geometry.cell(-0.75, 3.25) == (0, 2)  # that cell's centre: the map's top-left corner's cell
    assert grid.geometry.cell(0.25, 2.25) == (2, 0)  # and the bottom-right one's
    assert np.count_nonzero(grid.cells == OCCUPIED) == 2


def test_header_comments_an_absolute_image_path_and_a_yaml_in_another_folder(tmp_path: Path) -> None:
    image = tmp_path / "pictures" / "floor.pgm"
    image.parent.mkdir()
    image.write_bytes(p5([[0, 254]], header="P5 # made by hand\n# width and height\n2 # two\n1\n255\n"))
    (tmp_path / "maps").mkdir()
    absolute = tmp_path / "maps" / "absolute.yaml"
    absolute.write_text(yaml_text({**GOOD_YAML, "image": str(image)}))
    relative = tmp_path / "maps" / "relative.yaml"
    relative.write_text(yaml_text({**GOOD_YAML, "image": "../pictures/floor.pgm", "mode": "trinary"}))
    for path in (absolute, relative):
        np.testing.assert_array_equal(read_map(path).cells, [[100, 0]])


# --- bad files -------------------------------------------------------------------------------------

IMAGE = p5([[0, 254, 205], [254, 0, 254]])

BAD_FIELDS = [
    ({"resolution": 0}, "resolution"),
    ({"resolution": -0.05}, "resolution"),
    ({"resolution": ".nan"}, "resolution"),
    ({"resolution": ".inf"}, "resolution"),
    ({"resolution": "fine"}, "resolution"),
    ({"resolution": "true"}, "resolution"),
    ({"resolution": 10.5}, "resolution"),
    ({"resolution": 10**400}, "resolution"),
    ({"origin": "[0, 0]"}, "origin"),
    ({"origin": "[0, 0, 0, 0]"}, "origin"),
    ({"origin": "[0, .nan, 0]"}, "origin"),
    ({"origin": "[0, x, 0]"}, "origin"),
    ({"origin": "0"}, "origin"),
    ({"negate": 2}, "negate"),
    ({"negate": 0.5}, "negate"),
    ({"negate": "true"}, "negate"),
    ({"occupied_thresh": 1.5}, "occupied_thresh"),
    ({"occupied_thresh": "high"}, "occupied_thresh"),
    ({"free_thresh": -0.1}, "free_thresh"),
    ({"free_thresh": ".nan"}, "free_thresh"),
    ({"free_thresh": 0.65}, "free_thresh"),
    ({"free_thresh": 0.7}, "free_thresh"),
    ({"mode": "scale"}, "mode"),
    ({"mode": "raw"}, "mode"),
    ({"mode": "fancy"}, "mode"),
    ({"image": '""'}, "image"),
    ({"image": 3}, "image"),
    ({"image": "elsewhere.pgm"}, "image"),
    ({"colour": "red"}, "colour"),
    *(({key: None}, key) for key in GOOD_YAML),
]


@pytest.mark.parametrize(("fields", "field"), BAD_FIELDS, ids=[f"{fields}" for fields, _ in BAD_FIELDS])
def test_a_bad_field_is_refused_naming_the_file_and_the_field(
    tmp_path: Path, fields: dict[str, object], field: str
) -> None:
    path = write_files(tmp_path, IMAGE, fields)
    with pytest.raises(ConfigError) as refusal:
        read_map(path)
    assert str(path) in str(refusal.value)
    assert f"`{field}`" in str(refusal.value)


def test_a_missing_key_is_called_missing_and_an_unknown_one_unknown(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"`negate`: missing"):
        read_map(write_files(tmp_path, IMAGE, {"negate": None}))
    with pytest.raises(ConfigError, match=r"`colour`: unknown key"):
        read_map(write_files(tmp_path, IMAGE, {"colour": "red"}))


def test_a_rotated_map_is_refused_saying_rotations_are_unsupported(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"`origin`: yaw 0\.1 is not 0: rotated maps are not supported"):
        read_map(write_files(tmp_path, IMAGE, {"origin": [0.0, 0.0, 0.1]}))


def test_scale_and_raw_modes_are_refused_naming_mode(tmp_path: Path) -> None:
    for mode in ("scale", "raw"):
        with pytest.raises(ConfigError, match=rf"`mode`: '{mode}' is not supported: only trinary"):
            read_map(write_files(tmp_path, IMAGE, {"mode": mode}))


@pytest.mark.parametrize(
    "text",
    ["image: [map.pgm\nresolution: 0.05\n", "- just\n- a list\n", "plain words\n", "", "a: 1\na: 2\n"],
    ids=["unclosed", "list", "scalar", "empty", "duplicate"],
)
def test_a_yaml_that_does_not_parse_or_is_no_mapping_is_refused_naming_the_file(tmp_path: Path, text: str) -> None:
    path = tmp_path / "map.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=rf"map file {path}"):
        read_map(path)


def test_a_missing_yaml_or_an_image_given_as_the_map_is_refused_naming_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=rf"map file {tmp_path / 'absent.yaml'}: No such file"):
        read_map(tmp_path / "absent.yaml")
    (tmp_path / "map.pgm").write_bytes(p5([[0, 255, 128, 200]]))
    with pytest.raises(ConfigError, match=rf"map file {tmp_path / 'map.pgm'}"):
        read_map(tmp_path / "map.pgm")


BAD_IMAGES = [
    (b"\x89PNG\r\n\x1a\n" + bytes(40), "not a PGM image .*PNG.*PGM only"),
    (b"P6\n1 1\n255\n\x00\x00\x00", "not a PGM image"),
    (b"", "not a PGM image"),
    (b"P5\n3\n255\n" + bytes(6), "bad PGM header"),
    (b"P5\n3 x 255\n" + bytes(6), "bad PGM header"),
    (b"P53 2 255\n" + bytes(6), "bad PGM header"),
    (b"P5\n0 2\n255\n", "bad PGM header"),
    (b"P5\n3 2\n0\n" + bytes(6), "bad PGM header: maxval 0"),
    (b"P5\n3 2\n65535\n" + bytes(12), "bad PGM header: maxval 65535"),
    (b"P5\n3 2\n255", "bad PGM header"),
    (b"P5\n3 2\n255\n" + bytes(5), "5 bytes of pixels for 3 x 2"),
    (b"P5\n3 2\n255\n" + bytes(7), "7 bytes of pixels for 3 x 2"),
    (b"P2\n3 2\n255\n0 0 0 0 0\n", "5 pixels for 3 x 2"),
    (b"P2\n3 2\n255\n0 0 0 0 0 0 0\n", "7 pixels for 3 x 2"),
    (b"P2\n3 2\n100\n0 0 0 0 0 101\n", "above the image's maxval 100"),
    (b"P2\n3 2\n255\n0 0 0 0 0 -1\n", "negative"),
    (b"P2\n3 2\n255\n0 0 0 0 0 x\n", "not a whole number"),
    (
        f"P5\n{MAX_COSTMAP_CELLS_PER_SIDE + 1} 1\n255\n".encode() + bytes(MAX_COSTMAP_CELLS_PER_SIDE + 1),
        f"{MAX_COSTMAP_CELLS_PER_SIDE + 1} x 1 pixels: more than {MAX_COSTMAP_CELLS_PER_SIDE} a side",
    ),
    (b"P5\n1 99999999\n255\n", "more than 2048 a side"),
]


@pytest.mark.parametrize(("image", "problem"), BAD_IMAGES, ids=[problem for _, problem in BAD_IMAGES])
def test_a_bad_image_is_refused_naming_the_image_field_and_its_file(tmp_path: Path, image: bytes, problem: str) -> None:
    path = write_files(tmp_path, image)
    with pytest.raises(ConfigError, match=problem) as refusal:
        read_map(path)
    assert f"{path}: `image` {tmp_path / 'map.pgm'}" in str(refusal.value)


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
