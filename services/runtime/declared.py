"""A node's check of its service's declaration (:class:`schemas.interface.Interface`): a key under
``invent/`` that the service did not declare is refused where the node is asked for it, at start,
as :class:`UndeclaredKey` (a bug in the service, not bad input), so the declarations the grants,
the launcher and the docs are made from are what the code does. Keys outside ``invent/`` (the ROS
2 bridge's ROS graph) are declared by :mod:`services.ros2.graph` and not checked here.
"""

from __future__ import annotations

import zenoh

from schemas.interface import Interface
from schemas.keys import ROOT, Keys, Service


class UndeclaredKey(ValueError):
    """A service used a key of ``invent/`` its :class:`Interface` does not declare."""


class DeclaredKeys:
    """What ``interface`` lets its node declare; None: anything (a tool's node, a user service's)."""

    def __init__(self, interface: Interface | None, keys: Keys) -> None:
        self._interface = interface
        self._keys = keys
        self._publishes = self._subscribes = self._serves = self._queries = frozenset[str]()
        if interface is not None:
            self._publishes = frozenset(interface.publishes)
            self._subscribes = frozenset(interface.subscribes)
            self._serves = frozenset(
                (keys.status(interface.service), *interface.serves, *interface.latched_published(keys))
            )
            self._queries = frozenset(interface.queries)

    def also_serve(self, key: str) -> None:
        """Let the node serve ``key`` too: a queryable of the process it runs in, not of the service
        (``invent control``'s ``control/status``, which its role is granted beside the sim's and the motor's)."""
        self._serves |= {key}

    def publish(self, key: str) -> None:
        self._check(key, "publishes", self._publishes)

    def subscribe(self, key: str) -> None:
        if self._interface is not None and self._interface.follows_participants and self._a_user_services(key):
            return
        self._check(key, "subscribes", self._subscribes)

    def serve(self, key: str) -> None:
        self._check(key, "serves", self._serves)

    def query(self, key: str) -> None:
        if self._interface is not None and self._interface.follows_participants and self._a_user_services(key):
            return  # a user participant's status: has it seen this simulator?
        self._check(key, "queries", self._queries)

    def _a_user_services(self, key: str) -> bool:
        """Whether ``key`` is under a user service's own name (``invent/<robot>/<name>/...``)."""
        prefix = f"{self._keys.prefix}/"
        return key.startswith(prefix) and key[len(prefix) :].split("/", 1)[0] not in Service._value2member_map_

    def _check(self, key: str, what: str, declared: frozenset[str]) -> None:
        interface = self._interface
        if interface is None or not key.startswith(f"{ROOT}/") or key in declared:
            return
        wanted = zenoh.KeyExpr(key)
        if not any(zenoh.KeyExpr(expr).includes(wanted) for expr in declared):
            raise UndeclaredKey(
                f"{interface.service} {what} {key}, which its interface does not declare (services/interfaces.py)"
            )
