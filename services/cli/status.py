"""``invent status``: the services alive and their status."""

from __future__ import annotations

import argparse

from services.cli import tools
from services.cli.flags import Commands, Parents, session_from_args
from services.runtime.session import open_session


def add_parser(commands: Commands, parents: Parents) -> None:
    status = commands.add_parser(
        "status",
        parents=[parents.connection],
        help="list the services alive and their status",
        description="List the services alive (from their liveliness tokens) and print each one's status reply.",
    )
    status.add_argument("--robot", metavar="NAME", help="only this robot (default: every robot)")
    status.add_argument("--timeout", type=float, default=1.0, metavar="S", help="seconds to wait (default 1)")
    status.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    with open_session(session_from_args(args)) as session:
        return tools.run_status(session, args.robot, args.timeout)
