"""A stand-in for the drive's goal side, as ``invent goto`` meets it, on a real zenoh session: the
goal and cancel queryables (answering only a query on exactly their key), its liveliness token, the
latched ``drive/outcome`` (a queryable answering the last outcome) and publishers of ``drive/goal``,
``drive/goal/feedback`` and ``drive/outcome``. It answers goals as the test says, records what it was
sent, and publishes what the test tells it to, once ``invent goto``'s subscriptions match. For the
tool's own paths (a rejection, a cancel, an outcome missed, a drive gone) without the whole loop;
the real drive is tested with it in tests/test_goto_up.py."""

from __future__ import annotations

import queue
from collections.abc import Callable

import msgspec
import zenoh

from schemas.codec import ENCODING, decode, encode
from schemas.keys import Keys, Service
from schemas.messages import ScenarioOutcome
from schemas.navigation import CancelReply, CancelRequest, GoalReply, GoalRequest
from tests.harness import wait_until

GOAL_REFUSED = encode(GoalReply(accepted=False, id="", reason="a test"))
"""A drive's refusal of a goal, as a rights test's stand-in queryable replies."""


class StandInDrive:
    def __init__(self, session: zenoh.Session, keys: Keys, answer: Callable[[GoalRequest], GoalReply]) -> None:
        self.keys = keys
        self.answer = answer
        self.goals: queue.Queue[GoalRequest] = queue.Queue()
        self.cancels: queue.Queue[CancelRequest] = queue.Queue()
        self.latched_outcome: bytes | None = None
        """What the latched ``drive/outcome`` answers (None: nothing yet)."""
        self._entities = [
            session.declare_queryable(keys.drive_goal_send, self._on_goal),
            session.declare_queryable(keys.drive_goal_cancel, self._on_cancel),
            session.declare_queryable(keys.drive_outcome, self._on_latched),
        ]
        self.token = session.liveliness().declare_token(keys.alive(Service.DRIVE))
        self.publishers = {
            key: session.declare_publisher(key, encoding=zenoh.Encoding(ENCODING))
            for key in (keys.drive_goal, keys.drive_goal_feedback, keys.drive_outcome)
        }

    def _on_goal(self, query: zenoh.Query) -> None:
        request = decode(GoalRequest, query.payload.to_bytes() if query.payload else b"")
        self.goals.put(request)
        query.reply(self.keys.drive_goal_send, encode(self.answer(request)))

    def _on_cancel(self, query: zenoh.Query) -> None:
        request = decode(CancelRequest, query.payload.to_bytes() if query.payload else b"{}")
        self.cancels.put(request)
        query.reply(self.keys.drive_goal_cancel, encode(CancelReply([request.id])))

    def _on_latched(self, query: zenoh.Query) -> None:
        if self.latched_outcome is not None:
            query.reply(self.keys.drive_outcome, self.latched_outcome)

    def wait_for_subscribers(self, timeout: float = 10.0) -> None:
        """Until ``invent goto``'s subscriptions match every publisher (it declares them before it sends)."""
        wait_until(
            lambda: all(p.matching_status.matching for p in self.publishers.values()), timeout, "goto's subscribers"
        )

    def publish(self, key: str, message: msgspec.Struct) -> None:
        payload = encode(message)
        if key == self.keys.drive_outcome:
            assert isinstance(message, ScenarioOutcome)
            self.latched_outcome = payload
        self.publishers[key].put(payload)

    def close(self) -> None:
        self.token.undeclare()
        for entity in self._entities:
            entity.undeclare()
        for publisher in self.publishers.values():
            publisher.undeclare()
