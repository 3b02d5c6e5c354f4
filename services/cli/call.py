"""``invent call``: query a key (a Motor method, a status) and print the replies."""

from __future__ import annotations

import argparse

from services.cli import tools
from services.cli.flags import session_from_args
from services.runtime.session import open_session


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("key", metavar="KEY", help="e.g. invent/rh0/motor/gui/stop")
    parser.add_argument("payload", metavar="JSON", nargs="?", help="e.g. '{\"p_gain_l\": 5, ...}'")
    parser.add_argument("--timeout", type=float, default=2.0, metavar="S", help="seconds to wait (default 2)")


def run(args: argparse.Namespace) -> int:
    with open_session(session_from_args(args)) as session:
        return tools.run_call(session, args.key, args.payload, args.timeout)


HELP = "query a key (a Motor method, a status) and print the replies"
DESCRIPTION = (
    "Send a query to KEY with an optional JSON payload and print each reply as JSON. "
    "Exits 1 on an error reply or when nothing answers. Target velocities are not queries: "
    "drive/target_velocity is data the motor takes by its stamp, refusing as stale a target stamped "
    "before the simulation time minus motor.command_timeout (a target stamped 0.0 once the simulation is "
    "0.5 s in); send one with `invent drive --twist VX W`, which stamps with the newest simulation time."
)
GROUPS: tuple[str, ...] = ("connection",)
