"""``invent drive --goals`` and ``--goal-file`` in their own process, in the synthetic loop of
tests/test_drive_service.py (the test is the clock and an ideal unicycle plant): goals sent and
canceled over zenoh, the feedback, the started goal and each result, bad requests, goal files."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import LaserScan, MotorStateReport, ScenarioOutcome, Time, TimedVelocity
from schemas.navigation import GoalFeedback, GoalTarget
from services.clock.lockstep import encode_mark
from services.config import GoalsConfig
from services.exits import ExitStatus
from services.planar import Pose, wrap_angle
from tests.harness import Collector, call, status_reply, wait_alive, wait_until
from tests.test_drive_service import TICK_NS, SyntheticLoop, drive

KEYS = Keys()
GOALS = GoalsConfig()


def drive_status(session: zenoh.Session) -> dict:
    return status_reply(session, KEYS, Service.DRIVE)


def until(loop: SyntheticLoop, command: TimedVelocity, done, max_ticks: int = 3000) -> TimedVelocity:
    """Tick the loop until ``done()``; the last command."""
    for _ in range(max_ticks):
        if done():
            return command
        command = loop.next_command(command)
    raise AssertionError("the condition never came")


def test_goals_sent_over_zenoh_are_reached_preempted_canceled_and_bad_ones_refused(
    endpoint: str, session: zenoh.Session
) -> None:
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    outcomes = Collector(session, KEYS.drive_outcome, ScenarioOutcome)
    started = Collector(session, KEYS.drive_goal, GoalTarget)
    feedback = Collector(session, KEYS.drive_goal_feedback, GoalFeedback)
    with drive(endpoint, "--goals") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        command = loop.first_command()
        for _ in range(5):
            command = loop.next_command(command)
        assert (command.vx, command.w) == (0.0, 0.0), "no goal: zero"
        assert drive_status(session)["state"] == "waiting_for_goal"

        ok, reply = call(session, KEYS.drive_goal_send, json.dumps({"x": 1.0, "y": 0.5, "theta": 1.0}))
        assert ok and reply == {"accepted": True, "id": "g1", "reason": ""}
        command = until(loop, command, lambda: not outcomes.samples.empty())
        first = outcomes.get()
        assert (first.goal_id, first.outcome, first.reason, first.scenario) == ("g1", "completed", "", "goals")
        assert math.hypot(loop.pose.x - 1.0, loop.pose.y - 0.5) <= GOALS.position_tolerance
        assert abs(wrap_angle(loop.pose.theta - 1.0)) <= GOALS.heading_tolerance
        target = started.get()
        assert (target.id, target.x, target.y, target.theta, target.frame) == ("g1", 1.0, 0.5, 1.0, "map")
        assert target.position_tolerance == GOALS.position_tolerance and target.time_limit_s is not None
        ok, latched = call(session, KEYS.drive_goal)
        assert ok and latched["id"] == "g1", "drive/goal is latched"
        progress = feedback.drain()
        assert progress and {p.id for p in progress} == {"g1"} and {p.state for p in progress} == {"executing"}
        spacing = {b.tm.to_nanoseconds() - a.tm.to_nanoseconds() for a, b in itertools.pairwise(progress)}
        assert spacing == {round(1e9 / GOALS.feedback_rate)}, "at goals.feedback_rate of simulation time"
        assert progress[0].distance_remaining > progress[-1].distance_remaining

        # a bad goal, a bad payload and a bad cancel: refused with the reason, counted
        ok, refused = call(session, KEYS.drive_goal_send, json.dumps({"x": 1.0, "y": 0.0, "heading_tolerance": 0}))
        assert ok and not refused["accepted"] and "heading_tolerance" in refused["reason"]
        ok, garbage = call(session, KEYS.drive_goal_send, b"\xff" * 64)
        assert ok and not garbage["accepted"] and "not a GoalRequest" in garbage["reason"]
        ok, unknown = call(session, KEYS.drive_goal_cancel, json.dumps({"id": "nobody"}))
        assert ok and unknown == {"canceling": [], "reason": "unknown goal id 'nobody'"}

        # a long goal, preempted by a second, which is then canceled halfway
        ok, long = call(session, KEYS.drive_goal_send, json.dumps({"x": 4.0, "y": 0.5}))
        assert ok and long["accepted"]
        for _ in range(100):
            command = loop.next_command(command)
        assert command.vx > 0.2
        ok, second = call(session, KEYS.drive_goal_send, json.dumps({"x": 3.0, "y": 2.0, "id": "second"}))
        assert ok and second == {"accepted": True, "id": "second", "reason": ""}
        command = until(loop, command, lambda: not outcomes.samples.empty())
        preempted = outcomes.get()
        assert (preempted.goal_id, preempted.outcome, preempted.reason) == (
            long["id"],
            "canceled",
            "preempted by goal 'second'",
        )
        assert command.vx > 0.2, "no stop between the two"
        for _ in range(50):
            command = loop.next_command(command)
        ok, canceling = call(session, KEYS.drive_goal_cancel, b"")
        assert ok and canceling == {"canceling": ["second"], "reason": ""}
        command = until(loop, command, lambda: not outcomes.samples.empty())
        canceled = outcomes.get()
        assert (canceled.goal_id, canceled.outcome) == ("second", "canceled")
        assert (command.vx, command.w) == (0.0, 0.0), "braked to a stop before it ended"
        assert math.hypot(loop.pose.x - 3.0, loop.pose.y - 2.0) > 0.5, "canceled before it got there"

        status = drive_status(session)
        goals = status["goals"]
        assert (goals["accepted"], goals["completed"], goals["canceled"]) == (3, 1, 2)
        assert (goals["rejected"], goals["cancel_rejected"]) == (2, 1)
        assert {key: bad["count"] for key, bad in status["bad_input"]["by_key"].items()} == {KEYS.drive_goal_send: 1}

        # the motor latched stopped: a goal is refused, saying so
        session.put(KEYS.motor_state, encode(MotorStateReport(Time.from_nanoseconds(loop.now_ns), "stopped", "gui")))
        wait_until(
            lambda: not call(session, KEYS.drive_goal_send, json.dumps({"x": 0.0, "y": 0.0}))[1]["accepted"],
            what="a goal refused while the motor is stopped",
        )
        ok, stopped = call(session, KEYS.drive_goal_send, json.dumps({"x": 0.0, "y": 0.0}))
        assert "latched stopped (by gui)" in stopped["reason"]
        assert process.process.poll() is None, "goal mode runs until stopped"
        assert process.stop()[0] == 0


GOAL_FILE = """
[[goals]]
at = 0.0
x = 1.0
y = 0.0

[[goals]]
at = 2.0
x = 1.0
y = 1.0
theta = 3.14

[[goals]]
at = 4.0
cancel = true
"""


def _goal_file_run(endpoint: str, session: zenoh.Session, path: Path) -> tuple[int, list, list]:
    """The goal file played against the synthetic loop in lockstep: the clock carries a lockstep mark
    and an odometry token is alive, so the drive commands each tick from that tick's pose (without
    them it takes the newest pose it has when the clock comes, which varies with the machine's load)."""
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    outcomes = Collector(session, KEYS.drive_outcome, ScenarioOutcome)
    odometry = session.liveliness().declare_token(KEYS.alive(Service.ODOMETRY))
    try:
        with drive(endpoint, "--goal-file", str(path)) as process:
            wait_alive(session, KEYS.alive(Service.DRIVE))
            wait_until(lambda: drive_status(session)["odometry_alive"], what="the drive to see odometry")
            loop = SyntheticLoop(session, commands)
            loop.clock_attachment = encode_mark({}, observed=True)
            first = loop.first_command()
            received = loop.until_final_zeros(first)
            code = process.process.wait(timeout=10)
        start_ns = first.tm.to_nanoseconds()
        return (
            code,
            [(c.tm.to_nanoseconds() - start_ns, c.vx, c.w) for c in received],
            [(o.goal_id, o.outcome, o.reason, o.tm.to_nanoseconds() - start_ns) for o in outcomes.drain()],
        )
    finally:
        odometry.undeclare()
        commands.close()
        outcomes.close()


def test_a_goal_file_plays_the_same_commands_every_time_and_exits_with_its_last_goals_outcome(
    endpoint: str, session: zenoh.Session, tmp_path: Path
) -> None:
    path = tmp_path / "goals.toml"
    path.write_text(GOAL_FILE)
    code, commands, outcomes = _goal_file_run(endpoint, session, path)
    assert code == ExitStatus.CANCELED
    assert [(goal, outcome) for goal, outcome, _, _ in outcomes] == [("g1", "canceled"), ("g2", "canceled")]
    assert outcomes[0][2] == "preempted by goal 'g2'" and outcomes[0][3] == 2_000_000_000
    assert outcomes[1][2] == "canceled"
    assert commands[-1][1:] == (0.0, 0.0)
    assert [stamp for stamp, _, _ in commands] == [k * TICK_NS for k in range(len(commands))]
    assert _goal_file_run(endpoint, session, path) == (code, commands, outcomes), "the same, tick for tick"


def _scan(stamp_ns: int, reach: float = 2.0) -> bytes:
    """A full circle of 360 returns at ``reach`` m, stamped ``stamp_ns``."""
    return encode(LaserScan(Time.from_nanoseconds(stamp_ns), -math.pi, math.tau / 360, 0.12, 3.5, [reach] * 360))


def test_scans_with_wrong_stamps_or_off_the_costmap_are_dropped_counted_and_the_drive_navigates_on(
    endpoint: str, session: zenoh.Session
) -> None:
    """``sim/scan`` as a buggy or hostile peer sends it to a goal-mode drive (a costmap of 4 m around
    the start): a scan not after the last, one stamped beyond ``input.stamp_horizon``, one whose lidar
    lies off the costmap: each dropped, counted under ``sim/scan``, the costmap unchanged by it; the
    drive lives on and a goal then completes."""
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    outcomes = Collector(session, KEYS.drive_outcome, ScenarioOutcome)
    with drive(endpoint, "--goals", "--set", "navigation.size=4") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        scans = session.declare_publisher(KEYS.sim_scan)
        wait_until(lambda: scans.matching_status.matching, what="the drive's scan subscriber")
        command = loop.first_command()
        scans.put(_scan(loop.now_ns + TICK_NS))
        command = loop.next_command(command)
        scans.put(_scan(loop.now_ns))  # not after the last
        scans.put(_scan(loop.now_ns + 10 * 10**9))  # 10 s ahead of the drive's tick
        loop.pose = Pose(5.0, 0.0, 0.0)  # the lidar 3 m beyond the costmap's edge, from this tick on
        command = loop.next_command(command)
        scans.put(_scan(loop.now_ns + TICK_NS))
        for _ in range(5):
            command = loop.next_command(command)
        status = drive_status(session)
        assert status["bad_input"]["by_key"][KEYS.sim_scan]["count"] == 3, (status["bad_input"], status["navigation"])
        assert status["navigation"]["scans"] == 1 and status["navigation"]["costmap"]["scans"] == 1
        assert status["internal_errors"] == 0 and process.process.poll() is None

        loop.pose = Pose(0.0, 0.0, 0.0)
        ok, reply = call(session, KEYS.drive_goal_send, json.dumps({"x": 0.8, "y": 0.0}))
        assert ok and reply["accepted"], reply
        until(loop, command, lambda: not outcomes.samples.empty())
        assert outcomes.get().outcome == "completed"
