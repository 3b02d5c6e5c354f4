"""``invent``: the command line of invent-zenoh. ``invent --help`` lists every subcommand.

Each subcommand is a module of this package with its flags and its run; this one assembles the
parser from them, runs the subcommand asked for, and maps the project's exceptions to exit
statuses (services/exits.py)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from services.cli import (
    calibrate,
    call,
    config,
    echo,
    export,
    goto,
    record,
    replay,
    report,
    router,
    secrets,
    service,
    services,
    status,
    up,
    view,
    worker,
)
from services.cli.flags import Parents
from services.cli.subcommand import SubcommandModule
from services.config import ConfigError
from services.errors import SessionFailed
from services.exits import ExitStatus
from services.runtime.logs import configure_logging

SUBCOMMANDS: tuple[SubcommandModule, ...] = (
    router,
    secrets,
    echo,
    call,
    status,
    goto,
    config,
    record,
    export,
    view,
    report,
    replay,
    up,
    calibrate,
    worker,
    service,
)
"""The subcommands that are not services, in ``invent --help``'s order, each in its own module."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="invent",
        description="invent-zenoh: a differential-drive robot stack on zenoh (motor, odometry, "
        "localization, drive and a PyBullet simulator, each a service).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parents = Parents()
    for subcommand in SUBCOMMANDS:
        sub = commands.add_parser(
            subcommand.__name__.rpartition(".")[2],
            parents=[getattr(parents, group) for group in subcommand.GROUPS],
            help=subcommand.HELP,
            description=subcommand.DESCRIPTION,
        )
        subcommand.add_arguments(sub)
        sub.set_defaults(handler=subcommand.run)
    services.add_parsers(commands, parents)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(getattr(args, "log_level", "info"))  # a subcommand without the connection flags logs at info
    try:
        return args.handler(args)
    except ConfigError as error:
        print(f"invent {args.command}: invalid configuration: {error}", file=sys.stderr)
        return ExitStatus.CONFIG
    except SessionFailed as error:
        print(f"invent {args.command}: {error}", file=sys.stderr)
        return ExitStatus.FAILURE
