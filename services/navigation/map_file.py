"""Map files in ROS map_server's format (pure; docs/navigation.md): a YAML file naming a greyscale
image beside it, read into a :class:`~services.navigation.grid.Grid` and written from one.

The YAML holds exactly these keys (another is refused, as is a missing one but ``mode``):

* ``image``: the image's path, relative to the YAML's folder (or absolute);
* ``resolution``: metres per pixel (finite, > 0, at most :data:`MAX_RESOLUTION`);
* ``origin``: ``[x, y, yaw]``, the map-frame pose of the image's lower-left pixel's lower-left
  corner; ``yaw`` must be 0: rotated maps are not supported;
* ``negate``: 0 or 1;
* ``occupied_thresh``, ``free_thresh``: in [0, 1], ``free_thresh`` < ``occupied_thresh``;
* ``mode`` (optional): ``trinary``, the default and the only mode read. map_server's ``scale`` and
  ``raw`` are refused naming ``mode`` (ROS 1's map_server and Nav2's disagree on both, and the
  costmap takes a map's cells as occupied, free or unknown).

A pixel of value v (of the image's maxval, 255 for 8 bits) is occupied with probability
p = (maxval − v)/maxval (``negate: 0``: dark is occupied) or v/maxval (``negate: 1``); as map_server
in trinary mode, p > ``occupied_thresh`` is occupied (100), p < ``free_thresh`` free (0), anything
between unknown (-1). The image's first row is the top of the map (its largest y): it becomes the
grid's last row (the grid's row 0 is the lowest y).

Images: PGM only, binary (``P5``, maxval at most 255) or plain (``P2``); map_server also reads PNG,
BMP and the rest of SDL_image's (or GraphicsMagick's) formats: convert them to PGM first. An image
is at most :data:`~services.config.navigation.MAX_COSTMAP_CELLS_PER_SIDE` pixels a side.

Writing gives what map_saver gives: a ``P5`` image named after the YAML's stem, beside it, an
occupied cell (65 to 100) black (0), a free one (0 to 25) 254, any other (unknown, or between) 205;
``negate: 0``, ``occupied_thresh: 0.65`` and ``free_thresh: 0.196``, ROS 1 map_saver's: with Nav2's
0.25 the unknown grey 205 (p = 0.196) would read back as free. Read back, a written grid of -1, 0
and 100 is the same grid.

Every bad file raises :class:`~services.errors.ConfigError` naming the file and the field (the
command line exits 2).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from ruamel.yaml import YAML
from ruamel.yaml.error import MarkedYAMLError, YAMLError

from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE
from services.errors import ConfigError
from services.navigation.grid import FREE, OCCUPIED, UNKNOWN, Grid, GridGeometry

MAX_RESOLUTION = 10.0
"""The coarsest resolution a map may have, m per cell: more is a mistake, not a map."""
OCCUPIED_THRESH = 0.65
"""What a written map's YAML says: map_saver's ``occupied_thresh``."""
FREE_THRESH = 0.196
"""What a written map's YAML says: ROS 1 map_saver's ``free_thresh`` (just below the unknown grey's p)."""
OCCUPIED_PIXEL = 0
FREE_PIXEL = 254
UNKNOWN_PIXEL = 205
WRITTEN_FREE_MAX = 25
"""A written cell of at most this (and at least 0) is free in the image; map_saver's ``threshold_free``."""
WRITTEN_OCCUPIED_MIN = 65
"""A written cell of at least this is occupied in the image; map_saver's ``threshold_occupied``."""
MAX_YAML_BYTES = 65536
"""A map's YAML is a few lines: a larger file is not one."""
MAX_PGM_MAXVAL = 255
KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
REQUIRED_KEYS = KEYS[:-1]
MODES = ("trinary", "scale", "raw")
_PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")
"""An image name written into the YAML as it is (anything else is written double-quoted)."""


@dataclass(frozen=True)
class MapMetadata:
    """A map's YAML, checked: what its image is read with."""

    image: Path
    resolution: float
    origin_x: float
    origin_y: float
    negate: bool
    occupied_thresh: float
    free_thresh: float


def read_map(path: str | Path) -> Grid:
    """The grid of the map file ``path`` (its YAML); ConfigError naming the file and the field."""
    yaml_path = Path(path)
    metadata = read_metadata(yaml_path)
    pixels, maxval = read_pgm(metadata.image, f"{yaml_path}: `image` {metadata.image}")
    cells = occupancy(pixels, maxval, metadata)
    height, width = cells.shape
    geometry = GridGeometry(metadata.resolution, width, height, metadata.origin_x, metadata.origin_y)
    return Grid(geometry, cells)


def read_metadata(yaml_path: Path) -> MapMetadata:
    """The YAML of a map file, checked key by key (the image is only named, not read)."""
    try:
        with yaml_path.open("rb") as file:
            raw = file.read(MAX_YAML_BYTES + 1)
    except OSError as error:
        raise ConfigError(f"map file {yaml_path}: {error.strerror or error}") from None
    if len(raw) > MAX_YAML_BYTES:
        raise ConfigError(f"map file {yaml_path}: more than {MAX_YAML_BYTES} bytes: not a map's YAML")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"map file {yaml_path}: not UTF-8 text (give the map's YAML, not its image)") from None
    try:
        document = YAML(typ="safe", pure=True).load(text)
    except YAMLError as error:
        raise ConfigError(f"map file {yaml_path}: not valid YAML: {_yaml_problem(error)}") from None
    if not isinstance(document, dict):
        raise ConfigError(f"map file {yaml_path}: not a YAML mapping of {', '.join(REQUIRED_KEYS)}")
    return _metadata(yaml_path, document)


def _yaml_problem(error: YAMLError) -> str:
    if isinstance(error, MarkedYAMLError) and error.problem:
        mark = error.problem_mark
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        return f"{error.problem}{where}"
    return " ".join(str(error).split())


def _metadata(yaml_path: Path, document: dict[Any, Any]) -> MapMetadata:
    def fail(key: str, problem: str) -> ConfigError:
        return ConfigError(f"map file {yaml_path}: `{key}`: {problem}")

    unknown = [str(key) for key in document if key not in KEYS]
    if unknown:
        raise fail(unknown[0], f"unknown key (a map's YAML holds {', '.join(KEYS)})")
    for key in REQUIRED_KEYS:
        if key not in document:
            raise fail(key, "missing")
    mode = document.get("mode", "trinary")
    if mode not in MODES:
        raise fail("mode", f"{mode!r} is none of map_server's modes ({', '.join(MODES)})")
    if mode != "trinary":
        raise fail("mode", f"{mode!r} is not supported: only trinary (occupied, free, unknown) maps are read")

    image = document["image"]
    if not isinstance(image, str) or not image.strip():
        raise fail("image", f"{image!r} is not the image's path")
    resolution = _number(document["resolution"])
    if resolution is None or not resolution > 0.0:
        raise fail("resolution", f"{document['resolution']!r} must be a finite number of metres > 0")
    if resolution > MAX_RESOLUTION:
        raise fail("resolution", f"{resolution} m a cell: more than {MAX_RESOLUTION} m")
    origin = document["origin"]
    values = [_number(value) for value in origin] if isinstance(origin, list) else []
    if len(values) != 3 or any(value is None for value in values):
        raise fail("origin", f"{origin!r} must be three finite numbers [x, y, yaw]")
    origin_x, origin_y, yaw = (float(value) for value in values if value is not None)
    if yaw != 0.0:
        raise fail("origin", f"yaw {yaw} is not 0: rotated maps are not supported")
    negate = document["negate"]
    if isinstance(negate, bool) or negate not in (0, 1):
        raise fail("negate", f"{negate!r} must be 0 or 1")
    thresholds = {}
    for key in ("occupied_thresh", "free_thresh"):
        value = _number(document[key])
        if value is None or not 0.0 <= value <= 1.0:
            raise fail(key, f"{document[key]!r} must be a number in [0, 1]")
        thresholds[key] = value
    if thresholds["free_thresh"] >= thresholds["occupied_thresh"]:
        raise fail(
            "free_thresh",
            f"{thresholds['free_thresh']} must be below `occupied_thresh` = {thresholds['occupied_thresh']}",
        )
    return MapMetadata(
        image=yaml_path.parent / image,
        resolution=resolution,
        origin_x=origin_x,
        origin_y=origin_y,
        negate=negate == 1,
        occupied_thresh=thresholds["occupied_thresh"],
        free_thresh=thresholds["free_thresh"],
    )


def _number(value: object) -> float | None:
    """A YAML number as a float; None for anything else (a bool, a string, inf, nan)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:  # a whole number beyond a float's range
        return None
    return number if math.isfinite(number) else None


def read_pgm(path: Path, name: str) -> tuple[npt.NDArray[np.int64], int]:
    """The pixels of a PGM image (``[row, col]``, its first row first) and its maxval; ConfigError
    starting with ``name`` (the file and field it comes from)."""
    limit = MAX_COSTMAP_CELLS_PER_SIDE**2 * 4 + 65536  # the largest P2 raster of 3-digit values, and a header
    try:
        with path.open("rb") as file:
            data = file.read(limit + 1)
    except OSError as error:
        raise ConfigError(f"{name}: {error.strerror or error}") from None
    magic = data[:2]
    if magic not in (b"P5", b"P2"):
        raise ConfigError(
            f"{name}: not a PGM image (P5 or P2): map_server also reads PNG, BMP and others, we read PGM only"
        )
    width, height, maxval, raster_at = _pgm_header(data, name)
    if width > MAX_COSTMAP_CELLS_PER_SIDE or height > MAX_COSTMAP_CELLS_PER_SIDE:
        raise ConfigError(f"{name}: {width} x {height} pixels: more than {MAX_COSTMAP_CELLS_PER_SIDE} a side")
    if len(data) > limit:
        raise ConfigError(f"{name}: more than {limit} bytes for {width} x {height} pixels")
    raster = data[raster_at:]
    count = width * height
    if magic == b"P5":
        if len(raster) != count:
            raise ConfigError(f"{name}: {len(raster)} bytes of pixels for {width} x {height} pixels ({count})")
        pixels = np.frombuffer(raster, dtype=np.uint8).astype(np.int64)
    else:
        try:
            pixels = np.array([int(token) for token in raster.split()], dtype=np.int64)
        except ValueError:
            raise ConfigError(f"{name}: a pixel of the P2 image is not a whole number") from None
        if pixels.size != count:
            raise ConfigError(f"{name}: {pixels.size} pixels for {width} x {height} ({count})")
    if pixels.size and int(pixels.min()) < 0:
        raise ConfigError(f"{name}: a pixel of {int(pixels.min())} is negative")
    if pixels.size and int(pixels.max()) > maxval:
        raise ConfigError(f"{name}: a pixel of {int(pixels.max())} is above the image's maxval {maxval}")
    return pixels.reshape(height, width), maxval


def _pgm_header(data: bytes, name: str) -> tuple[int, int, int, int]:
    """Width, height, maxval and where the raster starts: three whole numbers after the magic number,
    separated by whitespace and ``#`` comments, then one whitespace character (Netpbm's header)."""
    at = 2
    numbers: list[int] = []
    while len(numbers) < 3:
        start = at
        while at < len(data) and (data[at : at + 1].isspace() or data[at : at + 1] == b"#"):
            if data[at : at + 1] == b"#":
                while at < len(data) and data[at : at + 1] not in (b"\n", b"\r"):
                    at += 1
            else:
                at += 1
        if at == start:
            raise ConfigError(f"{name}: bad PGM header: no whitespace after {data[:at][-16:]!r}")
        digits = at
        while at < len(data) and data[at : at + 1].isdigit():
            at += 1
        if at == digits:
            raise ConfigError(f"{name}: bad PGM header: width, height and maxval must be whole numbers")
        numbers.append(int(data[digits:at]))
    width, height, maxval = numbers
    if width < 1 or height < 1:
        raise ConfigError(f"{name}: bad PGM header: {width} x {height} pixels")
    if not 1 <= maxval <= MAX_PGM_MAXVAL:
        raise ConfigError(f"{name}: bad PGM header: maxval {maxval} (8-bit images only: 1 to {MAX_PGM_MAXVAL})")
    if at >= len(data) or not data[at : at + 1].isspace():
        raise ConfigError(f"{name}: bad PGM header: no whitespace after the maxval")
    return width, height, maxval, at + 1


def occupancy(pixels: npt.NDArray[np.int64], maxval: int, metadata: MapMetadata) -> npt.NDArray[np.int8]:
    """map_server's trinary mode on an image's pixels (first row on top): the cells, row 0 the lowest y."""
    p = (pixels if metadata.negate else maxval - pixels) / maxval
    cells = np.full(pixels.shape, UNKNOWN, dtype=np.int8)
    cells[p > metadata.occupied_thresh] = OCCUPIED
    cells[p < metadata.free_thresh] = FREE
    return np.ascontiguousarray(np.flipud(cells))


def write_map(grid: Grid, yaml_path: Path) -> Path:
    """Writes ``grid`` as map_saver would: the PGM beside ``yaml_path`` (named after its stem), then
    the YAML; returns the image's path. ConfigError naming a path that cannot be written."""
    yaml_path = Path(yaml_path)
    image_path = yaml_path.with_name(f"{yaml_path.stem}.pgm")
    if image_path == yaml_path:
        raise ConfigError(f"{yaml_path}: the map's YAML cannot be named .pgm (its image is {image_path.name})")
    if not yaml_path.parent.is_dir():
        raise ConfigError(f"{yaml_path}: cannot be written: no folder {yaml_path.parent}")
    if yaml_path.is_dir():
        raise ConfigError(f"{yaml_path}: cannot be written: a folder (give the YAML's file name, e.g. map.yaml)")
    geometry = grid.geometry
    pixels = np.full(grid.cells.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    pixels[(grid.cells >= FREE) & (grid.cells <= WRITTEN_FREE_MAX)] = FREE_PIXEL
    pixels[grid.cells >= WRITTEN_OCCUPIED_MIN] = OCCUPIED_PIXEL
    header = f"P5\n# CREATOR: invent-zenoh {_yaml_float(geometry.resolution)} m/pix\n{geometry.width} {geometry.height}\n255\n"
    image_name = image_path.name
    text = (
        f"image: {image_name if _PLAIN_NAME.fullmatch(image_name) else _quoted(image_name)}\n"
        "mode: trinary\n"
        f"resolution: {_yaml_float(geometry.resolution)}\n"
        f"origin: [{_yaml_float(geometry.origin_x)}, {_yaml_float(geometry.origin_y)}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
    )
    _write(image_path, header.encode("ascii") + np.flipud(pixels).tobytes())
    _write(yaml_path, text.encode("utf-8"))
    return image_path


def _write(path: Path, data: bytes) -> None:
    try:
        path.write_bytes(data)
    except OSError as error:
        raise ConfigError(f"{path}: cannot be written: {error.strerror or error}") from None


def _yaml_float(value: float) -> str:
    """A float as YAML 1.1 and 1.2 both read it back exactly (a dot before any exponent: ``1.0e-05``)."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        return f"{mantissa}.0e{exponent}"
    return text


def _quoted(name: str) -> str:
    """A YAML double-quoted scalar (a JSON string is one)."""
    return json.dumps(name, ensure_ascii=False)
