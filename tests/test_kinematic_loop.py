"""The loop on the kinematic engine (``invent up --engine kinematic``): the square closes, home within
1 cm by the ground truth; two runs give the same samples bit for bit; in the bump world the
collision monitor holds the robot short of the box its lidar sees, and with the monitor off the
robot bumps into the box and stops against it, its motor latched at the contact's step; a fleet's
two robots meeting head-on bump each other and stop touching. Every run is lockstep and ``--composed`` (one process: the fastest), shared by
the tests that read it; the five runs take about 10 s."""

from __future__ import annotations

import json
import math
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from schemas.codec import decode
from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, BumpEvent, LaserScan, MotorStateReport, TimedDoubleSeq
from services.config import SimConfig
from services.exits import ExitStatus
from services.recording.mcap_files import RecordedMessage, read_messages
from tests.harness import REPO, invent_command

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

KEYS = Keys("rh0")
HOME_TOLERANCE_M = 0.01
COMPARED = (
    KEYS.sim_wheel_angles,
    KEYS.sim_body_pose,
    KEYS.sim_scan,
    KEYS.sim_imu,
    KEYS.motor_torque,
    KEYS.odometry_pose,
    KEYS.localization_pose,
    KEYS.drive_target_velocity,
)
BOX_FACE_X = 0.9
BODY_RADIUS = 0.45
AHEAD = 180
STEP_NS = round(SimConfig().step * NANOSECONDS_PER_SECOND)


@dataclass
class Run:
    returncode: int
    output: str
    report: dict
    messages: list[RecordedMessage]

    def on(self, key: str) -> list[bytes]:
        return [message.data for message in self.messages if message.topic == key]

    def decoded(self, key: str, message_type: Callable[..., object]) -> list:
        return [decode(message_type, data) for data in self.on(key)]  # type: ignore[arg-type]


def up(report: Path, *flags: str) -> Run:
    result = subprocess.run(
        invent_command(
            "up", "--engine", "kinematic", "--composed", "--mode", "lockstep", "--report", str(report), *flags
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    output = result.stdout + result.stderr
    report_file = report / "report.json"
    assert report_file.is_file(), output[-4000:]
    return Run(
        result.returncode, output, json.loads(report_file.read_text()), read_messages(report / "run.mcap").messages
    )


@pytest.fixture(scope="module")
def squares(tmp_path_factory: pytest.TempPathFactory) -> tuple[Run, Run]:
    folder = tmp_path_factory.mktemp("kinematic_square")
    return up(folder / "first", "--scenario", "square"), up(folder / "second", "--scenario", "square")


@pytest.fixture(scope="module")
def bump_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Run, Run]:
    """The square in the bump world: with the collision monitor, and without it."""
    folder = tmp_path_factory.mktemp("kinematic_bump")
    world = ("--scenario", "square", "--set", "sim.world=bump")
    held = up(folder / "monitored", *world)
    bumped = up(folder / "unmonitored", *world, "--set", "collision_monitor.enabled=false")
    return held, bumped


def final_pose(run: Run) -> tuple[float, float]:
    pose = decode(TimedDoubleSeq, run.on(KEYS.sim_body_pose)[-1]).data
    return pose[0], pose[1]


def test_the_square_completes_home_within_a_centimetre_by_the_ground_truth(squares):
    run = squares[0]
    assert run.returncode == ExitStatus.OK, run.output[-4000:]
    assert run.report["outcome"]["outcome"] == "completed" and run.report["mode"] == "lockstep"
    x, y = final_pose(run)
    assert math.hypot(x, y) < HOME_TOLERANCE_M, (x, y)
    truth = run.report["final"]["ground_truth"]
    assert math.hypot(truth["x"], truth["y"]) < HOME_TOLERANCE_M, truth
    assert run.report["health"]["torques"]["late"] == 0 and not run.report["degraded"]
    status = json.loads(run.on(KEYS.status(Service.SIM))[-1])
    assert status["engine"] == "kinematic", "sim/status names the engine"


def test_two_runs_give_the_same_samples_bit_for_bit(squares):
    first, second = squares
    assert second.returncode == ExitStatus.OK, second.output[-4000:]
    for key in COMPARED:
        samples = first.on(key)
        assert samples, f"{key} recorded"
        assert samples == second.on(key), f"{key} differs between two lockstep runs"


def test_in_the_bump_world_the_collision_monitor_holds_the_robot_short_of_the_box_its_lidar_sees(bump_runs):
    held, _ = bump_runs
    assert held.returncode == ExitStatus.ABORTED, held.output[-4000:]
    assert "collision monitor" in held.report["outcome"]["reason"] and "'box'" in held.report["outcome"]["reason"]
    assert held.on(KEYS.sim_bump) == [], "held before touching"
    x, _ = final_pose(held)
    assert x < BOX_FACE_X - BODY_RADIUS
    scan = held.decoded(KEYS.sim_scan, LaserScan)[0]
    assert scan.bodies == ["box"] and scan.bodies[scan.hits[AHEAD]] == "box"
    assert scan.ranges[AHEAD] == pytest.approx(BOX_FACE_X, abs=1e-6), "the box's face, straight ahead"


def test_without_the_monitor_the_robot_bumps_into_the_box_and_stops_against_it(bump_runs):
    _, bumped = bump_runs
    assert bumped.returncode == ExitStatus.ABORTED, bumped.output[-4000:]
    assert "bumped into 'box'" in bumped.report["outcome"]["reason"], bumped.report["outcome"]
    bumps = bumped.decoded(KEYS.sim_bump, BumpEvent)
    assert len(bumps) == 1 and bumps[0].obstacle == "box" and bumps[0].x == pytest.approx(BOX_FACE_X)
    stops = [state for state in bumped.decoded(KEYS.motor_state, MotorStateReport) if state.state == "stopped"]
    latched_ns, bump_ns = stops[0].tm.to_nanoseconds(), bumps[0].tm.to_nanoseconds()
    assert stops[0].stopped_by == "bump" and latched_ns == bump_ns - STEP_NS, "latched at the contact's step"
    x, y = final_pose(bumped)
    assert BOX_FACE_X - BODY_RADIUS - 0.01 < x <= BOX_FACE_X - BODY_RADIUS and y == pytest.approx(0.0, abs=1e-9)


HEAD_ON = "".join(
    f'[[robots]]\nname = "{name}"\nstart = {{ x = {x}, y = 0.0, theta = {theta} }}\nscenario = "straight"\n'
    'set = { "collision_monitor.enabled" = false }\n'
    for name, x, theta in (("rh0", 0.0, 0.0), ("rh1", 3.0, math.pi))
)
"""Two robots 3 m apart facing each other, each to drive 2 m ahead, their collision monitors off."""


def test_a_fleet_runs_on_it_two_robots_meeting_head_on_bump_each_other_once_and_stop_touching(tmp_path: Path):
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(HEAD_ON)
    run = up(tmp_path / "report", "--fleet", str(fleet))
    assert run.returncode == ExitStatus.ABORTED, run.output[-4000:]
    between = run.report["fleet"]["bumps_between_robots"]
    assert {(bump["robot"], bump["other"]) for bump in between} == {("rh0", "rh1"), ("rh1", "rh0")}, between
    assert between[0]["t_s"] == between[1]["t_s"], "one contact, a bump for each at the same step"
    for robot, other in (("rh0", "rh1"), ("rh1", "rh0")):
        assert f"bumped into {other!r}" in run.report["robots"][robot]["outcome"]["reason"]
    touching = run.report["fleet"]["closest_approach"]["distance_m"]
    assert 2 * BODY_RADIUS <= touching < 2 * BODY_RADIUS + 0.002, "stopped touching, never into each other"
