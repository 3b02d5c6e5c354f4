"""A loaded user service run as any service is (services/service.py): its :class:`ServiceCommand`,
whose factory builds the :class:`~services.extension.api.Context` on the service's node, calls the
class's ``__init__``, starts its lockstep participation (or, for a service that drives, its output in
the drive's place: it runs as the drive) and merges its status with the runtime's."""

from __future__ import annotations

from dataclasses import dataclass

from schemas.keys import Service
from services.config import Config, ConfigError
from services.extension.api import Context, UserService
from services.extension.loader import Loaded
from services.runtime.node import Node
from services.service import ServiceCommand


@dataclass(frozen=True)
class UserOptions:
    """``invent service FILE.py:NAME``'s options: the loaded service."""

    loaded: Loaded


class HostedService:
    """A user service as the runtime runs it (a :class:`~services.service.RunningService`)."""

    finished = False
    exit_code = 0

    def __init__(self, node: Node, config: Config, options: UserOptions) -> None:
        loaded = options.loaded
        self.ctx = Context(node, config, loaded.service, self._finish)
        drives = loaded.service.drives
        try:
            if drives is not None:
                self.ctx._start_driving(drives)
            self.user: UserService = loaded.service(self.ctx)
            if loaded.service.lockstep is not None:
                self.ctx._start_lockstep(loaded.service.lockstep)
        except (ValueError, TypeError) as error:
            raise ConfigError(f"{loaded.spec}: {error}") from None
        node.set_status(self.ctx._runtime_status, own=self.user.status)
        lockstep = loaded.service.lockstep
        node.log.info(
            "%s from %s%s",
            loaded.name,
            loaded.spec,
            f": lockstep at {lockstep.rate_hz:g} Hz on {lockstep.output}"
            if lockstep
            else f": drives the robot at {drives.rate_hz:g} Hz, in the drive's place"
            if drives
            else "",
        )

    def _finish(self, exit_code: int) -> None:
        self.finished = True
        self.exit_code = exit_code

    def close(self) -> None:
        self.user.close()


def command(loaded: Loaded) -> ServiceCommand[UserOptions]:
    """What runs ``loaded`` (its options: :class:`UserOptions`): as the drive, if it drives."""
    return ServiceCommand(service=Service.DRIVE if loaded.service.drives else loaded.name, factory=HostedService)
