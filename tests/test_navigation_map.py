"""Map files: map_server's format read and written (services/navigation/map_file.py) on hand-made
images and hypothesis's grids, every bad file refused naming its field (tests/test_rasterize.py: the
worlds rasterised, and ``invent map``)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE
from services.errors import ConfigError
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry
from services.navigation.map_file import read_map, write_map

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
