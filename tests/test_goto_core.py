"""``invent goto``'s logic without zenoh (services/goto/core.py): the request it sends, its lines,
when a progress line is due (about once a second of wall time, at once on a change of state), which
samples are its goal's, and the exit status of each outcome."""

from __future__ import annotations

import itertools
import math

from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import decode, encode
from schemas.messages import ScenarioOutcome, Time
from schemas.navigation import CancelReply, GoalFeedback, GoalReply, GoalRequest, GoalTarget
from services.drive.outcome import EXIT_CODES, Outcome
from services.exits import ExitStatus
from services.goto.core import (
    PROGRESS_INTERVAL_S,
    Progress,
    accepted_line,
    cancel_line,
    exit_status,
    feedback_line,
    goal_request,
    outcome_line,
    rejected_line,
    started_line,
)


def _feedback(goal_id: str = "g1", state: str = "executing", elapsed_s: float = 1.0) -> GoalFeedback:
    return GoalFeedback(
        tm=Time(3, 0),
        id=goal_id,
        state=state,  # type: ignore[arg-type]
        x=0.512,
        y=0.17,
        theta=0.33,
        distance_remaining=1.234,
        elapsed_s=elapsed_s,
        estimated_remaining_s=3.14,
    )


def _outcome(outcome: str = "completed", goal_id: str = "g1", reason: str = "") -> ScenarioOutcome:
    return ScenarioOutcome(
        tm=Time(9, 0),
        scenario="goals",
        outcome=outcome,  # type: ignore[arg-type]
        reason=reason,
        iteration=0,
        elapsed_s=6.4219,
        goal_id=goal_id,
    )


def test_the_request_says_only_what_was_given_and_the_drive_defaults_the_rest():
    request = goal_request(1.5, 0.5, 1.57)
    assert request == GoalRequest(x=1.5, y=0.5, theta=1.57)
    assert decode(GoalRequest, encode(request)) == request
    everything = goal_request(-1.0, 2.0, frame="odom", time_limit=30.0, position_tolerance=0.1, heading_tolerance=0.2)
    assert (everything.theta, everything.frame, everything.time_limit) == (None, "odom", 30.0)
    assert (everything.position_tolerance, everything.heading_tolerance, everything.id) == (0.1, 0.2, "")
    assert goal_request(0.0, 0.0, position_tolerance=0.0).position_tolerance == 0.0, "the drive judges, not the tool"


def test_each_outcome_exits_with_its_code_completed_0_aborted_3_timed_out_4_canceled_5():
    assert {name: exit_status(_outcome(name)) for name in ("completed", "aborted", "timed_out", "canceled")} == {
        "completed": ExitStatus.OK,
        "aborted": ExitStatus.ABORTED,
        "timed_out": ExitStatus.TIMED_OUT,
        "canceled": ExitStatus.CANCELED,
    }
    assert {outcome: exit_status(_outcome(str(outcome))) for outcome in Outcome} == EXIT_CODES
    assert (ExitStatus.ABORTED, ExitStatus.TIMED_OUT, ExitStatus.CANCELED) == (3, 4, 5)


def test_the_lines_say_the_goal_its_progress_and_its_end():
    request = goal_request(1.5, 0.5, 1.57)
    assert accepted_line("rh0", GoalReply(True, "g1"), request) == (
        "goal g1 accepted by rh0's drive: x +1.500 y +0.500 theta +1.570 in map"
    )
    assert "any heading in odom" in accepted_line("rh1", GoalReply(True, "g2"), goal_request(1, 2, frame="odom"))
    assert rejected_line(GoalReply(False, "", "position_tolerance must be > 0")) == (
        "goal rejected: position_tolerance must be > 0"
    )
    target = GoalTarget(Time(12, 340_000_000), "g1", 1.5, 0.5, None, "odom", 0.05, 0.1, None)
    assert started_line(target) == (
        "goal g1 started at t = 12.340 s: x +1.500 y +0.500 any heading in map (given in odom); "
        "within 0.050 m and 0.100 rad; time limit none"
    )
    assert feedback_line(_feedback()) == (
        "goal g1 executing: 1.23 m to go, 1.0 s elapsed, about 3.1 s left; pose x +0.512 y +0.170 theta +0.330"
    )
    assert cancel_line("g1", CancelReply(["g1"])) == "canceling goal g1"
    assert cancel_line("g1", CancelReply([], "no goal runs")) == "cancel of goal g1 not taken: no goal runs"
    assert outcome_line(_outcome()) == "outcome: completed (goal g1 after 6.42 s)"
    assert outcome_line(_outcome("aborted", reason="bumped into 'box'")) == (
        "outcome: aborted (goal g1 after 6.42 s): bumped into 'box'"
    )


def test_only_the_goals_own_samples_count_and_its_outcome_ends_it_once():
    progress = Progress("g2")
    assert progress.on_feedback(_feedback("g1"), 0.0) is None, "another goal's feedback"
    assert progress.on_target(GoalTarget(Time(1, 0), "g1", 0, 0, None, "map", 0.05, 0.1, None)) is None
    assert not progress.started
    assert progress.on_target(GoalTarget(Time(1, 0), "g2", 0, 0, None, "map", 0.05, 0.1, 9.0)) is not None
    assert progress.on_target(GoalTarget(Time(1, 0), "g2", 0, 0, None, "map", 0.05, 0.1, 9.0)) is None, "said once"
    assert progress.on_outcome(_outcome("canceled", "g1", "preempted by goal g2")) is None, "the goal g2 preempted"
    assert progress.ending is None
    ending = progress.on_outcome(_outcome("aborted", "g2", "held"))
    assert ending is not None and ending.status == ExitStatus.ABORTED and ending.line.endswith(": held")
    assert progress.on_outcome(_outcome("completed", "g2")) is None and progress.ending is ending
    assert progress.on_feedback(_feedback("g2"), 10.0) is None, "nothing after the end"


def test_a_progress_line_comes_first_then_about_once_a_second_and_at_once_when_the_state_changes():
    progress = Progress("g1")
    # the drive's feedback at 5 Hz of simulated time, in lockstep at ten times the wall clock: 50 a second
    printed = [wall / 50 for wall in range(250) if progress.on_feedback(_feedback(), wall / 50)]
    assert printed == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert progress.on_feedback(_feedback(state="canceling"), 4.99) is not None, "canceling: at once"
    assert progress.on_feedback(_feedback(state="canceling"), 5.5) is None
    assert progress.on_feedback(_feedback(state="canceling"), 5.99) is not None


@given(
    st.lists(
        st.tuples(st.floats(0.0, 3.0, allow_nan=False), st.sampled_from(["executing", "canceling"])),
        max_size=200,
    )
)
def test_progress_lines_of_one_state_are_at_least_the_interval_apart_and_every_change_of_state_is_printed(steps):
    progress = Progress("g1")
    wall, printed, last_state = 0.0, [], None
    for step, state in steps:
        wall += step
        line = progress.on_feedback(_feedback(state=state), wall)
        changed = state != last_state
        assert (line is not None) or not changed, "a change of state is always said"
        if line is not None:
            printed.append((wall, state, changed))
            last_state = state
    for (earlier, _, _), (later, _, changed) in itertools.pairwise(printed):
        assert changed or later - earlier >= PROGRESS_INTERVAL_S
    if steps:
        span = sum(step for step, _ in steps)
        changes = sum(1 for _, _, changed in printed if changed)
        assert len(printed) <= changes + math.floor(span / PROGRESS_INTERVAL_S) + 1
