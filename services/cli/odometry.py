"""``invent odometry``: its flag, and the odometry's options it makes."""

from __future__ import annotations

import argparse

from services.cli.serve import ServiceCli
from services.odometry.service import COMMAND, OdometryOptions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trace",
        metavar="FILE",
        help="write one JSON line per wheel-angle sample (inputs, branch taken, pose) to FILE",
    )


def options(args: argparse.Namespace) -> OdometryOptions:
    return OdometryOptions(trace=args.trace)


CLI = ServiceCli(
    command=COMMAND,
    help="dead-reckoned pose from wheel angles, reset by localized poses",
    description="The OdometryRTC port: integrates motor/wheel_angles into odometry/pose (one pose per "
    "observed step, stamped with the sample's tm); every localization/pose overwrites the pose the next step "
    "starts from. Parameters: [robot] geometry and [odometry] in the robot description.",
    add_arguments=add_arguments,
    options=options,
)
