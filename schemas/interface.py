"""What a service takes and gives on zenoh, as data: the keys it publishes, subscribes, serves and
queries, and what it holds for the simulator's lockstep (docs/protocol.md section 2.9).

Each built-in service declares one :class:`Interface` (``services/interfaces.py``), a function of its
robot's keys and description; its node refuses a key it did not declare (``services/runtime/node.py``),
so the declarations are what the code does. From them come the roles' grants
(``services/security/grants.py``), the recording's channels, the launcher's liveliness waits and the
loop diagram of docs/architecture.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas.keys import Keys, ServiceName
from schemas.topics import LATCHED_TOPICS


@dataclass(frozen=True)
class Participation:
    """Taking part in lockstep: at every tick of ``rate_hz`` per second of simulation time, the
    simulator waits for one message on ``output`` (a key the service publishes)."""

    rate_hz: float
    output: str


@dataclass(frozen=True)
class Interface:
    """One service's keys on one robot (whole keys, ``invent/<robot>/...``). A latched key it
    publishes it also serves (its last message). Its status queryable and its liveliness token
    (``alive``) every service has; they are not listed."""

    service: ServiceName
    publishes: tuple[str, ...] = ()
    subscribes: tuple[str, ...] = ()
    serves: tuple[str, ...] = ()
    """Queryables besides its status and its latched keys (the motor's methods, the drive's goals)."""
    queries: tuple[str, ...] = ()
    """Other services' queryables it calls, and the latched keys it asks for the message published
    before it started."""
    participates: Participation | None = None
    observes: tuple[float, ...] = ()
    """Observer tokens' rates: it takes what the loop observes at these rates (no one waits for it)."""
    follows_participants: bool = False
    """It subscribes the output each lockstep participant's token names (the simulator), and asks
    the participant's status at the start: a user service's, under that service's own name,
    besides the built-ins' it lists."""

    def latched_published(self, keys: Keys) -> tuple[str, ...]:
        latched = {keys.topic(topic) for topic in LATCHED_TOPICS}
        return tuple(key for key in self.publishes if key in latched)

    def ticks(self, keys: Keys) -> tuple[str, ...]:
        """Its participant's token (``ticks``), if it takes part in lockstep: what the simulator waits on."""
        return () if self.participates is None else (keys.ticks(self.service, self.participates.rate_hz),)
