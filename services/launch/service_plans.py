"""The services a run starts, as typed plans, and their command lines at the process boundary.

Whatever starts services (``invent up``, a fleet's workers, ``invent calibrate umbmark``) plans
each one as a :class:`ChildPlan`: its command and its options (the dataclass its factory takes),
the robot description as given (``--robot``, ``--config``, each ``--set``, ``--rt``), its journal
and how its process connects. A service composed in a process is built from its plan
(:meth:`ChildPlan.service_plan`, no command line parsed); one in a process of its own is started as
:func:`service_argv` renders its plan, the one place a service's command line is written (the
``invent control`` child's too: :class:`ControlPlan`). tests/test_service_plans.py parses each
rendering back with the command line's parser, for every service and its options: the two agree.
A worker is sent its plans as JSON lines (:func:`encode_plan`, :func:`decode_plan`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path
from typing import Any, Generic

import msgspec

from schemas.keys import CONTROL
from services.config import load_config
from services.drive.options import GOALS_MODE, DriveOptions
from services.drive.service import COMMAND as DRIVE
from services.extension.hosting import UserOptions
from services.fleet.description import load_fleet, robot_config, sim_overrides
from services.launch.plan import Connection, Description
from services.localization.service import COMMAND as LOCALIZATION
from services.motor.service import COMMAND as MOTOR
from services.motor.service import MotorOptions
from services.odometry.service import COMMAND as ODOMETRY
from services.odometry.service import OdometryOptions
from services.ros2.service import COMMAND as ROS2
from services.ros2.service import Ros2Options
from services.service import Journaling, NoOptions, OptionsT, ServiceCommand, ServicePlan
from sim_bridge.bridge import COMMAND as SIM
from sim_bridge.bridge import SimOptions

BUILT_IN: dict[str, tuple[ServiceCommand[Any], type]] = {
    str(command.service): (command, options)
    for command, options in (
        (SIM, SimOptions),
        (MOTOR, MotorOptions),
        (ODOMETRY, OdometryOptions),
        (LOCALIZATION, NoOptions),
        (DRIVE, DriveOptions),
        (ROS2, Ros2Options),
    )
}
"""Each built-in service's command and the type of its options, by name."""


@dataclass(frozen=True)
class ChildPlan(Generic[OptionsT]):
    """One service as a run starts it, under ``name`` (a fleet robot's ``rh0/motor``)."""

    name: str
    command: ServiceCommand[OptionsT]
    options: OptionsT
    description: Description = field(default_factory=Description)
    journaling: Journaling = field(default_factory=Journaling)
    connection: Connection = field(default_factory=Connection)
    """How its process connects; a composed service shares the composition's session."""

    def service_plan(self) -> ServicePlan[OptionsT]:
        """The service to build: the description loaded, with what the options say of it (a fleet
        sim's world and name), checked as ``invent <service>`` checks it (ConfigError: exit 2)."""
        description, options = self.description, self.options
        implied = sim_overrides(options.fleet) if isinstance(options, SimOptions) and options.fleet else {}
        config = load_config(description.config, {**description.overrides(), **implied})
        self.command.check(config, options)
        return ServicePlan(self.command, config, options, self.journaling)


def sim_options(description: Description, fleet_file: str | None = None, **options: Any) -> SimOptions:
    """The sim's options: with ``fleet_file``, every robot of that fleet, each robot's description
    as ``invent sim --fleet`` makes it of ``description``; ``options``: the others."""
    if fleet_file is None:
        return SimOptions(**options)
    fleet = load_fleet(fleet_file)
    given = {**description.overrides(), **sim_overrides(fleet)}
    robots = tuple(robot_config(robot, description.config, given) for robot in fleet.robots)
    return SimOptions(fleet=fleet, fleet_file=fleet_file, fleet_robots=robots, **options)


@dataclass(frozen=True)
class ControlPlan:
    """``invent control``: the sim and the motor in one child process. Both connect, journal and
    are described alike, but for the sim's own settings (``--sim-set``) after the motor's."""

    motor: ChildPlan[MotorOptions]
    sim: SimOptions
    sim_set: tuple[str, ...] = ()
    name: str = CONTROL


def service_argv(child: ChildPlan[Any] | ControlPlan) -> list[str]:
    """``invent <service> ...`` that runs ``child``: its subcommand, connection, description, own
    options and journal (``invent control``'s: both services' options and the sim's ``--sim-set``)."""
    if isinstance(child, ControlPlan):
        motor = child.motor
        own = [*own_flags(child.sim), *own_flags(motor.options), *_repeated("--sim-set", child.sim_set)]
        return [CONTROL, *_process_flags(motor), *own, *_journal_flags(motor.journaling)]
    options = child.options
    command = ["service", options.loaded.spec] if isinstance(options, UserOptions) else [str(child.command.service)]
    return [*command, *_process_flags(child), *own_flags(options), *_journal_flags(child.journaling)]


def _process_flags(child: ChildPlan[Any]) -> list[str]:
    return [*connection_flags(child.connection), *description_flags(child.description)]


def connection_flags(connection: Connection) -> list[str]:
    """``--connect``, ``--listen``, ``--zenoh-config`` and ``--log-level`` as ``connection`` says."""
    return [
        *_repeated("--connect", connection.connect),
        *_repeated("--listen", connection.listen),
        *_valued("--zenoh-config", connection.zenoh_config),
        "--log-level",
        connection.log_level,
    ]


def description_flags(description: Description) -> list[str]:
    """``--robot``, ``--config``, each ``--set`` and ``--rt`` as ``description`` says."""
    return [
        *_valued("--robot", description.robot),
        *_valued("--config", description.config),
        *_repeated("--set", description.settings),
        *(["--rt"] if description.rt else []),
    ]


def own_flags(options: Any) -> list[str]:
    """A service's own flags for its ``options`` (a user service's are none: its file is its argument)."""
    return _OWN_FLAGS[type(options)](options)


def _sim_flags(options: SimOptions) -> list[str]:
    return [
        *_valued("--fleet", options.fleet_file),
        *_valued("--duration", options.duration),
        *(["--until-drive-ends"] if options.until_drive_ends else []),
        *(["--wait-for", *map(str, options.wait_for)] if options.wait_for else []),
        *(["--gui"] if options.gui else []),
    ]


def _drive_flags(options: DriveOptions) -> list[str]:
    """What the drive drives: goals, a scenario by the name it was given, or the scenario the
    flags make (a constant velocity, a twist held, waypoints) from its one segment."""
    loop = ["--loop"] if options.loop else []
    if options.mode == GOALS_MODE:
        return ["--goals"] if options.source is None else ["--goal-file", options.source]
    if options.mode == "scenario":
        return ["--scenario", str(options.source), *loop]
    assert options.scenario is not None, "every mode but goals drives a scenario"
    segment: Any = options.scenario.segments[0]
    if options.mode == "twist":
        return ["--twist", _number(segment.vx), _number(segment.w)]
    if options.mode == "waypoints":
        return [f"--waypoints={' '.join(f'{_number(x)},{_number(y)}' for x, y in segment.waypoints)}", *loop]
    return ["--for", _number(segment.duration), "--vx", _number(segment.vx), "--w", _number(segment.w), *loop]


def _journal_flags(journaling: Journaling) -> list[str]:
    return _journal("--journal", journaling.directory, journaling.share)


def _journal(flag: str, directory: Path | None, share: int) -> list[str]:
    return [*_valued(flag, directory), *([f"{flag}-share", str(share)] if share != 1 else [])]


_OWN_FLAGS: dict[type, Callable[[Any], list[str]]] = {
    SimOptions: _sim_flags,
    MotorOptions: lambda options: [*_valued("--state", options.state), *_valued("--trace", options.trace)],
    OdometryOptions: lambda options: _valued("--trace", options.trace),
    NoOptions: lambda _options: [],
    DriveOptions: _drive_flags,
    Ros2Options: lambda options: _journal("--bag-journal", options.bag_journal, options.bag_journal_share),
    UserOptions: lambda _options: [],
}


def _valued(flag: str, value: Any) -> list[str]:
    if value is None:
        return []
    return [flag, _number(value) if isinstance(value, float) else str(value)]


def _repeated(flag: str, values: tuple[str, ...]) -> list[str]:
    return [part for value in values for part in (flag, value)]


def _number(value: float) -> str:
    """``value`` exactly, without an exponent: the command line takes ``-0.00001`` as a value, ``-1e-05`` as a flag."""
    return format(Decimal(repr(value)), "f")


class _Request(msgspec.Struct, array_like=True):
    name: str
    service: str
    description: Description
    journaling: Journaling
    options: msgspec.Raw


def encode_plan(child: ChildPlan[Any]) -> bytes:
    """``child`` of a built-in service as one JSON line, for a worker (:func:`decode_plan`)."""
    options = msgspec.Raw(msgspec.json.encode(child.options, enc_hook=_encode_path))
    request = _Request(child.name, str(child.command.service), child.description, child.journaling, options)
    return msgspec.json.encode(request, enc_hook=_encode_path)


def decode_plan(line: str | bytes) -> ChildPlan[Any]:
    """The plan :func:`encode_plan` encoded (msgspec.ValidationError for a line that is none)."""
    request = msgspec.json.decode(line, type=_Request, dec_hook=_decode_path)
    command, options_type = BUILT_IN[request.service]
    options: Any = msgspec.json.decode(request.options, type=options_type, dec_hook=_decode_path)
    return ChildPlan(request.name, command, options, request.description, request.journaling)


def _encode_path(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    raise NotImplementedError(f"{type(value).__name__} in a plan")


def _decode_path(type_: type, value: Any) -> Any:
    if type_ is Path:
        return Path(value)
    raise NotImplementedError(f"{type_} in a plan")
