"""The service subcommands, ``invent sim``, ``motor``, ``odometry``, ``localization``, ``drive`` and
``ros2``, one module each; and :func:`service_plan`, which turns such a subcommand's arguments into
the service to start, as ``invent <service>`` does (tests/test_service_plans.py parses what the
launcher renders of its plans with it)."""

from __future__ import annotations

import argparse
import functools
import importlib
from collections.abc import Sequence
from typing import Any

from services.cli.flags import Commands, Parents
from services.cli.serve import ServiceCli, add_parser, plan_from_args
from services.service import ServicePlan

SERVICE_COMMANDS = ("sim", "motor", "odometry", "localization", "drive", "ros2")
"""One ``invent <service>`` subcommand each, in this order; each is the module of its name here,
whose ``CLI`` is its :class:`~services.cli.serve.ServiceCli`."""


def service_cli(name: str) -> ServiceCli[Any]:
    """The subcommand ``invent <name>``, its module imported only now: a process that runs one
    service does not import the others (every ``invent`` process would pay for all of them)."""
    cli: ServiceCli[Any] = importlib.import_module(f"services.cli.{name}").CLI
    return cli


def add_parsers(commands: Commands, parents: Parents, names: Sequence[str] = SERVICE_COMMANDS) -> None:
    for name in names:
        add_parser(commands, parents, service_cli(name))


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """``invent``'s parser of the service subcommands only: they parse as ``invent`` parses them."""
    parser = argparse.ArgumentParser(prog="invent")
    add_parsers(parser.add_subparsers(dest="command", required=True, metavar="COMMAND"), Parents())
    return parser


def service_plan(argv: Sequence[str]) -> ServicePlan:
    """The service ``invent <argv>`` would run (``["motor", "--robot", "rh1"]``)."""
    args = _parser().parse_args(list(argv))
    return plan_from_args(args.service_cli, args)
