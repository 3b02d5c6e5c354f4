"""The navigation tests' yardstick (tests/navigation_reference.py) against lengths known in closed
form, and the worlds, goal files and fleet of issue 51 (sim_bridge/worlds/u_trap.toml,
three_rooms.toml, pen.toml, corridor.toml; examples/goals/; examples/fleets/corridor_swap.toml)
measured with it: pure, no zenoh, no simulator."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from services.config import CollisionMonitorConfig, RobotConfig
from services.drive.goal_file import load_goal_file
from services.fleet.description import load_fleet
from sim_bridge.world import Box, Cylinder, World, builtin_worlds, load_world
from tests.navigation_reference import (
    SEGMENTS_PER_QUARTER,
    distance_driven,
    grown_polygons,
    route_length,
    shortest_clear_path,
    shortest_clear_route,
)

REPO = Path(__file__).resolve().parent.parent
GOALS = REPO / "examples" / "goals"
NAVIGATION_WORLDS = ("u_trap", "three_rooms", "pen", "corridor")
CLEARANCE = 0.5
OVER_AT_MOST = math.tan(math.pi / 4 / SEGMENTS_PER_QUARTER) / (math.pi / 4 / SEGMENTS_PER_QUARTER)
"""How much longer than the true shortest path the reference's may be (on its arcs): 1.0032."""


def _world(*boxes: tuple[float, float, float, float, float], cylinders: tuple[tuple[float, float, float], ...] = ()):
    """A world of boxes ``(x, y, length, width, yaw)`` and cylinders ``(x, y, radius)``."""
    return World(
        boxes=tuple(
            Box(name=f"b{i}", x=x, y=y, size=(length, width, 0.5), yaw=yaw)
            for i, (x, y, length, width, yaw) in enumerate(boxes)
        ),
        cylinders=tuple(
            Cylinder(name=f"c{i}", x=x, y=y, radius=r, height=0.5) for i, (x, y, r) in enumerate(cylinders)
        ),
    )


def _distance_to(obstacle: Box | Cylinder, point: tuple[float, float]) -> float:
    """The exact distance from ``point`` to ``obstacle``'s footprint on the floor."""
    dx, dy = point[0] - obstacle.x, point[1] - obstacle.y
    if isinstance(obstacle, Cylinder):
        return max(0.0, math.hypot(dx, dy) - obstacle.radius)
    c, s = math.cos(obstacle.yaw), math.sin(obstacle.yaw)
    along, across = c * dx + s * dy, -s * dx + c * dy
    return math.hypot(max(abs(along) - obstacle.size[0] / 2, 0.0), max(abs(across) - obstacle.size[1] / 2, 0.0))


def _clearance_of(world: World, route: list[tuple[float, float]]) -> float:
    """The least distance from the route (its corners and points 1 cm apart on each leg) to an obstacle."""
    points = [route[0]]
    for a, b in itertools.pairwise(route):
        steps = max(1, math.ceil(math.dist(a, b) / 0.01))
        points += [(a[0] + (b[0] - a[0]) * k / steps, a[1] + (b[1] - a[1]) * k / steps) for k in range(1, steps + 1)]
    obstacles: list[Box | Cylinder] = [*world.boxes, *world.cylinders]
    return min(_distance_to(obstacle, point) for obstacle in obstacles for point in points)


def _bracket(world: World, start, goal, clearance: float = CLEARANCE) -> tuple[float, float]:
    """The reference's length (outer polygons) and the inner polygons' (a lower bound of the true one)."""
    outer = shortest_clear_route(world, start, goal, clearance)
    inner = shortest_clear_route(world, start, goal, clearance, outer=False)
    assert outer is not None and inner is not None
    return route_length(outer), route_length(inner)


def _rotated(point: tuple[float, float], angle: float) -> tuple[float, float]:
    c, s = math.cos(angle), math.sin(angle)
    return (c * point[0] - s * point[1], s * point[0] + c * point[1])


# --- the reference against lengths known in closed form ---


@pytest.mark.parametrize(
    ("start", "goal"), [((0.0, 0.0), (5.0, 0.0)), ((-3.0, 2.0), (4.0, -1.5)), ((1.0, 1.0), (1.0, 1.0))]
)
def test_in_free_space_the_shortest_path_is_the_straight_line(start, goal):
    assert shortest_clear_path(load_world("empty"), start, goal) == pytest.approx(math.dist(start, goal), abs=1e-12)
    # an obstacle off to the side, further than the clearance from the line, changes nothing
    aside = _world((1.0, 3.0, 1.0, 1.0, 0.3), cylinders=((2.0, -3.0, 0.4),))
    assert shortest_clear_path(aside, start, goal) == pytest.approx(math.dist(start, goal), abs=1e-12)


@pytest.mark.parametrize(("radius", "clearance", "distance"), [(0.3, 0.5, 3.0), (0.1, 0.5, 1.5), (1.0, 0.25, 4.0)])
def test_around_a_cylinder_the_length_is_two_tangents_and_an_arc(radius, clearance, distance):
    grown = radius + clearance
    # from (-d, 0) to (d, 0) around a disc of radius R at the origin: each tangent sqrt(d^2 - R^2)
    # long, touching the disc acos(R / d) from the axis; the arc between them pi - 2 acos(R / d)
    exact = 2 * math.sqrt(distance**2 - grown**2) + grown * (math.pi - 2 * math.acos(grown / distance))
    world = _world(cylinders=((0.0, 0.0, radius),))
    outer, inner = _bracket(world, (-distance, 0.0), (distance, 0.0), clearance)
    assert inner <= exact <= outer <= exact * OVER_AT_MOST
    assert outer == pytest.approx(exact, rel=0.005)


@pytest.mark.parametrize("yaw", [0.0, 0.4, math.pi / 2, 2.5])
@pytest.mark.parametrize(("thickness", "half_length", "clearance"), [(0.1, 1.0, 0.5), (0.6, 1.5, 0.3), (2.0, 0.5, 0.5)])
def test_around_a_wall_the_length_is_tangents_arcs_and_its_thickness(yaw, thickness, half_length, clearance):
    # a wall across the line from (-d, 0) to (d, 0): over its near corner's circle (radius c about
    # (-t/2, h)), along its top at y = h + c for its thickness, down the far corner's: each tangent
    # sqrt(D^2 - c^2) with D the distance to the corner, each arc the angle the path turns there
    d = 3.0
    to_corner = math.hypot(d - thickness / 2, half_length)
    turn = math.atan2(half_length, d - thickness / 2) + math.asin(clearance / to_corner)
    exact = 2 * (math.sqrt(to_corner**2 - clearance**2) + clearance * turn) + thickness
    # the whole scene turned by yaw about the origin: the same length
    world = _world((0.0, 0.0, thickness, 2 * half_length, yaw))
    start, goal = _rotated((-d, 0.0), yaw), _rotated((d, 0.0), yaw)
    outer, inner = _bracket(world, start, goal, clearance)
    assert inner <= exact + 1e-9 and exact <= outer <= exact * OVER_AT_MOST
    assert outer == pytest.approx(exact, rel=0.005)
    route = shortest_clear_route(world, start, goal, clearance)
    assert route is not None and _clearance_of(world, route) >= clearance - 1e-9


def test_a_gap_is_driven_through_only_if_it_is_wider_than_twice_the_clearance():
    def gap(width: float) -> World:  # two boxes 2 m long across the line, ``width`` apart at y = 0
        return _world((2.0, 1.0 + width / 2, 0.2, 2.0, 0.0), (2.0, -1.0 - width / 2, 0.2, 2.0, 0.0))

    assert shortest_clear_path(gap(1.2), (0.0, 0.0), (4.0, 0.0)) == pytest.approx(4.0, abs=1e-12)
    assert shortest_clear_path(gap(1.0), (0.0, 0.0), (4.0, 0.0)) == pytest.approx(4.0, abs=1e-12)  # just
    narrow = shortest_clear_path(gap(0.9), (0.0, 0.0), (4.0, 0.0))
    assert narrow is not None and narrow > 5.0  # around one of them


def test_no_path_when_the_start_or_the_goal_is_too_close_to_an_obstacle_or_the_goal_is_closed_off():
    box = _world((2.0, 0.0, 1.0, 1.0, 0.0))
    assert shortest_clear_path(box, (1.2, 0.0), (5.0, 0.0)) is None  # 0.3 m from the box
    assert shortest_clear_path(box, (0.0, 0.0), (2.0, 0.7)) is None
    corners = math.hypot(1.5, 0.5) + 1.0 + math.hypot(2.5, 0.5)  # clearance 0: over the box's corners
    assert shortest_clear_path(box, (0.0, 0.0), (5.0, 0.0), clearance=0.0) == pytest.approx(corners, abs=1e-9)
    ring = _world(*((math.cos(a) * 2.0, math.sin(a) * 2.0, 0.1, 1.2, a) for a in np.linspace(0, math.tau, 16)[:-1]))
    assert shortest_clear_path(ring, (0.0, 0.0), (5.0, 0.0), clearance=0.0) is None
    assert shortest_clear_path(ring, (0.0, 0.0), (0.5, 0.0), clearance=0.0) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="clearance"):
        grown_polygons(box, -0.1)


def test_the_distance_driven_is_the_length_of_the_track():
    assert distance_driven([]) == 0.0
    assert distance_driven([(1.0, 2.0)]) == 0.0
    square = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
    assert distance_driven(square) == pytest.approx(4.0)
    assert distance_driven([(x, y, 0.3) for x, y in square]) == pytest.approx(4.0)  # headings ignored
    assert distance_driven(iter([(0.0, 0.0), (3.0, 4.0)])) == pytest.approx(5.0)
    back_and_forth = [(0.0, 0.0), (1.0, 0.0), (0.0, 0.0)]
    assert distance_driven(back_and_forth) == pytest.approx(2.0)


# --- the worlds of issue 51 ---


def _start(world: World) -> tuple[float, float]:
    return (world.initial_pose.x, world.initial_pose.y)


def _goals(name: str) -> list[tuple[float, float]]:
    goal_file = load_goal_file(str(GOALS / f"{name}.toml"))
    return [(entry.x, entry.y) for entry in goal_file.goals if entry.x is not None and entry.y is not None]


def _clear_of_everything(world: World, point: tuple[float, float]) -> float:
    obstacles: list[Box | Cylinder] = [*world.boxes, *world.cylinders]
    return min(_distance_to(obstacle, point) for obstacle in obstacles)


@pytest.mark.parametrize("name", NAVIGATION_WORLDS)
def test_each_navigation_world_is_built_in_commented_of_solid_walls_with_its_start_clear(name):
    path = builtin_worlds()[name]
    assert path.read_text().startswith("# Navigation test world (issue 51): ")
    world = load_world(name)
    assert world.boxes and not world.cylinders
    for box in world.boxes:
        assert min(box.size[:2]) >= 0.1 and box.size[2] >= 0.5 and box.mass == 0.0, box.name
    # the robot starts at the origin facing +x, nothing within its collision monitor's slow-down
    # zone in any direction (the body's radius, the margin and the slow-down distance)
    assert (world.initial_pose.x, world.initial_pose.y, world.initial_pose.theta) == (0.0, 0.0, 0.0)
    monitor = CollisionMonitorConfig()
    reach = RobotConfig().radius_of_body_area + monitor.margin + monitor.slow_distance
    assert _clear_of_everything(world, _start(world)) > reach


def test_u_trap_the_straight_line_leads_into_the_u_and_the_way_around_is_longer():
    world = load_world("u_trap")
    start, (goal,) = _start(world), _goals("u_trap")
    assert goal == (5.0, 0.0)
    back = next(box for box in world.boxes if box.name == "u_back")
    assert back.x - back.size[0] / 2 > start[0] and abs(back.y - goal[1]) < back.size[1] / 2  # across the line
    # inside, 2.0 m wide and 1.5 m deep, the robot fits with 0.5 m to spare each side: straight in
    arms = sorted((box for box in world.boxes if box.name != "u_back"), key=lambda box: box.y)
    inside = (arms[1].y - arms[1].size[1] / 2) - (arms[0].y + arms[0].size[1] / 2)
    assert inside == pytest.approx(2.0) and inside > 2 * CLEARANCE
    assert shortest_clear_path(world, start, (2.4, 0.0)) == pytest.approx(2.4)
    length = shortest_clear_path(world, start, goal)
    assert length is not None and 6.3 < length < 6.45 and length > 1.25 * math.dist(start, goal)
    route = shortest_clear_route(world, start, goal)
    assert route is not None and _clearance_of(world, route) >= CLEARANCE - 1e-9
    assert max(abs(y) for _, y in route) > 1.5  # around an arm: outside the U (|y| >= 1.1 + 0.5)


def _door(world: World, x: float) -> tuple[float, float]:
    """The opening in the inner wall at ``x``: from the wall's end to the outer wall's inner face."""
    (wall,) = (box for box in world.boxes if box.x == x)
    inner = [box for box in world.boxes if box.name in ("wall_south", "wall_north")]
    low = max(box.y + box.size[1] / 2 for box in inner if box.y < 0)
    high = min(box.y - box.size[1] / 2 for box in inner if box.y > 0)
    top, bottom = wall.y + wall.size[1] / 2, wall.y - wall.size[1] / 2
    return (top, high) if bottom <= low + 1e-9 else (low, bottom)


def test_three_rooms_doors_are_1_8_m_wide_not_in_line_and_the_path_bends_through_both():
    world = load_world("three_rooms")
    first, second = _door(world, 2.0), _door(world, 6.0)
    assert first == pytest.approx((0.15, 1.95)) and second == pytest.approx((-1.95, -0.15))
    assert first[1] - first[0] == pytest.approx(1.8) and second[1] - second[0] == pytest.approx(1.8)
    assert first[0] > 0.0 > second[1]  # the straight line y = 0 meets both walls
    start = _start(world)
    room_3, home = _goals("three_rooms")
    assert 6.05 < room_3[0] < 9.95 and home == start
    there = shortest_clear_path(world, start, room_3)
    back = shortest_clear_path(world, room_3, home)
    assert there is not None and back == pytest.approx(there, rel=1e-9)
    assert 8.35 < there < 8.5
    route = shortest_clear_route(world, start, room_3)
    assert route is not None and _clearance_of(world, route) >= CLEARANCE - 1e-9
    crossings = {x: np.interp(x, [p[0] for p in route], [p[1] for p in route]) for x in (2.0, 6.0)}
    assert first[0] + CLEARANCE - 1e-9 <= crossings[2.0] <= first[1] - CLEARANCE + 1e-9
    assert second[0] + CLEARANCE - 1e-9 <= crossings[6.0] <= second[1] - CLEARANCE + 1e-9
    # the walls all round: nothing outside is reachable
    assert shortest_clear_path(world, start, (4.0, 3.0)) is None


def test_the_pen_is_closed_and_the_room_lets_the_robot_drive_all_round_it():
    world = load_world("pen")
    start, (inside,) = _start(world), _goals("pen")
    assert inside == (3.5, 0.0)
    pen = [box for box in world.boxes if box.name.startswith("pen_")]
    assert len(pen) == 4
    assert min(_distance_to(box, inside) for box in pen) == pytest.approx(1.0)  # 2 m x 2 m inside, empty
    assert shortest_clear_path(world, start, inside) is None
    assert shortest_clear_path(world, start, inside, clearance=0.0) is None  # closed, not only narrow
    # beyond each side of the pen: reachable, the way round about as long either side
    for point in ((3.5, 2.0), (5.5, 0.0), (3.5, -2.0), (1.5, 0.0)):
        route = shortest_clear_route(world, start, point)
        assert route is not None and _clearance_of(world, route) >= CLEARANCE - 1e-9, point
    across = shortest_clear_route(world, (5.5, 0.0), (1.5, 0.0))
    assert across is not None and max(abs(y) for _, y in across) >= 1.1 + CLEARANCE - 1e-9  # round the pen
    assert shortest_clear_path(world, start, (-3.0, 0.0)) is None  # the room's walls all round


def test_the_corridor_is_3_m_wide_12_m_long_and_closed():
    world = load_world("corridor")
    south, north = (next(box for box in world.boxes if box.name == name) for name in ("wall_south", "wall_north"))
    west, east = (next(box for box in world.boxes if box.name == name) for name in ("wall_west", "wall_east"))
    assert (north.y - north.size[1] / 2) - (south.y + south.size[1] / 2) == pytest.approx(3.0)
    assert (east.x - east.size[0] / 2) - (west.x + west.size[0] / 2) == pytest.approx(12.0)
    start = _start(world)
    assert shortest_clear_path(world, start, (5.4, 0.9)) is not None
    assert (
        shortest_clear_path(world, start, (0.0, 3.0)) is None and shortest_clear_path(world, start, (8.0, 0.0)) is None
    )


def test_the_corridor_swap_starts_both_robots_head_on_on_the_centre_line_each_to_the_others_start():
    fleet = load_fleet(REPO / "examples" / "fleets" / "corridor_swap.toml")
    assert fleet.world == "corridor"
    world = load_world(fleet.world)
    rh0, rh1 = fleet.robots
    assert (rh0.start.y, rh1.start.y) == (0.0, 0.0) and rh0.start.x < 0.0 < rh1.start.x
    assert rh0.start.theta == 0.0 and rh1.start.theta == pytest.approx(math.pi)
    for robot, other in ((rh0, rh1), (rh1, rh0)):
        assert robot.scenario is None and robot.goals is not None
        (goal,) = ((entry.x, entry.y) for entry in load_goal_file(str(REPO / robot.goals)).goals if entry.x is not None)
        assert goal == (other.start.x, other.start.y)
        start = (robot.start.x, robot.start.y)
        monitor = CollisionMonitorConfig()
        assert _clear_of_everything(world, start) > RobotConfig().radius_of_body_area + monitor.margin + 0.8
        # alone in the corridor each would drive straight: the other robot is the only obstacle
        assert shortest_clear_path(world, start, goal) == pytest.approx(math.dist(start, goal))
    # each axle centre 0.5 m from its wall, the two are 2 m apart: each body 0.5 m and more from the other
    south, north = (next(box for box in world.boxes if box.name == name) for name in ("wall_south", "wall_north"))
    width = (north.y - north.size[1] / 2) - (south.y + south.size[1] / 2)
    assert width - 2 * CLEARANCE >= RobotConfig().radius_of_body_area + CLEARANCE + 1.0


@pytest.mark.parametrize(
    ("name", "start", "goal"),
    [("u_trap", (0.0, 0.0), (5.0, 0.0)), ("three_rooms", (0.0, 0.0), (8.0, 0.0)), ("pen", (0.0, 0.0), (5.5, 0.0))],
)
def test_in_each_world_the_reference_is_within_a_fraction_of_a_percent_of_the_true_length(name, start, goal):
    outer, inner = _bracket(load_world(name), start, goal)
    assert inner <= outer <= inner * OVER_AT_MOST  # the true length lies between the two
