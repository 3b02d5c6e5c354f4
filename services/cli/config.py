"""``invent config``: the resolved robot description (file + overrides) as JSON."""

from __future__ import annotations

import argparse
import json

import msgspec

from services.cli.flags import Commands, Parents, config_from_args


def add_parser(commands: Commands, parents: Parents) -> None:
    config = commands.add_parser(
        "config",
        parents=[parents.description],
        help="print the resolved robot description (file + overrides) as JSON",
        description="Load the robot description as a service would (--config file, then --set overrides) "
        "and print it as JSON. Exits 2 naming the field when it is invalid.",
    )
    config.set_defaults(handler=run, log_level="info")


def run(args: argparse.Namespace) -> int:
    print(json.dumps(msgspec.to_builtins(config_from_args(None, args)), indent=2))
    return 0
