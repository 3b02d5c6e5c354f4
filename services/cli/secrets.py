"""``invent secrets``: a secure deployment's credentials, router and per-role zenoh configurations."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import get_args

from schemas.keys import DEFAULT_ROBOT, Keys
from services.cli import tools
from services.cli.flags import robot_names
from services.config import TfLayout, load_config
from services.config.sections import LocalizationMode
from services.extension.loader import load_all
from services.ros2.graph import bridge_graph
from services.runtime.session import DEFAULT_ENDPOINT
from services.security import UserServiceGrant
from services.security.grants import DEFAULT_LOCALIZATION


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("directory", metavar="DIR", help="where to write the files (created 0700)")
    parser.add_argument(
        "--robot", default=DEFAULT_ROBOT, metavar="NAME", help=f"the robot the rules name (default {DEFAULT_ROBOT})"
    )
    parser.add_argument(
        "--robots",
        type=robot_names,
        default=(),
        metavar="R1,R2,...",
        help="a fleet's credentials, in place of --robot's: per robot, one user and ROBOT-ROLE.json5 for each of "
        "motor, odometry, localization, drive and ros2 (that robot's keys only; its bridge in the ROS namespace "
        "/ROBOT under --ros-namespace); one sim, operator, observer and ros_node for the whole fleet",
    )
    parser.add_argument(
        "--endpoint", default=DEFAULT_ENDPOINT, metavar="EP", help=f"where clients connect (default {DEFAULT_ENDPOINT})"
    )
    parser.add_argument(
        "--router-listen",
        action="append",
        default=[],
        metavar="EP",
        help="where the router listens (repeatable; default the endpoint; e.g. tcp/[::]:7447 in a container)",
    )
    parser.add_argument(
        "--tls", action="store_true", help="tls/ endpoints, a local CA and a router certificate in DIR/tls"
    )
    parser.add_argument(
        "--tls-name",
        action="append",
        default=[],
        metavar="NAME",
        help="another host name or address the router's certificate is valid for (repeatable; "
        "localhost and 127.0.0.1 always are)",
    )
    parser.add_argument(
        "--seen-as",
        metavar="PATH",
        help="the path the router and services see DIR at, when it is mounted elsewhere (a container's)",
    )
    parser.add_argument(
        "--router-base",
        metavar="FILE",
        help="a zenoh router configuration whose plugins (REST, storages) the router's file keeps, "
        "e.g. docker/zenohd.json5",
    )
    parser.add_argument(
        "--ros-namespace",
        metavar="NS",
        help="the ROS namespace of the ROS 2 bridge the ros2 role is granted (default none; the domain is "
        "$ROS_DOMAIN_ID, default 0); the ros_node role may do anything in that domain",
    )
    parser.add_argument(
        "--ros-tf",
        choices=list(TfLayout),
        help="the TF layout of the bridges the ros2 roles are granted (ros2.tf; default namespaced: each robot's "
        "tf in its namespace; prefixed: every robot's bridge may put on the shared /tf and /tf_static)",
    )
    parser.add_argument(
        "--localization-mode",
        choices=get_args(LocalizationMode),
        default=DEFAULT_LOCALIZATION,
        help=f"the localization.mode the localization role is granted for (default {DEFAULT_LOCALIZATION}): what "
        "it may subscribe (stub: motor/sim_pose/localization, the ground truth; amcl: sim/scan and "
        "motor/wheel_angles; none: motor/wheel_angles) and serve (amcl: localization/initial_pose and "
        "global_localization); amcl and none may not read sim/body_pose nor motor/sim_pose/* (docs/security.md)",
    )
    parser.add_argument(
        "--with",
        dest="with_services",
        action="append",
        metavar="FILE.py:NAME",
        help="also credentials for this service of your own (<name>.json5; docs/extending.md): it may put and "
        "serve only under its name and query only its class's calls (repeatable; not with --robots)",
    )


def run(args: argparse.Namespace) -> int:
    users = [
        UserServiceGrant(user.name, user.service.calls, user.service.reads)
        for user in load_all(args.with_services or ())
    ]
    return tools.run_secrets(
        Path(args.directory),
        Keys(args.robot),
        endpoint=args.endpoint,
        router_listen=args.router_listen,
        tls=args.tls,
        tls_names=args.tls_name,
        seen_as=Path(args.seen_as) if args.seen_as else None,
        router_base=args.router_base,
        ros=bridge_graph(load_config(overrides={"ros2.namespace": args.ros_namespace, "ros2.tf": args.ros_tf})),
        robots=args.robots,
        user_services=users,
        localization=args.localization_mode,
    )


HELP = "write a secure deployment's credentials, router and per-role zenoh configurations"
DESCRIPTION = (
    "Write fresh credentials for every role (sim, motor, odometry, localization, drive, ros2, "
    "ros_node, operator, observer) into DIR: router.json5 (usrpwd authentication and access control, default "
    "deny), dictionary.txt, and ROLE.json5, a complete client configuration per role (mode client, the "
    "router's endpoint, that role's user and password), all mode 0600. Start the router with "
    "`invent router --config DIR/router.json5` and each service with `--zenoh-config DIR/ROLE.json5`."
)
GROUPS: tuple[str, ...] = ()
