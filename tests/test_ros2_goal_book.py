"""The NavigateToPose action server's goals as rcl_action and Nav2's navigator keep them
(services/ros2/goal_book.py, pure, no zenoh): the states and the steps between them, the drive's
outcomes (a preempted goal ABORTED), rcl_action's cancel policy, results kept for
``ros2.result_timeout`` and bounded in number, UUIDs refused while kept, and the held
``get_result`` calls within their bounds. Over the wire: tests/test_ros2_action_rules.py.
"""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas.codec import BadInput
from schemas.messages import ScenarioOutcome, Time
from services.ros2 import goal_book
from services.ros2.goal_book import CancelCode, ErrorCode, GoalBook, GoalStatus


def _outcome(goal_id: str, outcome: str, reason: str = "") -> ScenarioOutcome:
    return ScenarioOutcome(Time(1, 0), "goal", outcome, reason, 0, 1.0, goal_id=goal_id)  # type: ignore[arg-type]


def _uuid(k: int) -> bytes:
    return bytes([k]) * 16


TIMEOUT_NS = 900_000_000_000
"""``ros2.result_timeout``'s default, 900 s."""


def test_a_goal_goes_accepted_executing_succeeded_and_ends_with_its_result():
    book = GoalBook(TIMEOUT_NS)
    book.send(_uuid(1))
    assert book.status_list() == [], "not listed while the drive has not answered"
    assert book.accepted(_uuid(1), 100)
    assert [goal.status for goal in book.status_list()] == [GoalStatus.ACCEPTED]
    assert book.executing(_uuid(1).hex()) and not book.executing(_uuid(1).hex())
    ended = book.ended(_outcome(_uuid(1).hex(), "completed"), 1)
    assert ended is not None and (ended.status, ended.error_code) == (GoalStatus.SUCCEEDED, ErrorCode.NONE)
    assert book.ended(_outcome(_uuid(1).hex(), "aborted"), 1) is None, "an ended goal ends once"
    assert not book.executing(_uuid(1).hex()) and not book.canceling(_uuid(1).hex())


@pytest.mark.parametrize(
    ("outcome", "status", "code"),
    [
        ("completed", GoalStatus.SUCCEEDED, 0),
        ("canceled", GoalStatus.CANCELED, 0),
        ("aborted", GoalStatus.ABORTED, 9000),
        ("timed_out", GoalStatus.ABORTED, 9003),
    ],
)
def test_each_drive_outcome_is_a_final_status_and_error_code(outcome, status, code):
    book = GoalBook(TIMEOUT_NS)
    book.send(_uuid(1))
    book.accepted(_uuid(1), 1)
    book.executing(_uuid(1).hex())
    if outcome == "canceled":
        book.cancel(_uuid(1), 0)
    goal = book.ended(_outcome(_uuid(1).hex(), outcome, "why"), 1)
    assert goal is not None and (goal.status, int(goal.error_code)) == (status, code)
    assert goal.error_msg == "why"


def test_the_drives_events_may_come_before_its_reply_and_never_move_a_goal_back():
    book = GoalBook(TIMEOUT_NS)
    book.send(_uuid(1))
    assert not book.executing(_uuid(1).hex()), "not listed yet: no status to publish"
    book.ended(_outcome(_uuid(1).hex(), "completed"), 1)
    assert book.accepted(_uuid(1), 5)
    assert [goal.status for goal in book.status_list()] == [GoalStatus.SUCCEEDED]
    book.send(_uuid(2))
    book.accepted(_uuid(2), 6)
    assert book.canceling(_uuid(2).hex()) and not book.executing(_uuid(2).hex())
    assert book.get(_uuid(2)).status is GoalStatus.CANCELING  # type: ignore[union-attr]


def test_a_refused_goal_is_forgotten_and_a_known_uuid_is_refused():
    book = GoalBook(TIMEOUT_NS)
    book.send(_uuid(1))
    with pytest.raises(BadInput, match="exists already"):
        book.send(_uuid(1))
    book.rejected(_uuid(1))
    assert _uuid(1) not in book
    book.send(_uuid(1))


def _book_with(*statuses: GoalStatus) -> GoalBook:
    """Goals 1, 2, ... accepted at 10, 20, ... with the given statuses."""
    book = GoalBook(TIMEOUT_NS)
    for k, status in enumerate(statuses, start=1):
        book.send(_uuid(k))
        book.accepted(_uuid(k), 10 * k)
        book.get(_uuid(k)).status = status  # type: ignore[union-attr]
    return book


def test_cancel_follows_rcl_actions_policy():
    running, done = GoalStatus.EXECUTING, GoalStatus.SUCCEEDED
    code, goals = _book_with(running, done, running).cancel(bytes(16), 0)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1), _uuid(3)], "zero id and stamp: all"
    code, goals = _book_with(running, running, running).cancel(bytes(16), 20)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1), _uuid(2)], "at or before the stamp"
    code, goals = _book_with(running, running, running).cancel(_uuid(3), 10)
    assert [g.uuid for g in goals] == [_uuid(1), _uuid(3)], "the id and those before the stamp"
    book = _book_with(running, done)
    code, goals = book.cancel(_uuid(1), 0)
    assert code is CancelCode.NONE and [g.uuid for g in goals] == [_uuid(1)]
    assert book.get(_uuid(1)).status is GoalStatus.CANCELING  # type: ignore[union-attr]
    assert book.cancel(_uuid(2), 0) == (CancelCode.GOAL_TERMINATED, [])
    assert book.cancel(_uuid(9), 0) == (CancelCode.UNKNOWN_GOAL_ID, [])
    assert book.cancel(_uuid(1), 0) == (CancelCode.GOAL_TERMINATED, []), "canceling already: rcl says terminated"
    assert _book_with(done).cancel(bytes(16), 0) == (CancelCode.NONE, []), "nothing to cancel: none, and no goal"
    pending = GoalBook(TIMEOUT_NS)
    pending.send(_uuid(1))
    assert pending.cancel(_uuid(1), 0) == (CancelCode.UNKNOWN_GOAL_ID, []), "not accepted yet: unknown to ROS"


events = st.lists(
    st.tuples(
        st.sampled_from(["send", "accept", "reject", "start", "cancel", "canceling", "end", "cancel_all"]),
        st.integers(1, 30),
        st.sampled_from(["completed", "canceled", "aborted", "timed_out"]),
    ),
    max_size=200,
)


def _apply(book: GoalBook, event: str, k: int, outcome: str) -> None:
    uuid, goal_id = _uuid(k), _uuid(k).hex()
    if event == "send":
        book.send(uuid)
    elif event == "accept":
        book.accepted(uuid, k)
    elif event == "reject":
        book.rejected(uuid)
    elif event == "start":
        book.executing(goal_id)
    elif event == "canceling":
        book.canceling(goal_id)
    elif event == "end":
        book.ended(_outcome(goal_id, outcome), k)
    else:
        book.cancel(uuid if event == "cancel" else bytes(16), 0)


@given(events)
def test_the_book_stays_bounded_and_no_goal_ever_moves_back(sequence):
    book = GoalBook(TIMEOUT_NS, max_running=8, max_ended=4)
    seen: dict[bytes, GoalStatus] = {}
    for event, k, outcome in sequence:
        try:
            _apply(book, event, k, outcome)
        except BadInput:
            assert event == "send"
        listed = book.status_list()
        assert sum(goal.status.terminal for goal in listed) <= 4
        assert len(listed) <= 12
        for goal in listed:
            before = seen.get(goal.uuid, GoalStatus.UNKNOWN)
            for step_from, step_to in itertools.pairwise([before, *goal_book.transitions(before, goal.status)]):
                assert (step_from, step_to) in RCL_ACTION_STEPS or step_from is GoalStatus.UNKNOWN, (
                    before,
                    goal.status,
                )
            assert not before.terminal or goal.status is before
            seen[goal.uuid] = goal.status
        for forgotten in [uuid for uuid in seen if uuid not in book]:
            del seen[forgotten]


RCL_ACTION_STEPS = {
    (GoalStatus.ACCEPTED, GoalStatus.EXECUTING),
    (GoalStatus.ACCEPTED, GoalStatus.CANCELING),
    (GoalStatus.EXECUTING, GoalStatus.CANCELING),
    (GoalStatus.EXECUTING, GoalStatus.SUCCEEDED),
    (GoalStatus.EXECUTING, GoalStatus.ABORTED),
    (GoalStatus.CANCELING, GoalStatus.SUCCEEDED),
    (GoalStatus.CANCELING, GoalStatus.CANCELED),
    (GoalStatus.CANCELING, GoalStatus.ABORTED),
}
"""rcl_action's goal state machine (``goal_state_machine.c``): the events' transitions."""
statuses = st.sampled_from(list(GoalStatus))


@given(statuses, statuses)
def test_transitions_are_rcl_actions_steps_accepted_first_and_the_status_reached_last(before, after):
    path = goal_book.transitions(before, after)
    if before is after:
        assert path == []
        return
    assert path[-1] is after
    if before is GoalStatus.UNKNOWN:
        assert path[0] is GoalStatus.ACCEPTED
        before = path.pop(0)
    steps = list(itertools.pairwise([before, *path]))
    if not before.terminal and after > before:
        assert all(step in RCL_ACTION_STEPS for step in steps), steps


def _running(book: GoalBook, k: int, stamp_ns: int = 0) -> None:
    book.send(_uuid(k))
    book.accepted(_uuid(k), stamp_ns)
    book.executing(_uuid(k).hex())


def test_a_preempted_goal_ends_aborted_as_nav2s_navigator_ends_it_and_a_canceled_one_canceled():
    """The drive ends both ``canceled``: CANCELED only comes from CANCELING (a cancel request)."""
    book = GoalBook(TIMEOUT_NS)
    _running(book, 1)
    goal = book.ended(_outcome(_uuid(1).hex(), "canceled", f"preempted by goal {_uuid(2).hex()!r}"), 5)
    assert goal is not None and (goal.status, goal.error_code) == (GoalStatus.ABORTED, ErrorCode.NONE)
    assert _uuid(2).hex() in goal.error_msg
    _running(book, 3)
    book.cancel(_uuid(3), 0)
    canceled = book.ended(_outcome(_uuid(3).hex(), "canceled"), 6)
    assert canceled is not None and canceled.status is GoalStatus.CANCELED


def test_an_ended_goals_result_is_kept_for_result_timeout_and_its_uuid_refused_meanwhile():
    book = GoalBook(result_timeout_ns=10)
    for k in range(1, 41):
        _running(book, k, stamp_ns=k)
        book.ended(_outcome(_uuid(k).hex(), "completed"), 100)
    assert book.expire(109) == [] and len(book.status_list()) == 40, "40 results kept, not the last 16"
    assert book.get(_uuid(1)).status is GoalStatus.SUCCEEDED  # type: ignore[union-attr]
    with pytest.raises(BadInput, match="exists already"):
        book.send(_uuid(1))
    _running(book, 41)
    book.ended(_outcome(_uuid(41).hex(), "aborted"), 105)
    assert [goal.uuid for goal in book.expire(110)] == [_uuid(k) for k in range(1, 41)], "in the order they ended"
    assert _uuid(1) not in book and _uuid(41) in book
    book.send(_uuid(1))
    last = book.get(_uuid(41))
    assert book.expire(114) == [] and book.expire(115) == [last] and _uuid(41) not in book


def test_results_are_bounded_in_number_too_the_oldest_forgotten_first():
    book = GoalBook(TIMEOUT_NS, max_ended=3)
    for k in range(1, 6):
        _running(book, k)
        book.ended(_outcome(_uuid(k).hex(), "completed"), k)
    assert [goal.uuid for goal in book.status_list()] == [_uuid(3), _uuid(4), _uuid(5)]


def test_a_new_simulator_keeps_the_results_a_whole_timeout_from_its_time():
    book = GoalBook(result_timeout_ns=10)
    _running(book, 1)
    book.ended(_outcome(_uuid(1).hex(), "completed"), 1_000)
    assert book.expire(5) == [], "time went back: nothing expires"
    book.restart(5)
    kept = book.get(_uuid(1))
    assert book.expire(14) == [] and book.expire(15) == [kept] and _uuid(1) not in book


def test_the_running_goals_are_bounded_and_ended_ones_do_not_count():
    book = GoalBook(TIMEOUT_NS, max_running=2)
    _running(book, 1)
    _running(book, 2)
    with pytest.raises(BadInput, match="2 goals are running"):
        book.send(_uuid(3))
    book.ended(_outcome(_uuid(1).hex(), "completed"), 1)
    book.send(_uuid(3))


def test_every_get_result_is_held_until_its_goal_ends_within_a_bound_per_goal_and_in_all():
    held: goal_book.HeldResults[int] = goal_book.HeldResults(per_goal=20, total=50)
    for caller in range(20):
        held.hold(_uuid(1), caller)
    with pytest.raises(BadInput, match="20 get_result calls already wait for goal"):
        held.hold(_uuid(1), 99)
    for k in range(2, 5):
        for caller in range(10):
            held.hold(_uuid(k), caller)
    with pytest.raises(BadInput, match="50 get_result calls already wait for goals"):
        held.hold(_uuid(9), 99)
    assert len(held) == 50 and held.release(_uuid(1)) == list(range(20)) and len(held) == 30
    assert held.release(_uuid(1)) == [] and held.release(_uuid(9)) == []
    held.hold(_uuid(9), 7)
    assert sorted(held.drain()) == sorted([*range(10), *range(10), *range(10), 7]) and len(held) == 0
