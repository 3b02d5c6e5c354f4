"""Intra-process delivery (services/runtime/intraprocess.py): nodes composed on one executor with a
LocalBus hand each other their messages as they are; zenoh carries them only to subscribers outside
the process. Real zenoh sessions; the nodes as a composition builds them."""

import threading

import pytest

from schemas import Keys, Service, Time, TimedDoubleSeq
from schemas.codec import encode
from services.runtime.executor import Executor
from services.runtime.inputs import Delivery
from services.runtime.intraprocess import LocalBus, Watch
from services.runtime.node import Node
from tests.harness import Collector, peer_session, wait_until

KEYS = Keys("rh0")


@pytest.fixture
def composed(session):
    """A sim's and a motor's node on one executor and one bus, as ``invent up --composed`` has them."""
    executor, bus = Executor(), LocalBus()
    sim = Node(session, KEYS, Service.SIM, executor=executor, bus=bus)
    motor = Node(session, KEYS, Service.MOTOR, executor=executor, bus=bus)
    yield sim, motor
    motor.close()
    sim.close()


def _angles(nanoseconds: int) -> TimedDoubleSeq:
    return TimedDoubleSeq(Time(0, nanoseconds), [0.1 * nanoseconds, 0.2])


def _spin_until(node, predicate):
    def spun_and_holds():
        node.spin_once(0.01)
        return predicate()

    wait_until(spun_and_holds, 5.0)


@pytest.mark.parametrize("delivery", [Delivery.EVERY, Delivery.NEWEST, Delivery.SAMPLED, Delivery.QUEUED])
def test_a_composed_service_gets_the_very_message_its_neighbour_published_counted_as_an_input(composed, delivery):
    sim, motor = composed
    taken = []
    motor.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, taken.append, delivery)
    publisher = sim.publisher(KEYS.sim_wheel_angles)
    assert publisher.matched, "a subscriber of the process matches as one outside it does"
    sent = _angles(1)
    publisher.put(sent)
    _spin_until(motor, lambda: taken)
    assert taken == [sent] and taken[0] is sent, "handed over as it is: not encoded, not decoded"
    assert motor.status().inputs[KEYS.sim_wheel_angles].samples == 1


def test_every_message_in_order_and_a_flood_keeps_the_newest_of_a_channel_s_capacity(composed):
    sim, motor = composed
    taken = []
    motor.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, taken.append, Delivery.EVERY)
    publisher = sim.publisher(KEYS.sim_wheel_angles)
    for nanoseconds in range(1, 301):
        publisher.put(_angles(nanoseconds))
    motor.drain()
    assert [message.tm.nsec for message in taken] == list(range(45, 301)), "256 newest, in order"


def test_zenoh_carries_a_message_only_to_a_subscriber_outside_the_process(endpoint, composed):
    sim, motor = composed
    taken = []
    motor.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, taken.append, Delivery.EVERY)
    publisher = sim.publisher(KEYS.sim_wheel_angles)
    publisher.put(_angles(1))
    with peer_session(endpoint) as outside:
        collector = Collector(outside, KEYS.sim_wheel_angles, TimedDoubleSeq)
        wait_until(lambda: publisher.remote_subscribers, 5.0, "the outside subscriber to match")
        publisher.put(_angles(2))
        assert collector.get() == _angles(2), "decoded from what zenoh carried"
        collector.close()
    motor.drain()
    assert [message.tm.nsec for message in taken] == [1, 2], "each message once to the process's own input"


def test_a_message_offered_from_another_thread_wakes_the_service_thread(composed):
    sim, motor = composed
    taken = []
    motor.subscribe(KEYS.sim_wheel_angles, TimedDoubleSeq, taken.append, Delivery.EVERY, wakes=True)
    publisher = sim.publisher(KEYS.sim_wheel_angles)
    motor.spin_once(0)  # this thread is the executor's
    sent = _angles(7)
    threading.Timer(0.2, publisher.put, args=(sent,)).start()
    assert motor.spin_once(5.0), "woken by the post, long before the wait is over"
    motor.drain()
    assert taken == [sent]


def test_a_watch_sees_its_key_from_the_composed_services_and_from_outside_and_skips_what_does_not_decode(
    endpoint, session, composed
):
    sim, _motor = composed
    seen = []
    watch = Watch(session, KEYS.sim_wheel_angles, TimedDoubleSeq, seen.append, sim.bus)
    try:
        local = _angles(1)
        sim.publisher(KEYS.sim_wheel_angles).put(local)
        assert seen == [local] and seen[0] is local, "tapped on the publishing thread, as it is"
        with peer_session(endpoint) as outside:
            publisher = outside.declare_publisher(KEYS.sim_wheel_angles)
            wait_until(lambda: publisher.matching_status.matching, 5.0)
            publisher.put(b"not a message")
            publisher.put(encode(_angles(2)))
            wait_until(lambda: len(seen) == 2, 5.0)
            publisher.undeclare()
        assert seen[1] == _angles(2)
    finally:
        watch.close()
    sim.publisher(KEYS.sim_wheel_angles).put(_angles(3))
    assert len(seen) == 2, "closed: the tap is off the bus"
