"""What ``invent goto`` asks, prints and exits with (pure, no zenoh): the goal request from its
arguments, one line per thing worth saying (accepted or rejected, started, its progress, the cancel,
the outcome), when a progress line is due, and the exit status of the goal's outcome
(docs/protocol.md section 7.3; the outcomes' codes: services/drive/outcome.py's ``EXIT_CODES``).

The drive sends feedback at ``goals.feedback_rate`` per simulated second (5 Hz; in lockstep a
simulated second may take much less than a second of wall time), so :class:`Progress` prints one
progress line about every :data:`PROGRESS_INTERVAL_S` of wall time, and at once when the goal's
state changes (``executing`` to ``canceling``): a line a second, not a flood."""

from __future__ import annotations

from dataclasses import dataclass

from schemas.messages import ScenarioOutcome
from schemas.navigation import CancelReply, GoalFeedback, GoalReply, GoalRequest, GoalTarget
from services.drive.outcome import Outcome

PROGRESS_INTERVAL_S = 1.0
"""Wall seconds between two progress lines of one state (a change of state prints at once)."""


def goal_request(
    x: float,
    y: float,
    theta: float | None = None,
    *,
    frame: str = "map",
    time_limit: float | None = None,
    position_tolerance: float | None = None,
    heading_tolerance: float | None = None,
) -> GoalRequest:
    """The goal ``invent goto X Y [THETA]`` sends; what is None takes the drive's default (``[goals]``,
    the drive's time-limit rule). Nothing is checked here: the drive checks every goal the same way,
    whoever sends it, and its reply says what it rejects."""
    return GoalRequest(
        x=x,
        y=y,
        theta=theta,
        frame=frame,
        time_limit=time_limit,
        position_tolerance=position_tolerance,
        heading_tolerance=heading_tolerance,
    )


def _where(x: float, y: float, theta: float | None) -> str:
    heading = "any heading" if theta is None else f"theta {theta:+.3f}"
    return f"x {x:+.3f} y {y:+.3f} {heading}"


def accepted_line(robot: str, reply: GoalReply, request: GoalRequest) -> str:
    """``goal g1 accepted by rh0's drive: x +1.500 y +0.500 theta +1.570 in map``."""
    return (
        f"goal {reply.id} accepted by {robot}'s drive: {_where(request.x, request.y, request.theta)} in {request.frame}"
    )


def rejected_line(reply: GoalReply) -> str:
    return f"goal rejected: {reply.reason or '(no reason given)'}"


def started_line(target: GoalTarget) -> str:
    """The goal as the drive started it: its pose in ``map``, what completes it, its time limit."""
    given = "" if target.frame == "map" else f" (given in {target.frame})"
    limit = "none" if target.time_limit_s is None else f"{target.time_limit_s:.1f} s"
    return (
        f"goal {target.id} started at t = {target.tm.to_seconds():.3f} s: "
        f"{_where(target.x, target.y, target.theta)} in map{given}; "
        f"within {target.position_tolerance:.3f} m and {target.heading_tolerance:.3f} rad; time limit {limit}"
    )


def feedback_line(feedback: GoalFeedback) -> str:
    """``goal g1 executing: 1.23 m to go, 2.4 s elapsed, about 3.1 s left; pose x +0.512 ...``."""
    return (
        f"goal {feedback.id} {feedback.state}: {feedback.distance_remaining:.2f} m to go, "
        f"{feedback.elapsed_s:.1f} s elapsed, about {feedback.estimated_remaining_s:.1f} s left; "
        f"pose {_where(feedback.x, feedback.y, feedback.theta)}"
    )


def cancel_line(goal_id: str, reply: CancelReply) -> str:
    """What the drive said to the cancel of ``goal_id``."""
    if goal_id in reply.canceling:
        return f"canceling goal {goal_id}"
    return f"cancel of goal {goal_id} not taken: {reply.reason or '(no reason given)'}"


def outcome_line(outcome: ScenarioOutcome) -> str:
    """``outcome: aborted (goal g1 after 3.20 s): bumped into 'box' ...``."""
    reason = f": {outcome.reason}" if outcome.reason else ""
    return f"outcome: {outcome.outcome} (goal {outcome.goal_id} after {outcome.elapsed_s:.2f} s){reason}"


def exit_status(outcome: ScenarioOutcome) -> int:
    """The outcome's exit code: 0 completed, 3 aborted, 4 timed out, 5 canceled."""
    return Outcome(outcome.outcome).exit_code


@dataclass(frozen=True)
class Ending:
    """How the goal ended: its outcome, the exit status it gives and the line that says it."""

    outcome: ScenarioOutcome
    status: int
    line: str


class Progress:
    """One goal followed as the drive's samples come: each method takes a sample of any goal and
    says what to print of it (None: nothing), ignoring other goals' samples (another client's goal,
    or the goal before ours on a latched key)."""

    def __init__(self, goal_id: str, interval_s: float = PROGRESS_INTERVAL_S) -> None:
        self.goal_id = goal_id
        self.interval_s = interval_s
        self.started = False
        """Whether the drive has said it started the goal (``drive/goal``)."""
        self.ending: Ending | None = None
        """How the goal ended, once its outcome came."""
        self._printed_at: float | None = None
        self._printed_state: str | None = None

    def on_target(self, target: GoalTarget) -> str | None:
        """``drive/goal``: the first time it names our goal, the line saying it started."""
        if target.id != self.goal_id or self.started:
            return None
        self.started = True
        return started_line(target)

    def on_feedback(self, feedback: GoalFeedback, wall_s: float) -> str | None:
        """A progress line when one is due at wall time ``wall_s`` (monotonic seconds): the goal's
        first feedback, a change of its state, or :attr:`interval_s` since the last line printed."""
        if feedback.id != self.goal_id or self.ending is not None:
            return None
        due = (
            self._printed_at is None
            or feedback.state != self._printed_state
            or wall_s - self._printed_at >= self.interval_s
        )
        if not due:
            return None
        self._printed_at, self._printed_state = wall_s, feedback.state
        return feedback_line(feedback)

    def on_outcome(self, outcome: ScenarioOutcome) -> Ending | None:
        """``drive/outcome``: our goal's outcome ends the goal (once); another goal's is not ours."""
        if outcome.goal_id != self.goal_id or self.ending is not None:
            return None
        self.ending = Ending(outcome, exit_status(outcome), outcome_line(outcome))
        return self.ending
