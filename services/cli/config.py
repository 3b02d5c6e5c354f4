"""``invent config``: the resolved robot description (file + overrides) as JSON."""

from __future__ import annotations

import argparse
import json

import msgspec

from services.cli.flags import config_from_args


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """None of its own."""


def run(args: argparse.Namespace) -> int:
    print(json.dumps(msgspec.to_builtins(config_from_args(None, args)), indent=2))
    return 0


HELP = "print the resolved robot description (file + overrides) as JSON"
DESCRIPTION = (
    "Load the robot description as a service would (--config file, then --set overrides) "
    "and print it as JSON. Exits 2 naming the field when it is invalid."
)
GROUPS: tuple[str, ...] = ("description",)
