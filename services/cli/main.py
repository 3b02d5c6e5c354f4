"""``invent``: the command line of invent-zenoh. ``invent --help`` lists every subcommand.

Each subcommand is a module of this package with its flags and its run; this one assembles the
parser from them, runs the subcommand asked for, and maps the project's exceptions to exit
statuses (services/exits.py)."""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from services.exits import ExitStatus

if TYPE_CHECKING:
    from services.cli.subcommand import SubcommandModule

# The rest of the project is imported by main(), inside its handling of SIGINT: a service
# interrupted while it imports (invent up stopping everything as one fails to start) then says so
# in one line, not in a traceback of the import it was in.

SUBCOMMANDS = (
    "router",
    "secrets",
    "echo",
    "call",
    "status",
    "goto",
    "localize",
    "config",
    "record",
    "export",
    "view",
    "report",
    "replay",
    "up",
    "compose",
    "calibrate",
    "map",
    "worker",
    "control",
    "service",
)
"""The subcommands that are not services, in ``invent --help``'s order, each the module of its name
in this package (a :class:`~services.cli.subcommand.SubcommandModule`)."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """``invent``'s parser; with ``only`` (a subcommand's name), that subcommand's alone, so that
    only its module is imported: an ``invent motor`` process then starts in about half the time
    (~0.2 s of the 0.4 s of importing every subcommand's module, measured here)."""
    from services.cli import services
    from services.cli.extras import install_hint, missing_extra
    from services.cli.flags import Parents

    parser = argparse.ArgumentParser(
        prog="invent",
        description="invent-zenoh: a differential-drive robot stack on zenoh (motor, odometry, "
        "localization, drive and a PyBullet simulator, each a service).",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parents = Parents()
    for name in SUBCOMMANDS:
        if only not in (None, name):
            continue
        try:
            subcommand: SubcommandModule = importlib.import_module(f"services.cli.{name}")
        except ModuleNotFoundError as error:
            extra = missing_extra(name, error)
            if only is not None or extra is None:
                raise
            # `invent --help` lists it; `invent NAME` imports it alone and says which extra it needs.
            commands.add_parser(name, help=f"(not installed: {install_hint(extra)})")
            continue
        sub = commands.add_parser(
            name,
            parents=[getattr(parents, group) for group in subcommand.GROUPS],
            help=subcommand.HELP,
            description=subcommand.DESCRIPTION,
        )
        subcommand.add_arguments(sub)
        sub.set_defaults(handler=subcommand.run)
    services.add_parsers(commands, parents, [name for name in services.SERVICE_COMMANDS if only in (None, name)])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started with SIGINT ignored (by a shell without job control: `invent motor &` in a
        # script): Python then leaves it ignored, and a SIGINT before the command takes over its
        # signals would be lost, the service running on (seen: a test suite run so).
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _run(argv)
    except KeyboardInterrupt:
        # SIGINT before the command took over its signals (while it imports or starts: invent up
        # stopping every service as one fails to start): a line, not a traceback. Then out at once:
        # the interpreter's own exit, with zenoh's threads half started, can crash (seen: SIGSEGV,
        # once in a test run) or wait on a session half open.
        print("invent: interrupted while starting", file=sys.stderr, flush=True)
        if argv is None:  # the program itself, not a caller in its own process (a test)
            sys.stdout.flush()
            os._exit(ExitStatus.INTERRUPTED)
        return ExitStatus.INTERRUPTED


def _run(argv: Sequence[str] | None) -> int:
    from services.cli import services
    from services.cli.extras import absent_extra, missing_extra, refuse

    arguments = list(sys.argv[1:] if argv is None else argv)
    command = arguments[0] if arguments else None
    needed = absent_extra(command)
    if needed is not None:
        return refuse(command, needed)
    known = command if command in SUBCOMMANDS or command in services.SERVICE_COMMANDS else None
    try:
        return _run_command(arguments, known)
    except ModuleNotFoundError as error:
        extra = missing_extra(command, error)
        if extra is None:
            raise
        return refuse(command, extra)


def _run_command(arguments: list[str], known: str | None) -> int:
    from services.config import ConfigError
    from services.errors import SessionFailed
    from services.runtime.logs import configure_logging

    args = build_parser(known).parse_args(arguments)
    configure_logging(getattr(args, "log_level", "info"))  # a subcommand without the connection flags logs at info
    try:
        return args.handler(args)
    except ConfigError as error:
        print(f"invent {args.command}: invalid configuration: {error}", file=sys.stderr)
        return ExitStatus.CONFIG
    except SessionFailed as error:
        print(f"invent {args.command}: {error}", file=sys.stderr)
        return ExitStatus.FAILURE
