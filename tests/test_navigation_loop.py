"""Goals that find their way, on the whole loop (``invent up --goal-file``, lockstep, composed, on the
kinematic engine: the navigation is the point, not the physics): in worlds with something across the
straight line (a U-shaped trap, three rooms joined by doors 1.8 m wide) every goal completes, the
ground truth within its tolerance, with no bump and no hold of the collision monitor, having driven at
most 1.5 times the shortest path that keeps 0.5 m from every obstacle (tests/navigation_reference.py,
computed apart from the planner); a goal in a closed pen ends ``aborted`` naming why within four
simulated minutes, touching nothing. Each with no map (the lidar's costmap alone) and with the map
``invent map`` makes of the world. And two robots swapping ends of a corridor 3 m wide, each seeing
the other with its lidar, pass without touching."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pytest

from services.config import RobotConfig
from services.exits import ExitStatus
from sim_bridge.world import load_world
from tests.harness import REPO, invent_command, run_invent
from tests.navigation_reference import shortest_clear_path

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

GOALS = REPO / "examples" / "goals"
DETOUR_BOUND = 1.5
"""The distance driven, at most this many times the shortest path keeping 0.5 m from every obstacle."""


@pytest.fixture(scope="module")
def maps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("maps")
    made = {}
    for world in ("u_trap", "three_rooms", "pen"):
        result = run_invent("map", "--world", world, "-o", str(folder / f"{world}.yaml"))
        assert result.returncode == 0, result.stderr
        made[world] = folder / f"{world}.yaml"
    return made


def run_up(report: Path, *flags: str) -> tuple[int, dict[str, Any], str]:
    """``invent up --composed --engine kinematic FLAGS`` into ``report``: its exit status, report.json, output."""
    result = subprocess.run(
        invent_command("up", "--composed", "--engine", "kinematic", "--report", str(report), *flags),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    output = result.stdout[-6000:] + result.stderr[-3000:]
    report_file = report / "report.json"
    assert report_file.exists(), output
    return result.returncode, json.loads(report_file.read_text()), output


def navigate(world: str, report: Path, map_file: Path | None) -> tuple[int, dict[str, Any], str]:
    """``invent up`` of the world's goal file, with its map or none."""
    flags = ["--map", str(map_file)] if map_file is not None else []
    return run_up(report, "--set", f"sim.world={world}", "--goal-file", str(GOALS / f"{world}.toml"), *flags)


def assert_touched_nothing(report: dict[str, Any], output: str) -> None:
    health = report["health"]
    assert health["safety"] == {"bumps": 0, "collision_monitor_holds": 0}, output
    assert health["lockstep"]["dropped_participants"] == [] and health["navigation"]["scans_late"] == 0, health


@pytest.mark.parametrize("with_map", [False, True], ids=["lidar_only", "map"])
@pytest.mark.parametrize("world", ["u_trap", "three_rooms"])
def test_every_goal_is_reached_around_what_stands_in_the_way_touching_nothing(world, with_map, maps, tmp_path):
    code, report, output = navigate(world, tmp_path, maps[world] if with_map else None)
    assert code == ExitStatus.OK, output
    assert_touched_nothing(report, output)
    layout = load_world(world)
    for goal in report["goals"]:
        truth = goal["ground_truth"]
        assert goal["outcome"] == "completed" and truth["within_tolerance"], goal
        start, end = truth["start"], goal["pose"]
        shortest = shortest_clear_path(layout, (start["x"], start["y"]), (end["x"], end["y"]))
        assert shortest is not None, goal
        assert truth["driven_m"] <= DETOUR_BOUND * shortest, f"{truth['driven_m']:.2f} m against {shortest:.2f} m"


@pytest.mark.parametrize("with_map", [False, True], ids=["lidar_only", "map"])
def test_a_goal_in_a_closed_pen_ends_aborted_naming_why_within_four_minutes_touching_nothing(with_map, maps, tmp_path):
    code, report, output = navigate("pen", tmp_path, maps["pen"] if with_map else None)
    assert code == ExitStatus.ABORTED, output
    assert_touched_nothing(report, output)
    (goal,) = report["goals"]
    assert goal["outcome"] == "aborted" and goal["reason"].startswith("no path to ("), goal
    assert "recoveries tried" in goal["reason"], goal["reason"]
    assert goal["ended_s"] <= 240.0, goal


def test_two_robots_swapping_ends_of_a_corridor_3_m_wide_pass_each_other_touching_nothing(tmp_path):
    """``examples/fleets/corridor_swap.toml``: head-on on the corridor's centre line, each to the
    other's start. Each lidar sees the other robot, each costmap marks it (and forgets it as it
    passes), each plan goes round it: both goals complete, no bump, no hold, the bodies apart."""
    code, report, output = run_up(tmp_path, "--fleet", "examples/fleets/corridor_swap.toml")
    assert code == ExitStatus.OK, output
    layout = load_world("corridor")
    for name, robot in report["robots"].items():
        assert_touched_nothing(robot, output)
        (goal,) = robot["goals"]
        truth = goal["ground_truth"]
        assert goal["outcome"] == "completed" and truth["within_tolerance"], (name, goal)
        start, end = truth["start"], goal["pose"]
        shortest = shortest_clear_path(layout, (start["x"], start["y"]), (end["x"], end["y"]))
        assert shortest is not None and truth["driven_m"] <= DETOUR_BOUND * shortest, (name, truth, shortest)
    fleet = report["fleet"]
    body = RobotConfig().radius_of_body_area
    assert fleet["bumps_between_robots"] == [] and fleet["closest_approach"]["distance_m"] > 2 * body, fleet
