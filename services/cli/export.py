"""``invent export --ros2``: a recording of a run (run.mcap) made into a ROS 2 bag."""

from __future__ import annotations

import argparse
import sys

from services.cli.flags import config_from_args, existing_file, fleet_flag, new_bag_directory, overrides_from_args
from services.config import Config, ConfigError
from services.fleet.description import load_fleet
from services.launch import ros2_run
from services.recording import rosbag
from services.recording.mcap_files import read_run
from services.ros2.graph import bridge_graph


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="RUN.mcap", help="the recording, e.g. runs/<timestamp>/run.mcap")
    parser.add_argument(
        "--ros2", action="store_true", required=True, help="the format: a rosbag2 bag (MCAP storage), ROS 2 CDR"
    )
    parser.add_argument("--output", "-o", metavar="DIR", required=True, help="the bag's new directory")
    fleet_flag(
        parser,
        "the fleet file of the run: each robot in its namespace, /clock from the first (needed for a "
        "recording of several robots)",
    )


def run(args: argparse.Namespace) -> int:
    path = existing_file(args.recording)
    output = new_bag_directory(args.output)
    if args.fleet:
        configs = fleet_bridge_configs(args)
    else:
        recorded = rosbag.robots_in(read_run(path).messages)
        if len(recorded) > 1:
            raise ConfigError(
                f"{path} holds the robots {', '.join(recorded)}: give the run's --fleet FILE (their namespaces "
                "and descriptions)"
            )
        if args.robot is None and recorded:
            args.robot = recorded[0]
        configs = [config_from_args(None, args)]
    result, refused = rosbag.export_run(
        path,
        output,
        [rosbag.ExportedRobot(config, bridge_graph(config)) for config in configs],
        configs[0].record,
    )
    for key, count in sorted(refused.items()):
        print(f"{count} recorded samples of {key} were bad input, not exported", file=sys.stderr)
    say_bag(result)
    return 0


def fleet_bridge_configs(args: argparse.Namespace) -> list[Config]:
    """``--fleet FILE``: each robot's bridge's description, in the fleet's order."""
    return list(ros2_run.fleet_bridges(load_fleet(args.fleet), args.config, overrides_from_args(None, args)).values())


def say_bag(result: rosbag.BagResult) -> None:
    counts = ", ".join(f"{topic} {count}" for topic, count in sorted(result.counts.items()))
    print(f"{result.path}: {result.messages} messages in {len(result.files)} file(s): {counts}")
    if result.stopped is not None:
        print(f"the bag stopped early: {result.stopped['reason']}")


HELP = "turn a recording of a run (run.mcap) into a ROS 2 bag"
DESCRIPTION = (
    "Replay a recording of `invent up` (its run.mcap, and the files it was split into) through the "
    "ROS 2 bridge's own mapping (services/ros2/outputs.py) and write what the bridge would have published, "
    "/clock, odom, tf, tf_static, joint_states and robot_description of each robot (and scan and imu, from "
    "the recording's sim/scan and sim/imu), into a rosbag2 bag with MCAP storage, each message at the simulation time it carries. The messages come at the recording's "
    "observed steps: a run with --ros2 has the bridge's rates. --robot, --config and --set (or --fleet) must "
    "match the run's; the [record] bounds apply to the bag."
)
GROUPS: tuple[str, ...] = ("description",)
