"""The bridge's node in the ROS graph, beside the shell (services/ros2/service.py): its liveliness
tokens (the node's and one per entity, ids drawn from one counter per zenoh session, as rmw_zenoh's
context does) and its publishers (CDR with rmw_zenoh's attachment; a transient-local one a zenoh-ext
advanced publisher with a cache), each message also kept in the bag's journal when there is one.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from typing import Any

import zenoh
import zenoh.ext

from services.ros2 import graph, interfaces, wire
from services.runtime.journal import Journal

SPORADIC_HEARTBEAT_S = 1.0
"""rmw_zenoh's heartbeat period for a reliable transient-local publisher's sample-miss detection."""


_CONTEXT_IDS: dict[str, Iterator[int]] = {}
"""rmw_zenoh's id counter of a context, per zenoh session (by its id): the bridges composed on one
session (a fleet's, ``invent ros2 --fleet``) draw their nodes' and entities' ids from one counter,
as the nodes of one rclcpp context do, so no two nodes of a session share an id."""


def context_ids(session: zenoh.Session) -> Iterator[int]:
    return _CONTEXT_IDS.setdefault(str(session.zid()), itertools.count())


class GraphTokens:
    """This bridge's node in the ROS graph: its liveliness token, and one token per entity, each
    with an id of its own, drawn after the node's from its session's counter."""

    def __init__(self, session: zenoh.Session, bridge: graph.BridgeGraph) -> None:
        self.session = session
        self.bridge = bridge
        self._ids = context_ids(session)
        self.identity = wire.NodeIdentity(
            bridge.domain, str(session.zid()), bridge.namespace, bridge.node_name, node_id=next(self._ids)
        )
        self._tokens: list[Any] = [session.liveliness().declare_token(self.identity.token())]

    def declare(self, kind: wire.EntityKind, entity: graph.Entity) -> str:
        """Hold the token of one more entity; returns it."""
        token = self.identity.entity_token(
            next(self._ids), kind, self.bridge.name(entity), entity.interface, self.bridge.type_hash(entity), entity.qos
        )
        self._tokens.append(self.session.liveliness().declare_token(token))
        return token

    def close(self) -> None:
        for token in reversed(self._tokens):
            token.undeclare()
        self._tokens.clear()


class RosPublisher:
    """One ROS topic's publisher: CDR payloads, each with its attachment (sequence from 1, one GID).
    A transient-local one is a zenoh-ext advanced publisher with a cache of ``depth`` samples,
    publisher detection and (reliable) sample-miss detection, as rmw_zenoh declares it, so a late
    subscriber gets the last message. Each message is also kept in ``journal``, if given, with its
    simulation time (``invent up --record-ros2``'s bag is made of those)."""

    def __init__(self, tokens: GraphTokens, entity: graph.Entity, journal: Journal | None = None) -> None:
        self.name = tokens.bridge.name(entity)
        self.key = tokens.bridge.key(entity)
        self._journal = journal
        self.sequence = wire.Sequence(wire.gid_of(tokens.declare(wire.EntityKind.PUBLISHER, entity)))
        qos = entity.qos
        self._publisher: Any
        if qos.transient_local:
            self._publisher = zenoh.ext.declare_advanced_publisher(
                tokens.session,
                self.key,
                cache=zenoh.ext.CacheConfig(qos.depth),
                publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=SPORADIC_HEARTBEAT_S
                )
                if qos.reliability is wire.Reliability.RELIABLE
                else None,
            )
        else:
            self._publisher = tokens.session.declare_publisher(self.key)

    @property
    def published(self) -> int:
        return self.sequence.last

    def put(self, message: Any, stamp_ns: int) -> None:
        """Publish ``message``, which carries the simulation time ``stamp_ns``."""
        payload = interfaces.serialize(message)
        self._publisher.put(payload, attachment=self.sequence.next(time.time_ns()))
        if self._journal is not None:
            self._journal.write(self.key, payload, time_ns=stamp_ns, stamp_ns=stamp_ns)

    def undeclare(self) -> None:
        self._publisher.undeclare()
