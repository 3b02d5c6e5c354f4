"""The fleet file, a scenario placed at a robot's start, a robot's goal file, and the fleet summary: pure, no zenoh."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.config import ConfigError
from services.drive.goal_file import load_goal_file
from services.drive.scenarios import BUILTIN_SCENARIOS, ConstantSegment, is_builtin, load_scenario, placed
from services.fleet import description
from services.fleet.description import (
    bridge_configs,
    bridge_settings,
    load_fleet,
    parse_fleet,
    robot_config,
    robot_overrides,
    robot_settings,
)
from services.fleet.summary import bumps_between, closest_approach
from services.launch.fleet import FleetRobots
from services.launch.plan import UpPlan
from services.launch.service_plans import own_flags, service_argv
from services.launch.up import _drive_options
from services.launch.worker import robot_plans
from services.planar import Pose

ISSUE_EXAMPLE = description.__doc__.split("```toml\n")[1].split("```")[0]
"""The fleet file of the issue that asked for fleets, as the module documents it."""


def test_the_documented_fleet_file_loads_with_each_robots_start_scenario_and_overrides():
    fleet = parse_fleet(ISSUE_EXAMPLE)
    assert fleet.world == "empty" and fleet.names == ("rh0", "rh1")
    rh1 = fleet.robot("rh1")
    assert (rh1.start.x, rh1.start.y, rh1.start.theta) == (0.0, 3.0, 0.0)
    assert rh1.scenario == "square" and rh1.set == {"motor.p_gain_l": 6.0}
    assert fleet.robot("rh0").set == {}


def test_a_robots_description_is_the_file_then_the_command_line_then_its_own(tmp_path):
    base = tmp_path / "robot.toml"
    base.write_text("[motor]\np_gain_l = 4.0\np_gain_r = 4.5\n")
    fleet = parse_fleet(ISSUE_EXAMPLE)
    rh0 = robot_config(fleet.robot("rh0"), base, {"motor.d_gain_l": 1.5})
    rh1 = robot_config(fleet.robot("rh1"), base, {"motor.d_gain_l": 1.5})
    assert (rh0.motor.p_gain_l, rh1.motor.p_gain_l) == (4.0, 6.0)
    assert rh0.motor.p_gain_r == rh1.motor.p_gain_r == 4.5 and rh1.motor.d_gain_l == 1.5
    assert (rh1.robot.name, rh1.odometry.initial_y, rh1.localization.initial_y) == ("rh1", 3.0, 3.0)


def test_nested_overrides_are_the_dotted_ones():
    fleet = parse_fleet('[[robots]]\nname = "rh0"\nset = { motor = { p_gain_l = 6.0 } }\n')
    assert fleet.robot("rh0").set == {"motor.p_gain_l": 6.0}


@pytest.mark.parametrize(
    ("text", "names"),
    [
        ("robots = []", "`robots`: a fleet needs at least one robot"),
        ('[[robots]]\nname = "rh/0"', "`robots[0].name`"),
        ('[[robots]]\nname = "rh0"\n[[robots]]\nname = "rh0"', "`robots[1].name`: robot name 'rh0' is used twice"),
        ('[[robots]]\nname = "rh0"\nset = { "sim.step" = 0.002 }', "`robots[0].set`: 'sim.step' cannot differ"),
        ('[[robots]]\nname = "rh0"\nset = { "robot.name" = "x" }', "`robots[0].set`: 'robot.name'"),
        ('[[robots]]\nname = "rh0"\nspeed = 1', "speed"),
        ('[[robots]]\nname = "rh0"\nstart = { x = nan }', "start.x"),
        ('world = 3\n[[robots]]\nname = "rh0"', "world"),
        ("[[robots", "fleet file"),
        ('[[robots]]\nname = "rh0"\n[[robots]]\nname = "rh1"\nnamespace = "rh0"', "`robots[1].namespace`: ROS"),
        ('[[robots]]\nname = "rh0"\nnamespace = "1st"', "`robots[0].namespace`: '1st' is not a ROS namespace"),
        ('[[robots]]\nname = "rh0"\nset = { "ros2.namespace" = "a" }', "`robots[0].set`: 'ros2.namespace'"),
        ('[[robots]]\nname = "rh0"\nset = { "ros2.publish_clock" = true }', "'ros2.publish_clock' is the fleet's"),
        (
            '[[robots]]\nname = "rh0"\n[[robots]]\nname = "rh1"\nscenario = "square"\ngoals = "g.toml"',
            "`robots[1].goals`: a robot runs a scenario or goals, not both (it has `scenario` = 'square')",
        ),
        ('[[robots]]\nname = "rh0"\ngoals = ""', "robots[0].goals"),
        ('[[robots]]\nname = "rh0"\ngoals = 1', "robots[0].goals"),
    ],
)
def test_a_wrong_fleet_file_is_a_configuration_error_naming_the_field(text, names):
    with pytest.raises(ConfigError, match=None) as raised:
        parse_fleet(text, "f.toml")
    assert names in str(raised.value) and "f.toml" in str(raised.value)


def test_a_missing_fleet_file_and_a_wrong_override_name_the_flag_and_the_robot(tmp_path):
    with pytest.raises(ConfigError, match="--fleet"):
        load_fleet(tmp_path / "none.toml")
    fleet = parse_fleet('[[robots]]\nname = "rh7"\nset = { "motor.no_such_gain" = 1 }')
    with pytest.raises(ConfigError, match="fleet robot 'rh7'.*no_such_gain"):
        robot_config(fleet.robot("rh7"), None, {})


def test_a_robots_services_are_started_with_its_name_overrides_and_start():
    robot = parse_fleet(ISSUE_EXAMPLE).robot("rh1")
    sets = dict(setting.split("=", 1) for setting in robot_settings(robot))
    assert sets["motor.p_gain_l"] == "6.0" and sets["odometry.initial_y"] == "3.0"
    assert len(sets) == len(robot_overrides(robot)) - 1  # all but the name, which is the description's robot


def test_a_robot_names_a_goal_file_or_a_scenario_and_its_drive_is_started_with_it(monkeypatch):
    monkeypatch.chdir(CORRIDOR_SWAP.parent.parent.parent)
    fleet = parse_fleet(
        '[[robots]]\nname = "rh0"\ngoals = "examples/goals/swap_east.toml"\n'
        '[[robots]]\nname = "rh1"\nscenario = "square"\n'
        '[[robots]]\nname = "rh2"\n'
    )
    assert fleet.robot("rh0").goals == "examples/goals/swap_east.toml" and fleet.robot("rh0").scenario is None
    drives = {child.name: own_flags(child.options) for child in robot_plans(fleet, fleet.names)}
    assert drives["rh0/drive"] == ["--goal-file", "examples/goals/swap_east.toml"]
    assert drives["rh1/drive"] == ["--scenario", "square"]
    assert drives["rh2/drive"] == ["--scenario", "square"]  # up's default scenario
    assert fleet.robot("rh1").goals is None


def test_each_robots_bridge_is_in_its_namespace_and_only_the_first_publishes_clock():
    fleet = parse_fleet(ISSUE_EXAMPLE)
    configs = bridge_configs(fleet, None, {"ros2.namespace": "ignored", "ros2.tf": "prefixed"})
    assert {name: config.ros2.namespace for name, config in configs.items()} == {"rh0": "/rh0", "rh1": "/robot1"}
    assert {name: config.ros2.publish_clock for name, config in configs.items()} == {"rh0": True, "rh1": False}
    assert configs["rh1"].ros2.tf == "prefixed" and configs["rh1"].motor.p_gain_l == 6.0
    assert bridge_settings(fleet, fleet.robot("rh1")) == ('ros2.namespace="/robot1"', "ros2.publish_clock=false")
    unnamed = parse_fleet('[[robots]]\nname = "robot-1"')
    with pytest.raises(ConfigError, match="fleet robot 'robot-1': its name is not a ROS namespace.*`namespace`"):
        bridge_configs(unnamed, None, {})


poses = st.builds(
    Pose,
    st.floats(-50, 50, allow_nan=False),
    st.floats(-50, 50, allow_nan=False),
    st.floats(-math.pi, math.pi, allow_nan=False),
)


@given(start=poses)
def test_a_placed_square_keeps_its_side_lengths_and_starts_its_first_leg_along_the_heading(start):
    square = placed(BUILTIN_SCENARIOS["square"], start)
    points = [(start.x, start.y), *square.segments[0].waypoints]
    sides = [math.dist(a, b) for a, b in itertools.pairwise(points)]
    assert sides == pytest.approx([1.0, 1.0, 1.0, 1.0], abs=1e-9)
    assert points[-1] == pytest.approx(points[0], abs=1e-9)
    first_leg = math.atan2(points[1][1] - points[0][1], points[1][0] - points[0][0])
    assert math.remainder(first_leg - start.theta, math.tau) == pytest.approx(0.0, abs=1e-9)


def test_placing_at_the_origin_changes_nothing_and_constant_segments_are_relative_already():
    circle = BUILTIN_SCENARIOS["circle"]
    assert placed(circle, Pose(0.0, 0.0, 0.0)) is circle
    moved = placed(circle, Pose(3.0, 4.0, 1.0))
    assert all(isinstance(segment, ConstantSegment) for segment in moved.segments)
    assert moved.segments == circle.segments


def test_only_a_built_in_is_placed(tmp_path):
    path = tmp_path / "square.toml"
    path.write_text('[[segments]]\ntype = "waypoints"\nwaypoints = [[1.0, 0.0]]\n')
    assert is_builtin(load_scenario("square")) and not is_builtin(load_scenario(str(path)))


def test_the_closest_approach_is_at_a_common_stamp_and_names_both_robots():
    tracks = {
        "rh0": [(0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (2.0, 2.0, 0.0)],
        "rh1": [(0.0, 3.0, 0.0), (1.0, 1.5, 0.0), (2.0, 1.0, 0.0)],
        "rh2": [(0.0, 0.0, 9.0)],
    }
    assert closest_approach(tracks) == {"distance_m": 0.5, "t_s": 1.0, "robots": ["rh0", "rh1"]}
    assert closest_approach({"rh0": tracks["rh0"]}) is None


def test_bumps_between_robots_leave_out_obstacles_and_are_in_time_order():
    bumps = {"rh0": [(2.0, "rh1"), (5.0, "box")], "rh1": [(2.0, "rh0")]}
    assert bumps_between(bumps, ["rh0", "rh1"]) == [
        {"t_s": 2.0, "robot": "rh0", "other": "rh1"},
        {"t_s": 2.0, "robot": "rh1", "other": "rh0"},
    ]


@pytest.mark.parametrize(
    "path", sorted((Path(__file__).resolve().parent.parent / "examples" / "fleets").glob("*.toml"))
)
def test_the_example_fleets_load_with_their_scenarios_or_goal_files(path, monkeypatch):
    monkeypatch.chdir(path.parent.parent.parent)  # their scenario and goal paths are from the repository's root
    fleet = load_fleet(path)
    assert len(fleet.robots) >= 2
    for robot in fleet.robots:
        robot_config(robot, None, {})
        if robot.goals is not None:
            load_goal_file(robot.goals)
        else:
            load_scenario(robot.scenario or "square")


CORRIDOR_SWAP = Path(__file__).resolve().parent.parent / "examples" / "fleets" / "corridor_swap.toml"


def test_up_checks_each_robots_goal_file_before_it_starts_anything_and_names_what_its_drive_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(CORRIDOR_SWAP.parent.parent.parent)  # the goal files' paths are from the repository's root
    robots = FleetRobots(UpPlan(fleet=str(CORRIDOR_SWAP)), str(CORRIDOR_SWAP))
    assert [(robot.name, robot.scenario) for robot in robots.each] == [
        ("rh0", "examples/goals/swap_east.toml"),
        ("rh1", "examples/goals/swap_west.toml"),
    ]
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text('[[robots]]\nname = "rh0"\n[[robots]]\nname = "rh1"\ngoals = "none.toml"\n')
    with pytest.raises(ConfigError, match="fleet robot 'rh1': goal file 'none.toml'"):
        FleetRobots(UpPlan(fleet=str(fleet_file)), str(fleet_file))
    (tmp_path / "bad.toml").write_text("[[goals]]\nat = 0.0\nx = 1.0\n")
    fleet_file.write_text(f'[[robots]]\nname = "rh0"\ngoals = "{tmp_path / "bad.toml"}"\n')
    with pytest.raises(ConfigError, match="fleet robot 'rh0': .*goals\\[0\\]: a goal needs `x` and `y`"):
        FleetRobots(UpPlan(fleet=str(fleet_file)), str(fleet_file))
    # with --goals every drive waits for goals: the fleet file's goal files are not played, nor read
    fleet_file.write_text('[[robots]]\nname = "rh0"\ngoals = "none.toml"\n')
    waiting = FleetRobots(UpPlan(fleet=str(fleet_file), goals=True), str(fleet_file))
    assert [robot.scenario for robot in waiting.each] == ["goals"]
    assert [own_flags(_drive_options(waiting.plan, robot)) for robot in waiting.each] == [["--goals"]]


def test_up_starts_a_robots_drive_with_its_goal_file_in_its_own_process_or_a_worker(monkeypatch):
    monkeypatch.chdir(CORRIDOR_SWAP.parent.parent.parent)
    plan = UpPlan(fleet=str(CORRIDOR_SWAP))
    robots = FleetRobots(plan, str(CORRIDOR_SWAP))
    assert [own_flags(_drive_options(plan, robot)) for robot in robots.each] == [
        ["--goal-file", "examples/goals/swap_east.toml"],
        ["--goal-file", "examples/goals/swap_west.toml"],
    ]
    plans = {child.name: service_argv(child) for child in robot_plans(robots.fleet, ["rh0", "rh1"])}
    assert plans["rh1/drive"][-2:] == ["--goal-file", "examples/goals/swap_west.toml"]
    assert "--goal-file" not in plans["rh1/motor"]
    two_squares = str(CORRIDOR_SWAP.parent / "two_squares.toml")
    squares = FleetRobots(UpPlan(fleet=two_squares), two_squares)
    assert [own_flags(_drive_options(squares.plan, robot)) for robot in squares.each] == [["--scenario", "square"]] * 2
