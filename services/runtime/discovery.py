"""Which services are there, and what they say: their liveliness tokens, then their ``status``
replies (docs/protocol.md sections 2.5 and 11.1), for the tools that look around (``invent status``,
``invent replay``)."""

from __future__ import annotations

import json
import queue
from typing import Any

import zenoh

from schemas.keys import Keys, ServiceName
from schemas.tokens import parse_alive_key


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


def service_statuses(session: zenoh.Session, key_expr: str, timeout: float) -> list[tuple[str, ServiceName, Any]]:
    """(robot, service, status reply) of each service whose liveliness token matches ``key_expr``:
    the tokens first (they reach a new session through the router at once), then each one's exact
    ``status`` key (a query on a wildcard, sent before the queryables reached this session, would
    reach none). The status is None when it did not answer."""
    statuses: list[tuple[str, ServiceName, Any]] = []
    for token in alive_services(session, key_expr, timeout):
        parsed = parse_alive_key(token)
        if parsed is None:
            continue
        robot_name, service = parsed
        status: Any = None
        for reply in session.get(Keys(robot_name).status(service), timeout=timeout):
            status = payload_value(reply.result.payload.to_bytes())
        statuses.append((robot_name, service, status))
    return statuses
