"""``invent map``: a world's obstacles made into a map file (map_server's YAML and PGM) for the
navigation's static layer (``invent up --map``)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from services.cli.flags import finite_number, non_negative_float
from services.config import ConfigError
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE, NavigationConfig
from services.navigation.grid import OCCUPIED
from services.navigation.map_file import MAX_RESOLUTION, write_map
from services.navigation.rasterize import MIN_MAP_SIZE, rasterize
from sim_bridge.world import builtin_worlds, load_world, obstacles


def map_resolution(text: str) -> float:
    """``--resolution``'s type: a finite length > 0 and at most what a map file may hold."""
    value = finite_number(text)
    if not 0.0 < value <= MAX_RESOLUTION:
        raise argparse.ArgumentTypeError(f"{text!r} must be a length in metres > 0 and at most {MAX_RESOLUTION}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--world",
        metavar="FILE|NAME",
        required=True,
        help=f"the world: a world file, or a built-in world's name ({', '.join(builtin_worlds())})",
    )
    parser.add_argument(
        "--output",
        "-o",
        metavar="FILE.yaml",
        required=True,
        help="the map's YAML; its PGM image is written beside it, named after it (map.yaml: map.pgm)",
    )
    parser.add_argument(
        "--resolution",
        type=map_resolution,
        default=NavigationConfig().resolution,
        metavar="M",
        help="the side of a cell, m (default: navigation.resolution, %(default)s)",
    )
    parser.add_argument(
        "--margin",
        type=non_negative_float,
        default=1.0,
        metavar="M",
        help="free space around the world's obstacles and initial pose, m (default: %(default)s)",
    )


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    try:
        world = load_world(args.world)
    except ConfigError as error:
        raise ConfigError(f"--world {args.world}: {error}") from None
    start = world.initial_pose
    try:
        grid = rasterize(obstacles(world), args.resolution, include=[(start.x, start.y)], margin=args.margin)
    except ValueError as error:
        raise ConfigError(f"--resolution {args.resolution}, --margin {args.margin}: {error}") from None
    image = write_map(grid, output)
    geometry = grid.geometry
    occupied = int(np.count_nonzero(grid.cells == OCCUPIED))
    print(
        f"wrote {output} and {image}: {geometry.width} x {geometry.height} cells of {geometry.resolution:g} m, "
        f"{geometry.width * geometry.resolution:g} x {geometry.height * geometry.resolution:g} m from "
        f"({geometry.origin_x:g}, {geometry.origin_y:g}); {occupied} occupied"
    )
    return 0


HELP = "make a map file (map_server's YAML and PGM) of a world's obstacles, for invent up --map"
DESCRIPTION = (
    "Rasterise a world's obstacles (its boxes, turned by their yaw, and its cylinders) into an occupancy "
    "grid and write it in ROS map_server's format: the YAML (-o, e.g. map.yaml: image, resolution, "
    "origin [x, y, 0], negate 0, occupied_thresh 0.65, free_thresh 0.196, mode trinary) and, beside it, "
    "its 8-bit PGM image named after it (map.pgm; black occupied, 254 free, the image's top row the "
    "largest y), as map_saver writes them. A cell is occupied where it overlaps an obstacle, free "
    "elsewhere. The map spans the obstacles and the world's initial pose with --margin around them, "
    f"at least {MIN_MAP_SIZE:g} m a side, and at most {MAX_COSTMAP_CELLS_PER_SIDE} cells a side "
    "(a coarser --resolution for a larger world). `invent up --map map.yaml` (navigation.map) "
    "takes it as the costmap's static layer and extent; ROS's map_server (and RViz, Foxglove) read it too."
)
GROUPS: tuple[str, ...] = ()
