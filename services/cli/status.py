"""``invent status``: the services alive and their status."""

from __future__ import annotations

import argparse

from services.cli import tools
from services.cli.flags import session_from_args
from services.runtime.session import open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", metavar="NAME", help="only this robot (default: every robot)")
    parser.add_argument("--timeout", type=float, default=1.0, metavar="S", help="seconds to wait (default 1)")


def run(args: argparse.Namespace) -> int:
    with open_session(session_from_args(args)) as session:
        return tools.run_status(session, args.robot, args.timeout)


HELP = "list the services alive and their status"
DESCRIPTION = "List the services alive (from their liveliness tokens) and print each one's status reply."
GROUPS: tuple[str, ...] = ("connection",)
