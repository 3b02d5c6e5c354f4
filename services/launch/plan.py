"""What a run of ``invent up`` is asked to do, as typed values (the command line builds them from
its flags: services/cli/up.py): how its processes connect, the robot description as given (the
children load it themselves from the same flags), and the run's own choices."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.config import Config, ConfigError, SimMode, load_config, parse_override, parse_sim_set
from services.launch.restart import RestartPlan

GOALS = "goals"
"""What a ``--goals`` run's summary names as its scenario (the drive's ``drive/outcome`` says the same)."""
DEPLOYMENT_SETTINGS = ("record.keep=newest",)
"""What a deployment's run (``--loop``, goal mode) sets first, before every ``--set`` (which may
override it): its recording keeps the newest files within its budget (docs/recording.md)."""
DEFAULT_SCENARIO = "square"
"""The scenario of ``invent up`` when no ``--scenario`` (or goal mode) says otherwise."""


@dataclass(frozen=True)
class Connection:
    """How the run's processes reach zenoh: ``--connect``, ``--listen``, ``--zenoh-config``, ``--log-level``."""

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    zenoh_config: str | None = None
    log_level: str = "info"


@dataclass(frozen=True)
class Description:
    """The robot description as the command line gives it: ``--robot``, ``--config``, each
    ``--set SECTION.KEY=VALUE`` (passed on to every child as given) and ``--rt``."""

    robot: str | None = None
    config: str | None = None
    settings: tuple[str, ...] = ()
    rt: bool = False

    def overrides(self) -> dict[str, Any]:
        """What it sets over the description file: ``--set``, then ``--robot`` and ``--rt``."""
        overrides: dict[str, Any] = {}
        for text in self.settings:
            key, value = parse_override(text)
            overrides[key] = value
        overrides["robot.name"] = self.robot
        if self.rt:
            overrides["rt.enabled"] = True
        return overrides

    def load(self) -> Config:
        """The robot description: the file, then :meth:`overrides` (ConfigError names the field)."""
        return load_config(self.config, self.overrides())


@dataclass(frozen=True)
class UpPlan:
    """One run of ``invent up``: one robot, or with ``fleet`` every robot of a fleet file."""

    connection: Connection = field(default_factory=Connection)
    description: Description = field(default_factory=Description)
    scenario: str = DEFAULT_SCENARIO
    scenario_given: bool = False
    """Whether ``--scenario`` was given (a service that drives refuses it: one velocity source per robot)."""
    fleet: str | None = None
    mode: SimMode | None = None
    report: Path | None = None
    no_record: bool = False
    gui: bool = False
    view: int | None = None
    """The port of the live view (``--view``), or None for none."""
    strict: bool = False
    loop: bool = False
    secure: bool = False
    tls: bool = False
    ros2: bool = False
    record_ros2: bool = False
    teleop: bool = False
    goals: bool = False
    """``--goals``: each robot's drive in goal mode (``invent drive --goals``), no scenario, until Ctrl-C."""
    goal_file: str | None = None
    """``--goal-file FILE``: goal mode with the goals of FILE (``invent drive --goal-file``), ending when the drive does."""
    composed: bool = False
    split: bool = False
    """``--split``: a realtime run's sim and motor as two processes, not composed in ``invent control``."""
    workers: int | None = None
    intra_process: bool = True
    with_services: tuple[str, ...] = ()
    """``--with FILE.py:NAME``, each a user service run beside the loop (services/extension/)."""
    restarts: RestartPlan = field(default_factory=RestartPlan)
    """``--restart``, ``--restart-limit``, ``--restart-backoff``: which services are started again when
    they fail (default: none; services/launch/restart.py)."""
    sim_set: tuple[str, ...] = ()
    """``--sim-set SECTION.KEY=VALUE``, as given (keys of :data:`services.config.SIM_BODY_KEYS`): the
    simulated body's own settings, given to the sim alone after the common ``--set``."""

    def check(self) -> None:
        """ConfigError (exit 2) naming what this plan asks that no run can do, whether its flags or
        its stack file (services/launch/stack.py) said it; the launcher checks the rest as it starts."""
        parse_sim_set(self.sim_set)  # a key outside SIM_BODY_KEYS, or not KEY=VALUE
        if self.sim_set and self.fleet:
            raise ConfigError(
                "--sim-set with --fleet: a fleet's simulated robots are described by the fleet file; --sim-set "
                "changes one robot's simulated body"
            )
        if self.restarts.restarts_any and self.composed and not self.with_services:
            raise ConfigError(
                "--restart with --composed: the services run as threads of this one process and share its session; "
                "one that fails cannot be started again alone (run them as processes, without --composed; the "
                "services of your own beside a composed run, --with, are processes and can be)"
            )

    def sim_config(self) -> Config:
        """The sim's description: the robot's, then :attr:`sim_set`; ConfigError naming the ``--sim-set``
        that makes it invalid."""
        description = self.description
        try:
            return dataclasses.replace(description, settings=(*description.settings, *self.sim_set)).load()
        except ConfigError as error:
            raise ConfigError(
                f"--sim-set {' '.join(self.sim_set)}: the simulated robot's description: {error}"
            ) from None

    @property
    def goal_mode(self) -> bool:
        """Whether the drives run goals (``--goals`` or ``--goal-file``) instead of a scenario."""
        return self.goals or self.goal_file is not None

    @property
    def until_interrupted(self) -> bool:
        """Whether the run goes on until Ctrl-C (``--loop``, ``--teleop``, ``--goals`` without a goal file)."""
        return self.loop or self.teleop or (self.goals and self.goal_file is None)

    @property
    def drive_runs(self) -> str:
        """What the drives run, as the run's summary names it: ``goals``, the goal file, or the scenario."""
        if self.goal_file is not None:
            return self.goal_file
        return GOALS if self.goals else self.scenario
