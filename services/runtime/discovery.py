"""Which services are there, and what they say: their liveliness tokens, then their ``status``
replies (docs/protocol.md sections 2.5 and 11.1), decoded with a Struct of schemas/status.py: for
the tools that look around (``invent status``, ``invent replay``) and ``invent up``
(:class:`StatusReader`)."""

from __future__ import annotations

import json
import logging
import queue
from typing import Any, NamedTuple

import msgspec
import zenoh

from schemas.keys import Keys, ServiceName
from schemas.status import ServiceStatus, StatusT
from schemas.tokens import parse_alive_key
from services.runtime.logs import RateLimitedLog, log

STATUS_QUERY_TIMEOUT_S = 2.0
"""How long a status query waits for its reply."""


def payload_value(payload: bytes) -> Any:
    """A reply payload as JSON when it is JSON, else as text."""
    try:
        return json.loads(payload)
    except ValueError:
        return payload.decode("utf-8", errors="replace")


def alive_services(session: zenoh.Session, key_expr: str, timeout: float, settle: float = 0.1) -> list[str]:
    """Liveliness tokens under ``key_expr``: waits up to ``timeout`` for the first, then ``settle`` for the rest."""
    tokens: queue.Queue[str] = queue.Queue()
    found: list[str] = []
    with session.liveliness().declare_subscriber(
        key_expr, lambda sample: tokens.put(str(sample.key_expr)), history=True
    ):
        wait = timeout
        while True:
            try:
                found.append(tokens.get(timeout=wait))
            except queue.Empty:
                break
            wait = settle
    return sorted(set(found))


class StatusReader:
    """Status queries, each reply decoded with the Struct its reader names: a reply that does not
    decode is a bad reply, counted (:attr:`bad_replies`, by key), logged at most once a second per
    key, and taken as no reply at all (None), as a service that does not answer."""

    def __init__(self, session: zenoh.Session, timeout: float = STATUS_QUERY_TIMEOUT_S) -> None:
        self.session = session
        self.timeout = timeout
        self.bad_replies: dict[str, int] = {}
        self._log = RateLimitedLog(log.getChild("status"))

    def get(self, key: str, status_type: type[StatusT]) -> StatusT | None:
        """The first reply on ``key`` as ``status_type``, or None when nothing answers or the reply is bad."""
        payload = self.payload(key)
        return None if payload is None else self.decode(key, payload, status_type)

    def get_with_own(self, key: str, status_type: type[StatusT]) -> tuple[StatusT, dict[str, Any]] | None:
        """:meth:`get`, with the reply as a JSON object too: a user service's own fields, free-form,
        are beside the runtime's typed ones."""
        payload = self.payload(key)
        status = None if payload is None else self.decode(key, payload, status_type)
        return None if payload is None or status is None else (status, json.loads(payload))

    def payload(self, key: str) -> bytes | None:
        for reply in self.session.get(key, timeout=self.timeout):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def decode(self, key: str, payload: bytes, status_type: type[StatusT]) -> StatusT | None:
        try:
            return msgspec.json.decode(payload, type=status_type)
        except (msgspec.ValidationError, msgspec.DecodeError) as error:
            self.bad_replies[key] = self.bad_replies.get(key, 0) + 1
            self._log(key, logging.WARNING, "bad status reply on %s (taken as none): %s", key, error)
            return None


class ServiceReply(NamedTuple):
    """A service alive, and its status: typed, and the reply as it came (a user service's own fields
    with it); both None when it did not answer or its reply did not decode."""

    robot: str
    service: ServiceName
    status: ServiceStatus | None
    reply: dict[str, Any] | None


def service_statuses(session: zenoh.Session, key_expr: str, timeout: float) -> list[ServiceReply]:
    """Each service whose liveliness token matches ``key_expr``, with its status: the tokens first
    (they reach a new session through the router at once), then each one's exact ``status`` key (a
    query on a wildcard, sent before the queryables reached this session, would reach none). Each
    reply is decoded as what every service's status has (:class:`ServiceStatus`), all these tools
    read: a real plant's ``sim/status``, its own (docs/plant.md), is one too."""
    reader = StatusReader(session, timeout)
    replies: list[ServiceReply] = []
    for token in alive_services(session, key_expr, timeout):
        parsed = parse_alive_key(token)
        if parsed is None:
            continue
        robot_name, service = parsed
        decoded = reader.get_with_own(Keys(robot_name).status(service), ServiceStatus)
        replies.append(ServiceReply(robot_name, service, *(decoded or (None, None))))
    return replies
