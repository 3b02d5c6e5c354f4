"""What the NavigateToPose action server (services/ros2/action_server.py) shares with its callers on
zenoh: the bridge's graph tokens and publishers it uses, a ROS service call to answer with
rmw_zenoh's attachment, and the drive's replies decoded (on zenoh's thread)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import zenoh

from schemas.codec import BadInput, decode
from schemas.messages import CancelReply, GoalReply
from services.ros2 import graph, interfaces, wire

ReplyT = TypeVar("ReplyT", GoalReply, CancelReply)


class Tokens(Protocol):
    """The bridge's node in the ROS graph (services/ros2/service.py's ``GraphTokens``)."""

    bridge: graph.BridgeGraph

    def declare(self, kind: wire.EntityKind, entity: graph.Entity) -> str: ...


class Publisher(Protocol):
    """One ROS topic's publisher (services/ros2/service.py's ``RosPublisher``)."""

    def put(self, message: Any, stamp_ns: int) -> None: ...

    def undeclare(self) -> None: ...


@dataclass
class Caller:
    """A ROS service call to answer: its query, the key it came on, its attachment (to echo)."""

    query: zenoh.Query
    key: str
    attachment: wire.Attachment

    def reply(self, message: Any) -> None:
        attachment = wire.Attachment(self.attachment.sequence_number, time.time_ns(), self.attachment.gid)
        try:
            self.query.reply(self.key, interfaces.serialize(message), attachment=attachment.encode())
        finally:
            self.query.drop()

    def refuse(self, reason: str) -> None:
        """An error reply naming why (no response of the service's type would be true)."""
        try:
            self.query.reply_err(reason.encode())
        finally:
            self.query.drop()


def goal_reply(reply: zenoh.Reply) -> GoalReply:
    """zenoh's thread: the drive's reply to a goal (a refusal naming why, for an error reply or
    one that does not decode)."""
    return drive_reply(reply, GoalReply, lambda why: GoalReply(False, "", why))


def cancel_reply(reply: zenoh.Reply) -> CancelReply:
    return drive_reply(reply, CancelReply, lambda why: CancelReply([], why))


def drive_reply(reply: zenoh.Reply, reply_type: type[ReplyT], refused: Callable[[str], ReplyT]) -> ReplyT:
    if reply.ok is None:
        text = reply.err.payload.to_bytes().decode(errors="replace") if reply.err is not None else ""
        return refused(f"the drive answered an error: {text}")
    try:
        return decode(reply_type, reply.ok.payload.to_bytes())
    except BadInput as error:
        return refused(f"the drive's reply does not decode: {error}")
