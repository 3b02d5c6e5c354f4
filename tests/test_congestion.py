"""A run's publishers and a reader that stalls (docs/protocol.md section 2.6): in lockstep every
sample reaches it, the publisher waiting for room; in realtime samples are dropped rather than wait.

The reader takes its samples through a small FIFO channel, which blocks zenoh's receiving thread
while full (zenoh-python's documented behaviour), and takes none for a second: the sender's
transmit queue fills, as it does when a reader (or the sending task itself) is descheduled on a
loaded machine."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from schemas import Keys, Service, Time, TimedDoubleSeq
from services.cli.services import service_plan
from services.runtime.inputs import LOCKSTEP_CONGESTION, congestion
from services.runtime.node import Node
from services.service import start_service
from tests.harness import peer_session, wait_until

KEYS = Keys("rh0")
KEY = KEYS.odometry_pose
SAMPLES = 5000
PAYLOAD = [0.5] * 2048
"""About 8 kB a sample (one zenoh batch holds it whole): 5000 of them (40 MB) overflow the buffers
between the sessions. A sample larger than a batch is fragmented, and zenoh waits up to 50 ms for each
fragment before dropping it (``max_wait_before_drop_fragments``), far longer than for a whole one."""
STALL_S = 1.0
QUIET_S = 0.5
"""How long the reader must get nothing, once the sender is done, to count what came."""


def _delivered(endpoint: str, lockstep: bool) -> tuple[int, float]:
    """How many of :data:`SAMPLES` samples a node's publisher put reach a reader that stalls for
    :data:`STALL_S` first, and how long the puts took."""
    with peer_session(endpoint) as sending, peer_session(endpoint) as reading:
        reader = reading.declare_subscriber(KEY, zenoh.handlers.FifoChannel(4))
        node = Node(sending, KEYS, Service.ODOMETRY, congestion=congestion(lockstep))
        try:
            publisher = node.publisher(KEY)
            wait_until(lambda: publisher.matched, 10.0, "the reader to match")
            started, took = time.monotonic(), []

            def send() -> None:
                for index in range(SAMPLES):
                    publisher.put(TimedDoubleSeq(Time(0, index), PAYLOAD))
                took.append(time.monotonic() - started)

            sender = threading.Thread(target=send)
            sender.start()
            time.sleep(STALL_S)  # the stall itself: the reader takes nothing meanwhile
            received, last = 0, time.monotonic()
            while sender.is_alive() or time.monotonic() - last < QUIET_S:
                if reader.try_recv() is not None:
                    received, last = received + 1, time.monotonic()
                else:
                    time.sleep(0.001)
            sender.join()
            return received, took[0]
        finally:
            node.close()
            reader.undeclare()


def test_a_lockstep_publisher_waits_for_a_stalled_reader_which_gets_every_sample(endpoint):
    received, took = _delivered(endpoint, lockstep=True)
    assert received == SAMPLES
    assert took > STALL_S, "the puts waited for the reader"


def test_a_realtime_publisher_drops_what_a_stalled_reader_cannot_take_rather_than_wait(endpoint):
    """The contrast that shows the reader above stalls long enough to lose samples without the wait."""
    received, _ = _delivered(endpoint, lockstep=False)
    assert received < SAMPLES


@pytest.mark.parametrize(("mode", "expected"), [("lockstep", "block"), ("realtime", "drop")])
def test_a_service_publishes_with_the_congestion_control_of_its_runs_mode_and_says_which(session, mode, expected):
    """``invent up`` gives every child ``--set sim.mode=`` of its run: the service takes it from there."""
    node, service = start_service(service_plan(["odometry", "--set", f"sim.mode={mode}"]), session)
    try:
        assert node.status().congestion == expected
        publisher = node.publisher(KEYS.odometry_pose)
        assert publisher.congestion_control == (
            LOCKSTEP_CONGESTION if expected == "block" else zenoh.CongestionControl.DROP
        )
    finally:
        service.close()
        node.close()
