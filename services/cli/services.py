"""The service subcommands, ``invent sim``, ``motor``, ``odometry``, ``localization``, ``drive`` and
``ros2``, one module each; and :func:`service_plan`, which turns such a subcommand's arguments into
the service to start, for a composition (``invent up --composed``, ``invent worker``)."""

from __future__ import annotations

import argparse
import functools
from collections.abc import Sequence
from typing import Any

from services.cli import drive, localization, motor, odometry, ros2, sim
from services.cli.flags import Commands, Parents
from services.cli.serve import ServiceCli, add_parser, plan_from_args
from services.service import ServicePlan

SERVICES: tuple[ServiceCli[Any], ...] = (sim.CLI, motor.CLI, odometry.CLI, localization.CLI, drive.CLI, ros2.CLI)
"""One ``invent <service>`` subcommand each, in this order."""


def add_parsers(commands: Commands, parents: Parents) -> None:
    for cli in SERVICES:
        add_parser(commands, parents, cli)


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """``invent``'s parser of the service subcommands only: they parse as ``invent`` parses them."""
    parser = argparse.ArgumentParser(prog="invent")
    add_parsers(parser.add_subparsers(dest="command", required=True, metavar="COMMAND"), Parents())
    return parser


def service_plan(argv: Sequence[str]) -> ServicePlan:
    """The service ``invent <argv>`` would run (``["motor", "--robot", "rh1"]``): a
    :data:`~services.service.ServiceParse`."""
    args = _parser().parse_args(list(argv))
    return plan_from_args(args.service_cli, args)
