"""``invent map``: a map file (map_server's YAML and PGM) for the navigation's static layer
(``invent up --map``), made of a world's obstacles (``--world``) or of a run's recorded scans
(``--from run.mcap``, services/mapping/)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from services.cli.flags import existing_file, finite_number, non_negative_float
from services.config import Config, ConfigError, load_config
from services.config.navigation import MAX_COSTMAP_CELLS_PER_SIDE, NavigationConfig
from services.mapping.from_recording import Recorded, build_map
from services.navigation.grid import OCCUPIED, Grid
from services.navigation.map_file import MAX_RESOLUTION, write_map
from services.navigation.rasterize import MIN_MAP_SIZE, rasterize
from services.recording.mcap_files import read_run
from sim_bridge.world import builtin_worlds, load_world, obstacles


def map_resolution(text: str) -> float:
    """``--resolution``'s type: a finite length > 0 and at most what a map file may hold."""
    value = finite_number(text)
    if not 0.0 < value <= MAX_RESOLUTION:
        raise argparse.ArgumentTypeError(f"{text!r} must be a length in metres > 0 and at most {MAX_RESOLUTION}")
    return value


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""How an MCAP file begins."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--world",
        metavar="FILE|NAME",
        help=f"the world: a world file, or a built-in world's name ({', '.join(builtin_worlds())})",
    )
    source.add_argument(
        "--from",
        dest="recording",
        metavar="FILE.mcap",
        help="a run's recording (run.mcap of invent up or invent record): the map of its robot's lidar scans "
        "(sim/scan), each placed by its odometry pose (odometry/pose) corrected by scan matching",
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
        help="with --world: free space around the world's obstacles and initial pose, m (default: %(default)s)",
    )
    parser.add_argument(
        "--robot",
        metavar="NAME",
        help="with --from: the robot whose scans make the map (default: the recording's only robot)",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="with --from: the robot description the run was made with: its wheels and axle (the recorded "
        "wheel angles are integrated with them) and where the lidar sits on the base (lidar.x, lidar.y, "
        "lidar.yaw); default: the description's defaults",
    )


def run(args: argparse.Namespace) -> int:
    output = Path(args.output)
    if not output.parent.is_dir():
        raise ConfigError(f"--output {output}: no folder {output.parent}")
    grid = _from_recording(args) if args.recording is not None else _from_world(args)
    image = write_map(grid, output)
    geometry = grid.geometry
    occupied = int(np.count_nonzero(grid.cells == OCCUPIED))
    print(
        f"wrote {output} and {image}: {geometry.width} x {geometry.height} cells of {geometry.resolution:g} m, "
        f"{geometry.width * geometry.resolution:g} x {geometry.height * geometry.resolution:g} m from "
        f"({geometry.origin_x:g}, {geometry.origin_y:g}); {occupied} occupied"
    )
    return 0


def _from_world(args: argparse.Namespace) -> Grid:
    for flag, value in (("--robot", args.robot), ("--config", args.config)):
        if value is not None:
            raise ConfigError(f"{flag} goes with --from (a recording), not --world")
    try:
        world = load_world(args.world)
    except ConfigError as error:
        raise ConfigError(f"--world {args.world}: {error}") from None
    start = world.initial_pose
    try:
        grid = rasterize(obstacles(world), args.resolution, include=[(start.x, start.y)], margin=args.margin)
    except ValueError as error:
        raise ConfigError(f"--resolution {args.resolution}, --margin {args.margin}: {error}") from None
    return grid


def _from_recording(args: argparse.Namespace) -> Grid:
    path = existing_file(args.recording)
    config = load_config(args.config) if args.config is not None else Config()
    messages = _recorded_messages(path)
    try:
        run = build_map(messages, args.robot, args.resolution, config, progress=_tell)
    except ConfigError as error:
        raise ConfigError(f"--from {path}: {error}") from None
    counters = run.builder.counters
    dropped = counters.before_odometry + counters.after_odometry + counters.outside + counters.empty
    resets = f", {counters.odometry_resets} resets taken out" if counters.odometry_resets else ""
    anchor = (
        "not moved: no first scan matched"
        if run.anchor is None
        else f"moved {math.hypot(run.anchor.x, run.anchor.y) * 100:.1f} cm and turned "
        f"{math.degrees(run.anchor.theta):.2f} deg to lie where the run started"
    )
    print(
        f"robot {run.robot}: {counters.scans} of {run.scans} scans mapped ({counters.matched} corrected by "
        f"scan matching, {dropped} dropped: {counters.before_odometry} before the motion, "
        f"{counters.after_odometry} after it, {counters.outside} past the map's bound, {counters.empty} empty), "
        f"posed by {run.motion_samples} samples of {run.motion}{resets}; the map {anchor}"
    )
    return run.builder.grid()


def _recorded_messages(path: Path) -> list[Recorded]:
    with open(path, "rb") as file:
        if file.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ConfigError(f"--from {path}: not an MCAP file (a run's recording is run.mcap)")
    return list(read_run(path).messages)


def _tell(progress: str) -> None:
    print(f"invent map: {progress}", file=sys.stderr, flush=True)


HELP = "make a map file (map_server's YAML and PGM) of a world's obstacles or a run's scans, for invent up --map"
DESCRIPTION = (
    "With --world, rasterise a world's obstacles (its boxes, turned by their yaw, and its cylinders) into an occupancy "
    "grid and write it in ROS map_server's format: the YAML (-o, e.g. map.yaml: image, resolution, "
    "origin [x, y, 0], negate 0, occupied_thresh 0.65, free_thresh 0.196, mode trinary) and, beside it, "
    "its 8-bit PGM image named after it (map.pgm; black occupied, 254 free, the image's top row the "
    "largest y), as map_saver writes them. A cell is occupied where it overlaps an obstacle, free "
    "elsewhere. The map spans the obstacles and the world's initial pose with --margin around them, "
    f"at least {MIN_MAP_SIZE:g} m a side, and at most {MAX_COSTMAP_CELLS_PER_SIDE} cells a side "
    "(a coarser --resolution for a larger world). `invent up --map map.yaml` (navigation.map) "
    "takes it as the costmap's static layer and extent; ROS's map_server (and RViz, Foxglove) read it too. "
    "With --from run.mcap, build it from a run's recording instead: each of the robot's lidar scans "
    "(sim/scan) is placed by the odometry pose at its stamp (odometry/pose, interpolated), corrected for the "
    "odometry's drift by matching the scan against the map built so far, then traced into a log-odds "
    "occupancy grid: the cells along each ray free, the cell of its return occupied, a ray with no return "
    "clearing up to range_max, a cell no ray reached unknown. The map grows with the run up to "
    f"{MAX_COSTMAP_CELLS_PER_SIDE} cells a side (scans past that are counted and left out). A file that is "
    "not a run's recording, or holds no scans or no odometry poses, is refused (exit 2). Progress goes to stderr."
)
GROUPS: tuple[str, ...] = ()
