"""``invent compose``: compose.yaml of a stack (services/launch/compose_file.py)."""

from __future__ import annotations

import argparse
import sys

from services.launch.compose_file import DEPLOYMENT, compose_yaml
from services.launch.stack import read_stack


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stack",
        metavar="FILE.toml",
        help="the stack to deploy (docs/stack.md): its settings given to every service, its scenario looped by the "
        "scenario profile's drive, its services of your own (--with) in the extension profile, its live view; "
        "default: the deployment of the committed compose.yaml",
    )


def run(args: argparse.Namespace) -> int:
    sys.stdout.write(compose_yaml(read_stack(args.stack) if args.stack else DEPLOYMENT))
    return 0


HELP = "print the compose.yaml of a stack (docker compose: docs/deploy.md)"
DESCRIPTION = (
    "Print compose.yaml for a stack file (invent up --print-stack writes one; docs/stack.md), or with no --stack "
    "the committed one: a zenohd router with access control, a container per service, one commander per profile "
    "(scenario, goals, ros2), your services in the extension profile. `invent compose > compose.yaml` then "
    "`make secrets` and `docker compose up`. A stack no compose deployment runs (a fleet, lockstep, composed "
    "processes, --sim-set, a description file) exits 2 naming it."
)
GROUPS: tuple[str, ...] = ()
