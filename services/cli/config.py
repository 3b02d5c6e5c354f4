"""``invent config``: the resolved robot description (file + overrides) as JSON."""

from __future__ import annotations

import argparse
import json

import msgspec

from services.cli.flags import config_from_args
from services.cli.subcommand import Subcommand


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """None of its own."""


def run(args: argparse.Namespace) -> int:
    print(json.dumps(msgspec.to_builtins(config_from_args(None, args)), indent=2))
    return 0


SUBCOMMAND = Subcommand(
    name="config",
    help="print the resolved robot description (file + overrides) as JSON",
    description="Load the robot description as a service would (--config file, then --set overrides) "
    "and print it as JSON. Exits 2 naming the field when it is invalid.",
    groups=("description",),
    add_arguments=add_arguments,
    run=run,
)
