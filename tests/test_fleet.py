"""A fleet in one world, end to end: ``invent up --fleet``.

Two robots drive the square each from its own start: both come home, and the run is the same bit
for bit composed on a quiet machine (over two processes: the simulator and one robot's services in
``up``'s, the other robot's in a worker) and as separate processes beside two CPU burners. Two robots
driven head-on are held short of each other by their collision monitors, each naming the other;
with the monitors off they meet: a bump for each naming the other, both motors latched stopped.
In a secure fleet (every service with its own robot's credentials) a robot whose motor dies
degrades only its own part of the report, and the other robot still reaches its goal.
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from schemas.keys import Keys
from schemas.topics import Topic
from services.config import RobotConfig
from services.drive.outcome import Outcome
from services.recording.mcap_files import read_messages
from tests.harness import REPO, free_port, start_up, wait_until

pytestmark = pytest.mark.slow


def _robot(name: str, x: float, y: float, theta: float, scenario: str, overrides: str = "") -> str:
    """One ``[[robots]]`` entry of a fleet file."""
    entry = f'[[robots]]\nname = "{name}"\nstart = {{ x = {x}, y = {y}, theta = {theta} }}\nscenario = "{scenario}"\n'
    return entry + (f"set = {{ {overrides} }}\n" if overrides else "")


SQUARES = (
    'world = "empty"\n'
    + _robot("rh0", 0.0, 0.0, 0.0, "square")
    + _robot("rh1", 0.5, 3.0, math.pi / 2, "square", '"motor.p_gain_l" = 6.0')
)
STRAIGHTS = _robot("rh0", 0.0, 0.0, 0.0, "straight") + _robot("rh1", 0.0, 3.0, 0.0, "straight")
"""Each robot 2 m straight ahead, rh0 to (2, 0): shorter than the square, for the run that loses a motor."""


NO_MONITOR = '"collision_monitor.enabled" = false'
HEAD_ON = _robot("rh0", 0.0, 0.0, 0.0, "straight", NO_MONITOR) + _robot(
    "rh1", 3.0, 0.0, math.pi, "straight", NO_MONITOR
)
"""Two robots 3 m apart facing each other, each to drive 2 m straight ahead: they meet half-way
(their collision monitors off: they bump)."""
COMPARED = (
    Topic.SIM_BODY_POSE,
    Topic.ODOMETRY_POSE,
    Topic.LOCALIZATION_POSE,
    Topic.DRIVE_TARGET_VELOCITY,
    Topic.SIM_SCAN,
    Topic.SIM_IMU,
)
PATIENT = ("--set", "sim.lockstep_timeout=5")
"""As in test_determinism: beside two burners a lockstep wait may take longer than the default."""
HOME_M = 0.05


@contextmanager
def _burning_cpus(count: int) -> Iterator[None]:
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()


def _up(directory: Path, fleet: str, *flags: str, timeout: float = 240.0) -> tuple[int, str, dict]:
    fleet_file = directory / "fleet.toml"
    fleet_file.write_text(fleet)
    report = directory / "report"
    process = start_up(
        "--fleet", str(fleet_file), "--report", str(report), "--listen", f"tcp/127.0.0.1:{free_port()}", *flags
    )
    output, _ = process.communicate(timeout=timeout)
    loaded = json.loads((report / "report.json").read_text()) if (report / "report.json").exists() else {}
    return process.returncode, output, loaded


def _samples(report_dir: Path) -> dict[str, list[bytes]]:
    """Every payload of the compared keys of both robots in run.mcap, in publication order, and
    under ``"shown"`` the names of the Foxglove topics of its scene."""
    keys = {Keys(name).topic(topic) for name in ("rh0", "rh1") for topic in COMPARED}
    samples: dict[str, list[bytes]] = {key: [] for key in keys}
    shown: set[str] = set()
    for message in read_messages(report_dir / "run.mcap").messages:
        if message.topic in samples:
            samples[message.topic].append(message.data)
        elif message.topic.startswith("/"):
            shown.add(message.topic)
    return {**samples, "shown": sorted(item.encode() for item in shown)}


def _home(report: dict) -> float:
    start, end = report["start"], report["final"]["ground_truth"]
    return math.hypot(end["x"] - start["x"], end["y"] - start["y"])


@pytest.fixture(scope="module")
def squares(tmp_path_factory) -> dict[str, tuple[int, str, dict, dict[str, list[bytes]]]]:
    runs = {}
    quiet = tmp_path_factory.mktemp("quiet_composed")
    code, output, report = _up(quiet, SQUARES, "--composed", "--workers", "2")
    runs["quiet composed"] = (code, output, report, _samples(quiet / "report") if code == 0 else {})
    loaded = tmp_path_factory.mktemp("loaded_separate")
    with _burning_cpus(2):
        code, output, report = _up(loaded, SQUARES, *PATIENT)
    runs["loaded separate"] = (code, output, report, _samples(loaded / "report") if code == 0 else {})
    return runs


def test_both_robots_drive_their_square_from_their_own_start_and_come_home(squares):
    assert "started worker1" in squares["quiet composed"][1], "one robot's services in a worker process"
    for name, (code, output, report, _samples_of_run) in squares.items():
        assert code == 0, (name, output[-3000:])
        assert set(report["robots"]) == {"rh0", "rh1"} and report["degraded"] == [], (name, report["degraded"])
        for robot, start in (("rh0", (0.0, 0.0)), ("rh1", (0.5, 3.0))):
            part = report["robots"][robot]
            assert (part["start"]["x"], part["start"]["y"]) == pytest.approx(start, abs=1e-3), (name, robot)
            assert _home(part) < HOME_M, (name, robot, part["final"])
            assert part["path_error"]["max_m"] < 0.10 and part["scenario"] == "square"
        turned = report["robots"]["rh1"]["planned_path"][1]
        assert turned == pytest.approx([0.5, 4.0], abs=1e-9), "rh1's square is placed at its start, facing +y"
        closest = report["fleet"]["closest_approach"]
        assert closest["robots"] == ["rh0", "rh1"] and closest["distance_m"] > 1.0
        assert report["fleet"]["bumps_between_robots"] == []
        shown = {topic.decode() for topic in squares[name][3]["shown"]}
        assert {"/rh0/odometry/pose", "/rh1/odometry/pose", "/tf", "/scene"} <= shown, "run.mcap shows every robot"
        assert {"/rh0/scan", "/rh1/scan"} <= shown, "and each robot's scan"


def test_a_fleet_run_is_the_same_bit_for_bit_composed_quietly_and_separate_beside_burners(squares):
    (quiet, loaded) = (squares["quiet composed"][3], squares["loaded separate"][3])
    assert quiet and loaded, "both runs recorded"
    for key, payloads in quiet.items():
        assert len(payloads) > 5, (
            key
        )  # localization: 1 Hz over 21 s; the scene's topics: 8  # localization: 1 Hz over 21 s
        assert loaded[key] == payloads, f"{key}: {len(payloads)} samples quiet, {len(loaded[key])} loaded"
    rh0_pose, rh1_pose = (quiet[Keys(name).odometry_pose] for name in ("rh0", "rh1"))
    assert rh0_pose != rh1_pose, "each robot has its own keys and its own motion"


def test_robots_that_meet_head_on_bump_each_other_stay_stopped_and_both_abort_by_themselves(tmp_path):
    code, output, report = _up(tmp_path, HEAD_ON, "--composed")
    assert code == Outcome.ABORTED.exit_code, output[-3000:]
    between = report["fleet"]["bumps_between_robots"]
    assert {(bump["robot"], bump["other"]) for bump in between} == {("rh0", "rh1"), ("rh1", "rh0")}, between
    assert between[0]["t_s"] == between[1]["t_s"], "one contact, a bump for each at the same step"
    for robot, other in (("rh0", "rh1"), ("rh1", "rh0")):
        part = report["robots"][robot]
        assert part["bumps"][0]["obstacle"] == other
        assert part["outcome"]["outcome"] == "aborted", (robot, part["outcome"])
        assert f"bumped into {other!r}" in part["outcome"]["reason"], (robot, part["outcome"])
        assert f"outcome: aborted (bumped into {other!r}" in output
        state = json.loads((tmp_path / "report" / robot / "motor-state.json").read_text())
        assert state["stopped"] is True, (robot, state)
        end = part["final"]["ground_truth"]
        assert abs(end["x"] - 1.5) < 0.5, f"{robot} stopped near where they met, not 2 m on"
    body = 2 * RobotConfig().radius_of_body_area
    assert report["fleet"]["closest_approach"]["distance_m"] == pytest.approx(body, abs=0.02), "bodies touching"


HEAD_ON_EXAMPLE = "examples/fleets/head_on.toml"
"""Two robots 3 m apart facing each other, each to drive 1.8 m (6 s at 0.3 m/s) ahead, their collision
monitors on (the default)."""


def test_robots_driven_head_on_are_held_short_of_each_other_by_their_collision_monitors(tmp_path):
    """The example fleet, as it is: each robot drives, then its collision monitor holds it short of
    the other (no contact, no sim/bump), and its drive gives its scenario up naming the other."""
    code, output, report = _up(tmp_path, (REPO / HEAD_ON_EXAMPLE).read_text(), "--composed")
    assert code == Outcome.ABORTED.exit_code, output[-3000:]
    assert report["fleet"]["bumps_between_robots"] == [] and "; no bumps" in output
    recorded = {message.topic for message in read_messages(tmp_path / "report" / "run.mcap").messages}
    assert not {Keys(name).sim_bump for name in ("rh0", "rh1")} & recorded, "no sim/bump for either robot"
    assert re.search(r"rh0: .*bumps 0, bump_stop_calls 0,.*rh1: .*bumps 0, bump_stop_calls 0,", output), "the sim's"
    ends = {}
    for robot, other in (("rh0", "rh1"), ("rh1", "rh0")):
        part = report["robots"][robot]
        assert part["bumps"] == [], (robot, part["bumps"])
        assert part["outcome"]["outcome"] == "aborted", (robot, part["outcome"])
        assert re.match(r"held by the collision monitor for 2\.0\d\d s", part["outcome"]["reason"]), part["outcome"]
        assert f"obstacle {other!r} in the stop zone" in part["outcome"]["reason"], (robot, part["outcome"])
        ends[robot] = part["final"]["ground_truth"]
        assert _home(part) > 0.5, f"{robot} drove before it was held: {ends[robot]}"
    body = 2 * RobotConfig().radius_of_body_area
    gap = math.hypot(ends["rh1"]["x"] - ends["rh0"]["x"], ends["rh1"]["y"] - ends["rh0"]["y"]) - body
    closest = report["fleet"]["closest_approach"]["distance_m"] - body
    assert gap >= 0.05 and closest >= 0.05, f"the bodies {gap:.3f} m apart at the end, {closest:.3f} m at the closest"


def _kill_mid_run(tmp_path: Path, child: str, *flags: str) -> tuple[int, str, dict]:
    """``invent up --fleet`` of :data:`STRAIGHTS` with ``flags``; SIGKILL its child ``child`` (as
    ``up`` names it when it starts it) one second into the run; the exit code, the output, the report."""
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text(STRAIGHTS)
    report_dir = tmp_path / "report"
    process = start_up(
        "--fleet", str(fleet_file), "--report", str(report_dir), "--listen", f"tcp/127.0.0.1:{free_port()}", *flags
    )  # fmt: skip
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.extend(process.stdout), daemon=True)
    reader.start()
    try:
        wait_until(lambda: re.search(r"sim +[1-9]\.\d\d s", "".join(output)), 120, "the fleet 1 s into its run")
        started = re.search(rf"started {re.escape(child)} \(pid (\d+)\)", "".join(output))
        assert started, "".join(output)[-2000:]
        subprocess.run(["kill", "-KILL", started.group(1)], check=True)
        process.wait(timeout=180)
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            process.wait(timeout=30)
    reader.join(5)
    report_file = report_dir / "report.json"
    return process.returncode, "".join(output), json.loads(report_file.read_text()) if report_file.exists() else {}


def test_a_secure_fleet_whose_robots_motor_dies_degrades_only_that_robot_and_the_other_drives_on(tmp_path):
    """With --secure, every service runs with its own robot's credentials (the run proves them
    enough); rh1's motor is then SIGKILLed."""
    code, log, report = _kill_mid_run(tmp_path, "rh1/motor", "--secure")
    assert code == 0, log[-3000:]
    secrets = tmp_path / "report" / "secrets"
    assert (secrets / "rh1-motor.json5").is_file() and not (secrets / "motor.json5").exists()
    assert f"--zenoh-config {secrets / 'rh1-motor.json5'}" in log, "rh1's motor ran with rh1's credentials"
    assert "rh1: motor ended (killed by SIGKILL): only rh1 degrades" in log
    rh0 = report["robots"]["rh0"]
    assert rh0["degraded"] == [] and rh0["path_error"]["max_m"] < 0.10, rh0
    end = rh0["final"]["ground_truth"]
    assert math.hypot(end["x"] - 2.0, end["y"]) < HOME_M, f"rh0 reached the end of its straight: {end}"
    assert report["robots"]["rh1"]["degraded"][0] == "motor ended early (killed by SIGKILL)"
    assert report["degraded"][0] == "rh1: motor ended early (killed by SIGKILL)"


def test_a_composed_fleet_whose_worker_dies_degrades_only_its_robot_and_the_other_drives_on(tmp_path):
    """``--composed --workers 2``: rh0's services run in the worker process (services/launch/worker.py,
    ``assign``), rh1's beside the simulator in ``up``'s; the worker is then SIGKILLed."""
    code, log, report = _kill_mid_run(tmp_path, "worker1", "--composed", "--workers", "2")
    assert code == 0, log[-3000:]
    assert "rh0: motor ended (worker1 killed by SIGKILL): only rh0 degrades" in log, log[-3000:]
    rh1 = report["robots"]["rh1"]
    assert rh1["degraded"] == [] and rh1["outcome"]["outcome"] == "completed", rh1
    end = rh1["final"]["ground_truth"]
    assert math.hypot(end["x"] - 2.0, end["y"] - 3.0) < HOME_M, f"rh1 reached the end of its straight: {end}"
    assert report["robots"]["rh0"]["degraded"][0].startswith("motor ended early (worker1 killed by SIGKILL)")
