"""``invent ros2``: its flags, the bridge's options they make, and ``--fleet``: a bridge per robot
of a fleet in one process (services/launch/ros2_run.py)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from services.cli.flags import fleet_flag, overrides_from_args, session_from_args
from services.cli.serve import ServiceCli, journaling_from_args, serve
from services.config import TfLayout
from services.errors import refuse_given
from services.fleet.description import load_fleet
from services.ros2 import graph
from services.ros2.service import COMMAND, Ros2Options
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals
from services.service import ServicePlan


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--namespace",
        metavar="NS",
        help="ROS namespace of the node, its topics and services (ros2.namespace; default none), e.g. rh0",
    )
    parser.add_argument(
        "--tf",
        choices=list(TfLayout),
        help="where a namespaced bridge publishes TF (ros2.tf; default namespaced): namespaced, on <NS>/tf and "
        "<NS>/tf_static with frames as named (Nav2's multi-robot bringup); prefixed, on the shared /tf and "
        "/tf_static with frames <NS>/odom, <NS>/base_link, ... under the world's map (one RViz for every robot)",
    )
    fleet_flag(
        parser,
        "bridge every robot of this fleet file, each its own ROS node in its namespace (the file's namespace, "
        "default its name): /<NS>/odom, /<NS>/tf, /<NS>/cmd_vel, /<NS>/motor/stop, ...; /clock once, from the first "
        "robot's bridge (docs/ros2.md, A fleet)",
    )
    # invent up --record-ros2's: where the bridge keeps what it publishes for the run's bag, and how
    # many bridges of the run share record.max_size
    parser.add_argument("--bag-journal", metavar="DIR", help=argparse.SUPPRESS)
    parser.add_argument("--bag-journal-share", type=int, default=1, help=argparse.SUPPRESS)


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {"ros2.namespace": args.namespace, "ros2.tf": args.tf}


def options(args: argparse.Namespace) -> Ros2Options:
    return Ros2Options(Path(args.bag_journal) if args.bag_journal else None, args.bag_journal_share)


def run(args: argparse.Namespace) -> int:
    return serve_fleet(args) if args.fleet else serve(args)


def serve_fleet(args: argparse.Namespace) -> int:
    """``invent ros2 --fleet FILE``: a bridge per robot, each in its namespace, in this process."""
    # Imported here: ros2_run writes bags (rosbags, mcap), and composition imports this module
    # for the flags of every service, also where the [ros2] extra is not installed.
    from services.launch import ros2_run

    given = {"--robot": args.robot, "--namespace": args.namespace}
    refuse_given(given, "--fleet with {}: each robot's name and namespace are the fleet file's".format)
    configs = ros2_run.fleet_bridges(load_fleet(args.fleet), args.config, overrides_from_args(CLI, args))
    journaling = journaling_from_args(args)
    plans = {name: ServicePlan(COMMAND, config, options(args), journaling) for name, config in configs.items()}
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args, timestamping=COMMAND.timestamped)) as session:
        return ros2_run.serve_bridges(session, plans, stop)


CLI = ServiceCli(
    command=COMMAND,
    help="bridge the robot (or a fleet) to ROS 2 over rmw_zenoh: odom, tf, joint_states, scan, imu, /clock, cmd_vel, "
    "Trigger services, the NavigateToPose action",
    description=f"The robot as one ROS 2 node on this zenoh network, in rmw_zenoh's wire format (no ROS install "
    f"needed on this side): /clock, odom, tf, tf_static, joint_states, robot_description, scan, imu out; cmd_vel "
    f"(Twist or TwistStamped) in, as drive/target_velocity stamped with simulation time; motor/stop, "
    f"motor/clear, motor/start, motor/finish as std_srvs/srv/Trigger services; the action navigate_to_pose "
    f"(nav2_msgs/NavigateToPose) and goal_pose (RViz's 2D Goal Pose), each goal sent to the drive in goal mode "
    f"(invent drive --goals). With --fleet FILE, one such node "
    f"per robot of the fleet, each in its own namespace. Domain: ${graph.DOMAIN_VARIABLE} (default 0). Frames, "
    f"rates and covariances: [ros2] in the robot description. See docs/ros2.md.",
    add_arguments=add_arguments,
    options=options,
    overrides=overrides,
    run=run,
)
