"""What a service is to whatever runs it, and how one runs: alone (its own session) or composed.

A service module defines one :class:`ServiceCommand` (its factory) and a frozen dataclass of its
own options beside it. The command line (services/cli/) turns ``invent <service>``'s flags into a
:class:`ServicePlan`: the command, the robot description (``--config`` file, then ``--set``
overrides, then the service's own flags), the service's options and where it journals; the
launcher builds the same of its typed plans (services/launch/service_plans.py).
:func:`run_service` opens nothing: it builds the service around a
:class:`~services.runtime.node.Node` on the session it is given and runs it until stopped or
until it finishes by itself. :func:`start_service` builds one on an existing session, so several
services can share one process and one session.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

import msgspec
import zenoh

from schemas.keys import Keys, Service, ServiceName
from schemas.messages import NANOSECONDS_PER_SECOND
from services.config import Config, ConfigError, RecordConfig, SimMode
from services.interfaces import declared
from services.runtime.executor import Executor
from services.runtime.inputs import congestion
from services.runtime.intraprocess import LocalBus
from services.runtime.journal import MB, Journal, JournalLimits, journal_path
from services.runtime.node import Node
from services.runtime.realtime import settle_garbage_collector


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


OptionsT = TypeVar("OptionsT")


def no_check(_config: Config, _options: Any) -> None:
    return None


@dataclass(frozen=True)
class ServiceCommand(Generic[OptionsT]):
    """A service as whatever runs it sees it: what it is, and how it is built from the robot
    description and its own options (a frozen dataclass beside its factory)."""

    service: ServiceName
    """A built-in's, or a user service's name (services/extension/)."""
    factory: Callable[[Node, Config, OptionsT], RunningService]
    timestamped: bool = False
    """Its session stamps what it publishes (zenoh's ``timestamping``): a zenoh-ext advanced
    publisher with a cache, which the ROS 2 bridge's latched topics are, needs it."""
    check: Callable[[Config, OptionsT], None] = no_check
    """Refuses (ConfigError: exit 2) what its description and its options allow each alone but not
    together (``invent sim --engine kinematic --gui``), before anything starts."""


@dataclass(frozen=True)
class NoOptions:
    """The options of a service that has none of its own (the robot description says everything)."""


@dataclass(frozen=True)
class Journaling:
    """What every service may be given (``invent up`` records its run so): the directory of the
    journal it keeps what it publishes in, and how many journals of the run share ``record.max_size``."""

    directory: Path | None = None
    share: int = 1


@dataclass(frozen=True)
class ServicePlan(Generic[OptionsT]):
    """One service to start: its command, its robot description, its own options (of the type its
    factory takes) and its journal."""

    command: ServiceCommand[OptionsT]
    config: Config
    options: OptionsT
    journaling: Journaling = field(default_factory=Journaling)


def start_service(
    plan: ServicePlan,
    session: zenoh.Session,
    executor: Executor | None = None,
    bus: LocalBus | None = None,
) -> tuple[Node, RunningService]:
    """Build ``plan``'s service on ``session`` (opened by the caller, maybe shared), its node on
    ``executor`` (default: one of its own), keeping what it publishes in a journal in
    ``plan.journaling.directory`` if given (``invent up`` records its run so); ``bus``: the
    process's intra-process delivery, when services are composed (services/runtime/intraprocess.py)."""
    command, config = plan.command, plan.config
    journal = _journal(plan.journaling, command.service, config.record)
    lockstep = config.sim.mode == SimMode.LOCKSTEP
    keys = Keys(config.robot.name)
    node = Node(
        session,
        keys,
        command.service,
        executor=executor,
        journal=journal,
        bus=bus,
        congestion=congestion(lockstep),
        interface=declared(command.service, keys, config) if isinstance(command.service, Service) else None,
    )
    try:
        return node, command.factory(node, config, plan.options)
    except BaseException:
        node.close()
        raise


def _journal(journaling: Journaling, service: ServiceName, record: RecordConfig) -> Journal | None:
    directory = journaling.directory
    if directory is None:
        return None
    try:
        return Journal(
            journal_path(directory, str(service)),
            journal_limits(record, journaling.share),
            every_step=record.every_step,
        )
    except OSError as error:
        raise ConfigError(f"--journal {directory}: {error.strerror}") from None


def journal_limits(record: RecordConfig, share: int) -> JournalLimits:
    """A journal's limits under ``record``, ``share`` journals of a run sharing ``record.max_size``."""
    return JournalLimits(
        max_bytes=record.journal_max_bytes(share),
        file_bytes=record.journal_file_bytes(share),
        max_stamp_ns=None if record.max_duration is None else round(record.max_duration * NANOSECONDS_PER_SECOND),
        min_free_bytes=round(record.min_free_disk * MB),
    )


def run_service(plan: ServicePlan, session: zenoh.Session, stop: threading.Event) -> int:
    node, service = start_service(plan, session)
    settle_garbage_collector(plan.config.rt)
    try:
        if isinstance(service, ClockedService):
            return service.run(stop)
        node.serve(stop, lambda: service.finished)
        return service.exit_code if service.finished else 0
    finally:
        service.close()
        node.close()
