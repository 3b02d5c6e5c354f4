"""What a service subcommand is, and how one runs: alone (its own session) or composed.

A service module defines one :class:`ServiceCommand`. ``invent <service>`` loads the robot
description (``--config`` file, then ``--set`` overrides, then the service's own flags),
opens a zenoh session, builds the service around a :class:`~services.runtime.node.Node` and runs it
until SIGINT/SIGTERM or until it finishes by itself. :func:`start_service` builds one on an
existing session instead, so several services can share one process and one session.
"""

from __future__ import annotations

import argparse
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import msgspec
import zenoh

from schemas.keys import Keys, Service, validate_robot_name
from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import Config, ConfigError, RecordConfig, load_config, parse_override
from services.runtime.executor import Executor
from services.runtime.intraprocess import LocalBus
from services.runtime.journal import MB, Journal, JournalLimits, journal_path
from services.runtime.node import Node
from services.runtime.realtime import settle_garbage_collector


def positive_seconds(text: str) -> float:
    """argparse type of a duration flag: a finite number of seconds > 0."""
    value = finite_number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number of seconds")
    return value


def non_negative_float(text: str) -> float:
    """argparse type of a flag that is a finite number >= 0."""
    value = finite_number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a number >= 0")
    return value


def port_number(text: str) -> int:
    """argparse type of a TCP port to serve on: 0..65535 (0: any free port)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} must be a port number, 0..65535")
    return port


def robot_name(text: str) -> str:
    """argparse type of a robot name (one key chunk)."""
    try:
        return validate_robot_name(text)
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


class TraceFile:
    """``--trace FILE``: one JSON line per cycle, unbuffered, so each line is on disk once the
    cycle's output is published. An unwritable path is a configuration error (exit 2)."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._file = Path(path).open("wb", buffering=0)  # noqa: SIM115 (open for the service's life; close() closes it)
        except OSError as error:
            raise ConfigError(f"--trace {path}: {error.strerror}") from None
        self._encoder = msgspec.json.Encoder()

    @classmethod
    def from_flag(cls, path: str | None) -> TraceFile | None:
        return cls(path) if path else None

    def write(self, record: Any) -> None:
        self._file.write(self._encoder.encode(record) + b"\n")

    def close(self) -> None:
        self._file.close()


class RunningService(Protocol):
    """A reactive service (motor, odometry, localization, drive): it declares its inputs on its
    node and has no loop; the runtime runs it (:meth:`~services.runtime.node.Node.serve`)."""

    finished: bool
    """True once the service has ended by itself (a drive at the end of its scenario, a sim at the
    end of its ``--duration``): whatever runs it then stops."""

    @property
    def exit_code(self) -> int:
        """The service's exit code once ``finished``: 0, but for a drive whose scenario was given up
        (services/drive/outcome.py)."""
        ...

    def close(self) -> None:
        """Release what the service holds beyond its node (files, simulators)."""
        ...


@runtime_checkable
class ClockedService(RunningService, Protocol):
    """A service that owns a clock (the simulator): it has a loop of its own, and in a composition
    that loop's thread handles every composed service's events too."""

    def run(self, stop: threading.Event) -> int:
        """Serve until ``stop`` is set (or the service's own end); return the exit code."""
        ...


ServiceFactory = Callable[[Node, Config, argparse.Namespace], RunningService]


@dataclass(frozen=True)
class ServiceCommand:
    service: Service
    help: str
    description: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    """Adds the service's own flags to its subcommand."""
    overrides: Callable[[argparse.Namespace], dict[str, Any]]
    """Maps the service's flags to config keys ({"motor.target_angle": args.target_angle}); None = unset."""
    factory: ServiceFactory
    timestamped: bool = False
    """Its session stamps what it publishes (zenoh's ``timestamping``): a zenoh-ext advanced
    publisher with a cache, which the ROS 2 bridge's latched topics are, needs it."""


def no_overrides(_args: argparse.Namespace) -> dict[str, Any]:
    return {}


def overrides_from_args(command: ServiceCommand | None, args: argparse.Namespace) -> dict[str, Any]:
    """What ``args`` sets over the robot description file: ``--set``, then ``--robot`` and
    ``command``'s flags."""
    overrides: dict[str, Any] = {}
    for text in args.set or ():
        path, value = parse_override(text)
        overrides[".".join(path)] = value
    overrides["robot.name"] = args.robot
    if getattr(args, "rt", False):
        overrides["rt.enabled"] = True
    if command is not None:
        overrides.update({key: value for key, value in command.overrides(args).items() if value is not None})
    return overrides


def config_from_args(command: ServiceCommand | None, args: argparse.Namespace) -> Config:
    """The robot description for ``args``: file, then ``--set``, then ``--robot`` and ``command``'s flags."""
    return load_config(args.config, overrides_from_args(command, args))


def start_service(
    command: ServiceCommand,
    session: zenoh.Session,
    config: Config,
    args: argparse.Namespace,
    executor: Executor | None = None,
    bus: LocalBus | None = None,
) -> tuple[Node, RunningService]:
    """Build ``command``'s service on ``session`` (opened by the caller, maybe shared), its node
    on ``executor`` (default: one of its own), keeping what it publishes in a journal in
    ``args.journal`` if given (``invent up`` records its run so); ``bus``: the process's
    intra-process delivery, when services are composed (services/runtime/intraprocess.py)."""
    journal = _journal(args, command.service, config.record)
    node = Node(session, Keys(config.robot.name), command.service, executor=executor, journal=journal, bus=bus)
    try:
        return node, command.factory(node, config, args)
    except BaseException:
        node.close()
        raise


def _journal(args: argparse.Namespace, service: Service, record: RecordConfig) -> Journal | None:
    directory = getattr(args, "journal", None)
    if directory is None:
        return None
    try:
        return Journal(
            journal_path(Path(directory), str(service)),
            journal_limits(record, getattr(args, "journal_share", 1)),
            every_step=record.every_step,
        )
    except OSError as error:
        raise ConfigError(f"--journal {directory}: {error.strerror}") from None


def journal_limits(record: RecordConfig, share: int) -> JournalLimits:
    """A journal's limits under ``record``, ``share`` journals of a run sharing ``record.max_size``."""
    return JournalLimits(
        max_bytes=None if record.max_size is None else round(record.max_size * MB / share),
        max_stamp_ns=None if record.max_duration is None else round(record.max_duration * NANOSECONDS_PER_SECOND),
        min_free_bytes=round(record.min_free_disk * MB),
    )


def run_service(
    command: ServiceCommand, session: zenoh.Session, config: Config, args: argparse.Namespace, stop: threading.Event
) -> int:
    node, service = start_service(command, session, config, args)
    settle_garbage_collector(config.rt)
    try:
        if isinstance(service, ClockedService):
            return service.run(stop)
        node.serve(stop, lambda: service.finished)
        return service.exit_code if service.finished else 0
    finally:
        service.close()
        node.close()
