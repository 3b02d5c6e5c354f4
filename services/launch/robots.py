"""What a run of ``invent up`` of one robot and a run of a fleet differ in, given to the one
sequence both go through (services/launch/up.py): the robots it starts (:class:`Robot`), and what
their run does its own way (:class:`Robots`: the one robot, services/launch/one_robot.py, or a
fleet's, services/launch/fleet.py), including how it watches them once the sim runs (:class:`Watch`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from schemas.keys import UserServiceName
from schemas.status import SimStatus
from services.config import Config
from services.drive.outcome import Outcome
from services.extension.loader import Loaded
from services.launch.plan import Description
from services.launch.run import Access, Outcomes, Run
from services.recording.report import degradations
from services.security import Role


@dataclass(frozen=True)
class Robot:
    """One robot of a run, as its services are started: the one robot of ``invent up`` (the run's
    own flags describe it) or a fleet's (``in_fleet``: its children, folders and lines go under its name)."""

    name: str
    config: Config
    scenario: str
    settings: tuple[str, ...] = ()
    """What its services' description sets after the run's (each ``SECTION.KEY=VALUE``): a fleet robot's own."""
    bridge_settings: tuple[str, ...] = ()
    """What its ROS 2 bridge's sets after those: a fleet robot's namespace and frames."""
    in_fleet: bool = False
    goal_file: str | None = None
    """A fleet robot's own goal file (the fleet file's ``goals``): its drive plays it instead of a scenario."""
    extensions: tuple[Loaded, ...] = ()
    """Its services of the user's own (``--with``; a fleet file's ``with``), run beside its loop."""

    @property
    def participants(self) -> tuple[UserServiceName, ...]:
        """Its user services taking part in lockstep: the sim waits for them before its first step."""
        return tuple(loaded.name for loaded in self.extensions if loaded.service.lockstep is not None)

    def child(self, service: str) -> str:
        """The name its ``service``'s child runs under (and its output is prefixed with)."""
        return f"{self.name}/{service}" if self.in_fleet else str(service)

    def folder(self, directory: Path) -> Path:
        """Its own part of ``directory``: a fleet robot's folder of its name, the one robot's the directory itself."""
        return directory / self.name if self.in_fleet else directory

    def description(self, run: Description) -> Description:
        """Its services' description: the run's, and a fleet robot's name and own settings after it."""
        if not self.in_fleet:
            return run
        return dataclasses.replace(run, robot=self.name, settings=(*run.settings, *self.settings))

    def credentials(self, access: Access, role: Role) -> str | None:
        """The file its service of ``role`` connects with: a fleet robot's own credentials when secure."""
        return access.config_file(role, self.name if self.in_fleet else None)

    def user_credentials(self, access: Access, name: str) -> str | None:
        """The file its service of one's own ``name`` connects with: a fleet robot's own credentials when secure."""
        return access.user_service_file(name, self.name if self.in_fleet else None)

    def label(self, line: str) -> str:
        """``line`` about this robot as ``up`` prints it: a fleet robot's prefixed with its name."""
        return f"{self.name}: {line}" if self.in_fleet else line


def robot_degradations(health: dict[str, Any]) -> list[str]:
    """What degraded a robot's part of the run: its services that ended early, then the loop's health."""
    lost = [f"{service} ended early ({how})" for service, how in health.get("lost_services", {}).items()]
    return [*lost, *degradations(health)]


class Watch(Protocol):
    """How a run watches its robots once the sim runs, and what it takes from them at the end."""

    def supervise(self, started: float, between_looks: Callable[[], None] | None, until_interrupted: bool) -> None:
        """Until the run is over (or, ``until_interrupted``, Ctrl-C), printing progress and calling ``between_looks``."""

    def health(self, robot: str) -> tuple[SimStatus | None, dict[str, Any]]:
        """``robot``'s last sim status and its loop's health, from its services' last status replies."""

    def outcomes(self, published: Outcomes) -> dict[str, Outcome]:
        """Each robot whose drive ended its scenario, and how."""

    def ended(self, child: str) -> bool:
        """Whether ``child`` ended before the run did as the run allows: its exit code is not unclean."""


class Robots(Protocol):
    """The robots of a run and what their run does its own way; checked (ConfigError: exit 2)
    before anything starts."""

    each: tuple[Robot, ...]
    scene: tuple[Config, ...]
    """Every robot's description for ``run.mcap``'s scene; empty for the one robot (the first's is the scene)."""
    records_statuses: bool
    """Whether ``up`` records its services' status replies in ``run.mcap``."""
    view_flags: list[str]
    """What the live view is given beyond the run's flags and its credentials."""
    fleet_file: str | None
    """The fleet file whose robots the sim simulates; None: the one robot."""
    teleop_line: str
    """What ``--teleop`` says as the sim starts."""

    def access(self, report_dir: Path) -> Access:
        """The run's :class:`Access`; with ``--secure``, its profile is written before anything starts."""

    def assignment(self) -> dict[str, int] | None:
        """A composed run's robots over worker processes (services/launch/worker.py), or None for one process."""

    def drive_waits(self, driven: Sequence[Robot]) -> list[list[str]]:
        """The liveliness tokens to wait for, in turn, once ``driven``'s drives are started."""

    def started_line(self, mode: str) -> str | None:
        """What ``up`` says once the sim has started, if anything."""

    def watch(self, run: Run, drives: dict[str, Any]) -> Watch:
        """How the run watches them, given each driven robot's drive child."""

    def health_lines(self, health: dict[str, dict[str, Any]]) -> list[str]:
        """What a run with no report prints of its robots' health beyond what degraded."""

    def report(self, report_dir: Path) -> tuple[list[str], str]:
        """Print the run's report made of ``run.mcap``; what degraded, and the line saying what was written."""
