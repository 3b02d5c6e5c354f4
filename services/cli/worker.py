"""``invent worker``: a worker of a composed fleet (services/launch/worker.py)."""

from __future__ import annotations

import argparse
from typing import Any

from services.cli.flags import fleet_flag, session_from_args
from services.config import ConfigError
from services.fleet.description import load_fleet
from services.launch import worker
from services.launch.service_plans import ChildPlan
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    fleet_flag(
        parser,
        "run the services (motor, odometry, localization, drive) of --robots of this fleet file, as "
        "invent up --fleet starts them: one process on a service host for its robots (docs/deploy.md)",
    )
    parser.add_argument(
        "--robots", metavar="R1,R2,...", help="with --fleet: the robots whose services this process runs"
    )
    parser.add_argument(
        "--no-intra-process", action="store_true", help="the services' messages through the zenoh session"
    )


def run(args: argparse.Namespace) -> int:
    plans: list[ChildPlan[Any]] = []
    if bool(args.fleet) != bool(args.robots):
        raise ConfigError("invent worker: --fleet and --robots go together (or neither: up sends the services)")
    if args.fleet:
        fleet_file = load_fleet(args.fleet)
        names = [name.strip() for name in args.robots.split(",") if name.strip()]
        unknown = [name for name in names if name not in fleet_file.names]
        if unknown or not names:
            raise ConfigError(f"--robots {args.robots}: not robots of {args.fleet} ({', '.join(fleet_file.names)})")
        plans = worker.robot_plans(fleet_file, names)
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args)) as session:
        return worker.run_worker(session, stop, intra_process=not args.no_intra_process, plans=plans)


HELP = "(started by invent up --fleet --composed) compose the services it is sent on standard input"
DESCRIPTION = (
    "A worker of a composed fleet (docs/fleet.md): reads one service's plan per line on standard input (a JSON "
    "array: its name, service, robot description, journal and options, as invent up sends them), builds each "
    "composed in this process and says so on standard output; stops on SIGINT or end of input."
)
GROUPS: tuple[str, ...] = ("connection",)
