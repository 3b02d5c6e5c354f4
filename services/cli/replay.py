"""``invent replay``: a recording's samples published again, e.g. into a changed odometry."""

from __future__ import annotations

import argparse
import sys

from schemas.keys import Keys
from services.cli.flags import existing_file, non_negative_float, robot_name, session_from_args
from services.recording import replay
from services.recording.mcap_files import read_run, replay_schedule
from services.runtime.session import open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="FILE.mcap", help="the recording")
    parser.add_argument(
        "--keys",
        metavar="SUFFIX",
        nargs="+",
        default=[],
        help="keys relative to the robot, e.g. motor/wheel_angles localization/pose (default: every data key "
        "recorded but up/run)",
    )
    parser.add_argument(
        "--rate", type=non_negative_float, default=1.0, metavar="X", help="time scale (default 1; 0: consumers' pace)"
    )
    parser.add_argument(
        "--robot",
        type=robot_name,
        metavar="NAME",
        help="publish under invent/NAME/ (default: the robot the recording is of)",
    )


def run(args: argparse.Namespace) -> int:
    path = existing_file(args.recording)
    read = read_run(path)  # and the files it was split into, if any
    if not read.complete:
        print(f"{path} was cut short: replaying its whole chunks", file=sys.stderr)
    recorded_robot, schedule = replay_schedule(read.messages, replay.parse_topics(args.keys))
    keys = Keys(args.robot or recorded_robot)
    stop = stop_on_signals()
    with open_session(session_from_args(args)) as session:
        return replay.run_replay(session, schedule, keys, args.rate, stop)


HELP = "publish a recording's samples again, e.g. into a changed odometry"
DESCRIPTION = (
    "Publish the samples of a recording (`invent record`, or the run.mcap of `invent up`) again, "
    "in simulation-time order, so a changed odometry, localization or drive runs on recorded inputs. "
    "--rate X paces them at X times the recorded simulation time; --rate 0 sends them as fast as the "
    "services that take every sample of those keys take them (read from their status), losing none. "
    "Exits 0 once those services have taken every sample, 1 if one stops taking them."
)
GROUPS: tuple[str, ...] = ("connection",)
