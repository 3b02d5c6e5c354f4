"""Issue 41's first "Must show", end to end with the real loop: ``invent up --goals`` (realtime;
composed and paced at twice the wall clock, to keep the suite short: the goals are the same in
simulation time), then ``invent goto``: a goal reached within its tolerance by the ground truth
(``sim/body_pose``), a goal canceled halfway (the robot brakes and stops, ``canceled``, exit 5), a
goal preempted by a second (the first exits 5, the second 0), a goal the drive rejects (exit 1 with
its reason), and Ctrl-C of ``up``: exit 0, its ``run.mcap`` holding the goals, the feedback and the
outcomes, and its report. One run serves those tests (in this order: each starts where the one
before left the robot); two more in the bump world, a goal behind the box: navigated around it
(``completed``, no bump, no hold of the collision monitor: issue 51), and along the straight line
(``navigation.enabled = false``: ``aborted``, naming the box, exit 3). A goal file run by ``invent up --goal-file``: lockstep, ending with the drive's last goal."""

from __future__ import annotations

import json
import math
import queue
import re
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from schemas.codec import decode
from schemas.keys import Keys, Service
from schemas.messages import TimedDoubleSeq
from schemas.topics import Topic
from services.config import DriveConfig, GoalsConfig
from services.exits import ExitStatus
from services.planar import Pose, wrap_angle
from services.recording.mcap_files import read_run
from services.recording.report import pose_from_body_pose
from tests.harness import REPO, InventProcess, call, free_port, invent_command, peer_session, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys()
STARTUP_TIMEOUT_S = 90.0
GOAL_TIMEOUT_S = 60.0
"""Wall seconds a goal of these tests may take (a few simulated seconds, realtime, on a loaded machine)."""
GOALS = GoalsConfig()
DRIVE = DriveConfig()


@dataclass
class GoalsRun:
    """A running ``invent up --goals``: its router's endpoint, a session on it, the ground truth as it comes."""

    endpoint: str
    session: zenoh.Session
    up: subprocess.Popen[str]
    output: Path
    report: Path

    def __post_init__(self) -> None:
        self._poses: queue.Queue[bytes] = queue.Queue()
        self.session.declare_subscriber(KEYS.sim_body_pose, lambda sample: self._poses.put(sample.payload.to_bytes()))

    def stepping(self) -> bool:
        """Whether the sim's body poses come."""
        return not self._poses.empty()

    def ground_truth(self) -> Pose:
        """The simulated body's pose (the axle centre's x, y and heading) from a sample published now."""
        while not self._poses.empty():
            self._poses.get_nowait()
        return pose_from_body_pose(decode(TimedDoubleSeq, self._poses.get(timeout=10.0)).data)

    def goto(self, *args: str) -> InventProcess:
        return InventProcess("goto", *args, "--connect", self.endpoint)

    def stop(self) -> int:
        """Ctrl-C: ``up`` stops everything, writes its recording and report; its exit status."""
        if self.up.poll() is None:
            self.up.send_signal(signal.SIGINT)
        try:
            return self.up.wait(120)
        except subprocess.TimeoutExpired:
            self.up.kill()
            raise AssertionError(f"invent up did not stop on Ctrl-C:\n{self.output.read_text()[-3000:]}") from None


@contextmanager
def goals_run(directory: Path, *flags: str, record: bool = True) -> Iterator[GoalsRun]:
    """``invent up --goals FLAGS`` on a router of its own (``record``: into ``directory/report``, else
    ``--no-record``), once its sim steps; stopped (Ctrl-C) at the end if a test did not."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    output = directory / "up.log"
    report = directory / "report"
    recording = ["--report", str(report)] if record else ["--no-record"]
    with output.open("w") as log:
        up = subprocess.Popen(
            invent_command("up", "--goals", "--listen", endpoint, *recording, *flags),
            cwd=REPO,
            stdout=log,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            with peer_session(endpoint) as session:
                run = GoalsRun(endpoint, session, up, output, report)
                wait_until(lambda: run.stepping() or up.poll() is not None, STARTUP_TIMEOUT_S, "the sim's first steps")
                assert up.poll() is None, output.read_text()[-3000:]
                yield run
        finally:
            if up.poll() is None:
                up.send_signal(signal.SIGINT)
                try:
                    up.wait(120)
                except subprocess.TimeoutExpired:
                    up.kill()


FAST = ("--composed", "--set", "sim.realtime_factor=2")
"""The runs' services in one process, paced at twice the wall clock: the goals are the same in
simulation time (the control runs on it), in half the wall time; the suite's time is short."""


@pytest.fixture(scope="module")
def loop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GoalsRun]:
    with goals_run(tmp_path_factory.mktemp("goals"), *FAST) as run:
        yield run


def _lines_until(goto: InventProcess, done: Callable[[str], bool], timeout: float = GOAL_TIMEOUT_S) -> list[str]:
    """``goto``'s output lines as they come, up to the first that is ``done`` (or its end)."""
    assert goto.process.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = goto.process.stdout.readline()
        if not line:
            return lines
        lines.append(line.rstrip("\n"))
        if done(lines[-1]):
            return lines
    raise AssertionError(f"invent goto {' '.join(goto.args)}: nothing done within {timeout} s:\n" + "\n".join(lines))


def _ended(goto: InventProcess) -> tuple[int, list[str], str]:
    """Once ``goto`` has exited by itself: its exit status, its output lines, its stderr."""
    out, err = goto.process.communicate(timeout=GOAL_TIMEOUT_S)
    return goto.process.returncode, out.splitlines(), err


_DISTANCE = re.compile(r"executing: (\d+\.\d+) m to go")


def test_a_goal_is_reached_within_its_tolerance_by_the_ground_truth_and_goto_exits_0(loop):
    with loop.goto("1.5", "0.5", "1.57") as goto:
        code, lines, err = _ended(goto)
    truth = loop.ground_truth()
    assert code == ExitStatus.OK, "\n".join(lines) + err
    assert lines[0].startswith("goal g1 accepted by rh0's drive: x +1.500 y +0.500 theta +1.570 in map")
    assert lines[-1].startswith("outcome: completed (goal g1 after ")
    progress = [line for line in lines if "to go" in line]
    elapsed = float(lines[-1].split("after ")[1].split(" s")[0])
    assert 1 <= len(progress) <= elapsed + 2, "about a line a second of wall time (here half a simulated second)"
    error = math.hypot(truth.x - 1.5, truth.y - 0.5)
    heading_error = abs(wrap_angle(truth.theta - 1.57))
    assert error <= GOALS.position_tolerance and heading_error <= GOALS.heading_tolerance, (truth, error, heading_error)


def test_a_goal_canceled_halfway_brakes_and_stops_and_goto_exits_5(loop):
    start = loop.ground_truth()
    goal = (-0.5, 0.5)
    whole = math.dist((start.x, start.y), goal)
    with loop.goto(str(goal[0]), str(goal[1])) as goto:
        _lines_until(goto, lambda line: "executing" in line)
        halfway = wait_until(
            lambda: (pose := loop.ground_truth()) and math.dist((pose.x, pose.y), goal) <= whole / 2 and pose,
            GOAL_TIMEOUT_S,
            "the robot halfway to its goal",
        )
        goto.process.send_signal(signal.SIGINT)
        code, lines, err = _ended(goto)
    assert code == ExitStatus.CANCELED == 5, "\n".join(lines) + err
    assert any(line.startswith("canceling goal g2") for line in lines), lines
    assert lines[-1].startswith("outcome: canceled (goal g2 after "), lines
    stopped = loop.ground_truth()
    time.sleep(1.0)  # the robot's stillness is the condition: it must not move over a second
    later = loop.ground_truth()
    assert math.dist((stopped.x, stopped.y), (later.x, later.y)) < 0.005, "at rest once canceled"
    # goto's reaction (a tenth of a second of wall time, two of simulation time) at cruise speed, then braking
    reaction = DRIVE.cruise_speed * 0.3
    braking = math.dist((halfway.x, halfway.y), (later.x, later.y))
    assert braking <= reaction + DRIVE.cruise_speed**2 / (2 * DRIVE.max_acceleration) + 0.05, (
        f"braked in {braking:.3f} m"
    )
    assert math.dist((later.x, later.y), goal) >= whole / 4, "stopped well short of the goal"


def test_a_second_goal_preempts_the_first_which_exits_5_while_the_second_exits_0(loop):
    with loop.goto("1.0", "-0.5") as first:
        _lines_until(first, lambda line: "executing" in line)
        with loop.goto("0.5", "0.0") as second:
            first_code, first_lines, first_err = _ended(first)
            second_code, second_lines, second_err = _ended(second)
    assert first_code == ExitStatus.CANCELED, "\n".join(first_lines) + first_err
    assert second_code == ExitStatus.OK, "\n".join(second_lines) + second_err
    second_id = second_lines[0].split()[1]
    assert first_lines[-1].startswith("outcome: canceled (goal g3 after ")
    assert first_lines[-1].endswith(f"preempted by goal {second_id!r}"), first_lines[-1]
    assert second_lines[-1].startswith(f"outcome: completed (goal {second_id} after ")
    truth = loop.ground_truth()
    assert math.hypot(truth.x - 0.5, truth.y) <= GOALS.position_tolerance, truth


def test_a_goal_the_drive_rejects_exits_1_with_its_reason(loop):
    with loop.goto("1", "0", "--position-tolerance", "0") as goto:
        code, lines, err = _ended(goto)
    assert code == ExitStatus.FAILURE and lines == [], err
    assert "goal rejected:" in err and "position_tolerance" in err, err


def test_ctrl_c_ends_the_goals_run_with_exit_0_its_recording_of_the_goals_and_its_report(loop):
    code = loop.stop()
    output = loop.output.read_text()
    assert code == ExitStatus.OK, output[-3000:]
    assert "scenario goals (realtime)" in output
    topics = {message.topic for message in read_run(loop.report / "run.mcap").messages}
    assert {KEYS.topic(t) for t in (Topic.DRIVE_GOAL, Topic.DRIVE_GOAL_FEEDBACK, Topic.DRIVE_OUTCOME)} <= topics
    report = json.loads((loop.report / "report.json").read_text())
    assert report["scenario"] == "goals" and report["mode"] == "realtime", report["scenario"]
    assert report["outcome"]["outcome"] == "completed", "the last goal's"
    ended = [(goal["id"], goal["outcome"]) for goal in report["goals"]]
    assert ended == [("g1", "completed"), ("g2", "canceled"), ("g3", "canceled"), ("g4", "completed")], ended
    assert all(goal["feedbacks"] > 0 for goal in report["goals"]), "each goal's progress recorded"


def test_a_goal_behind_the_box_of_the_bump_world_is_reached_around_it_touching_nothing_and_goto_exits_0(tmp_path):
    """Issue 51's first "Must show": the goal the straight line could not reach (below), navigated."""
    with goals_run(tmp_path, *FAST, "--set", "sim.world=bump", record=False) as run:
        with run.goto("2.0", "0.0", "0.0") as goto:
            code, lines, err = _ended(goto)
        truth = run.ground_truth()
        _, sim = call(run.session, KEYS.status(Service.SIM))
        _, motor = call(run.session, KEYS.status(Service.MOTOR))
        assert run.stop() == ExitStatus.OK, run.output.read_text()[-3000:]
    assert code == ExitStatus.OK, "\n".join(lines) + err
    assert lines[-1].startswith("outcome: completed (goal g1 after "), lines
    assert math.hypot(truth.x - 2.0, truth.y) <= GOALS.position_tolerance, truth
    assert abs(wrap_angle(truth.theta)) <= GOALS.heading_tolerance, truth
    assert sim["counters"]["bumps"] == 0, "no bump"
    assert motor["collision_monitor"]["counters"]["holds"] == 0, "the collision monitor never held the robot"
    assert (sim["congestion"], motor["congestion"]) == ("drop", "drop"), "realtime: a reader never delays the loop"


def test_along_the_straight_line_a_goal_behind_the_box_ends_aborted_naming_it_and_goto_exits_3(tmp_path):
    """``navigation.enabled = false``: the straight line, as before the navigation; the monitor holds
    the robot short of the box, and the hold gives the goal up."""
    with goals_run(
        tmp_path, *FAST, "--set", "sim.world=bump", "--set", "navigation.enabled=false", record=False
    ) as run:
        with run.goto("2.0", "0.0") as goto:
            code, lines, err = _ended(goto)
        truth = run.ground_truth()
        assert run.stop() == ExitStatus.OK, run.output.read_text()[-3000:]
    assert code == ExitStatus.ABORTED == 3, "\n".join(lines) + err
    assert lines[-1].startswith("outcome: aborted (goal g1 after "), lines
    assert "'box'" in lines[-1], "the reason names the box"
    assert truth.x < 0.45, "short of the box (its face at x = 0.9, the body's radius 0.45 m)"


def test_up_with_a_goal_file_runs_it_in_lockstep_and_ends_with_its_last_goals_outcome(tmp_path):
    goal_file = tmp_path / "there_and_back.toml"
    goal_file.write_text(
        "[[goals]]\nat = 0.0\nx = 0.5\ny = 0.0\n\n[[goals]]\nat = 0.5\nx = 0.0\ny = 0.0\ntheta = 0.0\n"
    )
    result = subprocess.run(
        invent_command("up", "--composed", "--goal-file", str(goal_file), "--report", str(tmp_path / "report")),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert result.returncode == ExitStatus.OK, result.stdout[-4000:] + result.stderr[-2000:]
    assert f"scenario {goal_file} (lockstep)" in result.stdout, result.stdout[-4000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["mode"] == "lockstep" and report["outcome"]["outcome"] == "completed", report["outcome"]
