"""``invent service FILE.py:NAME``: a service of one's own (docs/extending.md), alone, as
``invent motor`` runs the motor: the same connection, description and real-time flags."""

from __future__ import annotations

import argparse

from services.cli.flags import config_from_args, session_from_args
from services.cli.serve import add_journal_arguments, journaling_from_args
from services.extension.hosting import UserOptions, command
from services.extension.loader import load
from services.runtime.realtime import apply_realtime
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals
from services.service import ServicePlan, run_service

HELP = "run a service of your own: a UserService subclass in a Python file (docs/extending.md)"
DESCRIPTION = (
    "Run the UserService subclass NAME of FILE.py (services/extension/api.py) until SIGINT/SIGTERM or its own "
    "end: its keys are invent/<robot>/<name>/..., its status <name>/status, its log lines prefixed with its "
    "name. A FILE or NAME that cannot be loaded, or a class whose declarations (name, calls, lockstep) are "
    "wrong, exits 2 naming it. invent up --with FILE.py:NAME runs it beside the loop. See docs/extending.md."
)
GROUPS: tuple[str, ...] = ("connection", "description", "rt")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", metavar="FILE.py:NAME", help="the Python file and the UserService subclass in it")
    add_journal_arguments(parser)


def run(args: argparse.Namespace) -> int:
    loaded = load(args.spec)
    config = config_from_args(None, args)
    plan = ServicePlan(command(loaded), config, UserOptions(loaded), journaling_from_args(args))
    apply_realtime(config.rt, f"invent service {loaded.name}", control_path=False)
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args)) as session:
        return run_service(plan, session, stop)
