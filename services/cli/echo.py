"""``invent echo``: print samples as JSON lines, decoded with their key's schema."""

from __future__ import annotations

import argparse

from services.cli import tools
from services.cli.flags import session_from_args
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("keyexpr", metavar="KEYEXPR", help="zenoh key expression, e.g. 'invent/rh0/**'")
    parser.add_argument("--count", type=int, metavar="N", help="exit after N samples")


def run(args: argparse.Namespace) -> int:
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args)) as session:
        return tools.run_echo(session, args.keyexpr, args.count, stop)


HELP = "print samples as JSON lines, decoded with their key's schema"
DESCRIPTION = (
    "Subscribe to KEYEXPR and print one JSON line per sample: its key and its payload "
    "decoded with the schema that key carries (raw text for unknown keys)."
)
GROUPS: tuple[str, ...] = ("connection",)
