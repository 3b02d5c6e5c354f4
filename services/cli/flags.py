"""What every ``invent`` subcommand shares: the flag groups (zenoh connection, robot description,
real time), the argparse types that check a flag's value (a bad value is a usage error, exit 2,
naming the flag), and the turning of those flags into typed values: the robot description, a zenoh
session's configuration, the flags a child process is given."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, TypeAlias, TypeVar

import zenoh

from schemas.keys import DEFAULT_ROBOT, validate_robot_name
from services.config import Config, ConfigError, SimConfig, SimEngine, load_config
from services.launch.plan import Connection, Description
from services.runtime.logs import LOG_LEVELS
from services.runtime.session import DEFAULT_ENDPOINT, LOOPBACK_LISTEN, ZENOH_CONFIG_VARIABLE, session_config
from services.security import fleet_robots

Commands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"
"""Where a subcommand's module adds its parser (``invent``'s subparsers)."""
T = TypeVar("T")


class OwnFlags(Protocol):
    """A subcommand whose own flags set config keys (a service's: ``--target-angle`` sets
    ``motor.target_angle``)."""

    def overrides(self, args: argparse.Namespace) -> dict[str, Any]:
        """Its flags as config keys; a None value is unset (it must not mask the same key's ``--set``)."""
        ...


def _flag_group(title: str) -> tuple[argparse.ArgumentParser, argparse._ArgumentGroup]:
    """A parent parser (for a subcommand's ``parents``) holding one titled group of flags."""
    flags = argparse.ArgumentParser(add_help=False)
    return flags, flags.add_argument_group(title)


def connection_flags() -> argparse.ArgumentParser:
    flags, group = _flag_group("zenoh connection")
    group.add_argument(
        "--connect",
        metavar="EP",
        action="append",
        default=[],
        help=f"endpoint to connect to (repeatable; default {DEFAULT_ENDPOINT}, or $ZENOH_CONFIG)",
    )
    group.add_argument(
        "--listen",
        metavar="EP",
        action="append",
        default=[],
        help=f"endpoint to listen on as well (repeatable; a peer always listens on {LOOPBACK_LISTEN} and nothing "
        "else unless told, e.g. --listen tcp/0.0.0.0:0 to accept other machines)",
    )
    group.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help=f"zenoh configuration file replacing the default (e.g. a role's file from `invent secrets`; "
        f"default ${ZENOH_CONFIG_VARIABLE}); --connect/--listen still apply on top",
    )
    group.add_argument("--log-level", default="info", choices=LOG_LEVELS, help="log level (default info)")
    return flags


def description_flags() -> argparse.ArgumentParser:
    flags, group = _flag_group("robot description")
    group.add_argument(
        "--robot", metavar="NAME", help=f"robot name, the key prefix invent/NAME/ (default {DEFAULT_ROBOT})"
    )
    group.add_argument("--config", metavar="FILE", help="robot description TOML file (see docs/configuration.md)")
    group.add_argument(
        "--set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        help="override one config value, e.g. --set motor.p_gain_l=3.0 (repeatable)",
    )
    return flags


def rt_flags() -> argparse.ArgumentParser:
    flags, group = _flag_group("real time")
    group.add_argument(
        "--rt",
        action="store_true",
        help="real-time settings (the [rt] table, e.g. --set rt.priority=70): SCHED_FIFO, locked memory, "
        "the CPUs of rt.cpus, the garbage collector frozen after start-up; what the system refuses is said "
        "in one line and skipped (docs/realtime.md)",
    )
    return flags


class Parents:
    """The shared flag groups, made once for a parser: a subcommand takes them as its ``parents``."""

    def __init__(self) -> None:
        self.connection = connection_flags()
        self.description = description_flags()
        self.rt = rt_flags()


def positive_seconds(text: str) -> float:
    """argparse type of a duration flag: a finite number of seconds > 0."""
    return _finite_where(text, lambda value: value > 0.0, "a positive number of seconds")


def positive_length(text: str) -> float:
    """argparse type of a length flag: a finite number of metres > 0."""
    return _finite_where(text, lambda value: value > 0.0, "a positive length in metres")


def non_negative_float(text: str) -> float:
    """argparse type of a flag that is a finite number >= 0."""
    return _finite_where(text, lambda value: value >= 0.0, "a number >= 0")


def _finite_where(text: str, holds: Callable[[float], bool], must_be: str) -> float:
    value = finite_number(text)
    if not holds(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be {must_be}")
    return value


def positive_int(text: str) -> int:
    """argparse type of a count flag: a whole number >= 1."""
    value = whole_number(text, "a whole number")
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be at least 1")
    return value


def port_number(text: str) -> int:
    """argparse type of a TCP port to serve on: 0..65535 (0: any free port)."""
    port = whole_number(text, "a port number")
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} must be a port number, 0..65535")
    return port


def whole_number(text: str, what: str) -> int:
    """``text`` as an int, or argparse's usage error saying it is not ``what``."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None


def robot_name(text: str) -> str:
    """argparse type of a robot name (one key chunk)."""
    try:
        return validate_robot_name(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def robot_names(text: str) -> tuple[str, ...]:
    """``--robots rh0,rh1``: a fleet's robot names, comma-separated (an argparse ``type``: a bad or
    repeated name is a usage error, exit 2, naming the flag)."""
    try:
        return fleet_robots(name.strip() for name in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def finite_number(text: str) -> float:
    """argparse type of a float flag that must be finite (argparse's float takes nan and inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not finite")
    return value


def parsed_by(parse: Callable[[str], T]) -> Callable[[str], T]:
    """An argparse ``type`` from a parser raising ConfigError: argparse then exits 2 with the reason."""

    def convert(text: str) -> T:
        try:
            return parse(text)
        except ConfigError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    convert.__name__ = parse.__name__
    return convert


def given_as(load: Callable[[str], object]) -> Callable[[str], str]:
    """A parser (for :func:`parsed_by`) that loads what ``text`` names, to refuse it now, and keeps
    ``text`` as given: a service's plan names its scenario or goal file as its command line did."""

    def check(text: str) -> str:
        load(text)
        return text

    check.__name__ = load.__name__
    return check


def description_from_args(args: argparse.Namespace) -> Description:
    """The robot description flags as given (``--rt`` where the subcommand has it)."""
    return Description(args.robot, args.config, tuple(args.set or ()), getattr(args, "rt", False))


def connection_from_args(args: argparse.Namespace) -> Connection:
    return Connection(tuple(args.connect), tuple(args.listen), args.zenoh_config, args.log_level)


def overrides_from_args(command: OwnFlags | None, args: argparse.Namespace) -> dict[str, Any]:
    """What ``args`` sets over the robot description file: ``--set``, then ``--robot``, ``--rt``
    and ``command``'s own flags."""
    overrides = description_from_args(args).overrides()
    if command is not None:
        overrides.update({key: value for key, value in command.overrides(args).items() if value is not None})
    return overrides


def config_from_args(command: OwnFlags | None, args: argparse.Namespace) -> Config:
    """The robot description for ``args``: file, then ``--set``, then ``--robot`` and ``command``'s flags."""
    return load_config(args.config, overrides_from_args(command, args))


def session_from_args(args: argparse.Namespace, mode: str = "peer", timestamping: bool = False) -> zenoh.Config:
    """The zenoh session the connection flags ask for."""
    return session_config(
        connect=args.connect, listen=args.listen, mode=mode, file=args.zenoh_config, timestamping=timestamping
    )


def engine_flag(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--engine``: ``sim.engine`` (``invent sim``'s and ``invent up``'s)."""
    parser.add_argument(
        "--engine",
        choices=list(SimEngine),
        help="what moves the robot: PyBullet's physics, or a model of the wheels' motors and the robot's inertia "
        f"with ideal rolling and no PyBullet (sets sim.engine; default {SimConfig().engine}; docs/sim.md, Engines)",
    )


def fleet_flag(parser: argparse.ArgumentParser | argparse._ArgumentGroup, what_it_does: str) -> None:
    """``--fleet FILE``: a fleet file (docs/fleet.md); ``what_it_does`` with it, as its help says."""
    parser.add_argument("--fleet", metavar="FILE", help=what_it_does)


def existing_file(text: str) -> Path:
    """``text`` as the path of a file that is there; ConfigError (exit 2) naming it otherwise."""
    path = Path(text)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    return path


def new_bag_directory(text: str) -> Path:
    """``--output``: the directory a bag is written into, which must not be there yet (ConfigError)."""
    output = Path(text)
    if output.exists():
        raise ConfigError(f"--output {output}: it exists (a bag is written into a new directory)")
    return output
