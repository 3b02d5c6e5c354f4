"""``invent <service>``: what each service subcommand is to the command line (:class:`ServiceCli`:
its help, its flags, how they become its options and config keys), and how it runs alone: its
robot description, real-time settings and session, then :func:`services.service.run_service`."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic

from services.cli.flags import Commands, Parents, config_from_args, session_from_args
from services.runtime.realtime import CONTROL_PATH, apply_realtime
from services.runtime.session import SHUTDOWN_WATCHDOG_S, open_session, stop_on_signals
from services.service import Journaling, NoOptions, OptionsT, ServiceCommand, ServicePlan, run_service


def no_overrides(_args: argparse.Namespace) -> dict[str, Any]:
    return {}


def no_options(_args: argparse.Namespace) -> NoOptions:
    return NoOptions()


@dataclass(frozen=True)
class ServiceCli(Generic[OptionsT]):
    """A service's subcommand: ``invent <service>``."""

    command: ServiceCommand[OptionsT]
    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    """Adds the service's own flags to its subcommand."""
    options: Callable[[argparse.Namespace], OptionsT]
    """The service's own options from its flags (a frozen dataclass beside its factory)."""
    overrides: Callable[[argparse.Namespace], dict[str, Any]] = no_overrides
    """Maps the service's flags to config keys ({"motor.target_angle": args.target_angle}); None = unset."""
    run: Callable[[argparse.Namespace], int] | None = None
    """Its own handler, where it is more than :func:`serve` (``invent ros2 --fleet``)."""


def add_parser(commands: Commands, parents: Parents, cli: ServiceCli[Any]) -> None:
    sub = commands.add_parser(
        str(cli.command.service),
        parents=[parents.connection, parents.description, parents.rt],
        help=cli.help,
        description=cli.description,
    )
    cli.add_arguments(sub)
    add_journal_arguments(sub)
    sub.set_defaults(handler=cli.run or serve, service_cli=cli)


def plan_from_args(cli: ServiceCli[OptionsT], args: argparse.Namespace) -> ServicePlan[OptionsT]:
    """The service to start: its robot description (file, ``--set``, its flags), its options, its journal."""
    config = config_from_args(cli, args)
    options = cli.options(args)
    cli.command.check(config, options)
    return ServicePlan(cli.command, config, options, journaling_from_args(args))


def add_journal_arguments(parser: argparse.ArgumentParser) -> None:
    """``invent up``'s own flags of every process it starts a service in (hidden): where a service
    keeps what it publishes, for the run's recording, and how many journals of the run share
    ``record.max_size``; :func:`journaling_from_args` reads them."""
    parser.add_argument("--journal", metavar="DIR", help=argparse.SUPPRESS)
    parser.add_argument("--journal-share", type=int, default=1, help=argparse.SUPPRESS)


def journaling_from_args(args: argparse.Namespace) -> Journaling:
    return Journaling(Path(args.journal) if args.journal else None, args.journal_share)


def serve(args: argparse.Namespace) -> int:
    """``invent <service>``: the service alone, on a session of its own, until SIGINT/SIGTERM or its own end."""
    cli: ServiceCli[Any] = args.service_cli
    plan = plan_from_args(cli, args)
    apply_realtime(plan.config.rt, f"invent {cli.command.service}", control_path=cli.command.service in CONTROL_PATH)
    stop = stop_on_signals(SHUTDOWN_WATCHDOG_S)
    with open_session(session_from_args(args, timestamping=cli.command.timestamped)) as session:
        return run_service(plan, session, stop)
