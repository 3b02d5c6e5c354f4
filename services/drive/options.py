"""What ``invent drive`` drives (:class:`DriveOptions`: a scenario, a twist, waypoints or goals),
made from what names it, and the check a drive's description passes before anything starts. Pure:
the shell (services/drive/service.py) drives them."""

from __future__ import annotations

from dataclasses import dataclass

from services.config import Config
from services.drive.goal_file import GoalFile, load_goal_file
from services.drive.scenarios import Scenario, load_scenario
from services.navigation.map_file import read_map

GOALS_MODE = "goals"


@dataclass(frozen=True)
class DriveOptions:
    """What ``invent drive`` drives: ``mode`` (``constant``, ``twist``, ``scenario``,
    ``waypoints`` or ``goals``, as its status says), the scenario, whether it starts over when it
    ends; in goal mode, the goal file (None: goals come only from queries)."""

    mode: str
    scenario: Scenario | None
    """None in goal mode."""
    loop: bool = False
    goal_file: GoalFile | None = None
    source: str | None = None
    """The scenario (a built-in's name or a file) or the goal file as given: what names it on a
    command line (services/launch/service_plans.py)."""


def scenario_options(scenario: str, loop: bool = False) -> DriveOptions:
    """The scenario ``scenario`` names (a built-in or a file; ConfigError naming it), over and over with ``loop``."""
    return DriveOptions("scenario", load_scenario(scenario), loop, source=scenario)


def goal_options(goal_file: str | None = None) -> DriveOptions:
    """Goal mode: goals from queries, and from ``goal_file`` at its times if given (ConfigError naming it)."""
    return DriveOptions(
        GOALS_MODE, None, goal_file=None if goal_file is None else load_goal_file(goal_file), source=goal_file
    )


def check(config: Config, options: DriveOptions) -> None:
    """A map that goals navigate on must load (exit 2 naming the field before anything starts)."""
    if options.mode == GOALS_MODE and config.navigation.enabled and config.navigation.map is not None:
        read_map(config.navigation.map)
