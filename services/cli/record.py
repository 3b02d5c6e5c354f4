"""``invent record``: record keys into an MCAP file, or with ``--ros2`` the ROS 2 graph into a rosbag2 bag."""

from __future__ import annotations

import argparse
import datetime
from pathlib import Path

from schemas.keys import Keys
from services.cli.export import fleet_bridge_configs, say_bag
from services.cli.flags import (
    config_from_args,
    fleet_flag,
    new_bag_directory,
    positive_seconds,
    session_from_args,
)
from services.config import Config, ConfigError
from services.recording import record, ros2_record
from services.ros2.graph import bridge_graph
from services.runtime.realtime import apply_realtime
from services.runtime.session import open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "keyexprs", metavar="KEYEXPR", nargs="*", help="zenoh key expressions (default invent/<robot>/**)"
    )
    parser.add_argument(
        "--output",
        "-o",
        metavar="PATH",
        help="file to write (default invent.mcap); with --ros2, the bag's new directory (default "
        "rosbag2_<date>-<time>, as `ros2 bag record` names one)",
    )
    parser.add_argument("--duration", type=positive_seconds, metavar="S", help="stop after S seconds of wall time")
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="record the ROS 2 graph instead: every topic the robot's ROS 2 bridge publishes (of each robot with "
        "--fleet), as rmw_zenoh carries it, into a rosbag2 bag with MCAP storage (metadata.yaml, CDR, ros2msg "
        "schemas, ROS's type names and hashes), each message at the simulation time it carries, /clock included; "
        "the bounds of [record] apply (split_size, split_duration, max_size, max_duration, min_free_disk). "
        "`ros2 bag info DIR`, `ros2 bag play DIR --clock` (docs/ros2.md, Bags)",
    )
    fleet_flag(
        parser,
        "with --ros2: the bridges of every robot of this fleet file, in their namespaces",
    )


def run(args: argparse.Namespace) -> int:
    config = config_from_args(None, args)
    if args.fleet and not args.ros2:
        raise ConfigError("--fleet: it is an option of --ros2 (the bridges of a fleet)")
    if args.ros2 and args.keyexprs:
        raise ConfigError(f"--ros2 with {' '.join(args.keyexprs)}: a bag records the bridges' topics, not zenoh keys")
    apply_realtime(config.rt, "invent record", control_path=False)
    if args.ros2:
        return _run_ros2(args, config)
    stop = stop_on_signals()
    with open_session(session_from_args(args)) as session:
        return record.run_record(
            session,
            Keys(config.robot.name),
            args.keyexprs,
            Path(args.output or "invent.mcap"),
            config,
            stop,
            duration_s=args.duration,
        )


def _run_ros2(args: argparse.Namespace, config: Config) -> int:
    configs = fleet_bridge_configs(args) if args.fleet else [config]
    bridges = [bridge_graph(robot) for robot in configs]
    output = new_bag_directory(args.output or datetime.datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S"))
    stop = stop_on_signals()
    with open_session(session_from_args(args)) as session:
        result = ros2_record.run_record_ros2(
            session,
            bridges,
            output,
            config.record,
            config.ros2.distro,
            config.input.stamp_horizon_ns,
            stop,
            duration_s=args.duration,
        )
    say_bag(result)
    return 0


HELP = "record keys into an MCAP file (open it in Foxglove, read it with the mcap CLI)"
DESCRIPTION = (
    "Record every sample of KEYEXPR (default invent/<robot>/**) into an MCAP file: one channel "
    "per key, JSON messages with their JSON schema, log_time the receive time, publish_time the message's "
    "tm; beside them the robot's Foxglove scene (transforms, poses, robot, obstacles, path, trails, wheel "
    "speeds, a goal-mode drive's goals) and the services' status every 0.5 s. Ctrl-C, SIGTERM or --duration end it with a valid, "
    "indexed file; a recorder killed with SIGKILL loses at most its last chunk (about 0.2 s of the loop)."
)
GROUPS: tuple[str, ...] = ("connection", "description")
