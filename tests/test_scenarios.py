"""Scenarios: built-ins, TOML files (strict, errors naming the field), the runner, planned paths."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from services.config import ConfigError, DriveConfig
from services.drive.path_following import STOPPED, Command
from services.drive.scenarios import (
    BUILTIN_SCENARIOS,
    PATH_SEGMENT_SAMPLES,
    ConstantSegment,
    Scenario,
    ScenarioRunner,
    WaypointSegment,
    distance_to_path,
    load_scenario,
    parse_scenario,
    parse_waypoints,
    planned_path,
    planned_path_for,
)
from services.planar import Pose
from tests.harness import REPO, refused

PARAMS = DriveConfig()
ORIGIN = Pose(0.0, 0.0, 0.0)
MS = 1_000_000
DEAD_ENDPOINT = ("--connect", "tcp/127.0.0.1:1")
"""Nothing listens there: these commands must fail on their flags before they need a router."""


def test_builtins_load_by_name() -> None:
    assert set(BUILTIN_SCENARIOS) == {"straight", "circle", "square", "figure8"}
    for name in BUILTIN_SCENARIOS:
        assert load_scenario(name).name == name


def test_square_is_a_1m_square_by_waypoints_back_to_the_start() -> None:
    square = [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
    assert load_scenario("square").segments == [WaypointSegment(waypoints=square)]


def test_straight_is_a_waypoint_path_along_x() -> None:
    (segment,) = load_scenario("straight").segments
    assert isinstance(segment, WaypointSegment)
    assert all(y == 0.0 and x > 0.0 for x, y in segment.waypoints)


def test_circle_turns_exactly_once_and_closes() -> None:
    (segment,) = load_scenario("circle").segments
    assert isinstance(segment, ConstantSegment) and segment.vx > 0
    assert segment.w * segment.duration == pytest.approx(2 * math.pi)
    path = planned_path(load_scenario("circle"), ORIGIN)
    radius = segment.vx / segment.w
    assert all(math.dist(point, (0.0, radius)) == pytest.approx(radius) for point in path)
    assert math.dist(path[-1], path[0]) < 1e-9


def test_figure8_is_two_opposite_full_circles() -> None:
    first, second = load_scenario("figure8").segments
    assert isinstance(first, ConstantSegment) and isinstance(second, ConstantSegment)
    assert first.vx == second.vx and first.w == -second.w
    assert first.w * first.duration == pytest.approx(2 * math.pi)
    path = planned_path(load_scenario("figure8"), ORIGIN)
    assert math.dist(path[-1], (0.0, 0.0)) < 1e-9
    assert max(y for _x, y in path) > 0.9 and min(y for _x, y in path) < -0.9, "one loop left, one right"


def test_planned_path_of_waypoints_is_the_polyline_from_the_start() -> None:
    start = Pose(0.5, -0.5, 1.0)
    assert planned_path(load_scenario("square"), start) == [(0.5, -0.5), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]


def test_planned_path_chains_segments_from_where_the_last_one_ended() -> None:
    scenario = Scenario(
        name="mixed",
        segments=[
            WaypointSegment(waypoints=[(1.0, 0.0), (1.0, 1.0)]),
            ConstantSegment(vx=0.5, w=0.0, duration=2.0),
        ],
    )
    path = planned_path(scenario, ORIGIN)
    assert path[:3] == [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]
    assert path[-1] == pytest.approx((1.0, 2.0)), "the robot faces +y after the last leg, then drives 1 m"


def test_a_long_constant_segment_is_planned_in_bounded_work() -> None:
    """A scenario of hours (a benchmark's circle): one turn of the circle, its end, and a straight
    line's end only; the drive plans it when it starts, in the loop's time."""
    circle = Scenario(name="long", segments=[ConstantSegment(vx=0.3, w=0.3, duration=100_000.0)])
    started = time.perf_counter()
    path = planned_path(circle, ORIGIN)
    assert time.perf_counter() - started < 0.5
    assert len(path) <= PATH_SEGMENT_SAMPLES + 2
    assert all(math.dist(point, (0.0, 1.0)) == pytest.approx(1.0) for point in path), "on the circle"
    line = Scenario(name="line", segments=[ConstantSegment(vx=0.5, w=0.0, duration=3600.0)])
    assert planned_path(line, ORIGIN) == [(0.0, 0.0), pytest.approx((1800.0, 0.0))]


def test_planned_path_for_loads_by_name_or_file(tmp_path: Path) -> None:
    assert planned_path_for("square", None)[0] == (0.0, 0.0)
    assert planned_path_for("square", (0.1, 0.2, 0.0))[0] == (0.1, 0.2)
    file = tmp_path / "line.toml"
    file.write_text('name = "line"\n[[segments]]\ntype = "waypoints"\nwaypoints = [[0.0, 3.0]]\n')
    assert planned_path_for(str(file)) == [(0.0, 0.0), (0.0, 3.0)]


def test_distance_to_path_hand_values() -> None:
    square = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]
    assert distance_to_path((0.5, 0.1), square) == pytest.approx(0.1)
    assert distance_to_path((1.2, 0.5), square) == pytest.approx(0.2)
    assert distance_to_path((-3.0, -4.0), square) == pytest.approx(5.0)
    assert distance_to_path((2.0, 2.0), [(2.0, 1.0)]) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        distance_to_path((0.0, 0.0), [])


@pytest.mark.parametrize("example", sorted((REPO / "examples" / "scenarios").glob("*.toml")), ids=lambda p: p.name)
def test_example_scenario_files_load(example: Path) -> None:
    scenario = load_scenario(str(example))
    assert scenario.name and scenario.segments


def test_a_file_without_a_name_is_named_after_the_file(tmp_path: Path) -> None:
    file = tmp_path / "zigzag.toml"
    file.write_text('[[segments]]\ntype = "waypoints"\nwaypoints = [[1, 1], [2, 0]]\n')
    scenario = load_scenario(str(file))
    assert scenario.name == "zigzag"
    assert scenario.segments == [WaypointSegment(waypoints=[(1.0, 1.0), (2.0, 0.0)])]


@pytest.mark.parametrize(
    ("toml", "names"),
    [
        ('[[segments]]\ntype = "constant"\nvx = "fast"\nw = 0.0\nduration = 1.0\n', "segments[0].vx"),
        ('[[segments]]\ntype = "constant"\nvx = 0.1\nw = 0.0\nduration = 0.0\n', "segments[0].duration"),
        ('[[segments]]\ntype = "constant"\nvx = 0.1\nw = 0.0\n', "`duration`"),
        ('[[segments]]\ntype = "constant"\nvx = nan\nw = 0.0\nduration = 1.0\n', "`vx` must be finite"),
        ('[[segments]]\ntype = "waypoints"\nwaypoints = [[1, 0, 0]]\n', "segments[0].waypoints[0]"),
        ('[[segments]]\ntype = "waypoints"\nwaypoints = []\n', "segments[0].waypoints"),
        ('[[segments]]\ntype = "teleport"\n', "segments[0].type"),
        ('[[segments]]\ntype = "waypoints"\nwaypoints = [[1, 0]]\nspeed = 2\n', "unknown field `speed`"),
        ("name = 'empty'\nsegments = []\n", "segments"),
        ("name = 'unclosed\n", "scenario"),
    ],
)
def test_invalid_toml_is_a_config_error_naming_the_field(toml: str, names: str) -> None:
    with pytest.raises(ConfigError) as error:
        parse_scenario(toml)
    assert names in str(error.value)


def test_an_unknown_name_lists_the_builtins() -> None:
    with pytest.raises(ConfigError, match="neither a built-in") as error:
        load_scenario("pentagon")
    assert all(name in str(error.value) for name in BUILTIN_SCENARIOS)


def test_parse_waypoints() -> None:
    assert parse_waypoints("1,0 1,1  0,1\t0,0") == [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.0)]
    assert parse_waypoints("-1.5,2e-1") == [(-1.5, 0.2)]
    bad_lists = {"1,0 2": "waypoint 2", "1,0,0": "waypoint 1", "a,b": "X,Y", "": "at least one", "inf,0": "finite"}
    for bad, reason in bad_lists.items():
        with pytest.raises(ConfigError, match=reason):
            parse_waypoints(bad)


def test_bad_scenario_file_exits_2_naming_the_field(tmp_path: Path, capsys) -> None:
    file = tmp_path / "bad.toml"
    file.write_text(
        '[[segments]]\ntype = "waypoints"\nwaypoints = [[1, 0]]\n\n'
        '[[segments]]\ntype = "constant"\nvx = 1\nw = 0\nduration = -2\n'
    )
    code, _out, stderr = refused(capsys, "drive", "--scenario", str(file), *DEAD_ENDPOINT)
    assert code == 2, stderr
    assert "segments[1].duration" in stderr and str(file) in stderr


@pytest.mark.parametrize(
    ("flags", "names"),
    [
        (("--scenario", "pentagon"), "--scenario"),
        (("--waypoints", "1,0 1"), "waypoint 2"),
        (("--for", "0"), "--for"),
        (("--vx", "0.3"), "one of the arguments"),
        (("--for", "1", "--scenario", "square"), "not allowed with"),
        (("--scenario", "square", "--vx", "0.3"), "--vx and --w go with --for"),
        (("--for", "1", "--rate", "0"), "drive.rate"),
    ],
)
def test_bad_drive_flags_exit_2_naming_the_flag(flags: tuple[str, ...], names: str, capsys) -> None:
    code, _out, stderr = refused(capsys, "drive", *flags, *DEAD_ENDPOINT)
    assert code == 2, stderr
    assert names in stderr


class TestRunner:
    def ticks(self, runner: ScenarioRunner, count: int, period_ns: int = 20 * MS, pose: Pose | None = ORIGIN):
        return [runner.step(k * period_ns, pose) for k in range(count)]

    def test_a_constant_segment_holds_for_its_duration_then_ends(self) -> None:
        runner = ScenarioRunner(Scenario(segments=[ConstantSegment(vx=0.3, w=0.1, duration=1.0)]), PARAMS)
        commands = self.ticks(runner, 52)
        assert commands[:50] == [Command(0.3, 0.1)] * 50
        assert commands[50:] == [STOPPED, STOPPED]
        assert runner.done and runner.elapsed_s == pytest.approx(1.02)

    def test_segments_follow_each_other_on_the_same_tick(self) -> None:
        scenario = Scenario(
            segments=[ConstantSegment(vx=0.1, w=0.0, duration=0.04), ConstantSegment(vx=0.0, w=0.5, duration=0.04)]
        )
        runner = ScenarioRunner(scenario, PARAMS)
        assert self.ticks(runner, 5) == [Command(0.1, 0.0)] * 2 + [Command(0.0, 0.5)] * 2 + [STOPPED]
        assert runner.done

    def test_loop_starts_over_forever(self) -> None:
        runner = ScenarioRunner(Scenario(segments=[ConstantSegment(vx=0.2, w=0.0, duration=0.04)]), PARAMS, loop=True)
        assert self.ticks(runner, 7) == [Command(0.2, 0.0)] * 7
        assert runner.iteration == 3 and not runner.done

    def test_a_waypoint_segment_waits_stopped_for_a_pose(self) -> None:
        runner = ScenarioRunner(load_scenario("straight"), PARAMS)
        assert runner.step(0, None) == STOPPED
        assert runner.waiting_for_pose and runner.waypoint_index is None
        runner.step(20 * MS, ORIGIN)
        command = runner.step(40 * MS, ORIGIN)
        assert not runner.waiting_for_pose and command.vx > 0.0
        assert runner.waypoint_index == 0 and runner.phase == "follow"

    def test_a_looping_scenario_that_is_already_done_does_not_spin(self) -> None:
        runner = ScenarioRunner(Scenario(segments=[WaypointSegment(waypoints=[(0.0, 0.0)])]), PARAMS, loop=True)
        assert self.ticks(runner, 3) == [STOPPED] * 3
        assert 3 <= runner.iteration <= 2 * 3 and not runner.done, "each tick tries the scenario, at most twice"

    def test_a_follower_starts_from_the_previous_segments_command(self) -> None:
        scenario = Scenario(
            segments=[ConstantSegment(vx=0.3, w=0.0, duration=0.02), WaypointSegment(waypoints=[(5.0, 0.0)])]
        )
        runner = ScenarioRunner(scenario, PARAMS)
        assert runner.step(0, ORIGIN) == Command(0.3, 0.0)
        second = runner.step(20 * MS, Pose(0.006, 0.0, 0.0))
        assert second.vx == pytest.approx(0.3), "no drop to zero between segments"
        assert runner.segment_index == 1
