"""World files: the ground, optional obstacles and the robot's initial pose (TOML).

Loading is strict (msgspec): an unknown key, a wrong type, a value out of range, a missing
or duplicate obstacle name raises :class:`~services.config.ConfigError` naming the field, so
``invent sim`` exits with code 2. ``docs/sim.md`` documents the format; the built-in worlds
live in ``sim_bridge/worlds/`` and can be named without a path (``--world bump``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import msgspec

from schemas.messages import Obstacle
from services.config import ConfigError, NonNegative, Positive, convert_toml, require_finite_fields

Name = Annotated[str, msgspec.Meta(min_length=1)]

DEFAULT_WORLD = "empty"
"""The built-in world used when ``sim.world`` is not set: an empty floor."""
WORLD_SUFFIX = ".toml"
WORLDS_FOLDER = Path(__file__).resolve().parent / "worlds"


class _Table(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    def __post_init__(self) -> None:
        require_finite_fields(self)


class Ground(_Table, frozen=True):
    """The floor: an infinite plane at z = 0."""

    friction: NonNegative = 1.0
    """Lateral friction coefficient (PyBullet multiplies it with the wheel's)."""


class InitialPose(_Table, frozen=True):
    """Where the robot's axle centre starts on the floor, and its heading."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class _Standing(_Table, frozen=True):
    """An obstacle standing on the floor, centred on (x, y), named once in its world."""

    name: Name
    x: float
    y: float


class Box(_Standing, frozen=True):
    """A box standing on the floor, centred on (x, y), turned by ``yaw`` about z."""

    size: tuple[Positive, Positive, Positive]
    """Full lengths along the box's own x, y and z, in m."""
    yaw: float = 0.0
    mass: NonNegative = 0.0
    """kg; 0 = fixed in place."""


class Cylinder(_Standing, frozen=True):
    """An upright cylinder standing on the floor, centred on (x, y)."""

    radius: Positive
    height: Positive
    mass: NonNegative = 0.0
    """kg; 0 = fixed in place."""


class World(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    ground: Ground = msgspec.field(default_factory=Ground)
    initial_pose: InitialPose = msgspec.field(default_factory=InitialPose)
    boxes: tuple[Box, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()

    def __post_init__(self) -> None:
        seen: set[str] = set()
        tables: tuple[tuple[str, tuple[Box | Cylinder, ...]], ...] = (
            ("boxes", self.boxes),
            ("cylinders", self.cylinders),
        )
        for table, obstacles in tables:
            for index, obstacle in enumerate(obstacles):
                if obstacle.name in seen:
                    raise ValueError(f"`{table}[{index}].name`: obstacle name {obstacle.name!r} is used twice")
                seen.add(obstacle.name)


def obstacles(world: World) -> list[Obstacle]:
    """The world's obstacles as ``sim/world`` describes them."""
    boxes = [Obstacle(box.name, "box", box.x, box.y, box.yaw, box.size) for box in world.boxes]
    cylinders = [
        Obstacle(c.name, "cylinder", c.x, c.y, 0.0, (2.0 * c.radius, 2.0 * c.radius, c.height)) for c in world.cylinders
    ]
    return boxes + cylinders


def builtin_worlds() -> dict[str, Path]:
    """The worlds shipped in ``sim_bridge/worlds/``, by name (file stem)."""
    return {path.stem: path for path in sorted(WORLDS_FOLDER.glob(f"*{WORLD_SUFFIX}"))}


def resolve_world(world: str | None) -> Path:
    """The file for ``sim.world``: a path to a file, or the name of a built-in world (None = the default)."""
    builtins = builtin_worlds()
    if world is None:
        return builtins[DEFAULT_WORLD]
    path = Path(world)
    if path.is_file():
        return path
    if world in builtins:
        return builtins[world]
    raise ConfigError(f"`sim.world`: {world!r} is neither a file nor a built-in world ({', '.join(sorted(builtins))})")


def parse_world(text: str, source: str = "world") -> World:
    """A world from TOML text; ConfigError names ``source`` and the offending field."""
    return convert_toml(text, World, f"world file {source}")


def read_world(path: Path) -> World:
    try:
        text = path.read_text()
    except OSError as error:
        raise ConfigError(f"`sim.world`: {path}: {error.strerror}") from None
    return parse_world(text, str(path))


def load_world(world: str | None) -> World:
    """Load ``sim.world`` (see :func:`resolve_world`)."""
    return read_world(resolve_world(world))
