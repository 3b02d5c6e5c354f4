"""``invent goto`` as a process against a stand-in drive on a real router (tests/goal_standin.py):
the goal it sends, its lines, its exit for each path: a goal followed to its outcome (another goal's
samples ignored), Ctrl-C and SIGTERM canceling it (exit 5), an outcome whose sample was missed found
on the latched key, a rejection (exit 1 with the reason), nothing answering (exit 1 naming the key),
a drive that goes away; and its flags' checks. With the real drive and loop: tests/test_goto_up.py."""

from __future__ import annotations

import signal
from collections.abc import Iterator

import pytest

from schemas.codec import encode
from schemas.keys import Keys
from schemas.messages import ScenarioOutcome, Time
from schemas.navigation import GoalFeedback, GoalReply, GoalRequest, GoalTarget
from services.exits import ExitStatus
from tests.goal_standin import StandInDrive
from tests.harness import InventProcess, peer_session, refused, run_invent, running_router, wait_until

KEYS = Keys("rh0")


def _accept(goal_id: str = "g7"):
    return lambda _request: GoalReply(True, goal_id)


def _feedback(goal_id: str, state: str = "executing", elapsed_s: float = 0.2) -> GoalFeedback:
    return GoalFeedback(Time(1, 0), goal_id, state, 0.1, 0.0, 0.0, 1.5, elapsed_s, 3.0)  # type: ignore[arg-type]


def _outcome(outcome: str, goal_id: str, reason: str = "") -> ScenarioOutcome:
    return ScenarioOutcome(Time(5, 0), "goals", outcome, reason, 0, 4.2, goal_id)  # type: ignore[arg-type]


@pytest.fixture
def endpoint() -> Iterator[str]:
    with running_router() as endpoint:
        yield endpoint


def _goto(endpoint: str, *args: str) -> InventProcess:
    return InventProcess("goto", *args, "--connect", endpoint)


def _ended(goto: InventProcess) -> tuple[int, str, str]:
    """Once ``goto`` has exited by itself: its exit status, stdout and stderr."""
    out, err = goto.process.communicate(timeout=20)
    return goto.process.returncode, out, err


def test_a_goal_is_sent_followed_and_its_outcome_is_the_exit_status_other_goals_ignored(endpoint):
    with peer_session(endpoint) as session:
        drive = StandInDrive(session, KEYS, _accept())
        with _goto(endpoint, "1.5", "0.5", "1.57", "--frame", "odom", "--timeout", "30") as goto:
            assert drive.goals.get(timeout=20) == GoalRequest(x=1.5, y=0.5, theta=1.57, frame="odom", time_limit=30.0)
            drive.wait_for_subscribers()
            drive.publish(KEYS.drive_outcome, _outcome("canceled", "g6", "preempted by goal g7"))
            drive.publish(KEYS.drive_goal, GoalTarget(Time(1, 0), "g7", 1.5, 0.5, 1.57, "odom", 0.05, 0.1, 30.0))
            for elapsed in (0.2, 0.4, 0.6):
                drive.publish(KEYS.drive_goal_feedback, _feedback("g6", elapsed_s=elapsed))
                drive.publish(KEYS.drive_goal_feedback, _feedback("g7", elapsed_s=elapsed))
            drive.publish(KEYS.drive_outcome, _outcome("completed", "g7"))
            code, out, err = _ended(goto)
        drive.close()
    assert code == ExitStatus.OK, err
    lines = out.splitlines()
    assert lines[0] == "goal g7 accepted by rh0's drive: x +1.500 y +0.500 theta +1.570 in odom"
    assert lines[-1] == "outcome: completed (goal g7 after 4.20 s)"
    assert any(line.startswith("goal g7 started at t = 1.000 s") for line in lines)
    progress = [line for line in lines if "to go" in line]
    assert progress == [
        "goal g7 executing: 1.50 m to go, 0.2 s elapsed, about 3.0 s left; pose x +0.100 y +0.000 theta +0.000"
    ]
    assert "g6" not in out, "another goal's samples are not this goal's"
    assert "cancel" not in out


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_ctrl_c_or_sigterm_cancels_the_goal_waits_for_its_outcome_and_exits_5(endpoint, signum):
    with peer_session(endpoint) as session:
        drive = StandInDrive(session, KEYS, _accept("g3"))
        with _goto(endpoint, "2", "0") as goto:
            drive.goals.get(timeout=20)
            drive.wait_for_subscribers()
            drive.publish(KEYS.drive_goal_feedback, _feedback("g3"))
            goto.process.send_signal(signum)
            assert drive.cancels.get(timeout=10).id == "g3", "the cancel names the goal"
            drive.publish(KEYS.drive_goal_feedback, _feedback("g3", "canceling"))
            drive.publish(KEYS.drive_outcome, _outcome("canceled", "g3", "canceled by a cancel"))
            code, out, err = _ended(goto)
        drive.close()
    assert code == ExitStatus.CANCELED == 5, err
    assert "canceling goal g3" in out and "goal g3 canceling:" in out
    assert out.splitlines()[-1] == "outcome: canceled (goal g3 after 4.20 s): canceled by a cancel"


def test_an_outcome_whose_sample_was_missed_is_found_on_the_latched_key(endpoint):
    with peer_session(endpoint) as session:
        drive = StandInDrive(session, KEYS, _accept("g4"))
        with _goto(endpoint, "0.5", "0.5") as goto:
            drive.goals.get(timeout=20)
            # as if the sample went out before goto's subscription reached the drive: only the latch has it
            drive.latched_outcome = encode(_outcome("aborted", "g4", "held by the collision monitor"))
            code, out, err = _ended(goto)
        drive.close()
    assert code == ExitStatus.ABORTED == 3, err
    assert out.splitlines()[-1] == "outcome: aborted (goal g4 after 4.20 s): held by the collision monitor"


def test_a_rejected_goal_exits_1_with_the_drives_reason(endpoint):
    reason = "position_tolerance must be > 0, not 0"
    with peer_session(endpoint) as session:
        drive = StandInDrive(session, KEYS, lambda _request: GoalReply(False, "", reason))
        result = run_invent("goto", "1", "0", "--position-tolerance", "0", "--connect", endpoint)
        assert drive.goals.get_nowait().position_tolerance == 0.0, "sent as given: the drive judges"
        drive.close()
    assert result.returncode == ExitStatus.FAILURE, result.stderr
    assert f"goal rejected: {reason}" in result.stderr and "accepted" not in result.stdout


def test_nothing_answering_exits_1_naming_the_key(endpoint):
    result = run_invent("goto", "1", "0", "--robot", "rh9", "--wait", "0.5", "--connect", endpoint)
    assert result.returncode == ExitStatus.FAILURE
    assert f"nothing answers on {Keys('rh9').drive_goal_send}" in result.stderr, result.stderr


def test_a_drive_that_goes_away_while_the_goal_runs_ends_goto_with_1(endpoint):
    with peer_session(endpoint) as session:
        drive = StandInDrive(session, KEYS, _accept("g5"))
        with _goto(endpoint, "1", "1") as goto:
            drive.goals.get(timeout=20)
            wait_until(lambda: "accepted" in goto.process.stdout.readline(), 20, "goto to say the goal was accepted")
            drive.close()
            code, _out, err = _ended(goto)
    assert code == ExitStatus.FAILURE
    assert "rh0's drive is gone (its token withdrawn) before goal g5 ended" in err


@pytest.mark.parametrize(
    ("args", "named"),
    [(("1", "nan"), "argument Y"), (("1", "0", "inf"), "argument THETA"), (("1", "0", "--frame", "base"), "--frame")],
)
def test_a_bad_argument_exits_2_naming_it(args, named, capsys):
    code, _out, stderr = refused(capsys, "goto", *args)
    assert code == ExitStatus.CONFIG and named in stderr, stderr
