"""World files: built-in worlds, the format, and strict errors naming the field."""

from pathlib import Path

import pytest

from services.config import ConfigError
from sim_bridge.world import (
    DEFAULT_WORLD,
    Box,
    Cylinder,
    builtin_worlds,
    load_world,
    obstacles,
    parse_world,
    resolve_world,
)


def test_the_default_world_is_an_empty_floor_with_the_robot_at_the_origin():
    world = load_world(None)
    assert resolve_world(None) == builtin_worlds()[DEFAULT_WORLD]
    assert world.boxes == () and world.cylinders == ()
    assert (world.initial_pose.x, world.initial_pose.y, world.initial_pose.theta) == (0.0, 0.0, 0.0)
    assert world.ground.friction == 1.0


def test_the_bump_world_has_a_box_ahead_of_the_robot():
    world = load_world("bump")
    (box,) = world.boxes
    assert box.name == "box"
    assert box.x > world.initial_pose.x and abs(box.y - world.initial_pose.y) < box.size[1] / 2
    assert [o.name for o in obstacles(world)] == ["box"]


def test_a_world_file_is_found_by_path(tmp_path: Path):
    path = tmp_path / "mine.toml"
    path.write_text(
        '[initial_pose]\nx = 1.5\ntheta = 0.5\n[[cylinders]]\nname = "pillar"\nx = 2\ny = 0\nradius = 0.1\nheight = 1\n'
    )
    world = load_world(str(path))
    assert (world.initial_pose.x, world.initial_pose.y, world.initial_pose.theta) == (1.5, 0.0, 0.5)
    assert world.cylinders == (Cylinder(name="pillar", x=2.0, y=0.0, radius=0.1, height=1.0),)


def test_a_full_world_parses_every_table():
    world = parse_world(
        """
        [ground]
        friction = 0.8
        [initial_pose]
        x = -1.0
        y = 2.0
        theta = 3.0
        [[boxes]]
        name = "wall"
        x = 2.0
        y = 0.0
        size = [0.2, 2.0, 0.5]
        yaw = 0.3
        mass = 4.0
        [[cylinders]]
        name = "pillar"
        x = 1.0
        y = 1.0
        radius = 0.1
        height = 0.5
        """
    )
    assert world.ground.friction == 0.8
    assert world.boxes == (Box(name="wall", x=2.0, y=0.0, size=(0.2, 2.0, 0.5), yaw=0.3, mass=4.0),)
    assert [o.name for o in obstacles(world)] == ["wall", "pillar"]


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ('[[boxes]]\nname = "b"\nx = "far"\ny = 0\nsize = [1, 1, 1]\n', "boxes[0].x"),
        ('[[boxes]]\nname = "b"\nx = 1\ny = 0\nsize = [1, -1, 1]\n', "boxes[0].size[1]"),
        ('[[boxes]]\nname = "b"\nx = 1\ny = 0\nsize = [1, 1]\n', "boxes[0].size"),
        ("[[boxes]]\nx = 1\ny = 0\nsize = [1, 1, 1]\n", "`name` - at `boxes[0]`"),
        ('[[boxes]]\nname = ""\nx = 1\ny = 0\nsize = [1, 1, 1]\n', "boxes[0].name"),
        ('[[cylinders]]\nname = "c"\nx = 1\ny = 0\nradius = 0\nheight = 1\n', "cylinders[0].radius"),
        (
            '[[cylinders]]\nname = "c"\nx = nan\ny = 0\nradius = 1\nheight = 1\n',
            "`x` must be finite, got nan - at `cylinders[0]`",
        ),
        ("[initial_pose]\nheading = 1.0\n", "`heading` - at `initial_pose`"),
        ("[ground]\nfriction = -1.0\n", "ground.friction"),
        ("[sky]\ncolour = 1\n", "sky"),
    ],
)
def test_a_bad_world_raises_config_error_naming_the_field(text: str, field: str):
    with pytest.raises(ConfigError, match="world file") as error:
        parse_world(text)
    assert field in str(error.value)


def test_obstacle_names_are_unique_across_boxes_and_cylinders():
    text = (
        '[[boxes]]\nname = "thing"\nx = 1\ny = 0\nsize = [1, 1, 1]\n'
        '[[cylinders]]\nname = "thing"\nx = 3\ny = 0\nradius = 1\nheight = 1\n'
    )
    with pytest.raises(ConfigError, match=r"cylinders\[0\]\.name.*'thing'"):
        parse_world(text)


def test_invalid_toml_is_a_config_error():
    with pytest.raises(ConfigError, match="world file"):
        parse_world("[[boxes]\n")


def test_an_unknown_world_names_sim_world_and_the_built_in_worlds(tmp_path: Path):
    with pytest.raises(
        ConfigError, match=r"`sim\.world`.*bump, corridor, empty, living_room, pen, room, three_rooms, u_trap"
    ):
        load_world(str(tmp_path / "missing.toml"))
