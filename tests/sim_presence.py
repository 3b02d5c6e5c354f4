"""The simulator's presence on zenoh, played by a test: a session holding its liveliness token.

Services watch that token to pick up a restarted simulator (docs/protocol.md section 8). Zenoh reports one
token per key (a second token on ``sim/alive`` shows nothing while the first exists), so a test
playing a restart withdraws the old token and waits until the router no longer has it before
the next one appears, as a simulator process that exits and is started again does.
"""

from __future__ import annotations

from typing import Self

import zenoh

from schemas.keys import Keys, Service
from tests.harness import open_peer, wait_until


def token_present(session: zenoh.Session, key: str) -> bool:
    return any(reply.ok is not None for reply in session.liveliness().get(key, timeout=1.0))


class SimPresence:
    """A simulator that appears (on construction) and leaves (:meth:`leave`, or on exit)."""

    def __init__(self, endpoint: str, keys: Keys) -> None:
        self.key = keys.alive(Service.SIM)
        self._session = open_peer(endpoint)
        self._token = self._session.liveliness().declare_token(self.key)

    def leave(self, observer: zenoh.Session) -> None:
        """Close the session (its token goes with it) and wait until ``observer`` no longer sees it."""
        self._session.close()
        wait_until(lambda: not token_present(observer, self.key), what=f"{self.key} withdrawn")

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self._session.close()
