"""The bridge's NavigateToPose action server, and ``goal_pose``: a ROS goal becomes a goal of the
robot's drive (``drive/goal/send``), the drive's feedback and outcome become the action's feedback,
status and result. The shell around services/ros2/navigate.py (the pure core); docs/ros2.md
"Navigate" is the walkthrough, docs/protocol.md section 12 the contract.

rmw_zenoh's wire format for an action is rcl_action's five endpoints, each an ordinary service or
topic in the bridge's namespace: the queryables ``navigate_to_pose/_action/send_goal``,
``_action/cancel_goal`` and ``_action/get_result`` (requests and replies with rmw_zenoh's
attachment, the reply echoing the request's sequence number and GID), and the topics
``_action/feedback`` and ``_action/status`` (reliable, transient-local, depth 1), each with its
liveliness token.

- ``send_goal``: the goal (checked and turned into ``map``, navigate.py) is sent to the drive from
  the service thread; the ROS reply waits for the drive's (``accepted`` follows it). A goal the
  bridge refuses itself, or that the drive refuses or leaves unanswered (no drive serves goals: at
  once; the status's ``drive_serves_goals`` says whether one does), is answered ``accepted: false``
  and counted (the reason in the log and the status: SendGoal's response has no field for it).
  A goal in a frame the bridge's TF tree cannot turn into ``map`` is accepted and aborted at once
  (TF_ERROR, the reason in the result's ``error_msg``), as Nav2's navigator does.
- ``cancel_goal``: rcl_action's policy on the goals this server knows; each that moves to
  ``canceling`` is canceled in the drive (``drive/goal/cancel``).
- ``get_result``: answered once the goal has ended (each call held until then, within the bounds of
  services/ros2/goal_book.py; beyond, an error reply), at once for an ended or unknown goal.
- ``goal_pose`` (RViz's "2D Goal Pose", ``geometry_msgs/PoseStamped``): a goal with a UUID of the
  bridge's making, sent the same way; only ``status`` and ``feedback`` show how it goes.
- ``status``: published at each change, one sample per step of rcl_action's state machine a goal
  takes (goal_book.transitions), and when ended goals are forgotten (``ros2.result_timeout``).

Bad input (a request without rmw_zenoh's attachment, malformed or oversized CDR, a pose not finite)
is counted under its key and refused in the reply (an error reply without an attachment to echo;
else ``accepted: false``, return code 1 or status 0); nothing reaches the drive and the running goal
goes on. With ``ros2.navigate_to_pose`` off, none of this is declared (services/ros2/service.py).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import uuid as uuid_module
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import zenoh

from schemas.codec import BadInput, encode
from schemas.drive_status import NavigateStatus, NavigateWaiting
from schemas.messages import NANOSECONDS_PER_SECOND, ScenarioOutcome
from schemas.navigation import CancelReply, CancelRequest, GoalFeedback, GoalReply, GoalRequest, GoalTarget
from services.config import Config
from services.ros2 import graph, interfaces, navigate, wire
from services.ros2.action_calls import (
    Caller,
    Publisher,
    Tokens,
    caller_of,
    cancel_reply,
    goal_reply,
    reply_error,
    request_payload,
    serve,
)
from services.ros2.goal_book import (
    CancelCode,
    ErrorCode,
    Goal,
    GoalBook,
    GoalStatus,
    HeldResults,
    goal_id_of,
    transitions,
)
from services.ros2.graph import ActionService, ActionTopic
from services.ros2.tf_tree import TransformError
from services.runtime.inputs import Delivery
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node
from services.runtime.session import has_match

if TYPE_CHECKING:
    from services.clock.sim_time import StampClock
    from services.ros2.outputs import RosOutputs


GOAL_CALL_TIMEOUT_S = 2.0
"""How long a goal's send or cancel waits for the drive's reply."""
PENDING_SENDS = 16
"""Goals waiting for the drive's reply at once; beyond, a goal is refused at once."""
MAX_REQUEST_PAYLOAD: dict[ActionService, int] = {
    ActionService.SEND_GOAL: 4096,
    ActionService.CANCEL_GOAL: 64,
    ActionService.GET_RESULT: 64,
}
"""Bytes of CDR a request may have: a cancel is 28 (a UUID and a stamp), a result request 20; a goal
a pose, a frame id and a behaviour tree's name."""
MAX_GOAL_POSE_PAYLOAD = 4096
"""Bytes: a ``goal_pose`` larger than this is bad input, refused before it is decoded."""


@dataclass
class PendingSend:
    """A goal sent to the drive, waiting for its reply: to the ROS caller, or none (``goal_pose``)."""

    uuid: bytes
    caller: Caller | None
    source: str
    """The key it came on (the send_goal service's or goal_pose's)."""


class NavigateServer:
    """One bridge's ``navigate_to_pose`` action server and ``goal_pose`` subscription."""

    def __init__(
        self,
        node: Node,
        config: Config,
        tokens: Tokens,
        outputs: RosOutputs,
        publisher: Callable[[graph.Entity], Publisher],
    ) -> None:
        self.node = node
        self.config = config
        bridge = tokens.bridge
        self.outputs = outputs
        self.clock: StampClock = outputs.clock
        settings = config.ros2
        self.map_frame = settings.map_frame
        self.action = wire.full_name(bridge.namespace, graph.NAVIGATE_TO_POSE)
        self.book = GoalBook(round(settings.result_timeout * NANOSECONDS_PER_SECOND))
        self.counters = navigate.Counters()
        self._pending: dict[int, PendingSend] = {}
        self._call_ids = itertools.count(1)
        self.results: HeldResults[Caller] = HeldResults()
        self._frame_errors = RateLimitedLog(node.log)
        self.publishers = {topic: publisher(entity) for topic, entity in graph.ACTION_TOPICS.items()}
        self.service_keys, self._declarations = serve(node, tokens, graph.ACTION_SERVICES, self._take_call)
        self.goal_pose_key = bridge.key(graph.GOAL_POSE)
        tokens.declare(wire.EntityKind.SUBSCRIPTION, graph.GOAL_POSE)
        node.subscribe_bytes(self.goal_pose_key, self._on_goal_pose, Delivery.QUEUED)
        keys = node.keys
        self._send = node.querier(keys.drive_goal_send, timeout=GOAL_CALL_TIMEOUT_S)
        self._cancel = node.querier(keys.drive_goal_cancel, timeout=GOAL_CALL_TIMEOUT_S)
        self._declarations += [self._send, self._cancel]
        # Every sample, in order with the queries: each changes a goal's state.
        node.subscribe(keys.drive_goal, GoalTarget, self._on_started, Delivery.QUEUED)
        node.subscribe(keys.drive_goal_feedback, GoalFeedback, self._on_feedback, Delivery.QUEUED)
        node.subscribe(keys.drive_outcome, ScenarioOutcome, self._on_outcome, Delivery.QUEUED)
        # As rcl_action: the status is published once there are goals, then at each change.

    @property
    def now_ns(self) -> int:
        """The newest simulation time the bridge has (0 before the first)."""
        return self.clock.last_ns or 0

    # -- requests from ROS (zenoh's thread posts them to the service thread) ---------------------

    def _post(self, key: str, handle: Callable[[Any], None], item: Any) -> None:
        """Run ``handle(item)`` on the service thread (from zenoh's), a bug counted under ``key``."""
        self.node.executor.post(partial(self.node.guard, key, handle), item)

    def _take_call(self, service: ActionService, key: str, query: zenoh.Query) -> None:
        try:
            caller = caller_of(query, key)
        except BadInput as error:
            self.node.bad_inputs.record(key, str(error))
            reply_error(query, str(error))
            return
        try:
            payload = request_payload(query, MAX_REQUEST_PAYLOAD[service], f"{service} request")
            request_type = graph.ACTION_SERVICES[service].interface + "_Request"
            request = interfaces.deserialize(payload, request_type)
        except BadInput as error:
            self.node.bad_inputs.record(key, str(error))
            self._refuse(service, caller, str(error))
            return
        handler = {
            ActionService.SEND_GOAL: self._send_goal,
            ActionService.CANCEL_GOAL: self._cancel_goal,
            ActionService.GET_RESULT: self._get_result,
        }[service]
        handler(request, caller)

    def _refuse(self, service: ActionService, caller: Caller, reason: str) -> None:
        """A request the bridge cannot take, answered with its type's refusal."""
        if service is ActionService.SEND_GOAL:
            self._rejected(reason, caller)
        elif service is ActionService.CANCEL_GOAL:
            caller.reply(navigate.cancel_response(CancelCode.REJECTED, []))
        else:
            caller.reply(navigate.result_response(None))

    def _send_goal(self, request: Any, caller: Caller) -> None:
        uuid = navigate.uuid_bytes(request.goal_id)
        pose = request.goal.pose
        try:
            goal = self._goal_request(uuid, pose)
        except BadInput as error:
            self.node.bad_inputs.record(caller.key, str(error))
            self._refuse(ActionService.SEND_GOAL, caller, str(error))
            return
        except TransformError as error:
            self._abort_untransformable(uuid, pose.header.frame_id, str(error), caller)
            return
        self._send_to_drive(uuid, goal, caller, caller.key)

    def _on_goal_pose(self, payload: bytes, attachment: bytes | None) -> None:
        """A ``goal_pose`` (service thread): a goal with a UUID of the bridge's own. BadInput for a
        sample without rmw_zenoh's attachment, malformed or oversized, or a pose refused."""
        wire.Attachment.decode(attachment)
        if len(payload) > MAX_GOAL_POSE_PAYLOAD:
            raise BadInput(f"{len(payload)} bytes, more than a goal pose's {MAX_GOAL_POSE_PAYLOAD}")
        pose = interfaces.deserialize(payload, interfaces.POSE_STAMPED)
        uuid = uuid_module.uuid4().bytes
        try:
            goal = self._goal_request(uuid, pose)
        except BadInput as error:
            self._rejected(str(error))
            raise
        except TransformError as error:
            self._abort_untransformable(uuid, pose.header.frame_id, str(error), None)
            return
        self._send_to_drive(uuid, goal, None, self.goal_pose_key)

    def _goal_request(self, uuid: bytes, pose: Any) -> GoalRequest:
        return navigate.goal_request(
            pose, self.outputs.tree, self.map_frame, goal_id_of(uuid), self.config.input.max_coordinate
        )

    def _abort_untransformable(self, uuid: bytes, frame: str, reason: str, caller: Caller | None) -> None:
        """As Nav2's navigator: a goal whose frame cannot be turned into ``map`` is accepted, then
        aborted (TF_ERROR, the reason in ``error_msg``); it never reaches the drive."""
        try:
            self.book.send(uuid)
        except BadInput as error:
            self._rejected(str(error), caller)
            return
        now_ns = self.now_ns
        self.book.accepted(uuid, now_ns)
        self.counters.accepted += 1
        self.counters.frame_errors += 1
        if caller is not None:
            caller.reply(navigate.send_goal_response(True, now_ns))
        message = (
            f"Failed to transform a goal pose provided with frame_id '{frame}' to the global frame "
            f"'{self.map_frame}': {reason}"
        )
        goal = self.book.end(uuid, GoalStatus.ABORTED, ErrorCode.TF_ERROR, message, now_ns)
        if goal is not None:
            self.counters.ended(goal.status)
            self._publish_steps(goal, GoalStatus.UNKNOWN)
        self._frame_errors("frame", logging.WARNING, "goal %s aborted: %s", goal_id_of(uuid), message)

    def _send_to_drive(self, uuid: bytes, goal: GoalRequest, caller: Caller | None, source: str) -> None:
        """Send ``goal`` to the drive (a zenoh get from the service thread; its reply posted back)."""
        try:
            if len(self._pending) >= PENDING_SENDS:
                raise BadInput(f"{PENDING_SENDS} goals already wait for the drive's reply")
            self.book.send(uuid)
        except BadInput as error:
            self._rejected(str(error), caller)
            return
        call_id = next(self._call_ids)
        self._pending[call_id] = PendingSend(uuid, caller, source)
        self.counters.sent += 1
        key = self.node.keys.drive_goal_send

        def on_reply(reply: zenoh.Reply) -> None:
            self._post(key, self._drive_replied, (call_id, goal_reply(reply)))

        def on_done() -> None:
            self._post(key, self._drive_done, call_id)

        self._send.get(zenoh.handlers.Callback(on_reply, on_done), payload=encode(goal))

    def _drive_replied(self, answer: tuple[int, GoalReply]) -> None:
        call_id, reply = answer
        pending = self._pending.pop(call_id, None)
        if pending is None:
            return
        goal_id = goal_id_of(pending.uuid)
        if reply.accepted and reply.id == goal_id:
            stamp_ns = self.now_ns
            self.book.accepted(pending.uuid, stamp_ns)
            self.counters.accepted += 1
            self.node.log.info("goal %s from %s accepted by the drive", goal_id, pending.source)
            if pending.caller is not None:
                pending.caller.reply(navigate.send_goal_response(True, stamp_ns))
            goal = self.book.get(pending.uuid)
            if goal is not None:
                self._publish_steps(goal, GoalStatus.UNKNOWN)
            return
        self.book.rejected(pending.uuid)
        reason = reply.reason if not reply.accepted else f"the drive accepted it as {reply.id!r}, not {goal_id!r}"
        self._rejected(f"the drive refused goal {goal_id}: {reason}", pending.caller)

    def _drive_done(self, call_id: int) -> None:
        """The send's query ended: a goal still pending got no reply (no drive serves goals)."""
        if call_id in self._pending:
            self._drive_replied(
                (call_id, GoalReply(False, "", "no drive answered (is `invent drive --goals` running?)"))
            )

    def _rejected(self, reason: str, caller: Caller | None = None) -> None:
        """A goal refused: counted, logged, and answered so to ``caller`` (None: a ``goal_pose``)."""
        self.counters.rejected += 1
        self.counters.last_rejection = reason
        self.node.log.info("%s: goal refused: %s", self.action, reason)
        if caller is not None:
            caller.reply(navigate.send_goal_response(False, self.now_ns))

    def _cancel_goal(self, request: Any, caller: Caller) -> None:
        self.counters.cancel_requests += 1
        info = request.goal_info
        stamp_ns = int(info.stamp.sec) * 1_000_000_000 + int(info.stamp.nanosec)
        code, goals = self.book.cancel(navigate.uuid_bytes(info.goal_id), stamp_ns)
        caller.reply(navigate.cancel_response(code, goals))
        key = self.node.keys.drive_goal_cancel
        for goal in goals:

            def on_reply(reply: zenoh.Reply, goal_id: str = goal.id) -> None:
                self._post(key, self._cancel_replied, (goal_id, cancel_reply(reply)))

            self._cancel.get(on_reply, payload=encode(CancelRequest(id=goal.id)))
        if goals:
            self._publish_status()

    def _cancel_replied(self, answer: tuple[str, CancelReply]) -> None:
        goal_id, reply = answer
        if goal_id not in reply.canceling:
            self.node.log.info("%s: the drive did not cancel goal %s: %s", self.action, goal_id, reply.reason)

    def _get_result(self, request: Any, caller: Caller) -> None:
        """rcl_action's: an unknown goal's (or one whose result is no longer kept) at once, status 0;
        an ended goal's at once; a running goal's held until it ends (beyond the bounds, an error)."""
        self.counters.result_requests += 1
        goal = self.book.get(navigate.uuid_bytes(request.goal_id))
        if goal is None or goal.stamp_ns is None or goal.status.terminal:
            caller.reply(navigate.result_response(goal if goal is not None and goal.stamp_ns is not None else None))
            return
        try:
            self.results.hold(goal.uuid, caller)
        except BadInput as error:
            self.counters.results_refused += 1
            caller.refuse(str(error))

    # -- the drive's side -----------------------------------------------------------------------

    def _on_started(self, target: GoalTarget) -> None:
        goal = self.book.by_id(target.id)
        if goal is not None:
            before = goal.status
            if self.book.executing(target.id):
                self._publish_steps(goal, before)

    def _on_feedback(self, feedback: GoalFeedback) -> None:
        goal = self.book.by_id(feedback.id)
        if goal is None or goal.status.terminal:
            return
        before = goal.status
        changed = (
            self.book.canceling(feedback.id) if feedback.state == "canceling" else self.book.executing(feedback.id)
        )
        if changed:
            self._publish_steps(goal, before)
        if goal.stamp_ns is not None:
            message = navigate.feedback_message(goal.uuid, feedback, self.map_frame)
            self.publishers[ActionTopic.FEEDBACK].put(message, feedback.tm.to_nanoseconds())

    def _on_outcome(self, outcome: ScenarioOutcome) -> None:
        known = self.book.by_id(outcome.goal_id)
        before = known.status if known is not None else GoalStatus.UNKNOWN
        goal = self.book.ended(outcome, self.now_ns)
        if goal is None:
            return
        self.counters.ended(goal.status)
        self.node.log.info(
            "goal %s ended %s%s", goal.id, goal.status.name.lower(), f": {outcome.reason}" if outcome.reason else ""
        )
        if goal.stamp_ns is not None:
            self._publish_steps(goal, before)

    def _publish_steps(self, goal: Goal, before: GoalStatus) -> None:
        """The status at each step ``goal`` took since ``before`` (UNKNOWN: not listed yet); once it
        has ended, the results held for it answered."""
        for step in transitions(before, goal.status):
            self._publish_status({goal.uuid: step})
        if goal.status.terminal:
            for caller in self.results.release(goal.uuid):
                caller.reply(navigate.result_response(goal))

    def _publish_status(self, shown: dict[bytes, GoalStatus] | None = None) -> None:
        self.publishers[ActionTopic.STATUS].put(navigate.status_array(self.book.status_list(), shown), self.now_ns)

    def tick(self, now_ns: int, restarted: bool) -> None:
        """A new simulation time (the service thread, at each ``sim/clock``): after a new simulator,
        ended goals are kept a whole ``result_timeout`` again; those kept that long are forgotten."""
        if restarted:
            self.book.restart(now_ns)
        expired = self.book.expire(now_ns)
        if expired:
            self.counters.expired += len(expired)
            self._publish_status()

    def status(self) -> NavigateStatus:
        return NavigateStatus(
            action=self.action,
            drive_serves_goals=has_match(self._send),
            **dataclasses.asdict(self.counters),
            waiting=NavigateWaiting(sends=len(self._pending), results=len(self.results)),
            goals={goal.id: goal.status.name.lower() for goal in self.book.status_list()},
        )

    def close(self) -> None:
        for caller in self.results.drain():
            caller.query.drop()
        for pending in self._pending.values():
            if pending.caller is not None:
                pending.caller.query.drop()
        self._pending.clear()
        for declaration in self._declarations:
            declaration.undeclare()
        self._declarations.clear()
        for publisher in self.publishers.values():
            publisher.undeclare()
