"""The bridge's motor services, beside the shell (services/ros2/service.py): ``motor/stop``,
``motor/clear``, ``motor/start``, ``motor/finish`` (std_srvs/Trigger), each calling the Motor
method of that name (``motor/gui/<method>``, as an operator would) and answering with the motor's
state, or ``success: false`` and why (the motor refused, did not answer within
:data:`SERVICE_CALL_TIMEOUT_S`, or :data:`PENDING_CALLS` calls already wait). A call without
rmw_zenoh's attachment, or with a malformed or oversized request, is counted under its key and
dropped, unanswered.
"""

from __future__ import annotations

import itertools
from typing import Any

import zenoh

from schemas.codec import BadInput
from schemas.status import MotorStatus, decode_status
from schemas.topics import Method, MethodFamily
from services.ros2 import graph, interfaces
from services.ros2.action_calls import Caller, Tokens, caller_of, request_payload, serve
from services.runtime.node import Node

SERVICE_CALL_TIMEOUT_S = 2.0
"""How long a service call waits for the motor's answer before it answers ``success: false``."""
PENDING_CALLS = 16
"""Service calls waiting for the motor at once; beyond, a call is answered ``success: false`` at once."""
MAX_REQUEST_PAYLOAD = 64
"""Bytes: a Trigger request is 5 (CDR header, one byte); a larger one is bad input."""


class MotorServices:
    """One bridge's Trigger services on the Motor methods."""

    def __init__(self, node: Node, tokens: Tokens) -> None:
        self.node = node
        self.calls = {"answered": 0, "failed": 0}
        self._pending: dict[int, Caller] = {}
        self._call_ids = itertools.count(1)
        self.keys, self._queryables = serve(node, tokens, graph.MOTOR_SERVICES, self._take_call)
        self._methods = {
            method: node.querier(node.keys.method(MethodFamily.GUI, method), timeout=SERVICE_CALL_TIMEOUT_S)
            for method in graph.MOTOR_SERVICES
        }

    def _take_call(self, method: Method, key: str, query: zenoh.Query) -> None:
        try:
            caller = caller_of(query, key)
            interfaces.deserialize(
                request_payload(query, MAX_REQUEST_PAYLOAD, "Trigger request"), interfaces.TRIGGER_REQUEST
            )
        except BadInput as error:
            self.node.bad_inputs.record(key, str(error))
            query.drop()
            return
        if len(self._pending) >= PENDING_CALLS:
            self._answer(caller, False, f"{PENDING_CALLS} calls already wait for the motor")
            return
        call_id = next(self._call_ids)
        self._pending[call_id] = caller
        post = self.node.executor.post

        def on_reply(reply: zenoh.Reply) -> None:
            post(self._motor_replied, (call_id, *_reply_text(reply)))

        def on_done() -> None:
            post(self._motor_done, call_id)

        self._methods[method].get(zenoh.handlers.Callback(on_reply, on_done), payload=b"{}")

    def _motor_replied(self, reply: tuple[int, bool, str]) -> None:
        call_id, ok, text = reply
        caller = self._pending.pop(call_id, None)
        if caller is not None:
            self._answer(caller, ok, text)

    def _motor_done(self, call_id: int) -> None:
        caller = self._pending.pop(call_id, None)
        if caller is not None:
            self._answer(caller, False, "the motor did not answer (is `invent motor` running?)")

    def _answer(self, caller: Caller, success: bool, message: str) -> None:
        caller.reply(interfaces.message_class(interfaces.TRIGGER_RESPONSE)(success=success, message=message))
        self.calls["answered" if success else "failed"] += 1
        self.node.log.info("%s: %s", caller.key, message)

    def status(self) -> dict[str, Any]:
        return {**self.calls, "waiting": len(self._pending)}

    def close(self) -> None:
        for caller in self._pending.values():
            caller.query.drop()
        self._pending.clear()
        for entity in (*self._queryables, *self._methods.values()):
            entity.undeclare()


def _reply_text(reply: zenoh.Reply) -> tuple[bool, str]:
    """zenoh's thread: (ok, what to tell the ROS caller) of the motor's reply."""
    if reply.ok is None:
        return False, f"the motor refused: {reply.err.payload.to_bytes().decode(errors='replace') if reply.err else ''}"
    status = decode_status(MotorStatus, reply.ok.payload.to_bytes())  # the motor's status; a bad one says nothing
    return True, f"motor state: {'?' if status is None else status.state}"
