import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from services.motor.state import STATE_HOME_VARIABLE
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


@pytest.fixture(scope="session", autouse=True)
def _state_home_of_this_session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Motors keep their latches and gains in the user's state directory: tests must neither read
    the developer's nor leave theirs there. Processes started by module fixtures use this one."""
    previous = os.environ.get(STATE_HOME_VARIABLE)
    os.environ[STATE_HOME_VARIABLE] = str(tmp_path_factory.mktemp("state-home"))
    yield
    if previous is None:
        del os.environ[STATE_HOME_VARIABLE]
    else:
        os.environ[STATE_HOME_VARIABLE] = previous


@pytest.fixture(autouse=True)
def _state_home_of_this_test(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """And each test's own processes one of their own, so a robot stopped in one test is not
    found stopped by the next."""
    monkeypatch.setenv(STATE_HOME_VARIABLE, str(tmp_path / "state-home"))


_CPUS_OF_THE_TEST_RUN = os.sched_getaffinity(0)


@pytest.fixture(autouse=True)
def _cpus_of_the_test_run() -> Iterator[None]:
    """``invent`` run in this process (tests.harness.refused) may get as far as its real-time
    settings, which hold the calling thread, and every thread and process it starts later, to one
    side of the CPUs (rt.partition): every later test's processes would then share one core. Each
    test starts with every thread of this process on the CPUs the run began with."""
    yield
    for thread in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(thread), _CPUS_OF_THE_TEST_RUN)
        except OSError:  # the thread ended meanwhile
            pass
