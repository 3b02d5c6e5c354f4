"""The NavigateToPose action server's goals as rcl_action and Nav2's navigator keep them (pure, no
zenoh; services/ros2/action_server.py is the shell):

- each goal's state moves only along rcl_action's goal state machine (accepted, executing,
  canceling, then succeeded, canceled or aborted); a goal the drive ends ``canceled`` that no
  cancel request moved to canceling (a goal preempted by a newer one) ends ABORTED, as Nav2's
  navigator ends a preempted goal; :func:`transitions` gives the states a goal passes through
  between two published statuses, so that every status a client sees follows from the last;
- an ended goal's status and result are kept for ``ros2.result_timeout`` of simulation time
  (rcl_action's ``result_timeout``), and at most :data:`MAX_ENDED_GOALS` of them (the oldest
  forgotten first); its UUID is not taken again while it is kept;
- every ``get_result`` of a goal still running is held until the goal ends (:class:`HeldResults`),
  at most :data:`HELD_RESULTS_PER_GOAL` per goal and :data:`HELD_RESULTS` in all: beyond, the call
  is answered with an error, never with a status the goal does not have.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from enum import IntEnum
from typing import Generic, TypeVar

from schemas.codec import BadInput
from schemas.messages import ScenarioOutcome

UUID_BYTES = 16
ZERO_UUID = bytes(UUID_BYTES)
MAX_RUNNING_GOALS = 64
"""Goals the server keeps that have not ended (waiting for the drive's reply, or running)."""
MAX_ENDED_GOALS = 256
"""Ended goals kept for ``_action/status`` and ``get_result`` (each for ``ros2.result_timeout``, the
oldest forgotten first beyond this many): a bound on the memory and on the status message's size."""
HELD_RESULTS_PER_GOAL = 64
"""``get_result`` calls held for one goal at once; beyond, one is answered with an error."""
HELD_RESULTS = 1024
"""``get_result`` calls held for all goals at once; beyond, one is answered with an error."""


class GoalStatus(IntEnum):
    """``action_msgs/msg/GoalStatus``'s status codes."""

    UNKNOWN = 0
    ACCEPTED = 1
    EXECUTING = 2
    CANCELING = 3
    SUCCEEDED = 4
    CANCELED = 5
    ABORTED = 6

    @property
    def terminal(self) -> bool:
        return self in (GoalStatus.SUCCEEDED, GoalStatus.CANCELED, GoalStatus.ABORTED)

    @property
    def cancelable(self) -> bool:
        """rcl_action's goal state machine takes a cancel only from accepted and executing."""
        return self in (GoalStatus.ACCEPTED, GoalStatus.EXECUTING)


class CancelCode(IntEnum):
    """``action_msgs/srv/CancelGoal``'s return codes."""

    NONE = 0
    REJECTED = 1
    UNKNOWN_GOAL_ID = 2
    GOAL_TERMINATED = 3


class ErrorCode(IntEnum):
    """``NavigateToPose_Result.error_code``. Jazzy's ``.action`` defines only ``NONE``; the others
    are the codes Nav2's navigator uses from Kilted on (its ``.action`` adds them as constants,
    which do not change the type or its hash: the field is the same ``uint16``)."""

    NONE = 0
    UNKNOWN = 9000
    TF_ERROR = 9002
    TIMEOUT = 9003


OUTCOMES: dict[str, tuple[GoalStatus, ErrorCode]] = {
    "completed": (GoalStatus.SUCCEEDED, ErrorCode.NONE),
    "canceled": (GoalStatus.CANCELED, ErrorCode.NONE),
    "aborted": (GoalStatus.ABORTED, ErrorCode.UNKNOWN),
    "timed_out": (GoalStatus.ABORTED, ErrorCode.TIMEOUT),
}
"""The drive's outcome of a goal -> its final status and result's error code (``canceled`` is
CANCELED only for a goal canceling: :meth:`GoalBook.end`)."""


def transitions(before: GoalStatus, after: GoalStatus) -> list[GoalStatus]:
    """The states a goal passes through from ``before`` (UNKNOWN: not listed yet) to ``after``,
    ``after`` last, each a step of rcl_action's goal state machine: accepted first; executing
    before succeeded or aborted; canceling before canceled. Empty when nothing changed."""
    path: list[GoalStatus] = []
    current = before
    if current is GoalStatus.UNKNOWN and after is not GoalStatus.UNKNOWN:
        path.append(GoalStatus.ACCEPTED)
        current = GoalStatus.ACCEPTED
    if after is current:
        return path
    if after is GoalStatus.CANCELED and current is not GoalStatus.CANCELING:
        path.append(GoalStatus.CANCELING)
    elif after in (GoalStatus.SUCCEEDED, GoalStatus.ABORTED) and current is GoalStatus.ACCEPTED:
        path.append(GoalStatus.EXECUTING)
    path.append(after)
    return path


def goal_id_of(uuid: bytes) -> str:
    """A ROS goal's UUID as the drive's goal id: 32 lowercase hex digits."""
    if len(uuid) != UUID_BYTES:
        raise BadInput(f"a goal UUID of {len(uuid)} bytes, not {UUID_BYTES}")
    return uuid.hex()


def uuid_of(goal_id: str) -> bytes | None:
    """The UUID a drive goal id stands for; None for one that is not a ROS goal's (``g3``)."""
    if len(goal_id) != 2 * UUID_BYTES:
        return None
    try:
        return bytes.fromhex(goal_id)
    except ValueError:
        return None


@dataclass
class Goal:
    """One goal the server knows: sent (awaiting the drive's reply), accepted, running, or ended."""

    uuid: bytes
    stamp_ns: int | None = None
    """When it was accepted (simulation time); None while its send waits for the drive."""
    status: GoalStatus = GoalStatus.UNKNOWN
    error_code: ErrorCode = ErrorCode.NONE
    error_msg: str = ""
    ended_ns: int | None = None
    """When it ended (simulation time): its result is kept ``result_timeout`` from then."""

    @property
    def id(self) -> str:
        return goal_id_of(self.uuid)


class GoalBook:
    """The goals of one action server, in the order they were sent. Events may come in any order
    from the drive's keys (its outcome before the reply to the send): a later state is never undone
    by an earlier one."""

    def __init__(
        self, result_timeout_ns: int, max_running: int = MAX_RUNNING_GOALS, max_ended: int = MAX_ENDED_GOALS
    ) -> None:
        self._goals: OrderedDict[bytes, Goal] = OrderedDict()
        self._ended: OrderedDict[bytes, None] = OrderedDict()
        """The ended goals, in the order they ended (the first to expire first)."""
        self._result_timeout_ns = result_timeout_ns
        self._max_running = max_running
        self._max_ended = max_ended

    def __contains__(self, uuid: bytes) -> bool:
        return uuid in self._goals

    def get(self, uuid: bytes) -> Goal | None:
        return self._goals.get(uuid)

    def by_id(self, goal_id: str) -> Goal | None:
        """The goal a drive goal id names, if it is one of these."""
        uuid = uuid_of(goal_id)
        return None if uuid is None else self._goals.get(uuid)

    def send(self, uuid: bytes) -> Goal:
        """A goal about to be sent (or accepted to be aborted); BadInput for a UUID known, its
        result kept (rcl_action refuses a goal id that exists), or too many goals not ended."""
        if uuid in self._goals:
            raise BadInput(f"goal {goal_id_of(uuid)} exists already")
        if len(self._goals) - len(self._ended) >= self._max_running:
            raise BadInput(f"{self._max_running} goals are running or waiting for the drive")
        goal = self._goals[uuid] = Goal(uuid)
        return goal

    def rejected(self, uuid: bytes) -> None:
        """The drive refused it (or never answered): forgotten, as if never sent."""
        goal = self._goals.get(uuid)
        if goal is not None and goal.stamp_ns is None:
            del self._goals[uuid]
            self._ended.pop(uuid, None)

    def accepted(self, uuid: bytes, stamp_ns: int) -> bool:
        """Accepted at ``stamp_ns``: listed from now on (its state may be further already); True if
        the status list changed."""
        goal = self._goals.get(uuid)
        if goal is None or goal.stamp_ns is not None:
            return False
        goal.stamp_ns = stamp_ns
        if goal.status is GoalStatus.UNKNOWN:
            goal.status = GoalStatus.ACCEPTED
        return True

    def executing(self, goal_id: str) -> bool:
        """The drive started it (``drive/goal``) or reports it executing; True if it changed."""
        return self._advance(goal_id, GoalStatus.EXECUTING)

    def canceling(self, goal_id: str) -> bool:
        return self._advance(goal_id, GoalStatus.CANCELING)

    def _advance(self, goal_id: str, status: GoalStatus) -> bool:
        goal = self.by_id(goal_id)
        if goal is None or goal.status.terminal or goal.status >= status:
            return False
        goal.status = status
        return goal.stamp_ns is not None

    def ended(self, outcome: ScenarioOutcome, now_ns: int) -> Goal | None:
        """The drive's outcome of a goal; the goal, if it is one of these and had not ended yet."""
        goal = self.by_id(outcome.goal_id)
        if goal is None:
            return None
        status, code = OUTCOMES[outcome.outcome]
        return self.end(goal.uuid, status, code, outcome.reason, now_ns)

    def end(self, uuid: bytes, status: GoalStatus, code: ErrorCode, message: str, now_ns: int) -> Goal | None:
        """End a goal at ``now_ns`` with its result; CANCELED only from canceling (a goal canceled
        that no cancel request moved there was preempted: ABORTED). None if unknown or ended."""
        goal = self._goals.get(uuid)
        if goal is None or goal.status.terminal:
            return None
        if status is GoalStatus.CANCELED and goal.status is not GoalStatus.CANCELING:
            status = GoalStatus.ABORTED
        goal.status, goal.error_code, goal.error_msg, goal.ended_ns = status, code, message, now_ns
        self._ended[uuid] = None
        while len(self._ended) > self._max_ended:
            self._forget(next(iter(self._ended)))
        return goal

    def expire(self, now_ns: int) -> list[Goal]:
        """Forget the ended goals kept ``result_timeout`` or longer at ``now_ns``; those forgotten."""
        expired = []
        while self._ended:
            goal = self._goals[next(iter(self._ended))]
            if goal.ended_ns is None or now_ns - goal.ended_ns < self._result_timeout_ns:
                break
            expired.append(goal)
            self._forget(goal.uuid)
        return expired

    def restart(self, now_ns: int) -> None:
        """Simulation time started again (a new simulator): the ended goals' results are kept a
        whole ``result_timeout`` from ``now_ns``."""
        for uuid in self._ended:
            self._goals[uuid].ended_ns = now_ns

    def _forget(self, uuid: bytes) -> None:
        del self._goals[uuid]
        del self._ended[uuid]

    def cancel(self, uuid: bytes, stamp_ns: int) -> tuple[CancelCode, list[Goal]]:
        """rcl_action's cancel policy: a zero UUID and zero stamp cancel every goal; a zero UUID and
        a stamp, every goal accepted at or before it; a UUID and zero stamp, that goal (unknown: 2,
        no longer cancelable: 3); a UUID and a stamp, that goal and those before. The goals that
        move to ``canceling`` (marked so here), with return code 0 (even when none does, but for a
        single goal)."""
        if uuid != ZERO_UUID and stamp_ns == 0:
            goal = self._goals.get(uuid)
            if goal is None or goal.stamp_ns is None:
                return CancelCode.UNKNOWN_GOAL_ID, []
            if not goal.status.cancelable:
                return CancelCode.GOAL_TERMINATED, []
            goal.status = GoalStatus.CANCELING
            return CancelCode.NONE, [goal]
        before_ns = stamp_ns if stamp_ns != 0 or uuid != ZERO_UUID else None
        canceling = [
            goal
            for goal in self._goals.values()
            if goal.stamp_ns is not None
            and goal.status.cancelable
            and (before_ns is None or goal.stamp_ns <= before_ns or goal.uuid == uuid)
        ]
        for goal in canceling:
            goal.status = GoalStatus.CANCELING
        return CancelCode.NONE, canceling

    def status_list(self) -> list[Goal]:
        """The goals ``_action/status`` lists: every accepted one, ended ones kept, in order."""
        return [goal for goal in self._goals.values() if goal.stamp_ns is not None]

    def running(self) -> list[Goal]:
        return [goal for goal in self.status_list() if not goal.status.terminal]


CallerT = TypeVar("CallerT")


class HeldResults(Generic[CallerT]):
    """The ``get_result`` calls waiting for their goals to end, by goal, within both bounds."""

    def __init__(self, per_goal: int = HELD_RESULTS_PER_GOAL, total: int = HELD_RESULTS) -> None:
        self._callers: dict[bytes, list[CallerT]] = {}
        self._per_goal = per_goal
        self._total = total
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def hold(self, uuid: bytes, caller: CallerT) -> None:
        """Hold ``caller`` until ``uuid``'s goal ends; BadInput naming the bound it would pass."""
        callers = self._callers.setdefault(uuid, [])
        if len(callers) >= self._per_goal:
            raise BadInput(f"{self._per_goal} get_result calls already wait for goal {uuid.hex()}")
        if self._count >= self._total:
            if not callers:
                del self._callers[uuid]
            raise BadInput(f"{self._total} get_result calls already wait for goals")
        callers.append(caller)
        self._count += 1

    def release(self, uuid: bytes) -> list[CallerT]:
        """The calls held for ``uuid``'s goal (which has ended), no longer held."""
        callers = self._callers.pop(uuid, [])
        self._count -= len(callers)
        return callers

    def drain(self) -> list[CallerT]:
        """Every call held, no longer held."""
        callers = [caller for held in self._callers.values() for caller in held]
        self._callers.clear()
        self._count = 0
        return callers
