"""``invent motor``: its flags, and the motor's options and config keys they make."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from services.cli.serve import ServiceCli
from services.config import TargetAngleMode
from services.motor.service import COMMAND, MotorOptions
from services.motor.state import STATE_DIRECTORY, STATE_FILE, STATE_HOME_VARIABLE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--state",
        metavar="FILE",
        help="where the emergency-stop and finish latches and the gains set at run time are kept across "
        f"restarts (default ${STATE_HOME_VARIABLE}/{STATE_DIRECTORY}/<robot>/{STATE_FILE}, "
        f"${STATE_HOME_VARIABLE} defaulting to ~/.local/state)",
    )
    parser.add_argument(
        "--trace", metavar="FILE", help="write one JSON line per control cycle (inputs, targets, torques, state)"
    )
    parser.add_argument(
        "--target-angle",
        choices=list(TargetAngleMode),
        help="how the target wheel angle is formed (sets motor.target_angle; see docs/motor.md)",
    )
    parser.add_argument(
        "--command-timeout",
        type=float,
        metavar="S",
        help="seconds of wheel-angle time without a target velocity before braking; 0 disables "
        "(sets motor.command_timeout)",
    )


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {"motor.target_angle": args.target_angle, "motor.command_timeout": args.command_timeout}


def options(args: argparse.Namespace) -> MotorOptions:
    return MotorOptions(trace=args.trace, state=Path(args.state) if args.state else None)


CLI = ServiceCli(
    command=COMMAND,
    help="PD wheel-torque control from a target velocity (MotorControlRTC)",
    description="MotorControl: answers every sim/wheel_angles sample with one motor/torque (PD control "
    "towards drive/target_velocity) and passes the angles on to odometry; turns sim/body_pose into "
    "motor/sim_pose/*; serves the Motor interface on motor/gui/<method> and motor/bump/<method> "
    "(set_pd_gain, start, finish, clear, stop). Its collision monitor holds the robot, not latched, while "
    "sim/scan sees an obstacle in the stop zone along the commanded motion ([collision_monitor]). "
    "See docs/motor.md.",
    add_arguments=add_arguments,
    options=options,
    overrides=overrides,
)
