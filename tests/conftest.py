from collections.abc import Iterator

import pytest
import zenoh

from tests.harness import free_port, open_peer, open_router


@pytest.fixture
def endpoint() -> Iterator[str]:
    """A zenoh router of this test's own, on a free loopback port."""
    address = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(address)
    try:
        yield address
    finally:
        router.close()


@pytest.fixture
def session(endpoint: str) -> Iterator[zenoh.Session]:
    """A peer session connected to this test's router."""
    peer = open_peer(endpoint)
    try:
        yield peer
    finally:
        peer.close()
