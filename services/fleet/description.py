"""The fleet file: one world, several robots, each with its start pose, scenario (or goal file) and overrides.

```toml
world = "empty"                      # as sim.world: a built-in name or a world file
[[robots]]
name = "rh0"
start = { x = 0.0, y = 0.0, theta = 0.0 }
scenario = "square"                  # built-in or file; a built-in runs from this start pose
[[robots]]
name = "rh1"
start = { x = 0.0, y = 3.0, theta = 0.0 }
scenario = "square"
namespace = "robot1"                 # its ROS 2 namespace (default: its name)
set = { "motor.p_gain_l" = 6.0 }     # optional per-robot overrides of the robot description
```

A robot may name a goal file instead of a scenario, ``goals = "examples/goals/swap_west.toml"``:
its drive plays it (``invent drive --goal-file``) and ends by itself with its last goal's outcome.
A robot has a scenario or goals, not both.

Loading is strict, as for the robot description and world files: an unknown key, a wrong type, a
duplicate or invalid robot name, an override that does not fit the robot description raises
:class:`~services.config.ConfigError` naming the field, so the command exits with code 2. The world
is one for all: a robot's overrides may not touch ``sim.*`` (one simulator steps them all) or
``robot.name``. In ROS 2 (``--ros2``) each robot's bridge is in its own namespace, ``namespace``
(default its name; no two alike), and the first robot's bridge publishes ``/clock``, one for the
world (:func:`bridge_overrides`): neither is a robot's ``set``. Pure: no zenoh, no PyBullet.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import msgspec

from schemas.keys import validate_robot_name
from services.config import NAMESPACE, Config, ConfigError, convert_toml, load_config, require_finite_fields

FLEET_WIDE_SECTION = "sim"
"""The section a robot may not override: its parameters are the one simulator's."""
BRIDGE_KEYS = {
    "ros2.namespace": "its ROS 2 namespace is the robot's `namespace` (default its name)",
    "ros2.publish_clock": "the first robot's bridge publishes /clock, one for the world",
}
"""What the fleet sets for each robot's ROS 2 bridge, never a robot's ``set``."""


class Start(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Where a robot's axle centre starts on the floor (m), and its heading (rad)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def __post_init__(self) -> None:
        require_finite_fields(self, prefix="start.")


class FleetRobot(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    name: str
    start: Start = msgspec.field(default_factory=Start)
    scenario: str | None = None
    """A built-in scenario or a scenario file; None: the drive's default (unless ``goals``)."""
    goals: Annotated[str, msgspec.Meta(min_length=1)] | None = None
    """A goal file (docs/drive.md, Goals) its drive plays instead of a scenario; not with ``scenario``."""
    namespace: str | None = None
    """Its ROS 2 namespace (``rh1``: ``/rh1/odom``, ``/rh1/cmd_vel``); None: its name."""
    set: dict[str, Any] = msgspec.field(default_factory=dict)
    """Overrides of the robot description, ``"section.key" = value`` (nested tables are flattened)."""
    with_services: tuple[str, ...] = msgspec.field(default=(), name="with")
    """``with = ["FILE.py:NAME", ...]``: services of one's own for this robot (docs/extending.md)."""


class Fleet(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    world: str | None = None
    """As ``sim.world``: a built-in world's name or a world file; None: the default world."""
    robots: tuple[FleetRobot, ...]
    with_services: tuple[str, ...] = msgspec.field(default=(), name="with")
    """``with = ["FILE.py:NAME", ...]``: services of one's own beside every robot (docs/extending.md)."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(robot.name for robot in self.robots)

    def robot(self, name: str) -> FleetRobot:
        return next(robot for robot in self.robots if robot.name == name)

    def services_of(self, name: str) -> tuple[str, ...]:
        """The services of one's own beside robot ``name``: the fleet-wide ``with``, then its own."""
        return (*self.with_services, *self.robot(name).with_services)

    @property
    def clock_robot(self) -> str:
        """The robot whose ROS 2 bridge publishes ``/clock`` (one for the world): the first."""
        return self.robots[0].name


def ros_namespace(robot: FleetRobot) -> str:
    """``robot``'s ROS 2 namespace as ROS writes it: ``/<namespace>``, by default ``/<name>``."""
    name = robot.name if robot.namespace is None else robot.namespace
    return "/" + name.strip("/")


def _flatten(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"motor": {"p_gain_l": 6}}`` and ``{"motor.p_gain_l": 6}`` alike -> ``{"motor.p_gain_l": 6}``."""
    flat: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{dotted}."))
        else:
            flat[dotted] = value
    return flat


def _check(fleet: Fleet, source: str) -> Fleet:
    if not fleet.robots:
        raise ConfigError(f"fleet file {source}: `robots`: a fleet needs at least one robot")
    seen: set[str] = set()
    namespaces: set[str] = set()
    robots = []
    for index, robot in enumerate(fleet.robots):
        field = f"fleet file {source}: `robots[{index}]"
        try:
            validate_robot_name(robot.name)
        except ValueError as error:
            raise ConfigError(f"{field}.name`: {error}") from None
        if robot.name in seen:
            raise ConfigError(f"{field}.name`: robot name {robot.name!r} is used twice")
        seen.add(robot.name)
        if robot.goals is not None and robot.scenario is not None:
            raise ConfigError(
                f"{field}.goals`: a robot runs a scenario or goals, not both (it has `scenario` = {robot.scenario!r})"
            )
        if robot.namespace is not None and not NAMESPACE.fullmatch(robot.namespace):
            raise ConfigError(
                f"{field}.namespace`: {robot.namespace!r} is not a ROS namespace (names of letters, digits and "
                "underscores, each starting with a letter, joined by /)"
            )
        namespace = ros_namespace(robot)
        if namespace in namespaces:
            raise ConfigError(f"{field}.namespace`: ROS namespace {namespace!r} is used twice")
        namespaces.add(namespace)
        overrides = _flatten(robot.set)
        for key in overrides:
            if key in BRIDGE_KEYS:
                raise ConfigError(f"{field}.set`: {key!r} is the fleet's: {BRIDGE_KEYS[key]}")
            section = key.split(".", 1)[0]
            if section == FLEET_WIDE_SECTION or key == "robot.name":
                raise ConfigError(
                    f"{field}.set`: {key!r} cannot differ between robots "
                    f"({'the name is `name`' if key == 'robot.name' else 'one simulator steps the whole fleet'})"
                )
        robots.append(msgspec.structs.replace(robot, set=overrides))
    return msgspec.structs.replace(fleet, robots=tuple(robots))


def parse_fleet(text: str, source: str = "fleet") -> Fleet:
    """A fleet from TOML text; ConfigError names ``source`` and the offending field."""
    return _check(convert_toml(text, Fleet, f"fleet file {source}"), source)


def load_fleet(path: str | Path) -> Fleet:
    try:
        text = Path(path).read_text()
    except OSError as error:
        raise ConfigError(f"--fleet {path}: {error.strerror}") from None
    return parse_fleet(text, str(path))


def robot_overrides(robot: FleetRobot) -> dict[str, Any]:
    """The robot description's overrides for ``robot``: its own ``set``, its name, and its start
    as the pose the odometry starts from and the localization reports before its first fix."""
    return {
        **robot.set,
        "robot.name": robot.name,
        "localization.initial_x": robot.start.x,
        "localization.initial_y": robot.start.y,
        "localization.initial_theta": robot.start.theta,
        "odometry.initial_x": robot.start.x,
        "odometry.initial_y": robot.start.y,
        "odometry.initial_theta": robot.start.theta,
    }


def bridge_overrides(fleet: Fleet, robot: FleetRobot) -> dict[str, Any]:
    """What ``robot``'s ROS 2 bridge is started with beside :func:`robot_overrides`: its namespace,
    and whether it publishes ``/clock`` (only the :attr:`Fleet.clock_robot`'s does)."""
    return {"ros2.namespace": ros_namespace(robot), "ros2.publish_clock": robot.name == fleet.clock_robot}


def bridge_settings(fleet: Fleet, robot: FleetRobot) -> tuple[str, ...]:
    """:func:`bridge_overrides` as ``--set`` takes them, after :func:`robot_settings`."""
    return tuple(f"{key}={_toml(value)}" for key, value in bridge_overrides(fleet, robot).items())


def bridge_configs(fleet: Fleet, config_path: str | Path | None, overrides: dict[str, Any]) -> dict[str, Config]:
    """Every robot's description as its ROS 2 bridge has it (:func:`bridge_overrides`), by name;
    ConfigError for a robot whose name cannot be its namespace and that has no ``namespace``."""
    for robot in fleet.robots:
        if robot.namespace is None and not NAMESPACE.fullmatch(robot.name):
            raise ConfigError(
                f"fleet robot {robot.name!r}: its name is not a ROS namespace (letters, digits and underscores, "
                "starting with a letter): give it a `namespace` in the fleet file"
            )
    return {
        robot.name: robot_config(robot, config_path, {**overrides, **bridge_overrides(fleet, robot)})
        for robot in fleet.robots
    }


def robot_config(robot: FleetRobot, config_path: str | Path | None, overrides: dict[str, Any]) -> Config:
    """``robot``'s description: the file, ``overrides`` (the command line's), then the robot's own."""
    try:
        return load_config(config_path, {**overrides, **robot_overrides(robot)})
    except ConfigError as error:
        raise ConfigError(f"fleet robot {robot.name!r}: {error}") from None


def fleet_configs(fleet: Fleet, config_path: str | Path | None, overrides: dict[str, Any]) -> dict[str, Config]:
    """Every robot's description (:func:`robot_config`), by name, in the fleet's order."""
    return {robot.name: robot_config(robot, config_path, overrides) for robot in fleet.robots}


def _toml(value: Any) -> str:
    """``value`` as ``--set`` reads it (TOML)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def robot_settings(robot: FleetRobot) -> tuple[str, ...]:
    """What a robot's services are given beside its name, as ``--set`` takes them: its overrides and its start pose."""
    return tuple(f"{key}={_toml(value)}" for key, value in robot_overrides(robot).items() if key != "robot.name")


def sim_overrides(fleet: Fleet) -> dict[str, Any]:
    """What the sim of ``fleet`` takes of it over the description: the fleet's world, if it names
    one, and the first robot's name (the sim's own keys)."""
    return {"robot.name": fleet.robots[0].name, **({"sim.world": fleet.world} if fleet.world else {})}
