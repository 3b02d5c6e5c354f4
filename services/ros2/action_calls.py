"""What the bridge's ROS services (the NavigateToPose action's, services/ros2/action_server.py; the
odometry's and the motor's, beside it) share on zenoh: the bridge's graph tokens and publishers
they use, each service's queryable, a ROS service call to answer with rmw_zenoh's attachment, and
the replies of the stack's services decoded (on zenoh's thread)."""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol, TypeVar

import zenoh

from schemas.codec import BadInput, decode
from schemas.navigation import CancelReply, GoalReply, LocalizationReply
from services.ros2 import graph, interfaces, wire
from services.runtime.node import Node

ReplyT = TypeVar("ReplyT", GoalReply, CancelReply, LocalizationReply)
ServiceT = TypeVar("ServiceT", bound=Hashable)


class Tokens(Protocol):
    """The bridge's node in the ROS graph (services/ros2/node_entities.py's ``GraphTokens``)."""

    bridge: graph.BridgeGraph

    def declare(self, kind: wire.EntityKind, entity: graph.Entity) -> str: ...


class Publisher(Protocol):
    """One ROS topic's publisher (services/ros2/node_entities.py's ``RosPublisher``)."""

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
        reply_error(self.query, reason)


def reply_error(query: zenoh.Query, reason: str) -> None:
    """An error reply naming why (no response of the service's type would be true)."""
    try:
        query.reply_err(reason.encode())
    finally:
        query.drop()


def serve(
    node: Node,
    tokens: Tokens,
    services: Mapping[ServiceT, graph.Entity],
    take: Callable[[ServiceT, str, zenoh.Query], None],
) -> tuple[dict[ServiceT, str], list[Any]]:
    """Declare each of ``services`` in the graph and on its key: a call on exactly that key goes to
    ``take`` on the service thread (a bug counted under the key); any other query that reaches the
    queryable (a wildcard) is dropped, unanswered: looking never acts. Returns the keys and the
    queryables (to undeclare)."""
    keys: dict[ServiceT, str] = {}
    queryables: list[Any] = []
    for service, entity in services.items():
        key = keys[service] = tokens.bridge.key(entity)
        tokens.declare(wire.EntityKind.SERVICE, entity)
        queryables.append(
            node.session.declare_queryable(
                key, partial(_on_query, node, partial(take, service, key), key), complete=True
            )
        )
    return keys, queryables


def _on_query(node: Node, take: Callable[[zenoh.Query], None], key: str, query: zenoh.Query) -> None:
    if str(query.key_expr) == key:
        node.executor.post(partial(node.guard, key, take), query)


def caller_of(query: zenoh.Query, key: str) -> Caller:
    """The call to answer; BadInput without rmw_zenoh's attachment, or a malformed one."""
    return Caller(
        query, key, wire.Attachment.decode(query.attachment.to_bytes() if query.attachment is not None else None)
    )


def request_payload(query: zenoh.Query, limit: int, request: str) -> bytes:
    """The call's CDR; BadInput beyond ``limit`` bytes (a ``request`` is never as long)."""
    payload = query.payload.to_bytes() if query.payload is not None else b""
    if len(payload) > limit:
        raise BadInput(f"{len(payload)} bytes, more than a {request}'s {limit}")
    return payload


def goal_reply(reply: zenoh.Reply) -> GoalReply:
    """zenoh's thread: the drive's reply to a goal (a refusal naming why, for an error reply or
    one that does not decode)."""
    return decoded_reply(reply, GoalReply, lambda why: GoalReply(False, "", why), "the drive")


def cancel_reply(reply: zenoh.Reply) -> CancelReply:
    return decoded_reply(reply, CancelReply, lambda why: CancelReply([], why), "the drive")


def localization_reply(reply: zenoh.Reply) -> LocalizationReply:
    """zenoh's thread: the localization's reply to an initial pose."""
    return decoded_reply(reply, LocalizationReply, lambda why: LocalizationReply(False, why), "the localization")


def decoded_reply(
    reply: zenoh.Reply, reply_type: type[ReplyT], refused: Callable[[str], ReplyT], replier: str
) -> ReplyT:
    """``reply`` decoded, or ``refused`` naming why: an error reply, or one that does not decode."""
    if reply.ok is None:
        text = reply.err.payload.to_bytes().decode(errors="replace") if reply.err is not None else ""
        return refused(f"{replier} answered an error: {text}")
    try:
        return decode(reply_type, reply.ok.payload.to_bytes())
    except BadInput as error:
        return refused(f"{replier}'s reply does not decode: {error}")
