from collections.abc import Iterator

import pytest
import zenoh

from tests.harness import peer_session, running_router


@pytest.fixture
def endpoint() -> Iterator[str]:
    """A zenoh router of this test's own, on a free loopback port."""
    with running_router() as address:
        yield address


@pytest.fixture
def session(endpoint: str) -> Iterator[zenoh.Session]:
    """A peer session connected to this test's router."""
    with peer_session(endpoint) as peer:
        yield peer
